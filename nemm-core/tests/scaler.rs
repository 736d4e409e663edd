//! Neural scalers: a whole small MLP by hand through `Scaler::scale`, and the compiled
//! (folded) scaler that runs every step against the reference forward pass and an f64 oracle
//! with a Monte Carlo rounding tolerance, across random weights, shapes and inputs.

mod common;

use common::ScalerSpec;
use nemm_kernels::mlp::{
    param_count, CompiledScaler, MlpParams, Scaler, LAYER_NORM_EPS, LEAKY_RELU_SLOPE, MAX_HIDDEN,
    MAX_LAYERS,
};
use proptest::prelude::*;

fn sigmoid(z: f64) -> f64 {
    1.0 / (1.0 + (-z).exp())
}

fn leaky(y: f64) -> f64 {
    if y >= 0.0 {
        y
    } else {
        LEAKY_RELU_SLOPE as f64 * y
    }
}

/// d = 2, H = 2, L = 2. With two neurons LayerNorm maps `[h0, h1]` to
/// `+-(h0 - h1) / 2 / sqrt(((h0 - h1) / 2)^2 + eps)`, i.e. almost exactly `+-1`, which makes
/// the whole pass computable by hand:
///
/// ```text
/// x  = [0.6 / 1.2, 0.075 / 0.3] = [0.5, 0.25]
/// layer 1: W = [[1, 2], [-1, 0.5]], b = [0.5, -0.25], gamma = [1, 2], beta = [0, -1]
///   h = [0.5 + 0.5 + 0.5, -0.5 + 0.125 - 0.25] = [1.5, -0.625]; mean 0.4375; d = +-1.0625
///   r1 = 1 / sqrt(1.0625^2 + eps); n = [1.0625 r1, -1.0625 r1] (~ +-0.9999956)
///   y = [1.0625 r1, -2.125 r1 - 1];  a = [1.0625 r1, 0.01 (-2.125 r1 - 1)] (~ [1, -0.03])
/// layer 2: W = [[2, 0], [1, 1]], b = [0, 0.5], gamma = [1, 1], beta = [0.5, 0]
///   h = [2 a0, a0 + a1 + 0.5]; d = +-(a0 - a1 - 0.5) / 2 =: +-e (~ +-0.265)
///   r2 = 1 / sqrt(e^2 + eps); y = [0.5 + e r2, -e r2]; a = [0.5 + e r2, -0.01 e r2]
/// output: w_o = [1, -2], b_o = -0.5:  z = -0.5 + 0.5 + e r2 + 0.02 e r2 = 1.02 e r2 (~ 1.02)
/// scale: s = 0.5 + (2 - 0.5) sigmoid(z)
/// ```
#[cfg(not(feature = "micromath"))] // hand values use exact exp and 1/sqrt
#[test]
fn whole_small_mlp_by_hand_through_scale() {
    #[rustfmt::skip]
    let params = [
        1.0, 2.0, -1.0, 0.5,   0.5, -0.25,   1.0, 2.0,   0.0, -1.0, // layer 1
        2.0, 0.0, 1.0, 1.0,    0.0, 0.5,     1.0, 1.0,   0.5, 0.0,  // layer 2
        1.0, -2.0, -0.5,                                             // output
    ];
    assert_eq!(params.len(), param_count(2, 2, 2));
    let scaler = Scaler::<64> {
        mlp: MlpParams::new(2, 2, 2, &params).unwrap(),
        s_min: 0.5,
        s_max: 2.0,
    };
    let eps = LAYER_NORM_EPS as f64;
    let r1 = 1.0 / (1.0625f64 * 1.0625 + eps).sqrt();
    let a0 = 1.0625 * r1;
    let a1 = 0.01 * (-2.125 * r1 - 1.0);
    let e = (a0 - a1 - 0.5) / 2.0;
    let r2 = 1.0 / (e * e + eps).sqrt();
    let z = 1.02 * e * r2;
    // The hand estimate above (z ~ 1.02) and the exact closed form agree.
    assert!((z - 1.02).abs() < 1e-3, "{z}");
    let s = 0.5 + 1.5 * sigmoid(z);

    let got_z = scaler.mlp.forward(&[0.5, 0.25]).unwrap() as f64;
    assert!((got_z - z).abs() < 1e-6, "z: {got_z} vs {z}");
    let got = scaler.scale(&[0.5, 0.25]).unwrap() as f64;
    assert!((got - s).abs() < 1e-6, "s: {got} vs {s}");

    // The same network compiled for b_ini = 1000, v_scale 1.2, alpha 0.075 / 0.3.
    let c = CompiledScaler::compile(&scaler, 1000.0, 1.2, 0.075, 0.3).unwrap();
    let p = c.eval(0.6) as f64;
    assert!(
        (p - 1000.0 * s).abs() < 1e-3,
        "compiled: {p} vs {}",
        1000.0 * s
    );
    assert_eq!(c.bounds(), (500.0, 2000.0));
}

