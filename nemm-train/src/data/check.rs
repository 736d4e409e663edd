//! Plausibility checks of loaded runs for `nemm data check` (see `docs/data-format.md`,
//! "What `nemm data check` reports").
//!
//! `check_run` looks at the raw columns of one run and reports, each with run, time and
//! line:
//!
//! * **implausible magnitudes**: `|displacement_m|` above `MAX_ABS_DISPLACEMENT_M`,
//!   `|force_n|` above `MAX_ABS_FORCE_N`, `|velocity_m_s|` above `MAX_ABS_VELOCITY_M_S`
//!   (usually a unit error or a corrupt sample);
//! * **spikes**: one- or two-sample outliers from the running median of five samples, more
//!   than `SPIKE_SIGMAS` robust noise deviations and `SPIKE_MIN_FRACTION` of the
//!   column's robust range away;
//! * **dropouts**: at least `REPEAT_MIN_ROWS` consecutive rows with every data column
//!   repeated exactly (a held or zero-filled logger), one column frozen at one value for
//!   at least `FLAT_MIN_S` while it moves elsewhere in the run, or a column at one value
//!   over the whole run (a dead channel);
//! * **clipping**: at least `CLIP_MIN_SAMPLES` consecutive samples at the column's largest
//!   or smallest value, entered and left by a step of more than `CLIP_STEP_QUANTA` times
//!   the column's smallest non-zero step (a smooth, quantised turning point enters its
//!   plateau by one quantum);
//! * **offsets** (information, not errors: gas force and untared load cells are real): a
//!   displacement whose centre lies more than `OFFSET_FRACTION` of the half-stroke (and
//!   0.5 mm) from 0, and a mean force at zero velocity more than `OFFSET_FRACTION` of the
//!   force half-range (and 1 N) from 0;
//! * **time stamps** (information): rounded or jittered stamps that the loader accepted,
//!   with their largest deviation from the fitted grid.
//!
//! `damper_findings` checks what a damper's data must show:
//!
//! * **dissipation**: a force that assists the motion (negative force-velocity correlation,
//!   `preprocess::Dissipation`): an inverted force or displacement sign. Training commands
//!   refuse such a run unless `--accept-implausible` is given;
//! * **velocity**: a differentiated velocity whose noise (the displacement's noise through
//!   the run's cut-off, `preprocess::Cutoff`) exceeds `MAX_VELOCITY_NOISE` of its RMS;
//!   on a periodic run, a peak velocity more than `MAX_VELOCITY_MISMATCH` off `2 pi f A`
//!   from the run's own amplitude and frequency: displacement noise let through by the
//!   cut-off (or a velocity column in other units);
//! * **static force**: the force offsets above say what the static force of eq. 17 models; the
//!   training commands switch it on when the runs' median offset is at least
//!   `STATIC_FORCE_FRACTION` of the force half-range ([`preprocess::static_force_from_data`]).
//!
//! Lines are those of a run file with one header line and one row per line
//! ([`dataset::sample_line`]), as [`dataset::write()`] and `nemm data import` write them.
use crate::data::preprocess::{self, percentile};
pub(crate) use crate::data::preprocess::{STATIC_FORCE_FRACTION, ZERO_VELOCITY_FRACTION};
use nemm_dataset::{self as dataset, Run, COL_DISPLACEMENT, COL_FORCE, COL_VELOCITY};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Largest plausible `|displacement_m|` \[m\] (no road-vehicle damper strokes a metre).
pub(crate) const MAX_ABS_DISPLACEMENT_M: f64 = 1.0;
/// Largest plausible `|force_n|` \[N\] (1 MN).
pub(crate) const MAX_ABS_FORCE_N: f64 = 1e6;
/// Largest plausible `|velocity_m_s|` \[m/s\] (dyno actuators reach a few m/s).
pub(crate) const MAX_ABS_VELOCITY_M_S: f64 = 20.0;
/// A spike is more than this many robust standard deviations (1.4826 median absolute
/// deviation of the residuals from the running median of five) from the running median.
pub(crate) const SPIKE_SIGMAS: f64 = 10.0;
/// ... and more than this fraction of the column's robust range (0.5th to 99.5th percentile).
pub(crate) const SPIKE_MIN_FRACTION: f64 = 0.05;
/// Fewest consecutive identical rows reported as a dropout.
pub(crate) const REPEAT_MIN_ROWS: usize = 10;
/// Shortest time \[s\] a single column must stay at one value to be reported as flat.
pub(crate) const FLAT_MIN_S: f64 = 0.25;
/// Fewest consecutive samples at the column's extreme value reported as clipping.
pub(crate) const CLIP_MIN_SAMPLES: usize = 3;
/// A clipped plateau is entered and left by a step larger than this many quanta (the
/// column's smallest non-zero step).
pub(crate) const CLIP_STEP_QUANTA: f64 = 3.0;
/// Offsets above this fraction of the half-range are reported.
pub(crate) const OFFSET_FRACTION: f64 = 0.1;
/// A periodic run's peak velocity may differ from `2 pi f A` by this fraction.
pub(crate) const MAX_VELOCITY_MISMATCH: f64 = 0.2;
/// A differentiated velocity whose noise (from the displacement's, through the run's
/// cut-off: [`preprocess::Cutoff`]) exceeds this fraction of its RMS is dominated by noise.
pub(crate) const MAX_VELOCITY_NOISE: f64 = 0.1;

