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
//! decoder checks against the integrator's stability limit (see [`crate::model`]).
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
mod layout;
mod pass;

pub use layout::{BranchLayout, BranchRanges, LayerRanges, ScalerLayout};
pub use pass::{Folded, ScalerView, Tape, TapeMut};

pub use branch::{
    branch_param_count, AlphaBranch, BranchError, BranchView, CompiledBranch, Direction,
    BRANCH_CAPACITY, MAX_BRANCH_UNITS,
};

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

/// Weights of one MLP, in the layout of the module docs.
///
/// `clone_from` copies in place, and `Deserialize::deserialize_in_place` decodes the
/// parameters where they are (no temporary of `P` floats on the stack either way).
#[derive(Debug, PartialEq, Serialize)]
pub struct MlpParams<const P: usize> {
    /// Number of inputs `d` (1 or 2).
    pub inputs: u8,
    /// Hidden width `H` (1..=32).
    pub hidden: u8,
    /// Number of hidden layers `L` (1..=9).
    pub layers: u8,
    /// All parameters, flat.
    pub params: heapless::Vec<f32, P>,
}

impl<const P: usize> Clone for MlpParams<P> {
    fn clone(&self) -> Self {
        let mut c = Self {
            inputs: 0,
            hidden: 0,
            layers: 0,
            params: heapless::Vec::new(),
        };
        c.clone_from(self);
        c
    }

    fn clone_from(&mut self, source: &Self) {
        self.inputs = source.inputs;
        self.hidden = source.hidden;
        self.layers = source.layers;
        self.params.clear();
        // Same capacity `P`: cannot fail.
        let _ = self.params.extend_from_slice(&source.params);
    }
}

/// `Deserialize` by hand (the wire format is the derived one: the four fields in order, the
/// parameters as a length-prefixed sequence) so that the parameters are decoded straight
/// into the existing vector.
mod de {
    use super::MlpParams;
    use core::fmt;
    use serde::de::{self, DeserializeSeed, Deserializer, SeqAccess, Visitor};
    use serde::Deserialize;

    const FIELDS: &[&str] = &["inputs", "hidden", "layers", "params"];

    /// Appends a sequence of `f32` to a cleared vector.
    struct Params<'a, const P: usize>(&'a mut heapless::Vec<f32, P>);

    impl<'de, const P: usize> Visitor<'de> for Params<'_, P> {
        type Value = ();
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            write!(f, "at most {P} parameters")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
            self.0.clear();
            while let Some(v) = seq.next_element::<f32>()? {
                if self.0.push(v).is_err() {
                    return Err(de::Error::invalid_length(P + 1, &self));
                }
            }
            Ok(())
        }
    }

    impl<'de, const P: usize> DeserializeSeed<'de> for Params<'_, P> {
        type Value = ();
        fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            d.deserialize_seq(self)
        }
    }

    struct Fields<'a, const P: usize>(&'a mut MlpParams<P>);

    impl<'de, const P: usize> Visitor<'de> for Fields<'_, P> {
        type Value = ();
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("the fields of an MLP")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
            let m = self.0;
            for (i, field) in [&mut m.inputs, &mut m.hidden, &mut m.layers]
                .into_iter()
                .enumerate()
            {
                *field = seq
                    .next_element()?
                    .ok_or_else(|| de::Error::invalid_length(i, &"the fields of an MLP"))?;
            }
            seq.next_element_seed(Params(&mut m.params))?
                .ok_or_else(|| de::Error::invalid_length(3, &"the fields of an MLP"))
        }
    }

    impl<'de, const P: usize> Deserialize<'de> for MlpParams<P> {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            let mut m = MlpParams {
                inputs: 0,
                hidden: 0,
                layers: 0,
                params: heapless::Vec::new(),
            };
            Self::deserialize_in_place(d, &mut m)?;
            Ok(m)
        }

        fn deserialize_in_place<D: Deserializer<'de>>(
            d: D,
            place: &mut Self,
        ) -> Result<(), D::Error> {
            d.deserialize_struct("MlpParams", FIELDS, Fields(place))
        }
    }
}

