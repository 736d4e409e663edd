//! Filtering and differentiation: the zero-phase low-pass, the derivative stencils, the causal velocity of the firmware, and the per-run signals.

use super::{
    config_err, excitation_frequency_hz, median, PreprocessError, CUTOFF_FRACTION_OF_RATE,
    DEFAULT_CUTOFF_HZ,
};
use nemm_dataset::Dataset;
use nemm_dataset::Run;
use serde::Deserialize;
use serde::Serialize;

/// A biquad section `H(z) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)`.
#[derive(Debug, Clone, Copy)]
struct Biquad {
    b0: f64,
    b1: f64,
    b2: f64,
    a1: f64,
    a2: f64,
}

impl Biquad {
    /// 2nd-order Butterworth low-pass (bilinear transform with pre-warping).
    fn butterworth_lowpass(sample_rate_hz: f64, cutoff_hz: f64) -> Self {
        let w0 = 2.0 * std::f64::consts::PI * cutoff_hz / sample_rate_hz;
        let (s, c) = w0.sin_cos();
        let alpha = s * std::f64::consts::FRAC_1_SQRT_2; // sin(w0) / (2 Q), Q = 1/sqrt(2)
        let a0 = 1.0 + alpha;
        Biquad {
            b0: (1.0 - c) / 2.0 / a0,
            b1: (1.0 - c) / a0,
            b2: (1.0 - c) / 2.0 / a0,
            a1: -2.0 * c / a0,
            a2: (1.0 - alpha) / a0,
        }
    }

    /// Filters `x` in place (transposed direct form II), starting in the steady state of a
    /// constant input `x[0]` (unit DC gain), so that a padded signal starts without a jump.
    fn filter(&self, x: &mut [f64]) {
        let Some(&first) = x.first() else { return };
        let mut z2 = (self.b2 - self.a2) * first;
        let mut z1 = (self.b1 - self.a1) * first + z2;
        for v in x.iter_mut() {
            let input = *v;
            let y = self.b0 * input + z1;
            z1 = self.b1 * input - self.a1 * y + z2;
            z2 = self.b2 * input - self.a2 * y;
            *v = y;
        }
    }
}

/// Checks a low-pass cut-off against the sample rate (once per dataset: [`SignalConfig::at_rate`]).
fn check_cutoff(sample_rate_hz: f64, cutoff_hz: f64) -> Result<(), PreprocessError> {
    if !(cutoff_hz.is_finite() && cutoff_hz > 0.0 && cutoff_hz < 0.5 * sample_rate_hz) {
        return Err(config_err(
            "cutoff_hz",
            format!(
                "{cutoff_hz} Hz must be positive and below half the sample rate ({} Hz)",
                0.5 * sample_rate_hz
            ),
        ));
    }
    Ok(())
}

/// Odd coefficients `(b, d)` of the least-squares cubic `x = a + b t + c t^2 + d t^3`
/// through `(t, x)` pairs (`(0, 0)` if the fit is singular).
fn cubic_odd_coefficients(points: &[(f64, f64)]) -> (f64, f64) {
    // Normal equations with t scaled to [-1, 1] for conditioning.
    let scale = points
        .iter()
        .fold(0.0f64, |m, (t, _)| m.max(t.abs()))
        .max(1.0);
    let mut m = [[0.0f64; 5]; 4]; // augmented 4 x 4 system
    for &(t, x) in points {
        let t = t / scale;
        let p = [1.0, t, t * t, t * t * t];
        for (i, row) in m.iter_mut().enumerate() {
            for j in 0..4 {
                row[j] += p[i] * p[j];
            }
            row[4] += p[i] * x;
        }
    }
    // Gaussian elimination with partial pivoting.
    for col in 0..4 {
        let Some(pivot) = (col..4).max_by(|&i, &j| m[i][col].abs().total_cmp(&m[j][col].abs()))
        else {
            return (0.0, 0.0);
        };
        if m[pivot][col].abs() < 1e-300 {
            return (0.0, 0.0);
        }
        m.swap(col, pivot);
        let pivot_row = m[col];
        for row in m.iter_mut().skip(col + 1) {
            let f = row[col] / pivot_row[col];
            for (r, p) in row.iter_mut().zip(pivot_row.iter()).skip(col) {
                *r -= f * p;
            }
        }
    }
    let mut c = [0.0f64; 4];
    for row in (0..4).rev() {
        let tail: f64 = (row + 1..4).map(|k| m[row][k] * c[k]).sum();
        c[row] = (m[row][4] - tail) / m[row][row];
    }
    (c[1] / scale, c[3] / scale.powi(3))
}

