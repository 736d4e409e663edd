//! Matched training windows: the same excitation recorded at two condition levels (the
//! paper's Table 1 programme is run at every oil-loss level), found from the data, and the
//! batches that carry them in pairs for the difference term of the loss
//! ([`super::adjoint::loss_and_grad_paired`]).
//!
//! Two windows match when they start at the same sample of runs of equal-length windows,
//! their levels differ and their stroke velocities agree within [`MATCH_TOLERANCE`] (RMS of
//! the difference over the larger RMS): the sensor noise of two recordings of one programme
//! passes, another programme does not. Runs whose level changes within a window never match.
//! Data without repeated programmes (random excitation, one record per condition with
//! different trims) have no matches, and the difference term then does nothing.

use super::adjoint::LANES;
use crate::data::preprocess::Sequence;
use rand::seq::IndexedRandom;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::BTreeMap;

/// Largest RMS difference of two windows' stroke velocities, relative to the larger RMS,
/// for them to count as the same excitation.
pub(crate) const MATCH_TOLERANCE: f64 = 0.05;

/// The constant level of `s`, or `None` when it changes within the window.
fn constant_level(s: &Sequence) -> Option<f32> {
    match &s.alphas {
        None => Some(s.alpha),
        Some(a) => {
            let first = *a.first()?;
            a.iter().all(|&v| v == first).then_some(first)
        }
    }
}

/// Whether the stroke velocities `a` and `b` are the same excitation.
fn same_excitation(a: &[f32], b: &[f32]) -> bool {
    if a.len() != b.len() || a.is_empty() {
        return false;
    }
    let (mut sa, mut sb, mut sd) = (0.0f64, 0.0f64, 0.0f64);
    for (&x, &y) in a.iter().zip(b) {
        let (x, y) = (f64::from(x), f64::from(y));
        sa += x * x;
        sb += y * y;
        sd += (x - y) * (x - y);
    }
    let scale = sa.max(sb);
    scale > 0.0 && sd <= MATCH_TOLERANCE * MATCH_TOLERANCE * scale
}

/// Per window of `seqs`, the windows it matches at other levels (indices into `seqs`).
pub(crate) fn matched_windows(seqs: &[Sequence]) -> Vec<Vec<usize>> {
    let mut by_start: BTreeMap<(usize, usize), Vec<(usize, f32)>> = BTreeMap::new();
    for (i, s) in seqs.iter().enumerate() {
        if let Some(level) = constant_level(s) {
            by_start
                .entry((s.start, s.velocity_m_s.len()))
                .or_default()
                .push((i, level));
        }
    }
    let mut partners = vec![Vec::new(); seqs.len()];
    for group in by_start.values() {
        for (n, &(i, li)) in group.iter().enumerate() {
            for &(j, lj) in &group[n + 1..] {
                let (si, sj) = (&seqs[i], &seqs[j]);
                if li != lj
                    && si.run != sj.run
                    && same_excitation(&si.velocity_m_s, &sj.velocity_m_s)
                {
                    partners[i].push(j);
                    partners[j].push(i);
                }
            }
        }
    }
    partners
}

/// How many of the windows have a match.
pub(crate) fn matched_count(partners: &[Vec<usize>]) -> usize {
    partners.iter().filter(|p| !p.is_empty()).count()
}

/// One batch built from `anchors`: every anchor with a match followed by one of its
/// matches (drawn by `seed`), the pairs first so that none straddles a pack of [`LANES`]
/// windows, then the anchors without one. Returns the windows (indices into the training
/// windows) and, per entry, the position of its partner in the batch.
pub(crate) fn paired_batch(
    anchors: &[usize],
    partners: &[Vec<usize>],
    seed: u64,
) -> (Vec<usize>, Vec<Option<usize>>) {
    const { assert!(LANES.is_multiple_of(2), "pairs must not straddle packs") };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let (mut batch, mut partner) = (Vec::new(), Vec::new());
    let mut lone = Vec::new();
    for &a in anchors {
        match partners.get(a).and_then(|p| p.choose(&mut rng)) {
            Some(&b) => {
                let k = batch.len();
                batch.extend([a, b]);
                partner.extend([Some(k + 1), Some(k)]);
            }
            None => lone.push(a),
        }
    }
    partner.extend(lone.iter().map(|_| None));
    batch.extend(lone);
    (batch, partner)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seq(run: usize, start: usize, alpha: f32, u: Vec<f32>) -> Sequence {
        let n = u.len();
        Sequence {
            run,
            start,
            alpha,
            velocity_m_s: u,
            force_n: vec![0.0; n],
            position_m: vec![0.0; n],
            alphas: None,
        }
    }

    fn sine(amp: f32, noise: f32) -> Vec<f32> {
        (0..200)
            .map(|k| amp * (k as f32 * 0.1).sin() + noise * ((k * 7919 % 13) as f32 - 6.0) / 6.0)
            .collect()
    }

    #[test]
    fn the_same_programme_at_two_levels_matches_and_nothing_else_does() {
        let seqs = vec![
            seq(0, 0, 0.0, sine(0.5, 0.0)),
            seq(1, 0, 0.3, sine(0.5, 0.01)), // same programme, another level, sensor noise
            seq(2, 0, 0.3, sine(0.2, 0.0)),  // another amplitude
            seq(3, 0, 0.0, sine(0.5, 0.0)),  // same level as run 0
            seq(1, 50, 0.3, sine(0.5, 0.0)), // another start
        ];
        let p = matched_windows(&seqs);
        assert_eq!(p[0], vec![1]);
        assert_eq!(p[1], vec![0, 3]);
        assert!(p[2].is_empty());
        assert_eq!(p[3], vec![1]);
        assert!(p[4].is_empty());
        assert_eq!(matched_count(&p), 3);
    }

    #[test]
    fn a_level_changing_within_the_window_never_matches() {
        let mut s = seq(1, 0, 0.3, sine(0.5, 0.0));
        s.alphas = Some((0..200).map(|k| if k < 100 { 0.0 } else { 0.3 }).collect());
        let p = matched_windows(&[seq(0, 0, 0.0, sine(0.5, 0.0)), s]);
        assert_eq!(matched_count(&p), 0);
    }

    #[test]
    fn batches_put_pairs_first_and_partners_point_at_each_other() {
        let partners = vec![vec![3], vec![], vec![4], vec![0], vec![2]];
        let (batch, partner) = paired_batch(&[1, 0, 2], &partners, 7);
        assert_eq!(batch, vec![0, 3, 2, 4, 1]);
        assert_eq!(partner, vec![Some(1), Some(0), Some(3), Some(2), None]);
        for (k, p) in partner.iter().enumerate() {
            if let Some(p) = *p {
                assert_eq!(partner[p], Some(k));
                assert_eq!(k / LANES, p / LANES, "a pair straddles two packs");
            }
        }
    }
}
