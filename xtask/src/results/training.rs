//! The `training` block (`cargo xtask results --training DIR`): Table 4 (and Table 5 and
//! the degradation ablation, if present) of a finished report folder, with its provenance;
//! the blocks of collected sweeps ([`sweep_block()`]): `table3` (`cargo xtask results
//! --table3 DIR`, a collected Table 3 sweep) and `state-priors` (`cargo xtask results
//! --state-priors DIR`, the ablation of the priors in the state).

use super::{
    command_line, commit, refuse_dirty, sweep_commit, write_block, write_block_in, README,
};
use crate::Paths;
use std::fmt::Write as _;
use std::path::Path;

/// `cargo xtask results --training DIR`: the `training` block from a report directory.
pub fn training(paths: &Paths, dir: &Path, allow_dirty: bool) -> Result<(), String> {
    let read = |name: &str| -> Result<Option<String>, String> {
        let p = dir.join(name);
        match std::fs::read_to_string(&p) {
            Ok(t) => Ok(Some(t)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(format!("{}: {e}", p.display())),
        }
    };
    let table4 = read("table4.md")?.ok_or_else(|| {
        format!(
            "{}: no table4.md (a finished `nemm compare` or `nemm demo` report directory \
             has one)",
            dir.display()
        )
    })?;
    let table5 = read("table5.md")?;
    let degradation = read("degradation.md")?;
    let identify = read("identify.md")?;
    let info = match read("report.json")? {
        Some(json) => report_info(&json).map_err(|e| format!("{}: {e}", dir.display()))?,
        None => Vec::new(),
    };
    refuse_dirty("the work tree", &commit(&paths.root), allow_dirty)?;
    if let Some((_, c)) = info.iter().find(|(k, _)| k == "commit") {
        refuse_dirty(
            &format!("{}/report.json's training", dir.display()),
            c,
            allow_dirty,
        )?;
    }
    for (name, table) in [("table5.md", &table5), ("degradation.md", &degradation)] {
        if let Some(c) = table.as_deref().and_then(sweep_commit) {
            refuse_dirty(&format!("{}/{name}'s sweep", dir.display()), c, allow_dirty)?;
        }
    }
    let table4 = with_identify_summary(&table4, identify.as_deref());
    let md = training_markdown(
        &command_line(),
        &commit(&paths.root),
        dir,
        &info,
        &table4,
        table5.as_deref(),
        degradation.as_deref(),
    );
    write_block(paths, "training", &md)?;
    write_block_in(
        paths,
        README,
        "headline",
        &headline_markdown(&info, &table4),
    )
}

/// A collected sweep's table and the block of `docs/results.md` it fills
/// ([`sweep_block()`]).
#[derive(Debug)]
pub struct SweepBlock {
    /// The table file `nemm sweep --collect DIR` writes into the folder.
    pub table: &'static str,
    /// The block of the results file.
    pub block: &'static str,
    /// What the block shows, written between its provenance and the engine's lines (none:
    /// the table's own first lines say it).
    pub heading: Option<&'static str>,
}

/// The `table3` block: a collected `nemm sweep --grid table3` (the paper's Table 3 search).
pub const TABLE3: SweepBlock = SweepBlock {
    table: "table3.md",
    block: "table3",
    heading: None,
};

/// The `state-priors` block: a collected `nemm sweep --grid state-priors` (the ablation of
/// the priors in the state).
pub const STATE_PRIORS: SweepBlock = SweepBlock {
    table: "state-priors.md",
    block: "state-priors",
    heading: Some(
        "The ablation of the priors in the state on the data the sweep ran on (the table's \
         first line names it): the NEMM trained with `--state-priors construction` \
         (cumulative scalers: the flow and spring forces rise with the state for every \
         weight) against `--state-priors penalty` (the paper's MLPs and physics penalty) at \
         each `lambda_ph`, with the test RMSE, the violations and the training time of each \
         job.",
    ),
};

/// `cargo xtask results --table3 DIR` ([`TABLE3`]) and `--state-priors DIR`
/// ([`STATE_PRIORS`]): the block `sweep.block` from the report folder of a collected sweep
/// (`nemm sweep --grid ... --report DIR`, then `--collect DIR`): its table `sweep.table`,
/// the engine it ran on and its wall time from `sweep-jobs.json` and the jobs' `exit` files.
pub fn sweep_block(
    paths: &Paths,
    dir: &Path,
    allow_dirty: bool,
    sweep: &SweepBlock,
) -> Result<(), String> {
    let table_path = dir.join(sweep.table);
    let table = std::fs::read_to_string(&table_path).map_err(|e| {
        format!(
            "{}: {e} (collect the sweep first: `nemm sweep --collect {}`)",
            table_path.display(),
            dir.display()
        )
    })?;
    refuse_dirty("the work tree", &commit(&paths.root), allow_dirty)?;
    if let Some(c) = sweep_commit(&table) {
        refuse_dirty(&format!("{}'s sweep", table_path.display()), c, allow_dirty)?;
    }
    let jobs_path = dir.join("sweep-jobs.json");
    let manifest: serde_json::Value = std::fs::read_to_string(&jobs_path)
        .map_err(|e| format!("{}: {e}", jobs_path.display()))
        .and_then(|t| {
            serde_json::from_str(&t).map_err(|e| format!("{}: {e}", jobs_path.display()))
        })?;
    let md = sweep_markdown(
        &command_line(),
        &commit(&paths.root),
        dir,
        sweep,
        &manifest,
        last_exit_unix_s(&dir.join("jobs")),
        &table,
    );
    write_block(paths, sweep.block, &md)
}

/// When the last job of a sweep ended: the newest modification time of the `exit` files
/// under `jobs` (seconds since the epoch); `None` when none is there.
fn last_exit_unix_s(jobs: &Path) -> Option<f64> {
    std::fs::read_dir(jobs)
        .ok()?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            std::fs::metadata(e.path().join("exit"))
                .ok()?
                .modified()
                .ok()
        })
        .filter_map(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map(|d| d.as_secs_f64())
        .reduce(f64::max)
}

