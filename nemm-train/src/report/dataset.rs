//! The reports of a dataset on the command line: the per-run table and the findings of
//! `nemm data check` ([`check_report`]) and the split of `nemm data prepare`
//! (`prepare_report`).
use crate::data::check::{self, Finding};
use crate::data::preprocess::{self, Prepared, RunRole, RunSummary, SplitCounts};
use nemm_dataset::{self as dataset, Dataset};
use std::fmt::Write as _;

/// Relative deviation from the manifest metadata above which `check` prints a note.
const METADATA_TOLERANCE: f64 = 0.05;

/// Findings of one kind and column printed before the rest are summarised in a count.
const FINDINGS_SHOWN: usize = 5;

/// The per-run table of `nemm data check`, notes on suspicious runs, and the plausibility
/// findings of `check::check_run` (problems, then information).
pub fn check_report(ds: &Dataset, runs: &[RunSummary], findings: &[Finding]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", header_line(ds));
    let _ = writeln!(
        s,
        "{:>4} {:>6} {:>8} {:>8} {:>10} {:>9} {:>8} {:>21} {:>6} {:>8} {:>10}  file",
        "#",
        "alpha",
        "ampl mm",
        "freq Hz",
        "vpeak m/s",
        "samples",
        "dur s",
        "force min..max N",
        "v",
        "fc Hz",
        "fc rule"
    );
    let mut notes = Vec::new();
    for r in runs {
        let e = &r.excitation;
        let _ = writeln!(
            s,
            "{:>4} {:>6} {:>8.2} {} {:>10.4} {:>9} {:>8.3} {:>10.1}..{:<10.1} {:>6} {:>8} {:>10}  {}",
            r.index,
            dataset::alpha_text(r.alpha),
            e.amplitude_m * 1e3,
            fmt_opt(e.frequency_hz, 8, 3),
            e.peak_velocity_m_s,
            r.samples,
            r.duration_s,
            r.force_min_n,
            r.force_max_n,
            if r.measured_velocity { "meas" } else { "d/dt" },
            r.cutoff.hz,
            r.cutoff.rule.describe(),
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
    let condition = ds.condition.clone().unwrap_or_default();
    let _ = writeln!(s, "{} levels:", condition.name);
    for a in preprocess::distinct_levels(runs.iter().map(|r| r.alpha)) {
        let at: Vec<&RunSummary> = runs
            .iter()
            .filter(|r| (r.alpha - a).abs() <= preprocess::ALPHA_TOLERANCE)
            .collect();
        let _ = writeln!(
            s,
            "  {}: {} runs, {:.1} s",
            condition.level(a),
            at.len(),
            at.iter().map(|r| r.duration_s).sum::<f64>()
        );
    }
    let (info, problems): (Vec<&Finding>, Vec<&Finding>) =
        findings.iter().partition(|f| f.kind.is_info());
    if notes.is_empty() && problems.is_empty() {
        let _ = writeln!(s, "no anomalies found");
    }
    if !notes.is_empty() {
        let _ = writeln!(s, "notes:");
        for n in notes {
            let _ = writeln!(s, "  {n}");
        }
    }
    if !problems.is_empty() {
        let _ = writeln!(s, "plausibility problems:");
        write_findings(&mut s, &problems);
    }
    if !info.is_empty() {
        let _ = writeln!(s, "information:");
        write_findings(&mut s, &info);
    }
    s
}

/// Writes findings, at most [`FINDINGS_SHOWN`] per kind and column, then a count of the rest.
fn write_findings(s: &mut String, findings: &[&Finding]) {
    let mut groups: Vec<((check::FindingKind, &str), Vec<&Finding>)> = Vec::new();
    for f in findings {
        let key = (f.kind, f.column.as_str());
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, g)) => g.push(f),
            None => groups.push((key, vec![f])),
        }
    }
    for ((kind, column), g) in groups {
        for f in g.iter().take(FINDINGS_SHOWN) {
            let _ = writeln!(s, "  {f}");
        }
        if g.len() > FINDINGS_SHOWN {
            let _ = writeln!(
                s,
                "  ... {kind} in {column} in {} more run(s)",
                g.len() - FINDINGS_SHOWN,
                kind = kind.name()
            );
        }
    }
}

/// The report of `nemm data prepare`.
pub(crate) fn prepare_report(ds: &Dataset, p: &Prepared) -> String {
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
        "scales (training set, abs-max): velocity {:.4} m/s, force {:.1} N, alpha {}",
        p.scales.velocity_m_s,
        p.scales.force_n,
        dataset::alpha_text(p.scales.alpha)
    );
    s
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
