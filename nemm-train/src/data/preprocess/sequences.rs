//! Sequences: windows with a warm-up prefix for the rollout.

use super::{config_err, PreprocessError, DEFAULT_WARMUP_S, DEFAULT_WINDOW_S};
use serde::Deserialize;
use serde::Serialize;

/// Lengths of the training sequences.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SequenceConfig {
    /// Scored length \[s\] (default `DEFAULT_WINDOW_S`).
    pub window_s: f64,
    /// Warm-up prefix \[s\], simulated but not scored (default `DEFAULT_WARMUP_S`).
    pub warmup_s: f64,
}

impl Default for SequenceConfig {
    fn default() -> Self {
        SequenceConfig {
            window_s: DEFAULT_WINDOW_S,
            warmup_s: DEFAULT_WARMUP_S,
        }
    }
}

impl SequenceConfig {
    /// `(warm-up samples, scored samples)` at `sample_rate_hz` (rounded to whole samples).
    pub fn samples(&self, sample_rate_hz: f64) -> Result<(usize, usize), PreprocessError> {
        if !(self.window_s.is_finite() && self.window_s > 0.0) {
            return Err(config_err(
                "window_s",
                format!("{} s is not a positive duration", self.window_s),
            ));
        }
        if !(self.warmup_s.is_finite() && self.warmup_s >= 0.0) {
            return Err(config_err(
                "warmup_s",
                format!("{} s is not a non-negative duration", self.warmup_s),
            ));
        }
        let scored = (self.window_s * sample_rate_hz).round();
        if scored < 1.0 {
            return Err(config_err(
                "window_s",
                format!("{} s is shorter than one sample", self.window_s),
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
