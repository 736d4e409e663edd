//! The step benchmark (`nemm-bench`) in QEMU: instructions per estimator step, per model
//! kind and integrator; and per step of the firmware's alpha observer (the bench-controller
//! mode), on the example NEMM.

use crate::firmware::{self, Images};
use crate::toolchain::Toolchain;
use crate::{Kind, Mode, Paths, Variant};
use nemm_elf::Elf;
use std::path::PathBuf;

use crate::firmware::INSTRUCTIONS_PER_TICK;

/// The fields of a `table` line that a `target-step` line of mode `table` carries, in order.
const TABLE_FIELDS: [&str; 4] = ["segments", "table_bytes", "max_rel_error_ppb", "kinks"];

/// The figures of one model kind and integrator.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepFigures {
    /// Model kind (`kind=` of the benchmark), `+lm` with the lost-motion element
    /// ([`Variant::name`]).
    pub model: String,
    /// `rk4` or `rk3`.
    pub integrator: String,
    /// `exact` or `table`.
    pub mode: String,
    /// Instructions per estimator step.
    pub instructions_per_step: u64,
    /// Table mode: [`TABLE_FIELDS`] as printed, then `build_instructions` (building the
    /// estimator, tables and their check, at boot).
    pub table: Vec<(&'static str, String)>,
}

impl StepFigures {
    /// The `target-step` line: `target-step model=<kind> integrator=<rk4|rk3> mode=<mode>
    /// instructions_per_step=<N>`, plus the table fields in table mode.
    pub fn line(&self) -> String {
        let mut l = format!(
            "target-step model={} integrator={} mode={} instructions_per_step={}",
            self.model, self.integrator, self.mode, self.instructions_per_step
        );
        for (k, v) in &self.table {
            l += &format!(" {k}={v}");
        }
        l
    }

    /// A table field by name.
    pub fn table_field(&self, key: &str) -> Option<&str> {
        self.table
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v.as_str())
    }
}

/// `key=value` words of a line.
fn fields(line: &str) -> Vec<(&str, &str)> {
    line.split_ascii_whitespace()
        .filter_map(|w| w.split_once('='))
        .collect()
}

/// The figures of one run's output.
fn parse(out: &str, variant: Variant) -> Result<Vec<StepFigures>, String> {
    let get = |f: &[(&str, &str)], k: &str| -> Result<String, String> {
        f.iter()
            .find(|(key, _)| *key == k)
            .map(|(_, v)| v.to_string())
            .ok_or_else(|| format!("no `{k}` in the benchmark output:\n{out}"))
    };
    let num = |f: &[(&str, &str)], k: &str| -> Result<u64, String> {
        get(f, k)?
            .parse()
            .map_err(|e| format!("`{k}` in the benchmark output: {e}"))
    };
    if let Some(cal) = out.lines().find(|l| l.starts_with("calibration")) {
        // 2 instructions per iteration of the integer loop.
        let f = fields(cal);
        let expected = 2 * num(&f, "iterations")?;
        let measured = num(&f, "int_loop_ticks")? * INSTRUCTIONS_PER_TICK;
        if measured.abs_diff(expected) * 100 > expected {
            return Err(format!(
                "calibration: the 2-instruction loop measured {measured} instructions for \
                 {expected}: QEMU does not run at 40 instructions per SysTick tick"
            ));
        }
    }
    let mut figures = Vec::new();
    for line in out.lines().filter(|l| l.starts_with("bench ")) {
        let f = fields(line);
        let n = num(&f, "steps")?.max(1);
        let ticks = num(&f, "ticks")?.saturating_sub(num(&f, "baseline_ticks")?);
        let mut per_step = (ticks * INSTRUCTIONS_PER_TICK + n / 2) / n;
        // The benchmark may compute it itself (with its calibrated factor): the same number,
        // or something is off.
        if let Ok(own) = num(&f, "instructions_per_step") {
            if own.abs_diff(per_step) * 100 > per_step.max(100) {
                return Err(format!(
                    "the benchmark says {own} instructions per step, its ticks say \
                     {per_step}:\n{line}"
                ));
            }
            per_step = own;
        }
        let model = get(&f, "kind")?;
        if model != variant.name() {
            return Err(format!("benchmarked {model}, expected {}", variant.name()));
        }
        let integrator = get(&f, "integrator")?;
        let mut table = Vec::new();
        // Table mode: the `table` line of the same run (segments, RAM bytes of the tables,
        // measured worst relative error in parts per billion).
        if let Some(t) = out
            .lines()
            .find(|l| l.starts_with("table ") && l.contains(&format!(" integrator={integrator} ")))
        {
            let t = fields(t);
            for k in TABLE_FIELDS {
                table.push((k, get(&t, k)?));
            }
            table.push((
                "build_instructions",
                (num(&t, "build_ticks")? * INSTRUCTIONS_PER_TICK).to_string(),
            ));
        }
        figures.push(StepFigures {
            model,
            integrator,
            mode: get(&f, "mode")?,
            instructions_per_step: per_step,
            table,
        });
    }
    if figures.is_empty() {
        return Err(format!("no `bench` line in the output:\n{out}"));
    }
    Ok(figures)
}

