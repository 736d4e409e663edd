//! Preprocessing of bench data for training (paper section 5.3): velocity and acceleration,
//! excitation estimates, quasi-static points for the flow-force model, sequences with warm-up
//! for the pressure-force model, the train / validation / test split of Table 2 and the
//! abs-max feature scales.
//!
//! # Signals
//!
//! * Displacement is low-passed with a zero-phase Butterworth filter: a 2nd-order Butterworth
//!   biquad (bilinear transform, pre-warped) run forward and backward ("filtfilt"), i.e. an
//!   effective 4th-order magnitude `|H|^2 = 1 / (1 + (tan(pi f / fs) / tan(pi fc / fs))^4)`
//!   with no phase shift. The default cut-off [`DEFAULT_CUTOFF_HZ`] = 150 Hz, five times the
//!   model's 30 Hz scope: the gain is -0.014 % at 16.7 Hz, -0.16 % at 30 Hz, -6 dB at 150 Hz.
//!   Edges are padded by a reflection that continues value, slope and curvature (see
//!   [`lowpass_zero_phase`]) and the filter starts in its steady state.
//! * Velocity is the central difference of the filtered displacement,
//!   `v_i = (x_{i+1} - x_{i-1}) / (2 dt)`, second-order one-sided at the two ends
//!   (`(-3 x_0 + 4 x_1 - x_2) / (2 dt)`); acceleration is the same stencil applied to the
//!   velocity. When a run has a measured `velocity_m_s` column it is used instead (by
//!   default), passed through the same zero-phase low-pass so that both sources have the same
//!   bandwidth.
//! * The force used for training sequences is the raw measurement unless
//!   [`SignalConfig::filter_force`] is set (noise in the target does not bias a least-squares
//!   fit); quasi-static extraction always uses the filtered force, because the maximum of a
//!   noisy signal is biased upwards by the noise.
//!
//! * A run's per-sample condition level (the optional `alpha` column) is carried unfiltered
//!   into [`Signals::alpha`] and the sequences ([`Sequence::alphas`]).
//!
//! Everything here is at the data's sample rate; the model integrates at its own rate, onto
//! which the trainer interpolates the sequences (`train::adjoint::Grid`, docs/preprocessing.md).

use crate::data::dataset::{Dataset, Run};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Default low-pass cut-off for differentiation \[Hz\]: 5 x the model's 30 Hz scope.
pub const DEFAULT_CUTOFF_HZ: f64 = 150.0;
/// Default scored length of a training sequence \[s\] (section 5.3: 0.5 s).
pub const DEFAULT_SEQUENCE_S: f64 = 0.5;
/// Default warm-up prefix of a sequence, simulated but not scored \[s\].
pub const DEFAULT_WARMUP_S: f64 = 0.05;
/// Default half-width of the quasi-static window around `x = 0`, as a fraction of the
/// displacement amplitude (section 5.3: +-5 %).
pub const DEFAULT_QS_WINDOW: f64 = 0.05;
/// Default oil-loss level(s) held out for testing (Table 2).
pub const DEFAULT_TEST_ALPHAS: [f64; 1] = [0.15];
/// Default fraction of each training run's sequences held out for validation.
pub const DEFAULT_VALIDATION_FRACTION: f64 = 0.2;
/// Default seed of the validation choice; the trainer's default `--seed` is the same, so
/// `nemm data prepare` and `nemm train` describe the same split by default.
pub const DEFAULT_SPLIT_SEED: u64 = 1;
/// Displacement half-ranges below this \[m\] count as no stroke at all (a flat signal).
pub const MIN_STROKE_M: f64 = 1e-9;
/// Two oil-loss levels closer than this are the same level.
pub const ALPHA_TOLERANCE: f64 = 1e-6;

/// Why preprocessing failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PreprocessError {
    /// A configuration value is out of range.
    #[error("{key}: {message}")]
    InvalidConfig {
        /// The setting, e.g. `cutoff_hz`.
        key: &'static str,
        /// What is wrong with it.
        message: String,
    },
    /// [`VelocitySource::Measured`] was asked for but the run has no `velocity_m_s` column.
    #[error("run {run} ({}): no velocity_m_s column, but the measured velocity was requested", file.display())]
    NoMeasuredVelocity {
        /// Run index in the dataset.
        run: usize,
        /// The run's file (relative to the manifest).
        file: PathBuf,
    },
    /// The columns of an in-memory run have different lengths (a loaded run never has).
    #[error("run {run} ({}): columns of different lengths", file.display())]
    ColumnLengths {
        /// Run index in the dataset.
        run: usize,
        /// The run's file (relative to the manifest).
        file: PathBuf,
    },
    /// The split left no training sequence (every run is a test run or unused, or the
    /// training runs are too short); the text names the cause.
    #[error("no training data: {0}")]
    NoTrainingData(String),
    /// A feature is zero over the whole training set, so it cannot be scaled.
    #[error("the training set's {feature} is zero everywhere; it cannot be abs-max scaled")]
    ZeroScale {
        /// `velocity` or `force`.
        feature: &'static str,
    },
}

fn config_err(key: &'static str, message: String) -> PreprocessError {
    PreprocessError::InvalidConfig { key, message }
}

// ---------------------------------------------------------------------------------------------
// Filtering and differentiation
// ---------------------------------------------------------------------------------------------

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

