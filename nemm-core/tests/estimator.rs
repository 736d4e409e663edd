//! The online estimator: finite for any bounded input, recovery after NaN/Inf bursts, held
//! out-of-range inputs, refusal of unstable steps and non-finite weights, alpha handling, and
//! agreement of the folded hot path with the reference (unfolded) model.

mod common;

use common::{boxed, example, reference_run, stroke, table1_grid, KINDS, P};
use nemm_core::{
    Body, Estimate, Estimator, EstimatorConfig, EstimatorError, Flags, Integrator, Model,
    ModelError, ModelKind, Sample, DEFAULT_TABLE_SEGMENTS, STABILITY_MARGIN,
};
use nemm_kernels::emm::{Coefficients, State};
use nemm_kernels::integrator::{self, StepSize};
use proptest::prelude::*;
use std::f32::consts::TAU;

const INPUT_BITS: u8 = Flags::INPUT_NON_FINITE | Flags::INPUT_OUT_OF_RANGE | Flags::INPUT_HELD;

fn run<const Q: usize>(est: &mut Estimator<Q>, inputs: &[f32]) -> Vec<Estimate> {
    inputs
        .iter()
        .map(|&v| est.step(Sample::new(v)).unwrap())
        .collect()
}

/// The input the estimator must have used: every rejected sample replaced by the last
/// accepted one (0 before the first, as after `reset`).
fn held(inputs: &[f32], rejected: impl Fn(f32) -> bool) -> Vec<f32> {
    let mut last = 0.0;
    inputs
        .iter()
        .map(|&v| {
            if !rejected(v) {
                last = v;
            }
            last
        })
        .collect()
}

