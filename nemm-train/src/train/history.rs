//! What a training stage reports as it runs: the statistics of each epoch and why the
//! stage ended. Checkpoints store them, the session budget and the reports read them.

use serde::{Deserialize, Serialize};

/// Statistics of one epoch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpochStats {
    /// Epoch number (1-based).
    pub epoch: usize,
    /// Mean normalised MSE of the training batches.
    pub train_mse: f64,
    /// Mean matched-difference term of the batches (0 without `lambda_diff`).
    #[serde(default)]
    pub diff: f64,
    /// Mean physics-inconsistency loss of the batches.
    pub physics: f64,
    /// Validation RMSE, normalised by the force scale.
    pub val_rmse: f64,
    /// Wall time of the epoch \[s\].
    pub seconds: f64,
    /// Monotonicity violations of the epoch's model on the audit grid (eqs. 30-31, 37-38),
    /// when the stage selects physically consistent models (`lambda_ph > 0` and learned
    /// scalers; see [`super::fit::fit`]).
    #[serde(default)]
    pub violations: Option<usize>,
    /// Optimizer steps of the epoch after which the stability hold moved the constants
    /// (`super::stability`): the data pull the model faster than its step allows.
    #[serde(default)]
    pub held: usize,
}

/// Why training ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum StopReason {
    /// All epochs done.
    Epochs,
    /// No improvement for `patience` epochs.
    EarlyStopping,
    /// The session's epoch budget is used up (`session_epochs`); resume to continue.
    Session,
}
