//! The test programme: the grid of runs, their excitation and their lengths.
//!
//! Two kinds of runs: the sinusoidal grid of Table 1 (the default) and, when the configuration
//! has a `[program.random]` table, band-limited random excitation (a random-phase multisine
//! whose velocity spectrum is flat in a band). Either kind can carry an oil-loss schedule
//! (`[program.alpha_schedule]`): alpha changing in segments within the run.

use super::config::{AlphaScheduleProgram, Program, RandomProgram};
use super::sensor::run_rng;
use rand::RngExt;
use std::f64::consts::PI;
use std::path::PathBuf;

/// Sinusoidal stroke `x(t) = A w(t) sin(omega t)` with a raised-cosine amplitude ramp
/// `w(t) = (1 - cos(pi t / T_ramp)) / 2` for `t < T_ramp`, 1 afterwards.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sine {
    /// Stroke amplitude \[m\].
    pub amplitude_m: f64,
    /// Angular frequency \[rad/s\].
    pub omega: f64,
    /// Ramp-in length \[s\].
    pub ramp_s: f64,
}

/// One component of a [`Multisine`]: velocity `c cos(omega t + phase)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Component {
    /// Angular frequency \[rad/s\].
    pub omega: f64,
    /// Velocity amplitude \[m/s\].
    pub velocity_m_s: f64,
    /// Phase \[rad\].
    pub phase: f64,
}

/// Band-limited random stroke: the random-phase multisine
/// `v_0(t) = sum_k c cos(omega_k t + phi_k)`, `x_0(t) = sum_k (c / omega_k) sin(omega_k t + phi_k)`
/// with the frequencies `f_k = k / T` (`T` the run's steady duration) inside the band, equal
/// amplitudes `c` (a flat velocity spectrum) and independent uniform phases `phi_k`, so that
/// the velocity is close to Gaussian band-limited white noise and does not repeat within the
/// run. The stroke is `x(t) = w(t) x_0(t)` with the raised-cosine ramp `w` of [`Sine`].
#[derive(Debug, Clone, PartialEq)]
pub struct Multisine {
    /// The components.
    pub components: Vec<Component>,
    /// Ramp-in length \[s\].
    pub ramp_s: f64,
}

/// The stroke of one run.
#[derive(Debug, Clone, PartialEq)]
pub enum Excitation {
    /// Table 1 sinusoid.
    Sine(Sine),
    /// Band-limited random excitation.
    Random(Multisine),
}

/// Raised-cosine envelope `w(t)` and its derivative for a ramp of `ramp_s`.
fn envelope(t: f64, ramp_s: f64) -> (f64, f64) {
    if t >= ramp_s {
        (1.0, 0.0)
    } else if t <= 0.0 {
        (0.0, 0.0)
    } else {
        let a = PI * t / ramp_s;
        (0.5 * (1.0 - a.cos()), 0.5 * PI / ramp_s * a.sin())
    }
}

impl Sine {
    /// Displacement \[m\] at time `t` \[s\].
    pub fn position(&self, t: f64) -> f64 {
        self.amplitude_m * envelope(t, self.ramp_s).0 * (self.omega * t).sin()
    }

    /// Velocity \[m/s\] at time `t` \[s\].
    pub fn velocity(&self, t: f64) -> f64 {
        let (w, dw) = envelope(t, self.ramp_s);
        let (s, c) = (self.omega * t).sin_cos();
        self.amplitude_m * (dw * s + w * self.omega * c)
    }
}

impl Multisine {
    /// `(x_0(t), v_0(t))` without the ramp.
    fn steady(&self, t: f64) -> (f64, f64) {
        self.components.iter().fold((0.0, 0.0), |(x, v), c| {
            let (s, co) = (c.omega * t + c.phase).sin_cos();
            (x + c.velocity_m_s / c.omega * s, v + c.velocity_m_s * co)
        })
    }

    /// Displacement \[m\] at time `t` \[s\].
    pub fn position(&self, t: f64) -> f64 {
        envelope(t, self.ramp_s).0 * self.steady(t).0
    }

    /// Velocity \[m/s\] at time `t` \[s\].
    pub fn velocity(&self, t: f64) -> f64 {
        let (w, dw) = envelope(t, self.ramp_s);
        let (x, v) = self.steady(t);
        dw * x + w * v
    }

