//! Board support: QEMU's `mps2-an386` (Cortex-M4 with FPU), linked with the memory budget of
//! an STM32F4 (see `boards/`). Porting to a real board replaces this module: the clock,
//! the sensor's SPI device, where the force is published, and the console.
//!
//! Everything else in the firmware is board-independent.

use crate::replay::ReplayAdc;
use crate::sensor::StrokeSensor;
use crate::trace::Trace;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m_semihosting::hio::{self, HostStream};

/// Board name in the boot line.
pub const NAME: &str = "mps2-an386";

/// SysTick clock \[Hz\]: QEMU's mps2-an386 runs SysTick (core clock source) at 25 MHz. On an
/// STM32F4 at full speed this is 168 MHz.
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
