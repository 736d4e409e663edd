//! The accuracy part of `nemm diagnose` (`accuracy.md`, `accuracy.json`), in two parts:
//!
//! - **The observer's own error** ([`RunError`]): per run, the online estimate against the
//!   same run's offline best fit from [`FROM_S`] on. The criterion: on every run the
//!   observer calls excited (its flag after the last sample), every estimate from
//!   [`FROM_S`] to the end is within [`AGREEMENT`] of the offline fit. A run no longer than
//!   [`FROM_S`] is judged by its final estimate, and says so.
//! - **The model's resolution in alpha** ([`Resolution`]): per test condition (amplitude and
//!   peak velocity of the manifest), the offline fit and the final online estimate of the
//!   run at each labelled level, and whether they are in the labels' order: the lowest level
//!   below the highest (strictly), the levels between them within that range.

use crate::report::diagnose::{RunDiagnosis, Trace, AGREEMENT};
use nemm_dataset::RunEntry;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// Time from a run's first sample from which the observer's estimate is judged \[s\].
pub(crate) const FROM_S: f64 = 2.0;

/// Marker of a run the observer does not call excited, in the resolution table.
pub(crate) const NOT_EXCITED: &str = "†";

/// `accuracy.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct AccuracyReport {
    /// [`FROM_S`].
    pub(crate) from_s: f64,
    /// [`AGREEMENT`].
    pub(crate) tolerance: f64,
    /// The observer's error per run, in the order of `diagnose.json`.
    pub(crate) runs: Vec<RunError>,
    /// The summary line of the observer's error ([`error_summary`]).
    pub(crate) summary: String,
    /// Its detail line ([`error_detail`]).
    pub(crate) detail: String,
    /// The model's resolution per condition.
    pub(crate) resolution: Resolution,
}

/// The observer's error on one run (see the module documentation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RunError {
    /// Run file, relative to the manifest.
    pub(crate) file: String,
    /// Length of the run \[s\].
    pub(crate) duration_s: f64,
    /// The observer's excited flag after the last sample.
    pub(crate) excited: bool,
    /// Its excited flag at [`FROM_S`] (after the last sample for a shorter run).
    pub(crate) excited_at_from: bool,
    /// The offline best fit (`None`: the model does not tell the levels apart on the run).
    pub(crate) alpha_offline: Option<f64>,
    /// The estimate at [`FROM_S`] (the final one for a shorter run).
    pub(crate) alpha_at_from: f64,
    /// The largest `|estimate - alpha_offline|` from [`FROM_S`] to the end (of the final
    /// estimate for a shorter run); `None` without an offline fit.
    pub(crate) worst_error: Option<f64>,
    /// The run is no longer than [`FROM_S`]: judged by its final estimate.
    pub(crate) short: bool,
    /// The observer's settled flag after the last sample.
    pub(crate) settled: bool,
    /// Share of the estimates from [`FROM_S`] on (the final one for a shorter run) that
    /// the observer calls valid: excited and settled.
    pub(crate) valid_share: f64,
    /// The largest `|estimate - alpha_offline|` over those valid estimates; `None` without
    /// an offline fit or without a valid estimate.
    pub(crate) worst_valid_error: Option<f64>,
}

impl RunError {
    /// The estimate stays within [`AGREEMENT`] of the offline fit (from [`FROM_S`] on).
    pub(crate) fn within(&self) -> bool {
        self.worst_error.is_some_and(|e| e <= AGREEMENT + 1e-9)
    }

    /// The estimates the observer calls valid stay within [`AGREEMENT`] of the offline fit
    /// from [`FROM_S`] on, and it ends settled.
    pub(crate) fn within_valid(&self) -> bool {
        self.settled
            && self
                .worst_valid_error
                .is_some_and(|e| e <= AGREEMENT + 1e-9)
    }
}

