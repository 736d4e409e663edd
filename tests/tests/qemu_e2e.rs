//! End-to-end accuracy: held-out bench runs (15 % oil loss, `nemm-firmware/data/e2e/`)
//! replayed through the firmware's SPI sensor path in QEMU, displacement as recorded, and the
//! force estimates scored against the measured force.
//!
//! For each run the trace in the image is replaced by the run (`.nemm_trace`: displacement
//! and measured force), the firmware runs on a slow sample clock (every period's record
//! reaches the host) and its force RMSE over the whole run is compared with the trainer's
//! whole-run evaluation of the same model on the same run (its own preprocessing: the
//! zero-phase velocity, or the causal one for a model trained with `--velocity causal`).
//! The firmware must stay within [`RATIO`] x the host's RMSE + [`SLACK_N`] on every run:
//! the causal velocity estimate (backward difference and 500 Hz low-pass, 0.37 ms of lag)
//! and the ADC's quantisation are what the firmware adds.
//!
//! Prints `e2e run=<file> firmware_rmse_n=<x> host_rmse_n=<y>` per run (`cargo xtask e2e`
//! shows these lines). Run by `cargo xtask test`.

mod common;

use common::{e2e_runs, host_forces, recorded_config, rmse_n, signal_config, Embedded};
use nemm_firmware::trace;
use nemm_tests::firmware::{run_qemu, scratch_dir, slot_with, TRACE_SECTION, WEIGHTS_SECTION};
use std::time::Duration;

/// The firmware's RMSE may exceed the host's by this factor ...
const RATIO: f64 = 1.10;
/// ... plus this many newtons.
const SLACK_N: f64 = 2.0;

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn firmware_force_error_stays_within_the_hosts_on_every_held_out_run() {
    let e = Embedded::from_env();
    let ds = e2e_runs();
    let cfg = recorded_config(&e.model);
    let signal = signal_config(&cfg, &common::e2e_dir());
    let capacity = e.contents.trace.len();
    let slot = slot_with(&e.blob);
    let with_weights = e
        .elf
        .patched(WEIGHTS_SECTION, &slot)
        .expect("patch the weights slot");
    let base = nemm_tests::elf::Elf::parse(with_weights).expect("patched image");
    let mut failures = Vec::new();
    for (i, run) in ds.runs.iter().enumerate() {
        let samples: Vec<(f32, f32, f32)> = run
            .displacement_m
            .iter()
            .zip(&run.force_n)
            .map(|(&x, &f)| (x as f32, f32::NAN, f as f32))
            .collect();
        let mut bytes = vec![0u8; capacity];
        trace::encode(
            ds.sample_rate_hz as f32,
            run.entry.oil_loss as f32,
            &samples,
            &mut bytes,
        )
        .unwrap_or_else(|| {
            panic!(
                "{}: {} samples do not fit the image's {capacity}-byte trace",
                run.entry.file.display(),
                samples.len()
            )
        });
        let patched = base
            .patched(TRACE_SECTION, &bytes)
            .expect("patch the trace");
        let path = scratch_dir().join(format!("e2e-{i}.elf"));
        std::fs::write(&path, patched).expect("write the image");
        let r = run_qemu(
            &e.images.qemu,
            &path,
            &["period_ticks=100000"],
            Duration::from_secs(900),
        );
        assert_eq!(r.code, Some(0), "{}", r.describe());
        let out = r.output();
        assert_eq!(out.expect("summary").num("dropped"), 0, "records dropped");
        assert_eq!(out.steps.len(), samples.len(), "one record per sample");
        let firmware = rmse_n(out.steps.iter().map(|s| f64::from(s.force())), &run.force_n);
        let host = rmse_n(host_forces(&e.model, &ds, i, &signal), &run.force_n);
        println!(
            "e2e run={} firmware_rmse_n={firmware:.2} host_rmse_n={host:.2}",
            run.entry.file.display()
        );
        if firmware > RATIO * host + SLACK_N || firmware.is_nan() {
            failures.push(format!(
                "{}: firmware {firmware:.2} N > {RATIO} x host {host:.2} N + {SLACK_N} N",
                run.entry.file.display()
            ));
        }
        let _ = std::fs::remove_file(path);
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
