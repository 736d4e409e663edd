//! `docs/results.md`: the project's measured figures, in blocks that commands generate.
//!
//! Each block lies between `<!-- BEGIN <name> ... -->` and `<!-- END <name> -->`; a run
//! replaces its block (and adds it if the file lacks it) and keeps the rest of the file.
//! Its header names the commit (`git rev-parse --short HEAD`, `+dirty` when tracked files
//! other than `docs/results.md` differ from it) and the command that wrote it.
//!
//! - `target` ([`target()`], `cargo xtask results`): instructions per estimator step per model
//!   kind, integrator and mode (exact, table) in QEMU, and per step of the alpha observer;
//!   the estimated cycles per chip (Cortex-M4F, Cortex-M7) and which combinations fit 10 kHz
//!   (also the README's `fit` block, the NEMM's rows); the boot time; flash and RAM of each
//!   image; the stack of the application.
//! - `training` ([`training()`], `cargo xtask results --training DIR`): the Table 4 (and
//!   Table 5, if present) of a finished `nemm compare` / `nemm demo` report directory, with
//!   the facts its `report.json` records (the command that trained it, ...).
//! - `table3` ([`sweep_block()`] with [`TABLE3`], `cargo xtask results --table3 DIR`): the
//!   Table 3 search of a collected `nemm sweep --grid table3` report folder, with the engine
//!   it ran on and its wall time.
//! - `state-priors` ([`sweep_block()`] with [`STATE_PRIORS`], `cargo xtask results
//!   --state-priors DIR`): the ablation of the priors in the state (held by construction
//!   against the physics penalty at each `lambda_ph`) of a collected `nemm sweep --grid
//!   state-priors` report folder, with the engine it ran on and its wall time.
//! - `host` ([`host()`], `cargo xtask results --host`): the host criterion benches of nemm-core
//!   (estimator step per model kind, integrator, mode and math backend; the alpha observer's
//!   step; decoding) and nemm-train (a batch gradient), with the machine they ran on
//!   ([`crate::host_bench`]).
//! - `observer` ([`observer()`], `cargo xtask results --observer`): the alpha observer's
//!   accuracy on the virtual bench and a level step, from `nemm diagnose`
//!   ([`observer`](mod@observer)).
//! - `c` ([`c_example()`], `cargo xtask results --c`): the C interface's figures on the
//!   emulated Cortex-M4F, from the C example as `cargo xtask c-test` runs it with the
//!   firmware's blob: instructions per step of the estimator and the alpha observer (exact,
//!   table mode, on level tables), the stack peak, the image's sections.

mod c_example;
mod host;
mod observer;
mod tables;
mod target;
mod training;

pub use c_example::c_example;
pub use host::host;
pub use observer::observer;
pub use tables::tables;
pub use target::target;
pub use training::{sweep_block, training, STATE_PRIORS, TABLE3};

use crate::Paths;
use std::path::Path;
use std::process::Command;

/// The results file, relative to the workspace root.
pub const FILE: &str = "docs/results.md";

/// The README, whose `headline` block holds the Table 4 of the last `--training` copy.
pub const README: &str = "README.md";

/// The file as a first run writes it, before filling its blocks.
const SKELETON: &str = "\
# Results

The figures below are generated: each block between `BEGIN` and `END` comments is written by
the command named in its header, with the commit it measured. Do not edit inside the blocks
(the next run replaces them); the text around them is kept.

## On the target (Cortex-M4F and Cortex-M7, emulated)

<!-- BEGIN target -->
Not generated yet: run `cargo xtask results`.
<!-- END target -->

## Tabulated fast path

<!-- BEGIN tables -->
Not generated yet: run `cargo xtask results --tables`.
<!-- END tables -->

## C interface

<!-- BEGIN c -->
Not generated yet: run `cargo xtask results --c`.
<!-- END c -->

## Host benchmarks

<!-- BEGIN host -->
Not generated yet: run `cargo xtask results --host`.
<!-- END host -->

