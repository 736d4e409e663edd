//! The opaque storage types of the header and what they hold, their sizes and alignments
//! (compile-time constants of the header, checked here against the Rust objects on every
//! target the crate is built for), and the checked conversions of the caller's pointers.
//!
//! The sizes depend on the target's pointer width (the model's vectors hold their lengths
//! as `usize`), so the header has one set per width: 32-bit (checked on
//! `thumbv7em-none-eabihf`) and 64-bit (checked on the x86-64 and AArch64 hosts). A build
//! for a target whose layout differs fails here with both numbers in the message
//! (`expected an array with a size of <constant>, found one with a size of <size_of>`):
//! put the second into the constant, regenerate the header (`cargo xtask c-header`) and
//! update the storage table of `docs/c-interface.md` (checked by `tests/header.rs`).

use crate::status::nemm_status_t::{self, *};
use crate::{NEMM_OBSERVER_MAX_POINTS, NEMM_PARAM_CAPACITY, NEMM_TABLE_SEGMENTS};
use core::mem::{align_of, size_of};
use nemm_core::{AlphaObserver, Estimator, Model};

/// The model, as the library decodes it.
pub(crate) type CModel = Model<NEMM_PARAM_CAPACITY>;
/// The estimator, as the firmware instantiates it.
pub(crate) type CEstimator = Estimator<NEMM_PARAM_CAPACITY, NEMM_TABLE_SEGMENTS>;
/// The alpha observer.
pub(crate) type CObserver = AlphaObserver<NEMM_PARAM_CAPACITY, NEMM_OBSERVER_MAX_POINTS>;

/// What a `nemm_estimator_t` holds: the decoded model (kept, so that observers can be built
/// from it) and the estimator built from it.
#[repr(C)]
pub(crate) struct EstimatorCell {
    /// [`ESTIMATOR_MAGIC`] once `nemm_estimator_init` succeeded, anything else before.
    magic: u32,
    pub(crate) model: CModel,
    pub(crate) est: CEstimator,
}

/// What a `nemm_observer_t` holds.
#[repr(C)]
pub(crate) struct ObserverCell {
    /// [`OBSERVER_MAGIC`] once `nemm_observer_init` succeeded.
    magic: u32,
    pub(crate) obs: CObserver,
}

/// An empty observer, evaluated at compile time: copied into the storage rather than built
/// in a stack frame of its size.
const EMPTY_OBSERVER: CObserver = CObserver::empty();

/// The mark of an initialised estimator.
const ESTIMATOR_MAGIC: u32 = u32::from_le_bytes(*b"NEMe");
/// The mark of an initialised observer.
const OBSERVER_MAGIC: u32 = u32::from_le_bytes(*b"NEMo");

/// Bytes of a `nemm_estimator_t`: the decoded model and the estimator (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_ESTIMATOR_SIZE: usize = 46080;
/// Alignment of a `nemm_estimator_t` (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_ESTIMATOR_ALIGN: usize = 4;
/// Bytes of a `nemm_observer_t` (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_OBSERVER_SIZE: usize = 21584;
/// Alignment of a `nemm_observer_t` (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_OBSERVER_ALIGN: usize = 4;

/// Bytes of a `nemm_estimator_t`: the decoded model and the estimator (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_ESTIMATOR_SIZE: usize = 46280;
/// Alignment of a `nemm_estimator_t` (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_ESTIMATOR_ALIGN: usize = 8;
/// Bytes of a `nemm_observer_t` (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_OBSERVER_SIZE: usize = 21712;
/// Alignment of a `nemm_observer_t` (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_OBSERVER_ALIGN: usize = 8;

// The header's constants are the objects' sizes and alignments, exactly (a mismatch names
// both numbers: the constant first).
const _: [(); NEMM_ESTIMATOR_SIZE] = [(); size_of::<EstimatorCell>()];
const _: [(); NEMM_ESTIMATOR_ALIGN] = [(); align_of::<EstimatorCell>()];
const _: [(); NEMM_OBSERVER_SIZE] = [(); size_of::<ObserverCell>()];
const _: [(); NEMM_OBSERVER_ALIGN] = [(); align_of::<ObserverCell>()];

