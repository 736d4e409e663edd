//! Model selection of a stage: which epoch's model is kept (the most accurate one that
//! passes the monotonicity audit when the stage audits, else the most accurate one), early
//! stopping, and the line that reports the choice.

use serde::{Deserialize, Serialize};

/// The selection's state after some epochs: the kept model and the progress counters of
/// early stopping.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) struct Selection {
    /// Epoch of the kept model (0: the model the stage started from).
    pub(crate) best_epoch: usize,
    /// Its validation RMSE (normalised).
    pub(crate) best_val: f64,
    /// The kept model passed the monotonicity audit.
    pub(crate) best_consistent: bool,
    /// Epochs since the kept model changed.
    pub(crate) since_best: usize,
    /// Best validation RMSE of any epoch (early stopping's progress measure).
    pub(crate) best_any_val: f64,
    /// Epochs since `best_any_val` improved.
    pub(crate) since_any: usize,
}

impl Selection {
    /// The selection before the first epoch: the starting model (validation RMSE `val`,
    /// audit `violations`, `None` when the stage does not audit) is kept.
    pub(crate) fn start(val: f64, violations: Option<usize>) -> Self {
        Self {
            best_epoch: 0,
            best_val: val,
            best_consistent: violations == Some(0),
            since_best: 0,
            best_any_val: val,
            since_any: 0,
        }
    }

    /// Records epoch `epoch`'s model; `true` when it becomes the kept one ([`keeps`]).
    pub(crate) fn observe(&mut self, epoch: usize, val: f64, violations: Option<usize>) -> bool {
        let kept = keeps(val, violations, self.best_val, self.best_consistent);
        if kept {
            self.best_val = val;
            self.best_epoch = epoch;
            self.best_consistent = violations == Some(0);
            self.since_best = 0;
        } else {
            self.since_best += 1;
        }
        // Early stopping measures progress on either the kept (consistent) model or any
        // model: while the penalty is still cleaning up, the most accurate epochs can be
        // inconsistent ones, and stopping on the consistent ones alone would end a run that
        // still improves.
        if val < self.best_any_val {
            self.best_any_val = val;
            self.since_any = 0;
        } else {
            self.since_any += 1;
        }
        kept
    }

    /// Early stopping ([`patience_used`]); `audited`: the stage audits its models.
    pub(crate) fn patience_used(&self, patience: usize, audited: bool) -> bool {
        patience_used(
            patience,
            self.since_best,
            self.since_any,
            self.best_consistent || !audited,
        )
    }
}

/// Whether an epoch's model (validation RMSE `val`, audit `violations`; `None` when the
/// stage does not audit) replaces the kept one (`best_val`, `best_consistent`).
///
/// Without an audit the best validation RMSE wins (plain early stopping). With one, a model
/// that passes the audit always replaces one that does not, and among models that pass (or
/// while none has) the lower validation RMSE wins: the kept model is the most accurate
/// physically consistent one, with the most accurate model as the fallback.
pub(crate) fn keeps(
    val: f64,
    violations: Option<usize>,
    best_val: f64,
    best_consistent: bool,
) -> bool {
    match violations {
        None => val < best_val,
        Some(0) => !best_consistent || val < best_val,
        Some(_) => !best_consistent && val < best_val,
    }
}

/// Early stopping: `patience` epochs without progress, where progress is a better kept model
/// (`since_kept` epochs ago) or a better model of any kind (`since_any`), and only once the
/// kept model is acceptable (`kept_acceptable`: it passed the audit, or nothing is audited).
///
/// Counting progress of any model keeps a run going while the penalty is still cleaning up
/// the most accurate epochs; so this never stops earlier than plain early stopping on the
/// validation RMSE, and without an audit (both counters equal) it is exactly that.
pub(crate) fn patience_used(
    patience: usize,
    since_kept: usize,
    since_any: usize,
    kept_acceptable: bool,
) -> bool {
    since_kept.min(since_any) >= patience && kept_acceptable
}

/// A model that was more accurate than the kept one but failed the monotonicity audit: its
/// epoch (0: the model the stage started from), validation RMSE and violation count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassedOver {
    /// Epoch (0: the starting model).
    pub epoch: usize,
    /// Validation RMSE (normalised).
    pub val_rmse: f64,
    /// Violations found by the audit.
    pub violations: usize,
}

/// The most accurate audited model of `candidates` (`(epoch, val_rmse, violations)`, the
/// starting model as epoch 0 when known) if it is more accurate than the kept model
/// (`kept_val`) and failed the audit: what consistent model selection gave up.
pub(crate) fn passed_over(
    candidates: impl IntoIterator<Item = (usize, f64, Option<usize>)>,
    kept_val: f64,
) -> Option<PassedOver> {
    let (epoch, val_rmse, violations) = candidates
        .into_iter()
        .filter_map(|(e, v, n)| n.map(|n| (e, v, n)))
        .filter(|(_, v, _)| v.is_finite())
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    (val_rmse < kept_val && violations > 0).then_some(PassedOver {
        epoch,
        val_rmse,
        violations,
    })
}

