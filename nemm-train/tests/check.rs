//! `nemm data check`: plausibility findings, robust amplitude and the velocity-column check.
use nemm_dataset::{Dataset, Run, RunEntry};
use nemm_train::data::check::{self, Finding, FindingKind};
use nemm_train::data::preprocess::{self, SignalConfig};
use nemm_train::report::check_report;
use std::f64::consts::PI;
use std::path::PathBuf;
use support::quantise;

mod support;

/// Deterministic pseudo-noise in [-0.5, 0.5) (a small LCG: tests need no statistics).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    }
}

/// A sine run at `fs`: amplitude `a` \[m\], frequency `f` \[Hz\], damping force with noise
/// (`noise_n` peak-to-peak), displacement quantised to `qx`.
fn sine(fs: f64, a: f64, f: f64, seconds: f64, qx: f64, noise_n: f64) -> Run {
    let n = (fs * seconds) as usize;
    let w = 2.0 * PI * f;
    let mut rng = Lcg(3);
    let time_s: Vec<f64> = (0..n).map(|i| i as f64 / fs).collect();
    let displacement_m = time_s
        .iter()
        .map(|t| quantise(a * (w * t).sin(), qx))
        .collect();
    let force_n = time_s
        .iter()
        .map(|t| 1500.0 * a * w * (w * t).cos() + noise_n * rng.next())
        .collect();
    Run {
        entry: RunEntry {
            file: PathBuf::from("runs/r.csv"),
            oil_loss: 0.0,
            amplitude_m: None,
            target_velocity_m_s: None,
        },
        time_s,
        displacement_m,
        force_n,
        velocity_m_s: None,
        alpha: None,
    }
}

fn dataset(fs: f64, run: Run) -> Dataset {
    support::dataset("t", fs, vec![run])
}

/// Signal options with a cut-off below every test rate's Nyquist frequency.
fn signal(ds: &Dataset) -> SignalConfig {
    SignalConfig {
        cutoff_hz: Some(0.3 * ds.sample_rate_hz),
        ..SignalConfig::default()
    }
}

fn findings(ds: &Dataset) -> Vec<Finding> {
    check::check_dataset(ds, &signal(ds)).expect("check").1
}

fn report(ds: &Dataset) -> String {
    let (runs, f) = check::check_dataset(ds, &signal(ds)).expect("check");
    check_report(ds, &runs, &f)
}

fn only(f: &[Finding], kind: FindingKind, column: &str) -> Finding {
    let of: Vec<&Finding> = f
        .iter()
        .filter(|x| x.kind == kind && x.column == column)
        .collect();
    assert_eq!(of.len(), 1, "{kind:?} in {column}: {f:#?}");
    of[0].clone()
}

#[test]
fn a_clean_quantised_slow_run_has_no_findings() {
    // 0.2 Hz at 300 Hz, 25 mm, 0.01 mm resolution: the turning points stay on one value for
    // about 20 samples, which is neither clipping nor a dropout.
    let ds = dataset(300.0, sine(300.0, 0.025, 0.2, 15.0, 1e-5, 2.0));
    let f = findings(&ds);
    assert!(f.is_empty(), "{f:#?}");
    assert!(report(&ds).contains("no anomalies found"));
}

#[test]
fn a_displacement_of_1e30_m_is_caught_with_run_time_and_line() {
    let mut run = sine(1000.0, 0.01, 2.0, 2.0, 1e-6, 2.0);
    run.displacement_m[700] = 1e30;
    let ds = dataset(1000.0, run);
    let f = findings(&ds);
    let m = only(&f, FindingKind::Magnitude, "displacement_m");
    assert_eq!((m.sample, m.line, m.count), (700, 702, 1));
    assert!((m.time_s - 0.7).abs() < 1e-12);
    let r = report(&ds);
    assert!(!r.contains("no anomalies found"), "{r}");
    assert!(
        r.contains("run 0 (runs/r.csv:702, t = 0.7 s): implausible magnitude"),
        "{r}"
    );
}

#[test]
fn force_and_velocity_magnitudes_are_checked() {
    let mut run = sine(1000.0, 0.01, 2.0, 2.0, 1e-6, 2.0);
    run.force_n[10] = -2e6;
    let v: Vec<f64> = (0..run.len())
        .map(|i| if i == 20 { 25.0 } else { 0.0 })
        .collect();
    run.velocity_m_s = Some(v);
    let f = findings(&dataset(1000.0, run));
    assert_eq!(only(&f, FindingKind::Magnitude, "force_n").line, 12);
    assert_eq!(only(&f, FindingKind::Magnitude, "velocity_m_s").line, 22);
}

#[test]
fn spikes_are_found_at_their_sample() {
    let mut run = sine(1000.0, 0.01, 2.0, 2.0, 1e-6, 2.0);
    run.force_n[1234] += 400.0;
    run.force_n[1500] -= 300.0;
    run.force_n[1501] -= 300.0;
    let f = findings(&dataset(1000.0, run));
    let s = only(&f, FindingKind::Spike, "force_n");
    assert_eq!((s.sample, s.count), (1234, 2));
    assert!(f.iter().all(|x| x.kind == FindingKind::Spike), "{f:#?}");
}

#[test]
fn repeated_rows_and_a_frozen_column_are_dropouts() {
    let mut run = sine(1000.0, 0.01, 2.0, 3.0, 1e-6, 2.0);
    // The logger holds the last row for 15 samples.
    for i in 501..516 {
        run.displacement_m[i] = run.displacement_m[500];
        run.force_n[i] = run.force_n[500];
    }
    // The displacement sensor freezes for 0.4 s while the force goes on.
    for i in 2001..2401 {
        run.displacement_m[i] = run.displacement_m[2000];
    }
    let f = findings(&dataset(1000.0, run));
    let rows = only(&f, FindingKind::Dropout, "(all)");
    assert_eq!((rows.sample, rows.line), (500, 502));
    let flat = only(&f, FindingKind::Dropout, "displacement_m");
    assert_eq!(flat.sample, 2000);
    assert!(flat.message.contains("401 samples"), "{}", flat.message);
}

