//! The model rate is independent of the data rate (a model trained on 300 Hz or 1 kHz data
//! is a 10 kHz model), and a condition level changing within a run (the `alpha` column) is
//! used in training, evaluation and nemm-core's estimator.
//!
//! ```text
//! cargo test --release -p nemm-train --test rate -- --nocapture
//! ```
use nemm_core::ModelKind;
use nemm_core::{Estimator, EstimatorConfig, EstimatorError, EvalMode, Model, Sample, TableConfig};
use nemm_dataset::{self as dataset, Dataset, Run, RunEntry};
use nemm_train::data::preprocess::{self, PrepareConfig, Prepared, RunRole};
use nemm_train::train::eval::{predict, run_estimator, Input};
use nemm_train::train::pipeline::{train_variants, PipelineConfig, VariantInfo};
use nemm_virtual_bench::config::BenchConfig;
use nemm_virtual_bench::program::run_spec;
use nemm_virtual_bench::VirtualBench;
use std::path::PathBuf;

/// The rate of the virtual bench and of the model \[Hz\].
const FULL_RATE_HZ: f64 = 10_000.0;

/// A small virtual bench: 10 mm at 0.262 and 1.048 m/s, the three default oil-loss levels
/// (0.15 is the test level), 0.1 s ramps and 2.6 s steady (five 0.5 s windows per run).
fn small_bench() -> Dataset {
    let mut cfg = BenchConfig::default();
    cfg.program.amplitudes_m = vec![0.01];
    cfg.program.peak_velocities_m_s = vec![0.262, 1.048];
    cfg.program.max_ramp_s = 0.1;
    cfg.program.min_steady_s = 2.6;
    VirtualBench::new(cfg).generate(1, |_, _| {})
}

/// Linear interpolation of `x` (sampled at `fs_in`, starting at index 0) at time `t`.
fn at_time(x: &[f64], fs_in: f64, t: f64) -> f64 {
    let q = t * fs_in;
    let i = (q.floor() as usize).min(x.len() - 1);
    let w = q - i as f64;
    match x.get(i + 1) {
        Some(&b) if w > 0.0 => x[i] + w * (b - x[i]),
        _ => x[i],
    }
}

/// The dataset sampled at `rate_hz`: displacement and force (and a per-sample `alpha`) read
/// at the times `k / rate_hz` by linear interpolation of the 10 kHz record, without an
/// anti-alias filter (a logger without one: the force noise above the new Nyquist frequency
/// folds down). At 1 kHz this is exactly every 10th sample; at 300 Hz (33.3 samples per
/// sample) it interpolates between the two 10 kHz samples around each time.
fn resample(ds: &Dataset, rate_hz: f64) -> Dataset {
    let fs = ds.sample_rate_hz;
    let runs = ds
        .runs
        .iter()
        .map(|r| {
            let t0 = r.time_s[0];
            let span = (r.len() - 1) as f64 / fs;
            let n = (span * rate_hz).floor() as usize + 1;
            let times: Vec<f64> = (0..n).map(|k| k as f64 / rate_hz).collect();
            let read = |x: &[f64]| times.iter().map(|&t| at_time(x, fs, t)).collect();
            Run {
                entry: r.entry.clone(),
                time_s: times.iter().map(|t| t0 + t).collect(),
                displacement_m: read(&r.displacement_m),
                force_n: read(&r.force_n),
                velocity_m_s: r.velocity_m_s.as_deref().map(read),
                alpha: r.alpha.as_deref().map(read),
            }
        })
        .collect();
    Dataset {
        name: format!("{} at {rate_hz} Hz", ds.name),
        sample_rate_hz: rate_hz,
        condition: None,
        runs,
    }
}

/// The preprocessing for data at `rate_hz`: the default cut-off (150 Hz) where it is below
/// Nyquist, else 100 Hz (at 300 Hz).
fn prepare(ds: &Dataset) -> Prepared {
    let mut cfg = PrepareConfig::default();
    if ds.sample_rate_hz <= 2.0 * preprocess::DEFAULT_CUTOFF_HZ {
        cfg.signal.cutoff_hz = Some(100.0);
    }
    preprocess::prepare(ds, &cfg).expect("prepare")
}

