//! Runs the online alpha observer over recorded runs and compares it with the offline best
//! fit: per run (a CSV of `time_s,displacement_m,force_n` at the model's rate) the estimate
//! at 2 s and at the end, its band and flags, the time to settle, and the level whose
//! whole-run simulation fits the measured force best.
//!
//! ```text
//! cargo run --release -p nemm-core --example observer -- model.nemm runs/*.csv
//! ```
//!
//! The velocity is the firmware's: the backward difference of the stroke through the
//! 500 Hz low-pass of `nemm_core::LowPass`. The offline fit simulates the whole run from
//! rest at every level of a 0.01 grid over the trained range and then of a 0.001 grid around
//! the best (table mode, 256 segments, bound 1e-4), scoring the samples after the observer's
//! warm-up; the observer runs with its defaults.
use nemm_core::{
    decode, AlphaObserver, Estimator, EstimatorConfig, EvalMode, LowPass, Model, ObserverConfig,
    Sample, TableConfig,
};

fn fail(msg: String) -> ! {
    eprintln!("error: {msg}");
    std::process::exit(1);
}

/// Velocity \[m/s\] and force \[N\] of a run at rate `fs`.
fn read_run(path: &str, fs: f64) -> (Vec<f32>, Vec<f32>) {
    let mut rdr = csv::Reader::from_path(path).unwrap_or_else(|e| fail(format!("{path}: {e}")));
    let (mut x, mut f) = (Vec::new(), Vec::new());
    for rec in rdr.records() {
        let rec = rec.unwrap_or_else(|e| fail(format!("{path}: {e}")));
        let num = |i: usize| -> f64 {
            rec.get(i)
                .and_then(|s| s.trim().parse().ok())
                .unwrap_or_else(|| fail(format!("{path}: bad number in column {i}")))
        };
        x.push(num(1));
        f.push(num(2) as f32);
    }
    let mut lp = LowPass::new(fs as f32, nemm_core::DEFAULT_CUTOFF_HZ);
    let mut v = vec![0.0f32];
    v.extend(x.windows(2).map(|w| lp.push(((w[1] - w[0]) * fs) as f32)));
    v.truncate(f.len());
    (v, f)
}

/// RMSE of the model at `alpha` over the run, samples from `skip` on.
fn rmse(model: &Model, alpha: f32, v: &[f32], f: &[f32], skip: usize) -> f64 {
    let cfg = EstimatorConfig {
        mode: EvalMode::Table(TableConfig::new(1e-4)),
        ..EstimatorConfig::new(alpha)
    };
    let mut est: Box<Estimator> = Box::new(Estimator::empty());
    est.load(model, cfg)
        .unwrap_or_else(|e| fail(format!("{e}")));
    let mut se = 0.0f64;
    for (k, (&u, &y)) in v.iter().zip(f).enumerate() {
        let p = est.step(Sample::new(u)).unwrap().force_n;
        if k >= skip {
            se += f64::from(p - y).powi(2);
        }
    }
    (se / (v.len().saturating_sub(skip).max(1)) as f64).sqrt()
}

/// The level of least whole-run RMSE: a 0.01 grid over `[lo, hi]`, then 0.001 around it.
fn offline_fit(model: &Model, (lo, hi): (f32, f32), v: &[f32], f: &[f32], skip: usize) -> f32 {
    let argmin = |levels: Vec<f32>| {
        levels
            .into_iter()
            .map(|a| (a, rmse(model, a, v, f, skip)))
            .fold((lo, f64::INFINITY), |b, p| if p.1 < b.1 { p } else { b })
            .0
    };
    let coarse = argmin(
        (0..)
            .map(|i| lo + 0.01 * i as f32)
            .take_while(|&a| a <= hi + 1e-6)
            .collect(),
    );
    argmin(
        (-10..=10)
            .map(|i| (coarse + 0.001 * i as f32).clamp(lo, hi))
            .collect(),
    )
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        fail("usage: observer MODEL.nemm RUN.csv...".into())
    };
    let blob = std::fs::read(path).unwrap_or_else(|e| fail(format!("{path}: {e}")));
    let model: Box<Model> = Box::new(decode(&blob).unwrap_or_else(|e| fail(format!("{e}"))));
    let cfg = ObserverConfig::new();
    let fs = 1.0 / f64::from(model.dt_s);
    let skip = (cfg.warmup_s / model.dt_s) as usize;
    println!(
        "# size_of AlphaObserver<1313, 7> = {} B (H = 16, L = 5 capacity), AlphaObserver (default capacity) = {} B",
        std::mem::size_of::<AlphaObserver<1313, 7>>(),
        std::mem::size_of::<AlphaObserver>()
    );
    println!("run,duration_s,offline,alpha_2s,band_2s,alpha_end,band_end,excited_end,out_of_range_end,settle_s,err_2s");
    for run in &args[2..] {
        let (v, f) = read_run(run, fs);
        let mut obs: Box<AlphaObserver> = Box::new(AlphaObserver::empty());
        obs.load(&model, cfg)
            .unwrap_or_else(|e| fail(format!("{e}")));
        let trace: Vec<_> = v
            .iter()
            .zip(&f)
            .map(|(&u, &y)| obs.step(Sample::new(u).with_force(y)))
            .collect();
        let (lo, hi) = (model.meta.alpha_min, model.meta.alpha_max);
        let best = offline_fit(&model, (lo, hi), &v, &f, skip);
        let n2 = ((2.0 / model.dt_s) as usize).min(trace.len()) - 1;
        let (a2, end) = (trace[n2], trace[trace.len() - 1]);
        // Settled: from the first sample after which the estimate stays within 0.02 of its
        // final value.
        let settle = trace
            .iter()
            .rposition(|e| (e.alpha - end.alpha).abs() > 0.02)
            .map_or(0.0, |k| (k + 1) as f32 * model.dt_s);
        println!(
            "{},{:.2},{best:.3},{:.4},{:.4},{:.4},{:.4},{},{},{settle:.2},{:.4}",
            run.rsplit('/').next().unwrap_or(run),
            v.len() as f32 * model.dt_s,
            a2.alpha,
            a2.band,
            end.alpha,
            end.band,
            end.flags.excited(),
            end.flags.contains(nemm_core::ObserverFlags::OUT_OF_RANGE),
            a2.alpha - best,
        );
    }
}
