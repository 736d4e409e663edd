//! The measurement chain of the virtual bench: load-cell noise, mains pick-up, quantisation,
//! and a small deterministic random-number generator (independent of crate versions, so a
//! seed gives the same bytes forever).

/// SplitMix64 (Steele, Lea, Flood 2014): a tiny, well-mixed 64-bit generator.
#[derive(Debug, Clone)]
pub struct SplitMix64 {
    state: u64,
    spare_normal: Option<f64>,
}

impl SplitMix64 {
    /// A generator started from `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix64 {
            state: seed,
            spare_normal: None,
        }
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in the open interval (0, 1).
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    /// Standard normal (Box-Muller, both values used).
    pub fn normal(&mut self) -> f64 {
        if let Some(z) = self.spare_normal.take() {
            return z;
        }
        let r = (-2.0 * self.uniform().ln()).sqrt();
        let (s, c) = (2.0 * std::f64::consts::PI * self.uniform()).sin_cos();
        self.spare_normal = Some(r * s);
        r * c
    }
}

/// Seed of one run: the dataset seed mixed with a hash of the run's file name, so that a run
/// gets the same noise whatever else is in the programme and whichever thread computes it.
pub fn run_seed(seed: u64, file: &str) -> u64 {
    // FNV-1a of the name, then one SplitMix64 round with the seed.
    let mut h: u64 = 0xCBF2_9CE4_8422_2325;
    for b in file.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01B3);
    }
    SplitMix64::new(seed ^ h).next_u64()
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
        let mut r = SplitMix64::new(7);
        let n = 200_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let z = r.normal();
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
    }
}
