//! The C functions called from Rust: every status path, and bit-identity with nemm-core
//! used directly (the firmware's instantiation) over the project's blobs.

use crate::status::{nemm_status_t::*, ALL};
use crate::*;
use nemm_core::{
    decode_into, AlignedBlob, AlphaObserver, Estimator, EstimatorConfig, EvalMode, Model,
    ModelKind, ObserverConfig, Sample, StoredLayout, TableConfig,
};
use std::boxed::Box;
use std::ffi::CStr;
use std::vec::Vec;

type P = Model<NEMM_PARAM_CAPACITY>;
type E = Estimator<'static, NEMM_PARAM_CAPACITY, NEMM_TABLE_SEGMENTS>;

/// The firmware's trained NEMM (its blob stores 128-segment tables at 7 levels, 0 to 0.3).
const TRAINED: &[u8] = include_bytes!("../../nemm-firmware/data/trained-nemm.nemm");
/// The example blobs of each kind.
const EXAMPLES: [(&[u8], u32); 4] = [
    (
        include_bytes!("../../nemm-firmware/data/example-sem.nemm"),
        NEMM_KIND_SEM,
    ),
    (
        include_bytes!("../../nemm-firmware/data/example-linear-emm.nemm"),
        NEMM_KIND_LINEAR_EMM,
    ),
    (
        include_bytes!("../../nemm-firmware/data/example-nemm-light.nemm"),
        NEMM_KIND_NEMM_LIGHT,
    ),
    (
        include_bytes!("../../nemm-firmware/data/example-nemm.nemm"),
        NEMM_KIND_NEMM,
    ),
];

/// Storage at the alignment of the largest target's objects.
#[repr(C, align(16))]
struct Aligned<T>(T);

fn estimator_storage() -> Box<Aligned<nemm_estimator_t>> {
    // SAFETY: all-zero bytes are a valid `u8` array.
    unsafe { Box::new_zeroed().assume_init() }
}

fn observer_storage() -> Box<Aligned<nemm_observer_t>> {
    // SAFETY: as above.
    unsafe { Box::new_zeroed().assume_init() }
}

fn init(st: &mut nemm_estimator_t, blob: &[u8], cfg: &nemm_estimator_config_t) -> nemm_status_t {
    // SAFETY: valid storage, blob and configuration.
    unsafe {
        nemm_estimator_init(
            st,
            core::mem::size_of::<nemm_estimator_t>(),
            blob.as_ptr(),
            blob.len(),
            cfg,
        )
    }
}

/// A C sample of velocity `v` with the position, alpha and force present where given.
fn sample(v: f32, x: Option<f32>, alpha: Option<f32>, f: Option<f32>) -> nemm_sample_t {
    let bit = |o: Option<f32>, b: u8| if o.is_some() { b } else { 0 };
    nemm_sample_t {
        velocity_m_s: v,
        position_m: x.unwrap_or(0.0),
        alpha: alpha.unwrap_or(0.0),
        force_n: f.unwrap_or(0.0),
        fields: bit(x, NEMM_SAMPLE_POSITION)
            | bit(alpha, NEMM_SAMPLE_ALPHA)
            | bit(f, NEMM_SAMPLE_FORCE),
    }
}

/// `nemm_estimator_step` on `s`.
///
/// # Safety
/// `p` an estimator's storage (or NULL), `e` writable (or NULL).
unsafe fn c_step(
    p: *mut nemm_estimator_t,
    s: nemm_sample_t,
    e: *mut nemm_estimate_t,
) -> nemm_status_t {
    // SAFETY: the caller's guarantees; the sample is readable.
    unsafe { nemm_estimator_step(p, &s, e) }
}

/// `nemm_observer_step` on `s`.
///
/// # Safety
/// `p` an observer's storage (or NULL), `a` writable (or NULL).
unsafe fn c_observe(
    p: *mut nemm_observer_t,
    s: nemm_sample_t,
    a: *mut nemm_alpha_estimate_t,
) -> nemm_status_t {
    // SAFETY: the caller's guarantees; the sample is readable.
    unsafe { nemm_observer_step(p, &s, a) }
}

fn step(st: &mut nemm_estimator_t, v: f32) -> (nemm_status_t, nemm_estimate_t) {
    let mut e = nemm_estimate_t::default();
    // SAFETY: valid storage and output.
    let s = unsafe { c_step(st, sample(v, None, None, None), &mut e) };
    (s, e)
}

fn info(st: &nemm_estimator_t) -> nemm_estimator_info_t {
    let mut i = nemm_estimator_info_t::default();
    // SAFETY: valid storage and output.
    assert_eq!(unsafe { nemm_estimator_info(st, &mut i) }, NEMM_OK);
    i
}

fn cfg(alpha: f32, mode: u32) -> nemm_estimator_config_t {
    nemm_estimator_config_t {
        alpha,
        mode,
        ..Default::default()
    }
}

/// A velocity sequence over the model's range with a NaN and an implausible sample.
fn velocities(n: usize) -> Vec<f32> {
    (0..n)
        .map(|k| match k {
            100 => f32::NAN,
            200 => 1e6,
            _ => 0.8 * (k as f32 * 0.0021).sin() + 0.3 * (k as f32 * 0.013).sin(),
        })
        .collect()
}

/// nemm-core's estimator for `blob` as the library builds it (in place, stored tables).
fn reference(blob: &[u8], c: EstimatorConfig) -> (Box<P>, Box<E>) {
    let mut model = Box::new(P::empty());
    let tables = decode_into(blob, &mut model).expect("decodes");
    let mut est = Box::new(E::empty());
    est.load_with_tables(&model, c, &tables, blob)
        .expect("loads");
    (model, est)
}

fn table(bound: f32) -> EvalMode {
    EvalMode::Table(TableConfig::new(bound))
}

#[test]
fn statuses_are_distinct_and_described() {
    for (i, s) in ALL.iter().enumerate() {
        assert!(ALL[..i].iter().all(|o| *o as i32 != *s as i32));
        let text = s.text().to_str().unwrap();
        assert!(
            text.starts_with(&std::format!("{s:?}: ")),
            "{s:?} is described as {text}"
        );
        // SAFETY: a static C string.
        let c = unsafe { CStr::from_ptr(nemm_status_str(*s as i32)) };
        assert_eq!(c, s.text());
    }
    assert_eq!(NEMM_OK as i32, 0);
    for bad in [-1, 7, 9, 63, 80, 1000] {
        // SAFETY: a static C string.
        let c = unsafe { CStr::from_ptr(nemm_status_str(bad)) };
        assert_eq!(c.to_str().unwrap(), "unknown status");
    }
}

