//! The learned-coefficient figures: `b_fl(v_st, alpha)` (Figs. 8-10), `b_pr(alpha)`
//! (Fig. 11) and `k_pr(x_pr, alpha)` (Fig. 12): maps on the audit grid with their
//! monotonicity violations, and cuts.

use super::{
    linspace, num, sym_range, value_range, variant_color, Ctx, Drawn, CUT_VELOCITY_M_S,
    MEASURED_GREY, VIOLATION_DOT,
};
use crate::bench::reference::{Coefficient, EmmReference};
use crate::report::plot::{
    nice_levels, palette, ColorMap, Figure, HeatmapPanel, LegendPosition, LinePanel, Series,
};
use crate::train::physics::{violation, AUDIT_GRID};
use crate::train::pipeline::{TrainedVariant, VariantInfo};
use anyhow::{bail, Result};
use nemm_core::{EmmConstants, Model, ModelKind};
use plotters::style::RGBColor;

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
    crate::data::dataset::ConditionSpec::from_core(&m.condition).axis_label()
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

pub(super) fn fig_b_fl(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
    let m = &tv.model;
    let e = emm_constants(tv)?;
    let vs = f64::from(m.scales.velocity_m_s);
    let b0 = f64::from(e.b_fl_ns_per_m);
    let g = grid_2d(&|v, a| m.b_fl(v, a), m.scales.velocity_m_s, e.b_fl_ns_per_m);
    let v_lim = 1.2 * vs;
    let vc = cut_velocity(vs);
    let v_axis = linspace(-v_lim, v_lim, 481);
    let cuts = state_cuts(
        &cut_alphas(ctx, m),
        &v_axis,
        |v, a| b_fl_at(m, v, a),
        |v, b| b * v,
    );
    let title = format!(
        "Figs. 8-10: flow damping b_fl(v_st, α) of {} (b_fl,ini = {} N s/m, v_scale = {} m/s)",
        tv.variant.title(),
        num(b0),
        num(vs)
    );
    Ok(map_and_cuts(
        title,
        b_fl_map(ctx, m, &g, vs),
        [
            b_fl_over_alpha(ctx, tv, vc, b0),
            b_fl_over_velocity(ctx.reference, &cuts, &v_axis, vs, b0),
            flow_force(ctx, &cuts, vs, b0),
        ],
        b_fl_footer(ctx.reference, m, vc),
    ))
}

/// Velocity of the paper's Fig. 10 B cut, or half the training range when that is beyond the
/// map (`1.2 vs`).
fn cut_velocity(vs: f64) -> f64 {
    if CUT_VELOCITY_M_S <= 1.2 * vs {
        CUT_VELOCITY_M_S
    } else {
        0.5 * vs
    }
}

/// Panel A: the `b_fl` map with the quasi-static training points (white dots) and the
/// training velocity range `±vs`.
fn b_fl_map(ctx: &Ctx<'_>, m: &Model, g: &Grid2, vs: f64) -> HeatmapPanel {
    let v_lim = 1.2 * vs;
    let qs: Vec<(f64, f64)> = ctx
        .prepared
        .quasi_static
        .train
        .iter()
        .map(|p| (p.velocity_m_s, p.alpha))
        .filter(|p| p.0.abs() <= v_lim)
        .collect();
    let map = CoefficientMap {
        grid: g,
        name: "A: b_fl(v_st, α)",
        state: "v",
        state_label: "quasi-static velocity v_st [m/s]",
        x: g.state.clone(),
        z: g.value.clone(),
        z_label: "b_fl [N s/m]".into(),
        range: vs,
    }
    .panel(alpha_axis(m));
    if qs.is_empty() {
        map
    } else {
        map.with_overlay(Series::dots("", qs, RGBColor(255, 255, 255)))
    }
}