/// What a finding is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FindingKind {
    /// A value beyond the plausible magnitude of its column.
    Magnitude,
    /// One- or two-sample outliers.
    Spike,
    /// Repeated rows or a frozen column.
    Dropout,
    /// Runs of samples at the column's extreme value.
    Clipping,
    /// Displacement not centred or force offset at zero velocity (information).
    Offset,
    /// Rounded or jittered time stamps, accepted (information).
    TimeStamps,
    /// A force that assists the motion: an inverted sign.
    Dissipation,
    /// A periodic run's velocity inconsistent with its amplitude and frequency.
    Velocity,
    /// A differentiated velocity dominated by the displacement's noise.
    VelocityNoise,
    /// A run the preprocessing cannot derive signals from (the reason in the message): not
    /// checked further.
    Skipped,
}

impl FindingKind {
    /// `true` for findings that are information rather than a problem.
    pub fn is_info(self) -> bool {
        matches!(self, FindingKind::Offset | FindingKind::TimeStamps)
    }

    /// Short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            FindingKind::Magnitude => "implausible magnitude",
            FindingKind::Spike => "spike",
            FindingKind::Dropout => "dropout",
            FindingKind::Clipping => "clipping",
            FindingKind::Offset => "offset",
            FindingKind::TimeStamps => "time stamps",
            FindingKind::Dissipation => "force assists the motion",
            FindingKind::Velocity => "velocity inconsistent with the stroke",
            FindingKind::VelocityNoise => "velocity dominated by noise",
            FindingKind::Skipped => "run skipped",
        }
    }
}

/// One finding of `check_run`: where it starts and how often it occurs in the run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Finding {
    /// Run index in the dataset.
    pub run: usize,
    /// Run file relative to the manifest.
    pub file: PathBuf,
    /// What kind of finding.
    pub kind: FindingKind,
    /// The column concerned (`time_s` for time stamps).
    pub column: String,
    /// First sample concerned (index in the run).
    pub sample: usize,
    /// Its time stamp \[s\].
    pub time_s: f64,
    /// Its line in the run file.
    pub line: usize,
    /// Occurrences in the run (events, e.g. spikes or plateaus; samples for magnitudes).
    pub count: usize,
    /// What was found, with the values.
    pub message: String,
}

impl std::fmt::Display for Finding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "run {} ({}:{}, t = {} s): ",
            self.run,
            self.file.display(),
            self.line,
            self.time_s
        )?;
        // The time-stamp message names its kind itself.
        if self.kind != FindingKind::TimeStamps {
            write!(f, "{}: ", self.kind.name())?;
        }
        f.write_str(&self.message)
    }
}

/// 0.5th and 99.5th percentile of a column.
fn robust_bounds(x: &[f64]) -> (f64, f64) {
    (percentile(x, 0.005), percentile(x, 0.995))
}

