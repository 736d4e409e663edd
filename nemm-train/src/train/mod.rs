//! Training of the four variants (sections 5-6): the rollout and its discrete adjoint, the
//! burn modules, the physics losses, the training loop (epochs in [`fit`], model selection
//! in `selection`, checkpoints, the session budget in `session`), the two-step
//! procedure, evaluation, identification of the level ([`identify`]) and the conversion
//! to and from nemm-core models.
pub mod adjoint;
mod checkpoint;
pub mod eval;
pub mod fit;
pub mod history;
pub mod identify;
pub(crate) mod matched;
pub mod net;
pub mod params;
pub mod physics;
pub mod pipeline;
pub(crate) mod selection;
pub(crate) mod session;
pub(crate) mod stability;
pub(crate) mod static_fit;
pub mod table_check;

#[cfg(test)]
mod adjoint_tests;
#[cfg(test)]
mod oracle_tests;
