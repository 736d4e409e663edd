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
//! The blob starts at offset 8, so a slot placed on a 4-byte boundary (a flash sector) holds
//! it 4-byte aligned, as `nemm_core::LevelTables` needs to read its tables in place. The
//! capacity, 128 KiB, holds the trained NEMM (H = 16, L = 5) with its fast-path tables at up
//! to 15 levels of 128 segments (125,552 bytes).
//!
//! The slot only frames the blob; everything inside it (magic, version, CRC, shapes,
//! stability) is checked by `nemm_core::decode`. [`encode`] writes a slot: the firmware's
//! build script, `cargo xtask` and the host tests frame their blobs with it; [`blob`] reads
//! it on the target (`nemm_firmware::slot::flashed` is the firmware's region).
#![no_std]

/// Magic bytes of a slot.
pub const MAGIC: [u8; 4] = *b"NWSL";
/// Slot header length in bytes.
pub const HEADER_LEN: usize = 8;
/// Bytes the firmware image reserves for the slot (header and blob).
pub const CAPACITY: usize = 128 * 1024;

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

/// The slot header of a blob of `len` bytes: [`MAGIC`], then `len` little-endian.
pub fn header(len: u32) -> [u8; HEADER_LEN] {
    let [m0, m1, m2, m3] = MAGIC;
    let [l0, l1, l2, l3] = len.to_le_bytes();
    [m0, m1, m2, m3, l0, l1, l2, l3]
}

/// Writes the slot holding `blob` into `slot` (the whole reserved region): the
/// [`header`], the blob, and erased flash (`0xFF`) up to the end of `slot`.
///
/// # Errors
///
/// [`SlotError::TooLong`] if the header and `blob` do not fit `slot`.
pub fn encode(blob: &[u8], slot: &mut [u8]) -> Result<(), SlotError> {
    let len = u32::try_from(blob.len()).unwrap_or(u32::MAX);
    let too_long = SlotError::TooLong {
        len,
        capacity: u32::try_from(slot.len().saturating_sub(HEADER_LEN)).unwrap_or(u32::MAX),
    };
    let (head, body) = slot.split_at_mut_checked(HEADER_LEN).ok_or(too_long)?;
    let (data, erased) = body.split_at_mut_checked(blob.len()).ok_or(too_long)?;
    head.copy_from_slice(&header(len));
    data.copy_from_slice(blob);
    erased.fill(0xFF);
    Ok(())
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
    extern crate std;
    use std::vec;
    use std::vec::Vec;

    fn slot(blob: &[u8], cap: usize) -> Vec<u8> {
        let mut s = vec![0; cap];
        encode(blob, &mut s).unwrap();
        s
    }

    #[test]
    fn encodes_header_blob_and_erased_flash() {
        let s = slot(b"NEMM1234", 20);
        assert_eq!(&s[..8], b"NWSL\x08\x00\x00\x00");
        assert_eq!(&s[8..16], b"NEMM1234");
        assert_eq!(&s[16..], &[0xFF; 4]);
        assert_eq!(blob(&s), Ok(&b"NEMM1234"[..]));
        // Exactly full, and one byte too many.
        assert_eq!(blob(&slot(&[7; 12], 20)), Ok(&[7; 12][..]));
        let mut small = [0u8; 20];
        assert_eq!(
            encode(&[7; 13], &mut small),
            Err(SlotError::TooLong {
                len: 13,
                capacity: 12
            })
        );
        assert_eq!(
            encode(b"", &mut small[..7]),
            Err(SlotError::TooLong {
                len: 0,
                capacity: 0
            })
        );
        assert_eq!(header(0x0102_0304), *b"NWSL\x04\x03\x02\x01");
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