/// A smooth test input: two sines (velocity, m/s).
fn smooth(n: usize, amp: f32, f1: f32, f2: f32, dt: f32) -> Vec<f32> {
    (0..n)
        .map(|k| {
            let t = k as f32 * dt;
            amp * (0.7 * (TAU * f1 * t).sin() + 0.3 * (TAU * f2 * t + 1.0).cos())
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Any bounded finite input sequence, any kind, random valid model, any alpha: the force
    /// and the state stay finite; input flags are set exactly for the samples beyond the
    /// plausibility limit; the counters match.
    #[test]
    fn finite_for_any_bounded_input(
        spec in common::arb_model(16, 5),
        alpha in 0.0f32..=1.0,
        inputs in prop::collection::vec(-50.0f32..50.0, 1..400),
    ) {
        let m: Model<{ P }> = spec.build();
        let mut est = Estimator::new(&m, EstimatorConfig::new(alpha)).unwrap();
        let limit = est.velocity_limit_m_s();
        let mut resets = 0;
        for (k, &v) in inputs.iter().enumerate() {
            let e = est.step(Sample::new(v)).unwrap();
            prop_assert!(e.force_n.is_finite(), "step {}: {}", k, e.force_n);
            prop_assert!(est.state().is_finite());
            let out = v.abs() > limit;
            prop_assert_eq!(e.flags.0 & INPUT_BITS,
                if out { Flags::INPUT_OUT_OF_RANGE | Flags::INPUT_HELD } else { 0 });
            resets += u32::from(e.flags.contains(Flags::STATE_RESET));
        }
        let d = est.diagnostics();
        prop_assert_eq!(d.steps as usize, inputs.len());
        prop_assert_eq!(d.held_samples as usize, inputs.iter().filter(|v| v.abs() > limit).count());
        prop_assert_eq!(d.resets, resets);
    }

    /// A burst of NaN / +-Inf samples: during the burst the input is held and flagged
    /// (exactly `INPUT_NON_FINITE | INPUT_HELD`, nothing else changes); the estimate equals,
    /// during and after the burst, that of an undisturbed estimator fed the held-input
    /// sequence; outside the burst the flags are those of the undisturbed run.
    #[test]
    fn recovers_after_non_finite_burst(
        spec in common::arb_model(8, 3),
        alpha in 0.0f32..=1.0,
        (amp, f1, f2) in (0.05f32..1.0, 0.5f32..20.0, 0.5f32..30.0),
        (start, len) in (0usize..500, 1usize..100),
        bad in prop::collection::vec(prop::sample::select(vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -f32::NAN]), 1..8),
    ) {
        let m: Model<{ P }> = spec.build();
        let amp = amp * m.scales.velocity_m_s; // within the plausibility limit (3 x scale)
        let clean = smooth(700, amp, f1, f2, m.dt_s);
        let mut disturbed = clean.clone();
        for (i, v) in disturbed[start..start + len].iter_mut().enumerate() {
            *v = bad[i % bad.len()];
        }
        let held_inputs = held(&disturbed, |v| !v.is_finite());
        let cfg = EstimatorConfig::new(alpha);
        let mut a = Estimator::new(&m, cfg).unwrap();
        let mut b = Estimator::new(&m, cfg).unwrap();
        let ra = run(&mut a, &disturbed);
        let rb = run(&mut b, &held_inputs);
        for (k, (ea, eb)) in ra.iter().zip(&rb).enumerate() {
            prop_assert_eq!(ea.force_n.to_bits(), eb.force_n.to_bits(), "step {}", k);
            prop_assert_eq!(eb.flags.0 & INPUT_BITS, 0);
            let in_burst = (start..start + len).contains(&k);
            let want = eb.flags.0 | if in_burst { Flags::INPUT_NON_FINITE | Flags::INPUT_HELD } else { 0 };
            prop_assert_eq!(ea.flags.0, want, "step {}", k);
        }
        prop_assert_eq!(a.state(), b.state());
        prop_assert_eq!(a.diagnostics().held_samples as usize, len);
    }

    /// Samples beyond the plausibility limit (here configured) are held and flagged
    /// `INPUT_OUT_OF_RANGE | INPUT_HELD`; a sample exactly at the limit is used.
    #[test]
    fn out_of_range_inputs_are_held(
        spec in common::arb_model(8, 3),
        limit in 0.1f32..2.0,
        raw in prop::collection::vec((-1.0f32..1.0, prop::bool::weighted(0.2), 1.001f32..1e6), 1..300),
    ) {
        let m: Model<{ P }> = spec.build();
        let inputs: Vec<f32> = raw
            .iter()
            .map(|&(x, out, f)| if out { x.signum() * limit * f } else { x * limit })
            .collect();
        let cfg = EstimatorConfig { velocity_limit_m_s: Some(limit), ..EstimatorConfig::new(0.1) };
        let mut a = Estimator::new(&m, cfg).unwrap();
        prop_assert_eq!(a.velocity_limit_m_s(), limit);
        let mut b = Estimator::new(&m, cfg).unwrap();
        let ra = run(&mut a, &inputs);
        let rb = run(&mut b, &held(&inputs, |v| v.abs() > limit));
        for (k, ((ea, eb), (_, out, _))) in ra.iter().zip(&rb).zip(&raw).enumerate() {
            prop_assert_eq!(ea.force_n.to_bits(), eb.force_n.to_bits(), "step {}", k);
            let want = if *out { Flags::INPUT_OUT_OF_RANGE | Flags::INPUT_HELD } else { 0 };
            prop_assert_eq!(ea.flags.0 & INPUT_BITS, want, "step {}", k);
        }
        // At the limit: accepted, not held.
        let e = a.step(Sample::new(limit)).unwrap();
        prop_assert_eq!(e.flags.0 & INPUT_BITS, 0);
        let e = a.step(Sample::new(-limit)).unwrap();
        prop_assert_eq!(e.flags.0 & INPUT_BITS, 0);
    }

    /// A step is accepted exactly when `dt <= 0.8 * limit * tau_min`: the estimator refuses a
    /// longer configured step (or a scheme with a smaller limit) with `UnstableStep`, whose
    /// fields say what to do.
    #[test]
    fn unstable_step_is_refused(
        spec in common::arb_model(4, 2),
        factor in 0.2f32..3.0,
        integrator in common::arb_integrator(),
    ) {
        let m: Model<{ P }> = spec.build();
        let Some(tau) = m.fastest_time_constant_s() else {
            // The SEM has no dynamics: any positive step is fine.
            let cfg = EstimatorConfig { dt_s: Some(factor), ..EstimatorConfig::new(0.1) };
            prop_assert!(Estimator::new(&m, cfg).is_ok());
            return Ok(());
        };
        let max_dt = STABILITY_MARGIN * integrator.stability_limit() * tau;
        let dt = factor * max_dt;
        let cfg = EstimatorConfig {
            dt_s: Some(dt),
            integrator: Some(integrator),
            ..EstimatorConfig::new(0.1)
        };
        let r = Estimator::new(&m, cfg);
        if dt <= max_dt {
            prop_assert!(r.is_ok(), "{:?}", r.err());
        } else {
            let want = ModelError::UnstableStep { dt_s: dt, tau_min_s: tau, max_dt_s: max_dt, integrator: integrator.name() };
            prop_assert_eq!(r.err(), Some(EstimatorError::Model(want)));
            let mut bad = m.clone();
            bad.dt_s = dt;
            bad.integrator = integrator;
            prop_assert_eq!(bad.validate(), Err(want));
        }
    }

    /// A NaN or infinite weight anywhere in any scaler is refused (validation, estimator).
    #[test]
    fn non_finite_weights_are_refused(
        spec in common::arb_model(8, 3),
        role in 0usize..3,
        at in any::<prop::sample::Index>(),
        value in prop::sample::select(vec![f32::NAN, f32::INFINITY, f32::NEG_INFINITY]),
    ) {
        let mut m: Model<{ P }> = spec.build();
        let (name, params) = match &mut m.body {
            Body::Nemm { b_fl, b_pr, k_pr, .. } => match role {
                0 => ("b_fl", &mut b_fl.mlp.params),
                1 => ("b_pr", &mut b_pr.mlp.params),
                _ => ("k_pr", &mut k_pr.mlp.params),
            },
            Body::NemmLight { b_fl, .. } => ("b_fl", &mut b_fl.mlp.params),
            _ => return Ok(()),
        };
        let i = at.index(params.len());
        params[i] = value;
        let want = ModelError::NonFinite { field: name };
        prop_assert_eq!(m.validate(), Err(want));
        prop_assert_eq!(Estimator::new(&m, EstimatorConfig::new(0.1)).err(),
            Some(EstimatorError::Model(want)));
    }

    /// `set_alpha` re-folds everything alpha-dependent: after `set_alpha(a2)` and `reset`, the
    /// estimator is bit-identical to one built for `a2`; the extrapolation flag follows the
    /// training range.
    #[test]
    fn set_alpha_equals_new(
        spec in common::arb_model(8, 3),
        a1 in 0.0f32..=1.0,
        a2 in 0.0f32..=1.0,
    ) {
        let m: Model<{ P }> = spec.build();
        let inputs = smooth(200, 0.5 * m.scales.velocity_m_s, 3.0, 11.0, m.dt_s);
        let mut x = Estimator::new(&m, EstimatorConfig::new(a1)).unwrap();
        let _ = run(&mut x, &inputs[..50]);
        x.set_alpha(a2).unwrap();
        x.reset();
        prop_assert_eq!(x.alpha(), a2);
        let mut y = Estimator::new(&m, EstimatorConfig::new(a2)).unwrap();
        let rx = run(&mut x, &inputs);
        let ry = run(&mut y, &inputs);
        let outside = !(m.meta.alpha_min..=m.meta.alpha_max).contains(&a2);
        for (ex, ey) in rx.iter().zip(&ry) {
            prop_assert_eq!(ex.force_n.to_bits(), ey.force_n.to_bits());
            prop_assert_eq!(ex.flags, ey.flags);
            if outside {
                prop_assert!(ex.flags.contains(Flags::ALPHA_EXTRAPOLATED));
            }
        }
    }
}

/// After a burst the estimate converges back to that of the undisturbed input: the burst only
/// changed the state, and the model forgets its state with its time constants
/// (`(b_pr + b_fl) / k_pr` = 10 ms and `T_pr` = 2 ms for the examples at s = 1). 0.15 s
/// after a 20 ms burst the difference must have decayed below 1e-3 of the force scale.
#[test]
fn converges_to_undisturbed_run_after_burst() {
    for kind in KINDS {
        let m = example(kind);
        for integrator in common::INTEGRATORS {
            let cfg = EstimatorConfig {
                integrator: Some(integrator),
                ..EstimatorConfig::new(0.15)
            };
            let clean = smooth(4000, 0.5, 2.0, 7.0, m.dt_s);
            let mut disturbed = clean.clone();
            for v in &mut disturbed[1000..1200] {
                *v = f32::NAN;
            }
            let ra = run(&mut Estimator::new(&m, cfg).unwrap(), &disturbed);
            let rc = run(&mut Estimator::new(&m, cfg).unwrap(), &clean);
            let during = ra[1000..1200]
                .iter()
                .zip(&rc[1000..1200])
                .map(|(a, c)| (a.force_n - c.force_n).abs())
                .fold(0.0f32, f32::max);
            let after = ra[2700..]
                .iter()
                .zip(&rc[2700..])
                .map(|(a, c)| (a.force_n - c.force_n).abs())
                .fold(0.0f32, f32::max);
            // The burst must have mattered (else the test would prove nothing) ...
            assert!(during > 10.0, "{kind:?} {integrator:?}: {during}");
            // ... and be forgotten.
            assert!(
                after < 1e-3 * m.meta.force_scale_n,
                "{kind:?} {integrator:?}: {after}"
            );
            assert!(ra[1200..].iter().all(|e| e.flags.is_empty()));
        }
    }
}

#[test]
fn short_time_constant_is_refused() {
    let mut m = example(ModelKind::LinearEmm);
    if let Body::LinearEmm(e) = &mut m.body {
        e.t_pr_s = m.dt_s / 3.0;
    }
    let tau = m.dt_s / 3.0;
    let want = ModelError::UnstableStep {
        dt_s: m.dt_s,
        tau_min_s: tau,
        max_dt_s: STABILITY_MARGIN * 2.785 * tau,
        integrator: Integrator::Rk4.name(),
    };
    assert_eq!(m.validate(), Err(want));
    assert_eq!(
        Estimator::new(&m, EstimatorConfig::new(0.1)).err(),
        Some(EstimatorError::Model(want))
    );
    // RK3 has the smaller limit: a step between the two limits is RK4-only.
    let m = example(ModelKind::Nemm);
    let tau = m.fastest_time_constant_s().unwrap();
    let dt = STABILITY_MARGIN * 2.6 * tau;
    let cfg = |i| EstimatorConfig {
        dt_s: Some(dt),
        integrator: Some(i),
        ..EstimatorConfig::new(0.1)
    };
    assert!(Estimator::new(&m, cfg(Integrator::Rk4)).is_ok());
    assert!(matches!(
        Estimator::new(&m, cfg(Integrator::Rk3)),
        Err(EstimatorError::Model(ModelError::UnstableStep { .. }))
    ));
}

#[test]
fn bad_configuration_is_refused() {
    let m = example(ModelKind::NemmLight);
    for alpha in [f32::NAN, -0.01, 1.01, f32::INFINITY] {
        assert_eq!(
            boxed::<DEFAULT_TABLE_SEGMENTS>(&m, EstimatorConfig::new(alpha)).err(),
            Some(EstimatorError::AlphaOutOfRange)
        );
    }
    for limit in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let cfg = EstimatorConfig {
            velocity_limit_m_s: Some(limit),
            ..EstimatorConfig::new(0.1)
        };
        assert_eq!(
            boxed::<DEFAULT_TABLE_SEGMENTS>(&m, cfg).err(),
            Some(EstimatorError::BadVelocityLimit)
        );
    }
    for (dt, want) in [
        (0.0, ModelError::NotPositive { field: "dt_s" }),
        (f32::NAN, ModelError::NonFinite { field: "dt_s" }),
    ] {
        let cfg = EstimatorConfig {
            dt_s: Some(dt),
            ..EstimatorConfig::new(0.1)
        };
        assert_eq!(
            boxed::<DEFAULT_TABLE_SEGMENTS>(&m, cfg).err(),
            Some(EstimatorError::Model(want))
        );
    }
    let mut est = boxed::<DEFAULT_TABLE_SEGMENTS>(&m, EstimatorConfig::new(0.1)).unwrap();
    assert_eq!(
        est.set_alpha(f32::NAN),
        Err(EstimatorError::AlphaOutOfRange)
    );
    assert_eq!(est.alpha(), 0.1);
}