/// Trains `variant` with a small budget at the default model rate (10 kHz) and returns the
/// model after an encode / decode round trip (the exported blob).
fn train_and_export(prepared: &Prepared, variant: ModelKind, pipeline: &PipelineConfig) -> Model {
    let trained =
        train_variants(prepared, &[variant], pipeline, None, false).expect("training succeeds");
    let model = &trained
        .iter()
        .find(|t| t.variant == variant)
        .expect("trained")
        .model;
    let blob = nemm_core::encode_to_vec(model).expect("encode");
    nemm_core::decode(&blob).expect("decode")
}

/// The Linear EMM stage trained to convergence (40 epochs without early stopping, as in
/// `training.rs`; a second per epoch here), so that the comparison between data rates is
/// not one between stopping points.
fn linear_budget() -> PipelineConfig {
    let mut cfg = PipelineConfig {
        linear_epochs: 40,
        ..PipelineConfig::default()
    };
    cfg.fit.patience = 40;
    cfg
}

/// Normalised RMSE (by `force_scale`) of nemm-core's estimator on every test run of the
/// 10 kHz `prepared` set, whole runs from rest, scored after the warm-up; the level per
/// sample when the run has one.
fn core_rmse_on_test_runs(model: &Model, ds: &Dataset, prepared: &Prepared) -> f64 {
    let (mut se, mut n) = (0.0f64, 0usize);
    for r in prepared.runs.iter().filter(|r| r.role == RunRole::Test) {
        let i = r.summary.index;
        let sig = &prepared.signals[i];
        let u: Vec<f32> = sig.velocity_m_s.iter().map(|&v| v as f32).collect();
        let alphas: Option<Vec<f32>> = sig
            .alpha
            .as_ref()
            .map(|a| a.iter().map(|&v| v as f32).collect());
        let input = Input {
            velocity_m_s: &u,
            alpha: r.summary.alpha as f32,
            alphas: alphas.as_deref(),
            position_m: None,
        };
        let mut est =
            Estimator::new(model, EstimatorConfig::new(input.alpha)).expect("estimator accepts");
        let (forces, _) = run_estimator(&mut est, f64::from(model.dt_s), &input, prepared.dt_s)
            .expect("estimator run");
        let d = est.diagnostics();
        assert_eq!(d.held_samples + d.resets, 0, "no held input, no reset");
        for (y, f) in forces
            .iter()
            .zip(&ds.runs[i].force_n)
            .skip(prepared.warmup_samples)
        {
            se += ((y - f) / prepared.scales.force_n).powi(2);
            n += 1;
        }
    }
    assert!(n > 0, "test samples");
    (se / n as f64).sqrt()
}

/// Trains the Linear EMM (converged, [`linear_budget`]) and a small NEMM-Light (H 8, L 2,
/// 5 epochs) on `prepared` and returns both exported models.
fn train_both(prepared: &Prepared) -> Vec<(ModelKind, Model)> {
    let mut cfg = linear_budget();
    cfg.hidden = 8;
    cfg.layers = 2;
    cfg.qs_steps = 200;
    cfg.fit.epochs = 5;
    let variants = [ModelKind::LinearEmm, ModelKind::NemmLight];
    let trained = train_variants(prepared, &variants, &cfg, None, false).expect("training");
    trained
        .into_iter()
        .map(|t| {
            let blob = nemm_core::encode_to_vec(&t.model).expect("encode");
            (t.variant, nemm_core::decode(&blob).expect("decode"))
        })
        .collect()
}

