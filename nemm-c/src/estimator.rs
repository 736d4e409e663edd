//! The estimator: init from a blob, steps, alpha, reset, information.

use crate::blob::slice;
use crate::status::nemm_status_t::{self, *};
use crate::storage::{
    nemm_estimator_t, nemm_levels_t, out, overlap, EstimatorCell, LevelsCell, Marked,
    NEMM_ESTIMATOR_SIZE, NEMM_LEVELS_SIZE,
};
use crate::types::{
    kind_value, mode_value, nemm_estimate_t, nemm_estimator_config_t, nemm_estimator_info_t,
    nemm_sample_t, origin_value, NEMM_MODE_EXACT, NEMM_MODE_TABLE,
};
use crate::NEMM_TABLE_MAX_REL_ERROR;
use nemm_core::{decode_into, Estimate, EstimatorConfig, EvalMode, Sample, TableConfig};

/// `Ok(())` as `NEMM_OK`, an error as its code.
pub(crate) fn status(r: Result<(), nemm_status_t>) -> nemm_status_t {
    match r {
        Ok(()) => NEMM_OK,
        Err(s) => s,
    }
}

/// The nemm-core configuration of a C one.
fn core_config(c: &nemm_estimator_config_t) -> Result<EstimatorConfig, nemm_status_t> {
    let mode = match c.mode {
        NEMM_MODE_EXACT => EvalMode::Exact,
        NEMM_MODE_TABLE => EvalMode::Table(TableConfig::new(if c.table_max_rel_error == 0.0 {
            NEMM_TABLE_MAX_REL_ERROR
        } else {
            c.table_max_rel_error
        })),
        _ => return Err(NEMM_E_INVALID_ARGUMENT),
    };
    Ok(EstimatorConfig {
        velocity_limit_m_s: (c.velocity_limit_m_s != 0.0).then_some(c.velocity_limit_m_s),
        mode,
        ..EstimatorConfig::new(c.alpha)
    })
}

/// Builds an estimator in `storage` (`size` bytes, at least `NEMM_ESTIMATOR_SIZE`, aligned to
/// `NEMM_ESTIMATOR_ALIGN`) from the weights blob `blob` (`blob_len` bytes) with the settings
/// `config`: decodes and validates the blob (every check, the model's contents included)
/// into the storage, with the index of the tables it stores (kept for `nemm_levels_init`),
/// then builds the estimator (in table mode: reads the blob's stored tables if they match
/// `alpha` and the bound, else builds and checks the tables).
///
/// The estimator then owns everything it needs: neither the blob nor `config` is read after
/// this call returns. The storage must not overlap the blob. Nothing is allocated; the
/// stack holds at most one scaler's parameters at a time.
///
/// On error the storage holds no estimator (every other function returns
/// `NEMM_E_NOT_INITIALISED` for it) until an init succeeds. Calling init again on an
/// initialised estimator replaces it.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_SIZE`, `NEMM_E_STORAGE_ALIGN`,
/// `NEMM_E_INVALID_ARGUMENT` (mode), `NEMM_E_OVERLAP`, `NEMM_E_BLOB_*`, `NEMM_E_MODEL_*`,
/// `NEMM_E_ALPHA_OUT_OF_RANGE`, `NEMM_E_BAD_VELOCITY_LIMIT`, `NEMM_E_COMPILE`,
/// `NEMM_E_TABLE_*`.
///
/// # Safety
/// `size` bytes at `storage` must be writable, `blob_len` bytes at `blob` readable, and
/// `config` must point to a readable `nemm_estimator_config_t`; no other context may access
/// the storage during the call.
#[no_mangle]
pub unsafe extern "C" fn nemm_estimator_init(
    storage: *mut nemm_estimator_t,
    size: usize,
    blob: *const u8,
    blob_len: usize,
    config: *const nemm_estimator_config_t,
) -> nemm_status_t {
    status((|| {
        if config.is_null() {
            return Err(NEMM_E_NULL);
        }
        // SAFETY: non-null and readable (the caller); copied before the storage is written.
        let c = unsafe { config.read_unaligned() };
        // SAFETY: the caller's guarantee on `blob` and `blob_len`.
        let bytes = unsafe { slice(blob, blob_len) }?;
        if storage.is_null() {
            return Err(NEMM_E_NULL);
        }
        if overlap(storage.cast(), NEMM_ESTIMATOR_SIZE, blob, blob_len) {
            return Err(NEMM_E_OVERLAP);
        }
        let cfg = core_config(&c)?;
        // SAFETY: the caller's guarantee on `storage` and `size`.
        let cell = unsafe { EstimatorCell::claim(storage, size) }?;
        // SAFETY: claimed above, in this call.
        let cell = unsafe { EstimatorCell::fill(cell) };
        // The tables index is kept in the storage (for `nemm_levels_init`), written there
        // rather than kept in a local of this frame.
        cell.tables = decode_into(bytes, &mut cell.model)?;
        cell.est
            .load_with_tables(&cell.model, cfg, &cell.tables, bytes)?;
        cell.seal(bytes);
        Ok(())
    })())
}