/// The real-axis stability limits used by the step check are those of the schemes: the
/// amplification factor `R(z)` of one step of `x' = -x / tau` (`z = -dt / tau`) has
/// `|R| <= 1` at the limit and `|R| > 1` just beyond, both from the polynomials and from the
/// crate's own step.
#[test]
fn stability_limits_are_the_schemes() {
    let r4 = |z: f64| 1.0 + z + z * z / 2.0 + z.powi(3) / 6.0 + z.powi(4) / 24.0;
    let r3 = |z: f64| 1.0 + z + z * z / 2.0 + z.powi(3) / 6.0;
    for (integrator, r) in [
        (Integrator::Rk4, &r4 as &dyn Fn(f64) -> f64),
        (Integrator::Rk3, &r3),
    ] {
        let lim = f64::from(integrator.stability_limit());
        assert!(r(-lim).abs() <= 1.0, "{integrator:?}: {}", r(-lim));
        assert!(r(-lim * 1.002).abs() > 1.0, "{integrator:?}");
        // The crate's step on x' = -k x / (b_pr + b_fl) with b_pr -> 0: tau = b_fl / k.
        let c = Coefficients {
            b_fl: 1.0,
            b_pr: 1e-30,
            k_pr: 1000.0,
        };
        let tau = 1e-3;
        for (factor, grows) in [(0.99, false), (1.01, true)] {
            let h = StepSize::new((factor * lim * tau) as f32);
            let mut x = State {
                x_pr_m: 1.0,
                v_st_m_s: 0.0,
            };
            for _ in 0..300 {
                x = integrator::step(integrator, |_| c, &c, 1.0, &x, 0.0, 0.0, &h);
            }
            assert_eq!(
                x.x_pr_m.abs() > 1.0,
                grows,
                "{integrator:?} {factor}: {x:?}"
            );
        }
    }
}

