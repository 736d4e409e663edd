//! Online estimate of the oil-loss level `alpha` from the measured stroke velocity and force:
//! one call per sample, fixed capacity, no allocation, no panic.
//!
//! ```text
//! let mut obs: AlphaObserver = AlphaObserver::new(&model, ObserverConfig::new())?;
//! loop {
//!     let a = obs.step(Sample::new(velocity_m_s).with_force(force_n));
//!     publish(a.alpha, a.band, a.flags);
//! }
//! ```
//!
//! # Method: a bank of levels, least squares over whole stroke cycles
//!
//! The observer runs the model at `n` levels `a_0 < a_1 < ... < a_n-1` of a uniform grid
//! (default 7 over the trained range `[meta.alpha_min, meta.alpha_max]`), each with its own
//! state, all through one shared exact-mode [`Estimator`] (the weights are held once; a
//! level costs its state and the folding of its level into the first layers). Each sample
//! gives the forces `F_k` of the levels. Between two neighbouring levels the force at a
//! level `a = a_s + t (a_s+1 - a_s)`, `t in [0, 1]`, is taken as the linear interpolation
//! `F_s + t d_s`, `d_s = F_s+1 - F_s`, and the observer minimises the weighted squared
//! residual of that interpolated force over a window of samples,
//!
//! ```text
//! J_s(t) = sum_i w_i (y_i - F_s,i - t d_s,i)^2 = S_rr,s - 2 t S_rd,s + t^2 S_dd,s
//! ```
//!
//! (`y` the measured force, forces normalised by [`crate::Meta::force_scale_n`]), which
//! needs three sums per grid interval: the minimiser on interval `s` is `t = S_rd / S_dd`
//! clamped to `[0, 1]`, and `alpha_hat` is the minimiser of the interval with the least
//! cost. So the estimate is not limited to the grid: with 7 levels it is within a few
//! thousandths of the estimate of a 31-level bank.
//!
//! **Window of whole stroke cycles.** A model's error repeats with the stroke, so a fit over
//! part of a stroke leans towards whichever level fits that part best, and an estimate
//! updated every sample swings once per stroke period. The window therefore holds whole
//! stroke cycles only. A cycle ends where the velocity rises through
//! [`ObserverConfig::crossing_hysteresis`] times its recent peak after it was below minus
//! that (random excitation has such crossings too; a cycle longer than the window is cut
//! at the window's length). Cycles are gathered into blocks of at least
//! `horizon_s / `[`WINDOW_BLOCKS`]; at each block's close the window (the newest blocks
//! whose lengths add up to at most [`ObserverConfig::horizon_s`], at least the newest one)
//! is solved, and the estimate holds until the next close.
//!
//! **Change of level.** At a close, each of the two newest blocks is fitted on its own, and
//! the older blocks of the window together. When the two newest agree within
//! [`ObserverConfig::change_tolerance`] and both lie beyond it (and beyond their own bands)
//! from the older fit, on the same side, and the older fit is excited, the level has changed: the older blocks are dropped and the window restarts
//! from the two newest. A level step is then followed within about two blocks and a cycle,
//! not a window.
//!
//! **Settled.** An estimate is flagged [`ObserverFlags::NOT_SETTLED`] until two windows
//! were solved, and whenever its last update moved it by more than
//! [`ObserverConfig::settle_tolerance`] or the newest block's own fit lies farther than that
//! (or than its own band, if wider) from it: the ramp-in of a test, a change of level and
//! its restart are not settled. [`ObserverFlags::valid`] asks for excited, settled and in
//! range.
//!
//! **Band.** Around the minimum `J = J_min + C (alpha - alpha_hat)^2` with `C = S_dd / h^2`
//! (`h` the grid spacing). With the residual variance `sigma^2 = J_min / W` (`W` the
//! weight of the window's samples; at least the force noise floor squared) and residuals
//! correlated over [`ObserverConfig::residual_correlation_s`] (model error is not white
//! noise: it repeats with the stroke), the band is
//! `band_sigmas * sqrt(sigma^2 (t_c / dt) / C)`, capped at the grid's span (for the window,
//! and for each block's own fit).
//!
//! **Excitation.** The estimate is flagged [`ObserverFlags::NOT_EXCITED`] while the band is
//! wider than [`ObserverConfig::max_band`]: the forces of the levels differ too little, over
//! the window, against the fit residual (no motion, a constant velocity, strokes too small
//! or too slow for the model to tell the levels apart).
//!
//! **Range.** [`ObserverFlags::OUT_OF_RANGE`] is raised when the unclamped minimiser of the
//! best interval (the interpolated force extended linearly beyond the grid) lies more than
//! the band (uncapped) outside the trained range, or the estimate itself lies outside it (a grid that
//! reaches beyond the trained range).
//!
//! **Robustness.** A non-finite velocity, or one beyond the estimator's plausibility limit,
//! is held by every level (as [`Estimator::step`] does) and flagged
//! [`ObserverFlags::VELOCITY_FAULT`]; the costs are then not updated for that sample and the
//! following [`ObserverConfig::fault_holdoff_s`] (the cycle clock goes on). A missing force (a [`Sample`] without
//! [`Sample::force_n`]), a non-finite one, or one beyond [`ObserverConfig::force_limit_n`],
//! is flagged [`ObserverFlags::FORCE_FAULT`] and skipped (the levels still step).
//! A residual (measured minus the force at the current estimate) beyond
//! [`ObserverConfig::outlier_threshold`] times the running mean absolute residual is flagged
//! [`ObserverFlags::OUTLIER`] and weighted down so that it counts as a residual at the
//! threshold. A sample that updates nothing is flagged [`ObserverFlags::HELD`].
//!
//! # Cost
//!
//! Per step: `n` model steps of the shared estimator in exact mode (`n` evaluations of the
//! model's step, each with its scalers), `n` re-foldings of the level into the state
//! scalers (about `2 H + K_branch` operations each) and `O(n)` scalar work for the sums. At
//! a block's close (once per `horizon_s / WINDOW_BLOCKS` or more) the step also sums the
//! window's blocks and solves four fits, `O(WINDOW_BLOCKS n)` scalar work.
//! [`AlphaObserver::evaluations_per_step`] returns `n`.
//!
//! **On level tables.** [`AlphaObserver::load_on_levels`] takes the levels of a
//! [`LevelTables`] (stored in the blob, [`crate::estimator`], "Every level at table cost") as
//! the grid and keeps the tables (by reference, the observer's lifetime `'l`), and
//! [`AlphaObserver::step`] then steps each level on its own tables: `n` table-mode steps,
//! no re-folding, a tenth or less of the exact cost, the same estimate up to the tables'
//! error.

