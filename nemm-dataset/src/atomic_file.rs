//! Files written atomically and through symbolic links: the dataset writer's and every
//! other output of the trainer (weights blobs, reports, configurations).
use std::io::Write;
use std::path::{Component, Path, PathBuf};

/// Writes a file atomically: the content goes to a [`tempfile::NamedTempFile`] in the same
/// folder (created if missing; with a plain file's permissions), which is flushed to disk and then persisted (renamed) over
/// `path`. A crash leaves either the old file or the new one, never a partial file; on error
/// the temporary file is removed. A symbolic link at `path` is written through: the link
/// stays and its target gets the content ([`resolve_link`]).
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let target = resolve_link(path);
    let path = target.as_path();
    let parent = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(parent)?;
    let mut builder = tempfile::Builder::new();
    // A plain file's mode (0o666 less the umask), not the temporary file's 0o600.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    let tmp = builder.tempfile_in(parent)?;
    let mut w = std::io::BufWriter::with_capacity(1 << 16, tmp);
    fill(&mut w)?;
    let tmp = w.into_inner().map_err(|e| e.into_error())?;
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

/// [`write_atomic`] of a byte slice.
pub fn write_atomic_bytes(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic(path, |w| w.write_all(bytes))
}

/// `path` with its last component's symbolic links followed (up to 40 links): the path an
/// output is written to so that a symbolic link stays and its target gets the content.
/// A path that is not a link is returned as it is.
pub fn resolve_link(path: &Path) -> PathBuf {
    let mut p = path.to_path_buf();
    for _ in 0..40 {
        match std::fs::read_link(&p) {
            Ok(target) if target.is_absolute() => p = target,
            Ok(target) => {
                let parent = p.parent().map(Path::to_path_buf).unwrap_or_default();
                p = parent.join(target);
            }
            Err(_) => break,
        }
    }
    p
}

/// `path` absolute and resolved through symbolic links: canonical when it exists, else its
/// nearest existing ancestor canonical and the rest appended (`..` and `.` folded). Fails
/// only when the path is relative and the current folder cannot be read.
pub fn resolve(path: &Path) -> std::io::Result<PathBuf> {
    let path = resolve_link(path);
    if let Ok(p) = std::fs::canonicalize(&path) {
        return Ok(p);
    }
    let given = if path.is_absolute() {
        path
    } else {
        std::env::current_dir()?.join(path)
    };
    // `..` after the part that exists resolves from that part's real location.
    let mut absolute = PathBuf::new();
    for c in given.components() {
        match c {
            Component::ParentDir => {
                absolute = std::fs::canonicalize(&absolute).unwrap_or(absolute);
                absolute.pop();
            }
            Component::CurDir => {}
            other => absolute.push(other),
        }
    }
    let mut rest = Vec::new();
    let mut base = absolute.as_path();
    let mut out = loop {
        match std::fs::canonicalize(base) {
            Ok(p) => break p,
            Err(_) => match (base.parent(), base.file_name()) {
                (Some(parent), Some(name)) => {
                    rest.push(name.to_os_string());
                    base = parent;
                }
                _ => break base.to_path_buf(),
            },
        }
    };
    out.extend(rest.iter().rev());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_replaces_without_leftovers() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("sub");
        let p = dir.join("a.bin");
        write_atomic_bytes(&p, b"one").unwrap();
        write_atomic_bytes(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        // A failing writer leaves the old content and no temporary file.
        let err = write_atomic(&p, |_| Err(std::io::Error::other("boom")));
        assert!(err.is_err());
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&p).unwrap().permissions().mode();
            assert_eq!(mode & 0o044, 0o044, "readable like a plain file: {mode:o}");
            // A symbolic link is written through: the link stays, its target changes.
            let link = dir.join("link.bin");
            std::os::unix::fs::symlink("a.bin", &link).unwrap();
            write_atomic_bytes(&link, b"three").unwrap();
            assert!(std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink());
            assert_eq!(std::fs::read(&p).unwrap(), b"three");
        }
    }
}
