//! `nemm diagnose`: the online alpha observer over recorded runs against the offline best fit
//! of the same model ([`crate::report::diagnose`]), as a table, `diagnose.json` and one
//! alpha(t) figure per run.

use crate::atomic_file::write_atomic_bytes;
use crate::cli::identify::runs_matching;
use crate::cli::train::check_output_dir;
use crate::data::dataset;
use crate::report::diagnose::{
    alpha_figure, diagnose_run, figure_file, summary_line, table_markdown, DiagnoseReport,
};
use anyhow::{bail, Context, Result};
use std::path::Path;
use std::time::Instant;

/// The diagnosis's file in the `--report` folder.
pub const DIAGNOSE_JSON: &str = "diagnose.json";

/// `nemm diagnose`: checks the report folder `report`, loads the blob `model_path` and the
/// dataset in `data` (as recorded: no preprocessing), diagnoses the runs whose file matches
/// one of `runs` (every run without patterns), prints the table and the summary line, and
/// writes one `alpha_<run>.png` per run and then [`DIAGNOSE_JSON`] into `report`. Nothing is
/// written when an input is bad.
pub fn diagnose(model_path: &Path, data: &Path, runs: &[String], report: &Path) -> Result<()> {
    check_output_dir("--report", report)?;
    let blob = std::fs::read(model_path)
        .with_context(|| format!("--model: cannot read {}", model_path.display()))?;
    let model: nemm_core::Model = nemm_core::decode(&blob).map_err(|e| {
        anyhow::anyhow!(
            "--model {}: not a NEMM model blob ({e})",
            model_path.display()
        )
    })?;
    let ds = dataset::load(data)
        .with_context(|| format!("cannot load the dataset in {}", data.display()))?;
    let model_rate = 1.0 / f64::from(model.dt_s);
    if (ds.sample_rate_hz / model_rate - 1.0).abs() > 1e-6 {
        bail!(
            "the dataset in {} is sampled at {} Hz, the model steps at {model_rate:.0} Hz: the \
             observer takes one sample per model step (resample the runs to the model's rate)",
            data.display(),
            ds.sample_rate_hz
        );
    }
    let selected: Vec<usize> = if runs.is_empty() {
        (0..ds.runs.len()).collect()
    } else {
        runs_matching(ds.runs.iter().map(|r| r.entry.file.as_path()), runs)?
    };
    if selected.is_empty() {
        bail!(
            "no run to diagnose: --runs {} matches none of the {} runs in {}",
            runs.join(" "),
            ds.runs.len(),
            data.display()
        );
    }
    let t = Instant::now();
    let results = {
        use rayon::prelude::*;
        selected
            .par_iter()
            .map(|&i| diagnose_run(&model, &ds, i))
            .collect::<Result<Vec<_>>>()?
    };
    let out = DiagnoseReport {
        runs: results.iter().map(|(d, _)| d.clone()).collect(),
    };
    print!("{}", table_markdown(&out.runs));
    println!("{}", summary_line(&out.runs));
    eprintln!(
        "diagnosed {} runs ({} samples) in {:.1} s",
        results.len(),
        results.iter().map(|(_, t)| t.alpha.len()).sum::<usize>(),
        t.elapsed().as_secs_f64()
    );
    std::fs::create_dir_all(report)
        .with_context(|| format!("cannot create {}", report.display()))?;
    let range = (
        f64::from(model.meta.alpha_min),
        f64::from(model.meta.alpha_max),
    );
    for (d, trace) in &results {
        let path = report.join(figure_file(&d.file));
        alpha_figure(d, trace, range)
            .save_png(&path)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    let json = report.join(DIAGNOSE_JSON);
    write_atomic_bytes(&json, serde_json::to_string_pretty(&out)?.as_bytes())
        .with_context(|| format!("cannot write {}", json.display()))?;
    println!(
        "wrote {} and {} figures (alpha_*.png)",
        json.display(),
        results.len()
    );
    Ok(())
}
