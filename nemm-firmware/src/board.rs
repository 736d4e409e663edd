//! Board support: QEMU's `mps2-an386` (Cortex-M4 with FPU, cargo feature `mps2-an386`) or
//! `mps2-an500` (Cortex-M7 with FPU, cargo feature `mps2-an500`), linked with the memory
//! budget of an STM32F4 (see `boards/`). Porting to a real board replaces this module: the
//! clock, the sensor's SPI device, where the force is published, and the console.
//!
//! Both MPS2 images share everything here but the name, the memory layout (`build.rs`
//! picks `boards/<name>.x`) and [`init`], which enables the Cortex-M7's caches. QEMU 7.2
//! maps the code memory at 0x00000000 and the data RAM at 0x20000000 on both machines
//! (the AN500's PSRAM and peripherals move, which the firmware does not use: its console is
//! semihosting) and clocks SysTick at 25 MHz on both.
//!
//! The board also measures the boot: `__pre_init` runs SysTick free from the reset vector,
//! before RAM is initialised, and [`boot_ticks`] reads how far it got.
//!
//! Everything else in the firmware is board-independent.

use crate::loadcell::LoadCell;
use crate::replay::{ReplayAdc, ReplayLoadCell};
use crate::sensor::StrokeSensor;
use crate::trace::Trace;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m_semihosting::hio::{self, HostStream};

#[cfg(all(feature = "mps2-an386", feature = "mps2-an500"))]
compile_error!("features `mps2-an386` and `mps2-an500` select different boards: enable one");

/// Board name in the boot line.
#[cfg(not(feature = "mps2-an500"))]
pub const NAME: &str = "mps2-an386";
/// Board name in the boot line.
#[cfg(feature = "mps2-an500")]
pub const NAME: &str = "mps2-an500";

/// Board set-up at the start of `init`: on the Cortex-M7 (mps2-an500), invalidate and
/// enable the instruction and data caches (a product runs with them on; QEMU does not model
/// caches, so under QEMU this costs only its instructions); nothing on the Cortex-M4.
pub fn init() {
    #[cfg(feature = "mps2-an500")]
    {
        // SAFETY: called once from `init`, with interrupts disabled, before anything else
        // touches the system control block or the CPUID registers.
        let mut p = unsafe { cortex_m::Peripherals::steal() };
        p.SCB.enable_icache();
        p.SCB.enable_dcache(&mut p.CPUID);
    }
}

// The boot clock: SysTick counting down freely from its top (core clock, no interrupt),
// started as cortex-m-rt's `__pre_init`, the first thing the reset vector calls (before RAM
// is initialised, so in assembly), so that `boot_ticks` counts from reset. Under QEMU's
// `-icount shift=0` one tick is 40 instructions; the 24-bit counter covers 671 million
// instructions of boot. Registers: SYST_CSR 0xE000E010, RVR +4, CVR +8; CSR = ENABLE |
// CLKSOURCE (core clock), no TICKINT.
core::arch::global_asm!(
    ".section .text.__pre_init,\"ax\",%progbits",
    ".global __pre_init",
    ".type __pre_init,%function",
    ".thumb_func",
    "__pre_init:",
    "ldr r0, =0xE000E010",
    "ldr r1, =0x00FFFFFF",
    "str r1, [r0, #4]",
    "movs r1, #0",
    "str r1, [r0, #8]",
    "movs r1, #5",
    "str r1, [r0]",
    "bx lr",
    ".ltorg",
    ".size __pre_init, . - __pre_init",
);

/// The reload value of the boot clock (SysTick's 24-bit maximum, as `__pre_init` sets it).
const BOOT_CLOCK_TOP: u32 = 0x00FF_FFFF;

/// SysTick ticks since reset (the boot clock `__pre_init` starts, see above) while SysTick
/// still runs it; `None` once it wrapped (COUNTFLAG set: more than 2^24 ticks, or SysTick
/// was reconfigured).
pub fn boot_ticks() -> Option<u32> {
    let csr = cortex_m::peripheral::SYST::PTR;
    // SAFETY: reads of SysTick's CSR and CVR (reading CSR clears COUNTFLAG, which nothing
    // else uses before the application configures SysTick).
    let (flags, current) = unsafe { ((*csr).csr.read(), (*csr).cvr.read()) };
    (flags & (1 << 16) == 0).then(|| BOOT_CLOCK_TOP - (current & BOOT_CLOCK_TOP))
}

