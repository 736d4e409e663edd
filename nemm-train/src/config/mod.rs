//! The configuration of a job, with every option and default written once.
//!
//! [`Config`] holds the three parts a dataset-reading, model-training command needs:
//! [`DataConfig`] (which dataset, how it is split and cut into windows), [`ModelConfig`]
//! (variant, scaler size, integrator) and [`TrainConfig`] (the optimiser and its schedule).
//! Each part is defined once: the data options are one struct of `Option`s (command line,
//! `[data]` table and the dataset's options file) resolved against the dataset
//! ([`resolve_data`]); the model and training parts are each one list of fields in a
//! `section!` (doc, type, default, TOML attributes, command-line option) that defines the
//! resolved struct with its `Default`, its command-line options ([`ModelOptions`],
//! [`TrainOptions`]) and their `over`. The training procedure's settings
//! (`train::pipeline::PipelineConfig::of`, `train::fit::FitConfig::of`) are built from the
//! resolved structs, and the command line ([`ConfigArgs`]: `--config`, `--data` and the three
//! parts' options) overrides a configuration (the defaults, or a TOML file given with
//! `--config`). A configuration is written to and read from TOML (`Config::to_toml`,
//! [`Config::load`]); `nemm train --report`, `nemm compare` and `nemm demo` save the
//! effective one as `config.toml`, and `nemm sweep` runs each job from such a file.

use crate::data::preprocess;
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Name of the effective configuration saved into a report folder.
pub const CONFIG_FILE: &str = "config.toml";

pub use nemm_dataset::DATA_OPTIONS_FILE;

/// Nonzero `lambda_ph` values below this are most likely the paper's numbers (Table 5: 0.005
/// to 0.025) rather than this crate's.
const PAPER_SCALE_LAMBDA_PH: f64 = 0.1;

/// Test fraction at the end of every run chosen when the dataset has fewer than three
/// levels (no level can be held out and interpolated).
pub(crate) const DEFAULT_TEST_TAIL: f64 = 0.2;

mod args;
mod data;
mod model;
mod section;
mod training;

pub use args::ConfigArgs;
pub use data::{resolve_data, DataConfig};
pub use model::StatePriors;
pub(crate) use model::{AlphaPriors, DEFAULT_STATIC_FORCE};
pub use model::{ModelConfig, ModelOptions};
pub use training::{Balance, TrainConfig, TrainOptions};

/// The model rates \[Hz\] training accepts: a step from 100 ms down to 1 us, which an `f32`
/// step of the blob format holds to 7 digits (docs/training.md, "Limits of the options").
pub(crate) const MODEL_RATE_RANGE_HZ: (f64, f64) = (10.0, 1_000_000.0);

/// The most windows one batch may hold.
pub(crate) const MAX_BATCH: usize = 1024;

/// The most model steps one batch may roll out (windows x (window + warm-up) x model rate):
/// the rollout keeps every step's state for the backward pass, so this bounds a batch's
/// memory. The defaults roll out 88 000 (0.55 s x 10 kHz x 16).
pub(crate) const MAX_BATCH_STEPS: usize = 4_000_000;

