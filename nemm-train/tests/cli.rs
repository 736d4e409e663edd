//! The trainer end to end through the `nemm` binary, as a calibration engineer uses it: a
//! small virtual bench (`bench config`, `bench generate`), `compare` (Table 4, `report.json`
//! in the documented schema, one blob per variant, figures), `train` with checkpoints, `export`
//! from the checkpoint, `inspect`, a `sweep` run as separate processes and collected, and the
//! exported blob run through nemm-core's estimator against the trainer's own test RMSE.
use nemm_core::{Estimator, EstimatorConfig, Model, ModelKind, Sample};
use nemm_dataset as dataset;
use nemm_train::config::{Config, CONFIG_FILE};
use nemm_train::data::preprocess;
use nemm_train::report::Report;
use std::ffi::OsStr;
use std::path::Path;
use std::process::{Command, Output};

mod support;
use support::small_bench;

/// A budget of seconds: short windows, two epochs of two batches per stage, small scalers.
const BUDGET: &[&str] = &[
    "--window-s",
    "0.1",
    "--warmup-s",
    "0.02",
    "--epochs",
    "2",
    "--max-batches",
    "2",
    "--linear-epochs",
    "2",
    "--batch",
    "4",
    "--hidden",
    "8",
    "--layers",
    "3",
];

/// A `nemm` command line.
struct Nemm(Command);

impl Nemm {
    fn new(args: &[&str]) -> Self {
        let mut c = Command::new(env!("CARGO_BIN_EXE_nemm"));
        c.args(args);
        Nemm(c)
    }

    fn arg(mut self, a: impl AsRef<OsStr>) -> Self {
        self.0.arg(a);
        self
    }

    fn args(mut self, a: &[&str]) -> Self {
        self.0.args(a);
        self
    }

    /// Adds the seconds-long training budget.
    fn budget(mut self) -> Self {
        self.0.args(BUDGET);
        self
    }

    fn output(mut self) -> Output {
        self.0.output().expect("run nemm")
    }

    /// Runs it, expects it to fail, and returns its error output.
    fn fails(self) -> String {
        let out = self.output();
        assert!(!out.status.success(), "expected a failure");
        String::from_utf8_lossy(&out.stderr).into_owned()
    }

