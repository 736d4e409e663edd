//! The static force of eq. 17 in training: its fixed part (`x_ref`, `v_c`) from the data and
//! its least-squares initialisation on the residual of an EMM (`nemm_kernels::static_force`).
//!
//! `r = theta . phi(x, u, alpha)` is linear in its parameters `theta`, so for fixed EMM
//! dynamics the `theta` that minimises the training MSE is the least-squares fit of the
//! residual `F - y_EMM` on the features `phi` at the scored samples. The friction `F_c`
//! must not be negative: a negative fit is refitted without the friction column (`F_c = 0`).

// The normal equations index rows and columns of small arrays together; index loops read as
// the algebra does.
#![allow(clippy::needless_range_loop)]

use super::adjoint::{simulate, Grid, RolloutParams, StaticParams, Window};
use super::net::static_units;
use crate::data::preprocess::Sequence;
use nemm_kernels::static_force::{features, STATIC_PARAMS};

/// `v_c` as a fraction of the training abs-max velocity: the friction reaches 76 % of `F_c`
/// at this velocity (`tanh 1`), 2 % of the velocity scale (20 mm/s at 1 m/s).
pub(crate) const V_C_FRACTION: f64 = 0.02;

/// Ridge added to each diagonal entry of the normal equations, relative to it (keeps the
/// system solvable when two features are collinear, e.g. `1` and `alpha` at a single
/// condition level; a feature that is zero throughout gets a zero parameter).
const RIDGE: f64 = 1e-12;

/// The fixed part of a static force chosen from the training data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StaticSetup {
    /// Reference position: the mean measured position of the training samples \[m\].
    pub(crate) x_ref: f64,
    /// Largest `|x - x_ref|` of the training samples \[m\].
    pub(crate) x_span: f64,
    /// Smoothing velocity of the friction \[m/s\]: [`V_C_FRACTION`] of the velocity scale.
    pub(crate) v_c: f64,
}

impl StaticSetup {
    /// From the training sequences (every sample) and the velocity scale \[m/s\].
    pub(crate) fn of(train: &[Sequence], velocity_scale_m_s: f64) -> Self {
        let (sum, n) = train
            .iter()
            .flat_map(|s| &s.position_m)
            .fold((0.0f64, 0usize), |(a, n), &x| (a + f64::from(x), n + 1));
        let x_ref = if n > 0 { sum / n as f64 } else { 0.0 };
        let x_span = train
            .iter()
            .flat_map(|s| &s.position_m)
            .fold(0.0f64, |m, &x| m.max((f64::from(x) - x_ref).abs()));
        Self {
            x_ref,
            x_span,
            v_c: V_C_FRACTION * velocity_scale_m_s.max(1e-9),
        }
    }

    /// The training units of the parameters ([`static_units`]) at force scale `force_scale_n`.
    pub(crate) fn units(&self, force_scale_n: f64) -> [f32; STATIC_PARAMS] {
        static_units(force_scale_n as f32, self.x_span as f32)
    }
}

/// Least-squares static force on the residual of `p`'s EMM (its own static force, if any,
/// left out) over the scored samples (after `warmup`) of `windows`, with the fixed part
/// `setup`.
pub(crate) fn fit_residual(
    p: &RolloutParams<f32>,
    windows: &[Window<'_>],
    grid: &Grid,
    warmup: usize,
    setup: &StaticSetup,
) -> StaticParams<f32> {
    let emm_only = RolloutParams {
        static_force: None,
        ..p.clone()
    };
    let ys = simulate(&emm_only, windows, grid);
    let mut rows: Vec<([f64; STATIC_PARAMS], f64)> = Vec::new();
    for (w, y) in windows.iter().zip(&ys) {
        for k in warmup..w.u.len().min(y.len()) {
            let x =
                w.x.and_then(|x| x.get(k))
                    .map_or(setup.x_ref, |&v| f64::from(v));
            let a = w.alphas.and_then(|a| a.get(k)).copied().unwrap_or(w.alpha);
            let phi = features(setup.x_ref, setup.v_c, x, f64::from(w.u[k]), f64::from(a));
            rows.push((phi, f64::from(w.f[k]) - y[k]));
        }
    }
    let mut theta = least_squares(&rows, [true; STATIC_PARAMS]);
    if theta[STATIC_PARAMS - 1] < 0.0 {
        let mut used = [true; STATIC_PARAMS];
        used[STATIC_PARAMS - 1] = false;
        theta = least_squares(&rows, used);
    }
    StaticParams {
        theta: theta.map(|t| if t.is_finite() { t as f32 } else { 0.0 }),
        x_ref: setup.x_ref as f32,
        v_c: setup.v_c as f32,
    }
}

/// Least squares `min |A theta - b|^2` over the columns marked `used` (the others 0), by the
/// normal equations with a small ridge and Gaussian elimination with partial pivoting.
fn least_squares(
    rows: &[([f64; STATIC_PARAMS], f64)],
    used: [bool; STATIC_PARAMS],
) -> [f64; STATIC_PARAMS] {
    const N: usize = STATIC_PARAMS;
    let mut a = [[0.0f64; N + 1]; N];
    for (phi, b) in rows {
        for i in 0..N {
            for j in 0..N {
                a[i][j] += phi[i] * phi[j];
            }
            a[i][N] += phi[i] * b;
        }
    }
    for i in 0..N {
        if used[i] {
            a[i][i] += RIDGE * a[i][i];
        } else {
            for row in a.iter_mut() {
                row[i] = 0.0;
            }
            a[i] = [0.0; N + 1];
            a[i][i] = 1.0;
        }
    }
    for c in 0..N {
        let piv = (c..N)
            .max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))
            .unwrap_or(c);
        a.swap(c, piv);
        let d = a[c][c];
        if d.abs() < 1e-300 {
            continue;
        }
        for r in 0..N {
            if r != c {
                let f = a[r][c] / d;
                for k in c..=N {
                    a[r][k] -= f * a[c][k];
                }
            }
        }
    }
    std::array::from_fn(|i| {
        if used[i] && a[i][i].abs() >= 1e-300 {
            a[i][N] / a[i][i]
        } else {
            0.0
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn least_squares_recovers_a_linear_model_and_drops_columns() {
        let theta = [-90.0, 20.0, 800.0, -200.0, 15.0];
        let rows: Vec<([f64; 5], f64)> = (0..400)
            .map(|k| {
                let t = k as f64 * 0.01;
                let alpha = [0.0, 0.15, 0.3][k % 3];
                let phi = features(0.03, 0.01, 0.03 + 0.02 * t.sin(), 0.3 * t.cos(), alpha);
                let b = (0..5).map(|q| theta[q] * phi[q]).sum();
                (phi, b)
            })
            .collect();
        let got = least_squares(&rows, [true; 5]);
        for q in 0..5 {
            assert!(
                (got[q] - theta[q]).abs() < 1e-4 * theta[q].abs().max(1.0),
                "{got:?}"
            );
        }
        let got = least_squares(&rows, [true, true, true, true, false]);
        assert_eq!(got[4], 0.0);
    }
}