/// Rounds to 1e-4.
fn round4(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// The observer's error on the run `d` whose estimates are `trace`.
pub(crate) fn run_error(d: &RunDiagnosis, trace: &Trace) -> RunError {
    let n = trace.alpha.len();
    let from = (FROM_S / trace.dt_s).round() as usize;
    let short = from >= n;
    let k = if short { n.saturating_sub(1) } else { from };
    let at = |v: &[f32]| v.get(k).map_or(f64::NAN, |&a| f64::from(a));
    let worst_error = d.alpha_offline.map(|off| {
        let worst = trace.alpha[k.min(n)..]
            .iter()
            .map(|&a| (f64::from(a) - off).abs())
            .fold(0.0, f64::max);
        round4(worst)
    });
    let valid = |j: usize| {
        trace.excited.get(j).copied().unwrap_or(false)
            && trace.settled.get(j).copied().unwrap_or(false)
    };
    let tail = k.min(n)..n;
    let valid_count = tail.clone().filter(|&j| valid(j)).count();
    let worst_valid_error = d.alpha_offline.and_then(|off| {
        tail.clone()
            .filter(|&j| valid(j))
            .map(|j| (f64::from(trace.alpha[j]) - off).abs())
            .reduce(f64::max)
            .map(round4)
    });
    RunError {
        file: d.file.clone(),
        duration_s: round4(n as f64 * trace.dt_s),
        excited: d.excited,
        excited_at_from: trace.excited.get(k).copied().unwrap_or(false),
        alpha_offline: d.alpha_offline,
        alpha_at_from: round4(at(&trace.alpha)),
        worst_error,
        short,
        settled: trace.settled.last().copied().unwrap_or(false),
        valid_share: round4(valid_count as f64 / tail.len().max(1) as f64),
        worst_valid_error,
    }
}

/// `x` with 3 decimals, or `-`.
fn opt3(x: Option<f64>) -> String {
    x.map_or("-".into(), |v| format!("{v:.3}"))
}

/// `yes` or `no`.
fn yes_no(b: bool) -> &'static str {
    if b {
        "yes"
    } else {
        "no"
    }
}

/// The table of the observer's error, one row per run.
pub(crate) fn error_table(runs: &[RunError]) -> String {
    let mut s = format!(
        "| run | length [s] | excited (end) | excited at {FROM_S} s | offline | online at \
         {FROM_S} s | worst \\|online - offline\\| from {FROM_S} s | within {AGREEMENT} | \
         valid from {FROM_S} s | worst where valid | within where valid |\n\
         |---|---:|---|---|---:|---:|---:|---|---:|---:|---|\n"
    );
    for r in runs {
        let short = if r.short { " (end: run shorter)" } else { "" };
        let _ = writeln!(
            s,
            "| {} | {:.2} | {} | {} | {} | {:.3}{short} | {} | {} | {:.0} % | {} | {} |",
            r.file,
            r.duration_s,
            yes_no(r.excited),
            yes_no(r.excited_at_from),
            opt3(r.alpha_offline),
            r.alpha_at_from,
            opt3(r.worst_error),
            if r.excited {
                yes_no(r.within())
            } else {
                "(not excited)"
            },
            100.0 * r.valid_share,
            opt3(r.worst_valid_error),
            if r.excited {
                yes_no(r.within_valid())
            } else {
                "(not excited)"
            },
        );
    }
    s
}

/// The summary line: "N of M excited runs within 0.02 of the offline fit from 2 s on", with
/// how many runs were shorter, had no offline fit or were not excited.
pub(crate) fn error_summary(runs: &[RunError]) -> String {
    let excited: Vec<&RunError> = runs.iter().filter(|r| r.excited).collect();
    let within = excited.iter().filter(|r| r.within()).count();
    let mut notes = vec![format!("{} runs", runs.len())];
    notes.push(format!("{} not excited", runs.len() - excited.len()));
    let short = runs.iter().filter(|r| r.short).count();
    if short > 0 {
        notes.push(format!(
            "{short} no longer than {FROM_S} s, judged by their final estimate"
        ));
    }
    let no_fit = excited.iter().filter(|r| r.alpha_offline.is_none()).count();
    if no_fit > 0 {
        notes.push(format!("{no_fit} excited without an offline fit"));
    }
    format!(
        "{within} of {} excited runs within {AGREEMENT} of the offline fit from {FROM_S} s on \
         ({})",
        excited.len(),
        notes.join(", ")
    )
}

