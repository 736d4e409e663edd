//! Excitation estimate: the amplitude, frequency and peak velocity of a periodic run.

use super::MIN_STROKE_M;
use serde::Deserialize;
use serde::Serialize;

/// A zero crossing of the displacement (relative to its centre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Crossing {
    /// Fractional sample index of the crossing (linear interpolation).
    pub(crate) at: f64,
    /// `true` for extension (x increasing, rebound), `false` for compression.
    pub(crate) rising: bool,
}

/// Zero crossings of `y` with hysteresis `h`: a crossing counts once, and the next one only
/// after `y` has left the band `[-h, h]` on the other side.
pub(crate) fn zero_crossings(y: &[f64], h: f64) -> Vec<Crossing> {
    let mut out = Vec::new();
    // Confirmed side: Some(true) above +h, Some(false) below -h.
    let mut side = None;
    let mut crossed = false;
    for i in 0..y.len() {
        if i > 0 {
            let (a, b) = (y[i - 1], y[i]);
            let rising = match side {
                Some(false) if a < 0.0 && b >= 0.0 => Some(true),
                Some(true) if a > 0.0 && b <= 0.0 => Some(false),
                _ => None,
            };
            if let (Some(rising), false) = (rising, crossed) {
                out.push(Crossing {
                    at: (i - 1) as f64 + a / (a - b),
                    rising,
                });
                crossed = true;
            }
        }
        let now = if y[i] > h {
            Some(true)
        } else if y[i] < -h {
            Some(false)
        } else {
            None
        };
        if now.is_some() && now != side {
            side = now;
            crossed = false;
        }
    }
    out
}

/// Median of `v` (the mean of the two middle values for an even count); `None` when empty.
pub(crate) fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    })
}

/// Fraction of the reference (90th percentile) that a half-cycle must reach to count as
/// steady in [`steady_median`].
pub(crate) const STEADY_FRACTION: f64 = 0.9;

/// Median of the steady part of per-half-cycle values: those of at least
/// [`STEADY_FRACTION`] times their 90th percentile. Ramp-in and ramp-out cycles are smaller
/// and drop out even when they outnumber the steady ones; one outlying half-cycle (a spike)
/// moves the 90th percentile only when it is more than a tenth of them. `None` for no values.
pub(crate) fn steady_median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let k = ((0.9 * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1);
    let reference = sorted[k];
    median(
        sorted
            .into_iter()
            .filter(|v| *v >= STEADY_FRACTION * reference)
            .collect(),
    )
}

/// Estimated excitation of a (periodic) run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Excitation {
    /// Centre of the stroke \[m\]: mid-range of the filtered displacement.
    pub offset_m: f64,
    /// Stroke amplitude \[m\]: median over the steady complete half-cycles of the largest
    /// `|x - offset|` (half the range when the run has no complete half-cycle); see
    /// [`steady_median`].
    pub amplitude_m: f64,
    /// Frequency \[Hz\] from the mean period between rising zero crossings (half periods
    /// when there is only one); `None` with fewer than two crossings.
    pub frequency_hz: Option<f64>,
    /// Peak velocity \[m/s\]: median over the steady passes through the centre between two
    /// turning points of the largest `|v|` (the overall largest `|v|` without such a pass);
    /// see [`steady_median`].
    pub peak_velocity_m_s: f64,
    /// Complete half-cycles found (between two zero crossings).
    pub(crate) half_cycles: usize,
    /// `true` for a periodic run: at least [`PERIODIC_MIN_HALF_PERIODS`] half-periods between
    /// consecutive zero crossings, each within [`PERIODIC_TOLERANCE`] of their median (a sine
    /// programme with ramps; random excitation is not).
    #[serde(default)]
    pub periodic: bool,
}

/// Fewest half-periods for [`Excitation::periodic`].
pub(crate) const PERIODIC_MIN_HALF_PERIODS: usize = 3;
/// Largest relative deviation of a half-period from the median half-period for
/// [`Excitation::periodic`].
pub(crate) const PERIODIC_TOLERANCE: f64 = 0.1;

/// [`Excitation::periodic`] of the zero crossings.
fn is_periodic(crossings: &[Crossing]) -> bool {
    let halves: Vec<f64> = crossings.windows(2).map(|w| w[1].at - w[0].at).collect();
    if halves.len() < PERIODIC_MIN_HALF_PERIODS {
        return false;
    }
    let Some(m) = median(halves.clone()) else {
        return false;
    };
    m > 0.0
        && halves
            .iter()
            .all(|h| (h - m).abs() <= PERIODIC_TOLERANCE * m)
}