    /// Runs it and returns its standard output; fails the test with its error output.
    fn ok(mut self) -> String {
        let what = format!("{:?}", self.0);
        let out = self.0.output().expect("run nemm");
        assert!(
            out.status.success(),
            "{what} failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }
}

fn decode_file(path: &Path) -> Model {
    let blob = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    nemm_core::decode(&blob).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn no_temp_files(dir: &Path) {
    for e in std::fs::read_dir(dir).expect("read dir").flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        assert!(!name.ends_with(".tmp"), "temporary file left: {name}");
    }
}

#[test]
fn bench_generate_runs_the_programme_at_the_given_levels() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path();
    let config = Nemm::new(&["bench", "config"]).ok();
    let small: String = config
        .lines()
        .map(|line| match line.split('=').next().unwrap_or("").trim() {
            "amplitudes_m" => "amplitudes_m = [0.01]".to_string(),
            "peak_velocities_m_s" => "peak_velocities_m_s = [0.262]".to_string(),
            "max_ramp_s" => "max_ramp_s = 0.1".to_string(),
            "min_steady_s" => "min_steady_s = 0.5".to_string(),
            _ => line.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\n");
    let toml = dir.join("small.toml");
    std::fs::write(&toml, small).expect("write config");
    let data = dir.join("levels");
    Nemm::new(&["bench", "generate", "--levels", "0,0.075,0.3", "--config"])
        .arg(&toml)
        .arg("--out")
        .arg(&data)
        .ok();
    let ds = dataset::load(&data).expect("load the generated bench");
    let mut levels: Vec<(String, f64)> = ds
        .runs
        .iter()
        .map(|r| (r.entry.file.display().to_string(), r.entry.oil_loss))
        .collect();
    levels.sort_by(|a, b| a.1.total_cmp(&b.1));
    assert_eq!(
        levels,
        [
            ("runs/oil00_a010_v0262.csv".to_string(), 0.0),
            ("runs/oil08_a010_v0262.csv".to_string(), 0.075),
            ("runs/oil30_a010_v0262.csv".to_string(), 0.3),
        ]
    );
    // Two levels that would write the same files are refused before any simulation.
    let stderr = Nemm::new(&["bench", "generate", "--levels", "0,0.15,0.152", "--out"])
        .arg(dir.join("refused"))
        .fails();
    assert!(
        stderr.contains("--levels") && stderr.contains("oil15_"),
        "{stderr}"
    );
    assert!(!dir.join("refused").exists());
}

#[test]
fn the_cli_trains_evaluates_exports_and_sweeps() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path();
    let data = small_bench(dir);

    // Windows so long that no run has one left for validation: refused up front, saying why.
    let stderr = Nemm::new(&["compare", "--window-s", "1.0", "--data"])
        .arg(&data)
        .arg("--report")
        .arg(dir.join("refused"))
        .fails();
    assert!(
        stderr.contains("error: no validation windows") && stderr.contains("--window-s"),
        "{stderr}"
    );

    // compare: Table 4, report.json in the documented schema, blobs and figures.
    let report_dir = dir.join("report");
    let stdout = Nemm::new(&["compare", "--data"])
        .arg(&data)
        .arg("--report")
        .arg(&report_dir)
        .budget()
        .ok();
    assert!(stdout.contains("| NEMM |"), "{stdout}");
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(report_dir.join("report.json")).expect("report.json"),
    )
    .expect("json");
    assert_eq!(json["test_alpha"], 0.15);
    let force_scale = json["force_scale_n"].as_f64().expect("force_scale_n");
    assert!(force_scale > 100.0, "{force_scale}");
    for key in ["sem", "linear_emm", "nemm_light", "nemm"] {
        let v = &json["variants"][key];
        let (rmse, rmse_n) = (
            v["rmse"].as_f64().expect("rmse"),
            v["rmse_n"].as_f64().expect("rmse_n"),
        );
        assert!(rmse.is_finite() && rmse > 0.0, "{key}: {rmse}");
        assert!(
            (rmse_n - rmse * force_scale).abs() <= 1e-9 * rmse_n,
            "{key}"
        );
    }
    let report: Report = serde_json::from_value(json).expect("Report");
    assert_eq!(report.test_runs.len(), 2, "the two 15 % runs");
    let table = std::fs::read_to_string(report_dir.join("table4.md")).expect("table4.md");
    for row in ["| SEM |", "| Linear EMM |", "| NEMM-Light |", "| NEMM |"] {
        assert!(table.contains(row), "{row} missing:\n{table}");
    }
    assert!(table.contains("Test RMSE per held-out run"), "{table}");
    // Whole-run errors per level and run (training levels included), the identifiability
    // tables in identify.md, linked from table4.md, and the same in report.json.
    for part in [
        "Whole-run RMSE at the label per level",
        "| 0 | train | 2 |",
        "| 0.15 | test | 2 |",
        "| 10 | 16.7 | 0.3 | train | runs/oil30_a010_v1048.csv |",
        "[identify.md](identify.md)",
    ] {
        assert!(table.contains(part), "{part} missing:\n{table}");
    }
    let identify_md = std::fs::read_to_string(report_dir.join("identify.md")).expect("identify.md");
    for part in [
        "### NEMM (grid 0 to 0.3",
        "### NEMM-Light",
        "### Linear EMM",
        "### SEM",
    ] {
        assert!(identify_md.contains(part), "{part} missing:\n{identify_md}");
    }
    let id = report.identify.as_ref().expect("report.json: identify");
    assert_eq!(id.runs.len(), 6, "every run the split uses");
    assert_eq!(id.force_scale_n, report.force_scale_n);
    for key in ["sem", "linear_emm", "nemm_light", "nemm"] {
        let v = &id.variants[key];
        assert_eq!(
            (v.grid.len(), v.fits.len(), v.levels.len()),
            (31, 6, 3),
            "{key}"
        );
        for (l, role) in v.levels.iter().zip(["train", "test", "train"]) {
            assert_eq!((l.role.as_str(), l.runs), (role, 2), "{key}");
            assert!(l.rmse.is_finite() && l.rmse > 0.0, "{key}: {l:?}");
            assert!((l.rmse_n - l.rmse * id.force_scale_n).abs() <= 1e-9 * l.rmse_n);
            assert!(l.within <= l.runs && l.flat <= l.runs);
        }
        let order = v.order.as_ref().expect("three levels");
        assert_eq!(order.conditions, 2, "{key}");
        for fit in &v.fits {
            assert!(fit.rmse_label_n.is_finite() && fit.rmse_best_n <= fit.rmse_label_n + 1e-9);
        }
    }
    assert_eq!(
        id.variants["linear_emm"].fits[0].best, None,
        "the Linear EMM is flat"
    );
    for (file, kind) in [
        ("sem.nemm", ModelKind::Sem),
        ("linear-emm.nemm", ModelKind::LinearEmm),
        ("nemm-light.nemm", ModelKind::NemmLight),
        ("nemm.nemm", ModelKind::Nemm),
    ] {
        assert_eq!(decode_file(&report_dir.join(file)).kind(), kind, "{file}");
    }
    // The degradation signature: each model's difference loop against the measured one, per
    // condition at both lossy levels (2 conditions x 2 levels), in table4.md, signature.md,
    // report.json and a figure.
    let sig = report.signature.as_ref().expect("report.json: signature");
    assert_eq!(sig.rows.len(), 4, "{sig:?}");
    for row in &sig.rows {
        assert!(row.alpha > 0.0 && row.measured_rms_n > 0.0, "{row:?}");
        assert!((0.0..=1.0).contains(&row.compression_share), "{row:?}");
        for key in ["sem", "linear_emm", "nemm_light", "nemm"] {
            let e = row.rel_error[key];
            assert!(e.is_finite() && e >= 0.0, "{key}: {row:?}");
        }
        // The Linear EMM does not depend on the level: its difference loop is only that of
        // the two runs' slightly different measured velocities, so its error is that of
        // predicting no change.
        assert!(
            row.model_rms_n["linear_emm"] < 1e-3 * row.measured_rms_n,
            "{row:?}"
        );
        assert!((row.rel_error["linear_emm"] - 1.0).abs() < 1e-3, "{row:?}");
    }
    let signature_md =
        std::fs::read_to_string(report_dir.join("signature.md")).expect("signature.md");
    assert!(
        signature_md.contains("| 0.3 | 10 | 1.048 |"),
        "{signature_md}"
    );
    assert!(table.contains("Degradation signature"), "{table}");
    for fig in [
        "fig7_loops.png",
        "fig8_b_fl.png",
        "training_curves.png",
        "difference_loops_models.png",
    ] {
        assert!(report_dir.join(fig).is_file(), "{fig}");
    }
    no_temp_files(&report_dir);

    // train with checkpoints, export the same model from the checkpoint, inspect it.
    let model = dir.join("model.nemm");
    let ckpt = dir.join("ckpt");
    let train_report = dir.join("train-report");
    Nemm::new(&["train", "--variant", "nemm", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&model)
        .arg("--checkpoint")
        .arg(&ckpt)
        .arg("--report")
        .arg(&train_report)
        .budget()
        .ok();
    assert_eq!(decode_file(&model).kind(), ModelKind::Nemm);
    no_temp_files(dir);
    let exported = dir.join("exported.nemm");
    Nemm::new(&["export", "--checkpoint"])
        .arg(ckpt.join("nemm"))
        .arg("--out")
        .arg(&exported)
        .ok();
    // The same model; each blob's provenance names the command that wrote it.
    let (mut from_ckpt, mut trained) = (decode_file(&exported), decode_file(&model));
    assert!(from_ckpt.provenance.command.starts_with("nemm export"));
    assert!(trained.provenance.command.starts_with("nemm train"));
    from_ckpt.provenance = Default::default();
    trained.provenance = Default::default();
    assert_eq!(
        from_ckpt, trained,
        "export from the checkpoint writes the trained model"
    );
    // A folder without a checkpoint (the SEM's, say) is refused with what to do instead.
    let err = Nemm::new(&["export", "--checkpoint"])
        .arg(ckpt.join("sem"))
        .arg("--out")
        .arg(dir.join("sem-export.nemm"))
        .fails();
    assert!(
        err.contains("frame.json") && err.contains("nemm train --variant sem --out"),
        "{err}"
    );
    assert!(!dir.join("sem-export.nemm").exists());
    // Interrupted after one epoch per stage (`--session-epochs`, as a cluster job with a
    // wall-time limit) and resumed from the checkpoints: the same model, byte for byte.
    let ckpt2 = dir.join("ckpt2");
    let resumed = dir.join("resumed.nemm");
    let session = |extra: &[&str]| {
        Nemm::new(&["train", "--variant", "nemm", "--data"])
            .arg(&data)
            .arg("--out")
            .arg(&resumed)
            .arg("--checkpoint")
            .arg(&ckpt2)
            .budget()
            .0
            .args(extra)
            .output()
            .expect("run nemm")
    };
    // Session 1 ends in the Linear EMM stage, session 2 finishes it and ends in the NEMM
    // stage, session 3 finishes; nothing is exported before.
    for (k, extra) in [
        &["--session-epochs", "1"][..],
        &["--resume", "--session-epochs", "1"],
        &["--resume"],
    ]
    .into_iter()
    .enumerate()
    {
        let out = session(extra);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "session {}: {stderr}", k + 1);
        if k < 2 {
            let stage = ["`linear-emm`", "`nemm`"][k];
            assert!(
                stderr.contains(&format!("session budget used in stage {stage}"))
                    && stderr.contains("continue with --resume"),
                "session {}: {stderr}",
                k + 1
            );
            assert!(!resumed.exists(), "session {} exported a model", k + 1);
        }
        if k > 0 {
            assert!(stderr.contains("resuming after epoch 1"), "{stderr}");
        }
    }
    // The same model (the provenance records each run's own command line).
    let without_provenance = |path: &Path| {
        let mut m = decode_file(path);
        m.provenance = Default::default();
        m
    };
    assert_eq!(
        without_provenance(&resumed),
        without_provenance(&model),
        "an interrupted and resumed run gives the uninterrupted model"
    );
    let inspect = Nemm::new(&["inspect"]).arg(&exported).ok();
    assert!(inspect.contains("kind:            nemm"), "{inspect}");
    assert!(inspect.contains("CRC-32:          ok"), "{inspect}");
    assert!(inspect.contains("stored tables:   none"), "{inspect}");
    assert!(inspect.contains("static force:    none"), "{inspect}");

    // The same export with fast-path tables at two levels: the blob stores them (the model
    // part unchanged), an estimator at one of them reads them, `inspect` lists them.
    let with_tables = dir.join("tables.nemm");
    Nemm::new(&["export", "--checkpoint"])
        .arg(ckpt.join("nemm"))
        .arg("--out")
        .arg(&with_tables)
        .arg("--tables-alpha")
        .arg("0.1,0.2")
        .arg("--tables-segments")
        .arg("256")
        .ok();
    let blob = std::fs::read(&with_tables).expect("the blob");
    let (tabled, index): (nemm_core::Model, _) =
        nemm_core::decode_with_tables(&blob).expect("the blob decodes");
    assert_eq!(tabled.body, decode_file(&exported).body);
    let levels: Vec<(f32, u32)> = index.levels.iter().map(|l| (l.alpha, l.segments)).collect();
    assert_eq!(levels, [(0.1, 256), (0.2, 256)]);
    let cfg = nemm_core::EstimatorConfig {
        mode: nemm_core::EvalMode::Table(nemm_core::TableConfig::new(1e-4)),
        ..nemm_core::EstimatorConfig::new(0.2)
    };
    let mut est: Box<nemm_core::Estimator> = Box::new(nemm_core::Estimator::empty());
    est.load_with_tables(&tabled, cfg, &index, &blob)
        .expect("the estimator loads");
    assert_eq!(est.table_origin(), nemm_core::TableOrigin::Stored);
    let inspect = Nemm::new(&["inspect"]).arg(&with_tables).ok();
    assert!(
        inspect.contains("stored tables:   alpha 0.1, 256 segments")
            && inspect.contains("stored tables:   alpha 0.2, 256 segments"),
        "{inspect}"
    );

    // The exported blob through nemm-core's estimator matches the trainer's rollout sample by
    // sample (1e-5 of the force scale) and reproduces its reported test RMSE.
    let trained: Report = serde_json::from_str(
        &std::fs::read_to_string(train_report.join("report.json")).expect("report.json"),
    )
    .expect("train report");
    // The preprocessing of `nemm train` with the budget's windows (its seed picks the
    // validation windows, and so the training set's force scale).
    // `nemm train --report` saved the effective configuration, which reproduces it.
    let saved = Config::load(&train_report.join(CONFIG_FILE)).expect("config.toml");
    assert_eq!(
        (saved.data.window_s, saved.data.warmup_s),
        (Some(0.1), Some(0.02))
    );
    assert_eq!(saved.data.dir, data);
    assert_eq!(saved.model.variant, ModelKind::Nemm);
    let cfg = saved.data.prepare_config();
    // By default the trainer preprocesses as the library (and `nemm data prepare`) does.
    assert_eq!(
        Config::default().data.prepare_config(),
        preprocess::PrepareConfig::default()
    );
    let prepared = preprocess::prepare(&dataset::load(&data).expect("load"), &cfg).expect("prep");
    let core_model = decode_file(&exported);
    let inputs: Vec<nemm_train::train::eval::Input<'_>> = prepared
        .test
        .iter()
        .map(nemm_train::train::eval::input_of)
        .collect();
    let trainer =
        nemm_train::train::eval::predict(&core_model, &inputs, prepared.dt_s).expect("trainer");
    let fs = prepared.scales.force_n;
    let (mut se, mut n, mut worst, mut flagged) = (0.0f64, 0usize, 0.0f64, 0u32);
    for (seq, ys) in prepared.test.iter().zip(&trainer) {
        let mut est =
            Estimator::new(&core_model, EstimatorConfig::new(seq.alpha)).expect("estimator");
        for (i, ((&v, &f), &yt)) in seq
            .velocity_m_s
            .iter()
            .zip(&seq.force_n)
            .zip(ys)
            .enumerate()
        {
            let y = est.step(Sample::new(v)).unwrap().force_n as f64;
            worst = worst.max((y - yt).abs() / fs);
            if i >= prepared.warmup_samples {
                se += ((y - f as f64) / fs).powi(2);
                n += 1;
            }
        }
        let d = est.diagnostics();
        flagged += d.held_samples + d.resets;
    }
    assert_eq!(flagged, 0, "no input held, no divergence reset");
    assert!(
        worst <= 1e-5,
        "max |nemm-core - trainer| = {worst:e} of the force scale"
    );
    let core_rmse = (se / n as f64).sqrt();
    let trainer_rmse = trained.variants["nemm"].rmse;
    assert!(
        (core_rmse - trainer_rmse).abs() <= 1e-5 * trainer_rmse.max(1.0),
        "nemm-core {core_rmse} against the trainer's {trainer_rmse}"
    );

    // A damaged blob is refused with a readable error naming the file.
    let bytes = std::fs::read(&exported).expect("exported");
    let truncated = dir.join("truncated.nemm");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).expect("write");
    let stderr = Nemm::new(&["inspect"]).arg(&truncated).fails();
    assert!(
        stderr.starts_with("error: ") && stderr.contains("truncated.nemm"),
        "{stderr}"
    );

