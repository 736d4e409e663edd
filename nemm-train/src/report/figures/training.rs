//! The training curves: training MSE, validation RMSE and physics loss per epoch.

use super::{value_range, variant_color, Ctx, Drawn};
use crate::report::plot::{Figure, LegendPosition, LinePanel, Series};
use crate::train::pipeline::{TrainedVariant, VariantInfo};
use anyhow::Result;
use nemm_core::ModelKind;

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

pub(super) fn training_curves(ctx: &Ctx<'_>) -> Result<Drawn> {
    let with_history: Vec<&TrainedVariant> = ModelKind::ALL
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
        let pts = |f: &dyn Fn(&crate::train::history::EpochStats) -> f64| -> Vec<(f64, f64)> {
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
    if let Some(sem) = ctx.variant(ModelKind::Sem) {
        if sem.val_rmse.is_finite() && sem.val_rmse > 0.0 {
            p_val = p_val.with_series(Series::dashed(
                format!("SEM (no training): {:.4}", sem.val_rmse),
                vec![(x_range.0, sem.val_rmse), (x_range.1, sem.val_rmse)],
                variant_color(ModelKind::Sem),
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
