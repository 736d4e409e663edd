//! The cycle model: estimated core cycles of an estimator step on a real Cortex-M4F or
//! Cortex-M7, from the dynamic instruction mix of the step traced in QEMU.
//!
//! QEMU counts instructions, not cycles. [`trace_mix`] runs the benchmark image under QEMU's
//! gdb stub, stops at `Estimator::step` (or, [`observer_mix`], at the benchmark's
//! `observer_step`, one step of the alpha observer), single-steps whole steps and classifies every
//! executed instruction by its Thumb-2 encoding ([`classify`]), noting each control
//! transfer (the next PC is not the following instruction). [`Chip::cycles`] then prices the
//! mix with per-class costs. Both models assume zero-wait-state memory (the M4F's SRAM with
//! the flash accelerator keeping up with straight-line code; the M7's TCM or cache hits) and
//! add no interrupt or bus contention.
//!
//! **Cortex-M4F** (Arm Cortex-M4 TRM, DDI 0439, "Processor instruction timings" and the FPU
//! chapter's "FPU instruction set" table): single issue; ALU, `MUL`, `IT`, FP add/multiply/
//! move 1 cycle; `VFMA`/`VMLA` and relatives 3; `VDIV`/`VSQRT` 14; `LDR` 2 (the TRM's 1 for a
//! load pipelined after another is not modelled), `STR` 1, `LDRD`/`STRD` 3, `LDM`/`STM`/
//! `PUSH`/`POP` and `VLDM`/`VSTM`/`VPUSH`/`VPOP` 1 + N words, `VLDR`/`VSTR` 2, `VMOV` of two
//! core registers 2, `SDIV`/`UDIV` 7 (the TRM's 2 to 12); a control transfer adds a pipeline
//! refill of 2 (the TRM's 1 to 3). Uncertainty about +-15 %.
//!
//! **Cortex-M7**: Arm publishes no per-instruction timing for it (the TRM, DDI 0489, gives the
//! pipeline: in-order, six stages, dual issue, 64-bit instruction fetch and 64-bit loads from
//! TCM, branch prediction). The costs are effective cycles per instruction in a dual-issuing
//! stream, after published measurements on an STM32H7 at 480 MHz with caches on (Quinapalus,
//! "Cortex-M7 instruction cycle counts, timings, and dual-issue combinations"): ALU
//! instructions and `IT` pair with their neighbours (0.5); loads and stores 1 (`LDRD`/`STRD`
//! and two-register `VMOV` 1: one 64-bit access); `LDM`/`STM`/`VLDM`/`VSTM` 1 + N/2 (two
//! words per cycle); FP add/multiply/move 1; `VFMA` 3, because the network kernels accumulate
//! each output in one register in a fixed order (the order that makes them bit-identical to
//! the portable code), so consecutive multiply-adds wait for the previous result (a 3-cycle
//! FP result latency, as in LLVM's Cortex-M7 scheduling model `ARMScheduleM7.td`: `llvm-mca
//! -mcpu=cortex-m7` runs a chain of dependent `vfma.f32` at 3.0 cycles each, the same as
//! `-mcpu=cortex-m4`); `VDIV`/`VSQRT` 16 (that model's latency); `MUL` 1, `SDIV`/`UDIV` 7; a
//! control transfer adds 1 (mostly predicted; a misprediction costs about 8). Uncertainty
//! about +-30 %: the `VFMA` latency (+-1 cycle moves the NEMM's exact step by about +-30 %)
//! and the pairing rate dominate.
//!
//! The boards' DWT cycle counters measure what this estimates (`boards/nemm-stm32f407`
//! reports `worst_step_cycles`).

use crate::firmware::{self, Board, Images};
use crate::toolchain::Toolchain;
use crate::{Mode, Paths, Variant};
use nemm_elf::Elf;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

/// A core with a cycle model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chip {
    /// Cortex-M4F (STM32F4 class).
    M4f,
    /// Cortex-M7 (STM32F7 / STM32H7 class).
    M7,
}

impl Chip {
    /// The cycle model of `board`'s core.
    pub fn of(board: Board) -> Self {
        match board {
            Board::An386 => Chip::M4f,
            Board::An500 => Chip::M7,
        }
    }

