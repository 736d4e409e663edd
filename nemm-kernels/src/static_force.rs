//! The static force `r` of eq. 17: gas force and seal friction, added to the EMM force.
//!
//! ```text
//! r(x, v, alpha) = F_gas0(alpha) + k_gas(alpha) (x - x_ref) + F_c tanh(v / v_c)
//! F_gas0(alpha)  = F_gas0,0 + F_gas0,alpha alpha        (gas force at x_ref)
//! k_gas(alpha)   = k_gas,0 + k_gas,alpha alpha          (gas spring)
//! ```
//!
//! - `x` \[m\]: the stroke position as the position sensor measures it (its zero need not be
//!   the stroke centre; `x_ref` is a position inside the training data, so `F_gas0` is the
//!   gas force there);
//! - `v` \[m/s\]: the stroke velocity (the model's input);
//! - `F_c >= 0` \[N\]: seal friction, a Coulomb force smoothed over `v_c > 0` \[m/s\].
//!
//! `r` depends on the measured inputs only: it adds to the force and does not enter the
//! EMM states. It is linear in its five trained parameters ([`StaticForce::params`]) with
//! the features of [`features`], which the estimator and the trainer share.

use crate::error::ModelError;
use crate::math::Scalar;
use serde::{Deserialize, Serialize};

/// Number of trained parameters of a [`StaticForce`] ([`StaticForce::params`]).
pub const STATIC_PARAMS: usize = 5;

/// Gas force and seal friction (module docs). Every field is finite; `f_c_n >= 0`,
/// `v_c_m_s > 0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StaticForce {
    /// Gas force `F_gas0,0` at `x_ref` and `alpha = 0` \[N\].
    pub f_gas0_n: f32,
    /// Change of the gas force at `x_ref` per unit `alpha`, `F_gas0,alpha` \[N\].
    pub f_gas0_per_alpha_n: f32,
    /// Gas spring `k_gas,0` at `alpha = 0` \[N/m\].
    pub k_gas_n_per_m: f32,
    /// Change of the gas spring per unit `alpha`, `k_gas,alpha` \[N/m\].
    pub k_gas_per_alpha_n_per_m: f32,
    /// Reference stroke position `x_ref` \[m\] in the position sensor's coordinates.
    pub x_ref_m: f32,
    /// Seal friction `F_c` \[N\], >= 0.
    pub f_c_n: f32,
    /// Smoothing velocity `v_c` of the friction \[m/s\], > 0.
    pub v_c_m_s: f32,
}

/// `tanh(z)` as `1 - 2 / (e^{2z} + 1)`: finite for every finite `z` (`e^{2z}` overflowing to
/// infinity gives 1, underflowing to 0 gives -1).
#[inline(always)]
pub fn tanh<S: Scalar>(z: S) -> S {
    let one = S::from_f32(1.0);
    let two = S::from_f32(2.0);
    one - two / (S::exp(two * z) + one)
}

/// The features `[1, alpha, x - x_ref, alpha (x - x_ref), tanh(v / v_c)]` whose dot product
/// with [`StaticForce::params`] is `r` (position `x` \[m\], velocity `v` \[m/s\]).
#[inline(always)]
pub fn features<S: Scalar>(x_ref: S, v_c: S, x: S, v: S, alpha: S) -> [S; STATIC_PARAMS] {
    let dx = x - x_ref;
    [S::from_f32(1.0), alpha, dx, alpha * dx, tanh(v / v_c)]
}

impl StaticForce {
    /// An example static force for tests, examples and fuzz seeds: gas offset -90 N at
    /// `x_ref` = 30 mm, gas spring 800 N/m, seal friction 15 N smoothed over 5 mm/s, both gas
    /// terms depending on alpha.
    pub const EXAMPLE: StaticForce = StaticForce {
        f_gas0_n: -90.0,
        f_gas0_per_alpha_n: 20.0,
        k_gas_n_per_m: 800.0,
        k_gas_per_alpha_n_per_m: -200.0,
        x_ref_m: 0.03,
        f_c_n: 15.0,
        v_c_m_s: 0.005,
    };

