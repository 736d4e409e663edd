//! The configuration of a job, with every default written once.
//!
//! [`Config`] holds the three parts a dataset-reading, model-training command needs:
//! [`DataConfig`] (which dataset, how it is split and cut into windows), [`ModelConfig`]
//! (variant, scaler size, integrator) and [`TrainConfig`] (the optimiser and its schedule).
//! Their `Default` impls are the only place defaults are written: the library's
//! [`PipelineConfig`] and [`FitConfig`] are built from them, and the command line
//! ([`ConfigArgs`]) holds only `Option`s that override a configuration (the defaults, or a
//! TOML file given with `--config`). A configuration is written to and read from TOML
//! ([`Config::to_toml`], [`Config::load`]); `nemm train --report`, `nemm compare` and
//! `nemm demo` save the effective one as `config.toml`, and `nemm sweep` runs each job from
//! such a file.

use crate::data::preprocess::{
    PrepareConfig, DEFAULT_SEQUENCE_S, DEFAULT_SPLIT_SEED, DEFAULT_TEST_ALPHAS, DEFAULT_WARMUP_S,
};
use crate::train::fit::FitConfig;
use crate::train::pipeline::PipelineConfig;
use anyhow::{bail, Context, Result};
use nemm_core::{Integrator, ModelKind};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Name of the effective configuration saved into a report folder.
pub const CONFIG_FILE: &str = "config.toml";

/// Nonzero `lambda_ph` values below this are most likely the paper's numbers (Table 5: 0.005
/// to 0.025) rather than this crate's.
const PAPER_SCALE_LAMBDA_PH: f64 = 0.1;

/// Which dataset a job reads and how it is split and cut into windows: the data options
/// every dataset-reading command shares.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DataConfig {
    /// Dataset folder (manifest.toml + CSV runs; see docs/data-format.md). Empty: none given.
    pub dir: PathBuf,
    /// Oil-loss level(s) held out for testing (Table 2).
    pub test_alphas: Vec<f64>,
    /// Seed of the split (which windows are validation windows).
    pub seed: u64,
    /// Scored length of a training window \[s\] (section 5.3: 0.5 s).
    pub window_s: f64,
    /// Warm-up prefix of a window, simulated but not scored \[s\].
    pub warmup_s: f64,
}

impl Default for DataConfig {
    fn default() -> Self {
        Self {
            dir: PathBuf::new(),
            test_alphas: DEFAULT_TEST_ALPHAS.to_vec(),
            seed: DEFAULT_SPLIT_SEED,
            window_s: DEFAULT_SEQUENCE_S,
            warmup_s: DEFAULT_WARMUP_S,
        }
    }
}

impl DataConfig {
    /// The preprocessing configuration of section 5.3 with these options.
    pub fn prepare_config(&self) -> PrepareConfig {
        let mut c = PrepareConfig::default();
        c.split.test_alphas = self.test_alphas.clone();
        c.split.seed = self.seed;
        c.sequences.length_s = self.window_s;
        c.sequences.warmup_s = self.warmup_s;
        c
    }

    /// The dataset folder, or an error naming the option when none is given.
    pub fn require_dir(&self) -> Result<&Path> {
        if self.dir.as_os_str().is_empty() {
            bail!("no dataset: give --data DIR (or `[data] dir` in --config)");
        }
        Ok(&self.dir)
    }
}

/// Serde of `ModelKind` / `Integrator` by their `name()` (the CLI spelling).
mod by_name {
    use serde::{Deserialize, Deserializer, Serializer};
    use std::fmt::Display;
    use std::str::FromStr;

    pub trait Named: FromStr {
        fn name_of(&self) -> &'static str;
    }
    impl Named for nemm_core::ModelKind {
        fn name_of(&self) -> &'static str {
            self.name()
        }
    }
    impl Named for nemm_core::Integrator {
        fn name_of(&self) -> &'static str {
            self.name()
        }
    }

    pub fn serialize<T: Named, S: Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(v.name_of())
    }

    pub fn deserialize<'de, T, D>(d: D) -> Result<T, D::Error>
    where
        T: Named,
        T::Err: Display,
        D: Deserializer<'de>,
    {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// The model: variant, scaler size and integrator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Variant `nemm train` trains (`nemm compare` trains all four).
    #[serde(with = "by_name")]
    pub variant: ModelKind,
    /// Hidden width H of every scaler (Table 3: 8, 16, 32).
    pub hidden: usize,
    /// Hidden layers L of every scaler (Table 3: 3, 5, 7, 9).
    pub layers: usize,
    /// Integrator (paper: RK4; RK3 selectable).
    #[serde(with = "by_name")]
    pub integrator: Integrator,
    /// Bounds `(s_min, s_max)` of the `b_fl` scale factor.
    pub b_fl_bounds: (f32, f32),
    /// Bounds of the `b_pr` and `k_pr` scale factors (`s_max` of `k_pr` is lowered if the
    /// explicit-RK stability check needs it).
    pub pr_bounds: (f32, f32),
    /// Integration (deployment) rate of the model \[Hz\]: the model steps at
    /// `1 / rate_hz` whatever the data's sample rate, and the exported blob carries that step
    /// (docs/preprocessing.md, "Model rate and data rate").
    pub rate_hz: f64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            variant: ModelKind::Nemm,
            hidden: 16,
            layers: 5,
            integrator: Integrator::Rk4,
            b_fl_bounds: (0.1, 10.0),
            pr_bounds: (0.1, 5.0),
            rate_hz: DEFAULT_MODEL_RATE_HZ,
        }
    }
}

