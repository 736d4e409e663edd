//! Physics-inconsistency losses (paper section 5.2, eqs. 25-40) and the monotonicity audit.
//!
//! On a uniform grid of (normalised state) x (oil-loss level), the differences between
//! consecutive grid values (eqs. 27-28) estimate the derivatives whose signs physics
//! prescribes:
//!
//! | scaler | force-like function `f` | in the state (eqs. 30, 37) | in alpha (eqs. 31, 38) |
//! |--------|-------------------------|------------------------------|------------------------|
//! | `b_fl(v_st, alpha)` | `f = b_fl v_st` | `df/dv_st >= 0` | `d b_fl / d alpha <= 0` |
//! | `k_pr(x_pr, alpha)` | `f = k_pr x_pr` | `df/dx_pr >= 0` | `d k_pr / d alpha <= 0` |
//! | `b_pr(alpha)`       | `f = b_pr xdot_pr` | `df/dxdot = b_pr > 0` (by construction) | `d b_pr / d alpha <= 0` |
//!
//! The loss (eqs. 34, 39, 40) is the mean of
//! `max(0, -df/dstate)^2 + max(0, ds/dalpha + m)^2` over the grid, in normalised units: the
//! state is divided by its abs-max training scale and `f`, `s` are the dimensionless scale
//! factors (`p / p_ini`), so `lambda_ph` has the same meaning for every scaler and dataset.
//! Derivatives are difference quotients (the grid spacing divides the differences), so the
//! loss does not depend on the grid resolution.
//!
//! The margin `m` = `ALPHA_MARGIN` (1e-3 per unit alpha, 0.1 % over the whole range) asks
//! the coefficients to fall with alpha a little rather than stay flat: between the grid's
//! points a flat-at-the-points scaler can still rise slightly, which the audit's 4x finer
//! grid then counts. On the default virtual bench (demo budget, 12 epochs of 8 batches) the
//! margin and the 201 x 51 grid leave the NEMM's audit with tens of violations where a
//! 49 x 11 grid without margin leaves hundreds, at the same test RMSE and epoch time.
//!
//! The grid spans the state over `[-1.2, 1.2]` times its scale (the paper's Fig. 8 domain)
//! and alpha over `[0, 1]`.

use super::net::{EmmNet, NetFrame, ScalerNet, ScalerSpec};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use nemm_core::{Direction, Model};
use serde::{Deserialize, Serialize};

/// Dense audit grid of the reported monotonicity audit: states x alphas.
pub const AUDIT_GRID: (usize, usize) = (401, 101);

/// Grid of the training-time penalty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PenaltyGrid {
    /// Points along the normalised state in `[-state_extent, state_extent]`.
    pub(crate) n_state: usize,
    /// Points along alpha in `[0, 1]`.
    pub(crate) n_alpha: usize,
    /// Half-width of the normalised state range.
    pub(crate) state_extent: f32,
}

impl Default for PenaltyGrid {
    fn default() -> Self {
        Self {
            n_state: 201,
            n_alpha: 51,
            state_extent: 1.2,
        }
    }
}

/// Margin of the alpha conditions in the penalty: a scale factor is penalised unless it
/// falls by at least this much per unit alpha (normalised units).
pub(crate) const ALPHA_MARGIN: f32 = 1e-3;

fn linspace(a: f32, b: f32, n: usize) -> Vec<f32> {
    (0..n)
        .map(|i| a + (b - a) * i as f32 / (n.max(2) - 1) as f32)
        .collect()
}

/// The alpha term of the penalty for a scale factor's differences `ds` along alpha:
/// `max(0, -d ds + m)^2` for the declared direction `d` (none: no term). A scaler with an
/// alpha branch, or a cumulative scaler with gates in that direction, holds it by
/// construction and gets no term.
fn alpha_term<const D: usize>(ds: Tensor<D>, spec: &ScalerSpec, dir: Direction) -> Tensor<1> {
    let sign = dir.sign();
    let by_construction =
        spec.branch.is_some() || spec.cumulative.is_some_and(|c| c.direction == dir);
    if by_construction || sign == 0.0 {
        return Tensor::<1>::zeros([1], &ds.device());
    }
    relu(ds.mul_scalar(-sign).add_scalar(ALPHA_MARGIN))
        .powi_scalar(2)
        .mean()
}