#[test]
fn blob_validate_checks_what_decode_checks_in_its_order() {
    let mut i = nemm_blob_info_t::default();
    // SAFETY: valid blob and output.
    let validate =
        |b: &[u8], i: &mut nemm_blob_info_t| unsafe { nemm_blob_validate(b.as_ptr(), b.len(), i) };
    assert_eq!(validate(TRAINED, &mut i), NEMM_OK);
    let version = nemm_core::read_header(TRAINED).unwrap().version;
    assert!(version <= nemm_core::FORMAT_VERSION);
    assert_eq!(
        (i.format_version, i.kind, i.blob_len),
        (version.into(), NEMM_KIND_NEMM, TRAINED.len() as u32)
    );
    assert!(i.max_scaler_params as usize <= NEMM_PARAM_CAPACITY);
    // SAFETY: a NULL info is allowed.
    let s = unsafe { nemm_blob_validate(TRAINED.as_ptr(), TRAINED.len(), core::ptr::null_mut()) };
    assert_eq!(s, NEMM_OK);
    // SAFETY: a NULL blob is refused before it is read.
    let s = unsafe { nemm_blob_validate(core::ptr::null(), 10, &mut i) };
    assert_eq!(s, NEMM_E_NULL);
    let decode_status = |b: &[u8]| match decode_into(b, &mut Box::new(P::empty())) {
        Ok(_) => NEMM_OK,
        Err(e) => e.into(),
    };
    let mut cases: Vec<(Vec<u8>, nemm_status_t)> = std::vec![
        (TRAINED[..TRAINED.len() - 1].to_vec(), NEMM_E_BLOB_TRUNCATED),
        (TRAINED[..3].to_vec(), NEMM_E_BLOB_TRUNCATED),
        ([TRAINED, &[0]].concat(), NEMM_E_BLOB_TRAILING_BYTES),
    ];
    let mut bad_magic = TRAINED.to_vec();
    bad_magic[0] = b'X';
    cases.push((bad_magic, NEMM_E_BLOB_BAD_MAGIC));
    let mut version = TRAINED.to_vec();
    version[4] = 9;
    cases.push((version, NEMM_E_BLOB_UNSUPPORTED_VERSION));
    let mut crc = TRAINED.to_vec();
    crc[100] ^= 1;
    cases.push((crc, NEMM_E_BLOB_CRC_MISMATCH));
    // A model wider than the capacity: H = 32, L = 3.
    let wide: Model<4096> = nemm_core::testing::example_model(ModelKind::Nemm, 32, 3).unwrap();
    let mut buf = std::vec![0u8; 100_000];
    let wide = nemm_core::encode(&wide, &mut buf).unwrap().to_vec();
    cases.push((wide, NEMM_E_BLOB_OVER_CAPACITY));
    for (b, want) in &cases {
        assert_eq!(validate(b, &mut i), *want);
        assert_eq!(decode_status(b), *want, "decode agrees");
        let mut st = estimator_storage();
        assert_eq!(init(&mut st.0, b, &cfg(0.15, NEMM_MODE_EXACT)), *want);
    }
}

#[test]
fn init_refuses_bad_storage_and_settings_and_leaves_nothing_usable() {
    let mut st = estimator_storage();
    let size = core::mem::size_of::<nemm_estimator_t>();
    let c = cfg(0.15, NEMM_MODE_EXACT);
    let p: *mut nemm_estimator_t = &mut st.0;
    // SAFETY: every call below gets valid or NULL pointers and true sizes.
    unsafe {
        let blob = TRAINED.as_ptr();
        let n = TRAINED.len();
        assert_eq!(
            nemm_estimator_init(core::ptr::null_mut(), size, blob, n, &c),
            NEMM_E_NULL
        );
        assert_eq!(
            nemm_estimator_init(p, size, core::ptr::null(), n, &c),
            NEMM_E_NULL
        );
        assert_eq!(
            nemm_estimator_init(p, size, blob, n, core::ptr::null()),
            NEMM_E_NULL
        );
        assert_eq!(
            nemm_estimator_init(p, size - 1, blob, n, &c),
            NEMM_E_STORAGE_SIZE
        );
        let misaligned = p.cast::<u8>().add(1).cast::<nemm_estimator_t>();
        assert_eq!(
            nemm_estimator_init(misaligned, size - 1, blob, n, &c),
            NEMM_E_STORAGE_ALIGN
        );
        assert_eq!(
            nemm_estimator_init(p, size, blob, usize::MAX, &c),
            NEMM_E_INVALID_ARGUMENT
        );
        // (The first bytes of) the blob inside the storage.
        let inner = p.cast::<u8>().add(64);
        let part = n.min(size - 64);
        core::ptr::copy_nonoverlapping(blob, inner, part);
        assert_eq!(
            nemm_estimator_init(p, size, inner, part, &c),
            NEMM_E_OVERLAP
        );
    }
    // Never initialised.
    assert_eq!(step(&mut st.0, 0.1).0, NEMM_E_NOT_INITIALISED);
    let mut bad = c;
    bad.mode = 2;
    assert_eq!(init(&mut st.0, TRAINED, &bad), NEMM_E_INVALID_ARGUMENT);
    for (alpha, want) in [
        (1.5, NEMM_E_ALPHA_OUT_OF_RANGE),
        (-0.1, NEMM_E_ALPHA_OUT_OF_RANGE),
        (f32::NAN, NEMM_E_ALPHA_OUT_OF_RANGE),
    ] {
        assert_eq!(init(&mut st.0, TRAINED, &cfg(alpha, NEMM_MODE_EXACT)), want);
    }
    let mut limit = c;
    limit.velocity_limit_m_s = -1.0;
    assert_eq!(init(&mut st.0, TRAINED, &limit), NEMM_E_BAD_VELOCITY_LIMIT);
    let mut bound = cfg(0.15, NEMM_MODE_TABLE);
    bound.table_max_rel_error = f32::NAN;
    assert_eq!(init(&mut st.0, TRAINED, &bound), NEMM_E_TABLE_BAD_CONFIG);
    bound.table_max_rel_error = 1e-12;
    assert_eq!(init(&mut st.0, TRAINED, &bound), NEMM_E_TABLE_EXCEEDS_BOUND);
    // A good init, then a failed one: the storage is no estimator any more.
    assert_eq!(init(&mut st.0, TRAINED, &c), NEMM_OK);
    assert_eq!(step(&mut st.0, 0.1).0, NEMM_OK);
    assert_eq!(init(&mut st.0, &TRAINED[..50], &c), NEMM_E_BLOB_TRUNCATED);
    assert_eq!(step(&mut st.0, 0.1).0, NEMM_E_NOT_INITIALISED);
    // SAFETY: NULL arguments are refused before use.
    unsafe {
        let mut e = nemm_estimate_t::default();
        assert_eq!(
            c_step(core::ptr::null_mut(), sample(0.0, None, None, None), &mut e),
            NEMM_E_NULL
        );
        assert_eq!(init(&mut st.0, TRAINED, &c), NEMM_OK);
        assert_eq!(
            c_step(
                &mut st.0,
                sample(0.0, None, None, None),
                core::ptr::null_mut()
            ),
            NEMM_E_NULL
        );
        assert_eq!(
            nemm_estimator_step(&mut st.0, core::ptr::null(), &mut e),
            NEMM_E_NULL
        );
        // Bits other than the NEMM_SAMPLE_* ones: refused.
        let mut odd = sample(0.0, None, None, None);
        odd.fields = 1 << 5;
        assert_eq!(c_step(&mut st.0, odd, &mut e), NEMM_E_INVALID_ARGUMENT);
        assert_eq!(
            nemm_estimator_info(&st.0, core::ptr::null_mut()),
            NEMM_E_NULL
        );
        assert_eq!(nemm_estimator_reset(core::ptr::null_mut()), NEMM_E_NULL);
        assert_eq!(
            nemm_estimator_set_alpha(core::ptr::null_mut(), 0.1),
            NEMM_E_NULL
        );
    }
}

