//! End-to-end tests across the NEMM crates live in `tests/tests/`; this library holds their
//! shared helpers.
//!
//! - [`elf`]: reading and patching the firmware's ELF files (sections, symbols, call graph):
//!   the `nemm-elf` crate, which `cargo xtask` uses too.
//! - [`firmware`]: running the firmware in QEMU and parsing its output.
//! - [`reference`](mod@reference): the host run of the firmware's sample path, the QEMU tests' reference.

pub use nemm_elf as elf;
pub mod firmware;
pub mod reference;
