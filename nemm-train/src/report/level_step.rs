//! A level step (`nemm diagnose --level-step A,B`, `level-step.json`): two runs of one
//! periodic test condition at different levels joined into one record whose level steps
//! where the second begins, and how fast the online estimate follows.
//!
//! **The record** ([`join`]). Each run's *steady part* ([`steady_part`]) is its trailing
//! stretch of full periods: from one rising crossing of the displacement's mid-range to the
//! last, every period between reaching at least [`FULL_PERIOD`] of the run's half-range on
//! both sides (the ramp-in's smaller periods are left out). The record is the first run from
//! its first sample to the end of its steady part, its steady part `repeat - 1` more times,
//! then the second run's steady part `repeat` times. Every join is at a rising crossing, so
//! the displacement is continuous up to one sample's travel (the largest jump is recorded)
//! and, the two runs being of one condition (their periods within [`SAME_PERIOD`] and
//! half-ranges within [`SAME_AMPLITUDE`] of each other, else the join is refused), so is the
//! velocity. Playing a steady part again stands for a longer record of the same periodic
//! state (the noise repeats with it); `repeat` = 1 is the two recorded runs as they are.
//!
//! **The figures** ([`LevelStep`]). The observer runs over the record as over a run
//! ([`crate::report::diagnose::observe`]); each run's offline best fit is that of the run
//! alone ([`crate::report::diagnose::diagnose_run`]). The estimate just before the step is
//! compared with the first run's fit; after the step, the time until it is first within
//! [`AGREEMENT`] of the second run's fit (`reach_s`), the time from which it stays
//! within to the end (`settle_s`), and the time until the observer first calls it valid
//! (excited and settled) within [`AGREEMENT`] of that fit (`valid_reach_s`).

use crate::data::preprocess::centred_record;
use crate::report::diagnose::{estimate_series, RunDiagnosis, Trace, AGREEMENT};
use crate::report::plot::{palette, Figure, LegendPosition, LinePanel, Series};
use anyhow::{bail, Result};
use nemm_dataset::Run;
use serde::{Deserialize, Serialize};

/// A period is full when it reaches this fraction of the run's half-range on both sides.
pub(crate) const FULL_PERIOD: f64 = 0.95;

/// Largest relative difference of the two runs' periods.
pub(crate) const SAME_PERIOD: f64 = 0.01;

/// Largest relative difference of the two runs' half-ranges.
pub(crate) const SAME_AMPLITUDE: f64 = 0.05;

/// The steady part of a run: samples `start..end`, `periods` full periods.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct SteadyPart {
    /// First sample (the first at or above the mid-range after a rising crossing).
    pub(crate) start: usize,
    /// One past the last sample (the first at or above the mid-range after the last rising
    /// crossing).
    pub(crate) end: usize,
    /// Full periods in it.
    pub(crate) periods: usize,
}

/// The [`SteadyPart`] of a displacement record; an error when it has no full period.
pub(crate) fn steady_part(displacement_m: &[f64]) -> Result<SteadyPart> {
    let c = centred_record(displacement_m);
    let rising: Vec<usize> = c
        .crossings
        .iter()
        .filter(|x| x.rising)
        .map(|x| (x.at.ceil() as usize).min(displacement_m.len()))
        .collect();
    let full = |w: &[usize]| {
        let (lo, hi) = c.y[w[0]..w[1]]
            .iter()
            .fold((0.0f64, 0.0f64), |(lo, hi), &y| (lo.min(y), hi.max(y)));
        hi >= FULL_PERIOD * c.half_range && -lo >= FULL_PERIOD * c.half_range
    };
    let periods = rising.windows(2).rev().take_while(|w| full(w)).count();
    if periods == 0 {
        bail!(
            "no full period (reaching {FULL_PERIOD} of the half-range on both sides between \
             two rising crossings) at the end of the record"
        );
    }
    Ok(SteadyPart {
        start: rising[rising.len() - 1 - periods],
        end: rising[rising.len() - 1],
        periods,
    })
}

