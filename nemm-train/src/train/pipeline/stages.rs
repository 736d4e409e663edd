//! The stages of the EMM family: the Linear EMM, the quasi-static `b_fl` regression (eq. 41)
//! and the neural variants, with what they share.

use super::{
    fit, fit_residual, init_cumulative, init_scaler, loss_and_grad, meta_of, physics_loss, rmse,
    save_frame, simulate_x_pr, to_core_with, windows, with_branch, AlphaPriors, Direction, EmmNet,
    FitConfig, FitData, FitResult, Grid, PenaltyGrid, PipelineConfig, Prepared, QuasiStaticPoint,
    RolloutParams, ScalerWeights, SessionBudgetUsed, StabilityHold, StatePriors, StaticParams,
    StaticSetup, TrainedVariant, Window, STATIC_PARAMS,
};
use anyhow::{bail, Context, Result};
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, Tensor, TensorData};
use nemm_core::{Meta, ModelKind};
use std::path::Path;
use std::time::Instant;

/// The least growth over `k_pr,ini` the NEMM's `k_pr` scaler is given (its `s_max`, unless
/// the configured bound is lower). Where the stable set at the model's step allows less,
/// the stability hold lowers `k_pr,ini` instead ([`crate::train::stability`]).
const MIN_K_PR_HEADROOM: f32 = 1.5;

/// `s_max` of the NEMM's `k_pr` scaler: the largest growth of `k_pr` that keeps `p`'s
/// constants on the stable set with the dampings' scalers at their lower bounds
/// `s_min_fl`, `s_min_pr`, between [`MIN_K_PR_HEADROOM`] and `cap`.
fn stable_k_max(p: &RolloutParams<f32>, s_min_fl: f32, s_min_pr: f32, cap: f32) -> f32 {
    let free = StabilityHold {
        s_min_fl,
        s_min_pr,
        s_max_k: 1.0,
        ..StabilityHold::of_rollout(p)
    };
    (free.k_pr_cap(p.b_fl0, p.b_pr0) / p.k0)
        .min(cap)
        .max(MIN_K_PR_HEADROOM.min(cap))
}

/// Regresses the `b_fl` scaler on quasi-static points (eq. 41): normalised MSE of
/// `b_fl(v, alpha) v` against the quasi-static force, plus L2 and the physics penalty.
fn qs_regression(
    p: &RolloutParams<f32>,
    scaler: ScalerWeights<f32>,
    pts: &[QuasiStaticPoint],
    force_scale: f64,
    cfg: &PipelineConfig,
    device: &Device,
) -> Result<ScalerWeights<f32>> {
    if pts.is_empty() {
        return Ok(scaler);
    }
    let (mut net, frame) = EmmNet::from_rollout(
        &RolloutParams {
            b_fl: Some(scaler),
            b_pr: None,
            k_pr: None,
            static_force: None,
            lost_motion: None,
            ..p.clone()
        },
        None,
        device,
    );
    let spec = frame.b_fl.context("b_fl scaler")?;
    let n = pts.len();
    let x: Vec<f32> = pts
        .iter()
        .flat_map(|q| {
            [
                (q.velocity_m_s as f32) / p.v_scale,
                (q.alpha as f32) / p.alpha_scale,
            ]
        })
        .collect();
    let v: Vec<f32> = pts.iter().map(|q| q.velocity_m_s as f32).collect();
    let f: Vec<f32> = pts
        .iter()
        .map(|q| (q.force_n / force_scale) as f32)
        .collect();
    let x = Tensor::<2>::from_data(TensorData::new(x, [n, 2]), device);
    let v = Tensor::<1>::from_data(TensorData::new(v, [n]), device);
    let f = Tensor::<1>::from_data(TensorData::new(f, [n]), device);
    let b0 = p.b_fl0 / force_scale as f32;
    let mut optim = AdamConfig::new().init();
    let grid = PenaltyGrid::default();
    for step in 0..cfg.qs_steps {
        let b = net.b_fl.as_ref().context("b_fl scaler")?;
        let s = b.forward_scale(x.clone(), &spec).reshape([n]);
        let pred = s * v.clone().mul_scalar(b0);
        let mse = (pred - f.clone()).powi_scalar(2).mean();
        let loss = mse
            + physics_loss(&net, &frame, &grid, device).mul_scalar(cfg.fit.lambda_ph)
            + net.l2_norms(device).mul_scalar(cfg.fit.lambda_l2);
        let mut gp = GradientsParams::from_grads(loss.backward(), &net);
        // The constants stay those of the Linear EMM in this step.
        let _ = gp.remove::<1>(net.log_c.id);
        let progress = step as f64 / cfg.qs_steps.max(1) as f64;
        let lr = cfg.fit.lr * (0.1 + 0.9 * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos()));
        net = optim.step(lr, net, gp);
    }
    net.to_rollout(&frame).b_fl.context("b_fl scaler")
}

