//! `nemm data import`: raw dyno CSV files into the interchange format (see
//! `docs/data-format.md`, "Importing raw dyno files").
//!
//! An [`ImportSpec`] (a TOML file, or built from command-line flags) says which column holds
//! what, in which unit, with which gain, sign and offset, which condition level `alpha` each
//! file has, and how a long record is cut into runs (time ranges, pauses of the excitation or
//! gaps in the time stamps). [`import`] reads every file, converts it to SI units and the
//! sign conventions, cuts it, checks the time stamps with the loader's rule
//! ([`nemm_dataset::check_time_grid`]) or resamples them when asked (linear interpolation), and
//! returns a [`Dataset`](nemm_dataset::Dataset) that [`nemm_dataset::write()`] writes atomically.
//!
//! Every error names the raw file, its line and its column (or the spec key).
use nemm_core::Direction;
use nemm_dataset::DatasetError;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

mod convert;
mod spec;
mod stamp;

pub use convert::import;

pub(crate) use convert::Imported;
pub(crate) use spec::{condition_spec, unit_factor};
pub use spec::{read_spec, validate_spec, LevelMap};

/// Why an import failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImportError {
    /// A file could not be read.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating-system error.
        error: std::io::Error,
    },
    /// The spec is not valid TOML or does not have the spec's shape.
    #[error("{}:{line}:{column}: {message}", path.display())]
    SpecSyntax {
        /// The spec file.
        path: PathBuf,
        /// Line of the offending text.
        line: usize,
        /// Column (1-based, in characters).
        column: usize,
        /// What the TOML parser says.
        message: String,
    },
    /// A spec value (or the flag that set it) is out of range or inconsistent.
    #[error("import spec: {key}: {message}")]
    SpecValue {
        /// The key, e.g. `columns.force.unit` or `files[2].alpha`.
        key: String,
        /// What is wrong with it.
        message: String,
    },
    /// The CSV reader failed.
    #[error("{}:{line}: {message}", path.display())]
    Csv {
        /// The raw file.
        path: PathBuf,
        /// The line.
        line: usize,
        /// The reader's message.
        message: String,
    },
    /// A column named by the spec is not in the header (or the index is beyond it).
    #[error("{}:{line}: column {column} (columns.{role}) is not in the header ({header})", path.display())]
    MissingColumn {
        /// The raw file.
        path: PathBuf,
        /// The header line.
        line: usize,
        /// `columns.<role>` of the spec.
        role: String,
        /// The column as named by the spec.
        column: String,
        /// The header as found.
        header: String,
    },
    /// A cell is not a finite number.
    #[error("{}:{line}:{field}: column \"{column}\": \"{value}\" is not a finite number{hint}", path.display())]
    BadCell {
        /// The raw file.
        path: PathBuf,
        /// The line.
        line: usize,
        /// The field number (1-based).
        field: usize,
        /// The column's header name.
        column: String,
        /// The cell as found.
        value: String,
        /// What probably fixes it (empty when nothing is known), e.g. `decimal_comma`.
        hint: String,
    },
    /// A condition-level cell converts to a level outside \[0, 1\].
    #[error("{}:{line}:{field}: column \"{column}\": {value} converts to the condition level {level}, outside [0, 1] (columns.alpha: {mapping})", path.display())]
    LevelOutOfRange {
        /// The raw file.
        path: PathBuf,
        /// The line.
        line: usize,
        /// The field number (1-based).
        field: usize,
        /// The column's header name.
        column: String,
        /// The cell as found.
        value: String,
        /// The converted level.
        level: f64,
        /// The mapping, e.g. `range 0 .. 5 V` or `raw * gain + offset`.
        mapping: String,
    },
    /// A time cell is a malformed date-time stamp, or the time column mixes date-time
    /// stamps and numbers.
    #[error("{}:{line}:{field}: column \"{column}\": \"{value}\" is not a time stamp: {message}", path.display())]
    BadTimeStamp {
        /// The raw file.
        path: PathBuf,
        /// The line.
        line: usize,
        /// The field number (1-based).
        field: usize,
        /// The column's header name.
        column: String,
        /// The cell as found.
        value: String,
        /// What is wrong and what is accepted.
        message: String,
    },
    /// A file or a cut gives no run.
    #[error("{}: {message}", path.display())]
    NoRuns {
        /// The raw file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// Resampling a run would give more samples than a run may hold.
    #[error("{}: resampling {span_s} s at {rate_hz} Hz gives {samples} samples; a run holds at most {MAX_RESAMPLED_RUN_SAMPLES}: cut the record into runs (--split or [[files.runs]]) or lower --resample-hz", path.display())]
    TooManySamples {
        /// The raw file.
        path: PathBuf,
        /// The run's span \[s\].
        span_s: f64,
        /// The resampling rate \[Hz\].
        rate_hz: f64,
        /// The samples it would give.
        samples: f64,
    },
    /// The time stamps of a run break the loader's rule (named with the raw file's lines).
    #[error(transparent)]
    Time(#[from] DatasetError),
}

/// Highest resampling rate \[Hz\] (`--resample-hz`, `resample_hz`): the highest model rate
/// training accepts.
pub(crate) const MAX_RESAMPLE_HZ: f64 = crate::config::MODEL_RATE_RANGE_HZ.1;

/// Lowest resampling rate \[Hz\] (`--resample-hz`, `resample_hz`): the lowest model rate
/// (a slower grid leaves too few samples of a stroke to train or check on).
pub(crate) const MIN_RESAMPLE_HZ: f64 = crate::config::MODEL_RATE_RANGE_HZ.0;
/// Most samples a resampled run may hold (five `f64` columns: 2 GB), checked before the run
/// is allocated.
pub(crate) const MAX_RESAMPLED_RUN_SAMPLES: usize = 50_000_000;

fn spec_err(key: impl Into<String>, message: impl Into<String>) -> ImportError {
    ImportError::SpecValue {
        key: key.into(),
        message: message.into(),
    }
}

/// CSV dialect of the raw files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CsvOptions {
    /// Field delimiter: one character, or `"tab"` (default `","`).
    pub delimiter: String,
    /// Lines starting with this character are skipped (default: none).
    pub comment: Option<String>,
    /// 1-based line of the header; lines before it (a logger's preamble) are skipped
    /// (default 1).
    pub header_line: usize,
    /// Numbers use a decimal comma (`1,5`); needs a delimiter other than `,`.
    pub decimal_comma: bool,
}

