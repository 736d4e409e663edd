//! Identifiability: the condition level `alpha` that best explains a measured run.
//!
//! A trained model is simulated over a whole run at levels of a grid ([`AlphaGrid`]:
//! `0, step, 2 step, ...` up to the model's largest training level) and, once more, at the
//! run's own label; the grid level of least force RMSE is the best fit ([`identify`]). The
//! simulation is [`predict`]: one input per level, so the trainer's batched rollout advances
//! `LANES` levels in lock step (the SEM runs through nemm-core's estimator). A model whose
//! RMSE varies by no more than `FLAT_TOLERANCE` of its largest value (the Linear EMM, or a
//! network that ignores `alpha`) has no best fit: [`Fit::best`] is `None`.
//!
//! [`Search`] says which levels are simulated:
//!
//! - [`Search::CoarseToFine`] (the default): first a search on nemm-core's tables, then an
//!   exact search from its best level (`identify_with_tables`). The table search is
//!   `coarse_to_fine` with each level simulated by a table-mode estimator built at that
//!   level (nemm-core's `EvalMode::Table`, whose step costs a fraction of an exact one); it
//!   only picks where to look. The exact search starts from the table search's best level,
//!   `TABLE_WINDOW` levels on each side and the label (one pack of lanes), and refines
//!   the candidate minima of the exact curve as `coarse_to_fine` does (`refine`): a
//!   window whose least level is at its edge is extended towards the grid's end. So the
//!   best fit, the curve and the label's RMSE are exact simulations only. When no table can
//!   be built (an error from nemm-core), when the table curve is flat or not finite, or for
//!   a model without neural coefficients or batched rollout (the SEM, the Linear EMM), the
//!   exact search starts from `coarse_to_fine`'s first round; an exact window that is flat
//!   gets that round's levels too.
//!
//!   `coarse_to_fine` alone: first `LANES - 1` levels spread evenly over the grid, ends
//!   included, and the label's simulation (one pack of lanes); then, in rounds, the
//!   unsimulated levels between each candidate and its simulated neighbours, up to
//!   `LANES` per candidate and round, until every candidate's neighbours on the grid are
//!   simulated. The candidates are the local minima of the simulated curve within
//!   `MINIMA_MARGIN` of its range above its least value, so a second valley is refined as
//!   well as the deepest one. A curve flat at the first round's levels stops there.
//! - [`Search::Full`]: every grid level, the whole RMSE curve.
//!
//! The coarse-to-fine best fit is the full grid's wherever the exact RMSE curve has one
//! valley and the table search lands in it, and where another valley is deeper only if its
//! sampled levels come within the margin; `nemm-train/benches/identify_time.rs` compares
//! the two searches on a dataset. The label's simulation is the grid level's when the label
//! is constant and on the grid and that level is simulated, so it costs no lane of its own.
//!
//! `identify_runs` searches many runs together: their table searches in parallel, then
//! their exact searches a round at a time, the simulations of a round packed across runs
//! (longest runs first, `LANES` to a pack; a lane's force does not depend on its pack's
//! other lanes, so every fit is the one [`identify`] gives the run alone).
//!
//! The grid bounds the resolution: a run is identified to the nearest grid level, and only
//! where the model's force depends on `alpha` at that run's excitation.

use super::eval::{predict, run_estimator, Input};
use anyhow::{anyhow, bail, ensure, Result};
use nemm_core::{Estimator, EstimatorConfig, EvalMode, Model, ModelKind, TableConfig};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Default grid step in `alpha`.
pub const DEFAULT_STEP: f64 = 0.01;

/// Relative RMSE variation over the simulated levels, `(max - min) / max`, at or below which
/// a run's RMSE curve counts as flat (the model does not tell the levels apart on that run).
pub(crate) const FLAT_TOLERANCE: f64 = 1e-3;

/// Levels simulated in lock step by one pack of the batched rollout: the coarse round's
/// size and each candidate's share of a refining round.
pub(crate) const LANES: usize = super::adjoint::LANES;

/// A local minimum of the simulated RMSE curve whose value lies within this fraction of the
/// curve's range (largest minus least value) above the least value is refined by
/// [`coarse_to_fine`] as well as the least one.
pub(crate) const MINIMA_MARGIN: f64 = 0.25;

/// Which grid levels [`identify`] simulates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Search {
    /// A coarse round over the grid, then rounds that refine the candidate minima down to
    /// the grid step (`coarse_to_fine`).
    #[default]
    CoarseToFine,
    /// Every grid level.
    Full,
}

impl Search {
    /// The name in reports: `coarse-to-fine` or `full`.
    pub fn name(self) -> &'static str {
        match self {
            Search::CoarseToFine => "coarse-to-fine",
            Search::Full => "full",
        }
    }

    /// The search of a report that does not name one: [`Search::Full`].
    pub(crate) fn unnamed() -> Self {
        Search::Full
    }
}

/// The levels a run is simulated at: `0, step, 2 step, ...` up to `max` (included when it
/// is a multiple of the step; each level rounded to 1e-9).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlphaGrid {
    /// The levels, ascending.
    pub alphas: Vec<f64>,
}

impl AlphaGrid {
    /// `0, step, ...` up to `max` (`0 < step`, `0 <= max <= 1`).
    pub fn new(step: f64, max: f64) -> Result<Self> {
        if !(step.is_finite() && step > 0.0) {
            bail!("the alpha grid step must be positive (got {step})");
        }
        if !(0.0..=1.0).contains(&max) {
            bail!("the alpha grid must end in [0, 1] (got {max})");
        }
        let count = (max / step + 1e-9).floor() as usize + 1;
        Ok(Self {
            alphas: (0..count)
                .map(|i| (i as f64 * step * 1e9).round() / 1e9)
                .collect(),
        })
    }

    /// `0, step, ...` up to the largest training level of `model` (`Meta::alpha_max`; 1 for
    /// a model trained at level 0 only).
    pub fn for_model(model: &Model, step: f64) -> Result<Self> {
        let max = f64::from(model.meta.alpha_max);
        Self::new(step, if max > 0.0 { max.min(1.0) } else { 1.0 })
    }
}

