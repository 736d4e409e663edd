//! Every level at table cost: the stored tables of several levels drive an estimator with a
//! level per sample and the observer's bank. At a stored level the step is the table-mode
//! estimator's at that level, bit for bit; between levels the blend is monotone in alpha
//! and close to the exact model; a wrong blob, too few levels or another model's tables are
//! refused with typed errors.

mod common;

use common::blob_with_tables;
use nemm_core::testing::example_model_with_branches;
use nemm_core::Sample;
use nemm_core::{
    decode_into, AlignedBlob, AlphaObserver, Estimator, EstimatorConfig, EstimatorError, EvalMode,
    Flags, LevelTables, LevelsError, Model, ModelKind, ObserverConfig, Priors, TableConfig,
};
use nemm_kernels::emm::State;

const P: usize = 1400;
const T: usize = 128;
const LEVELS: [f32; 7] = [0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3];

type Levels = LevelTables<'static, T, 8>;

fn model() -> Box<Model<P>> {
    let mut m = Box::new(example_model_with_branches::<P>(16, 5, 8, Priors::PAPER).unwrap());
    m.meta.alpha_min = 0.0;
    m.meta.alpha_max = 0.3;
    m
}

fn table_cfg(alpha: f32) -> EstimatorConfig {
    EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1e-4)),
        ..EstimatorConfig::new(alpha)
    }
}

/// The blob of `m` with tables of `T` segments at `alphas`, held 4-byte aligned for the
/// test's whole run (level tables read it in place).
fn blob_with(m: &Model<P>, alphas: &[f32]) -> &'static [u8] {
    Box::leak(Box::new(AlignedBlob::new(&blob_vec(m, alphas))))
}

/// The blob of `m` with tables of `T` segments at `alphas`, as the encoder returns it.
fn blob_vec(m: &Model<P>, alphas: &[f32]) -> Vec<u8> {
    let ests: Vec<Box<Estimator<P, T>>> = alphas
        .iter()
        .map(|&a| {
            let mut e = Box::new(Estimator::empty());
            e.load(m, table_cfg(a)).expect("tables within the bound");
            e
        })
        .collect();
    let refs: Vec<&Estimator<P, T>> = ests.iter().map(|e| &**e).collect();
    blob_with_tables(m, &refs).expect("encodes")
}

/// The decoded model, its level tables and the blob.
fn loaded(alphas: &[f32]) -> (Box<Model<P>>, Box<Levels>, &'static [u8]) {
    loaded_of(&model(), alphas)
}

/// [`loaded`] for the model `of`.
fn loaded_of(of: &Model<P>, alphas: &[f32]) -> (Box<Model<P>>, Box<Levels>, &'static [u8]) {
    let blob = blob_with(of, alphas);
    let mut m: Box<Model<P>> = Box::new(Model::empty());
    let tables = decode_into(blob, &mut m).expect("decodes");
    let mut levels: Box<Levels> = Box::new(LevelTables::empty());
    levels.load(&m, &tables, blob).expect("levels load");
    (m, levels, blob)
}

fn exact<'l>(m: &Model<P>, alpha: f32) -> Box<Estimator<'l, P, 3>> {
    let mut e = Box::new(Estimator::empty());
    e.load(m, EstimatorConfig::new(alpha)).expect("loads");
    e
}

/// A 5 Hz sinusoid of `amp` m/s at sample `k` (10 kHz).
fn velocity(k: usize, amp: f32) -> f32 {
    amp * (2.0 * core::f32::consts::PI * 5.0 * k as f32 * 1e-4).sin()
}

#[test]
fn at_a_stored_level_the_step_is_the_table_mode_estimators() {
    let (m, levels, blob) = loaded(&LEVELS);
    assert_eq!(levels.alphas(), &LEVELS);
    assert_eq!(levels.table_bytes(), (14, 14 * (32 + 28 * T)));
    stored_levels_step_as_table_mode(&m, &levels, blob);
}

/// With the lost-motion element too: the level tables apply it at the level in use, as the
/// table-mode estimator does.
#[test]
fn with_lost_motion_a_stored_level_step_is_the_table_mode_estimators() {
    let mut m = model();
    m.lost_motion = Some(nemm_core::testing::EXAMPLE_LOST_MOTION);
    let (m, levels, blob) = loaded_of(&m, &LEVELS);
    assert!(m.lost_motion.is_some());
    stored_levels_step_as_table_mode(&m, &levels, blob);
}

