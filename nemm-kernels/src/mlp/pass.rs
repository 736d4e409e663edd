//! The scaler's forward pass (MLP and alpha branch, raw output `z`) and its reverse mode,
//! written once over any [`Lane`] and [`MulAdd`]: the reference path of the estimator and
//! model (`f32`, fused: [`super::MlpParams::forward`], [`super::Scaler::scale_with`]), the
//! trainer's rollout and adjoint ([`crate::math::Lanes`] of windows, unfused) and its
//! gradient checks (`f64`) all run these functions. The estimator's folded hot path
//! ([`super::CompiledScaler`]) and its Arm kernel are optimised forms of the same function,
//! tested against it.
//!
//! # Exact arithmetic (`M::mul_add` is `fma` for [`crate::math::Fused`])
//!
//! The MLP's second input (column 1 of `W1`, alpha for a scaler with a state input) is
//! folded into the first layer's bias once per condition level ([`Folded`]); the first
//! input `x` (the state, or alpha for a scaler of alpha alone) enters every evaluation:
//!
//! ```text
//! fold:     b1_i  = mul_add(W1_i1, x_1, b1_i)            (b1_i with one input)
//!           bias_k = mul_add(d theta_u,k^2, alpha_n, c_k)   (branch)
//! layer 1:  t_i   = mul_add(W1_i0, x, b1_i)
//! layer l:  t_i   = mul_add-chain: acc = bl_i; for j ascending: acc = mul_add(Wl_ij, a_j, acc)
//! each:     centre (mean left to right, times 1/H), then norm_act (crate::mlp::norm_act)
//! output:   z     = mul_add-chain from b_o over w_o_i a_i, i ascending
//! branch:   t_k   = mul_add(r_k, x, bias_k)                (bias_k without a state input)
//!           zb    = mul_add-chain from 0 over theta_v,k^2 leaky_relu(t_k), k ascending
//!           z     = z + zb
//! ```
//!
//! # Inputs by role ([`ScalerView::inputs`])
//!
//! A scaler with a state input (`b_fl`, `k_pr`: two MLP inputs) gets `x = state_n` and the
//! second input `alpha_n`; the scaler of alpha alone (`b_pr`: one input) gets
//! `x = alpha_n`. With an alpha branch the MLP's alpha input is 0 (its alpha column is zero
//! in a valid model) and the branch carries `alpha_n`.

#[cfg(feature = "reverse")]
use super::LEAKY_RELU_SLOPE;
use super::{centre, leaky_relu, norm_act};
#[cfg(feature = "reverse")]
use super::{centre_backward, norm_act_backward, BranchRanges, LayerRanges};
use super::{BranchLayout, Direction, ScalerLayout, MAX_BRANCH_UNITS, MAX_HIDDEN};
use crate::math::{Lane, MulAdd, Scalar};

/// A scaler's weights in the layout of [`ScalerLayout`]: the MLP's and the alpha
/// branch's (empty without a branch), and the branch's direction.
#[derive(Debug, Clone, Copy)]
pub struct ScalerView<'a, S> {
    /// Where each block sits.
    pub layout: ScalerLayout,
    /// The MLP's parameters (`layout.mlp_len()`).
    pub mlp: &'a [S],
    /// The branch's parameters (`layout.branch_len()`, relative ranges of
    /// [`super::BranchLayout::ranges`]).
    pub branch: &'a [S],
    /// The branch's direction `d` in alpha (ignored without a branch).
    pub direction: Direction,
}

/// The per-condition-level part of a scaler's evaluation: the first layer's bias with the
/// MLP's second input folded in, and the branch's unit biases (module docs).
#[derive(Debug, Clone, Copy)]
pub struct Folded<L> {
    /// `b1_i` with the second input folded in.
    pub b1: [L; MAX_HIDDEN],
    /// The branch's `mul_add(d theta_u,k^2, alpha_n, c_k)`.
    pub branch: [L; MAX_BRANCH_UNITS],
}

impl<L: Lane> Default for Folded<L> {
    fn default() -> Self {
        Self {
            b1: [L::default(); MAX_HIDDEN],
            branch: [L::default(); MAX_BRANCH_UNITS],
        }
    }
}

