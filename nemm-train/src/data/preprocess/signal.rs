//! Filtering and differentiation: the zero-phase low-pass, the derivative stencils, the causal velocity of the firmware, and the per-run signals.

use super::*;

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
    let path = SignalConfig {
        cutoff_hz,
        ..SignalConfig::default()
    }
    .at_rate(sample_rate_hz)?;
    Ok(path.lowpass(x))
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
    /// These settings at `sample_rate_hz`; refuses a cut-off that is not positive and below
    /// half the sample rate (the one check of the cut-off).
    pub fn at_rate(&self, sample_rate_hz: f64) -> Result<SignalPath, PreprocessError> {
        check_cutoff(sample_rate_hz, self.cutoff_hz)?;
        Ok(SignalPath {
            config: *self,
            sample_rate_hz,
        })
    }
}

impl SignalPath {
    /// The zero-phase low-pass of `x` ([`lowpass_zero_phase`]).
    pub fn lowpass(&self, x: &[f64]) -> Vec<f64> {
        zero_phase(x, self.sample_rate_hz, self.config.cutoff_hz)
    }

    /// Derives filtered displacement, velocity, acceleration and filtered force of a run.
    ///
    /// `run_index` only labels errors.
    pub fn process(&self, run: &Run, run_index: usize) -> Result<Signals, PreprocessError> {
        process_checked(run, run_index, self)
    }
}

/// Derives filtered displacement, velocity, acceleration and filtered force of a run
/// ([`SignalPath::process`] at `sample_rate_hz`).
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

fn process_checked(
    run: &Run,
    run_index: usize,
    path: &SignalPath,
) -> Result<Signals, PreprocessError> {
    let (sample_rate_hz, cfg) = (path.sample_rate_hz, &path.config);
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
    let displacement_m = path.lowpass(&run.displacement_m);
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
        Some(v) => path.lowpass(v),
        None if cfg.velocity_source == VelocitySource::Causal => {
            causal_velocity(&run.displacement_m, sample_rate_hz)
        }
        None => differentiate(&displacement_m, dt),
    };
    let acceleration_m_s2 = differentiate(&velocity_m_s, dt);
    let force_filtered_n = path.lowpass(&run.force_n);
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
