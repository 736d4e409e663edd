//! Cumulative scalers in a model (`Model::cumulative`): format version 7 round-trips them bit
//! for bit and refuses a damaged section; validation refuses every misuse with a typed
//! error; the exact estimator runs the reference path (`Model::b_fl`, `Model::k_pr`), the
//! table-mode estimator follows it within the table's bound, and `set_alpha` moves the
//! coefficients in the declared direction.

mod common;

use common::{blob_of, craft_blob, fix_crc, with_big_stack, P};
use nemm_core::testing::{
    example_branch, example_cumulative_model, example_cumulative_scaler, example_model,
};
use nemm_core::{
    decode, decode_into, read_header, Body, CumulativeError, CumulativeModelError,
    CumulativeScaler, DecodeError, Direction, EncodeError, Estimator, EstimatorConfig, EvalMode,
    MlpParams, Model, ModelError, ModelKind, Sample, ShapeError, TableConfig, FORMAT_VERSION,
};

/// Capacity of the small models below.
const Q: usize = 128;

/// A small NEMM-Light (`example_model(NemmLight, 2, 1)`) whose `b_fl` is a cumulative
/// scaler of `units` units: a blob of a few hundred bytes.
fn light(units: u8) -> Model<Q> {
    let mut m: Model<Q> = example_model(ModelKind::NemmLight, 2, 1).unwrap();
    if let Body::NemmLight { b_fl, .. } = &mut m.body {
        b_fl.mlp = MlpParams::without_weights(2);
    }
    m.cumulative.b_fl = example_cumulative_scaler(Direction::Decreasing, units, 5);
    m
}

/// Decodes into a boxed model (no copy of a large model on the test's stack).
fn decode_boxed(blob: &[u8]) -> Result<Box<Model>, DecodeError> {
    let mut m: Box<Model> = Box::new(Model::empty());
    decode_into(blob, &mut m)?;
    Ok(m)
}

/// An estimator of `m` built in place on the heap.
fn estimator<const T: usize>(m: &Model, cfg: EstimatorConfig) -> Box<Estimator<'static, P, T>> {
    let mut e = Box::new(Estimator::<P, T>::empty());
    e.load(m, cfg).expect("loads");
    e
}

fn table(alpha: f32) -> EstimatorConfig {
    EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1e-4)),
        ..EstimatorConfig::new(alpha)
    }
}

/// A velocity sweep: sinusoids of 0.1 to 1 m/s peak at 2 and 5 Hz, 10 kHz.
fn sweep() -> Vec<f32> {
    let mut v = Vec::new();
    for (amp, hz) in [(0.1f32, 5.0f32), (0.5, 2.0), (1.0, 5.0)] {
        v.extend(
            (0..4000).map(|k| amp * (2.0 * core::f32::consts::PI * hz * k as f32 * 1e-4).sin()),
        );
    }
    v
}

/// `example_cumulative_model` is valid and round-trips through format version 7: the same
/// model, the same bytes encoded again, the bytes of the independent writer of the layout;
/// the header counts the cumulative scaler's parameters. Decoded in place over a model with
/// other cumulative scalers (or none), the blob's replace them; a version-6 blob leaves none.
#[test]
fn format_version_7_round_trips_bit_identically() {
    with_big_stack(|| {
        for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
            let m = Box::new(example_cumulative_model(kind));
            assert_eq!(m.validate(), Ok(()), "{kind:?}");
            assert!(m.cumulative.b_fl.is_some());
            assert_eq!(m.cumulative.k_pr.is_some(), kind == ModelKind::Nemm);
            let blob = blob_of(&*m);
            let h = read_header(&blob).unwrap();
            assert_eq!((h.version, FORMAT_VERSION), (7, 7));
            assert_eq!(h.max_scaler_params as usize, m.max_scaler_params());
            assert!(m.max_scaler_params() >= nemm_core::cumulative_param_count(16));
            assert_eq!(
                blob,
                craft_blob(&*m, |_| {}),
                "{kind:?}: the documented layout"
            );
            let back = decode_boxed(&blob).unwrap();
            assert_eq!(*back, *m);
            assert_eq!(blob_of(&*back), blob, "{kind:?}: re-encoded bit for bit");
            // In place over other cumulative scalers, and a version-6 blob over these.
            let mut into: Box<Model> = Box::new(example_cumulative_model(ModelKind::Nemm));
            into.cumulative.k_pr = example_cumulative_scaler(Direction::None, 3, 99);
            decode_into(&blob, &mut into).unwrap();
            assert_eq!(*into, *m);
            let v6 = std::fs::read(
                std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                    .join(format!("tests/data/format-v6/example-{}.nemm", kind.name())),
            )
            .unwrap();
            assert_eq!(read_header(&v6).unwrap().version, 6);
            decode_into(&v6, &mut into).unwrap();
            assert!(into.cumulative.is_empty());
            assert_eq!(*into, example_model::<P>(kind, 16, 5).unwrap());
        }
    });
}

