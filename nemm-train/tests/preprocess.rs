//! Preprocessing (section 5.3): differentiation, excitation estimates, quasi-static points,
//! sequences, split and scales, on synthetic signals with known answers.
use nemm_dataset::{self as dataset, Dataset, Run};
use nemm_train::data::preprocess::{
    self, Direction, PrepareConfig, PreprocessError, QuasiStaticPoint, RunRole, SequenceConfig,
    SignalConfig, SplitConfig, VelocitySource,
};
use std::f64::consts::PI;
use support::{dataset as make_dataset, quantise, rms, DamperForce, Noise, SineRun};

mod support;

/// The tests' damper force ([`DamperForce::DEFAULT`]).
fn damper_force(x: f64, v: f64, alpha: f64) -> f64 {
    DamperForce::DEFAULT.at(x, v, alpha)
}

/// A sinusoidal run `x = A sin(w t + phase)` with the damper force; with `noise = (rng, sx,
/// sf)` the displacement gets `sx` and the force `sf` of normal noise, the displacement
/// quantised to 1 um.
#[allow(clippy::too_many_arguments)]
fn sine_run(
    file: &str,
    alpha: f64,
    amplitude: f64,
    freq: f64,
    phase: f64,
    n: usize,
    fs: f64,
    noise: Option<(&mut Noise, f64, f64)>,
) -> Run {
    let mut s = SineRun::new(file, alpha, amplitude, freq, fs, n);
    s.phase = phase;
    match noise {
        None => s.build(),
        Some((rng, sx, sf)) => s.build_measured(|x, f| {
            let xm = quantise(x + sx * rng.normal(), 1e-6);
            (xm, f + sf * rng.normal())
        }),
    }
}

/// Table-1-like dataset: 3 oil-loss levels x 2 amplitudes x 2 target velocities, 2 s each.
fn bench_dataset(fs: f64) -> Dataset {
    let mut rng = Noise::new(7);
    let mut runs = Vec::new();
    for alpha in [0.0, 0.15, 0.30] {
        for amplitude in [0.01, 0.05] {
            for v in [0.262, 0.524] {
                let f = v / (2.0 * PI * amplitude);
                let file = format!(
                    "runs/oil{:02}_a{:03}_v{:04}.csv",
                    (alpha * 100.0) as u32,
                    (amplitude * 1e3) as u32,
                    (v * 1e3) as u32
                );
                let n = (2.0 * fs) as usize + 123;
                let phase = rng.uniform() * 2.0 * PI;
                runs.push(sine_run(
                    &file,
                    alpha,
                    amplitude,
                    f,
                    phase,
                    n,
                    fs,
                    Some((&mut rng, 1e-6, 5.0)),
                ));
            }
        }
    }
    make_dataset("synthetic", fs, runs)
}

#[test]
fn clean_sinusoid_amplitude_frequency_and_peak_velocity_within_one_percent() {
    let fs = 10_000.0;
    let cfg = SignalConfig::default();
    // (amplitude, frequency, duration): the extremes of Table 1 and Fig. 4.
    for (i, &(a, f, dur)) in [
        (0.05, 0.2, 12.0),
        (0.05, 3.3, 2.0),
        (0.01, 0.83, 5.0),
        (0.01, 16.7, 1.0),
        (0.03, 5.56, 1.0),
    ]
    .iter()
    .enumerate()
    {
        let run = sine_run(
            "x.csv",
            0.0,
            a,
            f,
            0.1 + i as f64,
            (dur * fs) as usize,
            fs,
            None,
        );
        let (s, _) =
            preprocess::summarize_run(&run, 0, &cfg.at_rate(fs).unwrap()).expect("summary");
        let e = s.excitation;
        let v = 2.0 * PI * f * a;
        let rel = |x: f64, y: f64| (x - y).abs() / y;
        assert!(
            rel(e.amplitude_m, a) < 0.01,
            "A={a} f={f}: amplitude {}",
            e.amplitude_m
        );
        assert!(
            rel(e.peak_velocity_m_s, v) < 0.01,
            "A={a} f={f}: v {} vs {v}",
            e.peak_velocity_m_s
        );
        let fe = e.frequency_hz.expect("frequency");
        assert!(rel(fe, f) < 0.01, "A={a} f={f}: frequency {fe}");
        assert!(e.offset_m.abs() < 0.01 * a, "offset {}", e.offset_m);
        // These are far inside the 1 % bound; report them.
        eprintln!(
            "A={a} m f={f} Hz: amplitude {:+.4} %, peak velocity {:+.4} %, frequency {:+.4} %",
            (e.amplitude_m / a - 1.0) * 100.0,
            (e.peak_velocity_m_s / v - 1.0) * 100.0,
            (fe / f - 1.0) * 100.0
        );
    }
}