/// The example models run the whole Table 1 grid at alpha = 0.15 without any flag, reset or
/// held sample, for both schemes (half a period per stroke from rest: the velocity sweeps its
/// whole range, the stroke from one end to the other).
#[cfg_attr(
    debug_assertions,
    ignore = "minutes in a debug build; runs with --release"
)]
#[test]
fn example_models_run_table1_without_flags() {
    for kind in KINDS {
        let m = example(kind);
        for integrator in common::INTEGRATORS {
            let cfg = EstimatorConfig {
                integrator: Some(integrator),
                ..EstimatorConfig::new(0.15)
            };
            let mut est = Estimator::new(&m, cfg).unwrap();
            let mut steps = 0usize;
            for (amp, v) in table1_grid() {
                est.reset();
                let inputs = stroke(amp, v, 0.5, f64::from(m.dt_s));
                steps += inputs.len();
                for e in run(&mut est, &inputs) {
                    assert!(e.flags.is_empty(), "{kind:?} {integrator:?} {amp} {v}");
                }
            }
            let d = est.diagnostics();
            assert_eq!((d.steps as usize, d.held_samples, d.resets), (steps, 0, 0));
        }
    }
}

/// The folded hot path (compiled scalers, alpha folded into biases, coefficients reused as
/// stage 1) against the reference path (`Model::b_fl` etc., unfolded scalers, same RK step)
/// over Table 1 strokes. Per evaluation the two differ by rounding, ~1e-6 relative
/// (`tests/scaler.rs`); the EMM is contracting, so these differences do not accumulate:
/// allow 1e-5 of the force scale (0.03 N of 3000 N).
#[cfg_attr(
    debug_assertions,
    ignore = "minutes in a debug build; runs with --release"
)]
#[test]
fn hot_path_matches_reference_model() {
    for kind in [ModelKind::LinearEmm, ModelKind::NemmLight, ModelKind::Nemm] {
        let m = example(kind);
        for integrator in common::INTEGRATORS {
            for alpha in [0.0, 0.15, 0.3] {
                let cfg = EstimatorConfig {
                    integrator: Some(integrator),
                    ..EstimatorConfig::new(alpha)
                };
                let mut worst = 0.0f32;
                for (amp, v) in [(0.05, 1.048), (0.01, 0.524), (0.01, 0.131)] {
                    let inputs = stroke(amp, v, 1.0, f64::from(m.dt_s));
                    let mut est = Estimator::new(&m, cfg).unwrap();
                    let got: Vec<f32> = run(&mut est, &inputs).iter().map(|e| e.force_n).collect();
                    let want = reference_run(&m, integrator, m.dt_s, alpha, &inputs);
                    for (g, w) in got.iter().zip(&want) {
                        worst = worst.max((g - w).abs());
                    }
                }
                assert!(
                    worst <= 1e-5 * m.meta.force_scale_n,
                    "{kind:?} {integrator:?} alpha {alpha}: {worst} N"
                );
            }
        }
    }
}

