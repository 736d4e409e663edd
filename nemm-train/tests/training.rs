//! End-to-end checks of the training pipeline on data whose truth is known.
mod support;

use burn::tensor::Device;
use nemm_core::ModelKind;
use nemm_core::{Body, Estimator, EstimatorConfig, InputScales, Integrator, Meta, Model, Sample};
use nemm_dataset::{Dataset, Run};
use nemm_kernels::emm::EmmConstants;
use nemm_train::data::preprocess::{self, PrepareConfig, Sequence};
use nemm_train::train::adjoint::{Grid, RolloutParams};
use nemm_train::train::fit::{fit, FitConfig, FitData};
use nemm_train::train::net::EmmNet;
use nemm_train::train::params::from_core;
use nemm_train::train::pipeline::{init_scaler, train_variants, PipelineConfig};

const FS: f64 = 10_000.0;

fn truth() -> Model {
    Model {
        integrator: Integrator::Rk4,
        dt_s: 1e-4,
        scales: InputScales {
            velocity_m_s: 1.0,
            x_pr_m: 0.01,
            alpha: 0.3,
        },
        meta: Meta {
            force_scale_n: 2000.0,
            alpha_min: 0.0,
            alpha_max: 0.3,
        },
        // Corner frequency k / (b_pr + b_fl) = 1.5e5 / 2500 = 60 1/s (9.5 Hz).
        body: Body::LinearEmm(EmmConstants {
            b_fl_ns_per_m: 1500.0,
            b_pr_ns_per_m: 1000.0,
            k_pr_n_per_m: 1.5e5,
            t_pr_s: 0.002,
        }),
        condition: Default::default(),
        alpha_branches: Default::default(),
        cumulative: Default::default(),
        provenance: Default::default(),
        static_force: None,
        lost_motion: None,
    }
}

/// Sinusoidal strokes through `model` at several frequencies and oil-loss levels, with the
/// measured velocity column (so the preprocessing uses it as is).
fn dataset_from(model: &Model, freqs: &[f64], alphas: &[f64], seconds: f64) -> Dataset {
    let mut runs = Vec::new();
    for &alpha in alphas {
        for &f in freqs {
            let amp = 0.4 / (2.0 * std::f64::consts::PI * f);
            let n = (seconds * FS) as usize;
            let w = 2.0 * std::f64::consts::PI * f;
            let time_s: Vec<f64> = (0..n).map(|i| i as f64 / FS).collect();
            let displacement_m: Vec<f64> = time_s.iter().map(|t| amp * (w * t).sin()).collect();
            let velocity: Vec<f64> = time_s.iter().map(|t| amp * w * (w * t).cos()).collect();
            let mut est =
                Estimator::new(model, EstimatorConfig::new(alpha as f32)).expect("estimator");
            let force_n: Vec<f64> = velocity
                .iter()
                .map(|&v| est.step(Sample::new(v as f32)).unwrap().force_n as f64)
                .collect();
            runs.push(Run {
                velocity_m_s: Some(velocity),
                ..support::sine_record(
                    format!("runs/a{alpha}_f{f}.csv"),
                    alpha,
                    amp,
                    0.4,
                    time_s,
                    displacement_m,
                    force_n,
                )
            });
        }
    }
    Dataset {
        name: "synthetic linear EMM".into(),
        sample_rate_hz: FS,
        condition: None,
        runs,
    }
}

/// The Linear EMM stage for 40 epochs without early stopping, with or without the
/// lost-motion element.
fn linear_emm_config(lost_motion: bool) -> PipelineConfig {
    PipelineConfig {
        linear_epochs: 40,
        lost_motion,
        fit: FitConfig {
            patience: 40,
            ..FitConfig::default()
        },
        ..PipelineConfig::default()
    }
}

#[test]
fn linear_emm_stage_recovers_known_constants() {
    let truth = truth();
    let ds = dataset_from(&truth, &[2.0, 6.0, 12.0, 25.0], &[0.0, 0.15, 0.3], 2.5);
    let prepared = preprocess::prepare(&ds, &PrepareConfig::default()).expect("prepare");
    let cfg = linear_emm_config(false);
    let trained =
        train_variants(&prepared, &[ModelKind::LinearEmm], &cfg, None, false).expect("train");
    let e = trained[0].model.emm().copied().expect("emm");
    let t = truth.emm().copied().expect("emm");
    let rel = |a: f32, b: f32| ((a - b) / b).abs();
    eprintln!(
        "recovered {e:?} (truth {t:?}), validation RMSE {}",
        trained[0].val_rmse
    );
    assert!(rel(e.b_fl_ns_per_m, t.b_fl_ns_per_m) < 0.03, "b_fl {e:?}");
    assert!(rel(e.b_pr_ns_per_m, t.b_pr_ns_per_m) < 0.10, "b_pr {e:?}");
    assert!(rel(e.k_pr_n_per_m, t.k_pr_n_per_m) < 0.10, "k_pr {e:?}");
    assert!(trained[0].val_rmse < 0.01);
}

