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
        cmd: nemm_train::data_cli::DataCmd,
    },
    /// Virtual test bench: generate a synthetic dataset, plot loops of a dataset.
    Bench(nemm_train::bench::cli::BenchArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Inspect { model } => nemm_train::inspect::run(&model),
        Cmd::Data { cmd } => nemm_train::data_cli::run(cmd),
        Cmd::Bench(args) => nemm_train::bench::cli::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
