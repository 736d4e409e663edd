//! The online force estimator: one call per sample, fixed step, no allocation, no panic.
//!
//! ```text
//! let model: Model<P> = nemm_core::decode(blob)?;
//! let mut est = Estimator::new(&model, EstimatorConfig::new(alpha))?;
//! loop { let e = est.step(Sample::new(velocity_m_s))?; publish(e.force_n, e.flags); }
//! ```
//!
//! # One step
//!
//! [`Estimator::step`] is the one step: it takes a [`Sample`] (the stroke velocity, and
//! optionally the stroke position and this sample's level `alpha`), so that a firmware
//! with a position sensor, a controller with a level per sample and a test with neither
//! call the same function. A sample without an `alpha` steps at the estimator's own level
//! and cannot fail; the `Result` is for a sample's `alpha` the estimator refuses (see
//! [`Estimator::step`]). The level tables of "Every level at table cost" are an option of
//! the estimator ([`Estimator::attach_levels`]), not another family of steps: once
//! attached, a sample's `alpha` is served from them. They are held by reference (the
//! estimator's lifetime `'l`; `'static` for a `static`) behind a trait object, so that
//! their number of levels is not part of the estimator's type; the whole step on them is
//! one dynamic call (not one per Runge-Kutta stage), and a sample without an `alpha` does
//! not pass through it.
//!
//! # What happens per step
//!
//! 1. Input guard: a non-finite velocity, or one beyond the plausibility limit
//!    ([`EstimatorConfig::velocity_limit_m_s`]), is replaced by the last good sample (the
//!    estimator assumes the velocity held) and flagged; good samples resume normally.
//! 2. One RK step from the previous sample to this one (see [`nemm_kernels::integrator`]), or the map
//!    lookup for the SEM.
//! 3. Divergence guard: a non-finite state or force, or a state beyond
//!    [`DIVERGENCE_FACTOR`] times its training scale, resets the state to rest and is
//!    flagged; it never propagates.
//! 4. The force `F(x_n+1, u_n+1)`; the coefficients computed for it are reused as stage 1 of
//!    the next step.
//! 5. A model with a static force ([`nemm_kernels::static_force`]) adds `r(x, u, alpha)` at the
//!    stroke position `x` of the sample ([`Sample::position_m`]). `r` does not enter the
//!    state. Without a position, `r` uses the last good position and the step is flagged
//!    [`Flags::POSITION_MISSING`] (as is a non-finite position), so a firmware that forgets
//!    the position never gets an unflagged wrong force. Models without a static force ignore
//!    the position.
//!
//! Everything that depends on `alpha` only (the alpha column of each first layer, `b_pr`, the
//! SEM curve) is computed in [`Estimator::new`] / [`Estimator::set_alpha`], never per step.
//!
//! # Exact or tabulated
//!
//! [`EstimatorConfig::mode`] selects how the neural coefficients `b_fl(v_st)` and
//! `k_pr(x_pr)` are evaluated:
//!
//! - [`EvalMode::Exact`] (default): the compiled MLPs, the reference arithmetic; a
//!   coefficient with a cumulative scaler ([`crate::Model::cumulative`]) runs it compiled
//!   ([`CompiledScaler::compile_cumulative_into`]: the reference path's bits).
//! - [`EvalMode::Table`]: 1-D cubic tables of [`nemm_kernels::table`] with `T` segments each
//!   (`Estimator<P, T>`, default [`DEFAULT_TABLE_SEGMENTS`] = 256), built for the
//!   configured `alpha` in [`Estimator::new`] and rebuilt by [`Estimator::set_alpha`]. Both
//!   measure every table against the exact scaler on a grid 128x finer than the table and
//!   refuse, with [`EstimatorError::Table`], a table whose relative error exceeds
//!   [`TableConfig::max_rel_error`]. A state outside a table's domain is clamped and sets
//!   [`Flags::OUT_OF_TABLE_DOMAIN`]. The SEM and the Linear EMM have nothing to tabulate and
//!   run the same code in both modes. A blob can store the tables for declared alpha levels
//!   (format version 4, [`crate::format::tables`]): [`Estimator::load_with_tables`] then
//!   reads them from the blob instead of building them, bit for bit the same tables
//!   ([`Estimator::table_origin`] says which happened, and why stored ones were not used).
//!
//! # Every level at table cost
//!
//! A level per sample ([`Sample::alpha`]) and the observer's bank of levels would rebuild
//! tables every sample in table mode. A blob can store the tables of several levels instead
//! (`nemm export --tables-levels 7`); a [`LevelTables`] holds them (in RAM, loaded once from
//! the model, the tables index and the blob) and drives an estimator it is attached to
//! ([`Estimator::attach_levels`]; a level per sample: each coefficient the blend of its two
//! neighbouring levels' tables, ordered in the declared direction so that it is monotone
//! in `alpha` between levels by construction; at a stored level the table-mode step at
//! that level, bit for bit) and [`crate::AlphaObserver::load_on_levels`] (the bank on the
//! stored levels). The blend's error against the exact model is first order in the level
//! spacing and measured by [`LevelTables::check`] (docs/core.md, "Every level at table
//! cost").
//!
//! ```
//! use nemm_core::{Estimator, EstimatorConfig, EvalMode, Sample, TableConfig};
//! # let model: nemm_core::Model = nemm_core::testing::example_model(nemm_core::ModelKind::Nemm, 16, 5).unwrap();
//! let cfg = EstimatorConfig {
//!     mode: EvalMode::Table(TableConfig::new(1e-4)), // each coefficient within 1e-4 relative
//!     ..EstimatorConfig::new(0.15)
//! };
//! let mut est: Estimator = Estimator::new(&model, cfg).expect("tables within the bound");
//! let worst = est.table_accuracy().expect("tabulated").max_rel_error;
//! assert!(worst <= 1e-4);
//! let e = est.step(Sample::new(0.3))?;
//! assert!(e.force_n.is_finite());
//! # Ok::<(), nemm_core::EstimatorError>(())
//! ```

