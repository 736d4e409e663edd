//! The weight format: one definition, used by the trainer's exporter and by the firmware.
//!
//! ```text
//! +--------------------------- postcard Header ----------------------------+
//! | magic "NEMM" (4 raw bytes) | version (varint u16) | kind (varint)      |
//! | max_scaler_params (varint u32) | body_len (varint u32)                 |
//! +-------------------------------------------------------------------------+
//! | body (body_len bytes): postcard-encoded Model (version-1 fields), then, |
//! | from version 3 on, its condition, alpha branches and provenance, then,  |
//! | from version 4 on, Option<StaticForce>, (from version 5 on)             |
//! | Option<LostMotion>, (from version 7 on) CumulativeScalers, and the      |
//! | tables section (from version 6 on padded, so that its tables lie        |
//! | 4-byte aligned from the blob's start)                                   |
//! +-------------------------------------------------------------------------+
//! | CRC-32 (ISO-HDLC, as zlib / postcard's `use-crc`) of all bytes before,  |
//! | 4 bytes little-endian                                                   |
//! +-------------------------------------------------------------------------+
//! ```
//!
//! # Versions
//!
//! This build writes [`FORMAT_VERSION`] and reads every version from [`OLDEST_FORMAT_VERSION`]
//! on. The body is the version-1 part of the [`Model`] (its fields up to
//! [`Model::body`]); version 2 appended an empty extension (zero bytes, so a version-2 body
//! is a version-1 body); version 3 appends [`Model::condition`] (name, unit, map to
//! `alpha`, declared priors), [`Model::alpha_branches`] and [`Model::provenance`], in this
//! order; version 4 appends two sections after those: first [`Model::static_force`]
//! (`Option<StaticForce>`), then the tables section: precomputed fast-path tables for
//! declared oil-loss levels ([`tables`]; one byte, no levels, in a blob written by
//! [`encode`]); version 5 inserts [`Model::lost_motion`] (`Option<LostMotion>`) between
//! those two; version 6 stores each table as its memory image, 4-byte aligned from the
//! blob's start, so that a blob held aligned (a flash slot) is read in place
//! ([`crate::LevelTables`]); version 7 inserts [`Model::cumulative`]
//! ([`crate::CumulativeScalers`]: two `Option<CumulativeScaler>`, `b_fl` then `k_pr`)
//! between the lost-motion element and the tables section. A blob of an earlier version
//! decodes with the fields it lacks at their defaults ([`crate::Condition::default`], no
//! branches, no provenance, no static force, no lost motion, no cumulative scalers, no
//! tables), which reproduces what those versions meant (the paper's oil loss).
//!
//! The header repeats the model kind and the largest scaler size so that a decoder can refuse
//! a model that does not fit its capacity with a precise error before touching the body; the
//! decoder checks that both agree with the body.
//!
//! Decoding ([`decode`]) never allocates and never panics; checks run in this order and the
//! first failure is returned: length, magic, version, header, length vs. `body_len`, CRC,
//! capacity, body, header/body agreement, then [`Model::validate`] (finite values, shapes,
//! bounds, stability of the configured step).

pub mod tables;

use crate::limits::MAX_TABLE_LEVELS;
use crate::model::{
    AlphaBranches, Condition, CumulativeScalers, Model, ModelError, ModelKind, Provenance,
};
use core::fmt;
use nemm_kernels::lost_motion::LostMotion;
use nemm_kernels::static_force::StaticForce;
use nemm_kernels::table::DEFAULT_TABLE_SEGMENTS;
use nemm_kernels::wire::Writer;
use serde::{Deserialize, Serialize};
use tables::{StoredTables, TableLevel};

// `Model::deserialize_in_place` comes from the derive with serde_derive's
// `deserialize_in_place` feature.

