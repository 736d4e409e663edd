//! `nemm diagnose` through the binary: the committed trained NEMM on the committed held-out
//! 15 % runs (`nemm-firmware/data`), the shape of `diagnose.json`, its numbers against
//! nemm-core's observer and the identifiability search run here, the figures, the accuracy
//! files, a level step on two runs of the virtual bench, and the refusal of bad inputs with
//! nothing written.
use nemm_core::{AlphaObserver, ObserverConfig, Sample};
use nemm_dataset as dataset;
use nemm_train::data::preprocess::causal_velocity;
use nemm_train::train::identify::{identify, AlphaGrid, Run, Search, DEFAULT_STEP};
use nemm_virtual_bench::config::BenchConfig;
use nemm_virtual_bench::VirtualBench;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("workspace")
        .to_path_buf()
}

fn model_path() -> PathBuf {
    workspace().join("nemm-firmware/data/trained-nemm.nemm")
}

fn e2e() -> PathBuf {
    workspace().join("nemm-firmware/data/e2e")
}

fn nemm(args: &[&Path], runs: &[&str]) -> Output {
    nemm_with(args, runs, &[])
}

/// `nemm diagnose --model --data --report` (`args`), `--runs` each of `runs`, then `extra`.
fn nemm_with(args: &[&Path], runs: &[&str], extra: &[&str]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_nemm"));
    c.arg("diagnose");
    for (flag, value) in ["--model", "--data", "--report"].iter().zip(args) {
        c.arg(flag).arg(value);
    }
    for r in runs {
        c.arg("--runs").arg(r);
    }
    c.args(extra).output().expect("run nemm")
}

fn read_json(path: &Path) -> Value {
    serde_json::from_slice(
        &std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())),
    )
    .expect("parse")
}

const KEYS: [&str; 7] = [
    "alpha_hat",
    "alpha_offline",
    "band",
    "excited",
    "file",
    "label",
    "settle_s",
];

