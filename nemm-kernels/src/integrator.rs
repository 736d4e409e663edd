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
//! [`step_with`] is written once over any [`Lane`] (the estimator's `f32`, the trainer's
//! packed `Lanes`) and multiply-add [`MulAdd`]; `step_backward` (feature `reverse`), its
//! reverse mode for the trainer, follows it stage by stage.
//!
//! The coefficients (`b_fl`, `b_pr`, `k_pr`) of stage 1 are those of the previous step's
//! output evaluation at the same state, so they are passed in and never recomputed.

use crate::emm::{self, Coefficients, State};
use crate::math::Fused;
use crate::math::{Lane, MulAdd};
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

/// A scheme's Butcher tableau: stage `i` evaluates the right-hand side at
/// `x + dt sum_j a[i][j] k_j` with the input at `t + c[i] dt` (linear between the samples,
/// module docs), and the step is `x + dt sum_i b[i] k_i`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tableau {
    /// Stage coefficients, row `i` of length `i` (explicit).
    pub a: &'static [&'static [f32]],
    /// Weights of the stages.
    pub b: &'static [f32],
    /// Stage times as fractions of the step.
    pub c: &'static [f32],
}

impl Integrator {
    /// The scheme's Butcher tableau: its definition, which [`step_tableau`] runs as written.
    /// [`step_with`] is each scheme's own kernel (fewer operations, and the rounding the
    /// trainer's reverse mode reproduces); `tests/integrator.rs` checks that the two agree
    /// to within one unit of rounding of the state's scale.
    pub const fn tableau(self) -> Tableau {
        match self {
            Integrator::Rk4 => Tableau {
                a: &[&[], &[0.5], &[0.0, 0.5], &[0.0, 0.0, 1.0]],
                b: &[1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0],
                c: &[0.0, 0.5, 0.5, 1.0],
            },
            Integrator::Rk3 => Tableau {
                a: &[&[], &[0.5], &[-1.0, 2.0]],
                b: &[1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0],
                c: &[0.0, 0.5, 1.0],
            },
        }
    }
}

/// Most stages [`step_tableau`] runs.
pub const MAX_TABLEAU_STAGES: usize = 8;

/// One explicit Runge-Kutta step of any `tableau` (at most [`MAX_TABLEAU_STAGES`] stages;
/// further stages are ignored) from `x` with input `u0` at the start and `u1` at the end,
/// `dt` \[s\], `inv_t_pr = 1 / T_pr` \[1/s\], the coefficients at each stage's state from
/// `coeffs`; sums in stage order with fused multiply-adds. The reference a new scheme needs
/// nothing but its tableau for; the estimator runs [`step`].
pub fn step_tableau<C: FnMut(&State) -> Coefficients>(
    tableau: &Tableau,
    mut coeffs: C,
    inv_t_pr: f32,
    x: &State,
    u0: f32,
    u1: f32,
    dt: f32,
) -> State {
    let mut k = [State::default(); MAX_TABLEAU_STAGES];
    let stages = tableau.b.len().min(tableau.c.len()).min(MAX_TABLEAU_STAGES);
    for (i, &ci) in tableau.c.iter().enumerate().take(stages) {
        let row = tableau.a.get(i).copied().unwrap_or(&[]);
        let (mut sx, mut sv) = (0.0f32, 0.0f32);
        for (a, kj) in row.iter().zip(k.iter().take(i)) {
            sx = crate::math::fma(*a, kj.x_pr_m, sx);
            sv = crate::math::fma(*a, kj.v_st_m_s, sv);
        }
        let s = State {
            x_pr_m: crate::math::fma(dt, sx, x.x_pr_m),
            v_st_m_s: crate::math::fma(dt, sv, x.v_st_m_s),
        };
        let u = crate::math::fma(ci, u1 - u0, u0);
        if let Some(ki) = k.get_mut(i) {
            *ki = emm::rhs(&coeffs(&s), inv_t_pr, &s, u);
        }
    }
    let (mut sx, mut sv) = (0.0f32, 0.0f32);
    for (b, ki) in tableau.b.iter().zip(k.iter().take(stages)) {
        sx = crate::math::fma(*b, ki.x_pr_m, sx);
        sv = crate::math::fma(*b, ki.v_st_m_s, sv);
    }
    State {
        x_pr_m: crate::math::fma(dt, sx, x.x_pr_m),
        v_st_m_s: crate::math::fma(dt, sv, x.v_st_m_s),
    }
}

/// Precomputed step constants (per lane: the same in every lane).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepSize<L = f32> {
    /// `dt` \[s\].
    pub dt: L,
    /// `dt / 2`.
    pub h2: L,
    /// `dt / 6`.
    pub h6: L,
}