/// Checks a low-pass cut-off against the sample rate.
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
    let n = x.len();
    if n < 2 {
        return Ok(x.to_vec());
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
    Ok(ext)
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
/// [`nemm_core::velocity::LowPass`] at its default corner
/// ([`nemm_core::velocity::DEFAULT_CUTOFF_HZ`]), in `f32` as on the target. The first sample,
/// which has no difference yet, is 0 (the firmware primes its filter there and the estimator
/// holds its input at rest). The firmware differentiates integer ADC codes
/// (`nemm_core::velocity::Differentiator`, same low-pass): the two differ by the ADC's
/// quantisation of the stroke only.
pub fn causal_velocity(x: &[f64], sample_rate_hz: f64) -> Vec<f64> {
    let mut low_pass = nemm_core::velocity::LowPass::new(
        sample_rate_hz as f32,
        nemm_core::velocity::DEFAULT_CUTOFF_HZ,
    );
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
    /// Cut-off of the zero-phase low-pass \[Hz\] (default [`DEFAULT_CUTOFF_HZ`]).
    pub cutoff_hz: f64,
    /// Velocity source (default [`VelocitySource::Auto`]).
    pub velocity_source: VelocitySource,
    /// Low-pass the force of the training sequences too (default `false`: raw force).
    pub filter_force: bool,
}

impl Default for SignalConfig {
    fn default() -> Self {
        SignalConfig {
            cutoff_hz: DEFAULT_CUTOFF_HZ,
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
    pub force_filtered_n: Vec<f64>,
    /// `true` if the velocity is the (filtered) measured column, `false` if differentiated.
    pub measured_velocity: bool,
    /// Condition level per sample (the run's `alpha` column, unfiltered), if it has one.
    pub alpha: Option<Vec<f64>>,
}

/// Derives filtered displacement, velocity, acceleration and filtered force of a run.
///
/// `run_index` only labels errors.
pub fn process_run(
    run: &Run,
    run_index: usize,
    sample_rate_hz: f64,
    cfg: &SignalConfig,
) -> Result<Signals, PreprocessError> {
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
    let dt = 1.0 / sample_rate_hz;
    let displacement_m = lowpass_zero_phase(&run.displacement_m, sample_rate_hz, cfg.cutoff_hz)?;
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
        Some(v) => lowpass_zero_phase(v, sample_rate_hz, cfg.cutoff_hz)?,
        None if cfg.velocity_source == VelocitySource::Causal => {
            causal_velocity(&run.displacement_m, sample_rate_hz)
        }
        None => differentiate(&displacement_m, dt),
    };
    let acceleration_m_s2 = differentiate(&velocity_m_s, dt);
    let force_filtered_n = lowpass_zero_phase(&run.force_n, sample_rate_hz, cfg.cutoff_hz)?;
    Ok(Signals {
        displacement_m,
        velocity_m_s,
        acceleration_m_s2,
        force_filtered_n,
        measured_velocity: measured.is_some(),
        alpha: run.alpha.clone(),
    })
}

/// [`process_run`] of every run of a dataset (in parallel), in dataset order.
pub fn run_signals(dataset: &Dataset, cfg: &SignalConfig) -> Result<Vec<Signals>, PreprocessError> {
    use rayon::prelude::*;
    dataset
        .runs
        .par_iter()
        .enumerate()
        .map(|(i, r)| process_run(r, i, dataset.sample_rate_hz, cfg))
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
/// `cutoff_hz` is validated like the filter's and otherwise unused.
pub fn measured_velocity_mismatch(
    run: &Run,
    sample_rate_hz: f64,
    cutoff_hz: f64,
) -> Result<Option<f64>, PreprocessError> {
    let Some(measured) = &run.velocity_m_s else {
        return Ok(None);
    };
    check_cutoff(sample_rate_hz, cutoff_hz)?;
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
    Ok(Some(if norm > 0.0 {
        err / norm
    } else if err > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }))
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

// ---------------------------------------------------------------------------------------------
// Excitation estimate
// ---------------------------------------------------------------------------------------------

/// A zero crossing of the displacement (relative to its centre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Crossing {
    /// Fractional sample index of the crossing (linear interpolation).
    pub(crate) at: f64,
    /// `true` for extension (x increasing, rebound), `false` for compression.
    pub(crate) rising: bool,
}

/// Zero crossings of `y` with hysteresis `h`: a crossing counts once, and the next one only
/// after `y` has left the band `[-h, h]` on the other side.
pub(crate) fn zero_crossings(y: &[f64], h: f64) -> Vec<Crossing> {
    let mut out = Vec::new();
    // Confirmed side: Some(true) above +h, Some(false) below -h.
    let mut side = None;
    let mut crossed = false;
    for i in 0..y.len() {
        if i > 0 {
            let (a, b) = (y[i - 1], y[i]);
            let rising = match side {
                Some(false) if a < 0.0 && b >= 0.0 => Some(true),
                Some(true) if a > 0.0 && b <= 0.0 => Some(false),
                _ => None,
            };
            if let (Some(rising), false) = (rising, crossed) {
                out.push(Crossing {
                    at: (i - 1) as f64 + a / (a - b),
                    rising,
                });
                crossed = true;
            }
        }
        let now = if y[i] > h {
            Some(true)
        } else if y[i] < -h {
            Some(false)
        } else {
            None
        };
        if now.is_some() && now != side {
            side = now;
            crossed = false;
        }
    }
    out
}

/// Median of `v` (the mean of the two middle values for an even count); `None` when empty.
pub(crate) fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    })
}

/// Fraction of the reference (90th percentile) that a half-cycle must reach to count as
/// steady in [`steady_median`].
pub const STEADY_FRACTION: f64 = 0.9;

/// Median of the steady part of per-half-cycle values: those of at least
/// [`STEADY_FRACTION`] times their 90th percentile. Ramp-in and ramp-out cycles are smaller
/// and drop out even when they outnumber the steady ones; one outlying half-cycle (a spike)
/// moves the 90th percentile only when it is more than a tenth of them. `None` for no values.
pub fn steady_median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let k = ((0.9 * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1);
    let reference = sorted[k];
    median(
        sorted
            .into_iter()
            .filter(|v| *v >= STEADY_FRACTION * reference)
            .collect(),
    )
}

/// Estimated excitation of a (periodic) run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Excitation {
    /// Centre of the stroke \[m\]: mid-range of the filtered displacement.
    pub offset_m: f64,
    /// Stroke amplitude \[m\]: median over the steady complete half-cycles of the largest
    /// `|x - offset|` (half the range when the run has no complete half-cycle); see
    /// [`steady_median`].
    pub amplitude_m: f64,
    /// Frequency \[Hz\] from the mean period between rising zero crossings (half periods
    /// when there is only one); `None` with fewer than two crossings.
    pub frequency_hz: Option<f64>,
    /// Peak velocity \[m/s\]: median over the steady passes through the centre between two
    /// turning points of the largest `|v|` (the overall largest `|v|` without such a pass);
    /// see [`steady_median`].
    pub peak_velocity_m_s: f64,
    /// Complete half-cycles found (between two zero crossings).
    pub half_cycles: usize,
}

/// Estimates amplitude, frequency and peak velocity from filtered displacement and velocity.
///
/// Robust to ramp-in / ramp-out cycles (medians over the steady half-cycles, however many
/// ramp cycles there are) and to noise (zero crossings with a hysteresis of 10 % of the
/// half-range).
pub fn estimate_excitation(
    displacement_m: &[f64],
    velocity_m_s: &[f64],
    sample_rate_hz: f64,
) -> Excitation {
    let (lo, hi) = displacement_m
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
    let max_abs_v = velocity_m_s.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if displacement_m.is_empty() {
        return Excitation {
            offset_m: 0.0,
            amplitude_m: 0.0,
            frequency_hz: None,
            peak_velocity_m_s: max_abs_v,
            half_cycles: 0,
        };
    }
    let offset_m = 0.5 * (lo + hi);
    // A stroke below 1 nm is rounding noise of a flat signal, not an excitation.
    let half_range = match 0.5 * (hi - lo) {
        r if r < MIN_STROKE_M => 0.0,
        r => r,
    };
    let y: Vec<f64> = displacement_m.iter().map(|x| x - offset_m).collect();
    let crossings = if half_range > 0.0 {
        zero_crossings(&y, 0.1 * half_range)
    } else {
        Vec::new()
    };

    // Half-cycles between consecutive crossings: amplitude and turning point.
    let mut amplitudes = Vec::new();
    let mut turning = Vec::new();
    for w in crossings.windows(2) {
        let a = w[0].at.ceil() as usize;
        let b = (w[1].at.floor() as usize).min(y.len() - 1);
        if let Some((i, v)) = (a..=b)
            .map(|i| (i, y[i].abs()))
            .max_by(|p, q| p.1.total_cmp(&q.1))
        {
            amplitudes.push(v);
            turning.push(i);
        }
    }
    // Passes through the centre between consecutive turning points: peak |v|.
    let peaks: Vec<f64> = turning
        .windows(2)
        .map(|w| {
            velocity_m_s[w[0]..=w[1]]
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()))
        })
        .collect();
    let rising: Vec<f64> = crossings
        .iter()
        .filter(|c| c.rising)
        .map(|c| c.at)
        .collect();
    let frequency_hz = if rising.len() >= 2 {
        Some(sample_rate_hz * (rising.len() - 1) as f64 / (rising[rising.len() - 1] - rising[0]))
    } else if crossings.len() >= 2 {
        let span = crossings[crossings.len() - 1].at - crossings[0].at;
        Some(sample_rate_hz * (crossings.len() - 1) as f64 / (2.0 * span))
    } else {
        None
    };
    Excitation {
        offset_m,
        amplitude_m: steady_median(&amplitudes).unwrap_or(half_range),
        frequency_hz,
        peak_velocity_m_s: steady_median(&peaks).unwrap_or(max_abs_v),
        half_cycles: amplitudes.len(),
    }
}

