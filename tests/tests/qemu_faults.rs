//! Faults in QEMU: injected sensor faults (SPI errors, NaN bursts in the recording) are
//! counted and flagged, the estimator holds its last good input, the 10 kHz loop keeps
//! running and the estimate returns to the fault-free one afterwards; a period overrun is
//! detected and counted.
//!
//! Run by `cargo xtask test` (see `nemm_tests::firmware` for the environment it sets).

use nemm_core::Flags;
use nemm_firmware::options::Options;
use nemm_firmware::report::{FW_OVERRUN, FW_PRIMING, FW_SAMPLE_INVALID, FW_SENSOR_ERROR};
use nemm_tests::elf::Elf;
use nemm_tests::firmware::{run_qemu, Contents, Images, Output};
use nemm_tests::reference;
use std::time::Duration;

const TIMEOUT: Duration = Duration::from_secs(600);
const SLOW_CLOCK: &str = "period_ticks=100000";

/// A fault window: `(option, first sample, samples, the firmware flag it raises)`. The
/// recording is the 50 mm / 1.048 m/s bench run: the windows sit at the stroke's zero
/// crossings (highest velocity) and turning points (highest acceleration).
const FAULTS: [(&str, u32, u32, u8); 4] = [
    ("bus", 2250, 25, FW_SENSOR_ERROR),
    ("nan", 4500, 40, FW_SAMPLE_INVALID),
    ("bus", 6000, 1, FW_SENSOR_ERROR),
    ("nan", 8250, 1, FW_SAMPLE_INVALID),
];

/// Periods after the end of a window by which the estimate must be back on the fault-free
/// one (30 ms: three time constants `(b_pr + b_fl) / k_pr` of the example model).
const SETTLE: usize = 300;
/// "Back on": within this fraction of the run's largest |force|.
const RECOVERED: f32 = 1e-3;
/// Periods after the end of a window by which the estimate must equal the fault-free one bit
/// for bit (the sensor's low-pass and the model's state have forgotten the fault).
const IDENTICAL: usize = 2000;

