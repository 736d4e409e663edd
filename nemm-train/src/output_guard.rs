//! The one output rule of every `nemm` command, checked before any work: each output path
//! (a file or a folder, resolved through symbolic links) must not be, lie inside or contain
//! an input of the command (a dataset folder and its files, raw files, model blobs,
//! checkpoint folders), must not name an existing path of the other kind (a folder where a
//! file is written, or a file where a folder is), and must be writable. An existing file
//! that is not of the output's own kind (a weights blob where a blob is written) is replaced
//! only with the command's explicit flag.
//!
//! Outputs are written through symbolic links: the link stays and its target gets the new
//! content ([`resolve_link`], used by [`nemm_dataset::atomic_file::write_atomic`] and the dataset
//! writer).

use anyhow::{bail, Context, Result};
use nemm_dataset::atomic_file;
pub(crate) use nemm_dataset::atomic_file::resolve_link;
use std::path::{Path, PathBuf};

/// What a command writes at an output path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum OutputKind {
    /// A weights blob (`.nemm`): an existing file that is not one is replaced only with the
    /// command's replace flag.
    Blob,
    /// A file of any content (a JSON summary).
    File,
    /// A folder the command creates or writes files into.
    Folder,
    /// A dataset folder, replaced as a whole by a swap of folders: also not the current
    /// folder or one that holds it.
    Dataset,
}

/// One output of a command: the option that names it, its path and its kind.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Output<'a> {
    /// The option, e.g. `--out`.
    pub(crate) option: &'a str,
    /// The path as given.
    pub(crate) path: &'a Path,
    /// What is written there.
    pub(crate) kind: OutputKind,
}

impl<'a> Output<'a> {
    /// A weights blob written at `path`, named by `option`.
    pub(crate) fn blob(option: &'a str, path: &'a Path) -> Self {
        Self {
            option,
            path,
            kind: OutputKind::Blob,
        }
    }

    /// A file written at `path`, named by `option`.
    pub(crate) fn file(option: &'a str, path: &'a Path) -> Self {
        Self {
            option,
            path,
            kind: OutputKind::File,
        }
    }

    /// A folder written at `path`, named by `option`.
    pub(crate) fn folder(option: &'a str, path: &'a Path) -> Self {
        Self {
            option,
            path,
            kind: OutputKind::Folder,
        }
    }

    /// A dataset folder written (replaced as a whole) at `path`, named by `option`.
    pub(crate) fn dataset(option: &'a str, path: &'a Path) -> Self {
        Self {
            option,
            path,
            kind: OutputKind::Dataset,
        }
    }
}

/// One input, resolved.
#[derive(Debug, Clone)]
struct Input {
    /// What it is, e.g. `the dataset's manifest`.
    what: String,
    /// The path as given (for messages).
    given: PathBuf,
    /// The path resolved through symbolic links.
    resolved: PathBuf,
    /// A folder (outputs inside it are refused too).
    folder: bool,
}

/// The inputs of a command, each resolved through symbolic links. Inputs that do not exist
/// are left out (the command reports them when it reads them).
#[derive(Debug, Clone, Default)]
pub(crate) struct Inputs(Vec<Input>);

impl Inputs {
    /// No inputs.
    pub(crate) fn new() -> Self {
        Self::default()
    }

    /// An input file or folder `path`, described as `what` (e.g. `--model`).
    pub(crate) fn path(mut self, what: &str, path: &Path) -> Self {
        if let Ok(resolved) = std::fs::canonicalize(path) {
            self.0.push(Input {
                what: what.to_string(),
                given: path.to_path_buf(),
                folder: resolved.is_dir(),
                resolved,
            });
        }
        self
    }

    /// Input files `paths`, each described as `what`.
    pub(crate) fn paths<'p>(self, what: &str, paths: impl IntoIterator<Item = &'p Path>) -> Self {
        paths.into_iter().fold(self, |s, p| s.path(what, p))
    }

    /// The dataset folder `dir` (`what`: its option, e.g. `--data`), its manifest and every
    /// run file the manifest lists (run files may lie outside the folder).
    pub(crate) fn dataset(self, what: &str, dir: &Path) -> Self {
        let manifest = dir.join(nemm_dataset::MANIFEST_FILE);
        let runs: Vec<PathBuf> = nemm_dataset::read_manifest(dir)
            .map(|m| m.runs.iter().map(|r| dir.join(&r.file)).collect())
            .unwrap_or_default();
        let mut s = self
            .path(what, dir)
            .path(&format!("{what}'s manifest"), &manifest);
        for run in &runs {
            s = s.path(&format!("{what}'s run file"), run);
        }
        s
    }
}