/// A version-7 blob with a cumulative scaler: every truncation is `Truncated`, every
/// single-bit flip is refused, and a damaged cumulative section with its CRC recomputed is
/// refused as malformed (an unknown option tag) or invalid (a unit count out of range).
#[test]
fn damaged_version_7_blobs_are_refused() {
    let m = light(16);
    let blob = blob_of(&m);
    assert_eq!(decode::<Q>(&blob).as_ref(), Ok(&m));
    for n in 0..blob.len() {
        assert!(
            matches!(decode::<Q>(&blob[..n]), Err(DecodeError::Truncated { found, .. }) if found == n),
            "prefix of {n} bytes"
        );
    }
    for bit in 0..blob.len() * 8 {
        let mut b = blob.clone();
        b[bit / 8] ^= 1 << (bit % 8);
        assert!(decode::<Q>(&b).is_err(), "bit {bit} accepted");
    }
    // The cumulative section ends where the body's prefix does, before the tables section.
    let section = postcard::to_allocvec(&m.cumulative).unwrap();
    let header_len = blob.len() - read_header(&blob).unwrap().body_len as usize - 4;
    let end = header_len + common::body_prefix(&m).len();
    let start = end - section.len();
    assert_eq!(&blob[start..end], &section[..]);
    // `b_fl`'s option tag 2: no such variant.
    let mut b = blob.clone();
    b[start] = 2;
    fix_crc(&mut b);
    assert_eq!(
        decode::<Q>(&b),
        Err(DecodeError::Malformed { part: "cumulative" })
    );
    // The unit count (after the tag and the direction) 17.
    let mut b = blob.clone();
    assert_eq!(b[start + 2], 16);
    b[start + 2] = 17;
    fix_crc(&mut b);
    assert_eq!(
        decode::<Q>(&b),
        Err(DecodeError::Invalid(ModelError::Cumulative {
            scaler: "b_fl",
            error: CumulativeModelError::Scaler(CumulativeError::UnitsOutOfRange),
        }))
    );
}

