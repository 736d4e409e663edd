//! `nemm data import`: raw dyno files with other units, signs, headers and long records.
use nemm_dataset::{self as dataset, DatasetError};
use nemm_train::data::import::{self, ImportError, ImportSpec};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A 300 Hz FSAE-like export: a preamble, `;`-separated, ms / mm / lbf with compression
/// force positive, a 30 mm potentiometer zero, time stamps rounded to 0.1 ms.
fn write_fsae(dir: &Path, name: &str, seconds: f64) -> PathBuf {
    let mut s =
        String::from("# Dyno export v2\n# operator: test\nTime [ms];Pos [mm];Load [lbf];Temp\n");
    let n = (300.0 * seconds) as usize;
    for i in 0..n {
        let t = i as f64 / 300.0;
        let x = 30.0 + 25.0 * (2.0 * PI * 0.5 * t).sin();
        let v = 25.0 * 2.0 * PI * 0.5 * (2.0 * PI * 0.5 * t).cos();
        let f_lbf = -(0.5 * v + 10.0);
        s.push_str(&format!("{:.1};{x:.3};{f_lbf:.2};25\n", t * 1e3));
    }
    let p = dir.join(name);
    std::fs::write(&p, s).expect("write raw");
    p
}

fn spec_from(text: &str, dir: &Path) -> ImportSpec {
    let p = dir.join("import.toml");
    std::fs::write(&p, text).expect("write spec");
    import::read_spec(&p).expect("spec")
}

const FSAE_SPEC: &str = r#"
name = "FSAE damper"
[csv]
delimiter = ";"
header_line = 3
[columns.time]
name = "Time [ms]"
unit = "ms"
[columns.displacement]
name = "Pos [mm]"
unit = "mm"
[columns.force]
name = "Load [lbf]"
unit = "lbf"
invert = true
[[files]]
path = "p150.csv"
alpha = 0.0
[[files]]
path = "p50.csv"
alpha = 1.0
"#;

#[test]
fn a_300_hz_mm_lbf_ms_export_with_a_sign_flip_imports() {
    let dir = tempfile::tempdir().expect("dir");
    write_fsae(dir.path(), "p150.csv", 4.0);
    write_fsae(dir.path(), "p50.csv", 3.0);
    let spec = spec_from(FSAE_SPEC, dir.path());
    let imported = import::import(&spec, "x").expect("import");
    let ds = &imported.dataset;
    assert_eq!(ds.name, "FSAE damper");
    assert_eq!(ds.sample_rate_hz, 300.0);
    assert_eq!(ds.runs.len(), 2);
    assert_eq!(ds.runs[0].len(), 1200);
    assert_eq!(ds.runs[1].entry.oil_loss, 1.0);
    assert_eq!(ds.runs[0].entry.file, PathBuf::from("runs/p150.csv"));
    // Line 4 of the raw file is the first sample: 0 ms, 30.000 mm, -(0.5 v + 10) lbf.
    assert_eq!(imported.runs[0].lines, (4, 1203));
    let r = &ds.runs[0];
    assert!((r.displacement_m[0] - 0.030).abs() < 1e-12);
    let v0 = 25.0 * 2.0 * PI * 0.5;
    let f_lbf = ((0.5 * v0 + 10.0) * 100.0).round() / 100.0;
    assert!(
        (r.force_n[0] - f_lbf * 4.448_221_615_260_5).abs() < 1e-9,
        "{}",
        r.force_n[0]
    );
    assert!(!imported.runs[0].grid.is_exact(), "0.1 ms rounding");
    // Written atomically and read back by the loader unchanged.
    let out = dir.path().join("ds");
    dataset::write(&out, ds).expect("write");
    assert_eq!(&dataset::load(&out).expect("load"), ds);
}

#[test]
fn a_long_record_is_cut_at_pauses_and_by_time_ranges() {
    let dir = tempfile::tempdir().expect("dir");
    // 3 kHz, 2 s of motion then 1.5 s at rest, three times; stamps rounded to 0.1 ms.
    let fs = 3000.0;
    let mut s = String::from("t,x,F\n");
    let mut i = 0usize;
    for _ in 0..3 {
        for k in 0..6000 {
            let w = 2.0 * PI * 2.0 * k as f64 / fs;
            let t = ((i as f64 / fs) * 1e4).round() / 1e4;
            s.push_str(&format!("{t},{},{}\n", 0.01 * w.sin(), 100.0 * w.cos()));
            i += 1;
        }
        for k in 0..4500 {
            let t = ((i as f64 / fs) * 1e4).round() / 1e4;
            s.push_str(&format!("{t},0,{}\n", 0.5 * (k as f64).sin()));
            i += 1;
        }
    }
    std::fs::write(dir.path().join("long.csv"), s).expect("raw");
    let base = r#"
[columns.time]
name = "t"
unit = "s"
[columns.displacement]
name = "x"
unit = "m"
[columns.force]
name = "F"
unit = "N"
"#;
    let spec = spec_from(
        &format!(
            "{base}[split]\nmethod = \"pauses\"\n[[files]]\npath = \"long.csv\"\nalpha = 0.25\n"
        ),
        dir.path(),
    );
    let imported = import::import(&spec, "long").expect("pauses");
    let runs = &imported.dataset.runs;
    assert_eq!(runs.len(), 3, "{:?}", imported.runs);
    for (k, r) in imported.runs.iter().enumerate() {
        let start = k as f64 * 3.5;
        // Cut at the block resolution (a tenth of min_pause_s).
        assert!((r.time_s.0 - start).abs() < 0.11, "{r:?}");
        assert!((r.time_s.1 - (start + 2.0)).abs() < 0.11, "{r:?}");
    }
    assert_eq!(runs[2].entry.file, PathBuf::from("runs/long_03.csv"));
    assert!(runs.iter().all(|r| r.entry.oil_loss == 0.25));
    // Time ranges, one with its own level.
    let spec = spec_from(
        &format!(
            "{base}[[files]]\npath = \"long.csv\"\nalpha = 0.25\n\
             [[files.runs]]\nstart_s = 0.0\nend_s = 2.0\n\
             [[files.runs]]\nstart_s = 3.5\nend_s = 5.5\nalpha = 0.5\n"
        ),
        dir.path(),
    );
    let imported = import::import(&spec, "long").expect("ranges");
    let runs = &imported.dataset.runs;
    assert_eq!(runs.len(), 2);
    assert_eq!(runs[0].len(), 6000);
    assert_eq!(runs[1].entry.oil_loss, 0.5);
    assert_eq!(imported.runs[1].lines.0, 10_502);
}