/// The detail line: how many excited runs are within [`AGREEMENT`] at [`FROM_S`] (at the end
/// of a shorter run), and how many of those the observer calls excited at [`FROM_S`] as well
/// as at the end stay within from [`FROM_S`] on.
pub(crate) fn error_detail(runs: &[RunError]) -> String {
    let excited: Vec<&RunError> = runs.iter().filter(|r| r.excited).collect();
    let at_from = excited
        .iter()
        .filter(|r| {
            r.alpha_offline
                .is_some_and(|a| (r.alpha_at_from - a).abs() <= AGREEMENT + 1e-9)
        })
        .count();
    let both: Vec<&&RunError> = excited.iter().filter(|r| r.excited_at_from).collect();
    format!(
        "At {FROM_S} s (the end of a shorter run): {at_from} of {} excited runs within \
         {AGREEMENT}. Excited at {FROM_S} s as well as at the end: {} of {} within from {FROM_S} \
         s on. Where the observer calls its estimate valid (excited and settled): {} of {} \
         excited runs within from {FROM_S} s on and settled at the end ({} settled at the end).",
        excited.len(),
        both.iter().filter(|r| r.within()).count(),
        both.len(),
        excited.iter().filter(|r| r.within_valid()).count(),
        excited.len(),
        excited.iter().filter(|r| r.settled).count(),
    )
}

/// The run at one level of one condition.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct LevelCell {
    /// Run file, relative to the manifest.
    pub(crate) file: String,
    /// Its offline best fit.
    pub(crate) alpha_offline: Option<f64>,
    /// The observer's final estimate.
    pub(crate) alpha_hat: f64,
    /// The observer's final excited flag.
    pub(crate) excited: bool,
}

/// One test condition: its runs, one per labelled level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ConditionRow {
    /// Stroke amplitude \[m\].
    pub(crate) amplitude_m: f64,
    /// Target peak velocity \[m/s\].
    pub(crate) velocity_m_s: f64,
    /// The run at each of [`Resolution::levels`] (`None`: no run at that level).
    pub(crate) cells: Vec<Option<LevelCell>>,
}

impl ConditionRow {
    /// Every level has a run and every run is excited.
    pub(crate) fn excited(&self) -> bool {
        self.cells
            .iter()
            .all(|c| c.as_ref().is_some_and(|c| c.excited))
    }

    /// The order of the offline fits (`offline`) or of the final estimates.
    pub(crate) fn order(&self, offline: bool) -> Order {
        let values: Option<Vec<f64>> = self
            .cells
            .iter()
            .map(|c| {
                let c = c.as_ref()?;
                if offline {
                    c.alpha_offline
                } else {
                    Some(c.alpha_hat)
                }
            })
            .collect();
        order(&values.unwrap_or_default())
    }
}

/// Whether a condition's values are in the order of its levels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub(crate) enum Order {
    /// The lowest level's value below the highest's, every other level's within them.
    #[serde(rename = "in-order")]
    Ordered,
    /// The lowest below the highest, a level between them outside that range.
    MiddleOutside,
    /// The lowest level's value not below the highest's.
    NotBelow,
    /// A level without a run or without a value (no offline fit).
    Incomplete,
}

/// The [`Order`] of values at levels in increasing order.
pub(crate) fn order(values: &[f64]) -> Order {
    let (Some(&lo), Some(&hi)) = (values.first(), values.last()) else {
        return Order::Incomplete;
    };
    if values.len() < 2 {
        Order::Incomplete
    } else if lo >= hi {
        Order::NotBelow
    } else if values[1..values.len() - 1]
        .iter()
        .all(|v| (lo..=hi).contains(v))
    {
        Order::Ordered
    } else {
        Order::MiddleOutside
    }
}

/// The model's resolution: per condition, the offline fit and the online estimate of the run
/// at each level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Resolution {
    /// The labelled levels, increasing.
    pub(crate) levels: Vec<f64>,
    /// The conditions, by decreasing amplitude, then increasing peak velocity.
    pub(crate) rows: Vec<ConditionRow>,
    /// Runs left out: without an amplitude or a peak velocity in the manifest, or a second
    /// run of the same condition and level.
    pub(crate) left_out: Vec<String>,
}

/// Two levels or conditions closer than this are the same.
const SAME: f64 = 1e-6;