/// The default model rate \[Hz\]: the firmware's 10 kHz step.
pub const DEFAULT_MODEL_RATE_HZ: f64 = 10_000.0;

/// The training procedure: optimiser, penalties, schedule and budget.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Windows per batch (Table 3: 4, 8, 16).
    pub batch: usize,
    /// Adam learning rate at the start (Table 3: 5e-3, 1e-2, 1e-3); cosine decay to 10 %.
    pub lr: f64,
    /// Physics-inconsistency weight `lambda_ph`: 5 is the paper's best (Table 5: 0.005) in
    /// this crate's normalisation of the penalty, which takes 1000 times the paper's number
    /// to act (docs/training.md, "The scale of `lambda_ph`").
    pub lambda_ph: f64,
    /// Weight of the L2 term `sum ||W||_2` over the scalers' linear weights (paper: 1e-3).
    pub lambda_l2: f64,
    /// Maximum epochs of the neural stages.
    pub epochs: usize,
    /// Early stopping: epochs without progress on the validation RMSE.
    pub patience: usize,
    /// Epochs of the Linear EMM stage.
    pub linear_epochs: usize,
    /// Adam learning rate of the Linear EMM stage (on `ln(c) / LOG_CONSTANT_SCALE`: 3e-3 moves
    /// the constants by ~3 % per step).
    pub linear_lr: f64,
    /// Full-batch Adam steps of the quasi-static `b_fl` regression (eq. 41).
    pub qs_steps: usize,
    /// At most this many batches per epoch (a random subset; for quick runs).
    pub max_batches: Option<usize>,
    /// Train at most this many epochs per stage in one invocation, then stop with a
    /// checkpoint (time-boxed sessions); `--resume` continues.
    pub session_epochs: Option<usize>,
    /// Seed of the initial weights and the data order.
    pub seed: u64,
    /// Gradient clipping by norm, per parameter tensor.
    pub grad_clip: f32,
    /// Adam's epsilon (PyTorch's default 1e-8; burn's default 1e-5 would dominate the small
    /// gradients of a normalised MSE).
    pub adam_eps: f32,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            batch: 16,
            lr: 5e-3,
            lambda_ph: 5.0,
            lambda_l2: 1e-3,
            epochs: 40,
            patience: 8,
            linear_epochs: 8,
            linear_lr: 3e-3,
            qs_steps: 600,
            max_batches: None,
            session_epochs: None,
            seed: DEFAULT_SPLIT_SEED,
            grad_clip: 1.0,
            adam_eps: 1e-8,
        }
    }
}

impl TrainConfig {
    /// The settings of one stage labelled `label` (the neural stages' epochs and lr).
    pub fn fit_config(&self, label: &str) -> FitConfig {
        FitConfig {
            label: label.to_string(),
            epochs: self.epochs,
            batch: self.batch,
            lr: self.lr,
            lambda_l2: self.lambda_l2,
            lambda_ph: self.lambda_ph,
            patience: self.patience,
            grad_clip: self.grad_clip,
            max_batches_per_epoch: self.max_batches,
            seed: self.seed,
            session_epochs: self.session_epochs,
            adam_eps: self.adam_eps,
        }
    }
}

/// Everything a training job reads: data, model, training.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Dataset and split.
    pub data: DataConfig,
    /// Model.
    pub model: ModelConfig,
    /// Training.
    pub train: TrainConfig,
}