/// Panel B: `b_fl` over alpha at `v_st = -vc` (the paper's cut), zoomed, with the bench's
/// quasi-static `b_fl` and the violations of eq. 31.
fn b_fl_over_alpha(ctx: &Ctx<'_>, tv: &TrainedVariant, vc: f64, b0: f64) -> LinePanel {
    let m = &tv.model;
    let a_max = f64::from(m.meta.alpha_max);
    let at = |a: f64| b_fl_at(m, -vc, a);
    let comp = over_alpha(at);
    let (ylo, yhi) = value_range(comp.iter().map(|p| p.1));
    let mut pb = LinePanel::new(
        format!(
            "B: b_fl at v_st = -{} m/s: {} from α = 0 to {}",
            num(vc),
            rel_change(at(0.0), at(a_max)),
            num(a_max)
        ),
        alpha_axis(m),
        "b_fl [N s/m]",
    )
    .with_legend(LegendPosition::LowerLeft)
    .with_series(Series::line(
        format!("b_fl(v_st = -{} m/s, α)", num(vc)),
        comp.clone(),
        variant_color(tv.variant),
    ));
    if a_max > 0.0 && ylo.is_finite() {
        pb = pb.with_series(max_training_alpha(a_max, ylo, yhi));
    }
    if let Some(r) = ctx.reference {
        pb = pb.with_series(Series::dashed(
            "bench: quasi-static b_fl (scaled to α = 0)",
            scaled_reference(r, Coefficient::BFl(-vc), at(0.0)),
            REFERENCE_BLACK,
        ));
    }
    with_violations(
        pb,
        "db_fl/dα > 0 (eq. 31)",
        curve_violations(&comp, false, 1.0, b0),
    )
}

/// Panel C: `b_fl` over velocity at the cut alphas, with the bench's quasi-static `b_fl`
/// (absolute), the Linear EMM's constant and the training range.
fn b_fl_over_velocity(
    reference: Option<&EmmReference>,
    cuts: &[StateCut],
    v_axis: &[f64],
    vs: f64,
    b0: f64,
) -> LinePanel {
    let v_lim = 1.2 * vs;
    let mut b_max = cuts
        .iter()
        .flat_map(|c| c.coefficient.iter().map(|p| p.1))
        .filter(|v| v.is_finite())
        .fold(b0, f64::max);
    let mut pc = LinePanel::new(
        "C: b_fl over velocity (dashes: training range)",
        "quasi-static velocity v_st [m/s]",
        "b_fl [N s/m]",
    )
    .with_legend(LegendPosition::LowerRight);
    for c in cuts {
        pc = pc.with_series(Series::line(c.name.clone(), c.coefficient.clone(), c.color));
    }
    if let Some(r) = reference {
        // Absolute: b_fl is regressed on the quasi-static force, which the bench knows.
        let pts: Vec<(f64, f64)> = v_axis
            .iter()
            .filter(|v| v.abs() >= 0.02 * v_lim)
            .map(|&v| (v, crate::bench::reference::b_fl(r.bench(), v, 0.0)))
            .collect();
        b_max = pts
            .iter()
            .map(|p| p.1)
            .filter(|v| v.is_finite())
            .fold(b_max, f64::max);
        pc = pc.with_series(Series::dashed(
            "bench: quasi-static b_fl at α = 0 (absolute)",
            pts,
            REFERENCE_BLACK,
        ));
    }
    pc = pc
        .with_series(Series::dashed(
            "b_fl,ini (Linear EMM constant)",
            vec![(-v_lim, b0), (v_lim, b0)],
            MEASURED_GREY,
        ))
        .with_y_range(0.0, 1.12 * b_max);
    with_range_lines(pc, vs, 0.0, 1.12 * b_max)
}

/// Panel D: the flow force `F_fl = b_fl v_st` at the cut alphas, with every quasi-static
/// point of the split, the training range and the violations of eq. 30.
fn flow_force(ctx: &Ctx<'_>, cuts: &[StateCut], vs: f64, b0: f64) -> LinePanel {
    let v_lim = 1.2 * vs;
    let mut pd = LinePanel::new(
        "D: flow force F_fl = b_fl v_st",
        "quasi-static velocity v_st [m/s]",
        "F_fl [N]",
    )
    .with_legend(LegendPosition::UpperLeft)
    .with_zero_lines();
    let mut f_all: Vec<f64> = cuts
        .iter()
        .flat_map(|c| c.force.iter().map(|p| p.1))
        .collect();
    for c in cuts {
        pd = pd.with_series(Series::line(c.name.clone(), c.force.clone(), c.color));
    }
    let qs = &ctx.prepared.quasi_static;
    let qs_all: Vec<(f64, f64)> = qs
        .train
        .iter()
        .chain(&qs.validation)
        .chain(&qs.test)
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
    pd = with_range_lines(pd, vs, flo, fhi);
    with_violations(
        pd,
        "dF_fl/dv < 0 (eq. 30)",
        force_violations(cuts, vs, b0 * vs),
    )
}