fn run(images: &Images, args: &[&str]) -> Output {
    let r = run_qemu(&images.qemu, &images.app, args, TIMEOUT);
    assert_eq!(r.code, Some(0), "the firmware run failed: {}", r.describe());
    r.output()
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn sensor_faults_are_flagged_and_the_estimate_recovers() {
    let images = Images::from_env();
    let elf = Elf::read(&images.app).expect("firmware image");
    let contents = Contents::of(&elf);
    let fault_args: Vec<String> = FAULTS
        .iter()
        .map(|(kind, start, len, _)| format!("fault={kind}@{start}+{len}"))
        .collect();
    let mut args = vec![SLOW_CLOCK];
    args.extend(fault_args.iter().map(String::as_str));
    let out = run(&images, &args);

    // The same run on the host: bit-identical, faults included.
    let options = Options::parse(&args.join(" ")).expect("options");
    let faulty = reference::run(&contents.trace, contents.blob(), &options);
    let clean = reference::run(&contents.trace, contents.blob(), &Options::default());
    let n = clean.outputs.len();
    assert_eq!(out.steps.len(), n, "the loop ran every period");
    assert_eq!(out.expect("summary").num("dropped"), 0);
    for (s, r) in out.steps.iter().zip(&faulty.outputs) {
        assert_eq!(
            (s.velocity_bits, s.force_bits, s.estimator_flags),
            (
                r.velocity_m_s.to_bits(),
                r.estimate.force_n.to_bits(),
                r.estimate.flags.0
            ),
            "period {} differs from the host",
            s.k
        );
    }
    let exit = out.expect("exit");
    assert_eq!(exit.num("published") as usize, n, "a force every period");

    // Counted: each window's samples, plus one re-priming period after each window (and
    // the one at start-up); every one of them is held by the estimator.
    let count = |flag: u8| -> u32 {
        FAULTS
            .iter()
            .filter(|f| f.3 == flag)
            .map(|f| f.2)
            .sum::<u32>()
    };
    let summary = out.expect("summary");
    let windows = FAULTS.len() as u32;
    assert_eq!(summary.num("sensor_errors"), count(FW_SENSOR_ERROR));
    assert_eq!(summary.num("invalid_samples"), count(FW_SAMPLE_INVALID));
    assert_eq!(summary.num("priming"), 1 + windows);
    assert_eq!(
        summary.num("held"),
        1 + windows + count(FW_SENSOR_ERROR) + count(FW_SAMPLE_INVALID)
    );
    assert_eq!(summary.num("resets"), 0);

    let held = Flags::INPUT_NON_FINITE | Flags::INPUT_HELD;
    let f_max = clean
        .outputs
        .iter()
        .map(|o| o.estimate.force_n.abs())
        .fold(0.0, f32::max);
    let mut report = Vec::new();
    for (i, &(kind, start, len, flag)) in FAULTS.iter().enumerate() {
        let (start, len) = (start as usize, len as usize);
        // Flagged: the window, then one re-priming period, then clean records.
        for s in &out.steps[start..start + len] {
            assert_eq!(s.firmware_flags, flag, "period {} in a {kind} window", s.k);
            assert_eq!(s.estimator_flags, held, "period {}: input held", s.k);
            assert!(s.force().is_finite());
        }
        let after = &out.steps[start + len];
        assert_eq!(after.firmware_flags, FW_PRIMING, "period {}", after.k);
        assert_eq!(after.estimator_flags, held, "period {}", after.k);
        let next = &out.steps[start + len + 1];
        assert_eq!(
            (next.firmware_flags, next.estimator_flags),
            (0, 0),
            "period {}: clean again",
            next.k
        );
        // Recovered: back on the fault-free estimate within SETTLE periods, and staying
        // there until the next window.
        let end = FAULTS.get(i + 1).map_or(n, |f| f.1 as usize);
        let dev = |k: usize| (out.steps[k].force() - clean.outputs[k].estimate.force_n).abs();
        let worst_during = (start..start + len + 1).map(dev).fold(0.0, f32::max);
        let settled = (start + len + 1..end)
            .rev()
            .find(|&k| dev(k) > RECOVERED * f_max)
            .map_or(start + len + 1, |k| k + 1);
        let settle = settled - (start + len);
        report.push(format!(
            "{kind}@{start}+{len}: |dF| up to {worst_during:.1} N, within {:.1} N after {settle} periods",
            RECOVERED * f_max
        ));
        assert!(
            settle <= SETTLE,
            "after the {kind} window at {start}: still off the fault-free estimate by more \
             than {:.1} N {settle} periods later",
            RECOVERED * f_max
        );
        // And exactly back: once the filters have forgotten the fault, identical bits.
        let back = (start + len + 1..end)
            .rev()
            .find(|&k| dev(k) != 0.0)
            .map_or(0, |k| k + 1 - (start + len));
        report.push(format!(
            "    bit-identical to the fault-free run after {back} periods"
        ));
        assert!(
            back <= IDENTICAL && start + len + back < end,
            "after the {kind} window at {start}: not back to the fault-free bits ({back} periods)"
        );
    }
    eprintln!(
        "qemu_faults: (max |F| {f_max:.1} N)\n  {}",
        report.join("\n  ")
    );
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn a_period_overrun_is_detected_and_counted() {
    let images = Images::from_env();
    let elf = Elf::read(&images.app).expect("firmware image");
    let contents = Contents::of(&elf);
    // Periods 1500..1503 busy-wait one whole period before their step.
    let args = [SLOW_CLOCK, "samples=2000", "stall=1500+3"];
    let out = run(&images, &args);
    let summary = out.expect("summary");
    assert_eq!(summary.num("overruns"), 3, "overruns counted");
    assert_eq!(out.steps.len(), 2000);
    for s in &out.steps {
        let stalled = (1500..1503).contains(&s.k);
        assert_eq!(
            s.firmware_flags & FW_OVERRUN != 0,
            stalled,
            "period {}: overrun flag",
            s.k
        );
        if stalled {
            assert_eq!(s.ticks, 0, "period {}", s.k);
        }
    }
    // Overruns change nothing in the results.
    let options = Options::parse(&args.join(" ")).expect("options");
    let reference = reference::run(&contents.trace, contents.blob(), &options);
    assert_eq!(summary.num("digest"), reference.run_digest);
}