use crate::estimator::{
    BankMember, Estimator, EstimatorConfig, EstimatorError, LevelStep, LevelTables, LevelsError,
};
use crate::limits::DEFAULT_OBSERVER_POINTS;
use crate::model::Model;
use crate::sample::Sample;
use core::fmt;
use nemm_kernels::math;
use nemm_kernels::mlp::DEFAULT_PARAM_CAPACITY;

/// Default window length \[s\] ([`ObserverConfig::horizon_s`]).
pub const DEFAULT_HORIZON_S: f32 = 3.0;
/// Default residual correlation time \[s\] ([`ObserverConfig::residual_correlation_s`]).
pub const DEFAULT_RESIDUAL_CORRELATION_S: f32 = 0.005;
/// Default widest band \[-\] at which the data count as exciting
/// ([`ObserverConfig::max_band`]).
pub const DEFAULT_MAX_BAND: f32 = 0.05;
/// Default hysteresis of the stroke-cycle detector, a fraction of the recent peak velocity
/// ([`ObserverConfig::crossing_hysteresis`]).
pub const DEFAULT_CROSSING_HYSTERESIS: f32 = 0.1;
/// Default settle tolerance \[-\] ([`ObserverConfig::settle_tolerance`]).
pub const DEFAULT_SETTLE_TOLERANCE: f32 = 0.02;
/// Default change tolerance \[-\] ([`ObserverConfig::change_tolerance`]).
pub const DEFAULT_CHANGE_TOLERANCE: f32 = 0.03;
/// Most blocks of stroke cycles in the window: a block closes at the first cycle end at
/// least `horizon_s / WINDOW_BLOCKS` after it opened.
pub const WINDOW_BLOCKS: usize = 8;
/// Closed blocks held: the window's and one more.
const RING: usize = WINDOW_BLOCKS + 1;

/// Settings of an [`AlphaObserver`]. Units: seconds, newtons, `alpha` (oil-loss fraction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObserverConfig {
    /// Lowest and highest level of the grid \[-\], in `[0, 1]`, lowest first. `None`: the
    /// model's trained range `[meta.alpha_min, meta.alpha_max]` (`[0, 1]` for a model
    /// trained at one level).
    pub grid: Option<(f32, f32)>,
    /// Number of levels of the grid, `2..=K`; `None`: the capacity `K`.
    pub points: Option<usize>,
    /// Window length \[s\]: the estimate is the fit over the newest whole stroke cycles
    /// (in blocks of at least `horizon_s / WINDOW_BLOCKS`) that lie within it, updated at
    /// each block's close. A cycle longer than the window is cut at its length. Default
    /// [`DEFAULT_HORIZON_S`].
    pub horizon_s: f32,
    /// Outlier threshold, a multiple of the running mean absolute residual (> 1).
    /// Default 4.
    pub outlier_threshold: f32,
    /// Time constant \[s\] of the running mean absolute residual. Default 0.05 s.
    pub scale_horizon_s: f32,
    /// Force noise floor \[N\]: the residual variance of the band is at least its square,
    /// so that a perfect fit of no information is not read as certainty. `None`: 1e-3 of
    /// the model's force scale.
    pub force_noise_n: Option<f32>,
    /// Largest plausible |force| \[N\]; beyond it the sample is a sensor fault. `None`:
    /// 3 times the model's force scale.
    pub force_limit_n: Option<f32>,
    /// Largest plausible |velocity| \[m/s\], the estimator's input limit
    /// ([`EstimatorConfig::velocity_limit_m_s`]); `None`: the estimator's default.
    pub velocity_limit_m_s: Option<f32>,
    /// Time \[s\] after a velocity fault during which the costs are not updated (the levels'
    /// states, driven by the held velocity, recover). Default 0.005 s.
    pub fault_holdoff_s: f32,
    /// Time \[s\] from start (and [`AlphaObserver::reset`]) during which the costs are not
    /// updated (the levels' states start at rest). Default 0.01 s.
    pub warmup_s: f32,
    /// Correlation time \[s\] of the fit residual assumed by the band (the residual of a
    /// model is mostly model error, which repeats with the stroke). Default
    /// [`DEFAULT_RESIDUAL_CORRELATION_S`].
    pub residual_correlation_s: f32,
    /// Half-width of the band in standard deviations. Default 2.
    pub band_sigmas: f32,
    /// Widest band \[-\] (half-width, in `alpha`) at which the data count as exciting;
    /// wider is flagged [`ObserverFlags::NOT_EXCITED`]. Default [`DEFAULT_MAX_BAND`].
    pub max_band: f32,
    /// Hysteresis of the stroke-cycle detector, in `(0, 1)`: a cycle ends where the
    /// velocity rises above this fraction of its recent peak after it was below minus
    /// that fraction (the peak decays with a time constant of three windows). Default
    /// [`DEFAULT_CROSSING_HYSTERESIS`].
    pub crossing_hysteresis: f32,
    /// Settle tolerance \[-\]: the estimate is flagged [`ObserverFlags::NOT_SETTLED`] unless
    /// it moved by at most this at its last update and the newest block's own fit lies
    /// within this (or that fit's band, if wider) of it. Default
    /// [`DEFAULT_SETTLE_TOLERANCE`].
    pub settle_tolerance: f32,
    /// Change tolerance \[-\]: when the fits of the two newest blocks lie within this of
    /// each other and both more than this away from the fit of the older blocks, on the
    /// same side, the level has changed and the older blocks are dropped. Default
    /// [`DEFAULT_CHANGE_TOLERANCE`].
    pub change_tolerance: f32,
}