#[test]
fn differentiation_noise_is_reduced_by_the_filter() {
    let fs = 10_000.0;
    let dt = 1.0 / fs;
    // Slowest case of the paper (10 mm, 0.052 m/s -> 0.83 Hz) and a fast one (16.7 Hz);
    // displacement with 1 um quantisation, with and without 2 um RMS sensor noise.
    for &(a, f) in &[(0.01, 0.052 / (2.0 * PI * 0.01)), (0.01, 16.7)] {
        for sensor in [0.0, 2e-6] {
            let mut rng = Noise::new(42);
            let w = 2.0 * PI * f;
            let n = (4.0 * fs) as usize;
            let x: Vec<f64> = (0..n)
                .map(|i| {
                    quantise(
                        a * (w * i as f64 * dt + 0.3).sin() + sensor * rng.normal(),
                        1e-6,
                    )
                })
                .collect();
            let v_true: Vec<f64> = (0..n)
                .map(|i| a * w * (w * i as f64 * dt + 0.3).cos())
                .collect();
            let raw = preprocess::differentiate(&x, dt);
            let filtered = preprocess::differentiate(
                &preprocess::lowpass_zero_phase(&x, fs, preprocess::DEFAULT_CUTOFF_HZ)
                    .expect("filter"),
                dt,
            );
            let e_raw = rms(raw.iter().zip(&v_true).map(|(a, b)| a - b));
            let e_f = rms(filtered.iter().zip(&v_true).map(|(a, b)| a - b));
            // Interior (beyond 300 samples from the ends) and the worst sample at the ends.
            let m = 300;
            let e_fi = rms(filtered[m..n - m]
                .iter()
                .zip(&v_true[m..n - m])
                .map(|(a, b)| a - b));
            let e_edge = filtered[..m]
                .iter()
                .zip(&v_true[..m])
                .chain(filtered[n - m..].iter().zip(&v_true[n - m..]))
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            let peak = a * w;
            eprintln!(
                "A={a} m f={f:.2} Hz sensor noise {:.0} um + 1 um quantisation: velocity RMS error \
                 raw {e_raw:.3e} m/s ({:.2} % of peak), filtered {e_f:.3e} m/s ({:.3} %), \
                 reduction x{:.0}; filtered interior {e_fi:.3e} m/s, worst end sample {:.3} % of peak",
                sensor * 1e6,
                e_raw / peak * 100.0,
                e_f / peak * 100.0,
                e_raw / e_f,
                e_edge / peak * 100.0
            );
            assert!(
                e_f < e_raw / 10.0,
                "filter must cut the noise at least 10x: {e_raw} -> {e_f}"
            );
            assert!(
                e_f < 0.005 * peak,
                "filtered error {e_f} above 0.5 % of the peak {peak}"
            );
            // The first and last samples are less certain (one-sided data, the worst single
            // sample of one noise draw), but bounded.
            assert!(
                e_edge < 0.05 * peak,
                "end error {e_edge} above 5 % of the peak {peak}"
            );
        }
    }
}

#[test]
fn zero_phase_filter_keeps_the_band_and_cuts_the_noise_band() {
    let fs = 10_000.0;
    let n = 20_000;
    let tone = |f: f64| -> Vec<f64> {
        (0..n)
            .map(|i| (2.0 * PI * f * i as f64 / fs).sin())
            .collect()
    };
    let inside = tone(30.0);
    let out = preprocess::lowpass_zero_phase(&inside, fs, 150.0).expect("filter");
    // No phase shift and -0.16 % gain at 30 Hz, including the ends.
    let err = inside
        .iter()
        .zip(&out)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 0.003, "30 Hz tone changed by {err}");
    let hf = tone(1000.0);
    let out = preprocess::lowpass_zero_phase(&hf, fs, 150.0).expect("filter");
    let gain = rms(out[1000..n - 1000].iter().copied()) / rms(hf[1000..n - 1000].iter().copied());
    assert!(gain < 0.001, "1 kHz gain {gain}");
    assert!(matches!(
        preprocess::lowpass_zero_phase(&hf, fs, 6000.0),
        Err(PreprocessError::InvalidConfig {
            key: "cutoff_hz",
            ..
        })
    ));
}

#[test]
fn measured_velocity_column_is_used_when_present() {
    let fs = 10_000.0;
    let mut run = sine_run("x.csv", 0.0, 0.01, 5.0, 0.0, 5000, fs, None);
    // A measured velocity 2 % larger than the true one (e.g. a calibration difference).
    let measured: Vec<f64> = (0..run.len())
        .map(|i| 1.02 * 0.01 * 2.0 * PI * 5.0 * (2.0 * PI * 5.0 * i as f64 / fs).cos())
        .collect();
    run.velocity_m_s = Some(measured.clone());
    let auto = preprocess::process_run(&run, 0, fs, &SignalConfig::default()).expect("auto");
    assert!(auto.measured_velocity);
    let err = auto
        .velocity_m_s
        .iter()
        .zip(&measured)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        err < 1e-3 * 0.32,
        "auto velocity is not the measured one: {err}"
    );
    let diff_cfg = SignalConfig {
        velocity_source: VelocitySource::Differentiated,
        ..SignalConfig::default()
    };
    let d = preprocess::process_run(&run, 0, fs, &diff_cfg).expect("differentiated");
    assert!(!d.measured_velocity);
    let peak = d.velocity_m_s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        (peak / (0.01 * 2.0 * PI * 5.0) - 1.0).abs() < 0.005,
        "peak {peak}"
    );
    let mismatch = preprocess::measured_velocity_mismatch(&run, fs).expect("some");
    assert!((mismatch - 0.02).abs() < 0.002, "mismatch {mismatch}");
    run.velocity_m_s = None;
    let measured_cfg = SignalConfig {
        velocity_source: VelocitySource::Measured,
        ..SignalConfig::default()
    };
    assert!(matches!(
        preprocess::process_run(&run, 3, fs, &measured_cfg),
        Err(PreprocessError::NoMeasuredVelocity { run: 3, .. })
    ));
}

