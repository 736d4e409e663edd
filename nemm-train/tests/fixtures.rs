//! The committed fixtures (`nemm-train/tests/fixtures/`, see its README): they equal what
//! `nemm bench fixtures` generates, `nemm data check` loads each interchange fixture, and
//! bench plots and the SEM support points work on them.
use nemm_dataset as dataset;
use nemm_train::data::preprocess::{self, Direction, PrepareConfig, SignalConfig};
use nemm_train::data::support_points::periodicity;
use nemm_train::train::pipeline::PipelineConfig;
use nemm_virtual_bench::fixtures::{fixtures, write_fixtures};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn fixture_dir(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// Every file under `dir`, relative path -> content.
fn files(dir: &Path) -> BTreeMap<PathBuf, String> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, String>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_path_buf();
                out.insert(rel, std::fs::read_to_string(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// A copy of fixture `name` in a temporary folder (`data/` inside it), the file whose path
/// ends with `edited` passed through `edit`.
fn fixture_copy(
    name: &str,
    edited: &str,
    edit: impl Fn(String) -> String,
) -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    for (rel, text) in files(&fixture_dir(name)) {
        let path = data.join(&rel);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        let text = if rel.ends_with(edited) {
            edit(text)
        } else {
            text
        };
        std::fs::write(path, text).unwrap();
    }
    (tmp, data)
}

/// Decimals printed in a cell (`-12.34` -> 2).
fn decimals(cell: &str) -> i32 {
    cell.split_once('.').map_or(0, |(_, d)| d.len() as i32)
}

/// Compares two CSV texts cell by cell: equal text, or numbers at most one unit of the last
/// printed decimal of the committed cell apart (the simulation's transcendental functions may
/// round differently in the last bit on another platform).
fn same_csv(committed: &str, generated: &str) -> Result<(), String> {
    let (a, b): (Vec<&str>, Vec<&str>) = (committed.lines().collect(), generated.lines().collect());
    if a.len() != b.len() {
        return Err(format!("{} lines, generated {}", a.len(), b.len()));
    }
    for (i, (la, lb)) in a.iter().zip(&b).enumerate() {
        if la == lb {
            continue;
        }
        let (ca, cb): (Vec<&str>, Vec<&str>) = (la.split(',').collect(), lb.split(',').collect());
        if ca.len() != cb.len() {
            return Err(format!("line {}: {la:?} vs {lb:?}", i + 1));
        }
        for (x, y) in ca.iter().zip(&cb) {
            if x == y {
                continue;
            }
            let (Ok(u), Ok(v)) = (x.trim().parse::<f64>(), y.trim().parse::<f64>()) else {
                return Err(format!("line {}: {la:?} vs {lb:?}", i + 1));
            };
            let lsb = 10f64.powi(-decimals(x).max(decimals(y)));
            if (u - v).abs() > 1.000_001 * lsb {
                return Err(format!("line {}: {la:?} vs {lb:?}", i + 1));
            }
        }
    }
    Ok(())
}

#[test]
fn committed_fixtures_equal_the_generated_ones() {
    let tmp = tempfile::tempdir().unwrap();
    write_fixtures(tmp.path()).unwrap();
    let regenerate = "regenerate with `nemm bench fixtures --out nemm-train/tests/fixtures`";
    for f in fixtures() {
        let (committed, generated) = (files(&fixture_dir(f.name)), files(&tmp.path().join(f.name)));
        assert_eq!(
            committed.keys().collect::<Vec<_>>(),
            generated.keys().collect::<Vec<_>>(),
            "fixture {}: other files than generated; {regenerate}",
            f.name
        );
        for (path, text) in &committed {
            let gen = &generated[path];
            let ok = if path.extension().is_some_and(|e| e == "csv") {
                same_csv(text, gen)
            } else if text == gen {
                Ok(())
            } else {
                Err("differs".to_string())
            };
            if let Err(e) = ok {
                panic!("fixture {}/{}: {e}; {regenerate}", f.name, path.display());
            }
        }
        let bytes: usize = committed.values().map(String::len).sum();
        assert!(bytes < 160_000, "fixture {} is {bytes} bytes", f.name);
    }
}

/// `nemm ARGS DIR`: success, and stdout and stderr.
fn nemm_in(dir: &Path, args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(args)
        .arg(dir)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// `nemm ARGS` on a fixture (its folder last).
fn nemm_on(name: &str, args: &[&str]) -> (bool, String) {
    nemm_in(&fixture_dir(name), args)
}

/// `nemm data check DIR --cutoff-hz fs/6` (a cut-off every fixture's rate allows).
fn data_check(name: &str) -> String {
    let fs = dataset::read_manifest(&fixture_dir(name))
        .unwrap()
        .sample_rate_hz;
    let cutoff = format!("{}", fs / 6.0);
    let (ok, text) = nemm_on(name, &["data", "check", "--cutoff-hz", &cutoff]);
    assert!(ok, "nemm data check {name}: {text}");
    text
}

#[test]
fn data_check_loads_rate_300hz() {
    let text = data_check("rate_300hz");
    assert!(text.contains("loaded 4 runs"), "{text}");
}

#[test]
fn data_check_loads_offsets_300hz() {
    let text = data_check("offsets_300hz");
    assert!(text.contains("loaded 3 runs"), "{text}");
}

#[test]
fn data_check_loads_alpha_schedule_1khz() {
    let text = data_check("alpha_schedule_1khz");
    assert!(text.contains("loaded 2 runs"), "{text}");
    // Random excitation is not periodic: no 2 pi f A check.
    assert!(!text.contains("velocity inconsistent"), "{text}");
    let ds = dataset::load(&fixture_dir("alpha_schedule_1khz")).unwrap();
    for run in &ds.runs {
        let a = run.alpha.as_ref().expect("alpha column");
        assert_eq!(a.len(), run.len());
        assert_eq!(a[0], run.entry.oil_loss);
        let changes = a.windows(2).filter(|w| w[0] != w[1]).count();
        assert!(changes >= 2, "{} changes of alpha", changes);
        assert!(a.iter().all(|&x| x == 0.0 || x == 0.3));
    }
}

/// Rounded time stamps (3 kHz, 0.1 ms: steps of 0.3 and 0.4 ms) load: the loader fits the
/// uniform grid and says so.
#[test]
fn data_check_loads_random_3khz_rounded() {
    let text = data_check("random_3khz_rounded");
    assert!(text.contains("loaded 2 runs"), "{text}");
    assert!(text.contains("time stamps rounded/jittered"), "{text}");
}

#[test]
fn raw_dyno_fixture_has_the_documented_layout() {
    let dir = fixture_dir("raw_dyno");
    let index = std::fs::read_to_string(dir.join("levels.txt")).unwrap();
    let mut runs = 0;
    for line in index.lines().filter(|l| !l.starts_with('#')) {
        let cells: Vec<&str> = line.split(", ").collect();
        assert_eq!(cells.len(), 5, "{line}");
        let text = std::fs::read_to_string(dir.join(cells[0])).unwrap();
        let rows: Vec<&str> = text.lines().collect();
        assert_eq!(rows[0], "Time [ms],Position [mm],Force [lbf]");
        let (first, last): (usize, usize) = (cells[3].parse().unwrap(), cells[4].parse().unwrap());
        assert!(first >= 2 && last <= rows.len() && first < last, "{line}");
        // Time continues across the runs of a record at 300 Hz.
        let t = |l: usize| -> f64 { rows[l - 1].split(',').next().unwrap().parse().unwrap() };
        assert!((t(last) - t(first) - (last - first) as f64 * 1e3 / 300.0).abs() < 2e-3);
        runs += 1;
    }
    assert_eq!(runs, 4);
    // Compression positive: the slow run's force is positive where the position falls.
    let text = std::fs::read_to_string(dir.join("level_00.csv")).unwrap();
    let rows: Vec<(f64, f64)> = text
        .lines()
        .skip(1)
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (c[1], c[2])
        })
        .collect();
    let (mut falling, mut rising) = (0.0, 0.0);
    for w in rows.windows(2).skip(200).take(1000) {
        let dx = w[1].0 - w[0].0;
        if dx < -0.05 {
            falling += w[1].1;
        } else if dx > 0.05 {
            rising += w[1].1;
        }
    }
    assert!(falling > 0.0 && rising < 0.0, "{falling} {rising}");
}

#[test]
fn periodicity_follows_the_documented_rule_on_the_fixtures() {
    for (name, periodic) in [
        ("rate_300hz", true),
        ("offsets_300hz", true),
        ("alpha_schedule_1khz", false),
    ] {
        let ds = dataset::load(&fixture_dir(name)).unwrap();
        for run in &ds.runs {
            let mut stripped = run.clone();
            stripped.entry.amplitude_m = None;
            stripped.entry.target_velocity_m_s = None;
            let p = periodicity(&stripped, &run.displacement_m, ds.sample_rate_hz);
            assert_eq!(p.is_some(), periodic, "{name} {}", run.entry.file.display());
            if let (Some(p), Some(a), Some(v)) =
                (p, run.entry.amplitude_m, run.entry.target_velocity_m_s)
            {
                let f = v / (2.0 * std::f64::consts::PI * a);
                assert!(
                    (p.frequency_hz / f - 1.0).abs() < 0.01,
                    "{name}: {p:?} vs {f}"
                );
            }
        }
    }
}

#[test]
fn bench_plot_draws_loops_at_300_hz_with_offsets_and_density_for_random_runs() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, expect) in [
        ("rate_300hz", "force_velocity_loops.png"),
        ("offsets_300hz", "quasi_static.png"),
        ("alpha_schedule_1khz", "random_runs.png"),
    ] {
        let ds = dataset::load(&fixture_dir(name)).unwrap();
        let cfg = SignalConfig {
            cutoff_hz: Some(ds.sample_rate_hz / 6.0),
            ..SignalConfig::default()
        };
        let signals = preprocess::run_signals(&ds, &cfg).unwrap();
        let out = tmp.path().join(name);
        let plotted = nemm_train::report::plot_loaded(&ds, &signals, &out).unwrap();
        assert!(plotted.skipped.is_empty(), "{name}: {:?}", plotted.skipped);
        let files = plotted.written;
        assert!(files.iter().any(|f| f.ends_with(expect)), "{files:?}");
        for f in &files {
            assert!(std::fs::metadata(f).unwrap().len() > 10_000);
        }
    }
    // The 1.27 Hz run at 300 Hz (236 samples per period) folds into 128 bins; the quasi-static
    // force of the offset runs is found although the transducer's zero is 30 mm off centre.
    let ds = dataset::load(&fixture_dir("offsets_300hz")).unwrap();
    let cfg = SignalConfig {
        cutoff_hz: Some(50.0),
        ..SignalConfig::default()
    };
    for (run, sig) in ds
        .runs
        .iter()
        .zip(preprocess::run_signals(&ds, &cfg).unwrap())
    {
        let l = nemm_train::report::cycle_loop(run, &sig.velocity_m_s).unwrap();
        assert_eq!(l.bins(), 128);
        let (reb, comp) = l.quasi_static_n();
        assert!(reb > 100.0 && comp < -100.0, "{reb} {comp}");
    }
}

