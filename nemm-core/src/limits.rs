//! The fixed capacities of nemm-core's own layers: the weight format's tables section, the
//! provenance record and the alpha observer. The capacities of the model's parts (scalers,
//! branches, SEM map, condition) are nemm-kernels' (`nemm_kernels::limits`); the crate root
//! re-exports both.

/// Most oil-loss levels a blob's tables section holds.
pub const MAX_TABLE_LEVELS: usize = 16;

/// Longest [`crate::Provenance::command`] in bytes.
pub const PROVENANCE_COMMAND_LEN: usize = 192;
/// Longest [`crate::Provenance::dataset`] in bytes.
pub const PROVENANCE_DATASET_LEN: usize = 96;
/// Longest [`crate::Provenance::commit`] in bytes.
pub const PROVENANCE_COMMIT_LEN: usize = 48;

/// Default number of levels of an [`crate::AlphaObserver`]'s grid, and its default capacity
/// `K`: 7 levels over a trained range of 0 to 0.3 are 0.05 apart (measured against 4 and
/// 31 levels in `docs/observer.md`).
pub const DEFAULT_OBSERVER_POINTS: usize = 7;
