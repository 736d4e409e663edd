//! The errors that several layers share: a name that does not parse ([`UnknownName`]) and
//! why a model is not acceptable ([`ModelError`], with the shape, branch, cumulative-scaler
//! and SEM errors it carries). They sit below every other module, so that the parts of a
//! model (`mlp`, `cumulative`, `integrator`, `sem`, `static_force`) report in the same
//! terms as the model and the decoder without reaching up to them. Errors of one layer only stay with it:
//! nemm-core's `DecodeError` and `EncodeError` (the weight format) and `EstimatorError`;
//! [`crate::table::TableError`] (the tables).

use crate::limits::{
    MAX_BRANCH_UNITS, MAX_CONDITION_NAME, MAX_CONDITION_UNIT, MAX_HIDDEN, MAX_INPUTS, MAX_LAYERS,
    SCALE_RANGE,
};
use core::fmt;

/// A name that is none of the accepted spellings of a nemm-core `ModelKind`, an
/// [`crate::integrator::Integrator`] or a [`crate::mlp::Direction`] (their `name()`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownName {
    /// What was being parsed (`model kind`, `integrator`, `monotonicity direction`).
    pub what: &'static str,
    /// The accepted names.
    pub expected: &'static str,
}

impl fmt::Display for UnknownName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown {} (expected {})", self.what, self.expected)
    }
}

#[cfg(feature = "std")]
impl std::error::Error for UnknownName {}

/// Why an MLP's shape is not acceptable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShapeError {
    /// `inputs`, `hidden` or `layers` is zero or above its maximum.
    DimensionOutOfRange,
    /// The parameter vector's length does not match the dimensions.
    ParamCountMismatch {
        /// Length the dimensions imply.
        expected: usize,
        /// Length found.
        found: usize,
    },
    /// The dimensions need more parameters than the capacity `P` of this build.
    OverCapacity {
        /// Parameters needed.
        needed: usize,
        /// Capacity of this build.
        capacity: usize,
    },
}

/// Why a cumulative scaler ([`crate::cumulative`]) is not acceptable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CumulativeError {
    /// `units` is 0 or above [`crate::cumulative::MAX_CUMULATIVE_UNITS`].
    UnitsOutOfRange,
    /// The parameter vector's length does not match the unit count.
    ParamCountMismatch {
        /// Length the unit count implies.
        expected: usize,
        /// Length found.
        found: usize,
    },
    /// A parameter is NaN or infinite.
    NonFinite,
}

impl fmt::Display for CumulativeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CumulativeError::UnitsOutOfRange => write!(
                f,
                "units must be 1..={}",
                crate::cumulative::MAX_CUMULATIVE_UNITS
            ),
            CumulativeError::ParamCountMismatch { expected, found } => write!(
                f,
                "its unit count needs {expected} parameters but it holds {found}"
            ),
            CumulativeError::NonFinite => write!(f, "a parameter is NaN or infinite"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for CumulativeError {}

/// Why a coefficient's cumulative scaler ([`crate::cumulative`]) is not acceptable in its
/// model (nemm-core's `Model::cumulative`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CumulativeModelError {
    /// The scaler's own weights are not acceptable.
    Scaler(CumulativeError),
    /// The model does not learn this coefficient (its body has no scaler for it).
    NoScaler,
    /// The coefficient's MLP in the body has weights: beside a cumulative scaler it must be
    /// `MlpParams::without_weights` (the body keeps only the scaler's bounds).
    MlpWeights,
    /// The coefficient also has an alpha branch (the cumulative scaler's gates carry its
    /// dependence on `alpha`).
    AlphaBranch,
    /// The scaler's direction in `alpha` is neither the condition's declared prior nor
    /// `none`.
    DirectionMismatch,
}

