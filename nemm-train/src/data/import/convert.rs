//! The conversion: raw files read and converted to SI units, split into runs and resampled
//! onto the dataset's grid.

use super::spec::delimiter_byte;
use super::{
    condition_spec, spec_err, stamp, unit_factor, validate_spec, ColumnSpec, Columns, CsvOptions,
    FileSpec, ImportError, ImportSpec, LevelMap, SplitMethod, SplitSpec, MAX_RESAMPLED_RUN_SAMPLES,
};
use nemm_dataset as dataset;
use nemm_dataset::csv::{CsvError, CsvReader, Dialect, Header, Row};
use nemm_dataset::Dataset;
use nemm_dataset::DatasetError;
use nemm_dataset::Run;
use nemm_dataset::RunEntry;
use std::path::Path;
use std::path::PathBuf;

/// One raw file converted to SI units, with the source line of every sample.
#[derive(Debug, Clone, PartialEq)]
struct Converted {
    time_s: Vec<f64>,
    displacement_m: Vec<f64>,
    force_n: Vec<f64>,
    velocity_m_s: Option<Vec<f64>>,
    /// The level column: its raw numbers as read, alpha once mapped ([`Converted::map_levels`]).
    alpha: Option<Vec<f64>>,
    /// Field (0-based) and header name of the level column.
    alpha_field: (usize, String),
    lines: Vec<usize>,
    /// The first date-time stamp of the time column (times are seconds from it), when the
    /// column holds date-time stamps.
    origin: Option<stamp::Stamp>,
}

impl Converted {
    /// No samples yet, with the optional columns `spec` maps.
    fn empty(spec: &ImportSpec) -> Self {
        Converted {
            time_s: Vec::new(),
            displacement_m: Vec::new(),
            force_n: Vec::new(),
            velocity_m_s: spec.columns.velocity.as_ref().map(|_| Vec::new()),
            alpha: spec.columns.alpha.as_ref().map(|_| Vec::new()),
            alpha_field: (0, String::new()),
            lines: Vec::new(),
            origin: None,
        }
    }

    /// Converts one row: every mapped column to SI units (`role`, field, unit factor,
    /// spec), the time from the time column or `spec.rate_hz`; the level column's raw
    /// number is kept as read. Refuses a cell that is not a finite number and a time that
    /// does not increase.
    fn push_row(
        &mut self,
        row: &Row<'_, '_>,
        columns: &[(&'static str, usize, f64, &ColumnSpec)],
        rate_hz: Option<f64>,
        path: &Path,
    ) -> Result<(), ImportError> {
        let line = row.line();
        let mut time = None;
        for &(role, i, factor, c) in columns {
            if role == "time" {
                if let Some(t) = self.date_time(row, i, path)? {
                    time = Some(t);
                    continue;
                }
            }
            let v = row.number(i).map_err(|e| ImportError::BadCell {
                hint: if e.value.contains(',') && e.value.replace(',', ".").parse::<f64>().is_ok() {
                    "; it is written with a decimal comma: give decimal_comma = true under \
                     [csv] in the --spec file"
                        .into()
                } else {
                    String::new()
                },
                path: e.path,
                line: e.line,
                field: e.field + 1,
                column: e.column,
                value: e.value,
            })?;
            let si = (v * c.gain() + c.offset()) * factor * if c.invert { -1.0 } else { 1.0 };
            match role {
                "time" => time = Some(si),
                "displacement" => self.displacement_m.push(si),
                "force" => self.force_n.push(si),
                "alpha" => {
                    if let Some(a) = self.alpha.as_mut() {
                        if a.is_empty() {
                            self.alpha_field = (i, row.column(i));
                        }
                        a.push(v);
                    }
                }
                _ => {
                    if let Some(vel) = self.velocity_m_s.as_mut() {
                        vel.push(si);
                    }
                }
            }
        }
        let t = match (time, rate_hz) {
            (Some(t), _) => t,
            (None, Some(r)) => self.lines.len() as f64 / r,
            (None, None) => 0.0,
        };
        if let Some(&prev) = self.time_s.last() {
            if t.is_nan() || t <= prev {
                return Err(ImportError::Time(DatasetError::NonMonotonicTime {
                    path: path.to_path_buf(),
                    line,
                    time: t,
                    previous: prev,
                }));
            }
        }
        self.time_s.push(t);
        self.lines.push(line);
        Ok(())
    }
}

impl Converted {
    /// Smallest and largest raw number of the level column (`None` without one).
    fn raw_level_range(&self) -> Option<(f64, f64)> {
        self.alpha.as_ref().map(|a| {
            a.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
                    (l.min(v), h.max(v))
                })
        })
    }