#[test]
fn forces_are_bit_identical_to_nemm_core() {
    let vs = velocities(3000);
    let mut runs: Vec<(&[u8], u32, EvalMode, u32)> = Vec::new();
    for (blob, kind) in EXAMPLES {
        runs.push((blob, kind, EvalMode::Exact, NEMM_MODE_EXACT));
    }
    runs.push((TRAINED, NEMM_KIND_NEMM, EvalMode::Exact, NEMM_MODE_EXACT));
    runs.push((
        TRAINED,
        NEMM_KIND_NEMM,
        table(NEMM_TABLE_MAX_REL_ERROR),
        NEMM_MODE_TABLE,
    ));
    for (blob, kind, mode, c_mode) in runs {
        let (_, mut want) = reference(
            blob,
            EstimatorConfig {
                mode,
                ..EstimatorConfig::new(0.15)
            },
        );
        let mut st = estimator_storage();
        assert_eq!(init(&mut st.0, blob, &cfg(0.15, c_mode)), NEMM_OK);
        let i = info(&st.0);
        assert_eq!((i.kind, i.mode, i.alpha), (kind, c_mode, 0.15));
        assert_eq!(i.needs_position, 0);
        if c_mode == NEMM_MODE_TABLE {
            assert_eq!(
                i.table_origin, NEMM_TABLES_STORED,
                "the trained blob stores tables"
            );
            assert!(i.table_bytes > 0);
        }
        for &v in &vs {
            let (s, e) = step(&mut st.0, v);
            let w = want.step(Sample::new(v)).unwrap();
            assert_eq!(s, NEMM_OK);
            assert_eq!(
                (e.force_n.to_bits(), e.flags),
                (w.force_n.to_bits(), w.flags.0)
            );
        }
        let i = info(&st.0);
        let d = want.diagnostics();
        assert_eq!(
            (i.steps, i.held_samples, i.resets),
            (d.steps, d.held_samples, d.resets)
        );
        assert_eq!(i.held_samples, 2, "the NaN and the implausible sample");
    }
}

#[test]
fn alpha_changes_and_reset_follow_nemm_core() {
    let (_, mut want) = reference(TRAINED, EstimatorConfig::new(0.1));
    let mut st = estimator_storage();
    assert_eq!(
        init(&mut st.0, TRAINED, &cfg(0.1, NEMM_MODE_EXACT)),
        NEMM_OK
    );
    let p: *mut nemm_estimator_t = &mut st.0;
    for (k, &v) in velocities(600).iter().enumerate() {
        let alpha = 0.1 + 0.0005 * k as f32;
        let mut e = nemm_estimate_t::default();
        // SAFETY: valid storage and output.
        let s = unsafe {
            match k % 3 {
                0 => c_step(p, sample(v, None, Some(alpha), None), &mut e),
                1 => c_step(p, sample(v, Some(0.01), Some(alpha), None), &mut e),
                _ => c_step(p, sample(v, Some(0.01), None, Some(1.0)), &mut e),
            }
        };
        let w = match k % 3 {
            0 => want.step(Sample::new(v).with_alpha(alpha)),
            1 => want.step(Sample::new(v).with_alpha(alpha).with_position(0.01)),
            _ => want.step(Sample::new(v).with_position(0.01)),
        }
        .unwrap();
        assert_eq!(s, NEMM_OK);
        assert_eq!(
            (e.force_n.to_bits(), e.flags),
            (w.force_n.to_bits(), w.flags.0)
        );
        if k == 300 {
            // SAFETY: valid storage.
            assert_eq!(unsafe { nemm_estimator_reset(p) }, NEMM_OK);
            want.reset();
            // SAFETY: valid storage.
            assert_eq!(unsafe { nemm_estimator_set_alpha(p, 0.2) }, NEMM_OK);
            want.set_alpha(0.2).unwrap();
        }
    }
    let mut e = nemm_estimate_t {
        force_n: 7.0,
        flags: 9,
    };
    // SAFETY: valid storage and output.
    unsafe {
        assert_eq!(nemm_estimator_set_alpha(p, 2.0), NEMM_E_ALPHA_OUT_OF_RANGE);
        assert_eq!(
            c_step(p, sample(0.1, None, Some(f32::NAN), None), &mut e),
            NEMM_E_ALPHA_OUT_OF_RANGE
        );
    }
    assert_eq!(
        (e.force_n, e.flags),
        (7.0, 9),
        "nothing written after an error"
    );
    // Table mode refuses a changing per-sample alpha, steps an unchanged one.
    let mut tab = estimator_storage();
    assert_eq!(
        init(&mut tab.0, TRAINED, &cfg(0.15, NEMM_MODE_TABLE)),
        NEMM_OK
    );
    // SAFETY: valid storage and output.
    unsafe {
        assert_eq!(
            c_step(&mut tab.0, sample(0.1, None, Some(0.2), None), &mut e),
            NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE
        );
        assert_eq!(
            c_step(&mut tab.0, sample(0.1, None, Some(0.15), None), &mut e),
            NEMM_OK
        );
    }
}

#[test]
fn a_static_force_needs_the_position() {
    let mut model: Model<NEMM_PARAM_CAPACITY> =
        nemm_core::testing::example_model(ModelKind::Nemm, 16, 5).unwrap();
    model.static_force = Some(nemm_core::testing::EXAMPLE_STATIC_FORCE);
    let mut buf = std::vec![0u8; 100_000];
    let blob = nemm_core::encode(&model, &mut buf).unwrap().to_vec();
    let mut want = Box::new(E::empty());
    want.load(&model, EstimatorConfig::new(0.15)).unwrap();
    let mut st = estimator_storage();
    assert_eq!(init(&mut st.0, &blob, &cfg(0.15, NEMM_MODE_EXACT)), NEMM_OK);
    assert_eq!(info(&st.0).needs_position, 1);
    let (s, e) = step(&mut st.0, 0.1);
    assert_eq!(
        (s, e.flags & NEMM_FLAG_POSITION_MISSING),
        (NEMM_OK, NEMM_FLAG_POSITION_MISSING)
    );
    want.step(Sample::new(0.1)).unwrap();
    for (k, &v) in velocities(300).iter().enumerate() {
        let x = 0.03 + 0.01 * (k as f32 * 0.01).sin();
        let mut e = nemm_estimate_t::default();
        // SAFETY: valid storage and output.
        let s = unsafe { c_step(&mut st.0, sample(v, Some(x), None, None), &mut e) };
        let w = want.step(Sample::new(v).with_position(x)).unwrap();
        assert_eq!(s, NEMM_OK);
        assert_eq!(
            (e.force_n.to_bits(), e.flags),
            (w.force_n.to_bits(), w.flags.0)
        );
    }
}

/// The C estimator on `blob` at level `alpha` steps as nemm-core's estimator does, bit for
/// bit (force and flags), in exact and table mode, over 300 velocities.
fn runs_as_the_estimator(blob: &[u8], alpha: f32) {
    for mode in [NEMM_MODE_EXACT, NEMM_MODE_TABLE] {
        let core_cfg = EstimatorConfig {
            mode: if mode == NEMM_MODE_TABLE {
                table(NEMM_TABLE_MAX_REL_ERROR)
            } else {
                EvalMode::Exact
            },
            ..EstimatorConfig::new(alpha)
        };
        let (_, mut want) = reference(blob, core_cfg);
        let mut st = estimator_storage();
        assert_eq!(init(&mut st.0, blob, &cfg(alpha, mode)), NEMM_OK);
        for &v in velocities(300).iter() {
            let (s, e) = step(&mut st.0, v);
            let w = want.step(Sample::new(v)).unwrap();
            assert_eq!(s, NEMM_OK);
            assert_eq!(
                (e.force_n.to_bits(), e.flags),
                (w.force_n.to_bits(), w.flags.0),
                "mode {mode}"
            );
        }
    }
}

