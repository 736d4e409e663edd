//! Fixed-step explicit Runge-Kutta integrators (RK4 and RK3) with a defined input hold.
//!
//! # Input between samples: linear interpolation (first-order hold)
//!
//! The input is sampled at the step: `u_n = u(t_n)`. A step from `t_n` to `t_n+1 = t_n + dt`
//! uses `u_n` at the start, `u_n+1` at the end and their mean `u_m = 0.5 * (u_n + u_n+1)` at
//! the midpoint. This is exact for piecewise-linear inputs, keeps RK4 fourth-order for smooth
//! inputs, and is causal for an online estimator: the step that ends at the newest sample
//! needs nothing newer. The output at `t_n+1` is `F(x_n+1, u_n+1)`.
//!
//! # Exact f32 arithmetic (the trainer reproduces it operation for operation)
//!
//! `fma(a, b, c)` is a fused multiply-add, applied per state component; `h2 = 0.5 * dt`,
//! `h6 = dt / 6` are computed once per configuration.
//!
//! ```text
//! RK4 (classical):                          RK3 (Kutta's third order):
//! u_m = 0.5 * (u_n + u_n+1)                 u_m = 0.5 * (u_n + u_n+1)
//! k1 = f(x_n, u_n)                          k1 = f(x_n, u_n)
//! k2 = f(fma(h2, k1, x_n), u_m)             k2 = f(fma(h2, k1, x_n), u_m)
//! k3 = f(fma(h2, k2, x_n), u_m)             k3 = f(fma(dt, 2*k2 - k1, x_n), u_n+1)
//! k4 = f(fma(dt, k3, x_n), u_n+1)           x_n+1 = fma(h6, fma(4, k2, k1 + k3), x_n)
//! x_n+1 = fma(h6, (k1 + k4) + 2*(k2 + k3), x_n)
//! ```
//!
//! The coefficients (`b_fl`, `b_pr`, `k_pr`) of stage 1 are those of the previous step's
//! output evaluation at the same state, so they are passed in and never recomputed.

use crate::emm::{self, Coefficients, State};
use crate::math::{Fused, MulAdd};
use serde::{Deserialize, Serialize};

/// Explicit Runge-Kutta scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Integrator {
    /// Classical fourth-order Runge-Kutta (4 stages).
    Rk4,
    /// Kutta's third-order method (3 stages).
    Rk3,
}

impl Integrator {
    /// Real-axis stability limit: the scheme is stable for a decaying mode
    /// `x' = -x / tau` when `dt / tau <= limit` (RK4: 2.785, RK3: 2.512).
    pub const fn stability_limit(self) -> f32 {
        match self {
            Integrator::Rk4 => 2.785,
            Integrator::Rk3 => 2.512,
        }
    }

    /// Number of right-hand-side evaluations per step.
    pub const fn stages(self) -> usize {
        match self {
            Integrator::Rk4 => 4,
            Integrator::Rk3 => 3,
        }
    }

    /// Lower-case name (`"rk4"`, `"rk3"`).
    pub const fn name(self) -> &'static str {
        match self {
            Integrator::Rk4 => "rk4",
            Integrator::Rk3 => "rk3",
        }
    }
}

/// Precomputed step constants.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepSize {
    /// `dt` \[s\].
    pub dt: f32,
    /// `dt / 2`.
    pub h2: f32,
    /// `dt / 6`.
    pub h6: f32,
}

impl StepSize {
    /// Constants for step `dt_s` \[s\].
    pub fn new(dt_s: f32) -> Self {
        Self {
            dt: dt_s,
            h2: 0.5 * dt_s,
            h6: dt_s / 6.0,
        }
    }
}

#[inline(always)]
fn axpy<M: MulAdd>(a: f32, k: &State, x: &State) -> State {
    State {
        x_pr_m: M::mul_add(a, k.x_pr_m, x.x_pr_m),
        v_st_m_s: M::mul_add(a, k.v_st_m_s, x.v_st_m_s),
    }
}