impl ObserverConfig {
    /// The defaults (grid over the trained range with `K` levels, 3 s window).
    pub const fn new() -> Self {
        Self {
            grid: None,
            points: None,
            horizon_s: DEFAULT_HORIZON_S,
            outlier_threshold: 4.0,
            scale_horizon_s: 0.05,
            force_noise_n: None,
            force_limit_n: None,
            velocity_limit_m_s: None,
            fault_holdoff_s: 0.005,
            warmup_s: 0.01,
            residual_correlation_s: DEFAULT_RESIDUAL_CORRELATION_S,
            band_sigmas: 2.0,
            max_band: DEFAULT_MAX_BAND,
            crossing_hysteresis: DEFAULT_CROSSING_HYSTERESIS,
            settle_tolerance: DEFAULT_SETTLE_TOLERANCE,
            change_tolerance: DEFAULT_CHANGE_TOLERANCE,
        }
    }
}

impl Default for ObserverConfig {
    fn default() -> Self {
        Self::new()
    }
}

/// Status bits of one observer step ([`AlphaEstimate::flags`]); none set: an excited,
/// in-range estimate updated by a good sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ObserverFlags(pub u8);

impl ObserverFlags {
    /// The band is wider than [`ObserverConfig::max_band`]: the data so far do not tell
    /// the levels apart (too little motion over the window).
    pub const NOT_EXCITED: u8 = 1 << 0;
    /// The best fit lies outside the model's trained range by more than the band.
    pub const OUT_OF_RANGE: u8 = 1 << 1;
    /// The velocity was non-finite or beyond its plausibility limit (held by the levels),
    /// or a fault lies less than [`ObserverConfig::fault_holdoff_s`] back.
    pub const VELOCITY_FAULT: u8 = 1 << 2;
    /// The measured force was non-finite or beyond [`ObserverConfig::force_limit_n`].
    pub const FORCE_FAULT: u8 = 1 << 3;
    /// The residual was beyond [`ObserverConfig::outlier_threshold`] times the running mean
    /// absolute residual and was weighted down.
    pub const OUTLIER: u8 = 1 << 4;
    /// This sample did not update the costs (a fault, its hold-off, or the warm-up): the
    /// estimate is the previous one.
    pub const HELD: u8 = 1 << 5;
    /// The estimate is not settled ([`ObserverConfig::settle_tolerance`]): no window solved
    /// yet, it moved at its last update, the newest block disagrees with it, or the level
    /// changed and the window restarted.
    pub const NOT_SETTLED: u8 = 1 << 6;
    /// The observer holds no model ([`AlphaObserver::empty`] or a failed load).
    pub const NO_MODEL: u8 = 1 << 7;

    /// True if every bit of `bits` is set.
    pub const fn contains(self, bits: u8) -> bool {
        self.0 & bits == bits
    }
    /// True if no bit is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// True unless [`ObserverFlags::NOT_EXCITED`] is set.
    pub const fn excited(self) -> bool {
        self.0 & Self::NOT_EXCITED == 0
    }
    /// True unless [`ObserverFlags::NOT_SETTLED`] is set.
    pub const fn settled(self) -> bool {
        self.0 & Self::NOT_SETTLED == 0
    }
    /// An estimate to act on: excited, settled, in range, from a loaded model.
    pub const fn valid(self) -> bool {
        self.0 & (Self::NOT_EXCITED | Self::NOT_SETTLED | Self::OUT_OF_RANGE | Self::NO_MODEL) == 0
    }
}

/// Result of one observer step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlphaEstimate {
    /// Estimated oil-loss level \[-\], within the grid. Always finite.
    pub alpha: f32,
    /// Half-width of the uncertainty band \[-\] (`alpha +- band`), at most the grid's span.
    pub band: f32,
    /// The model's force at the estimate \[N\] (interpolated between the levels' forces).
    pub force_n: f32,
    /// What happened in this step.
    pub flags: ObserverFlags,
}

/// Why an [`AlphaObserver`] could not be built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ObserverError {
    /// The shared estimator refused the model or a level (see [`EstimatorError`]).
    Estimator(EstimatorError),
    /// The grid is not two finite levels in `[0, 1]`, lowest first.
    Grid,
    /// The number of levels is not in `2..=capacity`.
    Points {
        /// Levels asked for.
        requested: usize,
        /// The observer's capacity `K`.
        capacity: usize,
    },
    /// A setting is not finite, or not in its range (named by its field).
    Setting(&'static str),
}

impl fmt::Display for ObserverError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ObserverError::Estimator(e) => write!(f, "{e}"),
            ObserverError::Grid => write!(
                f,
                "the observer grid must be two finite levels in [0, 1], lowest first"
            ),
            ObserverError::Points {
                requested,
                capacity,
            } => write!(
                f,
                "the observer grid needs 2 to {capacity} levels (asked for {requested})"
            ),
            ObserverError::Setting(name) => {
                write!(
                    f,
                    "observer setting {name} is not finite or out of its range"
                )
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for ObserverError {}

impl From<EstimatorError> for ObserverError {
    fn from(e: EstimatorError) -> Self {
        ObserverError::Estimator(e)
    }
}

/// The settings of [`ObserverConfig`] resolved for a model, in the units the step uses
/// (samples, forces normalised by the force scale).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Resolved {
    /// Window length \[samples\].
    window: u32,
    /// Shortest block \[samples\].
    block_min: u32,
    /// Per-sample decay of the cycle detector's peak velocity.
    peak_decay: f32,
    hysteresis: f32,
    settle_tolerance: f32,
    change_tolerance: f32,
    scale_rate: f32,
    threshold: f32,
    noise2: f32,
    force_limit_n: f32,
    inv_force_scale: f32,
    force_scale_n: f32,
    holdoff: u32,
    warmup: u32,
    correlation_samples: f32,
    band_sigmas: f32,
    max_band: f32,
    lo: f32,
    /// Spacing of a uniform grid; 0 for the levels of a [`LevelTables`] that are not.
    spacing: f32,
    span: f32,
    trained: (f32, f32),
}

