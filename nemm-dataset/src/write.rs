//! Writing a dataset: the runs validated as loading would, then written atomically.

use crate::load::{check_alpha, check_increasing, check_time_grid, sample_line};
use crate::manifest::{read_manifest_with_lines, validate_manifest};
use crate::{
    io_err, Dataset, DatasetError, Run, COL_ALPHA, COL_DISPLACEMENT, COL_FORCE, COL_TIME,
    COL_VELOCITY, MANIFEST_FILE,
};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
/// Checks an in-memory run as [`load`](crate::load()) would check its file (lengths, finite values, time).
fn validate_run(run: &Run, path: &Path, sample_rate_hz: f64) -> Result<(), DatasetError> {
    let n = run.time_s.len();
    if n == 0 {
        return Err(DatasetError::NoSamples {
            path: path.to_path_buf(),
            line: 2,
        });
    }
    let mut columns: Vec<(&str, &[f64])> = vec![
        (COL_TIME, &run.time_s),
        (COL_DISPLACEMENT, &run.displacement_m),
        (COL_FORCE, &run.force_n),
    ];
    if let Some(v) = &run.velocity_m_s {
        columns.push((COL_VELOCITY, v));
    }
    if let Some(a) = &run.alpha {
        columns.push((COL_ALPHA, a));
    }
    for (name, values) in &columns {
        if values.len() != n {
            return Err(DatasetError::LengthMismatch {
                path: path.to_path_buf(),
                column: (*name).to_string(),
                expected: n,
                found: values.len(),
            });
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(DatasetError::NonFinite {
                path: path.to_path_buf(),
                line: sample_line(i),
                column: (*name).to_string(),
                value: values[i].to_string(),
            });
        }
    }
    if let Some(a) = &run.alpha {
        for (i, &value) in a.iter().enumerate() {
            check_alpha(value, path, sample_line(i))?;
        }
    }
    for (i, w) in run.time_s.windows(2).enumerate() {
        check_increasing(w[0], w[1], path, sample_line(i + 1))?;
    }
    check_time_grid(&run.time_s, sample_rate_hz, path, sample_line)?;
    Ok(())
}

/// [`crate::atomic_file::write_atomic`] with the dataset's error type (naming the file).
fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> Result<(), DatasetError> {
    crate::atomic_file::write_atomic(path, fill).map_err(|error| DatasetError::Io {
        path: path.to_path_buf(),
        error,
    })
}

/// Writes one run as CSV (`time_s,displacement_m,force_n[,velocity_m_s][,alpha]`).
fn write_run_csv(run: &Run, w: &mut dyn std::io::Write) -> std::io::Result<()> {
    let mut line = String::with_capacity(128);
    line.push_str("time_s,displacement_m,force_n");
    if run.velocity_m_s.is_some() {
        line.push_str(",velocity_m_s");
    }
    if run.alpha.is_some() {
        line.push_str(",alpha");
    }
    line.push('\n');
    w.write_all(line.as_bytes())?;
    for i in 0..run.time_s.len() {
        line.clear();
        // `{}` on f64 prints the shortest decimal that parses back to the same value.
        let _ = write!(
            line,
            "{},{},{}",
            run.time_s[i], run.displacement_m[i], run.force_n[i]
        );
        if let Some(v) = &run.velocity_m_s {
            let _ = write!(line, ",{}", v[i]);
        }
        if let Some(a) = &run.alpha {
            let _ = write!(line, ",{}", a[i]);
        }
        line.push('\n');
        w.write_all(line.as_bytes())?;
    }
    Ok(())
}

/// The files of the dataset in `dir` (its manifest, the run files it lists and its saved data
/// options), as `dir`-relative paths; empty when `dir` holds no manifest. A manifest that does not parse
/// counts as the manifest alone.
fn old_dataset_files(dir: &Path) -> std::collections::HashSet<PathBuf> {
    let mut files = std::collections::HashSet::new();
    if !dir.join(MANIFEST_FILE).is_file() {
        return files;
    }
    files.insert(PathBuf::from(MANIFEST_FILE));
    // The data options saved for the old dataset do not belong to the new one.
    files.insert(PathBuf::from(crate::DATA_OPTIONS_FILE));
    if let Ok((manifest, _)) = read_manifest_with_lines(dir) {
        files.extend(manifest.runs.iter().map(|r| r.file.clone()));
    }
    files
}

/// Copies the tree `from` into `to` (created) as hard links, leaving out the `dir`-relative
/// paths in `skip`; symbolic links are recreated, files that cannot be linked are copied.
fn carry_over(
    from: &Path,
    to: &Path,
    rel: &Path,
    skip: &std::collections::HashSet<PathBuf>,
) -> std::io::Result<()> {
    for entry in std::fs::read_dir(from.join(rel))? {
        let entry = entry?;
        let r = rel.join(entry.file_name());
        if skip.contains(&r) {
            continue;
        }
        let kind = entry.file_type()?;
        let (src, dst) = (from.join(&r), to.join(&r));
        if kind.is_dir() {
            std::fs::create_dir_all(&dst)?;
            carry_over(from, to, &r, skip)?;
        } else if kind.is_symlink() {
            #[cfg(unix)]
            std::os::unix::fs::symlink(std::fs::read_link(&src)?, &dst)?;
            #[cfg(not(unix))]
            std::fs::copy(&src, &dst).map(|_| ())?;
        } else if std::fs::hard_link(&src, &dst).is_err() {
            std::fs::copy(&src, &dst)?;
        }
    }
    Ok(())
}

