//! A table in the weight format's tables section (nemm-core's `format::tables`): written from
//! a built table as its image, parsed and checked, read back bit for bit (a copy), or read
//! in place; and the segments layout of the format's versions 4 and 5, read back.

use super::*;

/// Bytes of a table's stored image ([`Table1D::write_image`]) with `segments` segments:
/// its memory layout, `32 + 28 segments` (the four lookup scalars, the `2 segments` lookup
/// cells as `u16`, the segments, the accuracy as two `f32` and two `u32`), little-endian.
pub const fn image_len(segments: usize) -> usize {
    32 + TABLE_BYTES_PER_SEGMENT * segments
}

/// How a table is stored in a blob: the format's versions 4 and 5 store its segments
/// ([`parse_stored`]; the lookup cells are recomputed on reading), version 6 its image
/// ([`Table1D::write_image`]), which a 4-byte-aligned blob is read from in place.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoredLayout {
    /// The scalars and the segments (format versions 4 and 5).
    Segments,
    /// The table's memory image, 4-byte aligned from the blob's start (version 6).
    Image,
}

/// Why a stored image cannot be read in place ([`Table1D::in_place`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageError {
    /// The image does not start at a multiple of 4 bytes in memory: the blob is not held
    /// 4-byte aligned.
    Unaligned,
    /// A big-endian target: the little-endian image is not its memory layout.
    BigEndian,
    /// Too few bytes, or the image is not a valid table on the expected domain (values
    /// not finite, knots out of order, lookup cells or accuracy record inconsistent).
    Invalid,
}

/// A table is its memory: every field is `f32`, `u16` or `u32`, so every bit pattern is a
/// value (never UB to read), and the evaluation is panic-free for any contents (every
/// index is checked), which [`Table1D::in_place`] still validates before use.
// SAFETY: `Table1D<N>` is `repr(C)` with fields `[f32; 4]`-like scalars (16 bytes),
// `[[u16; 2]; N]` (4 N bytes, at offset 16), `[[f32; 6]; N]` (24 N bytes, at offset
// 16 + 4 N, a multiple of 4) and `Accuracy32` (`repr(C)`, two `f32` and two `u32`): no
// padding anywhere (checked by `Table1D::IMAGE_LEN`'s assertion, evaluated in
// `in_place`), every bit pattern valid, `Copy` and `'static`.
#[allow(unsafe_code)]
unsafe impl<const N: usize> bytemuck::Zeroable for Table1D<N> {}
// SAFETY: as for `Zeroable` above.
#[allow(unsafe_code)]
unsafe impl<const N: usize> bytemuck::Pod for Table1D<N> {}

impl<const N: usize> Table1D<N> {
    /// Bytes of the image: `size_of::<Self>()`, asserted (at compile time, where used) to be
    /// [`image_len`]`(N)`, i.e. the layout has no padding.
    pub const IMAGE_LEN: usize = {
        assert!(core::mem::size_of::<Self>() == image_len(N));
        assert!(core::mem::align_of::<Self>() == 4);
        image_len(N)
    };

    /// Writes the table's image ([`image_len`] bytes): its memory layout, little-endian,
    /// which [`Self::in_place`] reads back without a copy.
    pub fn write_image(&self, w: &mut Writer<'_>) -> Option<()> {
        let start = w.len();
        w.put(&[self.lo, self.hi, self.cell_scale, self.cell_offset])?;
        for c in self.first.as_flattened() {
            w.put(&c.to_le_bytes())?;
        }
        for s in &self.seg {
            w.put(s)?;
        }
        let a = &self.accuracy;
        w.put(&(a.max_rel_error, a.at))?;
        w.put(&a.kinks.to_le_bytes())?;
        w.put(&a.max_knots_per_cell.to_le_bytes())?;
        (w.len() - start == Self::IMAGE_LEN).then_some(())
    }

    /// The stored image at the start of `bytes` (written by [`Self::write_image`]) as a
    /// table, **in place**: no copy, the table is read where the blob lies (on a
    /// microcontroller: in flash). It is validated first, as [`Self::read_image`] validates
    /// a copy: its domain must be `[lo, hi]` bit for bit.
    pub fn in_place(bytes: &[u8], lo: f32, hi: f32) -> Result<&Self, ImageError> {
        if cfg!(target_endian = "big") {
            return Err(ImageError::BigEndian);
        }
        let image = bytes.get(..Self::IMAGE_LEN).ok_or(ImageError::Invalid)?;
        let t: &Self = bytemuck::try_from_bytes(image).map_err(|e| match e {
            bytemuck::PodCastError::TargetAlignmentGreaterAndInputNotAligned => {
                ImageError::Unaligned
            }
            _ => ImageError::Invalid,
        })?;
        t.is_valid_image(lo, hi)
            .then_some(t)
            .ok_or(ImageError::Invalid)
    }

