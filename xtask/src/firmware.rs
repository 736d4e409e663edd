//! Building the firmware configurations once per run, and running its images in QEMU.

use crate::toolchain::{Toolchain, TARGET};
use crate::{run, Paths};
use nemm_elf::{Elf, MemoryUse};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

/// The built images (copied out of cargo's output, which each configuration overwrites).
#[derive(Debug, Clone)]
pub struct Images {
    /// The application, `qemu` feature.
    pub app: PathBuf,
    /// The application as flashed to a board (no `qemu` feature).
    pub app_release: PathBuf,
    /// The step benchmark, `qemu` feature.
    pub bench: PathBuf,
}

impl Images {
    /// The images with their names in the reports: board build, qemu build, benchmark.
    pub fn named(&self) -> [(&'static str, &Path); 3] {
        [
            ("board build", &self.app_release),
            ("qemu build", &self.app),
            ("benchmark", &self.bench),
        ]
    }
}

/// Firmware options of the stack measurement runs: a short replay (the peak is at boot),
/// in each evaluation mode.
pub const STACK_RUNS: [(&str, &[&str]); 2] = [
    ("exact", &["samples=2000", "mode=exact"]),
    ("table", &["samples=2000", "mode=table"]),
];

/// Stack figures of one QEMU run of the application, by stack painting (bytes).
#[derive(Debug, Clone, Copy)]
pub struct StackFigures {
    /// Used when the boot ends (`boot_stack` of the `start` line): decoding the weights and
    /// building the estimator.
    pub boot: u64,
    /// Used by the whole run (`stack_used` of the `summary` line).
    pub peak: u64,
    /// The room the memory layout leaves the stack (`_stack_start - _stack_end`).
    pub room: u64,
    /// QEMU instructions of the boot (`boot_ticks` of the `start` line times
    /// [`crate::bench::INSTRUCTIONS_PER_TICK`]): from the start of `init` to the end of the estimator's
    /// loading (decoding the weights, and building or reading the tables in table mode).
    pub boot_instructions: u64,
    /// Table mode: whether the tables were read from the blob (`tables=stored` of the
    /// `weights ok` line) rather than built at boot; `None` without tables.
    pub tables_stored: Option<bool>,
}

impl StackFigures {
    /// `boot-stack bytes=<boot> mode=<mode> peak=<peak> room=<room>`.
    pub fn line(&self, mode: &str) -> String {
        format!(
            "boot-stack bytes={} mode={mode} peak={} room={}",
            self.boot, self.peak, self.room
        )
    }