/// Magic bytes at the start of every blob.
pub const MAGIC: [u8; 4] = *b"NEMM";
/// Format version this build writes (and the newest it reads).
pub const FORMAT_VERSION: u16 = 7;
/// Oldest format version this build reads.
pub const OLDEST_FORMAT_VERSION: u16 = 1;
/// The CRC used: CRC-32/ISO-HDLC (the zlib / Ethernet CRC-32).
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
/// Upper bound of the encoded header length in bytes.
pub const MAX_HEADER_LEN: usize = 4 + 3 + 5 + 5 + 5;
/// Length of the CRC trailer in bytes.
pub const CRC_LEN: usize = 4;

/// The blob header (postcard-encoded).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// [`MAGIC`].
    pub magic: [u8; 4],
    /// [`FORMAT_VERSION`].
    pub version: u16,
    /// Kind of the model in the body.
    pub kind: ModelKind,
    /// Parameter count of the largest scaler in the body (0 without scalers).
    pub max_scaler_params: u32,
    /// Length of the body in bytes.
    pub body_len: u32,
}

/// Why a blob was refused. Every variant says what a firmware engineer can do about it in
/// its [`Display`](fmt::Display) text.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DecodeError {
    /// The blob ends before the header, body or CRC does.
    Truncated {
        /// Bytes needed (at least).
        needed: usize,
        /// Bytes present.
        found: usize,
    },
    /// The first four bytes are not `NEMM`.
    BadMagic {
        /// The bytes found.
        found: [u8; 4],
    },
    /// Written by a format version this build cannot read.
    UnsupportedVersion {
        /// Version in the blob.
        found: u16,
        /// Newest version this build reads (it reads every version from
        /// [`OLDEST_FORMAT_VERSION`] up to this one).
        supported: u16,
    },
    /// Bytes after the CRC.
    TrailingBytes {
        /// How many.
        extra: usize,
    },
    /// The CRC does not match: the blob is corrupt.
    CrcMismatch {
        /// CRC stored in the blob.
        stored: u32,
        /// CRC computed over the blob.
        computed: u32,
    },
    /// A scaler needs more parameters than this build can hold.
    OverCapacity {
        /// Parameters needed (largest scaler).
        needed: usize,
        /// Capacity `P` of this build.
        capacity: usize,
    },
    /// The header or body does not parse although the CRC matched (encoder bug or a
    /// different format under the same version).
    Malformed {
        /// Which part.
        part: &'static str,
    },
    /// The decoded model is not acceptable.
    Invalid(ModelError),
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::Truncated { needed, found } => write!(
                f,
                "weights blob is truncated: {found} bytes, needs {needed} (incomplete flash or copy?)"
            ),
            DecodeError::BadMagic { found } => write!(
                f,
                "not a NEMM weights blob: starts with {found:02x?}, expected \"NEMM\" (wrong file or flash address?)"
            ),
            DecodeError::UnsupportedVersion { found, supported } => write!(
                f,
                "weights format version {found} is not supported by this firmware (reads versions \
                 {OLDEST_FORMAT_VERSION} to {supported}); re-export with a matching `nemm` or update \
                 the firmware"
            ),
            DecodeError::TrailingBytes { extra } => write!(
                f,
                "weights blob has {extra} unexpected bytes after its CRC (wrong length passed?)"
            ),
            DecodeError::CrcMismatch { stored, computed } => write!(
                f,
                "weights blob is corrupt: CRC-32 stored {stored:#010x}, computed {computed:#010x}"
            ),
            DecodeError::OverCapacity { needed, capacity } => write!(
                f,
                "model needs {needed} parameters per scaler but this build holds {capacity}; \
                 raise the capacity `P` or export a smaller model"
            ),
            DecodeError::Malformed { part } => {
                write!(f, "weights blob {part} does not parse although its CRC matches")
            }
            DecodeError::Invalid(e) => write!(f, "model rejected: {e}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for DecodeError {}

/// Why a model could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EncodeError {
    /// The model fails [`Model::validate`]; nothing that would be refused is written.
    Invalid(ModelError),
    /// The output buffer is too small.
    BufferTooSmall,
    /// An estimator given for the tables section is not in table mode, does not fit the
    /// model (its tables are not those of the model's neural coefficients on the model's
    /// domain), or there are more than [`MAX_TABLE_LEVELS`].
    Tables,
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EncodeError::Invalid(e) => write!(f, "refusing to export an invalid model: {e}"),
            EncodeError::BufferTooSmall => {
                write!(f, "output buffer too small for the weights blob")
            }
            EncodeError::Tables => write!(
                f,
                "the tables to store must come from table-mode estimators of this model \
                 (at most {} levels)",
                MAX_TABLE_LEVELS
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for EncodeError {}

fn header_for<const P: usize>(model: &Model<P>, body_len: usize) -> Header {
    Header {
        magic: MAGIC,
        version: FORMAT_VERSION,
        kind: model.kind(),
        max_scaler_params: u32::try_from(model.max_scaler_params()).unwrap_or(u32::MAX),
        body_len: u32::try_from(body_len).unwrap_or(u32::MAX),
    }
}

/// Writes (or counts) the body of `model`: the version-1 part, the version-3 fields
/// (condition, alpha branches, provenance: postcard writes a tuple as it writes a struct of
/// those fields), then the version-4 sections: the static force, the lost-motion element
/// (version 5), the cumulative scalers (version 7) and the tables section of `levels`
/// (version 6: after `pad` zero bytes).
fn write_body<const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[TableLevel<'_, T>],
    pad: u8,
    w: &mut Writer<'_>,
) -> Result<(), EncodeError> {
    write_prefix(model, w)?;
    tables::write_section(model, levels, pad, w)
}

/// Writes (or counts) the body of `model` up to its tables section.
fn write_prefix<const P: usize>(model: &Model<P>, w: &mut Writer<'_>) -> Result<(), EncodeError> {
    let too_small = EncodeError::BufferTooSmall;
    w.put(model).ok_or(too_small)?;
    w.put(&(&model.condition, &model.alpha_branches, &model.provenance))
        .ok_or(too_small)?;
    w.put(&model.static_force).ok_or(too_small)?;
    w.put(&model.lost_motion).ok_or(too_small)?;
    w.put(&model.cumulative).ok_or(too_small)?;
    Ok(())
}

/// The layout of the blob of `model` with the tables of `levels`: its header length, its
/// body length and the tables section's padding, chosen so that the section's contents
/// start at a multiple of 4 bytes from the blob's start ([`tables`]). The header's
/// `body_len` is a varint, so its length can depend on the padding: of the paddings
/// `0 ..= 7`, the first that agrees with the header it gives is taken (two candidates per
/// residue, and a varint's length changes at most once over 8 bytes, so one agrees).
fn layout<const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[TableLevel<'_, T>],
) -> Result<(usize, usize, u8), EncodeError> {
    let mut w = Writer::counter();
    write_prefix(model, &mut w)?;
    let prefix = w.len();
    for pad in 0..=tables::MAX_PAD {
        let mut w = Writer::counter();
        write_body(model, levels, pad, &mut w)?;
        let body_len = w.len();
        let header_len = postcard::experimental::serialized_size(&header_for(model, body_len))
            .map_err(|_| EncodeError::BufferTooSmall)?;
        if (header_len + prefix + 1 + usize::from(pad)).is_multiple_of(4) {
            return Ok((header_len, body_len, pad));
        }
    }
    Err(EncodeError::Tables)
}

/// Length in bytes of the blob of `model` (header, body, CRC).
pub fn encoded_len<const P: usize>(model: &Model<P>) -> Result<usize, EncodeError> {
    encoded_len_with_levels::<P, DEFAULT_TABLE_SEGMENTS>(model, &[])
}

/// Length in bytes of the blob of `model` with the tables of `levels`.
pub(crate) fn encoded_len_with_levels<const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[TableLevel<'_, T>],
) -> Result<usize, EncodeError> {
    let (header_len, body_len, _) = layout(model, levels)?;
    Ok(header_len + body_len + CRC_LEN)
}

/// Encodes a validated model into `buf` (at least [`encoded_len`] bytes), with an empty
/// tables section; returns the blob (a prefix of `buf`). A blob with precomputed tables:
/// [`crate::encode_with_tables`].
pub fn encode<'b, const P: usize>(
    model: &Model<P>,
    buf: &'b mut [u8],
) -> Result<&'b [u8], EncodeError> {
    encode_with_levels::<P, DEFAULT_TABLE_SEGMENTS>(model, &[], buf)
}

