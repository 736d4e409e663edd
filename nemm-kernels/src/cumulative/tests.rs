use super::*;

/// A small deterministic generator of weights in `[-r, r]`.
struct Lcg(u64);
impl Lcg {
    fn next(&mut self, r: f64) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * r
    }
}

fn weights(units: usize, seed: u64) -> Vec<f64> {
    let mut g = Lcg(seed);
    let mut w = Vec::new();
    w.extend((0..=units).map(|_| g.next(2.0))); // a
    w.extend((0..units).map(|_| g.next(2.5))); // omega: widths e^-2.5 .. e^2.5
    w.extend((0..units).map(|_| g.next(3.0))); // c
    w.extend((0..=units).map(|_| g.next(2.0))); // gamma
    w.extend((0..=units).map(|_| g.next(2.0))); // beta
    assert_eq!(w.len(), cumulative_param_count(units));
    w
}

const DIRECTIONS: [Direction; 3] = [
    Direction::Decreasing,
    Direction::Increasing,
    Direction::None,
];

fn scale64(w: &[f64], units: usize, d: Direction, x: f64, alpha_n: f64) -> f64 {
    let v = CumulativeView::new(w, units, d).unwrap();
    v.fold(alpha_n).scale(x, 0.2, 3.0)
}

/// With the exact backend (`libm`): `micromath`'s `exp` is an approximation whose error is
/// not monotone, so with it the computed force rises only up to that error.
#[cfg(not(feature = "micromath"))]
#[test]
fn the_force_rises_with_the_state_for_any_weights_in_f32() {
    for seed in 0..16 {
        for d in DIRECTIONS {
            let w: Vec<f32> = weights(8, seed).iter().map(|&v| v as f32).collect();
            let v = CumulativeView::new(&w, 8, d).unwrap();
            for alpha_n in [0.0f32, 0.5, 1.0] {
                let f = v.fold(alpha_n);
                let mut prev = f32::NEG_INFINITY;
                for i in 0..=20_000 {
                    let x = -4.0 + 8.0 * i as f32 / 20_000.0;
                    let s = f.scale(x, 0.2, 3.0);
                    assert!(s > 0.2 && s < 3.0, "bounds: s({x}) = {s}");
                    let force = x * s;
                    assert!(
                        force > prev,
                        "x s not rising at x = {x} (seed {seed}, {d:?})"
                    );
                    prev = force;
                }
            }
        }
    }
}

#[test]
fn the_scale_is_the_running_mean_of_the_incremental_scale() {
    for seed in 0..10 {
        let w = weights(6, seed);
        let v = CumulativeView::new(&w, 6, Direction::Decreasing).unwrap();
        let f = v.fold(0.3f64);
        for &x in &[-2.0, -0.3, -1e-4, 0.0, 1e-6, 0.02, 0.7, 3.0] {
            // (x s)' = q, by central differences of the closed form.
            let e = 1e-5;
            let fd = ((x + e) * f.scale(x + e, 0.2, 3.0) - (x - e) * f.scale(x - e, 0.2, 3.0))
                / (2.0 * e);
            let q = f.incremental(x, 0.2, 3.0);
            assert!((fd - q).abs() < 1e-7, "x {x}: fd {fd} q {q}");
        }
        // s(0) = q(0).
        let (s0, q0) = (f.scale(0.0, 0.2, 3.0), f.incremental(0.0, 0.2, 3.0));
        assert!((s0 - q0).abs() < 1e-12, "{s0} {q0}");
    }
}

#[test]
fn the_scale_is_monotone_in_alpha_in_the_declared_direction() {
    for seed in 0..20 {
        let w = weights(8, seed);
        for (d, sign) in [(Direction::Decreasing, -1.0), (Direction::Increasing, 1.0)] {
            for &x in &[-2.0, -0.1, 0.0, 0.4, 2.5] {
                let mut prev = scale64(&w, 8, d, x, -0.5);
                for i in 1..=40 {
                    let s = scale64(&w, 8, d, x, -0.5 + i as f64 * 0.05);
                    assert!(sign * (s - prev) >= 0.0, "{d:?} x {x}: {prev} -> {s}");
                    prev = s;
                }
            }
        }
    }
}

#[test]
fn backward_matches_central_differences() {
    for seed in 0..6 {
        for d in DIRECTIONS {
            let units = 5;
            let w = weights(units, seed);
            let alpha_n = 0.7;
            // Points near 0 (the series), either side of the series' bound, and far.
            for &x in &[0.0, 2e-4, -3e-3, 0.05, -0.4, 1.3, -2.7] {
                let v = CumulativeView::new(&w, units, d).unwrap();
                let f = v.fold(alpha_n);
                let mut grad = vec![0.0; w.len()];
                let xbar = f.mixture_backward(&v, x, 2.8, &mut grad);
                let e = 1e-6;
                let fdx = (scale64(&w, units, d, x + e, alpha_n)
                    - scale64(&w, units, d, x - e, alpha_n))
                    / (2.0 * e);
                assert!(
                    (xbar - fdx).abs() < 1e-7 * (1.0 + fdx.abs()),
                    "dx at {x}: {xbar} vs {fdx}"
                );
                for i in 0..w.len() {
                    let mut wp = w.clone();
                    wp[i] += e;
                    let mut wm = w.clone();
                    wm[i] -= e;
                    let fd = (scale64(&wp, units, d, x, alpha_n)
                        - scale64(&wm, units, d, x, alpha_n))
                        / (2.0 * e);
                    assert!(
                        (grad[i] - fd).abs() < 1e-7 * (1.0 + fd.abs()),
                        "param {i} at x {x} ({d:?}): {} vs {fd}",
                        grad[i]
                    );
                }
            }
        }
    }
}

#[test]
fn lanes_agree_with_one_lane() {
    use crate::math::Lanes;
    let w: Vec<f32> = weights(7, 3).iter().map(|&v| v as f32).collect();
    let v = CumulativeView::new(&w, 7, Direction::Decreasing).unwrap();
    let alphas = [0.0f32, 0.1, 0.2, 0.3, 0.5, 0.7, 0.9, 1.0];
    let xs = [-1.5f32, -0.2, 0.0, 1e-5, 0.03, 0.5, 1.0, 2.0];
    let fl = v.fold(Lanes::<f32, 8>(alphas));
    let s = fl.scale(Lanes(xs), 0.2, 3.0);
    let mut grad = vec![0.0f32; w.len()];
    let xbar = fl.mixture_backward(&v, Lanes(xs), Lanes([1.0; 8]), &mut grad);
    let mut grad1 = vec![0.0f32; w.len()];
    for k in 0..8 {
        let f1 = v.fold(alphas[k]);
        assert_eq!(s.0[k], f1.scale(xs[k], 0.2, 3.0));
        assert_eq!(xbar.0[k], f1.mixture_backward(&v, xs[k], 1.0, &mut grad1));
    }
    for (a, b) in grad.iter().zip(&grad1) {
        assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{a} vs {b}");
    }
}

#[test]
fn a_wrong_length_or_unit_count_is_refused() {
    let w = vec![0.0f32; cumulative_param_count(4)];
    assert!(CumulativeView::new(&w, 4, Direction::None).is_some());
    assert!(CumulativeView::new(&w, 3, Direction::None).is_none());
    assert!(CumulativeView::new(&w[..1], 0, Direction::None).is_none());
    let big = vec![0.0f32; cumulative_param_count(MAX_CUMULATIVE_UNITS + 1)];
    assert!(CumulativeView::new(&big, MAX_CUMULATIVE_UNITS + 1, Direction::None).is_none());
}
