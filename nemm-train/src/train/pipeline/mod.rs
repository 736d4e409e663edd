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
    loss_and_grad, simulate_x_pr, BranchShape, CumulativeShape, Grid, RolloutParams, ScalerWeights,
    StaticParams, Window,
};
use super::fit::{fit, rmse, windows, FitConfig, FitData, FitResult};
use super::history::{EpochStats, StopReason};
use super::net::EmmNet;
use super::params::to_core_with;
use super::physics::{physics_loss, PenaltyGrid};
use super::stability::StabilityHold;
use super::static_fit::{fit_residual, StaticSetup};
use crate::config::{AlphaPriors, Config, StatePriors, DEFAULT_STATIC_FORCE};
use crate::data::preprocess::{Prepared, QuasiStaticPoint};
use anyhow::{bail, Context, Result};
use nemm_core::{Integrator, Meta, Model, ModelKind, Scaler};
use nemm_kernels::mlp::{BranchLayout, Direction, ScalerLayout};
use nemm_kernels::sem::{MAX_SEM_ALPHAS, MAX_SEM_VELOCITIES};
use nemm_kernels::static_force::STATIC_PARAMS;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use sem::train_sem;
use serde::{Deserialize, Serialize};
use stages::Stages;
use std::path::Path;

mod sem;
mod stages;

pub use sem::fit_sem;

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
    /// Bounds of the `b_pr` and `k_pr` scale factors (`s_max` of `k_pr` is lowered to what
    /// the stable set at the model's step allows, `crate::train::stability`).
    pub pr_bounds: (f32, f32),
    /// Integration rate of the model \[Hz\] (the exported step is `1 / model_rate_hz`),
    /// independent of the data's sample rate.
    pub model_rate_hz: f64,
    /// How the declared priors in alpha are imposed.
    pub alpha_priors: AlphaPriors,
    /// Units `K` of each alpha branch.
    pub branch_units: usize,
    /// How the priors in the state are imposed on `b_fl` and `k_pr`.
    #[serde(default = "default_state_priors")]
    pub state_priors: StatePriors,
    /// Units `K` of each cumulative scaler.
    #[serde(default = "default_cumulative_units")]
    pub cumulative_units: usize,
    /// Adds the static force of eq. 17 to every EMM-family variant.
    pub static_force: bool,
    /// Adds the lost-motion element to every EMM-family variant.
    #[serde(default)]
    pub lost_motion: bool,
    /// Whether `b_fl` depends on alpha (the paper's `b_fl(v_st, alpha)`); `false`: the
    /// flow damping is the same at every level, so the pressure elements must form the
    /// degradation.
    #[serde(default = "yes")]
    pub b_fl_alpha: bool,
}

fn yes() -> bool {
    true
}

/// The configuration's default (for a saved pipeline configuration without the key).
fn default_state_priors() -> StatePriors {
    crate::config::ModelConfig::default().state_priors
}

/// The configuration's default (for a saved pipeline configuration without the key).
fn default_cumulative_units() -> usize {
    crate::config::ModelConfig::default().cumulative_units
}

impl PipelineConfig {
    /// The training procedure of the job `config` (its model and training parts).
    pub fn of(config: &Config) -> Self {
        let (m, t) = (&config.model, &config.train);
        PipelineConfig {
            hidden: m.hidden,
            layers: m.layers,
            integrator: m.integrator,
            fit: FitConfig::of(t, m.variant.name()),
            linear_epochs: t.linear_epochs,
            linear_lr: t.linear_lr,
            qs_steps: t.qs_steps,
            b_fl_bounds: m.b_fl_bounds,
            pr_bounds: m.pr_bounds,
            model_rate_hz: m.rate_hz,
            alpha_priors: m.alpha_priors,
            branch_units: m.branch_units,
            state_priors: m.state_priors,
            cumulative_units: m.cumulative_units,
            static_force: m.static_force.unwrap_or(DEFAULT_STATIC_FORCE),
            lost_motion: m.lost_motion,
            b_fl_alpha: m.b_fl_alpha,
        }
    }
}

/// The defaults are [`Config`]'s.
impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig::of(&Config::default())
    }
}

/// What `nemm export` needs to rebuild a model from a checkpoint folder: the initial
/// parameters (shapes, bounds, scales; the weights are replaced by the checkpoint's) and the
/// training-data facts.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct SavedFrame {
    /// Initial rollout parameters of the stage.
    pub(crate) initial: RolloutParams<f32>,
    /// Training-data facts.
    pub(crate) meta: Meta,
    /// Units of the static force's parameters in training (`None` without a static force).
    #[serde(default)]
    pub(crate) static_units: Option<[f32; STATIC_PARAMS]>,
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
        nemm_dataset::atomic_file::write_atomic_bytes(&dir.join("frame.json"), text.as_bytes())
            .with_context(|| format!("cannot write {}", dir.join("frame.json").display()))?;
    }
    Ok(())
}

/// One trained variant.
#[derive(Debug, Clone)]
pub struct TrainedVariant {
    /// Which.
    pub variant: ModelKind,
    /// The exportable model (boxed: a `Model` is about 110 KB by value, and variants are moved
    /// around in vectors and results).
    pub model: Box<Model>,
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
pub(crate) fn meta_of(prepared: &Prepared) -> Meta {
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
        cumulative: None,
    }
}

