//! Checks of the rollout against nemm-core and of the adjoint against finite differences.
use super::adjoint::{
    loss_and_grad, loss_and_grad_paired, simulate, Grid, Pairing, RolloutGrads, RolloutParams,
    Window,
};
use super::adjoint::{Real, ScalerWeights, StaticParams};
use super::params::from_core;
use nemm_core::testing::example_model;
use nemm_core::{Estimator, EstimatorConfig, Integrator, Model, ModelKind, Sample};

fn model(kind: ModelKind, h: u8, l: u8) -> Model {
    example_model(kind, h, l).expect("example model")
}

/// The example model of `kind` (H = 16, L = 5), or with `branches` the [`branched`] NEMM,
/// with the example static force if `stat`.
fn example_16x5(kind: ModelKind, branches: bool, stat: bool) -> Model {
    let m = if branches {
        branched(16, 5, 16)
    } else {
        model(kind, 16, 5)
    };
    if stat {
        with_static(m)
    } else {
        m
    }
}

/// The example model with the example static force.
fn with_static(mut m: Model) -> Model {
    m.static_force = Some(nemm_core::testing::EXAMPLE_STATIC_FORCE);
    m
}

/// A stroke position around 30 mm (the example static force's `x_ref`) \[m\].
fn position(n: usize, dt: f64, f1: f64, phase: f64) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let t = i as f64 * dt;
            (0.03 + 0.02 * (2.0 * std::f64::consts::PI * f1 * t + phase).sin()) as f32
        })
        .collect()
}

/// A bench-like velocity signal: sum of two sinusoids.
fn signal(n: usize, dt: f64, a: f64, f1: f64, phase: f64) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let t = i as f64 * dt;
            (a * (2.0 * std::f64::consts::PI * f1 * t + phase).sin()
                + 0.3 * a * (2.0 * std::f64::consts::PI * 3.7 * f1 * t).cos()) as f32
        })
        .collect()
}

#[test]
fn rollout_matches_core_estimator() {
    for (kind, with_branches) in [
        (ModelKind::LinearEmm, false),
        (ModelKind::NemmLight, false),
        (ModelKind::Nemm, false),
        (ModelKind::Nemm, true),
    ] {
        for integ in [Integrator::Rk4, Integrator::Rk3] {
            for stat in [false, true] {
                let mut m = example_16x5(kind, with_branches, stat);
                m.integrator = integ;
                let p: RolloutParams<f32> = from_core(&m).expect("emm model");
                let n = 20_000;
                let u = signal(n, 1e-4, 0.8, 8.3, 0.3);
                let x = position(n, 1e-4, 8.3, 0.3);
                let f = vec![0.0f32; n];
                let ys = simulate(
                    &p,
                    &[Window {
                        u: &u,
                        f: &f,
                        alpha: 0.15,
                        alphas: None,
                        x: Some(&x),
                    }],
                    &Grid::SAME,
                );
                let mut est = Estimator::new(&m, EstimatorConfig::new(0.15)).expect("estimator");
                let mut worst = 0.0f64;
                for (i, &ui) in u.iter().enumerate() {
                    let e = est.step(Sample::new(ui).with_position(x[i])).unwrap();
                    worst = worst.max((e.force_n as f64 - ys[0][i]).abs());
                }
                let rel = worst / m.meta.force_scale_n as f64;
                assert!(
                    rel < 1e-5,
                    "{kind:?} {integ:?} branches {with_branches} static {stat}: max |diff| = \
                     {worst} N ({rel:e} of force scale)"
                );
            }
        }
    }
}

/// All gradient components flattened, in a fixed order, with names.
fn flat(g: &RolloutGrads<f64>) -> Vec<(String, f64)> {
    let mut v = vec![
        ("b_fl0".to_string(), g.b_fl0),
        ("b_pr0".to_string(), g.b_pr0),
        ("k0".to_string(), g.k0),
        ("t_pr".to_string(), g.t_pr),
    ];
    for (name, w) in [
        ("b_fl", &g.b_fl),
        ("b_pr", &g.b_pr),
        ("k_pr", &g.k_pr),
        ("static", &g.static_force),
        ("lost_motion", &g.lost_motion),
    ] {
        v.extend(
            w.iter()
                .enumerate()
                .map(|(i, &x)| (format!("{name}[{i}]"), x)),
        );
    }
    v
}

