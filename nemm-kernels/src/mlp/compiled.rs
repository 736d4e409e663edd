//! The hot-path form of a scaler ([`CompiledScaler`]): compiled for one `alpha`, folded
//! and evaluated in the exact `f32` order the firmware runs.

use super::layers::{dot_acc_with, PATTERN_SEED};
use super::params::take;
use super::*;
use crate::cumulative::{self, CumulativeScaler};

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
///
/// # Cumulative mode
///
/// [`CompiledScaler::compile_cumulative_into`] compiles a cumulative scaler
/// ([`crate::cumulative`]) instead of an MLP, into the same storage (no second weight
/// array; a mode field says which is in use). With `K` units, `u_j` the gate slopes
/// (`d gamma_j^2`), `beta_j` the gate biases, `p_j` the softmax weights, `w_k = exp(omega_k)`,
/// `c_k` the centres and `pi_j = p_j g_j` the mixture weights at the current level:
///
/// ```text
/// w:          p_ini, pi_0, K x [w_k, c_k, tanh(c_k), pi_k], p_0 .. p_K     5 K + 3 values
/// alpha_col:  u_0 .. u_K          (the gates' slopes in alpha_n)
/// b1_raw:     beta_0 .. beta_K    (the gates' biases)
/// consts:     [u_scale, alpha_scale, s_min, s_max - s_min]
/// lo, span:   p_ini s_min, p_ini (s_max - s_min)   (the bounds, as in the MLP mode)
/// ```
///
/// [`CompiledScaler::set_alpha`] re-folds the gates (`K + 1` sigmoids):
///
/// ```text
/// alpha_n = alpha / alpha_scale
/// pi_j    = p_j * sigmoid(fma(u_j, alpha_n, beta_j)),   sigmoid(v) = 1 / (1 + exp(-v))
/// ```
///
/// and [`CompiledScaler::eval`] is
///
/// ```text
/// x   = u / u_scale
/// acc = pi_0; per unit k ascending:  y = w_k * x
///                                    h = (tanh(y) / y) * (1 - tanh(y + c_k) * tanh(c_k))
///                                    acc = fma(pi_k, h, acc)
/// p   = p_ini * fma(s_max - s_min, acc, s_min)
/// ```
///
/// with `tanh` and `tanh(y) / y` (its series for `|y| < 0.1`) those of
/// [`crate::cumulative::CumulativeFold::mixture`]: the operations of the reference path
/// `p_ini * CumulativeScaler::scale(u / u_scale, alpha / alpha_scale, s_min, s_max)` in its
/// order, so the compiled scaler returns its bits (also after [`CompiledScaler::set_alpha`]).
/// Per evaluation: one division, and per unit two `exp` and three divisions.
/// The function is smooth: [`CompiledScaler::pattern`] is constant, and a table of it
/// ([`crate::table`]) has no kinks and spreads its knots uniformly. A unit much sharper
/// than a table segment (`w_k / u_scale` times the segment width well above 1) makes the
/// table miss its bound, which the table's check refuses ([`crate::table::TableError`]):
/// such a scaler runs exactly or with more segments.
#[derive(Debug, Clone)]
pub struct CompiledScaler<const P: usize> {
    /// Which function is compiled.
    mode: Mode,
    /// `H` (the MLP's width), or `K` (the cumulative scaler's units).
    hidden: usize,
    /// `L` (0 in the cumulative mode).
    layers: usize,
    /// `[1 / H, LAYER_NORM_EPS, LEAKY_RELU_SLOPE, 0.0]`, in this order for the Arm kernel
    /// (cumulative mode: see the type's docs).
    consts: [f32; 4],
    w: heapless::Vec<f32, P>,
    /// Raw alpha column of layer 1 (times `1/alpha_scale`), for [`Self::set_alpha`]
    /// (cumulative mode: the gates' slopes).
    alpha_col: [f32; MAX_HIDDEN],
    /// Raw layer-1 bias (cumulative mode: the gates' biases).
    b1_raw: [f32; MAX_HIDDEN],
    lo: f32,
    span: f32,
    /// The alpha branch folded for the current `alpha`, if the scaler has one.
    branch: Option<CompiledBranch>,
}