fn simple_spec(file: &Path, extra: &str) -> String {
    format!(
        "{extra}\n[columns.time]\nname = \"t\"\nunit = \"s\"\n[columns.displacement]\nname = \"x\"\nunit = \"mm\"\n\
         [columns.force]\nname = \"F\"\nunit = \"N\"\n[[files]]\npath = \"{}\"\nalpha = 0.0\n",
        file.display()
    )
}

#[test]
fn errors_name_file_line_and_column() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = dir.path().join("r.csv");
    std::fs::write(&raw, "t,x,Force\n0,1,2\n").expect("raw");
    let spec = spec_from(&simple_spec(&raw, ""), dir.path());
    let e = import::import(&spec, "x").expect_err("missing column");
    assert!(
        matches!(e, ImportError::MissingColumn { line: 1, .. }),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .contains("r.csv:1: column \"F\" (columns.force)"),
        "{e}"
    );

    std::fs::write(&raw, "t,x,F\n0,1,2\n0.001,1,2\n0.002,abc,2\n").expect("raw");
    let e = import::import(&spec, "x").expect_err("bad cell");
    assert!(
        e.to_string().contains("r.csv:4:2: column \"x\": \"abc\""),
        "{e}"
    );

    // A gap of three samples at line 5, named in the raw file's lines.
    let mut s = String::from("t,x,F\n");
    for i in (0..10).chain(13..40) {
        s.push_str(&format!("{},0,0\n", i as f64 * 1e-3));
    }
    std::fs::write(&raw, s).expect("raw");
    let e = import::import(&spec, "x").expect_err("gap");
    assert!(
        matches!(
            e,
            ImportError::Time(DatasetError::Gap {
                line: 12,
                missing: 3,
                ..
            })
        ),
        "{e:?}"
    );

    let e = import::validate_spec(&spec_from(
        &simple_spec(&raw, "").replace("unit = \"mm\"", "unit = \"furlong\""),
        dir.path(),
    ))
    .expect_err("unit");
    assert!(e.to_string().contains("columns.displacement.unit"), "{e}");

    std::fs::write(dir.path().join("bad.toml"), "[columns.force]\nname = 3\n").expect("toml");
    let e = import::read_spec(&dir.path().join("bad.toml")).expect_err("syntax");
    assert!(
        matches!(e, ImportError::SpecSyntax { line: 2, .. }),
        "{e:?}"
    );
}

#[test]
fn errors_name_the_lines_an_editor_shows_with_crlf_comments_and_blank_lines() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = dir.path().join("w.csv");
    // Windows line ends, a comment line and a blank line: "abc" is on line 7.
    std::fs::write(
        &raw,
        "# logger v3\r\nt,x,F\r\n0,1,2\r\n# pause\r\n0.001,1,2\r\n\r\n0.002,abc,2\r\n",
    )
    .expect("raw");
    let spec = spec_from(&simple_spec(&raw, "[csv]\ncomment = \"#\""), dir.path());
    let e = import::import(&spec, "w").expect_err("bad cell");
    assert!(
        matches!(
            &e,
            ImportError::BadCell {
                line: 7,
                field: 2,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("w.csv:7:2: column \"x\""), "{e}");
    // The header named by its line, after a CRLF preamble.
    std::fs::write(
        &raw,
        "logger v3\r\nrate 1 kHz\r\nt,x,F\r\n0,1,2\r\n0.001,1,2\r\n",
    )
    .expect("raw");
    let spec = spec_from(&simple_spec(&raw, "[csv]\nheader_line = 3"), dir.path());
    let imported = import::import(&spec, "w").expect("imports");
    assert_eq!(imported.runs[0].lines, (4, 5));
}

#[test]
fn volts_with_a_gain_offset_and_no_time_column() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = dir.path().join("v.csv");
    std::fs::write(&raw, "ch1\tch2\n0.5\t-1.0\n1.0\t-2.0\n1.5\t-3.0\n").expect("raw");
    let spec = spec_from(
        &format!(
            "rate_hz = 1000.0\n[csv]\ndelimiter = \"tab\"\n\
             [columns.displacement]\nindex = 1\nunit = \"mm\"\ngain = 10.0\noffset = -5.0\n\
             [columns.force]\nname = \"ch2\"\nunit = \"kN\"\ngain = 2.0\ninvert = true\n\
             [[files]]\npath = \"{}\"\nalpha = 1.0\n",
            raw.display()
        ),
        dir.path(),
    );
    let ds = import::import(&spec, "v").expect("import").dataset;
    let r = &ds.runs[0];
    assert_eq!(r.time_s, vec![0.0, 0.001, 0.002]);
    // (0.5 V * 10 mm/V - 5 mm) = 0 mm; (1.0 * 10 - 5) mm = 5 mm.
    assert!((r.displacement_m[1] - 0.005).abs() < 1e-15);
    // -(-1 V * 2 kN/V) = 2 kN.
    assert!((r.force_n[0] - 2000.0).abs() < 1e-9);
}

