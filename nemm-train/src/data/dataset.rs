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
//! An optional `[condition]` table names what `alpha` stands for ([`ConditionSpec`]; default:
//! the paper's oil loss, every coefficient decreasing with it), and `alpha` is accepted as
//! a synonym of a run's `oil_loss`:
//!
//! ```toml
//! [condition]
//! name = "gas charge"       # used in tables, figures and the blob
//! unit = "psi"
//! at_alpha_0 = 150.0        # condition value at alpha = 0 and at alpha = 1 (linear map)
//! at_alpha_1 = 50.0
//! b_fl = "decreasing"       # prior of each coefficient in alpha:
//! b_pr = "none"             # "decreasing", "increasing" or "none"
//! k_pr = "increasing"
//! ```
//!
//! Each CSV has a header and one row per sample: `time_s,displacement_m,force_n`, optionally
//! `velocity_m_s` and `alpha` (the condition level per sample, in \[0, 1\], for a condition
//! changing within the run). Displacement positive = extension (rebound); force positive =
//! tension (rebound force). Values are `f64` in memory.
//!
//! Time stamps must lie on a uniform grid, as loggers write them: rounded or jittered stamps
//! are accepted when they stay within a quarter step of the least-squares grid
//! `t = t0 + i dt` (see [`check_time_grid`] for the rule), and the fitted rate must match
//! `sample_rate_hz` within [`MAX_RATE_MISMATCH`]. Gaps (missing samples) and times that do
//! not increase are refused with their line. Nothing is resampled by the loader.
//!
//! [`load`] refuses every malformed input with a [`DatasetError`] that names the file, the
//! line and (where there is one) the column or manifest key; nothing is silently dropped.
//! [`write()`] writes each file atomically (temporary file + rename, manifest last) with
//! Rust's shortest round-trip float format, so `load(write(d)) == d` exactly.

use nemm_core::{Condition, Direction, Priors};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use toml::Spanned;

/// File name of the manifest inside a dataset folder.
pub const MANIFEST_FILE: &str = "manifest.toml";

/// Largest accepted deviation of a time stamp from the fitted uniform grid, as a fraction of
/// the fitted step (a quarter step).
///
/// Rounding stamps to a resolution `q` moves them at most `q / 2` off the grid, so every
/// logger resolution up to half a sample step is accepted (e.g. 3 kHz rounded to 0.1 ms:
/// `q = 0.3 dt`, deviations up to `0.15 dt`, steps of 0.3 and 0.4 ms), as is random jitter
/// of up to a quarter step. A missing sample moves the following stamps a whole step off,
/// far outside this band.
pub const MAX_GRID_DEVIATION: f64 = 0.25;

/// Largest accepted relative difference between the rate fitted to the time stamps and the
/// manifest's `sample_rate_hz` (1 %).
pub const MAX_RATE_MISMATCH: f64 = 0.01;

/// A time step longer than this many nominal steps `1 / sample_rate_hz` is a gap (missing
/// samples). With rounding to at most half a step, regular steps stay below it.
pub const GAP_STEPS: f64 = 1.5;

/// Deviations from the fitted grid below this fraction of a step count as exact (the
/// float noise of stamps written as decimal numbers).
const EXACT_GRID_DEVIATION: f64 = 1e-6;

/// Name of the time column \[s\].
pub const COL_TIME: &str = "time_s";
/// Name of the displacement column \[m\].
pub const COL_DISPLACEMENT: &str = "displacement_m";
/// Name of the force column \[N\].
pub const COL_FORCE: &str = "force_n";
/// Name of the optional measured velocity column \[m/s\].
pub const COL_VELOCITY: &str = "velocity_m_s";
/// Name of the optional per-sample condition level column (alpha changing within a run, in
/// \[0, 1\]).
pub const COL_ALPHA: &str = "alpha";

/// The manifest: dataset name, sample rate, the condition and the list of runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Human-readable name of the damper / dataset.
    pub name: String,
    /// Sample rate of every run \[Hz\].
    pub sample_rate_hz: f64,
    /// What `alpha` stands for (`None`: the paper's oil loss).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub condition: Option<ConditionSpec>,
    /// The runs.
    pub runs: Vec<RunEntry>,
}

/// The degradation condition of a dataset, as the manifest's `[condition]` table declares
/// it: name and unit, the linear map from `alpha` in `[0, 1]` to the condition value, and
/// the direction of each coefficient's monotonicity prior in `alpha` (eqs. 31, 37-38).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConditionSpec {
    /// Name, e.g. `gas charge` (1 to [`nemm_core::model::MAX_CONDITION_NAME`] bytes).
    pub name: String,
    /// Unit of the condition value, e.g. `psi` (default `-`; at most
    /// [`nemm_core::model::MAX_CONDITION_UNIT`] bytes).
    #[serde(default = "ConditionSpec::default_unit")]
    pub unit: String,
    /// Condition value at `alpha = 0` (default 0).
    #[serde(default)]
    pub at_alpha_0: f64,
    /// Condition value at `alpha = 1` (default 1).
    #[serde(default = "ConditionSpec::default_at_alpha_1")]
    pub at_alpha_1: f64,
    /// Prior of `b_fl` in alpha (default decreasing).
    #[serde(default)]
    pub b_fl: Direction,
    /// Prior of `b_pr` in alpha (default decreasing).
    #[serde(default)]
    pub b_pr: Direction,
    /// Prior of `k_pr` in alpha (default decreasing).
    #[serde(default)]
    pub k_pr: Direction,
}

impl Default for ConditionSpec {
    /// The paper's condition: oil loss as a fraction, every coefficient decreasing with it.
    fn default() -> Self {
        Self::from_core(&Condition::default())
    }
}

impl ConditionSpec {
    /// The condition a weights blob carries.
    pub fn from_core(c: &Condition) -> Self {
        Self {
            name: c.name.as_str().into(),
            unit: c.unit.as_str().into(),
            at_alpha_0: f64::from(c.at_alpha_0),
            at_alpha_1: f64::from(c.at_alpha_1),
            b_fl: c.priors.b_fl,
            b_pr: c.priors.b_pr,
            k_pr: c.priors.k_pr,
        }
    }

