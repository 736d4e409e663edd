//! Where every block of a scaler sits in its flat parameter vector: the one definition of
//! the layout that the weight format, the reference and compiled forward passes, the
//! trainer's rollout and adjoint, and its burn modules all read.
//!
//! A scaler's parameters are its MLP's (module docs of [`crate::mlp`]), followed, in the
//! trainer's flat vector, by its alpha branch's ([`super::AlphaBranch`]; in a
//! nemm-core's `Model` the branch's parameters are a vector of their own, with the ranges of
//! [`BranchLayout::ranges`]):
//!
//! ```text
//! layer 1:        W1 (H x d, row-major), b1 (H), gamma1 (H), beta1 (H)
//! layer 2..=L:    Wl (H x H),            bl (H), gammal (H), betal (H)
//! output:         w_o (H), b_o (1)
//! branch:         r (K s), theta_u (K), c (K), theta_v (K)
//! ```
//!
//! Every method uses checked arithmetic and returns `None` (or a saturated count) instead of
//! overflowing, so a layout built from untrusted dimensions never panics; a range it returns
//! is meant for `slice::get`.

use core::ops::Range;

/// The shape of a scaler's alpha branch: `s` state inputs (0 or 1) and `K` units.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BranchLayout {
    /// State inputs `s` (1 for `b_fl`, `k_pr`; 0 for `b_pr`).
    pub state_inputs: usize,
    /// Units `K`.
    pub units: usize,
}

/// The ranges of a branch's blocks, relative to the start of the branch's parameters.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BranchRanges {
    /// State weights `r` (`K s`; empty without a state input).
    pub r: Range<usize>,
    /// `theta_u` (`K`).
    pub theta_u: Range<usize>,
    /// Biases `c` (`K`).
    pub c: Range<usize>,
    /// `theta_v` (`K`).
    pub theta_v: Range<usize>,
}

impl BranchRanges {
    /// The same ranges moved by `offset`, or `None` on overflow.
    fn shifted(self, offset: usize) -> Option<Self> {
        let s = |r: Range<usize>| Some(r.start.checked_add(offset)?..r.end.checked_add(offset)?);
        Some(Self {
            r: s(self.r)?,
            theta_u: s(self.theta_u)?,
            c: s(self.c)?,
            theta_v: s(self.theta_v)?,
        })
    }
}

impl BranchLayout {
    /// Number of the branch's parameters, `K (3 + s)` (saturating).
    pub const fn len(&self) -> usize {
        self.units
            .saturating_mul(3usize.saturating_add(self.state_inputs))
    }

    /// True without parameters (never for a valid branch).
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The blocks' ranges within the branch's parameters (`None` on overflow).
    pub fn ranges(&self) -> Option<BranchRanges> {
        let k = self.units;
        let r_end = k.checked_mul(self.state_inputs)?;
        let tu_end = r_end.checked_add(k)?;
        let c_end = tu_end.checked_add(k)?;
        let tv_end = c_end.checked_add(k)?;
        Some(BranchRanges {
            r: 0..r_end,
            theta_u: r_end..tu_end,
            c: tu_end..c_end,
            theta_v: c_end..tv_end,
        })
    }
}

/// The ranges of one hidden layer's blocks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LayerRanges {
    /// Inputs of the layer (`d` for the first, `H` for the others).
    pub fan_in: usize,
    /// Weight matrix, row-major `H x fan_in` (row `i` is output `i`).
    pub w: Range<usize>,
    /// Bias (`H`).
    pub b: Range<usize>,
    /// LayerNorm gain (`H`).
    pub gamma: Range<usize>,
    /// LayerNorm offset (`H`).
    pub beta: Range<usize>,
}

/// The shape of a scaler: its MLP (`d` inputs, width `H`, `L` hidden layers) and its
/// optional alpha branch, and from it the position of every block in the flat vector
/// (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ScalerLayout {
    /// Inputs `d` of the MLP.
    pub inputs: usize,
    /// Hidden width `H`.
    pub hidden: usize,
    /// Hidden layers `L`.
    pub layers: usize,
    /// The alpha branch, whose parameters follow the MLP's.
    pub branch: Option<BranchLayout>,
}

impl ScalerLayout {
    /// The layout of an MLP without a branch.
    pub const fn mlp(inputs: usize, hidden: usize, layers: usize) -> Self {
        Self {
            inputs,
            hidden,
            layers,
            branch: None,
        }
    }

    /// The same MLP with the branch `branch` after it.
    pub const fn with_branch(self, branch: Option<BranchLayout>) -> Self {
        Self { branch, ..self }
    }

    /// Number of the MLP's parameters ([`super::param_count`], saturating).
    pub const fn mlp_len(&self) -> usize {
        super::param_count(self.inputs, self.hidden, self.layers)
    }

    /// Number of the branch's parameters (0 without a branch).
    pub const fn branch_len(&self) -> usize {
        match self.branch {
            Some(b) => b.len(),
            None => 0,
        }
    }

