//! The tabulated fast path: tables agree with the exact scalers within their verified bound
//! inside the domain, clamp and flag outside it, and the table-mode estimator follows the
//! exact one over a bench programme within 1e-4 of the force scale.

mod common;

use common::{boxed, example, stroke, table1_grid, P};
use nemm_core::{
    Body, Estimator, EstimatorConfig, EstimatorError, EvalMode, Flags, Model, ModelKind, Sample,
    TableConfig, TableError,
};
use nemm_kernels::mlp::CompiledScaler;
use nemm_kernels::table::Table1D;
use proptest::prelude::*;

/// Segments of the tables in the property tests (the estimator's default).
const T: usize = nemm_core::DEFAULT_TABLE_SEGMENTS;

/// The neural state scalers of a model, compiled as the estimator compiles them, with the
/// half-width of their default table domain.
fn state_scalers(m: &Model<P>, alpha: f32) -> Vec<(&'static str, CompiledScaler<P>, f32)> {
    let sc = &m.scales;
    let margin = nemm_kernels::table::DEFAULT_DOMAIN_MARGIN;
    let mut v = Vec::new();
    if let Body::NemmLight { emm, b_fl } | Body::Nemm { emm, b_fl, .. } = &m.body {
        let c = CompiledScaler::compile(b_fl, emm.b_fl_ns_per_m, sc.velocity_m_s, alpha, sc.alpha)
            .unwrap();
        v.push(("b_fl", c, margin * sc.velocity_m_s));
    }
    if let Body::Nemm { emm, k_pr, .. } = &m.body {
        let c =
            CompiledScaler::compile(k_pr, emm.k_pr_n_per_m, sc.x_pr_m, alpha, sc.alpha).unwrap();
        v.push(("k_pr", c, margin * sc.x_pr_m));
    }
    v
}

