//! The schemes as the estimator uses them: order of accuracy, the input hold, and one RK3
//! step against the closed form.
//!
//! With a sinusoidal input the first-order hold's `(w dt)^2 / 12` hides the scheme's order
//! (see `frequency_response.rs`), so the order is measured on the free decay, and the hold on
//! a ramp, which it represents exactly.

use nemm_core::Integrator;
use nemm_kernels::emm::{Coefficients, State};
use nemm_kernels::integrator::{self, StepSize};

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

/// State-dependent coefficients (a damping that saturates in `v_st`, a stiffening `k_pr`) so
/// that every stage sees different coefficients.
fn nonlinear(s: &State) -> Coefficients {
    Coefficients {
        b_fl: 1500.0 + 400.0 * (3.0 * s.v_st_m_s).tanh(),
        b_pr: 800.0,
        k_pr: 4.0e5 * (1.0 + 1e4 * s.x_pr_m * s.x_pr_m),
    }
}

/// Each scheme's kernel is its Butcher tableau: over 20,000 random states and inputs the
/// estimator's step and the tableau run as written (`step_tableau`) agree to within one unit
/// of rounding of the state's scale (2 mm, 1.5 m/s; measured at most 0.67 eps). They differ in
/// the last bit on about one step in ten (printed): the kernel's operation order is the one
/// the trainer's reverse mode and the committed golden figures reproduce, so the estimator
/// keeps the kernel.
#[test]
fn each_kernel_is_its_butcher_tableau_to_rounding() {
    let (dt, inv_t) = (1e-4f32, 500.0f32);
    let h = StepSize::new(dt);
    let mut seed = 12345u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 33) as f64 / (1u64 << 31) as f64 * 2.0 - 1.0) as f32
    };
    for scheme in [Integrator::Rk4, Integrator::Rk3] {
        let tableau = scheme.tableau();
        assert_eq!(tableau.b.len(), scheme.stages());
        let (mut worst, mut differ) = (0.0f32, 0usize);
        for _ in 0..20_000 {
            let x = State {
                x_pr_m: 2e-3 * rnd(),
                v_st_m_s: 1.5 * rnd(),
            };
            let (u0, u1) = (1.5 * rnd(), 1.5 * rnd());
            let kernel = integrator::step(scheme, nonlinear, &nonlinear(&x), inv_t, &x, u0, u1, &h);
            let reference = integrator::step_tableau(&tableau, nonlinear, inv_t, &x, u0, u1, dt);
            let d = ((kernel.x_pr_m - reference.x_pr_m).abs() / 2e-3)
                .max((kernel.v_st_m_s - reference.v_st_m_s).abs() / 1.5)
                / f32::EPSILON;
            worst = worst.max(d);
            differ += usize::from(kernel != reference);
        }
        println!("{scheme:?}: {differ} of 20000 steps differ in some bit, at most {worst:.2} eps");
        assert!(worst <= 1.0, "{scheme:?}: {worst} eps of the state scale");
    }
}

/// A new explicit scheme needs only its tableau: Heun's method (`a = [[], [1]]`,
/// `b = [1/2, 1/2]`, `c = [0, 1]`) run by `step_tableau` shows its second order on the free
/// decay (as `global_order_on_free_decay` measures the built-in schemes).
#[test]
fn a_new_scheme_is_a_tableau() {
    let heun = integrator::Tableau {
        a: &[&[], &[1.0]],
        b: &[0.5, 0.5],
        c: &[0.0, 1.0],
    };
    let errs: Vec<f64> = [0.2, 0.1, 0.05]
        .iter()
        .map(|&z: &f64| {
            let dt = z / A;
            let n = (2.0 / z).round() as usize;
            let mut x = State {
                x_pr_m: 1.0,
                v_st_m_s: 0.0,
            };
            for _ in 0..n {
                x = integrator::step_tableau(&heun, |_| C, INV_T, &x, 0.0, 0.0, dt as f32);
            }
            (f64::from(x.x_pr_m) - (-A * dt * n as f64).exp()).abs() / (-2.0f64).exp()
        })
        .collect();
    for w in errs.windows(2) {
        let order = (w[0] / w[1]).log2();
        assert!((order - 2.0).abs() < 0.3, "{errs:?}: order {order:.2}");
    }
}
