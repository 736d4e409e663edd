//! The C interface (`nemm-c`): its static libraries for the host and the Cortex-M4F, the
//! header check, the host C unit test, and the C example on the target against the Rust
//! firmware.
//!
//! The C example (`examples/c/replay.c`, linked by `arm-none-eabi-gcc` against the
//! Cortex-M4F library) is fed, sample by sample, the velocity the Rust firmware handed its
//! estimator in a QEMU run over the recorded trace (the firmware's `s` lines), the trace's
//! stroke as the position and its measured force for the observer; its forces and flags
//! must equal the firmware's bit for bit, in exact mode over the whole trace and in table
//! mode over its first 3000 samples.

use crate::firmware::{self, Board, Images};
use crate::toolchain::{self, Toolchain, TARGET};
use crate::{cargo, run, Mode, Paths};
use nemm_elf::Elf;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// The crate, relative to the workspace root.
const CRATE: &str = "nemm-c";
/// The C example's sources, relative to the workspace root.
const EXAMPLE: &str = "examples/c";
/// The blobs the host C unit test loads: one with level tables (7 levels, 0.15 among them),
/// one without.
const HOST_TEST_BLOBS: [&str; 2] = [
    "nemm-firmware/data/trained-nemm.nemm",
    "nemm-firmware/data/example-nemm.nemm",
];
/// The C compiler of the target and its Debian package.
const ARM_GCC: (&str, &str) = ("arm-none-eabi-gcc", "gcc-arm-none-eabi");
/// Code generation flags of the C example: Cortex-M4 with its single-precision FPU, the
/// hard-float calling convention of `thumbv7em-none-eabihf`.
const ARM_FLAGS: &[&str] = &[
    "-mcpu=cortex-m4",
    "-mthumb",
    "-mfloat-abi=hard",
    "-mfpu=fpv4-sp-d16",
];
/// Warnings of every C compilation.
const C_WARNINGS: &[&str] = &["-std=c11", "-Wall", "-Wextra", "-Werror", "-pedantic"];
/// The comparison runs: the evaluation mode and the samples of the trace (all: `None`).
const RUNS: [(Mode, Option<u32>); 2] = [(Mode::Exact, None), (Mode::Table, Some(3000))];
/// The firmware's sample clock in the comparison: 4 ms per period, so that its logger keeps
/// every record (`-icount sleep=off`: no wall time).
const SLOW_CLOCK: &str = "period_ticks=100000";

/// Where the C builds go: `<workspace target>/nemm-c`.
fn out_dir(paths: &Paths) -> PathBuf {
    paths.target.join("nemm-c")
}

/// Builds the host static library (`cargo build --release -p nemm-c`) and returns it.
pub fn host_lib(paths: &Paths) -> Result<PathBuf, String> {
    run(cargo()
        .args(["build", "--release", "-p", CRATE, "--lib"])
        .current_dir(&paths.root))?;
    let lib = paths.target.join("release").join("libnemm_c.a");
    lib.is_file()
        .then_some(lib.clone())
        .ok_or_else(|| format!("the host build left no {}", lib.display()))
}

/// A `cargo <subcommand>` of nemm-c for the Cortex-M4F on the firmware's toolchain route
/// (the firmware's code generation: `target-cpu=cortex-m4`).
fn target_cargo(tc: &Toolchain, paths: &Paths, subcommand: &str) -> Command {
    let mut c = tc.cargo(subcommand, &paths.root.join(CRATE), &out_dir(paths));
    c.args(["--release", "--lib", "--target", TARGET]).env(
        "CARGO_TARGET_THUMBV7EM_NONE_EABIHF_RUSTFLAGS",
        "-C target-cpu=cortex-m4",
    );
    c
}

/// Builds the Cortex-M4F static library and returns it.
pub fn target_lib(tc: &Toolchain, paths: &Paths) -> Result<PathBuf, String> {
    run(&mut target_cargo(tc, paths, "build"))?;
    let lib = out_dir(paths)
        .join(TARGET)
        .join("release")
        .join("libnemm_c.a");
    lib.is_file()
        .then_some(lib.clone())
        .ok_or_else(|| format!("the target build left no {}", lib.display()))
}

/// Lints nemm-c for the Cortex-M4F (warnings denied), where the route has clippy.
pub fn target_clippy(tc: &Toolchain, paths: &Paths) -> Result<(), String> {
    run(target_cargo(tc, paths, "clippy").args(["--", "-D", "warnings"]))
}

