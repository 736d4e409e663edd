//! Parity: the firmware in QEMU, fed the recorded bench trace through its sensor driver,
//! produces force estimates bit-identical to `nemm-core` on the host over the same samples.
//!
//! The host reference (`nemm_tests::reference`) runs the firmware's own sample path (the
//! `StrokeSensor` driver on the replay ADC, then `Estimator::step`) compiled for x86-64, with
//! the trace and the weights read out of the firmware image. Compared per period: the
//! velocity handed to the estimator, the force, the estimator's flags and the firmware's
//! fault flags, all as bits; and the CRC-32 digests the 10 kHz task computes itself, which
//! cover every period even when the logger dropped records.
//!
//! Run by `cargo xtask test` (see `nemm_tests::firmware` for the environment it sets).

use nemm_core::testing::example_model;
use nemm_core::{encode_to_vec, Model, ModelKind};
use nemm_firmware::options::Options;
use nemm_firmware::pipeline::DETERMINISTIC_FLAGS;
use nemm_firmware::PARAM_CAPACITY;
use nemm_tests::elf::Elf;
use nemm_tests::firmware::{image_with_slot, run_qemu, slot_with, Contents, Images, Output, Run};
use nemm_tests::reference::{self, Reference};
use std::path::Path;
use std::time::Duration;

const TIMEOUT: Duration = Duration::from_secs(600);
/// A slow sample clock (4 ms per period, 4 M instructions): the logger always keeps up, so
/// every period's record reaches the host. (`-icount sleep=off` skips the idle time: a slow
/// clock costs no wall time.)
const SLOW_CLOCK: &str = "period_ticks=100000";

fn run(images: &Images, elf: &Path, args: &[&str]) -> (Run, Output) {
    let r = run_qemu(&images.qemu, elf, args, TIMEOUT);
    assert_eq!(r.code, Some(0), "the firmware run failed: {}", r.describe());
    let o = r.output();
    // The image is the one built for the machine it runs on.
    assert_eq!(
        o.expect("boot").get("board"),
        Some(nemm_tests::firmware::board().1.as_str()),
        "the image's board"
    );
    (r, o)
}

/// Checks the run's digests and summary against the reference; and, if `all_steps`, every
/// period's record.
fn assert_parity(what: &str, out: &Output, reference: &Reference, all_steps: bool) {
    let summary = out.expect("summary");
    let n = reference.outputs.len() as u32;
    assert_eq!(summary.num("steps"), n, "{what}: periods");
    for (key, want) in [
        ("sensor_errors", reference.counters.sensor_errors),
        ("invalid_samples", reference.counters.invalid_samples),
        ("priming", reference.counters.priming),
        ("held", reference.diagnostics.held_samples),
        ("resets", reference.diagnostics.resets),
    ] {
        assert_eq!(summary.num(key), want, "{what}: summary `{key}`");
    }
    let target: Vec<u32> = out.digests.iter().map(|d| d.crc).collect();
    assert_eq!(
        target.len(),
        reference.chunk_digests.len(),
        "{what}: digest chunks"
    );
    if all_steps {
        assert_eq!(
            summary.num("dropped"),
            0,
            "{what}: the logger dropped records"
        );
        assert_eq!(out.steps.len() as u32, n, "{what}: step records");
        let mut mismatches = 0usize;
        let mut max_abs = 0.0f64;
        let mut max_rel = 0.0f64;
        let mut first = None;
        for (k, (s, r)) in out.steps.iter().zip(&reference.outputs).enumerate() {
            assert_eq!(s.k, k as u32, "{what}: record order");
            let same = s.velocity_bits == r.velocity_m_s.to_bits()
                && s.force_bits == r.estimate.force_n.to_bits()
                && s.estimator_flags == r.estimate.flags.0
                && s.firmware_flags & DETERMINISTIC_FLAGS == r.firmware_flags;
            if !same {
                mismatches += 1;
                first.get_or_insert((k, *s, *r));
                let d = (f64::from(s.force()) - f64::from(r.estimate.force_n)).abs();
                max_abs = max_abs.max(d);
                max_rel = max_rel.max(d / f64::from(r.estimate.force_n.abs()).max(1.0));
            }
        }
        assert!(
            mismatches == 0,
            "{what}: {mismatches} of {n} periods differ from the host (max |dF| {max_abs:.3e} N, \
             max relative {max_rel:.3e}); first: {:?}",
            first
        );
    }
    for (d, (&t, &h)) in out
        .digests
        .iter()
        .zip(target.iter().zip(&reference.chunk_digests))
    {
        assert_eq!(
            t,
            h,
            "{what}: digest of periods {}..{} differs from the host",
            d.first,
            d.first + d.steps
        );
    }
    assert_eq!(
        summary.num("digest"),
        reference.run_digest,
        "{what}: run digest"
    );
}

