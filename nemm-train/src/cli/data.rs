//! `nemm data check` and `nemm data prepare`: validate a bench dataset and show what the
//! preprocessing of section 5.3 makes of it.
use crate::config::{resolve_data, DataArgs};
use crate::data::dataset::{self, Dataset};
use crate::data::preprocess::{
    self, PrepareConfig, RunRole, RunSummary, SignalConfig, SplitCounts,
};
use anyhow::{Context, Result};
use std::fmt::Write as _;
use std::io::{IsTerminal, Write as _};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Relative deviation from the manifest metadata above which `check` prints a note.
const METADATA_TOLERANCE: f64 = 0.05;

/// `nemm data ...`
#[derive(Debug, Clone, clap::Subcommand)]
pub enum DataCmd {
    /// Load and validate a dataset folder; print a per-run table (oil loss, amplitude,
    /// frequency, peak velocity, samples, duration, force range).
    Check {
        /// Dataset folder (with manifest.toml).
        dir: PathBuf,
        /// Data options.
        #[command(flatten)]
        data: DataArgs,
    },
    /// Split, cut into sequences, scale and extract quasi-static points; print the counts.
    Prepare {
        /// Dataset folder (with manifest.toml).
        dir: PathBuf,
        /// Also write a JSON summary (configuration, counts, scales, per-run facts).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write the resolved data options to DIR/nemm-data.toml, which every command reading
        /// this dataset then uses (options given on a command line still override it).
        #[arg(long)]
        save_options: bool,
        /// Quasi-static window half-width, as a fraction of the amplitude.
        #[arg(long, default_value_t = preprocess::DEFAULT_QS_WINDOW)]
        qs_window: f64,
        /// Low-pass the training force as well (default: raw force).
        #[arg(long)]
        filter_force: bool,
        /// Data options.
        #[command(flatten)]
        data: DataArgs,
    },
}

/// Runs a `nemm data` subcommand.
pub fn run(cmd: DataCmd) -> Result<()> {
    match cmd {
        DataCmd::Check { dir, data } => {
            let resolved = resolve_data(&data.with_dir(&dir))?;
            let mut signal = resolved.config.prepare_config().signal;
            signal.filter_force = false;
            check(&dir, &signal)
        }
        DataCmd::Prepare {
            dir,
            out,
            save_options,
            qs_window,
            filter_force,
            data,
        } => {
            let resolved = resolve_data(&data.with_dir(&dir))?;
            let mut config = resolved.config.prepare_config();
            config.signal.filter_force = filter_force;
            config.quasi_static_window = Some(qs_window);
            prepare(&dir, &config, out.as_deref())?;
            if save_options {
                let path = resolved.config.save_options_file(&dir)?;
                println!("data options written to {}", path.display());
            }
            Ok(())
        }
    }
}

/// Loads a dataset, showing progress on a terminal.
pub fn load_with_progress(dir: &Path) -> Result<Dataset> {
    let tty = std::io::stderr().is_terminal();
    let start = Instant::now();
    let ds = dataset::load_with_progress(dir, |p| {
        if tty {
            eprint!(
                "\rloading: {}/{} runs, {:.2} M samples",
                p.runs_done,
                p.runs_total,
                p.samples_done as f64 / 1e6
            );
            let _ = std::io::stderr().flush();
        }
    });
    if tty {
        eprint!("\r\x1b[K");
    }
    let ds = ds.with_context(|| format!("dataset {} is not valid", dir.display()))?;
    eprintln!(
        "loaded {} runs, {} samples in {:.2} s",
        ds.runs.len(),
        ds.total_samples(),
        start.elapsed().as_secs_f64()
    );
    Ok(ds)
}

fn header_line(ds: &Dataset) -> String {
    let total = ds.total_samples();
    format!(
        "dataset \"{}\": {} runs at {} Hz (dt = {} s), {} samples = {:.1} s",
        ds.name,
        ds.runs.len(),
        ds.sample_rate_hz,
        ds.dt_s(),
        total,
        total as f64 * ds.dt_s()
    )
}

fn fmt_opt(v: Option<f64>, width: usize, prec: usize) -> String {
    match v {
        Some(v) => format!("{v:>width$.prec$}"),
        None => format!("{:>width$}", "-"),
    }
}

