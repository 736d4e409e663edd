//! The observer diagnosis (`nemm diagnose`, `diagnose.json`): per recorded run, the online
//! alpha observer ([`nemm_core::AlphaObserver`]) driven as on target, against the offline
//! best fit of the same model ([`crate::train::identify`]).
//!
//! Both see what the firmware sees: the velocity is the causal estimate of the recorded
//! displacement ([`causal_velocity`]: backward difference through the estimator's 500 Hz
//! first-order low-pass), the position the recorded displacement, the force the recorded
//! force, unfiltered. The observer runs with its defaults ([`ObserverConfig::new`]), one step
//! per sample, so the run must be sampled at the model's rate.
//!
//! Per run ([`RunDiagnosis`]):
//!
//! - `alpha_hat`, `band`: the observer's estimate and band (half-width) after the last sample;
//! - `excited`: [`ObserverFlags::excited`] of that last estimate;
//! - `settle_s`: [`settle_time`], with the tolerance `max(band, 0.02)`;
//! - `label`: the manifest's level of the run, or the mean of its per-sample level column;
//! - `alpha_offline`: the level whose whole-run simulation from rest fits the measured force
//!   best ([`offline_fit`]), `null` where the model does not tell the levels apart on the run.
//!
//! Numbers are rounded: levels and bands to 1e-4, times to 1e-4 s.

use crate::data::preprocess::causal_velocity;
use crate::report::plot::{palette, Figure, LegendPosition, LinePanel, Series};
use crate::train::identify::{identify, AlphaGrid, Run, Search, DEFAULT_STEP};
use anyhow::{bail, Context, Result};
use nemm_core::{AlphaObserver, Model, ObserverConfig, ObserverFlags, Sample};
use nemm_dataset as dataset;
use plotters::style::RGBColor;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// Smallest settling tolerance in alpha (the band is used where it is wider).
pub(crate) const SETTLE_TOLERANCE: f64 = 0.02;

/// An excited run's online estimate within this of the offline fit counts as agreeing.
pub const AGREEMENT: f64 = 0.02;

/// Step of the offline fit's refinement around the best level of the coarse
/// ([`DEFAULT_STEP`]) grid.
pub(crate) const FINE_STEP: f64 = 0.001;

/// Points of the alpha(t) figures' curves at most (the trace is decimated to them).
pub(crate) const FIGURE_POINTS: usize = 2000;

/// `diagnose.json`: one entry per run, in manifest order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct DiagnoseReport {
    /// The runs.
    pub(crate) runs: Vec<RunDiagnosis>,
}

/// The diagnosis of one run (see the module documentation for the definitions).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunDiagnosis {
    /// Run file, relative to the manifest.
    pub file: String,
    /// The run's labelled level (the mean of its per-sample levels where it has them).
    pub label: f64,
    /// The observer's estimate after the last sample.
    pub alpha_hat: f64,
    /// Its band (half-width, in alpha).
    pub band: f64,
    /// The offline best fit; `None` when the model's whole-run error does not depend on
    /// the level (`crate::train::identify::FLAT_TOLERANCE`).
    pub alpha_offline: Option<f64>,
    /// The observer's excited flag after the last sample.
    pub excited: bool,
    /// Time from the run's first sample after which the estimate stays within
    /// `max(band, 0.02)` of `alpha_hat` \[s\] (`settle_time`); `None` if it never does.
    pub settle_s: Option<f64>,
}

impl RunDiagnosis {
    /// `|alpha_hat - alpha_offline|`, if there is an offline fit.
    pub(crate) fn offline_error(&self) -> Option<f64> {
        self.alpha_offline.map(|a| (self.alpha_hat - a).abs())
    }
}

/// The observer's estimates over a run, one per sample.
#[derive(Debug, Clone, PartialEq)]
pub struct Trace {
    /// Sample interval \[s\].
    pub dt_s: f64,
    /// Estimate per sample.
    pub alpha: Vec<f32>,
    /// Band per sample.
    pub band: Vec<f32>,
    /// [`ObserverFlags::excited`] per sample.
    pub excited: Vec<bool>,
    /// [`ObserverFlags::settled`] per sample.
    pub settled: Vec<bool>,
    /// Index of the first sample whose estimate came from a solved window (`None`: none
    /// did, the run ended before the observer's first block closed).
    pub(crate) first_update: Option<usize>,
    /// Flags of the last estimate.
    pub(crate) last_flags: ObserverFlags,
}