/// Penalty of a two-input scaler (`b_fl` or `k_pr`): state derivative of `s * state` and alpha
/// derivative of `s` in the declared direction `dir`. A cumulative scaler's force rises with
/// the state by construction: it gets the alpha term only (none with gates in `dir`).
fn penalty_2d(
    net: &ScalerNet,
    spec: &ScalerSpec,
    dir: Direction,
    alpha_scale: f32,
    g: &PenaltyGrid,
    device: &Device,
) -> Tensor<1> {
    let xs = linspace(-g.state_extent, g.state_extent, g.n_state);
    let al = linspace(0.0, 1.0, g.n_alpha);
    let mut pts = Vec::with_capacity(2 * xs.len() * al.len());
    for &a in &al {
        for &x in &xs {
            pts.push(x);
            pts.push(a / alpha_scale);
        }
    }
    let (na, nx) = (al.len(), xs.len());
    let input = Tensor::<2>::from_data(TensorData::new(pts, [na * nx, 2]), device);
    let s = net.forward_scale(input, spec).reshape([na, nx]);
    let da = al.get(1).copied().unwrap_or(1.0) - al.first().copied().unwrap_or(0.0);
    if spec.cumulative.is_some() {
        let ds = (s.clone().narrow(0, 1, na - 1) - s.narrow(0, 0, na - 1)).div_scalar(da);
        return alpha_term(ds, spec, dir);
    }
    let xrow = Tensor::<2>::from_data(TensorData::new(xs.clone(), [1, nx]), device);
    let f = s.clone() * xrow;
    let dx = xs.get(1).copied().unwrap_or(1.0) - xs.first().copied().unwrap_or(0.0);
    let df = (f.clone().narrow(1, 1, nx - 1) - f.narrow(1, 0, nx - 1)).div_scalar(dx);
    let ds = (s.clone().narrow(0, 1, na - 1) - s.narrow(0, 0, na - 1)).div_scalar(da);
    relu(df.neg()).powi_scalar(2).mean() + alpha_term(ds, spec, dir)
}

/// Penalty of the one-input `b_pr(alpha)` scaler in the declared direction `dir`.
fn penalty_1d(
    net: &ScalerNet,
    spec: &ScalerSpec,
    dir: Direction,
    alpha_scale: f32,
    g: &PenaltyGrid,
    device: &Device,
) -> Tensor<1> {
    let al = linspace(0.0, 1.0, g.n_alpha.max(2));
    let na = al.len();
    let input = Tensor::<2>::from_data(
        TensorData::new(
            al.iter().map(|a| a / alpha_scale).collect::<Vec<f32>>(),
            [na, 1],
        ),
        device,
    );
    let s = net.forward_scale(input, spec).reshape([na]);
    let da = al.get(1).copied().unwrap_or(1.0) - al.first().copied().unwrap_or(0.0);
    let ds = (s.clone().narrow(0, 1, na - 1) - s.narrow(0, 0, na - 1)).div_scalar(da);
    alpha_term(ds, spec, dir)
}

/// Sum of the physics-inconsistency losses of every scaler in `net` (a differentiable
/// scalar, `[1]`).
pub(crate) fn physics_loss(
    net: &EmmNet,
    f: &NetFrame,
    g: &PenaltyGrid,
    device: &Device,
) -> Tensor<1> {
    let mut total = Tensor::<1>::zeros([1], device);
    let pr = &f.priors;
    if let (Some(n), Some(s)) = (&net.b_fl, &f.b_fl) {
        total = total + penalty_2d(n, s, pr.b_fl, f.alpha_scale, g, device);
    }
    if let (Some(n), Some(s)) = (&net.k_pr, &f.k_pr) {
        total = total + penalty_2d(n, s, pr.k_pr, f.alpha_scale, g, device);
    }
    if let (Some(n), Some(s)) = (&net.b_pr, &f.b_pr) {
        total = total + penalty_1d(n, s, pr.b_pr, f.alpha_scale, g, device);
    }
    total
}

