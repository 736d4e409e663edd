//! Cost of one `Estimator::step` per model kind and integrator, and of decoding a blob.
//!
//! ```text
//! cargo bench -p nemm-core --bench step                                       # libm
//! cargo bench -p nemm-core --bench step --no-default-features --features micromath
//! ```
//!
//! `observer/*`: one step of the alpha observer (`AlphaObserver`, 7 levels) on the same
//! input, with the force of the model at alpha 0.15.
//!
//! `step-table/*`: the same step in the tabulated mode (`EvalMode::Table`, 256 segments per
//! table, bound 1e-4) for the neural kinds. A kind whose tables miss the bound is skipped with
//! a message (with `micromath` the approximated scalers of the example models do).
//!
//! Models: `nemm_core::testing::example_model(kind, 16, 5)` (the paper's best Table 3 size,
//! H = 16, L = 5), alpha 0.15, default step 1e-4 s. Each iteration is one step on a
//! precomputed 5 Hz sinusoidal velocity of 0.5 m/s (one period, 2000 samples, cycled), so the
//! state moves through its whole range as on the bench. Results are per step.
//!
//! On Linux the measurement is the benchmark thread's CPU time
//! (`CLOCK_THREAD_CPUTIME_ID`), not wall time: on a shared machine other processes then only
//! disturb the figures through caches, not by taking the core away (with wall time the same
//! benchmark varied by 2x between runs on the project's 2-core build machine).

use criterion::measurement::Measurement;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use nemm_core::Sample;
use nemm_core::{
    decode, encode, AlphaObserver, Estimator, EstimatorConfig, EvalMode, Integrator, Model,
    ModelKind, ObserverConfig, TableConfig, DEFAULT_PARAM_CAPACITY,
};
use std::hint::black_box;

const KINDS: [ModelKind; 4] = [
    ModelKind::Sem,
    ModelKind::LinearEmm,
    ModelKind::NemmLight,
    ModelKind::Nemm,
];

fn model(kind: ModelKind) -> Model {
    nemm_core::testing::example_model(kind, 16, 5).expect("example model")
}

fn velocities(dt: f32) -> Vec<f32> {
    (0..2000)
        .map(|k| 0.5 * (2.0 * std::f32::consts::PI * 5.0 * k as f32 * dt).sin())
        .collect()
}

fn step<M: Measurement>(c: &mut Criterion<M>) {
    let mut g = c.benchmark_group(format!("step/{}", nemm_kernels::math::BACKEND));
    g.throughput(Throughput::Elements(1));
    for kind in KINDS {
        let m = model(kind);
        let vs = velocities(m.dt_s);
        for integrator in [Integrator::Rk4, Integrator::Rk3] {
            let cfg = EstimatorConfig {
                integrator: Some(integrator),
                ..EstimatorConfig::new(0.15)
            };
            let mut est = Estimator::new(&m, cfg).expect("valid model");
            let mut k = 0usize;
            g.bench_function(BenchmarkId::new(kind.name(), integrator.name()), |b| {
                b.iter(|| {
                    k = if k + 1 == vs.len() { 0 } else { k + 1 };
                    black_box(est.step(Sample::new(black_box(vs[k]))).unwrap())
                })
            });
        }
    }
    g.finish();
}

/// The tabulated fast path (`EvalMode::Table`, 256 segments, bound 1e-4) of the neural kinds.
fn step_table<M: Measurement>(c: &mut Criterion<M>) {
    let mut g = c.benchmark_group(format!("step-table/{}", nemm_kernels::math::BACKEND));
    g.throughput(Throughput::Elements(1));
    for kind in [ModelKind::NemmLight, ModelKind::Nemm] {
        let m = model(kind);
        let vs = velocities(m.dt_s);
        for integrator in [Integrator::Rk4, Integrator::Rk3] {
            let cfg = EstimatorConfig {
                integrator: Some(integrator),
                mode: EvalMode::Table(TableConfig::new(1e-4)),
                ..EstimatorConfig::new(0.15)
            };
            let mut est: Estimator = match Estimator::new(&m, cfg) {
                Ok(est) => est,
                Err(e) => {
                    eprintln!(
                        "step-table/{}/{}/{}: skipped, the tables miss the bound: {e:?}",
                        nemm_kernels::math::BACKEND,
                        kind.name(),
                        integrator.name()
                    );
                    continue;
                }
            };
            let mut k = 0usize;
            g.bench_function(BenchmarkId::new(kind.name(), integrator.name()), |b| {
                b.iter(|| {
                    k = if k + 1 == vs.len() { 0 } else { k + 1 };
                    black_box(est.step(Sample::new(black_box(vs[k]))).unwrap())
                })
            });
        }
    }
    g.finish();
}