    /// True if `alpha` is the condition value itself (`0 -> 0`, `1 -> 1`, unit `-`).
    pub fn is_alpha_itself(&self) -> bool {
        self.at_alpha_0 == 0.0 && self.at_alpha_1 == 1.0 && self.unit == "-"
    }

    /// The condition value at `alpha`.
    pub fn value_at(&self, alpha: f64) -> f64 {
        self.at_alpha_0 + (self.at_alpha_1 - self.at_alpha_0) * alpha
    }

    /// A table column title: `oil loss`, `gas charge [psi]`.
    pub fn column(&self) -> String {
        if self.is_alpha_itself() {
            self.name.clone()
        } else {
            format!("{} [{}]", self.name, self.unit)
        }
    }

    /// A value in a table column ([`Self::column`]): alpha itself, or the condition value.
    pub fn cell(&self, alpha: f64) -> String {
        if self.is_alpha_itself() {
            alpha.to_string()
        } else {
            format!("{:.4}", self.value_at(alpha))
                .trim_end_matches('0')
                .trim_end_matches('.')
                .to_string()
        }
    }

    /// A level in words: `oil loss 0.15`, `gas charge 100 psi (alpha 0.5)`.
    pub fn level(&self, alpha: f64) -> String {
        if self.is_alpha_itself() {
            format!("{} {alpha}", self.name)
        } else {
            format!(
                "{} {} {} (alpha {alpha})",
                self.name,
                self.cell(alpha),
                self.unit
            )
        }
    }

    /// A figure's alpha axis title: `oil loss α [-]`, `gas charge α (0: 150 psi, 1: 50 psi)`.
    pub fn axis_label(&self) -> String {
        if self.is_alpha_itself() {
            format!("{} α [-]", self.name)
        } else {
            format!(
                "{} α (0: {} {u}, 1: {} {u})",
                self.name,
                self.cell(0.0),
                self.cell(1.0),
                u = self.unit
            )
        }
    }

    fn default_unit() -> String {
        "-".into()
    }

    fn default_at_alpha_1() -> f64 {
        1.0
    }

    /// The condition as the weights blob carries it (`None` if a name or unit is too long or
    /// a value is not acceptable: the manifest check refuses those with their line).
    pub fn to_core(&self) -> Option<Condition> {
        Condition::new(
            &self.name,
            &self.unit,
            self.at_alpha_0 as f32,
            self.at_alpha_1 as f32,
            Priors {
                b_fl: self.b_fl,
                b_pr: self.b_pr,
                k_pr: self.k_pr,
            },
        )
        .ok()
    }
}

/// One run as listed in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunEntry {
    /// CSV file, relative to the manifest.
    pub file: PathBuf,
    /// Condition level `alpha` in `[0, 1]` (the paper's oil loss: fraction of oil volume
    /// lost); the manifest key `alpha` is accepted as well.
    #[serde(alias = "alpha")]
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
    /// Condition level per sample in \[0, 1\] (a condition changing within the run), if the
    /// file has the `alpha` column; it then replaces the manifest's level for the samples.
    pub alpha: Option<Vec<f64>>,
}

impl Run {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.time_s.len()
    }

    /// `true` if the run has no samples (never the case for a loaded run).
    pub fn is_empty(&self) -> bool {
        self.time_s.is_empty()
    }
}

/// A whole dataset in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Name from the manifest.
    pub name: String,
    /// Sample rate \[Hz\].
    pub sample_rate_hz: f64,
    /// What `alpha` stands for (`None`: the paper's oil loss).
    pub condition: Option<ConditionSpec>,
    /// The runs, in manifest order.
    pub runs: Vec<Run>,
}

impl Dataset {
    /// The sample step `1 / sample_rate_hz` \[s\].
    pub fn dt_s(&self) -> f64 {
        1.0 / self.sample_rate_hz
    }

    /// Total number of samples over all runs.
    pub fn total_samples(&self) -> usize {
        self.runs.iter().map(Run::len).sum()
    }

    /// The condition as models carry it: the manifest's, or the paper's oil loss.
    pub fn condition(&self) -> Condition {
        self.condition
            .as_ref()
            .and_then(ConditionSpec::to_core)
            .unwrap_or_default()
    }

    /// The manifest describing this dataset.
    pub fn manifest(&self) -> Manifest {
        Manifest {
            name: self.name.clone(),
            sample_rate_hz: self.sample_rate_hz,
            condition: self.condition.clone(),
            runs: self.runs.iter().map(|r| r.entry.clone()).collect(),
        }
    }
}

/// Progress of [`load_with_progress`], reported after each finished run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoadProgress {
    /// Runs parsed so far (in any order; loading is parallel).
    pub runs_done: usize,
    /// Runs in the manifest.
    pub runs_total: usize,
    /// Samples parsed so far.
    pub samples_done: usize,
}

