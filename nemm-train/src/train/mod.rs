//! Training of the EMM-family variants (Linear EMM, NEMM-Light, NEMM): the rollout and its
//! discrete adjoint, the conversion to and from nemm-core models.
pub mod adjoint;
pub mod net;
pub mod params;

#[cfg(test)]
mod adjoint_tests;
#[cfg(test)]
mod oracle_tests;
