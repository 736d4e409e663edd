//! The tables section (format version 4): stored tables are the estimator's own, bit for
//! bit; an estimator whose configuration matches a stored level reads them instead of
//! building them, any other configuration builds them and says why; `set_alpha` rebuilds;
//! a damaged section is refused by the CRC, and past the CRC never panics.

mod common;

use common::{blob_of, blob_with_tables, fix_crc};
use nemm_core::{
    decode, decode_into, decode_with_tables, read_header, DecodeError, EncodeError, Estimator,
    EstimatorConfig, EvalMode, Model, ModelKind, Sample, StoredUnused, TableConfig, TableOrigin,
    CRC_LEN, FORMAT_VERSION, MAX_TABLE_LEVELS,
};

const P: usize = 1400;
/// Segments of the tables in these tests (small: quick to build, still tens of kinks).
const T: usize = 128;

type Est<const S: usize> = Estimator<'static, P, S>;

fn model(kind: ModelKind) -> Box<Model<P>> {
    Box::new(nemm_core::testing::example_model(kind, 16, 5).expect("example"))
}

fn table_cfg(alpha: f32) -> EstimatorConfig {
    EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1e-4)),
        ..EstimatorConfig::new(alpha)
    }
}

/// An estimator with `S` segments built (not read) at `cfg`.
fn built<const S: usize>(m: &Model<P>, cfg: EstimatorConfig) -> Box<Est<S>> {
    let mut e: Box<Est<S>> = Box::new(Estimator::empty());
    e.load(m, cfg).expect("builds");
    assert_eq!(
        e.table_origin(),
        TableOrigin::Built(StoredUnused::NotOffered)
    );
    e
}

/// The blob of `m` with tables of `S` segments at each of `alphas`.
fn blob_with<const S: usize>(m: &Model<P>, alphas: &[f32]) -> Vec<u8> {
    let ests: Vec<Box<Est<S>>> = alphas.iter().map(|&a| built(m, table_cfg(a))).collect();
    let refs: Vec<&Est<S>> = ests.iter().map(|e| &**e).collect();
    blob_with_tables(m, &refs).expect("encodes")
}

/// Loads `blob` (decoded) into an estimator with `S` segments at `cfg`, with the blob.
fn loaded<const S: usize>(blob: &[u8], cfg: EstimatorConfig) -> Box<Est<S>> {
    let mut m: Box<Model<P>> = Box::new(Model::empty());
    let tables = decode_into(blob, &mut m).expect("decodes");
    let mut e: Box<Est<S>> = Box::new(Estimator::empty());
    e.load_with_tables(&m, cfg, &tables, blob).expect("loads");
    e
}

/// A bench-like velocity input (m/s): two sines, reaching the tables' domain edges.
fn velocity(k: usize) -> f32 {
    let t = k as f32 * 1e-4;
    0.8 * (2.0 * core::f32::consts::PI * 3.0 * t).sin()
        + 0.3 * (2.0 * core::f32::consts::PI * 17.0 * t).sin()
}

/// Both estimators give the same force and flags, bit for bit, over a run.
fn assert_same_run<const A: usize, const B: usize>(a: &mut Est<A>, b: &mut Est<B>) {
    for k in 0..3000 {
        let (ea, eb) = (
            a.step(Sample::new(velocity(k))).unwrap(),
            b.step(Sample::new(velocity(k))).unwrap(),
        );
        assert_eq!(ea.force_n.to_bits(), eb.force_n.to_bits(), "step {k}");
        assert_eq!(ea.flags, eb.flags, "step {k}");
    }
}

