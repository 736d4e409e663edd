//! Inputs a command was not made for, through the binary: sizes refused before anything is
//! allocated (`diagnose --step-repeat`, `identify --step`), data checked against the model in
//! `identify` and `diagnose` (force scale, absurd samples, an inverted force), `--runs` globs
//! that match nothing, `--tables-alpha` outside the trained range, and the import's unclear
//! errors and loose ends (conflicting priors, a slow `--resample-hz`, a header-only file, a
//! decimal comma, one file stem twice, a stale `nemm-data.toml`, control characters in a
//! condition name, a leftover `.new-*` folder, an hour-long gap in the stamps, numbers beyond
//! single precision, `--out .`).
use std::path::{Path, PathBuf};
use std::process::Command;

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("workspace")
        .to_path_buf()
}

fn model() -> PathBuf {
    workspace().join("nemm-firmware/data/trained-nemm.nemm")
}

fn e2e() -> PathBuf {
    workspace().join("nemm-firmware/data/e2e")
}

/// Runs `nemm args` in `dir`; returns success, stdout and stderr.
fn nemm_in(dir: &Path, args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .current_dir(dir)
        .args(args)
        .output()
        .expect("run nemm");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs `nemm args` and expects a failure whose error output holds each of `needles`.
fn refused(dir: &Path, args: &[&str], needles: &[&str]) -> String {
    let (ok, stdout, stderr) = nemm_in(dir, args);
    assert!(!ok, "{args:?} succeeded:\n{stdout}\n{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "{args:?}: {n:?} not in\n{stderr}");
    }
    stderr
}

/// A copy of the e2e dataset in `dir/name`, with `edit` applied to the lines of its first
/// run file (the header is line 1).
fn e2e_copy(dir: &Path, name: &str, edit: impl Fn(usize, &str) -> String) -> PathBuf {
    let to = dir.join(name);
    std::fs::create_dir_all(to.join("runs")).expect("mkdir");
    std::fs::copy(e2e().join("manifest.toml"), to.join("manifest.toml")).expect("copy");
    let mut first = true;
    let mut names: Vec<PathBuf> = std::fs::read_dir(e2e().join("runs"))
        .expect("runs")
        .flatten()
        .map(|e| e.path())
        .collect();
    names.sort();
    // The manifest's first run.
    let manifest = std::fs::read_to_string(e2e().join("manifest.toml")).expect("manifest");
    let first_file = manifest
        .lines()
        .find_map(|l| l.strip_prefix("file = \""))
        .map(|l| l.trim_end_matches('"').to_string())
        .expect("a run");
    for p in names {
        let rel = format!("runs/{}", p.file_name().expect("name").to_string_lossy());
        let text = std::fs::read_to_string(&p).expect("read");
        let text = if rel == first_file && first {
            first = false;
            text.lines()
                .enumerate()
                .map(|(i, l)| edit(i + 1, l) + "\n")
                .collect()
        } else {
            text
        };
        std::fs::write(to.join(&rel), text).expect("write");
    }
    to
}

/// `line` of a run file with its force column multiplied by `factor`.
fn scale_force(line: &str, factor: f64) -> String {
    let cells: Vec<&str> = line.split(',').collect();
    match cells[2].parse::<f64>() {
        Ok(f) => format!("{},{},{}", cells[0], cells[1], f * factor),
        Err(_) => line.to_string(),
    }
}

/// `line` (line `i` of a run file) with its cell `column` set to 1e30 when `i` is `at`.
fn set_cell(i: usize, line: &str, at: usize, column: usize) -> String {
    if i != at {
        return line.to_string();
    }
    let mut cells: Vec<&str> = line.split(',').collect();
    cells[column] = "1e30";
    cells.join(",")
}

#[test]
fn sizes_are_bounded_before_anything_is_allocated() {
    let (tmp, m, data, report) = committed();
    let (d, m, data, report) = (tmp.path(), m.as_str(), data.as_str(), report.as_str());
    refused(
        d,
        &[
            &diagnose(m, data, report)[..],
            &[
                "--level-step",
                "oil15_a010_v1048.csv,oil15_a050_v1048.csv",
                "--step-repeat",
                "1000000",
            ],
        ]
        .concat(),
        &["--step-repeat 1000000", "at most 10000000"],
    );
    for (step, needle) in [
        ("1e-9", "at most 1001"),
        ("0.5", "does not contain the model's trained level 0.3"),
        ("0.2", "does not contain the model's trained level 0.3"),
        ("0", "must be a finite number > 0"),
    ] {
        refused(
            d,
            &["identify", "--model", m, "--data", data, "--step", step],
            &[&format!("--step {step}"), needle],
        );
    }
    // identify's report folder is checked before the work.
    let file = d.join("a-file");
    std::fs::write(&file, "x").expect("write");
    refused(
        d,
        &[
            "identify",
            "--model",
            m,
            "--data",
            data,
            "--report",
            file.to_str().expect("utf-8"),
        ],
        &["is a file, not a folder"],
    );
    assert!(!Path::new(report).exists());
}

/// A temporary folder, the committed model and dataset, and a report folder in the former.
fn committed() -> (tempfile::TempDir, String, String, String) {
    let tmp = tempfile::tempdir().expect("tempdir");
    let text = |p: PathBuf| p.to_str().expect("utf-8").to_string();
    let report = text(tmp.path().join("r"));
    (tmp, text(model()), text(e2e()), report)
}

/// `nemm diagnose --model M --data DATA --report REPORT`.
fn diagnose<'a>(m: &'a str, data: &'a str, report: &'a str) -> [&'a str; 7] {
    ["diagnose", "--model", m, "--data", data, "--report", report]
}

