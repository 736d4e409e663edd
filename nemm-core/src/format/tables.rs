//! The `tables` section of the weight format (version 4 on): fast-path tables precomputed
//! by the exporter for declared oil-loss levels, so that a firmware in
//! [`crate::EvalMode::Table`] boots without building them, and an observer or an estimator
//! with a level per sample reads every level's tables in place ([`crate::LevelTables`]).
//!
//! # Layout (version 6 on, after the lost-motion element and, from version 7, the
//! cumulative scalers)
//!
//! ```text
//! pad: u8                                0 ..= 7, then `pad` zero bytes, so that what
//!                                        follows starts at a multiple of 4 from the blob's start
//! levels: u32 LE                         0 ..= MAX_TABLE_LEVELS
//! per level:
//!   alpha: f32                           the oil-loss level the tables are built at [-]
//!   segments: u32 LE                     `T` of the `Estimator<P, T>` that built them
//!   max_rel_error, domain_margin: f32    the TableConfig they were built and checked with
//!   present: u32 LE                      bit 0: a `b_fl` table, bit 1: a `k_pr` table
//!                                        (exactly the model's neural scalers)
//!   the `b_fl` table, then the `k_pr` table, each present one as its image:
//!     lo, hi, cell_scale, cell_offset: f32   the domain [m/s or m] and the lookup scalars
//!     first: 2 x segments x u16 LE           the lookup cells
//!     segments x [x0, 1/width, c0, c1, c2, c3]: 6 x f32
//!     max_rel_error, at: f32; kinks, max_knots_per_cell: u32 LE   the measured accuracy
//! ```
//!
//! Every field is 4 bytes (the cells come in pairs), so every table image starts 4-byte
//! aligned from the blob's start: the image is the table's memory layout
//! ([`nemm_kernels::table::Table1D::write_image`], `32 + 28 T` bytes), and a blob held
//! 4-byte aligned (a flash slot, a `u32` buffer) is read in place
//! ([`nemm_kernels::table::Table1D::in_place`]) instead of copied.
//!
//! Versions 4 and 5 stored, with varints for `segments` and `levels` and a presence byte
//! per table, the scalars, the accuracy and the segments only (the lookup cells recomputed
//! on reading), unaligned: such blobs decode, and a table-mode estimator copies their
//! tables ([`StoredLayout::Segments`]); level tables read in place need a version-6 blob
//! ([`crate::LevelsError::Layout`]).
//!
//! The tables are written from estimators that built them ([`crate::encode_with_tables`]),
//! so they are the estimator's tables bit for bit. A blob without tables (every version up
//! to 3, or a blob exported without levels) holds no levels.
//!
//! # Decoding: an index, not a copy
//!
//! [`crate::format::decode_into`] parses and checks the whole section (every value finite,
//! knots in order, alpha in `[0, 1]`, a valid [`TableConfig`], a table for exactly the neural
//! coefficients of the model, zero padding to the 4-byte boundary) and returns only this index beside the model ([`StoredTables`]:
//! per level its alpha, segment count, configuration and where its tables lie in the blob),
//! a few hundred bytes. The tables themselves stay in the blob (on a
//! microcontroller: in flash) and are read straight into the estimator's own tables by
//! [`crate::Estimator::load_with_tables`], which therefore takes the index and the blob as
//! well as the model. A model's RAM does not grow with the tables.
//!
//! # Matching
//!
//! [`crate::Estimator::load_with_tables`] uses a level when its alpha, its segment count and
//! its table configuration are bit for bit those the estimator is loaded with, the blob is
//! the one the model was decoded from (length and CRC), and each table's domain is the one
//! the estimator would build. Otherwise the stored tables are **ignored**, not refused: the
//! estimator builds its tables as without them and says why in
//! [`crate::estimator::TableOrigin::Built`] ([`StoredUnused`]), which a firmware reports.
//! A mismatch is a configuration choice (another alpha, another segment count), not a fault
//! of the blob: a corrupt section never gets this far, its blob is refused by the CRC or by
//! the section's checks with [`crate::DecodeError::Malformed`] `{ part: "tables" }`.
//!
//! [`crate::Estimator::set_alpha`] rebuilds the tables as without a section.

use super::{EncodeError, CRC_LEN};
use crate::limits::MAX_TABLE_LEVELS;
use crate::model::{Body, Model};
use core::fmt;
use nemm_kernels::table::{self, StoredLayout, Table1D, TableAccuracy, TableConfig, MIN_SEGMENTS};
use nemm_kernels::wire::Writer;

