//! Host benchmarks: the criterion benches of nemm-core (`benches/step.rs`, with `libm` and with
//! `micromath`) and nemm-train (`benches/gradient.rs`) run on this machine, and their results
//! read back for the `host` block of `docs/results.md`.
//!
//! Each run ([`RUNS`]) writes criterion's results into a directory of its own under
//! `<target>/criterion-host/` (`CRITERION_HOME`), so that no result of an earlier or a
//! hand-started `cargo bench` is read; a complete set of runs leaves a stamp there
//! ([`Stamp`]: the commit, the command, the machine), from which `--no-run` writes the block
//! again without measuring.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One `cargo bench` invocation.
pub struct Run {
    /// The directory of its results under the host results directory.
    pub name: &'static str,
    /// The package and its bench target.
    pub package: &'static str,
    pub bench: &'static str,
    /// Feature arguments of `cargo bench`.
    pub features: &'static [&'static str],
    /// Criterion's filter (a regex on `group/function/value`), if not every benchmark.
    pub filter: Option<&'static str>,
}

/// What `cargo xtask results --host` runs: nemm-core's benches with its default features
/// (`libm`), its step groups again with `micromath`, and nemm-train's batch gradient.
pub const RUNS: [Run; 3] = [
    Run {
        name: "nemm-core-libm",
        package: "nemm-core",
        bench: "step",
        features: &[],
        filter: None,
    },
    Run {
        name: "nemm-core-micromath",
        package: "nemm-core",
        bench: "step",
        features: &["--no-default-features", "--features", "micromath"],
        filter: Some("^step/"),
    },
    Run {
        name: "nemm-train",
        package: "nemm-train",
        bench: "gradient",
        features: &[],
        filter: None,
    },
];

impl Run {
    /// The command line, as a user types it.
    pub fn command(&self) -> String {
        let mut c = format!("cargo bench -p {} --bench {}", self.package, self.bench);
        for f in self.features {
            c += " ";
            c += f;
        }
        if let Some(f) = self.filter {
            let _ = write!(c, " -- '{f}'");
        }
        c
    }
}

/// The directory of the host results: `<target>/criterion-host`.
pub fn results_dir(target: &Path) -> PathBuf {
    target.join("criterion-host")
}

/// The stamp file of a complete run, in the results directory.
const STAMP: &str = "stamp.txt";

/// One criterion result: criterion's `new/benchmark.json` and `new/estimates.json`.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// The benchmark group (`step/libm`, `decode`, ...).
    pub group: String,
    /// The function (the model kind in these benches).
    pub function: String,
    /// The parameter (`rk4`, `186B`, `1-thread`, ...).
    pub value: String,
    /// The bytes per iteration the bench declared as its throughput.
    pub bytes: Option<u64>,
    /// Mean time per iteration, criterion's point estimate \[ns\].
    pub mean_ns: f64,
}

/// Every result under `dir` (criterion's layout: `<group>/<function>/<value>/new/`), sorted by
/// group, function and value.
pub fn collect(dir: &Path) -> Result<Vec<Estimate>, String> {
    let mut out = Vec::new();
    collect_into(dir, &mut out)?;
    out.sort_by(|a, b| (&a.group, &a.function, &a.value).cmp(&(&b.group, &b.function, &b.value)));
    Ok(out)
}

fn collect_into(dir: &Path, out: &mut Vec<Estimate>) -> Result<(), String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries {
        let path = entry.map_err(|e| format!("{}: {e}", dir.display()))?.path();
        if !path.is_dir() {
            continue;
        }
        if path.file_name().is_some_and(|n| n == "new") && path.join("benchmark.json").is_file() {
            out.push(read_estimate(&path)?);
        } else {
            collect_into(&path, out)?;
        }
    }
    Ok(())
}

/// The result in one criterion `new/` directory.
fn read_estimate(new: &Path) -> Result<Estimate, String> {
    let read = |name: &str| -> Result<serde_json::Value, String> {
        let p = new.join(name);
        let text = std::fs::read_to_string(&p).map_err(|e| format!("{}: {e}", p.display()))?;
        serde_json::from_str(&text).map_err(|e| format!("{}: {e}", p.display()))
    };
    let id = read("benchmark.json")?;
    let est = read("estimates.json")?;
    let text = |k: &str| id.get(k).and_then(|v| v.as_str()).unwrap_or("").to_string();
    let group = text("group_id");
    if group.is_empty() {
        return Err(format!(
            "{}: no group_id",
            new.join("benchmark.json").display()
        ));
    }
    let mean_ns = est
        .pointer("/mean/point_estimate")
        .and_then(serde_json::Value::as_f64)
        .ok_or_else(|| {
            format!(
                "{}: no mean.point_estimate",
                new.join("estimates.json").display()
            )
        })?;
    Ok(Estimate {
        group,
        function: text("function_id"),
        value: text("value_str"),
        bytes: id.pointer("/throughput/Bytes").and_then(|v| v.as_u64()),
        mean_ns,
    })
}