/// The caption of Figs. 8-10, with the bench's change of `b_fl(±vc)` when there is a
/// reference.
fn b_fl_footer(reference: Option<&EmmReference>, m: &Model, vc: f64) -> String {
    let mut footer = format!(
        "A: b_fl on the audit grid ({} x {}: v_st in ±1.2 v_scale, α in [0, 1]); thin black lines: iso-lines. \
         Yellow cells: monotonicity violations, eq. 30 (d(b_fl v)/dv < 0)\n\
         or eq. 31 (db_fl/dα > 0), beyond f32 rounding; white dots: quasi-static training points \
         (eq. 41); white dashes: training velocity range ±v_scale.\n\
         B-D: cuts through the map; yellow dots: violations along a cut; α above {} is extrapolation.",
        AUDIT_GRID.0,
        AUDIT_GRID.1,
        num(f64::from(m.meta.alpha_max))
    );
    if let Some(r) = reference {
        let a1 = crate::report::reference::comparison_alpha(m, r);
        let pairs: Vec<(String, f64, f64, Coefficient)> = [-vc, vc]
            .iter()
            .map(|&v| {
                (
                    format!("b_fl({} m/s)", num(v)),
                    b_fl_at(m, v, 0.0),
                    b_fl_at(m, v, a1),
                    Coefficient::BFl(v),
                )
            })
            .collect();
        let pairs: Vec<(&str, f64, f64, Coefficient)> = pairs
            .iter()
            .map(|(n, a, b, c)| (n.as_str(), *a, *b, *c))
            .collect();
        footer.push('\n');
        footer.push_str(&reference_line(r, &pairs, a1));
    }
    footer
}

// ---------------------------------------------------------------------------------------------
// Fig. 11: b_pr
// ---------------------------------------------------------------------------------------------

pub(super) fn fig11_b_pr(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
    let m = &tv.model;
    let e = emm_constants(tv)?;
    let curve = over_alpha(|a| b_pr_at(m, a));
    let ref0 = b_pr_at(m, 0.0);
    let reference = ctx
        .reference
        .map(|r| scaled_reference(r, Coefficient::BPrDescribing, ref0));
    let fig = Figure::new(1, 2)
        .with_panel_size(680, 480)
        .with_title("Fig. 11: pressure-force damping b_pr(α) of the NEMM")
        .with_panel(b_pr_panel(
            m,
            &curve,
            reference.as_deref(),
            f64::from(e.b_pr_ns_per_m),
        ))
        .with_panel(b_pr_change(
            m,
            &curve,
            reference.as_deref(),
            b_pr_violations(m, e.b_pr_ns_per_m, ref0),
        ))
        .with_footer(b_pr_footer(ctx.reference, m));
    Ok(Drawn::Figure(Box::new(fig)))
}

/// Violations of eq. 38 on the audit's alpha grid, at their change relative to `b_pr(0) =
/// ref0` in percent; `b0` is the Linear EMM's constant `b_pr,ini`.
fn b_pr_violations(m: &Model, b0: f32, ref0: f64) -> Vec<(f64, f64)> {
    let al = linspace_f32(0.0, 1.0, AUDIT_GRID.1);
    let da = f64::from(al[1] - al[0]);
    let s: Vec<f64> = al
        .iter()
        .map(|&a| m.b_pr(a).map_or(f64::NAN, |p| f64::from(p / b0)))
        .collect();
    (0..al.len() - 1)
        .filter(|&i| violation(s[i], s[i + 1], da, false).is_some())
        .map(|i| {
            (
                f64::from(al[i]),
                100.0 * (s[i] * f64::from(b0) / ref0 - 1.0),
            )
        })
        .collect()
}

/// `(alpha, 100 (b / b(0) - 1))`: a curve as percent change relative to `ref0 = b(0)`.
fn percent_change(curve: &[(f64, f64)], ref0: f64) -> Vec<(f64, f64)> {
    curve
        .iter()
        .map(|&(a, b)| (a, 100.0 * (b / ref0 - 1.0)))
        .collect()
}

