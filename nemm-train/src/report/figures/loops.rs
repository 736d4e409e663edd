//! The loop figures: Fig. 7 (measured vs model force-velocity loops per oil-loss level and
//! frequency) and one run with every variant. Which runs they show depends on
//! the prepared set only, so the evaluation can simulate exactly those ([`loop_requests`]).

use super::{
    frequency_color, level_name, sym_range, variant_color, Ctx, Drawn, LOOP_AMPLITUDE_M,
    LOOP_FREQUENCIES_HZ, LOOP_PERIODS, LOOP_TRAIN_ALPHAS, MEASURED_GREY,
};
use crate::data::preprocess::{distinct_levels, Prepared, RunRole};
use crate::report::plot::{palette, Figure, LegendPosition, LinePanel, Panel, Series};
use crate::train::pipeline::{TrainedVariant, VariantInfo};
use anyhow::{Context, Result};
use nemm_core::ModelKind;
use std::ops::Range;

/// A run chosen for a loop figure.
#[derive(Debug, Clone, Copy)]
pub(super) struct RunPick {
    index: usize,
    alpha: f64,
    amplitude_m: f64,
    frequency_hz: f64,
}

/// The shown part of a simulated run (forces normalised by the training force scale).
struct LoopData {
    velocity_m_s: Vec<f64>,
    /// Low-passed measured force.
    measured: Vec<f64>,
    /// Raw measured force.
    measured_raw: Vec<f64>,
    /// One per requested model.
    models: Vec<Vec<f64>>,
}

impl LoopData {
    fn rmse(&self, k: usize) -> f64 {
        let m = &self.models[k];
        let n = m.len().min(self.measured_raw.len());
        if n == 0 {
            return f64::NAN;
        }
        let se: f64 = (0..n).map(|i| (m[i] - self.measured_raw[i]).powi(2)).sum();
        (se / n as f64).sqrt()
    }

    fn points(&self, f: &[f64]) -> Vec<(f64, f64)> {
        self.velocity_m_s
            .iter()
            .copied()
            .zip(f.iter().copied())
            .collect()
    }
}

/// The runs the loop figures show, chosen from the prepared set.
pub(super) struct LoopPicks {
    /// Fig. 7 columns: the training levels nearest [`LOOP_TRAIN_ALPHAS`], then the test level.
    pub(super) fig7_cols: Vec<(f64, RunRole)>,
    /// Fig. 7 runs (column, run), one per column and frequency, each run once.
    pub(super) fig7: Vec<(usize, RunPick)>,
    /// The run of the all-variants figure (a test run if there is one) and its role.
    pub(super) all_variants: Option<(RunPick, RunRole)>,
}

impl LoopPicks {
    /// The picks of `prepared`.
    pub(super) fn of(prepared: &Prepared) -> Self {
        let train = levels(prepared, RunRole::TrainValidation);
        let test = levels(prepared, RunRole::Test);
        let mut cols: Vec<(f64, RunRole)> = Vec::new();
        for target in LOOP_TRAIN_ALPHAS {
            if let Some(&a) = train
                .iter()
                .min_by(|a, b| (*a - target).abs().total_cmp(&(*b - target).abs()))
            {
                if !cols.iter().any(|c| (c.0 - a).abs() < 1e-6) {
                    cols.push((a, RunRole::TrainValidation));
                }
            }
        }
        // The report's test level: the first configured one.
        let test_alpha = prepared
            .config
            .split
            .test_alphas
            .first()
            .copied()
            .unwrap_or(f64::NAN);
        if let Some(&a) = test
            .iter()
            .min_by(|a, b| (*a - test_alpha).abs().total_cmp(&(*b - test_alpha).abs()))
        {
            cols.push((a, RunRole::Test));
        }
        let mut fig7: Vec<(usize, RunPick)> = Vec::new();
        for (c, &(a, _)) in cols.iter().enumerate() {
            for f in LOOP_FREQUENCIES_HZ {
                if let Some(pick) = pick_run(prepared, a, LOOP_AMPLITUDE_M, f) {
                    if !fig7.iter().any(|(_, p)| p.index == pick.index) {
                        fig7.push((c, pick));
                    }
                }
            }
        }
        let target_f = LOOP_FREQUENCIES_HZ[LOOP_FREQUENCIES_HZ.len() - 1];
        let all_variants = test
            .iter()
            .find_map(|&a| pick_run(prepared, a, LOOP_AMPLITUDE_M, target_f))
            .map(|p| (p, RunRole::Test))
            .or_else(|| {
                train
                    .iter()
                    .rev()
                    .find_map(|&a| pick_run(prepared, a, LOOP_AMPLITUDE_M, target_f))
                    .map(|p| (p, RunRole::TrainValidation))
            });
        LoopPicks {
            fig7_cols: cols,
            fig7,
            all_variants,
        }
    }
}

