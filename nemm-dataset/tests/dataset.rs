//! The dataset interchange format: round trip and one test per refused input.
use nemm_dataset::{self as dataset, Dataset, DatasetError, Run, RunEntry, MANIFEST_FILE};
use std::path::{Path, PathBuf};

fn entry(file: &str, oil_loss: f64) -> RunEntry {
    RunEntry {
        file: PathBuf::from(file),
        oil_loss,
        amplitude_m: Some(0.01),
        target_velocity_m_s: Some(0.524),
    }
}

/// A sinusoidal run with awkward floats (non-terminating binary fractions, tiny values).
fn sine_run(file: &str, oil_loss: f64, n: usize, fs: f64, with_velocity: bool) -> Run {
    let t0 = 12.345_678_9;
    let time_s: Vec<f64> = (0..n).map(|i| t0 + i as f64 / fs).collect();
    let w = 2.0 * std::f64::consts::PI * 8.3;
    let displacement_m: Vec<f64> = time_s.iter().map(|t| 0.01 * (w * t).sin()).collect();
    let force_n: Vec<f64> = time_s
        .iter()
        .map(|t| 1234.5678 * (w * t).cos() + 1e-9 * t)
        .collect();
    let velocity_m_s =
        with_velocity.then(|| time_s.iter().map(|t| 0.01 * w * (w * t).cos()).collect());
    Run {
        entry: entry(file, oil_loss),
        time_s,
        displacement_m,
        force_n,
        velocity_m_s,
        alpha: None,
    }
}

fn sample_dataset(fs: f64) -> Dataset {
    Dataset {
        name: "test damper \"A\"".into(),
        sample_rate_hz: fs,
        condition: None,
        runs: vec![
            sine_run("runs/oil00.csv", 0.0, 500, fs, false),
            sine_run("runs/oil15.csv", 0.15, 300, fs, true),
            sine_run("oil30.csv", 0.3, 200, fs, false),
        ],
    }
}

/// A dataset folder with `manifest` and the given `(file, content)` CSV files.
fn folder(manifest: &str, files: &[(&str, &str)]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::write(dir.path().join(MANIFEST_FILE), manifest).expect("write manifest");
    for (name, content) in files {
        let p = dir.path().join(name);
        std::fs::create_dir_all(p.parent().expect("parent")).expect("mkdir");
        std::fs::write(p, content).expect("write csv");
    }
    dir
}

const MANIFEST_ONE: &str =
    "name = \"d\"\nsample_rate_hz = 10000.0\n[[runs]]\nfile = \"runs/x.csv\"\noil_loss = 0.15\n";

/// Loads a one-run dataset whose CSV is `csv`.
fn load_csv(csv: &str) -> Result<Dataset, DatasetError> {
    let dir = folder(MANIFEST_ONE, &[("runs/x.csv", csv)]);
    dataset::load(dir.path())
}

fn load_manifest(manifest: &str) -> Result<Dataset, DatasetError> {
    let good = "time_s,displacement_m,force_n\n0,0,0\n0.0001,0,0\n";
    let dir = folder(manifest, &[("runs/x.csv", good), ("runs/y.csv", good)]);
    dataset::load(dir.path())
}

fn ends_with(p: &Path, tail: &str) -> bool {
    p.ends_with(tail)
}

#[test]
fn round_trip_is_exact() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = sample_dataset(10_000.0);
    dataset::write(dir.path(), &d).expect("write");
    let back = dataset::load(dir.path()).expect("load");
    assert_eq!(back, d);
    // Writing again over the existing files gives the same dataset and leaves no temp files.
    dataset::write(dir.path(), &back).expect("rewrite");
    assert_eq!(dataset::load(dir.path()).expect("reload"), d);
    let leftovers: Vec<_> = std::fs::read_dir(dir.path().join("runs"))
        .expect("read dir")
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}