/// Applies `f` to parameter number `idx` in the order of [`flat`].
fn perturb(p: &RolloutParams<f64>, idx: usize, delta: f64) -> (RolloutParams<f64>, f64) {
    let mut q = p.clone();
    let h;
    {
        let consts = [&mut q.b_fl0, &mut q.b_pr0, &mut q.k0, &mut q.t_pr];
        if idx < 4 {
            h = delta * consts[idx].abs();
            *consts[idx] += h;
            return (q, h);
        }
    }
    let mut i = idx - 4;
    let mut done = false;
    for s in [&mut q.b_fl, &mut q.b_pr, &mut q.k_pr]
        .into_iter()
        .flatten()
    {
        if i < s.w.len() {
            s.w[i] += delta;
            done = true;
            break;
        }
        i -= s.w.len();
    }
    if done {
        return (q, delta);
    }
    if let Some(sf) = q.static_force.as_mut() {
        if i < sf.theta.len() {
            let h = delta * sf.theta[i].abs().max(1.0);
            sf.theta[i] += h;
            return (q, h);
        }
        i -= sf.theta.len();
    }
    if let Some(l) = q.lost_motion.as_mut() {
        let h = delta * l[i].abs();
        l[i] += h;
        return (q, h);
    }
    (q, delta)
}

/// Per window of [`windows_for_test`], a stroke position \[m\].
fn positions_for_test(n: usize) -> Vec<Vec<f32>> {
    (0..10)
        .map(|w| position(n, 5e-4, 20.0 + 3.0 * w as f64, 0.4 * w as f64))
        .collect()
}

fn windows_for_test(n: usize) -> (Vec<Vec<f32>>, Vec<Vec<f32>>, Vec<f32>) {
    // Ten windows (two packs, the second padded) with different inputs, targets and alphas.
    let mut us = Vec::new();
    let mut fs = Vec::new();
    let mut alphas = Vec::new();
    for w in 0..10 {
        us.push(signal(
            n,
            5e-4,
            0.3 + 0.1 * w as f64,
            20.0 + 3.0 * w as f64,
            0.4 * w as f64,
        ));
        fs.push(signal(n, 5e-4, 800.0, 11.0 + w as f64, 1.0));
        alphas.push([0.0f32, 0.15, 0.3][w % 3]);
    }
    (us, fs, alphas)
}

fn check_fd(kind: ModelKind, integ: Integrator) {
    check_fd_on(kind, integ, 1.0, false, false);
}

/// Per-sample condition levels of window `w`: a switch and a ramp (so that the level changes
/// between model steps in both ways) between distinct levels per window.
fn alpha_steps(w: usize, n: usize) -> Vec<f32> {
    let (a, b) = ([0.0f32, 0.15, 0.3][w % 3], [0.3f32, 0.0, 0.2][w % 3]);
    (0..n)
        .map(|i| {
            if i < n / 3 {
                a
            } else if i < n / 2 {
                b
            } else {
                let t = (i - n / 2) as f32 / (n - n / 2) as f32;
                b + (a - b) * t
            }
        })
        .collect()
}

/// The adjoint against central differences with the data sampled `ratio` model steps apart
/// (`Grid`), with `varying` a condition level changing within every window, and with
/// `stat` the example static force fed with a stroke position.
fn check_fd_on(kind: ModelKind, integ: Integrator, ratio: f64, varying: bool, stat: bool) {
    let mut m = model(kind, 4, 2);
    if stat {
        m = with_static(m);
    }
    m.integrator = integ;
    check_fd_model(&m, &format!("{kind:?}"), ratio, varying);
}

/// The example NEMM with alpha branches of `units` units on every coefficient (`b_pr`
/// increasing, the others decreasing).
fn branched(h: u8, l: u8, units: u8) -> Model {
    use nemm_core::{Direction, Priors};
    nemm_core::testing::example_model_with_branches(
        h,
        l,
        units,
        Priors {
            b_fl: Direction::Decreasing,
            b_pr: Direction::Increasing,
            k_pr: Direction::Decreasing,
        },
    )
    .expect("branched example model")
}

/// [`check_fd_on`] for a given model (its integrator; the step set to 5e-4 s).
fn check_fd_model(m: &Model, label: &str, ratio: f64, varying: bool) {
    check_fd_paired(m, label, ratio, varying, None);
}