    /// Name in the output lines.
    pub fn name(self) -> &'static str {
        match self {
            Chip::M4f => "m4f",
            Chip::M7 => "m7",
        }
    }

    /// The core clocks \[MHz\] the budget is stated at: an STM32F407 (168); an STM32F7 (216)
    /// and an STM32H7 (480).
    pub fn clocks_mhz(self) -> &'static [u32] {
        match self {
            Chip::M4f => &[168],
            Chip::M7 => &[216, 480],
        }
    }

    /// Cycles of one instruction of `class`, without the control-transfer penalty.
    pub fn cost(self, class: Class) -> f64 {
        use Class::*;
        let m4 = self == Chip::M4f;
        match class {
            Alu | It => {
                if m4 {
                    1.0
                } else {
                    0.5
                }
            }
            Branch | Mul | FpAlu | Other | Store => 1.0,
            Div => 7.0,
            Load | FpLoad | FpStore => {
                if m4 {
                    2.0
                } else {
                    1.0
                }
            }
            LoadDual | StoreDual => {
                if m4 {
                    3.0
                } else {
                    1.0
                }
            }
            FpMovPair => {
                if m4 {
                    2.0
                } else {
                    1.0
                }
            }
            FpMac => 3.0,
            FpDivSqrt => {
                if m4 {
                    14.0
                } else {
                    16.0
                }
            }
            LoadMultiple(n) | StoreMultiple(n) | FpLoadMultiple(n) | FpStoreMultiple(n) => {
                if m4 {
                    1.0 + f64::from(n)
                } else {
                    1.0 + f64::from(n) / 2.0
                }
            }
        }
    }

    /// Extra cycles of an instruction after which the PC does not run on to the next one
    /// (pipeline refill; the M7 predicts most of its branches).
    pub fn transfer_penalty(self) -> f64 {
        match self {
            Chip::M4f => 2.0,
            Chip::M7 => 1.0,
        }
    }

    /// Estimated cycles of `mix`.
    pub fn cycles(self, mix: &Mix) -> f64 {
        mix.counts
            .iter()
            .map(|&(class, n)| self.cost(class) * n as f64)
            .sum::<f64>()
            + self.transfer_penalty() * mix.transfers as f64
    }
}

/// Instruction classes of the cycle model. `N` is the number of 32-bit words moved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Class {
    /// Integer data processing, moves, compares, shifts, extends.
    Alu,
    /// `IT`.
    It,
    /// Branches (`B`, `BL`, `BX`, `BLX`, `CBZ`, `CBNZ`).
    Branch,
    /// Integer multiplies (and multiply-accumulates).
    Mul,
    /// `SDIV`, `UDIV`.
    Div,
    /// Single loads (`LDR*`, `TBB`/`TBH`, `LDREX`).
    Load,
    /// Single stores.
    Store,
    /// `LDRD`.
    LoadDual,
    /// `STRD`.
    StoreDual,
    /// `LDM`, `POP` (N registers).
    LoadMultiple(u32),
    /// `STM`, `PUSH` (N registers).
    StoreMultiple(u32),
    /// FP arithmetic other than multiply-accumulate, divide and square root; FP moves,
    /// conversions, compares, `VMRS`.
    FpAlu,
    /// `VFMA`, `VFMS`, `VFNMA`, `VFNMS`, `VMLA`, `VMLS`, `VNMLA`, `VNMLS`.
    FpMac,
    /// `VDIV`, `VSQRT`.
    FpDivSqrt,
    /// `VLDR`.
    FpLoad,
    /// `VSTR`.
    FpStore,
    /// `VLDM`, `VPOP` (N words).
    FpLoadMultiple(u32),
    /// `VSTM`, `VPUSH` (N words).
    FpStoreMultiple(u32),
    /// `VMOV` between two core registers and two single or one double FP register.
    FpMovPair,
    /// Hints, barriers, system register access, supervisor calls.
    Other,
}

/// Whether a first halfword starts a 32-bit Thumb-2 instruction.
pub fn is_wide(hw1: u16) -> bool {
    matches!(hw1 >> 11, 0b11101..=0b11111)
}

/// The class of the Thumb instruction whose first halfword is `hw1` (and second `hw2`, for
/// a 32-bit one; ignored otherwise).
pub fn classify(hw1: u16, hw2: u16) -> Class {
    if is_wide(hw1) {
        classify_wide(hw1, hw2)
    } else {
        classify_narrow(hw1)
    }
}

/// The number of registers in a register-list field.
fn words(bits: u32) -> u32 {
    bits.count_ones()
}