fn table_cfg(bound: f32) -> EstimatorConfig {
    EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(bound)),
        ..EstimatorConfig::new(0.15)
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Random neural models (any width and depth up to 16 x 5, weight gains up to 3) and
    /// alphas: a table that compiles within the bound `1e-3` agrees with the exact scaler at
    /// random inputs inside its domain within the bound (the check grid is 128x finer than
    /// the table, so between its points the error may exceed the measured maximum only by
    /// the error's variation over 1/128 of a segment: allow 10 % of it). A table that is
    /// refused reports a measured error above the bound. Outside the domain every input is
    /// flagged and gives the finite boundary value.
    #[test]
    fn tables_agree_inside_and_clamp_outside(
        spec in common::arb_model(16, 5),
        alpha in 0.0f32..=1.0,
        inside in prop::collection::vec(-1.0f32..=1.0, 64),
        outside in prop::collection::vec(1.0001f32..1e3, 16),
    ) {
        let m: Model<P> = spec.build();
        let bound = 1e-3f32;
        for (name, exact, d) in state_scalers(&m, alpha) {
            // The estimator builds tables from the value of `eval` (the fast kernel on the
            // target) and the unfused `pattern`: the same value bits as the fused portable
            // network, and the same pattern except within rounding of a kink.
            for &r in &inside {
                let (v, p) = exact.eval_with_pattern(r * d);
                prop_assert_eq!(v.to_bits(), exact.eval(r * d).to_bits());
                prop_assert_eq!(p, exact.pattern(r * d));
            }
            let portable = Table1D::<T>::compile(|u| exact.eval_with_pattern(u), -d, d, bound, name);
            let built = Table1D::<T>::compile(&exact, -d, d, bound, name);
            match (&built, &portable) {
                (Ok(b), Ok(p)) => prop_assert_eq!(b.accuracy().kinks, p.accuracy().kinks),
                (Err(b), Err(p)) => prop_assert_eq!(
                    core::mem::discriminant(b),
                    core::mem::discriminant(p)
                ),
                (b, p) => prop_assert!(false, "{name}: {b:?} against {p:?}"),
            }
            match built {
                Err(TableError::ExceedsBound { max_rel_error, bound: b, .. }) => {
                    prop_assert!(max_rel_error > b && b == bound);
                }
                Err(TableError::TooManyKinks { segments, .. }) => prop_assert_eq!(segments, T),
                Err(e) => prop_assert!(false, "{name}: {e}"),
                Ok(t) => {
                    let measured = t.accuracy().max_rel_error;
                    prop_assert!(measured <= bound);
                    for &r in &inside {
                        let x = r * d;
                        let mut out = false;
                        let got = t.eval(x, &mut out);
                        let want = exact.eval(x);
                        let rel = ((got - want) / want).abs();
                        prop_assert!(!out, "{name} {x} flagged inside");
                        prop_assert!(
                            rel <= 1.1 * measured + 1e-6 && rel <= 1.1 * bound,
                            "{name} at {x}: {rel:e} (grid max {measured:e})"
                        );
                    }
                    let (lo, hi) = exact.bounds();
                    for (k, &r) in outside.iter().enumerate() {
                        let x = if k % 2 == 0 { r * d } else { -r * d };
                        let mut out = false;
                        let got = t.eval(x, &mut out);
                        let edge = t.eval(if x > 0.0 { d } else { -d }, &mut false);
                        prop_assert!(out && got.is_finite() && got == edge, "{name} {x}");
                        prop_assert!(got >= lo * (1.0 - 2.0 * bound) && got <= hi * (1.0 + 2.0 * bound));
                    }
                    let mut out = false;
                    prop_assert!(t.eval(f32::NAN, &mut out).is_finite() && out);
                }
            }
        }
    }

    /// The table-mode estimator on random models: finite force for any bounded input; the
    /// domain flag is set on every step whose new state lies outside a table's domain, and
    /// never in exact mode.
    #[test]
    fn table_mode_is_finite_and_flags_the_domain(
        spec in common::arb_model(8, 3),
        alpha in 0.0f32..=1.0,
        inputs in prop::collection::vec(-20.0f32..20.0, 1..200),
    ) {
        let m: Model<P> = spec.build();
        let base = EstimatorConfig { velocity_limit_m_s: Some(1e3), ..EstimatorConfig::new(alpha) };
        let cfg = EstimatorConfig { mode: EvalMode::Table(TableConfig::new(1.0)), ..base };
        let mut exact = Estimator::<P>::new(&m, base).unwrap();
        let mut table = match Estimator::<P, 128>::with_segments(&m, cfg) {
            Ok(e) => e,
            // A refused table is a typed error, not a failure: random scalers can have more
            // kinks than segments, or (H = 2: LayerNorm of two values is close to a sign
            // function) a near-jump no cubic can follow within the bound.
            Err(EstimatorError::Table(
                TableError::TooManyKinks { .. } | TableError::ExceedsBound { .. },
            )) => return Ok(()),
            Err(e) => return Err(TestCaseError::fail(format!("{e}"))),
        };
        let margin = nemm_kernels::table::DEFAULT_DOMAIN_MARGIN;
        let (vd, xd) = (margin * m.scales.velocity_m_s, margin * m.scales.x_pr_m);
        let neural = matches!(m.kind(), ModelKind::NemmLight | ModelKind::Nemm);
        for &u in &inputs {
            let e = exact.step(Sample::new(u)).unwrap();
            prop_assert!(!e.flags.contains(Flags::OUT_OF_TABLE_DOMAIN));
            let t = table.step(Sample::new(u)).unwrap();
            prop_assert!(t.force_n.is_finite());
            let s = table.state();
            let v_out = s.v_st_m_s.abs() > vd;
            let x_out = m.kind() == ModelKind::Nemm && s.x_pr_m.abs() > xd;
            if neural && (v_out || x_out) && !t.flags.contains(Flags::STATE_RESET) {
                prop_assert!(t.flags.contains(Flags::OUT_OF_TABLE_DOMAIN), "{s:?}");
            }
            if !neural {
                prop_assert!(!t.flags.contains(Flags::OUT_OF_TABLE_DOMAIN));
                prop_assert_eq!(t.force_n, e.force_n);
            }
        }
    }
}

