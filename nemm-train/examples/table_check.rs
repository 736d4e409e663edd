//! The export-time table check (`nemm_train::train::table_check`) on an existing blob:
//!
//! ```text
//! cargo run --release -p nemm-train --example table_check -- model.nemm [bound]
//! ```

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .expect("usage: table_check <model.nemm> [bound]");
    let bound: f32 = args
        .next()
        .map_or(nemm_train::train::table_check::DEFAULT_TABLE_BOUND, |b| {
            b.parse().expect("bound: a number")
        });
    let blob = std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let model: nemm_core::Model =
        nemm_core::decode(&blob).unwrap_or_else(|e| panic!("{path}: {e}"));
    print!("{}", nemm_train::train::table_check::report(&model, bound));
}