    /// Number of all parameters, the MLP's and the branch's (saturating).
    pub const fn len(&self) -> usize {
        self.mlp_len().saturating_add(self.branch_len())
    }

    /// True without parameters (an MLP without layers).
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Hidden layer `l` (0-based), or `None` past the last layer or on overflow.
    pub fn layer(&self, l: usize) -> Option<LayerRanges> {
        let (d, h) = (self.inputs, self.hidden);
        if l >= self.layers {
            return None;
        }
        let h3 = h.checked_mul(3)?;
        let first = d.checked_mul(h)?.checked_add(h3)?;
        let other = h.checked_mul(h)?.checked_add(h3)?;
        let start = match l.checked_sub(1) {
            None => 0,
            Some(m) => first.checked_add(other.checked_mul(m)?)?,
        };
        let fan_in = if l == 0 { d } else { h };
        let b = start.checked_add(fan_in.checked_mul(h)?)?;
        let gamma = b.checked_add(h)?;
        let beta = gamma.checked_add(h)?;
        let end = beta.checked_add(h)?;
        Some(LayerRanges {
            fan_in,
            w: start..b,
            b: b..gamma,
            gamma: gamma..beta,
            beta: beta..end,
        })
    }

    /// The output weights `w_o` (`H`) and the index of the output bias `b_o` (the MLP's
    /// last parameter), or `None` for an MLP without layers.
    pub fn output(&self) -> Option<(Range<usize>, usize)> {
        if self.layers == 0 {
            return None;
        }
        let b_o = self.mlp_len().checked_sub(1)?;
        Some((b_o.checked_sub(self.hidden)?..b_o, b_o))
    }

    /// The MLP's parameters within the flat vector.
    pub const fn mlp_range(&self) -> Range<usize> {
        0..self.mlp_len()
    }

    /// The branch's parameters within the flat vector (empty without a branch).
    pub const fn branch_range(&self) -> Range<usize> {
        self.mlp_len()..self.len()
    }

    /// The branch's blocks within the flat vector (`None` without a branch or on overflow).
    pub fn branch_ranges(&self) -> Option<BranchRanges> {
        self.branch?.ranges()?.shifted(self.mlp_len())
    }

    /// Index of the weight of MLP input `j` into hidden neuron `i` of the first layer
    /// (`j = d - 1` is the alpha column of a scaler with a state input), or `None` out of
    /// range.
    pub fn first_layer_weight(&self, i: usize, j: usize) -> Option<usize> {
        if i >= self.hidden || j >= self.inputs || self.layers == 0 {
            return None;
        }
        i.checked_mul(self.inputs)?.checked_add(j)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ranges tile the vector in the documented order, without gaps or overlaps.
    #[test]
    fn ranges_tile_the_vector() {
        for (d, h, l, b) in [
            (1, 1, 1, None),
            (2, 3, 2, Some((1, 4))),
            (1, 16, 5, Some((0, 2))),
            (2, 32, 9, None),
        ] {
            let layout = ScalerLayout::mlp(d, h, l).with_branch(b.map(|(s, k)| BranchLayout {
                state_inputs: s,
                units: k,
            }));
            let mut next = 0;
            let mut expect = |r: Range<usize>, n: usize| {
                assert_eq!(r, next..next + n);
                next += n;
                next
            };
            for i in 0..l {
                let lr = layout.layer(i).unwrap();
                let fan_in = if i == 0 { d } else { h };
                assert_eq!(lr.fan_in, fan_in);
                expect(lr.w, fan_in * h);
                expect(lr.b, h);
                expect(lr.gamma, h);
                expect(lr.beta, h);
            }
            assert!(layout.layer(l).is_none());
            let (w_o, b_o) = layout.output().unwrap();
            expect(w_o, h);
            let mlp_end = expect(b_o..b_o + 1, 1);
            assert_eq!(mlp_end, layout.mlp_len());
            assert_eq!(layout.mlp_range(), 0..mlp_end);
            let end = if let Some((s, k)) = b {
                let br = layout.branch_ranges().unwrap();
                expect(br.r, k * s);
                expect(br.theta_u, k);
                expect(br.c, k);
                expect(br.theta_v, k)
            } else {
                assert!(layout.branch_ranges().is_none());
                mlp_end
            };
            assert_eq!(end, layout.len());
            assert_eq!(layout.branch_range(), layout.mlp_len()..end);
        }
    }

    #[test]
    fn huge_dimensions_do_not_panic() {
        let layout =
            ScalerLayout::mlp(usize::MAX, usize::MAX, usize::MAX).with_branch(Some(BranchLayout {
                state_inputs: usize::MAX,
                units: usize::MAX,
            }));
        assert!(layout.layer(3).is_none());
        let _ = layout.output();
        assert!(layout.branch_ranges().is_none());
        assert_eq!(layout.len(), usize::MAX);
        assert!(layout.first_layer_weight(usize::MAX - 1, 0).is_none());
    }
}
