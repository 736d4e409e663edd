//! Wall time of identifying the level of every run with the NEMM (`nemm identify`, the
//! identifiability step of `nemm compare`) beside the NEMM's training time on the same data:
//! the full grid against the coarse-to-fine search, and whether their best fits agree (a
//! benchmark that prints, not a timed test).
//!
//! ```text
//! cargo bench -p nemm-train --bench identify_time      # generates the bench data, trains the NEMM
//! NEMM_BENCH_DATA=DIR NEMM_BENCH_MODEL=DIR/nemm.nemm cargo bench -p nemm-train --bench identify_time
//! ```
//!
//! Without `NEMM_BENCH_MODEL` the NEMM is trained here with the default settings of
//! `nemm train --variant nemm` and its training is timed. With it, the training time is the
//! NEMM's `train_seconds` in the `report.json` beside the blob (as `nemm compare` writes it),
//! or absent. Every run the split uses is identified, on the grid of step 0.01 (or
//! `NEMM_BENCH_STEP`) up to the model's largest training level, once per search; the runs
//! whose best fits differ by more than 0.01 are listed.
mod common;

use nemm_core::ModelKind;
use nemm_train::config::{resolve_data, Config};
use nemm_train::report::{identify_report, used_runs, IdentifyReport};
use nemm_train::train::identify::{Search, DEFAULT_STEP};
use nemm_train::train::pipeline::{train_variants, PipelineConfig};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The NEMM's training time recorded in the `report.json` beside `blob`, if any.
fn recorded_training_seconds(blob: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(blob.parent()?.join("report.json")).ok()?;
    let report: serde_json::Value = serde_json::from_str(&text).ok()?;
    report["variants"]["nemm"]["train_seconds"].as_f64()
}

/// The load averages over 1, 5 and 15 minutes (`/proc/loadavg`), or `-` where unknown: the
/// timings depend on what else runs.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(","))
        .unwrap_or_else(|| "-".into())
}

/// Level simulations of a report's single model.
fn simulated(r: &IdentifyReport) -> usize {
    r.variants
        .values()
        .flat_map(|v| &v.fits)
        .map(|f| f.levels.len())
        .sum()
}

fn main() {
    // `cargo bench` passes `--bench`; nothing else is accepted.
    let data = common::bench_data();
    let config = Config::default();
    let data_config = resolve_data(&config.data.in_dir(&data))
        .expect("data options")
        .config;
    let (ds, prepared) =
        nemm_train::data::load_dataset_prepared(&data, &data_config.prepare_config())
            .expect("dataset");
    let (model, training_seconds, source) = match std::env::var_os("NEMM_BENCH_MODEL") {
        Some(path) => {
            let path = PathBuf::from(path);
            let blob = std::fs::read(&path).expect("read the model blob");
            let model = nemm_core::decode(&blob).expect("decode the model blob");
            let seconds = recorded_training_seconds(&path);
            (model, seconds, format!("{}", path.display()))
        }
        None => {
            let t = Instant::now();
            let trained = train_variants(
                &prepared,
                &[ModelKind::Nemm],
                &PipelineConfig::of(&config),
                None,
                false,
            )
            .expect("train");
            let seconds = t.elapsed().as_secs_f64();
            let nemm = trained
                .into_iter()
                .find(|t| t.variant == ModelKind::Nemm)
                .expect("nemm");
            ((*nemm.model).clone(), Some(seconds), "trained here".into())
        }
    };
    let step: f64 = std::env::var("NEMM_BENCH_STEP")
        .map(|s| s.parse().expect("NEMM_BENCH_STEP: a number"))
        .unwrap_or(DEFAULT_STEP);
    let runs = used_runs(&prepared);
    let force_scale = f64::from(model.meta.force_scale_n);
    let identify = |search: Search| {
        let t = Instant::now();
        let r = identify_report(
            &[(ModelKind::Nemm, &model)],
            &ds,
            &prepared,
            &runs,
            step,
            search,
            force_scale,
        )
        .expect("identify");
        (r, t.elapsed().as_secs_f64())
    };
    let (full, full_s) = identify(Search::Full);
    let (fast, fast_s) = identify(Search::CoarseToFine);
    let grid = full.variants["nemm"].grid.len();
    let training = training_seconds.map_or("-".into(), |s| format!("{s:.1}"));
    let share = |s: f64| training_seconds.map_or("-".into(), |t| format!("{:.1}", 100.0 * s / t));
    println!(
        "identify-time model={source} data={} threads={} runs={} step={step} \
         grid_levels={grid} training_seconds={training} load_average={}",
        data.display(),
        rayon::current_num_threads(),
        runs.len(),
        load_average(),
    );
    for (search, r, s) in [
        (Search::Full, &full, full_s),
        (Search::CoarseToFine, &fast, fast_s),
    ] {
        println!(
            "identify-time search={} seconds={s:.1} simulated_levels={} percent_of_training={}",
            search.name(),
            simulated(r),
            share(s)
        );
    }
    let (full_fits, fast_fits) = (&full.variants["nemm"].fits, &fast.variants["nemm"].fits);
    let mut differ = Vec::new();
    let mut max_difference = 0.0f64;
    for ((run, a), b) in full.runs.iter().zip(full_fits).zip(fast_fits) {
        let difference = match (a.best, b.best) {
            (Some(x), Some(y)) => (x - y).abs(),
            (None, None) => 0.0,
            _ => f64::INFINITY,
        };
        max_difference = max_difference.max(difference);
        if difference > DEFAULT_STEP + 1e-9 {
            differ.push(format!(
                "{}: full {:?}, coarse-to-fine {:?}",
                run.file, a.best, b.best
            ));
        }
    }
    let flat = |fits: &[nemm_train::train::identify::Fit]| {
        fits.iter().filter(|f| f.best.is_none()).count()
    };
    println!(
        "identify-time agreement runs={} identical={} within_0.01={} max_difference={max_difference:.3} \
         flat_full={} flat_coarse_to_fine={} speedup={:.2}",
        full_fits.len(),
        full_fits
            .iter()
            .zip(fast_fits)
            .filter(|(a, b)| a.best == b.best)
            .count(),
        full_fits.len() - differ.len(),
        flat(full_fits),
        flat(fast_fits),
        full_s / fast_s
    );
    for d in &differ {
        println!("identify-time differs {d}");
    }
}
