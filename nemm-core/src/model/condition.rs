//! What the model's `alpha` stands for and what it declares of it: the condition, the
//! priors in `alpha` and the alpha branches that make them hold by construction.

use super::*;

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
