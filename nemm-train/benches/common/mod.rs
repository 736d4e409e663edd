//! What the host benchmarks share: the dataset they run on.
use std::path::PathBuf;

/// The benchmark's dataset: `NEMM_BENCH_DATA`, or the default virtual bench (seed 1)
/// generated once into the temporary folder.
pub fn bench_data() -> PathBuf {
    let data = std::env::var_os("NEMM_BENCH_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("nemm-train-time-bench"));
    if !data.join("manifest.toml").exists() {
        nemm_train::cli::bench::generate(
            &nemm_virtual_bench::config::BenchConfig::default(),
            1,
            &data,
        )
        .expect("generate the default virtual bench");
    }
    data
}
