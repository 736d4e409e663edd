//! Does the force of a run dissipate energy, as a damper's must? The correlation of the
//! force with the velocity and the mean power the damper absorbs, from the filtered signals;
//! and the force the damper holds at rest ([`ForceOffset`]).
//!
//! Sign conventions (docs/data-format.md): velocity positive in extension, force positive in
//! tension. A damper resists the motion: in extension it pulls (tension), in compression it
//! pushes, so `F v > 0` on average and the force rises with the velocity. A run whose force
//! *assists* the motion (negative correlation, negative mean power) has one of its signs
//! inverted (usually the load cell's: many dynos log compression positive).

use super::median;
use serde::Deserialize;
use serde::Serialize;

/// A force-velocity correlation below this means the force assists the motion (a damper's
/// is near +1, an inverted sign's near -1; the margin keeps noise on a barely moving run from
/// tipping it).
pub(crate) const MIN_FORCE_VELOCITY_CORRELATION: f64 = -0.2;
/// Fewest samples a run needs for its correlation to be judged.
pub(crate) const MIN_DISSIPATION_SAMPLES: usize = 64;

/// What a run says about the energy its damper dissipates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Dissipation {
    /// Pearson correlation of the force with the velocity (filtered signals); `None` when
    /// either is constant or the run has fewer than [`MIN_DISSIPATION_SAMPLES`].
    pub(crate) force_velocity_correlation: Option<f64>,
    /// Mean of `F v` over the run \[W\]: the power the damper absorbs on average (a static
    /// force cancels over whole strokes).
    pub(crate) mean_power_w: f64,
}

impl Dissipation {
    /// From a run's force and velocity (equal lengths; the shorter sets the length).
    pub fn of(force_n: &[f64], velocity_m_s: &[f64]) -> Dissipation {
        let n = force_n.len().min(velocity_m_s.len());
        let (f, v) = (&force_n[..n], &velocity_m_s[..n]);
        if n < MIN_DISSIPATION_SAMPLES {
            return Dissipation {
                force_velocity_correlation: None,
                mean_power_w: 0.0,
            };
        }
        let nf = n as f64;
        let (fm, vm) = (f.iter().sum::<f64>() / nf, v.iter().sum::<f64>() / nf);
        let (mut sfv, mut sff, mut svv, mut power) = (0.0, 0.0, 0.0, 0.0);
        for (&fi, &vi) in f.iter().zip(v) {
            let (df, dv) = (fi - fm, vi - vm);
            sfv += df * dv;
            sff += df * df;
            svv += dv * dv;
            power += fi * vi;
        }
        let denom = (sff * svv).sqrt();
        Dissipation {
            force_velocity_correlation: (denom > 0.0 && denom.is_finite()).then(|| sfv / denom),
            mean_power_w: power / nf,
        }
    }

    /// `true` when the force assists the motion: a force-velocity correlation below
    /// [`MIN_FORCE_VELOCITY_CORRELATION`] (`None`, too short or constant runs, is not judged).
    pub(crate) fn force_assists_motion(&self) -> bool {
        self.force_velocity_correlation
            .is_some_and(|r| r < MIN_FORCE_VELOCITY_CORRELATION)
    }

