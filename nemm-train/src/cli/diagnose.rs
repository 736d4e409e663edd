//! `nemm diagnose`: the online alpha observer over recorded runs against the offline best fit
//! of the same model (`crate::report::diagnose`), as a table, `diagnose.json` and one
//! alpha(t) figure per run; the accuracy tables (`crate::report::accuracy`); and, with
//! `--level-step`, a record whose level steps (`crate::report::level_step`).

use crate::cli::identify::runs_matching;
use crate::data::against_model::check_runs_against_model;
use crate::data::preprocess::causal_velocity;
use crate::output_guard::{self, Inputs, Output};
use crate::report::accuracy::{
    accuracy_markdown, error_detail, error_summary, resolution, run_error, AccuracyReport, FROM_S,
};
use crate::report::diagnose::{
    alpha_figure, diagnose_run, figure_file, observe, observer_inputs, run_file, summary_line,
    table_markdown, DiagnoseReport, RunDiagnosis, Trace, AGREEMENT,
};
use crate::report::level_step::{
    join, level_step, level_step_figure, level_step_markdown, LevelStep,
};
use anyhow::{bail, Context, Result};
use nemm_core::Model;
use nemm_dataset::atomic_file::write_atomic_bytes;
use nemm_dataset::{self as dataset, Dataset};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The diagnosis's file in the `--report` folder.
pub(crate) const DIAGNOSE_JSON: &str = "diagnose.json";

/// The accuracy tables ([`accuracy_markdown`]) in the `--report` folder.
pub(crate) const ACCURACY_MD: &str = "accuracy.md";

/// The accuracy figures ([`AccuracyReport`]) in the `--report` folder.
pub(crate) const ACCURACY_JSON: &str = "accuracy.json";

/// The level step ([`LevelStep`]) in the `--report` folder, with `level-step.md` and
/// `level-step.png`.
pub(crate) const LEVEL_STEP_JSON: &str = "level-step.json";

/// The longest level-step record `--step-repeat` may make (samples): 1000 s at 10 kHz.
pub(crate) const MAX_STEP_SAMPLES: usize = 10_000_000;

/// What `nemm diagnose` is asked.
#[derive(Debug, Clone)]
pub struct DiagnoseArgs {
    /// The weights blob.
    pub model: PathBuf,
    /// The dataset folder.
    pub data: PathBuf,
    /// Globs selecting the runs to diagnose (every run when empty).
    pub runs: Vec<String>,
    /// The report folder.
    pub report: PathBuf,
    /// The two runs of a level step (files as for `runs`, each matching one run).
    pub level_step: Option<[String; 2]>,
    /// Times each run's steady part is played in the level step.
    pub step_repeat: usize,
}

/// `nemm diagnose`: checks the report folder, loads the model blob and the dataset (as
/// recorded: no preprocessing), diagnoses the selected runs (every run without patterns),
/// prints the table, the summary lines and the ordering counts of the resolution table, and,
/// with a level step, joins
/// its two runs and runs the observer over the record. Writes one `alpha_<run>.png` per run,
/// the level step's files, `ACCURACY_MD`, `ACCURACY_JSON` and then `DIAGNOSE_JSON` into
/// the report folder. Nothing is written when an input is bad.
pub fn diagnose(args: &DiagnoseArgs) -> Result<()> {
    let inputs = Inputs::new()
        .path("--model", &args.model)
        .dataset("--data", &args.data);
    output_guard::check(
        &[Output::folder("--report", &args.report)],
        &inputs,
        false,
        "",
    )?;
    let model = load_model(&args.model)?;
    let ds = load_dataset(&args.data, &model)?;
    let selected = select_runs(&ds, &args.runs, &args.data)?;
    let step_runs = args
        .level_step
        .as_ref()
        .map(|files| step_pair(&ds, files, args.step_repeat))
        .transpose()?;
    let mut checked = selected.clone();
    checked.extend(step_runs.iter().flatten());
    checked.sort_unstable();
    checked.dedup();
    check_runs_against_model(
        &model,
        &ds,
        &checked,
        |i| causal_velocity(&ds.runs[i].displacement_m, ds.sample_rate_hz),
        false,
    )?;
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
    let accuracy = accuracy_report(&ds, &selected, &results);
    println!("{}\n{}", accuracy.summary, accuracy.detail);
    for line in accuracy.resolution.count_lines() {
        println!("{line}");
    }
    let step = step_runs
        .map(|pair| diagnose_level_step(&model, &ds, pair, args.step_repeat, &results))
        .transpose()?;
    if let Some((s, _)) = &step {
        print!("{}", level_step_markdown(s));
    }
    eprintln!(
        "diagnosed {} runs ({} samples) in {:.1} s",
        results.len(),
        results.iter().map(|(_, t)| t.alpha.len()).sum::<usize>(),
        t.elapsed().as_secs_f64()
    );
    write_report(&args.report, &model, &results, &accuracy, step.as_ref())?;
    let json = args.report.join(DIAGNOSE_JSON);
    write_atomic_bytes(&json, serde_json::to_string_pretty(&out)?.as_bytes())
        .with_context(|| format!("cannot write {}", json.display()))?;
    println!(
        "wrote {}, {ACCURACY_MD}, {ACCURACY_JSON}{} and {} figures (alpha_*.png)",
        json.display(),
        if step.is_some() {
            ", level-step.{json,md,png}"
        } else {
            ""
        },
        results.len()
    );
    Ok(())
}

/// The model blob at `path`.
fn load_model(path: &Path) -> Result<Model> {
    let blob =
        std::fs::read(path).with_context(|| format!("--model: cannot read {}", path.display()))?;
    nemm_core::decode(&blob)
        .map_err(|e| anyhow::anyhow!("--model {}: not a NEMM model blob ({e})", path.display()))
}