/// Why a dataset could not be loaded or written.
///
/// Paths are those of the files as opened: the dataset folder joined with the manifest
/// entry. Lines are 1-based; line 1 of a CSV file is its header.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DatasetError {
    /// A file could not be read, created or renamed.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating-system error (in the message, so not also reported as the error's
        /// source: error chains would print it twice).
        error: std::io::Error,
    },
    /// `manifest.toml` is not valid TOML or does not have the manifest's shape (missing or
    /// unknown key, wrong type).
    #[error("{}:{line}:{column}: {message}", path.display())]
    ManifestSyntax {
        /// The manifest.
        path: PathBuf,
        /// Line of the offending text.
        line: usize,
        /// Column (1-based, in characters) of the offending text.
        column: usize,
        /// What the TOML parser says.
        message: String,
    },
    /// A manifest value is out of range (`oil_loss` outside \[0, 1\], non-positive
    /// `sample_rate_hz`, empty or absolute `file`, no runs, ...).
    #[error("{}: {key}: {message}", location(path, *line))]
    ManifestValue {
        /// The manifest.
        path: PathBuf,
        /// Line of the value (`None` when validating an in-memory manifest for [`write()`]).
        line: Option<usize>,
        /// The key, e.g. `runs[3].oil_loss` (runs counted from 0).
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// The manifest names a run file that does not exist.
    #[error("{}: {key}: run file {} does not exist", location(manifest, Some(*line)), file.display())]
    MissingRunFile {
        /// The manifest.
        manifest: PathBuf,
        /// Line of the `file` value.
        line: usize,
        /// The key, e.g. `runs[3].file`.
        key: String,
        /// The missing file as it would be opened.
        file: PathBuf,
    },
    /// Two manifest entries name the same file.
    #[error("{}: {key}: {} is already listed as {first_key}", location(path, *line), file.display())]
    DuplicateRunFile {
        /// The manifest.
        path: PathBuf,
        /// Line of the second `file` value (`None` for an in-memory manifest).
        line: Option<usize>,
        /// The key of the duplicate, e.g. `runs[5].file`.
        key: String,
        /// The key of the first occurrence.
        first_key: String,
        /// The file named twice.
        file: PathBuf,
    },
    /// The CSV file has no content at all (not even a header).
    #[error("{}:1: the file is empty; expected the header `time_s,displacement_m,force_n`", path.display())]
    EmptyFile {
        /// The CSV file.
        path: PathBuf,
    },
    /// The CSV file has a header but no samples.
    #[error("{}:{line}: no samples after the header", path.display())]
    NoSamples {
        /// The CSV file.
        path: PathBuf,
        /// The line after the header.
        line: usize,
    },
    /// A required column is not in the header.
    #[error("{}:1: column \"{column}\" is missing (header: {header})", path.display())]
    MissingColumn {
        /// The CSV file.
        path: PathBuf,
        /// The missing column.
        column: String,
        /// The header as found.
        header: String,
    },
    /// A column name appears twice in the header.
    #[error("{}:1: column \"{column}\" appears more than once in the header", path.display())]
    DuplicateColumn {
        /// The CSV file.
        path: PathBuf,
        /// The repeated column.
        column: String,
    },
    /// A row has a different number of fields than the header.
    #[error("{}:{line}: {found} fields, but the header has {expected}", path.display())]
    FieldCount {
        /// The CSV file.
        path: PathBuf,
        /// The row's line.
        line: usize,
        /// Fields in the header.
        expected: usize,
        /// Fields in the row.
        found: usize,
    },
    /// A cell of a used column is not a number.
    #[error("{}:{line}: column \"{column}\": \"{value}\" is not a number", path.display())]
    NotANumber {
        /// The CSV file.
        path: PathBuf,
        /// The row's line.
        line: usize,
        /// The column.
        column: String,
        /// The cell as found.
        value: String,
    },
    /// A cell of a used column is NaN or infinite.
    #[error("{}:{line}: column \"{column}\": \"{value}\" is not a finite number", path.display())]
    NonFinite {
        /// The CSV file.
        path: PathBuf,
        /// The row's line.
        line: usize,
        /// The column.
        column: String,
        /// The cell as found (or formatted, when writing).
        value: String,
    },
    /// A per-sample condition level (`alpha` column) outside \[0, 1\].
    #[error("{}:{line}: column \"alpha\": {value} is outside [0, 1] (condition level)", path.display())]
    AlphaOutOfRange {
        /// The run file.
        path: PathBuf,
        /// Line of the sample (1-based; the header is line 1).
        line: usize,
        /// The value.
        value: f64,
    },
    /// Time does not strictly increase.
    #[error(
        "{}:{line}: column \"time_s\": {time} s does not increase (previous sample {previous} s)",
        path.display()
    )]
    NonMonotonicTime {
        /// The CSV file.
        path: PathBuf,
        /// The row's line.
        line: usize,
        /// This row's time \[s\].
        time: f64,
        /// The previous row's time \[s\].
        previous: f64,
    },
    /// A time step is longer than [`GAP_STEPS`] nominal steps: samples are missing.
    #[error(
        "{}:{line}: column \"time_s\": gap of {step} s after {previous} s, about {missing} \
         missing sample(s) at 1 / sample_rate_hz = {expected} s (cut the run there, or \
         resample explicitly with `nemm data import --resample-hz`)",
        path.display()
    )]
    Gap {
        /// The CSV file.
        path: PathBuf,
        /// The row's line (the step ends at this row).
        line: usize,
        /// Time of the previous row \[s\].
        previous: f64,
        /// The step \[s\].
        step: f64,
        /// The nominal step `1 / sample_rate_hz` \[s\].
        expected: f64,
        /// `round(step / expected) - 1`.
        missing: usize,
    },
    /// The rate fitted to the time stamps differs from `sample_rate_hz` by more than
    /// [`MAX_RATE_MISMATCH`].
    #[error(
        "{}: column \"time_s\": the time stamps give {fitted_hz} Hz (least-squares grid) but \
         the manifest says sample_rate_hz = {manifest_hz} Hz (at most {} % apart)",
        path.display(),
        MAX_RATE_MISMATCH * 100.0
    )]
    RateMismatch {
        /// The CSV file.
        path: PathBuf,
        /// Rate fitted to the time stamps \[Hz\].
        fitted_hz: f64,
        /// The manifest's `sample_rate_hz` \[Hz\].
        manifest_hz: f64,
    },
    /// A time stamp lies more than [`MAX_GRID_DEVIATION`] steps off the fitted uniform grid.
    #[error(
        "{}:{line}: column \"time_s\": {time} s is {deviation_us:.3} us off the fitted \
         uniform grid ({fitted_hz} Hz); at most a quarter step ({limit_us:.3} us) is accepted \
         as rounding or jitter (resample explicitly with `nemm data import --resample-hz`)",
        path.display()
    )]
    OffGrid {
        /// The CSV file.
        path: PathBuf,
        /// The row's line.
        line: usize,
        /// This row's time \[s\].
        time: f64,
        /// Deviation from the fitted grid \[us\] (signed: positive = late).
        deviation_us: f64,
        /// The accepted deviation, `MAX_GRID_DEVIATION * fitted step` \[us\].
        limit_us: f64,
        /// Rate of the fitted grid \[Hz\].
        fitted_hz: f64,
    },
    /// The CSV reader failed (malformed quoting, I/O while parsing).
    #[error("{}:{line}: {message}", path.display())]
    Csv {
        /// The CSV file.
        path: PathBuf,
        /// The line where the reader stopped.
        line: usize,
        /// The reader's message.
        message: String,
    },
    /// An in-memory run passed to [`write()`] has columns of different lengths.
    #[error("{}: column \"{column}\" has {found} values but \"time_s\" has {expected}", path.display())]
    LengthMismatch {
        /// The CSV file it was to be written to.
        path: PathBuf,
        /// The column.
        column: String,
        /// Length of `time_s`.
        expected: usize,
        /// Length of the column.
        found: usize,
    },
}