/// Runs the checks of the module docs on one run.
///
/// `force_offset` is the run's force at zero velocity as its summary holds it
/// ([`preprocess::RunSummary::force_offset`], from the velocity the preprocessing uses).
pub(crate) fn check_run(
    run: &Run,
    index: usize,
    sample_rate_hz: f64,
    force_offset: Option<&preprocess::ForceOffset>,
) -> Vec<Finding> {
    let finding = |kind: FindingKind, column: &str, sample: usize, count: usize, message| Finding {
        run: index,
        file: run.entry.file.clone(),
        kind,
        column: column.to_string(),
        sample,
        time_s: run.time_s.get(sample).copied().unwrap_or_default(),
        line: dataset::sample_line(sample),
        count,
        message,
    };
    let columns = data_columns(run);
    let mut out: Vec<Finding> = columns
        .iter()
        .flat_map(|c| column_findings(c, sample_rate_hz, &finding))
        .collect();
    let data: Vec<&[f64]> = columns.iter().map(|c| c.values).collect();
    if let Some((first, len, count)) = repeated_rows(&data) {
        out.push(finding(
            FindingKind::Dropout,
            "(all)",
            first,
            count,
            format!(
                "{len} identical consecutive rows ({count} such stretch(es)): held or \
                 zero-filled logger output, or a pause in the excitation?"
            ),
        ));
    }
    out.extend(offsets(run, force_offset, &finding));
    let grid = dataset::fit_time_grid(&run.time_s, 1.0 / sample_rate_hz);
    if !grid.is_exact() {
        out.push(finding(
            FindingKind::TimeStamps,
            dataset::COL_TIME,
            grid.max_deviation_sample,
            1,
            format!(
                "time stamps rounded/jittered: max deviation {:.1} us from the fitted {:.1} Hz \
                 grid, accepted (at most a quarter step, {:.1} us)",
                grid.max_deviation_s * 1e6,
                grid.rate_hz(),
                dataset::MAX_GRID_DEVIATION * grid.step_s * 1e6
            ),
        ));
    }
    out
}

/// A data column of a run with its plausible magnitude.
struct DataColumn<'a> {
    name: &'static str,
    values: &'a [f64],
    /// Largest plausible magnitude.
    limit: f64,
    unit: &'static str,
}

/// The data columns of a run: displacement, force and, when present, velocity.
fn data_columns(run: &Run) -> Vec<DataColumn<'_>> {
    let mut columns = vec![
        DataColumn {
            name: COL_DISPLACEMENT,
            values: &run.displacement_m,
            limit: MAX_ABS_DISPLACEMENT_M,
            unit: "m",
        },
        DataColumn {
            name: COL_FORCE,
            values: &run.force_n,
            limit: MAX_ABS_FORCE_N,
            unit: "N",
        },
    ];
    if let Some(v) = &run.velocity_m_s {
        columns.push(DataColumn {
            name: COL_VELOCITY,
            values: v,
            limit: MAX_ABS_VELOCITY_M_S,
            unit: "m/s",
        });
    }
    columns
}

/// The findings of one column: implausible magnitudes, spikes, a frozen stretch, clipping at
/// its largest and at its smallest value.
fn column_findings(
    c: &DataColumn<'_>,
    sample_rate_hz: f64,
    finding: &impl Fn(FindingKind, &str, usize, usize, String) -> Finding,
) -> Vec<Finding> {
    let (name, x, limit, unit) = (c.name, c.values, c.limit, c.unit);
    let mut out = Vec::new();
    if let Some(first) = x.iter().position(|v| v.abs() > limit) {
        let count = x.iter().filter(|v| v.abs() > limit).count();
        let largest = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        out.push(finding(
            FindingKind::Magnitude,
            name,
            first,
            count,
            format!(
                "{name} = {} {unit} exceeds +-{limit} {unit} in {count} sample(s) \
                 (largest {largest:e} {unit}); wrong unit or a corrupt value?",
                x[first]
            ),
        ));
    }
    if let Some((first, count, value, residual)) = spikes(x) {
        out.push(finding(
            FindingKind::Spike,
            name,
            first,
            count,
            format!(
                "{count} spike(s) in {name}; the first is {value} {unit}, {residual:+e} {unit} \
                 from the running median"
            ),
        ));
    }
    if let Some(value) = dead(x) {
        out.push(finding(
            FindingKind::Dropout,
            name,
            0,
            x.len(),
            format!(
                "{name} is {value} {unit} in every one of the run's {} samples: a dead \
                 channel (disconnected sensor, wrong column or a logger placeholder)",
                x.len()
            ),
        ));
    } else if let Some((first, len, count, value)) = flat(x, sample_rate_hz) {
        out.push(finding(
            FindingKind::Dropout,
            name,
            first,
            count,
            format!(
                "{name} frozen at {value} {unit} for {len} samples ({:.3} s; {count} such \
                 stretch(es)): stuck sensor or logger dropout?",
                len as f64 / sample_rate_hz
            ),
        ));
    }
    for (at_max, extreme) in [(true, "largest"), (false, "smallest")] {
        if let Some((first, len, count, value)) = clipped(x, at_max) {
            out.push(finding(
                FindingKind::Clipping,
                name,
                first,
                count,
                format!(
                    "{name} sits at its {extreme} value {value} {unit} for {len} samples \
                     ({count} plateau(s)), entered and left by steep steps: clipped \
                     sensor or amplifier range?"
                ),
            ));
        }
    }
    out
}