/// Rounds to 1e-4.
fn round4(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// The time \[s\] (samples `dt_s` apart, the first at 0) of the first sample from which every
/// estimate of `alpha` to the end stays within `tolerance` of the last one. `None` when
/// there is no estimate (`first_update` is `None`) or when only the last sample is within
/// (the estimate was still moving at the end).
pub(crate) fn settle_time(
    alpha: &[f32],
    tolerance: f64,
    first_update: Option<usize>,
    dt_s: f64,
) -> Option<f64> {
    first_update?;
    let last = f64::from(*alpha.last()?);
    let k = match alpha
        .iter()
        .rposition(|&a| (f64::from(a) - last).abs() > tolerance)
    {
        None => 0,
        Some(j) if j + 2 >= alpha.len() => return None,
        Some(j) => j + 1,
    };
    Some(k as f64 * dt_s)
}

/// Runs a fresh observer of `model` (defaults) over a run's velocity, position and force.
pub(crate) fn observe(
    model: &Model,
    velocity: &[f32],
    position: &[f32],
    force: &[f64],
) -> Result<Trace> {
    let mut obs: Box<AlphaObserver> = Box::new(AlphaObserver::empty());
    obs.load(model, ObserverConfig::new())
        .map_err(|e| anyhow::anyhow!("the observer cannot run this model: {e}"))?;
    let n = velocity.len().min(position.len()).min(force.len());
    let (mut alpha, mut band) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let (mut excited, mut settled) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut first_update = None;
    let mut last_flags = obs.estimate().flags;
    for k in 0..n {
        let sample = Sample::new(velocity[k])
            .with_position(position[k])
            .with_force(force[k] as f32);
        let e = obs.step(sample);
        if first_update.is_none() && obs.solves() > 0 {
            first_update = Some(k);
        }
        alpha.push(e.alpha);
        band.push(e.band);
        excited.push(e.flags.excited());
        settled.push(e.flags.settled());
        last_flags = e.flags;
    }
    Ok(Trace {
        dt_s: f64::from(model.dt_s),
        alpha,
        band,
        excited,
        settled,
        first_update,
        last_flags,
    })
}

/// The offline best fit of `run` (samples `dt_s` apart) by [`identify`]: the level of least
/// whole-run RMSE (after `warmup` samples) on the [`DEFAULT_STEP`] grid over the model's
/// range (searched coarse to fine, [`Search::CoarseToFine`]), then at every level of a
/// [`FINE_STEP`] grid within one grid step of it. `None` when the coarse
/// curve is flat (no best fit).
pub(crate) fn offline_fit(
    model: &Model,
    run: &Run<'_>,
    dt_s: f64,
    warmup: usize,
) -> Result<Option<f64>> {
    let coarse_grid = AlphaGrid::for_model(model, DEFAULT_STEP)?;
    let max = coarse_grid.alphas.last().copied().unwrap_or(0.0);
    let Some(coarse) = identify(model, run, &coarse_grid, dt_s, warmup, Search::CoarseToFine)?.best
    else {
        return Ok(None);
    };
    let steps = (DEFAULT_STEP / FINE_STEP).round() as i64;
    let centre = (coarse / FINE_STEP).round() as i64;
    let fine = AlphaGrid {
        alphas: (centre - steps + 1..centre + steps)
            .map(|i| i as f64 * FINE_STEP)
            .filter(|&a| (-1e-9..=max + 1e-9).contains(&a))
            .map(|a| (a * 1e9).round() / 1e9)
            .collect(),
    };
    let fit = identify(model, run, &fine, dt_s, warmup, Search::Full)?;
    // Near the minimum the curve is nearly flat by nature: take its least point as is.
    let best = fit
        .curve_n
        .iter()
        .zip(&fit.levels)
        .filter(|(e, _)| e.is_finite())
        .min_by(|a, b| a.0.total_cmp(b.0))
        .map(|(_, &a)| a);
    Ok(best.or(Some(coarse)))
}

/// The run's file, path relative to the manifest with `/` as the separator.
pub(crate) fn run_file(run: &dataset::Run) -> String {
    run.entry.file.to_string_lossy().replace('\\', "/")
}

/// The observer's velocity and position of a displacement record sampled at `fs` \[Hz\]:
/// the causal velocity ([`causal_velocity`]) and the displacement, as `f32`.
pub(crate) fn observer_inputs(displacement_m: &[f64], fs: f64) -> (Vec<f32>, Vec<f32>) {
    let velocity = causal_velocity(displacement_m, fs)
        .iter()
        .map(|&v| v as f32)
        .collect();
    let position = displacement_m.iter().map(|&x| x as f32).collect();
    (velocity, position)
}

/// Diagnoses run `index` of `ds` with `model`: the observer's trace and the summary.
pub fn diagnose_run(
    model: &Model,
    ds: &dataset::Dataset,
    index: usize,
) -> Result<(RunDiagnosis, Trace)> {
    let run = &ds.runs[index];
    let fs = ds.sample_rate_hz;
    let file = run_file(run);
    let (velocity, position) = observer_inputs(&run.displacement_m, fs);
    let label_alphas: Option<Vec<f32>> = run
        .alpha
        .as_ref()
        .map(|a| a.iter().map(|&x| x as f32).collect());
    let label = match &run.alpha {
        Some(a) if !a.is_empty() => a.iter().sum::<f64>() / a.len() as f64,
        _ => run.entry.oil_loss,
    };
    let trace = observe(model, &velocity, &position, &run.force_n)?;
    let warmup = (f64::from(ObserverConfig::new().warmup_s) * fs).round() as usize;
    let fit_input = Run {
        velocity_m_s: &velocity,
        position_m: Some(&position),
        force_n: &run.force_n,
        label,
        label_alphas: label_alphas.as_deref(),
    };
    let alpha_offline = offline_fit(model, &fit_input, 1.0 / fs, warmup)
        .with_context(|| format!("{file}: offline fit"))?;
    let (Some(&alpha_end), Some(&band_end)) = (trace.alpha.last(), trace.band.last()) else {
        bail!("{file}: the run has no samples");
    };
    let excited = trace.last_flags.excited();
    let tolerance = f64::from(band_end).max(SETTLE_TOLERANCE);
    let settle_s = settle_time(&trace.alpha, tolerance, trace.first_update, trace.dt_s);
    Ok((
        RunDiagnosis {
            file,
            label,
            alpha_hat: round4(f64::from(alpha_end)),
            band: round4(f64::from(band_end)),
            alpha_offline: alpha_offline.map(round4),
            excited,
            settle_s: settle_s.map(round4),
        },
        trace,
    ))
}

/// `x` with 3 decimals, or `-`.
fn opt3(x: Option<f64>) -> String {
    x.map_or("-".into(), |v| format!("{v:.3}"))
}

/// The table printed by `nemm diagnose`: per run the label, the online estimate and band,
/// the offline fit, their difference, the excitation and the settling time.
pub(crate) fn table_markdown(runs: &[RunDiagnosis]) -> String {
    let mut s = String::from(
        "| run | label | online ± band | offline | \\|online - offline\\| | excited | settle [s] |\n\
         |---|---:|---:|---:|---:|---|---:|\n",
    );
    for r in runs {
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.3} ± {:.3} | {} | {} | {} | {} |",
            r.file,
            r.label,
            r.alpha_hat,
            r.band,
            opt3(r.alpha_offline),
            opt3(r.offline_error()),
            if r.excited { "yes" } else { "no" },
            r.settle_s.map_or("never".into(), |t| format!("{t:.2}")),
        );
    }
    s
}