/// The demo's budget (`nemm demo`: the main job in a few minutes on two cores): epochs of
/// the neural stages.
pub(crate) const DEMO_EPOCHS: usize = 12;
/// The demo's budget: batches per epoch (a random subset).
pub(crate) const DEMO_MAX_BATCHES: usize = 8;
/// The demo's budget: epochs of the Linear EMM stage.
pub(crate) const DEMO_LINEAR_EPOCHS: usize = 6;
/// The demo's dataset folder (the default virtual bench is generated there if it is empty).
pub(crate) const DEMO_DATA_DIR: &str = "out/bench";

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
    /// The demo's configuration: the defaults on the demo's budget (`DEMO_EPOCHS`,
    /// `DEMO_MAX_BATCHES`, `DEMO_LINEAR_EPOCHS`) over `DEMO_DATA_DIR`.
    pub fn demo() -> Config {
        let mut c = Config::default();
        c.data.dir = PathBuf::from(DEMO_DATA_DIR);
        c.train.epochs = DEMO_EPOCHS;
        c.train.max_batches = Some(DEMO_MAX_BATCHES);
        c.train.linear_epochs = DEMO_LINEAR_EPOCHS;
        c
    }

    /// Reads a configuration from a TOML file; absent keys take their defaults.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("invalid configuration {}", path.display()))
    }

    /// The configuration as TOML (every key, so that the file alone reproduces the job).
    pub(crate) fn to_toml(&self) -> Result<String> {
        Ok(toml::to_string(self)?)
    }

    /// Writes the configuration as TOML to `path` (atomically).
    pub fn save(&self, path: &Path) -> Result<()> {
        nemm_dataset::atomic_file::write_atomic_bytes(path, self.to_toml()?.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))
    }

    /// Checks the values no training can run with, before anything is allocated: every size
    /// within what the model and its blob format hold ([`nemm_core::MAX_HIDDEN`], [`nemm_core::MAX_LAYERS`], [`nemm_core::MAX_BRANCH_UNITS`]), the model rate
    /// within `MODEL_RATE_RANGE_HZ`, the samples one batch rolls out within
    /// `MAX_BATCH_STEPS`, and every rate, weight and bound a finite number that lets
    /// training change the model. Each error names the option and its accepted range.
    pub fn validate(&self) -> Result<()> {
        let (m, t) = (&self.model, &self.train);
        let size = |name: &str, v: usize, max: usize| -> Result<()> {
            if !(1..=max).contains(&v) {
                bail!("{name} {v} is out of range: it must be in 1..={max}");
            }
            Ok(())
        };
        size("--hidden", m.hidden, nemm_core::MAX_HIDDEN)?;
        size("--layers", m.layers, nemm_core::MAX_LAYERS)?;
        size(
            "branch_units ([model] in --config)",
            m.branch_units,
            nemm_core::MAX_BRANCH_UNITS,
        )?;
        size(
            "cumulative_units ([model] in --config)",
            m.cumulative_units,
            nemm_core::MAX_CUMULATIVE_UNITS,
        )?;
        size("--batch", t.batch, MAX_BATCH)?;
        let (lo, hi) = MODEL_RATE_RANGE_HZ;
        if !(m.rate_hz.is_finite() && (lo..=hi).contains(&m.rate_hz)) {
            bail!(
                "--model-rate-hz {} is out of range: it must be in {lo}..={hi} Hz (a step of \
                 {} us down to {} us)",
                m.rate_hz,
                1e6 / lo,
                1e6 / hi
            );
        }
        let window_s = self.data.window_s.unwrap_or(preprocess::DEFAULT_WINDOW_S);
        let warmup_s = self.data.warmup_s.unwrap_or(preprocess::DEFAULT_WARMUP_S);
        let steps = (window_s + warmup_s) * m.rate_hz * t.batch as f64;
        // NaN (a non-finite window) fails too.
        if steps.is_nan() || steps > MAX_BATCH_STEPS as f64 {
            bail!(
                "a batch would roll out {steps:.0} model steps ((--window-s {window_s} + \
                 --warmup-s {warmup_s}) x --model-rate-hz {} x --batch {}), more than the \
                 {MAX_BATCH_STEPS} training holds in memory: lower one of them",
                m.rate_hz,
                t.batch
            );
        }
        let positive = |name: &str, v: f64| -> Result<()> {
            if !(v.is_finite() && v > 0.0) {
                bail!("{name} {v} is out of range: it must be a finite number > 0");
            }
            Ok(())
        };
        positive("--lr", t.lr)?;
        positive("linear_lr ([train] in --config)", t.linear_lr)?;
        positive("grad_clip ([train] in --config)", f64::from(t.grad_clip))?;
        positive("adam_eps ([train] in --config)", f64::from(t.adam_eps))?;
        for (name, v) in [
            ("--lambda-ph", t.lambda_ph),
            ("--lambda-diff", t.lambda_diff),
            ("--lambda-l2", t.lambda_l2),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                bail!("{name} {v} is out of range: it must be a finite number >= 0");
            }
        }
        for (name, (lo, hi)) in [
            ("b_fl_bounds ([model] in --config)", m.b_fl_bounds),
            ("pr_bounds ([model] in --config)", m.pr_bounds),
        ] {
            if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && lo < hi) {
                bail!(
                    "{name} ({lo}, {hi}) is out of range: it must be (s_min, s_max) with \
                     0 < s_min < s_max, both finite"
                );
            }
        }
        if t.epochs == 0 {
            bail!("--epochs 0 trains nothing: it must be at least 1");
        }
        if t.max_batches == Some(0) {
            bail!(
                "--max-batches 0 trains nothing: give at least 1, or leave it out for every batch"
            );
        }
        if t.session_epochs == Some(0) {
            bail!("--session-epochs 0 trains nothing: give at least 1, or leave it out");
        }
        Ok(())
    }

    /// This configuration with the static force decided: as given, else from the runs'
    /// force offsets at zero velocity ([`preprocess::static_force_from_data`]). Prints a
    /// choice made from the data, with its reason.
    pub fn with_static_force_from(&self, prepared: &preprocess::Prepared) -> Config {
        let mut c = self.clone();
        if c.model.static_force.is_some() {
            return c;
        }
        let offsets: Vec<_> = prepared
            .runs
            .iter()
            .map(|r| r.summary.force_offset)
            .collect();
        let (on, why) = preprocess::static_force_from_data(&offsets).unwrap_or_else(|| {
            (
                DEFAULT_STATIC_FORCE,
                "no run has samples at zero velocity".to_string(),
            )
        });
        println!(
            "static_force {}  (chosen from the data: {why})",
            if on { "on" } else { "off" }
        );
        c.model.static_force = Some(on);
        c
    }
}