#[test]
fn models_trained_on_decimated_data_are_10_khz_models_close_to_the_full_rate_one() {
    let full = small_bench();
    let full_prepared = prepare(&full);
    // (rate, variant, RMSE on the 10 kHz test runs)
    let mut rmse: Vec<(f64, ModelKind, f64)> = Vec::new();
    for rate in [FULL_RATE_HZ, 1000.0, 300.0] {
        let ds = if rate == FULL_RATE_HZ {
            full.clone()
        } else {
            resample(&full, rate)
        };
        let prepared = prepare(&ds);
        for (variant, model) in train_both(&prepared) {
            // The blob carries the model step, not the data's.
            assert_eq!(model.dt_s, 1e-4_f32, "{rate} Hz data: exported step");
            let e = core_rmse_on_test_runs(&model, &full, &full_prepared);
            eprintln!(
                "{} trained on {rate} Hz data: nemm-core RMSE on the 10 kHz test runs {e:.4} \
                 ({:.1} N)",
                variant.title(),
                e * full_prepared.scales.force_n
            );
            rmse.push((rate, variant, e));
        }
    }
    // The tolerance, measured (RMSE normalised by the force scale, on the 10 kHz test runs;
    // seed 1 as run here, seeds 2 and 3 as measured when the bounds were set):
    //
    // | data    | Linear EMM (40 epochs)  | NEMM-Light (H 8, L 2, 5 epochs) |
    // |---------|-------------------------|---------------------------------|
    // | 10 kHz  | 0.1734 0.1735 0.1735    | 0.1067 0.1127 0.1149            |
    // | 1 kHz   | 0.1735 0.1735 0.1735    | 0.1076 0.1131 0.1144            |
    // | 300 Hz  | 0.1734 0.1734 0.1734    | 0.0795 0.1039 0.1138            |
    //
    // The Linear EMM's error is its structure's (a linear damper), which the data rate does
    // not move (within 0.1 %): bound 1 %. NEMM-Light's 5 short epochs differ by up to 8 %
    // between seeds at 10 kHz; with the same seed (same initial weights and window order)
    // 1 kHz data stay within 1 % of 10 kHz data: bound 5 %. 300 Hz data gave a better
    // model for every seed (1 to 25 %); the bound of 10 % states what the data rate may
    // cost at most, the rest of the gap to an untrained model (0.2) being the training's.
    for &(rate, variant, e) in rmse.iter().filter(|r| r.0 != FULL_RATE_HZ) {
        let reference = rmse
            .iter()
            .find(|r| r.0 == FULL_RATE_HZ && r.1 == variant)
            .expect("full-rate model")
            .2;
        let bound = match (variant, rate >= 1000.0) {
            (ModelKind::LinearEmm, _) => 1.01,
            (_, true) => 1.05,
            (_, false) => 1.10,
        };
        assert!(
            e <= bound * reference,
            "{} on {rate} Hz data: RMSE {e:.4} vs {reference:.4} at 10 kHz (bound x{bound})",
            variant.title()
        );
    }
}

#[test]
fn a_300_hz_dataset_exports_a_10_khz_blob_that_the_estimator_accepts() {
    let full = small_bench();
    let low = resample(&full, 300.0);
    let prepared = prepare(&low);
    assert_eq!(prepared.sample_rate_hz, 300.0);
    let mut cfg = linear_budget();
    cfg.linear_epochs = 1;
    let model = train_and_export(&prepared, ModelKind::LinearEmm, &cfg);
    assert_eq!(model.dt_s, 1e-4_f32);
    let mut est = Estimator::new(&model, EstimatorConfig::new(0.15)).expect("estimator");
    assert!(est.step(Sample::new(0.1)).unwrap().force_n.is_finite());
    // Another model rate is a choice of the trainer.
    cfg.model_rate_hz = 5000.0;
    let model = train_and_export(&prepared, ModelKind::LinearEmm, &cfg);
    assert_eq!(model.dt_s, 2e-4_f32);
}

/// Steady runs of the virtual bench (0.262 m/s, 10 mm) at each level of `levels`, with the
/// index of their first rising zero crossing after the ramp and their period in samples.
struct Steady {
    runs: Vec<(f64, Run)>,
    first_period: f64,
    period_samples: f64,
}

fn steady_runs(b: &VirtualBench, levels: &[f64]) -> Steady {
    let p = &b.config().program;
    let spec = run_spec(p, levels[0], 0.01, 0.262);
    let fs = p.sample_rate_hz;
    Steady {
        runs: levels
            .iter()
            .map(|&a| (a, b.measure(&run_spec(p, a, 0.01, 0.262), 7)))
            .collect(),
        // The stroke is A sin(omega t): rising zero crossings at whole periods.
        first_period: (spec.ramp_s * spec.frequency_hz).ceil(),
        period_samples: fs / spec.frequency_hz,
    }
}