/// Largest (rebound) or smallest (compression) `damper_force` over the +-5 % window of a
/// pass, by brute force over the phase.
fn expected_window_force(a: f64, w: f64, alpha: f64, rebound: bool) -> f64 {
    let th_w = 0.05f64.asin();
    let k = 100_000;
    let vals = (0..=k).map(|j| {
        let th = -th_w + 2.0 * th_w * j as f64 / k as f64;
        // Rebound pass: x = A sin(th), v = A w cos(th); compression: mirrored.
        let (x, v) = if rebound {
            (a * th.sin(), a * w * th.cos())
        } else {
            (-a * th.sin(), -a * w * th.cos())
        };
        damper_force(x, v, alpha)
    });
    if rebound {
        vals.fold(f64::NEG_INFINITY, f64::max)
    } else {
        vals.fold(f64::INFINITY, f64::min)
    }
}

fn qs_points_of(run: &Run, fs: f64) -> Vec<QuasiStaticPoint> {
    let cfg = SignalConfig::default();
    let (s, signals) =
        preprocess::summarize_run(run, 0, &cfg.at_rate(fs).unwrap()).expect("summary");
    preprocess::quasi_static_points(0, &signals, &s.excitation, run.entry.oil_loss, 0.05)
}

#[test]
fn quasi_static_extraction_on_a_hysteretic_loop() {
    let fs = 10_000.0;
    let (a, f, alpha) = (0.01, 8.3, 0.3);
    let w = 2.0 * PI * f;
    // Exactly 5 periods starting at phase 0.3 rad: every pass through x = 0 is complete.
    let n = (5.0 * fs / f).round() as usize;
    let run = sine_run("x.csv", alpha, a, f, 0.3, n, fs, None);
    let pts = qs_points_of(&run, fs);
    assert_eq!(pts.len(), 10, "{pts:?}");
    let rebound_f = expected_window_force(a, w, alpha, true);
    let compression_f = expected_window_force(a, w, alpha, false);
    for (i, p) in pts.iter().enumerate() {
        // Phase 0.3 rad: x rises to its maximum first, so the first pass is compression.
        let rebound = i % 2 == 1;
        assert_eq!(
            p.direction,
            if rebound {
                Direction::Rebound
            } else {
                Direction::Compression
            }
        );
        let (fe, ve) = if rebound {
            (rebound_f, a * w)
        } else {
            (compression_f, -a * w)
        };
        // Against the continuous loop: the window's edge is only resolved to one sample
        // (A w dt = 52 um of the 500 um half-width here), hence 0.5 %.
        assert!(
            (p.force_n - fe).abs() < 0.005 * fe.abs(),
            "pass {i}: force {} vs {fe}",
            p.force_n
        );
        // Against the sampled loop: the extreme of the force over the same window of samples.
        let inside = |j: usize| run.displacement_m[j].abs() <= 0.05 * a;
        let (mut lo, mut hi) = (p.sample, p.sample);
        while lo > 0 && inside(lo - 1) {
            lo -= 1;
        }
        while hi + 1 < run.len() && inside(hi + 1) {
            hi += 1;
        }
        let window = &run.force_n[lo..=hi];
        let sampled = if rebound {
            window.iter().fold(f64::NEG_INFINITY, |m, &f| m.max(f))
        } else {
            window.iter().fold(f64::INFINITY, |m, &f| m.min(f))
        };
        assert!(
            (p.force_n - sampled).abs() < 0.001 * sampled.abs(),
            "pass {i}: force {} vs sampled {sampled}",
            p.force_n
        );
        assert!(
            (p.velocity_m_s - ve).abs() < 0.002 * ve.abs(),
            "pass {i}: velocity {} vs {ve}",
            p.velocity_m_s
        );
        assert_eq!(p.alpha, alpha);
        assert!((p.amplitude_m - a).abs() < 1e-4 * a);
        assert!((p.frequency_hz.expect("frequency") - f).abs() < 1e-3 * f);
        // The force extreme is inside the window.
        let x = run.displacement_m[p.sample];
        assert!(
            x.abs() <= 0.05 * a * 1.001,
            "sample {} at x = {x}",
            p.sample
        );
    }
    // The spring term puts the force extremes at the window's edge on the far side, not at
    // x = 0: the hysteresis is visible and the maximum, not the centre value, is taken.
    assert!(rebound_f > damper_force(0.0, a * w, alpha) * 1.001);
}

