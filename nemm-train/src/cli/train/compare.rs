//! `nemm compare`: all four variants on one split, Table 4, the figures and the identifiability tables.

use super::*;

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
/// ([`crate::report::identify`], `identify.md`), one blob per variant, the figures and the
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
        &cfg.pipeline_config(),
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
    let reference = bench_reference(&cfg.data.dir);
    if let (Some(r), Some(tv)) = (
        &reference,
        exported.iter().find(|t| t.variant == ModelKind::Nemm),
    ) {
        report.bench_reference = Some(crate::report::reference::compare(&tv.model, r));
    }
    for (v, reason) in failed {
        report.failed.insert(v.key().to_string(), reason);
    }
    let trained: Vec<TrainedVariant> = exported
        .into_iter()
        .filter(|tv| report.variants.contains_key(tv.variant.key()))
        .collect();
    let models: Vec<(ModelKind, &nemm_core::Model)> =
        trained.iter().map(|tv| (tv.variant, &*tv.model)).collect();
    match identify_report(
        &models,
        ds,
        prepared,
        &used_runs(prepared),
        crate::train::identify::DEFAULT_STEP,
        crate::train::identify::Search::CoarseToFine,
        prepared.scales.force_n,
    ) {
        Ok(id) => report.identify = Some(id),
        Err(e) => eprintln!("warning: no identifiability tables: {e:#}"),
    }
    let signature = match signature_loops(&models, ds, prepared, &used_runs(prepared)) {
        Ok(loops) => {
            report.signature = Some(signature_report(&loops));
            Some(loops)
        }
        Err(e) => {
            eprintln!("warning: no degradation signature: {e:#}");
            None
        }
    };
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
    let predictions = crate::report::predictions::RunPredictions::for_figures(&trained, prepared)?;
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

/// The virtual bench's reference coefficients when `dir` holds a dataset generated by
/// `nemm bench generate` (its `bench.toml`); `None` for other data, or with a warning when the
/// file cannot be read.
fn bench_reference(dir: &Path) -> Option<crate::bench::reference::EmmReference> {
    match crate::bench::reference::for_dataset(dir) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("warning: no bench reference for {}: {e:#}", dir.display());
            None
        }
    }
}

/// The degradation signature's figure ([`crate::report::signature::signature_figure`]) in
/// `report_dir`; a failure is a warning (the tables are written already).
fn write_signature_figure(
    loops: &crate::report::signature::SignatureLoops,
    report_dir: &Path,
    force_scale_n: f64,
) {
    let path = report_dir.join(SIGNATURE_FIGURE);
    if let Some(fig) = crate::report::signature::signature_figure(loops, force_scale_n) {
        if let Err(e) = fig.save_png(&path) {
            eprintln!("warning: no {}: {e:#}", path.display());
        }
    }
}