#[test]
fn random_runs_give_monotone_support_points_and_a_sem() {
    let ds = dataset::load(&fixture_dir("alpha_schedule_1khz")).unwrap();
    let mut cfg = PrepareConfig {
        signal: SignalConfig {
            cutoff_hz: Some(100.0),
            ..SignalConfig::default()
        },
        ..PrepareConfig::default()
    };
    cfg.split.test_alphas = vec![0.3];
    let p = preprocess::prepare(&ds, &cfg).unwrap();
    let pts = &p.quasi_static.train;
    assert!(pts.len() >= 8, "{} points", pts.len());
    for direction in [Direction::Rebound, Direction::Compression] {
        let mut own: Vec<_> = pts.iter().filter(|q| q.direction == direction).collect();
        assert!(own.len() >= 3, "{direction:?}: {} points", own.len());
        own.sort_by(|a, b| a.velocity_m_s.total_cmp(&b.velocity_m_s));
        for w in own.windows(2) {
            assert!(w[1].force_n >= w[0].force_n, "{direction:?}: {w:?}");
        }
        assert!(
            own.iter().all(|q| q.velocity_m_s * q.force_n > 0.0),
            "{own:?}"
        );
    }
    let sem = nemm_train::train::pipeline::fit_sem(&p.quasi_static.train).unwrap();
    assert!(sem.velocities_m_s.len() >= 6, "{:?}", sem.velocities_m_s);
}