/// What every EMM-family stage of one [`train_each`] call shares: the data, the model grid,
/// the static-force setup and where checkpoints go.
pub(super) struct Stages<'a> {
    prepared: &'a Prepared,
    cfg: &'a PipelineConfig,
    checkpoint_root: Option<&'a Path>,
    resume: bool,
    device: Device,
    pub(super) meta: Meta,
    grid: Grid,
    train_windows: Vec<Window<'a>>,
    static_setup: Option<StaticSetup>,
    static_units: Option<[f32; STATIC_PARAMS]>,
}

/// The Linear EMM stage's outcome: the starting point of the neural stages (`p0`: the
/// trained constants, the `x_pr` scale and the static force refitted to its residual), the
/// trained Linear EMM itself and its fit.
pub(super) struct LinearStage {
    pub(super) p0: RolloutParams<f32>,
    pub(super) trained: RolloutParams<f32>,
    pub(super) fit: FitResult,
    pub(super) seconds: f64,
}

// A `Model` is about 110 KB by value (scalers at their full capacity): each stage runs in its
// own frame (`inline(never)`), so that `train_each` does not hold every stage's temporaries at
// once (the debug tests run on 2 MiB threads).
impl<'a> Stages<'a> {
    pub(super) fn new(
        prepared: &'a Prepared,
        cfg: &'a PipelineConfig,
        checkpoint_root: Option<&'a Path>,
        resume: bool,
    ) -> Self {
        let grid = Grid::new(1.0 / cfg.model_rate_hz, prepared.dt_s);
        if grid != Grid::SAME {
            eprintln!(
                "[model] integrating at {} Hz, data at {} Hz: {:.2} model steps per sample \
                 (velocity interpolated between samples, force scored at the samples)",
                cfg.model_rate_hz,
                prepared.sample_rate_hz,
                grid.steps_per_sample()
            );
        }
        let static_setup = cfg
            .static_force
            .then(|| StaticSetup::of(&prepared.train, prepared.scales.velocity_m_s));
        if let Some(s) = &static_setup {
            eprintln!(
                "[static] static force on: x_ref {:.2} mm (mean training position), span \
                 {:.2} mm, v_c {:.1} mm/s",
                1e3 * s.x_ref,
                1e3 * s.x_span,
                1e3 * s.v_c
            );
        }
        Stages {
            prepared,
            cfg,
            checkpoint_root,
            resume,
            device: Device::flex().autodiff(),
            meta: meta_of(prepared),
            grid,
            train_windows: windows(&prepared.train),
            static_units: static_setup.map(|s| s.units(prepared.scales.force_n)),
            static_setup,
        }
    }

