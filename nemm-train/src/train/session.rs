//! The session budget (`--session-epochs`): a stage trains at most so many epochs in one
//! invocation, then stops after writing its checkpoint; `--resume` continues.

use super::history::StopReason;
use anyhow::Result;

/// The epochs one invocation of a stage may train.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct SessionBudget {
    /// First epoch of this invocation.
    pub(crate) start_epoch: usize,
    /// Epochs it may train (`None`: no limit).
    pub(crate) epochs: Option<usize>,
}

impl SessionBudget {
    /// Whether the budget is used before `epoch` would start.
    pub(crate) fn used_before(&self, epoch: usize) -> bool {
        self.epochs
            .is_some_and(|n| epoch >= self.start_epoch.saturating_add(n))
    }
}

/// A stage used up the session budget (`--session-epochs`): its checkpoint is written and
/// the later stages did not run, since they start from this stage's result; nothing is
/// exported. Returned as the error of [`train_variants`](super::pipeline::train_variants) so that no caller can mistake an
/// unfinished run for a trained model; the CLI reports it and exits successfully.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionBudgetUsed {
    /// The stage that stopped (`linear-emm`, `nemm-light`, `nemm`).
    pub stage: String,
}

impl std::fmt::Display for SessionBudgetUsed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "session budget used in stage `{}`: its checkpoint is written, the later stages \
             have not run and nothing is exported yet; continue with --resume",
            self.stage
        )
    }
}

impl std::error::Error for SessionBudgetUsed {}

impl SessionBudgetUsed {
    /// `Err` if the stage `label` ended with `stop` because the session budget was used.
    pub(crate) fn check(stop: StopReason, label: &str) -> Result<()> {
        if stop == StopReason::Session {
            return Err(Self {
                stage: label.to_string(),
            }
            .into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_budget_counts_from_the_first_epoch_of_the_session() {
        let b = SessionBudget {
            start_epoch: 3,
            epochs: Some(2),
        };
        assert!(!b.used_before(3) && !b.used_before(4));
        assert!(b.used_before(5));
        let unlimited = SessionBudget {
            start_epoch: 3,
            epochs: None,
        };
        assert!(!unlimited.used_before(1000));
        assert!(SessionBudgetUsed::check(StopReason::Session, "nemm").is_err());
        assert!(SessionBudgetUsed::check(StopReason::Epochs, "nemm").is_ok());
    }
}
