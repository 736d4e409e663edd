//! Everything fixed for one pack at one condition level: the coefficients, `b_pr(alpha)`,
//! `1 / T_pr` and the RK step, with the stage hooks of the forward and reverse step.

use super::coef::Coef;
use super::scaler::{Act, LaneScaler};
use crate::train::adjoint::{
    integrator, mlp, Coefficients, Lane, LostMotionAt, MulAdd, Real, RolloutGrads, RolloutParams,
    Stage, StageBackward, State, StepSize, Unfused, WindowLanes, LOST_MOTION_PARAMS,
};
use nemm_core::Integrator;

/// A state over the lanes (or its adjoint).
pub(super) type LaneState<T> = State<WindowLanes<T>>;
/// Coefficient values at one state over the lanes (or their adjoints).
pub(super) type LaneCoefficients<T> = Coefficients<WindowLanes<T>>;

/// Where to record the activations of the `b_fl` and `k_pr` evaluations and the inputs of
/// the lost-motion element.
pub(super) type ActPair<'r, T> = (
    &'r mut Option<Act<T>>,
    &'r mut Option<Act<T>>,
    &'r mut LostMotionRec<T>,
);

/// The inputs of the lost-motion element at one state: `x_pr` and the liquid stiffness
/// `k_l` (the `k_pr` coefficient before the element).
#[derive(Debug, Clone, Copy)]
pub(super) struct LostMotionRec<T> {
    pub(super) x_pr: WindowLanes<T>,
    pub(super) k_l: WindowLanes<T>,
}

impl<T: Real> Default for LostMotionRec<T> {
    fn default() -> Self {
        Self {
            x_pr: WindowLanes::default(),
            k_l: WindowLanes::default(),
        }
    }
}

/// The `b_pr(alpha)` scaler of a pack: its MLP, alpha branch, activations and output
/// bounds.
pub(super) struct BprRecord<'a, T> {
    pub(super) scaler: LaneScaler<'a, T>,
    pub(super) act: Act<T>,
    pub(super) s_min: T,
    pub(super) span: T,
}

/// Everything fixed for one pack (a batch of windows advanced in lock step).
pub(super) struct Pack<'a, T: Real> {
    /// The `b_fl(v_st, alpha)` coefficient at the pack's levels.
    pub(super) b_fl: Coef<'a, T>,
    /// The `k_pr(x_pr, alpha)` coefficient at the pack's levels.
    pub(super) k_pr: Coef<'a, T>,
    /// `b_pr(alpha)` per lane (constant over a window).
    pub(super) b_pr: WindowLanes<T>,
    /// The `b_pr(alpha)` scaler's evaluation, for its backward pass.
    pub(super) b_pr_record: Option<BprRecord<'a, T>>,
    /// `1 / T_pr`.
    pub(super) inv_t_pr: T,
    pub(super) integrator: Integrator,
    /// The model step `dt` and its fractions.
    pub(super) step_size: StepSize<WindowLanes<T>>,
    /// The lost-motion element at the pack's levels, if the model has one.
    pub(super) lost_motion: Option<LostMotionAt<WindowLanes<T>>>,
    /// The pack's levels `alpha` per lane.
    pub(super) alphas: WindowLanes<T>,
}