/// The figures of the alpha observer's step (`nemm-bench observer=1`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ObserverFigures {
    /// Model kind.
    pub model: String,
    /// The model's integrator (`rk4` or `rk3`), which the observer's levels step with.
    pub integrator: String,
    /// Levels of the observer's grid.
    pub levels: u32,
    /// Model steps per observer step.
    pub model_steps: u32,
    /// Where the levels' coefficients come from: `blob` (the blob's level tables, table
    /// cost) or `exact` (the scalers).
    pub levels_from: String,
    /// `size_of` the firmware's observer \[bytes\] (RAM, in a static).
    pub bytes: u64,
    /// Instructions per observer step.
    pub instructions_per_step: u64,
    /// Instructions of the longest measured observer step, and of the step that closes a
    /// block of stroke cycles (solving the window: the heaviest; `None` if the benchmark
    /// met none).
    pub max_step: (u64, Option<u64>),
    /// Instructions per step of the estimator with a level per sample on the same level
    /// tables (attached with `Estimator::attach_levels`, the `level-step` line; `None`
    /// without level tables).
    pub level_step_instructions: Option<u64>,
}

impl ObserverFigures {
    /// `target-observer model=<kind> integrator=<rk4|rk3> levels=<n> levels_from=<blob|exact>
    /// model_steps=<n> instructions_per_step=<N> max_step_instructions=<M>
    /// close_step_instructions=<C|none> ram_bytes=<B>`.
    pub fn line(&self) -> String {
        format!(
            "target-observer model={} integrator={} levels={} levels_from={} model_steps={} \
             instructions_per_step={} max_step_instructions={} close_step_instructions={} \
             ram_bytes={}",
            self.model,
            self.integrator,
            self.levels,
            self.levels_from,
            self.model_steps,
            self.instructions_per_step,
            self.max_step.0,
            self.max_step.1.map_or("none".into(), |n| n.to_string()),
            self.bytes
        ) + &self
            .level_step_instructions
            .map_or(String::new(), |n| format!(" level_step_instructions={n}"))
    }
}

/// The `observer` line of a benchmark run's output.
fn parse_observer(out: &str) -> Result<ObserverFigures, String> {
    let line = out
        .lines()
        .find(|l| l.starts_with("observer "))
        .ok_or_else(|| format!("no `observer` line in the benchmark output:\n{out}"))?;
    let f = fields(line);
    let get = |k: &str| -> Result<&str, String> {
        f.iter()
            .find(|(key, _)| *key == k)
            .map(|(_, v)| *v)
            .ok_or_else(|| format!("no `{k}` in the benchmark's observer line:\n{line}"))
    };
    let num = |k: &str| -> Result<u64, String> {
        get(k)?
            .parse()
            .map_err(|e| format!("`{k}` in the benchmark's observer line: {e}"))
    };
    let n = num("steps")?.max(1);
    let ticks = num("ticks")?.saturating_sub(num("baseline_ticks")?);
    let from_ticks = (ticks * INSTRUCTIONS_PER_TICK + n / 2) / n;
    let own = num("instructions_per_step")?;
    if own.abs_diff(from_ticks) * 100 > from_ticks.max(100) {
        return Err(format!(
            "the benchmark says {own} instructions per observer step, its ticks say \
             {from_ticks}:\n{line}"
        ));
    }
    if num("held")? > 0 {
        return Err(format!(
            "measured observer steps that updated nothing (the cheaper path):\n{line}"
        ));
    }
    Ok(ObserverFigures {
        model: get("kind")?.to_string(),
        integrator: get("integrator")?.to_string(),
        levels: u32::try_from(num("levels")?).map_err(|e| e.to_string())?,
        levels_from: get("levels_from")?.to_string(),
        model_steps: u32::try_from(num("model_steps")?).map_err(|e| e.to_string())?,
        bytes: num("bytes")?,
        instructions_per_step: own,
        max_step: parse_observer_steps(out)?,
        level_step_instructions: parse_level_step(out)?,
    })
}

