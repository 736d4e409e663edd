//! The bench controller's alpha observer: nemm-core's [`AlphaObserver`] on the level tables
//! the weights blob stores ([`LevelTables`]), so that its levels step at table cost.
//!
//! [`FwObserver::load`] reads the blob's stored levels of [`crate::TABLE_SEGMENTS`]
//! segments (a blob exported with `--tables-levels 7`: the firmware's trained model) into a
//! [`LevelTables`] in its own `static`, which holds references into the weights slot: the
//! tables are read in place from flash, not copied to RAM. It takes them as the observer's grid
//! ([`AlphaObserver::load_on_levels`]); each step is then 7 table-mode model steps. A blob
//! without level tables gives the exact observer (the grid over the trained range,
//! [`AlphaObserver::load`]): the same estimate up to the tables' error, about 7.5 exact
//! steps per sample, which does not fit the 100 us period of a 168 MHz Cortex-M4F. The
//! `observer ok` line says which (`levels_from=blob|exact`).

use crate::{observer_config, OBSERVER_LEVELS, PARAM_CAPACITY, TABLE_SEGMENTS};
use nemm_core::{
    AlphaEstimate, AlphaObserver, LevelTables, Model, ObserverError, Sample, StoredTables,
};

/// The level tables of the firmware's observer: up to [`OBSERVER_LEVELS`] levels of
/// [`TABLE_SEGMENTS`]-segment tables, read in place from the weights slot (`2 x (32 + 28 x
/// 128)` bytes of flash per level for a NEMM; the `LevelTables` themselves are a few hundred
/// bytes of RAM). They live in their own `static` (the observer holds them by reference).
pub type FwLevels = LevelTables<'static, TABLE_SEGMENTS, OBSERVER_LEVELS>;

/// The firmware's alpha observer and the level tables it steps on.
#[derive(Debug, Clone)]
pub struct FwObserver {
    observer: AlphaObserver<'static, PARAM_CAPACITY, OBSERVER_LEVELS>,
    levels: Option<&'static FwLevels>,
}

impl FwObserver {
    /// No model (a `const fn`: the storage of a `static`).
    pub const fn empty() -> Self {
        Self {
            observer: AlphaObserver::empty(),
            levels: None,
        }
    }

    /// Loads `model` in place: on the blob's level tables when it stores them (`tables` is
    /// the index [`nemm_core::decode_into`] returned for `blob`, the weights slot's blob,
    /// 4-byte aligned: `levels`, the storage of a `static`, then refers to its tables in
    /// flash), else exact. The observer's settings are [`observer_config`].
    pub fn load(
        &mut self,
        levels: &'static mut FwLevels,
        model: &Model<PARAM_CAPACITY>,
        tables: &StoredTables,
        blob: &'static [u8],
    ) -> Result<(), ObserverError> {
        let loaded = levels.load(model, tables, blob).is_ok();
        let levels: &'static FwLevels = levels;
        self.levels = None;
        if loaded {
            self.observer
                .load_on_levels(model, levels, observer_config())?;
            self.levels = Some(levels);
            Ok(())
        } else {
            self.observer.load(model, observer_config())
        }
    }

    /// One sample: the velocity, the position and the measured force (see
    /// [`AlphaObserver::step`]; on the level tables when loaded on them).
    #[inline(always)]
    pub fn step(&mut self, sample: Sample) -> AlphaEstimate {
        self.observer.step(sample)
    }

    /// The observer.
    pub fn observer(&self) -> &AlphaObserver<'static, PARAM_CAPACITY, OBSERVER_LEVELS> {
        &self.observer
    }

    /// The level tables the observer steps on (`None` when the blob stores none).
    pub fn levels(&self) -> Option<&'static FwLevels> {
        self.levels
    }

    /// Whether the levels step on the blob's level tables (else on the exact scalers).
    pub fn on_levels(&self) -> bool {
        self.levels.is_some()
    }

    /// The observer's levels \[-\].
    pub fn points(&self) -> usize {
        self.observer.points()
    }

    /// Model steps per observer step.
    pub fn evaluations_per_step(&self) -> usize {
        self.observer.evaluations_per_step()
    }

    /// Windows solved since the last load or reset ([`AlphaObserver::solves`]): one per
    /// close of a block of stroke cycles, the observer's heaviest step.
    pub fn solves(&self) -> u32 {
        self.observer.solves()
    }
}
