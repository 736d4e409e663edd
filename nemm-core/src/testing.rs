//! Deterministic example models for tests, benchmarks, fuzz seeds and documentation.
//!
//! The weights are pseudo-random (a fixed hash of the parameter index), initialised like a
//! freshly built scaler (output bias at the identity logit), on physically plausible
//! passenger-car constants. They are not trained models.

use crate::model::{
    AlphaBranches, Body, Condition, CumulativeScalers, InputScales, Meta, Model, ModelKind, Priors,
};
use nemm_kernels::cumulative::{cumulative_param_count, CumulativeScaler, CUMULATIVE_CAPACITY};
use nemm_kernels::emm::EmmConstants;
use nemm_kernels::integrator::Integrator;
use nemm_kernels::mlp::{
    branch_param_count, param_count, AlphaBranch, Direction, MlpParams, Scaler,
};
use nemm_kernels::sem::SemMap;

/// Constants of the examples: `b_fl` 2500 N s/m, `b_pr` 1500 N s/m, `k_pr` 4e5 N/m,
/// `T_pr` 2 ms.
pub const EXAMPLE_EMM: EmmConstants = EmmConstants {
    b_fl_ns_per_m: 2500.0,
    b_pr_ns_per_m: 1500.0,
    k_pr_n_per_m: 4.0e5,
    t_pr_s: 0.002,
};

/// Uniform pseudo-random value in `[-1, 1)` from an index and a seed (SplitMix64 finaliser).
pub fn hash_unit(i: u64, seed: u64) -> f32 {
    let mut z = i
        .wrapping_add(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15))
        .wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    ((z >> 40) as f32) / ((1u64 << 23) as f32) - 1.0
}

/// An example scaler with `inputs` inputs, width `hidden`, `layers` layers.
pub fn example_scaler<const P: usize>(
    inputs: u8,
    hidden: u8,
    layers: u8,
    seed: u64,
) -> Option<Scaler<P>> {
    let (d, h, l) = (inputs as usize, hidden as usize, layers as usize);
    let n = param_count(d, h, l);
    let mut p = heapless::Vec::<f32, P>::new();
    let (s_min, s_max) = (0.2f32, 3.0f32);
    for layer in 0..l {
        let fan_in = if layer == 0 { d } else { h };
        let a = 1.0 / libm::sqrtf(fan_in as f32);
        for j in 0..fan_in * h {
            p.push(a * hash_unit((layer * 10_000 + j) as u64, seed))
                .ok()?;
        }
        for j in 0..h {
            p.push(0.1 * hash_unit((layer * 10_000 + 5000 + j) as u64, seed))
                .ok()?;
        }
        for _ in 0..h {
            p.push(1.0).ok()?;
        }
        for _ in 0..h {
            p.push(0.0).ok()?;
        }
    }
    for j in 0..h {
        p.push(0.3 * hash_unit((900_000 + j) as u64, seed)).ok()?;
    }
    p.push(Scaler::<P>::identity_logit(s_min, s_max)).ok()?;
    debug_assert_eq!(p.len(), n);
    Some(Scaler {
        mlp: MlpParams::new(inputs, hidden, layers, &p).ok()?,
        s_min,
        s_max,
    })
}

/// An example SEM map: a digressive passenger-car characteristic (rebound stiffer than
/// compression) whose force falls with oil loss.
pub fn example_sem() -> SemMap {
    let vs = [
        -1.2f32, -0.6, -0.3, -0.1, -0.05, 0.0, 0.05, 0.1, 0.3, 0.6, 1.2,
    ];
    let alphas = [0.0f32, 0.3];
    let mut forces = heapless::Vec::new();
    for &a in &alphas {
        for &v in &vs {
            let c = if v >= 0.0 { 2.0 } else { 1.0 };
            let f = c * 1200.0 * libm::tanhf(v / 0.12) + c * 800.0 * v;
            let _ = forces.push(f * (1.0 - 0.8 * a));
        }
    }
    SemMap {
        velocities_m_s: heapless::Vec::from_slice(&vs).unwrap_or_default(),
        alphas: heapless::Vec::from_slice(&alphas).unwrap_or_default(),
        forces_n: forces,
    }
}

