//! The training loop of the EMM-family variants: mini-batches of windows, the adjoint's
//! rollout gradient plus burn's L2 and physics gradients, one Adam step per batch, validation
//! RMSE per epoch, early stopping, checkpoints every epoch and `--resume`.
//!
//! # Numbers
//!
//! The rollout and its adjoint run in f32 (the precision of the target), gradients of a batch
//! are summed over packs in f32 and the loss in f64; burn's parameters and Adam state are f32.
//!
//! # Parts
//!
//! [`fit`] is the epoch loop; model selection and early stopping are
//! `super::selection`, checkpoints (write, rotate, resume) `train::checkpoint`, and the
//! `--session-epochs` budget `super::session`. `resume` continues from the epoch after the
//! latest checkpoint with the same data order (the shuffle of epoch `e` depends only on the
//! seed and `e`). A non-finite loss stops training with an error and leaves the last good
//! checkpoint in place.

use super::adjoint::{loss_and_grad_paired, simulate, Grid, Pairing, Window};
use super::checkpoint::{self, CheckpointState};
use super::history::{EpochStats, StopReason};
use super::matched::{matched_count, matched_windows, paired_batch};
use super::net::{EmmNet, NetFrame};
use super::params::to_core;
use super::physics::{audit, physics_loss, Audit, PenaltyGrid};
use super::selection::{kept_model_summary, passed_over, PassedOver, Selection};
use super::session::SessionBudget;
use super::stability::StabilityHold;
use crate::config::{Balance, TrainConfig};
use crate::data::preprocess::Sequence;
use crate::train::physics::AUDIT_GRID;
use anyhow::{bail, Result};
use burn::grad_clipping::GradientClippingConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::Device;
use nemm_core::Meta;
use rand::seq::{IndexedRandom, SliceRandom};
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};
use std::path::Path;
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
    /// Weight `lambda_diff` of the matched-difference term (0: off): the force difference
    /// between matched windows at two levels (`super::matched`) against the measured one.
    pub lambda_diff: f64,
    /// Stop after this many epochs without a better validation RMSE (not before half of
    /// `epochs` are done).
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
    /// How batches draw the training windows.
    pub balance: Balance,
}

impl FitConfig {
    /// The settings of one stage labelled `label` from the job's training part (the neural
    /// stages' epochs and learning rate).
    pub fn of(t: &TrainConfig, label: &str) -> Self {
        FitConfig {
            label: label.to_string(),
            epochs: t.epochs,
            batch: t.batch,
            lr: t.lr,
            lambda_l2: t.lambda_l2,
            lambda_ph: t.lambda_ph,
            lambda_diff: t.lambda_diff,
            patience: t.patience,
            grad_clip: t.grad_clip,
            max_batches_per_epoch: t.max_batches,
            seed: t.seed,
            session_epochs: t.session_epochs,
            adam_eps: t.adam_eps,
            balance: t.balance,
        }
    }
}

/// The defaults are [`TrainConfig`]'s, for the stage `nemm`.
impl Default for FitConfig {
    fn default() -> Self {
        FitConfig::of(&TrainConfig::default(), "nemm")
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
    /// Where the sequences' samples fall on the model's integration grid.
    pub grid: Grid,
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

/// Order of the training windows in `epoch`, one entry per window of `runs` (the run of
/// each training window), drawn by xoshiro256++ seeded from `(seed, epoch)` so that a
/// resumed run sees the same order. [`Balance::Windows`]: a shuffle, every window once.
/// [`Balance::Runs`]: as many draws, each a run chosen uniformly among the runs that have
/// windows and then one of its windows uniformly, so that every run weighs the same whatever
/// its length.
fn epoch_order(runs: &[usize], balance: Balance, seed: u64, epoch: usize) -> Vec<usize> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(
        seed ^ (epoch as u64).wrapping_mul(0xD1B5_4A32_D192_ED03),
    );
    match balance {
        Balance::Windows => {
            let mut idx: Vec<usize> = (0..runs.len()).collect();
            idx.shuffle(&mut rng);
            idx
        }
        Balance::Runs => {
            let mut by_run: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
            for (i, &r) in runs.iter().enumerate() {
                by_run.entry(r).or_default().push(i);
            }
            let groups: Vec<Vec<usize>> = by_run.into_values().collect();
            (0..runs.len())
                .filter_map(|_| groups.choose(&mut rng)?.choose(&mut rng).copied())
                .collect()
        }
    }
}

/// The rollout windows of `seqs` (velocity, force, condition level and position per sample).
pub fn windows(seqs: &[Sequence]) -> Vec<Window<'_>> {
    seqs.iter()
        .map(|s| Window {
            u: &s.velocity_m_s,
            f: &s.force_n,
            alpha: s.alpha,
            alphas: s.alphas.as_deref(),
            x: Some(&s.position_m),
        })
        .collect()
}

