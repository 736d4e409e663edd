//! Tabulated fixed-alpha fast path: each neural coefficient as a 1-D cubic table.
//!
//! On a vehicle the oil-loss level `alpha` is constant for the estimator's lifetime (it
//! changes over months and is reconfigured on service), so for a fixed `alpha` every NEMM
//! coefficient is a function of one state variable: `b_fl(v_st)`, `k_pr(x_pr)`, and `b_pr` a
//! constant. [`Table1D`] replaces the 5-layer MLP behind such a function by a piecewise cubic
//! with knots at the MLP's kinks; nemm-core's `Estimator` uses it in `EvalMode::Table`.
//!
//! # Interpolation: cubic Hermite, knots at the kinks, uniform lookup
//!
//! The scalers are smooth (LayerNorm and sigmoid) except at the kinks of their LeakyReLUs,
//! where the slope jumps. Between kinks cubic Hermite converges as `h^4`; across a kink every
//! piecewise polynomial on fixed knots is only `O(h)` times the slope jump (measured on the
//! example NEMM with 256 uniform segments: 5.3e-3 relative, halving per doubling of `N`). So
//! [`Table1D::compile`]:
//!
//! 1. scans the activation pattern of the MLP (the signs of all LeakyReLU inputs,
//!    [`crate::mlp::CompiledScaler::pattern`], through the [`Tabulate`] trait) on a grid of
//!    [`SCAN_POINTS_PER_SEGMENT`] (16) points per segment and bisects every change to
//!    adjacent floats: a kink, which becomes a knot. Where the pattern at the bisected kink
//!    still differs from the grid point's, the bisection goes on from the kink, so that
//!    kinks of different neurons closer than the grid are all found (without that, a scan
//!    at 128 points per segment missed some: the example NEMM measured 1.8e-5 at 256
//!    segments and 1.17e-4 at 128 instead of 6.5e-6 and 4.8e-5 now, over seven oil-loss
//!    levels);
//! 2. spreads `N - 2` segments about uniformly over the smooth pieces between kinks (at
//!    least one each; [`TableError::TooManyKinks`] if there are more than `N - 3` kinks);
//!    the other two segments hold the constant boundary values (below `lo`, from `hi` on);
//! 3. per piece, takes the exact value at each knot and a slope by central differences (step
//!    `w / 8`), at the piece's ends by one-sided second-order differences, so no slope is
//!    taken across a kink; each segment stores its knot, `1 / width` and the Hermite cubic
//!    as monomial coefficients in `s in [0, 1]` (computed in `f64`);
//! 4. builds a uniform index of `2 N` cells of width `(hi - lo) / (2 N - 2)` over
//!    `[lo - width, hi + width]`: the segment holding each cell's left edge. Segments are
//!    about `(hi - lo) / N` wide, so a cell holds at most one further knot unless two kinks
//!    lie closer than a cell ([`TableAccuracy::max_knots_per_cell`]).
//!
//! An evaluation ([`Table1D::eval_finite`]) is then
//!
//! ```text
//! c = min(x * scale + offset as unsigned (saturating), 2N - 1)    below lo: 0, above hi: 2N - 1
//! i = first[c]
//! while x >= knot[i + 1]: i += 1         the knots inside one cell: usually one comparison
//! s = (x - knot[i]) * inv_width[i]       boundary segments: inv_width = 0, so s = 0
//! p = ((c3 s + c2) s + c1) s + c0        Horner
//! ```
//!
//! with no clamping of its own: a finite input outside the domain lands on a boundary
//! segment and gets the value at `lo` or `hi`. [`Table1D::eval`] adds the domain flag and
//! maps non-finite inputs to the domain's ends. About 30 Cortex-M4F instructions per lookup
//! (nemm-firmware/README.md), against ~1,800 for the exact 16 x 5 scaler. The table is `C1`
//! inside each smooth piece and continuous at the kinks, like the MLP.
//!
//! The Horner evaluation uses plain `f32` multiply and add (not the fused `fma` of the exact
//! path): its rounding, ~1e-7 relative, is three orders below any useful bound, and on the
//! Cortex-M4F it saves the moves of the `asm!` fused multiply-add. For the same reason the
//! estimator's table mode runs the RK step and the EMM with unfused arithmetic
//! ([`crate::math::Unfused`]).
//!
//! # Verified error bound
//!
//! [`Table1D::compile`] evaluates the table and the exact function on a check grid of
//! [`CHECK_POINTS_PER_SEGMENT`] (128) points per segment plus the upper end, i.e. 128 x the
//! table's resolution, and returns the largest relative error `|table - exact| / |exact|`.
//! Where the error exceeds an eighth of the caller's bound (a kink the scan may have missed:
//! one neuron crossing zero twice between two scan points), the neighbourhood (1.5 segments
//! either side) is scanned again at [`REFINE_POINTS_PER_SEGMENT`] (128) points per segment,
//! and if that finds kinks the table is built and checked again (at most 8 rounds). If the
//! error still exceeds the bound the table is refused with [`TableError::ExceedsBound`].
//! The values come from [`Tabulate::value`]: for a scaler its fast kernel (on the
//! Cortex-M4F 1,800 instructions instead of about 10,000 for the portable network with the
//! pattern); only the scan pays for the pattern. Building the two 128-segment tables of
//! the example NEMM on the Cortex-M4F takes 156 M instructions (about 0.9 s at 168 MHz;
//! 948 M before the coarser scan, the fast values and the unfused pattern).
//! Because `F = b_fl q` and `q` depends on the coefficients through ratios, a relative error
//! `e` of one coefficient changes the quasi-static force by at most `e |F|` (the logarithmic
//! sensitivities of `F` to `b_fl` and `k_pr` lie in `[0, 1]`); the force error of a whole
//! run is measured in `tests/table.rs` and `examples/table_error.rs`.
//!
//! # Domain
//!
//! The domain of each table is the training abs-max scale of its input times
//! [`TableConfig::domain_margin`] (default [`DEFAULT_DOMAIN_MARGIN`] = 1.1, symmetric about
//! 0): a run at the training extremes overshoots them slightly in `v_st` and `x_pr`, and the
//! margin keeps such runs inside the table. Outside, the coefficient stays at its boundary
//! value (finite and inside the scaler's bounds: the value at `lo` or `hi`, as if the input
//! were clamped) and the estimator sets `Flags::OUT_OF_TABLE_DOMAIN`.