/// One hidden layer's parameters, borrowed from the flat vector.
#[derive(Debug, Clone, Copy)]
pub struct LayerView<'a> {
    /// Weight matrix, row-major `H x in`.
    pub w: &'a [f32],
    /// Bias, `H`.
    pub b: &'a [f32],
    /// LayerNorm gain, `H`.
    pub gamma: &'a [f32],
    /// LayerNorm offset, `H`.
    pub beta: &'a [f32],
}

/// Splits `n` items off the front of `s`, or `None`.
fn take<'a>(s: &mut &'a [f32], n: usize) -> Option<&'a [f32]> {
    let (head, tail) = s.split_at_checked(n)?;
    *s = tail;
    Some(head)
}

impl<const P: usize> MlpParams<P> {
    /// Builds from dimensions and a parameter slice, checking the shape.
    pub fn new(inputs: u8, hidden: u8, layers: u8, params: &[f32]) -> Result<Self, ShapeError> {
        let mut v = heapless::Vec::new();
        let expected = param_count(inputs as usize, hidden as usize, layers as usize);
        if expected > P {
            return Err(ShapeError::OverCapacity {
                needed: expected,
                capacity: P,
            });
        }
        v.extend_from_slice(params)
            .map_err(|_| ShapeError::ParamCountMismatch {
                expected,
                found: params.len(),
            })?;
        let m = Self {
            inputs,
            hidden,
            layers,
            params: v,
        };
        m.check_shape()?;
        Ok(m)
    }

    /// Checks dimensions against the limits, the capacity and the parameter count.
    pub fn check_shape(&self) -> Result<(), ShapeError> {
        let (d, h, l) = (
            self.inputs as usize,
            self.hidden as usize,
            self.layers as usize,
        );
        if !(1..=MAX_INPUTS).contains(&d)
            || !(1..=MAX_HIDDEN).contains(&h)
            || !(1..=MAX_LAYERS).contains(&l)
        {
            return Err(ShapeError::DimensionOutOfRange);
        }
        let expected = param_count(d, h, l);
        if expected > P {
            return Err(ShapeError::OverCapacity {
                needed: expected,
                capacity: P,
            });
        }
        if self.params.len() != expected {
            return Err(ShapeError::ParamCountMismatch {
                expected,
                found: self.params.len(),
            });
        }
        Ok(())
    }

    /// The layout of the parameters ([`ScalerLayout`], no branch).
    pub fn layout(&self) -> ScalerLayout {
        ScalerLayout::mlp(
            self.inputs as usize,
            self.hidden as usize,
            self.layers as usize,
        )
    }

    /// Sets the first layer's weights of the last input (the alpha column of a scaler) to
    /// zero, so that the MLP does not see `alpha` (an alpha branch then carries the whole
    /// alpha dependence). Weights outside the parameter vector are left alone.
    pub fn clear_alpha_column(&mut self) {
        let layout = self.layout();
        let last = layout.inputs.saturating_sub(1);
        for i in 0..layout.hidden {
            if let Some(w) = layout
                .first_layer_weight(i, last)
                .and_then(|k| self.params.get_mut(k))
            {
                *w = 0.0;
            }
        }
    }