    // sweep: one `nemm train` process per lambda_ph, two at a time, collected into Table 5.
    let sweep = dir.join("sweep");
    let sweep_cmd = |extra: &[&str]| {
        Nemm::new(&["sweep", "--lambda-ph", "0,5"])
            .arg("--data")
            .arg(&data)
            .arg("--report")
            .arg(&sweep)
            .budget()
            .0
            .args(extra)
            .output()
            .expect("run nemm")
    };
    let list = sweep_cmd(&["--list"]);
    assert!(list.status.success());
    let list = String::from_utf8_lossy(&list.stdout).into_owned();
    let commands: Vec<&str> = list.lines().filter(|l| l.contains(" train ")).collect();
    assert_eq!(commands.len(), 2, "{list}");
    let run = sweep_cmd(&["--jobs", "2"]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let table5 = std::fs::read_to_string(sweep.join("table5.md")).expect("table5.md");
    for job in ["| lph0 | construction | 0 |", "| lph5 | construction | 5 |"] {
        assert!(table5.contains(job), "{job} missing:\n{table5}");
    }
    assert!(
        table5.starts_with("Sweep of the NEMM trained at commit `")
            && table5.contains("Rel. test error: the job's test RMSE against `lph0`'s."),
        "{table5}"
    );
    // The priors grid: the lambda list once by construction and once by the penalty alone.
    let list = sweep_cmd(&["--grid", "priors", "--list"]);
    assert!(list.status.success());
    let list = String::from_utf8_lossy(&list.stdout).into_owned();
    let commands: Vec<&str> = list.lines().filter(|l| l.contains(" train ")).collect();
    assert_eq!(commands.len(), 4, "{list}");
    for id in [
        "construction_lph0",
        "construction_lph5",
        "penalty_lph0",
        "penalty_lph5",
    ] {
        let config = sweep.join("jobs").join(id).join("config.toml");
        let text = std::fs::read_to_string(&config).expect("the job's config.toml");
        let priors = id.split('_').next().expect("prefix");
        assert!(
            text.contains(&format!("alpha_priors = \"{priors}\"")),
            "{id}: {text}"
        );
    }
    let sweep_json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(sweep.join("sweep.json")).expect("sweep.json"),
    )
    .expect("sweep.json");
    assert!(sweep_json.to_string().contains("lph5"), "{sweep_json}");
    // Table 5 does not show where a job's model puts the degradation: its jobs skip that
    // part of the report (`--degradation-report=false`).
    let read_report = |path: &Path| -> Report {
        serde_json::from_str(&std::fs::read_to_string(path).expect("report.json")).expect("Report")
    };
    assert!(list.contains("--degradation-report=false"), "{list}");
    let lph5 = read_report(&sweep.join("jobs/lph5/report.json"));
    assert!(
        lph5.identify.is_none() && lph5.signature.is_none() && lph5.bench_reference.is_none(),
        "a Table 5 job identified"
    );
    // `nemm train --report` says where its model puts the degradation: the levels read
    // back, the signature, the learned against the bench's coefficients.
    let job_report = read_report(&train_report.join("report.json"));
    let id = job_report.identify.as_ref().expect("identify");
    assert_eq!(id.variants["nemm"].fits.len(), id.runs.len());
    assert!(!job_report
        .signature
        .as_ref()
        .expect("signature")
        .rows
        .is_empty());
    assert!(job_report.bench_reference.is_some());

