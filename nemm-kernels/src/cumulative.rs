//! The cumulative scaler: a scale factor whose force is monotone in the state **by
//! construction** (the first conditions of eqs. 30-31 and 37-38: the flow force `b_fl v_st`
//! rising with `v_st`, the spring force `k_pr x_pr` rising with `x_pr`), bounded like the
//! MLP scaler of [`crate::mlp`] and monotone in `alpha` in a declared direction.
//!
//! # The construction
//!
//! The prior asks for `d(x s(x))/dx >= 0` at every normalised state `x`, not for `s` to be
//! monotone: a digressive valve (falling `b_fl`) and a friction-like force (`b_fl ~ 1/|v|`)
//! must stay representable. The scale is the running mean of a bounded positive
//! *incremental* scale `q`:
//!
//! ```text
//! q(u)  = s_min + (s_max - s_min) (pi_0 + sum_k pi_k sech^2(w_k u + c_k))
//! s(x)  = (1/x) integral_0^x q(u) du
//!       = s_min + (s_max - s_min) (pi_0 + sum_k pi_k h(w_k x, c_k)),
//! h(y, c) = (tanh(y + c) - tanh(c)) / y,       h(0, c) = sech^2(c)
//! ```
//!
//! so that `x s(x) = integral_0^x q` and `d(x s)/dx = q(x) >= s_min > 0`: the force rises
//! with the state for **every value of the weights**, between any grid points, and the
//! integral is closed-form (no quadrature, which would not keep the guarantee between its
//! nodes). In `f32` with the exact `libm` backend the computed force rises strictly on a
//! dense grid for random weights (tested); the `micromath` backend's `exp` approximation
//! is not monotone to the last bits, so with it the force rises up to that error. `h` is the mean of `sech^2` over `[c, c + y]`, in `(0, 1]`, so with `pi_j >= 0`
//! and `sum_j pi_j < 1` the scale keeps the MLP scaler's bounds `s_min < s < s_max`, and
//! with them the stability bound of the model's step.
//!
//! The weights of the mixture depend on the condition level `alpha_n` through gates:
//!
//! ```text
//! p      = softmax(a_0, .., a_K, 0)        (the last logit, fixed at 0, is the slack)
//! g_j    = sigmoid(beta_j + u_j alpha_n),  u_j = d gamma_j^2  (d = +1 or -1), gamma_j (none)
//! pi_j   = p_j g_j,                        j = 0 (the constant part), 1..K (the units)
//! w_k    = exp(omega_k)
//! ```
//!
//! Every `pi_j` moves with `alpha_n` in the declared direction `d` and `h` does not depend
//! on it, so the coefficient is monotone in `alpha` in that direction at every state, as the
//! MLP scaler's alpha branch makes it ([`crate::mlp::AlphaBranch`]).
//!
//! # Parameter layout
//!
//! With `K` = `units`, flat, in this order:
//!
//! ```text
//! a (K + 1), omega (K), c (K), gamma (K + 1), beta (K + 1)         5 K + 3 values
//! ```
//!
//! # Arithmetic
//!
//! `tanh(v) = 1 - 2 / (exp(2 v) + 1)` (saturates to `+-1` without overflow; every `exp`
//! argument is clamped to `+-80`), and
//! `h(y, c) = (tanh(y) / y) (1 - tanh(y + c) tanh(c))` (the identity `tanh a - tanh b =
//! tanh(a - b) (1 - tanh a tanh b)`), with `tanh(y) / y` by its Taylor series for
//! `|y| < 0.1`: no cancellation near `x = 0`. The reverse mode
//! (`CumulativeFold::mixture_backward`,
//! feature `reverse`) uses the series of the difference quotients for `|y| < 0.01`.

pub use crate::error::CumulativeError;
use crate::math::Lane;
use crate::mlp::Direction;
use serde::{Deserialize, Serialize};

/// Largest number of units `K` of a cumulative scaler.
pub const MAX_CUMULATIVE_UNITS: usize = 16;

/// Number of parameters of a cumulative scaler with `units` units: `5 K + 3`.
pub const fn cumulative_param_count(units: usize) -> usize {
    5 * units + 3
}

/// Parameter capacity of the largest cumulative scaler.
pub const CUMULATIVE_CAPACITY: usize = cumulative_param_count(MAX_CUMULATIVE_UNITS);

/// Below this `|y|`, `tanh(y) / y` is evaluated by its series.
const SERIES_Y: f32 = 0.1;
/// Below this `|y|`, the reverse mode's difference quotients use their series.
#[cfg(feature = "reverse")]
const SERIES_D: f32 = 0.01;

