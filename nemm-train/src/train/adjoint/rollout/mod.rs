//! The rollout over packs of [`LANES`] windows and its exact discrete adjoint, one job per
//! file:
//!
//! - `scaler`: one scaler over the lanes (nemm-core's `ScalerView`) and its activation record;
//! - `coef`: the coefficients `b_fl(v_st, alpha)` and `k_pr(x_pr, alpha)`, forward and reverse;
//! - `pack`: what is fixed for a pack at one condition level (`b_pr(alpha)`, `1 / T_pr`, the
//!   RK step and its stage hooks);
//! - `data`: a pack's inputs on the model grid;
//! - `forward`: the forward sweep (states `x_pr`, `v_st` and forces per model step);
//! - `reverse`: the loss at the data samples and the reverse sweep;
//! - here: the entry points ([`loss_and_grad`], [`simulate`], [`simulate_x_pr`]).

use super::*;

mod coef;
mod data;
mod forward;
mod pack;
mod reverse;
mod scaler;

use coef::*;
use data::*;
use forward::*;
use pack::*;
use reverse::*;
use scaler::*;

/// Checks that all windows have the same length and returns it.
fn common_len(windows: &[Window<'_>]) -> usize {
    let n = windows.first().map_or(0, |w| w.u.len());
    assert!(
        windows.iter().all(|w| w.u.len() == n
            && w.f.len() == n
            && w.alphas.is_none_or(|a| a.len() == n)
            && w.x.is_none_or(|x| x.len() == n)),
        "all windows of a batch must have the same length"
    );
    n
}

/// Normalised MSE loss (eq. 23) over `windows` and its exact gradient. The model integrates
/// on `grid`'s model steps and is scored at the data samples from sample `warmup` on (see
/// [`Grid`]). Returns `(loss, gradient)`; packs of [`LANES`] windows run in parallel.
pub fn loss_and_grad<T: Real>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
    warmup: usize,
    force_scale: f64,
) -> (f64, RolloutGrads<T>) {
    let n = common_len(windows);
    if n <= warmup || windows.is_empty() {
        return (0.0, RolloutGrads::zeros(p));
    }
    let m = (windows.len() * (n - warmup)) as f64;
    let inv_fs = T::c(1.0 / force_scale);
    let ybar_scale = T::c(2.0 / (force_scale * force_scale * m));
    let refs: Vec<&Window<'_>> = windows.iter().collect();
    let results: Vec<(T, RolloutGrads<T>)> = refs
        .par_chunks(LANES)
        .map(|chunk| {
            let d = pack_data::<T>(chunk, grid, n, true, p.static_force.as_ref());
            pack_loss_grad(p, &d, warmup, inv_fs, ybar_scale)
        })
        .collect();
    let mut g = RolloutGrads::zeros(p);
    let mut loss = 0.0f64;
    for (l, gi) in &results {
        loss += l.to_f64().unwrap_or(f64::NAN);
        g.add(gi);
    }
    (loss / m, g)
}

/// Runs every window from rest on `grid` and returns, per window, `out` of the forward
/// sweep's forces and states at the window's data samples.
fn sweep_windows<T: Real, R: Send>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
    out: impl Fn(&PackData<T>, &[LaneState<T>], &[WindowLanes<T>], usize, usize) -> R + Sync,
) -> Vec<R> {
    let refs: Vec<&Window<'_>> = windows.iter().collect();
    refs.par_chunks(LANES)
        .flat_map_iter(|chunk| {
            let samples = chunk.iter().map(|w| w.u.len()).max().unwrap_or(0);
            let d = pack_data::<T>(chunk, grid, samples, false, p.static_force.as_ref());
            let (states, ys) = forward_sweep(p, &d);
            chunk
                .iter()
                .enumerate()
                .map(|(k, w)| out(&d, &states, &ys, k, w.u.len()))
                .collect::<Vec<_>>()
        })
        .collect()
}

/// Simulated forces of every window at its data samples (same semantics as the estimator
/// at the model step; see [`Grid`] for the samples), one vector per window.
pub fn simulate<T: Real>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
) -> Vec<Vec<f64>> {
    sweep_windows(p, windows, grid, |d, _, ys, k, len| {
        at_samples(d, ys)
            .iter()
            .take(len)
            .map(|y| y.0[k].to_f64().unwrap_or(f64::NAN))
            .collect()
    })
}

/// Simulated states `x_pr` of every window at its data samples (for the `x_pr`
/// normalisation scale).
pub fn simulate_x_pr<T: Real>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
) -> Vec<Vec<f64>> {
    sweep_windows(p, windows, grid, |d, states, _, k, len| {
        let x: Vec<WindowLanes<T>> = states.iter().skip(1).map(|s| s.x_pr_m).collect();
        at_samples(d, &x)
            .iter()
            .take(len)
            .map(|y| y.0[k].to_f64().unwrap_or(f64::NAN))
            .collect()
    })
}
