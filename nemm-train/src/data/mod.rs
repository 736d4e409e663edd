//! Bench data: the dataset interchange format (manifest + CSV) and its preprocessing into
//! training sequences (section 5.3).
pub mod against_model;
pub mod check;
pub(crate) mod csv;
pub mod dataset;
pub mod import;
pub mod preprocess;
pub mod support_points;