/// The facts of a complete run, written next to its results.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Stamp {
    /// The commit measured (`+dirty` with uncommitted changes).
    pub commit: String,
    /// The command that ran the benches.
    pub command: String,
    /// The CPU model (`/proc/cpuinfo`'s `model name`).
    pub machine: String,
    /// Logical CPUs.
    pub cpus: usize,
    /// `rustc -V`.
    pub rustc: String,
    /// The 1-minute load average before and after the benches (`/proc/loadavg`).
    pub load_start: String,
    pub load_end: String,
}

impl Stamp {
    fn fields(&self) -> [(&'static str, String); 7] {
        [
            ("commit", self.commit.clone()),
            ("command", self.command.clone()),
            ("machine", self.machine.clone()),
            ("cpus", self.cpus.to_string()),
            ("rustc", self.rustc.clone()),
            ("load_start", self.load_start.clone()),
            ("load_end", self.load_end.clone()),
        ]
    }

    /// `key=value` lines.
    pub fn to_text(&self) -> String {
        self.fields()
            .iter()
            .map(|(k, v)| format!("{k}={v}\n"))
            .collect()
    }

    /// The stamp of [`Stamp::to_text`]; every key must be present.
    pub fn parse(text: &str) -> Result<Self, String> {
        let get = |key: &str| -> Result<String, String> {
            text.lines()
                .find_map(|l| l.strip_prefix(key)?.strip_prefix('='))
                .map(str::to_string)
                .ok_or_else(|| format!("no `{key}=` line"))
        };
        Ok(Self {
            commit: get("commit")?,
            command: get("command")?,
            machine: get("machine")?,
            cpus: get("cpus")?.parse().map_err(|e| format!("cpus: {e}"))?,
            rustc: get("rustc")?,
            load_start: get("load_start")?,
            load_end: get("load_end")?,
        })
    }

    /// The stamp of the last complete run in `dir`.
    pub fn read(dir: &Path) -> Result<Self, String> {
        let p = dir.join(STAMP);
        let text = std::fs::read_to_string(&p).map_err(|e| {
            format!(
                "{}: {e} (no complete `cargo xtask results --host` run to collect)",
                p.display()
            )
        })?;
        Self::parse(&text).map_err(|e| format!("{}: {e}", p.display()))
    }

    /// Writes the stamp into `dir`.
    pub fn write(&self, dir: &Path) -> Result<(), String> {
        let p = dir.join(STAMP);
        std::fs::write(&p, self.to_text()).map_err(|e| format!("{}: {e}", p.display()))
    }
}

/// The CPU model and the logical CPU count of this machine.
pub fn machine() -> (String, usize) {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = info
        .lines()
        .find_map(|l| {
            let (k, v) = l.split_once(':')?;
            (k.trim() == "model name").then(|| v.trim().to_string())
        })
        .unwrap_or_else(|| format!("unknown CPU ({})", std::env::consts::ARCH));
    let cpus = info
        .lines()
        .filter(|l| l.split(':').next().is_some_and(|k| k.trim() == "processor"))
        .count();
    let cpus = if cpus > 0 {
        cpus
    } else {
        std::thread::available_parallelism().map_or(0, usize::from)
    };
    (model, cpus)
}

/// The 1-minute load average (`/proc/loadavg`), `unknown` where there is none.
pub fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|t| t.split_whitespace().next().map(str::to_string))
        .unwrap_or_else(|| "unknown".into())
}

/// A time in ns with three significant figures and a unit (`7.20 ns`, `16.7 us`, `960 ms`).
pub fn format_ns(ns: f64) -> String {
    let (v, unit) = if ns < 1e3 {
        (ns, "ns")
    } else if ns < 1e6 {
        (ns / 1e3, "us")
    } else if ns < 1e9 {
        (ns / 1e6, "ms")
    } else {
        (ns / 1e9, "s")
    };
    let decimals = if v < 10.0 {
        2
    } else if v < 100.0 {
        1
    } else {
        0
    };
    format!("{v:.decimals$} {unit}")
}

/// Lookup of results by group, function and value.
struct Table<'a>(&'a [Estimate]);

