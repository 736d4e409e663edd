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

use crate::data::dataset::{self, Manifest};
use crate::data::preprocess::{
    self, PrepareConfig, VelocitySource, DEFAULT_CUTOFF_HZ, DEFAULT_SEQUENCE_S, DEFAULT_SPLIT_SEED,
    DEFAULT_TEST_ALPHAS, DEFAULT_VALIDATION_FRACTION, DEFAULT_WARMUP_S,
};
use crate::train::fit::FitConfig;
use crate::train::pipeline::{AlphaPriors, PipelineConfig};
use anyhow::{bail, Context, Result};
use nemm_core::{Integrator, ModelKind};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Name of the effective configuration saved into a report folder.
pub const CONFIG_FILE: &str = "config.toml";

/// Name of a dataset's own data options, next to its `manifest.toml`: read by every command
/// that reads the dataset, written by `nemm data prepare --save-options`.
pub const DATA_OPTIONS_FILE: &str = "nemm-data.toml";

/// Nonzero `lambda_ph` values below this are most likely the paper's numbers (Table 5: 0.005
/// to 0.025) rather than this crate's.
const PAPER_SCALE_LAMBDA_PH: f64 = 0.1;

/// The adaptive cut-off is at most this fraction of the sample rate (the Butterworth design
/// needs `fc < fs / 2`; at `0.4 fs` the model's 30 Hz band still passes within 0.013 % at
/// 300 Hz, and the zero-phase filter's zero at Nyquist still removes the noise there).
pub const CUTOFF_FRACTION_OF_RATE: f64 = 0.4;

/// Test fraction at the end of every run chosen when the dataset has fewer than three
/// levels (no level can be held out and interpolated).
pub const DEFAULT_TEST_TAIL: f64 = 0.2;

/// Which dataset a job reads and how it is filtered, split and cut into windows: the data
/// options every dataset-reading command shares (`nemm data check/prepare`, `bench plot`,
/// `train`, `compare`, `sweep`, `demo`).
///
/// `None` means "not given": [`resolve_data`] fills it from the dataset's
/// [`DATA_OPTIONS_FILE`] or chooses it from the data (the cut-off from the sample rate, the
/// test set from the levels present). A resolved configuration (as saved in `config.toml`)
/// has every key set. The test set is one group: `test_alphas`, `test_runs` and `test_tail`
/// given at one layer replace all three of a lower layer.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DataConfig {
    /// Dataset folder (manifest.toml + CSV runs; see docs/data-format.md). Empty: none given.
    pub dir: PathBuf,
    /// Cut-off of the zero-phase low-pass before differentiation \[Hz\]; chosen from the
    /// data: `min(150 Hz, 0.4 x sample rate)`.
    pub cutoff_hz: Option<f64>,
    /// Velocity source: `auto` (the CSV's `velocity_m_s` column where a run has one, else the
    /// differentiated displacement; default), `differentiated`, `measured` or `causal` (the
    /// firmware's online estimate, [`crate::data::preprocess::causal_velocity`]).
    pub velocity: Option<VelocitySource>,
    /// Scored length of a training window \[s\] (section 5.3: 0.5 s).
    pub window_s: Option<f64>,
    /// Warm-up prefix of a window, simulated but not scored \[s\] (default 0.05 s).
    pub warmup_s: Option<f64>,
    /// Oil-loss level(s) whose runs are held out for testing (Table 2: 0.15).
    pub test_alphas: Option<Vec<f64>>,
    /// Glob patterns on run files (path relative to the manifest, or file name) of runs held
    /// out for testing.
    pub test_runs: Option<Vec<String>>,
    /// Fraction of every training run, at its end, held out for testing.
    pub test_tail: Option<f64>,
    /// Levels used for training and validation (default: every level not held out).
    pub train_alphas: Option<Vec<f64>>,
    /// Glob patterns of run files not used at all.
    pub exclude_runs: Option<Vec<String>>,
    /// Fraction of each training run held out for validation, as one contiguous stretch
    /// (default 0.2).
    pub validation_fraction: Option<f64>,
    /// Seed of the validation stretches' places (default 1).
    pub seed: Option<u64>,
}