impl<'a, T: Real> Pack<'a, T> {
    pub(super) fn new(p: &'a RolloutParams<T>, alphas: WindowLanes<T>) -> Self {
        let alpha_n = alphas / WindowLanes::splat(p.alpha_scale);
        let (bp, b_pr_record) = match &p.b_pr {
            None => (WindowLanes::splat(p.b_pr0), None),
            Some(s) => {
                let scaler = LaneScaler::new(s, alpha_n);
                let mut act = scaler.act();
                let z = scaler.raw(scaler.x_alpha, Some(&mut act));
                let span = s.s_max - s.s_min;
                let (bp, sig) = mlp::bounded::<Unfused, WindowLanes<T>>(
                    z,
                    WindowLanes::splat(p.b_pr0 * s.s_min),
                    WindowLanes::splat(p.b_pr0 * span),
                );
                act.sig = sig;
                (
                    bp,
                    Some(BprRecord {
                        scaler,
                        act,
                        s_min: s.s_min,
                        span,
                    }),
                )
            }
        };
        Self {
            b_fl: Coef::new(p.b_fl0, p.b_fl.as_ref(), p.v_scale, alpha_n),
            k_pr: Coef::new(p.k0, p.k_pr.as_ref(), p.x_scale, alpha_n),
            b_pr: bp,
            b_pr_record,
            inv_t_pr: T::one() / p.t_pr,
            integrator: p.integrator,
            step_size: StepSize::splat(p.dt),
            // nemm-core's `LostMotion::at` (the clamp at 0 never acts: every parameter and
            // level is >= 0).
            lost_motion: p.lost_motion.map(|l| {
                let d = |d0: T, d1: T| WindowLanes::splat(d0) + WindowLanes::splat(d1) * alphas;
                LostMotionAt {
                    f0_n: WindowLanes::splat(l[0]),
                    travel_c_m: d(l[1], l[2]),
                    travel_r_m: d(l[3], l[4]),
                }
            }),
            alphas,
        }
    }

    #[inline]
    pub(super) fn coeffs(
        &self,
        s: &LaneState<T>,
        rec: Option<ActPair<'_, T>>,
    ) -> LaneCoefficients<T> {
        let (bf, k) = match rec {
            None => (
                self.b_fl.eval(s.v_st_m_s, None),
                self.k_pr.eval(s.x_pr_m, None),
            ),
            Some((rb, rk, rl)) => {
                let k = self.k_pr.eval(s.x_pr_m, rk.as_mut());
                *rl = LostMotionRec {
                    x_pr: s.x_pr_m,
                    k_l: k,
                };
                (self.b_fl.eval(s.v_st_m_s, rb.as_mut()), k)
            }
        };
        Coefficients {
            b_fl: bf,
            b_pr: self.b_pr,
            k_pr: self.k_eff(k, s.x_pr_m),
        }
    }

    /// `k_pr` through the lost-motion element (if any) at deflection `x_pr`.
    #[inline(always)]
    fn k_eff(&self, k_l: WindowLanes<T>, x_pr: WindowLanes<T>) -> WindowLanes<T> {
        match &self.lost_motion {
            None => k_l,
            Some(l) => l.k_eff(k_l, x_pr),
        }
    }

    /// One RK step from `s` (coefficients `c1`) with inputs `u0` -> `u1`: nemm-core's
    /// [`integrator::step_with`] over the lanes, unfused.
    pub(super) fn step(
        &self,
        s: &LaneState<T>,
        c1: &LaneCoefficients<T>,
        u0: WindowLanes<T>,
        u1: WindowLanes<T>,
    ) -> LaneState<T> {
        integrator::step_with::<Unfused, WindowLanes<T>, _>(
            self.integrator,
            &mut PackStage { pk: self },
            c1,
            WindowLanes::splat(self.inv_t_pr),
            s,
            u0,
            u1,
            &self.step_size,
        )
    }
}

/// The stage coefficients of a pack's forward step (no record).
struct PackStage<'p, 'a, T: Real> {
    pub(super) pk: &'p Pack<'a, T>,
}

impl<T: Real> Stage<WindowLanes<T>> for PackStage<'_, '_, T> {
    #[inline(always)]
    fn coeffs(&mut self, s: &LaneState<T>) -> LaneCoefficients<T> {
        self.pk.coeffs(s, None)
    }
}

/// Adjoint accumulators of one pack.
pub(super) struct PackAdjoint<T> {
    pub(super) g: RolloutGrads<T>,
    /// dL/d b_pr per lane (b_pr is constant over a window).
    pub(super) b_pr: WindowLanes<T>,
    /// dL/d(the lost-motion element at the pack's levels) per lane.
    pub(super) lost_motion: LostMotionAt<WindowLanes<T>>,
}

/// Activation records of the `b_fl` and `k_pr` scalers and the lost-motion element's inputs
/// at one state.
pub(super) type RecPair<T> = (Option<Act<T>>, Option<Act<T>>, LostMotionRec<T>);