/// The parameters of a cumulative scaler, split into their groups (module docs).
#[derive(Debug, Clone, Copy)]
pub struct CumulativeView<'a, S> {
    /// Logits `a_0` (constant part) and `a_1..a_K` (units), `K + 1`.
    pub a: &'a [S],
    /// Log widths `omega_k`, `K`.
    pub omega: &'a [S],
    /// Centres `c_k`, `K`.
    pub c: &'a [S],
    /// Gate slopes `gamma_j`, `K + 1`.
    pub gamma: &'a [S],
    /// Gate biases `beta_j`, `K + 1`.
    pub beta: &'a [S],
    /// The declared direction in `alpha`.
    pub direction: Direction,
}

/// A cumulative scaler at a condition level: the mixture weights `pi_j` (per lane), the gates
/// `g_j` and the softmax `p_j` they came from, and per unit `w_k` and `tanh(c_k)`.
#[derive(Debug, Clone)]
pub struct CumulativeFold<L: Lane> {
    units: usize,
    /// `pi_j = p_j g_j`, `j = 0..=K`.
    pi: [L; MAX_CUMULATIVE_UNITS + 1],
    /// `g_j`.
    g: [L; MAX_CUMULATIVE_UNITS + 1],
    /// `p_j`.
    pub(crate) p: [L::Scalar; MAX_CUMULATIVE_UNITS + 1],
    /// `w_k = exp(omega_k)`.
    pub(crate) w: [L::Scalar; MAX_CUMULATIVE_UNITS],
    /// `c_k`.
    pub(crate) c: [L::Scalar; MAX_CUMULATIVE_UNITS],
    /// `tanh(c_k)`.
    pub(crate) tc: [L::Scalar; MAX_CUMULATIVE_UNITS],
    /// `alpha_n` the gates were folded at (read by the reverse mode).
    #[cfg_attr(not(feature = "reverse"), allow(dead_code))]
    alpha_n: L,
}

/// Largest `|argument|` passed to `exp`: the approximations of the `micromath` backend do
/// not take arguments whose result over- or underflows, and every use here saturates long
/// before (`tanh(40) = 1` and `sigmoid(-80) < 2e-35` in `f32`).
const EXP_ARG_LIMIT: f32 = 80.0;

/// `e^v` with `v` clamped to `+-EXP_ARG_LIMIT` (NaN stays NaN).
#[inline(always)]
fn exp_clamped<L: Lane>(v: L) -> L {
    let hi = L::constant(EXP_ARG_LIMIT);
    let v = L::select_nonneg(v - hi, hi, v);
    let v = L::select_nonneg(-hi - v, -hi, v);
    L::exp(v)
}

/// `e^v` of one scalar with `v` clamped to `+-EXP_ARG_LIMIT` (NaN stays NaN).
#[inline(always)]
fn exp_clamped_scalar<S: crate::math::Scalar>(v: S) -> S {
    let hi = S::from_f32(EXP_ARG_LIMIT);
    let v = if v > hi {
        hi
    } else if v < -hi {
        -hi
    } else {
        v
    };
    S::exp(v)
}

/// `tanh(v) = 1 - 2 / (exp(2 v) + 1)`.
#[inline(always)]
pub fn tanh<L: Lane>(v: L) -> L {
    let one = L::constant(1.0);
    one - L::constant(2.0) / (exp_clamped(L::constant(2.0) * v) + one)
}

/// [`tanh`] of one scalar.
#[inline(always)]
fn tanh_scalar<S: crate::math::Scalar>(v: S) -> S {
    let one = S::from_f32(1.0);
    one - S::from_f32(2.0) / (exp_clamped_scalar(S::from_f32(2.0) * v) + one)
}

/// `sigmoid(v) = 1 / (1 + exp(-v))`.
#[inline(always)]
pub(crate) fn sigmoid<L: Lane>(v: L) -> L {
    let one = L::constant(1.0);
    one / (one + exp_clamped(-v))
}