mod config;
mod export;
mod levels;
mod runtime;

pub use config::{
    Diagnostics, Estimate, EstimatorConfig, EstimatorError, EvalMode, Flags, TableOrigin,
    DEFAULT_VELOCITY_LIMIT_FACTOR, DIVERGENCE_FACTOR,
};
use runtime::*;

#[cfg(feature = "std")]
pub use export::encode_to_vec_with_tables;
pub use export::encode_with_tables;
pub use export::encoded_len_with_tables;
pub(crate) use levels::LevelStep;
pub use levels::{BlendCheck, LevelTables, LevelsError};

use crate::format::tables::{StoredTable, StoredTables, StoredUnused, TableLevel};
use crate::model::{Body, Model, ModelError};
use crate::sample::Sample;
use core::fmt;
use nemm_kernels::cumulative::CumulativeScaler;
use nemm_kernels::emm::{self, Coefficients, State};
use nemm_kernels::integrator::{self, Integrator, Stage, StepSize};
use nemm_kernels::lost_motion::{LostMotion, LostMotionAt};
use nemm_kernels::math::{Fused, MulAdd, Unfused};
use nemm_kernels::mlp::{AlphaBranch, CompiledScaler, Scaler, DEFAULT_PARAM_CAPACITY};
use nemm_kernels::sem::{SemMap, MAX_SEM_VELOCITIES};
use nemm_kernels::static_force::StaticForce;
use nemm_kernels::table::StoredLayout;
use nemm_kernels::table::{
    self, Table1D, TableAccuracy, TableConfig, TableError, DEFAULT_TABLE_SEGMENTS,
};

/// Online estimator for one damper at one oil-loss level. Owns everything it needs; the
/// [`Model`] can be dropped after construction.
///
/// `P` is the parameter capacity per scaler (as for [`Model`]), `T` the number of segments
/// of each table in [`EvalMode::Table`] (28 bytes each; unused in exact mode, but part of
/// the size).
#[derive(Debug, Clone)]
#[repr(C)] // the per-step scalars first, the large runtime last (short offsets on Arm)
pub struct Estimator<
    'l,
    const P: usize = DEFAULT_PARAM_CAPACITY,
    const T: usize = DEFAULT_TABLE_SEGMENTS,
> {
    state: State,
    coeffs: Coefficients,
    last_u: f32,
    velocity_limit: f32,
    sticky: Flags,
    diag: Diagnostics,
    alpha: f32,
    alpha_range: (f32, f32),
    /// The static force, if the model has one.
    static_force: Option<StaticForce>,
    /// Last good stroke position \[m\] (`x_ref` after a reset).
    last_x: f32,
    mode: EvalMode,
    origin: TableOrigin,
    /// The level of the last step on the attached level tables (`None` after a load, an
    /// attach or a reset: the next one re-reads the coefficients at the state).
    levels_alpha: Option<f32>,
    rt: Runtime<P, T>,
    /// The attached level tables ([`Estimator::attach_levels`]; last: read on the step of a
    /// sample with an `alpha` only).
    levels: Option<&'l dyn LevelStep<P, T>>,
}

impl<const P: usize> Estimator<'_, P> {
    /// Builds an estimator: validates the model with the configured step and integrator and
    /// precomputes all alpha-only work (in table mode: builds and checks the tables, with
    /// [`DEFAULT_TABLE_SEGMENTS`] segments each; [`Estimator::with_segments`] picks another
    /// number). Returned by value: where the stack is small, use [`Estimator::load`].
    pub fn new(model: &Model<P>, cfg: EstimatorConfig) -> Result<Self, EstimatorError> {
        Self::with_segments(model, cfg)
    }
}