// ---------------------------------------------------------------------------------------------
// Quasi-static points
// ---------------------------------------------------------------------------------------------

/// Direction of a stroke half-cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Direction {
    /// Extension, positive velocity and (tension) force.
    Rebound,
    /// Compression, negative velocity and force.
    Compression,
}

/// One quasi-static support point of the flow-force model (section 5.3): the largest force
/// magnitude within +-window of the amplitude around the stroke centre, with the velocity
/// there. Rebound points have positive force and velocity, compression points negative.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct QuasiStaticPoint {
    /// Run index in the dataset.
    pub run: usize,
    /// Sample index of the force extreme.
    pub sample: usize,
    /// Rebound or compression pass.
    pub direction: Direction,
    /// Velocity at the centre crossing \[m/s\] (the pass's peak velocity).
    pub velocity_m_s: f64,
    /// Largest (rebound) or smallest (compression) filtered force in the window \[N\].
    pub force_n: f64,
    /// Condition level at the point: the run's, or its `alpha` column's at `sample`.
    pub alpha: f64,
    /// Estimated amplitude of the run \[m\].
    pub amplitude_m: f64,
    /// Estimated frequency of the run \[Hz\] (`None` if it has no full period).
    pub frequency_hz: Option<f64>,
}

/// Quasi-static points of one run: for every pass through the stroke centre, the window of
/// consecutive samples with `|x - offset| <= window * amplitude`, entered on one side and
/// left on the other (turning points inside the window and passes cut by the run's ends are
/// skipped); in it the largest force (rebound) or smallest force (compression) of the
/// filtered force, and the velocity interpolated at the crossing of `x = offset`.
pub fn quasi_static_points(
    run_index: usize,
    signals: &Signals,
    excitation: &Excitation,
    alpha: f64,
    window: f64,
) -> Vec<QuasiStaticPoint> {
    let y: Vec<f64> = signals
        .displacement_m
        .iter()
        .map(|x| x - excitation.offset_m)
        .collect();
    let half_width = window * excitation.amplitude_m;
    let n = y.len();
    let mut out = Vec::new();
    if half_width.is_nan() || half_width <= 0.0 || n < 3 {
        return out;
    }
    let mut i = 0;
    while i < n {
        if y[i].abs() > half_width {
            i += 1;
            continue;
        }
        let a = i;
        while i < n && y[i].abs() <= half_width {
            i += 1;
        }
        let b = i - 1; // last sample inside
        if a == 0 || i >= n {
            continue; // cut by the run's ends
        }
        let direction = match (y[a - 1] < 0.0, y[i] > 0.0) {
            (true, true) => Direction::Rebound,
            (false, false) => Direction::Compression,
            _ => continue, // turning point inside the window
        };
        let f = &signals.force_filtered_n[a..=b];
        let pick = match direction {
            Direction::Rebound => f.iter().enumerate().max_by(|p, q| p.1.total_cmp(q.1)),
            Direction::Compression => f.iter().enumerate().min_by(|p, q| p.1.total_cmp(q.1)),
        };
        let Some((k, &force_n)) = pick else { continue };
        // Crossing of y = 0 inside [a - 1, i]: first sign change.
        let v = &signals.velocity_m_s;
        let mut velocity_m_s = v[a];
        for j in a..=i {
            let (p, q) = (y[j - 1], y[j]);
            if (p < 0.0) != (q < 0.0) {
                let t = p / (p - q);
                velocity_m_s = v[j - 1] + t * (v[j] - v[j - 1]);
                break;
            }
        }
        out.push(QuasiStaticPoint {
            run: run_index,
            sample: a + k,
            direction,
            velocity_m_s,
            force_n,
            alpha,
            amplitude_m: excitation.amplitude_m,
            frequency_hz: excitation.frequency_hz,
        });
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Sequences
// ---------------------------------------------------------------------------------------------

/// Lengths of the training sequences.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SequenceConfig {
    /// Scored length \[s\] (default [`DEFAULT_SEQUENCE_S`]).
    pub length_s: f64,
    /// Warm-up prefix \[s\], simulated but not scored (default [`DEFAULT_WARMUP_S`]).
    pub warmup_s: f64,
}

impl Default for SequenceConfig {
    fn default() -> Self {
        SequenceConfig {
            length_s: DEFAULT_SEQUENCE_S,
            warmup_s: DEFAULT_WARMUP_S,
        }
    }
}

impl SequenceConfig {
    /// `(warm-up samples, scored samples)` at `sample_rate_hz` (rounded to whole samples).
    pub fn samples(&self, sample_rate_hz: f64) -> Result<(usize, usize), PreprocessError> {
        if !(self.length_s.is_finite() && self.length_s > 0.0) {
            return Err(config_err(
                "length_s",
                format!("{} s is not a positive duration", self.length_s),
            ));
        }
        if !(self.warmup_s.is_finite() && self.warmup_s >= 0.0) {
            return Err(config_err(
                "warmup_s",
                format!("{} s is not a non-negative duration", self.warmup_s),
            ));
        }
        let scored = (self.length_s * sample_rate_hz).round();
        if scored < 1.0 {
            return Err(config_err(
                "length_s",
                format!("{} s is shorter than one sample", self.length_s),
            ));
        }
        Ok((
            (self.warmup_s * sample_rate_hz).round() as usize,
            scored as usize,
        ))
    }
}

/// One training sequence: `warmup + scored` consecutive samples of a run, in SI units.
/// The first `warmup` samples are simulated to settle the model state but not scored.
#[derive(Debug, Clone, PartialEq)]
pub struct Sequence {
    /// Run index in the dataset.
    pub run: usize,
    /// First sample (start of the warm-up) in the run.
    pub start: usize,
    /// Oil-loss level of the run.
    pub alpha: f32,
    /// Stroke velocity \[m/s\], `warmup + scored` samples.
    pub velocity_m_s: Vec<f32>,
    /// Measured force \[N\], `warmup + scored` samples.
    pub force_n: Vec<f32>,
    /// Stroke position \[m\] as the position sensor measures it (low-passed like the
    /// velocity, its zero where the sensor has it), `warmup + scored` samples: the input of
    /// the static force.
    pub position_m: Vec<f32>,
    /// Condition level per sample, `warmup + scored` samples, when the run has an `alpha`
    /// column (it then replaces `alpha` in training and evaluation).
    pub alphas: Option<Vec<f32>>,
}

/// Cuts a run into sequences whose scored parts tile `[warmup, warmup + k * scored)` without
/// gaps or overlap: sequence `k` starts at `k * scored`, its scored part at
/// `k * scored + warmup`. The first `warmup` samples and a tail shorter than `scored` are not
/// scored; the count is [`unscored_samples`].
/// `alphas` is the run's condition level per sample, if it has one; `position_m` the stroke
/// position per sample.
#[allow(clippy::too_many_arguments)]
pub fn cut_sequences(
    run_index: usize,
    alpha: f64,
    velocity_m_s: &[f64],
    force_n: &[f64],
    position_m: &[f64],
    alphas: Option<&[f64]>,
    warmup: usize,
    scored: usize,
) -> Vec<Sequence> {
    let n = velocity_m_s.len().min(force_n.len()).min(position_m.len());
    let count = sequence_count(n, warmup, scored);
    (0..count)
        .map(|k| {
            let start = k * scored;
            let end = start + warmup + scored;
            Sequence {
                run: run_index,
                start,
                alpha: alpha as f32,
                velocity_m_s: velocity_m_s[start..end].iter().map(|&v| v as f32).collect(),
                force_n: force_n[start..end].iter().map(|&v| v as f32).collect(),
                position_m: position_m[start..end].iter().map(|&v| v as f32).collect(),
                alphas: alphas.map(|a| a[start..end].iter().map(|&v| v as f32).collect()),
            }
        })
        .collect()
}

/// Number of sequences [`cut_sequences`] makes from `n` samples.
pub fn sequence_count(n: usize, warmup: usize, scored: usize) -> usize {
    if scored == 0 {
        return 0;
    }
    n.saturating_sub(warmup) / scored
}

/// Samples of a run of `n` samples that no sequence scores (leading warm-up and tail).
pub fn unscored_samples(n: usize, warmup: usize, scored: usize) -> usize {
    n - sequence_count(n, warmup, scored) * scored
}

// ---------------------------------------------------------------------------------------------
// Split and scales
// ---------------------------------------------------------------------------------------------

/// How runs and sequences are split (Table 2 by default).
///
/// Three kinds of test set, which can be combined: whole runs at a test level
/// (`test_alphas`), whole runs whose file matches a glob (`test_runs`), and the last part of
/// every other run (`test_tail`). Every training run gives one contiguous validation stretch
/// ([`run_stretches`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SplitConfig {
    /// Oil-loss levels whose runs form the test set (default `[0.15]`).
    pub test_alphas: Vec<f64>,
    /// Glob patterns (`glob` crate syntax) on the run files: a run whose path relative to the
    /// manifest or whose file name matches one is a test run.
    #[serde(default)]
    pub test_runs: Vec<String>,
    /// Fraction in (0, 1) of every training run, at its end, held out as test data (a split
    /// in time, for datasets with a single level); `None`: no tail.
    #[serde(default)]
    pub test_tail: Option<f64>,
    /// Oil-loss levels used for training and validation; `None` = every level not in
    /// `test_alphas` (default). Runs at other levels are unused.
    pub train_alphas: Option<Vec<f64>>,
    /// Glob patterns of run files that are not used at all (as `test_runs`).
    #[serde(default)]
    pub exclude_runs: Vec<String>,
    /// Fraction of each training run's windows held out for validation, in \[0, 1)
    /// (default [`DEFAULT_VALIDATION_FRACTION`]).
    pub validation_fraction: f64,
    /// Seed of the position of each run's validation stretch (default [`DEFAULT_SPLIT_SEED`]).
    pub seed: u64,
}

