//! Loading a dataset: run CSVs parsed with file, line and column in every error, time stamps
//! fitted to the sample grid.

use super::*;

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
