//! The `tables` block (`cargo xtask results --tables`): the fast path's table errors, the
//! export check and the level tables of the firmware's trained NEMM.

use super::{command_line, commit, refuse_dirty, write_block, TRAINED_BLOB};
use crate::Paths;

/// `cargo xtask results --tables`: the `tables` block. Runs nemm-core's `table_error`
/// example (exact against tabulated forces over the Table 1 programme) and nemm-train's
/// `table_check` example (the export check) on the firmware's trained model.
pub fn tables(paths: &Paths, allow_dirty: bool) -> Result<(), String> {
    let commit = commit(&paths.root);
    refuse_dirty("the work tree", &commit, allow_dirty)?;
    let output = |package: &str, example: &str, args: &[&str]| -> Result<String, String> {
        let mut c = crate::cargo();
        c.args([
            "run",
            "-q",
            "--release",
            "-p",
            package,
            "--example",
            example,
            "--",
        ])
        .args(args)
        .current_dir(&paths.root);
        eprintln!("xtask: {package} example {example} {}", args.join(" "));
        let out = c.output().map_err(|e| format!("cargo: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "example {example} failed: {}",
                String::from_utf8_lossy(&out.stderr)
            ));
        }
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    };
    let errors = output("nemm-core", "table_error", &["--markdown", TRAINED_BLOB])?;
    let check = output("nemm-train", "table_check", &[TRAINED_BLOB])?;
    let levels = output("nemm-core", "levels_error", &["--markdown", TRAINED_BLOB])?;
    let md = tables_markdown(&command_line(), &commit, &errors, &check, &levels);
    write_block(paths, "tables", &md)
}

/// The `tables` block: the force errors of the fast path, the export check, then the level
/// tables.
fn tables_markdown(command: &str, commit: &str, errors: &str, check: &str, levels: &str) -> String {
    format!(
        "Measured by `{command}` at commit `{commit}`.\n\n\
         **Force error of the tables** (`cargo run --release -p nemm-core --example table_error \
         -- --markdown {TRAINED_BLOB}`): the paper's Table 1 programme (18 strokes of three \
         periods from rest at the model's step), exact and table mode side by side; \
         coefficient error: the largest relative error the table compile measured (bound 1 so \
         that every size is measured); `{TRAINED_BLOB}` is the firmware's trained NEMM, the \
         example models are `nemm_core::testing`'s (H = 16, L = 5, pseudo-random, untrained).\n\n\
         {}\n\n\
         **Export check** (`cargo run --release -p nemm-train --example table_check -- \
         {TRAINED_BLOB}`, what `nemm export` prints):\n\n```text\n{}\n```\n\n\
         **Every level at table cost** (`cargo run --release -p nemm-core --example levels_error \
         -- --markdown {TRAINED_BLOB}`): `LevelTables` of 4, 7 and 13 levels evenly over the \
         trained range (128 segments, bound 1e-4): the tables' bytes in the blob (flash, where \
         they are read in place) and the level tables' own RAM; \
         the worst relative error of each blended coefficient against the exact scalers (7 \
         levels inside each interval, 16 states per segment); points where neighbouring levels \
         are out of the declared order (tables / exact model); the force of a level per sample \
         (on the attached level tables) against the exact per-sample `alpha` (no tables), \
         over the Table 1 programme at \
         the middle of every interval and with alpha ramping over the trained range within \
         each stroke, as a fraction of the force scale.\n\n{}\n",
        errors.trim_end(),
        check.trim_end(),
        levels.trim_end()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tables_block_names_its_commit_and_keeps_the_rows() {
        let rows = "| model | alpha |\n|---|---:|\n| `x.nemm` | 0.15 |\n";
        let md = tables_markdown(
            "cargo xtask results --tables",
            "abc1234",
            rows,
            "check: ok\n",
            "| levels |\n|---:|\n| 7 |\n",
        );
        assert!(md.starts_with("Measured by `cargo xtask results --tables` at commit `abc1234`."));
        assert!(md.contains("| `x.nemm` | 0.15 |\n\n**Export check**"));
        assert!(md.contains("```text\ncheck: ok\n```"));
        assert!(md.ends_with("| 7 |\n"));
    }
}
