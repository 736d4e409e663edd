//! Finding a toolchain that builds the firmware for `thumbv7em-none-eabihf` (Cortex-M4F) and
//! the emulator that runs it, and saying exactly what is missing when there is none.
//!
//! Routes, in order of preference:
//!
//! 1. **rustup** with the `thumbv7em-none-eabihf` target installed: the stable `cargo` that
//!    runs xtask builds the firmware (precompiled `core`).
//! 2. **Debian** packages `rustc-web`, `cargo-web`, `rust-web-src` and `lld`: `/usr/bin/cargo`
//!    with `RUSTC=/usr/bin/rustc` builds `core` from `/usr/lib/rustlib/src` (`-Zbuild-std`,
//!    enabled with `RUSTC_BOOTSTRAP=1`) and links with `ld.lld`.
//!
//! Both need `qemu-system-arm` (package `qemu-system-arm`). If neither route is complete and
//! xtask runs as root on a machine with `apt-get`, it installs the Debian packages (and says
//! so); otherwise it fails with the commands to run.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The firmware's target.
pub const TARGET: &str = "thumbv7em-none-eabihf";
/// Oldest rustc that builds the firmware (its `rust-version`).
const MIN_RUSTC: (u32, u32) = (1, 87);
/// Debian packages of the Debian route (and the emulator).
pub const DEBIAN_PACKAGES: &[&str] = &[
    "rustc-web",
    "cargo-web",
    "rust-web-src",
    "lld",
    "qemu-system-arm",
];
/// Debian package of the Debian route's clippy (optional: the firmware lint).
pub const DEBIAN_CLIPPY: &str = "rust-web-clippy";

/// How the firmware is built.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Route {
    /// rustup's toolchain with the target installed.
    Rustup {
        /// The `cargo` running xtask.
        cargo: PathBuf,
    },
    /// Debian's `rustc-web` with `core` built from `rust-web-src`.
    Debian,
}

/// A complete toolchain.
#[derive(Debug, Clone)]
pub struct Toolchain {
    /// The build route.
    pub route: Route,
    /// `qemu-system-arm`.
    pub qemu: PathBuf,
}

