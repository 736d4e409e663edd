//! The weights slot of the firmware image: the format ([`nemm_slot`], re-exported here) and
//! the flash region that holds it on the target (`flashed`; on an STM32F407: the last
//! 128 KiB sector at `0x080E0000`, see `boards/stm32f407.x`).

pub use nemm_slot::*;

/// The weights slot with the blob chosen at build time (`NEMM_WEIGHTS`, framed by
/// `build.rs`), in the `.nemm_weights` section that `nemm-sections.x` places at the start of
/// the board's WEIGHTS region. Every image linked with this library carries it.
#[cfg(target_os = "none")]
#[link_section = ".nemm_weights"]
#[used]
static WEIGHTS_SLOT: [u8; CAPACITY] = *include_bytes!(concat!(env!("OUT_DIR"), "/weights.slot"));

#[cfg(target_os = "none")]
extern "C" {
    /// Start of the weights region (`nemm-sections.x`).
    static __nemm_weights_start: u8;
}

/// The weights slot as flashed. Read through the region's address rather than the `static`,
/// so the compiler cannot assume the build-time contents: whatever is programmed into the
/// region (a new model flashed on its own) is what the firmware validates.
#[cfg(target_os = "none")]
pub fn flashed() -> &'static [u8] {
    // Keep the default contents in the image.
    let _ = core::hint::black_box(&WEIGHTS_SLOT);
    // SAFETY: `__nemm_weights_start` is the first byte of the `.nemm_weights` output section,
    // which `nemm-sections.x` places at the start of the WEIGHTS region and which holds
    // `WEIGHTS_SLOT` (`CAPACITY` bytes of read-only flash); nothing writes it at run time.
    unsafe { core::slice::from_raw_parts(core::ptr::addr_of!(__nemm_weights_start), CAPACITY) }
}
