//! The equivalent mechanical model (EMM): right-hand side and output force, eqs. 15-17
//! (constant parameters) and 20-21 (neural parameters).
//!
//! # Elements and states
//!
//! - input `u = xdot_da` \[m/s\]: stroke velocity of the damper (positive = extension).
//! - `k_pr` \[N/m\] and `b_pr` \[N s/m\]: pressure-force stiffness and damping, **in parallel**;
//!   their deflection is `x_pr` \[m\] (state 1).
//! - `b_fl` \[N s/m\]: flow damping, **in series** with the pressure pair, evaluated at the
//!   quasi-static valve velocity `v_st` \[m/s\] (state 2).
//! - `T_pr` \[s\]: first-order valve lag between the velocity across the flow element and
//!   `v_st` (eq. 15).
//!
//! # Derivation (why the second row uses `b_pr`, as in eq. 16, not `b_fl` as printed in eq. 20)
//!
//! The series connection carries one force `F` through both branches. Let
//! `q = xdot_da - xdot_pr` be the velocity across the flow element. Then
//!
//! ```text
//! pressure pair:  F = k_pr x_pr + b_pr xdot_pr
//! flow element:   F = b_fl q = b_fl (u - xdot_pr)
//! ```
//!
//! Equating gives `xdot_pr = (b_fl u - k_pr x_pr) / (b_pr + b_fl)` (row 1 of eqs. 16/20) and
//!
//! ```text
//! q = u - xdot_pr = (k_pr x_pr + b_pr u) / (b_pr + b_fl)
//! ```
//!
//! Eq. 15 lags `q`: `T_pr vdot_st + v_st = q`, so
//!
//! ```text
//! vdot_st = -v_st / T_pr + k_pr x_pr / (T_pr (b_pr + b_fl)) + b_pr u / (T_pr (b_pr + b_fl))
//! ```
//!
//! The input term carries **`b_pr`**: eq. 16 is right and the `b_NN,fl` printed in the last
//! term of eq. 20 is a typo: with it, the steady state under a constant stroke velocity `u`
//! (where `xdot_pr = 0`, so `k_pr x_pr = b_fl u`) would be `v_st = 2 b_fl u / (b_pr + b_fl)`
//! instead of the flow velocity `u` the lag is meant to follow. The force is the series force
//!
//! ```text
//! F = b_fl q = k_pr b_fl x_pr / (b_pr + b_fl) + b_pr b_fl u / (b_pr + b_fl)     (eq. 17 / 21)
//! ```
//!
//! (friction `r(x_da)` is neglected, as in the paper). The implementation computes the shared
//! quantity `q` once:
//!
//! ```text
//! q        = (k_pr x_pr + b_pr u) / (b_pr + b_fl)      computed as  fma(k_pr, x_pr, b_pr * u) / (b_pr + b_fl)
//! xdot_pr  = u - q
//! vdot_st  = (q - v_st) * (1 / T_pr)
//! F        = b_fl * q
//! ```
//!
//! With constant parameters the eigenvalues are `-k_pr / (b_pr + b_fl)` and `-1 / T_pr`, so
//! the fastest time constant is `min((b_pr + b_fl) / k_pr, T_pr)` (see
//! nemm-core's `Model::fastest_time_constant_s`).

use crate::math::{Fused, Lane, MulAdd};
use serde::{Deserialize, Serialize};

/// Constant EMM parameters, the `*_ini` values of eq. 19 (or the whole model for the Linear
/// EMM).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EmmConstants {
    /// Flow damping `b_fl,ini` \[N s/m\], > 0.
    pub b_fl_ns_per_m: f32,
    /// Pressure-force damping `b_pr,ini` \[N s/m\], > 0.
    pub b_pr_ns_per_m: f32,
    /// Pressure-force stiffness `k_pr,ini` \[N/m\], > 0.
    pub k_pr_n_per_m: f32,
    /// Valve lag time constant `T_pr` \[s\], > 0.
    pub t_pr_s: f32,
}

/// EMM state `[x_pr, v_st]`, one `f32` in the estimator or packed [`Lane`]s in the trainer
/// (then also the adjoint of a state).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct State<L = f32> {
    /// Deflection of the pressure-force pair `x_pr` \[m\].
    pub x_pr_m: L,
    /// Quasi-static valve velocity `v_st` \[m/s\].
    pub v_st_m_s: L,
}