    fn data(&self) -> FitData<'a> {
        FitData {
            train: &self.prepared.train,
            validation: &self.prepared.validation,
            warmup: self.prepared.warmup_samples,
            force_scale_n: self.prepared.scales.force_n,
            grid: self.grid,
        }
    }

    /// Step 1: the Linear EMM (every EMM-family variant starts from it), from constants
    /// fitted to the quasi-static points `qs`.
    #[inline(never)]
    pub(super) fn linear(&self, qs: &[QuasiStaticPoint]) -> Result<LinearStage> {
        let (prepared, cfg) = (self.prepared, self.cfg);
        let force_scale = prepared.scales.force_n;
        let t_lin = Instant::now();
        let (num, den) = qs.iter().fold((0.0f64, 0.0f64), |(n, d), p| {
            (
                n + p.force_n * p.velocity_m_s,
                d + p.velocity_m_s * p.velocity_m_s,
            )
        });
        let b_fl0 = if den > 0.0 && num > 0.0 {
            (num / den) as f32
        } else {
            (force_scale / prepared.scales.velocity_m_s.max(1e-6)) as f32
        };
        let b_pr0 = b_fl0;
        let k0 = (b_pr0 + b_fl0) * 2.0 * std::f32::consts::PI * 15.0;
        let mut p0 = RolloutParams::<f32> {
            integrator: cfg.integrator,
            dt: (1.0 / cfg.model_rate_hz) as f32,
            b_fl0,
            b_pr0,
            k0,
            t_pr: 0.002,
            v_scale: prepared.scales.velocity_m_s as f32,
            x_scale: 1.0,
            alpha_scale: prepared.scales.alpha as f32,
            b_fl: None,
            b_pr: None,
            k_pr: None,
            priors: prepared.condition.priors,
            static_force: None,
            lost_motion: cfg
                .lost_motion
                .then(|| initial_lost_motion(force_scale as f32, k0)),
        };
        let (train_w, grid) = (&self.train_windows, &self.grid);
        if let Some(setup) = &self.static_setup {
            // Least squares on the residual of the initial constants.
            let sp = fit_residual(&p0, train_w, grid, prepared.warmup_samples, setup);
            print_static("initial least-squares fit", &sp);
            p0.static_force = Some(sp);
        }
        if p0.lost_motion.is_some() {
            let t = Instant::now();
            let (best, loss, tried) = self.search_lost_motion(&p0, force_scale as f32);
            eprintln!(
                "[linear-emm] lost motion: start from {} (the least training loss {loss:.3e} \
                 of {tried} candidates, {:.1} s)",
                describe_lost_motion(&best),
                t.elapsed().as_secs_f64()
            );
            p0.lost_motion = Some(best);
        }
        let lin_cfg = FitConfig {
            label: "linear-emm".into(),
            epochs: cfg.linear_epochs,
            lr: cfg.linear_lr,
            lambda_ph: 0.0,
            lambda_diff: 0.0,
            ..cfg.fit.clone()
        };
        if let Some(msg) = StabilityHold::of_rollout(&p0).announce("linear-emm", &p0) {
            eprintln!("{msg}");
        }
        let (net, frame) = EmmNet::from_rollout(&p0, self.static_units, &self.device);
        let lin_dir = self.checkpoint_root.map(|r| r.join("linear-emm"));
        save_frame(lin_dir.as_deref(), &p0, self.meta, self.static_units)?;
        let lin = fit(
            net,
            &frame,
            self.data(),
            &lin_cfg,
            lin_dir.as_deref(),
            self.resume,
            &self.device,
        )?;
        SessionBudgetUsed::check(lin.stop, &lin_cfg.label)?;
        let lin_p = lin.best.to_rollout(&frame);
        if let Some(last) = lin.history.last().filter(|h| h.held > 0) {
            let hold = StabilityHold::of_rollout(&lin_p);
            eprintln!(
                "[linear-emm] stability: the data pull the EMM's dynamics faster than its step \
                 of {:.1} us allows: the hold kept its time constant at {:.1} us in {} of the \
                 last epoch's steps (the kept model: {:.1} us). A higher --model-rate-hz lets \
                 the model follow; the neural variants are held at the same bound.",
                lin_p.dt * 1e6,
                hold.tau_s * 1e6,
                last.held,
                hold.fastest_time_constant_s([lin_p.b_fl0, lin_p.b_pr0, lin_p.k0, lin_p.t_pr])
                    * 1e6,
            );
        }
        p0.b_fl0 = lin_p.b_fl0;
        p0.b_pr0 = lin_p.b_pr0;
        p0.k0 = lin_p.k0;
        p0.t_pr = lin_p.t_pr;
        p0.lost_motion = lin_p.lost_motion;
        if let Some(trained) = lin_p.lost_motion {
            // Again around the trained element, with the trained constants: the neural
            // stages start from the best.
            let t = Instant::now();
            let (best, loss, tried) =
                self.search_lost_motion_in(&lin_p, &lost_motion_candidates(trained, &AROUND));
            eprintln!(
                "[linear-emm] lost motion for the neural stages: {} (training loss \
                 {loss:.3e}, the least of {tried} candidates around the trained element, {:.1} \
                 s)",
                describe_lost_motion(&best),
                t.elapsed().as_secs_f64()
            );
            p0.lost_motion = Some(best);
        }
        if let Some(lm) = lin_p.lost_motion {
            eprintln!("[linear-emm] lost motion: {}", describe_lost_motion(&lm));
        }
        if let Some(setup) = &self.static_setup {
            // The neural stages start from the least-squares static force of the trained
            // Linear EMM's residual (the best one for its dynamics).
            let sp = fit_residual(&lin_p, train_w, grid, prepared.warmup_samples, setup);
            print_static("Linear EMM", lin_p.static_force.as_ref().unwrap_or(&sp));
            print_static("least-squares refit for the neural stages", &sp);
            p0.static_force = Some(sp);
        }
        // x_pr scale from the Linear EMM over the training windows.
        let xs = simulate_x_pr(&lin_p, train_w, grid);
        let x_scale = xs
            .iter()
            .flat_map(|w| w.iter().skip(prepared.warmup_samples))
            .fold(0.0f64, |m, x| m.max(x.abs()));
        p0.x_scale = if x_scale > 0.0 { x_scale as f32 } else { 1e-3 };
        Ok(LinearStage {
            p0,
            trained: lin_p,
            fit: lin,
            seconds: t_lin.elapsed().as_secs_f64(),
        })
    }

    /// The lost-motion element to start the Linear EMM from: the candidates of
    /// [`lost_motion_candidates`] around [`initial_lost_motion`] for `p`'s constants, each
    /// scored by the training loss of `p` with it (every training window, the Linear EMM's
    /// rollout); returns the best, its loss and the number of candidates. Adam then moves
    /// each value by a few per cent per step: this puts it within a factor of about 1.4 of
    /// where the data want it first.
    fn search_lost_motion(
        &self,
        p: &RolloutParams<f32>,
        force_scale: f32,
    ) -> ([f32; 5], f64, usize) {
        let base = initial_lost_motion(force_scale, p.k0);
        self.search_lost_motion_in(p, &lost_motion_candidates(base, &FROM_START))
    }

    /// The candidate of least training loss of `p` with it, its loss and the number of
    /// candidates.
    fn search_lost_motion_in(
        &self,
        p: &RolloutParams<f32>,
        candidates: &[[f32; 5]],
    ) -> ([f32; 5], f64, usize) {
        let force_scale = self.prepared.scales.force_n as f32;
        let warmup = self.prepared.warmup_samples;
        let mut best = (candidates[0], f64::INFINITY);
        for c in candidates {
            let q = RolloutParams {
                lost_motion: Some(*c),
                ..p.clone()
            };
            let (loss, _) = loss_and_grad(
                &q,
                &self.train_windows,
                &self.grid,
                warmup,
                f64::from(force_scale),
            );
            if loss < best.1 {
                best = (*c, loss);
            }
        }
        (best.0, best.1, candidates.len())
    }

    /// `s` with an alpha branch in its declared direction `dir` when the priors are held by
    /// construction.
    fn branched(
        &self,
        s: ScalerWeights<f32>,
        dir: Direction,
        state: usize,
        seed: u64,
    ) -> ScalerWeights<f32> {
        if self.cfg.alpha_priors == AlphaPriors::Construction && dir != Direction::None {
            with_branch(s, dir, state, self.cfg.branch_units, seed)
        } else {
            s
        }
    }

    /// A cumulative scaler (`--state-priors construction`) with `bounds` whose gates hold
    /// the declared direction `dir` when the priors in alpha are held by construction
    /// (otherwise they are free in alpha and the penalty audits them); `alpha = false`: one
    /// scale for every level (gate slopes fixed at 0, which needs a declared direction).
    fn cumulative(
        &self,
        bounds: (f32, f32),
        dir: Direction,
        alpha: bool,
        seed: u64,
    ) -> Result<ScalerWeights<f32>> {
        let direction = if self.cfg.alpha_priors == AlphaPriors::Construction || !alpha {
            dir
        } else {
            Direction::None
        };
        if !alpha && direction == Direction::None {
            bail!(
                "--b-fl-alpha=false with --state-priors construction needs a declared \
                 direction of b_fl in alpha (the condition declares none): the gates' slopes \
                 stay at 0 only in a declared direction"
            );
        }
        Ok(init_cumulative(
            self.cfg.cumulative_units,
            bounds,
            direction,
            alpha,
            seed,
        ))
    }

    /// Step 2a: the `b_fl` scaler regressed on the quasi-static points (eq. 41), from `p0`,
    /// and the stage's wall time \[s\].
    #[inline(never)]
    pub(super) fn quasi_static_b_fl(
        &self,
        p0: &RolloutParams<f32>,
        qs: &[QuasiStaticPoint],
    ) -> Result<(ScalerWeights<f32>, f64)> {
        let t_qs = Instant::now();
        let cfg = self.cfg;
        let b_fl_init = if cfg.state_priors == StatePriors::Construction {
            self.cumulative(
                cfg.b_fl_bounds,
                self.prepared.condition.priors.b_fl,
                cfg.b_fl_alpha,
                cfg.fit.seed + 20,
            )?
        } else if cfg.b_fl_alpha {
            self.branched(
                init_scaler(2, cfg.hidden, cfg.layers, cfg.b_fl_bounds, cfg.fit.seed),
                self.prepared.condition.priors.b_fl,
                1,
                cfg.fit.seed + 10,
            )
        } else {
            without_alpha(with_branch(
                init_scaler(2, cfg.hidden, cfg.layers, cfg.b_fl_bounds, cfg.fit.seed),
                self.prepared.condition.priors.b_fl,
                1,
                cfg.branch_units,
                cfg.fit.seed + 10,
            ))
        };
        // With a static force, the quasi-static points lose its part at their position (the
        // run's stroke centre, where they are taken) before the b_fl regression.
        let qs_owned: Vec<QuasiStaticPoint>;
        let qs = match &p0.static_force {
            None => qs,
            Some(sp) => {
                qs_owned = without_static_force(qs, self.prepared, sp);
                &qs_owned
            }
        };
        let b_fl = qs_regression(
            p0,
            b_fl_init,
            qs,
            self.prepared.scales.force_n,
            cfg,
            &self.device,
        )?;
        let seconds = t_qs.elapsed().as_secs_f64();
        eprintln!(
            "[nemm] quasi-static b_fl regression (eq. 41): {} points, {} steps, {seconds:.1} s",
            qs.len(),
            cfg.qs_steps,
        );
        Ok((b_fl, seconds))
    }

    /// Step 2b: the neural variant `v` (NEMM-Light or NEMM) trained from `p0` with the
    /// quasi-static `b_fl`; `earlier_s` is the wall time of the stages it builds on.
    #[inline(never)]
    pub(super) fn neural(
        &self,
        v: ModelKind,
        p0: &RolloutParams<f32>,
        b_fl: &ScalerWeights<f32>,
        earlier_s: f64,
    ) -> Result<TrainedVariant> {
        let (prepared, cfg) = (self.prepared, self.cfg);
        let condition = &prepared.condition;
        let t = Instant::now();
        let mut p = p0.clone();
        p.b_fl = Some(b_fl.clone());
        if v == ModelKind::Nemm {
            let k_max = stable_k_max(&p, cfg.b_fl_bounds.0, cfg.pr_bounds.0, cfg.pr_bounds.1);
            p.b_pr = Some(self.branched(
                init_scaler(1, cfg.hidden, cfg.layers, cfg.pr_bounds, cfg.fit.seed + 1),
                condition.priors.b_pr,
                0,
                cfg.fit.seed + 11,
            ));
            p.k_pr = Some(if cfg.state_priors == StatePriors::Construction {
                self.cumulative(
                    (cfg.pr_bounds.0, k_max),
                    condition.priors.k_pr,
                    true,
                    cfg.fit.seed + 22,
                )?
            } else {
                self.branched(
                    init_scaler(
                        2,
                        cfg.hidden,
                        cfg.layers,
                        (cfg.pr_bounds.0, k_max),
                        cfg.fit.seed + 2,
                    ),
                    condition.priors.k_pr,
                    1,
                    cfg.fit.seed + 12,
                )
            });
        }
        if let Some(msg) = StabilityHold::of_rollout(&p).announce(v.name(), &p) {
            eprintln!("{msg}");
        }
        let fit_cfg = FitConfig {
            label: v.name().into(),
            ..cfg.fit.clone()
        };
        let (net, frame) = EmmNet::from_rollout(&p, self.static_units, &self.device);
        let dir = self.checkpoint_root.map(|root| root.join(v.name()));
        save_frame(dir.as_deref(), &p, self.meta, self.static_units)?;
        let r = fit(
            net,
            &frame,
            self.data(),
            &fit_cfg,
            dir.as_deref(),
            self.resume,
            &self.device,
        )?;
        SessionBudgetUsed::check(r.stop, &fit_cfg.label)?;
        let val = rmse(
            &r.best,
            &frame,
            &prepared.validation,
            &self.grid,
            prepared.warmup_samples,
            prepared.scales.force_n,
        );
        Ok(TrainedVariant {
            variant: v,
            model: Box::new(to_core_with(
                &r.best.to_rollout(&frame),
                self.meta,
                condition,
            )?),
            history: r.history,
            val_rmse: val,
            stop: Some(r.stop),
            kept_epoch: Some(r.best_epoch),
            seconds: t.elapsed().as_secs_f64() + earlier_s,
        })
    }

    /// The trained Linear EMM as a variant of its own (with the neural stages' `x_pr` scale).
    #[inline(never)]
    pub(super) fn linear_variant(&self, lin: &LinearStage) -> Result<TrainedVariant> {
        let scaled = lin_p_with_scale(&lin.trained, lin.p0.x_scale);
        Ok(TrainedVariant {
            variant: ModelKind::LinearEmm,
            model: Box::new(to_core_with(&scaled, self.meta, &self.prepared.condition)?),
            history: lin.fit.history.clone(),
            val_rmse: lin.fit.best_val_rmse,
            stop: Some(lin.fit.stop),
            kept_epoch: Some(lin.fit.best_epoch),
            seconds: lin.seconds,
        })
    }
}