/// `tanh(y) / y`, by its series below `|y| < 0.1` (error below `1e-9`).
#[inline(always)]
fn tanh_ratio<L: Lane>(y: L) -> L {
    let y2 = y * y;
    // 1 - y^2/3 + 2 y^4/15 - 17 y^6/315
    let series = L::constant(1.0)
        + y2 * (L::constant(-1.0 / 3.0)
            + y2 * (L::constant(2.0 / 15.0) + y2 * L::constant(-17.0 / 315.0)));
    // Away from 0 the direct quotient; `y` is not 0 where it is selected.
    let safe_y = L::select_nonneg(y2 - L::constant(SERIES_Y * SERIES_Y), y, L::constant(1.0));
    let direct = tanh(safe_y) / safe_y;
    L::select_nonneg(y2 - L::constant(SERIES_Y * SERIES_Y), direct, series)
}

/// The unit's mean `h(y, c)` of `sech^2` over `[c, c + y]`, given `tanh(c)`; also returns
/// `tanh(y + c)`.
#[inline(always)]
pub(crate) fn unit_mean<L: Lane>(y: L, c: L::Scalar, tc: L::Scalar) -> (L, L) {
    let t1 = tanh(y + L::splat(c));
    let h = tanh_ratio(y) * (L::constant(1.0) - t1 * L::splat(tc));
    (h, t1)
}

impl<'a, S: crate::math::Scalar> CumulativeView<'a, S> {
    /// Splits `params` (the layout of the module docs) for `units` units; `None` if the
    /// length does not match or `units` is 0 or above [`MAX_CUMULATIVE_UNITS`].
    pub fn new(params: &'a [S], units: usize, direction: Direction) -> Option<Self> {
        if units == 0
            || units > MAX_CUMULATIVE_UNITS
            || params.len() != cumulative_param_count(units)
        {
            return None;
        }
        let (a, rest) = params.split_at(units + 1);
        let (omega, rest) = rest.split_at(units);
        let (c, rest) = rest.split_at(units);
        let (gamma, beta) = rest.split_at(units + 1);
        Some(Self {
            a,
            omega,
            c,
            gamma,
            beta,
            direction,
        })
    }

    /// Units `K`.
    pub fn units(&self) -> usize {
        self.omega.len()
    }

    /// The gate's slope `u_j` from `gamma_j`, and `du_j / dgamma_j`.
    #[inline(always)]
    pub(crate) fn gate_slope(&self, gamma: S) -> (S, S) {
        let two = S::from_f32(2.0);
        match self.direction {
            Direction::Increasing => (gamma * gamma, two * gamma),
            Direction::Decreasing => (-(gamma * gamma), -(two * gamma)),
            Direction::None => (gamma, S::from_f32(1.0)),
        }
    }

    /// The scaler at condition level `alpha_n = alpha / alpha_scale` (per lane).
    pub fn fold<L: Lane<Scalar = S>>(&self, alpha_n: L) -> CumulativeFold<L> {
        let k = self.units();
        let mut f = CumulativeFold {
            units: k,
            pi: [L::default(); MAX_CUMULATIVE_UNITS + 1],
            g: [L::default(); MAX_CUMULATIVE_UNITS + 1],
            p: [S::from_f32(0.0); MAX_CUMULATIVE_UNITS + 1],
            w: [S::from_f32(0.0); MAX_CUMULATIVE_UNITS],
            c: [S::from_f32(0.0); MAX_CUMULATIVE_UNITS],
            tc: [S::from_f32(0.0); MAX_CUMULATIVE_UNITS],
            alpha_n,
        };
        // Softmax over the K + 1 logits and the slack's 0, shifted by the largest.
        let zero = S::from_f32(0.0);
        let top = self.a.iter().fold(zero, |m, &v| if v > m { v } else { m });
        let mut total = exp_clamped_scalar(zero - top);
        for (p, &a) in f.p.iter_mut().zip(self.a) {
            *p = exp_clamped_scalar(a - top);
            total = total + *p;
        }
        for p in f.p.iter_mut().take(k + 1) {
            *p = *p / total;
        }
        for (j, (&gamma, &beta)) in self.gamma.iter().zip(self.beta).enumerate() {
            let (u, _) = self.gate_slope(gamma);
            let g = sigmoid(L::fma(L::splat(u), alpha_n, L::splat(beta)));
            if let (Some(gj), Some(pij), Some(&pj)) = (f.g.get_mut(j), f.pi.get_mut(j), f.p.get(j))
            {
                *gj = g;
                *pij = L::splat(pj) * g;
            }
        }
        for (kk, (&om, &c)) in self.omega.iter().zip(self.c).enumerate() {
            if let (Some(w), Some(cc), Some(tc)) =
                (f.w.get_mut(kk), f.c.get_mut(kk), f.tc.get_mut(kk))
            {
                *w = exp_clamped_scalar(om);
                *cc = c;
                *tc = tanh_scalar(c);
            }
        }
        f
    }
}

