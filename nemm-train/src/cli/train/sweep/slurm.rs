//! The Slurm engine of `nemm sweep`: one job script per sweep (`<report>/slurm/sweep.sbatch`,
//! a job array with one task per job), submitted with `sbatch`.
//!
//! Task `i` trains job `i` of the sweep's job list from `<report>/jobs/ID/config.toml` with the
//! same `nemm train` command line as the local engine, on the report folder, which must be
//! on storage the nodes share (as must the `nemm` executable and the dataset). `nemm train`
//! writes `report.json` atomically and the task then its exit status (`exit`, by a rename),
//! so a task killed or preempted midway leaves no result, only what `--collect` lists as
//! missing and `--resume` submits again. Each task also records its start time (`start`,
//! seconds since the epoch) for the engine's overhead.

use super::collect::collect_sweep;
use super::record::{
    clear_exit, job_state, JobState, SlurmSettings, Submission, SweepManifest, EXIT_FILE, TRAIN_LOG,
};
use super::{job_dir, train_args, SweepGrid, SweepOptions};
use anyhow::{bail, Context, Result};
use nemm_dataset::atomic_file::write_atomic_bytes;
use std::path::Path;

/// The array's throttle (`%N`: tasks at a time) unless `--jobs` says otherwise.
pub(crate) const DEFAULT_THROTTLE: usize = 8;
/// The time limit of each task unless `--time` says otherwise.
pub(crate) const DEFAULT_TIME: &str = "1:00:00";
/// The CPUs of each task unless `--cpus-per-task` says otherwise.
pub(crate) const DEFAULT_CPUS: usize = 2;
/// The job script in the report folder.
pub(crate) const SCRIPT_FILE: &str = "slurm/sweep.sbatch";
/// A task's start time in its job folder (seconds since the epoch, written by the script).
pub(crate) const START_FILE: &str = "start";

/// The Slurm engine's options (`nemm sweep --engine slurm`); on `--resume`, those not given
/// keep the sweep's.
#[derive(Debug, Clone, Default, PartialEq, clap::Args)]
pub struct SlurmArgs {
    /// Slurm: the partition of the job array (`#SBATCH --partition`) [default: the cluster's].
    #[arg(long)]
    pub(crate) partition: Option<String>,
    /// Slurm: the account charged (`#SBATCH --account`) [default: the user's].
    #[arg(long)]
    pub(crate) account: Option<String>,
    /// Slurm: the time limit of each task, in Slurm's format (MM, MM:SS, HH:MM:SS, D-HH,
    /// D-HH:MM, D-HH:MM:SS); a task still training then is killed and shows as missing
    /// [default: 1:00:00].
    #[arg(long)]
    pub time: Option<String>,
    /// Slurm: the CPUs of each task (`#SBATCH --cpus-per-task`; the trainer's threads)
    /// [default: 2].
    #[arg(long)]
    pub(crate) cpus_per_task: Option<usize>,
}

impl SlurmSettings {
    /// The settings of `args` and `throttle` (`--jobs`), those not given from `previous`
    /// (the sweep's last), else the defaults; the time limit checked.
    pub(crate) fn resolve(
        args: &SlurmArgs,
        throttle: Option<usize>,
        previous: Option<&SlurmSettings>,
    ) -> Result<Self> {
        let s = SlurmSettings {
            partition: args
                .partition
                .clone()
                .or_else(|| previous.and_then(|p| p.partition.clone())),
            account: args
                .account
                .clone()
                .or_else(|| previous.and_then(|p| p.account.clone())),
            time: args
                .time
                .clone()
                .or_else(|| previous.map(|p| p.time.clone()))
                .unwrap_or_else(|| DEFAULT_TIME.into()),
            cpus_per_task: args
                .cpus_per_task
                .or(previous.map(|p| p.cpus_per_task))
                .unwrap_or(DEFAULT_CPUS),
            throttle: throttle
                .or(previous.map(|p| p.throttle))
                .unwrap_or(DEFAULT_THROTTLE),
        };
        parse_time(&s.time)?;
        if s.cpus_per_task == 0 || s.throttle == 0 {
            bail!("--cpus-per-task and --jobs must be at least 1");
        }
        for (name, v) in [("--partition", &s.partition), ("--account", &s.account)] {
            if let Some(v) = v {
                if v.is_empty() || v.chars().any(|c| c.is_whitespace() || c == '\'') {
                    bail!("{name} {v:?}: not a Slurm name");
                }
            }
        }
        Ok(s)
    }
}

