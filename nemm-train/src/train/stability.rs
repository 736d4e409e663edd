//! Stability at the model's step, held during training.
//!
//! nemm-core accepts a model only if its fastest reachable time constant is at least
//! [`nemm_core::shortest_stable_time_constant_s`] for its integrator and step
//! (`Model::check_step`). That time constant is reached at the scalers' bounds:
//!
//! ```text
//! tau_min = min( (b_pr,ini s_min,pr + b_fl,ini s_min,fl) / (k_pr,ini s_max,k),  T_pr )
//! ```
//!
//! (`s = 1` for a coefficient without a scaler). The bounds are fixed for a stage; the
//! constants are trained. After every optimizer step, and before the first, the trainer
//! moves the constants back onto the stable set ([`StabilityHold::hold`]):
//!
//! ```text
//! T_pr      <- max(T_pr, tau_hold)
//! k_pr,ini  <- min(k_pr,ini, (b_pr,ini s_min,pr + b_fl,ini s_min,fl) / (s_max,k tau_hold))
//! ```
//!
//! with `tau_hold = HOLD_FACTOR * shortest_stable_time_constant_s(integrator, dt)`: a
//! projection of each Adam step onto the set of models the runtime accepts, so every model
//! training holds, and therefore every model it exports, passes `Model::check_step`. Where
//! the data pull the model's dynamics faster than its step allows, the hold is active: the
//! epoch line counts the steps it moved the constants ([`super::history::EpochStats::held`]),
//! and the pipeline says so after the Linear EMM, before the neural variants train, with
//! the model rate that would leave the time constant free.

use super::adjoint::RolloutParams;
use super::net::{EmmNet, NetFrame};

/// Factor over nemm-core's shortest stable time constant at which the constants are held,
/// so that `f32` rounding of the stored constants cannot cross the runtime's bound.
pub(crate) const HOLD_FACTOR: f32 = 1.01;

/// The stable set of a stage's constants (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StabilityHold {
    /// `tau_hold` \[s\].
    pub(crate) tau_s: f32,
    /// `s_min` of the `b_fl` scaler (1 without one).
    pub(crate) s_min_fl: f32,
    /// `s_min` of the `b_pr` scaler (1 without one).
    pub(crate) s_min_pr: f32,
    /// `s_max` of the `k_pr` scaler (1 without one).
    pub(crate) s_max_k: f32,
}

impl StabilityHold {
    /// The stable set of a stage with frame `frame` (its integrator, step and scaler bounds).
    pub(crate) fn new(frame: &NetFrame) -> Self {
        Self {
            tau_s: HOLD_FACTOR
                * nemm_core::shortest_stable_time_constant_s(frame.integrator, frame.dt),
            s_min_fl: frame.b_fl.as_ref().map_or(1.0, |s| s.s_min),
            s_min_pr: frame.b_pr.as_ref().map_or(1.0, |s| s.s_min),
            s_max_k: frame.k_pr.as_ref().map_or(1.0, |s| s.s_max),
        }
    }

    /// The stable set of rollout parameters `p` (the same as [`StabilityHold::new`] of
    /// their frame).
    pub(crate) fn of_rollout(p: &RolloutParams<f32>) -> Self {
        Self {
            tau_s: HOLD_FACTOR * nemm_core::shortest_stable_time_constant_s(p.integrator, p.dt),
            s_min_fl: p.b_fl.as_ref().map_or(1.0, |s| s.s_min),
            s_min_pr: p.b_pr.as_ref().map_or(1.0, |s| s.s_min),
            s_max_k: p.k_pr.as_ref().map_or(1.0, |s| s.s_max),
        }
    }

    /// What holding `p`'s constants at the start of stage `label` does, in words, or `None`
    /// when they are on the stable set: the fastest time constant they would reach, the
    /// step's bound, `k_pr,ini` and `T_pr` before and after, and the model rate that would
    /// leave them free.
    pub(crate) fn announce(&self, label: &str, p: &RolloutParams<f32>) -> Option<String> {
        let c = [p.b_fl0, p.b_pr0, p.k0, p.t_pr];
        let held = self.hold(c)?;
        let tau = self.fastest_time_constant_s(c);
        let rate_hz = 1.0 / f64::from(p.dt);
        let free_hz = rate_hz * f64::from(self.tau_s) / f64::from(tau);
        Some(format!(
            "[{label}] stability: at the bounds of its scalers the model would reach a time \
             constant of {:.1} us, and its step of {:.1} us ({}) needs at least {:.1} us; \
             training holds it there (k_pr,ini {:.4e} -> {:.4e} N/m, T_pr {:.1} -> {:.1} us). \
             A model rate of at least {:.0} Hz (--model-rate-hz; now {rate_hz:.0} Hz) would \
             leave it free.",
            tau * 1e6,
            p.dt * 1e6,
            p.integrator.name(),
            self.tau_s * 1e6,
            c[2],
            held[2],
            c[3] * 1e6,
            held[3] * 1e6,
            free_hz.ceil(),
        ))
    }

    /// The largest `k_pr,ini` \[N/m\] the set allows with `b_fl,ini = b_fl0` and
    /// `b_pr,ini = b_pr0` \[N s/m\].
    pub(crate) fn k_pr_cap(&self, b_fl0: f32, b_pr0: f32) -> f32 {
        (b_pr0 * self.s_min_pr + b_fl0 * self.s_min_fl) / (self.s_max_k * self.tau_s)
    }

    /// `net` with its constants moved onto the stable set, and whether they moved (the
    /// parameter keeps its id, so the optimizer's moments stay attached to it).
    pub(crate) fn hold_net(&self, net: EmmNet) -> (EmmNet, bool) {
        match self.hold(net.constants()) {
            Some(c) => (net.with_constants(c), true),
            None => (net, false),
        }
    }

