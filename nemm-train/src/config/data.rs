//! The data options ([`DataConfig`]): their layers (command line, `--config`, the dataset's
//! options file) and their resolution, with the choices made from the data.

use super::args::with_default;
use super::{DATA_OPTIONS_FILE, DEFAULT_TEST_TAIL};
use crate::data::preprocess::{
    self, PrepareConfig, VelocitySource, CUTOFF_FRACTION_OF_RATE, DEFAULT_CUTOFF_HZ,
    DEFAULT_SPLIT_SEED, DEFAULT_TEST_ALPHAS, DEFAULT_VALIDATION_FRACTION, DEFAULT_WARMUP_S,
    DEFAULT_WINDOW_S,
};
use anyhow::{bail, Context, Result};
use nemm_dataset::{self as dataset, Manifest};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Which dataset a job reads and how it is filtered, split and cut into windows: the data
/// options every dataset-reading command shares (`nemm data check/prepare`, `bench plot`,
/// `train`, `compare`, `sweep`, `demo`).
///
/// `None` means "not given": [`resolve_data`] fills it from the dataset's
/// [`DATA_OPTIONS_FILE`] or chooses it from the data (the cut-off from the sample rate, the
/// test set from the levels present). A resolved configuration (as saved in `config.toml`)
/// has every key set. The test set is one group: `test_alphas`, `test_runs` and `test_tail`
/// given at one layer replace all three of a lower layer.
///
/// The one definition of the data options: the command line (`clap::Args`, flattened into
/// every command that reads a dataset, each flag named after its field), the `[data]` table
/// of a `--config` file and the dataset's options file (serde). The defaults are the
/// constants of [`crate::data::preprocess`], applied once by [`resolve_data`].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, clap::Args)]
#[serde(default, deny_unknown_fields)]
#[command(next_help_heading = "Data options")]
pub struct DataConfig {
    /// Dataset folder (manifest.toml + CSV runs; see docs/data-format.md). Empty: none given.
    /// On the command line: `--data` (or the command's folder argument).
    #[arg(skip)]
    pub dir: PathBuf,
    /// Cut-off of the zero-phase low-pass before differentiation \[Hz\], the same for every
    /// run; not set: chosen per run from its displacement noise and excitation
    /// (`preprocess::Cutoff`).
    #[arg(long, value_name = "HZ", help = with_default(
        "Cut-off of the zero-phase low-pass before differentiation (Hz), the same for every run",
        format!("per run: at most min({DEFAULT_CUTOFF_HZ}, {CUTOFF_FRACTION_OF_RATE} x sample \
                 rate), lowered where the displacement noise would dominate the velocity")))]
    pub cutoff_hz: Option<f64>,
    /// Velocity source: `auto` (the CSV's `velocity_m_s` column where a run has one, else the
    /// differentiated displacement; default), `differentiated`, `measured` or `causal` (the
    /// firmware's online estimate, [`crate::data::preprocess::causal_velocity`]).
    #[arg(long, value_enum, help = with_default(
        "Velocity source: auto (the CSV's velocity_m_s column where present, else d/dt \
         displacement), differentiated, measured, or causal (the firmware's online estimate: \
         backward difference and 500 Hz first-order low-pass, with its lag)", "auto"))]
    pub velocity: Option<VelocitySource>,
    /// Scored length of a training window \[s\] (section 5.3: 0.5 s).
    #[arg(long, alias = "length-s", value_name = "S", help = with_default(
        "Scored length of a training window (s; section 5.3: 0.5 s)", DEFAULT_WINDOW_S))]
    pub window_s: Option<f64>,
    /// Warm-up prefix of a window, simulated but not scored \[s\].
    #[arg(long, value_name = "S", help = with_default(
        "Warm-up prefix of a window, simulated but not scored (s)", DEFAULT_WARMUP_S))]
    pub warmup_s: Option<f64>,
    /// Oil-loss level(s) whose runs are held out for testing (Table 2: 0.15).
    #[arg(long, visible_alias = "test-alpha", value_delimiter = ',', value_name = "ALPHA",
        help = with_default(
        "Level(s) whose runs are held out for testing, comma-separated",
        "0.15 if an interior level (Table 2), else the interior level nearest the middle; \
         with fewer than 3 levels --test-tail 0.2"))]
    pub test_alphas: Option<Vec<f64>>,
    /// Glob patterns on run files (path relative to the manifest, or file name) of runs held
    /// out for testing.
    #[arg(
        long,
        value_name = "GLOB",
        help = "Runs held out for testing: glob(s) on the run files' paths (relative to the \
                manifest) or names, e.g. 'runs/*_a030_*' (repeatable)"
    )]
    pub test_runs: Option<Vec<String>>,
    /// Fraction of every training run, at its end, held out for testing.
    #[arg(
        long,
        value_name = "FRACTION",
        help = "Hold out the last FRACTION of every training run for testing (a split in time)"
    )]
    pub test_tail: Option<f64>,
    /// Levels used for training and validation (default: every level not held out).
    #[arg(
        long,
        visible_alias = "train-alpha",
        value_delimiter = ',',
        value_name = "ALPHA",
        help = "Level(s) for training and validation [default: every level not held out]"
    )]
    pub train_alphas: Option<Vec<f64>>,
    /// Glob patterns of run files not used at all.
    #[arg(
        long,
        value_name = "GLOB",
        help = "Runs not used at all: glob(s) as for --test-runs (repeatable)"
    )]
    pub exclude_runs: Option<Vec<String>>,
    /// Fraction of each training run held out for validation, as one contiguous stretch.
    #[arg(long, value_name = "FRACTION", help = with_default(
        "Fraction of each training run held out for validation as one contiguous stretch",
        DEFAULT_VALIDATION_FRACTION))]
    pub validation_fraction: Option<f64>,
    /// Seed of the validation stretches' places (in training commands also
    /// [`TrainConfig::seed`](super::TrainConfig::seed)).
    #[arg(long, help = with_default(
        "Seed of the validation stretches' places (training: also of the initial weights \
         and the data order)", DEFAULT_SPLIT_SEED))]
    pub seed: Option<u64>,
    /// Train on runs whose force assists the motion (an inverted sign, see
    /// [`crate::data::preprocess::Dissipation`]) instead of refusing them (default: refuse).
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "true",
        value_name = "BOOL",
        help = "Train on runs whose force assists the motion (an inverted force or \
                displacement sign) instead of refusing them [default: refuse]")]
    pub(crate) accept_implausible: Option<bool>,
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
    pub(crate) options_file: Option<PathBuf>,
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

