//! The whole preparation: signals, excitation, quasi-static points, sequences, split and scales of a dataset.

use super::{
    config_err, cut_sequences, distinct_levels, estimate_excitation, measured_velocity_mismatch,
    run_stretches, Cutoff, Dissipation, Excitation, ForceOffset, Part, PreprocessError,
    QuasiStaticPoint, RunRole, Scales, Sequence, SequenceConfig, SignalConfig, SignalPath, Signals,
    SplitConfig, SplitRules, Stretch, DEFAULT_QS_WINDOW,
};
use nemm_dataset::Dataset;
use nemm_dataset::Run;
use serde::Deserialize;
use serde::Serialize;
use std::path::PathBuf;

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
    /// means `DEFAULT_QS_WINDOW`.
    pub quasi_static_window: Option<f64>,
    /// Prepare runs whose force assists the motion (`Dissipation::force_assists_motion`)
    /// instead of refusing them (default `false`).
    #[serde(default)]
    pub accept_implausible: bool,
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
    pub(crate) force_min_n: f64,
    /// Largest measured force \[N\].
    pub(crate) force_max_n: f64,
    /// Estimated excitation.
    pub excitation: Excitation,
    /// `true` if the velocity is the measured column.
    pub measured_velocity: bool,
    /// Relative RMS difference of the measured velocity to the differentiated displacement.
    pub measured_velocity_mismatch: Option<f64>,
    /// Whether the force dissipates energy (force-velocity correlation, mean power).
    pub dissipation: Dissipation,
    /// Amplitude from the manifest \[m\], if given.
    pub manifest_amplitude_m: Option<f64>,
    /// Target velocity from the manifest \[m/s\], if given.
    pub manifest_target_velocity_m_s: Option<f64>,
    /// The low-pass cut-off of the run's signals, and why ([`Cutoff`]).
    pub cutoff: Cutoff,
    /// The force at zero velocity ([`ForceOffset`]); `None` without zero-velocity samples.
    pub force_offset: Option<ForceOffset>,
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
    pub(crate) unused_runs: usize,
    /// Scales.
    pub scales: Scales,
    /// Per run.
    pub runs: Vec<PreparedRun>,
}

/// Summarises one run: excitation, force range, velocity source.
pub fn summarize_run(
    run: &Run,
    index: usize,
    path: &SignalPath,
) -> Result<(RunSummary, Signals), PreprocessError> {
    let sample_rate_hz = path.sample_rate_hz;
    let signals = path.process(run, index)?;
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
        measured_velocity_mismatch: measured_velocity_mismatch(run, sample_rate_hz),
        dissipation: Dissipation::of(&signals.force_filtered_n, &signals.velocity_m_s),
        manifest_amplitude_m: run.entry.amplitude_m,
        manifest_target_velocity_m_s: run.entry.target_velocity_m_s,
        cutoff: signals.cutoff,
        force_offset: ForceOffset::of(&run.force_n, &signals.velocity_m_s),
    };
    Ok((summary, signals))
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
    let signal_path = config.signal.at_rate(fs)?;
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
    let ctx = RunContext {
        config,
        rules: &rules,
        signal_path: &signal_path,
        fs,
        window,
        warmup,
        scored,
    };
    let per_run: Vec<PerRun> = dataset
        .runs
        .par_iter()
        .enumerate()
        .map(|(i, run)| prepare_run(&ctx, run, i))
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
    let [v, f, a] = prepared.gather(per_run);
    if prepared.train.is_empty() {
        return Err(no_training_window(&prepared, config));
    }
    prepared.scales = Scales::from_absmax(v, f, a)?;
    Ok(prepared)
}

/// What [`prepare`] fixes for every run: the configuration and what it derived from it at
/// the dataset's sample rate.
struct RunContext<'a> {
    config: &'a PrepareConfig,
    rules: &'a SplitRules<'a>,
    signal_path: &'a SignalPath,
    /// Sample rate \[Hz\].
    fs: f64,
    /// Quasi-static window half-width as a fraction of the amplitude.
    window: f64,
    /// Warm-up samples per sequence.
    warmup: usize,
    /// Scored samples per sequence.
    scored: usize,
}

/// One run prepared: its summary, sequences, quasi-static points and signals.
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