/// The forward pass's record for the reverse mode, written by [`ScalerView::raw`]: per
/// hidden layer `l` the normalised pre-activations `n` and the activations `a`
/// (`l H .. (l + 1) H` each), `r = 1 / sqrt(var + eps)`, and the branch's pre-activations.
#[derive(Debug)]
pub struct TapeMut<'t, L> {
    /// `n_i = t_i r`, `L H`.
    pub n: &'t mut [L],
    /// `r` per layer, `L`.
    pub r: &'t mut [L],
    /// Activations, `L H`.
    pub a: &'t mut [L],
    /// The branch's `t_k`, `K` (empty without a branch).
    pub branch_t: &'t mut [L],
}

/// A recorded forward pass ([`TapeMut`]), read by `ScalerView::raw_backward` (feature
/// `reverse`).
#[derive(Debug, Clone, Copy)]
pub struct Tape<'t, L> {
    /// `n_i = t_i r`, `L H`.
    pub n: &'t [L],
    /// `r` per layer, `L`.
    pub r: &'t [L],
    /// Activations, `L H`.
    pub a: &'t [L],
    /// The branch's `t_k`, `K`.
    pub branch_t: &'t [L],
}

/// `acc = init; acc = mul_add(w_j, x_j, acc)` for `j` ascending.
#[inline(always)]
fn dot<M: MulAdd, L: Lane>(w: &[L::Scalar], x: &[L], init: L) -> L {
    w.iter()
        .zip(x)
        .fold(init, |acc, (&wj, &xj)| M::mul_add(L::splat(wj), xj, acc))
}

/// `*g += v`.
#[cfg(feature = "reverse")]
#[inline(always)]
fn add<S: Scalar>(g: Option<&mut S>, v: S) {
    if let Some(g) = g {
        *g = *g + v;
    }
}

impl<'a, S: Scalar> ScalerView<'a, S> {
    /// The view of a flat vector holding the MLP's parameters then the branch's, or `None`
    /// if its length is not the layout's.
    pub fn new(layout: ScalerLayout, w: &'a [S], direction: Direction) -> Option<Self> {
        if w.len() != layout.len() {
            return None;
        }
        let (mlp, branch) = w.split_at_checked(layout.mlp_len())?;
        Some(Self {
            layout,
            mlp,
            branch,
            direction,
        })
    }

    /// The MLP's inputs `(x, second)` by role (module docs) at normalised `state_n` (unused
    /// by a scaler of alpha alone) and `alpha_n`.
    #[inline(always)]
    pub fn inputs<L: Lane<Scalar = S>>(&self, state_n: L, alpha_n: L) -> (L, L) {
        let mlp_alpha = if self.layout.branch.is_some() {
            L::default()
        } else {
            alpha_n
        };
        if self.layout.inputs >= 2 {
            (state_n, mlp_alpha)
        } else {
            (mlp_alpha, L::default())
        }
    }

    /// [`Folded`] for the MLP's second input `second` and the branch's `alpha_n`, into
    /// `f`; `None` for an inconsistent shape.
    pub fn fold_into<M: MulAdd, L: Lane<Scalar = S>>(
        &self,
        second: L,
        alpha_n: L,
        f: &mut Folded<L>,
    ) -> Option<()> {
        let layout = &self.layout;
        let r0 = layout.layer(0)?;
        if layout.hidden > MAX_HIDDEN || r0.fan_in == 0 {
            return None;
        }
        let (w, b) = (self.mlp.get(r0.w)?, self.mlp.get(r0.b)?);
        for ((o, &bi), row) in f.b1.iter_mut().zip(b).zip(w.chunks_exact(r0.fan_in)) {
            *o = match row.get(1) {
                Some(&wa) => M::mul_add(L::splat(wa), second, L::splat(bi)),
                None => L::splat(bi),
            };
        }
        if let Some(b) = layout.branch {
            fold_branch::<M, L>(b, self.branch, self.direction, alpha_n, &mut f.branch)?;
        }
        Some(())
    }