/// A Slurm time limit in seconds: MM, MM:SS, HH:MM:SS, D-HH, D-HH:MM or D-HH:MM:SS (Slurm's
/// formats; a budget is needed, so no `UNLIMITED`).
pub(crate) fn parse_time(s: &str) -> Result<u64> {
    let bad =
        || anyhow::anyhow!("--time {s:?}: give MM, MM:SS, HH:MM:SS, D-HH, D-HH:MM or D-HH:MM:SS");
    let num = |p: &str| -> Result<u64> {
        if p.is_empty() || !p.bytes().all(|b| b.is_ascii_digit()) {
            return Err(bad());
        }
        p.parse().map_err(|_| bad())
    };
    let (days, rest) = match s.split_once('-') {
        Some((d, r)) => (Some(num(d)?), r),
        None => (None, s),
    };
    let parts = rest.split(':').map(num).collect::<Result<Vec<u64>>>()?;
    let secs = match (days, parts.as_slice()) {
        (None, [m]) => m * 60,
        (None, [m, s]) => m * 60 + s,
        (None, [h, m, s]) => h * 3600 + m * 60 + s,
        (Some(d), [h]) => d * 86400 + h * 3600,
        (Some(d), [h, m]) => d * 86400 + h * 3600 + m * 60,
        (Some(d), [h, m, s]) => d * 86400 + h * 3600 + m * 60 + s,
        _ => return Err(bad()),
    };
    if secs == 0 {
        return Err(bad());
    }
    Ok(secs)
}

/// The `--array` specification of task `indices` (ascending), runs of consecutive ones as
/// ranges, with the `%throttle`: e.g. `0-3,7,9-10%2`.
pub(crate) fn array_spec(indices: &[usize], throttle: usize) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < indices.len() {
        let mut j = i;
        while j + 1 < indices.len() && indices[j + 1] == indices[j] + 1 {
            j += 1;
        }
        parts.push(if j > i {
            format!("{}-{}", indices[i], indices[j])
        } else {
            indices[i].to_string()
        });
        i = j + 1;
    }
    format!("{}%{throttle}", parts.join(","))
}

