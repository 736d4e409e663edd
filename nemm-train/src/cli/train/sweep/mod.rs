//! `nemm sweep`: the `lambda_ph` sweep (Table 5, also with the priors by the penalty alone) and the Table 3
//! search space, one `nemm train` process per job, run on this machine ([`Engine::Local`]) or
//! as a Slurm job array ([`Engine::Slurm`], [`slurm`]), collected into one table ([`collect()`]).
//!
//! A sweep lives in its report folder: the job list ([`SweepManifest`], `sweep-jobs.json`),
//! one folder per job (`jobs/ID/`: `config.toml`, `train.log`, `report.json` when it
//! finished, `exit` with its exit status) and the tables. Collecting and resuming need only
//! that folder.

use super::{
    check_job_outputs, lambda_ph_scale_note, with_resolved_data, AlphaPriors, Config, StatePriors,
    CONFIG_FILE,
};
use anyhow::{bail, Context, Result};
use collect::collect_sweep;
use record::{clear_exit, job_state, write_exit, JobState, SweepManifest, TRAIN_LOG};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod collect;
mod record;
pub(crate) mod slurm;

pub use slurm::SlurmArgs;

/// Default `nemm sweep` list of physics weights: Table 5's 0, 0.005, 0.015, 0.025 times 1000.
pub(crate) const TABLE5_LAMBDAS: [f64; 4] = [0.0, 5.0, 15.0, 25.0];

/// The paper's Table 3 search space: batch sizes.
pub(crate) const TABLE3_BATCH: [usize; 3] = [4, 8, 16];
/// The paper's Table 3 search space: hidden widths.
pub(crate) const TABLE3_HIDDEN: [usize; 3] = [8, 16, 32];
/// The paper's Table 3 search space: hidden layers.
pub(crate) const TABLE3_LAYERS: [usize; 4] = [3, 5, 7, 9];
/// The paper's Table 3 search space: learning rates (0.5e-2, 1e-2, 0.1e-2).
pub(crate) const TABLE3_LR: [f64; 3] = [5e-3, 1e-2, 1e-3];
/// The paper's best configuration of Table 3: batch 16, hidden 16, 5 layers, learning rate
/// 0.5e-2.
pub(crate) const TABLE3_PAPER_BEST: Table3Point = Table3Point {
    batch: 16,
    hidden: 16,
    layers: 5,
    lr: 5e-3,
};

/// A sweep grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SweepGrid {
    /// Only the `--lambda-ph` list, other hyperparameters as given (Table 5).
    Lambda,
    /// The Table 3 search space (batch {4, 8, 16} x hidden {8, 16, 32} x layers {3, 5, 7, 9}
    /// x lr {5e-3, 1e-2, 1e-3}: 108 jobs; the values overridable, [`Table3Args`]) times the
    /// `--lambda-ph` list.
    Table3,
    /// The `--lambda-ph` list twice: with the priors in alpha held by construction (the alpha
    /// branches) and imposed by the physics penalty alone (the paper's way), other
    /// hyperparameters as given (Table 5 with the construction-against-penalty ablation).
    Priors,
    /// The priors in the state (the flow force rising with `v_st`, the spring force with
    /// `x_pr`): held by construction (cumulative scalers, at the base's `lambda_ph`, which
    /// then acts on `b_pr`'s alpha term alone) and imposed by the physics penalty on the
    /// paper's MLPs at each `--lambda-ph` (Table 5 with the state construction-against-
    /// penalty ablation, `state-priors.md`).
    StatePriors,
    /// Where the model may put the degradation (`DegradationPoint::ALL`: the paper's NEMM,
    /// `b_fl` without its alpha branch, the lost-motion element, both; with `--lambda-diff`
    /// each also trained with the matched-difference term, `DegradationPoint::grid`) times
    /// the `--lambda-ph` list (default: the base's `lambda_ph`), collected with the degradation
    /// signature, the levels read back and the learned against the bench's coefficients
    /// (`degradation.md`).
    Degradation,
}