    /// [`Self::fold_into`] returned by value.
    pub fn fold<M: MulAdd, L: Lane<Scalar = S>>(&self, second: L, alpha_n: L) -> Option<Folded<L>> {
        let mut f = Folded::default();
        self.fold_into::<M, L>(second, alpha_n, &mut f)?;
        Some(f)
    }

    /// The raw output `z` at first input `x` (module docs), recording into `tape` if
    /// given; `None` for an inconsistent shape (never for a validated model).
    #[inline]
    pub fn raw<M: MulAdd, L: Lane<Scalar = S>>(
        &self,
        fold: &Folded<L>,
        x: L,
        mut tape: Option<&mut TapeMut<'_, L>>,
    ) -> Option<L> {
        let layout = &self.layout;
        let h = layout.hidden;
        if h == 0 || h > MAX_HIDDEN {
            return None;
        }
        let w = self.mlp;
        let inv_h = S::from_f32(1.0) / S::from_f32(h as f32);
        let mut t = [L::default(); MAX_HIDDEN];
        let mut a = [L::default(); MAX_HIDDEN];
        for l in 0..layout.layers {
            let r = layout.layer(l)?;
            let th = t.get_mut(..h)?;
            let wl = w.get(r.w)?;
            if l == 0 {
                for ((ti, row), &b) in th
                    .iter_mut()
                    .zip(wl.chunks_exact(r.fan_in.max(1)))
                    .zip(&fold.b1)
                {
                    *ti = M::mul_add(L::splat(*row.first()?), x, b);
                }
            } else {
                let ah = a.get(..h)?;
                for ((ti, row), &b) in th.iter_mut().zip(wl.chunks_exact(h)).zip(w.get(r.b)?) {
                    *ti = dot::<M, L>(row, ah, L::splat(b));
                }
            }
            centre(th, inv_h);
            let (gamma, beta) = (w.get(r.gamma)?, w.get(r.beta)?);
            let span = l.checked_mul(h)?..l.checked_add(1)?.checked_mul(h)?;
            match tape.as_deref_mut() {
                Some(tp) => {
                    let mut out = a
                        .iter_mut()
                        .zip(tp.n.get_mut(span.clone())?)
                        .zip(tp.a.get_mut(span)?);
                    let rl = norm_act::<M, L>(th, gamma, beta, inv_h, |n, _, act| {
                        if let Some(((ai, tn), ta)) = out.next() {
                            *ai = act;
                            *tn = n;
                            *ta = act;
                        }
                    });
                    *tp.r.get_mut(l)? = rl;
                }
                None => {
                    let mut out = a.iter_mut();
                    norm_act::<M, L>(th, gamma, beta, inv_h, |_, _, act| {
                        if let Some(ai) = out.next() {
                            *ai = act;
                        }
                    });
                }
            }
        }
        let (w_o, b_o) = layout.output()?;
        let z = dot::<M, L>(w.get(w_o)?, a.get(..h)?, L::splat(*w.get(b_o)?));
        match layout.branch {
            None => Some(z),
            Some(b) => {
                let rec = tape.map(|tp| &mut *tp.branch_t);
                Some(z + branch_raw::<M, L>(b, self.branch, &fold.branch, x, rec)?)
            }
        }
    }

