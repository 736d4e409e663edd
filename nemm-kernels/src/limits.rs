//! The fixed capacities of the model's parts: what a scaler, an alpha branch, the SEM map
//! and a condition may hold, which sizes the RAM of nemm-core's `Model` and `Estimator`.
//! The errors ([`crate::error::ModelError`], [`crate::error::ShapeError`]) name these
//! limits; the modules that use them re-export them. nemm-core adds the capacities of its
//! own layers (tables section, provenance, observer).

/// Largest hidden width `H` of a scaler's MLP (Table 3 search space).
pub const MAX_HIDDEN: usize = 32;
/// Largest number of hidden layers `L` of a scaler's MLP (Table 3 search space).
pub const MAX_LAYERS: usize = 9;
/// Largest number of scaler inputs (state and `alpha`).
pub const MAX_INPUTS: usize = 2;
/// Largest number of units `K` of an alpha branch.
pub const MAX_BRANCH_UNITS: usize = 32;

/// Capacity of the SEM map's velocity axis.
pub const MAX_SEM_VELOCITIES: usize = 64;
/// Capacity of the SEM map's alpha axis.
pub const MAX_SEM_ALPHAS: usize = 8;
/// Capacity of the SEM map's force table.
pub const MAX_SEM_FORCES: usize = MAX_SEM_VELOCITIES * MAX_SEM_ALPHAS;

/// Longest condition name in bytes.
pub const MAX_CONDITION_NAME: usize = 32;
/// Longest condition unit in bytes.
pub const MAX_CONDITION_UNIT: usize = 16;

/// Accepted range of the normalisation scales and the force scale (SI units).
pub const SCALE_RANGE: (f32, f32) = (1e-9, 1e9);
