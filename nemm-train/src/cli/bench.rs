//! `nemm bench ...`: generate a virtual-bench dataset, plot a dataset, print the default config.

use crate::output_guard::{self, Inputs, Output};
use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use nemm_virtual_bench::config::{self, BenchConfig};
use nemm_virtual_bench::reference::{EmmReference, BENCH_CONFIG_FILE};
use nemm_virtual_bench::VirtualBench;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `nemm bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// What to do.
    #[command(subcommand)]
    pub cmd: BenchCmd,
}

/// Subcommands of `nemm bench`.
#[derive(Debug, Subcommand)]
pub enum BenchCmd {
    /// Simulate the test programme on the virtual damper and write a dataset folder.
    Generate {
        /// Output dataset folder (created; a dataset the virtual bench generated there is
        /// replaced as a whole, another only with --replace).
        #[arg(long)]
        out: PathBuf,
        /// Bench configuration (TOML, every key; default: the built-in `bench.toml`).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Seed of the measurement noise.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Oil-loss levels to run the programme at, comma-separated (for example
        /// `0,0.075,0.15,0.225,0.3`); replaces the configuration's `program.oil_loss`.
        #[arg(long, value_delimiter = ',', num_args = 1..)]
        levels: Option<Vec<f64>>,
        /// Replace a dataset in `--out` that the virtual bench did not generate (one without
        /// its `bench.toml`), e.g. imported dyno data.
        #[arg(long)]
        replace: bool,
    },
    /// Draw force-velocity loops (Fig. 4 style) and difference loops (Fig. 5 style) of a dataset.
    Plot {
        /// Dataset folder (with manifest.toml).
        dir: PathBuf,
        /// Output folder for the PNG files.
        #[arg(long)]
        out: PathBuf,
        /// Data options (the plots use the cut-off and the velocity source).
        #[command(flatten)]
        data: Box<crate::config::DataConfig>,
    },
    /// Print the built-in default configuration (a template for `--config`).
    Config,
    /// Print the equivalent EMM coefficients the bench implies per oil-loss level (the
    /// reference curves of Figs. 10-12; docs/virtual-bench.md, "Equivalent EMM coefficients").
    Reference {
        /// Bench configuration (default: the built-in `bench.toml`); a generated dataset
        /// folder's `bench.toml` reproduces its bench.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Print JSON instead of Markdown tables.
        #[arg(long)]
        json: bool,
        /// The pressure element on every condition of the programme (amplitude x peak
        /// velocity) at its levels, instead of on the reference run.
        #[arg(long)]
        every_condition: bool,
    },
    /// Write the test fixtures (small datasets with the traits of real dyno records) into
    /// `--out`, replacing their folders (the repository's are in nemm-train/tests/fixtures).
    Fixtures {
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Runs a `nemm bench` subcommand.
pub fn run(args: BenchArgs) -> Result<()> {
    match args.cmd {
        BenchCmd::Generate {
            out,
            config,
            seed,
            levels,
            replace,
        } => {
            let inputs = Inputs::new().paths("--config", config.as_deref());
            output_guard::check(&[Output::dataset("--out", &out)], &inputs, false, "")?;
            let manifest = out.join(nemm_dataset::MANIFEST_FILE);
            if manifest.exists() && !out.join(BENCH_CONFIG_FILE).exists() && !replace {
                bail!(
                    "--out {}: holds a dataset the virtual bench did not generate ({} without \
                     {BENCH_CONFIG_FILE}); give --replace to replace it as a whole, or choose \
                     another --out folder",
                    out.display(),
                    manifest.display()
                );
            }
            let mut cfg = match &config {
                Some(path) => config::load(path)?,
                None => BenchConfig::default(),
            };
            if let Some(levels) = levels {
                cfg.program.oil_loss = levels;
                if let Err(v) = cfg.validate() {
                    bail!("--levels: `{}` {}", v.key, v.message);
                }
            }
            generate(&cfg, seed, &out)
        }
        BenchCmd::Plot { dir, out, data } => {
            let inputs = Inputs::new().dataset("the dataset", &dir);
            output_guard::check(&[Output::folder("--out", &out)], &inputs, false, "")?;
            let resolved = crate::config::resolve_data(&data.in_dir(&dir))?;
            let signal = resolved.config.prepare_config().signal;
            let ds = nemm_dataset::load(&dir)
                .with_context(|| format!("cannot load the dataset {}", dir.display()))?;
            let signals = crate::data::preprocess::run_signals(&ds, &signal)
                .context("cannot derive the velocity of the runs")?;
            let plotted = crate::report::bench_plots::plot_loaded(&ds, &signals, &out)?;
            for f in &plotted.written {
                println!("wrote {}", f.display());
            }
            for (file, why) in &plotted.skipped {
                eprintln!("skipped {}: {why}", file.display());
            }
            if !plotted.skipped.is_empty() {
                bail!(
                    "{} of {} runs skipped (listed above); the figures show the others",
                    plotted.skipped.len(),
                    ds.runs.len()
                );
            }
            Ok(())
        }
        BenchCmd::Reference {
            config,
            json,
            every_condition,
        } => {
            let cfg = match &config {
                Some(path) => config::load(path)?,
                None => BenchConfig::default(),
            };
            if every_condition {
                let refs = nemm_virtual_bench::reference::every_condition(&VirtualBench::new(cfg))?;
                if json {
                    println!("{}", serde_json::to_string_pretty(&refs)?);
                } else {
                    print!(
                        "{}",
                        nemm_virtual_bench::reference::every_condition_markdown(&refs)
                    );
                }
                return Ok(());
            }
            let r = EmmReference::of(&VirtualBench::new(cfg))?;
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                print!("{}", r.markdown());
            }
            Ok(())
        }
        BenchCmd::Config => {
            print!("{}", config::DEFAULT_TOML);
            Ok(())
        }
        BenchCmd::Fixtures { out } => {
            output_guard::check(&[Output::folder("--out", &out)], &Inputs::new(), false, "")?;
            for f in nemm_virtual_bench::fixtures::write_fixtures(&out)? {
                println!("wrote {}", f.display());
            }
            Ok(())
        }
    }
}

/// Generates the programme of `cfg` into `out`, printing progress on stderr. The dataset
/// `out` holds is replaced as a whole ([`nemm_dataset::write()`]: built in a sibling
/// folder and swapped in; other files in `out` are kept).
pub fn generate(cfg: &BenchConfig, seed: u64, out: &Path) -> Result<()> {
    let bench = VirtualBench::new(cfg.clone());
    let total = bench.runs().len();
    let threads = rayon::current_num_threads();
    eprintln!(
        "virtual bench: {total} runs on {threads} threads, seed {seed} -> {}",
        out.display()
    );
    let start = Instant::now();
    let dataset = bench.generate(seed, |done, total| {
        let mut err = std::io::stderr().lock();
        let _ = write!(
            err,
            "\r  simulated {done:>3}/{total} runs, {:6.1} s",
            start.elapsed().as_secs_f64()
        );
        let _ = err.flush();
    });
    eprintln!();
    let simulated = start.elapsed().as_secs_f64();
    nemm_dataset::write(out, &dataset)
        .with_context(|| format!("cannot write the dataset to {}", out.display()))?;
    write_bench_config(cfg, out)?;
    let bytes: u64 = dataset
        .runs
        .iter()
        .filter_map(|r| std::fs::metadata(out.join(&r.entry.file)).ok())
        .map(|m| m.len())
        .sum();
    let seconds: f64 = dataset
        .runs
        .iter()
        .map(|r| r.len() as f64 / dataset.sample_rate_hz)
        .sum();
    eprintln!(
        "wrote {} runs, {} samples ({:.1} s of data, {:.1} MB CSV) in {:.1} s (simulation {:.1} s)",
        dataset.runs.len(),
        dataset.total_samples(),
        seconds,
        bytes as f64 / 1e6,
        start.elapsed().as_secs_f64(),
        simulated
    );
    Ok(())
}

/// Writes the configuration a dataset was generated with into its folder
/// ([`BENCH_CONFIG_FILE`]): it marks the data as the virtual bench's and lets the report draw
/// the bench's reference coefficients (`bench::reference::for_dataset`).
pub fn write_bench_config(cfg: &BenchConfig, dir: &Path) -> Result<()> {
    let path = dir.join(BENCH_CONFIG_FILE);
    let text = format!(
        "# The virtual-bench configuration this dataset was generated with (nemm bench generate).\n\
         # The report reads it to draw the bench's equivalent EMM coefficients\n\
         # (docs/virtual-bench.md, \"Equivalent EMM coefficients\").\n{}",
        cfg.to_toml()?
    );
    nemm_dataset::atomic_file::write_atomic_bytes(&path, text.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))
}