/// Encodes a validated model with the tables of `levels` (at most [`MAX_TABLE_LEVELS`]).
pub(crate) fn encode_with_levels<'b, const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[TableLevel<'_, T>],
    buf: &'b mut [u8],
) -> Result<&'b [u8], EncodeError> {
    model.validate().map_err(EncodeError::Invalid)?;
    let (header_len, body_len, pad) = layout(model, levels)?;
    let hlen = postcard::to_slice(&header_for(model, body_len), buf)
        .map_err(|_| EncodeError::BufferTooSmall)?
        .len();
    if hlen != header_len {
        return Err(EncodeError::BufferTooSmall);
    }
    let end = hlen
        .checked_add(body_len)
        .ok_or(EncodeError::BufferTooSmall)?;
    let body_area = buf.get_mut(hlen..end).ok_or(EncodeError::BufferTooSmall)?;
    let mut w = Writer::new(body_area);
    write_body(model, levels, pad, &mut w)?;
    if w.len() != body_len {
        return Err(EncodeError::BufferTooSmall);
    }
    let crc = CRC.checksum(buf.get(..end).ok_or(EncodeError::BufferTooSmall)?);
    buf.get_mut(end..end + CRC_LEN)
        .ok_or(EncodeError::BufferTooSmall)?
        .copy_from_slice(&crc.to_le_bytes());
    buf.get(..end + CRC_LEN).ok_or(EncodeError::BufferTooSmall)
}