#[test]
fn manifest_is_the_documented_toml() {
    let dir = tempfile::tempdir().expect("temp dir");
    dataset::write(dir.path(), &sample_dataset(10_000.0)).expect("write");
    let text = std::fs::read_to_string(dir.path().join(MANIFEST_FILE)).expect("manifest");
    assert!(text.contains("sample_rate_hz = 10000.0"), "{text}");
    assert!(text.contains("[[runs]]"), "{text}");
    assert!(text.contains("file = \"runs/oil15.csv\""), "{text}");
    assert!(text.contains("oil_loss = 0.15"), "{text}");
    let csv = std::fs::read_to_string(dir.path().join("runs/oil15.csv")).expect("csv");
    assert!(
        csv.starts_with("time_s,displacement_m,force_n,velocity_m_s\n"),
        "{csv}"
    );
}

#[test]
fn other_sample_rate_and_integer_rate_load() {
    // 2 kHz, and the rate written as a TOML integer.
    let csv = "time_s,displacement_m,force_n\n0,0,1\n0.0005,0.001,2\n0.001,0.002,3\n";
    let manifest =
        "name = \"d\"\nsample_rate_hz = 2000\n[[runs]]\nfile = \"x.csv\"\noil_loss = 0\n";
    let dir = folder(manifest, &[("x.csv", csv)]);
    let d = dataset::load(dir.path()).expect("2 kHz loads");
    assert_eq!(d.sample_rate_hz, 2000.0);
    assert_eq!(d.dt_s(), 0.0005);
    assert_eq!(d.runs[0].force_n, vec![1.0, 2.0, 3.0]);
}

#[test]
fn unknown_columns_are_ignored_and_order_is_free() {
    let csv = "force_n, temperature_c ,time_s,displacement_m,velocity_m_s\n5,20,0,0.1,1\n6,21,0.0001,0.2,2\n";
    let d = load_csv(csv).expect("loads");
    let r = &d.runs[0];
    assert_eq!(r.force_n, vec![5.0, 6.0]);
    assert_eq!(r.displacement_m, vec![0.1, 0.2]);
    assert_eq!(r.velocity_m_s, Some(vec![1.0, 2.0]));
}

#[test]
fn byte_order_mark_is_accepted() {
    let csv = "\u{feff}time_s,displacement_m,force_n\n0,0,0\n0.0001,0,0\n";
    assert!(load_csv(csv).is_ok());
}

/// A one-run dataset folder at `fs` whose CSV has the given time stamps (zero data).
fn load_times(fs: f64, times: &[f64]) -> Result<Dataset, DatasetError> {
    let mut csv = String::from("time_s,displacement_m,force_n\n");
    for t in times {
        csv.push_str(&format!("{t},0,0\n"));
    }
    let manifest = format!(
        "name = \"d\"\nsample_rate_hz = {fs}\n[[runs]]\nfile = \"runs/x.csv\"\noil_loss = 0.15\n"
    );
    let dir = folder(&manifest, &[("runs/x.csv", &csv)]);
    dataset::load(dir.path())
}

/// `n` stamps of a `fs` logger starting at `t0`, rounded to `resolution_s`.
fn rounded_times(fs: f64, n: usize, t0: f64, resolution_s: f64) -> Vec<f64> {
    (0..n)
        .map(|i| ((t0 + i as f64 / fs) / resolution_s).round() * resolution_s)
        .collect()
}

#[test]
fn three_khz_rounded_to_a_tenth_of_a_millisecond_is_accepted() {
    // Steps of 0.3 and 0.4 ms (20 % step jitter), deviations below 0.05 ms from the grid.
    let times = rounded_times(3000.0, 12_345, 0.0, 1e-4);
    let steps: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(steps.iter().any(|s| (s - 3e-4).abs() < 1e-9));
    assert!(steps.iter().any(|s| (s - 4e-4).abs() < 1e-9));
    let d = load_times(3000.0, &times).expect("rounded stamps accepted");
    let grid = dataset::fit_time_grid(&d.runs[0].time_s, 1.0 / 3000.0);
    assert!((grid.rate_hz() - 3000.0).abs() < 0.01, "{}", grid.rate_hz());
    assert!(!grid.is_exact());
    assert!(
        grid.max_deviation_s <= 0.5e-4 + 1e-9,
        "{}",
        grid.max_deviation_s
    );
    // Stamps are kept as read.
    assert_eq!(d.runs[0].time_s, times);
}