/// A model with the lost-motion element runs through the C interface as nemm-core's
/// estimator does, bit for bit, in exact and table mode; on the SEM the element is refused
/// with its own status.
#[test]
fn a_lost_motion_model_runs_as_the_estimator() {
    let mut model: Model<NEMM_PARAM_CAPACITY> =
        nemm_core::testing::example_model(ModelKind::Nemm, 16, 5).unwrap();
    model.lost_motion = Some(nemm_core::testing::EXAMPLE_LOST_MOTION);
    let mut buf = std::vec![0u8; 100_000];
    let blob = nemm_core::encode(&model, &mut buf).unwrap().to_vec();
    runs_as_the_estimator(&blob, 0.3);
    let mut sem: Model<NEMM_PARAM_CAPACITY> =
        nemm_core::testing::example_model(ModelKind::Sem, 16, 5).unwrap();
    sem.lost_motion = Some(nemm_core::testing::EXAMPLE_LOST_MOTION);
    assert_eq!(
        nemm_status_t::from(sem.validate().unwrap_err()),
        NEMM_E_MODEL_LOST_MOTION_ON_SEM
    );
}

/// A model with cumulative scalers (`b_fl` and `k_pr`) runs through the C interface as
/// nemm-core's estimator does, bit for bit, in exact and table mode; a misused cumulative
/// scaler is refused with its own status.
#[test]
fn a_cumulative_model_runs_as_the_estimator() {
    let model = Box::new(nemm_core::testing::example_cumulative_model(
        ModelKind::Nemm,
    ));
    let mut buf = std::vec![0u8; 100_000];
    let blob = nemm_core::encode(&*model, &mut buf).unwrap().to_vec();
    runs_as_the_estimator(&blob, 0.15);
    let mut bad = model.clone();
    bad.alpha_branches.b_fl =
        nemm_core::testing::example_branch(nemm_core::Direction::Decreasing, 1, 4, 1);
    assert_eq!(
        nemm_status_t::from(bad.validate().unwrap_err()),
        NEMM_E_MODEL_CUMULATIVE
    );
}

fn observer_init(
    obs: &mut nemm_observer_t,
    est: &nemm_estimator_t,
    c: Option<&nemm_observer_config_t>,
) -> nemm_status_t {
    // SAFETY: valid storages and configuration (or NULL).
    unsafe {
        nemm_observer_init(
            obs,
            core::mem::size_of::<nemm_observer_t>(),
            est,
            c.map_or(core::ptr::null(), |c| c as *const _),
        )
    }
}

#[test]
fn the_observer_follows_nemm_core_and_checks_its_settings() {
    let mut st = estimator_storage();
    assert_eq!(
        init(&mut st.0, TRAINED, &cfg(0.15, NEMM_MODE_TABLE)),
        NEMM_OK
    );
    let mut obs = observer_storage();
    let mut c = nemm_observer_config_t::default_values();
    // SAFETY: valid output.
    assert_eq!(unsafe { nemm_observer_config_default(&mut c) }, NEMM_OK);
    assert_eq!(c.to_core(), ObserverConfig::new());
    assert_eq!(observer_init(&mut obs.0, &st.0, Some(&c)), NEMM_OK);
    let mut model = Box::new(P::empty());
    decode_into(TRAINED, &mut model).unwrap();
    let mut want: Box<AlphaObserver<NEMM_PARAM_CAPACITY, NEMM_OBSERVER_MAX_POINTS>> =
        Box::new(AlphaObserver::empty());
    want.load(&model, ObserverConfig::new()).unwrap();
    // The measured force: the estimator's own at alpha 0.15.
    let mut last = nemm_alpha_estimate_t::default();
    for &v in &velocities(15_000) {
        let (_, f) = step(&mut st.0, v);
        let mut a = nemm_alpha_estimate_t::default();
        // SAFETY: valid storage and output.
        let s = unsafe { c_observe(&mut obs.0, sample(v, None, None, Some(f.force_n)), &mut a) };
        let w = want.step(Sample::new(v).with_force(f.force_n));
        assert_eq!(s, NEMM_OK);
        assert_eq!(
            (
                a.alpha.to_bits(),
                a.band.to_bits(),
                a.force_n.to_bits(),
                a.flags
            ),
            (
                w.alpha.to_bits(),
                w.band.to_bits(),
                w.force_n.to_bits(),
                w.flags.0
            )
        );
        last = a;
    }
    // Solved from the data, not the reset estimate (the middle of the grid, 0.15 too).
    assert!(want.solves() > 0);
    assert!((last.alpha - 0.15).abs() < 0.01, "alpha {}", last.alpha);
    let mut now = nemm_alpha_estimate_t::default();
    // SAFETY: valid storage and output.
    unsafe {
        assert_eq!(nemm_observer_estimate(&obs.0, &mut now), NEMM_OK);
        assert_eq!(now, last);
        assert_eq!(nemm_observer_reset(&mut obs.0), NEMM_OK);
        assert_eq!(nemm_observer_estimate(&obs.0, &mut now), NEMM_OK);
    }
    assert_ne!(now.flags & NEMM_OBSERVER_NOT_EXCITED, 0);
    assert_ne!(now.flags & NEMM_OBSERVER_NOT_SETTLED, 0);
    // Defaults with a NULL configuration.
    assert_eq!(observer_init(&mut obs.0, &st.0, None), NEMM_OK);
    for (edit, want) in [
        (
            (|c: &mut nemm_observer_config_t| c.points = 1) as fn(&mut nemm_observer_config_t),
            NEMM_E_OBSERVER_POINTS,
        ),
        (|c| c.points = 8, NEMM_E_OBSERVER_POINTS),
        (
            |c| {
                c.grid_lo = 0.3;
                c.grid_hi = 0.1;
            },
            NEMM_E_OBSERVER_GRID,
        ),
        (|c| c.horizon_s = -1.0, NEMM_E_OBSERVER_SETTING),
        (|c| c.settle_tolerance = 0.0, NEMM_E_OBSERVER_SETTING),
        (|c| c.crossing_hysteresis = 1.5, NEMM_E_OBSERVER_SETTING),
        (|c| c.velocity_limit_m_s = -1.0, NEMM_E_BAD_VELOCITY_LIMIT),
    ] {
        let mut bad = c;
        edit(&mut bad);
        assert_eq!(observer_init(&mut obs.0, &st.0, Some(&bad)), want);
        let mut a = nemm_alpha_estimate_t::default();
        // SAFETY: valid storage and output.
        let s = unsafe { c_observe(&mut obs.0, sample(0.1, None, None, Some(10.0)), &mut a) };
        assert_eq!(
            s, NEMM_E_NOT_INITIALISED,
            "a failed init leaves no observer"
        );
    }
    // An uninitialised estimator, overlapping storages.
    let fresh = estimator_storage();
    assert_eq!(
        observer_init(&mut obs.0, &fresh.0, None),
        NEMM_E_NOT_INITIALISED
    );
    let est: *mut nemm_estimator_t = &mut st.0;
    // SAFETY: the observer's storage would lie inside the estimator's: refused before use.
    let s = unsafe {
        nemm_observer_init(
            est.cast::<u8>().add(16).cast(),
            NEMM_OBSERVER_SIZE,
            est,
            core::ptr::null(),
        )
    };
    assert_eq!(s, NEMM_E_OVERLAP);
    assert_eq!(
        step(&mut st.0, 0.1).0,
        NEMM_OK,
        "the estimator is untouched"
    );
}

type Levels = nemm_core::LevelTables<'static, NEMM_TABLE_SEGMENTS, NEMM_LEVELS_CAPACITY>;

/// The levels of the trained blob.
const TRAINED_LEVELS: [f32; 7] = [0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3];

/// Bytes a stored table takes in the blob, where level tables read it in place.
const TABLE_IMAGE_BYTES: usize = 32 + 28 * NEMM_TABLE_SEGMENTS;