/// The coefficients at an RK stage's state (an intermediate state of a step).
///
/// Closures `FnMut(&State) -> Coefficients` are used through [`step`]; a type implementing
/// this trait with an `#[inline(always)]` method (the estimator's tabulated coefficients) is
/// inlined into [`step_with`] at every stage whatever its size.
pub trait Stage {
    /// Coefficients at `s`.
    fn coeffs(&mut self, s: &State) -> Coefficients;
}

/// A closure as a [`Stage`].
struct FromFn<C>(C);

impl<C: FnMut(&State) -> Coefficients> Stage for FromFn<C> {
    #[inline(always)]
    fn coeffs(&mut self, s: &State) -> Coefficients {
        (self.0)(s)
    }
}

/// One step from `x` (at which the coefficients are `c1`) with input `u0` at the start and
/// `u1` at the end. `coeffs` evaluates the coefficients at an intermediate state;
/// `inv_t_pr` is `1 / T_pr` \[1/s\]. Fused multiply-adds (the reference arithmetic).
#[inline(always)]
#[allow(clippy::too_many_arguments)] // the step's inputs are all distinct; a struct would only rename them
pub fn step<C: FnMut(&State) -> Coefficients>(
    scheme: Integrator,
    coeffs: C,
    c1: &Coefficients,
    inv_t_pr: f32,
    x: &State,
    u0: f32,
    u1: f32,
    h: &StepSize,
) -> State {
    step_with::<Fused, _>(scheme, &mut FromFn(coeffs), c1, inv_t_pr, x, u0, u1, h)
}

/// [`step`] with the multiply-add `M` (the module's formulas with `fma` replaced by
/// `M::mul_add`) and the stage coefficients of `stage`.
#[inline(always)]
#[allow(clippy::too_many_arguments)] // as `step`
pub fn step_with<M: MulAdd, S: Stage>(
    scheme: Integrator,
    stage: &mut S,
    c1: &Coefficients,
    inv_t_pr: f32,
    x: &State,
    u0: f32,
    u1: f32,
    h: &StepSize,
) -> State {
    let um = 0.5 * (u0 + u1);
    let k1 = emm::rhs_with::<M>(c1, inv_t_pr, x, u0);
    let x2 = axpy::<M>(h.h2, &k1, x);
    let k2 = emm::rhs_with::<M>(&stage.coeffs(&x2), inv_t_pr, &x2, um);
    match scheme {
        Integrator::Rk4 => {
            let x3 = axpy::<M>(h.h2, &k2, x);
            let k3 = emm::rhs_with::<M>(&stage.coeffs(&x3), inv_t_pr, &x3, um);
            let x4 = axpy::<M>(h.dt, &k3, x);
            let k4 = emm::rhs_with::<M>(&stage.coeffs(&x4), inv_t_pr, &x4, u1);
            let sum = State {
                x_pr_m: (k1.x_pr_m + k4.x_pr_m) + 2.0 * (k2.x_pr_m + k3.x_pr_m),
                v_st_m_s: (k1.v_st_m_s + k4.v_st_m_s) + 2.0 * (k2.v_st_m_s + k3.v_st_m_s),
            };
            axpy::<M>(h.h6, &sum, x)
        }
        Integrator::Rk3 => {
            let d = State {
                x_pr_m: 2.0 * k2.x_pr_m - k1.x_pr_m,
                v_st_m_s: 2.0 * k2.v_st_m_s - k1.v_st_m_s,
            };
            let x3 = axpy::<M>(h.dt, &d, x);
            let k3 = emm::rhs_with::<M>(&stage.coeffs(&x3), inv_t_pr, &x3, u1);
            let sum = State {
                x_pr_m: M::mul_add(4.0, k2.x_pr_m, k1.x_pr_m + k3.x_pr_m),
                v_st_m_s: M::mul_add(4.0, k2.v_st_m_s, k1.v_st_m_s + k3.v_st_m_s),
            };
            axpy::<M>(h.h6, &sum, x)
        }
    }
}

impl core::str::FromStr for Integrator {
    type Err = crate::model::UnknownName;

