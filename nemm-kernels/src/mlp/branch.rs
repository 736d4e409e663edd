//! The alpha branch: a scaler's dependence on the condition level `alpha`, monotone in a
//! declared direction by construction (the second conditions of eqs. 31, 37 and 38).
//!
//! A scaler with a branch computes its raw output as
//!
//! ```text
//! z(x, alpha_n) = f(x) + sum_k v_k leaky_relu(r_k x + u_k alpha_n + c_k)
//! v_k = theta_v,k^2 >= 0,      u_k = d theta_u,k^2,      d = +1 (increasing) or -1 (decreasing)
//! ```
//!
//! where `f` is the scaler's MLP with its alpha input column at zero (so `f` does not see
//! `alpha`), `x` the normalised state input (absent for `b_pr`, whose only input is
//! `alpha`) and `alpha_n = alpha / alpha_scale`. Every term of the sum has
//! `d/dalpha_n = v_k leaky_relu'(.) u_k`, with the sign of `d` or zero, so `z` is monotone in
//! `alpha` in the direction `d` at every state; the bounded output mapping
//! `s_min + (s_max - s_min) sigmoid(z)` is increasing in `z`, so the coefficient is too.
//! The construction holds in `f32` as well: every operation (fused multiply-add with a
//! non-negative factor, LeakyReLU, addition, the sigmoid) is monotone non-decreasing in
//! its argument under IEEE rounding.
//!
//! # Parameter layout
//!
//! With `K` = `units` and `s` = `state_inputs` (0 or 1):
//!
//! ```text
//! r (K s), theta_u (K), c (K), theta_v (K)
//! ```
//!
//! # Exact arithmetic of [`AlphaBranch::raw`]
//!
//! ```text
//! t_k = fma(r_k, x, fma(u_k, alpha_n, c_k))        (t_k = fma(u_k, alpha_n, c_k) without state)
//! z   = fma-chain from 0 over v_k leaky_relu(t_k), k ascending
//! ```

use super::{leaky_relu, BranchLayout};
pub use crate::error::BranchError;
pub use crate::limits::MAX_BRANCH_UNITS;
use crate::math::{self, MulAdd};
use serde::{Deserialize, Serialize};

/// Parameter capacity of an alpha branch (`K = 32` with a state input).
pub const BRANCH_CAPACITY: usize = 4 * MAX_BRANCH_UNITS;

/// Direction of a monotonicity prior of a coefficient in `alpha`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    /// The coefficient must not increase with `alpha` (the paper's oil loss).
    #[default]
    Decreasing,
    /// The coefficient must not decrease with `alpha`.
    Increasing,
    /// No prior in `alpha`.
    None,
}

impl Direction {
    /// `-1` (decreasing), `+1` (increasing), `0` (none).
    pub const fn sign(self) -> f32 {
        match self {
            Direction::Decreasing => -1.0,
            Direction::Increasing => 1.0,
            Direction::None => 0.0,
        }
    }

    /// The manifest / report name: `decreasing`, `increasing`, `none`.
    pub const fn name(self) -> &'static str {
        match self {
            Direction::Decreasing => "decreasing",
            Direction::Increasing => "increasing",
            Direction::None => "none",
        }
    }
}

impl core::str::FromStr for Direction {
    type Err = crate::error::UnknownName;

    /// Parses [`Direction::name`]'s spelling.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        [
            Direction::Decreasing,
            Direction::Increasing,
            Direction::None,
        ]
        .into_iter()
        .find(|d| d.name() == s)
        .ok_or(crate::error::UnknownName {
            what: "monotonicity direction",
            expected: "decreasing, increasing or none",
        })
    }
}

/// Number of parameters of a branch with `units` units and `state_inputs` state inputs.
pub const fn branch_param_count(state_inputs: usize, units: usize) -> usize {
    BranchLayout {
        state_inputs,
        units,
    }
    .len()
}

/// The alpha branch of a scaler (module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlphaBranch {
    /// Direction `d` of the coefficient in `alpha` (increasing or decreasing).
    pub direction: Direction,
    /// State inputs `s` (1 for `b_fl`, `k_pr`; 0 for `b_pr`).
    pub state_inputs: u8,
    /// Units `K` (1..=[`MAX_BRANCH_UNITS`]).
    pub units: u8,
    /// Parameters in the layout of the module docs.
    pub params: heapless::Vec<f32, BRANCH_CAPACITY>,
}

/// The per-unit weights of a branch, borrowed.
#[derive(Debug, Clone, Copy)]
pub struct BranchView<'a> {
    /// State weights `r_k` (empty without a state input).
    pub r: &'a [f32],
    /// `theta_u,k` (`u_k = d theta_u,k^2`).
    pub theta_u: &'a [f32],
    /// Biases `c_k`.
    pub c: &'a [f32],
    /// `theta_v,k` (`v_k = theta_v,k^2`).
    pub theta_v: &'a [f32],
}

impl AlphaBranch {
    /// Builds from dimensions and parameters, checking them.
    pub fn new(
        direction: Direction,
        state_inputs: u8,
        units: u8,
        params: &[f32],
    ) -> Result<Self, BranchError> {
        let expected = branch_param_count(state_inputs as usize, units as usize);
        let mut v = heapless::Vec::new();
        v.extend_from_slice(params)
            .map_err(|_| BranchError::ParamCountMismatch {
                expected,
                found: params.len(),
            })?;
        let b = Self {
            direction,
            state_inputs,
            units,
            params: v,
        };
        b.check()?;
        Ok(b)
    }