/// Regenerates `nemm-c/include/nemm.h` from the crate (the header test, blessing).
pub fn header(paths: &Paths) -> Result<(), String> {
    run(cargo()
        .args(["test", "--release", "-p", CRATE, "--test", "header"])
        .env("NEMM_BLESS", "1")
        .current_dir(&paths.root))
}

/// `cargo xtask c-lib`: both static libraries, with their paths and sizes.
pub fn libs(paths: &Paths, tc: Option<&Toolchain>) -> Result<(), String> {
    let mut built = vec![("host", host_lib(paths)?)];
    if let Some(tc) = tc {
        built.push((TARGET, target_lib(tc, paths)?));
    }
    for (what, lib) in built {
        let bytes = std::fs::metadata(&lib)
            .map_err(|e| format!("{}: {e}", lib.display()))?
            .len();
        println!(
            "c-lib target={what} path={} archive_bytes={bytes}",
            lib.display()
        );
    }
    println!(
        "c-lib header={}",
        paths.root.join(CRATE).join("include/nemm.h").display()
    );
    Ok(())
}

/// The host C unit test: `examples/c/test_host.c` compiled by the host's `cc` against the
/// host library and run on the firmware's trained blob and an example blob without level
/// tables; and the header compiled as C++.
pub fn host_test(paths: &Paths) -> Result<(), String> {
    let lib = host_lib(paths)?;
    let dir = out_dir(paths).join("host");
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let include = paths.root.join(CRATE).join("include");
    let exe = dir.join("test_host");
    run(Command::new("cc")
        .args(C_WARNINGS)
        .arg("-O2")
        .arg("-I")
        .arg(&include)
        .arg(paths.root.join(EXAMPLE).join("test_host.c"))
        .arg(&lib)
        .args(["-lpthread", "-ldl", "-lm", "-o"])
        .arg(&exe))?;
    let out = Command::new(&exe)
        .args(HOST_TEST_BLOBS.map(|b| paths.root.join(b)))
        .output()
        .map_err(|e| format!("cannot run {}: {e}", exe.display()))?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprint!("{}", String::from_utf8_lossy(&out.stderr));
    for l in stdout.lines() {
        eprintln!("xtask: {l}");
    }
    if !out.status.success() || !stdout.contains(" passed, 0 failed") {
        return Err(format!("the host C test failed ({})", out.status));
    }
    // C++ programs include the same header.
    if toolchain::which("c++").is_none() {
        eprintln!("xtask: no c++ on PATH: the header's C++ check is skipped");
        return Ok(());
    }
    let cpp = dir.join("header.cpp");
    std::fs::write(&cpp, "#include \"nemm.h\"\n").map_err(|e| format!("{e}"))?;
    run(Command::new("c++")
        .args(["-std=c++11", "-Wall", "-Wextra", "-Werror", "-pedantic"])
        .arg("-fsyntax-only")
        .arg("-I")
        .arg(&include)
        .arg(&cpp))
}

/// `arm-none-eabi-gcc`, installed with apt-get if missing and xtask runs as root.
fn arm_gcc() -> Result<PathBuf, String> {
    let (gcc, package) = ARM_GCC;
    if let Some(p) = toolchain::which(gcc) {
        return Ok(p);
    }
    if toolchain::is_root() && toolchain::which("apt-get").is_some() {
        toolchain::apt_install(&[package])?;
        if let Some(p) = toolchain::which(gcc) {
            return Ok(p);
        }
    }
    Err(format!(
        "the C example needs {gcc}: apt-get install -y {package} (Debian, Ubuntu), or the Arm \
         GNU toolchain on PATH; `cargo xtask test --host-only` skips it"
    ))
}

/// One `s` record: sample, velocity bits, force bits, estimator flags.
type Record = (u32, u32, u32, u8);

/// The `s` lines of a firmware or C example run (their first four fields).
fn records(out: &str) -> Result<Vec<Record>, String> {
    out.lines()
        .filter(|l| l.starts_with("s "))
        .map(|l| {
            let f: Vec<&str> = l.split_ascii_whitespace().collect();
            let hex = |i: usize| -> Result<u32, String> {
                let s = f.get(i).ok_or_else(|| format!("short line `{l}`"))?;
                u32::from_str_radix(s, 16).map_err(|e| format!("`{l}`: {e}"))
            };
            let k = f
                .get(1)
                .and_then(|s| s.parse().ok())
                .ok_or_else(|| format!("bad line `{l}`"))?;
            Ok((k, hex(2)?, hex(3)?, hex(4)? as u8))
        })
        .collect()
}