/// `path` absolute and resolved through symbolic links: canonical when it exists, else its
/// nearest existing ancestor canonical and the rest appended (`..` and `.` folded)
/// ([`nemm_dataset::atomic_file::resolve`]).
pub(crate) fn resolve(path: &Path) -> Result<PathBuf> {
    atomic_file::resolve(path).context("cannot read the current folder")
}

/// Checks every output of a command against its inputs, before any work: each output
/// (resolved through symbolic links) must not equal an input, lie inside an input folder or
/// (a folder) contain an input; must not name an existing path of the other kind; must be
/// writable ([`check_output_file`], [`check_output_dir`]); and an existing file at a blob
/// output must be a weights blob unless `replace` (the command's flag `replace_flag`) is
/// given. Each refusal names the option, the path and the input.
pub(crate) fn check(
    outputs: &[Output<'_>],
    inputs: &Inputs,
    replace: bool,
    replace_flag: &str,
) -> Result<()> {
    for out in outputs {
        let resolved = resolve(out.path)?;
        let shown = |r: &Path| {
            if r == out.path {
                format!("{}", out.path.display())
            } else {
                format!("{} (= {})", out.path.display(), r.display())
            }
        };
        for input in &inputs.0 {
            let relation = if resolved == input.resolved {
                "is"
            } else if input.folder && resolved.starts_with(&input.resolved) {
                "lies inside"
            } else if matches!(out.kind, OutputKind::Folder | OutputKind::Dataset)
                && input.resolved.starts_with(&resolved)
            {
                "contains"
            } else {
                continue;
            };
            bail!(
                "{} {}: {relation} the input {} ({}); a command never writes over its \
                 inputs: choose another {} path",
                out.option,
                shown(&resolved),
                input.given.display(),
                input.what,
                out.option
            );
        }
        if out.kind == OutputKind::Dataset {
            let cwd = resolve(Path::new("."))?;
            if cwd.starts_with(&resolved) {
                bail!(
                    "{} {}: is the current folder or holds it; the dataset is swapped in as a \
                     whole folder: give the path of a folder to create, e.g. {}",
                    out.option,
                    shown(&resolved),
                    Path::new("..").join("dataset").display()
                );
            }
        }
        match out.kind {
            OutputKind::Folder | OutputKind::Dataset => check_output_dir(out.option, out.path)?,
            OutputKind::File | OutputKind::Blob => check_output_file(out.option, out.path)?,
        }
        if out.kind == OutputKind::Blob && resolved.is_file() && !replace && !is_blob(&resolved) {
            bail!(
                "{} {}: an existing file that is not a NEMM weights blob; give {replace_flag} \
                 to replace it, or choose another {} path",
                out.option,
                shown(&resolved),
                out.option
            );
        }
    }
    Ok(())
}

/// `true` when the file at `path` starts with the weights blob's magic bytes.
fn is_blob(path: &Path) -> bool {
    use std::io::Read as _;
    let mut magic = [0u8; 4];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok_and(|()| magic == nemm_core::MAGIC)
}

/// `path` given as `option` (e.g. `--out`) can be written as a file: it is not a folder, its
/// parent folder exists, and a probe file can be created there (created with `create_new`
/// and removed at once).
pub(crate) fn check_output_file(option: &str, path: &Path) -> Result<()> {
    if path.is_dir() {
        bail!(
            "{option} {}: is a folder; give a file path, e.g. {}",
            path.display(),
            path.join("model.nemm").display()
        );
    }
    let target = resolve_link(path);
    let parent = match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if !parent.is_dir() {
        bail!(
            "{option} {}: the folder {} does not exist; create it first (mkdir -p {})",
            path.display(),
            parent.display(),
            parent.display()
        );
    }
    probe(option, path, &parent)
}

/// `path` given as `option` (e.g. `--report`) can be used as an output folder: it is a
/// writable folder, or it does not exist and its nearest existing ancestor is a writable
/// folder (the job creates it).
pub(crate) fn check_output_dir(option: &str, path: &Path) -> Result<()> {
    let mut existing = path.to_path_buf();
    loop {
        if existing.exists() {
            break;
        }
        match existing.parent() {
            Some(p) if !p.as_os_str().is_empty() => existing = p.to_path_buf(),
            _ => {
                existing = PathBuf::from(".");
                break;
            }
        }
    }
    if !existing.is_dir() {
        bail!(
            "{option} {}: {} is a file, not a folder; give a folder path or remove the file",
            path.display(),
            existing.display()
        );
    }
    probe(option, path, &existing)
}

/// Creates and removes a probe file in `dir` to show it is writable.
fn probe(option: &str, path: &Path, dir: &Path) -> Result<()> {
    let name = format!(".nemm-write-probe-{}", std::process::id());
    let probe = dir.join(name);
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .with_context(|| {
            format!(
                "{option} {}: cannot write into {}; choose a writable location",
                path.display(),
                dir.display()
            )
        })?;
    std::fs::remove_file(&probe)
        .with_context(|| format!("cannot remove the probe file {}", probe.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_paths_are_checked_before_training() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path();
        check_output_file("--out", &dir.join("m.nemm")).expect("writable");
        let e = check_output_file("--out", dir).unwrap_err().to_string();
        assert!(e.contains("is a folder"), "{e}");
        let e = check_output_file("--out", &dir.join("no/m.nemm"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("does not exist") && e.contains("mkdir -p"),
            "{e}"
        );
        let e = format!(
            "{:#}",
            check_output_file("--out", Path::new("/proc/m.nemm")).unwrap_err()
        );
        assert!(e.contains("cannot write into /proc"), "{e}");
        check_output_dir("--report", &dir.join("a/b")).expect("creatable");
        let file = dir.join("f");
        std::fs::write(&file, "x").expect("write");
        let e = check_output_dir("--report", &file).unwrap_err().to_string();
        assert!(e.contains("is a file, not a folder"), "{e}");
        let e = check_output_dir("--report", &file.join("sub"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("is a file"), "{e}");
        // No probe file is left behind.
        assert_eq!(std::fs::read_dir(dir).expect("read").count(), 1);
    }

    #[test]
    fn outputs_on_inputs_are_refused_naming_both() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path();
        let data = dir.join("data");
        std::fs::create_dir_all(data.join("runs")).expect("mkdir");
        std::fs::write(data.join("runs/a.csv"), "x").expect("write");
        let notes = dir.join("notes.txt");
        std::fs::write(&notes, "mine").expect("write");
        let inputs = Inputs::new().path("--data", &data);
        let refused = |o: Output<'_>| {
            check(&[o], &inputs, false, "--replace")
                .unwrap_err()
                .to_string()
        };
        let e = refused(Output::folder("--out", &data));
        assert!(e.contains("--out") && e.contains(" is the input"), "{e}");
        let e = refused(Output::blob("--out", &data.join("runs/a.csv")));
        assert!(e.contains("lies inside the input"), "{e}");
        let e = refused(Output::folder("--report", dir));
        assert!(e.contains("contains the input"), "{e}");
        // Through a `..` and a symbolic link to the input.
        let e = refused(Output::folder("--out", &dir.join("x/../data/new")));
        assert!(e.contains("lies inside"), "{e}");
        #[cfg(unix)]
        {
            let link = dir.join("link");
            std::os::unix::fs::symlink(&data, &link).expect("symlink");
            let e = refused(Output::file("--out", &link.join("s.json")));
            assert!(e.contains("lies inside"), "{e}");
        }
        // A file of another kind where a blob goes, and a folder over a file.
        let e = refused(Output::blob("--out", &notes));
        assert!(
            e.contains("not a NEMM weights blob") && e.contains("--replace"),
            "{e}"
        );
        check(&[Output::blob("--out", &notes)], &inputs, true, "--replace").expect("replace");
        let e = refused(Output::folder("--out", &notes));
        assert!(e.contains("is a file, not a folder"), "{e}");
        check(
            &[Output::folder("--out", &dir.join("new"))],
            &inputs,
            false,
            "",
        )
        .expect("free");
        assert_eq!(std::fs::read(&notes).expect("read"), b"mine");
    }
}