#[test]
fn non_uniform_stamps_are_resampled_only_on_request() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = dir.path().join("n.csv");
    // A logger clock wandering +-0.4 ms around a 1 kHz grid: every step within 3 % of
    // 1 ms, but up to 0.4 steps off the fitted grid, beyond a quarter step.
    let mut s = String::from("t,x,F\n");
    for i in 0..400 {
        let t = i as f64 * 1e-3 + 0.4e-3 * (2.0 * PI * i as f64 / 100.0).sin();
        s.push_str(&format!("{t},{},{}\n", 2.0 * t, -3.0 * t));
    }
    std::fs::write(&raw, s).expect("raw");
    let mut spec = spec_from(&simple_spec(&raw, ""), dir.path());
    match import::import(&spec, "n") {
        Err(ImportError::Time(DatasetError::OffGrid { deviation_us, .. })) => {
            // Beyond the quarter step (the least-squares line tilts with the wander).
            assert!(
                deviation_us.abs() > 250.0 && deviation_us.abs() < 500.0,
                "{deviation_us}"
            );
        }
        Err(e) => panic!("expected an off-grid error, got {e}"),
        Ok(_) => panic!("non-uniform stamps accepted"),
    }
    spec.resample_hz = Some(1000.0);
    let imported = import::import(&spec, "n").expect("resampled");
    let r = &imported.dataset.runs[0];
    assert!(imported.runs[0].resampled);
    assert_eq!(imported.dataset.sample_rate_hz, 1000.0);
    let span = imported.runs[0].time_s.1 - imported.runs[0].time_s.0;
    assert_eq!(r.len(), (span * 1000.0).floor() as usize + 1);
    // Linear interpolation reproduces a linear signal exactly (x in mm -> m).
    for (t, x) in r.time_s.iter().zip(&r.displacement_m) {
        assert!((x - 2e-3 * t).abs() < 1e-12, "{t} {x}");
    }
    // Sizes are bounded before anything is allocated: a rate above the highest model rate,
    // and a run that would hold more samples than a run may.
    spec.resample_hz = Some(1e9);
    let e = import::import(&spec, "n").expect_err("1 GHz");
    assert!(
        e.to_string()
            .contains("resample_hz: 1000000000 Hz is above the highest model rate, 1000000 Hz"),
        "{e}"
    );
    let slow = dir.path().join("slow.csv");
    std::fs::write(&slow, "t,x,F\n0,0,0\n30,1,1\n60,2,2\n").expect("raw");
    let mut spec = spec_from(&simple_spec(&slow, ""), dir.path());
    spec.resample_hz = Some(1e6);
    match import::import(&spec, "slow") {
        Err(e @ ImportError::TooManySamples { .. }) => assert!(
            e.to_string().contains(
                "resampling 60 s at 1000000 Hz gives 60000001 samples; a run holds at most \
                 50000000"
            ),
            "{e}"
        ),
        Err(e) => panic!("expected TooManySamples, got {e}"),
        Ok(_) => panic!("a 60 s run at 1 MHz accepted"),
    }
}

#[test]
fn the_cli_imports_with_flags_only() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = write_fsae(dir.path(), "p100.csv", 3.0);
    let out = dir.path().join("ds");
    let o = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(["data", "import"])
        .arg(&raw)
        .arg("--out")
        .arg(&out)
        .args([
            "--delimiter",
            ";",
            "--header-line",
            "3",
            "--time",
            "Time [ms]:ms",
            "--displacement",
            "Pos [mm]:mm",
            "--force",
            "Load [lbf]:lbf",
            "--invert-force",
            "--center-displacement",
            "--alpha",
            "0.5",
        ])
        .output()
        .expect("run nemm");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        stdout.contains("time stamps rounded/jittered: max deviation"),
        "{stdout}"
    );
    let ds = dataset::load(&out).expect("load");
    assert_eq!(ds.runs[0].entry.oil_loss, 0.5);
    let (lo, hi) = ds.runs[0]
        .displacement_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
            (l.min(x), h.max(x))
        });
    assert!((lo + hi).abs() < 1e-9, "centred: {lo} {hi}");
    let o = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(["data", "import"])
        .arg(&raw)
        .arg("--out")
        .arg(&out)
        .args([
            "--displacement",
            "Pos [mm]:mm",
            "--force",
            "Load:lbf",
            "--rate-hz",
            "300",
            "--alpha",
            "0.5",
            "--replace",
        ])
        .output()
        .expect("run nemm");
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("p100.csv:1: column"), "{stderr}");
}

