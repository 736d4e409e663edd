//! Evaluation of exported models on sequences and whole runs.
//!
//! EMM-family models are simulated by the trainer's batched f32 rollout, which reproduces
//! nemm-core's estimator within 1e-5 of the force scale (test `rollout_matches_core_estimator`);
//! the SEM, which has no state, runs through nemm-core's estimator directly.

use super::adjoint::{simulate, RolloutParams, Window};
use super::params::from_core;
use crate::data::preprocess::Sequence;
use anyhow::{Context, Result};
use nemm_core::{Estimator, EstimatorConfig, Model};

/// Forces predicted by `model` for each `(velocity, alpha)` input, starting at rest.
pub fn predict(model: &Model, inputs: &[(&[f32], f32)]) -> Result<Vec<Vec<f64>>> {
    match from_core::<f32>(model) {
        Some(p) => {
            let p: RolloutParams<f32> = p;
            let wins: Vec<Window<'_>> = inputs
                .iter()
                .map(|(u, a)| Window { u, f: u, alpha: *a })
                .collect();
            Ok(simulate(&p, &wins))
        }
        None => inputs
            .iter()
            .map(|(u, a)| {
                let mut est = Estimator::new(model, EstimatorConfig::new(*a))
                    .map_err(|e| anyhow::anyhow!("{e}"))
                    .context("cannot run the SEM")?;
                Ok(u.iter().map(|&v| est.step(v).force_n as f64).collect())
            })
            .collect(),
    }
}

/// Per sequence of `seqs`: the squared-error sum of `model` (normalised by `force_scale`) and
/// the count of scored samples (after `warmup`).
pub fn sse_per_sequence(
    model: &Model,
    seqs: &[Sequence],
    warmup: usize,
    force_scale: f64,
) -> Result<Vec<(f64, usize)>> {
    let inputs: Vec<(&[f32], f32)> = seqs
        .iter()
        .map(|s| (s.velocity_m_s.as_slice(), s.alpha))
        .collect();
    let ys = predict(model, &inputs)?;
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
pub fn sse_model(
    model: &Model,
    seqs: &[Sequence],
    warmup: usize,
    force_scale: f64,
) -> Result<(f64, usize)> {
    Ok(sse_per_sequence(model, seqs, warmup, force_scale)?
        .into_iter()
        .fold((0.0, 0), |(se, n), (s, k)| (se + s, n + k)))
}

/// Normalised RMSE of `model` over `seqs` (NaN without samples).
pub fn rmse_model(
    model: &Model,
    seqs: &[Sequence],
    warmup: usize,
    force_scale: f64,
) -> Result<f64> {
    let (se, n) = sse_model(model, seqs, warmup, force_scale)?;
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
