//! # nemm-dataset
//!
//! The test-bench dataset interchange format of NEMM (see `docs/data-format.md`): what the
//! trainer (`nemm-train`) reads, what the virtual bench (`nemm-virtual-bench`) and
//! `nemm data import` write, and what the firmware's build script reads its replay trace
//! from.
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
use std::path::{Path, PathBuf};

pub mod atomic_file;
pub mod csv;
mod load;
mod manifest;
mod write;

pub use load::{
    before_first_gap, check_time_grid, fit_time_grid, load, load_readable, load_with_progress,
    median_step, parse_run, read_lone_run, read_run, sample_line, TimeGrid,
};
pub use manifest::{condition_values_error, control_character, read_manifest, short_number};
pub use write::write;

/// File name of the manifest inside a dataset folder.
pub const MANIFEST_FILE: &str = "manifest.toml";

/// File name of a dataset's own data options, next to its `manifest.toml`: read by every
/// `nemm` command that reads the dataset, written by `nemm data prepare --save-options`. It
/// belongs to the dataset: [`write()`] does not carry it over into a new dataset.
pub const DATA_OPTIONS_FILE: &str = "nemm-data.toml";

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
    /// Name, e.g. `gas charge` (1 to [`nemm_core::MAX_CONDITION_NAME`] bytes).
    pub name: String,
    /// Unit of the condition value, e.g. `psi` (default `-`; at most
    /// [`nemm_core::MAX_CONDITION_UNIT`] bytes).
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

    /// A value in a table column ([`Self::column`]): alpha itself, or the condition value,
    /// rounded to what it means ([`Self::value_text`]).
    pub fn cell(&self, alpha: f64) -> String {
        if self.is_alpha_itself() {
            alpha_text(alpha)
        } else {
            self.value_text(self.value_at(alpha))
        }
    }

    /// A condition value rounded to the resolution of [`alpha_text`] on this condition's
    /// scale (four decimals of its span `at_alpha_1 - at_alpha_0`), trailing zeros trimmed:
    /// `2.252` V of a 0-5 V span, `100.25` psi of a 100 psi span.
    pub fn value_text(&self, value: f64) -> String {
        let span = (self.at_alpha_1 - self.at_alpha_0).abs();
        let decimals = if span.is_finite() && span > 0.0 {
            (LEVEL_DECIMALS as f64 - span.log10().floor()).clamp(0.0, 15.0) as usize
        } else {
            LEVEL_DECIMALS
        };
        rounded_text(value, decimals)
    }

    /// A level in words: `oil loss 0.15`, `gas charge 100 psi (alpha 0.5)`, rounded
    /// ([`Self::cell`], [`alpha_text`]).
    pub fn level(&self, alpha: f64) -> String {
        if self.is_alpha_itself() {
            format!("{} {}", self.name, alpha_text(alpha))
        } else {
            format!(
                "{} {} {} (alpha {})",
                self.name,
                self.cell(alpha),
                self.unit,
                alpha_text(alpha)
            )
        }
    }

    /// Levels in words, for a list: `oil loss 0, 0.15, 0.3`, `gas charge 150, 100 psi`.
    pub fn levels(&self, alphas: &[f64]) -> String {
        let cells: Vec<String> = alphas.iter().map(|&a| self.cell(a)).collect();
        if self.is_alpha_itself() {
            format!("{} {}", self.name, cells.join(", "))
        } else {
            format!("{} {} {}", self.name, cells.join(", "), self.unit)
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

/// Decimals of a printed condition level `alpha` (and of a condition value, relative to its
/// span): a level is set to about 1e-4 of its range.
pub const LEVEL_DECIMALS: usize = 4;

/// A condition level `alpha` as printed: at most [`LEVEL_DECIMALS`] decimals, trailing zeros
/// trimmed (`0.4504`, `0.15`, `1`). JSON outputs keep the exact number.
pub fn alpha_text(alpha: f64) -> String {
    rounded_text(alpha, LEVEL_DECIMALS)
}

/// `value` with at most `decimals` decimals, trailing zeros (and a bare point) trimmed;
/// a value rounding to zero prints `0`, not `-0`.
pub fn rounded_text(value: f64, decimals: usize) -> String {
    if !value.is_finite() {
        return value.to_string();
    }
    let s = format!("{value:.decimals$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        &s
    };
    if s == "-0" {
        "0".into()
    } else {
        s.to_string()
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
    /// A run file resolves (through a symbolic link or `..`) to a file outside the dataset
    /// folder; it is not read.
    #[error("{}: {key}: run file {} resolves to {}, outside the dataset folder; copy the file into the folder (a dataset reads only its own files)", location(manifest, Some(*line)), file.display(), resolved.display())]
    RunFileOutside {
        /// The manifest.
        manifest: PathBuf,
        /// Line of the `file` value.
        line: usize,
        /// The key, e.g. `runs[3].file`.
        key: String,
        /// The run file as named (joined to the folder).
        file: PathBuf,
        /// Where it resolves to.
        resolved: PathBuf,
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
