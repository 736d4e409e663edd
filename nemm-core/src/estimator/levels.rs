//! Every oil-loss level at table cost: the stored tables of several levels, held together,
//! and the estimator steps that read them (a level per sample, and a bank member at one
//! level for the [`crate::AlphaObserver`]).
//!
//! # What is held
//!
//! [`LevelTables`] reads from a blob's tables section ([`crate::format::tables`]) every
//! stored level with `T` segments, in ascending `alpha` (at least two): per level its
//! `alpha`, `b_pr(alpha)` (evaluated once, exactly, when loading) and the tables of
//! `b_fl(v_st)` and `k_pr(x_pr)` at that level, as a table-mode estimator at that level
//! uses them (bit for bit).
//!
//! The tables are **read in place**: a version-6 blob stores each table as its memory
//! image, 4-byte aligned from the blob's start, and [`LevelTables`] holds references into
//! the blob (on a microcontroller: into the flash slot), each table validated once when
//! loading ([`nemm_kernels::table::Table1D::in_place`]). Its RAM is a few hundred bytes
//! whatever the number of levels (`size_of::<LevelTables<'_, T, L>>()`); the tables take
//! `32 + 28 T` bytes each in the blob ([`LevelTables::table_bytes`]). The blob must
//! therefore outlive the level tables (the lifetime `'a`) and be held 4-byte aligned
//! ([`LevelsError::Unaligned`] otherwise; on the host, [`crate::AlignedBlob`] holds a
//! copy so), and a blob of format version 4 or 5 (tables stored unaligned) is refused
//! with [`LevelsError::Layout`]: export it again.
//!
//! # Between levels
//!
//! At a level `alpha` between the stored levels `a_i < a_i+1`, `w = (alpha - a_i) /
//! (a_i+1 - a_i)`, each coefficient is the linear blend of its two neighbouring levels'
//! tables at the state:
//!
//! ```text
//! c(x, alpha) = c_i(x) + w (o(c_i(x), c_i+1(x)) - c_i(x))
//! ```
//!
//! where `o` orders the upper level's value against the lower one's in the coefficient's
//! declared direction ([`crate::Priors`]): `min` for a coefficient decreasing in `alpha`,
//! `max` for one increasing, the value itself without a prior. With that, `c` is monotone
//! in `alpha` in the declared direction between two levels **by construction** (one
//! multiply-add whose factor `o(.) - c_i` has the declared sign, monotone in `w` under IEEE
//! rounding), for any tables. At the levels themselves the blend is the level's table,
//! which orders as the model does up to the tables' error; the export measures the
//! ordering of the stored levels on a fine grid ([`LevelTables::check`]), and a violation
//! can only come from two levels whose exact values lie within the tables' error of each
//! other.
//!
//! **Error.** Against the exact coefficient at `alpha`, the blend errs by the tables' own
//! error (the bound each level was checked with) plus the blend's, which is first order in
//! the level spacing where a kink of the scaler's LeakyReLU units moves with `alpha`
//! (measured per model by [`LevelTables::check`], printed by `nemm export`). `alpha`
//! outside the stored levels takes the nearest level's tables and is flagged
//! [`crate::Flags::ALPHA_EXTRAPOLATED`].

use super::*;
use nemm_kernels::mlp::Direction;
use nemm_kernels::table::ImageError;

/// Why a [`LevelTables`] could not be loaded, or a step on it was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LevelsError {
    /// The model has no neural coefficient to tabulate (SEM, Linear EMM).
    NoNeuralCoefficient,
    /// The blob is not the one the tables index was decoded with (length or CRC).
    OtherBlob,
    /// Fewer than two stored levels have `T` segments.
    TooFewLevels {
        /// Stored levels with `T` segments.
        found: usize,
        /// `T`.
        segments: usize,
    },
    /// More stored levels with `T` segments than the capacity `L`.
    TooManyLevels {
        /// Stored levels with `T` segments.
        found: usize,
        /// The capacity `L`.
        capacity: usize,
    },
    /// The levels are not in strictly ascending `alpha`, or their table configurations
    /// differ.
    Order,
    /// A stored table does not read back on the model's domain.
    Table,
    /// `b_pr` at a level could not be evaluated (inconsistent scaler shape).
    Compile,
    /// The tables are empty ([`LevelTables::empty`]), or belong to a model with other
    /// neural coefficients than the estimator's.
    Mismatch,
    /// The blob is not held 4-byte aligned in memory (or the target is big-endian), so its
    /// tables cannot be read in place.
    Unaligned,
    /// The blob stores its tables in the layout of format version 4 or 5, which cannot be
    /// read in place: export it again with this version.
    Layout,
}