/// A channel at one value over the whole run (a disconnected load cell logging zeros) is a
/// dead channel: a problem, not a note.
#[test]
fn a_dead_channel_is_a_problem() {
    let mut run = sine(1000.0, 0.01, 2.0, 2.0, 1e-6, 2.0);
    let n = run.force_n.len();
    run.force_n.iter_mut().for_each(|f| *f = 0.0);
    let f = findings(&dataset(1000.0, run));
    let dead = only(&f, FindingKind::Dropout, "force_n");
    assert_eq!((dead.sample, dead.count), (0, n));
    assert!(!dead.kind.is_info());
    assert!(dead.message.contains("dead channel"), "{}", dead.message);
}

#[test]
fn clipping_is_found_and_a_smooth_peak_is_not() {
    let mut run = sine(1000.0, 0.01, 2.0, 2.0, 1e-6, 2.0);
    let top = 0.8 * run.force_n.iter().fold(0.0f64, |m, v| m.max(*v));
    for v in &mut run.force_n {
        *v = v.min(top);
    }
    let f = findings(&dataset(1000.0, run));
    // The run starts at a force maximum: 5 clipped tops in 4 cycles, the first at sample 0.
    let c = only(&f, FindingKind::Clipping, "force_n");
    assert_eq!((c.count, c.sample), (5, 0), "{c:?}");
    assert!(c.message.contains("largest"), "{}", c.message);
    // The quantised displacement's turning points are not clipping.
    assert!(f.iter().all(|x| x.column != "displacement_m"), "{f:#?}");
}

#[test]
fn offsets_are_information() {
    let mut run = sine(300.0, 0.025, 0.5, 8.0, 1e-5, 2.0);
    for x in &mut run.displacement_m {
        *x += 0.02;
    }
    for f in &mut run.force_n {
        *f += 60.0;
    }
    let ds = dataset(300.0, run);
    let f = findings(&ds);
    let x = only(&f, FindingKind::Offset, "displacement_m");
    assert!(x.message.contains("+20.00 mm"), "{}", x.message);
    let g = only(&f, FindingKind::Offset, "force_n");
    assert!(g.message.contains("+60."), "{}", g.message);
    assert!(f.iter().all(|x| x.kind.is_info()));
    let r = report(&ds);
    assert!(
        r.contains("no anomalies found") && r.contains("information:"),
        "{r}"
    );
}

#[test]
fn rounded_time_stamps_are_reported_as_accepted() {
    let mut run = sine(3000.0, 0.01, 5.0, 2.0, 1e-6, 2.0);
    for t in &mut run.time_s {
        *t = quantise(*t, 1e-4);
    }
    let ds = dataset(3000.0, run);
    let t = only(&findings(&ds), FindingKind::TimeStamps, "time_s");
    assert!(
        t.message
            .contains("from the fitted 3000.0 Hz grid, accepted"),
        "{}",
        t.message
    );
    assert!(report(&ds).contains("time stamps rounded/jittered: max deviation"));
}

#[test]
fn ramp_in_cycles_do_not_lower_the_amplitude() {
    // 4 ramp-in cycles, 3 steady, 4 ramp-out at 1 kHz, 1 Hz, 40 mm: most half-cycles are
    // ramps, so a plain median would under-estimate.
    let (fs, f, a) = (1000.0, 1.0, 0.04);
    let n = (11.0 * fs) as usize;
    let env = |t: f64| (t / 4.0).min(1.0).min((11.0 - t) / 4.0).max(0.0);
    let x: Vec<f64> = (0..n)
        .map(|i| {
            let t = i as f64 / fs;
            a * env(t) * (2.0 * PI * f * t).sin()
        })
        .collect();
    let v = preprocess::differentiate(&x, 1.0 / fs);
    let e = preprocess::estimate_excitation(&x, &v, fs);
    assert!((e.amplitude_m / a - 1.0).abs() < 0.03, "{e:?}");
    assert!(
        (e.peak_velocity_m_s / (a * 2.0 * PI * f) - 1.0).abs() < 0.03,
        "{e:?}"
    );
}

#[test]
fn an_exact_velocity_column_passes_at_any_frequency() {
    // Exact velocity, displacement quantised to 0.01 mm, from 0.1 Hz at 1 kHz to 20 Hz at
    // 300 Hz.
    for (fs, f, a) in [
        (1000.0, 0.1, 0.02),
        (1000.0, 0.5, 0.01),
        (300.0, 20.0, 0.002),
    ] {
        let mut run = sine(fs, a, f, 2.0 / f, 1e-5, 2.0);
        let w = 2.0 * PI * f;
        run.velocity_m_s = Some(run.time_s.iter().map(|t| a * w * (w * t).cos()).collect());
        let m = preprocess::measured_velocity_mismatch(&run, fs).expect("some");
        assert!(m < 0.02, "fs {fs} f {f}: mismatch {m}");
        // A sign error and a mm/s column are still caught.
        let v = run.velocity_m_s.take().expect("v");
        run.velocity_m_s = Some(v.iter().map(|x| -x).collect());
        let m = preprocess::measured_velocity_mismatch(&run, fs).expect("some");
        assert!(m > 1.5, "sign: {m}");
        run.velocity_m_s = Some(v.iter().map(|x| 1000.0 * x).collect());
        let m = preprocess::measured_velocity_mismatch(&run, fs).expect("some");
        assert!(m > 100.0, "mm/s: {m}");
    }
}