/// One whole run to identify: the model inputs as [`Input`] takes them, the measured force
/// and the run's label.
#[derive(Debug, Clone, Copy)]
pub struct Run<'a> {
    /// Stroke velocity \[m/s\] per sample.
    pub velocity_m_s: &'a [f32],
    /// Stroke position \[m\] per sample (the static force's input), if known.
    pub position_m: Option<&'a [f32]>,
    /// Measured force \[N\] per sample.
    pub force_n: &'a [f64],
    /// The run's labelled level.
    pub label: f64,
    /// Level per sample, if the run has one: the label simulation uses it (the grid
    /// simulations hold each level constant).
    pub label_alphas: Option<&'a [f32]>,
}

/// A number that JSON wrote as `null` (serde_json writes NaN so) reads back as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The result of [`identify`] on one run (RMSE in newtons, over the samples after the
/// warm-up).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fit {
    /// The run's labelled level.
    pub label: f64,
    /// The simulated level of least RMSE (the lowest on a tie); `None` when the curve is
    /// flat (`FLAT_TOLERANCE`) or a simulation is not finite.
    pub best: Option<f64>,
    /// RMSE at the least-error simulated level \[N\] (defined when the curve is flat too).
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_best_n: f64,
    /// RMSE at the label (per sample where the run has a level column) \[N\].
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_label_n: f64,
    /// The grid levels simulated, ascending: every grid level for [`Search::Full`], the
    /// coarse and the refined levels for [`Search::CoarseToFine`] (absent in a report:
    /// every level of its grid).
    #[serde(default)]
    pub levels: Vec<f64>,
    /// RMSE at each level of [`Fit::levels`] \[N\], in that order.
    pub curve_n: Vec<f64>,
    /// Scored samples.
    pub samples: usize,
}

impl Fit {
    /// `true` if the best fit is within `tolerance` (plus
    /// `crate::data::preprocess::ALPHA_TOLERANCE`) of the label (`false` when flat).
    pub fn within(&self, tolerance: f64) -> bool {
        self.best.is_some_and(|b| {
            (b - self.label).abs() <= tolerance + crate::data::preprocess::ALPHA_TOLERANCE
        })
    }
}

/// `true` if `curve` varies by no more than [`FLAT_TOLERANCE`] of its largest value.
pub(crate) fn is_flat(curve: &[f64]) -> bool {
    let (lo, hi) = curve
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &e| {
            (lo.min(e), hi.max(e))
        });
    hi - lo <= FLAT_TOLERANCE * hi
}

/// At most `count` of the sorted indices `open`, spread evenly over them (all of them when
/// there are no more than `count`).
fn spread(open: &[usize], count: usize) -> Vec<usize> {
    if open.len() <= count {
        return open.to_vec();
    }
    (0..count)
        .map(|j| open[(2 * j + 1) * open.len() / (2 * count)])
        .collect()
}

/// The first round of [`coarse_to_fine`] over `n` indices: every index when `n <= count`,
/// else `count` indices spread evenly from `0` to `n - 1`, both ends included.
fn coarse_indices(n: usize, count: usize) -> Vec<usize> {
    if n <= count || count < 2 {
        return (0..n).collect();
    }
    let mut ks: Vec<usize> = (0..count)
        .map(|j| ((j * (n - 1)) as f64 / (count - 1) as f64).round() as usize)
        .collect();
    ks.dedup();
    ks
}

/// Coarse-to-fine search for the least value of a curve over the indices `0..n` (a grid's
/// levels), the values computed in rounds by `eval` (one value per index, in order; a NaN
/// counts as not finite). Returns every index evaluated with its value.
///
/// Round one evaluates `extra` (indices wanted anyway, such as a run's label) and
/// `LANES - 1` indices spread evenly from `0` to `n - 1`. Each further round takes the
/// candidates: the local minima of the evaluated curve (no greater than their evaluated
/// neighbours; an end counts when no greater than its one neighbour) whose value is within
/// [`MINIMA_MARGIN`] of the curve's range above its least value. For each it evaluates up
/// to [`LANES`] of the unevaluated indices between its evaluated neighbours, spread evenly.
/// The search ends when no candidate has an unevaluated index next to it, when the
/// evaluated curve is flat ([`is_flat`]) or when a value is not finite. The least value is
/// then the least over `0..n` if the curve has one valley, and if its other valleys are
/// within the margin where they are sampled.
pub(crate) fn coarse_to_fine(
    n: usize,
    extra: &[usize],
    eval: impl FnMut(&[usize]) -> Result<Vec<f64>>,
) -> Result<BTreeMap<usize, f64>> {
    let mut round: Vec<usize> = coarse_indices(n, LANES - 1);
    round.extend(extra.iter().copied());
    refine(n, BTreeMap::new(), round, eval)
}

/// The rounds of [`coarse_to_fine`] from the values already evaluated (`seen`) and a first
/// round of indices (those below `n` and not in `seen` are evaluated): after each round the
/// candidate minima of everything evaluated so far are refined as there. Returns every
/// index evaluated with its value, `seen` included.
pub(crate) fn refine(
    n: usize,
    seen: BTreeMap<usize, f64>,
    first: Vec<usize>,
    mut eval: impl FnMut(&[usize]) -> Result<Vec<f64>>,
) -> Result<BTreeMap<usize, f64>> {
    let mut rounds = Rounds::new(n, seen, first);
    while !rounds.round.is_empty() {
        let values = eval(&rounds.round)?;
        rounds.feed(values)?;
    }
    Ok(rounds.seen)
}

/// [`refine`] one round at a time: the indices to evaluate next ([`Rounds::round`], empty
/// when the search has ended) and everything evaluated so far.
#[derive(Debug, Clone)]
struct Rounds {
    n: usize,
    seen: BTreeMap<usize, f64>,
    round: Vec<usize>,
}

impl Rounds {
    /// The search from `seen` with the first round `first` (those below `n` and not in
    /// `seen`, ascending).
    fn new(n: usize, seen: BTreeMap<usize, f64>, first: Vec<usize>) -> Self {
        let mut round: Vec<usize> = first
            .into_iter()
            .filter(|&k| k < n && !seen.contains_key(&k))
            .collect();
        round.sort_unstable();
        round.dedup();
        Self { n, seen, round }
    }

