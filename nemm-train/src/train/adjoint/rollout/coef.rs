//! The state-dependent coefficients `b_fl(v_st, alpha)` and `k_pr(x_pr, alpha)` over the
//! lanes: a constant, a bounded MLP scaler or a cumulative scaler, forward and reverse.

use super::scaler::{Act, LaneScaler};
use crate::train::adjoint::{mlp, Lane, MulAdd, Real, ScalerWeights, Unfused, WindowLanes};
use nemm_kernels::cumulative::{CumulativeFold, CumulativeView};

/// A coefficient: constant `c0`, or `c0 (s_min + (s_max - s_min) m)` with `m =
/// sigmoid(z(state / scale, alpha_n))` for an MLP scaler (nemm-core's [`mlp::bounded`] with
/// `lo = c0 s_min`, `span = c0 (s_max - s_min)`) or `m` the mixture of a cumulative scaler
/// (`nemm_kernels::cumulative`).
pub(super) struct Coef<'a, T: Real> {
    pub(super) c0: T,
    pub(super) neural: Option<NeuralCoef<'a, T>>,
}

pub(super) struct NeuralCoef<'a, T: Real> {
    pub(super) family: Family<'a, T>,
    pub(super) s_min: T,
    pub(super) span: T,
    inv_scale: T,
}

/// The scaler of a neural coefficient over the lanes.
pub(super) enum Family<'a, T: Real> {
    /// An MLP (and alpha branch) with the bounded sigmoid output.
    Mlp(LaneScaler<'a, T>),
    /// A cumulative scaler folded at the pack's levels.
    Cumulative {
        view: CumulativeView<'a, T>,
        fold: Box<CumulativeFold<WindowLanes<T>>>,
    },
}

impl<'a, T: Real> Coef<'a, T> {
    pub(super) fn new(
        c0: T,
        s: Option<&'a ScalerWeights<T>>,
        scale: T,
        alpha_n: WindowLanes<T>,
    ) -> Self {
        Self {
            c0,
            neural: s.map(|s| NeuralCoef {
                family: match s.cumulative_view() {
                    Some(view) => Family::Cumulative {
                        fold: Box::new(view.fold(alpha_n)),
                        view,
                    },
                    None => Family::Mlp(LaneScaler::new(s, alpha_n)),
                },
                s_min: s.s_min,
                span: s.s_max - s.s_min,
                inv_scale: T::one() / scale,
            }),
        }
    }

    pub(super) fn act(&self) -> Option<Act<T>> {
        self.neural.as_ref().map(|n| match &n.family {
            Family::Mlp(scaler) => scaler.act(),
            Family::Cumulative { .. } => Act::new(0, 0, 0),
        })
    }

    #[inline]
    pub(super) fn eval(&self, x: WindowLanes<T>, mut rec: Option<&mut Act<T>>) -> WindowLanes<T> {
        match &self.neural {
            None => WindowLanes::splat(self.c0),
            Some(n) => {
                let x0 = x * WindowLanes::splat(n.inv_scale);
                let (p, m) = match &n.family {
                    Family::Mlp(scaler) => {
                        let z = scaler.raw(x0, rec.as_deref_mut());
                        self.bounded(n, z)
                    }
                    Family::Cumulative { fold, .. } => {
                        let m = fold.mixture(x0);
                        let p = Unfused::mul_add(
                            WindowLanes::splat(self.c0 * n.span),
                            m,
                            WindowLanes::splat(self.c0 * n.s_min),
                        );
                        (p, m)
                    }
                };
                if let Some(rec) = rec {
                    rec.x0 = x0;
                    rec.sig = m;
                }
                p
            }
        }
    }

    /// The output mapping of the neural coefficient `n` at raw output `z`: `(p, sigmoid)`.
    #[inline(always)]
    pub(super) fn bounded(
        &self,
        n: &NeuralCoef<'_, T>,
        z: WindowLanes<T>,
    ) -> (WindowLanes<T>, WindowLanes<T>) {
        mlp::bounded::<Unfused, WindowLanes<T>>(
            z,
            WindowLanes::splat(self.c0 * n.s_min),
            WindowLanes::splat(self.c0 * n.span),
        )
    }

    /// Back-propagates `cbar = dL/d(coefficient)`; returns `dL/d(state component)`.
    #[inline]
    pub(super) fn backward(
        &self,
        rec: Option<&Act<T>>,
        cbar: WindowLanes<T>,
        c0bar: &mut T,
        g: &mut [T],
    ) -> WindowLanes<T> {
        match (&self.neural, rec) {
            (Some(n), Some(rec)) => {
                *c0bar += WindowLanes::sum(
                    cbar * (WindowLanes::splat(n.s_min) + WindowLanes::splat(n.span) * rec.sig),
                );
                let xbar = match &n.family {
                    Family::Mlp(scaler) => {
                        let zbar = mlp::bounded_backward(
                            rec.sig,
                            WindowLanes::splat(self.c0 * n.span),
                            cbar,
                        );
                        scaler.backward(rec, zbar, g)
                    }
                    Family::Cumulative { view, fold } => fold.mixture_backward(
                        view,
                        rec.x0,
                        cbar * WindowLanes::splat(self.c0 * n.span),
                        g,
                    ),
                };
                xbar * WindowLanes::splat(n.inv_scale)
            }
            _ => {
                *c0bar += WindowLanes::sum(cbar);
                WindowLanes::default()
            }
        }
    }
}