## Alpha observer: accuracy

<!-- BEGIN observer -->
Not generated yet: run `cargo xtask results --observer`.
<!-- END observer -->

## Training (Tables 4 and 5)

<!-- BEGIN training -->
Not generated yet: `cargo xtask results --training DIR` copies the tables of a finished
`nemm compare` or `nemm demo` report directory here.
<!-- END training -->

## Priors in the state

<!-- BEGIN state-priors -->
Not generated yet: `cargo xtask results --state-priors DIR` copies the table of a collected
`nemm sweep --grid state-priors` report folder here.
<!-- END state-priors -->

## Hyperparameter search (Table 3)

<!-- BEGIN table3 -->
Not generated yet: `cargo xtask results --table3 DIR` copies the table of a collected
`nemm sweep --grid table3` report folder here.
<!-- END table3 -->
";

/// `text` with block `name` replaced by `block` (which carries its own markers), or with
/// `block` appended if `text` has no such block.
pub fn replace_block(text: &str, name: &str, block: &str) -> Result<String, String> {
    let begin = format!("<!-- BEGIN {name}");
    let end = format!("<!-- END {name} -->");
    let start = text.match_indices(&begin).map(|(i, _)| i).find(|&i| {
        // `<!-- BEGIN target -->` or `<!-- BEGIN target (...) -->`, not `targets`.
        matches!(text[i + begin.len()..].chars().next(), Some(' ' | '-'))
    });
    let Some(start) = start else {
        let sep = if text.ends_with('\n') || text.is_empty() {
            ""
        } else {
            "\n"
        };
        return Ok(format!("{text}{sep}\n{block}"));
    };
    let stop = text[start..]
        .find(&end)
        .map(|i| start + i + end.len())
        .ok_or_else(|| format!("{FILE}: `{begin}` without `{end}`"))?;
    let stop = if text[stop..].starts_with('\n') {
        stop + 1
    } else {
        stop
    };
    Ok(format!("{}{block}{}", &text[..start], &text[stop..]))
}

/// A block: the markers around `body`, the begin marker naming the command.
fn block(name: &str, command: &str, body: &str) -> String {
    format!(
        "<!-- BEGIN {name} (generated by {command}) -->\n{}\n<!-- END {name} -->\n",
        body.trim_end()
    )
}

/// The command line that runs this xtask, as a user types it.
fn command_line() -> String {
    std::iter::once("cargo xtask".to_string())
        .chain(std::env::args().skip(1))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The commit of the work tree: `git rev-parse --short HEAD`, plus `+dirty` if tracked
/// files other than the results file and the figure it links ([`observer::FIGURE`]) differ
/// from it; `unknown` outside a git checkout.
fn commit(root: &Path) -> String {
    let git = |args: &[&str]| -> Option<String> {
        let out = Command::new("git")
            .args(args)
            .current_dir(root)
            .output()
            .ok()?;
        out.status
            .success()
            .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
    };
    let Some(head) = git(&["rev-parse", "--short", "HEAD"]) else {
        return "unknown".into();
    };
    let exclude = format!(":(exclude){FILE}");
    let figure = format!(":(exclude){}", observer::FIGURE);
    match git(&[
        "status",
        "--porcelain",
        "--untracked-files=no",
        "--",
        ".",
        &exclude,
        &figure,
    ]) {
        Some(changes) if changes.is_empty() => head,
        _ => format!("{head}+dirty"),
    }
}

/// The commit a sweep table's first line names (`... trained at commit `abc1234` ...`, as
/// `nemm sweep` writes it).
fn sweep_commit(table5: &str) -> Option<&str> {
    let (_, rest) = table5.lines().next()?.split_once("at commit `")?;
    rest.split_once('`').map(|(c, _)| c)
}

/// Refuses a block whose figures come from code with uncommitted changes (`commit` ends in
/// `+dirty`): nobody could rebuild what produced them. `allow_dirty` writes it anyway (the
/// block then names the `+dirty` commit).
fn refuse_dirty(what: &str, commit: &str, allow_dirty: bool) -> Result<(), String> {
    if commit.ends_with("+dirty") && !allow_dirty {
        return Err(format!(
            "{what} has uncommitted changes ({commit}): commit them and rebuild first, or pass \
             --allow-dirty to write a block marked +dirty"
        ));
    }
    Ok(())
}

/// Replaces block `name` of the results file with `body`.
fn write_block(paths: &Paths, name: &str, body: &str) -> Result<(), String> {
    write_block_in(paths, FILE, name, body)
}

/// [`write_block`] into the file `file` (relative to the workspace root).
fn write_block_in(paths: &Paths, file: &str, name: &str, body: &str) -> Result<(), String> {
    let path = paths.root.join(file);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound && file == FILE => SKELETON.to_string(),
        Err(e) => return Err(format!("{}: {e}", path.display())),
    };
    let updated = replace_block(&text, name, &block(name, &command_line(), body))?;
    std::fs::write(&path, updated).map_err(|e| format!("{}: {e}", path.display()))?;
    eprintln!("xtask: wrote the `{name}` block of {}", path.display());
    Ok(())
}