    /// Takes the values of the current round (in its order) and sets the next round: the
    /// candidates' unevaluated neighbours, or nothing when the curve is flat or not finite.
    fn feed(&mut self, values: Vec<f64>) -> Result<()> {
        let round = std::mem::take(&mut self.round);
        ensure!(
            values.len() == round.len(),
            "{} values for {} levels",
            values.len(),
            round.len()
        );
        self.seen.extend(round.iter().copied().zip(values));
        let pts: Vec<(usize, f64)> = self.seen.iter().map(|(&k, &v)| (k, v)).collect();
        if pts.iter().any(|p| !p.1.is_finite()) {
            return Ok(());
        }
        let curve: Vec<f64> = pts.iter().map(|p| p.1).collect();
        if is_flat(&curve) {
            return Ok(());
        }
        let least = curve.iter().copied().fold(f64::INFINITY, f64::min);
        let most = curve.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let bar = least + MINIMA_MARGIN * (most - least);
        let mut next = Vec::new();
        for (j, &(k, v)) in pts.iter().enumerate() {
            let left = j.checked_sub(1).map(|j| pts[j]);
            let right = pts.get(j + 1).copied();
            let minimum = left.is_none_or(|l| v <= l.1) && right.is_none_or(|r| v <= r.1);
            if !minimum || v > bar {
                continue;
            }
            let lo = left.map_or(0, |l| l.0 + 1);
            let hi = right.map_or(self.n, |r| r.0);
            let open: Vec<usize> = (lo..hi).filter(|&i| i != k).collect();
            next.extend(spread(&open, LANES));
        }
        next.sort_unstable();
        next.dedup();
        self.round = next;
        Ok(())
    }
}

/// Simulates `run` (samples `sample_dt_s` apart, from rest) with `model` at the levels of
/// `grid` that `search` visits and at its label, and scores the force after `warmup`
/// samples. The label's simulation is the grid level's when the label is constant and on
/// the grid (as `f32`), else a simulation of its own in the first exact round.
/// [`Search::CoarseToFine`] first searches on nemm-core's tables ([`TableConfig::default`];
/// `identify_with_tables`).
pub fn identify(
    model: &Model,
    run: &Run<'_>,
    grid: &AlphaGrid,
    sample_dt_s: f64,
    warmup: usize,
    search: Search,
) -> Result<Fit> {
    identify_with_tables(
        model,
        run,
        grid,
        sample_dt_s,
        warmup,
        search,
        Some(&TableEstimators::new(grid, TableConfig::default())),
    )
}

/// Levels on each side of the table search's best level that the first exact round of
/// [`Search::CoarseToFine`] simulates (with that level: `LANES - 1`, and the label's lane).
pub(crate) const TABLE_WINDOW: usize = (LANES - 2) / 2;

/// `true` if [`identify`] runs `model`'s table search: a NEMM or a NEMM-Light (the models
/// with neural coefficients and a batched exact rollout).
pub(crate) fn has_table_search(model: &Model) -> bool {
    matches!(model.kind(), ModelKind::Nemm | ModelKind::NemmLight)
}

/// The table-mode estimators of the table search, one per grid level, built on first use
/// (at that level, with one [`TableConfig`]) and shared by the runs of [`identify_runs`]:
/// each simulation starts from a copy at rest. A level whose estimator cannot be built
/// holds `None`.
#[derive(Debug)]
pub(crate) struct TableEstimators {
    config: TableConfig,
    levels: Vec<std::sync::OnceLock<Option<Box<Estimator<'static>>>>>,
}

impl TableEstimators {
    /// No estimator built yet, for the levels of `grid`.
    pub(crate) fn new(grid: &AlphaGrid, config: TableConfig) -> Self {
        Self {
            config,
            levels: (0..grid.alphas.len())
                .map(|_| std::sync::OnceLock::new())
                .collect(),
        }
    }

    /// A copy at rest of level `k`'s estimator (alpha `alpha`), built on first use; `None`
    /// if it cannot be built.
    fn at(&self, model: &Model, k: usize, alpha: f64) -> Option<Box<Estimator<'static>>> {
        let cell = self.levels.get(k)?;
        let est = cell.get_or_init(|| {
            let cfg = EstimatorConfig {
                mode: EvalMode::Table(self.config),
                ..EstimatorConfig::new(alpha as f32)
            };
            Estimator::new(model, cfg).ok().map(Box::new)
        });
        est.clone().map(|mut e| {
            e.reset();
            e
        })
    }
}

/// The table search of [`identify_with_tables`]: [`coarse_to_fine`] over the grid with each
/// level simulated by a table-mode estimator at that level ([`run_estimator`]). Returns the
/// index of the least table RMSE, or `None` when a table-mode estimator cannot be built
/// (an error from nemm-core) or the table curve is flat or not finite.
fn table_search(
    model: &Model,
    run: &Run<'_>,
    grid: &AlphaGrid,
    sample_dt_s: f64,
    tables: &TableEstimators,
    rmse: &dyn Fn(&[f64]) -> f64,
) -> Option<usize> {
    let n = run.velocity_m_s.len().min(run.force_n.len());
    let input = |alpha: f64| Input {
        velocity_m_s: &run.velocity_m_s[..n],
        alpha: alpha as f32,
        alphas: None,
        position_m: run.position_m.map(|x| &x[..n.min(x.len())]),
    };
    let eval = |ks: &[usize]| -> Result<Vec<f64>> {
        ks.iter()
            .map(|&k| {
                let alpha = grid.alphas[k];
                let mut est = tables
                    .at(model, k, alpha)
                    .ok_or_else(|| anyhow!("no table at level {alpha}"))?;
                let (y, _) =
                    run_estimator(&mut est, f64::from(model.dt_s), &input(alpha), sample_dt_s)?;
                Ok(rmse(&y))
            })
            .collect()
    };
    let seen = coarse_to_fine(grid.alphas.len(), &[], eval).ok()?;
    let curve: Vec<f64> = seen.values().copied().collect();
    if curve.iter().any(|e| !e.is_finite()) || is_flat(&curve) {
        return None;
    }
    seen.iter()
        .fold(None, |b: Option<(usize, f64)>, (&k, &e)| match b {
            Some((_, be)) if be <= e => b,
            _ => Some((k, e)),
        })
        .map(|b| b.0)
}