/// The longest measured observer step and the close step of the `observer-steps` line
/// (instructions).
fn parse_observer_steps(out: &str) -> Result<(u64, Option<u64>), String> {
    let line = out
        .lines()
        .find(|l| l.starts_with("observer-steps "))
        .ok_or_else(|| format!("no `observer-steps` line in the benchmark output:\n{out}"))?;
    let f = fields(line);
    let num = |k: &str| -> Option<Result<u64, String>> {
        f.iter().find(|(key, _)| *key == k).map(|(_, v)| {
            v.parse()
                .map_err(|e| format!("`{k}` in the benchmark's observer-steps line: {e}"))
        })
    };
    let max = num("max_step_instructions")
        .ok_or_else(|| format!("no `max_step_instructions` in:\n{line}"))??;
    let close = num("close_step_instructions").transpose()?;
    Ok((max, close))
}

/// The instructions per step of the `level-step` line, if the output has one; checked
/// against its ticks like the observer's.
fn parse_level_step(out: &str) -> Result<Option<u64>, String> {
    let Some(line) = out.lines().find(|l| l.starts_with("level-step ")) else {
        return Ok(None);
    };
    let f = fields(line);
    let num = |k: &str| -> Result<u64, String> {
        f.iter()
            .find(|(key, _)| *key == k)
            .ok_or_else(|| format!("no `{k}` in the benchmark's level-step line:\n{line}"))?
            .1
            .parse()
            .map_err(|e| format!("`{k}` in the benchmark's level-step line: {e}"))
    };
    let n = num("steps")?.max(1);
    let ticks = num("ticks")?.saturating_sub(num("baseline_ticks")?);
    let from_ticks = (ticks * INSTRUCTIONS_PER_TICK + n / 2) / n;
    let own = num("instructions_per_step")?;
    if own.abs_diff(from_ticks) * 100 > from_ticks.max(100) || num("failed")? > 0 {
        return Err(format!("the level-step line does not add up:\n{line}"));
    }
    Ok(Some(own))
}

/// Runs the benchmark image with its built-in weights (the firmware's trained NEMM, whose
/// blob stores the level tables the observer steps on) in its `observer=1` mode: the
/// instructions of `steps` observer steps after 200 warm-up steps.
pub fn observer(tc: &Toolchain, images: &Images, steps: u32) -> Result<ObserverFigures, String> {
    let args = ["observer=1".to_string(), format!("steps={steps}")];
    let (code, out) = firmware::run_qemu(tc, images.board, &images.bench, &args)?;
    if code != 0 {
        return Err(format!(
            "the observer benchmark failed with exit code {code}:\n{out}"
        ));
    }
    parse_observer(&out)
}

/// The benchmark image of `images` with the example blob of `kind`
/// (`nemm-firmware/data/example-<kind>.nemm`) in its weights slot, written under the
/// firmware target directory.
pub fn image_with_example(paths: &Paths, images: &Images, kind: Kind) -> Result<PathBuf, String> {
    let elf = Elf::read(&images.bench)?;
    let scratch = firmware::target_dir(paths).join("bench");
    std::fs::create_dir_all(&scratch).map_err(|e| format!("{}: {e}", scratch.display()))?;
    let blob_path = paths
        .root
        .join("nemm-firmware/data")
        .join(format!("example-{}.nemm", kind.name()));
    let blob = std::fs::read(&blob_path).map_err(|e| format!("{}: {e}", blob_path.display()))?;
    let image = scratch.join(format!(
        "nemm-bench-{}-{}.elf",
        images.board.machine(),
        kind.name()
    ));
    firmware::with_weights(&elf, &blob, &image)?;
    Ok(image)
}