/// Where one stored table lies in its blob, and what it says of itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StoredTable {
    /// Byte offset of the table in the blob.
    pub offset: u32,
    /// The table's domain `[lo, hi]` (m/s for `b_fl`, m for `k_pr`).
    pub domain: (f32, f32),
    /// The accuracy measured when it was built.
    pub accuracy: TableAccuracy,
    /// How it is stored: its image (version 6, readable in place) or its segments.
    pub layout: StoredLayout,
}

/// Most zero bytes before the contents of a version-6 tables section.
pub(crate) const MAX_PAD: u8 = 7;

/// The tables of one oil-loss level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StoredLevel {
    /// The oil-loss level `alpha` \[-\] the tables were built at.
    pub alpha: f32,
    /// Segments per table (`T` of the estimator that built them).
    pub segments: u32,
    /// The configuration they were built and checked with.
    pub config: TableConfig,
    /// The table of `b_fl(v_st)` (if the model has that scaler).
    pub b_fl: Option<StoredTable>,
    /// The table of `k_pr(x_pr)` (if the model has that scaler).
    pub k_pr: Option<StoredTable>,
}

/// The index of a blob's tables section, returned beside the model by
/// [`crate::decode_into`] and [`crate::decode_with_tables`]: empty for a blob without
/// tables.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StoredTables {
    /// The stored levels, in the blob's order.
    pub levels: heapless::Vec<StoredLevel, MAX_TABLE_LEVELS>,
    /// Length of the blob the levels lie in (bytes; 0 without levels).
    pub blob_len: u32,
    /// CRC-32 trailer of that blob (0 without levels).
    pub blob_crc: u32,
}

/// Why an estimator in table mode built its tables instead of reading stored ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoredUnused {
    /// Loaded without a blob ([`crate::Estimator::load`]), or re-built by
    /// [`crate::Estimator::set_alpha`].
    NotOffered,
    /// The blob holds no tables (format version 3 or earlier, or exported without levels).
    NoLevels,
    /// No stored level has the estimator's alpha.
    Alpha,
    /// A level has the estimator's alpha but another segment count.
    Segments {
        /// Segments of the stored tables.
        stored: u32,
        /// Segments of this estimator (`T`).
        capacity: u32,
    },
    /// A level has the alpha and segment count but another table configuration (bound or
    /// domain margin).
    Config,
    /// The blob is not the one the model was decoded from (length or CRC differ).
    OtherBlob,
    /// A stored table's domain differs from the one the estimator builds (other input
    /// scales), or it does not read back.
    Table,
}

impl StoredUnused {
    /// A short name for report lines: `not-offered`, `no-levels`, `alpha`, `segments`,
    /// `config`, `other-blob`, `table`.
    pub const fn name(&self) -> &'static str {
        match self {
            StoredUnused::NotOffered => "not-offered",
            StoredUnused::NoLevels => "no-levels",
            StoredUnused::Alpha => "alpha",
            StoredUnused::Segments { .. } => "segments",
            StoredUnused::Config => "config",
            StoredUnused::OtherBlob => "other-blob",
            StoredUnused::Table => "table",
        }
    }
}

impl fmt::Display for StoredUnused {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StoredUnused::NotOffered => write!(f, "no stored tables offered"),
            StoredUnused::NoLevels => write!(f, "the blob holds no tables"),
            StoredUnused::Alpha => write!(f, "no stored tables at this alpha"),
            StoredUnused::Segments { stored, capacity } => write!(
                f,
                "stored tables have {stored} segments, the estimator {capacity}"
            ),
            StoredUnused::Config => write!(
                f,
                "stored tables were built with another error bound or domain margin"
            ),
            StoredUnused::OtherBlob => write!(f, "the blob is not the one the model came from"),
            StoredUnused::Table => write!(f, "a stored table does not match the model's domain"),
        }
    }
}

impl StoredTables {
    /// No levels; `const`, for [`crate::Model::empty`].
    pub const EMPTY: StoredTables = StoredTables {
        levels: heapless::Vec::new(),
        blob_len: 0,
        blob_crc: 0,
    };

    /// The level that a table-mode estimator at `alpha` with table configuration `tc` and
    /// `segments` segments uses from `blob`, or why there is none.
    pub fn find(
        &self,
        alpha: f32,
        tc: &TableConfig,
        segments: usize,
        blob: &[u8],
    ) -> Result<&StoredLevel, StoredUnused> {
        if self.levels.is_empty() {
            return Err(StoredUnused::NoLevels);
        }
        if u32::try_from(blob.len()).ok() != Some(self.blob_len)
            || trailer(blob) != Some(self.blob_crc)
        {
            return Err(StoredUnused::OtherBlob);
        }
        let mut why = StoredUnused::Alpha;
        for level in &self.levels {
            if level.alpha.to_bits() != alpha.to_bits() {
                continue;
            }
            if usize::try_from(level.segments).ok() != Some(segments) {
                why = StoredUnused::Segments {
                    stored: level.segments,
                    capacity: u32::try_from(segments).unwrap_or(u32::MAX),
                };
                continue;
            }
            if level.config.max_rel_error.to_bits() != tc.max_rel_error.to_bits()
                || level.config.domain_margin.to_bits() != tc.domain_margin.to_bits()
            {
                why = StoredUnused::Config;
                continue;
            }
            return Ok(level);
        }
        Err(why)
    }