/// At levels 0, 3 and 6 of [`LEVELS`] a level-per-sample step is bit for bit the
/// table-mode estimator's at that level.
fn stored_levels_step_as_table_mode(m: &Model<P>, levels: &Levels, blob: &[u8]) {
    for k in [0, 3, 6] {
        let alpha = LEVELS[k];
        let mut mm: Box<Model<P>> = Box::new(Model::empty());
        let tables = decode_into(blob, &mut mm).unwrap();
        let mut reference: Box<Estimator<P, T>> = Box::new(Estimator::empty());
        reference
            .load_with_tables(&mm, table_cfg(alpha), &tables, blob)
            .unwrap();
        let mut est = exact(m, 0.15);
        est.attach_levels(levels).unwrap();
        for i in 0..3000 {
            let v = velocity(i, 0.6);
            let a = reference.step(Sample::new(v)).unwrap();
            let b = est.step(Sample::new(v).with_alpha(alpha)).unwrap();
            assert_eq!(
                a.force_n.to_bits(),
                b.force_n.to_bits(),
                "level {alpha}, step {i}"
            );
            assert_eq!(a.flags, b.flags);
        }
    }
}

#[test]
fn the_blend_is_monotone_in_alpha_between_levels_and_across_ordered_levels() {
    let (m, levels, _) = loaded(&LEVELS);
    let mut ex = exact(&m, 0.0);
    let check = levels.check(&mut ex, 3, 2).unwrap();
    let sweep: Vec<f32> = (0..=600).map(|j| 0.3 * j as f32 / 600.0).collect();
    let mut inside = 0;
    let mut across = 0;
    for k in 0..=400 {
        let f = k as f32 / 400.0;
        let s = State {
            x_pr_m: (2.0 * f - 1.0) * m.scales.x_pr_m,
            v_st_m_s: (2.0 * f - 1.0) * m.scales.velocity_m_s,
        };
        let c: Vec<_> = sweep
            .iter()
            .map(|&a| levels.coefficients(&s, a).unwrap())
            .collect();
        for (j, w) in c.windows(2).enumerate() {
            let up = w[1].b_fl > w[0].b_fl || w[1].k_pr > w[0].k_pr || w[1].b_pr > w[0].b_pr;
            if up {
                // A rise can only sit on a stored level (the blend within an interval is
                // monotone by construction).
                let at_level = LEVELS.iter().any(|&l| sweep[j] <= l && l <= sweep[j + 1]);
                if at_level {
                    across += 1;
                } else {
                    inside += 1;
                }
            }
        }
    }
    assert_eq!(inside, 0, "the blend rose in alpha inside an interval");
    if check.table_order_violations == 0 {
        assert_eq!(across, 0, "ordered levels, yet the blend rose at a level");
    }
    // The example model's priors hold by construction (alpha branches): exact and tables
    // both ordered.
    assert_eq!(check.exact_order_violations, 0, "{check:?}");
}

#[test]
fn the_blend_error_is_measured_and_shrinks_with_more_levels() {
    let (m, seven, _) = loaded(&LEVELS);
    let (_, four, _) = loaded(&[0.0, 0.1, 0.2, 0.3]);
    let mut ex = exact(&m, 0.0);
    let c7 = seven.check(&mut ex, 3, 4).unwrap();
    let c4 = four.check(&mut ex, 3, 4).unwrap();
    assert!(c7.points > 0 && c4.points > 0);
    // b_fl and b_pr depend on alpha; the blend errs between the levels, less with more.
    assert!(
        c7.max_rel_error[0] > 0.0 && c7.max_rel_error[1] > 0.0,
        "{c7:?}"
    );
    for k in 0..3 {
        assert!(
            c7.max_rel_error[k] <= c4.max_rel_error[k],
            "coefficient {k}: 7 levels {c7:?}, 4 levels {c4:?}"
        );
    }
    assert!(
        c7.max_rel_error.iter().all(|e| e.is_finite() && *e < 0.1),
        "{c7:?}"
    );
}

#[test]
fn a_level_per_sample_follows_the_exact_model() {
    let (m, levels, _) = loaded(&LEVELS);
    let mut tab = exact(&m, 0.0);
    tab.attach_levels(&levels).unwrap();
    let mut ex = exact(&m, 0.0);
    let n = 20_000;
    let mut worst = 0.0f32;
    for i in 0..n {
        let alpha = 0.3 * i as f32 / n as f32;
        let v = velocity(i, 0.8);
        let a = ex.step(Sample::new(v).with_alpha(alpha)).unwrap().force_n;
        let b = tab.step(Sample::new(v).with_alpha(alpha)).unwrap();
        assert!(b.flags.is_empty(), "step {i}: {:?}", b.flags);
        worst = worst.max((a - b.force_n).abs());
    }
    let rel = worst / m.meta.force_scale_n;
    eprintln!("per-sample alpha on 7 levels: max |force difference| / force scale = {rel:.2e}");
    assert!(rel < 1e-2, "{rel}");
}

