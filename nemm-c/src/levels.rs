//! Level tables: the tables a blob stores for several oil-loss levels, held in RAM, for an
//! estimator with a level per sample and an alpha observer at table cost.

use crate::blob::slice;
use crate::estimator::status;
use crate::status::nemm_status_t::{self, *};
use crate::storage::{
    nemm_estimator_t, nemm_levels_t, out, overlap, EstimatorCell, LevelsCell, Marked,
    NEMM_ESTIMATOR_SIZE, NEMM_LEVELS_SIZE,
};
use crate::types::nemm_levels_info_t;
use crate::NEMM_LEVELS_CAPACITY;
use nemm_core::decode_into;

/// Loads level tables into `storage` (`size` bytes, at least `NEMM_LEVELS_SIZE`, aligned to
/// `NEMM_LEVELS_ALIGN`) from the weights blob `blob` (`blob_len` bytes) that the initialised
/// estimator `est` was built from: every stored level whose tables have
/// `NEMM_TABLE_SEGMENTS` segments (at least 2, at most `NEMM_LEVELS_CAPACITY`, ascending in
/// alpha, one table configuration), its tables copied into the storage (`2 x 28 x
/// NEMM_TABLE_SEGMENTS` bytes per level). A blob exported with `--tables-levels N` stores
/// them.
///
/// The blob must be the estimator's, byte for byte (its length and CRC-32 are compared with
/// those the estimator was built from; `NEMM_E_LEVELS_OTHER_BLOB` otherwise): the model is
/// taken from the estimator, and the blob is decoded and checked again (in the storage, not
/// on the stack) for the index of its tables. Neither the blob nor `est` is read after this
/// call returns; the level tables may drive any estimator or observer of the same model.
/// Nothing is allocated. This is init work (a CRC and a decode of the blob, and a copy of
/// the tables), not for the sample loop.
///
/// On error the storage holds no level tables until an init succeeds.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_SIZE`, `NEMM_E_STORAGE_ALIGN`,
/// `NEMM_E_NOT_INITIALISED` (est), `NEMM_E_INVALID_ARGUMENT` (blob_len), `NEMM_E_OVERLAP`
/// (the storage overlaps the blob or the estimator), `NEMM_E_LEVELS_*`, and the errors of a
/// blob that no longer decodes (`NEMM_E_BLOB_*`, `NEMM_E_MODEL_*`).
///
/// # Safety
/// `size` bytes at `storage` must be writable, `blob_len` bytes at `blob` readable, and `est`
/// must be an estimator's storage that no other context writes during the call; no other
/// context may access the level tables' storage during the call.
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
        // SAFETY: the caller's guarantee on `blob` and `blob_len`.
        let bytes = unsafe { slice(blob, blob_len) }?;
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
        let index = {
            // SAFETY: claimed above, in this call; the model is dropped at the end of the
            // block, before `fill`.
            let scratch = unsafe { LevelsCell::scratch(cell) };
            decode_into(bytes, scratch)?
        };
        // SAFETY: claimed above, in this call; no reference to the scratch model is alive.
        let levels = unsafe { LevelsCell::fill(cell) };
        levels.load(&estimator.model, &index, bytes)?;
        // SAFETY: claimed, filled and loaded in this call; `levels` is not used after it.
        unsafe { LevelsCell::seal(cell) };
        Ok(())
    })())
}

/// Fills `info` with the levels the level tables hold and their RAM.
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