/// The stage coefficients of a pack's step for [`integrator::step_backward`]: stages 2..=4
/// record their scalers' activations and back-propagate through them.
pub(super) struct PackStagesBack<'p, 'a, T: Real> {
    pub(super) pk: &'p Pack<'a, T>,
    pub(super) bar: &'p mut PackAdjoint<T>,
    pub(super) recs: &'p mut [RecPair<T>; 3],
}

impl<T: Real> StageBackward<WindowLanes<T>> for PackStagesBack<'_, '_, T> {
    #[inline(always)]
    fn coeffs(&mut self, i: usize, s: &LaneState<T>) -> LaneCoefficients<T> {
        let (rb, rk, rl) = &mut self.recs[i - 2];
        self.pk.coeffs(s, Some((rb, rk, rl)))
    }

    #[inline(always)]
    fn backward(&mut self, i: usize, cbar: &LaneCoefficients<T>, sbar: &mut LaneState<T>) {
        self.pk
            .coef_backward(&self.recs[i - 2], cbar, sbar, self.bar);
    }
}

impl<T: Real> Pack<'_, T> {
    /// Back-propagates coefficient adjoints through the scalers at the recorded state (and
    /// `b_pr`'s into its per-lane accumulator).
    #[inline]
    pub(super) fn coef_backward(
        &self,
        (rb, rk, rl): &RecPair<T>,
        cbar: &LaneCoefficients<T>,
        sbar: &mut LaneState<T>,
        bar: &mut PackAdjoint<T>,
    ) {
        let xv = self
            .b_fl
            .backward(rb.as_ref(), cbar.b_fl, &mut bar.g.b_fl0, &mut bar.g.b_fl);
        // Through the lost-motion element first: dL/dk_l and its direct dL/dx_pr.
        let (kbar, x_direct) = match &self.lost_motion {
            None => (cbar.k_pr, WindowLanes::default()),
            Some(l) => l.k_eff_backward(rl.k_l, rl.x_pr, cbar.k_pr, &mut bar.lost_motion),
        };
        let xx = self
            .k_pr
            .backward(rk.as_ref(), kbar, &mut bar.g.k0, &mut bar.g.k_pr);
        sbar.v_st_m_s = sbar.v_st_m_s + xv;
        sbar.x_pr_m = sbar.x_pr_m + xx + x_direct;
        bar.b_pr = bar.b_pr + cbar.b_pr;
    }

    /// Moves the per-lane adjoint of the lost-motion element at this pack's levels into
    /// the gradient of its parameters (`d = d0 + d1 alpha`) and clears it.
    pub(super) fn lost_motion_backward(&self, bar: &mut PackAdjoint<T>) {
        if self.lost_motion.is_none() {
            return;
        }
        let l = bar.lost_motion;
        let g = &mut bar.g.lost_motion;
        if g.len() == LOST_MOTION_PARAMS {
            g[0] += WindowLanes::sum(l.f0_n);
            g[1] += WindowLanes::sum(l.travel_c_m);
            g[2] += WindowLanes::sum(l.travel_c_m * self.alphas);
            g[3] += WindowLanes::sum(l.travel_r_m);
            g[4] += WindowLanes::sum(l.travel_r_m * self.alphas);
        }
        bar.lost_motion = LostMotionAt::default();
    }
}

impl<T: Real> Pack<'_, T> {
    /// Coefficient values from recorded activations (no recomputation).
    pub(super) fn coeffs_from_rec(&self, (rb, rk, rl): &RecPair<T>) -> LaneCoefficients<T> {
        let val = |c: &Coef<'_, T>, r: &Option<Act<T>>| -> WindowLanes<T> {
            match (&c.neural, r) {
                (Some(n), Some(r)) => Unfused::mul_add(
                    WindowLanes::splat(c.c0 * n.span),
                    r.sig,
                    WindowLanes::splat(c.c0 * n.s_min),
                ),
                _ => WindowLanes::splat(c.c0),
            }
        };
        Coefficients {
            b_fl: val(&self.b_fl, rb),
            b_pr: self.b_pr,
            k_pr: self.k_eff(val(&self.k_pr, rk), rl.x_pr),
        }
    }
}