/// Where a resolved data option came from.
#[derive(Debug, Clone, PartialEq)]
pub enum OptionSource {
    /// The command line or `--config`.
    Given,
    /// The dataset's [`DATA_OPTIONS_FILE`].
    DatasetFile,
    /// Chosen from the data, with the reason.
    Data(String),
    /// The built-in default.
    Default,
}

impl std::fmt::Display for OptionSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            OptionSource::Given => write!(f, "given"),
            OptionSource::DatasetFile => write!(f, "{DATA_OPTIONS_FILE}"),
            OptionSource::Data(why) => write!(f, "chosen from the data: {why}"),
            OptionSource::Default => write!(f, "default"),
        }
    }
}

/// A resolved data configuration and where each option came from.
#[derive(Debug, Clone, PartialEq)]
pub struct ResolvedData {
    /// Every key set.
    pub config: DataConfig,
    /// `(option, value, source)` in print order.
    pub choices: Vec<(&'static str, String, OptionSource)>,
    /// The dataset's options file, if one was read.
    pub options_file: Option<PathBuf>,
}

impl ResolvedData {
    /// The block printed at the start of every dataset-reading command.
    pub fn block(&self) -> String {
        let mut s = String::new();
        let _ = write!(s, "data options");
        if let Some(f) = &self.options_file {
            let _ = write!(s, " (options file {} read; flags override it)", f.display());
        }
        let _ = writeln!(s, ":");
        for (key, value, source) in &self.choices {
            let _ = writeln!(s, "  {key:<12} {value}  ({source})");
        }
        s
    }
}

fn list<T: std::fmt::Display>(v: &[T]) -> String {
    v.iter().map(T::to_string).collect::<Vec<_>>().join(", ")
}

impl DataConfig {
    /// `true` if any key of the test-set group is set.
    fn has_test_set(&self) -> bool {
        self.test_alphas.is_some() || self.test_runs.is_some() || self.test_tail.is_some()
    }

    /// `self` over `lower`: every key set here wins; the test-set group
    /// (`test_alphas`, `test_runs`, `test_tail`) is taken whole from the higher layer that
    /// sets any of it.
    pub fn over(&self, lower: &DataConfig) -> DataConfig {
        let group = if self.has_test_set() { self } else { lower };
        DataConfig {
            dir: if self.dir.as_os_str().is_empty() {
                lower.dir.clone()
            } else {
                self.dir.clone()
            },
            cutoff_hz: self.cutoff_hz.or(lower.cutoff_hz),
            velocity: self.velocity.or(lower.velocity),
            window_s: self.window_s.or(lower.window_s),
            warmup_s: self.warmup_s.or(lower.warmup_s),
            test_alphas: group.test_alphas.clone(),
            test_runs: group.test_runs.clone(),
            test_tail: group.test_tail,
            train_alphas: self.train_alphas.clone().or(lower.train_alphas.clone()),
            exclude_runs: self.exclude_runs.clone().or(lower.exclude_runs.clone()),
            validation_fraction: self.validation_fraction.or(lower.validation_fraction),
            seed: self.seed.or(lower.seed),
        }
    }

    /// The preprocessing configuration of section 5.3 with these options; keys not set take
    /// the library's defaults (use a [`resolve_data`]d configuration to get the choices made
    /// from the data).
    pub fn prepare_config(&self) -> PrepareConfig {
        let mut c = PrepareConfig::default();
        if let Some(v) = self.cutoff_hz {
            c.signal.cutoff_hz = v;
        }
        if let Some(v) = self.velocity {
            c.signal.velocity_source = v;
        }
        if let Some(v) = self.window_s {
            c.sequences.length_s = v;
        }
        if let Some(v) = self.warmup_s {
            c.sequences.warmup_s = v;
        }
        if self.has_test_set() {
            c.split.test_alphas = self.test_alphas.clone().unwrap_or_default();
            c.split.test_runs = self.test_runs.clone().unwrap_or_default();
            c.split.test_tail = self.test_tail;
        }
        c.split.train_alphas = self.train_alphas.clone();
        c.split.exclude_runs = self.exclude_runs.clone().unwrap_or_default();
        if let Some(v) = self.validation_fraction {
            c.split.validation_fraction = v;
        }
        if let Some(v) = self.seed {
            c.split.seed = v;
        }
        c
    }

