//! What a rollout is made of: the parameters ([`RolloutParams`]: constants, scalers and their
//! alpha branches, static force), their gradient ([`RolloutGrads`]), the windows it runs on
//! ([`Window`]) and where their samples fall on the model's grid ([`Grid`]).

use super::{mlp, Direction, Real, LOST_MOTION_PARAMS, STATIC_PARAMS};
use nemm_core::{Integrator, Priors};
use nemm_kernels::cumulative;

/// Shape of a scaler's alpha branch (`nemm_kernels::mlp::AlphaBranch`): its weights follow
/// the MLP's in [`ScalerWeights::w`], in nemm-core's branch layout.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BranchShape {
    /// Declared direction in alpha (increasing or decreasing).
    pub direction: Direction,
    /// State inputs (1 for `b_fl`, `k_pr`; 0 for `b_pr`).
    pub(crate) state_inputs: usize,
    /// Units `K`.
    pub units: usize,
}

impl BranchShape {
    /// Number of branch parameters.
    pub fn len(&self) -> usize {
        self.layout().len()
    }

    /// nemm-core's layout of the branch's parameters.
    pub fn layout(&self) -> mlp::BranchLayout {
        mlp::BranchLayout {
            state_inputs: self.state_inputs,
            units: self.units,
        }
    }

    /// True without parameters (never for a valid shape).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Shape of a cumulative scaler (`nemm_kernels::cumulative`): its weights are the whole of
/// [`ScalerWeights::w`], in the kernels' layout.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CumulativeShape {
    /// Declared direction in alpha (`None`: the gates are free in alpha).
    pub direction: Direction,
    /// Units `K`.
    pub units: usize,
}

/// Weights of one scaler in nemm-core's flat layout (see `nemm_kernels::mlp`), followed by
/// its alpha branch's weights if it has one.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScalerWeights<T> {
    /// Inputs `d` (2: state and alpha; 1: alpha only).
    pub inputs: usize,
    /// Hidden width `H`.
    pub hidden: usize,
    /// Hidden layers `L`.
    pub layers: usize,
    /// Flat parameters: the MLP's, then the branch's.
    pub w: Vec<T>,
    /// Lower bound of the scale factor.
    pub(crate) s_min: T,
    /// Upper bound of the scale factor.
    pub(crate) s_max: T,
    /// The alpha branch, if the scaler has one (its MLP then ignores alpha).
    #[serde(default)]
    pub branch: Option<BranchShape>,
    /// The cumulative scaler's shape if the scaler is one (its force monotone in the state
    /// by construction): [`Self::w`] then holds its weights, `hidden` and `layers` are 0
    /// and there is no branch.
    #[serde(default)]
    pub cumulative: Option<CumulativeShape>,
}

impl<T> ScalerWeights<T> {
    /// The cumulative scaler's view of [`Self::w`], if the scaler is one and its weights
    /// have its shape.
    pub(crate) fn cumulative_view(&self) -> Option<cumulative::CumulativeView<'_, T>>
    where
        T: nemm_kernels::math::Scalar,
    {
        let c = self.cumulative?;
        cumulative::CumulativeView::new(&self.w, c.units, c.direction)
    }

    /// Where each block sits in [`Self::w`]: nemm-core's one definition of the layout.
    pub fn layout(&self) -> mlp::ScalerLayout {
        mlp::ScalerLayout::mlp(self.inputs, self.hidden, self.layers).with_branch(self.branch.map(
            |b| mlp::BranchLayout {
                state_inputs: b.state_inputs,
                units: b.units,
            },
        ))
    }

    /// Number of the MLP's parameters (the head of [`Self::w`]).
    pub(crate) fn mlp_len(&self) -> usize {
        self.layout().mlp_len()
    }

    /// The MLP's parameters.
    pub(crate) fn mlp_w(&self) -> &[T] {
        &self.w[..self.mlp_len().min(self.w.len())]
    }

    /// The branch's parameters (empty without a branch).
    pub fn branch_w(&self) -> &[T] {
        &self.w[self.mlp_len().min(self.w.len())..]
    }
}