/// The summary line: how many of the excited runs end within [`AGREEMENT`] of the offline
/// fit.
pub(crate) fn summary_line(runs: &[RunDiagnosis]) -> String {
    let excited: Vec<&RunDiagnosis> = runs.iter().filter(|r| r.excited).collect();
    let agree = excited
        .iter()
        .filter(|r| r.offline_error().is_some_and(|e| e <= AGREEMENT + 1e-9))
        .count();
    format!(
        "{agree} of {} excited runs within {AGREEMENT} of the offline fit ({} runs, {} not excited)",
        excited.len(),
        runs.len(),
        runs.len() - excited.len()
    )
}

/// The figure file of run file `file` (its path relative to the manifest, `/` and `\` as
/// `_`, without the extension): `alpha_<path>.png`.
pub(crate) fn figure_file(file: &str) -> String {
    let stem = file.rsplit_once('.').map_or(file, |(s, _)| s);
    format!("alpha_{}.png", stem.replace(['/', '\\'], "_"))
}

/// The observer's estimate over `trace` as figure series (from its first update on, at most
/// [`FIGURE_POINTS`] points): the band shaded, clipped to `clip`, and the estimate as a line
/// named `label`. Empty when the observer never updated.
pub(crate) fn estimate_series(trace: &Trace, label: String, clip: (f64, f64)) -> Vec<Series> {
    let n = trace.alpha.len();
    let every = n.div_ceil(FIGURE_POINTS).max(1);
    let from = trace.first_update.unwrap_or(n);
    let pts: Vec<(f64, f64, f64)> = (from..n)
        .step_by(every)
        .chain((from < n).then_some(n - 1))
        .map(|k| {
            let (a, b) = (f64::from(trace.alpha[k]), f64::from(trace.band[k]));
            (k as f64 * trace.dt_s, a, b)
        })
        .collect();
    if pts.is_empty() {
        return Vec::new();
    }
    let blue = palette::categorical(0);
    let band: Vec<(f64, f64, f64)> = pts
        .iter()
        .map(|&(t, a, b)| {
            (
                t,
                (a - b).clamp(clip.0, clip.1),
                (a + b).clamp(clip.0, clip.1),
            )
        })
        .collect();
    vec![
        Series::band("band", &band, blue),
        Series::line(label, pts.iter().map(|&(t, a, _)| (t, a)).collect(), blue),
    ]
}