impl Config {
    /// Reads a configuration from a TOML file; absent keys take their defaults.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("invalid configuration {}", path.display()))
    }

    /// The configuration as TOML (every key, so that the file alone reproduces the job).
    pub fn to_toml(&self) -> Result<String> {
        Ok(toml::to_string(self)?)
    }

    /// Writes the configuration as TOML to `path` (atomically).
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::fsutil::write_atomic_bytes(path, self.to_toml()?.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))
    }

    /// Checks the values no training can run with.
    pub fn validate(&self) -> Result<()> {
        let (m, t) = (&self.model, &self.train);
        if t.batch == 0 || m.hidden == 0 || m.layers == 0 {
            bail!("--batch, --hidden and --layers must be positive");
        }
        if m.hidden > nemm_core::mlp::MAX_HIDDEN || m.layers > nemm_core::mlp::MAX_LAYERS {
            bail!(
                "--hidden must be <= {} and --layers <= {} (the capacity of nemm-core)",
                nemm_core::mlp::MAX_HIDDEN,
                nemm_core::mlp::MAX_LAYERS
            );
        }
        if !(t.lambda_ph.is_finite() && t.lambda_ph >= 0.0) {
            bail!("--lambda-ph must be a non-negative number");
        }
        if !(m.rate_hz.is_finite() && m.rate_hz > 0.0) {
            bail!("--model-rate-hz must be a positive rate in Hz");
        }
        Ok(())
    }

    /// The training procedure's configuration.
    pub fn pipeline_config(&self) -> PipelineConfig {
        let (m, t) = (&self.model, &self.train);
        PipelineConfig {
            hidden: m.hidden,
            layers: m.layers,
            integrator: m.integrator,
            fit: t.fit_config(m.variant.name()),
            linear_epochs: t.linear_epochs,
            linear_lr: t.linear_lr,
            qs_steps: t.qs_steps,
            b_fl_bounds: m.b_fl_bounds,
            pr_bounds: m.pr_bounds,
            model_rate_hz: m.rate_hz,
        }
    }
}

/// A note for `lambda_ph` values that look like the paper's numbers: in this crate's
/// normalisation they barely act (docs/training.md, "The scale of `lambda_ph`"). `None` when
/// every value is 0 or at least 0.1.
pub fn lambda_ph_scale_note(values: &[f64]) -> Option<String> {
    let small: Vec<String> = values
        .iter()
        .filter(|&&l| l > 0.0 && l < PAPER_SCALE_LAMBDA_PH)
        .map(|l| l.to_string())
        .collect();
    (!small.is_empty()).then(|| {
        format!(
            "note: --lambda-ph {} looks like the paper's scale; this crate's penalty takes 1000 \
             times the paper's numbers (the paper's 0.005 is 5 here), and at this value the \
             physics loss barely acts (docs/training.md, \"The scale of lambda_ph\")",
            small.join(",")
        )
    })
}

/// `help` text of an option with its default (from the `Default` impls).
fn with_default(text: &str, default: impl std::fmt::Display) -> String {
    format!("{text} [default: {default}]")
}