/// The value of `key=` in the line starting with `prefix`.
pub fn field<'a>(out: &'a str, prefix: &str, key: &str) -> Option<&'a str> {
    let k = format!("{key}=");
    out.lines()
        .find(|l| l.starts_with(prefix))?
        .split_ascii_whitespace()
        .find_map(|w| w.strip_prefix(k.as_str()))
}

/// `(displacement_m, force_n)` of each sample of the firmware image's trace.
fn trace(elf: &Elf) -> Result<Vec<(f32, f32)>, String> {
    let t = elf.section_data(".nemm_trace")?;
    let word = |at: usize| -> Option<u32> {
        Some(u32::from_le_bytes(t.get(at..at + 4)?.try_into().ok()?))
    };
    if t.get(..4) != Some(b"NTRC") {
        return Err("the firmware's .nemm_trace is not a trace".into());
    }
    let n = word(16).ok_or("truncated trace")? as usize;
    (0..n)
        .map(|i| {
            let at = 20 + 12 * i;
            match (word(at), word(at + 8)) {
                (Some(x), Some(f)) => Ok((f32::from_bits(x), f32::from_bits(f))),
                _ => Err("truncated trace".to_string()),
            }
        })
        .collect()
}

/// The inputs file of the C example (`examples/c/replay.c` describes it).
fn inputs(mode: Mode, alpha_bits: u32, velocities: &[u32], trace: &[(f32, f32)]) -> Vec<u8> {
    let mut b = Vec::with_capacity(16 + 12 * velocities.len());
    b.extend_from_slice(b"NCIN");
    b.extend_from_slice(&u32::from(mode == Mode::Table).to_le_bytes());
    b.extend_from_slice(&alpha_bits.to_le_bytes());
    b.extend_from_slice(&(velocities.len() as u32).to_le_bytes());
    for (k, v) in velocities.iter().enumerate() {
        let (x, f) = trace.get(k).copied().unwrap_or((f32::NAN, f32::NAN));
        b.extend_from_slice(&v.to_le_bytes());
        b.extend_from_slice(&x.to_bits().to_le_bytes());
        b.extend_from_slice(&f.to_bits().to_le_bytes());
    }
    b
}

/// Compiles and links the C example for the Cortex-M4F with `blob` and `inputs` embedded.
fn link_example(
    gcc: &Path,
    paths: &Paths,
    lib: &Path,
    blob: &Path,
    inputs: &Path,
    elf: &Path,
) -> Result<(), String> {
    let src = paths.root.join(EXAMPLE);
    let quoted = |p: &Path| format!("\"{}\"", p.display());
    run(Command::new(gcc)
        .args(ARM_FLAGS)
        .args(C_WARNINGS)
        .args([
            "-O2",
            "-ffreestanding",
            "-ffunction-sections",
            "-fdata-sections",
        ])
        // No executable stack (bare-metal gcc marks no object either way; ld warns).
        .arg("-Wa,--noexecstack")
        .arg("-I")
        .arg(paths.root.join(CRATE).join("include"))
        .arg("-I")
        .arg(src.join("mps2"))
        .arg(format!("-DNEMM_EXAMPLE_BLOB={}", quoted(blob)))
        .arg(format!("-DNEMM_EXAMPLE_INPUTS={}", quoted(inputs)))
        .args(["-nostdlib", "-Wl,--gc-sections", "-T"])
        .arg(src.join("mps2/mps2-an386.ld"))
        .arg(src.join("mps2/startup.c"))
        .arg(src.join("replay.c"))
        .arg(src.join("mps2/embed.S"))
        .arg(lib)
        .args(["-lgcc", "-o"])
        .arg(elf))
}

/// One run of the C example: its mode, the samples it replayed, its `c-example` lines and
/// its image's sections.
#[derive(Debug, Clone)]
pub struct ExampleRun {
    /// The estimator's mode of the run.
    pub mode: Mode,
    /// Samples replayed (the firmware's records).
    pub samples: usize,
    /// The `c-example boot` line: what was built.
    pub boot: String,
    /// The `c-example summary` line: counters, the exact observer's estimate, instructions per
    /// step, stack.
    pub summary: String,
    /// The `c-example levels` line: the level tables, the observer on them, the estimator's
    /// level per sample.
    pub levels: String,
    /// Sections of the linked image.
    pub memory: nemm_elf::MemoryUse,
    /// Bytes of the recorded inputs linked into the image.
    pub inputs_bytes: u64,
}

