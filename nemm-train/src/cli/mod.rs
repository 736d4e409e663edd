//! The `nemm` command line: argument types and the handlers of each command.
pub mod bench;
pub mod data;
pub mod diagnose;
pub mod identify;
pub mod train;
