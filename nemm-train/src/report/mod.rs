//! Results of a trained model and of a dataset: Table 4 / 5 and the JSON report
//! ([`Report`], [`evaluate`], [`test_runs_markdown`]), the identifiability of the level and
//! the whole-run errors per level and condition ([`IdentifyReport`], [`identify_report`]), the
//! comparison with the virtual bench's reference coefficients ([`compare_reference`]), the
//! whole-run predictions the loop figures draw ([`RunPredictions`]), the figures
//! ([`write_all`], [`write_all_with_reference`], [`figure_predictions`]) and the plots of a
//! bench dataset ([`plot_dataset`], [`plot_loaded`], [`cycle_loop`]), the text report of a
//! dataset's check ([`check_report`]), the description of a
//! weights blob ([`inspect`]), and the online alpha observer on a recorded run
//! ([`diagnose_run`]).
//!
//! These re-exports are the module's public surface (what the `nemm` command line and the
//! integration tests use). The submodules are internal: the tables (`tables`), the
//! identifiability report (`identify`), the degradation signature (Fig. 5, measured against
//! modelled: `signature`) and what a training job's report says of the degradation
//! (`degradation`), the degradation targets each against its bar (`targets`), the
//! reference comparison (`reference`), the figures (`figures`, `bench_plots`) drawn with the
//! plotting helpers (`plot`), the reports of `nemm data check` and `prepare` (`dataset`), the
//! blob description (`inspect`) and the observer on recorded
//! runs (`diagnose`) with its accuracy (`accuracy`) and a level step (`level_step`).
pub(crate) mod accuracy;
pub(crate) mod bench_plots;
pub(crate) mod dataset;
pub(crate) mod degradation;
pub(crate) mod diagnose;
pub(crate) mod figures;
pub(crate) mod identify;
pub(crate) mod inspect;
pub(crate) mod level_step;
mod plot;
mod predictions;
pub(crate) mod reference;
pub(crate) mod signature;
pub(crate) mod tables;
pub(crate) mod targets;

pub use bench_plots::{cycle_loop, plot_dataset, plot_loaded, CycleLoop, Plotted};
pub use dataset::check_report;
pub use diagnose::{diagnose_run, RunDiagnosis, AGREEMENT};
pub use figures::{figure_predictions, write_all, write_all_with_reference};
pub use identify::{identify_report, used_runs, IdentifyReport};
pub use inspect::run as inspect;
pub use predictions::RunPredictions;
pub use reference::{compare as compare_reference, ReferenceComparison};
pub use tables::{evaluate, test_runs_markdown, Report, RunBreakdown, VariantReport};
