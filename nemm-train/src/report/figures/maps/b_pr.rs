//! Fig. 11: the learned pressure damping `b_pr(alpha)`.

use super::{
    alpha_axis, b_pr_at, emm_constants, linspace_f32, max_training_alpha, num, over_alpha,
    reference_line, rel_change, scaled_reference, value_range, variant_color, violation,
    with_violations, Coefficient, Ctx, Drawn, EmmReference, Figure, LegendPosition, LinePanel,
    Series, TrainedVariant, AUDIT_GRID, MEASURED_GREY, REFERENCE_BLACK,
};
use anyhow::Result;
use nemm_core::{Model, ModelKind};

pub(in crate::report::figures) fn fig11_b_pr(ctx: &Ctx<'_>, tv: &TrainedVariant) -> Result<Drawn> {
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
pub(super) fn b_pr_violations(m: &Model, b0: f32, ref0: f64) -> Vec<(f64, f64)> {
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
pub(super) fn percent_change(curve: &[(f64, f64)], ref0: f64) -> Vec<(f64, f64)> {
    curve
        .iter()
        .map(|&(a, b)| (a, 100.0 * (b / ref0 - 1.0)))
        .collect()
}

/// Left panel: `b_pr(alpha)` on an axis from zero with the Linear EMM's constant `b0` and the
/// bench's describing-function `b_pr` (`reference`, scaled to the model at alpha = 0).
pub(super) fn b_pr_panel(
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
pub(super) const B_PR_REFERENCE_LABEL: &str = "bench: describing-function b_pr (scaled to α = 0)";

/// Right panel: the same as change relative to alpha = 0, zoomed, with the violations of
/// eq. 38 (`viol`).
pub(super) fn b_pr_change(
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
pub(super) fn b_pr_footer(reference: Option<&EmmReference>, m: &Model) -> String {
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