    /// Reads a stored image (written by [`Self::write_image`]; any alignment, any byte
    /// order of the host) into `self`, and returns the bytes after it. Refuses (`None`) an
    /// image that [`Self::in_place`] would refuse as invalid; `self` then holds a partial
    /// table that must be rebuilt before use.
    pub fn read_image<'a>(&mut self, bytes: &'a [u8], lo: f32, hi: f32) -> Option<&'a [u8]> {
        let ([l, h, cell_scale, cell_offset], mut rest) =
            postcard::take_from_bytes::<[f32; 4]>(bytes).ok()?;
        (self.lo, self.hi, self.cell_scale, self.cell_offset) = (l, h, cell_scale, cell_offset);
        for c in self.first.as_flattened_mut() {
            let (b, r) = postcard::take_from_bytes::<[u8; 2]>(rest).ok()?;
            *c = u16::from_le_bytes(b);
            rest = r;
        }
        for s in self.seg.iter_mut() {
            let (v, r) = postcard::take_from_bytes::<[f32; 6]>(rest).ok()?;
            *s = v;
            rest = r;
        }
        let ((max_rel_error, at, kinks, knots), rest) =
            postcard::take_from_bytes::<(f32, f32, [u8; 4], [u8; 4])>(rest).ok()?;
        self.accuracy = Accuracy32 {
            max_rel_error,
            at,
            kinks: u32::from_le_bytes(kinks),
            max_knots_per_cell: u32::from_le_bytes(knots),
        };
        self.is_valid_image(lo, hi).then_some(rest)
    }

    /// Reads a stored table of `layout` into `self` ([`Self::read_stored`] or
    /// [`Self::read_image`]).
    pub fn read_layout<'a>(
        &mut self,
        bytes: &'a [u8],
        layout: StoredLayout,
        lo: f32,
        hi: f32,
    ) -> Option<&'a [u8]> {
        match layout {
            StoredLayout::Segments => self.read_stored(bytes, lo, hi),
            StoredLayout::Image => self.read_image(bytes, lo, hi),
        }
    }

    /// Whether the table is one [`Self::compile`] could have built on `[lo, hi]`: the
    /// domain `[lo, hi]` bit for bit, every value finite, the knots in order, the lookup
    /// scalars and cells those the domain and the knots give, the accuracy record's knots
    /// per cell the cells' own.
    fn is_valid_image(&self, lo: f32, hi: f32) -> bool {
        let a = &self.accuracy;
        let scalars = self.lo.to_bits() == lo.to_bits()
            && self.hi.to_bits() == hi.to_bits()
            && lo.is_finite()
            && hi.is_finite()
            && hi > lo
            && self.cell_scale.is_finite()
            && self.cell_offset.is_finite()
            && a.max_rel_error.is_finite()
            && a.max_rel_error >= 0.0
            && a.at.is_finite();
        if !scalars {
            return false;
        }
        let mut prev_knot = f32::NEG_INFINITY;
        for s in &self.seg {
            if !s.iter().all(|v| v.is_finite()) || s[0] < prev_knot {
                return false;
            }
            prev_knot = s[0];
        }
        let mut cells_agree = true;
        let first = self.first.as_flattened();
        let most = walk_cells::<N>(lo, hi, &self.seg, |c, i| {
            cells_agree &= first.get(c) == Some(&i);
        });
        cells_agree && u32::try_from(most).ok() == Some(a.max_knots_per_cell)
    }

    /// Reads a stored table of `N` segments in the layout of format versions 4 and 5
    /// ([`StoredLayout::Segments`]: the scalars, the accuracy, the segments) into `self`,
    /// in place, and returns the bytes after it; the lookup cells are recomputed as
    /// [`Self::compile`] computes them, so the table is bit-identical to the one written.
    /// Refuses (`None`) a table that [`parse_stored`] refuses, whose domain is not
    /// `[lo, hi]` (bit for bit) or whose lookup cells disagree with its accuracy record;
    /// `self` then holds a partial table that must be rebuilt before use.
    pub fn read_stored<'a>(&mut self, bytes: &'a [u8], lo: f32, hi: f32) -> Option<&'a [u8]> {
        let seg = &mut self.seg;
        let (head, rest) = parse_stored(bytes, N, |i, s| {
            if let Some(slot) = seg.get_mut(i) {
                *slot = s;
            }
        })?;
        if head.domain.0.to_bits() != lo.to_bits() || head.domain.1.to_bits() != hi.to_bits() {
            return None;
        }
        (self.lo, self.hi) = head.domain;
        (self.cell_scale, self.cell_offset) = head.cells;
        self.accuracy = head.accuracy.into();
        (self.fill_cells() == head.accuracy.max_knots_per_cell).then_some(rest)
    }
}