/// A 4-byte-aligned copy of `blob` that lives for the rest of the test run, as level
/// tables need it (they read the blob in place).
fn aligned(blob: &[u8]) -> &'static [u8] {
    let b: &'static AlignedBlob = Box::leak(Box::new(AlignedBlob::new(blob)));
    b
}

/// `blob` (its model and stored levels of `NEMM_TABLE_SEGMENTS` segments, the tables bit
/// for bit) exported again at this build's format version.
fn exported_again(blob: &[u8]) -> Vec<u8> {
    let mut model = Box::new(P::empty());
    let index = decode_into(blob, &mut model).expect("decodes");
    let ests: Vec<Box<E>> = index
        .levels
        .iter()
        .filter(|l| l.segments as usize == NEMM_TABLE_SEGMENTS)
        .map(|l| {
            let mut e = Box::new(E::empty());
            let c = EstimatorConfig {
                mode: EvalMode::Table(l.config),
                ..EstimatorConfig::new(l.alpha)
            };
            e.load_with_tables(&model, c, &index, blob)
                .expect("the stored tables load");
            assert_eq!(e.table_origin(), nemm_core::TableOrigin::Stored);
            e
        })
        .collect();
    let refs: Vec<&E> = ests.iter().map(|e| &**e).collect();
    let mut buf = std::vec![0u8; 400_000];
    nemm_core::encode_with_tables(&model, &refs, &mut buf)
        .expect("encodes")
        .to_vec()
}

/// The firmware's trained blob with its 7 levels of tables, held 4-byte aligned for the
/// test run (`include_bytes!` gives no alignment).
fn trained() -> &'static [u8] {
    static BLOB: std::sync::OnceLock<&'static [u8]> = std::sync::OnceLock::new();
    BLOB.get_or_init(|| aligned(TRAINED))
}

/// `blob` (format version 6, with tables) written in the layout of format version 5: the
/// same header fields, body prefix and tables, the tables section as version 5 stored it
/// (varints, presence bytes, each table's scalars, accuracy and segments without its lookup
/// cells; `nemm_core::format::tables`), for the refusal of such blobs by level tables.
fn as_version_5(blob: &[u8]) -> Vec<u8> {
    let mut model = Box::new(P::empty());
    let index = decode_into(blob, &mut model).expect("decodes");
    let mut header = nemm_core::read_header(blob).unwrap();
    assert_eq!(header.version, 6);
    let mut buf = std::vec![0u8; 100_000];
    let hlen = postcard::to_slice(&header, &mut buf).unwrap().len();
    // The body up to the tables section, as the encoder writes it.
    let mut body = Vec::new();
    body.extend_from_slice(postcard::to_slice(&*model, &mut buf).unwrap());
    let v3 = (&model.condition, &model.alpha_branches, &model.provenance);
    body.extend_from_slice(postcard::to_slice(&v3, &mut buf).unwrap());
    body.extend_from_slice(postcard::to_slice(&model.static_force, &mut buf).unwrap());
    body.extend_from_slice(postcard::to_slice(&model.lost_motion, &mut buf).unwrap());
    assert_eq!(
        &blob[hlen..hlen + body.len()],
        &body[..],
        "the body's prefix"
    );
    let n = u32::try_from(index.levels.len()).unwrap();
    body.extend_from_slice(postcard::to_slice(&n, &mut buf).unwrap());
    let f32_at = |at: usize| f32::from_le_bytes(blob[at..at + 4].try_into().unwrap());
    let u32_at = |at: usize| u32::from_le_bytes(blob[at..at + 4].try_into().unwrap());
    for level in &index.levels {
        let c = &level.config;
        let head = (
            level.alpha,
            level.segments,
            c.max_rel_error,
            c.domain_margin,
        );
        body.extend_from_slice(postcard::to_slice(&head, &mut buf).unwrap());
        for table in [level.b_fl, level.k_pr] {
            let Some(t) = table else {
                body.push(0);
                continue;
            };
            assert_eq!(t.layout, StoredLayout::Image);
            body.push(1);
            // The image: 4 scalars, 2 T cells (u16), T segments of 6 f32, the accuracy.
            let (at, segs) = (t.offset as usize, level.segments as usize);
            let seg_at = at + 16 + 4 * segs;
            let acc_at = seg_at + 24 * segs;
            for k in 0..4 {
                body.extend_from_slice(&blob[at + 4 * k..at + 4 * k + 4]);
            }
            let acc = (f32_at(acc_at), f32_at(acc_at + 4));
            let counts = (u32_at(acc_at + 8), u32_at(acc_at + 12));
            body.extend_from_slice(postcard::to_slice(&acc, &mut buf).unwrap());
            body.extend_from_slice(postcard::to_slice(&counts, &mut buf).unwrap());
            body.extend_from_slice(&blob[seg_at..acc_at]);
        }
    }
    header.version = 5;
    header.body_len = u32::try_from(body.len()).unwrap();
    let mut v5 = postcard::to_slice(&header, &mut buf).unwrap().to_vec();
    v5.extend_from_slice(&body);
    let crc = nemm_core::CRC.checksum(&v5);
    v5.extend_from_slice(&crc.to_le_bytes());
    v5
}

fn levels_storage() -> Box<Aligned<nemm_levels_t>> {
    // SAFETY: all-zero bytes are a valid `u8` array.
    unsafe { Box::new_zeroed().assume_init() }
}

/// `nemm_levels_init` from `blob`, which the level tables read in place: where the init
/// succeeds, the blob is one that lives for the test run ([`aligned`]).
fn levels_init(lv: &mut nemm_levels_t, est: &nemm_estimator_t, blob: &[u8]) -> nemm_status_t {
    // SAFETY: valid storages and blob; a blob the level tables keep lives for the run.
    unsafe {
        nemm_levels_init(
            lv,
            core::mem::size_of::<nemm_levels_t>(),
            est,
            blob.as_ptr(),
            blob.len(),
        )
    }
}

fn levels_info(lv: &nemm_levels_t) -> nemm_levels_info_t {
    let mut i = nemm_levels_info_t::default();
    // SAFETY: valid storage and output.
    assert_eq!(unsafe { nemm_levels_info(lv, &mut i) }, NEMM_OK);
    i
}

/// nemm-core's level tables of `blob` as the library loads them.
fn reference_levels(blob: &'static [u8]) -> (Box<P>, Box<Levels>) {
    let mut model = Box::new(P::empty());
    let tables = decode_into(blob, &mut model).expect("decodes");
    let mut levels = Box::new(Levels::empty());
    levels.load(&model, &tables, blob).expect("levels load");
    (model, levels)
}

/// An estimator of `blob` (exact mode) in C storage.
fn c_estimator(blob: &[u8], alpha: f32) -> Box<Aligned<nemm_estimator_t>> {
    let mut st = estimator_storage();
    assert_eq!(init(&mut st.0, blob, &cfg(alpha, NEMM_MODE_EXACT)), NEMM_OK);
    st
}

/// The blob of the example NEMM with 128-segment tables at `alphas`, 4-byte aligned for the
/// test run.
fn example_blob_with_levels(alphas: &[f32]) -> &'static [u8] {
    let model: Box<P> =
        Box::new(nemm_core::testing::example_model(ModelKind::Nemm, 16, 5).unwrap());
    let ests: Vec<Box<E>> = alphas
        .iter()
        .map(|&a| {
            let mut e = Box::new(E::empty());
            e.load(
                &model,
                EstimatorConfig {
                    mode: table(NEMM_TABLE_MAX_REL_ERROR),
                    ..EstimatorConfig::new(a)
                },
            )
            .expect("tables within the bound");
            e
        })
        .collect();
    let refs: Vec<&E> = ests.iter().map(|e| &**e).collect();
    let mut buf = std::vec![0u8; 400_000];
    aligned(nemm_core::encode_with_tables(&model, &refs, &mut buf).expect("encodes"))
}