    /// The constants `[b_fl,ini, b_pr,ini, k_pr,ini, T_pr]` moved onto the stable set, or
    /// `None` when they are on it (or not finite: the training loop stops on a non-finite
    /// loss before such constants are used).
    pub(crate) fn hold(&self, c: [f32; 4]) -> Option<[f32; 4]> {
        let [b_fl0, b_pr0, k0, t_pr] = c;
        if !c.iter().all(|v| v.is_finite()) {
            return None;
        }
        let t = t_pr.max(self.tau_s);
        let k = k0.min(self.k_pr_cap(b_fl0, b_pr0));
        (t != t_pr || k != k0).then_some([b_fl0, b_pr0, k, t])
    }

    /// The fastest time constant \[s\] a model with constants `c` reaches at the bounds.
    pub(crate) fn fastest_time_constant_s(&self, c: [f32; 4]) -> f32 {
        let [b_fl0, b_pr0, k0, t_pr] = c;
        let tau_pr = (b_pr0 * self.s_min_pr + b_fl0 * self.s_min_fl) / (k0 * self.s_max_k);
        tau_pr.min(t_pr)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nemm_core::shortest_stable_time_constant_s;
    use nemm_core::Body;
    use nemm_core::{EmmConstants, Integrator, Model, ModelKind};

    fn hold(s_min_fl: f32, s_min_pr: f32, s_max_k: f32) -> StabilityHold {
        StabilityHold {
            tau_s: HOLD_FACTOR * shortest_stable_time_constant_s(Integrator::Rk4, 1e-4),
            s_min_fl,
            s_min_pr,
            s_max_k,
        }
    }

    /// Rollout parameters of a Linear EMM with constants `c` at step `dt`.
    fn linear(c: [f32; 4], dt: f32) -> RolloutParams<f32> {
        RolloutParams {
            integrator: Integrator::Rk4,
            dt,
            b_fl0: c[0],
            b_pr0: c[1],
            k0: c[2],
            t_pr: c[3],
            v_scale: 1.0,
            x_scale: 1e-3,
            alpha_scale: 0.3,
            b_fl: None,
            b_pr: None,
            k_pr: None,
            priors: Default::default(),
            static_force: None,
            lost_motion: None,
        }
    }

    #[test]
    fn the_announcement_names_the_bound_and_the_rate_that_frees_the_model() {
        // T_pr = 2 ms at a 4 ms step (RK4 needs 1.795 ms): free.
        let p = linear([1500.0, 1000.0, 1e5, 2e-3], 4e-3);
        assert_eq!(
            StabilityHold::of_rollout(&p).announce("linear-emm", &p),
            None
        );
        // At a 5 ms step (2.244 ms needed, held at 1.01 x: 2.267 ms) T_pr is held; a model
        // rate of ceil(200 Hz x 2.2666 / 2) = 227 Hz would leave it free.
        let p = linear([1500.0, 1000.0, 1e5, 2e-3], 5e-3);
        let hold = StabilityHold::of_rollout(&p);
        let msg = hold.announce("linear-emm", &p).expect("held");
        assert!(msg.starts_with("[linear-emm] stability:"), "{msg}");
        assert!(
            msg.contains("2000.0 us") && msg.contains("2266.6 us"),
            "{msg}"
        );
        assert!(msg.contains("at least 227 Hz"), "{msg}");
    }

    #[test]
    fn constants_on_the_set_are_left_alone() {
        let h = hold(0.1, 0.1, 5.0);
        // tau = (500 * 0.1 + 2000 * 0.1) / (1e5 * 5) = 500 us, T_pr = 2 ms: free.
        assert_eq!(h.hold([2000.0, 500.0, 1e5, 2e-3]), None);
        assert_eq!(h.hold([f32::NAN, 500.0, 1e5, 2e-3]), None);
    }

    #[test]
    fn a_too_fast_model_is_moved_to_the_bound_and_passes_the_runtime_check() {
        for (s_min_fl, s_min_pr, s_max_k) in [(0.1, 0.1, 5.0), (0.1, 1.0, 1.0), (1.0, 1.0, 1.0)] {
            let h = hold(s_min_fl, s_min_pr, s_max_k);
            // tau_pr of the worst case far below 45 us, T_pr 10 us.
            let c = [2000.0, 100.0, 5e7, 1e-5];
            let held = h.hold(c).expect("moved");
            assert_eq!(held[..2], c[..2], "the dampings are not moved");
            assert!(held[2] < c[2] && held[3] > c[3]);
            let tau = h.fastest_time_constant_s(held);
            assert!((tau / h.tau_s - 1.0).abs() < 1e-5, "{tau} vs {}", h.tau_s);
            assert_eq!(h.hold(held), None, "the hold is idempotent");
            // The runtime accepts the held constants at the step (a Linear EMM carries
            // the worst case when the scalers' bounds are folded into its constants).
            let mut m: Model =
                nemm_core::testing::example_model(ModelKind::LinearEmm, 0, 0).unwrap();
            m.body = Body::LinearEmm(EmmConstants {
                b_fl_ns_per_m: held[0] * s_min_fl,
                b_pr_ns_per_m: held[1] * s_min_pr,
                k_pr_n_per_m: held[2] * s_max_k,
                t_pr_s: held[3],
            });
            m.check_step(Integrator::Rk4, 1e-4)
                .expect("stable at 100 us");
            // ... and would refuse it 2 % faster.
            assert!(m.check_step(Integrator::Rk4, 1.03e-4).is_err());
        }
    }
}
