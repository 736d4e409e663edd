//! `nemm`: the command-line interface of nemm-train. Run `nemm --help`.
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "nemm",
    version,
    about = "Neural Equivalent Mechanical Model of degrading dampers: bench data, training, export"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Print what is inside a weights blob (`.nemm`): kind, sizes, constants, checks.
    Inspect {
        /// The weights blob.
        model: PathBuf,
    },
    /// Bench datasets: validate (`check`) and preprocess (`prepare`, section 5.3).
    Data {
        /// What to do.
        #[command(subcommand)]
        cmd: nemm_train::cli::data::DataCmd,
    },
    /// Virtual test bench: generate a synthetic dataset, plot loops of a dataset.
    Bench(nemm_train::cli::bench::BenchArgs),
    /// Train one variant and export it as a weights blob (written atomically).
    Train {
        /// Training options.
        #[command(flatten)]
        args: nemm_train::config::ConfigArgs,
        /// Output weights blob.
        #[arg(long, default_value = "model.nemm")]
        out: PathBuf,
        /// ModelKind: nemm, nemm-light, linear-emm or sem.
        #[arg(long, help = format!(
            "ModelKind: nemm, nemm-light, linear-emm or sem [default: {}]",
            nemm_train::config::ModelConfig::default().variant.name()))]
        variant: Option<nemm_core::ModelKind>,
        /// Checkpoint folder (one sub-folder per stage, written every epoch).
        #[arg(long)]
        checkpoint: Option<PathBuf>,
        /// Continue from the checkpoints in --checkpoint.
        #[arg(long, requires = "checkpoint")]
        resume: bool,
        /// Also write report.json, table.md and the effective config.toml into this folder.
        #[arg(long)]
        report: Option<PathBuf>,
        /// With --report, also where the model puts the degradation: every run's best-fit
        /// level (identify.md), the degradation signature and its figure, and the virtual
        /// bench's reference coefficients. `--degradation-report=false` skips them (they
        /// cost more than the rest of the report); `nemm sweep` does so for the grids whose
        /// tables do not show them.
        #[arg(long, requires = "report", num_args = 0..=1, default_value_t = true, value_name = "BOOL",
              default_missing_value = "true", action = clap::ArgAction::Set)]
        degradation_report: bool,
        /// Precomputed fast-path tables in the blob.
        #[command(flatten)]
        tables: nemm_train::cli::train::TablesArgs,
        /// Replace an existing --out file that is not a weights blob.
        #[arg(long)]
        replace: bool,
    },
    /// Export the best model of a checkpoint folder (`--checkpoint DIR/<variant>` of `nemm train`).
    Export {
        /// A variant's checkpoint folder, e.g. ckpt/nemm.
        #[arg(long)]
        checkpoint: PathBuf,
        /// Output weights blob.
        #[arg(long, default_value = "model.nemm")]
        out: PathBuf,
        /// Bound of the tabulated fast path's relative coefficient error checked at export
        /// (see docs/core.md, "Tabulated fast path").
        #[arg(long, default_value_t = nemm_train::train::table_check::DEFAULT_TABLE_BOUND)]
        table_bound: f32,
        /// Precomputed fast-path tables in the blob.
        #[command(flatten)]
        tables: nemm_train::cli::train::TablesArgs,
        /// Replace an existing --out file that is not a weights blob.
        #[arg(long)]
        replace: bool,
    },
    /// Store fast-path tables in an existing weights blob: the model (weights, condition,
    /// provenance) unchanged bit for bit, its tables section replaced by the levels of
    /// --tables-alpha and --tables-levels (e.g. `--tables-levels 7` for the level tables of a
    /// per-sample level and the alpha observer on a firmware).
    Tables {
        /// The weights blob.
        model: PathBuf,
        /// Output weights blob (may be the input).
        #[arg(long)]
        out: PathBuf,
        /// The tables to store.
        #[command(flatten)]
        tables: nemm_train::cli::train::TablesArgs,
        /// Replace an existing --out file that is not a weights blob.
        #[arg(long)]
        replace: bool,
        /// With --out the input: drop the stored tables of levels the table options do not
        /// list (refused without it, naming them).
        #[arg(long)]
        drop_tables: bool,
    },
    /// Train all four variants and write Table 4 (table4.md, report.json), the best-fit level
    /// of every run (identify.md), models and figures.
    Compare {
        /// Training options.
        #[command(flatten)]
        args: nemm_train::config::ConfigArgs,
        /// Report folder.
        #[arg(long, default_value = "report")]
        report: PathBuf,
        /// Checkpoint folder.
        #[arg(long)]
        checkpoint: Option<PathBuf>,
        /// Continue from the checkpoints in --checkpoint.
        #[arg(long, requires = "checkpoint")]
        resume: bool,
    },
    /// Hyperparameter / lambda_ph sweep (Tables 3 and 5): one `nemm train --config
    /// REPORT/jobs/ID/config.toml` process per configuration (`--lambda-ph 0,5,15,25` by
    /// default: Table 5's values x1000), on this machine or as a Slurm job array
    /// (`--engine slurm`), collected into table5.md (table3.md for `--grid table3`) and
    /// sweep.json.
    Sweep {
        /// Training options (the base of every job).
        #[command(flatten)]
        args: nemm_train::config::ConfigArgs,
        /// Grid: lambda (Table 5), priors (Table 5 by construction and by the penalty
        /// alone), state-priors (the priors in the state by construction at the base's
        /// lambda and by the penalty at each lambda; into state-priors.md), table3 (Table 3
        /// search space x lambda list) or degradation (the paper's NEMM, b_fl fixed in
        /// alpha, the lost-motion element, both; into degradation.md).
        #[arg(long, value_enum, default_value_t = nemm_train::cli::train::SweepGrid::Lambda)]
        grid: nemm_train::cli::train::SweepGrid,
        /// The Table 3 grid's values.
        #[command(flatten)]
        table3: nemm_train::cli::train::Table3Args,
        /// Report folder (jobs in REPORT/jobs/ID/).
        #[arg(long, default_value = "sweep")]
        report: PathBuf,
        /// Where the jobs run: local (processes on this machine, returns when they have
        /// finished) or slurm (a job array submitted with sbatch, returns at once)
        /// [default: local; on --resume the sweep's].
        #[arg(long, value_enum)]
        engine: Option<nemm_train::cli::train::Engine>,
        /// Jobs at a time: local processes, or the Slurm array's %N throttle [default: 1
        /// locally, 8 on Slurm; on --resume the sweep's].
        #[arg(long)]
        jobs: Option<usize>,
        /// The Slurm engine's options.
        #[command(flatten)]
        slurm: nemm_train::cli::train::SlurmArgs,
        /// Only write the jobs' config.toml files and print one `nemm train` command line per
        /// job.
        #[arg(long)]
        list: bool,
        /// Slurm: write the job script and print the cost estimate, do not submit.
        #[arg(long)]
        dry_run: bool,
        /// Only collect the finished jobs of the sweep in REPORT (default: --report) into
        /// the table, and list those that failed or have no result.
        #[arg(long, value_name = "REPORT", num_args = 0..=1, conflicts_with = "resume")]
        collect: Option<Option<PathBuf>>,
        /// Run the jobs of the sweep in REPORT (default: --report) that failed or have no
        /// result again (each from its config.toml as it is now).
        #[arg(long, value_name = "REPORT", num_args = 0..=1)]
        resume: Option<Option<PathBuf>>,
    },
    /// The best-fit condition level of every run of a dataset for a trained model (the level
    /// of least whole-run force RMSE on a grid, searched coarse to fine), against the run's
    /// label, and the model's whole-run error per level and run.
    Identify {
        /// The weights blob.
        #[arg(long)]
        model: PathBuf,
        /// Dataset folder (manifest.toml + CSV runs).
        #[arg(long)]
        data: PathBuf,
        /// Runs to identify: glob(s) on the run files' paths (relative to the manifest) or
        /// names, e.g. 'runs/oil15_*' (repeatable) [default: every run the split uses].
        #[arg(long, value_name = "GLOB")]
        runs: Vec<String>,
        /// Step of the grid of levels (0 up to the model's largest training level).
        #[arg(long, default_value_t = nemm_train::train::identify::DEFAULT_STEP)]
        step: f64,
        /// Simulate every level of the grid (the whole RMSE curve in identify.json) instead
        /// of the coarse-to-fine search.
        #[arg(long)]
        full_grid: bool,
        /// Also write identify.json and identify.md into this folder.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Data options.
        #[command(flatten)]
        data_options: nemm_train::config::DataConfig,
    },
    /// The online alpha observer (nemm-core's AlphaObserver) over recorded runs, driven as on
    /// target, against the offline best fit of the same model: per run the final estimate,
    /// its band, excitation and settling time; writes diagnose.json, one alpha(t) figure per
    /// run, the accuracy tables (the observer's error from 2 s on, the model's resolution per
    /// condition) and, with --level-step, a record whose level steps (docs/observer.md,
    /// "nemm diagnose").
    Diagnose {
        /// The weights blob.
        #[arg(long)]
        model: PathBuf,
        /// Dataset folder (manifest.toml + CSV runs), sampled at the model's rate.
        #[arg(long)]
        data: PathBuf,
        /// Runs to diagnose: glob(s) on the run files' paths (relative to the manifest) or
        /// names, e.g. 'runs/oil15_*' (repeatable) [default: every run].
        #[arg(long, value_name = "GLOB")]
        runs: Vec<String>,
        /// Report folder: diagnose.json, one figure alpha_RUN.png per run, accuracy.md and
        /// accuracy.json (the observer's error from 2 s on, the resolution per condition).
        #[arg(long)]
        report: PathBuf,
        /// A level step: two runs of one periodic condition (files as for --runs, each
        /// matching one run), joined at a rising crossing of the displacement into one record
        /// whose level steps where the second begins; writes level-step.json, level-step.md
        /// and level-step.png.
        #[arg(long, value_name = "A,B", value_delimiter = ',', num_args = 1)]
        level_step: Vec<String>,
        /// With --level-step: times each run's steady part (its trailing full periods) is
        /// played, for a longer record of the same periodic state.
        #[arg(long, value_name = "N", default_value_t = 1, requires = "level_step")]
        step_repeat: usize,
    },
    /// The main job: virtual bench (generated if absent), all four variants on a budget of a
    /// few minutes, Table 4, figures, model.nemm, and the exported model run through nemm-core.
    /// The options are those of `nemm compare`, over the demo's defaults: --data out/bench
    /// (the default virtual bench is generated there if it is empty) and the demo's budget
    /// of epochs and batches (`nemm_train::config::Config::demo`; the flags override it).
    Demo {
        /// Results folder.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        /// The job's options (as `nemm compare`'s).
        #[command(flatten)]
        args: nemm_train::config::ConfigArgs,
    },
}

