//! The three transcendental / fused operations the model needs, in one place.
//!
//! | operation | `libm` feature (default, exact)                 | `micromath` feature (fast, lossy) |
//! |-----------|-------------------------------------------------|-----------------------------------|
//! | [`exp`]   | `libm::expf` (< 1 ulp)                          | `micromath` `exp` (series, ~1e-3 relative) |
//! | [`rsqrt`] | `1 / sqrt(x)`, both correctly rounded            | `micromath` `invsqrt` (bit trick, ~5 %) |
//! | [`fma`]   | fused multiply-add, correctly rounded (always)  | same                              |
//!
//! `sqrt` and `fma` are correctly rounded IEEE 754 operations on every target (`libm::sqrtf`,
//! `libm::fmaf`), so they give the same bits on the host and on the Cortex-M4F.
//!
//! On `thumbv7em-none-eabihf` both are software routines: `libm` 0.2 has no ARM path, stable
//! Rust has no `no_std` intrinsic for either, and `asm!` cannot name FPU registers there
//! (Rust 1.95/1.96 refuse the `sreg` class without the `vfp2` target feature, which the
//! single-precision FPv4-SP target does not have). An `asm!` version that moves the operands
//! through core registers (`vmov`) compiled and was exact, but measured slower per step than
//! `libm` in QEMU (see nemm-firmware's README), so it is not used.
//!
//! If both math features are enabled, `micromath` wins (Cargo features are additive).

#[cfg(not(any(feature = "libm", feature = "micromath")))]
compile_error!(
    "nemm-core needs a math backend: enable the `libm` (default) or `micromath` feature"
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
    libm::sqrtf(x)
}

/// Fused multiply-add `a * b + c` with a single rounding.
#[inline(always)]
pub fn fma(a: f32, b: f32, c: f32) -> f32 {
    libm::fmaf(a, b, c)
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
