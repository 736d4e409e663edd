//! The weights slot: a fixed flash region that holds one exported `.nemm` blob, so new
//! weights can be flashed without rebuilding the firmware (on an STM32F407: the last 128 KiB
//! sector at `0x080E0000`; see `boards/stm32f407.x`).
//!
//! ```text
//! offset  field
//!  0      magic "NWSL"
//!  4      len: u32 LE, length of the blob (0xFFFF_FFFF: erased flash, no weights)
//!  8      blob: `len` bytes, the `.nemm` file as exported
//! ```
//!
//! The slot only frames the blob; everything inside it (magic, version, CRC, shapes,
//! stability) is checked by [`nemm_core::decode`].

/// Magic bytes of a slot.
pub const MAGIC: [u8; 4] = *b"NWSL";
/// Slot header length in bytes.
pub const HEADER_LEN: usize = 8;
/// Bytes the firmware image reserves for the slot (header and blob).
pub const CAPACITY: usize = 64 * 1024;

/// Why the slot holds no usable blob.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlotError {
    /// The slot is erased: no weights were flashed.
    Empty,
    /// The slot header is not `NWSL` (wrong address, or something else was flashed there).
    BadMagic,
    /// The length field exceeds the slot.
    TooLong {
        /// Length in the header.
        len: u32,
        /// Bytes available for the blob.
        capacity: u32,
    },
}

/// The blob framed by `slot` (the whole reserved region).
pub fn blob(slot: &[u8]) -> Result<&[u8], SlotError> {
    let header = slot.get(..HEADER_LEN).ok_or(SlotError::TooLong {
        len: 0,
        capacity: 0,
    })?;
    let mut len = [0u8; 4];
    len.copy_from_slice(header.get(4..8).unwrap_or(&[0xFF; 4]));
    let len = u32::from_le_bytes(len);
    if header.iter().all(|&b| b == 0xFF) {
        return Err(SlotError::Empty);
    }
    if header.get(..4) != Some(&MAGIC[..]) {
        return Err(SlotError::BadMagic);
    }
    let body = slot.get(HEADER_LEN..).unwrap_or(&[]);
    body.get(..len as usize).ok_or(SlotError::TooLong {
        len,
        capacity: u32::try_from(body.len()).unwrap_or(u32::MAX),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    fn slot(blob: &[u8], cap: usize) -> Vec<u8> {
        let mut s = Vec::new();
        s.extend_from_slice(&MAGIC);
        s.extend_from_slice(&(blob.len() as u32).to_le_bytes());
        s.extend_from_slice(blob);
        s.resize(cap, 0xFF);
        s
    }

    #[test]
    fn frames_the_blob() {
        let s = slot(b"NEMMxyz", 64);
        assert_eq!(blob(&s), Ok(&b"NEMMxyz"[..]));
        assert_eq!(blob(&[0xFF; 64]), Err(SlotError::Empty));
        let mut bad = s.clone();
        bad[0] = 0;
        assert_eq!(blob(&bad), Err(SlotError::BadMagic));
        let mut long = s;
        long[4..8].copy_from_slice(&100u32.to_le_bytes());
        assert_eq!(
            blob(&long),
            Err(SlotError::TooLong {
                len: 100,
                capacity: 56
            })
        );
    }
}
