//! `nemm train`, `nemm export`, `nemm compare`, `nemm sweep`: training, export and the
//! Table 4 / Table 5 reports from the command line.

use crate::config::{lambda_ph_scale_note, resolve_data, Config, CONFIG_FILE};
use crate::data::dataset;
use crate::data::preprocess::{self, PrepareConfig, Prepared};
use crate::fsutil::write_atomic_bytes;
use crate::report::identify::{identify_markdown, identify_report, used_runs, whole_run_markdown};
use crate::report::inspect::describe;
use crate::report::tables::{evaluate, table4_markdown, test_runs_markdown, Report};
use crate::train::net::{EmmNet, NetFrame};
use crate::train::params::to_core;
use crate::train::pipeline::{
    train_each, train_variants, AlphaPriors, Trained, TrainedVariant, VariantInfo,
};
use anyhow::{bail, Context, Result};
use burn::module::Module;
use nemm_core::ModelKind;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Default `nemm sweep` list of physics weights: Table 5's 0, 0.005, 0.015, 0.025 times 1000.
pub const TABLE5_LAMBDAS: [f64; 4] = [0.0, 5.0, 15.0, 25.0];

/// Loads and prepares a dataset, printing a one-line summary.
pub fn load_prepared(dir: &Path, cfg: &PrepareConfig) -> Result<Prepared> {
    load_dataset_prepared(dir, cfg).map(|(_, p)| p)
}

/// Loads and prepares a dataset; returns both (figures need the whole runs).
pub fn load_dataset_prepared(
    dir: &Path,
    cfg: &PrepareConfig,
) -> Result<(dataset::Dataset, Prepared)> {
    let t = Instant::now();
    let ds = dataset::load(dir)
        .with_context(|| format!("cannot load the dataset in {}", dir.display()))?;
    let prepared = preprocess::prepare(&ds, cfg)?;
    eprintln!(
        "dataset {:?}: {} runs; {} train / {} validation / {} test windows of {} + {} warm-up samples; force scale {:.0} N ({:.1} s)",
        ds.name,
        ds.runs.len(),
        prepared.train.len(),
        prepared.validation.len(),
        prepared.test.len(),
        prepared.scored_samples,
        prepared.warmup_samples,
        prepared.scales.force_n,
        t.elapsed().as_secs_f64()
    );
    if prepared.test.is_empty() {
        eprintln!(
            "warning: no test windows ({}); test RMSE will be NaN",
            cfg.split.describe()
        );
    }
    Ok((ds, prepared))
}

/// `cfg` with its data options resolved for its dataset ([`resolve_data`], which prints
/// them): what a job runs with and saves as `config.toml`.
pub fn with_resolved_data(cfg: &Config) -> Result<Config> {
    let mut cfg = cfg.clone();
    cfg.data = resolve_data(&cfg.data)?.config;
    Ok(cfg)
}

/// Precomputed fast-path tables to store in an exported blob (the format's tables section,
/// `nemm_core::stored_tables`): a firmware in table mode at one of these oil-loss levels, with
/// the same segment count and bound, boots without building its tables.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct TablesArgs {
    /// Oil-loss levels alpha (comma-separated, each in [0, 1]; at most 4) whose fast-path
    /// tables the blob stores. A firmware in table mode at one of them reads its tables from
    /// the blob instead of building them at boot. None by default.
    #[arg(long, value_delimiter = ',')]
    pub tables_alpha: Vec<f32>,
    /// Segments per stored table: the `T` of the firmware's estimator (128, nemm-firmware's
    /// TABLE_SEGMENTS, or 256, nemm-core's default).
    #[arg(long, default_value_t = DEFAULT_STORED_TABLE_SEGMENTS)]
    pub tables_segments: usize,
    /// Relative error bound the stored tables are built and checked with (the firmware's
    /// TABLE_MAX_REL_ERROR; it must be the same bit for bit for the firmware to use them).
    #[arg(long, default_value_t = crate::train::table_check::DEFAULT_TABLE_BOUND)]
    pub tables_bound: f32,
}

/// Segments of stored tables unless told otherwise: the example firmware's (128).
pub const DEFAULT_STORED_TABLE_SEGMENTS: usize = 128;