/// `path:line` or `path`.
fn location(path: &Path, line: Option<usize>) -> String {
    match line {
        Some(l) => format!("{}:{l}", path.display()),
        None => path.display().to_string(),
    }
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |error| DatasetError::Io {
        path: path.to_path_buf(),
        error,
    }
}

/// 1-based line and column (in characters) of a byte offset in `text`.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = text.get(..offset).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before[line_start..].chars().count() + 1;
    (line, column)
}

// ---------------------------------------------------------------------------------------------
// Manifest
// ---------------------------------------------------------------------------------------------

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    name: String,
    sample_rate_hz: Spanned<f64>,
    #[serde(default)]
    condition: Option<RawCondition>,
    #[serde(default)]
    runs: Vec<RawRun>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCondition {
    name: Spanned<String>,
    #[serde(default)]
    unit: Option<Spanned<String>>,
    #[serde(default)]
    at_alpha_0: Option<Spanned<f64>>,
    #[serde(default)]
    at_alpha_1: Option<Spanned<f64>>,
    #[serde(default)]
    b_fl: Option<Spanned<String>>,
    #[serde(default)]
    b_pr: Option<Spanned<String>>,
    #[serde(default)]
    k_pr: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRun {
    file: Spanned<PathBuf>,
    #[serde(alias = "alpha")]
    oil_loss: Spanned<f64>,
    #[serde(default)]
    amplitude_m: Option<Spanned<f64>>,
    #[serde(default)]
    target_velocity_m_s: Option<Spanned<f64>>,
}

/// Spans of the manifest values, for error lines (`None` for in-memory manifests).
struct ManifestLines {
    sample_rate_hz: usize,
    condition: Option<ConditionLines>,
    runs: Vec<RunLines>,
}

/// Lines of the `[condition]` values (the table's name line where a key is absent).
#[derive(Clone, Copy)]
struct ConditionLines {
    name: usize,
    unit: usize,
    at_alpha_0: usize,
    at_alpha_1: usize,
}

struct RunLines {
    file: usize,
    oil_loss: usize,
    amplitude_m: Option<usize>,
    target_velocity_m_s: Option<usize>,
}

/// Checks the values of a manifest (ranges, file names, duplicates).
fn validate_manifest(
    m: &Manifest,
    path: &Path,
    lines: Option<&ManifestLines>,
) -> Result<(), DatasetError> {
    let value_err =
        |line: Option<usize>, key: String, message: String| DatasetError::ManifestValue {
            path: path.to_path_buf(),
            line,
            key,
            message,
        };
    if !(m.sample_rate_hz.is_finite() && m.sample_rate_hz > 0.0) {
        return Err(value_err(
            lines.map(|l| l.sample_rate_hz),
            "sample_rate_hz".into(),
            format!("{} is not a positive finite rate in Hz", m.sample_rate_hz),
        ));
    }
    if let Some(c) = &m.condition {
        let cl = lines.and_then(|l| l.condition.as_ref());
        let limits = [
            (
                "condition.name",
                c.name.len(),
                1,
                nemm_core::model::MAX_CONDITION_NAME,
                cl.map(|l| l.name),
            ),
            (
                "condition.unit",
                c.unit.len(),
                0,
                nemm_core::model::MAX_CONDITION_UNIT,
                cl.map(|l| l.unit),
            ),
        ];
        for (key, len, lo, hi, line) in limits {
            if !(lo..=hi).contains(&len) {
                return Err(value_err(
                    line,
                    key.into(),
                    format!("{len} bytes; must be {lo} to {hi} bytes"),
                ));
            }
        }
        for (key, v, line) in [
            (
                "condition.at_alpha_0",
                c.at_alpha_0,
                cl.map(|l| l.at_alpha_0),
            ),
            (
                "condition.at_alpha_1",
                c.at_alpha_1,
                cl.map(|l| l.at_alpha_1),
            ),
        ] {
            if !(v.is_finite() && (v as f32).is_finite()) {
                return Err(value_err(
                    line,
                    key.into(),
                    format!("{v} is not a finite number"),
                ));
            }
        }
        if c.at_alpha_0 as f32 == c.at_alpha_1 as f32 {
            return Err(value_err(
                cl.map(|l| l.at_alpha_1),
                "condition.at_alpha_1".into(),
                format!(
                    "{} equals at_alpha_0: the condition needs distinct values at alpha 0 and 1",
                    c.at_alpha_1
                ),
            ));
        }
    }
    if m.runs.is_empty() {
        return Err(value_err(
            None,
            "runs".into(),
            "no runs listed (add [[runs]] tables)".into(),
        ));
    }
    let mut seen: HashMap<PathBuf, usize> = HashMap::new();
    for (i, r) in m.runs.iter().enumerate() {
        let rl = lines.and_then(|l| l.runs.get(i));
        let file_line = rl.map(|l| l.file);
        let key = |k: &str| format!("runs[{i}].{k}");
        let normalised = normalise_relative(&r.file).map_err(|message| {
            value_err(file_line, key("file"), format!("{:?}: {message}", r.file))
        })?;
        if let Some(&first) = seen.get(&normalised) {
            return Err(DatasetError::DuplicateRunFile {
                path: path.to_path_buf(),
                line: file_line,
                key: key("file"),
                first_key: format!("runs[{first}].file"),
                file: r.file.clone(),
            });
        }
        seen.insert(normalised, i);
        if !(r.oil_loss.is_finite() && (0.0..=1.0).contains(&r.oil_loss)) {
            return Err(value_err(
                rl.map(|l| l.oil_loss),
                key("oil_loss"),
                format!(
                    "{} is outside [0, 1] (condition level alpha, e.g. the fraction of oil \
                     volume lost)",
                    r.oil_loss
                ),
            ));
        }
        let positive = |v: Option<f64>, k: &str, line: Option<usize>| match v {
            Some(v) if !(v.is_finite() && v > 0.0) => Err(value_err(
                line,
                key(k),
                format!("{v} is not a positive finite number"),
            )),
            _ => Ok(()),
        };
        positive(r.amplitude_m, "amplitude_m", rl.and_then(|l| l.amplitude_m))?;
        positive(
            r.target_velocity_m_s,
            "target_velocity_m_s",
            rl.and_then(|l| l.target_velocity_m_s),
        )?;
    }
    Ok(())
}

/// The run file path without `.` components; refuses empty, absolute and `..` paths.
fn normalise_relative(file: &Path) -> Result<PathBuf, &'static str> {
    let mut out = PathBuf::new();
    for c in file.components() {
        match c {
            Component::Normal(p) => out.push(p),
            Component::CurDir => {}
            Component::ParentDir => {
                return Err("must stay inside the dataset folder (no `..`)");
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err("must be relative to the manifest, not absolute");
            }
        }
    }
    if out.as_os_str().is_empty() {
        return Err("is not a file name");
    }
    Ok(out)
}