    /// RMS of the steady velocity `v_0` \[m/s\] (`c sqrt(K / 2)`).
    pub fn velocity_rms_m_s(&self) -> f64 {
        (self
            .components
            .iter()
            .map(|c| c.velocity_m_s.powi(2))
            .sum::<f64>()
            / 2.0)
            .sqrt()
    }
}

impl Excitation {
    /// Displacement \[m\] at time `t` \[s\].
    pub fn position(&self, t: f64) -> f64 {
        match self {
            Excitation::Sine(s) => s.position(t),
            Excitation::Random(m) => m.position(t),
        }
    }

    /// Velocity \[m/s\] at time `t` \[s\].
    pub fn velocity(&self, t: f64) -> f64 {
        match self {
            Excitation::Sine(s) => s.velocity(t),
            Excitation::Random(m) => m.velocity(t),
        }
    }

    /// Ramp-in length \[s\].
    pub fn ramp_s(&self) -> f64 {
        match self {
            Excitation::Sine(s) => s.ramp_s,
            Excitation::Random(m) => m.ramp_s,
        }
    }

    /// Length of the stretch after the ramp over which the free gas is conditioned \[s\]:
    /// one period of a sine; the period of the lowest component of a multisine.
    pub fn conditioning_span_s(&self) -> f64 {
        match self {
            Excitation::Sine(s) => 2.0 * PI / s.omega,
            Excitation::Random(m) => m
                .components
                .iter()
                .map(|c| 2.0 * PI / c.omega)
                .fold(0.0, f64::max),
        }
    }
}

/// One segment of an oil-loss schedule: alpha from `start_s` until the next segment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlphaSegment {
    /// Start of the segment \[s\] (the first segment starts at 0).
    pub start_s: f64,
    /// Oil loss alpha \[-\] during the segment.
    pub alpha: f64,
}

/// One run of the programme.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSpec {
    /// Oil loss alpha \[-\] (at the start of the run when it has a schedule).
    pub oil_loss: f64,
    /// Stroke amplitude \[m\] (random runs: the largest `|x|` of the steady stroke).
    pub amplitude_m: f64,
    /// Target peak velocity \[m/s\] (random runs: `sqrt(2)` times the velocity RMS).
    pub peak_velocity_m_s: f64,
    /// Excitation frequency \[Hz\] = v / (2 pi A) (random runs: `1 / T`, the spacing of the
    /// multisine's lines).
    pub frequency_hz: f64,
    /// Ramp-in length \[s\].
    pub ramp_s: f64,
    /// Number of full-amplitude periods after the ramp (random runs: 1, the duration `T`).
    pub steady_periods: u32,
    /// Number of output samples.
    pub samples: usize,
    /// CSV path relative to the dataset folder, e.g. `runs/oil15_a010_v0524.csv`.
    pub file: PathBuf,
    /// The random stroke of a random run (`None`: the sine of the other fields).
    pub random: Option<Multisine>,
    /// Oil-loss schedule (empty: `oil_loss` throughout).
    pub alpha_segments: Vec<AlphaSegment>,
}

impl RunSpec {
    /// The excitation of this run.
    pub fn excitation(&self) -> Excitation {
        match &self.random {
            Some(m) => Excitation::Random(m.clone()),
            None => Excitation::Sine(Sine {
                amplitude_m: self.amplitude_m,
                omega: 2.0 * PI * self.frequency_hz,
                ramp_s: self.ramp_s,
            }),
        }
    }

    /// Total duration \[s\].
    pub fn duration_s(&self) -> f64 {
        self.ramp_s + f64::from(self.steady_periods) / self.frequency_hz
    }

    /// Oil loss at time `t` \[s\].
    pub fn alpha_at(&self, t: f64) -> f64 {
        self.alpha_segments
            .iter()
            .take_while(|s| s.start_s <= t)
            .last()
            .map_or(self.oil_loss, |s| s.alpha)
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
        random: None,
        alpha_segments: Vec::new(),
    }
}