impl Default for TablesArgs {
    fn default() -> Self {
        Self {
            tables_alpha: Vec::new(),
            tables_segments: DEFAULT_STORED_TABLE_SEGMENTS,
            tables_bound: crate::train::table_check::DEFAULT_TABLE_BOUND,
        }
    }
}

/// The blob of `model` with the tables of `tables` (none if it lists no levels).
fn encode_with_tables(model: &nemm_core::Model, tables: &TablesArgs) -> Result<Vec<u8>> {
    match tables.tables_segments {
        _ if tables.tables_alpha.is_empty() => {
            nemm_core::encode_to_vec(model).map_err(|e| anyhow::anyhow!("{e}"))
        }
        128 => encode_with_segments::<128>(model, tables),
        256 => encode_with_segments::<256>(model, tables),
        n => bail!("--tables-segments {n}: stored tables have 128 or 256 segments"),
    }
}

/// [`encode_with_tables`] with `T` segments per table: builds the estimator at each level in
/// table mode, as a firmware does at boot, and stores its tables.
fn encode_with_segments<const T: usize>(
    model: &nemm_core::Model,
    tables: &TablesArgs,
) -> Result<Vec<u8>> {
    use nemm_core::{Estimator, EstimatorConfig, EvalMode, TableConfig};
    if !matches!(model.kind(), ModelKind::NemmLight | ModelKind::Nemm) {
        bail!(
            "--tables-alpha: a {} model has no neural coefficients to tabulate",
            model.kind().name()
        );
    }
    let mut levels: Vec<Box<Estimator<{ nemm_core::DEFAULT_PARAM_CAPACITY }, T>>> = Vec::new();
    for &alpha in &tables.tables_alpha {
        let cfg = EstimatorConfig {
            mode: EvalMode::Table(TableConfig::new(tables.tables_bound)),
            ..EstimatorConfig::new(alpha)
        };
        let mut est = Box::new(Estimator::empty());
        est.load(model, cfg)
            .map_err(|e| anyhow::anyhow!("tables at alpha {alpha} ({T} segments): {e}"))?;
        levels.push(est);
    }
    let refs: Vec<&Estimator<{ nemm_core::DEFAULT_PARAM_CAPACITY }, T>> =
        levels.iter().map(|e| &**e).collect();
    nemm_core::encode_to_vec_with_tables(model, &refs).map_err(|e| anyhow::anyhow!("{e}"))
}

/// Encodes and writes a model blob atomically, with its provenance (this command line, the
/// commit the trainer was built from, and `dataset`) and the fast-path tables of `tables` in
/// the blob; returns its size and the model as written (as decoded from the blob).
pub fn export_model(
    model: &nemm_core::Model,
    out: &Path,
    dataset: &str,
    tables: &TablesArgs,
) -> Result<(usize, nemm_core::Model)> {
    let mut model = model.clone();
    model.ext.provenance = provenance(dataset);
    let blob = encode_with_tables(&model, tables)?;
    write_atomic_bytes(out, &blob).with_context(|| format!("cannot write {}", out.display()))?;
    let written = nemm_core::decode(&blob).map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok((blob.len(), written))
}

/// Writes `report.json` and `table4.md` (Table 4, then the test error per held-out run, the
/// learned against the virtual bench's reference coefficients when the data are the bench's,
/// then the whole-run error per level and run) into `dir`; with the report's identification,
/// also `identify.md`, which `table4.md` links to.
pub fn write_report(dir: &Path, report: &Report, table_name: &str) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    write_atomic_bytes(
        &dir.join("report.json"),
        serde_json::to_string_pretty(report)?.as_bytes(),
    )?;
    let mut table = table4_markdown(report);
    let runs = test_runs_markdown(report);
    if !runs.is_empty() {
        table = format!("{table}\n{runs}");
    }
    if let Some(c) = &report.bench_reference {
        table = format!("{table}\n{}\n", c.markdown().trim_end());
    }
    if let Some(id) = &report.identify {
        table = format!(
            "{table}\n{}\nThe best-fit {} of every run per model (can the model read the level \
             back?): [{IDENTIFY_MD}]({IDENTIFY_MD}).\n",
            whole_run_markdown(id),
            id.condition.column()
        );
        write_atomic_bytes(&dir.join(IDENTIFY_MD), identify_markdown(id).as_bytes())?;
    }
    write_atomic_bytes(&dir.join(table_name), table.as_bytes())?;
    Ok(())
}