#[test]
fn bad_levels_and_bad_inputs_are_refused_or_held() {
    let (m, levels, blob) = loaded(&LEVELS);
    let empty: Box<Levels> = Box::new(LevelTables::empty());
    let mut est = exact(&m, 0.0);
    est.attach_levels(&levels).unwrap();
    assert!(est.has_levels());
    // alpha outside [0, 1] or NaN: refused, nothing changes.
    for a in [f32::NAN, -0.1, 1.5] {
        assert_eq!(
            est.step(Sample::new(0.1).with_alpha(a)),
            Err(EstimatorError::AlphaOutOfRange)
        );
    }
    assert_eq!(est.diagnostics().steps, 0);
    // alpha beyond the levels: nearest level, flagged.
    let e = est.step(Sample::new(0.1).with_alpha(0.5)).unwrap();
    assert!(e.flags.contains(Flags::ALPHA_EXTRAPOLATED));
    // A NaN velocity is held, the state stays finite.
    let e = est.step(Sample::new(f32::NAN).with_alpha(0.1)).unwrap();
    assert!(e.flags.contains(Flags::INPUT_HELD) && e.force_n.is_finite());
    // The estimator's own level is not changed by the levels.
    assert_eq!(est.alpha(), 0.0);
    // Empty tables, or another model's: refused, the attached ones kept.
    assert_eq!(
        est.attach_levels(&empty),
        Err(EstimatorError::Levels(LevelsError::Mismatch))
    );
    assert!(est.has_levels());
    let light = nemm_core::testing::example_model::<P>(ModelKind::NemmLight, 16, 5).unwrap();
    let mut other = exact(&light, 0.1);
    assert_eq!(
        other.attach_levels(&levels),
        Err(EstimatorError::Levels(LevelsError::Mismatch))
    );
    assert!(!other.has_levels());
    // Detached, a sample's alpha is applied to the estimator's own scalers; loading a
    // model detaches too.
    est.detach_levels();
    est.step(Sample::new(0.1).with_alpha(0.2)).unwrap();
    assert_eq!(est.alpha(), 0.2);
    est.attach_levels(&levels).unwrap();
    est.load(&m, nemm_core::EstimatorConfig::new(0.1)).unwrap();
    assert!(!est.has_levels());
    // Loading: one level is too few; another blob is refused; the index and the blob of
    // one export belong together.
    let one = blob_with(&m, &[0.1]);
    let mut mm: Box<Model<P>> = Box::new(Model::empty());
    let tables = decode_into(one, &mut mm).unwrap();
    let mut l: Box<Levels> = Box::new(LevelTables::empty());
    assert_eq!(
        l.load(&mm, &tables, one),
        Err(LevelsError::TooFewLevels {
            found: 1,
            segments: T
        })
    );
    let tables = decode_into(blob, &mut mm).unwrap();
    assert_eq!(l.load(&mm, &tables, one), Err(LevelsError::OtherBlob));
    assert!(l.is_empty());
    let mut small: Box<LevelTables<'_, T, 4>> = Box::new(LevelTables::empty());
    assert_eq!(
        small.load(&mm, &tables, blob),
        Err(LevelsError::TooManyLevels {
            found: 7,
            capacity: 4
        })
    );
    let sem = nemm_core::testing::example_model::<P>(ModelKind::Sem, 16, 5).unwrap();
    assert_eq!(
        l.load(&sem, &tables, blob),
        Err(LevelsError::NoNeuralCoefficient)
    );
}

