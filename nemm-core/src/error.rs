//! Errors that the lowest layers share (the parsers of names), so that `integrator` and
//! `mlp` need not reach up into `model` for them.

use core::fmt;

/// A name that is none of the accepted spellings of a [`crate::ModelKind`], an
/// [`crate::Integrator`] or a [`crate::mlp::Direction`] (their `name()`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownName {
    /// What was being parsed (`model kind`, `integrator`, `monotonicity direction`).
    pub what: &'static str,
    /// The accepted names.
    pub expected: &'static str,
}

impl fmt::Display for UnknownName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown {} (expected {})", self.what, self.expected)
    }
}

#[cfg(feature = "std")]
impl std::error::Error for UnknownName {}
