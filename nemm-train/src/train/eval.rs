//! Evaluation of exported models on sequences and whole runs.
//!
//! The model runs at its own step (`Model::dt_s`), the data at theirs: inputs are
//! interpolated onto the model grid and the force is scored at the data samples (see
//! [`Grid`]). EMM-family models are simulated by the trainer's batched f32 rollout, which
//! reproduces nemm-core's estimator within 1e-5 of the force scale (test
//! `rollout_matches_core_estimator`); the SEM, which has no state, runs through nemm-core's
//! estimator directly, one evaluation per sample.

use super::adjoint::{simulate, Grid, RolloutParams, Window};
use super::params::from_core;
use crate::data::preprocess::Sequence;
use anyhow::{Context, Result};
use nemm_core::{Estimator, EstimatorConfig, Model, Sample};

/// One input of [`predict`]: stroke velocity per sample, the condition level, the level per
/// sample when it changes within the input, and the stroke position.
#[derive(Debug, Clone, Copy)]
pub struct Input<'a> {
    /// Stroke velocity \[m/s\] per data sample.
    pub velocity_m_s: &'a [f32],
    /// Condition level (used when `alphas` is `None`).
    pub alpha: f32,
    /// Condition level per data sample.
    pub alphas: Option<&'a [f32]>,
    /// Stroke position \[m\] per data sample as the position sensor measures it (the input
    /// of a model's static force; `None`: the static force's `x_ref` throughout, and
    /// [`run_estimator`] steps without a position).
    pub position_m: Option<&'a [f32]>,
}

/// Forces predicted by `model` at the data samples (`sample_dt_s` apart) of each input,
/// starting at rest; the model integrates at its own step `model.dt_s`.
pub fn predict(model: &Model, inputs: &[Input<'_>], sample_dt_s: f64) -> Result<Vec<Vec<f64>>> {
    match from_core::<f32>(model) {
        Some(p) => {
            let p: RolloutParams<f32> = p;
            let grid = Grid::new(f64::from(model.dt_s), sample_dt_s);
            let wins: Vec<Window<'_>> = inputs
                .iter()
                .map(|i| Window {
                    u: i.velocity_m_s,
                    f: i.velocity_m_s,
                    alpha: i.alpha,
                    alphas: i.alphas,
                    x: i.position_m,
                })
                .collect();
            Ok(simulate(&p, &wins, &grid))
        }
        None => inputs
            .iter()
            .map(|i| {
                let mut est = Estimator::new(model, EstimatorConfig::new(i.alpha))
                    .map_err(|e| anyhow::anyhow!("{e}"))
                    .context("cannot run the SEM")?;
                i.velocity_m_s
                    .iter()
                    .enumerate()
                    .map(|(k, &v)| {
                        if let Some(a) = i.alphas.and_then(|a| a.get(k)) {
                            est.set_alpha(*a)
                                .map_err(|e| anyhow::anyhow!("sample {k}: {e}"))?;
                        }
                        let e = est
                            .step(Sample::new(v))
                            .map_err(|e| anyhow::anyhow!("sample {k}: {e}"))?;
                        Ok(e.force_n as f64)
                    })
                    .collect()
            })
            .collect(),
    }
}

/// Runs nemm-core's estimator `est` (from its current state) over `input`, whose samples are
/// `sample_dt_s` apart, at the model step `model_dt_s`, as the trainer does ([`Grid`]): each
/// model step takes the input interpolated between the samples, a per-sample level and the
/// position (interpolated likewise) in its [`Sample`] ([`Estimator::step`]), and the force
/// at each sample is the model force interpolated at the sample time. Returns one force per sample and the model steps run.
pub fn run_estimator(
    est: &mut Estimator,
    model_dt_s: f64,
    input: &Input<'_>,
    sample_dt_s: f64,
) -> Result<(Vec<f64>, usize)> {
    let grid = Grid::new(model_dt_s, sample_dt_s);
    let n = input.velocity_m_s.len();
    let steps = grid.steps(n);
    let mut ys = Vec::with_capacity(steps);
    for j in 0..steps {
        let v = grid.interpolate(input.velocity_m_s, j) as f32;
        let x = input.position_m.map(|x| grid.interpolate(x, j) as f32);
        let sample = Sample {
            position_m: x,
            alpha: input.alphas.map(|a| grid.interpolate(a, j) as f32),
            ..Sample::new(v)
        };
        let e = est
            .step(sample)
            .map_err(|e| anyhow::anyhow!("model step {j}: {e}"))?;
        ys.push(f64::from(e.force_n));
    }
    let forces = (0..n)
        .map(|k| match grid.sample_at(k) {
            (j, 0.0) => ys[j],
            (j, w) => ys[j] + w * (ys[j + 1] - ys[j]),
        })
        .collect();
    Ok((forces, steps))
}

/// The [`predict`] input of a sequence.
pub fn input_of(s: &Sequence) -> Input<'_> {
    Input {
        velocity_m_s: &s.velocity_m_s,
        alpha: s.alpha,
        alphas: s.alphas.as_deref(),
        position_m: Some(&s.position_m),
    }
}

/// Per sequence of `seqs` (samples `sample_dt_s` apart): the squared-error sum of `model`
/// (normalised by `force_scale`) and the count of scored samples (after `warmup`).
pub(crate) fn sse_per_sequence(
    model: &Model,
    seqs: &[Sequence],
    sample_dt_s: f64,
    warmup: usize,
    force_scale: f64,
) -> Result<Vec<(f64, usize)>> {
    let inputs: Vec<Input<'_>> = seqs.iter().map(input_of).collect();
    let ys = predict(model, &inputs, sample_dt_s)?;
    Ok(seqs
        .iter()
        .zip(&ys)
        .map(|(s, y)| {
            y.iter()
                .zip(&s.force_n)
                .skip(warmup)
                .fold((0.0f64, 0usize), |(se, n), (&yi, &fi)| {
                    let e = (yi - fi as f64) / force_scale;
                    (se + e * e, n + 1)
                })
        })
        .collect())
}

/// Squared-error sum (normalised by `force_scale`) and count of `model` over `seqs`, scored
/// after `warmup` samples.
pub(crate) fn sse_model(
    model: &Model,
    seqs: &[Sequence],
    sample_dt_s: f64,
    warmup: usize,
    force_scale: f64,
) -> Result<(f64, usize)> {
    Ok(
        sse_per_sequence(model, seqs, sample_dt_s, warmup, force_scale)?
            .into_iter()
            .fold((0.0, 0), |(se, n), (s, k)| (se + s, n + k)),
    )
}

/// Normalised RMSE of `model` over `seqs` (NaN without samples).
pub fn rmse_model(
    model: &Model,
    seqs: &[Sequence],
    sample_dt_s: f64,
    warmup: usize,
    force_scale: f64,
) -> Result<f64> {
    let (se, n) = sse_model(model, seqs, sample_dt_s, warmup, force_scale)?;
    Ok(rmse_of(se, n))
}

/// RMSE from a squared-error sum `se` over `n` samples (NaN without samples).
pub fn rmse_of(se: f64, n: usize) -> f64 {
    if n == 0 {
        f64::NAN
    } else {
        (se / n as f64).sqrt()
    }
}