impl StepSize {
    /// Constants for step `dt_s` \[s\].
    pub fn new(dt_s: f32) -> Self {
        Self::splat(dt_s)
    }
}

impl<L: Lane> StepSize<L> {
    /// Constants for step `dt` (an element of the lane type), in every lane.
    pub fn splat(dt: L::Scalar) -> Self {
        let dt = L::splat(dt);
        Self {
            dt,
            h2: L::constant(0.5) * dt,
            h6: dt / L::constant(6.0),
        }
    }
}

/// The coefficients at an RK stage's state (an intermediate state of a step).
///
/// Closures `FnMut(&State) -> Coefficients` are used through [`step`]; a type implementing
/// this trait with an `#[inline(always)]` method (the estimator's tabulated coefficients) is
/// inlined into [`step_with`] at every stage whatever its size.
pub trait Stage<L = f32> {
    /// Coefficients at `s`.
    fn coeffs(&mut self, s: &State<L>) -> Coefficients<L>;
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
    step_with::<Fused, f32, _>(scheme, &mut FromFn(coeffs), c1, inv_t_pr, x, u0, u1, h)
}

/// [`step`] with the multiply-add `M` (the module's formulas with `fma` replaced by
/// `M::mul_add`) and the stage coefficients of `stage`, on any lane type: the one
/// definition of the schemes, used by the estimator (`f32`) and the trainer (packed lanes,
/// whose reverse mode is `step_backward`, feature `reverse`).
#[inline(always)]
#[allow(clippy::too_many_arguments)] // as `step`
pub fn step_with<M: MulAdd, L: Lane, S: Stage<L>>(
    scheme: Integrator,
    stage: &mut S,
    c1: &Coefficients<L>,
    inv_t_pr: L,
    x: &State<L>,
    u0: L,
    u1: L,
    h: &StepSize<L>,
) -> State<L> {
    let um = L::constant(0.5) * (u0 + u1);
    let k1 = emm::rhs_with::<M, L>(c1, inv_t_pr, x, u0);
    let x2 = x.axpy::<M>(h.h2, &k1);
    let k2 = emm::rhs_with::<M, L>(&stage.coeffs(&x2), inv_t_pr, &x2, um);
    match scheme {
        Integrator::Rk4 => {
            let x3 = x.axpy::<M>(h.h2, &k2);
            let k3 = emm::rhs_with::<M, L>(&stage.coeffs(&x3), inv_t_pr, &x3, um);
            let x4 = x.axpy::<M>(h.dt, &k3);
            let k4 = emm::rhs_with::<M, L>(&stage.coeffs(&x4), inv_t_pr, &x4, u1);
            let two = L::constant(2.0);
            let sum = k1
                .zip(&k4, |a, b| a + b)
                .zip(&k2.zip(&k3, |a, b| a + b), |a, b| a + two * b);
            x.axpy::<M>(h.h6, &sum)
        }
        Integrator::Rk3 => {
            let two = L::constant(2.0);
            let d = k2.zip(&k1, |b, a| two * b - a);
            let x3 = x.axpy::<M>(h.dt, &d);
            let k3 = emm::rhs_with::<M, L>(&stage.coeffs(&x3), inv_t_pr, &x3, u1);
            let four = L::constant(4.0);
            let sum = k2.zip(&k1.zip(&k3, |a, b| a + b), |b, a| M::mul_add(four, b, a));
            x.axpy::<M>(h.h6, &sum)
        }
    }
}

/// The coefficients at the RK stages of a step for its reverse mode: the forward evaluation
/// records what the backward needs (the scalers' activations), per stage.
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub trait StageBackward<L> {
    /// Coefficients at the state `s` of stage `i` (1-based: stage 2 is the first
    /// intermediate state; stage 1's coefficients are an input of the step), recorded.
    fn coeffs(&mut self, i: usize, s: &State<L>) -> Coefficients<L>;
    /// Back-propagates `cbar = dL/d(coefficients of stage i)` through the recorded
    /// evaluation: adds `dL/ds` to `sbar` (and accumulates the parameter gradients).
    fn backward(&mut self, i: usize, cbar: &Coefficients<L>, sbar: &mut State<L>);
}