impl Default for SplitConfig {
    fn default() -> Self {
        SplitConfig {
            test_alphas: DEFAULT_TEST_ALPHAS.to_vec(),
            test_runs: Vec::new(),
            test_tail: None,
            train_alphas: None,
            exclude_runs: Vec::new(),
            validation_fraction: DEFAULT_VALIDATION_FRACTION,
            seed: DEFAULT_SPLIT_SEED,
        }
    }
}

/// What a run is used for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RunRole {
    /// Training and validation sequences.
    TrainValidation,
    /// Test sequences only.
    Test,
    /// Not used (oil-loss level neither test nor train).
    Unused,
}

/// `true` if one of `patterns` matches the run file `file`: its path relative to the manifest
/// (with `/` separators) or its file name.
fn file_matches(patterns: &[glob::Pattern], file: &std::path::Path) -> bool {
    let path = file.to_string_lossy().replace('\\', "/");
    let name = file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    patterns
        .iter()
        .any(|p| p.matches(&path) || p.matches(&name))
}

/// Compiles glob patterns, naming the setting of a bad one.
fn compile_globs(
    key: &'static str,
    patterns: &[String],
) -> Result<Vec<glob::Pattern>, PreprocessError> {
    patterns
        .iter()
        .map(|p| {
            glob::Pattern::new(p)
                .map_err(|e| config_err(key, format!("{p:?} is not a glob pattern: {e}")))
        })
        .collect()
}

/// A [`SplitConfig`] with its glob patterns compiled.
#[derive(Debug, Clone)]
pub struct SplitRules<'a> {
    config: &'a SplitConfig,
    test_runs: Vec<glob::Pattern>,
    exclude_runs: Vec<glob::Pattern>,
}

impl SplitRules<'_> {
    /// The role of a run with oil-loss level `alpha` stored in `file`: unused if excluded
    /// (`exclude_runs`) or not at a training level, test if at a test level or matched by
    /// `test_runs`, else training and validation.
    pub fn role(&self, file: &std::path::Path, alpha: f64) -> RunRole {
        let c = self.config;
        let has = |set: &[f64]| set.iter().any(|&a| (a - alpha).abs() <= ALPHA_TOLERANCE);
        if file_matches(&self.exclude_runs, file) {
            RunRole::Unused
        } else if has(&c.test_alphas) || file_matches(&self.test_runs, file) {
            RunRole::Test
        } else if c.train_alphas.as_deref().is_none_or(has) {
            RunRole::TrainValidation
        } else {
            RunRole::Unused
        }
    }
}

impl SplitConfig {
    fn validate(&self) -> Result<(), PreprocessError> {
        if !(self.validation_fraction.is_finite() && (0.0..1.0).contains(&self.validation_fraction))
        {
            return Err(config_err(
                "validation_fraction",
                format!("{} is not in [0, 1)", self.validation_fraction),
            ));
        }
        if let Some(t) = self.test_tail {
            if !(t.is_finite() && t > 0.0 && t < 1.0) {
                return Err(config_err(
                    "test_tail",
                    format!("{t} is not a fraction of a run in (0, 1)"),
                ));
            }
        }
        let all = self
            .test_alphas
            .iter()
            .chain(self.train_alphas.iter().flatten());
        for &a in all {
            if !(a.is_finite() && (0.0..=1.0).contains(&a)) {
                return Err(config_err(
                    "test_alphas / train_alphas",
                    format!("{a} is not an oil-loss level in [0, 1]"),
                ));
            }
        }
        Ok(())
    }

