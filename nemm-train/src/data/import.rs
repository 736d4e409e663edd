//! `nemm data import`: raw dyno CSV files into the interchange format (see
//! `docs/data-format.md`, "Importing raw dyno files").
//!
//! An [`ImportSpec`] (a TOML file, or built from command-line flags) says which column holds
//! what, in which unit, with which gain, sign and offset, which condition level `alpha` each
//! file has, and how a long record is cut into runs (time ranges, pauses of the excitation or
//! gaps in the time stamps). [`import`] reads every file, converts it to SI units and the
//! sign conventions, cuts it, checks the time stamps with the loader's rule
//! ([`dataset::check_time_grid`]) or resamples them when asked (linear interpolation), and
//! returns a [`Dataset`] that [`dataset::write()`] writes atomically.
//!
//! Every error names the raw file, its line and its column (or the spec key).
use crate::data::dataset::{self, Dataset, DatasetError, Run, RunEntry};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

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
    /// The CSV reader failed (malformed quoting, not UTF-8, ...).
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
    #[error("{}:{line}:{field}: column \"{column}\": \"{value}\" is not a finite number", path.display())]
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
    },
    /// A condition-level cell converts to a level outside \[0, 1\].
    #[error("{}:{line}:{field}: column \"{column}\": {value} converts to the condition level {level}, outside [0, 1] (columns.alpha: raw * gain + offset)", path.display())]
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
    },
    /// A file or a cut gives no run.
    #[error("{}: {message}", path.display())]
    NoRuns {
        /// The raw file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// The time stamps of a run break the loader's rule (named with the raw file's lines).
    #[error(transparent)]
    Time(#[from] DatasetError),
}

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
    /// Unit of `raw * gain + offset`: see [`unit_factor`].
    pub unit: String,
    /// Multiplier of the raw number (e.g. mm per volt for a voltage channel; default 1).
    #[serde(default = "one")]
    pub gain: f64,
    /// Added after the gain, in `unit` (e.g. a potentiometer's zero; default 0).
    #[serde(default)]
    pub offset: f64,
    /// Negate the converted value (compression-positive stroke or force; default false).
    #[serde(default)]
    pub invert: bool,
    /// Subtract the mid-range of each run after conversion (a displacement whose zero is
    /// arbitrary; default false).
    #[serde(default)]
    pub center: bool,
}

fn one() -> f64 {
    1.0
}

impl ColumnSpec {
    /// Parses the command-line form `NAME:UNIT` or `#INDEX:UNIT` (the last `:` separates the
    /// unit, so names may contain colons).
    pub fn parse_flag(text: &str) -> Result<ColumnSpec, String> {
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
            gain: 1.0,
            offset: 0.0,
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
    /// Condition level per sample (unit `1`), optional: `raw * gain + offset` must lie in
    /// \[0, 1\] (e.g. an MR damper's 0-5 V control voltage with `gain = 0.2`). The runs then
    /// carry the level per sample (the run file's `alpha` column).
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
    pub method: SplitMethod,
    /// Shortest pause \[s\] (`pauses`; default 1).
    pub min_pause_s: f64,
    /// Displacement band of a pause, as a fraction of the file's stroke range (`pauses`;
    /// default 0.01).
    pub pause_band: f64,
    /// Segments shorter than this \[s\] are dropped and listed (default 1).
    pub min_run_s: f64,
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
    pub start_s: f64,
    /// End \[s\] (exclusive).
    pub end_s: f64,
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
    /// (default: the rate fitted to the first run's stamps, rounded to 1 Hz when that is
    /// within 0.1 %).
    #[serde(default)]
    pub rate_hz: Option<f64>,
    /// Resample every run onto a uniform grid at this rate \[Hz\] by linear interpolation
    /// (only on request; without it non-uniform stamps are refused like the loader does).
    #[serde(default)]
    pub resample_hz: Option<f64>,
    /// Default cutting of every file.
    #[serde(default)]
    pub split: SplitSpec,
    /// The raw files.
    #[serde(default)]
    pub files: Vec<FileSpec>,
}

/// 1-based line and column of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset.min(text.len())).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, before[start..].chars().count() + 1)
}