#[test]
fn quasi_static_extraction_is_robust_to_load_cell_noise() {
    let fs = 10_000.0;
    let (a, f, alpha) = (0.05, 1.67, 0.0);
    let w = 2.0 * PI * f;
    let n = (4.0 * fs / f).round() as usize;
    let mut rng = Noise::new(3);
    // 20 N RMS load-cell noise on ~1000 N, 2 um displacement noise + 1 um quantisation.
    let run = sine_run(
        "x.csv",
        alpha,
        a,
        f,
        0.3,
        n,
        fs,
        Some((&mut rng, 2e-6, 20.0)),
    );
    let pts = qs_points_of(&run, fs);
    assert_eq!(pts.len(), 8);
    for p in &pts {
        let rebound = p.direction == Direction::Rebound;
        let fe = expected_window_force(a, w, alpha, rebound);
        // The raw maximum would be biased by about 3 sigma = 60 N (6 %); the filtered one is not.
        assert!(
            (p.force_n - fe).abs() < 0.01 * fe.abs(),
            "{} vs {fe}",
            p.force_n
        );
    }
}

#[test]
fn sequences_tile_the_run() {
    let (warmup, scored) = (500, 5000);
    let n = 12_345;
    let v: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let f: Vec<f64> = (0..n).map(|i| -(i as f64)).collect();
    let x: Vec<f64> = (0..n).map(|i| 1e-3 * i as f64).collect();
    let seqs = preprocess::cut_sequences(4, 0.3, &v, &f, &x, None, warmup, scored);
    assert_eq!(seqs.len(), 2);
    for s in &seqs {
        assert_eq!(s.position_m.len(), s.velocity_m_s.len());
        assert_eq!(s.position_m[0], (1e-3 * s.start as f64) as f32);
    }
    let mut next_scored = warmup;
    for s in &seqs {
        assert_eq!(s.run, 4);
        assert_eq!(s.alpha, 0.3f32);
        assert_eq!(s.velocity_m_s.len(), warmup + scored);
        assert_eq!(s.force_n.len(), warmup + scored);
        // The scored part starts where the previous one ended.
        assert_eq!(s.start + warmup, next_scored);
        next_scored += scored;
        for (k, (&sv, &sf)) in s.velocity_m_s.iter().zip(&s.force_n).enumerate() {
            assert_eq!(sv, (s.start + k) as f32);
            assert_eq!(sf, -((s.start + k) as f32));
        }
    }
    assert_eq!(
        preprocess::unscored_samples(n, warmup, scored),
        n - 2 * scored
    );
    assert_eq!(
        preprocess::sequence_count(warmup + scored - 1, warmup, scored),
        0
    );
    assert_eq!(
        preprocess::sequence_count(warmup + scored, warmup, scored),
        1
    );
}

/// Checks the stretch invariants of every run of `p` (a dataset of `ds`): the stretches are
/// disjoint and ordered, every window (warm-up included) lies inside one stretch of its own
/// part, the windows of a stretch tile it, and no validation or test window shares a sample
/// with a training window.
fn assert_stretches(ds: &Dataset, p: &preprocess::Prepared) {
    use preprocess::Part;
    let (w, s) = (p.warmup_samples, p.scored_samples);
    for (i, run) in ds.runs.iter().enumerate() {
        let st = &p.runs[i].stretches;
        for pair in st.windows(2) {
            assert!(pair[0].end <= pair[1].start, "run {i}: {st:?}");
        }
        assert!(st.iter().all(|x| x.end <= run.len()));
        let mut scored_total = 0;
        for x in st {
            let set = match x.part {
                Part::Train => &p.train,
                Part::Validation => &p.validation,
                Part::Test => &p.test,
            };
            let starts: Vec<usize> = set
                .iter()
                .filter(|q| q.run == i && q.start >= x.start && q.start < x.end)
                .map(|q| q.start)
                .collect();
            let expected: Vec<usize> = (0..preprocess::sequence_count(x.end - x.start, w, s))
                .map(|k| x.start + k * s)
                .collect();
            assert_eq!(starts, expected, "run {i}, {x:?}");
            assert!(starts.iter().all(|&a| a + w + s <= x.end));
            scored_total += starts.len() * s;
        }
        let windows = |set: &[preprocess::Sequence]| -> Vec<(usize, usize)> {
            set.iter()
                .filter(|q| q.run == i)
                .map(|q| (q.start, q.start + w + s))
                .collect()
        };
        let train = windows(&p.train);
        for (a, b) in windows(&p.validation).into_iter().chain(windows(&p.test)) {
            for &(c, d) in &train {
                assert!(
                    b <= c || d <= a,
                    "run {i}: window {a}..{b} overlaps training {c}..{d}"
                );
            }
        }
        let n_windows = train.len() + windows(&p.validation).len() + windows(&p.test).len();
        assert_eq!(n_windows * s, scored_total);
        if p.runs[i].role != RunRole::Unused {
            assert_eq!(p.runs[i].unscored_samples, run.len() - scored_total);
        }
    }
}