/// Prepares run `i`: its signals and summary (refusing a run whose force assists the
/// motion unless configured otherwise), its stretches, the sequences cut from them and its
/// quasi-static points, each to the part of the stretch it lies in.
fn prepare_run(ctx: &RunContext<'_>, run: &Run, i: usize) -> Result<PerRun, PreprocessError> {
    let config = ctx.config;
    let alpha = run.entry.oil_loss;
    let role = ctx.rules.role(&run.entry.file, alpha);
    let (summary, signals) = summarize_run(run, i, ctx.signal_path)?;
    if role != RunRole::Unused
        && summary.dissipation.force_assists_motion()
        && !config.accept_implausible
    {
        return Err(PreprocessError::Implausible {
            run: i,
            file: run.entry.file.clone(),
            message: summary.dissipation.explain(),
        });
    }
    let force = if config.signal.filter_force {
        &signals.force_filtered_n
    } else {
        &run.force_n
    };
    let n = run.len().min(signals.velocity_m_s.len()).min(force.len());
    let stretches = run_stretches(n, role, ctx.warmup, ctx.scored, &config.split, i);
    let points = run_support_points(ctx, run, i, &signals, &summary.excitation, &stretches);
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
    let scored_total = out.cut_stretches(ctx, run, i, &signals, force, &stretches);
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
}

/// The quasi-static points of run `i` (at the run's level per sample when it varies).
/// Samples outside the training stretches are binned apart from training samples (the
/// low-acceleration rule of non-periodic runs).
fn run_support_points(
    ctx: &RunContext<'_>,
    run: &Run,
    i: usize,
    signals: &Signals,
    excitation: &Excitation,
    stretches: &[Stretch],
) -> Vec<QuasiStaticPoint> {
    let outside_training = |sample: usize| {
        stretches
            .iter()
            .any(|st| st.part != Part::Train && (st.start..st.end).contains(&sample))
    };
    let periodic =
        crate::data::support_points::periodicity(run, &signals.displacement_m, ctx.fs).is_some();
    let mut points = crate::data::support_points::support_points(
        i,
        periodic,
        signals,
        excitation,
        run.entry.oil_loss,
        ctx.window,
        &outside_training,
    );
    if let Some(a) = &run.alpha {
        for p in &mut points {
            p.alpha = a[p.sample];
        }
    }
    points
}

impl PerRun {
    /// Cuts the sequences of every stretch of run `i` into its part, and the training
    /// sequences' abs-max of velocity, force and alpha into `train_absmax`. Returns the
    /// scored samples.
    fn cut_stretches(
        &mut self,
        ctx: &RunContext<'_>,
        run: &Run,
        i: usize,
        signals: &Signals,
        force: &[f64],
        stretches: &[Stretch],
    ) -> usize {
        let (alpha, warmup, scored) = (run.entry.oil_loss, ctx.warmup, ctx.scored);
        let absmax = |x: &[f64]| x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut scored_total = 0;
        for st in stretches {
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
                Part::Test => self.test.extend(seqs),
                Part::Validation => self.validation.extend(seqs),
                Part::Train => {
                    for s in &seqs {
                        let range = s.start..s.start + warmup + scored;
                        let m = &mut self.train_absmax;
                        m[0] = m[0].max(absmax(&signals.velocity_m_s[range.clone()]));
                        m[1] = m[1].max(absmax(&force[range.clone()]));
                        m[2] = m[2].max(match &run.alpha {
                            Some(a) => absmax(&a[range]),
                            None => alpha.abs(),
                        });
                    }
                    self.train.extend(seqs);
                }
            }
        }
        scored_total
    }
}

impl Prepared {
    /// Appends the prepared runs in order; returns the abs-max of velocity, force and alpha
    /// over all training sequences.
    fn gather(&mut self, per_run: Vec<PerRun>) -> [f64; 3] {
        let mut train_absmax = [0.0f64; 3];
        for r in per_run {
            for (m, v) in train_absmax.iter_mut().zip(r.train_absmax) {
                *m = m.max(v);
            }
            self.train.extend(r.train);
            self.validation.extend(r.validation);
            self.test.extend(r.test);
            self.quasi_static.train.extend(r.qs.train);
            self.quasi_static.validation.extend(r.qs.validation);
            self.quasi_static.test.extend(r.qs.test);
            self.runs.push(r.prepared);
            self.signals.push(r.signals);
        }
        train_absmax
    }
}

/// The error of a preparation that gives no training window: the longest training stretch
/// is shorter than a sequence.
fn no_training_window(prepared: &Prepared, config: &PrepareConfig) -> PreprocessError {
    let (warmup, scored, fs) = (
        prepared.warmup_samples,
        prepared.scored_samples,
        prepared.sample_rate_hz,
    );
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
    PreprocessError::NoTrainingData(format!(
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
    ))
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
