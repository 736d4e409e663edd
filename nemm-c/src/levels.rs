//! Level tables: the tables a blob stores for several oil-loss levels, read in place from
//! the blob, for an estimator with a level per sample and an alpha observer at table cost.

use crate::blob::slice;
use crate::estimator::status;
use crate::status::nemm_status_t::{self, *};
use crate::storage::{
    nemm_estimator_t, nemm_levels_t, out, overlap, EstimatorCell, LevelsCell, Marked,
    NEMM_ESTIMATOR_SIZE, NEMM_LEVELS_SIZE,
};
use crate::types::nemm_levels_info_t;
use crate::{NEMM_LEVELS_CAPACITY, NEMM_PARAM_CAPACITY};
use nemm_core::check_frame;

/// Loads level tables into `storage` (`size` bytes, at least `NEMM_LEVELS_SIZE`, aligned to
/// `NEMM_LEVELS_ALIGN`) from the weights blob `blob` (`blob_len` bytes) that the initialised
/// estimator `est` was built from: every stored level whose tables have
/// `NEMM_TABLE_SEGMENTS` segments (at least 2, at most `NEMM_LEVELS_CAPACITY`, ascending in
/// alpha, one table configuration). A blob exported with `--tables-levels N` stores them.
///
/// The tables are **read in place**: they are not copied, the level tables refer to them
/// where the blob lies (on a microcontroller: in flash), so their RAM (`NEMM_LEVELS_SIZE`)
/// is a few hundred bytes whatever the number of levels. Hence the blob:
/// - must stay readable and unchanged, at the same address, for as long as the level
///   tables are in use, and so must every estimator they are attached to
///   (`nemm_estimator_attach_levels`) and every observer built on them
///   (`nemm_observer_init_on_levels`): a blob in flash or in a `static` is; before
///   rewriting it (e.g. a weights update of its flash slot) detach the level tables from
///   the estimators and initialise those observers again;
/// - must be 4-byte aligned in memory (`NEMM_E_LEVELS_UNALIGNED` otherwise: `.balign 4`
///   before the blob in flash, a `uint32_t` buffer in RAM);
/// - must be of format version 6 or later (`NEMM_E_LEVELS_LAYOUT` for a blob of version 4 or
///   5, whose tables lie unaligned: export it again).
///
/// The blob must be the estimator's, byte for byte: its length and CRC-32 trailer are
/// compared with those the estimator was built from (`NEMM_E_LEVELS_OTHER_BLOB` otherwise),
/// and its CRC-32 is computed again over its bytes (`NEMM_E_BLOB_CRC_MISMATCH` if they
/// changed since). The blob is not decoded again: the model and the index of the blob's
/// tables (where each level's tables lie in it) are those the estimator's init decoded
/// and kept in the estimator's storage; each table is validated once, here. `est` is not
/// read after this call returns; the level tables may drive any estimator or observer of
/// the same model. Nothing is allocated. This is init work (a CRC of the blob), not for
/// the sample loop.
///
/// On error the storage holds no level tables until an init succeeds.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_SIZE`, `NEMM_E_STORAGE_ALIGN`,
/// `NEMM_E_NOT_INITIALISED` (est), `NEMM_E_INVALID_ARGUMENT` (blob_len), `NEMM_E_OVERLAP`
/// (the storage overlaps the blob or the estimator), `NEMM_E_LEVELS_*` (among them
/// `NEMM_E_LEVELS_UNALIGNED` and `NEMM_E_LEVELS_LAYOUT`), and the errors of a blob that no
/// longer checks (`NEMM_E_BLOB_*`: its bytes changed since the estimator's init).
///
/// # Safety
/// `size` bytes at `storage` must be writable, `blob_len` bytes at `blob` readable, and `est`
/// must be an estimator's storage that no other context writes during the call; no other
/// context may access the level tables' storage during the call. After a successful call,
/// the `blob_len` bytes at `blob` must stay readable and unchanged for as long as the level
/// tables, or an estimator or observer using them, are used (above).
#[no_mangle]
pub unsafe extern "C" fn nemm_levels_init(
    storage: *mut nemm_levels_t,
    size: usize,
    est: *const nemm_estimator_t,
    blob: *const u8,
    blob_len: usize,
) -> nemm_status_t {
    status((|| {
        // SAFETY: the caller's guarantee on `est`.
        let estimator = unsafe { EstimatorCell::get(est) }?;
        // SAFETY: the caller's guarantee on `blob` and `blob_len`: readable during the call,
        // and, for the level tables that keep references into it, readable and unchanged
        // for as long as they (and any estimator or observer using them) are in use, the
        // documented contract of this function. The level tables' lifetime is `'static`
        // because the storage outlives any Rust borrow; the contract is what bounds it.
        let bytes: &'static [u8] = unsafe { slice(blob, blob_len) }?;
        if storage.is_null() {
            return Err(NEMM_E_NULL);
        }
        if overlap(storage.cast(), NEMM_LEVELS_SIZE, blob, blob_len)
            || overlap(
                storage.cast(),
                NEMM_LEVELS_SIZE,
                est.cast(),
                NEMM_ESTIMATOR_SIZE,
            )
        {
            return Err(NEMM_E_OVERLAP);
        }
        // SAFETY: the caller's guarantee on `storage` and `size`.
        let cell = unsafe { LevelsCell::claim(storage, size) }?;
        if !estimator.built_from(bytes) {
            return Err(NEMM_E_LEVELS_OTHER_BLOB);
        }
        // The same length and trailer: the bytes are still those the estimator decoded (and
        // its tables index points into) if their CRC still holds. No decode: the frame's
        // checks only.
        check_frame(bytes, NEMM_PARAM_CAPACITY)?;
        // SAFETY: claimed above, in this call.
        let levels = unsafe { LevelsCell::fill(cell) };
        // Reads the tables in place, from the index the estimator's init found:
        // `NEMM_E_LEVELS_UNALIGNED` for a blob that is not 4-byte aligned,
        // `NEMM_E_LEVELS_LAYOUT` for one of format version 4 or 5.
        levels.load(&estimator.model, &estimator.tables, bytes)?;
        // SAFETY: claimed, filled and loaded in this call; `levels` is not used after it.
        unsafe { LevelsCell::seal(cell) };
        Ok(())
    })())
}

/// Fills `info` with the levels the level tables hold, and the bytes their tables take in
/// the blob (where they are read).
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED`.
///
/// # Safety
/// `levels` must be level tables' storage that no other context writes during the call, and
/// `info` must point to a writable `nemm_levels_info_t`.
#[no_mangle]
pub unsafe extern "C" fn nemm_levels_info(
    levels: *const nemm_levels_t,
    info: *mut nemm_levels_info_t,
) -> nemm_status_t {
    status((|| {
        let o = out(info)?;
        // SAFETY: the caller's guarantee on `levels`.
        let l = unsafe { LevelsCell::tables(levels) }?;
        let mut value = nemm_levels_info_t {
            levels: u32::try_from(l.len()).unwrap_or(u32::MAX),
            table_bytes: u32::try_from(l.table_bytes().1).unwrap_or(u32::MAX),
            table_max_rel_error: l.config().max_rel_error,
            alpha: [0.0; NEMM_LEVELS_CAPACITY],
        };
        for (to, from) in value.alpha.iter_mut().zip(l.alphas()) {
            *to = *from;
        }
        // SAFETY: non-null (checked) and writable (the caller); unaligned write.
        unsafe { o.write_unaligned(value) };
        Ok(())
    })())
}
