//! The command line of a job ([`ConfigArgs`]): `--config`, `--data` and the three sections'
//! options ([`DataConfig`], [`ModelOptions`], [`TrainOptions`]), each of which overrides its
//! part of a [`Config`].

use super::{lambda_ph_scale_note, Config, DataConfig, ModelOptions, TrainOptions};
use anyhow::{bail, Result};
use std::path::{Path, PathBuf};

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
    /// The data options (its `--seed` also sets
    /// [`TrainConfig::seed`](super::TrainConfig::seed)).
    #[command(flatten)]
    pub data_options: DataConfig,
    /// The model options.
    #[command(flatten)]
    pub model: ModelOptions,
    /// The training options.
    #[command(flatten)]
    pub train: TrainOptions,
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
        if let Some(list) = self.train.lambda_ph.as_deref().filter(|l| l.len() > 1) {
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
        self.train.lambda_ph.as_deref()
    }

    /// Applies the given options onto `c`: each section's over its own, and `--seed` (a data
    /// option) onto [`TrainConfig::seed`](super::TrainConfig::seed) as well.
    pub fn apply(&self, c: &mut Config) {
        let given = self
            .data_options
            .in_dir(self.data.as_deref().unwrap_or(Path::new("")));
        c.data = given.over(&c.data);
        self.model.over(&mut c.model);
        self.train.over(&mut c.train);
        if let Some(seed) = self.data_options.seed {
            c.train.seed = seed;
        }
    }
}
