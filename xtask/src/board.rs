//! The STM32F407 image (`boards/nemm-stm32f407`): building and linking its two
//! configurations (the QEMU one runs in `tests/tests/qemu_board.rs`).

use crate::toolchain::{Toolchain, TARGET};
use crate::{run, Paths};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The board crate's directory, relative to the workspace root.
pub const DIR: &str = "boards/nemm-stm32f407";
/// The binary's name.
const BIN: &str = "nemm-stm32f407";

/// The built board images.
#[derive(Debug, Clone)]
pub struct BoardImages {
    /// What is flashed to the board (no `qemu` feature).
    pub board: PathBuf,
    /// The same image for QEMU's netduinoplus2 (`qemu` feature: no RCC waits, semihosting).
    pub qemu: PathBuf,
}

impl BoardImages {
    /// The images with their names in the reports.
    pub fn named(&self) -> [(&'static str, &Path); 2] {
        [
            ("stm32f407 board", &self.board),
            ("stm32f407 qemu", &self.qemu),
        ]
    }
}

/// The cargo arguments of the `qemu` build: the feature, and the memory layout of QEMU's
/// netduinoplus2 (`netduinoplus2.x`: no CCM, 192 KiB of SRAM) in place of the board's
/// (`NEMM_MEMORY_X` of the crate's `.cargo/config.toml`).
fn qemu_args(dir: &Path) -> Vec<String> {
    let layout = dir.join("netduinoplus2.x");
    vec![
        "--features".into(),
        "qemu".into(),
        "--config".into(),
        format!("env.NEMM_MEMORY_X.value={:?}", layout.display().to_string()),
    ]
}

/// Where the board builds go: `<workspace target dir>/nemm-stm32f407`.
fn target_dir(paths: &Paths) -> PathBuf {
    paths.target.join(BIN)
}

/// Builds the board image with and without the `qemu` feature and copies both to
/// `<target>/nemm-stm32f407/images`.
pub fn build(tc: &Toolchain, paths: &Paths) -> Result<BoardImages, String> {
    let dir = paths.root.join(DIR);
    let target = target_dir(paths);
    let out = target.join(TARGET).join("release").join(BIN);
    let images = target.join("images");
    std::fs::create_dir_all(&images).map_err(|e| format!("{}: {e}", images.display()))?;
    let t = Instant::now();
    let mut built = Vec::new();
    for (features, name) in [
        (Vec::new(), "nemm-stm32f407.elf"),
        (qemu_args(&dir), "nemm-stm32f407-qemu.elf"),
    ] {
        run(tc
            .cargo("build", &dir, &target)
            .args(["--release", "--bin", BIN])
            .args(features))?;
        let dst = images.join(name);
        std::fs::copy(&out, &dst)
            .map_err(|e| format!("copy {} to {}: {e}", out.display(), dst.display()))?;
        built.push(dst);
    }
    eprintln!(
        "xtask: stm32f407 image built in {:.0} s: {}",
        t.elapsed().as_secs_f64(),
        images.display()
    );
    let qemu = built.pop().ok_or("no qemu image")?;
    let board = built.pop().ok_or("no board image")?;
    Ok(BoardImages { board, qemu })
}

/// Lints the board crate for the target (clippy, warnings denied), both configurations.
pub fn clippy(tc: &Toolchain, paths: &Paths) -> Result<(), String> {
    let dir = paths.root.join(DIR);
    let target = target_dir(paths);
    for features in [qemu_args(&dir), Vec::new()] {
        run(tc
            .cargo("clippy", &dir, &target)
            .args(["--release", "--bins"])
            .args(features)
            .args(["--", "-D", "warnings"]))?;
    }
    Ok(())
}
