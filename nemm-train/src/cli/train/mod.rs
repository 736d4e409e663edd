//! `nemm train`, `nemm export`, `nemm compare`, `nemm sweep`: training, export and the
//! Table 4 / Table 5 reports from the command line.

use crate::config::{
    lambda_ph_scale_note, resolve_data, AlphaPriors, Config, StatePriors, CONFIG_FILE,
};
use crate::data::load_dataset_prepared;
use crate::data::preprocess::{self, Prepared};
use crate::output_guard::{self, Inputs, Output};
use crate::report::identify::{identify_markdown, whole_run_markdown};
use crate::report::inspect::describe;
use crate::report::signature::signature_markdown;
use crate::report::tables::{evaluate, table4_markdown, test_runs_markdown, Report};
use crate::train::net::{EmmNet, NetFrame};
use crate::train::params::to_core;
use crate::train::pipeline::{
    train_each, train_variants, PipelineConfig, Trained, TrainedVariant, VariantInfo,
};
use anyhow::{bail, Context, Result};
use burn::module::Module;
use nemm_core::{ModelKind, Sample};
use nemm_dataset as dataset;
use nemm_dataset::atomic_file::write_atomic_bytes;
use std::path::Path;
use std::time::Instant;

mod compare;
mod demo;
mod identity;
mod sweep;

pub use compare::{compare, compare_command};
pub use demo::{demo, DemoPaths};
pub(crate) use identity::open_checkpoint;
pub use sweep::{collect, resume, sweep, Engine, SlurmArgs, SweepGrid, SweepOptions, Table3Args};

/// `cfg` with its data options resolved for its dataset ([`resolve_data`], which prints
/// them): what a job runs with and saves as `config.toml`.
pub(crate) fn with_resolved_data(cfg: &Config) -> Result<Config> {
    let mut cfg = cfg.clone();
    cfg.data = resolve_data(&cfg.data)?.config;
    Ok(cfg)
}

/// Precomputed fast-path tables to store in an exported blob (the format's tables section,
/// `nemm_core::StoredTables`): a firmware in table mode at one of these oil-loss levels, with
/// the same segment count and bound, boots without building its tables.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct TablesArgs {
    /// Oil-loss levels alpha (comma-separated, each in [0, 1]; at most 16) whose fast-path
    /// tables the blob stores. A firmware in table mode at one of them reads its tables from
    /// the blob instead of building them at boot. None by default.
    #[arg(long, value_delimiter = ',')]
    pub(crate) tables_alpha: Vec<f32>,
    /// Also store this many levels evenly over the model's trained range of alpha (2 to
    /// 16, together with --tables-alpha at most 16): the level tables of
    /// `nemm_core::LevelTables`, with which a firmware runs a level per sample
    /// (`Estimator::attach_levels`) and the alpha observer (`AlphaObserver::load_on_levels`)
    /// at table cost. 7 levels take about 43 KB of the blob at 128 segments (docs/core.md,
    /// "Every level at table cost").
    #[arg(long)]
    pub(crate) tables_levels: Option<usize>,
    /// Segments per stored table: the `T` of the firmware's estimator (128, nemm-firmware's
    /// TABLE_SEGMENTS, or 256, nemm-core's default).
    #[arg(long, default_value_t = DEFAULT_STORED_TABLE_SEGMENTS)]
    pub(crate) tables_segments: usize,
    /// Relative error bound the stored tables are built and checked with (the firmware's
    /// TABLE_MAX_REL_ERROR; it must be the same bit for bit for the firmware to use them).
    #[arg(long, default_value_t = crate::train::table_check::DEFAULT_TABLE_BOUND)]
    pub(crate) tables_bound: f32,
}

/// Segments of stored tables unless told otherwise: the example firmware's (128).
pub(crate) const DEFAULT_STORED_TABLE_SEGMENTS: usize = 128;