/// Everything a rollout needs: constants, scalers, normalisation, integrator.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RolloutParams<T> {
    /// Integration scheme.
    pub integrator: Integrator,
    /// Step \[s\].
    pub dt: T,
    /// `b_fl,ini` \[N s/m\].
    pub b_fl0: T,
    /// `b_pr,ini` \[N s/m\].
    pub b_pr0: T,
    /// `k_pr,ini` \[N/m\].
    pub k0: T,
    /// `T_pr` \[s\].
    pub t_pr: T,
    /// Velocity scale \[m/s\] (input normalisation of `b_fl`).
    pub(crate) v_scale: T,
    /// `x_pr` scale \[m\] (input normalisation of `k_pr`).
    pub(crate) x_scale: T,
    /// Alpha scale.
    pub(crate) alpha_scale: T,
    /// `b_fl(v_st, alpha)` scaler, if neural.
    pub b_fl: Option<ScalerWeights<T>>,
    /// `b_pr(alpha)` scaler, if neural.
    pub b_pr: Option<ScalerWeights<T>>,
    /// `k_pr(x_pr, alpha)` scaler, if neural.
    pub k_pr: Option<ScalerWeights<T>>,
    /// Declared monotonicity priors in alpha (the physics penalty and the audit follow
    /// them; a scaler with an alpha branch holds its prior by construction).
    #[serde(default)]
    pub priors: Priors,
    /// The static force `r` of eq. 17 (`nemm_kernels::static_force`), if the model has one.
    #[serde(default)]
    pub static_force: Option<StaticParams<T>>,
    /// The lost-motion element (`nemm_kernels::lost_motion`), if the model has one:
    /// `[f0, d_c,0, d_c,alpha, d_r,0, d_r,alpha]` (N, m, m, m, m), the order of
    /// `nemm_core::LostMotion::params`.
    #[serde(default)]
    pub lost_motion: Option<[T; LOST_MOTION_PARAMS]>,
}

/// The static force of a rollout: `r = theta . features(x_ref, v_c, x, u, alpha)`
/// (`nemm_kernels::static_force::features`), added to the force at every model step.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StaticParams<T> {
    /// Trained parameters `[F_gas0,0, F_gas0,alpha, k_gas,0, k_gas,alpha, F_c]` (N, N, N/m,
    /// N/m, N), the order of `nemm_core::StaticForce::params`.
    pub(crate) theta: [T; STATIC_PARAMS],
    /// Reference position `x_ref` \[m\] (fixed).
    pub x_ref: T,
    /// Smoothing velocity `v_c` \[m/s\] of the friction (fixed).
    pub(crate) v_c: T,
}

/// Gradient of the loss with respect to every trainable quantity of [`RolloutParams`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RolloutGrads<T> {
    /// dL / d b_fl,ini.
    pub b_fl0: T,
    /// dL / d b_pr,ini.
    pub b_pr0: T,
    /// dL / d k_pr,ini.
    pub k0: T,
    /// dL / d T_pr.
    pub t_pr: T,
    /// dL / d (b_fl scaler weights), empty without the scaler.
    pub b_fl: Vec<T>,
    /// dL / d (b_pr scaler weights).
    pub b_pr: Vec<T>,
    /// dL / d (k_pr scaler weights).
    pub k_pr: Vec<T>,
    /// dL / d [`StaticParams::theta`], empty without a static force.
    pub static_force: Vec<T>,
    /// dL / d [`RolloutParams::lost_motion`], empty without the element.
    pub lost_motion: Vec<T>,
}

impl<T: Real> RolloutGrads<T> {
    pub(super) fn zeros(p: &RolloutParams<T>) -> Self {
        let z = |s: &Option<ScalerWeights<T>>| {
            s.as_ref()
                .map_or(Vec::new(), |s| vec![T::zero(); s.w.len()])
        };
        Self {
            b_fl0: T::zero(),
            b_pr0: T::zero(),
            k0: T::zero(),
            t_pr: T::zero(),
            b_fl: z(&p.b_fl),
            b_pr: z(&p.b_pr),
            k_pr: z(&p.k_pr),
            static_force: p
                .static_force
                .map_or(Vec::new(), |_| vec![T::zero(); STATIC_PARAMS]),
            lost_motion: p
                .lost_motion
                .map_or(Vec::new(), |_| vec![T::zero(); LOST_MOTION_PARAMS]),
        }
    }

