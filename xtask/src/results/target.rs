//! The `target` block (`cargo xtask results`): instructions per estimator and observer step
//! in QEMU, the estimated cycles per chip and which combinations fit 10 kHz (also the
//! README's `fit` block), the boot time, flash and RAM of each image, the application's stack.

use super::{command_line, commit, refuse_dirty, write_block, write_block_in, README};
use crate::cycles::CycleFigures;
use crate::firmware;
use crate::target_bench::{self, ObserverFigures, StepFigures};
use crate::toolchain::Toolchain;
use crate::BootFigures;
use crate::{Kind, Mode, Paths, Variant};
use nemm_elf::Elf;
use std::fmt::Write as _;

/// What `cargo xtask results` measures on the target.
pub struct TargetFigures<'a> {
    /// Measured steps per benchmark run.
    pub steps: u32,
    /// Instructions per step on the mps2-an386, exact mode.
    pub exact: &'a [StepFigures],
    /// The same in table mode.
    pub table: &'a [StepFigures],
    /// The alpha observer's step on the mps2-an386.
    pub observer: Option<&'a ObserverFigures>,
    /// Estimated cycles per chip, model kind, integrator and mode.
    pub cycles: &'a [CycleFigures],
    /// Flash and RAM per image.
    pub memory: &'a [(String, nemm_elf::MemoryUse)],
    /// Stack and boot figures per board and mode.
    pub boot: &'a [(firmware::StackFigures, BootFigures)],
}

/// The markdown of the target figures.
/// `provenance`: the command and the commit, as markdown.
fn target_markdown(provenance: &str, f: &TargetFigures) -> String {
    let (steps, exact, table) = (f.steps, f.exact, f.table);
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Measured by {provenance}, QEMU `mps2-an386` (Cortex-M4F) and `mps2-an500` \
         (Cortex-M7), `-icount shift=0`: instructions, not cycles; cycles are estimated by \
         the cycle model of `nemm-firmware/README.md` (\"Cycle model\").\n"
    );
    let _ = writeln!(
        md,
        "**Instructions per estimator step** (`mps2-an386`): {steps} steps of the bench trace \
         after 200 warm-up steps, weights slot = `nemm-firmware/data/example-<kind>.nemm` \
         (`cargo xtask bench-target --mode exact|table`); `<kind>+lm`: the same model with \
         the example lost-motion element (`nemm_core::testing::EXAMPLE_LOST_MOTION`, the \
         benchmark's `lost-motion=1`; `--model <kind>+lm`). Table mode: its RAM, the worst \
         relative error of the tables against the exact scalers (parts per billion), the \
         kinks placed, and the instructions that build the estimator at boot.\n"
    );
    md += "| model | integrator | exact | table | table RAM (B) | table error (ppb) | kinks | \
           table build (instructions) |\n";
    md += "|---|---|---:|---:|---:|---:|---:|---:|\n";
    for e in exact {
        let t = table
            .iter()
            .find(|t| t.model == e.model && t.integrator == e.integrator);
        let field = |k: &str| t.and_then(|t| t.table_field(k)).unwrap_or("-").to_string();
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} |",
            e.model,
            e.integrator,
            e.instructions_per_step,
            t.map_or("-".into(), |t| t.instructions_per_step.to_string()),
            field("table_bytes"),
            field("max_rel_error_ppb"),
            field("kinks"),
            field("build_instructions"),
        );
    }
    if let Some(o) = f.observer {
        let _ = writeln!(
            md,
            "\n**Alpha observer** (the bench-controller mode, `observer=on`; `cargo xtask \
             bench-target`, `target-observer` line): one step of the firmware's observer \
             (`nemm_firmware::FwObserver`) with the benchmark's built-in weights (the \
             firmware's trained NEMM, whose blob stores 7 levels of tables), {steps} steps \
             after 200 warm-up steps, the model's own force at the trace's alpha as the \
             measurement; levels from `blob`: each level steps on its stored tables, `exact`: \
             on the scalers. Beside it, one step of the estimator with a level per sample on \
             the same level tables (attached: `Estimator::attach_levels`, then `Estimator::step` \
             with the sample's `alpha`, the level changing every sample). Its rows in the fit table below are `{}`.\n\n\
             | model | integrator | levels | levels from | model steps per sample | instructions per step \
             | over one exact step | RAM (B) | estimator with a level per sample (instructions) \
             |\n|---|---|---:|---|---:|---:|---:|---:|---:|",
            crate::cycles::observer_row_name(o)
        );
        let one = exact
            .iter()
            .find(|e| e.model == o.model && e.integrator == o.integrator)
            .map_or("-".to_string(), |e| {
                format!(
                    "{:.1}",
                    o.instructions_per_step as f64 / e.instructions_per_step.max(1) as f64
                )
            });
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {one} | {} | {} |",
            o.model,
            o.integrator,
            o.levels,
            o.levels_from,
            o.model_steps,
            o.instructions_per_step,
            o.bytes,
            o.level_step_instructions
                .map_or("-".to_string(), |n| n.to_string())
        );
    }
    md += &fit_markdown(f.cycles, true);
    md += "\n**Boot time**: instructions from reset to the estimator ready (the application \
           with the built-in NEMM blob, QEMU's count from the reset vector to the `start` \
           line; the first step follows one 100 us period later), and the time at the chip's \
           clocks at the cycles per instruction of the exact NEMM RK4 step (the network \
           kernels, which build the tables in table mode; the exact-mode boot is mostly \
           integer code, which this overestimates). Tables: `stored` when the blob's stored \
           tables were read (the embedded model is exported with `--tables-alpha` at the \
           firmware's alpha), `built` when they were built at boot.\n\n";
    let _ = writeln!(
        md,
        "| board | mode | tables | instructions | cycles per instruction | {} |\n\
         |---|---|---|---:|---:|{}",
        clock_headers("ms at "),
        "---:|".repeat(CLOCK_COLUMNS.len())
    );
    for (s, b) in f.boot {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {:.2} | {} |",
            b.board.machine(),
            b.mode,
            s.tables(),
            b.instructions,
            b.cycles_per_instruction,
            clock_cells(crate::cycles::Chip::of(b.board), |mhz| format!(
                "{:.1}",
                b.ms_at(mhz)
            ))
        );
    }
    md += "\n**Flash and RAM** of the images (`cargo xtask build-target`; RAM: the statics, the \
           stack takes the rest).\n\n";
    md += "| image | flash (B) | code | rodata | trace | weights slot | data | RAM (B) | bss | \
           uninit |\n";
    md += "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for (name, m) in f.memory {
        let _ = writeln!(
            md,
            "| {name} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            m.flash,
            m.size_of(".vector_table") + m.size_of(".text"),
            m.size_of(".rodata"),
            m.size_of(".nemm_trace"),
            m.size_of(".nemm_weights"),
            m.size_of(".data"),
            m.ram,
            m.size_of(".bss"),
            m.size_of(".uninit"),
        );
    }
    md += "\n**Stack** of the application (qemu build, the built-in NEMM blob, 2000 samples; \
           painted stack): at the end of the boot, and the peak of the whole run.\n\n";
    md += "| board | mode | boot stack (B) | stack peak (B) | room the layout leaves (B) |\n\
           |---|---|---:|---:|---:|\n";
    for (s, b) in f.boot {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} |",
            b.board.machine(),
            b.mode,
            s.boot,
            s.peak,
            s.room
        );
    }
    md
}