impl<'l, const P: usize, const T: usize> Estimator<'l, P, T> {
    /// [`Estimator::new`] with `T` segments per table in [`EvalMode::Table`]
    /// (`Estimator::<P, T>::with_segments(&model, cfg)`).
    pub fn with_segments(model: &Model<P>, cfg: EstimatorConfig) -> Result<Self, EstimatorError> {
        let mut est = Self::empty();
        est.load(model, cfg)?;
        Ok(est)
    }

    /// An estimator without a model: the storage to [`load`](Self::load) one into, e.g. a
    /// `static` (a `const fn`, so the storage needs no stack). Until a model is loaded,
    /// [`step`](Self::step) returns 0 N with [`Flags::NO_MODEL`].
    pub const fn empty() -> Self {
        Self::EMPTY
    }

    /// The value of [`Estimator::empty`] (a constant: an unoptimised build copies it rather
    /// than building each part on the stack). All its bytes are zero (or uninitialised vector
    /// storage), so that filling a `static` with it is a `memset`, not a copy from flash.
    const EMPTY: Self = Self {
        state: State {
            x_pr_m: 0.0,
            v_st_m_s: 0.0,
        },
        coeffs: Coefficients {
            b_fl: 0.0,
            b_pr: 0.0,
            k_pr: 0.0,
        },
        last_u: 0.0,
        velocity_limit: 0.0,
        sticky: Flags(0),
        diag: Diagnostics {
            steps: 0,
            held_samples: 0,
            resets: 0,
        },
        alpha: 0.0,
        alpha_range: (0.0, 0.0),
        static_force: None,
        last_x: 0.0,
        mode: EvalMode::Exact,
        origin: TableOrigin::None,
        levels_alpha: None,
        rt: Runtime {
            kind: RuntimeKind::Empty,
            emm: EmmRuntime::empty(),
            sem_map: SemMap::empty(),
            sem_curve: heapless::Vec::new(),
        },
        levels: None,
    };

    /// Loads `model` into this estimator **in place**: what [`Estimator::new`] does, without
    /// building anything large on the stack (the compiled scalers and the tables are written
    /// where they live). The state returns to rest, the diagnostics restart and attached
    /// level tables are detached (they belong to the model that was loaded before).
    ///
    /// On error the estimator is empty (as [`Estimator::empty`]: 0 N with
    /// [`Flags::NO_MODEL`]) until a model loads.
    pub fn load(&mut self, model: &Model<P>, cfg: EstimatorConfig) -> Result<(), EstimatorError> {
        self.load_from(model, cfg, None)
    }

    /// [`Estimator::load`] with the blob `model` was decoded from and the index of its
    /// tables section (`tables`, returned by [`crate::decode_into`] or
    /// [`crate::decode_with_tables`]; see [`crate::StoredTables`]): in table mode, the
    /// tables are read from the blob when it holds a level that matches this estimator (its alpha, `T` segments and the table
    /// configuration, bit for bit), instead of being built; the result is bit for bit the
    /// same estimator. Otherwise they are built as by [`Estimator::load`], and
    /// [`Estimator::table_origin`] says why the stored ones were not used (a mismatch is
    /// not an error).
    pub fn load_with_tables(
        &mut self,
        model: &Model<P>,
        cfg: EstimatorConfig,
        tables: &StoredTables,
        blob: &[u8],
    ) -> Result<(), EstimatorError> {
        self.load_from(model, cfg, Some((tables, blob)))
    }