/// Zero-phase low-pass: the 2nd-order Butterworth biquad forward then backward over the
/// signal padded at both ends by `3 fs / fc` samples, starting in steady state.
///
/// The padding mirrors the signal about its end sample and adds back twice the odd part of
/// a least-squares cubic fitted to the last `2 fs / fc` samples
/// (`x_ext(n - 1 + k) = x(n - 1 - k) + 2 (b k + d k^3)`), so that value, slope, curvature and
/// third derivative continue smoothly into the pad: a plain odd reflection would flip the
/// curvature and distort the ends of a fast stroke. Short signals (fewer samples than the
/// pad or the fit) use what they have. The result has the length of `x`.
pub fn lowpass_zero_phase(
    x: &[f64],
    sample_rate_hz: f64,
    cutoff_hz: f64,
) -> Result<Vec<f64>, PreprocessError> {
    check_cutoff(sample_rate_hz, cutoff_hz)?;
    Ok(zero_phase(x, sample_rate_hz, cutoff_hz))
}

/// [`lowpass_zero_phase`] with a checked cut-off.
fn zero_phase(x: &[f64], sample_rate_hz: f64, cutoff_hz: f64) -> Vec<f64> {
    let n = x.len();
    if n < 2 {
        return x.to_vec();
    }
    let bq = Biquad::butterworth_lowpass(sample_rate_hz, cutoff_hz);
    let pad = ((3.0 * sample_rate_hz / cutoff_hz).ceil() as usize).min(n - 1);
    // The odd part of a cubic fitted to the last `2 fs / fc` samples continues the signal.
    let fit = ((sample_rate_hz / cutoff_hz).ceil() as usize).max(4).min(n);
    let start: Vec<(f64, f64)> = (0..fit).map(|i| (i as f64, x[i])).collect();
    let end: Vec<(f64, f64)> = (0..fit).map(|i| (-(i as f64), x[n - 1 - i])).collect();
    let (b0, d0) = cubic_odd_coefficients(&start);
    let (b1, d1) = cubic_odd_coefficients(&end);
    let odd = |b: f64, d: f64, k: f64| 2.0 * (b * k + d * k * k * k);
    let mut ext = Vec::with_capacity(n + 2 * pad);
    ext.extend((1..=pad).rev().map(|k| x[k] - odd(b0, d0, k as f64)));
    ext.extend_from_slice(x);
    ext.extend((1..=pad).map(|k| x[n - 1 - k] + odd(b1, d1, k as f64)));
    bq.filter(&mut ext);
    ext.reverse();
    bq.filter(&mut ext);
    ext.reverse();
    ext.truncate(pad + n);
    ext.drain(..pad);
    ext
}

/// Derivative of a signal sampled at step `dt`: central difference inside, second-order
/// one-sided differences at the ends (first-order with two samples, zero with one).
pub fn differentiate(x: &[f64], dt: f64) -> Vec<f64> {
    let n = x.len();
    match n {
        0 => Vec::new(),
        1 => vec![0.0],
        2 => {
            let d = (x[1] - x[0]) / dt;
            vec![d, d]
        }
        _ => {
            let h2 = 2.0 * dt;
            let mut d = Vec::with_capacity(n);
            d.push((-3.0 * x[0] + 4.0 * x[1] - x[2]) / h2);
            d.extend(x.windows(3).map(|w| (w[2] - w[0]) / h2));
            d.push((3.0 * x[n - 1] - 4.0 * x[n - 2] + x[n - 3]) / h2);
            d
        }
    }
}