/// Left panel: `b_pr(alpha)` on an axis from zero with the Linear EMM's constant `b0` and the
/// bench's describing-function `b_pr` (`reference`, scaled to the model at alpha = 0).
fn b_pr_panel(
    m: &Model,
    curve: &[(f64, f64)],
    reference: Option<&[(f64, f64)]>,
    b0: f64,
) -> LinePanel {
    let a_max = f64::from(m.meta.alpha_max);
    let (_, yhi) = value_range(
        curve
            .iter()
            .chain(reference.into_iter().flatten())
            .map(|p| p.1)
            .chain([b0]),
    );
    let y_top = 1.15 * yhi;
    let mut pa = LinePanel::new(
        format!(
            "b_pr(α): {} → {} N s/m from α = 0 to {}",
            num(b_pr_at(m, 0.0)),
            num(b_pr_at(m, a_max)),
            num(a_max)
        ),
        alpha_axis(m),
        "b_pr [N s/m]",
    )
    .with_y_range(0.0, y_top)
    .with_legend(LegendPosition::LowerLeft)
    .with_series(Series::line(
        "b_pr(α) (NEMM)",
        curve.to_vec(),
        variant_color(ModelKind::Nemm),
    ))
    .with_series(Series::dashed(
        "b_pr,ini (Linear EMM constant)",
        vec![(0.0, b0), (1.0, b0)],
        MEASURED_GREY,
    ));
    if let Some(abs) = reference {
        pa = pa.with_series(Series::dashed(
            B_PR_REFERENCE_LABEL,
            abs.to_vec(),
            REFERENCE_BLACK,
        ));
    }
    pa.reference_y.push(0.0);
    if a_max > 0.0 {
        pa = pa.with_series(max_training_alpha(a_max, 0.0, y_top));
    }
    pa
}

/// Legend label of the bench's `b_pr` on Fig. 11.
const B_PR_REFERENCE_LABEL: &str = "bench: describing-function b_pr (scaled to α = 0)";

/// Right panel: the same as change relative to alpha = 0, zoomed, with the violations of
/// eq. 38 (`viol`).
fn b_pr_change(
    m: &Model,
    curve: &[(f64, f64)],
    reference: Option<&[(f64, f64)]>,
    viol: Vec<(f64, f64)>,
) -> LinePanel {
    let a_max = f64::from(m.meta.alpha_max);
    let ref0 = b_pr_at(m, 0.0);
    let rel = percent_change(curve, ref0);
    let ref_rel = reference.map(|c| percent_change(c, ref0));
    let (rlo, rhi) = value_range(rel.iter().chain(ref_rel.iter().flatten()).map(|p| p.1));
    let mut pb = LinePanel::new(
        format!(
            "change relative to α = 0: {} at α = {}; {}",
            rel_change(ref0, b_pr_at(m, a_max)),
            num(a_max),
            if viol.is_empty() {
                "no violations".to_string()
            } else {
                format!("{} violations of eq. 38", viol.len())
            }
        ),
        alpha_axis(m),
        "b_pr(α) / b_pr(0) - 1 [%]",
    )
    .with_legend(LegendPosition::LowerLeft)
    .with_series(Series::line(
        "b_pr(α) / b_pr(0) - 1",
        rel,
        variant_color(ModelKind::Nemm),
    ));
    if let Some(rel) = ref_rel {
        pb = pb.with_series(Series::dashed(B_PR_REFERENCE_LABEL, rel, REFERENCE_BLACK));
    }
    pb.reference_y.push(0.0);
    if a_max > 0.0 && rlo.is_finite() {
        pb = pb.with_series(max_training_alpha(a_max, rlo.min(0.0), rhi.max(0.0)));
    }
    with_violations(pb, "db_pr/dα > 0 (eq. 38)", viol)
}