    /// `boot-instructions n=<boot_instructions> mode=<mode> tables=<stored|built|none>`.
    pub fn boot_line(&self, mode: &str) -> String {
        let tables = match self.tables_stored {
            Some(true) => "stored",
            Some(false) => "built",
            None => "none",
        };
        format!(
            "boot-instructions n={} mode={mode} tables={tables}",
            self.boot_instructions
        )
    }
}

/// Runs the qemu build of the application with `options` and reads its stack figures.
pub fn stack_figures(
    tc: &Toolchain,
    images: &Images,
    options: &[&str],
) -> Result<StackFigures, String> {
    let elf = Elf::read(&images.app)?;
    let symbol = |name: &str| {
        elf.symbol(name)
            .map(|s| u64::from(s.value))
            .ok_or_else(|| format!("{}: no symbol {name}", images.app.display()))
    };
    let room = symbol("_stack_start")? - symbol("_stack_end")?;
    let options: Vec<String> = options.iter().map(|o| o.to_string()).collect();
    let (code, out) = run_qemu(tc, &images.app, &options)?;
    if code != 0 {
        return Err(format!("the firmware exited with {code}:\n{out}"));
    }
    let value = |line: &str, key: &str| -> Result<u64, String> {
        let prefix = format!("{key}=");
        out.lines()
            .filter(|l| l.starts_with(&format!("{line} ")))
            .flat_map(|l| l.split_ascii_whitespace())
            .find_map(|w| w.strip_prefix(prefix.as_str()))
            .ok_or_else(|| format!("no `{key}` in the firmware's `{line}` line:\n{out}"))?
            .parse()
            .map_err(|e| format!("{key}: {e}"))
    };
    let tables = out
        .lines()
        .filter(|l| l.starts_with("weights ok "))
        .flat_map(|l| l.split_ascii_whitespace())
        .find_map(|w| w.strip_prefix("tables="));
    Ok(StackFigures {
        boot: value("start", "boot_stack")?,
        peak: value("summary", "stack_used")?,
        room,
        boot_instructions: value("start", "boot_ticks")? * crate::bench::INSTRUCTIONS_PER_TICK,
        tables_stored: tables.map(|t| t == "stored"),
    })
}

/// Where the firmware builds go: `<workspace target dir>/nemm-firmware`.
pub fn target_dir(paths: &Paths) -> PathBuf {
    paths.target.join("nemm-firmware")
}

/// Builds the two configurations (release with `qemu`: application and benchmark; release
/// without: the board application) and copies the images to `<target>/nemm-firmware/images`.
pub fn build(tc: &Toolchain, paths: &Paths) -> Result<Images, String> {
    let dir = paths.root.join("nemm-firmware");
    let target = target_dir(paths);
    let out = target.join(TARGET).join("release");
    let images = target.join("images");
    std::fs::create_dir_all(&images).map_err(|e| format!("{}: {e}", images.display()))?;
    let copy = |from: &str, to: &str| -> Result<PathBuf, String> {
        let (src, dst) = (out.join(from), images.join(to));
        std::fs::copy(&src, &dst)
            .map_err(|e| format!("copy {} to {}: {e}", src.display(), dst.display()))?;
        Ok(dst)
    };
    let t = Instant::now();
    run(tc
        .cargo("build", &dir, &target)
        .args(["--release", "--features", "qemu", "--bins"]))?;
    let app = copy("nemm-firmware", "nemm-firmware-qemu.elf")?;
    let bench = copy("nemm-bench", "nemm-bench-qemu.elf")?;
    run(tc
        .cargo("build", &dir, &target)
        .args(["--release", "--bin", "nemm-firmware"]))?;
    let app_release = copy("nemm-firmware", "nemm-firmware.elf")?;
    eprintln!(
        "xtask: firmware built in {:.0} s: {}",
        t.elapsed().as_secs_f64(),
        images.display()
    );
    Ok(Images {
        app,
        app_release,
        bench,
    })
}

/// Lints the firmware crate for the target (clippy, warnings denied), both configurations.
pub fn clippy(tc: &Toolchain, paths: &Paths) -> Result<(), String> {
    let dir = paths.root.join("nemm-firmware");
    let target = target_dir(paths);
    for features in [&["--features", "qemu"][..], &[]] {
        run(tc
            .cargo("clippy", &dir, &target)
            .args(["--release", "--bins", "--lib"])
            .args(features)
            .args(["--", "-D", "warnings"]))?;
    }
    Ok(())
}

/// A QEMU command for `elf` with the instruction counter on and the firmware options `args`.
pub fn qemu_command(tc: &Toolchain, elf: &Path, args: &[String]) -> Command {
    let mut semihosting = String::from("enable=on,target=native,arg=nemm-firmware");
    for a in args {
        semihosting += &format!(",arg={a}");
    }
    let mut c = Command::new(&tc.qemu);
    c.args(["-cpu", "cortex-m4", "-machine", "mps2-an386", "-nographic"])
        .args(["-monitor", "none", "-serial", "none"])
        .args(["-icount", "shift=0,sleep=off"])
        .args(["-semihosting-config", &semihosting])
        .arg("-kernel")
        .arg(elf)
        .stdin(Stdio::null());
    c
}

/// Runs `elf` in QEMU and returns its exit code and output.
pub fn run_qemu(tc: &Toolchain, elf: &Path, args: &[String]) -> Result<(i32, String), String> {
    let out = qemu_command(tc, elf, args)
        .stderr(Stdio::inherit())
        .output()
        .map_err(|e| format!("cannot run {}: {e}", tc.qemu.display()))?;
    Ok((
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    ))
}

/// A weights slot of `capacity` bytes holding `blob` (`nemm-firmware/src/slot.rs`: `NWSL`,
/// length, blob, erased flash).
pub fn slot(blob: &[u8], capacity: usize) -> Result<Vec<u8>, String> {
    let mut s = vec![0; capacity];
    crate::slot::encode(blob, &mut s).map_err(|e| {
        format!(
            "a {}-byte blob does not fit the {capacity}-byte weights slot ({e:?})",
            blob.len()
        )
    })?;
    Ok(s)
}

/// `elf` with `blob` in its weights slot, written to `path`.
pub fn with_weights(elf: &Elf, blob: &[u8], path: &Path) -> Result<(), String> {
    let capacity = elf
        .section(".nemm_weights")
        .ok_or("the image has no .nemm_weights section")?
        .size as usize;
    let bytes = elf.patched(".nemm_weights", &slot(blob, capacity)?)?;
    std::fs::write(path, bytes).map_err(|e| format!("{}: {e}", path.display()))
}

/// The memory report of an image: flash, RAM, and what takes them.
pub fn memory_report(name: &str, elf: &Elf) -> String {
    let m: MemoryUse = elf.memory_use();
    let code = m.size_of(".vector_table") + m.size_of(".text");
    format!(
        "{name}: flash {} B ({:.1} KiB) = code {code} + rodata {} + trace {} + weights slot {} \
         + data {}; RAM {} B ({:.1} KiB) of statics = data {} + bss {} + uninit {} (the stack \
         takes the rest of RAM)",
        m.flash,
        f64::from(m.flash) / 1024.0,
        m.size_of(".rodata"),
        m.size_of(".nemm_trace"),
        m.size_of(".nemm_weights"),
        m.size_of(".data"),
        m.ram,
        f64::from(m.ram) / 1024.0,
        m.size_of(".data"),
        m.size_of(".bss"),
        m.size_of(".uninit"),
    )
}