/// The class of a 16-bit Thumb instruction.
fn classify_narrow(hw: u16) -> Class {
    use Class::*;
    match hw {
        _ if hw & 0xFF00 == 0xBF00 => {
            if hw & 0xF != 0 {
                It
            } else {
                Other
            }
        }
        _ if hw & 0xF000 == 0xD000 => {
            if (hw >> 9) & 0x7 == 0x7 {
                Other // UDF, SVC
            } else {
                Branch
            }
        }
        _ if hw & 0xF800 == 0xE000 => Branch,
        _ if hw & 0xFF00 == 0x4700 => Branch,
        _ if hw & 0xF500 == 0xB100 => Branch,
        _ if hw & 0xFE00 == 0xB400 => StoreMultiple(words(u32::from(hw & 0x1FF))),
        _ if hw & 0xFE00 == 0xBC00 => LoadMultiple(words(u32::from(hw & 0x1FF))),
        _ if hw & 0xF800 == 0xC000 => StoreMultiple(words(u32::from(hw & 0xFF))),
        _ if hw & 0xF800 == 0xC800 => LoadMultiple(words(u32::from(hw & 0xFF))),
        _ if hw & 0xF800 == 0x4800 => Load,
        _ if hw & 0xF000 == 0x5000 => {
            if (hw >> 9) & 0x7 <= 2 {
                Store
            } else {
                Load
            }
        }
        _ if hw & 0xE000 == 0x6000 || hw & 0xE000 == 0x8000 => {
            if hw & 0x0800 == 0 {
                Store
            } else {
                Load
            }
        }
        _ if hw & 0xFFC0 == 0x4340 => Mul,
        _ => Alu,
    }
}

/// The class of a 32-bit Thumb-2 instruction (first halfword `hw1`, second `hw2`).
fn classify_wide(hw1: u16, hw2: u16) -> Class {
    use Class::*;
    let coproc_fp = (hw2 >> 9) & 0x7 == 0b101; // cp10 / cp11
    match hw1 {
        _ if hw1 & 0xFE00 == 0xEC00 && coproc_fp => fp_transfer(hw1, hw2),
        _ if hw1 & 0xFF00 == 0xEE00 && coproc_fp => fp_data(hw1, hw2),
        _ if hw1 & 0xFE40 == 0xE800 => {
            let n = words(u32::from(hw2 & 0xDFFF));
            if hw1 & 0x10 != 0 {
                LoadMultiple(n)
            } else {
                StoreMultiple(n)
            }
        }
        _ if hw1 & 0xFE40 == 0xE840 => {
            let load = hw1 & 0x10 != 0;
            match (hw1 & 0x0120 != 0, load) {
                (true, true) => LoadDual,
                (true, false) => StoreDual,
                (false, true) => Load, // LDREX*, TBB, TBH
                (false, false) => Store,
            }
        }
        _ if hw1 & 0xFE00 == 0xEA00 => Alu,
        _ if hw1 & 0xF800 == 0xF000 => {
            if hw2 & 0x8000 == 0 {
                Alu
            } else if hw2 & 0x5000 != 0 || (hw1 >> 6) & 0xE != 0xE {
                Branch
            } else {
                Other
            }
        }
        _ if hw1 & 0xFE00 == 0xF800 => {
            if hw1 & 0x10 != 0 {
                Load
            } else {
                Store
            }
        }
        _ if hw1 & 0xFF00 == 0xFA00 => Alu,
        _ if hw1 & 0xFF80 == 0xFB00 => Mul,
        _ if hw1 & 0xFF80 == 0xFB80 => {
            let op1 = (hw1 >> 4) & 0x7;
            if (op1 == 1 || op1 == 3) && (hw2 >> 4) & 0xF == 0xF {
                Div
            } else {
                Mul
            }
        }
        _ => Other,
    }
}

/// The class of an FP load, store or core-register-pair move (a cp10 / cp11 transfer,
/// `hw1` 0xEC00-0xEDFF).
fn fp_transfer(hw1: u16, hw2: u16) -> Class {
    use Class::*;
    if hw1 & 0xFFE0 == 0xEC40 {
        FpMovPair
    } else if hw1 & 0xFF20 == 0xED00 {
        if hw1 & 0x10 != 0 {
            FpLoad
        } else {
            FpStore
        }
    } else {
        let n = u32::from(hw2 & 0xFF);
        if hw1 & 0x10 != 0 {
            FpLoadMultiple(n)
        } else {
            FpStoreMultiple(n)
        }
    }
}