/// [`check_fd_model`] of the loss with the matched-difference term of `pairing` (mutual
/// partners among the ten test windows, weight).
fn check_fd_paired(
    m: &Model,
    label: &str,
    ratio: f64,
    varying: bool,
    pairing: Option<(&[Option<usize>], f64)>,
) {
    let pairing = pairing.map(|(partner, weight)| Pairing { partner, weight });
    let loss_grad = |p: &RolloutParams<f64>, wins: &[Window<'_>], grid: &Grid, warmup, fs| {
        let (parts, g) = loss_and_grad_paired(p, wins, pairing, grid, warmup, fs);
        if pairing.is_some() {
            assert!(parts.diff > 0.0, "the pairs add nothing to the loss");
        }
        (parts.total(), g)
    };
    let mut m = m.clone();
    let integ = m.integrator;
    let stat = m.static_force.is_some();
    // A longer step (still stable) so that 60 steps move the states well away from rest.
    m.dt_s = 5e-4;
    let p: RolloutParams<f64> = from_core(&m).expect("emm model");
    let grid = Grid::new(f64::from(m.dt_s), ratio * f64::from(m.dt_s));
    let n = (60.0 / ratio).ceil() as usize;
    let warmup = (7.0 / ratio).ceil() as usize;
    let (us, fs, alphas) = windows_for_test(n);
    let levels: Vec<Vec<f32>> = (0..us.len()).map(|w| alpha_steps(w, n)).collect();
    let xs = positions_for_test(n);
    let wins: Vec<Window<'_>> = (0..us.len())
        .map(|i| Window {
            u: &us[i],
            f: &fs[i],
            alpha: alphas[i],
            alphas: varying.then_some(levels[i].as_slice()),
            x: stat.then_some(xs[i].as_slice()),
        })
        .collect();
    let fs_scale = 1500.0;
    let (_, g) = loss_grad(&p, &wins, &grid, warmup, fs_scale);
    let g = flat(&g);
    let gmax = g.iter().fold(0.0f64, |a, (_, x)| a.max(x.abs()));
    let mut worst = 0.0f64;
    for (idx, (name, gi)) in g.iter().enumerate() {
        // Central differences. The step trades truncation error and LeakyReLU kinks (large h)
        // against rounding noise of the loss (small h); 1e-6 keeps both below 1e-5 relative
        // except for components near the floor.
        let central = |d: f64| {
            let (pp, h) = perturb(&p, idx, d);
            let (pm, _) = perturb(&p, idx, -d);
            let (lp, _) = loss_grad(&pp, &wins, &grid, warmup, fs_scale);
            let (lm, _) = loss_grad(&pm, &wins, &grid, warmup, fs_scale);
            (lp - lm) / (2.0 * h)
        };
        // Relative to the component, floored at 1e-6 of the largest component (absolute
        // noise of the difference quotient). A component far below the largest one drowns in
        // the loss's rounding noise at step 1e-6 (a per-step level makes many of them); the
        // smooth loss then gives the derivative at the larger steps 1e-4 and 1e-3. A kink
        // (LeakyReLU input crossing zero at some step) within 1e-6 of the point spoils the
        // larger steps alike; the steps 1e-7 and 1e-8 then still see the one-sided
        // derivatives (with many per-sample levels and a branch, kinks come within 1e-7:
        // the forward and backward quotients at 1e-7 then differ by a few per cent).
        let mut err = f64::INFINITY;
        let mut fd = 0.0;
        for d in [1e-6, 1e-7, 1e-8, 1e-4, 1e-3] {
            fd = central(d);
            err = err.min((gi - fd).abs() / fd.abs().max(1e-6 * gmax));
            if err < 1e-4 {
                break;
            }
        }
        worst = worst.max(err);
        assert!(
            err < 1e-4,
            "{label} {integ:?} ratio {ratio} varying alpha {varying} static {stat} {name}: \
             adjoint {gi:e}, finite difference {fd:e}"
        );
    }
    eprintln!(
        "{label} {integ:?} ratio {ratio} varying alpha {varying} static {stat}: worst \
         relative error vs central differences {worst:e}"
    );
}

