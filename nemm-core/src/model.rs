//! The model: the four variants of the paper, their normalisation and integration settings,
//! and the checks that make a decoded model safe to run.
//!
//! | kind | `b_fl` | `b_pr` | `k_pr` | state |
//! |------|--------|--------|--------|-------|
//! | [`ModelKind::Sem`] | - | - | - | none: `F = map(u, alpha)` |
//! | [`ModelKind::LinearEmm`] | `b_fl,ini` | `b_pr,ini` | `k_pr,ini` | `x_pr, v_st` |
//! | [`ModelKind::NemmLight`] | `b_fl,ini s_fl(v_st, alpha)` | `b_pr,ini` | `k_pr,ini` | `x_pr, v_st` |
//! | [`ModelKind::Nemm`] | `b_fl,ini s_fl(v_st, alpha)` | `b_pr,ini s_b(alpha)` | `k_pr,ini s_k(x_pr, alpha)` | `x_pr, v_st` |
//!
//! Each scale `s` is an MLP scaler ([`nemm_kernels::mlp`]); `s_fl` and `s_k` may instead be
//! cumulative scalers ([`Model::cumulative`], [`nemm_kernels::cumulative`]) between the same
//! bounds, whose force (`b_fl v_st`, `k_pr x_pr`) rises with the state by construction.
//!
//! # Stability check (explicit Runge-Kutta)
//!
//! With frozen coefficients the EMM has the eigenvalues `-k_pr / (b_pr + b_fl)` and
//! `-1 / T_pr`. Because every scale factor is bounded (`s_min < s < s_max`), the fastest time
//! constant the model can ever reach is
//!
//! ```text
//! tau_min = min( (b_pr,ini s_min,b + b_fl,ini s_min,fl) / (k_pr,ini s_max,k),  T_pr )
//! ```
//!
//! and a model is accepted only if `dt <= STABILITY_MARGIN * limit * tau_min`, where `limit`
//! is the real-axis stability limit of the integrator (2.785 for RK4, 2.512 for RK3). The
//! margin covers the state-dependence of the learned coefficients, which the frozen-coefficient
//! analysis does not see.

use crate::limits::{PROVENANCE_COMMAND_LEN, PROVENANCE_COMMIT_LEN, PROVENANCE_DATASET_LEN};
use nemm_kernels::emm::EmmConstants;
pub(crate) use nemm_kernels::error::ModelError;
use nemm_kernels::error::UnknownName;
use nemm_kernels::integrator::Integrator;
use nemm_kernels::limits::{MAX_CONDITION_NAME, MAX_CONDITION_UNIT, SCALE_RANGE};
use nemm_kernels::lost_motion::LostMotion;
use nemm_kernels::mlp::{AlphaBranch, BranchError, Direction, Scaler, DEFAULT_PARAM_CAPACITY};
use nemm_kernels::sem::SemMap;
use nemm_kernels::static_force::StaticForce;
use serde::{Deserialize, Serialize};

mod condition;
mod cumulative;
mod provenance;

pub use condition::{AlphaBranches, Condition, Priors};
pub use cumulative::CumulativeScalers;
pub use provenance::Provenance;

/// Fraction of the integrator's real-axis stability limit a model may use (see module docs).
pub const STABILITY_MARGIN: f32 = 0.8;

/// The shortest time constant \[s\] a model may reach to run with `integrator` at step
/// `dt_s`: `dt / (STABILITY_MARGIN * limit)` (module docs). [`Model::check_step`] accepts a
/// model whose [`Model::fastest_time_constant_s`] is at least this; the trainer holds its
/// constants there during training.
pub fn shortest_stable_time_constant_s(integrator: Integrator, dt_s: f32) -> f32 {
    dt_s / (STABILITY_MARGIN * integrator.stability_limit())
}

