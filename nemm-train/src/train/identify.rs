//! Identifiability: the condition level `alpha` that best explains a measured run.
//!
//! A trained model is simulated over a whole run at every level of a grid ([`AlphaGrid`]:
//! `0, step, 2 step, ...` up to the model's largest training level) and, once more, at the
//! run's own label; the level of least force RMSE is the best fit ([`identify`]). The
//! simulation is [`predict`]: one input per grid level, so the trainer's batched rollout
//! advances 8 levels in lock step (the SEM runs through nemm-core's estimator). A model whose
//! RMSE varies over the grid by no more than [`FLAT_TOLERANCE`] of its largest value (the
//! Linear EMM, or a network that ignores `alpha`) has no best fit: [`Fit::best`] is `None`.
//!
//! The grid bounds the resolution: a run is identified to the nearest grid level, and only
//! where the model's force depends on `alpha` at that run's excitation.

use super::eval::{predict, Input};
use anyhow::{bail, Result};
use nemm_core::Model;
use serde::{Deserialize, Serialize};

/// Default grid step in `alpha`.
pub const DEFAULT_STEP: f64 = 0.01;

/// Relative RMSE variation over the grid, `(max - min) / max`, at or below which a run's
/// RMSE curve counts as flat (the model does not tell the levels apart on that run).
pub const FLAT_TOLERANCE: f64 = 1e-3;

/// The levels a run is simulated at: `0, step, 2 step, ...` up to `max` (included when it
/// is a multiple of the step; each level rounded to 1e-9).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlphaGrid {
    /// The levels, ascending.
    pub alphas: Vec<f64>,
}

impl AlphaGrid {
    /// `0, step, ...` up to `max` (`0 < step`, `0 <= max <= 1`).
    pub fn new(step: f64, max: f64) -> Result<Self> {
        if !(step.is_finite() && step > 0.0) {
            bail!("the alpha grid step must be positive (got {step})");
        }
        if !(0.0..=1.0).contains(&max) {
            bail!("the alpha grid must end in [0, 1] (got {max})");
        }
        let count = (max / step + 1e-9).floor() as usize + 1;
        Ok(Self {
            alphas: (0..count)
                .map(|i| (i as f64 * step * 1e9).round() / 1e9)
                .collect(),
        })
    }

    /// `0, step, ...` up to the largest training level of `model` (`Meta::alpha_max`; 1 for
    /// a model trained at level 0 only).
    pub fn for_model(model: &Model, step: f64) -> Result<Self> {
        let max = f64::from(model.meta.alpha_max);
        Self::new(step, if max > 0.0 { max.min(1.0) } else { 1.0 })
    }
}

/// One whole run to identify: the model inputs as [`Input`] takes them, the measured force
/// and the run's label.
#[derive(Debug, Clone, Copy)]
pub struct Run<'a> {
    /// Stroke velocity \[m/s\] per sample.
    pub velocity_m_s: &'a [f32],
    /// Stroke position \[m\] per sample (the static force's input), if known.
    pub position_m: Option<&'a [f32]>,
    /// Measured force \[N\] per sample.
    pub force_n: &'a [f64],
    /// The run's labelled level.
    pub label: f64,
    /// Level per sample, if the run has one: the label simulation uses it (the grid
    /// simulations hold each level constant).
    pub label_alphas: Option<&'a [f32]>,
}

/// A number that JSON wrote as `null` (serde_json writes NaN so) reads back as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The result of [`identify`] on one run (RMSE in newtons, over the samples after the
/// warm-up).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fit {
    /// The run's labelled level.
    pub label: f64,
    /// The grid level of least RMSE (the first on a tie); `None` when the curve is flat
    /// ([`FLAT_TOLERANCE`]) or a simulation is not finite.
    pub best: Option<f64>,
    /// RMSE at the grid's least-error level \[N\] (defined when the curve is flat too).
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_best_n: f64,
    /// RMSE at the label (per sample where the run has a level column) \[N\].
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_label_n: f64,
    /// RMSE at every grid level \[N\], in grid order.
    pub curve_n: Vec<f64>,
    /// Scored samples.
    pub samples: usize,
}

impl Fit {
    /// `true` if the best fit is within `tolerance` (plus
    /// [`crate::data::preprocess::ALPHA_TOLERANCE`]) of the label (`false` when flat).
    pub fn within(&self, tolerance: f64) -> bool {
        self.best.is_some_and(|b| {
            (b - self.label).abs() <= tolerance + crate::data::preprocess::ALPHA_TOLERANCE
        })
    }
}

