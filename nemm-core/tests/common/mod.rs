//! Shared helpers of the integration tests: random valid models (described by a small,
//! printable [`ModelSpec`] so that a failing case shows its parameters, not 100 KB of
//! weights), blob helpers, and a reference simulation of the EMM through the unfolded scalers.
#![allow(dead_code)] // each test binary uses a different subset

use nemm_core::testing::hash_unit;
use nemm_core::STABILITY_MARGIN;
use nemm_core::{
    encode, Body, Estimator, EstimatorConfig, EstimatorError, Header, InputScales, Integrator,
    Meta, Model, ModelKind, SemMap, FORMAT_VERSION,
};
use nemm_core::{CRC, CRC_LEN, MAGIC};
use nemm_kernels::emm::{self, Coefficients, EmmConstants, State};
use nemm_kernels::integrator::{self, StepSize};
use nemm_kernels::mlp::{param_count, MlpParams, Scaler};
use proptest::prelude::*;

/// Every model kind.
pub const KINDS: [ModelKind; 4] = [
    ModelKind::Sem,
    ModelKind::LinearEmm,
    ModelKind::NemmLight,
    ModelKind::Nemm,
];

/// Every integrator.
pub const INTEGRATORS: [Integrator; 2] = [Integrator::Rk4, Integrator::Rk3];

/// Default capacity (holds every model of the Table 3 search space).
pub const P: usize = nemm_core::DEFAULT_PARAM_CAPACITY;

/// Runs `f` on a thread with a 64 MiB stack. `Model<P>` with the default capacity is 110 KB,
/// and unoptimised builds keep several copies of it per frame in `decode`, which overflows the
/// test harness's 2 MiB threads.
pub fn with_big_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(f)
        .expect("spawn test thread")
        .join()
        .unwrap_or_else(|e| std::panic::resume_unwind(e))
}

/// An estimator built in place on the heap ([`Estimator::load`]): tests that hold several
/// estimators keep only their boxes on the stack, which an unoptimised build needs (an
/// `Estimator<P>` of the default capacity is about 128 KB).
pub fn boxed<const T: usize>(
    m: &Model<P>,
    cfg: EstimatorConfig,
) -> Result<Box<Estimator<'static, P, T>>, EstimatorError> {
    let mut e = Box::new(Estimator::<P, T>::empty());
    e.load(m, cfg)?;
    Ok(e)
}

/// Encodes a valid model into a fresh vector (the no_std `encode` with a large buffer).
pub fn blob_of<const Q: usize>(m: &Model<Q>) -> Vec<u8> {
    let mut buf = vec![0u8; 4 * 3 * Q + 16 * 1024];
    let blob = encode(m, &mut buf).expect("valid model encodes");
    blob.to_vec()
}

/// The blob of a valid model with the tables of `levels` (table-mode estimators of `m`).
pub fn blob_with_tables<const Q: usize, const S: usize>(
    m: &Model<Q>,
    levels: &[&nemm_core::Estimator<Q, S>],
) -> Result<Vec<u8>, nemm_core::EncodeError> {
    let mut buf = vec![0u8; nemm_core::encoded_len_with_tables(m, levels)?];
    let n = nemm_core::encode_with_tables(m, levels, &mut buf)?.len();
    buf.truncate(n);
    Ok(buf)
}