    /// Hidden layer `l` (0-based), or `None` if out of range or the shape is inconsistent.
    pub fn layer(&self, l: usize) -> Option<LayerView<'_>> {
        let r = self.layout().layer(l)?;
        let p: &[f32] = &self.params;
        Some(LayerView {
            w: p.get(r.w)?,
            b: p.get(r.b)?,
            gamma: p.get(r.gamma)?,
            beta: p.get(r.beta)?,
        })
    }

    /// Output weights `w_o` (`H`) and bias `b_o`.
    pub fn output(&self) -> Option<(&[f32], f32)> {
        let (w, b) = self.layout().output()?;
        Some((self.params.get(w)?, *self.params.get(b)?))
    }

    /// Reference forward pass: raw output `z` for normalised inputs `x` (length `inputs`),
    /// [`ScalerView::raw`] in `f32` with fused multiply-adds.
    ///
    /// Returns `None` only if the shape is inconsistent (never for a validated model).
    pub fn forward(&self, x: &[f32]) -> Option<f32> {
        if x.len() != self.inputs as usize {
            return None;
        }
        let view = self.view(None)?;
        let fold = view.fold::<math::Fused, f32>(x.get(1).copied().unwrap_or(0.0), 0.0)?;
        view.raw::<math::Fused, f32>(&fold, *x.first()?, None)
    }

    /// The lane-generic view of these weights ([`ScalerView`]) with the alpha branch
    /// `branch`, if any; `None` if the branch's parameter count does not match its shape.
    pub fn view<'a>(&'a self, branch: Option<&'a AlphaBranch>) -> Option<ScalerView<'a, f32>> {
        let layout = self.layout().with_branch(branch.map(AlphaBranch::layout));
        let (bw, direction): (&[f32], _) = match branch {
            Some(b) => (&b.params, b.direction),
            None => (&[], Direction::None),
        };
        (bw.len() == layout.branch_len()).then_some(ScalerView {
            layout,
            mlp: &self.params,
            branch: bw,
            direction,
        })
    }
}

/// `acc = init; acc = fma(w_j, x_j, acc)` over `j`.
#[inline(always)]
pub fn dot_acc(w: &[f32], x: &[f32], init: f32) -> f32 {
    w.iter()
        .zip(x)
        .fold(init, |acc, (&wj, &xj)| math::fma(wj, xj, acc))
}

/// [`dot_acc`] with the multiply-add `M`.
#[inline(always)]
fn dot_acc_with<M: math::MulAdd>(w: &[f32], x: &[f32], init: f32) -> f32 {
    w.iter()
        .zip(x)
        .fold(init, |acc, (&wj, &xj)| M::mul_add(wj, xj, acc))
}