#[test]
fn adjoint_is_exact_on_a_coarser_data_grid() {
    // A non-integer ratio: the loss interpolates the model output between steps.
    check_fd_on(ModelKind::Nemm, Integrator::Rk4, 3.3, false, false);
    // An integer ratio: the samples fall on model steps.
    check_fd_on(ModelKind::NemmLight, Integrator::Rk4, 4.0, false, false);
}

#[test]
fn adjoint_is_exact_with_the_matched_difference_term() {
    // Pairs in the first pack (0-3, 1-2) and in the padded second one (8-9); 4-7 alone.
    let mut partner = vec![None; 10];
    for (a, b) in [(0, 3), (1, 2), (8, 9)] {
        partner[a] = Some(b);
        partner[b] = Some(a);
    }
    let m = branched(5, 3, 4);
    check_fd_paired(
        &m,
        "branched NEMM, paired",
        1.0,
        false,
        Some((&partner, 2.0)),
    );
    check_fd_paired(
        &m,
        "branched NEMM, paired",
        3.3,
        false,
        Some((&partner, 0.5)),
    );
}

#[test]
fn the_difference_term_is_the_error_of_the_model_difference() {
    // Two windows with the same target error add nothing; the MSE part is eq. 23's.
    let m = branched(5, 3, 4);
    let p: RolloutParams<f64> = from_core(&m).expect("emm model");
    let (us, _, _) = windows_for_test(40);
    let y = simulate(
        &p,
        &[Window {
            u: &us[0],
            f: &us[0],
            alpha: 0.1,
            alphas: None,
            x: None,
        }],
        &Grid::SAME,
    );
    let f0: Vec<f32> = y[0].iter().map(|&v| v as f32 + 50.0).collect();
    let win = Window {
        u: &us[0],
        f: &f0,
        alpha: 0.1,
        alphas: None,
        x: None,
    };
    let wins = [win, win];
    let partner = [Some(1), Some(0)];
    let pairing = Some(Pairing {
        partner: &partner,
        weight: 3.0,
    });
    let (parts, _) = loss_and_grad_paired(&p, &wins, pairing, &Grid::SAME, 5, 1000.0);
    let (mse, _) = loss_and_grad(&p, &wins, &Grid::SAME, 5, 1000.0);
    assert!((parts.mse - mse).abs() <= 1e-12 * mse);
    assert!((mse - 0.05 * 0.05).abs() < 1e-4 * mse, "mse {mse}");
    assert!(parts.diff.abs() < 1e-12, "diff {}", parts.diff);
}

#[test]
fn adjoint_is_exact_with_a_condition_level_changing_within_windows() {
    check_fd_on(ModelKind::Nemm, Integrator::Rk4, 1.0, true, false);
    check_fd_on(ModelKind::Nemm, Integrator::Rk3, 2.5, true, false);
    check_fd_on(ModelKind::Nemm, Integrator::Rk4, 3.3, true, false);
}

#[test]
fn adjoint_is_exact_with_a_static_force() {
    check_fd_on(ModelKind::LinearEmm, Integrator::Rk4, 1.0, false, true);
    check_fd_on(ModelKind::NemmLight, Integrator::Rk4, 1.0, true, true);
    check_fd_on(ModelKind::Nemm, Integrator::Rk4, 3.3, false, true);
    check_fd_on(ModelKind::Nemm, Integrator::Rk3, 2.5, true, true);
}

/// The alpha branches' weights (and the MLPs' without their alpha column) get their exact
/// gradients, also with a level changing within the windows, on a coarser data grid and
/// with a static force.
#[test]
fn adjoint_is_exact_with_alpha_branches() {
    let m = branched(4, 2, 3);
    check_fd_model(&m, "branched NEMM", 1.0, false);
    check_fd_model(&m, "branched NEMM", 2.5, true);
    check_fd_model(&m, "branched NEMM", 3.3, true);
    check_fd_model(&with_static(m), "branched NEMM", 2.5, true);
}

/// The cumulative scalers' weights (`b_fl`, `k_pr`; `nemm_kernels::cumulative`) get their
/// exact gradients, also with a level changing within the windows, on a coarser data grid
/// and with a static force (the NEMM: NEMM-Light's `b_fl` is the same code).
#[test]
fn adjoint_is_exact_with_cumulative_scalers() {
    let m = nemm_core::testing::example_cumulative_model(ModelKind::Nemm);
    check_fd_model(&m, "cumulative NEMM", 1.0, false);
    check_fd_model(&with_static(m), "cumulative NEMM", 2.5, true);
}

