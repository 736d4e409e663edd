//! The static map (SEM): interpolation in velocity and alpha, extrapolation, alpha clamping,
//! and the estimator's SEM path, on random grids.

mod common;

use nemm_core::Sample;
use nemm_core::{Body, Estimator, EstimatorConfig, Flags, Model, ModelKind, SemMap};
use proptest::prelude::*;

/// Tolerance of one interpolation step in f32: a few ulps of the largest force involved
/// (`f0 + (f1 - f0) t` with `|t| <= 1` rounds three times; `t` itself twice).
fn tol(fmax: f32) -> f32 {
    8.0 * f32::EPSILON * fmax.max(1.0)
}

fn fmax(m: &SemMap) -> f32 {
    m.forces_n.iter().fold(0.0f32, |a, f| a.max(f.abs()))
}

fn row(m: &SemMap, ia: usize) -> &[f32] {
    let nv = m.velocities_m_s.len();
    &m.forces_n[ia * nv..(ia + 1) * nv]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// At a tabulated alpha the curve is that row; at a support point the force is the table
    /// value; between two support points it is the straight line through them. (At the last
    /// level and the last knot the value is `f0 + (f1 - f0) * 1`, which may differ from `f1`
    /// by an ulp, hence a tolerance rather than equality.)
    #[test]
    fn piecewise_linear_in_velocity(spec in common::arb_sem(), ia in 0usize..8, t in 0.0f32..1.0) {
        let m = spec.build();
        prop_assert_eq!(m.validate(), Ok(()));
        let ia = ia % m.alphas.len();
        let (curve, clamped) = m.curve_at(m.alphas[ia]);
        prop_assert!(!clamped);
        let t_f = tol(fmax(&m));
        for (&c, &r) in curve.iter().zip(row(&m, ia)) {
            prop_assert!((c - r).abs() <= t_f, "{} vs {}", c, r);
        }
        let v = &m.velocities_m_s;
        for (i, (&vi, &fi)) in v.iter().zip(curve.iter()).enumerate() {
            let f = m.force_on_curve(&curve, vi);
            prop_assert!((f - fi).abs() <= t_f, "knot {}: {} vs {}", i, f, fi);
        }
        for i in 0..v.len() - 1 {
            let x = v[i] + t * (v[i + 1] - v[i]);
            let tt = f64::from(x - v[i]) / f64::from(v[i + 1] - v[i]);
            let want = f64::from(curve[i]) + f64::from(curve[i + 1] - curve[i]) * tt;
            let got = m.force_on_curve(&curve, x);
            prop_assert!((f64::from(got) - want).abs() <= f64::from(tol(fmax(&m))),
                "segment {}: {} vs {}", i, got, want);
        }
    }

    /// Beyond the ends the force continues the end segments' straight lines.
    #[test]
    fn linear_extrapolation(spec in common::arb_sem(), beyond in 0.01f32..10.0) {
        let m = spec.build();
        let (curve, _) = m.curve_at(m.alphas[0]);
        let v = &m.velocities_m_s;
        let n = v.len();
        let slope_lo = f64::from(curve[1] - curve[0]) / f64::from(v[1] - v[0]);
        let slope_hi = f64::from(curve[n - 1] - curve[n - 2]) / f64::from(v[n - 1] - v[n - 2]);
        let (lo, hi) = (v[0] - beyond, v[n - 1] + beyond);
        let want_lo = f64::from(curve[0]) + slope_lo * f64::from(lo - v[0]);
        let want_hi = f64::from(curve[n - 1]) + slope_hi * f64::from(hi - v[n - 1]);
        // Extrapolating by `k` segment lengths multiplies the rounding of `t` by `k`.
        let k_lo = 1.0 + f64::from(beyond / (v[1] - v[0]));
        let k_hi = 1.0 + f64::from(beyond / (v[n - 1] - v[n - 2]));
        let got_lo = f64::from(m.force_on_curve(&curve, lo));
        let got_hi = f64::from(m.force_on_curve(&curve, hi));
        prop_assert!((got_lo - want_lo).abs() <= k_lo * f64::from(tol(fmax(&m))), "{} vs {}", got_lo, want_lo);
        prop_assert!((got_hi - want_hi).abs() <= k_hi * f64::from(tol(fmax(&m))), "{} vs {}", got_hi, want_hi);
    }

    /// Between two tabulated levels the curve is the straight line between their rows;
    /// outside the alpha range it is clamped to the end row and reported as clamped.
    #[test]
    fn linear_in_alpha_and_clamped(spec in common::arb_sem(), ia in 0usize..8, t in 0.0f32..1.0) {
        let m = spec.build();
        let na = m.alphas.len();
        if na >= 2 {
            let ia = ia % (na - 1);
            let a = m.alphas[ia] + t * (m.alphas[ia + 1] - m.alphas[ia]);
            let (curve, clamped) = m.curve_at(a);
            prop_assert!(!clamped);
            let tt = f64::from(a - m.alphas[ia]) / f64::from(m.alphas[ia + 1] - m.alphas[ia]);
            for (k, &f) in curve.iter().enumerate() {
                let (f0, f1) = (f64::from(row(&m, ia)[k]), f64::from(row(&m, ia + 1)[k]));
                let want = f0 + (f1 - f0) * tt;
                prop_assert!((f64::from(f) - want).abs() <= f64::from(tol(fmax(&m))));
            }
        }
        let below = m.alphas[0] - 0.01;
        let above = m.alphas[na - 1] + 0.01;
        for (a, r) in [(below, 0), (above, na - 1)] {
            let (curve, clamped) = m.curve_at(a);
            prop_assert!(clamped, "alpha {} is outside [{}, {}]", a, m.alphas[0], m.alphas[na - 1]);
            for (&c, &f) in curve.iter().zip(row(&m, r)) {
                prop_assert!((c - f).abs() <= tol(fmax(&m)), "{} vs {}", c, f);
            }
        }
    }

    /// The estimator's SEM path is the map, memoryless: every step returns the curve at the
    /// configured alpha at this sample's velocity (or the held one).
    #[test]
    fn estimator_is_the_map(spec in common::arb_sem(), alpha in 0.0f32..1.0,
                            vs in prop::collection::vec(-4.0f32..4.0, 1..200)) {
        let map = spec.build();
        let mut model: Model<16> = nemm_core::testing::example_model(ModelKind::Sem, 1, 1).unwrap();
        model.body = Body::Sem(map.clone());
        model.scales.velocity_m_s = 2.0; // plausibility limit 6 m/s: nothing is held
        let mut est = Estimator::new(&model, EstimatorConfig::new(alpha)).unwrap();
        let (curve, clamped) = map.curve_at(alpha);
        let outside_training = !(model.meta.alpha_min..=model.meta.alpha_max).contains(&alpha);
        for &v in &vs {
            let e = est.step(Sample::new(v)).unwrap();
            prop_assert_eq!(e.force_n, map.force_on_curve(&curve, v));
            prop_assert_eq!(e.flags.contains(Flags::ALPHA_EXTRAPOLATED), clamped || outside_training);
            prop_assert_eq!(e.flags.0 & !Flags::ALPHA_EXTRAPOLATED, 0);
        }
    }
}

/// The example map (digressive, rebound stiffer than compression) is monotone in velocity at
/// every alpha of its range, and its force falls with oil loss: interpolation preserves both.
#[test]
fn example_map_is_monotone_and_degrades() {
    let m = nemm_core::testing::example_sem();
    let mut prev_curve: Option<Vec<f32>> = None;
    for k in 0..=30 {
        let alpha = 0.01 * k as f32;
        let (curve, clamped) = m.curve_at(alpha);
        assert!(!clamped);
        let mut last = f32::NEG_INFINITY;
        for j in -300..=300 {
            let f = m.force_on_curve(&curve, 0.005 * j as f32);
            assert!(
                f >= last,
                "alpha {alpha}: not monotone at {}",
                0.005 * j as f32
            );
            last = f;
        }
        if let Some(p) = &prev_curve {
            for (&a, &b) in p.iter().zip(curve.iter()) {
                assert!(b.abs() <= a.abs(), "force must fall with alpha");
            }
        }
        prev_curve = Some(curve.to_vec());
    }
}