/// Reads and validates `DIR/manifest.toml` (without opening the run files).
pub fn read_manifest(dir: &Path) -> Result<Manifest, DatasetError> {
    Ok(read_manifest_with_lines(dir)?.0)
}

fn read_manifest_with_lines(dir: &Path) -> Result<(Manifest, ManifestLines), DatasetError> {
    let path = dir.join(MANIFEST_FILE);
    let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
    let raw: RawManifest = toml::from_str(&text).map_err(|e| {
        let (line, column) = line_col(&text, e.span().map_or(0, |s| s.start));
        DatasetError::ManifestSyntax {
            path: path.clone(),
            line,
            column,
            message: e.message().trim().to_string(),
        }
    })?;
    let line_of = |span: std::ops::Range<usize>| line_col(&text, span.start).0;
    let condition = raw
        .condition
        .map(|c| raw_condition(c, &text, &path))
        .transpose()?;
    let lines = ManifestLines {
        sample_rate_hz: line_of(raw.sample_rate_hz.span()),
        condition: condition.as_ref().map(|c| c.1),
        runs: raw
            .runs
            .iter()
            .map(|r| RunLines {
                file: line_of(r.file.span()),
                oil_loss: line_of(r.oil_loss.span()),
                amplitude_m: r.amplitude_m.as_ref().map(|s| line_of(s.span())),
                target_velocity_m_s: r.target_velocity_m_s.as_ref().map(|s| line_of(s.span())),
            })
            .collect(),
    };
    let manifest = Manifest {
        name: raw.name,
        sample_rate_hz: raw.sample_rate_hz.into_inner(),
        condition: condition.map(|c| c.0),
        runs: raw
            .runs
            .into_iter()
            .map(|r| RunEntry {
                file: r.file.into_inner(),
                oil_loss: r.oil_loss.into_inner(),
                amplitude_m: r.amplitude_m.map(Spanned::into_inner),
                target_velocity_m_s: r.target_velocity_m_s.map(Spanned::into_inner),
            })
            .collect(),
    };
    validate_manifest(&manifest, &path, Some(&lines))?;
    Ok((manifest, lines))
}

/// The `[condition]` table with its lines; a direction that is none of the accepted names
/// is refused with its line.
fn raw_condition(
    c: RawCondition,
    text: &str,
    path: &Path,
) -> Result<(ConditionSpec, ConditionLines), DatasetError> {
    let line_of = |span: std::ops::Range<usize>| line_col(text, span.start).0;
    let name_line = line_of(c.name.span());
    let line = |s: &Option<Spanned<f64>>| s.as_ref().map_or(name_line, |s| line_of(s.span()));
    let lines = ConditionLines {
        name: name_line,
        unit: c.unit.as_ref().map_or(name_line, |s| line_of(s.span())),
        at_alpha_0: line(&c.at_alpha_0),
        at_alpha_1: line(&c.at_alpha_1),
    };
    let direction = |s: Option<Spanned<String>>, key: &str| -> Result<Direction, DatasetError> {
        match s {
            None => Ok(Direction::default()),
            Some(s) => {
                let l = line_of(s.span());
                s.into_inner()
                    .parse::<Direction>()
                    .map_err(|e| DatasetError::ManifestValue {
                        path: path.to_path_buf(),
                        line: Some(l),
                        key: format!("condition.{key}"),
                        message: format!("{e}"),
                    })
            }
        }
    };
    let spec = ConditionSpec {
        name: c.name.into_inner(),
        unit: c
            .unit
            .map_or_else(ConditionSpec::default_unit, Spanned::into_inner),
        at_alpha_0: c.at_alpha_0.map_or(0.0, Spanned::into_inner),
        at_alpha_1: c.at_alpha_1.map_or(1.0, Spanned::into_inner),
        b_fl: direction(c.b_fl, "b_fl")?,
        b_pr: direction(c.b_pr, "b_pr")?,
        k_pr: direction(c.k_pr, "k_pr")?,
    };
    Ok((spec, lines))
}

// ---------------------------------------------------------------------------------------------
// Loading
// ---------------------------------------------------------------------------------------------

/// Loads and validates a dataset folder (runs are parsed in parallel).
pub fn load(dir: &Path) -> Result<Dataset, DatasetError> {
    load_with_progress(dir, |_| {})
}

