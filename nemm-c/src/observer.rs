//! The alpha observer: the oil-loss level online from the measured velocity and force.

use crate::estimator::{read_sample, status};
use crate::status::nemm_status_t::{self, *};
use crate::storage::{
    nemm_estimator_t, nemm_levels_t, nemm_observer_t, out, overlap, EstimatorCell, LevelsCell,
    Marked, ObserverCell, NEMM_ESTIMATOR_SIZE, NEMM_LEVELS_SIZE, NEMM_OBSERVER_SIZE,
};
use crate::types::{nemm_alpha_estimate_t, nemm_observer_config_t, nemm_sample_t};
use nemm_core::AlphaEstimate;

/// Fills `config` with the default observer settings (a grid of
/// `NEMM_OBSERVER_MAX_POINTS` levels over the model's trained range, a 3 s window of whole
/// stroke cycles; the fields that default to the model's values are 0).
///
/// Errors: `NEMM_E_NULL`.
///
/// # Safety
/// `config` must point to a writable `nemm_observer_config_t`.
#[no_mangle]
pub unsafe extern "C" fn nemm_observer_config_default(
    config: *mut nemm_observer_config_t,
) -> nemm_status_t {
    status((|| {
        let o = out(config)?;
        // SAFETY: non-null (checked) and writable (the caller); unaligned write.
        unsafe { o.write_unaligned(nemm_observer_config_t::default_values()) };
        Ok(())
    })())
}

/// Builds an alpha observer in `storage` (`size` bytes, at least `NEMM_OBSERVER_SIZE`,
/// aligned to `NEMM_OBSERVER_ALIGN`) for the model of the initialised estimator `est`, with
/// the settings `config` (NULL: the defaults). The observer runs the model at
/// `points` levels of alpha beside the estimator and fits the measured force; it owns its
/// copy of what it needs, so `est` is only read during this call (and may be used, reset or
/// re-initialised afterwards) and the two objects are independent.
///
/// On error the storage holds no observer until an init succeeds.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_SIZE`, `NEMM_E_STORAGE_ALIGN`,
/// `NEMM_E_NOT_INITIALISED` (est), `NEMM_E_OVERLAP`, `NEMM_E_OBSERVER_*`, and the estimator
/// errors of its levels (`NEMM_E_BAD_VELOCITY_LIMIT`, `NEMM_E_MODEL_*`).
///
/// # Safety
/// `size` bytes at `storage` must be writable, `est` must be an estimator's storage that no
/// other context writes during the call, `config` (if not NULL) must point to a readable
/// `nemm_observer_config_t`, and no other context may access the observer's storage.
#[no_mangle]
pub unsafe extern "C" fn nemm_observer_init(
    storage: *mut nemm_observer_t,
    size: usize,
    est: *const nemm_estimator_t,
    config: *const nemm_observer_config_t,
) -> nemm_status_t {
    // SAFETY: the caller's guarantees; no level tables.
    unsafe { init(storage, size, est, core::ptr::null(), config) }
}

/// Builds an alpha observer as `nemm_observer_init` whose grid is the levels of the level
/// tables `levels` (loaded from the blob of `est`'s model), so that `nemm_observer_step`
/// steps each level on its stored tables: `points` table-mode
/// steps per sample instead of exact ones (about a tenth or less of the cost; the estimate
/// agrees with the exact observer's up to the tables' error). The grid need not be uniform.
/// In `config` (NULL: the defaults) `grid_lo` and `grid_hi` must be 0 and `points` 0 or the
/// number of levels, which must be at most `NEMM_OBSERVER_MAX_POINTS`.
///
/// The observer keeps a pointer to `levels`: their storage must stay valid, and must not be
/// written (no `nemm_levels_init` on it), while the observer is used (until it is
/// initialised again); so must the blob they read their tables from, in place (see
/// `nemm_levels_init`).
///
/// Errors: those of `nemm_observer_init`, `NEMM_E_NOT_INITIALISED` (levels),
/// `NEMM_E_OVERLAP` (the observer's storage overlaps the estimator's or the levels'),
/// `NEMM_E_OBSERVER_GRID` (a grid set), `NEMM_E_OBSERVER_POINTS` (`points` not the number
/// of levels, or more than `NEMM_OBSERVER_MAX_POINTS` levels), `NEMM_E_LEVELS_MISMATCH`
/// (level tables of another model).
///
/// # Safety
/// As `nemm_observer_init`, and `levels` must be level tables' storage that stays valid and
/// unwritten while the observer is used, as does their blob.
#[no_mangle]
pub unsafe extern "C" fn nemm_observer_init_on_levels(
    storage: *mut nemm_observer_t,
    size: usize,
    est: *const nemm_estimator_t,
    levels: *const nemm_levels_t,
    config: *const nemm_observer_config_t,
) -> nemm_status_t {
    if levels.is_null() {
        return NEMM_E_NULL;
    }
    // SAFETY: the caller's guarantees.
    unsafe { init(storage, size, est, levels, config) }
}