/// The line that ends a stage: which model is kept. Epoch 0 is the model the stage started
/// from (for the neural variants: the Linear EMM constants and the eq. 41 regression), kept
/// when no epoch improved on its validation RMSE; the user is told so, because the stage then
/// changed nothing. With `passed_over`, the line also names the more accurate model that
/// consistent selection passed over because it failed the monotonicity audit, so the
/// accuracy given up for physical consistency is visible.
pub(crate) fn kept_model_summary(
    best_epoch: usize,
    best_val_rmse: f64,
    passed_over: Option<PassedOver>,
) -> String {
    let mut line = if best_epoch == 0 {
        format!(
            "kept the starting model (validation RMSE {best_val_rmse:.4}): no epoch improved on it; \
             train longer (--epochs, --patience) or with a smaller --lr"
        )
    } else {
        format!("kept epoch {best_epoch} (validation RMSE {best_val_rmse:.4})")
    };
    if let Some(p) = passed_over {
        let which = if p.epoch == 0 {
            "the starting model".to_string()
        } else {
            format!("epoch {}", p.epoch)
        };
        line.push_str(&format!(
            ", the most accurate that passes the monotonicity audit; {which} was more accurate \
             (validation RMSE {:.4}) but has {} violation(s)",
            p.val_rmse, p.violations
        ));
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn early_stopping_waits_for_a_consistent_model_and_for_all_progress_to_stop() {
        // Plain early stopping (no audit: both counters are equal).
        assert!(patience_used(8, 8, 8, true));
        assert!(!patience_used(8, 7, 7, true));
        // More accurate (inconsistent) epochs still count as progress ...
        assert!(!patience_used(8, 8, 2, true));
        // ... and so does a better consistent model while the most accurate one is older.
        assert!(!patience_used(8, 2, 8, true));
        // No stop while no acceptable model is kept.
        assert!(!patience_used(8, 30, 30, false));
    }

    #[test]
    fn consistent_models_win_over_more_accurate_inconsistent_ones() {
        // No audit: plain early stopping on the validation RMSE.
        assert!(keeps(0.03, None, 0.04, false));
        assert!(!keeps(0.05, None, 0.04, false));
        // The first model that passes the audit replaces an inconsistent one, even if worse.
        assert!(keeps(0.05, Some(0), 0.04, false));
        // Once a consistent model is kept, an inconsistent one never replaces it ...
        assert!(!keeps(0.01, Some(3), 0.04, true));
        // ... and a consistent one only if it is more accurate.
        assert!(keeps(0.03, Some(0), 0.04, true));
        assert!(!keeps(0.05, Some(0), 0.04, true));
        // While none is consistent, the most accurate model is the fallback.
        assert!(keeps(0.03, Some(3), 0.04, false));
        assert!(!keeps(0.05, Some(3), 0.04, false));
    }

    #[test]
    fn kept_model_summary_names_the_epoch_and_the_starting_model() {
        assert_eq!(
            kept_model_summary(7, 0.04123, None),
            "kept epoch 7 (validation RMSE 0.0412)"
        );
        let start = kept_model_summary(0, 0.043, None);
        assert!(
            start.starts_with("kept the starting model (validation RMSE 0.0430)"),
            "{start}"
        );
        assert!(start.contains("--lr"), "{start}");
    }

    #[test]
    fn the_summary_names_the_more_accurate_model_that_failed_the_audit() {
        // Start 0.043 with 216 violations, epoch 5 clean at 0.056, epoch 6 at 0.041 with 37.
        let cands = [
            (0, 0.043, Some(216)),
            (5, 0.056, Some(0)),
            (6, 0.041, Some(37)),
        ];
        let p = passed_over(cands, 0.056).expect("epoch 6 was passed over");
        assert_eq!((p.epoch, p.violations), (6, 37));
        let line = kept_model_summary(5, 0.056, Some(p));
        assert!(
            line.starts_with(
                "kept epoch 5 (validation RMSE 0.0560), the most accurate that passes"
            ),
            "{line}"
        );
        assert!(
            line.contains(
                "epoch 6 was more accurate (validation RMSE 0.0410) but has 37 violation(s)"
            ),
            "{line}"
        );
        // The starting model is named as such.
        let p0 = passed_over([(0, 0.043, Some(216)), (5, 0.056, Some(0))], 0.056).unwrap();
        assert!(
            kept_model_summary(5, 0.056, Some(p0)).contains("the starting model was more accurate")
        );
        // Nothing is reported when the kept model is the most accurate, when the more accurate
        // one is clean (not a selection by the audit), or without an audit.
        assert_eq!(
            passed_over([(5, 0.056, Some(0)), (6, 0.06, Some(3))], 0.056),
            None
        );
        assert_eq!(passed_over([(3, 0.05, Some(0))], 0.056), None);
        assert_eq!(passed_over([(3, 0.05, None)], 0.056), None);
        assert_eq!(passed_over([(3, f64::NAN, Some(2))], 0.056), None);
    }

    #[test]
    fn the_selection_keeps_the_most_accurate_consistent_epoch_and_counts_progress() {
        // Start: 0.05 with violations; epoch 1 more accurate but inconsistent; epoch 2 clean.
        let mut s = Selection::start(0.05, Some(4));
        assert!(s.observe(1, 0.04, Some(2)));
        assert_eq!((s.best_epoch, s.best_consistent), (1, false));
        assert!(s.observe(2, 0.045, Some(0)));
        assert_eq!((s.best_epoch, s.since_best, s.since_any), (2, 0, 1));
        assert!(!s.observe(3, 0.03, Some(1)));
        assert_eq!((s.best_epoch, s.since_best, s.since_any), (2, 1, 0));
        assert!(!s.patience_used(1, true));
        assert!(!s.observe(4, 0.05, Some(0)));
        assert!(s.patience_used(1, true));
        // Without an audit it is plain early stopping on the validation RMSE.
        let mut plain = Selection::start(0.05, None);
        assert!(plain.observe(1, 0.04, None));
        assert!(!plain.observe(2, 0.041, None));
        assert!(plain.patience_used(1, false));
    }
}
