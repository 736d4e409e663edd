//! Bench data in the trainer: raw logger files imported into the dataset interchange format
//! ([`nemm_dataset`]), plausibility checks, and the preprocessing into training sequences
//! (section 5.3).
//!
//! The public surface is four modules, their helpers crate-private: [`import`] (raw files
//! into a dataset), [`check`] (plausibility findings), [`preprocess`] (signals, split,
//! sequences, scales: [`preprocess::prepare`]) and [`support_points`] (periodicity and
//! quasi-static points of any excitation); and the loading of a prepared dataset
//! ([`load_prepared`], [`load_dataset_prepared`]). The check of recorded runs against a
//! trained model (`against_model`) is internal.
pub(crate) mod against_model;
pub mod check;
pub mod import;
pub mod preprocess;
pub mod support_points;

use anyhow::{Context, Result};
use nemm_dataset as dataset;
use preprocess::{PrepareConfig, Prepared};
use std::path::Path;
use std::time::Instant;

/// Loads and prepares a dataset, printing a one-line summary.
pub fn load_prepared(dir: &Path, cfg: &PrepareConfig) -> Result<Prepared> {
    load_dataset_prepared(dir, cfg).map(|(_, p)| p)
}

/// Loads and prepares a dataset; returns both (figures need the whole runs).
pub fn load_dataset_prepared(
    dir: &Path,
    cfg: &PrepareConfig,
) -> Result<(dataset::Dataset, Prepared)> {
    let t = Instant::now();
    let ds = dataset::load(dir)
        .with_context(|| format!("cannot load the dataset in {}", dir.display()))?;
    let prepared = preprocess::prepare(&ds, cfg)?;
    eprintln!(
        "dataset {:?}: {} runs; {} train / {} validation / {} test windows of {} + {} warm-up samples; force scale {:.0} N ({:.1} s)",
        ds.name,
        ds.runs.len(),
        prepared.train.len(),
        prepared.validation.len(),
        prepared.test.len(),
        prepared.scored_samples,
        prepared.warmup_samples,
        prepared.scales.force_n,
        t.elapsed().as_secs_f64()
    );
    if prepared.test.is_empty() {
        eprintln!(
            "warning: no test windows ({}); test RMSE will be NaN",
            cfg.split.describe()
        );
    }
    Ok((ds, prepared))
}