/// The 10 kHz fit table: per chip, model kind, integrator and mode, the instructions and
/// estimated cycles per step and the fraction of the 100 us period at each stated clock;
/// `intro` adds its explanation.
fn fit_markdown(cycles: &[CycleFigures], intro: bool) -> String {
    let mut md = String::new();
    if intro {
        md += "\n**Does it fit 10 kHz?** Estimated cycles per step (`cargo xtask \
               bench-target`: instructions per step measured in QEMU on each core, times the \
               cycles per instruction of the traced step's instruction mix under the chip's \
               cycle model; M4F about +-15 %, M7 about +-30 %) and the fraction of the 100 us \
               period at each clock (STM32F407 168 MHz; STM32F7 216 MHz, STM32H7 480 MHz). \
               **yes**: under 1; the rest of the period is left to the sensor read, the \
               publication and the other tasks, and a fraction within the model's \
               uncertainty of 1 is a fit to be measured on the chip, not counted on.\n\n";
    }
    let _ = writeln!(
        md,
        "| chip | model | integrator | mode | instructions | est. cycles | cycles per \
         instruction | {} |\n|---|---|---|---|---:|---:|---:|{}",
        clock_headers(""),
        "---:|".repeat(CLOCK_COLUMNS.len())
    );
    for c in cycles {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {:.2} | {} |",
            c.chip.name(),
            c.model,
            c.integrator,
            c.mode,
            c.instructions_per_step,
            c.cycles_per_step(),
            c.cycles_per_instruction,
            clock_cells(c.chip, |mhz| {
                let f = c.budget_fraction(mhz);
                format!("{f:.2} {}", if f < 1.0 { "**yes**" } else { "no" })
            })
        );
    }
    md
}

