//! Figures of a comparison report (`nemm compare`): the paper's Figs. 7-12 and the training
//! curves, as PNG files (see `docs/training.md`, section "Figures").
//!
//! | file | content |
//! |------|---------|
//! | `fig7_loops.png` | measured vs model force-velocity loops at 10 mm, ~8.3 and ~16.7 Hz, at 0 %, 30 % and the test oil loss (Fig. 7) |
//! | `loops_all_variants.png` | one high-frequency test run, measured vs each variant |
//! | `fig8_b_fl.png`, `fig8_b_fl_nemm-light.png` | `b_fl(v_st, alpha)` map with monotonicity violations, and cuts (Figs. 8-10), NEMM and NEMM-Light |
//! | `fig11_b_pr.png` | `b_pr(alpha)` of the NEMM (Fig. 11) |
//! | `fig12_k_pr.png` | `k_pr(x_pr, alpha)` of the NEMM with violations, and cuts (Fig. 12) |
//! | `training_curves.png` | training MSE, validation RMSE, physics loss per epoch |
//!
//! Loops are whole runs simulated from rest by [`predict`] on the preprocessing's velocity
//! (the trainer's input), shown over full-amplitude periods at the end of the run (after the
//! ramp-in). Measured forces are the preprocessing's zero-phase low-passed force; RMSEs in the
//! legends are against the raw force over the shown periods, normalised like Table 4.
//!
//! Violations are found exactly as [`crate::train::physics::audit`] finds them, on the same
//! grid ([`AUDIT_GRID`]): a grid interval where `d(p x)/dx < 0` (eqs. 30, 37) or
//! `dp/d alpha > 0` (eqs. 31, 38) beyond rounding ([`violation`]). On the maps the cell at
//! the lower end of each violating interval is painted yellow.
//!
//! A figure that cannot be drawn (missing runs, rendering trouble) is skipped with a warning;
//! only I/O errors fail [`write_all`].

use crate::data::dataset::Dataset;
use crate::data::preprocess::{process_run, Prepared, RunRole};
use crate::report::plot::{
    self, nice_levels, palette, ColorMap, Figure, HeatmapPanel, LegendPosition, LinePanel, Panel,
    Series,
};
use crate::report::tables::Report;
use crate::train::eval::predict;
use crate::train::physics::violation;
use crate::train::physics::AUDIT_GRID;
use crate::train::pipeline::{TrainedVariant, Variant, VariantInfo};
use anyhow::{bail, Context, Result};
use nemm_core::Model;
use plotters::style::RGBColor;
use std::ops::Range;
use std::panic::AssertUnwindSafe;
use std::path::Path;
use std::time::Instant;

/// Stroke amplitude of the loop figures \[m\] (paper Fig. 7: 10 mm).
pub const LOOP_AMPLITUDE_M: f64 = 0.010;
/// Excitation frequencies of the loop figures \[Hz\] (paper Fig. 7).
pub const LOOP_FREQUENCIES_HZ: [f64; 2] = [8.3, 16.7];
/// Full-amplitude periods shown per loop.
pub const LOOP_PERIODS: usize = 2;
/// Oil-loss levels of the training columns of Fig. 7 (the nearest training levels are used).
pub const LOOP_TRAIN_ALPHAS: [f64; 2] = [0.0, 0.3];
/// Velocity of the paper's Fig. 10 B cut \[m/s\].
pub const CUT_VELOCITY_M_S: f64 = 0.5;

/// File name of the `b_fl` figure of a variant.
pub fn b_fl_file(v: Variant) -> String {
    match v {
        Variant::Nemm => "fig8_b_fl.png".into(),
        other => format!("fig8_b_fl_{}.png", other.name()),
    }
}

/// What a figure builder produced.
enum Drawn {
    Figure(Box<Figure>),
    /// Not drawn, with the reason (e.g. no run at 10 mm).
    Skipped(String),
}

type Builder<'a> = Box<dyn Fn() -> Result<Drawn> + 'a>;