impl Default for CsvOptions {
    fn default() -> Self {
        CsvOptions {
            delimiter: ",".into(),
            comment: None,
            header_line: 1,
            decimal_comma: false,
        }
    }
}

/// One column of the raw files and how it converts: `SI = sign (raw gain + offset) unit`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColumnSpec {
    /// Header name of the column (exactly one of `name` and `index`).
    #[serde(default)]
    pub name: Option<String>,
    /// 1-based column number (for files without a usable header).
    #[serde(default)]
    pub index: Option<usize>,
    /// Unit of `raw * gain + offset`: see `unit_factor`. For the level column
    /// (`columns.alpha`) mapped by `range` (given or taken from the data), the unit of the raw
    /// numbers themselves, e.g. `V`: the condition's unit.
    pub unit: String,
    /// Multiplier of the raw number (e.g. mm per volt for a voltage channel; default 1).
    #[serde(default)]
    pub gain: Option<f64>,
    /// Added after the gain, in `unit` (e.g. a potentiometer's zero; default 0).
    #[serde(default)]
    pub offset: Option<f64>,
    /// Level column only: the raw values at alpha 0 and at alpha 1, e.g. `[0.0, 5.0]` for a
    /// 0-5 V control voltage (`[5.0, 0.0]` when the level falls as the raw value rises);
    /// instead of `gain` and `offset`. Without `range`, `gain` and `offset`, a level column in
    /// a unit other than `1` takes the range from the data: the smallest and largest raw
    /// value over all imported files.
    #[serde(default)]
    pub range: Option<[f64; 2]>,
    /// Negate the converted value (compression-positive stroke or force; default false).
    #[serde(default)]
    pub invert: bool,
    /// Subtract the mid-range of each run after conversion (a displacement whose zero is
    /// arbitrary; default false).
    #[serde(default)]
    pub center: bool,
}

