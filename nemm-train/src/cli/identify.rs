//! `nemm identify`: the best-fit level of every run of a dataset for a trained model, and
//! the model's whole-run error per level and run (`crate::report::identify`).

use crate::cli::train::IDENTIFY_MD;
use crate::config::{resolve_data, DataConfig};
use crate::data::against_model::check_runs_against_model;
use crate::data::load_dataset_prepared;
use crate::data::preprocess::{file_matches, Prepared, ALPHA_TOLERANCE};
use crate::output_guard::{self, Inputs, Output};
use crate::report::identify::{identify_markdown, identify_report, used_runs, whole_run_markdown};
use crate::train::identify::Search;
use anyhow::{bail, Context, Result};
use nemm_dataset::atomic_file::write_atomic_bytes;
use nemm_dataset::short_number;
use std::path::Path;
use std::time::Instant;

/// The identification's file in a `nemm identify --report` folder.
pub(crate) const IDENTIFY_JSON: &str = "identify.json";

/// The positions in `files` (run files, paths relative to the manifest) of those matched by
/// one of the glob `patterns` on the path or the file name
/// ([`crate::data::preprocess::file_matches`]); a pattern that is not a glob, or that
/// matches no file (even when another pattern does), is an error naming it.
pub(crate) fn runs_matching<'a>(
    files: impl IntoIterator<Item = &'a Path>,
    patterns: &[String],
) -> Result<Vec<usize>> {
    let globs = patterns
        .iter()
        .map(|p| glob::Pattern::new(p).with_context(|| format!("--runs {p:?}: not a glob")))
        .collect::<Result<Vec<_>>>()?;
    let files: Vec<&Path> = files.into_iter().collect();
    for (p, g) in patterns.iter().zip(&globs) {
        if !files
            .iter()
            .any(|f| file_matches(std::slice::from_ref(g), f))
        {
            let like: Vec<String> = files
                .iter()
                .take(3)
                .map(|f| f.display().to_string())
                .collect();
            bail!(
                "--runs {p:?} matches none of the {} runs (the files are named like {}); give \
                 a glob on the path relative to the manifest or on the file name",
                files.len(),
                like.join(", ")
            );
        }
    }
    Ok(files
        .into_iter()
        .enumerate()
        .filter(|(_, f)| file_matches(&globs, f))
        .map(|(i, _)| i)
        .collect())
}

/// The dataset indices of the runs of `prepared` whose file (path relative to the manifest,
/// or file name) matches one of `patterns`; without patterns, every run the split uses.
pub(crate) fn select_runs(prepared: &Prepared, patterns: &[String]) -> Result<Vec<usize>> {
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

/// The most levels of `nemm identify`'s grid (a step of 1/1000 of the trained range).
pub(crate) const MAX_GRID_LEVELS: usize = 1001;

/// Checks identify's grid of step `step` for `model` before it is built: at most
/// [`MAX_GRID_LEVELS`] levels, and each of `levels` (`what`: what they are) on it, so that the
/// best fit can land on them (`nemm identify` refuses a grid without the model's trained
/// range's ends and warns of one without a run's label).
pub(crate) fn check_grid(
    model: &nemm_core::Model,
    step: f64,
    levels: impl IntoIterator<Item = f64>,
    what: &str,
) -> Result<()> {
    let max = f64::from(model.meta.alpha_max);
    let max = if max > 0.0 { max.min(1.0) } else { 1.0 };
    let (shown, top) = (short_number(step), max as f32);
    if !(step.is_finite() && step > 0.0) {
        bail!("--step {shown}: the grid step must be a finite number > 0");
    }
    let count = max / step + 1.0;
    if count > MAX_GRID_LEVELS as f64 {
        bail!(
            "--step {shown}: a grid of {count:.0} levels over 0..{top}; at most \
             {MAX_GRID_LEVELS} (a step of at least {})",
            short_number(max / (MAX_GRID_LEVELS - 1) as f64)
        );
    }
    for level in levels {
        let k = level / step;
        if (k - k.round()).abs() * step > ALPHA_TOLERANCE {
            let divides = max / (max / step).ceil().max(1.0);
            bail!(
                "--step {shown}: the grid 0, {shown}, ... up to {top} does not contain {what} \
                 {}, so the best fit could never equal it; give a step that divides it, \
                 e.g. --step {}",
                level as f32,
                (divides * 1e6).round() / 1e6
            );
        }
    }
    Ok(())
}

/// `nemm identify`: loads the blob `model_path` and the dataset of `data` (its data options
/// resolved as every command does), identifies the runs matched by `runs` (every run the
/// split uses without patterns) on a grid of step `step` searched by `search`, prints the
/// tables and, with `report`, writes `IDENTIFY_JSON` and `identify.md` there. The
/// normalised RMSE divides by the model's training force scale.
pub fn identify(
    model_path: &Path,
    data: &DataConfig,
    runs: &[String],
    step: f64,
    search: Search,
    report: Option<&Path>,
) -> Result<()> {
    if let Some(dir) = report {
        let inputs = Inputs::new()
            .path("--model", model_path)
            .dataset("--data", data.require_dir()?);
        output_guard::check(&[Output::folder("--report", dir)], &inputs, false, "")?;
    }
    let blob = std::fs::read(model_path)
        .with_context(|| format!("cannot read {}", model_path.display()))?;
    let model: nemm_core::Model =
        nemm_core::decode(&blob).map_err(|e| anyhow::anyhow!("{}: {e}", model_path.display()))?;
    let trained = [model.meta.alpha_min, model.meta.alpha_max].map(f64::from);
    check_grid(&model, step, trained, "the model's trained level")?;
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
    check_runs_against_model(
        &model,
        &ds,
        &selected,
        |i| prepared.signals[i].velocity_m_s.clone(),
        cfg.accept_implausible.unwrap_or(false),
    )?;
    let max = f64::from(model.meta.alpha_max);
    let labels = selected
        .iter()
        .filter(|&&i| ds.runs[i].alpha.is_none())
        .map(|&i| ds.runs[i].entry.oil_loss)
        .filter(|&a| a <= max + ALPHA_TOLERANCE);
    for label in labels {
        if let Err(e) = check_grid(&model, step, [label], "the level of a run") {
            eprintln!("warning: {e}");
            break;
        }
    }
    let force_scale = f64::from(model.meta.force_scale_n);
    let t = Instant::now();
    let id = identify_report(
        &[(model.kind(), &model)],
        &ds,
        &prepared,
        &selected,
        step,
        search,
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
