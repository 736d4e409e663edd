//! Loading a dataset: run CSVs parsed with file, line and column in every error, time stamps
//! fitted to the sample grid.

use crate::csv::{CellError, CellProblem, CsvError, CsvReader, Dialect, Row};
use crate::manifest::read_manifest_with_lines;
use crate::{
    io_err, Dataset, DatasetError, LoadProgress, Manifest, Run, RunEntry, COL_ALPHA,
    COL_DISPLACEMENT, COL_FORCE, COL_TIME, COL_VELOCITY, EXACT_GRID_DEVIATION, GAP_STEPS,
    MANIFEST_FILE, MAX_GRID_DEVIATION, MAX_RATE_MISMATCH,
};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Loads and validates a dataset folder (runs are parsed in parallel).
pub fn load(dir: &Path) -> Result<Dataset, DatasetError> {
    load_with_progress(dir, |_| {})
}

/// [`load`], calling `progress` after each run is parsed (from worker threads).
///
/// Every run file must exist and resolve inside the folder before any is parsed (a typo is
/// reported at once, and no file outside the dataset is ever read). On several bad files
/// the error of the first one in manifest order is returned.
pub fn load_with_progress(
    dir: &Path,
    progress: impl Fn(LoadProgress) + Sync,
) -> Result<Dataset, DatasetError> {
    let (manifest, files) = run_files(dir)?;
    let files = files.into_iter().collect::<Result<Vec<_>, _>>()?;
    let runs = read_runs(&manifest, files.into_iter().map(Ok).collect(), &progress);
    let runs = runs.into_iter().collect::<Result<Vec<_>, _>>()?;
    Ok(Dataset {
        name: manifest.name,
        sample_rate_hz: manifest.sample_rate_hz,
        condition: manifest.condition,
        runs,
    })
}

/// A dataset whose readable runs are loaded, with the errors of those that are not (a
/// missing file, one outside the folder, a malformed row), in manifest order: what `nemm
/// data check` reports on, so that one bad file does not hide the others' findings. Errors
/// of the manifest itself are returned as such.
pub fn load_readable(dir: &Path) -> Result<(Dataset, Vec<DatasetError>), DatasetError> {
    let (manifest, files) = run_files(dir)?;
    let mut runs = Vec::new();
    let mut errors = Vec::new();
    for r in read_runs(&manifest, files, &|_| {}) {
        match r {
            Ok(run) => runs.push(run),
            Err(e) => errors.push(e),
        }
    }
    Ok((
        Dataset {
            name: manifest.name,
            sample_rate_hz: manifest.sample_rate_hz,
            condition: manifest.condition,
            runs,
        },
        errors,
    ))
}

/// The manifest of `dir` and the path of each run file, checked to exist and to resolve
/// inside the folder.
#[allow(clippy::type_complexity)] // a manifest and one result per run
fn run_files(dir: &Path) -> Result<(Manifest, Vec<Result<PathBuf, DatasetError>>), DatasetError> {
    let (manifest, lines) = read_manifest_with_lines(dir)?;
    let manifest_path = dir.join(MANIFEST_FILE);
    let root = std::fs::canonicalize(dir).map_err(io_err(dir))?;
    let files = manifest
        .runs
        .iter()
        .zip(&lines.runs)
        .enumerate()
        .map(|(i, (entry, rl))| {
            let file = dir.join(&entry.file);
            if !file.is_file() {
                return Err(DatasetError::MissingRunFile {
                    manifest: manifest_path.clone(),
                    line: rl.file,
                    key: format!("runs[{i}].file"),
                    file,
                });
            }
            let resolved = std::fs::canonicalize(&file).map_err(io_err(&file))?;
            if !resolved.starts_with(&root) {
                return Err(DatasetError::RunFileOutside {
                    manifest: manifest_path.clone(),
                    line: rl.file,
                    key: format!("runs[{i}].file"),
                    file,
                    resolved,
                });
            }
            Ok(file)
        })
        .collect();
    Ok((manifest, files))
}

