//! Conversions between the trainer's rollout parameters and `nemm-core`'s [`Model`]: the
//! weight layout and the semantics are nemm-core's, so exporting is a copy, not a
//! re-implementation.

use super::adjoint::{
    BranchShape, CumulativeShape, Real, RolloutParams, ScalerWeights, StaticParams,
};
use anyhow::{bail, Result};
use nemm_core::{
    AlphaBranches, Body, Condition, CumulativeScaler, CumulativeScalers, InputScales, LostMotion,
    Meta, MlpParams, Model, Scaler, StaticForce, DEFAULT_PARAM_CAPACITY,
};
use nemm_kernels::emm::EmmConstants;
use nemm_kernels::mlp::AlphaBranch;

fn scaler_from_core<T: Real>(
    s: &Scaler<DEFAULT_PARAM_CAPACITY>,
    branch: Option<&AlphaBranch>,
    cumulative: Option<&CumulativeScaler>,
) -> ScalerWeights<T> {
    if let Some(c) = cumulative {
        return ScalerWeights {
            inputs: s.mlp.inputs as usize,
            hidden: 0,
            layers: 0,
            w: c.params.iter().map(|&v| T::c(v as f64)).collect(),
            s_min: T::c(s.s_min as f64),
            s_max: T::c(s.s_max as f64),
            branch: None,
            cumulative: Some(CumulativeShape {
                direction: c.direction,
                units: c.units as usize,
            }),
        };
    }
    let tail: &[f32] = branch.map_or(&[], |b| &b.params);
    ScalerWeights {
        inputs: s.mlp.inputs as usize,
        hidden: s.mlp.hidden as usize,
        layers: s.mlp.layers as usize,
        w: s.mlp
            .params
            .iter()
            .chain(tail)
            .map(|&v| T::c(v as f64))
            .collect(),
        s_min: T::c(s.s_min as f64),
        s_max: T::c(s.s_max as f64),
        branch: branch.map(|b| BranchShape {
            direction: b.direction,
            state_inputs: b.state_inputs as usize,
            units: b.units as usize,
        }),
        cumulative: None,
    }
}

/// A core scaler, its alpha branch and its cumulative scaler (which replaces the MLP).
type CoreScaler = (
    Scaler<DEFAULT_PARAM_CAPACITY>,
    Option<AlphaBranch>,
    Option<CumulativeScaler>,
);

fn scaler_to_core<T: Real>(s: &ScalerWeights<T>) -> Result<CoreScaler> {
    let f = |v: &T| v.to_f32().unwrap_or(f32::NAN);
    let bounds = |mlp| Scaler {
        mlp,
        s_min: s.s_min.to_f32().unwrap_or(f32::NAN),
        s_max: s.s_max.to_f32().unwrap_or(f32::NAN),
    };
    if let Some(c) = s.cumulative {
        let w: Vec<f32> = s.w.iter().map(f).collect();
        let cum = CumulativeScaler::new(c.direction, u8::try_from(c.units)?, &w)
            .map_err(|e| anyhow::anyhow!("cumulative scaler: {e}"))?;
        let inputs = u8::try_from(s.inputs)?;
        return Ok((bounds(MlpParams::without_weights(inputs)), None, Some(cum)));
    }
    let w: Vec<f32> = s.mlp_w().iter().map(f).collect();
    let mlp = MlpParams::new(s.inputs as u8, s.hidden as u8, s.layers as u8, &w)
        .map_err(|e| anyhow::anyhow!("scaler shape: {e:?}"))?;
    let branch = match s.branch {
        None => None,
        Some(b) => {
            let bw: Vec<f32> = s.branch_w().iter().map(f).collect();
            let units = u8::try_from(b.units)?;
            let state = u8::try_from(b.state_inputs)?;
            Some(
                AlphaBranch::new(b.direction, state, units, &bw)
                    .map_err(|e| anyhow::anyhow!("alpha branch: {e}"))?,
            )
        }
    };
    Ok((bounds(mlp), branch, None))
}

