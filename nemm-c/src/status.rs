//! The status codes every function returns, and the mapping of nemm-core's typed errors to
//! them: one code per variant of [`DecodeError`], [`ModelError`], [`EstimatorError`],
//! [`TableError`], [`LevelsError`] and [`ObserverError`] (the variants that only carry
//! another error take that error's code).

use core::ffi::c_char;
use nemm_core::{DecodeError, EstimatorError, LevelsError, ModelError, ObserverError, TableError};

/// What a call did. `NEMM_OK` (0) is success; every other value is an error, after which
/// nothing was written unless the function says otherwise. `nemm_status_str` gives a
/// one-line description of each.
///
/// Codes 1-9 are argument and storage errors, 10-19 blob errors (the weights file itself),
/// 20-39 model errors (the blob decodes but its model is not acceptable), 40-49 estimator
/// errors, 50-59 table errors (table mode), 60-69 observer errors, 70-79 level tables
/// errors. Values are stable.
#[allow(non_camel_case_types)]
#[repr(i32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum nemm_status_t {
    /// Success.
    NEMM_OK = 0,
    /// A required pointer argument is NULL.
    NEMM_E_NULL = 1,
    /// The storage is smaller than its `NEMM_*_SIZE` (the `size` argument): a header of
    /// another build of the library, or the wrong object.
    NEMM_E_STORAGE_SIZE = 2,
    /// The storage is not aligned to its `NEMM_*_ALIGN`.
    NEMM_E_STORAGE_ALIGN = 3,
    /// The object was not initialised (or its last `*_init` failed).
    NEMM_E_NOT_INITIALISED = 4,
    /// An argument is out of its domain: an unknown `mode`, a length beyond the address
    /// space.
    NEMM_E_INVALID_ARGUMENT = 5,
    /// Two memory areas that must be distinct overlap: the blob and the estimator's storage,
    /// or the observer's storage and the estimator's.
    NEMM_E_OVERLAP = 6,

    /// The blob ends before its header, body or CRC does (incomplete flash or copy, or a
    /// wrong length passed).
    NEMM_E_BLOB_TRUNCATED = 10,
    /// The blob does not start with `NEMM`: not a weights blob (wrong file or address).
    NEMM_E_BLOB_BAD_MAGIC = 11,
    /// The blob's format version is not one this library reads (re-export the weights with a
    /// matching `nemm`, or update the library).
    NEMM_E_BLOB_UNSUPPORTED_VERSION = 12,
    /// Bytes follow the blob's CRC (a wrong length passed?).
    NEMM_E_BLOB_TRAILING_BYTES = 13,
    /// The CRC-32 does not match: the blob is corrupt.
    NEMM_E_BLOB_CRC_MISMATCH = 14,
    /// A scaler of the model needs more parameters than this library holds
    /// (`NEMM_PARAM_CAPACITY`).
    NEMM_E_BLOB_OVER_CAPACITY = 15,
    /// The header or body does not parse although the CRC matches (a different format under
    /// the same version).
    NEMM_E_BLOB_MALFORMED = 16,

    /// Model: a value that must be finite is NaN or infinite.
    NEMM_E_MODEL_NON_FINITE = 20,
    /// Model: a value that must be positive is not.
    NEMM_E_MODEL_NOT_POSITIVE = 21,
    /// Model: a value that must not be negative is.
    NEMM_E_MODEL_NEGATIVE = 22,
    /// Model: a static force on a SEM (whose map already holds every force).
    NEMM_E_MODEL_STATIC_FORCE_ON_SEM = 23,
    /// Model: a normalisation or force scale outside `[1e-9, 1e9]`.
    NEMM_E_MODEL_OUT_OF_RANGE = 24,
    /// Model: a scaler's bounds are not `0 < s_min < s_max`.
    NEMM_E_MODEL_BAD_SCALER_BOUNDS = 25,
    /// Model: a scaler's network shape is invalid or over capacity.
    NEMM_E_MODEL_SHAPE = 26,
    /// Model: a scaler's alpha branch is not acceptable.
    NEMM_E_MODEL_BRANCH = 27,
    /// Model: the condition's name, unit or end points are not acceptable.
    NEMM_E_MODEL_CONDITION = 28,
    /// Model: a scaler has the wrong number of inputs for its role.
    NEMM_E_MODEL_WRONG_INPUT_COUNT = 29,
    /// Model: the SEM force map is invalid.
    NEMM_E_MODEL_SEM = 30,
    /// Model: the training alpha range is not `0 <= alpha_min <= alpha_max <= 1`.
    NEMM_E_MODEL_ALPHA_RANGE = 31,
    /// Model: a text field holds a control character.
    NEMM_E_MODEL_CONTROL_CHARACTER = 32,
    /// Model: the step is too long for the fastest time constant the model can reach (run
    /// faster, or retrain with tighter scaler bounds).
    NEMM_E_MODEL_UNSTABLE_STEP = 33,
    /// Model: a lost-motion element on a SEM (which has no pressure stiffness).
    NEMM_E_MODEL_LOST_MOTION_ON_SEM = 34,
    /// Model: a coefficient's cumulative scaler is not acceptable (its weights, a
    /// coefficient the model does not learn, an MLP with weights or an alpha branch beside
    /// it, or a direction against the declared prior).
    NEMM_E_MODEL_CUMULATIVE = 35,

    /// `alpha` is not a finite value in `[0, 1]`.
    NEMM_E_ALPHA_OUT_OF_RANGE = 40,
    /// The velocity limit is not finite and positive.
    NEMM_E_BAD_VELOCITY_LIMIT = 41,
    /// A scaler could not be compiled (cannot happen for a blob that decodes).
    NEMM_E_COMPILE = 42,
    /// Table mode: a per-sample `alpha` that differs from the one in use (a per-sample
    /// condition level needs `NEMM_MODE_EXACT`); nothing changed.
    NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE = 43,

    /// Table mode: the table configuration is invalid (the error bound is not finite and
    /// positive).
    NEMM_E_TABLE_BAD_CONFIG = 50,
    /// Table mode: a coefficient is non-finite on the table's check grid.
    NEMM_E_TABLE_NON_FINITE = 51,
    /// Table mode: a coefficient has more kinks than the table has segments.
    NEMM_E_TABLE_TOO_MANY_KINKS = 52,
    /// Table mode: a table misses the error bound (use exact mode, or a looser bound).
    NEMM_E_TABLE_EXCEEDS_BOUND = 53,

    /// Observer: the grid is not two finite levels in `[0, 1]`, lowest first.
    NEMM_E_OBSERVER_GRID = 60,
    /// Observer: the number of levels is not in `2..=NEMM_OBSERVER_MAX_POINTS`.
    NEMM_E_OBSERVER_POINTS = 61,
    /// Observer: a setting is not finite, or not in its range.
    NEMM_E_OBSERVER_SETTING = 62,

    /// Level tables: the model has no neural coefficient to tabulate (SEM, Linear EMM).
    NEMM_E_LEVELS_NO_NEURAL_COEFFICIENT = 70,
    /// Level tables: the blob is not the one the estimator was built from (its length or
    /// CRC differs from the tables index decoded at the estimator's init).
    NEMM_E_LEVELS_OTHER_BLOB = 71,
    /// Level tables: the blob stores fewer than two levels of `NEMM_TABLE_SEGMENTS`-segment
    /// tables (export it with `--tables-levels`).
    NEMM_E_LEVELS_TOO_FEW = 72,
    /// Level tables: the blob stores more levels of `NEMM_TABLE_SEGMENTS`-segment tables
    /// than `NEMM_LEVELS_CAPACITY`.
    NEMM_E_LEVELS_TOO_MANY = 73,
    /// Level tables: the stored levels are not in strictly ascending alpha with one table
    /// configuration.
    NEMM_E_LEVELS_ORDER = 74,
    /// Level tables: a stored table does not read back on the model's domain.
    NEMM_E_LEVELS_TABLE = 75,
    /// Level tables: `b_pr` could not be evaluated at a level (cannot happen for a blob
    /// that decodes).
    NEMM_E_LEVELS_COMPILE = 76,
    /// Level tables: the tables belong to another model than the estimator's or observer's,
    /// or an observer step got level tables other than those the observer was built on (or
    /// the observer was not built on level tables); nothing stepped.
    NEMM_E_LEVELS_MISMATCH = 77,
    /// Level tables: the blob is not 4-byte aligned in memory (or the target is big-endian),
    /// so its tables cannot be read in place; nothing was initialised. Place the blob at a
    /// multiple of 4 bytes (`.balign 4` before it in flash, a `uint32_t` buffer in RAM).
    NEMM_E_LEVELS_UNALIGNED = 78,
    /// Level tables: the blob stores its tables in the layout of format version 4 or 5,
    /// which cannot be read in place; nothing was initialised. Export the blob again with
    /// this version of `nemm` (format version 6 or later; e.g. `nemm tables MODEL
    /// --tables-levels N --out FILE`).
    NEMM_E_LEVELS_LAYOUT = 79,
}