#[test]
fn level_tables_load_from_the_estimators_blob_and_step_as_nemm_core() {
    let mut st = estimator_storage();
    assert_eq!(
        init(&mut st.0, trained(), &cfg(0.15, NEMM_MODE_TABLE)),
        NEMM_OK
    );
    let mut lv = levels_storage();
    assert_eq!(levels_init(&mut lv.0, &st.0, trained()), NEMM_OK);
    let i = levels_info(&lv.0);
    assert_eq!(i.levels, 7);
    assert_eq!(&i.alpha[..7], &TRAINED_LEVELS);
    assert_eq!(i.alpha[7], 0.0);
    // The tables' bytes in the blob, where they are read; the level tables' RAM is a few
    // hundred bytes: their storage holds them and its mark, nothing else.
    assert_eq!(i.table_bytes as usize, 14 * TABLE_IMAGE_BYTES);
    assert!(core::mem::size_of::<Levels>() < 1024);
    assert!(core::mem::size_of::<Levels>() < NEMM_LEVELS_SIZE);
    assert!(
        core::mem::size_of::<nemm_levels_t>() < 1024,
        "the storage holds the level tables only"
    );
    assert_eq!(i.table_max_rel_error, NEMM_TABLE_MAX_REL_ERROR);
    let (model, levels) = reference_levels(trained());
    let mut want: Box<Estimator<'_, NEMM_PARAM_CAPACITY, NEMM_TABLE_SEGMENTS>> =
        Box::new(Estimator::empty());
    want.load(&model, EstimatorConfig::new(0.15)).unwrap();
    // SAFETY: valid storage.
    assert_eq!(unsafe { nemm_estimator_reset(&mut st.0) }, NEMM_OK);
    want.attach_levels(&levels).unwrap();
    let p: *mut nemm_estimator_t = &mut st.0;
    // SAFETY: valid storages; `lv` outlives every step of `st` below.
    assert_eq!(unsafe { nemm_estimator_attach_levels(p, &lv.0) }, NEMM_OK);
    for (k, &v) in velocities(3000).iter().enumerate() {
        // A level per sample, across and beyond the stored levels.
        let alpha = 0.35 * (k as f32 * 0.003).sin().abs();
        let x = 0.01 * (k as f32 * 0.002).sin();
        let mut e = nemm_estimate_t::default();
        let position = (k % 2 == 1).then_some(x);
        // SAFETY: valid storages and output.
        let s = unsafe { c_step(p, sample(v, position, Some(alpha), None), &mut e) };
        let mut w_sample = Sample::new(v).with_alpha(alpha);
        w_sample.position_m = position;
        let w = want.step(w_sample).unwrap();
        assert_eq!(s, NEMM_OK);
        assert_eq!(
            (e.force_n.to_bits(), e.flags),
            (w.force_n.to_bits(), w.flags.0),
            "sample {k}"
        );
    }
    // Refused with nothing written: alpha outside [0, 1], uninitialised level tables.
    let mut e = nemm_estimate_t {
        force_n: 7.0,
        flags: 9,
    };
    let fresh = levels_storage();
    // SAFETY: valid storages and output; NULLs are refused before use.
    unsafe {
        for a in [f32::NAN, -0.1, 1.5] {
            assert_eq!(
                c_step(p, sample(0.1, None, Some(a), None), &mut e),
                NEMM_E_ALPHA_OUT_OF_RANGE
            );
        }
        assert_eq!(
            c_step(p, sample(0.1, None, Some(0.1), None), core::ptr::null_mut()),
            NEMM_E_NULL
        );
        assert_eq!(
            nemm_estimator_attach_levels(p, &fresh.0),
            NEMM_E_NOT_INITIALISED
        );
        // The level tables inside the estimator's storage.
        assert_eq!(
            nemm_estimator_attach_levels(p, p.cast::<u8>().add(64).cast()),
            NEMM_E_OVERLAP
        );
    }
    assert_eq!((e.force_n, e.flags), (7.0, 9), "nothing written");
    // Refused attachments keep the attached tables; NULL detaches them: a changed alpha is
    // then applied to the estimator's own tables, which table mode refuses.
    // SAFETY: valid storages and output.
    unsafe {
        assert_eq!(
            c_step(p, sample(0.1, None, Some(0.1), None), &mut e),
            NEMM_OK
        );
        assert_eq!(nemm_estimator_attach_levels(p, core::ptr::null()), NEMM_OK);
        assert_eq!(
            c_step(p, sample(0.1, None, Some(0.1), None), &mut e),
            NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE
        );
    }
    // Level tables of another model: refused.
    let mut light = c_estimator(EXAMPLES[2].0, 0.15);
    // SAFETY: valid storages.
    let s = unsafe { nemm_estimator_attach_levels(&mut light.0, &lv.0) };
    assert_eq!(s, NEMM_E_LEVELS_MISMATCH);
}

#[test]
fn level_tables_refuse_other_blobs_and_bad_storage() {
    let on_trained = c_estimator(trained(), 0.15);
    let mut lv = levels_storage();
    // A blob without level tables, a model without neural coefficients.
    let example = c_estimator(EXAMPLES[3].0, 0.15);
    assert_eq!(
        levels_init(&mut lv.0, &example.0, EXAMPLES[3].0),
        NEMM_E_LEVELS_TOO_FEW
    );
    let sem = c_estimator(EXAMPLES[0].0, 0.15);
    assert_eq!(
        levels_init(&mut lv.0, &sem.0, EXAMPLES[0].0),
        NEMM_E_LEVELS_NO_NEURAL_COEFFICIENT
    );
    // Not the estimator's blob, either way round.
    assert_eq!(
        levels_init(&mut lv.0, &on_trained.0, EXAMPLES[3].0),
        NEMM_E_LEVELS_OTHER_BLOB
    );
    assert_eq!(
        levels_init(&mut lv.0, &example.0, trained()),
        NEMM_E_LEVELS_OTHER_BLOB
    );
    // A good init, then a failed one: no level tables any more.
    assert_eq!(levels_init(&mut lv.0, &on_trained.0, trained()), NEMM_OK);
    let mut corrupt = trained().to_vec();
    corrupt[1000] ^= 1;
    assert_eq!(
        levels_init(&mut lv.0, &on_trained.0, &corrupt),
        NEMM_E_BLOB_CRC_MISMATCH
    );
    let mut i = nemm_levels_info_t::default();
    // SAFETY: valid storage and output.
    let s = unsafe { nemm_levels_info(&lv.0, &mut i) };
    assert_eq!(s, NEMM_E_NOT_INITIALISED);
    // More levels than the capacity.
    let nine: Vec<f32> = (0..9).map(|k| 0.05 * k as f32).collect();
    let blob = example_blob_with_levels(&nine);
    let many = c_estimator(blob, 0.15);
    assert_eq!(
        levels_init(&mut lv.0, &many.0, blob),
        NEMM_E_LEVELS_TOO_MANY
    );
    // Storage, pointers, an uninitialised estimator.
    let size = core::mem::size_of::<nemm_levels_t>();
    let p: *mut nemm_levels_t = &mut lv.0;
    let (b, n) = (trained().as_ptr(), trained().len());
    // SAFETY: valid or NULL pointers, true sizes; refused before anything is read beyond
    // them.
    unsafe {
        assert_eq!(
            nemm_levels_init(core::ptr::null_mut(), size, &on_trained.0, b, n),
            NEMM_E_NULL
        );
        assert_eq!(
            nemm_levels_init(p, size, core::ptr::null(), b, n),
            NEMM_E_NULL
        );
        assert_eq!(
            nemm_levels_init(p, size, &on_trained.0, core::ptr::null(), n),
            NEMM_E_NULL
        );
        assert_eq!(
            nemm_levels_init(p, size - 1, &on_trained.0, b, n),
            NEMM_E_STORAGE_SIZE
        );
        assert_eq!(
            nemm_levels_init(p.cast::<u8>().add(1).cast(), size - 1, &on_trained.0, b, n),
            NEMM_E_STORAGE_ALIGN
        );
        assert_eq!(
            nemm_levels_init(p, size, &on_trained.0, b, usize::MAX),
            NEMM_E_INVALID_ARGUMENT
        );
        let fresh = estimator_storage();
        assert_eq!(
            nemm_levels_init(p, size, &fresh.0, b, n),
            NEMM_E_NOT_INITIALISED
        );
        // The blob inside the storage; the estimator inside the storage.
        let inner = p.cast::<u8>().add(64);
        let part = n.min(size - 64);
        core::ptr::copy_nonoverlapping(b, inner, part);
        assert_eq!(
            nemm_levels_init(p, size, &on_trained.0, inner, part),
            NEMM_E_OVERLAP
        );
        let est_inside = p.cast::<u8>().add(64).cast::<nemm_estimator_t>();
        assert_eq!(
            nemm_levels_init(p, size, est_inside, b, n),
            NEMM_E_NOT_INITIALISED,
            "no estimator there"
        );
        assert_eq!(nemm_levels_info(p, core::ptr::null_mut()), NEMM_E_NULL);
    }
}

