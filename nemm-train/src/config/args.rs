//! The command line of a job ([`ConfigArgs`], [`DataArgs`]): `Option`s that override a
//! [`Config`], with the defaults shown from the `Default` impls.

use super::*;

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
        "Scored length of a training window (s; section 5.3: 0.5 s)", DEFAULT_WINDOW_S))]
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