use nemm_status_t::*;

/// Every status, in the order of their values.
pub(crate) const ALL: [nemm_status_t; 51] = [
    NEMM_OK,
    NEMM_E_NULL,
    NEMM_E_STORAGE_SIZE,
    NEMM_E_STORAGE_ALIGN,
    NEMM_E_NOT_INITIALISED,
    NEMM_E_INVALID_ARGUMENT,
    NEMM_E_OVERLAP,
    NEMM_E_BLOB_TRUNCATED,
    NEMM_E_BLOB_BAD_MAGIC,
    NEMM_E_BLOB_UNSUPPORTED_VERSION,
    NEMM_E_BLOB_TRAILING_BYTES,
    NEMM_E_BLOB_CRC_MISMATCH,
    NEMM_E_BLOB_OVER_CAPACITY,
    NEMM_E_BLOB_MALFORMED,
    NEMM_E_MODEL_NON_FINITE,
    NEMM_E_MODEL_NOT_POSITIVE,
    NEMM_E_MODEL_NEGATIVE,
    NEMM_E_MODEL_STATIC_FORCE_ON_SEM,
    NEMM_E_MODEL_OUT_OF_RANGE,
    NEMM_E_MODEL_BAD_SCALER_BOUNDS,
    NEMM_E_MODEL_SHAPE,
    NEMM_E_MODEL_BRANCH,
    NEMM_E_MODEL_CONDITION,
    NEMM_E_MODEL_WRONG_INPUT_COUNT,
    NEMM_E_MODEL_SEM,
    NEMM_E_MODEL_ALPHA_RANGE,
    NEMM_E_MODEL_CONTROL_CHARACTER,
    NEMM_E_MODEL_UNSTABLE_STEP,
    NEMM_E_MODEL_LOST_MOTION_ON_SEM,
    NEMM_E_MODEL_CUMULATIVE,
    NEMM_E_ALPHA_OUT_OF_RANGE,
    NEMM_E_BAD_VELOCITY_LIMIT,
    NEMM_E_COMPILE,
    NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE,
    NEMM_E_TABLE_BAD_CONFIG,
    NEMM_E_TABLE_NON_FINITE,
    NEMM_E_TABLE_TOO_MANY_KINKS,
    NEMM_E_TABLE_EXCEEDS_BOUND,
    NEMM_E_OBSERVER_GRID,
    NEMM_E_OBSERVER_POINTS,
    NEMM_E_OBSERVER_SETTING,
    NEMM_E_LEVELS_NO_NEURAL_COEFFICIENT,
    NEMM_E_LEVELS_OTHER_BLOB,
    NEMM_E_LEVELS_TOO_FEW,
    NEMM_E_LEVELS_TOO_MANY,
    NEMM_E_LEVELS_ORDER,
    NEMM_E_LEVELS_TABLE,
    NEMM_E_LEVELS_COMPILE,
    NEMM_E_LEVELS_MISMATCH,
    NEMM_E_LEVELS_UNALIGNED,
    NEMM_E_LEVELS_LAYOUT,
];