/// SysTick clock \[Hz\]: QEMU's mps2-an386 and mps2-an500 run SysTick (core clock source) at
/// 25 MHz. On an STM32F4 at full speed this is 168 MHz.
pub const SYSTICK_HZ: u32 = 25_000_000;

/// SysTick ticks per sample period.
pub const PERIOD_TICKS: u32 = SYSTICK_HZ / crate::SAMPLE_RATE_HZ;

/// The description of the interrupt controller RTIC needs (`#[rtic::app(device = ...)]`). The
/// application only uses the SysTick exception, so no device interrupts are listed; a PAC
/// (e.g. `stm32f4::stm32f407`) takes this place on a real board.
pub mod device {
    /// Priority bits of the NVIC (3 on the MPS2 Cortex-M4 image, 4 on an STM32F4).
    pub const NVIC_PRIO_BITS: u8 = 3;
}

/// The sensor as wired on this board: the stroke driver on the replay device.
pub type Sensor = StrokeSensor<ReplayAdc<'static>>;

/// The recorded bench trace in flash (written by `build.rs`).
#[link_section = ".nemm_trace"]
#[used]
static TRACE: [u8; include_bytes!(concat!(env!("OUT_DIR"), "/trace.bin")).len()] =
    *include_bytes!(concat!(env!("OUT_DIR"), "/trace.bin"));

/// The recorded trace. Read through an opaque reference, so the compiler cannot fold the
/// build-time contents (the header's sample count) into the code: a trace patched into the
/// section (the end-to-end test replays other runs that way) is what the firmware serves.
pub fn trace_bytes() -> &'static [u8] {
    core::hint::black_box(&TRACE)
}

/// The weights slot as flashed ([`crate::slot::flashed`]).
pub fn weights_slot() -> &'static [u8] {
    crate::slot::flashed()
}

/// The trace parsed, and the sensor on the replay device.
pub fn sensor(trace: Trace<'static>) -> Sensor {
    let cal = crate::stroke_calibration();
    StrokeSensor::new(ReplayAdc::new(trace, cal), cal)
}

/// The load cell as wired on this board (bench-controller mode): the load-cell driver on the
/// replay device serving the recorded force.
pub type LoadCellSensor = LoadCell<ReplayLoadCell<'static>>;

/// The load cell on the replay device of `trace`.
pub fn load_cell(trace: Trace<'static>) -> LoadCellSensor {
    let cal = crate::load_cell_calibration();
    LoadCell::new(ReplayLoadCell::new(trace, cal), cal)
}

/// Where the force estimate goes each period: on this board a word other tasks (or a
/// debugger) read; on an ECU a CAN mailbox, a DAC or shared memory.
pub struct ForceOutput {
    bits: AtomicU32,
    seq: AtomicU32,
}

impl ForceOutput {
    /// Publishes `force_n`.
    #[inline(always)]
    pub fn publish(&self, force_n: f32) {
        self.bits.store(force_n.to_bits(), Ordering::Relaxed);
        self.seq.fetch_add(1, Ordering::Release);
    }

    /// The last published force and how many were published.
    pub fn latest(&self) -> (f32, u32) {
        let seq = self.seq.load(Ordering::Acquire);
        (f32::from_bits(self.bits.load(Ordering::Relaxed)), seq)
    }
}

/// The force output of this board.
pub static FORCE_OUTPUT: ForceOutput = ForceOutput {
    bits: AtomicU32::new(0),
    seq: AtomicU32::new(0),
};

/// Where the alpha observer's estimate goes each period (bench-controller mode), beside the
/// force: on this board words other tasks (or a debugger) read; on a bench controller a
/// status register of its host interface.
pub struct AlphaOutput {
    alpha: AtomicU32,
    band: AtomicU32,
    flags: AtomicU32,
    seq: AtomicU32,
}