/// `name` found in `PATH`.
pub fn which(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

fn output(cmd: &mut Command) -> Option<String> {
    let out = cmd.stderr(Stdio::null()).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

/// `(major, minor)` of a `rustc --version` line.
fn rustc_version(text: &str) -> Option<(u32, u32)> {
    let v = text.split_whitespace().nth(1)?;
    let mut parts = v.split(['.', '-']);
    Some((parts.next()?.parse().ok()?, parts.next()?.parse().ok()?))
}

/// The `cargo` that runs xtask.
pub fn host_cargo() -> PathBuf {
    std::env::var_os("CARGO")
        .map(PathBuf::from)
        .unwrap_or_else(|| "cargo".into())
}

/// Why the rustup route is not usable (`None`: it is).
fn rustup_gap(root: &Path) -> Option<String> {
    if which("rustup").is_none() {
        return Some("rustup is not installed".into());
    }
    let installed = output(
        Command::new("rustup")
            .args(["target", "list", "--installed"])
            .current_dir(root),
    )
    .unwrap_or_default();
    if installed.lines().any(|l| l.trim() == TARGET) {
        None
    } else {
        Some(format!("rustup has no `{TARGET}` target"))
    }
}

/// What the Debian route lacks: `(what, package)`.
fn debian_gaps() -> Vec<(String, &'static str)> {
    let mut gaps = Vec::new();
    let rustc = Path::new("/usr/bin/rustc");
    let version = output(Command::new(rustc).arg("--version"));
    match version.as_deref().and_then(rustc_version) {
        None => gaps.push(("/usr/bin/rustc".to_string(), "rustc-web")),
        Some(v) if v < MIN_RUSTC => gaps.push((
            format!(
                "/usr/bin/rustc {}.{} (the firmware needs {}.{}+)",
                v.0, v.1, MIN_RUSTC.0, MIN_RUSTC.1
            ),
            "rustc-web",
        )),
        Some(_) => {
            let targets =
                output(Command::new(rustc).args(["--print", "target-list"])).unwrap_or_default();
            if !targets.lines().any(|l| l.trim() == TARGET) {
                gaps.push((format!("/usr/bin/rustc without `{TARGET}`"), "rustc-web"));
            }
            let sysroot = output(Command::new(rustc).args(["--print", "sysroot"]))
                .map(|s| PathBuf::from(s.trim()))
                .unwrap_or_else(|| "/usr".into());
            let core = sysroot.join("lib/rustlib/src/rust/library/core/Cargo.toml");
            if !core.is_file() {
                gaps.push((
                    format!("the standard library sources ({})", core.display()),
                    "rust-web-src",
                ));
            }
        }
    }
    if !Path::new("/usr/bin/cargo").is_file() {
        gaps.push(("/usr/bin/cargo".into(), "cargo-web"));
    }
    if which("ld.lld").is_none() {
        gaps.push(("ld.lld".into(), "lld"));
    }
    gaps
}

/// Whether xtask runs as root.
pub fn is_root() -> bool {
    output(Command::new("id").arg("-u")).is_some_and(|s| s.trim() == "0")
}

/// Installs the Debian route's packages with apt-get (xtask runs as root).
pub fn apt_install(packages: &[&str]) -> Result<(), String> {
    eprintln!(
        "xtask: installing the firmware toolchain with apt-get: {}",
        packages.join(" ")
    );
    let status = |cmd: &mut Command| {
        cmd.env("DEBIAN_FRONTEND", "noninteractive")
            .stdout(Stdio::null())
            .status()
            .map_err(|e| format!("cannot run apt-get: {e}"))
    };
    if !status(Command::new("apt-get").args(["-q", "update"]))?.success() {
        return Err("`apt-get update` failed".into());
    }
    let ok = status(
        Command::new("apt-get")
            .args(["-q", "install", "-y", "--no-install-recommends"])
            .args(packages),
    )?;
    if ok.success() {
        Ok(())
    } else {
        Err(format!(
            "`apt-get install -y {}` failed",
            packages.join(" ")
        ))
    }
}

fn missing_message(rustup: &str, debian: &[(String, &str)], qemu: bool) -> String {
    let mut m = String::from(
        "the firmware build needs a Cortex-M4F toolchain and QEMU; on this machine:\n",
    );
    m += &format!("  - rustup route: {rustup}\n");
    if !debian.is_empty() {
        let what: Vec<&str> = debian.iter().map(|g| g.0.as_str()).collect();
        m += &format!("  - Debian route: missing {}\n", what.join(", "));
    }
    if !qemu {
        m += "  - qemu-system-arm is not installed\n";
    }
    m += &format!(
        "install either route, as root on Debian 12 (or Ubuntu):\n    \
         apt-get update && apt-get install -y {}\n\
         or with rustup (plus qemu-system-arm from your distribution):\n    \
         rustup target add {TARGET}\n\
         or run only the host tests: cargo xtask test --host-only",
        DEBIAN_PACKAGES.join(" ")
    );
    m
}

/// Finds the toolchain; installs the Debian packages first if `install` allows it and xtask
/// runs as root with apt-get.
pub fn detect(root: &Path, install: bool) -> Result<Toolchain, String> {
    let mut installed = false;
    loop {
        let qemu = which("qemu-system-arm");
        let rustup = rustup_gap(root);
        let debian = debian_gaps();
        let route = if rustup.is_none() {
            Some(Route::Rustup {
                cargo: host_cargo(),
            })
        } else if debian.is_empty() {
            Some(Route::Debian)
        } else {
            None
        };
        if let (Some(route), Some(qemu)) = (route.clone(), qemu.clone()) {
            return Ok(Toolchain { route, qemu });
        }
        let message = missing_message(
            rustup.as_deref().unwrap_or("complete"),
            if route.is_some() { &[] } else { &debian },
            qemu.is_some(),
        );
        if installed || !install || !is_root() || which("apt-get").is_none() {
            return Err(message);
        }
        eprintln!("xtask: {message}");
        apt_install(DEBIAN_PACKAGES)?;
        installed = true;
    }
}

impl Toolchain {
    /// One line for the log.
    pub fn describe(&self) -> String {
        match &self.route {
            Route::Rustup { cargo } => format!(
                "rustup route ({}, precompiled core for {TARGET}), {}",
                cargo.display(),
                self.qemu.display()
            ),
            Route::Debian => format!(
                "Debian route (/usr/bin/cargo, RUSTC=/usr/bin/rustc, -Zbuild-std=core, ld.lld), {}",
                self.qemu.display()
            ),
        }
    }

    /// A `cargo <subcommand>` for the firmware crate in `dir`, building into `target_dir`,
    /// with the route's settings; the caller adds the rest of the arguments.
    pub fn cargo(&self, subcommand: &str, dir: &Path, target_dir: &Path) -> Command {
        let mut c = match &self.route {
            Route::Rustup { cargo } => {
                let mut c = Command::new(cargo);
                c.arg(subcommand);
                c
            }
            Route::Debian => {
                let mut c = Command::new("/usr/bin/cargo");
                // `cargo clippy` must find Debian's cargo-clippy / clippy-driver, not rustup's.
                let path = std::env::var_os("PATH").unwrap_or_default();
                let mut dirs = vec![PathBuf::from("/usr/bin")];
                dirs.extend(std::env::split_paths(&path));
                c.env("PATH", std::env::join_paths(dirs).unwrap_or(path))
                    .env("RUSTC", "/usr/bin/rustc")
                    .env("RUSTC_BOOTSTRAP", "1")
                    .env_remove("RUSTUP_TOOLCHAIN")
                    .arg(subcommand)
                    .args([
                        "-Zbuild-std=core",
                        "--config",
                        &format!("target.{TARGET}.linker=\"ld.lld\""),
                    ]);
                c
            }
        };
        // Host flags must not replace the target's (`-Tlink.x`, `target-cpu`).
        c.env_remove("RUSTFLAGS")
            .env_remove("CARGO_ENCODED_RUSTFLAGS")
            .env_remove("CARGO_BUILD_TARGET")
            .env("CARGO_TARGET_DIR", target_dir)
            .current_dir(dir);
        c
    }

    /// Whether the route has clippy; the reason if not.
    pub fn clippy_gap(&self) -> Option<String> {
        match &self.route {
            Route::Rustup { .. } => {
                output(Command::new(host_cargo()).args(["clippy", "--version"]))
                    .is_none()
                    .then(|| "rustup's clippy component (`rustup component add clippy`)".into())
            }
            Route::Debian => (!Path::new("/usr/bin/clippy-driver").is_file()
                || !Path::new("/usr/bin/cargo-clippy").is_file())
            .then(|| format!("Debian package {DEBIAN_CLIPPY}")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_rustc_versions() {
        assert_eq!(
            rustc_version("rustc 1.96.0 (ac68faa20 2026-05-25) (built from a source tarball)"),
            Some((1, 96))
        );
        assert_eq!(rustc_version("rustc 1.85.0-nightly"), Some((1, 85)));
        assert_eq!(rustc_version("garbage"), None);
        assert!((1, 63) < MIN_RUSTC && (1, 96) > MIN_RUSTC);
    }

    #[test]
    fn the_message_names_the_packages_and_the_fallback() {
        let m = missing_message(
            "rustup has no `thumbv7em-none-eabihf` target",
            &[("ld.lld".into(), "lld")],
            false,
        );
        assert!(m.contains("missing ld.lld"));
        assert!(m.contains("qemu-system-arm is not installed"));
        assert!(
            m.contains("apt-get install -y rustc-web cargo-web rust-web-src lld qemu-system-arm")
        );
        assert!(m.contains("rustup target add thumbv7em-none-eabihf"));
        assert!(m.contains("--host-only"));
    }
}
