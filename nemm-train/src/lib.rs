//! # nemm-train
//!
//! Host side of the NEMM project: import and preprocessing of test-bench data (section 5.3),
//! training and evaluation of the four model variants (sections 5-6), reports and export to
//! the `nemm-core` weight format. The dataset interchange format is the `nemm-dataset` crate,
//! the virtual test bench that synthesises datasets the `nemm-virtual-bench` crate.
//!
//! The modules follow the data (see `ARCHITECTURE.md` at the repository root):
//!
//! - [`data`]: raw-data import ([`data::import`]), plausibility checks ([`data::check`]),
//!   the preprocessing of section 5.3 ([`data::preprocess`], [`data::support_points`]) of
//!   datasets in the interchange format ([`nemm_dataset`]), and loading a prepared dataset
//!   ([`data::load_prepared`]);
//! - [`train`]: the rollout and its adjoint, the physics losses, the training loop, the four
//!   variants, evaluation and export checks;
//! - [`report`]: Table 4 / 5, figures and plotting, blob descriptions, the reports of a
//!   dataset; its public surface is the re-exports in the module, its submodules are
//!   internal;
//! - [`config`]: the configuration of a job (data, model, training), its defaults and TOML;
//! - [`cli`]: the `nemm` command line, a thin layer over the modules above: argument types
//!   and the handlers `src/main.rs` calls;
//! - `output_guard` (internal): the output rule every command checks before any work.
//!
//! An item is `pub` only where a user outside the crate (the binary, the integration tests,
//! benches and examples, the `nemm-tests` crate) reaches it; everything else is `pub(crate)`
//! or private, which the `unreachable_pub` lint keeps so. Re-exports name their items (no
//! glob re-exports).

#![warn(unreachable_pub)]

pub mod cli;
pub mod config;
pub mod data;
pub(crate) mod output_guard;
pub mod report;
pub mod train;