/// With the lost-motion element every EMM kind runs the reference semantics (exact mode, as
/// [`hot_path_matches_reference_model`]); table mode stays within its error bound of exact
/// mode; `set_alpha` moves the element's travel; the element deflects `x_pr` further on the
/// compression side (the longer travel) and changes the force more at the higher level.
#[cfg_attr(
    debug_assertions,
    ignore = "a minute in a debug build; runs with --release"
)]
#[test]
fn lost_motion_runs_the_reference_semantics() {
    use nemm_core::testing::example_model_with_lost_motion;
    for kind in [ModelKind::LinearEmm, ModelKind::NemmLight, ModelKind::Nemm] {
        let m: Model<P> = example_model_with_lost_motion(kind, 16, 5).unwrap();
        let plain = example(kind);
        let inputs = stroke(0.01, 0.524, 1.0, f64::from(m.dt_s));
        let mut change = [0.0f32; 2];
        for (i, alpha) in [0.0f32, 0.3].into_iter().enumerate() {
            let cfg = EstimatorConfig::new(alpha);
            let mut est = Estimator::new(&m, cfg).unwrap();
            let got: Vec<f32> = run(&mut est, &inputs).iter().map(|e| e.force_n).collect();
            let want = reference_run(&m, m.integrator, m.dt_s, alpha, &inputs);
            let worst = got
                .iter()
                .zip(&want)
                .fold(0.0f32, |w, (g, r)| w.max((g - r).abs()));
            assert!(
                worst <= 1e-5 * m.meta.force_scale_n,
                "{kind:?} alpha {alpha}: {worst} N"
            );
            // set_alpha on an estimator loaded at another level: the same run.
            let mut moved = Estimator::new(&m, EstimatorConfig::new(0.15)).unwrap();
            moved.set_alpha(alpha).unwrap();
            let again: Vec<f32> = run(&mut moved, &inputs).iter().map(|e| e.force_n).collect();
            assert_eq!(again, got, "{kind:?} alpha {alpha}: set_alpha");
            // Table mode within its bound (1e-3 of the coefficients) of exact mode.
            if kind != ModelKind::LinearEmm {
                let tcfg = EstimatorConfig {
                    mode: nemm_core::EvalMode::Table(nemm_core::TableConfig::new(1e-4)),
                    ..cfg
                };
                let mut table = Estimator::new(&m, tcfg).unwrap();
                let tab: Vec<f32> = run(&mut table, &inputs).iter().map(|e| e.force_n).collect();
                let worst = tab
                    .iter()
                    .zip(&got)
                    .fold(0.0f32, |w, (g, r)| w.max((g - r).abs()));
                assert!(
                    worst <= 5e-3 * m.meta.force_scale_n,
                    "{kind:?} alpha {alpha}: table {worst} N"
                );
            }
            // Against the same model without the element: the force changes, and the
            // deflection x_pr grows more on the compression side (the longer travel).
            let mut base = Estimator::new(&plain, cfg).unwrap();
            let mut with = Estimator::new(&m, cfg).unwrap();
            let (mut lo, mut hi) = ([0.0f32; 2], [0.0f32; 2]);
            let mut sq = 0.0f32;
            let n = inputs.len();
            for (k, &u) in inputs.iter().enumerate() {
                let (a, b) = (
                    with.step(Sample::new(u)).unwrap(),
                    base.step(Sample::new(u)).unwrap(),
                );
                if k >= n / 2 {
                    sq += (a.force_n - b.force_n).powi(2);
                    for (j, e) in [&with, &base].into_iter().enumerate() {
                        let x = e.state().x_pr_m;
                        lo[j] = lo[j].min(x);
                        hi[j] = hi[j].max(x);
                    }
                }
            }
            assert!(
                lo[1] - lo[0] > hi[0] - hi[1],
                "{kind:?} alpha {alpha}: x_pr {lo:?} {hi:?}"
            );
            change[i] = sq.sqrt();
        }
        assert!(change[1] > change[0], "{kind:?}: {change:?}");
    }
}

