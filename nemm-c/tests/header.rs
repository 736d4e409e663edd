//! The committed header `include/nemm.h` is what cbindgen generates from the crate now.
//!
//! `NEMM_BLESS=1 cargo test -p nemm-c --test header` (or `cargo xtask c-header`) rewrites
//! it.

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
