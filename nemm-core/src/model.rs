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

use crate::emm::EmmConstants;
pub use crate::error::ModelError;
use crate::error::UnknownName;
use crate::integrator::Integrator;
pub use crate::limits::{
    MAX_CONDITION_NAME, MAX_CONDITION_UNIT, PROVENANCE_COMMAND_LEN, PROVENANCE_COMMIT_LEN,
    PROVENANCE_DATASET_LEN, SCALE_RANGE,
};
use crate::mlp::{AlphaBranch, BranchError, Direction, Scaler, DEFAULT_PARAM_CAPACITY};
use crate::sem::SemMap;
use crate::static_force::StaticForce;
use serde::{Deserialize, Serialize};

/// Fraction of the integrator's real-axis stability limit a model may use (see module docs).
pub const STABILITY_MARGIN: f32 = 0.8;

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
/// [`crate::mlp::param_count`]); the default holds every model of the Table 3 search space.
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
    /// version 3 and later, encoded after the body (see [`crate::format`]); earlier blobs
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
    /// [`crate::static_force`]) added to the EMM force; `None`: no static force (the
    /// paper's model). Refused on the SEM. Version 4; `None` in earlier blobs.
    #[serde(skip)]
    pub static_force: Option<StaticForce>,
}

/// Where a model came from, recorded by the exporter: free text for people and tools
/// (`nemm inspect` prints it); the estimator never reads it. Each field is printable: no
/// control characters (so each prints as one line). Empty means unknown.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Provenance {
    /// The command that trained and exported the model.
    pub command: heapless::String<PROVENANCE_COMMAND_LEN>,
    /// The training data: a dataset path or a description of a generated dataset.
    pub dataset: heapless::String<PROVENANCE_DATASET_LEN>,
    /// The source revision of the trainer (e.g. a git commit).
    pub commit: heapless::String<PROVENANCE_COMMIT_LEN>,
}

impl Provenance {
    /// No provenance recorded.
    pub const fn empty() -> Self {
        Self {
            command: heapless::String::new(),
            dataset: heapless::String::new(),
            commit: heapless::String::new(),
        }
    }

    /// A provenance with each text cut to its field's capacity (at a character boundary)
    /// and control characters replaced by spaces, so that it always validates.
    pub fn new(command: &str, dataset: &str, commit: &str) -> Self {
        fn fit<const N: usize>(s: &str) -> heapless::String<N> {
            let mut out = heapless::String::new();
            for c in s.chars() {
                let c = if c.is_control() { ' ' } else { c };
                if out.push(c).is_err() {
                    break;
                }
            }
            out
        }
        Self {
            command: fit(command),
            dataset: fit(dataset),
            commit: fit(commit),
        }
    }

    /// True if nothing is recorded.
    pub fn is_empty(&self) -> bool {
        self.command.is_empty() && self.dataset.is_empty() && self.commit.is_empty()
    }

    /// Checks that no field holds a control character.
    pub fn validate(&self) -> Result<(), ModelError> {
        for (text, field) in [
            (self.command.as_str(), "provenance.command"),
            (self.dataset.as_str(), "provenance.dataset"),
            (self.commit.as_str(), "provenance.commit"),
        ] {
            if text.chars().any(char::is_control) {
                return Err(ModelError::ControlCharacter { field });
            }
        }
        Ok(())
    }
}

/// The declared direction of each coefficient's monotonicity prior in `alpha` (the second
/// conditions of eqs. 31, 37 and 38).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Priors {
    /// Direction of `b_fl` in `alpha`.
    pub b_fl: Direction,
    /// Direction of `b_pr` in `alpha`.
    pub b_pr: Direction,
    /// Direction of `k_pr` in `alpha`.
    pub k_pr: Direction,
}

impl Priors {
    /// The paper's priors: every coefficient decreases with oil loss.
    pub const PAPER: Priors = Priors {
        b_fl: Direction::Decreasing,
        b_pr: Direction::Decreasing,
        k_pr: Direction::Decreasing,
    };

    /// `[b_fl, b_pr, k_pr]`.
    pub const fn all(&self) -> [Direction; 3] {
        [self.b_fl, self.b_pr, self.k_pr]
    }
}

impl Default for Priors {
    fn default() -> Self {
        Self::PAPER
    }
}