/// The online estimate of the stroke velocity as the firmware computes it: the backward
/// difference of the recorded displacement `x` (sampled at `sample_rate_hz`) through
/// [`nemm_core::LowPass`] at its default corner
/// ([`nemm_core::DEFAULT_CUTOFF_HZ`]), in `f32` as on the target. The first sample,
/// which has no difference yet, is 0 (the firmware primes its filter there and the estimator
/// holds its input at rest). The firmware differentiates integer ADC codes
/// (`nemm_core::Differentiator`, same low-pass): the two differ by the ADC's
/// quantisation of the stroke only.
pub fn causal_velocity(x: &[f64], sample_rate_hz: f64) -> Vec<f64> {
    let mut low_pass = nemm_core::LowPass::new(sample_rate_hz as f32, nemm_core::DEFAULT_CUTOFF_HZ);
    let mut v = Vec::with_capacity(x.len());
    if !x.is_empty() {
        v.push(0.0);
    }
    v.extend(
        x.windows(2)
            .map(|w| f64::from(low_pass.push(((w[1] - w[0]) * sample_rate_hz) as f32))),
    );
    v
}

/// Where the velocity comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum VelocitySource {
    /// The measured `velocity_m_s` column when the run has one, else differentiation.
    #[default]
    Auto,
    /// Always differentiate the displacement.
    Differentiated,
    /// Always the measured column (a run without it is an error).
    Measured,
    /// What the firmware sees: the backward difference of the recorded displacement through
    /// the online estimator's first-order low-pass ([`causal_velocity`]), lag included.
    Causal,
}

/// How signals are derived from a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SignalConfig {
    /// Cut-off of the zero-phase low-pass \[Hz\], one for every run; `None` (the default):
    /// chosen per run from its displacement noise and excitation (`Cutoff`).
    pub cutoff_hz: Option<f64>,
    /// Velocity source (default [`VelocitySource::Auto`]).
    pub velocity_source: VelocitySource,
    /// Low-pass the force of the training sequences too (default `false`: raw force).
    pub filter_force: bool,
}

impl Default for SignalConfig {
    fn default() -> Self {
        SignalConfig {
            cutoff_hz: None,
            velocity_source: VelocitySource::Auto,
            filter_force: false,
        }
    }
}

/// The derived signals of one run, all of the run's length.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Signals {
    /// Low-passed displacement \[m\].
    pub displacement_m: Vec<f64>,
    /// Velocity \[m/s\] (see [`Signals::measured_velocity`]).
    pub velocity_m_s: Vec<f64>,
    /// Acceleration \[m/s^2\]: derivative of [`Signals::velocity_m_s`].
    pub acceleration_m_s2: Vec<f64>,
    /// Low-passed force \[N\] (for quasi-static extraction and plots).
    pub(crate) force_filtered_n: Vec<f64>,
    /// `true` if the velocity is the (filtered) measured column, `false` if differentiated.
    pub measured_velocity: bool,
    /// Condition level per sample (the run's `alpha` column, unfiltered), if it has one.
    pub alpha: Option<Vec<f64>>,
    /// The cut-off these signals were filtered with, and why.
    pub cutoff: Cutoff,
}

/// The automatic cut-off lets through displacement noise worth at most this fraction of the
/// run's RMS velocity ([`Cutoff`]).
pub(crate) const AUTO_CUTOFF_NOISE_FRACTION: f64 = 0.02;
/// The automatic cut-off stays at least this many times the run's excitation frequency (the
/// zero-phase filter's gain there is `1 / (1 + 1e-4)`: -0.01 %).
pub(crate) const AUTO_CUTOFF_EXCITATION_MULTIPLE: f64 = 10.0;