/// On a sine the low-acceleration rule selects the paper's window (`|a| <= 5 % a_max` is
/// `|x| <= 5 % A`): its fastest points agree with the paper's points of the run.
#[test]
fn low_acceleration_rule_on_a_sine_stays_close_to_the_paper_rule() {
    use nemm_train::data::support_points::low_acceleration_points;
    use nemm_virtual_bench::{config::BenchConfig, program::run_spec, VirtualBench};
    let bench = VirtualBench::new(BenchConfig::default());
    for (amp, v) in [(0.03, 0.262), (0.01, 0.524)] {
        let spec = run_spec(&bench.config().program, 0.0, amp, v);
        let run = bench.measure(&spec, 3);
        let fs = bench.config().program.sample_rate_hz;
        let (summary, sig) =
            preprocess::summarize_run(&run, 0, &SignalConfig::default().at_rate(fs).unwrap())
                .unwrap();
        let paper = preprocess::quasi_static_points(0, &sig, &summary.excitation, 0.0, 0.05);
        let low = low_acceleration_points(0, &sig, 0.0, 0.05, &|_| false);
        for direction in [Direction::Rebound, Direction::Compression] {
            // The paper's points of the full-amplitude passes (the ramp-in's are slower).
            let of = |d| paper.iter().filter(move |p| p.direction == d);
            let v_top = of(direction)
                .map(|p| p.velocity_m_s.abs())
                .fold(0.0, f64::max);
            let steady: Vec<_> = of(direction)
                .filter(|p| p.velocity_m_s.abs() >= 0.98 * v_top)
                .collect();
            let mean = |x: Vec<f64>| x.iter().sum::<f64>() / x.len() as f64;
            let pv = mean(steady.iter().map(|p| p.velocity_m_s).collect());
            let pf = mean(steady.iter().map(|p| p.force_n).collect());
            let fastest = low
                .iter()
                .filter(|p| p.direction == direction)
                .max_by(|a, b| a.velocity_m_s.abs().total_cmp(&b.velocity_m_s.abs()))
                .unwrap();
            let dv = fastest.velocity_m_s / pv - 1.0;
            let df = fastest.force_n / pf - 1.0;
            eprintln!(
                "{amp} m {v} m/s {direction:?}: paper {pv:.4} m/s {pf:.1} N, low-acceleration \
                 {:.4} m/s {:.1} N ({:+.2} %, {:+.2} %)",
                fastest.velocity_m_s,
                fastest.force_n,
                100.0 * dv,
                100.0 * df
            );
            assert!(dv.abs() < 0.01 && df.abs() < 0.01, "{dv} {df}");
        }
    }
}

