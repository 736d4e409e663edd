//! The three transcendental / fused operations the model needs, in one place.
//!
//! | operation | `libm` feature (default, exact)                 | `micromath` feature (fast, lossy) |
//! |-----------|-------------------------------------------------|-----------------------------------|
//! | [`exp`]   | `libm::expf` (< 1 ulp)                          | `micromath` `exp` (series, 2.4e-3 relative) |
//! | [`rsqrt`] | `1 / sqrt(x)`, both correctly rounded            | `micromath` `invsqrt` (bit trick, 3.4e-2 relative) |
//! | [`fma`]   | fused multiply-add, correctly rounded (always)  | same                              |
//!
//! Measured error of `micromath` (`examples/math_backends.rs`; details in `docs/core.md`):
//! the largest relative error of `exp` on \[-20, 20\] is 2.4e-3 (`libm`: 7.4e-8), of `rsqrt`
//! on \[1e-5, 1e3\] 3.4e-2 (`libm`: 8.9e-8). Over a full Table 1 bench programme (3
//! amplitudes x 6 peak velocities, three periods each, 612,222 samples; example NEMM with
//! H = 16, L = 5, alpha 0.15, RK4 at 10 kHz) the force differs from the `libm` build by at
//! most 19.0 N (6.3e-3 of the 3000 N force scale; 0.6-1.3 % of each stroke's peak force) and
//! by 2.71 N RMS (9.0e-4 of the force scale); NEMM-Light: 18.6 N max, 2.66 N RMS. The SEM and
//! the Linear EMM use neither function and are bit-identical. On x86-64 `micromath` is not
//! faster (criterion, thread CPU time: 21.34 against 20.97 us per NEMM RK4 step); the
//! Cortex-M4F figures belong to the firmware benchmarks.
//!
//! `sqrt` and `fma` are correctly rounded IEEE 754 operations on every target, so they give
//! the same bits on the host and on the Cortex-M4F:
//!
//! - on bare-metal ARM hard-float targets (`thumbv7em-none-eabihf`, FPv4-SP) they are the
//!   instructions `vsqrt.f32` and `vfma.f32` in `asm!` (see the `arm` module for why the
//!   operands travel through core registers). `libm` 0.2 has no ARM path: it compiles
//!   `sqrtf` to a ~100-instruction integer routine and `fmaf` to soft `f64` arithmetic (over
//!   a thousand instructions per call in QEMU); stable Rust has no `no_std` intrinsic for
//!   either. This module and the scalers' FPU kernels (`mlp::arm`) hold the only `unsafe`
//!   in the crate.
//! - elsewhere `libm::sqrtf` (SSE `sqrtss` on x86-64) and `libm::fmaf` (hardware FMA when
//!   the CPU has it, detected at run time, otherwise an exact software routine).
//!
//! If both math features are enabled, `micromath` wins (Cargo features are additive).

use core::ops::{Add, Div, Mul, Neg, Sub};

#[cfg(not(any(feature = "libm", feature = "micromath")))]
compile_error!(
    "nemm-kernels needs a math backend: enable the `libm` (default) or `micromath` feature"
);

/// Name of the math backend this build uses (`"libm"` or `"micromath"`), for reports.
pub const BACKEND: &str = if cfg!(feature = "micromath") {
    "micromath"
} else {
    "libm"
};

/// `e^x`.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    #[cfg(feature = "micromath")]
    {
        micromath::F32Ext::exp(x)
    }
    #[cfg(not(feature = "micromath"))]
    {
        libm::expf(x)
    }
}

/// `1 / sqrt(x)` for `x > 0`.
#[inline(always)]
pub fn rsqrt(x: f32) -> f32 {
    #[cfg(feature = "micromath")]
    {
        micromath::F32Ext::invsqrt(x)
    }
    #[cfg(not(feature = "micromath"))]
    {
        1.0 / sqrt(x)
    }
}

/// Logistic sigmoid `1 / (1 + e^-z)`; `0` for `z -> -inf`, `1` for `z -> +inf`, never NaN
/// for non-NaN `z`.
#[inline(always)]
pub fn sigmoid(z: f32) -> f32 {
    1.0 / (1.0 + exp(-z))
}