/// Prints a static force's parameters.
fn print_static(what: &str, s: &StaticParams<f32>) {
    let t = s.theta;
    eprintln!(
        "[static] {what}: F_gas0 = {:.1} N {:+.1} N x alpha, k_gas = {:.0} N/m {:+.0} N/m x alpha, \
         F_c = {:.1} N",
        t[0], t[1], t[2], t[3], t[4]
    );
}

/// Quasi-static points with the static force at their position (the stroke centre of their
/// run, [`crate::data::preprocess::Excitation::offset_m`]) subtracted.
fn without_static_force(
    qs: &[QuasiStaticPoint],
    prepared: &Prepared,
    sp: &StaticParams<f32>,
) -> Vec<QuasiStaticPoint> {
    qs.iter()
        .map(|q| {
            let x = prepared
                .runs
                .get(q.run)
                .map_or(f64::from(sp.x_ref), |r| r.summary.excitation.offset_m);
            let phi = nemm_kernels::static_force::features(
                f64::from(sp.x_ref),
                f64::from(sp.v_c),
                x,
                q.velocity_m_s,
                q.alpha,
            );
            let r: f64 = (0..STATIC_PARAMS)
                .map(|i| f64::from(sp.theta[i]) * phi[i])
                .sum();
            QuasiStaticPoint {
                force_n: q.force_n - r,
                ..*q
            }
        })
        .collect()
}

