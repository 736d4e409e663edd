//! The paper's training procedure for the four variants (sections 5-6).
//!
//! 1. **SEM**: the quasi-static points of the training set (section 5.3) become support
//!    points per oil-loss level: points of one level whose velocities agree within 5 % are
//!    averaged (a cluster spans at most 20 %) (the gap is widened by factors of 1.5 while there are more clusters than the
//!    map holds, as with the dense points of random excitation), the origin is added, and
//!    every level is resampled (piecewise linear) onto the common velocity grid. nemm-core interpolates linearly in alpha between the levels.
//! 2. **Linear EMM** (first step of the two-step procedure): constant `b_fl`, `b_pr`, `k_pr`,
//!    `T_pr`, initialised from the quasi-static data (`b_fl,ini` the least-squares slope of
//!    force over velocity, `b_pr,ini = b_fl,ini`, `k_pr,ini` such that the pressure branch's
//!    corner frequency is 15 Hz, `T_pr` = 2 ms) and fitted by Adam on the rollout MSE.
//! 3. **NEMM-Light**: the Linear EMM's constants; `b_fl(v_st, alpha)` first regressed on the
//!    quasi-static points (eq. 41, burn only), then everything trained on the rollout (eq. 42).
//! 4. **NEMM**: as NEMM-Light plus `b_pr(alpha)` and `k_pr(x_pr, alpha)`, initialised to
//!    reproduce the constants (output bias at the identity logit, small output weights). The
//!    `x_pr` input scale is the abs-max `x_pr` of the Linear EMM over the training windows.
//!
//! All variants share the split, the normalisation and the force scale.

use super::adjoint::{
    simulate_x_pr, BranchShape, Grid, RolloutParams, ScalerWeights, StaticParams, Window,
};
use super::fit::{fit, rmse, windows, EpochStats, FitConfig, FitData, FitResult, StopReason};
use super::net::EmmNet;
use super::params::to_core_with;
use super::physics::{physics_loss, PenaltyGrid};
use super::static_fit::{fit_residual, StaticSetup};
use crate::data::preprocess::{Prepared, QuasiStaticPoint};
use anyhow::{bail, Context, Result};
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, Tensor, TensorData};
use nemm_core::mlp::{BranchLayout, Direction, ScalerLayout};
use nemm_core::model::{Extension, STABILITY_MARGIN};
use nemm_core::sem::{MAX_SEM_ALPHAS, MAX_SEM_VELOCITIES};
use nemm_core::static_force::STATIC_PARAMS;
use nemm_core::{Body, InputScales, Integrator, Meta, Model, ModelKind, Scaler, SemMap};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

pub use super::session::SessionBudgetUsed;

/// The trainer's names and order of the four variants of section 6 (nemm-core's
/// [`ModelKind`], parsed and printed by its `name()`: `sem`, `linear-emm`, `nemm-light`,
/// `nemm`).
pub trait VariantInfo: Sized {
    /// All four, in the order of Table 4.
    const ALL: [Self; 4];
    /// Key in `report.json` (`sem`, `linear_emm`, `nemm_light`, `nemm`).
    fn key(self) -> &'static str;
    /// Name in tables (`SEM`, `Linear EMM`, `NEMM-Light`, `NEMM`).
    fn title(self) -> &'static str;
}

impl VariantInfo for ModelKind {
    const ALL: [ModelKind; 4] = [
        ModelKind::Sem,
        ModelKind::LinearEmm,
        ModelKind::NemmLight,
        ModelKind::Nemm,
    ];

    fn key(self) -> &'static str {
        match self {
            ModelKind::Sem => "sem",
            ModelKind::LinearEmm => "linear_emm",
            ModelKind::NemmLight => "nemm_light",
            ModelKind::Nemm => "nemm",
        }
    }

    fn title(self) -> &'static str {
        match self {
            ModelKind::Sem => "SEM",
            ModelKind::LinearEmm => "Linear EMM",
            ModelKind::NemmLight => "NEMM-Light",
            ModelKind::Nemm => "NEMM",
        }
    }
}