use crate::mlp::CompiledScaler;
use crate::wire::Writer;
use core::fmt;

mod kinks;
mod stored;

pub use kinks::REFINE_POINTS_PER_SEGMENT;
use kinks::*;
pub use stored::{image_len, parse_image, parse_stored, ImageError, StoredHead, StoredLayout};

/// Default number of segments of a table: 256 (7 KiB per table, 28 bytes per segment).
pub const DEFAULT_TABLE_SEGMENTS: usize = 256;
/// Points of the error check per table segment (the check grid is this much finer than the
/// table).
pub const CHECK_POINTS_PER_SEGMENT: usize = 128;
/// Points of the kink scan per table segment (see [`Table1D::compile`] for the finer scan
/// where the check finds an error over the bound).
pub const SCAN_POINTS_PER_SEGMENT: usize = 16;
/// Default table domain: the training abs-max scale of the input times this factor.
pub const DEFAULT_DOMAIN_MARGIN: f32 = 1.1;
/// Default bound of the relative coefficient error, `1e-4`.
pub const DEFAULT_MAX_REL_ERROR: f32 = 1e-4;

/// How tables are built: the error bound they must meet and their domain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableConfig {
    /// Largest acceptable relative error `|table - exact| / |exact|` of a coefficient on the
    /// check grid (finite, > 0).
    pub max_rel_error: f32,
    /// Table domain: `[-m s, m s]` with `s` the training abs-max scale of the input and `m`
    /// this factor (finite, >= 1e-3).
    pub domain_margin: f32,
}

impl TableConfig {
    /// Tables within `max_rel_error` on the default domain.
    pub const fn new(max_rel_error: f32) -> Self {
        Self {
            max_rel_error,
            domain_margin: DEFAULT_DOMAIN_MARGIN,
        }
    }

    /// Whether the bound is finite and positive and the domain margin finite and at least
    /// 1e-3 (what [`check_config`] checks).
    pub fn is_valid(&self) -> bool {
        self.max_rel_error.is_finite()
            && self.max_rel_error > 0.0
            && self.domain_margin.is_finite()
            && self.domain_margin >= 1e-3
    }
}

impl Default for TableConfig {
    fn default() -> Self {
        Self::new(DEFAULT_MAX_REL_ERROR)
    }
}

/// Why a table could not be built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TableError {
    /// The configuration is invalid (bound not finite and positive, margin too small, an
    /// empty or non-finite domain, or zero segments).
    BadConfig,
    /// The exact function or the table is non-finite somewhere on the check grid.
    NonFinite {
        /// Which coefficient.
        scaler: &'static str,
        /// Input where it happened.
        at: f32,
    },
    /// More kinks than the table has segments to separate them.
    TooManyKinks {
        /// Which coefficient.
        scaler: &'static str,
        /// Segments of the table.
        segments: usize,
    },
    /// The measured error exceeds the bound.
    ExceedsBound {
        /// Which coefficient.
        scaler: &'static str,
        /// Measured largest relative error on the check grid.
        max_rel_error: f32,
        /// The bound.
        bound: f32,
        /// Input where the largest error occurs (SI units of the input).
        at: f32,
        /// Segments of the table.
        segments: usize,
    },
}

impl fmt::Display for TableError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TableError::BadConfig => write!(
                f,
                "table configuration: the bound must be finite and positive, the domain margin \
                 at least 1e-3, the domain non-empty and the table at least one segment"
            ),
            TableError::NonFinite { scaler, at } => {
                write!(f, "table of `{scaler}`: non-finite value at input {at:e}")
            }
            TableError::TooManyKinks { scaler, segments } => write!(
                f,
                "table of `{scaler}`: its MLP has more kinks than the {segments} segments can separate"
            ),
            TableError::ExceedsBound {
                scaler,
                max_rel_error,
                bound,
                at,
                segments,
            } => write!(
                f,
                "table of `{scaler}` ({segments} segments): largest relative error {max_rel_error:.2e} \
                 at input {at:e} exceeds the bound {bound:.2e} (use more segments or the exact mode)"
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for TableError {}

/// The measured accuracy of a compiled table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableAccuracy {
    /// Largest relative error on the check grid.
    pub max_rel_error: f32,
    /// Input where it occurs.
    pub at: f32,
    /// Kinks found inside the domain (each made a knot).
    pub kinks: usize,
    /// Most knots inside one lookup cell (the evaluation steps over them one comparison
    /// each; usually one).
    pub max_knots_per_cell: usize,
}

/// Bytes per table segment: 24 for the segment (knot, inverse width, four coefficients), 4
/// for its two lookup cells.
pub const TABLE_BYTES_PER_SEGMENT: usize = 28;

/// Fewest segments of a table: two boundary segments and one inside.
pub const MIN_SEGMENTS: usize = 3;

/// Longest bisection of a kink (f32 has 24 bits of mantissa; 40 halvings reach adjacent
/// floats from any check-grid interval).
const BISECTION_STEPS: usize = 40;