/// The rollout of a model with cumulative scalers reproduces nemm-core's estimator (exact
/// mode), as the MLP scalers' does.
#[test]
fn rollout_matches_core_estimator_with_cumulative_scalers() {
    for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
        for integ in [Integrator::Rk4, Integrator::Rk3] {
            let mut m = nemm_core::testing::example_cumulative_model(kind);
            m.integrator = integ;
            let p: RolloutParams<f32> = from_core(&m).expect("emm model");
            assert!(p.b_fl.as_ref().is_some_and(|s| s.cumulative.is_some()));
            for alpha in [0.0f32, 0.15, 0.4] {
                let (worst, rel) = rollout_against_estimator(&m, alpha);
                assert!(
                    rel < 1e-5,
                    "{kind:?} {integ:?} alpha {alpha}: max |diff| = {worst} N ({rel:e} of \
                     the force scale)"
                );
            }
        }
    }
}

/// The largest difference \[N\] between the trainer's rollout of `m` and nemm-core's
/// estimator (exact mode) at level `alpha` over 2 s of the bench-like signal at 10 kHz,
/// and that as a fraction of the force scale.
fn rollout_against_estimator(m: &Model, alpha: f32) -> (f64, f64) {
    let p: RolloutParams<f32> = from_core(m).expect("emm model");
    let n = 20_000;
    let u = signal(n, 1e-4, 0.8, 8.3, 0.3);
    let f = vec![0.0f32; n];
    let ys = simulate(
        &p,
        &[Window {
            u: &u,
            f: &f,
            alpha,
            alphas: None,
            x: None,
        }],
        &Grid::SAME,
    );
    let mut est = Estimator::new(m, EstimatorConfig::new(alpha)).expect("estimator");
    let mut worst = 0.0f64;
    for (i, &ui) in u.iter().enumerate() {
        let e = est.step(Sample::new(ui)).unwrap();
        worst = worst.max((e.force_n as f64 - ys[0][i]).abs());
    }
    (worst, worst / m.meta.force_scale_n as f64)
}

/// The example model of `kind` (H = 4, L = 2) with the example lost-motion element.
fn with_lost_motion(kind: ModelKind) -> Model {
    nemm_core::testing::example_model_with_lost_motion(kind, 4, 2).expect("example model")
}

/// The lost-motion element's five parameters and every other parameter through it get their
/// exact gradients: each EMM kind, a level changing within the windows (the travels follow
/// the level), a coarser data grid, a static force.
#[test]
fn adjoint_is_exact_with_lost_motion() {
    check_fd_model(
        &with_lost_motion(ModelKind::LinearEmm),
        "Linear EMM + lost motion",
        1.0,
        false,
    );
    check_fd_model(
        &with_lost_motion(ModelKind::NemmLight),
        "NEMM-Light + lost motion",
        1.0,
        true,
    );
    check_fd_model(
        &with_lost_motion(ModelKind::Nemm),
        "NEMM + lost motion",
        3.3,
        true,
    );
    let mut m = with_static(with_lost_motion(ModelKind::Nemm));
    m.integrator = Integrator::Rk3;
    check_fd_model(&m, "NEMM + lost motion + static", 2.5, true);
}

/// With the lost-motion element the trainer's rollout is nemm-core's estimator (parity as
/// [`rollout_matches_core_estimator`]), at two levels.
#[test]
fn rollout_matches_core_estimator_with_lost_motion() {
    for kind in [ModelKind::LinearEmm, ModelKind::NemmLight, ModelKind::Nemm] {
        let m = nemm_core::testing::example_model_with_lost_motion(kind, 16, 5).expect("model");
        for alpha in [0.0f32, 0.3] {
            let (worst, rel) = rollout_against_estimator(&m, alpha);
            assert!(
                rel < 1e-5,
                "{kind:?} alpha {alpha}: max |diff| = {worst} N ({rel:e})"
            );
        }
    }
}