/// `integral_0^inf u^2 / (1 + u^4)^2 du = pi / (8 sqrt 2)`: the noise bandwidth of the
/// differentiated zero-phase low-pass, `|H(f)|^4 = 1 / (1 + (f / fc)^4)^2`, in units of
/// `fc^3`.
const DIFFERENTIATED_NOISE_BANDWIDTH: f64 = std::f64::consts::PI / (8.0 * std::f64::consts::SQRT_2);

/// Why a run's cut-off has its value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CutoffRule {
    /// Given (`--cutoff-hz` or the options file), the same for every run.
    Given,
    /// The rate's limit `min(150 Hz, 0.4 fs)`: the noise allows it, or the velocity is
    /// measured (no differentiation).
    #[default]
    RateLimit,
    /// Lowered until the displacement noise gives at most [`AUTO_CUTOFF_NOISE_FRACTION`] of
    /// the run's RMS velocity.
    Noise,
    /// The noise asks for less, but the cut-off stays [`AUTO_CUTOFF_EXCITATION_MULTIPLE`]
    /// times the excitation frequency: the velocity keeps more noise than the target.
    Excitation,
}

impl CutoffRule {
    /// The rule in words, for `data check`.
    pub fn describe(self) -> &'static str {
        match self {
            CutoffRule::Given => "given",
            CutoffRule::RateLimit => "rate limit",
            CutoffRule::Noise => "noise",
            CutoffRule::Excitation => "excitation",
        }
    }
}

/// A run's low-pass cut-off.
///
/// Chosen per run when no cut-off is given. The displacement noise is taken as white with
/// the standard deviation [`displacement_noise_std_m`] estimates from the raw samples; through
/// the zero-phase low-pass at `fc` and differentiation it gives a velocity noise of RMS
/// `sigma_v(fc) = 2 pi sigma_x sqrt(2 / fs * pi / (8 sqrt 2) * fc^3)`
/// ([`velocity_noise_rms`]). The run's RMS velocity without noise, `v_s`, is the RMS of the
/// velocity at the rate's limit `fc_max = min(150 Hz, 0.4 fs)` with `sigma_v(fc_max)` removed
/// in quadrature. The cut-off is then the largest `fc <= fc_max` with
/// `sigma_v(fc) <= AUTO_CUTOFF_NOISE_FRACTION * v_s` (rounded to three significant digits),
/// but at least [`AUTO_CUTOFF_EXCITATION_MULTIPLE`] times the excitation frequency (from the
/// displacement's zero crossings). Clean data keep `fc_max`; a 20 um potentiometer at 300 Hz
/// on a 0.21 Hz, 18.6 mm stroke gets about 16 Hz.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Cutoff {
    /// The cut-off \[Hz\].
    pub hz: f64,
    /// Why it has this value.
    pub rule: CutoffRule,
    /// Standard deviation of the displacement noise \[m\] ([`displacement_noise_std_m`]).
    pub(crate) displacement_noise_m: f64,
    /// RMS of the velocity noise this cut-off lets through, as a fraction of the run's RMS
    /// velocity; `None` for a measured velocity.
    pub(crate) velocity_noise_fraction: Option<f64>,
}

/// Standard deviation \[m\] of white noise on a displacement record, from its third
/// differences: `1.4826 median |x[i+3] - 3 x[i+2] + 3 x[i+1] - x[i]| / sqrt(20)` (the third
/// difference of white noise has 20 times its variance; the median ignores spikes, and the
/// stroke itself adds `(2 pi f / fs)^3 A`, negligible below a tenth of the rate). 0 for fewer
/// than 8 samples or a record that rarely changes (a slow, quantised stroke).
pub(crate) fn displacement_noise_std_m(displacement_m: &[f64]) -> f64 {
    if displacement_m.len() < 8 {
        return 0.0;
    }
    let d3: Vec<f64> = displacement_m
        .windows(4)
        .map(|w| (w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0]).abs())
        .filter(|d| d.is_finite())
        .collect();
    1.4826 * median(d3).unwrap_or(0.0) / 20f64.sqrt()
}