/// Reads an import spec; file paths in it become relative to the spec's folder.
pub fn read_spec(path: &Path) -> Result<ImportSpec, ImportError> {
    let text = std::fs::read_to_string(path).map_err(|error| ImportError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    let mut spec: ImportSpec = toml::from_str(&text).map_err(|e| {
        let (line, column) = line_col(&text, e.span().map_or(0, |s| s.start));
        ImportError::SpecSyntax {
            path: path.to_path_buf(),
            line,
            column,
            message: e.message().trim().to_string(),
        }
    })?;
    let base = path.parent().unwrap_or(Path::new(""));
    for f in &mut spec.files {
        if f.path.is_relative() {
            f.path = base.join(&f.path);
        }
    }
    Ok(spec)
}

/// SI factor of a unit name (`m`, `cm`, `mm`, `um`, `in`; `N`, `kN`, `lbf`, `kgf`; `m/s`,
/// `mm/s`, `in/s`; `s`, `ms`, `us`, `min`; `1` for the level) for a column role (`time`,
/// `displacement`, `force`, `velocity`, `alpha`).
pub fn unit_factor(role: &str, unit: &str) -> Option<f64> {
    let table: &[(&str, f64)] = match role {
        "time" => &[("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("min", 60.0)],
        "displacement" => &[
            ("m", 1.0),
            ("cm", 1e-2),
            ("mm", 1e-3),
            ("um", 1e-6),
            ("in", 0.0254),
        ],
        "force" => &[
            ("N", 1.0),
            ("kN", 1e3),
            ("lbf", 4.448_221_615_260_5),
            ("kgf", 9.806_65),
        ],
        "velocity" => &[("m/s", 1.0), ("mm/s", 1e-3), ("in/s", 0.0254)],
        "alpha" => &[("1", 1.0)],
        _ => &[],
    };
    table.iter().find(|(u, _)| *u == unit).map(|(_, f)| *f)
}

/// Checks the spec's values (units, gains, levels, rates, cutting options).
pub fn validate_spec(spec: &ImportSpec) -> Result<(), ImportError> {
    for (role, c) in spec.columns.roles() {
        let Some(c) = c else { continue };
        let key = |k: &str| format!("columns.{role}.{k}");
        if c.name.is_some() == c.index.is_some() {
            return Err(spec_err(
                key("name"),
                "give exactly one of `name` and `index`",
            ));
        }
        if c.index == Some(0) {
            return Err(spec_err(key("index"), "columns are counted from 1"));
        }
        if unit_factor(role, &c.unit).is_none() {
            let accepted: Vec<&str> = ["s", "ms", "us", "min", "m", "cm", "mm", "um", "in"]
                .into_iter()
                .chain(["N", "kN", "lbf", "kgf", "m/s", "mm/s", "in/s", "1"])
                .filter(|u| unit_factor(role, u).is_some())
                .collect();
            return Err(spec_err(
                key("unit"),
                format!(
                    "\"{}\" is not a {role} unit (one of {}; for volts give the unit of \
                     `gain` times volts, e.g. unit = \"mm\" with gain = mm per volt)",
                    c.unit,
                    accepted.join(", ")
                ),
            ));
        }
        if !(c.gain.is_finite() && c.gain != 0.0) {
            return Err(spec_err(
                key("gain"),
                format!("{} is not a non-zero number", c.gain),
            ));
        }
        if !c.offset.is_finite() {
            return Err(spec_err(key("offset"), "is not finite"));
        }
    }
    for (k, v) in [("rate_hz", spec.rate_hz), ("resample_hz", spec.resample_hz)] {
        if let Some(v) = v {
            if !(v.is_finite() && v > 0.0) {
                return Err(spec_err(k, format!("{v} is not a positive rate in Hz")));
            }
        }
    }
    if spec.columns.time.is_none() && spec.rate_hz.is_none() {
        return Err(spec_err(
            "rate_hz",
            "needed when there is no time column (columns.time)",
        ));
    }
    let csv = &spec.csv;
    if csv.header_line == 0 {
        return Err(spec_err("csv.header_line", "lines are counted from 1"));
    }
    delimiter_byte(&csv.delimiter)?;
    if csv.decimal_comma && delimiter_byte(&csv.delimiter)? == b',' {
        return Err(spec_err(
            "csv.decimal_comma",
            "needs a delimiter other than \",\"",
        ));
    }
    if let Some(c) = &csv.comment {
        if c.len() != 1 {
            return Err(spec_err("csv.comment", "must be one ASCII character"));
        }
    }
    if spec.files.is_empty() {
        return Err(spec_err("files", "no raw files given"));
    }
    let check_split = |key: String, s: &SplitSpec| {
        for (k, v) in [
            ("min_pause_s", s.min_pause_s),
            ("pause_band", s.pause_band),
            ("min_run_s", s.min_run_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(spec_err(
                    format!("{key}.{k}"),
                    format!("{v} is not positive"),
                ));
            }
        }
        Ok(())
    };
    check_split("split".into(), &spec.split)?;
    for (i, f) in spec.files.iter().enumerate() {
        let level_ok = |a: f64| (0.0..=1.0).contains(&a);
        match f.alpha {
            Some(a) if !level_ok(a) => {
                return Err(spec_err(
                    format!("files[{i}].alpha"),
                    format!("{a} is outside [0, 1]"),
                ))
            }
            None if spec.columns.alpha.is_none() => {
                return Err(spec_err(
                    format!("files[{i}].alpha"),
                    "missing: give the file's condition level, or a level column \
                     (columns.alpha)",
                ))
            }
            _ => {}
        }
        if let Some(s) = &f.split {
            check_split(format!("files[{i}].split"), s)?;
        }
        for (j, r) in f.runs.iter().enumerate() {
            if !(r.start_s.is_finite() && r.end_s.is_finite() && r.start_s < r.end_s) {
                return Err(spec_err(
                    format!("files[{i}].runs[{j}]"),
                    format!("start_s {} must be below end_s {}", r.start_s, r.end_s),
                ));
            }
            if let Some(a) = r.alpha.filter(|a| !level_ok(*a)) {
                return Err(spec_err(
                    format!("files[{i}].runs[{j}].alpha"),
                    format!("{a} is outside [0, 1]"),
                ));
            }
        }
    }
    Ok(())
}

fn delimiter_byte(d: &str) -> Result<u8, ImportError> {
    match d {
        "tab" | "\t" => Ok(b'\t'),
        d if d.len() == 1 => Ok(d.as_bytes()[0]),
        _ => Err(spec_err(
            "csv.delimiter",
            format!("\"{d}\" is not one ASCII character or \"tab\""),
        )),
    }
}

/// One raw file converted to SI units, with the source line of every sample.
#[derive(Debug, Clone, PartialEq)]
struct Converted {
    time_s: Vec<f64>,
    displacement_m: Vec<f64>,
    force_n: Vec<f64>,
    velocity_m_s: Option<Vec<f64>>,
    alpha: Option<Vec<f64>>,
    lines: Vec<usize>,
}

fn read_file(spec: &ImportSpec, path: &Path) -> Result<Converted, ImportError> {
    let bytes = std::fs::read(path).map_err(|error| ImportError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(&bytes);
    let o = &spec.csv;
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .delimiter(delimiter_byte(&o.delimiter)?)
        .comment(o.comment.as_ref().and_then(|c| c.bytes().next()))
        .from_reader(bytes);
    let csv_err = |e: csv::Error, line: usize| ImportError::Csv {
        path: path.to_path_buf(),
        line: e
            .position()
            .map_or(line, |p| usize::try_from(p.line()).unwrap_or(usize::MAX)),
        message: e.to_string(),
    };
    let mut header: Option<(usize, Vec<String>)> = None;
    let mut idx: Vec<(&'static str, usize, f64, &ColumnSpec)> = Vec::new();
    let mut out = Converted {
        time_s: Vec::new(),
        displacement_m: Vec::new(),
        force_n: Vec::new(),
        velocity_m_s: spec.columns.velocity.as_ref().map(|_| Vec::new()),
        alpha: spec.columns.alpha.as_ref().map(|_| Vec::new()),
        lines: Vec::new(),
    };
    let mut record = csv::StringRecord::new();
    let mut last = 0;
    loop {
        match reader.read_record(&mut record) {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => return Err(csv_err(e, last + 1)),
        }
        let line = record.position().map_or(last + 1, |p| {
            usize::try_from(p.line()).unwrap_or(usize::MAX)
        });
        last = line;
        let Some((hline, names)) = &header else {
            if line < o.header_line {
                continue;
            }
            let names: Vec<String> = record.iter().map(str::to_string).collect();
            for (role, c) in spec.columns.roles() {
                let Some(c) = c else { continue };
                let found = match (&c.name, c.index) {
                    (Some(n), _) => names.iter().position(|h| h == n),
                    (None, Some(i)) => (i >= 1 && i <= names.len()).then(|| i - 1),
                    (None, None) => None,
                };
                let i = found.ok_or_else(|| ImportError::MissingColumn {
                    path: path.to_path_buf(),
                    line,
                    role: role.to_string(),
                    column: c.label(),
                    header: names.join(","),
                })?;
                let factor = unit_factor(role, &c.unit).unwrap_or(1.0);
                idx.push((role, i, factor, c));
            }
            header = Some((line, names));
            continue;
        };
        let _ = hline;
        if record.iter().all(str::is_empty) {
            continue;
        }
        let mut time = None;
        for &(role, i, factor, c) in &idx {
            let raw = record.get(i).unwrap_or("");
            let text = if o.decimal_comma {
                raw.replace(',', ".")
            } else {
                raw.to_string()
            };
            let v = match text.parse::<f64>() {
                Ok(v) if v.is_finite() => v,
                _ => {
                    return Err(ImportError::BadCell {
                        path: path.to_path_buf(),
                        line,
                        field: i + 1,
                        column: names.get(i).cloned().unwrap_or_default(),
                        value: raw.to_string(),
                    })
                }
            };
            let si = (v * c.gain + c.offset) * factor * if c.invert { -1.0 } else { 1.0 };
            match role {
                "time" => time = Some(si),
                "displacement" => out.displacement_m.push(si),
                "force" => out.force_n.push(si),
                "alpha" => {
                    if !(0.0..=1.0).contains(&si) {
                        return Err(ImportError::LevelOutOfRange {
                            path: path.to_path_buf(),
                            line,
                            field: i + 1,
                            column: names.get(i).cloned().unwrap_or_default(),
                            value: raw.to_string(),
                            level: si,
                        });
                    }
                    if let Some(a) = out.alpha.as_mut() {
                        a.push(si);
                    }
                }
                _ => {
                    if let Some(vel) = out.velocity_m_s.as_mut() {
                        vel.push(si);
                    }
                }
            }
        }
        let t = match (time, spec.rate_hz) {
            (Some(t), _) => t,
            (None, Some(r)) => out.lines.len() as f64 / r,
            (None, None) => 0.0,
        };
        if let Some(&prev) = out.time_s.last() {
            if t.is_nan() || t <= prev {
                return Err(ImportError::Time(DatasetError::NonMonotonicTime {
                    path: path.to_path_buf(),
                    line,
                    time: t,
                    previous: prev,
                }));
            }
        }
        out.time_s.push(t);
        out.lines.push(line);
    }
    if header.is_none() {
        return Err(ImportError::NoRuns {
            path: path.to_path_buf(),
            message: format!("no header at line {} (csv.header_line)", o.header_line),
        });
    }
    if out.time_s.is_empty() {
        return Err(ImportError::NoRuns {
            path: path.to_path_buf(),
            message: "no samples after the header".into(),
        });
    }
    Ok(out)
}

/// Sample ranges `[start, end)` of the segments of a converted file: those kept and those
/// shorter than `min_run_s`.
type Segments = (Vec<(usize, usize)>, Vec<(usize, usize)>);

fn segments(c: &Converted, split: &SplitSpec) -> Segments {
    let n = c.time_s.len();
    let cuts: Vec<(usize, usize)> = match split.method {
        SplitMethod::None => vec![(0, n)],
        SplitMethod::Gaps => {
            let mut steps: Vec<f64> = c.time_s.windows(2).map(|w| w[1] - w[0]).collect();
            if steps.is_empty() {
                return (vec![(0, n)], Vec::new());
            }
            let mid = steps.len() / 2;
            let median = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
            let mut out = Vec::new();
            let mut start = 0;
            for i in 1..n {
                if c.time_s[i] - c.time_s[i - 1] > dataset::GAP_STEPS * median {
                    out.push((start, i));
                    start = i;
                }
            }
            out.push((start, n));
            out
        }
        SplitMethod::Pauses => {
            let span = (c.time_s[n - 1] - c.time_s[0]).max(f64::MIN_POSITIVE);
            let dt = span / (n.max(2) - 1) as f64;
            // Blocks of a tenth of the shortest pause; a pause is ten quiet blocks in a row.
            let block = ((0.1 * split.min_pause_s / dt).round() as usize).max(1);
            let (lo, hi) = c
                .displacement_m
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
                    (l.min(x), h.max(x))
                });
            let band = split.pause_band * (hi - lo);
            let quiet: Vec<bool> = c
                .displacement_m
                .chunks(block)
                .map(|b| {
                    let (l, h) = b
                        .iter()
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
                            (l.min(x), h.max(x))
                        });
                    h - l <= band
                })
                .collect();
            let mut pause = vec![false; quiet.len()];
            let mut k = 0;
            while k < quiet.len() {
                if quiet[k] {
                    let end = quiet[k..]
                        .iter()
                        .position(|q| !q)
                        .map_or(quiet.len(), |e| k + e);
                    if end - k >= 10 {
                        pause[k..end].iter_mut().for_each(|p| *p = true);
                    }
                    k = end;
                } else {
                    k += 1;
                }
            }
            let mut out = Vec::new();
            let mut start = None;
            for (b, p) in pause.iter().enumerate() {
                match (start, p) {
                    (None, false) => start = Some(b),
                    (Some(s), true) => {
                        out.push((s * block, b * block));
                        start = None;
                    }
                    _ => {}
                }
            }
            if let Some(s) = start {
                out.push((s * block, n));
            }
            out
        }
    };
    // A file that is not cut is one run, however short.
    cuts.into_iter()
        .filter(|&(a, b)| b > a)
        .partition(|&(a, b)| {
            split.method == SplitMethod::None || c.time_s[b - 1] - c.time_s[a] >= split.min_run_s
        })
}

/// Linear interpolation of `y(t)` at `tq` (inside `t`'s range).
fn interpolate(t: &[f64], y: &[f64], tq: &[f64]) -> Vec<f64> {
    let mut j = 0;
    tq.iter()
        .map(|&q| {
            while j + 2 < t.len() && t[j + 1] < q {
                j += 1;
            }
            let (t0, t1) = (t[j], t[(j + 1).min(t.len() - 1)]);
            let w = if t1 > t0 {
                ((q - t0) / (t1 - t0)).clamp(0.0, 1.0)
            } else {
                0.0
            };
            y[j] + w * (y[(j + 1).min(t.len() - 1)] - y[j])
        })
        .collect()
}

/// What the import did, for the report.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportedRun {
    /// The raw file.
    pub source: PathBuf,
    /// First and last source line of the run.
    pub lines: (usize, usize),
    /// Source time range \[s\].
    pub time_s: (f64, f64),
    /// The grid fitted to the source stamps.
    pub grid: dataset::TimeGrid,
    /// `true` if the run was resampled.
    pub resampled: bool,
}

