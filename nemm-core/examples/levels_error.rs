//! Every level at table cost, measured: the blend of stored level tables against the exact
//! model, per number of levels.
//!
//! ```text
//! cargo run --release -p nemm-core --example levels_error -- model.nemm
//! cargo run --release -p nemm-core --example levels_error -- --markdown model.nemm
//! ```
//!
//! For 4, 7 and 13 levels evenly over the model's trained range `[meta.alpha_min,
//! meta.alpha_max]`, the example builds the table-mode estimator of each level (128
//! segments, bound 1e-4: the firmware's tables), stores the tables in a blob as `nemm export
//! --tables-levels` does, loads them into `LevelTables` and prints:
//!
//! - the tables section's bytes in the blob (flash, where the tables are read in place) and
//!   the level tables' own RAM;
//! - `LevelTables::check` (7 levels inside each interval, 16 states per segment): the worst
//!   relative error of each blended coefficient against the exact scalers, and the points
//!   where neighbouring levels are out of the declared order in the tables and in the
//!   exact model;
//! - the force: the paper's Table 1 programme (18 strokes of three periods from rest) at
//!   the middle of every interval between levels (where the blend errs most), and one
//!   stroke programme with alpha ramping over the trained range within each stroke, run by
//!   `Estimator::step_on_levels` and by the exact estimator with `step_with_alpha`: the
//!   largest and RMS force difference as a fraction of the model's force scale.

use nemm_core::Sample;
use nemm_core::{
    decode, decode_into, encode_with_tables, encoded_len_with_tables, AlignedBlob, Estimator,
    EstimatorConfig, EvalMode, LevelTables, Model, TableConfig, DEFAULT_PARAM_CAPACITY,
};

const P: usize = DEFAULT_PARAM_CAPACITY;
const T: usize = 128;
const AMPLITUDES_M: [f64; 3] = [0.05, 0.03, 0.01];
const PEAK_VELOCITIES_M_S: [f64; 6] = [0.052, 0.131, 0.262, 0.393, 0.524, 1.048];

fn stroke(amp: f64, v_peak: f64, dt: f64) -> Vec<f32> {
    let w = v_peak / amp;
    let n = (3.0 * 2.0 * std::f64::consts::PI / w / dt).round() as usize;
    (0..n)
        .map(|k| (v_peak * (w * k as f64 * dt).cos()) as f32)
        .collect()
}

/// The blob of `m` with table-mode tables at each of `alphas`.
fn blob_with_levels(m: &Model, alphas: &[f32]) -> Vec<u8> {
    let ests: Vec<Box<Estimator<P, T>>> = alphas
        .iter()
        .map(|&a| {
            let cfg = EstimatorConfig {
                mode: EvalMode::Table(TableConfig::new(1e-4)),
                ..EstimatorConfig::new(a)
            };
            let mut e = Box::new(Estimator::empty());
            e.load(m, cfg)
                .unwrap_or_else(|e| panic!("tables at alpha {a}: {e}"));
            e
        })
        .collect();
    let refs: Vec<&Estimator<P, T>> = ests.iter().map(|e| &**e).collect();
    let mut buf = vec![0u8; encoded_len_with_tables(m, &refs).expect("encodes")];
    let n = encode_with_tables(m, &refs, &mut buf)
        .expect("encodes")
        .len();
    buf.truncate(n);
    buf
}