pub(super) fn lin_p_with_scale(p: &RolloutParams<f32>, x_scale: f32) -> RolloutParams<f32> {
    RolloutParams {
        x_scale,
        ..p.clone()
    }
}

/// Initial lost-motion element (order of `nemm_core::LostMotion::params`) for force scale
/// `force_scale` \[N\] and initial `k_pr` `k0` \[N/m\]: `f0` a quarter of the force
/// scale, a travel of a tenth of the liquid spring's deflection under the force scale at
/// `alpha = 0` on each side, growing by that deflection per unit alpha. Training moves
/// every value by factors (they are trained in log space).
pub(super) fn initial_lost_motion(force_scale: f32, k0: f32) -> [f32; 5] {
    let x = force_scale / k0;
    [0.25 * force_scale, 0.1 * x, x, 0.1 * x, x]
}

/// `s` (a scaler with an alpha branch) made independent of alpha for good: the branch's
/// output weights `v_k = theta_v,k^2` start at 0, where their gradient `2 theta_v,k dL/dv_k`
/// is 0, so no optimizer step moves them, and the MLP does not see alpha (its alpha column
/// is zero by [`with_branch`] and the branch feeds it none).
pub(super) fn without_alpha(mut s: ScalerWeights<f32>) -> ScalerWeights<f32> {
    let layout = s.layout();
    if let Some(v) = layout.branch_ranges().and_then(|r| s.w.get_mut(r.theta_v)) {
        v.fill(0.0);
    }
    s
}