    /// The split with its glob patterns compiled (errors name a bad pattern).
    pub fn rules(&self) -> Result<SplitRules<'_>, PreprocessError> {
        Ok(SplitRules {
            config: self,
            test_runs: compile_globs("test_runs", &self.test_runs)?,
            exclude_runs: compile_globs("exclude_runs", &self.exclude_runs)?,
        })
    }

    /// Every requested level must match a run of `dataset`, and every glob a run file: a
    /// level or pattern that matches none (a typo in `--test-alpha`, say) would silently
    /// leave the test set empty, or drop training data.
    fn check_levels(&self, dataset: &Dataset) -> Result<(), PreprocessError> {
        let present = |a: f64| {
            dataset
                .runs
                .iter()
                .any(|r| (r.entry.oil_loss - a).abs() <= ALPHA_TOLERANCE)
        };
        let sets = [
            ("test_alphas", self.test_alphas.as_slice()),
            ("train_alphas", self.train_alphas.as_deref().unwrap_or(&[])),
        ];
        for (key, set) in sets {
            if let Some(&a) = set.iter().find(|&&a| !present(a)) {
                let levels: Vec<String> =
                    distinct_levels(dataset.runs.iter().map(|r| r.entry.oil_loss))
                        .iter()
                        .map(f64::to_string)
                        .collect();
                return Err(config_err(
                    key,
                    format!(
                        "oil-loss level {a} matches no run; the dataset's levels are {}",
                        levels.join(", ")
                    ),
                ));
            }
        }
        for (key, patterns) in [
            ("test_runs", &self.test_runs),
            ("exclude_runs", &self.exclude_runs),
        ] {
            for p in patterns {
                let one = compile_globs(key, std::slice::from_ref(p))?;
                if !dataset
                    .runs
                    .iter()
                    .any(|r| file_matches(&one, &r.entry.file))
                {
                    let files: Vec<String> = dataset
                        .runs
                        .iter()
                        .take(3)
                        .map(|r| r.entry.file.display().to_string())
                        .collect();
                    return Err(config_err(
                        key,
                        format!(
                            "pattern {p:?} matches no run file (the files are named like {}{})",
                            files.join(", "),
                            if dataset.runs.len() > 3 { ", ..." } else { "" }
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// One line for reports: the test set, the training runs and the validation rule.
    pub fn describe(&self) -> String {
        self.describe_for(&crate::data::dataset::ConditionSpec::default())
    }

    /// [`Self::describe`] with the levels named by the dataset's `condition`.
    pub fn describe_for(&self, condition: &crate::data::dataset::ConditionSpec) -> String {
        let list = |v: &[f64]| {
            v.iter()
                .map(|&a| condition.cell(a))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let what = condition.column();
        let mut test = Vec::new();
        if !self.test_alphas.is_empty() {
            test.push(format!("runs at {what} {}", list(&self.test_alphas)));
        }
        if !self.test_runs.is_empty() {
            test.push(format!("runs matching {}", self.test_runs.join(", ")));
        }
        if let Some(t) = self.test_tail {
            test.push(format!("the last {} % of every training run", 100.0 * t));
        }
        if test.is_empty() {
            test.push("none".into());
        }
        let mut train = match &self.train_alphas {
            Some(a) => format!("runs at {what} {}", list(a)),
            None => "every other run".into(),
        };
        if !self.exclude_runs.is_empty() {
            train.push_str(&format!(" except {}", self.exclude_runs.join(", ")));
        }
        format!(
            "test: {}; training: {train}; validation: {} % of each training run's windows as \
             one contiguous stretch (seed {})",
            test.join(" + "),
            100.0 * self.validation_fraction,
            self.seed
        )
    }

    /// The role of a run with oil-loss level `alpha` when only levels are known (no file
    /// patterns): [`SplitRules::role`] without `test_runs` and `exclude_runs`.
    pub fn role(&self, alpha: f64) -> RunRole {
        let has = |set: &[f64]| set.iter().any(|&a| (a - alpha).abs() <= ALPHA_TOLERANCE);
        if has(&self.test_alphas) {
            RunRole::Test
        } else if self.train_alphas.as_deref().is_none_or(has) {
            RunRole::TrainValidation
        } else {
            RunRole::Unused
        }
    }
}

/// The distinct oil-loss levels among `alphas`, ascending (levels closer than
/// [`ALPHA_TOLERANCE`] are one).
pub fn distinct_levels(alphas: impl IntoIterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = alphas.into_iter().collect();
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| (*a - *b).abs() <= ALPHA_TOLERANCE);
    v
}

/// What a stretch of a run is used for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Part {
    /// Training windows.
    Train,
    /// Validation windows (early stopping, model selection).
    Validation,
    /// Test windows.
    Test,
}

/// A stretch `[start, end)` of a run's samples and its use. The stretches of a run are
/// disjoint and each is cut into windows on its own ([`cut_sequences`]), so no window, warm-up
/// included, reads a sample of another stretch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Stretch {
    /// Use.
    pub part: Part,
    /// First sample.
    pub start: usize,
    /// One past the last sample.
    pub end: usize,
}

/// The stretches of a run of `n` samples with `role`:
///
/// * a test run is one test stretch, an unused run none;
/// * a training run first loses its last `round(test_tail * n)` samples to a test stretch
///   (with [`SplitConfig::test_tail`]); in the rest, of `K` windows if cut whole,
///   `round(validation_fraction * K)` consecutive windows (at most `K - 1`) form one
///   validation stretch and the samples before and after it are training stretches. Where the
///   validation stretch sits is drawn uniformly among the places where it fits with its own
///   warm-up (whole windows of the tiling, from the run's start to its end) by xoshiro256++
///   seeded with the 64-bit FNV-1a hash of `seed` and `run_index`, so a run's choice does not
///   depend on the other runs.
///
/// Each stretch after the first needs its own warm-up, so a training run gives at most one
/// window fewer than if it were cut whole (two with a test tail) when its unscored tail is
/// shorter than the extra warm-ups.
pub fn run_stretches(
    n: usize,
    role: RunRole,
    warmup: usize,
    scored: usize,
    split: &SplitConfig,
    run_index: usize,
) -> Vec<Stretch> {
    use rand::SeedableRng;
    use std::hash::Hasher;
    let stretch = |part, start, end| Stretch { part, start, end };
    match role {
        RunRole::Unused => return Vec::new(),
        RunRole::Test => return vec![stretch(Part::Test, 0, n)],
        RunRole::TrainValidation => {}
    }
    let mut out = Vec::new();
    let tail = split
        .test_tail
        .map_or(0, |f| ((f * n as f64).round() as usize).min(n));
    let t = n - tail;
    let count = sequence_count(t, warmup, scored);
    let take =
        ((split.validation_fraction * count as f64).round() as usize).min(count.saturating_sub(1));
    if take == 0 {
        if t > 0 {
            out.push(stretch(Part::Train, 0, t));
        }
    } else {
        // Validation after `j` training windows: [before, before + warmup + take * scored).
        let before = |j: usize| if j == 0 { 0 } else { warmup + j * scored };
        let fits: Vec<usize> = (0..=count - take)
            .filter(|&j| before(j) + warmup + take * scored <= t)
            .collect();
        let mut h = fnv::FnvHasher::default();
        h.write(&split.seed.to_le_bytes());
        h.write(&(run_index as u64).to_le_bytes());
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(h.finish());
        let pick = rand::seq::index::sample(&mut rng, fits.len(), 1).index(0);
        let j = fits[pick];
        let (a, b) = (before(j), before(j) + warmup + take * scored);
        if a > 0 {
            out.push(stretch(Part::Train, 0, a));
        }
        out.push(stretch(Part::Validation, a, b));
        if b < t {
            out.push(stretch(Part::Train, b, t));
        }
    }
    if tail > 0 {
        out.push(stretch(Part::Test, t, n));
    }
    out
}

/// Abs-max feature scales from the training set (section 5.3): each feature is divided by
/// its largest magnitude over the training sequences (warm-up included).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Scales {
    /// Largest `|velocity|` \[m/s\].
    pub velocity_m_s: f64,
    /// Largest `|force|` \[N\].
    pub force_n: f64,
    /// Largest oil-loss level; 1 if every training run has `alpha = 0` (the feature is then
    /// constant zero and any positive scale leaves it so).
    pub alpha: f64,
}

impl Scales {
    /// Scales of a set of (training) sequences (from their f32 values; [`prepare`] uses the
    /// f64 signals, which agree to f32 rounding).
    pub fn from_sequences(train: &[Sequence]) -> Result<Scales, PreprocessError> {
        let absmax = |f: &dyn Fn(&Sequence) -> f64| train.iter().map(f).fold(0.0f64, f64::max);
        let velocity_m_s = absmax(&|s| {
            s.velocity_m_s
                .iter()
                .fold(0.0f64, |m, v| m.max(f64::from(v.abs())))
        });
        let force_n = absmax(&|s| {
            s.force_n
                .iter()
                .fold(0.0f64, |m, v| m.max(f64::from(v.abs())))
        });
        let alpha = absmax(&|s| f64::from(s.alpha.abs()));
        Scales::from_absmax(velocity_m_s, force_n, alpha)
    }

    /// Scales from the abs-max values of the training set (errors on zero velocity or force;
    /// a zero alpha scale becomes 1).
    pub fn from_absmax(
        velocity_m_s: f64,
        force_n: f64,
        alpha: f64,
    ) -> Result<Scales, PreprocessError> {
        if velocity_m_s <= 0.0 {
            return Err(PreprocessError::ZeroScale {
                feature: "velocity",
            });
        }
        if force_n <= 0.0 {
            return Err(PreprocessError::ZeroScale { feature: "force" });
        }
        Ok(Scales {
            velocity_m_s,
            force_n,
            alpha: if alpha > 0.0 { alpha } else { 1.0 },
        })
    }

    /// A sequence with velocity, force and alpha divided by the scales.
    pub fn normalise(&self, s: &Sequence) -> Sequence {
        let (sv, sf) = (self.velocity_m_s as f32, self.force_n as f32);
        Sequence {
            run: s.run,
            start: s.start,
            alpha: (f64::from(s.alpha) / self.alpha) as f32,
            velocity_m_s: s.velocity_m_s.iter().map(|v| v / sv).collect(),
            force_n: s.force_n.iter().map(|f| f / sf).collect(),
            position_m: s.position_m.clone(),
            alphas: s.alphas.as_ref().map(|a| {
                a.iter()
                    .map(|&x| (f64::from(x) / self.alpha) as f32)
                    .collect()
            }),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The whole preparation
// ---------------------------------------------------------------------------------------------

/// Everything [`prepare`] needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct PrepareConfig {
    /// Signal derivation.
    pub signal: SignalConfig,
    /// Sequence lengths.
    pub sequences: SequenceConfig,
    /// Split.
    pub split: SplitConfig,
    /// Quasi-static window half-width as a fraction of the amplitude; `None` (the default)
    /// means [`DEFAULT_QS_WINDOW`].
    pub quasi_static_window: Option<f64>,
}

/// Per-run facts for reports, plots and `nemm data check`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    /// Run index in the dataset.
    pub index: usize,
    /// File relative to the manifest.
    pub file: PathBuf,
    /// Oil-loss level.
    pub alpha: f64,
    /// Samples.
    pub samples: usize,
    /// Duration `samples / sample_rate_hz` \[s\].
    pub duration_s: f64,
    /// Smallest measured force \[N\].
    pub force_min_n: f64,
    /// Largest measured force \[N\].
    pub force_max_n: f64,
    /// Estimated excitation.
    pub excitation: Excitation,
    /// `true` if the velocity is the measured column.
    pub measured_velocity: bool,
    /// Relative RMS difference of the measured velocity to the differentiated displacement.
    pub measured_velocity_mismatch: Option<f64>,
    /// Amplitude from the manifest \[m\], if given.
    pub manifest_amplitude_m: Option<f64>,
    /// Target velocity from the manifest \[m/s\], if given.
    pub manifest_target_velocity_m_s: Option<f64>,
}

/// The summary of one run in a [`Prepared`] set: role and counts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PreparedRun {
    /// Facts about the run.
    pub summary: RunSummary,
    /// What the run is used for.
    pub role: RunRole,
    /// Training sequences.
    pub train_sequences: usize,
    /// Validation sequences.
    pub validation_sequences: usize,
    /// Test sequences.
    pub test_sequences: usize,
    /// Samples not scored by any sequence (first warm-up and the tail).
    pub unscored_samples: usize,
    /// Quasi-static points.
    pub quasi_static_points: usize,
    /// The run's training, validation and test stretches ([`run_stretches`]).
    #[serde(default)]
    pub stretches: Vec<Stretch>,
}

/// Quasi-static points split like the sequences: a point is validation if its sample lies in
/// the scored part of a validation sequence, test if its run is a test run, else training.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct QuasiStaticSplit {
    /// Training points.
    pub train: Vec<QuasiStaticPoint>,
    /// Validation points.
    pub validation: Vec<QuasiStaticPoint>,
    /// Test points.
    pub test: Vec<QuasiStaticPoint>,
}

/// Training data ready for the trainer (sequences in SI units, f32; divide by
/// [`Prepared::scales`] with [`Scales::normalise`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Prepared {
    /// The configuration used.
    pub config: PrepareConfig,
    /// Sample rate \[Hz\] of the data (the model integrates at its own rate).
    pub sample_rate_hz: f64,
    /// Sample step `1 / sample_rate_hz` \[s\].
    pub dt_s: f64,
    /// Warm-up samples at the start of every sequence (simulated, not scored).
    pub warmup_samples: usize,
    /// Scored samples of every sequence.
    pub scored_samples: usize,
    /// Training sequences (ordered by run, then start).
    pub train: Vec<Sequence>,
    /// Validation sequences.
    pub validation: Vec<Sequence>,
    /// Test sequences.
    pub test: Vec<Sequence>,
    /// Quasi-static points for the flow-force model.
    pub quasi_static: QuasiStaticSplit,
    /// Abs-max scales from the training sequences.
    pub scales: Scales,
    /// Per-run role and counts, in dataset order.
    pub runs: Vec<PreparedRun>,
    /// Derived signals of every run, in dataset order (the source of the sequences and
    /// quasi-static points, and of the figures' measured loops).
    pub signals: Vec<Signals>,
    /// The dataset's condition (name, unit, map to alpha, declared priors).
    pub condition: nemm_core::Condition,
}

/// Counts of one split, for reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SplitCounts {
    /// Runs contributing at least one sequence.
    pub runs: usize,
    /// Sequences.
    pub sequences: usize,
    /// Scored samples.
    pub scored_samples: usize,
    /// Quasi-static points.
    pub quasi_static_points: usize,
}

