//! The reverse sweep of a pack: the loss at the data samples and its exact discrete adjoint
//! back through the output force, the RK steps, the scalers, `b_pr(alpha)` and `T_pr`.

use super::*;

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

/// Loss sum (unnormalised) and gradient of one pack. `ybar_scale` is `2 / (F_s^2 M)`;
/// samples before `warmup` are not scored.
pub(super) fn pack_loss_grad<T: Real>(
    p: &RolloutParams<T>,
    d: &PackData<T>,
    warmup: usize,
    inv_fs: T,
    ybar_scale: T,
) -> (T, RolloutGrads<T>) {
    let n = d.u.len();
    let mut pk = Pack::new(p, d.alpha(n.saturating_sub(1)));
    let (states, ys) = forward_sweep(p, d);
    // The loss at the data samples and its adjoint per model step: formed here on a
    // coarser data grid, inline in the reverse sweep when every step is a sample.
    let mut loss = T::zero();
    let sample_loss = |y: &WindowLanes<T>, f: &WindowLanes<T>, loss: &mut T| -> WindowLanes<T> {
        Lanes(std::array::from_fn(|l| {
            let e = (y.0[l] - f.0[l]) * d.lane_w.0[l];
            let en = e * inv_fs;
            *loss += en * en;
            ybar_scale * e
        }))
    };
    let on_grid: Option<(Vec<WindowLanes<T>>, Vec<bool>)> = (!d.identity).then(|| {
        let mut ybar = vec![WindowLanes::<T>::default(); n];
        let mut scored = vec![false; n];
        for (k, (y, f)) in at_samples(d, &ys).iter().zip(&d.f).enumerate().skip(warmup) {
            let (j, wgt) = d.at[k];
            let g = sample_loss(y, f, &mut loss);
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
    });
    let mut bar = PackAdjoint {
        g: RolloutGrads::zeros(p),
        b_pr: WindowLanes::splat(T::zero()),
    };
    let it = WindowLanes::splat(pk.inv_t_pr);
    // dL/d(1/T_pr) per lane.
    let mut it_bar = WindowLanes::<T>::splat(T::zero());
    // Reverse sweep. `sbar` is dL/ds_n (direct paths so far); `cbar_n` the coefficient
    // adjoint at s_n from stage 1 of step n+1; `rb_n`/`rk_n` the activations at s_n.
    let mut sbar = LaneState::<T>::default();
    let mut cbar_n = LaneCoefficients::<T>::default();
    let (mut rb_n, mut rk_n) = (pk.b_fl.act(), pk.k_pr.act());
    let mut have_rec_n = false;
    let (mut rb1, mut rk1) = (pk.b_fl.act(), pk.k_pr.act());
    let mut recs: [RecPair<T>; 3] = std::array::from_fn(|_| (pk.b_fl.act(), pk.k_pr.act()));
    for i in (0..n).rev() {
        let s_n = states[i + 1];
        let s_p = states[i];
        let u1 = d.u[i];
        let u0 = if i == 0 {
            WindowLanes::default()
        } else {
            d.u[i - 1]
        };
        // Coefficients at s_n with activations (carried from the previous iteration's stage 1).
        let c_n = if have_rec_n {
            pk.coeffs_from_rec(&rb_n, &rk_n)
        } else {
            pk.coeffs(&s_n, Some((&mut rb_n, &mut rk_n)))
        };
        // Output y_i = F(s_n, u_i).
        let ybar_i = match &on_grid {
            Some((ybar, scored)) => scored[i].then(|| ybar[i]),
            None => (i >= warmup).then(|| sample_loss(&ys[i], &d.f[i], &mut loss)),
        };
        if let (Some(yb), Some(phi)) = (&ybar_i, &d.phi) {
            for (q, gq) in bar.g.static_force.iter_mut().enumerate() {
                *gq += (0..LANES).fold(T::zero(), |a, l| a + yb.0[l] * phi[i][q].0[l]);
            }
        }
        if let Some(yb) = ybar_i {
            emm::force_backward::<Unfused, WindowLanes<T>>(
                &c_n,
                &s_n,
                u1,
                yb,
                &mut sbar,
                &mut cbar_n,
            );
        }
        // Scalers at s_n: complete dL/ds_n.
        pk.coef_backward(&rb_n, &rk_n, &cbar_n, &mut sbar, &mut bar);
        // Step i: s_p -> s_n, its stages recomputed with activations.
        let c1 = pk.coeffs(&s_p, Some((&mut rb1, &mut rk1)));
        let mut sbar_p = LaneState::<T>::default();
        let mut cbar1 = LaneCoefficients::<T>::default();
        integrator::step_backward::<Unfused, WindowLanes<T>, _>(
            pk.integrator,
            &mut PackStagesBack {
                pk: &pk,
                bar: &mut bar,
                recs: &mut recs,
            },
            &c1,
            it,
            &s_p,
            u0,
            u1,
            &pk.step_size,
            &sbar,
            &mut sbar_p,
            &mut cbar1,
            &mut it_bar,
        );
        // Move to s_p: its activations are rb1/rk1, its coefficient adjoint cbar1.
        sbar = sbar_p;
        cbar_n = cbar1;
        std::mem::swap(&mut rb_n, &mut rb1);
        std::mem::swap(&mut rk_n, &mut rk1);
        have_rec_n = true;
        if d.alpha_changes(i) {
            // Step i ran at its own level: its stage-1 coefficients at s_p go back through
            // that level's scalers, and so does b_pr's adjoint so far; step i - 1 (and the
            // output at s_p) ran at the previous level.
            pk.coef_backward(&rb_n, &rk_n, &cbar_n, &mut sbar, &mut bar);
            cbar_n = LaneCoefficients::<T>::default();
            bpr_backward(p, &pk, &mut bar);
            pk = Pack::new(p, d.alpha(i - 1));
            have_rec_n = false;
        }
    }
    // s_{-1} is the fixed rest state: its adjoint is dropped, but the coefficients there
    // depend on the weights.
    let mut sdummy = LaneState::default();
    pk.coef_backward(&rb_n, &rk_n, &cbar_n, &mut sdummy, &mut bar);
    // b_pr: constant over the window (or since its last change).
    bpr_backward(p, &pk, &mut bar);
    // T_pr from 1/T_pr.
    bar.g.t_pr = -WindowLanes::sum(it_bar) * pk.inv_t_pr * pk.inv_t_pr;
    (loss, bar.g)
}