impl fmt::Display for CumulativeModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CumulativeModelError::Scaler(e) => write!(f, "{e}"),
            CumulativeModelError::NoScaler => {
                write!(f, "the model does not learn this coefficient")
            }
            CumulativeModelError::MlpWeights => write!(
                f,
                "the coefficient's MLP must have no weights beside a cumulative scaler"
            ),
            CumulativeModelError::AlphaBranch => write!(
                f,
                "the coefficient cannot have an alpha branch beside a cumulative scaler"
            ),
            CumulativeModelError::DirectionMismatch => write!(
                f,
                "its direction differs from the condition's declared prior (and is not none)"
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for CumulativeModelError {}

/// Why an alpha branch is not acceptable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BranchError {
    /// `units` is 0 or above [`MAX_BRANCH_UNITS`], or `state_inputs` above 1.
    DimensionOutOfRange,
    /// The parameter vector's length does not match the dimensions.
    ParamCountMismatch {
        /// Length the dimensions imply.
        expected: usize,
        /// Length found.
        found: usize,
    },
    /// A parameter is NaN or infinite.
    NonFinite,
    /// The direction is [`crate::mlp::Direction::None`] (a coefficient without a prior has no branch).
    NoDirection,
    /// The number of state inputs does not match the scaler's role (1 for `b_fl` and
    /// `k_pr`, 0 for `b_pr`).
    WrongStateInputs {
        /// State inputs the role needs.
        expected: u8,
    },
    /// The branch's direction differs from the condition's declared prior.
    DirectionMismatch,
    /// A branch for a coefficient the model does not learn.
    NoScaler,
    /// The scaler's MLP has a non-zero weight in its alpha input column, so it would
    /// depend on `alpha` outside the branch.
    AlphaColumnNotZero,
}

impl fmt::Display for BranchError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BranchError::DimensionOutOfRange => write!(
                f,
                "units must be 1..={MAX_BRANCH_UNITS} and state inputs 0 or 1"
            ),
            BranchError::ParamCountMismatch { expected, found } => write!(
                f,
                "its dimensions need {expected} parameters but it holds {found}"
            ),
            BranchError::NonFinite => write!(f, "a parameter is NaN or infinite"),
            BranchError::NoDirection => write!(f, "its direction must be increasing or decreasing"),
            BranchError::WrongStateInputs { expected } => {
                write!(f, "it must have {expected} state input(s)")
            }
            BranchError::DirectionMismatch => {
                write!(
                    f,
                    "its direction differs from the condition's declared prior"
                )
            }
            BranchError::NoScaler => write!(f, "the model has no scaler for this coefficient"),
            BranchError::AlphaColumnNotZero => write!(
                f,
                "the scaler's MLP must have a zero alpha input column when it has an alpha branch"
            ),
        }
    }
}

/// Why a SEM map is not acceptable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SemError {
    /// Fewer than 2 velocities or no alpha.
    TooFewPoints,
    /// An axis is not strictly increasing (or holds a non-finite value).
    NotIncreasing,
    /// `forces_n.len() != velocities.len() * alphas.len()`.
    CountMismatch,
    /// A force is not finite.
    NonFiniteForce,
    /// An alpha is outside `[0, 1]`.
    AlphaOutOfRange,
}

