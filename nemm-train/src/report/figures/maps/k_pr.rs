//! Fig. 12: the learned pressure stiffness `k_pr(x_pr, alpha)`.

use super::{
    alpha_axis, curve_violations, cut_alphas, emm_constants, force_violations, grid_2d, k_pr_at,
    linspace, map_and_cuts, max_training_alpha, num, over_alpha, palette, reference_line,
    rel_change, scaled_reference, state_cuts, value_range, with_violations, Coefficient,
    CoefficientMap, Ctx, Drawn, EmmReference, Grid2, LegendPosition, LinePanel, Series, StateCut,
    TrainedVariant, AUDIT_GRID, REFERENCE_K_COLORS,
};
use anyhow::Result;
use nemm_core::Model;

/// The `k_pr` reference curves of the bench on Fig. 12 (colours [`REFERENCE_K_COLORS`]).
pub(super) const K_PR_REFERENCES: [Coefficient; 4] = [
    Coefficient::KPrCombined,
    Coefficient::KPrCompression,
    Coefficient::KPrRebound,
    Coefficient::KPrDescribing,
];

/// Display unit of a stiffness: factor from N/m and name.
pub(super) type StiffnessUnit = (f64, &'static str);

/// N/m, or kN/m when a value of the map or `k0` reaches 1e5 N/m (where ticks would need
/// exponents).
pub(super) fn stiffness_unit(g: &Grid2, k0: f64) -> StiffnessUnit {
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

pub(in crate::report::figures) fn fig12_k_pr(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
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
pub(super) fn k_pr_over_deflection(cuts: &[StateCut], (ku, kname): StiffnessUnit) -> LinePanel {
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
pub(super) fn spring_force(cuts: &[StateCut], xmm: f64, f_norm: f64) -> LinePanel {
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
pub(super) fn k_pr_over_alpha(
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
pub(super) fn k_pr_footer(reference: Option<&EmmReference>, m: &Model) -> String {
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