/// The clock columns of the tables \[MHz\]: every chip's stated clocks.
const CLOCK_COLUMNS: [u32; 3] = [168, 216, 480];

/// The headers of the clock columns: `<prefix><f> MHz`, joined as table cells.
fn clock_headers(prefix: &str) -> String {
    CLOCK_COLUMNS
        .iter()
        .map(|mhz| format!("{prefix}{mhz} MHz"))
        .collect::<Vec<_>>()
        .join(" | ")
}

/// One cell per clock column, joined: `cell(f)` where `chip` is stated at `f`, `-` elsewhere.
fn clock_cells(chip: crate::cycles::Chip, cell: impl Fn(u32) -> String) -> String {
    CLOCK_COLUMNS
        .iter()
        .map(|&mhz| {
            if chip.clocks_mhz().contains(&mhz) {
                cell(mhz)
            } else {
                "-".into()
            }
        })
        .collect::<Vec<_>>()
        .join(" | ")
}

/// The README's `fit` block: the NEMM's rows of the fit table and where the rest is.
fn fit_readme_markdown(provenance: &str, cycles: &[CycleFigures]) -> String {
    let nemm: Vec<CycleFigures> = cycles
        .iter()
        .filter(|c| c.model == "nemm")
        .cloned()
        .collect();
    format!(
        "The NEMM (H = 16, L = 5) against the 10 kHz budget by the cycle model (estimated \
         cycles per step and the fraction of the 100 us period; **yes** fits), measured by \
         {provenance}; every model kind, the boot time and the model itself: \
         [docs/results.md](docs/results.md), \
         [nemm-firmware/README.md](nemm-firmware/README.md#cycle-model).\n\n{}",
        fit_markdown(&nemm, false)
    )
}

/// The models of the target figures: every kind, each EMM-family kind followed by itself
/// with the example lost-motion element (`<kind>+lm`).
fn target_models() -> Vec<Variant> {
    Kind::ALL
        .into_iter()
        .flat_map(|k| {
            let lm = (k != Kind::Sem).then_some(Variant::with_lost_motion(k));
            std::iter::once(Variant::plain(k)).chain(lm)
        })
        .collect()
}