/// The alpha(t) figure of one run: the observer's estimate with its band shaded (from its
/// first update on), the label and the offline fit as horizontal lines, and a vertical line
/// at the settling time; the levels axis spans the model's trained range `range`, the label
/// and the fit (the band is cut at 0.05 beyond them), with room above for the legend.
pub(crate) fn alpha_figure(d: &RunDiagnosis, trace: &Trace, range: (f64, f64)) -> Figure {
    let n = trace.alpha.len();
    let end = n as f64 * trace.dt_s;
    let lo = [range.0, d.label, d.alpha_offline.unwrap_or(range.0)]
        .into_iter()
        .fold(f64::INFINITY, f64::min)
        - 0.05;
    let hi = [range.1, d.label, d.alpha_offline.unwrap_or(range.1)]
        .into_iter()
        .fold(f64::NEG_INFINITY, f64::max)
        + 0.05;
    // Headroom above the levels for the legend.
    let top = hi + 0.12;
    let mut panel = LinePanel::new(
        "online estimate with its band; label, offline fit; | settled",
        "time [s]",
        "alpha [-]",
    )
    .with_x_range(0.0, end.max(trace.dt_s))
    .with_y_range(lo, top)
    .with_legend(LegendPosition::UpperRight);
    let label = format!("online: {:.3} ± {:.3}", d.alpha_hat, d.band);
    for s in estimate_series(trace, label, (lo, hi)) {
        panel = panel.with_series(s);
    }
    panel = panel.with_series(Series::dashed(
        format!("label {:.3}", d.label),
        vec![(0.0, d.label), (end, d.label)],
        RGBColor(80, 80, 80),
    ));
    panel.reference_x.extend(d.settle_s);
    if let Some(a) = d.alpha_offline {
        panel = panel.with_series(Series::dashed(
            format!("offline fit {a:.3}"),
            vec![(0.0, a), (end, a)],
            palette::categorical(1),
        ));
    }
    Figure::new(1, 1)
        .with_panel_size(760, 420)
        .with_title(format!("Online alpha estimate: {}", d.file))
        .with_footer(format!(
            "Excited at the end: {}. |online - offline| = {}.\n\
             Settled (within max(band, {SETTLE_TOLERANCE}) of the final estimate to the end) from {}.",
            if d.excited { "yes" } else { "no" },
            opt3(d.offline_error()),
            d.settle_s.map_or("never".into(), |t| format!("{t:.2} s")),
        ))
        .with_panel(panel)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settling_is_the_start_of_the_last_stretch_within_the_tolerance() {
        let a = [0.15f32, 0.3, 0.2, 0.11, 0.12, 0.1, 0.1];
        // From sample 3 on within 0.02 of 0.1.
        assert_eq!(settle_time(&a, 0.02, Some(0), 0.5), Some(1.5));
        // Everything within a wide tolerance: settled from the start.
        assert_eq!(settle_time(&a, 0.25, Some(0), 0.5), Some(0.0));
        // Only the last sample within: never settled; no update: no estimate.
        assert_eq!(settle_time(&[0.1, 0.2, 0.3], 0.02, Some(0), 1.0), None);
        assert_eq!(settle_time(&a, 0.02, None, 0.5), None);
        assert_eq!(settle_time(&[], 0.02, Some(0), 0.5), None);
    }

    #[test]
    fn the_summary_counts_excited_runs_near_the_offline_fit() {
        let run = |alpha_hat: f64, offline: Option<f64>, excited: bool| RunDiagnosis {
            file: "runs/a.csv".into(),
            label: 0.15,
            alpha_hat,
            band: 0.01,
            alpha_offline: offline,
            excited,
            settle_s: Some(0.5),
        };
        let runs = [
            run(0.15, Some(0.16), true),
            run(0.15, Some(0.2), true),
            run(0.15, None, true),
            run(0.3, Some(0.1), false),
        ];
        assert_eq!(
            summary_line(&runs),
            "1 of 3 excited runs within 0.02 of the offline fit (4 runs, 1 not excited)"
        );
        let table = table_markdown(&runs);
        assert_eq!(table.lines().count(), 6, "{table}");
        assert!(
            table.contains("| runs/a.csv | 0.150 | 0.150 ± 0.010 | 0.160 | 0.010 | yes | 0.50 |")
        );
        assert_eq!(
            figure_file("runs/oil15_a050.csv"),
            "alpha_runs_oil15_a050.png"
        );
    }
}