/// With one hidden neuron LayerNorm outputs exactly `beta` (the deviation from the mean is 0),
/// so a width-1 scaler is a constant: `z = w_o leaky(beta_last) + b_o`.
#[cfg(not(feature = "micromath"))] // hand values use exact exp and 1/sqrt
#[test]
fn width_one_scaler_is_constant() {
    // d = 2, H = 1, L = 2: W1 (2), b1, g1, be1; W2 (1), b2, g2, be2; w_o, b_o.
    let params = [3.0, -7.0, 0.4, 2.0, 0.25, 5.0, -1.0, 3.0, -0.5, 2.0, 0.1];
    let s = Scaler::<16> {
        mlp: MlpParams::new(2, 1, 2, &params).unwrap(),
        s_min: 0.2,
        s_max: 3.0,
    };
    let z = 2.0 * leaky(-0.5) + 0.1;
    let want = 0.2 + 2.8 * sigmoid(z);
    for x in [[-1.0f32, 0.0], [0.0, 0.5], [2.5, 1.0], [1e6, -3.0]] {
        let got = s.scale(&x).unwrap() as f64;
        assert!((got - want).abs() < 1e-6, "{x:?}: {got} vs {want}");
    }
}

/// An output layer of zeros with the identity logit as bias reproduces `p_ini` exactly up to
/// rounding (the trainer's initialisation), whatever the hidden weights.
#[cfg(not(feature = "micromath"))] // hand values use exact exp and 1/sqrt
#[test]
fn identity_logit_reproduces_the_constant() {
    for (s_min, s_max) in [(0.2f32, 3.0f32), (0.05, 10.0), (0.9, 1.1)] {
        let spec = ScalerSpec {
            hidden: 8,
            layers: 3,
            seed: 11,
            gain: 1.0,
            s_min,
            s_max,
        };
        let mut sc: Scaler<1024> = spec.build(2);
        let n = sc.mlp.params.len();
        for p in &mut sc.mlp.params[n - 9..n - 1] {
            *p = 0.0;
        }
        sc.mlp.params[n - 1] = Scaler::<1024>::identity_logit(s_min, s_max);
        for u in [-1.0f32, 0.0, 0.7] {
            let s = sc.scale(&[u, 0.5]).unwrap();
            assert!((s - 1.0).abs() < 4.0 * f32::EPSILON, "{s_min} {s_max}: {s}");
            let c = CompiledScaler::compile(&sc, 2500.0, 1.0, 0.15, 0.3).unwrap();
            let p = c.eval(u);
            assert!((p - 2500.0).abs() < 2500.0 * 4.0 * f32::EPSILON, "{p}");
        }
    }
}