/// A collected sweep's block: where it was copied from, the sweep's heading (if any), the
/// engine (for Slurm: the submissions, CPUs per task, throttle, time limit) and the wall time
/// from the first submission to the last job's end, then the table.
fn sweep_markdown(
    command: &str,
    commit: &str,
    dir: &Path,
    sweep: &SweepBlock,
    manifest: &serde_json::Value,
    last_exit_unix_s: Option<f64>,
    table: &str,
) -> String {
    let mut md = format!(
        "Copied by `{command}` at commit `{commit}` from `{}`.\n\n",
        dir.join(sweep.table).display()
    );
    if let Some(heading) = sweep.heading {
        let _ = writeln!(md, "{heading}\n");
    }
    let engine = manifest
        .get("engine")
        .and_then(serde_json::Value::as_str)
        .unwrap_or("unknown");
    let submissions = manifest
        .get("submissions")
        .and_then(serde_json::Value::as_array)
        .map(Vec::as_slice)
        .unwrap_or_default();
    match (engine, manifest.get("slurm")) {
        ("slurm", Some(s)) => {
            let field = |k: &str| {
                s.get(k)
                    .map(|v| v.as_str().map_or_else(|| v.to_string(), str::to_string))
                    .unwrap_or_else(|| "-".into())
            };
            let arrays: Vec<String> = submissions
                .iter()
                .map(|sub| {
                    let get = |k: &str| sub.get(k).and_then(serde_json::Value::as_str);
                    format!(
                        "job {} (array {})",
                        get("job_id").unwrap_or("?"),
                        get("array").unwrap_or("?")
                    )
                })
                .collect();
            let _ = writeln!(
                md,
                "Run by the Slurm engine: {}; {} CPU(s) per task, at most {} task(s) at a \
                 time, time limit {} per task.",
                if arrays.is_empty() {
                    "no submission recorded".to_string()
                } else {
                    arrays.join(", ")
                },
                field("cpus_per_task"),
                field("throttle"),
                field("time"),
            );
        }
        (e, _) => {
            let _ = writeln!(md, "Run by the {e} engine.");
        }
    }
    let first = submissions
        .iter()
        .filter_map(|s| {
            s.get("submitted_unix_s")
                .and_then(serde_json::Value::as_f64)
        })
        .reduce(f64::min);
    if let (Some(a), Some(b)) = (first, last_exit_unix_s) {
        if b >= a {
            let _ = writeln!(
                md,
                "Wall time from the first submission to the last job's end: {:.0} min.",
                (b - a) / 60.0
            );
        }
    }
    let _ = writeln!(md, "\n{}", table.trim_end());
    md
}