/// Rollout parameters of a core EMM-family model (`None` for the SEM).
pub fn from_core<T: Real>(m: &Model) -> Option<RolloutParams<T>> {
    let e = m.emm()?;
    let c = |v: f32| T::c(v as f64);
    let br = &m.alpha_branches;
    let cu = &m.cumulative;
    let (b_fl, b_pr, k_pr) = match &m.body {
        Body::Sem(_) => return None,
        Body::LinearEmm(_) => (None, None, None),
        Body::NemmLight { b_fl, .. } => (
            Some(scaler_from_core(b_fl, br.b_fl.as_ref(), cu.b_fl.as_ref())),
            None,
            None,
        ),
        Body::Nemm {
            b_fl, b_pr, k_pr, ..
        } => (
            Some(scaler_from_core(b_fl, br.b_fl.as_ref(), cu.b_fl.as_ref())),
            Some(scaler_from_core(b_pr, br.b_pr.as_ref(), None)),
            Some(scaler_from_core(k_pr, br.k_pr.as_ref(), cu.k_pr.as_ref())),
        ),
    };
    Some(RolloutParams {
        integrator: m.integrator,
        dt: c(m.dt_s),
        b_fl0: c(e.b_fl_ns_per_m),
        b_pr0: c(e.b_pr_ns_per_m),
        k0: c(e.k_pr_n_per_m),
        t_pr: c(e.t_pr_s),
        v_scale: c(m.scales.velocity_m_s),
        x_scale: c(m.scales.x_pr_m),
        alpha_scale: c(m.scales.alpha),
        b_fl,
        b_pr,
        k_pr,
        priors: m.condition.priors,
        static_force: m.static_force.map(|s| StaticParams {
            theta: s.params().map(c),
            x_ref: c(s.x_ref_m),
            v_c: c(s.v_c_m_s),
        }),
        lost_motion: m.lost_motion.map(|l| l.params().map(c)),
    })
}

/// The core model of rollout parameters, with training-data facts `meta` and the paper's
/// condition (oil loss) with the parameters' priors (`to_core_with`).
pub fn to_core<T: Real>(p: &RolloutParams<T>, meta: Meta) -> Result<Model> {
    let condition = Condition {
        priors: p.priors,
        ..Condition::default()
    };
    to_core_with(p, meta, &condition)
}

/// The core model of rollout parameters, with training-data facts `meta` and the dataset's
/// `condition`. The kind follows from which scalers are present (none: Linear EMM; `b_fl`:
/// NEMM-Light; all: NEMM); the scalers' alpha branches go into the extension.
pub(crate) fn to_core_with<T: Real>(
    p: &RolloutParams<T>,
    meta: Meta,
    condition: &Condition,
) -> Result<Model> {
    let f = |v: T| v.to_f32().unwrap_or(f32::NAN);
    let emm = EmmConstants {
        b_fl_ns_per_m: f(p.b_fl0),
        b_pr_ns_per_m: f(p.b_pr0),
        k_pr_n_per_m: f(p.k0),
        t_pr_s: f(p.t_pr),
    };
    let mut branches = AlphaBranches::default();
    let mut cumulative = CumulativeScalers::default();
    let body = match (&p.b_fl, &p.b_pr, &p.k_pr) {
        (None, None, None) => Body::LinearEmm(emm),
        (Some(b_fl), None, None) => {
            let (b_fl, bb, cb) = scaler_to_core(b_fl)?;
            branches.b_fl = bb;
            cumulative.b_fl = cb;
            Body::NemmLight { emm, b_fl }
        }
        (Some(b_fl), Some(b_pr), Some(k_pr)) => {
            let (b_fl, bf, cf) = scaler_to_core(b_fl)?;
            let (b_pr, bp, cp) = scaler_to_core(b_pr)?;
            let (k_pr, bk, ck) = scaler_to_core(k_pr)?;
            if cp.is_some() {
                bail!("b_pr has no state input: it cannot be a cumulative scaler");
            }
            branches = AlphaBranches {
                b_fl: bf,
                b_pr: bp,
                k_pr: bk,
            };
            cumulative = CumulativeScalers { b_fl: cf, k_pr: ck };
            Body::Nemm {
                emm,
                b_fl,
                b_pr,
                k_pr,
            }
        }
        _ => bail!("unsupported scaler combination (need none, b_fl, or all three)"),
    };
    let model = Model {
        integrator: p.integrator,
        dt_s: f(p.dt),
        scales: InputScales {
            velocity_m_s: f(p.v_scale),
            x_pr_m: f(p.x_scale),
            alpha: f(p.alpha_scale),
        },
        meta,
        body,
        // The provenance is the exporter's (cli::train::export_model).
        condition: condition.clone(),
        alpha_branches: branches,
        cumulative,
        provenance: Default::default(),
        static_force: p.static_force.map(|s| StaticForce {
            f_gas0_n: f(s.theta[0]),
            f_gas0_per_alpha_n: f(s.theta[1]),
            k_gas_n_per_m: f(s.theta[2]),
            k_gas_per_alpha_n_per_m: f(s.theta[3]),
            x_ref_m: f(s.x_ref),
            f_c_n: f(s.theta[4]),
            v_c_m_s: f(s.v_c),
        }),
        lost_motion: p.lost_motion.map(|l| LostMotion::from_params(l.map(f))),
    };
    model
        .validate()
        .map_err(|e| anyhow::anyhow!("the trained model is not valid: {e}"))?;
    Ok(model)
}
