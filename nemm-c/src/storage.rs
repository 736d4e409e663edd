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
use crate::{
    NEMM_LEVELS_CAPACITY, NEMM_OBSERVER_MAX_POINTS, NEMM_PARAM_CAPACITY, NEMM_TABLE_SEGMENTS,
};
use core::mem::{align_of, size_of};
use nemm_core::{AlphaObserver, Estimator, LevelTables, Model, StoredTables};

/// The model, as the library decodes it.
pub(crate) type CModel = Model<NEMM_PARAM_CAPACITY>;
/// The estimator, as the firmware instantiates it.
pub(crate) type CEstimator = Estimator<'static, NEMM_PARAM_CAPACITY, NEMM_TABLE_SEGMENTS>;
/// The alpha observer.
pub(crate) type CObserver = AlphaObserver<'static, NEMM_PARAM_CAPACITY, NEMM_OBSERVER_MAX_POINTS>;
/// The level tables: the estimator's segment count, `NEMM_LEVELS_CAPACITY` levels, read in
/// place from a blob the caller keeps (the `'static` is `nemm_levels_init`'s contract: the
/// blob stays readable and unchanged while the level tables are in use).
pub(crate) type CLevels = LevelTables<'static, NEMM_TABLE_SEGMENTS, NEMM_LEVELS_CAPACITY>;

/// What a `nemm_estimator_t` holds: the decoded model and the index of the blob's tables
/// (kept, so that observers and level tables can be built from them), the estimator built
/// from the model, and which blob it came from.
#[repr(C)]
pub(crate) struct EstimatorCell {
    /// [`ESTIMATOR_MAGIC`] once `nemm_estimator_init` succeeded, anything else before.
    magic: u32,
    /// Length and CRC-32 trailer of the blob the model was decoded from.
    blob: (usize, u32),
    /// The index of the blob's tables (where each stored level's tables lie in the blob),
    /// as the decode of the model returned it: `nemm_levels_init` loads level tables from
    /// it, without decoding the blob again.
    pub(crate) tables: StoredTables,
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

/// What a `nemm_levels_t` holds: the level tables (a few hundred bytes: per level its
/// alpha, `b_pr` and references to its tables in the blob).
#[repr(C)]
pub(crate) struct LevelsCell {
    /// [`LEVELS_MAGIC`] once `nemm_levels_init` succeeded.
    magic: u32,
    levels: CLevels,
}

/// An empty observer, evaluated at compile time: copied into the storage rather than built
/// in a stack frame of its size.
const EMPTY_OBSERVER: CObserver = CObserver::empty();

/// An empty model: one image in flash for the estimator's model, copied into the storage.
static EMPTY_MODEL: CModel = CModel::empty();

/// The mark of an initialised estimator.
const ESTIMATOR_MAGIC: u32 = u32::from_le_bytes(*b"NEMe");
/// The mark of an initialised observer.
const OBSERVER_MAGIC: u32 = u32::from_le_bytes(*b"NEMo");
/// The mark of loaded level tables.
const LEVELS_MAGIC: u32 = u32::from_le_bytes(*b"NEMl");

/// Bytes of a `nemm_estimator_t`: the decoded model, the index of the blob's tables and
/// the estimator (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_ESTIMATOR_SIZE: usize = 48136;
/// Alignment of a `nemm_estimator_t` (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_ESTIMATOR_ALIGN: usize = 4;
/// Bytes of a `nemm_observer_t` (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_OBSERVER_SIZE: usize = 22696;
/// Alignment of a `nemm_observer_t` (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_OBSERVER_ALIGN: usize = 4;
/// Bytes of a `nemm_levels_t`: the level tables (their tables are read in place from the
/// blob, whatever the number of levels) (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_LEVELS_SIZE: usize = 188;
/// Alignment of a `nemm_levels_t` (32-bit targets).
#[cfg(target_pointer_width = "32")]
pub const NEMM_LEVELS_ALIGN: usize = 4;

/// Bytes of a `nemm_estimator_t`: the decoded model, the index of the blob's tables and
/// the estimator (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_ESTIMATOR_SIZE: usize = 48632;
/// Alignment of a `nemm_estimator_t` (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_ESTIMATOR_ALIGN: usize = 8;
/// Bytes of a `nemm_observer_t` (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_OBSERVER_SIZE: usize = 22848;
/// Alignment of a `nemm_observer_t` (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_OBSERVER_ALIGN: usize = 8;
/// Bytes of a `nemm_levels_t`: the level tables (their tables are read in place from the
/// blob, whatever the number of levels) (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_LEVELS_SIZE: usize = 264;
/// Alignment of a `nemm_levels_t` (64-bit targets).
#[cfg(target_pointer_width = "64")]
pub const NEMM_LEVELS_ALIGN: usize = 8;

// The header's constants are the objects' sizes and alignments, exactly (a mismatch names
// both numbers: the constant first).
const _: [(); NEMM_ESTIMATOR_SIZE] = [(); size_of::<EstimatorCell>()];
const _: [(); NEMM_ESTIMATOR_ALIGN] = [(); align_of::<EstimatorCell>()];
const _: [(); NEMM_OBSERVER_SIZE] = [(); size_of::<ObserverCell>()];
const _: [(); NEMM_OBSERVER_ALIGN] = [(); align_of::<ObserverCell>()];
const _: [(); NEMM_LEVELS_SIZE] = [(); size_of::<LevelsCell>()];
const _: [(); NEMM_LEVELS_ALIGN] = [(); align_of::<LevelsCell>()];

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

/// Storage of one set of level tables (the stored tables of several oil-loss levels, read
/// in place from a blob by `nemm_levels_init`: the storage refers to the blob, which must
/// stay in place while the level tables are in use): `NEMM_LEVELS_SIZE` bytes aligned to
/// `NEMM_LEVELS_ALIGN`, opaque to the caller (as `nemm_estimator_t`).
#[allow(non_camel_case_types)]
#[repr(C)]
pub struct nemm_levels_t {
    /// The level tables' bytes (opaque).
    pub opaque: [u8; NEMM_LEVELS_SIZE],
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

/// A storage cell of the interface (`nemm_estimator_t`, `nemm_observer_t`,
/// `nemm_levels_t`): its `u32` mark at offset 0, written with [`Marked::MAGIC`] by the init
/// function only once the cell holds valid values, so that a pointer to storage that was
/// never initialised (or failed to be) is refused, not read.
///
/// # Safety
/// An implementor is `repr(C)` with its `magic: u32` field first (offset 0; checked at
/// compile time below for the three cells), and every cell that carries the mark holds
/// valid values in all its fields.
pub(crate) unsafe trait Marked: Sized {
    /// The header's storage type of the cell.
    type Storage;
    /// The mark of an initialised cell.
    const MAGIC: u32;