impl AlphaOutput {
    /// Publishes an estimate.
    #[inline(always)]
    pub fn publish(&self, e: &nemm_core::AlphaEstimate) {
        self.alpha.store(e.alpha.to_bits(), Ordering::Relaxed);
        self.band.store(e.band.to_bits(), Ordering::Relaxed);
        self.flags.store(u32::from(e.flags.0), Ordering::Relaxed);
        self.seq.fetch_add(1, Ordering::Release);
    }

    /// The last published estimate (alpha, band, flags) and how many were published.
    pub fn latest(&self) -> (f32, f32, u8, u32) {
        let seq = self.seq.load(Ordering::Acquire);
        (
            f32::from_bits(self.alpha.load(Ordering::Relaxed)),
            f32::from_bits(self.band.load(Ordering::Relaxed)),
            self.flags.load(Ordering::Relaxed) as u8,
            seq,
        )
    }
}

/// The alpha output of this board.
pub static ALPHA_OUTPUT: AlphaOutput = AlphaOutput {
    alpha: AtomicU32::new(0),
    band: AtomicU32::new(0),
    flags: AtomicU32::new(0),
    seq: AtomicU32::new(0),
};

/// Text output: semihosting stdout (with a debug probe attached on a real board, or QEMU).
pub struct Console {
    out: Option<HostStream>,
}

impl Console {
    /// Opens the host's stdout (silently does nothing if the host refuses).
    pub fn open() -> Self {
        Self {
            out: hio::hstdout().ok(),
        }
    }

    /// Writes bytes.
    pub fn write(&mut self, bytes: &[u8]) {
        if let Some(out) = &mut self.out {
            let _ = out.write_all(bytes);
        }
    }
}

/// Ends the run. Under the `qemu` feature QEMU exits with `code` (semihosting
/// `SYS_EXIT_EXTENDED`); on a board the core sleeps forever.
pub fn exit(code: u32) -> ! {
    #[cfg(feature = "qemu")]
    {
        const ADP_STOPPED_APPLICATION_EXIT: usize = 0x20026;
        const SYS_EXIT_EXTENDED: usize = 0x20;
        let block = [ADP_STOPPED_APPLICATION_EXIT, code as usize];
        // SAFETY: a semihosting call with a valid parameter block; QEMU ends the process.
        unsafe {
            cortex_m_semihosting::syscall(SYS_EXIT_EXTENDED, &block);
        }
    }
    #[cfg(not(feature = "qemu"))]
    let _ = code;
    loop {
        cortex_m::asm::wfi();
    }
}

/// Buffer for the command line.
pub const ARGS_CAPACITY: usize = 256;

/// The semihosting command line (QEMU: `-semihosting-config arg=...`), `None` without one.
/// Only used under the `qemu` feature, for fault injection.
pub fn args(buf: &mut [u8; ARGS_CAPACITY]) -> Option<&str> {
    #[cfg(feature = "qemu")]
    {
        const SYS_GET_CMDLINE: usize = 0x15;
        let mut block = [buf.as_mut_ptr() as usize, buf.len()];
        // SAFETY: the block points at `buf` with its length; the host writes at most that many
        // bytes and stores the length written in `block[1]`. The block goes by address (an
        // exposed pointer, the `asm!` may write through it), not as a shared reference.
        let r =
            unsafe { cortex_m_semihosting::syscall1(SYS_GET_CMDLINE, block.as_mut_ptr() as usize) };
        if r != 0 {
            return None;
        }
        let n = block[1].min(buf.len());
        core::str::from_utf8(buf.get(..n)?).ok()
    }
    #[cfg(not(feature = "qemu"))]
    {
        let _ = buf;
        None
    }
}

pub use crate::stack_used;

/// Hard faults end the run with [`crate::report::EXIT_HARD_FAULT`] (never expected).
#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    Console::open().write(b"hard-fault\n");
    exit(crate::report::EXIT_HARD_FAULT)
}

/// Panics end the run with [`crate::report::EXIT_PANIC`]. The release build links no panic
/// path at all (`tests/tests/qemu_no_panic.rs` checks the symbols), so this is never called.
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    Console::open().write(b"panic\n");
    exit(crate::report::EXIT_PANIC)
}
