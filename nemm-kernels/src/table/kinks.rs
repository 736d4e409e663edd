//! Where a scaler's kinks lie: the scan of its activation pattern and the refinement of
//! each change to a knot of the table.

use super::*;

/// Points of the fine scan per table segment, around check points over the bound (see
/// [`Table1D::compile`]).
pub const REFINE_POINTS_PER_SEGMENT: usize = 128;
/// Most ranges rescanned per refinement round.
pub(super) const REFINE_RANGES: usize = 8;
/// A check point whose error exceeds the bound divided by this is rescanned for missed kinks.
pub(super) const REFINE_FRACTION: f32 = 8.0;
/// Most kinks separated between two neighbouring scan points.
pub(super) const MAX_KINKS_PER_INTERVAL: usize = 8;
/// Most refinement rounds.
pub(super) const REFINE_ROUNDS: usize = 8;

/// The kinks found so far: sorted, at most `N`, none closer to another than a millionth of
/// the domain (a kink found again from another scan interval is the same kink).
pub(super) struct Kinks<const N: usize> {
    x: [f64; N],
    n: usize,
    tol: f64,
}

impl<const N: usize> Kinks<N> {
    pub(super) fn new(span: f64) -> Self {
        Self {
            x: [0.0; N],
            n: 0,
            tol: span * 1e-6,
        }
    }

    pub(super) fn as_slice(&self) -> &[f64] {
        self.x.get(..self.n).unwrap_or(&[])
    }

    /// Adds `x` in order; `Ok(false)` if it is a kink already known.
    pub(super) fn insert(&mut self, x: f64, scaler: &'static str) -> Result<bool, TableError> {
        let known = self.as_slice();
        let at = known.partition_point(|&k| k < x);
        let near = |i: Option<usize>| {
            i.and_then(|i| known.get(i))
                .is_some_and(|&k| (k - x).abs() <= self.tol)
        };
        if near(Some(at)) || near(at.checked_sub(1)) {
            return Ok(false);
        }
        if self.n == N {
            return Err(TableError::TooManyKinks {
                scaler,
                segments: N,
            });
        }
        // Shift the tail up by one and insert, by passing `x` along the slots (the last slot,
        // index `n`, is unused). Not `rotate_right`: its length assertion is a panic path
        // the compiler cannot remove.
        let tail = self.x.get_mut(at..=self.n).ok_or(TableError::BadConfig)?;
        let mut carry = x;
        for slot in tail {
            core::mem::swap(slot, &mut carry);
        }
        self.n += 1;
        Ok(true)
    }
}

/// Scans `[a, b]` (`range`) at `n` intervals for changes of the pattern, bisects each to
/// adjacent floats and adds the kinks strictly inside the domain `(lo, hi)` (`domain`) to
/// `kinks`; returns how many were new.
pub(super) fn scan_kinks<const N: usize>(
    exact: &mut impl Tabulate,
    (a, b): (f32, f32),
    n: usize,
    (lo, hi): (f32, f32),
    kinks: &mut Kinks<N>,
    scaler: &'static str,
) -> Result<usize, TableError> {
    let (a64, span) = (f64::from(a), f64::from(b) - f64::from(a));
    let mut new = 0usize;
    let mut prev_x = a;
    let mut prev_p = exact.pattern(a);
    for j in 1..=n {
        let x = if j == n {
            b
        } else {
            (a64 + span * j as f64 / n as f64) as f32
        };
        let p = exact.pattern(x);
        // Every change between the two points: bisect to the first, and again from there
        // while the pattern still differs from `x`'s (kinks of different neurons closer
        // than the grid; the same neuron's two crossings are found by the finer rescans).
        let (mut from_x, mut from_p) = (prev_x, prev_p);
        for _ in 0..MAX_KINKS_PER_INTERVAL {
            if from_p == p {
                break;
            }
            let (mut l, mut r) = (from_x, x);
            let mut r_p = p;
            for _ in 0..BISECTION_STEPS {
                let mid = l + 0.5 * (r - l);
                if mid <= l || mid >= r {
                    break;
                }
                let mid_p = exact.pattern(mid);
                if mid_p == from_p {
                    l = mid;
                } else {
                    (r, r_p) = (mid, mid_p);
                }
            }
            // A kink on the domain's ends needs no knot.
            if r > lo && r < hi && kinks.insert(f64::from(r), scaler)? {
                new += 1;
            }
            (from_x, from_p) = (r, r_p);
        }
        prev_x = x;
        prev_p = p;
    }
    Ok(new)
}