    /// Checks the storage for the init function and marks it uninitialised; the fields are
    /// still to be written.
    ///
    /// # Safety
    /// If `p` is non-null, `size` bytes at `p` must be writable and not accessed otherwise
    /// during the call.
    unsafe fn claim(p: *mut Self::Storage, size: usize) -> Result<*mut Self, nemm_status_t> {
        let cell = fresh::<Self>(p.cast(), size)?;
        // SAFETY: `cell` is non-null, aligned and the storage holds a whole cell (checked
        // above); the caller lends it to this call. The mark is the `u32` at offset 0 (the
        // trait's contract), written raw.
        unsafe { cell.cast::<u32>().write(0) };
        Ok(cell)
    }

    /// The cell behind `p` if it carries the mark.
    ///
    /// # Safety
    /// If `p` is non-null and aligned, it must point to the storage's readable bytes that
    /// no other context writes during the call.
    unsafe fn marked(p: *const Self::Storage) -> Result<*const Self, nemm_status_t> {
        let cell = p.cast::<Self>();
        checked(cell)?;
        // SAFETY: `cell` is non-null and aligned and the storage holds at least the `u32`
        // mark at offset 0 (the trait's contract); every bit pattern is a valid `u32`.
        let magic = unsafe { cell.cast::<u32>().read() };
        if magic != Self::MAGIC {
            return Err(NEMM_E_NOT_INITIALISED);
        }
        Ok(cell)
    }

    /// The cell of an initialised object, shared.
    ///
    /// # Safety
    /// As [`Marked::marked`], and no other context writes the storage during the borrow.
    unsafe fn get<'a>(p: *const Self::Storage) -> Result<&'a Self, nemm_status_t> {
        // SAFETY: the mark is written only once the cell holds valid values (the trait's
        // contract); the caller gives shared access for the borrow.
        Ok(unsafe { &*Self::marked(p)? })
    }