/// A lost-motion element (order of `nemm_core::LostMotion::params`) in words.
fn describe_lost_motion(l: &[f32; 5]) -> String {
    format!(
        "f0 {:.0} N, travels {:.2} / {:.2} mm + {:.2} / {:.2} mm per unit alpha (compression / \
         rebound)",
        l[0],
        1e3 * l[1],
        1e3 * l[3],
        1e3 * l[2],
        1e3 * l[4]
    )
}

/// Factors of a lost-motion search: `f0`, the travels at `alpha = 0`, their growth per
/// unit alpha, and the compression side's growth over the rebound side's.
pub(super) struct SearchFactors {
    f0: [f32; 3],
    travel: [f32; 2],
    growth: [f32; 4],
    split: [f32; 2],
}

/// From [`initial_lost_motion`]: wide.
pub(super) const FROM_START: SearchFactors = SearchFactors {
    f0: [0.5, 1.0, 2.0],
    travel: [1.0, 10.0],
    growth: [0.5, 2.0, 8.0, 32.0],
    split: [1.0, 2.0],
};

/// Around a trained element: near (the trained element itself is a candidate).
pub(super) const AROUND: SearchFactors = SearchFactors {
    f0: [0.7, 1.0, 1.4],
    travel: [1.0, 3.0],
    growth: [1.0, 1.5, 2.5, 4.0],
    split: [1.0, 1.5],
};