    /// The trained parameters in the order of [`features`]:
    /// `[F_gas0,0, F_gas0,alpha, k_gas,0, k_gas,alpha, F_c]`.
    pub const fn params(&self) -> [f32; STATIC_PARAMS] {
        [
            self.f_gas0_n,
            self.f_gas0_per_alpha_n,
            self.k_gas_n_per_m,
            self.k_gas_per_alpha_n_per_m,
            self.f_c_n,
        ]
    }

    /// The static force with parameters `p` (order of [`StaticForce::params`]) and the
    /// fixed `x_ref`, `v_c` of `self`.
    pub const fn with_params(&self, p: [f32; STATIC_PARAMS]) -> Self {
        Self {
            f_gas0_n: p[0],
            f_gas0_per_alpha_n: p[1],
            k_gas_n_per_m: p[2],
            k_gas_per_alpha_n_per_m: p[3],
            x_ref_m: self.x_ref_m,
            f_c_n: p[4],
            v_c_m_s: self.v_c_m_s,
        }
    }

    /// `r` \[N\] at stroke position `x` \[m\], stroke velocity `v` \[m/s\] and `alpha`.
    #[inline]
    pub fn force(&self, x_m: f32, v_m_s: f32, alpha: f32) -> f32 {
        let phi = features(self.x_ref_m, self.v_c_m_s, x_m, v_m_s, alpha);
        self.params()
            .iter()
            .zip(phi.iter())
            .fold(0.0, |r, (&p, &f)| crate::math::fma(p, f, r))
    }

    /// Checks the fields: all finite, `f_c_n >= 0`, `v_c_m_s > 0`.
    pub fn validate(&self) -> Result<(), ModelError> {
        for (v, field) in [
            (self.f_gas0_n, "static_force.f_gas0_n"),
            (self.f_gas0_per_alpha_n, "static_force.f_gas0_per_alpha_n"),
            (self.k_gas_n_per_m, "static_force.k_gas_n_per_m"),
            (
                self.k_gas_per_alpha_n_per_m,
                "static_force.k_gas_per_alpha_n_per_m",
            ),
            (self.x_ref_m, "static_force.x_ref_m"),
            (self.f_c_n, "static_force.f_c_n"),
            (self.v_c_m_s, "static_force.v_c_m_s"),
        ] {
            if !v.is_finite() {
                return Err(ModelError::NonFinite { field });
            }
        }
        if self.f_c_n < 0.0 {
            return Err(ModelError::Negative {
                field: "static_force.f_c_n",
            });
        }
        if self.v_c_m_s <= 0.0 {
            return Err(ModelError::NotPositive {
                field: "static_force.v_c_m_s",
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> StaticForce {
        StaticForce::EXAMPLE
    }

    #[test]
    fn force_is_the_documented_sum() {
        let s = example();
        let (x, v, a) = (0.05f32, -0.2f32, 0.3f32);
        let expected =
            (-90.0 + 20.0 * a) + (800.0 - 200.0 * a) * (x - 0.03) + 15.0 * libm::tanhf(v / 0.005);
        assert!((s.force(x, v, a) - expected).abs() < 0.1);
        assert_eq!(s.with_params(s.params()), s);
    }

    #[test]
    fn tanh_is_finite_and_accurate_everywhere() {
        for z in [-1e30f32, -100.0, -3.0, -0.1, 0.0, 1e-6, 0.7, 44.0, 1e30] {
            let t = tanh(z);
            let tol = if cfg!(feature = "micromath") {
                5e-3
            } else {
                2e-6
            };
            assert!(
                t.is_finite() && (t - libm::tanhf(z)).abs() < tol,
                "{z}: {t}"
            );
        }
        assert!((tanh(0.5f64) - libm::tanh(0.5)).abs() < 1e-15);
    }

    #[test]
    fn validation_refuses_each_bad_field() {
        assert_eq!(example().validate(), Ok(()));
        let mut s = example();
        s.k_gas_n_per_m = f32::NAN;
        assert_eq!(
            s.validate(),
            Err(ModelError::NonFinite {
                field: "static_force.k_gas_n_per_m"
            })
        );
        let mut s = example();
        s.f_c_n = -1.0;
        assert_eq!(
            s.validate(),
            Err(ModelError::Negative {
                field: "static_force.f_c_n"
            })
        );
        let mut s = example();
        s.v_c_m_s = 0.0;
        assert_eq!(
            s.validate(),
            Err(ModelError::NotPositive {
                field: "static_force.v_c_m_s"
            })
        );
    }
}
