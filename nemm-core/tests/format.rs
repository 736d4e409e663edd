//! The weight format: round trips over random valid models of every kind and size; every
//! truncation and every single-bit flip of a valid blob is refused with a typed error;
//! garbage never panics (also past the CRC, with the trailer recomputed); capacity, version,
//! magic and header/body agreement; well-formed blobs with invalid contents are refused.

mod common;

use common::{blob_of, craft_blob, fix_crc, ModelSpec, KINDS, P};
use nemm_core::{
    decode, encode, read_header, Body, DecodeError, EncodeError, Estimator, EstimatorConfig, Model,
    ModelError, ModelKind, Sample, CRC_LEN, FORMAT_VERSION, MAX_HEADER_LEN,
};
use nemm_kernels::mlp::ShapeError;
use proptest::prelude::*;

/// Small models of every kind (scalers 2 wide, 1 deep): blobs of 40 to 500 bytes whose every
/// bit can be flipped.
fn small_models() -> Vec<Model<64>> {
    KINDS
        .iter()
        .map(|&k| nemm_core::testing::example_model(k, 2, 1).unwrap())
        .collect()
}

/// What a decoder may do with a damaged or hostile blob: return a typed error, or a model that
/// passed validation and runs.
fn decode_must_not_panic<const Q: usize>(bytes: &[u8]) -> Result<(), TestCaseError> {
    if let Ok(m) = decode::<Q>(bytes) {
        prop_assert_eq!(m.validate(), Ok(()));
        if let Ok(mut est) = Estimator::new(&m, EstimatorConfig::new(0.1)) {
            for k in 0..50 {
                let e = est.step(Sample::new(0.3 * (k as f32 * 0.2).sin())).unwrap();
                prop_assert!(e.force_n.is_finite());
            }
        }
    }
    Ok(())
}

#[test]
fn layout_is_header_body_crc() {
    for m in small_models() {
        let blob = blob_of(&m);
        // An independent writer of the documented layout produces the same bytes.
        assert_eq!(blob, craft_blob(&m, |_| {}), "{:?}", m.kind());
        assert_eq!(&blob[..4], b"NEMM");
        let h = read_header(&blob).unwrap();
        assert_eq!(h.version, FORMAT_VERSION);
        assert_eq!(h.kind, m.kind());
        assert_eq!(h.max_scaler_params as usize, m.max_scaler_params());
        let header_len = blob.len() - h.body_len as usize - CRC_LEN;
        assert!(header_len <= MAX_HEADER_LEN);
        let crc = u32::from_le_bytes(blob[blob.len() - 4..].try_into().unwrap());
        assert_eq!(crc, nemm_core::CRC.checksum(&blob[..blob.len() - 4]));
    }
}

/// `encode` into every buffer length: too short is `BufferTooSmall`, never a panic; a buffer
/// of exactly `encoded_len` bytes (the blob's length) or longer gives the same blob.
#[test]
fn encode_into_every_buffer_length() {
    for m in small_models() {
        let blob = blob_of(&m);
        let need = nemm_core::encoded_len(&m).unwrap();
        assert_eq!(need, blob.len());
        let mut buf = vec![0u8; need + 8];
        for n in 0..buf.len() {
            match encode(&m, &mut buf[..n]) {
                Ok(b) => {
                    assert!(n >= need, "{n}");
                    assert_eq!(b, &blob[..]);
                }
                Err(e) => {
                    assert_eq!(e, EncodeError::BufferTooSmall);
                    assert!(n < need, "{n}");
                }
            }
        }
    }
}