/// Writes every figure of a comparison into `dir`. Figures of variants that were not trained
/// are left out; a figure that cannot be drawn is skipped with a warning on stderr. Errors
/// only on I/O failures.
pub fn write_all(
    trained: &[TrainedVariant],
    dataset: &Dataset,
    prepared: &Prepared,
    report: &Report,
    dir: &Path,
) -> Result<()> {
    let t0 = Instant::now();
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let ctx = Ctx {
        trained,
        dataset,
        prepared,
        report,
    };
    let ctx = &ctx;
    let mut jobs: Vec<(String, Builder<'_>)> = Vec::new();
    if !trained.is_empty() {
        jobs.push(("fig7_loops.png".into(), Box::new(move || fig7_loops(ctx))));
        jobs.push((
            "loops_all_variants.png".into(),
            Box::new(move || loops_all_variants(ctx)),
        ));
    }
    for v in [Variant::Nemm, Variant::NemmLight] {
        if let Some(tv) = ctx.variant(v) {
            jobs.push((b_fl_file(v), Box::new(move || fig_b_fl(ctx, tv))));
        }
    }
    if let Some(tv) = ctx.variant(Variant::Nemm) {
        jobs.push((
            "fig11_b_pr.png".into(),
            Box::new(move || fig11_b_pr(ctx, tv)),
        ));
        jobs.push((
            "fig12_k_pr.png".into(),
            Box::new(move || fig12_k_pr(ctx, tv)),
        ));
    }
    if trained.iter().any(|t| !t.history.is_empty()) {
        jobs.push((
            "training_curves.png".into(),
            Box::new(move || training_curves(ctx)),
        ));
    }
    let mut written = Vec::new();
    for (name, build) in &jobs {
        let rendered = std::panic::catch_unwind(AssertUnwindSafe(|| -> Result<_> {
            Ok(match build()? {
                Drawn::Figure(fig) => Some((fig.render_rgb()?, fig.size())),
                Drawn::Skipped(why) => {
                    eprintln!("note: figure {name} skipped: {why}");
                    None
                }
            })
        }));
        match rendered {
            Ok(Ok(Some((rgb, size)))) => {
                plot::save_rgb_png(&dir.join(name), size, &rgb)
                    .with_context(|| format!("cannot write figure {name}"))?;
                written.push(name.as_str());
            }
            Ok(Ok(None)) => {}
            Ok(Err(e)) => eprintln!("warning: figure {name} not drawn: {e:#}"),
            Err(_) => eprintln!("warning: figure {name} not drawn: the plotting code panicked"),
        }
    }
    eprintln!(
        "figures: {} written in {:.1} s ({})",
        written.len(),
        t0.elapsed().as_secs_f64(),
        written.join(", ")
    );
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Shared context: runs, loops, colours
// ---------------------------------------------------------------------------------------------

struct Ctx<'a> {
    trained: &'a [TrainedVariant],
    dataset: &'a Dataset,
    prepared: &'a Prepared,
    report: &'a Report,
}

/// A run chosen for a loop figure.
#[derive(Debug, Clone, Copy)]
struct RunPick {
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

impl Ctx<'_> {
    fn variant(&self, v: Variant) -> Option<&TrainedVariant> {
        self.trained.iter().find(|t| t.variant == v)
    }

    fn force_scale(&self) -> f64 {
        self.prepared.scales.force_n
    }

    /// The model of the loop figure: the most complete variant trained.
    fn loop_model(&self) -> Option<&TrainedVariant> {
        [
            Variant::Nemm,
            Variant::NemmLight,
            Variant::LinearEmm,
            Variant::Sem,
        ]
        .into_iter()
        .find_map(|v| self.variant(v))
    }

    /// Distinct oil-loss levels of runs with `role`, ascending.
    fn levels(&self, role: RunRole) -> Vec<f64> {
        crate::data::preprocess::distinct_levels(
            self.prepared
                .runs
                .iter()
                .filter(|r| r.role == role)
                .map(|r| r.summary.alpha),
        )
    }

    /// The run at oil loss `alpha` with the amplitude nearest `amplitude_m` (within 25 % of
    /// the best match) and, among those, the frequency nearest `frequency_hz`.
    fn pick_run(&self, alpha: f64, amplitude_m: f64, frequency_hz: f64) -> Option<RunPick> {
        let cands: Vec<RunPick> = self
            .prepared
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
            .filter(|p| p.index < self.dataset.runs.len() && p.amplitude_m > 0.0)
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

    /// Simulates `models` over the whole run and returns the last `LOOP_PERIODS`
    /// full-amplitude periods.
    fn loop_of(&self, pick: &RunPick, models: &[&Model]) -> Result<LoopData> {
        self.loops_of(std::slice::from_ref(pick), models)
            .pop()
            .context("no loop")?
    }

    /// [`Ctx::loop_of`] for several runs, simulated in one batch per model.
    fn loops_of(&self, picks: &[RunPick], models: &[&Model]) -> Vec<Result<LoopData>> {
        use rayon::prelude::*;
        let fs = self.dataset.sample_rate_hz;
        let fsc = self.force_scale();
        // Signals and shown window of every run.
        let prepared: Vec<Result<(crate::data::preprocess::Signals, Range<usize>)>> = picks
            .par_iter()
            .map(|pick| {
                let run = &self.dataset.runs[pick.index];
                let sig = process_run(run, pick.index, fs, &self.prepared.config.signal)
                    .with_context(|| {
                        format!("cannot preprocess run {}", run.entry.file.display())
                    })?;
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
                Ok((sig, w))
            })
            .collect();
        let v32: Vec<Option<Vec<f32>>> = prepared
            .iter()
            .map(|r| {
                r.as_ref()
                    .ok()
                    .map(|(sig, _)| sig.velocity_m_s.iter().map(|&v| v as f32).collect())
            })
            .collect();
        let inputs: Vec<(&[f32], f32)> = v32
            .iter()
            .zip(picks)
            .filter_map(|(v, p)| v.as_ref().map(|v| (v.as_slice(), p.alpha as f32)))
            .collect();
        // predictions[model][ok run]
        let predictions: Vec<Result<Vec<Vec<f64>>>> =
            models.par_iter().map(|m| predict(m, &inputs)).collect();
        let mut k = 0;
        prepared
            .into_iter()
            .zip(picks)
            .map(|(r, pick)| {
                let (sig, w) = r?;
                let run = &self.dataset.runs[pick.index];
                let mut out = Vec::with_capacity(models.len());
                for p in &predictions {
                    let y = match p {
                        Ok(ys) => ys.get(k).context("missing prediction")?,
                        Err(e) => bail!("cannot simulate: {e:#}"),
                    };
                    out.push(y[w.clone()].iter().map(|f| f / fsc).collect());
                }
                k += 1;
                Ok(LoopData {
                    velocity_m_s: sig.velocity_m_s[w.clone()].to_vec(),
                    measured: sig.force_filtered_n[w.clone()]
                        .iter()
                        .map(|f| f / fsc)
                        .collect(),
                    measured_raw: run.force_n[w].iter().map(|f| f / fsc).collect(),
                    models: out,
                })
            })
            .collect()
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

fn variant_color(v: Variant) -> RGBColor {
    match v {
        Variant::Sem => palette::categorical(4),
        Variant::LinearEmm => palette::categorical(1),
        Variant::NemmLight => palette::categorical(2),
        Variant::Nemm => palette::categorical(0),
    }
}

/// Paper colours: the lower frequency blue, the higher red.
fn frequency_color(k: usize) -> RGBColor {
    if k == 0 {
        palette::categorical(0)
    } else {
        palette::categorical(3)
    }
}

const MEASURED_GREY: RGBColor = RGBColor(150, 150, 150);
const VIOLATION_DOT: RGBColor = RGBColor(235, 180, 0);

/// A number to 4 significant digits (f32 values without their binary tail).
fn num(v: f64) -> String {
    plot::format_tick(v)
}

fn pct(a: f64) -> String {
    format!("{:.0} %", 100.0 * a)
}

fn level_name(a: f64, role: RunRole) -> String {
    match role {
        RunRole::Test => format!("{} oil loss (test)", pct(a)),
        _ => format!("{} oil loss (training)", pct(a)),
    }
}

/// Symmetric range `+-1.06 max|v|` over all points.
fn sym_range<'a>(it: impl Iterator<Item = &'a f64>) -> (f64, f64) {
    let m = it
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let m = if m > 0.0 { 1.06 * m } else { 1.0 };
    (-m, m)
}

fn linspace(a: f64, b: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| a + (b - a) * i as f64 / (n.max(2) - 1) as f64)
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Fig. 7 and the all-variants loops
// ---------------------------------------------------------------------------------------------

fn fig7_loops(ctx: &Ctx<'_>) -> Result<Drawn> {
    let Some(tv) = ctx.loop_model() else {
        return Ok(Drawn::Skipped("no trained model".into()));
    };
    let model_name = tv.variant.title();
    // Columns: the training levels nearest 0 % and 30 %, then the test level.
    let train = ctx.levels(RunRole::TrainValidation);
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
    let test = ctx.levels(RunRole::Test);
    if let Some(&a) = test.iter().min_by(|a, b| {
        (*a - ctx.report.test_alpha)
            .abs()
            .total_cmp(&(*b - ctx.report.test_alpha).abs())
    }) {
        cols.push((a, RunRole::Test));
    }
    // Loops per column and frequency, simulated in one batch.
    let mut picks: Vec<(usize, RunPick)> = Vec::new();
    for (c, &(a, _)) in cols.iter().enumerate() {
        for f in LOOP_FREQUENCIES_HZ {
            if let Some(pick) = ctx.pick_run(a, LOOP_AMPLITUDE_M, f) {
                if !picks.iter().any(|(_, p)| p.index == pick.index) {
                    picks.push((c, pick));
                }
            }
        }
    }
    let just: Vec<RunPick> = picks.iter().map(|p| p.1).collect();
    let mut data: Vec<Vec<(RunPick, LoopData)>> = cols.iter().map(|_| Vec::new()).collect();
    let mut problems = Vec::new();
    for ((c, pick), d) in picks.iter().zip(ctx.loops_of(&just, &[&tv.model])) {
        match d {
            Ok(d) => data[*c].push((*pick, d)),
            Err(e) => problems.push(format!("{e:#}")),
        }
    }
    if data.iter().all(|c| c.is_empty()) {
        return Ok(Drawn::Skipped(if problems.is_empty() {
            "no runs with a frequency estimate".into()
        } else {
            problems.join("; ")
        }));
    }
    for p in &problems {
        eprintln!("warning: fig7_loops.png: {p}");
    }
    let all = data.iter().flatten();
    let xr = sym_range(all.clone().flat_map(|(_, d)| d.velocity_m_s.iter()));
    let yr = sym_range(all.flat_map(|(_, d)| d.measured.iter().chain(d.models.iter().flatten())));
    let ylabel = "force / force scale [-]";
    let xlabel = "damper velocity [m/s]";
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
    let label_of = |p: &RunPick| {
        format!(
            "{:.1} Hz, A = {:.0} mm",
            p.frequency_hz,
            p.amplitude_m * 1e3
        )
    };
    let base = |title: String| {
        LinePanel::new(title, xlabel, ylabel)
            .with_x_range(xr.0, xr.1)
            .with_y_range(yr.0, yr.1)
            .with_zero_lines()
            .with_legend(LegendPosition::UpperLeft)
    };
    // Row 1: measured.
    for (c, col) in cols.iter().zip(&data) {
        let mut p = base(format!("measured: {}", level_name(c.0, c.1)));
        // The higher frequency first: its loop encloses the lower one's.
        for (k, (pick, d)) in col.iter().enumerate().rev() {
            p = p.with_series(Series::line(
                label_of(pick),
                d.points(&d.measured),
                frequency_color(k),
            ));
        }
        fig = fig.with_panel(if col.is_empty() {
            Panel::Note(format!("no run at {}", level_name(c.0, c.1)))
        } else {
            p.into()
        });
    }
    // Row 2: model.
    for (c, col) in cols.iter().zip(&data) {
        let mut p = base(format!("{model_name}: {}", level_name(c.0, c.1)));
        for (k, (pick, d)) in col.iter().enumerate().rev() {
            p = p.with_series(Series::line(
                format!("{}: RMSE {:.3}", label_of(pick), d.rmse(0)),
                d.points(&d.models[0]),
                frequency_color(k),
            ));
        }
        fig = fig.with_panel(if col.is_empty() {
            Panel::Note(format!("no run at {}", level_name(c.0, c.1)))
        } else {
            p.into()
        });
    }
    // Row 3: overlay.
    for (c, col) in cols.iter().zip(&data) {
        let mut p = base(format!("overlay: {}", level_name(c.0, c.1)));
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
        // One legend entry per kind.
        for (i, s) in p.series.iter_mut().enumerate() {
            if i != 0 && i != col.len() {
                s.label = None;
            }
        }
        fig = fig.with_panel(if col.is_empty() {
            Panel::Note(format!("no run at {}", level_name(c.0, c.1)))
        } else {
            p.into()
        });
    }
    let fig = fig.with_footer(format!(
        "Top: measured (zero-phase low-passed force, {:.0} Hz); middle: {model_name} simulated over the whole run from rest on the \
         preprocessed velocity; bottom: both. Blue: the run nearest {} Hz, red: nearest {} Hz.\n\
         Shown: the last {LOOP_PERIODS} full-amplitude periods (after the ramp-in). RMSE: against the raw force over these periods, \
         divided by the force scale as in Table 4. The test level was not used in training.",
        ctx.prepared.config.signal.cutoff_hz,
        LOOP_FREQUENCIES_HZ[0],
        LOOP_FREQUENCIES_HZ[1]
    ));
    Ok(Drawn::Figure(Box::new(fig)))
}

fn loops_all_variants(ctx: &Ctx<'_>) -> Result<Drawn> {
    let test = ctx.levels(RunRole::Test);
    let train = ctx.levels(RunRole::TrainValidation);
    let target_f = LOOP_FREQUENCIES_HZ[LOOP_FREQUENCIES_HZ.len() - 1];
    let (pick, role) = match test
        .iter()
        .filter_map(|&a| ctx.pick_run(a, LOOP_AMPLITUDE_M, target_f))
        .next()
    {
        Some(p) => (p, RunRole::Test),
        None => match train
            .iter()
            .rev()
            .find_map(|&a| ctx.pick_run(a, LOOP_AMPLITUDE_M, target_f))
        {
            Some(p) => (p, RunRole::TrainValidation),
            None => return Ok(Drawn::Skipped("no run with a frequency estimate".into())),
        },
    };
    let variants: Vec<&TrainedVariant> = Variant::ALL
        .iter()
        .filter_map(|&v| ctx.variant(v))
        .collect();
    let models: Vec<&Model> = variants.iter().map(|t| &t.model).collect();
    let d = ctx.loop_of(&pick, &models)?;
    let xr = sym_range(d.velocity_m_s.iter());
    let yr = sym_range(d.measured.iter().chain(d.models.iter().flatten()));
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
            level_name(pick.alpha, role),
            pick.amplitude_m * 1e3,
            pick.frequency_hz
        ));
    for (k, tv) in variants.iter().enumerate() {
        let r = d.rmse(k);
        let p = LinePanel::new(
            format!(
                "{}: RMSE {:.3} ({:.0} N)",
                tv.variant.title(),
                r,
                r * ctx.force_scale()
            ),
            "damper velocity [m/s]",
            "force / force scale [-]",
        )
        .with_x_range(xr.0, xr.1)
        .with_y_range(yr.0, yr.1)
        .with_zero_lines()
        .with_series(Series::line("measured", d.points(&d.measured), MEASURED_GREY).with_width(5))
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
         Measured: zero-phase low-passed force ({:.0} Hz). RMSE: against the raw force over the shown periods, normalised \
         like Table 4 (the report's RMSE averages all test windows).",
        ctx.force_scale(),
        ctx.prepared.config.signal.cutoff_hz
    ));
    Ok(Drawn::Figure(Box::new(fig)))
}

// ---------------------------------------------------------------------------------------------
// Learned functions: grids and violations
// ---------------------------------------------------------------------------------------------

/// A learned coefficient on the audit grid: state in `[-1.2, 1.2]` of its scale, alpha in
/// `[0, 1]`, with the violating cells of eqs. 30-31 / 37-38.
struct Grid2 {
    /// Physical state at the grid points.
    state: Vec<f64>,
    /// Alpha at the grid points.
    alpha: Vec<f64>,
    /// Coefficient `p[ia][ix]` (physical units).
    value: Vec<Vec<f64>>,
    /// Cells at the lower end of a violating interval.
    mark: Vec<Vec<bool>>,
    state_violations: usize,
    alpha_violations: usize,
}

/// `f32` grid exactly as the audit builds it.
fn linspace_f32(a: f32, b: f32, n: usize) -> Vec<f32> {
    (0..n)
        .map(|i| a + (b - a) * i as f32 / (n.max(2) - 1) as f32)
        .collect()
}

fn grid_2d(eval: &dyn Fn(f32, f32) -> Option<f32>, scale: f32, p0: f32) -> Grid2 {
    let (n_state, n_alpha) = AUDIT_GRID;
    let xs = linspace_f32(-1.2, 1.2, n_state);
    let al = linspace_f32(0.0, 1.0, n_alpha);
    let dx = f64::from(xs[1] - xs[0]);
    let da = f64::from(al[1] - al[0]);
    let raw: Vec<Vec<Option<f32>>> = al
        .iter()
        .map(|&a| xs.iter().map(|&x| eval(x * scale, a)).collect())
        .collect();
    // Normalised scale factor, as the audit computes it.
    let s: Vec<Vec<f64>> = raw
        .iter()
        .map(|r| {
            r.iter()
                .map(|p| p.map_or(f64::NAN, |p| f64::from(p / p0)))
                .collect()
        })
        .collect();
    let mut mark = vec![vec![false; xs.len()]; al.len()];
    let (mut nv_state, mut nv_alpha) = (0, 0);
    for (ia, row) in s.iter().enumerate() {
        for ix in 0..xs.len() - 1 {
            let f0 = row[ix] * f64::from(xs[ix]);
            let f1 = row[ix + 1] * f64::from(xs[ix + 1]);
            if violation(f0, f1, dx, true).is_some() {
                nv_state += 1;
                mark[ia][ix] = true;
            }
        }
    }
    for ia in 0..al.len() - 1 {
        for ix in 0..xs.len() {
            if violation(s[ia][ix], s[ia + 1][ix], da, false).is_some() {
                nv_alpha += 1;
                mark[ia][ix] = true;
            }
        }
    }
    Grid2 {
        state: xs.iter().map(|&x| f64::from(x * scale)).collect(),
        alpha: al.iter().map(|&a| f64::from(a)).collect(),
        value: raw
            .iter()
            .map(|r| r.iter().map(|p| p.map_or(f64::NAN, f64::from)).collect())
            .collect(),
        mark,
        state_violations: nv_state,
        alpha_violations: nv_alpha,
    }
}

/// Points of a curve `y(x)` where it breaks monotonicity: `increasing` asks `dy/dx >= 0`
/// (else `<= 0`), in units normalised by `x_norm` and `y_norm`. The lower end of each
/// violating interval is returned.
fn curve_violations(
    pts: &[(f64, f64)],
    increasing: bool,
    x_norm: f64,
    y_norm: f64,
) -> Vec<(f64, f64)> {
    pts.windows(2)
        .filter(|w| {
            let step = (w[1].0 - w[0].0) / x_norm;
            violation(w[0].1 / y_norm, w[1].1 / y_norm, step, increasing).is_some()
        })
        .map(|w| w[0])
        .collect()
}

fn violation_text(g: &Grid2, state: &str) -> String {
    if g.state_violations + g.alpha_violations == 0 {
        "no violations".into()
    } else {
        format!(
            "violations: {} in {state}, {} in α",
            g.state_violations, g.alpha_violations
        )
    }
}

/// `max / min - 1` of the finite values, as text.
fn spread_text(values: &[Vec<f64>]) -> String {
    let (lo, hi) = values
        .iter()
        .flatten()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    if lo > 0.0 && hi.is_finite() {
        format!("varies by {} %", percent(100.0 * (hi / lo - 1.0)))
    } else {
        "not positive everywhere".into()
    }
}

fn value_range(it: impl Iterator<Item = f64>) -> (f64, f64) {
    it.filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        })
}