/// The class of an FP data-processing instruction or a core <-> FP move (cp10 / cp11,
/// `hw1` 0xEExx).
fn fp_data(hw1: u16, hw2: u16) -> Class {
    use Class::*;
    if hw2 & 0x10 != 0 {
        return FpAlu; // VMOV core <-> FP, VMRS, VMSR
    }
    match (hw1 >> 4) & 0xB {
        0b0000 | 0b0001 | 0b1001 | 0b1010 => FpMac,
        0b1000 => FpDivSqrt,
        0b1011 if hw1 & 0xF == 0b0001 && (hw2 >> 6) & 0x3 == 0b11 => FpDivSqrt,
        _ => FpAlu,
    }
}

/// The dynamic instruction mix of the traced steps, per step.
#[derive(Debug, Clone, Default)]
pub struct Mix {
    /// Executed instructions per class (summed over the traced steps).
    pub counts: Vec<(Class, u64)>,
    /// Instructions after which the PC did not run on to the next one.
    pub transfers: u64,
    /// Instructions executed.
    pub instructions: u64,
    /// Steps traced.
    pub steps: u64,
}

impl Mix {
    fn add(&mut self, class: Class) {
        self.instructions += 1;
        match self.counts.iter_mut().find(|(c, _)| *c == class) {
            Some((_, n)) => *n += 1,
            None => self.counts.push((class, 1)),
        }
    }

    /// Estimated cycles per instruction on `chip`.
    pub fn cycles_per_instruction(&self, chip: Chip) -> f64 {
        chip.cycles(self) / self.instructions.max(1) as f64
    }

    /// Executed instructions of the classes `pick` selects, per traced step.
    pub fn per_step(&self, pick: impl Fn(Class) -> bool) -> f64 {
        let n: u64 = self
            .counts
            .iter()
            .filter(|(c, _)| pick(*c))
            .map(|&(_, n)| n)
            .sum();
        n as f64 / self.steps.max(1) as f64
    }
}

/// The cycle estimate of one model kind, integrator and mode on one chip.
#[derive(Debug, Clone)]
pub struct CycleFigures {
    /// The chip.
    pub chip: Chip,
    /// QEMU's machine.
    pub board: Board,
    /// Model kind.
    pub model: String,
    /// `rk4` or `rk3`.
    pub integrator: String,
    /// `exact` or `table`.
    pub mode: String,
    /// Instructions per step (the benchmark's `-icount` measure).
    pub instructions_per_step: u64,
    /// Estimated cycles per instruction of the traced step.
    pub cycles_per_instruction: f64,
    /// `VFMA` and relatives per traced step.
    pub fp_mac_per_step: f64,
}

impl CycleFigures {
    /// Estimated cycles per step: the measured instructions at the traced mix's cycles per
    /// instruction.
    pub fn cycles_per_step(&self) -> u64 {
        (self.instructions_per_step as f64 * self.cycles_per_instruction).round() as u64
    }

    /// The fraction of the 10 kHz period (100 us) the step takes at `mhz`.
    pub fn budget_fraction(&self, mhz: u32) -> f64 {
        self.cycles_per_step() as f64 / (f64::from(mhz) * 100.0)
    }

    /// `target-cycles chip=.. board=.. model=.. integrator=.. mode=.. instructions_per_step=..
    /// est_cycles_per_step=.. cycles_per_instruction=.. fp_mac_per_step=.. budget_<f>mhz=..`,
    /// one budget fraction per stated clock.
    pub fn line(&self) -> String {
        let mut l = format!(
            "target-cycles chip={} board={} model={} integrator={} mode={} \
             instructions_per_step={} est_cycles_per_step={} cycles_per_instruction={:.2} \
             fp_mac_per_step={:.0}",
            self.chip.name(),
            self.board.machine(),
            self.model,
            self.integrator,
            self.mode,
            self.instructions_per_step,
            self.cycles_per_step(),
            self.cycles_per_instruction,
            self.fp_mac_per_step,
        );
        for &mhz in self.chip.clocks_mhz() {
            l += &format!(" budget_{mhz}mhz={:.2}", self.budget_fraction(mhz));
        }
        l
    }
}

/// Steps of the benchmark before the traced ones (the estimator settled after its start).
const TRACE_SKIP: u32 = 40;
/// Steps traced.
const TRACE_STEPS: u32 = 2;

/// Steps of the observer benchmark before the traced one (beyond the observer's own
/// warm-up of 100 samples, so that the traced step updates the estimate).
const OBSERVER_TRACE_SKIP: u32 = 120;