/// `decode_into` decodes in place: a model of the largest capacity (three 36.6 KiB scalers)
/// decodes on a thread whose whole stack is the size of one model (decode by value
/// needs several copies), and re-decoding into a model of another kind switches the kind.
/// An unoptimised build holds one copy of the empty body of the new kind on the stack while
/// it switches (the old body is dropped after the new one is made), so it gets twice that.
#[test]
fn decode_into_works_in_place_with_a_small_stack() {
    // Boxed: the closure below captures them and must not put them on the small stack.
    let big: Box<Model> =
        Box::new(nemm_core::testing::example_model(nemm_core::ModelKind::Nemm, 32, 9).unwrap());
    let blob = blob_of(&big);
    let small: Box<Model> =
        Box::new(nemm_core::testing::example_model(nemm_core::ModelKind::Sem, 16, 5).unwrap());
    let sem_blob = blob_of(&small);
    let model_bytes = std::mem::size_of::<Model>();
    assert!(model_bytes > 100_000, "{model_bytes}");
    let stack = if cfg!(debug_assertions) {
        2 * model_bytes
    } else {
        model_bytes
    };
    // The place is made here, on the big main-test stack, and only its box moves.
    let mut place: Box<Model> = Box::new(Model::empty());
    let handle = std::thread::Builder::new()
        .stack_size(stack)
        .spawn(move || {
            let place = &mut *place;
            nemm_core::decode_into(&blob, place).unwrap();
            let same = *place == *big;
            nemm_core::decode_into(&sem_blob, place).unwrap();
            (same, *place == *small)
        })
        .unwrap();
    assert_eq!(handle.join().unwrap(), (true, true));
}

#[test]
fn every_truncation_is_truncated() {
    for m in small_models() {
        let blob = blob_of(&m);
        for n in 0..blob.len() {
            match decode::<64>(&blob[..n]) {
                Err(DecodeError::Truncated { needed, found }) => {
                    assert_eq!(found, n);
                    assert!(needed > n);
                }
                other => panic!("{:?}: prefix of {n} bytes gave {other:?}", m.kind()),
            }
        }
        assert_eq!(decode::<64>(&blob).as_ref(), Ok(&m));
    }
}

#[test]
fn trailing_bytes_are_refused() {
    for m in small_models() {
        let mut blob = blob_of(&m);
        for extra in 1..=5 {
            blob.push(0);
            assert_eq!(
                decode::<64>(&blob),
                Err(DecodeError::TrailingBytes { extra })
            );
        }
    }
}

/// Exhaustive: every single-bit flip of every small blob is refused (CRC-32 detects every
/// single-bit error; flips in the header are caught earlier).
#[test]
fn every_bit_flip_of_small_blobs_is_refused() {
    let mut checked = 0;
    for m in small_models() {
        let blob = blob_of(&m);
        for bit in 0..blob.len() * 8 {
            let mut b = blob.clone();
            b[bit / 8] ^= 1 << (bit % 8);
            let r = decode::<64>(&b);
            assert!(
                r.is_err(),
                "{:?}: flipping bit {bit} was accepted",
                m.kind()
            );
            checked += 1;
        }
    }
    assert!(checked > 4 * 8 * 40);
}

#[test]
fn bad_magic_and_version() {
    let m = &small_models()[1];
    let mut blob = blob_of(m);
    blob[0] = b'X';
    assert_eq!(
        decode::<64>(&blob),
        Err(DecodeError::BadMagic { found: *b"XEMM" })
    );
    let blob = craft_blob(m, |h| h.version = FORMAT_VERSION + 1);
    assert_eq!(
        decode::<64>(&blob),
        Err(DecodeError::UnsupportedVersion {
            found: FORMAT_VERSION + 1,
            supported: FORMAT_VERSION
        })
    );
    let blob = craft_blob(m, |h| h.version = nemm_core::OLDEST_FORMAT_VERSION - 1);
    assert_eq!(
        decode::<64>(&blob),
        Err(DecodeError::UnsupportedVersion {
            found: nemm_core::OLDEST_FORMAT_VERSION - 1,
            supported: FORMAT_VERSION
        })
    );
}