impl ColumnSpec {
    /// The multiplier of the raw number (`gain`, default 1).
    pub fn gain(&self) -> f64 {
        self.gain.unwrap_or(1.0)
    }

    /// The offset added after the gain (`offset`, default 0).
    pub fn offset(&self) -> f64 {
        self.offset.unwrap_or(0.0)
    }

    /// Parses the command-line form `NAME:UNIT` or `#INDEX:UNIT` (the last `:` separates the
    /// unit, so names may contain colons).
    pub(crate) fn parse_flag(text: &str) -> Result<ColumnSpec, String> {
        let (col, unit) = text
            .rsplit_once(':')
            .ok_or_else(|| format!("\"{text}\": expected NAME:UNIT or #INDEX:UNIT"))?;
        let (name, index) = match col.strip_prefix('#') {
            Some(i) => (
                None,
                Some(
                    i.parse::<usize>()
                        .map_err(|_| format!("\"{col}\": #INDEX must be a column number"))?,
                ),
            ),
            None => (Some(col.to_string()), None),
        };
        Ok(ColumnSpec {
            name,
            index,
            unit: unit.to_string(),
            gain: None,
            offset: None,
            range: None,
            invert: false,
            center: false,
        })
    }

    fn label(&self) -> String {
        match (&self.name, self.index) {
            (Some(n), _) => format!("\"{n}\""),
            (None, Some(i)) => format!("#{i}"),
            (None, None) => "(none)".into(),
        }
    }
}

/// The columns of the raw files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Columns {
    /// Time (units `s`, `ms`, `us`, `min`); without it, `rate_hz` gives the times.
    #[serde(default)]
    pub time: Option<ColumnSpec>,
    /// Displacement (units `m`, `cm`, `mm`, `um`, `in`), positive = extension after `invert`.
    pub displacement: ColumnSpec,
    /// Force (units `N`, `kN`, `lbf`, `kgf`), positive = tension after `invert`.
    pub force: ColumnSpec,
    /// Measured velocity (units `m/s`, `mm/s`, `in/s`), optional.
    #[serde(default)]
    pub velocity: Option<ColumnSpec>,
    /// Condition level per sample, optional. Mapped to alpha in \[0, 1\] by `range` (the raw
    /// values at alpha 0 and 1, in the column's unit, e.g. `V`), by the range of the data
    /// when neither `range` nor `gain` is given and the unit is not `1`, or as
    /// `raw * gain + offset` in unit `1`. The runs then carry the level per sample (the run
    /// file's `alpha` column).
    #[serde(default)]
    pub alpha: Option<ColumnSpec>,
}

impl Columns {
    /// Every column with its role, in reading order (absent optional ones as `None`).
    fn roles(&self) -> [(&'static str, Option<&ColumnSpec>); 5] {
        [
            ("time", self.time.as_ref()),
            ("displacement", Some(&self.displacement)),
            ("force", Some(&self.force)),
            ("velocity", self.velocity.as_ref()),
            ("alpha", self.alpha.as_ref()),
        ]
    }
}

/// How a long record is cut into runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum SplitMethod {
    /// One run per file (or per `[[files.runs]]` range).
    #[default]
    None,
    /// Cut at pauses of the excitation: the displacement stays within `pause_band` of the
    /// file's stroke range for at least `min_pause_s`.
    Pauses,
    /// Cut where the time stamps jump by more than 1.5 median steps.
    Gaps,
}

/// Cutting options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SplitSpec {
    /// The method (default `none`).
    pub(crate) method: SplitMethod,
    /// Shortest pause \[s\] (`pauses`; default 1).
    pub min_pause_s: f64,
    /// Displacement band of a pause, as a fraction of the file's stroke range (`pauses`;
    /// default 0.01).
    pub(crate) pause_band: f64,
    /// Segments shorter than this \[s\] are dropped and listed (default 1).
    pub(crate) min_run_s: f64,
}