/// A function of one input as `N` cubic Hermite segments (module docs).
///
/// `repr(C)` with the scalars the evaluation reads first: they stay within reach of one
/// base register on the Cortex-M4F.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C)]
pub struct Table1D<const N: usize> {
    lo: f32,
    hi: f32,
    /// Lookup cells per unit input: the `2 N` cells of width `(hi - lo) / (2 N - 2)` cover
    /// `[lo - width, hi + width]`.
    cell_scale: f32,
    /// Cell coordinate of `x = 0`.
    cell_offset: f32,
    /// Per lookup cell (`2 N`, in pairs): the segment holding the cell's left edge. Every
    /// cell holds at most one further knot (checked by `compile`), so one comparison finds
    /// the segment.
    first: [[u16; 2]; N],
    /// Per segment `[x0, 1 / width, c0, c1, c2, c3]`: `p = c0 + c1 s + c2 s^2 + c3 s^3`,
    /// `s = (x - x0) / width`. Segments `0` and `N - 1` are the constant boundary values
    /// below `lo` and from `hi` on (`1 / width = 0`, so `s = 0`); `1 ..= N - 2` tabulate the
    /// domain.
    seg: [[f32; 6]; N],
    accuracy: Accuracy32,
}

/// [`TableAccuracy`] as a table holds it: fixed-width fields, so that a table's memory
/// layout is the same on every target and is its stored image ([`Table1D::write_image`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C)]
struct Accuracy32 {
    max_rel_error: f32,
    at: f32,
    kinks: u32,
    max_knots_per_cell: u32,
}

impl Accuracy32 {
    const ZERO: Self = Self {
        max_rel_error: 0.0,
        at: 0.0,
        kinks: 0,
        max_knots_per_cell: 0,
    };
}

impl From<Accuracy32> for TableAccuracy {
    fn from(a: Accuracy32) -> Self {
        Self {
            max_rel_error: a.max_rel_error,
            at: a.at,
            kinks: a.kinks as usize,
            max_knots_per_cell: a.max_knots_per_cell as usize,
        }
    }
}

impl From<TableAccuracy> for Accuracy32 {
    fn from(a: TableAccuracy) -> Self {
        Self {
            max_rel_error: a.max_rel_error,
            at: a.at,
            kinks: u32::try_from(a.kinks).unwrap_or(u32::MAX),
            max_knots_per_cell: u32::try_from(a.max_knots_per_cell).unwrap_or(u32::MAX),
        }
    }
}

/// The pieces of a table's domain between its breakpoints: `lo`, the kinks (sorted, inside
/// the domain) and `hi`.
#[derive(Debug, Clone, Copy)]
struct Pieces<'k> {
    lo: f64,
    hi: f64,
    kinks: &'k [f64],
}

impl Pieces<'_> {
    /// The number of pieces.
    fn len(&self) -> usize {
        self.kinks.len() + 1
    }

    /// The ends of piece `k`.
    fn get(&self, k: usize) -> (f64, f64) {
        let a = if k == 0 {
            self.lo
        } else {
            self.kinks.get(k - 1).copied().unwrap_or(self.hi)
        };
        let b = self.kinks.get(k).copied().unwrap_or(self.hi);
        (a, b)
    }
}

/// Hermite cubic in `s in [0, 1]` through values `p0`, `p1` with slopes (per unit `s`)
/// `m0`, `m1`, as monomial coefficients.
fn hermite(p0: f64, m0: f64, p1: f64, m1: f64) -> [f64; 4] {
    let d = p1 - p0;
    [p0, m0, 3.0 * d - 2.0 * m0 - m1, -2.0 * d + m0 + m1]
}

/// A function [`Table1D::compile`] can tabulate: its value, and a pattern that identifies the
/// smooth piece an input lies in.
///
/// A closure `FnMut(f32) -> (f32, u64)` returning both is one; a compiled scaler
/// ([`crate::mlp::CompiledScaler`]) is another, which computes the value with its fast
/// kernel and the pattern (the signs of its LeakyReLU inputs) with the portable network, so
/// that only the kink scan pays for the pattern.
pub trait Tabulate {
    /// The function's value at `x`.
    fn value(&mut self, x: f32) -> f32;
    /// Identifies the smooth piece `x` lies in: equal patterns at two inputs mean no kink
    /// between them is known (a smooth function returns a constant).
    fn pattern(&mut self, x: f32) -> u64;
}

impl<F: FnMut(f32) -> (f32, u64)> Tabulate for F {
    fn value(&mut self, x: f32) -> f32 {
        self(x).0
    }
    fn pattern(&mut self, x: f32) -> u64 {
        self(x).1
    }
}

/// Tables of a scaler ([`Table1D::compile`]): the value through
/// [`CompiledScaler::eval`] (the fast kernel where there is one), the pattern through
/// [`CompiledScaler::pattern`] (portable, unfused).
impl<const P: usize> Tabulate for &CompiledScaler<P> {
    fn value(&mut self, x: f32) -> f32 {
        self.eval(x)
    }
    fn pattern(&mut self, x: f32) -> u64 {
        CompiledScaler::pattern(self, x)
    }
}

impl<const N: usize> Table1D<N> {
    /// Tabulates `exact` over `[lo, hi]`, measures the error on the check grid and refuses
    /// the table if it exceeds `max_rel_error` (`scaler` names the coefficient in errors).
    ///
    /// `exact` gives the value and a pattern that identifies the smooth piece `x` lies in
    /// ([`Tabulate`]; for a scaler: [`crate::mlp::CompiledScaler`]; for a smooth function: a
    /// closure returning any constant pattern). A change of the pattern between two points
    /// of the scan grid ([`SCAN_POINTS_PER_SEGMENT`] points per segment) is bisected to the
    /// adjacent floats and becomes a knot, so that no segment straddles a kink.
    pub fn compile(
        exact: impl Tabulate,
        lo: f32,
        hi: f32,
        max_rel_error: f32,
        scaler: &'static str,
    ) -> Result<Self, TableError> {
        let mut t = Self::empty();
        t.compile_into(exact, lo, hi, max_rel_error, scaler)?;
        Ok(t)
    }