/// An example model of the given kind, scalers of width `hidden` and depth `layers`.
pub fn example_model<const P: usize>(kind: ModelKind, hidden: u8, layers: u8) -> Option<Model<P>> {
    let body = match kind {
        ModelKind::Sem => Body::Sem(example_sem()),
        ModelKind::LinearEmm => Body::LinearEmm(EXAMPLE_EMM),
        ModelKind::NemmLight => Body::NemmLight {
            emm: EXAMPLE_EMM,
            b_fl: example_scaler(2, hidden, layers, 1)?,
        },
        ModelKind::Nemm => Body::Nemm {
            emm: EXAMPLE_EMM,
            b_fl: example_scaler(2, hidden, layers, 1)?,
            b_pr: example_scaler(1, hidden, layers, 2)?,
            k_pr: example_scaler(2, hidden, layers, 3)?,
        },
    };
    Some(Model {
        integrator: Integrator::Rk4,
        dt_s: 1e-4,
        scales: InputScales {
            velocity_m_s: 1.05,
            x_pr_m: 0.01,
            alpha: 0.3,
        },
        meta: Meta {
            force_scale_n: 3000.0,
            alpha_min: 0.0,
            alpha_max: 0.3,
        },
        body,
        condition: Condition::default(),
        alpha_branches: AlphaBranches::default(),
        provenance: crate::Provenance::empty(),
        static_force: None,
        lost_motion: None,
        cumulative: CumulativeScalers::default(),
    })
}

/// An example lost-motion element: `f0` 1.5 kN, compression travel 3.4 mm growing by
/// 30 mm per unit `alpha`, rebound travel 1.3 mm growing by 7.7 mm.
pub const EXAMPLE_LOST_MOTION: crate::LostMotion = crate::LostMotion {
    f0_n: 1500.0,
    travel_c_m: 3.4e-3,
    travel_c_per_alpha_m: 30e-3,
    travel_r_m: 1.3e-3,
    travel_r_per_alpha_m: 7.7e-3,
};

/// [`example_model`] with [`EXAMPLE_LOST_MOTION`] (`None` for the SEM, which refuses it).
pub fn example_model_with_lost_motion<const P: usize>(
    kind: ModelKind,
    hidden: u8,
    layers: u8,
) -> Option<Model<P>> {
    if kind == ModelKind::Sem {
        return None;
    }
    let mut m = example_model(kind, hidden, layers)?;
    m.lost_motion = Some(EXAMPLE_LOST_MOTION);
    Some(m)
}

/// An example alpha branch: `units` units, `state_inputs` state inputs, pseudo-random
/// weights in `+-1` (`theta_u` in `+-1.5`).
pub fn example_branch(
    direction: Direction,
    state_inputs: u8,
    units: u8,
    seed: u64,
) -> Option<AlphaBranch> {
    let n = branch_param_count(state_inputs as usize, units as usize);
    let k = units as usize;
    let p: heapless::Vec<f32, { nemm_kernels::mlp::BRANCH_CAPACITY }> = (0..n)
        .map(|i| {
            let u = hash_unit(700_000 + i as u64, seed);
            let in_theta_u =
                (k * state_inputs as usize..k * (state_inputs as usize + 1)).contains(&i);
            if in_theta_u {
                1.5 * u
            } else {
                u
            }
        })
        .collect();
    AlphaBranch::new(direction, state_inputs, units, &p).ok()
}

/// The example NEMM ([`example_model`]) with the condition's `priors` held by
/// construction: every coefficient with a direction gets an [`example_branch`] of `units`
/// units and its MLP's alpha column set to zero.
pub fn example_model_with_branches<const P: usize>(
    hidden: u8,
    layers: u8,
    units: u8,
    priors: Priors,
) -> Option<Model<P>> {
    let mut m = example_model::<P>(ModelKind::Nemm, hidden, layers)?;
    let mut branches = AlphaBranches::default();
    if let Body::Nemm {
        b_fl, b_pr, k_pr, ..
    } = &mut m.body
    {
        for (scaler, slot, dir, state, seed) in [
            (b_fl, &mut branches.b_fl, priors.b_fl, 1u8, 11u64),
            (b_pr, &mut branches.b_pr, priors.b_pr, 0, 12),
            (k_pr, &mut branches.k_pr, priors.k_pr, 1, 13),
        ] {
            if dir == Direction::None {
                continue;
            }
            scaler.mlp.clear_alpha_column();
            *slot = Some(example_branch(dir, state, units, seed)?);
        }
    }
    m.condition = Condition {
        priors,
        ..Condition::default()
    };
    m.alpha_branches = branches;
    Some(m)
}
/// An example cumulative scaler ([`nemm_kernels::cumulative`]) of `units` units in the
/// direction `direction`: logits in `+-0.5`, widths `exp(omega)` with `omega` in `0.5 +-
/// 1.5` (0.37 to 7.4 per unit of normalised state), centres in `+-2`, gate slopes
/// `gamma` in `+-1.2`, gate biases in `+-0.5` (pseudo-random, [`hash_unit`]).
pub fn example_cumulative_scaler(
    direction: Direction,
    units: u8,
    seed: u64,
) -> Option<CumulativeScaler> {
    let k = units as usize;
    let h = |i: usize| hash_unit(800_000 + i as u64, seed);
    let mut p = heapless::Vec::<f32, CUMULATIVE_CAPACITY>::new();
    for j in 0..=k {
        p.push(0.5 * h(j)).ok()?;
    }
    for j in 0..k {
        p.push(0.5 + 1.5 * h(100 + j)).ok()?;
    }
    for j in 0..k {
        p.push(2.0 * h(200 + j)).ok()?;
    }
    for j in 0..=k {
        p.push(1.2 * h(300 + j)).ok()?;
    }
    for j in 0..=k {
        p.push(0.5 * h(400 + j)).ok()?;
    }
    debug_assert_eq!(p.len(), cumulative_param_count(k));
    CumulativeScaler::new(direction, units, &p).ok()
}