/// [`load`], calling `progress` after each run is parsed (from worker threads).
///
/// On several bad files the error of the first one in manifest order is returned.
pub fn load_with_progress(
    dir: &Path,
    progress: impl Fn(LoadProgress) + Sync,
) -> Result<Dataset, DatasetError> {
    use rayon::prelude::*;
    let (manifest, lines) = read_manifest_with_lines(dir)?;
    let manifest_path = dir.join(MANIFEST_FILE);
    // Every file must exist before any is parsed, so a typo is reported at once.
    for (i, (entry, rl)) in manifest.runs.iter().zip(&lines.runs).enumerate() {
        let file = dir.join(&entry.file);
        if !file.is_file() {
            return Err(DatasetError::MissingRunFile {
                manifest: manifest_path.clone(),
                line: rl.file,
                key: format!("runs[{i}].file"),
                file,
            });
        }
    }
    let runs_total = manifest.runs.len();
    let runs_done = AtomicUsize::new(0);
    let samples_done = AtomicUsize::new(0);
    let fs = manifest.sample_rate_hz;
    let results: Vec<Result<Run, DatasetError>> = manifest
        .runs
        .par_iter()
        .map(|entry| {
            let run = read_run(&dir.join(&entry.file), entry.clone(), fs)?;
            let samples = samples_done.fetch_add(run.len(), Ordering::Relaxed) + run.len();
            let done = runs_done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(LoadProgress {
                runs_done: done,
                runs_total,
                samples_done: samples,
            });
            Ok(run)
        })
        .collect();
    let runs = results.into_iter().collect::<Result<Vec<_>, _>>()?;
    Ok(Dataset {
        name: manifest.name,
        sample_rate_hz: fs,
        condition: manifest.condition,
        runs,
    })
}

/// Reads and validates one run CSV file at `path` sampled at `sample_rate_hz`.
pub fn read_run(path: &Path, entry: RunEntry, sample_rate_hz: f64) -> Result<Run, DatasetError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    parse_run(&bytes, path, entry, sample_rate_hz)
}

/// Parses and validates the content of one run CSV file; `path` is used in errors only.
pub fn parse_run(
    bytes: &[u8],
    path: &Path,
    entry: RunEntry,
    sample_rate_hz: f64,
) -> Result<Run, DatasetError> {
    let csv_err = |e: csv::Error, fallback_line: usize| {
        let line = e.position().map_or(fallback_line, |p| {
            usize::try_from(p.line()).unwrap_or(usize::MAX)
        });
        match e.kind() {
            csv::ErrorKind::UnequalLengths {
                expected_len, len, ..
            } => DatasetError::FieldCount {
                path: path.to_path_buf(),
                line,
                expected: usize::try_from(*expected_len).unwrap_or(usize::MAX),
                found: usize::try_from(*len).unwrap_or(usize::MAX),
            },
            _ => DatasetError::Csv {
                path: path.to_path_buf(),
                line,
                message: e.to_string(),
            },
        }
    };
    // Spreadsheet exports often start with a UTF-8 byte-order mark.
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .trim(csv::Trim::All)
        .from_reader(bytes);
    let header = reader.byte_headers().map_err(|e| csv_err(e, 1))?.clone();
    if header.is_empty() || (header.len() == 1 && header[0].is_empty()) {
        return Err(DatasetError::EmptyFile {
            path: path.to_path_buf(),
        });
    }
    let names: Vec<String> = header
        .iter()
        .map(|h| String::from_utf8_lossy(h).into_owned())
        .collect();
    let mut index: HashMap<&str, usize> = HashMap::new();
    for (i, n) in names.iter().enumerate() {
        if index.insert(n.as_str(), i).is_some() {
            return Err(DatasetError::DuplicateColumn {
                path: path.to_path_buf(),
                column: n.clone(),
            });
        }
    }
    let required = |c: &str| {
        index
            .get(c)
            .copied()
            .ok_or_else(|| DatasetError::MissingColumn {
                path: path.to_path_buf(),
                column: c.to_string(),
                header: names.join(","),
            })
    };
    let (it, ix, iff) = (
        required(COL_TIME)?,
        required(COL_DISPLACEMENT)?,
        required(COL_FORCE)?,
    );
    let iv = index.get(COL_VELOCITY).copied();
    let ia = index.get(COL_ALPHA).copied();

    // Pre-size from the byte count (about 30-60 bytes per row).
    let guess = bytes.len() / 32;
    let mut time_s = Vec::with_capacity(guess);
    let mut displacement_m = Vec::with_capacity(guess);
    let mut force_n = Vec::with_capacity(guess);
    let mut velocity_m_s = iv.map(|_| Vec::with_capacity(guess));
    let mut alpha = ia.map(|_| Vec::with_capacity(guess));
    let mut record = csv::ByteRecord::new();
    let mut last_line = 1;
    let mut lines: Vec<usize> = Vec::with_capacity(guess);
    loop {
        match reader.read_byte_record(&mut record) {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => return Err(csv_err(e, last_line + 1)),
        }
        let line = record.position().map_or(last_line + 1, |p| {
            usize::try_from(p.line()).unwrap_or(usize::MAX)
        });
        last_line = line;
        let cell = |i: usize, column: &str| -> Result<f64, DatasetError> {
            let raw = record.get(i).unwrap_or_default();
            parse_cell(raw, path, line, column)
        };
        let t = cell(it, COL_TIME)?;
        if let Some(&previous) = time_s.last() {
            check_increasing(previous, t, path, line)?;
        }
        time_s.push(t);
        lines.push(line);
        displacement_m.push(cell(ix, COL_DISPLACEMENT)?);
        force_n.push(cell(iff, COL_FORCE)?);
        if let (Some(i), Some(v)) = (iv, velocity_m_s.as_mut()) {
            v.push(cell(i, COL_VELOCITY)?);
        }
        if let (Some(i), Some(a)) = (ia, alpha.as_mut()) {
            let value = cell(i, COL_ALPHA)?;
            check_alpha(value, path, line)?;
            a.push(value);
        }
    }
    if time_s.is_empty() {
        return Err(DatasetError::NoSamples {
            path: path.to_path_buf(),
            line: last_line + 1,
        });
    }
    check_time_grid(&time_s, sample_rate_hz, path, |i| {
        lines.get(i).copied().unwrap_or(i + 2)
    })?;
    Ok(Run {
        entry,
        time_s,
        displacement_m,
        force_n,
        velocity_m_s,
        alpha,
    })
}