/// The resolution table of the diagnosed runs `runs` with their manifest entries.
pub(crate) fn resolution(runs: &[(&RunDiagnosis, &RunEntry)]) -> Resolution {
    let mut levels: Vec<f64> = Vec::new();
    for (d, _) in runs {
        if !levels.iter().any(|l| (l - d.label).abs() < SAME) {
            levels.push(d.label);
        }
    }
    levels.sort_by(f64::total_cmp);
    let mut rows: Vec<ConditionRow> = Vec::new();
    let mut left_out = Vec::new();
    for (d, e) in runs {
        let (Some(a), Some(v)) = (e.amplitude_m, e.target_velocity_m_s) else {
            left_out.push(d.file.clone());
            continue;
        };
        let i = match rows
            .iter()
            .position(|r| (r.amplitude_m - a).abs() < SAME && (r.velocity_m_s - v).abs() < SAME)
        {
            Some(i) => i,
            None => {
                rows.push(ConditionRow {
                    amplitude_m: a,
                    velocity_m_s: v,
                    cells: vec![None; levels.len()],
                });
                rows.len() - 1
            }
        };
        let level = levels.iter().position(|l| (l - d.label).abs() < SAME);
        match level.map(|k| &mut rows[i].cells[k]) {
            Some(cell @ None) => {
                *cell = Some(LevelCell {
                    file: d.file.clone(),
                    alpha_offline: d.alpha_offline,
                    alpha_hat: d.alpha_hat,
                    excited: d.excited,
                });
            }
            _ => left_out.push(d.file.clone()),
        }
    }
    rows.sort_by(|p, q| {
        q.amplitude_m
            .total_cmp(&p.amplitude_m)
            .then(p.velocity_m_s.total_cmp(&q.velocity_m_s))
    });
    Resolution {
        levels,
        rows,
        left_out,
    }
}

/// A level as a percentage (`0.15` -> `15 %`).
pub(crate) fn percent(level: f64) -> String {
    format!("{} %", (level * 1000.0).round() / 10.0)
}

impl Resolution {
    /// The names of the ordering checks: "0 % below 30 %" and "15 % between them".
    fn check_names(&self) -> (String, String) {
        let names: Vec<String> = self.levels.iter().map(|&l| percent(l)).collect();
        let below = format!(
            "{} below {}",
            names.first().map_or("", String::as_str),
            names.last().map_or("", String::as_str)
        );
        let middle = names.get(1..names.len().saturating_sub(1)).unwrap_or(&[]);
        (below, format!("{} between them", middle.join(", ")))
    }

    /// The count lines of the ordering checks, for the offline fits and the final estimates.
    pub(crate) fn count_lines(&self) -> Vec<String> {
        if self.levels.len() < 2 || self.rows.is_empty() {
            return vec![format!(
                "No ordering check: {} labelled level(s), {} condition(s).",
                self.levels.len(),
                self.rows.len()
            )];
        }
        let (below, between) = self.check_names();
        let with_middle = self.levels.len() > 2;
        [(true, "Offline fit"), (false, "Online estimate (end)")]
            .iter()
            .map(|&(offline, what)| {
                let count = |excited_only: bool, ok: &dyn Fn(Order) -> bool| {
                    let rows: Vec<&ConditionRow> = self
                        .rows
                        .iter()
                        .filter(|r| !excited_only || r.excited())
                        .collect();
                    let n = rows.iter().filter(|r| ok(r.order(offline))).count();
                    format!("{n} of {}", rows.len())
                };
                let below_ok = |o| matches!(o, Order::Ordered | Order::MiddleOutside);
                let mut s = format!(
                    "{what}: {below} on {} excited conditions ({} conditions in all)",
                    count(true, &below_ok),
                    count(false, &below_ok)
                );
                if with_middle {
                    let in_order = |o| o == Order::Ordered;
                    let _ = write!(
                        s,
                        "; {between} on {} ({})",
                        count(true, &in_order),
                        count(false, &in_order)
                    );
                }
                s.push('.');
                s
            })
            .collect()
    }
}

/// An [`Order`] as a table cell.
fn order_cell(o: Order, r: &Resolution) -> String {
    let names: Vec<String> = r.levels.iter().map(|&l| percent(l)).collect();
    match o {
        Order::Ordered => "in order".into(),
        Order::MiddleOutside => format!(
            "{} outside",
            names[1..names.len().saturating_sub(1)].join(", ")
        ),
        Order::NotBelow => format!(
            "{} not below {}",
            names.first().map_or("", String::as_str),
            names.last().map_or("", String::as_str)
        ),
        Order::Incomplete => "-".into(),
    }
}

