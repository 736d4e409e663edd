//! Checkpoints of a training stage: written after every epoch, rotated, and read back by
//! `--resume`.
//!
//! After every epoch, `DIR/epoch-NNNN/` receives the module (`net.bpk`), the optimizer state
//! (`optim.bpk`), the best module so far (`best.bpk`) and `state.json` (epoch, history, model
//! selection); then `DIR/latest` is replaced atomically (temp file + rename) to name the new
//! epoch, and older epoch folders are removed. A crash or kill loses at most the epoch in
//! progress.

use super::history::EpochStats;
use super::net::EmmNet;
use super::selection::Selection;
use anyhow::{bail, Context, Result};
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// `state.json` of an epoch folder.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct CheckpointState {
    label: String,
    pub(crate) epoch: usize,
    pub(crate) history: Vec<EpochStats>,
    best_epoch: usize,
    best_val_rmse: f64,
    since_best: usize,
    /// The kept model passed the monotonicity audit (absent in older checkpoints).
    #[serde(default)]
    best_consistent: bool,
    /// Best validation RMSE of any epoch and epochs since it improved (early stopping's
    /// progress measure; absent in older checkpoints, where they equal the kept model's).
    #[serde(default)]
    progress: Option<(f64, usize)>,
}

impl CheckpointState {
    /// The state after `epoch` of stage `label`.
    pub(crate) fn new(label: &str, epoch: usize, history: &[EpochStats], s: &Selection) -> Self {
        Self {
            label: label.to_string(),
            epoch,
            history: history.to_vec(),
            best_epoch: s.best_epoch,
            best_val_rmse: s.best_val,
            since_best: s.since_best,
            best_consistent: s.best_consistent,
            progress: Some((s.best_any_val, s.since_any)),
        }
    }

    /// The model selection it records.
    pub(crate) fn selection(&self) -> Selection {
        let (best_any_val, since_any) = self
            .progress
            .unwrap_or((self.best_val_rmse, self.since_best));
        Selection {
            best_epoch: self.best_epoch,
            best_val: self.best_val_rmse,
            best_consistent: self.best_consistent,
            since_best: self.since_best,
            best_any_val,
            since_any,
        }
    }
}

/// A stage read back from its latest checkpoint.
pub(crate) struct Resumed {
    /// The module after the last finished epoch.
    pub(crate) net: EmmNet,
    /// The kept module.
    pub(crate) best: EmmNet,
    /// The optimizer state.
    pub(crate) optim: ModuleOptimizer,
    /// Epoch, history and selection.
    pub(crate) state: CheckpointState,
}

/// The folder of the latest finished epoch in `dir`, if any.
pub(crate) fn latest(dir: &Path) -> Option<PathBuf> {
    let name = std::fs::read_to_string(dir.join("latest")).ok()?;
    Some(dir.join(name.trim()))
}

/// Reads the checkpoint `ep_dir` (an epoch folder of `dir`, see [`latest`]) of stage `label`
/// into modules shaped like `net` and an optimizer like `optim`.
pub(crate) fn load(
    dir: &Path,
    ep_dir: &Path,
    label: &str,
    net: EmmNet,
    optim: ModuleOptimizer,
) -> Result<Resumed> {
    let state_path = ep_dir.join("state.json");
    let state: CheckpointState = serde_json::from_str(
        &std::fs::read_to_string(&state_path)
            .with_context(|| format!("cannot read {}", state_path.display()))?,
    )
    .with_context(|| format!("corrupt checkpoint state in {}", ep_dir.display()))?;
    if state.label != label {
        bail!(
            "checkpoint in {} is for `{}`, not `{label}`",
            dir.display(),
            state.label
        );
    }
    let best = net
        .clone()
        .try_load_file(ep_dir.join("best"))
        .map_err(|e| anyhow::anyhow!("cannot load {}: {e:?}", ep_dir.join("best.bpk").display()))?;
    let net = net
        .try_load_file(ep_dir.join("net"))
        .map_err(|e| anyhow::anyhow!("cannot load {}: {e:?}", ep_dir.join("net.bpk").display()))?;
    let optim = optim
        .load(ep_dir.join("optim"))
        .map_err(|e| anyhow::anyhow!("cannot load optimizer state: {e:?}"))?;
    Ok(Resumed {
        net,
        best,
        optim,
        state,
    })
}

/// Writes the checkpoint of `st.epoch`, points `latest` at it and removes older epochs.
pub(crate) fn save(
    dir: &Path,
    net: &EmmNet,
    best: &EmmNet,
    optim: &ModuleOptimizer,
    st: &CheckpointState,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let name = format!("epoch-{:04}", st.epoch);
    let ep_dir: PathBuf = dir.join(&name);
    let _ = std::fs::remove_dir_all(&ep_dir);
    std::fs::create_dir_all(&ep_dir)?;
    net.clone()
        .save_file(ep_dir.join("net"))
        .map_err(|e| anyhow::anyhow!("cannot save checkpoint: {e:?}"))?;
    best.clone()
        .save_file(ep_dir.join("best"))
        .map_err(|e| anyhow::anyhow!("cannot save checkpoint: {e:?}"))?;
    optim
        .save(ep_dir.join("optim"))
        .map_err(|e| anyhow::anyhow!("cannot save optimizer state: {e:?}"))?;
    write(
        &ep_dir.join("state.json"),
        serde_json::to_string_pretty(st)?.as_bytes(),
    )?;
    write(&dir.join("latest"), name.as_bytes())?;
    rotate(dir, &name);
    Ok(())
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    nemm_dataset::atomic_file::write_atomic_bytes(path, bytes)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Removes every epoch folder of `dir` but `keep`.
fn rotate(dir: &Path, keep: &str) {
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let n = e.file_name().to_string_lossy().to_string();
            if n.starts_with("epoch-") && n != keep {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
}