/// Encodes a validated model into a new vector.
#[cfg(feature = "std")]
pub fn encode_to_vec<const P: usize>(model: &Model<P>) -> Result<std::vec::Vec<u8>, EncodeError> {
    encode_to_vec_with_levels::<P, DEFAULT_TABLE_SEGMENTS>(model, &[])
}

/// [`encode_with_levels`] into a new vector.
#[cfg(feature = "std")]
pub(crate) fn encode_to_vec_with_levels<const P: usize, const T: usize>(
    model: &Model<P>,
    levels: &[TableLevel<'_, T>],
) -> Result<std::vec::Vec<u8>, EncodeError> {
    model.validate().map_err(EncodeError::Invalid)?;
    let mut out = std::vec![0u8; encoded_len_with_levels(model, levels)?];
    let n = encode_with_levels(model, levels, &mut out)?.len();
    out.truncate(n);
    Ok(out)
}

/// A copy of a blob held 4-byte aligned, so that its tables can be read in place
/// ([`crate::LevelTables`]) on the host, where a `Vec<u8>` (a file read into memory) has no
/// alignment guarantee. Dereferences to the blob's bytes.
#[cfg(feature = "std")]
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AlignedBlob {
    words: std::vec::Vec<u32>,
    len: usize,
}

#[cfg(feature = "std")]
impl AlignedBlob {
    /// Copies `blob`.
    pub fn new(blob: &[u8]) -> Self {
        let mut words = std::vec![0u32; blob.len().div_ceil(4)];
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
        if let Some(to) = bytes.get_mut(..blob.len()) {
            to.copy_from_slice(blob);
        }
        Self {
            words,
            len: blob.len(),
        }
    }

    /// The blob's bytes, 4-byte aligned.
    pub fn as_bytes(&self) -> &[u8] {
        let bytes: &[u8] = bytemuck::cast_slice(&self.words);
        bytes.get(..self.len).unwrap_or(&[])
    }
}

#[cfg(feature = "std")]
impl core::ops::Deref for AlignedBlob {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        self.as_bytes()
    }
}

