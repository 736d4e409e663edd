//! What an estimator is configured with and what each step returns: the configuration, the
//! estimate and its flags, the diagnostics, the evaluation mode and the errors.

use super::*;

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
    /// Table mode: the new state lies outside a table's domain, so its coefficient was
    /// clamped to the boundary value (RK stages outside are clamped too, unflagged).
    pub const OUT_OF_TABLE_DOMAIN: u8 = 1 << 5;
    /// The estimator holds no model ([`Estimator::empty`], or a failed
    /// [`Estimator::load`]): the force is 0.
    pub const NO_MODEL: u8 = 1 << 7;
    /// The model has a static force ([`crate::Model::static_force`]) and this step had
    /// no usable stroke position ([`Estimator::step`] without one, or a non-finite
    /// position): its position term used the last good position (`x_ref` before the first).
    pub const POSITION_MISSING: u8 = 1 << 6;

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

/// How the neural coefficients are evaluated (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum EvalMode {
    /// The compiled MLPs (reference arithmetic).
    #[default]
    Exact,
    /// 1-D cubic tables for the fixed `alpha`, verified against the MLPs within the bound of
    /// the [`TableConfig`].
    Table(TableConfig),
}

impl EvalMode {
    /// `"exact"` or `"table"`.
    pub const fn name(&self) -> &'static str {
        match self {
            EvalMode::Exact => "exact",
            EvalMode::Table(_) => "table",
        }
    }
}

/// Where the tables of an estimator came from ([`Estimator::table_origin`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TableOrigin {
    /// No tables: exact mode, a model without neural coefficients, or no model.
    #[default]
    None,
    /// Built and checked by the estimator; why stored tables were not used.
    Built(StoredUnused),
    /// Read from the blob's tables section ([`Estimator::load_with_tables`]): bit for bit
    /// the tables the estimator would build, without building them.
    Stored,
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
    /// Exact MLPs or verified tables (default exact).
    pub mode: EvalMode,
}

impl EstimatorConfig {
    /// Defaults for oil-loss level `alpha`.
    pub const fn new(alpha: f32) -> Self {
        Self {
            alpha,
            velocity_limit_m_s: None,
            integrator: None,
            dt_s: None,
            mode: EvalMode::Exact,
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
    /// Table mode: a table could not be built or misses the error bound.
    Table(TableError),
    /// Table mode without level tables: [`Estimator::step`] was given a sample with a
    /// changed `alpha` (a per-sample condition level needs [`EvalMode::Exact`] or level
    /// tables, [`Estimator::attach_levels`]).
    AlphaPerSampleInTableMode,
    /// The level tables cannot drive this estimator: empty, or of another model
    /// ([`Estimator::attach_levels`], [`crate::AlphaObserver::load_on_levels`]).
    Levels(LevelsError),
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
            EstimatorError::Table(e) => write!(f, "{e}"),
            EstimatorError::AlphaPerSampleInTableMode => write!(
                f,
                "a per-sample alpha needs exact mode (table mode would rebuild its tables every sample)"
            ),
            EstimatorError::Levels(e) => write!(f, "level tables: {e}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for EstimatorError {}
