//! Cost of one training batch's rollout gradient (forward sweep + discrete adjoint).
//!
//! ```text
//! cargo bench -p nemm-train --bench gradient
//! ```
//!
//! A batch is 16 windows of 5000 steps (0.5 s at 10 kHz, Table 3's best batch size), NEMM with
//! 16-wide, 5-layer scalers, RK4, on a sinusoidal velocity of bench-like amplitude. Measured on
//! one thread and on all threads (packs of 8 windows run in parallel). The reference figure is
//! a hand-written single-thread f32 forward + adjoint without the lane packing, 1.0 s per
//! batch on this machine kind.
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use nemm_core::testing::example_model;
use nemm_core::ModelKind;
use nemm_train::train::adjoint::{loss_and_grad, Grid, RolloutParams, Window};
use nemm_train::train::params::from_core;
use std::hint::black_box;

const BATCH: usize = 16;
const STEPS: usize = 5000;

fn inputs() -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let us: Vec<Vec<f32>> = (0..BATCH)
        .map(|w| {
            let f = 2.0 + w as f32;
            (0..STEPS)
                .map(|i| 0.5 * (2.0 * std::f32::consts::PI * f * i as f32 * 1e-4 + w as f32).sin())
                .collect()
        })
        .collect();
    let fs = us
        .iter()
        .map(|u| u.iter().map(|x| 1800.0 * x).collect())
        .collect();
    (us, fs)
}

fn bench(c: &mut Criterion) {
    let (us, fs) = inputs();
    let wins: Vec<Window<'_>> = (0..BATCH)
        .map(|i| Window {
            u: &us[i],
            f: &fs[i],
            alpha: [0.0, 0.3][i % 2],
            alphas: None,
            x: None,
        })
        .collect();
    let mut g = c.benchmark_group("batch_gradient_16x5000");
    g.sample_size(10);
    for kind in [ModelKind::LinearEmm, ModelKind::NemmLight, ModelKind::Nemm] {
        let m = example_model(kind, 16, 5).expect("model");
        let p: RolloutParams<f32> = from_core(&m).expect("emm");
        let all = rayon::current_num_threads();
        for threads in [1, all] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            g.bench_with_input(
                BenchmarkId::new(kind.name(), format!("{threads}-thread")),
                &threads,
                |b, _| {
                    b.iter(|| {
                        pool.install(|| {
                            black_box(loss_and_grad(&p, &wins, &Grid::SAME, 500, 3000.0))
                        })
                    })
                },
            );
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