/// The scaler's real-arithmetic function evaluated in f64, with every operation's result (and
/// every weight, standing in for the compiled path's folds) optionally perturbed by a relative
/// error `noise()` in `[-u, u]`, `u = 2^-24` the f32 unit roundoff: Monte Carlo arithmetic
/// (Parker, 1997). Without noise it is the oracle; the spread of noisy evaluations measures
/// how strongly f32 rounding can move this particular network at this particular input,
/// which a worst-case bound overstates by orders of magnitude after a few LayerNorms.
fn forward64<const Q: usize>(
    sc: &Scaler<Q>,
    x: &[f64],
    p_ini: f64,
    noise: &mut dyn FnMut() -> f64,
) -> f64 {
    let mlp = &sc.mlp;
    let h = mlp.hidden as usize;
    let eps = f64::from(LAYER_NORM_EPS);
    let mut r = |v: f64| v * (1.0 + noise());
    let mut a: Vec<f64> = x.iter().map(|&v| r(v)).collect();
    for l in 0..mlp.layers as usize {
        let layer = mlp.layer(l).unwrap();
        let mut hv = Vec::with_capacity(h);
        for (row, &b) in layer.w.chunks_exact(a.len()).zip(layer.b) {
            let mut acc = r(f64::from(b));
            for (&w, &v) in row.iter().zip(&a) {
                let w = r(f64::from(w));
                acc = r(acc + w * v);
            }
            hv.push(acc);
        }
        let mean = r(hv.iter().sum::<f64>() / h as f64);
        let d: Vec<f64> = hv.iter().map(|&v| r(v - mean)).collect();
        let var = r(d.iter().map(|v| v * v).sum::<f64>() / h as f64);
        let rs = r(1.0 / (var + eps).sqrt());
        a = (0..h)
            .map(|i| {
                let nrm = r(d[i] * rs);
                leaky(r(f64::from(layer.gamma[i]) * nrm + f64::from(layer.beta[i])))
            })
            .collect();
    }
    let (w_o, b_o) = mlp.output().unwrap();
    let mut z = r(f64::from(b_o));
    for (&w, &v) in w_o.iter().zip(&a) {
        let w = r(f64::from(w));
        z = r(z + w * v);
    }
    let (s_min, s_max) = (f64::from(sc.s_min), f64::from(sc.s_max));
    let sg = r(sigmoid(z));
    let s = r(s_min + (s_max - s_min) * sg);
    r(p_ini * s)
}