/// Which of the paper's four model variants (section 6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ModelKind {
    /// Static empirical model: force-velocity map per oil-loss level.
    Sem,
    /// EMM with constant `b_fl`, `b_pr`, `k_pr`, `T_pr`.
    LinearEmm,
    /// EMM with neural `b_fl(v_st, alpha)`.
    NemmLight,
    /// EMM with neural `b_fl(v_st, alpha)`, `b_pr(alpha)`, `k_pr(x_pr, alpha)`.
    Nemm,
}

impl ModelKind {
    /// The CLI / report name: `sem`, `linear-emm`, `nemm-light`, `nemm`.
    pub const fn name(self) -> &'static str {
        match self {
            ModelKind::Sem => "sem",
            ModelKind::LinearEmm => "linear-emm",
            ModelKind::NemmLight => "nemm-light",
            ModelKind::Nemm => "nemm",
        }
    }
}

impl core::str::FromStr for ModelKind {
    type Err = UnknownName;

    /// Parses [`ModelKind::name`]'s spelling.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        [
            ModelKind::Sem,
            ModelKind::LinearEmm,
            ModelKind::NemmLight,
            ModelKind::Nemm,
        ]
        .into_iter()
        .find(|k| k.name() == s)
        .ok_or(UnknownName {
            what: "model kind",
            expected: "sem, linear-emm, nemm-light or nemm",
        })
    }
}

/// Abs-max normalisation scales of the scaler inputs, from the training set (section 5.3).
/// They also bound the training domain of each input.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct InputScales {
    /// Abs-max stroke velocity of the training set \[m/s\]; scale of `v_st`.
    pub velocity_m_s: f32,
    /// Abs-max deflection `x_pr` reached on the training set \[m\]; scale of `x_pr`.
    pub x_pr_m: f32,
    /// Abs-max oil-loss level of the training set \[-\]; scale of `alpha`.
    pub alpha: f32,
}

/// Facts about the training data the model carries for reporting and range checks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Meta {
    /// Abs-max force of the training set \[N\] (normalised RMSE divides by it).
    pub force_scale_n: f32,
    /// Smallest oil-loss level in the training set.
    pub alpha_min: f32,
    /// Largest oil-loss level in the training set.
    pub alpha_max: f32,
}

/// The variant-specific part.
///
/// `Deserialize` is written by hand (the wire format is exactly the derived one: variant index,
/// then the fields in order) so that [`crate::format::decode_into`] can decode in place: a
/// derived enum would be built by value on the stack, several copies of a `Scaler<P>` deep.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum Body<const P: usize> {
    /// SEM map.
    Sem(SemMap),
    /// Linear EMM constants.
    LinearEmm(EmmConstants),
    /// NEMM-Light: constants plus the `b_fl` scaler (inputs `v_st`, `alpha`).
    NemmLight {
        /// `*_ini` constants and `T_pr`.
        emm: EmmConstants,
        /// Scaler of `b_fl`, inputs `[v_st / v_scale, alpha / alpha_scale]`.
        b_fl: Scaler<P>,
    },
    /// NEMM: constants plus three scalers.
    Nemm {
        /// `*_ini` constants and `T_pr`.
        emm: EmmConstants,
        /// Scaler of `b_fl`, inputs `[v_st / v_scale, alpha / alpha_scale]`.
        b_fl: Scaler<P>,
        /// Scaler of `b_pr`, input `[alpha / alpha_scale]`.
        b_pr: Scaler<P>,
        /// Scaler of `k_pr`, inputs `[x_pr / x_scale, alpha / alpha_scale]`.
        k_pr: Scaler<P>,
    },
}

