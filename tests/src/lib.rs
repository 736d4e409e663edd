//! End-to-end tests across the NEMM crates live in `tests/tests/`; this library holds their
//! shared helpers.
#![deny(missing_docs)]