/// Checks one per-sample condition level (in \[0, 1\]).
fn check_alpha(value: f64, path: &Path, line: usize) -> Result<(), DatasetError> {
    if (0.0..=1.0).contains(&value) {
        Ok(())
    } else {
        Err(DatasetError::AlphaOutOfRange {
            path: path.to_path_buf(),
            line,
            value,
        })
    }
}

fn parse_cell(raw: &[u8], path: &Path, line: usize, column: &str) -> Result<f64, DatasetError> {
    let text = std::str::from_utf8(raw).ok();
    match text.and_then(|t| t.parse::<f64>().ok()) {
        Some(v) if v.is_finite() => Ok(v),
        Some(_) => Err(DatasetError::NonFinite {
            path: path.to_path_buf(),
            line,
            column: column.to_string(),
            value: String::from_utf8_lossy(raw).into_owned(),
        }),
        None => Err(DatasetError::NotANumber {
            path: path.to_path_buf(),
            line,
            column: column.to_string(),
            value: String::from_utf8_lossy(raw).into_owned(),
        }),
    }
}

/// Line of sample `i` in a file written by [`write()`] (header is line 1, one row per line).
pub fn sample_line(i: usize) -> usize {
    i + 2
}

/// Refuses a time that does not strictly increase (the step ending at `line`).
fn check_increasing(
    previous: f64,
    time: f64,
    path: &Path,
    line: usize,
) -> Result<(), DatasetError> {
    let step = time - previous;
    if step.is_nan() || step <= 0.0 {
        return Err(DatasetError::NonMonotonicTime {
            path: path.to_path_buf(),
            line,
            time,
            previous,
        });
    }
    Ok(())
}

/// The uniform grid `t = t0 + i step` fitted to a run's time stamps by least squares.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TimeGrid {
    /// Time of sample 0 on the grid \[s\].
    pub t0_s: f64,
    /// Fitted step \[s\].
    pub step_s: f64,
    /// Largest `|t_i - (t0 + i step)|` \[s\].
    pub max_deviation_s: f64,
    /// Index of the sample with the largest deviation.
    pub max_deviation_sample: usize,
}

impl TimeGrid {
    /// The fitted rate `1 / step_s` \[Hz\].
    pub fn rate_hz(&self) -> f64 {
        1.0 / self.step_s
    }

    /// `true` when the stamps lie on the grid up to decimal float noise (below a millionth
    /// of a step), `false` for rounded or jittered stamps.
    pub fn is_exact(&self) -> bool {
        self.max_deviation_s <= EXACT_GRID_DEVIATION * self.step_s
    }
}

/// Least-squares fit of `t_i = t0 + i step` to increasing time stamps.
///
/// With fewer than two stamps the step is `nominal_step_s`.
pub fn fit_time_grid(time_s: &[f64], nominal_step_s: f64) -> TimeGrid {
    let n = time_s.len();
    let Some(&first) = time_s.first() else {
        return TimeGrid {
            t0_s: 0.0,
            step_s: nominal_step_s,
            max_deviation_s: 0.0,
            max_deviation_sample: 0,
        };
    };
    let step_s = if n < 2 {
        nominal_step_s
    } else {
        // Centred sums, relative to the first stamp for precision.
        let nf = n as f64;
        let i_mean = 0.5 * (nf - 1.0);
        let t_mean = time_s.iter().map(|t| t - first).sum::<f64>() / nf;
        let sxy: f64 = time_s
            .iter()
            .enumerate()
            .map(|(i, t)| (i as f64 - i_mean) * (t - first - t_mean))
            .sum();
        let sxx = nf * (nf * nf - 1.0) / 12.0;
        sxy / sxx
    };
    let t_mean = time_s.iter().map(|t| t - first).sum::<f64>() / n as f64;
    let offset = t_mean - step_s * 0.5 * (n as f64 - 1.0);
    let (mut max_dev, mut at) = (0.0f64, 0);
    for (i, t) in time_s.iter().enumerate() {
        let d = (t - first - offset - step_s * i as f64).abs();
        if d > max_dev {
            (max_dev, at) = (d, i);
        }
    }
    TimeGrid {
        t0_s: first + offset,
        step_s,
        max_deviation_s: max_dev,
        max_deviation_sample: at,
    }
}