impl ExampleRun {
    /// The lines `cargo xtask c-test` prints for the run.
    pub fn lines(&self, blob_bytes: usize) -> [String; 4] {
        let m = &self.memory;
        [
            self.boot.clone(),
            self.summary.clone(),
            self.levels.clone(),
            format!(
                "c-example image: .text {} B, .rodata {} B (blob {blob_bytes} B, inputs {} B), \
                 .bss {} B",
                m.size_of(".text"),
                m.size_of(".rodata"),
                self.inputs_bytes,
                m.size_of(".bss"),
            ),
        ]
    }
}

/// What [`target_example`] measured: the blob it ran (the firmware's) and one
/// [`ExampleRun`] per run of [`RUNS`].
#[derive(Debug, Clone)]
pub struct ExampleFigures {
    /// The blob of the firmware's weights slot, linked into the example.
    pub blob: Vec<u8>,
    /// The runs, in the order of [`RUNS`] (exact mode, then table mode).
    pub runs: Vec<ExampleRun>,
}

impl ExampleFigures {
    /// The run in `mode`.
    pub fn run(&self, mode: Mode) -> Result<&ExampleRun, String> {
        self.runs
            .iter()
            .find(|r| r.mode == mode)
            .ok_or_else(|| format!("no {}-mode run of the C example", mode.name()))
    }
}

/// The C example against the Rust firmware (`images`: the mps2-an386 build) in QEMU: builds
/// the Cortex-M4F library, then per run of [`RUNS`] the firmware's records, the example
/// linked with the firmware's blob and those inputs, and compares record by record. Prints
/// each run's `c-example` lines and image sizes, and returns them (`cargo xtask c-test`,
/// and the `c` block of `cargo xtask results --c`).
pub fn target_example(
    tc: &Toolchain,
    paths: &Paths,
    images: &Images,
) -> Result<ExampleFigures, String> {
    let started = Instant::now();
    let gcc = arm_gcc()?;
    let lib = target_lib(tc, paths)?;
    let fw = Elf::read(&images.app)?;
    let blob = crate::slot::blob(fw.section_data(".nemm_weights")?)
        .map_err(|e| format!("the firmware's weights slot: {e:?}"))?;
    let trace = trace(&fw)?;
    let dir = out_dir(paths).join("example");
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let blob_path = dir.join("blob.nemm");
    std::fs::write(&blob_path, blob).map_err(|e| format!("{}: {e}", blob_path.display()))?;
    let mut runs = Vec::with_capacity(RUNS.len());
    for (mode, samples) in RUNS {
        let mut options = vec![SLOW_CLOCK.to_string(), format!("mode={}", mode.name())];
        options.extend(samples.map(|n| format!("samples={n}")));
        let (code, fw_out) = firmware::run_qemu(tc, Board::An386, &images.app, &options)?;
        if code != 0 {
            return Err(format!("the firmware exited with {code}:\n{fw_out}"));
        }
        let want = records(&fw_out)?;
        let steps: usize = field(&fw_out, "summary ", "steps")
            .and_then(|s| s.parse().ok())
            .ok_or("no steps in the firmware's summary")?;
        if want.len() != steps {
            return Err(format!(
                "the firmware printed {} of its {steps} records (dropped?)",
                want.len()
            ));
        }
        let alpha = field(&fw_out, "start ", "alpha")
            .and_then(|a| u32::from_str_radix(a.trim_start_matches("0x"), 16).ok())
            .ok_or("no alpha in the firmware's start line")?;
        let velocities: Vec<u32> = want.iter().map(|r| r.1).collect();
        let inputs_path = dir.join(format!("inputs-{}.bin", mode.name()));
        std::fs::write(&inputs_path, inputs(mode, alpha, &velocities, &trace))
            .map_err(|e| format!("{}: {e}", inputs_path.display()))?;
        let elf = dir.join(format!("replay-{}.elf", mode.name()));
        link_example(&gcc, paths, &lib, &blob_path, &inputs_path, &elf)?;
        let image = Elf::read(&elf)?;
        let panics: Vec<String> = image
            .symbols
            .iter()
            .filter(|s| nemm_elf::is_panic_symbol(&s.name))
            .map(|s| nemm_elf::demangle(&s.name))
            .collect();
        if !panics.is_empty() {
            return Err(format!(
                "the C example links panic code: {}",
                panics.join(", ")
            ));
        }
        let (code, c_out) = firmware::run_qemu(tc, Board::An386, &elf, &[])?;
        if code != 0 {
            return Err(format!("the C example exited with {code}:\n{c_out}"));
        }
        if field(&c_out, "c-example boot ", "needs_position") != Some("0") {
            return Err(
                "the model has a static force: the C example feeds the recorded stroke as the \
                 position, the firmware its ADC's, so their forces differ"
                    .into(),
            );
        }
        compare(mode, &want, &records(&c_out)?)?;
        let line = |prefix: &str| {
            c_out
                .lines()
                .find(|l| l.starts_with(prefix))
                .unwrap_or("")
                .to_string()
        };
        eprintln!(
            "xtask: c-example mode={} samples={} forces and flags bit-identical to the firmware",
            mode.name(),
            want.len()
        );
        let run = ExampleRun {
            mode,
            samples: want.len(),
            boot: line("c-example boot "),
            summary: line("c-example summary "),
            levels: line("c-example levels "),
            memory: image.memory_use(),
            inputs_bytes: std::fs::metadata(&inputs_path).map_or(0, |f| f.len()),
        };
        for l in run.lines(blob.len()) {
            eprintln!("xtask: {l}");
        }
        runs.push(run);
    }
    eprintln!(
        "xtask: the C example matched the firmware in {:.0} s",
        started.elapsed().as_secs_f64()
    );
    Ok(ExampleFigures {
        blob: blob.to_vec(),
        runs,
    })
}