/// The imported dataset and a per-run account.
#[derive(Debug, Clone, PartialEq)]
pub struct Imported {
    /// The dataset (write it with [`dataset::write()`]).
    pub dataset: Dataset,
    /// One entry per run, in dataset order.
    pub runs: Vec<ImportedRun>,
    /// Segments dropped as shorter than `min_run_s`: `(file, start s, end s)`.
    pub dropped: Vec<(PathBuf, f64, f64)>,
}

/// Reads, converts and cuts every file of `spec` into a dataset named `name`.
pub fn import(spec: &ImportSpec, name: &str) -> Result<Imported, ImportError> {
    validate_spec(spec)?;
    let mut pieces: Vec<(usize, Converted, Option<f64>)> = Vec::new();
    let mut dropped = Vec::new();
    for (fi, f) in spec.files.iter().enumerate() {
        let c = read_file(spec, &f.path)?;
        let mut ranges: Vec<(usize, usize, Option<f64>)> = Vec::new();
        if f.runs.is_empty() {
            let split = f.split.as_ref().unwrap_or(&spec.split);
            let (segs, short) = segments(&c, split);
            dropped.extend(
                short
                    .into_iter()
                    .map(|(a, b)| (f.path.clone(), c.time_s[a], c.time_s[b - 1])),
            );
            if segs.is_empty() {
                return Err(ImportError::NoRuns {
                    path: f.path.clone(),
                    message: format!(
                        "no segment of at least min_run_s = {} s (split {:?})",
                        split.min_run_s, split.method
                    ),
                });
            }
            ranges.extend(segs.into_iter().map(|(a, b)| (a, b, f.alpha)));
        } else {
            for (j, r) in f.runs.iter().enumerate() {
                let a = c.time_s.partition_point(|t| *t < r.start_s);
                let b = c.time_s.partition_point(|t| *t < r.end_s);
                if b <= a {
                    return Err(ImportError::NoRuns {
                        path: f.path.clone(),
                        message: format!(
                            "files[{fi}].runs[{j}]: no samples in {} .. {} s (the file spans \
                             {} .. {} s)",
                            r.start_s,
                            r.end_s,
                            c.time_s[0],
                            c.time_s[c.time_s.len() - 1]
                        ),
                    });
                }
                ranges.push((a, b, r.alpha.or(f.alpha)));
            }
        }
        for (a, b, alpha) in ranges {
            let mut piece = Converted {
                time_s: c.time_s[a..b].to_vec(),
                displacement_m: c.displacement_m[a..b].to_vec(),
                force_n: c.force_n[a..b].to_vec(),
                velocity_m_s: c.velocity_m_s.as_ref().map(|v| v[a..b].to_vec()),
                alpha: c.alpha.as_ref().map(|v| v[a..b].to_vec()),
                lines: c.lines[a..b].to_vec(),
            };
            if spec.columns.displacement.center {
                center(&mut piece.displacement_m);
            }
            if spec.columns.force.center {
                center(&mut piece.force_n);
            }
            if let (Some(v), Some(true)) = (
                piece.velocity_m_s.as_mut(),
                spec.columns.velocity.as_ref().map(|c| c.center),
            ) {
                center(v);
            }
            pieces.push((fi, piece, alpha));
        }
    }
    let rate_hz = match (spec.resample_hz, spec.rate_hz) {
        (Some(r), _) | (None, Some(r)) => r,
        (None, None) => {
            let first = &pieces
                .first()
                .map(|p| &p.1.time_s)
                .cloned()
                .unwrap_or_default();
            let r = dataset::fit_time_grid(first, 1.0).rate_hz();
            let rounded = r.round();
            if rounded > 0.0 && (r / rounded - 1.0).abs() <= 1e-3 {
                rounded
            } else {
                r
            }
        }
    };
    let mut runs = Vec::new();
    let mut account = Vec::new();
    let mut counters: Vec<usize> = vec![0; spec.files.len()];
    let total_of = |fi: usize| pieces.iter().filter(|p| p.0 == fi).count();
    for (fi, piece, alpha) in &pieces {
        let f = &spec.files[*fi];
        let grid = dataset::fit_time_grid(&piece.time_s, 1.0 / rate_hz);
        let k = counters[*fi];
        counters[*fi] += 1;
        let stem = f
            .path
            .file_stem()
            .map_or("run".into(), |s| s.to_string_lossy().into_owned());
        let file = if total_of(*fi) > 1 {
            PathBuf::from(format!("runs/{stem}_{:02}.csv", k + 1))
        } else {
            PathBuf::from(format!("runs/{stem}.csv"))
        };
        // The label: the given level, else the mean of the run's levels (a level column).
        let label = alpha.unwrap_or_else(|| {
            piece
                .alpha
                .as_ref()
                .map_or(0.0, |a| a.iter().sum::<f64>() / a.len().max(1) as f64)
        });
        let entry = RunEntry {
            file,
            oil_loss: label,
            amplitude_m: None,
            target_velocity_m_s: None,
        };
        let run = if let Some(r) = spec.resample_hz {
            let t0 = piece.time_s[0];
            let span = piece.time_s[piece.time_s.len() - 1] - t0;
            let m = (span * r + 1e-9).floor() as usize + 1;
            let tq: Vec<f64> = (0..m).map(|i| t0 + i as f64 / r).collect();
            Run {
                entry,
                displacement_m: interpolate(&piece.time_s, &piece.displacement_m, &tq),
                force_n: interpolate(&piece.time_s, &piece.force_n, &tq),
                velocity_m_s: piece
                    .velocity_m_s
                    .as_ref()
                    .map(|v| interpolate(&piece.time_s, v, &tq)),
                alpha: piece
                    .alpha
                    .as_ref()
                    .map(|a| interpolate(&piece.time_s, a, &tq)),
                time_s: tq,
            }
        } else {
            dataset::check_time_grid(&piece.time_s, rate_hz, &f.path, |i| {
                piece.lines.get(i).copied().unwrap_or(0)
            })?;
            Run {
                entry,
                time_s: piece.time_s.clone(),
                displacement_m: piece.displacement_m.clone(),
                force_n: piece.force_n.clone(),
                velocity_m_s: piece.velocity_m_s.clone(),
                alpha: piece.alpha.clone(),
            }
        };
        account.push(ImportedRun {
            source: f.path.clone(),
            lines: (
                piece.lines.first().copied().unwrap_or(0),
                piece.lines.last().copied().unwrap_or(0),
            ),
            time_s: (
                piece.time_s.first().copied().unwrap_or(0.0),
                piece.time_s.last().copied().unwrap_or(0.0),
            ),
            grid,
            resampled: spec.resample_hz.is_some(),
        });
        runs.push(run);
    }
    Ok(Imported {
        dataset: Dataset {
            name: spec.name.clone().unwrap_or_else(|| name.to_string()),
            sample_rate_hz: rate_hz,
            condition: None,
            runs,
        },
        runs: account,
        dropped,
    })
}

/// Subtracts the mid-range.
fn center(x: &mut [f64]) {
    let (lo, hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let mid = 0.5 * (lo + hi);
    x.iter_mut().for_each(|v| *v -= mid);
}