/// Correctly rounded square root.
#[inline(always)]
pub fn sqrt(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf", target_os = "none"))]
    {
        arm::vsqrt(x)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf", target_os = "none")))]
    {
        libm::sqrtf(x)
    }
}

/// Fused multiply-add `a * b + c` with a single rounding.
#[inline(always)]
pub fn fma(a: f32, b: f32, c: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf", target_os = "none"))]
    {
        arm::vfma(a, b, c)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf", target_os = "none")))]
    {
        libm::fmaf(a, b, c)
    }
}

/// How the integrator and the EMM multiply and add: `a * b + c`, on any [`Lane`].
///
/// [`Fused`] is the reference arithmetic (one rounding); [`Unfused`] rounds twice and is what
/// the tabulated fast path and the trainer use: on the Cortex-M4F the fused operation goes
/// through `asm!` with three moves in and one out (see the `arm` module), the unfused one is
/// two FPU instructions; on the host the trainer's packed lanes vectorise multiply and add.
/// The difference, about one rounding of `f32` (6e-8 relative) per operation, is far below
/// the table's error bound and the trainer's parity bound.
pub trait MulAdd {
    /// `a * b + c`.
    fn mul_add<L: Lane>(a: L, b: L, c: L) -> L;
}

/// Fused multiply-add, [`fma`].
#[derive(Debug, Clone, Copy)]
pub struct Fused;

/// Multiply, round, add, round.
#[derive(Debug, Clone, Copy)]
pub struct Unfused;

impl MulAdd for Fused {
    #[inline(always)]
    fn mul_add<L: Lane>(a: L, b: L, c: L) -> L {
        L::fma(a, b, c)
    }
}

impl MulAdd for Unfused {
    #[inline(always)]
    fn mul_add<L: Lane>(a: L, b: L, c: L) -> L {
        a * b + c
    }
}

/// A floating-point element type of a [`Lane`]: `f32` (estimator, training) or `f64`
/// (the trainer's gradient checks).
///
/// The operations are associated functions, not methods, so that they never clash with the
/// inherent or `num_traits` methods of the same names at a call site.
pub trait Scalar:
    Copy
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// `v` converted (exact for the small constants the model uses: 0.5, 2, 4, 6).
    fn from_f32(v: f32) -> Self;
    /// Fused multiply-add `a * b + c`, one rounding.
    fn fma(a: Self, b: Self, c: Self) -> Self;
    /// `e^x`.
    fn exp(x: Self) -> Self;
    /// Correctly rounded square root.
    fn sqrt(x: Self) -> Self;
    /// `1 / sqrt(x)` for `x > 0` ([`rsqrt`] for `f32`: the math backend's).
    fn rsqrt(x: Self) -> Self;
}

impl Scalar for f32 {
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn fma(a: Self, b: Self, c: Self) -> Self {
        fma(a, b, c)
    }
    #[inline(always)]
    fn exp(x: Self) -> Self {
        exp(x)
    }
    #[inline(always)]
    fn sqrt(x: Self) -> Self {
        sqrt(x)
    }
    #[inline(always)]
    fn rsqrt(x: Self) -> Self {
        rsqrt(x)
    }
}

impl Scalar for f64 {
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        f64::from(v)
    }
    #[inline(always)]
    fn fma(a: Self, b: Self, c: Self) -> Self {
        libm::fma(a, b, c)
    }
    #[inline(always)]
    fn exp(x: Self) -> Self {
        libm::exp(x)
    }
    #[inline(always)]
    fn sqrt(x: Self) -> Self {
        libm::sqrt(x)
    }
    #[inline(always)]
    fn rsqrt(x: Self) -> Self {
        1.0 / libm::sqrt(x)
    }
}

/// The value type the model's pieces ([`crate::emm`], [`crate::integrator`], the scaler
/// layers of [`crate::mlp`]) are written over: one `f32` in the estimator, `Lanes` of `N`
/// windows advanced in lock step in the trainer. Element-wise arithmetic through the
/// operators; constants and weights are [`Lane::splat`] into every lane.
pub trait Lane:
    Copy
    + Default
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// The element type.
    type Scalar: Scalar;
    /// `v` in every lane.
    fn splat(v: Self::Scalar) -> Self;
    /// The constant `v` (see [`Scalar::from_f32`]) in every lane.
    #[inline(always)]
    fn constant(v: f32) -> Self {
        Self::splat(Self::Scalar::from_f32(v))
    }
    /// Fused multiply-add per lane.
    fn fma(a: Self, b: Self, c: Self) -> Self;
    /// `e^x` per lane.
    fn exp(x: Self) -> Self;
    /// Square root per lane.
    fn sqrt(x: Self) -> Self;
    /// `1 / sqrt(x)` per lane ([`Scalar::rsqrt`]).
    fn rsqrt(x: Self) -> Self;
    /// Per lane: `if_nonneg` where `test >= 0`, `otherwise` elsewhere (LeakyReLU and its
    /// derivative).
    fn select_nonneg(test: Self, if_nonneg: Self, otherwise: Self) -> Self;
    /// Sum over the lanes (a weight gradient from per-lane contributions).
    fn sum(x: Self) -> Self::Scalar;
}