#[test]
fn exact_stamps_fit_exactly() {
    let d = sample_dataset(10_000.0);
    let grid = dataset::fit_time_grid(&d.runs[0].time_s, 1e-4);
    assert!(grid.is_exact(), "{grid:?}");
    assert!((grid.t0_s - 12.345_678_9).abs() < 1e-12);
    assert_eq!(
        grid.max_deviation_sample,
        grid.max_deviation_sample.min(499)
    );
}

#[test]
fn jitter_within_a_quarter_step_is_accepted_beyond_is_refused() {
    // Alternating +-0.2 step: within the rule.
    let ok: Vec<f64> = (0..200)
        .map(|i| (i as f64 + if i % 2 == 0 { 0.2 } else { -0.2 }) * 1e-3)
        .collect();
    assert!(load_times(1000.0, &ok).is_ok());
    // One stamp 0.4 steps late (line 52 = sample 50): refused at its line.
    let mut bad: Vec<f64> = (0..200).map(|i| i as f64 * 1e-3).collect();
    bad[50] += 0.4e-3;
    match load_times(1000.0, &bad) {
        Err(e @ DatasetError::OffGrid { .. }) => {
            let DatasetError::OffGrid {
                line,
                deviation_us,
                limit_us,
                ..
            } = e
            else {
                unreachable!()
            };
            assert_eq!(line, 52);
            assert!((deviation_us - 400.0).abs() < 5.0, "{deviation_us}");
            assert!((limit_us - 250.0).abs() < 0.1, "{limit_us}");
            assert!(
                e.to_string().contains("runs/x.csv:52: column \"time_s\""),
                "{e}"
            );
        }
        other => panic!("expected an off-grid error, got {other:?}"),
    }
}

#[test]
fn missing_samples_are_a_gap_with_their_line() {
    // Rounded 3 kHz stamps with samples 100..103 missing: the step ends at sample 100 of the
    // file, i.e. line 102.
    let mut times = rounded_times(3000.0, 1000, 0.5, 1e-4);
    times.drain(100..103);
    match load_times(3000.0, &times) {
        Err(e @ DatasetError::Gap { .. }) => {
            let DatasetError::Gap { line, missing, .. } = e else {
                unreachable!()
            };
            assert_eq!(line, 102);
            assert_eq!(missing, 3);
            assert!(e.to_string().contains("runs/x.csv:102:"), "{e}");
            assert!(e.to_string().contains("--resample-hz"), "{e}");
        }
        other => panic!("expected a gap, got {other:?}"),
    }
}

#[test]
fn manifest_rate_is_compared_with_the_fitted_rate() {
    // 1.5 % slower clock: every step regular, but the grid says 2955.7 Hz.
    let times: Vec<f64> = (0..3000).map(|i| i as f64 / 2955.7).collect();
    let e = load_times(3000.0, &times).expect_err("rate mismatch");
    assert!(
        matches!(e, DatasetError::RateMismatch { fitted_hz, manifest_hz, .. }
            if (fitted_hz - 2955.7).abs() < 0.01 && manifest_hz == 3000.0),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(msg.contains("2955.7") && msg.contains("3000 Hz"), "{msg}");
    // A 300 Hz file declared as 1000 Hz is a wrong rate, not a gap at line 3.
    let times: Vec<f64> = (0..300).map(|i| i as f64 / 300.0).collect();
    let e = load_times(1000.0, &times).expect_err("wrong rate");
    assert!(matches!(e, DatasetError::RateMismatch { .. }), "{e:?}");
    // Within 1 %: accepted.
    let times: Vec<f64> = (0..3000).map(|i| i as f64 / 2990.0).collect();
    assert!(load_times(3000.0, &times).is_ok());
}

#[test]
fn non_numeric_cell_names_file_line_and_column() {
    let csv = "time_s,displacement_m,force_n\n0,0,1\n0.0001,0,abc\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::NotANumber { line: 3, column, value, .. } if column == "force_n" && value == "abc"),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .ends_with("runs/x.csv:3: column \"force_n\": \"abc\" is not a number"),
        "{e}"
    );
}

