//! The online force estimator: one call per sample, fixed step, no allocation, no panic.
//!
//! ```text
//! let model: Model<P> = nemm_core::decode(blob)?;
//! let mut est = Estimator::new(&model, EstimatorConfig::new(alpha))?;
//! loop { let e = est.step(velocity_m_s); publish(e.force_n, e.flags); }
//! ```
//!
//! # What happens per step
//!
//! 1. Input guard: a non-finite velocity, or one beyond the plausibility limit
//!    ([`EstimatorConfig::velocity_limit_m_s`]), is replaced by the last good sample (the
//!    estimator assumes the velocity held) and flagged; good samples resume normally.
//! 2. One RK step from the previous sample to this one (see [`crate::integrator`]), or the map
//!    lookup for the SEM.
//! 3. Divergence guard: a non-finite state or force, or a state beyond
//!    [`DIVERGENCE_FACTOR`] times its training scale, resets the state to rest and is
//!    flagged; it never propagates.
//! 4. The force `F(x_n+1, u_n+1)`; the coefficients computed for it are reused as stage 1 of
//!    the next step.
//!
//! Everything that depends on `alpha` only (the alpha column of each first layer, `b_pr`, the
//! SEM curve) is computed in [`Estimator::new`] / [`Estimator::set_alpha`], never per step.

use crate::emm::{self, Coefficients, State};
use crate::integrator::{self, Integrator, StepSize};
use crate::mlp::{CompiledScaler, Scaler, DEFAULT_PARAM_CAPACITY};
use crate::model::{Body, Model, ModelError};
use crate::sem::{SemMap, MAX_SEM_VELOCITIES};
use core::fmt;

/// Default plausibility limit of the input, as a multiple of the training abs-max velocity.
pub const DEFAULT_VELOCITY_LIMIT_FACTOR: f32 = 3.0;
/// A state beyond this multiple of its training scale counts as diverged.
pub const DIVERGENCE_FACTOR: f32 = 1.0e3;

/// Status bits of one step ([`Estimate::flags`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Flags(pub u8);

impl Flags {
    /// The input sample was NaN or infinite.
    pub const INPUT_NON_FINITE: u8 = 1 << 0;
    /// The input sample was beyond the plausibility limit.
    pub const INPUT_OUT_OF_RANGE: u8 = 1 << 1;
    /// The last good input was used instead of this sample.
    pub const INPUT_HELD: u8 = 1 << 2;
    /// The state diverged (non-finite or runaway) and was reset to rest.
    pub const STATE_RESET: u8 = 1 << 3;
    /// `alpha` lies outside the oil-loss range the model was trained on (extrapolation).
    pub const ALPHA_EXTRAPOLATED: u8 = 1 << 4;
    /// A tabulated scaler's input left its table domain and was clamped.
    pub const OUT_OF_TABLE_DOMAIN: u8 = 1 << 5;

    /// True if every bit of `bits` is set.
    pub const fn contains(self, bits: u8) -> bool {
        self.0 & bits == bits
    }
    /// True if no bit is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
}

/// Result of one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// Estimated damper force \[N\], positive in tension (rebound). Always finite.
    pub force_n: f32,
    /// What happened in this step.
    pub flags: Flags,
}

/// Counters since construction (not cleared by [`Estimator::reset`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Diagnostics {
    /// Steps taken.
    pub steps: u32,
    /// Samples replaced by the last good input (non-finite or out of range).
    pub held_samples: u32,
    /// Divergence resets.
    pub resets: u32,
}

/// Settings of an estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EstimatorConfig {
    /// Oil-loss level `alpha` in `[0, 1]` (fraction of oil volume lost).
    pub alpha: f32,
    /// Largest plausible |velocity| \[m/s\]; `None`: [`DEFAULT_VELOCITY_LIMIT_FACTOR`] times
    /// the model's training abs-max velocity.
    pub velocity_limit_m_s: Option<f32>,
    /// Integrator; `None`: the model's.
    pub integrator: Option<Integrator>,
    /// Step \[s\]; `None`: the model's. Checked against the model's stability bound.
    pub dt_s: Option<f32>,
}