    /// Reverse mode of [`Self::raw`] from `zbar = dL/dz` at the recorded `tape`, with the
    /// forward's inputs `x`, `second` and `alpha_n`: adds the lane sums of the weight
    /// gradients to `g_mlp` and `g_branch` (the layout of [`Self::mlp`] and
    /// [`Self::branch`]) and returns `dL/dx`. `None` for an inconsistent shape.
    #[allow(clippy::too_many_arguments)] // the record, the three inputs, two gradients
    #[inline]
    #[cfg(feature = "reverse")]
    #[cfg_attr(docsrs, doc(cfg(feature = "reverse")))]
    pub fn raw_backward<L: Lane<Scalar = S>>(
        &self,
        tape: &Tape<'_, L>,
        x: L,
        second: L,
        alpha_n: L,
        zbar: L,
        g_mlp: &mut [S],
        g_branch: &mut [S],
    ) -> Option<L> {
        let layout = &self.layout;
        let h = layout.hidden;
        let layers = layout.layers;
        if h == 0 || h > MAX_HIDDEN || layers == 0 {
            return None;
        }
        let inv_h = S::from_f32(1.0) / S::from_f32(h as f32);
        let mut abar = [L::default(); MAX_HIDDEN];
        self.output_backward(tape, zbar, g_mlp, &mut abar)?;
        let mut xbar = L::default();
        let mut hbar = [L::default(); MAX_HIDDEN];
        for l in (0..layers).rev() {
            let r = layout.layer(l)?;
            let hb = hbar.get_mut(..h)?;
            self.norm_backward(tape, l, &r, inv_h, abar.get(..h)?, hb, g_mlp)?;
            if l == 0 {
                self.input_layer_backward(&r, hb, x, second, g_mlp, &mut xbar)?;
            } else {
                self.hidden_layer_backward(tape, l, &r, hb, abar.get_mut(..h)?, g_mlp)?;
            }
        }
        if let Some(br) = layout.branch.and_then(|b| b.ranges()) {
            self.branch_backward(&br, tape.branch_t, x, alpha_n, zbar, g_branch, &mut xbar)?;
        }
        Some(xbar)
    }

    /// The output layer `z = b_o + sum_i w_o,i a_i` in reverse: adds the gradients of `b_o`
    /// and `w_o` to `g_mlp` and writes `dL/da` of the last layer into `abar`.
    #[cfg(feature = "reverse")]
    #[inline(always)]
    fn output_backward<L: Lane<Scalar = S>>(
        &self,
        tape: &Tape<'_, L>,
        zbar: L,
        g_mlp: &mut [S],
        abar: &mut [L; MAX_HIDDEN],
    ) -> Option<()> {
        let layout = &self.layout;
        let (w_o, b_o) = layout.output()?;
        add(g_mlp.get_mut(b_o), L::sum(zbar));
        let a_last = tape.a.get(layer_span(layout.hidden, layout.layers - 1)?)?;
        for (((ab, &ai), &wo), gi) in abar
            .iter_mut()
            .zip(a_last)
            .zip(self.mlp.get(w_o.clone())?)
            .zip(g_mlp.get_mut(w_o)?)
        {
            *gi = *gi + L::sum(zbar * ai);
            *ab = L::splat(wo) * zbar;
        }
        Some(())
    }

    /// Layer `l`'s LeakyReLU, LayerNorm affine, normalisation and centring in reverse: from
    /// `abar = dL/da` to `hb = dL/dt` (the pre-activations), adding the gradients of the gain
    /// and offset to `g_mlp`.
    #[allow(clippy::too_many_arguments)] // the record, the layer, two adjoints, the gradient
    #[cfg(feature = "reverse")]
    #[inline(always)]
    fn norm_backward<L: Lane<Scalar = S>>(
        &self,
        tape: &Tape<'_, L>,
        l: usize,
        r: &LayerRanges,
        inv_h: S,
        abar: &[L],
        hb: &mut [L],
        g_mlp: &mut [S],
    ) -> Option<()> {
        let h = self.layout.hidden;
        let span = layer_span(h, l)?;
        let (gg, gb) = g_mlp
            .get_mut(r.gamma.start..r.beta.end)?
            .split_at_mut_checked(h)?;
        norm_act_backward(
            abar,
            tape.n.get(span.clone())?,
            tape.a.get(span)?,
            *tape.r.get(l)?,
            self.mlp.get(r.gamma.clone())?,
            inv_h,
            hb,
            gg,
            gb,
        );
        centre_backward(hb, inv_h);
        Some(())
    }