/// A level-step record ([`join`]).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Joined {
    /// Displacement \[m\].
    pub(crate) displacement_m: Vec<f64>,
    /// Force \[N\].
    pub(crate) force_n: Vec<f64>,
    /// Index of the first sample of the second run.
    pub(crate) step: usize,
    /// The first run's steady part.
    pub(crate) first: SteadyPart,
    /// The second run's steady part.
    pub(crate) second: SteadyPart,
    /// The largest displacement jump at a join: the joined sample against the one that
    /// followed in the recorded run \[m\].
    pub(crate) jump_m: f64,
}

/// Mean period of a steady part \[samples\].
fn period(p: &SteadyPart) -> f64 {
    (p.end - p.start) as f64 / p.periods as f64
}

/// Joins run `a` and run `b` of one condition, each steady part played `repeat` times (see
/// the module documentation); an error when a run has no full period, the runs' periods or
/// half-ranges differ (not one condition) or `repeat` is 0.
pub(crate) fn join(a: &Run, b: &Run, repeat: usize) -> Result<Joined> {
    if repeat == 0 {
        bail!("the steady parts must be played at least once");
    }
    let part = |r: &Run| {
        steady_part(&r.displacement_m)
            .map_err(|e| anyhow::anyhow!("{}: {e}", r.entry.file.display()))
    };
    let (pa, pb) = (part(a)?, part(b)?);
    let (ta, tb) = (period(&pa), period(&pb));
    let (ra, rb) = (
        centred_record(&a.displacement_m).half_range,
        centred_record(&b.displacement_m).half_range,
    );
    if (ta / tb - 1.0).abs() > SAME_PERIOD || (ra / rb - 1.0).abs() > SAME_AMPLITUDE {
        bail!(
            "{} and {} are not one condition: periods {ta:.0} and {tb:.0} samples, \
             half-ranges {:.2} and {:.2} mm (at most {SAME_PERIOD} and {SAME_AMPLITUDE} apart)",
            a.entry.file.display(),
            b.entry.file.display(),
            ra * 1e3,
            rb * 1e3
        );
    }
    let mut pieces: Vec<(&Run, usize, usize)> = vec![(a, 0, pa.end)];
    pieces.extend((1..repeat).map(|_| (a, pa.start, pa.end)));
    pieces.extend((0..repeat).map(|_| (b, pb.start, pb.end)));
    let mut out = Joined {
        displacement_m: Vec::new(),
        force_n: Vec::new(),
        step: 0,
        first: pa,
        second: pb,
        jump_m: 0.0,
    };
    let mut next: Option<f64> = None;
    for (k, &(r, from, to)) in pieces.iter().enumerate() {
        if k == repeat {
            out.step = out.displacement_m.len();
        }
        if let Some(x) = next {
            out.jump_m = out.jump_m.max((r.displacement_m[from] - x).abs());
        }
        next = r.displacement_m.get(to).copied();
        out.displacement_m
            .extend_from_slice(&r.displacement_m[from..to]);
        out.force_n.extend_from_slice(&r.force_n[from..to]);
    }
    Ok(out)
}

/// One of the two runs of a level step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct StepRun {
    /// Run file, relative to the manifest.
    pub(crate) file: String,
    /// Its labelled level.
    pub(crate) label: f64,
    /// Its offline best fit (the run alone).
    pub(crate) alpha_offline: Option<f64>,
    /// Start and end of its steady part in the run \[s\].
    pub(crate) steady_s: [f64; 2],
    /// Full periods in the steady part.
    pub(crate) periods: usize,
}