/// Why a model is not acceptable. Field names are those of the weight format.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ModelError {
    /// A value that must be finite is NaN or infinite.
    NonFinite {
        /// Which field.
        field: &'static str,
    },
    /// A value that must be positive is not.
    NotPositive {
        /// Which field.
        field: &'static str,
    },
    /// A value that must not be negative is.
    Negative {
        /// Which field.
        field: &'static str,
    },
    /// A static force (nemm-core's `Model::static_force`) on the SEM, whose map already holds
    /// every force of its data.
    StaticForceOnSem,
    /// A lost-motion element (nemm-core's `Model::lost_motion`) on the SEM, which has no
    /// pressure stiffness.
    LostMotionOnSem,
    /// A scale outside [`SCALE_RANGE`].
    OutOfRange {
        /// Which field.
        field: &'static str,
    },
    /// A scaler's bounds are not `0 < s_min < s_max`.
    BadScalerBounds {
        /// Which scaler.
        scaler: &'static str,
    },
    /// A scaler's MLP shape is invalid or over capacity.
    Shape {
        /// Which scaler.
        scaler: &'static str,
        /// What is wrong.
        error: ShapeError,
    },
    /// A scaler's alpha branch is not acceptable.
    Branch {
        /// Which scaler.
        scaler: &'static str,
        /// What is wrong.
        error: BranchError,
    },
    /// A coefficient's cumulative scaler is not acceptable.
    Cumulative {
        /// Which coefficient (`b_fl` or `k_pr`).
        scaler: &'static str,
        /// What is wrong.
        error: CumulativeModelError,
    },
    /// The condition's name is empty or too long, its unit too long, or its end points
    /// coincide.
    Condition {
        /// Which field.
        field: &'static str,
    },
    /// A scaler has the wrong number of inputs for its role.
    WrongInputCount {
        /// Which scaler.
        scaler: &'static str,
        /// Inputs its role needs.
        expected: u8,
        /// Inputs found.
        found: u8,
    },
    /// The SEM map is invalid.
    Sem(SemError),
    /// The training alpha range is not `0 <= alpha_min <= alpha_max <= 1`.
    AlphaRange,
    /// A text field holds a control character.
    ControlCharacter {
        /// Which field.
        field: &'static str,
    },
    /// The step is too long for the fastest time constant the model can reach.
    UnstableStep {
        /// Integration step \[s\].
        dt_s: f32,
        /// Fastest reachable time constant \[s\].
        tau_min_s: f32,
        /// Longest acceptable step \[s\].
        max_dt_s: f32,
        /// The integration scheme's name ([`crate::integrator::Integrator::name`]).
        integrator: &'static str,
    },
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ModelError::NonFinite { field } => write!(f, "`{field}` holds a NaN or infinite value"),
            ModelError::NotPositive { field } => write!(f, "`{field}` must be positive"),
            ModelError::Negative { field } => write!(f, "`{field}` must not be negative"),
            ModelError::StaticForceOnSem => write!(
                f,
                "the SEM takes no static force (its map already holds every force of its data)"
            ),
            ModelError::LostMotionOnSem => write!(
                f,
                "the SEM takes no lost-motion element (it has no pressure stiffness)"
            ),
            ModelError::OutOfRange { field } => write!(
                f,
                "`{field}` must lie in [{:e}, {:e}] (SI units)",
                SCALE_RANGE.0, SCALE_RANGE.1
            ),
            ModelError::BadScalerBounds { scaler } => {
                write!(f, "scaler `{scaler}` needs bounds 0 < s_min < s_max")
            }
            ModelError::Shape { scaler, error } => match error {
                ShapeError::DimensionOutOfRange => write!(
                    f,
                    "scaler `{scaler}`: inputs must be 1..={MAX_INPUTS}, hidden width \
                     1..={MAX_HIDDEN}, layers 1..={MAX_LAYERS}"
                ),
                ShapeError::ParamCountMismatch { expected, found } => write!(
                    f,
                    "scaler `{scaler}`: its dimensions need {expected} parameters but it holds {found}"
                ),
                ShapeError::OverCapacity { needed, capacity } => write!(
                    f,
                    "scaler `{scaler}` needs {needed} parameters but this build holds at most {capacity} \
                     (raise the capacity `P` of `Model<P>`/`Estimator<P>`)"
                ),
            },
            ModelError::Branch { scaler, error } => {
                write!(f, "alpha branch of `{scaler}`: {error}")
            }
            ModelError::Cumulative { scaler, error } => {
                write!(f, "cumulative scaler of `{scaler}`: {error}")
            }
            ModelError::Condition { field } => write!(
                f,
                "`{field}`: the condition needs a name of 1 to {MAX_CONDITION_NAME} bytes, a unit of \
                 at most {MAX_CONDITION_UNIT} bytes and distinct values at alpha 0 and 1"
            ),
            ModelError::WrongInputCount {
                scaler,
                expected,
                found,
            } => write!(f, "scaler `{scaler}` must have {expected} input(s), has {found}"),
            ModelError::Sem(e) => write!(f, "SEM map: {e:?}"),
            ModelError::AlphaRange => {
                write!(f, "training alpha range must satisfy 0 <= alpha_min <= alpha_max <= 1")
            }
            ModelError::ControlCharacter { field } => {
                write!(f, "`{field}` holds a control character")
            }
            ModelError::UnstableStep {
                dt_s,
                tau_min_s,
                max_dt_s,
                integrator,
            } => write!(
                f,
                "step {:.1} us is too long for {}: the model can reach a time constant of {:.2} us, \
                 so the step must be at most {:.2} us (run faster, or retrain with tighter scaler bounds)",
                dt_s * 1e6,
                integrator,
                tau_min_s * 1e6,
                max_dt_s * 1e6
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for ModelError {}
