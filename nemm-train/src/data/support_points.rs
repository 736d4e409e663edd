//! Excitation of any kind: whether a run is periodic, and the quasi-static support points of
//! the flow-force model (SEM, `b_fl` regression) from periodic and non-periodic runs alike.
//! The rules are documented in `docs/preprocessing.md` ("Periodic runs", "Quasi-static
//! points").
//!
//! * **Periodicity** ([`periodicity`]): a run is periodic when its manifest entry gives both
//!   `amplitude_m` and `target_velocity_m_s` (a sine of frequency `v / (2 pi A)`), or when the
//!   zero crossings of the displacement (about its mid-range, hysteresis 10 % of the
//!   half-range) are regular: at least `MIN_INTERVALS` intervals between consecutive
//!   crossings all within `PERIOD_TOLERANCE` of their median (the half period), or else at
//!   least `MIN_INTERVALS` intervals between every other crossing (full periods, for
//!   asymmetric strokes) all within that tolerance of their median.
//! * **Support points of a periodic run**: the paper's rule, [`quasi_static_points`] (the
//!   extreme force within +-5 % of the amplitude around each centre crossing).
//! * **Support points of a non-periodic run** ([`low_acceleration_points`]): the samples whose
//!   `|a|` is at most `window` times the run's reference acceleration (the 99th percentile of
//!   `|a|`), grouped in velocity bins; per bin with at least `MIN_BIN_SAMPLES` samples one
//!   point at the median velocity and the median filtered force; then the points of each
//!   direction are made monotone in velocity (pool-adjacent-violators, weighted by the
//!   sample counts). For a sine, `|a| <= window a_max` is `|x| <= window A`: the same samples
//!   as the paper's window.

use super::preprocess::{
    median, quasi_static_points, zero_crossings, Direction, Excitation, QuasiStaticPoint, Signals,
};
use nemm_dataset::Run;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Fewest intervals between zero crossings that make a run periodic without manifest
/// metadata.
pub(crate) const MIN_INTERVALS: usize = 2;
/// Largest relative deviation of a period from the median period of a periodic run.
pub(crate) const PERIOD_TOLERANCE: f64 = 0.05;
/// Velocity bins per direction of [`low_acceleration_points`].
pub(crate) const VELOCITY_BINS: usize = 12;
/// Fewest low-acceleration samples that make a velocity bin a support point.
pub(crate) const MIN_BIN_SAMPLES: usize = 5;
/// Quantile of `|a|` that is the run's reference acceleration.
pub(crate) const REFERENCE_QUANTILE: f64 = 0.99;

/// Where a run's period comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PeriodSource {
    /// `target_velocity_m_s / (2 pi amplitude_m)` of the manifest entry.
    Manifest,
    /// Regular rising zero crossings of the displacement.
    ZeroCrossings,
}

/// The period of a periodic run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Periodicity {
    /// Frequency \[Hz\].
    pub frequency_hz: f64,
    /// Where it comes from.
    pub source: PeriodSource,
}

/// The median of `d` if every entry lies within [`PERIOD_TOLERANCE`] of it.
fn regular(d: &[f64]) -> Option<f64> {
    let m = median(d.to_vec())?;
    (m > 0.0 && d.iter().all(|x| (x - m).abs() <= PERIOD_TOLERANCE * m)).then_some(m)
}

/// The period of a run, or `None` when it is not periodic (see the module docs).
/// `displacement_m` is the run's (filtered) displacement.
pub fn periodicity(run: &Run, displacement_m: &[f64], sample_rate_hz: f64) -> Option<Periodicity> {
    if let (Some(a), Some(v)) = (run.entry.amplitude_m, run.entry.target_velocity_m_s) {
        if a > 0.0 && v > 0.0 && a.is_finite() && v.is_finite() {
            return Some(Periodicity {
                frequency_hz: v / (2.0 * PI * a),
                source: PeriodSource::Manifest,
            });
        }
    }
    let (lo, hi) = displacement_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
            (l.min(x), h.max(x))
        });
    let half = 0.5 * (hi - lo);
    if half.is_nan() || half <= super::preprocess::MIN_STROKE_M {
        return None;
    }
    let mid = 0.5 * (hi + lo);
    let y: Vec<f64> = displacement_m.iter().map(|x| x - mid).collect();
    let c: Vec<f64> = zero_crossings(&y, 0.1 * half)
        .iter()
        .map(|c| c.at)
        .collect();
    // Half periods between consecutive crossings (symmetric strokes, from 1.5 crossings' worth
    // of signal), else full periods between crossings of the same direction.
    let halves: Vec<f64> = c.windows(2).map(|w| w[1] - w[0]).collect();
    let fulls: Vec<f64> = c.windows(3).map(|w| w[2] - w[0]).collect();
    let period = if halves.len() >= MIN_INTERVALS {
        regular(&halves).map(|h| 2.0 * h)
    } else {
        None
    }
    .or_else(|| {
        if fulls.len() >= MIN_INTERVALS {
            regular(&fulls)
        } else {
            None
        }
    })?;
    Some(Periodicity {
        frequency_hz: sample_rate_hz / period,
        source: PeriodSource::ZeroCrossings,
    })
}

/// The `q`-quantile of `|x|` (nearest rank).
fn abs_quantile(x: &[f64], q: f64) -> f64 {
    let mut a: Vec<f64> = x.iter().map(|v| v.abs()).collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f64::total_cmp);
    let k = ((q * a.len() as f64).ceil() as usize).clamp(1, a.len()) - 1;
    a[k]
}