/// `cargo xtask results`: builds the firmware, measures it and writes the `target` block
/// (and the README's `fit` block).
pub fn target(tc: &Toolchain, paths: &Paths, steps: u32, allow_dirty: bool) -> Result<(), String> {
    let commit = commit(&paths.root);
    refuse_dirty("the work tree", &commit, allow_dirty)?;
    let images = firmware::build_all(tc, paths, &firmware::Board::ALL)?;
    let mut exact = Vec::new();
    let mut table = Vec::new();
    let mut cycles = Vec::new();
    let mut memory = Vec::new();
    let mut boot = Vec::new();
    let mut observer = None;
    for im in &images {
        let models = target_models();
        let e = target_bench::run(tc, paths, im, Mode::Exact, steps, &models)?;
        let t = target_bench::run(tc, paths, im, Mode::Table, steps, &models)?;
        let o = target_bench::observer(tc, im, steps)?;
        for f in e.iter().chain(&t) {
            println!("{} board={}", f.line(), im.board.machine());
        }
        println!("{} board={}", o.line(), im.board.machine());
        for (mode, figs) in [(Mode::Exact, &e), (Mode::Table, &t)] {
            for c in crate::cycles::estimate(tc, paths, im, mode, figs)? {
                println!("{}", c.line());
                cycles.push(c);
            }
        }
        let c = crate::cycles::estimate_observer(tc, paths, im, &o)?;
        println!("{}", c.line());
        cycles.push(c);
        if im.board == firmware::Board::An386 {
            (exact, table) = (e, t);
            observer = Some(o);
        }
        for (name, path) in im.named() {
            let elf = Elf::read(path)?;
            println!("{}", firmware::memory_report(&name, &elf));
            memory.push((name, elf.memory_use()));
        }
        for (s, b) in crate::boot_figures(tc, paths, im)? {
            println!("{} board={}", s.line(b.mode), im.board.machine());
            println!("{}", b.line());
            boot.push((s, b));
        }
    }
    // Chip by chip, then model (the observer's rows last), integrator, mode.
    let models = target_models();
    cycles.sort_by_key(|c| {
        let kind = models
            .iter()
            .position(|m| m.name() == c.model)
            .unwrap_or(models.len());
        (
            c.chip.name() != "m4f",
            kind,
            c.integrator != "rk4",
            c.mode.clone(),
        )
    });
    let provenance = format!("`{}` at commit `{commit}`", command_line());
    let md = target_markdown(
        &provenance,
        &TargetFigures {
            steps,
            exact: &exact,
            table: &table,
            observer: observer.as_ref(),
            cycles: &cycles,
            memory: &memory,
            boot: &boot,
        },
    );
    write_block(paths, "target", &md)?;
    write_block_in(
        paths,
        README,
        "fit",
        &fit_readme_markdown(&provenance, &cycles),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_target_figures_pair_each_emm_with_its_lost_motion_variant() {
        let names: Vec<String> = target_models().into_iter().map(Variant::name).collect();
        assert_eq!(
            names,
            [
                "sem",
                "linear-emm",
                "linear-emm+lm",
                "nemm-light",
                "nemm-light+lm",
                "nemm",
                "nemm+lm"
            ]
        );
    }

    #[test]
    fn the_target_block_pairs_exact_and_table_figures() {
        let fig = |mode: &str, n: u64, table: Vec<(&'static str, String)>| StepFigures {
            model: "nemm".into(),
            integrator: "rk4".into(),
            mode: mode.into(),
            instructions_per_step: n,
            table,
        };
        let t = vec![
            ("segments", "128".into()),
            ("table_bytes", "7168".into()),
            ("max_rel_error_ppb", "2792".into()),
            ("kinks", "73".into()),
            ("build_instructions", "156316320".into()),
        ];
        let memory = nemm_elf::MemoryUse {
            flash: 300,
            ram: 40,
            sections: vec![
                (".vector_table".into(), 0, 8),
                (".text".into(), 8, 100),
                (".bss".into(), 0x2000_0000, 40),
            ],
        };
        let cycles = [crate::cycles::CycleFigures {
            chip: crate::cycles::Chip::M7,
            board: firmware::Board::An500,
            model: "nemm".into(),
            integrator: "rk4".into(),
            mode: "exact".into(),
            instructions_per_step: 15541,
            cycles_per_instruction: 2.0,
            fp_mac_per_step: 9728.0,
        }];
        let stack = firmware::StackFigures {
            boot: 1200,
            peak: 1864,
            room: 140000,
            boot_instructions: 480_000,
            tables_stored: None,
        };
        let boot = BootFigures {
            board: firmware::Board::An386,
            mode: "exact",
            instructions: 480_000,
            cycles_per_instruction: 3.5,
        };
        let md = target_markdown(
            "`cargo xtask results` at commit `abc1234+dirty`",
            &TargetFigures {
                steps: 4000,
                exact: &[fig("exact", 15541, vec![])],
                table: &[fig("table", 492, t)],
                observer: Some(&ObserverFigures {
                    model: "nemm".into(),
                    integrator: "rk4".into(),
                    levels: 7,
                    levels_from: "blob".into(),
                    model_steps: 7,
                    bytes: 21572,
                    instructions_per_step: 116_558,
                    max_step: (118_000, Some(121_000)),
                    level_step_instructions: Some(1514),
                }),
                cycles: &cycles,
                memory: &[("board build".into(), memory)],
                boot: &[(stack, boot)],
            },
        );
        assert!(md.starts_with("Measured by `cargo xtask results` at commit `abc1234+dirty`"));
        assert!(md.contains("| nemm | rk4 | 15541 | 492 | 7168 | 2792 | 73 | 156316320 |\n"));
        // 116,558 instructions: 7.5 exact steps.
        assert!(
            md.contains("| nemm | rk4 | 7 | blob | 7 | 116558 | 7.5 | 21572 | 1514 |\n"),
            "{md}"
        );
        assert!(md.contains("rows in the fit table below are `nemm-observer`"));
        assert!(md.contains("| board build | 300 | 108 | 0 | 0 | 0 | 0 | 40 | 40 | 0 |\n"));
        assert!(md.contains("| mps2-an386 | exact | 1200 | 1864 | 140000 |\n"));
        // 31,082 cycles: 0.65 of the period at 480 MHz, 1.44 at 216 MHz.
        assert!(md.contains(
            "| m7 | nemm | rk4 | exact | 15541 | 31082 | 2.00 | - | 1.44 no | 0.65 **yes** |\n"
        ));
        // 480,000 x 3.5 cycles at 168 MHz: 10.0 ms.
        assert!(md.contains("| mps2-an386 | exact | none | 480000 | 3.50 | 10.0 | - | - |\n"));
        let readme = fit_readme_markdown("`cargo xtask results`", &cycles);
        assert!(readme.contains("| m7 | nemm | rk4 | exact | 15541 | 31082 |"));
    }
}
