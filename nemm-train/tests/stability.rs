//! Training never ends in a model the runtime refuses: data whose dynamics are faster than
//! the model's step allows train to models that `Model::check_step` accepts at that step,
//! with the stability hold reporting that it was active; a rate-independent friction damper
//! (its force follows the stroke position, not the velocity) trains every variant to a model
//! the runtime accepts, and with the priors in the state by construction (cumulative
//! scalers) both neural variants keep their most accurate epoch, audit-clean, below the
//! static map's error, where the penalty's MLPs fail the audit.
mod support;

use nemm_core::ModelKind;
use nemm_dataset::Run;
use nemm_train::config::StatePriors;
use nemm_train::data::preprocess::{self, PrepareConfig};
use nemm_train::train::eval::rmse_model;
use nemm_train::train::fit::FitConfig;
use nemm_train::train::physics::audit;
use nemm_train::train::pipeline::{train_variants, PipelineConfig};
use std::f64::consts::PI;

/// Sample rate of the friction damper's logger \[Hz\].
const FS: f64 = 1000.0;

/// A Dahl friction damper: `dF/dx = sigma (1 - F / F_c sgn(v))` with the breakaway force
/// `F_c = 2 kN (1 - 0.4 alpha)` (the condition wears the friction band) over a
/// pre-sliding stiffness `sigma = 4e7 N/m` (50 um to saturate), plus 100 N s/m of viscous
/// damping. Rate-independent: a stroke's loop is the same at every frequency.
fn friction_run(alpha: f64, amplitude_m: f64, freq_hz: f64, seconds: f64) -> Run {
    let (sigma, f_c, c) = (4e7, 2000.0 * (1.0 - 0.4 * alpha), 100.0);
    let w = 2.0 * PI * freq_hz;
    let n = (seconds * FS) as usize;
    let sub = 200;
    let h = 1.0 / (FS * sub as f64);
    let mut f = 0.0f64;
    let (mut time_s, mut displacement_m, mut force_n) = (vec![], vec![], vec![]);
    for i in 0..n {
        let t0 = i as f64 / FS;
        let v = amplitude_m * w * (w * t0).cos();
        time_s.push(t0);
        displacement_m.push(amplitude_m * (w * t0).sin());
        force_n.push(f + c * v);
        for j in 0..sub {
            let t = t0 + (j as f64 + 0.5) * h;
            let v = amplitude_m * w * (w * t).cos();
            f += h * sigma * v * (1.0 - f / f_c * v.signum());
        }
    }
    support::sine_record(
        format!("runs/a{alpha}_x{amplitude_m}_f{freq_hz}.csv"),
        alpha,
        amplitude_m,
        amplitude_m * w,
        time_s,
        displacement_m,
        force_n,
    )
}

/// Sines of 0.4 m/s peak through a Linear EMM with `b_fl = 1500`, `b_pr = 1000` N s/m,
/// `k_pr = 2.5e7` N/m (time constant 100 us) and `T_pr = 100 us`, logged at 10 kHz (the
/// truth integrated exactly over 100 sub-steps per sample).
fn fast_damper_run(alpha: f64, freq_hz: f64, seconds: f64) -> Run {
    const FS_FAST: f64 = 10_000.0;
    let (b_fl, b_pr, k) = (1500.0, 1000.0, 2.5e7);
    let w = 2.0 * PI * freq_hz;
    let amp = 0.4 / w;
    let n = (seconds * FS_FAST) as usize;
    let sub = 100;
    let h = 1.0 / (FS_FAST * sub as f64);
    let mut x_pr = 0.0f64;
    let (mut time_s, mut displacement_m, mut force_n) = (vec![], vec![], vec![]);
    for i in 0..n {
        let t0 = i as f64 / FS_FAST;
        let u = amp * w * (w * t0).cos();
        time_s.push(t0);
        displacement_m.push(amp * (w * t0).sin());
        force_n.push(b_fl * (k * x_pr + b_pr * u) / (b_pr + b_fl));
        for j in 0..sub {
            // dx_pr/dt = (b_fl u - k x_pr) / (b_pr + b_fl), exact over the sub-step for the
            // sub-step's mid velocity.
            let u = amp * w * (w * (t0 + (j as f64 + 0.5) * h)).cos();
            let x_ss = b_fl * u / k;
            x_pr = x_ss + (x_pr - x_ss) * (-h * k / (b_pr + b_fl)).exp();
        }
    }
    support::sine_record(
        format!("runs/a{alpha}_f{freq_hz}.csv"),
        alpha,
        amp,
        0.4,
        time_s,
        displacement_m,
        force_n,
    )
}

/// Trains `kinds` on `runs` at `fs` (level `test_alpha` held out) and model rate
/// `model_rate_hz`; checks that every
/// variant's model is valid and accepted at its step; returns the steps the stability hold
/// moved the constants, summed over all variants and epochs.
fn train_and_check(
    name: &str,
    fs: f64,
    runs: Vec<Run>,
    test_alpha: f64,
    model_rate_hz: f64,
    kinds: &[ModelKind],
) -> usize {
    let ds = support::dataset(name, fs, runs);
    let mut prep = PrepareConfig::default();
    prep.split.test_alphas = vec![test_alpha];
    let prepared = preprocess::prepare(&ds, &prep).expect("prepare");
    let cfg = PipelineConfig {
        hidden: 8,
        layers: 2,
        model_rate_hz,
        linear_epochs: 20,
        linear_lr: 2e-2,
        fit: FitConfig {
            epochs: 20,
            patience: 20,
            max_batches_per_epoch: Some(6),
            ..FitConfig::default()
        },
        ..PipelineConfig::default()
    };
    let trained =
        train_variants(&prepared, kinds, &cfg, None, false).expect("every variant trains");
    assert_eq!(trained.len(), kinds.len());
    let dt = (1.0 / cfg.model_rate_hz) as f32;
    let mut held = 0;
    for t in &trained {
        let m = &t.model;
        m.validate()
            .unwrap_or_else(|e| panic!("{:?}: {e}", t.variant));
        m.check_step(cfg.integrator, dt)
            .unwrap_or_else(|e| panic!("{:?} is refused at its step: {e}", t.variant));
        let h: usize = t.history.iter().map(|h| h.held).sum();
        held += h;
        eprintln!(
            "{name}: {:?}: validation RMSE {:.4}, fastest time constant {:.1} us, held {h}",
            t.variant,
            t.val_rmse,
            m.fastest_time_constant_s().unwrap_or(f32::NAN) * 1e6,
        );
    }
    held
}