/// A JSON-friendly summary of a [`Prepared`] set (`nemm data prepare --out`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrepareSummary {
    /// Dataset name.
    pub dataset: String,
    /// The configuration used.
    pub config: PrepareConfig,
    /// Sample rate \[Hz\].
    pub sample_rate_hz: f64,
    /// Sample step \[s\].
    pub dt_s: f64,
    /// Warm-up samples per sequence.
    pub warmup_samples: usize,
    /// Scored samples per sequence.
    pub scored_samples: usize,
    /// Training counts.
    pub train: SplitCounts,
    /// Validation counts.
    pub validation: SplitCounts,
    /// Test counts.
    pub test: SplitCounts,
    /// Runs not used.
    pub unused_runs: usize,
    /// Scales.
    pub scales: Scales,
    /// Per run.
    pub runs: Vec<PreparedRun>,
}

/// Summarises one run: excitation, force range, velocity source.
pub fn summarize_run(
    run: &Run,
    index: usize,
    sample_rate_hz: f64,
    cfg: &SignalConfig,
) -> Result<(RunSummary, Signals), PreprocessError> {
    let signals = process_run(run, index, sample_rate_hz, cfg)?;
    let excitation = estimate_excitation(
        &signals.displacement_m,
        &signals.velocity_m_s,
        sample_rate_hz,
    );
    let (force_min_n, force_max_n) = run
        .force_n
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &f| {
            (lo.min(f), hi.max(f))
        });
    let summary = RunSummary {
        index,
        file: run.entry.file.clone(),
        alpha: run.entry.oil_loss,
        samples: run.len(),
        duration_s: run.len() as f64 / sample_rate_hz,
        force_min_n,
        force_max_n,
        excitation,
        measured_velocity: signals.measured_velocity,
        measured_velocity_mismatch: measured_velocity_mismatch(run, sample_rate_hz, cfg.cutoff_hz)?,
        manifest_amplitude_m: run.entry.amplitude_m,
        manifest_target_velocity_m_s: run.entry.target_velocity_m_s,
    };
    Ok((summary, signals))
}

