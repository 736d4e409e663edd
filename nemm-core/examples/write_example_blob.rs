//! Writes the built-in example NEMM (pseudo-random weights, not trained) as a weights blob.
//!
//! ```text
//! cargo run -p nemm-core --example write_example_blob -- example.nemm
//! ```
fn main() {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "example.nemm".into());
    let blob = nemm_core::testing::example_blob();
    if let Err(e) = std::fs::write(&path, &blob) {
        eprintln!("error: cannot write {path}: {e}");
        std::process::exit(1);
    }
    println!("wrote {path} ({} bytes)", blob.len());
}
