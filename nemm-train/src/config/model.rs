//! The model section ([`ModelConfig`], `[model]` of a configuration, and its command-line
//! options [`ModelOptions`]): variant, scaler size, integrator and model elements.

use super::args::with_default;
use super::section::section;
use nemm_core::{Integrator, ModelKind};
use serde::{Deserialize, Serialize};

/// How the declared monotonicity priors in alpha (eqs. 31, 37-38, second conditions) are
/// imposed on the neural coefficients.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum AlphaPriors {
    /// An alpha branch per coefficient with a declared direction
    /// (`nemm_kernels::mlp::AlphaBranch`): monotone in alpha for every weight; the physics
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

/// How the monotonicity priors in the state (eqs. 30-31 and 37-38, first conditions: the
/// flow force rising with `v_st`, the spring force rising with `x_pr`) are imposed on
/// `b_fl` and `k_pr`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum StatePriors {
    /// Cumulative scalers (`nemm_kernels::cumulative`): the force is the integral of a
    /// bounded positive incremental coefficient, so it rises with the state for every
    /// weight; the penalty keeps no state term.
    Construction,
    /// The paper's MLP scalers with the physics penalty (section 5.2), checked by the audit.
    Penalty,
}

impl StatePriors {
    /// `construction` or `penalty`.
    pub const fn name(self) -> &'static str {
        match self {
            StatePriors::Construction => "construction",
            StatePriors::Penalty => "penalty",
        }
    }
}

impl std::str::FromStr for StatePriors {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "construction" => Ok(StatePriors::Construction),
            "penalty" => Ok(StatePriors::Penalty),
            other => Err(format!(
                "unknown state-priors mode `{other}` (expected construction or penalty)"
            )),
        }
    }
}

/// Serde of `ModelKind` / `Integrator` / [`AlphaPriors`] / [`StatePriors`] by their
/// `name()` (the CLI spelling).
mod by_name {
    use serde::{Deserialize, Deserializer, Serializer};
    use std::fmt::Display;
    use std::str::FromStr;