impl nemm_status_t {
    /// The name and a one-line description, as a NUL-terminated string.
    pub const fn text(self) -> &'static core::ffi::CStr {
        match self {
            NEMM_OK => c"NEMM_OK: success",
            NEMM_E_NULL => c"NEMM_E_NULL: a required pointer argument is NULL",
            NEMM_E_STORAGE_SIZE => {
                c"NEMM_E_STORAGE_SIZE: the storage is smaller than the library needs (header of another build?)"
            }
            NEMM_E_STORAGE_ALIGN => {
                c"NEMM_E_STORAGE_ALIGN: the storage is not aligned to its NEMM_*_ALIGN"
            }
            NEMM_E_NOT_INITIALISED => {
                c"NEMM_E_NOT_INITIALISED: the object is not initialised (or its init failed)"
            }
            NEMM_E_INVALID_ARGUMENT => {
                c"NEMM_E_INVALID_ARGUMENT: an argument is out of its domain (unknown mode, length)"
            }
            NEMM_E_OVERLAP => {
                c"NEMM_E_OVERLAP: memory areas that must be distinct overlap (blob, storages)"
            }
            NEMM_E_BLOB_TRUNCATED => {
                c"NEMM_E_BLOB_TRUNCATED: the weights blob is truncated (incomplete flash or copy, wrong length?)"
            }
            NEMM_E_BLOB_BAD_MAGIC => {
                c"NEMM_E_BLOB_BAD_MAGIC: not a NEMM weights blob (wrong file or address?)"
            }
            NEMM_E_BLOB_UNSUPPORTED_VERSION => {
                c"NEMM_E_BLOB_UNSUPPORTED_VERSION: the blob's format version is not supported by this library"
            }
            NEMM_E_BLOB_TRAILING_BYTES => {
                c"NEMM_E_BLOB_TRAILING_BYTES: bytes follow the blob's CRC (wrong length passed?)"
            }
            NEMM_E_BLOB_CRC_MISMATCH => {
                c"NEMM_E_BLOB_CRC_MISMATCH: the weights blob is corrupt (CRC-32 mismatch)"
            }
            NEMM_E_BLOB_OVER_CAPACITY => {
                c"NEMM_E_BLOB_OVER_CAPACITY: the model needs more parameters per scaler than NEMM_PARAM_CAPACITY"
            }
            NEMM_E_BLOB_MALFORMED => {
                c"NEMM_E_BLOB_MALFORMED: the blob does not parse although its CRC matches"
            }
            NEMM_E_MODEL_NON_FINITE => {
                c"NEMM_E_MODEL_NON_FINITE: the model holds a NaN or infinite value"
            }
            NEMM_E_MODEL_NOT_POSITIVE => {
                c"NEMM_E_MODEL_NOT_POSITIVE: a model value that must be positive is not"
            }
            NEMM_E_MODEL_NEGATIVE => {
                c"NEMM_E_MODEL_NEGATIVE: a model value that must not be negative is"
            }
            NEMM_E_MODEL_STATIC_FORCE_ON_SEM => {
                c"NEMM_E_MODEL_STATIC_FORCE_ON_SEM: the SEM takes no static force"
            }
            NEMM_E_MODEL_OUT_OF_RANGE => {
                c"NEMM_E_MODEL_OUT_OF_RANGE: a model scale lies outside [1e-9, 1e9]"
            }
            NEMM_E_MODEL_BAD_SCALER_BOUNDS => {
                c"NEMM_E_MODEL_BAD_SCALER_BOUNDS: a scaler's bounds are not 0 < s_min < s_max"
            }
            NEMM_E_MODEL_SHAPE => {
                c"NEMM_E_MODEL_SHAPE: a scaler's network shape is invalid or over capacity"
            }
            NEMM_E_MODEL_BRANCH => {
                c"NEMM_E_MODEL_BRANCH: a scaler's alpha branch is not acceptable"
            }
            NEMM_E_MODEL_CONDITION => {
                c"NEMM_E_MODEL_CONDITION: the model's condition (name, unit, end points) is not acceptable"
            }
            NEMM_E_MODEL_WRONG_INPUT_COUNT => {
                c"NEMM_E_MODEL_WRONG_INPUT_COUNT: a scaler has the wrong number of inputs"
            }
            NEMM_E_MODEL_SEM => c"NEMM_E_MODEL_SEM: the SEM force map is invalid",
            NEMM_E_MODEL_ALPHA_RANGE => {
                c"NEMM_E_MODEL_ALPHA_RANGE: the training alpha range is not 0 <= min <= max <= 1"
            }
            NEMM_E_MODEL_CONTROL_CHARACTER => {
                c"NEMM_E_MODEL_CONTROL_CHARACTER: a text field of the model holds a control character"
            }
            NEMM_E_MODEL_UNSTABLE_STEP => {
                c"NEMM_E_MODEL_UNSTABLE_STEP: the step is too long for the model's fastest time constant"
            }
            NEMM_E_MODEL_LOST_MOTION_ON_SEM => {
                c"NEMM_E_MODEL_LOST_MOTION_ON_SEM: the SEM takes no lost-motion element"
            }
            NEMM_E_MODEL_CUMULATIVE => {
                c"NEMM_E_MODEL_CUMULATIVE: a coefficient's cumulative scaler is not acceptable"
            }
            NEMM_E_ALPHA_OUT_OF_RANGE => {
                c"NEMM_E_ALPHA_OUT_OF_RANGE: alpha must be a finite value in [0, 1]"
            }
            NEMM_E_BAD_VELOCITY_LIMIT => {
                c"NEMM_E_BAD_VELOCITY_LIMIT: the velocity limit must be finite and positive"
            }
            NEMM_E_COMPILE => c"NEMM_E_COMPILE: a scaler has an inconsistent shape",
            NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE => {
                c"NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE: a changing per-sample alpha needs exact mode"
            }
            NEMM_E_TABLE_BAD_CONFIG => {
                c"NEMM_E_TABLE_BAD_CONFIG: the table error bound must be finite and positive"
            }
            NEMM_E_TABLE_NON_FINITE => {
                c"NEMM_E_TABLE_NON_FINITE: a coefficient is non-finite on the table's check grid"
            }
            NEMM_E_TABLE_TOO_MANY_KINKS => {
                c"NEMM_E_TABLE_TOO_MANY_KINKS: a coefficient has more kinks than the table has segments"
            }
            NEMM_E_TABLE_EXCEEDS_BOUND => {
                c"NEMM_E_TABLE_EXCEEDS_BOUND: a table misses its error bound (use exact mode or a looser bound)"
            }
            NEMM_E_OBSERVER_GRID => {
                c"NEMM_E_OBSERVER_GRID: the observer grid must be two finite levels in [0, 1], lowest first"
            }
            NEMM_E_OBSERVER_POINTS => {
                c"NEMM_E_OBSERVER_POINTS: the observer needs 2 to NEMM_OBSERVER_MAX_POINTS levels"
            }
            NEMM_E_OBSERVER_SETTING => {
                c"NEMM_E_OBSERVER_SETTING: an observer setting is not finite or out of its range"
            }
            NEMM_E_LEVELS_NO_NEURAL_COEFFICIENT => {
                c"NEMM_E_LEVELS_NO_NEURAL_COEFFICIENT: the model has no neural coefficient to tabulate"
            }
            NEMM_E_LEVELS_OTHER_BLOB => {
                c"NEMM_E_LEVELS_OTHER_BLOB: the blob is not the one the estimator was built from"
            }
            NEMM_E_LEVELS_TOO_FEW => {
                c"NEMM_E_LEVELS_TOO_FEW: the blob stores fewer than 2 levels of tables (export with --tables-levels)"
            }
            NEMM_E_LEVELS_TOO_MANY => {
                c"NEMM_E_LEVELS_TOO_MANY: the blob stores more levels than NEMM_LEVELS_CAPACITY"
            }
            NEMM_E_LEVELS_ORDER => {
                c"NEMM_E_LEVELS_ORDER: the stored levels are not ascending with one table configuration"
            }
            NEMM_E_LEVELS_TABLE => {
                c"NEMM_E_LEVELS_TABLE: a stored level table does not match the model's domain"
            }
            NEMM_E_LEVELS_COMPILE => {
                c"NEMM_E_LEVELS_COMPILE: b_pr could not be evaluated at a level"
            }
            NEMM_E_LEVELS_MISMATCH => {
                c"NEMM_E_LEVELS_MISMATCH: the level tables belong to another model, or are not the observer's"
            }
            NEMM_E_LEVELS_UNALIGNED => {
                c"NEMM_E_LEVELS_UNALIGNED: the blob is not 4-byte aligned in memory: its tables cannot be read in place"
            }
            NEMM_E_LEVELS_LAYOUT => {
                c"NEMM_E_LEVELS_LAYOUT: the blob stores its tables unaligned (format version 4 or 5): export it again"
            }
        }
    }
}