/// The command-line options of a training job: each overrides one field of a [`Config`]
/// (the defaults, or the `--config` file), so no default is written here.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ConfigArgs {
    /// Job configuration (TOML: `[data]`, `[model]`, `[train]`; see docs/training.md); the
    /// options given as well override it.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Dataset folder (manifest.toml + CSV runs; see docs/data-format.md).
    #[arg(long, value_name = "DIR")]
    pub data: Option<PathBuf>,
    /// Overrides [`DataConfig::test_alphas`].
    #[arg(long, value_delimiter = ',', help = with_default(
        "Oil-loss level(s) held out for testing (Table 2), comma-separated",
        DataConfig::default().test_alphas.iter().map(f64::to_string).collect::<Vec<_>>().join(",")))]
    pub test_alpha: Option<Vec<f64>>,
    /// Overrides [`DataConfig::seed`] and [`TrainConfig::seed`].
    #[arg(long, help = with_default(
        "Seed of the split, the initial weights and the data order", TrainConfig::default().seed))]
    pub seed: Option<u64>,
    /// Overrides [`ModelConfig::hidden`].
    #[arg(long, help = with_default(
        "Hidden width H of the scalers (Table 3: 8, 16, 32)", ModelConfig::default().hidden))]
    pub hidden: Option<usize>,
    /// Overrides [`ModelConfig::layers`].
    #[arg(long, help = with_default(
        "Hidden layers L of the scalers (Table 3: 3, 5, 7, 9)", ModelConfig::default().layers))]
    pub layers: Option<usize>,
    /// Overrides [`ModelConfig::integrator`].
    #[arg(long, help = with_default(
        "Integrator: rk4 or rk3", ModelConfig::default().integrator.name()))]
    pub integrator: Option<Integrator>,
    /// Overrides [`ModelConfig::rate_hz`].
    #[arg(long, help = with_default(
        "Integration rate of the model in Hz, independent of the data's sample rate (the \
         exported step is 1 / rate)", ModelConfig::default().rate_hz))]
    pub model_rate_hz: Option<f64>,
    /// Overrides [`TrainConfig::batch`].
    #[arg(long, help = with_default(
        "Windows per batch (Table 3: 4, 8, 16)", TrainConfig::default().batch))]
    pub batch: Option<usize>,
    /// Overrides [`TrainConfig::lr`].
    #[arg(long, help = with_default(
        "Adam learning rate (Table 3: 5e-3, 1e-2, 1e-3)", TrainConfig::default().lr))]
    pub lr: Option<f64>,
    /// Overrides [`TrainConfig::lambda_ph`].
    #[arg(long, value_delimiter = ',', help = with_default(
        "Physics-inconsistency weight lambda_ph (the paper's best, 0.005, in this crate's \
         penalty normalisation, x1000). `nemm sweep` takes a comma-separated list (default \
         0,5,15,25: Table 5's values x1000)", TrainConfig::default().lambda_ph))]
    pub lambda_ph: Option<Vec<f64>>,
    /// Overrides [`TrainConfig::lambda_l2`].
    #[arg(long, help = with_default(
        "L2 weight lambda on the scalers' linear weights", TrainConfig::default().lambda_l2))]
    pub lambda_l2: Option<f64>,
    /// Overrides [`TrainConfig::epochs`].
    #[arg(long, help = with_default(
        "Maximum epochs of the neural stages", TrainConfig::default().epochs))]
    pub epochs: Option<usize>,
    /// Overrides [`TrainConfig::patience`].
    #[arg(long, help = with_default(
        "Early stopping: epochs without a better validation RMSE", TrainConfig::default().patience))]
    pub patience: Option<usize>,
    /// Overrides [`TrainConfig::linear_epochs`].
    #[arg(long, help = with_default(
        "Epochs of the Linear EMM stage", TrainConfig::default().linear_epochs))]
    pub linear_epochs: Option<usize>,
    /// At most this many batches per epoch (random subset; for quick runs).
    #[arg(long)]
    pub max_batches: Option<usize>,
    /// Train at most this many epochs per stage in this invocation, then stop with a
    /// checkpoint (time-boxed sessions); continue with --resume.
    #[arg(long)]
    pub session_epochs: Option<usize>,
    /// Overrides [`DataConfig::window_s`].
    #[arg(long, help = with_default(
        "Scored length of a training window (s; section 5.3: 0.5 s)", DataConfig::default().window_s))]
    pub window_s: Option<f64>,
    /// Overrides [`DataConfig::warmup_s`].
    #[arg(long, help = with_default(
        "Warm-up prefix of a window, simulated but not scored (s)", DataConfig::default().warmup_s))]
    pub warmup_s: Option<f64>,
}

impl ConfigArgs {
    /// The `--config` file (or the defaults) with the given options applied. A
    /// `--lambda-ph` list is applied only when it has one value (`nemm sweep` reads the list
    /// itself, see [`ConfigArgs::lambda_ph_list`]).
    pub fn base(&self) -> Result<Config> {
        let mut c = match &self.config {
            Some(path) => Config::load(path)?,
            None => Config::default(),
        };
        self.apply(&mut c);
        Ok(c)
    }

    /// The configuration of one training job: [`ConfigArgs::base`], which must have a
    /// dataset and at most one `--lambda-ph` value, validated.
    pub fn resolve(&self) -> Result<Config> {
        if let Some(list) = self.lambda_ph.as_deref().filter(|l| l.len() > 1) {
            bail!(
                "--lambda-ph takes one value here ({} given); `nemm sweep` trains one model per value",
                list.len()
            );
        }
        let c = self.base()?;
        c.data.require_dir()?;
        c.validate()?;
        if let Some(note) = lambda_ph_scale_note(&[c.train.lambda_ph]) {
            eprintln!("{note}");
        }
        Ok(c)
    }

    /// The `--lambda-ph` list, if given.
    pub fn lambda_ph_list(&self) -> Option<&[f64]> {
        self.lambda_ph.as_deref()
    }

