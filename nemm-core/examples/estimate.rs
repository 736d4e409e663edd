//! Loads a weights blob (a file given as the first argument, or the built-in example NEMM),
//! runs the online estimator over sinusoidal strokes of the paper's Table 1 grid and prints
//! the force range per condition.
//!
//! ```text
//! cargo run --release -p nemm-core --example estimate [-- model.nemm [alpha]]
//! ```
use nemm_core::Sample;
use nemm_core::{decode, read_header, Estimator, EstimatorConfig, Model};
use std::f32::consts::PI;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let blob: Vec<u8> = match args.get(1) {
        Some(path) => match std::fs::read(path) {
            Ok(b) => b,
            Err(e) => {
                eprintln!("error: cannot read {path}: {e}");
                std::process::exit(1);
            }
        },
        None => nemm_core::testing::example_blob().to_vec(),
    };
    let alpha: f32 = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(0.15);
    let header = match read_header(&blob) {
        Ok(h) => h,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    let model: Model = match decode(&blob) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    println!(
        "model: {} ({} bytes, format v{}), {} at {:.0} Hz, alpha = {alpha}",
        model.kind().name(),
        blob.len(),
        header.version,
        model.integrator.name(),
        1.0 / model.dt_s
    );
    println!(
        "{:>8} {:>10} {:>9} {:>10} {:>10}",
        "ampl_m", "v_peak", "freq_hz", "F_min_N", "F_max_N"
    );
    for &amp in &[0.05f32, 0.01] {
        for &v_peak in &[0.052f32, 0.262, 0.524, 1.048] {
            let mut est = match Estimator::new(&model, EstimatorConfig::new(alpha)) {
                Ok(e) => e,
                Err(e) => {
                    eprintln!("error: {e}");
                    std::process::exit(1);
                }
            };
            let w = v_peak / amp;
            let f_hz = w / (2.0 * PI);
            let n = (3.0 / f_hz / model.dt_s).min(200_000.0) as usize;
            let (mut lo, mut hi) = (f32::MAX, f32::MIN);
            for k in 0..n {
                let t = k as f32 * model.dt_s;
                let e = est.step(Sample::new(v_peak * (w * t).cos())).unwrap();
                if k > n / 3 {
                    lo = lo.min(e.force_n);
                    hi = hi.max(e.force_n);
                }
            }
            println!("{amp:>8.3} {v_peak:>10.3} {f_hz:>9.2} {lo:>10.1} {hi:>10.1}");
        }
    }
}