/// A damper whose oil loss is lost motion (the truth: [`truth`] with a lost-motion element,
/// travel growing 4x faster in compression than in rebound). The Linear EMM with the element
/// reads it from levels 0 and 0.3: the held-out 0.15 error falls below 0.6 of the Linear EMM's
/// without it (which has no alpha dependence at all; observed 0.52), the learned travel
/// grows with alpha and at least 1.5x faster in compression (observed 2x in 40 epochs; the
/// truth's 4x is not reached), and the exported blob carries the element.
#[test]
fn lost_motion_is_learned_on_the_side_the_damper_loses_it() {
    let mut truth = truth();
    truth.lost_motion = Some(nemm_core::LostMotion {
        f0_n: 400.0,
        travel_c_m: 0.5e-3,
        travel_c_per_alpha_m: 20e-3,
        travel_r_m: 0.5e-3,
        travel_r_per_alpha_m: 5e-3,
    });
    let ds = dataset_from(&truth, &[2.0, 6.0, 12.0, 25.0], &[0.0, 0.15, 0.3], 2.5);
    let prepared = preprocess::prepare(&ds, &PrepareConfig::default()).expect("prepare");
    assert!(!prepared.test.is_empty(), "0.15 held out");
    let train = |lost_motion: bool| {
        let cfg = linear_emm_config(lost_motion);
        let trained =
            train_variants(&prepared, &[ModelKind::LinearEmm], &cfg, None, false).expect("train");
        let blob = nemm_core::encode_to_vec(&trained[0].model).expect("encode");
        nemm_core::decode::<{ nemm_core::DEFAULT_PARAM_CAPACITY }>(&blob).expect("decode")
    };
    let fs = prepared.scales.force_n;
    let test_rmse = |m: &Model| {
        nemm_train::train::eval::rmse_model(
            m,
            &prepared.test,
            prepared.dt_s,
            prepared.warmup_samples,
            fs,
        )
        .expect("evaluation")
    };
    let (without, with) = (train(false), train(true));
    let (e0, e1) = (test_rmse(&without), test_rmse(&with));
    let l = with.lost_motion.expect("the element is exported");
    eprintln!("held-out RMSE {e0:.4} without, {e1:.4} with the element; learned {l:?}");
    assert!(without.lost_motion.is_none());
    assert!(e1 < 0.6 * e0, "{e1} vs {e0}");
    assert!(
        l.travel_c_per_alpha_m > 1.5 * l.travel_r_per_alpha_m,
        "compression side: {l:?}"
    );
    let (a0, a3) = (l.at(0.0), l.at(0.3));
    assert!(a3.travel_c_m > 2.0 * a0.travel_c_m, "{l:?}");
}

fn small_windows() -> (Vec<Sequence>, Vec<Sequence>) {
    let ds = dataset_from(&truth(), &[5.0, 15.0], &[0.0, 0.3], 1.2);
    let mut cfg = PrepareConfig::default();
    cfg.split.test_alphas.clear(); // training and validation only
    cfg.sequences.window_s = 0.1;
    cfg.sequences.warmup_s = 0.02;
    let p = preprocess::prepare(&ds, &cfg).expect("prepare");
    (p.train, p.validation)
}

/// The fit inputs of [`small_windows`] (warm-up 200 samples, force scale of [`truth`]).
fn small_fit_data<'a>(train: &'a [Sequence], val: &'a [Sequence]) -> FitData<'a> {
    FitData {
        train,
        validation: val,
        warmup: 200,
        force_scale_n: 2000.0,
        grid: Grid::SAME,
    }
}

fn light_net(device: &Device) -> (EmmNet, nemm_train::train::net::NetFrame) {
    light_net_seeded(device, 3)
}