/// A 3 kHz MR-damper-like record whose control voltage (0, 2.5 or 5 V) switches every 20 to
/// 70 ms: the level per sample comes from the voltage column (`gain = 0.2` per volt). The
/// column holds the voltage times `scale`; `bad_line` gets 6 V (level 1.2) instead.
fn write_mr(dir: &Path, name: &str, bad_line: Option<usize>, scale: f64) -> PathBuf {
    let mut s = String::from("time_s,stroke_mm,force_kN,U_ctrl_V\n");
    let levels = [0.0, 2.5, 5.0];
    let (mut seg_end, mut k, mut u) = (0usize, 0usize, 0.0);
    for i in 0..9000 {
        if i == seg_end {
            u = levels[k % 3];
            seg_end = i + 60 + (k * 37) % 150;
            k += 1;
        }
        let t = i as f64 / 3000.0;
        let x = 10.0 * (2.0 * PI * 1.7 * t).sin() + 4.0 * (2.0 * PI * 7.3 * t).sin();
        let cell = if Some(i + 2) == bad_line { 6.0 } else { u } * scale;
        s.push_str(&format!(
            "{t:.4},{x:.3},{:.4},{cell}\n",
            0.001 * x * (1.0 + cell)
        ));
    }
    let p = dir.join(name);
    std::fs::write(&p, s).expect("write raw");
    p
}

const MR_SPEC: &str = r#"
[columns.time]
name = "time_s"
unit = "s"
[columns.displacement]
name = "stroke_mm"
unit = "mm"
[columns.force]
name = "force_kN"
unit = "kN"
[columns.alpha]
name = "U_ctrl_V"
unit = "1"
gain = 0.2
[[files]]
path = "mr.csv"
"#;

#[test]
fn a_level_column_becomes_the_runs_alpha_per_sample() {
    let dir = tempfile::tempdir().expect("dir");
    write_mr(dir.path(), "mr.csv", None, 1.0);
    let spec = spec_from(MR_SPEC, dir.path());
    let imported = import::import(&spec, "mr").expect("import");
    let ds = &imported.dataset;
    assert_eq!(ds.runs.len(), 1);
    let run = &ds.runs[0];
    let levels = run.alpha.as_ref().expect("per-sample levels");
    assert_eq!(levels.len(), run.len());
    assert!(levels.iter().all(|a| [0.0, 0.5, 1.0].contains(a)), "levels");
    assert!(levels.windows(2).filter(|w| w[0] != w[1]).count() > 50);
    // Without a level in the spec, the run's label is the mean of its levels.
    let mean = levels.iter().sum::<f64>() / levels.len() as f64;
    assert!((run.entry.oil_loss - mean).abs() < 1e-12);
    // The run file carries the column and reads back the same.
    let out = dir.path().join("dataset");
    dataset::write(&out, ds).expect("write");
    assert_eq!(&dataset::load(&out).expect("load"), ds);

    // Resampled on request, the levels are interpolated with the rest.
    let mut resampled = spec.clone();
    resampled.resample_hz = Some(1000.0);
    let r = import::import(&resampled, "mr").expect("resampled");
    let run = &r.dataset.runs[0];
    assert_eq!(run.alpha.as_ref().map(Vec::len), Some(run.len()));
}

#[test]
fn a_level_cell_outside_0_1_and_a_missing_level_are_refused_with_their_place() {
    let dir = tempfile::tempdir().expect("dir");
    write_mr(dir.path(), "mr.csv", Some(4321), 1.0);
    let spec = spec_from(MR_SPEC, dir.path());
    let e = import::import(&spec, "mr").expect_err("6 V is level 1.2");
    assert!(
        matches!(
            e,
            ImportError::LevelOutOfRange {
                line: 4321,
                field: 4,
                ..
            }
        ),
        "{e:?}"
    );
    assert!(
        e.to_string().contains("mr.csv:4321:4: column \"U_ctrl_V\""),
        "{e}"
    );
    // Without a level column, every file needs its level.
    let no_column = MR_SPEC.replace(
        "[columns.alpha]\nname = \"U_ctrl_V\"\nunit = \"1\"\ngain = 0.2\n",
        "",
    );
    let spec = spec_from(&no_column, dir.path());
    let e = import::import(&spec, "mr").expect_err("no level");
    assert!(e.to_string().contains("files[0].alpha: missing"), "{e}");
}

#[test]
fn the_cli_takes_a_level_column_instead_of_file_levels() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = write_mr(dir.path(), "mr.csv", None, 0.2);
    let out = dir.path().join("ds");
    let o = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(["data", "import"])
        .arg(&raw)
        .arg("--out")
        .arg(&out)
        .args([
            "--time",
            "time_s:s",
            "--displacement",
            "stroke_mm:mm",
            "--force",
            "force_kN:kN",
            "--alpha-column",
            "U_ctrl_V:1",
        ])
        .output()
        .expect("run nemm");
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let ds = dataset::load(&out).expect("load");
    let levels = ds.runs[0].alpha.as_ref().expect("levels");
    assert!(levels.contains(&0.0) && levels.contains(&0.5) && levels.contains(&1.0));
}

/// Runs `nemm data import` on `raw` into `out` with the simple columns (`t` in s, `x` in
/// mm, `F` in N) and the `extra` flags.
fn cli_import(raw: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(["data", "import"])
        .arg(raw)
        .arg("--out")
        .arg(out)
        .args([
            "--time",
            "t:s",
            "--displacement",
            "x:mm",
            "--force",
            "F:N",
            "--alpha",
            "0.5",
        ])
        .args(extra)
        .output()
        .expect("run nemm")
}

/// A 1 kHz raw file of `seconds`, columns `t,x,F`, the force `scale` times the displacement.
fn write_simple(path: &Path, seconds: f64, scale: f64) {
    let mut s = String::from("t,x,F\n");
    for i in 0..(1000.0 * seconds) as usize {
        let t = i as f64 / 1000.0;
        let x = (2.0 * PI * 2.0 * t).sin();
        s.push_str(&format!("{t},{x:.6},{:.6}\n", scale * x));
    }
    std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
    std::fs::write(path, s).expect("raw");
}