/// Which function a [`CompiledScaler`] holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// An MLP (and its alpha branch, if any).
    Mlp,
    /// A cumulative scaler (the type's docs, "Cumulative mode").
    Cumulative,
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
            mode: Mode::Mlp,
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
        self.mode = Mode::Mlp;
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
        if self.mode == Mode::Cumulative {
            self.set_cumulative_alpha(alpha);
            return;
        }
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
        match self.mode {
            Mode::Mlp => bounded::<math::Fused, f32>(self.raw(u), self.lo, self.span).0,
            Mode::Cumulative => self.eval_cumulative(u),
        }
    }

    /// Raw network output `z` at state input `u`: the Arm FPU kernel where there is one
    /// for this width, the portable code otherwise (same bits; compared on the target by
    /// the firmware's bench through `testing::scaler_raw`). In the cumulative mode: the
    /// mixture `pi_0 + sum_k pi_k h(w_k x, c_k)` at `x = u / u_scale`.
    #[inline(always)]
    pub fn raw(&self, u: f32) -> f32 {
        if self.mode == Mode::Cumulative {
            let [u_scale, ..] = self.consts;
            return self.mixture(u / u_scale);
        }
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
    pub fn raw_portable(&self, u: f32) -> f32 {
        self.raw_generic::<false, math::Fused>(u, &mut 0)
    }

    /// [`Self::eval`] and the activation pattern at `u`: a hash of the signs of every
    /// LeakyReLU input. The function is smooth (analytic) wherever the pattern is constant;
    /// where it changes, one LeakyReLU switches slope (a kink). Portable arithmetic (the
    /// same bits as `eval`): the reference of [`Self::pattern`].
    pub fn eval_with_pattern(&self, u: f32) -> (f32, u64) {
        if self.mode == Mode::Cumulative {
            return (self.eval_cumulative(u), PATTERN_SEED);
        }
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
    ///
    /// In the cumulative mode the function is smooth: the pattern is a constant.
    pub fn pattern(&self, u: f32) -> u64 {
        if self.mode == Mode::Cumulative {
            return PATTERN_SEED;
        }
        let mut pattern = PATTERN_SEED;
        self.raw_generic::<true, math::Unfused>(u, &mut pattern);
        pattern
    }

    /// The portable network; with `TRACK` the signs of the LeakyReLU inputs are hashed into
    /// `pattern` (FNV-1a over one byte per neuron).
    #[inline(always)]
    fn raw_generic<const TRACK: bool, M: math::MulAdd>(&self, u: f32, pattern: &mut u64) -> f32 {
        if self.mode == Mode::Cumulative {
            let [u_scale, ..] = self.consts;
            return self.mixture(u / u_scale);
        }
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

    /// Output bounds `(lo, hi)` of [`Self::eval`] in physical units: `p_ini s_min` and
    /// `p_ini s_max` (up to rounding), in both modes.
    pub fn bounds(&self) -> (f32, f32) {
        (self.lo, self.lo + self.span)
    }

    /// Compiles the cumulative scaler `c` with the bounds `s_min`, `s_max` (the model's
    /// scaler bounds of the coefficient) into `self`, in place: [`Self::eval`] then returns
    /// `p_ini * s(u / u_scale, alpha / alpha_scale)`, the cumulative scale
    /// ([`CumulativeScaler::scale`]) bit for bit; [`Self::set_alpha`] re-folds its gates
    /// (the type's docs, "Cumulative mode"). Never has an alpha branch.
    ///
    /// Returns `None` if `c`'s shape is inconsistent or its `5 K + 3` compiled values do not
    /// fit the capacity `P`; `self` then holds a partial compilation that must be compiled
    /// again before use (its evaluation stays finite and panic-free, but meaningless).
    #[allow(clippy::too_many_arguments)]
    pub fn compile_cumulative_into(
        &mut self,
        c: &CumulativeScaler,
        s_min: f32,
        s_max: f32,
        p_ini: f32,
        u_scale: f32,
        alpha: f32,
        alpha_scale: f32,
    ) -> Option<()> {
        self.mode = Mode::Mlp;
        self.hidden = 0;
        self.layers = 0;
        self.branch = None;
        self.w.clear();
        self.alpha_col = [0.0; MAX_HIDDEN];
        self.b1_raw = [0.0; MAX_HIDDEN];
        let view = c.view()?;
        let k = view.units();
        // The gates' slopes and biases (K + 1 <= MAX_CUMULATIVE_UNITS + 1 <= MAX_HIDDEN).
        for (j, (&gamma, &beta)) in view.gamma.iter().zip(view.beta).enumerate() {
            *self.alpha_col.get_mut(j)? = view.gate_slope(gamma).0;
            *self.b1_raw.get_mut(j)? = beta;
        }
        // The softmax and the units as the reference fold computes them (the gates are
        // folded again by `set_alpha` below).
        let fold = view.fold::<f32>(alpha / alpha_scale);
        let w = &mut self.w;
        w.push(p_ini).ok()?;
        w.push(0.0).ok()?;
        for ((&wk, &ck), &tk) in fold.w.iter().zip(&fold.c).zip(&fold.tc).take(k) {
            w.extend_from_slice(&[wk, ck, tk, 0.0]).ok()?;
        }
        w.extend_from_slice(fold.p.get(..=k)?).ok()?;
        self.consts = [u_scale, alpha_scale, s_min, s_max - s_min];
        self.lo = p_ini * s_min;
        self.span = p_ini * (s_max - s_min);
        self.hidden = k;
        self.mode = Mode::Cumulative;
        self.set_cumulative_alpha(alpha);
        Some(())
    }

    /// True if a cumulative scaler is compiled ([`Self::compile_cumulative_into`]).
    pub fn is_cumulative(&self) -> bool {
        self.mode == Mode::Cumulative
    }

    /// The cumulative mode's [`Self::set_alpha`]: `pi_j = p_j g_j(alpha_n)`.
    fn set_cumulative_alpha(&mut self, alpha: f32) {
        let k = self.hidden;
        let [_, alpha_scale, ..] = self.consts;
        let alpha_n = alpha / alpha_scale;
        let (slopes, biases) = (&self.alpha_col, &self.b1_raw);
        let Some((head, rest)) = self.w.split_at_mut_checked(2) else {
            return;
        };
        let Some((units, p)) = rest.split_at_mut_checked(4 * k) else {
            return;
        };
        let pi = |j: usize| -> Option<f32> {
            let g = cumulative::sigmoid(math::fma(*slopes.get(j)?, alpha_n, *biases.get(j)?));
            Some(*p.get(j)? * g)
        };
        if let (Some(slot), Some(v)) = (head.get_mut(1), pi(0)) {
            *slot = v;
        }
        for (j, unit) in units.chunks_exact_mut(4).enumerate() {
            if let (Some(slot), Some(v)) = (unit.get_mut(3), pi(j + 1)) {
                *slot = v;
            }
        }
    }

    /// The cumulative mode's mixture `pi_0 + sum_k pi_k h(w_k x, c_k)` at `x`.
    #[inline]
    fn mixture(&self, x: f32) -> f32 {
        let rest = self.w.get(1..).unwrap_or(&[]);
        let Some((&pi0, units)) = rest.split_first() else {
            return 0.0;
        };
        let units = units.get(..4 * self.hidden).unwrap_or(&[]);
        let mut acc = pi0;
        for u in units.chunks_exact(4) {
            if let [w, c, tc, pi] = *u {
                let (h, _) = cumulative::unit_mean(w * x, c, tc);
                acc = math::fma(pi, h, acc);
            }
        }
        acc
    }

    /// The cumulative mode's [`Self::eval`].
    #[inline]
    fn eval_cumulative(&self, u: f32) -> f32 {
        let [u_scale, _, s_min, s_span] = self.consts;
        let p_ini = self.w.first().copied().unwrap_or(0.0);
        p_ini * math::fma(s_span, self.mixture(u / u_scale), s_min)
    }
}

#[cfg(test)]
mod tests;