/// Violations of one monotonicity condition on the audit grid.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ConditionAudit {
    /// Grid intervals checked.
    pub checked: usize,
    /// Intervals that violate the condition.
    pub violations: usize,
    /// Largest violation: the wrong-signed derivative in normalised units (0 if none).
    pub worst: f64,
}

/// Monotonicity audit of one scaler.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ScalerAudit {
    /// Force-like function increasing in the state (eqs. 30 / 37); absent for `b_pr`.
    pub state: Option<ConditionAudit>,
    /// Coefficient monotone in alpha in the declared direction (eqs. 31 / 38; nothing is
    /// checked for a coefficient without a prior in alpha).
    pub alpha: ConditionAudit,
}

/// Monotonicity audit of a model (absent scalers are `None`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Audit {
    /// `b_fl(v_st, alpha)`.
    pub b_fl: Option<ScalerAudit>,
    /// `b_pr(alpha)`.
    pub b_pr: Option<ScalerAudit>,
    /// `k_pr(x_pr, alpha)`.
    pub k_pr: Option<ScalerAudit>,
}

impl Audit {
    /// The violated conditions, one phrase each in the paper's terms, e.g. `the flow force
    /// b_fl v_st rising with v_st: 6886 of 40400 points (worst slope -0.205)`, joined with
    /// `; `; empty when the audit passes.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        let state_names = [
            (self.b_fl, "the flow force b_fl v_st rising with v_st"),
            (self.k_pr, "the spring force k_pr x_pr rising with x_pr"),
        ];
        for (sc, what) in state_names {
            if let Some(c) = sc.and_then(|s| s.state).filter(|c| c.violations > 0) {
                parts.push(format!(
                    "{what}: {} of {} points (worst slope -{:.3})",
                    c.violations, c.checked, c.worst
                ));
            }
        }
        for (sc, name) in [
            (self.b_fl, "b_fl"),
            (self.b_pr, "b_pr"),
            (self.k_pr, "k_pr"),
        ] {
            if let Some(c) = sc.map(|s| s.alpha).filter(|c| c.violations > 0) {
                parts.push(format!(
                    "{name} in its declared direction in alpha: {} of {} points",
                    c.violations, c.checked
                ));
            }
        }
        parts.join("; ")
    }

    /// Total number of violations over all conditions.
    pub fn total_violations(&self) -> usize {
        [self.b_fl, self.b_pr, self.k_pr]
            .iter()
            .flatten()
            .map(|s| s.alpha.violations + s.state.map_or(0, |c| c.violations))
            .sum()
    }
}

/// Derivatives (normalised units) at or below this are not counted as violations.
pub(crate) const MIN_VIOLATION: f64 = 1e-5;

/// Rounding floor of the audit, in units in the last place (f32) of the larger of two grid
/// values: the scalers are evaluated in f32, so two neighbouring values of a coefficient that
/// is flat (a saturated sigmoid) differ by a few ulps in either direction, which decides
/// nothing about its monotonicity. 16 ulps is a relative difference of 1.9e-6.
pub(crate) const ROUNDING_ULPS: f64 = 16.0;

/// The wrong-signed derivative `(hi - lo) / step` (normalised units) when going from grid value
/// `lo` to its neighbour `hi`, one `step` further, breaks monotonicity (`must_increase`:
/// `hi >= lo` is required, else `hi <= lo`) by more than the rounding floor
/// ([`ROUNDING_ULPS`]) and [`MIN_VIOLATION`]; `None` otherwise. The one criterion of the
/// audit, the report and the figures.
pub(crate) fn violation(lo: f64, hi: f64, step: f64, must_increase: bool) -> Option<f64> {
    let diff = if must_increase { lo - hi } else { hi - lo };
    let floor = ROUNDING_ULPS * f64::from(f32::EPSILON) * lo.abs().max(hi.abs());
    let deriv = diff / step;
    (diff > floor && deriv > MIN_VIOLATION).then_some(deriv)
}