impl LevelsError {
    /// A short name for report lines: `no-neural-coefficient`, `other-blob`,
    /// `too-few-levels`, `too-many-levels`, `order`, `table`, `compile`, `mismatch`,
    /// `unaligned`, `layout`.
    pub const fn name(&self) -> &'static str {
        match self {
            LevelsError::NoNeuralCoefficient => "no-neural-coefficient",
            LevelsError::OtherBlob => "other-blob",
            LevelsError::TooFewLevels { .. } => "too-few-levels",
            LevelsError::TooManyLevels { .. } => "too-many-levels",
            LevelsError::Order => "order",
            LevelsError::Table => "table",
            LevelsError::Compile => "compile",
            LevelsError::Mismatch => "mismatch",
            LevelsError::Unaligned => "unaligned",
            LevelsError::Layout => "layout",
        }
    }
}

impl fmt::Display for LevelsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LevelsError::NoNeuralCoefficient => {
                write!(f, "the model has no neural coefficient to tabulate")
            }
            LevelsError::OtherBlob => write!(f, "the blob is not the one the model came from"),
            LevelsError::TooFewLevels { found, segments } => write!(
                f,
                "the blob stores {found} levels of {segments}-segment tables; at least 2 are needed \
                 (export with --tables-levels)"
            ),
            LevelsError::TooManyLevels { found, capacity } => write!(
                f,
                "the blob stores {found} levels, the level tables hold {capacity}"
            ),
            LevelsError::Order => write!(
                f,
                "the stored levels are not in ascending alpha with one table configuration"
            ),
            LevelsError::Table => write!(f, "a stored table does not match the model's domain"),
            LevelsError::Compile => write!(f, "b_pr could not be evaluated at a level"),
            LevelsError::Mismatch => write!(
                f,
                "the level tables are empty or belong to a model with other coefficients"
            ),
            LevelsError::Unaligned => write!(
                f,
                "the blob is not held 4-byte aligned in memory (or the target is big-endian): \
                 its tables cannot be read in place"
            ),
            LevelsError::Layout => write!(
                f,
                "the blob stores its tables unaligned (format version 4 or 5): export it again \
                 to read them in place"
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for LevelsError {}

/// The tables of up to `L` oil-loss levels with `T` segments each, read in place from the
/// blob `'a` (module docs), for an [`Estimator`] with a level per sample
/// ([`Estimator::attach_levels`]) and a table-cost [`crate::AlphaObserver`]
/// ([`crate::AlphaObserver::load_on_levels`]). Load once (e.g. into a `static` made with
/// [`LevelTables::empty`]) and pass by reference.
#[derive(Debug, Clone)]
pub struct LevelTables<'a, const T: usize, const L: usize> {
    count: usize,
    alpha: [f32; L],
    b_pr: [f32; L],
    /// Present coefficients: `b_fl`, `k_pr`.
    neural: (bool, bool),
    /// Declared directions in `alpha` of `b_fl`, `b_pr`, `k_pr`.
    priors: [Direction; 3],
    config: TableConfig,
    /// `b_pr_ini` and `1 / T_pr` of the model, bits: what a stepping estimator is checked
    /// against.
    fingerprint: (u32, u32),
    /// The constant `k_pr` of a model without a `k_pr` scaler (NEMM-Light) \[N/m\].
    k_pr_ini: f32,
    /// The model's lost-motion element, evaluated at the level in use.
    lost_motion: Option<LostMotion>,
    /// Per level, the table of `b_fl(v_st)` in the blob.
    b_fl: [Option<&'a Table1D<T>>; L],
    /// Per level, the table of `k_pr(x_pr)` in the blob (a NEMM's).
    k_pr: [Option<&'a Table1D<T>>; L],
}

impl<'a, const T: usize, const L: usize> LevelTables<'a, T, L> {
    /// No levels (a `const fn`, for a `static`); [`LevelTables::load`] fills it.
    pub const fn empty() -> Self {
        Self {
            count: 0,
            alpha: [0.0; L],
            b_pr: [0.0; L],
            neural: (false, false),
            priors: [Direction::None; 3],
            config: TableConfig {
                max_rel_error: 0.0,
                domain_margin: 0.0,
            },
            fingerprint: (0, 0),
            k_pr_ini: 0.0,
            lost_motion: None,
            b_fl: [None; L],
            k_pr: [None; L],
        }
    }

    /// Loads the levels of `tables` (the index [`crate::decode_into`] returned for `blob`)
    /// whose tables have `T` segments: at least two, at most `L`, ascending in `alpha`, one
    /// table configuration. The tables are read in place from `blob`, which must be held
    /// 4-byte aligned and be of format version 6 or later (module docs). On error `self`
    /// is empty.
    pub fn load<const P: usize>(
        &mut self,
        model: &Model<P>,
        tables: &StoredTables,
        blob: &'a [u8],
    ) -> Result<(), LevelsError> {
        self.count = 0;
        let r = self.load_inner(model, tables, blob);
        if r.is_err() {
            self.count = 0;
        }
        r
    }

    fn load_inner<const P: usize>(
        &mut self,
        model: &Model<P>,
        tables: &StoredTables,
        blob: &'a [u8],
    ) -> Result<(), LevelsError> {
        let (b_pr, k_pr, emm) = match &model.body {
            Body::Sem(_) | Body::LinearEmm(_) => return Err(LevelsError::NoNeuralCoefficient),
            Body::NemmLight { emm, .. } => (None, None, emm),
            Body::Nemm {
                emm, b_pr, k_pr, ..
            } => (Some(b_pr), Some(k_pr), emm),
        };
        let first = tables.levels.iter().find(|l| l.segments as usize == T);
        let found = tables
            .levels
            .iter()
            .filter(|l| l.segments as usize == T)
            .count();
        let Some(first) = first.filter(|_| found >= 2) else {
            return Err(LevelsError::TooFewLevels { found, segments: T });
        };
        if found > L {
            return Err(LevelsError::TooManyLevels { found, capacity: L });
        }
        let crc_ok = u32::try_from(blob.len()).ok() == Some(tables.blob_len)
            && blob
                .len()
                .checked_sub(4)
                .and_then(|at| blob.get(at..))
                .and_then(|b| b.try_into().ok())
                .map(u32::from_le_bytes)
                == Some(tables.blob_crc);
        if !crc_ok {
            return Err(LevelsError::OtherBlob);
        }
        let config = first.config;
        let sc = &model.scales;
        let branches = &model.alpha_branches;
        let mut last = f32::NEG_INFINITY;
        let levels = tables.levels.iter().filter(|l| l.segments as usize == T);
        for (k, level) in levels.enumerate() {
            let same_config = level.config.max_rel_error.to_bits()
                == config.max_rel_error.to_bits()
                && level.config.domain_margin.to_bits() == config.domain_margin.to_bits();
            if !(level.alpha > last && same_config) {
                return Err(LevelsError::Order);
            }
            last = level.alpha;
            let (Some(a), Some(bp), Some(tb), Some(tk)) = (
                self.alpha.get_mut(k),
                self.b_pr.get_mut(k),
                self.b_fl.get_mut(k),
                self.k_pr.get_mut(k),
            ) else {
                return Err(LevelsError::TooManyLevels { found, capacity: L });
            };
            *a = level.alpha;
            *bp = match b_pr {
                None => emm.b_pr_ns_per_m,
                Some(s) => b_pr_of(
                    s,
                    branches.b_pr.as_ref(),
                    emm.b_pr_ns_per_m,
                    sc.alpha,
                    level.alpha,
                )
                .ok_or(LevelsError::Compile)?,
            };
            *tb = Some(level_table(
                level.b_fl,
                blob,
                config.domain_margin * sc.velocity_m_s,
            )?);
            *tk = match k_pr {
                Some(_) => Some(level_table(
                    level.k_pr,
                    blob,
                    config.domain_margin * sc.x_pr_m,
                )?),
                None => None,
            };
        }
        self.neural = (true, k_pr.is_some());
        self.priors = model.condition.priors.all();
        self.config = config;
        self.fingerprint = (emm.b_pr_ns_per_m.to_bits(), (1.0 / emm.t_pr_s).to_bits());
        self.k_pr_ini = emm.k_pr_n_per_m;
        self.lost_motion = model.lost_motion;
        self.count = found;
        Ok(())
    }

    /// Number of levels loaded (0: empty).
    pub fn len(&self) -> usize {
        self.count
    }

    /// True if no levels are loaded.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The levels \[-\], ascending.
    pub fn alphas(&self) -> &[f32] {
        self.alpha.get(..self.count).unwrap_or(&[])
    }

    /// The table configuration every level was built and checked with.
    pub fn config(&self) -> TableConfig {
        self.config
    }

    /// The worst accuracy any level's tables measured when they were built.
    pub fn accuracy(&self) -> Option<TableAccuracy> {
        let n = self.count;
        let k_pr = self.neural.1;
        self.b_fl
            .iter()
            .take(n)
            .chain(self.k_pr.iter().take(if k_pr { n } else { 0 }))
            .flatten()
            .map(|t| t.accuracy())
            .fold(None, |w: Option<TableAccuracy>, a| match w {
                Some(w) if w.max_rel_error >= a.max_rel_error => Some(w),
                _ => Some(a),
            })
    }

    /// Tables in use and the bytes they take in the blob, where they are read
    /// (`32 + 28 T` each); the level tables' own RAM is `size_of::<Self>()`.
    pub fn table_bytes(&self) -> (usize, usize) {
        let n = self.count * (1 + usize::from(self.neural.1));
        (n, n * Table1D::<T>::IMAGE_LEN)
    }

    /// The bracket of `alpha`: the lower level's index `i` and the weight `w` in `[0, 1)`
    /// of level `i + 1` (`w = 0` at a level, whose own tables are then read, and from the
    /// last level on), and whether `alpha` lies outside the levels (then clamped to the
    /// nearest). `None` when empty.
    pub fn bracket(&self, alpha: f32) -> Option<(usize, f32, bool)> {
        let a = self.alphas();
        let (&lo, &hi) = (a.first()?, a.last()?);
        // NaN lands on the first level, flagged outside.
        if alpha.partial_cmp(&lo) != Some(core::cmp::Ordering::Greater) {
            return Some((0, 0.0, alpha != lo));
        }
        if alpha >= hi {
            return Some((a.len() - 1, 0.0, alpha > hi));
        }
        // First level above alpha: at least 1, at most len - 1.
        let above = a.partition_point(|&x| x <= alpha).max(1).min(a.len() - 1);
        let (a0, a1) = (a.get(above - 1)?, a.get(above)?);
        let w = ((alpha - a0) / (a1 - a0)).clamp(0.0, 1.0);
        Some((above - 1, w, false))
    }

    /// The lost-motion element (if the model has one) at level `alpha`.
    fn lost_motion_at(&self, alpha: f32) -> Option<LostMotionAt> {
        self.lost_motion.map(|l| l.at(alpha))
    }

    /// The coefficients at state `s` at level `alpha` (the blend of the module docs;
    /// `alpha` outside the levels takes the nearest). `None` when empty.
    pub fn coefficients(&self, s: &State, alpha: f32) -> Option<Coefficients> {
        let (i, w, _) = self.bracket(alpha)?;
        let b_fl = self.blend(&self.b_fl, 0, i, w)?;
        let b_pr = self.blend_b_pr(i, w)?;
        let lm = self.lost_motion_at(alpha);
        let lost_motion = lm.as_ref();
        Some(match self.neural.1 {
            true => with_coef_stage!(
                b_fl,
                self.blend(&self.k_pr, 2, i, w)?,
                b_pr,
                lost_motion,
                |stage| stage.coeffs(s)
            ),
            false => with_coef_stage!(b_fl, self.k_pr_ini, b_pr, lost_motion, |stage| stage
                .coeffs(s)),
        })
    }

    /// The coefficients at state `s` at stored level `k` (its own tables, as a table-mode
    /// estimator at that level computes them). `None` if `k` is not a level.
    pub fn level_coefficients(&self, s: &State, k: usize) -> Option<Coefficients> {
        if k >= self.count {
            return None;
        }
        let (b_fl, b_pr) = (self.b_fl.get(k).copied().flatten()?, *self.b_pr.get(k)?);
        let lm = self.lost_motion_at(*self.alpha.get(k)?);
        let lost_motion = lm.as_ref();
        Some(match self.neural.1 {
            true => with_coef_stage!(
                b_fl,
                self.k_pr.get(k).copied().flatten()?,
                b_pr,
                lost_motion,
                |stage| stage.coeffs(s)
            ),
            false => with_coef_stage!(b_fl, self.k_pr_ini, b_pr, lost_motion, |stage| stage
                .coeffs(s)),
        })
    }

    /// The blend of `tables` between levels `i` and `i + 1` at weight `w`, ordered in the
    /// direction of prior `p` (0: `b_fl`, 2: `k_pr`).
    fn blend(
        &self,
        tables: &[Option<&'a Table1D<T>>; L],
        p: usize,
        i: usize,
        w: f32,
    ) -> Option<Blend<'a, T>> {
        let lo = tables.get(i).copied().flatten()?;
        Some(Blend {
            lo,
            hi: tables.get(i + 1).copied().flatten().unwrap_or(lo),
            w,
            direction: *self.priors.get(p)?,
        })
    }

    /// `b_pr` blended as the state coefficients are.
    fn blend_b_pr(&self, i: usize, w: f32) -> Option<f32> {
        let lo = *self.b_pr.get(i)?;
        let hi = self.b_pr.get(i + 1).map_or(lo, |&b| b);
        Some(blend_values(lo, hi, w, *self.priors.get(1)?))
    }

    /// True if `s` lies in every table's domain (the levels share one domain).
    fn contains(&self, s: &State) -> bool {
        let b = matches!(self.b_fl.first(), Some(Some(t)) if t.contains(s.v_st_m_s));
        let k =
            !self.neural.1 || matches!(self.k_pr.first(), Some(Some(t)) if t.contains(s.x_pr_m));
        b && k
    }
}

/// `lo + w (o(lo, hi) - lo)`: the upper value ordered against the lower one in `direction`,
/// then the linear blend; monotone in `w` in `direction` for any `lo`, `hi`.
#[inline(always)]
fn blend_values(lo: f32, hi: f32, w: f32, direction: Direction) -> f32 {
    let hi = match direction {
        Direction::Decreasing => hi.min(lo),
        Direction::Increasing => hi.max(lo),
        Direction::None => hi,
    };
    w * (hi - lo) + lo
}

/// A state coefficient between two levels' tables (module docs).
#[derive(Debug, Clone, Copy)]
pub(super) struct Blend<'a, const T: usize> {
    lo: &'a Table1D<T>,
    hi: &'a Table1D<T>,
    w: f32,
    direction: Direction,
}

impl<const T: usize> StateCoef for Blend<'_, T> {
    #[inline(always)]
    fn at(&self, u: f32) -> f32 {
        blend_values(
            self.lo.eval_finite(u),
            self.hi.eval_finite(u),
            self.w,
            self.direction,
        )
    }
}