#[test]
fn diagnoses_the_committed_runs_as_the_observer_and_the_search_do() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let report = tmp.path().join("a/diag");
    let out = nemm(&[&model_path(), &e2e(), &report], &[]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: Value =
        serde_json::from_slice(&std::fs::read(report.join("diagnose.json")).expect("json"))
            .expect("parse");
    let top: Vec<&String> = json.as_object().expect("object").keys().collect();
    assert_eq!(top, ["runs"]);
    let runs = json["runs"].as_array().expect("runs");
    let files: Vec<&str> = runs
        .iter()
        .map(|r| r["file"].as_str().expect("file"))
        .collect();
    assert_eq!(
        files,
        [
            "runs/oil15_a050_v1048.csv",
            "runs/oil15_a010_v1048.csv",
            "runs/oil15_a010_v0262.csv",
            "runs/oil15_a030_v0524.csv",
            "runs/oil15_a050_v0262.csv",
        ],
        "every run, in manifest order"
    );
    let num = |r: &Value, k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k}: {r}"));
    let mut excited = 0;
    for r in runs {
        let mut keys: Vec<&String> = r.as_object().expect("run").keys().collect();
        keys.sort();
        assert_eq!(keys, KEYS, "{r}");
        assert_eq!(num(r, "label"), 0.15);
        let (a, band) = (num(r, "alpha_hat"), num(r, "band"));
        assert!(
            (0.0..=0.3).contains(&a) && (0.0..=0.3).contains(&band),
            "{r}"
        );
        // Every run here has an offline fit (the model tells the levels apart on each).
        let offline = num(r, "alpha_offline");
        let settle = num(r, "settle_s");
        assert!((0.0..=1.1).contains(&settle), "{r}");
        if r["excited"].as_bool().expect("excited") {
            excited += 1;
            assert!(band <= 0.05, "excited means a band of at most 0.05: {r}");
            assert!((a - offline).abs() <= 0.02, "{r}");
        } else {
            assert!(band > 0.05, "{r}");
        }
        let figure = report.join(format!(
            "alpha_{}.png",
            r["file"]
                .as_str()
                .expect("file")
                .trim_end_matches(".csv")
                .replace('/', "_")
        ));
        let png = std::fs::read(&figure).unwrap_or_else(|e| panic!("{}: {e}", figure.display()));
        assert!(
            png.len() > 1000 && png.starts_with(b"\x89PNG"),
            "{}",
            figure.display()
        );
    }
    // Measured: the runs (0.6 to 1.05 s) are shorter than the observer's 3 s window, so by
    // their end it has solved one or two blocks of stroke cycles; only the 10 mm, 1.048 m/s
    // run (the most cycles) is excited. The 50 mm, 1.048 m/s run fits best at 0.150 offline.
    assert_eq!(excited, 1, "{json}");
    assert!(
        (num(&runs[0], "alpha_offline") - 0.15).abs() <= 0.003,
        "{}",
        runs[0]
    );
    assert!(runs[1]["excited"].as_bool().expect("excited"));
    assert!(
        stdout.contains("1 of 1 excited runs within 0.02 of the offline fit"),
        "{stdout}"
    );
    assert!(
        stdout.contains("| runs/oil15_a010_v1048.csv | 0.150 | "),
        "{stdout}"
    );

    accuracy_of_the_committed_runs(&report, runs);

    // The same numbers from nemm-core's observer and the identifiability search, run here on
    // the firmware's velocity path.
    let model: nemm_core::Model =
        nemm_core::decode(&std::fs::read(model_path()).expect("blob")).expect("model");
    let ds = dataset::load(&e2e()).expect("dataset");
    let fs = ds.sample_rate_hz;
    for (k, r) in runs.iter().enumerate().take(2) {
        let run = &ds.runs[k];
        let v: Vec<f32> = causal_velocity(&run.displacement_m, fs)
            .iter()
            .map(|&v| v as f32)
            .collect();
        let x: Vec<f32> = run.displacement_m.iter().map(|&x| x as f32).collect();
        let mut obs: Box<AlphaObserver> = Box::new(AlphaObserver::empty());
        obs.load(&model, ObserverConfig::new()).expect("observer");
        for ((&v, &x), &f) in v.iter().zip(&x).zip(&run.force_n) {
            obs.step(Sample::new(v).with_position(x).with_force(f as f32));
        }
        let end = obs.estimate();
        assert!(
            (f64::from(end.alpha) - num(r, "alpha_hat")).abs() <= 6e-5,
            "{r}"
        );
        assert!((f64::from(end.band) - num(r, "band")).abs() <= 6e-5, "{r}");
        assert_eq!(
            end.flags.excited(),
            r["excited"].as_bool().expect("excited")
        );
        let grid = AlphaGrid::for_model(&model, DEFAULT_STEP).expect("grid");
        let fit = identify(
            &model,
            &Run {
                velocity_m_s: &v,
                position_m: Some(&x),
                force_n: &run.force_n,
                label: 0.15,
                label_alphas: None,
            },
            &grid,
            1.0 / fs,
            (0.01 * fs) as usize,
            Search::CoarseToFine,
        )
        .expect("identify");
        let best = fit.best.expect("a best fit");
        assert!(
            (best - num(r, "alpha_offline")).abs() <= DEFAULT_STEP,
            "{best}: {r}"
        );
    }
}