/// [`light_net`] with the initial `b_fl` weights drawn from `seed`.
fn light_net_seeded(device: &Device, seed: u64) -> (EmmNet, nemm_train::train::net::NetFrame) {
    let mut p: RolloutParams<f32> = from_core(&truth()).expect("emm");
    p.b_fl = Some(init_scaler(2, 8, 2, (0.1, 10.0), seed));
    EmmNet::from_rollout(&p, None, device)
}

fn flat(net: &EmmNet, frame: &nemm_train::train::net::NetFrame) -> Vec<f32> {
    let p = net.to_rollout(frame);
    let mut v = vec![p.b_fl0, p.b_pr0, p.k0, p.t_pr];
    v.extend(p.b_fl.map(|s| s.w).unwrap_or_default());
    v
}

#[test]
fn resume_after_a_kill_continues_exactly() {
    let device = Device::flex().autodiff();
    let (train, val) = small_windows();
    let data = small_fit_data(&train, &val);
    let cfg = FitConfig {
        label: "nemm-light".into(),
        epochs: 3,
        batch: 4,
        patience: 10,
        ..FitConfig::default()
    };
    // Straight three epochs.
    let (net, frame) = light_net(&device);
    let straight = fit(net, &frame, data, &cfg, None, false, &device).expect("fit");
    // The same run stopped after two epochs (as if killed after the second checkpoint),
    // then resumed.
    let dir = std::env::temp_dir().join(format!("nemm-resume-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (net, frame) = light_net(&device);
    let two = FitConfig {
        session_epochs: Some(2),
        ..cfg.clone()
    };
    let first = fit(net, &frame, data, &two, Some(&dir), false, &device).expect("fit 2");
    assert_eq!(first.history.len(), 2);
    assert_eq!(
        std::fs::read_to_string(dir.join("latest"))
            .expect("latest")
            .trim(),
        "epoch-0002"
    );
    let (net, frame) = light_net(&device);
    let resumed = fit(net, &frame, data, &cfg, Some(&dir), true, &device).expect("resume");
    let losses = |h: &[nemm_train::train::history::EpochStats]| -> Vec<(f64, f64, Option<usize>)> {
        h.iter()
            .map(|e| (e.train_mse, e.val_rmse, e.violations))
            .collect()
    };
    assert_eq!(resumed.history.len(), 3);
    assert_eq!(
        losses(&resumed.history),
        losses(&straight.history),
        "same losses per epoch"
    );
    assert_eq!(
        flat(&resumed.best, &frame),
        flat(&straight.best, &frame),
        "same parameters"
    );
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

#[test]
fn kept_model_is_the_most_accurate_epoch_that_passes_the_audit() {
    let device = Device::flex().autodiff();
    let (train, val) = small_windows();
    let data = small_fit_data(&train, &val);
    // With a physics weight every epoch is audited ...
    let cfg = FitConfig {
        label: "nemm-light".into(),
        epochs: 10,
        batch: 4,
        patience: 20,
        lambda_ph: 50.0,
        balance: nemm_train::config::Balance::Windows,
        ..FitConfig::default()
    };
    // Initial weights of seed 16: epoch 3 is the only clean one, and the inconsistent epochs
    // 1 and 4-10 are more accurate.
    let (net, frame) = light_net_seeded(&device, 16);
    let r = fit(net, &frame, data, &cfg, None, false, &device).expect("fit");
    assert_eq!(r.history.len(), 10);
    assert!(r.history.iter().all(|e| e.violations.is_some()));
    let clean: Vec<_> = r
        .history
        .iter()
        .filter(|e| e.violations == Some(0))
        .collect();
    // The scenario (seeded) reaches clean epochs, and an inconsistent epoch is more accurate
    // than some clean one.
    assert!(!clean.is_empty(), "the scenario must reach clean epochs");
    assert!(r
        .history
        .iter()
        .any(|e| e.violations != Some(0) && clean.iter().any(|c| e.val_rmse < c.val_rmse)));
    if r.best_epoch > 0 {
        let kept = &r.history[r.best_epoch - 1];
        assert_eq!(kept.val_rmse, r.best_val_rmse);
        if !clean.is_empty() {
            // ... and the kept one passes it and is the most accurate of those that pass.
            assert_eq!(kept.violations, Some(0), "kept epoch {}", r.best_epoch);
            let best_clean = clean
                .iter()
                .map(|e| e.val_rmse)
                .fold(f64::INFINITY, f64::min);
            assert_eq!(kept.val_rmse, best_clean);
        }
    } else {
        // The starting model kept: no clean epoch beat it.
        assert!(clean.iter().all(|e| e.val_rmse >= r.best_val_rmse));
    }
    // What the selection gave up is reported: the most accurate audited model when it fails
    // the audit and beats the kept one (here the kept epoch is the most accurate of all).
    let most_accurate = r
        .history
        .iter()
        .min_by(|a, b| a.val_rmse.total_cmp(&b.val_rmse))
        .expect("epochs");
    match r.passed_over {
        Some(p) if p.epoch > 0 => {
            assert_eq!(p.epoch, most_accurate.epoch);
            assert_eq!(most_accurate.violations, Some(p.violations));
            assert!(p.val_rmse < r.best_val_rmse && p.violations > 0);
        }
        Some(p) => assert!(p.val_rmse <= most_accurate.val_rmse && p.violations > 0),
        None => assert!(
            most_accurate.violations == Some(0) || most_accurate.val_rmse >= r.best_val_rmse
        ),
    }
    // Stopped after epoch 3 (same schedule), the same run keeps clean epoch 3 over the more
    // accurate starting model (epoch 0, with violations) and says so.
    let short = FitConfig {
        session_epochs: Some(3),
        ..cfg.clone()
    };
    let (net, frame3) = light_net_seeded(&device, 16);
    let r3 = fit(net, &frame3, data, &short, None, false, &device).expect("fit");
    assert_eq!(r3.best_epoch, 3, "{:?}", r3.history);
    let p = r3.passed_over.expect("the starting model was passed over");
    assert_eq!(p.epoch, 0);
    assert!(p.violations > 0);
    assert!(p.val_rmse < r3.best_val_rmse);
    // The kept model's own audit agrees with the epoch line.
    let model = nemm_train::train::params::to_core(&r.best.to_rollout(&frame), truth().meta)
        .expect("model");
    let audit = nemm_train::train::physics::audit(&model, 401, 101).total_violations();
    if r.best_epoch > 0 {
        assert_eq!(Some(audit), r.history[r.best_epoch - 1].violations);
    }
    // Without a physics weight nothing is audited (the paper's lambda_ph = 0 ablation).
    let no_ph = FitConfig {
        epochs: 1,
        lambda_ph: 0.0,
        ..cfg.clone()
    };
    let (net, frame) = light_net(&device);
    let r0 = fit(net, &frame, data, &no_ph, None, false, &device).expect("fit");
    assert!(r0.history.iter().all(|e| e.violations.is_none()));
    assert_eq!(r0.passed_over, None);
}

#[test]
fn nan_loss_stops_with_a_clear_error_and_keeps_the_checkpoint() {
    let device = Device::flex().autodiff();
    let (train, val) = small_windows();
    let dir = std::env::temp_dir().join(format!("nemm-nan-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cfg = FitConfig {
        label: "nemm-light".into(),
        epochs: 1,
        batch: 4,
        ..FitConfig::default()
    };
    let data = small_fit_data(&train, &val);
    let (net, frame) = light_net(&device);
    fit(net, &frame, data, &cfg, Some(&dir), false, &device).expect("first epoch");
    let mut bad = train.clone();
    for s in &mut bad {
        s.force_n[300] = f32::NAN;
    }
    let data_bad = FitData {
        train: &bad,
        ..data
    };
    let (net, frame) = light_net(&device);
    let err = fit(
        net,
        &frame,
        data_bad,
        &FitConfig { epochs: 2, ..cfg },
        Some(&dir),
        true,
        &device,
    )
    .expect_err("NaN must stop training");
    let msg = format!("{err:#}");
    assert!(
        msg.contains("NaN") && msg.contains("last good checkpoint"),
        "{msg}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("latest"))
            .expect("latest")
            .trim(),
        "epoch-0001"
    );
    std::fs::remove_dir_all(&dir).expect("cleanup");
}

/// A `b_fl` with an alpha branch, trained without any physics penalty, is monotone in
/// alpha after every epoch (the construction), while the same scaler without the branch
/// is free to break the prior.
#[test]
fn alpha_branch_keeps_the_trained_model_clean_in_alpha_without_a_penalty() {
    use nemm_core::Direction;
    use nemm_train::train::physics::{audit, AUDIT_GRID};
    use nemm_train::train::pipeline::with_branch;
    let device = Device::flex().autodiff();
    let (train, val) = small_windows();
    let data = small_fit_data(&train, &val);
    let cfg = FitConfig {
        label: "nemm-light".into(),
        epochs: 4,
        batch: 4,
        patience: 20,
        lambda_ph: 0.0,
        ..FitConfig::default()
    };
    let mut p: RolloutParams<f32> = from_core(&truth()).expect("emm");
    p.b_fl = Some(with_branch(
        init_scaler(2, 8, 2, (0.1, 10.0), 16),
        Direction::Decreasing,
        1,
        8,
        17,
    ));
    let (net, frame) = EmmNet::from_rollout(&p, None, &device);
    let r = fit(net, &frame, data, &cfg, None, false, &device).expect("fit");
    let trained = r.best.to_rollout(&frame);
    let model = nemm_train::train::params::to_core(&trained, truth().meta).expect("valid model");
    assert!(model.alpha_branches.b_fl.is_some());
    // The branch was trained (not left at its initial values).
    assert_ne!(
        trained.b_fl.as_ref().map(|s| s.branch_w().to_vec()),
        p.b_fl.as_ref().map(|s| s.branch_w().to_vec())
    );
    let a = audit(&model, AUDIT_GRID.0, AUDIT_GRID.1);
    let b_fl = a.b_fl.expect("audited");
    assert!(b_fl.alpha.checked > 0);
    assert_eq!(b_fl.alpha.violations, 0, "{a:?}");
}

/// A damper other than the default bench's: wider bore and rod, a 6 bar gas charge, softer
/// rebound and compression valves, other foaming and separation, more seal friction and
/// load-cell noise; 10 and 30 mm at three velocities, levels 0, 0.15 (test) and 0.3, short
/// ramps.
fn other_damper() -> nemm_dataset::Dataset {
    use nemm_virtual_bench::config::BenchConfig;
    use nemm_virtual_bench::VirtualBench;
    let mut cfg = BenchConfig {
        name: "another damper".into(),
        ..BenchConfig::default()
    };
    cfg.geometry.piston_diameter_m = 0.036;
    cfg.geometry.rod_diameter_m = 0.022;
    cfg.gas.charge_pressure_pa = 6.0e5;
    cfg.aeration.intake_gas_linear = 0.35;
    cfg.aeration.intake_gas_quadratic = 0.6;
    cfg.aeration.separation_time_s = 4.0;
    cfg.piston.rebound_valve.preload_dp_pa = 7.0e5;
    cfg.base.compression_valve.preload_dp_pa = 4.5e5;
    cfg.friction.coulomb_n = 25.0;
    cfg.sensors.force_noise_std_n = 4.0;
    cfg.program.amplitudes_m = vec![0.03, 0.01];
    cfg.program.peak_velocities_m_s = vec![0.131, 0.524, 1.048];
    cfg.program.max_ramp_s = 0.2;
    cfg.program.min_steady_s = 2.1;
    VirtualBench::new(cfg).generate(7, |_, _| {})
}

/// On data the defaults were not tuned on, each rollout stage keeps a model better than the
/// one it started from (a stage whose epochs all made the validation error worse would keep
/// its start: `kept_epoch == Some(0)`), and the neural variants beat the Linear EMM.
#[test]
fn every_stage_improves_on_its_start_on_another_damper() {
    let ds = other_damper();
    let mut pc = PrepareConfig::default();
    pc.split.test_alphas = vec![0.15];
    let prepared = preprocess::prepare(&ds, &pc).expect("prepare");
    let mut cfg = PipelineConfig {
        linear_epochs: 8,
        ..PipelineConfig::default()
    };
    cfg.fit.epochs = 10;
    let trained = train_variants(
        &prepared,
        &[ModelKind::LinearEmm, ModelKind::NemmLight, ModelKind::Nemm],
        &cfg,
        None,
        false,
    )
    .expect("training");
    let linear = trained
        .iter()
        .find(|t| t.variant == ModelKind::LinearEmm)
        .expect("linear");
    for t in &trained {
        let kept = t.kept_epoch.expect("a rollout stage");
        eprintln!(
            "{:?}: kept epoch {kept}, validation RMSE {:.4}",
            t.variant, t.val_rmse
        );
        assert!(kept > 0, "{:?} kept its starting model", t.variant);
        if t.variant != ModelKind::LinearEmm {
            assert!(
                t.val_rmse < 0.8 * linear.val_rmse,
                "{:?}: validation RMSE {} against the Linear EMM's {}",
                t.variant,
                t.val_rmse,
                linear.val_rmse
            );
        }
    }
}