/// How the declared monotonicity priors in alpha (eqs. 31, 37-38, second conditions) are
/// imposed on the neural coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum AlphaPriors {
    /// An alpha branch per coefficient with a declared direction
    /// (`nemm_core::mlp::AlphaBranch`): monotone in alpha for every weight; the physics
    /// penalty keeps only the state conditions.
    Construction,
    /// The paper's physics penalty on a grid alone (section 5.2), checked by the audit.
    Penalty,
}

impl AlphaPriors {
    /// `construction` or `penalty`.
    pub const fn name(self) -> &'static str {
        match self {
            AlphaPriors::Construction => "construction",
            AlphaPriors::Penalty => "penalty",
        }
    }
}

impl std::str::FromStr for AlphaPriors {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "construction" => Ok(AlphaPriors::Construction),
            "penalty" => Ok(AlphaPriors::Penalty),
            other => Err(format!(
                "unknown alpha-priors mode `{other}` (expected construction or penalty)"
            )),
        }
    }
}

/// Settings of the whole procedure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PipelineConfig {
    /// Hidden width `H` of every scaler (paper: 16).
    pub hidden: usize,
    /// Hidden layers `L` (paper: 5).
    pub layers: usize,
    /// Integrator (paper: RK4; RK3 selectable).
    pub integrator: Integrator,
    /// Training settings of the neural stages (batch, lr, lambdas, epochs, ...).
    pub fit: FitConfig,
    /// Epochs of the Linear EMM stage.
    pub linear_epochs: usize,
    /// Adam learning rate of the Linear EMM stage (on `ln(c) / LOG_CONSTANT_SCALE`: 3e-3 moves
    /// the constants by ~3 % per step).
    pub linear_lr: f64,
    /// Full-batch Adam steps of the quasi-static `b_fl` regression (eq. 41).
    pub qs_steps: usize,
    /// Bounds `(s_min, s_max)` of the `b_fl` scale factor.
    pub b_fl_bounds: (f32, f32),
    /// Bounds of the `b_pr` and `k_pr` scale factors (`s_max` of `k_pr` is lowered if the
    /// explicit-RK stability check needs it).
    pub pr_bounds: (f32, f32),
    /// Integration rate of the model \[Hz\] (the exported step is `1 / model_rate_hz`),
    /// independent of the data's sample rate.
    pub model_rate_hz: f64,
    /// How the declared priors in alpha are imposed.
    pub alpha_priors: AlphaPriors,
    /// Units `K` of each alpha branch.
    pub branch_units: usize,
    /// Adds the static force of eq. 17 to every EMM-family variant.
    pub static_force: bool,
}

/// The defaults are [`crate::config::Config`]'s.
impl Default for PipelineConfig {
    fn default() -> Self {
        crate::config::Config::default().pipeline_config()
    }
}

/// What `nemm export` needs to rebuild a model from a checkpoint folder: the initial
/// parameters (shapes, bounds, scales; the weights are replaced by the checkpoint's) and the
/// training-data facts.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SavedFrame {
    /// Initial rollout parameters of the stage.
    pub initial: RolloutParams<f32>,
    /// Training-data facts.
    pub meta: Meta,
    /// Units of the static force's parameters in training (`None` without a static force).
    #[serde(default)]
    pub static_units: Option<[f32; STATIC_PARAMS]>,
}

fn save_frame(
    dir: Option<&Path>,
    p: &RolloutParams<f32>,
    meta: Meta,
    static_units: Option<[f32; STATIC_PARAMS]>,
) -> Result<()> {
    if let Some(dir) = dir {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let text = serde_json::to_string_pretty(&SavedFrame {
            initial: p.clone(),
            meta,
            static_units,
        })?;
        crate::fsutil::write_atomic_bytes(&dir.join("frame.json"), text.as_bytes())
            .with_context(|| format!("cannot write {}", dir.join("frame.json").display()))?;
    }
    Ok(())
}