/// The evidence of the fast path: the example NEMM and NEMM-Light (H = 16, L = 5, 256
/// segments, bound 1e-4) over the whole Table 1 programme (18 strokes, one period each, from
/// rest), RK4 and RK3, at alphas 0, 0.15 and 0.3: the tabulated force stays within 1e-4 of
/// the force scale of the exact one (observed at most 1.3e-6), and no step leaves the table
/// domain.
#[cfg_attr(
    debug_assertions,
    ignore = "minutes in a debug build; runs with --release"
)]
#[test]
fn table_mode_follows_exact_over_the_programme() {
    for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
        let m = example(kind);
        let mut worst_all = 0.0f32;
        for integrator in common::INTEGRATORS {
            for alpha in [0.0, 0.15, 0.3] {
                let base = EstimatorConfig {
                    integrator: Some(integrator),
                    ..EstimatorConfig::new(alpha)
                };
                let mut exact = Estimator::<P>::new(&m, base).unwrap();
                let mut table = Estimator::<P>::new(
                    &m,
                    EstimatorConfig {
                        mode: EvalMode::Table(TableConfig::new(1e-4)),
                        ..base
                    },
                )
                .unwrap();
                assert!(table.table_accuracy().unwrap().max_rel_error <= 1e-4);
                let mut worst = 0.0f32;
                for (amp, v) in table1_grid() {
                    let inputs = stroke(amp, v, 1.0, f64::from(m.dt_s));
                    exact.reset();
                    table.reset();
                    for &u in &inputs {
                        let (a, b) = (
                            exact.step(Sample::new(u)).unwrap(),
                            table.step(Sample::new(u)).unwrap(),
                        );
                        assert!(b.flags.is_empty(), "{kind:?} {amp} {v}: {:?}", b.flags);
                        worst = worst.max((a.force_n - b.force_n).abs());
                    }
                }
                println!(
                    "{} {} alpha {alpha}: max |F_table - F_exact| = {worst:.4} N = {:.2e} of the force scale",
                    kind.name(),
                    integrator.name(),
                    worst / m.meta.force_scale_n
                );
                worst_all = worst_all.max(worst);
            }
        }
        assert!(
            worst_all <= 1e-4 * m.meta.force_scale_n,
            "{kind:?}: {worst_all} N"
        );
    }
}

