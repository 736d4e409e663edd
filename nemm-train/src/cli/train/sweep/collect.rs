//! A sweep's collection: the grid's table (`SweepGrid::table_file`) with `sweep.json` of the jobs
//! its record ([`super::record`]) shows finished, whichever engine ran them.

use super::record::{job_state, JobState, SweepManifest, TRAIN_LOG};
use super::{
    job_dir, Config, DegradationPoint, SweepGrid, SweepJob, Table3Point, TABLE3_PAPER_BEST,
};
use crate::report::signature::LevelSignature;
use crate::report::tables::Report;
use anyhow::Result;
use nemm_dataset::atomic_file::write_atomic_bytes;
use std::fmt::Write as _;
use std::path::Path;

/// What [`collect_sweep`] found and wrote.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Collected {
    /// The table as written (the grid's `SweepGrid::table_file`).
    pub(crate) markdown: String,
    /// Jobs in the table.
    pub(crate) done: usize,
    /// Failed jobs: id and why (exit status, the last line of the log).
    pub(crate) failed: Vec<(String, String)>,
    /// Jobs without a result or an exit status.
    pub(crate) missing: Vec<String>,
}

impl Collected {
    /// Prints the table, where it was written, and the jobs not in it.
    pub(super) fn print(&self, report: &Path, grid: SweepGrid) {
        println!("{}", self.markdown);
        println!(
            "sweep table in {} and {}",
            report.join(grid.table_file()).display(),
            report.join("sweep.json").display()
        );
        for (id, why) in &self.failed {
            eprintln!(
                "[sweep] FAILED {id} ({why}); see {}",
                job_dir(report, id).join(TRAIN_LOG).display()
            );
        }
        if !self.missing.is_empty() {
            eprintln!(
                "[sweep] {} job(s) without a result (waiting, running, killed or never run): {}",
                self.missing.len(),
                self.missing.join(", ")
            );
        }
        if !self.failed.is_empty() || !self.missing.is_empty() {
            eprintln!(
                "[sweep] `nemm sweep --resume {}` runs the failed and missing jobs again",
                report.display()
            );
        }
    }
}

/// One finished job's figures.
struct Row<'a> {
    job: &'a SweepJob,
    val: f64,
    test: f64,
    test_n: f64,
    violations: usize,
    seconds: f64,
    info: std::collections::BTreeMap<String, String>,
    /// The degradation grid's figures of the job's NEMM.
    degradation: DegradationCells,
}

