//! Table 4 / Table 5 style reports: test RMSE per variant (normalised by the training set's
//! abs-max force, and in newtons), the monotonicity audit, training facts; as `report.json`
//! and Markdown.

use crate::data::preprocess::Prepared;
use crate::report::identify::IdentifyReport;
use crate::train::eval::{rmse_of, sse_per_sequence};
use crate::train::history::EpochStats;
use crate::train::physics::{audit, Audit, AUDIT_GRID};
use crate::train::pipeline::{TrainedVariant, VariantInfo};
use anyhow::Result;
use nemm_core::ModelKind;
use nemm_dataset::ConditionSpec;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// A number that JSON wrote as `null` (serde_json writes NaN so) reads back as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

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
    pub(crate) blob_bytes: usize,
    /// Per-epoch history.
    #[serde(default)]
    pub history: Vec<EpochStats>,
}

/// A whole report (`report.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// Oil-loss level(s) of the test set (the first one; Table 2: 0.15); NaN (`null` in
    /// JSON) when the test set is not a level (`--test-runs`, `--test-tail`).
    #[serde(deserialize_with = "nan_if_null")]
    pub test_alpha: f64,
    /// Abs-max force of the training set \[N\].
    pub force_scale_n: f64,
    /// Per variant, keyed `sem`, `linear_emm`, `nemm_light`, `nemm`.
    pub variants: BTreeMap<String, VariantReport>,
    /// Variants that could not be trained, exported or evaluated (keys as in
    /// [`Report::variants`]) and why; Table 4 gives each a row with the reason.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub failed: BTreeMap<String, String>,
    /// The test set, split and validation rule ([`crate::data::preprocess::SplitConfig::describe`]).
    #[serde(default)]
    pub(crate) test_set: String,
    /// Test sequences and scored samples.
    pub test_sequences: usize,
    /// The test error per held-out run, in the order of the dataset (where each model errs:
    /// amplitude, frequency). Empty in reports written before it existed.
    #[serde(default)]
    pub test_runs: Vec<RunBreakdown>,
    /// Identifiability of the level and whole-run errors per level and condition, every
    /// run the split uses (`crate::report::identify`); absent where not computed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub identify: Option<IdentifyReport>,
    /// Free-form facts about the run (configuration, dataset).
    #[serde(default)]
    pub(crate) info: BTreeMap<String, String>,
    /// What `alpha` stands for (the dataset's `[condition]`; default the paper's oil loss).
    #[serde(default)]
    pub condition: ConditionSpec,
    /// The NEMM's coefficients against the virtual bench's equivalent EMM coefficients
    /// (datasets written by `nemm bench generate`; absent for other data).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bench_reference: Option<crate::report::reference::ReferenceComparison>,
    /// The degradation signature: each model's difference loops `F(0) - F(alpha)` against
    /// the measured ones per condition (`crate::report::signature`); absent where not
    /// computed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub signature: Option<crate::report::signature::SignatureReport>,
}

/// The test error of every variant on one held-out run (its scored test sequences).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunBreakdown {
    /// Run file, relative to the manifest.
    pub file: String,
    /// Oil-loss level.
    pub alpha: f64,
    /// Stroke amplitude \[m\] (estimated from the run).
    pub amplitude_m: f64,
    /// Excitation frequency \[Hz\] (estimated; absent without two zero crossings).
    pub frequency_hz: Option<f64>,
    /// Peak stroke velocity \[m/s\] (estimated).
    pub peak_velocity_m_s: f64,
    /// Scored samples.
    pub samples: usize,
    /// Normalised RMSE per variant (keys as in [`Report::variants`]).
    pub rmse: BTreeMap<String, f64>,
}

