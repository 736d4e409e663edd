//! Shared by the tests of the firmware's trained model (`qemu_e2e`, `qemu_model`): the
//! embedded blob, the training job its provenance records, and the held-out runs.
// Each test file uses part of this module.
#![allow(dead_code)]

use clap::Parser;
use nemm_core::{decode, Model};
use nemm_dataset::{self as dataset, Dataset};
use nemm_tests::elf::Elf;
use nemm_tests::firmware::{Contents, Images};
use nemm_train::config::{Config, ConfigArgs};
use nemm_train::data::preprocess::{self, SignalConfig};
use nemm_train::train::eval::{predict, Input};
use std::path::{Path, PathBuf};

/// The held-out runs of the end-to-end test: a dataset (manifest + run CSVs, 15 % oil loss).
pub fn e2e_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../nemm-firmware/data/e2e")
}

/// The firmware image and the blob it runs: the embedded one, or `NEMM_E2E_WEIGHTS`.
pub struct Embedded {
    /// The images named in the environment.
    pub images: Images,
    /// The application image.
    pub elf: Elf,
    /// Its weights slot and trace.
    pub contents: Contents,
    /// The blob under test.
    pub blob: Vec<u8>,
    /// It decoded.
    pub model: Model,
}

impl Embedded {
    /// Reads the images named in the environment.
    pub fn from_env() -> Self {
        let images = Images::from_env();
        let elf = Elf::read(&images.app).expect("firmware image");
        let contents = Contents::of(&elf);
        let blob = match std::env::var_os("NEMM_E2E_WEIGHTS") {
            Some(p) => std::fs::read(&p).unwrap_or_else(|e| panic!("{p:?}: {e}")),
            None => contents.blob().to_vec(),
        };
        let model = decode(&blob).expect("the blob decodes on the host");
        Self {
            images,
            elf,
            contents,
            blob,
            model,
        }
    }
}

/// `nemm train` as its provenance records it.
#[derive(Debug, Parser)]
#[command(name = "nemm")]
enum Recorded {
    /// The training job.
    Train {
        #[command(flatten)]
        args: ConfigArgs,
        #[arg(long)]
        out: PathBuf,
        #[arg(long)]
        variant: Option<nemm_core::ModelKind>,
        #[command(flatten)]
        tables: nemm_train::cli::train::TablesArgs,
    },
}

/// The training configuration of the `nemm train` command a blob's provenance records
/// (dataset folder as recorded).
pub fn recorded_config(model: &Model) -> Config {
    let command = model.provenance.command.as_str();
    let words: Vec<&str> = command.split_ascii_whitespace().collect();
    let Ok(Recorded::Train { args, variant, .. }) = Recorded::try_parse_from(&words) else {
        panic!("the blob's provenance is not a `nemm train` command: {command:?}")
    };
    let mut cfg = args.base().expect("the recorded options apply");
    if let Some(v) = variant {
        cfg.model.variant = v;
    }
    cfg
}

/// The trainer's whole-run evaluation: `model`'s forces \[N\] at every sample of run `index`
/// of `ds`, from rest, on the velocity and stroke position the trainer's preprocessing
/// (`signal`) derives.
pub fn host_forces(model: &Model, ds: &Dataset, index: usize, signal: &SignalConfig) -> Vec<f64> {
    let run = &ds.runs[index];
    let s = preprocess::process_run(run, index, ds.sample_rate_hz, signal).expect("preprocess");
    let u: Vec<f32> = s.velocity_m_s.iter().map(|&v| v as f32).collect();
    let x: Vec<f32> = s.displacement_m.iter().map(|&v| v as f32).collect();
    let input = Input {
        velocity_m_s: &u,
        alpha: run.entry.oil_loss as f32,
        alphas: None,
        position_m: Some(&x),
    };
    predict(model, &[input], 1.0 / ds.sample_rate_hz)
        .expect("evaluation")
        .remove(0)
}

/// RMSE \[N\] of `forces` against the measured `force_n`.
pub fn rmse_n(forces: impl IntoIterator<Item = f64>, force_n: &[f64]) -> f64 {
    let (se, n) = forces
        .into_iter()
        .zip(force_n)
        .fold((0.0, 0usize), |(se, n), (y, m)| {
            (se + (y - m).powi(2), n + 1)
        });
    (se / n.max(1) as f64).sqrt()
}

/// The held-out runs.
pub fn e2e_runs() -> Dataset {
    dataset::load(&e2e_dir()).expect("the end-to-end runs load")
}

/// The signal options of `cfg` (the velocity source the model was trained on).
pub fn signal_config(cfg: &Config, dir: &Path) -> SignalConfig {
    let mut data = cfg.data.clone();
    data.dir = dir.to_path_buf();
    nemm_train::config::resolve_data(&data)
        .expect("data options")
        .config
        .prepare_config()
        .signal
}