/// Alpha values of the cut curves: 0, the test level, the largest training level, 1.
fn cut_alphas(ctx: &Ctx<'_>, model: &Model) -> Vec<(f64, String)> {
    let mut v: Vec<(f64, String)> = vec![(0.0, "α = 0".into())];
    let test = ctx.report.test_alpha;
    let a_max = f64::from(model.meta.alpha_max);
    if test.is_finite() && test > 0.0 && test < 1.0 {
        v.push((test, format!("α = {} (test)", num(test))));
    }
    if a_max > 0.0 && a_max < 1.0 && (a_max - test).abs() > 1e-6 {
        v.push((a_max, format!("α = {} (max. training)", num(a_max))));
    }
    v.push((1.0, "α = 1 (extrapolated)".into()));
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}

fn alpha_color(i: usize) -> RGBColor {
    [
        palette::categorical(0),
        palette::categorical(2),
        palette::categorical(3),
        palette::categorical(4),
        palette::categorical(5),
    ][i % 5]
}

fn rel_change(a: f64, b: f64) -> String {
    if a.abs() > 0.0 && a.is_finite() && b.is_finite() {
        let p = 100.0 * (b - a) / a;
        let sign = if p > 0.0 {
            "+"
        } else if p < 0.0 {
            "-"
        } else {
            ""
        };
        format!("{sign}{} %", percent(p.abs()))
    } else {
        "n/a".into()
    }
}