/// One trained variant.
#[derive(Debug, Clone)]
pub struct TrainedVariant {
    /// Which.
    pub variant: ModelKind,
    /// The exportable model.
    pub model: Model,
    /// Training history of its rollout stage (empty for the SEM).
    pub history: Vec<EpochStats>,
    /// Validation RMSE (normalised) of the kept model.
    pub val_rmse: f64,
    /// Why its training ended (`None` for the SEM).
    pub stop: Option<StopReason>,
    /// The epoch of its rollout stage whose model was kept: `Some(0)` is the model the stage
    /// started from (no epoch improved on it); `None` for the SEM.
    pub kept_epoch: Option<usize>,
    /// Training wall time \[s\] of this variant's own stages.
    pub seconds: f64,
}

/// Training-data facts every model carries.
pub fn meta_of(prepared: &Prepared) -> Meta {
    let alphas = prepared.train.iter().flat_map(|s| match &s.alphas {
        Some(a) => a.clone(),
        None => vec![s.alpha],
    });
    let (lo, hi) = alphas.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), a| {
        (lo.min(a), hi.max(a))
    });
    Meta {
        force_scale_n: prepared.scales.force_n as f32,
        alpha_min: if lo.is_finite() { lo } else { 0.0 },
        alpha_max: if hi.is_finite() { hi } else { 0.0 },
    }
}

/// A freshly initialised scaler: uniform `+-1/sqrt(fan_in)` weights and biases (burn's and
/// PyTorch's default), LayerNorm `gamma = 1`, `beta = 0`, small output weights and the output
/// bias at the identity logit, so that the scale factor starts at ~1 (the constants). The
/// uniform draws come from xoshiro256++ seeded with `seed`.
pub fn init_scaler(
    inputs: usize,
    hidden: usize,
    layers: usize,
    bounds: (f32, f32),
    seed: u64,
) -> ScalerWeights<f32> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut uniform = move || rng.random_range(-1.0f32..1.0);
    let layout = ScalerLayout::mlp(inputs, hidden, layers);
    let mut w = vec![0.0f32; layout.mlp_len()];
    for l in 0..layers {
        let r = layout.layer(l).expect("layer of the layout");
        let k = 1.0 / (r.fan_in as f32).sqrt();
        // Weights then biases, in one stream of draws.
        for v in w[r.w.start..r.b.end].iter_mut() {
            *v = k * uniform();
        }
        w[r.gamma].fill(1.0);
        w[r.beta].fill(0.0);
    }
    let (w_o, b_o) = layout.output().expect("an MLP with layers");
    let k = 0.05 / (hidden as f32).sqrt();
    for v in w[w_o].iter_mut() {
        *v = k * uniform();
    }
    w[b_o] = Scaler::<1>::identity_logit(bounds.0, bounds.1);
    ScalerWeights {
        inputs,
        hidden,
        layers,
        w,
        s_min: bounds.0,
        s_max: bounds.1,
        branch: None,
    }
}