/// Parses the run files (in parallel; an error in `files` is passed through), in manifest
/// order, calling `progress` after each run.
fn read_runs(
    manifest: &Manifest,
    files: Vec<Result<PathBuf, DatasetError>>,
    progress: &(impl Fn(LoadProgress) + Sync),
) -> Vec<Result<Run, DatasetError>> {
    use rayon::prelude::*;
    let runs_total = manifest.runs.len();
    let runs_done = AtomicUsize::new(0);
    let samples_done = AtomicUsize::new(0);
    let fs = manifest.sample_rate_hz;
    manifest
        .runs
        .par_iter()
        .zip(files)
        .map(|(entry, file)| {
            let run = read_run(&file?, entry.clone(), fs)?;
            let samples = samples_done.fetch_add(run.len(), Ordering::Relaxed) + run.len();
            let done = runs_done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(LoadProgress {
                runs_done: done,
                runs_total,
                samples_done: samples,
            });
            Ok(run)
        })
        .collect()
}

/// Reads and validates one run CSV file at `path` sampled at `sample_rate_hz`.
pub fn read_run(path: &Path, entry: RunEntry, sample_rate_hz: f64) -> Result<Run, DatasetError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    parse_run(&bytes, path, entry, sample_rate_hz)
}

/// Reads and validates one run CSV file at `path` without its manifest (a replay trace):
/// the sample rate is the one its time stamps show (the inverse of their median step), held
/// to the grid rule of [`check_time_grid`]. Returns the run and the fitted grid.
pub fn read_lone_run(path: &Path, entry: RunEntry) -> Result<(Run, TimeGrid), DatasetError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let (run, lines) = parse_samples(&bytes, path, entry)?;
    let rate_hz = 1.0 / median_step(before_first_gap(&run.time_s));
    let grid = check_time_grid(&run.time_s, rate_hz, path, |i| {
        lines.get(i).copied().unwrap_or(i + 2)
    })?;
    Ok((run, grid))
}

/// Parses and validates the content of one run CSV file; `path` is used in errors only.
pub fn parse_run(
    bytes: &[u8],
    path: &Path,
    entry: RunEntry,
    sample_rate_hz: f64,
) -> Result<Run, DatasetError> {
    let (run, lines) = parse_samples(bytes, path, entry)?;
    check_time_grid(&run.time_s, sample_rate_hz, path, |i| {
        lines.get(i).copied().unwrap_or(i + 2)
    })?;
    Ok(run)
}

/// The samples of one run CSV file and the line of each, before the time-grid check.
fn parse_samples(
    bytes: &[u8],
    path: &Path,
    entry: RunEntry,
) -> Result<(Run, Vec<usize>), DatasetError> {
    let mut reader = CsvReader::new(bytes, path, Dialect::RUN_FILE);
    let header = match reader.read_header().map_err(csv_error)? {
        Some(h) if !(h.names.len() == 1 && h.names[0].is_empty()) => h,
        _ => {
            return Err(DatasetError::EmptyFile {
                path: path.to_path_buf(),
            })
        }
    };
    let columns = RunColumns::find(&header.names, path)?;
    // Pre-size from the byte count (about 30-60 bytes per row).
    let mut samples = Samples::new(&columns, bytes.len() / 32);
    while let Some(row) = reader.next_row().map_err(csv_error)? {
        samples.push(&row, &columns, path)?;
    }
    if samples.time_s.is_empty() {
        return Err(DatasetError::NoSamples {
            path: path.to_path_buf(),
            line: header.line + 1,
        });
    }
    let run = Run {
        entry,
        time_s: samples.time_s,
        displacement_m: samples.displacement_m,
        force_n: samples.force_n,
        velocity_m_s: samples.velocity_m_s,
        alpha: samples.alpha,
    };
    Ok((run, samples.lines))
}

/// The reader's error as a [`DatasetError`].
fn csv_error(e: CsvError) -> DatasetError {
    match e {
        CsvError::Malformed {
            path,
            line,
            message,
        } => DatasetError::Csv {
            path,
            line,
            message,
        },
        CsvError::FieldCount {
            path,
            line,
            expected,
            found,
        } => DatasetError::FieldCount {
            path,
            line,
            expected,
            found,
        },
    }
}

/// A cell that is not a finite number as a [`DatasetError`].
fn cell_error(e: CellError) -> DatasetError {
    let CellError {
        path,
        line,
        column,
        value,
        problem,
        ..
    } = e;
    match problem {
        CellProblem::NotANumber => DatasetError::NotANumber {
            path,
            line,
            column,
            value,
        },
        CellProblem::NonFinite => DatasetError::NonFinite {
            path,
            line,
            column,
            value,
        },
    }
}

/// Where the columns of a run file are (field indices).
struct RunColumns {
    time: usize,
    displacement: usize,
    force: usize,
    velocity: Option<usize>,
    alpha: Option<usize>,
}