/// A freshly initialised cumulative scaler (`nemm_kernels::cumulative`) of `units` units
/// with the bounds `bounds` and gates in `direction`: unit centres uniform in the
/// normalised state `[-1, 1]` and widths `w_k` log-uniform in `[1, 30]` (drawn from
/// xoshiro256++ seeded with `seed`), each unit at 1 % of the softmax, gates at
/// `sigmoid(2)` with slopes `gamma = 0.5` in a declared direction (without one the slope is
/// `gamma` itself and starts at 0; `alpha_slope = false`: 0, where the gradient of a signed
/// slope `d gamma^2` is 0, so the scaler stays independent of alpha), and the constant part
/// set so that the scale factor starts at 1 at `x = 0`.
pub fn init_cumulative(
    units: usize,
    bounds: (f32, f32),
    direction: Direction,
    alpha_slope: bool,
    seed: u64,
) -> ScalerWeights<f32> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut uniform = move |a: f32, b: f32| rng.random_range(a..b);
    let (s_min, s_max) = bounds;
    let gate = 1.0 / (1.0 + (-2.0f32).exp());
    let p_unit = 0.01f32;
    let omega: Vec<f32> = (0..units).map(|_| uniform(0.0, 30f32.ln())).collect();
    let c: Vec<f32> = omega
        .iter()
        .map(|&om| -om.exp() * uniform(-1.0, 1.0))
        .collect();
    // At x = 0 each unit adds pi_k sech^2(c_k); the constant part makes up the rest of 1.
    let units_at_0: f32 = c
        .iter()
        .map(|&ck| p_unit * gate * (1.0 - ck.tanh().powi(2)))
        .sum();
    let target = ((1.0 - s_min) / (s_max - s_min) - units_at_0).max(1e-3);
    let p0 = (target / gate).min(0.98 - p_unit * units as f32);
    let slack = (1.0 - p0 - p_unit * units as f32).max(1e-3);
    let mut w = Vec::with_capacity(nemm_core::cumulative_param_count(units));
    w.push((p0 / slack).ln());
    w.extend(std::iter::repeat_n((p_unit / slack).ln(), units));
    w.extend(&omega);
    w.extend(&c);
    let gamma = if alpha_slope && direction != Direction::None {
        0.5
    } else {
        0.0
    };
    w.extend(std::iter::repeat_n(gamma, units + 1));
    w.extend(std::iter::repeat_n(2.0f32, units + 1));
    ScalerWeights {
        inputs: 2,
        hidden: 0,
        layers: 0,
        w,
        s_min,
        s_max,
        branch: None,
        cumulative: Some(CumulativeShape { direction, units }),
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
        .map(|&ci| 0.09 * nemm_kernels::mlp::leaky_relu(ci))
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

/// A variant that could not be trained or exported, and why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct VariantFailure {
    /// Which.
    pub(crate) variant: ModelKind,
    /// The error, with its causes.
    pub(crate) reason: String,
}

/// What [`train_each`] made of the requested variants.
#[derive(Debug, Clone)]
pub(crate) struct Trained {
    /// The variants that were trained, in the order of Table 4.
    pub(crate) trained: Vec<TrainedVariant>,
    /// The variants that failed, in the order of Table 4.
    pub(crate) failed: Vec<VariantFailure>,
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
/// error). `train_each` keeps going past failures.
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

/// Refuses data and options no EMM-family variant can be trained with.
fn check_trainable(
    prepared: &Prepared,
    variants: &[ModelKind],
    cfg: &PipelineConfig,
) -> Result<()> {
    if prepared.validation.is_empty() && variants.iter().any(|v| *v != ModelKind::Sem) {
        bail!(
            "no validation windows: the runs at the training {} levels are too short for \
             the {:.0} % validation split of their {:.2} s windows ({} training windows in all); \
             early stopping and model selection need them. Use longer or more runs, or \
             shorter windows (--window-s)",
            prepared.condition.name.as_str(),
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
pub(crate) fn train_each(
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
        match stages.linear_variant(&lin) {
            Ok(t) => out.push(t),
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
    let (b_fl, qs_seconds) = match stages.quasi_static_b_fl(&lin.p0, qs) {
        Ok(b) => b,
        Err(e) => {
            for &v in &neural {
                let reason = anyhow::anyhow!("the quasi-static b_fl regression failed: {e:#}");
                record(&mut failed, v, reason)?;
            }
            return Ok(done(out, failed));
        }
    };
    let earlier_s = qs_seconds + lin.seconds;
    for v in neural {
        match stages.neural(v, &lin.p0, &b_fl, earlier_s) {
            Ok(t) => out.push(t),
            Err(e) => record(&mut failed, v, e)?,
        }
    }
    Ok(done(out, failed))
}

#[cfg(test)]
mod config_tests {
    use super::*;

    #[test]
    fn the_procedure_defaults_are_the_configuration_defaults() {
        let p = PipelineConfig::default();
        assert_eq!(p, PipelineConfig::of(&Config::default()));
        assert_eq!(p.fit, FitConfig::default());
        assert_eq!(
            p.fit.lambda_ph,
            crate::config::TrainConfig::default().lambda_ph
        );
    }
}