    /// Maps the level column's raw numbers to alpha with `map`; refuses a level outside
    /// \[0, 1\] with the file `path`, its line and column.
    fn map_levels(&mut self, map: &LevelMap, path: &Path) -> Result<(), ImportError> {
        let Some(levels) = self.alpha.as_mut() else {
            return Ok(());
        };
        for (k, v) in levels.iter_mut().enumerate() {
            let level = map.alpha(*v);
            if !(0.0..=1.0).contains(&level) {
                return Err(ImportError::LevelOutOfRange {
                    path: path.to_path_buf(),
                    line: self.lines[k],
                    field: self.alpha_field.0 + 1,
                    column: self.alpha_field.1.clone(),
                    value: v.to_string(),
                    level,
                    mapping: map.describe(),
                });
            }
            *v = level;
        }
        Ok(())
    }

    /// The time of field `i` when it is a date-time stamp: seconds from the file's first
    /// stamp (the time column's unit, gain and offset do not apply). `None` when the cell
    /// is not written as a date (a number). Refuses a malformed stamp and a column that
    /// mixes stamps and numbers.
    fn date_time(
        &mut self,
        row: &Row<'_, '_>,
        i: usize,
        path: &Path,
    ) -> Result<Option<f64>, ImportError> {
        let text = row.text(i);
        let bad = |message: String| ImportError::BadTimeStamp {
            path: path.to_path_buf(),
            line: row.line(),
            field: i + 1,
            column: row.column(i),
            value: text.clone(),
            message,
        };
        if !stamp::looks_like_date(&text) {
            if self.origin.is_some() && row.number(i).is_ok() {
                return Err(bad(format!(
                    "the column holds date-time stamps above; write every time as a stamp ({})",
                    stamp::FORMS
                )));
            }
            return Ok(None);
        }
        if self.origin.is_none() && !self.time_s.is_empty() {
            return Err(bad(
                "the column holds numbers above; write every time as a number or every time as a date-time stamp"
                    .into(),
            ));
        }
        let s = stamp::parse(&text).map_err(|m| bad(format!("{m}; accepted: {}", stamp::FORMS)))?;
        let origin = *self.origin.get_or_insert(s);
        Ok(Some(s.since(&origin)))
    }
}

/// The reader's error as an [`ImportError`].
fn csv_error(e: CsvError) -> ImportError {
    match e {
        CsvError::Malformed {
            path,
            line,
            message,
        } => ImportError::Csv {
            path,
            line,
            message,
        },
        CsvError::FieldCount {
            path,
            line,
            expected,
            found,
        } => ImportError::Csv {
            path,
            line,
            message: format!(
                "{found} fields, but the header has {expected}: the row is ragged, so its cells \
                 cannot be matched to columns; fix or delete the row"
            ),
        },
    }
}

/// The CSV dialect of the spec's raw files.
fn dialect(o: &CsvOptions) -> Result<Dialect, ImportError> {
    Ok(Dialect {
        delimiter: delimiter_byte(&o.delimiter)?,
        comment: o.comment.as_ref().and_then(|c| c.bytes().next()),
        header_line: o.header_line,
        // Checked in `read_file`, where a line of spaces (a blank row) is skipped instead.
        same_field_count: false,
        decimal_comma: o.decimal_comma,
    })
}

