//! # nemm-train
//!
//! Host side of the NEMM project: test-bench data (interchange format and a first-principles
//! virtual bench), the preprocessing of section 5.3, training and evaluation of the four model
//! variants (sections 5-6) and export to the `nemm-core` weight format.
//!
//! The modules follow the data (see `ARCHITECTURE.md` at the repository root):
//!
//! - [`data`]: the dataset interchange format and the preprocessing of section 5.3;
//! - [`bench`](mod@bench): the virtual test bench that synthesises a dataset;
//! - [`train`]: the rollout and its adjoint, the physics losses, the training loop, the four
//!   variants, evaluation and export checks;
//! - [`report`]: Table 4 / 5, figures and plotting, blob descriptions;
//! - [`config`]: the configuration of a job (data, model, training), its defaults and TOML;
//! - [`cli`]: the `nemm` command line, a thin layer over the modules above;
//! - [`output_guard`]: the output rule every command checks before any work.

pub mod atomic_file;
pub mod bench;
pub mod cli;
pub mod config;
pub mod data;
pub mod output_guard;
pub mod report;
pub mod train;