    /// Parses and checks a tables section at the start of `bytes` into `self` (module
    /// docs); `covered` is the CRC-covered part of the blob that `bytes` is a suffix of
    /// (offsets are taken from its start), `crc` the blob's trailer; `b_fl` / `k_pr`: whether
    /// the model has those scalers; `version` the blob's format version (4 or later).
    /// Returns the bytes after the section.
    pub(crate) fn read<'a>(
        &mut self,
        bytes: &'a [u8],
        covered: &[u8],
        crc: u32,
        (b_fl, k_pr): (bool, bool),
        version: u16,
    ) -> Option<&'a [u8]> {
        // Without levels the index is empty (equal to a model's not decoded from a blob).
        *self = StoredTables::EMPTY;
        let image = version >= 6;
        let (n, mut rest) = if image {
            take_u32(aligned_contents(bytes, covered)?)?
        } else {
            postcard::take_from_bytes::<u32>(bytes).ok()?
        };
        if usize::try_from(n).ok()? > MAX_TABLE_LEVELS {
            return None;
        }
        for _ in 0..n {
            let ((alpha, segments, config), r) = if image {
                let ((alpha, segments), r) =
                    postcard::take_from_bytes::<(f32, [u8; 4])>(rest).ok()?;
                let ((max_rel_error, domain_margin), r) =
                    postcard::take_from_bytes::<(f32, f32)>(r).ok()?;
                let (present, r) = take_u32(r)?;
                if present != u32::from(b_fl) | (u32::from(k_pr) << 1) {
                    return None;
                }
                let config = TableConfig {
                    max_rel_error,
                    domain_margin,
                };
                ((alpha, u32::from_le_bytes(segments), config), r)
            } else {
                let ((alpha, segments, max_rel_error, domain_margin), r) =
                    postcard::take_from_bytes::<(f32, u32, f32, f32)>(rest).ok()?;
                let config = TableConfig {
                    max_rel_error,
                    domain_margin,
                };
                ((alpha, segments, config), r)
            };
            let n_seg = usize::try_from(segments).ok()?;
            let valid = alpha.is_finite()
                && (0.0..=1.0).contains(&alpha)
                && (MIN_SEGMENTS..=usize::from(u16::MAX)).contains(&n_seg)
                && config.is_valid();
            if !valid {
                return None;
            }
            let table = |r, present| match image {
                true => read_image(r, covered, n_seg, present),
                false => read_table(r, covered, n_seg, present),
            };
            let (b_fl_table, r) = table(r, b_fl)?;
            let (k_pr_table, r) = table(r, k_pr)?;
            rest = r;
            self.levels
                .push(StoredLevel {
                    alpha,
                    segments,
                    config,
                    b_fl: b_fl_table,
                    k_pr: k_pr_table,
                })
                .ok()?;
        }
        if n > 0 {
            self.blob_len = u32::try_from(covered.len().checked_add(CRC_LEN)?).ok()?;
            self.blob_crc = crc;
        }
        Some(rest)
    }
}

/// The contents of a version-6 section at the start of `bytes` (a suffix of `covered`):
/// after its padding byte and that many zeros, which must bring them to a multiple of 4
/// bytes from the blob's start.
fn aligned_contents<'a>(bytes: &'a [u8], covered: &[u8]) -> Option<&'a [u8]> {
    let (&pad, rest) = bytes.split_first()?;
    if pad > MAX_PAD {
        return None;
    }
    let (zeros, rest) = rest.split_at_checked(usize::from(pad))?;
    let at = covered.len().checked_sub(rest.len())?;
    (zeros.iter().all(|&b| b == 0) && at.is_multiple_of(4)).then_some(rest)
}

/// A `u32`, little-endian, at the start of `bytes`.
fn take_u32(bytes: &[u8]) -> Option<(u32, &[u8])> {
    let (b, rest) = bytes.split_first_chunk::<4>()?;
    Some((u32::from_le_bytes(*b), rest))
}