#[test]
fn the_observer_on_levels_agrees_with_the_exact_observer() {
    let (m, levels, _) = loaded(&LEVELS);
    let truth = 0.12;
    let mut plant = exact(&m, truth);
    let mut on_levels: Box<AlphaObserver<P, 8>> = Box::new(AlphaObserver::empty());
    on_levels
        .load_on_levels(&m, &levels, ObserverConfig::new())
        .unwrap();
    let mut reference: Box<AlphaObserver<P, 8>> = Box::new(AlphaObserver::empty());
    let cfg = ObserverConfig {
        points: Some(7),
        grid: Some((0.0, 0.3)),
        ..ObserverConfig::new()
    };
    reference.load(&m, cfg).unwrap();
    assert_eq!(on_levels.grid().collect::<Vec<_>>(), LEVELS);
    assert_eq!(reference.grid().collect::<Vec<_>>(), LEVELS);
    let (mut a, mut b) = (on_levels.estimate(), reference.estimate());
    for i in 0..20_000 {
        let v = velocity(i, 0.6);
        let f = plant.step(Sample::new(v)).unwrap().force_n;
        a = on_levels.step(Sample::new(v).with_force(f));
        b = reference.step(Sample::new(v).with_force(f));
    }
    assert!(
        !a.flags.contains(nemm_core::ObserverFlags::NOT_EXCITED),
        "{a:?}"
    );
    assert!(
        (a.alpha - b.alpha).abs() < 2e-3,
        "levels {a:?}, exact {b:?}"
    );
    assert!((a.alpha - truth).abs() < 0.01, "{a:?}");
    // The grid is the levels': another grid is refused.
    let mut o: Box<AlphaObserver<P, 8>> = Box::new(AlphaObserver::empty());
    let bad = ObserverConfig {
        grid: Some((0.0, 0.2)),
        ..ObserverConfig::new()
    };
    assert!(o.load_on_levels(&m, &levels, bad).is_err());
}

#[test]
fn the_tables_are_read_in_place_from_an_aligned_blob_only() {
    let (m, levels, blob) = loaded(&LEVELS);
    drop(m);
    // In place: the level tables take a few hundred bytes whatever their number; the
    // tables lie in the blob.
    assert!(
        core::mem::size_of::<Levels>() < 512,
        "{}",
        core::mem::size_of::<Levels>()
    );
    let (_, bytes) = levels.table_bytes();
    assert!(bytes < blob.len());
    // The same blob one byte off the 4-byte boundary: refused, typed, nothing loaded.
    let mut shifted: Vec<u32> = vec![0; blob.len().div_ceil(4) + 1];
    let off: &mut [u8] = bytemuck::cast_slice_mut(&mut shifted);
    let off = &mut off[1..=blob.len()];
    off.copy_from_slice(blob);
    let off: &[u8] = off;
    let mut mm: Box<Model<P>> = Box::new(Model::empty());
    let tables = decode_into(off, &mut mm).expect("an unaligned blob decodes");
    let mut l: Box<LevelTables<'_, T, 8>> = Box::new(LevelTables::empty());
    assert_eq!(l.load(&mm, &tables, off), Err(LevelsError::Unaligned));
    assert!(l.is_empty());
    // A table-mode estimator copies the stored tables from any alignment: the same
    // tables as from the aligned blob.
    let mut a: Box<Estimator<P, T>> = Box::new(Estimator::empty());
    a.load_with_tables(&mm, table_cfg(LEVELS[2]), &tables, off)
        .unwrap();
    let mut b: Box<Estimator<P, T>> = Box::new(Estimator::empty());
    let aligned = decode_into(blob, &mut mm).unwrap();
    b.load_with_tables(&mm, table_cfg(LEVELS[2]), &aligned, blob)
        .unwrap();
    assert_eq!(
        a.table_origin(),
        b.table_origin(),
        "both read the stored tables"
    );
    for i in 0..2_000 {
        let v = velocity(i, 0.6);
        let (fa, fb) = (
            a.step(Sample::new(v)).unwrap(),
            b.step(Sample::new(v)).unwrap(),
        );
        assert_eq!(fa.force_n.to_bits(), fb.force_n.to_bits(), "{i}");
    }
}

