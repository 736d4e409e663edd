//! # nemm-train
//!
//! Host side of the NEMM project: test-bench data (interchange format and a first-principles
//! virtual bench), the preprocessing of section 5.3, training and evaluation of the four model
//! variants (sections 5-6) and export to the `nemm-core` weight format.

pub mod bench;
pub mod data_cli;
pub mod dataset;
pub mod figures;
pub mod fsutil;
pub mod inspect;
pub mod plot;
pub mod preprocess;
pub mod report;
pub mod table_check;
pub mod train;
pub mod train_cli;