/// The README's headline block: the summary of Table 4 of the copied report (without the
/// per-run breakdown) and where it came from.
fn headline_markdown(info: &[(String, String)], table4: &str) -> String {
    let recorded = |key: &str| info.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str());
    // The summary table and its test-set line; the per-run breakdown stays in results.md.
    let summary = table4
        .split("\nTest RMSE per held-out run")
        .next()
        .unwrap_or(table4);
    let mut md = summary.trim_end().to_string();
    md += "\n\n";
    match (recorded("command"), recorded("commit")) {
        (Some(cmd), Some(c)) => {
            let _ = write!(md, "Trained by `{cmd}` at commit `{c}`; ");
        }
        (Some(cmd), None) => {
            let _ = write!(md, "Trained by `{cmd}`; ");
        }
        _ => {}
    }
    md += "details in [docs/results.md](docs/results.md).";
    md
}

/// The `info` facts of a `report.json` (`command`, `dataset`, `total_seconds`, ...).
fn report_info(json: &str) -> Result<Vec<(String, String)>, String> {
    let v: serde_json::Value =
        serde_json::from_str(json).map_err(|e| format!("report.json: {e}"))?;
    Ok(v.get("info")
        .and_then(serde_json::Value::as_object)
        .map(|o| {
            o.iter()
                .map(|(k, v)| {
                    let v = v.as_str().map_or_else(|| v.to_string(), str::to_string);
                    (k.clone(), v)
                })
                .collect()
        })
        .unwrap_or_default())
}

/// `table4.md` for `docs/results.md`: without the whole-run error of every single run (the
/// report folder keeps it), and with the link to the report's `identify.md` replaced by its
/// summary (each model's heading and its lines per level), which a link out of
/// `docs/results.md` could not reach.
fn with_identify_summary(table4: &str, identify: Option<&str>) -> String {
    const PER_RUN: &str = "Whole-run RMSE at the label per run";
    let mut out = String::new();
    let mut skipping = false;
    for line in table4.lines() {
        if line.starts_with(PER_RUN) {
            skipping = true;
            continue;
        }
        if line.contains("(identify.md)") {
            skipping = false;
            match identify {
                Some(id) => {
                    out += "Identifiability of the level (the report's `identify.md`: each run \
                            simulated whole at the levels of the grid its search visits; the \
                            best fit is the level of least force RMSE):\n\n";
                    for l in id.lines() {
                        if let Some(h) = l.strip_prefix("### ") {
                            let _ = writeln!(out, "- **{h}**");
                        } else if l.starts_with("- ") {
                            let _ = writeln!(out, "  {l}");
                        }
                    }
                }
                None => out += "The report has no `identify.md`.\n",
            }
            continue;
        }
        if !skipping {
            out += line;
            out.push('\n');
        }
    }
    out
}