/// [`identify`] with the table search's settings: `None` runs [`Search::CoarseToFine`]
/// exactly from its first round.
///
/// With tables (and a model with [`has_table_search`]), [`Search::CoarseToFine`] first
/// runs [`coarse_to_fine`] on table simulations (one table-mode estimator per level, built
/// at that level); its best level and [`TABLE_WINDOW`] levels on each side, and the label,
/// are the first exact round, and [`refine`] continues from there exactly, so the best fit
/// is decided by exact simulations. When a table cannot be built (an error from
/// nemm-core), or the table curve is flat or not finite, the exact search starts from its
/// coarse round; when the exact window is flat or not finite, the coarse round's levels
/// are added.
pub(crate) fn identify_with_tables(
    model: &Model,
    run: &Run<'_>,
    grid: &AlphaGrid,
    sample_dt_s: f64,
    warmup: usize,
    search: Search,
    tables: Option<&TableEstimators>,
) -> Result<Fit> {
    let mut fits = identify_packed(
        model,
        std::slice::from_ref(run),
        grid,
        sample_dt_s,
        warmup,
        search,
        tables,
    )?;
    fits.pop().ok_or_else(|| anyhow!("no fit"))
}

/// What a run's exact simulations are scored on: its samples and warm-up, and the grid
/// level of its label when the label is constant and on the grid.
struct Scoring {
    /// Samples of the run (velocity and force).
    n: usize,
    /// Samples scored (after the warm-up).
    samples: usize,
    warmup: usize,
    label_level: Option<usize>,
}

impl Scoring {
    fn new(run: &Run<'_>, grid: &AlphaGrid, warmup: usize) -> Self {
        let n = run.velocity_m_s.len().min(run.force_n.len());
        Self {
            n,
            samples: n.saturating_sub(warmup),
            warmup,
            label_level: match run.label_alphas {
                None => grid
                    .alphas
                    .iter()
                    .position(|&a| a as f32 == run.label as f32),
                Some(_) => None,
            },
        }
    }

    /// The force RMSE of the simulated force `y` after the warm-up.
    fn rmse(&self, run: &Run<'_>, y: &[f64]) -> f64 {
        let (w, n) = (self.warmup.min(self.n), self.n);
        let se: f64 = y[w..n]
            .iter()
            .zip(&run.force_n[w..n])
            .map(|(&y, &f)| (y - f) * (y - f))
            .sum();
        super::eval::rmse_of(se, self.samples)
    }
}

/// The exact search of one run, one round at a time: [`Rounds`] from its first round
/// (the table window, the coarse round or every level), the coarse round after a table
/// window whose curve is flat or not finite, and the label's simulation with the first
/// round.
struct ExactSearch {
    rounds: Rounds,
    /// The coarse round follows if the curve is flat or not finite once `rounds` ends.
    coarse_after: bool,
    /// The label's own simulation joins the next round.
    label_pending: bool,
    rmse_label_n: f64,
}

impl ExactSearch {
    fn new(search: Search, table_best: Option<usize>, levels: usize, scoring: &Scoring) -> Self {
        let extra: Vec<usize> = scoring.label_level.into_iter().collect();
        let (first, coarse_after) = match (search, table_best) {
            (Search::CoarseToFine, Some(k)) => (
                (k.saturating_sub(TABLE_WINDOW)..=k + TABLE_WINDOW)
                    .chain(extra)
                    .collect(),
                true,
            ),
            (Search::CoarseToFine, None) => {
                let mut first = coarse_indices(levels, LANES - 1);
                first.extend(extra);
                (first, false)
            }
            (Search::Full, _) => ((0..levels).collect(), false),
        };
        Self {
            rounds: Rounds::new(levels, BTreeMap::new(), first),
            coarse_after,
            label_pending: scoring.label_level.is_none(),
            rmse_label_n: f64::NAN,
        }
    }

    /// The grid levels to simulate next and whether the label's simulation follows them
    /// (nothing when the search has ended).
    fn request(&self) -> (&[usize], bool) {
        let round = self.rounds.round.as_slice();
        (round, self.label_pending && !round.is_empty())
    }

    /// Takes the RMSE of the simulations of [`Self::request`], in its order.
    fn feed(&mut self, mut values: Vec<f64>) -> Result<()> {
        if self.request().1 {
            self.rmse_label_n = values.pop().unwrap_or(f64::NAN);
            self.label_pending = false;
        }
        self.rounds.feed(values)?;
        if self.rounds.round.is_empty() && self.coarse_after {
            self.coarse_after = false;
            let curve: Vec<f64> = self.rounds.seen.values().copied().collect();
            if curve.iter().any(|e| !e.is_finite()) || is_flat(&curve) {
                let n = self.rounds.n;
                let seen = std::mem::take(&mut self.rounds.seen);
                self.rounds = Rounds::new(n, seen, coarse_indices(n, LANES - 1));
            }
        }
        Ok(())
    }

    /// The fit from every level simulated.
    fn fit(self, run: &Run<'_>, grid: &AlphaGrid, scoring: &Scoring) -> Fit {
        let seen = self.rounds.seen;
        let rmse_label_n = match scoring.label_level {
            Some(k) => seen.get(&k).copied().unwrap_or(f64::NAN),
            None => self.rmse_label_n,
        };
        let levels: Vec<f64> = seen.keys().map(|&k| grid.alphas[k]).collect();
        let curve_n: Vec<f64> = seen.into_values().collect();
        let (k, rmse_best_n) =
            curve_n
                .iter()
                .enumerate()
                .fold(
                    (0, f64::INFINITY),
                    |(bk, be), (k, &e)| {
                        if e < be {
                            (k, e)
                        } else {
                            (bk, be)
                        }
                    },
                );
        let finite = curve_n.iter().all(|e| e.is_finite());
        let best = (finite && !curve_n.is_empty() && !is_flat(&curve_n)).then(|| levels[k]);
        Fit {
            label: run.label,
            best,
            rmse_best_n: if curve_n.is_empty() {
                f64::NAN
            } else {
                rmse_best_n
            },
            rmse_label_n,
            levels,
            curve_n,
            samples: scoring.samples,
        }
    }
}

