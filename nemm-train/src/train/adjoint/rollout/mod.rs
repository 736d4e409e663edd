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
//! - here: the entry points ([`loss_and_grad`], [`loss_and_grad_paired`], [`simulate`],
//!   [`simulate_x_pr`]).

use super::{Grid, Real, RolloutGrads, RolloutParams, Window, WindowLanes, LANES};
use data::{pack_data, PackData};
use forward::{at_samples, forward_sweep};
use pack::LaneState;
use rayon::prelude::{IndexedParallelIterator, ParallelIterator, ParallelSlice};
use reverse::{pack_loss_grad, SampleLoss};

mod coef;
mod data;
mod forward;
mod pack;
mod reverse;
mod scaler;

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
/// [`Grid`]). Returns `(loss, gradient)`; packs of `LANES` windows run in parallel.
pub fn loss_and_grad<T: Real>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
    warmup: usize,
    force_scale: f64,
) -> (f64, RolloutGrads<T>) {
    let (loss, g) = loss_and_grad_paired(p, windows, None, grid, warmup, force_scale);
    (loss.mse, g)
}

/// Matched windows of a batch for the difference term of the loss: windows of the same
/// excitation recorded at two condition levels, whose force difference the model's must
/// follow (the degradation signature, Fig. 5).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pairing<'a> {
    /// Per window of the batch, the index of its matched window in the same batch. Pairs are
    /// mutual (`partner[b] == Some(a)` where `partner[a] == Some(b)`: the term is split half
    /// onto each side, so a one-sided entry would get a gradient that is not its loss's) and
    /// lie in one pack of [`LANES`] windows (indices `LANES k .. LANES (k + 1)`); a partner
    /// outside its pack is ignored.
    pub(crate) partner: &'a [Option<usize>],
    /// Weight `lambda_diff` of the term, relative to eq. 23's.
    pub(crate) weight: f64,
}

/// The parts of the training loss of a batch, each normalised by the scored samples.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct LossParts {
    /// Eq. 23: the normalised MSE of the force.
    pub(crate) mse: f64,
    /// The matched-difference term: `lambda_diff` times the mean over matched samples of
    /// `((e_a - e_b) / F_s)^2` (`e` the force error of two matched windows), counted per
    /// window so that it is comparable with `mse`.
    pub(crate) diff: f64,
}

impl LossParts {
    /// The loss the gradient is of.
    pub(crate) fn total(&self) -> f64 {
        self.mse + self.diff
    }
}

/// [`loss_and_grad`] with the matched-difference term of `pairing`: per sample of two
/// matched windows `a`, `b` the loss adds `lambda_diff ((e_a - e_b) / F_s)^2 / M`, the
/// error of the model's difference `y_a - y_b` against the measured one. Returns the
/// parts of the loss and the gradient of their sum.
pub(crate) fn loss_and_grad_paired<T: Real>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    pairing: Option<Pairing<'_>>,
    grid: &Grid,
    warmup: usize,
    force_scale: f64,
) -> (LossParts, RolloutGrads<T>) {
    let n = common_len(windows);
    if n <= warmup || windows.is_empty() {
        return (LossParts::default(), RolloutGrads::zeros(p));
    }
    let m = (windows.len() * (n - warmup)) as f64;
    let inv_fs = T::c(1.0 / force_scale);
    let ybar_scale = T::c(2.0 / (force_scale * force_scale * m));
    let diff_w = T::c(pairing.map_or(0.0, |pr| pr.weight));
    let refs: Vec<&Window<'_>> = windows.iter().collect();
    let results: Vec<(T, T, RolloutGrads<T>)> = refs
        .par_chunks(LANES)
        .enumerate()
        .map(|(c, chunk)| {
            let d = pack_data::<T>(chunk, grid, n, true, p.static_force.as_ref());
            let partner = std::array::from_fn(|l| {
                pairing
                    .and_then(|pr| pr.partner.get(c * LANES + l).copied().flatten())
                    .and_then(|j| j.checked_sub(c * LANES))
                    .filter(|&k| k < chunk.len())
                    .unwrap_or(l)
            });
            let sl = SampleLoss {
                lane_w: d.lane_w,
                inv_fs,
                ybar_scale,
                partner,
                diff_w,
            };
            pack_loss_grad(p, &d, warmup, &sl)
        })
        .collect();
    let mut g = RolloutGrads::zeros(p);
    let mut loss = LossParts::default();
    for (l, dl, gi) in &results {
        loss.mse += l.to_f64().unwrap_or(f64::NAN);
        loss.diff += dl.to_f64().unwrap_or(f64::NAN);
        g.add(gi);
    }
    loss.mse /= m;
    loss.diff /= m;
    (loss, g)
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
pub(crate) fn simulate_x_pr<T: Real>(
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