/// One run whose condition level switches every two stroke periods, `segments` times,
/// cycling through `order` (indices into `s.runs`): pairs of steady periods of the
/// runs at each level, cut at rising zero crossings of the displacement so that the stroke
/// continues across a switch, the level in the `alpha` column. The manifest's level
/// (`label`) only assigns the run to the training or test split.
fn switching_run(s: &Steady, order: &[usize], segments: usize, label: f64, file: &str) -> Run {
    let (mut x, mut f, mut alpha) = (Vec::new(), Vec::new(), Vec::new());
    for seg in 0..segments {
        let (a, run) = &s.runs[order[seg % order.len()]];
        let pair = (seg / order.len()) as f64;
        let at = |periods: f64| (periods * s.period_samples).round() as usize;
        let start = at(s.first_period + 2.0 * pair);
        let end = at(s.first_period + 2.0 * pair + 2.0).min(run.len());
        assert!(start < end, "run too short for {segments} segments");
        x.extend_from_slice(&run.displacement_m[start..end]);
        f.extend_from_slice(&run.force_n[start..end]);
        alpha.extend(std::iter::repeat_n(*a, end - start));
    }
    Run {
        entry: RunEntry {
            file: PathBuf::from(file),
            oil_loss: label,
            amplitude_m: Some(0.01),
            target_velocity_m_s: Some(0.262),
        },
        time_s: (0..x.len()).map(|i| i as f64 / FULL_RATE_HZ).collect(),
        displacement_m: x,
        force_n: f,
        velocity_m_s: None,
        alpha: Some(alpha),
    }
}

#[test]
fn a_condition_level_changing_within_runs_is_trained_evaluated_and_run_by_the_estimator() {
    let mut cfg = BenchConfig::default();
    cfg.program.max_ramp_s = 0.1;
    cfg.program.min_steady_s = 2.0;
    let b = VirtualBench::new(cfg);
    let steady = steady_runs(&b, &[0.0, 0.3]);
    let ds = Dataset {
        name: "switching".into(),
        sample_rate_hz: FULL_RATE_HZ,
        condition: None,
        runs: vec![
            switching_run(&steady, &[0, 1], 8, 0.0, "runs/switch_a.csv"),
            switching_run(&steady, &[1, 0], 8, 0.3, "runs/switch_b.csv"),
            switching_run(&steady, &[0, 1, 1, 0], 6, 0.15, "runs/switch_test.csv"),
        ],
    };
    // The column survives the interchange format.
    let tmp = tempfile::tempdir().expect("temp dir");
    dataset::write(tmp.path(), &ds).expect("write");
    let ds = dataset::load(tmp.path()).expect("load");
    assert!(ds.runs.iter().all(|r| r.alpha.is_some()));
    let mut pc = PrepareConfig::default();
    pc.sequences.window_s = 0.3;
    let prepared = preprocess::prepare(&ds, &pc).expect("prepare");
    assert!(prepared.train.iter().all(|s| s.alphas.is_some()));
    let mut pipeline = PipelineConfig {
        hidden: 8,
        layers: 2,
        linear_epochs: 4,
        qs_steps: 200,
        ..PipelineConfig::default()
    };
    pipeline.fit.epochs = 3;
    let model = train_and_export(&prepared, ModelKind::NemmLight, &pipeline);

    // Parity: the trainer's whole-run prediction with alpha(t) and nemm-core's estimator fed
    // the level per sample (exact mode).
    let test = prepared
        .runs
        .iter()
        .find(|r| r.role == RunRole::Test)
        .expect("test run");
    let i = test.summary.index;
    let u: Vec<f32> = prepared.signals[i]
        .velocity_m_s
        .iter()
        .map(|&v| v as f32)
        .collect();
    let levels: Vec<f32> = ds.runs[i]
        .alpha
        .as_ref()
        .expect("alpha column")
        .iter()
        .map(|&a| a as f32)
        .collect();
    let input = Input {
        velocity_m_s: &u,
        alpha: test.summary.alpha as f32,
        alphas: Some(&levels),
        position_m: None,
    };
    let trainer = predict(&model, &[input], prepared.dt_s).expect("trainer prediction");
    let mut est = Estimator::new(&model, EstimatorConfig::new(levels[0])).expect("estimator");
    let core: Vec<f64> = u
        .iter()
        .zip(&levels)
        .map(|(&v, &a)| {
            f64::from(
                est.step(Sample::new(v).with_alpha(a))
                    .expect("exact mode")
                    .force_n,
            )
        })
        .collect();
    let fs = prepared.scales.force_n;
    let worst = core
        .iter()
        .zip(&trainer[0])
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
        / fs;
    // Both in f32 and causal: a level sampled at sample k applies from model step k on (the
    // 10 kHz data fall on the 10 kHz model grid exactly, `Grid::new`); what remains is the
    // rounding of the two evaluation orders.
    assert!(
        worst <= 1e-5,
        "max |nemm-core - trainer| = {worst:e} of the force scale"
    );

    // The level per sample is what the model was trained on: the test run scored with its
    // alpha(t) is more accurate than with the manifest's constant label.
    let rmse_of = |ys: &[f64]| {
        let (se, n) = ys
            .iter()
            .zip(&ds.runs[i].force_n)
            .skip(prepared.warmup_samples)
            .fold((0.0f64, 0usize), |(s, n), (y, f)| {
                (s + ((y - f) / fs).powi(2), n + 1)
            });
        (se / n as f64).sqrt()
    };
    let constant = predict(
        &model,
        &[Input {
            alphas: None,
            ..input
        }],
        prepared.dt_s,
    )
    .expect("constant level");
    let (with_t, with_label) = (rmse_of(&trainer[0]), rmse_of(&constant[0]));
    eprintln!(
        "NEMM-Light on the switching test run: RMSE {with_t:.4} with alpha(t), {with_label:.4} \
         with the constant label {}",
        test.summary.alpha
    );
    assert!(with_t < with_label, "{with_t} vs {with_label}");

    // Table mode refuses a changing level, and nothing changes.
    let table = EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1e-3)),
        ..EstimatorConfig::new(levels[0])
    };
    let mut tab = Estimator::new(&model, table).expect("table estimator");
    assert!(tab.step(Sample::new(0.1).with_alpha(levels[0])).is_ok());
    let before = tab.state();
    assert_eq!(
        tab.step(Sample::new(0.1).with_alpha(0.3))
            .map(|e| e.force_n),
        Err(EstimatorError::AlphaPerSampleInTableMode)
    );
    assert_eq!(tab.state(), before);
    assert_eq!(tab.alpha(), levels[0]);
}

