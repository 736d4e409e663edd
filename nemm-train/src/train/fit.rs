//! The training loop of the EMM-family variants: mini-batches of windows, the adjoint's
//! rollout gradient plus burn's L2 and physics gradients, one Adam step per batch, validation
//! RMSE per epoch, early stopping, checkpoints every epoch and `--resume`.
//!
//! # Numbers
//!
//! The rollout and its adjoint run in f32 (the precision of the target), gradients of a batch
//! are summed over packs in f32 and the loss in f64; burn's parameters and Adam state are f32.
//!
//! # Checkpoints
//!
//! After every epoch, `DIR/epoch-NNNN/` receives the module (`net.bpk`), the optimizer state
//! (`optim.bpk`), the best module so far (`best.bpk`) and `state.json` (epoch, history, best
//! validation RMSE); then `DIR/latest` is replaced atomically (temp file + rename) to name the
//! new epoch, and older epoch folders are removed. A crash or kill loses at most the epoch in
//! progress; `resume` continues from the epoch after `latest` with the same data order (the
//! shuffle of epoch `e` depends only on the seed and `e`). A non-finite loss stops training
//! with an error and leaves the last good checkpoint in place.

use super::adjoint::{loss_and_grad, simulate, Window};
use super::net::{EmmNet, NetFrame};
use super::params::to_core;
use super::physics::{audit, physics_loss, PenaltyGrid};
use crate::data::preprocess::Sequence;
use crate::train::physics::AUDIT_GRID;
use anyhow::{bail, Context, Result};
use burn::grad_clipping::GradientClippingConfig;
use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::Device;
use nemm_core::Meta;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Settings of one training stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FitConfig {
    /// Name shown in progress lines (e.g. `nemm`).
    pub label: String,
    /// Maximum number of epochs.
    pub epochs: usize,
    /// Windows per batch (paper default 16).
    pub batch: usize,
    /// Adam learning rate at the start (paper default 5e-3); cosine decay to 10 % of it.
    pub lr: f64,
    /// Weight `lambda` of the L2 term `sum ||W||_2` over the scalers (paper: 1e-3).
    pub lambda_l2: f64,
    /// Physics-inconsistency weight `lambda_ph`.
    pub lambda_ph: f64,
    /// Stop after this many epochs without a better validation RMSE.
    pub patience: usize,
    /// Gradient clipping by norm, per parameter tensor.
    pub grad_clip: f32,
    /// At most this many batches per epoch (a random subset), to fit a time budget.
    pub max_batches_per_epoch: Option<usize>,
    /// Seed of the data order.
    pub seed: u64,
    /// Train at most this many epochs in this invocation, then stop after writing the
    /// checkpoint (time-boxed sessions, e.g. cluster jobs with a wall-time limit); `resume`
    /// continues with the same schedule.
    pub session_epochs: Option<usize>,
    /// Adam's epsilon (PyTorch's default 1e-8; burn's default 1e-5 would dominate the small
    /// gradients of a normalised MSE).
    pub adam_eps: f32,
}

impl Default for FitConfig {
    fn default() -> Self {
        Self {
            label: "nemm".into(),
            epochs: 30,
            batch: 16,
            lr: 5e-3,
            lambda_l2: 1e-3,
            lambda_ph: 5e-3,
            patience: 6,
            grad_clip: 1.0,
            max_batches_per_epoch: None,
            seed: 1,
            session_epochs: None,
            adam_eps: 1e-8,
        }
    }
}

/// Training and validation windows.
#[derive(Debug, Clone, Copy)]
pub struct FitData<'a> {
    /// Training sequences.
    pub train: &'a [Sequence],
    /// Validation sequences.
    pub validation: &'a [Sequence],
    /// Warm-up samples at the start of each sequence (simulated, not scored).
    pub warmup: usize,
    /// Abs-max force of the training set \[N\].
    pub force_scale_n: f64,
}