    // The degradation grid: the four element choices, with --lambda-diff each also with
    // the matched-difference term, each in its job's config.toml.
    let degradation = dir.join("degradation");
    let list = Nemm::new(&[
        "sweep",
        "--grid",
        "degradation",
        "--lambda-diff",
        "2",
        "--list",
    ])
    .arg("--data")
    .arg(&data)
    .arg("--report")
    .arg(&degradation)
    .budget()
    .ok();
    let commands: Vec<&str> = list.lines().filter(|l| l.contains(" train ")).collect();
    assert_eq!(commands.len(), 8, "{list}");
    for (id, lost_motion, b_fl_alpha, lambda_diff) in [
        ("paper_lph5", false, true, 0.0),
        ("fixed-b-fl_lph5", false, false, 0.0),
        ("lost-motion_lph5", true, true, 0.0),
        ("lost-motion-fixed-b-fl_lph5", true, false, 0.0),
        ("paper_diff2_lph5", false, true, 2.0),
        ("lost-motion-fixed-b-fl_diff2_lph5", true, false, 2.0),
    ] {
        let job = degradation.join("jobs").join(id);
        let text = std::fs::read_to_string(job.join("config.toml")).expect("config.toml");
        assert!(
            text.contains(&format!("lost_motion = {lost_motion}"))
                && text.contains(&format!("b_fl_alpha = {b_fl_alpha}"))
                && text.contains(&format!("lambda_diff = {lambda_diff:?}")),
            "{id}: {text}"
        );
        assert!(
            !commands.iter().any(|c| c.contains("--degradation-report")),
            "the degradation grid's jobs identify: {list}"
        );
        if id == "paper_lph5" {
            // The paper's point trained by `nemm train --report` above (the same
            // configuration): its report collected with the degradation columns.
            std::fs::copy(train_report.join("report.json"), job.join("report.json"))
                .expect("copy the report");
        }
    }
    let collected = Nemm::new(&["sweep", "--collect"]).arg(&degradation).ok();
    let table =
        std::fs::read_to_string(degradation.join("degradation.md")).expect("degradation.md");
    assert!(
        collected.contains("| paper_lph5 | no | yes | 0 | 5 |"),
        "{collected}"
    );
    let row = table
        .lines()
        .find(|l| l.starts_with("| paper_lph5 | no | yes | 0 | 5 |"))
        .unwrap_or_else(|| panic!("no paper row:\n{table}"));
    let sig = job_report
        .signature
        .as_ref()
        .expect("signature")
        .summary("nemm");
    let top = sig.last().expect("a lossy level");
    for part in [
        format!("{:.2} at {}", top.median, top.alpha),
        "0.15 (test): ".to_string(),
    ] {
        assert!(row.contains(&part), "{part} missing: {row}");
    }
    assert!(table.contains("- `lost-motion_lph5`: no result"), "{table}");