/// `accuracy.json` and `accuracy.md` of the committed runs (all shorter than 2 s, one level)
/// against `diagnose.json`'s `runs`.
fn accuracy_of_the_committed_runs(report: &Path, runs: &[Value]) {
    let acc = read_json(&report.join("accuracy.json"));
    let mut keys: Vec<&String> = acc.as_object().expect("object").keys().collect();
    keys.sort();
    assert_eq!(
        keys,
        [
            "detail",
            "from_s",
            "resolution",
            "runs",
            "summary",
            "tolerance"
        ]
    );
    assert_eq!(acc["from_s"], 2.0);
    let errors = acc["runs"].as_array().expect("runs");
    assert_eq!(errors.len(), runs.len());
    for (e, r) in errors.iter().zip(runs) {
        assert_eq!(e["file"], r["file"]);
        // Every committed run is shorter than 2 s: judged by its final estimate.
        assert_eq!(e["short"], true, "{e}");
        assert!(e["duration_s"].as_f64().expect("duration") < 2.0, "{e}");
        assert_eq!(e["alpha_at_from"], r["alpha_hat"], "{e}");
        let worst = e["worst_error"].as_f64().expect("worst");
        let end = (r["alpha_hat"].as_f64().expect("hat")
            - r["alpha_offline"].as_f64().expect("fit"))
        .abs();
        assert!((worst - end).abs() <= 2e-4, "{e} {r}");
    }
    assert_eq!(
        acc["summary"],
        "1 of 1 excited runs within 0.02 of the offline fit from 2 s on (5 runs, 4 not \
         excited, 5 no longer than 2 s, judged by their final estimate)"
    );
    assert_eq!(
        acc["detail"],
        "At 2 s (the end of a shorter run): 1 of 1 excited runs within 0.02. Excited at 2 s \
         as well as at the end: 1 of 1 within from 2 s on. Where the observer calls its \
         estimate valid (excited and settled): 0 of 1 excited runs within from 2 s on and \
         settled at the end (0 settled at the end)."
    );
    // One level only: one column, every condition a row, no ordering check.
    let res = &acc["resolution"];
    assert_eq!(res["levels"], serde_json::json!([0.15]));
    assert_eq!(res["rows"].as_array().expect("rows").len(), 5);
    let md = std::fs::read_to_string(report.join("accuracy.md")).expect("accuracy.md");
    assert!(
        md.contains("No ordering check: 1 labelled level(s), 5 condition(s)."),
        "{md}"
    );
    assert!(
        md.contains(
            "| runs/oil15_a010_v1048.csv | 1.05 | yes | yes | 0.064 | 0.071 (end: run shorter) |"
        ),
        "{md}"
    );
    assert!(
        md.contains("| 10 | 1.048 | 0.064 | 0.071 | yes | - | - |"),
        "{md}"
    );
    assert!(!report.join("level-step.json").exists());
}

/// The 50 mm, 1.048 m/s runs at 0 and 30 % of the default virtual bench (seed 1, as
/// `nemm bench generate` writes them), in `dir`.
fn bench_condition(dir: &Path) {
    let mut cfg = BenchConfig::default();
    cfg.program.oil_loss = vec![0.0, 0.3];
    cfg.program.amplitudes_m = vec![0.05];
    cfg.program.peak_velocities_m_s = vec![1.048];
    dataset::write(dir, &VirtualBench::new(cfg).generate(1, |_, _| {})).expect("write");
}