/// Writes `e` to `out_ptr`.
fn put(out_ptr: *mut nemm_estimate_t, e: Estimate) {
    // SAFETY: every caller checked `out_ptr` with `out` (non-null); the C caller promises a
    // writable `nemm_estimate_t` there. Unaligned write: no alignment is required.
    unsafe { out_ptr.write_unaligned(e.into()) }
}

/// Reads the sample at `p` (non-null: checked).
pub(crate) fn read_sample(p: *const nemm_sample_t) -> Result<Sample, nemm_status_t> {
    if p.is_null() {
        return Err(NEMM_E_NULL);
    }
    // SAFETY: non-null (checked); the C caller promises a readable `nemm_sample_t` there.
    // Unaligned read: no alignment is required.
    unsafe { p.read_unaligned() }.to_core()
}

/// One sample in (`nemm_sample_t`: the stroke velocity, and optionally the stroke position
/// and this sample's level `alpha`; its force is not read), the force estimate out. Call
/// once per model step (`nemm_estimator_info_t.dt_s`, e.g. every 100 us at 10 kHz). A NaN,
/// infinite or implausible velocity is replaced by the last good one and flagged; the force
/// is always finite.
///
/// Position: a model with a static force (`needs_position`) needs it
/// (`NEMM_SAMPLE_POSITION`); without one, or with a non-finite one, the last good position
/// is used and the step is flagged `NEMM_FLAG_POSITION_MISSING`. Models without a static
/// force ignore it.
///
/// Level (`NEMM_SAMPLE_ALPHA`): without one the step runs at the estimator's own level
/// (`nemm_estimator_info_t.alpha`). With one:
/// - with level tables attached (`nemm_estimator_attach_levels`), the coefficients are read
///   from them at table cost, each the blend of its two neighbouring stored levels (at a
///   stored level: that level's tables, the table-mode step at that level bit for bit), in
///   either mode of the estimator. The state carries over between levels. An `alpha`
///   outside the stored levels takes the nearest level's tables, flagged
///   `NEMM_FLAG_ALPHA_EXTRAPOLATED` (as is one outside the trained range). The estimator's
///   own level is not changed: before switching between samples with and without an
///   `alpha`, call `nemm_estimator_reset`;
/// - without level tables, a changed `alpha` is applied first (as `nemm_estimator_set_alpha`,
///   the state kept) and the step runs at the new level. That needs `NEMM_MODE_EXACT`
///   (where a change costs about one network evaluation); in table mode a changed alpha is
///   refused with `NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE` (an unchanged one steps
///   normally).
///
/// Refused with nothing changed and nothing written: an `alpha` that is not a finite value
/// in `[0, 1]` (`NEMM_E_ALPHA_OUT_OF_RANGE`), a changed one in table mode without level
/// tables, other bits in `fields` than the `NEMM_SAMPLE_*` ones (`NEMM_E_INVALID_ARGUMENT`).
/// A sample without an `alpha` is never refused.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED` (nothing
/// stepped), `NEMM_E_INVALID_ARGUMENT`, `NEMM_E_ALPHA_OUT_OF_RANGE`,
/// `NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE`.
///
/// # Safety
/// `est` must be an estimator's storage (see `nemm_estimator_t`) that no other context
/// accesses during the call, `sample` must point to a readable `nemm_sample_t`, and `out`
/// must point to a writable `nemm_estimate_t`. Level tables attached to the estimator must
/// still be valid (see `nemm_estimator_attach_levels`).
#[no_mangle]
pub unsafe extern "C" fn nemm_estimator_step(
    est: *mut nemm_estimator_t,
    sample: *const nemm_sample_t,
    out_estimate: *mut nemm_estimate_t,
) -> nemm_status_t {
    status((|| {
        let o = out(out_estimate)?;
        let s = read_sample(sample)?;
        // SAFETY: the caller's guarantee on `est`.
        let cell = unsafe { EstimatorCell::get_mut(est) }?;
        put(o, cell.est.step(s)?);
        Ok(())
    })())
}