/// Runs the benchmark image once per model (the example blob of its kind, from
/// `nemm-firmware/data/`, patched into its weights slot; the lost-motion element added by
/// the benchmark, `lost-motion=1`) and returns the figures.
pub fn run(
    tc: &Toolchain,
    paths: &Paths,
    images: &Images,
    mode: Mode,
    steps: u32,
    models: &[Variant],
) -> Result<Vec<StepFigures>, String> {
    let mut figures = Vec::new();
    for &variant in models {
        let image = image_with_example(paths, images, variant.kind)?;
        let mut args = vec![format!("mode={}", mode.name()), format!("steps={steps}")];
        args.extend(variant.bench_args());
        let (code, out) = firmware::run_qemu(tc, images.board, &image, &args)?;
        if code != 0 {
            let hint = if out.contains("kind=bad-option") {
                format!(
                    " (this firmware build does not know one of {})",
                    args.join(" ")
                )
            } else {
                String::new()
            };
            return Err(format!(
                "the benchmark failed for {} with exit code {code}{hint}:\n{out}",
                variant.name()
            ));
        }
        figures.extend(parse(&out, variant)?);
    }
    Ok(figures)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_benchmark_output_into_target_step_lines() {
        let out = "\
calibration iterations=1000 int_loop_ticks=50 fp_loop_ticks=60
table kind=nemm integrator=rk4 segments=128 tables=2 table_bytes=7168 max_rel_error_ppb=2792 kinks=73 build_ticks=100
bench kind=nemm integrator=rk4 mode=table steps=4000 ticks=49300 baseline_ticks=100
";
        let nemm = Variant::plain(Kind::Nemm);
        let f = parse(out, nemm).expect("parse");
        assert_eq!(
            f.iter().map(StepFigures::line).collect::<Vec<_>>(),
            [
                "target-step model=nemm integrator=rk4 mode=table instructions_per_step=492 \
              segments=128 table_bytes=7168 max_rel_error_ppb=2792 kinks=73 \
              build_instructions=4000"
            ]
        );
        assert_eq!(f[0].table_field("table_bytes"), Some("7168"));
        assert!(parse(out, Variant::plain(Kind::Sem)).is_err());
        // Without the lost-motion element, not what a `nemm+lm` run asked for.
        assert!(parse(out, Variant::with_lost_motion(Kind::Nemm)).is_err());
        assert!(parse("calibration iterations=1000 int_loop_ticks=80\n", nemm).is_err());
        assert!(parse("boot\n", nemm).is_err());
    }

    #[test]
    fn reads_a_run_with_the_lost_motion_element() {
        let out = "\
calibration iterations=1000 int_loop_ticks=50 fp_loop_ticks=60
bench kind=linear-emm+lm integrator=rk4 mode=exact hidden=0 layers=0 steps=4000 ticks=20100 baseline_ticks=100 held=0 resets=0
bench kind=linear-emm+lm integrator=rk3 mode=exact hidden=0 layers=0 steps=4000 ticks=15100 baseline_ticks=100 held=0 resets=0
";
        let lm = Variant::with_lost_motion(Kind::LinearEmm);
        let f = parse(out, lm).expect("parse");
        assert_eq!(
            f.iter().map(StepFigures::line).collect::<Vec<_>>(),
            [
                "target-step model=linear-emm+lm integrator=rk4 mode=exact \
                 instructions_per_step=200",
                "target-step model=linear-emm+lm integrator=rk3 mode=exact \
                 instructions_per_step=150"
            ]
        );
        assert!(parse(out, Variant::plain(Kind::LinearEmm)).is_err());
    }

    #[test]
    fn reads_the_observer_line() {
        let out = "\
calibration iterations=1000000 int_loop_ticks=50000 fp_loop_ticks=75000
observer kind=nemm integrator=rk4 levels=7 levels_from=blob model_steps=7 bytes=21572 hidden=16 layers=5 steps=4000 ticks=14060122 baseline_ticks=800 instructions_per_step=140593 held=0
observer-steps closes=0 max_step_ticks=3600 max_step_instructions=144000 close_step_ticks=3700 close_step_instructions=148000
";
        let f = parse_observer(out).expect("parse");
        assert_eq!(
            f.line(),
            "target-observer model=nemm integrator=rk4 levels=7 levels_from=blob model_steps=7 \
             instructions_per_step=140593 max_step_instructions=144000 \
             close_step_instructions=148000 ram_bytes=21572"
        );
        // A run too short to meet a close of a block of stroke cycles.
        let no_close = out.replace(
            " close_step_ticks=3700 close_step_instructions=148000",
            " close_step=none",
        );
        assert_eq!(
            parse_observer(&no_close).expect("parse").max_step,
            (144000, None)
        );
        assert!(parse_observer(&out.replace("held=0", "held=3")).is_err());
        assert!(parse_observer(&out.replace("=140593", "=99999")).is_err());
        assert!(parse_observer("calibration\n").is_err());
    }
}