/// The identifiability tables' file in a report folder.
pub const IDENTIFY_MD: &str = "identify.md";

fn print_audit(t: &TrainedVariant, r: &Report) {
    if let Some(v) = r.variants.get(t.variant.key()) {
        if let Some(a) = &v.audit {
            let mut parts = Vec::new();
            for (name, s) in [("b_fl", a.b_fl), ("b_pr", a.b_pr), ("k_pr", a.k_pr)] {
                if let Some(s) = s {
                    let st = s.state.map_or(String::new(), |c| {
                        format!(
                            "state {}/{} (worst {:.2e}), ",
                            c.violations, c.checked, c.worst
                        )
                    });
                    parts.push(format!(
                        "{name}: {st}alpha {}/{} (worst {:.2e})",
                        s.alpha.violations, s.alpha.checked, s.alpha.worst
                    ));
                }
            }
            println!(
                "monotonicity audit ({}): {}",
                t.variant.name(),
                parts.join("; ")
            );
        }
    }
}

/// `nemm train`: trains `cfg.model.variant` on `cfg.data` and writes the blob `out`; with
/// `report_dir`, also `report.json`, `table.md` and the effective `config.toml` there.
pub fn train(
    cfg: &Config,
    out: &Path,
    checkpoint: Option<&Path>,
    resume: bool,
    report_dir: Option<&Path>,
    tables: &TablesArgs,
) -> Result<()> {
    let cfg = &with_resolved_data(cfg)?;
    let variant = cfg.model.variant;
    let (ds, prepared) =
        load_dataset_prepared(cfg.data.require_dir()?, &cfg.data.prepare_config())?;
    let pipeline = cfg.pipeline_config();
    let t = Instant::now();
    let trained = train_variants(&prepared, &[variant], &pipeline, checkpoint, resume)?;
    let tv = trained
        .iter()
        .find(|t| t.variant == variant)
        .context("training produced no model")?;
    let (n, written) = export_model(
        &tv.model,
        out,
        &dataset_provenance(&ds, &cfg.data.dir),
        tables,
    )?;
    let report = evaluate(std::slice::from_ref(tv), &prepared)?;
    let vr = report.variants.get(variant.key()).context("report")?;
    println!(
        "wrote {} ({n} bytes) in {:.0} s",
        out.display(),
        t.elapsed().as_secs_f64()
    );
    print!("{}", describe(&written, n));
    println!(
        "test RMSE ({}): {:.4} of the force scale ({:.1} N); validation {:.4}",
        prepared.config.split.describe(),
        vr.rmse,
        vr.rmse_n,
        vr.val_rmse
    );
    print_audit(tv, &report);
    // The fast path's verdict at export time, as `nemm export` prints it.
    print!(
        "{}",
        crate::train::table_check::report(
            &tv.model,
            crate::train::table_check::DEFAULT_TABLE_BOUND
        )
    );
    if let Some(dir) = report_dir {
        let mut report = report;
        record_provenance(&mut report);
        write_report(dir, &report, "table.md")?;
        cfg.save(&dir.join(CONFIG_FILE))?;
    }
    Ok(())
}

/// The input of an estimator for run `idx`: the preprocessing's velocity (the trainer's
/// input) in f32, and the run's oil-loss level.
fn estimator_input(
    ds: &dataset::Dataset,
    prepared: &preprocess::Prepared,
    idx: usize,
) -> Result<(Vec<f32>, Vec<f32>, f32)> {
    let signals = preprocess::process_run(
        &ds.runs[idx],
        idx,
        ds.sample_rate_hz,
        &prepared.config.signal,
    )?;
    let u = signals.velocity_m_s.iter().map(|&v| v as f32).collect();
    // The position as the sensor measures it (unfiltered), as the firmware gets it.
    let x = ds.runs[idx]
        .displacement_m
        .iter()
        .map(|&v| v as f32)
        .collect();
    Ok((u, x, ds.runs[idx].entry.oil_loss as f32))
}