/// The candidates around `base` ([`initial_lost_motion`]'s order): every combination of
/// `factors` (the compression side's growth times `split`; the candidate with every factor
/// 1 first, when there is one). The bench's foam gives the compression chamber the larger
/// loss, hence the split.
pub(super) fn lost_motion_candidates(base: [f32; 5], factors: &SearchFactors) -> Vec<[f32; 5]> {
    let mut out = vec![base];
    for &f in &factors.f0 {
        for &d0 in &factors.travel {
            for &g in &factors.growth {
                for &split in &factors.split {
                    let c = [
                        base[0] * f,
                        base[1] * d0,
                        base[2] * g * split,
                        base[3] * d0,
                        base[4] * g,
                    ];
                    if c != base {
                        out.push(c);
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod lost_motion_tests {
    use super::*;

    /// The search's candidates: the base first, every combination of the factors once, every
    /// value positive, the compression side's growth never below the rebound side's.
    #[test]
    fn candidates_start_at_the_base_and_cover_the_factors() {
        let base = initial_lost_motion(2000.0, 1.0e6);
        let want = [500.0, 2e-4, 2e-3, 2e-4, 2e-3];
        assert!(base
            .iter()
            .zip(want)
            .all(|(a, b)| (a - b).abs() <= 1e-6 * b));
        for (factors, n) in [(&FROM_START, 1 + 3 * 2 * 4 * 2), (&AROUND, 3 * 2 * 4 * 2)] {
            let c = lost_motion_candidates(base, factors);
            assert_eq!(c[0], base);
            assert_eq!(c.len(), n, "every combination once (the base once)");
            for (i, x) in c.iter().enumerate() {
                assert!(x.iter().all(|v| *v > 0.0 && v.is_finite()));
                assert!(x[2] >= x[4]);
                assert!(c[..i].iter().all(|y| y != x), "duplicate {x:?}");
            }
        }
    }
}