/// Summaries of every run (in parallel), for `nemm data check`.
pub fn summarize(
    dataset: &Dataset,
    cfg: &SignalConfig,
) -> Result<Vec<RunSummary>, PreprocessError> {
    use rayon::prelude::*;
    dataset
        .runs
        .par_iter()
        .enumerate()
        .map(|(i, r)| summarize_run(r, i, dataset.sample_rate_hz, cfg).map(|(s, _)| s))
        .collect()
}

/// The true cause when the split leaves no run to train on: every run is a test run, or the
/// rest are unused.
fn no_training_runs(dataset: &Dataset, rules: &SplitRules<'_>) -> Result<(), PreprocessError> {
    let roles: Vec<RunRole> = dataset
        .runs
        .iter()
        .map(|r| rules.role(&r.entry.file, r.entry.oil_loss))
        .collect();
    if roles.contains(&RunRole::TrainValidation) {
        return Ok(());
    }
    let test = roles.iter().filter(|&&r| r == RunRole::Test).count();
    let unused = roles.len() - test;
    let c = rules.config;
    let levels = distinct_levels(dataset.runs.iter().map(|r| r.entry.oil_loss));
    let fmt = |v: &[f64]| v.iter().map(f64::to_string).collect::<Vec<_>>().join(", ");
    let hint = "nothing left to train on; use --test-tail FRACTION (the end of every run is \
                the test set) or --test-runs GLOB (some runs are)";
    let cause = if dataset.runs.is_empty() {
        "the dataset has no runs".to_string()
    } else if unused == 0 && levels.len() == 1 && c.role(levels[0]) == RunRole::Test {
        format!("every run is at the test level {}: {hint}", levels[0])
    } else if unused == 0 {
        format!(
            "every run is a test run (test levels [{}], test runs {:?}): {hint}",
            fmt(&c.test_alphas),
            c.test_runs
        )
    } else {
        format!(
            "no run is left for training: {test} test run(s) (test levels [{}], test runs {:?}) \
             and {unused} unused (excluded by {:?} or not at the training levels {})",
            fmt(&c.test_alphas),
            c.test_runs,
            c.exclude_runs,
            c.train_alphas
                .as_deref()
                .map_or("(all others)".to_string(), |a| format!("[{}]", fmt(a)))
        )
    };
    Err(PreprocessError::NoTrainingData(cause))
}

