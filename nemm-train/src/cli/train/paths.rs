//! Checks of the output paths before a job trains: a path that cannot be written is
//! reported before the training it would lose, naming the option and the path.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// `path` given as `option` (e.g. `--out`) can be written as a file: it is not a folder, its
/// parent folder exists, and a probe file can be created there (created with `create_new`
/// and removed at once).
pub fn check_output_file(option: &str, path: &Path) -> Result<()> {
    if path.is_dir() {
        bail!(
            "{option} {}: is a folder; give a file path, e.g. {}",
            path.display(),
            path.join("model.nemm").display()
        );
    }
    let parent = match path.parent() {
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
pub fn check_output_dir(option: &str, path: &Path) -> Result<()> {
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
}
