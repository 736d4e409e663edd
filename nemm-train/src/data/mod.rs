//! Bench data in the trainer: raw logger files imported into the dataset interchange format
//! ([`nemm_dataset`]), plausibility checks, and the preprocessing into training sequences
//! (section 5.3).
pub(crate) mod against_model;
pub mod check;
pub mod import;
pub mod preprocess;
pub mod support_points;