    /// Checks dimensions, parameter count, finiteness and direction.
    pub fn check(&self) -> Result<(), BranchError> {
        let (s, k) = (self.state_inputs as usize, self.units as usize);
        if s > 1 || !(1..=MAX_BRANCH_UNITS).contains(&k) {
            return Err(BranchError::DimensionOutOfRange);
        }
        let expected = branch_param_count(s, k);
        if self.params.len() != expected {
            return Err(BranchError::ParamCountMismatch {
                expected,
                found: self.params.len(),
            });
        }
        if self.params.iter().any(|p| !p.is_finite()) {
            return Err(BranchError::NonFinite);
        }
        if self.direction == Direction::None {
            return Err(BranchError::NoDirection);
        }
        Ok(())
    }

    /// The layout of the parameters ([`BranchLayout`]).
    pub fn layout(&self) -> BranchLayout {
        BranchLayout {
            state_inputs: self.state_inputs as usize,
            units: self.units as usize,
        }
    }

    /// The weights by role, or `None` if the shape is inconsistent.
    pub fn view(&self) -> Option<BranchView<'_>> {
        let layout = self.layout();
        let r = layout.ranges()?;
        let p: &[f32] = &self.params;
        (p.len() == layout.len()).then_some(())?;
        Some(BranchView {
            r: p.get(r.r)?,
            theta_u: p.get(r.theta_u)?,
            c: p.get(r.c)?,
            theta_v: p.get(r.theta_v)?,
        })
    }

    /// The branch's contribution to the raw output at normalised state `x` (ignored
    /// without a state input) and normalised `alpha_n` (module docs' arithmetic); 0 for an
    /// inconsistent shape.
    pub fn raw(&self, x: f32, alpha_n: f32) -> f32 {
        let mut bias = [0.0f32; MAX_BRANCH_UNITS];
        let layout = self.layout();
        super::pass::fold_branch::<math::Fused, f32>(
            layout,
            &self.params,
            self.direction,
            alpha_n,
            &mut bias,
        )
        .and_then(|()| {
            super::pass::branch_raw::<math::Fused, f32>(layout, &self.params, &bias, x, None)
        })
        .filter(|_| self.params.len() == layout.len())
        .unwrap_or(0.0)
    }
}

/// A branch folded for a fixed `alpha` and one state input scaled by `1 / u_scale`: per
/// unit `t_k = fma(r_k / u_scale, u, bias_k)` with `bias_k = fma(u_k / alpha_scale, alpha,
/// c_k)` ([`CompiledBranch::set_alpha`]).
#[derive(Debug, Clone)]
pub struct CompiledBranch {
    units: usize,
    /// `r_k / u_scale` (zeros without a state input).
    r: [f32; MAX_BRANCH_UNITS],
    /// `bias_k` at the current `alpha`.
    bias: [f32; MAX_BRANCH_UNITS],
    /// `v_k = theta_v,k^2`.
    v: [f32; MAX_BRANCH_UNITS],
    /// `u_k / alpha_scale`.
    u: [f32; MAX_BRANCH_UNITS],
    /// `c_k`.
    c: [f32; MAX_BRANCH_UNITS],
}

impl CompiledBranch {
    /// Folds `b` for state scale `u_scale`, `alpha` and `alpha_scale`; `None` for an
    /// inconsistent shape.
    pub fn compile(b: &AlphaBranch, u_scale: f32, alpha: f32, alpha_scale: f32) -> Option<Self> {
        b.check().ok()?;
        let view = b.view()?;
        let d = b.direction.sign();
        let mut cb = Self {
            units: b.units as usize,
            r: [0.0; MAX_BRANCH_UNITS],
            bias: [0.0; MAX_BRANCH_UNITS],
            v: [0.0; MAX_BRANCH_UNITS],
            u: [0.0; MAX_BRANCH_UNITS],
            c: [0.0; MAX_BRANCH_UNITS],
        };
        for (k, ((&tu, &c), &tv)) in view
            .theta_u
            .iter()
            .zip(view.c)
            .zip(view.theta_v)
            .enumerate()
        {
            if let Some(r) = cb.r.get_mut(k) {
                *r = view.r.get(k).map_or(0.0, |&r| r / u_scale);
            }
            if let (Some(u), Some(cc), Some(v)) =
                (cb.u.get_mut(k), cb.c.get_mut(k), cb.v.get_mut(k))
            {
                *u = d * (tu * tu) / alpha_scale;
                *cc = c;
                *v = tv * tv;
            }
        }
        cb.set_alpha(alpha);
        Some(cb)
    }

    /// Re-folds `alpha` (in the units of compile time, before normalisation) into the
    /// biases: `K` fused multiply-adds.
    pub fn set_alpha(&mut self, alpha: f32) {
        for ((b, &u), &c) in self.bias.iter_mut().zip(&self.u).zip(&self.c) {
            *b = math::fma(u, alpha, c);
        }
    }

    /// The contribution to `z` at state `u` (SI units); with `TRACK` the signs of the
    /// LeakyReLU inputs are hashed into `pattern` as [`super::CompiledScaler`] does.
    #[inline(always)]
    pub fn raw<const TRACK: bool, M: MulAdd>(&self, u: f32, pattern: &mut u64) -> f32 {
        let k = self.units.min(MAX_BRANCH_UNITS);
        let mut z = 0.0f32;
        for ((&r, &b), &v) in self.r.iter().zip(&self.bias).zip(&self.v).take(k) {
            let t = M::mul_add(r, u, b);
            if TRACK {
                *pattern = (*pattern ^ u64::from(t >= 0.0)).wrapping_mul(0x0000_0100_0000_01b3);
            }
            z = M::mul_add(v, leaky_relu(t), z);
        }
        z
    }

    /// Units `K`.
    pub fn units(&self) -> usize {
        self.units
    }
}