#[test]
fn an_alpha_column_outside_0_1_is_refused_with_file_and_line() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path();
    std::fs::create_dir_all(dir.join("runs")).expect("runs dir");
    std::fs::write(
        dir.join("manifest.toml"),
        "name = \"d\"\nsample_rate_hz = 1000\n[[runs]]\nfile = \"runs/a.csv\"\noil_loss = 0.0\n",
    )
    .expect("manifest");
    let csv = |third: &str| {
        format!(
            "time_s,displacement_m,force_n,alpha\n0,0,0,0.2\n0.001,0,0,0.2\n0.002,0,0,{third}\n"
        )
    };
    std::fs::write(dir.join("runs/a.csv"), csv("1.2")).expect("csv");
    let err = dataset::load(dir)
        .expect_err("alpha 1.2 refused")
        .to_string();
    assert!(
        err.ends_with("runs/a.csv:4: column \"alpha\": 1.2 is outside [0, 1] (condition level)"),
        "{err}"
    );
    std::fs::write(dir.join("runs/a.csv"), csv("0.8")).expect("csv");
    let ds = dataset::load(dir).expect("valid alpha column");
    assert_eq!(ds.runs[0].alpha.as_deref(), Some(&[0.2, 0.2, 0.8][..]));
    // Writing refuses what loading refuses.
    let mut bad = ds.clone();
    if let Some(a) = bad.runs[0].alpha.as_mut() {
        a[1] = -0.1;
    }
    let err = dataset::write(dir, &bad)
        .expect_err("write refuses")
        .to_string();
    assert!(err.contains("a.csv:3: column \"alpha\": -0.1"), "{err}");
}
