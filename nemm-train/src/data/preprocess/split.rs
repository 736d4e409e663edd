//! Split and scales: the train / validation / test split of Table 2 and the abs-max feature scales.

use super::{
    config_err, sequence_count, PreprocessError, Sequence, ALPHA_TOLERANCE, DEFAULT_SPLIT_SEED,
    DEFAULT_TEST_ALPHAS, DEFAULT_VALIDATION_FRACTION,
};
use nemm_dataset::Dataset;
use serde::Deserialize;
use serde::Serialize;

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
    /// (default `DEFAULT_VALIDATION_FRACTION`).
    pub validation_fraction: f64,
    /// Seed of the position of each run's validation stretch (default `DEFAULT_SPLIT_SEED`).
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
pub(crate) fn file_matches(patterns: &[glob::Pattern], file: &std::path::Path) -> bool {
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
pub(crate) struct SplitRules<'a> {
    pub(super) config: &'a SplitConfig,
    test_runs: Vec<glob::Pattern>,
    exclude_runs: Vec<glob::Pattern>,
}

impl SplitRules<'_> {
    /// The role of a run with oil-loss level `alpha` stored in `file`: unused if excluded
    /// (`exclude_runs`) or not at a training level, test if at a test level or matched by
    /// `test_runs`, else training and validation.
    pub(crate) fn role(&self, file: &std::path::Path, alpha: f64) -> RunRole {
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
    pub(super) fn validate(&self) -> Result<(), PreprocessError> {
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
                    format!("{a} is not a condition level alpha in [0, 1]"),
                ));
            }
        }
        Ok(())
    }

    /// The split with its glob patterns compiled (errors name a bad pattern).
    pub(crate) fn rules(&self) -> Result<SplitRules<'_>, PreprocessError> {
        Ok(SplitRules {
            config: self,
            test_runs: compile_globs("test_runs", &self.test_runs)?,
            exclude_runs: compile_globs("exclude_runs", &self.exclude_runs)?,
        })
    }

    /// Every requested level must match a run of `dataset`, and every glob a run file: a
    /// level or pattern that matches none (a typo in `--test-alphas`, say) would silently
    /// leave the test set empty, or drop training data.
    pub(super) fn check_levels(&self, dataset: &Dataset) -> Result<(), PreprocessError> {
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
                let levels = distinct_levels(dataset.runs.iter().map(|r| r.entry.oil_loss));
                let alphas: Vec<String> = levels
                    .iter()
                    .map(|&l| nemm_dataset::alpha_text(l))
                    .collect();
                let condition = dataset.condition.clone().unwrap_or_default();
                let values = if condition.is_alpha_itself() {
                    String::new()
                } else {
                    format!(" ({})", condition.levels(&levels))
                };
                return Err(config_err(
                    key,
                    format!(
                        "alpha {} matches no run; the dataset's {} levels are alpha {}{values}",
                        nemm_dataset::alpha_text(a),
                        condition.name,
                        alphas.join(", ")
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
        self.describe_for(&nemm_dataset::ConditionSpec::default())
    }

    /// [`Self::describe`] with the levels named by the dataset's `condition`.
    pub(crate) fn describe_for(&self, condition: &nemm_dataset::ConditionSpec) -> String {
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
    /// patterns): `SplitRules::role` without `test_runs` and `exclude_runs`.
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
pub(crate) fn distinct_levels(alphas: impl IntoIterator<Item = f64>) -> Vec<f64> {
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
/// disjoint and each is cut into windows on its own ([`cut_sequences`](super::cut_sequences)), so no window, warm-up
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
    /// Scales of a set of (training) sequences (from their f32 values; [`prepare`](super::prepare()) uses the
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
    pub(crate) fn from_absmax(
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
