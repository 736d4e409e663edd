//! The output rule of every `nemm` command through the binary: each command's output options
//! pointed at each of its inputs (the dataset folder, its manifest and run files, raw files,
//! the model blob, the checkpoint folder) exit non-zero naming the path, before any work, and
//! leave every input byte-identical; an output of the other kind, an existing file that is
//! not a blob, an in-place `tables` that would drop stored tables and a fixture folder with
//! the user's files are refused; a symbolic link is written through.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("workspace")
        .to_path_buf()
}

/// Copies the tree `from` into `to`.
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("read").flatten() {
        let dst = to.join(e.file_name());
        if e.file_type().expect("type").is_dir() {
            copy_tree(&e.path(), &dst);
        } else {
            std::fs::copy(e.path(), &dst).expect("copy");
        }
    }
}

/// Every file under `dir` and its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dir).expect("read").flatten() {
        let p = e.path();
        if std::fs::symlink_metadata(&p)
            .expect("meta")
            .file_type()
            .is_symlink()
        {
            continue;
        } else if p.is_dir() {
            out.extend(snapshot(&p));
        } else {
            out.insert(p.clone(), std::fs::read(&p).expect("read"));
        }
    }
    out
}

/// A working folder: the committed model (`model.nemm`), the committed e2e dataset
/// (`data/`), a raw dyno file (`raw/level_00.csv`), a checkpoint-like folder
/// (`ck/nemm/...`) and a note of the user's (`notes.txt`).
struct Work {
    _tmp: tempfile::TempDir,
    root: PathBuf,
}

impl Work {
    fn new() -> Self {
        let tmp = tempfile::tempdir().expect("tempdir");
        let root = tmp.path().to_path_buf();
        let ws = workspace();
        std::fs::copy(
            ws.join("nemm-firmware/data/trained-nemm.nemm"),
            root.join("model.nemm"),
        )
        .expect("model");
        copy_tree(&ws.join("nemm-firmware/data/e2e"), &root.join("data"));
        std::fs::create_dir_all(root.join("raw")).expect("mkdir");
        std::fs::copy(
            ws.join("nemm-train/tests/fixtures/raw_dyno/level_00.csv"),
            root.join("raw/level_00.csv"),
        )
        .expect("raw");
        let epoch = root.join("ck/nemm/epoch-0001");
        std::fs::create_dir_all(&epoch).expect("mkdir");
        std::fs::write(epoch.join("best.bpk"), b"checkpoint bytes").expect("write");
        std::fs::write(root.join("ck/nemm/latest"), "epoch-0001\n").expect("write");
        std::fs::write(root.join("ck/nemm/frame.json"), "{}").expect("write");
        std::fs::write(root.join("notes.txt"), "a week of notes").expect("write");
        Work { _tmp: tmp, root }
    }

    fn p(&self, rel: &str) -> PathBuf {
        self.root.join(rel)
    }

    fn run_file(&self) -> PathBuf {
        let runs = self.p("data/runs");
        std::fs::read_dir(&runs)
            .expect("runs")
            .flatten()
            .map(|e| e.path())
            .min()
            .expect("a run")
    }

    /// Runs `nemm args` in the working folder and expects a refusal naming `named`, with
    /// every file of the working folder unchanged.
    fn refused(&self, args: &[&Path], named: &str) -> String {
        let before = snapshot(&self.root);
        let out = Command::new(env!("CARGO_BIN_EXE_nemm"))
            .current_dir(&self.root)
            .args(args)
            .output()
            .expect("run nemm");
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(!out.status.success(), "{args:?} succeeded:\n{stderr}");
        assert!(
            stderr.contains(named),
            "{args:?}: {named:?} not in\n{stderr}"
        );
        let after = snapshot(&self.root);
        assert_eq!(
            before.keys().collect::<Vec<_>>(),
            after.keys().collect::<Vec<_>>(),
            "{args:?}: files added or removed"
        );
        for (path, bytes) in &before {
            assert!(after[path] == *bytes, "{args:?} changed {}", path.display());
        }
        stderr
    }