/// A note for `lambda_ph` values that look like the paper's numbers: in this crate's
/// normalisation they barely act (docs/training.md, "The scale of `lambda_ph`"). `None` when
/// every value is 0 or at least 0.1.
pub(crate) fn lambda_ph_scale_note(values: &[f64]) -> Option<String> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::preprocess::{PrepareConfig, VelocitySource};
    use clap::Parser;
    use data::{adaptive_test_set, resolve_with, OptionSource, ResolvedData};
    use nemm_core::{Integrator, ModelKind};
    use nemm_dataset::{self as dataset, Manifest};

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: ConfigArgs,
    }

    #[test]
    fn the_library_defaults_are_the_command_line_defaults() {
        let cli = Cli::parse_from(["nemm"]).args.base().expect("defaults");
        assert_eq!(cli, Config::default());
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

    /// Each model and training option lands in its field; an option not given keeps the
    /// configuration's value.
    #[test]
    fn each_section_option_overrides_its_field() {
        let mut c = Config::default();
        c.model.static_force = Some(false);
        c.train.max_batches = Some(9);
        c.train.seed = 5;
        let args = Cli::parse_from([
            "nemm",
            "--static-force",
            "--b-fl-alpha=false",
            "--model-rate-hz",
            "5000",
            "--lambda-ph",
            "7",
            "--balance",
            "windows",
            "--session-epochs",
            "2",
        ])
        .args;
        args.apply(&mut c);
        assert_eq!(
            (c.model.static_force, c.model.b_fl_alpha, c.model.rate_hz),
            (Some(true), false, 5000.0)
        );
        assert_eq!(
            (c.train.lambda_ph, c.train.balance, c.train.session_epochs),
            (7.0, Balance::Windows, Some(2))
        );
        assert_eq!(
            (c.train.max_batches, c.train.seed),
            (Some(9), 5),
            "not given: kept"
        );
        // A list of lambda_ph values (a sweep's) leaves the field as it is.
        let list = Cli::parse_from(["nemm", "--lambda-ph", "0,5"]).args;
        list.apply(&mut c);
        assert_eq!(c.train.lambda_ph, 7.0);
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

    /// Every size and rate is bounded before anything is allocated, and the error names the
    /// option and its range.
    #[test]
    fn validate_bounds_every_size_and_rate() {
        let err = |edit: &dyn Fn(&mut Config)| {
            let mut c = Config::default();
            edit(&mut c);
            c.validate().expect_err("refused").to_string()
        };
        assert!(Config::default().validate().is_ok());
        let e = err(&|c| c.model.rate_hz = 1e9);
        assert!(
            e.contains("--model-rate-hz 1000000000 is out of range"),
            "{e}"
        );
        let e = err(&|c| c.model.branch_units = 1_000_000);
        assert!(e.contains("branch_units") && e.contains("1..=32"), "{e}");
        let e = err(&|c| c.model.branch_units = 0);
        assert!(
            e.contains("branch_units ([model] in --config) 0 is out of range"),
            "{e}"
        );
        let e = err(&|c| c.model.hidden = 33);
        assert!(e.contains("--hidden 33") && e.contains("1..=32"), "{e}");
        let e = err(&|c| c.model.layers = 0);
        assert!(e.contains("--layers 0"), "{e}");
        let e = err(&|c| c.train.batch = 5000);
        assert!(e.contains("--batch 5000"), "{e}");
        // Each within its range, but together too many steps in one batch.
        let e = err(&|c| {
            c.model.rate_hz = 1e6;
            c.train.batch = 64;
        });
        assert!(e.contains("model steps") && e.contains("--batch 64"), "{e}");
        let e = err(&|c| c.train.lr = f64::NAN);
        assert!(e.contains("--lr NaN"), "{e}");
        let e = err(&|c| c.train.lr = 0.0);
        assert!(e.contains("--lr 0 is out of range"), "{e}");
        let e = err(&|c| c.model.b_fl_bounds = (10.0, 0.1));
        assert!(
            e.contains("b_fl_bounds") && e.contains("(10, 0.1) is out of range"),
            "{e}"
        );
        let e = err(&|c| c.model.pr_bounds = (0.0, 5.0));
        assert!(e.contains("pr_bounds"), "{e}");
        let e = err(&|c| c.train.lambda_l2 = -1.0);
        assert!(e.contains("--lambda-l2 -1"), "{e}");
        let e = err(&|c| c.train.lambda_diff = f64::NAN);
        assert!(e.contains("--lambda-diff NaN"), "{e}");
        let e = err(&|c| c.train.epochs = 0);
        assert!(e.contains("--epochs 0 trains nothing"), "{e}");
        let e = err(&|c| c.train.max_batches = Some(0));
        assert!(e.contains("--max-batches 0"), "{e}");
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
        // The cut-off is chosen per run, at most 0.4 x 300 Hz: below the Nyquist frequency.
        assert_eq!(r.config.cutoff_hz, None);
        assert!(matches!(choice(&r, "cutoff_hz").2, OptionSource::Data(_)));
        // The test level exists: the interior one.
        assert_eq!(r.config.test_alphas, Some(vec![0.5]));
        assert_eq!(r.config.test_tail, None);
        let block = r.block();
        assert!(block.starts_with("data options:\n"), "{block}");
        assert!(
            block.contains(
                "cutoff_hz    auto  (chosen from the data: per run: at most min(150 Hz, 0.4 x \
                 the 300 Hz rate) = 120 Hz, lowered until"
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
        assert_eq!(c.signal.cutoff_hz, None);
        assert_eq!(
            c.signal.at_rate(300.0).expect("rate").max_cutoff_hz(),
            120.0
        );
        let text = toml::to_string(&r.config).expect("toml");
        let back: DataConfig = toml::from_str(&text).expect("parse");
        assert_eq!(back, r.config);
        let again = resolve_with(&back, None, &manifest(300.0, &[0.0, 0.5, 1.0]));
        assert_eq!(again.config, r.config);
        // Saved, every option is given except the cut-off, chosen per run again.
        assert!(again
            .choices
            .iter()
            .all(|c| (c.2 == OptionSource::Given) != (c.0 == "cutoff_hz")));
        // At 10 kHz the paper's settings: at most 150 Hz and the test level 0.15.
        let r = resolve_with(&given, None, &manifest(10_000.0, &[0.0, 0.15, 0.3]));
        assert_eq!(r.config.cutoff_hz, None);
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

    /// Each data flag is named after its field (`--test-alphas` for `test_alphas`), the
    /// singular spellings are aliases, and the demo's options go through the same
    /// `ConfigArgs::apply` as every training command's: its budget is a base the flags
    /// override, and `--seed` seeds the split and the training alike.
    #[test]
    fn flags_are_named_after_fields_and_the_demo_takes_the_same_path() {
        let plural = Cli::parse_from(["nemm", "--test-alphas", "0.3", "--train-alphas", "0,0.15"]);
        let singular = Cli::parse_from(["nemm", "--test-alpha", "0.3", "--train-alpha", "0,0.15"]);
        assert_eq!(plural.args.data_options, singular.args.data_options);
        assert_eq!(plural.args.data_options.test_alphas, Some(vec![0.3]));
        assert_eq!(plural.args.data_options.train_alphas, Some(vec![0.0, 0.15]));

        let demo = Cli::parse_from(["nemm", "--seed", "7", "--epochs", "3"])
            .args
            .base_over(Config::demo())
            .expect("demo config");
        assert_eq!((demo.data.seed, demo.train.seed), (Some(7), 7));
        assert_eq!(demo.train.epochs, 3, "a flag overrides the demo's budget");
        assert_eq!(demo.train.max_batches, Some(DEMO_MAX_BATCHES));
        assert_eq!(demo.train.linear_epochs, DEMO_LINEAR_EPOCHS);
        assert_eq!(demo.data.dir, PathBuf::from(DEMO_DATA_DIR));
        let elsewhere = Cli::parse_from(["nemm", "--data", "mine"])
            .args
            .base_over(Config::demo())
            .expect("demo config");
        assert_eq!(elsewhere.data.dir, PathBuf::from("mine"));
    }
}
