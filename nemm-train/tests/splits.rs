//! The data options and the splits through the `nemm` binary: the options block with the
//! choices made from a 300 Hz dataset, the dataset's options file, the true cause of a split
//! that leaves nothing to train on, a split in time of a single-level dataset, and a
//! comparison in which one variant fails but Table 4 is still written.
use nemm_dataset as dataset;
use nemm_train::config::{Config, CONFIG_FILE, DATA_OPTIONS_FILE};
use nemm_train::report::Report;
use std::path::Path;
use std::process::{Command, Output};
use support::SineRun;

mod support;

fn nemm(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(args)
        .arg(dir)
        .output()
        .expect("run nemm")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Sinusoidal runs, one per level, of `seconds` at `fs`, with the tests' damper force (no
/// nominal velocity in the manifest).
fn write_dataset(dir: &Path, fs: f64, levels: &[f64], seconds: f64) {
    let n = (seconds * fs) as usize;
    let runs = levels
        .iter()
        .enumerate()
        .map(|(k, &alpha)| {
            let file = format!("runs/level{k}.csv");
            let mut run = SineRun::new(&file, alpha, 0.02, 1.5 + 0.25 * k as f64, fs, n).build();
            run.entry.target_velocity_m_s = None;
            run
        })
        .collect();
    dataset::write(dir, &support::dataset("splits", fs, runs)).expect("write the dataset");
}

#[test]
fn options_are_chosen_from_a_300_hz_dataset_printed_and_saved() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let data = tmp.path().join("low-rate");
    write_dataset(&data, 300.0, &[0.0, 0.5, 1.0], 20.0);
    // `data check` and `bench plot` take the data options and print what was chosen.
    let out = nemm(&["data", "check"], &data);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains(
            "cutoff_hz    auto  (chosen from the data: per run: at most min(150 Hz, 0.4 x the \
             300 Hz rate) = 120 Hz"
        ),
        "{stderr}"
    );
    assert!(
        stderr.contains("test set     runs at alpha 0.5  (chosen from the data"),
        "{stderr}"
    );
    let out = nemm(
        &["data", "prepare", "--window-s", "1", "--save-options"],
        &data,
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let saved = std::fs::read_to_string(data.join(DATA_OPTIONS_FILE)).expect("options file");
    // An automatic cut-off is chosen per run again from the same data: not saved.
    assert!(!saved.contains("cutoff_hz"), "{saved}");
    assert!(saved.contains("window_s = 1.0"), "{saved}");
    assert!(saved.contains("test_alphas = [0.5]"), "{saved}");
    // Read back by the next command, and overridden by a flag.
    let out = nemm(&["data", "check", "--cutoff-hz", "50"], &data);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "options file {} read",
            data.join(DATA_OPTIONS_FILE).display()
        )),
        "{stderr}"
    );
    assert!(stderr.contains("cutoff_hz    50 Hz  (given)"), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "window_s     1 s scored + 0.05 s warm-up  ({DATA_OPTIONS_FILE})"
        )),
        "{stderr}"
    );
    let plots = tmp.path().join("plots");
    let out = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(["bench", "plot", "--cutoff-hz", "140", "--out"])
        .arg(&plots)
        .arg(&data)
        .output()
        .expect("run nemm");
    // Whatever the plots make of these runs, the options are resolved first and a cut-off
    // at or above Nyquist is refused by name.
    assert!(
        text(&out.stderr).contains("cutoff_hz    140 Hz  (given)"),
        "{}",
        text(&out.stderr)
    );
    let out = nemm(&["data", "check", "--cutoff-hz", "150"], &data);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr)
            .contains("cutoff_hz: 150 Hz must be positive and below half the sample rate (150 Hz)"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn a_single_level_is_split_in_time_and_the_level_split_names_the_cause() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let data = tmp.path().join("one-level");
    write_dataset(&data, 1000.0, &[0.0, 0.0, 0.0], 12.0);
    let out = nemm(&["data", "prepare", "--test-alpha", "0"], &data);
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains(
            "every run is at the test level 0: nothing left to train on; use --test-tail"
        ),
        "{stderr}"
    );
    // By default: the last 20 % of every run (one level, none to hold out).
    let out = nemm(&["data", "prepare"], &data);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains(
            "test set     the last 20 % of every other run  (chosen from the data: 1 level(s)"
        ),
        "{stderr}"
    );
    assert!(
        stdout.contains("split: test: the last 20 % of every training run"),
        "{stdout}"
    );
    // 12 s runs: 2.4 s test tails of four 0.5 s windows each (after their 0.05 s warm-up).
    let test_line = stdout
        .lines()
        .find(|l| l.starts_with("test "))
        .expect("test row");
    assert_eq!(
        test_line.split_whitespace().take(3).collect::<Vec<_>>(),
        ["test", "3", "12"],
        "{stdout}"
    );
}