/// The SEM of sine runs of one amplitude (ramp-in passes included) has a support velocity at
/// every run's peak velocity (the force there is the cluster's mean, ramp-in passes of similar
/// velocity included; its distance to the full-amplitude passes is printed).
#[test]
fn sem_from_sine_points_reproduces_the_steady_support_points() {
    use nemm_virtual_bench::{config::BenchConfig, VirtualBench};
    let mut cfg = BenchConfig::default();
    cfg.program.oil_loss = vec![0.0, 0.3];
    cfg.program.amplitudes_m = vec![0.03];
    cfg.program.peak_velocities_m_s = vec![0.131, 0.262, 0.524];
    let ds = VirtualBench::new(cfg).generate(2, |_, _| {});
    let mut prep = PrepareConfig::default();
    prep.split.test_alphas = vec![];
    prep.split.train_alphas = None;
    prep.split.validation_fraction = 0.0;
    let p = preprocess::prepare(&ds, &prep).unwrap();
    let pts = &p.quasi_static.train;
    let sem = nemm_train::train::pipeline::fit_sem(pts).unwrap();
    let mut worst: f64 = 0.0;
    for &alpha in &sem.alphas {
        let curve = sem.curve_at(alpha).0;
        for run in &p.runs {
            if (run.summary.alpha as f32 - alpha).abs() > 1e-6 {
                continue;
            }
            let own: Vec<_> = pts.iter().filter(|q| q.run == run.summary.index).collect();
            for direction in [Direction::Rebound, Direction::Compression] {
                let d: Vec<_> = own.iter().filter(|q| q.direction == direction).collect();
                let v_top = d.iter().map(|q| q.velocity_m_s.abs()).fold(0.0, f64::max);
                let steady: Vec<_> = d
                    .iter()
                    .filter(|q| q.velocity_m_s.abs() >= 0.98 * v_top)
                    .collect();
                let n = steady.len() as f64;
                let v = steady.iter().map(|q| q.velocity_m_s).sum::<f64>() / n;
                let f = steady.iter().map(|q| q.force_n).sum::<f64>() / n;
                let model = f64::from(sem.force_on_curve(&curve, v as f32));
                worst = worst.max(((model - f) / f).abs());
                assert!(
                    sem.velocities_m_s
                        .iter()
                        .any(|&k| (f64::from(k) / v - 1.0).abs() < 0.02),
                    "no support velocity near {v}: {:?}",
                    sem.velocities_m_s
                );
            }
        }
    }
    eprintln!(
        "SEM of {} sine points: {} support velocities, worst error at the steady points {:.2} %",
        pts.len(),
        sem.velocities_m_s.len(),
        100.0 * worst
    );
    assert!(worst.is_finite());
}