/// Statistics of one epoch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpochStats {
    /// Epoch number (1-based).
    pub epoch: usize,
    /// Mean normalised MSE of the training batches.
    pub train_mse: f64,
    /// Mean physics-inconsistency loss of the batches.
    pub physics: f64,
    /// Validation RMSE, normalised by the force scale.
    pub val_rmse: f64,
    /// Wall time of the epoch \[s\].
    pub seconds: f64,
    /// Monotonicity violations of the epoch's model on the audit grid (eqs. 30-31, 37-38),
    /// when the stage selects physically consistent models (`lambda_ph > 0` and learned
    /// scalers; see [`fit`]).
    #[serde(default)]
    pub violations: Option<usize>,
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

/// The outcome of a stage.
#[derive(Debug)]
pub struct FitResult {
    /// The module with the best validation RMSE.
    pub best: EmmNet,
    /// Per-epoch statistics.
    pub history: Vec<EpochStats>,
    /// Epoch of the best module (0: the initial one).
    pub best_epoch: usize,
    /// Its validation RMSE (normalised).
    pub best_val_rmse: f64,
    /// Why training ended.
    pub stop: StopReason,
    /// The most accurate audited model, when it is more accurate than the kept one and
    /// failed the monotonicity audit (the accuracy consistent selection gave up); `None` when
    /// the kept model is the most accurate, or nothing is audited. The starting model is a
    /// candidate only when this invocation evaluated it (not after `--resume`).
    pub passed_over: Option<PassedOver>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct CheckpointState {
    label: String,
    epoch: usize,
    history: Vec<EpochStats>,
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

/// SplitMix64, for a reproducible data order.
fn splitmix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Order of the training windows in `epoch` (Fisher-Yates with a seed of `(seed, epoch)`).
fn epoch_order(n: usize, seed: u64, epoch: usize) -> Vec<usize> {
    let mut st = seed ^ (epoch as u64).wrapping_mul(0xD1B5_4A32_D192_ED03);
    let mut idx: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        let j = (splitmix(&mut st) % (i as u64 + 1)) as usize;
        idx.swap(i, j);
    }
    idx
}

fn windows(seqs: &[Sequence]) -> Vec<Window<'_>> {
    seqs.iter()
        .map(|s| Window {
            u: &s.velocity_m_s,
            f: &s.force_n,
            alpha: s.alpha,
        })
        .collect()
}

/// Normalised RMSE of `net` over `seqs` (scored after `warmup`), by the f32 rollout.
pub fn rmse(
    net: &EmmNet,
    frame: &NetFrame,
    seqs: &[Sequence],
    warmup: usize,
    force_scale: f64,
) -> f64 {
    if seqs.is_empty() {
        return f64::NAN;
    }
    let p = net.to_rollout(frame);
    let wins = windows(seqs);
    let ys = simulate(&p, &wins);
    let (mut se, mut n) = (0.0f64, 0usize);
    for (w, y) in wins.iter().zip(&ys) {
        for (&yi, &fi) in y.iter().zip(w.f).skip(warmup) {
            let e = (yi - fi as f64) / force_scale;
            se += e * e;
            n += 1;
        }
    }
    (se / n.max(1) as f64).sqrt()
}