/// Condition levels as printed ([`nemm_dataset::alpha_text`]), comma-separated.
fn alpha_list(v: &[f64]) -> String {
    v.iter()
        .map(|&a| nemm_dataset::alpha_text(a))
        .collect::<Vec<_>>()
        .join(", ")
}

impl DataConfig {
    /// These options over the dataset folder `dir`.
    pub fn in_dir(&self, dir: &Path) -> DataConfig {
        DataConfig {
            dir: dir.to_path_buf(),
            ..self.clone()
        }
    }

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
            accept_implausible: self.accept_implausible.or(lower.accept_implausible),
        }
    }

    /// The preprocessing configuration of section 5.3 with these options; keys not set take
    /// the library's defaults (use a [`resolve_data`]d configuration to get the choices made
    /// from the data).
    pub fn prepare_config(&self) -> PrepareConfig {
        let mut c = PrepareConfig::default();
        if let Some(v) = self.cutoff_hz {
            c.signal.cutoff_hz = Some(v);
        }
        if let Some(v) = self.velocity {
            c.signal.velocity_source = v;
        }
        if let Some(v) = self.window_s {
            c.sequences.window_s = v;
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
        c.accept_implausible = self.accept_implausible.unwrap_or(false);
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
    pub(crate) fn load_options_file(dataset_dir: &Path) -> Result<Option<DataConfig>> {
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
    pub(crate) fn save_options_file(&self, dataset_dir: &Path) -> Result<PathBuf> {
        let path = dataset_dir.join(DATA_OPTIONS_FILE);
        let mut c = self.clone();
        c.dir = PathBuf::new();
        let text = format!(
            "# nemm data options of this dataset, read by every nemm command that reads it;\n\
             # command-line options override them (docs/preprocessing.md, \"Data options\").\n{}",
            toml::to_string(&c)?
        );
        nemm_dataset::atomic_file::write_atomic_bytes(&path, text.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
        Ok(path)
    }
}

/// The test set chosen from the levels of a dataset when none is given: the paper's 0.15
/// (Table 2) if it is an interior level, else the interior level nearest the middle of the
/// range (the lower one on a tie), so that the test is an interpolation in alpha as in the
/// paper; with fewer than three levels, the last [`DEFAULT_TEST_TAIL`] of every run.
pub(crate) fn adaptive_test_set(levels: &[f64]) -> (Option<f64>, Option<f64>, String) {
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

/// Resolves the data options `given` (command line over `--config`) over the dataset's
/// options file `file` over the choices from the dataset `manifest`, recording where each
/// came from.
pub(crate) fn resolve_with(
    given: &DataConfig,
    file: Option<&DataConfig>,
    manifest: &Manifest,
) -> ResolvedData {
    let empty = DataConfig::default();
    let layers = Layers {
        given,
        file: file.unwrap_or(&empty),
    };
    let mut c = given.over(layers.file);
    let choices = vec![
        resolve_cutoff(&layers, &mut c, manifest.sample_rate_hz),
        resolve_velocity(&layers, &mut c),
        resolve_window(&layers, &mut c),
        resolve_test_set(&layers, &mut c, manifest),
        resolve_training(&layers, &mut c),
        resolve_validation(&layers, &mut c),
    ];
    ResolvedData {
        config: c,
        choices,
        options_file: None,
    }
}

/// The two layers of data options above the choices from the data: the given ones (command
/// line and `--config`) over the dataset's options file.
struct Layers<'a> {
    given: &'a DataConfig,
    file: &'a DataConfig,
}

/// One printed choice: `(option, value, source)`.
type Choice = (&'static str, String, OptionSource);

impl Layers<'_> {
    /// Where an option set by `is_set` (on a layer) came from: given, the options file, or
    /// the built-in default.
    fn source(&self, is_set: impl Fn(&DataConfig) -> bool) -> OptionSource {
        if is_set(self.given) {
            OptionSource::Given
        } else if is_set(self.file) {
            OptionSource::DatasetFile
        } else {
            OptionSource::Default
        }
    }
}

/// The cut-off: given or from the options file, the same for every run; else chosen per run
/// from its displacement noise and excitation ([`preprocess::Cutoff`]).
fn resolve_cutoff(layers: &Layers<'_>, c: &mut DataConfig, fs: f64) -> Choice {
    if let Some(hz) = c.cutoff_hz {
        return (
            "cutoff_hz",
            format!("{hz} Hz"),
            layers.source(|l| l.cutoff_hz.is_some()),
        );
    }
    let fc_max = DEFAULT_CUTOFF_HZ.min(CUTOFF_FRACTION_OF_RATE * fs);
    (
        "cutoff_hz",
        "auto".to_string(),
        OptionSource::Data(format!(
            "per run: at most min({DEFAULT_CUTOFF_HZ} Hz, {CUTOFF_FRACTION_OF_RATE} x the {fs} \
             Hz rate) = {fc_max} Hz, lowered until the displacement noise gives at most {:.0} \
             % of the run's RMS velocity, not below {} x its excitation frequency; data check \
             prints each run's value",
            preprocess::AUTO_CUTOFF_NOISE_FRACTION * 100.0,
            preprocess::AUTO_CUTOFF_EXCITATION_MULTIPLE
        )),
    )
}

/// The velocity source (default `auto`).
fn resolve_velocity(layers: &Layers<'_>, c: &mut DataConfig) -> Choice {
    let text = match c.velocity.get_or_insert(VelocitySource::Auto) {
        VelocitySource::Auto => {
            "auto (the velocity_m_s column where a run has one, else d/dt displacement)"
        }
        VelocitySource::Differentiated => "differentiated (d/dt of the filtered displacement)",
        VelocitySource::Measured => "measured (the velocity_m_s column of every run)",
        VelocitySource::Causal => {
            "causal (the firmware's backward difference and 500 Hz low-pass, lag included)"
        }
    };
    (
        "velocity",
        text.to_string(),
        layers.source(|l| l.velocity.is_some()),
    )
}

/// The scored window and its warm-up.
fn resolve_window(layers: &Layers<'_>, c: &mut DataConfig) -> Choice {
    let window = *c.window_s.get_or_insert(DEFAULT_WINDOW_S);
    let warmup = *c.warmup_s.get_or_insert(DEFAULT_WARMUP_S);
    (
        "window_s",
        format!("{window} s scored + {warmup} s warm-up"),
        layers.source(|l| l.window_s.is_some() || l.warmup_s.is_some()),
    )
}

/// The test set: given or from the options file as one group, else chosen from the levels
/// of the manifest ([`adaptive_test_set`]).
fn resolve_test_set(layers: &Layers<'_>, c: &mut DataConfig, manifest: &Manifest) -> Choice {
    let source = if layers.given.has_test_set() {
        OptionSource::Given
    } else if layers.file.has_test_set() {
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
        parts.push(format!("runs at alpha {}", alpha_list(&test_alphas)));
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
    ("test set", parts.join(" + "), source)
}

/// The training runs: the training levels, less the excluded runs.
fn resolve_training(layers: &Layers<'_>, c: &mut DataConfig) -> Choice {
    let exclude = c.exclude_runs.get_or_insert_with(Vec::new).clone();
    let levels = match &c.train_alphas {
        Some(a) => format!("runs at alpha {}", alpha_list(a)),
        None => "every other run".to_string(),
    };
    let text = if exclude.is_empty() {
        levels
    } else {
        format!("{levels}, except runs matching {}", list(&exclude))
    };
    (
        "training",
        text,
        layers.source(|l| l.train_alphas.is_some() || l.exclude_runs.is_some()),
    )
}

/// The validation stretch of each training run and the seed that places it.
fn resolve_validation(layers: &Layers<'_>, c: &mut DataConfig) -> Choice {
    let fraction = *c
        .validation_fraction
        .get_or_insert(DEFAULT_VALIDATION_FRACTION);
    let seed = *c.seed.get_or_insert(DEFAULT_SPLIT_SEED);
    (
        "validation",
        format!(
            "{} % of each training run's windows as one contiguous stretch, placed by seed {seed}",
            100.0 * fraction
        ),
        layers.source(|l| l.validation_fraction.is_some() || l.seed.is_some()),
    )
}

/// Resolves the data options of `given` for its dataset (`given.dir`): reads the manifest
/// and the dataset's [`DATA_OPTIONS_FILE`] if there is one, chooses the rest from the data
/// (`resolve_with`) and prints the "data options" block on stderr.
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