/// The whole-run predictions the loop figures draw, as `(variant, run index)`: the loop model
/// (the most complete variant trained) on the Fig. 7 runs, every trained variant on the all-variants run.
pub(crate) fn loop_requests(
    trained: &[TrainedVariant],
    prepared: &Prepared,
) -> Vec<(ModelKind, usize)> {
    let picks = LoopPicks::of(prepared);
    let mut out: Vec<(ModelKind, usize)> = Vec::new();
    if let Some(tv) = loop_model(trained) {
        out.extend(picks.fig7.iter().map(|(_, p)| (tv.variant, p.index)));
    }
    if let Some((p, _)) = picks.all_variants {
        out.extend(trained.iter().map(|t| (t.variant, p.index)));
    }
    out.sort_by_key(|&(v, run)| (v as u8, run));
    out.dedup();
    out
}

/// The model of the loop figure: the most complete variant trained.
fn loop_model(trained: &[TrainedVariant]) -> Option<&TrainedVariant> {
    [
        ModelKind::Nemm,
        ModelKind::NemmLight,
        ModelKind::LinearEmm,
        ModelKind::Sem,
    ]
    .into_iter()
    .find_map(|v| trained.iter().find(|t| t.variant == v))
}

/// Distinct oil-loss levels of runs with `role`, ascending.
fn levels(prepared: &Prepared, role: RunRole) -> Vec<f64> {
    distinct_levels(
        prepared
            .runs
            .iter()
            .filter(|r| r.role == role)
            .map(|r| r.summary.alpha),
    )
}

/// The run at oil loss `alpha` with the amplitude nearest `amplitude_m` (within 25 % of the
/// best match) and, among those, the frequency nearest `frequency_hz`.
fn pick_run(
    prepared: &Prepared,
    alpha: f64,
    amplitude_m: f64,
    frequency_hz: f64,
) -> Option<RunPick> {
    let cands: Vec<RunPick> = prepared
        .runs
        .iter()
        .enumerate()
        .filter(|(_, r)| (r.summary.alpha - alpha).abs() < 1e-6)
        .filter_map(|(i, r)| {
            let e = &r.summary.excitation;
            Some(RunPick {
                index: i,
                alpha: r.summary.alpha,
                amplitude_m: r.summary.manifest_amplitude_m.unwrap_or(e.amplitude_m),
                frequency_hz: e.frequency_hz.filter(|f| f.is_finite() && *f > 0.0)?,
            })
        })
        .filter(|p| p.index < prepared.signals.len() && p.amplitude_m > 0.0)
        .collect();
    let amp_err = |p: &RunPick| (p.amplitude_m / amplitude_m).ln().abs();
    let best = cands.iter().map(amp_err).fold(f64::INFINITY, f64::min);
    cands
        .into_iter()
        .filter(|p| amp_err(p) <= best + 0.25)
        .min_by(|a, b| {
            let fa = (a.frequency_hz / frequency_hz).ln().abs();
            let fb = (b.frequency_hz / frequency_hz).ln().abs();
            fa.total_cmp(&fb)
        })
}

