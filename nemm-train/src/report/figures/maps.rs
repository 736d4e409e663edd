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
use nemm_core::Model;
use nemm_core::ModelKind;
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
// Figs. 8-10: b_fl
// ---------------------------------------------------------------------------------------------

pub(super) fn fig_b_fl(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
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
        alpha_axis(m),
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
        pb = pb.with_series(
            Series::dashed("max. training α", vline(a_max, ylo, yhi), MEASURED_GREY).with_width(1),
        );
    }
    let reference = ctx.reference;
    let ref_a1 = reference.map(|r| crate::report::reference::comparison_alpha(m, r));
    if let Some(r) = reference {
        pb = pb.with_series(Series::dashed(
            "bench: quasi-static b_fl (scaled to α = 0)",
            scaled_reference(r, Coefficient::BFl(-vc), at(0.0)),
            REFERENCE_BLACK,
        ));
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
    let mut footer = format!(
        "A: b_fl on the audit grid ({} x {}: v_st in ±1.2 v_scale, α in [0, 1]); thin black lines: iso-lines. \
         Yellow cells: monotonicity violations, eq. 30 (d(b_fl v)/dv < 0)\n\
         or eq. 31 (db_fl/dα > 0), beyond f32 rounding; white dots: quasi-static training points \
         (eq. 41); white dashes: training velocity range ±v_scale.\n\
         B-D: cuts through the map; yellow dots: violations along a cut; α above {} is extrapolation.",
        AUDIT_GRID.0,
        AUDIT_GRID.1,
        num(a_max)
    );
    if let (Some(r), Some(a1)) = (reference, ref_a1) {
        let pairs: Vec<(String, f64, f64, Coefficient)> = [-vc, vc]
            .iter()
            .map(|&v| {
                let f = |a: f64| m.b_fl(v as f32, a as f32).map_or(f64::NAN, f64::from);
                (
                    format!("b_fl({} m/s)", num(v)),
                    f(0.0),
                    f(a1),
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
        .with_footer(footer);
    Ok(Drawn::Figure(Box::new(fig)))
}

// ---------------------------------------------------------------------------------------------
// Fig. 11: b_pr
// ---------------------------------------------------------------------------------------------

pub(super) fn fig11_b_pr(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
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
    let reference = ctx.reference;
    let ref_abs = reference.map(|r| scaled_reference(r, Coefficient::BPrDescribing, ref0));
    let ref_rel: Option<Vec<(f64, f64)>> = ref_abs.as_ref().map(|c| {
        c.iter()
            .map(|&(a, b)| (a, 100.0 * (b / ref0 - 1.0)))
            .collect()
    });
    let (_, yhi) = value_range(
        curve
            .iter()
            .chain(ref_abs.iter().flatten())
            .map(|p| p.1)
            .chain([b0]),
    );
    let y_top = 1.15 * yhi;
    let mut pa = LinePanel::new(
        format!(
            "b_pr(α): {} → {} N s/m from α = 0 to {}",
            num(ref0),
            num(at(a_max)),
            num(a_max)
        ),
        alpha_axis(m),
        "b_pr [N s/m]",
    )
    .with_y_range(0.0, y_top)
    .with_legend(LegendPosition::LowerLeft)
    .with_series(Series::line(
        "b_pr(α) (NEMM)",
        curve.clone(),
        variant_color(ModelKind::Nemm),
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
    let (rlo, rhi) = value_range(rel.iter().chain(ref_rel.iter().flatten()).map(|p| p.1));
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
        alpha_axis(m),
        "b_pr(α) / b_pr(0) - 1 [%]",
    )
    .with_legend(LegendPosition::LowerLeft)
    .with_series(Series::line(
        "b_pr(α) / b_pr(0) - 1",
        rel,
        variant_color(ModelKind::Nemm),
    ));
    if let (Some(abs), Some(rel)) = (ref_abs, ref_rel) {
        let label = "bench: describing-function b_pr (scaled to α = 0)";
        pa = pa.with_series(Series::dashed(label, abs, REFERENCE_BLACK));
        pb = pb.with_series(Series::dashed(label, rel, REFERENCE_BLACK));
    }
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
    let mut footer = format!(
        "Left: b_pr on an axis from zero with the Linear EMM's constant; right: the same, zoomed, as change relative to α = 0.\n\
         Yellow dots: grid intervals (audit grid, {} values of α) where b_pr breaks its declared prior in α (eq. 38); α above {} is extrapolation.",
        AUDIT_GRID.1,
        num(a_max)
    );
    if let Some(r) = reference {
        let a1 = crate::report::reference::comparison_alpha(m, r);
        footer.push('\n');
        footer.push_str(&reference_line(
            r,
            &[("b_pr", ref0, at(a1), Coefficient::BPrDescribing)],
            a1,
        ));
    }
    let fig = Figure::new(1, 2)
        .with_panel_size(680, 480)
        .with_title("Fig. 11: pressure-force damping b_pr(α) of the NEMM")
        .with_panel(pa)
        .with_panel(pb)
        .with_footer(footer);
    Ok(Drawn::Figure(Box::new(fig)))
}

// ---------------------------------------------------------------------------------------------
// Fig. 12: k_pr
// ---------------------------------------------------------------------------------------------

pub(super) fn fig12_k_pr(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
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
        alpha_axis(m),
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
    let reference = ctx.reference;
    let k_ref = [
        Coefficient::KPrCombined,
        Coefficient::KPrCompression,
        Coefficient::KPrRebound,
        Coefficient::KPrDescribing,
    ];
    if let Some(r) = reference {
        for (c, color) in k_ref.iter().zip(REFERENCE_K_COLORS) {
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
        pd = pd.with_series(
            Series::dashed("max. training α", vline(a_max, dlo, dhi), MEASURED_GREY).with_width(1),
        );
    }
    if !d_viol.is_empty() {
        pd = pd.with_series(
            Series::dots("dk_pr/dα > 0 (eq. 38)", d_viol, VIOLATION_DOT).with_width(3),
        );
    }
    let mut footer = format!(
        "A: k_pr on the audit grid ({} x {}: x_pr in ±1.2 x_scale, α in [0, 1]); thin black lines: iso-lines. \
         Yellow cells: monotonicity violations, eq. 37 (d(k_pr x_pr)/dx_pr < 0)\n\
         or eq. 38 (dk_pr/dα > 0), beyond f32 rounding; white dashes: the range of x_pr reached \
         on the training data (±x_scale).\n\
         B-D: cuts through the map (B and D zoomed: read the values); yellow dots: violations along a cut; \
         α above {} is extrapolation.",
        AUDIT_GRID.0,
        AUDIT_GRID.1,
        num(a_max)
    );
    if let Some(r) = reference {
        let a1 = crate::report::reference::comparison_alpha(m, r);
        let pairs: Vec<(&str, f64, f64, Coefficient)> = k_ref
            .iter()
            .map(|c| ("k_pr(x_pr = 0)", at0(0.0), at0(a1), *c))
            .collect();
        footer.push('\n');
        footer.push_str(&reference_line(r, &pairs, a1));
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
        .with_footer(footer);
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
