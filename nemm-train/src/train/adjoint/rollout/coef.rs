//! The state-dependent coefficients `b_fl(v_st, alpha)` and `k_pr(x_pr, alpha)` over the
//! lanes: a constant or a bounded scaler, forward and reverse.

use super::scaler::{Act, LaneScaler};
use crate::train::adjoint::{mlp, Lane, Real, ScalerWeights, Unfused, WindowLanes};

/// A coefficient: constant `c0`, or `c0 (s_min + (s_max - s_min) sigmoid(z(state / scale,
/// alpha_n)))` (nemm-core's [`mlp::bounded`] with `lo = c0 s_min`, `span = c0 (s_max -
/// s_min)`).
pub(super) struct Coef<'a, T> {
    pub(super) c0: T,
    pub(super) neural: Option<NeuralCoef<'a, T>>,
}

pub(super) struct NeuralCoef<'a, T> {
    pub(super) scaler: LaneScaler<'a, T>,
    pub(super) s_min: T,
    pub(super) span: T,
    inv_scale: T,
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
                scaler: LaneScaler::new(s, alpha_n),
                s_min: s.s_min,
                span: s.s_max - s.s_min,
                inv_scale: T::one() / scale,
            }),
        }
    }

    pub(super) fn act(&self) -> Option<Act<T>> {
        self.neural.as_ref().map(|n| n.scaler.act())
    }

    #[inline]
    pub(super) fn eval(&self, x: WindowLanes<T>, mut rec: Option<&mut Act<T>>) -> WindowLanes<T> {
        match &self.neural {
            None => WindowLanes::splat(self.c0),
            Some(n) => {
                let x0 = x * WindowLanes::splat(n.inv_scale);
                let z = n.scaler.raw(x0, rec.as_deref_mut());
                let (p, sig) = self.bounded(n, z);
                if let Some(rec) = rec {
                    rec.sig = sig;
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
                let zbar =
                    mlp::bounded_backward(rec.sig, WindowLanes::splat(self.c0 * n.span), cbar);
                n.scaler.backward(rec, zbar, g) * WindowLanes::splat(n.inv_scale)
            }
            _ => {
                *c0bar += WindowLanes::sum(cbar);
                WindowLanes::default()
            }
        }
    }
}
