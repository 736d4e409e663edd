//! Table 4 / Table 5 style reports: test RMSE per variant (normalised by the training set's
//! abs-max force, and in newtons), the monotonicity audit, training facts; as `report.json`
//! and Markdown.

use crate::preprocess::Prepared;
use crate::train::eval::rmse_model;
use crate::train::fit::EpochStats;
use crate::train::physics::{audit, Audit};
use crate::train::pipeline::{TrainedVariant, Variant};
use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// Dense audit grid: states x alphas.
pub const AUDIT_GRID: (usize, usize) = (401, 101);

/// Results of one variant.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VariantReport {
    /// Test RMSE normalised by `force_scale_n` (the paper's Table 4 metric).
    pub rmse: f64,
    /// Test RMSE \[N\].
    pub rmse_n: f64,
    /// Validation RMSE (normalised) of the kept model.
    pub val_rmse: f64,
    /// Monotonicity audit of the learned scalers (eqs. 30-31, 37-38); absent for the SEM and
    /// Linear EMM.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub audit: Option<Audit>,
    /// Total violations (0 for models without learned scalers).
    pub violations: usize,
    /// Training wall time \[s\].
    pub train_seconds: f64,
    /// Epochs trained.
    pub epochs: usize,
    /// Size of the exported blob \[bytes\].
    pub blob_bytes: usize,
    /// Per-epoch history.
    #[serde(default)]
    pub history: Vec<EpochStats>,
}

/// A whole report (`report.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// Oil-loss level(s) of the test set (the first one; Table 2: 0.15).
    pub test_alpha: f64,
    /// Abs-max force of the training set \[N\].
    pub force_scale_n: f64,
    /// Per variant, keyed `sem`, `linear_emm`, `nemm_light`, `nemm`.
    pub variants: BTreeMap<String, VariantReport>,
    /// Test sequences and scored samples.
    pub test_sequences: usize,
    /// Free-form facts about the run (configuration, dataset).
    #[serde(default)]
    pub info: BTreeMap<String, String>,
}

/// Evaluates trained variants on the prepared test set.
pub fn evaluate(trained: &[TrainedVariant], prepared: &Prepared) -> Result<Report> {
    let fs = prepared.scales.force_n;
    let mut variants = BTreeMap::new();
    for t in trained {
        let rmse = rmse_model(&t.model, &prepared.test, prepared.warmup_samples, fs)?;
        let audit = matches!(t.variant, Variant::NemmLight | Variant::Nemm)
            .then(|| audit(&t.model, AUDIT_GRID.0, AUDIT_GRID.1));
        let blob_bytes = nemm_core::encode_to_vec(&t.model)
            .map(|b| b.len())
            .unwrap_or(0);
        variants.insert(
            t.variant.key().to_string(),
            VariantReport {
                rmse,
                rmse_n: rmse * fs,
                val_rmse: t.val_rmse,
                violations: audit.map_or(0, |a| a.total_violations()),
                audit,
                train_seconds: t.seconds,
                epochs: t.history.len(),
                blob_bytes,
                history: t.history.clone(),
            },
        );
    }
    Ok(Report {
        test_alpha: prepared
            .config
            .split
            .test_alphas
            .first()
            .copied()
            .unwrap_or(f64::NAN),
        force_scale_n: fs,
        variants,
        test_sequences: prepared.test.len(),
        info: BTreeMap::new(),
    })
}

/// Table 4 as Markdown: RMSE (normalised and in N) and relative to the SEM.
pub fn table4_markdown(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| Model | Model error (RMSE) | RMSE [N] | Rel. model error (%) | Monotonicity violations | Training time |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|");
    let sem = r.variants.get("sem").map(|v| v.rmse);
    for v in Variant::ALL {
        if let Some(x) = r.variants.get(v.key()) {
            let rel = sem.map_or("-".to_string(), |b| format!("{:.1}", 100.0 * x.rmse / b));
            let viol = match v {
                Variant::NemmLight | Variant::Nemm => x.violations.to_string(),
                _ => "-".to_string(),
            };
            let _ = writeln!(
                s,
                "| {} | {:.4} | {:.1} | {} | {} | {:.0} s |",
                v.title(),
                x.rmse,
                x.rmse_n,
                rel,
                viol,
                x.train_seconds
            );
        }
    }
    let _ = writeln!(
        s,
        "\nTest set: oil loss {} ({} sequences); RMSE normalised by the training set's abs-max force {:.0} N.",
        r.test_alpha, r.test_sequences, r.force_scale_n
    );
    s
}