    pub(super) fn add(&mut self, o: &Self) {
        self.b_fl0 += o.b_fl0;
        self.b_pr0 += o.b_pr0;
        self.k0 += o.k0;
        self.t_pr += o.t_pr;
        for (a, b) in [
            (&mut self.b_fl, &o.b_fl),
            (&mut self.b_pr, &o.b_pr),
            (&mut self.k_pr, &o.k_pr),
            (&mut self.static_force, &o.static_force),
            (&mut self.lost_motion, &o.lost_motion),
        ] {
            for (x, &y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
    }

    /// Multiplies every component by `f`.
    pub fn scale(&mut self, f: T) {
        self.b_fl0 = self.b_fl0 * f;
        self.b_pr0 = self.b_pr0 * f;
        self.k0 = self.k0 * f;
        self.t_pr = self.t_pr * f;
        for v in [
            &mut self.b_fl,
            &mut self.b_pr,
            &mut self.k_pr,
            &mut self.static_force,
            &mut self.lost_motion,
        ] {
            for x in v.iter_mut() {
                *x = *x * f;
            }
        }
    }
}

/// One measured window: stroke velocity and force at the data samples, and its condition
/// level.
#[derive(Debug, Clone, Copy)]
pub struct Window<'a> {
    /// Stroke velocity \[m/s\] per data sample.
    pub u: &'a [f32],
    /// Measured force \[N\] per data sample (ignored by [`simulate`](super::simulate)).
    pub f: &'a [f32],
    /// Condition level `alpha` of the whole window (used when `alphas` is `None`).
    pub alpha: f32,
    /// Condition level per data sample (a condition changing within the window), one value
    /// per sample like `u`; `None`: the constant `alpha`.
    pub alphas: Option<&'a [f32]>,
    /// Stroke position \[m\] per data sample as the position sensor measures it, the input
    /// of the static force ([`RolloutParams::static_force`]); `None`: `x_ref` throughout.
    pub x: Option<&'a [f32]>,
}

/// Relative distance to a whole number below which a grid position counts as exactly on it.
const GRID_SNAP: f64 = 1e-9;

/// Relative distance to a whole number below which the ratio of the sample step to the model
/// step counts as that number: the model step is stored in f32 (`Model::dt_s`), so a sample
/// step within f32 resolution of a whole multiple of it is that multiple (10 kHz data and a
/// 10 kHz model: `1e-4 / f64::from(1e-4f32)` is 1 - 4.7e-8). Left unsnapped, the output
/// interpolation would mix a sliver of the next step's force into every sample, which shows
/// at a condition level's switch.
const RATIO_SNAP: f64 = f32::EPSILON as f64;

/// Where a window's data samples fall on the model's integration grid.
///
/// The model integrates at its own step `dt` ([`RolloutParams::dt`]), the data are sampled
/// every `sample_dt`; both grids start at the window's first sample (model step 0 is the
/// first sample). With `r = sample_dt / dt` model steps per sample:
///
/// - **input**: model step `j` lies at sample position `q = j / r`; its stroke velocity (and a
///   per-sample `alpha`) is the linear interpolation `(1 - w) u_k + w u_{k+1}` with
///   `k = floor(q)`, `w = q - k` (past the last sample the last value is held);
/// - **output**: sample `k` lies at model position `p = k r`; the model force there is
///   `(1 - w) y_j + w y_{j+1}` with `j = floor(p)`, `w = p - j`, i.e. exactly `y_j` when the
///   sample falls on a model step (positions within 1e-9 of a whole number are snapped to it).
///
/// At equal rates (`r = 1`) both are the identity. The loss is scored at the samples through
/// the output interpolation, and the adjoint back-propagates through it exactly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Model steps per data sample, `sample_dt / dt`.
    steps_per_sample: f64,
}

impl Grid {
    /// The model step equals the sample step.
    pub const SAME: Grid = Grid {
        steps_per_sample: 1.0,
    };

    /// The grid of a model step `model_dt_s` over samples `sample_dt_s` apart (both
    /// positive and finite, else [`Grid::SAME`]); a ratio within f32 resolution
    /// (`f32::EPSILON`, relative) of a whole number is taken as that number.
    pub fn new(model_dt_s: f64, sample_dt_s: f64) -> Self {
        let r = sample_dt_s / model_dt_s;
        if !(r.is_finite() && r > 0.0) {
            return Self::SAME;
        }
        let whole = r.round();
        Grid {
            steps_per_sample: if whole >= 1.0 && (r - whole).abs() <= RATIO_SNAP * whole {
                whole
            } else {
                r
            },
        }
    }

    /// Model steps per data sample.
    pub(crate) fn steps_per_sample(&self) -> f64 {
        self.steps_per_sample
    }

    fn split(x: f64) -> (usize, f64) {
        let whole = x.round();
        if (x - whole).abs() <= GRID_SNAP * whole.max(1.0) {
            (whole as usize, 0.0)
        } else {
            let f = x.floor();
            (f as usize, x - f)
        }
    }

    /// `(j, w)`: the model force at sample `k` is `(1 - w) y_j + w y_{j+1}`.
    pub(crate) fn sample_at(&self, k: usize) -> (usize, f64) {
        Self::split(k as f64 * self.steps_per_sample)
    }

    /// `(k, w)`: the input at model step `j` is `(1 - w) u_k + w u_{k+1}`.
    pub(crate) fn input_at(&self, j: usize) -> (usize, f64) {
        Self::split(j as f64 / self.steps_per_sample)
    }

    /// Model steps a window of `samples` data samples is integrated over (through the last
    /// sample's output interpolation).
    pub fn steps(&self, samples: usize) -> usize {
        match samples.checked_sub(1) {
            None => 0,
            Some(last) => {
                let (j, w) = self.sample_at(last);
                j + 1 + usize::from(w > 0.0)
            }
        }
    }

    /// The input `x` (one value per data sample) at model step `j`: linearly interpolated
    /// between the samples around it, the last sample held past the end (0 for an empty `x`).
    pub(crate) fn interpolate(&self, x: &[f32], j: usize) -> f64 {
        let (k, w) = self.input_at(j);
        let last = x.len().saturating_sub(1);
        let a = x.get(k.min(last)).map_or(0.0, |&v| f64::from(v));
        if w == 0.0 || k >= last {
            a
        } else {
            let b = x.get(k + 1).map_or(a, |&v| f64::from(v));
            a + w * (b - a)
        }
    }
}
