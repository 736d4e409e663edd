//! # nemm-core
//!
//! `no_std`, allocation-free runtime of the Neural Equivalent Mechanical Model (NEMM) of a
//! degrading twin-tube suspension damper, and the definition of its weight format.
//!
//! Everything is at the crate root, in one curated list (the modules are private):
//!
//! - the online [`Estimator`]: one `step(sample) -> force` per sample, with its
//!   [`EstimatorConfig`], [`EvalMode`] (exact or tabulated evaluation), the [`Estimate`], its
//!   [`Flags`] and [`Diagnostics`];
//! - the [`Sample`] both steps take: the stroke velocity, and optionally the stroke
//!   position, the sample's level `alpha` and the measured force;
//! - the weight format: [`decode`] / [`decode_into`] (in place, for a `static`),
//!   [`decode_with_tables`], [`read_header`] and [`check_frame`], [`encode`] /
//!   [`encode_with_tables`], the [`Header`], the stored tables ([`StoredTables`],
//!   [`StoredUnused`]) and the framing constants ([`MAGIC`], [`FORMAT_VERSION`], [`CRC`]);
//! - the [`Model`] and the types it is made of ([`ModelKind`], [`Body`], [`Condition`],
//!   [`Scaler`], [`CumulativeScalers`], [`SemMap`], [`StaticForce`], [`LostMotion`],
//!   [`Integrator`], ...) and the step-stability check ([`shortest_stable_time_constant_s`], [`STABILITY_MARGIN`]);
//! - the typed errors: [`DecodeError`], [`ModelError`], [`EstimatorError`], [`EncodeError`],
//!   [`TableError`], [`LevelsError`], [`ObserverError`];
//! - the [`AlphaObserver`]: the oil-loss level `alpha` online from the measured velocity and
//!   force, with an uncertainty band and flags (excitation, range, sensor faults), its
//!   [`ObserverConfig`], [`AlphaEstimate`] and [`ObserverFlags`];
//! - [`LevelTables`]: the stored tables of several oil-loss levels, for a level per sample
//!   at table cost (attached to an estimator, [`Estimator::attach_levels`]) and a
//!   table-cost observer
//!   ([`AlphaObserver::load_on_levels`]);
//! - [`LowPass`] and [`Differentiator`]: the causal stroke-velocity estimate (backward
//!   difference and first-order low-pass) that feeds the estimator online;
//! - the fixed capacities a firmware sizes its RAM by ([`MAX_HIDDEN`], [`MAX_LAYERS`],
//!   [`MAX_TABLE_LEVELS`], [`DEFAULT_OBSERVER_POINTS`], ...).
//!
//! How each part works (what happens per step, the blob layout, the observer's method and
//! cost) is written at the top of its source file (`src/estimator.rs`, `src/format.rs`,
//! `src/model.rs`, `src/observer.rs`, `src/velocity.rs`) and in the project's
//! `docs/core.md`.
//!
//! The model's arithmetic (EMM, scalers, Runge-Kutta step, SEM map, tables, math backends)
//! is the crate `nemm_kernels` below this one: public for the trainer (with its reverse
//! mode), tests and tools, outside this crate's stability promise. This crate re-exports the
//! kernel types its API is made of.
//!
//! Units are SI throughout: m, m/s, N, N s/m, N/m, s. `alpha` is the oil-loss fraction in
//! `[0, 1]`. All arithmetic is `f32`.
//!
//! ## Ten lines: load a blob and estimate force
//!
//! ```
//! # let blob = nemm_core::testing::example_blob();
//! use nemm_core::{decode, Estimator, EstimatorConfig, Model, Sample};
//!
//! let model: Model = decode(&blob).expect("valid weights");
//! let mut est = Estimator::new(&model, EstimatorConfig::new(0.15)).expect("alpha in range");
//! for k in 0..1000 {
//!     let t = k as f32 * model.dt_s;
//!     let v = 0.5 * (2.0 * core::f32::consts::PI * 5.0 * t).sin(); // stroke velocity [m/s]
//!     let e = est.step(Sample::new(v)).expect("no alpha in the sample: never refused");
//!     assert!(e.force_n.is_finite() && e.flags.is_empty());
//! }
//! ```
//!
//! Nothing in this crate panics on any input or blob (`clippy::indexing_slicing`,
//! `unwrap_used`, `expect_used`, `panic` are denied outside tests); every failure is a typed
//! error ([`DecodeError`], [`ModelError`], [`EstimatorError`]).
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![cfg_attr(docsrs, feature(doc_cfg))]
#![deny(unsafe_code)]
// Without an allocator, variants cannot be boxed; sizes are bounded by the capacities.
#![allow(clippy::large_enum_variant)]
#![cfg_attr(
    not(test),
    deny(
        clippy::indexing_slicing,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::unreachable,
        clippy::todo
    )
)]