/// Storage of one estimator: `NEMM_ESTIMATOR_SIZE` bytes aligned to `NEMM_ESTIMATOR_ALIGN`,
/// opaque to the caller. Declare it (a `static` is usual: it is large) and pass its address
/// and `sizeof` to `nemm_estimator_init`; then pass its address to the other
/// `nemm_estimator_*` functions. Never copy it (it may be moved only before init).
#[allow(non_camel_case_types)]
#[repr(C)]
pub struct nemm_estimator_t {
    /// The estimator's bytes (opaque).
    pub opaque: [u8; NEMM_ESTIMATOR_SIZE],
}

/// Storage of one alpha observer: `NEMM_OBSERVER_SIZE` bytes aligned to
/// `NEMM_OBSERVER_ALIGN`, opaque to the caller (as `nemm_estimator_t`).
#[allow(non_camel_case_types)]
#[repr(C)]
pub struct nemm_observer_t {
    /// The observer's bytes (opaque).
    pub opaque: [u8; NEMM_OBSERVER_SIZE],
}

/// A non-null, aligned pointer, or the status that says why not.
fn checked<T>(p: *const T) -> Result<(), nemm_status_t> {
    if p.is_null() {
        Err(NEMM_E_NULL)
    } else if !p.is_aligned() {
        Err(NEMM_E_STORAGE_ALIGN)
    } else {
        Ok(())
    }
}

/// Whether the byte ranges `[a, a + a_len)` and `[b, b + b_len)` overlap.
pub(crate) fn overlap(a: *const u8, a_len: usize, b: *const u8, b_len: usize) -> bool {
    let (a, b) = (a as usize, b as usize);
    a < b.saturating_add(b_len) && b < a.saturating_add(a_len)
}

/// Storage given to an init function: `size` bytes at `p`, to be filled.
fn fresh<C>(p: *mut u8, size: usize) -> Result<*mut C, nemm_status_t> {
    let cell = p.cast::<C>();
    checked(cell)?;
    if size < size_of::<C>() {
        return Err(NEMM_E_STORAGE_SIZE);
    }
    Ok(cell)
}

impl EstimatorCell {
    /// Checks the storage for `nemm_estimator_init` and marks it uninitialised; the fields
    /// are still to be written.
    ///
    /// # Safety
    /// If `p` is non-null, `size` bytes at `p` must be writable and not accessed otherwise
    /// during the call.
    pub(crate) unsafe fn claim(
        p: *mut nemm_estimator_t,
        size: usize,
    ) -> Result<*mut Self, nemm_status_t> {
        let cell = fresh::<Self>(p.cast(), size)?;
        // SAFETY: `cell` is non-null, aligned and the storage holds a whole `EstimatorCell`
        // (checked above); the caller lends it to this call. A `u32` is written raw.
        unsafe { core::ptr::addr_of_mut!((*cell).magic).write(0) };
        Ok(cell)
    }

    /// Fills a claimed cell with an empty model and estimator (all bytes valid, so that the
    /// cell can be referenced) and returns it.
    ///
    /// # Safety
    /// `cell` must come from [`EstimatorCell::claim`] in the same call.
    pub(crate) unsafe fn fill<'a>(cell: *mut Self) -> &'a mut Self {
        // SAFETY: the fields of a claimed cell are writable; `write` does not read or drop
        // the old bytes. After the three writes every field holds a valid value.
        unsafe {
            core::ptr::addr_of_mut!((*cell).model).write(CModel::empty());
            core::ptr::addr_of_mut!((*cell).est).write(CEstimator::empty());
            &mut *cell
        }
    }

    /// Marks the cell initialised (the model and the estimator loaded).
    pub(crate) fn seal(&mut self) {
        self.magic = ESTIMATOR_MAGIC;
    }

