//! Quasi-static points: the force-velocity points of section 5.3 for the flow-force model.

use super::{Excitation, Signals};
use serde::Deserialize;
use serde::Serialize;

/// Direction of a stroke half-cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Direction {
    /// Extension, positive velocity and (tension) force.
    Rebound,
    /// Compression, negative velocity and force.
    Compression,
}

/// One quasi-static support point of the flow-force model (section 5.3): the largest force
/// magnitude within +-window of the amplitude around the stroke centre, with the velocity
/// there. Rebound points have positive force and velocity, compression points negative.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct QuasiStaticPoint {
    /// Run index in the dataset.
    pub run: usize,
    /// Sample index of the force extreme.
    pub sample: usize,
    /// Rebound or compression pass.
    pub direction: Direction,
    /// Velocity at the centre crossing \[m/s\] (the pass's peak velocity).
    pub velocity_m_s: f64,
    /// Largest (rebound) or smallest (compression) filtered force in the window \[N\].
    pub force_n: f64,
    /// Condition level at the point: the run's, or its `alpha` column's at `sample`.
    pub alpha: f64,
    /// Estimated amplitude of the run \[m\].
    pub amplitude_m: f64,
    /// Estimated frequency of the run \[Hz\] (`None` if it has no full period).
    pub frequency_hz: Option<f64>,
}

/// Quasi-static points of one run: for every pass through the stroke centre, the window of
/// consecutive samples with `|x - offset| <= window * amplitude`, entered on one side and
/// left on the other (turning points inside the window and passes cut by the run's ends are
/// skipped); in it the largest force (rebound) or smallest force (compression) of the
/// filtered force, and the velocity interpolated at the crossing of `x = offset`.
pub fn quasi_static_points(
    run_index: usize,
    signals: &Signals,
    excitation: &Excitation,
    alpha: f64,
    window: f64,
) -> Vec<QuasiStaticPoint> {
    let y: Vec<f64> = signals
        .displacement_m
        .iter()
        .map(|x| x - excitation.offset_m)
        .collect();
    let half_width = window * excitation.amplitude_m;
    let n = y.len();
    let mut out = Vec::new();
    if half_width.is_nan() || half_width <= 0.0 || n < 3 {
        return out;
    }
    let mut i = 0;
    while i < n {
        if y[i].abs() > half_width {
            i += 1;
            continue;
        }
        let a = i;
        while i < n && y[i].abs() <= half_width {
            i += 1;
        }
        let b = i - 1; // last sample inside
        if a == 0 || i >= n {
            continue; // cut by the run's ends
        }
        let direction = match (y[a - 1] < 0.0, y[i] > 0.0) {
            (true, true) => Direction::Rebound,
            (false, false) => Direction::Compression,
            _ => continue, // turning point inside the window
        };
        let f = &signals.force_filtered_n[a..=b];
        let pick = match direction {
            Direction::Rebound => f.iter().enumerate().max_by(|p, q| p.1.total_cmp(q.1)),
            Direction::Compression => f.iter().enumerate().min_by(|p, q| p.1.total_cmp(q.1)),
        };
        let Some((k, &force_n)) = pick else { continue };
        // Crossing of y = 0 inside [a - 1, i]: first sign change.
        let v = &signals.velocity_m_s;
        let mut velocity_m_s = v[a];
        for j in a..=i {
            let (p, q) = (y[j - 1], y[j]);
            if (p < 0.0) != (q < 0.0) {
                let t = p / (p - q);
                velocity_m_s = v[j - 1] + t * (v[j] - v[j - 1]);
                break;
            }
        }
        out.push(QuasiStaticPoint {
            run: run_index,
            sample: a + k,
            direction,
            velocity_m_s,
            force_n,
            alpha,
            amplitude_m: excitation.amplitude_m,
            frequency_hz: excitation.frequency_hz,
        });
    }
    out
}