/// Estimates amplitude, frequency and peak velocity from filtered displacement and velocity.
///
/// Robust to ramp-in / ramp-out cycles (medians over the steady half-cycles, however many
/// ramp cycles there are) and to noise (zero crossings with a hysteresis of 10 % of the
/// half-range).
pub fn estimate_excitation(
    displacement_m: &[f64],
    velocity_m_s: &[f64],
    sample_rate_hz: f64,
) -> Excitation {
    let (lo, hi) = displacement_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
    let max_abs_v = velocity_m_s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if displacement_m.is_empty() {
        return Excitation {
            offset_m: 0.0,
            amplitude_m: 0.0,
            frequency_hz: None,
            peak_velocity_m_s: max_abs_v,
            half_cycles: 0,
            periodic: false,
        };
    }
    let Centred {
        offset_m,
        half_range,
        y,
        crossings,
    } = centred(displacement_m, lo, hi);

    // Half-cycles between consecutive crossings: amplitude and turning point.
    let mut amplitudes = Vec::new();
    let mut turning = Vec::new();
    for w in crossings.windows(2) {
        let a = w[0].at.ceil() as usize;
        let b = (w[1].at.floor() as usize).min(y.len() - 1);
        if let Some((i, v)) = (a..=b)
            .map(|i| (i, y[i].abs()))
            .max_by(|p, q| p.1.total_cmp(&q.1))
        {
            amplitudes.push(v);
            turning.push(i);
        }
    }
    // Passes through the centre between consecutive turning points: peak |v|.
    let peaks: Vec<f64> = turning
        .windows(2)
        .map(|w| {
            velocity_m_s[w[0]..=w[1]]
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()))
        })
        .collect();
    let frequency_hz = frequency_of(&crossings, sample_rate_hz);
    Excitation {
        offset_m,
        amplitude_m: steady_median(&amplitudes).unwrap_or(half_range),
        frequency_hz,
        peak_velocity_m_s: steady_median(&peaks).unwrap_or(max_abs_v),
        half_cycles: amplitudes.len(),
        periodic: is_periodic(&crossings),
    }
}

/// Frequency \[Hz\] from the mean period between rising zero crossings (half periods when
/// there is only one); `None` with fewer than two crossings.
fn frequency_of(crossings: &[Crossing], sample_rate_hz: f64) -> Option<f64> {
    let rising: Vec<f64> = crossings
        .iter()
        .filter(|c| c.rising)
        .map(|c| c.at)
        .collect();
    if rising.len() >= 2 {
        Some(sample_rate_hz * (rising.len() - 1) as f64 / (rising[rising.len() - 1] - rising[0]))
    } else if crossings.len() >= 2 {
        let span = crossings[crossings.len() - 1].at - crossings[0].at;
        Some(sample_rate_hz * (crossings.len() - 1) as f64 / (2.0 * span))
    } else {
        None
    }
}

/// The excitation frequency \[Hz\] of a displacement record, as [`estimate_excitation`]
/// finds it (zero crossings about the mid-range with a hysteresis of 10 % of the
/// half-range); `None` with fewer than two crossings.
pub(crate) fn excitation_frequency_hz(displacement_m: &[f64], sample_rate_hz: f64) -> Option<f64> {
    frequency_of(&centred_record(displacement_m).crossings, sample_rate_hz)
}

/// A displacement record about its mid-range, and its zero crossings.
pub(crate) struct Centred {
    /// Mid-range \[m\].
    pub(crate) offset_m: f64,
    /// Half the range \[m\]; 0 below [`MIN_STROKE_M`] (rounding noise of a flat signal, not
    /// an excitation).
    pub(crate) half_range: f64,
    /// The record minus `offset_m`.
    pub(crate) y: Vec<f64>,
    /// Zero crossings of `y` with a hysteresis of 10 % of the half-range (none for a flat
    /// record).
    pub(crate) crossings: Vec<Crossing>,
}

/// [`Centred`] of `displacement_m` about the mid-point of its smallest and largest values.
pub(crate) fn centred_record(displacement_m: &[f64]) -> Centred {
    let (lo, hi) = displacement_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
    centred(displacement_m, lo, hi)
}

/// [`Centred`] of `displacement_m`, whose smallest and largest values are `lo` and `hi`.
fn centred(displacement_m: &[f64], lo: f64, hi: f64) -> Centred {
    let offset_m = 0.5 * (lo + hi);
    let half_range = match 0.5 * (hi - lo) {
        r if r < MIN_STROKE_M => 0.0,
        r => r,
    };
    let y: Vec<f64> = displacement_m.iter().map(|x| x - offset_m).collect();
    let crossings = if half_range > 0.0 {
        zero_crossings(&y, 0.1 * half_range)
    } else {
        Vec::new()
    };
    Centred {
        offset_m,
        half_range,
        y,
        crossings,
    }
}