    fn load_from(
        &mut self,
        model: &Model<P>,
        cfg: EstimatorConfig,
        stored: Option<(&StoredTables, &[u8])>,
    ) -> Result<(), EstimatorError> {
        self.rt.kind = RuntimeKind::Empty;
        self.levels = None;
        self.static_force = None;
        self.origin = TableOrigin::None;
        self.sticky = Flags(0);
        self.diag = Diagnostics::default();
        self.state = State::default();
        self.last_u = 0.0;
        model.validate().map_err(EstimatorError::Model)?;
        let alpha = cfg.alpha;
        if !(alpha.is_finite() && (0.0..=1.0).contains(&alpha)) {
            return Err(EstimatorError::AlphaOutOfRange);
        }
        let velocity_limit = cfg
            .velocity_limit_m_s
            .unwrap_or(DEFAULT_VELOCITY_LIMIT_FACTOR * model.scales.velocity_m_s);
        if !(velocity_limit.is_finite() && velocity_limit > 0.0) {
            return Err(EstimatorError::BadVelocityLimit);
        }
        let integrator = cfg.integrator.unwrap_or(model.integrator);
        let dt = cfg.dt_s.unwrap_or(model.dt_s);
        model
            .check_step(integrator, dt)
            .map_err(EstimatorError::Model)?;
        if let EvalMode::Table(tc) = &cfg.mode {
            table::check_config(tc).map_err(EstimatorError::Table)?;
        }
        let sc = &model.scales;
        let kind = match &model.body {
            Body::Sem(map) => {
                self.rt.sem_map.clone_from(map);
                self.rt.sem_curve = map.curve_at(alpha).0;
                RuntimeKind::Sem
            }
            body => {
                let (emm, b_fl, b_pr, k_pr) = match body {
                    Body::LinearEmm(e) => (e, None, None, None),
                    Body::NemmLight { emm, b_fl } => (emm, Some(b_fl), None, None),
                    Body::Nemm {
                        emm,
                        b_fl,
                        b_pr,
                        k_pr,
                    } => (emm, Some(b_fl), Some(b_pr), Some(k_pr)),
                    Body::Sem(_) => return Err(EstimatorError::Compile),
                };
                let branches = &model.alpha_branches;
                let cumulative = &model.cumulative;
                let level = match (stored, &cfg.mode) {
                    (Some((tables, b)), EvalMode::Table(tc)) => tables.find(cfg.alpha, tc, T, b),
                    _ => Err(StoredUnused::NotOffered),
                };
                let blob = stored.map(|(_, b)| b);
                let bytes = |t: Option<StoredTable>| -> Option<(&[u8], StoredLayout)> {
                    let t = t?;
                    Some((blob?.get(usize::try_from(t.offset).ok()?..)?, t.layout))
                };
                let (stored_b_fl, stored_k_pr) = match level {
                    Ok(l) => (bytes(l.b_fl), bytes(l.k_pr)),
                    Err(_) => (None, None),
                };
                let rt = &mut self.rt.emm;
                let read_b_fl = rt.b_fl.load(
                    "b_fl",
                    b_fl.map(|s| (s, branches.b_fl.as_ref(), cumulative.b_fl.as_ref())),
                    emm.b_fl_ns_per_m,
                    sc.velocity_m_s,
                    (alpha, sc.alpha),
                    (&cfg.mode, stored_b_fl),
                )?;
                let read_k_pr = rt.k_pr.load(
                    "k_pr",
                    k_pr.map(|s| (s, branches.k_pr.as_ref(), cumulative.k_pr.as_ref())),
                    emm.k_pr_n_per_m,
                    sc.x_pr_m,
                    (alpha, sc.alpha),
                    (&cfg.mode, stored_k_pr),
                )?;
                self.origin = match (read_b_fl, read_k_pr, level) {
                    (None, None, _) => TableOrigin::None,
                    (_, _, Err(why)) => TableOrigin::Built(why),
                    (b, k, Ok(_)) if b != Some(false) && k != Some(false) => TableOrigin::Stored,
                    _ => TableOrigin::Built(StoredUnused::Table),
                };
                rt.table_cfg = match cfg.mode {
                    EvalMode::Exact => None,
                    EvalMode::Table(tc) => Some(tc),
                };
                rt.b_pr_neural = b_pr.is_some();
                if let Some(s) = b_pr {
                    rt.b_pr_scaler.clone_from(s);
                }
                rt.b_pr_branch.clone_from(&branches.b_pr);
                rt.b_pr_ini = emm.b_pr_ns_per_m;
                rt.lost_motion = model.lost_motion.map(|l| (l, l.at(alpha)));
                rt.alpha_scale = sc.alpha;
                rt.b_pr = rt.b_pr_at(alpha)?;
                rt.inv_t_pr = 1.0 / emm.t_pr_s;
                rt.integrator = integrator;
                rt.h = StepSize::new(dt);
                rt.x_limit = DIVERGENCE_FACTOR * sc.x_pr_m;
                rt.v_limit = DIVERGENCE_FACTOR * sc.velocity_m_s;
                RuntimeKind::Emm
            }
        };
        self.rt.kind = kind;
        self.mode = cfg.mode;
        self.alpha = alpha;
        self.alpha_range = (model.meta.alpha_min, model.meta.alpha_max);
        self.velocity_limit = velocity_limit;
        self.static_force = model.static_force;
        self.update_alpha_flags();
        self.reset();
        Ok(())
    }

    fn update_alpha_flags(&mut self) {
        let (lo, hi) = self.alpha_range;
        let mut extrapolated = !(lo..=hi).contains(&self.alpha);
        if self.rt.kind == RuntimeKind::Sem {
            extrapolated |= self.rt.sem_map.curve_at(self.alpha).1;
        }
        self.sticky = Flags(if extrapolated {
            Flags::ALPHA_EXTRAPOLATED
        } else {
            0
        });
    }

