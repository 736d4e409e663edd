//! `nemm sweep --engine slurm` on a real Slurm: a one-node cluster (Debian's `slurm-wlm` and
//! `munge`, started as root with its own `slurm.conf` under the temporary folder, or reused
//! when this test started it before and it still answers) runs a tiny Table 3 sweep through
//! `sbatch`; the collected table must equal the local engine's for the same seeds, a task
//! with a bad option must show as failed while the others are kept, and `--resume` must
//! submit only that one again.
//!
//! Ignored by a plain `cargo test` (it needs root and the packages); `cargo xtask test` runs
//! it. Where no cluster can be started it prints why and passes as skipped. Every wait is
//! bounded; the daemons it started are stopped when it ends.
//!
//! `overhead_of_the_slurm_engine` is the engine's benchmark (`cargo xtask bench-slurm`):
//! the same small sweep on both engines, printing submission, start and collection times.

mod support;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The cluster's folder: configuration, state, logs and pid files.
const CLUSTER_DIR: &str = "/tmp/nemm-slurm-test";

/// The base configuration's file: a short quasi-static regression (the default's 600 steps
/// would take most of a job's time here).
const BASE_CONFIG: &str = "[train]\nqs_steps = 20\n";

/// One epoch of two batches on short windows and small scalers: seconds per job.
const BUDGET: &[&str] = &[
    "--window-s",
    "0.1",
    "--warmup-s",
    "0.02",
    "--epochs",
    "1",
    "--max-batches",
    "2",
    "--linear-epochs",
    "1",
];

