//! Whole-run force predictions of trained variants: the evaluation output the loop figures
//! draw (`report::figures::figure_predictions` simulates the runs they show).

use crate::data::preprocess::Prepared;
use crate::train::eval::{predict, Input};
use crate::train::pipeline::{TrainedVariant, VariantInfo};
use anyhow::{Context, Result};
use nemm_core::Model;
use nemm_core::ModelKind;

/// Forces of whole runs simulated from rest by a variant at the model's own step, on the
/// preprocessed velocity ([`Prepared::signals`]) at the run's condition level (per sample
/// when the run has an `alpha` column), one force per data sample.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunPredictions {
    /// `(variant, run index, force per sample [N])`.
    entries: Vec<(ModelKind, usize, Vec<f64>)>,
}

impl RunPredictions {
    /// Simulates each `(variant, run index)` of `requests` (one batch per variant, the
    /// variants in parallel). Requests of variants not in `trained` are left out; an unknown
    /// run index is an error.
    pub fn simulate(
        trained: &[TrainedVariant],
        prepared: &Prepared,
        requests: &[(ModelKind, usize)],
    ) -> Result<Self> {
        let models: Vec<(ModelKind, &Model)> =
            trained.iter().map(|tv| (tv.variant, &*tv.model)).collect();
        Self::simulate_models(&models, prepared, requests)
    }

    /// [`RunPredictions::simulate`] of models given by kind (an exported or loaded model
    /// needs no training history).
    pub(crate) fn simulate_models(
        models: &[(ModelKind, &Model)],
        prepared: &Prepared,
        requests: &[(ModelKind, usize)],
    ) -> Result<Self> {
        use rayon::prelude::*;
        let mut batches: Vec<(ModelKind, &Model, Vec<usize>)> = Vec::new();
        for &(v, run) in requests {
            let Some(&(_, model)) = models.iter().find(|(k, _)| *k == v) else {
                continue;
            };
            match batches.iter_mut().find(|(k, _, _)| *k == v) {
                Some((_, _, runs)) => runs.push(run),
                None => batches.push((v, model, vec![run])),
            }
        }
        let velocity: Vec<Vec<f32>> = prepared
            .signals
            .iter()
            .map(|s| s.velocity_m_s.iter().map(|&v| v as f32).collect())
            .collect();
        let positions: Vec<Vec<f32>> = prepared
            .signals
            .iter()
            .map(|s| s.displacement_m.iter().map(|&v| v as f32).collect())
            .collect();
        let alphas: Vec<Option<Vec<f32>>> = prepared
            .signals
            .iter()
            .map(|s| {
                s.alpha
                    .as_ref()
                    .map(|a| a.iter().map(|&v| v as f32).collect())
            })
            .collect();
        let simulated: Vec<Vec<(ModelKind, usize, Vec<f64>)>> = batches
            .par_iter()
            .map(|(variant, model, runs)| {
                let inputs = runs
                    .iter()
                    .map(|&i| {
                        let v = velocity.get(i).context("run not in the prepared set")?;
                        Ok(Input {
                            velocity_m_s: v,
                            alpha: prepared.runs[i].summary.alpha as f32,
                            alphas: alphas.get(i).and_then(|a| a.as_deref()),
                            position_m: positions.get(i).map(Vec::as_slice),
                        })
                    })
                    .collect::<Result<Vec<Input<'_>>>>()?;
                let ys = predict(model, &inputs, prepared.dt_s)
                    .with_context(|| format!("cannot simulate the {}", variant.title()))?;
                Ok(runs
                    .iter()
                    .zip(ys)
                    .map(|(&i, y)| (*variant, i, y))
                    .collect())
            })
            .collect::<Result<_>>()?;
        Ok(RunPredictions {
            entries: simulated.into_iter().flatten().collect(),
        })
    }

    /// The predicted force of `variant` over run `run`, if simulated.
    pub fn get(&self, variant: ModelKind, run: usize) -> Option<&[f64]> {
        self.entries
            .iter()
            .find(|(v, i, _)| *v == variant && *i == run)
            .map(|(_, _, y)| y.as_slice())
    }
}