    /// The cell of an initialised object, exclusive.
    ///
    /// # Safety
    /// As [`Marked::get`], and no other context accesses the storage during the borrow.
    unsafe fn get_mut<'a>(p: *mut Self::Storage) -> Result<&'a mut Self, nemm_status_t> {
        // SAFETY: the caller's guarantees are those `marked` needs.
        unsafe { Self::marked(p)? };
        // SAFETY: `marked` checked pointer and mark (the cell holds valid values); the
        // caller gives exclusive access through its mutable pointer.
        Ok(unsafe { &mut *p.cast::<Self>() })
    }
}

// The mark is the first field of every cell (the contract of `Marked`).
const _: () = assert!(core::mem::offset_of!(EstimatorCell, magic) == 0);
const _: () = assert!(core::mem::offset_of!(ObserverCell, magic) == 0);
const _: () = assert!(core::mem::offset_of!(LevelsCell, magic) == 0);

// SAFETY: `repr(C)`, `magic` first; `seal` marks it after `fill` wrote every field.
unsafe impl Marked for EstimatorCell {
    type Storage = nemm_estimator_t;
    const MAGIC: u32 = ESTIMATOR_MAGIC;
}

// SAFETY: `repr(C)`, `magic` first; `seal` marks it after `fill` wrote every field.
unsafe impl Marked for ObserverCell {
    type Storage = nemm_observer_t;
    const MAGIC: u32 = OBSERVER_MAGIC;
}

// SAFETY: `repr(C)`, `magic` first; `seal` marks it after `fill` wrote the level tables
// and they were loaded.
unsafe impl Marked for LevelsCell {
    type Storage = nemm_levels_t;
    const MAGIC: u32 = LEVELS_MAGIC;
}

impl EstimatorCell {
    /// Fills a claimed cell with an empty tables index, model and estimator (all bytes
    /// valid, so that the cell can be referenced) and returns it.
    ///
    /// # Safety
    /// `cell` must come from [`Marked::claim`] in the same call.
    pub(crate) unsafe fn fill<'a>(cell: *mut Self) -> &'a mut Self {
        // SAFETY: the fields of a claimed cell are writable; `write` and the copy do not read
        // or drop the old bytes. A model owns nothing (no `Drop`, no pointers), so a bitwise
        // copy of `EMPTY_MODEL` is a valid model. After the writes every field holds a valid
        // value.
        unsafe {
            core::ptr::addr_of_mut!((*cell).blob).write((0, 0));
            core::ptr::addr_of_mut!((*cell).tables).write(StoredTables::EMPTY);
            core::ptr::addr_of_mut!((*cell).model).copy_from_nonoverlapping(&EMPTY_MODEL, 1);
            core::ptr::addr_of_mut!((*cell).est).write(CEstimator::empty());
            &mut *cell
        }
    }

    /// Marks the cell initialised (the model, the tables index and the estimator loaded
    /// from `blob`).
    pub(crate) fn seal(&mut self, blob: &[u8]) {
        self.blob = (blob.len(), trailer(blob));
        self.magic = ESTIMATOR_MAGIC;
    }

    /// True if `blob` has the length and CRC-32 trailer of the blob the model and the
    /// tables index were decoded from.
    pub(crate) fn built_from(&self, blob: &[u8]) -> bool {
        self.blob == (blob.len(), trailer(blob))
    }
}

impl ObserverCell {
    /// As [`EstimatorCell::fill`]: an empty observer, not on level tables.
    ///
    /// # Safety
    /// `cell` must come from [`Marked::claim`] in the same call.
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
}

impl LevelsCell {
    /// Fills a claimed cell with empty level tables and returns them.
    ///
    /// # Safety
    /// `cell` must come from [`Marked::claim`] in the same call.
    pub(crate) unsafe fn fill<'a>(cell: *mut Self) -> &'a mut CLevels {
        // SAFETY: the fields of a claimed cell are writable; `write` does not read or drop
        // the old bytes. After it the `levels` field holds valid (empty) tables.
        unsafe {
            let levels = core::ptr::addr_of_mut!((*cell).levels);
            levels.write(CLevels::empty());
            &mut *levels
        }
    }

    /// Marks the cell initialised (the level tables loaded, by [`LevelsCell::fill`]'s
    /// reference).
    ///
    /// # Safety
    /// `cell` must come from [`Marked::claim`] in the same call, its tables filled and
    /// loaded, and no reference into the cell alive.
    pub(crate) unsafe fn seal(cell: *mut Self) {
        // SAFETY: the caller's guarantees; a `u32` is written raw.
        unsafe { core::ptr::addr_of_mut!((*cell).magic).write(LEVELS_MAGIC) };
    }

    /// The tables of loaded level tables, shared.
    ///
    /// # Safety
    /// As [`Marked::get`], for a `nemm_levels_t`.
    pub(crate) unsafe fn tables<'a>(p: *const nemm_levels_t) -> Result<&'a CLevels, nemm_status_t> {
        // SAFETY: the caller's guarantees are those `marked` needs.
        let cell = unsafe { Self::marked(p) }?;
        // SAFETY: the mark is written only by a successful init, after the `levels` field
        // was written and loaded; the caller gives shared access.
        Ok(unsafe { &*core::ptr::addr_of!((*cell).levels) })
    }
}

/// The CRC-32 trailer of a blob (its last four bytes, little-endian; 0 if shorter).
fn trailer(blob: &[u8]) -> u32 {
    blob.len()
        .checked_sub(4)
        .and_then(|at| blob.get(at..))
        .and_then(|b| <[u8; 4]>::try_from(b).ok())
        .map_or(0, u32::from_le_bytes)
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