#[test]
fn windows_stay_inside_disjoint_stretches() {
    let ds = bench_dataset(10_000.0);
    let p = preprocess::prepare(&ds, &PrepareConfig::default()).expect("prepare");
    assert_eq!((p.warmup_samples, p.scored_samples), (500, 5000));
    assert_stretches(&ds, &p);
    // Shorter windows: more of them, several per stretch, and a validation stretch per run.
    let mut cfg = PrepareConfig {
        sequences: SequenceConfig {
            window_s: 0.1,
            warmup_s: 0.02,
        },
        ..Default::default()
    };
    for seed in 0..5 {
        cfg.split.seed = seed;
        let p = preprocess::prepare(&ds, &cfg).expect("prepare");
        assert_stretches(&ds, &p);
    }
    // A test run is one test stretch over the whole run.
    let test_run = p
        .runs
        .iter()
        .find(|r| r.role == RunRole::Test)
        .expect("a test run");
    assert_eq!(test_run.stretches.len(), 1);
    assert_eq!(test_run.stretches[0].part, preprocess::Part::Test);
}

/// A validation window drawn among a run's windows (the split before stretches) shares its
/// warm-up with the scored part of the training window before it: the overlap the
/// stretches remove.
#[test]
fn interleaved_windows_would_overlap_in_time() {
    let (w, s) = (100, 1000);
    let seqs =
        preprocess::cut_sequences(0, 0.0, &[0.0; 5000], &[0.0; 5000], &[0.0; 5000], None, w, s);
    let (before, validation) = (&seqs[1], &seqs[2]);
    // The validation window's warm-up [2000, 2100) is the end of window 1's scored part.
    assert!(validation.start < before.start + w + s);
    let stretches = preprocess::run_stretches(
        5000,
        RunRole::TrainValidation,
        w,
        s,
        &SplitConfig {
            validation_fraction: 0.25,
            ..SplitConfig::default()
        },
        0,
    );
    let v: Vec<_> = stretches
        .iter()
        .filter(|x| x.part == preprocess::Part::Validation)
        .collect();
    assert_eq!(v.len(), 1, "{stretches:?}");
    assert_eq!(
        v[0].end - v[0].start,
        w + s,
        "one window of four, with its warm-up"
    );
}

#[test]
fn split_is_deterministic_and_respects_the_test_alpha() {
    let ds = bench_dataset(10_000.0);
    let cfg = PrepareConfig {
        sequences: SequenceConfig {
            window_s: 0.1,
            warmup_s: 0.02,
        },
        ..PrepareConfig::default()
    };
    let a = preprocess::prepare(&ds, &cfg).expect("prepare");
    let b = preprocess::prepare(&ds, &cfg).expect("prepare again");
    assert_eq!(a, b, "same seed, same split");
    assert!(!a.test.is_empty() && !a.validation.is_empty() && !a.train.is_empty());
    assert!(a.test.iter().all(|s| (s.alpha - 0.15).abs() < 1e-6));
    assert!(a
        .train
        .iter()
        .chain(&a.validation)
        .all(|s| (s.alpha - 0.15).abs() > 1e-3));
    assert!(a.quasi_static.test.iter().all(|p| p.alpha == 0.15));
    assert!(a
        .quasi_static
        .train
        .iter()
        .chain(&a.quasi_static.validation)
        .all(|p| p.alpha != 0.15));
    // Per training run: round(20 %) of its windows (if cut whole) are validation, consecutive
    // (one stretch, stratified per run).
    for r in &a.runs {
        match r.role {
            RunRole::TrainValidation => {
                assert_eq!(r.test_sequences, 0);
                let whole = preprocess::sequence_count(r.summary.samples, 200, 1000);
                assert_eq!(
                    r.validation_sequences,
                    (0.2f64 * whole as f64).round() as usize
                );
                assert!(r.train_sequences + r.validation_sequences + 1 >= whole);
                let mut starts: Vec<usize> = a
                    .validation
                    .iter()
                    .filter(|s| s.run == r.summary.index)
                    .map(|s| s.start)
                    .collect();
                starts.sort_unstable();
                assert!(starts.windows(2).all(|p| p[1] - p[0] == 1000), "{starts:?}");
            }
            RunRole::Test => assert_eq!(r.train_sequences + r.validation_sequences, 0),
            RunRole::Unused => panic!("no unused runs by default"),
        }
    }
    // Validation quasi-static points lie in the run's validation stretch.
    for p in &a.quasi_static.validation {
        assert!(a.runs[p.run].stretches.iter().any(
            |x| x.part == preprocess::Part::Validation && (x.start..x.end).contains(&p.sample)
        ));
    }
    // Another seed places the validation stretches elsewhere, with the same counts.
    let mut cfg2 = cfg.clone();
    cfg2.split.seed = cfg.split.seed + 1;
    let c = preprocess::prepare(&ds, &cfg2).expect("prepare another seed");
    assert_eq!(c.validation.len(), a.validation.len());
    assert_eq!(c.test, a.test);
    let key = |s: &preprocess::Sequence| (s.run, s.start);
    assert_ne!(
        a.validation.iter().map(key).collect::<Vec<_>>(),
        c.validation.iter().map(key).collect::<Vec<_>>()
    );
    // Counts match the summary.
    let sum = a.summary("synthetic");
    assert_eq!(sum.train.sequences, a.train.len());
    assert_eq!(
        (sum.train.runs, sum.validation.runs, sum.test.runs),
        (8, 8, 4)
    );
    assert_eq!(
        sum.validation.quasi_static_points,
        a.quasi_static.validation.len()
    );
}

