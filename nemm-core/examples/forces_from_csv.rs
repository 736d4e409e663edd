//! Runs a weights blob over a CSV file of stroke velocities and prints the estimated forces:
//! the starting point of a tool of your own.
//!
//! ```text
//! cargo run -p nemm-core --example forces_from_csv -- MODEL.nemm VELOCITIES.csv [ALPHA]
//! cargo run -p nemm-core --example forces_from_csv -- - nemm-core/examples/data/velocities.csv
//! ```
//!
//! `-` as the model runs the built-in example NEMM. The CSV has a header; the velocity column
//! is `velocity_m_s` (m/s, positive in extension), a `time_s` column is copied through if
//! present, and the samples must be at the model's step (`dt_s`, 10 kHz by default). ALPHA is
//! the condition level in `[0, 1]` (default 0.15). Output on stdout:
//! `time_s,velocity_m_s,force_n,flags`.
//!
//! The model and the estimator are built in place on the heap (`decode_into`,
//! `Estimator::load`), so the example runs in debug builds with a small stack.
use nemm_core::Sample;
use nemm_core::{decode_into, Estimator, EstimatorConfig, Model};
use std::error::Error;
use std::io::Write;

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(model_path), Some(csv_path)) = (args.first(), args.get(1)) else {
        return Err("usage: forces_from_csv MODEL.nemm|- VELOCITIES.csv [ALPHA]".into());
    };
    let alpha: f32 = match args.get(2) {
        Some(a) => a.parse().map_err(|e| format!("alpha {a:?}: {e}"))?,
        None => 0.15,
    };
    let blob = if model_path == "-" {
        nemm_core::testing::example_blob().to_vec()
    } else {
        std::fs::read(model_path).map_err(|e| format!("{model_path}: {e}"))?
    };
    let mut model: Box<Model> = Box::new(Model::empty());
    decode_into(&blob, &mut model).map_err(|e| format!("{model_path}: {e}"))?;
    let mut est: Box<Estimator> = Box::new(Estimator::empty());
    est.load(&model, EstimatorConfig::new(alpha))
        .map_err(|e| format!("{model_path}: {e}"))?;

    let mut reader = csv::Reader::from_path(csv_path).map_err(|e| format!("{csv_path}: {e}"))?;
    let headers = reader.headers()?.clone();
    let column = |name: &str| headers.iter().position(|h| h.trim() == name);
    let v_col = column("velocity_m_s")
        .ok_or_else(|| format!("{csv_path}: no `velocity_m_s` column in {headers:?}"))?;
    let t_col = column("time_s");

    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    writeln!(out, "time_s,velocity_m_s,force_n,flags")?;
    for (i, record) in reader.records().enumerate() {
        // Line numbers count the header as line 1.
        let line = i + 2;
        let record = record.map_err(|e| format!("{csv_path}:{line}: {e}"))?;
        let field = |c: usize| record.get(c).map(str::trim).unwrap_or("");
        let v: f32 = field(v_col)
            .parse()
            .map_err(|e| format!("{csv_path}:{line}: velocity_m_s {:?}: {e}", field(v_col)))?;
        let t = t_col.map_or_else(
            || format!("{:.6}", i as f64 * f64::from(model.dt_s)),
            |c| field(c).to_string(),
        );
        let e = est.step(Sample::new(v)).unwrap();
        writeln!(out, "{t},{v},{},{}", e.force_n, e.flags.0)?;
    }
    out.flush()?;
    Ok(())
}