/// A Table 3 grid of one batch size, width and depth at `lrs`, lambda_ph 0.
fn grid(lrs: &str) -> Vec<String> {
    [
        "--grid",
        "table3",
        "--grid-batch",
        "4",
        "--grid-hidden",
        "8",
        "--grid-layers",
        "3",
        "--lambda-ph",
        "0",
        "--grid-lr",
        lrs,
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

/// Runs `cmd`, killing it after `timeout`; `Err` if it cannot start or times out.
fn run_for(cmd: &mut Command, timeout: Duration) -> Result<Output, String> {
    let what = format!("{cmd:?}");
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot run {what}: {e}"))?;
    let t = Instant::now();
    loop {
        match child.try_wait() {
            Ok(Some(_)) => return child.wait_with_output().map_err(|e| e.to_string()),
            Ok(None) if t.elapsed() < timeout => std::thread::sleep(Duration::from_millis(50)),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(format!("{what} did not finish within {timeout:?}"));
            }
        }
    }
}

/// A process's id from a pid file, if that process is alive (not a zombie: a daemon's
/// parent is init, which may not reap it in a container).
fn live_pid(pid_file: &Path) -> Option<u32> {
    let pid: u32 = std::fs::read_to_string(pid_file)
        .ok()?
        .trim()
        .parse()
        .ok()?;
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let state = stat.rsplit_once(") ")?.1.chars().next()?;
    (state != 'Z' && state != 'X').then_some(pid)
}

/// A one-node Slurm cluster; the daemons this value started are stopped when it drops.
struct Cluster {
    /// `SLURM_CONF` for every Slurm command.
    conf: PathBuf,
    /// Pid files of the daemons started here.
    started: Vec<PathBuf>,
}

impl Cluster {
    /// Starts the cluster (or reuses the one a previous run left), or says why it cannot.
    fn start() -> Result<Cluster, String> {
        for bin in [
            "/usr/sbin/slurmctld",
            "/usr/sbin/slurmd",
            "/usr/sbin/munged",
        ] {
            if !Path::new(bin).exists() {
                return Err(format!(
                    "{bin} is not installed (apt-get install slurm-wlm munge)"
                ));
            }
        }
        let uid = run_for(Command::new("id").arg("-u"), Duration::from_secs(5))?;
        if String::from_utf8_lossy(&uid.stdout).trim() != "0" {
            return Err("not root: the one-node cluster's daemons need root".into());
        }
        let dir = PathBuf::from(CLUSTER_DIR);
        for sub in ["state", "spool", "log"] {
            std::fs::create_dir_all(dir.join(sub)).map_err(|e| e.to_string())?;
        }
        let host = run_for(&mut Command::new("hostname"), Duration::from_secs(5))?;
        let host = String::from_utf8_lossy(&host.stdout).trim().to_string();
        let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
        let d = dir.display();
        let conf = dir.join("slurm.conf");
        let text = format!(
            "ClusterName=nemmtest\nSlurmctldHost={host}\nSlurmUser=root\nSlurmdUser=root\n\
             AuthType=auth/munge\nProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\n\
             SchedulerType=sched/backfill\nSelectType=select/cons_tres\n\
             SelectTypeParameters=CR_Core\nStateSaveLocation={d}/state\n\
             SlurmdSpoolDir={d}/spool\nSlurmctldPidFile={d}/slurmctld.pid\n\
             SlurmdPidFile={d}/slurmd.pid\nSlurmctldLogFile={d}/log/slurmctld.log\n\
             SlurmdLogFile={d}/log/slurmd.log\nReturnToService=2\n\
             NodeName={host} CPUs={cpus} State=UNKNOWN\n\
             PartitionName=debug Nodes={host} Default=YES MaxTime=INFINITE State=UP\n"
        );
        if std::fs::read_to_string(&conf).ok().as_deref() != Some(text.as_str()) {
            std::fs::write(&conf, &text).map_err(|e| e.to_string())?;
        }
        let mut cluster = Cluster {
            conf,
            started: Vec::new(),
        };
        cluster.start_munge()?;
        for (daemon, pid) in [("slurmctld", "slurmctld.pid"), ("slurmd", "slurmd.pid")] {
            let pid = dir.join(pid);
            if live_pid(&pid).is_none() {
                let out = run_for(
                    Command::new(format!("/usr/sbin/{daemon}")).env("SLURM_CONF", &cluster.conf),
                    Duration::from_secs(20),
                )?;
                if !out.status.success() {
                    return Err(format!(
                        "{daemon} did not start: {}",
                        String::from_utf8_lossy(&out.stderr).trim()
                    ));
                }
                cluster.started.push(pid);
            }
        }
        // The node idle within 30 s.
        let t = Instant::now();
        loop {
            let out = run_for(
                cluster.cmd("sinfo").args(["-h", "-o", "%T"]),
                Duration::from_secs(15),
            );
            let state = out
                .as_ref()
                .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
                .unwrap_or_default();
            if state == "idle" || state == "mixed" || state == "allocated" {
                return Ok(cluster);
            }
            if t.elapsed() > Duration::from_secs(30) {
                let log =
                    std::fs::read_to_string(dir.join("log/slurmctld.log")).unwrap_or_default();
                let tail: Vec<&str> = log.lines().rev().take(5).collect();
                return Err(format!(
                    "the node is not idle after 30 s (sinfo: {state:?}; slurmctld.log: {tail:?})"
                ));
            }
            std::thread::sleep(Duration::from_millis(300));
        }
    }

    /// munged with the machine's key (created if missing), unless one answers already.
    fn start_munge(&mut self) -> Result<(), String> {
        let pid = PathBuf::from("/run/munge/munged.pid");
        if live_pid(&pid).is_some() {
            return Ok(());
        }
        let key = Path::new("/etc/munge/munge.key");
        if !key.exists() {
            let mut bytes = vec![0u8; 1024];
            use std::io::Read;
            std::fs::File::open("/dev/urandom")
                .and_then(|mut f| f.read_exact(&mut bytes))
                .and_then(|_| std::fs::write(key, &bytes))
                .map_err(|e| format!("cannot create {}: {e}", key.display()))?;
        }
        for cmd in [
            vec!["chown", "munge:munge", "/etc/munge/munge.key"],
            vec!["chmod", "400", "/etc/munge/munge.key"],
            vec!["mkdir", "-p", "/run/munge"],
            vec!["chown", "munge:munge", "/run/munge"],
            vec!["/usr/sbin/munged", "--force"],
        ] {
            let out = run_for(
                Command::new(cmd[0]).args(&cmd[1..]),
                Duration::from_secs(20),
            )?;
            if !out.status.success() {
                return Err(format!(
                    "{cmd:?} failed: {}",
                    String::from_utf8_lossy(&out.stderr).trim()
                ));
            }
        }
        self.started.push(pid);
        Ok(())
    }

    /// A Slurm client command on this cluster.
    fn cmd(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    /// A `nemm` command line on this cluster.
    fn nemm<S: AsRef<OsStr>>(&self, args: &[S]) -> Command {
        let mut c = self.cmd(env!("CARGO_BIN_EXE_nemm"));
        c.args(args);
        c
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // slurmd and slurmctld first, munged last.
        for pid in self.started.iter().rev() {
            if let Some(p) = live_pid(pid) {
                let _ = Command::new("kill").arg(p.to_string()).status();
            }
        }
    }
}

/// The cluster, or `None` after printing why the test is skipped.
fn cluster_or_skip(test: &str) -> Option<Cluster> {
    match Cluster::start() {
        Ok(c) => Some(c),
        Err(why) => {
            // Straight to the process's stderr: the test harness captures `eprintln!` of a
            // passing test, and a skip must never be silent.
            use std::io::Write;
            let line = format!("SKIPPED {test}: no Slurm cluster here: {why}\n");
            let _ = std::io::stderr().write_all(line.as_bytes());
            None
        }
    }
}

/// One cluster user at a time in this test binary.
static CLUSTER: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Runs `cmd` (at most 2 minutes) and returns its standard output; fails the test with its
/// error output.
fn ok(cmd: &mut Command) -> String {
    let out = run_for(cmd, Duration::from_secs(120)).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        out.status.success(),
        "{cmd:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `nemm sweep` over `data` into `report` with the tiny budget ([`BASE_CONFIG`] next to
/// `data`, [`BUDGET`]) and `args`.
fn sweep_args(data: &Path, report: &Path, args: &[String]) -> Vec<String> {
    let base = data.with_file_name("base.toml");
    std::fs::write(&base, BASE_CONFIG).expect("write base.toml");
    let mut v: Vec<String> = vec!["sweep".into(), "--data".into(), data.display().to_string()];
    v.extend(["--config".into(), base.display().to_string()]);
    v.extend(["--report".into(), report.display().to_string()]);
    v.extend(BUDGET.iter().map(|s| s.to_string()));
    v.extend(args.iter().cloned());
    v
}

/// Waits (at most `timeout`) until every job folder of `report` has a result or an exit
/// status; panics with the queue otherwise.
fn wait_for_jobs(cluster: &Cluster, report: &Path, ids: &[&str], timeout: Duration) {
    let t = Instant::now();
    let ended = |id: &str| {
        let dir = report.join("jobs").join(id);
        dir.join("report.json").exists() || dir.join("exit").exists()
    };
    while !ids.iter().all(|id| ended(id)) {
        if t.elapsed() > timeout {
            let q = run_for(&mut cluster.cmd("squeue"), Duration::from_secs(15))
                .map(|o| String::from_utf8_lossy(&o.stdout).into_owned());
            panic!("the Slurm tasks did not end within {timeout:?}; squeue: {q:?}");
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// The table's provenance and rows without the training-time column, and its best lines:
/// what must not depend on the engine.
fn engine_independent(table: &str) -> Vec<String> {
    table
        .lines()
        .take_while(|l| !l.starts_with("Not in the table"))
        .filter(|l| !l.starts_with("Training time per configuration"))
        .map(|l| {
            if l.starts_with("| ") && l.ends_with(" s |") {
                let cut = l[..l.len() - 2].rfind('|').expect("a column");
                l[..cut].to_string()
            } else {
                l.to_string()
            }
        })
        .filter(|l| !l.is_empty())
        .collect()
}

#[test]
#[ignore = "needs root and slurm-wlm + munge; run by cargo xtask test"]
fn a_sweep_through_slurm_equals_the_local_one() {
    let _one = CLUSTER.lock().unwrap_or_else(|e| e.into_inner());
    let started = Instant::now();
    let Some(cluster) = cluster_or_skip("a_sweep_through_slurm_equals_the_local_one") else {
        return;
    };
    let cluster_s = started.elapsed().as_secs_f64();
    let tmp = tempfile::tempdir().expect("temp dir");
    let data = support::small_bench(tmp.path());
    let (good, bad) = (
        ["b4_h8_l3_lr0.01_lph0", "b4_h8_l3_lr0.005_lph0"],
        "b4_h8_l3_lr0.001_lph0",
    );

    // The local engine on the two good configurations.
    let local = tmp.path().join("local");
    let mut args = grid("0.01,0.005");
    args.extend(["--jobs".into(), "2".into()]);
    ok(&mut cluster.nemm(&sweep_args(&data, &local, &args)));
    let local_table = std::fs::read_to_string(local.join("table3.md")).expect("table3.md");

    // Slurm: the script first (--dry-run), the cost printed, nothing submitted.
    let slurm = tmp.path().join("slurm");
    let mut args = grid("0.01,0.005,0.001");
    args.extend(
        [
            "--engine",
            "slurm",
            "--jobs",
            "2",
            "--time",
            "5",
            "--cpus-per-task",
            "1",
            "--dry-run",
        ]
        .map(String::from),
    );
    let out = ok(&mut cluster.nemm(&sweep_args(&data, &slurm, &args)));
    assert!(
        out.contains("cost: 3 task(s) x 1 CPU(s) x at most 5 = at most "),
        "{out}"
    );
    let script = std::fs::read_to_string(slurm.join("slurm/sweep.sbatch")).expect("the script");
    for line in [
        "#SBATCH --array=0-2%2",
        "#SBATCH --time=5",
        "#SBATCH --cpus-per-task=1",
    ] {
        assert!(script.contains(line), "{line} missing:\n{script}");
    }
    let manifest = std::fs::read_to_string(slurm.join("sweep-jobs.json")).expect("job list");
    assert!(manifest.contains("\"submissions\": []"), "{manifest}");

    // A bad option in one job's configuration, then the submission.
    let config = slurm.join("jobs").join(bad).join("config.toml");
    let original = std::fs::read_to_string(&config).expect("config.toml");
    assert!(original.contains("[train]\n"), "{original}");
    std::fs::write(
        &config,
        original.replace("[train]\n", "[train]\nno_such_option = 1\n"),
    )
    .expect("write config.toml");
    let submit = Instant::now();
    let out = ok(&mut cluster.nemm(&["sweep", "--resume", &slurm.display().to_string()]));
    assert!(
        out.contains("submitted Slurm job ") && out.contains("array 0-2%2"),
        "{out}"
    );
    let mut all = good.to_vec();
    all.push(bad);
    wait_for_jobs(&cluster, &slurm, &all, Duration::from_secs(90));
    let slurm_s = submit.elapsed().as_secs_f64();

    // Collected: the good ones as the local engine has them, the bad one failed.
    let out = run_for(
        &mut cluster.nemm(&["sweep", "--collect", &slurm.display().to_string()]),
        Duration::from_secs(60),
    )
    .expect("collect");
    assert!(out.status.success(), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!("FAILED {bad} (exit 1: ")),
        "{stderr}"
    );
    assert!(stderr.contains("no_such_option"), "{stderr}");
    let table = std::fs::read_to_string(slurm.join("table3.md")).expect("table3.md");
    assert_eq!(
        engine_independent(&table),
        engine_independent(&local_table),
        "{table}\n---\n{local_table}"
    );
    assert!(
        table.contains(&format!("- `{bad}`: failed (exit 1: ")),
        "{table}"
    );
    assert!(
        table.contains("The paper's best (Table 3: batch 16, hidden 16, 5 layers, learning rate 0.005): not in this grid."),
        "{table}"
    );
    let sweep_json = std::fs::read_to_string(slurm.join("sweep.json")).expect("sweep.json");
    assert_eq!(
        sweep_json.matches("\"status\": \"done\"").count(),
        2,
        "{sweep_json}"
    );
    assert_eq!(
        sweep_json.matches("\"status\": \"failed\"").count(),
        1,
        "{sweep_json}"
    );

    // The option fixed, --resume submits the failed task alone; the others are kept.
    std::fs::write(&config, &original).expect("write config.toml");
    let kept = std::fs::metadata(slurm.join("jobs").join(good[0]).join("report.json"))
        .and_then(|m| m.modified())
        .expect("report.json");
    let out = ok(&mut cluster.nemm(&["sweep", "--resume", &slurm.display().to_string()]));
    assert!(
        out.contains("array 2%2") && out.contains("1 task(s)"),
        "{out}"
    );
    wait_for_jobs(&cluster, &slurm, &all, Duration::from_secs(60));
    let out = ok(&mut cluster.nemm(&["sweep", "--collect", &slurm.display().to_string()]));
    assert!(
        out.contains(&format!("| {bad} | 4 | 8 | 3 | 0.001 | 0 |")),
        "{out}"
    );
    assert!(!out.contains("Not in the table"), "{out}");
    let again = std::fs::metadata(slurm.join("jobs").join(good[0]).join("report.json"))
        .and_then(|m| m.modified())
        .expect("report.json");
    assert_eq!(kept, again, "a finished job ran again");
    eprintln!(
        "slurm test: cluster ready in {cluster_s:.1} s, the 3-task array ended {slurm_s:.1} s \
         after submission, {:.1} s in all",
        started.elapsed().as_secs_f64()
    );
}

/// Seconds since the epoch in a task's `start` file.
fn start_time(report: &Path, id: &str) -> f64 {
    let p = report.join("jobs").join(id).join("start");
    std::fs::read_to_string(&p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .trim()
        .parse()
        .expect("a time")
}

#[test]
#[ignore = "a benchmark (cargo xtask bench-slurm); needs root and slurm-wlm + munge"]
fn overhead_of_the_slurm_engine() {
    let _one = CLUSTER.lock().unwrap_or_else(|e| e.into_inner());
    let Some(cluster) = cluster_or_skip("overhead_of_the_slurm_engine") else {
        return;
    };
    let tasks: usize = std::env::var("NEMM_BENCH_TASKS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(4);
    let throttle = 2;
    let tmp = tempfile::tempdir().expect("temp dir");
    let data = support::small_bench(tmp.path());
    let lrs: Vec<String> = (1..=tasks)
        .map(|i| format!("{}", i as f64 * 1e-3))
        .collect();
    let mut args = grid(&lrs.join(","));
    args.extend(["--jobs".into(), throttle.to_string()]);

    let local = tmp.path().join("local");
    let t = Instant::now();
    ok(&mut cluster.nemm(&sweep_args(&data, &local, &args)));
    let local_s = t.elapsed().as_secs_f64();

    let slurm = tmp.path().join("slurm");
    args.extend(["--engine", "slurm", "--time", "10", "--cpus-per-task", "1"].map(String::from));
    let t = Instant::now();
    ok(&mut cluster.nemm(&sweep_args(&data, &slurm, &args)));
    let submit_s = t.elapsed().as_secs_f64();
    let manifest: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(slurm.join("sweep-jobs.json")).expect("job list"),
    )
    .expect("job list");
    let submitted = manifest["submissions"][0]["submitted_unix_s"]
        .as_f64()
        .expect("a submission");
    let ids: Vec<String> = manifest["jobs"]
        .as_array()
        .expect("jobs")
        .iter()
        .map(|j| j["id"].as_str().expect("id").to_string())
        .collect();
    let refs: Vec<&str> = ids.iter().map(String::as_str).collect();
    wait_for_jobs(&cluster, &slurm, &refs, Duration::from_secs(600));
    let slurm_s = t.elapsed().as_secs_f64();
    let starts: Vec<f64> = ids
        .iter()
        .map(|id| start_time(&slurm, id) - submitted)
        .collect();
    let t = Instant::now();
    ok(&mut cluster.nemm(&["sweep", "--collect", &slurm.display().to_string()]));
    let collect_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    ok(&mut cluster.nemm(&["sweep", "--collect", &local.display().to_string()]));
    let local_collect_s = t.elapsed().as_secs_f64();
    let waves = tasks.div_ceil(throttle);
    let first_wave: Vec<f64> = starts.iter().copied().take(throttle).collect();
    println!(
        "slurm-overhead tasks={tasks} throttle={throttle} local_wall_s={local_s:.2} \
         slurm_wall_s={slurm_s:.2} sbatch_submit_s={submit_s:.2} \
         first_wave_start_after_submit_s={:.2} task_starts_after_submit_s={:?} \
         extra_wall_per_wave_s={:.2} extra_wall_per_task_s={:.2} collect_s={collect_s:.3} \
         local_collect_s={local_collect_s:.3}",
        first_wave.iter().sum::<f64>() / first_wave.len() as f64,
        starts
            .iter()
            .map(|s| (s * 100.0).round() / 100.0)
            .collect::<Vec<_>>(),
        (slurm_s - local_s) / waves as f64,
        (slurm_s - local_s) / tasks as f64,
    );
}