/// A complete model. `P` is the parameter capacity per scaler (see
/// [`nemm_kernels::mlp::param_count`]); the default holds every model of the Table 3 search space.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Model<const P: usize = DEFAULT_PARAM_CAPACITY> {
    /// Integration scheme.
    pub integrator: Integrator,
    /// Step \[s\] the model was trained at (the sample period; default `1e-4`, 10 kHz).
    pub dt_s: f32,
    /// Input normalisation scales.
    pub scales: InputScales,
    /// Training-data facts.
    pub meta: Meta,
    /// Variant-specific parameters.
    pub body: Body<P>,
    /// The degradation condition `alpha` stands for and its declared priors. Format
    /// version 3 and later, encoded after the body (see [`crate::encode`]); earlier blobs
    /// decode with [`Condition::default`] (oil loss, the paper's priors).
    #[serde(skip)]
    pub condition: Condition,
    /// The alpha branches that make the declared priors hold by construction (version 3;
    /// none in earlier blobs).
    #[serde(skip)]
    pub alpha_branches: AlphaBranches,
    /// Where the weights came from (version 3; empty in earlier blobs).
    #[serde(skip)]
    pub provenance: Provenance,
    /// The static force `r` of eq. 17 (gas force and seal friction, see
    /// [`nemm_kernels::static_force`]) added to the EMM force; `None`: no static force (the
    /// paper's model). Refused on the SEM. Version 4; `None` in earlier blobs.
    #[serde(skip)]
    pub static_force: Option<StaticForce>,
    /// The lost-motion element ([`nemm_kernels::lost_motion`]): free gas in series with
    /// `k_pr`, whose travel grows with `alpha`; `None`: the paper's `k_pr`. Refused on the
    /// SEM. Version 5; `None` in earlier blobs.
    #[serde(skip)]
    pub lost_motion: Option<LostMotion>,
    /// The cumulative scalers of `b_fl` and `k_pr` ([`CumulativeScalers`]): coefficients
    /// whose force rises with their state by construction, in place of their MLP's scale.
    /// Version 7; none in earlier blobs.
    #[serde(skip)]
    pub cumulative: CumulativeScalers,
}

fn finite_positive(v: f32, field: &'static str) -> Result<(), ModelError> {
    if !v.is_finite() {
        Err(ModelError::NonFinite { field })
    } else if v <= 0.0 {
        Err(ModelError::NotPositive { field })
    } else {
        Ok(())
    }
}

fn check_emm(e: &EmmConstants) -> Result<(), ModelError> {
    finite_positive(e.b_fl_ns_per_m, "emm.b_fl_ns_per_m")?;
    finite_positive(e.b_pr_ns_per_m, "emm.b_pr_ns_per_m")?;
    finite_positive(e.k_pr_n_per_m, "emm.k_pr_n_per_m")?;
    finite_positive(e.t_pr_s, "emm.t_pr_s")
}

/// Checks a scaler of the body with `inputs` inputs; `cumulative`: whether the coefficient
/// has a cumulative scaler, beside which the MLP must have no weights (its own checks are
/// [`CumulativeScalers::validate`]'s).
fn check_scaler<const P: usize>(
    s: &Scaler<P>,
    name: &'static str,
    inputs: u8,
    cumulative: bool,
) -> Result<(), ModelError> {
    if cumulative {
        if !s.mlp.is_without_weights() {
            return Err(ModelError::Cumulative {
                scaler: name,
                error: nemm_kernels::error::CumulativeModelError::MlpWeights,
            });
        }
    } else {
        s.mlp.check_shape().map_err(|error| ModelError::Shape {
            scaler: name,
            error,
        })?;
    }
    if s.mlp.inputs != inputs {
        return Err(ModelError::WrongInputCount {
            scaler: name,
            expected: inputs,
            found: s.mlp.inputs,
        });
    }
    if s.mlp.params.iter().any(|p| !p.is_finite()) {
        return Err(ModelError::NonFinite { field: name });
    }
    if !(s.s_min.is_finite() && s.s_max.is_finite() && s.s_min > 0.0 && s.s_max > s.s_min) {
        return Err(ModelError::BadScalerBounds { scaler: name });
    }
    Ok(())
}

impl<const P: usize> Model<P> {
    /// A placeholder model (an empty SEM map, not valid) to decode into with
    /// [`crate::format::decode_into`]; `const`, so it can initialise a `static`.
    pub const fn empty() -> Self {
        Self::EMPTY
    }