/// RMS \[m/s\] of the velocity that white displacement noise of standard deviation
/// `noise_m` gives through the zero-phase low-pass at `cutoff_hz` and differentiation, at
/// `sample_rate_hz` ([`Cutoff`]).
pub(crate) fn velocity_noise_rms(noise_m: f64, sample_rate_hz: f64, cutoff_hz: f64) -> f64 {
    let psd = 2.0 * noise_m * noise_m / sample_rate_hz;
    2.0 * std::f64::consts::PI * (psd * DIFFERENTIATED_NOISE_BANDWIDTH * cutoff_hz.powi(3)).sqrt()
}

/// `x` rounded to three significant digits.
fn three_digits(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return x;
    }
    let scale = 10f64.powi(2 - x.log10().floor() as i32);
    (x * scale).round() / scale
}

/// A [`SignalConfig`] checked against a dataset's sample rate ([`SignalConfig::at_rate`]):
/// what derives the signals of each of its runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignalPath {
    /// The configuration.
    pub config: SignalConfig,
    /// The sample rate of the runs \[Hz\].
    pub sample_rate_hz: f64,
}

impl SignalConfig {
    /// These settings at `sample_rate_hz`; refuses a given cut-off that is not positive and
    /// below half the sample rate (the one check of the cut-off).
    pub fn at_rate(&self, sample_rate_hz: f64) -> Result<SignalPath, PreprocessError> {
        if let Some(hz) = self.cutoff_hz {
            check_cutoff(sample_rate_hz, hz)?;
        }
        Ok(SignalPath {
            config: *self,
            sample_rate_hz,
        })
    }
}

impl SignalPath {
    /// The highest cut-off a run gets: the given one, else the rate's limit
    /// `min(DEFAULT_CUTOFF_HZ, 0.4 fs)` ([`Cutoff`]).
    pub(crate) fn max_cutoff_hz(&self) -> f64 {
        self.config
            .cutoff_hz
            .unwrap_or_else(|| DEFAULT_CUTOFF_HZ.min(CUTOFF_FRACTION_OF_RATE * self.sample_rate_hz))
    }

    /// Derives filtered displacement, velocity, acceleration and filtered force of a run,
    /// at the given cut-off or the one chosen for the run ([`Cutoff`]).
    ///
    /// `run_index` only labels errors.
    pub fn process(&self, run: &Run, run_index: usize) -> Result<Signals, PreprocessError> {
        check_lengths(run, run_index)?;
        let fc_max = self.max_cutoff_hz();
        let first = derive(run, run_index, self, fc_max)?;
        let cutoff = self.cutoff_of(run, &first, fc_max);
        if cutoff.hz == fc_max {
            return Ok(Signals { cutoff, ..first });
        }
        Ok(Signals {
            cutoff,
            ..derive(run, run_index, self, cutoff.hz)?
        })
    }

