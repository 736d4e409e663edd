//! Records the commit the trainer is built from (`NEMM_GIT_COMMIT`: `git rev-parse --short
//! HEAD`, with `+dirty` when tracked files differ from it; `unknown` outside a git checkout),
//! so every report names the code that produced it. The script reruns when HEAD, the index
//! or the sources of the trainer, nemm-core, nemm-dataset and nemm-virtual-bench change.
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn main() {
    let commit = git(&["rev-parse", "--short", "HEAD"]).unwrap_or_else(|| "unknown".into());
    let dirty =
        git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
    let suffix = if dirty { "+dirty" } else { "" };
    println!("cargo:rustc-env=NEMM_GIT_COMMIT={commit}{suffix}");
    if let Some(dir) = git(&["rev-parse", "--git-dir"]) {
        println!("cargo:rerun-if-changed={dir}/HEAD");
        println!("cargo:rerun-if-changed={dir}/index");
    }
    // The sources whose edits make the tree dirty: without these the script would rerun only
    // when HEAD or the index move, and a binary built from an edited tree would carry a clean
    // commit.
    for dir in [
        "src",
        "Cargo.toml",
        "../nemm-core/src",
        "../nemm-core/Cargo.toml",
        "../nemm-dataset/src",
        "../nemm-dataset/Cargo.toml",
        "../nemm-virtual-bench/src",
        "../nemm-virtual-bench/assets",
        "../nemm-virtual-bench/Cargo.toml",
    ] {
        println!("cargo:rerun-if-changed={dir}");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
