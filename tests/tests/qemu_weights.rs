//! Bad weights in QEMU: a corrupt blob (truncated, bit-flipped, wrong version, ...) in the
//! weights slot makes the firmware report the typed error and exit cleanly (semihosting exit
//! code 2), without starting the estimator: never a panic or a hard fault.
//!
//! Each case patches the weights section of the one built image (`.nemm_weights`, which the
//! firmware reads through its address, as it would a slot flashed on its own) instead of
//! rebuilding the firmware. The expected line is the host's: `nemm_core::decode` on the same
//! bytes, formatted by the firmware's own `report` module.
//!
//! Run by `cargo xtask test` (see `nemm_tests::firmware` for the environment it sets).

use nemm_core::testing::example_model;
use nemm_core::{decode, encode_to_vec, Model, ModelKind, CRC, CRC_LEN};
use nemm_firmware::report::{self, Line, EXIT_BAD_WEIGHTS};
use nemm_firmware::slot::{self, CAPACITY};
use nemm_firmware::PARAM_CAPACITY;
use nemm_tests::elf::Elf;
use nemm_tests::firmware::{image_with_slot, run_qemu, slot_with, slot_with_len, Contents, Images};
use std::time::Duration;

/// What the firmware must print for `slot`, computed on the host.
fn expected_line(slot_bytes: &[u8]) -> String {
    let mut l = Line::new();
    match slot::blob(slot_bytes) {
        Err(e) => report::slot_error(&mut l, &e),
        Ok(blob) => match decode::<PARAM_CAPACITY>(blob) {
            Err(e) => report::decode_error(&mut l, &e),
            Ok(m) if (m.dt_s - 1e-4).abs() > 1e-7 => {
                l.str("weights-error")
                    .ks("source", "firmware")
                    .ks("kind", "rate-mismatch")
                    .kx("dt_s", m.dt_s.to_bits());
            }
            Ok(_) => panic!("this slot is valid"),
        },
    }
    String::from_utf8(l.as_bytes().to_vec()).expect("ASCII")
}

/// Runs the firmware with `slot` and checks the report and the exit; `kind` is the error
/// kind the case is about (`kind=...` in the line).
fn refused(name: &str, slot_bytes: Vec<u8>, kind: &str) {
    let images = Images::from_env();
    let elf = Elf::read(&images.app).expect("firmware image");
    let want = expected_line(&slot_bytes);
    assert!(
        want.contains(&format!(" kind={kind}")),
        "{name}: the case does not produce `{kind}` on the host: {want}"
    );
    let image = image_with_slot(&elf, &slot_bytes, &format!("weights-{name}"));
    let run = run_qemu(&images.qemu, &image, &[], Duration::from_secs(60));
    let out = run.output();
    assert_eq!(
        run.code,
        Some(EXIT_BAD_WEIGHTS as i32),
        "{name}: exit code: {}",
        run.describe()
    );
    assert!(out.get("boot").is_some(), "{name}: no boot line");
    assert_eq!(
        out.weights_error_line(),
        Some(want.as_str()),
        "{name}: the typed error: {}",
        run.describe()
    );
    assert!(
        out.get("start").is_none() && out.steps.is_empty(),
        "{name}: estimator started"
    );
    assert!(
        !run.stdout.contains("panic") && !run.stdout.contains("hard-fault"),
        "{name}: {}",
        run.describe()
    );
    let _ = std::fs::remove_file(image);
}

/// The blob built into the firmware.
fn built_in_blob() -> Vec<u8> {
    let images = Images::from_env();
    let elf = Elf::read(&images.app).expect("firmware image");
    Contents::of(&elf).blob().to_vec()
}

/// Rewrites the CRC trailer after editing a blob (so the edit reaches the later checks).
fn fix_crc(blob: &mut [u8]) {
    let n = blob.len() - CRC_LEN;
    let crc = CRC.checksum(&blob[..n]);
    blob[n..].copy_from_slice(&crc.to_le_bytes());
}

fn encoded(model: &Model<8192>) -> Vec<u8> {
    encode_to_vec(model).expect("encode")
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn truncated_blob() {
    let b = built_in_blob();
    refused("truncated", slot_with(&b[..b.len() - 1000]), "truncated");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn blob_truncated_inside_its_header() {
    let b = built_in_blob();
    refused("truncated-header", slot_with(&b[..3]), "truncated");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn bit_flip_in_the_body() {
    let mut b = built_in_blob();
    let at = b.len() / 2;
    b[at] ^= 0x10;
    refused("bit-flip", slot_with(&b), "crc-mismatch");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn bit_flip_in_the_crc() {
    let mut b = built_in_blob();
    let last = b.len() - 1;
    b[last] ^= 0x80;
    refused("bit-flip-crc", slot_with(&b), "crc-mismatch");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn wrong_format_version() {
    let mut b = built_in_blob();
    // Magic (4 bytes), then the version as a postcard varint (one byte below 128): the
    // blob's version (at most the current one) -> the one after the current one.
    assert!(u16::from(b[4]) <= nemm_core::FORMAT_VERSION);
    b[4] = u8::try_from(nemm_core::FORMAT_VERSION + 1).expect("a one-byte varint");
    refused("wrong-version", slot_with(&b), "unsupported-version");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn not_a_nemm_blob() {
    let mut b = built_in_blob();
    b[0] = b'X';
    refused("bad-magic", slot_with(&b), "bad-magic");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn trailing_bytes_after_the_crc() {
    let mut b = built_in_blob();
    b.push(0);
    refused("trailing", slot_with(&b), "trailing-bytes");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn erased_slot() {
    refused("erased", vec![0xFF; CAPACITY], "empty");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn slot_length_beyond_the_slot() {
    let b = built_in_blob();
    refused(
        "slot-too-long",
        slot_with_len(&b, CAPACITY as u32, CAPACITY),
        "too-long",
    );
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn nan_weight_with_a_valid_crc() {
    let mut b = built_in_blob();
    // The example model's dt_s (1e-4, f32) is stored as raw little-endian bytes in the body.
    let dt = 1e-4f32.to_le_bytes();
    let at = b
        .windows(4)
        .position(|w| w == dt)
        .expect("dt_s in the blob");
    b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    fix_crc(&mut b);
    refused("nan-dt", slot_with(&b), "invalid");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn model_larger_than_the_firmware_holds() {
    let big = example_model::<8192>(ModelKind::Nemm, 32, 5).expect("H = 32 example");
    refused("over-capacity", slot_with(&encoded(&big)), "over-capacity");
}

#[test]
#[ignore = "needs the firmware images and QEMU: run by `cargo xtask test`"]
fn model_trained_at_another_rate() {
    let mut m = example_model::<8192>(ModelKind::Nemm, 16, 5).expect("example");
    m.dt_s = 0.5e-4; // 20 kHz
    refused("rate-mismatch", slot_with(&encoded(&m)), "rate-mismatch");
}
