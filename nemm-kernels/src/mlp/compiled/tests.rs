//! The cumulative mode of [`CompiledScaler`] against the reference path
//! ([`CumulativeScaler::scale`]), and its tables.

use super::*;
use crate::cumulative::{cumulative_param_count, CumulativeScaler};
#[cfg(not(feature = "micromath"))]
use crate::table::{Table1D, TableError};

/// A deterministic value in `[-1, 1)` from an index and a seed.
fn unit(i: usize, seed: u64) -> f32 {
    let mut z = (i as u64).wrapping_add(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    ((z >> 40) as f32) / ((1u64 << 23) as f32) - 1.0
}

/// A cumulative scaler of `units` units: logits in `+-0.5`, widths `exp(omega)` with
/// `omega` in `omega0 +- 1.5`, centres in `+-2`, gate slopes in `+-1.2`, biases in `+-0.5`.
fn scaler(units: usize, direction: Direction, omega0: f32, seed: u64) -> CumulativeScaler {
    let k = units;
    let mut p = Vec::new();
    p.extend((0..=k).map(|j| 0.5 * unit(j, seed)));
    p.extend((0..k).map(|j| omega0 + 1.5 * unit(100 + j, seed)));
    p.extend((0..k).map(|j| 2.0 * unit(200 + j, seed)));
    p.extend((0..=k).map(|j| 1.2 * unit(300 + j, seed)));
    p.extend((0..=k).map(|j| 0.5 * unit(400 + j, seed)));
    assert_eq!(p.len(), cumulative_param_count(k));
    CumulativeScaler::new(direction, units as u8, &p).unwrap()
}

const S_MIN: f32 = 0.2;
const S_MAX: f32 = 3.0;
const P_INI: f32 = 2500.0;
const U_SCALE: f32 = 1.05;
const ALPHA_SCALE: f32 = 0.3;

fn reference(c: &CumulativeScaler, u: f32, alpha: f32) -> f32 {
    P_INI
        * c.scale(u / U_SCALE, alpha / ALPHA_SCALE, S_MIN, S_MAX)
            .unwrap()
}

/// State inputs from 0 and subnormal to beyond the training scale, both signs.
fn grid() -> Vec<f32> {
    let mut us = vec![0.0f32, -0.0, 1e-40, 1e-30, 1e-12, 1e-7, 1e-4, 0.01, 0.05];
    us.extend((0..=64).map(|i| 1.6 * U_SCALE * i as f32 / 64.0));
    let neg: Vec<f32> = us.iter().map(|u| -u).collect();
    us.extend(neg);
    us
}

/// The compiled cumulative scaler returns the reference's bits (the same operations in the
/// same order), at every level compiled for and after `set_alpha` to another; it has no
/// branch, a constant pattern, and the MLP mode's bounds.
#[test]
fn cumulative_mode_is_the_reference_bit_for_bit() {
    for (units, direction, seed) in [
        (16, Direction::Decreasing, 1),
        (3, Direction::Increasing, 2),
        (1, Direction::None, 3),
    ] {
        let c = scaler(units, direction, 0.5, seed);
        let alphas = [0.0f32, 0.1, 0.3, 1.0];
        for &alpha in &alphas {
            let mut cs = CompiledScaler::<128>::empty();
            cs.compile_cumulative_into(&c, S_MIN, S_MAX, P_INI, U_SCALE, alpha, ALPHA_SCALE)
                .unwrap();
            assert!(cs.is_cumulative() && !cs.has_branch());
            let (lo, hi) = cs.bounds();
            assert_eq!(lo, P_INI * S_MIN);
            assert!((hi - P_INI * S_MAX).abs() <= 1e-6 * hi);
            for &u in &grid() {
                let want = reference(&c, u, alpha);
                let got = cs.eval(u);
                assert_eq!(got.to_bits(), want.to_bits(), "{units} {alpha} {u}");
                assert!(lo < got && got < hi, "{got}");
                let (v, pattern) = cs.eval_with_pattern(u);
                assert_eq!(v.to_bits(), got.to_bits());
                assert_eq!(pattern, cs.pattern(0.0));
                assert_eq!(cs.pattern(u), cs.pattern(0.0));
            }
            // Re-folded at every other level: the reference at that level.
            for &other in &alphas {
                cs.set_alpha(other);
                for &u in &grid() {
                    assert_eq!(
                        cs.eval(u).to_bits(),
                        reference(&c, u, other).to_bits(),
                        "{units} {alpha} -> {other} {u}"
                    );
                }
            }
        }
    }
}

/// An MLP compiled into storage that held a cumulative scaler (and back) is the MLP's
/// compilation, and a capacity below `5 K + 3` values is refused.
#[test]
fn modes_switch_in_place_and_capacity_is_checked() {
    let c = scaler(16, Direction::Decreasing, 0.5, 4);
    let n = param_count(1, 3, 1);
    let params: Vec<f32> = (0..n).map(|i| 0.3 * unit(i, 9)).collect();
    let sc = Scaler {
        mlp: MlpParams::<128>::new(1, 3, 1, &params).unwrap(),
        s_min: S_MIN,
        s_max: S_MAX,
    };
    let mlp = CompiledScaler::compile(&sc, P_INI, U_SCALE, 0.1, ALPHA_SCALE).unwrap();
    let mut cs = CompiledScaler::<128>::empty();
    cs.compile_cumulative_into(&c, S_MIN, S_MAX, P_INI, U_SCALE, 0.1, ALPHA_SCALE)
        .unwrap();
    cs.compile_into(&sc, None, P_INI, U_SCALE, 0.1, ALPHA_SCALE)
        .unwrap();
    assert!(!cs.is_cumulative());
    for u in [-1.0f32, 0.0, 0.4] {
        assert_eq!(cs.eval(u).to_bits(), mlp.eval(u).to_bits());
        assert_eq!(cs.pattern(u), mlp.pattern(u));
    }
    cs.compile_cumulative_into(&c, S_MIN, S_MAX, P_INI, U_SCALE, 0.1, ALPHA_SCALE)
        .unwrap();
    assert_eq!(cs.eval(0.3).to_bits(), reference(&c, 0.3, 0.1).to_bits());
    let mut small = CompiledScaler::<82>::empty();
    assert_eq!(
        small.compile_cumulative_into(&c, S_MIN, S_MAX, P_INI, U_SCALE, 0.1, ALPHA_SCALE),
        None
    );
    let mut fits = CompiledScaler::<83>::empty();
    assert!(fits
        .compile_cumulative_into(&c, S_MIN, S_MAX, P_INI, U_SCALE, 0.1, ALPHA_SCALE)
        .is_some());
}

/// A table of a typical cumulative scaler (16 units, widths up to `e^2 ~ 7.4` per unit of
/// normalised state) has no kinks and meets a 1e-4 bound with 256 and with 64 segments; a
/// scaler with units far sharper than a segment (widths near `e^8 ~ 3000`) misses the
/// bound, which the table's check refuses. With the exact `exp` only: the `micromath`
/// approximation is not smooth at this resolution (the table's check refuses it at 1e-4).
#[cfg(not(feature = "micromath"))]
#[test]
fn tables_of_cumulative_scalers_meet_their_bound_or_are_refused() {
    let d = 1.1 * U_SCALE;
    for alpha in [0.0f32, 0.15, 0.3] {
        let c = scaler(16, Direction::Decreasing, 0.5, 5);
        let mut cs = CompiledScaler::<128>::empty();
        cs.compile_cumulative_into(&c, S_MIN, S_MAX, P_INI, U_SCALE, alpha, ALPHA_SCALE)
            .unwrap();
        let t = Table1D::<256>::compile(&cs, -d, d, 1e-4, "b_fl").unwrap();
        let a = t.accuracy();
        assert_eq!(a.kinks, 0);
        assert!(a.max_rel_error <= 1e-4, "{a:?}");
        let t = Table1D::<64>::compile(&cs, -d, d, 1e-4, "b_fl").unwrap();
        assert!(t.accuracy().max_rel_error <= 1e-4);
        // Independent check of the table against the exact scaler between its knots.
        for i in 0..=1000 {
            let u = -d + 2.0 * d * i as f32 / 1000.0;
            let (exact, table) = (cs.eval(u), t.eval(u, &mut false));
            assert!(
                (table - exact).abs() <= 1e-4 * exact,
                "{u}: {table} vs {exact}"
            );
        }
    }
    let sharp = scaler(16, Direction::Decreasing, 8.0, 6);
    let mut cs = CompiledScaler::<128>::empty();
    cs.compile_cumulative_into(&sharp, S_MIN, S_MAX, P_INI, U_SCALE, 0.1, ALPHA_SCALE)
        .unwrap();
    assert!(matches!(
        Table1D::<64>::compile(&cs, -d, d, 1e-4, "b_fl"),
        Err(TableError::ExceedsBound { .. })
    ));
}