impl TablesArgs {
    /// Checks the options before anything is trained: each level in [0, 1], at most
    /// [`nemm_core::MAX_TABLE_LEVELS`] of them, 128 or 256 segments, a finite
    /// positive bound.
    pub fn validate(&self) -> Result<()> {
        for &a in &self.tables_alpha {
            if !(0.0..=1.0).contains(&a) {
                bail!("--tables-alpha {a} is out of range: each level must be in [0, 1]");
            }
        }
        let max = nemm_core::MAX_TABLE_LEVELS;
        if self.tables_alpha.len() > max {
            bail!(
                "--tables-alpha lists {} levels: a blob stores at most {max}",
                self.tables_alpha.len()
            );
        }
        if let Some(n) = self.tables_levels {
            if !(2..=max).contains(&n) {
                bail!("--tables-levels {n}: between 2 and {max} levels");
            }
        }
        if !matches!(self.tables_segments, 128 | 256) {
            bail!(
                "--tables-segments {}: stored tables have 128 or 256 segments",
                self.tables_segments
            );
        }
        if !(self.tables_bound.is_finite() && self.tables_bound > 0.0) {
            bail!(
                "--tables-bound {} is out of range: it must be a finite number > 0",
                self.tables_bound
            );
        }
        Ok(())
    }

    /// Refuses a --tables-alpha level outside the trained range of `meta` (a model's, or
    /// [`crate::train::pipeline::meta_of`] the prepared data before training): its tables
    /// would hold an extrapolated model.
    pub(crate) fn check_range(&self, meta: &nemm_core::Meta) -> Result<()> {
        let (min, max) = (meta.alpha_min, meta.alpha_max);
        if let Some(a) = self
            .tables_alpha
            .iter()
            .find(|&&a| a < min - 1e-6 || a > max + 1e-6)
        {
            bail!(
                "--tables-alpha {a} is outside the model's trained range of alpha ({min} to \
                 {max}): its tables would hold an extrapolated model; give levels in that range"
            );
        }
        Ok(())
    }

    /// The levels to store for `model` (each of --tables-alpha in the model's trained range,
    /// else an error): those of --tables-alpha and the --tables-levels
    /// levels evenly over the trained range (computed in f64, each rounded once to f32, so
    /// that a level such as 0.15 is the f32 of 0.15), ascending, without repeats.
    pub fn levels(&self, model: &nemm_core::Model) -> Result<Vec<f32>> {
        self.check_range(&model.meta)?;
        let mut levels = self.tables_alpha.clone();
        if let Some(n) = self.tables_levels {
            let (lo, hi) = (
                f64::from(model.meta.alpha_min),
                f64::from(model.meta.alpha_max),
            );
            if hi <= lo {
                bail!(
                    "--tables-levels: the model was trained at one level ({lo}); list levels with --tables-alpha"
                );
            }
            // Rounded to 6 decimals first, so that 0.3 * 3 / 6 is stored as 0.15.
            let at = |k: usize| (lo + (hi - lo) * k as f64 / (n - 1) as f64) * 1e6;
            levels.extend((0..n).map(|k| (at(k).round() / 1e6) as f32));
        }
        levels.sort_by(f32::total_cmp);
        levels.dedup_by(|a, b| a.to_bits() == b.to_bits());
        let max = nemm_core::MAX_TABLE_LEVELS;
        if levels.len() > max {
            bail!(
                "--tables-alpha and --tables-levels give {} levels: a blob stores at most {max}",
                levels.len()
            );
        }
        Ok(levels)
    }
}

impl Default for TablesArgs {
    fn default() -> Self {
        Self {
            tables_alpha: Vec::new(),
            tables_levels: None,
            tables_segments: DEFAULT_STORED_TABLE_SEGMENTS,
            tables_bound: crate::train::table_check::DEFAULT_TABLE_BOUND,
        }
    }
}