fn max_abs_force(r: &Reference) -> f32 {
    r.outputs
        .iter()
        .map(|o| o.estimate.force_n.abs())
        .fold(0.0, f32::max)
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn every_estimate_is_bit_identical_to_the_host() {
    let images = Images::from_env();
    let elf = Elf::read(&images.app).expect("firmware image");
    let contents = Contents::of(&elf);
    let args = [SLOW_CLOCK];
    let (run, out) = run(&images, &images.app, &args);
    let options = Options::parse(&args.join(" ")).expect("options");
    let reference = reference::run(&contents.trace, contents.blob(), &options);
    assert_eq!(out.expect("weights ok").get("kind"), Some("nemm"));
    assert_eq!(out.expect("summary").num("overruns"), 0);
    assert_parity("nemm, slow clock", &out, &reference, true);
    // The stack (deepest at boot, while `decode` builds the model) stayed inside the RAM the
    // layout leaves it: painted from `_stack_end` (end of the statics) to `_stack_start`.
    let symbol = |name: &str| {
        elf.symbols
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("no symbol {name}"))
            .value
    };
    let room = symbol("_stack_start") - symbol("_stack_end");
    let used = out.expect("summary").num("stack_used");
    assert!(
        used < room,
        "the stack peak reached the statics: {used} of {room} bytes"
    );
    eprintln!("qemu_parity: stack peak {used} B of the {room} B the memory layout leaves it");
    eprintln!(
        "qemu_parity: {} periods of the bench trace, every velocity, force and flag \
         bit-identical to the host (|F| up to {:.1} N, {} digest chunks); QEMU {:.1} s",
        reference.outputs.len(),
        max_abs_force(&reference),
        reference.chunk_digests.len(),
        run.wall.as_secs_f64()
    );
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn digests_match_at_the_real_sample_rate() {
    let images = Images::from_env();
    let elf = Elf::read(&images.app).expect("firmware image");
    let contents = Contents::of(&elf);
    // The board's 10 kHz period: if the step is slower than the period every step overruns
    // and the logger starves, but the results (and their digests) must not change.
    let (run, out) = run(&images, &images.app, &[]);
    let reference = reference::run(&contents.trace, contents.blob(), &Options::default());
    assert_eq!(out.expect("start").num("period_ticks"), 2500);
    assert_parity("nemm, 10 kHz", &out, &reference, false);
    // Whatever records did get through are the reference's.
    for s in &out.steps {
        let r = &reference.outputs[s.k as usize];
        assert_eq!(s.force_bits, r.estimate.force_n.to_bits(), "period {}", s.k);
    }
    let summary = out.expect("summary");
    eprintln!(
        "qemu_parity: at 10 kHz: digests match; {} overruns, {} records dropped, longest \
         step {} ticks; QEMU {:.1} s",
        summary.num("overruns"),
        summary.num("dropped"),
        summary.num("max_step_ticks"),
        run.wall.as_secs_f64()
    );
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn the_other_model_kinds_are_bit_identical_too() {
    let images = Images::from_env();
    let elf = Elf::read(&images.app).expect("firmware image");
    let contents = Contents::of(&elf);
    let args = [SLOW_CLOCK, "samples=3000"];
    let options = Options::parse(&args.join(" ")).expect("options");
    for kind in [ModelKind::Sem, ModelKind::LinearEmm, ModelKind::NemmLight] {
        let model: Model<PARAM_CAPACITY> = example_model(kind, 16, 5).expect("example model");
        let blob = encode_to_vec(&model).expect("encode");
        let image = image_with_slot(&elf, &slot_with(&blob), kind.name());
        let (_, out) = run(&images, &image, &args);
        assert_eq!(out.expect("weights ok").get("kind"), Some(kind.name()));
        let reference = reference::run(&contents.trace, &blob, &options);
        assert_parity(kind.name(), &out, &reference, true);
        let _ = std::fs::remove_file(image);
    }
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn table_mode_is_bit_identical_to_the_host() {
    // The tabulated fast path (`mode=table`): the target reads the tables the embedded blob
    // stores at the trace's alpha (no table build at boot), and every period's estimate
    // equals the host's, which builds and checks its tables.
    let images = Images::from_env();
    let elf = Elf::read(&images.app).expect("firmware image");
    let contents = Contents::of(&elf);
    let args = [SLOW_CLOCK, "samples=3000", "mode=table"];
    let options = Options::parse(&args.join(" ")).expect("options");
    let (_, out) = run(&images, &images.app, &args);
    let ok = out.expect("weights ok");
    assert_eq!(ok.get("kind"), Some("nemm"));
    assert_eq!(ok.get("mode"), Some("table"));
    assert_eq!(ok.get("tables"), Some("stored"));
    let reference = reference::run(&contents.trace, contents.blob(), &options);
    assert_parity("nemm, table mode", &out, &reference, true);
}
