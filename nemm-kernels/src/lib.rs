//! # nemm-kernels
//!
//! The arithmetic of the Neural Equivalent Mechanical Model (NEMM) of a degrading
//! twin-tube suspension damper: the EMM right-hand side and force, the neural scalers of
//! `b_fl`, `b_pr` and `k_pr`, the Runge-Kutta step of the states `x_pr` and `v_st`, the SEM
//! map, the static force, the lost-motion element, the fast-path tables and the math
//! backends, each written once, in the `f32` operation order the firmware runs. `no_std`,
//! no allocator, no panics (`clippy::indexing_slicing`, `unwrap_used`, `expect_used`,
//! `panic` are denied outside tests).
//!
//! This is the layer below `nemm-core`, which builds the model, the weight format, the
//! online estimator and the alpha observer on it. A firmware or a C wrapper uses
//! `nemm-core` alone (it re-exports the kernel types its API is made of). The modules here
//! are public for the trainer (which differentiates this very arithmetic, with the
//! `reverse` feature), for tests and for tools. **They are not covered by semver beyond
//! this crate's exact version**: their items may change in any release.
//!
//! Layering (each module uses only those before it, by its own path, `crate::mlp::...`):
//!
//! 1. [`limits`] (the fixed capacities), [`error`] (the errors the layers and nemm-core's
//!    model share), [`wire`] (the byte writer of the weight format);
//! 2. [`math`] (the `exp`, `rsqrt` and `fma` backends, the lane abstraction);
//! 3. [`emm`], [`mlp`], [`cumulative`] (the scaler whose force is monotone in its state by
//!    construction), [`integrator`], [`sem`], [`static_force`], [`lost_motion`];
//! 4. [`table`] (tables of [`mlp`]'s compiled scalers).
//!
//! Above them, in `nemm-core`: the model, then the weight format, then the estimator and
//! the observer.
//!
//! Units are SI throughout: m, m/s, N, N s/m, N/m, s. `alpha` is the oil-loss fraction in
//! `[0, 1]`. All arithmetic is `f32`.
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![cfg_attr(docsrs, feature(doc_cfg))]
#![deny(unsafe_code)]
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

pub mod cumulative;
pub mod emm;
pub mod error;
pub mod integrator;
pub mod limits;
pub mod lost_motion;
pub mod math;
pub mod mlp;
pub mod sem;
pub mod static_force;
pub mod table;
pub mod wire;
