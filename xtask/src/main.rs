//! Project automation. Run `cargo xtask help`.
//!
//! - `cargo xtask test`: everything: the firmware for the target (found or installed
//!   toolchain, see [`toolchain`]), its lint, then the host workspace tests (release) with the
//!   QEMU tests (`tests/tests/qemu_*.rs`) pointed at the firmware images, the firmware
//!   library's host unit tests, nemm-core's unit tests with `micromath`, and a short
//!   `bench-target`.
//! - `cargo xtask bench-target`: instructions per estimator step on the emulated Cortex-M4,
//!   per model kind and integrator.
//!
//! std only, so that it compiles in seconds.

#[path = "../../tests/src/elf.rs"]
#[allow(dead_code)]
mod elf;
mod firmware;
#[path = "../../nemm-firmware/src/slot.rs"]
#[allow(dead_code)]
mod slot;
mod toolchain;

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::Instant;
use toolchain::Toolchain;

fn usage() -> &'static str {
    "usage: cargo xtask <command> [options]

commands:
  test [--host-only]     every test: the firmware (target build, lint), the host workspace
                         (release) with the QEMU tests, a short bench-target; --host-only
                         skips everything that needs the embedded toolchain
  bench-target [--mode exact|table] [--steps N] [--model KIND]...
                         instructions per estimator step in QEMU (-icount shift=0; N steps of
                         the bench trace, default 4000, after 200 warm-up steps), one line
                         per model kind and integrator:
                         target-step model=<kind> integrator=<rk4|rk3> mode=<mode> instructions_per_step=<N>
                         (mode=table adds segments=, table_bytes= (RAM), max_rel_error_ppb=, kinks=,
                          build_instructions=: building the tables at boot)
  build-target           build the firmware images and print their flash and RAM use
  run-target [OPTION]... run the firmware in QEMU with firmware options, e.g.
                         period_ticks=100000 fault=bus@3000+20 fault=nan@5000+40 samples=2000
  toolchain              say which toolchain route builds the firmware (install it if root)
  help                   this text"
}

/// Workspace locations.
pub struct Paths {
    /// Workspace root.
    pub root: PathBuf,
    /// Cargo's target directory of the workspace.
    pub target: PathBuf,
}

impl Paths {
    fn find() -> Result<Self, String> {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"))
            .parent()
            .ok_or("xtask has no parent directory")?
            .to_path_buf();
        let target = match std::env::var_os("CARGO_TARGET_DIR") {
            Some(t) => root.join(t),
            None => {
                let meta = Command::new(toolchain::host_cargo())
                    .args(["metadata", "--format-version", "1", "--no-deps"])
                    .current_dir(&root)
                    .output()
                    .map_err(|e| format!("cannot run cargo metadata: {e}"))?;
                let text = String::from_utf8_lossy(&meta.stdout);
                json_string(&text, "target_directory")
                    .map(PathBuf::from)
                    .unwrap_or_else(|| root.join("target"))
            }
        };
        Ok(Self { root, target })
    }
}