#[test]
fn an_existing_dataset_is_replaced_only_with_replace_and_as_a_whole() {
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("ds");
    // Four raw files beside the output folder (an output never contains its inputs) and a
    // note of the user's in it: a 4-run dataset.
    std::fs::create_dir_all(&out).expect("mkdir");
    std::fs::write(out.join("notes.txt"), "mine").expect("note");
    let raws: Vec<PathBuf> = (0..4)
        .map(|k| {
            let p = dir.path().join("raw").join(format!("raw{k}.csv"));
            write_simple(&p, 1.0, 1.0 + k as f64);
            p
        })
        .collect();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_nemm"));
    cmd.args(["data", "import"])
        .args(&raws)
        .arg("--out")
        .arg(&out)
        .args(["--time", "t:s", "--displacement", "x:mm", "--force", "F:N"])
        .args(["--alpha", "0,0.25,0.5,1"]);
    let o = cmd.output().expect("run nemm");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(dataset::load(&out).expect("4 runs").runs.len(), 4);

    // A second import into the same folder is refused without --replace.
    let o = cli_import(&raws[0], &out, &[]);
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("already holds a dataset") && stderr.contains("--replace"),
        "{stderr}"
    );
    assert_eq!(dataset::load(&out).expect("untouched").runs.len(), 4);

    // With --replace the dataset is replaced as a whole: one run, no orphaned run files, the
    // raw files and the note (no dataset's files) kept.
    let o = cli_import(&raws[0], &out, &["--replace"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(dataset::load(&out).expect("1 run").runs.len(), 1);
    let run_files: Vec<_> = std::fs::read_dir(out.join("runs"))
        .expect("runs")
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert_eq!(run_files.len(), 1, "{run_files:?}");
    for raw in &raws {
        assert!(raw.is_file(), "{} lost", raw.display());
    }
    assert_eq!(std::fs::read(out.join("notes.txt")).expect("kept"), b"mine");
}

#[test]
fn an_input_is_never_overwritten_even_with_replace() {
    let dir = tempfile::tempdir().expect("dir");
    let out = dir.path().join("ds");
    // The raw file sits where the dataset writes its run file (runs/<stem>.csv).
    let raw = out.join("runs").join("p.csv");
    write_simple(&raw, 1.0, 1.0);
    let before = std::fs::read(&raw).expect("read");
    for extra in [&[][..], &["--replace"][..]] {
        let o = cli_import(&raw, &out, extra);
        assert!(!o.status.success());
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(
            stderr.contains("contains the input") && stderr.contains("p.csv"),
            "{stderr}"
        );
        assert_eq!(std::fs::read(&raw).expect("read"), before);
    }
    // An old run file given back as an input is not removed by --replace either.
    let other = dir.path().join("q.csv");
    write_simple(&other, 1.0, 2.0);
    let ds2 = dir.path().join("ds2");
    assert!(cli_import(&other, &ds2, &[]).status.success());
    let old_run = ds2.join("runs/q.csv");
    let o = cli_import(&old_run, &ds2, &["--replace"]);
    assert!(!o.status.success());
    assert!(old_run.is_file());
}

#[test]
fn the_fitted_rate_is_written_as_fitted() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = dir.path().join("r.csv");
    let mut s = String::from("t,x,F\n");
    for i in 0..6000 {
        let t = i as f64 / 3004.8;
        s.push_str(&format!("{t:.9},{:.6},1\n", (7.0 * t).sin()));
    }
    std::fs::write(&raw, s).expect("raw");
    let out = dir.path().join("ds");
    let o = cli_import(&raw, &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ds = dataset::load(&out).expect("load");
    assert!(
        (ds.sample_rate_hz - 3004.8).abs() < 1e-6,
        "{}",
        ds.sample_rate_hz
    );
}

/// `HH:MM:SS.ffffff` of `micros` after midnight.
fn clock(micros: u64) -> String {
    let s = micros / 1_000_000;
    format!(
        "{:02}:{:02}:{:02}.{:06}",
        s / 3600,
        s / 60 % 60,
        s % 60,
        micros % 1_000_000
    )
}

#[test]
fn date_time_stamps_are_time_stamps() {
    let dir = tempfile::tempdir().expect("dir");
    let start = ((19 * 60 + 25) * 60 + 35) * 1_000_000 + 107_472;
    for (form, suffix) in [(" ", ""), ("T", "Z"), ("T", "+01:00")] {
        let raw = dir.path().join("stamps.csv");
        let mut s = String::from("t,x,F\n");
        for i in 0..2000u64 {
            let stamp = format!("2025-11-14{form}{}{suffix}", clock(start + i * 1000));
            s.push_str(&format!("{stamp},{:.6},1\n", (i as f64 * 0.01).sin()));
        }
        std::fs::write(&raw, &s).expect("raw");
        let spec = spec_from(&simple_spec(&raw, ""), dir.path());
        let imported = import::import(&spec, "d").expect("date-time stamps");
        let ds = &imported.dataset;
        assert_eq!(ds.sample_rate_hz, 1000.0, "{form}{suffix}");
        let t = &ds.runs[0].time_s;
        assert_eq!(t.len(), 2000);
        assert!(t[0].abs() < 1e-9 && (t[1999] - 1.999).abs() < 1e-9, "{t:?}");
    }
    // A malformed stamp is named with its file, line and field.
    let raw = dir.path().join("bad.csv");
    std::fs::write(
        &raw,
        "t,x,F\n2025-11-14 19:25:35.1,0,0\n2025-11-14 19:25:35.2,0,0\n2025-11-14 19:61:35.3,0,0\n",
    )
    .expect("raw");
    let spec = spec_from(&simple_spec(&raw, ""), dir.path());
    let e = import::import(&spec, "d").expect_err("minute 61");
    assert!(
        matches!(
            &e,
            ImportError::BadTimeStamp {
                line: 4,
                field: 1,
                ..
            }
        ),
        "{e:?}"
    );
    let text = e.to_string();
    assert!(
        text.contains("bad.csv:4:1: column \"t\"") && text.contains("minute 61"),
        "{text}"
    );
}

#[test]
fn a_ragged_row_and_a_duplicate_column_are_refused_with_their_line() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = dir.path().join("r.csv");
    std::fs::write(&raw, "t,x,F\n0,1,2\n0.001,1,9,2\n0.002,1,2\n").expect("raw");
    let spec = spec_from(&simple_spec(&raw, ""), dir.path());
    let e = import::import(&spec, "r").expect_err("ragged");
    assert!(matches!(&e, ImportError::Csv { line: 3, .. }), "{e:?}");
    assert!(
        e.to_string()
            .contains("r.csv:3: 4 fields, but the header has 3"),
        "{e}"
    );
    std::fs::write(&raw, "t,x,F,x\n0,1,2,3\n0.001,1,2,3\n").expect("raw");
    let e = import::import(&spec, "r").expect_err("duplicate");
    assert!(matches!(&e, ImportError::Csv { line: 1, .. }), "{e:?}");
    assert!(
        e.to_string().contains(
            "column \"x\" (columns.displacement) appears 2 times in the header (fields 2, 4)"
        ),
        "{e}"
    );
}