/// Reverse mode of [`step_with`] (exact for `M = Unfused`, up to rounding for `Fused`):
/// recomputes the stages from `x` through `stage` (which records them), then propagates
/// `xbar_next = dL/dx_n+1` back. Adds `dL/dx` to `xbar`, `dL/d(c1)` (stage 1's
/// coefficients, at `x`) to `c1bar` and `dL/d(inv_t_pr)` to `itbar`; the other stages'
/// coefficient adjoints go to [`StageBackward::backward`]. Each block below is the
/// transpose of the forward line it names, in reverse order.
#[inline(always)]
#[allow(clippy::too_many_arguments)] // the step's inputs and the four adjoints
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub fn step_backward<M: MulAdd, L: Lane, S: StageBackward<L>>(
    scheme: Integrator,
    stage: &mut S,
    c1: &Coefficients<L>,
    inv_t_pr: L,
    x: &State<L>,
    u0: L,
    u1: L,
    h: &StepSize<L>,
    xbar_next: &State<L>,
    xbar: &mut State<L>,
    c1bar: &mut Coefficients<L>,
    itbar: &mut L,
) {
    let um = L::constant(0.5) * (u0 + u1);
    let k1 = emm::rhs_with::<M, L>(c1, inv_t_pr, x, u0);
    let x2 = x.axpy::<M>(h.h2, &k1);
    let c2 = stage.coeffs(2, &x2);
    let k2 = emm::rhs_with::<M, L>(&c2, inv_t_pr, &x2, um);
    let add = |a: L, b: L| a + b;
    // The stage: k = rhs(c(xs), xs, u); returns dL/dxs.
    let stage_back = |stage: &mut S,
                      i: usize,
                      c: &Coefficients<L>,
                      xs: &State<L>,
                      u: L,
                      kb: &State<L>,
                      itbar: &mut L| {
        let mut xsb = State::<L>::default();
        let mut cb = Coefficients::<L>::default();
        emm::rhs_backward::<M, L>(c, inv_t_pr, xs, u, kb, &mut xsb, &mut cb, itbar);
        stage.backward(i, &cb, &mut xsb);
        xsb
    };
    // x_n+1 = x + ...: the identity part.
    *xbar = xbar.zip(xbar_next, add);
    let mut k1b;
    let mut k2b;
    match scheme {
        Integrator::Rk4 => {
            let x3 = x.axpy::<M>(h.h2, &k2);
            let c3 = stage.coeffs(3, &x3);
            let k3 = emm::rhs_with::<M, L>(&c3, inv_t_pr, &x3, um);
            let x4 = x.axpy::<M>(h.dt, &k3);
            let c4 = stage.coeffs(4, &x4);
            // x_n+1 = x + h6 ((k1 + k4) + 2 (k2 + k3))
            let a2 = L::constant(2.0) * h.h6;
            k1b = xbar_next.scale(h.h6);
            k2b = xbar_next.scale(a2);
            let mut k3b = xbar_next.scale(a2);
            let k4b = xbar_next.scale(h.h6);
            // k4 = rhs(c4, x4, u1); x4 = x + dt k3
            let x4b = stage_back(stage, 4, &c4, &x4, u1, &k4b, itbar);
            *xbar = xbar.zip(&x4b, add);
            k3b = k3b.zip(&x4b, |a, b| a + h.dt * b);
            // k3 = rhs(c3, x3, um); x3 = x + h2 k2
            let x3b = stage_back(stage, 3, &c3, &x3, um, &k3b, itbar);
            *xbar = xbar.zip(&x3b, add);
            k2b = k2b.zip(&x3b, |a, b| a + h.h2 * b);
        }
        Integrator::Rk3 => {
            let two = L::constant(2.0);
            let d = k2.zip(&k1, |b, a| two * b - a);
            let x3 = x.axpy::<M>(h.dt, &d);
            let c3 = stage.coeffs(3, &x3);
            // x_n+1 = x + h6 (4 k2 + (k1 + k3))
            k1b = xbar_next.scale(h.h6);
            k2b = xbar_next.scale(L::constant(4.0) * h.h6);
            let k3b = xbar_next.scale(h.h6);
            // k3 = rhs(c3, x3, u1); x3 = x + dt (2 k2 - k1)
            let x3b = stage_back(stage, 3, &c3, &x3, u1, &k3b, itbar);
            *xbar = xbar.zip(&x3b, add);
            k2b = k2b.zip(&x3b, |a, b| a + (two * h.dt) * b);
            k1b = k1b.zip(&x3b, |a, b| a + (-h.dt) * b);
        }
    }
    // k2 = rhs(c2, x2, um); x2 = x + h2 k1
    let x2b = stage_back(stage, 2, &c2, &x2, um, &k2b, itbar);
    *xbar = xbar.zip(&x2b, add);
    k1b = k1b.zip(&x2b, |a, b| a + h.h2 * b);
    // k1 = rhs(c1, x, u0): the coefficients at x stay with the caller.
    emm::rhs_backward::<M, L>(c1, inv_t_pr, x, u0, &k1b, xbar, c1bar, itbar);
}

impl core::str::FromStr for Integrator {
    type Err = crate::error::UnknownName;

