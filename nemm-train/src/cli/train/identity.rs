//! What a checkpoint folder was trained on, and who writes it.
//!
//! `identity.json` holds the resolved configuration (data options, model, training; every
//! key but the per-invocation budget [`SESSION_KEYS`]) and fingerprints of the dataset's
//! manifest and of its run files' contents. Training afresh writes it; `--resume` compares it with the job's and refuses any
//! difference, naming each key with both values, so a checkpoint of another dataset, rate,
//! seed or learning rate is never continued. `lock` holds the pid of the process writing the
//! folder for as long as it runs: a second job on the same folder is refused; a lock left by
//! a process that no longer exists is taken over.

use super::{dataset, write_atomic_bytes, Config};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::hash::Hasher;
use std::path::{Path, PathBuf};

/// The identity file in a checkpoint folder.
pub(crate) const IDENTITY_FILE: &str = "identity.json";
/// The lock file in a checkpoint folder.
pub(crate) const LOCK_FILE: &str = "lock";
/// Keys a resumed session may change: the budget of one invocation.
pub(crate) const SESSION_KEYS: [&str; 2] = ["train.epochs", "train.session_epochs"];

/// Holds a checkpoint folder's lock; removes it when dropped.
#[derive(Debug)]
pub(crate) struct CheckpointLock {
    path: PathBuf,
}

impl Drop for CheckpointLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Takes the lock of checkpoint folder `dir` (created if needed), then writes its identity
/// (training afresh) or checks it against `cfg` (`resume`).
pub(crate) fn open_checkpoint(dir: &Path, cfg: &Config, resume: bool) -> Result<CheckpointLock> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let lock = take_lock(dir)?;
    let now = identity(cfg)?;
    let path = dir.join(IDENTITY_FILE);
    if resume {
        match std::fs::read_to_string(&path) {
            Ok(text) => {
                let recorded: BTreeMap<String, String> = serde_json::from_str(&text)
                    .with_context(|| format!("corrupt {}", path.display()))?;
                let diffs = differences(&recorded, &now);
                if !diffs.is_empty() {
                    bail!(
                        "--resume: the checkpoint in {} was trained on something else ({}); \
                         resume with the options it was trained with, or train afresh without \
                         --resume",
                        dir.display(),
                        diffs.join("; ")
                    );
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                if std::fs::read_dir(dir)?.any(|e| e.is_ok_and(|e| e.path() != lock.path)) {
                    bail!(
                        "--resume: {} holds no {IDENTITY_FILE}, so what its checkpoint was \
                         trained on cannot be checked; train afresh without --resume",
                        dir.display()
                    );
                }
            }
            Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
        }
    }
    write_atomic_bytes(&path, serde_json::to_string_pretty(&now)?.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(lock)
}

/// `key: checkpoint A, now B` for every key that differs or is in one map only.
fn differences(recorded: &BTreeMap<String, String>, now: &BTreeMap<String, String>) -> Vec<String> {
    let none = "(none)".to_string();
    let keys: std::collections::BTreeSet<&String> = recorded.keys().chain(now.keys()).collect();
    keys.into_iter()
        .filter_map(|k| {
            let (a, b) = (
                recorded.get(k).unwrap_or(&none),
                now.get(k).unwrap_or(&none),
            );
            (a != b).then(|| format!("{k}: checkpoint {a}, now {b}"))
        })
        .collect()
}

/// The identity of a job: its configuration as dotted keys, less [`SESSION_KEYS`], and the
/// FNV-1a fingerprints of its dataset's manifest (`dataset.manifest`) and of the contents
/// of every run file it lists (`dataset.runs`).
fn identity(cfg: &Config) -> Result<BTreeMap<String, String>> {
    fn flatten(prefix: &str, v: &toml::Value, out: &mut BTreeMap<String, String>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let key = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    flatten(&key, v, out);
                }
            }
            other => {
                out.insert(prefix.to_string(), other.to_string());
            }
        }
    }
    let mut out = BTreeMap::new();
    flatten("", &toml::Value::try_from(cfg)?, &mut out);
    for k in SESSION_KEYS {
        out.remove(k);
    }
    let dir = cfg.data.require_dir()?;
    let manifest = dir.join(dataset::MANIFEST_FILE);
    let bytes =
        std::fs::read(&manifest).with_context(|| format!("cannot read {}", manifest.display()))?;
    let mut h = fnv::FnvHasher::default();
    h.write(&bytes);
    out.insert("dataset.manifest".into(), format!("{:016x}", h.finish()));
    // The runs' contents: a run file edited in place changes the data as much as the manifest.
    let runs = dataset::read_manifest(dir)
        .map(|m| m.runs)
        .unwrap_or_default();
    let mut h = fnv::FnvHasher::default();
    for run in &runs {
        let path = dir.join(&run.file);
        h.write(run.file.to_string_lossy().as_bytes());
        let mut f = std::fs::File::open(&path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let mut buf = vec![0u8; 1 << 16];
        loop {
            use std::io::Read as _;
            let n = f
                .read(&mut buf)
                .with_context(|| format!("cannot read {}", path.display()))?;
            if n == 0 {
                break;
            }
            h.write(&buf[..n]);
        }
    }
    out.insert("dataset.runs".into(), format!("{:016x}", h.finish()));
    Ok(out)
}