/// The blob of `model` with the tables of `tables` (none if it lists no levels).
fn encode_with_tables(model: &nemm_core::Model, tables: &TablesArgs) -> Result<Vec<u8>> {
    match tables.tables_segments {
        _ if tables.tables_alpha.is_empty() && tables.tables_levels.is_none() => {
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
    for alpha in tables.levels(model)? {
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
pub(crate) fn export_model(
    model: &nemm_core::Model,
    out: &Path,
    dataset: &str,
    tables: &TablesArgs,
) -> Result<Written> {
    let mut model = model.clone();
    model.provenance = provenance(dataset);
    let blob = encode_with_tables(&model, tables)?;
    write_atomic_bytes(out, &blob).with_context(|| format!("cannot write {}", out.display()))?;
    let (model, stored) =
        nemm_core::decode_with_tables(&blob).map_err(|e| anyhow::anyhow!("{e}"))?;
    let levels = match tables.tables_segments {
        128 => levels_check::<128>(&model, &stored, &blob)?,
        _ => levels_check::<256>(&model, &stored, &blob)?,
    };
    Ok(Written {
        len: blob.len(),
        model,
        tables: stored,
        levels,
    })
}

/// `nemm tables MODEL --out OUT`: re-encodes the model of `model` (bit for bit, provenance
/// included) with the tables of `tables`, writes it atomically and describes it.
///
/// `out` may be `model` (rewritten in place); it may not be another input's path. Rewriting
/// in place drops the stored tables of levels `tables` does not list only with `drop_tables`;
/// `replace` lets `out` replace an existing file that is not a weights blob.
pub fn store_tables(
    model: &Path,
    out: &Path,
    tables: &TablesArgs,
    replace: bool,
    drop_tables: bool,
) -> Result<()> {
    tables.validate()?;
    let in_place = output_guard::resolve(model)? == output_guard::resolve(out)?;
    let inputs = if in_place {
        Inputs::new()
    } else {
        Inputs::new().path("the model", model)
    };
    output_guard::check(&[Output::blob("--out", out)], &inputs, replace, "--replace")?;
    let blob = std::fs::read(model).with_context(|| format!("cannot read {}", model.display()))?;
    let (m, old): (nemm_core::Model, _) =
        nemm_core::decode_with_tables(&blob).with_context(|| format!("{}", model.display()))?;
    let kept = if tables.tables_alpha.is_empty() && tables.tables_levels.is_none() {
        Vec::new()
    } else {
        tables.levels(&m)?
    };
    let dropped: Vec<&nemm_core::StoredLevel> = old
        .levels
        .iter()
        .filter(|l| {
            l.segments as usize != tables.tables_segments
                || !kept.iter().any(|a| a.to_bits() == l.alpha.to_bits())
        })
        .collect();
    if in_place && !dropped.is_empty() && !drop_tables {
        let count: usize = dropped
            .iter()
            .map(|l| usize::from(l.b_fl.is_some()) + usize::from(l.k_pr.is_some()))
            .sum();
        let levels: Vec<String> = dropped
            .iter()
            .map(|l| format!("{} ({} segments)", l.alpha, l.segments))
            .collect();
        bail!(
            "--out {}: rewriting the model in place would drop {count} stored table(s) of {} \
             of its {} level(s): alpha {}; list them with --tables-alpha (and --tables-segments), \
             or give --drop-tables to drop them",
            out.display(),
            dropped.len(),
            old.levels.len(),
            levels.join(", ")
        );
    }
    let new = encode_with_tables(&m, tables)?;
    write_atomic_bytes(out, &new).with_context(|| format!("cannot write {}", out.display()))?;
    let (decoded, stored) =
        nemm_core::decode_with_tables(&new).map_err(|e| anyhow::anyhow!("{e}"))?;
    if decoded != m {
        bail!(
            "{}: the re-encoded model differs from the input",
            out.display()
        );
    }
    let levels = match tables.tables_segments {
        128 => levels_check::<128>(&decoded, &stored, &new)?,
        _ => levels_check::<256>(&decoded, &stored, &new)?,
    };
    println!("wrote {} ({} bytes)", out.display(), new.len());
    print!("{}", describe(&decoded, &stored, new.len()));
    print!("{}", levels.as_deref().unwrap_or(""));
    Ok(())
}

/// With two or more stored levels of `T` segments: the line that says what the level
/// tables take and how far their blend between levels lies from the exact model
/// (`nemm_core::LevelTables::check`, 3 levels inside each interval, 4 states per segment).
fn levels_check<const T: usize>(
    model: &nemm_core::Model,
    stored: &nemm_core::StoredTables,
    blob: &[u8],
) -> Result<Option<String>> {
    use nemm_core::{AlignedBlob, Estimator, EstimatorConfig, LevelTables, LevelsError};
    const MAX: usize = nemm_core::MAX_TABLE_LEVELS;
    // Held 4-byte aligned, as a flash slot holds it: the level tables read it in place.
    let blob = AlignedBlob::new(blob);
    let mut levels: Box<LevelTables<'_, T, MAX>> = Box::new(LevelTables::empty());
    match levels.load(model, stored, &blob) {
        Ok(()) => {}
        Err(LevelsError::TooFewLevels { .. } | LevelsError::NoNeuralCoefficient) => {
            return Ok(None)
        }
        Err(e) => bail!("level tables: {e}"),
    }
    let mut exact: Box<Estimator<{ nemm_core::DEFAULT_PARAM_CAPACITY }, 3>> =
        Box::new(Estimator::empty());
    exact
        .load(model, EstimatorConfig::new(model.meta.alpha_min))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let c = levels
        .check(&mut exact, 3, 4)
        .map_err(|e| anyhow::anyhow!("level tables: {e}"))?;
    let [b_fl, b_pr, k_pr] = c.max_rel_error;
    Ok(Some(format!(
        "level tables:    {} levels of {T} segments, {} B in the blob, read in place; blend between levels within \
         {b_fl:.1e} (b_fl), {b_pr:.1e} (b_pr), {k_pr:.1e} (k_pr) relative of the exact model \
         (worst at alpha {:.3}); neighbouring levels out of the declared order in {} of {} \
         checks (b_fl and k_pr at {} states between each pair of levels; exact model: {})\n",
        levels.len(),
        levels.table_bytes().1,
        c.at_alpha,
        c.table_order_violations,
        2 * (c.points / 3),
        c.points / 3,
        c.exact_order_violations
    )))
}

/// A model as `export_model` wrote it: the blob's length, and the model and the index of
/// its stored tables decoded back from the blob.
pub struct Written {
    /// Bytes written.
    pub len: usize,
    /// The model the blob decodes to.
    pub model: nemm_core::Model,
    /// The index of the blob's precomputed tables.
    pub tables: nemm_core::StoredTables,
    /// With level tables (two or more stored levels): what they take and their measured
    /// blend error, one line.
    pub levels: Option<String>,
}

/// Writes `report.json` and `table4.md` (Table 4, then the test error per held-out run, the
/// learned against the virtual bench's reference coefficients when the data are the bench's,
/// then the whole-run error per level and run) into `dir`; with the report's identification,
/// also `identify.md`, which `table4.md` links to, and the degradation targets
/// ([`crate::report::targets`]) at the end of `table4.md`.
pub(crate) fn write_report(dir: &Path, report: &Report, table_name: &str) -> Result<()> {
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
    if let Some(sig) = &report.signature {
        let md = signature_markdown(sig);
        table = format!("{table}\n{}\n", md.trim_end());
        write_atomic_bytes(&dir.join(SIGNATURE_MD), md.as_bytes())?;
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
    if report.identify.is_some() {
        let targets = crate::report::targets::targets_markdown(report);
        if !targets.is_empty() {
            table = format!("{table}\n{}\n", targets.trim_end());
        }
    }
    write_atomic_bytes(&dir.join(table_name), table.as_bytes())?;
    Ok(())
}

/// The identifiability tables' file in a report folder.
pub(crate) const IDENTIFY_MD: &str = "identify.md";
/// The degradation signature in a report folder ([`crate::report::signature`]).
pub(crate) const SIGNATURE_MD: &str = "signature.md";

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

/// The output rule ([`output_guard::check`]) for a job on `cfg`'s dataset: the blob `out`,
/// the report and checkpoint folders against the dataset folder and its files; `replace`
/// lets `out` replace an existing file that is not a weights blob.
pub(crate) fn check_job_outputs(
    cfg: &Config,
    out: Option<&Path>,
    report_dir: Option<&Path>,
    checkpoint: Option<&Path>,
    replace: bool,
) -> Result<()> {
    let inputs = Inputs::new().dataset("--data", cfg.data.require_dir()?);
    let outputs: Vec<Output<'_>> = out
        .map(|p| Output::blob("--out", p))
        .into_iter()
        .chain(report_dir.map(|p| Output::folder("--report", p)))
        .chain(checkpoint.map(|p| Output::folder("--checkpoint", p)))
        .collect();
    output_guard::check(&outputs, &inputs, replace, "--replace")
}

/// Where `nemm train` writes its report, and how much of it.
#[derive(Debug, Clone, Copy)]
pub struct ReportTo<'a> {
    /// The report folder.
    pub dir: &'a Path,
    /// Also where the model puts the degradation (`crate::report::degradation::degradation_report`: every
    /// run's best-fit level, the signature and its figure, the bench's reference), which
    /// costs more than the rest of the report; `false` writes the force errors, the audit
    /// and the configuration only (a sweep whose table does not show it).
    pub degradation: bool,
}

/// `nemm train`: trains `cfg.model.variant` on `cfg.data` and writes the blob `out`; with
/// `report`, also `report.json`, `table.md`, the effective `config.toml` and (with
/// [`ReportTo::degradation`]) `identify.md`, the signature and its figure there.
/// `replace`: `out` may replace an existing file that is not a weights blob.
pub fn train(
    cfg: &Config,
    out: &Path,
    checkpoint: Option<&Path>,
    resume: bool,
    report: Option<ReportTo<'_>>,
    tables: &TablesArgs,
    replace: bool,
) -> Result<()> {
    let report_dir = report.map(|r| r.dir);
    tables.validate()?;
    check_job_outputs(cfg, Some(out), report_dir, checkpoint, replace)?;
    let cfg = &with_resolved_data(cfg)?;
    let _lock = checkpoint
        .map(|dir| open_checkpoint(dir, cfg, resume))
        .transpose()?;
    let variant = cfg.model.variant;
    let (ds, prepared) =
        load_dataset_prepared(cfg.data.require_dir()?, &cfg.data.prepare_config())?;
    tables.check_range(&crate::train::pipeline::meta_of(&prepared))?;
    let cfg = &cfg.with_static_force_from(&prepared);
    let pipeline = PipelineConfig::of(cfg);
    let t = Instant::now();
    let trained = train_variants(&prepared, &[variant], &pipeline, checkpoint, resume)?;
    let tv = trained
        .iter()
        .find(|t| t.variant == variant)
        .context("training produced no model")?;
    let written = export_model(
        &tv.model,
        out,
        &dataset_provenance(&ds, &cfg.data.dir),
        tables,
    )?;
    let evaluated = evaluate(std::slice::from_ref(tv), &prepared)?;
    let vr = evaluated.variants.get(variant.key()).context("report")?;
    println!(
        "wrote {} ({} bytes) in {:.0} s",
        out.display(),
        written.len,
        t.elapsed().as_secs_f64()
    );
    print!("{}", describe(&written.model, &written.tables, written.len));
    print!("{}", written.levels.as_deref().unwrap_or(""));
    println!(
        "test RMSE ({}): {:.4} of the force scale ({:.1} N); validation {:.4}",
        prepared.config.split.describe(),
        vr.rmse,
        vr.rmse_n,
        vr.val_rmse
    );
    print_audit(tv, &evaluated);
    // The fast path's verdict at export time, as `nemm export` prints it.
    print!(
        "{}",
        crate::train::table_check::report(
            &tv.model,
            crate::train::table_check::DEFAULT_TABLE_BOUND
        )
    );
    if let Some(to) = report {
        let mut report = evaluated;
        let degradation = to.degradation.then(|| {
            crate::report::degradation::degradation_report(
                &mut report,
                std::slice::from_ref(tv),
                &ds,
                &prepared,
                &cfg.data.dir,
            )
        });
        if let Some(c) = &report.bench_reference {
            println!("{}", c.markdown());
        }
        record_provenance(&mut report);
        write_report(to.dir, &report, "table.md")?;
        cfg.save(&to.dir.join(CONFIG_FILE))?;
        if let Some(loops) = degradation.as_ref().and_then(|d| d.signature.as_ref()) {
            crate::report::degradation::write_signature_figure(loops, to.dir, report.force_scale_n);
        }
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
                println!(
                    "fast path at {}: refused ({e}); use the exact mode",
                    ds.condition
                        .clone()
                        .unwrap_or_default()
                        .level(f64::from(alpha))
                );
                return Ok(());
            }
        };
        for (&v, &x) in u.iter().zip(&x) {
            let sample = Sample::new(v).with_position(x);
            let (Ok(a), Ok(b)) = (exact.step(sample), table.step(sample)) else {
                anyhow::bail!("a sample without alpha was refused");
            };
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
/// `replace`: `out` may replace an existing file that is not a weights blob.
pub fn export(
    checkpoint: &Path,
    out: &Path,
    table_bound: f32,
    tables: &TablesArgs,
    replace: bool,
) -> Result<()> {
    tables.validate()?;
    let inputs = Inputs::new().path("--checkpoint", checkpoint);
    output_guard::check(&[Output::blob("--out", out)], &inputs, replace, "--replace")?;
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
    let written = export_model(
        &model,
        out,
        &format!("checkpoint {}", checkpoint.display()),
        tables,
    )?;
    println!(
        "wrote {} ({} bytes) from {}",
        out.display(),
        written.len,
        checkpoint.join(latest.trim()).display()
    );
    let model = &written.model;
    print!("{}", describe(model, &written.tables, written.len));
    print!("{}", written.levels.as_deref().unwrap_or(""));
    print!("{}", crate::train::table_check::report(model, table_bound));
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
pub(crate) fn dataset_provenance(ds: &dataset::Dataset, dir: &Path) -> String {
    format!("{} ({})", ds.name, dir.display())
}