    /// Returns to rest: `x_pr = 0`, `v_st = 0`, last input 0, last position `x_ref` (with a
    /// static force). Diagnostics are kept.
    pub fn reset(&mut self) {
        self.state = State::default();
        self.last_u = 0.0;
        self.levels_alpha = None;
        self.last_x = self.static_force.map_or(0.0, |s| s.x_ref_m);
        if self.rt.kind == RuntimeKind::Emm {
            self.coeffs = self.rt.emm.coeffs(&self.state, &mut false);
        }
    }

    /// Changes the oil-loss level (bench controllers): re-folds the alpha-only work
    /// (first-layer biases, `b_pr(alpha)`, the SEM curve; in table mode it rebuilds and
    /// re-checks the tables, which costs about `128 T` exact scaler evaluations per table).
    /// The state is kept. Refuses values outside `[0, 1]`, and in table mode an `alpha` whose
    /// tables miss the bound ([`EstimatorError::Table`]); after an error nothing changed.
    pub fn set_alpha(&mut self, alpha: f32) -> Result<(), EstimatorError> {
        if !(alpha.is_finite() && (0.0..=1.0).contains(&alpha)) {
            return Err(EstimatorError::AlphaOutOfRange);
        }
        match self.rt.kind {
            RuntimeKind::Empty => return Ok(()),
            RuntimeKind::Sem => self.rt.sem_curve = self.rt.sem_map.curve_at(alpha).0,
            RuntimeKind::Emm => {
                self.rt.emm.set_alpha(alpha, self.alpha)?;
                if self.origin != TableOrigin::None {
                    self.origin = TableOrigin::Built(StoredUnused::NotOffered);
                }
            }
        }
        self.alpha = alpha;
        self.update_alpha_flags();
        if self.rt.kind == RuntimeKind::Emm {
            self.coeffs = self.rt.emm.coeffs(&self.state, &mut false);
        }
        Ok(())
    }

    /// One sample in ([`Sample`]: the stroke velocity, and optionally the stroke position
    /// and this sample's level `alpha`; the measured force is not read), the force estimate
    /// out. The one step of the estimator.
    ///
    /// - **Position.** A model with a static force needs the stroke position
    ///   ([`Sample::with_position`]); without one (or with a non-finite one) its position term
    ///   holds the last good position and the step is flagged [`Flags::POSITION_MISSING`].
    ///   Models without a static force ignore the position.
    /// - **Level.** Without an `alpha` the step runs at the estimator's own level
    ///   ([`Estimator::alpha`]) and cannot fail. With one (a condition changing within a
    ///   run, e.g. an MR damper's control signal mapped to `[0, 1]`):
    ///   - with level tables attached ([`Estimator::attach_levels`]), the coefficients are
    ///     read from them at that level at table cost (module docs, "Every level at table
    ///     cost"), in either [`EvalMode`]: the state carries over between levels, when
    ///     `alpha` changes the coefficients at the state are re-read at the new level first,
    ///     and an `alpha` outside the stored levels or the trained range is flagged
    ///     [`Flags::ALPHA_EXTRAPOLATED`]. The estimator's own level is not changed: a
    ///     firmware that switches between samples with and without an `alpha` calls
    ///     [`Estimator::reset`] first;
    ///   - without level tables, a changed `alpha` is applied as [`Estimator::set_alpha`]
    ///     does (the state is kept, the coefficients at the state re-evaluated) and the whole
    ///     step runs at the new level: the trainer's semantics of a per-sample `alpha` column
    ///     at the model step. In [`EvalMode::Exact`] a change costs one evaluation of the
    ///     `b_pr(alpha)` scaler and of the state scalers at the current state; in
    ///     [`EvalMode::Table`] it would rebuild and re-check every table (about `128 T` exact
    ///     evaluations each), which no sample period affords, so a changed `alpha` is
    ///     refused there with [`EstimatorError::AlphaPerSampleInTableMode`] (an unchanged one
    ///     steps normally).
    ///
    /// Refused, with nothing changed: an `alpha` that is not a finite value in `[0, 1]`
    /// ([`EstimatorError::AlphaOutOfRange`]), a changed `alpha` in table mode without level
    /// tables ([`EstimatorError::AlphaPerSampleInTableMode`]), and attached level tables
    /// that cannot drive this estimator ([`LevelsError::Mismatch`]: checked when attached,
    /// and a load detaches them, so only as a guard).
    ///
    /// ```
    /// # let model: nemm_core::Model = nemm_core::testing::example_model(nemm_core::ModelKind::Nemm, 16, 5).unwrap();
    /// use nemm_core::{Estimator, EstimatorConfig, Sample};
    /// let mut est: Estimator = Estimator::new(&model, EstimatorConfig::new(0.15)).unwrap();
    /// let e = est.step(Sample::new(0.3))?;
    /// let e_at_level = est.step(Sample::new(0.3).with_alpha(0.2))?;
    /// assert_eq!(est.alpha(), 0.2);
    /// # Ok::<(), nemm_core::EstimatorError>(())
    /// ```
    #[inline]
    pub fn step(&mut self, sample: Sample) -> Result<Estimate, EstimatorError> {
        match sample.alpha {
            None => Ok(self.step_at(sample.velocity_m_s, sample.position_m)),
            Some(alpha) => self.step_on_level(sample, alpha),
        }
    }