impl RunColumns {
    /// The columns in the header `names`; refuses a repeated name and a missing required
    /// column.
    fn find(names: &[String], path: &Path) -> Result<Self, DatasetError> {
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
        Ok(RunColumns {
            time: required(COL_TIME)?,
            displacement: required(COL_DISPLACEMENT)?,
            force: required(COL_FORCE)?,
            velocity: index.get(COL_VELOCITY).copied(),
            alpha: index.get(COL_ALPHA).copied(),
        })
    }
}

/// The samples of a run as read, with the line of each.
struct Samples {
    time_s: Vec<f64>,
    displacement_m: Vec<f64>,
    force_n: Vec<f64>,
    velocity_m_s: Option<Vec<f64>>,
    alpha: Option<Vec<f64>>,
    lines: Vec<usize>,
}

impl Samples {
    /// Empty columns for `columns`, with room for `capacity` samples.
    fn new(columns: &RunColumns, capacity: usize) -> Self {
        Samples {
            time_s: Vec::with_capacity(capacity),
            displacement_m: Vec::with_capacity(capacity),
            force_n: Vec::with_capacity(capacity),
            velocity_m_s: columns.velocity.map(|_| Vec::with_capacity(capacity)),
            alpha: columns.alpha.map(|_| Vec::with_capacity(capacity)),
            lines: Vec::with_capacity(capacity),
        }
    }

    /// Parses one row; refuses a cell that is not a finite number, a time that does not
    /// increase and a condition level outside \[0, 1\].
    fn push(&mut self, row: &Row<'_, '_>, c: &RunColumns, path: &Path) -> Result<(), DatasetError> {
        let line = row.line();
        let cell = |i: usize| row.number(i).map_err(cell_error);
        let t = cell(c.time)?;
        if let Some(&previous) = self.time_s.last() {
            check_increasing(previous, t, path, line)?;
        }
        self.time_s.push(t);
        self.lines.push(line);
        self.displacement_m.push(cell(c.displacement)?);
        self.force_n.push(cell(c.force)?);
        if let (Some(i), Some(v)) = (c.velocity, self.velocity_m_s.as_mut()) {
            v.push(cell(i)?);
        }
        if let (Some(i), Some(a)) = (c.alpha, self.alpha.as_mut()) {
            let value = cell(i)?;
            check_alpha(value, path, line)?;
            a.push(value);
        }
        Ok(())
    }
}

/// Checks one per-sample condition level (in \[0, 1\]).
pub(super) fn check_alpha(value: f64, path: &Path, line: usize) -> Result<(), DatasetError> {
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

/// Line of sample `i` in a file written by [`write()`](crate::write()) (header is line 1, one row per line).
pub fn sample_line(i: usize) -> usize {
    i + 2
}

/// Refuses a time that does not strictly increase (the step ending at `line`).
pub(super) fn check_increasing(
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

/// The median of the steps of `time_s` (NaN with fewer than two stamps).
pub fn median_step(time_s: &[f64]) -> f64 {
    let mut steps: Vec<f64> = time_s.windows(2).map(|w| w[1] - w[0]).collect();
    if steps.is_empty() {
        return f64::NAN;
    }
    let mid = steps.len() / 2;
    *steps.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The leading part of `time_s` before its first gap (a step longer than [`GAP_STEPS`]
/// median steps): the stretch a rate is fitted on.
pub fn before_first_gap(time_s: &[f64]) -> &[f64] {
    let limit = GAP_STEPS * median_step(time_s);
    match time_s.windows(2).position(|w| w[1] - w[0] > limit) {
        Some(i) => &time_s[..=i],
        None => time_s,
    }
}

/// Checks that increasing time stamps lie on a uniform grid at `sample_rate_hz`, as
/// rounded or jittered logger stamps do, and returns the fitted grid.
///
/// The rule, in order (`h = 1 / sample_rate_hz`; `line_of(i)` is the line of sample `i`):
/// 1. a step longer than [`GAP_STEPS`]` h` is a gap: [`DatasetError::Gap`] at its line,
///    unless the median step is more than 50 % off `h`, which is a wrong
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
    // A typical step more than 50 % off is a wrong rate, not a run full of gaps or bursts.
    // The median step, not the fitted one: a single long gap (a logger paused for an hour)
    // moves the fitted grid far off, and is then reported as a gap at its line.
    let typical = median_step(time_s);
    let coarse_off = (typical * sample_rate_hz - 1.0).abs();
    if coarse_off.is_nan() || coarse_off > 0.5 {
        return Err(rate_err(1.0 / typical));
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