/// One stored table of a level, read in place from `blob` on the domain `[-d, d]`.
fn level_table<const T: usize>(
    stored: Option<StoredTable>,
    blob: &[u8],
    d: f32,
) -> Result<&Table1D<T>, LevelsError> {
    let stored = stored.ok_or(LevelsError::Table)?;
    if stored.layout != StoredLayout::Image {
        return Err(LevelsError::Layout);
    }
    let bytes = usize::try_from(stored.offset)
        .ok()
        .and_then(|at| blob.get(at..))
        .ok_or(LevelsError::Table)?;
    Table1D::in_place(bytes, -d, d).map_err(|e| match e {
        ImageError::Unaligned | ImageError::BigEndian => LevelsError::Unaligned,
        ImageError::Invalid => LevelsError::Table,
    })
}

/// Level tables as an estimator holds them ([`Estimator::attach_levels`],
/// [`crate::AlphaObserver::load_on_levels`]): the whole step on them, with their number of
/// levels `L` and of segments `T` behind one dynamic call, so that neither is part of the
/// estimator's type. Implemented by [`LevelTables`] alone. Not `Debug` (a supertrait would
/// put the tables' formatting, and its panic paths, into every vtable): the trait object has
/// its own `Debug` below.
pub(crate) trait LevelStep<const P: usize, const T0: usize>: Sync {
    /// One sample at level `alpha` on these tables ([`Estimator::step`] with an `alpha`).
    fn step(
        &self,
        est: &mut Estimator<'_, P, T0>,
        velocity_m_s: f32,
        alpha: f32,
        position_m: Option<f32>,
    ) -> Result<Estimate, EstimatorError>;