    /// Applies the given options onto `c`.
    pub fn apply(&self, c: &mut Config) {
        fn set<T: Clone>(field: &mut T, value: &Option<T>) {
            if let Some(v) = value {
                *field = v.clone();
            }
        }
        let (d, m, t) = (&mut c.data, &mut c.model, &mut c.train);
        set(&mut d.dir, &self.data);
        set(&mut d.test_alphas, &self.test_alpha);
        set(&mut d.seed, &self.seed);
        set(&mut d.window_s, &self.window_s);
        set(&mut d.warmup_s, &self.warmup_s);
        set(&mut m.hidden, &self.hidden);
        set(&mut m.layers, &self.layers);
        set(&mut m.integrator, &self.integrator);
        set(&mut m.rate_hz, &self.model_rate_hz);
        set(&mut t.seed, &self.seed);
        set(&mut t.batch, &self.batch);
        set(&mut t.lr, &self.lr);
        if let Some([one]) = self.lambda_ph.as_deref() {
            t.lambda_ph = *one;
        }
        set(&mut t.lambda_l2, &self.lambda_l2);
        set(&mut t.epochs, &self.epochs);
        set(&mut t.patience, &self.patience);
        set(&mut t.linear_epochs, &self.linear_epochs);
        if self.max_batches.is_some() {
            t.max_batches = self.max_batches;
        }
        if self.session_epochs.is_some() {
            t.session_epochs = self.session_epochs;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: ConfigArgs,
    }

    #[test]
    fn the_library_defaults_are_the_command_line_defaults() {
        let cli = Cli::parse_from(["nemm"]).args.base().expect("defaults");
        assert_eq!(cli, Config::default());
        assert_eq!(cli.pipeline_config(), PipelineConfig::default());
        assert_eq!(cli.pipeline_config().fit, FitConfig::default());
        assert_eq!(FitConfig::default().lambda_ph, 5.0);
        // The trainer preprocesses as the library (and `nemm data prepare`) does.
        assert_eq!(cli.data.prepare_config(), PrepareConfig::default());
    }

    #[test]
    fn options_override_a_config_file_and_the_file_round_trips() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join(CONFIG_FILE);
        let mut file = Config::default();
        file.model.hidden = 8;
        file.model.variant = ModelKind::NemmLight;
        file.train.lambda_ph = 15.0;
        file.train.max_batches = Some(3);
        file.save(&path).expect("save");
        let text = std::fs::read_to_string(&path).expect("read");
        assert!(text.contains("variant = \"nemm-light\""), "{text}");
        assert!(text.contains("integrator = \"rk4\""), "{text}");
        assert_eq!(Config::load(&path).expect("load"), file);
        let args = Cli::parse_from([
            "nemm",
            "--config",
            path.to_str().expect("utf-8"),
            "--data",
            "bench",
            "--layers",
            "3",
            "--integrator",
            "rk3",
            "--seed",
            "7",
        ])
        .args;
        let c = args.resolve().expect("resolve");
        assert_eq!((c.model.hidden, c.model.layers), (8, 3));
        assert_eq!(c.model.integrator, Integrator::Rk3);
        assert_eq!((c.train.lambda_ph, c.train.max_batches), (15.0, Some(3)));
        assert_eq!((c.data.seed, c.train.seed), (7, 7));
        assert_eq!(c.data.dir, PathBuf::from("bench"));
        // A partial file takes the defaults for the rest; unknown keys are refused.
        let partial: Config = toml::from_str("[train]\nepochs = 3\n").expect("partial");
        assert_eq!(partial.train.epochs, 3);
        assert_eq!(partial.model, ModelConfig::default());
        assert!(toml::from_str::<Config>("[train]\nepoch = 3\n").is_err());
    }

    #[test]
    fn a_job_needs_a_dataset_and_one_lambda() {
        let err = Cli::parse_from(["nemm"]).args.resolve().unwrap_err();
        assert!(err.to_string().contains("--data"), "{err}");
        let err = Cli::parse_from(["nemm", "--data", "d", "--lambda-ph", "0,5"])
            .args
            .resolve()
            .unwrap_err();
        assert!(err.to_string().contains("one value"), "{err}");
        assert!(Cli::try_parse_from(["nemm", "--integrator", "euler"]).is_err());
    }

    #[test]
    fn paper_scale_lambda_ph_gets_a_note() {
        let note = lambda_ph_scale_note(&[0.0, 0.005, 0.015, 0.025]).expect("a note");
        assert!(note.contains("0.005,0.015,0.025"), "{note}");
        assert!(note.contains("0.005 is 5 here"), "{note}");
        assert_eq!(lambda_ph_scale_note(&[0.0, 5.0, 15.0, 25.0]), None);
        assert_eq!(
            lambda_ph_scale_note(&[TrainConfig::default().lambda_ph]),
            None
        );
        assert_eq!(lambda_ph_scale_note(&[0.0]), None);
    }
}