/// Reads only the header (after checking magic and version), without the CRC or body.
/// Useful to report what a blob holds before decoding it into a capacity.
pub fn read_header(blob: &[u8]) -> Result<Header, DecodeError> {
    let magic = blob.get(..4).ok_or(DecodeError::Truncated {
        needed: 4,
        found: blob.len(),
    })?;
    if magic != MAGIC {
        let mut found = [0u8; 4];
        found.copy_from_slice(magic);
        return Err(DecodeError::BadMagic { found });
    }
    let ((_magic, version), _) = postcard::take_from_bytes::<([u8; 4], u16)>(blob)
        .map_err(|e| parse_error(e, blob.len(), "header"))?;
    if !(OLDEST_FORMAT_VERSION..=FORMAT_VERSION).contains(&version) {
        return Err(DecodeError::UnsupportedVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let (header, _) = postcard::take_from_bytes::<Header>(blob)
        .map_err(|e| parse_error(e, blob.len(), "header"))?;
    Ok(header)
}

fn parse_error(e: postcard::Error, len: usize, part: &'static str) -> DecodeError {
    match e {
        postcard::Error::DeserializeUnexpectedEnd => DecodeError::Truncated {
            needed: len.saturating_add(1),
            found: len,
        },
        _ => DecodeError::Malformed { part },
    }
}

/// Decodes and validates a blob into a model with scaler capacity `P`, returned by value.
/// The blob's tables section is checked but its index is not kept: a table-mode estimator
/// that should read the stored tables needs [`decode_with_tables`] or [`decode_into`].
///
/// Convenient on the host; on a microcontroller prefer [`decode_into`] with a `static`
/// model, which does not build the model on the stack.
pub fn decode<const P: usize>(blob: &[u8]) -> Result<Model<P>, DecodeError> {
    decode_with_tables(blob).map(|(model, _)| model)
}

/// [`decode`], and beside the model the index of the blob's precomputed tables (empty for
/// a blob without tables), for [`crate::Estimator::load_with_tables`].
pub fn decode_with_tables<const P: usize>(
    blob: &[u8],
) -> Result<(Model<P>, StoredTables), DecodeError> {
    let mut model = Model::empty();
    let tables = decode_into(blob, &mut model)?;
    Ok((model, tables))
}

/// A blob's frame as [`check_frame`] found it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame<'a> {
    /// The header.
    pub header: Header,
    /// Bytes of the header.
    pub header_len: usize,
    /// The CRC-covered part of the blob (header and body).
    pub covered: &'a [u8],
    /// The CRC-32 trailer (checked).
    pub crc: u32,
}

/// The checks of [`decode_into`] that need no model, in its order: length, magic, version,
/// header, length against the header ([`DecodeError::Truncated`],
/// [`DecodeError::TrailingBytes`]), CRC, and the largest scaler against the capacity
/// `capacity` ([`DecodeError::OverCapacity`]).
pub fn check_frame(blob: &[u8], capacity: usize) -> Result<Frame<'_>, DecodeError> {
    let header = read_header(blob)?;
    let (_, after_header) = postcard::take_from_bytes::<Header>(blob)
        .map_err(|e| parse_error(e, blob.len(), "header"))?;
    let header_len = blob.len() - after_header.len();
    let body_len = header.body_len as usize;
    let total = header_len.saturating_add(body_len).saturating_add(CRC_LEN);
    if blob.len() < total {
        return Err(DecodeError::Truncated {
            needed: total,
            found: blob.len(),
        });
    }
    if blob.len() > total {
        return Err(DecodeError::TrailingBytes {
            extra: blob.len() - total,
        });
    }
    let (covered, crc_bytes) = blob.split_at(total - CRC_LEN);
    let mut stored = [0u8; CRC_LEN];
    stored.copy_from_slice(crc_bytes);
    let stored = u32::from_le_bytes(stored);
    let computed = CRC.checksum(covered);
    if stored != computed {
        return Err(DecodeError::CrcMismatch { stored, computed });
    }
    let needed = header.max_scaler_params as usize;
    if needed > capacity {
        return Err(DecodeError::OverCapacity { needed, capacity });
    }
    Ok(Frame {
        header,
        header_len,
        covered,
        crc: stored,
    })
}