/// Normalised RMSE of `net` over `seqs` (scored at the samples after `warmup`, the model on
/// `grid`), by the f32 rollout.
pub fn rmse(
    net: &EmmNet,
    frame: &NetFrame,
    seqs: &[Sequence],
    grid: &Grid,
    warmup: usize,
    force_scale: f64,
) -> f64 {
    if seqs.is_empty() {
        return f64::NAN;
    }
    let p = net.to_rollout(frame);
    let wins = windows(seqs);
    let ys = simulate(&p, &wins, grid);
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

/// Learning rate at `step` of `total`: a linear warm-up over the first 5 % of the steps (at
/// least 10: Adam's first steps are sign-like and would knock a pre-trained scaler off its
/// optimum), then cosine decay to 10 % of `lr`.
pub(crate) fn learning_rate(lr: f64, step: usize, total: usize) -> f64 {
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
    let optim = AdamConfig::new()
        .with_epsilon(cfg.adam_eps)
        .with_grad_clipping(Some(GradientClippingConfig::Norm(cfg.grad_clip)))
        .init();
    let stage = Stage {
        frame,
        data,
        cfg,
        checkpoint_dir,
        device,
        audited: cfg.lambda_ph > 0.0 && net.b_fl.is_some(),
    };
    let (net, _) = StabilityHold::new(frame).hold_net(net);
    let start_val = stage.validation_rmse(&net);
    let start_violations = stage.violations(&net)?;
    let mut progress = Progress::start(net, optim, start_val, start_violations);
    if let (true, Some(dir)) = (resume, checkpoint_dir) {
        progress = progress.resume(dir, &cfg.label)?;
    }
    // `(epoch 0, validation RMSE, violations)` of the starting model, when evaluated here.
    let start_audit = progress
        .history
        .is_empty()
        .then_some((0, start_val, start_violations));
    if progress.history.is_empty() {
        eprintln!(
            "[{}] start: validation RMSE {:.4} ({:.1} N){}",
            cfg.label,
            start_val,
            start_val * data.force_scale_n,
            start_violations.map_or(String::new(), |n| format!("  violations {n}"))
        );
    }
    let (progress, stop) = stage.train_epochs(progress)?;
    Ok(stage.finish(progress, start_audit, stop))
}

/// What stays fixed during a stage: the model's frame, the data, the settings, the
/// checkpoint folder and the device.
struct Stage<'a> {
    frame: &'a NetFrame,
    data: FitData<'a>,
    cfg: &'a FitConfig,
    checkpoint_dir: Option<&'a Path>,
    device: &'a Device,
    /// Physically consistent model selection: with a physics penalty and learned scalers, an
    /// epoch's model may only replace a kept model that passed the audit if it passes too.
    audited: bool,
}

/// A stage between epochs: the current and the kept module, the optimizer, the model
/// selection, the history and the first epoch this invocation trains.
struct Progress {
    net: EmmNet,
    best: EmmNet,
    optim: ModuleOptimizer,
    sel: Selection,
    history: Vec<EpochStats>,
    start_epoch: usize,
}

impl Progress {
    /// A fresh stage from `net`, whose validation RMSE is `val` and violations `violations`.
    fn start(net: EmmNet, optim: ModuleOptimizer, val: f64, violations: Option<usize>) -> Self {
        Progress {
            best: net.clone(),
            net,
            optim,
            sel: Selection::start(val, violations),
            history: Vec::new(),
            start_epoch: 1,
        }
    }

