//! `nemm demo`: the main job on the default virtual bench, on a budget of a few minutes.

use super::compare::compare;
use super::{
    dataset, estimator_input, load_dataset_prepared, output_guard, preprocess, table_vs_exact,
    with_resolved_data, Config, Inputs, Output, Prepared, VariantInfo,
};
use anyhow::{bail, Context, Result};
use nemm_core::ModelKind;
use std::path::PathBuf;
use std::time::Instant;

/// Where a demo keeps its data and results.
#[derive(Debug, Clone)]
pub struct DemoPaths {
    /// Dataset folder (generated if it has no manifest).
    pub data: PathBuf,
    /// Results folder.
    pub out: PathBuf,
}

/// `nemm demo`: virtual bench (generated if absent), all four variants on a budget of a few
/// minutes, Table 4, `model.nemm`, and the exported NEMM run through nemm-core on a
/// held-out run. The dataset (`paths.data`; `cfg.data.dir` is replaced by it) is loaded and
/// prepared once, for the comparison and the estimator check.
pub fn demo(paths: &DemoPaths, cfg: &Config) -> Result<()> {
    let t0 = Instant::now();
    let inputs = Inputs::new().dataset("--data", &paths.data);
    output_guard::check(&[Output::folder("--out", &paths.out)], &inputs, false, "")?;
    if !paths.data.join(dataset::MANIFEST_FILE).exists() {
        eprintln!(
            "no dataset in {}: generating the default virtual bench",
            paths.data.display()
        );
        crate::cli::bench::generate(
            &nemm_virtual_bench::config::BenchConfig::default(),
            1,
            &paths.data,
        )?;
    }
    let mut cfg = cfg.clone();
    cfg.data.dir = paths.data.clone();
    cfg.validate()?;
    let cfg = with_resolved_data(&cfg)?;
    let (ds, prepared) = load_dataset_prepared(&cfg.data.dir, &cfg.data.prepare_config())?;
    let report = compare(&ds, &prepared, &cfg, &paths.out, None, false)?;
    if let Some(reason) = report.failed.get(ModelKind::Nemm.key()) {
        bail!(
            "the NEMM failed ({reason}); Table 4 and the other variants are in {}",
            paths.out.display()
        );
    }
    let nemm_blob = paths.out.join("nemm.nemm");
    let model_path = paths.out.join("model.nemm");
    std::fs::copy(&nemm_blob, &model_path).with_context(|| {
        format!(
            "cannot copy {} to {}",
            nemm_blob.display(),
            model_path.display()
        )
    })?;
    // The exported blob through nemm-core on a held-out (test) run.
    let blob = std::fs::read(&model_path)?;
    let model: nemm_core::Model = nemm_core::decode(&blob).map_err(|e| anyhow::anyhow!("{e}"))?;
    print!(
        "{}",
        crate::train::table_check::report(&model, crate::train::table_check::DEFAULT_TABLE_BOUND)
    );
    estimator_on_held_out_run(&model, &ds, &prepared)?;
    table_vs_exact(&model, &ds, &prepared)?;
    let rmse = |kind: &str| report.variants.get(kind).map_or(f64::NAN, |v| v.rmse);
    let (nemm, sem) = (rmse("nemm"), rmse("sem"));
    println!(
        "demo done in {:.1} min: NEMM test RMSE {:.4} = {:.0} % of the SEM's; weights in {}",
        t0.elapsed().as_secs_f64() / 60.0,
        nemm,
        100.0 * nemm / sem,
        model_path.display()
    );
    Ok(())
}

/// The most dynamic run with test sequences: the highest frequency among those of small
/// amplitude (below 20 mm), else the first.
fn most_dynamic_test_run(prepared: &Prepared) -> Result<&preprocess::PreparedRun> {
    let test_runs: Vec<_> = prepared
        .runs
        .iter()
        .filter(|r| r.test_sequences > 0)
        .collect();
    let run = test_runs
        .iter()
        .filter(|r| r.summary.excitation.amplitude_m < 0.02)
        .max_by(|a, b| {
            a.summary
                .excitation
                .frequency_hz
                .unwrap_or(0.0)
                .total_cmp(&b.summary.excitation.frequency_hz.unwrap_or(0.0))
        })
        .or(test_runs.first())
        .context("no held-out test run")?;
    Ok(run)
}

/// Runs `model` through nemm-core's estimator over the whole of the most dynamic test run
/// from rest and prints its RMSE, its time per step on this host and its largest
/// difference to the trainer's simulation.
fn estimator_on_held_out_run(
    model: &nemm_core::Model,
    ds: &dataset::Dataset,
    prepared: &Prepared,
) -> Result<()> {
    let run = most_dynamic_test_run(prepared)?;
    let idx = run.summary.index;
    let what = if run.role == preprocess::RunRole::Test {
        "held-out run"
    } else {
        "run with a test tail (its training part included)"
    };
    let (u, x, alpha) = estimator_input(ds, prepared, idx)?;
    let mut est = nemm_core::Estimator::new(model, nemm_core::EstimatorConfig::new(alpha))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let input = crate::train::eval::Input {
        velocity_m_s: &u,
        alpha,
        alphas: None,
        position_m: Some(&x),
    };
    let t = Instant::now();
    let (forces, steps) =
        crate::train::eval::run_estimator(&mut est, f64::from(model.dt_s), &input, prepared.dt_s)?;
    let ns_per_step = t.elapsed().as_secs_f64() * 1e9 / steps.max(1) as f64;
    let fs = prepared.scales.force_n;
    let skip = prepared.warmup_samples.min(forces.len());
    let se: f64 = forces[skip..]
        .iter()
        .zip(&ds.runs[idx].force_n[skip..])
        .map(|(&y, &m)| ((y - m) / fs).powi(2))
        .sum();
    let rmse = (se / (forces.len() - skip).max(1) as f64).sqrt();
    let trainer = crate::train::eval::predict(model, &[input], prepared.dt_s)?;
    let parity = forces
        .iter()
        .zip(&trainer[0])
        .fold(0.0f64, |m, (&a, &b)| m.max((a - b).abs()))
        / fs;
    println!(
        "most dynamic {what} {} ({}, {:.0} mm, {:.1} Hz), whole run from rest: nemm-core estimator RMSE {:.4} ({:.1} N) over {} samples, {:.0} ns/step on this host; \
         max |nemm-core - trainer| = {:.2e} of the force scale",
        ds.runs[idx].entry.file.display(),
        ds.condition
            .clone()
            .unwrap_or_default()
            .level(f64::from(alpha)),
        run.summary.excitation.amplitude_m * 1e3,
        run.summary.excitation.frequency_hz.unwrap_or(f64::NAN),
        rmse,
        rmse * fs,
        forces.len(),
        ns_per_step,
        parity
    );
    Ok(())
}
