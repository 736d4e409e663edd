//! Checking a weights blob before building anything from it.

use crate::status::nemm_status_t::{self, *};
use crate::storage::out;
use crate::types::{kind_value, nemm_blob_info_t};
use crate::NEMM_PARAM_CAPACITY;
use nemm_core::{DecodeError, Header};

/// The blob as a slice: non-null and within the address space.
///
/// # Safety
/// If `blob` is non-null, `len` bytes at `blob` must be readable and unchanged during the
/// borrow.
pub(crate) unsafe fn slice<'a>(blob: *const u8, len: usize) -> Result<&'a [u8], nemm_status_t> {
    if blob.is_null() {
        return Err(NEMM_E_NULL);
    }
    if len > isize::MAX as usize {
        return Err(NEMM_E_INVALID_ARGUMENT);
    }
    // SAFETY: non-null, `u8` needs no alignment, `len` bytes readable (the caller), and at
    // most `isize::MAX` bytes (checked).
    Ok(unsafe { core::slice::from_raw_parts(blob, len) })
}

/// The checks of `nemm_core::decode` that need no model, in its order
/// (`nemm_core::check_frame` at this library's capacity).
fn check(blob: &[u8]) -> Result<Header, DecodeError> {
    nemm_core::check_frame(blob, NEMM_PARAM_CAPACITY).map(|f| f.header)
}

/// Checks a weights blob (a `.nemm` file, `len` bytes at `blob`) without decoding its
/// model, so without storage: its length, magic, format version, header, CRC-32 and that
/// its largest scaler fits `NEMM_PARAM_CAPACITY`, in this order (the first failure is
/// returned). Fills `info` (may be NULL) on success.
///
/// The model's contents (finite values, shapes, step stability) are checked by
/// `nemm_estimator_init`, which decodes it: a blob that passes here can still be refused
/// there with a `NEMM_E_MODEL_*` or `NEMM_E_BLOB_MALFORMED` code.
///
/// Errors: `NEMM_E_NULL` (blob), `NEMM_E_INVALID_ARGUMENT` (len), `NEMM_E_BLOB_*`.
///
/// # Safety
/// `len` bytes at `blob` must be readable; `info`, if not NULL, must point to a writable
/// `nemm_blob_info_t`.
#[no_mangle]
pub unsafe extern "C" fn nemm_blob_validate(
    blob: *const u8,
    len: usize,
    info: *mut nemm_blob_info_t,
) -> nemm_status_t {
    // SAFETY: the caller's guarantee on `blob` and `len`.
    let bytes = match unsafe { slice(blob, len) } {
        Ok(b) => b,
        Err(s) => return s,
    };
    match check(bytes) {
        Ok(h) => {
            if let Ok(info) = out(info) {
                let value = nemm_blob_info_t {
                    format_version: u32::from(h.version),
                    kind: kind_value(h.kind),
                    max_scaler_params: h.max_scaler_params,
                    blob_len: u32::try_from(len).unwrap_or(u32::MAX),
                };
                // SAFETY: non-null (checked) and writable (the caller); unaligned write.
                unsafe { info.write_unaligned(value) };
            }
            NEMM_OK
        }
        Err(e) => e.into(),
    }
}