/// A header that disagrees with its body (with a valid CRC) is malformed.
#[test]
fn header_must_agree_with_body() {
    let nemm: Model<64> = nemm_core::testing::example_model(ModelKind::Nemm, 2, 1).unwrap();
    let blob = craft_blob(&nemm, |h| h.kind = ModelKind::NemmLight);
    assert_eq!(
        decode::<64>(&blob),
        Err(DecodeError::Malformed { part: "body" })
    );
    let blob = craft_blob(&nemm, |h| h.max_scaler_params -= 1);
    assert_eq!(
        decode::<64>(&blob),
        Err(DecodeError::Malformed { part: "body" })
    );
    // A header understating the scaler size cannot smuggle a body over capacity past the
    // capacity check: the body's vectors are bounded by their capacity when parsed.
    let big: Model<{ P }> = nemm_core::testing::example_model(ModelKind::Nemm, 8, 2).unwrap();
    let blob = craft_blob(&big, |h| h.max_scaler_params = 10);
    assert_eq!(
        decode::<64>(&blob),
        Err(DecodeError::Malformed { part: "body" })
    );
}

/// Decoding into a capacity smaller than the largest scaler is `OverCapacity`, with the
/// numbers a firmware engineer needs; exactly enough capacity decodes.
#[test]
fn over_capacity() {
    let m: Model<{ P }> = nemm_core::testing::example_model(ModelKind::Nemm, 16, 5).unwrap();
    let blob = blob_of(&m);
    let needed = m.max_scaler_params();
    assert_eq!(needed, 1313);
    assert_eq!(
        decode::<1312>(&blob),
        Err(DecodeError::OverCapacity {
            needed,
            capacity: 1312
        })
    );
    assert_eq!(
        decode::<64>(&blob),
        Err(DecodeError::OverCapacity {
            needed,
            capacity: 64
        })
    );
    let exact: Model<1313> = decode(&blob).unwrap();
    assert_eq!(blob_of(&exact), blob);
    // The b_pr scaler (1 input) is the smallest; a capacity between it and the others fails.
    let light: Model<{ P }> =
        nemm_core::testing::example_model(ModelKind::NemmLight, 16, 5).unwrap();
    assert!(matches!(
        decode::<1000>(&blob_of(&light)),
        Err(DecodeError::OverCapacity { needed: 1313, .. })
    ));
}