/// One table image of a level, if `present` ([`table::parse_image`]).
fn read_image<'a>(
    bytes: &'a [u8],
    covered: &[u8],
    segments: usize,
    present: bool,
) -> Option<(Option<StoredTable>, &'a [u8])> {
    if !present {
        return Some((None, bytes));
    }
    let offset = u32::try_from(covered.len().checked_sub(bytes.len())?).ok()?;
    let (head, after) = table::parse_image(bytes, segments)?;
    let t = StoredTable {
        offset,
        domain: head.domain,
        accuracy: head.accuracy,
        layout: StoredLayout::Image,
    };
    Some((Some(t), after))
}

/// One optional table of a level: its presence byte must say `expected`.
fn read_table<'a>(
    bytes: &'a [u8],
    covered: &[u8],
    segments: usize,
    expected: bool,
) -> Option<(Option<StoredTable>, &'a [u8])> {
    let (present, rest) = postcard::take_from_bytes::<u8>(bytes).ok()?;
    match (present, expected) {
        (0, false) => Some((None, rest)),
        (1, true) => {
            let offset = u32::try_from(covered.len().checked_sub(rest.len())?).ok()?;
            let (head, after) = table::parse_stored(rest, segments, |_, _| {})?;
            let t = StoredTable {
                offset,
                domain: head.domain,
                accuracy: head.accuracy,
                layout: StoredLayout::Segments,
            };
            Some((Some(t), after))
        }
        _ => None,
    }
}

/// The CRC trailer of a blob.
fn trailer(blob: &[u8]) -> Option<u32> {
    let at = blob.len().checked_sub(CRC_LEN)?;
    let bytes: [u8; 4] = blob.get(at..)?.try_into().ok()?;
    Some(u32::from_le_bytes(bytes))
}

/// Which neural coefficients `model` has: `(b_fl, k_pr)`.
pub(crate) fn neural<const P: usize>(model: &Model<P>) -> (bool, bool) {
    match &model.body {
        Body::Sem(_) | Body::LinearEmm(_) => (false, false),
        Body::NemmLight { .. } => (true, false),
        Body::Nemm { .. } => (true, true),
    }
}

/// What the tables section stores of one oil-loss level: the tables a table-mode estimator
/// built at `alpha` with the configuration `config` (`crate::Estimator::table_level`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct TableLevel<'a, const T: usize> {
    /// The oil-loss level \[-\].
    pub alpha: f32,
    /// The configuration the tables were built and checked with.
    pub config: TableConfig,
    /// The table of `b_fl`, if the model has a `b_fl` scaler.
    pub b_fl: Option<&'a Table1D<T>>,
    /// The table of `k_pr`, if the model has a `k_pr` scaler.
    pub k_pr: Option<&'a Table1D<T>>,
}

/// Writes (or counts) the version-6 tables section of `levels` for `model` after `pad`
/// zero bytes (module docs; the caller chooses `pad` so that the contents are 4-byte
/// aligned from the blob's start).
pub(crate) fn write_section<const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[TableLevel<'_, T>],
    pad: u8,
    w: &mut Writer<'_>,
) -> Result<(), EncodeError> {
    if levels.len() > MAX_TABLE_LEVELS || pad > MAX_PAD {
        return Err(EncodeError::Tables);
    }
    let too_small = EncodeError::BufferTooSmall;
    w.put(&pad).ok_or(too_small)?;
    for _ in 0..pad {
        w.put(&0u8).ok_or(too_small)?;
    }
    let n = u32::try_from(levels.len()).map_err(|_| EncodeError::Tables)?;
    w.put(&n.to_le_bytes()).ok_or(too_small)?;
    let (has_b_fl, has_k_pr) = neural(model);
    let present = u32::from(has_b_fl) | (u32::from(has_k_pr) << 1);
    let sc = &model.scales;
    for &TableLevel {
        alpha,
        config: tc,
        b_fl,
        k_pr,
    } in levels
    {
        let segments = u32::try_from(T).map_err(|_| EncodeError::Tables)?;
        w.put(&(
            alpha,
            segments.to_le_bytes(),
            tc.max_rel_error,
            tc.domain_margin,
        ))
        .ok_or(too_small)?;
        w.put(&present.to_le_bytes()).ok_or(too_small)?;
        for (table, present, scale) in [
            (b_fl, has_b_fl, sc.velocity_m_s),
            (k_pr, has_k_pr, sc.x_pr_m),
        ] {
            match table {
                Some(t) if present => {
                    let d = tc.domain_margin * scale;
                    let (lo, hi) = t.domain();
                    if lo.to_bits() != (-d).to_bits() || hi.to_bits() != d.to_bits() {
                        return Err(EncodeError::Tables);
                    }
                    t.write_image(w).ok_or(too_small)?;
                }
                None if !present => {}
                _ => return Err(EncodeError::Tables),
            }
        }
    }
    Ok(())
}