/// A percentage `p >= 0` with one decimal, or two significant digits below 1 % (so that a
/// change of 0.02 % does not read as 0.0 %).
fn percent(p: f64) -> String {
    if p == 0.0 || !p.is_finite() || p >= 0.95 {
        format!("{p:.1}")
    } else {
        let decimals = (1 - p.log10().floor() as i32).clamp(1, 9) as usize;
        format!("{p:.decimals$}")
    }
}

fn vline(x: f64, y0: f64, y1: f64) -> Vec<(f64, f64)> {
    vec![(x, y0), (x, y1)]
}

// ---------------------------------------------------------------------------------------------
// Figs. 8-10: b_fl
// ---------------------------------------------------------------------------------------------

fn fig_b_fl(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
    let m = &tv.model;
    let Some(e) = m.emm() else {
        bail!("{} has no EMM constants", tv.variant.title());
    };
    let vs = f64::from(m.scales.velocity_m_s);
    let b0 = f64::from(e.b_fl_ns_per_m);
    let g = grid_2d(&|v, a| m.b_fl(v, a), m.scales.velocity_m_s, e.b_fl_ns_per_m);
    let v_lim = 1.2 * vs;
    let a_max = f64::from(m.meta.alpha_max);
    let (zlo, zhi) = value_range(g.value.iter().flatten().copied());
    let white = RGBColor(255, 255, 255);
    // A: the map, with the quasi-static training points and the training velocity range.
    let qs: Vec<(f64, f64)> = ctx
        .prepared
        .quasi_static
        .train
        .iter()
        .map(|p| (p.velocity_m_s, p.alpha))
        .filter(|p| p.0.abs() <= v_lim)
        .collect();
    let mut map = HeatmapPanel::new(
        format!(
            "A: b_fl(v_st, α), {}; {}",
            spread_text(&g.value),
            violation_text(&g, "v")
        ),
        "quasi-static velocity v_st [m/s]",
        "oil loss α [-]",
        g.state.clone(),
        g.alpha.clone(),
        g.value.clone(),
    )
    .with_z_label("b_fl [N s/m]")
    .with_colormap(ColorMap::Ocean)
    .with_contours(nice_levels(zlo, zhi, 8))
    .with_marks(g.mark.clone(), None)
    .with_legend(LegendPosition::None);
    for x in [-vs, vs] {
        map = map.with_overlay(Series::dashed("", vline(x, 0.0, 1.0), white).with_width(1));
    }
    if !qs.is_empty() {
        map = map.with_overlay(Series::dots("", qs, white));
    }
    // B: b_fl over alpha at -0.5 m/s (the paper's cut), zoomed.
    let vc = if CUT_VELOCITY_M_S <= v_lim {
        CUT_VELOCITY_M_S
    } else {
        0.5 * vs
    };
    let comp: Vec<(f64, f64)> = linspace(0.0, 1.0, 201)
        .into_iter()
        .map(|a| (a, m.b_fl(-vc as f32, a as f32).map_or(f64::NAN, f64::from)))
        .collect();
    let at = |a: f64| m.b_fl(-vc as f32, a as f32).map_or(f64::NAN, f64::from);
    let (ylo, yhi) = value_range(comp.iter().map(|p| p.1));
    let mut pb = LinePanel::new(
        format!(
            "B: b_fl at v_st = -{} m/s: {} from α = 0 to {}",
            num(vc),
            rel_change(at(0.0), at(a_max)),
            num(a_max)
        ),
        "oil loss α [-]",
        "b_fl [N s/m]",
    )
    .with_legend(LegendPosition::LowerLeft)
    .with_series(Series::line(
        format!("b_fl(v_st = -{} m/s, α)", num(vc)),
        comp.clone(),
        variant_color(tv.variant),
    ));
    if a_max > 0.0 && ylo.is_finite() {
        pb = pb.with_series(
            Series::dashed("max. training α", vline(a_max, ylo, yhi), MEASURED_GREY).with_width(1),
        );
    }
    let viol = curve_violations(&comp, false, 1.0, b0);
    if !viol.is_empty() {
        pb = pb
            .with_series(Series::dots("db_fl/dα > 0 (eq. 31)", viol, VIOLATION_DOT).with_width(3));
    }
    // C and D: b_fl and F_fl over v at several alphas.
    let cuts = cut_alphas(ctx, m);
    let v_axis = linspace(-v_lim, v_lim, 481);
    let mut b_max = b0;
    let mut pc = LinePanel::new(
        "C: b_fl over velocity (dashes: training range)",
        "quasi-static velocity v_st [m/s]",
        "b_fl [N s/m]",
    )
    .with_legend(LegendPosition::LowerRight);
    let mut pd = LinePanel::new(
        "D: flow force F_fl = b_fl v_st",
        "quasi-static velocity v_st [m/s]",
        "F_fl [N]",
    )
    .with_legend(LegendPosition::UpperLeft)
    .with_zero_lines();
    let mut f_viol = Vec::new();
    let mut f_all = Vec::new();
    for (i, (a, name)) in cuts.iter().enumerate() {
        let b: Vec<(f64, f64)> = v_axis
            .iter()
            .map(|&v| (v, m.b_fl(v as f32, *a as f32).map_or(f64::NAN, f64::from)))
            .collect();
        b_max = b
            .iter()
            .map(|p| p.1)
            .filter(|v| v.is_finite())
            .fold(b_max, f64::max);
        let f: Vec<(f64, f64)> = b.iter().map(|&(v, b)| (v, b * v)).collect();
        f_viol.extend(curve_violations(&f, true, vs, b0 * vs));
        f_all.extend(f.iter().map(|p| p.1));
        pc = pc.with_series(Series::line(name.clone(), b, alpha_color(i)));
        pd = pd.with_series(Series::line(name.clone(), f, alpha_color(i)));
    }
    pc = pc
        .with_series(Series::dashed(
            "b_fl,ini (Linear EMM constant)",
            vec![(-v_lim, b0), (v_lim, b0)],
            MEASURED_GREY,
        ))
        .with_y_range(0.0, 1.12 * b_max);
    for x in [-vs, vs] {
        pc = pc.with_series(
            Series::dashed("", vline(x, 0.0, 1.12 * b_max), MEASURED_GREY)
                .with_width(1)
                .unlabelled(),
        );
    }
    let qs_all: Vec<(f64, f64)> = ctx
        .prepared
        .quasi_static
        .train
        .iter()
        .chain(&ctx.prepared.quasi_static.validation)
        .chain(&ctx.prepared.quasi_static.test)
        .filter(|p| p.velocity_m_s.abs() <= v_lim)
        .map(|p| (p.velocity_m_s, p.force_n))
        .collect();
    if !qs_all.is_empty() {
        f_all.extend(qs_all.iter().map(|p| p.1));
        pd = pd.with_series(
            Series::dots("quasi-static points (all α)", qs_all, RGBColor(60, 60, 60)).with_width(3),
        );
    }
    let (flo, fhi) = sym_range(f_all.iter());
    for x in [-vs, vs] {
        pd = pd.with_series(
            Series::dashed("", vline(x, flo, fhi), MEASURED_GREY)
                .with_width(1)
                .unlabelled(),
        );
    }
    if !f_viol.is_empty() {
        pd = pd.with_series(
            Series::dots("dF_fl/dv < 0 (eq. 30)", f_viol, VIOLATION_DOT).with_width(3),
        );
    }
    let fig = Figure::new(2, 2)
        .with_panel_size(680, 480)
        .with_title(format!(
            "Figs. 8-10: flow damping b_fl(v_st, α) of {} (b_fl,ini = {} N s/m, v_scale = {} m/s)",
            tv.variant.title(),
            num(b0),
            num(vs)
        ))
        .with_panel(map)
        .with_panel(pb)
        .with_panel(pc)
        .with_panel(pd)
        .with_footer(format!(
            "A: b_fl on the audit grid ({} x {}: v_st in ±1.2 v_scale, α in [0, 1]); thin black lines: iso-lines. \
             Yellow cells: monotonicity violations, eq. 30 (d(b_fl v)/dv < 0)\n\
             or eq. 31 (db_fl/dα > 0), beyond f32 rounding; white dots: quasi-static training points \
             (eq. 41); white dashes: training velocity range ±v_scale.\n\
             B-D: cuts through the map; yellow dots: violations along a cut; α above {} is extrapolation.",
            AUDIT_GRID.0,
            AUDIT_GRID.1,
            num(a_max)
        ));
    Ok(Drawn::Figure(Box::new(fig)))
}

