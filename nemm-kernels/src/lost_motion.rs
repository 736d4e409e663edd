//! The lost-motion element: free gas (foamed oil) in series with the pressure-force stiffness
//! `k_pr`, so that the pressure force builds only after a travel that grows with the oil loss.
//!
//! A damper that loses oil draws gas into its chambers. Gas bubbles compress before the
//! pressure builds: after a stroke reversal the rod travels with little force, then the
//! force rises to what the valves set. Measured difference loops F(0) - F(alpha) put most of
//! that change on the compression stroke just after the upper reversal (the paper's Fig. 5).
//! A linear `k_pr x_pr` softened symmetrically cannot form that one-sided lost motion; this
//! element can.
//!
//! # The element
//!
//! The pressure pair's spring force `f` deflects the liquid stiffness `k_l` (the model's
//! `k_pr`, constant or neural) and the gas of the loaded side, isothermal bubbles of travel
//! `d` taken up over the force scale `f0`:
//!
//! ```text
//! x_pr = f / k_l + sgn(f) d_side(alpha) |f| / (|f| + f0)
//! d_side(alpha) = max(0, d_side,0 + d_side,alpha alpha)     side: rebound (x_pr >= 0), compression (x_pr < 0)
//! ```
//!
//! Solved for `f` (a quadratic, one positive root), the spring force is `k_eff x_pr` with
//! the secant stiffness
//!
//! ```text
//! k_eff = k_l g,   g = 2 c / (B + sqrt(B^2 + 4 |x_pr| c)),   B = c + d - |x_pr|,   c = f0 / k_l
//! ```
//!
//! `0 < g <= 1`; at `x_pr = 0`, `g = c / (c + d)` (finite: the element is smooth in
//! `x_pr` on each side); for `|x_pr| >> d`, `g -> 1`. The tangent stiffness `df/dx_pr` never
//! exceeds `k_l` (`dx_pr/df >= 1/k_l`), so the stability bound of the model
//! (nemm-core's model: `k_pr,ini s_max,k`) holds with the element. With `d = 0` the element
//! is the paper's `k_pr` exactly (`g = 1`).
//!
//! `B + sqrt(...)` loses digits when `B` is much below zero (a deflection far beyond the
//! travel): the relative error of `g` is about `eps |B| / c`, below `1e-5` in `f32` as
//! long as the force stays below a few hundred `f0`.
//!
//! # Priors
//!
//! `d_side,alpha >= 0` on both sides (every trained value is an exponential), so the travel
//! grows and `k_eff` falls with the level: the paper's prior on `k_pr` (oil loss softens the
//! pressure build-up) holds by construction.

use crate::error::ModelError;
use crate::math::Lane;
use serde::{Deserialize, Serialize};

/// Number of parameters of a [`LostMotion`] ([`LostMotion::params`]).
pub const LOST_MOTION_PARAMS: usize = 5;

/// The lost-motion element (module docs). Every field is finite; `f0_n > 0`, the travels
/// and their slopes `>= 0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LostMotion {
    /// Force scale `f0` over which the gas travel is taken up \[N\], > 0.
    pub f0_n: f32,
    /// Compression-side travel `d_c,0` at `alpha = 0` \[m\], >= 0.
    pub travel_c_m: f32,
    /// Growth of the compression-side travel per unit `alpha`, `d_c,alpha` \[m\], >= 0.
    pub travel_c_per_alpha_m: f32,
    /// Rebound-side travel `d_r,0` at `alpha = 0` \[m\], >= 0.
    pub travel_r_m: f32,
    /// Growth of the rebound-side travel per unit `alpha`, `d_r,alpha` \[m\], >= 0.
    pub travel_r_per_alpha_m: f32,
}

/// The element at one level: `f0` and the travel of each side.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LostMotionAt<L = f32> {
    /// `f0` \[N\].
    pub f0_n: L,
    /// Compression-side travel `d_c(alpha)` \[m\].
    pub travel_c_m: L,
    /// Rebound-side travel `d_r(alpha)` \[m\].
    pub travel_r_m: L,
}

impl LostMotion {
    /// The parameters in the order `[f0, d_c,0, d_c,alpha, d_r,0, d_r,alpha]`.
    pub const fn params(&self) -> [f32; LOST_MOTION_PARAMS] {
        [
            self.f0_n,
            self.travel_c_m,
            self.travel_c_per_alpha_m,
            self.travel_r_m,
            self.travel_r_per_alpha_m,
        ]
    }

    /// The element with parameters `p` (order of [`LostMotion::params`]).
    pub const fn from_params(p: [f32; LOST_MOTION_PARAMS]) -> Self {
        Self {
            f0_n: p[0],
            travel_c_m: p[1],
            travel_c_per_alpha_m: p[2],
            travel_r_m: p[3],
            travel_r_per_alpha_m: p[4],
        }
    }

