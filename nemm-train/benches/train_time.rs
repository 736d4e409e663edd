//! Wall time of training the default NEMM on the default virtual bench, per epoch and in
//! total (a benchmark that prints, not a timed test).
//!
//! ```text
//! cargo bench -p nemm-train --bench train_time            # generates the bench data if needed
//! NEMM_BENCH_DATA=DIR cargo bench -p nemm-train --bench train_time
//! ```
//!
//! Default settings of `nemm train --variant nemm` (section 5.4: batch 16, H 16, L 5, lr 5e-3,
//! RK4 at 10 kHz, lambda_ph 5), all epochs up to early stopping. Target: <= 10 minutes on
//! 2 cores.
mod common;

use nemm_core::ModelKind;
use nemm_train::config::Config;
use nemm_train::train::pipeline::{train_variants, PipelineConfig};
use std::time::Instant;

fn main() {
    // `cargo bench` passes `--bench`; nothing else is accepted.
    let data = common::bench_data();
    let config = Config::default();
    let prepared =
        nemm_train::data::load_prepared(&data, &config.data.prepare_config()).expect("dataset");
    let cfg = PipelineConfig::of(&config);
    let t = Instant::now();
    let trained = train_variants(&prepared, &[ModelKind::Nemm], &cfg, None, false).expect("train");
    let total = t.elapsed().as_secs_f64();
    let nemm = trained
        .iter()
        .find(|t| t.variant == ModelKind::Nemm)
        .expect("nemm");
    let epochs = nemm.history.len();
    let epoch_s: f64 = nemm.history.iter().map(|e| e.seconds).sum::<f64>() / epochs.max(1) as f64;
    println!(
        "train-time variant=nemm threads={} windows={} epochs={} seconds_per_epoch={:.2} total_seconds={:.1} val_rmse={:.4}",
        rayon::current_num_threads(),
        prepared.train.len(),
        epochs,
        epoch_s,
        total,
        nemm.val_rmse
    );
}