// ---------------------------------------------------------------------------------------------
// Fig. 11: b_pr
// ---------------------------------------------------------------------------------------------

fn fig11_b_pr(_ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
    let m = &tv.model;
    let Some(e) = m.emm() else {
        bail!("NEMM has no EMM constants");
    };
    let b0 = f64::from(e.b_pr_ns_per_m);
    let a_max = f64::from(m.meta.alpha_max);
    let curve: Vec<(f64, f64)> = linspace(0.0, 1.0, 201)
        .into_iter()
        .map(|a| (a, m.b_pr(a as f32).map_or(f64::NAN, f64::from)))
        .collect();
    let at = |a: f64| m.b_pr(a as f32).map_or(f64::NAN, f64::from);
    let ref0 = at(0.0);
    // Violations on the audit's alpha grid.
    let al = linspace_f32(0.0, 1.0, AUDIT_GRID.1);
    let da = f64::from(al[1] - al[0]);
    let s: Vec<f64> = al
        .iter()
        .map(|&a| {
            m.b_pr(a)
                .map_or(f64::NAN, |p| f64::from(p / e.b_pr_ns_per_m))
        })
        .collect();
    let viol: Vec<(f64, f64)> = (0..al.len() - 1)
        .filter(|&i| violation(s[i], s[i + 1], da, false).is_some())
        .map(|i| (f64::from(al[i]), 100.0 * (s[i] * b0 / ref0 - 1.0)))
        .collect();
    let (_, yhi) = value_range(curve.iter().map(|p| p.1).chain([b0]));
    let y_top = 1.15 * yhi;
    let mut pa = LinePanel::new(
        format!(
            "b_pr(α): {} → {} N s/m from α = 0 to {}",
            num(ref0),
            num(at(a_max)),
            num(a_max)
        ),
        "oil loss α [-]",
        "b_pr [N s/m]",
    )
    .with_y_range(0.0, y_top)
    .with_legend(LegendPosition::LowerLeft)
    .with_series(Series::line(
        "b_pr(α) (NEMM)",
        curve.clone(),
        variant_color(Variant::Nemm),
    ))
    .with_series(Series::dashed(
        "b_pr,ini (Linear EMM constant)",
        vec![(0.0, b0), (1.0, b0)],
        MEASURED_GREY,
    ));
    let rel: Vec<(f64, f64)> = curve
        .iter()
        .map(|&(a, b)| (a, 100.0 * (b / ref0 - 1.0)))
        .collect();
    let (rlo, rhi) = value_range(rel.iter().map(|p| p.1));
    let mut pb = LinePanel::new(
        format!(
            "change relative to α = 0: {} at α = {}; {}",
            rel_change(ref0, at(a_max)),
            num(a_max),
            if viol.is_empty() {
                "no violations".to_string()
            } else {
                format!("{} violations of eq. 38", viol.len())
            }
        ),
        "oil loss α [-]",
        "b_pr(α) / b_pr(0) - 1 [%]",
    )
    .with_legend(LegendPosition::LowerLeft)
    .with_series(Series::line(
        "b_pr(α) / b_pr(0) - 1",
        rel,
        variant_color(Variant::Nemm),
    ));
    for p in [&mut pa, &mut pb] {
        p.reference_y.push(0.0);
    }
    if a_max > 0.0 {
        pa = pa.with_series(
            Series::dashed("max. training α", vline(a_max, 0.0, y_top), MEASURED_GREY)
                .with_width(1),
        );
        if rlo.is_finite() {
            pb = pb.with_series(
                Series::dashed(
                    "max. training α",
                    vline(a_max, rlo.min(0.0), rhi.max(0.0)),
                    MEASURED_GREY,
                )
                .with_width(1),
            );
        }
    }
    if !viol.is_empty() {
        pb = pb
            .with_series(Series::dots("db_pr/dα > 0 (eq. 38)", viol, VIOLATION_DOT).with_width(3));
    }
    let fig = Figure::new(1, 2)
        .with_panel_size(680, 480)
        .with_title("Fig. 11: pressure-force damping b_pr(α) of the NEMM")
        .with_panel(pa)
        .with_panel(pb)
        .with_footer(format!(
            "Left: b_pr on an axis from zero with the Linear EMM's constant; right: the same, zoomed, as change relative to α = 0.\n\
             Yellow dots: grid intervals (audit grid, {} values of α) where b_pr grows with oil loss (eq. 38); α above {} is extrapolation.",
            AUDIT_GRID.1,
            num(a_max)
        ));
    Ok(Drawn::Figure(Box::new(fig)))
}

