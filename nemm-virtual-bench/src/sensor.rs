//! The measurement chain of the virtual bench: load-cell noise, mains pick-up, quantisation,
//! and the per-run noise generator.

use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::hash::Hasher;

/// The measurement-noise generator of one run: xoshiro256++ ([`Xoshiro256PlusPlus`]) seeded
/// with [`run_seed`]. Uniform draws are `rng.random::<f64>()`, Gaussian ones
/// `rng.sample::<f64, _>(StandardNormal)`.
pub fn run_rng(seed: u64, file: &str) -> Xoshiro256PlusPlus {
    Xoshiro256PlusPlus::seed_from_u64(run_seed(seed, file))
}

/// Seed of one run: the 64-bit FNV-1a hash of the dataset seed (little-endian bytes) followed
/// by the run's file name, so that a run gets the same noise whatever else is in the
/// programme and whichever thread computes it.
pub fn run_seed(seed: u64, file: &str) -> u64 {
    let mut h = fnv::FnvHasher::default();
    h.write(&seed.to_le_bytes());
    h.write(file.as_bytes());
    h.finish()
}

/// Quantiser to a step `lsb`; the result is snapped to the decimal grid of `lsb` so that the
/// shortest round-trip float format prints it compactly (1e-6 m prints as `0.012345`).
#[derive(Debug, Clone, Copy)]
pub struct Quantiser {
    lsb: f64,
    scale: f64,
}

impl Quantiser {
    /// A quantiser with step `lsb` (> 0).
    pub fn new(lsb: f64) -> Self {
        // Smallest number of decimals that represents multiples of lsb exactly (max 12).
        let mut scale = 1.0;
        for _ in 0..12 {
            let k = lsb * scale;
            if (k - k.round()).abs() <= 1e-9 * k.max(1.0) && k.round() >= 1.0 {
                break;
            }
            scale *= 10.0;
        }
        Quantiser { lsb, scale }
    }

    /// The quantised value.
    pub fn apply(&self, x: f64) -> f64 {
        let q = (x / self.lsb).round() * self.lsb;
        // `+ 0.0` turns -0.0 into 0.0 (prints as `0`).
        (q * self.scale).round() / self.scale + 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_has_unit_variance_and_zero_mean() {
        use rand::RngExt;
        let mut r = run_rng(7, "runs/x.csv");
        let n = 200_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let z: f64 = r.sample(rand_distr::StandardNormal);
            s += z;
            s2 += z * z;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.02, "{var}");
    }

    #[test]
    fn quantiser_snaps_to_a_printable_grid() {
        let q = Quantiser::new(1e-6);
        assert_eq!(format!("{}", q.apply(0.0123454)), "0.012345");
        let q = Quantiser::new(2.5e-6);
        assert_eq!(format!("{}", q.apply(0.00000374)), "0.0000025");
        let q = Quantiser::new(0.1);
        assert_eq!(format!("{}", q.apply(-1234.56)), "-1234.6");
    }

    #[test]
    fn run_seeds_differ_by_name_and_seed() {
        assert_ne!(run_seed(1, "a"), run_seed(1, "b"));
        assert_ne!(run_seed(1, "a"), run_seed(2, "a"));
        assert_eq!(run_seed(3, "runs/x.csv"), run_seed(3, "runs/x.csv"));
        // FNV-1a of the empty input is its offset basis; the seed bytes always go in.
        assert_ne!(run_seed(0, ""), 0xCBF2_9CE4_8422_2325);
    }
}