/// Splits, cuts and scales a dataset (see the module docs and `docs/data-format.md`).
///
/// Test runs (at a test level or matched by `test_runs`) give test sequences; every other run
/// (or those at `train_alphas`, and not excluded) is cut into the stretches of
/// [`run_stretches`]: training, one validation stretch and, with `test_tail`, a test tail.
/// Deterministic for a given dataset and configuration.
pub fn prepare(dataset: &Dataset, config: &PrepareConfig) -> Result<Prepared, PreprocessError> {
    use rayon::prelude::*;
    let fs = dataset.sample_rate_hz;
    check_cutoff(fs, config.signal.cutoff_hz)?;
    config.split.validate()?;
    config.split.check_levels(dataset)?;
    let rules = config.split.rules()?;
    no_training_runs(dataset, &rules)?;
    let window = config.quasi_static_window.unwrap_or(DEFAULT_QS_WINDOW);
    if !(window.is_finite() && window > 0.0 && window < 1.0) {
        return Err(config_err(
            "quasi_static_window",
            format!("{window} is not a fraction of the amplitude in (0, 1)"),
        ));
    }
    let (warmup, scored) = config.sequences.samples(fs)?;

    struct PerRun {
        prepared: PreparedRun,
        train: Vec<Sequence>,
        validation: Vec<Sequence>,
        test: Vec<Sequence>,
        qs: QuasiStaticSplit,
        /// Abs-max of velocity, force and alpha over the training sequences, in f64.
        train_absmax: [f64; 3],
        signals: Signals,
    }
    let per_run: Vec<PerRun> = dataset
        .runs
        .par_iter()
        .enumerate()
        .map(|(i, run)| -> Result<PerRun, PreprocessError> {
            let alpha = run.entry.oil_loss;
            let role = rules.role(&run.entry.file, alpha);
            let (summary, signals) = summarize_run(run, i, fs, &config.signal)?;
            let force = if config.signal.filter_force {
                &signals.force_filtered_n
            } else {
                &run.force_n
            };
            let n = run.len().min(signals.velocity_m_s.len()).min(force.len());
            let stretches = run_stretches(n, role, warmup, scored, &config.split, i);
            // Samples outside the training stretches are binned apart from training samples
            // (the low-acceleration rule of non-periodic runs).
            let outside_training = |sample: usize| {
                stretches
                    .iter()
                    .any(|st| st.part != Part::Train && (st.start..st.end).contains(&sample))
            };
            let periodic = super::support::periodicity(run, &signals.displacement_m, fs).is_some();
            let mut points = super::support::support_points(
                i,
                periodic,
                &signals,
                &summary.excitation,
                alpha,
                window,
                &outside_training,
            );
            if let Some(a) = &run.alpha {
                for p in &mut points {
                    p.alpha = a[p.sample];
                }
            }
            let mut out = PerRun {
                prepared: PreparedRun {
                    role,
                    train_sequences: 0,
                    validation_sequences: 0,
                    test_sequences: 0,
                    unscored_samples: 0,
                    quasi_static_points: points.len(),
                    stretches: stretches.clone(),
                    summary,
                },
                train: Vec::new(),
                validation: Vec::new(),
                test: Vec::new(),
                qs: QuasiStaticSplit::default(),
                train_absmax: [0.0; 3],
                signals: Signals::default(),
            };
            let absmax = |x: &[f64]| x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let mut scored_total = 0;
            for st in &stretches {
                let (a, b) = (st.start, st.end);
                let mut seqs = cut_sequences(
                    i,
                    alpha,
                    &signals.velocity_m_s[a..b],
                    &force[a..b],
                    &signals.displacement_m[a..b],
                    run.alpha.as_deref().map(|x| &x[a..b]),
                    warmup,
                    scored,
                );
                for s in &mut seqs {
                    s.start += a;
                }
                scored_total += seqs.len() * scored;
                match st.part {
                    Part::Test => out.test.extend(seqs),
                    Part::Validation => out.validation.extend(seqs),
                    Part::Train => {
                        for s in &seqs {
                            let range = s.start..s.start + warmup + scored;
                            let m = &mut out.train_absmax;
                            m[0] = m[0].max(absmax(&signals.velocity_m_s[range.clone()]));
                            m[1] = m[1].max(absmax(&force[range.clone()]));
                            m[2] = m[2].max(match &run.alpha {
                                Some(a) => absmax(&a[range]),
                                None => alpha.abs(),
                            });
                        }
                        out.train.extend(seqs);
                    }
                }
            }
            out.prepared.unscored_samples = if role == RunRole::Unused {
                0
            } else {
                n - scored_total
            };
            // A quasi-static point belongs to the stretch its sample lies in.
            for p in points {
                match stretches
                    .iter()
                    .find(|st| (st.start..st.end).contains(&p.sample))
                {
                    Some(st) if st.part == Part::Test => out.qs.test.push(p),
                    Some(st) if st.part == Part::Validation => out.qs.validation.push(p),
                    Some(_) => out.qs.train.push(p),
                    None => {}
                }
            }
            out.prepared.train_sequences = out.train.len();
            out.prepared.validation_sequences = out.validation.len();
            out.prepared.test_sequences = out.test.len();
            out.signals = signals;
            Ok(out)
        })
        .collect::<Result<_, _>>()?;

    let mut prepared = Prepared {
        config: config.clone(),
        sample_rate_hz: fs,
        dt_s: 1.0 / fs,
        warmup_samples: warmup,
        scored_samples: scored,
        train: Vec::new(),
        validation: Vec::new(),
        test: Vec::new(),
        quasi_static: QuasiStaticSplit::default(),
        scales: Scales {
            velocity_m_s: 1.0,
            force_n: 1.0,
            alpha: 1.0,
        },
        runs: Vec::with_capacity(per_run.len()),
        signals: Vec::with_capacity(per_run.len()),
        condition: dataset.condition(),
    };
    let mut train_absmax = [0.0f64; 3];
    for r in per_run {
        for (m, v) in train_absmax.iter_mut().zip(r.train_absmax) {
            *m = m.max(v);
        }
        prepared.train.extend(r.train);
        prepared.validation.extend(r.validation);
        prepared.test.extend(r.test);
        prepared.quasi_static.train.extend(r.qs.train);
        prepared.quasi_static.validation.extend(r.qs.validation);
        prepared.quasi_static.test.extend(r.qs.test);
        prepared.runs.push(r.prepared);
        prepared.signals.push(r.signals);
    }
    if prepared.train.is_empty() {
        let longest = prepared
            .runs
            .iter()
            .flat_map(|r| &r.stretches)
            .filter(|st| st.part == Part::Train)
            .map(|st| st.end - st.start)
            .max()
            .unwrap_or(0);
        let train_runs = prepared
            .runs
            .iter()
            .filter(|r| r.role == RunRole::TrainValidation)
            .count();
        return Err(PreprocessError::NoTrainingData(format!(
            "{train_runs} training run(s), whose longest training stretch has {longest} samples \
             ({:.3} s), fewer than one window needs (warm-up {warmup} + window {scored} = {} \
             samples, {:.3} s); use a shorter --window-s or --warmup-s{}",
            longest as f64 / fs,
            warmup + scored,
            (warmup + scored) as f64 / fs,
            if config.split.test_tail.is_some() {
                ", or a smaller --test-tail"
            } else {
                ""
            }
        )));
    }
    let [v, f, a] = train_absmax;
    prepared.scales = Scales::from_absmax(v, f, a)?;
    Ok(prepared)
}

impl Prepared {
    fn counts(&self, seqs: &[Sequence], qs: &[QuasiStaticPoint]) -> SplitCounts {
        let mut runs: Vec<usize> = seqs.iter().map(|s| s.run).collect();
        runs.dedup();
        SplitCounts {
            runs: runs.len(),
            sequences: seqs.len(),
            scored_samples: seqs.len() * self.scored_samples,
            quasi_static_points: qs.len(),
        }
    }

    /// Counts, scales and per-run facts.
    pub fn summary(&self, dataset_name: &str) -> PrepareSummary {
        PrepareSummary {
            dataset: dataset_name.to_string(),
            config: self.config.clone(),
            sample_rate_hz: self.sample_rate_hz,
            dt_s: self.dt_s,
            warmup_samples: self.warmup_samples,
            scored_samples: self.scored_samples,
            train: self.counts(&self.train, &self.quasi_static.train),
            validation: self.counts(&self.validation, &self.quasi_static.validation),
            test: self.counts(&self.test, &self.quasi_static.test),
            unused_runs: self
                .runs
                .iter()
                .filter(|r| r.role == RunRole::Unused)
                .count(),
            scales: self.scales,
            runs: self.runs.clone(),
        }
    }
}
