//! The reverse sweep of a pack: the loss at the data samples and its exact discrete adjoint
//! back through the output force, the RK steps, the scalers, `b_pr(alpha)` and `T_pr`.

use super::data::PackData;
use super::forward::{at_samples, forward_sweep};
use super::pack::{
    BprRecord, LaneCoefficients, LaneState, LostMotionRec, Pack, PackAdjoint, PackStagesBack,
    RecPair,
};
use crate::train::adjoint::{
    emm, integrator, mlp, Lane, Lanes, LostMotionAt, Real, RolloutGrads, RolloutParams, Unfused,
    WindowLanes, LANES, STATIC_PARAMS,
};

/// Back-propagates the accumulated `dL/d b_pr` of the current condition level through the
/// `b_pr(alpha)` scaler (or into `b_pr,ini`) and clears it.
fn bpr_backward<T: Real>(p: &RolloutParams<T>, pk: &Pack<'_, T>, bar: &mut PackAdjoint<T>) {
    let bp_bar = bar.b_pr.0;
    match &pk.b_pr_record {
        None => bar.g.b_pr0 += WindowLanes::sum(bar.b_pr),
        Some(BprRecord {
            scaler,
            act,
            s_min,
            span,
        }) => {
            for k in 0..LANES {
                bar.g.b_pr0 += bp_bar[k] * (*s_min + *span * act.sig.0[k]);
            }
            let zbar =
                mlp::bounded_backward(act.sig, WindowLanes::splat(p.b_pr0 * *span), bar.b_pr);
            // No state input: the input's adjoint is not used.
            let _ = scaler.backward(act, zbar, &mut bar.g.b_pr);
        }
    }
    bar.b_pr = WindowLanes::splat(T::zero());
}

/// The loss term of one data sample (eq. 23): the per-lane weighted error of the force,
/// normalised by the force scale and squared; with matched lanes ([`Pairing`]) also the
/// squared difference of a lane's error and its partner's, weighted by `diff_w`.
pub(super) struct SampleLoss<T> {
    /// Weight of each lane's squared error (0 for padding).
    pub(super) lane_w: WindowLanes<T>,
    /// `1 / F_s`.
    pub(super) inv_fs: T,
    /// `2 / (F_s^2 M)`.
    pub(super) ybar_scale: T,
    /// Each lane's matched lane in the pack (itself when it has none: its difference term
    /// is then zero).
    pub(super) partner: [usize; LANES],
    /// Weight `lambda_diff` of the matched-difference term (0: eq. 23 alone).
    pub(super) diff_w: T,
}

impl<T: Real> SampleLoss<T> {
    /// Adds the term of model force `y` against measured force `f` to `loss` (the
    /// difference term to `diff`) and returns its adjoint `dL/dy`. The difference term of a
    /// pair `(a, b)`, `diff_w ((e_a - e_b) / F_s)^2`, is split half onto each lane, so that
    /// `dL/dy_a = ybar_scale (e_a + diff_w (e_a - e_b))`.
    #[inline(always)]
    fn add(
        &self,
        y: &WindowLanes<T>,
        f: &WindowLanes<T>,
        loss: &mut T,
        diff: &mut T,
    ) -> WindowLanes<T> {
        let e: [T; LANES] = std::array::from_fn(|l| (y.0[l] - f.0[l]) * self.lane_w.0[l]);
        if self.diff_w == T::zero() {
            return Lanes(std::array::from_fn(|l| {
                let en = e[l] * self.inv_fs;
                *loss += en * en;
                self.ybar_scale * e[l]
            }));
        }
        let half = T::c(0.5) * self.diff_w;
        Lanes(std::array::from_fn(|l| {
            let en = e[l] * self.inv_fs;
            *loss += en * en;
            let de = e[l] - e[self.partner[l]];
            let dn = de * self.inv_fs;
            *diff += half * dn * dn;
            self.ybar_scale * (e[l] + self.diff_w * de)
        }))
    }
}

/// The output adjoints per model step when the data samples lie between model steps
/// ([`Grid`]): each scored sample's `dL/dy` split onto the model steps it interpolates, and
/// whether a step receives any. Adds the samples' loss to `loss`.
fn output_adjoints_on_grid<T: Real>(
    d: &PackData<T>,
    ys: &[WindowLanes<T>],
    warmup: usize,
    sl: &SampleLoss<T>,
    loss: &mut T,
    diff: &mut T,
) -> (Vec<WindowLanes<T>>, Vec<bool>) {
    let n = d.u.len();
    let mut ybar = vec![WindowLanes::<T>::default(); n];
    let mut scored = vec![false; n];
    for (k, (y, f)) in at_samples(d, ys).iter().zip(&d.f).enumerate().skip(warmup) {
        let (j, wgt) = d.at[k];
        let g = sl.add(y, f, loss, diff);
        if wgt == T::zero() {
            ybar[j] = ybar[j] + g;
            scored[j] = true;
        } else {
            ybar[j] = ybar[j] + WindowLanes::splat(T::one() - wgt) * g;
            ybar[j + 1] = ybar[j + 1] + WindowLanes::splat(wgt) * g;
            scored[j] = true;
            scored[j + 1] = true;
        }
    }
    (ybar, scored)
}