/// The two inits: on the level tables `levels`, or (NULL) on the exact scalers.
///
/// # Safety
/// As `nemm_observer_init_on_levels`, `levels` may be NULL.
unsafe fn init(
    storage: *mut nemm_observer_t,
    size: usize,
    est: *const nemm_estimator_t,
    levels: *const nemm_levels_t,
    config: *const nemm_observer_config_t,
) -> nemm_status_t {
    status((|| {
        let c = if config.is_null() {
            nemm_observer_config_t::default_values()
        } else {
            // SAFETY: non-null and readable (the caller); copied before anything is written.
            unsafe { config.read_unaligned() }
        };
        // SAFETY: the caller's guarantee on `est`.
        let estimator = unsafe { EstimatorCell::get(est) }?;
        let tables = if levels.is_null() {
            None
        } else {
            // SAFETY: the caller's guarantee on `levels`: valid and unwritten while the
            // observer is used, which is the lifetime the observer holds them for.
            Some(unsafe { LevelsCell::tables(levels) }?)
        };
        if storage.is_null() {
            return Err(NEMM_E_NULL);
        }
        let overlaps =
            |p: *const u8, len: usize| overlap(storage.cast(), NEMM_OBSERVER_SIZE, p, len);
        if overlaps(est.cast(), NEMM_ESTIMATOR_SIZE)
            || (tables.is_some() && overlaps(levels.cast(), NEMM_LEVELS_SIZE))
        {
            return Err(NEMM_E_OVERLAP);
        }
        // SAFETY: the caller's guarantee on `storage` and `size`.
        let cell = unsafe { ObserverCell::claim(storage, size) }?;
        // SAFETY: claimed above, in this call.
        let cell = unsafe { ObserverCell::fill(cell) };
        match tables {
            None => cell.obs.load(&estimator.model, c.to_core())?,
            Some(t) => cell.obs.load_on_levels(&estimator.model, t, c.to_core())?,
        }
        cell.seal();
        Ok(())
    })())
}

/// Writes `a` to `out_ptr`.
fn put(out_ptr: *mut nemm_alpha_estimate_t, a: AlphaEstimate) {
    // SAFETY: every caller checked `out_ptr` with `out` (non-null); the C caller promises a
    // writable `nemm_alpha_estimate_t` there. Unaligned write.
    unsafe { out_ptr.write_unaligned(a.into()) }
}

/// One sample in (`nemm_sample_t`: the stroke velocity (m/s) as given to the estimator, the
/// measured force (N, positive in tension, `NEMM_SAMPLE_FORCE`) of the same instant, and
/// the stroke position (m, `NEMM_SAMPLE_POSITION`) for a model with a static force; its
/// `alpha` is not read); `out` gets the estimate after it. An observer built by
/// `nemm_observer_init_on_levels` steps each level on its stored tables (`points` table-mode
/// steps, 7 for the firmware's trained blob), one built by `nemm_observer_init` on the exact
/// networks (`points` exact model steps: about seven exact estimator steps by default).
///
/// A sample without a force is a missing measurement, handled as a NaN one: the levels
/// step, the estimate is held and flagged `NEMM_OBSERVER_FORCE_FAULT` and
/// `NEMM_OBSERVER_HELD`.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED` (nothing
/// stepped), `NEMM_E_INVALID_ARGUMENT` (other bits in `fields` than the `NEMM_SAMPLE_*`
/// ones; nothing stepped).
///
/// # Safety
/// `obs` must be an observer's storage that no other context accesses during the call,
/// `sample` must point to a readable `nemm_sample_t`, and `out` must point to a writable
/// `nemm_alpha_estimate_t`. The level tables of an observer built on them must still be
/// valid (see `nemm_observer_init_on_levels`).
#[no_mangle]
pub unsafe extern "C" fn nemm_observer_step(
    obs: *mut nemm_observer_t,
    sample: *const nemm_sample_t,
    out_estimate: *mut nemm_alpha_estimate_t,
) -> nemm_status_t {
    status((|| {
        let o = out(out_estimate)?;
        let s = read_sample(sample)?;
        // SAFETY: the caller's guarantee on `obs`.
        let cell = unsafe { ObserverCell::get_mut(obs) }?;
        put(o, cell.obs.step(s));
        Ok(())
    })())
}

/// The current estimate (the last step's; after init or reset: the middle of the grid,
/// flagged `NEMM_OBSERVER_NOT_EXCITED`).
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED`.
///
/// # Safety
/// `obs` must be an observer's storage that no other context writes during the call, and
/// `out` must point to a writable `nemm_alpha_estimate_t`.
#[no_mangle]
pub unsafe extern "C" fn nemm_observer_estimate(
    obs: *const nemm_observer_t,
    out_estimate: *mut nemm_alpha_estimate_t,
) -> nemm_status_t {
    status((|| {
        let o = out(out_estimate)?;
        // SAFETY: the caller's guarantee on `obs`.
        let cell = unsafe { ObserverCell::get(obs) }?;
        put(o, cell.obs.estimate());
        Ok(())
    })())
}

/// Returns the observer to rest with no data (the levels' states at rest, the fit cleared,
/// the warm-up restarted); the settings are kept.
///
/// Errors: `NEMM_E_NULL`, `NEMM_E_STORAGE_ALIGN`, `NEMM_E_NOT_INITIALISED`.
///
/// # Safety
/// `obs` must be an observer's storage that no other context accesses during the call.
#[no_mangle]
pub unsafe extern "C" fn nemm_observer_reset(obs: *mut nemm_observer_t) -> nemm_status_t {
    status((|| {
        // SAFETY: the caller's guarantee on `obs`.
        let cell = unsafe { ObserverCell::get_mut(obs) }?;
        cell.obs.reset();
        Ok(())
    })())
}
