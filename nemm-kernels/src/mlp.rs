//! Neural scalers (paper section 5.1, eq. 18-19; architecture of section 5.4).
//!
//! A scaler is an MLP with `L` hidden layers of width `H`, each
//! `Linear -> LayerNorm -> LeakyReLU` (dropout is training-only and absent here), followed by
//! a linear output neuron `z`. The scale factor is bounded and positive **by construction**:
//!
//! ```text
//! s(z) = s_min + (s_max - s_min) * sigmoid(z),      0 < s_min < s(z) < s_max
//! ```
//!
//! and the physical parameter is `p = p_ini * s(z)` (eq. 18), e.g.
//! `b_fl(v_st, alpha) = b_fl,ini * s_fl(v_st / v_scale, alpha / alpha_scale)`. Because `s` can
//! neither vanish nor explode, the EMM time constants stay inside bounds that the weight
//! decoder checks against the integrator's stability limit (see nemm-core's model).
//!
//! # Parameter layout (the weight format's `params` vector)
//!
//! With `d` inputs, `H` = `hidden`, `L` = `layers`, row-major matrices (`W[i][j]`, output `i`,
//! input `j`):
//!
//! ```text
//! layer 1:        W1 (H x d), b1 (H), gamma1 (H), beta1 (H)
//! layer 2..=L:    Wl (H x H), bl (H), gammal (H), betal (H)
//! output:         w_o (H), b_o (1)
//! ```
//!
//! [`ScalerLayout`] is the one definition of these positions (and of the alpha branch's,
//! [`BranchLayout`]); every reader of a flat vector, here and in the trainer, asks it.
//!
//! # The forward pass and its reverse mode, once
//!
//! [`ScalerView::raw`] is the scaler's raw output `z` (MLP and alpha branch) over any
//! [`Lane`] and [`math::MulAdd`], with `ScalerView::raw_backward` (feature `reverse`) beside it: the
//! reference path ([`MlpParams::forward`], [`Scaler::scale_with`]: `f32`, fused), the
//! trainer's rollout and adjoint (`Lanes<f32, 8>`, unfused) and its gradient checks (`f64`)
//! run it. [`CompiledScaler`] (the estimator's folded hot path) and its Arm kernel are
//! optimised forms of it, tested against it (`tests/scaler.rs`, `tests/estimator.rs`).
//!
//! # Exact arithmetic of [`MlpParams::forward`] (the reference the trainer reproduces)
//!
//! ```text
//! b1'_i = fma(W_i1, x_1, b_i)          (second input folded into the bias; b_i for d = 1)
//! h_i   = layer 1: fma(W_i0, x_0, b1'_i); layer l: acc = b_i; acc = fma(W_ij, a_j, acc), j ascending
//! mean  = (sum_i h_i, left to right) / H
//! d_i   = h_i - mean
//! var   = (fma-chain of d_i * d_i from 0) / H
//! r     = rsqrt(var + LAYER_NORM_EPS)
//! y_i   = fma(gamma_i, d_i * r, beta_i)
//! a_i   = y_i if y_i >= 0 else LEAKY_RELU_SLOPE * y_i
//! z     = fma-chain from b_o over w_o_i * a_i
//! ```
//!
//! (the second input is folded first, as [`CompiledScaler::set_alpha`] and the trainer do,
//! so that it is computed once per condition level).

pub use crate::error::ShapeError;
pub use crate::limits::{MAX_HIDDEN, MAX_INPUTS, MAX_LAYERS};
use crate::math::{self, Lane};
use serde::{Deserialize, Serialize};

#[cfg(all(
    target_arch = "arm",
    target_abi = "eabihf",
    target_os = "none",
    not(feature = "micromath")
))]
#[allow(unsafe_code)]
mod arm;
mod branch;
mod compiled;
mod layers;
mod layout;
mod params;
mod pass;

pub use compiled::{compiled_len, CompiledScaler, COLUMN_BLOCK};
pub use layers::{bounded, centre, layer_norm_leaky, leaky_relu, norm_act, sigmoid};
#[cfg(feature = "reverse")]
pub use layers::{bounded_backward, centre_backward, norm_act_backward};
pub use params::{LayerView, MlpParams};

pub use branch::{branch_param_count, BranchView, BRANCH_CAPACITY};
pub use branch::{AlphaBranch, BranchError, CompiledBranch, Direction, MAX_BRANCH_UNITS};
pub use layout::{BranchLayout, ScalerLayout};
pub use layout::{BranchRanges, LayerRanges};
pub use pass::{Folded, ScalerView, Tape, TapeMut};