impl<L: Lane> CumulativeFold<L> {
    /// The mixture `pi_0 + sum_k pi_k h(w_k x, c_k)` in `(0, 1)` at normalised state `x`;
    /// the scale is `s_min + (s_max - s_min)` times it.
    #[inline]
    pub fn mixture(&self, x: L) -> L {
        let mut acc = self.pi.first().copied().unwrap_or_default();
        let units = self
            .w
            .iter()
            .zip(&self.c)
            .zip(&self.tc)
            .zip(self.pi.iter().skip(1));
        for (((&w, &c), &tc), &pi) in units.take(self.units) {
            let (h, _) = unit_mean(L::splat(w) * x, c, tc);
            acc = L::fma(pi, h, acc);
        }
        acc
    }

    /// The scale `s(x) = s_min + (s_max - s_min) mixture(x)`.
    #[inline]
    pub fn scale(&self, x: L, s_min: L::Scalar, s_max: L::Scalar) -> L {
        L::fma(L::splat(s_max - s_min), self.mixture(x), L::splat(s_min))
    }

    /// The incremental scale `q(x) = d(x s)/dx = s_min + (s_max - s_min) (pi_0 + sum_k pi_k
    /// sech^2(w_k x + c_k))`: the slope of the force, at least `s_min`.
    pub fn incremental(&self, x: L, s_min: L::Scalar, s_max: L::Scalar) -> L {
        let one = L::constant(1.0);
        let mut acc = self.pi.first().copied().unwrap_or_default();
        let units = self.w.iter().zip(&self.c).zip(self.pi.iter().skip(1));
        for ((&w, &c), &pi) in units.take(self.units) {
            let t = tanh(L::fma(L::splat(w), x, L::splat(c)));
            acc = L::fma(pi, one - t * t, acc);
        }
        L::fma(L::splat(s_max - s_min), acc, L::splat(s_min))
    }
}

/// A cumulative scaler's weights (module docs), owned: what a model stores for a
/// coefficient whose force is monotone in its state by construction. Its bounds `s_min`,
/// `s_max` are the model's scaler bounds of that coefficient.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CumulativeScaler {
    /// Direction `d` of the coefficient in `alpha` (`None`: gates free in `alpha`).
    pub direction: Direction,
    /// Units `K` (1..=[`MAX_CUMULATIVE_UNITS`]).
    pub units: u8,
    /// Parameters in the layout of the module docs.
    pub params: heapless::Vec<f32, CUMULATIVE_CAPACITY>,
}

impl CumulativeScaler {
    /// Builds from dimensions and parameters, checking them.
    pub fn new(direction: Direction, units: u8, params: &[f32]) -> Result<Self, CumulativeError> {
        let mut v = heapless::Vec::new();
        v.extend_from_slice(params)
            .map_err(|_| CumulativeError::ParamCountMismatch {
                expected: cumulative_param_count(units as usize),
                found: params.len(),
            })?;
        let c = Self {
            direction,
            units,
            params: v,
        };
        c.check()?;
        Ok(c)
    }

    /// Checks the unit count, the parameter count and finiteness.
    pub fn check(&self) -> Result<(), CumulativeError> {
        let k = self.units as usize;
        if !(1..=MAX_CUMULATIVE_UNITS).contains(&k) {
            return Err(CumulativeError::UnitsOutOfRange);
        }
        let expected = cumulative_param_count(k);
        if self.params.len() != expected {
            return Err(CumulativeError::ParamCountMismatch {
                expected,
                found: self.params.len(),
            });
        }
        if self.params.iter().any(|p| !p.is_finite()) {
            return Err(CumulativeError::NonFinite);
        }
        Ok(())
    }

    /// The weights by role, or `None` if the shape is inconsistent.
    pub fn view(&self) -> Option<CumulativeView<'_, f32>> {
        CumulativeView::new(&self.params, self.units as usize, self.direction)
    }

    /// The scale `s(x, alpha_n)` with bounds `s_min`, `s_max` by the reference path (one
    /// fold per call); `None` for an inconsistent shape.
    pub fn scale(&self, x: f32, alpha_n: f32, s_min: f32, s_max: f32) -> Option<f32> {
        Some(self.view()?.fold(alpha_n).scale(x, s_min, s_max))
    }
}

#[cfg(feature = "reverse")]
mod reverse;

#[cfg(test)]
mod tests;