/// Gives `s` an alpha branch of `units` units in `direction` (with `state_inputs` state
/// inputs: 1 for `b_fl`, `k_pr`, 0 for `b_pr`): the MLP's alpha column (the last input of
/// layer 1) is set to zero, where it stays (its gradient is zero, the MLP gets `alpha_n =
/// 0`), and the branch weights are drawn from xoshiro256++ seeded with `seed`: `r`, `c`
/// uniform in `+-1`, `theta_u` uniform in `[0.2, 0.6]` (a moderate slope in alpha),
/// `theta_v = 0.3`. The output bias absorbs the branch's value at the origin, so the scale
/// factor still starts at ~1.
pub fn with_branch(
    mut s: ScalerWeights<f32>,
    direction: Direction,
    state_inputs: usize,
    units: usize,
    seed: u64,
) -> ScalerWeights<f32> {
    let layout = s.layout();
    for i in 0..s.hidden {
        let alpha_col = layout
            .first_layer_weight(i, s.inputs - 1)
            .expect("first-layer weight");
        s.w[alpha_col] = 0.0;
    }
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut uniform = move |a: f32, b: f32| rng.random_range(a..b);
    let branch = BranchLayout {
        state_inputs,
        units,
    };
    let ranges = branch.ranges().expect("branch layout");
    let mut bw = vec![0.0f32; branch.len()];
    for v in bw[ranges.r].iter_mut() {
        *v = uniform(-1.0, 1.0);
    }
    for v in bw[ranges.theta_u].iter_mut() {
        *v = uniform(0.2, 0.6);
    }
    for v in bw[ranges.c.clone()].iter_mut() {
        *v = uniform(-1.0, 1.0);
    }
    bw[ranges.theta_v].fill(0.3);
    let at_origin: f32 = bw[ranges.c]
        .iter()
        .map(|&ci| 0.09 * nemm_core::mlp::leaky_relu(ci))
        .sum();
    let (_, b_o) = layout.output().expect("an MLP with layers");
    s.w[b_o] -= at_origin;
    s.w.extend(bw);
    s.branch = Some(BranchShape {
        direction,
        state_inputs,
        units,
    });
    s
}

/// Relative velocity gap that separates two SEM support velocities (5 %).
pub const SEM_CLUSTER_GAP: f64 = 0.05;

/// Largest span of one velocity cluster, relative to its largest magnitude, in units of the
/// gap (4 x 5 % = 20 %).
pub const SEM_CLUSTER_SPAN: f64 = 4.0;

/// Knots from sorted velocities: the origin plus the mean of every cluster. A cluster holds
/// velocities of one sign, each less than `gap` times the larger magnitude from the previous
/// one, and spans at most [`SEM_CLUSTER_SPAN`] `gap` times its largest magnitude (so that dense
/// points, e.g. of random excitation, do not chain into one cluster).
fn velocity_knots(sorted: &[f64], gap: f64) -> Vec<f64> {
    let mut knots: Vec<f64> = vec![0.0];
    let mut cluster: Vec<f64> = Vec::new();
    for &v in sorted {
        if let (Some(&first), Some(&last)) = (cluster.first(), cluster.last()) {
            let scale = first.abs().max(v.abs());
            if (v - last).abs() > gap * last.abs().max(v.abs())
                || (v - first).abs() > SEM_CLUSTER_SPAN * gap * scale
                || v.signum() != last.signum()
            {
                knots.push(cluster.iter().sum::<f64>() / cluster.len() as f64);
                cluster.clear();
            }
        }
        cluster.push(v);
    }
    if !cluster.is_empty() {
        knots.push(cluster.iter().sum::<f64>() / cluster.len() as f64);
    }
    knots.sort_by(f64::total_cmp);
    knots.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
    knots
}