    /// The first layer's linear map `t_i = W1_i0 x + W1_i1 second + b1_i` in reverse from
    /// `hb = dL/dt`: adds the gradients of `W1` and `b1` to `g_mlp` and `dL/dx` to `xbar`.
    #[cfg(feature = "reverse")]
    #[inline(always)]
    fn input_layer_backward<L: Lane<Scalar = S>>(
        &self,
        r: &LayerRanges,
        hb: &[L],
        x: L,
        second: L,
        g_mlp: &mut [S],
        xbar: &mut L,
    ) -> Option<()> {
        let fan_in = r.fan_in.max(1);
        let (gw, gbias) = g_mlp
            .get_mut(r.w.start..r.b.end)?
            .split_at_mut_checked(r.w.len())?;
        let wl = self.mlp.get(r.w.clone())?;
        for (((&hbi, gbi), grow), row) in hb
            .iter()
            .zip(gbias)
            .zip(gw.chunks_exact_mut(fan_in))
            .zip(wl.chunks_exact(fan_in))
        {
            *gbi = *gbi + L::sum(hbi);
            let s0 = L::sum(hbi * x);
            let s1 = L::sum(hbi * second);
            add(grow.first_mut(), s0);
            add(grow.get_mut(1), s1);
            *xbar = *xbar + L::splat(*row.first()?) * hbi;
        }
        Some(())
    }

    /// Hidden layer `l`'s linear map `t_i = sum_j Wl_ij a_j + bl_i` in reverse from
    /// `hb = dL/dt`: adds the gradients of `Wl` and `bl` to `g_mlp` and writes `dL/da` of
    /// layer `l - 1` into `abar`.
    #[cfg(feature = "reverse")]
    #[inline(always)]
    fn hidden_layer_backward<L: Lane<Scalar = S>>(
        &self,
        tape: &Tape<'_, L>,
        l: usize,
        r: &LayerRanges,
        hb: &[L],
        abar: &mut [L],
        g_mlp: &mut [S],
    ) -> Option<()> {
        let h = self.layout.hidden;
        let (gw, gbias) = g_mlp
            .get_mut(r.w.start..r.b.end)?
            .split_at_mut_checked(r.w.len())?;
        let a_prev = tape.a.get(layer_span(h, l - 1)?)?;
        for ((&hbi, gbi), grow) in hb.iter().zip(gbias).zip(gw.chunks_exact_mut(h)) {
            *gbi = *gbi + L::sum(hbi);
            for (gij, &aj) in grow.iter_mut().zip(a_prev) {
                *gij = *gij + L::sum(hbi * aj);
            }
        }
        // abar_{l-1, j} = sum_i W_ij hbar_i
        abar.fill(L::default());
        for (&hbi, row) in hb.iter().zip(self.mlp.get(r.w.clone())?.chunks_exact(h)) {
            for (abj, &wij) in abar.iter_mut().zip(row) {
                *abj = *abj + L::splat(wij) * hbi;
            }
        }
        Some(())
    }

    /// The alpha branch `zb = sum_k theta_v,k^2 leaky_relu(t_k)`,
    /// `t_k = r_k x + d theta_u,k^2 alpha_n + c_k`, in reverse from `zbar` at the recorded
    /// `branch_t`: adds its gradients to `g_branch` (relative ranges `br`) and `dL/dx` to `xbar`.
    #[allow(clippy::too_many_arguments)] // the ranges, the record, two inputs, two adjoints
    #[cfg(feature = "reverse")]
    #[inline(always)]
    fn branch_backward<L: Lane<Scalar = S>>(
        &self,
        br: &BranchRanges,
        branch_t: &[L],
        x: L,
        alpha_n: L,
        zbar: L,
        g_branch: &mut [S],
        xbar: &mut L,
    ) -> Option<()> {
        let d = S::from_f32(self.direction.sign());
        let two = S::from_f32(2.0);
        let one = L::constant(1.0);
        let slope = L::constant(LEAKY_RELU_SLOPE);
        let (r, tu, tv) = (
            self.branch.get(br.r.clone())?,
            self.branch.get(br.theta_u.clone())?,
            self.branch.get(br.theta_v.clone())?,
        );
        for (k, ((&t, &tu), &tv)) in branch_t.iter().zip(tu).zip(tv).enumerate() {
            let act = leaky_relu(t);
            let da = L::select_nonneg(t, one, slope);
            let s_act = L::sum(zbar * act);
            let tbar = zbar * L::splat(tv * tv) * da;
            if let Some(&rk) = r.get(k) {
                add(g_branch.get_mut(br.r.start + k), L::sum(tbar * x));
                *xbar = *xbar + L::splat(rk) * tbar;
            }
            add(
                g_branch.get_mut(br.theta_u.start + k),
                L::sum(tbar * alpha_n) * d * two * tu,
            );
            add(g_branch.get_mut(br.c.start + k), L::sum(tbar));
            add(g_branch.get_mut(br.theta_v.start + k), s_act * two * tv);
        }
        Some(())
    }
}