    /// What is wrong and which option fixes it, for a run whose force assists the motion.
    pub(crate) fn explain(&self) -> String {
        format!(
            "correlation of force with velocity {:.2}, mean power F v {:.1} W: a damper \
             dissipates energy, so the force or the displacement sign is inverted; re-import \
             with --invert-force (force positive in tension) or --invert-displacement \
             (positive in extension)",
            self.force_velocity_correlation.unwrap_or(f64::NAN),
            self.mean_power_w
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A damper's force on a sine stroke: damping plus a gas force.
    fn stroke(sign: f64) -> (Vec<f64>, Vec<f64>) {
        let v: Vec<f64> = (0..1000).map(|i| 0.3 * (i as f64 * 0.0126).sin()).collect();
        let f = v.iter().map(|v| sign * 2000.0 * v - 100.0).collect();
        (f, v)
    }

    #[test]
    fn a_resisting_force_dissipates_and_an_inverted_one_assists() {
        let (f, v) = stroke(1.0);
        let d = Dissipation::of(&f, &v);
        assert!(d.force_velocity_correlation.unwrap() > 0.99 && d.mean_power_w > 0.0);
        assert!(!d.force_assists_motion());
        let (f, v) = stroke(-1.0);
        let d = Dissipation::of(&f, &v);
        assert!(d.force_velocity_correlation.unwrap() < -0.99 && d.mean_power_w < 0.0);
        assert!(d.force_assists_motion());
        assert!(d.explain().contains("--invert-force"), "{}", d.explain());
    }

    #[test]
    fn a_constant_signal_has_no_correlation() {
        let d = Dissipation::of(&[5.0; 100], &[0.1; 100]);
        assert_eq!(d.force_velocity_correlation, None);
        assert!(!d.force_assists_motion());
        assert_eq!(Dissipation::of(&[], &[]).force_velocity_correlation, None);
        // Too short to judge.
        assert_eq!(
            Dissipation::of(&[1.0, -1.0, 2.0], &[1.0, 2.0, 3.0]).force_velocity_correlation,
            None
        );
    }
}

/// Velocities at most this fraction of a run's largest `|v|` count as zero velocity for the
/// force offset ([`ForceOffset`]).
pub(crate) const ZERO_VELOCITY_FRACTION: f64 = 0.05;
/// The training commands switch the static force of eq. 17 on when the median over the runs
/// of the signed force offset at zero velocity, as a fraction of each run's force half-range
/// ([`ForceOffset::signed_fraction`]), is at least this in magnitude
/// ([`static_force_from_data`]): a consistent offset, where a tared damper's scatters about 0.
pub(crate) const STATIC_FORCE_FRACTION: f64 = 0.05;

/// The force a run holds at zero velocity: a gas force or an untared load cell.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ForceOffset {
    /// Mean raw force over the zero-velocity samples (`|v| <=` [`ZERO_VELOCITY_FRACTION`] of
    /// the largest `|v|`) \[N\].
    pub(crate) mean_n: f64,
    /// Half the force's robust range (0.5th to 99.5th percentile) \[N\].
    pub(crate) half_range_n: f64,
    /// Zero-velocity samples.
    pub samples: usize,
    /// Index of the first of them.
    pub first: usize,
}

impl ForceOffset {
    /// From a run's raw force and its velocity (equal lengths); `None` when they differ in
    /// length or no sample is at zero velocity.
    pub fn of(force_n: &[f64], velocity_m_s: &[f64]) -> Option<ForceOffset> {
        if force_n.len() != velocity_m_s.len() || force_n.is_empty() {
            return None;
        }
        let v_max = velocity_m_s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let slow: Vec<usize> = (0..velocity_m_s.len())
            .filter(|&i| velocity_m_s[i].abs() <= ZERO_VELOCITY_FRACTION * v_max)
            .collect();
        let &first = slow.first()?;
        let mean_n = slow.iter().map(|&i| force_n[i]).sum::<f64>() / slow.len() as f64;
        let (lo, hi) = (percentile(force_n, 0.005), percentile(force_n, 0.995));
        Some(ForceOffset {
            mean_n,
            half_range_n: 0.5 * (hi - lo),
            samples: slow.len(),
            first,
        })
    }

    /// `mean / half range` (infinite for a constant force with an offset).
    pub(crate) fn signed_fraction(&self) -> f64 {
        if self.half_range_n > 0.0 {
            self.mean_n / self.half_range_n
        } else if self.mean_n != 0.0 {
            f64::INFINITY.copysign(self.mean_n)
        } else {
            0.0
        }
    }

    /// `|mean| / half range`.
    pub fn fraction(&self) -> f64 {
        self.signed_fraction().abs()
    }
}

/// Percentile `p` (0..1) of a copy of `x` (nearest rank); 0 for no values.
pub(crate) fn percentile(x: &[f64], p: f64) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    let mut v = x.to_vec();
    let k = ((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1);
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

/// Whether the data ask for the static force: `Some((true, why))` when the median over the
/// runs of the signed offset fraction (`ForceOffset::signed_fraction`) is at least
/// `STATIC_FORCE_FRACTION` in magnitude, `Some((false, why))` when not, `None` for no run
/// with zero-velocity samples. `why` gives the median, the count and the largest offset.
pub fn static_force_from_data(offsets: &[Option<ForceOffset>]) -> Option<(bool, String)> {
    let known: Vec<&ForceOffset> = offsets.iter().flatten().collect();
    if known.is_empty() {
        return None;
    }
    let median = median(known.iter().map(|o| o.signed_fraction()).collect()).unwrap_or(0.0);
    let largest =
        known
            .iter()
            .map(|o| o.mean_n)
            .fold(0.0f64, |m, f| if f.abs() > m.abs() { f } else { m });
    let on = median.abs() >= STATIC_FORCE_FRACTION;
    Some((
        on,
        format!(
            "the median force at zero velocity is {:+.1} % of the force half-range over {} \
             runs (largest {largest:+.1} N); {} % or more switches it on{}",
            median * 100.0,
            known.len(),
            STATIC_FORCE_FRACTION * 100.0,
            if on {
                ", --static-force=false turns it off"
            } else {
                ""
            }
        ),
    ))
}