/// Creates `dir/lock` with this process's pid; a lock of a live other process is refused, a
/// lock whose process no longer exists is taken over.
fn take_lock(dir: &Path) -> Result<CheckpointLock> {
    let path = dir.join(LOCK_FILE);
    let me = std::process::id();
    for _ in 0..2 {
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
        {
            Ok(mut f) => {
                use std::io::Write as _;
                writeln!(f, "{me}").with_context(|| format!("cannot write {}", path.display()))?;
                return Ok(CheckpointLock { path });
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                let text = std::fs::read_to_string(&path).unwrap_or_default();
                let pid: Option<u32> = text.trim().parse().ok();
                let alive = pid.is_some_and(|p| {
                    p == me
                        || !Path::new("/proc").is_dir()
                        || Path::new(&format!("/proc/{p}")).exists()
                });
                if alive {
                    bail!(
                        "checkpoint folder {} is in use by process {} ({}); wait for it to end \
                         or give another --checkpoint",
                        dir.display(),
                        pid.map_or("unknown".to_string(), |p| p.to_string()),
                        path.display()
                    );
                }
                eprintln!(
                    "taking over the stale lock {} (process {} no longer runs)",
                    path.display(),
                    text.trim()
                );
                std::fs::remove_file(&path)
                    .with_context(|| format!("cannot remove {}", path.display()))?;
            }
            Err(e) => return Err(e).with_context(|| format!("cannot create {}", path.display())),
        }
    }
    bail!("cannot take the lock {}", path.display())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn job(dir: &Path) -> Config {
        let data = dir.join("data");
        std::fs::create_dir_all(&data).unwrap();
        std::fs::write(data.join(dataset::MANIFEST_FILE), "name = \"d\"\n").unwrap();
        let mut c = Config::default();
        c.data.dir = data;
        c
    }

    #[test]
    fn resume_refuses_another_job_and_the_lock_refuses_a_second_writer() {
        let tmp = tempfile::tempdir().unwrap();
        let ck = tmp.path().join("ck");
        let cfg = job(tmp.path());
        drop(open_checkpoint(&ck, &cfg, false).unwrap());
        // The same job resumes, with another epoch budget too.
        let mut more = cfg.clone();
        more.train.epochs += 10;
        drop(open_checkpoint(&ck, &more, true).unwrap());
        // Another learning rate and seed: refused, naming both keys and values.
        let mut other = cfg.clone();
        other.train.lr = 1e-3;
        other.train.seed = 9;
        let e = open_checkpoint(&ck, &other, true).unwrap_err().to_string();
        assert!(
            e.contains("train.lr: checkpoint 0.005, now 0.001") && e.contains("train.seed"),
            "{e}"
        );
        // Another dataset (its manifest changed): refused.
        std::fs::write(cfg.data.dir.join(dataset::MANIFEST_FILE), "name = \"e\"\n").unwrap();
        let e = open_checkpoint(&ck, &cfg, true).unwrap_err().to_string();
        assert!(e.contains("dataset.manifest"), "{e}");
        // While a job holds the folder, a second one is refused; its lock goes with it.
        let held = open_checkpoint(&ck, &cfg, false).unwrap();
        let e = open_checkpoint(&ck, &cfg, false).unwrap_err().to_string();
        assert!(e.contains("is in use by process"), "{e}");
        drop(held);
        assert!(!ck.join(LOCK_FILE).exists());
        // A lock left by a process that no longer exists is taken over.
        std::fs::write(ck.join(LOCK_FILE), "4294967\n").unwrap();
        drop(open_checkpoint(&ck, &cfg, false).unwrap());
    }
}

#[cfg(test)]
mod run_content_tests {
    use super::*;

    #[test]
    fn resume_refuses_a_run_file_edited_in_place() {
        let tmp = tempfile::tempdir().unwrap();
        let e2e = Path::new(env!("CARGO_MANIFEST_DIR")).join("../nemm-firmware/data/e2e");
        let data = tmp.path().join("data");
        std::fs::create_dir_all(data.join("runs")).unwrap();
        std::fs::copy(
            e2e.join(dataset::MANIFEST_FILE),
            data.join(dataset::MANIFEST_FILE),
        )
        .unwrap();
        let manifest = dataset::read_manifest(&data).unwrap();
        for r in &manifest.runs {
            std::fs::copy(e2e.join(&r.file), data.join(&r.file)).unwrap();
        }
        let mut cfg = Config::default();
        cfg.data.dir = data.clone();
        let ck = tmp.path().join("ck");
        drop(open_checkpoint(&ck, &cfg, false).unwrap());
        drop(open_checkpoint(&ck, &cfg, true).unwrap());
        let run = data.join(&manifest.runs[0].file);
        let text = std::fs::read_to_string(&run).unwrap();
        std::fs::write(&run, text.replacen(',', ",1", 2)).unwrap();
        let e = open_checkpoint(&ck, &cfg, true).unwrap_err().to_string();
        assert!(
            e.contains("dataset.runs") && !e.contains("dataset.manifest"),
            "{e}"
        );
    }
}
