//! Static empirical model (SEM): the industry-standard force-velocity map (paper section 6,
//! variant 1), support points per oil-loss level.
//!
//! The map holds forces on a rectangular grid: `velocities_m_s` (strictly increasing, at least
//! 2) x `alphas` (strictly increasing, at least 1). Evaluation is piecewise linear in velocity
//! with linear extrapolation from the end segments, and piecewise linear in `alpha`, clamped
//! to the grid's alpha range (a flag reports the clamp, see nemm-core's estimator flags).

pub use crate::error::SemError;
pub use crate::limits::{MAX_SEM_ALPHAS, MAX_SEM_FORCES, MAX_SEM_VELOCITIES};
use serde::{Deserialize, Serialize};

/// A force-velocity map per oil-loss level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SemMap {
    /// Velocity support points \[m/s\], strictly increasing.
    pub velocities_m_s: heapless::Vec<f32, MAX_SEM_VELOCITIES>,
    /// Oil-loss levels `alpha` \[-\], strictly increasing, in `[0, 1]`.
    pub alphas: heapless::Vec<f32, MAX_SEM_ALPHAS>,
    /// Forces \[N\], row per alpha: `forces_n[ia * n_v + iv]`.
    pub forces_n: heapless::Vec<f32, MAX_SEM_FORCES>,
}

fn strictly_increasing(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite()) && v.windows(2).all(|w| matches!(w, [a, b] if a < b))
}

impl SemMap {
    /// A map without support points (not valid; a place to decode into).
    pub const fn empty() -> Self {
        Self {
            velocities_m_s: heapless::Vec::new(),
            alphas: heapless::Vec::new(),
            forces_n: heapless::Vec::new(),
        }
    }

    /// Checks the grid.
    pub fn validate(&self) -> Result<(), SemError> {
        let (nv, na) = (self.velocities_m_s.len(), self.alphas.len());
        if nv < 2 || na < 1 {
            return Err(SemError::TooFewPoints);
        }
        if !strictly_increasing(&self.velocities_m_s) || !strictly_increasing(&self.alphas) {
            return Err(SemError::NotIncreasing);
        }
        if self.alphas.iter().any(|a| !(0.0..=1.0).contains(a)) {
            return Err(SemError::AlphaOutOfRange);
        }
        if self.forces_n.len() != nv.saturating_mul(na) {
            return Err(SemError::CountMismatch);
        }
        if self.forces_n.iter().any(|f| !f.is_finite()) {
            return Err(SemError::NonFiniteForce);
        }
        Ok(())
    }

    /// The force curve at `alpha` (linear between levels, clamped to the alpha range), one
    /// value per velocity support point; and whether `alpha` had to be clamped.
    pub fn curve_at(&self, alpha: f32) -> (heapless::Vec<f32, MAX_SEM_VELOCITIES>, bool) {
        let nv = self.velocities_m_s.len();
        let mut out = heapless::Vec::new();
        let (first, last) = match (self.alphas.first(), self.alphas.last()) {
            (Some(&f), Some(&l)) => (f, l),
            _ => return (out, true),
        };
        let clamped = !(first..=last).contains(&alpha);
        // Not `f32::clamp`: it panics on bounds out of order, which `validate` rules out but
        // the compiler cannot see. A NaN `alpha` stays NaN, as with `clamp`.
        let a = if alpha < first {
            first
        } else if alpha > last {
            last
        } else {
            alpha
        };
        let (i, t) = segment(&self.alphas, a);
        let row = |ia: usize| self.forces_n.get(ia * nv..(ia + 1) * nv).unwrap_or(&[]);
        let (r0, r1) = (row(i), row((i + 1).min(self.alphas.len() - 1)));
        for (&f0, &f1) in r0.iter().zip(r1) {
            let _ = out.push(f0 + (f1 - f0) * t);
        }
        (out, clamped)
    }

    /// Force \[N\] at velocity `v` \[m/s\] on a curve from [`Self::curve_at`].
    pub fn force_on_curve(&self, curve: &[f32], v: f32) -> f32 {
        let (i, t) = segment(&self.velocities_m_s, v);
        match (curve.get(i), curve.get(i + 1)) {
            (Some(&f0), Some(&f1)) => f0 + (f1 - f0) * t,
            (Some(&f0), None) => f0,
            _ => 0.0,
        }
    }
}

/// Segment index `i` and fraction `t` of `x` on knots `k` (at least one knot), such that the
/// value is `y[i] + (y[i+1] - y[i]) t`; `t` is outside `[0, 1]` beyond the ends (linear
/// extrapolation). With a single knot returns `(0, 0)`.
pub fn segment(k: &[f32], x: f32) -> (usize, f32) {
    let n = k.len();
    if n < 2 {
        return (0, 0.0);
    }
    // Largest i in [0, n-2] with k[i] <= x (or 0).
    let mut lo = 0usize;
    let mut hi = n - 1;
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        match k.get(mid) {
            Some(&km) if km <= x => lo = mid,
            _ => hi = mid,
        }
    }
    match (k.get(lo), k.get(lo + 1)) {
        (Some(&a), Some(&b)) => (lo, (x - a) / (b - a)),
        _ => (0, 0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map() -> SemMap {
        SemMap {
            velocities_m_s: heapless::Vec::from_slice(&[-1.0, 0.0, 1.0]).unwrap(),
            alphas: heapless::Vec::from_slice(&[0.0, 0.3]).unwrap(),
            forces_n: heapless::Vec::from_slice(&[-1000.0, 0.0, 2000.0, -700.0, 0.0, 1400.0])
                .unwrap(),
        }
    }

    #[test]
    fn interpolates_and_extrapolates() {
        let m = map();
        m.validate().unwrap();
        let (c, clamped) = m.curve_at(0.15);
        assert!(!clamped);
        assert_eq!(c.as_slice(), &[-850.0, 0.0, 1700.0]);
        assert_eq!(m.force_on_curve(&c, 0.5), 850.0);
        assert_eq!(m.force_on_curve(&c, 2.0), 3400.0);
        assert_eq!(m.force_on_curve(&c, -2.0), -1700.0);
        let (_, clamped) = m.curve_at(0.5);
        assert!(clamped);
    }

    #[test]
    fn rejects_bad_grids() {
        let mut m = map();
        m.velocities_m_s[1] = -1.0;
        assert_eq!(m.validate(), Err(SemError::NotIncreasing));
        let mut m = map();
        m.forces_n.pop();
        assert_eq!(m.validate(), Err(SemError::CountMismatch));
        let mut m = map();
        m.forces_n[0] = f32::NAN;
        assert_eq!(m.validate(), Err(SemError::NonFiniteForce));
    }
}