/// The caption of Fig. 11, with the bench's change of `b_pr` when there is a reference.
fn b_pr_footer(reference: Option<&EmmReference>, m: &Model) -> String {
    let mut footer = format!(
        "Left: b_pr on an axis from zero with the Linear EMM's constant; right: the same, zoomed, as change relative to α = 0.\n\
         Yellow dots: grid intervals (audit grid, {} values of α) where b_pr breaks its declared prior in α (eq. 38); α above {} is extrapolation.",
        AUDIT_GRID.1,
        num(f64::from(m.meta.alpha_max))
    );
    if let Some(r) = reference {
        let a1 = crate::report::reference::comparison_alpha(m, r);
        footer.push('\n');
        footer.push_str(&reference_line(
            r,
            &[(
                "b_pr",
                b_pr_at(m, 0.0),
                b_pr_at(m, a1),
                Coefficient::BPrDescribing,
            )],
            a1,
        ));
    }
    footer
}

// ---------------------------------------------------------------------------------------------
// Fig. 12: k_pr
// ---------------------------------------------------------------------------------------------

/// The `k_pr` reference curves of the bench on Fig. 12 (colours [`REFERENCE_K_COLORS`]).
const K_PR_REFERENCES: [Coefficient; 4] = [
    Coefficient::KPrCombined,
    Coefficient::KPrCompression,
    Coefficient::KPrRebound,
    Coefficient::KPrDescribing,
];

