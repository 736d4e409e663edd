//! The Slurm engine of `nemm sweep` on a real one-node cluster: its test (a step of `cargo
//! xtask test`) and its overhead benchmark (`cargo xtask bench-slurm`), both in
//! nemm-train/tests/slurm.rs, ignored by a plain `cargo test` because they need root and
//! Debian's `slurm-wlm` and `munge`; without them they print why they are skipped and pass.

use crate::{cargo, run, Paths};
use std::process::Command;
use std::time::Instant;

/// `cargo test` of one ignored test of nemm-train/tests/slurm.rs, in release (`--workspace`
/// keeps the features, and so the build, of the workspace run).
fn slurm_test(paths: &Paths, name: &str) -> Command {
    let mut c = cargo();
    c.args(["test", "--workspace", "--release", "--test", "slurm", "--"])
        .args(["--ignored", "--exact", "--nocapture", name])
        .current_dir(&paths.root);
    c
}

/// The sweep through a one-node Slurm against the local engine (at most 2 minutes once
/// built; skipped with a message where no cluster can be started).
pub fn test(paths: &Paths) -> Result<(), String> {
    let t = Instant::now();
    run(&mut slurm_test(
        paths,
        "a_sweep_through_slurm_equals_the_local_one",
    ))?;
    eprintln!(
        "xtask: the Slurm sweep test took {:.0} s",
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The overhead of the Slurm engine against the local one on `tasks` tiny configurations,
/// two at a time: one `slurm-overhead` line of figures.
pub fn bench(paths: &Paths, tasks: usize) -> Result<(), String> {
    run(slurm_test(paths, "overhead_of_the_slurm_engine")
        .env("NEMM_BENCH_TASKS", tasks.to_string()))
}