    /// A table with no segments: the place to [`compile_into`](Self::compile_into) (every
    /// evaluation returns 0 until then).
    pub const fn empty() -> Self {
        Self {
            lo: 0.0,
            hi: 0.0,
            cell_scale: 0.0,
            cell_offset: 0.0,
            first: [[0; 2]; N],
            seg: [[0.0; 6]; N],
            accuracy: Accuracy32::ZERO,
        }
    }

    /// [`Self::compile`] into `self`, in place (no copy of the table on the stack). After an
    /// error `self` holds a partial table that must be compiled again before use (its
    /// evaluation stays finite and panic-free, but meaningless).
    pub fn compile_into(
        &mut self,
        mut exact: impl Tabulate,
        lo: f32,
        hi: f32,
        max_rel_error: f32,
        scaler: &'static str,
    ) -> Result<(), TableError> {
        if N < MIN_SEGMENTS
            || N > usize::from(u16::MAX)
            || !(lo.is_finite() && hi.is_finite() && hi > lo)
            || !(max_rel_error.is_finite() && max_rel_error > 0.0)
        {
            return Err(TableError::BadConfig);
        }
        let (lo64, hi64) = (f64::from(lo), f64::from(hi));
        let span = hi64 - lo64;
        // 1. Kinks: pattern changes on the scan grid, bisected.
        let mut kinks = Kinks::<N>::new(span);
        scan_kinks(
            &mut exact,
            (lo, hi),
            N * SCAN_POINTS_PER_SEGMENT,
            (lo, hi),
            &mut kinks,
            scaler,
        )?;
        let seg_w = span / (N - 2) as f64;
        // Where the error exceeds this fraction of the bound, a missed kink is suspected.
        let suspect = max_rel_error / REFINE_FRACTION;
        let mut round = 0usize;
        loop {
            self.build(&mut exact, lo, hi, kinks.as_slice(), scaler)?;
            // 5. Error check on the grid CHECK_POINTS_PER_SEGMENT x finer, plus the upper
            //    end; the neighbourhoods of suspect points are rescanned finely.
            let mut ranges = [(0.0f32, 0.0f32); REFINE_RANGES];
            let (n_ranges, worst) = self.check(&mut exact, suspect, seg_w, &mut ranges, scaler)?;
            let mut found = 0usize;
            if round < REFINE_ROUNDS {
                for &(a, b) in ranges.get(..n_ranges).unwrap_or(&[]) {
                    // The density per unit input of REFINE_POINTS_PER_SEGMENT per segment.
                    let n = libm::ceil(f64::from(b - a) / seg_w * REFINE_POINTS_PER_SEGMENT as f64)
                        .max(1.0) as usize;
                    found += scan_kinks(&mut exact, (a, b), n, (lo, hi), &mut kinks, scaler)?;
                }
            }
            round += 1;
            // No further kink found (the error is the smooth pieces', or nothing is
            // suspect): the verdict.
            if found == 0 {
                if worst > f64::from(max_rel_error) {
                    return Err(TableError::ExceedsBound {
                        scaler,
                        max_rel_error: self.accuracy.max_rel_error,
                        bound: max_rel_error,
                        at: self.accuracy.at,
                        segments: N,
                    });
                }
                return Ok(());
            }
        }
    }

    /// Steps 2-4 of [`Self::compile`], into `self`: the segments between the breakpoints `lo`, `kinks`
    /// (sorted, inside the domain) and `hi`, and the lookup cells.
    fn build(
        &mut self,
        exact: &mut impl Tabulate,
        lo: f32,
        hi: f32,
        kinks: &[f64],
        scaler: &'static str,
    ) -> Result<(), TableError> {
        let pieces = Pieces {
            lo: f64::from(lo),
            hi: f64::from(hi),
            kinks,
        };
        // The lookup cells' width.
        let cell_w = (pieces.hi - pieces.lo) / (2 * N - 2) as f64;
        let cell_scale = (1.0 / cell_w) as f32;
        if !(cell_scale.is_finite() && cell_scale > 0.0) {
            return Err(TableError::BadConfig);
        }
        // Segments inside the domain: N - 2.
        if kinks.len() + 1 > N - 2 {
            return Err(TableError::TooManyKinks {
                scaler,
                segments: N,
            });
        }
        let counts = Self::segment_counts(pieces, scaler)?;
        self.lo = lo;
        self.hi = hi;
        self.cell_scale = cell_scale;
        self.cell_offset = (-(pieces.lo - cell_w) / cell_w) as f32;
        self.first.fill([0; 2]);
        self.seg.fill([0.0; 6]);
        self.accuracy = Accuracy32 {
            max_rel_error: 0.0,
            at: lo,
            kinks: u32::try_from(kinks.len()).unwrap_or(u32::MAX),
            max_knots_per_cell: 0,
        };
        self.fill_segments(exact, pieces, &counts, scaler)?;
        self.close_ends();
        // 5. Lookup cells.
        self.accuracy.max_knots_per_cell = u32::try_from(self.fill_cells()).unwrap_or(u32::MAX);
        Ok(())
    }