#[test]
fn an_error_in_a_cr_only_file_names_the_line_an_editor_shows() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = dir.path().join("mac.csv");
    std::fs::write(&raw, "t,x,F\r0,1,2\r0.001,1,2\r0.002,abc,2\r").expect("raw");
    let spec = spec_from(&simple_spec(&raw, ""), dir.path());
    let e = import::import(&spec, "m").expect_err("bad cell");
    assert!(e.to_string().contains("mac.csv:4:2: column \"x\""), "{e}");
}

/// [`MR_SPEC`] with the level column `U_ctrl_V` in volts mapped by `mapping` (e.g.
/// `range = [0.0, 5.0]`, or nothing to take the range from the data) and the spec's tail
/// `tail` (a `[condition]` table) before the files.
fn mr_volts_spec(mapping: &str, tail: &str, files: &[&str]) -> String {
    let files: String = files
        .iter()
        .map(|f| format!("[[files]]\npath = \"{f}\"\n"))
        .collect();
    MR_SPEC
        .replace(
            "unit = \"1\"\ngain = 0.2\n",
            &format!("unit = \"V\"\n{mapping}\n"),
        )
        .replace(
            "[[files]]\npath = \"mr.csv\"\n",
            &format!("{tail}\n{files}"),
        )
}

const MR_CONDITION: &str = "[condition]\nname = \"control voltage\"\nb_fl = \"increasing\"\n\
                            b_pr = \"increasing\"\nk_pr = \"none\"\n";

#[test]
fn a_spec_condition_with_a_level_range_is_written_to_the_manifest() {
    let dir = tempfile::tempdir().expect("dir");
    write_mr(dir.path(), "mr.csv", None, 1.0);
    let text = mr_volts_spec("range = [0.0, 5.0]", MR_CONDITION, &["mr.csv"]);
    let imported = import::import(&spec_from(&text, dir.path()), "mr").expect("import");
    let ds = &imported.dataset;
    // Raw 0, 2.5 and 5 V are alpha 0, 0.5 and 1, exactly.
    let levels = ds.runs[0].alpha.as_ref().expect("per-sample levels");
    for a in [0.0, 0.5, 1.0] {
        assert!(levels.contains(&a), "level {a}");
    }
    assert!(levels.iter().all(|a| [0.0, 0.5, 1.0].contains(a)));
    // The condition takes the column's unit and range; the priors are the spec's.
    let expected = dataset::ConditionSpec {
        name: "control voltage".into(),
        unit: "V".into(),
        at_alpha_0: 0.0,
        at_alpha_1: 5.0,
        b_fl: nemm_core::Direction::Increasing,
        b_pr: nemm_core::Direction::Increasing,
        k_pr: nemm_core::Direction::None,
    };
    assert_eq!(ds.condition.as_ref(), Some(&expected));
    let out = dir.path().join("ds");
    dataset::write(&out, ds).expect("write");
    let manifest = dataset::read_manifest(&out).expect("manifest");
    assert_eq!(manifest.condition, Some(expected.clone()));
    assert_eq!(
        dataset::load(&out).expect("load").condition(),
        expected.to_core().expect("core condition")
    );

    // A reversed range maps the other way; the spec's own values and unit win over the
    // column's.
    let text = mr_volts_spec(
        "range = [5.0, 0.0]",
        &format!("{MR_CONDITION}unit = \"mA\"\nat_alpha_0 = 20.0\nat_alpha_1 = 4.0\n"),
        &["mr.csv"],
    );
    let imported = import::import(&spec_from(&text, dir.path()), "mr").expect("import");
    let c = imported.dataset.condition.expect("condition");
    assert_eq!(
        (c.unit.as_str(), c.at_alpha_0, c.at_alpha_1),
        ("mA", 20.0, 4.0)
    );
    let reversed = imported.dataset.runs[0].alpha.as_ref().expect("levels");
    assert!(levels.iter().zip(reversed).all(|(a, b)| a + b == 1.0));
}