    /// The dataset folder, or an error naming the option when none is given.
    pub fn require_dir(&self) -> Result<&Path> {
        if self.dir.as_os_str().is_empty() {
            bail!("no dataset: give --data DIR (or `[data] dir` in --config)");
        }
        Ok(&self.dir)
    }

    /// Reads a dataset's [`DATA_OPTIONS_FILE`] (`None` if it has none). Its keys are those of
    /// `[data]` without `dir`.
    pub fn load_options_file(dataset_dir: &Path) -> Result<Option<DataConfig>> {
        let path = dataset_dir.join(DATA_OPTIONS_FILE);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
        };
        let c: DataConfig =
            toml::from_str(&text).with_context(|| format!("invalid {}", path.display()))?;
        if !c.dir.as_os_str().is_empty() {
            bail!(
                "{}: `dir` has no place in a dataset's options file (it is the folder it is in)",
                path.display()
            );
        }
        Ok(Some(c))
    }

    /// Writes these options (without `dir`) as the dataset's [`DATA_OPTIONS_FILE`]; returns
    /// its path.
    pub fn save_options_file(&self, dataset_dir: &Path) -> Result<PathBuf> {
        let path = dataset_dir.join(DATA_OPTIONS_FILE);
        let mut c = self.clone();
        c.dir = PathBuf::new();
        let text = format!(
            "# nemm data options of this dataset, read by every nemm command that reads it;\n\
             # command-line options override them (docs/preprocessing.md, \"Data options\").\n{}",
            toml::to_string(&c)?
        );
        crate::fsutil::write_atomic_bytes(&path, text.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
        Ok(path)
    }
}

/// The test set chosen from the levels of a dataset when none is given: the paper's 0.15
/// (Table 2) if it is an interior level, else the interior level nearest the middle of the
/// range (the lower one on a tie), so that the test is an interpolation in alpha as in the
/// paper; with fewer than three levels, the last [`DEFAULT_TEST_TAIL`] of every run.
pub fn adaptive_test_set(levels: &[f64]) -> (Option<f64>, Option<f64>, String) {
    let interior: Vec<f64> = match levels {
        [_, inner @ .., _] => inner.to_vec(),
        _ => Vec::new(),
    };
    let paper = DEFAULT_TEST_ALPHAS[0];
    if interior
        .iter()
        .any(|&a| (a - paper).abs() <= preprocess::ALPHA_TOLERANCE)
    {
        return (
            Some(paper),
            None,
            format!(
                "the paper's test level (Table 2), between levels {}",
                list(levels)
            ),
        );
    }
    if let (Some(&lo), Some(&hi)) = (levels.first(), levels.last()) {
        let mid = 0.5 * (lo + hi);
        if let Some(&a) = interior
            .iter()
            .min_by(|a, b| (*a - mid).abs().total_cmp(&(*b - mid).abs()))
        {
            return (
                Some(a),
                None,
                format!(
                    "the level nearest the middle of {lo}..{hi} with levels on both sides \
                     (levels {})",
                    list(levels)
                ),
            );
        }
    }
    (
        None,
        Some(DEFAULT_TEST_TAIL),
        format!(
            "{} level(s) ({}): none can be held out between others, so the end of every run",
            levels.len(),
            list(levels)
        ),
    )
}

/// The cut-off chosen from the sample rate: `min(150 Hz, 0.4 fs)`.
pub fn adaptive_cutoff_hz(sample_rate_hz: f64) -> f64 {
    DEFAULT_CUTOFF_HZ.min(CUTOFF_FRACTION_OF_RATE * sample_rate_hz)
}

/// Resolves the data options `given` (command line over `--config`) over the dataset's
/// options file `file` over the choices from the dataset `manifest`, recording where each
/// came from.
pub fn resolve_with(
    given: &DataConfig,
    file: Option<&DataConfig>,
    manifest: &Manifest,
) -> ResolvedData {
    let empty = DataConfig::default();
    let file = file.unwrap_or(&empty);
    let merged = given.over(file);
    let src = |in_given: bool, in_file: bool| {
        if in_given {
            OptionSource::Given
        } else if in_file {
            OptionSource::DatasetFile
        } else {
            OptionSource::Default
        }
    };
    let mut c = merged.clone();
    let mut choices = Vec::new();
    let fs = manifest.sample_rate_hz;
    let cutoff_source = match (given.cutoff_hz, file.cutoff_hz) {
        (None, None) => {
            c.cutoff_hz = Some(adaptive_cutoff_hz(fs));
            if DEFAULT_CUTOFF_HZ < CUTOFF_FRACTION_OF_RATE * fs {
                OptionSource::Default
            } else {
                OptionSource::Data(format!(
                    "{CUTOFF_FRACTION_OF_RATE} x the {fs} Hz sample rate, below its Nyquist \
                     frequency {} Hz",
                    fs / 2.0
                ))
            }
        }
        (g, _) => src(g.is_some(), true),
    };
    choices.push((
        "cutoff_hz",
        format!("{} Hz", c.cutoff_hz.unwrap_or(DEFAULT_CUTOFF_HZ)),
        cutoff_source,
    ));
    let velocity = c.velocity.get_or_insert(VelocitySource::Auto);
    let velocity_text = match velocity {
        VelocitySource::Auto => {
            "auto (the velocity_m_s column where a run has one, else d/dt displacement)"
        }
        VelocitySource::Differentiated => "differentiated (d/dt of the filtered displacement)",
        VelocitySource::Measured => "measured (the velocity_m_s column of every run)",
        VelocitySource::Causal => {
            "causal (the firmware's backward difference and 500 Hz low-pass, lag included)"
        }
    };
    choices.push((
        "velocity",
        velocity_text.to_string(),
        src(given.velocity.is_some(), file.velocity.is_some()),
    ));
    let window = *c.window_s.get_or_insert(DEFAULT_SEQUENCE_S);
    let warmup = *c.warmup_s.get_or_insert(DEFAULT_WARMUP_S);
    choices.push((
        "window_s",
        format!("{window} s scored + {warmup} s warm-up"),
        src(
            given.window_s.is_some() || given.warmup_s.is_some(),
            file.window_s.is_some() || file.warmup_s.is_some(),
        ),
    ));
    let test_source = if given.has_test_set() {
        OptionSource::Given
    } else if file.has_test_set() {
        OptionSource::DatasetFile
    } else {
        let levels = preprocess::distinct_levels(manifest.runs.iter().map(|r| r.oil_loss));
        let (alpha, tail, why) = adaptive_test_set(&levels);
        c.test_alphas = Some(alpha.into_iter().collect());
        c.test_tail = tail;
        OptionSource::Data(why)
    };
    let test_alphas = c.test_alphas.get_or_insert_with(Vec::new).clone();
    let test_runs = c.test_runs.get_or_insert_with(Vec::new).clone();
    let mut parts = Vec::new();
    if !test_alphas.is_empty() {
        parts.push(format!("runs at alpha {}", list(&test_alphas)));
    }
    if !test_runs.is_empty() {
        parts.push(format!("runs matching {}", list(&test_runs)));
    }
    if let Some(t) = c.test_tail {
        parts.push(format!("the last {} % of every other run", 100.0 * t));
    }
    if parts.is_empty() {
        parts.push("none".into());
    }
    choices.push(("test set", parts.join(" + "), test_source));
    let exclude = c.exclude_runs.get_or_insert_with(Vec::new).clone();
    let train_text = match &c.train_alphas {
        Some(a) => format!("runs at alpha {}", list(a)),
        None => "every other run".to_string(),
    };
    let train_text = if exclude.is_empty() {
        train_text
    } else {
        format!("{train_text}, except runs matching {}", list(&exclude))
    };
    choices.push((
        "training",
        train_text,
        src(
            given.train_alphas.is_some() || given.exclude_runs.is_some(),
            file.train_alphas.is_some() || file.exclude_runs.is_some(),
        ),
    ));
    let fraction = *c
        .validation_fraction
        .get_or_insert(DEFAULT_VALIDATION_FRACTION);
    let seed = *c.seed.get_or_insert(DEFAULT_SPLIT_SEED);
    choices.push((
        "validation",
        format!(
            "{} % of each training run's windows as one contiguous stretch, placed by seed {seed}",
            100.0 * fraction
        ),
        src(
            given.validation_fraction.is_some() || given.seed.is_some(),
            file.validation_fraction.is_some() || file.seed.is_some(),
        ),
    ));
    ResolvedData {
        config: c,
        choices,
        options_file: None,
    }
}

/// Resolves the data options of `given` for its dataset (`given.dir`): reads the manifest
/// and the dataset's [`DATA_OPTIONS_FILE`] if there is one, chooses the rest from the data
/// ([`resolve_with`]) and prints the "data options" block on stderr.
pub fn resolve_data(given: &DataConfig) -> Result<ResolvedData> {
    let dir = given.require_dir()?;
    let manifest = dataset::read_manifest(dir)
        .with_context(|| format!("cannot read the dataset in {}", dir.display()))?;
    let file = DataConfig::load_options_file(dir)?;
    let mut resolved = resolve_with(given, file.as_ref(), &manifest);
    if file.is_some() {
        resolved.options_file = Some(dir.join(DATA_OPTIONS_FILE));
    }
    eprint!("{}", resolved.block());
    Ok(resolved)
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
    impl Named for crate::train::pipeline::AlphaPriors {
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
    /// ModelKind `nemm train` trains (`nemm compare` trains all four).
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
    /// How the condition's declared monotonicity priors in alpha are imposed:
    /// `construction` (an alpha branch that holds them for every weight) or `penalty`
    /// (the paper's physics penalty alone) (docs/training.md, "Priors in alpha").
    #[serde(with = "by_name")]
    pub alpha_priors: AlphaPriors,
    /// Units `K` of each alpha branch.
    pub branch_units: usize,
    /// Adds the static force of eq. 17 (gas force and seal friction in the stroke
    /// position, `nemm_core::static_force`) to every EMM-family variant (docs/training.md,
    /// "The static force").
    pub static_force: bool,
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
            alpha_priors: AlphaPriors::Construction,
            branch_units: 16,
            static_force: DEFAULT_STATIC_FORCE,
        }
    }
}

