//! # nemm-core
//!
//! `no_std`, allocation-free runtime of the Neural Equivalent Mechanical Model (NEMM) of a
//! degrading twin-tube suspension damper, and the definition of its weight format.
//!
//! - [`emm`]: the EMM right-hand side and force (eqs. 15-17 / 20-21) with their derivation.
//! - [`mlp`]: the neural scalers (section 5.4) and their bounded positive output mapping.
//! - [`integrator`]: fixed-step RK4 / RK3 with linear interpolation of the input.
//! - [`model`]: the four variants (SEM, Linear EMM, NEMM-Light, NEMM) and their validation.
//! - [`format`](mod@format): the postcard weight blob with magic, version and CRC-32.
//! - [`estimator`]: the online estimator, one `step(velocity) -> force` per sample.
//! - [`sem`]: the static force-velocity map.
//! - [`static_force`]: the optional static force of eq. 17 (gas force, seal friction).
//! - [`table`]: the tabulated fixed-alpha fast path (1-D cubic tables with a verified error
//!   bound).
//! - [`velocity`]: the causal stroke-velocity estimate (backward difference and first-order
//!   low-pass) that feeds the estimator online.
//! - [`math`]: `exp`, `sqrt` and `fma` backends (`libm` exact, `micromath` fast).
//!
//! Units are SI throughout: m, m/s, N, N s/m, N/m, s. `alpha` is the oil-loss fraction in
//! `[0, 1]`. All arithmetic is `f32`.
//!
//! ## Ten lines: load a blob and estimate force
//!
//! ```
//! # let blob = nemm_core::testing::example_blob();
//! use nemm_core::{decode, Estimator, EstimatorConfig, Model};
//!
//! let model: Model = decode(&blob).expect("valid weights");
//! let mut est = Estimator::new(&model, EstimatorConfig::new(0.15)).expect("alpha in range");
//! for k in 0..1000 {
//!     let t = k as f32 * model.dt_s;
//!     let v = 0.5 * (2.0 * core::f32::consts::PI * 5.0 * t).sin(); // stroke velocity [m/s]
//!     let e = est.step(v);
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

pub mod emm;
mod error;
pub mod estimator;
pub mod format;
pub mod integrator;
pub mod math;
pub mod mlp;
pub mod model;
pub mod sem;
pub mod static_force;
pub mod stored_tables;
pub mod table;
#[cfg(any(test, feature = "testing"))]
#[cfg_attr(docsrs, doc(cfg(feature = "testing")))]
pub mod testing;
pub mod velocity;

pub use emm::{Coefficients, EmmConstants, State};
pub use error::UnknownName;
pub use estimator::{
    Diagnostics, Estimate, Estimator, EstimatorConfig, EstimatorError, EvalMode, Flags, TableOrigin,
};
pub use format::{
    decode, decode_into, encode, encode_with_tables, read_header, DecodeError, EncodeError, Header,
    FORMAT_VERSION, OLDEST_FORMAT_VERSION,
};
pub use integrator::Integrator;
pub use mlp::{AlphaBranch, Direction, MlpParams, Scaler, DEFAULT_PARAM_CAPACITY};
pub use model::{
    AlphaBranches, Body, Condition, Extension, InputScales, Meta, Model, ModelError, ModelKind,
    Priors, Provenance,
};
pub use sem::SemMap;
pub use static_force::StaticForce;
pub use stored_tables::{StoredTables, StoredUnused};
pub use table::{Table1D, TableAccuracy, TableConfig, TableError, DEFAULT_TABLE_SEGMENTS};

#[cfg(feature = "std")]
pub use format::{encode_to_vec, encode_to_vec_with_tables};