/// `level-step.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct LevelStep {
    /// The run before the step.
    pub(crate) first: StepRun,
    /// The run after the step.
    pub(crate) second: StepRun,
    /// Times each steady part is played.
    pub(crate) repeat: usize,
    /// Time of the step from the record's start \[s\].
    pub(crate) step_s: f64,
    /// Length of the record \[s\].
    pub(crate) duration_s: f64,
    /// The largest displacement jump at a join \[m\].
    pub(crate) jump_m: f64,
    /// The estimate, band and excited flag at the last sample before the step.
    pub(crate) before: StepEstimate,
    /// The same after the last sample.
    pub(crate) end: StepEstimate,
    /// Time from the step until the estimate is first within [`AGREEMENT`] of the second
    /// run's offline fit \[s\]; `None`: never (or no fit).
    pub(crate) reach_s: Option<f64>,
    /// Time from the step after which the estimate stays within [`AGREEMENT`] of the second
    /// run's offline fit to the end \[s\]; `None`: not at the end (or no fit).
    pub(crate) settle_s: Option<f64>,
    /// Time from the step until the first estimate the observer calls valid (excited and
    /// settled) within [`AGREEMENT`] of the second run's offline fit \[s\]; `None`: never
    /// (or no fit).
    pub(crate) valid_reach_s: Option<f64>,
}

/// The observer's output at one sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct StepEstimate {
    /// Estimate.
    pub(crate) alpha: f64,
    /// Band (half-width).
    pub(crate) band: f64,
    /// Excited flag.
    pub(crate) excited: bool,
}

