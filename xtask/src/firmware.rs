//! Building the firmware configurations once per run, and running its images in QEMU.

use crate::toolchain::{Toolchain, TARGET};
use crate::{run, Paths};
use nemm_elf::{Elf, MemoryUse};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

/// A QEMU board the firmware builds for (`nemm-firmware`'s board features).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Board {
    /// `mps2-an386`: Cortex-M4 with FPU (the default image).
    An386,
    /// `mps2-an500`: Cortex-M7 with FPU.
    An500,
}

impl Board {
    /// Both boards, the default image first.
    pub const ALL: [Board; 2] = [Board::An386, Board::An500];

    /// QEMU's machine name, which is also the cargo feature and the `board=` of the boot
    /// line.
    pub fn machine(self) -> &'static str {
        match self {
            Board::An386 => "mps2-an386",
            Board::An500 => "mps2-an500",
        }
    }

    /// QEMU's CPU name.
    pub fn cpu(self) -> &'static str {
        match self {
            Board::An386 => "cortex-m4",
            Board::An500 => "cortex-m7",
        }
    }

    /// The cargo features that select it (the default features select the AN386).
    fn features(self) -> &'static [&'static str] {
        match self {
            Board::An386 => &[],
            Board::An500 => &["--no-default-features", "--features", "mps2-an500"],
        }
    }

    /// Suffix of its image files (`nemm-firmware<suffix>.elf`).
    fn suffix(self) -> &'static str {
        match self {
            Board::An386 => "",
            Board::An500 => "-an500",
        }
    }
}

/// The built images of one board (copied out of cargo's output, which each configuration
/// overwrites).
#[derive(Debug, Clone)]
pub struct Images {
    /// The board they run on.
    pub board: Board,
    /// The application, `qemu` feature.
    pub app: PathBuf,
    /// The application as flashed to a board (no `qemu` feature).
    pub app_release: PathBuf,
    /// The step benchmark, `qemu` feature.
    pub bench: PathBuf,
}

impl Images {
    /// The images with their names in the reports: board build, qemu build, benchmark (with
    /// the board's name for the AN500).
    pub fn named(&self) -> [(String, &Path); 3] {
        let tag = match self.board {
            Board::An386 => String::new(),
            b => format!(" ({})", b.machine()),
        };
        [
            (format!("board build{tag}"), &self.app_release),
            (format!("qemu build{tag}"), &self.app),
            (format!("benchmark{tag}"), &self.bench),
        ]
    }
}

impl Images {
    /// Points the QEMU tests (`tests/src/firmware.rs`) at these images and this board.
    pub fn test_env(&self, cmd: &mut Command, tc: &Toolchain) {
        cmd.env("NEMM_FIRMWARE_ELF", &self.app)
            .env("NEMM_FIRMWARE_RELEASE_ELF", &self.app_release)
            .env("NEMM_BENCH_ELF", &self.bench)
            .env("NEMM_QEMU_MACHINE", self.board.machine())
            .env("NEMM_QEMU_CPU", self.board.cpu())
            .env("NEMM_QEMU", &tc.qemu);
    }
}

/// Firmware options of the stack measurement runs: a short replay (the peak is at boot),
/// in each evaluation mode.
pub const STACK_RUNS: [(&str, &[&str]); 2] = [
    ("exact", &["samples=2000", "mode=exact"]),
    ("table", &["samples=2000", "mode=table"]),
];

/// Instructions per SysTick tick: `-icount shift=0` runs one instruction per emulated
/// nanosecond, and SysTick counts the MPS2 core clock of 25 MHz (both boards).
pub const INSTRUCTIONS_PER_TICK: u64 = 40;

/// Stack and boot figures of one QEMU run of the application.
#[derive(Debug, Clone, Copy)]
pub struct StackFigures {
    /// Stack used when the boot ends (`boot_stack` of the `start` line, by stack painting,
    /// bytes): decoding the weights and building the estimator.
    pub boot: u64,
    /// Stack used by the whole run (`stack_used` of the `summary` line, bytes).
    pub peak: u64,
    /// The room the memory layout leaves the stack (`_stack_start - _stack_end`, bytes).
    pub room: u64,
    /// Instructions from reset to the estimator ready and the sample timer about to start
    /// (`boot_ticks` of the `start` line x [`INSTRUCTIONS_PER_TICK`]); the first step runs
    /// one sample period (100 us) later.
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

    /// `stored`, `built` or `none`: where table mode's tables came from at boot.
    pub fn tables(&self) -> &'static str {
        match self.tables_stored {
            Some(true) => "stored",
            Some(false) => "built",
            None => "none",
        }
    }
}