/// The SEM's map holds at most 8 levels (nemm-core's `MAX_SEM_ALPHAS`): on nine training
/// levels it bins them into 8 and interpolates between, so Table 4 keeps its reference row
/// beside the EMM-family variants.
#[test]
fn nine_levels_are_binned_into_the_sem_and_table_4_keeps_its_reference() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let data = tmp.path().join("nine-levels");
    let levels: Vec<f64> = (0..9).map(|k| k as f64 * 0.1).collect();
    write_dataset(&data, 2000.0, &levels, 2.5);
    let report = tmp.path().join("report");
    let out = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args([
            "compare",
            "--test-tail",
            "0.25",
            "--window-s",
            "0.2",
            "--warmup-s",
            "0.02",
            "--epochs",
            "1",
            "--max-batches",
            "2",
            "--linear-epochs",
            "1",
            "--batch",
            "4",
            "--hidden",
            "8",
            "--layers",
            "3",
            "--data",
        ])
        .arg(&data)
        .arg("--report")
        .arg(&report)
        .output()
        .expect("run nemm");
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("oil loss levels (9 binned)"), "{stderr}");
    let table = std::fs::read_to_string(report.join("table4.md")).expect("table4.md");
    assert!(table.contains("| SEM | 0."), "{table}");
    assert!(
        table.contains("| 100.0 |"),
        "the SEM is its own reference: {table}"
    );
    assert!(!table.contains("failed"), "{table}");
    assert!(stdout.contains("| SEM | 0."), "{stdout}");
    for v in ["Linear EMM", "NEMM-Light", "NEMM"] {
        assert!(table.contains(&format!("| {v} | 0.")), "{v}: {table}");
    }
    assert!(
        table.contains("Split: test: the last 25 % of every training run"),
        "{table}"
    );
    for blob in ["sem", "linear-emm", "nemm-light", "nemm"] {
        assert!(report.join(format!("{blob}.nemm")).exists(), "{blob}");
    }
    let r: Report = serde_json::from_str(
        &std::fs::read_to_string(report.join("report.json")).expect("report.json"),
    )
    .expect("report");
    assert!(r.failed.is_empty(), "{:?}", r.failed);
    assert_eq!(r.variants.len(), 4);
    // The map: 8 levels, strictly increasing inside the trained range.
    let sem: nemm_core::Model =
        nemm_core::decode(&std::fs::read(report.join("sem.nemm")).expect("sem.nemm"))
            .expect("decode");
    let nemm_core::Body::Sem(map) = &sem.body else {
        panic!("not a SEM")
    };
    assert_eq!(map.alphas.len(), 8);
    assert!(map.alphas.windows(2).all(|w| w[0] < w[1]));
    assert!(map.alphas[0] >= 0.0 && map.alphas[7] <= 0.8 + 1e-6);
    // config.toml records the resolved data options (the cut-off is chosen per run).
    let cfg = Config::load(&report.join(CONFIG_FILE)).expect("config.toml");
    assert_eq!(cfg.data.test_tail, Some(0.25));
    assert_eq!(cfg.data.test_alphas, Some(vec![]));
    assert_eq!(cfg.data.cutoff_hz, None);
    assert_eq!(cfg.data.seed, Some(1));
}
