//! `nemm sweep`: the `lambda_ph` sweep (Table 5, also with the priors by the penalty alone) and the Table 3
//! search space, one `nemm train` process per job.

use super::*;

/// Default `nemm sweep` list of physics weights: Table 5's 0, 0.005, 0.015, 0.025 times 1000.
pub const TABLE5_LAMBDAS: [f64; 4] = [0.0, 5.0, 15.0, 25.0];

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
/// `table5.md` (one row per job: hyperparameters, validation and test RMSE, violations). A
/// job whose report is missing or cannot be read is left out with a warning.
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
        let read = std::fs::read_to_string(&p)
            .map_err(|e| format!("no report ({}: {e}): not finished or failed", p.display()))
            .and_then(|t| {
                serde_json::from_str::<Report>(&t)
                    .map_err(|e| format!("a corrupt report ({}: {e}): left out", p.display()))
            });
        match read {
            Ok(r) => {
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
            Err(why) => eprintln!("warning: job {} has {why}", j.id),
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
    if !collect_only {
        check_job_outputs(base, None, Some(report), None, false)?;
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn collect_leaves_out_a_corrupt_report_as_a_missing_one() {
        let tmp = tempfile::tempdir().unwrap();
        let jobs = sweep_jobs(&Config::default(), SweepGrid::Lambda, &[0.0, 5.0]);
        assert_eq!(jobs.len(), 2);
        // One job's report cut short, the other's missing: both left out, the table written.
        let dir = job_dir(tmp.path(), &jobs[0]);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("report.json"), "{\"variants\": {").unwrap();
        let md = collect_sweep(&jobs, tmp.path()).unwrap();
        assert!(!md.contains(&jobs[0].id), "{md}");
        assert!(tmp.path().join("table5.md").is_file());
    }
}