/// A force logged compression positive assists the motion on every run: `data check` says
/// so and names the flag that fixes it, and preparing the data for training refuses it
/// unless `--accept-implausible` is given.
#[test]
fn an_inverted_force_is_found_and_refused_before_training() {
    let text = data_check("inverted_force_300hz");
    assert_eq!(
        text.matches("force assists the motion").count(),
        4,
        "{text}"
    );
    assert!(
        text.contains("--invert-force") && text.contains("plausibility problems"),
        "{text}"
    );
    let (ok, text) = nemm_on("inverted_force_300hz", &["data", "prepare"]);
    assert!(!ok, "{text}");
    assert!(
        text.contains("run 0 (runs/oil00_a030_v0100.csv): the force assists the motion")
            && text.contains("--invert-force")
            && text.contains("--accept-implausible"),
        "{text}"
    );
    let (ok, text) = nemm_on(
        "inverted_force_300hz",
        &["data", "prepare", "--accept-implausible"],
    );
    assert!(ok, "{text}");
    // The correctly signed data pass.
    assert!(!data_check("rate_300hz").contains("force assists the motion"));
}

/// The cut-off and rule of each run in `nemm data check`'s run table.
fn run_cutoffs(text: &str) -> Vec<(f64, String)> {
    text.lines()
        .filter(|l| l.trim_end().ends_with(".csv") && l.contains(" runs/"))
        .map(|l| {
            let cells: Vec<&str> = l.split_whitespace().collect();
            // ... v, fc Hz, fc rule (one or two words), file.
            let file_at = cells.len() - 1;
            let (hz_at, rule) = if cells[file_at - 1] == "limit" {
                (file_at - 3, "rate limit".to_string())
            } else {
                (file_at - 2, cells[file_at - 1].to_string())
            };
            (cells[hz_at].parse().expect("fc Hz"), rule)
        })
        .collect()
}

/// Slow strokes logged at 300 Hz by a noisy potentiometer: through the rate's limit
/// (0.4 x the rate, given) the differentiated velocity is noise-dominated, which `data check`
/// finds from the displacement's noise and against the runs' own amplitude and frequency;
/// the cut-off chosen per run by default clears both.
#[test]
fn a_noise_dominated_velocity_is_found_and_the_automatic_cut_off_clears_it() {
    let (ok, text) = nemm_on("slow_pot_300hz", &["data", "check", "--cutoff-hz", "120"]);
    assert!(ok, "{text}");
    assert_eq!(
        text.matches("velocity dominated by noise").count(),
        2,
        "{text}"
    );
    assert_eq!(
        text.matches("velocity inconsistent with the stroke")
            .count(),
        2,
        "{text}"
    );
    assert!(
        text.contains("leave it out to have it chosen per run"),
        "{text}"
    );
    let (ok, text) = nemm_on("slow_pot_300hz", &["data", "check"]);
    assert!(ok, "{text}");
    assert!(!text.contains("velocity dominated"), "{text}");
    assert!(!text.contains("velocity inconsistent"), "{text}");
    let cutoffs = run_cutoffs(&text);
    assert_eq!(cutoffs.len(), 2, "{text}");
    for (hz, rule) in cutoffs {
        // 20 um of noise at 300 Hz against 0.0173 m/s RMS: about 16 Hz (module docs).
        assert!((10.0..25.0).contains(&hz) && rule == "noise", "{text}");
    }
    // Clean records keep the rate's limit.
    let (ok, text) = nemm_on("rate_300hz", &["data", "check"]);
    assert!(ok, "{text}");
    let cutoffs = run_cutoffs(&text);
    assert_eq!(cutoffs.len(), 4, "{text}");
    assert!(
        cutoffs
            .iter()
            .all(|(hz, rule)| *hz == 120.0 && rule == "rate limit"),
        "{text}"
    );
}

