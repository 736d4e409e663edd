//! The test programme: the grid of runs, their excitation and their lengths.

use super::config::Program;
use std::f64::consts::PI;
use std::path::PathBuf;

/// Sinusoidal stroke `x(t) = A w(t) sin(omega t)` with a raised-cosine amplitude ramp
/// `w(t) = (1 - cos(pi t / T_ramp)) / 2` for `t < T_ramp`, 1 afterwards.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Excitation {
    /// Stroke amplitude \[m\].
    pub amplitude_m: f64,
    /// Angular frequency \[rad/s\].
    pub omega: f64,
    /// Ramp-in length \[s\].
    pub ramp_s: f64,
}

impl Excitation {
    /// Displacement \[m\] at time `t` \[s\].
    pub fn position(&self, t: f64) -> f64 {
        self.amplitude_m * self.envelope(t).0 * (self.omega * t).sin()
    }

    /// Velocity \[m/s\] at time `t` \[s\].
    pub fn velocity(&self, t: f64) -> f64 {
        let (w, dw) = self.envelope(t);
        let (s, c) = (self.omega * t).sin_cos();
        self.amplitude_m * (dw * s + w * self.omega * c)
    }

    fn envelope(&self, t: f64) -> (f64, f64) {
        if t >= self.ramp_s {
            (1.0, 0.0)
        } else if t <= 0.0 {
            (0.0, 0.0)
        } else {
            let a = PI * t / self.ramp_s;
            (0.5 * (1.0 - a.cos()), 0.5 * PI / self.ramp_s * a.sin())
        }
    }
}

/// One run of the programme.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSpec {
    /// Oil loss alpha \[-\].
    pub oil_loss: f64,
    /// Stroke amplitude \[m\].
    pub amplitude_m: f64,
    /// Target peak velocity \[m/s\].
    pub peak_velocity_m_s: f64,
    /// Excitation frequency \[Hz\] = v / (2 pi A).
    pub frequency_hz: f64,
    /// Ramp-in length \[s\].
    pub ramp_s: f64,
    /// Number of full-amplitude periods after the ramp.
    pub steady_periods: u32,
    /// Number of output samples.
    pub samples: usize,
    /// CSV path relative to the dataset folder, e.g. `runs/oil15_a010_v0524.csv`.
    pub file: PathBuf,
}

impl RunSpec {
    /// The excitation of this run.
    pub fn excitation(&self) -> Excitation {
        Excitation {
            amplitude_m: self.amplitude_m,
            omega: 2.0 * PI * self.frequency_hz,
            ramp_s: self.ramp_s,
        }
    }

    /// Total duration \[s\].
    pub fn duration_s(&self) -> f64 {
        self.ramp_s + f64::from(self.steady_periods) / self.frequency_hz
    }
}

/// Builds one run: ramp `min(ramp_periods T, max_ramp_s)`, then
/// `max(min_steady_periods, ceil(min_steady_s / T))` full periods, sampled at `fs`.
pub fn run_spec(p: &Program, oil_loss: f64, amplitude_m: f64, peak_velocity_m_s: f64) -> RunSpec {
    let frequency_hz = peak_velocity_m_s / (2.0 * PI * amplitude_m);
    let period = 1.0 / frequency_hz;
    let ramp_s = (p.ramp_periods * period).min(p.max_ramp_s);
    let by_time = (p.min_steady_s / period - 1e-9).ceil().max(0.0) as u32;
    let steady_periods = p.min_steady_periods.max(by_time);
    let duration = ramp_s + f64::from(steady_periods) * period;
    let samples = (duration * p.sample_rate_hz).round() as usize + 1;
    let file = PathBuf::from(format!(
        "runs/oil{:02}_a{:03}_v{:04}.csv",
        (oil_loss * 100.0).round() as u32,
        (amplitude_m * 1000.0).round() as u32,
        (peak_velocity_m_s * 1000.0).round() as u32
    ));
    RunSpec {
        oil_loss,
        amplitude_m,
        peak_velocity_m_s,
        frequency_hz,
        ramp_s,
        steady_periods,
        samples,
        file,
    }
}

/// The whole grid, ordered by oil loss, amplitude, velocity.
pub fn grid(p: &Program) -> Vec<RunSpec> {
    let mut runs = Vec::new();
    for &alpha in &p.oil_loss {
        for &amp in &p.amplitudes_m {
            for &v in &p.peak_velocities_m_s {
                runs.push(run_spec(p, alpha, amp, v));
            }
        }
    }
    runs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::config::BenchConfig;

    #[test]
    fn excitation_velocity_is_the_derivative_and_peaks_at_target() {
        let p = BenchConfig::default().program;
        let r = run_spec(&p, 0.15, 0.01, 0.524);
        assert_eq!(r.file, PathBuf::from("runs/oil15_a010_v0524.csv"));
        let e = r.excitation();
        let mut vmax: f64 = 0.0;
        let mut t = 0.0;
        while t < r.duration_s() {
            let h = 1e-6;
            let num = (e.position(t + h) - e.position(t - h)) / (2.0 * h);
            assert!((num - e.velocity(t)).abs() < 1e-5, "t {t}");
            if t > r.ramp_s {
                vmax = vmax.max(e.velocity(t).abs());
            }
            t += 1.3e-3;
        }
        assert!((vmax / 0.524 - 1.0).abs() < 1e-3, "{vmax}");
    }

    #[test]
    fn run_lengths_follow_the_documented_rule() {
        let p = BenchConfig::default().program;
        let slow = run_spec(&p, 0.0, 0.05, 0.052);
        let period = 1.0 / slow.frequency_hz;
        assert!((period - 6.0415).abs() < 1e-3);
        assert_eq!(slow.ramp_s, p.max_ramp_s); // capped
        assert_eq!(slow.steady_periods, 2);
        let fast = run_spec(&p, 0.0, 0.01, 1.048);
        assert!((fast.ramp_s * fast.frequency_hz - p.ramp_periods).abs() < 1e-12);
        assert!(f64::from(fast.steady_periods) / fast.frequency_hz >= p.min_steady_s);
        assert_eq!(grid(&p).len(), 54);
    }
}