/// The resolution table: one row per condition, the offline fits and the final estimates at
/// every level (a non-excited run's estimate marked [`NOT_EXCITED`]), the orders, then the
/// count lines.
pub(crate) fn resolution_markdown(r: &Resolution) -> String {
    let names: Vec<String> = r.levels.iter().map(|&l| percent(l)).collect();
    let mut s = String::from("| amplitude [mm] | peak velocity [m/s] |");
    for n in &names {
        let _ = write!(s, " offline {n} |");
    }
    for n in &names {
        let _ = write!(s, " online {n} |");
    }
    s.push_str(" all excited | order offline | order online |\n|---:|---:|");
    s.push_str(&"---:|".repeat(2 * names.len()));
    s.push_str("---|---|---|\n");
    for row in &r.rows {
        let _ = write!(
            s,
            "| {} | {:.3} |",
            (row.amplitude_m * 1e4).round() / 10.0,
            row.velocity_m_s
        );
        for c in &row.cells {
            let _ = write!(s, " {} |", opt3(c.as_ref().and_then(|c| c.alpha_offline)));
        }
        for c in &row.cells {
            let cell = c.as_ref().map_or("-".into(), |c| {
                let mark = if c.excited { "" } else { NOT_EXCITED };
                format!("{:.3}{mark}", c.alpha_hat)
            });
            let _ = write!(s, " {cell} |");
        }
        let _ = writeln!(
            s,
            " {} | {} | {} |",
            yes_no(row.excited()),
            order_cell(row.order(true), r),
            order_cell(row.order(false), r)
        );
    }
    s.push('\n');
    for line in r.count_lines() {
        let _ = writeln!(s, "{line}");
    }
    if !r.left_out.is_empty() {
        let _ = writeln!(
            s,
            "\nLeft out (no amplitude or peak velocity in the manifest, or a second run of a \
             condition and level): {}.",
            r.left_out.join(", ")
        );
    }
    s
}