impl EstimatorConfig {
    /// Defaults for oil-loss level `alpha`.
    pub const fn new(alpha: f32) -> Self {
        Self {
            alpha,
            velocity_limit_m_s: None,
            integrator: None,
            dt_s: None,
        }
    }
}

/// Why an estimator could not be built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EstimatorError {
    /// `alpha` is not a finite value in `[0, 1]`.
    AlphaOutOfRange,
    /// The velocity limit is not finite and positive.
    BadVelocityLimit,
    /// The model (or the chosen step / integrator) is not acceptable.
    Model(ModelError),
    /// A scaler could not be compiled (inconsistent shape; cannot happen for a decoded model).
    Compile,
}

impl fmt::Display for EstimatorError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EstimatorError::AlphaOutOfRange => write!(f, "alpha must be a finite value in [0, 1]"),
            EstimatorError::BadVelocityLimit => {
                write!(f, "velocity limit must be a finite positive value in m/s")
            }
            EstimatorError::Model(e) => write!(f, "{e}"),
            EstimatorError::Compile => write!(f, "a scaler has an inconsistent shape"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for EstimatorError {}

/// A coefficient that is either constant or a compiled neural scaler of one state input.
#[derive(Debug, Clone)]
enum Coef<const P: usize> {
    Const(f32),
    Neural(CompiledScaler<P>),
}

impl<const P: usize> Coef<P> {
    #[inline(always)]
    fn eval(&self, u: f32) -> f32 {
        match self {
            Coef::Const(c) => *c,
            Coef::Neural(s) => s.eval(u),
        }
    }
    fn set_alpha(&mut self, alpha: f32) {
        if let Coef::Neural(s) = self {
            s.set_alpha(alpha);
        }
    }
}

#[derive(Debug, Clone)]
struct EmmRuntime<const P: usize> {
    b_fl: Coef<P>,
    k_pr: Coef<P>,
    b_pr: f32,
    /// The `b_pr(alpha)` scaler with `b_pr,ini` and the alpha scale, kept for `set_alpha`.
    b_pr_scaler: Option<(Scaler<P>, f32, f32)>,
    inv_t_pr: f32,
    integrator: Integrator,
    h: StepSize,
    x_limit: f32,
    v_limit: f32,
}

impl<const P: usize> EmmRuntime<P> {
    #[inline(always)]
    fn coeffs(&self, s: &State) -> Coefficients {
        Coefficients {
            b_fl: self.b_fl.eval(s.v_st_m_s),
            b_pr: self.b_pr,
            k_pr: self.k_pr.eval(s.x_pr_m),
        }
    }
}

#[derive(Debug, Clone)]
enum Runtime<const P: usize> {
    Sem {
        map: SemMap,
        curve: heapless::Vec<f32, MAX_SEM_VELOCITIES>,
    },
    Emm(EmmRuntime<P>),
}

/// Online estimator for one damper at one oil-loss level. Owns everything it needs; the
/// [`Model`] can be dropped after construction.
#[derive(Debug, Clone)]
pub struct Estimator<const P: usize = DEFAULT_PARAM_CAPACITY> {
    rt: Runtime<P>,
    alpha: f32,
    alpha_range: (f32, f32),
    state: State,
    coeffs: Coefficients,
    last_u: f32,
    velocity_limit: f32,
    sticky: Flags,
    diag: Diagnostics,
}

impl<const P: usize> Estimator<P> {
    /// Builds an estimator: validates the model with the configured step and integrator and
    /// precomputes all alpha-only work.
    pub fn new(model: &Model<P>, cfg: EstimatorConfig) -> Result<Self, EstimatorError> {
        model.validate().map_err(EstimatorError::Model)?;
        let alpha = cfg.alpha;
        if !(alpha.is_finite() && (0.0..=1.0).contains(&alpha)) {
            return Err(EstimatorError::AlphaOutOfRange);
        }
        let velocity_limit = cfg
            .velocity_limit_m_s
            .unwrap_or(DEFAULT_VELOCITY_LIMIT_FACTOR * model.scales.velocity_m_s);
        if !(velocity_limit.is_finite() && velocity_limit > 0.0) {
            return Err(EstimatorError::BadVelocityLimit);
        }
        let integrator = cfg.integrator.unwrap_or(model.integrator);
        let dt = cfg.dt_s.unwrap_or(model.dt_s);
        model
            .check_step(integrator, dt)
            .map_err(EstimatorError::Model)?;
        let sc = &model.scales;
        let rt = match &model.body {
            Body::Sem(map) => Runtime::Sem {
                map: map.clone(),
                curve: map.curve_at(alpha).0,
            },
            body => {
                let (emm, b_fl, b_pr, k_pr) = match body {
                    Body::LinearEmm(e) => (e, None, None, None),
                    Body::NemmLight { emm, b_fl } => (emm, Some(b_fl), None, None),
                    Body::Nemm {
                        emm,
                        b_fl,
                        b_pr,
                        k_pr,
                    } => (emm, Some(b_fl), Some(b_pr), Some(k_pr)),
                    Body::Sem(_) => return Err(EstimatorError::Compile),
                };
                let compile = |s: Option<&Scaler<P>>, p_ini: f32, u_scale: f32| match s {
                    None => Ok(Coef::Const(p_ini)),
                    Some(s) => CompiledScaler::compile(s, p_ini, u_scale, alpha, sc.alpha)
                        .map(Coef::Neural)
                        .ok_or(EstimatorError::Compile),
                };
                let b_pr_value = match b_pr {
                    None => emm.b_pr_ns_per_m,
                    Some(s) => {
                        emm.b_pr_ns_per_m
                            * s.scale(&[alpha / sc.alpha])
                                .ok_or(EstimatorError::Compile)?
                    }
                };
                Runtime::Emm(EmmRuntime {
                    b_fl: compile(b_fl, emm.b_fl_ns_per_m, sc.velocity_m_s)?,
                    k_pr: compile(k_pr, emm.k_pr_n_per_m, sc.x_pr_m)?,
                    b_pr: b_pr_value,
                    b_pr_scaler: b_pr.map(|s| (s.clone(), emm.b_pr_ns_per_m, sc.alpha)),
                    inv_t_pr: 1.0 / emm.t_pr_s,
                    integrator,
                    h: StepSize::new(dt),
                    x_limit: DIVERGENCE_FACTOR * sc.x_pr_m,
                    v_limit: DIVERGENCE_FACTOR * sc.velocity_m_s,
                })
            }
        };
        let mut est = Self {
            rt,
            alpha,
            alpha_range: (model.meta.alpha_min, model.meta.alpha_max),
            state: State::default(),
            coeffs: Coefficients {
                b_fl: 0.0,
                b_pr: 0.0,
                k_pr: 0.0,
            },
            last_u: 0.0,
            velocity_limit,
            sticky: Flags(0),
            diag: Diagnostics::default(),
        };
        est.update_alpha_flags();
        est.reset();
        Ok(est)
    }

    fn update_alpha_flags(&mut self) {
        let (lo, hi) = self.alpha_range;
        let mut extrapolated = !(lo..=hi).contains(&self.alpha);
        if let Runtime::Sem { map, .. } = &self.rt {
            extrapolated |= map.curve_at(self.alpha).1;
        }
        self.sticky = Flags(if extrapolated {
            Flags::ALPHA_EXTRAPOLATED
        } else {
            0
        });
    }

    /// Returns to rest: `x_pr = 0`, `v_st = 0`, last input 0. Diagnostics are kept.
    pub fn reset(&mut self) {
        self.state = State::default();
        self.last_u = 0.0;
        if let Runtime::Emm(rt) = &self.rt {
            self.coeffs = rt.coeffs(&self.state);
        }
    }

    /// Changes the oil-loss level (bench controllers): re-folds the alpha-only work
    /// (first-layer biases, `b_pr(alpha)`, the SEM curve). The state is kept. Refuses values
    /// outside `[0, 1]`.
    pub fn set_alpha(&mut self, alpha: f32) -> Result<(), EstimatorError> {
        if !(alpha.is_finite() && (0.0..=1.0).contains(&alpha)) {
            return Err(EstimatorError::AlphaOutOfRange);
        }
        self.alpha = alpha;
        match &mut self.rt {
            Runtime::Sem { map, curve } => *curve = map.curve_at(alpha).0,
            Runtime::Emm(rt) => {
                rt.b_fl.set_alpha(alpha);
                rt.k_pr.set_alpha(alpha);
            }
        }
        self.update_alpha_flags();
        if let Runtime::Emm(rt) = &mut self.rt {
            if let Some((scaler, b_pr_ini, alpha_scale)) = &rt.b_pr_scaler {
                rt.b_pr = *b_pr_ini
                    * scaler
                        .scale(&[alpha / *alpha_scale])
                        .ok_or(EstimatorError::Compile)?;
            }
            self.coeffs = rt.coeffs(&self.state);
        }
        Ok(())
    }

    /// One sample: velocity \[m/s\] in (positive = extension), force estimate out.
    #[inline]
    pub fn step(&mut self, velocity_m_s: f32) -> Estimate {
        let mut flags = self.sticky.0;
        let u = if !velocity_m_s.is_finite() {
            flags |= Flags::INPUT_NON_FINITE | Flags::INPUT_HELD;
            self.last_u
        } else if velocity_m_s.abs() > self.velocity_limit {
            flags |= Flags::INPUT_OUT_OF_RANGE | Flags::INPUT_HELD;
            self.last_u
        } else {
            velocity_m_s
        };
        if flags & Flags::INPUT_HELD != 0 {
            self.diag.held_samples = self.diag.held_samples.wrapping_add(1);
        }
        self.diag.steps = self.diag.steps.wrapping_add(1);
        let force_n = match &self.rt {
            Runtime::Sem { map, curve } => map.force_on_curve(curve, u),
            Runtime::Emm(rt) => {
                let x1 = integrator::step(
                    rt.integrator,
                    |s| rt.coeffs(s),
                    &self.coeffs,
                    rt.inv_t_pr,
                    &self.state,
                    self.last_u,
                    u,
                    &rt.h,
                );
                let c1 = rt.coeffs(&x1);
                let f = emm::force(&c1, &x1, u);
                if f.is_finite() && x1.x_pr_m.abs() <= rt.x_limit && x1.v_st_m_s.abs() <= rt.v_limit
                {
                    self.state = x1;
                    self.coeffs = c1;
                    f
                } else {
                    flags |= Flags::STATE_RESET;
                    self.diag.resets = self.diag.resets.wrapping_add(1);
                    self.state = State::default();
                    self.coeffs = rt.coeffs(&self.state);
                    let f0 = emm::force(&self.coeffs, &self.state, u);
                    if f0.is_finite() {
                        f0
                    } else {
                        0.0
                    }
                }
            }
        };
        self.last_u = u;
        Estimate {
            force_n: if force_n.is_finite() { force_n } else { 0.0 },
            flags: Flags(flags),
        }
    }

    /// Runs a whole input sequence from the current state; `forces` gets one value per input
    /// (up to the shorter length).
    pub fn run(&mut self, velocities_m_s: &[f32], forces_n: &mut [f32]) {
        for (&v, f) in velocities_m_s.iter().zip(forces_n.iter_mut()) {
            *f = self.step(v).force_n;
        }
    }

    /// Current state `[x_pr, v_st]`.
    pub fn state(&self) -> State {
        self.state
    }

    /// Coefficients `b_fl`, `b_pr`, `k_pr` at the current state (zeros for the SEM).
    pub fn coefficients(&self) -> Coefficients {
        self.coeffs
    }

    /// Counters.
    pub fn diagnostics(&self) -> Diagnostics {
        self.diag
    }

    /// The oil-loss level in use.
    pub fn alpha(&self) -> f32 {
        self.alpha
    }

    /// The plausibility limit of the input \[m/s\].
    pub fn velocity_limit_m_s(&self) -> f32 {
        self.velocity_limit
    }
}