    /// One step of a bank ([`crate::AlphaObserver`]): member `k` on stored level `k` (its
    /// own tables), a member these tables do not hold on the exact scalers
    /// ([`Estimator::step_bank`]); one dynamic call for the whole bank.
    fn step_bank(
        &self,
        est: &mut Estimator<'_, P, T0>,
        bank: (&mut [BankMember], &mut [f32]),
        velocity_m_s: f32,
        position_m: Option<f32>,
    ) -> bool;

    /// The stored levels \[-\], ascending.
    fn alphas(&self) -> &[f32];

    /// Whether these tables can drive `est` ([`Estimator::accepts_levels`]).
    fn accepted_by(&self, est: &Estimator<'_, P, T0>) -> bool;
}

impl<const P: usize, const T0: usize> fmt::Debug for dyn LevelStep<P, T0> + '_ {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LevelTables")
            .field("alphas", &self.alphas())
            .finish_non_exhaustive()
    }
}

impl<const P: usize, const T0: usize, const T: usize, const L: usize> LevelStep<P, T0>
    for LevelTables<'_, T, L>
{
    fn step(
        &self,
        est: &mut Estimator<'_, P, T0>,
        velocity_m_s: f32,
        alpha: f32,
        position_m: Option<f32>,
    ) -> Result<Estimate, EstimatorError> {
        est.levels_step(self, velocity_m_s, alpha, position_m)
    }

    fn step_bank(
        &self,
        est: &mut Estimator<'_, P, T0>,
        (members, forces): (&mut [BankMember], &mut [f32]),
        velocity_m_s: f32,
        position_m: Option<f32>,
    ) -> bool {
        let mut velocity_fault = false;
        for (k, (m, f)) in members.iter_mut().zip(forces.iter_mut()).enumerate() {
            let e = match est.step_member_on_level(self, k, m, velocity_m_s, position_m) {
                Some(e) => e,
                None => est.step_member(m, velocity_m_s, position_m),
            };
            velocity_fault |= e.flags.0 & Flags::INPUT_HELD != 0;
            *f = e.force_n;
        }
        velocity_fault
    }

    fn alphas(&self) -> &[f32] {
        LevelTables::alphas(self)
    }

    fn accepted_by(&self, est: &Estimator<'_, P, T0>) -> bool {
        est.accepts_levels(self)
    }
}