/// The tabulated fast path against the exact estimator over every run with test data (a test
/// run or a run with a test tail), whole and from rest: the largest force difference in units of the force scale,
/// and the samples outside the table domain.
fn table_vs_exact(
    model: &nemm_core::Model,
    ds: &dataset::Dataset,
    prepared: &preprocess::Prepared,
) -> Result<()> {
    use nemm_core::{EstimatorConfig, EvalMode, Flags, TableConfig};
    let t = Instant::now();
    let bound = crate::train::table_check::DEFAULT_TABLE_BOUND;
    let (mut worst, mut samples, mut outside, mut runs) = (0.0f64, 0usize, 0usize, 0usize);
    for run in prepared.runs.iter().filter(|r| r.test_sequences > 0) {
        let (u, x, alpha) = estimator_input(ds, prepared, run.summary.index)?;
        let exact_cfg = EstimatorConfig::new(alpha);
        let table_cfg = EstimatorConfig {
            mode: EvalMode::Table(TableConfig::new(bound)),
            ..exact_cfg
        };
        let mut exact = nemm_core::Estimator::new(model, exact_cfg)
            .map_err(|e| anyhow::anyhow!("exact estimator: {e}"))?;
        let mut table = match nemm_core::Estimator::new(model, table_cfg) {
            Ok(e) => e,
            Err(e) => {
                println!("fast path at oil loss {alpha}: refused ({e}); use the exact mode");
                return Ok(());
            }
        };
        for (&v, &x) in u.iter().zip(&x) {
            let (a, b) = (
                exact.step_with_position(v, x),
                table.step_with_position(v, x),
            );
            worst = worst.max(f64::from((a.force_n - b.force_n).abs()));
            outside += usize::from(b.flags.contains(Flags::OUT_OF_TABLE_DOMAIN));
        }
        samples += u.len();
        runs += 1;
    }
    println!(
        "fast path (tables, bound {bound:.0e}) vs exact over {runs} runs with test data ({samples} samples, whole runs from rest): \
         max |table - exact| = {:.2e} of the force scale, {outside} samples outside the table domain ({:.1} s)",
        worst / prepared.scales.force_n,
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

/// `nemm export`: the best model of a checkpoint folder written by `nemm train --checkpoint`.
/// Also reports whether the tabulated fast path meets `table_bound`
/// ([`crate::train::table_check`]).
pub fn export(checkpoint: &Path, out: &Path, table_bound: f32, tables: &TablesArgs) -> Result<()> {
    let frame_path = checkpoint.join("frame.json");
    let text = std::fs::read_to_string(&frame_path).with_context(|| {
        format!(
            "cannot read {} (is {} a variant folder written by `nemm train --checkpoint`? \
             The SEM has no epochs and no checkpoint: `nemm train --variant sem --out FILE` \
             fits and writes it directly)",
            frame_path.display(),
            checkpoint.display()
        )
    })?;
    let saved: crate::train::pipeline::SavedFrame =
        serde_json::from_str(&text).with_context(|| format!("corrupt {}", frame_path.display()))?;
    let latest = std::fs::read_to_string(checkpoint.join("latest"))
        .with_context(|| format!("no finished epoch in {}", checkpoint.display()))?;
    let device = burn::tensor::Device::flex();
    let (net, frame): (EmmNet, NetFrame) =
        EmmNet::from_rollout(&saved.initial, saved.static_units, &device);
    let net = net
        .try_load_file(checkpoint.join(latest.trim()).join("best"))
        .map_err(|e| anyhow::anyhow!("cannot load the best module: {e:?}"))?;
    let model = to_core(&net.to_rollout(&frame), saved.meta)?;
    let (n, model) = export_model(
        &model,
        out,
        &format!("checkpoint {}", checkpoint.display()),
        tables,
    )?;
    println!(
        "wrote {} ({n} bytes) from {}",
        out.display(),
        checkpoint.join(latest.trim()).display()
    );
    print!("{}", describe(&model, n));
    print!("{}", crate::train::table_check::report(&model, table_bound));
    Ok(())
}

/// `nemm compare` from the command line: loads and prepares `cfg.data`, then [`compare`].
pub fn compare_command(
    cfg: &Config,
    report_dir: &Path,
    checkpoint: Option<&Path>,
    resume: bool,
) -> Result<Report> {
    let cfg = &with_resolved_data(cfg)?;
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
        trained.iter().map(|tv| (tv.variant, &tv.model)).collect();
    match identify_report(
        &models,
        ds,
        prepared,
        &used_runs(prepared),
        crate::train::identify::DEFAULT_STEP,
        prepared.scales.force_n,
    ) {
        Ok(id) => report.identify = Some(id),
        Err(e) => eprintln!("warning: no identifiability tables: {e:#}"),
    }
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

/// A sweep grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SweepGrid {
    /// Only the `--lambda-ph` list, other hyperparameters as given (Table 5).
    Lambda,
    /// The Table 3 search space (batch {4, 8, 16} x hidden {8, 16, 32} x layers {3, 5, 7, 9}
    /// x lr {5e-3, 1e-2, 1e-3}: 108 jobs) times the `--lambda-ph` list.
    Table3,
    /// The `--lambda-ph` list twice: with the priors in alpha held by construction (the alpha
    /// branches) and imposed by the physics penalty alone (the paper's way), other
    /// hyperparameters as given (Table 5 with the construction-against-penalty ablation).
    Priors,
}

/// One sweep job: its id and its whole configuration (the base with the job's overrides).
#[derive(Debug, Clone, PartialEq)]
pub struct SweepJob {
    /// Folder name under `<report>/jobs/`.
    pub id: String,
    /// The overridden settings (`lambda_ph`; for the Table 3 grid `batch`, `hidden`,
    /// `layers`, `lr`; for the priors grid `alpha_priors`) with their values, for
    /// `sweep.json`.
    pub overrides: Vec<(String, String)>,
    /// The job's configuration.
    pub config: Config,
}

/// The jobs of a sweep: one per grid point and `lambdas` value, each a copy of `base` with
/// the `nemm` variant and the point's settings.
pub fn sweep_jobs(base: &Config, grid: SweepGrid, lambdas: &[f64]) -> Vec<SweepJob> {
    /// Batch, hidden width, layers, learning rate (`None`: the base configuration's).
    type Combo = Option<(usize, usize, usize, f64)>;
    let combos: Vec<Combo> = match grid {
        SweepGrid::Lambda | SweepGrid::Priors => vec![None],
        SweepGrid::Table3 => {
            let mut v = Vec::new();
            for b in [4, 8, 16] {
                for h in [8, 16, 32] {
                    for l in [3, 5, 7, 9] {
                        for lr in [5e-3, 1e-2, 1e-3] {
                            v.push(Some((b, h, l, lr)));
                        }
                    }
                }
            }
            v
        }
    };
    let priors: Vec<Option<AlphaPriors>> = match grid {
        SweepGrid::Priors => vec![Some(AlphaPriors::Construction), Some(AlphaPriors::Penalty)],
        SweepGrid::Lambda | SweepGrid::Table3 => vec![None],
    };
    let mut jobs = Vec::new();
    for combo in combos {
        for (&prior, &lam) in priors
            .iter()
            .flat_map(|p| lambdas.iter().map(move |l| (p, l)))
        {
            let mut config = base.clone();
            config.model.variant = nemm_core::ModelKind::Nemm;
            let mut id = String::new();
            let mut o: Vec<(String, String)> = Vec::new();
            if let Some(p) = prior {
                id.push_str(&format!("{}_", p.name()));
                config.model.alpha_priors = p;
                o.push(("alpha_priors".into(), p.name().into()));
            }
            if let Some((b, h, l, lr)) = combo {
                id.push_str(&format!("b{b}_h{h}_l{l}_lr{lr}_"));
                (config.train.batch, config.model.hidden) = (b, h);
                (config.model.layers, config.train.lr) = (l, lr);
                o.push(("batch".into(), b.to_string()));
                o.push(("hidden".into(), h.to_string()));
                o.push(("layers".into(), l.to_string()));
                o.push(("lr".into(), lr.to_string()));
            }
            id.push_str(&format!("lph{lam}"));
            config.train.lambda_ph = lam;
            o.push(("lambda_ph".into(), lam.to_string()));
            jobs.push(SweepJob {
                id,
                overrides: o,
                config,
            });
        }
    }
    jobs
}

/// A job's folder under `report`.
fn job_dir(report: &Path, job: &SweepJob) -> PathBuf {
    report.join("jobs").join(&job.id)
}

/// Writes the job's configuration to `<report>/jobs/<id>/config.toml` and returns its
/// `nemm train` command line (without the program name).
pub fn job_args(job: &SweepJob, report: &Path) -> Result<Vec<String>> {
    let dir = job_dir(report, job);
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let config = dir.join(CONFIG_FILE);
    job.config.save(&config)?;
    Ok(vec![
        "train".into(),
        "--config".into(),
        config.display().to_string(),
        "--out".into(),
        dir.join("model.nemm").display().to_string(),
        "--report".into(),
        dir.display().to_string(),
    ])
}

/// Reads every job's `report.json` under `<report>/jobs/` and writes `sweep.json` and
/// `table5.md` (one row per job: hyperparameters, validation and test RMSE, violations).
pub fn collect_sweep(jobs: &[SweepJob], report: &Path) -> Result<String> {
    use std::fmt::Write as _;
    struct Row {
        job: SweepJob,
        val: f64,
        test: f64,
        test_n: f64,
        violations: usize,
        seconds: f64,
        info: std::collections::BTreeMap<String, String>,
    }
    let mut rows: Vec<Row> = Vec::new();
    for j in jobs {
        let p = report.join("jobs").join(&j.id).join("report.json");
        match std::fs::read_to_string(&p) {
            Ok(t) => {
                let r: Report =
                    serde_json::from_str(&t).with_context(|| format!("corrupt {}", p.display()))?;
                if let Some(v) = r.variants.get("nemm") {
                    rows.push(Row {
                        job: j.clone(),
                        val: v.val_rmse,
                        test: v.rmse,
                        test_n: v.rmse_n,
                        violations: v.violations,
                        seconds: v.train_seconds,
                        info: r.info.clone(),
                    });
                }
            }
            Err(_) => eprintln!(
                "warning: job {} has no report ({}): not finished or failed",
                j.id,
                p.display()
            ),
        }
    }
    let base = rows
        .iter()
        .find(|r| r.job.config.train.lambda_ph == 0.0)
        .or(rows.first());
    let mut md = String::new();
    if let Some(r) = rows.first() {
        md += &sweep_provenance(&r.job.config, &r.info);
    }
    if let Some(b) = base {
        let _ = writeln!(
            md,
            "Rel. test error: the job's test RMSE against `{}`'s.\n",
            b.job.id
        );
    }
    let _ = writeln!(md, "| Job | Alpha priors | lambda_ph | Validation RMSE | Test RMSE | Test RMSE [N] | Rel. test error (%) | Violations | Time |");
    let _ = writeln!(md, "|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in &rows {
        let (j, val, test, test_n, viol, secs) =
            (&r.job, r.val, r.test, r.test_n, r.violations, r.seconds);
        let lam = j.config.train.lambda_ph;
        let priors = j.config.model.alpha_priors.name();
        let rel = base.map_or("-".into(), |b| format!("{:.1}", 100.0 * test / b.test));
        let _ = writeln!(
            md,
            "| {} | {priors} | {lam} | {val:.4} | {test:.4} | {test_n:.1} | {rel} | {viol} | {secs:.0} s |",
            j.id
        );
    }
    if let Some(best) = rows.iter().min_by(|a, b| a.val.total_cmp(&b.val)) {
        let _ = writeln!(
            md,
            "\nBest by validation RMSE: `{}` (test RMSE {:.4}).",
            best.job.id, best.test
        );
    }
    let json: Vec<serde_json::Value> = rows
        .iter()
        .map(|r| {
            serde_json::json!({
                "id": r.job.id,
                "overrides": r.job.overrides.iter().cloned().collect::<std::collections::BTreeMap<_, _>>(),
                "val_rmse": r.val, "rmse": r.test, "rmse_n": r.test_n, "violations": r.violations, "train_seconds": r.seconds,
            })
        })
        .collect();
    write_atomic_bytes(
        &report.join("sweep.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    write_atomic_bytes(&report.join("table5.md"), md.as_bytes())?;
    Ok(md)
}

/// The sweep table's first lines: the commit the jobs were trained at (from the first job's
/// report) and the budget they share.
fn sweep_provenance(config: &Config, info: &std::collections::BTreeMap<String, String>) -> String {
    let t = &config.train;
    let batches = t.max_batches.map_or("all batches".to_string(), |b| {
        format!("at most {b} batches")
    });
    format!(
        "Sweep of the NEMM trained at commit `{}` on `{}`: at most {} epochs of {batches} \
         (patience {}), {} Linear EMM epochs, seed {}, batch {}, lr {}.\n\n",
        info.get("commit").map_or("unrecorded", String::as_str),
        config.data.dir.display(),
        t.epochs,
        t.patience,
        t.linear_epochs,
        t.seed,
        t.batch,
        t.lr,
    )
}

/// `nemm sweep`: every configuration is an independent `nemm train --config
/// <report>/jobs/<id>/config.toml` process (a cluster scheduler can run the lines of `--list`
/// instead); results are collected into one table.
pub fn sweep(
    base: &Config,
    grid: SweepGrid,
    lambdas: &[f64],
    report: &Path,
    jobs_parallel: usize,
    list_only: bool,
    collect_only: bool,
) -> Result<()> {
    base.data.require_dir()?;
    // Every job runs with the data options resolved once, as this run prints them.
    let resolved;
    let base = if collect_only {
        base
    } else {
        resolved = with_resolved_data(base)?;
        &resolved
    };
    let jobs = sweep_jobs(base, grid, lambdas);
    for j in &jobs {
        j.config.validate()?;
    }
    if let Some(note) = lambda_ph_scale_note(lambdas) {
        eprintln!("{note}");
    }
    let exe = std::env::current_exe().context("cannot find the nemm executable")?;
    if list_only {
        for j in &jobs {
            let args = job_args(j, report)?;
            println!("{} {}", exe.display(), args.join(" "));
        }
        return Ok(());
    }
    if !collect_only {
        std::fs::create_dir_all(report.join("jobs"))?;
        let t = Instant::now();
        let mut pending: std::collections::VecDeque<&SweepJob> = jobs.iter().collect();
        let mut running: Vec<(String, std::process::Child)> = Vec::new();
        let mut failed = Vec::new();
        let total = jobs.len();
        let mut done = 0;
        while !pending.is_empty() || !running.is_empty() {
            while running.len() < jobs_parallel.max(1) {
                let Some(j) = pending.pop_front() else { break };
                let dir = job_dir(report, j);
                std::fs::create_dir_all(&dir)?;
                if dir.join("report.json").exists() {
                    eprintln!("[sweep] {} already done, skipped", j.id);
                    done += 1;
                    continue;
                }
                let log = std::fs::File::create(dir.join("train.log"))?;
                let child = std::process::Command::new(&exe)
                    .args(job_args(j, report)?)
                    .stdout(log.try_clone()?)
                    .stderr(log)
                    .spawn()
                    .with_context(|| format!("cannot start job {}", j.id))?;
                eprintln!(
                    "[sweep] started {} ({} running, {} waiting)",
                    j.id,
                    running.len() + 1,
                    pending.len()
                );
                running.push((j.id.clone(), child));
            }
            std::thread::sleep(std::time::Duration::from_millis(200));
            let mut i = 0;
            while i < running.len() {
                if let Some(status) = running[i].1.try_wait()? {
                    let (id, _) = running.remove(i);
                    done += 1;
                    let el = t.elapsed().as_secs_f64();
                    if status.success() {
                        eprintln!(
                            "[sweep] {id} done ({done}/{total}, {:.0} s, ETA {:.0} s)",
                            el,
                            el / done as f64 * (total - done) as f64
                        );
                    } else {
                        eprintln!(
                            "[sweep] {id} FAILED ({status}); see {}",
                            report.join("jobs").join(&id).join("train.log").display()
                        );
                        failed.push(id);
                    }
                } else {
                    i += 1;
                }
            }
        }
        if !failed.is_empty() {
            eprintln!(
                "[sweep] {} job(s) failed: {}",
                failed.len(),
                failed.join(", ")
            );
        }
    }
    let md = collect_sweep(&jobs, report)?;
    println!("{md}");
    println!(
        "sweep table in {} and {}",
        report.join("table5.md").display(),
        report.join("sweep.json").display()
    );
    Ok(())
}

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
    if !paths.data.join(dataset::MANIFEST_FILE).exists() {
        eprintln!(
            "no dataset in {}: generating the default virtual bench",
            paths.data.display()
        );
        crate::cli::bench::generate(
            &crate::bench::config::BenchConfig::default(),
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
    let idx = run.summary.index;
    let what = if run.role == preprocess::RunRole::Test {
        "held-out run"
    } else {
        "run with a test tail (its training part included)"
    };
    let (u, x, alpha) = estimator_input(&ds, &prepared, idx)?;
    let mut est = nemm_core::Estimator::new(&model, nemm_core::EstimatorConfig::new(alpha))
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
    let trainer = crate::train::eval::predict(&model, &[input], prepared.dt_s)?;
    let parity = forces
        .iter()
        .zip(&trainer[0])
        .fold(0.0f64, |m, (&a, &b)| m.max((a - b).abs()))
        / fs;
    println!(
        "most dynamic {what} {} (oil loss {alpha}, {:.0} mm, {:.1} Hz), whole run from rest: nemm-core estimator RMSE {:.4} ({:.1} N) over {} samples, {:.0} ns/step on this host; \
         max |nemm-core - trainer| = {:.2e} of the force scale",
        ds.runs[idx].entry.file.display(),
        run.summary.excitation.amplitude_m * 1e3,
        run.summary.excitation.frequency_hz.unwrap_or(f64::NAN),
        rmse,
        rmse * fs,
        forces.len(),
        ns_per_step,
        parity
    );
    table_vs_exact(&model, &ds, &prepared)?;
    let nemm = report
        .variants
        .get("nemm")
        .map(|v| v.rmse)
        .unwrap_or(f64::NAN);
    let sem = report
        .variants
        .get("sem")
        .map(|v| v.rmse)
        .unwrap_or(f64::NAN);
    println!(
        "demo done in {:.1} min: NEMM test RMSE {:.4} = {:.0} % of the SEM's; weights in {}",
        t0.elapsed().as_secs_f64() / 60.0,
        nemm,
        100.0 * nemm / sem,
        model_path.display()
    );
    Ok(())
}

/// Records in `report.info` the command line that made it and the commit the trainer was
/// built from (`+dirty`: with uncommitted changes).
fn record_provenance(report: &mut Report) {
    report.info.insert("command".into(), command_line());
    report
        .info
        .insert("commit".into(), env!("NEMM_GIT_COMMIT").to_string());
}

/// This process's command line, the program by its file name (`nemm train ...`).
fn command_line() -> String {
    let mut args = std::env::args();
    let program = args
        .next()
        .map(|p| {
            Path::new(&p)
                .file_name()
                .map_or(p.clone(), |f| f.to_string_lossy().into_owned())
        })
        .unwrap_or_default();
    std::iter::once(program)
        .chain(args)
        .collect::<Vec<_>>()
        .join(" ")
}

/// The provenance a blob exported by this process records: the command line, `dataset` and
/// the commit the trainer was built from (each cut to its field's capacity).
pub fn provenance(dataset: &str) -> nemm_core::Provenance {
    nemm_core::Provenance::new(&command_line(), dataset, env!("NEMM_GIT_COMMIT"))
}

/// How a blob names its training data: the dataset's name and folder.
pub fn dataset_provenance(ds: &dataset::Dataset, dir: &Path) -> String {
    format!("{} ({})", ds.name, dir.display())
}