/// Checks that increasing time stamps lie on a uniform grid at `sample_rate_hz`, as
/// rounded or jittered logger stamps do, and returns the fitted grid.
///
/// The rule, in order (`h = 1 / sample_rate_hz`; `line_of(i)` is the line of sample `i`):
/// 1. a step longer than [`GAP_STEPS`]` h` is a gap: [`DatasetError::Gap`] at its line,
///    unless the fitted step (below) is more than 50 % off `h`, which is a wrong
///    `sample_rate_hz`: [`DatasetError::RateMismatch`];
/// 2. the least-squares grid `t = t0 + i dt` is fitted over the whole run; its rate
///    `1 / dt` must be within [`MAX_RATE_MISMATCH`] of `sample_rate_hz`
///    ([`DatasetError::RateMismatch`], naming both);
/// 3. every stamp must lie within [`MAX_GRID_DEVIATION`]` dt` of the fitted grid
///    ([`DatasetError::OffGrid`] at the line of the largest deviation).
///
/// Accepted samples are treated as exactly on the grid (step `h`); the stamps themselves are
/// kept as read. Increase is checked while parsing ([`DatasetError::NonMonotonicTime`]).
pub fn check_time_grid(
    time_s: &[f64],
    sample_rate_hz: f64,
    path: &Path,
    line_of: impl Fn(usize) -> usize,
) -> Result<TimeGrid, DatasetError> {
    let h = 1.0 / sample_rate_hz;
    let grid = fit_time_grid(time_s, h);
    if time_s.len() < 2 {
        return Ok(grid);
    }
    let rate_err = |fitted_hz: f64| DatasetError::RateMismatch {
        path: path.to_path_buf(),
        fitted_hz,
        manifest_hz: sample_rate_hz,
    };
    // A grid more than 50 % off is a wrong rate, not a run full of gaps or bursts.
    let coarse_off = (grid.step_s * sample_rate_hz - 1.0).abs();
    if coarse_off.is_nan() || coarse_off > 0.5 {
        return Err(rate_err(grid.rate_hz()));
    }
    for (i, w) in time_s.windows(2).enumerate() {
        let step = w[1] - w[0];
        if step > GAP_STEPS * h {
            let missing = ((step / h).round() as usize).saturating_sub(1).max(1);
            return Err(DatasetError::Gap {
                path: path.to_path_buf(),
                line: line_of(i + 1),
                previous: w[0],
                step,
                expected: h,
                missing,
            });
        }
    }
    if (grid.step_s * sample_rate_hz - 1.0).abs() > MAX_RATE_MISMATCH {
        return Err(rate_err(grid.rate_hz()));
    }
    let limit = MAX_GRID_DEVIATION * grid.step_s;
    if grid.max_deviation_s > limit {
        let i = grid.max_deviation_sample;
        let t = time_s.get(i).copied().unwrap_or_default();
        return Err(DatasetError::OffGrid {
            path: path.to_path_buf(),
            line: line_of(i),
            time: t,
            deviation_us: (t - grid.t0_s - grid.step_s * i as f64) * 1e6,
            limit_us: limit * 1e6,
            fitted_hz: grid.rate_hz(),
        });
    }
    Ok(grid)
}

// ---------------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------------

/// Checks an in-memory run as [`load`] would check its file (lengths, finite values, time).
fn validate_run(run: &Run, path: &Path, sample_rate_hz: f64) -> Result<(), DatasetError> {
    let n = run.time_s.len();
    if n == 0 {
        return Err(DatasetError::NoSamples {
            path: path.to_path_buf(),
            line: 2,
        });
    }
    let mut columns: Vec<(&str, &[f64])> = vec![
        (COL_TIME, &run.time_s),
        (COL_DISPLACEMENT, &run.displacement_m),
        (COL_FORCE, &run.force_n),
    ];
    if let Some(v) = &run.velocity_m_s {
        columns.push((COL_VELOCITY, v));
    }
    if let Some(a) = &run.alpha {
        columns.push((COL_ALPHA, a));
    }
    for (name, values) in &columns {
        if values.len() != n {
            return Err(DatasetError::LengthMismatch {
                path: path.to_path_buf(),
                column: (*name).to_string(),
                expected: n,
                found: values.len(),
            });
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(DatasetError::NonFinite {
                path: path.to_path_buf(),
                line: sample_line(i),
                column: (*name).to_string(),
                value: values[i].to_string(),
            });
        }
    }
    if let Some(a) = &run.alpha {
        for (i, &value) in a.iter().enumerate() {
            check_alpha(value, path, sample_line(i))?;
        }
    }
    for (i, w) in run.time_s.windows(2).enumerate() {
        check_increasing(w[0], w[1], path, sample_line(i + 1))?;
    }
    check_time_grid(&run.time_s, sample_rate_hz, path, sample_line)?;
    Ok(())
}

/// [`crate::fsutil::write_atomic`] with the dataset's error type (naming the file).
fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> Result<(), DatasetError> {
    crate::fsutil::write_atomic(path, fill).map_err(|error| DatasetError::Io {
        path: path.to_path_buf(),
        error,
    })
}

/// Writes one run as CSV (`time_s,displacement_m,force_n[,velocity_m_s][,alpha]`).
fn write_run_csv(run: &Run, w: &mut dyn std::io::Write) -> std::io::Result<()> {
    let mut line = String::with_capacity(128);
    line.push_str("time_s,displacement_m,force_n");
    if run.velocity_m_s.is_some() {
        line.push_str(",velocity_m_s");
    }
    if run.alpha.is_some() {
        line.push_str(",alpha");
    }
    line.push('\n');
    w.write_all(line.as_bytes())?;
    for i in 0..run.time_s.len() {
        line.clear();
        // `{}` on f64 prints the shortest decimal that parses back to the same value.
        let _ = write!(
            line,
            "{},{},{}",
            run.time_s[i], run.displacement_m[i], run.force_n[i]
        );
        if let Some(v) = &run.velocity_m_s {
            let _ = write!(line, ",{}", v[i]);
        }
        if let Some(a) = &run.alpha {
            let _ = write!(line, ",{}", a[i]);
        }
        line.push('\n');
        w.write_all(line.as_bytes())?;
    }
    Ok(())
}

/// Writes `dataset` to the folder `dir` (created if needed): every run CSV at its manifest
/// path, then `manifest.toml`. Each file is written atomically; the dataset is validated
/// first with the same rules as [`load`], so whatever `write` accepts, `load` reads back
/// exactly. Existing files of the same names are replaced; other files are left alone.
pub fn write(dir: &Path, dataset: &Dataset) -> Result<(), DatasetError> {
    use rayon::prelude::*;
    let manifest = dataset.manifest();
    let manifest_path = dir.join(MANIFEST_FILE);
    validate_manifest(&manifest, &manifest_path, None)?;
    for run in &dataset.runs {
        validate_run(run, &dir.join(&run.entry.file), dataset.sample_rate_hz)?;
    }
    dataset
        .runs
        .par_iter()
        .map(|run| write_atomic(&dir.join(&run.entry.file), |w| write_run_csv(run, w)))
        .collect::<Result<Vec<()>, _>>()?;
    let text = toml::to_string(&manifest).map_err(|e| DatasetError::ManifestValue {
        path: manifest_path.clone(),
        line: None,
        key: "(manifest)".into(),
        message: format!("cannot be encoded as TOML: {e}"),
    })?;
    write_atomic(&manifest_path, |w| w.write_all(text.as_bytes()))
}
