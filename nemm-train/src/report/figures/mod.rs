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
//! The figures draw what the earlier stages produced, and compute nothing of theirs: the
//! measured loops are the preprocessing's signals ([`Prepared::signals`]), the quasi-static
//! points its split, the model loops the evaluation's whole-run predictions
//! ([`RunPredictions`], simulated from rest on the preprocessing's velocity for the runs
//! [`loop_requests`] names). Loops are shown over full-amplitude periods at the end of the run
//! (after the ramp-in). Measured forces are the zero-phase low-passed force; RMSEs in the
//! legends are against the raw force over the shown periods, normalised like Table 4.
//!
//! One file per kind of figure: [`loops`] (Fig. 7 and the all-variants loops), [`maps`] (the
//! learned coefficients, Figs. 8-12), [`training`] (the training curves).
//!
//! Violations are found exactly as [`crate::train::physics::audit`] finds them, on the same
//! grid ([`AUDIT_GRID`](crate::train::physics::AUDIT_GRID)): a grid interval where `d(p x)/dx < 0` (eqs. 30, 37) or
//! `dp/d alpha > 0` (eqs. 31, 38) beyond rounding ([`violation`](crate::train::physics::violation)). On the maps the cell at
//! the lower end of each violating interval is painted yellow.
//!
//! A figure that cannot be drawn (missing runs, rendering trouble) is skipped with a warning;
//! only I/O errors fail [`write_all`].

pub mod loops;
pub mod maps;
pub mod training;

pub use loops::loop_requests;

use crate::data::dataset::Dataset;
use crate::data::preprocess::{Prepared, RunRole};
use crate::report::plot::{self, palette, Figure};
use crate::report::predictions::RunPredictions;
use crate::report::tables::Report;
use crate::train::pipeline::{TrainedVariant, Variant};
use anyhow::{Context, Result};
use loops::{fig7_loops, loops_all_variants, LoopPicks};
use maps::{fig11_b_pr, fig12_k_pr, fig_b_fl};
use plotters::style::RGBColor;
use std::panic::AssertUnwindSafe;
use std::path::Path;
use std::time::Instant;
use training::training_curves;

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

/// Writes every figure of a comparison into `dir`, from the loaded `dataset` (raw forces),
/// its `prepared` set, the `trained` variants, their test `report` and their whole-run
/// `predictions` (for the runs [`loop_requests`] names). Figures of variants that were not
/// trained are left out; a figure that cannot be drawn is skipped with a warning on stderr.
/// Errors only on I/O failures.
pub fn write_all(
    trained: &[TrainedVariant],
    dataset: &Dataset,
    prepared: &Prepared,
    report: &Report,
    predictions: &RunPredictions,
    dir: &Path,
) -> Result<()> {
    let t0 = Instant::now();
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let ctx = Ctx {
        trained,
        dataset,
        prepared,
        report,
        predictions,
        picks: LoopPicks::of(prepared),
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

/// What every figure builder reads.
struct Ctx<'a> {
    trained: &'a [TrainedVariant],
    dataset: &'a Dataset,
    prepared: &'a Prepared,
    report: &'a Report,
    predictions: &'a RunPredictions,
    /// The runs of the loop figures.
    picks: LoopPicks,
}

impl Ctx<'_> {
    fn variant(&self, v: Variant) -> Option<&TrainedVariant> {
        self.trained.iter().find(|t| t.variant == v)
    }

    fn force_scale(&self) -> f64 {
        self.prepared.scales.force_n
    }
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

/// Smallest and largest finite value.
fn value_range(it: impl Iterator<Item = f64>) -> (f64, f64) {
    it.filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        })
}
