//! The `c` block (`cargo xtask results --c`): the C interface's figures on the emulated
//! Cortex-M4F, from the C example as `cargo xtask c-test` runs it
//! ([`crate::c_interface::target_example`]): instructions per step of the estimator and the
//! alpha observer, the stack peak, the image's sections.

use super::{command_line, commit, refuse_dirty, write_block, TRAINED_BLOB};
use crate::c_interface::{self, ExampleFigures};
use crate::firmware::{self, Board};
use crate::toolchain::Toolchain;
use crate::{Mode, Paths};
use std::fmt::Write as _;

/// `cargo xtask results --c`: builds the firmware's mps2-an386 image, runs the C example
/// against it (both runs of `cargo xtask c-test`, compared with the firmware bit for bit)
/// and writes the `c` block.
pub fn c_example(tc: &Toolchain, paths: &Paths, allow_dirty: bool) -> Result<(), String> {
    let commit = commit(&paths.root);
    refuse_dirty("the work tree", &commit, allow_dirty)?;
    let images = firmware::build(tc, paths, Board::An386)?;
    let figures = c_interface::target_example(tc, paths, &images)?;
    let trained = std::fs::read(paths.root.join(TRAINED_BLOB)).ok();
    let provenance = format!("`{}` at commit `{commit}`", command_line());
    let md = c_markdown(
        &provenance,
        trained.as_deref() == Some(&figures.blob[..]),
        &figures,
    )?;
    write_block(paths, "c", &md)
}

/// The value of `key=` in `line` (a `c-example` line).
fn value<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    c_interface::field(line, "c-example ", key)
}

/// The decimal number `key=` of `line`.
fn number(line: &str, key: &str) -> Option<u64> {
    value(line, key)?.parse().ok()
}

/// The number `key=` of `line` as a table cell: `-` if the line lacks it.
fn cell(line: &str, key: &str) -> String {
    number(line, key).map_or("-".into(), |n| n.to_string())
}

/// An observer's final estimate from `line` (`observer_alpha_e4`, `observer_band_e4`,
/// `observer_flags`): `0.1500 +- 0.0120, flags 0x00`, or `-`.
fn estimate(line: &str) -> String {
    let e4 = |key: &str| number(line, key).map(|n| n as f64 / 1e4);
    match (
        e4("observer_alpha_e4"),
        e4("observer_band_e4"),
        value(line, "observer_flags"),
    ) {
        (Some(a), Some(b), Some(f)) => format!("{a:.4} +- {b:.4}, flags 0x{f}"),
        _ => "-".into(),
    }
}