/// The instruction mix of `Estimator::step` (its body `step_at`) in the benchmark image `elf` (with the blob of
/// `kind` in its slot, as [`crate::target_bench::run`] patches it), the model `variant` of
/// that kind, evaluation `mode`, integrator `integrator`: [`TRACE_STEPS`] steps after
/// [`TRACE_SKIP`], single-stepped through QEMU's gdb stub on `board`.
pub fn trace_mix(
    tc: &Toolchain,
    board: Board,
    (elf_path, variant): (&Path, Variant),
    mode: Mode,
    integrator: &str,
) -> Result<Mix, String> {
    let mut args = vec![
        format!("mode={}", mode.name()),
        format!("integrator={integrator}"),
        format!("warmup={TRACE_SKIP}"),
        format!("steps={}", TRACE_STEPS + 2),
        "calibrate=0".to_string(),
    ];
    args.extend(variant.bench_args());
    // The benchmarked estimator's, not the alpha observer's members' (`Estimator<P, 1>`: no
    // tables), whose `step_at` the image may hold outlined as well, never called here.
    let is_step = |d: &str| {
        d.contains("nemm_core::estimator::Estimator<")
            && !d.contains(", 1>>::")
            && (d.ends_with(">>::step") || d.ends_with(">>::step_at"))
    };
    trace(
        tc,
        board,
        elf_path,
        ("Estimator::step", &is_step),
        &args,
        TRACE_SKIP,
        TRACE_STEPS,
    )
}

/// The instruction mix of one step of the alpha observer (the benchmark's `observer_step`,
/// `observer=1`) in the benchmark image `elf`: one step after [`OBSERVER_TRACE_SKIP`].
pub fn observer_mix(tc: &Toolchain, board: Board, elf_path: &Path) -> Result<Mix, String> {
    let args = [
        "observer=1".to_string(),
        format!("warmup={OBSERVER_TRACE_SKIP}"),
        "steps=3".to_string(),
        "calibrate=0".to_string(),
    ];
    let is_step = |d: &str| d.ends_with("::observer_step");
    trace(
        tc,
        board,
        elf_path,
        ("observer_step", &is_step),
        &args,
        OBSERVER_TRACE_SKIP,
        1,
    )
}

/// Runs the benchmark image `elf_path` with `args` under QEMU's gdb stub on `board`, lets the
/// function `func` (its name and a test of its demangled symbol) run `skip` times, then
/// single-steps `steps` whole calls of it and returns their instruction mix.
fn trace(
    tc: &Toolchain,
    board: Board,
    elf_path: &Path,
    func: (&str, &dyn Fn(&str) -> bool),
    args: &[String],
    skip: u32,
    steps: u32,
) -> Result<Mix, String> {
    let (name, matches) = func;
    let elf = Elf::read(elf_path)?;
    let step = elf
        .functions()
        .into_values()
        .find(|s| matches(&nemm_elf::demangle(&s.name)))
        .ok_or_else(|| format!("{}: no {name} function", elf_path.display()))?
        .start();
    let code = Code::of(&elf);
    let port = free_port()?;
    let mut qemu = firmware::qemu_command(tc, board, elf_path, args);
    qemu.args(["-gdb", &format!("tcp:127.0.0.1:{port}"), "-S"])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    let child = qemu
        .spawn()
        .map_err(|e| format!("cannot run {}: {e}", tc.qemu.display()))?;
    let mut guard = KillOnDrop(child);
    let mut gdb = Gdb::connect(port)?;
    gdb.command(&format!("Z0,{step:x},2"))?;
    for _ in 0..skip {
        gdb.resume("c")?;
    }
    gdb.command(&format!("z0,{step:x},2"))?;
    let mut mix = Mix::default();
    for _ in 0..steps {
        gdb.command(&format!("Z0,{step:x},2"))?;
        gdb.resume("c")?;
        gdb.command(&format!("z0,{step:x},2"))?;
        let ret = gdb.register(14)? & !1;
        let mut pc = gdb.register(15)?;
        if pc != step {
            return Err(format!("stopped at {pc:#x}, not at {name} ({step:#x})"));
        }
        let mut n = 0u64;
        while pc != ret {
            let (class, size) = code.classify(pc)?;
            gdb.resume("s")?;
            let next = gdb.register(15)?;
            mix.add(class);
            if next != pc + size {
                mix.transfers += 1;
            }
            pc = next;
            n += 1;
            if n > 10_000_000 {
                return Err(format!("{name} did not return within 10^7 instructions"));
            }
        }
        mix.steps += 1;
    }
    let _ = guard.0.kill();
    Ok(mix)
}