/// Builds one random run (see [`Multisine`]): lines `f_k = k / T` in `band_hz`, `T =
/// duration_s`, amplitudes for the velocity RMS `velocity_rms_m_s`, phases drawn from
/// [`run_rng`]`(r.seed, file)`; if the steady stroke (evaluated at the sample times) would
/// exceed `max_stroke_m`, every amplitude is scaled down to meet it (the velocity RMS falls by
/// the same factor).
pub fn random_run_spec(
    p: &Program,
    r: &RandomProgram,
    oil_loss: f64,
    velocity_rms_m_s: f64,
) -> RunSpec {
    let t = r.duration_s;
    let file = PathBuf::from(format!(
        "runs/oil{:02}_random_v{:04}.csv",
        (oil_loss * 100.0).round() as u32,
        (velocity_rms_m_s * 1000.0).round() as u32
    ));
    let mut rng = run_rng(r.seed, &file.to_string_lossy());
    let (lo, hi) = (r.band_hz[0], r.band_hz[1]);
    let lines: Vec<f64> = ((lo * t).ceil() as u64..=(hi * t).floor() as u64)
        .map(|k| k as f64 / t)
        .filter(|f| *f > 0.0)
        .collect();
    let c = velocity_rms_m_s * (2.0 / lines.len().max(1) as f64).sqrt();
    let mut m = Multisine {
        components: lines
            .iter()
            .map(|f| Component {
                omega: 2.0 * PI * f,
                velocity_m_s: c,
                phase: 2.0 * PI * rng.random::<f64>(),
            })
            .collect(),
        ramp_s: r.ramp_s,
    };
    let samples = ((r.ramp_s + t) * p.sample_rate_hz).round() as usize + 1;
    let stroke = (0..samples)
        .map(|i| m.steady(i as f64 / p.sample_rate_hz).0.abs())
        .fold(0.0f64, f64::max);
    if stroke > r.max_stroke_m {
        let k = r.max_stroke_m / stroke;
        for comp in &mut m.components {
            comp.velocity_m_s *= k;
        }
    }
    RunSpec {
        oil_loss,
        amplitude_m: stroke.min(r.max_stroke_m),
        peak_velocity_m_s: std::f64::consts::SQRT_2 * m.velocity_rms_m_s(),
        frequency_hz: 1.0 / t,
        ramp_s: r.ramp_s,
        steady_periods: 1,
        samples,
        file,
        random: Some(m),
        alpha_segments: Vec::new(),
    }
}

/// Draws the oil-loss schedule of a run: segments of uniform random length in
/// `[min_segment_s, max_segment_s]` until the end of the run, the first at the run's own
/// level, each following one at a level drawn uniformly from the other `levels`; the generator
/// is [`run_rng`]`(s.seed, "alpha_schedule:" + file)`.
pub fn alpha_schedule(
    spec: &RunSpec,
    s: &AlphaScheduleProgram,
    levels: &[f64],
) -> Vec<AlphaSegment> {
    let mut rng = run_rng(
        s.seed,
        &format!("alpha_schedule:{}", spec.file.to_string_lossy()),
    );
    let duration = spec.duration_s();
    let mut out = vec![AlphaSegment {
        start_s: 0.0,
        alpha: spec.oil_loss,
    }];
    let mut t = 0.0;
    loop {
        t += s.min_segment_s + (s.max_segment_s - s.min_segment_s) * rng.random::<f64>();
        if t >= duration {
            break;
        }
        let current = out.last().map_or(spec.oil_loss, |seg| seg.alpha);
        let others: Vec<f64> = levels.iter().copied().filter(|a| *a != current).collect();
        if others.is_empty() {
            break;
        }
        let pick = ((rng.random::<f64>() * others.len() as f64) as usize).min(others.len() - 1);
        out.push(AlphaSegment {
            start_s: t,
            alpha: others[pick],
        });
    }
    out
}