/// Rounds to 1e-4.
fn round4(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// The observer's output at sample `k` of `trace`.
fn estimate_at(trace: &Trace, k: usize) -> StepEstimate {
    StepEstimate {
        alpha: round4(f64::from(trace.alpha[k])),
        band: round4(f64::from(trace.band[k])),
        excited: trace.excited[k],
    }
}

/// The first sample from `from` on within `tol` of `target`, and the first from which every
/// sample to the end is (`None` when the last is not).
pub(crate) fn reach_and_settle(
    alpha: &[f32],
    target: f64,
    tol: f64,
    from: usize,
) -> (Option<usize>, Option<usize>) {
    let near = |a: &f32| (f64::from(*a) - target).abs() <= tol + 1e-9;
    let tail = alpha.get(from..).unwrap_or(&[]);
    let reach = tail.iter().position(near).map(|k| from + k);
    let settle = match tail.iter().rposition(|a| !near(a)) {
        None if !tail.is_empty() => Some(from),
        Some(j) if j + 1 < tail.len() => Some(from + j + 1),
        _ => None,
    };
    (reach, settle)
}

/// The level step of the record `joined` (of the runs diagnosed as `first` and `second`)
/// whose estimates are `trace`.
pub(crate) fn level_step(
    joined: &Joined,
    runs: [(&RunDiagnosis, &SteadyPart); 2],
    trace: &Trace,
    repeat: usize,
) -> LevelStep {
    let dt = trace.dt_s;
    let step_run = |(d, p): (&RunDiagnosis, &SteadyPart)| StepRun {
        file: d.file.clone(),
        label: d.label,
        alpha_offline: d.alpha_offline,
        steady_s: [round4(p.start as f64 * dt), round4(p.end as f64 * dt)],
        periods: p.periods,
    };
    let (reach, settle) = runs[1].0.alpha_offline.map_or((None, None), |target| {
        reach_and_settle(&trace.alpha, target, AGREEMENT, joined.step)
    });
    let valid_reach = runs[1].0.alpha_offline.and_then(|target| {
        (joined.step..trace.alpha.len()).find(|&k| {
            trace.excited[k]
                && trace.settled[k]
                && (f64::from(trace.alpha[k]) - target).abs() <= AGREEMENT + 1e-9
        })
    });
    let after = |k: Option<usize>| k.map(|k| round4((k - joined.step) as f64 * dt));
    let n = trace.alpha.len();
    LevelStep {
        first: step_run(runs[0]),
        second: step_run(runs[1]),
        repeat,
        step_s: round4(joined.step as f64 * dt),
        duration_s: round4(n as f64 * dt),
        jump_m: (joined.jump_m * 1e7).round() / 1e7,
        before: estimate_at(trace, joined.step.saturating_sub(1)),
        end: estimate_at(trace, n - 1),
        reach_s: after(reach),
        settle_s: after(settle),
        valid_reach_s: after(valid_reach),
    }
}

/// `x` with 3 decimals, or `-`.
fn opt3(x: Option<f64>) -> String {
    x.map_or("-".into(), |v| format!("{v:.3}"))
}

/// How the estimate followed the step: when it first came within [`AGREEMENT`] of the second
/// run's fit and from when it stayed within.
fn follow_text(s: &LevelStep) -> String {
    let valid = match s.valid_reach_s {
        Some(v) => format!(
            "; the observer first calls it valid (excited and settled) within {AGREEMENT} \
             {v:.2} s after the step"
        ),
        None => format!("; the observer never calls it valid within {AGREEMENT}"),
    };
    let followed = match (s.reach_s, s.settle_s) {
        (None, _) => format!("never within {AGREEMENT} of the second run's fit"),
        (Some(r), None) => format!(
            "first within {AGREEMENT} of the second run's fit {r:.2} s after the step, but \
             not at the end"
        ),
        (Some(r), Some(t)) => format!(
            "first within {AGREEMENT} of the second run's fit {r:.2} s after the step, and \
             from {t:.2} s after the step to the end"
        ),
    };
    followed + &valid
}

/// An estimate as `0.123 ± 0.020 (excited)`.
fn estimate_text(e: &StepEstimate) -> String {
    let ex = if e.excited { "excited" } else { "not excited" };
    format!("{:.3} ± {:.3} ({ex})", e.alpha, e.band)
}

/// `level-step.md`: what the record is and how the estimate followed the step.
pub(crate) fn level_step_markdown(s: &LevelStep) -> String {
    format!(
        "**Level step**: `{}` (label {:.2}, offline fit {}) joined at a rising crossing to \
         `{}` (label {:.2}, offline fit {}), each run's steady part ({} and {} full periods) \
         played {} time(s): step at {:.2} s of a {:.2} s record, largest displacement jump at \
         a join {:.1} um. Just before the step the estimate is {}; after it, {}. At the end: \
         {}.\n",
        s.first.file,
        s.first.label,
        opt3(s.first.alpha_offline),
        s.second.file,
        s.second.label,
        opt3(s.second.alpha_offline),
        s.first.periods,
        s.second.periods,
        s.repeat,
        s.step_s,
        s.duration_s,
        s.jump_m * 1e6,
        estimate_text(&s.before),
        follow_text(s),
        estimate_text(&s.end),
    )
}

/// The level-step figure: the estimate with its band, each run's offline fit as a dashed
/// line over its part of the record, vertical lines at the step and where the estimate
/// settles within [`AGREEMENT`] of the second fit; the levels axis spans `range` and the fits.
pub(crate) fn level_step_figure(s: &LevelStep, trace: &Trace, range: (f64, f64)) -> Figure {
    let fits = [s.first.alpha_offline, s.second.alpha_offline];
    let lo = fits.iter().flatten().fold(range.0, |m, &a| m.min(a)) - 0.05;
    let hi = fits.iter().flatten().fold(range.1, |m, &a| m.max(a)) + 0.05;
    let mut panel = LinePanel::new(
        "online estimate with its band; offline fit of each run; | step, settled",
        "time [s]",
        "alpha [-]",
    )
    .with_x_range(0.0, s.duration_s.max(trace.dt_s))
    .with_y_range(lo, hi + 0.12)
    .with_legend(LegendPosition::UpperLeft);
    let label = format!("online: {:.3} ± {:.3} at the end", s.end.alpha, s.end.band);
    for series in estimate_series(trace, label, (lo, hi)) {
        panel = panel.with_series(series);
    }
    let spans = [(0.0, s.step_s), (s.step_s, s.duration_s)];
    for (k, (run, (t0, t1))) in [&s.first, &s.second].into_iter().zip(spans).enumerate() {
        if let Some(a) = run.alpha_offline {
            panel = panel.with_series(Series::dashed(
                format!("offline fit {a:.3}: {}", run.file),
                vec![(t0, a), (t1, a)],
                palette::categorical(k + 1),
            ));
        }
    }
    panel.reference_x.push(s.step_s);
    panel.reference_x.extend(s.settle_s.map(|t| s.step_s + t));
    Figure::new(1, 1)
        .with_panel_size(860, 420)
        .with_title(format!(
            "Level step: {} then {}",
            s.first.file, s.second.file
        ))
        .with_footer(format!(
            "Before the step: {}.\nAfter it: {}.\n\
             Each steady part played {} time(s); largest displacement jump at a join {:.1} um.",
            estimate_text(&s.before),
            follow_text(s),
            s.repeat,
            s.jump_m * 1e6,
        ))
        .with_panel(panel)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nemm_dataset::RunEntry;

    /// A run of `n` samples of a sine of `period` samples and amplitude 10 mm, ramped in over
    /// the first two periods; the force is `level` everywhere.
    fn run(file: &str, n: usize, period: f64, level: f64) -> Run {
        let x: Vec<f64> = (0..n)
            .map(|k| {
                let t = k as f64 / period;
                0.01 * (t / 2.0).min(1.0) * (std::f64::consts::TAU * t).sin()
            })
            .collect();
        Run {
            entry: RunEntry {
                file: file.into(),
                oil_loss: level,
                amplitude_m: None,
                target_velocity_m_s: None,
            },
            time_s: (0..n).map(|k| k as f64).collect(),
            force_n: vec![level; n],
            displacement_m: x,
            velocity_m_s: None,
            alpha: None,
        }
    }

    #[test]
    fn the_steady_part_is_the_trailing_stretch_of_full_periods() {
        // 100 samples per period, 7.5 periods: full from period 2 on, the half period at the
        // end left out.
        let r = run("a.csv", 750, 100.0, 0.0);
        let p = steady_part(&r.displacement_m).expect("steady part");
        assert_eq!(p.periods, 5);
        assert_eq!((p.start, p.end), (200, 700));
        assert!(steady_part(&[0.0; 50]).is_err());
    }

    #[test]
    fn the_join_repeats_the_steady_parts_and_refuses_two_conditions() {
        let a = run("a.csv", 750, 100.0, 0.0);
        let b = run("b.csv", 650, 100.0, 1.0);
        let j = join(&a, &b, 2).expect("join");
        // a to 700, a's 500 again, b's 400 twice.
        assert_eq!(j.step, 1200);
        assert_eq!(j.displacement_m.len(), 2000);
        assert_eq!(j.second.periods, 4);
        assert!(j.force_n[..1200].iter().all(|&f| f == 0.0));
        assert!(j.force_n[1200..].iter().all(|&f| f == 1.0));
        assert!(j.jump_m < 1e-12, "{}", j.jump_m);
        let slower = run("c.csv", 900, 120.0, 1.0);
        let e = join(&a, &slower, 1).expect_err("two conditions");
        assert!(e.to_string().contains("not one condition"), "{e}");
        assert!(join(&a, &b, 0).is_err());
    }

    #[test]
    fn reaching_and_settling_count_from_the_step() {
        let a = [0.0f32, 0.0, 0.2, 0.29, 0.25, 0.31, 0.3];
        assert_eq!(reach_and_settle(&a, 0.3, 0.02, 1), (Some(3), Some(5)));
        assert_eq!(reach_and_settle(&a, 0.0, 0.02, 0), (Some(0), None));
        assert_eq!(reach_and_settle(&a, 0.3, 0.5, 2), (Some(2), Some(2)));
    }
}