    // The main job on this bench (found, not generated), at one batch: Table 4, model.nemm,
    // and the exported model run through nemm-core on a held-out run.
    let demo = dir.join("demo");
    let stdout = Nemm::new(&["demo", "--epochs", "1", "--max-batches", "1", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&demo)
        .ok();
    assert!(stdout.contains("| NEMM |"), "{stdout}");
    assert!(stdout.contains("nemm-core estimator RMSE"), "{stdout}");
    assert!(stdout.contains("demo done in"), "{stdout}");
    assert_eq!(
        decode_file(&demo.join("model.nemm")).kind(),
        ModelKind::Nemm
    );
    no_temp_files(&demo);
}

/// `nemm identify` on a fixture (three levels at 300 Hz) with example blobs: the tables and
/// `identify.json` for every run the split uses or the runs of `--runs`; a model without
/// alpha dependence is flat; a pattern that matches nothing is refused.
#[test]
fn identify_prints_and_writes_the_best_fit_level_of_each_run() {
    use nemm_train::report::IdentifyReport;
    use nemm_train::train::identify::Search;
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path();
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/offsets_300hz");
    let blob = |kind: ModelKind| {
        let m =
            nemm_core::testing::example_model::<{ nemm_core::DEFAULT_PARAM_CAPACITY }>(kind, 8, 3)
                .expect("example model");
        let path = dir.join(format!("{}.nemm", kind.name()));
        std::fs::write(&path, nemm_core::encode_to_vec(&m).expect("encode")).expect("write");
        path
    };
    let read = |report: &Path| -> IdentifyReport {
        serde_json::from_str(
            &std::fs::read_to_string(report.join("identify.json")).expect("identify.json"),
        )
        .expect("IdentifyReport")
    };

    let report = dir.join("nemm-id");
    let stdout = Nemm::new(&["identify", "--model"])
        .arg(blob(ModelKind::Nemm))
        .arg("--data")
        .arg(&data)
        .arg("--report")
        .arg(&report)
        .ok();
    for part in [
        "## Identifiability",
        "### NEMM (grid 0 to 0.3, 31 levels",
        "| runs/oil15_a030_v0240.csv | test | 0.15 |",
        "Whole-run RMSE at the label per level",
        "identified 3 runs",
    ] {
        assert!(stdout.contains(part), "{part} missing:\n{stdout}");
    }
    let id = read(&report);
    assert_eq!(id.runs.len(), 3);
    assert_eq!(id.step, 0.01);
    assert_eq!(id.search, Search::CoarseToFine);
    let nemm = &id.variants["nemm"];
    assert_eq!(nemm.grid.len(), 31);
    assert_eq!(nemm.fits.len(), 3);
    for (run, fit) in id.runs.iter().zip(&nemm.fits) {
        assert_eq!(fit.label, run.alpha);
        assert_eq!(fit.curve_n.len(), fit.levels.len());
        assert!(fit.levels.len() < 31, "{fit:?}");
        assert!(fit.levels.iter().all(|a| nemm.grid.contains(a)), "{fit:?}");
        assert!(
            fit.rmse_label_n.is_finite() && fit.rmse_label_n > 0.0,
            "{fit:?}"
        );
        let least = fit.curve_n.iter().copied().fold(f64::INFINITY, f64::min);
        assert_eq!(fit.rmse_best_n, least);
        if let Some(b) = fit.best {
            assert!(nemm.grid.contains(&b));
        }
    }
    // --full-grid: the whole curve, and the same fits.
    let full_report = dir.join("nemm-id-full");
    Nemm::new(&["identify", "--full-grid", "--model"])
        .arg(blob(ModelKind::Nemm))
        .arg("--data")
        .arg(&data)
        .arg("--report")
        .arg(&full_report)
        .ok();
    let full = read(&full_report);
    assert_eq!(full.search, Search::Full);
    for (fast, full) in nemm.fits.iter().zip(&full.variants["nemm"].fits) {
        assert_eq!((full.levels.len(), full.curve_n.len()), (31, 31));
        assert_eq!(fast.best, full.best);
        assert_eq!(fast.rmse_best_n, full.rmse_best_n);
        assert_eq!(fast.rmse_label_n, full.rmse_label_n);
    }
    let levels: Vec<(f64, &str, usize)> = nemm
        .levels
        .iter()
        .map(|l| (l.alpha, l.role.as_str(), l.runs))
        .collect();
    assert_eq!(
        levels,
        [(0.0, "train", 1), (0.15, "test", 1), (0.3, "train", 1)]
    );
    let order = nemm.order.as_ref().expect("two levels or more");
    assert_eq!((order.low, order.high, order.conditions), (0.0, 0.3, 1));
    let md = std::fs::read_to_string(report.join("identify.md")).expect("identify.md");
    assert!(md.contains("## Identifiability"), "{md}");

    // The Linear EMM does not depend on alpha: every run flat; one run by its name.
    let report = dir.join("linear-id");
    let stdout = Nemm::new(&["identify", "--runs", "oil30_*", "--step", "0.05", "--model"])
        .arg(blob(ModelKind::LinearEmm))
        .arg("--data")
        .arg(&data)
        .arg("--report")
        .arg(&report)
        .ok();
    assert!(
        stdout.contains("| runs/oil30_a030_v0240.csv | train | 0.3 | flat |"),
        "{stdout}"
    );
    let id = read(&report);
    let linear = &id.variants["linear_emm"];
    assert_eq!((id.runs.len(), linear.grid.len()), (1, 7));
    assert_eq!(linear.fits[0].best, None);
    assert_eq!(linear.levels[0].flat, 1);

    let err = Nemm::new(&["identify", "--runs", "nothing*", "--model"])
        .arg(blob(ModelKind::Nemm))
        .arg("--data")
        .arg(&data)
        .fails();
    assert!(
        err.contains("--runs \"nothing*\" matches none of the 3 runs"),
        "{err}"
    );
}

/// Bad sizes, option values and output paths are refused before any data is read or any
/// model trained, each with an error naming the option.
#[test]
fn bad_inputs_are_refused_before_training() {
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path();
    let out = dir.join("m.nemm");
    let train = |extra: &[&str]| {
        Nemm::new(&["train", "--data"])
            .arg(dir.join("no-dataset"))
            .arg("--out")
            .arg(&out)
            .arg("--epochs")
            .arg("1")
            .0
            .args(extra)
            .output()
            .expect("run nemm")
    };
    let refused = |extra: &[&str], expected: &str| {
        let o = train(extra);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{extra:?} was accepted");
        assert!(err.contains(expected), "{extra:?}: {err}");
        assert!(!err.contains("panicked"), "{extra:?}: {err}");
    };
    refused(
        &["--model-rate-hz", "1e9"],
        "--model-rate-hz 1000000000 is out of range",
    );
    refused(&["--lr", "nan"], "--lr NaN is out of range");
    refused(&["--lr", "0"], "--lr 0 is out of range");
    refused(&["--tables-alpha", "2"], "--tables-alpha 2 is out of range");
    refused(&["--tables-segments", "7"], "--tables-segments 7");
    refused(
        &["--session-epochs", "1"],
        "--session-epochs 1 needs --checkpoint",
    );
    for units in ["0", "1000000"] {
        let cfg = dir.join(format!("units-{units}.toml"));
        std::fs::write(&cfg, format!("[model]\nbranch_units = {units}\n")).expect("write");
        let cfg = cfg.to_str().expect("utf-8").to_string();
        refused(
            &["--config", &cfg],
            &format!("branch_units ([model] in --config) {units} is out of range"),
        );
    }
    let o = Nemm::new(&["train", "--data", "d", "--out"])
        .arg(dir.join("missing/m.nemm"))
        .output();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("does not exist"),
        "{err}"
    );
    let o = Nemm::new(&["train", "--data", "d", "--out", "/proc/m.nemm"]).output();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("cannot write into /proc"),
        "{err}"
    );
    let file = dir.join("a-file");
    std::fs::write(&file, "x").expect("write");
    let err = Nemm::new(&["compare", "--data", "d", "--report"])
        .arg(&file)
        .fails();
    assert!(err.contains("is a file, not a folder"), "{err}");
    assert!(!out.exists(), "nothing was written");
}

