//! `cargo xtask results --observer`: the `observer` block of `docs/results.md` and the figure
//! `docs/img/level_step.png`, from `nemm diagnose` on the virtual bench with the trained model
//! the firmware embeds (minutes; not part of `cargo xtask test`).

use super::{command_line, commit, refuse_dirty, write_block, TRAINED_BLOB};
use crate::Paths;

/// The dataset diagnosed, relative to the workspace root.
pub const BENCH: &str = "out/bench";

/// The report folder `nemm diagnose` writes, relative to the workspace root.
pub const REPORT: &str = "out/observer";

/// The level step's figure as committed, relative to the workspace root (linked from the
/// block, so relative to `docs/` there).
pub const FIGURE: &str = "docs/img/level_step.png";

/// The level step: the 50 mm, 1.048 m/s runs at 0 and 30 % (both excited, their offline fits
/// about 0.2 apart).
pub const LEVEL_STEP: [&str; 2] = ["runs/oil00_a050_v1048.csv", "runs/oil30_a050_v1048.csv"];

/// Times each steady part is played in the level step: the second run's part then lasts
/// 7.2 s, more than two of the observer's 3 s windows.
pub const STEP_REPEAT: usize = 4;

/// The `nemm diagnose` arguments the block is generated with.
fn diagnose_args() -> Vec<String> {
    [
        "diagnose",
        "--model",
        TRAINED_BLOB,
        "--data",
        BENCH,
        "--report",
        REPORT,
        "--level-step",
        &LEVEL_STEP.join(","),
        "--step-repeat",
        &STEP_REPEAT.to_string(),
    ]
    .map(String::from)
    .to_vec()
}

/// Runs `nemm diagnose` on [`BENCH`] (which must exist: `nemm bench generate --out
/// out/bench`), copies its level-step figure to [`FIGURE`] and writes the `observer` block
/// from its `accuracy.md` and `level-step.md`.
pub fn observer(paths: &Paths, allow_dirty: bool) -> Result<(), String> {
    let commit = commit(&paths.root);
    refuse_dirty("the work tree", &commit, allow_dirty)?;
    let manifest = paths.root.join(BENCH).join("manifest.toml");
    if !manifest.is_file() {
        return Err(format!(
            "{} is missing: generate the virtual bench first (cargo run --release -p \
             nemm-train -- bench generate --out {BENCH})",
            manifest.display()
        ));
    }
    let args = diagnose_args();
    eprintln!("xtask: nemm {}", args.join(" "));
    let status = crate::cargo()
        .args([
            "run",
            "-q",
            "--release",
            "-p",
            "nemm-train",
            "--bin",
            "nemm",
            "--",
        ])
        .args(&args)
        .current_dir(&paths.root)
        .status()
        .map_err(|e| format!("cargo: {e}"))?;
    if !status.success() {
        return Err(format!("nemm diagnose failed ({status})"));
    }
    let report = paths.root.join(REPORT);
    let read = |name: &str| {
        let p = report.join(name);
        std::fs::read_to_string(&p).map_err(|e| format!("{}: {e}", p.display()))
    };
    let (accuracy, step) = (read("accuracy.md")?, read("level-step.md")?);
    let figure = paths.root.join(FIGURE);
    std::fs::copy(report.join("level-step.png"), &figure)
        .map_err(|e| format!("{}: {e}", figure.display()))?;
    let md = observer_markdown(&command_line(), &commit, &accuracy, &step);
    write_block(paths, "observer", &md)
}

/// The `observer` block: provenance, the accuracy tables, the level step and its figure.
fn observer_markdown(command: &str, commit: &str, accuracy: &str, step: &str) -> String {
    let figure = FIGURE.trim_start_matches("docs/");
    format!(
        "Measured by `{command}` at commit `{commit}`: `nemm {}` (the firmware's trained NEMM, \
         trained at 0 and 30 %, on the virtual bench `{BENCH}` as `nemm bench generate` \
         writes it by default: the 54 runs of Table 1 at 10 kHz, seed 1).\n\n{}\n\n{}\n\n\
         ![The level step: the online estimate with its band]({figure})\n\n\
         `{FIGURE}`, written by the same command.\n",
        diagnose_args().join(" "),
        accuracy.trim_end(),
        step.trim_end(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_block_names_the_command_and_links_the_figure() {
        let md = observer_markdown(
            "cargo xtask results --observer",
            "abc1234",
            "**The observer's own error.**\n| a |\n",
            "**Level step**: x\n",
        );
        assert!(md.starts_with(
            "Measured by `cargo xtask results --observer` at commit `abc1234`: `nemm diagnose \
             --model nemm-firmware/data/trained-nemm.nemm --data out/bench --report \
             out/observer --level-step runs/oil00_a050_v1048.csv,runs/oil30_a050_v1048.csv \
             --step-repeat 4`"
        ));
        assert!(
            md.contains("| a |\n\n**Level step**: x\n\n![The level step"),
            "{md}"
        );
        assert!(md.contains("](img/level_step.png)"), "{md}");
    }
}