    /// Parses [`Integrator::name`]'s spelling (`rk4`, `rk3`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        [Integrator::Rk4, Integrator::Rk3]
            .into_iter()
            .find(|i| i.name() == s)
            .ok_or(crate::model::UnknownName {
                what: "integrator",
                expected: "rk4 or rk3",
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integrators_parse_from_their_names_only() {
        assert_eq!("rk4".parse::<Integrator>(), Ok(Integrator::Rk4));
        assert_eq!("rk3".parse::<Integrator>(), Ok(Integrator::Rk3));
        let err = "RK4".parse::<Integrator>().unwrap_err();
        assert_eq!(err.what, "integrator");
        assert_eq!(err.expected, "rk4 or rk3");
    }

    /// Linear EMM with constant coefficients; closed-form single step for u = const:
    /// x_pr' = u - q, q = (k x + b_pr u) / (b_pr + b_fl) => x' = -a x + c u with
    /// a = k / (b_pr + b_fl), c = b_fl / (b_pr + b_fl); x(dt) = x_inf + (x0 - x_inf) e^{-a dt}.
    #[test]
    fn rk4_step_matches_closed_form() {
        let c = Coefficients {
            b_fl: 2000.0,
            b_pr: 800.0,
            k_pr: 5.6e5,
        };
        let u = 0.4f32;
        let t = 0.002f32;
        let x0 = State {
            x_pr_m: 0.0005,
            v_st_m_s: -0.1,
        };
        let dt = 1e-4f32;
        let x1 = step(
            Integrator::Rk4,
            |_| c,
            &c,
            1.0 / t,
            &x0,
            u,
            u,
            &StepSize::new(dt),
        );
        let (k, bp, bf) = (5.6e5f64, 800.0f64, 2000.0f64);
        let (uu, dt64, t64) = (0.4f64, 1e-4f64, 0.002f64);
        let a = k / (bp + bf);
        let x_inf = bf * uu / k;
        let x_exact = x_inf + (0.0005 - x_inf) * (-a * dt64).exp();
        // v' = (q - v)/T with q = (k x + bp u)/(bp + bf) = u - x' ... solve exactly:
        // q(t) = u - x'(t) = u + a (x0 - x_inf) e^{-a t} = u + A e^{-a t}
        let big_a = a * (0.0005 - x_inf);
        let v0 = -0.1f64;
        let inv = 1.0 / t64;
        // v(t) = u + (v0 - u) e^{-t/T} + A inv/(inv - a) (e^{-a t} - e^{-t/T})
        let v_exact = uu
            + (v0 - uu) * (-dt64 * inv).exp()
            + big_a * inv / (inv - a) * ((-a * dt64).exp() - (-dt64 * inv).exp());
        // RK4 local error ~ (a dt)^5 / 120 ~ 1e-7 relative here; f32 rounding ~ 1e-7.
        assert!(
            (x1.x_pr_m as f64 - x_exact).abs() < 2e-9,
            "{} {}",
            x1.x_pr_m,
            x_exact
        );
        assert!(
            (x1.v_st_m_s as f64 - v_exact).abs() < 2e-6,
            "{} {}",
            x1.v_st_m_s,
            v_exact
        );
    }

    #[test]
    fn rk3_is_third_order_on_decay() {
        // One RK3 step of x' = -x/tau (b_pr = 0 limit) must equal 1 + z + z^2/2 + z^3/6.
        let c = Coefficients {
            b_fl: 1.0,
            b_pr: 1e-30,
            k_pr: 100.0,
        };
        let x0 = State {
            x_pr_m: 1.0,
            v_st_m_s: 0.0,
        };
        let dt = 1e-3f32;
        let x1 = step(
            Integrator::Rk3,
            |_| c,
            &c,
            1.0,
            &x0,
            0.0,
            0.0,
            &StepSize::new(dt),
        );
        let z = -0.1f64;
        let r = 1.0 + z + z * z / 2.0 + z * z * z / 6.0;
        assert!((x1.x_pr_m as f64 - r).abs() < 1e-6);
    }
}