    /// Finite values, `f0 > 0`, travels and slopes `>= 0`.
    pub fn validate(&self) -> Result<(), ModelError> {
        let field = "lost_motion";
        if !self.params().iter().all(|v| v.is_finite()) {
            return Err(ModelError::NonFinite { field });
        }
        if self.f0_n <= 0.0 {
            return Err(ModelError::NotPositive {
                field: "lost_motion.f0_n",
            });
        }
        if self.params().iter().any(|&v| v < 0.0) {
            return Err(ModelError::Negative { field });
        }
        Ok(())
    }

    /// `f0` and the travels at level `alpha` (each clamped at 0).
    pub fn at(&self, alpha: f32) -> LostMotionAt {
        let d = |d0: f32, d1: f32| libm::fmaxf(0.0, d0 + d1 * alpha);
        LostMotionAt {
            f0_n: self.f0_n,
            travel_c_m: d(self.travel_c_m, self.travel_c_per_alpha_m),
            travel_r_m: d(self.travel_r_m, self.travel_r_per_alpha_m),
        }
    }
}

/// `g = 2 c / (B + sqrt(B^2 + 4 x c))`, `B = c + d - x` (module docs) for `x = |x_pr|`,
/// `c = f0 / k_l` \[m\], travel `d` \[m\]; with `D = B + sqrt(...)` for the backward pass.
#[inline(always)]
fn factor<L: Lane>(x: L, c: L, d: L) -> (L, L, L, L) {
    let b = c + d - x;
    let s = L::sqrt(L::fma(b, b, L::constant(4.0) * x * c));
    let den = b + s;
    (L::constant(2.0) * c / den, b, s, den)
}

impl<L: Lane> LostMotionAt<L> {
    /// The travel on the side of `x_pr` and `|x_pr|`.
    #[inline(always)]
    fn side(&self, x_pr: L) -> (L, L) {
        (
            L::select_nonneg(x_pr, x_pr, -x_pr),
            L::select_nonneg(x_pr, self.travel_r_m, self.travel_c_m),
        )
    }

    /// The secant stiffness `k_eff` \[N/m\] at deflection `x_pr` \[m\] for the liquid
    /// stiffness `k_l` \[N/m\] (the model's `k_pr`).
    #[inline(always)]
    pub fn k_eff(&self, k_l: L, x_pr: L) -> L {
        let (x, d) = self.side(x_pr);
        k_l * factor(x, self.f0_n / k_l, d).0
    }

    #[cfg(feature = "reverse")]
    #[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
    /// Reverse mode of [`Self::k_eff`]: given `kbar = dL/dk_eff`, returns `dL/dk_l` and
    /// `dL/dx_pr`, and adds `dL/df0` and `dL/d(travel of the loaded side)` to `bar`.
    #[inline(always)]
    pub fn k_eff_backward(&self, k_l: L, x_pr: L, kbar: L, bar: &mut LostMotionAt<L>) -> (L, L) {
        let (x, d) = self.side(x_pr);
        let c = self.f0_n / k_l;
        let (g, b, s, den) = factor(x, c, d);
        // D = B + S, S^2 = B^2 + 4 x c:  dD/dd = 1 + B/S,  dD/dx = -(1 + B/S) + 2c/S,
        // dD/dc = 1 + B/S + 2x/S;  g = 2c/D:  dg/dc = g/c - (g/D) dD/dc.
        let one = L::constant(1.0);
        let two = L::constant(2.0);
        let dd = one + b / s;
        let g_over_den = g / den;
        let dg_dd = -g_over_den * dd;
        let dg_dx = -g_over_den * (two * c / s - dd);
        let dg_dc_times_c = g - g_over_den * c * (dd + two * x / s);
        // k = k_l g(x, c, d), c = f0 / k_l: dk/dk_l = g - c dg/dc, dk/df0 = dg/dc.
        let zero = L::constant(0.0);
        let sign = L::select_nonneg(x_pr, one, -one);
        let dbar = kbar * k_l * dg_dd;
        bar.f0_n = bar.f0_n + kbar * dg_dc_times_c / c;
        bar.travel_r_m = bar.travel_r_m + L::select_nonneg(x_pr, dbar, zero);
        bar.travel_c_m = bar.travel_c_m + L::select_nonneg(x_pr, zero, dbar);
        (kbar * (g - dg_dc_times_c), kbar * k_l * dg_dx * sign)
    }
}

/// The spring force `k_eff x_pr` \[N\] of the element at deflection `x_pr` for the liquid
/// stiffness `k_l` (a check of the closed form: it solves the module's `x_pr(f)`).
pub fn spring_force<L: Lane>(at: &LostMotionAt<L>, k_l: L, x_pr: L) -> L {
    at.k_eff(k_l, x_pr) * x_pr
}

#[cfg(test)]
mod tests {
    use super::*;

    const LM: LostMotion = LostMotion {
        f0_n: 1500.0,
        travel_c_m: 3.4e-3,
        travel_c_per_alpha_m: 30e-3,
        travel_r_m: 1.3e-3,
        travel_r_per_alpha_m: 7.7e-3,
    };
    const K_L: f64 = 2.0e6;

