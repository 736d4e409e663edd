//! One scaler over the lanes of a pack (nemm-core's `ScalerView`, forward `raw` and
//! reverse `raw_backward`) and the activation record of one evaluation.

use crate::train::adjoint::{mlp, Direction, Real, ScalerWeights, Unfused, WindowLanes};

/// One scaler over the lanes at the pack's condition level: nemm-core's view of its
/// weights ([`mlp::ScalerView`]) and its alpha level folded in ([`mlp::Folded`]).
#[derive(Debug, Clone)]
pub(super) struct LaneScaler<'a, T> {
    view: mlp::ScalerView<'a, T>,
    pub(super) fold: Box<mlp::Folded<WindowLanes<T>>>,
    /// The MLP's first input when it has no state input (`b_pr`: `alpha_n`, or 0 with a
    /// branch).
    pub(super) x_alpha: WindowLanes<T>,
    /// The MLP's second input (`alpha_n`, or 0 with a branch).
    second: WindowLanes<T>,
    /// The branch's `alpha_n`.
    pub(super) alpha_n: WindowLanes<T>,
}

impl<'a, T: Real> LaneScaler<'a, T> {
    pub(super) fn new(s: &'a ScalerWeights<T>, alpha_n: WindowLanes<T>) -> Self {
        let direction = s.branch.map_or(Direction::None, |b| b.direction);
        let view = mlp::ScalerView::new(s.layout(), &s.w, direction)
            .expect("scaler weight count does not match its shape");
        let (x_alpha, second) = view.inputs(WindowLanes::default(), alpha_n);
        let fold = Box::new(
            view.fold::<Unfused, WindowLanes<T>>(second, alpha_n)
                .expect("consistent scaler shape"),
        );
        Self {
            view,
            fold,
            x_alpha,
            second,
            alpha_n,
        }
    }

    /// A record of the right size for this scaler.
    pub(super) fn act(&self) -> Act<T> {
        let l = &self.view.layout;
        Act::new(l.hidden, l.layers, l.branch.map_or(0, |b| b.units))
    }

    /// Raw output `z` at first input `x`, recording into `rec` if given.
    #[inline]
    pub(super) fn raw(&self, x: WindowLanes<T>, rec: Option<&mut Act<T>>) -> WindowLanes<T> {
        let z = match rec {
            None => self
                .view
                .raw::<Unfused, WindowLanes<T>>(&self.fold, x, None),
            Some(r) => {
                r.x0 = x;
                self.view
                    .raw::<Unfused, WindowLanes<T>>(&self.fold, x, Some(&mut r.tape_mut()))
            }
        };
        z.expect("consistent scaler shape")
    }

    /// Reverse mode of [`Self::raw`]: adds the weight gradients to `g` (the flat layout)
    /// and returns `dL/dx`.
    #[inline]
    pub(super) fn backward(
        &self,
        rec: &Act<T>,
        zbar: WindowLanes<T>,
        g: &mut [T],
    ) -> WindowLanes<T> {
        let (gm, gb) = g.split_at_mut(self.view.layout.mlp_len());
        self.view
            .raw_backward(&rec.tape(), rec.x0, self.second, self.alpha_n, zbar, gm, gb)
            .expect("consistent scaler shape")
    }
}

/// Activations of one scaler evaluation over the lanes (for the backward pass): the
/// storage of nemm-core's [`mlp::Tape`], the input and the sigmoid.
#[derive(Debug, Clone)]
pub(super) struct Act<T> {
    /// The MLP's first input.
    pub(super) x0: WindowLanes<T>,
    /// Normalised pre-activations `n = (h - mean) r`, `layers * H`.
    pub(super) n: Vec<WindowLanes<T>>,
    /// `1 / sqrt(var + eps)`, per layer.
    pub(super) r: Vec<WindowLanes<T>>,
    /// Activations after LeakyReLU, `layers * H`.
    pub(super) a: Vec<WindowLanes<T>>,
    /// `sigmoid(z)`.
    pub(super) sig: WindowLanes<T>,
    /// The alpha branch's pre-activations `t_k` (empty without a branch).
    bt: Vec<WindowLanes<T>>,
}

impl<T: Real> Act<T> {
    pub(super) fn new(h: usize, layers: usize, units: usize) -> Self {
        Self {
            x0: WindowLanes::default(),
            n: vec![WindowLanes::default(); h * layers],
            r: vec![WindowLanes::default(); layers],
            a: vec![WindowLanes::default(); h * layers],
            sig: WindowLanes::default(),
            bt: vec![WindowLanes::default(); units],
        }
    }

    fn tape_mut(&mut self) -> mlp::TapeMut<'_, WindowLanes<T>> {
        mlp::TapeMut {
            n: &mut self.n,
            r: &mut self.r,
            a: &mut self.a,
            branch_t: &mut self.bt,
        }
    }

    fn tape(&self) -> mlp::Tape<'_, WindowLanes<T>> {
        mlp::Tape {
            n: &self.n,
            r: &self.r,
            a: &self.a,
            branch_t: &self.bt,
        }
    }
}