/// The two runs of `nemm diagnose --level-step A,B` (`None` without the option).
fn level_step_pair(files: Vec<String>) -> anyhow::Result<Option<[String; 2]>> {
    match <[String; 2]>::try_from(files) {
        Ok(pair) => Ok(Some(pair)),
        Err(v) if v.is_empty() => Ok(None),
        Err(v) => anyhow::bail!("--level-step takes two runs, A,B (got {})", v.len()),
    }
}

/// `--session-epochs` stops a job so that `--resume` continues it from its checkpoint: without
/// `--checkpoint` the epochs trained would be lost.
fn session_needs_checkpoint(
    cfg: &nemm_train::config::Config,
    checkpoint: bool,
) -> anyhow::Result<()> {
    if let (Some(n), false) = (cfg.train.session_epochs, checkpoint) {
        anyhow::bail!(
            "--session-epochs {n} needs --checkpoint DIR: the session stops after {n} epoch(s) \
             and only a checkpoint keeps them for --resume"
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Inspect { model } => nemm_train::report::inspect(&model),
        Cmd::Data { cmd } => nemm_train::cli::data::run(cmd),
        Cmd::Bench(args) => nemm_train::cli::bench::run(args),
        Cmd::Train {
            args,
            out,
            variant,
            checkpoint,
            resume,
            report,
            degradation_report,
            tables,
            replace,
        } => args.resolve().and_then(|mut cfg| {
            session_needs_checkpoint(&cfg, checkpoint.is_some())?;
            if let Some(v) = variant {
                cfg.model.variant = v;
            }
            nemm_train::cli::train::train(
                &cfg,
                &out,
                checkpoint.as_deref(),
                resume,
                report
                    .as_deref()
                    .map(|dir| nemm_train::cli::train::ReportTo {
                        dir,
                        degradation: degradation_report,
                    }),
                &tables,
                replace,
            )
        }),
        Cmd::Export {
            checkpoint,
            out,
            table_bound,
            tables,
            replace,
        } => nemm_train::cli::train::export(&checkpoint, &out, table_bound, &tables, replace),
        Cmd::Tables {
            model,
            out,
            tables,
            replace,
            drop_tables,
        } => nemm_train::cli::train::store_tables(&model, &out, &tables, replace, drop_tables),
        Cmd::Compare {
            args,
            report,
            checkpoint,
            resume,
        } => args.resolve().and_then(|cfg| {
            session_needs_checkpoint(&cfg, checkpoint.is_some())?;
            nemm_train::cli::train::compare_command(&cfg, &report, checkpoint.as_deref(), resume)
                .map(|_| ())
        }),
        Cmd::Sweep {
            args,
            grid,
            table3,
            report,
            engine,
            jobs,
            slurm,
            list,
            dry_run,
            collect,
            resume,
        } => {
            use nemm_train::cli::train as t;
            let options = t::SweepOptions {
                jobs,
                engine,
                slurm,
                list,
                dry_run,
            };
            if let Some(dir) = collect {
                t::collect(&dir.unwrap_or(report))
            } else if let Some(dir) = resume {
                t::resume(&dir.unwrap_or(report), &options)
            } else {
                args.base().and_then(|base| {
                    base.validate()?;
                    let lambdas = args
                        .lambda_ph_list()
                        .map_or_else(|| grid.default_lambdas(&base), <[f64]>::to_vec);
                    t::sweep(&base, grid, &table3, &lambdas, &report, &options)
                })
            }
        }
        Cmd::Identify {
            model,
            data,
            runs,
            step,
            full_grid,
            report,
            data_options,
        } => nemm_train::cli::identify::identify(
            &model,
            &data_options.in_dir(&data),
            &runs,
            step,
            if full_grid {
                nemm_train::train::identify::Search::Full
            } else {
                nemm_train::train::identify::Search::CoarseToFine
            },
            report.as_deref(),
        ),
        Cmd::Diagnose {
            model,
            data,
            runs,
            report,
            level_step,
            step_repeat,
        } => level_step_pair(level_step).and_then(|level_step| {
            nemm_train::cli::diagnose::diagnose(&nemm_train::cli::diagnose::DiagnoseArgs {
                model,
                data,
                runs,
                report,
                level_step,
                step_repeat,
            })
        }),
        Cmd::Demo { out, args } => {
            args.base_over(nemm_train::config::Config::demo())
                .and_then(|cfg| {
                    let paths = nemm_train::cli::train::DemoPaths {
                        data: cfg.data.require_dir()?.to_path_buf(),
                        out,
                    };
                    nemm_train::cli::train::demo(&paths, &cfg)
                })
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.is::<nemm_train::train::pipeline::SessionBudgetUsed>() => {
            eprintln!("{e}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