#[test]
fn without_gain_or_range_the_level_range_comes_from_the_data_of_every_file() {
    let dir = tempfile::tempdir().expect("dir");
    write_mr(dir.path(), "mr5.csv", None, 1.0); // 0, 2.5, 5 V
    write_mr(dir.path(), "mr10.csv", None, 2.0); // 0, 5, 10 V
    let text = mr_volts_spec("", MR_CONDITION, &["mr5.csv", "mr10.csv"]);
    let imported = import::import(&spec_from(&text, dir.path()), "mr").expect("import");
    assert_eq!(
        imported.level,
        Some(import::LevelMap::Range {
            at_0: 0.0,
            at_1: 10.0,
            unit: "V".into(),
            from_data: true
        })
    );
    let ds = &imported.dataset;
    let c = ds.condition.as_ref().expect("condition");
    assert_eq!(
        (c.at_alpha_0, c.at_alpha_1, c.unit.as_str()),
        (0.0, 10.0, "V")
    );
    // 5 V is alpha 0.5 in both files; the first file reaches only alpha 0.5.
    let first = ds.runs[0].alpha.as_ref().expect("levels");
    let second = ds.runs[1].alpha.as_ref().expect("levels");
    assert!(first.iter().all(|a| [0.0, 0.25, 0.5].contains(a)));
    assert!(first.contains(&0.25) && first.contains(&0.5));
    assert!(second.iter().all(|a| [0.0, 0.5, 1.0].contains(a)));
    assert!(second.contains(&1.0));

    // A constant column has no range to take.
    let flat = dir.path().join("flat.csv");
    write_simple(&flat, 2.0, 1.0);
    let text = std::fs::read_to_string(&flat).expect("flat");
    let with_level: String = text
        .lines()
        .enumerate()
        .map(|(i, l)| format!("{l},{}\n", if i == 0 { "U" } else { "2.5" }))
        .collect();
    std::fs::write(&flat, with_level).expect("write");
    let spec = format!(
        "{}[condition]\nname = \"v\"\nb_fl = \"none\"\nb_pr = \"none\"\nk_pr = \"none\"\n",
        simple_spec(&flat, "").replace(
            "[[files]]",
            "[columns.alpha]\nname = \"U\"\nunit = \"V\"\n[[files]]"
        )
    );
    let e = import::import(&spec_from(&spec, dir.path()), "flat").expect_err("constant");
    let msg = e.to_string();
    assert!(
        msg.contains("columns.alpha.range") && msg.contains("holds only 2.5"),
        "{msg}"
    );
}