/// The `c` block: provenance, the blob, the runs, then one row per figure.
/// `provenance`: the command and the commit, as markdown; `trained`: whether the blob is
/// [`TRAINED_BLOB`].
fn c_markdown(provenance: &str, trained: bool, f: &ExampleFigures) -> Result<String, String> {
    let (exact, table) = (f.run(Mode::Exact)?, f.run(Mode::Table)?);
    for r in [exact, table] {
        if number(&r.summary, "step_instructions").is_none() {
            return Err(format!(
                "the C example's {}-mode run printed no instructions per step: `{}`",
                r.mode.name(),
                r.summary
            ));
        }
    }
    let blob = if trained {
        format!("`{TRAINED_BLOB}`, the firmware's trained NEMM")
    } else {
        format!("the firmware's weights, not `{TRAINED_BLOB}` (built with `NEMM_WEIGHTS`?)")
    };
    let alpha = value(&exact.boot, "alpha")
        .and_then(|a| u32::from_str_radix(a.trim_start_matches("0x"), 16).ok())
        .map_or("-".into(), |bits| format!("{}", f32::from_bits(bits)));
    let levels = if number(&exact.levels, "status") == Some(0) {
        format!(
            "{} levels of tables ({} B of the blob)",
            cell(&exact.levels, "levels"),
            cell(&exact.levels, "table_bytes")
        )
    } else {
        format!(
            "no level tables (`nemm_levels_init` status {})",
            cell(&exact.levels, "status")
        )
    };
    let tables = match value(&table.boot, "tables") {
        Some("stored") => "the table-mode run's estimator read its tables at that alpha from the \
                           blob"
            .to_string(),
        Some("built") => "the table-mode run's estimator built its tables at init (the blob \
                          stores none at that alpha)"
            .to_string(),
        other => format!("the table-mode run's tables: `{}`", other.unwrap_or("-")),
    };
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Measured by {provenance}: the C example (`examples/c/replay.c`, built with \
         `arm-none-eabi-gcc -O2` against nemm-c's Cortex-M4F library as `cargo xtask c-test` \
         builds it) in QEMU `mps2-an386` (Cortex-M4F), `-icount shift=0`: instructions, not \
         cycles (the SysTick ticks of each call times the board's \
         `BOARD_INSTRUCTIONS_PER_TICK`, averaged over the run's samples); \
         the firmware's cycle model turns instructions into time ([target \
         block](#on-the-target-cortex-m4f-and-cortex-m7-emulated)). Blob: {blob}, taken from \
         the weights slot of the firmware's `mps2-an386` image: {} B, format version {}, \
         {levels}, at alpha {alpha}; {tables}. Inputs: the velocities the Rust firmware handed \
         its estimator over its recorded trace, with the trace's stroke and measured force; {} \
         samples in the exact-mode run, {} in the table-mode run, whose forces and flags equal \
         the firmware's bit for bit. Sections: the exact-mode run's image.\n",
        f.blob.len(),
        cell(&exact.boot, "format_version"),
        exact.samples,
        table.samples,
    );
    md += "| figure | value | what |\n|---|---:|---|\n";
    let exact_run = format!("exact-mode run ({} samples)", exact.samples);
    let table_run = format!("table-mode run ({} samples)", table.samples);
    let on_levels = |key: &str| number(&exact.levels, key);
    let both = match (
        on_levels("observer_step_instructions"),
        on_levels("step_instructions"),
    ) {
        (Some(o), Some(e)) => (o + e).to_string(),
        _ => "-".into(),
    };
    let stack = [exact, table]
        .iter()
        .filter_map(|r| number(&r.summary, "stack_used"))
        .max()
        .map_or("-".into(), |n| n.to_string());
    let (objects, objects_what) = match (
        number(&exact.boot, "estimator_bytes"),
        number(&exact.levels, "levels_bytes"),
        number(&exact.boot, "observer_bytes"),
    ) {
        (Some(e), Some(l), Some(o)) => (
            (e + l + o).to_string(),
            format!(
                "`sizeof` of a `nemm_estimator_t` ({e}), a `nemm_levels_t` ({l}) and a \
                 `nemm_observer_t` ({o}): the statics of the 10 kHz pattern with the observer \
                 on level tables"
            ),
        ),
        _ => (
            "-".into(),
            "`sizeof` of a `nemm_estimator_t`, a `nemm_levels_t` and a `nemm_observer_t`".into(),
        ),
    };
    let m = &exact.memory;
    let rodata = u64::from(m.size_of(".rodata"));
    let blob_bytes = f.blob.len() as u64;
    let other = rodata.saturating_sub(blob_bytes + exact.inputs_bytes);
    let rows: [(&str, String, String); 15] = [
        (
            "estimator step, exact mode (instructions)",
            cell(&exact.summary, "step_instructions"),
            format!("`nemm_estimator_step` in exact mode, {exact_run}"),
        ),
        (
            "estimator step, table mode (instructions)",
            cell(&table.summary, "step_instructions"),
            format!(
                "`nemm_estimator_step` in table mode (the blob's tables at alpha), {table_run}"
            ),
        ),
        (
            "exact observer step (instructions)",
            cell(&exact.summary, "observer_step_instructions"),
            format!(
                "`nemm_observer_step` of the observer of `nemm_observer_init` (default \
                 configuration: each of its levels an exact step), {exact_run}"
            ),
        ),
        (
            "observer step on level tables (instructions)",
            cell(&exact.levels, "observer_step_instructions"),
            format!(
                "`nemm_observer_step` of the observer of `nemm_observer_init_on_levels` (each \
                 stored level a table-mode step), {exact_run}"
            ),
        ),
        (
            "estimator step on level tables (instructions)",
            cell(&exact.levels, "step_instructions"),
            format!(
                "`nemm_estimator_step` with `NEMM_SAMPLE_ALPHA` on the attached level tables, \
                 the level ramping across the stored levels (another level every sample), a \
                 second pass over the velocities of the {exact_run}"
            ),
        ),
        (
            "observer and estimator on level tables (instructions per sample)",
            both,
            "the two rows above together: the 10 kHz pattern of \
             [c-interface.md](c-interface.md#level-tables-every-level-at-table-cost)"
                .into(),
        ),
        (
            "exact observer, final estimate",
            estimate(&exact.summary),
            format!("alpha, band and `NEMM_OBSERVER_*` flags after the last sample, {exact_run}"),
        ),
        (
            "observer on level tables, final estimate",
            estimate(&exact.levels),
            format!("the same for the observer on level tables, {exact_run}"),
        ),
        (
            "stack peak (B)",
            stack,
            "the painted stack's deepest point over a whole run (inits and steps; the objects \
             are statics), the deeper of the two runs"
                .into(),
        ),
        ("objects (B)", objects, objects_what),
        (
            "`.text` (B)",
            m.size_of(".text").to_string(),
            "code: the example, its board support and what it links of nemm-c's library".into(),
        ),
        (
            "`.rodata` (B)",
            rodata.to_string(),
            "constants: the blob, the recorded inputs and the rest (the next three rows)".into(),
        ),
        (
            "of which the blob (B)",
            blob_bytes.to_string(),
            "the weights blob, in flash (the level tables read its tables in place)".into(),
        ),
        (
            "of which the recorded inputs (B)",
            exact.inputs_bytes.to_string(),
            "the example's inputs (12 B per sample), not part of an application".into(),
        ),
        (
            "of which other constants (B)",
            other.to_string(),
            "the library's and the example's own constants (with the blob's alignment padding)"
                .into(),
        ),
    ];
    for (figure, value, what) in rows {
        let _ = writeln!(md, "| {figure} | {value} | {what} |");
    }
    let _ = writeln!(
        md,
        "| `.bss` (B) | {} | statics: the estimator, the level tables, two observers (exact \
         and on level tables) and the output line |",
        m.size_of(".bss")
    );
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::c_interface::ExampleRun;

    fn run(mode: Mode, samples: usize, summary: &str, levels: &str) -> ExampleRun {
        ExampleRun {
            mode,
            samples,
            boot: format!(
                "c-example boot estimator_bytes=46156 observer_bytes=22688 format_version=6 \
                 kind=3 mode={} tables=stored alpha=0x3e19999a needs_position=0 samples={samples}",
                mode.name()
            ),
            summary: summary.into(),
            levels: levels.into(),
            memory: nemm_elf::MemoryUse {
                flash: 0,
                ram: 0,
                sections: vec![
                    (".text".into(), 0, 272_608),
                    (".rodata".into(), 0, 300_000),
                    (".bss".into(), 0x2000_0000, 110_000),
                ],
            },
            inputs_bytes: 16 + 12 * samples as u64,
        }
    }

    fn figures() -> ExampleFigures {
        let levels = |o: u32, s: u32| {
            format!(
                "c-example levels status=0 levels=7 levels_bytes=17892 table_bytes=50624 \
                 observer_alpha_e4=1502 observer_band_e4=120 observer_flags=00 \
                 observer_step_instructions={o} step_instructions={s}"
            )
        };
        ExampleFigures {
            blob: vec![0; 66_000],
            runs: vec![
                run(
                    Mode::Exact,
                    10_493,
                    "c-example summary steps=10493 held=0 resets=0 observer_alpha_e4=1500 \
                     observer_band_e4=118 observer_flags=00 step_instructions=18523 \
                     observer_step_instructions=139989 stack_used=8268",
                    &levels(4540, 1497),
                ),
                run(
                    Mode::Table,
                    3000,
                    "c-example summary steps=3000 held=0 resets=0 observer_alpha_e4=1400 \
                     observer_band_e4=300 observer_flags=02 step_instructions=559 \
                     observer_step_instructions=139000 stack_used=8200",
                    &levels(4500, 1490),
                ),
            ],
        }
    }

    #[test]
    fn the_c_block_reads_each_figure_from_its_run() {
        let md = c_markdown(
            "`cargo xtask results --c` at commit `abc1234`",
            true,
            &figures(),
        )
        .unwrap();
        assert!(md.starts_with("Measured by `cargo xtask results --c` at commit `abc1234`"));
        assert!(md.contains("Blob: `nemm-firmware/data/trained-nemm.nemm`, the firmware's"));
        assert!(md.contains("66000 B, format version 6, 7 levels of tables (50624 B of the blob), at alpha 0.15; the table-mode run's estimator read its tables at that alpha from the blob."), "{md}");
        assert!(md.contains("10493 samples in the exact-mode run, 3000 in the table-mode run"));
        let row = |figure: &str, value: &str| {
            let r = format!("| {figure} | {value} |");
            assert!(md.contains(&r), "no row {r} in\n{md}");
        };
        row("estimator step, exact mode (instructions)", "18523");
        row("estimator step, table mode (instructions)", "559");
        row("exact observer step (instructions)", "139989");
        row("observer step on level tables (instructions)", "4540");
        row("estimator step on level tables (instructions)", "1497");
        row(
            "observer and estimator on level tables (instructions per sample)",
            "6037",
        );
        row(
            "exact observer, final estimate",
            "0.1500 +- 0.0118, flags 0x00",
        );
        row(
            "observer on level tables, final estimate",
            "0.1502 +- 0.0120, flags 0x00",
        );
        row("stack peak (B)", "8268");
        row("objects (B)", "86736");
        row("`.text` (B)", "272608");
        row("`.rodata` (B)", "300000");
        row("of which the blob (B)", "66000");
        row("of which the recorded inputs (B)", "125932");
        // 300,000 - 66,000 - 125,932.
        row("of which other constants (B)", "108068");
        row("`.bss` (B)", "110000");
        // Every row has its three cells.
        for l in md.lines().filter(|l| l.starts_with("| ")) {
            assert_eq!(l.matches(" | ").count(), 2, "{l}");
        }
    }

    #[test]
    fn the_c_block_says_when_the_blob_is_not_the_trained_one_or_has_no_levels() {
        let mut f = figures();
        for r in &mut f.runs {
            r.levels =
                "c-example levels status=72 levels=0 levels_bytes=17892 table_bytes=0".into();
            r.boot = "c-example boot format_version=6".into();
        }
        let md = c_markdown("`x`", false, &f).unwrap();
        assert!(md.contains("not `nemm-firmware/data/trained-nemm.nemm`"));
        assert!(md.contains("no level tables (`nemm_levels_init` status 72)"));
        assert!(md.contains("; the table-mode run's tables: `-`."), "{md}");
        assert!(md.contains("| objects (B) | - |"));
        assert!(md.contains("| observer step on level tables (instructions) | - |"));
        assert!(md.contains("| observer on level tables, final estimate | - |"));
        f.runs[1].summary = String::new();
        assert!(c_markdown("`x`", true, &f)
            .unwrap_err()
            .contains("table-mode run"));
        f.runs.pop();
        assert!(c_markdown("`x`", true, &f).is_err());
    }
}