/// Adds the static force's weight gradients at model step `i` (features `phi_i`, output
/// adjoint `ybar`) to `g`.
#[inline(always)]
fn static_force_backward<T: Real>(
    ybar: &WindowLanes<T>,
    phi_i: &[WindowLanes<T>; STATIC_PARAMS],
    g: &mut [T],
) {
    for (q, gq) in g.iter_mut().enumerate() {
        *gq += (0..LANES).fold(T::zero(), |a, l| a + ybar.0[l] * phi_i[q].0[l]);
    }
}

/// What the reverse sweep carries from model step `n` back to step `n - 1`: the adjoints at
/// the state `s_n` and the scalers' activation records.
struct ReverseSweep<T> {
    /// The pack's gradient and `dL/d b_pr` per lane.
    bar: PackAdjoint<T>,
    /// `dL/d(1/T_pr)` per lane.
    it_bar: WindowLanes<T>,
    /// `dL/ds_n` (the direct paths so far).
    sbar: LaneState<T>,
    /// The coefficient adjoint at `s_n` from stage 1 of step `n + 1`.
    cbar_n: LaneCoefficients<T>,
    /// The `b_fl` / `k_pr` activations at `s_n`.
    rec_n: RecPair<T>,
    /// `rec_n` holds the activations at `s_n` (carried from the later step's stage 1).
    have_rec_n: bool,
    /// The activations at a step's start state (its stage 1).
    rec1: RecPair<T>,
    /// The activations of stages 2..=4.
    recs: [RecPair<T>; 3],
}

impl<T: Real> ReverseSweep<T> {
    /// At the last model step, all adjoints zero; records sized for `pk`'s scalers.
    fn new(p: &RolloutParams<T>, pk: &Pack<'_, T>) -> Self {
        Self {
            bar: PackAdjoint {
                g: RolloutGrads::zeros(p),
                b_pr: WindowLanes::splat(T::zero()),
                lost_motion: LostMotionAt::default(),
            },
            it_bar: WindowLanes::<T>::splat(T::zero()),
            sbar: LaneState::<T>::default(),
            cbar_n: LaneCoefficients::<T>::default(),
            rec_n: (pk.b_fl.act(), pk.k_pr.act(), LostMotionRec::default()),
            have_rec_n: false,
            rec1: (pk.b_fl.act(), pk.k_pr.act(), LostMotionRec::default()),
            recs: std::array::from_fn(|_| (pk.b_fl.act(), pk.k_pr.act(), LostMotionRec::default())),
        }
    }

    /// Back-propagates the output `y_i = F(s_n, u_i)` of model step `i` from its adjoint
    /// `ybar_i` (`None`: not scored) and the coefficients at `s_n` through the scalers:
    /// completes `dL/ds_n`.
    #[inline(always)]
    fn output_backward(
        &mut self,
        pk: &Pack<'_, T>,
        d: &PackData<T>,
        i: usize,
        s_n: &LaneState<T>,
        u1: WindowLanes<T>,
        ybar_i: Option<WindowLanes<T>>,
    ) {
        // Coefficients at s_n with activations (carried from the previous iteration's stage 1).
        let c_n = if self.have_rec_n {
            pk.coeffs_from_rec(&self.rec_n)
        } else {
            let (rb_n, rk_n, rl_n) = &mut self.rec_n;
            pk.coeffs(s_n, Some((rb_n, rk_n, rl_n)))
        };
        if let (Some(yb), Some(phi)) = (&ybar_i, &d.phi) {
            static_force_backward(yb, &phi[i], &mut self.bar.g.static_force);
        }
        if let Some(yb) = ybar_i {
            emm::force_backward::<Unfused, WindowLanes<T>>(
                &c_n,
                s_n,
                u1,
                yb,
                &mut self.sbar,
                &mut self.cbar_n,
            );
        }
        pk.coef_backward(&self.rec_n, &self.cbar_n, &mut self.sbar, &mut self.bar);
    }