/// The columns `spec` maps, found in `header`: `(role, field, unit factor, spec)` in
/// reading order.
fn find_columns<'s>(
    spec: &'s ImportSpec,
    path: &Path,
    header: &Header,
) -> Result<Vec<(&'static str, usize, f64, &'s ColumnSpec)>, ImportError> {
    let names = &header.names;
    let mut idx = Vec::new();
    for (role, c) in spec.columns.roles() {
        let Some(c) = c else { continue };
        let found = match (&c.name, c.index) {
            (Some(n), _) => names.iter().position(|h| h == n),
            (None, Some(i)) => (i >= 1 && i <= names.len()).then(|| i - 1),
            (None, None) => None,
        };
        let i = found.ok_or_else(|| ImportError::MissingColumn {
            path: path.to_path_buf(),
            line: header.line,
            role: role.to_string(),
            column: c.label(),
            header: names.join(","),
        })?;
        if let Some(n) = &c.name {
            let fields: Vec<String> = names
                .iter()
                .enumerate()
                .filter(|(_, h)| *h == n)
                .map(|(k, _)| (k + 1).to_string())
                .collect();
            if fields.len() > 1 {
                return Err(ImportError::Csv {
                    path: path.to_path_buf(),
                    line: header.line,
                    message: format!(
                        "column \"{n}\" (columns.{role}) appears {} times in the header (fields {}); \
                         rename the columns so each name is unique, or select one by its index",
                        fields.len(),
                        fields.join(", ")
                    ),
                });
            }
        }
        let factor = unit_factor(role, &c.unit).unwrap_or(1.0);
        idx.push((role, i, factor, c));
    }
    Ok(idx)
}

/// Reads one raw file and converts it to SI units.
fn read_file(spec: &ImportSpec, path: &Path) -> Result<Converted, ImportError> {
    let bytes = std::fs::read(path).map_err(|error| ImportError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    let mut reader = CsvReader::new(&bytes, path, dialect(&spec.csv)?);
    let Some(header) = reader.read_header().map_err(csv_error)? else {
        return Err(ImportError::NoRuns {
            path: path.to_path_buf(),
            message: format!(
                "no header at line {} (csv.header_line)",
                spec.csv.header_line
            ),
        });
    };
    let columns = find_columns(spec, path, &header)?;
    let mut out = Converted::empty(spec);
    while let Some(row) = reader.next_row().map_err(csv_error)? {
        if !row.is_blank() {
            if row.field_count() != header.names.len() {
                return Err(csv_error(CsvError::FieldCount {
                    path: path.to_path_buf(),
                    line: row.line(),
                    expected: header.names.len(),
                    found: row.field_count(),
                }));
            }
            out.push_row(&row, &columns, spec.rate_hz, path)?;
        }
    }
    if out.time_s.is_empty() {
        return Err(ImportError::NoRuns {
            path: path.to_path_buf(),
            message: format!(
                "no samples after the header (line {}): the file holds no data rows",
                header.line
            ),
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
    /// How the level column became alpha (`None` without a level column).
    pub level: Option<LevelMap>,
    /// Segments dropped as shorter than `min_run_s`: `(file, start s, end s)`.
    pub dropped: Vec<(PathBuf, f64, f64)>,
}

/// Reads, converts and cuts every file of `spec` into a dataset named `name`.
pub fn import(spec: &ImportSpec, name: &str) -> Result<Imported, ImportError> {
    validate_spec(spec)?;
    let mut files = spec
        .files
        .iter()
        .map(|f| read_file(spec, &f.path))
        .collect::<Result<Vec<Converted>, ImportError>>()?;
    let level = level_map(spec, &files)?;
    if let Some(map) = &level {
        for (c, f) in files.iter_mut().zip(&spec.files) {
            c.map_levels(map, &f.path)?;
        }
    }
    let condition = condition_spec(spec, level.as_ref())?;
    let mut pieces: Vec<(usize, Converted, Option<f64>)> = Vec::new();
    let mut dropped = Vec::new();
    for ((fi, f), c) in spec.files.iter().enumerate().zip(files) {
        let cuts = if f.runs.is_empty() {
            split_cuts(spec, f, &c, &mut dropped)?
        } else {
            time_cuts(fi, f, &c)?
        };
        for (a, b, alpha) in cuts {
            pieces.push((fi, c.piece(a, b, &spec.columns), alpha));
        }
    }
    let rate_hz = dataset_rate(spec, &pieces);
    let mut runs = Vec::new();
    let mut account = Vec::new();
    let mut counters: Vec<usize> = vec![0; spec.files.len()];
    for (fi, piece, alpha) in &pieces {
        let f = &spec.files[*fi];
        let k = counters[*fi];
        counters[*fi] += 1;
        let total = pieces.iter().filter(|p| p.0 == *fi).count();
        let entry = RunEntry {
            file: run_file(f, k, total),
            oil_loss: piece.label(*alpha),
            amplitude_m: None,
            target_velocity_m_s: None,
        };
        runs.push(piece.run(entry, spec.resample_hz, rate_hz, &f.path)?);
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
            grid: dataset::fit_time_grid(&piece.time_s, 1.0 / rate_hz),
            resampled: spec.resample_hz.is_some(),
        });
    }
    Ok(Imported {
        dataset: Dataset {
            name: spec.name.clone().unwrap_or_else(|| name.to_string()),
            sample_rate_hz: rate_hz,
            condition,
            runs,
        },
        runs: account,
        level,
        dropped,
    })
}

/// The mapping of the spec's level column, with the range of the raw numbers over all
/// `files` when the spec takes it from the data (refused when the column is constant).
fn level_map(spec: &ImportSpec, files: &[Converted]) -> Result<Option<LevelMap>, ImportError> {
    let Some(c) = &spec.columns.alpha else {
        return Ok(None);
    };
    let data = files
        .iter()
        .filter_map(Converted::raw_level_range)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), (a, b)| {
            (l.min(a), h.max(b))
        });
    let map = LevelMap::new(c, data);
    if let LevelMap::Range {
        at_0,
        at_1,
        from_data: true,
        ..
    } = map
    {
        if at_0 == at_1 {
            return Err(spec_err(
                "columns.alpha.range",
                format!(
                    "missing, and the level column {} holds only {at_0} over all files, so \
                     its range cannot be taken from the data: give the raw values at alpha 0 \
                     and 1, e.g. range = [0.0, 5.0] (--alpha-range 0,5)",
                    c.label()
                ),
            ));
        }
    }
    Ok(Some(map))
}