impl Ctx<'_> {
    /// The last `LOOP_PERIODS` full-amplitude periods of a run: its preprocessed signals and
    /// the evaluation's prediction of each of `variants`.
    fn loop_of(&self, pick: &RunPick, variants: &[ModelKind]) -> Result<LoopData> {
        let fs = self.prepared.sample_rate_hz;
        let fsc = self.force_scale();
        let run = self
            .dataset
            .runs
            .get(pick.index)
            .context("run not in the dataset")?;
        let sig = self
            .prepared
            .signals
            .get(pick.index)
            .context("run not in the prepared set")?;
        let exc = &self.prepared.runs[pick.index].summary.excitation;
        let min_start = self.prepared.warmup_samples.max((0.05 * fs) as usize);
        let w = steady_window(
            &sig.displacement_m,
            exc.offset_m,
            exc.amplitude_m,
            fs / pick.frequency_hz,
            LOOP_PERIODS,
            min_start,
        )
        .with_context(|| {
            format!(
                "run {} has no full-amplitude period after the ramp-in",
                run.entry.file.display()
            )
        })?;
        let models = variants
            .iter()
            .map(|&v| {
                let y = self.predictions.get(v, pick.index).with_context(|| {
                    format!(
                        "no {} prediction of run {}",
                        v.title(),
                        run.entry.file.display()
                    )
                })?;
                let y = y
                    .get(w.clone())
                    .context("prediction shorter than the run")?;
                Ok(y.iter().map(|f| f / fsc).collect())
            })
            .collect::<Result<_>>()?;
        Ok(LoopData {
            velocity_m_s: sig.velocity_m_s[w.clone()].to_vec(),
            measured: sig.force_filtered_n[w.clone()]
                .iter()
                .map(|f| f / fsc)
                .collect(),
            measured_raw: run.force_n[w].iter().map(|f| f / fsc).collect(),
            models,
        })
    }

    /// [`Ctx::loop_of`] for several runs.
    fn loops_of(&self, picks: &[RunPick], variants: &[ModelKind]) -> Vec<Result<LoopData>> {
        picks.iter().map(|p| self.loop_of(p, variants)).collect()
    }
}

/// Up to `periods` consecutive periods (of `period` samples) in which `x - offset` reaches at
/// least 95 % of `amplitude` on both sides, with full-amplitude peaks also in the half periods
/// just before and after (where the signal has them), starting at or after `min_start`: the
/// latest such stretch, so that neither a ramp-in nor a ramp-out is shown.
fn steady_window(
    x: &[f64],
    offset: f64,
    amplitude: f64,
    period: f64,
    periods: usize,
    min_start: usize,
) -> Option<Range<usize>> {
    if !(period.is_finite() && period >= 4.0 && amplitude > 0.0) || periods == 0 {
        return None;
    }
    let level = 0.95 * amplitude;
    let full = |a: usize, b: usize| {
        let (lo, hi) = x[a..b]
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                (l.min(v - offset), h.max(v - offset))
            });
        hi >= level && lo <= -level
    };
    let half = ((0.5 * period).round() as usize).max(1);
    let peak = |a: usize, b: usize| x[a..b].iter().any(|v| (v - offset).abs() >= level);
    let bounded_after = |b: usize| b + half > x.len() || peak(b, b + half);
    let bounded_before = |a: usize| a < half || peak(a - half, a);
    let len = |k: usize| (k as f64 * period).round() as usize;
    let step = ((period / 8.0) as usize).max(1);
    let mut end = x.len();
    while end >= len(1) + min_start {
        if full(end - len(1), end) && bounded_after(end) && bounded_before(end - len(1)) {
            let mut k = 1;
            while k < periods
                && end >= len(k + 1) + min_start
                && full(end - len(k + 1), end - len(k))
                && bounded_before(end - len(k + 1))
            {
                k += 1;
            }
            return Some(end - len(k)..end);
        }
        end = end.checked_sub(step)?;
    }
    None
}