/// Level tables attached to an estimator: a condition level per sample at table cost, and
/// bank members on stored levels.
impl<'l, const P: usize, const T0: usize> Estimator<'l, P, T0> {
    /// Attaches level tables (loaded from this estimator's model; module docs): from now on
    /// a sample with an `alpha` ([`crate::Sample::with_alpha`]) is stepped on them at table
    /// cost, in either [`EvalMode`] (the estimator's own scalers or tables are not read for
    /// it), as [`Estimator::step`] describes. A sample without an `alpha` steps at the
    /// estimator's own level as before. The tables are held by reference until
    /// [`Estimator::detach_levels`] or the next load; attaching re-reads the coefficients
    /// at the state on the next step with an `alpha`.
    ///
    /// Refused with [`LevelsError::Mismatch`], nothing changed: tables that are empty or of
    /// a model with other neural coefficients, `b_pr_ini` or `T_pr`, and an estimator
    /// without an EMM model.
    pub fn attach_levels<const T: usize, const L: usize>(
        &mut self,
        levels: &'l LevelTables<'_, T, L>,
    ) -> Result<(), EstimatorError> {
        if !self.accepts_levels(levels) {
            return Err(EstimatorError::Levels(LevelsError::Mismatch));
        }
        self.levels = Some(levels);
        self.levels_alpha = None;
        Ok(())
    }