/// Whether the EMM-family variants get the static force by default.
pub const DEFAULT_STATIC_FORCE: bool = false;

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
    /// How the training windows are drawn into batches: every run equally often
    /// ([`Balance::Runs`], the default) or every window once per epoch ([`Balance::Windows`]).
    pub balance: Balance,
}

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
            balance: Balance::default(),
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
            balance: self.balance,
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
            alpha_priors: m.alpha_priors,
            branch_units: m.branch_units,
            static_force: m.static_force,
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
    /// The data options (its `--seed` also sets [`TrainConfig::seed`]).
    #[command(flatten)]
    pub data_options: DataArgs,
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
    /// Overrides [`ModelConfig::alpha_priors`].
    #[arg(long, help = with_default(
        "How the declared priors in alpha are imposed: construction (an alpha branch, \
         monotone for every weight) or penalty (the paper's physics penalty alone)",
        ModelConfig::default().alpha_priors.name()))]
    pub alpha_priors: Option<AlphaPriors>,
    /// Overrides [`ModelConfig::static_force`].
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL",
        help = with_default(
        "Add the static force of eq. 17 (gas force and gas spring in the stroke position, \
         seal friction) to every EMM-family variant: --static-force or --static-force=false",
        ModelConfig::default().static_force))]
    pub static_force: Option<bool>,
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
    /// Overrides [`TrainConfig::balance`].
    #[arg(
        long,
        value_enum,
        help = "How batches draw the training windows: runs (every run \
        equally often) or windows (every window once per epoch) [default: runs]"
    )]
    pub balance: Option<Balance>,
    /// Train at most this many epochs per stage in this invocation, then stop with a
    /// checkpoint (time-boxed sessions); continue with --resume.
    #[arg(long)]
    pub session_epochs: Option<usize>,
}