/// Oracle value and tolerance for an f32 evaluation: `10 x` the largest deviation of 16
/// Monte Carlo evaluations (deterministic noise from `seed`), plus 4 ulps of the result.
fn oracle<const Q: usize>(sc: &Scaler<Q>, x: &[f64], p_ini: f64, seed: u64) -> (f64, f64) {
    let u = f64::from(f32::EPSILON) / 2.0;
    let exact = forward64(sc, x, p_ini, &mut || 0.0);
    let mut k = 0u64;
    let mut noise = || {
        k += 1;
        u * f64::from(nemm_core::testing::hash_unit(k, seed))
    };
    let spread = (0..16)
        .map(|_| (forward64(sc, x, p_ini, &mut noise) - exact).abs())
        .fold(0.0f64, f64::max);
    (
        exact,
        10.0 * spread + 4.0 * f64::from(f32::EPSILON) * exact.abs(),
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Reference and compiled scaler both stay within the Monte Carlo rounding tolerance of
    /// the f64 oracle, for random shapes (1..=32 wide, 1..=9 deep, 1 or 2 inputs), weights, bounds,
    /// physical constants, scales, inputs and alpha (re-folded with `set_alpha`).
    #[cfg(not(feature = "micromath"))]
    #[test]
    fn compiled_and_reference_match_f64_oracle(
        spec in common::arb_scaler(MAX_HIDDEN as u8, MAX_LAYERS as u8),
        inputs in 1u8..=2,
        p_ini in 1.0f32..1e6,
        u_scale in 1e-3f32..5.0,
        a_scale in 0.05f32..1.0,
        alpha0 in 0.0f32..1.0,
        alpha in 0.0f32..1.0,
        xs in prop::collection::vec(-1.5f32..1.5, 1..8),
    ) {
        let sc: Scaler<{ common::P }> = spec.build(inputs);
        let mut c = CompiledScaler::compile(&sc, p_ini, u_scale, alpha0, a_scale).unwrap();
        c.set_alpha(alpha);
        let (lo, hi) = c.bounds();
        for &xn in &xs {
            let u = xn * u_scale;
            let xr: Vec<f32> = if inputs == 2 {
                vec![u / u_scale, alpha / a_scale]
            } else {
                vec![u / u_scale]
            };
            let x64: Vec<f64> = if inputs == 2 {
                vec![f64::from(u) / f64::from(u_scale), f64::from(alpha) / f64::from(a_scale)]
            } else {
                vec![f64::from(u) / f64::from(u_scale)]
            };
            let (exact, tol) = oracle(&sc, &x64, f64::from(p_ini), spec.seed);
            let reference = f64::from(p_ini * sc.scale(&xr).unwrap());
            let compiled = f64::from(c.eval(u));
            prop_assert!((reference - exact).abs() <= tol,
                "reference {reference} vs oracle {exact} (tolerance {tol}) at u = {u}");
            prop_assert!((compiled - exact).abs() <= tol,
                "compiled {compiled} vs oracle {exact} (tolerance {tol}) at u = {u}");
            prop_assert!(f64::from(lo) <= compiled && compiled <= f64::from(hi));
        }
    }

    /// Bounded and positive by construction: for any input whose pre-activations stay finite
    /// (states up to the estimator's divergence limit, 1e3 times their scale), both paths
    /// return a value in `[p_ini s_min, p_ini s_max]`.
    #[test]
    fn output_is_bounded_and_positive(
        spec in common::arb_scaler(16, 5),
        p_ini in 1.0f32..1e6,
        alpha in 0.0f32..1.0,
        xn in -1e3f32..1e3,
    ) {
        let sc: Scaler<2048> = spec.build(2);
        let c = CompiledScaler::compile(&sc, p_ini, 1.0, alpha, 1.0).unwrap();
        let (lo, hi) = c.bounds();
        prop_assert!(lo > 0.0 && lo < hi);
        let p = c.eval(xn);
        prop_assert!(lo <= p && p <= hi, "{p} not in [{lo}, {hi}]");
        let s = sc.scale(&[xn, alpha]).unwrap();
        prop_assert!(sc.s_min <= s && s <= sc.s_max, "{s}");
    }
}

/// The example scalers (the benchmark's and the documentation's), across the training domain:
/// compiled and reference agree to a few f32 ulps of the parameter range.
#[test]
fn compiled_matches_reference_on_example_scalers() {
    for (inputs, seed) in [(2u8, 1u64), (2, 3)] {
        let sc: Scaler<{ common::P }> =
            nemm_core::testing::example_scaler(inputs, 16, 5, seed).unwrap();
        for &alpha in &[0.0f32, 0.15, 0.3] {
            let c = CompiledScaler::compile(&sc, 2500.0, 1.05, alpha, 0.3).unwrap();
            let (lo, hi) = c.bounds();
            let mut worst = 0.0f32;
            for k in -100..=100 {
                let u = 1.05 * k as f32 / 100.0;
                let reference = 2500.0 * sc.scale(&[u / 1.05, alpha / 0.3]).unwrap();
                worst = worst.max((c.eval(u) - reference).abs());
            }
            // Rounding of a 5-layer network: the oracle test's tolerance is ~1e-6 of the range
            // for these; require the same order.
            assert!(
                worst <= 1e-5 * (hi - lo),
                "seed {seed} alpha {alpha}: {worst}"
            );
        }
    }
}