    /// Continues from the latest checkpoint of stage `label` in `dir`, or from the start
    /// when there is none.
    fn resume(self, dir: &Path, label: &str) -> Result<Self> {
        let Some(ep_dir) = checkpoint::latest(dir) else {
            eprintln!(
                "[{label}] no checkpoint in {}: starting fresh",
                dir.display()
            );
            return Ok(self);
        };
        let r = checkpoint::load(dir, &ep_dir, label, self.net, self.optim)?;
        let sel = r.state.selection();
        eprintln!(
            "[{label}] resuming after epoch {} (best validation RMSE {:.4} at epoch {})",
            r.state.epoch, sel.best_val, sel.best_epoch
        );
        Ok(Progress {
            net: r.net,
            best: r.best,
            optim: r.optim,
            sel,
            start_epoch: r.state.epoch + 1,
            history: r.state.history,
        })
    }
}

impl Stage<'_> {
    /// Normalised validation RMSE of `net`.
    fn validation_rmse(&self, net: &EmmNet) -> f64 {
        let data = &self.data;
        rmse(
            net,
            self.frame,
            data.validation,
            &data.grid,
            data.warmup,
            data.force_scale_n,
        )
    }

    /// Monotonicity violations of `net` on the audit grid (`None` when the stage does not
    /// audit).
    fn violations(&self, net: &EmmNet) -> Result<Option<usize>> {
        if !self.audited {
            return Ok(None);
        }
        Ok(self.audit(net)?.map(|a| a.total_violations()))
    }

    /// The monotonicity audit of `net` on the audit grid (`None` when the stage does not
    /// audit).
    fn audit(&self, net: &EmmNet) -> Result<Option<Audit>> {
        if !self.audited {
            return Ok(None);
        }
        // The audit reads the scalers and input scales only; `meta` just completes the model.
        let meta = Meta {
            force_scale_n: self.data.force_scale_n as f32,
            alpha_min: 0.0,
            alpha_max: 1.0,
        };
        let model = to_core(&net.to_rollout(self.frame), meta)?;
        Ok(Some(audit(&model, AUDIT_GRID.0, AUDIT_GRID.1)))
    }

    /// The epoch loop from `p.start_epoch`: every epoch trains, validates, selects and
    /// checkpoints, until the last epoch, early stopping or the end of the session's budget
    /// (the reason returned).
    fn train_epochs(&self, mut p: Progress) -> Result<(Progress, StopReason)> {
        let cfg = self.cfg;
        let train_w = windows(self.data.train);
        let partners = if cfg.lambda_diff > 0.0 {
            let partners = matched_windows(self.data.train);
            let matched = matched_count(&partners);
            eprintln!(
                "[{}] difference term (lambda_diff {}): {matched} of {} training windows matched at another level{}",
                cfg.label,
                cfg.lambda_diff,
                partners.len(),
                if matched == 0 {
                    " (no excitation recorded at two levels: the term does nothing, batches as without it)"
                } else {
                    ""
                }
            );
            if matched == 0 {
                Vec::new()
            } else {
                partners
            }
        } else {
            Vec::new()
        };
        let n_batches_full = self.data.train.len().div_ceil(cfg.batch);
        let n_batches = cfg
            .max_batches_per_epoch
            .map_or(n_batches_full, |m| m.min(n_batches_full));
        let total_steps = (cfg.epochs * n_batches).max(1);
        let grid = PenaltyGrid::default();
        let session = SessionBudget {
            start_epoch: p.start_epoch,
            epochs: cfg.session_epochs,
        };
        let t_start = Instant::now();
        // Early stopping waits for the first half of the stage: the learning rate peaks after
        // the warm-up, where a pre-trained model can be knocked off its start, and comes down
        // only in the second half of the cosine schedule, where such a model recovers.
        let min_epochs = cfg.epochs / 2;
        let stopping = |sel: &Selection, epoch: usize| {
            epoch > min_epochs + 1 && sel.patience_used(cfg.patience, self.audited)
        };
        // A resumed run may have used its patience already (then the loop does not run either).
        let mut stop = if stopping(&p.sel, p.start_epoch) {
            StopReason::EarlyStopping
        } else {
            StopReason::Epochs
        };
        for epoch in p.start_epoch..=cfg.epochs {
            if stopping(&p.sel, epoch) {
                stop = StopReason::EarlyStopping;
                break;
            }
            if session.used_before(epoch) {
                stop = StopReason::Session;
                eprintln!("[{}] session budget of {} epoch(s) used: stopping after epoch {}; continue with --resume", cfg.label, epoch - p.start_epoch, epoch - 1);
                break;
            }
            let plan = EpochPlan {
                epoch,
                n_batches,
                total_steps,
            };
            p = self.epoch(p, &train_w, &partners, plan, &grid, t_start)?;
        }
        Ok((p, stop))
    }

    /// One epoch: Adam steps over the training windows, the validation RMSE, the audit, the
    /// model selection, the progress line and the checkpoint. A non-finite validation RMSE
    /// is an error.
    fn epoch(
        &self,
        mut p: Progress,
        train_w: &[Window<'_>],
        partners: &[Vec<usize>],
        plan: EpochPlan,
        grid: &PenaltyGrid,
        t_start: Instant,
    ) -> Result<Progress> {
        let (cfg, epoch) = (self.cfg, plan.epoch);
        let t_epoch = Instant::now();
        let sums;
        (p.net, sums) = train_epoch(
            p.net,
            &mut p.optim,
            self.frame,
            self.data,
            train_w,
            partners,
            cfg,
            plan,
            grid,
            self.device,
        )?;
        let val = self.validation_rmse(&p.net);
        if !val.is_finite() {
            bail!("[{}] the validation RMSE became {val} in epoch {epoch}: stopping, last good checkpoint kept", cfg.label);
        }
        let stats = EpochStats {
            epoch,
            train_mse: sums.mse,
            diff: sums.diff,
            physics: sums.physics,
            val_rmse: val,
            seconds: t_epoch.elapsed().as_secs_f64(),
            violations: self.violations(&p.net)?,
            held: sums.held,
        };
        p.history.push(stats);
        if p.sel.observe(epoch, val, stats.violations) {
            p.best = p.net.clone();
        }
        self.print_epoch(&p, &stats, t_start);
        if let Some(dir) = self.checkpoint_dir {
            checkpoint::save(
                dir,
                &p.net,
                &p.best,
                &p.optim,
                &CheckpointState::new(&cfg.label, epoch, &p.history, &p.sel),
            )?;
        }
        Ok(p)
    }

    /// The progress line of an epoch (`*` when its model is kept), with the time left.
    fn print_epoch(&self, p: &Progress, stats: &EpochStats, t_start: Instant) {
        let (cfg, epoch, val) = (self.cfg, stats.epoch, stats.val_rmse);
        let elapsed = t_start.elapsed().as_secs_f64();
        let done = epoch + 1 - p.start_epoch;
        let eta = elapsed / done as f64 * (cfg.epochs - epoch) as f64;
        eprintln!(
            "\r[{}] epoch {epoch:>3}/{} train MSE {:.3e}{}  physics {:.2e}  val RMSE {:.4} ({:.1} N){}{}{}  {:.1} s/epoch  ETA {}",
            cfg.label,
            cfg.epochs,
            stats.train_mse,
            if cfg.lambda_diff > 0.0 {
                format!("  difference {:.3e}", stats.diff)
            } else {
                String::new()
            },
            stats.physics,
            val,
            val * self.data.force_scale_n,
            stats
                .violations
                .map_or(String::new(), |n| format!("  violations {n}")),
            if stats.held > 0 {
                format!("  held at the step's stability bound {}x", stats.held)
            } else {
                String::new()
            },
            if p.sel.best_epoch == epoch { " *" } else { "  " },
            stats.seconds,
            fmt_duration(eta)
        );
    }

    /// The stage's result from its final state; unless the session's budget ended it, prints
    /// which model is kept (and a warning when it fails the audit). `start_audit` is the
    /// starting model's `(0, validation RMSE, violations)` when this invocation evaluated it.
    fn finish(
        &self,
        p: Progress,
        start_audit: Option<(usize, f64, Option<usize>)>,
        stop: StopReason,
    ) -> FitResult {
        let label = &self.cfg.label;
        let gave_up = passed_over(
            start_audit.into_iter().chain(
                p.history
                    .iter()
                    .map(|h| (h.epoch, h.val_rmse, h.violations)),
            ),
            p.sel.best_val,
        );
        if stop != StopReason::Session {
            eprintln!(
                "[{label}] {}",
                kept_model_summary(p.sel.best_epoch, p.sel.best_val, gave_up)
            );
            if self.audited && !p.sel.best_consistent {
                let what = self
                    .audit(&p.best)
                    .ok()
                    .flatten()
                    .map(|a| a.describe())
                    .filter(|d| !d.is_empty())
                    .unwrap_or_else(|| "eqs. 30-31/37-38".to_string());
                eprintln!(
                    "[{label}] warning: no epoch passed the monotonicity audit; the kept model \
                     violates {what}. With --state-priors penalty the priors in the state are a \
                     penalty (--lambda-ph): a larger one trades accuracy for them (an earlier, less \
                     accurate epoch passes), and a force that does not rise with the velocity or \
                     the stroke (friction) fights them; --state-priors construction holds them for \
                     every weight"
                );
            }
        }
        FitResult {
            best: p.best,
            history: p.history,
            best_epoch: p.sel.best_epoch,
            best_val_rmse: p.sel.best_val,
            stop,
            passed_over: gave_up,
        }
    }
}