/// The data options on the command line, flattened into every command that reads a dataset;
/// each overrides one key of [`DataConfig`] (over the `--config` file, the dataset's
/// [`DATA_OPTIONS_FILE`] and the choices from the data).
#[derive(Debug, Clone, Default, clap::Args)]
#[command(next_help_heading = "Data options")]
pub struct DataArgs {
    /// Overrides [`DataConfig::cutoff_hz`].
    #[arg(long, value_name = "HZ", help = with_default(
        "Cut-off of the zero-phase low-pass before differentiation (Hz)",
        format!("min({DEFAULT_CUTOFF_HZ}, {CUTOFF_FRACTION_OF_RATE} x sample rate)")))]
    pub cutoff_hz: Option<f64>,
    /// Overrides [`DataConfig::velocity`].
    #[arg(long, value_enum, help = with_default(
        "Velocity source: auto (the CSV's velocity_m_s column where present, else d/dt \
         displacement), differentiated, measured, or causal (the firmware's online estimate: \
         backward difference and 500 Hz first-order low-pass, with its lag)", "auto"))]
    pub velocity: Option<VelocitySource>,
    /// Overrides [`DataConfig::window_s`].
    #[arg(long, alias = "length-s", value_name = "S", help = with_default(
        "Scored length of a training window (s; section 5.3: 0.5 s)", DEFAULT_SEQUENCE_S))]
    pub window_s: Option<f64>,
    /// Overrides [`DataConfig::warmup_s`].
    #[arg(long, value_name = "S", help = with_default(
        "Warm-up prefix of a window, simulated but not scored (s)", DEFAULT_WARMUP_S))]
    pub warmup_s: Option<f64>,
    /// Overrides [`DataConfig::test_alphas`].
    #[arg(long, value_delimiter = ',', value_name = "ALPHA", help = with_default(
        "Level(s) whose runs are held out for testing, comma-separated",
        "0.15 if an interior level (Table 2), else the interior level nearest the middle; \
         with fewer than 3 levels --test-tail 0.2"))]
    pub test_alpha: Option<Vec<f64>>,
    /// Overrides [`DataConfig::test_runs`].
    #[arg(
        long,
        value_name = "GLOB",
        help = "Runs held out for testing: glob(s) on the run files' paths (relative to the \
                manifest) or names, e.g. 'runs/*_a030_*' (repeatable)"
    )]
    pub test_runs: Option<Vec<String>>,
    /// Overrides [`DataConfig::test_tail`].
    #[arg(
        long,
        value_name = "FRACTION",
        help = "Hold out the last FRACTION of every training run for testing (a split in time)"
    )]
    pub test_tail: Option<f64>,
    /// Overrides [`DataConfig::train_alphas`].
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "ALPHA",
        help = "Level(s) for training and validation [default: every level not held out]"
    )]
    pub train_alpha: Option<Vec<f64>>,
    /// Overrides [`DataConfig::exclude_runs`].
    #[arg(
        long,
        value_name = "GLOB",
        help = "Runs not used at all: glob(s) as for --test-runs (repeatable)"
    )]
    pub exclude_runs: Option<Vec<String>>,
    /// Overrides [`DataConfig::validation_fraction`].
    #[arg(long, value_name = "FRACTION", help = with_default(
        "Fraction of each training run held out for validation as one contiguous stretch",
        DEFAULT_VALIDATION_FRACTION))]
    pub validation_fraction: Option<f64>,
    /// Overrides [`DataConfig::seed`] (and, in training commands, [`TrainConfig::seed`]).
    #[arg(long, help = with_default(
        "Seed of the validation stretches' places (training: also of the initial weights \
         and the data order)", DEFAULT_SPLIT_SEED))]
    pub seed: Option<u64>,
}