impl From<ModelError> for nemm_status_t {
    fn from(e: ModelError) -> Self {
        match e {
            ModelError::NonFinite { .. } => NEMM_E_MODEL_NON_FINITE,
            ModelError::NotPositive { .. } => NEMM_E_MODEL_NOT_POSITIVE,
            ModelError::Negative { .. } => NEMM_E_MODEL_NEGATIVE,
            ModelError::StaticForceOnSem => NEMM_E_MODEL_STATIC_FORCE_ON_SEM,
            ModelError::LostMotionOnSem => NEMM_E_MODEL_LOST_MOTION_ON_SEM,
            ModelError::OutOfRange { .. } => NEMM_E_MODEL_OUT_OF_RANGE,
            ModelError::BadScalerBounds { .. } => NEMM_E_MODEL_BAD_SCALER_BOUNDS,
            ModelError::Shape { .. } => NEMM_E_MODEL_SHAPE,
            ModelError::Branch { .. } => NEMM_E_MODEL_BRANCH,
            ModelError::Cumulative { .. } => NEMM_E_MODEL_CUMULATIVE,
            ModelError::Condition { .. } => NEMM_E_MODEL_CONDITION,
            ModelError::WrongInputCount { .. } => NEMM_E_MODEL_WRONG_INPUT_COUNT,
            ModelError::Sem(_) => NEMM_E_MODEL_SEM,
            ModelError::AlphaRange => NEMM_E_MODEL_ALPHA_RANGE,
            ModelError::ControlCharacter { .. } => NEMM_E_MODEL_CONTROL_CHARACTER,
            ModelError::UnstableStep { .. } => NEMM_E_MODEL_UNSTABLE_STEP,
        }
    }
}

