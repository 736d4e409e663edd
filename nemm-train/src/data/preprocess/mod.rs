//! Preprocessing of bench data for training (paper section 5.3): velocity and acceleration,
//! excitation estimates, quasi-static points for the flow-force model, sequences with warm-up
//! for the pressure-force model, the train / validation / test split of Table 2 and the
//! abs-max feature scales.
//!
//! # Signals
//!
//! * Displacement is low-passed with a zero-phase Butterworth filter: a 2nd-order Butterworth
//!   biquad (bilinear transform, pre-warped) run forward and backward ("filtfilt"), i.e. an
//!   effective 4th-order magnitude `|H|^2 = 1 / (1 + (tan(pi f / fs) / tan(pi fc / fs))^4)`
//!   with no phase shift. The default cut-off [`DEFAULT_CUTOFF_HZ`] = 150 Hz, five times the
//!   model's 30 Hz scope: the gain is -0.014 % at 16.7 Hz, -0.16 % at 30 Hz, -6 dB at 150 Hz.
//!   Edges are padded by a reflection that continues value, slope and curvature (see
//!   [`lowpass_zero_phase`]) and the filter starts in its steady state.
//! * Velocity is the central difference of the filtered displacement,
//!   `v_i = (x_{i+1} - x_{i-1}) / (2 dt)`, second-order one-sided at the two ends
//!   (`(-3 x_0 + 4 x_1 - x_2) / (2 dt)`); acceleration is the same stencil applied to the
//!   velocity. When a run has a measured `velocity_m_s` column it is used instead (by
//!   default), passed through the same zero-phase low-pass so that both sources have the same
//!   bandwidth.
//! * The force used for training sequences is the raw measurement unless
//!   [`SignalConfig::filter_force`] is set (noise in the target does not bias a least-squares
//!   fit); quasi-static extraction always uses the filtered force, because the maximum of a
//!   noisy signal is biased upwards by the noise.
//!
//! * A run's per-sample condition level (the optional `alpha` column) is carried unfiltered
//!   into `Signals::alpha` and the sequences ([`Sequence::alphas`]).
//!
//! Everything here is at the data's sample rate; the model integrates at its own rate, onto
//! which the trainer interpolates the sequences (`train::adjoint::Grid`, docs/preprocessing.md).

use std::path::PathBuf;

/// Default low-pass cut-off for differentiation \[Hz\]: 5 x the model's 30 Hz scope.
pub const DEFAULT_CUTOFF_HZ: f64 = 150.0;
/// The cut-off is at most this fraction of the sample rate (the Butterworth design needs
/// `fc < fs / 2`; at `0.4 fs` the model's 30 Hz band still passes within 0.013 % at 300 Hz,
/// and the zero-phase filter's zero at Nyquist still removes the noise there).
pub(crate) const CUTOFF_FRACTION_OF_RATE: f64 = 0.4;
/// Default scored length of a training sequence \[s\] (section 5.3: 0.5 s).
pub(crate) const DEFAULT_WINDOW_S: f64 = 0.5;
/// Default warm-up prefix of a sequence, simulated but not scored \[s\].
pub(crate) const DEFAULT_WARMUP_S: f64 = 0.05;
/// Default half-width of the quasi-static window around `x = 0`, as a fraction of the
/// displacement amplitude (section 5.3: +-5 %).
pub(crate) const DEFAULT_QS_WINDOW: f64 = 0.05;
/// Default oil-loss level(s) held out for testing (Table 2).
pub(crate) const DEFAULT_TEST_ALPHAS: [f64; 1] = [0.15];
/// Default fraction of each training run's sequences held out for validation.
pub(crate) const DEFAULT_VALIDATION_FRACTION: f64 = 0.2;
/// Default seed of the validation choice; the trainer's default `--seed` is the same, so
/// `nemm data prepare` and `nemm train` describe the same split by default.
pub(crate) const DEFAULT_SPLIT_SEED: u64 = 1;
/// Displacement half-ranges below this \[m\] count as no stroke at all (a flat signal).
pub(crate) const MIN_STROKE_M: f64 = 1e-9;
/// Two oil-loss levels closer than this are the same level.
pub(crate) const ALPHA_TOLERANCE: f64 = 1e-6;

/// Why preprocessing failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PreprocessError {
    /// A configuration value is out of range.
    #[error("{key}: {message}")]
    InvalidConfig {
        /// The setting, e.g. `cutoff_hz`.
        key: &'static str,
        /// What is wrong with it.
        message: String,
    },
    /// [`VelocitySource::Measured`] was asked for but the run has no `velocity_m_s` column.
    #[error("run {run} ({}): no velocity_m_s column, but the measured velocity was requested", file.display())]
    NoMeasuredVelocity {
        /// Run index in the dataset.
        run: usize,
        /// The run's file (relative to the manifest).
        file: PathBuf,
    },
    /// The columns of an in-memory run have different lengths (a loaded run never has).
    #[error("run {run} ({}): columns of different lengths", file.display())]
    ColumnLengths {
        /// Run index in the dataset.
        run: usize,
        /// The run's file (relative to the manifest).
        file: PathBuf,
    },
    /// The split left no training sequence (every run is a test run or unused, or the
    /// training runs are too short); the text names the cause.
    #[error("no training data: {0}")]
    NoTrainingData(String),
    /// A run's force assists the motion (an inverted sign); refused unless the data options
    /// accept implausible runs (`--accept-implausible`).
    #[error("run {run} ({}): the force assists the motion ({message}); or pass --accept-implausible to use it as it is", file.display())]
    Implausible {
        /// Run index in the dataset.
        run: usize,
        /// The run's file (relative to the manifest).
        file: PathBuf,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// A feature is zero over the whole training set, so it cannot be scaled.
    #[error("the training set's {feature} is zero everywhere; it cannot be abs-max scaled")]
    ZeroScale {
        /// `velocity` or `force`.
        feature: &'static str,
    },
}

fn config_err(key: &'static str, message: String) -> PreprocessError {
    PreprocessError::InvalidConfig { key, message }
}

mod dissipation;
mod excitation;
mod prepare;
mod quasi_static;
mod sequences;
mod signal;
mod split;

pub use dissipation::static_force_from_data;

pub(crate) use dissipation::{
    percentile, Dissipation, ForceOffset, STATIC_FORCE_FRACTION, ZERO_VELOCITY_FRACTION,
};
pub use excitation::estimate_excitation;
pub(crate) use excitation::{centred_record, median, zero_crossings};
pub(crate) use excitation::{excitation_frequency_hz, Excitation};
pub use prepare::{prepare, summarize_run, PrepareConfig, PrepareSummary, Prepared};
pub(crate) use prepare::{PreparedRun, RunSummary, SplitCounts};
pub use quasi_static::{quasi_static_points, Direction, QuasiStaticPoint};
pub use sequences::{cut_sequences, sequence_count, unscored_samples, Sequence, SequenceConfig};
pub use signal::{
    causal_velocity, differentiate, lowpass_zero_phase, measured_velocity_mismatch, process_run,
    run_signals, SignalConfig, VelocitySource,
};
pub(crate) use signal::{
    Cutoff, CutoffRule, SignalPath, Signals, AUTO_CUTOFF_EXCITATION_MULTIPLE,
    AUTO_CUTOFF_NOISE_FRACTION,
};
pub(crate) use split::{distinct_levels, file_matches, SplitRules, Stretch};
pub use split::{run_stretches, Part, RunRole, Scales, SplitConfig};