impl DataArgs {
    /// These options as a [`DataConfig`] layer (no `dir`).
    pub fn to_config(&self) -> DataConfig {
        DataConfig {
            dir: PathBuf::new(),
            cutoff_hz: self.cutoff_hz,
            velocity: self.velocity,
            window_s: self.window_s,
            warmup_s: self.warmup_s,
            test_alphas: self.test_alpha.clone(),
            test_runs: self.test_runs.clone(),
            test_tail: self.test_tail,
            train_alphas: self.train_alpha.clone(),
            exclude_runs: self.exclude_runs.clone(),
            validation_fraction: self.validation_fraction,
            seed: self.seed,
        }
    }

    /// The options over a dataset folder `dir` (and nothing else): the layer of the commands
    /// without `--config`.
    pub fn with_dir(&self, dir: &Path) -> DataConfig {
        DataConfig {
            dir: dir.to_path_buf(),
            ..self.to_config()
        }
    }
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
        let given = DataConfig {
            dir: self.data.clone().unwrap_or_default(),
            ..self.data_options.to_config()
        };
        c.data = given.over(&c.data);
        let (m, t) = (&mut c.model, &mut c.train);
        set(&mut m.hidden, &self.hidden);
        set(&mut m.layers, &self.layers);
        set(&mut m.integrator, &self.integrator);
        set(&mut m.rate_hz, &self.model_rate_hz);
        set(&mut m.alpha_priors, &self.alpha_priors);
        set(&mut m.static_force, &self.static_force);
        set(&mut t.seed, &self.data_options.seed);
        set(&mut t.batch, &self.batch);
        set(&mut t.lr, &self.lr);
        if let Some([one]) = self.lambda_ph.as_deref() {
            t.lambda_ph = *one;
        }
        set(&mut t.lambda_l2, &self.lambda_l2);
        set(&mut t.epochs, &self.epochs);
        set(&mut t.patience, &self.patience);
        set(&mut t.linear_epochs, &self.linear_epochs);
        set(&mut t.balance, &self.balance);
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
        assert_eq!((c.data.seed, c.train.seed), (Some(7), 7));
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