const KINDS: [ModelKind; 3] = [ModelKind::LinearEmm, ModelKind::NemmLight, ModelKind::Nemm];

#[test]
fn data_faster_than_the_step_train_to_models_the_runtime_accepts() {
    let runs = [0.0, 0.15, 0.3]
        .into_iter()
        .flat_map(|a| [20.0, 50.0, 100.0].map(|f| fast_damper_run(a, f, 2.0)))
        .collect();
    // A 250 Hz model (RK4 needs time constants of at least 1.8 ms) of a 100 us damper.
    let held = train_and_check("fast damper", 10_000.0, runs, 0.15, 250.0, &KINDS);
    assert!(
        held > 0,
        "the data pull the model against the step's stability bound"
    );
}

#[test]
fn a_friction_damper_trains_to_models_the_runtime_accepts() {
    let mut runs = vec![];
    for alpha in [0.0, 0.5, 1.0] {
        for (amp, freq) in [(0.005, 1.0), (0.01, 2.0), (0.02, 0.5)] {
            runs.push(friction_run(alpha, amp, freq, 4.0));
        }
    }
    train_and_check("friction damper", FS, runs, 0.5, FS, &KINDS);
}

/// The friction damper with the priors in the state by construction and by the penalty: with
/// cumulative scalers every epoch of NEMM-Light and the NEMM passes the monotonicity audit,
/// so each keeps its most accurate epoch, and the NEMM's test error is below the static
/// map's; with the penalty's MLPs (the same budget and `lambda_ph`) the flow force falls
/// with the velocity in most epochs' audits.
#[test]
fn a_friction_damper_keeps_its_best_epoch_with_the_state_priors_by_construction() {
    let mut runs = vec![];
    for alpha in [0.0, 0.5, 1.0] {
        for (amp, freq) in [(0.005, 1.0), (0.01, 2.0), (0.02, 0.5)] {
            runs.push(friction_run(alpha, amp, freq, 4.0));
        }
    }
    let ds = support::dataset("friction damper", FS, runs);
    let mut prep = PrepareConfig::default();
    prep.split.test_alphas = vec![0.5];
    let prepared = preprocess::prepare(&ds, &prep).expect("prepare");
    let kinds = [
        ModelKind::Sem,
        ModelKind::LinearEmm,
        ModelKind::NemmLight,
        ModelKind::Nemm,
    ];
    let base = PipelineConfig {
        model_rate_hz: FS,
        fit: FitConfig {
            epochs: 16,
            patience: 16,
            max_batches_per_epoch: Some(4),
            ..FitConfig::default()
        },
        ..PipelineConfig::default()
    };
    let test_rmse = |m: &nemm_core::Model| {
        rmse_model(
            m,
            &prepared.test,
            prepared.dt_s,
            prepared.warmup_samples,
            prepared.scales.force_n,
        )
        .expect("test RMSE")
    };
    let construction = PipelineConfig {
        state_priors: StatePriors::Construction,
        ..base.clone()
    };
    let trained = train_variants(&prepared, &kinds, &construction, None, false)
        .expect("every variant trains");
    assert_eq!(trained.len(), kinds.len(), "a variant failed");
    let sem = test_rmse(&trained[0].model);
    for t in &trained[2..] {
        let history: Vec<(usize, f64, Option<usize>)> = t
            .history
            .iter()
            .map(|h| (h.epoch, h.val_rmse, h.violations))
            .collect();
        assert!(
            history.iter().all(|&(_, _, v)| v == Some(0)),
            "{:?}: an epoch failed the audit: {history:?}",
            t.variant
        );
        let best = history
            .iter()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|h| h.0);
        assert_eq!(
            t.kept_epoch, best,
            "{:?} did not keep its most accurate epoch: {history:?}",
            t.variant
        );
        assert_eq!(audit(&t.model, 401, 101).total_violations(), 0);
        let rmse = test_rmse(&t.model);
        eprintln!(
            "construction: {:?} test RMSE {rmse:.4} (SEM {sem:.4}), kept epoch {:?}",
            t.variant, t.kept_epoch
        );
        if t.variant == ModelKind::Nemm {
            assert!(rmse < sem, "NEMM {rmse:.4} is not below the SEM {sem:.4}");
        }
    }
    let penalty = train_variants(&prepared, &[ModelKind::NemmLight], &base, None, false)
        .expect("NEMM-Light trains");
    let failing = penalty[0]
        .history
        .iter()
        .filter(|h| h.violations.is_some_and(|v| v > 0))
        .count();
    eprintln!(
        "penalty: NEMM-Light: {failing} of {} epochs fail the audit, test RMSE {:.4}",
        penalty[0].history.len(),
        test_rmse(&penalty[0].model)
    );
    assert!(
        2 * failing > penalty[0].history.len(),
        "the fixture no longer fights the penalty: {failing} of {} epochs fail the audit",
        penalty[0].history.len()
    );
}