/// The degradation condition the model's `alpha` in `[0, 1]` stands for (named by the
/// dataset's manifest): its name and unit, the linear map from `alpha` to the user's unit,
/// and the declared priors in `alpha`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Condition {
    /// Name, e.g. `oil loss`, `gas charge` (at most [`MAX_CONDITION_NAME`] bytes, not
    /// empty).
    pub name: heapless::String<MAX_CONDITION_NAME>,
    /// Unit of the condition value, e.g. `-`, `psi` (at most [`MAX_CONDITION_UNIT`] bytes).
    pub unit: heapless::String<MAX_CONDITION_UNIT>,
    /// Condition value (in `unit`) at `alpha = 0`.
    pub at_alpha_0: f32,
    /// Condition value (in `unit`) at `alpha = 1`; differs from `at_alpha_0`.
    pub at_alpha_1: f32,
    /// Declared monotonicity priors in `alpha`.
    pub priors: Priors,
}

impl Default for Condition {
    /// The paper's condition: oil loss as a fraction (`alpha` itself), every coefficient
    /// decreasing with it.
    fn default() -> Self {
        let mut name = heapless::String::new();
        let _ = name.push_str("oil loss");
        let mut unit = heapless::String::new();
        let _ = unit.push('-');
        Self {
            name,
            unit,
            at_alpha_0: 0.0,
            at_alpha_1: 1.0,
            priors: Priors::PAPER,
        }
    }
}

impl Condition {
    /// A validated condition; a name or unit longer than [`MAX_CONDITION_NAME`] /
    /// [`MAX_CONDITION_UNIT`] bytes is refused like an empty name.
    pub fn new(
        name: &str,
        unit: &str,
        at_alpha_0: f32,
        at_alpha_1: f32,
        priors: Priors,
    ) -> Result<Self, ModelError> {
        let c = Self {
            name: heapless::String::try_from(name).map_err(|_| ModelError::Condition {
                field: "condition.name",
            })?,
            unit: heapless::String::try_from(unit).map_err(|_| ModelError::Condition {
                field: "condition.unit",
            })?,
            at_alpha_0,
            at_alpha_1,
            priors,
        };
        c.validate()?;
        Ok(c)
    }

    /// The condition value (in [`Condition::unit`]) at `alpha`.
    pub fn value_at(&self, alpha: f32) -> f32 {
        self.at_alpha_0 + (self.at_alpha_1 - self.at_alpha_0) * alpha
    }

    /// Checks: a non-empty name, finite and distinct end points.
    pub fn validate(&self) -> Result<(), ModelError> {
        if self.name.is_empty() {
            return Err(ModelError::Condition {
                field: "condition.name",
            });
        }
        for (v, field) in [
            (self.at_alpha_0, "condition.at_alpha_0"),
            (self.at_alpha_1, "condition.at_alpha_1"),
        ] {
            if !v.is_finite() {
                return Err(ModelError::NonFinite { field });
            }
        }
        let span = self.at_alpha_1 - self.at_alpha_0;
        if !(span.is_finite() && span != 0.0) {
            return Err(ModelError::Condition {
                field: "condition.at_alpha_1",
            });
        }
        Ok(())
    }
}

/// The alpha branches ([`AlphaBranch`]) of the three neural coefficients; `None` where the
/// coefficient's dependence on `alpha` is its MLP's own (no prior, or a penalty only).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct AlphaBranches {
    /// Branch of `b_fl(v_st, alpha)` (one state input).
    pub b_fl: Option<AlphaBranch>,
    /// Branch of `b_pr(alpha)` (no state input).
    pub b_pr: Option<AlphaBranch>,
    /// Branch of `k_pr(x_pr, alpha)` (one state input).
    pub k_pr: Option<AlphaBranch>,
}

impl AlphaBranches {
    /// Checks every branch against the model: its own shape and values, the scaler it
    /// belongs to (present, alpha column zero), its number of state inputs and its
    /// direction against the declared `priors`.
    pub fn validate<const P: usize>(
        &self,
        body: &Body<P>,
        priors: &Priors,
    ) -> Result<(), ModelError> {
        let (fl, bp, k) = match body {
            Body::Sem(_) | Body::LinearEmm(_) => (None, None, None),
            Body::NemmLight { b_fl, .. } => (Some(b_fl), None, None),
            Body::Nemm {
                b_fl, b_pr, k_pr, ..
            } => (Some(b_fl), Some(b_pr), Some(k_pr)),
        };
        for (branch, scaler, name, state, dir) in [
            (&self.b_fl, fl, "b_fl", 1u8, priors.b_fl),
            (&self.b_pr, bp, "b_pr", 0, priors.b_pr),
            (&self.k_pr, k, "k_pr", 1, priors.k_pr),
        ] {
            let Some(b) = branch else { continue };
            let err = |error| ModelError::Branch {
                scaler: name,
                error,
            };
            b.check().map_err(err)?;
            let Some(s) = scaler else {
                return Err(err(BranchError::NoScaler));
            };
            if b.state_inputs != state {
                return Err(err(BranchError::WrongStateInputs { expected: state }));
            }
            if b.direction != dir {
                return Err(err(BranchError::DirectionMismatch));
            }
            if s.alpha_column_max_abs() != 0.0 {
                return Err(err(BranchError::AlphaColumnNotZero));
            }
        }
        Ok(())
    }
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

fn check_scaler<const P: usize>(
    s: &Scaler<P>,
    name: &'static str,
    inputs: u8,
) -> Result<(), ModelError> {
    s.mlp.check_shape().map_err(|error| ModelError::Shape {
        scaler: name,
        error,
    })?;
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
    };