/// The value of a column that holds one value over the whole run (at least
/// [`REPEAT_MIN_ROWS`] samples): a dead channel.
fn dead(x: &[f64]) -> Option<f64> {
    let &first = x.first()?;
    (x.len() >= REPEAT_MIN_ROWS && x.iter().all(|v| v.to_bits() == first.to_bits()))
        .then_some(first)
}

/// Spikes of one column: `(first sample, events, value, residual)`; the first sample is
/// the largest residual of the first event.
fn spikes(x: &[f64]) -> Option<(usize, usize, f64, f64)> {
    let n = x.len();
    if n < 5 {
        return None;
    }
    let residual: Vec<f64> = (0..n)
        .map(|i| {
            let lo = i.saturating_sub(2).min(n - 5);
            let mut w = [0.0; 5];
            w.copy_from_slice(&x[lo..lo + 5]);
            w.sort_by(f64::total_cmp);
            x[i] - w[2]
        })
        .collect();
    let abs: Vec<f64> = residual.iter().map(|r| r.abs()).collect();
    let sigma = 1.4826 * percentile(&abs, 0.5);
    let (lo, hi) = robust_bounds(x);
    let threshold = (SPIKE_SIGMAS * sigma).max(SPIKE_MIN_FRACTION * (hi - lo));
    if threshold <= 0.0 {
        // A constant column (all but at most 0.5 % of its samples): anything else sticks out.
        let mid = percentile(x, 0.5);
        let first = x.iter().position(|v| *v != mid)?;
        let count = events(x.iter().map(|v| *v != mid));
        return Some((first, count, x[first], x[first] - mid));
    }
    let flags = abs.iter().map(|a| *a > threshold);
    let count = events(flags);
    if count == 0 {
        return None;
    }
    let start = abs.iter().position(|a| *a > threshold)?;
    let end = abs[start..]
        .iter()
        .position(|a| *a <= threshold)
        .map_or(n, |k| start + k);
    let first = (start..end).max_by(|&a, &b| abs[a].total_cmp(&abs[b]))?;
    Some((first, count, x[first], residual[first]))
}

/// Number of stretches of consecutive `true`.
fn events(flags: impl Iterator<Item = bool>) -> usize {
    let mut count = 0;
    let mut inside = false;
    for f in flags {
        if f && !inside {
            count += 1;
        }
        inside = f;
    }
    count
}

/// Stretches `(start, length)` of consecutive equal values of at least `min_len` samples,
/// where `equal(i)` says whether sample `i` equals sample `i - 1`.
fn stretches(n: usize, min_len: usize, equal: impl Fn(usize) -> bool) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..=n {
        if i == n || !equal(i) {
            if i - start >= min_len {
                out.push((start, i - start));
            }
            start = i;
        }
    }
    out
}

/// A column frozen at one value for [`FLAT_MIN_S`] while it varies elsewhere:
/// `(first start, longest length, stretches, value)`.
fn flat(x: &[f64], sample_rate_hz: f64) -> Option<(usize, usize, usize, f64)> {
    let min_len = ((FLAT_MIN_S * sample_rate_hz).ceil() as usize).max(REPEAT_MIN_ROWS);
    let found = stretches(x.len(), min_len, |i| x[i] == x[i - 1]);
    let &(start, _) = found.first()?;
    let longest = found.iter().map(|s| s.1).max()?;
    // A column that never moves is a constant, not a dropout (spikes reports the outliers).
    if found.len() == 1 && longest == x.len() {
        return None;
    }
    Some((start, longest, found.len(), x[start]))
}