/// One `AlphaObserver::step` (7 levels over the trained range, exact mode, RK4) of the NEMM
/// example model: the velocity as in `step`, the force that of the model at alpha 0.15.
fn observer<M: Measurement>(c: &mut Criterion<M>) {
    let mut g = c.benchmark_group(format!("observer/{}", nemm_kernels::math::BACKEND));
    g.throughput(Throughput::Elements(1));
    let m = model(ModelKind::Nemm);
    let vs = velocities(m.dt_s);
    let mut est = Estimator::new(&m, EstimatorConfig::new(0.15)).expect("valid model");
    let fs: Vec<f32> = vs
        .iter()
        .map(|&v| est.step(Sample::new(v)).unwrap().force_n)
        .collect();
    let mut obs: Box<AlphaObserver> = Box::new(AlphaObserver::empty());
    obs.load(&m, ObserverConfig::new()).expect("valid model");
    let mut k = 0usize;
    g.bench_function(BenchmarkId::new("nemm", obs.points()), |b| {
        b.iter(|| {
            k = if k + 1 == vs.len() { 0 } else { k + 1 };
            black_box(obs.step(Sample::new(black_box(vs[k])).with_force(black_box(fs[k]))))
        })
    });
    g.finish();
}

fn decode_blob<M: Measurement>(c: &mut Criterion<M>) {
    let mut g = c.benchmark_group("decode");
    for kind in KINDS {
        let m = model(kind);
        let mut buf = vec![0u8; 64 * 1024];
        let blob = encode(&m, &mut buf).expect("valid model").to_vec();
        g.throughput(Throughput::Bytes(blob.len() as u64));
        g.bench_function(
            BenchmarkId::new(kind.name(), format!("{}B", blob.len())),
            |b| {
                b.iter(|| {
                    let m: Model<DEFAULT_PARAM_CAPACITY> =
                        decode(black_box(&blob)).expect("valid blob");
                    black_box(&m);
                })
            },
        );
    }
    // The default capacity makes `Model` 110 KB, whose moves dominate small blobs; a firmware
    // that knows its model decodes into the announced capacity (1313 for H = 16, L = 5).
    let m = model(ModelKind::Nemm);
    let mut buf = vec![0u8; 64 * 1024];
    let blob = encode(&m, &mut buf).expect("valid model").to_vec();
    g.throughput(Throughput::Bytes(blob.len() as u64));
    g.bench_function(BenchmarkId::new("nemm", "capacity-1313"), |b| {
        b.iter(|| {
            let m: Model<1313> = decode(black_box(&blob)).expect("valid blob");
            black_box(&m);
        })
    });
    g.finish();
}

#[cfg(target_os = "linux")]
mod cpu_time {
    //! Thread CPU time as a criterion measurement, in nanoseconds (so criterion's duration
    //! formatting applies).
    use criterion::measurement::{Measurement, ValueFormatter, WallTime};

    /// `CLOCK_THREAD_CPUTIME_ID` of the calling thread.
    pub struct ThreadCpuTime;

    static WALL: WallTime = WallTime;

    fn now_ns() -> u64 {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant.
        let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID) failed");
        ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
    }

    impl Measurement for ThreadCpuTime {
        type Intermediate = u64;
        type Value = u64;
        fn start(&self) -> u64 {
            now_ns()
        }
        fn end(&self, start: u64) -> u64 {
            now_ns() - start
        }
        fn add(&self, a: &u64, b: &u64) -> u64 {
            a + b
        }
        fn zero(&self) -> u64 {
            0
        }
        fn to_f64(&self, v: &u64) -> f64 {
            *v as f64
        }
        fn formatter(&self) -> &dyn ValueFormatter {
            WALL.formatter()
        }
    }
}

#[cfg(target_os = "linux")]
criterion_group! {
    name = benches;
    config = Criterion::default().with_measurement(cpu_time::ThreadCpuTime);
    targets = step, step_table, observer, decode_blob
}
#[cfg(not(target_os = "linux"))]
criterion_group!(benches, step, step_table, observer, decode_blob);
criterion_main!(benches);