impl From<DecodeError> for nemm_status_t {
    fn from(e: DecodeError) -> Self {
        match e {
            DecodeError::Truncated { .. } => NEMM_E_BLOB_TRUNCATED,
            DecodeError::BadMagic { .. } => NEMM_E_BLOB_BAD_MAGIC,
            DecodeError::UnsupportedVersion { .. } => NEMM_E_BLOB_UNSUPPORTED_VERSION,
            DecodeError::TrailingBytes { .. } => NEMM_E_BLOB_TRAILING_BYTES,
            DecodeError::CrcMismatch { .. } => NEMM_E_BLOB_CRC_MISMATCH,
            DecodeError::OverCapacity { .. } => NEMM_E_BLOB_OVER_CAPACITY,
            DecodeError::Malformed { .. } => NEMM_E_BLOB_MALFORMED,
            DecodeError::Invalid(m) => m.into(),
        }
    }
}

impl From<TableError> for nemm_status_t {
    fn from(e: TableError) -> Self {
        match e {
            TableError::BadConfig => NEMM_E_TABLE_BAD_CONFIG,
            TableError::NonFinite { .. } => NEMM_E_TABLE_NON_FINITE,
            TableError::TooManyKinks { .. } => NEMM_E_TABLE_TOO_MANY_KINKS,
            TableError::ExceedsBound { .. } => NEMM_E_TABLE_EXCEEDS_BOUND,
        }
    }
}