    /// Detaches the level tables: a sample's `alpha` is then applied to the estimator's own
    /// scalers ([`Estimator::step`]).
    pub fn detach_levels(&mut self) {
        self.levels = None;
        self.levels_alpha = None;
    }

    /// Whether level tables are attached.
    pub fn has_levels(&self) -> bool {
        self.levels.is_some()
    }

    /// Whether `levels` can drive this estimator: loaded, with the same neural
    /// coefficients, `b_pr_ini` and `T_pr` as the estimator's model.
    pub(crate) fn accepts_levels<const T: usize, const L: usize>(
        &self,
        levels: &LevelTables<'_, T, L>,
    ) -> bool {
        let rt = &self.rt.emm;
        self.rt.kind == RuntimeKind::Emm
            && !levels.is_empty()
            && levels.neural
                == (
                    rt.b_fl.kind != CoefKind::Const,
                    rt.k_pr.kind != CoefKind::Const,
                )
            && levels.fingerprint == (rt.b_pr_ini.to_bits(), rt.inv_t_pr.to_bits())
    }

    /// The step of a sample with level `alpha` on `levels`: refused, with nothing changed,
    /// for an `alpha` outside `[0, 1]` and for tables that cannot drive this estimator.
    #[inline]
    fn levels_step<const T: usize, const L: usize>(
        &mut self,
        levels: &LevelTables<'_, T, L>,
        velocity_m_s: f32,
        alpha: f32,
        position_m: Option<f32>,
    ) -> Result<Estimate, EstimatorError> {
        if !(alpha.is_finite() && (0.0..=1.0).contains(&alpha)) {
            return Err(EstimatorError::AlphaOutOfRange);
        }
        let mismatch = EstimatorError::Levels(LevelsError::Mismatch);
        if !self.accepts_levels(levels) {
            return Err(mismatch);
        }
        let (i, w, outside) = levels.bracket(alpha).ok_or(mismatch)?;
        let (lo, hi) = self.alpha_range;
        let extrapolated = outside || !(lo..=hi).contains(&alpha);
        let b_pr = levels.blend_b_pr(i, w).ok_or(mismatch)?;
        let fresh = self.levels_alpha.map(f32::to_bits) != Some(alpha.to_bits());
        self.levels_alpha = Some(alpha);
        let b_fl = levels.blend(&levels.b_fl, 0, i, w).ok_or(mismatch)?;
        let at = (position_m, alpha, extrapolated, fresh);
        let lm = levels.lost_motion_at(alpha);
        let lost_motion = lm.as_ref();
        Ok(if levels.neural.1 {
            let k_pr = levels.blend(&levels.k_pr, 2, i, w).ok_or(mismatch)?;
            with_coef_stage!(b_fl, k_pr, b_pr, lost_motion, |stage| self.stage_step(
                &mut stage,
                levels,
                velocity_m_s,
                at
            ))
        } else {
            let k_pr = levels.k_pr_ini;
            with_coef_stage!(b_fl, k_pr, b_pr, lost_motion, |stage| self.stage_step(
                &mut stage,
                levels,
                velocity_m_s,
                at
            ))
        })
    }

