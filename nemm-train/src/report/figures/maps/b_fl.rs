//! Figs. 8-10: the learned flow damping `b_fl(v_st, alpha)`.

use super::{
    alpha_axis, b_fl_at, curve_violations, cut_alphas, emm_constants, force_violations, grid_2d,
    linspace, map_and_cuts, max_training_alpha, num, over_alpha, reference_line, rel_change,
    scaled_reference, state_cuts, sym_range, value_range, variant_color, with_range_lines,
    with_violations, Coefficient, CoefficientMap, Ctx, Drawn, EmmReference, Grid2, HeatmapPanel,
    LegendPosition, LinePanel, Series, StateCut, TrainedVariant, VariantInfo, AUDIT_GRID,
    CUT_VELOCITY_M_S, MEASURED_GREY, REFERENCE_BLACK,
};
use anyhow::Result;
use nemm_core::Model;
use plotters::style::RGBColor;

pub(in crate::report::figures) fn fig_b_fl(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
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
pub(super) fn cut_velocity(vs: f64) -> f64 {
    if CUT_VELOCITY_M_S <= 1.2 * vs {
        CUT_VELOCITY_M_S
    } else {
        0.5 * vs
    }
}

/// Panel A: the `b_fl` map with the quasi-static training points (white dots) and the
/// training velocity range `±vs`.
pub(super) fn b_fl_map(ctx: &Ctx<'_>, m: &Model, g: &Grid2, vs: f64) -> HeatmapPanel {
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
pub(super) fn b_fl_over_alpha(ctx: &Ctx<'_>, tv: &TrainedVariant, vc: f64, b0: f64) -> LinePanel {
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
pub(super) fn b_fl_over_velocity(
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
            .map(|&v| (v, nemm_virtual_bench::reference::b_fl(r.bench(), v, 0.0)))
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
pub(super) fn flow_force(ctx: &Ctx<'_>, cuts: &[StateCut], vs: f64, b0: f64) -> LinePanel {
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
pub(super) fn b_fl_footer(reference: Option<&EmmReference>, m: &Model, vc: f64) -> String {
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