impl Resolved {
    const EMPTY: Self = Self {
        window: 1,
        block_min: 1,
        peak_decay: 0.0,
        hysteresis: 0.0,
        settle_tolerance: 0.0,
        change_tolerance: 0.0,
        scale_rate: 0.0,
        threshold: 0.0,
        noise2: 0.0,
        force_limit_n: 0.0,
        inv_force_scale: 0.0,
        force_scale_n: 0.0,
        holdoff: 0,
        warmup: 0,
        correlation_samples: 1.0,
        band_sigmas: 0.0,
        max_band: 0.0,
        lo: 0.0,
        spacing: 0.0,
        span: 0.0,
        trained: (0.0, 0.0),
    };
}

/// The grid's number of levels and its ends: the levels of `levels` if given (then
/// `cfg.grid` must be `None` and `cfg.points` `None` or their number), else `cfg`'s or the
/// model's trained range with `cfg.points` (default `capacity`) levels.
fn grid_of<const P: usize>(
    model: &Model<P>,
    cfg: &ObserverConfig,
    levels: Option<&[f32]>,
    capacity: usize,
) -> Result<(usize, f32, f32), ObserverError> {
    if let Some(a) = levels {
        if cfg.grid.is_some() {
            return Err(ObserverError::Grid);
        }
        let points = a.len();
        if cfg.points.is_some_and(|p| p != points) || !(2..=capacity).contains(&points) {
            return Err(ObserverError::Points {
                requested: points,
                capacity,
            });
        }
        let (&lo, &hi) = (
            a.first().ok_or(ObserverError::Grid)?,
            a.last().ok_or(ObserverError::Grid)?,
        );
        return Ok((points, lo, hi));
    }
    let points = cfg.points.unwrap_or(capacity);
    if !(2..=capacity).contains(&points) {
        return Err(ObserverError::Points {
            requested: points,
            capacity,
        });
    }
    let meta = model.meta;
    let (lo, hi) = cfg.grid.unwrap_or(if meta.alpha_max > meta.alpha_min {
        (meta.alpha_min, meta.alpha_max)
    } else {
        (0.0, 1.0)
    });
    let in_unit = |a: f32| a.is_finite() && (0.0..=1.0).contains(&a);
    if !(in_unit(lo) && in_unit(hi) && lo < hi) {
        return Err(ObserverError::Grid);
    }
    Ok((points, lo, hi))
}

/// True if `levels` are, bit for bit, the uniform grid of `spacing` from the first to the
/// last (as [`AlphaObserver::load`] builds it).
fn uniform_grid(levels: &[f32], spacing: f32) -> bool {
    let (Some(&lo), Some(&hi)) = (levels.first(), levels.last()) else {
        return false;
    };
    levels.iter().enumerate().all(|(k, &a)| {
        let u = if k + 1 == levels.len() {
            hi
        } else {
            math::fma(k as f32, spacing, lo)
        };
        u.to_bits() == a.to_bits()
    })
}

/// Sums of one grid level and of the interval above it (the last level's interval sums
/// stay zero).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sums {
    /// Weighted sum of the squared residual at this level, `S_rr`.
    rr: f32,
    /// Of the residual times the force difference to the next level, `S_rd`.
    rd: f32,
    /// Of the squared force difference to the next level, `S_dd`.
    dd: f32,
}

impl Sums {
    const ZERO: Self = Self {
        rr: 0.0,
        rd: 0.0,
        dd: 0.0,
    };
}

/// The sums of a stretch of samples: a stroke cycle, a block of cycles, or the window.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Block<const K: usize> {
    sums: [Sums; K],
    /// Weight of its samples, `W`.
    weight: f32,
    /// Its length \[samples\] (held samples included).
    samples: u32,
}

impl<const K: usize> Block<K> {
    const EMPTY: Self = Self {
        sums: [Sums::ZERO; K],
        weight: 0.0,
        samples: 0,
    };

    fn add(&mut self, other: &Self) {
        for (a, b) in self.sums.iter_mut().zip(other.sums.iter()) {
            a.rr += b.rr;
            a.rd += b.rd;
            a.dd += b.dd;
        }
        self.weight += other.weight;
        self.samples = self.samples.saturating_add(other.samples);
    }
}

/// The least-squares fit of a [`Block`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct Fit {
    interval: usize,
    t: f32,
    alpha: f32,
    band: f32,
    /// The unclamped minimiser of the best interval, extended beyond the grid \[-\].
    free: f32,
    /// The band before the cap at the grid's span (infinite without curvature).
    raw_band: f32,
}

/// Online estimator of the oil-loss level `alpha` (module docs): a bank of up to `K`
/// levels of one model, stepped through one shared exact-mode estimator, fitted over a
/// window of whole stroke cycles.
///
/// `P` is the parameter capacity per scaler (as for [`Model`]); `K` the most levels
/// (default [`DEFAULT_OBSERVER_POINTS`]); `'l` the lifetime of the level tables it was
/// loaded on ([`AlphaObserver::load_on_levels`]; `'static` for a `static`). The size is one
/// `Estimator<P, 1>` plus about 160 bytes per level (its state and the sums of the open
/// cycle, the open block, the window and [`WINDOW_BLOCKS`]` + 1` closed blocks).
#[derive(Debug, Clone)]
pub struct AlphaObserver<
    'l,
    const P: usize = DEFAULT_PARAM_CAPACITY,
    const K: usize = DEFAULT_OBSERVER_POINTS,