/// Where an epoch sits in the schedule.
#[derive(Debug, Clone, Copy)]
struct EpochPlan {
    /// Epoch number (1-based).
    epoch: usize,
    /// Batches per epoch.
    n_batches: usize,
    /// Optimizer steps of the whole stage (the learning-rate schedule's length).
    total_steps: usize,
}

/// The windows of batch `b` of `epoch` (indices into the training windows) and each one's
/// partner in the batch: `cfg.batch` windows of `order`, or with the difference term half
/// as many anchors each followed by a matched window ([`paired_batch`]).
fn batch_windows(
    order: &[usize],
    partners: &[Vec<usize>],
    cfg: &FitConfig,
    epoch: usize,
    b: usize,
) -> (Vec<usize>, Vec<Option<usize>>) {
    let take = |n: usize| &order[(b * n).min(order.len())..((b + 1) * n).min(order.len())];
    if cfg.lambda_diff > 0.0 && !partners.is_empty() {
        let seed = cfg.seed
            ^ (epoch as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        paired_batch(take((cfg.batch / 2).max(1)), partners, seed)
    } else {
        let idx = take(cfg.batch).to_vec();
        let none = vec![None; idx.len()];
        (idx, none)
    }
}

/// What an epoch's batches measured.
#[derive(Debug, Clone, Copy, Default)]
struct EpochSums {
    /// Mean normalised MSE of the batches.
    mse: f64,
    /// Mean matched-difference term of the batches (0 without it).
    diff: f64,
    /// Mean physics loss of the batches.
    physics: f64,
    /// Optimizer steps after which the stability hold moved the constants.
    held: usize,
}

/// One epoch of Adam steps over the shuffled training windows, each followed by the
/// stability hold; returns the module and what its batches measured.
#[allow(clippy::too_many_arguments)]
fn train_epoch(
    mut net: EmmNet,
    optim: &mut ModuleOptimizer,
    frame: &NetFrame,
    data: FitData<'_>,
    train_w: &[Window<'_>],
    partners: &[Vec<usize>],
    cfg: &FitConfig,
    plan: EpochPlan,
    grid: &PenaltyGrid,
    device: &Device,
) -> Result<(EmmNet, EpochSums)> {
    let hold = StabilityHold::new(frame);
    let mut sums = EpochSums::default();
    let EpochPlan {
        epoch,
        n_batches,
        total_steps,
    } = plan;
    let runs: Vec<usize> = data.train.iter().map(|s| s.run).collect();
    let order = epoch_order(&runs, cfg.balance, cfg.seed, epoch);
    for b in 0..n_batches {
        let (idx, partner) = batch_windows(&order, partners, cfg, epoch, b);
        let batch: Vec<Window<'_>> = idx.iter().map(|&i| train_w[i]).collect();
        let p = net.to_rollout(frame);
        // Without a pair in the batch the term is zero: eq. 23's loss alone.
        let paired = cfg.lambda_diff > 0.0 && partner.iter().any(Option::is_some);
        let pairing = paired.then_some(Pairing {
            partner: &partner,
            weight: cfg.lambda_diff,
        });
        let (parts, g) = loss_and_grad_paired(
            &p,
            &batch,
            pairing,
            &data.grid,
            data.warmup,
            data.force_scale_n,
        );
        let mse = parts.mse;
        if !parts.total().is_finite() {
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
            let phys = physics_loss(&net, frame, grid, device);
            let l2 = net.l2_norms(device);
            // The zero term roots the tape in a trained parameter: with cumulative scalers
            // whose gates hold the alpha priors, the penalties have nothing left to act on
            // and are constants without a tape of their own.
            let root = net.log_c.val().sum().mul_scalar(0.0);
            let aux = phys.clone().mul_scalar(cfg.lambda_ph) + l2.mul_scalar(cfg.lambda_l2) + root;
            let phys_v = scalar(phys);
            (GradientsParams::from_grads(aux.backward(), &net), phys_v)
        } else {
            (GradientsParams::new(), 0.0)
        };
        net.add_rollout_grads(frame, &g, [true; 4], &mut gp, device);
        let step = (epoch - 1) * n_batches + b;
        let lr = learning_rate(cfg.lr, step, total_steps);
        let moved;
        (net, moved) = hold.hold_net(optim.step(lr, net, gp));
        sums.held += usize::from(moved);
        sums.mse += mse;
        sums.diff += parts.diff;
        sums.physics += phys_v;
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
    let n = n_batches.max(1) as f64;
    sums.mse /= n;
    sums.diff /= n;
    sums.physics /= n;
    Ok((net, sums))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batches_carry_pairs_only_where_windows_match() {
        let order: Vec<usize> = (0..40).collect();
        let cfg = FitConfig {
            lambda_diff: 2.0,
            ..FitConfig::default()
        };
        // Nothing matched: full batches of the order, as without the term.
        let (idx, partner) = batch_windows(&order, &[], &cfg, 1, 1);
        assert_eq!(idx, (16..32).collect::<Vec<_>>());
        assert!(partner.iter().all(Option::is_none));
        // Every window matched with the one 20 places away: eight pairs, mutual.
        let partners: Vec<Vec<usize>> = (0..40).map(|i| vec![(i + 20) % 40]).collect();
        let (idx, partner) = batch_windows(&order, &partners, &cfg, 1, 1);
        assert_eq!(idx.len(), 16);
        for (k, p) in partner.iter().enumerate() {
            let p = p.expect("every window has its partner");
            assert_eq!(partner[p], Some(k));
            assert_eq!(partners[idx[k]], vec![idx[p]]);
        }
        // Without the term the partners are ignored.
        let off = FitConfig::default();
        assert_eq!(
            batch_windows(&order, &partners, &off, 1, 1).0,
            (16..32).collect::<Vec<_>>()
        );
    }

    #[test]
    fn epoch_order_is_a_permutation_and_reproducible() {
        let runs: Vec<usize> = (0..100).map(|i| i / 10).collect();
        let a = epoch_order(&runs, Balance::Windows, 7, 3);
        let mut s = a.clone();
        s.sort();
        assert_eq!(s, (0..100).collect::<Vec<_>>());
        assert_eq!(a, epoch_order(&runs, Balance::Windows, 7, 3));
        assert_ne!(a, epoch_order(&runs, Balance::Windows, 7, 4));
    }

    #[test]
    fn run_balanced_order_weighs_every_run_alike() {
        // Run 0 has 90 windows, run 1 has 10: by windows run 1 gets 10 % of the draws, by
        // runs about half of them.
        let runs: Vec<usize> = (0..100).map(|i| usize::from(i >= 90)).collect();
        let mut short = 0usize;
        let epochs = 200;
        for epoch in 1..=epochs {
            let order = epoch_order(&runs, Balance::Runs, 3, epoch);
            assert_eq!(order.len(), runs.len());
            assert!(order.iter().all(|&i| i < runs.len()));
            short += order.iter().filter(|&&i| runs[i] == 1).count();
        }
        let share = short as f64 / (epochs * runs.len()) as f64;
        assert!((share - 0.5).abs() < 0.02, "share of the short run {share}");
        assert_eq!(
            epoch_order(&runs, Balance::Runs, 3, 5),
            epoch_order(&runs, Balance::Runs, 3, 5)
        );
    }

    #[test]
    fn the_default_stage_is_the_command_line_default() {
        let t = crate::config::TrainConfig::default();
        let f = FitConfig::default();
        assert_eq!(
            (f.lambda_ph, f.epochs, f.patience),
            (t.lambda_ph, t.epochs, t.patience)
        );
    }
}