/// `accuracy.md`: both parts, each table with its caption and count lines.
pub(crate) fn accuracy_markdown(report: &AccuracyReport) -> String {
    format!(
        "**The observer's own error.** Per run: the estimate at {FROM_S} s and the largest \
         distance of the estimate from the run's offline best fit from {FROM_S} s to the end \
         (a run no longer than {FROM_S} s: its final estimate); the criterion is that every \
         run the observer calls excited (its flag after the last sample) stays within \
         {AGREEMENT}. The last three columns judge only the estimates the observer calls \
         valid (excited and settled): their share from {FROM_S} s on, their largest distance, \
         and whether they stay within {AGREEMENT} with the run ending settled.\n\n{}\n{}\n\n{}\n\n\
         **The model's resolution in alpha.** Per test condition (rows) and labelled level \
         (columns): the offline best fit and the observer's final estimate of the run \
         ({NOT_EXCITED}: not excited at the end); the order of each against the labels. A \
         condition is excited when all its runs are.\n\n{}",
        error_table(&report.runs),
        report.summary,
        report.detail,
        resolution_markdown(&report.resolution)
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use nemm_core::ObserverFlags;

    fn diagnosis(
        file: &str,
        label: f64,
        offline: Option<f64>,
        hat: f64,
        excited: bool,
    ) -> RunDiagnosis {
        RunDiagnosis {
            file: file.into(),
            label,
            alpha_hat: hat,
            band: 0.01,
            alpha_offline: offline,
            excited,
            settle_s: None,
        }
    }

    fn trace(alpha: Vec<f32>, dt_s: f64) -> Trace {
        let n = alpha.len();
        Trace {
            dt_s,
            band: vec![0.01; n],
            excited: (0..n).map(|k| k >= n / 2).collect(),
            settled: (0..n).map(|k| k + 1 >= n).collect(),
            alpha,
            first_update: Some(0),
            last_flags: ObserverFlags::default(),
        }
    }

    #[test]
    fn the_error_is_the_worst_from_two_seconds_on_or_the_final_one_of_a_short_run() {
        // 0.5 s per sample: sample 4 is at 2 s.
        let long = trace(vec![0.3, 0.3, 0.2, 0.2, 0.11, 0.13, 0.1], 0.5);
        let d = diagnosis("runs/a.csv", 0.15, Some(0.1), 0.1, true);
        let e = run_error(&d, &long);
        assert!(!e.short);
        assert_eq!(e.duration_s, 3.5);
        assert_eq!(e.alpha_at_from, 0.11);
        assert_eq!(e.worst_error, Some(0.03));
        assert!(!e.within() && e.excited_at_from);
        // Only the last estimate (0.1) is excited and settled: within where valid.
        assert_eq!((e.valid_share, e.worst_valid_error), (0.3333, Some(0.0)));
        assert!(e.within_valid());
        let short = trace(vec![0.3, 0.2, 0.11], 0.5);
        let e = run_error(&d, &short);
        assert!(e.short && e.within());
        assert_eq!((e.alpha_at_from, e.worst_error), (0.11, Some(0.01)));
        let no_fit = run_error(&diagnosis("runs/b.csv", 0.15, None, 0.1, true), &short);
        let not_excited = run_error(&diagnosis("runs/c.csv", 0.15, Some(0.3), 0.1, false), &long);
        let runs = [e, no_fit, not_excited];
        assert_eq!(
            error_detail(&runs),
            "At 2 s (the end of a shorter run): 1 of 2 excited runs within 0.02. Excited at \
             2 s as well as at the end: 1 of 2 within from 2 s on. Where the observer calls its \
             estimate valid (excited and settled): 1 of 2 excited runs within from 2 s on and \
             settled at the end (2 settled at the end)."
        );
        let summary = error_summary(&runs);
        assert_eq!(
            summary,
            "1 of 2 excited runs within 0.02 of the offline fit from 2 s on (3 runs, 1 not \
             excited, 2 no longer than 2 s, judged by their final estimate, 1 excited without \
             an offline fit)"
        );
    }

    #[test]
    fn orders_are_checked_on_the_labels_levels() {
        assert_eq!(order(&[0.0, 0.1, 0.2]), Order::Ordered);
        assert_eq!(order(&[0.0, 0.0, 0.2]), Order::Ordered);
        assert_eq!(order(&[0.0, 0.3, 0.2]), Order::MiddleOutside);
        assert_eq!(order(&[0.1, 0.05, 0.1]), Order::NotBelow);
        assert_eq!(order(&[0.1]), Order::Incomplete);
        assert_eq!(percent(0.15), "15 %");
        assert_eq!(percent(0.0), "0 %");
    }

    #[test]
    fn the_resolution_table_groups_the_runs_by_condition() {
        let entry = |a: Option<f64>, v: f64| RunEntry {
            file: "x".into(),
            oil_loss: 0.0,
            amplitude_m: a,
            target_velocity_m_s: Some(v),
        };
        let runs = [
            diagnosis("oil00_a.csv", 0.0, Some(0.0), 0.0, true),
            diagnosis("oil15_a.csv", 0.15, Some(0.1), 0.12, true),
            diagnosis("oil30_a.csv", 0.3, Some(0.25), 0.3, false),
            diagnosis("oil00_b.csv", 0.0, Some(0.1), 0.1, true),
            diagnosis("oil15_b.csv", 0.15, Some(0.0), 0.0, true),
            diagnosis("oil30_b.csv", 0.3, Some(0.2), 0.2, true),
            diagnosis("oil30_c.csv", 0.3, Some(0.2), 0.2, true),
            diagnosis("oil30_b2.csv", 0.3, Some(0.2), 0.2, true),
        ];
        let entries = [
            entry(Some(0.01), 0.5),
            entry(Some(0.01), 0.5),
            entry(Some(0.01), 0.5),
            entry(Some(0.05), 1.0),
            entry(Some(0.05), 1.0),
            entry(Some(0.05), 1.0),
            entry(None, 1.0),
            entry(Some(0.05), 1.0),
        ];
        let pairs: Vec<(&RunDiagnosis, &RunEntry)> = runs.iter().zip(&entries).collect();
        let r = resolution(&pairs);
        assert_eq!(r.levels, [0.0, 0.15, 0.3]);
        assert_eq!(r.left_out, ["oil30_c.csv", "oil30_b2.csv"]);
        // 50 mm first.
        assert_eq!(r.rows[0].amplitude_m, 0.05);
        assert!(r.rows[0].excited() && !r.rows[1].excited());
        assert_eq!(r.rows[0].order(true), Order::MiddleOutside);
        assert_eq!(r.rows[1].order(false), Order::Ordered);
        let md = resolution_markdown(&r);
        assert!(
            md.contains(
                "| 50 | 1.000 | 0.100 | 0.000 | 0.200 | 0.100 | 0.000 | 0.200 | yes | 15 % \
                 outside | 15 % outside |"
            ),
            "{md}"
        );
        assert!(
            md.contains("| 0.000 | 0.120 | 0.300† | no | in order | in order |"),
            "{md}"
        );
        assert!(
            md.contains(
                "Offline fit: 0 % below 30 % on 1 of 1 excited conditions (2 of 2 conditions \
                 in all); 15 % between them on 0 of 1 (1 of 2)."
            ),
            "{md}"
        );
    }
}