#[test]
fn crlf_and_blank_lines_keep_the_lines_an_editor_shows() {
    // Windows line ends: the bad cell is on line 4.
    let csv = "time_s,displacement_m,force_n\r\n0,0,1\r\n0.0001,0,1\r\n0.0002,0,abc\r\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        e.to_string()
            .ends_with("runs/x.csv:4: column \"force_n\": \"abc\" is not a number"),
        "{e}"
    );
    // A blank line before the row: the row's own line, 5.
    let csv = "time_s,displacement_m,force_n\r\n0,0,1\r\n0.0001,0,1\r\n\r\n0.0001,0,1\r\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(e, DatasetError::NonMonotonicTime { line: 5, .. }),
        "{e:?}"
    );
    let csv = "time_s,displacement_m,force_n\r\n0,0,0\r\n0.0001,0,0\r\n";
    assert_eq!(load_csv(csv).expect("CRLF loads").runs[0].len(), 2);
}

#[test]
fn empty_cell_is_not_a_number() {
    let csv = "time_s,displacement_m,force_n\n0,,1\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::NotANumber { line: 2, column, .. } if column == "displacement_m"),
        "{e:?}"
    );
}

#[test]
fn nan_is_refused() {
    let csv = "time_s,displacement_m,force_n\n0,0,1\n0.0001,NaN,1\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::NonFinite { line: 3, column, value, .. } if column == "displacement_m" && value == "NaN"),
        "{e:?}"
    );
}

#[test]
fn infinity_is_refused() {
    let csv = "time_s,displacement_m,force_n,velocity_m_s\n0,0,1,inf\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::NonFinite { line: 2, column, .. } if column == "velocity_m_s"),
        "{e:?}"
    );
}

#[test]
fn missing_required_column_is_refused() {
    let csv = "time_s,displacement_m,force\n0,0,1\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::MissingColumn { column, .. } if column == "force_n"),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .contains("runs/x.csv:1: column \"force_n\" is missing"),
        "{e}"
    );
}

#[test]
fn duplicate_column_is_refused() {
    let csv = "time_s,displacement_m,force_n,force_n\n0,0,1,2\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::DuplicateColumn { column, .. } if column == "force_n"),
        "{e:?}"
    );
}

#[test]
fn non_monotonic_time_is_refused() {
    let csv = "time_s,displacement_m,force_n\n0,0,0\n0.0001,0,0\n0.0001,0,0\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(e, DatasetError::NonMonotonicTime { line: 4, .. }),
        "{e:?}"
    );
    assert!(
        e.to_string().contains("runs/x.csv:4: column \"time_s\""),
        "{e}"
    );
}

#[test]
fn empty_file_is_refused() {
    let e = load_csv("").expect_err("refused");
    assert!(
        matches!(&e, DatasetError::EmptyFile { path } if ends_with(path, "runs/x.csv")),
        "{e:?}"
    );
}

#[test]
fn header_only_file_is_refused() {
    let e = load_csv("time_s,displacement_m,force_n\n").expect_err("refused");
    assert!(
        matches!(e, DatasetError::NoSamples { line: 2, .. }),
        "{e:?}"
    );
}

#[test]
fn wrong_field_count_is_refused() {
    let csv = "time_s,displacement_m,force_n\n0,0,0\n0.0001,0\n";
    let e = load_csv(csv).expect_err("refused");
    assert!(
        matches!(
            e,
            DatasetError::FieldCount {
                line: 3,
                expected: 3,
                found: 2,
                ..
            }
        ),
        "{e:?}"
    );
}

#[test]
fn manifest_naming_a_missing_file_is_refused() {
    let manifest = format!("{MANIFEST_ONE}[[runs]]\nfile = \"runs/nope.csv\"\noil_loss = 0.0\n");
    let e = load_manifest(&manifest).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::MissingRunFile { line: 7, key, file, .. } if key == "runs[1].file" && ends_with(file, "runs/nope.csv")),
        "{e:?}"
    );
    assert!(
        e.to_string().contains("manifest.toml:7: runs[1].file"),
        "{e}"
    );
}

