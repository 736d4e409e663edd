//! The firmware's checked-in example blobs (`nemm-firmware/data/example-<kind>.nemm`, used by
//! the firmware build and by `cargo xtask bench-target`) are `nemm-core`'s example models of
//! each kind (scalers H = 16, L = 5), as `encode` writes them today.
//!
//! `NEMM_BLESS=1 cargo test --release -p nemm-tests --test firmware_data` rewrites them after
//! a deliberate change of the examples or the format.

use nemm_core::testing::example_model;
use nemm_core::{decode, encode_to_vec, Model, ModelKind};
use nemm_firmware::PARAM_CAPACITY;
use std::path::PathBuf;

#[test]
fn example_blobs_are_the_core_examples() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../nemm-firmware/data");
    let bless = std::env::var_os("NEMM_BLESS").is_some();
    for kind in [
        ModelKind::Sem,
        ModelKind::LinearEmm,
        ModelKind::NemmLight,
        ModelKind::Nemm,
    ] {
        let model: Model<PARAM_CAPACITY> = example_model(kind, 16, 5).expect("example model");
        let blob = encode_to_vec(&model).expect("encode");
        let path = dir.join(format!("example-{}.nemm", kind.name()));
        if bless {
            std::fs::write(&path, &blob).expect("write the blob");
        }
        let stored = std::fs::read(&path)
            .unwrap_or_else(|e| panic!("{}: {e} (NEMM_BLESS=1 writes it)", path.display()));
        assert!(
            stored == blob,
            "{} is not the current {} example (NEMM_BLESS=1 rewrites it)",
            path.display(),
            kind.name()
        );
        // And the firmware's capacity holds it.
        let back: Model<PARAM_CAPACITY> = decode(&stored).expect("decodes at the firmware's P");
        assert_eq!(back, model);
    }
}

/// The trained blob the firmware embeds by default decodes at the firmware's capacity and
/// records where it came from (`cargo xtask firmware-model` writes it).
#[test]
fn the_trained_blob_decodes_and_records_its_provenance() {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../nemm-firmware/data/trained-nemm.nemm");
    let blob = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let model: Model<PARAM_CAPACITY> = decode(&blob).expect("decodes at the firmware's P");
    assert_eq!(model.kind(), ModelKind::Nemm);
    let p = &model.provenance;
    assert!(
        p.command.starts_with("nemm train ") && !p.dataset.is_empty() && !p.commit.is_empty(),
        "{p:?}"
    );
}