/// Negative-side slope of the LeakyReLU activation (PyTorch and burn default).
pub const LEAKY_RELU_SLOPE: f32 = 0.01;
/// LayerNorm epsilon added to the variance (PyTorch and burn default).
pub const LAYER_NORM_EPS: f32 = 1e-5;

/// Number of parameters of an MLP with `inputs` inputs, width `hidden` and `layers` hidden
/// layers, in the layout described in the module docs. Saturates instead of overflowing.
pub const fn param_count(inputs: usize, hidden: usize, layers: usize) -> usize {
    if layers == 0 {
        return 0;
    }
    let first = inputs
        .saturating_mul(hidden)
        .saturating_add(hidden.saturating_mul(3));
    let other = hidden
        .saturating_mul(hidden)
        .saturating_add(hidden.saturating_mul(3))
        .saturating_mul(layers - 1);
    first
        .saturating_add(other)
        .saturating_add(hidden)
        .saturating_add(1)
}

/// Parameter capacity for the largest scaler of the Table 3 search space (`d = 2, H = 32,
/// L = 9`): 9,153 `f32`, 36.6 KiB. Firmware for a smaller model picks a smaller capacity.
pub const DEFAULT_PARAM_CAPACITY: usize = param_count(MAX_INPUTS, MAX_HIDDEN, MAX_LAYERS);

/// A neural scaler: MLP plus the bounded positive output mapping of the module docs.
///
/// `clone_from` copies in place (no temporary of `P` floats on the stack).
#[derive(Debug, PartialEq, Serialize, Deserialize)]
pub struct Scaler<const P: usize> {
    /// The MLP producing the raw output `z`.
    pub mlp: MlpParams<P>,
    /// Lower bound of the scale factor, `> 0` (dimensionless).
    pub s_min: f32,
    /// Upper bound of the scale factor, `> s_min` (dimensionless).
    pub s_max: f32,
}

impl<const P: usize> Clone for Scaler<P> {
    fn clone(&self) -> Self {
        let mut c = Self::empty();
        c.clone_from(self);
        c
    }

    fn clone_from(&mut self, source: &Self) {
        self.mlp.clone_from(&source.mlp);
        self.s_min = source.s_min;
        self.s_max = source.s_max;
    }
}

impl<const P: usize> Scaler<P> {
    /// A scaler without parameters (not valid on its own; a place to decode into).
    pub const fn empty() -> Self {
        Self::EMPTY
    }

    /// The value of [`Scaler::empty`] as a constant.
    pub const EMPTY: Self = Self {
        mlp: MlpParams {
            inputs: 0,
            hidden: 0,
            layers: 0,
            params: heapless::Vec::new(),
        },
        s_min: 0.0,
        s_max: 0.0,
    };

    /// Scale factor `s(z) = s_min + (s_max - s_min) sigmoid(z)` for normalised inputs.
    pub fn scale(&self, x: &[f32]) -> Option<f32> {
        let z = self.mlp.forward(x)?;
        Some(scale_from_raw(z, self.s_min, self.s_max))
    }

    /// Scale factor with an optional alpha branch ([`AlphaBranch`]): `x` are the
    /// normalised inputs as for [`Self::scale`] (`alpha` last). With a branch the MLP gets
    /// `alpha_n = 0` (its alpha column, zero in a valid model, sees nothing) and the raw
    /// output is `f(x) + branch(x_state, alpha_n)`.
    pub fn scale_with(&self, x: &[f32], branch: Option<&AlphaBranch>) -> Option<f32> {
        let Some(b) = branch else {
            return self.scale(x);
        };
        let (&alpha_n, state) = x.split_last()?;
        if x.len() != self.mlp.inputs as usize {
            return None;
        }
        let view = self.mlp.view(Some(b))?;
        let (xi, second) = view.inputs(state.first().copied().unwrap_or(0.0), alpha_n);
        let fold = view.fold::<math::Fused, f32>(second, alpha_n)?;
        let z = view.raw::<math::Fused, f32>(&fold, xi, None)?;
        Some(scale_from_raw(z, self.s_min, self.s_max))
    }