/// The dataset in `data`, refused unless it is sampled at the model's rate.
fn load_dataset(data: &Path, model: &Model) -> Result<Dataset> {
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
    Ok(ds)
}

/// The runs of `ds` matching one of `runs` (every run without patterns); an error when none.
fn select_runs(ds: &Dataset, runs: &[String], data: &Path) -> Result<Vec<usize>> {
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
    Ok(selected)
}

/// The runs of `ds` matching the level step's `files`, refused before any work unless they
/// can be joined.
fn step_pair(ds: &Dataset, files: &[String; 2], repeat: usize) -> Result<[usize; 2]> {
    let pair = [find_run(ds, &files[0])?, find_run(ds, &files[1])?];
    // Each run's steady part is at most the run: the record's length is bounded before it is
    // built.
    let most = (ds.runs[pair[0]].len() + ds.runs[pair[1]].len()).checked_mul(repeat);
    if most.is_none_or(|n| n > MAX_STEP_SAMPLES) {
        bail!(
            "--step-repeat {repeat}: the level step's record could take up to {} samples ({} \
             and {} samples per play); at most {MAX_STEP_SAMPLES}: give a --step-repeat of at \
             most {}",
            most.map_or("more than 2^64".to_string(), |n| n.to_string()),
            ds.runs[pair[0]].len(),
            ds.runs[pair[1]].len(),
            MAX_STEP_SAMPLES / (ds.runs[pair[0]].len() + ds.runs[pair[1]].len()).max(1)
        );
    }
    join(&ds.runs[pair[0]], &ds.runs[pair[1]], repeat).context("--level-step")?;
    Ok(pair)
}

/// The one run of `ds` whose file matches `pattern`.
fn find_run(ds: &Dataset, pattern: &str) -> Result<usize> {
    let found = runs_matching(
        ds.runs.iter().map(|r| r.entry.file.as_path()),
        &[pattern.to_string()],
    )
    .context("--level-step")?;
    match found[..] {
        [i] => Ok(i),
        _ => bail!(
            "--level-step {pattern}: matches {} runs, not one",
            found.len()
        ),
    }
}

/// The accuracy figures of the diagnosed runs `results` (runs `selected` of `ds`).
fn accuracy_report(
    ds: &Dataset,
    selected: &[usize],
    results: &[(RunDiagnosis, Trace)],
) -> AccuracyReport {
    let runs: Vec<_> = results.iter().map(|(d, t)| run_error(d, t)).collect();
    let pairs: Vec<_> = results
        .iter()
        .zip(selected)
        .map(|((d, _), &i)| (d, &ds.runs[i].entry))
        .collect();
    AccuracyReport {
        from_s: FROM_S,
        tolerance: AGREEMENT,
        summary: error_summary(&runs),
        detail: error_detail(&runs),
        runs,
        resolution: resolution(&pairs),
    }
}

/// The level step of runs `pair` of `ds`, each steady part played `repeat` times; each run's
/// offline fit is taken from `results` where it was diagnosed, else diagnosed here.
fn diagnose_level_step(
    model: &Model,
    ds: &Dataset,
    pair: [usize; 2],
    repeat: usize,
    results: &[(RunDiagnosis, Trace)],
) -> Result<(LevelStep, Trace)> {
    let diagnosis = |i: usize| -> Result<RunDiagnosis> {
        let file = run_file(&ds.runs[i]);
        match results.iter().find(|(d, _)| d.file == file) {
            Some((d, _)) => Ok(d.clone()),
            None => diagnose_run(model, ds, i).map(|(d, _)| d),
        }
    };
    let (first, second) = (diagnosis(pair[0])?, diagnosis(pair[1])?);
    let joined = join(&ds.runs[pair[0]], &ds.runs[pair[1]], repeat)?;
    let (velocity, position) = observer_inputs(&joined.displacement_m, ds.sample_rate_hz);
    let trace = observe(model, &velocity, &position, &joined.force_n)?;
    let step = level_step(
        &joined,
        [(&first, &joined.first), (&second, &joined.second)],
        &trace,
        repeat,
    );
    Ok((step, trace))
}

/// Writes the figures, the accuracy files and the level step's files into `report`.
fn write_report(
    report: &Path,
    model: &Model,
    results: &[(RunDiagnosis, Trace)],
    accuracy: &AccuracyReport,
    step: Option<&(LevelStep, Trace)>,
) -> Result<()> {
    std::fs::create_dir_all(report)
        .with_context(|| format!("cannot create {}", report.display()))?;
    let range = (
        f64::from(model.meta.alpha_min),
        f64::from(model.meta.alpha_max),
    );
    let write = |name: &str, bytes: &[u8]| {
        let path = report.join(name);
        write_atomic_bytes(&path, bytes).with_context(|| format!("cannot write {}", path.display()))
    };
    for (d, trace) in results {
        let path = report.join(figure_file(&d.file));
        alpha_figure(d, trace, range)
            .save_png(&path)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some((s, trace)) = step {
        let path = report.join("level-step.png");
        level_step_figure(s, trace, range)
            .save_png(&path)
            .with_context(|| format!("cannot write {}", path.display()))?;
        write("level-step.md", level_step_markdown(s).as_bytes())?;
        write(LEVEL_STEP_JSON, serde_json::to_string_pretty(s)?.as_bytes())?;
    }
    write(ACCURACY_MD, accuracy_markdown(accuracy).as_bytes())?;
    write(
        ACCURACY_JSON,
        serde_json::to_string_pretty(accuracy)?.as_bytes(),
    )
}