/// The axes of the loop panels: velocity and force symmetric about zero over every shown loop.
struct LoopFrame {
    /// Velocity range \[m/s\].
    x: (f64, f64),
    /// Normalised force range.
    y: (f64, f64),
}

impl LoopFrame {
    /// The frame of `loops` (measured and model forces).
    fn of<'a>(loops: impl Iterator<Item = &'a LoopData> + Clone) -> Self {
        LoopFrame {
            x: sym_range(loops.clone().flat_map(|d| d.velocity_m_s.iter())),
            y: sym_range(loops.flat_map(|d| d.measured.iter().chain(d.models.iter().flatten()))),
        }
    }

    /// An empty loop panel titled `title` in this frame.
    fn panel(&self, title: String) -> LinePanel {
        LinePanel::new(title, "damper velocity [m/s]", "force / force scale [-]")
            .with_x_range(self.x.0, self.x.1)
            .with_y_range(self.y.0, self.y.1)
            .with_zero_lines()
            .with_legend(LegendPosition::UpperLeft)
    }
}

impl RunPick {
    /// Legend label: frequency and amplitude.
    fn label(&self) -> String {
        format!(
            "{:.1} Hz, A = {:.0} mm",
            self.frequency_hz,
            self.amplitude_m * 1e3
        )
    }
}

/// The loops of one Fig. 7 column (one oil-loss level), one per frequency.
type Column = Vec<(RunPick, LoopData)>;

pub(super) fn fig7_loops(ctx: &Ctx<'_>) -> Result<Drawn> {
    let Some(tv) = loop_model(ctx.trained) else {
        return Ok(Drawn::Skipped("no trained model".into()));
    };
    let model_name = tv.variant.title();
    let cols = &ctx.picks.fig7_cols;
    let data = match fig7_columns(ctx, tv.variant) {
        Ok(data) => data,
        Err(why) => return Ok(Drawn::Skipped(why)),
    };
    let frame = LoopFrame::of(data.iter().flatten().map(|(_, d)| d));
    let condition = ctx.condition();
    let at_10mm = data
        .iter()
        .flatten()
        .all(|(p, _)| (p.amplitude_m / LOOP_AMPLITUDE_M).ln().abs() < 0.25);
    let mut fig = Figure::new(3, cols.len())
        .with_panel_size(540, 410)
        .with_title(format!(
            "Fig. 7: measured vs {model_name} force-velocity loops {} (force scale {:.0} N)",
            if at_10mm {
                "at A = 10 mm"
            } else {
                "(no 10 mm runs at every level: nearest amplitudes)"
            },
            ctx.force_scale()
        ));
    // Rows: measured, model, both.
    for (c, col) in cols.iter().zip(&data) {
        let title = format!("measured: {}", level_name(&condition, c.0, c.1));
        fig = fig.with_panel(column_panel(&level_name(&condition, c.0, c.1), col, || {
            measured_loops(&frame, title, col)
        }));
    }
    for (c, col) in cols.iter().zip(&data) {
        let title = format!("{model_name}: {}", level_name(&condition, c.0, c.1));
        fig = fig.with_panel(column_panel(&level_name(&condition, c.0, c.1), col, || {
            model_loops(&frame, title, col)
        }));
    }
    for (c, col) in cols.iter().zip(&data) {
        let title = format!("overlay: {}", level_name(&condition, c.0, c.1));
        fig = fig.with_panel(column_panel(&level_name(&condition, c.0, c.1), col, || {
            overlay_loops(&frame, title, col, model_name)
        }));
    }
    let fig = fig.with_footer(format!(
        "Top: measured (zero-phase low-passed force, {}); middle: {model_name} simulated over the whole run from rest on the \
         preprocessed velocity; bottom: both. Blue: the run nearest {} Hz, red: nearest {} Hz.\n\
         Shown: the last {LOOP_PERIODS} full-amplitude periods (after the ramp-in). RMSE: against the raw force over these periods, \
         divided by the force scale as in Table 4. The test level was not used in training.",
        cutoff_words(&ctx.prepared.runs),
        LOOP_FREQUENCIES_HZ[0],
        LOOP_FREQUENCIES_HZ[1]
    ));
    Ok(Drawn::Figure(Box::new(fig)))
}

