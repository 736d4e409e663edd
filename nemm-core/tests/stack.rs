//! Peak stack of decoding a blob and of building an estimator, measured by stack painting
//! on a fresh thread, in whatever profile the test is built (`cargo test -p nemm-core --test
//! stack -- --nocapture` prints the figures; add `--release` for the optimised ones).
//!
//! The in-place paths ([`nemm_core::decode_into`], [`Estimator::load`]) must stay within a
//! few KiB in an optimised build and within one model's size unoptimised, whatever the
//! parameter capacity; the by-value paths (`decode`, `Estimator::new`) hold their result on
//! the stack and are measured for the docs.
#![allow(unsafe_code)] // painting the unused part of a thread's stack

mod common;

use common::{blob_of, P};
use core::hint::black_box;
use nemm_core::{
    decode, decode_into, Estimator, EstimatorConfig, EvalMode, Model, ModelKind, TableConfig,
};

/// Stack of the measuring thread.
const STACK: usize = 16 << 20;
/// Left unpainted at the far end of the thread's stack (thread start-up frames, TLS, guard).
const MARGIN: usize = 2 << 20;
/// Left unpainted just below the painting function's frame.
const GAP: usize = 1024;
const PATTERN: u64 = 0xA5A5_5A5A_C3C3_3C3C;

/// An address in the caller's frame.
#[inline(never)]
fn here() -> usize {
    let x = 0u8;
    black_box(&x) as *const u8 as usize
}

/// Fills `[top - depth, top - GAP)` with the pattern; returns `top`, an address in this
/// frame, which is as deep as the frame of the next call from the same caller starts.
#[inline(never)]
fn paint(depth: usize) -> usize {
    let top = here();
    let mut p = (top - depth) & !7;
    while p < top - GAP {
        // SAFETY: below the live frames of this thread and above its guard page (`MARGIN`
        // from the stack's end): unused stack memory this thread owns.
        unsafe { core::ptr::write_volatile(p as *mut u64, PATTERN) };
        p += 8;
    }
    top
}

/// Bytes from `top` down to the deepest word that no longer holds the pattern.
#[inline(never)]
fn used(top: usize, depth: usize) -> usize {
    let mut p = (top - depth) & !7;
    // SAFETY: the range `paint` wrote, still owned by this thread.
    while p < top - GAP && unsafe { core::ptr::read_volatile(p as *const u64) } == PATTERN {
        p += 8;
    }
    top - p
}

#[inline(never)]
fn run<R>(f: impl FnOnce() -> R) {
    black_box(f());
}

/// Peak stack of `f` in bytes (everything `f` and its callees wrote below the caller's frame;
/// figures under `GAP` read as `GAP`). `f` must capture only small values (boxes).
fn peak_stack<R>(f: impl FnOnce() -> R + Send + 'static) -> usize {
    std::thread::Builder::new()
        .stack_size(STACK)
        .spawn(move || {
            let depth = STACK - MARGIN;
            let top = paint(depth);
            run(f);
            used(top, depth)
        })
        .expect("spawn")
        .join()
        .expect("measured thread")
}

fn profile() -> &'static str {
    if cfg!(debug_assertions) {
        "debug"
    } else {
        "release"
    }
}

fn report(op: &str, bytes: usize) {
    println!(
        "stack op={op} profile={} capacity={P} bytes={bytes}",
        profile()
    );
}

fn table_mode(alpha: f32) -> EstimatorConfig {
    EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1e-4)),
        ..EstimatorConfig::new(alpha)
    }
}