/// `s` as one single-quoted shell word.
fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// The job script of a sweep whose job ids are `ids` (task `i` trains `ids[i]`), its report
/// folder `report` and working folder `workdir` (both absolute), run by `exe`.
pub(crate) fn job_script(
    settings: &SlurmSettings,
    grid: SweepGrid,
    report: &Path,
    workdir: &Path,
    exe: &Path,
    ids: &[String],
) -> Result<String> {
    for (what, p) in [("report folder", report), ("working folder", workdir)] {
        let s = p.to_str().context("a path that is not UTF-8")?;
        if s.chars().any(char::is_whitespace) {
            bail!("the Slurm engine needs a {what} without spaces: {s:?}");
        }
    }
    let r = report.display();
    let mut s = format!(
        "#!/bin/bash\n\
         # The jobs of the nemm sweep in {r} as a Slurm job array (written by `nemm sweep\n\
         # --engine slurm`). Task i trains job ids[i] from {r}/jobs/ID/config.toml: output in\n\
         # train.log there, the result in report.json (written atomically by nemm train), the\n\
         # exit status in exit (by a rename). `nemm sweep --collect {r}` builds the table of\n\
         # what finished; `nemm sweep --resume {r}` submits what failed or is missing again.\n\
         #SBATCH --job-name=nemm-sweep\n\
         #SBATCH --array={}\n\
         #SBATCH --ntasks=1\n\
         #SBATCH --cpus-per-task={}\n\
         #SBATCH --time={}\n\
         #SBATCH --chdir={}\n\
         #SBATCH --output={r}/slurm/%A_%a.out\n",
        array_spec(&(0..ids.len()).collect::<Vec<_>>(), settings.throttle),
        settings.cpus_per_task,
        settings.time,
        workdir.display(),
    );
    if let Some(p) = &settings.partition {
        s += &format!("#SBATCH --partition={p}\n");
    }
    if let Some(a) = &settings.account {
        s += &format!("#SBATCH --account={a}\n");
    }
    let quoted: Vec<String> = ids.iter().map(|i| sh_quote(i)).collect();
    let train: Vec<String> = train_args("$dir", grid)
        .iter()
        .map(|a| format!("\"{a}\""))
        .collect();
    s += &format!(
        "set -u\n\
         ids=({})\n\
         id=${{ids[$SLURM_ARRAY_TASK_ID]}}\n\
         dir={}/jobs/$id\n\
         rm -f \"$dir/{EXIT_FILE}\"\n\
         date +%s.%N > \"$dir/.{START_FILE}.$SLURM_JOB_ID\" && mv -f \"$dir/.{START_FILE}.$SLURM_JOB_ID\" \"$dir/{START_FILE}\"\n\
         export RAYON_NUM_THREADS=\"${{SLURM_CPUS_PER_TASK:-{}}}\"\n\
         {} {} > \"$dir/{TRAIN_LOG}\" 2>&1\n\
         rc=$?\n\
         echo \"$rc\" > \"$dir/.{EXIT_FILE}.$SLURM_JOB_ID\" && mv -f \"$dir/.{EXIT_FILE}.$SLURM_JOB_ID\" \"$dir/{EXIT_FILE}\"\n\
         exit \"$rc\"\n",
        quoted.join(" "),
        sh_quote(&report.display().to_string()),
        settings.cpus_per_task,
        sh_quote(&exe.display().to_string()),
        train.join(" "),
    );
    Ok(s)
}

/// Hours and minutes of `secs`, e.g. `2 h 05 min`.
fn hm(secs: f64) -> String {
    let m = (secs / 60.0).ceil() as u64;
    format!("{} h {:02} min", m / 60, m % 60)
}

/// The cost of `tasks` tasks at `settings` before they are submitted: the bound of the
/// allocation (tasks x CPUs x time limit, and the wall time at the throttle) and, with
/// `measured` (the mean training seconds of the sweep's finished jobs and their count), the
/// expected cost at that mean.
pub(crate) fn cost_estimate(
    tasks: usize,
    settings: &SlurmSettings,
    measured: Option<(f64, usize)>,
) -> Result<String> {
    let limit = parse_time(&settings.time)? as f64;
    let (n, cpus, at) = (
        tasks as f64,
        settings.cpus_per_task as f64,
        settings.throttle,
    );
    let waves = tasks.div_ceil(at) as f64;
    let mut s = format!(
        "cost: {tasks} task(s) x {} CPU(s) x at most {} = at most {:.1} CPU-hours; {at} at a \
         time: at most {} of wall time (plus the queue)",
        settings.cpus_per_task,
        settings.time,
        n * cpus * limit / 3600.0,
        hm(waves * limit),
    );
    if let Some((mean, count)) = measured {
        s += &format!(
            "\nexpected at the mean training time of the {count} finished job(s), {mean:.0} s: \
             {:.1} CPU-hours, {} of wall time",
            n * cpus * mean / 3600.0,
            hm(waves * mean)
        );
    }
    Ok(s)
}