/// The loops of the Fig. 7 runs, by column, with the prediction of `variant`. Runs that
/// cannot be shown are warned about on stderr; when none can, the reason is the error.
fn fig7_columns(ctx: &Ctx<'_>, variant: ModelKind) -> Result<Vec<Column>, String> {
    let (cols, picks) = (&ctx.picks.fig7_cols, &ctx.picks.fig7);
    let just: Vec<RunPick> = picks.iter().map(|p| p.1).collect();
    let mut data: Vec<Column> = cols.iter().map(|_| Vec::new()).collect();
    let mut problems = Vec::new();
    for ((c, pick), d) in picks.iter().zip(ctx.loops_of(&just, &[variant])) {
        match d {
            Ok(d) => data[*c].push((*pick, d)),
            Err(e) => problems.push(format!("{e:#}")),
        }
    }
    if data.iter().all(|c| c.is_empty()) {
        return Err(if problems.is_empty() {
            "no runs with a frequency estimate".into()
        } else {
            problems.join("; ")
        });
    }
    for p in &problems {
        eprintln!("warning: fig7_loops.png: {p}");
    }
    Ok(data)
}

/// The panel of a column of Fig. 7 (its level in words `level`), or a note when the column
/// has no run.
fn column_panel(level: &str, col: &Column, panel: impl FnOnce() -> LinePanel) -> Panel {
    if col.is_empty() {
        Panel::Note(format!("no run at {level}"))
    } else {
        panel().into()
    }
}

/// Fig. 7, top row: the measured loops of a column.
fn measured_loops(frame: &LoopFrame, title: String, col: &Column) -> LinePanel {
    let mut p = frame.panel(title);
    // The higher frequency first: its loop encloses the lower one's.
    for (k, (pick, d)) in col.iter().enumerate().rev() {
        p = p.with_series(Series::line(
            pick.label(),
            d.points(&d.measured),
            frequency_color(k),
        ));
    }
    p
}

/// Fig. 7, middle row: the model's loops of a column, with their RMSE.
fn model_loops(frame: &LoopFrame, title: String, col: &Column) -> LinePanel {
    let mut p = frame.panel(title);
    for (k, (pick, d)) in col.iter().enumerate().rev() {
        p = p.with_series(Series::line(
            format!("{}: RMSE {:.3}", pick.label(), d.rmse(0)),
            d.points(&d.models[0]),
            frequency_color(k),
        ));
    }
    p
}

/// Fig. 7, bottom row: measured (light, wide) under model (dark) loops of a column, one
/// legend entry per kind.
fn overlay_loops(frame: &LoopFrame, title: String, col: &Column, model_name: &str) -> LinePanel {
    let mut p = frame.panel(title);
    for (k, (_, d)) in col.iter().enumerate().rev() {
        p = p.with_series(
            Series::line(
                "measured (light)",
                d.points(&d.measured),
                palette::lighten(frequency_color(k), 0.55),
            )
            .with_width(5),
        );
    }
    for (k, (_, d)) in col.iter().enumerate().rev() {
        p = p.with_series(Series::line(
            format!("{model_name} (dark)"),
            d.points(&d.models[0]),
            frequency_color(k),
        ));
    }
    for (i, s) in p.series.iter_mut().enumerate() {
        if i != 0 && i != col.len() {
            s.label = None;
        }
    }
    p
}