/// The level tables are loaded from the index of the blob's tables that the estimator's
/// latest init kept (the blob is not decoded again): after an init from another blob, that
/// blob's levels; after a failed init, none.
#[test]
fn level_tables_use_the_tables_index_of_the_estimators_latest_init() {
    let other = example_blob_with_levels(&[0.0, 0.1, 0.2]);
    let mut st = c_estimator(trained(), 0.15);
    let mut lv = levels_storage();
    assert_eq!(levels_init(&mut lv.0, &st.0, trained()), NEMM_OK);
    assert_eq!(levels_info(&lv.0).levels, 7);
    let c = cfg(0.1, NEMM_MODE_EXACT);
    assert_eq!(init(&mut st.0, other, &c), NEMM_OK);
    assert_eq!(
        levels_init(&mut lv.0, &st.0, trained()),
        NEMM_E_LEVELS_OTHER_BLOB
    );
    assert_eq!(levels_init(&mut lv.0, &st.0, other), NEMM_OK);
    let i = levels_info(&lv.0);
    assert_eq!(i.levels, 3);
    assert_eq!(&i.alpha[..3], &[0.0, 0.1, 0.2]);
    assert_eq!(init(&mut st.0, trained(), &c), NEMM_OK);
    assert_eq!(levels_init(&mut lv.0, &st.0, trained()), NEMM_OK);
    assert_eq!(levels_info(&lv.0).levels, 7);
    let mut corrupt = trained().to_vec();
    corrupt[1000] ^= 1;
    assert_eq!(init(&mut st.0, &corrupt, &c), NEMM_E_BLOB_CRC_MISMATCH);
    assert_eq!(
        levels_init(&mut lv.0, &st.0, trained()),
        NEMM_E_NOT_INITIALISED
    );
}

/// Level tables read their tables in place: a blob off the 4-byte boundary is refused with
/// its own status, and the storage holds no level tables after it (nor after a good init
/// before it); the estimator decodes (copies) the same bytes at any alignment.
#[test]
fn level_tables_refuse_an_unaligned_blob_and_leave_nothing_initialised() {
    let blob = trained();
    let est = c_estimator(blob, 0.15);
    // The same bytes at an address of 1 modulo 4: the estimator's blob (its length and CRC).
    let mut buf = std::vec![0u8; blob.len() + 4];
    let off = (5 - buf.as_ptr() as usize % 4) % 4;
    let shifted = &mut buf[off..off + blob.len()];
    shifted.copy_from_slice(blob);
    let shifted: &[u8] = shifted;
    assert_eq!(shifted.as_ptr() as usize % 4, 1);
    let mut fresh = levels_storage();
    assert_eq!(
        levels_init(&mut fresh.0, &est.0, shifted),
        NEMM_E_LEVELS_UNALIGNED
    );
    let mut lv = levels_storage();
    assert_eq!(levels_init(&mut lv.0, &est.0, blob), NEMM_OK);
    assert_eq!(
        levels_init(&mut lv.0, &est.0, shifted),
        NEMM_E_LEVELS_UNALIGNED
    );
    let mut on_shifted = c_estimator(shifted, 0.15);
    let mut obs = observer_storage();
    for l in [&fresh.0, &lv.0] {
        let mut i = nemm_levels_info_t::default();
        // SAFETY: valid storages and output.
        unsafe {
            assert_eq!(nemm_levels_info(l, &mut i), NEMM_E_NOT_INITIALISED);
            assert_eq!(
                nemm_estimator_attach_levels(&mut on_shifted.0, l),
                NEMM_E_NOT_INITIALISED
            );
        }
        assert_eq!(i, nemm_levels_info_t::default(), "nothing written");
        assert_eq!(
            observer_init_on_levels(&mut obs.0, &est.0, l, None),
            NEMM_E_NOT_INITIALISED
        );
    }
    assert_eq!(
        NEMM_E_LEVELS_UNALIGNED as i32, 78,
        "the header's value is stable"
    );
}

/// A blob of format version 5 stores its tables unaligned: level tables refuse it with
/// their own status (an estimator still decodes it and copies its tables); exported again
/// at this version, the same model and tables (the trained blob's, bit for bit) are read in
/// place.
#[test]
fn level_tables_refuse_a_version_5_blob_until_it_is_exported_again() {
    let v5 = aligned(&as_version_5(trained()));
    assert_eq!(nemm_core::read_header(v5).unwrap().version, 5);
    let mut model = Box::new(P::empty());
    let index = decode_into(v5, &mut model).expect("a version-5 blob decodes");
    assert_eq!(index.levels.len(), TRAINED_LEVELS.len());
    for l in &index.levels {
        assert_eq!(l.b_fl.unwrap().layout, StoredLayout::Segments);
        assert_eq!(l.k_pr.unwrap().layout, StoredLayout::Segments);
    }
    let mut tab = estimator_storage();
    assert_eq!(init(&mut tab.0, v5, &cfg(0.15, NEMM_MODE_TABLE)), NEMM_OK);
    assert_eq!(info(&tab.0).table_origin, NEMM_TABLES_STORED);
    let mut lv = levels_storage();
    assert_eq!(levels_init(&mut lv.0, &tab.0, v5), NEMM_E_LEVELS_LAYOUT);
    let mut i = nemm_levels_info_t::default();
    // SAFETY: valid storage and output.
    let s = unsafe { nemm_levels_info(&lv.0, &mut i) };
    assert_eq!(s, NEMM_E_NOT_INITIALISED);
    // Exported again at this version: the trained blob's model and table images, and its
    // level tables load.
    let again = aligned(&exported_again(v5));
    assert_eq!(
        nemm_core::read_header(again).unwrap().version,
        nemm_core::FORMAT_VERSION
    );
    let (mut a, mut b) = (Box::new(P::empty()), Box::new(P::empty()));
    let index_again = decode_into(again, &mut a).expect("decodes");
    let index_trained = decode_into(trained(), &mut b).expect("decodes");
    assert!(*a == *b, "the same model");
    let image = 32 + 28 * NEMM_TABLE_SEGMENTS;
    let bytes = |blob: &'static [u8], t: Option<nemm_core::StoredTable>| {
        let at = t.expect("a table").offset as usize;
        &blob[at..at + image]
    };
    assert_eq!(index_again.levels.len(), index_trained.levels.len());
    for (la, lt) in index_again.levels.iter().zip(&index_trained.levels) {
        assert_eq!(bytes(again, la.b_fl), bytes(trained(), lt.b_fl));
        assert_eq!(bytes(again, la.k_pr), bytes(trained(), lt.k_pr));
    }
    let est = c_estimator(again, 0.15);
    assert_eq!(levels_init(&mut lv.0, &est.0, again), NEMM_OK);
    assert_eq!(levels_info(&lv.0).levels, 7);
    assert_eq!(
        NEMM_E_LEVELS_LAYOUT as i32, 79,
        "the header's value is stable"
    );
}