/// Estimates the cycles of every benchmarked `(kind, integrator)` of `figures` (the
/// benchmark's output for `images`, mode `mode`).
pub fn estimate(
    tc: &Toolchain,
    paths: &Paths,
    images: &Images,
    mode: Mode,
    figures: &[crate::target_bench::StepFigures],
) -> Result<Vec<CycleFigures>, String> {
    let mut out = Vec::new();
    for f in figures {
        let variant = Variant::parse(&f.model)?;
        let image = crate::target_bench::image_with_example(paths, images, variant.kind)?;
        let mix = trace_mix(tc, images.board, (&image, variant), mode, &f.integrator)?;
        let chip = Chip::of(images.board);
        out.push(CycleFigures {
            chip,
            board: images.board,
            model: f.model.clone(),
            integrator: f.integrator.clone(),
            mode: f.mode.clone(),
            instructions_per_step: f.instructions_per_step,
            cycles_per_instruction: mix.cycles_per_instruction(chip),
            fp_mac_per_step: mix.per_step(|c| c == Class::FpMac),
        });
    }
    Ok(out)
}

/// The model name of the observer's rows: `<kind>-observer` (a word: it is a field of the
/// `target-cycles` line).
pub fn observer_row_name(f: &crate::target_bench::ObserverFigures) -> String {
    format!("{}-observer", f.model)
}

/// Estimates the cycles of the alpha observer's step (`figures`, the benchmark's output for
/// `images`) from the traced mix of one observer step.
pub fn estimate_observer(
    tc: &Toolchain,
    paths: &Paths,
    images: &Images,
    figures: &crate::target_bench::ObserverFigures,
) -> Result<CycleFigures, String> {
    let _ = paths;
    let mix = observer_mix(tc, images.board, &images.bench)?;
    let chip = Chip::of(images.board);
    Ok(CycleFigures {
        chip,
        board: images.board,
        model: observer_row_name(figures),
        integrator: figures.integrator.clone(),
        mode: if figures.levels_from == "blob" {
            "table".into()
        } else {
            "exact".into()
        },
        instructions_per_step: figures.instructions_per_step,
        cycles_per_instruction: mix.cycles_per_instruction(chip),
        fp_mac_per_step: mix.per_step(|c| c == Class::FpMac),
    })
}

/// The executable sections of an image, for classifying the instruction at an address.
struct Code {
    sections: Vec<(u32, Vec<u8>)>,
}

impl Code {
    fn of(elf: &Elf) -> Self {
        let sections = elf
            .sections
            .iter()
            .filter(|s| s.is_exec() && s.has_bits())
            .filter_map(|s| Some((s.addr, elf.section_data(&s.name).ok()?.to_vec())))
            .collect();
        Self { sections }
    }

    fn halfword(&self, addr: u32) -> Option<u16> {
        self.sections.iter().find_map(|(base, bytes)| {
            let at = usize::try_from(addr.checked_sub(*base)?).ok()?;
            let b = bytes.get(at..at + 2)?;
            Some(u16::from_le_bytes([b[0], b[1]]))
        })
    }

    /// The class and size of the instruction at `pc`.
    fn classify(&self, pc: u32) -> Result<(Class, u32), String> {
        let hw1 = self
            .halfword(pc)
            .ok_or_else(|| format!("executed {pc:#x}, outside the image's code"))?;
        if is_wide(hw1) {
            let hw2 = self
                .halfword(pc + 2)
                .ok_or_else(|| format!("executed {pc:#x}, outside the image's code"))?;
            Ok((classify(hw1, hw2), 4))
        } else {
            Ok((classify(hw1, 0), 2))
        }
    }
}

/// Kills QEMU when the trace ends, however it ends.
struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A free TCP port on the loopback interface for QEMU's gdb stub.
fn free_port() -> Result<u16, String> {
    let l = TcpListener::bind("127.0.0.1:0").map_err(|e| format!("no free port: {e}"))?;
    l.local_addr()
        .map(|a| a.port())
        .map_err(|e| format!("no free port: {e}"))
}

/// A minimal client of the gdb remote serial protocol (QEMU 7.2's stub has no no-ack mode:
/// every packet received is acknowledged; its acknowledgements are skipped).
struct Gdb {
    reader: BufReader<TcpStream>,
    writer: TcpStream,
}