#[test]
fn configurable_test_and_train_levels() {
    let ds = bench_dataset(10_000.0);
    let cfg = PrepareConfig {
        split: SplitConfig {
            test_alphas: vec![0.3],
            train_alphas: Some(vec![0.0]),
            validation_fraction: 0.0,
            seed: 0,
            ..SplitConfig::default()
        },
        ..PrepareConfig::default()
    };
    let p = preprocess::prepare(&ds, &cfg).expect("prepare");
    assert!(p.validation.is_empty());
    assert!(p.train.iter().all(|s| s.alpha == 0.0));
    assert!(p.test.iter().all(|s| (s.alpha - 0.3).abs() < 1e-6));
    assert_eq!(
        p.runs.iter().filter(|r| r.role == RunRole::Unused).count(),
        4
    );
    assert_eq!(p.scales.alpha, 1.0, "all-zero alpha scales by 1");
}

#[test]
fn scales_come_from_the_training_set_only() {
    let mut ds = bench_dataset(10_000.0);
    // Make the test runs (alpha 0.15) much stronger: they must not change the scales.
    for r in ds.runs.iter_mut().filter(|r| r.entry.oil_loss == 0.15) {
        r.force_n.iter_mut().for_each(|f| *f *= 10.0);
    }
    let p = preprocess::prepare(&ds, &PrepareConfig::default()).expect("prepare");
    let absmax = |seqs: &[preprocess::Sequence], f: &dyn Fn(&preprocess::Sequence) -> f64| {
        seqs.iter().map(f).fold(0.0f64, f64::max)
    };
    let fmax = |s: &preprocess::Sequence| {
        s.force_n
            .iter()
            .fold(0.0f64, |m, v| m.max(f64::from(v.abs())))
    };
    let vmax = |s: &preprocess::Sequence| {
        s.velocity_m_s
            .iter()
            .fold(0.0f64, |m, v| m.max(f64::from(v.abs())))
    };
    // The scales are the f64 abs-max of the training sequences (which hold f32 copies).
    assert_eq!(p.scales.force_n as f32 as f64, absmax(&p.train, &fmax));
    assert_eq!(p.scales.velocity_m_s as f32 as f64, absmax(&p.train, &vmax));
    assert_eq!(p.scales.alpha, 0.3);
    let from_f32 = preprocess::Scales::from_sequences(&p.train).expect("scales");
    assert!((from_f32.force_n / p.scales.force_n - 1.0).abs() < 1e-6);
    assert!(absmax(&p.test, &fmax) > 5.0 * p.scales.force_n);
    // Normalised training data is within [-1, 1] and reaches 1.
    let norm: Vec<_> = p.train.iter().map(|s| p.scales.normalise(s)).collect();
    let m = absmax(&norm, &fmax);
    assert!((m - 1.0).abs() < 1e-6, "{m}");
}

#[test]
fn two_khz_dataset_loads_and_is_handled() {
    let fs = 2_000.0;
    let ds = bench_dataset(fs);
    let dir = tempfile::tempdir().expect("temp dir");
    dataset::write(dir.path(), &ds).expect("write");
    let back = dataset::load(dir.path()).expect("load");
    assert_eq!(back.sample_rate_hz, fs);
    let p = preprocess::prepare(&back, &PrepareConfig::default()).expect("prepare");
    assert_eq!(p.dt_s, 1.0 / fs);
    assert_eq!((p.warmup_samples, p.scored_samples), (100, 1000));
    assert!(p.train.iter().all(|s| s.velocity_m_s.len() == 1100));
    for r in &p.runs {
        let e = &r.summary.excitation;
        let a = r.summary.manifest_amplitude_m.expect("amplitude");
        let v = r.summary.manifest_target_velocity_m_s.expect("velocity");
        assert!((e.amplitude_m / a - 1.0).abs() < 0.01, "{e:?}");
        assert!((e.peak_velocity_m_s / v - 1.0).abs() < 0.01, "{e:?}");
        assert!(r.quasi_static_points > 0);
    }
}

#[test]
fn invalid_configurations_are_refused() {
    let ds = bench_dataset(2_000.0);
    let bad = |f: &dyn Fn(&mut PrepareConfig)| {
        let mut c = PrepareConfig::default();
        f(&mut c);
        match preprocess::prepare(&ds, &c) {
            Err(PreprocessError::InvalidConfig { key, .. }) => key,
            other => panic!("expected a config error, got {:?}", other.map(|_| ())),
        }
    };
    assert_eq!(bad(&|c| c.signal.cutoff_hz = Some(1000.0)), "cutoff_hz");
    // A level that matches no run (a typo) would leave the test set empty or drop training
    // data: refused, naming the levels there are.
    assert_eq!(bad(&|c| c.split.test_alphas = vec![0.2]), "test_alphas");
    assert_eq!(
        bad(&|c| c.split.train_alphas = Some(vec![0.0, 0.5])),
        "train_alphas"
    );
    let mut c = PrepareConfig::default();
    c.split.test_alphas = vec![0.2];
    let msg = preprocess::prepare(&ds, &c)
        .map(|_| ())
        .expect_err("no run at 0.2")
        .to_string();
    assert_eq!(
        msg,
        "test_alphas: alpha 0.2 matches no run; the dataset's oil loss levels are alpha 0, 0.15, 0.3"
    );
    assert_eq!(
        bad(&|c| c.split.validation_fraction = 1.0),
        "validation_fraction"
    );
    assert_eq!(bad(&|c| c.sequences.window_s = 0.0), "window_s");
    assert_eq!(bad(&|c| c.sequences.warmup_s = -0.1), "warmup_s");
    assert_eq!(
        bad(&|c| c.quasi_static_window = Some(0.0)),
        "quasi_static_window"
    );
    // Sequences longer than every run: no training data, said so.
    let mut c = PrepareConfig::default();
    c.sequences.window_s = 10.0;
    assert!(matches!(
        preprocess::prepare(&ds, &c),
        Err(PreprocessError::NoTrainingData(_))
    ));
}