    pub(crate) trait Named: FromStr {
        fn name_of(&self) -> &'static str;
    }
    impl Named for nemm_core::ModelKind {
        fn name_of(&self) -> &'static str {
            self.name()
        }
    }
    impl Named for nemm_core::Integrator {
        fn name_of(&self) -> &'static str {
            self.name()
        }
    }
    impl Named for super::AlphaPriors {
        fn name_of(&self) -> &'static str {
            self.name()
        }
    }
    impl Named for super::StatePriors {
        fn name_of(&self) -> &'static str {
            self.name()
        }
    }

    pub(crate) fn serialize<T: Named, S: Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(v.name_of())
    }

    pub(crate) fn deserialize<'de, T, D>(d: D) -> Result<T, D::Error>
    where
        T: Named,
        T::Err: Display,
        D: Deserializer<'de>,
    {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// The default model rate \[Hz\]: the firmware's 10 kHz step.
pub(crate) const DEFAULT_MODEL_RATE_HZ: f64 = 10_000.0;

/// Whether the EMM-family variants get the static force when neither the options nor the
/// data decide ([`super::Config::with_static_force_from`]).
pub(crate) const DEFAULT_STATIC_FORCE: bool = false;

section! {
    /// The model: variant, scaler size, integrator and the model elements (`[model]` of a
    /// configuration file). Absent keys take the defaults ([`ModelConfig::default`]).
    pub struct ModelConfig;
    /// The model options of the command line: each given one overrides its field of a
    /// [`ModelConfig`] ([`ModelOptions::over`]); the keys without an option (`variant`,
    /// which `nemm train --variant` sets, `b_fl_bounds`, `pr_bounds`, `branch_units`) are
    /// set in a `--config` file.
    pub struct ModelOptions;

    /// ModelKind `nemm train` trains (`nemm compare` trains all four).
    #[serde(with = "by_name")]
    #[arg(skip)]
    variant: ModelKind = ModelKind::Nemm, Option<ModelKind>;
    /// Hidden width H of every scaler (Table 3: 8, 16, 32).
    #[arg(long, help = with_default(
        "Hidden width H of the scalers (Table 3: 8, 16, 32)", ModelConfig::default().hidden))]
    hidden: usize = 16, Option<usize>;
    /// Hidden layers L of every scaler (Table 3: 3, 5, 7, 9).
    #[arg(long, help = with_default(
        "Hidden layers L of the scalers (Table 3: 3, 5, 7, 9)", ModelConfig::default().layers))]
    layers: usize = 5, Option<usize>;
    /// Integrator (paper: RK4; RK3 selectable).
    #[serde(with = "by_name")]
    #[arg(long, help = with_default(
        "Integrator: rk4 or rk3", ModelConfig::default().integrator.name()))]
    integrator: Integrator = Integrator::Rk4, Option<Integrator>;
    /// Bounds `(s_min, s_max)` of the `b_fl` scale factor.
    #[arg(skip)]
    b_fl_bounds: (f32, f32) = (0.1, 10.0), Option<(f32, f32)>;
    /// Bounds of the `b_pr` and `k_pr` scale factors (`s_max` of `k_pr` is lowered if the
    /// explicit-RK stability check needs it).
    #[arg(skip)]
    pr_bounds: (f32, f32) = (0.1, 5.0), Option<(f32, f32)>;
    /// Integration (deployment) rate of the model \[Hz\]: the model steps at
    /// `1 / rate_hz` whatever the data's sample rate, and the exported blob carries that step
    /// (docs/preprocessing.md, "Model rate and data rate").
    #[arg(long = "model-rate-hz", value_name = "MODEL_RATE_HZ", help = with_default(
        "Integration rate of the model in Hz, independent of the data's sample rate (the \
         exported step is 1 / rate)", ModelConfig::default().rate_hz))]
    rate_hz: f64 = DEFAULT_MODEL_RATE_HZ, Option<f64>;
    /// How the condition's declared monotonicity priors in alpha are imposed:
    /// `construction` (an alpha branch that holds them for every weight) or `penalty`
    /// (the paper's physics penalty alone) (docs/training.md, "Priors in alpha").
    #[serde(with = "by_name")]
    #[arg(long, help = with_default(
        "How the declared priors in alpha are imposed: construction (an alpha branch, \
         monotone for every weight) or penalty (the paper's physics penalty alone)",
        ModelConfig::default().alpha_priors.name()))]
    alpha_priors: AlphaPriors = AlphaPriors::Construction, Option<AlphaPriors>;
    /// Units `K` of each alpha branch.
    #[arg(skip)]
    branch_units: usize = 16, Option<usize>;
    /// How the priors in the state (the flow force rising with `v_st`, the spring force
    /// rising with `x_pr`) are imposed on `b_fl` and `k_pr`: `construction` (cumulative
    /// scalers, monotone for every weight) or `penalty` (the paper's MLP scalers and
    /// physics penalty) (docs/training.md, "Priors in the state").
    #[serde(with = "by_name")]
    #[arg(long, help = with_default(
        "How the priors in the state are imposed on b_fl and k_pr: construction (cumulative \
         scalers, the force monotone for every weight) or penalty (the paper's MLPs and \
         physics penalty)",
        ModelConfig::default().state_priors.name()))]
    state_priors: StatePriors = StatePriors::Penalty, Option<StatePriors>;
    /// Units `K` of each cumulative scaler (`--state-priors construction`).
    #[arg(skip)]
    cumulative_units: usize = 16, Option<usize>;
    /// Adds the static force of eq. 17 (gas force and seal friction in the stroke
    /// position, `nemm_kernels::static_force`) to every EMM-family variant
    /// (docs/training.md, "The static force"). `None` (the default): on when most runs hold a
    /// force offset at zero velocity ([`super::Config::with_static_force_from`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL",
        help = with_default(
        "Add the static force of eq. 17 (gas force and gas spring in the stroke position, \
         seal friction) to every EMM-family variant: --static-force or --static-force=false",
        "from the data: on when most runs hold a force offset at zero velocity"))]
    static_force: Option<bool> = None, Option<bool>;
    /// Adds the lost-motion element (free gas in series with `k_pr`, whose travel per
    /// stroke side grows with alpha, `nemm_kernels::lost_motion`) to every
    /// EMM-family variant (docs/training.md, "The lost-motion element"). Off by default:
    /// the paper's model.
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL",
        help = with_default(
        "Add the lost-motion element (gas in series with k_pr; its travel per stroke side \
         grows with alpha) to every EMM-family variant: --lost-motion or --lost-motion=false",
        ModelConfig::default().lost_motion))]
    lost_motion: bool = false, Option<bool>;
    /// Whether the flow damping depends on alpha (the paper's `b_fl(v_st, alpha)`, the
    /// default); `false`: one `b_fl(v_st)` for every level, so that the pressure elements
    /// must form the degradation (docs/training.md, "The lost-motion element").
    #[arg(long, num_args = 0..=1, default_missing_value = "true", value_name = "BOOL",
        help = with_default(
        "Whether the flow damping b_fl depends on alpha (the paper's b_fl(v_st, alpha)); \
         --b-fl-alpha=false: one b_fl(v_st) for every level",
        ModelConfig::default().b_fl_alpha))]
    b_fl_alpha: bool = true, Option<bool>;
}