#[test]
fn stored_tables_are_the_built_ones_bit_for_bit() {
    for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
        let m = model(kind);
        let blob = blob_with::<T>(&m, &[0.15, 0.3]);
        assert_eq!(read_header(&blob).unwrap().version, FORMAT_VERSION);
        let mut back: Box<Model<P>> = Box::new(Model::empty());
        let tables = decode_into(&blob, &mut back).unwrap();
        assert_eq!(tables.levels.len(), 2);
        assert_eq!(tables.blob_len as usize, blob.len());
        for alpha in [0.15f32, 0.3] {
            let tc = TableConfig::new(1e-4);
            let level = tables.find(alpha, &tc, T, &blob).unwrap();
            assert_eq!((level.segments as usize, level.alpha), (T, alpha));
            assert!(level.b_fl.is_some());
            assert_eq!(level.k_pr.is_some(), kind == ModelKind::Nemm);
            let mut stored = loaded::<T>(&blob, table_cfg(alpha));
            assert_eq!(
                stored.table_origin(),
                TableOrigin::Stored,
                "{kind:?} {alpha}"
            );
            let mut fresh = built::<T>(&m, table_cfg(alpha));
            assert_eq!(stored.table_accuracy(), fresh.table_accuracy());
            assert_eq!(stored.coefficients(), fresh.coefficients());
            assert!(level.b_fl.unwrap().accuracy.kinks > 0);
            assert_same_run(&mut stored, &mut fresh);
        }
        // The model part is the model: the blob without tables decodes to the same model.
        let plain: Model<P> = decode(&blob_of(&*m)).unwrap();
        assert_eq!(plain.body, back.body);
        let (_, plain_tables) = decode_with_tables::<P>(&blob_of(&*m)).unwrap();
        assert!(plain_tables.levels.is_empty());
    }
}

#[test]
fn other_configurations_build_their_tables_and_say_why() {
    let m = model(ModelKind::Nemm);
    let blob = blob_with::<T>(&m, &[0.15]);
    let cases: [(EstimatorConfig, TableOrigin); 3] = [
        (table_cfg(0.2), TableOrigin::Built(StoredUnused::Alpha)),
        (
            EstimatorConfig {
                mode: EvalMode::Table(TableConfig::new(2e-4)),
                ..EstimatorConfig::new(0.15)
            },
            TableOrigin::Built(StoredUnused::Config),
        ),
        (EstimatorConfig::new(0.15), TableOrigin::None),
    ];
    for (cfg, origin) in cases {
        let mut e = loaded::<T>(&blob, cfg);
        assert_eq!(e.table_origin(), origin, "{cfg:?}");
        let mut fresh: Box<Est<T>> = Box::new(Estimator::empty());
        fresh.load(&m, cfg).unwrap();
        assert_same_run(&mut e, &mut fresh);
    }
    // Another segment count (the capacity): built, with both counts.
    let mut e = loaded::<256>(&blob, table_cfg(0.15));
    assert_eq!(
        e.table_origin(),
        TableOrigin::Built(StoredUnused::Segments {
            stored: T as u32,
            capacity: 256
        })
    );
    assert_same_run(&mut e, &mut built::<256>(&m, table_cfg(0.15)));
    // A model decoded from another blob: the tables are not taken from it.
    let other = blob_with::<T>(&m, &[0.3]);
    let mut decoded: Box<Model<P>> = Box::new(Model::empty());
    let other_tables = decode_into(&other, &mut decoded).unwrap();
    let mut e: Box<Est<T>> = Box::new(Estimator::empty());
    e.load_with_tables(&decoded, table_cfg(0.15), &other_tables, &blob)
        .unwrap();
    assert_eq!(
        e.table_origin(),
        TableOrigin::Built(StoredUnused::OtherBlob)
    );
    // A blob without tables.
    let plain = blob_of(&*m);
    let e = loaded::<T>(&plain, table_cfg(0.15));
    assert_eq!(e.table_origin(), TableOrigin::Built(StoredUnused::NoLevels));
}