/// Start of the activation-pattern hash (FNV-1a offset basis).
const PATTERN_SEED: u64 = 0xcbf2_9ce4_8422_2325;

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
    pub(crate) const EMPTY: Self = Self {
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

/// A scaler specialised for a fixed `alpha` and one state input, with the constant
/// `p_ini`, the input normalisation and the LayerNorm mean folded into the weights.
///
/// This is what runs every step. Relative to [`Scaler::scale`] it is the same function up to
/// f32 rounding (the folds are exact in real arithmetic):
///
/// - first layer: `h_i = W_i0 (u / u_scale) + (W_i1 alpha_n + b_i)`: the alpha column and
///   bias collapse into one bias, computed once per `alpha` ([`CompiledScaler::set_alpha`]);
///   `1/u_scale` is folded into the weight column.
/// - LayerNorm mean: `mean_i(W x + b) = (mean_i W_i) x + mean_i b`, so subtracting the row
///   mean of every column of `W` and the mean of `b` gives a pre-activation with zero mean;
///   the per-step mean and subtraction disappear.
/// - output: `p = p_ini (s_min + (s_max - s_min) sigmoid(z))` becomes
///   `fma(span, sigmoid(z), lo)` with `lo = p_ini s_min`, `span = p_ini (s_max - s_min)`.
///
/// Layout of `w`: layer 1 `w1c (H), b1c (H), gamma (H), beta (H)`; layers 2..=L `Wc (H x H),
/// bc (H), gamma (H), beta (H)`; output `w_o (H), b_o`. `Wc` is stored in column blocks of
/// [`COLUMN_BLOCK`] inputs (block `c`: all `H` rows, columns `16c .. min(16c + 16, H)`,
/// row-major), so for `H <= 16` it is plain row-major. The order of the arithmetic does not
/// depend on the layout.
///
/// # Exact arithmetic of [`CompiledScaler::eval`] (identical on every target)
///
/// ```text
/// layer 1:  t_i = fma(w1c_i, u, b1c_i)
/// layer l:  t_i = fma-chain: acc = bc_i; for j in 0..H: acc = fma(Wc_ij, a_j, acc)
/// each:     var = (fma-chain of t_i * t_i from 0, i ascending) * (1 / H)
///           r   = 1 / sqrt(var + LAYER_NORM_EPS)
///           a_i = leaky_relu(fma(gamma_i, t_i * r, beta_i))
/// output:   z   = fma-chain from b_o over w_o_i * a_i
/// branch:   z   = z + (fma-chain from 0 over v_k * leaky_relu(fma(r_k, u, bias_k)))
///                 (only with an alpha branch, see [`CompiledBranch`])
///           p   = fma(span, sigmoid(z), lo)
/// ```
///
/// On bare-metal hard-float Arm (Cortex-M4F) and `H` = 8, 16 or 32 the part from `u` to `z`
/// runs as a hand-scheduled FPU kernel (module `mlp::arm`) that performs exactly these
/// operations in this order with the IEEE 754 instructions `vfma.f32`, `vmul.f32`,
/// `vadd.f32`, `vsqrt.f32`, `vdiv.f32`, so it returns the same bits as this portable code on
/// the host (where `fma` is `libm::fmaf` and `sqrt` is `libm::sqrtf`, both correctly
/// rounded). Other widths use the portable code on every target.
#[derive(Debug, Clone)]
pub struct CompiledScaler<const P: usize> {
    hidden: usize,
    layers: usize,
    /// `[1 / H, LAYER_NORM_EPS, LEAKY_RELU_SLOPE, 0.0]`, in this order for the Arm kernel.
    consts: [f32; 4],
    w: heapless::Vec<f32, P>,
    /// Raw alpha column of layer 1 (times `1/alpha_scale`), for [`Self::set_alpha`].
    alpha_col: [f32; MAX_HIDDEN],
    /// Raw layer-1 bias.
    b1_raw: [f32; MAX_HIDDEN],
    lo: f32,
    span: f32,
    /// The alpha branch folded for the current `alpha`, if the scaler has one.
    branch: Option<CompiledBranch>,
}

/// Inputs per column block of a compiled hidden-layer matrix (see [`CompiledScaler`]).
pub const COLUMN_BLOCK: usize = 16;

/// Length of a compiled scaler's weight vector for width `h` and `layers` hidden layers
/// (`None` on overflow): `4H + (L - 1)(H^2 + 3H) + H + 1`.
pub const fn compiled_len(h: usize, layers: usize) -> Option<usize> {
    if layers == 0 {
        return None;
    }
    let Some(hh) = h.checked_mul(h) else {
        return None;
    };
    let Some(per) = hh.checked_add(3 * h) else {
        return None;
    };
    let Some(hidden) = per.checked_mul(layers - 1) else {
        return None;
    };
    let Some(n) = hidden.checked_add(5 * h) else {
        return None;
    };
    n.checked_add(1)
}

impl<const P: usize> CompiledScaler<P> {
    /// A scaler with no weights (`eval` returns `lo = 0`): the place to
    /// [`compile_into`](Self::compile_into), e.g. inside a `static`.
    pub const fn empty() -> Self {
        Self {
            hidden: 0,
            layers: 0,
            consts: [0.0; 4],
            w: heapless::Vec::new(),
            alpha_col: [0.0; MAX_HIDDEN],
            b1_raw: [0.0; MAX_HIDDEN],
            lo: 0.0,
            span: 0.0,
            branch: None,
        }
    }

    /// Compiles `scaler` for parameter constant `p_ini`, state scale `u_scale` (input 0) and
    /// `alpha` normalised by `alpha_scale` (input 1, if the MLP has two inputs), returned by
    /// value ([`Self::compile_into`] writes in place).
    ///
    /// Returns `None` if the scaler's shape is inconsistent (never for a validated model).
    pub fn compile(
        scaler: &Scaler<P>,
        p_ini: f32,
        u_scale: f32,
        alpha: f32,
        alpha_scale: f32,
    ) -> Option<Self> {
        Self::compile_with_branch(scaler, None, p_ini, u_scale, alpha, alpha_scale)
    }

    /// [`Self::compile`] with an optional alpha branch ([`AlphaBranch`]): the MLP's alpha
    /// column is ignored (zero in a valid model) and the branch is folded for `alpha`
    /// ([`CompiledBranch`]); [`Self::set_alpha`] re-folds both. The branch adds `K` fused
    /// multiply-adds, LeakyReLUs and fused multiply-adds per evaluation. Returned by value
    /// ([`Self::compile_into`] writes in place).
    ///
    /// Returns `None` if the scaler's or the branch's shape is inconsistent.
    pub fn compile_with_branch(
        scaler: &Scaler<P>,
        branch: Option<&AlphaBranch>,
        p_ini: f32,
        u_scale: f32,
        alpha: f32,
        alpha_scale: f32,
    ) -> Option<Self> {
        let mut c = Self::empty();
        c.compile_into(scaler, branch, p_ini, u_scale, alpha, alpha_scale)?;
        Some(c)
    }

    /// [`Self::compile_with_branch`] into `self`, in place: no copy of the weight vector on
    /// the stack. On `None` `self` holds a partial compilation and must be compiled again
    /// before use (its evaluation stays finite and panic-free, but meaningless).
    pub fn compile_into(
        &mut self,
        scaler: &Scaler<P>,
        branch: Option<&AlphaBranch>,
        p_ini: f32,
        u_scale: f32,
        alpha: f32,
        alpha_scale: f32,
    ) -> Option<()> {
        let compiled_branch = match branch {
            None => None,
            Some(b) => Some(CompiledBranch::compile(b, u_scale, alpha, alpha_scale)?),
        };
        let mlp = &scaler.mlp;
        mlp.check_shape().ok()?;
        let h = mlp.hidden as usize;
        let d = mlp.inputs as usize;
        self.hidden = 0;
        self.layers = 0;
        self.branch = None;
        let w = &mut self.w;
        w.clear();
        let alpha_col = &mut self.alpha_col;
        let b1_raw = &mut self.b1_raw;
        *alpha_col = [0.0f32; MAX_HIDDEN];
        *b1_raw = [0.0f32; MAX_HIDDEN];
        let hf = h as f32;
        for l in 0..mlp.layers as usize {
            let layer = mlp.layer(l)?;
            if l == 0 {
                // Weight column of the state input, scaled, then centred.
                let mut col = [0.0f32; MAX_HIDDEN];
                for ((c, row), (ac, br)) in col
                    .iter_mut()
                    .zip(layer.w.chunks_exact(d))
                    .zip(alpha_col.iter_mut().zip(b1_raw.iter_mut()))
                    .take(h)
                {
                    *c = *row.first()? / u_scale;
                    *ac = if d > 1 && compiled_branch.is_none() {
                        *row.get(1)? / alpha_scale
                    } else {
                        0.0
                    };
                    *br = 0.0;
                }
                for (br, &b) in b1_raw.iter_mut().zip(layer.b) {
                    *br = b;
                }
                let col = col.get(..h)?;
                let mean = col.iter().fold(0.0f32, |s, &v| s + v) / hf;
                for &c in col {
                    w.push(c - mean).ok()?;
                }
                // Placeholder bias; filled by set_alpha below.
                for _ in 0..h {
                    w.push(0.0).ok()?;
                }
            } else {
                let mut mean_col = [0.0f32; MAX_HIDDEN];
                for row in layer.w.chunks_exact(h) {
                    for (m, &v) in mean_col.iter_mut().zip(row) {
                        *m += v;
                    }
                }
                for m in mean_col.iter_mut() {
                    *m /= hf;
                }
                // Centred columns, block by block of COLUMN_BLOCK inputs.
                let mut c0 = 0;
                while c0 < h {
                    let c1 = (c0 + COLUMN_BLOCK).min(h);
                    let means = mean_col.get(c0..c1)?;
                    for row in layer.w.chunks_exact(h) {
                        for (&v, &m) in row.get(c0..c1)?.iter().zip(means) {
                            w.push(v - m).ok()?;
                        }
                    }
                    c0 = c1;
                }
                let mean_b = layer.b.iter().fold(0.0f32, |s, &v| s + v) / hf;
                for &b in layer.b {
                    w.push(b - mean_b).ok()?;
                }
            }
            w.extend_from_slice(layer.gamma).ok()?;
            w.extend_from_slice(layer.beta).ok()?;
        }
        let (w_o, b_o) = mlp.output()?;
        w.extend_from_slice(w_o).ok()?;
        w.push(b_o).ok()?;
        if Some(w.len()) != compiled_len(h, mlp.layers as usize) {
            return None;
        }
        self.hidden = h;
        self.layers = mlp.layers as usize;
        self.consts = [1.0 / hf, LAYER_NORM_EPS, LEAKY_RELU_SLOPE, 0.0];
        self.lo = p_ini * scaler.s_min;
        self.span = p_ini * (scaler.s_max - scaler.s_min);
        self.branch = compiled_branch;
        self.set_alpha(alpha);
        Some(())
    }

    /// Re-folds the alpha column into the first-layer bias (`alpha` in the same units as at
    /// compile time, before normalisation), and into the alpha branch's biases if there is
    /// one. `H` (+ `K`) fused multiply-adds; no per-step cost.
    pub fn set_alpha(&mut self, alpha: f32) {
        if let Some(b) = self.branch.as_mut() {
            b.set_alpha(alpha);
        }
        let h = self.hidden;
        let mut b = [0.0f32; MAX_HIDDEN];
        for ((bi, &br), &ac) in b.iter_mut().zip(&self.b1_raw).zip(&self.alpha_col).take(h) {
            *bi = math::fma(ac, alpha, br);
        }
        let bh = b.get(..h).unwrap_or(&[]);
        let [inv_h, ..] = self.consts;
        let mean = bh.iter().fold(0.0f32, |s, &v| s + v) * inv_h;
        if let Some(dst) = self.w.get_mut(h..2 * h) {
            for (d, &v) in dst.iter_mut().zip(bh) {
                *d = v - mean;
            }
        }
    }

    /// Physical parameter value `p(u)` at state input `u` (SI units of the state).
    #[inline]
    pub fn eval(&self, u: f32) -> f32 {
        bounded::<math::Fused, f32>(self.raw(u), self.lo, self.span).0
    }

    /// Raw network output `z` at state input `u`: the Arm FPU kernel where there is one
    /// for this width, the portable code otherwise (same bits; compared on the target by
    /// the firmware's bench through `testing::scaler_raw`).
    #[inline(always)]
    pub(crate) fn raw(&self, u: f32) -> f32 {
        #[cfg(all(
            target_arch = "arm",
            target_abi = "eabihf",
            target_os = "none",
            not(feature = "micromath")
        ))]
        if let Some(z) = arm::raw(self.hidden, self.layers, &self.w, &self.consts, u) {
            return match &self.branch {
                None => z,
                Some(b) => z + b.raw::<false, math::Fused>(u, &mut 0),
            };
        }
        self.raw_portable(u)
    }

    /// Portable evaluation of the raw output `z`: the reference of the Arm kernel.
    pub(crate) fn raw_portable(&self, u: f32) -> f32 {
        self.raw_generic::<false, math::Fused>(u, &mut 0)
    }

    /// [`Self::eval`] and the activation pattern at `u`: a hash of the signs of every
    /// LeakyReLU input. The function is smooth (analytic) wherever the pattern is constant;
    /// where it changes, one LeakyReLU switches slope (a kink). Portable arithmetic (the
    /// same bits as `eval`): the reference of [`Self::pattern`].
    pub fn eval_with_pattern(&self, u: f32) -> (f32, u64) {
        let mut pattern = PATTERN_SEED;
        let z = self.raw_generic::<true, math::Fused>(u, &mut pattern);
        (
            bounded::<math::Fused, f32>(z, self.lo, self.span).0,
            pattern,
        )
    }

    /// The activation pattern at `u` alone, as [`Self::eval_with_pattern`] hashes it but
    /// computed with unfused multiply-adds ([`math::Unfused`]), which [`crate::table`] uses
    /// to place table knots at the kinks.
    ///
    /// Why unfused: on the Cortex-M4F the portable fused multiply-add moves its operands
    /// through core registers (module docs of `mlp::arm`), and the kink scan evaluates the
    /// pattern at 128 points per table segment: with `f32` multiply and add the scan of the
    /// firmware's two 128-segment NEMM tables takes about a quarter of the instructions
    /// (nemm-firmware/README.md). The signs differ from the fused network's only where a
    /// LeakyReLU input is within rounding of zero, i.e. within a few ulps of a kink, which
    /// moves a knot by as much: far below the table's checked error bound. Host and target
    /// compute the same bits (IEEE `f32` operations in the same order).
    pub fn pattern(&self, u: f32) -> u64 {
        let mut pattern = PATTERN_SEED;
        self.raw_generic::<true, math::Unfused>(u, &mut pattern);
        pattern
    }

    /// The portable network; with `TRACK` the signs of the LeakyReLU inputs are hashed into
    /// `pattern` (FNV-1a over one byte per neuron).
    #[inline(always)]
    fn raw_generic<const TRACK: bool, M: math::MulAdd>(&self, u: f32, pattern: &mut u64) -> f32 {
        let h = self.hidden;
        // For an inconsistent layout (which `compile` rules out): `z = -inf` makes `eval`
        // return `lo`.
        let fallback = f32::NEG_INFINITY;
        let mut a = [0.0f32; MAX_HIDDEN];
        let mut t = [0.0f32; MAX_HIDDEN];
        let mut rest: &[f32] = &self.w;
        // Layer 1: scalar input.
        let (Some(w1), Some(b1)) = (take(&mut rest, h), take(&mut rest, h)) else {
            return fallback;
        };
        for ((ti, &wi), &bi) in t.iter_mut().zip(w1).zip(b1) {
            *ti = M::mul_add(wi, u, bi);
        }
        if !self.norm_act::<TRACK, M>(&mut rest, &t, &mut a, pattern) {
            return fallback;
        }
        for _ in 1..self.layers {
            let (Some(wm), Some(b)) = (take(&mut rest, h * h), take(&mut rest, h)) else {
                return fallback;
            };
            for (ti, &bi) in t.iter_mut().zip(b) {
                *ti = bi;
            }
            let mut blocks = wm;
            for xs in a.get(..h).unwrap_or(&[]).chunks(COLUMN_BLOCK) {
                let Some(block) = take(&mut blocks, h * xs.len()) else {
                    return fallback;
                };
                for (ti, row) in t.iter_mut().zip(block.chunks_exact(xs.len())) {
                    *ti = dot_acc_with::<M>(row, xs, *ti);
                }
            }
            if !self.norm_act::<TRACK, M>(&mut rest, &t, &mut a, pattern) {
                return fallback;
            }
        }
        let (Some(w_o), Some(b_o)) = (take(&mut rest, h), take(&mut rest, 1)) else {
            return fallback;
        };
        let z = dot_acc_with::<M>(
            w_o,
            a.get(..h).unwrap_or(&[]),
            b_o.first().copied().unwrap_or(0.0),
        );
        match &self.branch {
            None => z,
            Some(b) => z + b.raw::<TRACK, M>(u, pattern),
        }
    }

    /// True if the scaler has an alpha branch.
    pub fn has_branch(&self) -> bool {
        self.branch.is_some()
    }

    /// Centred LayerNorm + affine + LeakyReLU from `t` into `a`; consumes gamma and beta.
    #[inline(always)]
    fn norm_act<const TRACK: bool, M: math::MulAdd>(
        &self,
        rest: &mut &[f32],
        t: &[f32; MAX_HIDDEN],
        a: &mut [f32; MAX_HIDDEN],
        pattern: &mut u64,
    ) -> bool {
        let h = self.hidden;
        let (Some(g), Some(be)) = (take(rest, h), take(rest, h)) else {
            return false;
        };
        let th = t.get(..h).unwrap_or(&[]);
        let [inv_h, ..] = self.consts;
        let mut out = a.iter_mut();
        norm_act::<M, f32>(th, g, be, inv_h, |_, y, act| {
            if TRACK {
                *pattern = (*pattern ^ u64::from(y >= 0.0)).wrapping_mul(0x0000_0100_0000_01b3);
            }
            if let Some(ai) = out.next() {
                *ai = act;
            }
        });
        true
    }

    /// Output bounds `(lo, hi)` of [`Self::eval`] in physical units.
    pub fn bounds(&self) -> (f32, f32) {
        (self.lo, self.lo + self.span)
    }
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