    fn ok(&self, args: &[&Path]) -> String {
        let out = Command::new(env!("CARGO_BIN_EXE_nemm"))
            .current_dir(&self.root)
            .args(args)
            .output()
            .expect("run nemm");
        assert!(
            out.status.success(),
            "{args:?} failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }
}

fn p(s: &str) -> &Path {
    Path::new(s)
}

/// `nemm CMD --model MODEL --data DATA OPTION TARGET`.
fn with_model<'a>(
    cmd: &'a str,
    model: &'a Path,
    data: &'a Path,
    option: &'a str,
    target: &'a Path,
) -> [&'a Path; 7] {
    [
        p(cmd),
        p("--model"),
        model,
        p("--data"),
        data,
        p(option),
        target,
    ]
}

#[test]
fn no_command_writes_over_its_inputs() {
    let w = Work::new();
    let (data, model, manifest, run) = (
        w.p("data"),
        w.p("model.nemm"),
        w.p("data/manifest.toml"),
        w.run_file(),
    );
    let runs_dir = w.p("data/runs");
    let data_inputs: [&Path; 4] = [&data, &manifest, &run, &runs_dir];
    let run_name = run
        .file_name()
        .expect("name")
        .to_string_lossy()
        .into_owned();
    for target in data_inputs {
        let shown = target
            .file_name()
            .expect("name")
            .to_string_lossy()
            .into_owned();
        // The blob output of `tables` (its input is the model).
        w.refused(
            &[
                p("tables"),
                &model,
                p("--tables-alpha"),
                p("0.1"),
                p("--out"),
                target,
            ],
            &shown,
        );
        // The blob, JSON and folder outputs of the commands that read the dataset.
        for (cmd, option) in [
            (&["train", "--data"][..], "--out"),
            (&["data", "prepare"][..], "--out"),
            (&["train", "--data"][..], "--report"),
            (&["train", "--data"][..], "--checkpoint"),
            (&["compare", "--data"][..], "--report"),
            (&["sweep", "--data"][..], "--report"),
            (&["demo", "--data"][..], "--out"),
            (&["bench", "plot"][..], "--out"),
        ] {
            let mut args: Vec<&Path> = cmd.iter().map(|a| p(a)).collect();
            args.extend([data.as_path(), p(option), target]);
            w.refused(&args, &shown);
        }
        for cmd in ["identify", "diagnose"] {
            w.refused(&with_model(cmd, &model, &data, "--report", target), &shown);
        }
    }
    // A report folder that holds the model, and the model itself as a report folder.
    for cmd in ["identify", "diagnose"] {
        for target in [&w.root, &model] {
            w.refused(
                &with_model(cmd, &model, &data, "--report", target),
                "--report",
            );
        }
    }
    let e = w.refused(
        &[
            p("diagnose"),
            p("--model"),
            &model,
            p("--data"),
            &data,
            p("--report"),
            &w.root,
        ],
        "contains the input",
    );
    assert!(e.contains("model.nemm"), "{e}");
    // Relative paths, `..` and a run file named from inside the dataset.
    w.refused(
        &[
            p("train"),
            p("--data"),
            p("data"),
            p("--out"),
            p("raw/../data/runs/x.nemm"),
        ],
        "lies inside the input",
    );
    w.refused(
        &[
            p("data"),
            p("prepare"),
            p("data"),
            p("--out"),
            &Path::new("data/runs").join(&run_name),
        ],
        &run_name,
    );
    // The raw files of an import, and the folder that holds them.
    let raw = w.p("raw/level_00.csv");
    let import = |out: &Path, extra: &[&str]| -> Vec<PathBuf> {
        let mut args: Vec<PathBuf> = [
            "data",
            "import",
            raw.to_str().expect("utf-8"),
            "--time",
            "Time [ms]:ms",
            "--displacement",
            "Position [mm]:mm",
            "--force",
            "Force [lbf]:lbf",
            "--alpha",
            "0",
            "--out",
        ]
        .iter()
        .map(PathBuf::from)
        .collect();
        args.push(out.to_path_buf());
        args.extend(extra.iter().map(PathBuf::from));
        args
    };
    for (out, named) in [
        (raw.clone(), "is the input"),
        (w.p("raw"), "contains the input"),
        (w.root.clone(), "contains the input"),
        (PathBuf::from("."), "contains the input"),
        (w.p("notes.txt"), "is a file, not a folder"),
    ] {
        for extra in [&[][..], &["--replace"][..]] {
            let args = import(&out, extra);
            let args: Vec<&Path> = args.iter().map(PathBuf::as_path).collect();
            w.refused(&args, named);
        }
    }
    // The checkpoint of an export.
    let ck = w.p("ck/nemm");
    for target in [
        w.p("ck/nemm/epoch-0001/best.bpk"),
        w.p("ck/nemm/latest"),
        w.p("ck/nemm/frame.json"),
    ] {
        w.refused(
            &[p("export"), p("--checkpoint"), &ck, p("--out"), &target],
            "lies inside the input",
        );
    }
    // Outputs of the other kind, and a file that is not a blob.
    let notes = w.p("notes.txt");
    w.refused(
        &[p("bench"), p("generate"), p("--out"), &notes],
        "is a file, not a folder",
    );
    w.refused(
        &[
            p("identify"),
            p("--model"),
            &model,
            p("--data"),
            &data,
            p("--report"),
            &notes,
        ],
        "is a file, not a folder",
    );
    w.refused(
        &[p("tables"), &model, p("--out"), &notes],
        "not a NEMM weights blob",
    );
    w.refused(
        &[p("train"), p("--data"), &data, p("--out"), &notes],
        "not a NEMM weights blob",
    );
    w.refused(
        &[p("export"), p("--checkpoint"), &ck, p("--out"), &notes],
        "not a NEMM weights blob",
    );
    w.refused(
        &[p("tables"), &model, p("--out"), &w.p("raw")],
        "is a folder",
    );
}

#[test]
fn tables_in_place_refuses_to_drop_stored_tables() {
    let w = Work::new();
    let model = w.p("model.nemm");
    let stored = String::from_utf8_lossy(&std::fs::read(&model).expect("model")[..4]).into_owned();
    assert_eq!(stored, "NEMM");
    // The committed model stores level tables: rewriting it without table options drops them.
    let e = w.refused(&[p("tables"), &model, p("--out"), &model], "--drop-tables");
    assert!(
        e.contains("would drop") && e.contains("stored table(s)"),
        "{e}"
    );
    // Into another file the input stays as it is and the tables go only from the copy.
    let copy = w.p("copy.nemm");
    w.ok(&[p("tables"), &model, p("--out"), &copy]);
    assert!(
        std::fs::metadata(&copy).expect("copy").len()
            < std::fs::metadata(&model).expect("model").len()
    );
    // With the flag, in place.
    w.ok(&[p("tables"), &model, p("--out"), &model, p("--drop-tables")]);
    assert_eq!(
        std::fs::read(&model).expect("model"),
        std::fs::read(&copy).expect("copy")
    );
}

#[cfg(unix)]
#[test]
fn a_symbolic_link_output_is_written_through() {
    let w = Work::new();
    let model = w.p("model.nemm");
    let target = w.p("out/real.nemm");
    std::fs::create_dir_all(w.p("out")).expect("mkdir");
    let link = w.p("link.nemm");
    std::os::unix::fs::symlink(&target, &link).expect("symlink");
    w.ok(&[
        p("tables"),
        &model,
        p("--tables-alpha"),
        p("0.1"),
        p("--out"),
        &link,
    ]);
    assert!(std::fs::symlink_metadata(&link)
        .expect("link")
        .file_type()
        .is_symlink());
    assert_eq!(&std::fs::read(&target).expect("target")[..4], b"NEMM");
    // A dataset folder behind a link: the link stays, the folder behind it holds the dataset.
    let real = w.p("real-data");
    std::fs::create_dir_all(&real).expect("mkdir");
    let data_link = w.p("data-link");
    std::os::unix::fs::symlink(&real, &data_link).expect("symlink");
    let raw = w.p("raw/level_00.csv");
    w.ok(&[
        p("data"),
        p("import"),
        &raw,
        p("--time"),
        p("Time [ms]:ms"),
        p("--displacement"),
        p("Position [mm]:mm"),
        p("--force"),
        p("Force [lbf]:lbf"),
        p("--alpha"),
        p("0"),
        p("--out"),
        &data_link,
    ]);
    assert!(std::fs::symlink_metadata(&data_link)
        .expect("link")
        .file_type()
        .is_symlink());
    assert!(real.join("manifest.toml").is_file());
}

#[test]
fn bench_fixtures_and_generate_keep_the_users_files() {
    let w = Work::new();
    let out = w.p("fixtures");
    let mine = out.join("rate_300hz/runs/mine.csv");
    std::fs::create_dir_all(mine.parent().expect("parent")).expect("mkdir");
    std::fs::write(&mine, "my own run").expect("write");
    w.refused(&[p("bench"), p("fixtures"), p("--out"), &out], "mine.csv");
    std::fs::remove_file(&mine).expect("rm");
    w.ok(&[p("bench"), p("fixtures"), p("--out"), &out]);
    // Its own files are replaced again.
    w.ok(&[p("bench"), p("fixtures"), p("--out"), &out]);
    // `bench generate` does not replace a dataset it did not generate without --replace.
    let data = w.p("data");
    w.refused(&[p("bench"), p("generate"), p("--out"), &data], "--replace");
}