/// Every misuse of a cumulative scaler is refused by `validate`, by `encode` and, written by
/// the independent writer, by `decode`, with the same typed error.
#[test]
fn every_misuse_is_refused_with_a_typed_error() {
    type Edit = fn(&mut Model<Q>);
    let cum = |error| ModelError::Cumulative {
        scaler: "b_fl",
        error,
    };
    let cases: Vec<(&str, Edit, ModelError)> = vec![
        (
            "k_pr on a NEMM-Light",
            |m| m.cumulative.k_pr = example_cumulative_scaler(Direction::Decreasing, 4, 1),
            ModelError::Cumulative {
                scaler: "k_pr",
                error: CumulativeModelError::NoScaler,
            },
        ),
        (
            "an MLP with weights beside it",
            |m| {
                if let Body::NemmLight { b_fl, .. } = &mut m.body {
                    b_fl.mlp = nemm_core::testing::example_scaler::<Q>(2, 2, 1, 1)
                        .unwrap()
                        .mlp;
                }
            },
            cum(CumulativeModelError::MlpWeights),
        ),
        (
            "an MLP without weights and without a cumulative scaler",
            |m| m.cumulative.b_fl = None,
            ModelError::Shape {
                scaler: "b_fl",
                error: ShapeError::DimensionOutOfRange,
            },
        ),
        (
            "an MLP without weights of one input",
            |m| {
                if let Body::NemmLight { b_fl, .. } = &mut m.body {
                    b_fl.mlp = MlpParams::without_weights(1);
                }
            },
            ModelError::WrongInputCount {
                scaler: "b_fl",
                expected: 2,
                found: 1,
            },
        ),
        (
            "an alpha branch beside it",
            |m| m.alpha_branches.b_fl = example_branch(Direction::Decreasing, 1, 4, 3),
            cum(CumulativeModelError::AlphaBranch),
        ),
        (
            "a direction against the prior",
            |m| m.cumulative.b_fl.as_mut().unwrap().direction = Direction::Increasing,
            cum(CumulativeModelError::DirectionMismatch),
        ),
        (
            "a direction where the prior is none",
            |m| m.condition.priors.b_fl = Direction::None,
            cum(CumulativeModelError::DirectionMismatch),
        ),
        (
            "a NaN weight",
            |m| m.cumulative.b_fl.as_mut().unwrap().params[7] = f32::NAN,
            cum(CumulativeModelError::Scaler(CumulativeError::NonFinite)),
        ),
        (
            "no units",
            |m| {
                let c = m.cumulative.b_fl.as_mut().unwrap();
                c.units = 0;
                c.params.truncate(3);
            },
            cum(CumulativeModelError::Scaler(
                CumulativeError::UnitsOutOfRange,
            )),
        ),
        (
            "a parameter missing",
            |m| {
                m.cumulative.b_fl.as_mut().unwrap().params.pop();
            },
            cum(CumulativeModelError::Scaler(
                CumulativeError::ParamCountMismatch {
                    expected: 83,
                    found: 82,
                },
            )),
        ),
        (
            "bounds not 0 < s_min < s_max",
            |m| {
                if let Body::NemmLight { b_fl, .. } = &mut m.body {
                    b_fl.s_min = 4.0;
                }
            },
            ModelError::BadScalerBounds { scaler: "b_fl" },
        ),
    ];
    for (what, edit, err) in cases {
        let mut m = light(16);
        edit(&mut m);
        assert_eq!(m.validate(), Err(err), "{what}");
        assert_eq!(
            nemm_core::encode(&m, &mut [0u8; 4096]),
            Err(EncodeError::Invalid(err)),
            "{what}"
        );
        assert_eq!(
            decode::<Q>(&craft_blob(&m, |_| {})),
            Err(DecodeError::Invalid(err)),
            "{what}"
        );
    }
    // A cumulative scaler on a kind without state-dependent coefficients.
    let mut lin: Model<Q> = example_model(ModelKind::LinearEmm, 2, 1).unwrap();
    lin.cumulative.b_fl = example_cumulative_scaler(Direction::Decreasing, 4, 1);
    assert_eq!(lin.validate(), Err(cum(CumulativeModelError::NoScaler)));
    // `none` is accepted whatever the prior.
    let mut m = light(16);
    m.cumulative.b_fl.as_mut().unwrap().direction = Direction::None;
    assert_eq!(m.validate(), Ok(()));
    // A capacity below the scaler's 5 K + 3 = 83 values: refused before the body is read.
    let small: Model<64> = {
        let mut s: Model<64> = example_model(ModelKind::NemmLight, 2, 1).unwrap();
        if let Body::NemmLight { b_fl, .. } = &mut s.body {
            b_fl.mlp = MlpParams::without_weights(2);
        }
        s.cumulative = light(16).cumulative;
        s
    };
    let over = ModelError::Shape {
        scaler: "b_fl",
        error: ShapeError::OverCapacity {
            needed: 83,
            capacity: 64,
        },
    };
    assert_eq!(small.validate(), Err(over));
    assert_eq!(
        decode::<64>(&craft_blob(&small, |_| {})),
        Err(DecodeError::OverCapacity {
            needed: 83,
            capacity: 64,
        })
    );
    assert_eq!(
        decode::<83>(&blob_of(&light(16))).map(|m| m.max_scaler_params()),
        Ok(83)
    );
}

/// The exact estimator's coefficients at its state are the reference path's
/// (`Model::b_fl`, `Model::k_pr`) within 1e-6 relative (in fact bit for bit) over a velocity
/// sweep, at three levels, and its force is the reference run's.
#[test]
fn exact_estimator_runs_the_reference_path() {
    with_big_stack(|| {
        let inputs = sweep();
        for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
            let m = Box::new(example_cumulative_model(kind));
            for alpha in [0.0f32, 0.15, 0.3] {
                let mut e = estimator::<3>(&m, EstimatorConfig::new(alpha));
                let reference = common::reference_run(&*m, m.integrator, m.dt_s, alpha, &inputs);
                let mut worst = 0.0f32;
                for (&u, &f) in inputs.iter().zip(&reference) {
                    let est = e.step(Sample::new(u)).unwrap();
                    assert!(est.flags.is_empty(), "{:?}", est.flags);
                    let (s, c) = (e.state(), e.coefficients());
                    let b_fl = m.b_fl(s.v_st_m_s, alpha).unwrap();
                    let k_pr = m.k_pr(s.x_pr_m, alpha).unwrap();
                    assert!((c.b_fl - b_fl).abs() <= 1e-6 * b_fl, "{} vs {b_fl}", c.b_fl);
                    assert!((c.k_pr - k_pr).abs() <= 1e-6 * k_pr, "{} vs {k_pr}", c.k_pr);
                    assert_eq!(c.b_fl.to_bits(), b_fl.to_bits());
                    worst = worst.max((est.force_n - f).abs());
                }
                assert!(
                    worst <= 1e-6 * m.meta.force_scale_n,
                    "{kind:?} {alpha}: {worst} N"
                );
            }
        }
    });
}