/// The static force adds `r(x, u, alpha)` to the force of the same model without it, in
/// exact and table mode, and leaves the states alone; `step` without a position and a
/// non-finite position are flagged and hold the last good position; per-sample alpha works
/// with a position.
#[test]
fn static_force_adds_r_and_needs_the_position() {
    common::with_big_stack(static_force_adds_r);
}

fn static_force_adds_r() {
    use nemm_core::testing::EXAMPLE_STATIC_FORCE as SF;
    use nemm_core::{EvalMode, TableConfig};
    let dt = 1e-4f32;
    let n = 4000;
    let t = |k: usize| k as f32 * dt;
    let v: Vec<f32> = (0..n).map(|k| 0.3 * (TAU * 3.0 * t(k)).cos()).collect();
    let x: Vec<f32> = (0..n)
        .map(|k| 0.03 + 0.3 / (TAU * 3.0) * (TAU * 3.0 * t(k)).sin())
        .collect();
    let alpha = 0.15;
    for kind in [ModelKind::LinearEmm, ModelKind::NemmLight, ModelKind::Nemm] {
        for mode in [EvalMode::Exact, EvalMode::Table(TableConfig::new(1e-4))] {
            let plain = example(kind);
            let mut with = plain.clone();
            with.static_force = Some(SF);
            let cfg = EstimatorConfig {
                mode,
                ..EstimatorConfig::new(alpha)
            };
            let mut e0 = boxed::<DEFAULT_TABLE_SEGMENTS>(&plain, cfg).unwrap();
            let mut e1 = boxed::<DEFAULT_TABLE_SEGMENTS>(&with, cfg).unwrap();
            assert!(!e0.needs_position() && e1.needs_position());
            for k in 0..n {
                let a = e0.step(Sample::new(v[k]).with_position(x[k])).unwrap();
                let b = e1.step(Sample::new(v[k]).with_position(x[k])).unwrap();
                assert_eq!(a.flags, b.flags, "{kind:?} {k}");
                assert_eq!(e0.state(), e1.state(), "r must not enter the state");
                let r = SF.force(x[k], v[k], alpha);
                assert!(
                    (b.force_n - a.force_n - r).abs() <= 1e-4 * a.force_n.abs().max(100.0),
                    "{kind:?} {}: {} + {r} != {}",
                    mode.name(),
                    a.force_n,
                    b.force_n
                );
            }
            // `step` without a position: flagged, the last good position held.
            let (vk, xk) = (v[n - 1], x[n - 1]);
            let a = e0.step(Sample::new(vk)).unwrap();
            let b = e1.step(Sample::new(vk)).unwrap();
            assert!(b.flags.contains(Flags::POSITION_MISSING));
            assert!(!a.flags.contains(Flags::POSITION_MISSING));
            let r = SF.force(xk, vk, alpha);
            assert!((b.force_n - a.force_n - r).abs() <= 1e-4 * a.force_n.abs().max(100.0));
            // A non-finite position: flagged, held, the state unharmed.
            for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
                let a = e0.step(Sample::new(vk).with_position(bad)).unwrap();
                let b = e1.step(Sample::new(vk).with_position(bad)).unwrap();
                assert!(b.flags.contains(Flags::POSITION_MISSING));
                assert!(!b.flags.contains(Flags::STATE_RESET) && b.force_n.is_finite());
                assert_eq!(e0.state(), e1.state());
                assert!((b.force_n - a.force_n - r).abs() <= 1e-4 * a.force_n.abs().max(100.0));
            }
            // After a reset the held position is x_ref.
            e1.reset();
            let b = e1.step(Sample::new(0.0)).unwrap();
            assert!((b.force_n - SF.force(SF.x_ref_m, 0.0, alpha)).abs() < 1e-3);
        }
    }
    // A per-sample condition level with the position (exact mode).
    let mut with = example(ModelKind::Nemm);
    with.static_force = Some(SF);
    let mut e = boxed::<DEFAULT_TABLE_SEGMENTS>(&with, EstimatorConfig::new(0.0)).unwrap();
    let mut plain =
        boxed::<DEFAULT_TABLE_SEGMENTS>(&example(ModelKind::Nemm), EstimatorConfig::new(0.0))
            .unwrap();
    for k in 0..200 {
        let a = if k < 100 { 0.0 } else { 0.3 };
        let f = e
            .step(Sample::new(v[k]).with_alpha(a).with_position(x[k]))
            .unwrap();
        let f0 = plain.step(Sample::new(v[k]).with_alpha(a)).unwrap();
        assert!(f.flags.is_empty());
        let r = SF.force(x[k], v[k], a);
        assert!((f.force_n - f0.force_n - r).abs() <= 1e-4 * f0.force_n.abs().max(100.0));
    }
}

