//! The model's arithmetic: the EMM right-hand side, the neural scalers, the Runge-Kutta
//! step, the SEM map, the static force, the fast-path tables and the math backends, each
//! written once, in the `f32` operation order the firmware runs.
//!
//! These modules are public for the trainer (which differentiates this very arithmetic,
//! with the `reverse` feature), for tests and for tools. **They are not covered by the
//! crate's stability promise**: their items may change in any release. A firmware or a C
//! wrapper needs only the crate root: the [`crate::Estimator`], the weight format and the
//! model types.
//!
//! Layering (each module uses only those before it): [`math`] -> [`emm`], [`mlp`],
//! [`integrator`], [`sem`], [`static_force`], [`lost_motion`] -> [`table`] (tables of [`mlp`]'s compiled
//! scalers). Above them, outside this module: [`crate::Model`], then the weight format
//! ([`crate::format`]), then the [`crate::Estimator`]. The errors they share are in the
//! lowest layer ([`crate::ModelError`] and the errors it carries).

pub mod emm;
pub mod integrator;
pub mod lost_motion;
pub mod math;
pub mod mlp;
pub mod sem;
pub mod static_force;
pub mod table;