/// The records of layer `l` in a tape of `h` units per layer: `l h .. (l + 1) h`.
#[cfg(feature = "reverse")]
#[inline(always)]
fn layer_span(h: usize, l: usize) -> Option<core::ops::Range<usize>> {
    Some(l.checked_mul(h)?..l.checked_add(1)?.checked_mul(h)?)
}

/// The branch's unit biases `bias_k = mul_add(d theta_u,k^2, alpha_n, c_k)` of `branch`
/// (weights `w`, direction `direction`) into `bias`; `None` for an inconsistent shape.
pub(super) fn fold_branch<M: MulAdd, L: Lane>(
    branch: BranchLayout,
    w: &[L::Scalar],
    direction: Direction,
    alpha_n: L,
    bias: &mut [L],
) -> Option<()> {
    let br = branch.ranges()?;
    let d = L::Scalar::from_f32(direction.sign());
    let (tu, c) = (w.get(br.theta_u)?, w.get(br.c)?);
    if tu.len() > bias.len() {
        return None;
    }
    for ((o, &tu), &c) in bias.iter_mut().zip(tu).zip(c) {
        *o = M::mul_add(L::splat(d * (tu * tu)), alpha_n, L::splat(c));
    }
    Some(())
}

/// The branch's contribution `zb` at first input `x` from the folded unit biases `bias`
/// (module docs), recording the pre-activations `t_k` into `rec` if given.
#[inline(always)]
pub(super) fn branch_raw<M: MulAdd, L: Lane>(
    branch: BranchLayout,
    w: &[L::Scalar],
    bias: &[L],
    x: L,
    rec: Option<&mut [L]>,
) -> Option<L> {
    let br = branch.ranges()?;
    let (r, tv) = (w.get(br.r)?, w.get(br.theta_v)?);
    let mut zb = L::default();
    let mut rec = rec.map(|r| r.iter_mut());
    for (k, (&tv, &bias)) in tv.iter().zip(bias).enumerate() {
        let t = match r.get(k) {
            Some(&rk) => M::mul_add(L::splat(rk), x, bias),
            None => bias,
        };
        if let Some(bt) = rec.as_mut().and_then(|it| it.next()) {
            *bt = t;
        }
        zb = M::mul_add(L::splat(tv * tv), leaky_relu(t), zb);
    }
    Some(zb)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Fused, Lanes, Unfused};
    use crate::mlp::BranchLayout;

    type L2 = Lanes<f64, 2>;

    fn weights(n: usize, seed: f64) -> [f64; 128] {
        let mut w = [0.0; 128];
        for (i, v) in w.iter_mut().enumerate().take(n) {
            *v = libm::sin(i as f64 * 0.7 + seed) * 0.9 + 0.05;
        }
        w
    }

    /// `L = sum_lanes c . z` through `raw`, for the finite differences.
    fn loss(view: &ScalerView<'_, f64>, state: L2, alpha: L2, c: L2) -> f64 {
        let (x, second) = view.inputs(state, alpha);
        let fold = view.fold::<Unfused, L2>(second, alpha).unwrap();
        L2::sum(c * view.raw::<Unfused, L2>(&fold, x, None).unwrap())
    }

    /// `raw_backward` is the transpose of `raw`: every weight's and the state's adjoint match
    /// central differences (f64 lanes), with and without a branch, with and without a
    /// state input.
    #[test]
    fn raw_backward_matches_finite_differences() {
        for (inputs, branch) in [
            (2, None),
            (
                2,
                Some(BranchLayout {
                    state_inputs: 1,
                    units: 3,
                }),
            ),
            (1, None),
            (
                1,
                Some(BranchLayout {
                    state_inputs: 0,
                    units: 2,
                }),
            ),
        ] {
            let layout = ScalerLayout::mlp(inputs, 3, 2).with_branch(branch);
            let n = layout.len();
            let w0 = weights(n, inputs as f64);
            let dir = Direction::Decreasing;
            let view = ScalerView::new(layout, &w0[..n], dir).unwrap();
            let state = Lanes([0.4, -1.1]);
            let alpha = Lanes([0.3, 0.9]);
            let c = Lanes([1.0, -0.7]);
            // Backward.
            let (x, second) = view.inputs(state, alpha);
            let fold = view.fold::<Unfused, L2>(second, alpha).unwrap();
            let h = layout.hidden * layout.layers;
            let (mut tn, mut tr, mut ta) =
                ([L2::default(); 6], [L2::default(); 2], [L2::default(); 6]);
            let mut tb = [L2::default(); 3];
            let units = branch.map_or(0, |b| b.units);
            let mut tape = TapeMut {
                n: &mut tn[..h],
                r: &mut tr,
                a: &mut ta[..h],
                branch_t: &mut tb[..units],
            };
            view.raw::<Unfused, L2>(&fold, x, Some(&mut tape)).unwrap();
            let mut g = [0.0; 128];
            let (gm, gb) = g[..n].split_at_mut(layout.mlp_len());
            let tape = Tape {
                n: &tn[..h],
                r: &tr,
                a: &ta[..h],
                branch_t: &tb[..units],
            };
            let xbar = view
                .raw_backward(&tape, x, second, alpha, c, gm, gb)
                .unwrap();
            let eps = 1e-6;
            for i in 0..n {
                let (mut p, mut m) = (w0, w0);
                p[i] += eps;
                m[i] -= eps;
                let lp = loss(
                    &ScalerView::new(layout, &p[..n], dir).unwrap(),
                    state,
                    alpha,
                    c,
                );
                let lm = loss(
                    &ScalerView::new(layout, &m[..n], dir).unwrap(),
                    state,
                    alpha,
                    c,
                );
                let want = (lp - lm) / (2.0 * eps);
                assert!(
                    (g[i] - want).abs() <= 1e-6 * want.abs().max(1.0),
                    "inputs {inputs} branch {branch:?} weight {i}: {} vs {want}",
                    g[i]
                );
            }
            if inputs == 2 {
                for k in 0..2 {
                    let (mut p, mut m) = (state, state);
                    p.0[k] += eps;
                    m.0[k] -= eps;
                    let want = (loss(&view, p, alpha, c) - loss(&view, m, alpha, c)) / (2.0 * eps);
                    assert!(
                        (xbar.0[k] - want).abs() <= 1e-6 * want.abs().max(1.0),
                        "branch {branch:?} state lane {k}: {} vs {want}",
                        xbar.0[k]
                    );
                }
            }
        }
    }

    /// One definition over every lane type: a pack of `f32` lanes computes, lane by lane,
    /// the bits of the scalar `f32` evaluation (fused and unfused).
    #[test]
    fn lanes_compute_the_scalar_bits() {
        let layout = ScalerLayout::mlp(2, 5, 3).with_branch(Some(BranchLayout {
            state_inputs: 1,
            units: 4,
        }));
        let n = layout.len();
        let w: [f32; 128] = weights(n, 0.3).map(|v| v as f32);
        let view = ScalerView::new(layout, &w[..n], Direction::Increasing).unwrap();
        let xs = [-1.3f32, -0.2, 0.0, 0.7];
        let al = [0.0f32, 0.25, 0.5, 1.0];
        macro_rules! check {
            ($m:ty) => {
                let fold = view
                    .fold::<$m, Lanes<f32, 4>>(Lanes::default(), Lanes(al))
                    .unwrap();
                let z = view
                    .raw::<$m, Lanes<f32, 4>>(&fold, Lanes(xs), None)
                    .unwrap();
                for k in 0..4 {
                    let f1 = view.fold::<$m, f32>(0.0, al[k]).unwrap();
                    let z1 = view.raw::<$m, f32>(&f1, xs[k], None).unwrap();
                    assert_eq!(z.0[k].to_bits(), z1.to_bits(), "lane {k}");
                }
            };
        }
        check!(Fused);
        check!(Unfused);
    }
}