    /// The cell of an initialised estimator, shared.
    ///
    /// # Safety
    /// If `p` is non-null and aligned, it must point to `NEMM_ESTIMATOR_SIZE` readable
    /// bytes (an estimator's storage) that no other context writes during the borrow.
    pub(crate) unsafe fn get<'a>(p: *const nemm_estimator_t) -> Result<&'a Self, nemm_status_t> {
        let cell = p.cast::<Self>();
        checked(cell)?;
        // SAFETY: `cell` is non-null and aligned and the storage holds at least the `u32`
        // mark at offset 0 (`repr(C)`); every bit pattern is a valid `u32`.
        let magic = unsafe { core::ptr::addr_of!((*cell).magic).read() };
        if magic != ESTIMATOR_MAGIC {
            return Err(NEMM_E_NOT_INITIALISED);
        }
        // SAFETY: the mark is written only by a successful init, after which the cell holds
        // a valid model and estimator; the caller gives shared access for the borrow.
        Ok(unsafe { &*cell })
    }

    /// The cell of an initialised estimator, exclusive.
    ///
    /// # Safety
    /// As [`EstimatorCell::get`], and no other context accesses the storage during the
    /// borrow.
    pub(crate) unsafe fn get_mut<'a>(
        p: *mut nemm_estimator_t,
    ) -> Result<&'a mut Self, nemm_status_t> {
        // SAFETY: the caller's guarantees are those `get` needs.
        unsafe { Self::get(p) }?;
        // SAFETY: `get` checked pointer and mark; the caller gives exclusive access.
        Ok(unsafe { &mut *p.cast::<Self>() })
    }
}

impl ObserverCell {
    /// As [`EstimatorCell::claim`], for `nemm_observer_init`.
    ///
    /// # Safety
    /// As [`EstimatorCell::claim`].
    pub(crate) unsafe fn claim(
        p: *mut nemm_observer_t,
        size: usize,
    ) -> Result<*mut Self, nemm_status_t> {
        let cell = fresh::<Self>(p.cast(), size)?;
        // SAFETY: as in `EstimatorCell::claim`.
        unsafe { core::ptr::addr_of_mut!((*cell).magic).write(0) };
        Ok(cell)
    }

    /// As [`EstimatorCell::fill`]: an empty observer.
    ///
    /// # Safety
    /// `cell` must come from [`ObserverCell::claim`] in the same call.
    pub(crate) unsafe fn fill<'a>(cell: *mut Self) -> &'a mut Self {
        // SAFETY: as in `EstimatorCell::fill`.
        unsafe {
            core::ptr::addr_of_mut!((*cell).obs).write(EMPTY_OBSERVER);
            &mut *cell
        }
    }

    /// Marks the cell initialised.
    pub(crate) fn seal(&mut self) {
        self.magic = OBSERVER_MAGIC;
    }

    /// The cell of an initialised observer, shared.
    ///
    /// # Safety
    /// As [`EstimatorCell::get`], for an observer's storage.
    pub(crate) unsafe fn get<'a>(p: *const nemm_observer_t) -> Result<&'a Self, nemm_status_t> {
        let cell = p.cast::<Self>();
        checked(cell)?;
        // SAFETY: as in `EstimatorCell::get`.
        let magic = unsafe { core::ptr::addr_of!((*cell).magic).read() };
        if magic != OBSERVER_MAGIC {
            return Err(NEMM_E_NOT_INITIALISED);
        }
        // SAFETY: as in `EstimatorCell::get`.
        Ok(unsafe { &*cell })
    }

    /// The cell of an initialised observer, exclusive.
    ///
    /// # Safety
    /// As [`EstimatorCell::get_mut`], for an observer's storage.
    pub(crate) unsafe fn get_mut<'a>(
        p: *mut nemm_observer_t,
    ) -> Result<&'a mut Self, nemm_status_t> {
        // SAFETY: the caller's guarantees are those `get` needs.
        unsafe { Self::get(p) }?;
        // SAFETY: `get` checked pointer and mark; the caller gives exclusive access.
        Ok(unsafe { &mut *p.cast::<Self>() })
    }
}

/// A pointer to an out-parameter, checked for null (any alignment is accepted for the
/// plain structs: they are written unaligned).
pub(crate) fn out<T>(p: *mut T) -> Result<*mut T, nemm_status_t> {
    if p.is_null() {
        Err(NEMM_E_NULL)
    } else {
        Ok(p)
    }
}