impl Gdb {
    fn connect(port: u16) -> Result<Self, String> {
        let started = Instant::now();
        let stream = loop {
            match TcpStream::connect(("127.0.0.1", port)) {
                Ok(s) => break s,
                Err(e) if started.elapsed() > Duration::from_secs(20) => {
                    return Err(format!("QEMU's gdb stub on port {port}: {e}"))
                }
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        let _ = stream.set_nodelay(true);
        stream
            .set_read_timeout(Some(Duration::from_secs(120)))
            .map_err(|e| e.to_string())?;
        let writer = stream.try_clone().map_err(|e| e.to_string())?;
        Ok(Self {
            reader: BufReader::new(stream),
            writer,
        })
    }

    fn send(&mut self, data: &str) -> Result<(), String> {
        let sum = data.bytes().fold(0u8, |s, b| s.wrapping_add(b));
        self.writer
            .write_all(format!("${data}#{sum:02x}").as_bytes())
            .map_err(|e| format!("gdb stub: {e}"))
    }

    fn receive(&mut self) -> Result<String, String> {
        let mut byte = [0u8];
        loop {
            self.reader
                .read_exact(&mut byte)
                .map_err(|e| format!("gdb stub: {e}"))?;
            if byte[0] == b'$' {
                break;
            }
        }
        let mut data = Vec::new();
        self.reader
            .read_until(b'#', &mut data)
            .map_err(|e| format!("gdb stub: {e}"))?;
        data.pop();
        let mut sum = [0u8; 2];
        self.reader
            .read_exact(&mut sum)
            .map_err(|e| format!("gdb stub: {e}"))?;
        self.writer
            .write_all(b"+")
            .map_err(|e| format!("gdb stub: {e}"))?;
        Ok(String::from_utf8_lossy(&data).into_owned())
    }

    /// Sends `data`, expects `OK`.
    fn command(&mut self, data: &str) -> Result<(), String> {
        self.send(data)?;
        match self.receive()?.as_str() {
            "OK" => Ok(()),
            r => Err(format!("gdb stub: `{data}` answered `{r}`")),
        }
    }

    /// `c` or `s`; expects a stop by trap.
    fn resume(&mut self, how: &str) -> Result<(), String> {
        self.send(how)?;
        let r = self.receive()?;
        if r.starts_with("T05") || r.starts_with("S05") {
            Ok(())
        } else {
            Err(format!(
                "gdb stub: `{how}` ended with `{r}` (the benchmark ended before the traced step?)"
            ))
        }
    }

    /// Core register `n` (14: LR, 15: PC).
    fn register(&mut self, n: u32) -> Result<u32, String> {
        // `g`: r0..r15 first, 8 hex digits each, little-endian (QEMU 7.2 has no `p`).
        self.send("g")?;
        let r = self.receive()?;
        let at = 8 * n as usize;
        let bytes: Vec<u8> = (0..4)
            .filter_map(|i| u8::from_str_radix(r.get(at + 2 * i..at + 2 * i + 2)?, 16).ok())
            .collect();
        match bytes[..] {
            [a, b, c, d] => Ok(u32::from_le_bytes([a, b, c, d])),
            _ => Err(format!("gdb stub: register {n} not in `{r}`")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Encodings as assembled by LLVM for Thumb-2 (FPv4-SP), with their classes.
    #[test]
    fn classifies_thumb2_encodings() {
        let cases: &[(u16, u16, Class)] = &[
            (0xEEA0, 0x0AAF, Class::FpMac),               // vfma.f32 s0, s1, s31
            (0xEE00, 0x0A20, Class::FpMac),               // vmla.f32 s0, s0, s1
            (0xEE20, 0x0A20, Class::FpAlu),               // vmul.f32 s0, s0, s1
            (0xEE30, 0x0A20, Class::FpAlu),               // vadd.f32 s0, s0, s1
            (0xEE80, 0x0A20, Class::FpDivSqrt),           // vdiv.f32 s0, s0, s1
            (0xEEB1, 0x0AC0, Class::FpDivSqrt),           // vsqrt.f32 s0, s0
            (0xEEB1, 0x0A40, Class::FpAlu),               // vneg.f32 s0, s0
            (0xEE10, 0x0A10, Class::FpAlu),               // vmov r0, s0
            (0xEC41, 0x0A10, Class::FpMovPair),           // vmov s0, s1, r0, r1
            (0xED90, 0x0A00, Class::FpLoad),              // vldr s0, [r0]
            (0xED80, 0x0A00, Class::FpStore),             // vstr s0, [r0]
            (0xECB0, 0x0A0B, Class::FpLoadMultiple(11)),  // vldmia r0!, {s0-s10}
            (0xED2D, 0x8B10, Class::FpStoreMultiple(16)), // vpush {d8-d15}
            (0xB5F0, 0, Class::StoreMultiple(5)),         // push {r4-r7, lr}
            (0xBDF0, 0, Class::LoadMultiple(5)),          // pop {r4-r7, pc}
            (0xE8BD, 0x8FF0, Class::LoadMultiple(9)),     // pop.w {r4-r11, pc}
            (0x6800, 0, Class::Load),                     // ldr r0, [r0]
            (0x6008, 0, Class::Store),                    // str r0, [r1]
            (0xF8D0, 0x0004, Class::Load),                // ldr.w r0, [r0, #4]
            (0xF8C0, 0x1004, Class::Store),               // str.w r1, [r0, #4]
            (0xE9D0, 0x2300, Class::LoadDual),            // ldrd r2, r3, [r0]
            (0xE9C0, 0x2300, Class::StoreDual),           // strd r2, r3, [r0]
            (0xE8D0, 0xF001, Class::Load),                // tbb [r0, r1]
            (0xBF48, 0, Class::It),                       // it mi
            (0xBF00, 0, Class::Other),                    // nop
            (0xD1FE, 0, Class::Branch),                   // bne .
            (0xE7FE, 0, Class::Branch),                   // b .
            (0x4770, 0, Class::Branch),                   // bx lr
            (0xB100, 0, Class::Branch),                   // cbz r0, +4
            (0xF000, 0xF800, Class::Branch),              // bl
            (0xF040, 0x8000, Class::Branch),              // bne.w
            (0xF3BF, 0x8F4F, Class::Other),               // dsb sy
            (0xF04F, 0x0001, Class::Alu),                 // mov.w r0, #1
            (0xEA40, 0x0001, Class::Alu),                 // orr.w r0, r0, r1
            (0x1840, 0, Class::Alu),                      // adds r0, r0, r1
            (0x4348, 0, Class::Mul),                      // muls r0, r1
            (0xFB00, 0xF001, Class::Mul),                 // mul.w r0, r0, r1
            (0xFB90, 0xF0F1, Class::Div),                 // sdiv r0, r0, r1
            (0xFBB0, 0xF0F1, Class::Div),                 // udiv r0, r0, r1
            (0xFBA0, 0x0101, Class::Mul),                 // umull r0, r1, r0, r1
        ];
        for &(hw1, hw2, class) in cases {
            assert_eq!(classify(hw1, hw2), class, "{hw1:04x} {hw2:04x}");
        }
        assert!(is_wide(0xEEA0) && is_wide(0xF000) && !is_wide(0x4770) && !is_wide(0xBDF0));
    }

    #[test]
    fn prices_a_mix_per_chip() {
        let mut mix = Mix::default();
        for c in [
            Class::FpMac,
            Class::FpMac,
            Class::Alu,
            Class::Alu,
            Class::Load,
        ] {
            mix.add(c);
        }
        mix.add(Class::FpLoadMultiple(4));
        mix.add(Class::Branch);
        mix.transfers = 1;
        mix.steps = 1;
        // M4F: 3 + 3 + 1 + 1 + 2 + (1 + 4) + 1 + refill 2.
        assert_eq!(Chip::M4f.cycles(&mix), 18.0);
        // M7: 3 + 3 + 0.5 + 0.5 + 1 + (1 + 2) + 1 + predicted transfer 1.
        assert_eq!(Chip::M7.cycles(&mix), 13.0);
        assert_eq!(mix.per_step(|c| c == Class::FpMac), 2.0);
        let f = CycleFigures {
            chip: Chip::M7,
            board: Board::An500,
            model: "nemm".into(),
            integrator: "rk4".into(),
            mode: "exact".into(),
            instructions_per_step: 1000,
            cycles_per_instruction: 2.5,
            fp_mac_per_step: 2.0,
        };
        assert_eq!(f.cycles_per_step(), 2500);
        assert_eq!(
            f.line(),
            "target-cycles chip=m7 board=mps2-an500 model=nemm integrator=rk4 mode=exact \
             instructions_per_step=1000 est_cycles_per_step=2500 cycles_per_instruction=2.50 \
             fp_mac_per_step=2 budget_216mhz=0.12 budget_480mhz=0.05"
        );
    }
}
