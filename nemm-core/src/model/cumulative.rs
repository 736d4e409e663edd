//! The cumulative scalers of a model: `b_fl` and `k_pr` coefficients whose force is
//! monotone in their state by construction ([`nemm_kernels::cumulative`]).

use super::*;
use nemm_kernels::cumulative::{cumulative_param_count, CumulativeScaler};
use nemm_kernels::error::{CumulativeModelError, ShapeError};

/// The cumulative scalers ([`CumulativeScaler`]) of the two state-dependent coefficients;
/// `None` where the coefficient's scale is its MLP's (the paper's scaler).
///
/// A coefficient with a cumulative scaler keeps its [`Scaler`] in the body for the bounds
/// `s_min`, `s_max`, with [`MlpParams::without_weights`](nemm_kernels::mlp::MlpParams::without_weights)
/// (2 inputs) as its MLP; its value is `p_ini s(u / u_scale, alpha / alpha_scale)` with `s`
/// the cumulative scale between those bounds.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CumulativeScalers {
    /// Cumulative scaler of `b_fl(v_st, alpha)`: the flow force `b_fl v_st` rises with
    /// `v_st`.
    pub b_fl: Option<CumulativeScaler>,
    /// Cumulative scaler of `k_pr(x_pr, alpha)`: the spring force `k_pr x_pr` rises with
    /// `x_pr`.
    pub k_pr: Option<CumulativeScaler>,
}

impl CumulativeScalers {
    /// None (a `const`, for [`Model::empty`]).
    pub const NONE: CumulativeScalers = CumulativeScalers {
        b_fl: None,
        k_pr: None,
    };

    /// True without cumulative scalers.
    pub fn is_empty(&self) -> bool {
        self.b_fl.is_none() && self.k_pr.is_none()
    }

    /// Checks every cumulative scaler against the model: its own weights, the capacity `P`
    /// (its `5 K + 3` values, [`ModelError::Shape`] `OverCapacity` beyond), a scaler in
    /// the body for its coefficient, no alpha branch for that coefficient, and its
    /// direction against the declared `priors` (equal, or [`Direction::None`]). That the
    /// body's MLP of the coefficient has no weights is checked with the body.
    pub fn validate<const P: usize>(
        &self,
        body: &Body<P>,
        priors: &Priors,
        branches: &AlphaBranches,
    ) -> Result<(), ModelError> {
        let (fl, k) = match body {
            Body::Sem(_) | Body::LinearEmm(_) => (false, false),
            Body::NemmLight { .. } => (true, false),
            Body::Nemm { .. } => (true, true),
        };
        for (slot, learned, name, prior, branch) in [
            (&self.b_fl, fl, "b_fl", priors.b_fl, branches.b_fl.is_some()),
            (&self.k_pr, k, "k_pr", priors.k_pr, branches.k_pr.is_some()),
        ] {
            let Some(c) = slot else { continue };
            let err = |error| ModelError::Cumulative {
                scaler: name,
                error,
            };
            if !learned {
                return Err(err(CumulativeModelError::NoScaler));
            }
            c.check()
                .map_err(|e| err(CumulativeModelError::Scaler(e)))?;
            let needed = cumulative_param_count(c.units as usize);
            if needed > P {
                return Err(ModelError::Shape {
                    scaler: name,
                    error: ShapeError::OverCapacity {
                        needed,
                        capacity: P,
                    },
                });
            }
            if branch {
                return Err(err(CumulativeModelError::AlphaBranch));
            }
            if c.direction != Direction::None && c.direction != prior {
                return Err(err(CumulativeModelError::DirectionMismatch));
            }
        }
        Ok(())
    }

    /// Largest parameter count of the cumulative scalers (0 without).
    pub fn max_params(&self) -> usize {
        [&self.b_fl, &self.k_pr]
            .into_iter()
            .flatten()
            .map(|c| c.params.len())
            .max()
            .unwrap_or(0)
    }
}
