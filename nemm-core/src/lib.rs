//! # nemm-core
//!
//! `no_std`, allocation-free runtime of the Neural Equivalent Mechanical Model (NEMM) of a
//! degrading twin-tube suspension damper, and the definition of its weight format.
//!
//! What a firmware (or a C wrapper) uses is at the crate root:
//!
//! - the online [`Estimator`]: one `step(sample) -> force` per sample, with its
//!   [`EstimatorConfig`], the [`Estimate`] and its [`Flags`] (module [`estimator`]: what
//!   happens per step, exact or tabulated evaluation);
//! - the [`Sample`] both steps take: the stroke velocity, and optionally the stroke
//!   position, the sample's level `alpha` and the measured force (module [`sample`]);
//! - the weight format: [`decode`] / [`decode_into`] (in place, for a `static`),
//!   [`read_header`], [`encode`]; the layout and the tables section in [`format`](mod@format);
//! - the [`Model`] and the types it is made of ([`ModelKind`], [`Body`], [`Condition`],
//!   ...; module [`model`]: the four variants and the step-stability check);
//! - the typed errors: [`DecodeError`], [`ModelError`], [`EstimatorError`], [`EncodeError`],
//!   [`TableError`];
//! - the [`AlphaObserver`]: the oil-loss level `alpha` online from the measured velocity and
//!   force, with an uncertainty band and flags (excitation, range, sensor faults), its
//!   [`ObserverConfig`], [`AlphaEstimate`], [`ObserverFlags`] and [`ObserverError`] (module
//!   [`observer`]: the method, its cost);
//! - [`LevelTables`]: the stored tables of several oil-loss levels, for a level per sample
//!   at table cost (attached to an estimator, [`Estimator::attach_levels`]) and a table-cost
//!   observer
//!   ([`AlphaObserver::load_on_levels`]) (module `estimator`, section "Every level");
//! - [`velocity`]: the causal stroke-velocity estimate (backward difference and first-order
//!   low-pass) that feeds the estimator online;
//! - [`limits`]: the fixed capacities a firmware sizes its RAM by.
//!
//! The model's arithmetic (EMM, scalers, Runge-Kutta step, SEM map, tables, math backends)
//! is in [`semantics`], public for the trainer and tests but outside the stability promise.
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

mod error;
pub mod estimator;
pub mod format;
pub mod limits;
pub mod model;
pub mod observer;
pub mod sample;
#[cfg(feature = "semantics")]
#[cfg_attr(docsrs, doc(cfg(feature = "semantics")))]
pub mod semantics;
// Without the feature the arithmetic is the crate's own: the items only the trainer and the
// tools call are compiled with the feature (or for tests) alone.
#[cfg(not(feature = "semantics"))]
mod semantics;
#[cfg(any(test, feature = "testing"))]
#[cfg_attr(docsrs, doc(cfg(feature = "testing")))]
pub mod testing;
pub mod velocity;
mod wire;

// The arithmetic modules by their short names inside the crate.
use semantics::{emm, integrator, lost_motion, math, mlp, sem, static_force, table};

pub use error::{BranchError, ModelError, SemError, ShapeError, UnknownName};
#[cfg(feature = "std")]
pub use estimator::encode_to_vec_with_tables;
pub use estimator::{
    encode_with_tables, encoded_len_with_tables, Diagnostics, Estimate, Estimator, EstimatorConfig,
    EstimatorError, EvalMode, Flags, LevelTables, LevelsError, TableOrigin,
};
#[cfg(feature = "std")]
pub use format::encode_to_vec;
pub use format::tables::{StoredTables, StoredUnused};
pub use format::{
    decode, decode_into, decode_with_tables, encode, encoded_len, read_header, DecodeError,
    EncodeError, Header, FORMAT_VERSION, OLDEST_FORMAT_VERSION,
};
pub use model::{
    AlphaBranches, Body, Condition, InputScales, Meta, Model, ModelKind, Priors, Provenance,
};
pub use observer::{AlphaEstimate, AlphaObserver, ObserverConfig, ObserverError, ObserverFlags};
pub use sample::Sample;
pub use semantics::emm::EmmConstants;
pub use semantics::integrator::Integrator;
pub use semantics::lost_motion::LostMotion;
pub use semantics::mlp::{
    param_count, AlphaBranch, Direction, MlpParams, Scaler, DEFAULT_PARAM_CAPACITY,
};
pub use semantics::sem::SemMap;
pub use semantics::static_force::StaticForce;
pub use semantics::table::{TableAccuracy, TableConfig, TableError, DEFAULT_TABLE_SEGMENTS};