#[test]
fn a_level_step_is_followed_from_the_first_runs_fit_to_the_seconds() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let data = tmp.path().join("bench");
    bench_condition(&data);
    let report = tmp.path().join("report");
    let out = nemm_with(
        &[&model_path(), &data, &report],
        &[],
        &[
            "--level-step",
            "runs/oil00_a050_v1048.csv,oil30_a050_v1048.csv",
            "--step-repeat",
            "4",
        ],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = read_json(&report.join("level-step.json"));
    let num = |v: &Value| v.as_f64().unwrap_or_else(|| panic!("{v}: {s}"));
    let (a, b) = (
        num(&s["first"]["alpha_offline"]),
        num(&s["second"]["alpha_offline"]),
    );
    // The two levels fit apart (measured: 0.061 and 0.273).
    assert!(b - a > 0.15, "{s}");
    // 3 s runs: the ramp-in's three 0.3 s periods left out, six full periods each; the first
    // run to the end of its steady part and it three more times, the second's four times.
    assert_eq!(s["first"]["periods"], 6);
    assert_eq!(s["second"]["periods"], 6);
    let steady = num(&s["second"]["steady_s"][1]) - num(&s["second"]["steady_s"][0]);
    assert!((steady - 1.8).abs() < 0.01, "{s}");
    let step = num(&s["step_s"]);
    assert!(
        (step - (num(&s["first"]["steady_s"][1]) + 3.0 * steady)).abs() < 1e-3,
        "{s}"
    );
    assert!(
        (num(&s["duration_s"]) - (step + 4.0 * steady)).abs() < 1e-3,
        "{s}"
    );
    // Continuous up to one sample's travel at 1.048 m/s (105 um).
    assert!(num(&s["jump_m"]) < 1.1e-4, "{s}");
    // Before the step the estimate sits on the first run's fit, at the end on the second's;
    // it follows within the second run's part of the record.
    assert!((num(&s["before"]["alpha"]) - a).abs() <= 0.02, "{s}");
    assert_eq!(s["before"]["excited"], true);
    assert!((num(&s["end"]["alpha"]) - b).abs() <= 0.02, "{s}");
    let (reach, settle) = (num(&s["reach_s"]), num(&s["settle_s"]));
    assert!(
        0.5 < reach && reach <= settle && settle < 4.0 * steady,
        "{s}"
    );
    let md = std::fs::read_to_string(report.join("level-step.md")).expect("level-step.md");
    assert!(
        md.contains(&format!("after the step, and from {settle:.2} s")),
        "{md}"
    );
    assert!(stdout.contains("**Level step**"), "{stdout}");
    let png = std::fs::read(report.join("level-step.png")).expect("png");
    assert!(png.len() > 1000 && png.starts_with(b"\x89PNG"));
    // The two diagnosed runs: two levels of one condition, in order offline.
    let acc = read_json(&report.join("accuracy.json"));
    assert_eq!(acc["resolution"]["levels"], serde_json::json!([0.0, 0.3]));
    assert_eq!(acc["resolution"]["rows"].as_array().expect("rows").len(), 1);
    assert!(
        stdout.contains("Offline fit: 0 % below 30 % on 1 of 1 excited conditions"),
        "{stdout}"
    );
}

#[test]
fn bad_inputs_are_refused_with_a_clear_error_and_nothing_written() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let report = tmp.path().join("report");
    let refused = |args: &[&Path], runs: &[&str], expect: &str| {
        let out = nemm(args, runs);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} {runs:?} succeeded");
        assert!(stderr.contains(expect), "{args:?} {runs:?}: {stderr}");
        assert!(
            !report.exists(),
            "{args:?} {runs:?} wrote {}",
            report.display()
        );
    };
    let missing = tmp.path().join("missing.nemm");
    refused(&[&missing, &e2e(), &report], &[], "--model: cannot read");
    let not_a_model = tmp.path().join("not-a-model.nemm");
    std::fs::write(&not_a_model, b"this is not a weights blob").expect("write");
    refused(
        &[&not_a_model, &e2e(), &report],
        &[],
        "not a NEMM model blob",
    );
    refused(
        &[&model_path(), &e2e(), &report],
        &["runs/oil30_*"],
        "--runs \"runs/oil30_*\" matches none of the 5 runs",
    );
    let step = |pair: &str, expect: &str| {
        let out = nemm_with(
            &[&model_path(), &e2e(), &report],
            &[],
            &["--level-step", pair],
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{pair} succeeded");
        assert!(stderr.contains(expect), "{pair}: {stderr}");
        assert!(!report.exists(), "{pair} wrote {}", report.display());
    };
    step("runs/oil15_a050_v1048.csv", "--level-step takes two runs");
    step("runs/*,oil15_a010_v1048.csv", "matches 5 runs, not one");
    step(
        "oil15_a010_v1048.csv,oil15_a010_v0262.csv",
        "are not one condition",
    );
    let rate = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/offsets_300hz");
    refused(&[&model_path(), &rate, &report], &[], "sampled at 300 Hz");
    // A report path that is a file: refused before any work, the file left as it was.
    let file = tmp.path().join("report-file");
    std::fs::write(&file, b"keep").expect("write");
    let out = nemm(&[&model_path(), &e2e(), &file], &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("--report") && stderr.contains("is a file, not a folder"),
        "{stderr}"
    );
    assert_eq!(std::fs::read(&file).expect("read"), b"keep");
    let names: Vec<_> = std::fs::read_dir(tmp.path())
        .expect("read")
        .map(|e| e.expect("entry").file_name())
        .collect();
    assert_eq!(names.len(), 2, "nothing else written: {names:?}");
}