/// Plateaus at the extreme value (`at_max`: the largest) of at least [`CLIP_MIN_SAMPLES`]
/// entered and left by steep steps: `(first start, longest length, plateaus, value)`.
fn clipped(x: &[f64], at_max: bool) -> Option<(usize, usize, usize, f64)> {
    let n = x.len();
    let extreme = if at_max {
        x.iter().copied().fold(f64::NEG_INFINITY, f64::max)
    } else {
        x.iter().copied().fold(f64::INFINITY, f64::min)
    };
    let quantum = x
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    if !quantum.is_finite() {
        return None;
    }
    let steep = |a: f64, b: f64| (a - b).abs() > CLIP_STEP_QUANTA * quantum;
    let found: Vec<(usize, usize)> =
        stretches(n, CLIP_MIN_SAMPLES, |i| x[i] == x[i - 1] && x[i] == extreme)
            .into_iter()
            .filter(|&(start, len)| {
                x[start] == extreme
                    && len < n
                    && (start == 0 || steep(x[start], x[start - 1]))
                    && (start + len == n || steep(x[start + len - 1], x[start + len]))
            })
            .collect();
    let &(start, _) = found.first()?;
    let longest = found.iter().map(|s| s.1).max()?;
    Some((start, longest, found.len(), extreme))
}

/// Stretches of at least [`REPEAT_MIN_ROWS`] identical rows: `(first start, longest, count)`.
fn repeated_rows(columns: &[&[f64]]) -> Option<(usize, usize, usize)> {
    let n = columns.first()?.len();
    let found = stretches(n, REPEAT_MIN_ROWS, |i| {
        columns.iter().all(|c| c[i] == c[i - 1])
    });
    // A run that is one repeated row throughout is reported by the columns' own checks.
    if found.len() == 1 && found.first().is_some_and(|s| s.1 == n) {
        return None;
    }
    let &(start, _) = found.first()?;
    Some((start, found.iter().map(|s| s.1).max()?, found.len()))
}

/// The displacement centre and the force at zero velocity (information).
fn offsets(
    run: &Run,
    force_offset: Option<&preprocess::ForceOffset>,
    finding: &impl Fn(FindingKind, &str, usize, usize, String) -> Finding,
) -> Vec<Finding> {
    let mut out = Vec::new();
    let (lo, hi) = robust_bounds(&run.displacement_m);
    let (centre, half) = (0.5 * (lo + hi), 0.5 * (hi - lo));
    if centre.abs() > OFFSET_FRACTION * half && centre.abs() > 5e-4 {
        out.push(finding(
            FindingKind::Offset,
            COL_DISPLACEMENT,
            0,
            1,
            format!(
                "displacement centred at {:+.2} mm, stroke +-{:.2} mm (0.5th..99.5th \
                 percentile): the position is used as measured; shift it in the import if the \
                 zero is arbitrary",
                centre * 1e3,
                half * 1e3
            ),
        ));
    }
    if let Some(o) = force_offset {
        if o.fraction() > OFFSET_FRACTION && o.mean_n.abs() > 1.0 {
            out.push(finding(
                FindingKind::Offset,
                COL_FORCE,
                o.first,
                o.samples,
                format!(
                    "mean force at zero velocity (|v| <= {:.0} % of its peak, {} samples) is \
                     {:+.1} N, {:.0} % of the force half-range {:.1} N: a gas force or an \
                     untared load cell; the static force of eq. 17 models it (switched on \
                     when the runs' median is {:.0} % or more)",
                    ZERO_VELOCITY_FRACTION * 100.0,
                    o.samples,
                    o.mean_n,
                    100.0 * o.fraction(),
                    o.half_range_n,
                    100.0 * STATIC_FORCE_FRACTION
                ),
            ));
        }
    }
    out
}