#[test]
fn data_that_do_not_suit_the_model_are_refused_by_identify_and_diagnose() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let m = model();
    let m = m.to_str().expect("utf-8");
    let cases: Vec<(PathBuf, Vec<&str>)> = vec![
        (
            e2e_copy(d, "x30", |_, l| scale_force(l, 30.0)),
            vec!["times the model's force scale", "do not suit this model"],
        ),
        (
            e2e_copy(d, "force1e30", |i, l| set_cell(i, l, 500, 2)),
            vec![":500: force_n = 1e30 is beyond", "fix or cut the run"],
        ),
        (
            e2e_copy(d, "x1e30", |i, l| set_cell(i, l, 700, 1)),
            vec![
                ":700: displacement_m = 1e30 is beyond",
                "fix or cut the run",
            ],
        ),
        (
            e2e_copy(d, "inverted", |_, l| scale_force(l, -1.0)),
            vec!["the force assists the motion", "--invert-force"],
        ),
    ];
    for (data, needles) in &cases {
        let data = data.to_str().expect("utf-8");
        let report = d.join("report");
        refused(
            d,
            &diagnose(m, data, report.to_str().expect("utf-8")),
            needles,
        );
        assert!(!report.exists(), "nothing written");
        // identify: the same check (the inverted force is refused by the preparation).
        refused(
            d,
            &["identify", "--model", m, "--data", data],
            &[needles[0]],
        );
    }
}

#[test]
fn a_glob_that_matches_nothing_is_refused_even_beside_one_that_matches() {
    let (tmp, m, data, report) = committed();
    let (d, m, data, report) = (tmp.path(), m.as_str(), data.as_str(), report.as_str());
    let runs = ["--runs", "runs/oil15_a050_*", "--runs", "runs/oil99_*"];
    let mut args = diagnose(m, data, report).to_vec();
    args.extend(runs);
    refused(
        d,
        &args,
        &["--runs \"runs/oil99_*\" matches none of the 5 runs"],
    );
    let mut args = vec!["identify", "--model", m, "--data", data];
    args.extend(runs);
    refused(d, &args, &["--runs \"runs/oil99_*\" matches none"]);
}

#[test]
fn tables_alpha_outside_the_trained_range_is_refused() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("t.nemm");
    let m = model();
    for a in ["0.5", "0.9"] {
        refused(
            tmp.path(),
            &[
                "tables",
                m.to_str().expect("utf-8"),
                "--tables-alpha",
                a,
                "--out",
                out.to_str().expect("utf-8"),
            ],
            &[&format!(
                "--tables-alpha {a} is outside the model's trained range"
            )],
        );
    }
    assert!(!out.exists());
}

/// A 1 kHz raw file of `seconds`, columns `t,x,F` (s, mm, N), after the header `header`
/// lines; `jump_s` added to every stamp after the middle.
fn write_raw(path: &Path, seconds: f64, jump_s: f64) {
    let mut s = String::from("t,x,F\n");
    let n = (1000.0 * seconds) as usize;
    for i in 0..n {
        let t = i as f64 / 1000.0 + if i >= n / 2 { jump_s } else { 0.0 };
        let x = (2.0 * std::f64::consts::PI * 2.0 * i as f64 / 1000.0).sin();
        s.push_str(&format!("{t},{x:.6},{:.6}\n", 100.0 * x));
    }
    std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
    std::fs::write(path, s).expect("raw");
}

/// `nemm data import RAW... --out OUT` with the columns of [`write_raw`], then `extra`.
fn import_args<'a>(raws: &'a [&'a str], out: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["data", "import"];
    a.extend(raws);
    a.extend([
        "--time",
        "t:s",
        "--displacement",
        "x:mm",
        "--force",
        "F:N",
        "--alpha",
        "0.5",
        "--out",
        out,
    ]);
    a.extend(extra);
    a
}