    /// The value of [`Model::empty`] (a constant: an unoptimised build copies it rather than
    /// building it on the stack). All its bytes are zero (or uninitialised vector storage),
    /// so that filling a `static` with it is a `memset`, not a copy from flash.
    const EMPTY: Self = Self {
        integrator: Integrator::Rk4,
        dt_s: 0.0,
        scales: InputScales {
            velocity_m_s: 0.0,
            x_pr_m: 0.0,
            alpha: 0.0,
        },
        meta: Meta {
            force_scale_n: 0.0,
            alpha_min: 0.0,
            alpha_max: 0.0,
        },
        body: Body::Sem(SemMap::empty()),
        condition: Condition {
            name: heapless::String::new(),
            unit: heapless::String::new(),
            at_alpha_0: 0.0,
            at_alpha_1: 1.0,
            priors: Priors::PAPER,
        },
        alpha_branches: AlphaBranches {
            b_fl: None,
            b_pr: None,
            k_pr: None,
        },
        provenance: Provenance::empty(),
        static_force: None,
        lost_motion: None,
        cumulative: CumulativeScalers::NONE,
    };

    /// A model of the paper's kind: the oil-loss condition with the paper's priors
    /// ([`Condition::default`]), no alpha branches, no provenance, no static force, no
    /// lost motion, no cumulative scalers. Set those fields to declare more.
    pub fn new(
        integrator: Integrator,
        dt_s: f32,
        scales: InputScales,
        meta: Meta,
        body: Body<P>,
    ) -> Self {
        Self {
            integrator,
            dt_s,
            scales,
            meta,
            body,
            condition: Condition::default(),
            alpha_branches: AlphaBranches::default(),
            provenance: Provenance::empty(),
            static_force: None,
            lost_motion: None,
            cumulative: CumulativeScalers::default(),
        }
    }

    /// The variant.
    pub fn kind(&self) -> ModelKind {
        match self.body {
            Body::Sem(_) => ModelKind::Sem,
            Body::LinearEmm(_) => ModelKind::LinearEmm,
            Body::NemmLight { .. } => ModelKind::NemmLight,
            Body::Nemm { .. } => ModelKind::Nemm,
        }
    }

    /// EMM constants (`None` for the SEM).
    pub fn emm(&self) -> Option<&EmmConstants> {
        match &self.body {
            Body::Sem(_) => None,
            Body::LinearEmm(e) | Body::NemmLight { emm: e, .. } | Body::Nemm { emm: e, .. } => {
                Some(e)
            }
        }
    }

    /// Largest parameter count of any scaler, an MLP's or a cumulative scaler's (0 without
    /// scalers).
    pub fn max_scaler_params(&self) -> usize {
        let mlp = match &self.body {
            Body::Sem(_) | Body::LinearEmm(_) => 0,
            Body::NemmLight { b_fl, .. } => b_fl.mlp.params.len(),
            Body::Nemm {
                b_fl, b_pr, k_pr, ..
            } => b_fl
                .mlp
                .params
                .len()
                .max(b_pr.mlp.params.len())
                .max(k_pr.mlp.params.len()),
        };
        mlp.max(self.cumulative.max_params())
    }

    /// Fastest time constant \[s\] the model can reach over all scaler outputs (module docs);
    /// `None` for the SEM, which has no dynamics.
    pub fn fastest_time_constant_s(&self) -> Option<f32> {
        let (e, fl, bp, k) = match &self.body {
            Body::Sem(_) => return None,
            Body::LinearEmm(e) => (e, 1.0, 1.0, 1.0),
            Body::NemmLight { emm, b_fl } => (emm, b_fl.s_min, 1.0, 1.0),
            Body::Nemm {
                emm,
                b_fl,
                b_pr,
                k_pr,
            } => (emm, b_fl.s_min, b_pr.s_min, k_pr.s_max),
        };
        let tau_pr = (e.b_pr_ns_per_m * bp + e.b_fl_ns_per_m * fl) / (e.k_pr_n_per_m * k);
        // Not `f32::min`, which would hide a NaN.
        Some(if tau_pr.is_nan() || tau_pr > e.t_pr_s {
            if tau_pr.is_nan() {
                f32::NAN
            } else {
                e.t_pr_s
            }
        } else {
            tau_pr
        })
    }

