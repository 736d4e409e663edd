//! The firmware's trained model and its end-to-end accuracy.
//!
//! - `cargo xtask firmware-model`: trains the model the firmware images embed
//!   ([`FIRMWARE_MODEL`]) with one `nemm train` command ([`train_args`]) on the default
//!   virtual bench (generated into [`BENCH_DIR`] if absent); the trainer records the command,
//!   the dataset and its commit in the blob (`nemm inspect` prints them).
//! - `cargo xtask e2e`: the held-out runs of `nemm-firmware/data/e2e/` through the firmware in
//!   QEMU (the QEMU test `qemu_e2e`), one line per run.

use crate::firmware;
use crate::toolchain::Toolchain;
use crate::{cargo, run, Paths};
use std::path::Path;
use std::process::{Command, Stdio};

/// The blob the firmware embeds by default (`nemm-firmware/build.rs`), relative to the
/// workspace root.
pub const FIRMWARE_MODEL: &str = "nemm-firmware/data/trained-nemm.nemm";
/// Where the training data are generated, relative to the workspace root.
pub const BENCH_DIR: &str = "out/firmware-bench";
/// Seed of the virtual bench.
pub const BENCH_SEED: &str = "1";

/// The oil-loss level the firmware images run at, whose fast-path tables the embedded blob
/// stores: the bench trace's (nemm-firmware's `trace`) and the board's `ALPHA`, 15 %.
pub const FIRMWARE_ALPHA: &str = "0.15";

/// Levels evenly over the trained range whose tables the embedded blob stores as well: the
/// level tables of the alpha observer and of a level per sample (nemm-core's `LevelTables`).
pub const FIRMWARE_LEVELS: usize = 7;

/// The `nemm train` arguments of the firmware's model: the demo's NEMM budget (12 epochs of
/// 8 batches, 6 Linear EMM epochs), the default data options (15 % oil loss held out),
/// `velocity` the velocity source (`None`: the default zero-phase preprocessing); the blob
/// stores the fast-path tables at [`FIRMWARE_ALPHA`] with the firmware's segment count and
/// bound (the trainer's defaults), so that the images boot without building them, and at
/// [`FIRMWARE_LEVELS`] levels over the trained range.
pub fn train_args(out: &str, velocity: Option<&str>) -> Vec<String> {
    let mut a: Vec<String> = [
        "train",
        "--data",
        BENCH_DIR,
        "--variant",
        "nemm",
        "--epochs",
        "12",
        "--max-batches",
        "8",
        "--linear-epochs",
        "6",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    if let Some(v) = velocity {
        a.extend(["--velocity".to_string(), v.to_string()]);
    }
    a.extend(["--tables-alpha".to_string(), FIRMWARE_ALPHA.to_string()]);
    a.extend(["--tables-levels".to_string(), FIRMWARE_LEVELS.to_string()]);
    a.extend(["--out".to_string(), out.to_string()]);
    a
}

/// Builds the trainer and returns the path of `nemm`.
fn build_trainer(paths: &Paths) -> Result<std::path::PathBuf, String> {
    run(cargo()
        .args(["build", "--release", "-p", "nemm-train"])
        .current_dir(&paths.root))?;
    Ok(paths.target.join("release").join("nemm"))
}

/// `cargo xtask firmware-model [--velocity causal] [--out FILE]`.
pub fn firmware_model(paths: &Paths, velocity: Option<&str>, out: &str) -> Result<(), String> {
    let nemm = build_trainer(paths)?;
    if !paths.root.join(BENCH_DIR).join("manifest.toml").exists() {
        run(Command::new(&nemm)
            .args([
                "bench", "generate", "--out", BENCH_DIR, "--seed", BENCH_SEED,
            ])
            .current_dir(&paths.root))?;
    }
    run(Command::new(&nemm)
        .args(train_args(out, velocity))
        .current_dir(&paths.root))?;
    run(Command::new(&nemm)
        .args(["inspect", out])
        .current_dir(&paths.root))
}

/// `cargo xtask e2e [--weights FILE]`: builds the images, runs the QEMU test `qemu_e2e`
/// (with `weights` in the slot instead of the embedded blob, if given) and prints its
/// `e2e run=<file> firmware_rmse_n=<x> host_rmse_n=<y>` lines.
pub fn e2e(tc: &Toolchain, paths: &Paths, weights: Option<&Path>) -> Result<(), String> {
    let images = firmware::build(tc, paths, firmware::Board::An386)?;
    let mut c = cargo();
    if let Some(w) = weights {
        c.env(
            "NEMM_E2E_WEIGHTS",
            std::path::absolute(w).map_err(|e| e.to_string())?,
        );
    }
    // `--workspace`, as `cargo xtask test` runs the QEMU tests: the same features, the same
    // build.
    images.test_env(&mut c, tc);
    c.args(["test", "--workspace", "--release", "--test", "qemu_e2e"])
        .args(["--", "--ignored", "--nocapture", "--test-threads", "1"])
        .current_dir(&paths.root)
        .stderr(Stdio::inherit());
    eprintln!("xtask: running {}", crate::show(&c));
    let out = c
        .output()
        .map_err(|e| format!("cannot run cargo test: {e}"))?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    // The test harness prints `test <name> ... ` before the test's own output on the same
    // line: take each `e2e` record from where it starts.
    let lines: Vec<&str> = stdout
        .lines()
        .filter_map(|l| l.find("e2e run=").map(|i| &l[i..]))
        .collect();
    for l in &lines {
        println!("{l}");
    }
    if !out.status.success() {
        eprintln!("{stdout}");
        return Err(format!("the end-to-end test failed ({})", out.status));
    }
    if lines.is_empty() {
        return Err("the end-to-end test printed no `e2e` line".into());
    }
    Ok(())
}
