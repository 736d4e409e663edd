//! Report figures (`nemm_train::report`): every figure is written as a valid PNG of the
//! expected size from example models and a small synthetic dataset; figures of variants that
//! were not trained are left out; only I/O failures are errors.
use nemm_core::testing::example_model;
use nemm_core::ModelKind;
use nemm_dataset::{Dataset, Run};
use nemm_train::data::preprocess::{self, PrepareConfig, Prepared};
use nemm_train::report::RunPredictions;
use nemm_train::report::{evaluate, Report};
use nemm_train::report::{figure_predictions, write_all, write_all_with_reference};
use nemm_train::train::history::EpochStats;
use nemm_train::train::pipeline::TrainedVariant;
use nemm_virtual_bench::config::BenchConfig;
use nemm_virtual_bench::reference::{self, EmmReference};
use nemm_virtual_bench::VirtualBench;
use std::path::Path;

use support::{DamperForce, SineRun};

mod support;

const FS: f64 = 10_000.0;

/// A damper-like run: `x = A w(t) sin(2 pi f t)` with a raised-cosine ramp-in over two
/// periods, force `c(v, alpha) v + k x` (asymmetric damping, a spring term: a hysteresis loop
/// in the force-velocity plane).
fn run(alpha: f64, amplitude: f64, freq: f64, duration_s: f64) -> Run {
    let file = format!("runs/oil{:02.0}_f{freq:.1}.csv", alpha * 100.0);
    let mut s = SineRun::new(
        &file,
        alpha,
        amplitude,
        freq,
        FS,
        (duration_s * FS) as usize,
    );
    s.ramp_periods = 2.0;
    s.force = DamperForce {
        c_rebound_ns_per_m: 2600.0,
        c_compression_ns_per_m: 1500.0,
        softening: 0.6,
        k_n_per_m: 40_000.0,
    };
    s.build()
}

/// Runs at 0 %, 30 % (training) and 15 % (test) oil loss, 10 mm at 8.3 and 16.7 Hz, plus a
/// slow 50 mm run per training level.
fn dataset() -> Dataset {
    let mut runs = Vec::new();
    for alpha in [0.0, 0.3, 0.15] {
        for f in [8.3, 16.7] {
            runs.push(run(alpha, 0.010, f, 0.6));
        }
        if alpha != 0.15 {
            runs.push(run(alpha, 0.050, 1.0, 1.0));
        }
    }
    support::dataset("figures test", FS, runs)
}

fn prepared(ds: &Dataset) -> Prepared {
    prepared_with_test(ds, &[0.15])
}

fn prepared_with_test(ds: &Dataset, test_alphas: &[f64]) -> Prepared {
    let mut cfg = PrepareConfig::default();
    cfg.sequences.window_s = 0.1;
    cfg.sequences.warmup_s = 0.01;
    cfg.split.test_alphas = test_alphas.to_vec();
    preprocess::prepare(ds, &cfg).expect("prepare")
}

fn history(n: usize, start: f64) -> Vec<EpochStats> {
    (1..=n)
        .map(|e| EpochStats {
            epoch: e,
            train_mse: start / e as f64,
            diff: 0.0,
            physics: 1e-4 / e as f64,
            val_rmse: (start / e as f64).sqrt(),
            seconds: 0.1,
            violations: None,
            held: 0,
        })
        .collect()
}

fn trained(kinds: &[(ModelKind, ModelKind)]) -> Vec<TrainedVariant> {
    kinds
        .iter()
        .map(|&(variant, kind)| {
            let model = example_model(kind, 8, 3).expect("example model");
            let history = if variant == ModelKind::Sem {
                vec![]
            } else {
                history(4, 0.01)
            };
            TrainedVariant {
                variant,
                model: Box::new(model),
                val_rmse: history.last().map_or(0.05, |h| h.val_rmse),
                history,
                stop: None,
                kept_epoch: None,
                seconds: 1.0,
            }
        })
        .collect()
}

