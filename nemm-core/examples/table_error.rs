//! Force difference of the tabulated fast path against the exact one over a full bench
//! programme, per model, integrator and table size.
//!
//! ```text
//! cargo run --release -p nemm-core --example table_error                  # example models
//! cargo run --release -p nemm-core --example table_error -- model.nemm    # a trained blob
//! cargo run --release -p nemm-core --example table_error -- --markdown [model.nemm ..]
//! ```
//!
//! `--markdown` prints one table row per run, for the example models and each blob given
//! (what `cargo xtask results --tables` writes into docs/results.md).
//!
//! The programme: the paper's Table 1 grid of sinusoidal strokes (amplitudes 50, 30, 10 mm x
//! peak velocities 0.052 ... 1.048 m/s), three periods each from rest, at the model's step
//! (612,222 samples at 10 kHz), at alphas 0, 0.15 and 0.3 (the example models' training
//! range; for a blob its `meta.alpha_min`, middle and `alpha_max`) with RK4 and the default
//! 256 segments, and at the middle alpha also with RK3 and with 64 and 128 segments. Both
//! estimators see the same velocities; the example prints, per run, the
//! largest relative coefficient error the table compile measured, and the largest and RMS
//! force difference in N and as a fraction of the model's force scale, and the steps that
//! left the table domain (flag `OUT_OF_TABLE_DOMAIN`). The example models are those of
//! `nemm_core::testing` (H = 16, L = 5; pseudo-random, not trained).

use nemm_core::Sample;
use nemm_core::{
    decode, Estimator, EstimatorConfig, EvalMode, Flags, Integrator, Model, ModelKind, TableConfig,
};

const AMPLITUDES_M: [f64; 3] = [0.05, 0.03, 0.01];
const PEAK_VELOCITIES_M_S: [f64; 6] = [0.052, 0.131, 0.262, 0.393, 0.524, 1.048];
const PERIODS: f64 = 3.0;

fn stroke(amp: f64, v_peak: f64, dt: f64) -> Vec<f32> {
    let w = v_peak / amp;
    let n = (PERIODS * 2.0 * std::f64::consts::PI / w / dt).round() as usize;
    (0..n)
        .map(|k| (v_peak * (w * k as f64 * dt).cos()) as f32)
        .collect()
}

/// Runs the programme in exact mode and in table mode with `T` segments (a bound of 1, so
/// that every size is measured; the compile's measured error is printed).
fn compare<const T: usize>(
    (name, m): (&str, &Model),
    alpha: f32,
    integrator: Integrator,
    strokes: &[Vec<f32>],
    markdown: bool,
) {
    let base = EstimatorConfig {
        integrator: Some(integrator),
        ..EstimatorConfig::new(alpha)
    };
    let mut exact: Estimator = Estimator::new(m, base).expect("valid model");
    let cfg = EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1.0)),
        ..base
    };
    let mut table: Estimator<{ nemm_core::DEFAULT_PARAM_CAPACITY }, T> =
        match Estimator::with_segments(m, cfg) {
            Ok(e) => e,
            Err(e) if markdown => {
                println!(
                    "| {name} | {alpha} | {} | {T} | refused: {e} | - | - | - |",
                    integrator.name()
                );
                return;
            }
            Err(e) => {
                println!("  T={T}: {e}");
                return;
            }
        };
    let (mut worst, mut sum2, mut n, mut outside) = (0.0f64, 0.0f64, 0usize, 0usize);
    for s in strokes {
        exact.reset();
        table.reset();
        for &v in s {
            let a = exact.step(Sample::new(v)).unwrap();
            let b = table.step(Sample::new(v)).unwrap();
            let d = f64::from(b.force_n) - f64::from(a.force_n);
            worst = worst.max(d.abs());
            sum2 += d * d;
            n += 1;
            if b.flags.contains(Flags::OUT_OF_TABLE_DOMAIN) {
                outside += 1;
            }
        }
    }
    let fs = f64::from(m.meta.force_scale_n);
    let rms = (sum2 / n.max(1) as f64).sqrt();
    let acc = table.table_accuracy().map_or(0.0, |a| a.max_rel_error);
    let kinks = table.table_accuracy().map_or(0, |a| a.kinks);
    let (tables, bytes) = table.table_bytes();
    if markdown {
        println!(
            "| {name} | {alpha} | {} | {T} | {acc:.1e} ({kinks} kinks) | {:.1e} | {:.1e} | {outside} |",
            integrator.name(),
            worst / fs,
            rms / fs,
        );
        return;
    }
    println!(
        "  alpha={alpha:.3} {} T={T:4}: {tables} table(s) {bytes} B, coefficient max rel error {acc:.2e} ({kinks} kinks in the worst); \
         force max {worst:.4} N = {:.2e} of the force scale, RMS {rms:.4} N = {:.2e}; \
         {outside} of {n} steps outside the table domain",
        integrator.name(),
        worst / fs,
        rms / fs,
    );
}

fn example_models() -> Vec<(String, Model)> {
    [ModelKind::NemmLight, ModelKind::Nemm]
        .into_iter()
        .map(|k| {
            let m = nemm_core::testing::example_model(k, 16, 5).expect("example model");
            (format!("example {}", k.name()), m)
        })
        .collect()
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let markdown = args.first().is_some_and(|a| a == "--markdown");
    if markdown {
        args.remove(0);
    }
    let mut models: Vec<(String, Model)> = args
        .iter()
        .map(|path| {
            let blob = std::fs::read(path).unwrap_or_else(|e| panic!("{path}: {e}"));
            let m: Model = decode(&blob).unwrap_or_else(|e| panic!("{path}: {e}"));
            (format!("`{path}`"), m)
        })
        .collect();
    if models.is_empty() || markdown {
        models.extend(example_models());
    }
    if markdown {
        println!(
            "| model | alpha | integrator | segments | coefficient error (kinks) | max force difference / force scale | RMS / force scale | steps outside |"
        );
        println!("|---|---:|---|---:|---:|---:|---:|---:|");
    }
    for (name, m) in &models {
        let strokes: Vec<Vec<f32>> = AMPLITUDES_M
            .iter()
            .flat_map(|&a| PEAK_VELOCITIES_M_S.iter().map(move |&v| (a, v)))
            .map(|(a, v)| stroke(a, v, f64::from(m.dt_s)))
            .collect();
        let samples: usize = strokes.iter().map(Vec::len).sum();
        if !markdown {
            println!(
                "{name}: {}, force scale {} N, {samples} samples per run",
                m.kind().name(),
                m.meta.force_scale_n
            );
        }
        let (a0, a1) = (m.meta.alpha_min, m.meta.alpha_max);
        let mid = 0.5 * (a0 + a1);
        let named = (name.as_str(), m);
        for alpha in [a0, mid, a1] {
            compare::<256>(named, alpha, Integrator::Rk4, &strokes, markdown);
        }
        compare::<256>(named, mid, Integrator::Rk3, &strokes, markdown);
        compare::<64>(named, mid, Integrator::Rk4, &strokes, markdown);
        compare::<128>(named, mid, Integrator::Rk4, &strokes, markdown);
    }
}
