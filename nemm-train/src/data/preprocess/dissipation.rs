//! Does the force of a run dissipate energy, as a damper's must? The correlation of the
//! force with the velocity and the mean power the damper absorbs, from the filtered signals.
//!
//! Sign conventions (docs/data-format.md): velocity positive in extension, force positive in
//! tension. A damper resists the motion: in extension it pulls (tension), in compression it
//! pushes, so `F v > 0` on average and the force rises with the velocity. A run whose force
//! *assists* the motion (negative correlation, negative mean power) has one of its signs
//! inverted (usually the load cell's: many dynos log compression positive).

use super::*;

/// A force-velocity correlation below this means the force assists the motion (a damper's
/// is near +1, an inverted sign's near -1; the margin keeps noise on a barely moving run from
/// tipping it).
pub const MIN_FORCE_VELOCITY_CORRELATION: f64 = -0.2;
/// Fewest samples a run needs for its correlation to be judged.
pub const MIN_DISSIPATION_SAMPLES: usize = 64;

/// What a run says about the energy its damper dissipates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Dissipation {
    /// Pearson correlation of the force with the velocity (filtered signals); `None` when
    /// either is constant or the run has fewer than [`MIN_DISSIPATION_SAMPLES`].
    pub force_velocity_correlation: Option<f64>,
    /// Mean of `F v` over the run \[W\]: the power the damper absorbs on average (a static
    /// force cancels over whole strokes).
    pub mean_power_w: f64,
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
    pub fn force_assists_motion(&self) -> bool {
        self.force_velocity_correlation
            .is_some_and(|r| r < MIN_FORCE_VELOCITY_CORRELATION)
    }

    /// What is wrong and which option fixes it, for a run whose force assists the motion.
    pub fn explain(&self) -> String {
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