#[test]
fn cli_check_and_prepare() {
    let dir = tempfile::tempdir().expect("temp dir");
    dataset::write(dir.path(), &bench_dataset(10_000.0)).expect("write");
    let exe = env!("CARGO_BIN_EXE_nemm");
    let out = std::process::Command::new(exe)
        .args(["data", "check"])
        .arg(dir.path())
        .output()
        .expect("run nemm");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("12 runs at 10000 Hz"), "{stdout}");
    assert!(stdout.contains("runs/oil15_a010_v0524.csv"), "{stdout}");
    assert!(stdout.contains("no anomalies found"), "{stdout}");
    // The summary goes outside the dataset folder: a command never writes into its inputs.
    let elsewhere = tempfile::tempdir().expect("tempdir");
    let json = elsewhere.path().join("summary.json");
    let out = std::process::Command::new(exe)
        .args(["data", "prepare", "--seed", "3", "--out"])
        .arg(&json)
        .arg(dir.path())
        .output()
        .expect("run nemm");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: preprocess::PrepareSummary =
        serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("parse");
    assert_eq!(summary.config.split.seed, 3);
    assert_eq!(summary.test.runs, 4);
    assert_eq!(summary.train.runs, 8);
    // A broken dataset fails with the file and line.
    std::fs::write(
        dir.path().join("runs/oil00_a010_v0262.csv"),
        "time_s,displacement_m,force_n\n0,0,x\n",
    )
    .expect("break");
    let out = std::process::Command::new(exe)
        .args(["data", "check"])
        .arg(dir.path())
        .output()
        .expect("run nemm");
    assert!(!out.status.success());
    // The unreadable run is listed in the report, the others are checked.
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("oil00_a010_v0262.csv:2: column \"force_n\": \"x\" is not a number"),
        "{text}"
    );
    assert!(text.contains("1 of 12 runs could not be read"), "{text}");
}

#[test]
fn tiny_and_flat_runs_do_not_panic() {
    let fs = 10_000.0;
    for n in 1..12 {
        let mut run = sine_run("x.csv", 0.0, 0.01, 5.0, 0.3, n, fs, None);
        let (s, sig) =
            preprocess::summarize_run(&run, 0, &SignalConfig::default().at_rate(fs).unwrap())
                .expect("summary of a short run");
        assert_eq!(sig.velocity_m_s.len(), n);
        assert_eq!(sig.acceleration_m_s2.len(), n);
        assert!(sig.velocity_m_s.iter().all(|v| v.is_finite()), "n = {n}");
        assert_eq!(s.excitation.frequency_hz, None);
        // A flat run: no excitation, no quasi-static point.
        run.displacement_m.iter_mut().for_each(|x| *x = 0.001);
        let (s, sig) =
            preprocess::summarize_run(&run, 0, &SignalConfig::default().at_rate(fs).unwrap())
                .expect("flat");
        assert_eq!(s.excitation.amplitude_m, 0.0);
        assert!(preprocess::quasi_static_points(0, &sig, &s.excitation, 0.0, 0.05).is_empty());
    }
    // Columns of different lengths (only possible in memory) are an error.
    let mut run = sine_run("x.csv", 0.0, 0.01, 5.0, 0.3, 100, fs, None);
    run.force_n.pop();
    assert!(matches!(
        preprocess::process_run(&run, 2, fs, &SignalConfig::default()),
        Err(PreprocessError::ColumnLengths { run: 2, .. })
    ));
    // A dataset of short runs prepares to "no training data", not a panic.
    let ds = make_dataset(
        "short",
        fs,
        vec![sine_run("a.csv", 0.0, 0.01, 5.0, 0.0, 3, fs, None)],
    );
    let mut no_test_level = PrepareConfig::default();
    no_test_level.split.test_alphas.clear();
    assert!(matches!(
        preprocess::prepare(&ds, &no_test_level),
        Err(PreprocessError::NoTrainingData(_))
    ));
}

/// The error text of preparing `ds` with `cfg`.
fn prepare_error(ds: &Dataset, cfg: &PrepareConfig) -> String {
    preprocess::prepare(ds, cfg)
        .map(|_| ())
        .expect_err("the split should be refused")
        .to_string()
}