/// Evaluates trained variants on the prepared test set: overall (Table 4) and per held-out
/// run. A variant whose evaluation fails is listed in [`Report::failed`] with the error.
pub fn evaluate(trained: &[TrainedVariant], prepared: &Prepared) -> Result<Report> {
    let fs = prepared.scales.force_n;
    let mut variants = BTreeMap::new();
    let mut failed = BTreeMap::new();
    // run index -> (scored samples, variant -> squared-error sum)
    let mut by_run: BTreeMap<usize, (usize, BTreeMap<String, f64>)> = BTreeMap::new();
    let mut counted = false;
    for t in trained {
        let per_seq = match sse_per_sequence(
            &t.model,
            &prepared.test,
            prepared.dt_s,
            prepared.warmup_samples,
            fs,
        ) {
            Ok(p) => p,
            Err(e) => {
                failed.insert(t.variant.key().to_string(), format!("evaluation: {e:#}"));
                continue;
            }
        };
        let (mut se, mut n) = (0.0f64, 0usize);
        for (seq, &(s, k)) in prepared.test.iter().zip(&per_seq) {
            se += s;
            n += k;
            let run = by_run.entry(seq.run).or_default();
            *run.1.entry(t.variant.key().to_string()).or_default() += s;
            if !counted {
                run.0 += k;
            }
        }
        counted = true;
        let rmse = rmse_of(se, n);
        let audit = matches!(t.variant, ModelKind::NemmLight | ModelKind::Nemm)
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
    let condition = ConditionSpec::from_core(&prepared.condition);
    Ok(Report {
        bench_reference: None,
        signature: None,
        condition: condition.clone(),
        test_alpha: prepared
            .config
            .split
            .test_alphas
            .first()
            .copied()
            .unwrap_or(f64::NAN),
        force_scale_n: fs,
        variants,
        failed,
        test_set: prepared.config.split.describe_for(&condition),
        test_sequences: prepared.test.len(),
        test_runs: by_run
            .into_iter()
            .filter_map(|(idx, (samples, se))| {
                let sum = &prepared
                    .runs
                    .iter()
                    .find(|r| r.summary.index == idx)?
                    .summary;
                Some(RunBreakdown {
                    file: sum.file.display().to_string(),
                    alpha: sum.alpha,
                    amplitude_m: sum.excitation.amplitude_m,
                    frequency_hz: sum.excitation.frequency_hz,
                    peak_velocity_m_s: sum.excitation.peak_velocity_m_s,
                    samples,
                    rmse: se
                        .into_iter()
                        .map(|(k, e)| (k, (e / samples.max(1) as f64).sqrt()))
                        .collect(),
                })
            })
            .collect(),
        identify: None,
        info: BTreeMap::new(),
    })
}

/// The per-run breakdown as Markdown: RMSE in newtons per variant, the NEMM relative to the
/// reference of `relative_reference` (the SEM when it ran), and each run's share of the NEMM's squared error over the test set (which runs the
/// headline number comes from). Empty when the report has no per-run data.
pub fn test_runs_markdown(r: &Report) -> String {
    let mut s = String::new();
    if r.test_runs.is_empty() {
        return s;
    }
    let keys: Vec<ModelKind> = ModelKind::ALL
        .into_iter()
        .filter(|v| r.test_runs.iter().any(|t| t.rmse.contains_key(v.key())))
        .collect();
    let nemm_sse: f64 = r
        .test_runs
        .iter()
        .filter_map(|t| {
            t.rmse
                .get(ModelKind::Nemm.key())
                .map(|e| e * e * t.samples as f64)
        })
        .sum();
    let _ = writeln!(s, "Test RMSE per held-out run [N]:\n");
    let mut head = format!(
        "| run | {} | amplitude [mm] | frequency [Hz] | peak velocity [m/s] | samples |",
        r.condition.column()
    );
    let mut rule = "|---|---:|---:|---:|---:|---:|".to_string();
    for v in &keys {
        head.push_str(&format!(" {} |", v.title()));
        rule.push_str("---:|");
    }
    let reference = relative_reference(r)
        .map(|(v, _)| v)
        .filter(|v| keys.contains(v) && *v != ModelKind::Nemm);
    let has_pair = reference.is_some() && keys.contains(&ModelKind::Nemm);
    if let (true, Some(v)) = (has_pair, reference) {
        head.push_str(&format!(
            " NEMM / {} | share of NEMM's squared error |",
            v.title()
        ));
        rule.push_str("---:|---:|");
    }
    let _ = writeln!(s, "{head}\n{rule}");
    for t in &r.test_runs {
        let mut row = format!(
            "| {} | {} | {:.0} | {} | {:.3} | {} |",
            t.file,
            r.condition.cell(t.alpha),
            t.amplitude_m * 1e3,
            t.frequency_hz.map_or("-".into(), |f| format!("{f:.1}")),
            t.peak_velocity_m_s,
            t.samples
        );
        for v in &keys {
            row.push_str(&match t.rmse.get(v.key()) {
                Some(e) => format!(" {:.1} |", e * r.force_scale_n),
                None => " - |".into(),
            });
        }
        if let (true, Some(v)) = (has_pair, reference) {
            match (t.rmse.get(v.key()), t.rmse.get(ModelKind::Nemm.key())) {
                (Some(base), Some(nemm)) => row.push_str(&format!(
                    " {:.0} % | {:.1} % |",
                    100.0 * nemm / base,
                    100.0 * nemm * nemm * t.samples as f64 / nemm_sse
                )),
                _ => row.push_str(" - | - |"),
            }
        }
        let _ = writeln!(s, "{row}");
    }
    s
}

/// The reference of the relative errors: the SEM when it ran, else the baseline that ran
/// (Linear EMM, NEMM-Light) with the lowest test RMSE; `None` when none of them ran.
pub(crate) fn relative_reference(r: &Report) -> Option<(ModelKind, f64)> {
    if let Some(sem) = r.variants.get(ModelKind::Sem.key()) {
        return Some((ModelKind::Sem, sem.rmse));
    }
    [ModelKind::LinearEmm, ModelKind::NemmLight]
        .into_iter()
        .filter_map(|v| r.variants.get(v.key()).map(|x| (v, x.rmse)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

/// Why the relative errors are not relative to the SEM, for the note under a table; `None`
/// when they are (or no reference ran).
fn reference_note(r: &Report) -> Option<String> {
    let (reference, _) = relative_reference(r)?;
    (reference != ModelKind::Sem).then(|| {
        let why = match r.failed.get(ModelKind::Sem.key()) {
            Some(reason) => format!("the SEM failed: {}", reason.replace(['\n', '\r'], " ")),
            None => "the SEM did not run".to_string(),
        };
        format!(
            "Relative errors are relative to the {}, the best baseline that ran ({why}).",
            reference.title()
        )
    })
}

/// Table 4 as Markdown: RMSE (normalised and in N) and relative to the SEM (or, when the SEM
/// did not run, to the best baseline that did: [`relative_reference`], said under the table).
pub(crate) fn table4_markdown(r: &Report) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| Model | Model error (RMSE) | RMSE [N] | Rel. model error (%) | Monotonicity violations | Training time |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|");
    let reference = relative_reference(r).map(|(_, rmse)| rmse);
    for v in ModelKind::ALL {
        if let Some(reason) = r.failed.get(v.key()) {
            // One table cell: no pipes or line breaks from the error text.
            let reason = reason.replace('|', "\\|").replace(['\n', '\r'], " ");
            let _ = writeln!(s, "| {} | failed: {reason} | - | - | - | - |", v.title());
        } else if let Some(x) = r.variants.get(v.key()) {
            let rel = reference.map_or("-".to_string(), |b| format!("{:.1}", 100.0 * x.rmse / b));
            let viol = match v {
                ModelKind::NemmLight | ModelKind::Nemm => x.violations.to_string(),
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
    let split = if r.test_set.is_empty() {
        format!("test: {}", r.condition.level(r.test_alpha))
    } else {
        r.test_set.clone()
    };
    let _ = writeln!(
        s,
        "\nSplit: {split} ({} test sequences); RMSE normalised by the training set's abs-max force {:.0} N.",
        r.test_sequences, r.force_scale_n
    );
    if let Some(note) = reference_note(r) {
        let _ = writeln!(s, "{note}");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn variant(rmse: f64) -> VariantReport {
        VariantReport {
            rmse,
            rmse_n: 1000.0 * rmse,
            val_rmse: rmse,
            audit: None,
            violations: 0,
            train_seconds: 1.0,
            epochs: 1,
            blob_bytes: 100,
            history: Vec::new(),
        }
    }

    fn report(sem: Option<f64>) -> Report {
        let mut variants = BTreeMap::new();
        let mut failed = BTreeMap::new();
        match sem {
            Some(x) => {
                variants.insert(ModelKind::Sem.key().to_string(), variant(x));
            }
            None => {
                failed.insert(
                    ModelKind::Sem.key().to_string(),
                    "no quasi-static points in the training set".to_string(),
                );
            }
        }
        variants.insert(ModelKind::LinearEmm.key().to_string(), variant(0.08));
        variants.insert(ModelKind::NemmLight.key().to_string(), variant(0.05));
        variants.insert(ModelKind::Nemm.key().to_string(), variant(0.04));
        Report {
            test_alpha: 0.15,
            force_scale_n: 1000.0,
            variants,
            failed,
            test_set: String::new(),
            test_sequences: 10,
            test_runs: Vec::new(),
            identify: None,
            info: BTreeMap::new(),
            condition: ConditionSpec::default(),
            bench_reference: None,
            signature: None,
        }
    }

    #[test]
    fn the_relative_column_falls_back_to_the_best_baseline_and_says_so() {
        // With the SEM: relative to it, no note.
        let with = report(Some(0.1));
        assert_eq!(relative_reference(&with), Some((ModelKind::Sem, 0.1)));
        let table = table4_markdown(&with);
        assert!(table.contains("| NEMM | 0.0400 | 40.0 | 40.0 |"), "{table}");
        assert!(
            !table.contains("Relative errors are relative to"),
            "{table}"
        );
        // Without: relative to NEMM-Light (0.05 < the Linear EMM's 0.08), said under the table.
        let without = report(None);
        assert_eq!(
            relative_reference(&without),
            Some((ModelKind::NemmLight, 0.05))
        );
        let table = table4_markdown(&without);
        assert!(table.contains("| NEMM | 0.0400 | 40.0 | 80.0 |"), "{table}");
        assert!(
            table.contains("| NEMM-Light | 0.0500 | 50.0 | 100.0 |"),
            "{table}"
        );
        assert!(
            table.contains(
                "Relative errors are relative to the NEMM-Light, the best baseline that ran \
                 (the SEM failed: no quasi-static points in the training set)."
            ),
            "{table}"
        );
    }
}