/// The jobs of `manifest` (indices into its job list) that Slurm still has queued or running
/// under one of the sweep's submissions, by `squeue`; none where `squeue` cannot say.
pub(crate) fn queued_jobs(manifest: &SweepManifest) -> Vec<usize> {
    if manifest.submissions.is_empty() {
        return Vec::new();
    }
    let ids: Vec<&str> = manifest
        .submissions
        .iter()
        .map(|s| s.job_id.as_str())
        .collect();
    let Ok(out) = std::process::Command::new("squeue")
        .args(["--noheader", "--array", "--format=%i", "--jobs"])
        .arg(ids.join(","))
        .output()
    else {
        return Vec::new();
    };
    let mut queued: Vec<usize> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.trim().rsplit_once('_')?.1.parse().ok())
        .filter(|&i| i < manifest.jobs.len())
        .collect();
    queued.sort_unstable();
    queued.dedup();
    queued
}

/// The Slurm engine: writes the job script, prints the cost, and (unless `--dry-run`)
/// submits the `pending` jobs (indices into the job list) as one job array, records the
/// submission in the job list and returns.
pub(super) fn submit_sweep(
    mut manifest: SweepManifest,
    pending: &[usize],
    report: &Path,
    options: &SweepOptions,
) -> Result<()> {
    let pending_given = pending.len();
    let settings = SlurmSettings::resolve(&options.slurm, options.jobs, manifest.slurm.as_ref())?;
    // Tasks still queued or running (with no result yet) are not submitted twice.
    let queued = queued_jobs(&manifest);
    let pending: Vec<usize> = pending
        .iter()
        .copied()
        .filter(|i| {
            !queued.contains(i)
                || !matches!(
                    job_state(report, &manifest.jobs[*i].id),
                    Ok(JobState::Missing)
                )
        })
        .collect();
    if pending.len() < pending_given {
        eprintln!(
            "[sweep] {} job(s) still queued or running in Slurm: not submitted again",
            pending_given - pending.len()
        );
    }
    let pending = &pending[..];
    manifest.slurm = Some(settings.clone());
    manifest.save(report)?;
    if pending.is_empty() {
        eprintln!("[sweep] nothing to submit");
        let c = collect_sweep(&manifest, report)?;
        c.print(report, manifest.grid);
        return Ok(());
    }
    let report_abs = std::fs::canonicalize(report)
        .with_context(|| format!("cannot find {}", report.display()))?;
    let workdir = std::env::current_dir().context("no working folder")?;
    let exe = std::env::current_exe().context("cannot find the nemm executable")?;
    let ids: Vec<String> = manifest.jobs.iter().map(|j| j.id.clone()).collect();
    let script = report.join(SCRIPT_FILE);
    write_atomic_bytes(
        &script,
        job_script(&settings, manifest.grid, &report_abs, &workdir, &exe, &ids)?.as_bytes(),
    )
    .with_context(|| format!("cannot write {}", script.display()))?;
    let mut secs = Vec::new();
    for j in &manifest.jobs {
        if let JobState::Done(r) = job_state(report, &j.id)? {
            secs.extend(r.variants.get("nemm").map(|v| v.train_seconds));
        }
    }
    let measured =
        (!secs.is_empty()).then(|| (secs.iter().sum::<f64>() / secs.len() as f64, secs.len()));
    println!("{}", cost_estimate(pending.len(), &settings, measured)?);
    let array = array_spec(pending, settings.throttle);
    if options.dry_run {
        println!(
            "dry run: wrote {}; submit with `nemm sweep --resume {} --engine slurm` (or `sbatch --array={array} {}`)",
            script.display(),
            report.display(),
            script.display()
        );
        return Ok(());
    }
    for &i in pending {
        clear_exit(&job_dir(report, &manifest.jobs[i].id))?;
    }
    let out = std::process::Command::new("sbatch")
        .arg("--parsable")
        .arg(format!("--array={array}"))
        .arg(&script)
        .output()
        .context("cannot run sbatch: is Slurm installed here (a login node)?")?;
    if !out.status.success() {
        bail!(
            "sbatch --array={array} {} failed ({}): {}",
            script.display(),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let job_id = stdout
        .lines()
        .last()
        .and_then(|l| l.trim().split(';').next())
        .filter(|id| !id.is_empty())
        .with_context(|| format!("sbatch printed no job id: {stdout:?}"))?
        .to_string();
    let submitted_unix_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64());
    manifest.submissions.push(Submission {
        job_id: job_id.clone(),
        array: array.clone(),
        submitted_unix_s,
    });
    manifest.save(report)?;
    println!(
        "submitted Slurm job {job_id}: {} task(s), array {array}; `squeue -j {job_id}` shows them, \
         `nemm sweep --collect {}` builds the table of what finished",
        pending.len(),
        report.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::{sweep_jobs, Table3Args, Table3Point, TABLE3_PAPER_BEST};
    use super::*;
    use crate::config::Config;

    #[test]
    fn reads_slurm_time_limits() {
        for (s, secs) in [
            ("5", 300),
            ("5:30", 330),
            ("1:00:00", 3600),
            ("2-3", 2 * 86400 + 3 * 3600),
            ("1-0:30", 86400 + 1800),
            ("1-00:00:10", 86410),
        ] {
            assert_eq!(parse_time(s).unwrap(), secs, "{s}");
        }
        for s in [
            "",
            "0",
            "UNLIMITED",
            "1:2:3:4",
            "-5",
            "1-",
            "a:b",
            "1-2:3:4:5",
        ] {
            assert!(parse_time(s).is_err(), "{s}");
        }
    }

    #[test]
    fn arrays_are_ranges_with_the_throttle() {
        assert_eq!(array_spec(&[0, 1, 2, 3], 8), "0-3%8");
        assert_eq!(array_spec(&[0, 1, 2, 5, 7, 8], 2), "0-2,5,7-8%2");
        assert_eq!(array_spec(&[4], 1), "4%1");
    }

    #[test]
    fn the_script_names_every_job_and_the_requests() {
        let s = SlurmSettings::resolve(
            &SlurmArgs {
                partition: Some("compute".into()),
                account: Some("dyno".into()),
                time: Some("0:15:00".into()),
                cpus_per_task: Some(4),
            },
            Some(16),
            None,
        )
        .unwrap();
        let ids = ["a_lph0".to_string(), "b_lph0".to_string()];
        let script = job_script(
            &s,
            SweepGrid::Table3,
            Path::new("/shared/t3"),
            Path::new("/shared"),
            Path::new("/shared/bin/nemm"),
            &ids,
        )
        .unwrap();
        for line in [
            "#SBATCH --array=0-1%16\n",
            "#SBATCH --cpus-per-task=4\n",
            "#SBATCH --time=0:15:00\n",
            "#SBATCH --partition=compute\n",
            "#SBATCH --account=dyno\n",
            "#SBATCH --chdir=/shared\n",
            "ids=('a_lph0' 'b_lph0')\n",
            "'/shared/bin/nemm' \"train\" \"--config\" \"$dir/config.toml\"",
            // Table 3 does not show the degradation: its jobs do not identify.
            "\"--report\" \"$dir\" \"--degradation-report=false\"",
        ] {
            assert!(script.contains(line), "{line} missing:\n{script}");
        }
        // On --resume, what is not given again is the sweep's.
        let again = SlurmSettings::resolve(&SlurmArgs::default(), None, Some(&s)).unwrap();
        assert_eq!(again, s);
        let cost = cost_estimate(108, &s, None).unwrap();
        assert!(
            cost.starts_with("cost: 108 task(s) x 4 CPU(s) x at most 0:15:00 = at most 108.0 CPU-hours; 16 at a time: at most 1 h 45 min"),
            "{cost}"
        );
        assert!(job_script(
            &s,
            SweepGrid::Table3,
            Path::new("/my report"),
            Path::new("/"),
            Path::new("/n"),
            &ids
        )
        .is_err());
    }

    #[test]
    fn the_table3_grid_is_the_papers() {
        let jobs = sweep_jobs(
            &Config::default(),
            SweepGrid::Table3,
            &Table3Args::default(),
            &[15.0],
        );
        assert_eq!(jobs.len(), 108);
        assert!(jobs
            .iter()
            .any(|j| Table3Point::of(&j.config) == TABLE3_PAPER_BEST
                && j.id == "b16_h16_l5_lr0.005_lph15"));
    }
}