/// `true` if `curve` varies by no more than [`FLAT_TOLERANCE`] of its largest value.
pub fn is_flat(curve: &[f64]) -> bool {
    let (lo, hi) = curve
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &e| {
            (lo.min(e), hi.max(e))
        });
    hi - lo <= FLAT_TOLERANCE * hi
}

/// Simulates `run` (samples `sample_dt_s` apart, from rest) with `model` at every level of
/// `grid` and at its label, and scores the force after `warmup` samples.
pub fn identify(
    model: &Model,
    run: &Run<'_>,
    grid: &AlphaGrid,
    sample_dt_s: f64,
    warmup: usize,
) -> Result<Fit> {
    let input = |alpha: f64| Input {
        velocity_m_s: run.velocity_m_s,
        alpha: alpha as f32,
        alphas: None,
        position_m: run.position_m,
    };
    let mut inputs: Vec<Input<'_>> = grid.alphas.iter().map(|&a| input(a)).collect();
    inputs.push(Input {
        alphas: run.label_alphas,
        ..input(run.label)
    });
    let ys = predict(model, &inputs, sample_dt_s)?;
    let n = run.velocity_m_s.len().min(run.force_n.len());
    let samples = n.saturating_sub(warmup);
    let rmse = |y: &[f64]| {
        let se: f64 = y[warmup.min(n)..n]
            .iter()
            .zip(&run.force_n[warmup.min(n)..n])
            .map(|(&y, &f)| (y - f) * (y - f))
            .sum();
        super::eval::rmse_of(se, samples)
    };
    let mut curve_n: Vec<f64> = ys.iter().map(|y| rmse(y)).collect();
    let rmse_label_n = curve_n.pop().unwrap_or(f64::NAN);
    let (k, rmse_best_n) = curve_n.iter().enumerate().fold(
        (0, f64::INFINITY),
        |(bk, be), (k, &e)| {
            if e < be {
                (k, e)
            } else {
                (bk, be)
            }
        },
    );
    let finite = curve_n.iter().all(|e| e.is_finite());
    let best = (finite && !curve_n.is_empty() && !is_flat(&curve_n)).then(|| grid.alphas[k]);
    Ok(Fit {
        label: run.label,
        best,
        rmse_best_n: if curve_n.is_empty() {
            f64::NAN
        } else {
            rmse_best_n
        },
        rmse_label_n,
        curve_n,
        samples,
    })
}