fn all_four() -> Vec<TrainedVariant> {
    trained(&[
        (ModelKind::Sem, ModelKind::Sem),
        (ModelKind::LinearEmm, ModelKind::LinearEmm),
        (ModelKind::NemmLight, ModelKind::NemmLight),
        (ModelKind::Nemm, ModelKind::Nemm),
    ])
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// Checks the PNG structure (signature, chunk lengths and CRCs, IHDR first, IDAT, IEND last)
/// and returns `(width, height, bit depth, colour type)` from the IHDR.
fn png_header(path: &Path) -> (u32, u32, u8, u8) {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(
        &b[..8],
        b"\x89PNG\r\n\x1a\n",
        "{}: signature",
        path.display()
    );
    let mut at = 8;
    let mut chunks = Vec::new();
    while at + 12 <= b.len() {
        let len = u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]) as usize;
        let kind = &b[at + 4..at + 8];
        let end = at + 8 + len;
        assert!(end + 4 <= b.len(), "{}: truncated chunk", path.display());
        let crc = u32::from_be_bytes([b[end], b[end + 1], b[end + 2], b[end + 3]]);
        assert_eq!(crc, crc32(&b[at + 4..end]), "{}: CRC", path.display());
        chunks.push((String::from_utf8_lossy(kind).to_string(), at + 8, len));
        at = end + 4;
    }
    assert_eq!(at, b.len(), "{}: trailing bytes", path.display());
    assert_eq!(chunks.first().map(|c| c.0.as_str()), Some("IHDR"));
    assert_eq!(chunks.last().map(|c| c.0.as_str()), Some("IEND"));
    assert!(chunks.iter().any(|c| c.0 == "IDAT"));
    let (_, s, len) = chunks[0];
    assert_eq!(len, 13);
    let w = u32::from_be_bytes([b[s], b[s + 1], b[s + 2], b[s + 3]]);
    let h = u32::from_be_bytes([b[s + 4], b[s + 5], b[s + 6], b[s + 7]]);
    (w, h, b[s + 8], b[s + 9])
}

fn pngs_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .expect("read dir")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".png"))
        .collect();
    v.sort();
    v
}

#[test]
fn all_figures_are_written_as_pngs_of_the_expected_size() {
    let ds = dataset();
    let prep = prepared(&ds);
    let tr = all_four();
    let report: Report = evaluate(&tr, &prep).expect("report");
    let dir = tempfile::tempdir().expect("tempdir");
    let t = std::time::Instant::now();
    write_all(
        &tr,
        &ds,
        &prep,
        &report,
        &figure_predictions(&tr, &prep).expect("predictions"),
        dir.path(),
    )
    .expect("figures");
    let secs = t.elapsed().as_secs_f64();
    // (file, width, panel rows x panel height): + 40 px title + footer (14 + 21 px per
    // line; the number of lines depends on the wrapping).
    let expected = [
        ("fig11_b_pr.png", 2 * 680, 480),
        ("fig12_k_pr.png", 2 * 680, 2 * 480),
        ("fig7_loops.png", 3 * 540, 3 * 410),
        ("fig8_b_fl.png", 2 * 680, 2 * 480),
        ("fig8_b_fl_nemm-light.png", 2 * 680, 2 * 480),
        ("loops_all_variants.png", 2 * 600, 2 * 440),
        ("training_curves.png", 3 * 620, 460),
    ];
    let mut names: Vec<String> = expected.iter().map(|e| e.0.to_string()).collect();
    names.sort();
    assert_eq!(
        pngs_in(dir.path()),
        names,
        "no temporary files left, nothing missing"
    );
    for (name, w, panels_h) in expected {
        let (pw, ph, depth, colour) = png_header(&dir.path().join(name));
        assert_eq!(pw, w, "{name}: width");
        let footer = ph.checked_sub(panels_h + 40 + 14).expect("footer");
        assert!(
            footer % 21 == 0 && (21..=6 * 21).contains(&footer),
            "{name}: height {ph}"
        );
        assert_eq!((depth, colour), (8, 2), "{name}: 8-bit RGB");
    }
    // Generous bound (debug builds, loaded CI machines); release takes well under a second.
    assert!(secs < 60.0, "figures took {secs:.1} s");
}

