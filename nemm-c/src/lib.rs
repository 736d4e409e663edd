//! # nemm-c
//!
//! The C interface of [`nemm_core`]: the online damper-force estimator and the alpha
//! observer for ECU and bench-controller software written in C. A `no_std` static library
//! (`libnemm_c.a`, built by `cargo xtask c-lib` for the Cortex-M4F and the host) and its
//! header `include/nemm.h`, generated from this crate by cbindgen and checked against it by
//! the crate's tests. The integration guide is `docs/c-interface.md`.
//!
//! - No allocation: the caller provides the storage of each object (`nemm_estimator_t`,
//!   `nemm_observer_t`, `nemm_levels_t`), whose size and alignment are compile-time constants of the header
//!   ([`NEMM_ESTIMATOR_SIZE`], ...), checked against the Rust objects at compile time and
//!   against the caller's pointer and size at run time.
//! - No panic: nothing in the library panics (nemm-core never does, and this crate denies
//!   the panicking constructs); every error is a documented [`nemm_status_t`].
//! - The capacities are the firmware's ([`NEMM_PARAM_CAPACITY`], [`NEMM_TABLE_SEGMENTS`],
//!   [`NEMM_TABLE_MAX_REL_ERROR`]), so a C program and the Rust firmware give bit-identical
//!   forces for the same blob, alpha, mode and inputs (`cargo xtask test` checks it in
//!   QEMU).
//! - Level tables (`nemm_levels_t`, [`NEMM_LEVELS_CAPACITY`] levels): the tables a blob
//!   stores for several oil-loss levels, read in place from the blob (which stays in place,
//!   4-byte aligned, while they are used), for an estimator with a level per sample and an
//!   alpha observer at table cost (`nemm_estimator_attach_levels`,
//!   `nemm_observer_init_on_levels`).
//! - One step per object: `nemm_estimator_step` and `nemm_observer_step` take one
//!   `nemm_sample_t` (the stroke velocity, and the position, level and measured force that
//!   its `fields` bits mark present).
//!
//! The functions are `unsafe extern "C"`: their safety contracts are the pointer rules of
//! their C documentation (valid, writable where written, not accessed by another context
//! during the call).
#![no_std]
#![deny(unsafe_op_in_unsafe_fn, clippy::undocumented_unsafe_blocks)]
#![cfg_attr(
    not(test),
    deny(
        clippy::indexing_slicing,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::unreachable,
        clippy::todo
    )
)]

// Hosted targets (the host static library of the C unit test, the Rust tests) take the
// panic runtime from std, which is never entered; bare-metal ones get the handler below.
#[cfg(test)]
extern crate std;
#[cfg(all(not(target_os = "none"), not(test)))]
extern crate std as _;

mod blob;
mod estimator;
mod levels;
mod observer;
mod status;
mod storage;
mod types;

#[cfg(test)]
mod tests;

pub use blob::nemm_blob_validate;
pub use estimator::{
    nemm_estimator_attach_levels, nemm_estimator_info, nemm_estimator_init, nemm_estimator_reset,
    nemm_estimator_set_alpha, nemm_estimator_step,
};
pub use levels::{nemm_levels_info, nemm_levels_init};
pub use observer::{
    nemm_observer_config_default, nemm_observer_estimate, nemm_observer_init,
    nemm_observer_init_on_levels, nemm_observer_reset, nemm_observer_step,
};
pub use status::{nemm_status_str, nemm_status_t};
pub use storage::{
    nemm_estimator_t, nemm_levels_t, nemm_observer_t, NEMM_ESTIMATOR_ALIGN, NEMM_ESTIMATOR_SIZE,
    NEMM_LEVELS_ALIGN, NEMM_LEVELS_SIZE, NEMM_OBSERVER_ALIGN, NEMM_OBSERVER_SIZE,
};
pub use types::*;

/// Parameters per scaler network the library holds: the paper's optimum scaler (16 wide,
/// 5 layers: 1,313 parameters), as the firmware. A blob whose largest scaler needs more is
/// refused with `NEMM_E_BLOB_OVER_CAPACITY`.
pub const NEMM_PARAM_CAPACITY: usize = 1313;
/// Segments per table in `NEMM_MODE_TABLE` (28 bytes of RAM each), as the firmware.
pub const NEMM_TABLE_SEGMENTS: usize = 128;
/// Default bound of table mode: each table's largest relative error against its exact
/// network, as the firmware.
pub const NEMM_TABLE_MAX_REL_ERROR: f32 = 1e-4;
/// Most levels of an alpha observer's grid (its default).
pub const NEMM_OBSERVER_MAX_POINTS: usize = 7;
/// Most levels a `nemm_levels_t` holds (each two tables of `NEMM_TABLE_SEGMENTS` segments,
/// read in place from the blob: no RAM per level). A blob storing more levels of
/// `NEMM_TABLE_SEGMENTS`-segment tables is refused with `NEMM_E_LEVELS_TOO_MANY`; an
/// observer on level tables needs at most `NEMM_OBSERVER_MAX_POINTS` levels
/// (`NEMM_E_OBSERVER_POINTS` otherwise).
pub const NEMM_LEVELS_CAPACITY: usize = 8;

const _: () = {
    assert!(NEMM_PARAM_CAPACITY == nemm_core::param_count(2, 16, 5));
    assert!(NEMM_OBSERVER_MAX_POINTS == nemm_core::DEFAULT_OBSERVER_POINTS);
    assert!(NEMM_LEVELS_CAPACITY <= nemm_core::MAX_TABLE_LEVELS);
};

/// The bare-metal static library's panic handler. Nothing in the library panics, so the
/// linker drops it from a program (the C example links no panic path); were it ever
/// entered it would stop the core in a permanent fault loop for the watchdog to reset.
#[cfg(all(target_os = "none", feature = "panic-handler", not(test)))]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo<'_>) -> ! {
    loop {
        core::hint::spin_loop();
    }
}