// ---------------------------------------------------------------------------------------------
// Fig. 12: k_pr
// ---------------------------------------------------------------------------------------------

fn fig12_k_pr(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
    let m = &tv.model;
    let Some(e) = m.emm() else {
        bail!("NEMM has no EMM constants");
    };
    let xs = f64::from(m.scales.x_pr_m);
    let k0 = f64::from(e.k_pr_n_per_m);
    let g = grid_2d(&|x, a| m.k_pr(x, a), m.scales.x_pr_m, e.k_pr_n_per_m);
    // Display units: mm and N/m (kN/m from 1e5 N/m on, where ticks would need exponents).
    let kilo = g
        .value
        .iter()
        .flatten()
        .chain(std::iter::once(&k0))
        .any(|v| v.abs() >= 1e5);
    let (ku, kname) = if kilo { (1e-3, "kN/m") } else { (1.0, "N/m") };
    let xmm = xs * 1e3;
    let x_lim = 1.2 * xmm;
    let a_max = f64::from(m.meta.alpha_max);
    let z: Vec<Vec<f64>> = g
        .value
        .iter()
        .map(|r| r.iter().map(|v| v * ku).collect())
        .collect();
    let (zlo, zhi) = value_range(z.iter().flatten().copied());
    let white = RGBColor(255, 255, 255);
    let mut map = HeatmapPanel::new(
        format!(
            "A: k_pr(x_pr, α), {}; {}",
            spread_text(&g.value),
            violation_text(&g, "x_pr")
        ),
        "valve deflection x_pr [mm]",
        "oil loss α [-]",
        g.state.iter().map(|x| x * 1e3).collect(),
        g.alpha.clone(),
        z,
    )
    .with_z_label(format!("k_pr [{kname}]"))
    .with_colormap(ColorMap::Ocean)
    .with_contours(nice_levels(zlo, zhi, 8))
    .with_marks(g.mark.clone(), None)
    .with_legend(LegendPosition::None);
    for x in [-xmm, xmm] {
        map = map.with_overlay(Series::dashed("", vline(x, 0.0, 1.0), white).with_width(1));
    }
    let cuts = cut_alphas(ctx, m);
    let x_axis = linspace(-x_lim, x_lim, 481);
    let mut pb = LinePanel::new(
        "B: k_pr over deflection",
        "valve deflection x_pr [mm]",
        format!("k_pr [{kname}]"),
    )
    .with_legend(LegendPosition::UpperRight);
    let mut pc = LinePanel::new(
        "C: spring force F = k_pr x_pr",
        "valve deflection x_pr [mm]",
        "F [N]",
    )
    .with_legend(LegendPosition::UpperLeft)
    .with_zero_lines();
    let mut f_viol = Vec::new();
    for (i, (a, name)) in cuts.iter().enumerate() {
        let k: Vec<(f64, f64)> = x_axis
            .iter()
            .map(|&x| {
                (
                    x,
                    m.k_pr((x * 1e-3) as f32, *a as f32)
                        .map_or(f64::NAN, f64::from),
                )
            })
            .collect();
        let f: Vec<(f64, f64)> = k.iter().map(|&(x, k)| (x, k * x * 1e-3)).collect();
        f_viol.extend(curve_violations(&f, true, xmm, k0 * xs));
        pb = pb.with_series(Series::line(
            name.clone(),
            k.iter().map(|&(x, k)| (x, k * ku)).collect(),
            alpha_color(i),
        ));
        pc = pc.with_series(Series::line(name.clone(), f, alpha_color(i)));
    }
    if !f_viol.is_empty() {
        pc = pc.with_series(
            Series::dots("dF/dx_pr < 0 (eq. 37)", f_viol, VIOLATION_DOT).with_width(3),
        );
    }
    // D: k_pr over alpha at a few deflections.
    let alphas = linspace(0.0, 1.0, 201);
    let at0 = |a: f64| m.k_pr(0.0, a as f32).map_or(f64::NAN, f64::from);
    let mut pd = LinePanel::new(
        format!(
            "D: k_pr over oil loss; at x_pr = 0: {} from α = 0 to {}",
            rel_change(at0(0.0), at0(a_max)),
            num(a_max)
        ),
        "oil loss α [-]",
        format!("k_pr [{kname}]"),
    )
    .with_legend(LegendPosition::LowerLeft);
    let mut d_viol = Vec::new();
    let mut d_all = Vec::new();
    for (i, frac) in [0.0, 0.5, 1.0].iter().enumerate() {
        let x = frac * xs;
        let c: Vec<(f64, f64)> = alphas
            .iter()
            .map(|&a| (a, m.k_pr(x as f32, a as f32).map_or(f64::NAN, f64::from)))
            .collect();
        d_viol.extend(
            curve_violations(&c, false, 1.0, k0)
                .into_iter()
                .map(|(a, k)| (a, k * ku)),
        );
        d_all.extend(c.iter().map(|p| p.1 * ku));
        pd = pd.with_series(Series::line(
            format!("x_pr = {} mm", num(x * 1e3)),
            c.into_iter().map(|(a, k)| (a, k * ku)).collect(),
            palette::categorical([0, 2, 3][i]),
        ));
    }
    let (dlo, dhi) = value_range(d_all.into_iter());
    if a_max > 0.0 && dlo.is_finite() {
        pd = pd.with_series(
            Series::dashed("max. training α", vline(a_max, dlo, dhi), MEASURED_GREY).with_width(1),
        );
    }
    if !d_viol.is_empty() {
        pd = pd.with_series(
            Series::dots("dk_pr/dα > 0 (eq. 38)", d_viol, VIOLATION_DOT).with_width(3),
        );
    }
    let fig = Figure::new(2, 2)
        .with_panel_size(680, 480)
        .with_title(format!(
            "Fig. 12: pressure-force stiffness k_pr(x_pr, α) of the NEMM (k_pr,ini = {} {kname}, x_scale = {} mm)",
            num(k0 * ku),
            num(xmm)
        ))
        .with_panel(map)
        .with_panel(pb)
        .with_panel(pc)
        .with_panel(pd)
        .with_footer(format!(
            "A: k_pr on the audit grid ({} x {}: x_pr in ±1.2 x_scale, α in [0, 1]); thin black lines: iso-lines. \
             Yellow cells: monotonicity violations, eq. 37 (d(k_pr x_pr)/dx_pr < 0)\n\
             or eq. 38 (dk_pr/dα > 0), beyond f32 rounding; white dashes: the range of x_pr reached \
             on the training data (±x_scale).\n\
             B-D: cuts through the map (B and D zoomed: read the values); yellow dots: violations along a cut; \
             α above {} is extrapolation.",
            AUDIT_GRID.0,
            AUDIT_GRID.1,
            num(a_max)
        ));
    Ok(Drawn::Figure(Box::new(fig)))
}