/// One exact simulation of a round: run `run` at grid level `level`, or at its label.
#[derive(Debug, Clone, Copy)]
struct Lane {
    run: usize,
    level: Option<usize>,
}

/// [`identify_with_tables`] of every run of `runs`: the table searches run in parallel,
/// then the exact searches advance together, a round of every run at a time, and the
/// simulations of a round are packed across runs: ordered by run length, longest first,
/// [`LANES`] to a pack (a pack runs as long as its longest run; a shorter run's force is
/// not affected by the padding), the packs in parallel. A lane's force does not depend on
/// the other lanes of its pack, so the fits are those of each run searched alone.
fn identify_packed(
    model: &Model,
    runs: &[Run<'_>],
    grid: &AlphaGrid,
    sample_dt_s: f64,
    warmup: usize,
    search: Search,
    tables: Option<&TableEstimators>,
) -> Result<Vec<Fit>> {
    use rayon::prelude::*;
    let scorings: Vec<Scoring> = runs.iter().map(|r| Scoring::new(r, grid, warmup)).collect();
    let table_best: Vec<Option<usize>> = match (search, tables) {
        (Search::CoarseToFine, Some(t)) if has_table_search(model) => runs
            .par_iter()
            .zip(&scorings)
            .map(|(run, sc)| {
                table_search(model, run, grid, sample_dt_s, t, &|y: &[f64]| {
                    sc.rmse(run, y)
                })
            })
            .collect(),
        _ => vec![None; runs.len()],
    };
    let mut searches: Vec<ExactSearch> = table_best
        .iter()
        .zip(&scorings)
        .map(|(&k, sc)| ExactSearch::new(search, k, grid.alphas.len(), sc))
        .collect();
    loop {
        let mut lanes: Vec<Lane> = Vec::new();
        for (i, s) in searches.iter().enumerate() {
            let (levels, label) = s.request();
            lanes.extend(levels.iter().map(|&k| Lane {
                run: i,
                level: Some(k),
            }));
            if label {
                lanes.push(Lane {
                    run: i,
                    level: None,
                });
            }
        }
        if lanes.is_empty() {
            break;
        }
        // Longest runs first; a run's lanes stay in request order.
        lanes.sort_by_key(|l| std::cmp::Reverse(runs[l.run].velocity_m_s.len()));
        let input = |l: &Lane| {
            let run = &runs[l.run];
            let base = Input {
                velocity_m_s: run.velocity_m_s,
                alpha: 0.0,
                alphas: None,
                position_m: run.position_m,
            };
            match l.level {
                Some(k) => Input {
                    alpha: grid.alphas[k] as f32,
                    ..base
                },
                None => Input {
                    alpha: run.label as f32,
                    alphas: run.label_alphas,
                    ..base
                },
            }
        };
        let errors: Vec<Vec<f64>> = lanes
            .par_chunks(LANES)
            .map(|pack| -> Result<Vec<f64>> {
                let inputs: Vec<Input<'_>> = pack.iter().map(input).collect();
                Ok(predict(model, &inputs, sample_dt_s)?
                    .iter()
                    .zip(pack)
                    .map(|(y, l)| scorings[l.run].rmse(&runs[l.run], y))
                    .collect())
            })
            .collect::<Result<_>>()?;
        let mut values: Vec<Vec<f64>> = vec![Vec::new(); runs.len()];
        for (l, e) in lanes.iter().zip(errors.into_iter().flatten()) {
            values[l.run].push(e);
        }
        // The sort is stable: each run's values are in its request order (the levels,
        // then the label).
        for (s, v) in searches.iter_mut().zip(values) {
            if !s.request().0.is_empty() {
                s.feed(v)?;
            }
        }
    }
    Ok(searches
        .into_iter()
        .zip(runs)
        .zip(&scorings)
        .map(|((s, run), sc)| s.fit(run, grid, sc))
        .collect())
}

/// [`identify`] of every run of `runs` ([`identify_packed`]: the exact simulations of the
/// runs share packs); returns the fits in order.
pub(crate) fn identify_runs(
    model: &Model,
    runs: &[Run<'_>],
    grid: &AlphaGrid,
    sample_dt_s: f64,
    warmup: usize,
    search: Search,
) -> Result<Vec<Fit>> {
    let tables = TableEstimators::new(grid, TableConfig::default());
    identify_packed(
        model,
        runs,
        grid,
        sample_dt_s,
        warmup,
        search,
        Some(&tables),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use nemm_core::testing::example_model;
    use nemm_core::{Body, ModelKind, DEFAULT_PARAM_CAPACITY};

    /// A 10 mm sine at 5 Hz for 0.4 s at 10 kHz: velocity and position.
    fn sine() -> (Vec<f32>, Vec<f32>) {
        let (a, w, dt) = (0.01f64, 2.0 * std::f64::consts::PI * 5.0, 1e-4);
        (0..4000)
            .map(|k| {
                let t = k as f64 * dt;
                ((a * w * (w * t).cos()) as f32, (a * (w * t).sin()) as f32)
            })
            .unzip()
    }

    fn model(kind: ModelKind) -> Model {
        example_model::<DEFAULT_PARAM_CAPACITY>(kind, 8, 3).expect("example model")
    }

    /// The force of `model` over `sine()` at `alpha`, simulated by [`predict`] alone.
    fn force_at(model: &Model, v: &[f32], x: &[f32], alpha: f32) -> Vec<f64> {
        let input = Input {
            velocity_m_s: v,
            alpha,
            alphas: None,
            position_m: Some(x),
        };
        predict(model, &[input], 1e-4).expect("predict").remove(0)
    }

    #[test]
    fn the_grid_runs_from_zero_to_the_largest_multiple_of_the_step() {
        let g = AlphaGrid::new(0.01, 0.3).expect("grid");
        assert_eq!(g.alphas.len(), 31);
        assert_eq!((g.alphas[7], g.alphas[20], g.alphas[30]), (0.07, 0.2, 0.3));
        let g = AlphaGrid::new(0.07, 0.3).expect("grid");
        assert_eq!(g.alphas, [0.0, 0.07, 0.14, 0.21, 0.28]);
        assert_eq!(
            AlphaGrid::for_model(&model(ModelKind::Nemm), 0.05)
                .expect("grid")
                .alphas
                .len(),
            7
        );
        assert!(AlphaGrid::new(0.0, 0.3).is_err());
        assert!(AlphaGrid::new(0.01, 1.5).is_err());
    }

    #[test]
    fn a_run_simulated_at_a_grid_level_is_identified_exactly() {
        let (v, x) = sine();
        let grid = AlphaGrid::new(0.01, 0.3).expect("grid");
        for kind in [ModelKind::Nemm, ModelKind::NemmLight, ModelKind::Sem] {
            let m = model(kind);
            for (truth, k) in [(0.2f32, 20usize), (0.07, 7)] {
                let f = force_at(&m, &v, &x, truth);
                let run = |label: f64| Run {
                    velocity_m_s: &v,
                    position_m: Some(&x),
                    force_n: &f,
                    label,
                    label_alphas: None,
                };
                let fit = identify(&m, &run(grid.alphas[k]), &grid, 1e-4, 100, Search::Full)
                    .expect("fit");
                let what = format!("{} at {truth}", kind.name());
                assert_eq!(fit.best, Some(grid.alphas[k]), "{what}: {:?}", fit.curve_n);
                // The force runs to about 2 kN: nothing but last-bit differences.
                assert!(fit.rmse_best_n <= 1e-3, "{what}: {}", fit.rmse_best_n);
                assert_eq!(fit.curve_n[k], fit.rmse_best_n, "{what}");
                assert!(fit.rmse_label_n <= 1e-3, "{what}: {}", fit.rmse_label_n);
                assert_eq!((fit.curve_n.len(), fit.samples), (31, 3900), "{what}");
                assert!(fit.within(0.0), "{what}");
                // Every other level errs.
                assert!(
                    fit.curve_n
                        .iter()
                        .enumerate()
                        .all(|(j, &e)| j == k || e > 100.0 * fit.rmse_best_n),
                    "{what}: {:?}",
                    fit.curve_n
                );
                // Labelled 0.15: the fit is still the truth, the label's error is not 0.
                let other = identify(&m, &run(0.15), &grid, 1e-4, 100, Search::Full).expect("fit");
                assert_eq!(other.best, fit.best, "{what}");
                assert!(other.rmse_label_n > 0.0, "{what}");
                assert_eq!(other.within(0.03), (f64::from(truth) - 0.15).abs() <= 0.03);
            }
        }
    }

    #[test]
    fn a_model_without_alpha_dependence_has_a_flat_curve_and_no_best_fit() {
        let (v, x) = sine();
        let grid = AlphaGrid::new(0.01, 0.3).expect("grid");
        // The Linear EMM, and the example NEMM with the alpha column of every scaler's first
        // layer zeroed.
        let mut constant = model(ModelKind::Nemm);
        if let Body::Nemm {
            b_fl, b_pr, k_pr, ..
        } = &mut constant.body
        {
            for s in [b_fl, b_pr, k_pr] {
                s.mlp.clear_alpha_column();
            }
        }
        let measured = force_at(&model(ModelKind::Nemm), &v, &x, 0.1);
        let runs: Vec<Run<'_>> = (0..3)
            .map(|_| Run {
                velocity_m_s: &v,
                position_m: Some(&x),
                force_n: &measured,
                label: 0.1,
                label_alphas: None,
            })
            .collect();
        for m in [model(ModelKind::LinearEmm), constant] {
            for search in [Search::Full, Search::CoarseToFine] {
                let fits = identify_runs(&m, &runs, &grid, 1e-4, 100, search).expect("fits");
                for fit in &fits {
                    assert_eq!(fit.best, None, "{}: {:?}", m.kind().name(), fit.curve_n);
                    assert!(is_flat(&fit.curve_n) && fit.rmse_best_n > 0.0);
                    assert!(!fit.within(1.0));
                }
                assert_eq!(fits[0], fits[2], "runs in parallel give the same fits");
                // A curve flat at the coarse levels is not refined.
                let simulated = if search == Search::Full { 31 } else { 7 };
                assert_eq!(fits[0].levels.len(), simulated, "{search:?}");
            }
        }
        assert!(is_flat(&[2.0, 2.0 * (1.0 - 0.9 * FLAT_TOLERANCE)]));
        assert!(!is_flat(&[2.0, 2.0 * (1.0 - 1.1 * FLAT_TOLERANCE)]));
    }

    #[test]
    fn runs_packed_together_get_the_fits_of_each_run_alone() {
        // Runs of three lengths at several levels, labelled on the grid, off it and per
        // sample: identify_runs packs their simulations across runs (a pack as long as its
        // longest run), identify simulates each alone; the fits are the same to the bit.
        let (v, x) = sine();
        let grid = AlphaGrid::new(0.01, 0.3).expect("grid");
        // A level column that steps within most runs.
        let column: Vec<f32> = (0..v.len())
            .map(|k| if k < 1500 { 0.1 } else { 0.2 })
            .collect();
        for kind in [ModelKind::Nemm, ModelKind::Sem] {
            let m = model(kind);
            let forces: Vec<Vec<f64>> = [0.0f32, 0.07, 0.2, 0.3]
                .iter()
                .map(|&a| force_at(&m, &v, &x, a))
                .collect();
            let mut runs = Vec::new();
            for (j, f) in forces.iter().enumerate() {
                for (len, label, alphas) in [
                    (4000, 0.15, None),
                    (2500, 0.123, None),
                    (1700, 0.12, Some(&column)),
                ] {
                    let len = len - 100 * j;
                    runs.push(Run {
                        velocity_m_s: &v[..len],
                        position_m: Some(&x[..len]),
                        force_n: &f[..len],
                        label,
                        label_alphas: alphas.map(|a| &a[..len]),
                    });
                }
            }
            for search in [Search::CoarseToFine, Search::Full] {
                let together = identify_runs(&m, &runs, &grid, 1e-4, 100, search).expect("fits");
                for (run, fit) in runs.iter().zip(&together) {
                    let alone = identify(&m, run, &grid, 1e-4, 100, search).expect("fit");
                    let what = format!("{} {search:?}, {} samples", kind.name(), fit.samples);
                    assert_eq!(fit.best, alone.best, "{what}");
                    assert_eq!(fit.levels, alone.levels, "{what}");
                    let bits = |f: &Fit| {
                        let mut b: Vec<u64> = f.curve_n.iter().map(|e| e.to_bits()).collect();
                        b.extend([f.rmse_best_n.to_bits(), f.rmse_label_n.to_bits()]);
                        b
                    };
                    assert_eq!(bits(fit), bits(&alone), "{what}");
                    assert!(fit.rmse_label_n.is_finite(), "{what}");
                }
            }
        }
    }

    /// [`coarse_to_fine`] over `curve`: the evaluated indices and the rounds taken.
    fn search(curve: &[f64], extra: &[usize]) -> (BTreeMap<usize, f64>, usize) {
        let mut rounds = 0;
        let seen = coarse_to_fine(curve.len(), extra, |ks| {
            rounds += 1;
            Ok(ks.iter().map(|&k| curve[k]).collect())
        })
        .expect("search");
        for (&k, &v) in &seen {
            assert_eq!(v.to_bits(), curve[k].to_bits(), "index {k}");
        }
        (seen, rounds)
    }

    /// The index of the least value of `values` (the first on a tie).
    fn least_index<'a>(values: impl IntoIterator<Item = (usize, &'a f64)>) -> usize {
        values
            .into_iter()
            .fold(
                (0, f64::INFINITY),
                |(bk, be), (k, &e)| {
                    if e < be {
                        (k, e)
                    } else {
                        (bk, be)
                    }
                },
            )
            .0
    }

    #[test]
    fn the_search_finds_the_least_level_of_one_valley_anywhere_in_two_packs() {
        for n in [2usize, 5, 8, 9, 16, 31, 61, 101] {
            for truth in 0..n {
                // A V with a slight tilt, and a parabola.
                let v: Vec<f64> = (0..n)
                    .map(|i| 10.0 + (i as f64 - truth as f64).abs() + 0.01 * i as f64)
                    .collect();
                let p: Vec<f64> = (0..n)
                    .map(|i| 1.0 + ((i as f64 - truth as f64) / n as f64).powi(2))
                    .collect();
                for curve in [&v, &p] {
                    let (seen, rounds) = search(curve, &[]);
                    let found = least_index(seen.iter().map(|(&k, v)| (k, v)));
                    assert_eq!(found, truth, "n {n}: {seen:?}");
                    assert!(seen.contains_key(&0) && seen.contains_key(&(n - 1)));
                    if n <= 31 {
                        // A coarse pack and one refining pack.
                        assert!(seen.len() < 2 * LANES, "n {n}, {truth}: {seen:?}");
                        assert!(rounds <= 2, "n {n}, {truth}: {rounds} rounds");
                    } else {
                        assert!(seen.len() <= n / 2, "n {n}, {truth}: {} levels", seen.len());
                    }
                }
            }
        }
    }

    #[test]
    fn the_search_finds_the_grid_ends() {
        // Boundaries: the least level at 0 and at the grid's top (alpha_max).
        for n in [31usize, 101] {
            let rising: Vec<f64> = (0..n).map(|i| 5.0 + i as f64).collect();
            let falling: Vec<f64> = rising.iter().rev().copied().collect();
            let (seen, _) = search(&rising, &[]);
            assert_eq!(least_index(seen.iter().map(|(&k, v)| (k, v))), 0);
            assert!(
                seen.contains_key(&1),
                "the neighbour of the end is simulated"
            );
            let (seen, _) = search(&falling, &[]);
            assert_eq!(least_index(seen.iter().map(|(&k, v)| (k, v))), n - 1);
            assert!(seen.contains_key(&(n - 2)));
        }
    }

    /// A 31-level curve with a broad valley at 6 (least 1.0) and a narrow one at 22 (least
    /// `least`, rising by `slope` per level).
    fn two_valleys(least: f64, slope: f64) -> Vec<f64> {
        (0..31)
            .map(|i| {
                let x = i as f64;
                (1.0 + 0.1 * (x - 6.0).powi(2)).min(least + slope * (x - 22.0).abs())
            })
            .collect()
    }

    #[test]
    fn the_search_follows_a_second_valley_within_the_margin() {
        // A broad valley around 6 (least 1.0, sampled at 5 as 1.1) and a narrow, deeper one
        // at 22 (least 0.5) that the coarse levels 20 and 25 see only as 1.3 and 1.7: the
        // narrow one lies within the margin of the curve's range and is refined.
        let curve = two_valleys(0.5, 0.4);
        let (seen, _) = search(&curve, &[]);
        let full = least_index(curve.iter().enumerate());
        assert_eq!(full, 22);
        assert_eq!(
            least_index(seen.iter().map(|(&k, v)| (k, v))),
            full,
            "{seen:?}"
        );
        // Both valleys were refined to their neighbours.
        for k in [5, 6, 7, 21, 22, 23] {
            assert!(seen.contains_key(&k), "{k}: {seen:?}");
        }
        // A second valley far above the first (least 4.0, sampled at 20 as 5.0, beyond the
        // margin) is not refined.
        let curve = two_valleys(4.0, 0.5);
        let (seen, _) = search(&curve, &[]);
        assert_eq!(least_index(seen.iter().map(|(&k, v)| (k, v))), 6);
        assert!(
            !seen.contains_key(&22) && !seen.contains_key(&21),
            "{seen:?}"
        );
    }

    #[test]
    fn the_search_stops_on_a_flat_or_unfinite_curve_and_takes_the_wanted_levels() {
        let flat: Vec<f64> = (0..101)
            .map(|i| 2.0 * (1.0 - 0.4 * FLAT_TOLERANCE * (i % 3) as f64))
            .collect();
        let (seen, rounds) = search(&flat, &[]);
        assert_eq!((seen.len(), rounds), (LANES - 1, 1));
        assert!(is_flat(&seen.values().copied().collect::<Vec<_>>()));
        let mut broken: Vec<f64> = (0..31).map(|i| 1.0 + (i as f64 - 12.0).abs()).collect();
        broken[30] = f64::NAN;
        let (seen, rounds) = search(&broken, &[]);
        assert_eq!((seen.len(), rounds), (LANES - 1, 1));
        // The wanted levels join the first round.
        let v: Vec<f64> = (0..31).map(|i| 1.0 + (i as f64 - 12.0).abs()).collect();
        let (seen, _) = search(&v, &[3, 17]);
        assert!(seen.contains_key(&3) && seen.contains_key(&17));
        assert_eq!(least_index(seen.iter().map(|(&k, v)| (k, v))), 12);
        assert_eq!(coarse_indices(31, 7), [0, 5, 10, 15, 20, 25, 30]);
        assert_eq!(coarse_indices(5, 7), [0, 1, 2, 3, 4]);
        assert_eq!(spread(&[1, 2, 3, 4], 8), [1, 2, 3, 4]);
        assert_eq!(spread(&(0..16).collect::<Vec<_>>(), 4), [2, 6, 10, 14]);
    }

    #[test]
    fn the_coarse_to_fine_search_agrees_with_the_full_grid_on_the_fixture_models() {
        // Runs of several amplitudes and frequencies, simulated at levels on and off the
        // grid and labelled on it, off it and per sample.
        let grid = AlphaGrid::new(0.01, 0.3).expect("grid");
        let excitations: Vec<(Vec<f32>, Vec<f32>)> =
            [(0.01f64, 5.0f64), (0.02, 2.0), (0.004, 12.0)]
                .iter()
                .map(|&(a, hz)| {
                    let (w, dt) = (2.0 * std::f64::consts::PI * hz, 1e-4);
                    (0..3000)
                        .map(|k| {
                            let t = k as f64 * dt;
                            ((a * w * (w * t).cos()) as f32, (a * (w * t).sin()) as f32)
                        })
                        .unzip()
                })
                .collect();
        let column = vec![0.12f32; 3000];
        for kind in [ModelKind::Nemm, ModelKind::NemmLight, ModelKind::Sem] {
            let m = model(kind);
            let (mut full_levels, mut fast_levels) = (0, 0);
            for (v, x) in &excitations {
                for truth in [0.0f32, 0.043, 0.12, 0.3] {
                    let f = force_at(&m, v, x, truth);
                    for (label, alphas) in [(0.15, None), (0.123, None), (0.12, Some(&column))] {
                        let run = Run {
                            velocity_m_s: v,
                            position_m: Some(x),
                            force_n: &f,
                            label,
                            label_alphas: alphas.map(|a| a.as_slice()),
                        };
                        let full =
                            identify(&m, &run, &grid, 1e-4, 100, Search::Full).expect("full");
                        let fast = identify(&m, &run, &grid, 1e-4, 100, Search::CoarseToFine)
                            .expect("fast");
                        let what = format!("{} at {truth}, label {label}", kind.name());
                        // The table search finds a level near the truth on the models that
                        // have one; without tables, or when no table can be built, the
                        // exact coarse round is the first: the same fit.
                        let sampled = run.force_n.len().saturating_sub(100);
                        let score = |y: &[f64]| {
                            let se: f64 = y[100..]
                                .iter()
                                .zip(&run.force_n[100..])
                                .map(|(&y, &f)| (y - f) * (y - f))
                                .sum();
                            super::super::eval::rmse_of(se, sampled)
                        };
                        let unbuildable = TableEstimators::new(
                            &grid,
                            TableConfig {
                                max_rel_error: -1.0,
                                ..TableConfig::default()
                            },
                        );
                        let tables = TableEstimators::new(&grid, TableConfig::default());
                        if has_table_search(&m) {
                            assert_eq!(
                                table_search(&m, &run, &grid, 1e-4, &unbuildable, &score),
                                None,
                                "{what}"
                            );
                            let k = table_search(&m, &run, &grid, 1e-4, &tables, &score)
                                .expect("a table fit");
                            assert!(
                                (grid.alphas[k] - f64::from(truth)).abs() <= 0.015,
                                "{what}: tables at {}",
                                grid.alphas[k]
                            );
                        }
                        for tables in [None, Some(&unbuildable)] {
                            let exact = identify_with_tables(
                                &m,
                                &run,
                                &grid,
                                1e-4,
                                100,
                                Search::CoarseToFine,
                                tables,
                            )
                            .expect("exact coarse round");
                            assert_eq!(exact.best, full.best, "{what}, {:?}", tables.is_some());
                            assert_eq!(exact.rmse_label_n, full.rmse_label_n, "{what}");
                            assert!(exact.levels.contains(&0.0) && exact.levels.contains(&0.3));
                        }
                        assert!(fast.best.is_some(), "{what}");
                        assert_eq!(fast.best, full.best, "{what}: {:?}", full.curve_n);
                        assert!((fast.best.unwrap() - f64::from(truth)).abs() <= 0.005);
                        assert_eq!(fast.rmse_best_n, full.rmse_best_n, "{what}");
                        assert_eq!(fast.rmse_label_n, full.rmse_label_n, "{what}");
                        assert_eq!(fast.samples, full.samples);
                        assert_eq!(full.levels, grid.alphas);
                        // The fast curve is the full one at the levels it simulated.
                        for (a, e) in fast.levels.iter().zip(&fast.curve_n) {
                            let k = grid.alphas.iter().position(|g| g == a).expect("on grid");
                            assert_eq!(*e, full.curve_n[k], "{what} at {a}");
                        }
                        full_levels += full.levels.len();
                        fast_levels += fast.levels.len();
                    }
                }
            }
            assert!(
                2 * fast_levels <= full_levels,
                "{}: {fast_levels} levels simulated against {full_levels}",
                kind.name()
            );
        }
    }
}