#[test]
fn split_by_run_takes_whole_runs_matched_by_a_glob() {
    let ds = bench_dataset(10_000.0);
    let mut cfg = PrepareConfig::default();
    cfg.split.test_alphas.clear();
    // A pattern on the path relative to the manifest and one on the file name.
    cfg.split.test_runs = vec!["runs/oil15_a010_*".into(), "oil30_a050_v0524.csv".into()];
    let p = preprocess::prepare(&ds, &cfg).expect("prepare");
    let test_files: Vec<String> = p
        .runs
        .iter()
        .filter(|r| r.role == RunRole::Test)
        .map(|r| r.summary.file.display().to_string())
        .collect();
    assert_eq!(
        test_files,
        [
            "runs/oil15_a010_v0262.csv",
            "runs/oil15_a010_v0524.csv",
            "runs/oil30_a050_v0524.csv"
        ]
    );
    assert!(p.test.iter().all(|s| test_files
        .iter()
        .any(|f| *f == ds.runs[s.run].entry.file.display().to_string())));
    assert!(p.train.iter().any(|s| s.run == 0));
    assert_stretches(&ds, &p);
    // Excluded runs are not used at all; exclusion wins over a test pattern.
    cfg.split.exclude_runs = vec!["*_a050_*".into()];
    let p = preprocess::prepare(&ds, &cfg).expect("prepare");
    for r in &p.runs {
        let file = r.summary.file.display().to_string();
        if file.contains("_a050_") {
            assert_eq!(r.role, RunRole::Unused, "{file}");
        }
    }
    assert_eq!(p.runs.iter().filter(|r| r.role == RunRole::Test).count(), 2);
    // A pattern that matches no run is refused, naming it and how the files are named.
    cfg.split.test_runs = vec!["oil15_*.txt".into()];
    assert_eq!(
        prepare_error(&ds, &cfg),
        "test_runs: pattern \"oil15_*.txt\" matches no run file (the files are named like \
         runs/oil00_a010_v0262.csv, runs/oil00_a010_v0524.csv, runs/oil00_a050_v0262.csv, ...)"
    );
    cfg.split.test_runs = vec!["[".into()];
    assert!(prepare_error(&ds, &cfg).starts_with("test_runs: \"[\" is not a glob pattern"));
}

#[test]
fn split_by_time_tests_the_end_of_every_run_of_a_single_level() {
    let fs = 10_000.0;
    let mut rng = Noise::new(3);
    let runs: Vec<Run> = (0..3)
        .map(|k| {
            sine_run(
                &format!("runs/r{k}.csv"),
                0.0,
                0.02,
                2.0 + k as f64,
                0.3,
                30_000,
                fs,
                Some((&mut rng, 1e-6, 5.0)),
            )
        })
        .collect();
    let ds = make_dataset("one level", fs, runs);
    let mut cfg = PrepareConfig {
        sequences: SequenceConfig {
            window_s: 0.2,
            warmup_s: 0.02,
        },
        ..Default::default()
    };
    // The true cause when every run is at the test level.
    cfg.split.test_alphas = vec![0.0];
    assert_eq!(
        prepare_error(&ds, &cfg),
        "no training data: every run is at the test level 0: nothing left to train on; use \
         --test-tail FRACTION (the end of every run is the test set) or --test-runs GLOB (some \
         runs are)"
    );
    cfg.split.test_alphas.clear();
    cfg.split.test_tail = Some(0.25);
    let p = preprocess::prepare(&ds, &cfg).expect("prepare");
    assert_stretches(&ds, &p);
    for r in &p.runs {
        assert_eq!(r.role, RunRole::TrainValidation);
        let last = r.stretches.last().expect("stretches");
        assert_eq!(last.part, preprocess::Part::Test);
        assert_eq!((last.start, last.end), (22_500, 30_000));
        // (7500 - 200) / 2000: three test windows per run.
        assert_eq!(r.test_sequences, 3);
        assert!(r.train_sequences > 0 && r.validation_sequences > 0);
    }
    assert!(p.test.iter().all(|s| s.start >= 22_500));
    assert!(p
        .train
        .iter()
        .chain(&p.validation)
        .all(|s| s.start + 2200 <= 22_500));
    // A tail so long that no training window is left: the cause and the way out.
    cfg.split.test_tail = Some(0.95);
    assert_eq!(
        prepare_error(&ds, &cfg),
        "no training data: 3 training run(s), whose longest training stretch has 1500 samples \
         (0.150 s), fewer than one window needs (warm-up 200 + window 2000 = 2200 samples, \
         0.220 s); use a shorter --window-s or --warmup-s, or a smaller --test-tail"
    );
    cfg.split.test_tail = Some(1.0);
    assert_eq!(
        prepare_error(&ds, &cfg),
        "test_tail: 1 is not a fraction of a run in (0, 1)"
    );
    // Every run excluded.
    cfg.split.test_tail = None;
    cfg.split.exclude_runs = vec!["r*.csv".into()];
    assert!(prepare_error(&ds, &cfg).starts_with(
        "no training data: no run is left for training: 0 test run(s) (test levels [], test \
         runs []) and 3 unused (excluded by [\"r*.csv\"]"
    ));
}