/// Reads every job's state under `<report>/jobs/` and writes `sweep.json` (every job with its
/// status, the figures of those that finished) and the grid's table (`table5.md`,
/// `state-priors.md` for the state grid, or
/// `table3.md` with the Table 3 hyperparameters and the paper's best configuration against
/// the best found): one row per finished job (hyperparameters, validation and test RMSE,
/// violations, training time), then the jobs that failed or have no result.
pub(crate) fn collect_sweep(manifest: &SweepManifest, report: &Path) -> Result<Collected> {
    let mut rows: Vec<Row> = Vec::new();
    let (mut failed, mut missing) = (Vec::new(), Vec::new());
    let mut status = std::collections::BTreeMap::new();
    for j in &manifest.jobs {
        let s = job_state(report, &j.id)?;
        let name = match &s {
            JobState::Done(_) => "done",
            JobState::Failed(_) => "failed",
            JobState::Missing => "missing",
        };
        status.insert(j.id.as_str(), name);
        match s {
            JobState::Done(r) => match r.variants.get("nemm") {
                Some(v) => rows.push(Row {
                    job: j,
                    val: v.val_rmse,
                    test: v.rmse,
                    test_n: v.rmse_n,
                    violations: v.violations,
                    seconds: v.train_seconds,
                    info: r.info.clone(),
                    degradation: DegradationCells::of(&r, "nemm"),
                }),
                None => failed.push((j.id.clone(), "its report has no NEMM".to_string())),
            },
            JobState::Failed(why) => failed.push((j.id.clone(), why)),
            JobState::Missing => missing.push(j.id.clone()),
        }
    }
    let table3 = manifest.grid == SweepGrid::Table3;
    let degradation = manifest.grid == SweepGrid::Degradation;
    let state = manifest.grid == SweepGrid::StatePriors;
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
    let (head, rule) = if table3 {
        (
            "| Job | Batch | Hidden | Layers | Learning rate |",
            "|---|---:|---:|---:|---:|",
        )
    } else if degradation {
        (
            "| Job | Lost motion | b_fl in alpha | lambda_diff |",
            "|---|---|---|---:|",
        )
    } else if state {
        ("| Job | State priors |", "|---|---|")
    } else {
        ("| Job | Alpha priors |", "|---|---|")
    };
    if degradation {
        md += DegradationCells::LEGEND;
    }
    let (tail_head, tail_rule) = if degradation {
        (DegradationCells::HEAD, DegradationCells::RULE)
    } else {
        ("", "")
    };
    let _ = writeln!(md, "{head} lambda_ph | Validation RMSE | Test RMSE | Test RMSE [N] | Rel. test error (%) | Violations |{tail_head} Time |");
    let _ = writeln!(md, "{rule}---:|---:|---:|---:|---:|---:|{tail_rule}---:|");
    for r in &rows {
        let (j, val, test, test_n, viol, secs) =
            (&r.job, r.val, r.test, r.test_n, r.violations, r.seconds);
        let lam = j.config.train.lambda_ph;
        let rel = base.map_or("-".into(), |b| format!("{:.1}", 100.0 * test / b.test));
        let cols = if table3 {
            let p = Table3Point::of(&j.config);
            format!("{} | {} | {} | {}", p.batch, p.hidden, p.layers, p.lr)
        } else if degradation {
            let p = DegradationPoint::of(&j.config);
            let yes = |b: bool| if b { "yes" } else { "no" };
            format!(
                "{} | {} | {}",
                yes(p.lost_motion),
                yes(p.b_fl_alpha),
                p.lambda_diff
            )
        } else if state {
            j.config.model.state_priors.name().to_string()
        } else {
            j.config.model.alpha_priors.name().to_string()
        };
        let tail = if degradation {
            r.degradation.cells()
        } else {
            String::new()
        };
        let _ = writeln!(
            md,
            "| {} | {cols} | {lam} | {val:.4} | {test:.4} | {test_n:.1} | {rel} | {viol} |{tail} {secs:.0} s |",
            j.id
        );
    }
    let mut ranked: Vec<&Row> = rows.iter().collect();
    ranked.sort_by(|a, b| a.val.total_cmp(&b.val));
    if let Some(best) = ranked.first() {
        let _ = writeln!(
            md,
            "\nBest by validation RMSE: `{}` (test RMSE {:.4}).",
            best.job.id, best.test
        );
    }
    if table3 {
        md += &paper_best_line(manifest, &ranked);
        if !rows.is_empty() {
            let secs: Vec<f64> = rows.iter().map(|r| r.seconds).collect();
            let _ = writeln!(
                md,
                "\nTraining time per configuration: mean {:.0} s, longest {:.0} s ({} configurations).",
                secs.iter().sum::<f64>() / secs.len() as f64,
                secs.iter().copied().fold(0.0, f64::max),
                secs.len()
            );
        }
    }
    if !failed.is_empty() || !missing.is_empty() {
        let _ = writeln!(md, "\nNot in the table:");
        for (id, why) in &failed {
            let _ = writeln!(md, "- `{id}`: failed ({why})");
        }
        for id in &missing {
            let _ = writeln!(
                md,
                "- `{id}`: no result (waiting, running, killed or never run)"
            );
        }
    }
    let by_id: std::collections::BTreeMap<&str, &Row> =
        rows.iter().map(|r| (r.job.id.as_str(), r)).collect();
    let json: Vec<serde_json::Value> = manifest
        .jobs
        .iter()
        .map(|j| {
            let overrides: std::collections::BTreeMap<_, _> = j.overrides.iter().cloned().collect();
            match by_id.get(j.id.as_str()) {
                Some(r) => {
                    let mut v = serde_json::json!({
                        "id": j.id, "status": "done", "overrides": overrides,
                        "val_rmse": r.val, "rmse": r.test, "rmse_n": r.test_n, "violations": r.violations, "train_seconds": r.seconds,
                    });
                    if degradation {
                        v["degradation"] = r.degradation.json();
                    }
                    v
                }
                None => serde_json::json!({
                    "id": j.id, "status": status.get(j.id.as_str()).copied().unwrap_or("failed"), "overrides": overrides,
                }),
            }
        })
        .collect();
    write_atomic_bytes(
        &report.join("sweep.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    write_atomic_bytes(&report.join(manifest.grid.table_file()), md.as_bytes())?;
    Ok(Collected {
        markdown: md,
        done: rows.len(),
        failed,
        missing,
    })
}

/// Where a job's model puts the degradation, from its report: the signature at the highest
/// lossy level, the levels read back, and the learned against the bench's coefficients.
#[derive(Debug, Clone, Default, PartialEq)]
struct DegradationCells {
    /// The highest lossy level of the signature and the model's signature there.
    signature: Option<LevelSignature>,
    /// Per level of the identification: level, role, runs within, runs.
    read_back: Vec<(f64, String, usize, usize)>,
    /// The learned against the bench's `k_pr,c` and `b_fl` changes.
    figures: crate::report::reference::DegradationFigures,
}

impl DegradationCells {
    /// What the degradation columns are, above the table.
    const LEGEND: &'static str = "lambda_diff: the weight of the matched-difference term in the \
        training loss (0: the paper's loss). Signature: the relative error of the model's difference loop \
        F(0) - F(alpha) against the measured one at the highest lossy level (median over the \
        conditions; worst at the smallest amplitude; 0 is the measured degradation, 1 no change). \
        Read back: per level, the runs whose best-fit level is within the identification's \
        tolerance of the label (test levels marked). k_pr,c: the learned change of the \
        compression-side stiffness (through the lost-motion element where the model has it) \
        over the bench's. b_fl: the learned minus the bench's change of b_fl at -1 m/s.\n\n";
    /// The degradation columns' header cells.
    const HEAD: &'static str =
        " Signature (median) | Signature (worst, small amplitude) | Read back | k_pr,c ratio | b_fl change - bench's [pp] |";
    /// Their alignment row.
    const RULE: &'static str = "---:|---:|---|---:|---:|";

    /// Model `key`'s figures in `report` (each absent where the report has no part for it).
    fn of(report: &Report, key: &str) -> Self {
        let signature = report.signature.as_ref().and_then(|s| s.summary(key).pop());
        let read_back = report
            .identify
            .as_ref()
            .and_then(|id| id.variants.get(key))
            .map(|f| {
                f.levels
                    .iter()
                    .map(|l| (l.alpha, l.role.clone(), l.within, l.runs))
                    .collect()
            })
            .unwrap_or_default();
        DegradationCells {
            signature,
            read_back,
            figures: report
                .bench_reference
                .as_ref()
                .map(|c| c.degradation_figures())
                .unwrap_or_default(),
        }
    }

    /// The table cells, each `-` where absent.
    fn cells(&self) -> String {
        let dash = || "-".to_string();
        let (median, worst) = self.signature.as_ref().map_or((dash(), dash()), |l| {
            (
                format!("{:.2} at {}", l.median, l.alpha),
                format!(
                    "{:.2} at {:.0} mm",
                    l.small_worst,
                    l.small_amplitude_m * 1e3
                ),
            )
        });
        let read_back = if self.read_back.is_empty() {
            dash()
        } else {
            self.read_back
                .iter()
                .map(|(a, role, within, runs)| {
                    let mark = if role == "test" { " (test)" } else { "" };
                    format!("{a}{mark}: {within}/{runs}")
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        let k = self
            .figures
            .k_pr_compression_ratio
            .map_or_else(dash, |r| format!("{r:.2}"));
        let b = self
            .figures
            .b_fl_change_pp
            .map_or_else(dash, |d| format!("{d:+.1}"));
        format!(" {median} | {worst} | {read_back} | {k} | {b} |")
    }

    /// The figures for `sweep.json`.
    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "signature": self.signature.as_ref().map(|l| serde_json::json!({
                "alpha": l.alpha, "median": l.median, "within": l.within,
                "conditions": l.conditions, "small_amplitude_m": l.small_amplitude_m,
                "small_worst": l.small_worst,
            })),
            "read_back": self.read_back.iter().map(|(a, role, within, runs)| serde_json::json!({
                "alpha": a, "role": role, "within": within, "runs": runs,
            })).collect::<Vec<_>>(),
            "k_pr_compression_ratio": self.figures.k_pr_compression_ratio,
            "b_fl_change_minus_bench_pp": self.figures.b_fl_change_pp,
        })
    }
}

/// The Table 3 summary's line on the paper's best configuration ([`TABLE3_PAPER_BEST`]):
/// its rank by validation RMSE among the finished jobs and its errors, or why it has none.
fn paper_best_line(manifest: &SweepManifest, ranked: &[&Row]) -> String {
    let p = TABLE3_PAPER_BEST;
    let head = format!(
        "The paper's best (Table 3: batch {}, hidden {}, {} layers, learning rate {}): ",
        p.batch, p.hidden, p.layers, p.lr
    );
    let is_paper = |c: &Config| Table3Point::of(c) == p;
    if let Some((k, r)) = ranked
        .iter()
        .enumerate()
        .find(|(_, r)| is_paper(&r.job.config))
    {
        let best = ranked[0];
        format!(
            "{head}`{}`, validation RMSE {:.4}, rank {} of {} by validation RMSE, test RMSE {:.4} \
             (the best here: validation RMSE {:.4}, test RMSE {:.4}).\n",
            r.job.id,
            r.val,
            k + 1,
            ranked.len(),
            r.test,
            best.val,
            best.test
        )
    } else if manifest.jobs.iter().any(|j| is_paper(&j.config)) {
        format!("{head}in the grid, not finished.\n")
    } else {
        format!("{head}not in this grid.\n")
    }
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