#[test]
fn oil_loss_out_of_range_is_refused() {
    let manifest = MANIFEST_ONE.replace("oil_loss = 0.15", "oil_loss = 15");
    let e = load_manifest(&manifest).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::ManifestValue { line: Some(5), key, .. } if key == "runs[0].oil_loss"),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .contains("manifest.toml:5: runs[0].oil_loss: 15 is outside [0, 1]"),
        "{e}"
    );
}

#[test]
fn negative_oil_loss_is_refused() {
    let manifest = MANIFEST_ONE.replace("oil_loss = 0.15", "oil_loss = -0.1");
    let e = load_manifest(&manifest).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::ManifestValue { key, .. } if key == "runs[0].oil_loss"),
        "{e:?}"
    );
}

#[test]
fn non_positive_sample_rate_is_refused() {
    for rate in ["0.0", "-10000.0", "nan"] {
        let manifest = MANIFEST_ONE.replace("10000.0", rate);
        let e = load_manifest(&manifest).expect_err("refused");
        assert!(
            matches!(&e, DatasetError::ManifestValue { line: Some(2), key, .. } if key == "sample_rate_hz"),
            "{rate}: {e:?}"
        );
    }
}

#[test]
fn duplicate_files_are_refused() {
    let manifest = format!("{MANIFEST_ONE}[[runs]]\nfile = \"./runs/x.csv\"\noil_loss = 0.3\n");
    let e = load_manifest(&manifest).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::DuplicateRunFile { line: Some(7), key, first_key, .. } if key == "runs[1].file" && first_key == "runs[0].file"),
        "{e:?}"
    );
}

#[test]
fn absolute_or_escaping_file_is_refused() {
    for file in ["/tmp/x.csv", "../x.csv", ""] {
        let manifest = MANIFEST_ONE.replace("runs/x.csv", file);
        let e = load_manifest(&manifest).expect_err("refused");
        assert!(
            matches!(&e, DatasetError::ManifestValue { line: Some(4), key, .. } if key == "runs[0].file"),
            "{file}: {e:?}"
        );
    }
}

#[test]
fn non_positive_optional_metadata_is_refused() {
    let manifest = format!("{MANIFEST_ONE}amplitude_m = -0.01\n");
    let e = load_manifest(&manifest).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::ManifestValue { line: Some(6), key, .. } if key == "runs[0].amplitude_m"),
        "{e:?}"
    );
}

#[test]
fn unknown_manifest_key_is_refused() {
    let manifest = format!("{MANIFEST_ONE}oil_los = 0.1\n");
    let e = load_manifest(&manifest).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::ManifestSyntax { line: 6, message, .. } if message.contains("oil_los")),
        "{e:?}"
    );
}

#[test]
fn missing_manifest_key_is_refused() {
    let manifest = MANIFEST_ONE.replace("oil_loss = 0.15\n", "");
    let e = load_manifest(&manifest).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::ManifestSyntax { message, .. } if message.contains("oil_loss")),
        "{e:?}"
    );
}

#[test]
fn toml_syntax_error_has_line_and_column() {
    let manifest = "name = \"d\"\nsample_rate_hz = = 10\n";
    let e = load_manifest(manifest).expect_err("refused");
    assert!(
        matches!(e, DatasetError::ManifestSyntax { line: 2, .. }),
        "{e:?}"
    );
}

#[test]
fn manifest_without_runs_is_refused() {
    let e = load_manifest("name = \"d\"\nsample_rate_hz = 10000.0\n").expect_err("refused");
    assert!(
        matches!(&e, DatasetError::ManifestValue { key, .. } if key == "runs"),
        "{e:?}"
    );
}

#[test]
fn missing_manifest_is_an_io_error() {
    let dir = tempfile::tempdir().expect("temp dir");
    let e = dataset::load(dir.path()).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::Io { path, .. } if ends_with(path, MANIFEST_FILE)),
        "{e:?}"
    );
}