    /// One step of bank member `m` on stored level `k` of `levels` (its own tables: a
    /// table-mode estimator at that level): the member's state is restored, stepped and
    /// written back; the shared scalers are not touched. `None` if `levels` cannot drive
    /// this estimator or `k` is not a level.
    #[inline]
    fn step_member_on_level<const T: usize, const L: usize>(
        &mut self,
        levels: &LevelTables<'_, T, L>,
        k: usize,
        m: &mut BankMember,
        velocity_m_s: f32,
        position_m: Option<f32>,
    ) -> Option<Estimate> {
        let own = levels.alphas().get(k)?.to_bits() == m.alpha.to_bits();
        if !(own && self.accepts_levels(levels)) {
            return None;
        }
        let (b_fl, b_pr) = (levels.b_fl.get(k).copied().flatten()?, *levels.b_pr.get(k)?);
        let (lo, hi) = self.alpha_range;
        let at = (position_m, m.alpha, !(lo..=hi).contains(&m.alpha), false);
        self.load_member(m);
        let lm = levels.lost_motion_at(m.alpha);
        let lost_motion = lm.as_ref();
        let e = if levels.neural.1 {
            let k_pr = levels.k_pr.get(k).copied().flatten()?;
            with_coef_stage!(b_fl, k_pr, b_pr, lost_motion, |stage| self.stage_step(
                &mut stage,
                levels,
                velocity_m_s,
                at
            ))
        } else {
            let k_pr = levels.k_pr_ini;
            with_coef_stage!(b_fl, k_pr, b_pr, lost_motion, |stage| self.stage_step(
                &mut stage,
                levels,
                velocity_m_s,
                at
            ))
        };
        self.store_member(m);
        Some(e)
    }

    /// One step with the coefficients of `stage` (table arithmetic, [`Unfused`]) behind the
    /// input and divergence guards of [`Estimator::step`]; `at` = (position, the level for
    /// the static force, whether it is extrapolated, whether the coefficients at the state
    /// are re-read first).
    #[inline(always)]
    fn stage_step<S: Stage, const T: usize, const L: usize>(
        &mut self,
        stage: &mut S,
        levels: &LevelTables<'_, T, L>,
        velocity_m_s: f32,
        (position_m, alpha, extrapolated, fresh): (Option<f32>, f32, bool, bool),
    ) -> Estimate {
        let mut flags = if extrapolated {
            Flags::ALPHA_EXTRAPOLATED
        } else {
            0
        };
        let u = self.guard_input(velocity_m_s, &mut flags);
        self.diag.steps = self.diag.steps.wrapping_add(1);
        if fresh {
            self.coeffs = stage.coeffs(&self.state);
        }
        let r = self
            .rt
            .emm
            .run::<Unfused, S>(stage, &self.state, &self.coeffs, self.last_u, u);
        if !levels.contains(&r.0) {
            flags |= Flags::OUT_OF_TABLE_DOMAIN;
        }
        let force_n = self.accept_step(r, u, &mut flags, |_, s| stage.coeffs(s));
        self.last_u = u;
        let force_n = self.add_static_force(force_n, position_m, u, alpha, &mut flags);
        Estimate {
            force_n: if force_n.is_finite() { force_n } else { 0.0 },
            flags: Flags(flags),
        }
    }
}

/// What [`LevelTables::check`] measured: the blend against the exact model between the
/// levels, and the ordering of the levels in `alpha`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BlendCheck {
    /// Worst relative error of the blended `b_fl`, `b_pr`, `k_pr` against the exact
    /// scalers (0 for a constant coefficient).
    pub max_rel_error: [f32; 3],
    /// The level `alpha` \[-\] of the worst error over the three.
    pub at_alpha: f32,
    /// Points of the state grid where two neighbouring levels' tables are out of the
    /// declared order (`b_fl` and `k_pr` together).
    pub table_order_violations: usize,
    /// The same count for the exact scalers at the levels (the model's own).
    pub exact_order_violations: usize,
    /// Points compared (states times levels between the levels).
    pub points: usize,
}