#[test]
fn set_alpha_rebuilds_from_stored_tables() {
    let m = model(ModelKind::Nemm);
    let blob = blob_with::<T>(&m, &[0.15]);
    let mut e = loaded::<T>(&blob, table_cfg(0.15));
    assert_eq!(e.table_origin(), TableOrigin::Stored);
    e.set_alpha(0.25).unwrap();
    assert_eq!(
        e.table_origin(),
        TableOrigin::Built(StoredUnused::NotOffered)
    );
    assert_same_run(&mut e, &mut built::<T>(&m, table_cfg(0.25)));
}

#[test]
fn encoding_refuses_tables_that_are_not_the_models() {
    let m = model(ModelKind::Nemm);
    let exact: Box<Est<T>> = {
        let mut e: Box<Est<T>> = Box::new(Estimator::empty());
        e.load(&m, EstimatorConfig::new(0.15)).unwrap();
        e
    };
    assert_eq!(blob_with_tables(&*m, &[&*exact]), Err(EncodeError::Tables));
    let t = built::<T>(&m, table_cfg(0.15));
    let many = vec![&*t; MAX_TABLE_LEVELS + 1];
    assert_eq!(blob_with_tables(&*m, &many), Err(EncodeError::Tables));
    // A NEMM-Light's tables (no `k_pr`) for a NEMM.
    let light = model(ModelKind::NemmLight);
    let lt = built::<T>(&light, table_cfg(0.15));
    assert_eq!(blob_with_tables(&*m, &[&*lt]), Err(EncodeError::Tables));
}

/// Where the tables section starts in `blob`: after its header and the model's body up to
/// the section.
fn section_start(m: &Model<P>, blob: &[u8]) -> usize {
    let header_len = blob.len() - read_header(blob).unwrap().body_len as usize - CRC_LEN;
    header_len + common::body_prefix(m).len()
}

#[test]
fn a_damaged_section_is_refused_by_the_crc_and_never_panics() {
    let m = model(ModelKind::Nemm);
    let blob = blob_with::<T>(&m, &[0.15]);
    let start = section_start(&m, &blob);
    // The padding byte, its zeros, then the level count (u32 LE) at a multiple of 4.
    let count = start + 1 + usize::from(blob[start]);
    assert_eq!(count % 4, 0);
    assert_eq!(blob[count..count + 4], 1u32.to_le_bytes(), "one level");
    let end = blob.len() - CRC_LEN;
    let stride = if cfg!(debug_assertions) { 257 } else { 7 };
    let mut refused = 0usize;
    for i in (start..end).step_by(stride) {
        let mut bad = blob.clone();
        bad[i] ^= 0x5a;
        assert!(
            matches!(decode::<P>(&bad), Err(DecodeError::CrcMismatch { .. })),
            "byte {i}"
        );
        // Past the CRC: a typed error, or a model whose estimator runs (reading its tables
        // or, if they do not read back, building them).
        fix_crc(&mut bad);
        match decode_with_tables::<P>(&bad) {
            Err(e) => {
                refused += 1;
                assert!(
                    matches!(e, DecodeError::Malformed { .. }),
                    "byte {i}: {e:?}"
                );
            }
            Ok((dm, tables)) => {
                let dm = Box::new(dm);
                let mut e: Box<Est<T>> = Box::new(Estimator::empty());
                if e.load_with_tables(&dm, table_cfg(0.15), &tables, &bad)
                    .is_ok()
                {
                    for k in 0..200 {
                        assert!(e
                            .step(Sample::new(velocity(k)))
                            .unwrap()
                            .force_n
                            .is_finite());
                    }
                }
            }
        }
    }
    assert!(refused > 0);
    // A NaN coefficient in a stored segment is refused by the section's checks.
    // The last table's last segment ends before the image's accuracy record (16 bytes).
    let mut nan = blob.clone();
    let last_value = end - 16 - 4;
    nan[last_value..last_value + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    fix_crc(&mut nan);
    assert_eq!(
        decode::<P>(&nan),
        Err(DecodeError::Malformed { part: "tables" })
    );
}