impl SweepGrid {
    /// Whether the grid's table shows where each job's model puts the degradation (the
    /// degradation grid); the other grids' jobs skip that part of their report
    /// (`nemm train --degradation-report=false`), the larger part of a short job's time.
    pub(crate) fn shows_degradation(self) -> bool {
        self == SweepGrid::Degradation
    }

    /// The table file the grid is collected into: `table3.md` for the Table 3 grid,
    /// `degradation.md` for the degradation grid, `state-priors.md` for the state grid,
    /// `table5.md` otherwise.
    pub(crate) fn table_file(self) -> &'static str {
        match self {
            SweepGrid::Table3 => "table3.md",
            SweepGrid::Degradation => "degradation.md",
            SweepGrid::StatePriors => "state-priors.md",
            SweepGrid::Lambda | SweepGrid::Priors => "table5.md",
        }
    }

    /// The `lambda_ph` list of the grid when `--lambda-ph` gives none: Table 5's
    /// (`TABLE5_LAMBDAS`), for the degradation grid the base's one value.
    pub fn default_lambdas(self, base: &Config) -> Vec<f64> {
        match self {
            SweepGrid::Degradation => vec![base.train.lambda_ph],
            SweepGrid::Lambda | SweepGrid::Priors | SweepGrid::StatePriors | SweepGrid::Table3 => {
                TABLE5_LAMBDAS.to_vec()
            }
        }
    }
}

/// One point of the degradation grid: which elements may change with alpha, and the weight
/// of the matched-difference term the model is trained with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DegradationPoint {
    /// The lost-motion element in series with `k_pr` ([`crate::config::ModelConfig::lost_motion`]).
    pub(crate) lost_motion: bool,
    /// `b_fl`'s alpha branch ([`crate::config::ModelConfig::b_fl_alpha`]).
    pub(crate) b_fl_alpha: bool,
    /// [`crate::config::TrainConfig::lambda_diff`] (0: the paper's loss).
    pub(crate) lambda_diff: f64,
}

impl DegradationPoint {
    /// The four element choices, trained with the paper's loss: the paper's NEMM (alpha in
    /// `b_fl`, `b_pr`, `k_pr`), the same with `b_fl` fixed in alpha, the lost-motion element
    /// added, and the element with `b_fl` fixed in alpha.
    pub(crate) const ALL: [DegradationPoint; 4] = [
        DegradationPoint::element(false, true),
        DegradationPoint::element(false, false),
        DegradationPoint::element(true, true),
        DegradationPoint::element(true, false),
    ];

    const fn element(lost_motion: bool, b_fl_alpha: bool) -> Self {
        DegradationPoint {
            lost_motion,
            b_fl_alpha,
            lambda_diff: 0.0,
        }
    }

    /// The grid: [`DegradationPoint::ALL`], and with a positive `lambda_diff` (the sweep's
    /// `--lambda-diff`) the four again trained with the difference term of that weight.
    pub(super) fn grid(lambda_diff: f64) -> Vec<DegradationPoint> {
        let mut v = Self::ALL.to_vec();
        if lambda_diff > 0.0 {
            v.extend(Self::ALL.map(|p| DegradationPoint { lambda_diff, ..p }));
        }
        v
    }

    /// The point a job's configuration trains.
    pub(super) fn of(config: &Config) -> Self {
        DegradationPoint {
            lost_motion: config.model.lost_motion,
            b_fl_alpha: config.model.b_fl_alpha,
            lambda_diff: config.train.lambda_diff,
        }
    }

    /// The job id's prefix: `paper`, `fixed-b-fl`, `lost-motion`, `lost-motion-fixed-b-fl`,
    /// followed by `_diff<lambda_diff>` with the difference term.
    pub(super) fn name(self) -> String {
        let element = match (self.lost_motion, self.b_fl_alpha) {
            (false, true) => "paper",
            (false, false) => "fixed-b-fl",
            (true, true) => "lost-motion",
            (true, false) => "lost-motion-fixed-b-fl",
        };
        if self.lambda_diff > 0.0 {
            format!("{element}_diff{}", self.lambda_diff)
        } else {
            element.to_string()
        }
    }
}

