//! The test-bench dataset interchange format (see `docs/data-format.md`).
//!
//! A dataset is a folder with `manifest.toml` and one CSV file per run:
//!
//! ```toml
//! name = "my damper"
//! sample_rate_hz = 10000.0
//! [[runs]]
//! file = "runs/oil15_a010_v0524.csv"   # relative to the manifest
//! oil_loss = 0.15                       # alpha: fraction of oil volume lost, 0..1
//! amplitude_m = 0.010                   # optional metadata
//! target_velocity_m_s = 0.524           # optional metadata
//! ```
//!
//! Each CSV has a header and one row per sample: `time_s,displacement_m,force_n`, optionally
//! `velocity_m_s`. Displacement positive = extension (rebound); force positive = tension
//! (rebound force). Values are `f64` in memory.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// File name of the manifest inside a dataset folder.
pub const MANIFEST_FILE: &str = "manifest.toml";

/// The manifest: dataset name, sample rate and the list of runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Human-readable name of the damper / dataset.
    pub name: String,
    /// Sample rate of every run \[Hz\].
    pub sample_rate_hz: f64,
    /// The runs.
    pub runs: Vec<RunEntry>,
}

/// One run as listed in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunEntry {
    /// CSV file, relative to the manifest.
    pub file: PathBuf,
    /// Oil-loss level `alpha` (fraction of oil volume lost, 0..1).
    pub oil_loss: f64,
    /// Stroke amplitude \[m\] (optional metadata).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub amplitude_m: Option<f64>,
    /// Target peak velocity \[m/s\] (optional metadata).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target_velocity_m_s: Option<f64>,
}

/// One loaded run: the manifest entry and its samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    /// The manifest entry.
    pub entry: RunEntry,
    /// Sample times \[s\].
    pub time_s: Vec<f64>,
    /// Stroke displacement \[m\], positive = extension.
    pub displacement_m: Vec<f64>,
    /// Measured force \[N\], positive = tension.
    pub force_n: Vec<f64>,
    /// Measured stroke velocity \[m/s\], if the file has the column.
    pub velocity_m_s: Option<Vec<f64>>,
}

/// A whole dataset in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Name from the manifest.
    pub name: String,
    /// Sample rate \[Hz\].
    pub sample_rate_hz: f64,
    /// The runs, in manifest order.
    pub runs: Vec<Run>,
}
