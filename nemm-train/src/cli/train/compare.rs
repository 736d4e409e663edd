//! `nemm compare`: all four variants on one split, Table 4, the figures and the identifiability tables.

use super::identity::open_checkpoint;
use super::{
    check_job_outputs, dataset, dataset_provenance, evaluate, export_model, load_dataset_prepared,
    print_audit, record_provenance, table4_markdown, train_each, with_resolved_data, write_report,
    Config, PipelineConfig, Prepared, Report, TablesArgs, Trained, TrainedVariant, VariantInfo,
    CONFIG_FILE,
};
use crate::report::degradation::{degradation_report, write_signature_figure, Degradation};
use anyhow::{bail, Result};
use nemm_core::ModelKind;
use std::path::Path;
use std::time::Instant;

/// `nemm compare` from the command line: loads and prepares `cfg.data`, then [`compare`].
pub fn compare_command(
    cfg: &Config,
    report_dir: &Path,
    checkpoint: Option<&Path>,
    resume: bool,
) -> Result<Report> {
    check_job_outputs(cfg, None, Some(report_dir), checkpoint, false)?;
    let cfg = &with_resolved_data(cfg)?;
    let _lock = checkpoint
        .map(|dir| open_checkpoint(dir, cfg, resume))
        .transpose()?;
    let (ds, prepared) =
        load_dataset_prepared(cfg.data.require_dir()?, &cfg.data.prepare_config())?;
    compare(&ds, &prepared, cfg, report_dir, checkpoint, resume)
}

/// All four variants on a prepared dataset (`ds` is the dataset `prepared` was made from;
/// the figures need its whole runs): Table 4, `report.json`, the identifiability of the
/// level and the whole-run errors of every run the split uses
/// (`crate::report::identify`, `identify.md`), one blob per variant, the figures and the
/// effective `config.toml`, all in `report_dir`.
pub fn compare(
    ds: &dataset::Dataset,
    prepared: &Prepared,
    cfg: &Config,
    report_dir: &Path,
    checkpoint: Option<&Path>,
    resume: bool,
) -> Result<Report> {
    let cfg = &cfg.with_static_force_from(prepared);
    let t = Instant::now();
    let Trained {
        trained,
        failed: train_failed,
    } = train_each(
        prepared,
        &ModelKind::ALL,
        &PipelineConfig::of(cfg),
        checkpoint,
        resume,
    )?;
    std::fs::create_dir_all(report_dir)?;
    let mut failed: Vec<(ModelKind, String)> = train_failed
        .into_iter()
        .map(|f| (f.variant, f.reason))
        .collect();
    let mut exported = Vec::new();
    let dataset = dataset_provenance(ds, &cfg.data.dir);
    for tv in trained {
        let out = report_dir.join(format!("{}.nemm", tv.variant.name()));
        match export_model(&tv.model, &out, &dataset, &TablesArgs::default()) {
            Ok(_) => exported.push(tv),
            Err(e) => {
                eprintln!("[{}] export failed: {e:#}", tv.variant.name());
                failed.push((tv.variant, format!("export: {e:#}")));
            }
        }
    }
    let mut report = evaluate(&exported, prepared)?;
    for (v, reason) in failed {
        report.failed.insert(v.key().to_string(), reason);
    }
    let trained: Vec<TrainedVariant> = exported
        .into_iter()
        .filter(|tv| report.variants.contains_key(tv.variant.key()))
        .collect();
    let Degradation {
        reference,
        signature,
    } = degradation_report(&mut report, &trained, ds, prepared, &cfg.data.dir);
    record_provenance(&mut report);
    report
        .info
        .insert("dataset".into(), cfg.data.dir.display().to_string());
    report.info.insert(
        "total_seconds".into(),
        format!("{:.1}", t.elapsed().as_secs_f64()),
    );
    write_report(report_dir, &report, "table4.md")?;
    cfg.save(&report_dir.join(CONFIG_FILE))?;
    println!("{}", table4_markdown(&report));
    if trained.is_empty() {
        bail!(
            "every variant failed (reasons in {})",
            report_dir.join("table4.md").display()
        );
    }
    for tv in &trained {
        print_audit(tv, &report);
    }
    if let Some(c) = &report.bench_reference {
        println!("{}", c.markdown());
    }
    let predictions = crate::report::figures::figure_predictions(&trained, prepared)?;
    crate::report::figures::write_all_with_reference(
        &trained,
        ds,
        prepared,
        &report,
        &predictions,
        reference.as_ref(),
        report_dir,
    )?;
    if let Some(loops) = &signature {
        write_signature_figure(loops, report_dir, report.force_scale_n);
    }
    println!("report, models and figures in {}", report_dir.display());
    if !report.failed.is_empty() {
        eprintln!(
            "warning: {} of 4 variants failed (their rows in Table 4 give the reason): {}",
            report.failed.len(),
            report.failed.keys().cloned().collect::<Vec<_>>().join(", ")
        );
    }
    Ok(report)
}