#[test]
fn grid_maps_samples_and_steps() {
    let same = Grid::new(1e-4, 1e-4);
    assert_eq!(same, Grid::SAME);
    assert_eq!(
        (same.sample_at(7), same.input_at(7), same.steps(10)),
        ((7, 0.0), (7, 0.0), 10)
    );
    // The model step is stored in f32: 10 kHz data on it is the same grid, 1 kHz data ten
    // steps per sample; a ratio off a whole number by more than f32 resolution is kept.
    let stored = f64::from(1e-4f32);
    assert_eq!(Grid::new(stored, 1e-4), Grid::SAME);
    assert_eq!(Grid::new(stored, 1e-3).steps_per_sample(), 10.0);
    assert_eq!(
        Grid::new(1e-4, 1e-4 * (1.0 + 1e-6)).steps_per_sample(),
        1.0 + 1e-6
    );
    // 1 kHz data on a 10 kHz model: every 10th step is a sample.
    let g = Grid::new(1e-4, 1e-3);
    assert_eq!(g.steps_per_sample(), 10.0);
    assert_eq!(g.sample_at(3), (30, 0.0));
    assert_eq!(g.input_at(35), (3, 0.5));
    assert_eq!(g.steps(4), 31);
    // 300 Hz data: 33.3 steps per sample, the output interpolated between two steps.
    let g = Grid::new(1e-4, 1.0 / 300.0);
    let (j, w) = g.sample_at(1);
    assert_eq!(j, 33);
    assert!((w - 1.0 / 3.0).abs() < 1e-9, "{w}");
    assert_eq!(g.sample_at(3), (100, 0.0));
    assert_eq!(g.steps(2), 35);
    // Input interpolation, held past the last sample.
    let x = [0.0f32, 1.0, 3.0];
    let g = Grid::new(1e-4, 4e-4);
    let at: Vec<f64> = (0..10).map(|j| g.interpolate(&x, j)).collect();
    assert_eq!(at, [0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 3.0]);
}

/// The f32 rollout against nemm-core's estimator fed per model step, with a per-sample
/// condition level and a data rate below the model rate (`eval::run_estimator`).
#[test]
fn rollout_matches_core_estimator_with_alpha_per_sample_on_a_coarse_grid() {
    use super::eval::{run_estimator, Input};
    for (kind, ratio, with_branches, stat) in [
        (ModelKind::Nemm, 1.0, false, false),
        (ModelKind::Nemm, 100.0 / 3.0, false, false),
        (ModelKind::NemmLight, 10.0, false, false),
        (ModelKind::Nemm, 1.0, true, false),
        (ModelKind::Nemm, 10.0, true, false),
        (ModelKind::Nemm, 100.0 / 3.0, false, true),
        (ModelKind::LinearEmm, 10.0, false, true),
        (ModelKind::Nemm, 10.0, true, true),
    ] {
        let m = example_16x5(kind, with_branches, stat);
        let p: RolloutParams<f32> = from_core(&m).expect("emm model");
        let sample_dt = ratio * f64::from(m.dt_s);
        let n = (1.5 / sample_dt) as usize;
        let u = signal(n, sample_dt, 0.8, 8.3, 0.3);
        let x = position(n, sample_dt, 8.3, 0.3);
        let levels = alpha_steps(1, n);
        let grid = Grid::new(f64::from(m.dt_s), sample_dt);
        let ys = simulate(
            &p,
            &[Window {
                u: &u,
                f: &u,
                alpha: 0.15,
                alphas: Some(&levels),
                x: Some(&x),
            }],
            &grid,
        );
        let mut est = Estimator::new(&m, EstimatorConfig::new(0.15)).expect("estimator");
        let input = Input {
            velocity_m_s: &u,
            alpha: 0.15,
            alphas: Some(&levels),
            position_m: Some(&x),
        };
        let (forces, steps) =
            run_estimator(&mut est, f64::from(m.dt_s), &input, sample_dt).expect("estimator run");
        assert_eq!(steps, grid.steps(n));
        let worst = forces
            .iter()
            .zip(&ys[0])
            .fold(0.0f64, |w, (a, b)| w.max((a - b).abs()));
        let rel = worst / f64::from(m.meta.force_scale_n);
        assert!(
            rel < 1e-5,
            "{kind:?} ratio {ratio} branches {with_branches} static {stat}: max |diff| = \
             {worst} N ({rel:e} of force scale)"
        );
    }
}