    /// The largest magnitude of the MLP's alpha input column (the last input of layer 1):
    /// 0 when the MLP does not see `alpha`, as a scaler with an alpha branch requires.
    pub fn alpha_column_max_abs(&self) -> f32 {
        let d = self.mlp.inputs as usize;
        self.mlp.layer(0).map_or(0.0, |l| {
            l.w.chunks_exact(d.max(1))
                .filter_map(|row| row.last())
                .fold(0.0f32, |m, &v| {
                    if v.abs() > m || v.is_nan() {
                        v.abs()
                    } else {
                        m
                    }
                })
        })
    }

    /// Raw output `z` that makes `s(z) = 1`, i.e. reproduces the constant `p_ini`:
    /// `logit((1 - s_min) / (s_max - s_min))`. The trainer initialises the output bias with it.
    pub fn identity_logit(s_min: f32, s_max: f32) -> f32 {
        let p = (1.0 - s_min) / (s_max - s_min);
        libm::logf(p / (1.0 - p))
    }
}

/// `s_min + (s_max - s_min) * sigmoid(z)` ([`bounded`] with `p_ini = 1`).
#[inline(always)]
pub fn scale_from_raw(z: f32, s_min: f32, s_max: f32) -> f32 {
    bounded::<math::Fused, f32>(z, s_min, s_max - s_min).0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mlp_1x2x1() -> MlpParams<64> {
        // d = 1, H = 2, L = 1: W1 = [1, -1]^T, b1 = [0.5, 0], gamma = [2, 1], beta = [0, 1],
        // w_o = [1, 2], b_o = 0.25
        MlpParams::new(
            1,
            2,
            1,
            &[1.0, -1.0, 0.5, 0.0, 2.0, 1.0, 0.0, 1.0, 1.0, 2.0, 0.25],
        )
        .unwrap()
    }

    #[test]
    fn param_count_matches_layout() {
        assert_eq!(param_count(1, 2, 1), 11);
        assert_eq!(param_count(2, 16, 5), 2 * 16 + 48 + 4 * (256 + 48) + 17);
        assert_eq!(DEFAULT_PARAM_CAPACITY, 9153);
    }

    /// Tolerance of a by-hand check: `exact` with libm; with the `micromath` approximations
    /// (1/sqrt within 3.4e-2, see the `math` module) only their accuracy can be asked for.
    fn tol(exact: f64) -> f64 {
        if cfg!(feature = "micromath") {
            5e-2
        } else {
            exact
        }
    }

    #[test]
    fn layer_norm_by_hand() {
        // h = [1, 3]: mean 2, d = [-1, 1], var = 1, r = 1/sqrt(1 + 1e-5)
        let mut h = [1.0f32, 3.0];
        layer_norm_leaky(&mut h, &[1.0, 1.0], &[0.0, 0.0]);
        let r = 1.0 / (1.0f64 + 1e-5).sqrt();
        assert!(
            (h[0] as f64 - (-0.01 * r)).abs() < tol(1e-5) * 0.01,
            "{h:?}"
        );
        assert!((h[1] as f64 - r).abs() < tol(1e-6), "{h:?}");
    }

    #[test]
    fn mlp_by_hand() {
        // x = 2: h = [2.5, -2]; mean 0.25; d = [2.25, -2.25]; var = 5.0625; r = 1/sqrt(var+eps)
        // y = [2 * 2.25 r, -2.25 r + 1] = [~2.0, ~0.0]; leaky: y1 = 1 - 2.25r = 1 - 0.999999 > 0?
        let m = mlp_1x2x1();
        let var = 5.0625f64;
        let r = 1.0 / (var + 1e-5).sqrt();
        let y0 = 2.0 * 2.25 * r;
        let y1 = -2.25 * r + 1.0;
        let a1 = if y1 >= 0.0 { y1 } else { 0.01 * y1 };
        let z = 0.25 + y0 + 2.0 * a1;
        let got = m.forward(&[2.0]).unwrap() as f64;
        assert!(
            (got - z).abs() < tol(1e-6) * z.abs().max(1.0),
            "{got} vs {z}"
        );
    }

    #[test]
    fn scaler_is_bounded_and_identity_logit_gives_one() {
        let z0 = Scaler::<64>::identity_logit(0.2, 5.0);
        assert!(f64::from((scale_from_raw(z0, 0.2, 5.0) - 1.0).abs()) < tol(1e-6));
        assert!(scale_from_raw(1e30, 0.2, 5.0) <= 5.0);
        assert!(scale_from_raw(-1e30, 0.2, 5.0) >= 0.2);
    }

    #[test]
    fn compiled_matches_reference() {
        // d = 2, H = 3, L = 2 with arbitrary weights.
        let n = param_count(2, 3, 2);
        let params: heapless::Vec<f32, 64> = (0..n)
            .map(|i| ((i as f32) * 0.7).sin() * 0.8 + 0.05)
            .collect();
        let mlp = MlpParams::<64>::new(2, 3, 2, &params).unwrap();
        let sc = Scaler {
            mlp,
            s_min: 0.1,
            s_max: 4.0,
        };
        let (p_ini, u_scale, alpha, a_scale) = (1500.0, 1.2, 0.15, 0.3);
        let mut c = CompiledScaler::compile(&sc, p_ini, u_scale, alpha, a_scale).unwrap();
        for &u in &[-1.3f32, -0.5, 0.0, 0.2, 1.1] {
            let reference = p_ini * sc.scale(&[u / u_scale, alpha / a_scale]).unwrap();
            let got = c.eval(u);
            assert!(
                (got - reference).abs() <= 2e-6 * reference,
                "{u}: {got} vs {reference}"
            );
        }
        c.set_alpha(0.3);
        let reference = p_ini * sc.scale(&[0.4 / u_scale, 1.0]).unwrap();
        assert!((c.eval(0.4) - reference).abs() <= 2e-6 * reference);
    }

    /// `norm_act_backward` after `centre_backward` is the transpose of `centre` then
    /// `norm_act`: the adjoint of the pre-activations and of `gamma`, `beta` match central
    /// differences of `L = w . a` (f64 lanes).
    #[test]
    fn layer_backward_matches_finite_differences() {
        use crate::math::{Lanes, Unfused};
        type L2 = Lanes<f64, 2>;
        const H: usize = 4;
        let t0: [L2; H] = [
            Lanes([0.3, -1.0]),
            Lanes([-0.7, 0.2]),
            Lanes([1.1, 0.05]),
            Lanes([-0.02, 0.9]),
        ];
        let gamma = [1.2, -0.4, 0.8, 1.0];
        let beta = [0.1, -0.3, 0.0, 0.05];
        let wts = [0.7, -1.3, 0.4, 2.0];
        let inv_h = 1.0 / H as f64;
        let forward = |t0: &[L2; H], gamma: &[f64; H], beta: &[f64; H]| -> f64 {
            let mut t = *t0;
            centre(&mut t, inv_h);
            let mut l = L2::default();
            let mut w = wts.iter();
            norm_act::<Unfused, L2>(&t, gamma, beta, inv_h, |_, _, a| {
                l = l + L2::splat(*w.next().unwrap()) * a;
            });
            L2::sum(l)
        };
        let mut t = t0;
        centre(&mut t, inv_h);
        let (mut n, mut a) = ([L2::default(); H], [L2::default(); H]);
        let mut i = 0;
        let r = norm_act::<Unfused, L2>(&t, &gamma, &beta, inv_h, |ni, _, ai| {
            n[i] = ni;
            a[i] = ai;
            i += 1;
        });
        let abar: [L2; H] = core::array::from_fn(|i| L2::splat(wts[i]));
        let mut tbar = [L2::default(); H];
        let (mut gg, mut gb) = ([0.0; H], [0.0; H]);
        norm_act_backward(&abar, &n, &a, r, &gamma, inv_h, &mut tbar, &mut gg, &mut gb);
        centre_backward(&mut tbar, inv_h);
        let eps = 1e-6;
        for i in 0..H {
            for k in 0..2 {
                let (mut p, mut m) = (t0, t0);
                p[i].0[k] += eps;
                m[i].0[k] -= eps;
                let want = (forward(&p, &gamma, &beta) - forward(&m, &gamma, &beta)) / (2.0 * eps);
                assert!(
                    (tbar[i].0[k] - want).abs() < 1e-7,
                    "t {i} {k}: {:?} vs {want}",
                    tbar[i]
                );
            }
            let (mut p, mut m) = (gamma, gamma);
            p[i] += eps;
            m[i] -= eps;
            let want = (forward(&t0, &p, &beta) - forward(&t0, &m, &beta)) / (2.0 * eps);
            assert!(
                (gg[i] - want).abs() < 1e-7,
                "gamma {i}: {} vs {want}",
                gg[i]
            );
            let (mut p, mut m) = (beta, beta);
            p[i] += eps;
            m[i] -= eps;
            let want = (forward(&t0, &gamma, &p) - forward(&t0, &gamma, &m)) / (2.0 * eps);
            assert!((gb[i] - want).abs() < 1e-7, "beta {i}: {} vs {want}", gb[i]);
        }
    }
}
