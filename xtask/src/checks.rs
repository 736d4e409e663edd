//! The checks a published `no_std` crate needs beyond its tests: every valid feature
//! combination of `nemm-kernels` and `nemm-core` on the host and on the target, and honest
//! `rust-version`s.

use crate::toolchain::{Toolchain, TARGET};
use crate::{cargo, run, Paths};
use cargo_metadata::{semver, DependencyKind, Metadata, PackageId};
use std::collections::{HashMap, HashSet};

/// The published `no_std` crates whose feature sets are checked: the kernels, then the
/// runtime on them.
const NO_STD_CRATES: [&str; 2] = ["nemm-kernels", "nemm-core"];

/// The math backends of `nemm-kernels` (and of `nemm-core`, which passes them on): a build
/// needs at least one (`micromath` wins when both are on).
const BACKENDS: [&str; 3] = ["libm", "micromath", "libm,micromath"];

/// Every valid feature combination of `nemm-kernels` and `nemm-core`: each backend set, with
/// and without `std` (the host), and without `std` for the target.
pub fn host_feature_sets() -> Vec<String> {
    BACKENDS
        .iter()
        .flat_map(|b| [b.to_string(), format!("{b},std")])
        .collect()
}

/// `cargo xtask features`: the tests of `nemm-kernels` and `nemm-core` for every host
/// feature set without `std` (release; the sets with `std` type-checked), then a build of
/// each library for the target with every `no_std` set, and of `nemm-kernels` with `reverse`
/// (when a target toolchain is given). The kernels' tests always have `reverse` (the crate's
/// own dev-dependency turns it on); the target builds check the library without it.
///
/// The integration and doc tests hold the exact backend's tolerances (their reference is
/// computed with `libm`); with `micromath` on, the libraries' unit tests run and nemm-core's
/// examples build (the micromath error is measured by `cargo run -p nemm-core --example
/// math_backends`).
pub fn features(tc: Option<&Toolchain>, paths: &Paths) -> Result<(), String> {
    for krate in NO_STD_CRATES {
        for set in host_feature_sets() {
            let mut c = cargo();
            // `std` adds conveniences (encoding to a `Vec`, `Error` impls), not arithmetic:
            // with it the library and its tests are type-checked; the tests run without it
            // (and with the default `libm,std` in the workspace run).
            let std = set.split(',').any(|f| f == "std");
            c.args([
                if std { "check" } else { "test" },
                "--release",
                "-p",
                krate,
                "--no-default-features",
            ])
            .args(["--features", &set]);
            // The integration tests hold the exact backend's tolerances: with `micromath`,
            // the library's unit tests (and nemm-core's examples).
            if set.contains("micromath") {
                c.arg("--lib");
                if krate == "nemm-core" {
                    c.arg("--examples");
                }
            } else if std {
                c.args(["--lib", "--tests"]);
            }
            eprintln!(
                "xtask: {krate} features {set} ({})",
                if std { "host check" } else { "host tests" }
            );
            run(c.current_dir(&paths.root))?;
        }
    }
    match tc {
        Some(tc) => {
            let target_dir = paths.target.join("nemm-core-features");
            for krate in NO_STD_CRATES {
                // `reverse` (the trainer's reverse mode of the kernels) stays `no_std` too.
                let reverse = (krate == "nemm-kernels").then_some("libm,reverse");
                for set in BACKENDS.into_iter().chain(reverse) {
                    eprintln!("xtask: {krate} features {set} (build for {TARGET})");
                    run(tc
                        .cargo("build", &paths.root, &target_dir)
                        .args(["--release", "-p", krate, "--lib", "--target", TARGET])
                        .args(["--no-default-features", "--features", set]))?;
                }
            }
        }
        None => eprintln!("xtask: no target toolchain: the target builds of the features skipped"),
    }
    Ok(())
}

/// `nemm-core`'s user-facing example, run in the debug and the release profile on its bundled
/// CSV of velocities with the built-in example NEMM: one finite force per input line.
pub fn example(paths: &Paths) -> Result<(), String> {
    let csv = "nemm-core/examples/data/velocities.csv";
    let inputs = std::fs::read_to_string(paths.root.join(csv))
        .map_err(|e| format!("{csv}: {e}"))?
        .lines()
        .count()
        .saturating_sub(1);
    for profile in [None, Some("--release")] {
        let mut c = cargo();
        c.args([
            "run",
            "-q",
            "-p",
            "nemm-core",
            "--example",
            "forces_from_csv",
        ]);
        c.args(profile);
        let out = c
            .args(["--", "-", csv])
            .current_dir(&paths.root)
            .output()
            .map_err(|e| format!("cargo run --example forces_from_csv: {e}"))?;
        let name = profile.unwrap_or("debug");
        let stdout = String::from_utf8_lossy(&out.stdout);
        if !out.status.success() {
            return Err(format!(
                "forces_from_csv ({name}) failed: {}\n{stdout}",
                String::from_utf8_lossy(&out.stderr)
            ));
        }
        let forces: Vec<f32> = stdout
            .lines()
            .skip(1)
            .filter_map(|l| l.split(',').nth(2)?.parse().ok())
            .collect();
        if forces.len() != inputs || !forces.iter().all(|f| f.is_finite()) {
            return Err(format!(
                "forces_from_csv ({name}): {} finite forces for {inputs} velocities:\n{stdout}",
                forces.len()
            ));
        }
        let peak = forces.iter().fold(0.0f32, |m, f| m.max(f.abs()));
        eprintln!("xtask: forces_from_csv ({name}): {inputs} forces, peak {peak:.1} N");
    }
    Ok(())
}