#[test]
fn adjoint_matches_finite_differences_nemm_rk4() {
    check_fd(ModelKind::Nemm, Integrator::Rk4);
}

#[test]
fn adjoint_matches_finite_differences_nemm_rk3() {
    check_fd(ModelKind::Nemm, Integrator::Rk3);
}

#[test]
fn adjoint_matches_finite_differences_light_and_linear() {
    check_fd(ModelKind::NemmLight, Integrator::Rk4);
    check_fd(ModelKind::LinearEmm, Integrator::Rk4);
}

#[test]
fn f32_adjoint_is_close_to_f64() {
    let mut m = model(ModelKind::Nemm, 16, 5);
    m.dt_s = 1e-4;
    let p64: RolloutParams<f64> = from_core(&m).expect("emm model");
    let p32: RolloutParams<f32> = convert(&p64);
    let n = 2000;
    let (us, fs, alphas) = windows_for_test(n);
    let wins: Vec<Window<'_>> = (0..us.len())
        .map(|i| Window {
            u: &us[i],
            f: &fs[i],
            alpha: alphas[i],
            alphas: None,
            x: None,
        })
        .collect();
    let (l64, g64) = loss_and_grad(&p64, &wins, &Grid::SAME, 100, 1500.0);
    let (l32, g32) = loss_and_grad(&p32, &wins, &Grid::SAME, 100, 1500.0);
    assert!((l64 - l32).abs() <= 1e-5 * l64, "loss {l64} vs {l32}");
    let a = flat(&g64);
    let b = flat(&convert_grads(&g32));
    // Per group, relative to the group's largest component.
    for group in ["b_fl0", "b_pr0", "k0", "t_pr", "b_fl[", "b_pr[", "k_pr["] {
        let sel: Vec<_> = a
            .iter()
            .zip(&b)
            .filter(|((n, _), _)| n.starts_with(group))
            .collect();
        let scale = sel.iter().fold(0.0f64, |m, ((_, x), _)| m.max(x.abs()));
        let worst = sel
            .iter()
            .fold(0.0f64, |m, ((_, x), (_, y))| m.max((x - y).abs() / scale));
        assert!(worst < 1e-3, "{group}: f32 relative error {worst:e}");
        eprintln!("{group}: f32 vs f64 worst relative error {worst:e}");
    }
}

fn convert_grads(g: &RolloutGrads<f32>) -> RolloutGrads<f64> {
    let v = |x: &Vec<f32>| x.iter().map(|&y| y as f64).collect();
    RolloutGrads {
        b_fl0: g.b_fl0 as f64,
        b_pr0: g.b_pr0 as f64,
        k0: g.k0 as f64,
        t_pr: g.t_pr as f64,
        b_fl: v(&g.b_fl),
        b_pr: v(&g.b_pr),
        k_pr: v(&g.k_pr),
        static_force: v(&g.static_force),
        lost_motion: v(&g.lost_motion),
    }
}

/// Converts parameters between float types.
fn convert<A: Real, B: Real>(p: &RolloutParams<A>) -> RolloutParams<B> {
    let c = |v: A| B::c(v.to_f64().unwrap_or(f64::NAN));
    let s = |s: &Option<ScalerWeights<A>>| {
        s.as_ref().map(|s| ScalerWeights {
            inputs: s.inputs,
            hidden: s.hidden,
            layers: s.layers,
            w: s.w.iter().map(|&v| c(v)).collect(),
            s_min: c(s.s_min),
            s_max: c(s.s_max),
            branch: s.branch,
            cumulative: s.cumulative,
        })
    };
    RolloutParams {
        integrator: p.integrator,
        dt: c(p.dt),
        b_fl0: c(p.b_fl0),
        b_pr0: c(p.b_pr0),
        k0: c(p.k0),
        t_pr: c(p.t_pr),
        v_scale: c(p.v_scale),
        x_scale: c(p.x_scale),
        alpha_scale: c(p.alpha_scale),
        b_fl: s(&p.b_fl),
        b_pr: s(&p.b_pr),
        k_pr: s(&p.k_pr),
        priors: p.priors,
        static_force: p.static_force.map(|s| StaticParams {
            theta: s.theta.map(c),
            x_ref: c(s.x_ref),
            v_c: c(s.v_c),
        }),
        lost_motion: p.lost_motion.map(|l| l.map(c)),
    }
}