mod estimator;
mod format;
mod limits;
mod model;
mod observer;
mod sample;
#[cfg(any(test, feature = "testing"))]
#[cfg_attr(docsrs, doc(cfg(feature = "testing")))]
pub mod testing;
mod velocity;

// The online estimator.
#[cfg(feature = "std")]
pub use estimator::encode_to_vec_with_tables;
pub use estimator::{
    encode_with_tables, encoded_len_with_tables, BlendCheck, Diagnostics, Estimate, Estimator,
    EstimatorConfig, EstimatorError, EvalMode, Flags, LevelTables, LevelsError, TableOrigin,
    DEFAULT_VELOCITY_LIMIT_FACTOR, DIVERGENCE_FACTOR,
};
// The weight format.
pub use format::tables::{StoredLevel, StoredTable, StoredTables, StoredUnused};
pub use format::{
    check_frame, decode, decode_into, decode_with_tables, encode, encoded_len, read_header,
    DecodeError, EncodeError, Frame, Header, CRC, CRC_LEN, FORMAT_VERSION, MAGIC, MAX_HEADER_LEN,
    OLDEST_FORMAT_VERSION,
};
#[cfg(feature = "std")]
pub use format::{encode_to_vec, AlignedBlob};
pub use nemm_kernels::table::StoredLayout;
// The model.
pub use model::{
    shortest_stable_time_constant_s, AlphaBranches, Body, Condition, CumulativeScalers,
    InputScales, Meta, Model, ModelKind, Priors, Provenance, STABILITY_MARGIN,
};
// The alpha observer.
pub use observer::{
    AlphaEstimate, AlphaObserver, ObserverConfig, ObserverError, ObserverFlags,
    DEFAULT_CHANGE_TOLERANCE, DEFAULT_CROSSING_HYSTERESIS, DEFAULT_HORIZON_S, DEFAULT_MAX_BAND,
    DEFAULT_RESIDUAL_CORRELATION_S, DEFAULT_SETTLE_TOLERANCE, WINDOW_BLOCKS,
};
// One sample, the input of both steps.
pub use sample::Sample;
// The velocity estimate.
pub use velocity::{Differentiator, LowPass, DEFAULT_CUTOFF_HZ};
// The capacities a firmware sizes its RAM by.
pub use limits::{
    DEFAULT_OBSERVER_POINTS, MAX_TABLE_LEVELS, PROVENANCE_COMMAND_LEN, PROVENANCE_COMMIT_LEN,
    PROVENANCE_DATASET_LEN,
};
pub use nemm_kernels::limits::{
    MAX_BRANCH_UNITS, MAX_CONDITION_NAME, MAX_CONDITION_UNIT, MAX_HIDDEN, MAX_INPUTS, MAX_LAYERS,
    MAX_SEM_ALPHAS, MAX_SEM_FORCES, MAX_SEM_VELOCITIES, SCALE_RANGE,
};
// The errors a model is refused with.
pub use nemm_kernels::error::{
    BranchError, CumulativeModelError, ModelError, SemError, ShapeError, UnknownName,
};
// The kernel types the model and the estimator are made of (their arithmetic is
// `nemm_kernels`').
pub use nemm_kernels::cumulative::{
    cumulative_param_count, CumulativeError, CumulativeScaler, MAX_CUMULATIVE_UNITS,
};
pub use nemm_kernels::emm::{Coefficients, EmmConstants, State};
pub use nemm_kernels::integrator::Integrator;
pub use nemm_kernels::lost_motion::LostMotion;
pub use nemm_kernels::mlp::{
    param_count, AlphaBranch, Direction, MlpParams, Scaler, DEFAULT_PARAM_CAPACITY,
};
pub use nemm_kernels::sem::SemMap;
pub use nemm_kernels::static_force::StaticForce;
pub use nemm_kernels::table::{TableAccuracy, TableConfig, TableError, DEFAULT_TABLE_SEGMENTS};