/// The per-run table of `nemm data check`, and notes on suspicious runs.
pub fn check_report(ds: &Dataset, runs: &[RunSummary]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", header_line(ds));
    let _ = writeln!(
        s,
        "{:>4} {:>6} {:>8} {:>8} {:>10} {:>9} {:>8} {:>21} {:>6}  file",
        "#",
        "alpha",
        "ampl mm",
        "freq Hz",
        "vpeak m/s",
        "samples",
        "dur s",
        "force min..max N",
        "v"
    );
    let mut notes = Vec::new();
    for r in runs {
        let e = &r.excitation;
        let _ = writeln!(
            s,
            "{:>4} {:>6.3} {:>8.2} {} {:>10.4} {:>9} {:>8.3} {:>10.1}..{:<10.1} {:>6}  {}",
            r.index,
            r.alpha,
            e.amplitude_m * 1e3,
            fmt_opt(e.frequency_hz, 8, 3),
            e.peak_velocity_m_s,
            r.samples,
            r.duration_s,
            r.force_min_n,
            r.force_max_n,
            if r.measured_velocity { "meas" } else { "d/dt" },
            r.file.display()
        );
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
        if let Some(a) = r.manifest_amplitude_m {
            if rel(e.amplitude_m, a) > METADATA_TOLERANCE {
                notes.push(format!(
                    "run {}: estimated amplitude {:.2} mm differs from amplitude_m = {:.2} mm",
                    r.index,
                    e.amplitude_m * 1e3,
                    a * 1e3
                ));
            }
        }
        if let Some(v) = r.manifest_target_velocity_m_s {
            if rel(e.peak_velocity_m_s, v) > METADATA_TOLERANCE {
                notes.push(format!(
                    "run {}: estimated peak velocity {:.4} m/s differs from target_velocity_m_s = {v} m/s",
                    r.index, e.peak_velocity_m_s
                ));
            }
        }
        if let Some(m) = r.measured_velocity_mismatch {
            if m > METADATA_TOLERANCE {
                notes.push(format!(
                    "run {}: the velocity_m_s column differs from d/dt displacement by {:.1} % RMS \
                     (units or sign?)",
                    r.index,
                    m * 100.0
                ));
            }
        }
        if e.frequency_hz.is_none() {
            notes.push(format!(
                "run {}: less than one stroke cycle; frequency unknown",
                r.index
            ));
        }
    }
    let _ = writeln!(s, "oil-loss levels:");
    for a in preprocess::distinct_levels(runs.iter().map(|r| r.alpha)) {
        let at: Vec<&RunSummary> = runs
            .iter()
            .filter(|r| (r.alpha - a).abs() <= preprocess::ALPHA_TOLERANCE)
            .collect();
        let _ = writeln!(
            s,
            "  alpha {a:.3}: {} runs, {:.1} s",
            at.len(),
            at.iter().map(|r| r.duration_s).sum::<f64>()
        );
    }
    if notes.is_empty() {
        let _ = writeln!(s, "no anomalies found");
    } else {
        let _ = writeln!(s, "notes:");
        for n in notes {
            let _ = writeln!(s, "  {n}");
        }
    }
    s
}

fn check(dir: &Path, cfg: &SignalConfig) -> Result<()> {
    let ds = load_with_progress(dir)?;
    let runs = preprocess::summarize(&ds, cfg)?;
    print!("{}", check_report(&ds, &runs));
    Ok(())
}

/// The report of `nemm data prepare`.
pub fn prepare_report(ds: &Dataset, p: &preprocess::Prepared) -> String {
    let sum = p.summary(&ds.name);
    let mut s = String::new();
    let _ = writeln!(s, "{}", header_line(ds));
    let _ = writeln!(s, "split: {}", p.config.split.describe());
    let _ = writeln!(
        s,
        "sequences: {} + {} warm-up samples ({} s + {} s at dt = {} s)",
        p.scored_samples,
        p.warmup_samples,
        p.scored_samples as f64 * p.dt_s,
        p.warmup_samples as f64 * p.dt_s,
        p.dt_s
    );
    let _ = writeln!(
        s,
        "{:<11} {:>5} {:>10} {:>10} {:>10}",
        "", "runs", "sequences", "scored s", "qs points"
    );
    let row = |s: &mut String, name: &str, c: &SplitCounts| {
        let _ = writeln!(
            s,
            "{name:<11} {:>5} {:>10} {:>10.1} {:>10}",
            c.runs,
            c.sequences,
            c.scored_samples as f64 * p.dt_s,
            c.quasi_static_points
        );
    };
    row(&mut s, "train", &sum.train);
    row(&mut s, "validation", &sum.validation);
    row(&mut s, "test", &sum.test);
    let unscored: usize = p
        .runs
        .iter()
        .filter(|r| r.role != RunRole::Unused)
        .map(|r| r.unscored_samples)
        .sum();
    let short: Vec<String> = p
        .runs
        .iter()
        .filter(|r| {
            r.role != RunRole::Unused
                && r.train_sequences + r.validation_sequences + r.test_sequences == 0
        })
        .map(|r| r.summary.index.to_string())
        .collect();
    let _ = writeln!(
        s,
        "unused runs: {}; samples not scored (first warm-up and tails): {unscored}",
        sum.unused_runs
    );
    if !short.is_empty() {
        let _ = writeln!(s, "runs too short for one sequence: {}", short.join(", "));
    }
    let _ = writeln!(
        s,
        "scales (training set, abs-max): velocity {} m/s, force {} N, alpha {}",
        p.scales.velocity_m_s, p.scales.force_n, p.scales.alpha
    );
    s
}

fn prepare(dir: &Path, config: &PrepareConfig, out: Option<&Path>) -> Result<()> {
    let ds = load_with_progress(dir)?;
    let prepared = preprocess::prepare(&ds, config).context("preprocessing failed")?;
    print!("{}", prepare_report(&ds, &prepared));
    if let Some(out) = out {
        let json = serde_json::to_string_pretty(&prepared.summary(&ds.name))?;
        std::fs::write(out, json + "\n")
            .with_context(|| format!("cannot write {}", out.display()))?;
        println!("summary written to {}", out.display());
    }
    Ok(())
}