/// One package's declared `rust-version` against what its dependencies declare.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RustVersion {
    /// The workspace package.
    pub package: String,
    /// Its declared `rust-version` (`None`: not declared).
    pub declared: Option<semver::Version>,
    /// The highest `rust-version` among the normal and build dependencies it compiles (the
    /// resolved graph of the lock file), and the crate that declares it.
    pub needed: Option<(semver::Version, String)>,
}

impl RustVersion {
    /// True if the declaration is at least what the dependencies need.
    pub fn honest(&self) -> bool {
        match (&self.declared, &self.needed) {
            (Some(d), Some((n, _))) => d >= n,
            (Some(_), None) => true,
            (None, _) => false,
        }
    }

    /// `rust-version package=<p> declared=<v> needed=<v> by=<crate>`.
    pub fn line(&self) -> String {
        let show = |v: &Option<semver::Version>| v.as_ref().map_or("-".into(), |v| v.to_string());
        let (needed, by) = match &self.needed {
            Some((v, by)) => (v.to_string(), by.as_str()),
            None => ("-".into(), "-"),
        };
        format!(
            "rust-version package={} declared={} needed={needed} by={by}",
            self.package,
            show(&self.declared)
        )
    }
}

/// The declared and the needed `rust-version` of every workspace package.
pub fn rust_versions(metadata: &Metadata) -> Vec<RustVersion> {
    let packages: HashMap<&PackageId, &cargo_metadata::Package> =
        metadata.packages.iter().map(|p| (&p.id, p)).collect();
    let Some(resolve) = &metadata.resolve else {
        return Vec::new();
    };
    let nodes: HashMap<&PackageId, &cargo_metadata::Node> =
        resolve.nodes.iter().map(|n| (&n.id, n)).collect();
    metadata
        .workspace_members
        .iter()
        .filter_map(|id| {
            let pkg = packages.get(id)?;
            // Everything compiled for the package: normal and build dependencies,
            // transitively (dev-dependencies are not compiled for its users).
            let mut seen: HashSet<&PackageId> = HashSet::new();
            let mut stack = vec![id];
            let mut needed: Option<(semver::Version, String)> = None;
            while let Some(at) = stack.pop() {
                let Some(node) = nodes.get(at) else { continue };
                for dep in &node.deps {
                    let compiled = dep
                        .dep_kinds
                        .iter()
                        .any(|k| matches!(k.kind, DependencyKind::Normal | DependencyKind::Build));
                    if !compiled || !seen.insert(&dep.pkg) {
                        continue;
                    }
                    if let Some(p) = packages.get(&dep.pkg) {
                        if let Some(v) = &p.rust_version {
                            if needed.as_ref().is_none_or(|(n, _)| v > n) {
                                needed = Some((v.clone(), format!("{}@{}", p.name, p.version)));
                            }
                        }
                    }
                    stack.push(&dep.pkg);
                }
            }
            Some(RustVersion {
                package: pkg.name.to_string(),
                declared: pkg.rust_version.clone(),
                needed,
            })
        })
        .collect()
}

/// `cargo xtask msrv`: every workspace package declares a `rust-version` at least as high as
/// every crate it compiles declares (read from the lock file's resolved graph). No compiler of
/// the declared version is run: rustup cannot install one here, and Debian packages only
/// older and newer ones (docs/core.md, "Minimum Rust version").
pub fn msrv(paths: &Paths) -> Result<(), String> {
    let mut dishonest = Vec::new();
    // The host workspace and the firmware's own.
    for dir in [paths.root.clone(), paths.root.join("nemm-firmware")] {
        let metadata = cargo_metadata::MetadataCommand::new()
            .cargo_path(crate::toolchain::host_cargo())
            .current_dir(&dir)
            .exec()
            .map_err(|e| format!("cargo metadata in {}: {e}", dir.display()))?;
        for v in rust_versions(&metadata) {
            println!("{}", v.line());
            if !v.honest() {
                dishonest.push(v.line());
            }
        }
    }
    if dishonest.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "rust-version below what the dependencies need (or missing):\n{}",
            dishonest.join("\n")
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feature_sets_cover_every_valid_combination() {
        let sets = host_feature_sets();
        assert_eq!(sets.len(), 6);
        assert!(sets
            .iter()
            .all(|s| s.contains("libm") || s.contains("micromath")));
        assert_eq!(sets.iter().filter(|s| s.contains("std")).count(), 3);
    }

    #[test]
    fn a_declaration_below_the_dependencies_is_not_honest() {
        let v = |s: &str| semver::Version::parse(s).unwrap();
        let r = |declared: Option<&str>, needed: Option<&str>| RustVersion {
            package: "p".into(),
            declared: declared.map(v),
            needed: needed.map(|n| (v(n), "dep@1.0.0".into())),
        };
        assert!(r(Some("1.87.0"), Some("1.87.0")).honest());
        assert!(r(Some("1.88.0"), Some("1.87.0")).honest());
        assert!(!r(Some("1.85.0"), Some("1.87.0")).honest());
        assert!(!r(None, Some("1.60.0")).honest());
        assert!(r(Some("1.85.0"), None).honest());
        assert_eq!(
            r(Some("1.85.0"), Some("1.87.0")).line(),
            "rust-version package=p declared=1.85.0 needed=1.87.0 by=dep@1.0.0"
        );
    }
}