/// `set_alpha` in table mode rebuilds the tables: the same as a new estimator at that alpha;
/// a refused alpha (bound missed) changes nothing.
#[test]
fn table_set_alpha_equals_new_and_refusal_changes_nothing() {
    let m = example(ModelKind::Nemm);
    let inputs = stroke(0.01, 0.524, 0.5, f64::from(m.dt_s));
    let mut a = boxed::<128>(&m, table_cfg(1.0)).unwrap();
    a.set_alpha(0.3).unwrap();
    let mut b = boxed::<128>(
        &m,
        EstimatorConfig {
            alpha: 0.3,
            ..table_cfg(1.0)
        },
    )
    .unwrap();
    assert_eq!(a.table_accuracy(), b.table_accuracy());
    for &u in &inputs {
        assert_eq!(
            a.step(Sample::new(u)).unwrap(),
            b.step(Sample::new(u)).unwrap()
        );
    }
    // A bound below f32 resolution: new refuses it with the measured error.
    match boxed::<128>(&m, table_cfg(1e-9)) {
        Err(EstimatorError::Table(TableError::ExceedsBound {
            max_rel_error,
            bound,
            ..
        })) => assert!(max_rel_error > bound),
        other => panic!("{other:?}"),
    }
    // Fewer segments than the MLP has kinks (the example has 60-90 per table).
    assert!(matches!(
        boxed::<16>(&m, table_cfg(1.0)),
        Err(EstimatorError::Table(TableError::TooManyKinks {
            segments: 16,
            ..
        }))
    ));
    // An estimator whose bound holds at one alpha but not at another keeps its state.
    let tight = (0..=30)
        .map(|i| i as f32 / 100.0)
        .filter_map(|alpha| {
            let e = boxed::<128>(
                &m,
                EstimatorConfig {
                    alpha,
                    ..table_cfg(1.0)
                },
            )
            .ok()?;
            Some((alpha, e.table_accuracy()?.max_rel_error))
        })
        .collect::<Vec<_>>();
    let (a_lo, e_lo) = tight
        .iter()
        .copied()
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .unwrap();
    let e_hi = tight.iter().map(|t| t.1).fold(0.0f32, f32::max);
    assert!(e_lo < e_hi);
    // A bound the first alpha's table meets as it is, and an alpha whose table misses it
    // even after `compile` rescans around the errors for missed kinks.
    let bound = e_lo * (1.0 + 1e-6);
    let a_hi = tight
        .iter()
        .filter(|t| t.1 > bound)
        .map(|t| t.0)
        .find(|&alpha| {
            matches!(
                boxed::<128>(
                    &m,
                    EstimatorConfig {
                        alpha,
                        ..table_cfg(bound)
                    },
                ),
                Err(EstimatorError::Table(TableError::ExceedsBound { .. }))
            )
        })
        .expect("an alpha whose table misses the bound");
    let mut est = boxed::<128>(
        &m,
        EstimatorConfig {
            alpha: a_lo,
            ..table_cfg(bound)
        },
    )
    .unwrap();
    let mut twin = est.clone();
    for &u in &inputs[..100] {
        est.step(Sample::new(u)).unwrap();
        twin.step(Sample::new(u)).unwrap();
    }
    assert!(matches!(
        est.set_alpha(a_hi),
        Err(EstimatorError::Table(TableError::ExceedsBound { .. }))
    ));
    assert_eq!(est.alpha(), a_lo);
    assert_eq!(est.table_accuracy(), twin.table_accuracy());
    for &u in &inputs[100..] {
        assert_eq!(
            est.step(Sample::new(u)).unwrap(),
            twin.step(Sample::new(u)).unwrap()
        );
    }
}

/// The SEM and the Linear EMM have nothing to tabulate: table mode is the exact path.
#[test]
fn kinds_without_scalers_are_unchanged() {
    for kind in [ModelKind::Sem, ModelKind::LinearEmm] {
        let m = example(kind);
        let mut a = Estimator::<P>::new(&m, EstimatorConfig::new(0.15)).unwrap();
        let mut b = Estimator::<P>::new(&m, table_cfg(1e-4)).unwrap();
        assert_eq!(b.table_accuracy(), None);
        assert_eq!(b.table_bytes(), (0, 0));
        for &u in &stroke(0.01, 0.524, 0.5, f64::from(m.dt_s)) {
            assert_eq!(
                a.step(Sample::new(u)).unwrap(),
                b.step(Sample::new(u)).unwrap()
            );
        }
    }
}

/// Invalid table configurations are refused.
#[test]
fn bad_table_configuration_is_refused() {
    let m = example(ModelKind::NemmLight);
    for (bound, margin) in [
        (0.0, 1.1),
        (f32::NAN, 1.1),
        (1e-4, 0.0),
        (1e-4, f32::INFINITY),
    ] {
        let cfg = EstimatorConfig {
            mode: EvalMode::Table(TableConfig {
                max_rel_error: bound,
                domain_margin: margin,
            }),
            ..EstimatorConfig::new(0.15)
        };
        assert_eq!(
            Estimator::<P>::new(&m, cfg).err(),
            Some(EstimatorError::Table(TableError::BadConfig))
        );
    }
}