/// A blob of format version 5 with tables (`tests/data/format-v5/example-nemm-tables.nemm`,
/// written by this crate at format version 5: `example_model_with_branches(4, 2, 4,
/// Priors::PAPER)` with alpha over `[0, 0.3]`, the tables of two table-mode estimators of
/// 64 segments at alpha 0 and 0.3, bound 1e-2): its tables lie unaligned, so level tables
/// refuse it with `Layout`, while a table-mode estimator still reads (copies) them; exported
/// again, the same tables are read in place.
#[test]
fn version_5_tables_are_copied_and_refused_in_place_until_exported_again() {
    const T5: usize = 64;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/format-v5/example-nemm-tables.nemm");
    let v5 = AlignedBlob::new(&std::fs::read(path).unwrap());
    assert_eq!(nemm_core::read_header(&v5).unwrap().version, 5);
    let mut m: Box<Model<P>> = Box::new(Model::empty());
    let tables = decode_into(&v5, &mut m).unwrap();
    assert_eq!(tables.levels.len(), 2);
    let mut l: Box<LevelTables<'_, T5, 4>> = Box::new(LevelTables::empty());
    assert_eq!(l.load(&m, &tables, &v5), Err(LevelsError::Layout));
    let cfg = |alpha| EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1e-2)),
        ..EstimatorConfig::new(alpha)
    };
    let mut ests: Vec<Box<Estimator<P, T5>>> = Vec::new();
    for alpha in [0.0, 0.3] {
        let mut e: Box<Estimator<P, T5>> = Box::new(Estimator::empty());
        e.load_with_tables(&m, cfg(alpha), &tables, &v5).unwrap();
        assert_eq!(e.table_origin(), nemm_core::TableOrigin::Stored, "{alpha}");
        ests.push(e);
    }
    let refs: Vec<&Estimator<P, T5>> = ests.iter().map(|e| &**e).collect();
    let v6 = AlignedBlob::new(&blob_with_tables(&m, &refs).unwrap());
    assert_eq!(
        nemm_core::read_header(&v6).unwrap().version,
        nemm_core::FORMAT_VERSION
    );
    let mut m6: Box<Model<P>> = Box::new(Model::empty());
    let tables6 = decode_into(&v6, &mut m6).unwrap();
    assert_eq!(*m6, *m);
    let mut l6: Box<LevelTables<'_, T5, 4>> = Box::new(LevelTables::empty());
    l6.load(&m6, &tables6, &v6).unwrap();
    assert_eq!(l6.alphas(), &[0.0, 0.3]);
    // The in-place tables are the copied ones: a level's step is the estimator's.
    let mut on_level: Box<Estimator<P, T5>> = Box::new(Estimator::empty());
    on_level.load(&m6, EstimatorConfig::new(0.3)).unwrap();
    on_level.attach_levels(&l6).unwrap();
    for i in 0..2_000 {
        let v = velocity(i, 0.5);
        let a = on_level.step(Sample::new(v).with_alpha(0.3)).unwrap();
        let b = ests[1].step(Sample::new(v)).unwrap();
        assert_eq!(a.force_n.to_bits(), b.force_n.to_bits(), "{i}");
    }
}

/// A blob of format version 6 with tables (`tests/data/format-v6/example-nemm-tables.nemm`,
/// written by this crate at format version 6 from the model and levels of the version-5
/// blob above): it decodes to that model without cumulative scalers, its level tables are
/// read in place, and exported again (the current version) its tables are the same bits.
#[test]
fn version_6_tables_are_read_in_place() {
    const T6: usize = 64;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/format-v6/example-nemm-tables.nemm");
    let v6 = AlignedBlob::new(&std::fs::read(path).unwrap());
    assert_eq!(nemm_core::read_header(&v6).unwrap().version, 6);
    let mut m: Box<Model<P>> = Box::new(Model::empty());
    let tables = decode_into(&v6, &mut m).unwrap();
    assert_eq!(
        *m,
        example_model_with_branches::<P>(4, 2, 4, Priors::PAPER).unwrap()
    );
    assert!(m.cumulative.is_empty());
    let mut l: Box<LevelTables<'_, T6, 4>> = Box::new(LevelTables::empty());
    l.load(&m, &tables, &v6).unwrap();
    assert_eq!(l.alphas(), &[0.0, 0.3]);
    let cfg = EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1e-2)),
        ..EstimatorConfig::new(0.3)
    };
    let mut stored: Box<Estimator<P, T6>> = Box::new(Estimator::empty());
    stored.load_with_tables(&m, cfg, &tables, &v6).unwrap();
    assert_eq!(stored.table_origin(), nemm_core::TableOrigin::Stored);
    let mut built: Box<Estimator<P, T6>> = Box::new(Estimator::empty());
    built.load(&m, cfg).unwrap();
    let again = AlignedBlob::new(&blob_with_tables(&m, &[&*stored]).unwrap());
    assert_eq!(
        nemm_core::read_header(&again).unwrap().version,
        nemm_core::FORMAT_VERSION
    );
    for i in 0..2_000 {
        let v = velocity(i, 0.5);
        let (a, b) = (
            stored.step(Sample::new(v)).unwrap(),
            built.step(Sample::new(v)).unwrap(),
        );
        assert_eq!(a.force_n.to_bits(), b.force_n.to_bits(), "{i}");
    }
}