#[test]
fn first_bad_file_in_manifest_order_is_reported() {
    let bad = "time_s,displacement_m,force_n\n0,0,x\n";
    let manifest = "name = \"d\"\nsample_rate_hz = 10000.0\n[[runs]]\nfile = \"a.csv\"\noil_loss = 0\n[[runs]]\nfile = \"b.csv\"\noil_loss = 0\n";
    let dir = folder(manifest, &[("a.csv", bad), ("b.csv", "")]);
    let e = dataset::load(dir.path()).expect_err("refused");
    assert!(
        matches!(&e, DatasetError::NotANumber { path, .. } if ends_with(path, "a.csv")),
        "{e:?}"
    );
}

#[test]
fn write_refuses_what_load_would_refuse() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut d = sample_dataset(10_000.0);
    d.runs[1].force_n[7] = f64::NAN;
    let e = dataset::write(dir.path(), &d).expect_err("NaN refused");
    assert!(
        matches!(&e, DatasetError::NonFinite { line: 9, column, .. } if column == "force_n"),
        "{e:?}"
    );
    let mut d = sample_dataset(10_000.0);
    d.runs[0].displacement_m.pop();
    let e = dataset::write(dir.path(), &d).expect_err("length refused");
    assert!(matches!(e, DatasetError::LengthMismatch { .. }), "{e:?}");
    let mut d = sample_dataset(10_000.0);
    d.runs[2].entry.oil_loss = 1.5;
    assert!(dataset::write(dir.path(), &d).is_err());
    let mut d = sample_dataset(10_000.0);
    d.sample_rate_hz = 9000.0;
    let e = dataset::write(dir.path(), &d).expect_err("wrong rate refused");
    assert!(matches!(e, DatasetError::RateMismatch { .. }), "{e:?}");
    // Nothing was written by the refused calls.
    assert!(!dir.path().join(MANIFEST_FILE).exists());
}

#[test]
fn progress_reports_every_run() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = sample_dataset(10_000.0);
    dataset::write(dir.path(), &d).expect("write");
    let seen = std::sync::Mutex::new(Vec::new());
    dataset::load_with_progress(dir.path(), |p| {
        if let Ok(mut s) = seen.lock() {
            s.push(p);
        }
    })
    .expect("load");
    let seen = seen.into_inner().expect("lock");
    assert_eq!(seen.len(), 3);
    let last = seen.iter().max_by_key(|p| p.runs_done).expect("some");
    assert_eq!((last.runs_done, last.runs_total), (3, 3));
    assert_eq!(
        seen.iter().map(|p| p.samples_done).max(),
        Some(d.total_samples())
    );
}

/// Load speed on 5 million rows (50 runs x 100 000 rows with velocity). Ignored by default
/// because writing the 250 MB of CSV takes a while: `cargo test --release -p nemm-train
/// --test dataset -- --ignored --nocapture`.
#[test]
#[ignore]
fn load_speed_five_million_rows() {
    let fs = 10_000.0;
    let dir = tempfile::tempdir().expect("temp dir");
    let runs = (0..50)
        .map(|i| {
            sine_run(
                &format!("runs/r{i:02}.csv"),
                0.3 * (i % 3) as f64 / 2.0,
                100_000,
                fs,
                true,
            )
        })
        .collect();
    let d = Dataset {
        name: "speed".into(),
        sample_rate_hz: fs,
        condition: None,
        runs,
    };
    let t = std::time::Instant::now();
    dataset::write(dir.path(), &d).expect("write");
    let write_s = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let back = dataset::load(dir.path()).expect("load");
    let load_s = t.elapsed().as_secs_f64();
    eprintln!(
        "5 000 000 rows: write {write_s:.2} s, load {load_s:.2} s ({:.1} M rows/s) on {} threads",
        5.0 / load_s,
        rayon::current_num_threads()
    );
    assert_eq!(back.total_samples(), 5_000_000);
    assert!(back == d, "round trip");
    assert!(load_s < 30.0, "load took {load_s:.1} s");
}

/// A manifest with a `[condition]` table (before the runs), `alpha` for a run's level.
fn condition_manifest(condition: &str) -> String {
    format!(
        "name = \"d\"\nsample_rate_hz = 10000.0\n[condition]\n{condition}\n[[runs]]\nfile = \"runs/x.csv\"\nalpha = 0.5\n"
    )
}