/// Fails at the first record of the C example that differs from the firmware's.
fn compare(mode: Mode, want: &[Record], got: &[Record]) -> Result<(), String> {
    if got.len() != want.len() {
        return Err(format!(
            "mode={}: the C example printed {} records, the firmware {}",
            mode.name(),
            got.len(),
            want.len()
        ));
    }
    let differ = want.iter().zip(got).filter(|(w, g)| w != g).count();
    match want.iter().zip(got).find(|(w, g)| w != g) {
        None => Ok(()),
        Some((w, g)) => Err(format!(
            "mode={}: {differ} of {} records differ from the firmware; first at sample {}: \
             firmware velocity {:#010x} force {:#010x} flags {:#04x}, C example velocity \
             {:#010x} force {:#010x} flags {:#04x}",
            mode.name(),
            want.len(),
            w.0,
            w.1,
            w.2,
            w.3,
            g.1,
            g.2,
            g.3
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_records_and_fields() {
        let out =
            "boot x\nstart period_ticks=1 alpha=0x3e19999a\ns 0 7fc00000 00000000 05 04 473\n\
                   s 1 bc241000 c144f8d1 00 00 477\nsummary steps=2\n";
        assert_eq!(
            records(out).unwrap(),
            [(0, 0x7fc0_0000, 0, 5), (1, 0xbc24_1000, 0xc144_f8d1, 0)]
        );
        assert_eq!(field(out, "start ", "alpha"), Some("0x3e19999a"));
        assert_eq!(field(out, "summary ", "steps"), Some("2"));
        assert!(records("s 0 zz 0 0").is_err());
        let w = [(0, 1, 2, 3)];
        assert!(compare(Mode::Exact, &w, &w).is_ok());
        let e = compare(Mode::Exact, &w, &[(0, 1, 9, 3)]).unwrap_err();
        assert!(e.contains("first at sample 0"), "{e}");
    }

    #[test]
    fn writes_the_inputs_format() {
        let b = inputs(Mode::Table, 0x3e19_999a, &[1, 2], &[(0.5, 10.0)]);
        assert_eq!(&b[..4], b"NCIN");
        assert_eq!(b.len(), 16 + 2 * 12);
        assert_eq!(u32::from_le_bytes(b[4..8].try_into().unwrap()), 1);
        assert_eq!(u32::from_le_bytes(b[12..16].try_into().unwrap()), 2);
        assert_eq!(f32::from_le_bytes(b[20..24].try_into().unwrap()), 0.5);
        assert!(f32::from_le_bytes(b[32..36].try_into().unwrap()).is_nan());
    }
}