/// Samples `[start, end)` of a converted file that make one run, and the run's level when
/// the spec gives it.
type Cut = (usize, usize, Option<f64>);

/// The runs of file `f` cut by its `split` (else the spec's), with the file's level; the
/// segments shorter than `min_run_s` go to `dropped` as `(file, start s, end s)`. A file
/// without a segment long enough is an error.
fn split_cuts(
    spec: &ImportSpec,
    f: &FileSpec,
    c: &Converted,
    dropped: &mut Vec<(PathBuf, f64, f64)>,
) -> Result<Vec<Cut>, ImportError> {
    let split = f.split.as_ref().unwrap_or(&spec.split);
    let (segs, short) = segments(c, split);
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
    Ok(segs.into_iter().map(|(a, b)| (a, b, f.alpha)).collect())
}

/// The runs of file `f` (number `fi` of the spec) given by time (`[[files.runs]]`), each with
/// its level or the file's. A range without samples is an error.
fn time_cuts(fi: usize, f: &FileSpec, c: &Converted) -> Result<Vec<Cut>, ImportError> {
    let mut cuts = Vec::new();
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
        cuts.push((a, b, r.alpha.or(f.alpha)));
    }
    Ok(cuts)
}

/// The dataset's sample rate: `resample_hz`, else `rate_hz`, else the rate fitted to the
/// first run's stamps as fitted (a whole number of hertz only when the fit is within
/// 1 ppm of one, the noise of stamps rounded to 0.1 ms: a 3004.8 Hz logger keeps its
/// 3004.8 Hz).
fn dataset_rate(spec: &ImportSpec, pieces: &[(usize, Converted, Option<f64>)]) -> f64 {
    match (spec.resample_hz, spec.rate_hz) {
        (Some(r), _) | (None, Some(r)) => r,
        (None, None) => {
            let first = &pieces
                .first()
                .map(|p| &p.1.time_s)
                .cloned()
                .unwrap_or_default();
            // Fitted before the first gap, which the run check then reports at its line.
            let r = dataset::fit_time_grid(dataset::before_first_gap(first), 1.0).rate_hz();
            let rounded = r.round();
            if rounded > 0.0 && (r / rounded - 1.0).abs() <= 1e-6 {
                rounded
            } else {
                r
            }
        }
    }
}