    /// Step 2 of [`Self::compile`]: the number of segments of each piece, of about uniform
    /// width, at least one per piece, all `N - 2` segments inside the domain in all (the
    /// evaluation then needs no count).
    fn segment_counts(pieces: Pieces<'_>, scaler: &'static str) -> Result<[usize; N], TableError> {
        let real = N - 2;
        let count = |h: f64, k: usize| -> usize {
            let (a, b) = pieces.get(k);
            libm::ceil((b - a) / h - 1e-9).max(1.0) as usize
        };
        let mut h = (pieces.hi - pieces.lo) / real as f64;
        let mut fits = false;
        for _ in 0..4000 {
            if (0..pieces.len()).map(|k| count(h, k)).sum::<usize>() <= real {
                fits = true;
                break;
            }
            h *= 1.01;
        }
        if !fits {
            return Err(TableError::TooManyKinks {
                scaler,
                segments: N,
            });
        }
        // The spare segments go, one at a time, to the piece with the widest segments.
        let mut counts = [0usize; N];
        for (k, c) in counts.iter_mut().enumerate().take(pieces.len()) {
            *c = count(h, k);
        }
        let mut total: usize = counts.iter().sum();
        while total < real {
            let mut widest = (0usize, 0.0f64);
            for (k, &c) in counts.iter().enumerate().take(pieces.len()) {
                let (a, b) = pieces.get(k);
                let w = (b - a) / c.max(1) as f64;
                if w > widest.1 {
                    widest = (k, w);
                }
            }
            match counts.get_mut(widest.0) {
                Some(c) => *c += 1,
                None => return Err(TableError::BadConfig),
            }
            total += 1;
        }
        Ok(counts)
    }

    /// Step 3 of [`Self::compile`]: the Hermite segments of every piece, `counts[k]` of
    /// equal width in piece `k`, from segment 1 on (segment 0 is the boundary value below
    /// `lo`); slopes by central differences inside a piece, one-sided second-order
    /// differences at its ends (never across a kink).
    fn fill_segments(
        &mut self,
        exact: &mut impl Tabulate,
        pieces: Pieces<'_>,
        counts: &[usize; N],
        scaler: &'static str,
    ) -> Result<(), TableError> {
        let mut value = |x: f64| -> Result<f64, TableError> {
            let v = f64::from(exact.value(x as f32));
            if v.is_finite() {
                Ok(v)
            } else {
                Err(TableError::NonFinite {
                    scaler,
                    at: x as f32,
                })
            }
        };
        let mut used = 1usize;
        for k in 0..pieces.len() {
            let (a, b) = pieces.get(k);
            let n = counts.get(k).copied().unwrap_or(1);
            let w = (b - a) / n as f64;
            let d = w / 8.0;
            let mut knot = |i: usize| -> Result<(f64, f64), TableError> {
                let x = if i == n { b } else { a + w * i as f64 };
                let p = value(x)?;
                let slope = if i == 0 {
                    (-3.0 * p + 4.0 * value(x + d)? - value(x + 2.0 * d)?) / (2.0 * d)
                } else if i == n {
                    (3.0 * p - 4.0 * value(x - d)? + value(x - 2.0 * d)?) / (2.0 * d)
                } else {
                    (value(x + d)? - value(x - d)?) / (2.0 * d)
                };
                Ok((p, slope * w))
            };
            let (mut p0, mut m0) = knot(0)?;
            for i in 0..n {
                let (p1, m1) = knot(i + 1)?;
                let c = hermite(p0, m0, p1, m1);
                let x0 = a + w * i as f64;
                let Some(slot) = self.seg.get_mut(used) else {
                    return Err(TableError::BadConfig);
                };
                *slot = [
                    x0 as f32,
                    (1.0 / w) as f32,
                    c[0] as f32,
                    c[1] as f32,
                    c[2] as f32,
                    c[3] as f32,
                ];
                used += 1;
                (p0, m0) = (p1, m1);
            }
        }
        if used != N - 1 {
            return Err(TableError::BadConfig);
        }
        Ok(())
    }

    /// Step 4 of [`Self::compile`]: the boundary segments, constant, the value at `lo` (the
    /// first segment's `c0`) and the table's own value at `hi`, so that clamping is
    /// continuous.
    fn close_ends(&mut self) {
        let (lo, hi) = (self.lo, self.hi);
        let first_c0 = self.seg.get(1).map_or(0.0, |s| s[2]);
        let at_hi = self.segment_value(N - 2, hi);
        if let Some(s) = self.seg.first_mut() {
            *s = [lo, 0.0, first_c0, 0.0, 0.0, 0.0];
        }
        if let Some(s) = self.seg.last_mut() {
            *s = [hi, 0.0, at_hi, 0.0, 0.0, 0.0];
        }
    }

    /// Step 5 of [`Self::compile`]: the lookup cells from the domain and the segments' knots
    /// (the segment holding each cell's left edge; each cell may hold one further knot only:
    /// knots are at least a cell apart by construction, measured). Returns the most knots
    /// inside one cell.
    fn fill_cells(&mut self) -> usize {
        let first = self.first.as_flattened_mut();
        walk_cells::<N>(self.lo, self.hi, &self.seg, |c, i| {
            if let Some(f) = first.get_mut(c) {
                *f = i;
            }
        })
    }

    /// Measures the table against `exact` on the check grid (sets the accuracy) and returns
    /// how many ranges of `bad` it filled: the neighbourhoods (1.5 segment widths `seg_w`
    /// either side, overlapping ones merged) of the check points whose error exceeds
    /// `bound` (the suspect level), at most [`REFINE_RANGES`] of them; and the largest error.
    fn check(
        &mut self,
        exact: &mut impl Tabulate,
        bound: f32,
        seg_w: f64,
        bad: &mut [(f32, f32); REFINE_RANGES],
        scaler: &'static str,
    ) -> Result<(usize, f64), TableError> {
        let (lo64, hi64) = (f64::from(self.lo), f64::from(self.hi));
        let span = hi64 - lo64;
        let mut worst64 = 0.0f64;
        let mut n_bad = 0usize;
        let n_check = N * CHECK_POINTS_PER_SEGMENT;
        self.accuracy.max_rel_error = 0.0;
        self.accuracy.at = self.lo;
        for j in 0..=n_check {
            let x = if j == n_check {
                self.hi
            } else {
                (lo64 + span * j as f64 / n_check as f64) as f32
            };
            let want = exact.value(x);
            let got = self.eval(x, &mut false);
            if !(want.is_finite() && got.is_finite() && want != 0.0) {
                return Err(TableError::NonFinite { scaler, at: x });
            }
            let rel = (f64::from(got) - f64::from(want)).abs() / f64::from(want).abs();
            if rel > worst64 {
                worst64 = rel;
                self.accuracy.max_rel_error = rel as f32;
                self.accuracy.at = x;
            }
            if rel > f64::from(bound) {
                let x64 = f64::from(x);
                let a = (x64 - 1.5 * seg_w).max(lo64) as f32;
                let b = (x64 + 1.5 * seg_w).min(hi64) as f32;
                match n_bad.checked_sub(1).and_then(|k| bad.get_mut(k)) {
                    Some(last) if a <= last.1 => last.1 = b,
                    _ => {
                        if let Some(slot) = bad.get_mut(n_bad) {
                            *slot = (a, b);
                            n_bad += 1;
                        }
                    }
                }
            }
        }
        Ok((n_bad, worst64))
    }