pub(super) fn loops_all_variants(ctx: &Ctx<'_>) -> Result<Drawn> {
    let Some((pick, role)) = ctx.picks.all_variants else {
        return Ok(Drawn::Skipped("no run with a frequency estimate".into()));
    };
    let variants: Vec<&TrainedVariant> = ModelKind::ALL
        .iter()
        .filter_map(|&v| ctx.variant(v))
        .collect();
    let shown: Vec<ModelKind> = variants.iter().map(|t| t.variant).collect();
    let d = ctx.loop_of(&pick, &shown)?;
    let frame = LoopFrame::of(std::iter::once(&d));
    let n = variants.len();
    let cols = if n <= 2 { n } else { 2 };
    let mut fig = Figure::new(n.div_ceil(cols), cols)
        .with_panel_size(600, 440)
        .with_title(format!(
            "All variants on one {} run: {}, A = {:.0} mm, f = {:.1} Hz",
            if role == RunRole::Test {
                "test"
            } else {
                "training"
            },
            level_name(&ctx.condition(), pick.alpha, role),
            pick.amplitude_m * 1e3,
            pick.frequency_hz
        ));
    for (k, tv) in variants.iter().enumerate() {
        let r = d.rmse(k);
        let p = frame
            .panel(format!(
                "{}: RMSE {:.3} ({:.0} N)",
                tv.variant.title(),
                r,
                r * ctx.force_scale()
            ))
            .with_series(
                Series::line("measured", d.points(&d.measured), MEASURED_GREY).with_width(5),
            )
            .with_series(Series::line(
                tv.variant.title(),
                d.points(&d.models[k]),
                variant_color(tv.variant),
            ));
        fig = fig.with_panel(p);
    }
    let fig = fig.with_footer(format!(
        "Forces divided by the training set's abs-max force ({:.0} N). Each variant simulated over the whole run from rest \
         on the preprocessed velocity; shown: the last {LOOP_PERIODS} full-amplitude periods.\n\
         Measured: zero-phase low-passed force ({}). RMSE: against the raw force over the shown periods, normalised \
         like Table 4 (the report's RMSE averages all test windows).",
        ctx.force_scale(),
        cutoff_words(&ctx.prepared.runs)
    ));
    Ok(Drawn::Figure(Box::new(fig)))
}

/// The low-pass cut-offs of the runs in words: `150 Hz`, or `16-150 Hz, per run`.
fn cutoff_words(runs: &[crate::data::preprocess::PreparedRun]) -> String {
    let (lo, hi) = runs.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), r| {
        (lo.min(r.summary.cutoff.hz), hi.max(r.summary.cutoff.hz))
    });
    if runs.is_empty() {
        String::from("no run")
    } else if lo == hi {
        format!("{lo} Hz")
    } else {
        format!("{lo}-{hi} Hz, per run")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_window_skips_ramps_at_both_ends() {
        // 20 periods of 100 samples: 3 periods of ramp-in, 2 of ramp-out.
        let n = 2000;
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / 100.0;
                let w = if t < 3.0 {
                    t / 3.0
                } else if t > 18.0 {
                    (20.0 - t) / 2.0
                } else {
                    1.0
                };
                0.01 * w * (2.0 * std::f64::consts::PI * t).sin()
            })
            .collect();
        let w = steady_window(&x, 0.0, 0.01, 100.0, 2, 10).expect("window");
        assert_eq!(w.len(), 200);
        assert!(w.start >= 300 && w.end <= 1800, "{w:?}");
        // Without a ramp-out the window ends with the signal.
        let w = steady_window(&x[..1750], 0.0, 0.01, 100.0, 2, 10).expect("window");
        assert_eq!(w, 1550..1750);
        assert!(steady_window(&x, 0.0, 0.02, 100.0, 2, 10).is_none());
        assert!(steady_window(&x[..50], 0.0, 0.01, 100.0, 2, 0).is_none());
    }
}
