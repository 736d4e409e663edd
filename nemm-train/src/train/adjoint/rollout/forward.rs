//! The forward sweep of a pack over the model grid and its forces at the data samples.

use super::data::PackData;
use super::pack::{LaneState, Pack};
use crate::train::adjoint::{emm, Lanes, Real, RolloutParams, Unfused, WindowLanes};

/// Forward sweep over the model grid: states after every step (index 0 = rest, before step
/// 0) and forces per step. A step whose condition level changed re-folds it (a new [`Pack`])
/// and re-evaluates the coefficients at the step's start state with it, as
/// `nemm_core::Estimator::set_alpha` does.
pub(super) fn forward_sweep<T: Real>(
    p: &RolloutParams<T>,
    d: &PackData<T>,
) -> (Vec<LaneState<T>>, Vec<WindowLanes<T>>) {
    let n = d.u.len();
    let mut pk = Pack::new(p, d.alpha(0));
    let mut states = Vec::with_capacity(n + 1);
    let mut ys = Vec::with_capacity(n);
    let mut s = LaneState::default();
    let mut c = pk.coeffs(&s, None);
    let mut u_prev = WindowLanes::default();
    states.push(s);
    for (j, u) in d.u.iter().enumerate() {
        if d.alpha_changes(j) {
            pk = Pack::new(p, d.alpha(j));
            c = pk.coeffs(&s, None);
        }
        s = pk.step(&s, &c, u_prev, *u);
        c = pk.coeffs(&s, None);
        let r = d.static_at(p, j);
        let y = emm::force_with::<Unfused, WindowLanes<T>>(&c, &s, *u);
        ys.push(y + r);
        states.push(s);
        u_prev = *u;
    }
    (states, ys)
}

/// The forces of a forward sweep at the data samples (output interpolation of [`Grid`]).
pub(super) fn at_samples<T: Real>(d: &PackData<T>, ys: &[WindowLanes<T>]) -> Vec<WindowLanes<T>> {
    if d.identity {
        return ys.to_vec();
    }
    d.at.iter()
        .map(|&(j, w)| {
            if w == T::zero() {
                ys[j]
            } else {
                let (a, b) = (ys[j], ys[j + 1]);
                Lanes(std::array::from_fn(|k| a.0[k] + w * (b.0[k] - a.0[k])))
            }
        })
        .collect()
}