    /// The table at `x`; inputs outside the domain (and NaN) are clamped to it and set
    /// `*out = true` (never cleared).
    #[inline(always)]
    pub fn eval(&self, x: f32, out: &mut bool) -> f32 {
        *out |= !self.contains(x);
        // Non-finite inputs to the domain's ends (NaN to `lo`); finite ones outside the
        // domain land on the boundary segments.
        let x = if x.is_finite() {
            x
        } else if x > 0.0 {
            self.hi
        } else {
            self.lo
        };
        self.eval_finite(x)
    }

    /// True if `x` lies in the domain `[lo, hi]` (false for NaN).
    #[inline(always)]
    pub fn contains(&self, x: f32) -> bool {
        x >= self.lo && x <= self.hi
    }

    /// [`Table1D::eval`] for a finite `x`, without the flag: the same value, about 27
    /// Cortex-M4F instructions. A non-finite `x` gives NaN or an unspecified finite value
    /// (never a panic); the estimator's RK stages use it, whose states are finite.
    #[inline(always)]
    pub fn eval_finite(&self, x: f32) -> f32 {
        // `as` saturates (and maps NaN to 0): below the domain cell 0, above it the last.
        let cell = ((x * self.cell_scale + self.cell_offset) as usize).min(2 * N - 1);
        // `first` is at most `N - 1`; the `min` (which only changes the last cell's `N - 1`
        // to `N - 2`, whose next knot is `hi`) keeps `i + 1` in bounds without a check.
        let mut i = self
            .first
            .as_flattened()
            .get(cell)
            .map_or(0, |&f| usize::from(f))
            .min(N.saturating_sub(2));
        // The knots inside the cell: one comparison, a loop only past the first knot.
        if self.seg.get(i + 1).is_some_and(|next| x >= next[0]) {
            i += 1;
            while self.seg.get(i + 1).is_some_and(|next| x >= next[0]) {
                i += 1;
            }
        }
        self.segment_value(i, x)
    }

    /// Segment `i`'s cubic at `x`.
    #[inline(always)]
    fn segment_value(&self, i: usize, x: f32) -> f32 {
        match self.seg.get(i) {
            Some(&[x0, inv_w, c0, c1, c2, c3]) => {
                let s = (x - x0) * inv_w;
                ((c3 * s + c2) * s + c1) * s + c0
            }
            None => 0.0, // not reached: `i < N`
        }
    }

    /// The domain `[lo, hi]`.
    pub fn domain(&self) -> (f32, f32) {
        (self.lo, self.hi)
    }

    /// The accuracy measured when the table was built.
    pub fn accuracy(&self) -> TableAccuracy {
        self.accuracy.into()
    }

    /// Cubic segments inside the domain (`N - 2`; the other two hold the boundary values).
    pub fn segments_used(&self) -> usize {
        N - 2
    }

    /// Bytes of a table with `N` segments: 24 per segment (knot, inverse width, four
    /// coefficients) and 4 for its two lookup cells, `28 N` (plus a few scalars).
    pub const fn table_bytes() -> usize {
        N * TABLE_BYTES_PER_SEGMENT
    }
}

/// The lookup cells of a table with domain `[lo, hi]` and segments `seg` (step 5 of
/// [`Table1D::compile`]): hands each cell's index and the segment holding its left edge to
/// `each`, in order, and returns the most knots inside one cell.
fn walk_cells<const N: usize>(
    lo: f32,
    hi: f32,
    seg: &[[f32; 6]; N],
    mut each: impl FnMut(usize, u16),
) -> usize {
    let lo64 = f64::from(lo);
    let cell_w = (f64::from(hi) - lo64) / (2 * N - 2) as f64;
    let mut most = 0usize;
    let mut i = 0usize;
    let mut prev = 0usize;
    for c in 0..2 * N {
        let edge = (lo64 - cell_w + cell_w * c as f64) as f32;
        while seg.get(i + 1).is_some_and(|s| s[0] <= edge) {
            i += 1;
        }
        most = most.max(i - prev);
        prev = i;
        each(c, u16::try_from(i).unwrap_or(u16::MAX));
    }
    most
}

