//! The schemes as the estimator uses them: order of accuracy, the input hold, and one RK3
//! step against the closed form.
//!
//! With a sinusoidal input the first-order hold's `(w dt)^2 / 12` hides the scheme's order
//! (see `frequency_response.rs`), so the order is measured on the free decay, and the hold on
//! a ramp, which it represents exactly.

use nemm_core::semantics::emm::{Coefficients, State};
use nemm_core::semantics::integrator::{self, StepSize};
use nemm_core::Integrator;

/// Example constants (`b_fl` 2500, `b_pr` 1500 N s/m, `k` 4e5 N/m): `a = k / B` = 100 1/s.
const C: Coefficients = Coefficients {
    b_fl: 2500.0,
    b_pr: 1500.0,
    k_pr: 4.0e5,
};
const A: f64 = 100.0;
const INV_T: f32 = 1.0; // slow valve lag: v_st does not limit the step here

fn run(scheme: Integrator, dt: f64, n: usize, x0: f32, u: impl Fn(usize) -> f64) -> f32 {
    let h = StepSize::new(dt as f32);
    let mut x = State {
        x_pr_m: x0,
        v_st_m_s: 0.0,
    };
    for i in 0..n {
        x = integrator::step(
            scheme,
            |_| C,
            &C,
            INV_T,
            &x,
            u(i) as f32,
            u(i + 1) as f32,
            &h,
        );
    }
    x.x_pr_m
}

/// Free decay `x' = -a x` over two time constants: halving the step divides the relative
/// error by 2^p, p = 4 (RK4) and 3 (RK3). `a dt` = 0.4, 0.2, 0.1: the scheme's error
/// (`2 (a dt)^4 / 120` resp. `2 (a dt)^3 / 24` = 4e-4 ... 8e-5) dominates f32 rounding
/// (< 1e-6 over 80 steps) and is asymptotic. The observed order must be within 0.3.
#[test]
fn global_order_on_free_decay() {
    for (scheme, p) in [(Integrator::Rk4, 4.0), (Integrator::Rk3, 3.0)] {
        let errs: Vec<f64> = [0.4, 0.2, 0.1]
            .iter()
            .map(|&z: &f64| {
                let dt = z / A;
                let n = (2.0 / z).round() as usize;
                let x = run(scheme, dt, n, 1.0, |_| 0.0);
                (f64::from(x) - (-A * dt * n as f64).exp()).abs() / (-2.0f64).exp()
            })
            .collect();
        for w in errs.windows(2) {
            let order = (w[0] / w[1]).log2();
            assert!(
                (order - p).abs() < 0.3,
                "{scheme:?}: relative errors {errs:?} give order {order:.2}, expected {p}"
            );
        }
    }
}

/// The hold is linear between samples with the mean at the midpoint: a ramp `u = s t` is
/// represented exactly, so started on the ramp's particular solution
/// `x_p(t) = (c s / a) (t - 1 / a)` (`c = b_fl / B`) both schemes stay on it to rounding, even
/// at a long step (`a dt` = 0.5). Holding `u_n` over the step instead would lag by
/// `c s dt / (2 a)` in steady state (1.6e-4 m here, 1e5 times the tolerance).
#[test]
fn ramp_input_is_integrated_exactly() {
    let c = 2500.0 / 4000.0;
    let s = 10.0;
    let dt = 0.5 / A;
    let x_p = |t: f64| c * s / A * (t - 1.0 / A);
    for scheme in [Integrator::Rk4, Integrator::Rk3] {
        for n in [1usize, 7, 40] {
            let x = run(scheme, dt, n, x_p(0.0) as f32, |i| s * i as f64 * dt);
            let want = x_p(n as f64 * dt);
            // Rounding: a few ulps of the larger of x and c s / a^2 per step, decaying.
            let tol = 8.0 * f64::from(f32::EPSILON) * (c * s / (A * A) + want.abs());
            assert!(
                (f64::from(x) - want).abs() <= tol,
                "{scheme:?} after {n} steps: {x} vs {want}"
            );
        }
    }
}

/// One RK3 step of the Linear EMM with constant input against the closed form of both state
/// components (the src unit test does RK4 the same way): local error `O((a dt)^4)`.
#[test]
fn rk3_step_matches_closed_form() {
    let (bf, bp, k, t_pr) = (2000.0f64, 800.0f64, 5.6e5f64, 0.002f64);
    let c = Coefficients {
        b_fl: bf as f32,
        b_pr: bp as f32,
        k_pr: k as f32,
    };
    let (u, x0, v0, dt) = (0.4f64, 0.0005f64, -0.1f64, 1e-4f64);
    let x1 = integrator::step(
        Integrator::Rk3,
        |_| c,
        &c,
        (1.0 / t_pr) as f32,
        &State {
            x_pr_m: x0 as f32,
            v_st_m_s: v0 as f32,
        },
        u as f32,
        u as f32,
        &StepSize::new(dt as f32),
    );
    let a = k / (bp + bf);
    let x_inf = bf * u / k;
    let x_exact = x_inf + (x0 - x_inf) * (-a * dt).exp();
    // q(t) = u + a (x0 - x_inf) e^{-a t}; v' = (q - v) / T.
    let big_a = a * (x0 - x_inf);
    let inv = 1.0 / t_pr;
    let v_exact = u
        + (v0 - u) * (-dt * inv).exp()
        + big_a * inv / (inv - a) * ((-a * dt).exp() - (-dt * inv).exp());
    // Local error of a third-order step: (a dt)^4 / 24 relative to the transient, with
    // a dt = 0.02 (x) and dt / T = 0.05 (v): 7e-9 and 3e-7 relative.
    let tol_x = 0.02f64.powi(4) / 24.0 * (x0 - x_inf).abs() + 4.0 * f64::from(f32::EPSILON) * x0;
    let tol_v = 0.05f64.powi(4) / 24.0 * (v0 - u).abs() + 4.0 * f64::from(f32::EPSILON) * u;
    assert!(
        (f64::from(x1.x_pr_m) - x_exact).abs() <= tol_x,
        "{} {x_exact}",
        x1.x_pr_m
    );
    assert!(
        (f64::from(x1.v_st_m_s) - v_exact).abs() <= tol_v,
        "{} {v_exact}",
        x1.v_st_m_s
    );
}
