//! The layers a scaler is built from, lane-generic where the trainer differentiates them:
//! the fused dot product, LeakyReLU, LayerNorm (centre, normalise and activate), sigmoid
//! and the bounded output.

use super::*;

/// `acc = init; acc = M::mul_add(w_j, x_j, acc)` over `j` (with [`math::Fused`]: the fused
/// dot product).
#[inline(always)]
pub(super) fn dot_acc_with<M: math::MulAdd>(w: &[f32], x: &[f32], init: f32) -> f32 {
    w.iter()
        .zip(x)
        .fold(init, |acc, (&wj, &xj)| M::mul_add(wj, xj, acc))
}

/// Start of the activation-pattern hash (FNV-1a offset basis).
pub(super) const PATTERN_SEED: u64 = 0xcbf2_9ce4_8422_2325;

/// LeakyReLU with [`LEAKY_RELU_SLOPE`].
#[inline(always)]
pub fn leaky_relu<L: Lane>(y: L) -> L {
    L::select_nonneg(y, y, L::constant(LEAKY_RELU_SLOPE) * y)
}

// ---------------------------------------------------------------------------------------
// The hidden layer's normalisation and activation, and the output mapping: the one
// definition of the scaler architecture past the linear maps, generic over the lane type.
// The estimator (`f32`, folded weights), the reference forward and the trainer (packed
// lanes, with the reverse modes below each forward) all run these.
// ---------------------------------------------------------------------------------------

/// LayerNorm's centring, in place: `t_i <- t_i - mean(t)`, `mean = (sum_i t_i) * inv_h`
/// (left to right). [`CompiledScaler::compile`] folds the same centring into the weights.
#[inline(always)]
pub fn centre<L: Lane>(t: &mut [L], inv_h: L::Scalar) {
    let mean = t.iter().fold(L::default(), |s, &v| s + v) * L::splat(inv_h);
    for v in t.iter_mut() {
        *v = *v - mean;
    }
}

/// Reverse mode of [`centre`], in place on the adjoints (the centring is an orthogonal
/// projection: its own transpose).
#[inline(always)]
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub fn centre_backward<L: Lane>(tbar: &mut [L], inv_h: L::Scalar) {
    centre(tbar, inv_h);
}

/// Normalisation (by the root mean square of the centred pre-activations `t`), affine
/// `gamma`, `beta` and LeakyReLU of one hidden layer, in the order of the module docs:
/// `var = (fma-chain of t_i^2) * inv_h`, `r = rsqrt(var + LAYER_NORM_EPS)`,
/// `n_i = t_i r`, `y_i = fma(gamma_i, n_i, beta_i)`, `a_i = leaky_relu(y_i)`. Calls
/// `out(n_i, y_i, a_i)` for every neuron in order and returns `r`.
#[inline(always)]
pub fn norm_act<M: math::MulAdd, L: Lane>(
    t: &[L],
    gamma: &[L::Scalar],
    beta: &[L::Scalar],
    inv_h: L::Scalar,
    mut out: impl FnMut(L, L, L),
) -> L {
    let var = t.iter().fold(L::default(), |s, &d| M::mul_add(d, d, s)) * L::splat(inv_h);
    let r = L::rsqrt(var + L::constant(LAYER_NORM_EPS));
    for ((&ti, &g), &b) in t.iter().zip(gamma).zip(beta) {
        let n = ti * r;
        let y = M::mul_add(L::splat(g), n, L::splat(b));
        out(n, y, leaky_relu(y));
    }
    r
}

/// Reverse mode of [`norm_act`] from the adjoints `abar` of the activations and the record
/// of the forward (`n_i`, `a_i`, `r`): writes the adjoints of the centred pre-activations
/// `t` into `tbar` and adds the lane sums of `dL/dgamma_i`, `dL/dbeta_i` to `ggamma`,
/// `gbeta`. `tbar_i = r (nbar_i - n_i mean(nbar n))`, `nbar_i = gamma_i ybar_i`.
#[inline(always)]
#[allow(clippy::too_many_arguments)] // the record, the weights and three adjoint outputs
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub fn norm_act_backward<L: Lane>(
    abar: &[L],
    n: &[L],
    a: &[L],
    r: L,
    gamma: &[L::Scalar],
    inv_h: L::Scalar,
    tbar: &mut [L],
    ggamma: &mut [L::Scalar],
    gbeta: &mut [L::Scalar],
) {
    let slope = L::constant(LEAKY_RELU_SLOPE);
    let mut mean_nbar_n = L::default();
    for ((((tb, &ab), (&ni, &ai)), &g), (gg, gb)) in tbar
        .iter_mut()
        .zip(abar)
        .zip(n.iter().zip(a))
        .zip(gamma)
        .zip(ggamma.iter_mut().zip(gbeta.iter_mut()))
    {
        let yb = L::select_nonneg(ai, ab, slope * ab);
        *gg = *gg + L::sum(yb * ni);
        *gb = *gb + L::sum(yb);
        let nb = yb * L::splat(g);
        mean_nbar_n = mean_nbar_n + nb * ni;
        *tb = nb;
    }
    let mean_nbar_n = mean_nbar_n * L::splat(inv_h);
    for (tb, &ni) in tbar.iter_mut().zip(n) {
        *tb = r * (*tb - ni * mean_nbar_n);
    }
}

/// Logistic sigmoid `1 / (1 + e^-z)` per lane (as [`math::sigmoid`] for `f32`).
#[inline(always)]
pub fn sigmoid<L: Lane>(z: L) -> L {
    L::constant(1.0) / (L::constant(1.0) + L::exp(-z))
}

/// The bounded positive output mapping of a scaler, scaled by its constant:
/// `p = lo + span sigmoid(z)` computed as `mul_add(span, sigmoid(z), lo)`, with
/// `lo = p_ini s_min` and `span = p_ini (s_max - s_min)`. Returns `(p, sigmoid(z))`.
#[inline(always)]
pub fn bounded<M: math::MulAdd, L: Lane>(z: L, lo: L, span: L) -> (L, L) {
    let sig = sigmoid(z);
    (M::mul_add(span, sig, lo), sig)
}

/// Reverse mode of [`bounded`] in `z`: `dL/dz = pbar span sig (1 - sig)` from the recorded
/// `sig` (the derivatives in `lo` and `span` are `pbar` and `pbar sig`).
#[inline(always)]
#[cfg(feature = "reverse")]
#[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
pub fn bounded_backward<L: Lane>(sig: L, span: L, pbar: L) -> L {
    pbar * span * sig * (L::constant(1.0) - sig)
}

/// In place: LayerNorm over `h` (mean and biased variance), affine `gamma`, `beta`, then
/// LeakyReLU ([`centre`] then [`norm_act`], fused multiply-adds).
pub fn layer_norm_leaky(h: &mut [f32], gamma: &[f32], beta: &[f32]) {
    let inv_h = 1.0 / h.len() as f32;
    centre(h, inv_h);
    let mut act = [0.0f32; MAX_HIDDEN];
    let mut it = act.iter_mut();
    norm_act::<math::Fused, f32>(h, gamma, beta, inv_h, |_, _, a| {
        if let Some(o) = it.next() {
            *o = a;
        }
    });
    for (v, &a) in h.iter_mut().zip(&act) {
        *v = a;
    }
}