/// Checks a configuration (used by the estimator).
pub fn check_config(cfg: &TableConfig) -> Result<(), TableError> {
    if cfg.is_valid() {
        Ok(())
    } else {
        Err(TableError::BadConfig)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinks_stay_sorted_without_near_duplicates_and_refuse_overflow() {
        let mut k = Kinks::<4>::new(1.0);
        for (x, new) in [(0.5, true), (0.1, true), (0.9, true), (0.5 + 1e-7, false)] {
            assert_eq!(k.insert(x, "t"), Ok(new), "{x}");
        }
        assert_eq!(k.as_slice(), &[0.1, 0.5, 0.9]);
        assert_eq!(k.insert(0.3, "t"), Ok(true));
        assert_eq!(k.as_slice(), &[0.1, 0.3, 0.5, 0.9]);
        assert_eq!(
            k.insert(0.7, "t"),
            Err(TableError::TooManyKinks {
                scaler: "t",
                segments: 4
            })
        );
        assert_eq!(k.as_slice(), &[0.1, 0.3, 0.5, 0.9]);
    }

    fn smooth(f: impl Fn(f32) -> f32) -> impl FnMut(f32) -> (f32, u64) {
        move |x| (f(x), 0)
    }

    #[test]
    fn reproduces_a_cubic() {
        // Hermite interpolation is exact for cubics; only the knot slopes err: the central
        // difference of a cubic is off by d^2 f'''(x) / 6 = (1/56)^2 * 0.75 / 6 ~ 4e-5.
        let f = |x: f32| 2.0 + 0.5 * x - 0.25 * x * x + 0.125 * x * x * x;
        let t = Table1D::<16>::compile(smooth(f), -1.0, 1.0, 1e-3, "cubic").unwrap();
        let mut out = false;
        for k in 0..=200 {
            let x = -1.0 + 2.0 * k as f32 / 200.0;
            assert!((t.eval(x, &mut out) - f(x)).abs() < 1e-5, "{x}");
        }
        assert!(!out);
        assert!(t.accuracy().max_rel_error < 1e-5);
        // 16 segments: 14 inside the domain, two for the boundary values.
        assert_eq!((t.segments_used(), t.accuracy().kinks), (14, 0));
    }

    #[test]
    fn error_shrinks_as_h_to_the_fourth() {
        let f = |x: f32| 2.0 + libm::sinf(3.0 * x);
        let e16 = Table1D::<16>::compile(smooth(f), -1.0, 1.0, 1.0, "sin")
            .unwrap()
            .accuracy()
            .max_rel_error;
        let e32 = Table1D::<32>::compile(smooth(f), -1.0, 1.0, 1.0, "sin")
            .unwrap()
            .accuracy()
            .max_rel_error;
        // h^4: 16x smaller; allow 11-22x (finite-difference slopes and rounding).
        let ratio = e16 / e32;
        assert!((11.0..22.0).contains(&ratio), "{e16} {e32} {ratio}");
    }

    #[test]
    fn kinks_become_knots() {
        // Two slope jumps inside cells of a uniform 8-segment grid: with knots at the kinks
        // the pieces are straight lines and the table is exact up to rounding.
        let f = |x: f32| 1.0 + (x - 0.3).abs() + 0.5 * (x + 0.41).abs();
        let pattern = move |x: f32| (f(x), u64::from(x >= 0.3) | (u64::from(x >= -0.41) << 1));
        let t = Table1D::<8>::compile(pattern, -1.0, 1.0, 1e-5, "abs").unwrap();
        assert_eq!(t.accuracy().kinks, 2);
        assert!(t.accuracy().max_rel_error < 1e-6, "{:?}", t.accuracy());
        // The same function without the pattern: the kinks fall inside segments.
        let e = Table1D::<8>::compile(smooth(f), -1.0, 1.0, 1.0, "abs")
            .unwrap()
            .accuracy()
            .max_rel_error;
        assert!(e > 1e-3, "{e}");
    }

    #[test]
    fn refuses_a_table_over_the_bound() {
        let f = |x: f32| 2.0 + libm::sinf(20.0 * x);
        match Table1D::<8>::compile(smooth(f), -1.0, 1.0, 1e-4, "sin") {
            Err(TableError::ExceedsBound {
                scaler,
                max_rel_error,
                bound,
                segments,
                ..
            }) => {
                assert_eq!((scaler, bound, segments), ("sin", 1e-4, 8));
                assert!(max_rel_error > 1e-4);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn refuses_more_kinks_than_segments() {
        // A new piece every 0.1 on [-1, 1]: 19 kinks, 4 segments.
        let p = |x: f32| (1.0 + x * x, (libm::floorf(x * 10.0) as i64) as u64);
        assert_eq!(
            Table1D::<4>::compile(p, -1.0, 1.0, 1.0, "saw"),
            Err(TableError::TooManyKinks {
                scaler: "saw",
                segments: 4
            })
        );
    }

    #[test]
    fn boundary_segments_hold_the_values_at_the_ends() {
        let f = |x: f32| 1.0 + x + 0.3 * x * x;
        let t = Table1D::<32>::compile(smooth(f), -1.0, 2.0, 1e-3, "q").unwrap();
        let (at_lo, at_hi) = (t.eval(-1.0, &mut false), t.eval(2.0, &mut false));
        for x in [
            -1.0000001,
            -1.5,
            -1e30,
            f32::MIN,
            f32::NEG_INFINITY,
            f32::NAN,
        ] {
            assert_eq!(t.eval(x, &mut false).to_bits(), at_lo.to_bits(), "{x}");
        }
        for x in [2.0000002, 7.0, 1e30, f32::MAX, f32::INFINITY] {
            assert_eq!(t.eval(x, &mut false).to_bits(), at_hi.to_bits(), "{x}");
        }
        // The fast evaluation is the same function for every finite input.
        for k in -300..=600 {
            let x = k as f32 / 100.0;
            let mut out = false;
            assert_eq!(
                t.eval(x, &mut out).to_bits(),
                t.eval_finite(x).to_bits(),
                "{x}"
            );
            assert_eq!(out, !(-1.0..=2.0).contains(&x), "{x}");
        }
        assert!(t.accuracy().max_knots_per_cell <= 1);
        assert_eq!(Table1D::<32>::table_bytes(), 32 * 28);
    }

    #[test]
    fn clamps_and_flags_outside() {
        let f = |x: f32| 1.0 + x * x;
        let t = Table1D::<32>::compile(smooth(f), -1.0, 1.0, 1e-3, "sq").unwrap();
        let mut out = false;
        let inside = t.eval(0.999, &mut out);
        assert!(!out && (inside - f(0.999)).abs() < 1e-4);
        for (x, want) in [(5.0, 2.0), (-7.0, 2.0), (f32::INFINITY, 2.0)] {
            let mut out = false;
            let v = t.eval(x, &mut out);
            assert!(out && (v - want).abs() < 1e-5, "{x} {v}");
        }
        let mut out = false;
        assert!(t.eval(f32::NAN, &mut out).is_finite() && out);
    }

    #[test]
    fn bad_configuration_is_refused() {
        let f = |x: f32| (1.0 + x, 0);
        assert_eq!(
            Table1D::<0>::compile(f, 0.0, 1.0, 1e-3, "f"),
            Err(TableError::BadConfig)
        );
        assert_eq!(
            Table1D::<4>::compile(f, 1.0, 1.0, 1e-3, "f"),
            Err(TableError::BadConfig)
        );
        assert_eq!(
            Table1D::<4>::compile(f, 0.0, 1.0, f32::NAN, "f"),
            Err(TableError::BadConfig)
        );
        assert!(matches!(
            Table1D::<4>::compile(|_| (f32::NAN, 0), 0.0, 1.0, 1e-3, "f"),
            Err(TableError::NonFinite { .. })
        ));
    }

    /// The image of a table in a `u32` buffer (4-byte aligned), from byte `at` on.
    fn image_of<const N: usize>(t: &Table1D<N>, at: usize) -> std::vec::Vec<u32> {
        let len = at + Table1D::<N>::IMAGE_LEN;
        let mut words = std::vec![0u32; len.div_ceil(4) + 1];
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
        let mut w = Writer::new(&mut bytes[at..]);
        t.write_image(&mut w).unwrap();
        assert_eq!(w.len(), image_len(N));
        words
    }

    #[test]
    fn the_image_is_the_memory_and_reads_back_in_place_and_as_a_copy() {
        let f = |x: f32| 1.0 + x + 0.3 * x * x;
        let t = Table1D::<32>::compile(smooth(f), -1.0, 2.0, 1e-3, "q").unwrap();
        assert_eq!(Table1D::<32>::IMAGE_LEN, 32 + 28 * 32);
        let words = image_of(&t, 0);
        let bytes: &[u8] = bytemuck::cast_slice(&words);
        // On a little-endian host the image is the table's memory, byte for byte.
        if cfg!(target_endian = "little") {
            assert_eq!(&bytes[..Table1D::<32>::IMAGE_LEN], bytemuck::bytes_of(&t));
            let view = Table1D::<32>::in_place(bytes, -1.0, 2.0).unwrap();
            assert_eq!(view, &t);
            assert!(core::ptr::eq(view as *const _ as *const u8, bytes.as_ptr()));
        }
        let mut copy = Table1D::<32>::empty();
        let rest = copy.read_image(bytes, -1.0, 2.0).unwrap();
        assert_eq!(copy, t);
        assert_eq!(rest.len(), bytes.len() - Table1D::<32>::IMAGE_LEN);
        // Another domain, a short image: refused.
        assert_eq!(
            Table1D::<32>::in_place(bytes, -1.0, 2.5),
            Err(ImageError::Invalid)
        );
        assert_eq!(
            Table1D::<32>::in_place(&bytes[..100], -1.0, 2.0),
            Err(ImageError::Invalid)
        );
        assert!(Table1D::<32>::empty()
            .read_image(&bytes[..100], -1.0, 2.0)
            .is_none());
    }

    #[test]
    fn an_unaligned_image_is_copied_but_not_read_in_place() {
        let f = |x: f32| 2.0 + libm::sinf(3.0 * x);
        let t = Table1D::<16>::compile(smooth(f), -1.0, 1.0, 1e-2, "sin").unwrap();
        let words = image_of(&t, 1);
        let bytes: &[u8] = &bytemuck::cast_slice::<u32, u8>(&words)[1..];
        let want = if cfg!(target_endian = "little") {
            ImageError::Unaligned
        } else {
            ImageError::BigEndian
        };
        assert_eq!(Table1D::<16>::in_place(bytes, -1.0, 1.0), Err(want));
        let mut copy = Table1D::<16>::empty();
        assert!(copy.read_image(bytes, -1.0, 1.0).is_some());
        assert_eq!(copy, t);
    }

    #[test]
    fn a_corrupt_image_is_refused_where_it_is_read() {
        let f = |x: f32| 1.0 + x * x;
        let t = Table1D::<16>::compile(smooth(f), -1.0, 1.0, 1e-2, "sq").unwrap();
        let clean = image_of(&t, 0);
        // A lookup cell pointing at the wrong segment (offset 16 + 2 * cell), a knot out of
        // order (segment 5's knot at 16 + 64 + 24 * 5), a NaN coefficient, a wrong record
        // of knots per cell (the image's last u32): each refused, in place and as a copy.
        let cell = 16 + 2 * 10;
        let knot = 16 + 4 * 16 + 24 * 5;
        let coef = knot + 12;
        let record = Table1D::<16>::IMAGE_LEN - 4;
        let corruptions: [(usize, [u8; 4]); 4] = [
            (cell, [0x0e, 0x00, 0, 0]),
            (knot, 1.0e3f32.to_le_bytes()),
            (coef, f32::NAN.to_le_bytes()),
            (record, 7u32.to_le_bytes()),
        ];
        for (at, put) in corruptions {
            let mut words = clean.clone();
            let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
            let n = if at == cell { 2 } else { 4 };
            bytes[at..at + n].copy_from_slice(&put[..n]);
            let bytes: &[u8] = bytes;
            if cfg!(target_endian = "little") {
                assert_eq!(
                    Table1D::<16>::in_place(bytes, -1.0, 1.0),
                    Err(ImageError::Invalid),
                    "{at}"
                );
            }
            assert!(
                Table1D::<16>::empty()
                    .read_image(bytes, -1.0, 1.0)
                    .is_none(),
                "{at}"
            );
        }
    }
}