#[test]
fn figures_of_untrained_variants_are_left_out_and_missing_data_is_not_an_error() {
    let ds = dataset();
    let prep = prepared(&ds);
    // Only the SEM: no EMM figures, no training curves (no history).
    let sem = trained(&[(ModelKind::Sem, ModelKind::Sem)]);
    let report = evaluate(&sem, &prep).expect("report");
    let dir = tempfile::tempdir().expect("tempdir");
    write_all(
        &sem,
        &ds,
        &prep,
        &report,
        &figure_predictions(&sem, &prep).expect("predictions"),
        dir.path(),
    )
    .expect("figures");
    assert_eq!(
        pngs_in(dir.path()),
        vec!["fig7_loops.png", "loops_all_variants.png"]
    );
    // NEMM-Light only, on a dataset without 10 mm runs and without a test level: the loop
    // figures fall back to what exists, the b_fl figure is there, nothing fails.
    let mut slow = dataset();
    slow.runs.retain(|r| r.entry.amplitude_m == Some(0.050));
    let prep = prepared_with_test(&slow, &[]);
    let light = trained(&[(ModelKind::NemmLight, ModelKind::NemmLight)]);
    let report = evaluate(&light, &prep).expect("report");
    let dir = tempfile::tempdir().expect("tempdir");
    write_all(
        &light,
        &slow,
        &prep,
        &report,
        &figure_predictions(&light, &prep).expect("predictions"),
        dir.path(),
    )
    .expect("figures");
    let names = pngs_in(dir.path());
    assert!(
        names.contains(&"fig8_b_fl_nemm-light.png".to_string()),
        "{names:?}"
    );
    assert!(
        names.contains(&"training_curves.png".to_string()),
        "{names:?}"
    );
    assert!(!names
        .iter()
        .any(|n| n.starts_with("fig11") || n.starts_with("fig12")));
    for n in &names {
        png_header(&dir.path().join(n));
    }
    // Nothing at all: no figures, no error.
    let dir = tempfile::tempdir().expect("tempdir");
    write_all(
        &[],
        &slow,
        &prep,
        &report,
        &RunPredictions::default(),
        dir.path(),
    )
    .expect("figures");
    assert!(pngs_in(dir.path()).is_empty());
}

#[test]
fn an_unwritable_report_folder_is_an_error() {
    let ds = dataset();
    let prep = prepared(&ds);
    let tr = all_four();
    let report = evaluate(&tr, &prep).expect("report");
    let dir = tempfile::tempdir().expect("tempdir");
    // A file where the folder should be.
    let blocker = dir.path().join("figs");
    std::fs::write(&blocker, b"not a folder").expect("write");
    assert!(write_all(
        &tr,
        &ds,
        &prep,
        &report,
        &figure_predictions(&tr, &prep).expect("predictions"),
        &blocker
    )
    .is_err());
}

#[test]
fn the_report_breaks_the_test_error_down_by_held_out_run() {
    let ds = dataset();
    let prep = prepared(&ds);
    let report = evaluate(&all_four(), &prep).expect("report");
    // One row per held-out run (the two 15 % runs), in dataset order, with the estimated
    // excitation.
    let files: Vec<&str> = report.test_runs.iter().map(|r| r.file.as_str()).collect();
    assert_eq!(files, ["runs/oil15_f8.3.csv", "runs/oil15_f16.7.csv"]);
    for (r, f) in report.test_runs.iter().zip([8.3, 16.7]) {
        assert_eq!(r.alpha, 0.15);
        assert!((r.amplitude_m - 0.010).abs() < 5e-4, "{}", r.amplitude_m);
        assert!((r.frequency_hz.expect("frequency") - f).abs() < 0.2);
        assert_eq!(r.rmse.len(), 4);
    }
    // The rows add up to the test set: every scored sample once, and each variant's overall
    // RMSE is the sample-weighted mean square of its rows.
    let scored: usize = report.test_runs.iter().map(|r| r.samples).sum();
    assert_eq!(scored, prep.test.len() * prep.scored_samples);
    for (key, v) in &report.variants {
        let se: f64 = report
            .test_runs
            .iter()
            .map(|r| r.rmse[key].powi(2) * r.samples as f64)
            .sum();
        let overall = (se / scored as f64).sqrt();
        assert!(
            (overall - v.rmse).abs() <= 1e-12 * v.rmse,
            "{key}: {overall} vs {}",
            v.rmse
        );
    }
    // Markdown: a row per run in newtons, and the shares of the NEMM's squared error add up
    // to 100 %.
    let md = nemm_train::report::test_runs_markdown(&report);
    let rows: Vec<&str> = md.lines().filter(|l| l.starts_with("| runs/")).collect();
    assert_eq!(rows.len(), 2, "{md}");
    let share: f64 = rows
        .iter()
        .map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            cells[cells.len() - 2]
                .trim_end_matches(" %")
                .parse::<f64>()
                .expect("share")
        })
        .sum();
    assert!((share - 100.0).abs() < 0.2, "{share}\n{md}");
    let nemm_n = report.test_runs[0].rmse["nemm"] * report.force_scale_n;
    assert!(rows[0].contains(&format!("{nemm_n:.1}")), "{}", rows[0]);
    // report.json keeps it, and reports written before it existed still load.
    let json = serde_json::to_string(&report).expect("json");
    let back: Report = serde_json::from_str(&json).expect("parse");
    // (serde_json may round the last bit of an f64)
    assert_eq!(back.test_runs.len(), report.test_runs.len());
    for (b, r) in back.test_runs.iter().zip(&report.test_runs) {
        assert_eq!((&b.file, b.samples), (&r.file, r.samples));
        assert!((b.amplitude_m - r.amplitude_m).abs() <= 1e-15);
        for (key, e) in &r.rmse {
            assert!((b.rmse[key] - e).abs() <= 1e-15 * e, "{key}");
        }
    }
    let mut old: serde_json::Value = serde_json::from_str(&json).expect("value");
    old.as_object_mut().expect("object").remove("test_runs");
    let old: Report = serde_json::from_value(old).expect("old report");
    assert!(old.test_runs.is_empty());
    assert!(nemm_train::report::test_runs_markdown(&old).is_empty());
}