impl Table<'_> {
    fn get(&self, group: &str, function: &str, value: &str) -> Option<&Estimate> {
        self.0
            .iter()
            .find(|e| e.group == group && e.function == function && e.value == value)
    }

    fn cell(&self, group: &str, function: &str, value: &str) -> String {
        self.get(group, function, value)
            .map_or("-".into(), |e| format_ns(e.mean_ns))
    }

    /// The functions of `group`, in `order` first (the model kinds of the paper's tables),
    /// then the rest by name.
    fn functions(&self, group: &str, order: &[&str]) -> Vec<String> {
        let mut fs: Vec<String> = Vec::new();
        for e in self.0.iter().filter(|e| e.group == group) {
            if !fs.contains(&e.function) {
                fs.push(e.function.clone());
            }
        }
        fs.sort_by_key(|f| {
            (
                order.iter().position(|o| o == f).unwrap_or(order.len()),
                f.clone(),
            )
        });
        fs
    }
}

/// The markdown of the `host` block: the run's facts, then a table per bench group.
/// `kinds`: the model kinds in the order of the paper's tables.
pub fn markdown(stamp: &Stamp, estimates: &[Estimate], kinds: &[&str]) -> String {
    let t = Table(estimates);
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Measured by `{}` at commit `{}` on {}, {} logical CPUs (`{}`; 1-minute load average {} \
         at the start, {} at the end). Each figure is criterion's mean time per iteration (its \
         point estimate); nemm-core's benches measure the benchmark thread's CPU time, so \
         other processes on the machine disturb them through the caches only, nemm-train's \
         measure wall time. Host figures say little about the Cortex-M4F: see the target \
         block above for instructions and cycles per step.\n",
        stamp.command,
        stamp.commit,
        stamp.machine,
        stamp.cpus,
        stamp.rustc,
        stamp.load_start,
        stamp.load_end
    );

    let _ = writeln!(
        md,
        "**Estimator step** (`{}` and `{}`, groups `step/<backend>` and \
         `step-table/libm`): one `Estimator::step` of the example models \
         (`testing::example_model(kind, 16, 5)`, alpha 0.15, step 1e-4 s) on a 5 Hz, 0.5 m/s \
         sinusoid; exact mode with `libm` (the default) and with `micromath`, table mode \
         (256 segments per table, bound 1e-4) with `libm`.\n",
        RUNS[0].command(),
        RUNS[1].command()
    );
    md += "| kind | exact RK4 | exact RK3 | table RK4 | table RK3 | exact RK4 (`micromath`) | \
           exact RK3 (`micromath`) |\n|---|---:|---:|---:|---:|---:|---:|\n";
    for kind in t.functions("step/libm", kinds) {
        let _ = writeln!(
            md,
            "| `{kind}` | {} | {} | {} | {} | {} | {} |",
            t.cell("step/libm", &kind, "rk4"),
            t.cell("step/libm", &kind, "rk3"),
            t.cell("step-table/libm", &kind, "rk4"),
            t.cell("step-table/libm", &kind, "rk3"),
            t.cell("step/micromath", &kind, "rk4"),
            t.cell("step/micromath", &kind, "rk3"),
        );
    }

    md += "\n**Alpha observer** (group `observer/libm`): one `AlphaObserver::step` of the \
           example NEMM (levels over the trained range, exact mode, RK4), on the same velocity \
           and the force of the model at alpha 0.15; the last column is the time over that of \
           one exact RK4 step of the same model.\n\n\
           | model | levels | step | exact RK4 steps |\n|---|---:|---:|---:|\n";
    for e in estimates.iter().filter(|e| e.group == "observer/libm") {
        let ratio = t
            .get("step/libm", &e.function, "rk4")
            .map_or("-".into(), |s| format!("{:.1}", e.mean_ns / s.mean_ns));
        let _ = writeln!(
            md,
            "| `{}` | {} | {} | {ratio} |",
            e.function,
            e.value,
            format_ns(e.mean_ns)
        );
    }

    md += "\n**Decode** (group `decode`, `libm` build): `decode` of the example models' blobs \
           into the default capacity (`DEFAULT_PARAM_CAPACITY`, a `Model` of about 110 KB), \
           and of the NEMM's into the capacity it needs.\n\n\
           | kind | blob (B) | capacity | decode |\n|---|---:|---|---:|\n";
    for kind in t.functions("decode", kinds) {
        let mut rows: Vec<&Estimate> = estimates
            .iter()
            .filter(|e| e.group == "decode" && e.function == kind)
            .collect();
        // The default capacity first.
        rows.sort_by_key(|e| e.value.starts_with("capacity-"));
        for e in rows {
            let capacity = e.value.strip_prefix("capacity-").unwrap_or("default");
            let _ = writeln!(
                md,
                "| `{kind}` | {} | {capacity} | {} |",
                e.bytes.map_or("-".into(), |b| b.to_string()),
                format_ns(e.mean_ns)
            );
        }
    }

    const GRADIENT: &str = "batch_gradient_16x5000";
    // Thread counts as the bench names them (`1-thread`, `2-thread`), in increasing order.
    let mut threads: Vec<&str> = Vec::new();
    for e in estimates.iter().filter(|e| e.group == GRADIENT) {
        if !threads.contains(&e.value.as_str()) {
            threads.push(&e.value);
        }
    }
    threads.sort_by_key(|v| {
        v.trim_end_matches("-thread")
            .parse::<u32>()
            .unwrap_or(u32::MAX)
    });
    let _ = write!(
        md,
        "\n**Training gradient** (`{}`, group `{GRADIENT}`, wall time): the loss and \
         gradient of one batch (16 windows of 5000 RK4 steps, the forward sweep and the \
         discrete adjoint) of the example models, on 1 thread and on all.\n\n| kind |",
        RUNS[2].command()
    );
    for th in &threads {
        let n = th.trim_end_matches("-thread");
        let plural = if n == "1" { "" } else { "s" };
        let _ = write!(md, " {n} thread{plural} |");
    }
    let _ = writeln!(md, "\n|---|{}", "---:|".repeat(threads.len()));
    for kind in t.functions(GRADIENT, kinds) {
        let _ = write!(md, "| `{kind}` |");
        for th in &threads {
            let _ = write!(md, " {} |", t.cell(GRADIENT, &kind, th));
        }
        md.push('\n');
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A temporary directory of its own, removed when dropped.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new(name: &str) -> Self {
            let p = std::env::temp_dir().join(format!("xtask-{name}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&p);
            std::fs::create_dir_all(&p).unwrap();
            Self(p)
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    /// Writes a criterion result as criterion does (`<dir>/<group dir>/<fn>/<value>/new/`).
    fn write_result(root: &Path, group_dir: &str, id: (&str, &str, &str), bytes: u64, ns: f64) {
        let (group, function, value) = id;
        let new = root.join(group_dir).join(function).join(value).join("new");
        std::fs::create_dir_all(&new).unwrap();
        let throughput = if bytes > 0 {
            format!(r#"{{"Bytes":{bytes}}}"#)
        } else {
            r#"{"Elements":1}"#.to_string()
        };
        std::fs::write(
            new.join("benchmark.json"),
            format!(
                r#"{{"group_id":"{group}","function_id":"{function}","value_str":"{value}","throughput":{throughput},"full_id":"{group}/{function}/{value}","directory_name":"{group_dir}/{function}/{value}","title":"{group}/{function}/{value}"}}"#
            ),
        )
        .unwrap();
        std::fs::write(
            new.join("estimates.json"),
            format!(
                r#"{{"mean":{{"confidence_interval":{{"confidence_level":0.95,"lower_bound":{lo},"upper_bound":{hi}}},"point_estimate":{ns},"standard_error":1.0}},"median":{{"point_estimate":1.0}},"slope":null}}"#,
                lo = ns * 0.99,
                hi = ns * 1.01
            ),
        )
        .unwrap();
        // Criterion keeps the previous run next to it; it must not be read.
        let before = new.with_file_name("before");
        std::fs::create_dir_all(&before).unwrap();
        std::fs::copy(new.join("benchmark.json"), before.join("benchmark.json")).unwrap();
    }

    #[test]
    fn criterion_results_become_the_host_tables() {
        let dir = TempDir::new("host-bench");
        let libm = dir.0.join("nemm-core-libm");
        let micro = dir.0.join("nemm-core-micromath");
        let train = dir.0.join("nemm-train");
        write_result(
            &libm,
            "step_libm",
            ("step/libm", "nemm", "rk4"),
            0,
            16_720.0,
        );
        write_result(
            &libm,
            "step_libm",
            ("step/libm", "nemm", "rk3"),
            0,
            12_560.4,
        );
        write_result(&libm, "step_libm", ("step/libm", "sem", "rk4"), 0, 7.2);
        write_result(&libm, "step_libm", ("step/libm", "sem", "rk3"), 0, 7.25);
        write_result(
            &libm,
            "step-table_libm",
            ("step-table/libm", "nemm", "rk4"),
            0,
            111.0,
        );
        write_result(
            &libm,
            "observer_libm",
            ("observer/libm", "nemm", "7"),
            0,
            118_000.0,
        );
        write_result(
            &libm,
            "decode",
            ("decode", "nemm", "15791B"),
            15791,
            69_300.0,
        );
        write_result(
            &libm,
            "decode",
            ("decode", "nemm", "capacity-1313"),
            15791,
            48_800.0,
        );
        write_result(
            &micro,
            "step_micromath",
            ("step/micromath", "nemm", "rk4"),
            0,
            21_340.0,
        );
        let gradient = "batch_gradient_16x5000";
        write_result(&train, gradient, (gradient, "nemm", "2-thread"), 0, 5.4e8);
        write_result(&train, gradient, (gradient, "nemm", "1-thread"), 0, 9.6e8);

        let mut est = Vec::new();
        for d in [&libm, &micro, &train] {
            est.extend(collect(d).unwrap());
        }
        assert_eq!(est.len(), 11, "{est:?}");
        assert_eq!(
            est.iter().find(|e| e.value == "capacity-1313").unwrap(),
            &Estimate {
                group: "decode".into(),
                function: "nemm".into(),
                value: "capacity-1313".into(),
                bytes: Some(15791),
                mean_ns: 48_800.0,
            }
        );
        let stamp = Stamp {
            commit: "abc1234+dirty".into(),
            command: "cargo xtask results --host".into(),
            machine: "AMD EPYC".into(),
            cpus: 2,
            rustc: "rustc 1.95.0".into(),
            load_start: "1.30".into(),
            load_end: "1.90".into(),
        };
        let kinds = ["sem", "linear-emm", "nemm-light", "nemm"];
        let md = markdown(&stamp, &est, &kinds);
        assert!(
            md.starts_with(
                "Measured by `cargo xtask results --host` at commit `abc1234+dirty` on AMD \
                 EPYC, 2 logical CPUs (`rustc 1.95.0`; 1-minute load average 1.30 at the start, \
                 1.90 at the end)."
            ),
            "{md}"
        );
        // Kinds in the paper's order; missing figures are `-`.
        let sem = md
            .find("| `sem` | 7.20 ns | 7.25 ns | - | - | - | - |\n")
            .unwrap();
        let nemm = md
            .find("| `nemm` | 16.7 us | 12.6 us | 111 ns | - | 21.3 us | - |\n")
            .unwrap();
        assert!(sem < nemm, "{md}");
        // 118 us over 16.72 us: 7.1 exact steps.
        assert!(md.contains("| `nemm` | 7 | 118 us | 7.1 |\n"), "{md}");
        assert!(md.contains(
            "| `nemm` | 15791 | default | 69.3 us |\n| `nemm` | 15791 | 1313 | 48.8 us |\n"
        ));
        assert!(md.contains("| kind | 1 thread | 2 threads |\n|---|---:|---:|\n"));
        assert!(md.contains("| `nemm` | 960 ms | 540 ms |\n"), "{md}");
        assert!(md.contains(
            "`cargo bench -p nemm-core --bench step --no-default-features --features \
             micromath -- '^step/'`"
        ));
    }

    #[test]
    fn a_stamp_reads_back_and_a_missing_one_is_an_error() {
        let dir = TempDir::new("host-stamp");
        assert!(Stamp::read(&dir.0).unwrap_err().contains("no complete"));
        let stamp = Stamp {
            commit: "abc1234".into(),
            command: "cargo xtask results --host".into(),
            machine: "Intel(R) Xeon(R) CPU @ 2.20GHz".into(),
            cpus: 2,
            rustc: "rustc 1.95.0 (59807616e 2026-04-14)".into(),
            load_start: "3.37".into(),
            load_end: "2.10".into(),
        };
        stamp.write(&dir.0).unwrap();
        assert_eq!(Stamp::read(&dir.0).unwrap(), stamp);
        assert!(Stamp::parse("commit=abc\n")
            .unwrap_err()
            .contains("command"));
    }

    #[test]
    fn times_keep_three_significant_figures() {
        assert_eq!(format_ns(7.2), "7.20 ns");
        assert_eq!(format_ns(42.04), "42.0 ns");
        assert_eq!(format_ns(101.4), "101 ns");
        assert_eq!(format_ns(8_540.0), "8.54 us");
        assert_eq!(format_ns(118_400.0), "118 us");
        assert_eq!(format_ns(2.4e6), "2.40 ms");
        assert_eq!(format_ns(1.02e9), "1.02 s");
    }
}