/// The table-mode estimator (256 segments, bound 1e-4) follows the exact one over the
/// velocity sweep within 1e-4 of the force scale, at three levels; its tables have no kinks.
#[test]
fn table_mode_follows_exact_mode() {
    with_big_stack(|| {
        let inputs = sweep();
        for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
            let m = Box::new(example_cumulative_model(kind));
            for alpha in [0.0f32, 0.15, 0.3] {
                let mut exact = estimator::<3>(&m, EstimatorConfig::new(alpha));
                let mut tab = estimator::<256>(&m, table(alpha));
                let acc = tab.table_accuracy().unwrap();
                assert!(acc.max_rel_error <= 1e-4 && acc.kinks == 0, "{acc:?}");
                let mut worst = 0.0f32;
                for &u in &inputs {
                    let (a, b) = (
                        exact.step(Sample::new(u)).unwrap(),
                        tab.step(Sample::new(u)).unwrap(),
                    );
                    assert!(b.flags.is_empty(), "{:?}", b.flags);
                    worst = worst.max((a.force_n - b.force_n).abs());
                }
                assert!(
                    worst <= 1e-4 * m.meta.force_scale_n,
                    "{kind:?} {alpha}: {worst} N"
                );
            }
        }
    });
}

/// `set_alpha` moves each cumulative coefficient in its declared direction (decreasing) at
/// the state the estimator is in, in exact and table mode, and gives the reference there.
#[test]
fn set_alpha_moves_in_the_declared_direction() {
    with_big_stack(|| {
        let m = Box::new(example_cumulative_model(ModelKind::Nemm));
        let inputs = sweep();
        for cfg in [EstimatorConfig::new(0.0), table(0.0)] {
            let mut e = estimator::<256>(&m, cfg);
            for (k, &u) in inputs.iter().enumerate() {
                e.step(Sample::new(u)).unwrap();
                if k % 2999 != 0 {
                    continue;
                }
                let mut last = e.coefficients();
                for alpha in [0.1f32, 0.2, 0.3, 0.6, 1.0] {
                    e.set_alpha(alpha).unwrap();
                    let c = e.coefficients();
                    assert!(c.b_fl < last.b_fl && c.k_pr < last.k_pr, "{alpha}: {c:?}");
                    if matches!(cfg.mode, EvalMode::Exact) {
                        let s = e.state();
                        assert_eq!(c.b_fl, m.b_fl(s.v_st_m_s, alpha).unwrap());
                        assert_eq!(c.k_pr, m.k_pr(s.x_pr_m, alpha).unwrap());
                    }
                    last = c;
                }
                e.set_alpha(0.0).unwrap();
            }
        }
    });
}

/// The scaler's own constructor refuses what `validate` refuses of its weights.
#[test]
fn cumulative_scaler_new_checks_its_weights() {
    assert_eq!(
        CumulativeScaler::new(Direction::Decreasing, 2, &[0.0; 12]),
        Err(CumulativeError::ParamCountMismatch {
            expected: 13,
            found: 12
        })
    );
    assert!(CumulativeScaler::new(Direction::Decreasing, 2, &[0.0; 13]).is_ok());
}

/// The tables section after the cumulative scalers stays 4-byte aligned: the stored tables
/// of two levels of a cumulative model are read back by a table-mode estimator (the built
/// tables' steps, bit for bit) and in place by level tables.
#[test]
fn stored_tables_of_a_cumulative_model_are_read_in_place() {
    use nemm_core::{AlignedBlob, LevelTables, TableOrigin};
    with_big_stack(|| {
        for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
            let m = Box::new(example_cumulative_model(kind));
            let built: Vec<Box<Estimator<'static, P, 128>>> = [0.0f32, 0.3]
                .iter()
                .map(|&a| estimator::<128>(&m, table(a)))
                .collect();
            let refs: Vec<&Estimator<P, 128>> = built.iter().map(|e| &**e).collect();
            let blob: &'static AlignedBlob = Box::leak(Box::new(AlignedBlob::new(
                &common::blob_with_tables(&*m, &refs).unwrap(),
            )));
            let mut back: Box<Model> = Box::new(Model::empty());
            let index = decode_into(blob, &mut back).unwrap();
            assert_eq!(*back, *m);
            assert_eq!(index.levels.len(), 2);
            let mut stored = Box::new(Estimator::<P, 128>::empty());
            stored
                .load_with_tables(&back, table(0.3), &index, blob)
                .unwrap();
            assert_eq!(stored.table_origin(), TableOrigin::Stored);
            let mut levels: Box<LevelTables<'static, 128, 4>> = Box::new(LevelTables::empty());
            levels.load(&back, &index, blob).unwrap();
            assert_eq!(levels.alphas(), &[0.0, 0.3]);
            let mut again = estimator::<128>(&m, table(0.3));
            for &u in &sweep()[..3000] {
                let (a, b) = (
                    stored.step(Sample::new(u)).unwrap(),
                    again.step(Sample::new(u)).unwrap(),
                );
                assert_eq!(a.force_n.to_bits(), b.force_n.to_bits());
            }
        }
    });
}