/// Well-formed blobs (valid CRC, parseable body) with contents `encode` refuses to write are
/// refused by `decode` with the model error.
#[test]
fn invalid_contents_are_refused() {
    let base: Model<64> = nemm_core::testing::example_model(ModelKind::Nemm, 2, 1).unwrap();
    type Edit = fn(&mut Model<64>);
    let cases: [(Edit, ModelError); 10] = [
        (
            |m| {
                if let Body::Nemm { b_fl, .. } = &mut m.body {
                    b_fl.mlp.params[3] = f32::NAN;
                }
            },
            ModelError::NonFinite { field: "b_fl" },
        ),
        (
            |m| {
                if let Body::Nemm { b_pr, .. } = &mut m.body {
                    b_pr.mlp.params[0] = f32::INFINITY;
                }
            },
            ModelError::NonFinite { field: "b_pr" },
        ),
        (
            |m| {
                if let Body::Nemm { k_pr, .. } = &mut m.body {
                    let n = k_pr.mlp.params.len();
                    k_pr.mlp.params[n - 1] = f32::NEG_INFINITY;
                }
            },
            ModelError::NonFinite { field: "k_pr" },
        ),
        (
            |m| {
                if let Body::Nemm { emm, .. } = &mut m.body {
                    emm.t_pr_s = f32::NAN;
                }
            },
            ModelError::NonFinite {
                field: "emm.t_pr_s",
            },
        ),
        (
            |m| m.scales.x_pr_m = 0.0,
            ModelError::NotPositive {
                field: "scales.x_pr_m",
            },
        ),
        (
            |m| {
                if let Body::Nemm { k_pr, .. } = &mut m.body {
                    k_pr.s_min = k_pr.s_max;
                }
            },
            ModelError::BadScalerBounds { scaler: "k_pr" },
        ),
        (
            |m| {
                if let Body::Nemm { b_fl, .. } = &mut m.body {
                    b_fl.s_max = f32::INFINITY;
                }
            },
            ModelError::BadScalerBounds { scaler: "b_fl" },
        ),
        (
            |m| {
                if let Body::Nemm { b_fl, .. } = &mut m.body {
                    b_fl.mlp.params.pop();
                }
            },
            ModelError::Shape {
                scaler: "b_fl",
                error: ShapeError::ParamCountMismatch {
                    expected: 13,
                    found: 12,
                },
            },
        ),
        (|m| m.meta.alpha_max = 1.5, ModelError::AlphaRange),
        (
            |m| {
                if let Body::Nemm { emm, .. } = &mut m.body {
                    emm.t_pr_s = 1e-5; // limit 0.8 * 2.785 * 10 us = 22.3 us < 100 us
                }
            },
            ModelError::UnstableStep {
                dt_s: 1e-4,
                tau_min_s: 1e-5,
                max_dt_s: 0.8 * 2.785 * 1e-5,
                integrator: nemm_core::Integrator::Rk4.name(),
            },
        ),
    ];
    for (edit, want) in cases {
        let mut m = base.clone();
        edit(&mut m);
        assert_eq!(m.validate(), Err(want));
        let mut buf = vec![0u8; 4096];
        assert_eq!(encode(&m, &mut buf), Err(EncodeError::Invalid(want)));
        let blob = craft_blob(&m, |_| {});
        assert_eq!(decode::<64>(&blob), Err(DecodeError::Invalid(want)));
    }
    // The scaler roles have fixed input counts.
    let mut m = base.clone();
    if let Body::Nemm { b_pr, b_fl, .. } = &mut m.body {
        *b_pr = b_fl.clone();
    }
    let want = ModelError::WrongInputCount {
        scaler: "b_pr",
        expected: 1,
        found: 2,
    };
    assert_eq!(
        decode::<64>(&craft_blob(&m, |_| {})),
        Err(DecodeError::Invalid(want))
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    /// decode(encode(m)) == m for random valid models of every kind, with scalers up to the
    /// largest of the Table 3 search space (32 wide, 9 deep), decoded into the default
    /// capacity and into exactly the capacity the header announces.
    #[test]
    fn round_trip(spec in common::arb_model(32, 9)) {
        common::with_big_stack(move || -> Result<(), TestCaseError> {
            let m: Model<{ P }> = spec.build();
            prop_assert_eq!(m.validate(), Ok(()));
            let blob = blob_of(&m);
            let h = read_header(&blob).unwrap();
            prop_assert_eq!(h.kind, spec.kind);
            prop_assert_eq!(h.max_scaler_params as usize, spec.max_params());
            prop_assert_eq!(h.max_scaler_params as usize, m.max_scaler_params());
            let back: Model<{ P }> = decode(&blob).unwrap();
            prop_assert_eq!(&back, &m);
            #[cfg(feature = "std")]
            prop_assert_eq!(nemm_core::encode_to_vec(&m).unwrap(), blob.clone());
            // Capacity: smaller than needed is refused, the announced size is enough.
            if h.max_scaler_params > 0 {
                let small = decode::<100>(&blob);
                if h.max_scaler_params > 100 {
                    prop_assert_eq!(small, Err(DecodeError::OverCapacity {
                        needed: h.max_scaler_params as usize, capacity: 100 }));
                } else {
                    prop_assert!(small.is_ok());
                }
            }
            Ok(())
        })?;
    }

    /// Sampled truncations and bit flips of large random models (up to 110 KB blobs).
    #[test]
    fn truncations_and_bit_flips_of_large_blobs(
        spec in common::arb_model(32, 9),
        cuts in prop::collection::vec(any::<prop::sample::Index>(), 16),
        flips in prop::collection::vec(any::<prop::sample::Index>(), 16),
    ) {
        common::with_big_stack(move || -> Result<(), TestCaseError> {
            let m: Model<{ P }> = spec.build();
            let blob = blob_of(&m);
            for cut in &cuts {
                let n = cut.index(blob.len());
                let r = decode::<{ P }>(&blob[..n]);
                prop_assert!(matches!(r, Err(DecodeError::Truncated { .. })), "{} bytes: {:?}", n, r);
            }
            for flip in &flips {
                let bit = flip.index(blob.len() * 8);
                let mut b = blob.clone();
                b[bit / 8] ^= 1 << (bit % 8);
                prop_assert!(decode::<{ P }>(&b).is_err(), "bit {} accepted", bit);
            }
            Ok(())
        })?;
    }

    /// Random bytes never panic.
    #[test]
    fn garbage_never_panics(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        decode_must_not_panic::<64>(&bytes)?;
        let _ = read_header(&bytes);
    }

    /// Random bytes behind a valid magic and version never panic.
    #[test]
    fn garbage_after_magic_never_panics(tail in prop::collection::vec(any::<u8>(), 0..512)) {
        let mut bytes = b"NEMM".to_vec();
        bytes.push(FORMAT_VERSION as u8);
        bytes.extend_from_slice(&tail);
        decode_must_not_panic::<64>(&bytes)?;
    }

    /// Past the CRC: a valid header and random or mutated body bytes with a recomputed CRC
    /// reach the body parser and the model validation; never a panic.
    #[test]
    fn garbage_body_with_valid_crc_never_panics(
        kind in 0usize..4,
        body in prop::collection::vec(any::<u8>(), 0..300),
        mutations in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..8),
    ) {
        // Random body under a header announcing its length.
        let m = &small_models()[kind];
        let h = read_header(&blob_of(m)).unwrap();
        let mut hb = [0u8; 32];
        let mut bytes = postcard::to_slice(
            &nemm_core::Header { body_len: body.len() as u32, ..h }, &mut hb).unwrap().to_vec();
        bytes.extend_from_slice(&body);
        bytes.extend_from_slice(&[0; CRC_LEN]);
        fix_crc(&mut bytes);
        decode_must_not_panic::<64>(&bytes)?;
        // A valid blob with a few bytes of its body replaced.
        let mut blob = blob_of(m);
        let header_len = blob.len() - h.body_len as usize - CRC_LEN;
        for (at, v) in &mutations {
            let i = header_len + at.index(h.body_len as usize);
            blob[i] = *v;
        }
        fix_crc(&mut blob);
        decode_must_not_panic::<64>(&blob)?;
        decode_must_not_panic::<8>(&blob)?;
    }
}