/// The whole programme: the Table 1 grid ordered by oil loss, amplitude, velocity, or, with
/// `[program.random]`, the random runs ordered by oil loss and velocity RMS; with
/// `[program.alpha_schedule]` every run gets a schedule over the `oil_loss` levels.
pub fn grid(p: &Program) -> Vec<RunSpec> {
    let mut runs = Vec::new();
    for &alpha in &p.oil_loss {
        match &p.random {
            Some(r) => {
                for &v in &r.velocity_rms_m_s {
                    runs.push(random_run_spec(p, r, alpha, v));
                }
            }
            None => {
                for &amp in &p.amplitudes_m {
                    for &v in &p.peak_velocities_m_s {
                        runs.push(run_spec(p, alpha, amp, v));
                    }
                }
            }
        }
    }
    if let Some(s) = &p.alpha_schedule {
        for r in &mut runs {
            r.alpha_segments = alpha_schedule(r, s, &p.oil_loss);
        }
    }
    runs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::BenchConfig;

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

    fn random_program() -> (Program, RandomProgram) {
        let mut p = BenchConfig::default().program;
        p.sample_rate_hz = 1000.0;
        let r = RandomProgram {
            seed: 3,
            velocity_rms_m_s: vec![0.1],
            band_hz: [1.0, 20.0],
            duration_s: 2.0,
            ramp_s: 0.1,
            max_stroke_m: 0.05,
        };
        (p, r)
    }

    #[test]
    fn random_excitation_has_a_flat_velocity_spectrum_in_its_band() {
        let (p, r) = random_program();
        let spec = random_run_spec(&p, &r, 0.0, 0.1);
        assert_eq!(spec.file, PathBuf::from("runs/oil00_random_v0100.csv"));
        let m = spec.random.clone().unwrap();
        // Lines k / T for k = 2..=40, all of one amplitude.
        assert_eq!(m.components.len(), 39);
        // DFT of the steady velocity over one repetition T at every line k / T.
        let n = (r.duration_s * p.sample_rate_hz) as usize;
        let v: Vec<f64> = (0..n)
            .map(|i| m.steady(i as f64 / p.sample_rate_hz).1)
            .collect();
        let rms = (v.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        assert!((rms / 0.1 - 1.0).abs() < 1e-6, "{rms}");
        let c = 0.1 * (2.0f64 / 39.0).sqrt();
        for k in 0..60 {
            let f = k as f64 / r.duration_s;
            let (mut re, mut im) = (0.0, 0.0);
            for (i, x) in v.iter().enumerate() {
                let ph = 2.0 * PI * f * i as f64 / p.sample_rate_hz;
                re += x * ph.cos();
                im += x * ph.sin();
            }
            let amp = 2.0 * re.hypot(im) / n as f64;
            let expect = if (1.0..=20.0).contains(&f) { c } else { 0.0 };
            assert!(
                (amp - expect).abs() < 1e-9,
                "line {f} Hz: {amp} vs {expect}"
            );
        }
        // Velocity is the derivative of the position, ramp included.
        for i in 0..300 {
            let t = i as f64 * 7.3e-3;
            let h = 1e-6;
            let num = (m.position(t + h) - m.position(t - h)) / (2.0 * h);
            assert!((num - m.velocity(t)).abs() < 1e-6, "t {t}");
        }
        // Same seed and file: same phases; another seed: others.
        assert_eq!(random_run_spec(&p, &r, 0.0, 0.1), spec);
        let other = RandomProgram {
            seed: 4,
            ..r.clone()
        };
        assert_ne!(random_run_spec(&p, &other, 0.0, 0.1).random, spec.random);
    }

    #[test]
    fn random_stroke_is_limited_by_scaling_the_amplitudes() {
        let (p, mut r) = random_program();
        r.band_hz = [0.5, 5.0];
        let free = random_run_spec(&p, &r, 0.0, 0.3);
        r.max_stroke_m = 0.5 * free.amplitude_m;
        let limited = random_run_spec(&p, &r, 0.0, 0.3);
        assert!((limited.amplitude_m - r.max_stroke_m).abs() < 1e-12);
        let ratio = limited.peak_velocity_m_s / free.peak_velocity_m_s;
        assert!((ratio - 0.5).abs() < 1e-9, "{ratio}");
    }

    #[test]
    fn alpha_schedule_alternates_levels_in_segments_of_the_configured_length() {
        let (p, r) = random_program();
        let spec = random_run_spec(&p, &r, 0.15, 0.1);
        let s = AlphaScheduleProgram {
            seed: 9,
            min_segment_s: 0.1,
            max_segment_s: 0.3,
        };
        let seg = alpha_schedule(&spec, &s, &[0.0, 0.15, 0.3]);
        assert!(seg.len() >= 7, "{seg:?}");
        assert_eq!(seg[0].start_s, 0.0);
        assert_eq!(seg[0].alpha, 0.15);
        for w in seg.windows(2) {
            let d = w[1].start_s - w[0].start_s;
            assert!((0.1..=0.3).contains(&d), "{seg:?}");
            assert_ne!(w[0].alpha, w[1].alpha);
        }
        assert!(seg.last().unwrap().start_s < spec.duration_s());
        let mut with = spec.clone();
        with.alpha_segments = seg.clone();
        assert_eq!(with.alpha_at(0.0), 0.15);
        assert_eq!(with.alpha_at(seg[2].start_s + 1e-9), seg[2].alpha);
    }
}