/// The trained model the firmware embeds: what the `tables` block measures besides the
/// example models.
const TRAINED_BLOB: &str = "nemm-firmware/data/trained-nemm.nemm";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sweep_table_names_its_commit() {
        let t5 = "Sweep of the NEMM trained at commit `0b984fd+dirty` on `d`: ...\n\n| Job |\n";
        assert_eq!(super::sweep_commit(t5), Some("0b984fd+dirty"));
        assert_eq!(super::sweep_commit("| Job |\n"), None);
    }

    #[test]
    fn figures_from_uncommitted_code_are_refused_unless_allowed() {
        let e = super::refuse_dirty("the work tree", "abc1234+dirty", false).unwrap_err();
        assert!(
            e.contains("abc1234+dirty") && e.contains("--allow-dirty"),
            "{e}"
        );
        assert!(super::refuse_dirty("the work tree", "abc1234+dirty", true).is_ok());
        assert!(super::refuse_dirty("the work tree", "abc1234", false).is_ok());
    }

    #[test]
    fn replaces_only_its_block() {
        let text = "intro\n<!-- BEGIN targets -->\nx\n<!-- END targets -->\n\
                    <!-- BEGIN target (generated by cargo xtask results) -->\nold\n\
                    <!-- END target -->\noutro\n";
        let new = block("target", "cargo xtask results", "new figures\n");
        let out = replace_block(text, "target", &new).unwrap();
        assert_eq!(
            out,
            "intro\n<!-- BEGIN targets -->\nx\n<!-- END targets -->\n\
             <!-- BEGIN target (generated by cargo xtask results) -->\nnew figures\n\
             <!-- END target -->\noutro\n"
        );
        // Idempotent, and the skeleton's bare markers are found too.
        assert_eq!(replace_block(&out, "target", &new).unwrap(), out);
        let filled = replace_block(SKELETON, "training", &block("training", "c", "t4")).unwrap();
        assert!(filled
            .contains("<!-- BEGIN training (generated by c) -->\nt4\n<!-- END training -->\n"));
        assert!(filled.contains("Not generated yet: run `cargo xtask results`."));
        let filled =
            replace_block(SKELETON, "state-priors", &block("state-priors", "c", "sp")).unwrap();
        assert!(filled.contains(
            "## Priors in the state\n\n<!-- BEGIN state-priors (generated by c) -->\nsp\n\
             <!-- END state-priors -->\n\n## Hyperparameter search"
        ));
        // A missing block is appended; a block without its end is an error.
        assert_eq!(
            replace_block("# R", "training", "B\n").unwrap(),
            "# R\n\nB\n"
        );
        assert!(replace_block("<!-- BEGIN target -->\n", "target", "B").is_err());
    }
}