#[test]
fn import_refuses_unclear_input_with_clear_errors() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let raw = d.join("raw/a.csv");
    write_raw(&raw, 2.0, 0.0);
    let raw = raw.to_str().expect("utf-8");
    let out = "ds";
    let run = |extra: &[&str], needles: &[&str]| {
        refused(d, &import_args(&[raw], out, extra), needles);
        assert!(!d.join(out).exists(), "{extra:?}: nothing written");
    };
    run(
        &[
            "--prior",
            "b_fl=none,b_fl=increasing",
            "--condition-name",
            "valve",
        ],
        &["--prior gives b_fl two directions, none and increasing"],
    );
    run(
        &["--resample-hz", "0.001"],
        &["below the lowest model rate"],
    );
    run(
        &[
            "--condition-name",
            "oil\nloss",
            "--prior",
            "b_fl=none,b_pr=none,k_pr=none",
        ],
        &["control character '\\n'"],
    );
    let named = [
        "--condition-name",
        "valve",
        "--prior",
        "b_fl=none,b_pr=none,k_pr=none",
    ];
    for (range, needle) in [
        (
            "0,1e300",
            "1e300 is not a finite number in the blob's single precision",
        ),
        (
            "1e-300,2e-300",
            "are one number in the blob's single precision",
        ),
    ] {
        let extra = [&named[..], &["--condition-range", range]].concat();
        let e = run_text(d, &import_args(&[raw], out, &extra));
        assert!(e.contains(needle) && !e.contains("000000000000"), "{e}");
    }
    // One file stem twice.
    let other = d.join("raw2/a.txt");
    write_raw(&other, 2.0, 0.0);
    run_both(d, raw, other.to_str().expect("utf-8"), out);
    // A header-only file: the error names its line.
    let empty = d.join("raw/empty.csv");
    std::fs::write(&empty, "t,x,F\n").expect("write");
    refused(
        d,
        &import_args(&[empty.to_str().expect("utf-8")], out, &[]),
        &["empty.csv", "no samples after the header (line 1)"],
    );
    // A decimal comma, with a hint.
    let comma = d.join("raw/comma.csv");
    std::fs::write(&comma, "t;x;F\n0;1,5;2\n0,001;1,6;2\n").expect("write");
    refused(
        d,
        &import_args(
            &[comma.to_str().expect("utf-8")],
            out,
            &["--delimiter", ";"],
        ),
        &["comma.csv:2", "decimal_comma = true"],
    );
    // An hour-long pause in the stamps: a gap at its line, with and without --rate-hz.
    let paused = d.join("raw/paused.csv");
    write_raw(&paused, 2.0, 3600.0);
    for extra in [&[][..], &["--rate-hz", "1000"][..]] {
        refused(
            d,
            &import_args(&[paused.to_str().expect("utf-8")], out, extra),
            &[
                "paused.csv:1002",
                "gap of",
                "about 3600000 missing sample(s)",
            ],
        );
    }
    // `--out .` when the raw files lie elsewhere: the current folder is not swapped away.
    let here = d.join("here");
    std::fs::create_dir_all(&here).expect("mkdir");
    refused(
        &here,
        &import_args(&[raw], ".", &[]),
        &["is the current folder"],
    );
}

fn run_text(d: &Path, args: &[&str]) -> String {
    let (ok, _, stderr) = nemm_in(d, args);
    assert!(!ok, "{args:?} succeeded");
    stderr
}

fn run_both(d: &Path, a: &str, b: &str, out: &str) {
    let raws = [a, b];
    let mut args = import_args(&raws, out, &[]);
    // One level per file.
    let k = args.iter().position(|x| *x == "0.5").expect("alpha");
    args[k] = "0.1,0.2";
    refused(d, &args, &["one file name stem, \"a\""]);
}

#[test]
fn import_replace_drops_stale_options_and_cleans_leftovers() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let raw = d.join("raw/a.csv");
    write_raw(&raw, 2.0, 0.0);
    let raw = raw.to_str().expect("utf-8");
    let (ok, _, e) = nemm_in(d, &import_args(&[raw], "ds", &[]));
    assert!(ok, "{e}");
    std::fs::write(d.join("ds/nemm-data.toml"), "cutoff_hz = 40.0\n").expect("write");
    std::fs::write(d.join("ds/notes.txt"), "mine").expect("write");
    // A folder left by an import killed between its renames (its process is gone).
    let leftover = d.join(".ds.new-4294967-0");
    std::fs::create_dir_all(&leftover).expect("mkdir");
    let (ok, stdout, stderr) = nemm_in(d, &import_args(&[raw], "ds", &["--replace"]));
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("nemm-data.toml: the data options saved for the replaced dataset"),
        "{stdout}"
    );
    assert!(!d.join("ds/nemm-data.toml").exists());
    assert_eq!(
        std::fs::read(d.join("ds/notes.txt")).expect("kept"),
        b"mine"
    );
    assert!(
        stderr.contains(".ds.new-4294967-0, left by an interrupted write"),
        "{stderr}"
    );
    assert!(!leftover.exists());
}