    /// The step of a sample with a level `alpha`: on the attached level tables (one dynamic
    /// call for the whole step), else at the estimator's own scalers after the level is
    /// applied.
    fn step_on_level(&mut self, sample: Sample, alpha: f32) -> Result<Estimate, EstimatorError> {
        if let Some(levels) = self.levels {
            return levels.step(self, sample.velocity_m_s, alpha, sample.position_m);
        }
        self.alpha_per_sample(alpha)?;
        Ok(self.step_at(sample.velocity_m_s, sample.position_m))
    }

    /// Whether the model adds a static force (and so needs the stroke position).
    pub fn needs_position(&self) -> bool {
        self.static_force.is_some()
    }

    /// The step of [`Estimator::step`] at the estimator's own level, with or without a
    /// position (not forced inline), which the target's cycle trace finds by name.
    #[inline]
    fn step_at(&mut self, velocity_m_s: f32, position_m: Option<f32>) -> Estimate {
        let mut flags = self.sticky.0;
        let u = self.guard_input(velocity_m_s, &mut flags);
        self.diag.steps = self.diag.steps.wrapping_add(1);
        let force_n = match self.rt.kind {
            RuntimeKind::Empty => {
                flags |= Flags::NO_MODEL;
                0.0
            }
            RuntimeKind::Sem => self.rt.sem_map.force_on_curve(&self.rt.sem_curve, u),
            RuntimeKind::Emm => self.emm_step(u, &mut flags),
        };
        self.last_u = u;
        let force_n = self.add_static_force(force_n, position_m, u, self.alpha, &mut flags);
        Estimate {
            force_n: if force_n.is_finite() { force_n } else { 0.0 },
            flags: Flags(flags),
        }
    }

    /// The input guard: the velocity, or the last good one (flagged, and counted as held)
    /// for a non-finite or implausible sample.
    #[inline(always)]
    fn guard_input(&mut self, velocity_m_s: f32, flags: &mut u8) -> f32 {
        let u = if !velocity_m_s.is_finite() {
            *flags |= Flags::INPUT_NON_FINITE | Flags::INPUT_HELD;
            self.last_u
        } else if velocity_m_s.abs() > self.velocity_limit {
            *flags |= Flags::INPUT_OUT_OF_RANGE | Flags::INPUT_HELD;
            self.last_u
        } else {
            velocity_m_s
        };
        if *flags & Flags::INPUT_HELD != 0 {
            self.diag.held_samples = self.diag.held_samples.wrapping_add(1);
        }
        u
    }

    /// One RK step of an EMM from the last input to `u` and the force at the new state,
    /// behind the divergence guard: a non-finite force or a state beyond its limits resets
    /// the state to rest (flagged) and gives the force there.
    #[inline(always)]
    fn emm_step(&mut self, u: f32, flags: &mut u8) -> f32 {
        let rt = &self.rt.emm;
        // The domain flag reports the new state (the output evaluation); the RK stages in
        // between are clamped alike, unflagged (their states lie between the old and the
        // new one up to the local error).
        let mut out = false;
        let r = rt.advance(&self.state, &self.coeffs, self.last_u, u, &mut out);
        if out {
            *flags |= Flags::OUT_OF_TABLE_DOMAIN;
        }
        self.accept_step(r, u, flags, |rt, s| rt.coeffs(s, &mut false))
    }