/// What a damper's data must show, from a run's summary ([`preprocess::summarize_run`]):
/// a force that dissipates energy, a differentiated velocity not dominated by the
/// displacement's noise and, on a periodic run, a peak velocity consistent with the run's
/// amplitude and frequency (module docs).
pub(crate) fn damper_findings(run: &Run, summary: &preprocess::RunSummary) -> Vec<Finding> {
    let cutoff = &summary.cutoff;
    let cutoff_hz = cutoff.hz;
    let finding = |kind: FindingKind, column: &str, message| Finding {
        run: summary.index,
        file: run.entry.file.clone(),
        kind,
        column: column.to_string(),
        sample: 0,
        time_s: run.time_s.first().copied().unwrap_or_default(),
        line: dataset::sample_line(0),
        count: 1,
        message,
    };
    let mut out = Vec::new();
    if summary.dissipation.force_assists_motion() {
        out.push(finding(
            FindingKind::Dissipation,
            COL_FORCE,
            summary.dissipation.explain(),
        ));
    }
    if let Some(q) = cutoff
        .velocity_noise_fraction
        .filter(|q| *q > MAX_VELOCITY_NOISE)
    {
        let remedy = match cutoff.rule {
            preprocess::CutoffRule::Given => "lower --cutoff-hz, or leave it out to have it \
                                              chosen per run"
                .to_string(),
            _ => format!(
                "the cut-off stays at {} x the excitation frequency; record the velocity \
                 (a velocity_m_s column) or a finer displacement",
                preprocess::AUTO_CUTOFF_EXCITATION_MULTIPLE
            ),
        };
        out.push(finding(
            FindingKind::VelocityNoise,
            COL_DISPLACEMENT,
            format!(
                "the displacement's noise ({:.1} um, from its \
                 third differences) gives {:.0} % of the run's RMS velocity through the \
                 {cutoff_hz} Hz cut-off; {remedy}",
                cutoff.displacement_noise_m * 1e6,
                100.0 * q
            ),
        ));
    }
    let ex = &summary.excitation;
    if let (Some(f), false) = (ex.frequency_hz, summary.measured_velocity) {
        let expected = 2.0 * std::f64::consts::PI * f * ex.amplitude_m;
        let ratio = ex.peak_velocity_m_s / expected;
        if ex.periodic && expected > 0.0 && (ratio - 1.0).abs() > MAX_VELOCITY_MISMATCH {
            out.push(finding(
                FindingKind::Velocity,
                COL_DISPLACEMENT,
                format!(
                    "peak velocity {:.4} m/s is {:+.0} % off 2 pi f A = {expected:.4} m/s from \
                     the run's own amplitude ({:.2} mm) and frequency ({f:.3} Hz): the \
                     displacement's noise passes the {cutoff_hz} Hz cut-off ({}) into the \
                     differentiated velocity; {}",
                    ex.peak_velocity_m_s,
                    100.0 * (ratio - 1.0),
                    ex.amplitude_m * 1e3,
                    cutoff.rule.describe(),
                    if cutoff.rule == preprocess::CutoffRule::Given {
                        "lower --cutoff-hz, or leave it out to have it chosen per run"
                    } else {
                        "record the velocity (a velocity_m_s column) or a finer displacement"
                    }
                ),
            ));
        }
    }
    out
}

/// Summaries ([`preprocess::summarize_run`]) and findings (`check_run`, `damper_findings`)
/// of every run of a dataset (in parallel), in dataset order. A run the preprocessing cannot
/// take is a [`FindingKind::Skipped`] finding and has no summary; the dataset-wide error (a
/// cut-off the rate refuses) is returned.
pub fn check_dataset(
    dataset: &nemm_dataset::Dataset,
    cfg: &preprocess::SignalConfig,
) -> Result<(Vec<preprocess::RunSummary>, Vec<Finding>), preprocess::PreprocessError> {
    use rayon::prelude::*;
    let fs = dataset.sample_rate_hz;
    let path = cfg.at_rate(fs)?;
    let per_run: Vec<(Option<preprocess::RunSummary>, Vec<Finding>)> = dataset
        .runs
        .par_iter()
        .enumerate()
        .map(|(i, r)| match preprocess::summarize_run(r, i, &path) {
            Ok((summary, _)) => {
                let mut findings = check_run(r, i, fs, summary.force_offset.as_ref());
                findings.extend(damper_findings(r, &summary));
                (Some(summary), findings)
            }
            Err(e) => (
                None,
                vec![Finding {
                    run: i,
                    file: r.entry.file.clone(),
                    kind: FindingKind::Skipped,
                    column: String::new(),
                    sample: 0,
                    time_s: r.time_s.first().copied().unwrap_or_default(),
                    line: dataset::sample_line(0),
                    count: 1,
                    message: format!("{e}; not checked"),
                }],
            ),
        })
        .collect();
    let mut summaries = Vec::with_capacity(per_run.len());
    let mut findings = Vec::new();
    for (s, f) in per_run {
        summaries.extend(s);
        findings.extend(f);
    }
    Ok((summaries, findings))
}