#[test]
fn condition_table_names_the_condition_and_its_priors() {
    let d = load_manifest(&condition_manifest(
        "name = \"gas charge\"\nunit = \"psi\"\nat_alpha_0 = 150.0\nat_alpha_1 = 50.0\nb_fl = \"decreasing\"\nb_pr = \"none\"\nk_pr = \"increasing\"",
    ))
    .expect("loads");
    assert_eq!(d.runs[0].entry.oil_loss, 0.5);
    let c = d.condition();
    assert_eq!(c.name.as_str(), "gas charge");
    assert_eq!(c.unit.as_str(), "psi");
    assert_eq!(c.value_at(0.5), 100.0);
    assert_eq!(
        c.priors,
        nemm_core::Priors {
            b_fl: nemm_core::Direction::Decreasing,
            b_pr: nemm_core::Direction::None,
            k_pr: nemm_core::Direction::Increasing,
        }
    );
    let spec = d.condition.clone().expect("declared");
    assert_eq!(spec.level(0.5), "gas charge 100 psi (alpha 0.5)");
    // Levels print rounded to what they mean: four decimals of alpha, and of the span for a
    // condition value (100 psi: two decimals).
    assert_eq!(
        spec.level(0.4503572053013052),
        "gas charge 104.96 psi (alpha 0.4504)"
    );
    assert_eq!(spec.levels(&[0.0, 0.5, 1.0]), "gas charge 150, 100, 50 psi");
    let oil = dataset::ConditionSpec::default();
    assert_eq!(oil.level(0.4503572053013052), "oil loss 0.4504");
    assert_eq!(oil.level(0.15), "oil loss 0.15");
    assert_eq!(oil.cell(1.0), "1");
    assert_eq!(dataset::alpha_text(0.30000000000000004), "0.3");
    assert_eq!(dataset::alpha_text(-1e-9), "0");
    // Omitted keys take the paper's defaults; a dataset without the table is the oil loss.
    let d = load_manifest(&condition_manifest("name = \"voltage\"")).expect("loads");
    assert_eq!(d.condition().priors, nemm_core::Priors::PAPER);
    assert_eq!(
        load_csv_default().condition(),
        nemm_core::Condition::default()
    );
    // The condition survives writing and loading.
    let dir = tempfile::tempdir().expect("temp dir");
    let mut w = sample_dataset(10_000.0);
    w.condition = Some(spec);
    dataset::write(dir.path(), &w).expect("write");
    assert_eq!(dataset::load(dir.path()).expect("load"), w);
}

fn load_csv_default() -> Dataset {
    load_csv("time_s,displacement_m,force_n\n0,0,0\n0.0001,0,0\n").expect("loads")
}

#[test]
fn bad_condition_values_are_refused_with_file_and_line() {
    for (table, line, key, text) in [
        (
            "name = \"gas\"\nb_pr = \"falling\"",
            5,
            "condition.b_pr",
            "unknown monotonicity direction",
        ),
        (
            "name = \"gas\"\nat_alpha_0 = 2.0\nat_alpha_1 = 2.0",
            6,
            "condition.at_alpha_1",
            "equals at_alpha_0",
        ),
        ("name = \"\"", 4, "condition.name", "0 bytes"),
        (
            "name = \"a condition name that is far too long\"",
            4,
            "condition.name",
            "must be 1 to 32 bytes",
        ),
    ] {
        let e = load_manifest(&condition_manifest(table)).expect_err("refused");
        assert!(
            matches!(&e, DatasetError::ManifestValue { line: Some(l), key: k, .. } if *l == line && k == key),
            "{table}: {e:?}"
        );
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("manifest.toml:{line}: {key}")) && msg.contains(text),
            "{msg}"
        );
    }
    // An unknown key of the table is a syntax error with its line.
    let e = load_manifest(&condition_manifest("name = \"gas\"\ndirection = \"up\""))
        .expect_err("refused");
    assert!(e.to_string().contains("manifest.toml:5"), "{e}");
}

