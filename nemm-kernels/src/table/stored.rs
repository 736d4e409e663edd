//! A table in the weight format's tables section (nemm-core's `format::tables`): written from
//! a built table, parsed and checked, read back bit for bit.

use super::*;

impl<const N: usize> Table1D<N> {
    /// Writes the table as the format's stored table (nemm-core's `format::tables`): the domain,
    /// the lookup scalars, the accuracy, then the `N` segments (the lookup cells are not
    /// stored: [`Self::read_stored`] recomputes them).
    pub fn write_stored(&self, w: &mut Writer<'_>) -> Option<()> {
        w.put(&[self.lo, self.hi, self.cell_scale, self.cell_offset])?;
        w.put(&(self.accuracy.max_rel_error, self.accuracy.at))?;
        w.put(&(
            u32::try_from(self.accuracy.kinks).ok()?,
            u32::try_from(self.accuracy.max_knots_per_cell).ok()?,
        ))?;
        for s in &self.seg {
            w.put(s)?;
        }
        Some(())
    }

    /// Reads a stored table of `N` segments (written by [`Self::write_stored`]) into `self`,
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
        self.accuracy = head.accuracy;
        (self.fill_cells() == self.accuracy.max_knots_per_cell).then_some(rest)
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

/// Parses a stored table of `segments` segments (the layout of [`Table1D::write_stored`]),
/// handing each segment to `each` (index, `[x0, 1 / width, c0, c1, c2, c3]`); returns its
/// scalars and the bytes after it. `None` if it does not parse, a value is not finite, the
/// domain is empty or the knots are not in order.
pub fn parse_stored(
    bytes: &[u8],
    segments: usize,
    mut each: impl FnMut(usize, [f32; 6]),
) -> Option<(StoredHead, &[u8])> {
    let ([lo, hi, cell_scale, cell_offset], rest) =
        postcard::take_from_bytes::<[f32; 4]>(bytes).ok()?;
    let ((max_rel_error, at), rest) = postcard::take_from_bytes::<(f32, f32)>(rest).ok()?;
    let ((kinks, max_knots), mut rest) = postcard::take_from_bytes::<(u32, u32)>(rest).ok()?;
    let valid = lo.is_finite()
        && hi.is_finite()
        && hi > lo
        && cell_scale.is_finite()
        && cell_offset.is_finite()
        && max_rel_error.is_finite()
        && max_rel_error >= 0.0
        && at.is_finite();
    if !valid {
        return None;
    }
    let mut prev_knot = f32::NEG_INFINITY;
    for i in 0..segments {
        let (s, r) = postcard::take_from_bytes::<[f32; 6]>(rest).ok()?;
        if !s.iter().all(|v| v.is_finite()) || s[0] < prev_knot {
            return None;
        }
        prev_knot = s[0];
        each(i, s);
        rest = r;
    }
    let head = StoredHead {
        domain: (lo, hi),
        cells: (cell_scale, cell_offset),
        accuracy: TableAccuracy {
            max_rel_error,
            at,
            kinks: usize::try_from(kinks).ok()?,
            max_knots_per_cell: usize::try_from(max_knots).ok()?,
        },
    };
    Some((head, rest))
}