/// One point of the Table 3 search space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Table3Point {
    /// Batch size.
    pub batch: usize,
    /// Hidden width of the scalers.
    pub hidden: usize,
    /// Hidden layers of the scalers.
    pub layers: usize,
    /// Learning rate.
    pub lr: f64,
}

impl Table3Point {
    /// The point a job's configuration trains.
    pub fn of(config: &Config) -> Self {
        Table3Point {
            batch: config.train.batch,
            hidden: config.model.hidden,
            layers: config.model.layers,
            lr: config.train.lr,
        }
    }
}

/// The values of the Table 3 grid (`--grid table3`), the paper's by default.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct Table3Args {
    /// Batch sizes of `--grid table3` (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = TABLE3_BATCH)]
    pub(crate) grid_batch: Vec<usize>,
    /// Hidden widths of `--grid table3` (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = TABLE3_HIDDEN)]
    pub(crate) grid_hidden: Vec<usize>,
    /// Hidden layers of `--grid table3` (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = TABLE3_LAYERS)]
    pub(crate) grid_layers: Vec<usize>,
    /// Learning rates of `--grid table3` (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = TABLE3_LR)]
    pub(crate) grid_lr: Vec<f64>,
}

impl Default for Table3Args {
    fn default() -> Self {
        Table3Args {
            grid_batch: TABLE3_BATCH.to_vec(),
            grid_hidden: TABLE3_HIDDEN.to_vec(),
            grid_layers: TABLE3_LAYERS.to_vec(),
            grid_lr: TABLE3_LR.to_vec(),
        }
    }
}

impl Table3Args {
    /// Every point of the grid, batch outermost and learning rate innermost.
    pub fn points(&self) -> Vec<Table3Point> {
        let mut v = Vec::new();
        for &batch in &self.grid_batch {
            for &hidden in &self.grid_hidden {
                for &layers in &self.grid_layers {
                    for &lr in &self.grid_lr {
                        v.push(Table3Point {
                            batch,
                            hidden,
                            layers,
                            lr,
                        });
                    }
                }
            }
        }
        v
    }
}

/// One sweep job: its id and its whole configuration (the base with the job's overrides).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct SweepJob {
    /// Folder name under `<report>/jobs/`.
    pub(crate) id: String,
    /// The overridden settings (`lambda_ph`; for the Table 3 grid `batch`, `hidden`,
    /// `layers`, `lr`; for the priors grid `alpha_priors`, for the state grid
    /// `state_priors`; for the degradation grid
    /// `lost_motion`, `b_fl_alpha` and `lambda_diff`) with their values, for `sweep.json`.
    pub(crate) overrides: Vec<(String, String)>,
    /// The job's configuration.
    pub(crate) config: Config,
}