    /// The divergence guard of a step's result `(state, coefficients, force)`: kept if the
    /// force is finite and the state within its limits; otherwise the state is reset to
    /// rest (flagged, counted) with the coefficients `at_rest` gives there, and the force
    /// at rest for input `u` is returned.
    #[inline(always)]
    fn accept_step(
        &mut self,
        (x1, c1, f): (State, Coefficients, f32),
        u: f32,
        flags: &mut u8,
        at_rest: impl FnOnce(&EmmRuntime<P, T>, &State) -> Coefficients,
    ) -> f32 {
        let (x_limit, v_limit) = (self.rt.emm.x_limit, self.rt.emm.v_limit);
        if f.is_finite() && x1.x_pr_m.abs() <= x_limit && x1.v_st_m_s.abs() <= v_limit {
            self.state = x1;
            self.coeffs = c1;
            f
        } else {
            *flags |= Flags::STATE_RESET;
            self.diag.resets = self.diag.resets.wrapping_add(1);
            self.state = State::default();
            self.coeffs = at_rest(&self.rt.emm, &self.state);
            let f0 = emm::force(&self.coeffs, &self.state, u);
            if f0.is_finite() {
                f0
            } else {
                0.0
            }
        }
    }

    /// `force_n` plus the static force at level `alpha` and the stroke position (the last
    /// good one when `position_m` is missing or non-finite, flagged); `force_n` for a model
    /// without one.
    #[inline(always)]
    fn add_static_force(
        &mut self,
        force_n: f32,
        position_m: Option<f32>,
        u: f32,
        alpha: f32,
        flags: &mut u8,
    ) -> f32 {
        match &self.static_force {
            None => force_n,
            Some(s) => {
                match position_m {
                    Some(x) if x.is_finite() => self.last_x = x,
                    _ => *flags |= Flags::POSITION_MISSING,
                }
                force_n + s.force(self.last_x, u, alpha)
            }
        }
    }

    /// Runs a whole input sequence from the current state, each input as
    /// `step(Sample::new(velocity))`; `forces` gets one value per input (up to the shorter
    /// length).
    pub fn run(&mut self, velocities_m_s: &[f32], forces_n: &mut [f32]) {
        for (&v, f) in velocities_m_s.iter().zip(forces_n.iter_mut()) {
            *f = self.step_at(v, None).force_n;
        }
    }

    /// Current state `[x_pr, v_st]`.
    pub fn state(&self) -> State {
        self.state
    }

    /// Coefficients `b_fl`, `b_pr`, `k_pr` at the current state (zeros for the SEM).
    pub fn coefficients(&self) -> Coefficients {
        self.coeffs
    }

    /// Counters.
    pub fn diagnostics(&self) -> Diagnostics {
        self.diag
    }

    /// The oil-loss level in use.
    pub fn alpha(&self) -> f32 {
        self.alpha
    }

    /// The plausibility limit of the input \[m/s\].
    pub fn velocity_limit_m_s(&self) -> f32 {
        self.velocity_limit
    }

    /// The evaluation mode.
    pub fn mode(&self) -> EvalMode {
        self.mode
    }

    /// Where the tables in use came from: built, or read from the blob
    /// ([`Estimator::load_with_tables`]); [`TableOrigin::None`] without tables.
    pub fn table_origin(&self) -> TableOrigin {
        self.origin
    }

    /// Table mode: what the tables section of a blob stores for this estimator (its alpha,
    /// table configuration and the tables of `b_fl` and `k_pr`); `None` in exact mode or
    /// without neural coefficients.
    pub(crate) fn table_level(&self) -> Option<TableLevel<'_, T>> {
        let EvalMode::Table(tc) = self.mode else {
            return None;
        };
        if self.rt.kind != RuntimeKind::Emm {
            return None;
        }
        let rt = &self.rt.emm;
        let (b, k) = (rt.b_fl.table(), rt.k_pr.table());
        (b.is_some() || k.is_some()).then_some(TableLevel {
            alpha: self.alpha,
            config: tc,
            b_fl: b,
            k_pr: k,
        })
    }

    /// Table mode: the worst accuracy of the tables in use, measured when they were built
    /// (`None` in exact mode and for kinds without neural coefficients).
    pub fn table_accuracy(&self) -> Option<TableAccuracy> {
        match self.rt.kind {
            RuntimeKind::Empty | RuntimeKind::Sem => None,
            RuntimeKind::Emm => {
                self.rt
                    .emm
                    .tables()
                    .map(|t| t.accuracy())
                    .fold(None, |w, a| match w {
                        Some(w) if w.max_rel_error >= a.max_rel_error => Some(w),
                        _ => Some(a),
                    })
            }
        }
    }

    /// Number of tables in use and their bytes (`28 T` each, [`Table1D::table_bytes`]).
    pub fn table_bytes(&self) -> (usize, usize) {
        let n = match self.rt.kind {
            RuntimeKind::Empty | RuntimeKind::Sem => 0,
            RuntimeKind::Emm => self.rt.emm.tables().count(),
        };
        (n, n * Table1D::<T>::table_bytes())
    }
}

