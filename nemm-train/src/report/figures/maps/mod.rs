//! The learned-coefficient figures: `b_fl(v_st, alpha)` (Figs. 8-10), `b_pr(alpha)`
//! (Fig. 11) and `k_pr(x_pr, alpha)` (Fig. 12): maps on the audit grid with their
//! monotonicity violations, and cuts.

use super::{
    linspace, num, sym_range, value_range, variant_color, Ctx, Drawn, CUT_VELOCITY_M_S,
    MEASURED_GREY, VIOLATION_DOT,
};
use crate::report::plot::{
    nice_levels, palette, ColorMap, Figure, HeatmapPanel, LegendPosition, LinePanel, Series,
};
use crate::train::physics::{violation, AUDIT_GRID};
use crate::train::pipeline::{TrainedVariant, VariantInfo};
use anyhow::{bail, Result};
use nemm_core::{EmmConstants, Model};
use nemm_virtual_bench::reference::{Coefficient, EmmReference};
use plotters::style::RGBColor;

mod b_fl;
mod b_pr;
mod k_pr;

pub(super) use b_fl::fig_b_fl;
pub(super) use b_pr::fig11_b_pr;
pub(super) use k_pr::fig12_k_pr;

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

/// The alpha axis title, named by the model's condition.
fn alpha_axis(m: &Model) -> String {
    nemm_dataset::ConditionSpec::from_core(&m.condition).axis_label()
}

fn vline(x: f64, y0: f64, y1: f64) -> Vec<(f64, f64)> {
    vec![(x, y0), (x, y1)]
}

/// Colour of the bench's reference curves.
const REFERENCE_BLACK: RGBColor = RGBColor(0, 0, 0);

/// Colours of the `k_pr` reference curves: both chambers, compression, rebound, describing
/// function.
const REFERENCE_K_COLORS: [RGBColor; 4] = [
    REFERENCE_BLACK,
    RGBColor(140, 70, 0),
    RGBColor(110, 110, 110),
    RGBColor(130, 0, 130),
];

/// The reference curve of `c` scaled to `model_at_0` at alpha = 0: `model(0) r(alpha) / r(0)`.
fn scaled_reference(r: &EmmReference, c: Coefficient, model_at_0: f64) -> Vec<(f64, f64)> {
    let pts = r.curve(c);
    let r0 = pts.first().map_or(f64::NAN, |p| p.1);
    pts.into_iter()
        .map(|(a, v)| (a, model_at_0 * v / r0))
        .collect()
}

/// Caption line comparing the learned change from alpha = 0 to `a1` with the reference's.
fn reference_line(r: &EmmReference, pairs: &[(&str, f64, f64, Coefficient)], a1: f64) -> String {
    let parts: Vec<String> = pairs
        .iter()
        .map(|(name, l0, l1, c)| {
            let rc = r
                .relative(*c, a1)
                .map_or("n/a".to_string(), |x| rel_change(1.0, 1.0 + x));
            format!(
                "{name}: learned {}, bench {} ({})",
                rel_change(*l0, *l1),
                rc,
                c.name()
            )
        })
        .collect();
    format!(
        "Dashed black/coloured: the virtual bench's equivalent coefficients (reference run {} mm, {} m/s; \
         docs/virtual-bench.md), scaled to the model at α = 0. Change from α = 0 to {}:\n{}.",
        num(r.run.amplitude_m * 1e3),
        num(r.run.peak_velocity_m_s),
        num(a1),
        parts.join(";\n")
    )
}

// ---------------------------------------------------------------------------------------------
// Shared panels: the map (A), cuts along the state, cuts along alpha
// ---------------------------------------------------------------------------------------------

/// `b_fl(v_st, alpha)` of the model (NaN where it cannot be evaluated).
fn b_fl_at(m: &Model, v: f64, a: f64) -> f64 {
    m.b_fl(v as f32, a as f32).map_or(f64::NAN, f64::from)
}

/// `b_pr(alpha)` of the model (NaN where it cannot be evaluated).
fn b_pr_at(m: &Model, a: f64) -> f64 {
    m.b_pr(a as f32).map_or(f64::NAN, f64::from)
}

/// `k_pr(x_pr, alpha)` of the model (NaN where it cannot be evaluated).
fn k_pr_at(m: &Model, x: f64, a: f64) -> f64 {
    m.k_pr(x as f32, a as f32).map_or(f64::NAN, f64::from)
}

/// The EMM constants of a trained variant (an error for a variant without them).
fn emm_constants(tv: &TrainedVariant) -> Result<&EmmConstants> {
    match tv.model.emm() {
        Some(e) => Ok(e),
        None => bail!("{} has no EMM constants", tv.variant.title()),
    }
}