impl From<EstimatorError> for nemm_status_t {
    fn from(e: EstimatorError) -> Self {
        match e {
            EstimatorError::AlphaOutOfRange => NEMM_E_ALPHA_OUT_OF_RANGE,
            EstimatorError::BadVelocityLimit => NEMM_E_BAD_VELOCITY_LIMIT,
            EstimatorError::Model(m) => m.into(),
            EstimatorError::Compile => NEMM_E_COMPILE,
            EstimatorError::Table(t) => t.into(),
            EstimatorError::AlphaPerSampleInTableMode => NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE,
            EstimatorError::Levels(l) => l.into(),
        }
    }
}

impl From<LevelsError> for nemm_status_t {
    fn from(e: LevelsError) -> Self {
        match e {
            LevelsError::NoNeuralCoefficient => NEMM_E_LEVELS_NO_NEURAL_COEFFICIENT,
            LevelsError::OtherBlob => NEMM_E_LEVELS_OTHER_BLOB,
            LevelsError::TooFewLevels { .. } => NEMM_E_LEVELS_TOO_FEW,
            LevelsError::TooManyLevels { .. } => NEMM_E_LEVELS_TOO_MANY,
            LevelsError::Order => NEMM_E_LEVELS_ORDER,
            LevelsError::Table => NEMM_E_LEVELS_TABLE,
            LevelsError::Compile => NEMM_E_LEVELS_COMPILE,
            LevelsError::Mismatch => NEMM_E_LEVELS_MISMATCH,
            LevelsError::Unaligned => NEMM_E_LEVELS_UNALIGNED,
            LevelsError::Layout => NEMM_E_LEVELS_LAYOUT,
        }
    }
}

impl From<ObserverError> for nemm_status_t {
    fn from(e: ObserverError) -> Self {
        match e {
            ObserverError::Estimator(e) => e.into(),
            ObserverError::Grid => NEMM_E_OBSERVER_GRID,
            ObserverError::Points { .. } => NEMM_E_OBSERVER_POINTS,
            ObserverError::Setting(_) => NEMM_E_OBSERVER_SETTING,
        }
    }
}

/// The name and a one-line description of a status code, as a static NUL-terminated
/// string (never NULL; `"unknown status"` for a value that is no `nemm_status_t`).
#[no_mangle]
pub extern "C" fn nemm_status_str(status: i32) -> *const c_char {
    ALL.iter()
        .find(|s| **s as i32 == status)
        .map_or(c"unknown status".as_ptr(), |s| s.text().as_ptr())
}