#[test]
fn decoding_and_loading_in_place_use_bounded_stack() {
    let model: Box<Model<P>> =
        Box::new(nemm_core::testing::example_model(ModelKind::Nemm, 16, 5).expect("example"));
    let blob = blob_of(&model);
    let model_bytes = core::mem::size_of::<Model<P>>();
    let (in_place_bound, load_bound) = bounds();

    let mut place: Box<Model<P>> = Box::new(Model::empty());
    let b = blob.clone();
    let in_place = peak_stack(move || decode_into(&b, &mut place).expect("decodes"));
    report("decode_into", in_place);
    assert!(in_place <= in_place_bound, "{in_place} > {in_place_bound}");

    for (op, cfg) in [
        ("load-exact", EstimatorConfig::new(0.15)),
        ("load-table", table_mode(0.15)),
    ] {
        let mut est: Box<Estimator<P>> = Box::new(Estimator::empty());
        let m = model.clone();
        let bytes = peak_stack(move || est.load(&m, cfg).expect("loads"));
        report(op, bytes);
        assert!(bytes <= load_bound, "{op}: {bytes} > {load_bound}");
    }

    // A blob with stored tables at 0.15: decoding indexes them, loading reads them in place.
    // Made on a thread of the measuring size: an unoptimised build needs more than the
    // 2 MiB of a test thread to build the tables and encode them.
    let m = model.clone();
    let (tables_blob, (with_tables, index)) = std::thread::Builder::new()
        .stack_size(STACK)
        .spawn(move || {
            let mut built: Box<Estimator<P>> = Box::new(Estimator::empty());
            built.load(&m, table_mode(0.15)).expect("loads");
            let blob = common::blob_with_tables(&m, &[&*built]).expect("encodes");
            let mut with_tables: Box<Model<P>> = Box::new(Model::empty());
            let index = decode_into(&blob, &mut with_tables).expect("decodes");
            (blob, (with_tables, index))
        })
        .expect("thread")
        .join()
        .expect("tables made");
    let mut place: Box<Model<P>> = Box::new(Model::empty());
    let b = tables_blob.clone();
    let in_place = peak_stack(move || {
        decode_into(&b, &mut place).expect("decodes");
        place
    });
    report("decode_into-tables", in_place);
    assert!(in_place <= in_place_bound, "{in_place} > {in_place_bound}");
    let mut est: Box<Estimator<P>> = Box::new(Estimator::empty());
    let bytes = peak_stack(move || {
        est.load_with_tables(&with_tables, table_mode(0.15), &index, &tables_blob)
            .expect("loads");
        assert_eq!(est.table_origin(), nemm_core::TableOrigin::Stored);
    });
    report("load-stored-tables", bytes);
    assert!(
        bytes <= load_bound,
        "load-stored-tables: {bytes} > {load_bound}"
    );

    // The by-value paths, for the docs: they hold the model / the estimator on the stack.
    let b = blob.clone();
    report(
        "decode",
        peak_stack(move || {
            let m: Model<P> = decode(&b).expect("decodes");
            black_box(&m);
        }),
    );
    let m = model.clone();
    report(
        "new-exact",
        peak_stack(move || {
            let e: Estimator<P> = Estimator::new(&m, EstimatorConfig::new(0.15)).expect("builds");
            black_box(&e);
        }),
    );
    println!(
        "size model={model_bytes} estimator={}",
        core::mem::size_of::<Estimator<P>>()
    );
}

/// The bounds of the in-place paths: `decode_into` and the estimator's `load`.
fn bounds() -> (usize, usize) {
    if cfg!(debug_assertions) {
        // Unoptimised: `decode_into` holds one empty body of the new kind when it switches
        // kinds (see tests/format.rs); the estimator's loading writes in place.
        (core::mem::size_of::<Model<P>>() + (16 << 10), 32 << 10)
    } else {
        // Loading in table mode builds the tables, the deepest path: a little over 8 KiB.
        (8 << 10, (8 << 10) + 512)
    }
}

/// A model with cumulative scalers (format version 7's section, decoded in place) decodes
/// and loads within the bounds of the paper's model.
#[test]
fn cumulative_models_decode_and_load_in_place_with_bounded_stack() {
    let (in_place_bound, load_bound) = bounds();
    let cumulative: Box<Model<P>> = Box::new(nemm_core::testing::example_cumulative_model(
        ModelKind::Nemm,
    ));
    let cumulative_blob = blob_of(&cumulative);
    let mut place: Box<Model<P>> = Box::new(Model::empty());
    let b = cumulative_blob.clone();
    let in_place = peak_stack(move || decode_into(&b, &mut place).expect("decodes"));
    report("decode_into-cumulative", in_place);
    assert!(in_place <= in_place_bound, "{in_place} > {in_place_bound}");
    for (op, cfg) in [
        ("load-cumulative-exact", EstimatorConfig::new(0.15)),
        ("load-cumulative-table", table_mode(0.15)),
    ] {
        let mut est: Box<Estimator<P>> = Box::new(Estimator::empty());
        let m = cumulative.clone();
        let bytes = peak_stack(move || est.load(&m, cfg).expect("loads"));
        report(op, bytes);
        assert!(bytes <= load_bound, "{op}: {bytes} > {load_bound}");
    }
}