impl State {
    /// Both components finite.
    #[inline]
    pub fn is_finite(&self) -> bool {
        self.x_pr_m.is_finite() && self.v_st_m_s.is_finite()
    }
}

impl<L: Lane> State<L> {
    /// `a * k + self` per component with the multiply-add `M` (an RK stage update).
    #[inline(always)]
    pub fn axpy<M: MulAdd>(&self, a: L, k: &Self) -> Self {
        State {
            x_pr_m: M::mul_add(a, k.x_pr_m, self.x_pr_m),
            v_st_m_s: M::mul_add(a, k.v_st_m_s, self.v_st_m_s),
        }
    }

    /// Component-wise `f(self, o)`.
    #[inline(always)]
    pub fn zip(&self, o: &Self, f: impl Fn(L, L) -> L) -> Self {
        State {
            x_pr_m: f(self.x_pr_m, o.x_pr_m),
            v_st_m_s: f(self.v_st_m_s, o.v_st_m_s),
        }
    }

    /// Both components times `a`.
    #[inline(always)]
    pub fn scale(&self, a: L) -> Self {
        State {
            x_pr_m: a * self.x_pr_m,
            v_st_m_s: a * self.v_st_m_s,
        }
    }
}

/// Parameter values at one state: `b_fl(v_st)`, `k_pr(x_pr)` and `b_pr` (all physical
/// units); in the adjoint, the derivatives of the loss with respect to them.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Coefficients<L = f32> {
    /// `b_fl` \[N s/m\].
    pub b_fl: L,
    /// `b_pr` \[N s/m\].
    pub b_pr: L,
    /// `k_pr` \[N/m\].
    pub k_pr: L,
}

/// Velocity across the flow element, `q = (k_pr x_pr + b_pr u) / (b_pr + b_fl)` \[m/s\].
#[inline(always)]
pub fn flow_velocity(c: &Coefficients, x_pr: f32, u: f32) -> f32 {
    flow_velocity_with::<Fused, f32>(c, x_pr, u)
}

/// [`flow_velocity`] with the multiply-add `M`, on any lane type.
#[inline(always)]
pub fn flow_velocity_with<M: MulAdd, L: Lane>(c: &Coefficients<L>, x_pr: L, u: L) -> L {
    M::mul_add(c.k_pr, x_pr, c.b_pr * u) / (c.b_pr + c.b_fl)
}

/// Reverse mode of [`flow_velocity_with`]: given `qbar = dL/dq` and the value `q`, adds
/// `dL/d(coefficients)` to `cbar` and returns `dL/dx_pr`.
#[inline(always)]
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub fn flow_velocity_backward<L: Lane>(
    c: &Coefficients<L>,
    x_pr: L,
    u: L,
    q: L,
    qbar: L,
    cbar: &mut Coefficients<L>,
) -> L {
    let den = c.b_pr + c.b_fl;
    let numbar = qbar / den;
    let denbar = -qbar * q / den;
    cbar.k_pr = cbar.k_pr + numbar * x_pr;
    cbar.b_pr = cbar.b_pr + (numbar * u + denbar);
    cbar.b_fl = cbar.b_fl + denbar;
    numbar * c.k_pr
}

/// State derivative `[xdot_pr, vdot_st]` (eq. 16 with the parameters of `c`; `inv_t_pr` is
/// `1 / T_pr` in 1/s).
#[inline(always)]
pub fn rhs(c: &Coefficients, inv_t_pr: f32, s: &State, u: f32) -> State {
    rhs_with::<Fused, f32>(c, inv_t_pr, s, u)
}

/// [`rhs`] with the multiply-add `M`, on any lane type.
#[inline(always)]
pub fn rhs_with<M: MulAdd, L: Lane>(
    c: &Coefficients<L>,
    inv_t_pr: L,
    s: &State<L>,
    u: L,
) -> State<L> {
    let q = flow_velocity_with::<M, L>(c, s.x_pr_m, u);
    State {
        x_pr_m: u - q,
        v_st_m_s: (q - s.v_st_m_s) * inv_t_pr,
    }
}