/// Runs the qemu build of the application with `options` and reads its stack and boot
/// figures.
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
    let (code, out) = run_qemu(tc, images.board, &images.app, &options)?;
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
            .map_err(|e| format!("{key} in the `{line}` line: {e}"))
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
        boot_instructions: value("start", "boot_ticks")? * INSTRUCTIONS_PER_TICK,
        tables_stored: tables.map(|t| t == "stored"),
    })
}

/// Where the firmware builds go: `<workspace target dir>/nemm-firmware`.
pub fn target_dir(paths: &Paths) -> PathBuf {
    paths.target.join("nemm-firmware")
}

/// Builds the two configurations of `board` (release with `qemu`: application and
/// benchmark; release without: the board application) and copies the images to
/// `<target>/nemm-firmware/images`.
pub fn build(tc: &Toolchain, paths: &Paths, board: Board) -> Result<Images, String> {
    let dir = paths.root.join("nemm-firmware");
    let target = target_dir(paths);
    let out = target.join(TARGET).join("release");
    let images = target.join("images");
    std::fs::create_dir_all(&images).map_err(|e| format!("{}: {e}", images.display()))?;
    // `<bin>` from cargo's output to `<bin><board suffix><tag>.elf`.
    let copy = |bin: &str, tag: &str| -> Result<PathBuf, String> {
        let (src, dst) = (
            out.join(bin),
            images.join(format!("{bin}{}{tag}.elf", board.suffix())),
        );
        std::fs::copy(&src, &dst)
            .map_err(|e| format!("copy {} to {}: {e}", src.display(), dst.display()))?;
        Ok(dst)
    };
    let t = Instant::now();
    run(tc
        .cargo("build", &dir, &target)
        .args(["--release", "--bins"])
        .args(board.features())
        .args(["--features", "qemu,bench"]))?;
    let app = copy("nemm-firmware", "-qemu")?;
    let bench = copy("nemm-bench", "-qemu")?;
    run(tc
        .cargo("build", &dir, &target)
        .args(["--release", "--bin", "nemm-firmware"])
        .args(board.features()))?;
    let app_release = copy("nemm-firmware", "")?;
    eprintln!(
        "xtask: firmware for {} built in {:.0} s: {}",
        board.machine(),
        t.elapsed().as_secs_f64(),
        images.display()
    );
    Ok(Images {
        board,
        app,
        app_release,
        bench,
    })
}

/// Builds the images of every board in `boards`.
pub fn build_all(tc: &Toolchain, paths: &Paths, boards: &[Board]) -> Result<Vec<Images>, String> {
    boards.iter().map(|&b| build(tc, paths, b)).collect()
}

/// Lints the firmware crate for the target (clippy, warnings denied), both configurations of
/// both boards.
pub fn clippy(tc: &Toolchain, paths: &Paths) -> Result<(), String> {
    let dir = paths.root.join("nemm-firmware");
    let target = target_dir(paths);
    for board in Board::ALL {
        for qemu in [&["--features", "qemu,bench"][..], &[]] {
            run(tc
                .cargo("clippy", &dir, &target)
                .args(["--release", "--bins", "--lib"])
                .args(board.features())
                .args(qemu)
                .args(["--", "-D", "warnings"]))?;
        }
    }
    Ok(())
}

/// A QEMU command for `elf` on `board` with the instruction counter on and the firmware
/// options `args`.
pub fn qemu_command(tc: &Toolchain, board: Board, elf: &Path, args: &[String]) -> Command {
    let mut semihosting = String::from("enable=on,target=native,arg=nemm-firmware");
    for a in args {
        semihosting += &format!(",arg={a}");
    }
    let mut c = Command::new(&tc.qemu);
    c.args([
        "-cpu",
        board.cpu(),
        "-machine",
        board.machine(),
        "-nographic",
    ])
    .args(["-monitor", "none", "-serial", "none"])
    .args(["-icount", "shift=0,sleep=off"])
    .args(["-semihosting-config", &semihosting])
    .arg("-kernel")
    .arg(elf)
    .stdin(Stdio::null());
    c
}

/// Runs `elf` in QEMU on `board` and returns its exit code and output.
pub fn run_qemu(
    tc: &Toolchain,
    board: Board,
    elf: &Path,
    args: &[String],
) -> Result<(i32, String), String> {
    let out = qemu_command(tc, board, elf, args)
        .stderr(Stdio::inherit())
        .output()
        .map_err(|e| format!("cannot run {}: {e}", tc.qemu.display()))?;
    Ok((
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    ))
}

/// A weights slot of `capacity` bytes holding `blob` (the `nemm-slot` format: `NWSL`,
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