/// Decodes and validates a blob **in place** into `model` (e.g. a `static`): the large
/// parameter vectors are written where they live, so the stack holds at most one scaler's
/// parameter vector at a time instead of several copies of the whole model.
///
/// On error `model` holds unspecified, possibly partial contents: it must not be used (an
/// [`crate::Estimator`] built from it would refuse it anyway, since it re-validates).
///
/// Returns the index of the blob's precomputed tables (empty for a blob without tables), a
/// few dozen bytes: the tables themselves stay in the blob, and
/// [`crate::Estimator::load_with_tables`] reads them from there.
pub fn decode_into<const P: usize>(
    blob: &[u8],
    model: &mut Model<P>,
) -> Result<StoredTables, DecodeError> {
    let Frame {
        header,
        header_len,
        covered,
        crc: stored,
    } = check_frame(blob, P)?;
    let needed = header.max_scaler_params as usize;
    let body = covered
        .get(header_len..)
        .ok_or(DecodeError::Malformed { part: "body" })?;
    let mut de = postcard::Deserializer::from_bytes(body);
    Model::<P>::deserialize_in_place(&mut de, model)
        .map_err(|_| DecodeError::Malformed { part: "body" })?;
    let rest = de
        .finalize()
        .map_err(|_| DecodeError::Malformed { part: "body" })?;
    // Version 2 added no fields (zero bytes); version 3 the condition, the alpha branches
    // and the provenance, one after another (as a struct of them). In place too: the
    // branches hold parameter vectors.
    let rest = if header.version >= 3 {
        let malformed = |_| DecodeError::Malformed { part: "extension" };
        let mut de = postcard::Deserializer::from_bytes(rest);
        Condition::deserialize_in_place(&mut de, &mut model.condition).map_err(malformed)?;
        AlphaBranches::deserialize_in_place(&mut de, &mut model.alpha_branches)
            .map_err(malformed)?;
        Provenance::deserialize_in_place(&mut de, &mut model.provenance).map_err(malformed)?;
        de.finalize().map_err(malformed)?
    } else {
        model.condition = Condition::default();
        model.alpha_branches = AlphaBranches::default();
        model.provenance = Provenance::empty();
        rest
    };
    // Version 4's sections after the version-3 fields: the static force (in place), then
    // the tables section (an index of it; the tables stay in the blob).
    let mut tables = StoredTables::EMPTY;
    let rest = if header.version >= 4 {
        let mut de = postcard::Deserializer::from_bytes(rest);
        Option::<StaticForce>::deserialize_in_place(&mut de, &mut model.static_force).map_err(
            |_| DecodeError::Malformed {
                part: "static_force",
            },
        )?;
        let rest = de.finalize().map_err(|_| DecodeError::Malformed {
            part: "static_force",
        })?;
        // Version 5: the lost-motion element between the static force and the tables.
        let rest = if header.version >= 5 {
            let malformed = |_| DecodeError::Malformed {
                part: "lost_motion",
            };
            let mut de = postcard::Deserializer::from_bytes(rest);
            model.lost_motion = Option::<LostMotion>::deserialize(&mut de).map_err(malformed)?;
            de.finalize().map_err(malformed)?
        } else {
            model.lost_motion = None;
            rest
        };
        // Version 7: the cumulative scalers between the lost-motion element and the tables
        // (in place: they hold parameter vectors).
        let rest = if header.version >= 7 {
            let malformed = |_| DecodeError::Malformed { part: "cumulative" };
            let mut de = postcard::Deserializer::from_bytes(rest);
            CumulativeScalers::deserialize_in_place(&mut de, &mut model.cumulative)
                .map_err(malformed)?;
            de.finalize().map_err(malformed)?
        } else {
            model.cumulative = CumulativeScalers::NONE;
            rest
        };
        let neural = tables::neural(model);
        tables
            .read(rest, covered, stored, neural, header.version)
            .ok_or(DecodeError::Malformed { part: "tables" })?
    } else {
        model.static_force = None;
        model.lost_motion = None;
        model.cumulative = CumulativeScalers::NONE;
        rest
    };
    if !rest.is_empty() || model.kind() != header.kind || model.max_scaler_params() != needed {
        return Err(DecodeError::Malformed { part: "body" });
    }
    model.validate().map_err(DecodeError::Invalid)?;
    Ok(tables)
}