/// Reverse mode of [`rhs_with`] (the unfused `M = Unfused` form; with fused multiply-adds
/// it differs by rounding only): given `kbar = dL/d(rhs)`, adds `dL/ds` to `sbar`,
/// `dL/d(coefficients)` to `cbar` and `dL/d(inv_t_pr)` to `itbar`.
#[inline(always)]
#[allow(clippy::too_many_arguments)] // the inputs of `rhs_with` and their three adjoints
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub fn rhs_backward<M: MulAdd, L: Lane>(
    c: &Coefficients<L>,
    inv_t_pr: L,
    s: &State<L>,
    u: L,
    kbar: &State<L>,
    sbar: &mut State<L>,
    cbar: &mut Coefficients<L>,
    itbar: &mut L,
) {
    let q = flow_velocity_with::<M, L>(c, s.x_pr_m, u);
    let qbar = inv_t_pr * kbar.v_st_m_s - kbar.x_pr_m;
    sbar.v_st_m_s = sbar.v_st_m_s - inv_t_pr * kbar.v_st_m_s;
    *itbar = *itbar + (q - s.v_st_m_s) * kbar.v_st_m_s;
    let xbar = flow_velocity_backward(c, s.x_pr_m, u, q, qbar, cbar);
    sbar.x_pr_m = sbar.x_pr_m + xbar;
}

/// Damper force `F = b_fl q` \[N\] (eq. 17/21), positive in tension (rebound).
#[inline(always)]
pub fn force(c: &Coefficients, s: &State, u: f32) -> f32 {
    force_with::<Fused, f32>(c, s, u)
}

/// [`force`] with the multiply-add `M`, on any lane type.
#[inline(always)]
pub fn force_with<M: MulAdd, L: Lane>(c: &Coefficients<L>, s: &State<L>, u: L) -> L {
    c.b_fl * flow_velocity_with::<M, L>(c, s.x_pr_m, u)
}

/// Reverse mode of [`force_with`]: given `fbar = dL/dF`, adds `dL/ds` to `sbar` and
/// `dL/d(coefficients)` to `cbar`; returns `F`.
#[inline(always)]
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub fn force_backward<M: MulAdd, L: Lane>(
    c: &Coefficients<L>,
    s: &State<L>,
    u: L,
    fbar: L,
    sbar: &mut State<L>,
    cbar: &mut Coefficients<L>,
) -> L {
    let q = flow_velocity_with::<M, L>(c, s.x_pr_m, u);
    cbar.b_fl = cbar.b_fl + fbar * q;
    let xbar = flow_velocity_backward(c, s.x_pr_m, u, q, fbar * c.b_fl, cbar);
    sbar.x_pr_m = sbar.x_pr_m + xbar;
    c.b_fl * q
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rhs_and_force_by_hand() {
        // k = 1000, b_pr = 300, b_fl = 100, T = 0.01; x = 0.002, v = 0.1, u = 0.5
        // q = (2 + 150) / 400 = 0.38; xdot = 0.12; vdot = (0.38 - 0.1) * 100 = 28; F = 38
        let c = Coefficients {
            b_fl: 100.0,
            b_pr: 300.0,
            k_pr: 1000.0,
        };
        let s = State {
            x_pr_m: 0.002,
            v_st_m_s: 0.1,
        };
        let d = rhs(&c, 100.0, &s, 0.5);
        assert!((d.x_pr_m - 0.12).abs() < 1e-6);
        assert!((d.v_st_m_s - 28.0).abs() < 1e-4);
        assert!((force(&c, &s, 0.5) - 38.0).abs() < 1e-4);
        // Paper form of eq. 16, row 2, and eq. 17:
        let den = 400.0f32;
        let vdot = -0.1 / 0.01 + 1000.0 * 0.002 / (0.01 * den) + 300.0 * 0.5 / (0.01 * den);
        assert!((d.v_st_m_s - vdot).abs() < 1e-3);
        let f = 1000.0 * 100.0 / den * 0.002 + 300.0 * 100.0 / den * 0.5;
        assert!((force(&c, &s, 0.5) - f).abs() < 1e-4);
    }

    #[test]
    fn steady_state_under_constant_velocity() {
        // At equilibrium xdot_pr = 0 and v_st = u: k x = b_fl u, F = b_fl u.
        let c = Coefficients {
            b_fl: 2000.0,
            b_pr: 500.0,
            k_pr: 4e5,
        };
        let u = 0.3;
        let s = State {
            x_pr_m: 2000.0 * u / 4e5,
            v_st_m_s: u,
        };
        let d = rhs(&c, 1.0 / 0.003, &s, u);
        assert!(d.x_pr_m.abs() < 1e-6 && d.v_st_m_s.abs() < 1e-3, "{d:?}");
        assert!((force(&c, &s, u) - 600.0).abs() < 1e-2);
    }
}