/// A scalar as one lane, through its [`Scalar`] arithmetic (for `f32` the math backend's).
macro_rules! scalar_lane {
    ($t:ty) => {
        impl Lane for $t {
            type Scalar = $t;
            #[inline(always)]
            fn splat(v: $t) -> Self {
                v
            }
            #[inline(always)]
            fn fma(a: Self, b: Self, c: Self) -> Self {
                <$t as Scalar>::fma(a, b, c)
            }
            #[inline(always)]
            fn exp(x: Self) -> Self {
                <$t as Scalar>::exp(x)
            }
            #[inline(always)]
            fn sqrt(x: Self) -> Self {
                <$t as Scalar>::sqrt(x)
            }
            #[inline(always)]
            fn rsqrt(x: Self) -> Self {
                <$t as Scalar>::rsqrt(x)
            }
            #[inline(always)]
            fn select_nonneg(test: Self, if_nonneg: Self, otherwise: Self) -> Self {
                if test >= 0.0 {
                    if_nonneg
                } else {
                    otherwise
                }
            }
            #[inline(always)]
            fn sum(x: Self) -> $t {
                x
            }
        }
    };
}

scalar_lane!(f32);
// `f64` as one lane: the reference arithmetic of tests and tools.
scalar_lane!(f64);

#[cfg(feature = "reverse")]
mod lanes;
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub use lanes::Lanes;

#[cfg(all(target_arch = "arm", target_abi = "eabihf", target_os = "none"))]
#[allow(unsafe_code)]
mod arm {
    //! `vsqrt.f32` and `vfma.f32` through `asm!`.
    //!
    //! Stable Rust (1.95/1.96) refuses the `sreg` register class on `thumbv7em-none-eabihf`
    //! ("requires the `vfp2` target feature": the target only has `vfp4d16sp`, which Rust does
    //! not map to `vfp2`), so the operands travel in core registers and each block moves them
    //! into `s0..s2` itself. Those FPU registers are declared as clobbers (`out("s0") _`),
    //! which rustc accepts without the feature check, so the compiler keeps none of its own
    //! values there across the block. `vmov` between core and FPU registers is one cycle each
    //! on a Cortex-M4F; the hardware instruction still beats the software routines
    //! (`libm::sqrtf`: ~100 integer instructions; `libm::fmaf`: soft `f64`) by far.
    //!
    //! The per-step hot path (the scalers' networks) does not come through here: it runs as
    //! whole-network FPU kernels (`mlp::arm`). These remain for the EMM right-hand side, the
    //! integrator and the output mapping (a few dozen per step).
    //!
    //! Requires an FPU with fused multiply-add (VFPv4 or later: Cortex-M4F, M7, M33).

    /// `vsqrt.f32`: IEEE 754 square root, correctly rounded.
    #[inline(always)]
    pub fn vsqrt(x: f32) -> f32 {
        let r: u32;
        // SAFETY: register-only; the FPU register used is declared clobbered; no memory, no
        // stack, no flags other than the FPSCR cumulative exception bits.
        unsafe {
            core::arch::asm!(
                "vmov s0, {x}",
                "vsqrt.f32 s0, s0",
                "vmov {r}, s0",
                x = in(reg) x.to_bits(),
                r = lateout(reg) r,
                out("s0") _,
                options(pure, nomem, nostack, preserves_flags),
            );
        }
        f32::from_bits(r)
    }

    /// `vfma.f32`: fused `a * b + c`, one rounding.
    #[inline(always)]
    pub fn vfma(a: f32, b: f32, c: f32) -> f32 {
        let r: u32;
        // SAFETY: as above; `s0..s2` are declared clobbered.
        unsafe {
            core::arch::asm!(
                "vmov s0, s1, {a}, {b}",
                "vmov s2, {c}",
                "vfma.f32 s2, s0, s1",
                "vmov {r}, s2",
                a = in(reg) a.to_bits(),
                b = in(reg) b.to_bits(),
                c = in(reg) c.to_bits(),
                r = lateout(reg) r,
                out("s0") _,
                out("s1") _,
                out("s2") _,
                options(pure, nomem, nostack, preserves_flags),
            );
        }
        f32::from_bits(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fma_is_fused() {
        // (1 + 2^-12)^2 - (1 + 2^-11) = 2^-24 exactly; unfused f32 loses it.
        let a = 1.0 + f32::powi(2.0, -12);
        let c = -(1.0 + f32::powi(2.0, -11));
        assert_eq!(fma(a, a, c), f32::powi(2.0, -24));
        assert_eq!(a * a + c, 0.0);
    }

    #[test]
    fn sigmoid_saturates_without_nan() {
        assert_eq!(sigmoid(-200.0), 0.0);
        assert_eq!(sigmoid(200.0), 1.0);
        assert!((sigmoid(0.0) - 0.5).abs() < 1e-6);
    }

    #[cfg(not(feature = "micromath"))]
    #[test]
    fn exact_backend_values() {
        assert_eq!(sqrt(2.0), core::f32::consts::SQRT_2);
        assert_eq!(rsqrt(4.0), 0.5);
        assert!((exp(1.0) - core::f32::consts::E).abs() <= f32::EPSILON * 3.0);
    }
}
