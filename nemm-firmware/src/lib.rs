//! # nemm-firmware
//!
//! A 10 kHz NEMM damper-force estimator for a Cortex-M4F, in the form a firmware engineer
//! copies onto an ECU or a bench controller. The application (`src/main.rs`, RTIC 2) reads the
//! stroke sensor through [`sensor::StrokeSensor`] on an `embedded-hal` 1.0 `SpiDevice`, steps
//! the [`nemm_core`] estimator and publishes the force every 100 us; logging runs at the
//! lowest priority behind a lock-free queue.
//!
//! This library holds the portable parts (host-tested with
//! `cargo test --lib --target x86_64-unknown-linux-gnu`) and, on the target, the board
//! support of QEMU's `mps2-an386` (`board`, cargo feature `mps2-an386`, on by default) or
//! `mps2-an500` (Cortex-M7, cargo feature `mps2-an500`).
//! Other boards depend on the library without that feature and bring their own (the
//! STM32F407 image in `boards/nemm-stm32f407`).
//!
//! - [`adc`]: the bus protocol both 24-bit SPI converters share (read transaction, status bits).
//! - [`sensor`]: ADC frame, calibration, differentiation filter, the driver.
//! - [`loadcell`]: the load-cell channel (bridge ADC frame, calibration, saturation), the
//!   measured force of the bench-controller build's alpha observer.
//! - [`pipeline`]: one sample period (sensor, estimator, fault classification; with the
//!   observer, the load cell and the alpha estimate) and the digests of the results; shared
//!   with the host tests' reference run.
//! - [`replay`]: the replay `SpiDevice`s serving a recorded trace (stroke and force), with
//!   fault injection.
//! - [`options`]: the run options of the QEMU build (fault injection, sample clock).
//! - [`trace`]: the trace format in flash.
//! - [`slot`]: the weights slot in flash.
//! - [`report`]: the output lines the host tests parse.
#![cfg_attr(not(test), no_std)]

pub mod adc;
pub mod loadcell;
pub mod observer;
pub mod options;
pub mod pipeline;
pub mod replay;
pub mod report;
pub mod sensor;
pub mod slot;
pub mod trace;

#[cfg(all(target_os = "none", feature = "mps2"))]
pub mod board;

#[cfg(target_os = "none")]
extern "C" {
    /// Lowest address of the stack (end of the statics), from cortex-m-rt's `link.x`.
    static _stack_end: u32;
    /// Initial stack pointer (top of the stack region).
    static _stack_start: u32;
}

/// Bytes of stack used so far: the stack is painted with `0xCCCC_CCCC` at reset
/// (cortex-m-rt's `paint-stack`); the lowest overwritten word is the high-water mark.
#[cfg(target_os = "none")]
pub fn stack_used() -> u32 {
    // Only the addresses of the linker symbols are taken.
    let (lo, hi) = (
        core::ptr::addr_of!(_stack_end) as usize,
        core::ptr::addr_of!(_stack_start) as usize,
    );
    let mut p = lo;
    while p < hi {
        // SAFETY: `p` is word-aligned and inside the stack region [_stack_end, _stack_start).
        let w = unsafe { core::ptr::read_volatile(p as *const u32) };
        if w != 0xCCCC_CCCC {
            break;
        }
        p += 4;
    }
    (hi - p) as u32
}

/// Parameter capacity `P` of `Model<P>` / `Estimator<P>` in this firmware: the paper's
/// optimum scaler (`H = 16, L = 5`, section 5.4: 1,313 parameters), which also holds `H = 8`
/// at any depth of the search space (Table 3) and `H = 32` up to `L = 2`.
///
/// RAM: the model and the estimator hold six vectors of `P` floats (31 KiB) in statics; both
/// are built in place (`nemm_core::decode_into`, `nemm_core::Estimator::load`), so the boot
/// stack does not grow with `P` (`cargo xtask build-target` prints it, `boot-stack bytes=`).
/// A larger `P` costs 24 bytes of RAM per parameter.
pub const PARAM_CAPACITY: usize = nemm_core::param_count(2, 16, 5);

/// Bound of the tabulated fast path: each table's largest relative error against its exact
/// scaler (measured at boot on a grid 128x finer than the table; a model whose tables miss it
/// is refused with `weights-error source=estimator kind=table`). Over the bench programme it
/// keeps the force within about 1e-5 of the force scale of the exact mode (docs/core.md).
pub const TABLE_MAX_REL_ERROR: f32 = 1e-4;

/// Segments per table: 128 (28 bytes of RAM each, 3.5 KiB per table). Half the host
/// default: the tables are built and checked at boot, and that work grows with the number of
/// segments. The example models have 60-90 kinks per scaler, the demo's trained NEMM about
/// 40, so 128 segments separate them (a model with more is refused at boot with
/// `table=too-many-kinks`).
pub const TABLE_SEGMENTS: usize = 128;

/// The estimator type of this firmware.
pub type FwEstimator = nemm_core::Estimator<'static, PARAM_CAPACITY, TABLE_SEGMENTS>;

/// Whether the application runs the tabulated fast path unless told otherwise: the `table`
/// cargo feature (the one setting for a board build); QEMU runs override it with
/// `mode=exact|table`.
pub const TABLE_MODE_DEFAULT: bool = cfg!(feature = "table");