    /// Checks that the model is safe to run with `integrator` at step `dt_s`: every
    /// [`ModelError`] case.
    pub fn check_step(&self, integrator: Integrator, dt_s: f32) -> Result<(), ModelError> {
        finite_positive(dt_s, "dt_s")?;
        if let Some(tau_min_s) = self.fastest_time_constant_s() {
            // A NaN or infinite time constant (coefficients near f32::MAX) is not stable.
            let tau_min_s = if tau_min_s.is_finite() {
                tau_min_s
            } else {
                0.0
            };
            let max_dt_s = STABILITY_MARGIN * integrator.stability_limit() * tau_min_s;
            if max_dt_s.is_nan() || dt_s > max_dt_s {
                return Err(ModelError::UnstableStep {
                    dt_s,
                    tau_min_s,
                    max_dt_s,
                    integrator: integrator.name(),
                });
            }
        }
        Ok(())
    }

    /// Full validation: finiteness, positivity, shapes, SEM grid, alpha range, stability.
    pub fn validate(&self) -> Result<(), ModelError> {
        for (v, field) in [
            (self.scales.velocity_m_s, "scales.velocity_m_s"),
            (self.scales.x_pr_m, "scales.x_pr_m"),
            (self.scales.alpha, "scales.alpha"),
            (self.meta.force_scale_n, "meta.force_scale_n"),
        ] {
            finite_positive(v, field)?;
            // Normalisation divides by the scales: keep them far from under- and overflow.
            if !(SCALE_RANGE.0..=SCALE_RANGE.1).contains(&v) {
                return Err(ModelError::OutOfRange { field });
            }
        }
        let (a0, a1) = (self.meta.alpha_min, self.meta.alpha_max);
        if !(a0.is_finite() && a1.is_finite() && 0.0 <= a0 && a0 <= a1 && a1 <= 1.0) {
            return Err(ModelError::AlphaRange);
        }
        match &self.body {
            Body::Sem(m) => m.validate().map_err(ModelError::Sem)?,
            Body::LinearEmm(e) => check_emm(e)?,
            Body::NemmLight { emm, b_fl } => {
                check_emm(emm)?;
                check_scaler(b_fl, "b_fl", 2, self.cumulative.b_fl.is_some())?;
            }
            Body::Nemm {
                emm,
                b_fl,
                b_pr,
                k_pr,
            } => {
                check_emm(emm)?;
                check_scaler(b_fl, "b_fl", 2, self.cumulative.b_fl.is_some())?;
                check_scaler(b_pr, "b_pr", 1, false)?;
                check_scaler(k_pr, "k_pr", 2, self.cumulative.k_pr.is_some())?;
            }
        }
        self.condition.validate()?;
        self.provenance.validate()?;
        if let Some(s) = &self.static_force {
            s.validate()?;
        }
        self.alpha_branches
            .validate(&self.body, &self.condition.priors)?;
        self.cumulative
            .validate(&self.body, &self.condition.priors, &self.alpha_branches)?;
        if self.static_force.is_some() && matches!(self.body, Body::Sem(_)) {
            return Err(ModelError::StaticForceOnSem);
        }
        if let Some(l) = &self.lost_motion {
            l.validate()?;
            if matches!(self.body, Body::Sem(_)) {
                return Err(ModelError::LostMotionOnSem);
            }
        }
        self.check_step(self.integrator, self.dt_s)
    }