/// SEM map from quasi-static points (see the module docs).
pub fn fit_sem(points: &[QuasiStaticPoint]) -> Result<SemMap> {
    if points.is_empty() {
        bail!("no quasi-static points in the training set: cannot build the SEM");
    }
    let mut alphas: Vec<f64> = points.iter().map(|p| p.alpha).collect();
    alphas.sort_by(f64::total_cmp);
    alphas.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    if alphas.len() > MAX_SEM_ALPHAS {
        bail!(
            "{} oil-loss levels; the SEM holds at most {MAX_SEM_ALPHAS}",
            alphas.len()
        );
    }
    // Velocity clusters over all levels: 5 % gaps, widened until the knots fit the map.
    let mut vs: Vec<f64> = points.iter().map(|p| p.velocity_m_s).collect();
    vs.sort_by(f64::total_cmp);
    let mut gap = SEM_CLUSTER_GAP;
    let mut knots = velocity_knots(&vs, gap);
    while knots.len() > MAX_SEM_VELOCITIES && gap < 1.0 {
        gap *= 1.5;
        knots = velocity_knots(&vs, gap);
    }
    if knots.len() > MAX_SEM_VELOCITIES {
        bail!(
            "{} velocity support points; the SEM holds at most {MAX_SEM_VELOCITIES}",
            knots.len()
        );
    }
    let mut forces = Vec::new();
    for &a in &alphas {
        // This level's points, averaged per knot (nearest knot), plus the origin.
        let mut sum = vec![0.0f64; knots.len()];
        let mut cnt = vec![0usize; knots.len()];
        for p in points.iter().filter(|p| (p.alpha - a).abs() < 1e-9) {
            let (i, _) = knots
                .iter()
                .enumerate()
                .map(|(i, k)| (i, (k - p.velocity_m_s).abs()))
                .min_by(|x, y| x.1.total_cmp(&y.1))
                .unwrap_or((0, 0.0));
            sum[i] += p.force_n;
            cnt[i] += 1;
        }
        let own: Vec<(f64, f64)> = knots
            .iter()
            .enumerate()
            .filter(|(i, k)| cnt[*i] > 0 || **k == 0.0)
            .map(|(i, &k)| {
                (
                    k,
                    if cnt[i] > 0 {
                        sum[i] / cnt[i] as f64
                    } else {
                        0.0
                    },
                )
            })
            .collect();
        for &k in &knots {
            forces.push(interp(&own, k) as f32);
        }
    }
    let map = SemMap {
        velocities_m_s: knots.iter().map(|&v| v as f32).collect(),
        alphas: alphas.iter().map(|&a| a as f32).collect(),
        forces_n: forces.into_iter().collect(),
    };
    map.validate()
        .map_err(|e| anyhow::anyhow!("SEM map from the quasi-static points is invalid: {e:?}"))?;
    Ok(map)
}

/// Piecewise-linear interpolation through sorted points, linear extrapolation at the ends.
fn interp(pts: &[(f64, f64)], x: f64) -> f64 {
    match pts.len() {
        0 => 0.0,
        1 => pts[0].1,
        n => {
            let i = pts.partition_point(|p| p.0 <= x).clamp(1, n - 1);
            let (x0, y0) = pts[i - 1];
            let (x1, y1) = pts[i];
            y0 + (y1 - y0) * (x - x0) / (x1 - x0)
        }
    }
}

/// Largest `s_max` of `k_pr` that passes nemm-core's stability check, capped at `cap`.
fn stable_k_max(p: &RolloutParams<f32>, s_min_fl: f32, s_min_pr: f32, cap: f32) -> f32 {
    let limit = STABILITY_MARGIN * p.integrator.stability_limit() * 0.95;
    let den = p.b_pr0 * s_min_pr + p.b_fl0 * s_min_fl;
    // dt <= limit * den / (k0 s)  =>  s <= limit den / (k0 dt)
    (limit * den / (p.k0 * p.dt)).min(cap)
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

/// A variant that could not be trained or exported, and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VariantFailure {
    /// Which.
    pub variant: ModelKind,
    /// The error, with its causes.
    pub reason: String,
}

/// What [`train_each`] made of the requested variants.
#[derive(Debug, Clone)]
pub struct Trained {
    /// The variants that were trained, in the order of Table 4.
    pub trained: Vec<TrainedVariant>,
    /// The variants that failed, in the order of Table 4.
    pub failed: Vec<VariantFailure>,
}

/// Records the failure of `variant`, unless `e` is the end of a time-boxed session (which
/// stops the whole job with a checkpoint and is returned).
fn record(failed: &mut Vec<VariantFailure>, variant: ModelKind, e: anyhow::Error) -> Result<()> {
    if e.is::<SessionBudgetUsed>() {
        return Err(e);
    }
    eprintln!("[{}] failed: {e:#}", variant.name());
    failed.push(VariantFailure {
        variant,
        reason: format!("{e:#}"),
    });
    Ok(())
}