    /// Back-propagates the RK step from `s_p` (inputs `u0` -> `u1`) to `s_n`, its stages
    /// recomputed with activations, and moves the carry to `s_p`.
    #[inline(always)]
    fn step_backward(
        &mut self,
        pk: &Pack<'_, T>,
        s_p: &LaneState<T>,
        u0: WindowLanes<T>,
        u1: WindowLanes<T>,
    ) {
        let (rb1, rk1, rl1) = &mut self.rec1;
        let c1 = pk.coeffs(s_p, Some((rb1, rk1, rl1)));
        let mut sbar_p = LaneState::<T>::default();
        let mut cbar1 = LaneCoefficients::<T>::default();
        integrator::step_backward::<Unfused, WindowLanes<T>, _>(
            pk.integrator,
            &mut PackStagesBack {
                pk,
                bar: &mut self.bar,
                recs: &mut self.recs,
            },
            &c1,
            WindowLanes::splat(pk.inv_t_pr),
            s_p,
            u0,
            u1,
            &pk.step_size,
            &self.sbar,
            &mut sbar_p,
            &mut cbar1,
            &mut self.it_bar,
        );
        // Move to s_p: its activations are rec1, its coefficient adjoint cbar1.
        self.sbar = sbar_p;
        self.cbar_n = cbar1;
        std::mem::swap(&mut self.rec_n, &mut self.rec1);
        self.have_rec_n = true;
    }

    /// The step just back-propagated ran at `pk`'s condition level and the one before it
    /// at another: its stage-1 coefficients at `s_p` go back through `pk`'s scalers, and so
    /// does `b_pr`'s adjoint so far. The caller continues with the earlier level's pack.
    fn leave_level(&mut self, p: &RolloutParams<T>, pk: &Pack<'_, T>) {
        pk.coef_backward(&self.rec_n, &self.cbar_n, &mut self.sbar, &mut self.bar);
        self.cbar_n = LaneCoefficients::<T>::default();
        bpr_backward(p, pk, &mut self.bar);
        pk.lost_motion_backward(&mut self.bar);
        self.have_rec_n = false;
    }

    /// The gradient, after the first model step: the coefficients at the rest state, `b_pr`
    /// and `T_pr`.
    fn finish(mut self, p: &RolloutParams<T>, pk: &Pack<'_, T>) -> RolloutGrads<T> {
        // s_{-1} is the fixed rest state: its adjoint is dropped, but the coefficients there
        // depend on the weights.
        let mut sdummy = LaneState::default();
        pk.coef_backward(&self.rec_n, &self.cbar_n, &mut sdummy, &mut self.bar);
        // b_pr and the lost-motion element: constant over the window (or since the level's
        // last change).
        bpr_backward(p, pk, &mut self.bar);
        pk.lost_motion_backward(&mut self.bar);
        // T_pr from 1/T_pr.
        self.bar.g.t_pr = -WindowLanes::sum(self.it_bar) * pk.inv_t_pr * pk.inv_t_pr;
        self.bar.g
    }
}

/// Loss sums (unnormalised: eq. 23's and the matched-difference term's) and gradient of one
/// pack. `sl` holds the lanes' weights, partners and scales (`ybar_scale` is
/// `2 / (F_s^2 M)`); samples before `warmup` are not scored.
pub(super) fn pack_loss_grad<T: Real>(
    p: &RolloutParams<T>,
    d: &PackData<T>,
    warmup: usize,
    sl: &SampleLoss<T>,
) -> (T, T, RolloutGrads<T>) {
    let n = d.u.len();
    let mut pk = Pack::new(p, d.alpha(n.saturating_sub(1)));
    let (states, ys) = forward_sweep(p, d);
    // The loss at the data samples and its adjoint per model step: formed here on a
    // coarser data grid, inline in the reverse sweep when every step is a sample.
    let (mut loss, mut diff) = (T::zero(), T::zero());
    let on_grid =
        (!d.identity).then(|| output_adjoints_on_grid(d, &ys, warmup, sl, &mut loss, &mut diff));
    let mut rev = ReverseSweep::new(p, &pk);
    for i in (0..n).rev() {
        let u1 = d.u[i];
        let u0 = if i == 0 {
            WindowLanes::default()
        } else {
            d.u[i - 1]
        };
        let ybar_i = match &on_grid {
            Some((ybar, scored)) => scored[i].then(|| ybar[i]),
            None => (i >= warmup).then(|| sl.add(&ys[i], &d.f[i], &mut loss, &mut diff)),
        };
        rev.output_backward(&pk, d, i, &states[i + 1], u1, ybar_i);
        rev.step_backward(&pk, &states[i], u0, u1);
        if d.alpha_changes(i) {
            // Step i - 1 (and the output at s_p) ran at the previous level.
            rev.leave_level(p, &pk);
            pk = Pack::new(p, d.alpha(i - 1));
        }
    }
    (loss, diff, rev.finish(p, &pk))
}