/// The example model of `kind` ([`example_model`], `H = 16`, `L = 5`) with a cumulative
/// `b_fl` (NEMM-Light and NEMM) and a cumulative `k_pr` (NEMM) of 16 units each
/// ([`example_cumulative_scaler`], seeds 21 and 23), in the directions of the paper's
/// priors (decreasing); their scalers in the body keep the example bounds 0.2 and 3.0 with
/// an MLP without weights. The SEM and the Linear EMM, which learn no state-dependent
/// coefficient, are [`example_model`]'s.
pub fn example_cumulative_model(kind: ModelKind) -> Model {
    let Some(mut m) = example_model(kind, 16, 5) else {
        return Model::empty();
    };
    let priors = m.condition.priors;
    let cumulative = |scaler: &mut Scaler<{ crate::DEFAULT_PARAM_CAPACITY }>, dir, seed| {
        scaler.mlp = MlpParams::without_weights(2);
        example_cumulative_scaler(dir, 16, seed)
    };
    match &mut m.body {
        Body::Sem(_) | Body::LinearEmm(_) => {}
        Body::NemmLight { b_fl, .. } => {
            m.cumulative.b_fl = cumulative(b_fl, priors.b_fl, 21);
        }
        Body::Nemm { b_fl, k_pr, .. } => {
            m.cumulative.b_fl = cumulative(b_fl, priors.b_fl, 21);
            m.cumulative.k_pr = cumulative(k_pr, priors.k_pr, 23);
        }
    }
    m
}

/// An example static force (gas offset -90 N at x_ref = 30 mm, gas spring 800 N/m, seal
/// friction 15 N smoothed over 5 mm/s, both gas terms depending on alpha).
pub const EXAMPLE_STATIC_FORCE: crate::StaticForce = crate::StaticForce::EXAMPLE;

/// Capacity of [`example_blob`].
pub const EXAMPLE_BLOB_CAPACITY: usize = 40_000;

/// The blob of the default-size (H = 16, L = 5) example NEMM.
pub fn example_blob() -> heapless::Vec<u8, EXAMPLE_BLOB_CAPACITY> {
    let mut buf = [0u8; EXAMPLE_BLOB_CAPACITY];
    let model = example_model::<{ crate::DEFAULT_PARAM_CAPACITY }>(ModelKind::Nemm, 16, 5);
    match model.map(|m| crate::format::encode(&m, &mut buf).map(heapless::Vec::from_slice)) {
        Some(Ok(Ok(v))) => v,
        _ => heapless::Vec::new(),
    }
}

/// The raw network output `z` of a compiled scaler at state input `u` as the estimator
/// computes it: the Arm FPU kernel where there is one for the scaler's width, the portable
/// code otherwise.
pub fn scaler_raw<const P: usize>(scaler: &nemm_kernels::mlp::CompiledScaler<P>, u: f32) -> f32 {
    scaler.raw(u)
}

/// The portable evaluation of [`scaler_raw`]: the reference the Arm kernel must match bit for
/// bit.
pub fn scaler_raw_portable<const P: usize>(
    scaler: &nemm_kernels::mlp::CompiledScaler<P>,
    u: f32,
) -> f32 {
    scaler.raw_portable(u)
}