/// The markdown of the training block.
fn training_markdown(
    command: &str,
    commit: &str,
    dir: &Path,
    info: &[(String, String)],
    table4: &str,
    table5: Option<&str>,
    degradation: Option<&str>,
) -> String {
    let mut md = format!(
        "Copied by `{command}` at commit `{commit}` from `{}`.\n\n",
        dir.join("table4.md").display()
    );
    let recorded = |k: &str| info.iter().find(|(key, _)| key == k).map(|(_, v)| v);
    match recorded("command") {
        Some(c) => {
            let _ = writeln!(md, "Trained by `{c}`.");
        }
        None => md += "The report does not record the command that trained it.\n",
    }
    match recorded("commit") {
        Some(c) => {
            let _ = writeln!(md, "Trained at commit `{c}`.");
        }
        None => md += "The report does not record the commit it was trained at.\n",
    }
    for (k, v) in info.iter().filter(|(k, _)| k != "command" && k != "commit") {
        let _ = writeln!(md, "- {k}: `{v}`");
    }
    let _ = writeln!(md, "\n{}", table4.trim_end());
    if let Some(t5) = table5 {
        let _ = writeln!(
            md,
            "\n**Table 5**: the `lambda_ph` sweep of the NEMM (the report folder's `table5.md`, \
             from `nemm sweep --report` into it; rows `penalty_*` train with the priors in \
             alpha imposed by the physics penalty alone).\n\n{}",
            t5.trim_end()
        );
    }
    if let Some(d) = degradation {
        let _ = writeln!(
            md,
            "\n**Where the NEMM puts the degradation**: the ablation of the report folder's \
             `degradation.md` (from `nemm sweep --grid degradation --report` into it: the \
             paper's NEMM, `b_fl` fixed in alpha, the lost-motion element, both).\n\n{}",
            d.trim_end()
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table3_block_names_the_engine_and_the_wall_time() {
        let manifest = serde_json::json!({
            "grid": "table3",
            "engine": "slurm",
            "slurm": {"partition": null, "account": null, "time": "0:20:00",
                      "cpus_per_task": 1, "throttle": 2},
            "submissions": [{"job_id": "7", "array": "0-107%2", "submitted_unix_s": 1000.0}],
        });
        let table = "Sweep of the NEMM trained at commit `abc1234` on `d`.\n\n| Job |\n";
        let md = sweep_markdown(
            "cargo xtask results --table3 t3",
            "abc1234",
            Path::new("t3"),
            &TABLE3,
            &manifest,
            Some(1000.0 + 3600.0),
            table,
        );
        assert!(md.starts_with("Copied by `cargo xtask results --table3 t3` at commit `abc1234` from `t3/table3.md`."), "{md}");
        assert!(md.contains("Run by the Slurm engine: job 7 (array 0-107%2); 1 CPU(s) per task, at most 2 task(s) at a time, time limit 0:20:00 per task."), "{md}");
        assert!(md.contains("last job's end: 60 min."), "{md}");
        assert!(md.ends_with("| Job |\n"), "{md}");
        // Table 3 has no heading of its own: the provenance, the engine, the table.
        assert_eq!(
            md,
            format!(
                "Copied by `cargo xtask results --table3 t3` at commit `abc1234` from \
                 `t3/table3.md`.\n\nRun by the Slurm engine: job 7 (array 0-107%2); 1 CPU(s) \
                 per task, at most 2 task(s) at a time, time limit 0:20:00 per task.\nWall time \
                 from the first submission to the last job's end: 60 min.\n\n{table}"
            )
        );
        let local = serde_json::json!({"engine": "local", "slurm": null, "submissions": []});
        let md = sweep_markdown("c", "x", Path::new("t3"), &TABLE3, &local, None, table);
        assert!(
            md.contains("Run by the local engine.") && !md.contains("Wall time"),
            "{md}"
        );
    }

    #[test]
    fn the_state_priors_block_says_what_it_ablates_before_the_engine() {
        let manifest = serde_json::json!({
            "grid": "state-priors",
            "engine": "slurm",
            "slurm": {"partition": null, "account": null, "time": "1:00:00",
                      "cpus_per_task": 2, "throttle": 4},
            "submissions": [{"job_id": "9", "array": "0-4%4", "submitted_unix_s": 500.0}],
        });
        let table = "Sweep of the NEMM trained at commit `abc1234` on `d`.\n\n| Job |\n";
        let md = sweep_markdown(
            "cargo xtask results --state-priors sp",
            "abc1234",
            Path::new("sp"),
            &STATE_PRIORS,
            &manifest,
            Some(500.0 + 1800.0),
            table,
        );
        let heading = STATE_PRIORS.heading.unwrap();
        assert_eq!(
            md,
            format!(
                "Copied by `cargo xtask results --state-priors sp` at commit `abc1234` from \
                 `sp/state-priors.md`.\n\n{heading}\n\nRun by the Slurm engine: job 9 (array \
                 0-4%4); 2 CPU(s) per task, at most 4 task(s) at a time, time limit 1:00:00 per \
                 task.\nWall time from the first submission to the last job's end: 30 min.\n\n\
                 {table}"
            )
        );
        for words in [
            "ablation of the priors in the state",
            "data the sweep ran on",
            "`--state-priors construction` (cumulative scalers: the flow and spring forces \
             rise with the state for every weight)",
            "`--state-priors penalty` (the paper's MLPs and physics penalty)",
            "each `lambda_ph`",
            "test RMSE, the violations and the training time",
        ] {
            assert!(heading.contains(words), "{words}: {heading}");
        }
        let local = serde_json::json!({"engine": "local", "slurm": null, "submissions": []});
        let md = sweep_markdown(
            "c",
            "x",
            Path::new("sp"),
            &STATE_PRIORS,
            &local,
            None,
            table,
        );
        assert!(
            md.contains(&format!("{heading}\n\nRun by the local engine.\n\n{table}")),
            "{md}"
        );
    }

    #[test]
    fn the_headline_is_the_summary_table_with_its_provenance() {
        let table4 = "| Model | RMSE |\n|---|---:|\n| NEMM | 0.0354 |\n\nTest set: oil loss 0.15.\n\nTest RMSE per held-out run [N]:\n\n| run |\n";
        let info = vec![
            ("command".to_string(), "nemm demo".to_string()),
            ("commit".to_string(), "abc1234".to_string()),
        ];
        let md = headline_markdown(&info, table4);
        assert!(md.starts_with("| Model | RMSE |"));
        assert!(md.contains("Test set: oil loss 0.15."));
        assert!(!md.contains("per held-out run"), "{md}");
        assert!(md.contains("Trained by `nemm demo` at commit `abc1234`"));
        assert!(md.ends_with("[docs/results.md](docs/results.md)."));
    }

    #[test]
    fn the_training_block_summarises_the_identifiability() {
        let table4 = "| Model |\n\nWhole-run RMSE at the label per level:\n\n| 0 |\n\n\
                      Whole-run RMSE at the label per run, by amplitude:\n\n| run |\n\n\
                      The best-fit level: [identify.md](identify.md).\n";
        let identify = "## Identifiability\n\n### NEMM (grid 0 to 0.3)\n\n| run |\n\n\
                        - oil loss 0.15 (test): 4 of 18 runs within 0.03 of the label\n";
        let md = with_identify_summary(table4, Some(identify));
        assert!(md.contains("per level:\n\n| 0 |\n"), "{md}");
        assert!(!md.contains("per run"), "{md}");
        assert!(!md.contains("(identify.md)"), "{md}");
        assert!(md.contains("- **NEMM (grid 0 to 0.3)**\n  - oil loss 0.15 (test): 4 of 18"));
        assert!(with_identify_summary(table4, None).contains("no `identify.md`"));
    }

    #[test]
    fn the_training_block_carries_the_reports_provenance() {
        let info = report_info(
            r#"{"test_alpha":0.15,"info":{"command":"nemm compare --data d","dataset":"d","total_seconds":"12.5"}}"#,
        )
        .unwrap();
        let block = |degradation| {
            training_markdown(
                "cargo xtask results --training runs/c",
                "abc1234",
                Path::new("runs/c"),
                &info,
                "| model | RMSE |\n",
                Some("| job |\n"),
                degradation,
            )
        };
        let md = block(None);
        assert!(md.starts_with(
            "Copied by `cargo xtask results --training runs/c` at commit `abc1234` from \
             `runs/c/table4.md`.\n"
        ));
        assert!(md.contains("Trained by `nemm compare --data d`."));
        assert!(md.contains("does not record the commit"));
        assert!(md.contains("- dataset: `d`\n- total_seconds: `12.5`\n"));
        assert!(md.contains("\n| model | RMSE |\n\n**Table 5**"), "{md}");
        assert!(md.ends_with("alone).\n\n| job |\n"), "{md}");
        assert!(report_info("{").is_err());
        assert!(report_info("{}").unwrap().is_empty());
        // The degradation ablation follows Table 5 when the folder has one.
        let md = block(Some("| paper_lph5 | no | yes |\n"));
        assert!(
            md.contains("| job |\n\n**Where the NEMM puts the degradation**")
                && md.ends_with("both).\n\n| paper_lph5 | no | yes |\n"),
            "{md}"
        );
    }
}