#[test]
fn tables_restores_the_level_tables_of_an_existing_blob() {
    let dir = tempfile::tempdir().expect("temp dir");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let input = root.join("nemm-firmware/data/trained-nemm.nemm");
    let out = dir.path().join("levels.nemm");
    let text = Nemm::new(&["tables"])
        .arg(&input)
        .args(&["--tables-levels", "4", "--out"])
        .arg(&out)
        .ok();
    // The model is the input's, bit for bit; the levels are 4 evenly over the trained range.
    let (a, b) = (decode_file(&input), decode_file(&out));
    assert_eq!(a, b);
    let blob = std::fs::read(&out).unwrap();
    let (_, stored) = nemm_core::decode_with_tables::<{ nemm_core::DEFAULT_PARAM_CAPACITY }>(&blob)
        .expect("decodes");
    let alphas: Vec<f32> = stored.levels.iter().map(|l| l.alpha).collect();
    assert_eq!(alphas, [0.0, 0.1, 0.2, 0.3]);
    assert!(
        text.contains(
            "level tables:    4 levels of 128 segments, 28928 B in the blob, read in place"
        ),
        "{text}"
    );
    assert!(text.contains("out of the declared order in 0 of"), "{text}");
    no_temp_files(dir.path());
    // Too many levels, or one: refused before anything is written.
    let bad = dir.path().join("bad.nemm");
    for n in ["17", "1"] {
        let err = Nemm::new(&["tables"])
            .arg(&input)
            .args(&["--tables-levels", n, "--out"])
            .arg(&bad)
            .fails();
        assert!(err.contains("--tables-levels"), "{err}");
        assert!(!bad.exists());
    }
}