fn check(lo: f64, hi: f64, step: f64, must_increase: bool, c: &mut ConditionAudit) {
    c.checked += 1;
    if let Some(bad) = violation(lo, hi, step, must_increase) {
        c.violations += 1;
        c.worst = c.worst.max(bad);
    }
}

/// Audits every learned scaler of `model` on a dense grid (`n_state x n_alpha`, state in
/// `[-1.2, 1.2]` of its scale, alpha in `[0, 1]`), with nemm-core's reference evaluation.
/// Constant coefficients are monotone trivially and are not audited (`None`).
pub fn audit(model: &Model, n_state: usize, n_alpha: usize) -> Audit {
    let Some(e) = model.emm() else {
        return Audit::default();
    };
    let xs = linspace(-1.2, 1.2, n_state);
    let al = linspace(0.0, 1.0, n_alpha);
    let dx = (xs[1] - xs[0]) as f64;
    let da = (al[1] - al[0]) as f64;
    let priors = model.condition.priors;
    let audit_2d = |eval: &dyn Fn(f32, f32) -> Option<f32>, scale: f32, p0: f32, dir: Direction| {
        let mut a = ScalerAudit {
            state: Some(ConditionAudit::default()),
            alpha: ConditionAudit::default(),
        };
        // s[ia][ix] in normalised units.
        let s: Vec<Vec<f64>> = al
            .iter()
            .map(|&alpha| {
                xs.iter()
                    .map(|&x| eval(x * scale, alpha).map_or(f64::NAN, |p| (p / p0) as f64))
                    .collect()
            })
            .collect();
        for row in &s {
            let f: Vec<f64> = row.iter().zip(&xs).map(|(&si, &x)| si * x as f64).collect();
            for w in f.windows(2) {
                if let Some(c) = a.state.as_mut() {
                    check(w[0], w[1], dx, true, c);
                }
            }
        }
        if dir != Direction::None {
            for rows in s.windows(2) {
                for (&lo, &hi) in rows[0].iter().zip(&rows[1]) {
                    check(lo, hi, da, dir == Direction::Increasing, &mut a.alpha);
                }
            }
        }
        a
    };
    let kind = model.kind();
    let b_fl = matches!(
        kind,
        nemm_core::ModelKind::NemmLight | nemm_core::ModelKind::Nemm
    )
    .then(|| {
        audit_2d(
            &|v, a| model.b_fl(v, a),
            model.scales.velocity_m_s,
            e.b_fl_ns_per_m,
            priors.b_fl,
        )
    });
    let k_pr = matches!(kind, nemm_core::ModelKind::Nemm).then(|| {
        audit_2d(
            &|x, a| model.k_pr(x, a),
            model.scales.x_pr_m,
            e.k_pr_n_per_m,
            priors.k_pr,
        )
    });
    let b_pr = matches!(kind, nemm_core::ModelKind::Nemm).then(|| {
        let mut c = ConditionAudit::default();
        let s: Vec<f64> = al
            .iter()
            .map(|&a| {
                model
                    .b_pr(a)
                    .map_or(f64::NAN, |p| (p / e.b_pr_ns_per_m) as f64)
            })
            .collect();
        if priors.b_pr != Direction::None {
            for w in s.windows(2) {
                check(w[0], w[1], da, priors.b_pr == Direction::Increasing, &mut c);
            }
        }
        ScalerAudit {
            state: None,
            alpha: c,
        }
    });
    Audit { b_fl, b_pr, k_pr }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::adjoint::RolloutParams;
    use crate::train::params::from_core;
    use nemm_core::testing::example_model;
    use nemm_core::ModelKind;

    #[test]
    fn penalty_of_constant_scalers_is_the_margin_and_random_ones_violate() {
        let device = Device::flex().autodiff();
        let m = example_model(ModelKind::Nemm, 8, 3).expect("model");
        let mut p: RolloutParams<f32> = from_core(&m).expect("emm");
        let (net, frame) = EmmNet::from_rollout(&p, None, &device);
        let random = physics_loss(&net, &frame, &PenaltyGrid::default(), &device)
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .unwrap_or_default()[0];
        // Random weights violate monotonicity somewhere.
        assert!(random > 0.0);
        let a = audit(&m, 101, 21);
        assert!(a.total_violations() > 0, "{a:?}");
        // Output weights zero: every scaler is the constant 1, which is monotone.
        for s in [&mut p.b_fl, &mut p.b_pr, &mut p.k_pr]
            .into_iter()
            .flatten()
        {
            let h = s.hidden;
            let n = s.w.len();
            for w in &mut s.w[n - h - 1..n - 1] {
                *w = 0.0;
            }
        }
        let (net, frame) = EmmNet::from_rollout(&p, None, &device);
        let flat = physics_loss(&net, &frame, &PenaltyGrid::default(), &device)
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .unwrap_or_default()[0];
        // Constant scalers are monotone (the audit finds nothing) but do not fall with alpha:
        // each of the three alpha terms costs the margin squared.
        let margin2 = f64::from(ALPHA_MARGIN).powi(2);
        assert!(
            (f64::from(flat) - 3.0 * margin2).abs() < 1e-3 * margin2,
            "{flat}"
        );
        let model = crate::train::params::to_core(&p, m.meta).expect("valid");
        assert_eq!(audit(&model, 101, 21).total_violations(), 0);
        assert_eq!(audit(&model, 101, 21).describe(), "");
    }

    #[test]
    fn the_description_names_each_violated_condition() {
        let c = |violations, worst| ConditionAudit {
            checked: 400,
            violations,
            worst,
        };
        let a = Audit {
            b_fl: Some(ScalerAudit {
                state: Some(c(37, 0.2051)),
                alpha: c(0, 0.0),
            }),
            b_pr: Some(ScalerAudit {
                state: None,
                alpha: c(2, 0.01),
            }),
            k_pr: Some(ScalerAudit {
                state: Some(c(0, 0.0)),
                alpha: c(0, 0.0),
            }),
        };
        assert_eq!(
            a.describe(),
            "the flow force b_fl v_st rising with v_st: 37 of 400 points (worst slope -0.205); \
             b_pr in its declared direction in alpha: 2 of 400 points"
        );
        assert_eq!(a.total_violations(), 39);
    }

    #[test]
    fn violations_are_decided_beyond_f32_rounding_only() {
        let ulp = f64::from(f32::EPSILON);
        // A flat coefficient: one ulp up over a grid step of 0.01 is rounding, not a violation
        // (its difference quotient, 1.2e-5, exceeds a fixed 1e-5 threshold).
        assert_eq!(violation(1.0, 1.0 + ulp, 0.01, false), None);
        assert_eq!(violation(1.0 + ulp, 1.0, 0.01, true), None);
        // A real increase with alpha / decrease in the state is one, with its derivative.
        let d = violation(1.0, 1.001, 0.01, false).unwrap();
        assert!((d - 0.1).abs() < 1e-9);
        assert!(violation(0.5, 0.4, 0.1, true).is_some());
        // The right direction never is, however large.
        assert_eq!(violation(1.0, 0.5, 0.01, false), None);
        assert_eq!(violation(0.5, 1.0, 0.01, true), None);
        // Tiny derivatives of large values: below the rounding floor.
        assert_eq!(violation(1e3, 1e3 + 1e-4, 1.0, false), None);
        // A failed evaluation (NaN) is not counted as a violation.
        assert_eq!(violation(f64::NAN, 1.0, 0.01, false), None);
    }
}