/// A sibling path of `dir` (same parent, so on the same file system) that does not exist:
/// `.<name>.<tag>-<pid>-<n>`.
fn sibling(dir: &Path, tag: &str) -> PathBuf {
    let name = dir
        .file_name()
        .map_or("dataset".into(), |n| n.to_string_lossy().into_owned());
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    (0u32..)
        .map(|n| parent.join(format!(".{name}.{tag}-{}-{n}", std::process::id())))
        .find(|p| std::fs::symlink_metadata(p).is_err())
        .expect("a free name")
}

/// The sibling folders `.<name>.new-*` and `.<name>.old-*` of `dir` left by a write that was
/// killed (their process no longer runs). When `dir` holds a dataset they are removed, each
/// with a message; otherwise they are named in a message only, as one of them may hold the
/// only complete copy.
fn clean_leftovers(dir: &Path) {
    let Some(name) = dir.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return;
    };
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let Ok(entries) = std::fs::read_dir(parent) else {
        return;
    };
    let complete = dir.join(MANIFEST_FILE).is_file();
    for e in entries.flatten() {
        let file = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = ["new", "old"]
            .iter()
            .find_map(|tag| file.strip_prefix(&format!(".{name}.{tag}-")))
        else {
            continue;
        };
        let pid = rest.split('-').next().and_then(|p| p.parse::<u32>().ok());
        let running = pid.is_some_and(|p| {
            p == std::process::id()
                || !Path::new("/proc").is_dir()
                || Path::new(&format!("/proc/{p}")).exists()
        });
        if pid.is_none() || running {
            continue;
        }
        let path = e.path();
        if complete && std::fs::remove_dir_all(&path).is_ok() {
            eprintln!(
                "removed {}, left by an interrupted write of {}",
                path.display(),
                dir.display()
            );
        } else if !complete {
            eprintln!(
                "note: {} was left by an interrupted write of {}; it may hold a complete \
                 dataset (look for its manifest.toml) and is kept",
                path.display(),
                dir.display()
            );
        }
    }
}

/// Writes `dataset` to the folder `dir`, replacing the dataset `dir` holds as a whole.
///
/// The dataset is validated first with the same rules as [`load`](crate::load()), so whatever `write`
/// accepts, `load` reads back exactly. The new dataset is built in a sibling temporary
/// folder: every run CSV at its manifest path, then `manifest.toml`, each file written
/// atomically, and the files of `dir` that belong to no dataset (neither the old manifest,
/// nor a run file it lists, nor a path of the new dataset) hard-linked in. The folders are
/// then swapped with renames: `dir` moves to a sibling `.<name>.old-*`, the new folder
/// takes its place, and the old one is removed. A kill at any point leaves the old or the
/// new dataset complete: in `dir`, or (between the two renames) in the sibling
/// `.<name>.old-*` and `.<name>.new-*` folders, which the next write into `dir` removes (when
/// `dir` holds a dataset) or names (when not). A symbolic link `dir` is written through (its
/// target folder is replaced, the link stays); an existing `dir` that is not a folder is
/// refused. The old dataset's run files are removed
/// with it, so no run file of an earlier dataset is left behind.
///
/// Callers that must not replace a dataset check for one first (`nemm data import` refuses
/// without `--replace`); `nemm bench generate` replaces its own output folder.
pub fn write(dir: &Path, dataset: &Dataset) -> Result<(), DatasetError> {
    use rayon::prelude::*;
    // A symbolic link to a folder is written through: the link stays.
    let dir = &crate::atomic_file::resolve(dir).unwrap_or_else(|_| dir.to_path_buf());
    if std::fs::symlink_metadata(dir).is_ok_and(|m| !m.is_dir()) {
        return Err(DatasetError::Io {
            path: dir.clone(),
            error: std::io::Error::other("exists and is not a folder; the dataset was not written"),
        });
    }
    let manifest = dataset.manifest();
    let manifest_path = dir.join(MANIFEST_FILE);
    validate_manifest(&manifest, &manifest_path, None)?;
    for run in &dataset.runs {
        validate_run(run, &dir.join(&run.entry.file), dataset.sample_rate_hz)?;
    }
    let text = toml::to_string(&manifest).map_err(|e| DatasetError::ManifestValue {
        path: manifest_path.clone(),
        line: None,
        key: "(manifest)".into(),
        message: format!("cannot be encoded as TOML: {e}"),
    })?;
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(io_err(parent))?;
    }
    clean_leftovers(dir);
    let new = sibling(dir, "new");
    let built = (|| {
        std::fs::create_dir(&new).map_err(io_err(&new))?;
        if dir.is_dir() {
            let mut skip = old_dataset_files(dir);
            skip.insert(PathBuf::from(MANIFEST_FILE));
            skip.extend(dataset.runs.iter().map(|r| r.entry.file.clone()));
            carry_over(dir, &new, Path::new(""), &skip).map_err(io_err(dir))?;
        }
        dataset
            .runs
            .par_iter()
            .map(|run| write_atomic(&new.join(&run.entry.file), |w| write_run_csv(run, w)))
            .collect::<Result<Vec<()>, _>>()?;
        write_atomic(&new.join(MANIFEST_FILE), |w| w.write_all(text.as_bytes()))
    })();
    if let Err(e) = built {
        let _ = std::fs::remove_dir_all(&new);
        return Err(e);
    }
    if std::fs::symlink_metadata(dir).is_ok() {
        let old = sibling(dir, "old");
        std::fs::rename(dir, &old).map_err(io_err(dir))?;
        std::fs::rename(&new, dir).map_err(io_err(dir))?;
        std::fs::remove_dir_all(&old).map_err(io_err(&old))?;
    } else {
        std::fs::rename(&new, dir).map_err(io_err(dir))?;
    }
    Ok(())
}