/// One member of a bank of levels ([`crate::observer`]): what an exact-mode estimator holds
/// that depends on its own `alpha` (the level, `b_pr(alpha)`, the state, the coefficients at
/// the state, the last inputs). A bank of them is stepped through one shared estimator, so
/// the weights are held once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BankMember {
    pub(crate) alpha: f32,
    b_pr: f32,
    state: State,
    coeffs: Coefficients,
    last_u: f32,
    last_x: f32,
}

impl BankMember {
    /// A member at `alpha` that [`Estimator::step_member`] has not stepped (zeros).
    pub(crate) const EMPTY: Self = Self {
        alpha: 0.0,
        b_pr: 0.0,
        state: State {
            x_pr_m: 0.0,
            v_st_m_s: 0.0,
        },
        coeffs: Coefficients {
            b_fl: 0.0,
            b_pr: 0.0,
            k_pr: 0.0,
        },
        last_u: 0.0,
        last_x: 0.0,
    };
}

/// Banks of levels through one estimator (exact mode).
impl<const P: usize, const T: usize> Estimator<'_, P, T> {
    /// A bank member at `alpha`, at rest. Leaves this estimator at `alpha`, at rest.
    /// Refused in table mode (a level would need its own tables).
    pub(crate) fn bank_member(&mut self, alpha: f32) -> Result<BankMember, EstimatorError> {
        if matches!(self.mode, EvalMode::Table(_)) {
            return Err(EstimatorError::AlphaPerSampleInTableMode);
        }
        self.set_alpha(alpha)?;
        self.reset();
        Ok(BankMember {
            alpha,
            b_pr: self.rt.emm.b_pr,
            state: self.state,
            coeffs: self.coeffs,
            last_u: self.last_u,
            last_x: self.last_x,
        })
    }

    /// One step of member `m` (made by [`Estimator::bank_member`] of this estimator): its
    /// level is folded into the shared scalers if another member stepped last (the
    /// first-layer biases and the alpha branch: about `2 H + K` operations per scaler;
    /// `b_pr` and the coefficients at the state are the member's), then the step at the
    /// estimator's own level ([`Estimator::step`] without an `alpha`) from the member's
    /// state, which is written back.
    pub(crate) fn step_member(
        &mut self,
        m: &mut BankMember,
        velocity_m_s: f32,
        position_m: Option<f32>,
    ) -> Estimate {
        if m.alpha.to_bits() != self.alpha.to_bits() {
            match self.rt.kind {
                RuntimeKind::Empty => {}
                RuntimeKind::Sem => self.rt.sem_curve = self.rt.sem_map.curve_at(m.alpha).0,
                RuntimeKind::Emm => self.rt.emm.fold_exact_alpha(m.alpha, m.b_pr),
            }
            self.alpha = m.alpha;
            self.update_alpha_flags();
        }
        self.load_member(m);
        let e = self.step_at(velocity_m_s, position_m);
        self.store_member(m);
        e
    }

    /// One step of a bank on the exact scalers: each member of `members` by
    /// [`Estimator::step_member`], its force into `forces`; true if any member held its
    /// input (a velocity fault).
    pub(crate) fn step_bank(
        &mut self,
        (members, forces): (&mut [BankMember], &mut [f32]),
        velocity_m_s: f32,
        position_m: Option<f32>,
    ) -> bool {
        let mut velocity_fault = false;
        for (m, f) in members.iter_mut().zip(forces.iter_mut()) {
            let e = self.step_member(m, velocity_m_s, position_m);
            velocity_fault |= e.flags.0 & Flags::INPUT_HELD != 0;
            *f = e.force_n;
        }
        velocity_fault
    }

    /// Takes member `m`'s state, coefficients at the state and last inputs.
    pub(crate) fn load_member(&mut self, m: &BankMember) {
        self.state = m.state;
        self.coeffs = m.coeffs;
        self.last_u = m.last_u;
        self.last_x = m.last_x;
    }

    /// Gives member `m` this estimator's state, coefficients at the state and last inputs.
    pub(crate) fn store_member(&self, m: &mut BankMember) {
        m.state = self.state;
        m.coeffs = self.coeffs;
        m.last_u = self.last_u;
        m.last_x = self.last_x;
    }
}

/// A condition level per sample.
impl<const P: usize, const T: usize> Estimator<'_, P, T> {
    /// Applies a sample's `alpha` without level tables ([`Estimator::step`]): a changed one
    /// as [`Estimator::set_alpha`], refused in table mode with tables.
    fn alpha_per_sample(&mut self, alpha: f32) -> Result<(), EstimatorError> {
        if alpha.to_bits() != self.alpha.to_bits() {
            if matches!(self.mode, EvalMode::Table(_)) && self.table_bytes().0 > 0 {
                return Err(EstimatorError::AlphaPerSampleInTableMode);
            }
            self.set_alpha(alpha)?;
        }
        Ok(())
    }
}