/// The runs of `ds` as `(file, first force)`, to tell two datasets apart.
fn fingerprint(ds: &Dataset) -> Vec<(PathBuf, f64)> {
    ds.runs
        .iter()
        .map(|r| (r.entry.file.clone(), r.force_n[0]))
        .collect()
}

#[test]
fn a_write_that_fails_midway_leaves_the_old_dataset_or_the_new_one_whole() {
    let root = tempfile::tempdir().expect("temp dir");
    let dir = root.path().join("ds");
    let mut old = sample_dataset(1000.0);
    old.runs.truncate(1);
    dataset::write(&dir, &old).expect("write old");
    // The new dataset writes runs/oil00.csv (in place, before) and then runs/zz.csv, where a
    // folder stands in the way; a write in place then left the old manifest over new data.
    let mut new = sample_dataset(1000.0);
    for r in &mut new.runs {
        for f in &mut r.force_n {
            *f += 1.0;
        }
    }
    new.runs
        .push(sine_run("runs/zz.csv", 0.5, 100, 1000.0, false));
    std::fs::create_dir_all(dir.join("runs/zz.csv/inside")).expect("blocking folder");
    let _ = dataset::write(&dir, &new);
    let found = fingerprint(&dataset::load(&dir).expect("a complete dataset"));
    assert!(
        found == fingerprint(&old) || found == fingerprint(&new),
        "a mix of the old and the new dataset: {found:?}"
    );
    // No temporary or old folder is left next to it.
    let names: Vec<_> = std::fs::read_dir(root.path())
        .expect("read")
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("ds")]);
}

#[test]
fn a_rewrite_replaces_the_dataset_as_a_whole_and_keeps_other_files() {
    let root = tempfile::tempdir().expect("temp dir");
    let dir = root.path().join("ds");
    dataset::write(&dir, &sample_dataset(1000.0)).expect("write 3 runs");
    std::fs::write(dir.join("notes.txt"), "mine").expect("notes");
    let mut one = sample_dataset(1000.0);
    one.runs.truncate(1);
    dataset::write(&dir, &one).expect("write 1 run");
    assert_eq!(dataset::load(&dir).expect("load").runs.len(), 1);
    assert!(!dir.join("runs/oil15.csv").exists(), "orphaned run file");
    assert!(!dir.join("oil30.csv").exists(), "orphaned run file");
    assert_eq!(
        std::fs::read_to_string(dir.join("notes.txt")).expect("kept"),
        "mine"
    );
}

#[cfg(unix)]
#[test]
fn a_run_file_linked_out_of_the_folder_is_refused_unread() {
    let outside = tempfile::tempdir().expect("temp dir");
    let secret = outside.path().join("secret.csv");
    std::fs::write(&secret, "top secret first line\n").expect("secret");
    let dir = folder(
        "name = \"x\"\nsample_rate_hz = 1000.0\n\n[[runs]]\nfile = \"runs/a.csv\"\noil_loss = 0.0\n",
        &[],
    );
    std::fs::create_dir_all(dir.path().join("runs")).expect("runs");
    std::os::unix::fs::symlink(&secret, dir.path().join("runs/a.csv")).expect("link");
    let e = dataset::load(dir.path()).expect_err("outside");
    assert!(
        matches!(&e, DatasetError::RunFileOutside { line: 5, key, .. } if key == "runs[0].file"),
        "{e:?}"
    );
    let text = e.to_string();
    assert!(text.contains("outside the dataset folder"), "{text}");
    assert!(!text.contains("top secret"), "{text}");
    // A link that stays inside the folder is followed.
    std::fs::write(
        dir.path().join("runs/real.csv"),
        "time_s,displacement_m,force_n\n0,0,0\n0.001,0,0\n",
    )
    .expect("real");
    std::fs::remove_file(dir.path().join("runs/a.csv")).expect("unlink");
    std::os::unix::fs::symlink("real.csv", dir.path().join("runs/a.csv")).expect("link");
    assert_eq!(dataset::load(dir.path()).expect("inside").runs.len(), 1);
}
