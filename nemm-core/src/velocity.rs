//! Causal stroke-velocity estimate of an online estimator: a backward difference of the
//! measured stroke followed by a first-order low-pass, the velocity a controller hands to
//! [`crate::Estimator::step`] every sample.
//!
//! Per sample `n` of the stroke `x_n` at rate `fs`:
//!
//! ```text
//! raw_n = (x_n - x_n-1) * fs                backward difference [m/s]
//! v_n   = fma(a, raw_n - v_n-1, v_n-1)      a = w / (1 + w),  w = 2 pi fc / fs
//! ```
//!
//! a backward-Euler RC low-pass with corner `fc` (default [`DEFAULT_CUTOFF_HZ`]), seeded with
//! the first raw difference (no start-up transient). At 10 kHz and `fc` = 500 Hz the group
//! delay at low frequency is `1/(2 pi fc) + 1/(2 fs)` = 0.37 ms, i.e. 4 degrees of phase at
//! 30 Hz (the top of the model's frequency range, paper section 4).
//!
//! [`Differentiator`] runs it on integer ADC codes (the difference of two codes is exact,
//! then one multiplication by `metres_per_lsb * fs`), as the firmware's sensor driver does;
//! [`LowPass`] is the filter alone, which the trainer runs on the backward differences of a
//! recorded stroke to train on the velocity the firmware sees. Both are `f32`, as on the
//! target.

use nemm_kernels::math::fma;

/// Default corner frequency of the velocity low-pass \[Hz\].
pub const DEFAULT_CUTOFF_HZ: f32 = 500.0;

/// First-order low-pass `v_n = v_n-1 + a (raw_n - v_n-1)`, seeded with its first input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LowPass {
    a: f32,
    v: Option<f32>,
}

impl LowPass {
    /// Backward-Euler RC with corner `cutoff_hz` at `sample_rate_hz`: `a = w / (1 + w)`,
    /// `w = 2 pi cutoff_hz / sample_rate_hz`. A corner that is not positive and finite (or a
    /// rate that is not) gives `a` outside `(0, 1]`; callers validate their configuration.
    pub fn new(sample_rate_hz: f32, cutoff_hz: f32) -> Self {
        let w = 2.0 * core::f32::consts::PI * cutoff_hz / sample_rate_hz;
        Self {
            a: w / (1.0 + w),
            v: None,
        }
    }

    /// Coefficient `a`.
    pub fn coefficient(&self) -> f32 {
        self.a
    }

    /// Filters the next input; the first input after [`LowPass::reset`] passes unchanged.
    pub fn push(&mut self, raw: f32) -> f32 {
        let v = match self.v {
            None => raw,
            Some(v) => fma(self.a, raw - v, v),
        };
        self.v = Some(v);
        v
    }

    /// Forgets the state: the next input seeds the filter.
    pub fn reset(&mut self) {
        self.v = None;
    }
}

/// Backward difference of integer stroke codes plus [`LowPass`]: the velocity \[m/s\] of a
/// stroke transducer read once per sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Differentiator {
    k: f32,
    last_code: Option<i32>,
    low_pass: LowPass,
}

impl Differentiator {
    /// Filter for codes of `metres_per_lsb` sampled at `sample_rate_hz`, low-pass corner
    /// `cutoff_hz`.
    pub fn new(metres_per_lsb: f32, sample_rate_hz: f32, cutoff_hz: f32) -> Self {
        Self {
            k: metres_per_lsb * sample_rate_hz,
            last_code: None,
            low_pass: LowPass::new(sample_rate_hz, cutoff_hz),
        }
    }

    /// Low-pass coefficient `a`.
    pub fn coefficient(&self) -> f32 {
        self.low_pass.coefficient()
    }

    /// Next good code; `None` while priming (the first code after start-up or
    /// [`Differentiator::invalidate`]), else the filtered velocity \[m/s\].
    pub fn push(&mut self, code: i32) -> Option<f32> {
        let prev = self.last_code.replace(code)?;
        let raw = code.wrapping_sub(prev) as f32 * self.k;
        Some(self.low_pass.push(raw))
    }

    /// Forgets the history after a missing sample: the next code primes again and the one
    /// after it seeds the low-pass with its raw difference.
    pub fn invalidate(&mut self) {
        self.last_code = None;
        self.low_pass.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_pass_step_response_matches_its_formula() {
        let lsb = 1.2e-8f32;
        let mut d = Differentiator::new(lsb, 10_000.0, 500.0);
        let a = f64::from(d.coefficient());
        let w = 2.0 * core::f64::consts::PI * 500.0 / 10_000.0;
        assert!((a - w / (1.0 + w)).abs() < 1e-7);
        // Rest, then a ramp of 100 LSB per sample: v_n = raw (1 - (1 - a)^n) after the seed 0.
        assert_eq!(d.push(0), None);
        assert_eq!(d.push(0), Some(0.0));
        let raw = 100.0 * f64::from(lsb) * 10_000.0;
        for n in 1..50 {
            let v = f64::from(d.push(100 * n).unwrap());
            let expect = raw * (1.0 - (1.0 - a).powi(n));
            assert!((v - expect).abs() < 1e-5 * raw, "{n}: {v} vs {expect}");
        }
    }

    #[test]
    fn invalidate_reprimes_and_reseeds() {
        let mut d = Differentiator::new(1e-6, 10_000.0, 500.0);
        let v = 30.0 * (1e-6f32 * 10_000.0);
        assert_eq!(d.push(0), None);
        assert_eq!(d.push(30), Some(v));
        d.invalidate();
        assert_eq!(d.push(1000), None);
        // Seeded with the raw difference of the new direction, no transient from before.
        assert_eq!(d.push(970), Some(-v));
        // The low-pass alone: the same arithmetic as the differentiator's.
        let mut lp = LowPass::new(10_000.0, 500.0);
        assert_eq!(lp.push(v), v);
        let mut d = Differentiator::new(1e-6, 10_000.0, 500.0);
        d.push(0);
        d.push(30);
        assert_eq!(d.push(30), Some(lp.push(0.0)));
    }
}