/// The spec generator covers every kind and the extreme sizes (guards the proptests above
/// against a generator that silently stopped producing some of them).
#[test]
fn generator_covers_kinds_and_sizes() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::TestRunner;
    let mut runner = TestRunner::deterministic();
    let strategy = common::arb_model(32, 9);
    let mut kinds = std::collections::HashSet::new();
    let mut largest = 0;
    for _ in 0..400 {
        let spec: ModelSpec = strategy.new_tree(&mut runner).unwrap().current();
        kinds.insert(spec.kind.name());
        largest = largest.max(spec.max_params());
    }
    assert_eq!(kinds.len(), 4);
    assert!(largest > 5000, "{largest}");
}

/// Every earlier format version still loads: the version-1 to -4 and -6 blobs in
/// `tests/data/format-v1` ... `format-v4`, `format-v6` (the example models of every kind as
/// those encoders wrote them; a version-2 body is the version-1 body with an empty
/// extension, the examples' version-3 extension is the default one) decode to the current
/// example models with the default extension (the paper's oil loss, no alpha branches, no
/// cumulative scalers) and no stored tables, and re-encode as the current version.
#[test]
fn version_1_to_4_and_6_blobs_still_load() {
    for version in [1u16, 2, 3, 4, 6] {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("tests/data/format-v{version}"));
        check_old_blobs(&dir, version);
    }
}

fn check_old_blobs(dir: &std::path::Path, version: u16) {
    for kind in KINDS {
        let path = dir.join(format!("example-{}.nemm", kind.name()));
        let v1 = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!(
            read_header(&v1).unwrap().version,
            version,
            "{}",
            path.display()
        );
        let model: Model<1400> = decode(&v1).unwrap_or_else(|e| panic!("{kind:?}: {e}"));
        let expected: Model<1400> = nemm_core::testing::example_model(kind, 16, 5).unwrap();
        assert_eq!(model, expected, "{kind:?}");
        let paper = nemm_core::Model::<1400>::new(
            model.integrator,
            model.dt_s,
            model.scales,
            model.meta,
            model.body.clone(),
        );
        assert_eq!(
            model, paper,
            "a version-1 blob reads as the paper's oil-loss model"
        );
        let (_, tables) = nemm_core::decode_with_tables::<1400>(&v1).unwrap();
        assert!(tables.levels.is_empty());
        let again = blob_of(&model);
        assert_eq!(read_header(&again).unwrap().version, FORMAT_VERSION);
        assert_eq!(decode::<1400>(&again).unwrap(), model);
    }
}