/// Largest and RMS |force difference| / force scale of the levels against the exact
/// estimator over `runs` (velocity, alpha per sample), each from rest.
fn force_error(m: &Model, levels: &LevelTables<'_, T, 16>, runs: &[Vec<(f32, f32)>]) -> (f64, f64) {
    let mut exact: Box<Estimator<P, 3>> = Box::new(Estimator::empty());
    let mut tab: Box<Estimator<P, 3>> = Box::new(Estimator::empty());
    let (mut worst, mut sum2, mut n) = (0.0f64, 0.0f64, 0usize);
    for run in runs {
        let a0 = run.first().map_or(0.0, |s| s.1);
        exact.load(m, EstimatorConfig::new(a0)).expect("loads");
        tab.load(m, EstimatorConfig::new(a0)).expect("loads");
        tab.attach_levels(levels).expect("levels of this model");
        for &(v, a) in run {
            let x = exact
                .step(Sample::new(v).with_alpha(a))
                .expect("alpha in range")
                .force_n;
            let y = tab
                .step(Sample::new(v).with_alpha(a))
                .expect("levels")
                .force_n;
            let d = f64::from(y - x).abs();
            worst = worst.max(d);
            sum2 += d * d;
            n += 1;
        }
    }
    let s = f64::from(m.meta.force_scale_n);
    (worst / s, (sum2 / n.max(1) as f64).sqrt() / s)
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let markdown = args.first().is_some_and(|a| a == "--markdown");
    if markdown {
        args.remove(0);
    }
    let path = args
        .first()
        .expect("usage: levels_error [--markdown] model.nemm");
    let blob = std::fs::read(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let m: Box<Model> = Box::new(decode(&blob).unwrap_or_else(|e| panic!("{path}: {e}")));
    let (lo, hi) = (m.meta.alpha_min, m.meta.alpha_max);
    let dt = f64::from(m.dt_s);
    let strokes: Vec<Vec<f32>> = AMPLITUDES_M
        .iter()
        .flat_map(|&a| PEAK_VELOCITIES_M_S.iter().map(move |&v| stroke(a, v, dt)))
        .collect();
    println!(
        "| levels | flash (B) | RAM (B) | b_fl error | b_pr error | k_pr error | out of order: tables / exact (of points) | max force difference / force scale | RMS / force scale |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for count in [4usize, 7, 13] {
        let alphas: Vec<f32> = (0..count)
            .map(|k| lo + (hi - lo) * k as f32 / (count - 1) as f32)
            .collect();
        // Held 4-byte aligned: the level tables read it in place.
        let with = AlignedBlob::new(&blob_with_levels(&m, &alphas));
        let mut mm: Box<Model> = Box::new(Model::empty());
        let tables = decode_into(&with, &mut mm).expect("decodes");
        let mut levels: Box<LevelTables<'_, T, 16>> = Box::new(LevelTables::empty());
        levels.load(&mm, &tables, &with).expect("levels");
        let mut ex: Box<Estimator<P, 3>> = Box::new(Estimator::empty());
        ex.load(&mm, EstimatorConfig::new(lo)).expect("loads");
        let c = levels.check(&mut ex, 7, 16).expect("check");
        let mut runs: Vec<Vec<(f32, f32)>> = Vec::new();
        for w in alphas.windows(2) {
            let mid = 0.5 * (w[0] + w[1]);
            runs.extend(
                strokes
                    .iter()
                    .map(|s| s.iter().map(|&v| (v, mid)).collect()),
            );
        }
        runs.extend(strokes.iter().map(|s| {
            let n = s.len().max(2) - 1;
            s.iter()
                .enumerate()
                .map(|(k, &v)| (v, lo + (hi - lo) * k as f32 / n as f32))
                .collect()
        }));
        let (worst, rms) = force_error(&mm, &levels, &runs);
        // The tables section's bytes: the blob with these levels over the model without any.
        let plain = encoded_len_with_tables::<P, T>(&m, &[]).expect("encodes");
        let flash = with.len().saturating_sub(plain);
        // The level tables' own RAM: the tables are read in place from the blob.
        let ram = core::mem::size_of::<LevelTables<'_, T, 16>>();
        let [e_fl, e_pr, e_k] = c.max_rel_error;
        let order = format!(
            "{} / {} (of {})",
            c.table_order_violations,
            c.exact_order_violations,
            c.points / 7
        );
        if markdown {
            println!(
                "| {count} | {flash} | {ram} | {e_fl:.1e} | {e_pr:.1e} | {e_k:.1e} | {order} | {worst:.1e} | {rms:.1e} |"
            );
        } else {
            println!(
                "{count} levels: flash {flash} B, RAM {ram} B, blend error b_fl {e_fl:.2e} b_pr {e_pr:.2e} k_pr {e_k:.2e} (worst at alpha {:.3}), order {order}, force max {worst:.2e} RMS {rms:.2e}",
                c.at_alpha
            );
        }
    }
}