> {
    cfg: Resolved,
    points: usize,
    members: [BankMember; K],
    forces: [f32; K],
    /// The open stroke cycle.
    cycle: Block<K>,
    /// The open block (closed cycles).
    block: Block<K>,
    /// Closed blocks, a ring; `newest` the index of the newest, `count` how many hold data.
    blocks: [Block<K>; RING],
    newest: usize,
    count: usize,
    /// The window of the last solve.
    window: Block<K>,
    /// Windows solved since the last reset.
    solves: u32,
    /// Cycle detector: recent peak |velocity| \[m/s\], and whether the velocity was below
    /// minus the hysteresis since the last cycle end.
    peak: f32,
    armed: bool,
    /// Running mean absolute residual (normalised).
    scale: f32,
    /// Samples until the warm-up ends.
    warmup_left: u32,
    /// Samples until a velocity fault's hold-off ends.
    holdoff_left: u32,
    /// Interval and position of the current estimate.
    interval: usize,
    t: f32,
    /// Flags of the last solve ([`ObserverFlags::NOT_EXCITED`],
    /// [`ObserverFlags::OUT_OF_RANGE`], [`ObserverFlags::NOT_SETTLED`]).
    fit_flags: u8,
    last: AlphaEstimate,
    loaded: bool,
    /// The level tables of [`AlphaObserver::load_on_levels`]: the grid's levels are
    /// theirs, and each steps on its own tables.
    levels: Option<&'l dyn LevelStep<P, 1>>,
    shared: Estimator<'l, P, 1>,
}

impl<'l, const P: usize, const K: usize> AlphaObserver<'l, P, K> {
    /// Builds an observer for `model` (returned by value; where the stack is small, use
    /// [`AlphaObserver::empty`] and [`AlphaObserver::load`]).
    pub fn new(model: &Model<P>, cfg: ObserverConfig) -> Result<Self, ObserverError> {
        let mut o = Self::empty();
        o.load(model, cfg)?;
        Ok(o)
    }

    /// An observer without a model, e.g. for a `static`: [`step`](Self::step) returns the
    /// flag [`ObserverFlags::NO_MODEL`] until [`load`](Self::load) succeeds.
    pub const fn empty() -> Self {
        Self {
            cfg: Resolved::EMPTY,
            points: 0,
            members: [BankMember::EMPTY; K],
            forces: [0.0; K],
            cycle: Block::EMPTY,
            block: Block::EMPTY,
            blocks: [Block::EMPTY; RING],
            newest: 0,
            count: 0,
            window: Block::EMPTY,
            solves: 0,
            peak: 0.0,
            armed: false,
            scale: 0.0,
            warmup_left: 0,
            holdoff_left: 0,
            interval: 0,
            t: 0.0,
            fit_flags: ObserverFlags::NOT_EXCITED | ObserverFlags::NOT_SETTLED,
            last: AlphaEstimate {
                alpha: 0.0,
                band: 0.0,
                force_n: 0.0,
                flags: ObserverFlags(
                    ObserverFlags::NO_MODEL
                        | ObserverFlags::NOT_EXCITED
                        | ObserverFlags::NOT_SETTLED,
                ),
            },
            loaded: false,
            levels: None,
            shared: Estimator::empty(),
        }
    }

    /// Loads `model` in place (the shared estimator is written where it lives), checks the
    /// configuration and starts from rest with no data. On error the observer is empty.
    pub fn load(&mut self, model: &Model<P>, cfg: ObserverConfig) -> Result<(), ObserverError> {
        self.load_with(model, &cfg, None)
    }

    /// Loads `model` with the levels of `levels` (loaded from the same model's blob) as the
    /// grid and keeps them (by reference), so that [`AlphaObserver::step`] steps each level
    /// on its stored tables (table cost, module docs "Cost") instead of the exact scalers. The grid is
    /// the levels' (at most `K`, ascending, not necessarily uniform): `cfg.grid` must be
    /// `None` and `cfg.points` `None` or the number of levels. On error the observer is
    /// empty.
    pub fn load_on_levels<const T: usize, const L: usize>(
        &mut self,
        model: &Model<P>,
        levels: &'l LevelTables<'_, T, L>,
        cfg: ObserverConfig,
    ) -> Result<(), ObserverError> {
        self.load_with(model, &cfg, Some(levels))
    }

    fn load_with(
        &mut self,
        model: &Model<P>,
        cfg: &ObserverConfig,
        levels: Option<&'l dyn LevelStep<P, 1>>,
    ) -> Result<(), ObserverError> {
        self.loaded = false;
        self.levels = None;
        self.points = 0;
        let r = self.load_inner(model, cfg, levels);
        if r.is_err() {
            self.points = 0;
            self.fit_flags = ObserverFlags::NOT_EXCITED | ObserverFlags::NOT_SETTLED;
            self.last = Self::empty().last;
        }
        r
    }