/// Whether an epoch's model (validation RMSE `val`, audit `violations`; `None` when the
/// stage does not audit) replaces the kept one (`best_val`, `best_consistent`).
///
/// Without an audit the best validation RMSE wins (plain early stopping). With one, a model
/// that passes the audit always replaces one that does not, and among models that pass (or
/// while none has) the lower validation RMSE wins: the kept model is the most accurate
/// physically consistent one, with the most accurate model as the fallback.
pub fn keeps(val: f64, violations: Option<usize>, best_val: f64, best_consistent: bool) -> bool {
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
pub fn patience_used(
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
pub fn passed_over(
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
pub fn kept_model_summary(
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

/// Learning rate at `step` of `total`: a linear warm-up over the first 5 % of the steps (at
/// least 10: Adam's first steps are sign-like and would knock a pre-trained scaler off its
/// optimum), then cosine decay to 10 % of `lr`.
pub fn learning_rate(lr: f64, step: usize, total: usize) -> f64 {
    let warm = (total / 20).max(10);
    if step < warm {
        return lr * (step + 1) as f64 / warm as f64;
    }
    let progress = (step - warm) as f64 / (total.saturating_sub(warm)).max(1) as f64;
    lr * (0.1 + 0.9 * 0.5 * (1.0 + (std::f64::consts::PI * progress.min(1.0)).cos()))
}

fn scalar(t: burn::tensor::Tensor<1>) -> f64 {
    t.into_data()
        .convert::<f64>()
        .try_to_vec::<f64>()
        .ok()
        .and_then(|v| v.first().copied())
        .unwrap_or(f64::NAN)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::fsutil::write_atomic_bytes(path, bytes)
        .with_context(|| format!("cannot write {}", path.display()))
}

fn fmt_duration(s: f64) -> String {
    if s < 90.0 {
        format!("{s:.0} s")
    } else {
        format!("{:.1} min", s / 60.0)
    }
}

/// Trains `net` on `data`. With `checkpoint_dir`, checkpoints every epoch; with `resume`,
/// continues from the latest checkpoint there (the initial `net` must have the same shape).
pub fn fit(
    net: EmmNet,
    frame: &NetFrame,
    data: FitData<'_>,
    cfg: &FitConfig,
    checkpoint_dir: Option<&Path>,
    resume: bool,
    device: &Device,
) -> Result<FitResult> {
    if data.train.is_empty() {
        bail!("no training sequences: the dataset or split leaves nothing to train on");
    }
    let mut optim = AdamConfig::new()
        .with_epsilon(cfg.adam_eps)
        .with_grad_clipping(Some(GradientClippingConfig::Norm(cfg.grad_clip)))
        .init();
    let mut net = net;
    let mut best = net.clone();
    let mut history = Vec::new();
    let mut best_epoch = 0;
    let mut best_val = rmse(
        &net,
        frame,
        data.validation,
        data.warmup,
        data.force_scale_n,
    );
    // Physically consistent model selection: with a physics penalty and learned scalers, an
    // epoch's model may only replace a kept model that passed the audit if it passes too.
    let audit_epochs = cfg.lambda_ph > 0.0 && net.b_fl.is_some();
    let violations_of = |n: &EmmNet| -> Result<Option<usize>> {
        if !audit_epochs {
            return Ok(None);
        }
        // The audit reads the scalers and input scales only; `meta` just completes the model.
        let meta = Meta {
            force_scale_n: data.force_scale_n as f32,
            alpha_min: 0.0,
            alpha_max: 1.0,
        };
        let model = to_core(&n.to_rollout(frame), meta)?;
        Ok(Some(
            audit(&model, AUDIT_GRID.0, AUDIT_GRID.1).total_violations(),
        ))
    };
    let start_violations = violations_of(&net)?;
    let start_val = best_val;
    let mut best_consistent = start_violations == Some(0);
    let mut since_best = 0;
    // Early stopping measures progress on either the kept (consistent) model or any model:
    // while the penalty is still cleaning up, the most accurate epochs can be inconsistent
    // ones, and stopping on the consistent ones alone would end a run that still improves.
    let mut best_any_val = best_val;
    let mut since_any = 0;
    let mut start_epoch = 1;
    if let (true, Some(dir)) = (resume, checkpoint_dir) {
        match std::fs::read_to_string(dir.join("latest")) {
            Ok(name) => {
                let ep_dir = dir.join(name.trim());
                let st: CheckpointState = serde_json::from_str(
                    &std::fs::read_to_string(ep_dir.join("state.json")).with_context(|| {
                        format!("cannot read {}", ep_dir.join("state.json").display())
                    })?,
                )
                .with_context(|| format!("corrupt checkpoint state in {}", ep_dir.display()))?;
                if st.label != cfg.label {
                    bail!(
                        "checkpoint in {} is for `{}`, not `{}`",
                        dir.display(),
                        st.label,
                        cfg.label
                    );
                }
                net = net.try_load_file(ep_dir.join("net")).map_err(|e| {
                    anyhow::anyhow!("cannot load {}: {e:?}", ep_dir.join("net.bpk").display())
                })?;
                best = best.try_load_file(ep_dir.join("best")).map_err(|e| {
                    anyhow::anyhow!("cannot load {}: {e:?}", ep_dir.join("best.bpk").display())
                })?;
                optim = optim
                    .load(ep_dir.join("optim"))
                    .map_err(|e| anyhow::anyhow!("cannot load optimizer state: {e:?}"))?;
                history = st.history;
                best_epoch = st.best_epoch;
                best_val = st.best_val_rmse;
                since_best = st.since_best;
                best_consistent = st.best_consistent;
                (best_any_val, since_any) = st.progress.unwrap_or((best_val, since_best));
                start_epoch = st.epoch + 1;
                eprintln!(
                    "[{}] resuming after epoch {} (best validation RMSE {:.4} at epoch {})",
                    cfg.label, st.epoch, best_val, best_epoch
                );
            }
            Err(_) => eprintln!(
                "[{}] no checkpoint in {}: starting fresh",
                cfg.label,
                dir.display()
            ),
        }
    }
    // `(epoch 0, validation RMSE, violations)` of the starting model, when evaluated here.
    let start_audit = history
        .is_empty()
        .then_some((0, start_val, start_violations));
    if history.is_empty() {
        eprintln!(
            "[{}] start: validation RMSE {:.4} ({:.1} N){}",
            cfg.label,
            best_val,
            best_val * data.force_scale_n,
            start_violations.map_or(String::new(), |n| format!("  violations {n}"))
        );
    }
    let train_w = windows(data.train);
    let n_batches_full = data.train.len().div_ceil(cfg.batch);
    let n_batches = cfg
        .max_batches_per_epoch
        .map_or(n_batches_full, |m| m.min(n_batches_full));
    let total_steps = (cfg.epochs * n_batches).max(1);
    let grid = PenaltyGrid::default();
    let t_start = Instant::now();
    let mut stop = StopReason::Epochs;
    let stop_early = |since_best: usize, since_any: usize, best_consistent: bool| {
        patience_used(
            cfg.patience,
            since_best,
            since_any,
            best_consistent || !audit_epochs,
        )
    };
    // A resumed run may have used its patience already (then the loop does not run either).
    if stop_early(since_best, since_any, best_consistent) {
        stop = StopReason::EarlyStopping;
    }
    for epoch in start_epoch..=cfg.epochs {
        if stop_early(since_best, since_any, best_consistent) {
            stop = StopReason::EarlyStopping;
            break;
        }
        if cfg.session_epochs.is_some_and(|n| epoch >= start_epoch + n) {
            stop = StopReason::Session;
            eprintln!("[{}] session budget of {} epoch(s) used: stopping after epoch {}; continue with --resume", cfg.label, epoch - start_epoch, epoch - 1);
            break;
        }
        let t_epoch = Instant::now();
        let order = epoch_order(train_w.len(), cfg.seed, epoch);
        let (mut mse_sum, mut phys_sum) = (0.0f64, 0.0f64);
        for b in 0..n_batches {
            let idx = &order[b * cfg.batch..((b + 1) * cfg.batch).min(order.len())];
            let batch: Vec<Window<'_>> = idx.iter().map(|&i| train_w[i]).collect();
            let p = net.to_rollout(frame);
            let (mse, g) = loss_and_grad(&p, &batch, data.warmup, data.force_scale_n);
            if !mse.is_finite() {
                bail!(
                    "[{}] the training loss became {mse} in epoch {epoch}, batch {}: stopping. \
                     The last good checkpoint is kept; try a smaller learning rate (--lr) or \
                     tighter scaler bounds",
                    cfg.label,
                    b + 1
                );
            }
            // burn part: L2 and physics penalties (only scalers have them).
            let has_scalers = net.b_fl.is_some() || net.b_pr.is_some() || net.k_pr.is_some();
            let (mut gp, phys_v) = if has_scalers {
                let phys = physics_loss(&net, frame, &grid, device);
                let l2 = net.l2_norms(device);
                let aux = phys.clone().mul_scalar(cfg.lambda_ph) + l2.mul_scalar(cfg.lambda_l2);
                let phys_v = scalar(phys);
                (GradientsParams::from_grads(aux.backward(), &net), phys_v)
            } else {
                (GradientsParams::new(), 0.0)
            };
            net.add_rollout_grads(&g, [true; 4], &mut gp, device);
            let step = (epoch - 1) * n_batches + b;
            let lr = learning_rate(cfg.lr, step, total_steps);
            net = optim.step(lr, net, gp);
            mse_sum += mse;
            phys_sum += phys_v;
            if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
                eprint!(
                    "\r[{}] epoch {epoch}/{} batch {}/{} loss {:.3e}      ",
                    cfg.label,
                    cfg.epochs,
                    b + 1,
                    n_batches,
                    mse
                );
            }
        }
        let val = rmse(
            &net,
            frame,
            data.validation,
            data.warmup,
            data.force_scale_n,
        );
        if !val.is_finite() {
            bail!("[{}] the validation RMSE became {val} in epoch {epoch}: stopping, last good checkpoint kept", cfg.label);
        }
        let stats = EpochStats {
            epoch,
            train_mse: mse_sum / n_batches as f64,
            physics: phys_sum / n_batches as f64,
            val_rmse: val,
            seconds: t_epoch.elapsed().as_secs_f64(),
            violations: violations_of(&net)?,
        };
        history.push(stats);
        if keeps(val, stats.violations, best_val, best_consistent) {
            best_val = val;
            best_epoch = epoch;
            best = net.clone();
            best_consistent = stats.violations == Some(0);
            since_best = 0;
        } else {
            since_best += 1;
        }
        if val < best_any_val {
            best_any_val = val;
            since_any = 0;
        } else {
            since_any += 1;
        }
        let elapsed = t_start.elapsed().as_secs_f64();
        let done = epoch + 1 - start_epoch;
        let eta = elapsed / done as f64 * (cfg.epochs - epoch) as f64;
        eprintln!(
            "\r[{}] epoch {epoch:>3}/{} train MSE {:.3e}  physics {:.2e}  val RMSE {:.4} ({:.1} N){}{}  {:.1} s/epoch  ETA {}",
            cfg.label,
            cfg.epochs,
            stats.train_mse,
            stats.physics,
            val,
            val * data.force_scale_n,
            stats
                .violations
                .map_or(String::new(), |n| format!("  violations {n}")),
            if best_epoch == epoch { " *" } else { "  " },
            stats.seconds,
            fmt_duration(eta)
        );
        if let Some(dir) = checkpoint_dir {
            save_checkpoint(
                dir,
                &net,
                &best,
                &optim,
                &CheckpointState {
                    label: cfg.label.clone(),
                    epoch,
                    history: history.clone(),
                    best_epoch,
                    best_val_rmse: best_val,
                    since_best,
                    best_consistent,
                    progress: Some((best_any_val, since_any)),
                },
            )?;
        }
    }
    // The starting model is a candidate only when this invocation evaluated it.
    let gave_up = passed_over(
        start_audit
            .into_iter()
            .chain(history.iter().map(|h| (h.epoch, h.val_rmse, h.violations))),
        best_val,
    );
    if stop != StopReason::Session {
        eprintln!(
            "[{}] {}",
            cfg.label,
            kept_model_summary(best_epoch, best_val, gave_up)
        );
        if audit_epochs && !best_consistent {
            eprintln!(
                "[{}] warning: no epoch passed the monotonicity audit; the kept model violates \
                 eqs. 30-31/37-38 (train longer or with a larger --lambda-ph)",
                cfg.label
            );
        }
    }
    Ok(FitResult {
        best,
        history,
        best_epoch,
        best_val_rmse: best_val,
        stop,
        passed_over: gave_up,
    })
}

fn save_checkpoint(
    dir: &Path,
    net: &EmmNet,
    best: &EmmNet,
    optim: &burn::optim::ModuleOptimizer,
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
    write_atomic(
        &ep_dir.join("state.json"),
        serde_json::to_string_pretty(st)?.as_bytes(),
    )?;
    write_atomic(&dir.join("latest"), name.as_bytes())?;
    // Older epochs are no longer needed.
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let n = e.file_name().to_string_lossy().to_string();
            if n.starts_with("epoch-") && n != name {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
    }
    Ok(())
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
    fn epoch_order_is_a_permutation_and_reproducible() {
        let a = epoch_order(100, 7, 3);
        let mut s = a.clone();
        s.sort();
        assert_eq!(s, (0..100).collect::<Vec<_>>());
        assert_eq!(a, epoch_order(100, 7, 3));
        assert_ne!(a, epoch_order(100, 7, 4));
    }
}