/// The provenance round-trips, is cut to its capacity on construction, and a blob whose
/// provenance holds a control character is refused with the field named.
#[test]
fn provenance_round_trips_and_is_validated() {
    use nemm_core::{Provenance, PROVENANCE_COMMIT_LEN};
    let mut model: Model<1400> = nemm_core::testing::example_model(ModelKind::Nemm, 16, 5).unwrap();
    let long_commit = "0123456789abcdef".repeat(8);
    model.provenance = Provenance::new(
        "nemm train --data bench\nx --out m.nemm",
        "virtual bench, seed 1",
        &long_commit,
    );
    assert_eq!(model.provenance.commit.len(), PROVENANCE_COMMIT_LEN);
    assert!(long_commit.starts_with(model.provenance.commit.as_str()));
    let blob = blob_of(&model);
    let back: Model<1400> = decode(&blob).unwrap();
    assert_eq!(back.provenance, model.provenance);
    assert_eq!(back.condition, model.condition);
    assert!(!back.provenance.is_empty());
    // Control characters are replaced on construction...
    let p = Provenance::new("a\tb", "", "");
    assert_eq!(p.command.as_str(), "a b");
    // ... and refused in a blob.
    model.provenance.dataset = heapless::String::try_from("line\nbreak").unwrap();
    assert_eq!(
        model.validate(),
        Err(ModelError::ControlCharacter {
            field: "provenance.dataset"
        })
    );
}

/// A static force round-trips on every EMM kind; the SEM refuses one; invalid fields are
/// refused by `encode` and, crafted into a blob, by `decode` with the same typed error.
#[test]
fn static_force_round_trips_and_is_validated() {
    let sf = nemm_core::testing::EXAMPLE_STATIC_FORCE;
    for kind in KINDS {
        let mut m: Model<64> = nemm_core::testing::example_model(kind, 2, 1).unwrap();
        m.static_force = Some(sf);
        if kind == ModelKind::Sem {
            assert_eq!(m.validate(), Err(ModelError::StaticForceOnSem));
            let blob = craft_blob(&m, |_| {});
            assert_eq!(
                decode::<64>(&blob),
                Err(DecodeError::Invalid(ModelError::StaticForceOnSem))
            );
            continue;
        }
        let blob = blob_of(&m);
        let back = decode::<64>(&blob).unwrap();
        assert_eq!(back.static_force, Some(sf), "{kind:?}");
        assert_eq!(back, m);
    }
    let base: Model<64> = nemm_core::testing::example_model(ModelKind::LinearEmm, 2, 1).unwrap();
    type Edit = fn(&mut nemm_core::StaticForce);
    let cases: [(Edit, ModelError); 4] = [
        (
            |s| s.f_gas0_n = f32::NAN,
            ModelError::NonFinite {
                field: "static_force.f_gas0_n",
            },
        ),
        (
            |s| s.x_ref_m = f32::INFINITY,
            ModelError::NonFinite {
                field: "static_force.x_ref_m",
            },
        ),
        (
            |s| s.f_c_n = -0.5,
            ModelError::Negative {
                field: "static_force.f_c_n",
            },
        ),
        (
            |s| s.v_c_m_s = -1e-3,
            ModelError::NotPositive {
                field: "static_force.v_c_m_s",
            },
        ),
    ];
    for (edit, err) in cases {
        let mut m = base.clone();
        let mut s = sf;
        edit(&mut s);
        m.static_force = Some(s);
        assert_eq!(encode(&m, &mut [0u8; 512]), Err(EncodeError::Invalid(err)));
        let blob = craft_blob(&m, |_| {});
        assert_eq!(decode::<64>(&blob), Err(DecodeError::Invalid(err)));
    }
}