/// Panel A of Figs. 8-10 and 12: a learned coefficient on the audit grid, its violating cells
/// in yellow, iso-lines, and white dashes at the edges of the training range.
struct CoefficientMap<'g> {
    /// The audit grid (alpha values, marked cells, violation counts).
    grid: &'g Grid2,
    /// Start of the caption, e.g. `A: b_fl(v_st, α)`.
    name: &'static str,
    /// The state as the violation count names it (`v`, `x_pr`).
    state: &'static str,
    /// Title of the state axis.
    state_label: &'static str,
    /// The state at the grid points, in display units.
    x: Vec<f64>,
    /// The coefficient `z[ia][ix]`, in display units.
    z: Vec<Vec<f64>>,
    /// Title of the colour bar.
    z_label: String,
    /// Edge of the training range in display units (dashes at `±range`).
    range: f64,
}

impl CoefficientMap<'_> {
    /// The heat map, with the alpha axis titled `alpha_label`.
    fn panel(self, alpha_label: String) -> HeatmapPanel {
        let g = self.grid;
        let (zlo, zhi) = value_range(self.z.iter().flatten().copied());
        let white = RGBColor(255, 255, 255);
        let mut map = HeatmapPanel::new(
            format!(
                "{}, {}; {}",
                self.name,
                spread_text(&g.value),
                violation_text(g, self.state)
            ),
            self.state_label,
            alpha_label,
            self.x,
            g.alpha.clone(),
            self.z,
        )
        .with_z_label(self.z_label)
        .with_colormap(ColorMap::Ocean)
        .with_contours(nice_levels(zlo, zhi, 8))
        .with_marks(g.mark.clone(), None)
        .with_legend(LegendPosition::None);
        for x in [-self.range, self.range] {
            map = map.with_overlay(Series::dashed("", vline(x, 0.0, 1.0), white).with_width(1));
        }
        map
    }
}

/// A coefficient along its state at one alpha of [`cut_alphas`], and the force it gives.
struct StateCut {
    /// Legend label (the alpha).
    name: String,
    /// Colour of the alpha.
    color: RGBColor,
    /// `(state, coefficient)`.
    coefficient: Vec<(f64, f64)>,
    /// `(state, force)`.
    force: Vec<(f64, f64)>,
}

/// The cuts of a coefficient `p(state, alpha)` along `axis` at each of the `alphas`
/// ([`cut_alphas`]), with the force `force(state, p)`.
fn state_cuts(
    alphas: &[(f64, String)],
    axis: &[f64],
    p: impl Fn(f64, f64) -> f64,
    force: impl Fn(f64, f64) -> f64,
) -> Vec<StateCut> {
    alphas
        .iter()
        .enumerate()
        .map(|(i, (a, name))| {
            let coefficient: Vec<(f64, f64)> = axis.iter().map(|&x| (x, p(x, *a))).collect();
            let force = coefficient.iter().map(|&(x, c)| (x, force(x, c))).collect();
            StateCut {
                name: name.clone(),
                color: alpha_color(i),
                coefficient,
                force,
            }
        })
        .collect()
}

/// Points where a cut's force falls with the state (eqs. 30, 37), with the state normalised
/// by `x_norm` and the force by `f_norm`.
fn force_violations(cuts: &[StateCut], x_norm: f64, f_norm: f64) -> Vec<(f64, f64)> {
    cuts.iter()
        .flat_map(|c| curve_violations(&c.force, true, x_norm, f_norm))
        .collect()
}

/// `(alpha, p(alpha))` at 201 points of `[0, 1]`.
fn over_alpha(p: impl Fn(f64) -> f64) -> Vec<(f64, f64)> {
    linspace(0.0, 1.0, 201)
        .into_iter()
        .map(|a| (a, p(a)))
        .collect()
}

/// The grey dashes at the largest training alpha, from `lo` to `hi`.
fn max_training_alpha(a_max: f64, lo: f64, hi: f64) -> Series {
    Series::dashed("max. training α", vline(a_max, lo, hi), MEASURED_GREY).with_width(1)
}

/// Unlabelled grey dashes at `±range` (the training range of the state), from `lo` to `hi`.
fn with_range_lines(mut panel: LinePanel, range: f64, lo: f64, hi: f64) -> LinePanel {
    for x in [-range, range] {
        panel = panel.with_series(
            Series::dashed("", vline(x, lo, hi), MEASURED_GREY)
                .with_width(1)
                .unlabelled(),
        );
    }
    panel
}

/// The violations along a cut as yellow dots labelled `label` (nothing when there are none).
fn with_violations(panel: LinePanel, label: &str, viol: Vec<(f64, f64)>) -> LinePanel {
    if viol.is_empty() {
        panel
    } else {
        panel.with_series(Series::dots(label, viol, VIOLATION_DOT).with_width(3))
    }
}

/// A figure of the map and three cuts, 2 x 2 panels of 680 x 480 pixels (Figs. 8-10, 12).
fn map_and_cuts(
    title: String,
    map: HeatmapPanel,
    [b, c, d]: [LinePanel; 3],
    footer: String,
) -> Drawn {
    let fig = Figure::new(2, 2)
        .with_panel_size(680, 480)
        .with_title(title)
        .with_panel(map)
        .with_panel(b)
        .with_panel(c)
        .with_panel(d)
        .with_footer(footer);
    Drawn::Figure(Box::new(fig))
}

// ---------------------------------------------------------------------------------------------
// Figs. 8-10: b_fl
// ---------------------------------------------------------------------------------------------

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