#[test]
fn a_raw_level_outside_the_range_is_refused_with_file_line_and_column() {
    let dir = tempfile::tempdir().expect("dir");
    write_mr(dir.path(), "mr.csv", Some(4321), 1.0); // 6 V at line 4321
    let text = mr_volts_spec("range = [0.0, 5.0]", MR_CONDITION, &["mr.csv"]);
    let e = import::import(&spec_from(&text, dir.path()), "mr").expect_err("6 V is beyond 5 V");
    assert!(
        matches!(
            e,
            ImportError::LevelOutOfRange {
                line: 4321,
                field: 4,
                ..
            }
        ),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(
        msg.contains("mr.csv:4321:4: column \"U_ctrl_V\": 6 converts to the condition level 1.2")
            && msg.contains("range 0 .. 5 V"),
        "{msg}"
    );
}

#[test]
fn a_condition_without_name_or_priors_and_bad_level_mappings_are_refused_before_reading() {
    let dir = tempfile::tempdir().expect("dir");
    // No raw file exists: every error here comes from the spec alone.
    let refused = |text: &str| {
        import::validate_spec(&spec_from(text, dir.path()))
            .expect_err("refused")
            .to_string()
    };
    let no_name = refused(&mr_volts_spec("", "", &["mr.csv"]));
    assert!(
        no_name.contains("condition.name: missing") && no_name.contains("--condition-name"),
        "{no_name}"
    );
    let no_prior = refused(&mr_volts_spec(
        "",
        &MR_CONDITION.replace("k_pr = \"none\"\n", ""),
        &["mr.csv"],
    ));
    assert!(no_prior.contains("condition.k_pr: missing"), "{no_prior}");
    let long = refused(&mr_volts_spec(
        "",
        &MR_CONDITION.replace("control voltage", &"x".repeat(33)),
        &["mr.csv"],
    ));
    assert!(
        long.contains("condition.name") && long.contains("33 bytes"),
        "{long}"
    );
    let same = refused(&mr_volts_spec(
        "range = [1.0, 1.0]",
        MR_CONDITION,
        &["mr.csv"],
    ));
    assert!(same.contains("columns.alpha.range"), "{same}");
    let same = refused(&mr_volts_spec(
        "range = [0.0, 5.0]",
        &format!("{MR_CONDITION}at_alpha_0 = 5.0\n"),
        &["mr.csv"],
    ));
    assert!(same.contains("condition.at_alpha_1"), "{same}");
    let both = refused(&mr_volts_spec(
        "range = [0.0, 5.0]\ngain = 0.2",
        MR_CONDITION,
        &["mr.csv"],
    ));
    assert!(both.contains("either `range` or `gain`"), "{both}");
    let volts_gain = refused(&mr_volts_spec("gain = 0.2", MR_CONDITION, &["mr.csv"]));
    assert!(
        volts_gain.contains("columns.alpha.unit") && volts_gain.contains("range"),
        "{volts_gain}"
    );
    std::fs::write(
        dir.path().join("bad.toml"),
        mr_volts_spec(
            "",
            &MR_CONDITION.replace("\"none\"", "\"down\""),
            &["mr.csv"],
        ),
    )
    .expect("write");
    let e = import::read_spec(&dir.path().join("bad.toml")).expect_err("direction");
    assert!(matches!(e, ImportError::SpecSyntax { .. }), "{e:?}");
}

/// Runs `nemm` with `args`; its stdout, or a panic with its output.
fn nemm_ok(args: &[&std::ffi::OsStr]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(args)
        .output()
        .expect("run nemm");
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn the_cli_names_the_condition_with_flags_and_check_prints_rounded_levels() {
    let dir = tempfile::tempdir().expect("dir");
    let raw = dir.path().join("r.csv");
    write_simple(&raw, 3.0, 100.0);
    let out = dir.path().join("ds");
    let flags = [
        "--condition-name",
        "control voltage",
        "--condition-unit",
        "V",
        "--condition-range",
        "0,5",
        "--prior",
        "b_fl=increasing,b_pr=increasing",
        "--prior",
        "k_pr=none",
    ];
    // Without every prior, nothing is written.
    let o = Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(["data", "import"])
        .arg(&raw)
        .arg("--out")
        .arg(&out)
        .args(["--time", "t:s", "--displacement", "x:mm", "--force", "F:N"])
        .args(["--alpha", "0.5"])
        .args(&flags[..8])
        .output()
        .expect("run nemm");
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(stderr.contains("condition.k_pr: missing"), "{stderr}");
    assert!(!out.exists());

    let mut args: Vec<&std::ffi::OsStr> = ["data", "import"].map(std::ffi::OsStr::new).to_vec();
    args.extend([raw.as_os_str(), "--out".as_ref(), out.as_os_str()]);
    args.extend(
        [
            "--time",
            "t:s",
            "--displacement",
            "x:mm",
            "--force",
            "F:N",
            "--alpha",
            "0.4503572053013052",
        ]
        .map(std::ffi::OsStr::new),
    );
    args.extend(flags.map(std::ffi::OsStr::new));
    let report = nemm_ok(&args);
    assert!(
        report.contains(
            "condition: control voltage (alpha 0 = 0 V, alpha 1 = 5 V); priors in alpha: \
             b_fl increasing, b_pr increasing, k_pr none"
        ),
        "{report}"
    );
    assert!(
        report.contains("runs/r.csv: control voltage 2.2518 V (alpha 0.4504), 3000 samples"),
        "{report}"
    );
    let manifest = dataset::read_manifest(&out).expect("manifest");
    let c = manifest.condition.expect("condition");
    assert_eq!(
        (c.name.as_str(), c.unit.as_str(), c.at_alpha_0, c.at_alpha_1),
        ("control voltage", "V", 0.0, 5.0)
    );
    assert_eq!(
        (c.b_fl, c.b_pr, c.k_pr),
        (
            nemm_core::Direction::Increasing,
            nemm_core::Direction::Increasing,
            nemm_core::Direction::None
        )
    );
    // The manifest keeps the exact level; `data check` prints it rounded, by the name.
    assert_eq!(manifest.runs[0].oil_loss, 0.4503572053013052);
    let check = nemm_ok(&["data".as_ref(), "check".as_ref(), out.as_os_str()]);
    assert!(check.contains("control voltage levels:"), "{check}");
    assert!(
        check.contains("  control voltage 2.2518 V (alpha 0.4504): 1 runs, 3.0 s"),
        "{check}"
    );
    assert!(!check.contains("oil"), "{check}");
    assert!(!check.contains("0.45035"), "{check}");

    // A level column in volts from flags alone: its range comes from the data and is printed.
    let mr = write_mr(dir.path(), "mr.csv", None, 1.0);
    let out = dir.path().join("mr");
    let mut args: Vec<&std::ffi::OsStr> = ["data", "import"].map(std::ffi::OsStr::new).to_vec();
    args.extend([mr.as_os_str(), "--out".as_ref(), out.as_os_str()]);
    args.extend(
        [
            "--time",
            "time_s:s",
            "--displacement",
            "stroke_mm:mm",
            "--force",
            "force_kN:kN",
            "--alpha-column",
            "U_ctrl_V:V",
        ]
        .map(std::ffi::OsStr::new),
    );
    args.extend(
        [flags[0], flags[1], flags[6], flags[7], flags[8], flags[9]].map(std::ffi::OsStr::new),
    );
    let report = nemm_ok(&args);
    assert!(
        report.contains("level column: range 0 .. 5 V (the smallest and largest raw value"),
        "{report}"
    );
    let ds = dataset::load(&out).expect("load");
    let c = ds.condition.as_ref().expect("condition");
    assert_eq!(
        (c.unit.as_str(), c.at_alpha_0, c.at_alpha_1),
        ("V", 0.0, 5.0)
    );
    let levels = ds.runs[0].alpha.as_ref().expect("levels");
    assert!(levels.contains(&0.5) && levels.contains(&1.0));
    // --alpha-range fixes the range instead: 0-10 V puts 5 V at alpha 0.5.
    let mut fixed = args.clone();
    fixed.extend(["--alpha-range", "0,10", "--replace"].map(std::ffi::OsStr::new));
    let report = nemm_ok(&fixed);
    assert!(!report.contains("level column:"), "{report}");
    let ds = dataset::load(&out).expect("load");
    assert_eq!(ds.condition.as_ref().map(|c| c.at_alpha_1), Some(10.0));
    let levels = ds.runs[0].alpha.as_ref().expect("levels");
    assert!(levels.iter().all(|a| [0.0, 0.25, 0.5].contains(a)));
}