/// The static force goes with every version-3 field (condition, alpha branches,
/// provenance): decoded in place into a model that held another one, it is replaced; a
/// version-3 blob decoded into a model with a static force leaves none.
#[test]
fn static_force_decodes_in_place_with_the_version_3_fields() {
    use nemm_core::{Priors, Provenance};
    let sf = nemm_core::testing::EXAMPLE_STATIC_FORCE;
    let mut m: Model<1400> =
        nemm_core::testing::example_model_with_branches(16, 5, 4, Priors::PAPER).unwrap();
    m.provenance = Provenance::new("nemm train --static-force", "bench", "abc");
    m.static_force = Some(sf);
    let blob = blob_of(&m);
    let mut into: Box<Model<1400>> = Box::new(Model::empty());
    into.static_force = Some(sf.with_params([1.0, 2.0, 3.0, 4.0, 5.0]));
    nemm_core::decode_into(&blob, &mut into).unwrap();
    assert_eq!(*into, m);
    assert!(into.alpha_branches.b_fl.is_some());
    let v3 = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/format-v3/example-nemm.nemm"),
    )
    .unwrap();
    nemm_core::decode_into(&v3, &mut into).unwrap();
    assert_eq!(into.static_force, None);
    assert_eq!(
        *into,
        nemm_core::testing::example_model(ModelKind::Nemm, 16, 5).unwrap()
    );
}

/// The lost-motion element round-trips on every EMM kind, is refused on the SEM and with a
/// bad value (field named), and a version-4 blob decoded in place into a model that held
/// one leaves none.
#[test]
fn lost_motion_round_trips_and_is_validated() {
    let lm = nemm_core::testing::EXAMPLE_LOST_MOTION;
    for kind in KINDS {
        let mut m: Model<64> = nemm_core::testing::example_model(kind, 2, 1).unwrap();
        m.lost_motion = Some(lm);
        if kind == ModelKind::Sem {
            assert_eq!(m.validate(), Err(ModelError::LostMotionOnSem));
            let blob = craft_blob(&m, |_| {});
            assert_eq!(
                decode::<64>(&blob),
                Err(DecodeError::Invalid(ModelError::LostMotionOnSem))
            );
            continue;
        }
        m.static_force = Some(nemm_core::testing::EXAMPLE_STATIC_FORCE);
        let blob = blob_of(&m);
        let back = decode::<64>(&blob).unwrap();
        assert_eq!(back.lost_motion, Some(lm), "{kind:?}");
        assert_eq!(back, m);
    }
    let base: Model<64> = nemm_core::testing::example_model(ModelKind::Nemm, 2, 1).unwrap();
    type Edit = fn(&mut nemm_core::LostMotion);
    let cases: [(Edit, ModelError); 3] = [
        (
            |l| l.travel_c_m = f32::NAN,
            ModelError::NonFinite {
                field: "lost_motion",
            },
        ),
        (
            |l| l.f0_n = 0.0,
            ModelError::NotPositive {
                field: "lost_motion.f0_n",
            },
        ),
        (
            |l| l.travel_r_per_alpha_m = -1e-4,
            ModelError::Negative {
                field: "lost_motion",
            },
        ),
    ];
    for (edit, err) in cases {
        let mut m = base.clone();
        let mut l = lm;
        edit(&mut l);
        m.lost_motion = Some(l);
        assert_eq!(encode(&m, &mut [0u8; 2048]), Err(EncodeError::Invalid(err)));
        let blob = craft_blob(&m, |_| {});
        assert_eq!(decode::<64>(&blob), Err(DecodeError::Invalid(err)));
    }
    let v4 = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/format-v4/example-nemm.nemm"),
    )
    .unwrap();
    let mut into: Box<Model<1400>> = Box::new(Model::empty());
    into.lost_motion = Some(lm);
    nemm_core::decode_into(&v4, &mut into).unwrap();
    assert_eq!(into.lost_motion, None);
    assert_eq!(
        *into,
        nemm_core::testing::example_model(ModelKind::Nemm, 16, 5).unwrap()
    );
}
