//! Rollout of the (N)EMM over measured windows and its exact discrete adjoint.
//!
//! burn's autodiff tape costs 7-80 ms per RK step of this model (quadratic backward in the
//! number of recorded ops), so the 10 kHz rollout is differentiated here by hand: the forward
//! sweep stores the state after every sample; the reverse sweep recomputes each step's RK
//! stages from the stored state (with the MLP activations) and back-propagates through the
//! output force, the RK stages, the right-hand side, the scalers, LayerNorm and LeakyReLU.
//! The result is the exact gradient of the discrete loss (up to rounding), checked against
//! central finite differences and burn's autodiff in the tests.
//!
//! # Semantics (identical to `nemm_core::Estimator` at the model step)
//!
//! - the model integrates at its own step [`RolloutParams::dt`], not at the data's: a
//!   window's samples are mapped onto the model grid by [`Grid`] (input linearly
//!   interpolated between samples, output linearly interpolated at the sample times); at
//!   equal rates this is the identity;
//! - state at rest and previous input 0 before the first model step;
//! - model step `n`: one RK step from `(s_{n-1}, u_{n-1})` to `(s_n, u_n)` with linear input
//!   interpolation (`u_m = 0.5 (u_{n-1} + u_n)`), then `y_n = F(s_n, u_n)`;
//! - a condition level changing within a window ([`Window::alphas`]) is re-folded before
//!   the step that uses it, with the coefficients at the step's start state re-evaluated
//!   (`nemm_core::Estimator::set_alpha`); the whole step runs at the new level;
//! - the EMM right-hand side and force (`nemm_kernels::emm`), the RK step
//!   (`nemm_kernels::integrator::step_with`) and the scalers (MLP and alpha branch,
//!   `nemm_kernels::mlp::ScalerView::raw`, with the bounded output mapping `mlp::bounded`) are
//!   nemm-core's own generic definitions, run here over [`Lanes`] of `LANES` windows with
//!   unfused multiply-adds; their reverse modes (`rhs_backward`, `force_backward`,
//!   `step_backward`, `ScalerView::raw_backward`, `bounded_backward`) sit next to them in
//!   nemm-core, as does the weight layout (`mlp::ScalerLayout`). This module keeps the
//!   packing, the activation records, the loss and the sweeps. The parity test bounds the
//!   difference to the estimator's fused arithmetic.
//!
//! # Batching
//!
//! Windows are processed in packs of `LANES` that advance in lock step, so every weight is
//! loaded once per pack and the inner loops vectorise across the lanes; packs run in
//! parallel (rayon). Lanes that pad the last pack have zero loss weight.
//!
//! # Loss
//!
//! `L = (1 / M) sum_{windows} sum_{k >= warmup} ((y(t_k) - F_k) / F_scale)^2` over the data
//! samples `k` (`y(t_k)` the model force at the sample time, [`Grid`]) with `M` the number
//! of scored samples: the normalised MSE of eq. 23. The forward sweep keeps the force of
//! every model step, the loss and its adjoint per model step are formed at the samples, and
//! the reverse sweep back-propagates from the model steps that a sample touches.

// The lane loops (`for k in 0..LANES`) index several lane arrays in lock step; written as
// plain index loops they vectorise reliably, which iterator chains over 3-4 arrays do not.
#![allow(clippy::needless_range_loop)]

use nemm_kernels::emm::{self, Coefficients, State};
use nemm_kernels::integrator::{self, Stage, StageBackward, StepSize};
use nemm_kernels::lost_motion::{LostMotionAt, LOST_MOTION_PARAMS};
use nemm_kernels::math::{Lane, Lanes, MulAdd, Scalar, Unfused};
use nemm_kernels::mlp::{self, Direction};
use nemm_kernels::static_force::{self, STATIC_PARAMS};
use num_traits::Float;
use std::fmt::Debug;
use std::ops::{AddAssign, DivAssign};

/// Number of windows advanced in lock step.
pub(crate) const LANES: usize = 8;

/// Floating-point type of a rollout (`f32` for training, `f64` for gradient checks).
pub trait Real:
    Float + Scalar + AddAssign + DivAssign + Send + Sync + Debug + Default + 'static
{
    /// From `f64`.
    fn c(v: f64) -> Self;
}
impl Real for f32 {
    #[inline(always)]
    fn c(v: f64) -> Self {
        v as f32
    }
}
impl Real for f64 {
    #[inline(always)]
    fn c(v: f64) -> Self {
        v
    }
}

/// The lane type of a pack: one value per window (nemm-core's [`Lanes`]).
type WindowLanes<T> = Lanes<T, LANES>;

mod params;
mod rollout;

pub use params::{Grid, RolloutParams, Window};

pub(crate) use params::{BranchShape, CumulativeShape, RolloutGrads, ScalerWeights, StaticParams};
pub use rollout::{loss_and_grad, simulate};
pub(crate) use rollout::{loss_and_grad_paired, simulate_x_pr, Pairing};