fn observer_init_on_levels(
    obs: &mut nemm_observer_t,
    est: &nemm_estimator_t,
    lv: &nemm_levels_t,
    c: Option<&nemm_observer_config_t>,
) -> nemm_status_t {
    // SAFETY: valid storages and configuration (or NULL).
    unsafe {
        nemm_observer_init_on_levels(
            obs,
            core::mem::size_of::<nemm_observer_t>(),
            est,
            lv,
            c.map_or(core::ptr::null(), |c| c as *const _),
        )
    }
}

#[test]
fn the_observer_on_levels_follows_nemm_core_and_finds_alpha() {
    let mut st = estimator_storage();
    assert_eq!(
        init(&mut st.0, trained(), &cfg(0.12, NEMM_MODE_EXACT)),
        NEMM_OK
    );
    let mut lv = levels_storage();
    assert_eq!(levels_init(&mut lv.0, &st.0, trained()), NEMM_OK);
    let mut obs = observer_storage();
    assert_eq!(
        observer_init_on_levels(&mut obs.0, &st.0, &lv.0, None),
        NEMM_OK
    );
    let (model, levels) = reference_levels(trained());
    let mut want: Box<AlphaObserver<'_, NEMM_PARAM_CAPACITY, NEMM_OBSERVER_MAX_POINTS>> =
        Box::new(AlphaObserver::empty());
    want.load_on_levels(&model, &levels, ObserverConfig::new())
        .unwrap();
    assert_eq!(want.grid().collect::<Vec<_>>(), TRAINED_LEVELS);
    // The measured force: the exact estimator's at alpha 0.12 (between two levels), a
    // 0.5 m/s 5 Hz sinusoid for 3 s.
    let mut last = nemm_alpha_estimate_t::default();
    for k in 0..30_000 {
        let v = 0.5 * (2.0 * core::f32::consts::PI * 5.0 * k as f32 * 1e-4).sin();
        let (_, f) = step(&mut st.0, v);
        let mut a = nemm_alpha_estimate_t::default();
        // SAFETY: valid storages and output.
        let position = (k % 2 == 1).then_some(0.0);
        // SAFETY: valid storages and output.
        let s = unsafe {
            c_observe(
                &mut obs.0,
                sample(v, position, None, Some(f.force_n)),
                &mut a,
            )
        };
        let mut w_sample = Sample::new(v).with_force(f.force_n);
        w_sample.position_m = position;
        let w = want.step(w_sample);
        assert_eq!(s, NEMM_OK);
        assert_eq!(a, nemm_alpha_estimate_t::from(w), "sample {k}");
        last = a;
    }
    assert_eq!(
        last.flags & (NEMM_OBSERVER_NOT_EXCITED | NEMM_OBSERVER_NOT_SETTLED),
        0,
        "{last:?}"
    );
    assert!((last.alpha - 0.12).abs() < 0.02, "{last:?}");
    // Settings that contradict the levels.
    let mut c = nemm_observer_config_t::default_values();
    c.points = 7;
    assert_eq!(
        observer_init_on_levels(&mut obs.0, &st.0, &lv.0, Some(&c)),
        NEMM_OK
    );
    c.points = 5;
    assert_eq!(
        observer_init_on_levels(&mut obs.0, &st.0, &lv.0, Some(&c)),
        NEMM_E_OBSERVER_POINTS
    );
    c.points = 0;
    c.grid_hi = 0.2;
    assert_eq!(
        observer_init_on_levels(&mut obs.0, &st.0, &lv.0, Some(&c)),
        NEMM_E_OBSERVER_GRID
    );
    let mut a = nemm_alpha_estimate_t::default();
    // SAFETY: valid storage and output.
    let s = unsafe { c_observe(&mut obs.0, sample(0.1, None, None, Some(1.0)), &mut a) };
    assert_eq!(
        s, NEMM_E_NOT_INITIALISED,
        "a failed init leaves no observer"
    );
    // Another model's estimator with these level tables.
    let light = c_estimator(EXAMPLES[2].0, 0.15);
    assert_eq!(
        observer_init_on_levels(&mut obs.0, &light.0, &lv.0, None),
        NEMM_E_LEVELS_MISMATCH
    );
    // Uninitialised level tables, NULL, overlapping storages.
    let fresh = levels_storage();
    assert_eq!(
        observer_init_on_levels(&mut obs.0, &st.0, &fresh.0, None),
        NEMM_E_NOT_INITIALISED
    );
    // SAFETY: NULL and overlapping arguments are refused before use.
    unsafe {
        let size = core::mem::size_of::<nemm_observer_t>();
        assert_eq!(
            nemm_observer_init_on_levels(
                &mut obs.0,
                size,
                &st.0,
                core::ptr::null(),
                core::ptr::null()
            ),
            NEMM_E_NULL
        );
        let inside = (&raw mut lv.0)
            .cast::<u8>()
            .add(64)
            .cast::<nemm_observer_t>();
        assert_eq!(
            nemm_observer_init_on_levels(inside, size, &st.0, &lv.0, core::ptr::null()),
            NEMM_E_OVERLAP
        );
    }
    // Two observers on two level tables each step on their own.
    let blob = example_blob_with_levels(&[0.1, 0.2]);
    let other = c_estimator(blob, 0.15);
    let mut lv2 = levels_storage();
    assert_eq!(levels_init(&mut lv2.0, &other.0, blob), NEMM_OK);
    assert_eq!(levels_info(&lv2.0).levels, 2);
    let mut obs2 = observer_storage();
    assert_eq!(
        observer_init_on_levels(&mut obs2.0, &other.0, &lv2.0, None),
        NEMM_OK
    );
    assert_eq!(
        observer_init_on_levels(&mut obs.0, &st.0, &lv.0, None),
        NEMM_OK
    );
    // SAFETY: valid storages and output.
    unsafe {
        assert_eq!(
            c_observe(&mut obs.0, sample(0.1, None, None, Some(1.0)), &mut a),
            NEMM_OK
        );
        assert_eq!(
            c_observe(&mut obs2.0, sample(0.1, None, None, Some(1.0)), &mut a),
            NEMM_OK
        );
    }
    // A sample without a force: a missing measurement, as a NaN force.
    // SAFETY: valid storages and output.
    unsafe {
        assert_eq!(
            c_observe(&mut obs2.0, sample(0.1, None, None, None), &mut a),
            NEMM_OK
        );
    }
    assert_eq!(
        a.flags & (NEMM_OBSERVER_FORCE_FAULT | NEMM_OBSERVER_HELD),
        NEMM_OBSERVER_FORCE_FAULT | NEMM_OBSERVER_HELD
    );
}