impl Default for SplitSpec {
    fn default() -> Self {
        SplitSpec {
            method: SplitMethod::None,
            min_pause_s: 1.0,
            pause_band: 0.01,
            min_run_s: 1.0,
        }
    }
}

/// A run cut from a file by time (in the file's converted time, seconds).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunRange {
    /// Start \[s\] (inclusive).
    pub(crate) start_s: f64,
    /// End \[s\] (exclusive).
    pub(crate) end_s: f64,
    /// Condition level of this run (default: the file's).
    #[serde(default)]
    pub alpha: Option<f64>,
}

/// One raw file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileSpec {
    /// The file (relative to the spec file; as given on the command line).
    pub path: PathBuf,
    /// Condition level `alpha` in \[0, 1\] of every run from this file: the runs' label in the
    /// manifest. Optional with a level column (`columns.alpha`); each run's label is then
    /// the mean of its levels.
    #[serde(default)]
    pub alpha: Option<f64>,
    /// Cutting for this file (default: the spec's `split`).
    #[serde(default)]
    pub split: Option<SplitSpec>,
    /// Explicit time ranges (instead of `split`).
    #[serde(default)]
    pub runs: Vec<RunRange>,
}

/// Everything `nemm data import` needs (the TOML import spec).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImportSpec {
    /// Dataset name (default: the output folder's name).
    #[serde(default)]
    pub name: Option<String>,
    /// CSV dialect.
    #[serde(default)]
    pub csv: CsvOptions,
    /// Column mapping.
    pub columns: Columns,
    /// Sample rate \[Hz\]: required without a time column; with one, the manifest's rate
    /// (default: the rate fitted to the first run's stamps, as fitted; a whole number of hertz
    /// only when the fit is within 1 ppm of one, the noise of rounded stamps).
    #[serde(default)]
    pub rate_hz: Option<f64>,
    /// Resample every run onto a uniform grid at this rate \[Hz\] by linear interpolation
    /// (only on request; without it non-uniform stamps are refused like the loader does).
    #[serde(default)]
    pub resample_hz: Option<f64>,
    /// Default cutting of every file.
    #[serde(default)]
    pub split: SplitSpec,
    /// What alpha stands for, written to the manifest's `[condition]` (default: none, the
    /// paper's oil loss).
    #[serde(default)]
    pub condition: Option<ImportCondition>,
    /// The raw files.
    #[serde(default)]
    pub files: Vec<FileSpec>,
}

/// The import spec's `[condition]` table (and the `--condition-*` and `--prior` flags): the
/// manifest's `[condition]` ([`nemm_dataset::ConditionSpec`]) with defaults from a level column.
///
/// A condition is written when this table is given or the level column is mapped by a range
/// (given or taken from the data); it then needs `name` and the prior of every coefficient
/// (the defaults of a manifest, all `decreasing`, are oil loss's and are not assumed).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImportCondition {
    /// Name, e.g. `control voltage` (1 to [`nemm_core::MAX_CONDITION_NAME`] bytes).
    #[serde(default)]
    pub name: Option<String>,
    /// Unit of the condition value (at most [`nemm_core::MAX_CONDITION_UNIT`] bytes;
    /// default: the level column's unit when it is mapped by a range, else `-`).
    #[serde(default)]
    pub unit: Option<String>,
    /// Condition value at alpha 0 (default: the level column's raw value at alpha 0 when it
    /// is mapped by a range, else 0).
    #[serde(default)]
    pub at_alpha_0: Option<f64>,
    /// Condition value at alpha 1 (default: the level column's raw value at alpha 1 when it
    /// is mapped by a range, else 1).
    #[serde(default)]
    pub at_alpha_1: Option<f64>,
    /// Prior of `b_fl` in alpha: `decreasing`, `increasing` or `none` (required).
    #[serde(default)]
    pub b_fl: Option<Direction>,
    /// Prior of `b_pr` in alpha (required).
    #[serde(default)]
    pub b_pr: Option<Direction>,
    /// Prior of `k_pr` in alpha (required).
    #[serde(default)]
    pub k_pr: Option<Direction>,
}