proptest! {
    /// Any position (finite or not, huge or tiny) and any velocity: the force is finite and
    /// the state equals that of the model without the static force.
    #[test]
    fn static_force_never_poisons(
        xs in proptest::collection::vec(prop_oneof![
            Just(f32::NAN), Just(f32::INFINITY), Just(-1e30f32), Just(1e30f32), -1.0f32..1.0
        ], 1..60),
        vs in proptest::collection::vec(prop_oneof![Just(f32::NAN), -3.0f32..3.0], 1..60),
    ) {
        let plain = example(ModelKind::LinearEmm);
        let mut with = plain.clone();
        with.static_force = Some(nemm_core::testing::EXAMPLE_STATIC_FORCE);
        let mut e0 = boxed::<DEFAULT_TABLE_SEGMENTS>(&plain, EstimatorConfig::new(0.1)).unwrap();
        let mut e1 = boxed::<DEFAULT_TABLE_SEGMENTS>(&with, EstimatorConfig::new(0.1)).unwrap();
        for (&x, &v) in xs.iter().zip(vs.iter().cycle()) {
            let b = e1.step(Sample::new(v).with_position(x)).unwrap();
            e0.step(Sample::new(v)).unwrap();
            prop_assert!(b.force_n.is_finite());
            prop_assert_eq!(e0.state(), e1.state());
            prop_assert_eq!(b.flags.contains(Flags::POSITION_MISSING), !x.is_finite());
        }
    }
}
