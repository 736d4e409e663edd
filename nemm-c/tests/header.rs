//! The committed header `include/nemm.h` is what cbindgen generates from the crate now, and
//! the integration guide (`docs/c-interface.md`) states its status codes and storage sizes.
//!
//! `NEMM_BLESS=1 cargo test -p nemm-c --test header` (or `cargo xtask c-header`) rewrites
//! the header; the guide is edited by hand.

use std::path::Path;

fn generated() -> String {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let bindings = cbindgen::Builder::new()
        .with_config(config)
        .with_src(dir.join("src/lib.rs"))
        .generate()
        .expect("cbindgen generates the header");
    let mut out = Vec::new();
    bindings.write(&mut out);
    String::from_utf8(out).expect("UTF-8 header")
}

#[test]
fn the_committed_header_is_generated_from_the_code() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("include/nemm.h");
    let now = generated();
    if std::env::var_os("NEMM_BLESS").is_some() {
        std::fs::write(&path, &now).expect("write include/nemm.h");
        eprintln!("header: wrote {}", path.display());
        return;
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    if committed != now {
        let first = committed
            .lines()
            .zip(now.lines())
            .position(|(a, b)| a != b)
            .unwrap_or_else(|| committed.lines().count().min(now.lines().count()));
        panic!(
            "{} differs from what cbindgen generates from nemm-c's source (first at line {}: \
             committed {:?}, generated {:?}); regenerate it with `cargo xtask c-header` and \
             commit it",
            path.display(),
            first + 1,
            committed.lines().nth(first).unwrap_or("<end>"),
            now.lines().nth(first).unwrap_or("<end>"),
        );
    }
}

/// The integration guide's tables state the header's status codes and storage sizes.
#[test]
fn the_guide_states_the_headers_codes_and_sizes() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let header = std::fs::read_to_string(dir.join("include/nemm.h")).expect("nemm.h");
    let guide_path = dir.join("../docs/c-interface.md");
    let guide = std::fs::read_to_string(&guide_path).expect("docs/c-interface.md");
    let mut codes = 0;
    for line in header.lines() {
        let Some((name, value)) = line.trim().trim_end_matches(',').split_once(" = ") else {
            continue;
        };
        if name.starts_with("NEMM_OK") || name.starts_with("NEMM_E_") {
            let row = format!("| `{name}` | {value} |");
            assert!(
                guide.contains(&row),
                "{}: no row {row}",
                guide_path.display()
            );
            codes += 1;
        }
    }
    assert!(codes >= 47, "{codes} status codes in the header");
    // `#define <name> <value>` inside `#if defined(NEMM_TARGET_<width>)`.
    let mut width = "";
    let mut sizes = std::collections::BTreeMap::new();
    for line in header.lines() {
        if let Some(w) = line.strip_prefix("#if defined(NEMM_TARGET_") {
            width = w.trim_end_matches(')');
        } else if let Some(rest) = line.strip_prefix("#define NEMM_") {
            if let Some((name, value)) = rest.split_once(' ') {
                sizes.insert((name.to_string(), width.to_string()), value.to_string());
            }
        } else if line.starts_with("#endif") {
            width = "";
        }
    }
    for object in ["ESTIMATOR", "OBSERVER", "LEVELS"] {
        let get = |what: &str, width: &str| {
            sizes
                .get(&(format!("{object}_{what}"), width.to_string()))
                .unwrap_or_else(|| panic!("no NEMM_{object}_{what} for {width}-bit targets"))
        };
        let row = format!(
            "| {} B, align {} | {} B, align {} |",
            get("SIZE", "32"),
            get("ALIGN", "32"),
            get("SIZE", "64"),
            get("ALIGN", "64")
        );
        assert!(
            guide.contains(&row),
            "{}: the `nemm_{}_t` row does not end in {row}",
            guide_path.display(),
            object.to_lowercase()
        );
    }
}