/// The run file of the `k`-th of the `total` runs cut from `f`: `runs/<stem>.csv`, or
/// `runs/<stem>_NN.csv` when there are several.
fn run_file(f: &FileSpec, k: usize, total: usize) -> PathBuf {
    let stem = f
        .path
        .file_stem()
        .map_or("run".into(), |s| s.to_string_lossy().into_owned());
    if total > 1 {
        PathBuf::from(format!("runs/{stem}_{:02}.csv", k + 1))
    } else {
        PathBuf::from(format!("runs/{stem}.csv"))
    }
}

impl Converted {
    /// Samples `[a, b)`, with the columns the spec asks to centre centred.
    fn piece(&self, a: usize, b: usize, columns: &Columns) -> Converted {
        let mut piece = Converted {
            time_s: self.time_s[a..b].to_vec(),
            displacement_m: self.displacement_m[a..b].to_vec(),
            force_n: self.force_n[a..b].to_vec(),
            velocity_m_s: self.velocity_m_s.as_ref().map(|v| v[a..b].to_vec()),
            alpha: self.alpha.as_ref().map(|v| v[a..b].to_vec()),
            alpha_field: self.alpha_field.clone(),
            lines: self.lines[a..b].to_vec(),
            origin: self.origin,
        };
        if columns.displacement.center {
            center(&mut piece.displacement_m);
        }
        if columns.force.center {
            center(&mut piece.force_n);
        }
        if let (Some(v), Some(true)) = (
            piece.velocity_m_s.as_mut(),
            columns.velocity.as_ref().map(|c| c.center),
        ) {
            center(v);
        }
        piece
    }

    /// The run's label: the given level, else the mean of its levels (a level column), else 0.
    fn label(&self, alpha: Option<f64>) -> f64 {
        alpha.unwrap_or_else(|| {
            self.alpha
                .as_ref()
                .map_or(0.0, |a| a.iter().sum::<f64>() / a.len().max(1) as f64)
        })
    }

    /// The run of this piece: resampled at `resample_hz` when given (linear interpolation),
    /// else its stamps as read, checked against `rate_hz` with the loader's rule (errors name
    /// the lines of the raw file at `path`).
    fn run(
        &self,
        entry: RunEntry,
        resample_hz: Option<f64>,
        rate_hz: f64,
        path: &Path,
    ) -> Result<Run, ImportError> {
        if let Some(r) = resample_hz {
            let t0 = self.time_s[0];
            let span = self.time_s[self.time_s.len() - 1] - t0;
            let samples = (span * r + 1e-9).floor() + 1.0;
            if samples.is_nan() || samples > MAX_RESAMPLED_RUN_SAMPLES as f64 {
                return Err(ImportError::TooManySamples {
                    path: path.to_path_buf(),
                    span_s: span,
                    rate_hz: r,
                    samples,
                });
            }
            let m = samples as usize;
            let tq: Vec<f64> = (0..m).map(|i| t0 + i as f64 / r).collect();
            return Ok(Run {
                entry,
                displacement_m: interpolate(&self.time_s, &self.displacement_m, &tq),
                force_n: interpolate(&self.time_s, &self.force_n, &tq),
                velocity_m_s: self
                    .velocity_m_s
                    .as_ref()
                    .map(|v| interpolate(&self.time_s, v, &tq)),
                alpha: self
                    .alpha
                    .as_ref()
                    .map(|a| interpolate(&self.time_s, a, &tq)),
                time_s: tq,
            });
        }
        dataset::check_time_grid(&self.time_s, rate_hz, path, |i| {
            self.lines.get(i).copied().unwrap_or(0)
        })?;
        Ok(Run {
            entry,
            time_s: self.time_s.clone(),
            displacement_m: self.displacement_m.clone(),
            force_n: self.force_n.clone(),
            velocity_m_s: self.velocity_m_s.clone(),
            alpha: self.alpha.clone(),
        })
    }
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