    /// A model of the paper's kind: the oil-loss condition with the paper's priors
    /// ([`Condition::default`]), no alpha branches, no provenance, no static force. Set
    /// those fields to declare more.
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

    /// Largest parameter count of any scaler (0 without scalers).
    pub fn max_scaler_params(&self) -> usize {
        match &self.body {
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
        }
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
                check_scaler(b_fl, "b_fl", 2)?;
            }
            Body::Nemm {
                emm,
                b_fl,
                b_pr,
                k_pr,
            } => {
                check_emm(emm)?;
                check_scaler(b_fl, "b_fl", 2)?;
                check_scaler(b_pr, "b_pr", 1)?;
                check_scaler(k_pr, "k_pr", 2)?;
            }
        }
        self.condition.validate()?;
        self.provenance.validate()?;
        if let Some(s) = &self.static_force {
            s.validate()?;
        }
        self.alpha_branches
            .validate(&self.body, &self.condition.priors)?;
        if self.static_force.is_some() && matches!(self.body, Body::Sem(_)) {
            return Err(ModelError::StaticForceOnSem);
        }
        self.check_step(self.integrator, self.dt_s)
    }

    /// `b_fl` \[N s/m\] at `v_st` \[m/s\] and `alpha` by the reference (unfolded) path.
    pub fn b_fl(&self, v_st_m_s: f32, alpha: f32) -> Option<f32> {
        match &self.body {
            Body::Sem(_) => None,
            Body::LinearEmm(e) => Some(e.b_fl_ns_per_m),
            Body::NemmLight { emm, b_fl } | Body::Nemm { emm, b_fl, .. } => {
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

    /// `k_pr` \[N/m\] at `x_pr` \[m\] and `alpha` by the reference path.
    pub fn k_pr(&self, x_pr_m: f32, alpha: f32) -> Option<f32> {
        match &self.body {
            Body::Sem(_) => None,
            Body::LinearEmm(e) | Body::NemmLight { emm: e, .. } => Some(e.k_pr_n_per_m),
            Body::Nemm { emm, k_pr, .. } => {
                let x = [x_pr_m / self.scales.x_pr_m, alpha / self.scales.alpha];
                Some(emm.k_pr_n_per_m * k_pr.scale_with(&x, self.alpha_branches.k_pr.as_ref())?)
            }
        }
    }
}

mod body_serde {
    //! In-place deserialization of [`Body`] (see its docs).
    use super::Body;
    use crate::emm::EmmConstants;
    use crate::mlp::Scaler;
    use crate::sem::SemMap;
    use core::fmt;
    use serde::de::{
        self, DeserializeSeed, Deserializer, EnumAccess, SeqAccess, VariantAccess, Visitor,
    };
    use serde::Deserialize;

    const VARIANTS: &[&str] = &["Sem", "LinearEmm", "NemmLight", "Nemm"];
    const LIGHT_FIELDS: &[&str] = &["emm", "b_fl"];
    const NEMM_FIELDS: &[&str] = &["emm", "b_fl", "b_pr", "k_pr"];
    const ZERO: EmmConstants = EmmConstants {
        b_fl_ns_per_m: 0.0,
        b_pr_ns_per_m: 0.0,
        k_pr_n_per_m: 0.0,
        t_pr_s: 0.0,
    };

    /// The empty scaler of a variant switch. An unoptimised build copies the constant into
    /// place (a call's result would be one more copy on the stack); an optimised build writes
    /// the few fields of an inlined constructor in place (the constant would be copied through
    /// the stack).
    #[cfg(debug_assertions)]
    macro_rules! empty_scaler {
        () => {
            Scaler::EMPTY
        };
    }

    #[cfg(not(debug_assertions))]
    macro_rules! empty_scaler {
        () => {
            Scaler {
                mlp: crate::mlp::MlpParams {
                    inputs: 0,
                    hidden: 0,
                    layers: 0,
                    params: heapless::Vec::new(),
                },
                s_min: 0.0,
                s_max: 0.0,
            }
        };
    }

    // The variant switches, each out of line: an unoptimised build gives every temporary its
    // own stack slot, so inside the visitor the three would add up; here only the one in use
    // is on the stack. An optimised build writes the tag and the vector lengths in place.

    #[inline(never)]
    fn switch_to_sem<const P: usize>(place: &mut Body<P>) {
        *place = Body::Sem(SemMap::empty());
    }

    #[inline(never)]
    fn switch_to_linear_emm<const P: usize>(place: &mut Body<P>) {
        *place = Body::LinearEmm(ZERO);
    }

    #[inline(never)]
    fn switch_to_nemm_light<const P: usize>(place: &mut Body<P>) {
        *place = Body::NemmLight {
            emm: ZERO,
            b_fl: empty_scaler!(),
        };
    }

    #[inline(never)]
    fn switch_to_nemm<const P: usize>(place: &mut Body<P>) {
        *place = Body::Nemm {
            emm: ZERO,
            b_fl: empty_scaler!(),
            b_pr: empty_scaler!(),
            k_pr: empty_scaler!(),
        };
    }

    /// Deserializes a value into an existing place.
    struct InPlace<'a, T>(&'a mut T);

    impl<'de, T: Deserialize<'de>> DeserializeSeed<'de> for InPlace<'_, T> {
        type Value = ();
        fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            T::deserialize_in_place(d, self.0)
        }
    }

    /// Fills the fields of a struct variant in order.
    struct Fields<'a, const P: usize> {
        emm: &'a mut EmmConstants,
        scalers: [Option<&'a mut Scaler<P>>; 3],
    }

    impl<'de, const P: usize> Visitor<'de> for Fields<'_, P> {
        type Value = ();
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("the fields of a NEMM body")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
            let n = 1 + self.scalers.iter().filter(|s| s.is_some()).count();
            if seq.next_element_seed(InPlace(self.emm))?.is_none() {
                return Err(de::Error::invalid_length(0, &self));
            }
            let mut i = 1;
            for s in self.scalers.into_iter().flatten() {
                if seq.next_element_seed(InPlace(s))?.is_none() {
                    return Err(de::Error::invalid_length(i, &"the fields of a NEMM body"));
                }
                i += 1;
            }
            debug_assert_eq!(i, n);
            Ok(())
        }
    }

    struct BodyVisitor<'a, const P: usize>(&'a mut Body<P>);

    impl<'de, const P: usize> Visitor<'de> for BodyVisitor<'_, P> {
        type Value = ();
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("a NEMM model body")
        }
        fn visit_enum<A: EnumAccess<'de>>(self, data: A) -> Result<(), A::Error> {
            let (idx, variant) = data.variant::<u32>()?;
            let place = self.0;
            // Switch the place to the variant first (cheap: empty vectors), then fill its
            // fields where they are.
            match idx {
                0 => {
                    if !matches!(place, Body::Sem(_)) {
                        switch_to_sem(place);
                    }
                    match place {
                        Body::Sem(m) => variant.newtype_variant_seed(InPlace(m)),
                        _ => Err(de::Error::custom("variant switch")),
                    }
                }
                1 => {
                    if !matches!(place, Body::LinearEmm(_)) {
                        switch_to_linear_emm(place);
                    }
                    match place {
                        Body::LinearEmm(e) => variant.newtype_variant_seed(InPlace(e)),
                        _ => Err(de::Error::custom("variant switch")),
                    }
                }
                2 => {
                    if !matches!(place, Body::NemmLight { .. }) {
                        switch_to_nemm_light(place);
                    }
                    match place {
                        Body::NemmLight { emm, b_fl } => variant.struct_variant(
                            LIGHT_FIELDS,
                            Fields {
                                emm,
                                scalers: [Some(b_fl), None, None],
                            },
                        ),
                        _ => Err(de::Error::custom("variant switch")),
                    }
                }
                3 => {
                    if !matches!(place, Body::Nemm { .. }) {
                        switch_to_nemm(place);
                    }
                    match place {
                        Body::Nemm {
                            emm,
                            b_fl,
                            b_pr,
                            k_pr,
                        } => variant.struct_variant(
                            NEMM_FIELDS,
                            Fields {
                                emm,
                                scalers: [Some(b_fl), Some(b_pr), Some(k_pr)],
                            },
                        ),
                        _ => Err(de::Error::custom("variant switch")),
                    }
                }
                other => Err(de::Error::invalid_value(
                    de::Unexpected::Unsigned(u64::from(other)),
                    &"variant index 0 <= i < 4",
                )),
            }
        }
    }

    impl<'de, const P: usize> Deserialize<'de> for Body<P> {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            let mut b = Body::LinearEmm(ZERO);
            Self::deserialize_in_place(d, &mut b)?;
            Ok(b)
        }

        fn deserialize_in_place<D: Deserializer<'de>>(
            d: D,
            place: &mut Self,
        ) -> Result<(), D::Error> {
            d.deserialize_enum("Body", VARIANTS, BodyVisitor(place))
        }
    }
}

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