    fn manifest(sample_rate_hz: f64, levels: &[f64]) -> Manifest {
        Manifest {
            name: "m".into(),
            sample_rate_hz,
            condition: None,
            runs: levels
                .iter()
                .enumerate()
                .map(|(i, &a)| dataset::RunEntry {
                    file: PathBuf::from(format!("runs/r{i}.csv")),
                    oil_loss: a,
                    amplitude_m: None,
                    target_velocity_m_s: None,
                })
                .collect(),
        }
    }

    fn choice<'a>(r: &'a ResolvedData, key: &str) -> &'a (&'static str, String, OptionSource) {
        r.choices
            .iter()
            .find(|c| c.0 == key)
            .unwrap_or_else(|| panic!("no {key} in {:?}", r.choices))
    }

    #[test]
    fn defaults_adapt_to_a_300_hz_dataset_with_other_levels() {
        let given = DataConfig::default();
        let r = resolve_with(&given, None, &manifest(300.0, &[0.0, 0.5, 0.5, 1.0]));
        // The cut-off is below the 150 Hz Nyquist frequency: 0.4 x 300 Hz.
        assert_eq!(r.config.cutoff_hz, Some(120.0));
        assert!(matches!(choice(&r, "cutoff_hz").2, OptionSource::Data(_)));
        // The test level exists: the interior one.
        assert_eq!(r.config.test_alphas, Some(vec![0.5]));
        assert_eq!(r.config.test_tail, None);
        let block = r.block();
        assert!(block.starts_with("data options:\n"), "{block}");
        assert!(
            block.contains(
                "cutoff_hz    120 Hz  (chosen from the data: 0.4 x the 300 Hz sample rate, \
                 below its Nyquist frequency 150 Hz)"
            ),
            "{block}"
        );
        assert!(
            block.contains("test set     runs at alpha 0.5  (chosen from the data"),
            "{block}"
        );
        // A resolved configuration prepares without error at 300 Hz, and saved as TOML it
        // resolves to itself.
        let c = r.config.prepare_config();
        assert_eq!(c.signal.cutoff_hz, 120.0);
        let text = toml::to_string(&r.config).expect("toml");
        let back: DataConfig = toml::from_str(&text).expect("parse");
        assert_eq!(back, r.config);
        let again = resolve_with(&back, None, &manifest(300.0, &[0.0, 0.5, 1.0]));
        assert_eq!(again.config, r.config);
        assert!(again.choices.iter().all(|c| c.2 == OptionSource::Given));
        // At 10 kHz the paper's settings: 150 Hz and the test level 0.15.
        let r = resolve_with(&given, None, &manifest(10_000.0, &[0.0, 0.15, 0.3]));
        assert_eq!(r.config.cutoff_hz, Some(150.0));
        assert_eq!(r.config.test_alphas, Some(vec![0.15]));
        assert_eq!(r.config.prepare_config(), PrepareConfig::default());
    }

    #[test]
    fn the_test_set_chosen_from_the_levels() {
        let t = |levels: &[f64]| {
            let (a, tail, _) = adaptive_test_set(levels);
            (a, tail)
        };
        assert_eq!(t(&[0.0, 0.15, 0.3]), (Some(0.15), None));
        // The paper's level is taken when it is interior, else the middle one.
        assert_eq!(t(&[0.0, 0.1, 0.15, 0.2, 0.6]), (Some(0.15), None));
        assert_eq!(t(&[0.0, 0.1, 0.2, 0.3]), (Some(0.1), None));
        assert_eq!(t(&[0.0, 0.2, 0.7, 1.0]), (Some(0.7), None));
        // Fewer than three levels: the end of every run.
        assert_eq!(t(&[0.15, 0.3]), (None, Some(DEFAULT_TEST_TAIL)));
        assert_eq!(t(&[0.0]), (None, Some(DEFAULT_TEST_TAIL)));
        let r = resolve_with(&DataConfig::default(), None, &manifest(1000.0, &[0.0, 0.0]));
        assert_eq!(r.config.test_alphas, Some(vec![]));
        assert_eq!(r.config.test_tail, Some(0.2));
        assert!(
            r.block().contains("the last 20 % of every other run"),
            "{}",
            r.block()
        );
    }

    #[test]
    fn flags_override_the_dataset_file_which_overrides_the_choices() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert_eq!(
            DataConfig::load_options_file(dir.path()).expect("none"),
            None
        );
        let file = DataConfig {
            cutoff_hz: Some(40.0),
            window_s: Some(1.0),
            test_runs: Some(vec!["runs/r1*".into()]),
            ..DataConfig::default()
        };
        let path = file.save_options_file(dir.path()).expect("save");
        assert_eq!(path, dir.path().join(DATA_OPTIONS_FILE));
        let loaded = DataConfig::load_options_file(dir.path())
            .expect("load")
            .expect("a file");
        assert_eq!(loaded, file);
        let m = manifest(300.0, &[0.0, 0.5, 1.0]);
        let r = resolve_with(&DataConfig::default(), Some(&loaded), &m);
        assert_eq!(r.config.cutoff_hz, Some(40.0));
        assert_eq!(choice(&r, "cutoff_hz").2, OptionSource::DatasetFile);
        assert_eq!(r.config.test_runs, Some(vec!["runs/r1*".to_string()]));
        assert_eq!(
            r.config.test_alphas,
            Some(vec![]),
            "the file's test set, whole"
        );
        // A flag wins; a test-set flag replaces the file's whole test set.
        let given = DataConfig {
            cutoff_hz: Some(100.0),
            test_tail: Some(0.3),
            ..DataConfig::default()
        };
        let r = resolve_with(&given, Some(&loaded), &m);
        assert_eq!(r.config.cutoff_hz, Some(100.0));
        assert_eq!(choice(&r, "cutoff_hz").2, OptionSource::Given);
        assert_eq!(r.config.window_s, Some(1.0));
        assert_eq!(
            (r.config.test_tail, r.config.test_runs.clone()),
            (Some(0.3), Some(vec![]))
        );
        // Errors name the file and the line; `dir` has no place there.
        std::fs::write(&path, "cutoff_hz = 40.0\nwindow = 1\n").expect("write");
        let err = format!(
            "{:#}",
            DataConfig::load_options_file(dir.path()).unwrap_err()
        );
        assert!(
            err.contains(DATA_OPTIONS_FILE) && err.contains("line 2"),
            "{err}"
        );
        std::fs::write(&path, "dir = \"x\"\n").expect("write");
        let err = DataConfig::load_options_file(dir.path())
            .unwrap_err()
            .to_string();
        assert!(err.contains("`dir` has no place"), "{err}");
    }

    #[test]
    fn data_options_parse_on_every_command_line() {
        let args = Cli::parse_from([
            "nemm",
            "--data",
            "d",
            "--cutoff-hz",
            "60",
            "--velocity",
            "differentiated",
            "--test-runs",
            "a*",
            "--test-runs",
            "b{1,2}*",
            "--exclude-runs",
            "c*",
            "--length-s",
            "0.4",
        ])
        .args;
        let c = args.resolve().expect("resolve");
        assert_eq!(c.data.cutoff_hz, Some(60.0));
        assert_eq!(c.data.velocity, Some(VelocitySource::Differentiated));
        assert_eq!(
            c.data.test_runs,
            Some(vec!["a*".to_string(), "b{1,2}*".to_string()])
        );
        assert_eq!(c.data.exclude_runs, Some(vec!["c*".to_string()]));
        assert_eq!(c.data.window_s, Some(0.4));
    }
}