impl<const T: usize, const L: usize> LevelTables<'_, T, L> {
    /// Measures the blend against `exact` (an estimator of the same model in
    /// [`EvalMode::Exact`], whose level it changes): at `sub` levels evenly inside each
    /// interval between stored levels and `per_segment` states per table segment across
    /// each table's domain, the relative error of every coefficient; and at the stored
    /// levels, how often neighbouring levels are out of the declared order, in the tables
    /// and in the exact scalers. A host-side check (about `sub (n - 1) per_segment T` exact
    /// evaluations per coefficient).
    pub fn check<const P: usize, const T0: usize>(
        &self,
        exact: &mut Estimator<'_, P, T0>,
        sub: usize,
        per_segment: usize,
    ) -> Result<BlendCheck, EstimatorError> {
        let mismatch = EstimatorError::Levels(LevelsError::Mismatch);
        if exact.mode != EvalMode::Exact || !exact.accepts_levels(self) {
            return Err(mismatch);
        }
        let states = self.check_states(per_segment.max(1)).ok_or(mismatch)?;
        let mut out = BlendCheck::default();
        let alphas = self.alphas();
        for (i, pair) in alphas.windows(2).enumerate() {
            let (a0, a1) = (
                pair.first().copied().unwrap_or(0.0),
                pair.last().copied().unwrap_or(0.0),
            );
            self.check_order(exact, i, &states, &mut out)?;
            for j in 1..=sub {
                let alpha = a0 + (a1 - a0) * j as f32 / (sub + 1) as f32;
                exact.set_alpha(alpha)?;
                for s in states.clone() {
                    let e = exact.rt.emm.coeffs(&s, &mut false);
                    let b = self.coefficients(&s, alpha).ok_or(mismatch)?;
                    let rel = |x: f32, y: f32| {
                        if y != 0.0 {
                            ((x - y) / y).abs()
                        } else {
                            (x - y).abs()
                        }
                    };
                    for (k, r) in [
                        rel(b.b_fl, e.b_fl),
                        rel(b.b_pr, e.b_pr),
                        rel(b.k_pr, e.k_pr),
                    ]
                    .into_iter()
                    .enumerate()
                    {
                        if let Some(w) = out.max_rel_error.get_mut(k) {
                            if r > *w {
                                *w = r;
                                out.at_alpha = alpha;
                            }
                        }
                    }
                    out.points += 1;
                }
            }
        }
        Ok(out)
    }

    /// The states of the check: `per_segment` points per segment across the domains of
    /// `b_fl` (`v_st`) and `k_pr` (`x_pr`), paired by index.
    fn check_states(&self, per_segment: usize) -> Option<impl Iterator<Item = State> + Clone> {
        let (v0, v1) = self.b_fl.first().copied().flatten()?.domain();
        let (x0, x1) = if self.neural.1 {
            self.k_pr.first().copied().flatten()?.domain()
        } else {
            (0.0, 0.0)
        };
        let n = per_segment * T;
        Some((0..=n).map(move |k| {
            let f = k as f32 / n as f32;
            State {
                x_pr_m: x0 + (x1 - x0) * f,
                v_st_m_s: v0 + (v1 - v0) * f,
            }
        }))
    }

    /// Counts, at `states`, where levels `i` and `i + 1` are out of the declared order, in
    /// the tables and in the exact scalers (`exact` is left at level `i + 1`).
    fn check_order<const P: usize, const T0: usize>(
        &self,
        exact: &mut Estimator<'_, P, T0>,
        i: usize,
        states: &(impl Iterator<Item = State> + Clone),
        out: &mut BlendCheck,
    ) -> Result<(), EstimatorError> {
        let mismatch = EstimatorError::Levels(LevelsError::Mismatch);
        let (a0, a1) = (
            *self.alpha.get(i).ok_or(mismatch)?,
            *self.alpha.get(i + 1).ok_or(mismatch)?,
        );
        let wrong = |d: Direction, lo: f32, hi: f32| match d {
            Direction::Decreasing => hi > lo,
            Direction::Increasing => hi < lo,
            Direction::None => false,
        };
        let [d_fl, _, d_k] = self.priors;
        for s in states.clone() {
            let t0 = self.level_coefficients(&s, i).ok_or(mismatch)?;
            let t1 = self.level_coefficients(&s, i + 1).ok_or(mismatch)?;
            exact.set_alpha(a0)?;
            let e0 = exact.rt.emm.coeffs(&s, &mut false);
            exact.set_alpha(a1)?;
            let e1 = exact.rt.emm.coeffs(&s, &mut false);
            let count = |c0: Coefficients, c1: Coefficients| {
                usize::from(wrong(d_fl, c0.b_fl, c1.b_fl))
                    + usize::from(wrong(d_k, c0.k_pr, c1.k_pr))
            };
            out.table_order_violations += count(t0, t1);
            out.exact_order_violations += count(e0, e1);
        }
        Ok(())
    }
}
