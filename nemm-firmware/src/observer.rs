//! The bench controller's alpha observer: nemm-core's [`AlphaObserver`] on the level tables
//! the weights blob stores ([`LevelTables`]), so that its levels step at table cost.
//!
//! [`FwObserver::load`] reads the blob's stored levels of [`crate::TABLE_SEGMENTS`]
//! segments (a blob exported with `--tables-levels 7`: the firmware's trained model) into its
//! own [`LevelTables`] and takes them as the observer's grid
//! ([`AlphaObserver::load_on_levels`]); each step is then 7 table-mode model steps. A blob
//! without level tables gives the exact observer (the grid over the trained range,
//! [`AlphaObserver::load`]): the same estimate up to the tables' error, about 7.5 exact
//! steps per sample, which does not fit the 100 us period of a 168 MHz Cortex-M4F. The
//! `observer ok` line says which (`levels_from=blob|exact`).

use crate::{observer_config, OBSERVER_LEVELS, PARAM_CAPACITY, TABLE_SEGMENTS};
use nemm_core::{AlphaEstimate, AlphaObserver, LevelTables, Model, ObserverError, StoredTables};

/// The level tables of the firmware's observer: up to [`OBSERVER_LEVELS`] levels of
/// [`TABLE_SEGMENTS`]-segment tables (`2 x 28 x 128` bytes per level for a NEMM).
pub type FwLevels = LevelTables<TABLE_SEGMENTS, OBSERVER_LEVELS>;

/// The firmware's alpha observer and the level tables it steps on.
#[derive(Debug, Clone)]
pub struct FwObserver {
    observer: AlphaObserver<PARAM_CAPACITY, OBSERVER_LEVELS>,
    levels: FwLevels,
    on_levels: bool,
}

impl FwObserver {
    /// No model (a `const fn`: the storage of a `static`).
    pub const fn empty() -> Self {
        Self {
            observer: AlphaObserver::empty(),
            levels: LevelTables::empty(),
            on_levels: false,
        }
    }

    /// Loads `model` in place: on the blob's level tables when it stores them (`tables` is
    /// the index [`nemm_core::decode_into`] returned for `blob`), else exact. The
    /// observer's settings are [`observer_config`].
    pub fn load(
        &mut self,
        model: &Model<PARAM_CAPACITY>,
        tables: &StoredTables,
        blob: &[u8],
    ) -> Result<(), ObserverError> {
        self.on_levels = self.levels.load(model, tables, blob).is_ok();
        if self.on_levels {
            self.observer
                .load_on_levels(model, &self.levels, observer_config())
        } else {
            self.observer.load(model, observer_config())
        }
    }

    /// One sample (see [`AlphaObserver::step_with_position`]).
    #[inline(always)]
    pub fn step_with_position(
        &mut self,
        velocity_m_s: f32,
        position_m: f32,
        force_n: f32,
    ) -> AlphaEstimate {
        if self.on_levels {
            self.observer.step_on_levels_with_position(
                &self.levels,
                velocity_m_s,
                position_m,
                force_n,
            )
        } else {
            self.observer
                .step_with_position(velocity_m_s, position_m, force_n)
        }
    }

    /// One sample without a position (see [`AlphaObserver::step`]).
    #[inline(always)]
    pub fn step(&mut self, velocity_m_s: f32, force_n: f32) -> AlphaEstimate {
        if self.on_levels {
            self.observer
                .step_on_levels(&self.levels, velocity_m_s, force_n)
        } else {
            self.observer.step(velocity_m_s, force_n)
        }
    }

    /// The observer.
    pub fn observer(&self) -> &AlphaObserver<PARAM_CAPACITY, OBSERVER_LEVELS> {
        &self.observer
    }

    /// The level tables (empty when the blob stores none).
    pub fn levels(&self) -> &FwLevels {
        &self.levels
    }

    /// Whether the levels step on the blob's level tables (else on the exact scalers).
    pub fn on_levels(&self) -> bool {
        self.on_levels
    }

    /// The observer's levels \[-\].
    pub fn points(&self) -> usize {
        self.observer.points()
    }

    /// Model steps per observer step.
    pub fn evaluations_per_step(&self) -> usize {
        self.observer.evaluations_per_step()
    }
}