    /// The cut-off of `run`, from its signals at `fc_max` ([`Cutoff`]).
    fn cutoff_of(&self, run: &Run, at_max: &Signals, fc_max: f64) -> Cutoff {
        let fs = self.sample_rate_hz;
        let noise_m = displacement_noise_std_m(&run.displacement_m);
        let given = self.config.cutoff_hz.is_some();
        if at_max.measured_velocity {
            return Cutoff {
                hz: fc_max,
                rule: if given {
                    CutoffRule::Given
                } else {
                    CutoffRule::RateLimit
                },
                displacement_noise_m: noise_m,
                velocity_noise_fraction: None,
            };
        }
        let v = &at_max.velocity_m_s;
        let total = (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
        let noise_at_max = velocity_noise_rms(noise_m, fs, fc_max);
        // The noise-free RMS velocity; a record that is nearly all noise keeps a tenth of it.
        let signal = (total * total - noise_at_max * noise_at_max)
            .max(0.01 * total * total)
            .sqrt();
        let fraction =
            |hz: f64| (signal > 0.0).then(|| velocity_noise_rms(noise_m, fs, hz) / signal);
        let (hz, rule) = if given {
            (fc_max, CutoffRule::Given)
        } else {
            auto_cutoff_hz(&at_max.displacement_m, fs, noise_m, signal, fc_max)
        };
        Cutoff {
            hz,
            rule,
            displacement_noise_m: noise_m,
            velocity_noise_fraction: fraction(hz).or(Some(0.0)),
        }
    }
}

/// The automatic cut-off ([`Cutoff`]) for a run with displacement noise `noise_m` and
/// noise-free RMS velocity `signal_m_s`, not above `fc_max`; `displacement_m` (filtered at
/// `fc_max`) gives the excitation frequency.
fn auto_cutoff_hz(
    displacement_m: &[f64],
    sample_rate_hz: f64,
    noise_m: f64,
    signal_m_s: f64,
    fc_max: f64,
) -> (f64, CutoffRule) {
    // sigma_v(fc) = eps v_s  <=>  fc^3 = (eps v_s)^2 / (psd (2 pi)^2 bandwidth).
    let psd = 2.0 * noise_m * noise_m / sample_rate_hz;
    let target = AUTO_CUTOFF_NOISE_FRACTION * signal_m_s;
    let by_noise = if psd > 0.0 {
        (target * target
            / (psd * (2.0 * std::f64::consts::PI).powi(2) * DIFFERENTIATED_NOISE_BANDWIDTH))
            .cbrt()
    } else {
        f64::INFINITY
    };
    if by_noise >= fc_max {
        return (fc_max, CutoffRule::RateLimit);
    }
    let floor = excitation_frequency_hz(displacement_m, sample_rate_hz)
        .map_or(0.0, |f| AUTO_CUTOFF_EXCITATION_MULTIPLE * f);
    if by_noise >= floor {
        (three_digits(by_noise).min(fc_max), CutoffRule::Noise)
    } else {
        (three_digits(floor).min(fc_max), CutoffRule::Excitation)
    }
}

/// Derives filtered displacement, velocity, acceleration and filtered force of a run
/// (`SignalPath::process` at `sample_rate_hz`).
///
/// `run_index` only labels errors.
pub fn process_run(
    run: &Run,
    run_index: usize,
    sample_rate_hz: f64,
    cfg: &SignalConfig,
) -> Result<Signals, PreprocessError> {
    cfg.at_rate(sample_rate_hz)?.process(run, run_index)
}

/// Refuses a run whose columns differ in length.
fn check_lengths(run: &Run, run_index: usize) -> Result<(), PreprocessError> {
    let n = run.displacement_m.len();
    if run.time_s.len() != n
        || run.force_n.len() != n
        || run.velocity_m_s.as_ref().is_some_and(|v| v.len() != n)
        || run.alpha.as_ref().is_some_and(|a| a.len() != n)
    {
        return Err(PreprocessError::ColumnLengths {
            run: run_index,
            file: run.entry.file.clone(),
        });
    }
    Ok(())
}

/// The signals of `run` filtered at `cutoff_hz` (checked against the rate by the caller);
/// their [`Signals::cutoff`] says only the value.
fn derive(
    run: &Run,
    run_index: usize,
    path: &SignalPath,
    cutoff_hz: f64,
) -> Result<Signals, PreprocessError> {
    let (sample_rate_hz, cfg) = (path.sample_rate_hz, &path.config);
    let lowpass = |x: &[f64]| zero_phase(x, sample_rate_hz, cutoff_hz);
    let dt = 1.0 / sample_rate_hz;
    let displacement_m = lowpass(&run.displacement_m);
    let measured = match (cfg.velocity_source, &run.velocity_m_s) {
        (VelocitySource::Differentiated | VelocitySource::Causal, _) => None,
        (VelocitySource::Auto, v) => v.as_ref(),
        (VelocitySource::Measured, Some(v)) => Some(v),
        (VelocitySource::Measured, None) => {
            return Err(PreprocessError::NoMeasuredVelocity {
                run: run_index,
                file: run.entry.file.clone(),
            })
        }
    };
    let velocity_m_s = match measured {
        Some(v) => lowpass(v),
        None if cfg.velocity_source == VelocitySource::Causal => {
            causal_velocity(&run.displacement_m, sample_rate_hz)
        }
        None => differentiate(&displacement_m, dt),
    };
    let acceleration_m_s2 = differentiate(&velocity_m_s, dt);
    let force_filtered_n = lowpass(&run.force_n);
    Ok(Signals {
        displacement_m,
        velocity_m_s,
        acceleration_m_s2,
        force_filtered_n,
        measured_velocity: measured.is_some(),
        alpha: run.alpha.clone(),
        cutoff: Cutoff {
            hz: cutoff_hz,
            ..Cutoff::default()
        },
    })
}

/// [`process_run`] of every run of a dataset (in parallel), in dataset order.
pub fn run_signals(dataset: &Dataset, cfg: &SignalConfig) -> Result<Vec<Signals>, PreprocessError> {
    use rayon::prelude::*;
    let path = cfg.at_rate(dataset.sample_rate_hz)?;
    dataset
        .runs
        .par_iter()
        .enumerate()
        .map(|(i, r)| path.process(r, i))
        .collect()
}

/// Relative RMS difference between the run's displacement and its measured velocity column
/// integrated over time: a check of units and sign conventions. `None` without a measured
/// column.
///
/// The velocity is integrated with the trapezoidal rule, the difference to the displacement
/// is detrended (least-squares offset and slope removed: the integration constant and a
/// velocity bias) and its RMS is divided by the RMS of the detrended displacement.
/// Integration averages noise out, so an exact velocity column gives a small mismatch at any
/// excitation frequency (differentiating a quantised displacement instead would amplify its
/// noise on slow runs); a scale error `s` gives `|s - 1|`, a sign error about 2.
pub fn measured_velocity_mismatch(run: &Run, sample_rate_hz: f64) -> Option<f64> {
    let measured = run.velocity_m_s.as_ref()?;
    let dt = 1.0 / sample_rate_hz;
    let mut integral = 0.0;
    let mut diff = Vec::with_capacity(measured.len());
    for (i, x) in run.displacement_m.iter().enumerate() {
        if i > 0 {
            integral += 0.5 * dt * (measured[i - 1] + measured[i]);
        }
        diff.push(x - integral);
    }
    let err = detrended_rms(&diff);
    let norm = detrended_rms(&run.displacement_m);
    Some(if norm > 0.0 {
        err / norm
    } else if err > 0.0 {
        f64::INFINITY
    } else {
        0.0
    })
}

/// RMS of `y` after removing its least-squares line over the sample index.
fn detrended_rms(y: &[f64]) -> f64 {
    let n = y.len();
    if n < 2 {
        return 0.0;
    }
    let nf = n as f64;
    let i_mean = 0.5 * (nf - 1.0);
    let y_mean = y.iter().sum::<f64>() / nf;
    let sxy: f64 = y
        .iter()
        .enumerate()
        .map(|(i, v)| (i as f64 - i_mean) * (v - y_mean))
        .sum();
    let slope = sxy / (nf * (nf * nf - 1.0) / 12.0);
    let ss: f64 = y
        .iter()
        .enumerate()
        .map(|(i, v)| (v - y_mean - slope * (i as f64 - i_mean)).powi(2))
        .sum();
    (ss / nf).sqrt()
}
