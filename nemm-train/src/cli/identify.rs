//! `nemm identify`: the best-fit level of every run of a dataset for a trained model, and
//! the model's whole-run error per level and run ([`crate::report::identify`]).

use crate::atomic_file::write_atomic_bytes;
use crate::cli::train::{load_dataset_prepared, IDENTIFY_MD};
use crate::config::{resolve_data, DataConfig};
use crate::data::preprocess::{file_matches, Prepared};
use crate::report::identify::{identify_markdown, identify_report, used_runs, whole_run_markdown};
use anyhow::{bail, Context, Result};
use std::path::Path;
use std::time::Instant;

/// The identification's file in a `nemm identify --report` folder.
pub const IDENTIFY_JSON: &str = "identify.json";

/// The positions in `files` (run files, paths relative to the manifest) of those matched by
/// one of the glob `patterns` on the path or the file name
/// ([`crate::data::preprocess::file_matches`]); a pattern that is not a glob is an error
/// naming it.
pub fn runs_matching<'a>(
    files: impl IntoIterator<Item = &'a Path>,
    patterns: &[String],
) -> Result<Vec<usize>> {
    let globs = patterns
        .iter()
        .map(|p| glob::Pattern::new(p).with_context(|| format!("--runs {p:?}: not a glob")))
        .collect::<Result<Vec<_>>>()?;
    Ok(files
        .into_iter()
        .enumerate()
        .filter(|(_, f)| file_matches(&globs, f))
        .map(|(i, _)| i)
        .collect())
}

/// The dataset indices of the runs of `prepared` whose file (path relative to the manifest,
/// or file name) matches one of `patterns`; without patterns, every run the split uses.
pub fn select_runs(prepared: &Prepared, patterns: &[String]) -> Result<Vec<usize>> {
    if patterns.is_empty() {
        return Ok(used_runs(prepared));
    }
    let files: Vec<&Path> = prepared
        .runs
        .iter()
        .map(|r| r.summary.file.as_path())
        .collect();
    Ok(runs_matching(files, patterns)?
        .into_iter()
        .map(|k| prepared.runs[k].summary.index)
        .collect())
}

/// `nemm identify`: loads the blob `model_path` and the dataset of `data` (its data options
/// resolved as every command does), identifies the runs matched by `runs` (every run the
/// split uses without patterns) on a grid of step `step`, prints the tables and, with
/// `report`, writes [`IDENTIFY_JSON`] and `identify.md` there. The normalised RMSE divides
/// by the model's training force scale.
pub fn identify(
    model_path: &Path,
    data: &DataConfig,
    runs: &[String],
    step: f64,
    report: Option<&Path>,
) -> Result<()> {
    let blob = std::fs::read(model_path)
        .with_context(|| format!("cannot read {}", model_path.display()))?;
    let model: nemm_core::Model =
        nemm_core::decode(&blob).map_err(|e| anyhow::anyhow!("{}: {e}", model_path.display()))?;
    let cfg = resolve_data(data)?.config;
    let (ds, prepared) = load_dataset_prepared(cfg.require_dir()?, &cfg.prepare_config())?;
    let selected = select_runs(&prepared, runs)?;
    if selected.is_empty() {
        bail!(
            "no run to identify (--runs {} matches none of the {} runs)",
            runs.join(" "),
            prepared.runs.len()
        );
    }
    let force_scale = f64::from(model.meta.force_scale_n);
    let t = Instant::now();
    let id = identify_report(
        &[(model.kind(), &model)],
        &ds,
        &prepared,
        &selected,
        step,
        force_scale,
    )?;
    let md = format!("{}\n{}", identify_markdown(&id), whole_run_markdown(&id));
    print!("{md}");
    println!(
        "identified {} runs ({} samples) in {:.1} s",
        selected.len(),
        id.variants
            .values()
            .next()
            .map_or(0, |f| f.fits.iter().map(|f| f.samples).sum::<usize>()),
        t.elapsed().as_secs_f64()
    );
    if let Some(dir) = report {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        write_atomic_bytes(
            &dir.join(IDENTIFY_JSON),
            serde_json::to_string_pretty(&id)?.as_bytes(),
        )?;
        write_atomic_bytes(&dir.join(IDENTIFY_MD), md.as_bytes())?;
        println!(
            "wrote {} and {}",
            dir.join(IDENTIFY_JSON).display(),
            dir.join(IDENTIFY_MD).display()
        );
    }
    Ok(())
}