/// Trains the requested variants; every variant must succeed (the first failure is the
/// error). [`train_each`] keeps going past failures.
pub fn train_variants(
    prepared: &Prepared,
    variants: &[ModelKind],
    cfg: &PipelineConfig,
    checkpoint_root: Option<&Path>,
    resume: bool,
) -> Result<Vec<TrainedVariant>> {
    let r = train_each(prepared, variants, cfg, checkpoint_root, resume)?;
    if let Some(f) = r.failed.first() {
        bail!("{} failed: {}", f.variant.title(), f.reason);
    }
    Ok(r.trained)
}

/// The SEM from the training set's quasi-static points.
fn train_sem(prepared: &Prepared, cfg: &PipelineConfig, meta: Meta) -> Result<TrainedVariant> {
    let t = Instant::now();
    let map = fit_sem(&prepared.quasi_static.train)?;
    let model = Model {
        integrator: cfg.integrator,
        dt_s: (1.0 / cfg.model_rate_hz) as f32,
        scales: InputScales {
            velocity_m_s: prepared.scales.velocity_m_s as f32,
            x_pr_m: 1.0,
            alpha: prepared.scales.alpha as f32,
        },
        meta,
        body: Body::Sem(map),
        ext: Extension {
            condition: prepared.condition.clone(),
            ..Extension::default()
        },
        tables: nemm_core::stored_tables::StoredTables::EMPTY,
    };
    model
        .validate()
        .map_err(|e| anyhow::anyhow!("SEM model invalid: {e}"))?;
    let val = super::eval::rmse_model(
        &model,
        &prepared.validation,
        prepared.dt_s,
        prepared.warmup_samples,
        prepared.scales.force_n,
    )?;
    eprintln!(
        "[sem] {} support velocities x {} oil-loss levels, validation RMSE {val:.4}",
        match &model.body {
            Body::Sem(m) => m.velocities_m_s.len(),
            _ => 0,
        },
        match &model.body {
            Body::Sem(m) => m.alphas.len(),
            _ => 0,
        }
    );
    Ok(TrainedVariant {
        variant: ModelKind::Sem,
        model,
        history: Vec::new(),
        val_rmse: val,
        stop: None,
        kept_epoch: None,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// What every EMM-family stage of one [`train_each`] call shares: the data, the model grid,
/// the static-force setup and where checkpoints go.
struct Stages<'a> {
    prepared: &'a Prepared,
    cfg: &'a PipelineConfig,
    checkpoint_root: Option<&'a Path>,
    resume: bool,
    device: Device,
    meta: Meta,
    grid: Grid,
    train_windows: Vec<Window<'a>>,
    static_setup: Option<StaticSetup>,
    static_units: Option<[f32; STATIC_PARAMS]>,
}

/// The Linear EMM stage's outcome: the starting point of the neural stages (`p0`: the
/// trained constants, the `x_pr` scale and the static force refitted to its residual), the
/// trained Linear EMM itself and its fit.
struct LinearStage {
    p0: RolloutParams<f32>,
    trained: RolloutParams<f32>,
    fit: FitResult,
    seconds: f64,
}

impl<'a> Stages<'a> {
    fn new(
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
    fn linear(&self, qs: &[QuasiStaticPoint]) -> Result<LinearStage> {
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
        };
        let (train_w, grid) = (&self.train_windows, &self.grid);
        if let Some(setup) = &self.static_setup {
            // Least squares on the residual of the initial constants.
            let sp = fit_residual(&p0, train_w, grid, prepared.warmup_samples, setup);
            print_static("initial least-squares fit", &sp);
            p0.static_force = Some(sp);
        }
        let lin_cfg = FitConfig {
            label: "linear-emm".into(),
            epochs: cfg.linear_epochs,
            lr: cfg.linear_lr,
            lambda_ph: 0.0,
            ..cfg.fit.clone()
        };
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
        p0.b_fl0 = lin_p.b_fl0;
        p0.b_pr0 = lin_p.b_pr0;
        p0.k0 = lin_p.k0;
        p0.t_pr = lin_p.t_pr;
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

    /// Step 2a: the `b_fl` scaler regressed on the quasi-static points (eq. 41), from `p0`.
    fn quasi_static_b_fl(
        &self,
        p0: &RolloutParams<f32>,
        qs: &[QuasiStaticPoint],
    ) -> Result<ScalerWeights<f32>> {
        let cfg = self.cfg;
        let b_fl_init = self.branched(
            init_scaler(2, cfg.hidden, cfg.layers, cfg.b_fl_bounds, cfg.fit.seed),
            self.prepared.condition.priors.b_fl,
            1,
            cfg.fit.seed + 10,
        );
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
        let t_qs = Instant::now();
        let b_fl = qs_regression(
            p0,
            b_fl_init,
            qs,
            self.prepared.scales.force_n,
            cfg,
            &self.device,
        )?;
        eprintln!(
            "[nemm] quasi-static b_fl regression (eq. 41): {} points, {} steps, {:.1} s",
            qs.len(),
            cfg.qs_steps,
            t_qs.elapsed().as_secs_f64()
        );
        Ok(b_fl)
    }

    /// Step 2b: the neural variant `v` (NEMM-Light or NEMM) trained from `p0` with the
    /// quasi-static `b_fl`; `earlier_s` is the wall time of the stages it builds on.
    fn neural(
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
            if k_max < 1.5 {
                bail!(
                    "the fitted EMM is too stiff for dt = {} s: k_pr may only grow {k_max:.2}x \
                     before the explicit RK step becomes unstable; use a shorter step (higher \
                     sample rate) or RK4",
                    p.dt
                );
            }
            p.b_pr = Some(self.branched(
                init_scaler(1, cfg.hidden, cfg.layers, cfg.pr_bounds, cfg.fit.seed + 1),
                condition.priors.b_pr,
                0,
                cfg.fit.seed + 11,
            ));
            p.k_pr = Some(self.branched(
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
            ));
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
        let model = to_core_with(&r.best.to_rollout(&frame), self.meta, condition)?;
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
            model,
            history: r.history,
            val_rmse: val,
            stop: Some(r.stop),
            kept_epoch: Some(r.best_epoch),
            seconds: t.elapsed().as_secs_f64() + earlier_s,
        })
    }
}

/// Refuses data and options no EMM-family variant can be trained with.
fn check_trainable(
    prepared: &Prepared,
    variants: &[ModelKind],
    cfg: &PipelineConfig,
) -> Result<()> {
    if prepared.validation.is_empty() && variants.iter().any(|v| *v != ModelKind::Sem) {
        bail!(
            "no validation windows: the runs at the training oil-loss levels are too short for \
             the {:.0} % validation split of their {:.2} s windows ({} training windows in all); \
             early stopping and model selection need them. Use longer or more runs, or \
             shorter windows (--window-s)",
            100.0 * prepared.config.split.validation_fraction,
            prepared.scored_samples as f64 * prepared.dt_s,
            prepared.train.len()
        );
    }
    if !(cfg.model_rate_hz.is_finite() && cfg.model_rate_hz > 0.0) {
        bail!(
            "model rate {} Hz: must be a positive rate (--model-rate-hz)",
            cfg.model_rate_hz
        );
    }
    Ok(())
}

/// Trains the requested variants, keeping going past a variant that fails (its error is
/// recorded in [`Trained::failed`]): a failed Linear EMM stage fails every EMM-family variant
/// (they start from it), a failed quasi-static regression NEMM-Light and NEMM. Checkpoints go
/// to `checkpoint_root/<variant>/` when given. Errors only when the data cannot train any
/// EMM-family variant (no validation windows) and when a time-boxed session ends.
pub fn train_each(
    prepared: &Prepared,
    variants: &[ModelKind],
    cfg: &PipelineConfig,
    checkpoint_root: Option<&Path>,
    resume: bool,
) -> Result<Trained> {
    check_trainable(prepared, variants, cfg)?;
    let stages = Stages::new(prepared, cfg, checkpoint_root, resume);
    let qs = &prepared.quasi_static.train;
    let mut out = Vec::new();
    let mut failed = Vec::new();
    if variants.contains(&ModelKind::Sem) {
        match train_sem(prepared, cfg, stages.meta) {
            Ok(t) => out.push(t),
            Err(e) => record(&mut failed, ModelKind::Sem, e)?,
        }
    }
    let emm_variants: Vec<ModelKind> = variants
        .iter()
        .copied()
        .filter(|v| *v != ModelKind::Sem)
        .collect();
    let done = |trained: Vec<TrainedVariant>, mut failed: Vec<VariantFailure>| {
        let order = |v: ModelKind| ModelKind::ALL.iter().position(|&w| w == v);
        let mut trained = trained;
        trained.sort_by_key(|t| order(t.variant));
        failed.sort_by_key(|f| order(f.variant));
        Trained { trained, failed }
    };
    if emm_variants.is_empty() {
        return Ok(done(out, failed));
    }
    let lin = match stages.linear(qs) {
        Ok(r) => r,
        Err(e) => {
            if e.is::<SessionBudgetUsed>() {
                return Err(e);
            }
            for &v in &emm_variants {
                let reason = if v == ModelKind::LinearEmm {
                    anyhow::anyhow!("{e:#}")
                } else {
                    anyhow::anyhow!("the Linear EMM stage it starts from failed: {e:#}")
                };
                record(&mut failed, v, reason)?;
            }
            return Ok(done(out, failed));
        }
    };
    if emm_variants.contains(&ModelKind::LinearEmm) {
        let scaled = lin_p_with_scale(&lin.trained, lin.p0.x_scale);
        match to_core_with(&scaled, stages.meta, &prepared.condition) {
            Ok(model) => out.push(TrainedVariant {
                variant: ModelKind::LinearEmm,
                model,
                history: lin.fit.history.clone(),
                val_rmse: lin.fit.best_val_rmse,
                stop: Some(lin.fit.stop),
                kept_epoch: Some(lin.fit.best_epoch),
                seconds: lin.seconds,
            }),
            Err(e) => record(&mut failed, ModelKind::LinearEmm, e)?,
        }
    }
    let neural: Vec<ModelKind> = emm_variants
        .iter()
        .copied()
        .filter(|v| matches!(v, ModelKind::NemmLight | ModelKind::Nemm))
        .collect();
    if neural.is_empty() {
        return Ok(done(out, failed));
    }
    let t_qs = Instant::now();
    let b_fl = match stages.quasi_static_b_fl(&lin.p0, qs) {
        Ok(b) => b,
        Err(e) => {
            for &v in &neural {
                let reason = anyhow::anyhow!("the quasi-static b_fl regression failed: {e:#}");
                record(&mut failed, v, reason)?;
            }
            return Ok(done(out, failed));
        }
    };
    let earlier_s = t_qs.elapsed().as_secs_f64() + lin.seconds;
    for v in neural {
        match stages.neural(v, &lin.p0, &b_fl, earlier_s) {
            Ok(t) => out.push(t),
            Err(e) => record(&mut failed, v, e)?,
        }
    }
    Ok(done(out, failed))
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
            let phi = nemm_core::static_force::features(
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

fn lin_p_with_scale(p: &RolloutParams<f32>, x_scale: f32) -> RolloutParams<f32> {
    RolloutParams {
        x_scale,
        ..p.clone()
    }
}