    /// Parses [`Integrator::name`]'s spelling (`rk4`, `rk3`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        [Integrator::Rk4, Integrator::Rk3]
            .into_iter()
            .find(|i| i.name() == s)
            .ok_or(crate::error::UnknownName {
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

    /// Coefficients affine in the state, `b_fl = 2000 + 4000 v_st`, `k_pr = 5e5 + 1e8 x_pr`,
    /// in f64 lanes, for the reverse-mode check.
    struct AffineStage;

    type L2 = crate::math::Lanes<f64, 2>;

    fn affine(s: &State<L2>) -> Coefficients<L2> {
        Coefficients {
            b_fl: L2::splat(2000.0) + L2::splat(4000.0) * s.v_st_m_s,
            b_pr: L2::splat(800.0),
            k_pr: L2::splat(5e5) + L2::splat(1e8) * s.x_pr_m,
        }
    }

    impl Stage<L2> for AffineStage {
        fn coeffs(&mut self, s: &State<L2>) -> Coefficients<L2> {
            affine(s)
        }
    }

    impl StageBackward<L2> for AffineStage {
        fn coeffs(&mut self, _: usize, s: &State<L2>) -> Coefficients<L2> {
            affine(s)
        }
        fn backward(&mut self, _: usize, cbar: &Coefficients<L2>, sbar: &mut State<L2>) {
            sbar.v_st_m_s = sbar.v_st_m_s + L2::splat(4000.0) * cbar.b_fl;
            sbar.x_pr_m = sbar.x_pr_m + L2::splat(1e8) * cbar.k_pr;
        }
    }

    /// `step_backward` is the transpose of `step_with`: `dL/dx` and `dL/d(inv_t_pr)` of
    /// `L = w . x_n+1` match central differences, for both schemes.
    #[test]
    fn step_backward_matches_finite_differences() {
        use crate::math::{Lanes, Unfused};
        let h = StepSize::<L2>::splat(1e-4);
        let x = State {
            x_pr_m: Lanes([4e-4, -2e-4]),
            v_st_m_s: Lanes([0.1, -0.3]),
        };
        let (u0, u1) = (Lanes([0.3, -0.2]), Lanes([0.35, -0.1]));
        let it = L2::splat(1.0 / 0.003);
        let wx = State {
            x_pr_m: Lanes([1e3, -2e3]),
            v_st_m_s: Lanes([1.0, 0.5]),
        };
        let loss = |x: &State<L2>, it: L2, scheme| -> [f64; 2] {
            let c1 = affine(x);
            let y = step_with::<Unfused, L2, _>(scheme, &mut AffineStage, &c1, it, x, u0, u1, &h);
            let l = wx.x_pr_m * y.x_pr_m + wx.v_st_m_s * y.v_st_m_s;
            l.0
        };
        for scheme in [Integrator::Rk4, Integrator::Rk3] {
            let c1 = affine(&x);
            let mut xbar = State::<L2>::default();
            let mut c1bar = Coefficients::<L2>::default();
            let mut itbar = L2::default();
            step_backward::<Unfused, L2, _>(
                scheme,
                &mut AffineStage,
                &c1,
                it,
                &x,
                u0,
                u1,
                &h,
                &wx,
                &mut xbar,
                &mut c1bar,
                &mut itbar,
            );
            // Stage 1's coefficients are the caller's: complete the chain.
            AffineStage.backward(1, &c1bar, &mut xbar);
            let fd = |f: &dyn Fn(f64) -> [f64; 2], eps: f64| {
                let (p, m) = (f(eps), f(-eps));
                [(p[0] - m[0]) / (2.0 * eps), (p[1] - m[1]) / (2.0 * eps)]
            };
            let dx = fd(
                &|e| {
                    loss(
                        &State {
                            x_pr_m: x.x_pr_m + L2::splat(e),
                            ..x
                        },
                        it,
                        scheme,
                    )
                },
                1e-9,
            );
            let dv = fd(
                &|e| {
                    loss(
                        &State {
                            v_st_m_s: x.v_st_m_s + L2::splat(e),
                            ..x
                        },
                        it,
                        scheme,
                    )
                },
                1e-6,
            );
            let di = fd(&|e| loss(&x, it + L2::splat(e), scheme), 1e-2);
            for k in 0..2 {
                for (got, want) in [
                    (xbar.x_pr_m.0[k], dx[k]),
                    (xbar.v_st_m_s.0[k], dv[k]),
                    (itbar.0[k], di[k]),
                ] {
                    assert!(
                        (got - want).abs() <= 1e-6 * want.abs().max(1e-3),
                        "{scheme:?} {got} vs {want}"
                    );
                }
            }
        }
    }
}
