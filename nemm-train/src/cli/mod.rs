//! The `nemm` command line: argument types and the handlers of each command, which
//! `src/main.rs` calls after parsing. A handler checks the outputs, loads the inputs, calls
//! the library ([`crate::data`], [`crate::train`], [`crate::report`]) and writes or prints
//! the result.
pub mod bench;
pub mod data;
pub mod diagnose;
pub mod identify;
pub mod train;
