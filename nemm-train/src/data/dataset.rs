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
//! `velocity_m_s` and `alpha` (the condition level per sample, in \[0, 1\], for a condition
//! changing within the run). Displacement positive = extension (rebound); force positive =
//! tension (rebound force). Values are `f64` in memory.
//!
//! Time must be uniform at `sample_rate_hz`: every step may deviate from `1 / sample_rate_hz`
//! by at most [`MAX_STEP_JITTER`] (1 %). Any sample rate works; the model integrates at its
//! own rate, independent of the data's (see `docs/preprocessing.md`).
//!
//! [`load`] refuses every malformed input with a [`DatasetError`] that names the file, the
//! line and (where there is one) the column or manifest key; nothing is silently dropped.
//! [`write()`] writes each file atomically (temporary file + rename, manifest last) with
//! Rust's shortest round-trip float format, so `load(write(d)) == d` exactly.

use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use toml::Spanned;

/// File name of the manifest inside a dataset folder.
pub const MANIFEST_FILE: &str = "manifest.toml";

/// Largest tolerated relative deviation of a time step from `1 / sample_rate_hz` (1 %).
pub const MAX_STEP_JITTER: f64 = 0.01;

/// Name of the time column \[s\].
pub const COL_TIME: &str = "time_s";
/// Name of the displacement column \[m\].
pub const COL_DISPLACEMENT: &str = "displacement_m";
/// Name of the force column \[N\].
pub const COL_FORCE: &str = "force_n";
/// Name of the optional measured velocity column \[m/s\].
pub const COL_VELOCITY: &str = "velocity_m_s";
/// Name of the optional per-sample condition level column (in \[0, 1\]).
pub const COL_ALPHA: &str = "alpha";

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

    /// The manifest describing this dataset.
    pub fn manifest(&self) -> Manifest {
        Manifest {
            name: self.name.clone(),
            sample_rate_hz: self.sample_rate_hz,
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
    /// A time step deviates more than [`MAX_STEP_JITTER`] from `1 / sample_rate_hz`.
    #[error(
        "{}:{line}: column \"time_s\": step {step} s deviates {deviation_percent:.2} % from \
         1 / sample_rate_hz = {expected} s (at most 1 % tolerated)",
        path.display()
    )]
    Jitter {
        /// The CSV file.
        path: PathBuf,
        /// The row's line (the step ends at this row).
        line: usize,
        /// The step \[s\].
        step: f64,
        /// The nominal step \[s\].
        expected: f64,
        /// `|step - expected| / expected` in percent.
        deviation_percent: f64,
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
    runs: Vec<RawRun>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRun {
    file: Spanned<PathBuf>,
    oil_loss: Spanned<f64>,
    #[serde(default)]
    amplitude_m: Option<Spanned<f64>>,
    #[serde(default)]
    target_velocity_m_s: Option<Spanned<f64>>,
}

/// Spans of the manifest values, for error lines (`None` for in-memory manifests).
struct ManifestLines {
    sample_rate_hz: usize,
    runs: Vec<RunLines>,
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
                    "{} is outside [0, 1] (fraction of oil volume lost)",
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
    let lines = ManifestLines {
        sample_rate_hz: line_of(raw.sample_rate_hz.span()),
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
    let nominal_step = 1.0 / sample_rate_hz;
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
            check_step(previous, t, nominal_step, path, line)?;
        }
        time_s.push(t);
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

/// Line of sample `i` in a file written by [`write`] (header is line 1).
fn sample_line(i: usize) -> usize {
    i + 2
}

/// Checks one time step ending at `line`: strictly increasing and within
/// [`MAX_STEP_JITTER`] of `nominal_step`.
fn check_step(
    previous: f64,
    time: f64,
    nominal_step: f64,
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
    let deviation = (step - nominal_step).abs() / nominal_step;
    if deviation > MAX_STEP_JITTER {
        return Err(DatasetError::Jitter {
            path: path.to_path_buf(),
            line,
            step,
            expected: nominal_step,
            deviation_percent: deviation * 100.0,
        });
    }
    Ok(())
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
    let nominal_step = 1.0 / sample_rate_hz;
    for (i, w) in run.time_s.windows(2).enumerate() {
        check_step(w[0], w[1], nominal_step, path, sample_line(i + 1))?;
    }
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