/// The estimator's evaluation mode: the verified tables ([`TABLE_MAX_REL_ERROR`]) or the
/// exact MLPs.
pub fn eval_mode(table: bool) -> nemm_core::EvalMode {
    if table {
        nemm_core::EvalMode::Table(nemm_core::TableConfig::new(TABLE_MAX_REL_ERROR))
    } else {
        nemm_core::EvalMode::Exact
    }
}

/// Sample (and estimator step) rate \[Hz\].
pub const SAMPLE_RATE_HZ: u32 = 10_000;

/// Full scale of the stroke channel: `±0.1 m` over the ADC's 24 bits (12 nm per LSB).
pub const STROKE_FULL_SCALE_M: f32 = 0.1;

/// Calibration of the stroke channel at [`SAMPLE_RATE_HZ`].
pub fn stroke_calibration() -> sensor::Calibration {
    sensor::Calibration::new(STROKE_FULL_SCALE_M, SAMPLE_RATE_HZ as f32)
}

/// Full scale of the load-cell channel: `±10 kN` over the ADC's 24 bits (1.19 mN per count),
/// a bench load cell for passenger-car dampers (the recorded forces reach about 2 kN).
pub const LOAD_CELL_FULL_SCALE_N: f32 = 10_000.0;

/// The load-cell channel's reading at zero load \[counts\] (2.6 N): the bench amplifier's
/// offset, from its tare. A board enters its own.
pub const LOAD_CELL_OFFSET_COUNTS: i32 = 2150;

/// Calibration of the load-cell channel.
pub fn load_cell_calibration() -> loadcell::Calibration {
    loadcell::Calibration::new(LOAD_CELL_FULL_SCALE_N, LOAD_CELL_OFFSET_COUNTS)
}

/// Levels of the alpha observer's grid: nemm-core's default (7).
pub const OBSERVER_LEVELS: usize = nemm_core::DEFAULT_OBSERVER_POINTS;

/// The alpha observer of the bench-controller build: the one place its type is chosen (the
/// application, the step benchmark and the host tests' reference all use this): nemm-core's
/// observer on the blob's level tables ([`observer`]).
pub use observer::{FwLevels, FwObserver};

/// The alpha observer's settings: nemm-core's defaults (the grid over the model's trained
/// range, 3 s window of whole stroke cycles), those `nemm diagnose` runs on the host.
pub fn observer_config() -> nemm_core::ObserverConfig {
    nemm_core::ObserverConfig::new()
}

/// Whether the application runs the alpha observer unless told otherwise: the `observer`
/// cargo feature (the one setting for a board build); QEMU runs override it with
/// `observer=on|off`.
pub const OBSERVER_DEFAULT: bool = cfg!(feature = "observer");

/// Whether the application holds the observer and the load-cell path at all: with the
/// `observer` feature, or under QEMU (`qemu` feature), where `observer=on` can ask for it. A
/// board build without the feature never runs it, so its code and its RAM (the observer's
/// static) are left out.
pub const OBSERVER_BUILT: bool = cfg!(any(feature = "observer", feature = "qemu"));

/// A `static` that is filled once at run time and then lent out as `&'static mut T`: the
/// storage for large objects (the model, the estimator) that must not live on the stack.
/// It starts as zero bytes in `.bss` (an `Option<T>` would go to `.data` and cost its size
/// twice: RAM and a flash image of `None`).
pub struct StaticSlot<T> {
    taken: core::sync::atomic::AtomicBool,
    cell: core::cell::UnsafeCell<core::mem::MaybeUninit<T>>,
}

// SAFETY: the only access to `cell` is through `init`, which hands out the one `&mut` at most
// once (guarded by the atomic swap), so sharing the slot between contexts is sound.
unsafe impl<T: Send> Sync for StaticSlot<T> {}

impl<T> StaticSlot<T> {
    /// An empty slot.
    pub const fn new() -> Self {
        Self {
            taken: core::sync::atomic::AtomicBool::new(false),
            cell: core::cell::UnsafeCell::new(core::mem::MaybeUninit::uninit()),
        }
    }

    /// Moves `value` into the slot and returns it; `None` if the slot was already filled.
    // A `&mut` out of `&self` is what a once-cell is: the atomic swap makes it unique.
    #[allow(clippy::mut_from_ref)]
    pub fn init(&'static self, value: T) -> Option<&'static mut T> {
        if self.taken.swap(true, core::sync::atomic::Ordering::AcqRel) {
            return None;
        }
        // SAFETY: the swap above succeeds once, so this is the only reference ever made.
        let slot = unsafe { &mut *self.cell.get() };
        Some(slot.write(value))
    }

    /// Fills the slot with the value `make` returns and returns it; `None` (and `make` not
    /// called) if the slot was already filled. Unlike [`StaticSlot::init`], whose argument
    /// is evaluated before the slot is known to be free, `make` runs after: its result can
    /// be written straight into the slot, without a temporary of `T`'s size on the stack
    /// (what a large value the compiler does not build in place needs).
    // See `init`.
    #[allow(clippy::mut_from_ref)]
    #[inline(always)]
    pub fn init_with(&'static self, make: impl FnOnce() -> T) -> Option<&'static mut T> {
        if self.taken.swap(true, core::sync::atomic::Ordering::AcqRel) {
            return None;
        }
        // SAFETY: as in `init`: the swap above succeeds once.
        let slot = unsafe { &mut *self.cell.get() };
        Some(slot.write(make()))
    }
}

impl<T> Default for StaticSlot<T> {
    fn default() -> Self {
        Self::new()
    }
}
