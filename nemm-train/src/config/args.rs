//! The command line of a job ([`ConfigArgs`]): `Option`s that override a [`Config`], with
//! the defaults shown from the `Default` impls. The data options are [`DataConfig`] itself.

use super::*;

/// `help` text of an option with its default (from the `Default` impls).
pub(super) fn with_default(text: &str, default: impl std::fmt::Display) -> String {
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
    pub data_options: DataConfig,
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
        "from the data: on when most runs hold a force offset at zero velocity"))]
    pub static_force: Option<bool>,
    /// Overrides [`ModelConfig::lost_motion`].
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL",
        help = with_default(
        "Add the lost-motion element (gas in series with k_pr; its travel per stroke side \
         grows with alpha) to every EMM-family variant: --lost-motion or --lost-motion=false",
        false))]
    pub lost_motion: Option<bool>,
    /// Overrides [`ModelConfig::b_fl_alpha`].
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL",
        help = with_default(
        "Whether the flow damping b_fl depends on alpha (the paper's b_fl(v_st, alpha)); \
         --b-fl-alpha=false: one b_fl(v_st) for every level",
        true))]
    pub b_fl_alpha: Option<bool>,
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
    /// Overrides [`TrainConfig::lambda_diff`].
    #[arg(long, help = with_default(
        "Weight of the matched-difference term: windows of the same excitation at two levels \
         fit the measured force difference between the levels (0: the paper's loss)",
        TrainConfig::default().lambda_diff))]
    pub lambda_diff: Option<f64>,
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

impl ConfigArgs {
    /// The `--config` file (or the defaults) with the given options applied. A
    /// `--lambda-ph` list is applied only when it has one value (`nemm sweep` reads the list
    /// itself, see [`ConfigArgs::lambda_ph_list`]).
    pub fn base(&self) -> Result<Config> {
        self.base_over(Config::default())
    }

    /// [`ConfigArgs::base`] over `defaults` instead of [`Config::default`] when no
    /// `--config` is given (`nemm demo`: [`Config::demo`]).
    pub fn base_over(&self, defaults: Config) -> Result<Config> {
        let mut c = match &self.config {
            Some(path) => Config::load(path)?,
            None => defaults,
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
        let given = self
            .data_options
            .in_dir(self.data.as_deref().unwrap_or(Path::new("")));
        c.data = given.over(&c.data);
        let (m, t) = (&mut c.model, &mut c.train);
        set(&mut m.hidden, &self.hidden);
        set(&mut m.layers, &self.layers);
        set(&mut m.integrator, &self.integrator);
        set(&mut m.rate_hz, &self.model_rate_hz);
        set(&mut m.alpha_priors, &self.alpha_priors);
        if self.static_force.is_some() {
            m.static_force = self.static_force;
        }
        set(&mut m.lost_motion, &self.lost_motion);
        set(&mut m.b_fl_alpha, &self.b_fl_alpha);
        set(&mut t.seed, &self.data_options.seed);
        set(&mut t.batch, &self.batch);
        set(&mut t.lr, &self.lr);
        if let Some([one]) = self.lambda_ph.as_deref() {
            t.lambda_ph = *one;
        }
        set(&mut t.lambda_diff, &self.lambda_diff);
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