/// The scalars of a stored table (see [`parse_stored`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StoredHead {
    /// `[lo, hi]`.
    pub domain: (f32, f32),
    /// Lookup cells per unit input and the cell coordinate of `x = 0`.
    pub cells: (f32, f32),
    /// The accuracy measured when the table was built.
    pub accuracy: TableAccuracy,
}

/// Parses a stored table of `segments` segments in the layout of format versions 4 and 5
/// ([`StoredLayout::Segments`]),
/// handing each segment to `each` (index, `[x0, 1 / width, c0, c1, c2, c3]`); returns its
/// scalars and the bytes after it. `None` if it does not parse, a value is not finite, the
/// domain is empty or the knots are not in order.
pub fn parse_stored(
    bytes: &[u8],
    segments: usize,
    each: impl FnMut(usize, [f32; 6]),
) -> Option<(StoredHead, &[u8])> {
    let ([lo, hi, cell_scale, cell_offset], rest) =
        postcard::take_from_bytes::<[f32; 4]>(bytes).ok()?;
    let ((max_rel_error, at), rest) = postcard::take_from_bytes::<(f32, f32)>(rest).ok()?;
    let ((kinks, max_knots), rest) = postcard::take_from_bytes::<(u32, u32)>(rest).ok()?;
    let head = stored_head(
        [lo, hi, cell_scale, cell_offset],
        (max_rel_error, at),
        (kinks, max_knots),
    )?;
    let rest = segments_in_order(rest, segments, each)?;
    Some((head, rest))
}

/// Parses a stored table image of `segments` segments ([`StoredLayout::Image`], the layout
/// of [`Table1D::write_image`]) at the start of `bytes`, of any alignment, and returns its
/// scalars and the bytes after it. `None` under the conditions of [`parse_stored`] and when a
/// lookup cell names a segment the table does not have; whether the cells are the ones the
/// knots give is checked where the table is read ([`Table1D::in_place`],
/// [`Table1D::read_image`]).
pub fn parse_image(bytes: &[u8], segments: usize) -> Option<(StoredHead, &[u8])> {
    let (image, after) = bytes.split_at_checked(image_len(segments))?;
    let (scalars, rest) = postcard::take_from_bytes::<[f32; 4]>(image).ok()?;
    let (cells, rest) = rest.split_at_checked(4 * segments)?;
    let cells_inside = cells.chunks_exact(2).all(|c| {
        c.first_chunk::<2>()
            .is_some_and(|&c| usize::from(u16::from_le_bytes(c)) < segments)
    });
    if !cells_inside {
        return None;
    }
    let acc = segments_in_order(rest, segments, |_, _| {})?;
    let ((max_rel_error, at, kinks, knots), _) =
        postcard::take_from_bytes::<(f32, f32, [u8; 4], [u8; 4])>(acc).ok()?;
    let head = stored_head(
        scalars,
        (max_rel_error, at),
        (u32::from_le_bytes(kinks), u32::from_le_bytes(knots)),
    )?;
    Some((head, after))
}

/// The scalars of a stored table, checked: every value finite, the domain non-empty, the
/// measured error not negative.
fn stored_head(
    [lo, hi, cell_scale, cell_offset]: [f32; 4],
    (max_rel_error, at): (f32, f32),
    (kinks, max_knots): (u32, u32),
) -> Option<StoredHead> {
    let valid = [lo, hi, cell_scale, cell_offset, max_rel_error, at]
        .iter()
        .all(|v| v.is_finite())
        && hi > lo
        && max_rel_error >= 0.0;
    valid.then_some(())?;
    Some(StoredHead {
        domain: (lo, hi),
        cells: (cell_scale, cell_offset),
        accuracy: TableAccuracy {
            max_rel_error,
            at,
            kinks: usize::try_from(kinks).ok()?,
            max_knots_per_cell: usize::try_from(max_knots).ok()?,
        },
    })
}

/// `segments` segments `[x0, 1 / width, c0, c1, c2, c3]` at the start of `bytes`, each handed
/// to `each` (index, segment); the bytes after them. `None` if they do not parse, a value is
/// not finite or the knots are not in order.
fn segments_in_order(
    mut bytes: &[u8],
    segments: usize,
    mut each: impl FnMut(usize, [f32; 6]),
) -> Option<&[u8]> {
    let mut prev_knot = f32::NEG_INFINITY;
    for i in 0..segments {
        let (s, rest) = postcard::take_from_bytes::<[f32; 6]>(bytes).ok()?;
        if !s.iter().all(|v| v.is_finite()) || s[0] < prev_knot {
            return None;
        }
        prev_knot = s[0];
        each(i, s);
        bytes = rest;
    }
    Some(bytes)
}