/// The string value of `"key":"..."` in a JSON text (no escapes other than `\\` and `\"`).
fn json_string(json: &str, key: &str) -> Option<String> {
    let start = json.find(&format!("\"{key}\":\""))? + key.len() + 4;
    let mut out = String::new();
    let mut chars = json[start..].chars();
    while let Some(c) = chars.next() {
        match c {
            '"' => return Some(out),
            '\\' => out.push(chars.next()?),
            c => out.push(c),
        }
    }
    None
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let rest = args.get(1..).unwrap_or(&[]);
    let result = match args.first().map(String::as_str) {
        Some("test") => test(rest),
        Some("bench-target") => bench_target(rest),
        Some("build-target") => build_target(rest),
        Some("run-target") => run_target(rest),
        Some("toolchain") => setup().map(|(tc, _)| println!("{}", tc.describe())),
        Some("help") | Some("-h") | Some("--help") | None => {
            println!("{}", usage());
            Ok(())
        }
        Some(other) => Err(format!("unknown command `{other}`\n\n{}", usage())),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Runs `cmd`, echoing it; fails with its exit status.
pub fn run(cmd: &mut Command) -> Result<(), String> {
    eprintln!("xtask: running {}", show(cmd));
    let status = cmd
        .status()
        .map_err(|e| format!("cannot start {}: {e}", show(cmd)))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{} failed with {status}", show(cmd)))
    }
}

/// A command as a shell line (environment changes first).
fn show(cmd: &Command) -> String {
    let mut s = String::new();
    if let Some(dir) = cmd.get_current_dir() {
        s += &format!("(in {}) ", dir.display());
    }
    for (k, v) in cmd.get_envs() {
        if let (Some(v), false) = (v, k == "PATH") {
            s += &format!("{}={} ", k.to_string_lossy(), v.to_string_lossy());
        }
    }
    s += &cmd.get_program().to_string_lossy();
    for a in cmd.get_args() {
        s += " ";
        s += &a.to_string_lossy();
    }
    s
}

fn cargo() -> Command {
    Command::new(toolchain::host_cargo())
}

fn setup() -> Result<(Toolchain, Paths), String> {
    let paths = Paths::find()?;
    let tc = toolchain::detect(&paths.root, true)?;
    eprintln!("xtask: firmware toolchain: {}", tc.describe());
    Ok((tc, paths))
}

fn no_args(cmd: &str, args: &[String]) -> Result<(), String> {
    match args.first() {
        Some(a) => Err(format!("`{cmd}` takes no argument `{a}`\n\n{}", usage())),
        None => Ok(()),
    }
}

fn test(args: &[String]) -> Result<(), String> {
    let host_only = match args {
        [] => false,
        [a] if a == "--host-only" => true,
        [a, ..] => return Err(format!("unknown option `{a}` of `test`\n\n{}", usage())),
    };
    let started = Instant::now();
    let paths = Paths::find()?;
    let mut workspace_tests = cargo();
    workspace_tests
        .args(["test", "--workspace", "--release", "--no-fail-fast"])
        .current_dir(&paths.root);
    let mut firmware_secs = 0.0;
    let firmware = if host_only {
        eprintln!("xtask: --host-only: no firmware build, no QEMU tests");
        None
    } else {
        // Fails here, before the long host build, if the toolchain is missing.
        let (tc, paths) = setup()?;
        let t = Instant::now();
        let images = firmware::build(&tc, &paths)?;
        match tc.clippy_gap() {
            None => firmware::clippy(&tc, &paths)?,
            Some(what) => eprintln!("xtask: firmware lint skipped: no {what}"),
        }
        firmware_secs += t.elapsed().as_secs_f64();
        workspace_tests
            .env("NEMM_FIRMWARE_ELF", &images.app)
            .env("NEMM_FIRMWARE_RELEASE_ELF", &images.app_release)
            .env("NEMM_BENCH_ELF", &images.bench)
            .env("NEMM_QEMU", &tc.qemu)
            .env("NEMM_REQUIRE_FIRMWARE", "1");
        Some((tc, paths, images))
    };
    run(&mut workspace_tests)?;
    // The firmware library's own unit tests, on the host.
    run(cargo()
        .args(["test", "--release", "-p", "nemm-firmware", "--lib"])
        .current_dir(&paths.root))?;
    // nemm-core's unit tests with the fast math backend (the integration tests' tolerances
    // are those of libm; the micromath error is measured by the math_backends example).
    run(cargo()
        .args([
            "test",
            "--release",
            "-p",
            "nemm-core",
            "--features",
            "micromath",
            "--lib",
        ])
        .current_dir(&paths.root))?;
    if let Some((tc, paths, images)) = firmware {
        let t = Instant::now();
        let lines = bench(&tc, &paths, &images, "exact", 50, &all_kinds())?;
        for l in &lines {
            eprintln!("xtask: (smoke, 50 steps) {l}");
        }
        for (name, path) in [
            ("board build", &images.app_release),
            ("qemu build", &images.app),
        ] {
            eprintln!(
                "xtask: {}",
                firmware::memory_report(name, &elf::Elf::read(path)?)
            );
        }
        firmware_secs += t.elapsed().as_secs_f64();
        eprintln!(
            "xtask: firmware build, lint and bench smoke test took {firmware_secs:.0} s (the \
             QEMU tests ran inside `cargo test`)"
        );
    }
    eprintln!(
        "xtask: all tests passed in {:.0} s",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

const KINDS: [&str; 4] = ["sem", "linear-emm", "nemm-light", "nemm"];

fn all_kinds() -> Vec<String> {
    KINDS.iter().map(|k| k.to_string()).collect()
}

fn bench_target(args: &[String]) -> Result<(), String> {
    let mut mode = "exact".to_string();
    let mut steps = 4000u32;
    let mut kinds = Vec::new();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || {
            it.next()
                .cloned()
                .ok_or_else(|| format!("`{a}` needs a value"))
        };
        match a.as_str() {
            "--mode" => mode = value()?,
            "--steps" => {
                steps = value()?.parse().map_err(|e| format!("--steps: {e}"))?;
            }
            "--model" => {
                let k = value()?;
                if !KINDS.contains(&k.as_str()) {
                    return Err(format!("--model {k}: one of {}", KINDS.join(", ")));
                }
                kinds.push(k);
            }
            _ => return Err(format!("unknown option `{a}`\n\n{}", usage())),
        }
    }
    if kinds.is_empty() {
        kinds = all_kinds();
    }
    let (tc, paths) = setup()?;
    let images = firmware::build(&tc, &paths)?;
    for line in bench(&tc, &paths, &images, &mode, steps, &kinds)? {
        println!("{line}");
    }
    eprintln!(
        "xtask: {}",
        firmware::memory_report(
            "firmware (board build)",
            &elf::Elf::read(&images.app_release)?
        )
    );
    Ok(())
}

/// Instructions per SysTick tick: `-icount shift=0` runs one instruction per emulated
/// nanosecond, and SysTick counts the mps2-an386 core clock of 25 MHz.
const INSTRUCTIONS_PER_TICK: u64 = 40;

/// Runs the benchmark image once per model kind (the example blobs of
/// `nemm-firmware/data/`, patched into its weights slot) and returns the `target-step` lines.
fn bench(
    tc: &Toolchain,
    paths: &Paths,
    images: &firmware::Images,
    mode: &str,
    steps: u32,
    kinds: &[String],
) -> Result<Vec<String>, String> {
    let elf = elf::Elf::read(&images.bench)?;
    let scratch = firmware::target_dir(paths).join("bench");
    std::fs::create_dir_all(&scratch).map_err(|e| format!("{}: {e}", scratch.display()))?;
    let mut lines = Vec::new();
    for kind in kinds {
        let blob_path = paths
            .root
            .join("nemm-firmware/data")
            .join(format!("example-{kind}.nemm"));
        let blob =
            std::fs::read(&blob_path).map_err(|e| format!("{}: {e}", blob_path.display()))?;
        let image = scratch.join(format!("nemm-bench-{kind}.elf"));
        firmware::with_weights(&elf, &blob, &image)?;
        let args = [format!("mode={mode}"), format!("steps={steps}")];
        let (code, out) = firmware::run_qemu(tc, &image, &args)?;
        if code != 0 {
            let hint = if out.contains("kind=bad-option") {
                format!(" (this firmware build does not know mode={mode} or steps={steps})")
            } else {
                String::new()
            };
            return Err(format!(
                "the benchmark failed for {kind} with exit code {code}{hint}:\n{out}"
            ));
        }
        let fields = |line: &str| -> Vec<(String, String)> {
            line.split_ascii_whitespace()
                .filter_map(|w| w.split_once('='))
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect()
        };
        let get = |f: &[(String, String)], k: &str| -> Result<String, String> {
            f.iter()
                .find(|(key, _)| key == k)
                .map(|(_, v)| v.clone())
                .ok_or_else(|| format!("no `{k}` in the benchmark output:\n{out}"))
        };
        let num = |f: &[(String, String)], k: &str| -> Result<u64, String> {
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
        let mut found = 0;
        for line in out.lines().filter(|l| l.starts_with("bench ")) {
            let f = fields(line);
            let n = num(&f, "steps")?.max(1);
            let ticks = num(&f, "ticks")?.saturating_sub(num(&f, "baseline_ticks")?);
            let mut per_step = (ticks * INSTRUCTIONS_PER_TICK + n / 2) / n;
            // The benchmark may compute it itself (with its calibrated factor): the same
            // number, or something is off.
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
            if &model != kind {
                return Err(format!("benchmarked {model}, expected {kind}"));
            }
            let integrator = get(&f, "integrator")?;
            let mut step_line = format!(
                "target-step model={model} integrator={integrator} mode={} instructions_per_step={per_step}",
                get(&f, "mode")?
            );
            // Table mode: the `table` line of the same run (segments, RAM bytes of the
            // tables, measured worst relative error in parts per billion).
            if let Some(t) = out.lines().find(|l| {
                l.starts_with("table ") && l.contains(&format!(" integrator={integrator} "))
            }) {
                let t = fields(t);
                for k in ["segments", "table_bytes", "max_rel_error_ppb", "kinks"] {
                    step_line += &format!(" {k}={}", get(&t, k)?);
                }
                // Building the estimator (the tables and their check) at boot.
                step_line += &format!(
                    " build_instructions={}",
                    num(&t, "build_ticks")? * INSTRUCTIONS_PER_TICK
                );
            }
            lines.push(step_line);
            found += 1;
        }
        if found == 0 {
            return Err(format!("no `bench` line in the output:\n{out}"));
        }
    }
    Ok(lines)
}

fn build_target(args: &[String]) -> Result<(), String> {
    no_args("build-target", args)?;
    let (tc, paths) = setup()?;
    let images = firmware::build(&tc, &paths)?;
    for (name, path) in [
        ("board build", &images.app_release),
        ("qemu build", &images.app),
        ("benchmark", &images.bench),
    ] {
        let elf = elf::Elf::read(path)?;
        println!("{}\n{}", path.display(), elf.memory_use().table());
        println!("{}\n", firmware::memory_report(name, &elf));
    }
    Ok(())
}

fn run_target(args: &[String]) -> Result<(), String> {
    let (tc, paths) = setup()?;
    let images = firmware::build(&tc, &paths)?;
    let status = firmware::qemu_command(&tc, &images.app, args)
        .status()
        .map_err(|e| format!("cannot run {}: {e}", tc.qemu.display()))?;
    match status.code() {
        Some(0) => Ok(()),
        code => Err(format!("the firmware exited with {code:?}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_target_directory_from_cargo_metadata() {
        let json = r#"{"packages":[],"target_directory":"/tmp/a \"b\"\\c","version":1}"#;
        assert_eq!(
            json_string(json, "target_directory").as_deref(),
            Some("/tmp/a \"b\"\\c")
        );
        assert_eq!(json_string(json, "workspace_root"), None);
    }

    #[test]
    fn frames_a_weights_slot() {
        let s = firmware::slot(b"NEMM1234", 32).unwrap();
        assert_eq!(&s[..8], b"NWSL\x08\x00\x00\x00");
        assert_eq!(&s[8..16], b"NEMM1234");
        assert!(s[16..].iter().all(|&b| b == 0xFF));
        assert!(firmware::slot(&[0; 30], 32).is_err());
    }
}
