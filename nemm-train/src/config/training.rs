//! The training section ([`TrainConfig`], `[train]` of a configuration, and its
//! command-line options [`TrainOptions`]): optimiser, penalties, schedule and budget.

use super::args::with_default;
use super::section::section;
use crate::data::preprocess::DEFAULT_SPLIT_SEED;
use serde::{Deserialize, Serialize};

/// How the training windows are drawn into an epoch's batches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Balance {
    /// Each draw picks a training run uniformly, then one of its windows uniformly (with
    /// replacement): short runs (the fast, small-stroke ones where degradation shows) weigh
    /// as much as long slow ones.
    #[default]
    Runs,
    /// Each window once per epoch in a shuffled order: a run weighs by its length.
    Windows,
}

impl Balance {
    /// `runs` or `windows` (the option's and the TOML key's spelling).
    pub const fn name(self) -> &'static str {
        match self {
            Balance::Runs => "runs",
            Balance::Windows => "windows",
        }
    }
}

section! {
    /// The training procedure: optimiser, penalties, schedule and budget (`[train]` of a
    /// configuration file). Absent keys take the defaults ([`TrainConfig::default`]).
    pub struct TrainConfig;
    /// The training options of the command line: each given one overrides its field of a
    /// [`TrainConfig`] ([`TrainOptions::over`]). `seed` is the data options' `--seed`
    /// (`super::ConfigArgs` sets both); the keys without an option (`linear_lr`,
    /// `qs_steps`, `grad_clip`, `adam_eps`) are set in a `--config` file.
    pub struct TrainOptions;

    /// Windows per batch (Table 3: 4, 8, 16).
    #[arg(long, help = with_default(
        "Windows per batch (Table 3: 4, 8, 16)", TrainConfig::default().batch))]
    batch: usize = 16, Option<usize>;
    /// Adam learning rate at the start (Table 3: 5e-3, 1e-2, 1e-3); cosine decay to 10 %.
    #[arg(long, help = with_default(
        "Adam learning rate (Table 3: 5e-3, 1e-2, 1e-3)", TrainConfig::default().lr))]
    lr: f64 = 5e-3, Option<f64>;
    /// Physics-inconsistency weight `lambda_ph`: 5 is the paper's best (Table 5: 0.005) in
    /// this crate's normalisation of the penalty, which takes 1000 times the paper's number
    /// to act (docs/training.md, "The scale of `lambda_ph`"). On the command line a list:
    /// one value sets it, `nemm sweep` trains one job per value.
    #[arg(long, value_delimiter = ',', help = with_default(
        "Physics-inconsistency weight lambda_ph (the paper's best, 0.005, in this crate's \
         penalty normalisation, x1000). `nemm sweep` takes a comma-separated list (default \
         0,5,15,25: Table 5's values x1000)", TrainConfig::default().lambda_ph))]
    lambda_ph: f64 = 5.0, Option<Vec<f64>>;
    /// Weight `lambda_diff` of the matched-difference term (0, the paper's loss: off): for
    /// windows of the same excitation recorded at two levels, the model's force difference
    /// against the measured one (docs/training.md, "The difference term").
    #[arg(long, help = with_default(
        "Weight of the matched-difference term: windows of the same excitation at two levels \
         fit the measured force difference between the levels (0: the paper's loss)",
        TrainConfig::default().lambda_diff))]
    lambda_diff: f64 = 0.0, Option<f64>;
    /// Weight of the L2 term `sum ||W||_2` over the scalers' linear weights (paper: 1e-3).
    #[arg(long, help = with_default(
        "L2 weight lambda on the scalers' linear weights", TrainConfig::default().lambda_l2))]
    lambda_l2: f64 = 1e-3, Option<f64>;
    /// Maximum epochs of the neural stages.
    #[arg(long, help = with_default(
        "Maximum epochs of the neural stages", TrainConfig::default().epochs))]
    epochs: usize = 40, Option<usize>;
    /// Early stopping: epochs without progress on the validation RMSE.
    #[arg(long, help = with_default(
        "Early stopping: epochs without a better validation RMSE", TrainConfig::default().patience))]
    patience: usize = 8, Option<usize>;
    /// Epochs of the Linear EMM stage.
    #[arg(long, help = with_default(
        "Epochs of the Linear EMM stage", TrainConfig::default().linear_epochs))]
    linear_epochs: usize = 8, Option<usize>;
    /// Adam learning rate of the Linear EMM stage (on `ln(c) / LOG_CONSTANT_SCALE`: 3e-3 moves
    /// the constants by ~3 % per step).
    #[arg(skip)]
    linear_lr: f64 = 3e-3, Option<f64>;
    /// Full-batch Adam steps of the quasi-static `b_fl` regression (eq. 41).
    #[arg(skip)]
    qs_steps: usize = 600, Option<usize>;
    /// At most this many batches per epoch (a random subset; for quick runs).
    #[arg(long, help = "At most this many batches per epoch (random subset; for quick runs)")]
    max_batches: Option<usize> = None, Option<usize>;
    /// Train at most this many epochs per stage in one invocation, then stop with a
    /// checkpoint (time-boxed sessions); `--resume` continues.
    #[arg(long, help = "Train at most this many epochs per stage in this invocation, then stop \
        with a checkpoint (time-boxed sessions); continue with --resume")]
    session_epochs: Option<usize> = None, Option<usize>;
    /// Seed of the initial weights and the data order.
    #[arg(skip)]
    seed: u64 = DEFAULT_SPLIT_SEED, Option<u64>;
    /// Gradient clipping by norm, per parameter tensor.
    #[arg(skip)]
    grad_clip: f32 = 1.0, Option<f32>;
    /// Adam's epsilon (PyTorch's default 1e-8; burn's default 1e-5 would dominate the small
    /// gradients of a normalised MSE).
    #[arg(skip)]
    adam_eps: f32 = 1e-8, Option<f32>;
    /// How the training windows are drawn into batches: every run equally often
    /// ([`Balance::Runs`], the default) or every window once per epoch ([`Balance::Windows`]).
    #[arg(long, value_enum, help = with_default(
        "How batches draw the training windows: runs (every run equally often) or windows \
         (every window once per epoch)", TrainConfig::default().balance.name()))]
    balance: Balance = Balance::default(), Option<Balance>;
}
