//! The sweep's record on disk, which every engine writes and the collection reads: the job
//! list (`sweep-jobs.json`) with the Slurm settings and submissions it keeps, and each job's
//! state from the files it leaves (`report.json`, `exit`, `train.log`).

use super::{job_dir, Engine, SweepGrid, SweepJob};
use crate::report::tables::Report;
use anyhow::{Context, Result};
use nemm_dataset::atomic_file::write_atomic_bytes;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The sweep's job list in its report folder.
pub(crate) const SWEEP_MANIFEST_FILE: &str = "sweep-jobs.json";
/// A job's output (standard output and error of its `nemm train`) in its folder.
pub(crate) const TRAIN_LOG: &str = "train.log";
/// A job's exit status in its folder: the exit code or `signal N`, written atomically when
/// the job's process ends (absent while it runs, and after a kill that took the task's shell
/// with it).
pub(crate) const EXIT_FILE: &str = "exit";

/// A sweep as its report folder records it: what `--collect` and `--resume` read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct SweepManifest {
    /// The grid (names the table file).
    pub(crate) grid: SweepGrid,
    /// The engine the jobs were last run on.
    pub(crate) engine: Engine,
    /// Every job, in the order of the Slurm array's task indices.
    pub(crate) jobs: Vec<SweepJob>,
    /// The Slurm job script's settings, once one was written.
    #[serde(default)]
    pub(crate) slurm: Option<SlurmSettings>,
    /// Every Slurm submission of the sweep, oldest first.
    #[serde(default)]
    pub(crate) submissions: Vec<Submission>,
}

impl SweepManifest {
    /// Reads `<report>/sweep-jobs.json`.
    pub(crate) fn load(report: &Path) -> Result<Self> {
        let p = report.join(SWEEP_MANIFEST_FILE);
        let text = std::fs::read_to_string(&p).with_context(|| {
            format!(
                "cannot read {}: is {} a sweep's report folder (nemm sweep --report)?",
                p.display(),
                report.display()
            )
        })?;
        serde_json::from_str(&text).with_context(|| format!("corrupt {}", p.display()))
    }

    /// Writes `<report>/sweep-jobs.json` (atomically).
    pub(crate) fn save(&self, report: &Path) -> Result<()> {
        let p = report.join(SWEEP_MANIFEST_FILE);
        write_atomic_bytes(&p, serde_json::to_string_pretty(self)?.as_bytes())
            .with_context(|| format!("cannot write {}", p.display()))
    }
}

/// A job's state, from the files in its folder.
#[derive(Debug, Clone)]
pub(crate) enum JobState {
    /// Finished: its `report.json`.
    Done(Box<Report>),
    /// Ended without a report: its exit status and the last line of its log.
    Failed(String),
    /// No result and no exit status: waiting, running, killed with its task, or never run.
    Missing,
}

/// The state of job `id` of the sweep in `report`.
pub(crate) fn job_state(report: &Path, id: &str) -> Result<JobState> {
    let dir = job_dir(report, id);
    let p = dir.join("report.json");
    if let Ok(t) = std::fs::read_to_string(&p) {
        // A report that cannot be read is the job's failure, not the collection's.
        return Ok(match serde_json::from_str::<Report>(&t) {
            Ok(r) => JobState::Done(Box::new(r)),
            Err(e) => JobState::Failed(format!("a corrupt report ({}: {e})", p.display())),
        });
    }
    let Ok(exit) = std::fs::read_to_string(dir.join(EXIT_FILE)) else {
        return Ok(JobState::Missing);
    };
    let log = std::fs::read_to_string(dir.join(TRAIN_LOG)).unwrap_or_default();
    let last = log
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("")
        .trim();
    let mut short: String = last.chars().take(200).collect();
    if short.len() < last.len() {
        short.push_str("...");
    }
    Ok(JobState::Failed(format!("exit {}: {short}", exit.trim())))
}

/// Writes a job's `exit` file (atomically).
pub(crate) fn write_exit(dir: &Path, status: &str) -> Result<()> {
    write_atomic_bytes(&dir.join(EXIT_FILE), format!("{status}\n").as_bytes())
        .with_context(|| format!("cannot write {}", dir.join(EXIT_FILE).display()))
}

/// Removes a job's `exit` file (before it runs again).
pub(crate) fn clear_exit(dir: &Path) -> Result<()> {
    match std::fs::remove_file(dir.join(EXIT_FILE)) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("cannot remove {}", dir.join(EXIT_FILE).display()))
        }
        _ => Ok(()),
    }
}

/// The job script's settings, as the sweep's job list records them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct SlurmSettings {
    /// `--partition`, if any.
    pub(crate) partition: Option<String>,
    /// `--account`, if any.
    pub(crate) account: Option<String>,
    /// The time limit of each task (Slurm's format).
    pub(crate) time: String,
    /// CPUs per task.
    pub(crate) cpus_per_task: usize,
    /// Tasks at a time (the array's `%N`).
    pub(crate) throttle: usize,
}

/// One `sbatch` of the sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Submission {
    /// Slurm's job id of the array.
    pub(crate) job_id: String,
    /// The `--array` specification submitted (task indices and `%N`).
    pub(crate) array: String,
    /// When `sbatch` returned, in seconds since the epoch.
    pub(crate) submitted_unix_s: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_corrupt_report_is_the_jobs_failure_not_the_collections() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = job_dir(tmp.path(), "lph5");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("report.json"), "{\"variants\": {").unwrap();
        match job_state(tmp.path(), "lph5").unwrap() {
            JobState::Failed(why) => assert!(why.contains("corrupt"), "{why}"),
            other => panic!("expected a failure, got {other:?}"),
        }
        assert!(matches!(
            job_state(tmp.path(), "other").unwrap(),
            JobState::Missing
        ));
    }
}
