//! The fixed capacities of this allocation-free crate: what a model may hold and what the
//! RAM of a [`crate::Model`] and a [`crate::Estimator`] is sized by. The errors
//! ([`crate::ModelError`], [`crate::ShapeError`]) name these limits; the modules that use
//! them re-export them.

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

/// Most oil-loss levels a blob's tables section holds.
pub const MAX_TABLE_LEVELS: usize = 16;

/// Longest condition name in bytes.
pub const MAX_CONDITION_NAME: usize = 32;
/// Longest condition unit in bytes.
pub const MAX_CONDITION_UNIT: usize = 16;
/// Longest [`crate::Provenance::command`] in bytes.
pub const PROVENANCE_COMMAND_LEN: usize = 192;
/// Longest [`crate::Provenance::dataset`] in bytes.
pub const PROVENANCE_DATASET_LEN: usize = 96;
/// Longest [`crate::Provenance::commit`] in bytes.
pub const PROVENANCE_COMMIT_LEN: usize = 48;

/// Accepted range of the normalisation scales and the force scale (SI units).
pub const SCALE_RANGE: (f32, f32) = (1e-9, 1e9);

/// Default number of levels of an [`crate::AlphaObserver`]'s grid, and its default capacity
/// `K`: 7 levels over a trained range of 0 to 0.3 are 0.05 apart (measured against 4 and
/// 31 levels in `docs/observer.md`).
pub const DEFAULT_OBSERVER_POINTS: usize = 7;