// ---------------------------------------------------------------------------------------------
// Training curves
// ---------------------------------------------------------------------------------------------

/// Epoch of the kept model: the best validation epoch, or 0 if no epoch beat the start.
fn best_epoch(tv: &TrainedVariant) -> Option<(usize, f64)> {
    let best = tv
        .history
        .iter()
        .filter(|s| s.val_rmse.is_finite())
        .min_by(|a, b| a.val_rmse.total_cmp(&b.val_rmse))?;
    if tv.val_rmse.is_finite() && tv.val_rmse < best.val_rmse * (1.0 - 1e-6) {
        Some((0, tv.val_rmse))
    } else {
        Some((best.epoch, best.val_rmse))
    }
}

fn training_curves(ctx: &Ctx<'_>) -> Result<Drawn> {
    let with_history: Vec<&TrainedVariant> = Variant::ALL
        .iter()
        .filter_map(|&v| ctx.variant(v))
        .filter(|t| !t.history.is_empty())
        .collect();
    if with_history.is_empty() {
        return Ok(Drawn::Skipped("no training history".into()));
    }
    let max_epoch = with_history
        .iter()
        .flat_map(|t| t.history.iter().map(|s| s.epoch))
        .max()
        .unwrap_or(1);
    let from_start = with_history
        .iter()
        .any(|t| best_epoch(t).is_some_and(|b| b.0 == 0));
    let x_range = (if from_start { -0.2 } else { 0.8 }, max_epoch as f64 + 0.2);
    let mut p_mse = LinePanel::new(
        "training MSE (normalised force, mean over batches)",
        "epoch",
        "MSE [-]",
    )
    .with_x_range(x_range.0, x_range.1)
    .with_legend(LegendPosition::UpperRight);
    p_mse.log_y = true;
    let mut p_val = LinePanel::new(
        "validation RMSE (normalised force); ● kept model",
        "epoch",
        "RMSE [-]",
    )
    .with_x_range(x_range.0, x_range.1)
    .with_legend(LegendPosition::UpperRight);
    p_val.log_y = true;
    let mut p_phys = LinePanel::new(
        "physics-inconsistency loss (eqs. 34, 39, 40)",
        "epoch",
        "loss [-]",
    )
    .with_x_range(x_range.0, x_range.1)
    .with_legend(LegendPosition::UpperRight);
    p_phys.log_y = true;
    let mut any_phys = false;
    for tv in &with_history {
        let c = variant_color(tv.variant);
        let name = tv.variant.title();
        let pts = |f: &dyn Fn(&crate::train::fit::EpochStats) -> f64| -> Vec<(f64, f64)> {
            tv.history.iter().map(|s| (s.epoch as f64, f(s))).collect()
        };
        let mse = pts(&|s| s.train_mse);
        let val = pts(&|s| s.val_rmse);
        p_mse = p_mse
            .with_series(Series::line(name, mse.clone(), c))
            .with_series(Series::dots("", mse, c).unlabelled());
        p_val = p_val
            .with_series(Series::line(name, val.clone(), c))
            .with_series(Series::dots("", val, c).unlabelled());
        if let Some((e, v)) = best_epoch(tv) {
            p_val = p_val.with_series(
                Series::dots(
                    format!("{name}: kept epoch {e}, {v:.4}"),
                    vec![(e as f64, v)],
                    c,
                )
                .with_width(7),
            );
        }
        let phys = pts(&|s| s.physics);
        if phys.iter().any(|p| p.1 > 0.0) {
            any_phys = true;
            p_phys = p_phys
                .with_series(Series::line(name, phys.clone(), c))
                .with_series(Series::dots("", phys, c).unlabelled());
        }
    }
    if let Some(sem) = ctx.variant(Variant::Sem) {
        if sem.val_rmse.is_finite() && sem.val_rmse > 0.0 {
            p_val = p_val.with_series(Series::dashed(
                format!("SEM (no training): {:.4}", sem.val_rmse),
                vec![(x_range.0, sem.val_rmse), (x_range.1, sem.val_rmse)],
                variant_color(Variant::Sem),
            ));
        }
    }
    // Headroom above the curves for the legend (upper right).
    for p in [&mut p_mse, &mut p_val, &mut p_phys] {
        let (lo, hi) = value_range(
            p.series
                .iter()
                .flat_map(|s| s.points.iter().map(|q| q.1))
                .filter(|v| *v > 0.0),
        );
        if lo.is_finite() && hi.is_finite() {
            let (l, h) = (lo.log10(), hi.log10());
            let span = (h - l).max(0.3);
            p.y_range = Some((10f64.powf(l - 0.06 * span), 10f64.powf(h + 0.75 * span)));
        }
    }
    let mut fig = Figure::new(1, if any_phys { 3 } else { 2 })
        .with_panel_size(620, 460)
        .with_title("Training curves per variant (rollout stage)")
        .with_footer(
            "Per epoch: mean normalised MSE of the training batches, validation RMSE (normalised by the training force scale; \
             large dot: the epoch of the kept model, 0 = the initial one),\n\
             and the physics-inconsistency loss (monotonicity penalty) of the neural variants. The SEM has no training; \
             its validation RMSE is the dashed line.",
        )
        .with_panel(p_mse)
        .with_panel(p_val);
    if any_phys {
        fig = fig.with_panel(p_phys);
    }
    Ok(Drawn::Figure(Box::new(fig)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_changes_keep_their_sign_and_size() {
        assert_eq!(rel_change(398.9, 398.82), "-0.020 %");
        assert_eq!(rel_change(100.0, 125.6), "+25.6 %");
        assert_eq!(rel_change(100.0, 100.0), "0.0 %");
        assert_eq!(rel_change(0.0, 1.0), "n/a");
        assert_eq!(percent(0.07), "0.070");
    }

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

    #[test]
    fn map_violations_are_the_audit_violations() {
        let m: Model =
            nemm_core::testing::example_model(nemm_core::ModelKind::Nemm, 8, 3).expect("model");
        let e = *m.emm().expect("emm");
        let audit = crate::train::physics::audit(&m, AUDIT_GRID.0, AUDIT_GRID.1);
        let b = grid_2d(&|v, a| m.b_fl(v, a), m.scales.velocity_m_s, e.b_fl_ns_per_m);
        let k = grid_2d(&|x, a| m.k_pr(x, a), m.scales.x_pr_m, e.k_pr_n_per_m);
        for (g, s) in [(&b, audit.b_fl), (&k, audit.k_pr)] {
            let s = s.expect("audited");
            assert_eq!(g.state_violations, s.state.expect("state").violations);
            assert_eq!(g.alpha_violations, s.alpha.violations);
            let marked = g.mark.iter().flatten().filter(|m| **m).count();
            assert!(marked > 0 && marked <= g.state_violations + g.alpha_violations);
        }
        // The random example weights do violate monotonicity somewhere.
        assert!(b.state_violations + b.alpha_violations > 0);
    }

    #[test]
    fn curve_violations_find_wrong_slopes() {
        let up: Vec<(f64, f64)> = (0..10).map(|i| (f64::from(i), f64::from(i))).collect();
        assert!(curve_violations(&up, true, 1.0, 1.0).is_empty());
        assert_eq!(curve_violations(&up, false, 1.0, 1.0).len(), 9);
        let mut bump = up.clone();
        bump[5].1 = 3.0;
        assert_eq!(curve_violations(&bump, true, 1.0, 1.0), vec![(4.0, 4.0)]);
    }
}