#[test]
fn coefficient_figures_draw_the_bench_reference_on_bench_data() {
    let ds = dataset();
    let prep = prepared(&ds);
    let tr = all_four();
    let report: Report = evaluate(&tr, &prep).expect("report");
    let predictions = figure_predictions(&tr, &prep).expect("predictions");
    let r = EmmReference::of(&VirtualBench::new(BenchConfig::default())).expect("reference");
    let plain = tempfile::tempdir().expect("tempdir");
    let with = tempfile::tempdir().expect("tempdir");
    write_all(&tr, &ds, &prep, &report, &predictions, plain.path()).expect("figures");
    write_all_with_reference(
        &tr,
        &ds,
        &prep,
        &report,
        &predictions,
        Some(&r),
        with.path(),
    )
    .expect("figures");
    assert_eq!(pngs_in(plain.path()), pngs_in(with.path()));
    for name in ["fig8_b_fl.png", "fig11_b_pr.png", "fig12_k_pr.png"] {
        let (w0, h0, _, _) = png_header(&plain.path().join(name));
        let (w1, h1, d, c) = png_header(&with.path().join(name));
        assert_eq!((w1, d, c), (w0, 8, 2), "{name}");
        // The caption gains the reference lines.
        assert!(h1 > h0 && (h1 - h0) % 21 == 0, "{name}: {h0} -> {h1}");
    }
    // The other figures do not change.
    for name in ["fig7_loops.png", "training_curves.png"] {
        let a = std::fs::read(plain.path().join(name)).expect("png");
        let b = std::fs::read(with.path().join(name)).expect("png");
        assert_eq!(a, b, "{name}");
    }
    // The report's comparison: every pair, the bench's k_pr falling.
    let nemm = tr
        .iter()
        .find(|t| t.variant == ModelKind::Nemm)
        .expect("nemm");
    let cmp = nemm_train::report::compare_reference(&nemm.model, &r);
    assert_eq!(cmp.rows.len(), 4 + 1 + 6, "{cmp:?}");
    for row in cmp.rows.iter().filter(|r| r.learned.starts_with("k_pr")) {
        assert!(row.reference_change < -0.5, "{row:?}");
        assert!(
            row.learned_from.is_finite() && row.ratio.is_finite(),
            "{row:?}"
        );
    }
    assert!(cmp
        .markdown()
        .contains("| k_pr(x_pr = 0) | k_pr, both chambers |"));
}

#[test]
fn a_generated_dataset_names_its_bench_and_other_data_have_no_reference() {
    let dir = tempfile::tempdir().expect("tempdir");
    assert!(reference::for_dataset(dir.path()).expect("none").is_none());
    nemm_train::cli::bench::write_bench_config(&BenchConfig::default(), dir.path()).expect("write");
    let r = reference::for_dataset(dir.path())
        .expect("read")
        .expect("bench data");
    assert_eq!(r.bench().config(), &BenchConfig::default());
    std::fs::write(dir.path().join(reference::BENCH_CONFIG_FILE), "name = 1").expect("write");
    assert!(reference::for_dataset(dir.path()).is_err());
}