/// Display unit of a stiffness: factor from N/m and name.
type StiffnessUnit = (f64, &'static str);

/// N/m, or kN/m when a value of the map or `k0` reaches 1e5 N/m (where ticks would need
/// exponents).
fn stiffness_unit(g: &Grid2, k0: f64) -> StiffnessUnit {
    let kilo = g
        .value
        .iter()
        .flatten()
        .chain(std::iter::once(&k0))
        .any(|v| v.abs() >= 1e5);
    if kilo {
        (1e-3, "kN/m")
    } else {
        (1.0, "N/m")
    }
}

pub(super) fn fig12_k_pr(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
    let m = &tv.model;
    let e = emm_constants(tv)?;
    let xs = f64::from(m.scales.x_pr_m);
    let k0 = f64::from(e.k_pr_n_per_m);
    let g = grid_2d(&|x, a| m.k_pr(x, a), m.scales.x_pr_m, e.k_pr_n_per_m);
    // Display units: mm and N/m or kN/m.
    let unit = stiffness_unit(&g, k0);
    let (ku, kname) = unit;
    let xmm = xs * 1e3;
    let x_lim = 1.2 * xmm;
    let map = CoefficientMap {
        grid: &g,
        name: "A: k_pr(x_pr, α)",
        state: "x_pr",
        state_label: "valve deflection x_pr [mm]",
        x: g.state.iter().map(|x| x * 1e3).collect(),
        z: g.value
            .iter()
            .map(|r| r.iter().map(|v| v * ku).collect())
            .collect(),
        z_label: format!("k_pr [{kname}]"),
        range: xmm,
    }
    .panel(alpha_axis(m));
    let x_axis = linspace(-x_lim, x_lim, 481);
    let cuts = state_cuts(
        &cut_alphas(ctx, m),
        &x_axis,
        |x, a| k_pr_at(m, x * 1e-3, a),
        |x, k| k * x * 1e-3,
    );
    let title = format!(
        "Fig. 12: pressure-force stiffness k_pr(x_pr, α) of the NEMM (k_pr,ini = {} {kname}, x_scale = {} mm)",
        num(k0 * ku),
        num(xmm)
    );
    Ok(map_and_cuts(
        title,
        map,
        [
            k_pr_over_deflection(&cuts, unit),
            spring_force(&cuts, xmm, k0 * xs),
            k_pr_over_alpha(ctx.reference, m, k0, unit),
        ],
        k_pr_footer(ctx.reference, m),
    ))
}

/// Panel B: `k_pr` over the valve deflection at the cut alphas.
fn k_pr_over_deflection(cuts: &[StateCut], (ku, kname): StiffnessUnit) -> LinePanel {
    let mut pb = LinePanel::new(
        "B: k_pr over deflection",
        "valve deflection x_pr [mm]",
        format!("k_pr [{kname}]"),
    )
    .with_legend(LegendPosition::UpperRight);
    for c in cuts {
        pb = pb.with_series(Series::line(
            c.name.clone(),
            c.coefficient.iter().map(|&(x, k)| (x, k * ku)).collect(),
            c.color,
        ));
    }
    pb
}

/// Panel C: the spring force `F = k_pr x_pr` at the cut alphas, with the violations of eq. 37
/// (deflection normalised by `xmm`, force by `f_norm`).
fn spring_force(cuts: &[StateCut], xmm: f64, f_norm: f64) -> LinePanel {
    let mut pc = LinePanel::new(
        "C: spring force F = k_pr x_pr",
        "valve deflection x_pr [mm]",
        "F [N]",
    )
    .with_legend(LegendPosition::UpperLeft)
    .with_zero_lines();
    for c in cuts {
        pc = pc.with_series(Series::line(c.name.clone(), c.force.clone(), c.color));
    }
    with_violations(
        pc,
        "dF/dx_pr < 0 (eq. 37)",
        force_violations(cuts, xmm, f_norm),
    )
}

/// Panel D: `k_pr` over alpha at `x_pr` = 0, half and all of `x_scale`, with the bench's
/// stiffnesses (scaled to the model at alpha = 0) and the violations of eq. 38.
fn k_pr_over_alpha(
    reference: Option<&EmmReference>,
    m: &Model,
    k0: f64,
    (ku, kname): StiffnessUnit,
) -> LinePanel {
    let xs = f64::from(m.scales.x_pr_m);
    let a_max = f64::from(m.meta.alpha_max);
    let at0 = |a: f64| k_pr_at(m, 0.0, a);
    let mut pd = LinePanel::new(
        format!(
            "D: k_pr over α; at x_pr = 0: {} from α = 0 to {}",
            rel_change(at0(0.0), at0(a_max)),
            num(a_max)
        ),
        alpha_axis(m),
        format!("k_pr [{kname}]"),
    )
    .with_legend(LegendPosition::LowerLeft);
    let mut d_viol = Vec::new();
    let mut d_all = Vec::new();
    for (i, frac) in [0.0, 0.5, 1.0].iter().enumerate() {
        let x = frac * xs;
        let c = over_alpha(|a| k_pr_at(m, x, a));
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
    if let Some(r) = reference {
        for (c, color) in K_PR_REFERENCES.iter().zip(REFERENCE_K_COLORS) {
            let pts: Vec<(f64, f64)> = scaled_reference(r, *c, at0(0.0))
                .into_iter()
                .map(|(a, k)| (a, k * ku))
                .collect();
            d_all.extend(pts.iter().map(|p| p.1));
            pd = pd.with_series(Series::dashed(format!("bench: {}", c.name()), pts, color));
        }
    }
    let (dlo, dhi) = value_range(d_all.into_iter());
    if a_max > 0.0 && dlo.is_finite() {
        pd = pd.with_series(max_training_alpha(a_max, dlo, dhi));
    }
    with_violations(pd, "dk_pr/dα > 0 (eq. 38)", d_viol)
}

/// The caption of Fig. 12, with the bench's change of `k_pr(x_pr = 0)` when there is a
/// reference.
fn k_pr_footer(reference: Option<&EmmReference>, m: &Model) -> String {
    let at0 = |a: f64| k_pr_at(m, 0.0, a);
    let mut footer = format!(
        "A: k_pr on the audit grid ({} x {}: x_pr in ±1.2 x_scale, α in [0, 1]); thin black lines: iso-lines. \
         Yellow cells: monotonicity violations, eq. 37 (d(k_pr x_pr)/dx_pr < 0)\n\
         or eq. 38 (dk_pr/dα > 0), beyond f32 rounding; white dashes: the range of x_pr reached \
         on the training data (±x_scale).\n\
         B-D: cuts through the map (B and D zoomed: read the values); yellow dots: violations along a cut; \
         α above {} is extrapolation.",
        AUDIT_GRID.0,
        AUDIT_GRID.1,
        num(f64::from(m.meta.alpha_max))
    );
    if let Some(r) = reference {
        let a1 = crate::report::reference::comparison_alpha(m, r);
        let pairs: Vec<(&str, f64, f64, Coefficient)> = K_PR_REFERENCES
            .iter()
            .map(|c| ("k_pr(x_pr = 0)", at0(0.0), at0(a1), *c))
            .collect();
        footer.push('\n');
        footer.push_str(&reference_line(r, &pairs, a1));
    }
    footer
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
