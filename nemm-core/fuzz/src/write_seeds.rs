//! Writes the seed corpora: valid blobs of every kind, both integrators and several scaler
//! sizes into `corpus/decode/`, and the same models as `decode_body` inputs into
//! `corpus/decode_body/`.
//!
//! ```text
//! cargo run --manifest-path nemm-core/fuzz/Cargo.toml --bin write_seeds [-- <fuzz dir>]
//! ```

use nemm_core::testing::example_model;
use nemm_core::{encode_to_vec, Integrator, Model, ModelKind, DEFAULT_PARAM_CAPACITY};
use nemm_core_fuzz::{unwrap_body, wrap_body};
use std::path::PathBuf;

fn main() {
    let dir = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")));
    let raw = dir.join("corpus/decode");
    let body = dir.join("corpus/decode_body");
    for d in [&raw, &body] {
        std::fs::create_dir_all(d).expect("create corpus directory");
    }
    let mut n = 0;
    for kind in [
        ModelKind::Sem,
        ModelKind::LinearEmm,
        ModelKind::NemmLight,
        ModelKind::Nemm,
    ] {
        for (h, l) in [(1u8, 1u8), (2, 1), (3, 2), (8, 3), (16, 5)] {
            if matches!(kind, ModelKind::Sem | ModelKind::LinearEmm) && h > 1 {
                continue; // no scalers: the size does not change the blob
            }
            for integrator in [Integrator::Rk4, Integrator::Rk3] {
                let mut m: Model<DEFAULT_PARAM_CAPACITY> =
                    example_model(kind, h, l).expect("example model");
                m.integrator = integrator;
                let blob = encode_to_vec(&m).expect("valid example");
                let name = format!("{}-h{h}-l{l}-{}", kind.name(), integrator.name());
                std::fs::write(raw.join(format!("{name}.nemm")), &blob).expect("write seed");
                let b = unwrap_body(&blob).expect("valid blob");
                assert_eq!(wrap_body(&b).as_deref(), Some(&blob[..]));
                std::fs::write(body.join(name), &b).expect("write seed");
                n += 1;
            }
        }
    }
    println!(
        "wrote {n} seeds into {} and {}",
        raw.display(),
        body.display()
    );
}