/// An untared load cell's offset is reported as what the static force models, and the
/// training commands switch the static force on for it (and not for tared records).
#[test]
fn a_force_offset_switches_the_static_force_on() {
    let text = data_check("offsets_300hz");
    assert!(
        text.contains(
            "a gas force or an untared load cell; the static force of eq. 17 models it \
             (switched on when the runs' median is 5 % or more)"
        ),
        "{text}"
    );
    let prepared = |name: &str| {
        let ds = dataset::load(&fixture_dir(name)).unwrap();
        let mut cfg = PrepareConfig::default();
        cfg.split.test_alphas.clear();
        cfg.split.test_tail = Some(0.2);
        preprocess::prepare(&ds, &cfg).unwrap()
    };
    let decided = |p: &preprocess::Prepared| {
        let offsets: Vec<_> = p.runs.iter().map(|r| r.summary.force_offset).collect();
        preprocess::static_force_from_data(&offsets).expect("zero-velocity samples")
    };
    let (untared, tared) = (prepared("offsets_300hz"), prepared("rate_300hz"));
    let (on, why) = decided(&untared);
    assert!(on, "{why}");
    assert!(
        why.starts_with("the median force at zero velocity is -9.7 %")
            && why.contains("over 3 runs"),
        "{why}"
    );
    let (on, why) = decided(&tared);
    assert!(!on, "{why}");
    // Not given, the data decide; given, the option does.
    let mut cfg = nemm_train::config::Config::default();
    assert_eq!(cfg.model.static_force, None);
    assert_eq!(
        cfg.with_static_force_from(&untared).model.static_force,
        Some(true)
    );
    assert_eq!(
        cfg.with_static_force_from(&tared).model.static_force,
        Some(false)
    );
    assert!(PipelineConfig::of(&cfg.with_static_force_from(&untared)).static_force);
    cfg.model.static_force = Some(false);
    assert_eq!(
        cfg.with_static_force_from(&untared).model.static_force,
        Some(false)
    );
}

/// A run shorter than its period (its metadata says 0.53 Hz, its samples last 1.3 s) does not
/// abort `nemm bench plot`: the other runs are drawn, the run is listed with the reason, and
/// the exit status says that something was skipped.
#[test]
fn bench_plot_skips_a_run_shorter_than_its_period_and_draws_the_rest() {
    let (tmp, data) = fixture_copy("rate_300hz", "oil00_a030_v0100.csv", |text| {
        text.lines().take(400).collect::<Vec<_>>().join("\n") + "\n"
    });
    let out = tmp.path().join("plots");
    let out_arg = out.to_str().unwrap();
    let (ok, text) = nemm_in(
        &data,
        &["bench", "plot", "--cutoff-hz", "50", "--out", out_arg],
    );
    assert!(!ok, "{text}");
    assert!(
        text.contains("skipped runs/oil00_a030_v0100.csv: run runs/oil00_a030_v0100.csv: shorter than one period")
            && text.contains("1 of 4 runs skipped"),
        "{text}"
    );
    assert!(out.join("force_velocity_loops.png").exists(), "{text}");
}

/// One unreadable run does not hide the others' findings: `nemm data check` lists it with its
/// file, line and column, checks the rest, and fails.
#[test]
fn data_check_reports_an_unreadable_run_and_checks_the_rest() {
    let (_tmp, data) = fixture_copy("rate_300hz", "oil00_a030_v0100.csv", |text| {
        // Line 11: the displacement cell is not a number.
        let mut lines: Vec<String> = text.lines().map(String::from).collect();
        let cells: Vec<&str> = lines[10].split(',').collect();
        lines[10] = format!("{},x,{}", cells[0], cells[2..].join(","));
        lines.join("\n") + "\n"
    });
    let (ok, text) = nemm_in(&data, &["data", "check"]);
    assert!(!ok, "{text}");
    assert!(text.contains("loaded 3 runs"), "{text}");
    assert!(
        text.contains("runs that could not be read (skipped):"),
        "{text}"
    );
    assert!(text.contains("oil00_a030_v0100.csv:11"), "{text}");
    assert!(
        text.contains("1 of 4 runs could not be read (listed above); the other 3 were checked"),
        "{text}"
    );
    // The other runs' table rows are there.
    assert_eq!(run_cutoffs(&text).len(), 3, "{text}");
}
