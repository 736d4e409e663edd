//! The byte writer nemm-core's weight-format encoder and the stored tables
//! ([`crate::table::Table1D::write_image`]) serialise with: postcard into a buffer, or a
//! counter of the bytes it would write (to size the buffer first).

use serde::Serialize;

/// A postcard writer into a buffer, or (without one) a counter of the bytes it would write.
pub struct Writer<'a> {
    buf: Option<&'a mut [u8]>,
    len: usize,
}

impl<'a> Writer<'a> {
    /// Writes into `buf`.
    pub fn new(buf: &'a mut [u8]) -> Self {
        Self {
            buf: Some(buf),
            len: 0,
        }
    }

    /// Counts only.
    pub fn counter() -> Self {
        Self { buf: None, len: 0 }
    }

    /// Bytes written (or counted).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing was written (or counted) yet.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Appends `v`; `None` if the buffer is too small.
    pub fn put<T: Serialize + ?Sized>(&mut self, v: &T) -> Option<()> {
        let n = match self.buf.as_deref_mut() {
            Some(buf) => postcard::to_slice(v, buf.get_mut(self.len..)?).ok()?.len(),
            None => postcard::experimental::serialized_size(v).ok()?,
        };
        self.len = self.len.checked_add(n)?;
        Some(())
    }
}