/// Weighted pool-adjacent-violators: the non-decreasing sequence closest to `y` in the
/// weighted least-squares sense.
fn isotonic(y: &[f64], w: &[f64]) -> Vec<f64> {
    // Blocks of (mean, weight, count).
    let mut blocks: Vec<(f64, f64, usize)> = Vec::new();
    for (&yi, &wi) in y.iter().zip(w) {
        blocks.push((yi, wi, 1));
        while blocks.len() > 1 {
            let n = blocks.len();
            let (b, a) = (blocks[n - 1], blocks[n - 2]);
            if a.0 <= b.0 {
                break;
            }
            let wsum = a.1 + b.1;
            let merged = ((a.0 * a.1 + b.0 * b.1) / wsum, wsum, a.2 + b.2);
            blocks.truncate(n - 2);
            blocks.push(merged);
        }
    }
    blocks
        .iter()
        .flat_map(|&(m, _, c)| std::iter::repeat_n(m, c))
        .collect()
}

/// Support points of a run of any excitation by the low-acceleration rule (see the module
/// docs). `window` is the fraction of the reference acceleration (the same number as the
/// paper's +-5 % displacement window). `side(sample)` splits the samples into two groups
/// (e.g. validation windows and the rest) that are binned separately, so that every point is
/// built from samples of one group. A point's `sample` is the sample of its median force;
/// its `amplitude_m` is 0 and `frequency_hz` `None` (no period).
pub fn low_acceleration_points(
    run_index: usize,
    signals: &Signals,
    alpha: f64,
    window: f64,
    side: &dyn Fn(usize) -> bool,
) -> Vec<QuasiStaticPoint> {
    let a = &signals.acceleration_m_s2;
    let v = &signals.velocity_m_s;
    let f = &signals.force_filtered_n;
    let n = a.len().min(v.len()).min(f.len());
    let a_ref = abs_quantile(&a[..n], REFERENCE_QUANTILE);
    let v_max = abs_quantile(&v[..n], REFERENCE_QUANTILE);
    let mut out = Vec::new();
    if !(a_ref > 0.0 && v_max > 0.0 && window > 0.0) {
        return out;
    }
    let limit = window * a_ref;
    let width = v_max / VELOCITY_BINS as f64;
    for part in [false, true] {
        for direction in [Direction::Rebound, Direction::Compression] {
            let sign = match direction {
                Direction::Rebound => 1.0,
                Direction::Compression => -1.0,
            };
            let mut bins: Vec<Vec<usize>> = vec![Vec::new(); VELOCITY_BINS];
            for i in 0..n {
                let s = sign * v[i];
                if side(i) != part || s <= 0.0 || a[i].abs() > limit {
                    continue;
                }
                let k = ((s / width) as usize).min(VELOCITY_BINS - 1);
                bins[k].push(i);
            }
            let mut pts: Vec<(f64, f64, usize, usize)> = Vec::new(); // (|v|, sign F, sample, count)
            for members in bins.iter().filter(|m| m.len() >= MIN_BIN_SAMPLES) {
                let vel = median(members.iter().map(|&i| sign * v[i]).collect()).unwrap_or(0.0);
                let mut by_force: Vec<usize> = members.clone();
                by_force.sort_by(|&i, &j| f[i].total_cmp(&f[j]));
                let mid = by_force.len() / 2;
                let force = median(by_force.iter().map(|&i| sign * f[i]).collect()).unwrap_or(0.0);
                pts.push((vel, force, by_force[mid], members.len()));
            }
            let mono = isotonic(
                &pts.iter().map(|p| p.1).collect::<Vec<_>>(),
                &pts.iter().map(|p| p.3 as f64).collect::<Vec<_>>(),
            );
            for (p, force) in pts.iter().zip(mono) {
                out.push(QuasiStaticPoint {
                    run: run_index,
                    sample: p.2,
                    direction,
                    velocity_m_s: sign * p.0,
                    force_n: sign * force,
                    alpha,
                    amplitude_m: 0.0,
                    frequency_hz: None,
                });
            }
        }
    }
    out.sort_by(|p, q| p.velocity_m_s.total_cmp(&q.velocity_m_s));
    out
}

/// Support points of one run: the paper's rule for a periodic run, the low-acceleration rule
/// otherwise (see the module docs). `side` splits the samples of a non-periodic run into two
/// groups that never share a point (the validation split).
pub fn support_points(
    run_index: usize,
    periodic: bool,
    signals: &Signals,
    excitation: &Excitation,
    alpha: f64,
    window: f64,
    side: &dyn Fn(usize) -> bool,
) -> Vec<QuasiStaticPoint> {
    if periodic {
        quasi_static_points(run_index, signals, excitation, alpha, window)
    } else {
        low_acceleration_points(run_index, signals, alpha, window, side)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isotonic_pools_violators() {
        let y = isotonic(&[1.0, 3.0, 2.0, 4.0], &[1.0, 1.0, 1.0, 1.0]);
        assert_eq!(y, vec![1.0, 2.5, 2.5, 4.0]);
        let y = isotonic(&[5.0, 1.0], &[3.0, 1.0]);
        assert_eq!(y, vec![4.0, 4.0]);
    }

    #[test]
    fn crossings_of_a_sine_are_half_a_period_apart() {
        let y: Vec<f64> = (0..1000).map(|i| (i as f64 * 0.05).sin()).collect();
        let c = zero_crossings(&y, 0.1);
        assert!(c.len() >= 14, "{c:?}");
        for w in c.windows(2) {
            assert!((w[1].at - w[0].at - PI / 0.05).abs() < 0.05, "{c:?}");
            assert_ne!(w[0].rising, w[1].rising);
        }
    }
}