/// [`identify`] of every run of `runs`, the runs in parallel; returns the fits in order.
pub fn identify_runs(
    model: &Model,
    runs: &[Run<'_>],
    grid: &AlphaGrid,
    sample_dt_s: f64,
    warmup: usize,
) -> Result<Vec<Fit>> {
    use rayon::prelude::*;
    runs.par_iter()
        .map(|r| identify(model, r, grid, sample_dt_s, warmup))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nemm_core::testing::example_model;
    use nemm_core::{Body, ModelKind, DEFAULT_PARAM_CAPACITY};

    /// A 10 mm sine at 5 Hz for 0.4 s at 10 kHz: velocity and position.
    fn sine() -> (Vec<f32>, Vec<f32>) {
        let (a, w, dt) = (0.01f64, 2.0 * std::f64::consts::PI * 5.0, 1e-4);
        (0..4000)
            .map(|k| {
                let t = k as f64 * dt;
                ((a * w * (w * t).cos()) as f32, (a * (w * t).sin()) as f32)
            })
            .unzip()
    }

    fn model(kind: ModelKind) -> Model {
        example_model::<DEFAULT_PARAM_CAPACITY>(kind, 8, 3).expect("example model")
    }

    /// The force of `model` over `sine()` at `alpha`, simulated by [`predict`] alone.
    fn force_at(model: &Model, v: &[f32], x: &[f32], alpha: f32) -> Vec<f64> {
        let input = Input {
            velocity_m_s: v,
            alpha,
            alphas: None,
            position_m: Some(x),
        };
        predict(model, &[input], 1e-4).expect("predict").remove(0)
    }

    #[test]
    fn the_grid_runs_from_zero_to_the_largest_multiple_of_the_step() {
        let g = AlphaGrid::new(0.01, 0.3).expect("grid");
        assert_eq!(g.alphas.len(), 31);
        assert_eq!((g.alphas[7], g.alphas[20], g.alphas[30]), (0.07, 0.2, 0.3));
        let g = AlphaGrid::new(0.07, 0.3).expect("grid");
        assert_eq!(g.alphas, [0.0, 0.07, 0.14, 0.21, 0.28]);
        assert_eq!(
            AlphaGrid::for_model(&model(ModelKind::Nemm), 0.05)
                .expect("grid")
                .alphas
                .len(),
            7
        );
        assert!(AlphaGrid::new(0.0, 0.3).is_err());
        assert!(AlphaGrid::new(0.01, 1.5).is_err());
    }

    #[test]
    fn a_run_simulated_at_a_grid_level_is_identified_exactly() {
        let (v, x) = sine();
        let grid = AlphaGrid::new(0.01, 0.3).expect("grid");
        for kind in [ModelKind::Nemm, ModelKind::NemmLight, ModelKind::Sem] {
            let m = model(kind);
            for (truth, k) in [(0.2f32, 20usize), (0.07, 7)] {
                let f = force_at(&m, &v, &x, truth);
                let run = |label: f64| Run {
                    velocity_m_s: &v,
                    position_m: Some(&x),
                    force_n: &f,
                    label,
                    label_alphas: None,
                };
                let fit = identify(&m, &run(grid.alphas[k]), &grid, 1e-4, 100).expect("fit");
                let what = format!("{} at {truth}", kind.name());
                assert_eq!(fit.best, Some(grid.alphas[k]), "{what}: {:?}", fit.curve_n);
                // The force runs to about 2 kN: nothing but last-bit differences.
                assert!(fit.rmse_best_n <= 1e-3, "{what}: {}", fit.rmse_best_n);
                assert_eq!(fit.curve_n[k], fit.rmse_best_n, "{what}");
                assert!(fit.rmse_label_n <= 1e-3, "{what}: {}", fit.rmse_label_n);
                assert_eq!((fit.curve_n.len(), fit.samples), (31, 3900), "{what}");
                assert!(fit.within(0.0), "{what}");
                // Every other level errs.
                assert!(
                    fit.curve_n
                        .iter()
                        .enumerate()
                        .all(|(j, &e)| j == k || e > 100.0 * fit.rmse_best_n),
                    "{what}: {:?}",
                    fit.curve_n
                );
                // Labelled 0.15: the fit is still the truth, the label's error is not 0.
                let other = identify(&m, &run(0.15), &grid, 1e-4, 100).expect("fit");
                assert_eq!(other.best, fit.best, "{what}");
                assert!(other.rmse_label_n > 0.0, "{what}");
                assert_eq!(other.within(0.03), (f64::from(truth) - 0.15).abs() <= 0.03);
            }
        }
    }

    #[test]
    fn a_model_without_alpha_dependence_has_a_flat_curve_and_no_best_fit() {
        let (v, x) = sine();
        let grid = AlphaGrid::new(0.01, 0.3).expect("grid");
        // The Linear EMM, and the example NEMM with the alpha column of every scaler's first
        // layer zeroed.
        let mut constant = model(ModelKind::Nemm);
        if let Body::Nemm {
            b_fl, b_pr, k_pr, ..
        } = &mut constant.body
        {
            for s in [b_fl, b_pr, k_pr] {
                s.mlp.clear_alpha_column();
            }
        }
        let measured = force_at(&model(ModelKind::Nemm), &v, &x, 0.1);
        let runs: Vec<Run<'_>> = (0..3)
            .map(|_| Run {
                velocity_m_s: &v,
                position_m: Some(&x),
                force_n: &measured,
                label: 0.1,
                label_alphas: None,
            })
            .collect();
        for m in [model(ModelKind::LinearEmm), constant] {
            let fits = identify_runs(&m, &runs, &grid, 1e-4, 100).expect("fits");
            for fit in &fits {
                assert_eq!(fit.best, None, "{}: {:?}", m.kind().name(), fit.curve_n);
                assert!(is_flat(&fit.curve_n) && fit.rmse_best_n > 0.0);
                assert!(!fit.within(1.0));
            }
            assert_eq!(fits[0], fits[2], "runs in parallel give the same fits");
        }
        assert!(is_flat(&[2.0, 2.0 * (1.0 - 0.9 * FLAT_TOLERANCE)]));
        assert!(!is_flat(&[2.0, 2.0 * (1.0 - 1.1 * FLAT_TOLERANCE)]));
    }
}