/// Attaches the level tables `levels` (loaded by `nemm_levels_init` from this estimator's
/// blob) to the estimator: from now on a sample with an `alpha` (`NEMM_SAMPLE_ALPHA`) is
/// stepped on them at table cost (see `nemm_estimator_step`), a condition that changes
/// every sample. NULL detaches them (a sample's `alpha` is then applied to the estimator's
/// own networks). `nemm_estimator_init` detaches them too.
///
/// The estimator keeps a pointer to `levels`: their storage must stay valid, and must not
/// be written (no `nemm_levels_init` on it), while they are attached; so must the blob they
/// read their tables from, in place (see `nemm_levels_init`).
///
/// Refused with nothing changed: level tables of another model, or an estimator of a model
/// without neural coefficients (`NEMM_E_LEVELS_MISMATCH`).
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED` (est or
/// levels), `NEMM_E_OVERLAP` (the two storages), `NEMM_E_LEVELS_MISMATCH`.
///
/// # Safety
/// `est` must be an estimator's storage that no other context accesses during the call;
/// `levels` NULL or level tables' storage (see `nemm_levels_t`) that stays valid and
/// unwritten while attached, as does their blob.
#[no_mangle]
pub unsafe extern "C" fn nemm_estimator_attach_levels(
    est: *mut nemm_estimator_t,
    levels: *const nemm_levels_t,
) -> nemm_status_t {
    status((|| {
        if levels.is_null() {
            // SAFETY: the caller's guarantee on `est`.
            let cell = unsafe { EstimatorCell::get_mut(est) }?;
            cell.est.detach_levels();
            return Ok(());
        }
        if overlap(
            est.cast(),
            NEMM_ESTIMATOR_SIZE,
            levels.cast(),
            NEMM_LEVELS_SIZE,
        ) {
            return Err(NEMM_E_OVERLAP);
        }
        // SAFETY: the caller's guarantee on `levels`: valid and unwritten while attached,
        // which is the lifetime the estimator holds them for.
        let tables = unsafe { LevelsCell::tables(levels) }?;
        // SAFETY: the caller's guarantee on `est`; it does not overlap `levels` (checked).
        let cell = unsafe { EstimatorCell::get_mut(est) }?;
        Ok(cell.est.attach_levels(tables)?)
    })())
}

/// Changes the oil-loss level (e.g. from a bench controller or the alpha observer), keeping
/// the state. In exact mode this costs about one network evaluation; in table mode it
/// rebuilds and re-checks the tables (about `128 * NEMM_TABLE_SEGMENTS` network evaluations
/// per table: not for the sample loop). After an error nothing changed.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED`,
/// `NEMM_E_ALPHA_OUT_OF_RANGE`, `NEMM_E_TABLE_*` (table mode).
///
/// # Safety
/// `est` must be an estimator's storage that no other context accesses during the call.
#[no_mangle]
pub unsafe extern "C" fn nemm_estimator_set_alpha(
    est: *mut nemm_estimator_t,
    alpha: f32,
) -> nemm_status_t {
    status((|| {
        // SAFETY: the caller's guarantee on `est`.
        let cell = unsafe { EstimatorCell::get_mut(est) }?;
        Ok(cell.est.set_alpha(alpha)?)
    })())
}

/// Returns the estimator to rest (as after init: state at rest, last input 0); the alpha,
/// the settings and the counters are kept.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED`.
///
/// # Safety
/// `est` must be an estimator's storage that no other context accesses during the call.
#[no_mangle]
pub unsafe extern "C" fn nemm_estimator_reset(est: *mut nemm_estimator_t) -> nemm_status_t {
    status((|| {
        // SAFETY: the caller's guarantee on `est`.
        let cell = unsafe { EstimatorCell::get_mut(est) }?;
        cell.est.reset();
        Ok(())
    })())
}

/// Fills `info` with the estimator's model kind, settings and counters.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED`.
///
/// # Safety
/// `est` must be an estimator's storage that no other context writes during the call, and
/// `info` must point to a writable `nemm_estimator_info_t`.
#[no_mangle]
pub unsafe extern "C" fn nemm_estimator_info(
    est: *const nemm_estimator_t,
    info: *mut nemm_estimator_info_t,
) -> nemm_status_t {
    status((|| {
        let o = out(info)?;
        // SAFETY: the caller's guarantee on `est`.
        let cell = unsafe { EstimatorCell::get(est) }?;
        let (e, m) = (&cell.est, &cell.model);
        let d = e.diagnostics();
        let value = nemm_estimator_info_t {
            kind: kind_value(m.kind()),
            mode: mode_value(e.mode()),
            table_origin: origin_value(e.table_origin()),
            table_bytes: u32::try_from(e.table_bytes().1).unwrap_or(u32::MAX),
            needs_position: u32::from(e.needs_position()),
            dt_s: m.dt_s,
            alpha: e.alpha(),
            alpha_min: m.meta.alpha_min,
            alpha_max: m.meta.alpha_max,
            velocity_limit_m_s: e.velocity_limit_m_s(),
            steps: d.steps,
            held_samples: d.held_samples,
            resets: d.resets,
        };
        // SAFETY: non-null (checked) and writable (the caller); unaligned write.
        unsafe { o.write_unaligned(value) };
        Ok(())
    })())
}