/// The blob layout of nemm-core's weight format (`src/format.rs`), written independently of `encode` and without any
/// validation: postcard header, postcard body (version-1 part, the version-3 fields, the
/// version-4 static force, the version-5 lost-motion element, the version-7 cumulative
/// scalers and an empty version-6 tables section), CRC-32 little-endian. Lets tests build
/// well-formed blobs with contents `encode` refuses (NaN weights, unstable steps), or
/// headers that disagree with the body.
pub fn craft_blob<const Q: usize>(m: &Model<Q>, edit: impl Fn(&mut Header)) -> Vec<u8> {
    let body = body_prefix(m);
    // Version 6's tables section, without levels: `pad` zero bytes after the padding byte
    // so that the level count (u32 LE, 0) starts at a multiple of 4 from the blob's start.
    for pad in 0..=7u8 {
        let mut b = body.clone();
        b.push(pad);
        b.extend(std::iter::repeat_n(0u8, usize::from(pad)));
        let contents = b.len();
        b.extend_from_slice(&0u32.to_le_bytes());
        let mut header = Header {
            magic: MAGIC,
            version: FORMAT_VERSION,
            kind: m.kind(),
            max_scaler_params: m.max_scaler_params() as u32,
            body_len: b.len() as u32,
        };
        edit(&mut header);
        let mut hbuf = [0u8; 64];
        let mut out = postcard::to_slice(&header, &mut hbuf)
            .expect("header serialises")
            .to_vec();
        if (out.len() + contents) % 4 != 0 {
            continue;
        }
        out.extend_from_slice(&b);
        let crc = CRC.checksum(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        return out;
    }
    unreachable!("one padding of 0 to 7 aligns the section")
}

/// The body of `m`'s blob up to its tables section: the version-1 part, the version-3
/// fields, the static force, the lost-motion element and the cumulative scalers.
pub fn body_prefix<const Q: usize>(m: &Model<Q>) -> Vec<u8> {
    let mut body = vec![0u8; 4 * 3 * Q + 16 * 1024];
    let mut body = postcard::to_slice(m, &mut body)
        .expect("body serialises")
        .to_vec();
    let mut ext = vec![0u8; 64 * 1024];
    let v3 = (&m.condition, &m.alpha_branches, &m.provenance);
    body.extend_from_slice(postcard::to_slice(&v3, &mut ext).expect("version-3 fields serialise"));
    body.extend_from_slice(
        postcard::to_slice(&m.static_force, &mut ext).expect("static force serialises"),
    );
    // Version 5's lost-motion element.
    body.extend_from_slice(
        postcard::to_slice(&m.lost_motion, &mut ext).expect("lost motion serialises"),
    );
    // Version 7's cumulative scalers.
    body.extend_from_slice(
        postcard::to_slice(&m.cumulative, &mut ext).expect("cumulative scalers serialise"),
    );
    body
}

/// Recomputes the CRC trailer of `blob` (at least [`CRC_LEN`] bytes) over everything before it.
pub fn fix_crc(blob: &mut [u8]) {
    let n = blob.len() - CRC_LEN;
    let crc = CRC.checksum(&blob[..n]);
    blob[n..].copy_from_slice(&crc.to_le_bytes());
}

/// Shape and weight source of one random scaler.
#[derive(Debug, Clone, Copy)]
pub struct ScalerSpec {
    pub hidden: u8,
    pub layers: u8,
    pub seed: u64,
    /// Multiplies the He-uniform weight amplitude `1/sqrt(fan_in)`.
    pub gain: f32,
    pub s_min: f32,
    pub s_max: f32,
}

impl ScalerSpec {
    /// Random weights: He-uniform times `gain` for matrices, `0.3 gain` for biases, LayerNorm
    /// gains in `[0.5, 1.5]`, offsets in `[-0.3, 0.3]`, output layer like a matrix.
    pub fn build<const Q: usize>(&self, inputs: u8) -> Scaler<Q> {
        let (d, h, l) = (inputs as usize, self.hidden as usize, self.layers as usize);
        let mut p = Vec::with_capacity(param_count(d, h, l));
        let mut i = 0u64;
        let mut next = || {
            i += 1;
            hash_unit(i, self.seed)
        };
        for layer in 0..l {
            let fan_in = if layer == 0 { d } else { h };
            let a = self.gain / (fan_in as f32).sqrt();
            p.extend((0..fan_in * h).map(|_| a * next()));
            p.extend((0..h).map(|_| 0.3 * self.gain * next()));
            p.extend((0..h).map(|_| 1.0 + 0.5 * next()));
            p.extend((0..h).map(|_| 0.3 * next()));
        }
        let a = self.gain / (h as f32).sqrt();
        p.extend((0..h).map(|_| a * next()));
        p.push(next());
        Scaler {
            mlp: MlpParams::new(inputs, self.hidden, self.layers, &p).expect("shape"),
            s_min: self.s_min,
            s_max: self.s_max,
        }
    }

    pub fn params(&self, inputs: u8) -> usize {
        param_count(inputs as usize, self.hidden as usize, self.layers as usize)
    }
}

/// A random SEM grid: strictly increasing velocities and alphas, random forces.
#[derive(Debug, Clone)]
pub struct SemSpec {
    pub v0: f32,
    pub v_steps: Vec<f32>,
    pub alphas: Vec<f32>,
    pub seed: u64,
    pub force_amp: f32,
}

impl SemSpec {
    pub fn build(&self) -> SemMap {
        let mut v = vec![self.v0];
        for s in &self.v_steps {
            let last = *v.last().unwrap();
            v.push(last + s);
        }
        let n = v.len() * self.alphas.len();
        let forces: Vec<f32> = (0..n)
            .map(|i| self.force_amp * hash_unit(i as u64, self.seed))
            .collect();
        SemMap {
            velocities_m_s: heapless::Vec::from_slice(&v).unwrap(),
            alphas: heapless::Vec::from_slice(&self.alphas).unwrap(),
            forces_n: heapless::Vec::from_slice(&forces).unwrap(),
        }
    }
}

/// Everything that defines a random valid model.
#[derive(Debug, Clone)]
pub struct ModelSpec {
    pub kind: ModelKind,
    pub integrator: Integrator,
    pub emm: EmmConstants,
    pub b_fl: ScalerSpec,
    pub b_pr: ScalerSpec,
    pub k_pr: ScalerSpec,
    pub sem: SemSpec,
    pub scales: InputScales,
    pub meta: Meta,
    /// The step as a fraction of the longest stable step (`(0, 1)`), capped at `dt_cap_s`.
    pub dt_fraction: f32,
    pub dt_cap_s: f32,
}

impl ModelSpec {
    pub fn build<const Q: usize>(&self) -> Model<Q> {
        let body = match self.kind {
            ModelKind::Sem => Body::Sem(self.sem.build()),
            ModelKind::LinearEmm => Body::LinearEmm(self.emm),
            ModelKind::NemmLight => Body::NemmLight {
                emm: self.emm,
                b_fl: self.b_fl.build(2),
            },
            ModelKind::Nemm => Body::Nemm {
                emm: self.emm,
                b_fl: self.b_fl.build(2),
                b_pr: self.b_pr.build(1),
                k_pr: self.k_pr.build(2),
            },
        };
        let mut m = Model {
            integrator: self.integrator,
            dt_s: self.dt_cap_s,
            scales: self.scales,
            meta: self.meta,
            body,
            condition: Default::default(),
            alpha_branches: Default::default(),
            provenance: Default::default(),
            static_force: None,
            lost_motion: None,
            cumulative: Default::default(),
        };
        if let Some(tau) = m.fastest_time_constant_s() {
            let max_dt = STABILITY_MARGIN * self.integrator.stability_limit() * tau;
            m.dt_s = (self.dt_fraction * max_dt).min(self.dt_cap_s);
        }
        m
    }

    /// Largest scaler parameter count of the built model.
    pub fn max_params(&self) -> usize {
        match self.kind {
            ModelKind::Sem | ModelKind::LinearEmm => 0,
            ModelKind::NemmLight => self.b_fl.params(2),
            ModelKind::Nemm => self
                .b_fl
                .params(2)
                .max(self.b_pr.params(1))
                .max(self.k_pr.params(2)),
        }
    }
}

pub fn arb_kind() -> impl Strategy<Value = ModelKind> {
    prop::sample::select(KINDS.to_vec())
}

pub fn arb_integrator() -> impl Strategy<Value = Integrator> {
    prop::sample::select(INTEGRATORS.to_vec())
}

pub fn arb_scaler(max_hidden: u8, max_layers: u8) -> impl Strategy<Value = ScalerSpec> {
    (
        1..=max_hidden,
        1..=max_layers,
        any::<u64>(),
        0.1f32..3.0,
        0.05f32..0.95,
        1.05f32..10.0,
    )
        .prop_map(|(hidden, layers, seed, gain, s_min, s_max)| ScalerSpec {
            hidden,
            layers,
            seed,
            gain,
            s_min,
            s_max,
        })
}

pub fn arb_sem() -> impl Strategy<Value = SemSpec> {
    (
        -5.0f32..0.0,
        prop::collection::vec(0.01f32..0.5, 1..64),
        (1usize..=8, 0.0f32..0.1),
        any::<u64>(),
        1.0f32..1e4,
    )
        .prop_map(|(v0, v_steps, (na, a0), seed, force_amp)| {
            // Evenly spread levels in [a0, 1] (strictly increasing after rounding).
            let alphas = (0..na)
                .map(|i| a0 + (1.0 - a0) * i as f32 / na as f32)
                .collect();
            SemSpec {
                v0,
                v_steps,
                alphas,
                seed,
                force_amp,
            }
        })
}

pub fn arb_emm() -> impl Strategy<Value = EmmConstants> {
    (100.0f32..2e4, 50.0f32..1e4, 1e4f32..5e6, 2e-4f32..5e-2).prop_map(|(bf, bp, k, t)| {
        EmmConstants {
            b_fl_ns_per_m: bf,
            b_pr_ns_per_m: bp,
            k_pr_n_per_m: k,
            t_pr_s: t,
        }
    })
}

/// Random valid models; scalers up to `max_hidden` x `max_layers`.
pub fn arb_model(max_hidden: u8, max_layers: u8) -> impl Strategy<Value = ModelSpec> {
    let scalers = (
        arb_scaler(max_hidden, max_layers),
        arb_scaler(max_hidden, max_layers),
        arb_scaler(max_hidden, max_layers),
    );
    let scales = (0.1f32..3.0, 1e-4f32..0.05, 0.05f32..1.0).prop_map(|(v, x, a)| InputScales {
        velocity_m_s: v,
        x_pr_m: x,
        alpha: a,
    });
    let meta = (10.0f32..1e5, 0.0f32..0.5, 0.0f32..0.5).prop_map(|(f, a0, da)| Meta {
        force_scale_n: f,
        alpha_min: a0,
        alpha_max: a0 + da,
    });
    (
        arb_kind(),
        arb_integrator(),
        arb_emm(),
        scalers,
        arb_sem(),
        scales,
        meta,
        0.05f32..0.95,
    )
        .prop_map(
            |(kind, integrator, emm, (b_fl, b_pr, k_pr), sem, scales, meta, dt_fraction)| {
                ModelSpec {
                    kind,
                    integrator,
                    emm,
                    b_fl,
                    b_pr,
                    k_pr,
                    sem,
                    scales,
                    meta,
                    dt_fraction,
                    dt_cap_s: 1e-4,
                }
            },
        )
}

/// The example model of `kind` (pseudo-random weights, H = 16, L = 5).
pub fn example(kind: ModelKind) -> Model<P> {
    nemm_core::testing::example_model(kind, 16, 5).expect("example model")
}

/// Coefficients by the reference (unfolded) path of [`Model`] (`k_pr` through the
/// lost-motion element if the model has one).
pub fn reference_coeffs<const Q: usize>(m: &Model<Q>, s: &State, alpha: f32) -> Coefficients {
    Coefficients {
        b_fl: m.b_fl(s.v_st_m_s, alpha).unwrap(),
        b_pr: m.b_pr(alpha).unwrap(),
        k_pr: m.k_pr_eff(s.x_pr_m, alpha).unwrap(),
    }
}

/// The estimator's semantics without its folds: reference scalers, the public RK step and
/// force, same input convention (start from rest, previous input 0). EMM kinds only.
pub fn reference_run<const Q: usize>(
    m: &Model<Q>,
    integrator: Integrator,
    dt: f32,
    alpha: f32,
    inputs: &[f32],
) -> Vec<f32> {
    let inv_t = 1.0 / m.emm().expect("EMM kind").t_pr_s;
    let h = StepSize::new(dt);
    let mut x = State::default();
    let mut c = reference_coeffs(m, &x, alpha);
    let mut last_u = 0.0;
    inputs
        .iter()
        .map(|&u| {
            x = integrator::step(
                integrator,
                |s| reference_coeffs(m, s, alpha),
                &c,
                inv_t,
                &x,
                last_u,
                u,
                &h,
            );
            c = reference_coeffs(m, &x, alpha);
            last_u = u;
            emm::force(&c, &x, u)
        })
        .collect()
}

/// Sinusoidal strokes of the paper's Table 1 grid: `(amplitude m, peak velocity m/s)`.
pub fn table1_grid() -> Vec<(f64, f64)> {
    let mut g = Vec::new();
    for &a in &[0.05, 0.03, 0.01] {
        for &v in &[0.052, 0.131, 0.262, 0.393, 0.524, 1.048] {
            g.push((a, v));
        }
    }
    g
}

/// Velocity samples `v_peak cos(w t)` of a sinusoidal stroke of amplitude `amp`, `periods`
/// periods at step `dt` (phase computed in f64, then rounded).
pub fn stroke(amp: f64, v_peak: f64, periods: f64, dt: f64) -> Vec<f32> {
    let w = v_peak / amp;
    let n = (periods * 2.0 * std::f64::consts::PI / w / dt).round() as usize;
    (0..n)
        .map(|k| (v_peak * (w * k as f64 * dt).cos()) as f32)
        .collect()
}