/// The jobs of a sweep: one per grid point and `lambdas` value, each a copy of `base` with
/// the `nemm` variant and the point's settings (`table3`: the points of the Table 3 grid).
pub(crate) fn sweep_jobs(
    base: &Config,
    grid: SweepGrid,
    table3: &Table3Args,
    lambdas: &[f64],
) -> Vec<SweepJob> {
    let combos: Vec<Option<Table3Point>> = match grid {
        SweepGrid::Lambda | SweepGrid::Priors | SweepGrid::StatePriors | SweepGrid::Degradation => {
            vec![None]
        }
        SweepGrid::Table3 => table3.points().into_iter().map(Some).collect(),
    };
    let priors: Vec<Option<AlphaPriors>> = match grid {
        SweepGrid::Priors => vec![Some(AlphaPriors::Construction), Some(AlphaPriors::Penalty)],
        SweepGrid::Lambda | SweepGrid::Table3 | SweepGrid::StatePriors | SweepGrid::Degradation => {
            vec![None]
        }
    };
    // The state grid: the penalty at every lambda, the construction once at the base's.
    let states: Vec<(Option<StatePriors>, bool)> = match grid {
        SweepGrid::StatePriors => vec![
            (Some(StatePriors::Construction), false),
            (Some(StatePriors::Penalty), true),
        ],
        _ => vec![(None, true)],
    };
    let elements: Vec<Option<DegradationPoint>> = match grid {
        SweepGrid::Degradation => DegradationPoint::grid(base.train.lambda_diff)
            .into_iter()
            .map(Some)
            .collect(),
        SweepGrid::Lambda | SweepGrid::Table3 | SweepGrid::Priors | SweepGrid::StatePriors => {
            vec![None]
        }
    };
    let base_lambda = [base.train.lambda_ph];
    let mut jobs = Vec::new();
    for (combo, element) in combos
        .iter()
        .flat_map(|c| elements.iter().map(move |e| (*c, *e)))
    {
        let mut arms: Vec<(Option<AlphaPriors>, Option<StatePriors>, f64)> = Vec::new();
        for &p in &priors {
            for &(state, every_lambda) in &states {
                let lams: &[f64] = if every_lambda { lambdas } else { &base_lambda };
                arms.extend(lams.iter().map(|&l| (p, state, l)));
            }
        }
        for (prior, state, lam) in arms {
            let mut config = base.clone();
            config.model.variant = nemm_core::ModelKind::Nemm;
            let mut id = String::new();
            let mut o: Vec<(String, String)> = Vec::new();
            if let Some(e) = element {
                id.push_str(&format!("{}_", e.name()));
                config.model.lost_motion = e.lost_motion;
                config.model.b_fl_alpha = e.b_fl_alpha;
                config.train.lambda_diff = e.lambda_diff;
                o.push(("lost_motion".into(), e.lost_motion.to_string()));
                o.push(("b_fl_alpha".into(), e.b_fl_alpha.to_string()));
                o.push(("lambda_diff".into(), e.lambda_diff.to_string()));
            }
            if let Some(p) = prior {
                id.push_str(&format!("{}_", p.name()));
                config.model.alpha_priors = p;
                o.push(("alpha_priors".into(), p.name().into()));
            }
            if let Some(p) = state {
                id.push_str(&format!("state-{}_", p.name()));
                config.model.state_priors = p;
                o.push(("state_priors".into(), p.name().into()));
            }
            if let Some(Table3Point {
                batch: b,
                hidden: h,
                layers: l,
                lr,
            }) = combo
            {
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

/// Where a sweep's jobs run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Engine {
    /// Processes on this machine, `--jobs` at a time; returns when all have finished.
    #[default]
    Local,
    /// A Slurm job array (one task per job, `--jobs` at a time) submitted with `sbatch`;
    /// returns once submitted.
    Slurm,
}

/// A job's folder under `report`.
pub(crate) fn job_dir(report: &Path, id: &str) -> PathBuf {
    report.join("jobs").join(id)
}

/// The `nemm train` command line (without the program name) of a job of `grid` in folder
/// `dir`: its `config.toml` there, its blob and report written there (the report without
/// the degradation part unless the grid's table shows it,
/// [`SweepGrid::shows_degradation`]).
pub(crate) fn train_args(dir: &str, grid: SweepGrid) -> Vec<String> {
    let mut args: Vec<String> = vec![
        "train".into(),
        "--config".into(),
        format!("{dir}/{CONFIG_FILE}"),
        "--out".into(),
        format!("{dir}/model.nemm"),
        "--report".into(),
        dir.into(),
    ];
    if !grid.shows_degradation() {
        args.push("--degradation-report=false".into());
    }
    args
}

/// The `nemm train` command line (without the program name) of a job of `grid`; its
/// configuration is `<report>/jobs/<id>/config.toml`, written by [`write_jobs`].
pub(crate) fn job_args(job: &SweepJob, report: &Path, grid: SweepGrid) -> Vec<String> {
    train_args(&job_dir(report, &job.id).display().to_string(), grid)
}

/// Writes every job's configuration to `<report>/jobs/<id>/config.toml`.
pub(crate) fn write_jobs(jobs: &[SweepJob], report: &Path) -> Result<()> {
    for job in jobs {
        let dir = job_dir(report, &job.id);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        job.config.save(&dir.join(CONFIG_FILE))?;
    }
    Ok(())
}

/// What `nemm sweep` does besides building the jobs.
#[derive(Debug, Clone, Default)]
pub struct SweepOptions {
    /// Jobs at a time: local processes, or the Slurm array's `%N` throttle (default
    /// `slurm::DEFAULT_THROTTLE` there, 1 locally).
    pub jobs: Option<usize>,
    /// Where the jobs run (default: as the sweep was created; [`Engine::Local`] for a new
    /// one).
    pub engine: Option<Engine>,
    /// The Slurm engine's options.
    pub slurm: SlurmArgs,
    /// Only print one `nemm train` command line per job.
    pub list: bool,
    /// Slurm: write the job script and print the cost, do not submit.
    pub dry_run: bool,
}

/// `nemm sweep`: every configuration is an independent `nemm train --config
/// <report>/jobs/<id>/config.toml` process, run by `options.engine`; results are collected
/// into one table (the grid's `SweepGrid::table_file`).
pub fn sweep(
    base: &Config,
    grid: SweepGrid,
    table3: &Table3Args,
    lambdas: &[f64],
    report: &Path,
    options: &SweepOptions,
) -> Result<()> {
    if grid != SweepGrid::Table3 && *table3 != Table3Args::default() {
        bail!("--grid-batch, --grid-hidden, --grid-layers and --grid-lr set the values of --grid table3");
    }
    base.data.require_dir()?;
    check_job_outputs(base, None, Some(report), None, false)?;
    // Every job runs with the data options resolved once, as this run prints them.
    let base = &with_resolved_data(base)?;
    let jobs = sweep_jobs(base, grid, table3, lambdas);
    if jobs.is_empty() {
        bail!("the sweep has no jobs (an empty grid or --lambda-ph list)");
    }
    for j in &jobs {
        j.config.validate()?;
    }
    if let Some(note) = lambda_ph_scale_note(lambdas) {
        eprintln!("{note}");
    }
    write_jobs(&jobs, report)?;
    let manifest = SweepManifest {
        grid,
        engine: options.engine.unwrap_or_default(),
        jobs,
        slurm: None,
        submissions: Vec::new(),
    };
    if options.list {
        let exe = std::env::current_exe().context("cannot find the nemm executable")?;
        manifest.save(report)?;
        for j in &manifest.jobs {
            println!(
                "{} {}",
                exe.display(),
                job_args(j, report, manifest.grid).join(" ")
            );
        }
        return Ok(());
    }
    run_sweep(manifest, report, options)
}

/// `nemm sweep --resume REPORT`: runs the jobs of the sweep in `report` that have no result
/// (failed, killed, or never run) again, on the sweep's engine unless `options.engine` says
/// otherwise; each from its `config.toml` as it is now.
pub fn resume(report: &Path, options: &SweepOptions) -> Result<()> {
    let manifest = SweepManifest::load(report)?;
    if options.list {
        bail!("--list lists a new sweep's jobs; --collect shows an existing one's");
    }
    run_sweep(manifest, report, options)
}

/// Runs the unfinished jobs of `manifest` on its engine (or `options.engine`).
fn run_sweep(mut manifest: SweepManifest, report: &Path, options: &SweepOptions) -> Result<()> {
    let engine = options.engine.unwrap_or(manifest.engine);
    manifest.engine = engine;
    let mut pending = Vec::new();
    for (i, j) in manifest.jobs.iter().enumerate() {
        if !matches!(job_state(report, &j.id)?, JobState::Done(_)) {
            pending.push(i);
        }
    }
    let done = manifest.jobs.len() - pending.len();
    if done > 0 {
        eprintln!("[sweep] {done} job(s) already done, skipped");
    }
    match engine {
        Engine::Local => {
            if options.dry_run {
                bail!("--dry-run writes a Slurm job script: give --engine slurm (--list prints the local command lines)");
            }
            manifest.save(report)?;
            let jobs: Vec<&SweepJob> = pending.iter().map(|&i| &manifest.jobs[i]).collect();
            run_local(&jobs, manifest.grid, report, options.jobs.unwrap_or(1))?;
            let c = collect_sweep(&manifest, report)?;
            c.print(report, manifest.grid);
            Ok(())
        }
        Engine::Slurm => slurm::submit_sweep(manifest, &pending, report, options),
    }
}

/// Runs `jobs` as local `nemm train` processes, `parallel` at a time; each one's output in
/// its `train.log` and its exit status in its `exit` file (written atomically when it ends).
pub(crate) fn run_local(
    jobs: &[&SweepJob],
    grid: SweepGrid,
    report: &Path,
    parallel: usize,
) -> Result<()> {
    let exe = std::env::current_exe().context("cannot find the nemm executable")?;
    std::fs::create_dir_all(report.join("jobs"))?;
    let t = Instant::now();
    let mut pending: std::collections::VecDeque<&SweepJob> = jobs.iter().copied().collect();
    let mut running: Vec<(String, std::process::Child)> = Vec::new();
    let mut failed = Vec::new();
    let total = jobs.len();
    let mut done = 0;
    while !pending.is_empty() || !running.is_empty() {
        while running.len() < parallel.max(1) {
            let Some(j) = pending.pop_front() else { break };
            let dir = job_dir(report, &j.id);
            std::fs::create_dir_all(&dir)?;
            clear_exit(&dir)?;
            let log = std::fs::File::create(dir.join(TRAIN_LOG))?;
            let child = std::process::Command::new(&exe)
                .args(job_args(j, report, grid))
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
                let dir = job_dir(report, &id);
                write_exit(&dir, &exit_text(&status))?;
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
                        dir.join(TRAIN_LOG).display()
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
    Ok(())
}

/// A process's exit status as the `exit` file holds it: the code, or `signal N`.
fn exit_text(status: &std::process::ExitStatus) -> String {
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        if let Some(s) = status.signal() {
            return format!("signal {s}");
        }
    }
    status.code().map_or("unknown".into(), |c| c.to_string())
}

/// `nemm sweep --collect REPORT`: the table of whatever finished in the sweep in `report`,
/// and the jobs that failed or have no result.
pub fn collect(report: &Path) -> Result<()> {
    let manifest = SweepManifest::load(report)?;
    let c = collect_sweep(&manifest, report)?;
    c.print(report, manifest.grid);
    let queued: Vec<&str> = slurm::queued_jobs(&manifest)
        .into_iter()
        .map(|i| manifest.jobs[i].id.as_str())
        .filter(|id| c.missing.iter().any(|m| m == id))
        .collect();
    if !queued.is_empty() {
        eprintln!(
            "[sweep] of those, still queued or running in Slurm: {}",
            queued.join(", ")
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_state_grid_is_the_construction_once_and_the_penalty_per_lambda() {
        let base = Config::default();
        let jobs = sweep_jobs(
            &base,
            SweepGrid::StatePriors,
            &Table3Args::default(),
            &[0.0, 5.0, 15.0],
        );
        let ids: Vec<&str> = jobs.iter().map(|j| j.id.as_str()).collect();
        assert_eq!(
            ids,
            [
                "state-construction_lph5",
                "state-penalty_lph0",
                "state-penalty_lph5",
                "state-penalty_lph15"
            ]
        );
        assert_eq!(jobs[0].config.model.state_priors, StatePriors::Construction);
        assert_eq!(jobs[0].config.train.lambda_ph, base.train.lambda_ph);
        assert!(jobs[1..]
            .iter()
            .all(|j| j.config.model.state_priors == StatePriors::Penalty));
        assert_eq!(SweepGrid::StatePriors.table_file(), "state-priors.md");
    }
}