    fn load_inner(
        &mut self,
        model: &Model<P>,
        cfg: &ObserverConfig,
        levels: Option<&'l dyn LevelStep<P, 1>>,
    ) -> Result<(), ObserverError> {
        let setting = |ok: bool, name: &'static str| {
            if ok {
                Ok(())
            } else {
                Err(ObserverError::Setting(name))
            }
        };
        let positive = |v: f32| v.is_finite() && v > 0.0;
        let non_negative = |v: f32| v.is_finite() && v >= 0.0;
        setting(positive(cfg.horizon_s), "horizon_s")?;
        setting(
            cfg.outlier_threshold.is_finite() && cfg.outlier_threshold > 1.0,
            "outlier_threshold",
        )?;
        setting(positive(cfg.scale_horizon_s), "scale_horizon_s")?;
        setting(non_negative(cfg.fault_holdoff_s), "fault_holdoff_s")?;
        setting(non_negative(cfg.warmup_s), "warmup_s")?;
        setting(
            non_negative(cfg.residual_correlation_s),
            "residual_correlation_s",
        )?;
        setting(positive(cfg.band_sigmas), "band_sigmas")?;
        setting(positive(cfg.max_band), "max_band")?;
        setting(
            positive(cfg.crossing_hysteresis) && cfg.crossing_hysteresis < 1.0,
            "crossing_hysteresis",
        )?;
        setting(positive(cfg.settle_tolerance), "settle_tolerance")?;
        setting(positive(cfg.change_tolerance), "change_tolerance")?;
        let (points, lo, hi) = grid_of(model, cfg, levels.map(|l| l.alphas()), K)?;
        let meta = model.meta;
        let force_scale = meta.force_scale_n;
        let noise = cfg.force_noise_n.unwrap_or(1e-3 * force_scale);
        setting(positive(noise), "force_noise_n")?;
        let force_limit = cfg.force_limit_n.unwrap_or(3.0 * force_scale);
        setting(positive(force_limit), "force_limit_n")?;
        let est_cfg = EstimatorConfig {
            velocity_limit_m_s: cfg.velocity_limit_m_s,
            ..EstimatorConfig::new(lo)
        };
        self.shared.load(model, est_cfg)?;
        let dt = model.dt_s;
        let spacing = (hi - lo) / (points - 1) as f32;
        for (k, m) in self.members.iter_mut().enumerate().take(points) {
            let a = match levels.and_then(|l| l.alphas().get(k)) {
                Some(&a) => a,
                None if k + 1 == points => hi,
                None => math::fma(k as f32, spacing, lo),
            };
            *m = self.shared.bank_member(a)?;
        }
        if let Some(l) = levels {
            if !l.accepted_by(&self.shared) {
                return Err(ObserverError::Estimator(EstimatorError::Levels(
                    LevelsError::Mismatch,
                )));
            }
        }
        let uniform = levels.is_none_or(|l| uniform_grid(l.alphas(), spacing));
        let samples = |s: f32| {
            let n = s / dt;
            if n >= u32::MAX as f32 {
                u32::MAX
            } else {
                n as u32
            }
        };
        let window = samples(cfg.horizon_s).max(1);
        self.cfg = Resolved {
            window,
            block_min: (window / WINDOW_BLOCKS as u32).max(1),
            peak_decay: math::exp(-dt / (3.0 * cfg.horizon_s)),
            hysteresis: cfg.crossing_hysteresis,
            settle_tolerance: cfg.settle_tolerance,
            change_tolerance: cfg.change_tolerance,
            scale_rate: (dt / cfg.scale_horizon_s).min(1.0),
            threshold: cfg.outlier_threshold,
            noise2: (noise / force_scale) * (noise / force_scale),
            force_limit_n: force_limit,
            inv_force_scale: 1.0 / force_scale,
            force_scale_n: force_scale,
            holdoff: samples(cfg.fault_holdoff_s),
            warmup: samples(cfg.warmup_s),
            correlation_samples: (cfg.residual_correlation_s / dt).max(1.0),
            band_sigmas: cfg.band_sigmas,
            max_band: cfg.max_band,
            lo,
            spacing: if uniform { spacing } else { 0.0 },
            span: hi - lo,
            trained: (meta.alpha_min, meta.alpha_max),
        };
        self.points = points;
        self.loaded = true;
        self.levels = levels;
        self.reset();
        Ok(())
    }

    /// Returns to rest with no data: every level's state at rest, the cycles, blocks and
    /// window cleared, the warm-up restarted. The estimate is the middle of the grid, not
    /// excited, not settled.
    pub fn reset(&mut self) {
        let n = self.points;
        for m in self.members.iter_mut().take(n) {
            if let Ok(fresh) = self.shared.bank_member(m.alpha) {
                *m = fresh;
            }
        }
        self.forces = [0.0; K];
        self.cycle = Block::EMPTY;
        self.block = Block::EMPTY;
        self.blocks = [Block::EMPTY; RING];
        self.newest = 0;
        self.count = 0;
        self.window = Block::EMPTY;
        self.solves = 0;
        self.peak = 0.0;
        self.armed = false;
        self.scale = 1.0;
        self.warmup_left = self.cfg.warmup;
        self.holdoff_left = 0;
        self.interval = n.saturating_sub(1) / 2;
        self.t = if n.is_multiple_of(2) { 0.5 } else { 0.0 };
        self.fit_flags = ObserverFlags::NOT_EXCITED | ObserverFlags::NOT_SETTLED;
        let flags = if self.loaded {
            self.fit_flags
        } else {
            self.fit_flags | ObserverFlags::NO_MODEL
        };
        self.last = AlphaEstimate {
            alpha: self.alpha_at(self.interval, self.t),
            band: self.cfg.span,
            force_n: 0.0,
            flags: ObserverFlags(flags),
        };
    }

    fn alpha_at(&self, interval: usize, t: f32) -> f32 {
        let c = &self.cfg;
        if c.spacing > 0.0 {
            return math::fma(interval as f32 + t, c.spacing, c.lo);
        }
        math::fma(t, self.width(interval), self.level(interval))
    }

    /// Level `k` of the grid \[-\].
    fn level(&self, k: usize) -> f32 {
        self.members.get(k).map_or(self.cfg.lo, |m| m.alpha)
    }

    /// Width of grid interval `s` \[-\].
    fn width(&self, s: usize) -> f32 {
        if self.cfg.spacing > 0.0 {
            return self.cfg.spacing;
        }
        self.level(s + 1) - self.level(s)
    }

    /// One sample in ([`Sample`]: the stroke velocity \[m/s\], positive = extension, the
    /// measured force \[N\], positive in tension, of the same instant, and the stroke
    /// position \[m\] for a model with a static force; a sample's `alpha` is not read), the
    /// estimate after it out. The one step of the observer: on an observer loaded by
    /// [`AlphaObserver::load_on_levels`] each level steps on its stored tables, otherwise on
    /// the exact scalers. A sample without a force is a missing measurement, handled as a
    /// non-finite one: the levels step, the sums are not updated, and the estimate is
    /// flagged [`ObserverFlags::FORCE_FAULT`] and [`ObserverFlags::HELD`].
    pub fn step(&mut self, sample: Sample) -> AlphaEstimate {
        let y = sample.force_n.unwrap_or(f32::NAN);
        self.step_at(sample.velocity_m_s, sample.position_m, y)
    }

    fn step_at(&mut self, velocity_m_s: f32, position_m: Option<f32>, y: f32) -> AlphaEstimate {
        if !self.loaded {
            return self.last;
        }
        let n = self.points;
        let (Some(members), Some(forces)) = (self.members.get_mut(..n), self.forces.get_mut(..n))
        else {
            return self.last;
        };
        // On level tables: one dynamic call for the whole bank (a level the tables do not
        // hold steps on the exact scalers).
        let velocity_fault = match self.levels {
            Some(l) => l.step_bank(
                &mut self.shared,
                (members, forces),
                velocity_m_s,
                position_m,
            ),
            None => self
                .shared
                .step_bank((members, forces), velocity_m_s, position_m),
        };
        let c = self.cfg;
        let mut flags = 0u8;
        if velocity_fault {
            self.holdoff_left = c.holdoff;
            flags |= ObserverFlags::VELOCITY_FAULT;
        } else if self.holdoff_left > 0 {
            self.holdoff_left -= 1;
            flags |= ObserverFlags::VELOCITY_FAULT;
        }
        if !(y.is_finite() && y.abs() <= c.force_limit_n) {
            flags |= ObserverFlags::FORCE_FAULT;
        }
        // The stroke-cycle clock: a cycle ends at a rising crossing, or at the window's
        // length; this sample opens the next one.
        let crossing = !velocity_fault && self.rising_crossing(velocity_m_s);
        if crossing || self.cycle.samples >= c.window {
            self.close_cycle();
        }
        self.cycle.samples = self.cycle.samples.saturating_add(1);
        let warming = self.warmup_left > 0;
        self.warmup_left = self.warmup_left.saturating_sub(1);
        if flags != 0 || warming {
            return self.publish(flags | ObserverFlags::HELD);
        }
        // Residual at the current estimate, robust weight, running scale.
        let y_n = y * c.inv_force_scale;
        let e = y_n - self.force_at(self.interval, self.t) * c.inv_force_scale;
        let limit = c.threshold * self.scale;
        let mut w = 1.0;
        if e.abs() > limit {
            flags |= ObserverFlags::OUTLIER;
            let q = limit / e.abs();
            w = q * q;
        }
        let floor = math::sqrt(c.noise2);
        self.scale =
            math::fma(c.scale_rate, e.abs().min(limit) - self.scale, self.scale).max(floor);
        // The open cycle's sums.
        self.cycle.weight += w;
        let mut next = self.forces.iter().skip(1);
        for (s, &f) in self.cycle.sums.iter_mut().zip(self.forces.iter()).take(n) {
            let r = y_n - f * c.inv_force_scale;
            let wr = w * r;
            s.rr = math::fma(wr, r, s.rr);
            if let Some(&f1) = next.next() {
                let d = (f1 - f) * c.inv_force_scale;
                s.rd = math::fma(wr, d, s.rd);
                s.dd = math::fma(w * d, d, s.dd);
            }
        }
        self.publish(flags)
    }

    /// The estimate of the last solve with this sample's force and flags.
    fn publish(&mut self, flags: u8) -> AlphaEstimate {
        self.last.force_n = self.force_at(self.interval, self.t);
        self.last.flags = ObserverFlags(self.fit_flags | flags);
        self.last
    }

    /// The cycle detector: true at a rising crossing of the velocity through the
    /// hysteresis after it was below its negative.
    fn rising_crossing(&mut self, v: f32) -> bool {
        if !v.is_finite() {
            return false;
        }
        self.peak = (self.peak * self.cfg.peak_decay).max(v.abs());
        let h = self.cfg.hysteresis * self.peak;
        if v < -h {
            self.armed = true;
            false
        } else if self.armed && v > h {
            self.armed = false;
            true
        } else {
            false
        }
    }

    /// Ends the open cycle: into the open block, which closes (and the window is solved)
    /// once it is at least the shortest block.
    fn close_cycle(&mut self) {
        let cycle = core::mem::replace(&mut self.cycle, Block::EMPTY);
        self.block.add(&cycle);
        if self.block.samples >= self.cfg.block_min {
            let block = core::mem::replace(&mut self.block, Block::EMPTY);
            self.newest = (self.newest + 1) % RING;
            if let Some(slot) = self.blocks.get_mut(self.newest) {
                *slot = block;
            }
            self.count = (self.count + 1).min(RING);
            self.solve_window();
        }
    }

    /// The `i`-th newest closed block (0: the newest).
    fn nth(&self, i: usize) -> Block<K> {
        self.blocks
            .get((self.newest + RING - i % RING) % RING)
            .copied()
            .unwrap_or(Block::EMPTY)
    }

    /// The sum of the closed blocks `from..to` (newest first).
    fn sum_blocks(&self, from: usize, to: usize) -> Block<K> {
        let mut b = Block::EMPTY;
        for i in from..to {
            b.add(&self.nth(i));
        }
        b
    }

    /// Solves the window at a block's close: the newest blocks within the window length
    /// (at least the newest), restarted on a change of level; sets the estimate and the
    /// fit flags.
    fn solve_window(&mut self) {
        let c = self.cfg;
        let mut blocks = 0;
        let mut samples = 0u32;
        while blocks < self.count.min(WINDOW_BLOCKS) {
            let len = self.nth(blocks).samples;
            if blocks > 0 && samples.saturating_add(len) > c.window {
                break;
            }
            samples = samples.saturating_add(len);
            blocks += 1;
        }
        let newest = self.fit(&self.nth(0));
        // A change of level: the two newest blocks agree with each other and both lie on
        // the same side of the older blocks' fit, beyond the tolerance and their own bands;
        // the older fit excited (older blocks that are not, a ramp-in say, are no level to
        // change from).
        let mut restarted = false;
        if blocks >= 3 {
            let second = self.fit(&self.nth(1));
            let older = self.fit(&self.sum_blocks(2, blocks));
            if let (Some(b0), Some(b1), Some(o)) = (newest, second, older) {
                let tol = c.change_tolerance;
                let (d0, d1) = (b0.alpha - o.alpha, b1.alpha - o.alpha);
                if o.band <= c.max_band
                    && (b0.alpha - b1.alpha).abs() <= tol
                    && d0 * d1 > 0.0
                    && d0.abs() > tol.max(b0.band)
                    && d1.abs() > tol.max(b1.band)
                {
                    blocks = 2;
                    self.count = 2;
                    restarted = true;
                }
            }
        }
        self.window = self.sum_blocks(0, blocks);
        let Some(w) = self.fit(&self.window) else {
            self.fit_flags = ObserverFlags::NOT_EXCITED | ObserverFlags::NOT_SETTLED;
            return;
        };
        let moved = (w.alpha - self.last.alpha).abs();
        let agrees =
            newest.is_some_and(|b| (b.alpha - w.alpha).abs() <= c.settle_tolerance.max(b.band));
        let settled = !restarted && self.solves > 0 && moved <= c.settle_tolerance && agrees;
        self.solves = self.solves.saturating_add(1);
        let mut flags = 0;
        if w.band > c.max_band {
            flags |= ObserverFlags::NOT_EXCITED;
        }
        let (t_lo, t_hi) = c.trained;
        let outside = |a: f32, margin: f32| a < t_lo - margin || a > t_hi + margin;
        if outside(w.alpha, 0.0) || outside(w.free, w.raw_band) {
            flags |= ObserverFlags::OUT_OF_RANGE;
        }
        if !settled {
            flags |= ObserverFlags::NOT_SETTLED;
        }
        self.fit_flags = flags;
        self.interval = w.interval;
        self.t = w.t;
        self.last.alpha = w.alpha;
        self.last.band = w.band;
    }

    /// The interpolated force at interval `s`, position `t` \[N\].
    fn force_at(&self, s: usize, t: f32) -> f32 {
        match (self.forces.get(s), self.forces.get(s + 1)) {
            (Some(&f0), Some(&f1)) => math::fma(t, f1 - f0, f0),
            (Some(&f0), None) => f0,
            _ => 0.0,
        }
    }

    /// The least-squares fit of `b` (module docs): the minimiser over the grid's
    /// intervals, its band. `None` for a block without weight.
    fn fit(&self, b: &Block<K>) -> Option<Fit> {
        let c = self.cfg;
        if b.weight <= 0.0 || !b.weight.is_finite() {
            return None;
        }
        // (cost, interval, t, unclamped t, S_dd)
        let mut best: Option<(f32, usize, f32, f32, f32)> = None;
        for (s, sums) in b
            .sums
            .iter()
            .enumerate()
            .take(self.points.saturating_sub(1))
        {
            let t_free = if sums.dd > 0.0 {
                sums.rd / sums.dd
            } else {
                0.0
            };
            let t_free = if t_free.is_finite() { t_free } else { 0.0 };
            let t = t_free.clamp(0.0, 1.0);
            let cost = (sums.rr - t * (2.0 * sums.rd - t * sums.dd)).max(0.0);
            if best.is_none_or(|b| cost < b.0) {
                best = Some((cost, s, t, t_free, sums.dd));
            }
        }
        let (j_min, s, t, t_free, dd) = best?;
        let sigma2 = (j_min / b.weight).max(c.noise2);
        let h = self.width(s);
        let curvature = dd / (h * h);
        let raw_band = c.band_sigmas * math::sqrt(sigma2 * c.correlation_samples / curvature);
        let raw_band = if raw_band.is_nan() {
            f32::INFINITY
        } else {
            raw_band
        };
        Some(Fit {
            interval: s,
            t,
            alpha: self.alpha_at(s, t),
            band: raw_band.min(c.span),
            free: self.alpha_at(s, t_free),
            raw_band,
        })
    }

    /// The last estimate (that of the last [`step`](Self::step), or of
    /// [`reset`](Self::reset)).
    pub fn estimate(&self) -> AlphaEstimate {
        self.last
    }

    /// Number of levels of the grid (0 without a model).
    pub fn points(&self) -> usize {
        self.points
    }

    /// Model evaluations per step: one model step per level.
    pub fn evaluations_per_step(&self) -> usize {
        self.points
    }

    /// The grid's levels \[-\], ascending.
    pub fn grid(&self) -> impl Iterator<Item = f32> + '_ {
        self.members.iter().take(self.points).map(|m| m.alpha)
    }

    /// Windows solved since the last [`reset`](Self::reset) (or load): 0 while the
    /// estimate is still the reset one.
    pub fn solves(&self) -> u32 {
        self.solves
    }

    /// Per level of the grid: the level \[-\] and the weighted RMS of its force residual
    /// over the window of the last solve \[N\] (`sqrt(S_rr / W)`; 0 before any solve).
    pub fn residual_rms(&self) -> impl Iterator<Item = (f32, f32)> + '_ {
        let (w, fs) = (self.window.weight, self.cfg.force_scale_n);
        self.members
            .iter()
            .zip(self.window.sums.iter())
            .take(self.points)
            .map(move |(m, s)| {
                let rms = if w > 0.0 {
                    fs * math::sqrt((s.rr / w).max(0.0))
                } else {
                    0.0
                };
                (m.alpha, rms)
            })
    }

    /// The weight of the samples in the window of the last solve, in samples (at most the
    /// window length, `horizon_s / dt`).
    pub fn weight(&self) -> f32 {
        self.window.weight
    }
}