    /// `b_fl` \[N s/m\] at `v_st` \[m/s\] and `alpha` by the reference (unfolded) path:
    /// with a cumulative scaler `b_fl,ini s(v_st / v_scale, alpha / alpha_scale)` between the
    /// body's scaler bounds
    /// ([`nemm_kernels::cumulative::CumulativeScaler::scale`]).
    pub fn b_fl(&self, v_st_m_s: f32, alpha: f32) -> Option<f32> {
        match &self.body {
            Body::Sem(_) => None,
            Body::LinearEmm(e) => Some(e.b_fl_ns_per_m),
            Body::NemmLight { emm, b_fl } | Body::Nemm { emm, b_fl, .. } => {
                if let Some(c) = &self.cumulative.b_fl {
                    let x = v_st_m_s / self.scales.velocity_m_s;
                    let s = c.scale(x, alpha / self.scales.alpha, b_fl.s_min, b_fl.s_max)?;
                    return Some(emm.b_fl_ns_per_m * s);
                }
                let x = [
                    v_st_m_s / self.scales.velocity_m_s,
                    alpha / self.scales.alpha,
                ];
                Some(emm.b_fl_ns_per_m * b_fl.scale_with(&x, self.alpha_branches.b_fl.as_ref())?)
            }
        }
    }

    /// `b_pr` \[N s/m\] at `alpha` by the reference path.
    pub fn b_pr(&self, alpha: f32) -> Option<f32> {
        match &self.body {
            Body::Sem(_) => None,
            Body::LinearEmm(e) | Body::NemmLight { emm: e, .. } => Some(e.b_pr_ns_per_m),
            Body::Nemm { emm, b_pr, .. } => Some(
                emm.b_pr_ns_per_m
                    * b_pr.scale_with(
                        &[alpha / self.scales.alpha],
                        self.alpha_branches.b_pr.as_ref(),
                    )?,
            ),
        }
    }

    /// The pressure pair's stiffness \[N/m\] at `x_pr` \[m\] and `alpha` by the reference
    /// path: [`Model::k_pr`], through the lost-motion element's secant stiffness if the
    /// model has one.
    pub fn k_pr_eff(&self, x_pr_m: f32, alpha: f32) -> Option<f32> {
        let k = self.k_pr(x_pr_m, alpha)?;
        Some(match &self.lost_motion {
            None => k,
            Some(l) => l.at(alpha).k_eff(k, x_pr_m),
        })
    }

    /// `k_pr` \[N/m\] at `x_pr` \[m\] and `alpha` by the reference path (the liquid
    /// stiffness `k_l` of a model with a lost-motion element); with a cumulative scaler
    /// `k_pr,ini s(x_pr / x_scale, alpha / alpha_scale)` as for [`Model::b_fl`].
    pub fn k_pr(&self, x_pr_m: f32, alpha: f32) -> Option<f32> {
        match &self.body {
            Body::Sem(_) => None,
            Body::LinearEmm(e) | Body::NemmLight { emm: e, .. } => Some(e.k_pr_n_per_m),
            Body::Nemm { emm, k_pr, .. } => {
                if let Some(c) = &self.cumulative.k_pr {
                    let x = x_pr_m / self.scales.x_pr_m;
                    let s = c.scale(x, alpha / self.scales.alpha, k_pr.s_min, k_pr.s_max)?;
                    return Some(emm.k_pr_n_per_m * s);
                }
                let x = [x_pr_m / self.scales.x_pr_m, alpha / self.scales.alpha];
                Some(emm.k_pr_n_per_m * k_pr.scale_with(&x, self.alpha_branches.k_pr.as_ref())?)
            }
        }
    }
}

mod body_serde;

#[cfg(test)]
mod name_tests {
    use super::*;

    #[test]
    fn model_kinds_parse_from_their_names_only() {
        for k in [
            ModelKind::Sem,
            ModelKind::LinearEmm,
            ModelKind::NemmLight,
            ModelKind::Nemm,
        ] {
            assert_eq!(k.name().parse::<ModelKind>(), Ok(k));
        }
        let err = "linear_emm".parse::<ModelKind>().unwrap_err();
        assert_eq!(err.what, "model kind");
        assert!(err.expected.contains("linear-emm"));
        assert!("NEMM".parse::<ModelKind>().is_err());
    }
}