    fn at64(alpha: f32) -> LostMotionAt<f64> {
        let a = LM.at(alpha);
        LostMotionAt {
            f0_n: f64::from(a.f0_n),
            travel_c_m: f64::from(a.travel_c_m),
            travel_r_m: f64::from(a.travel_r_m),
        }
    }

    /// The closed form inverts `x_pr(f) = f / k_l + sgn(f) d |f| / (|f| + f0)`.
    #[test]
    fn secant_stiffness_solves_the_element() {
        let at = at64(0.3);
        for f in [
            -4000.0f64, -1500.0, -200.0, -1.0, 1.0, 300.0, 2500.0, 6000.0,
        ] {
            let d = if f >= 0.0 {
                at.travel_r_m
            } else {
                at.travel_c_m
            };
            let x = f / K_L + f.signum() * d * f.abs() / (f.abs() + at.f0_n);
            let back = spring_force(&at, K_L, x);
            assert!((back - f).abs() < 1e-9 * f.abs().max(1.0), "{f}: {back}");
        }
        // At x_pr = 0: g = c / (c + d); no travel: the liquid stiffness.
        let c = at.f0_n / K_L;
        let k0 = at.k_eff(K_L, 0.0);
        assert!((k0 / K_L - c / (c + at.travel_r_m)).abs() < 1e-12);
        let none = LostMotionAt {
            f0_n: 1500.0,
            travel_c_m: 0.0,
            travel_r_m: 0.0,
        };
        for x in [-0.02, -1e-4, 0.0, 1e-3, 0.05] {
            assert!((none.k_eff(K_L, x) - K_L).abs() < 1e-6 * K_L);
        }
    }

    /// The element softens with the level on both sides, more on the compression side.
    #[test]
    fn travel_grows_with_alpha() {
        let (a0, a3) = (LM.at(0.0), LM.at(0.3));
        assert!(a3.travel_c_m > a0.travel_c_m && a3.travel_r_m > a0.travel_r_m);
        let k = |a: &LostMotionAt, x: f32| a.k_eff(2.0e6, x);
        assert!(k(&a3, -2e-3) < k(&a0, -2e-3) && k(&a3, 2e-3) < k(&a0, 2e-3));
        assert!(k(&a3, -2e-3) < k(&a3, 2e-3));
        assert!(LM.validate().is_ok());
        let bad = LostMotion {
            travel_c_per_alpha_m: -1e-3,
            ..LM
        };
        assert!(bad.validate().is_err());
        let bad = LostMotion { f0_n: 0.0, ..LM };
        assert!(bad.validate().is_err());
        let bad = LostMotion {
            travel_r_m: f32::NAN,
            ..LM
        };
        assert!(bad.validate().is_err());
    }

    /// The reverse mode against central differences (f64), on both sides and both
    /// branches of `B`.
    #[cfg(feature = "reverse")]
    #[test]
    fn backward_matches_finite_differences() {
        let at = at64(0.2);
        for &x in &[-0.03, -4e-3, -1e-4, 2e-5, 1.5e-3, 0.02] {
            let k_l = K_L * 0.7;
            let mut bar = LostMotionAt::default();
            let (dk_l, dx) = at.k_eff_backward(k_l, x, 1.0, &mut bar);
            let h = |v: f64| 1e-6 * v.abs().max(1e-9);
            let num = |f: &dyn Fn(f64) -> f64, v: f64| (f(v + h(v)) - f(v - h(v))) / (2.0 * h(v));
            let want_kl = num(&|v| at.k_eff(v, x), k_l);
            let want_x = num(&|v| at.k_eff(k_l, v), x);
            let want_f0 = num(&|v| LostMotionAt { f0_n: v, ..at }.k_eff(k_l, x), at.f0_n);
            let (d_side, bar_side, bar_other) = if x >= 0.0 {
                (at.travel_r_m, bar.travel_r_m, bar.travel_c_m)
            } else {
                (at.travel_c_m, bar.travel_c_m, bar.travel_r_m)
            };
            let want_d = num(
                &|v| {
                    let mut a = at;
                    if x >= 0.0 {
                        a.travel_r_m = v;
                    } else {
                        a.travel_c_m = v;
                    }
                    a.k_eff(k_l, x)
                },
                d_side,
            );
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-5 * b.abs().max(1e-3 * K_L);
            assert!(close(dk_l, want_kl), "x {x}: dk_l {dk_l} vs {want_kl}");
            assert!(
                (dx - want_x).abs() <= 1e-5 * want_x.abs().max(1.0),
                "x {x}: dx {dx} vs {want_x}"
            );
            assert!(
                (bar.f0_n - want_f0).abs() <= 1e-5 * want_f0.abs().max(1.0),
                "x {x}: df0 {} vs {want_f0}",
                bar.f0_n
            );
            assert!(
                (bar_side - want_d).abs() <= 1e-5 * want_d.abs().max(1.0),
                "x {x}: dd {bar_side} vs {want_d}"
            );
            assert_eq!(bar_other, 0.0);
        }
    }
}
