//! The plain C structs and constants the functions take and fill: configurations, results,
//! information, flag bits and the values of the `uint32_t` selector fields.

use crate::status::nemm_status_t::{self, NEMM_E_INVALID_ARGUMENT};
use crate::NEMM_LEVELS_CAPACITY;
use nemm_core::{
    AlphaEstimate, Estimate, EvalMode, Flags, ModelKind, ObserverConfig, ObserverFlags, Sample,
    TableOrigin,
};

/// `mode`: the compiled networks, the reference arithmetic (default).
pub const NEMM_MODE_EXACT: u32 = 0;
/// `mode`: the networks tabulated at init (`NEMM_TABLE_SEGMENTS` cubic segments each,
/// checked against the exact networks within `table_max_rel_error`), faster per step; the
/// blob's stored tables are used when they match.
pub const NEMM_MODE_TABLE: u32 = 1;

/// `kind`: static empirical model (force-velocity map per oil-loss level).
pub const NEMM_KIND_SEM: u32 = 0;
/// `kind`: equivalent mechanical model with constant coefficients.
pub const NEMM_KIND_LINEAR_EMM: u32 = 1;
/// `kind`: EMM with a neural friction coefficient `b_fl(v_st, alpha)`.
pub const NEMM_KIND_NEMM_LIGHT: u32 = 2;
/// `kind`: EMM with neural `b_fl`, `b_pr` and `k_pr`.
pub const NEMM_KIND_NEMM: u32 = 3;

/// `table_origin`: no tables (exact mode, or a model without neural coefficients).
pub const NEMM_TABLES_NONE: u32 = 0;
/// `table_origin`: the tables were built and checked at init (or by a change of alpha).
pub const NEMM_TABLES_BUILT: u32 = 1;
/// `table_origin`: the tables were read from the blob's tables section (no build at init).
pub const NEMM_TABLES_STORED: u32 = 2;

/// Estimate flag: the velocity was NaN or infinite (the last good one was used).
pub const NEMM_FLAG_INPUT_NON_FINITE: u8 = 1 << 0;
/// Estimate flag: the velocity was beyond the plausibility limit (the last good one was
/// used).
pub const NEMM_FLAG_INPUT_OUT_OF_RANGE: u8 = 1 << 1;
/// Estimate flag: the last good velocity was used instead of this sample.
pub const NEMM_FLAG_INPUT_HELD: u8 = 1 << 2;
/// Estimate flag: the state diverged (non-finite or runaway) and was reset to rest.
pub const NEMM_FLAG_STATE_RESET: u8 = 1 << 3;
/// Estimate flag: `alpha` lies outside the oil-loss range the model was trained on.
pub const NEMM_FLAG_ALPHA_EXTRAPOLATED: u8 = 1 << 4;
/// Estimate flag: table mode, the state lies outside a table's domain (the coefficient was
/// clamped to the boundary value).
pub const NEMM_FLAG_OUT_OF_TABLE_DOMAIN: u8 = 1 << 5;
/// Estimate flag: the model has a static force and this step had no usable position (a
/// step without one, or a non-finite one): the last good position was used.
pub const NEMM_FLAG_POSITION_MISSING: u8 = 1 << 6;
/// Estimate flag: no model (never set by an initialised estimator).
pub const NEMM_FLAG_NO_MODEL: u8 = 1 << 7;

/// Observer flag: the band is wider than `max_band`: the data so far do not tell the levels
/// apart (too little motion over the window).
pub const NEMM_OBSERVER_NOT_EXCITED: u8 = 1 << 0;
/// Observer flag: the best fit lies outside the model's trained range by more than the band.
pub const NEMM_OBSERVER_OUT_OF_RANGE: u8 = 1 << 1;
/// Observer flag: the velocity was non-finite or beyond its limit, or a fault lies less
/// than `fault_holdoff_s` back.
pub const NEMM_OBSERVER_VELOCITY_FAULT: u8 = 1 << 2;
/// Observer flag: the measured force was non-finite or beyond `force_limit_n`.
pub const NEMM_OBSERVER_FORCE_FAULT: u8 = 1 << 3;
/// Observer flag: the residual was an outlier and was weighted down.
pub const NEMM_OBSERVER_OUTLIER: u8 = 1 << 4;
/// Observer flag: this sample did not update the estimate (a fault, its hold-off, or the
/// warm-up).
pub const NEMM_OBSERVER_HELD: u8 = 1 << 5;
/// Observer flag: the estimate is not settled (no window solved yet, it moved at its last
/// update, the newest block of stroke cycles disagrees with it, or the level changed and
/// the window restarted).
pub const NEMM_OBSERVER_NOT_SETTLED: u8 = 1 << 6;
/// Observer flag: no model (never set by an initialised observer).
pub const NEMM_OBSERVER_NO_MODEL: u8 = 1 << 7;

const _: () = {
    assert!(NEMM_FLAG_INPUT_NON_FINITE == Flags::INPUT_NON_FINITE);
    assert!(NEMM_FLAG_INPUT_OUT_OF_RANGE == Flags::INPUT_OUT_OF_RANGE);
    assert!(NEMM_FLAG_INPUT_HELD == Flags::INPUT_HELD);
    assert!(NEMM_FLAG_STATE_RESET == Flags::STATE_RESET);
    assert!(NEMM_FLAG_ALPHA_EXTRAPOLATED == Flags::ALPHA_EXTRAPOLATED);
    assert!(NEMM_FLAG_OUT_OF_TABLE_DOMAIN == Flags::OUT_OF_TABLE_DOMAIN);
    assert!(NEMM_FLAG_POSITION_MISSING == Flags::POSITION_MISSING);
    assert!(NEMM_FLAG_NO_MODEL == Flags::NO_MODEL);
    assert!(NEMM_OBSERVER_NOT_EXCITED == ObserverFlags::NOT_EXCITED);
    assert!(NEMM_OBSERVER_OUT_OF_RANGE == ObserverFlags::OUT_OF_RANGE);
    assert!(NEMM_OBSERVER_VELOCITY_FAULT == ObserverFlags::VELOCITY_FAULT);
    assert!(NEMM_OBSERVER_FORCE_FAULT == ObserverFlags::FORCE_FAULT);
    assert!(NEMM_OBSERVER_OUTLIER == ObserverFlags::OUTLIER);
    assert!(NEMM_OBSERVER_HELD == ObserverFlags::HELD);
    assert!(NEMM_OBSERVER_NOT_SETTLED == ObserverFlags::NOT_SETTLED);
    assert!(NEMM_OBSERVER_NO_MODEL == ObserverFlags::NO_MODEL);
};

/// The `kind` value of a model kind.
pub(crate) fn kind_value(kind: ModelKind) -> u32 {
    match kind {
        ModelKind::Sem => NEMM_KIND_SEM,
        ModelKind::LinearEmm => NEMM_KIND_LINEAR_EMM,
        ModelKind::NemmLight => NEMM_KIND_NEMM_LIGHT,
        ModelKind::Nemm => NEMM_KIND_NEMM,
    }
}

/// What `nemm_blob_validate` read from a blob's header.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct nemm_blob_info_t {
    /// Format version of the blob.
    pub format_version: u32,
    /// Model kind, a `NEMM_KIND_*` value.
    pub kind: u32,
    /// Parameters of the model's largest scaler (at most `NEMM_PARAM_CAPACITY`).
    pub max_scaler_params: u32,
    /// Length of the whole blob in bytes (header, body, CRC).
    pub blob_len: u32,
}

/// Settings of an estimator. A zero-initialised struct with `alpha` set is a complete
/// configuration: `{ .alpha = 0.15f }` is the exact mode with the default limits.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct nemm_estimator_config_t {
    /// Oil-loss level `alpha` in `[0, 1]` (fraction of the oil volume lost).
    pub alpha: f32,
    /// `NEMM_MODE_EXACT` (0) or `NEMM_MODE_TABLE`.
    pub mode: u32,
    /// Largest plausible |velocity| (m/s); a sample beyond it is replaced by the last good
    /// one (flagged). 0: three times the model's training abs-max velocity.
    pub velocity_limit_m_s: f32,
    /// Table mode: the largest relative error of each table against its exact network,
    /// checked at init. 0: `NEMM_TABLE_MAX_REL_ERROR`.
    pub table_max_rel_error: f32,
}

/// The result of one estimator step.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct nemm_estimate_t {
    /// Estimated damper force (N), positive in tension (rebound). Always finite.
    pub force_n: f32,
    /// What happened in this step: `NEMM_FLAG_*` bits (0: a normal step).
    pub flags: u8,
}

/// `nemm_sample_t.fields`: `position_m` is present.
pub const NEMM_SAMPLE_POSITION: u8 = 1 << 0;
/// `nemm_sample_t.fields`: `alpha` is present.
pub const NEMM_SAMPLE_ALPHA: u8 = 1 << 1;
/// `nemm_sample_t.fields`: `force_n` is present.
pub const NEMM_SAMPLE_FORCE: u8 = 1 << 2;

/// One sample of the damper's signals, the input of `nemm_estimator_step` and
/// `nemm_observer_step`: the stroke velocity, and the optional signals that `fields` marks
/// present (`NEMM_SAMPLE_*` bits; a field whose bit is clear is not read). A present value
/// that is NaN or infinite is a sensor fault, flagged by the step as such, not an absent
/// value.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct nemm_sample_t {
    /// Stroke velocity (m/s), positive = extension. Always read.
    pub velocity_m_s: f32,
    /// Stroke position (m) as the position sensor measures it (the coordinates the model was
    /// trained in), with `NEMM_SAMPLE_POSITION`: for a model with a static force
    /// (`needs_position`); without it such a step holds the last good position and is flagged
    /// `NEMM_FLAG_POSITION_MISSING`. Other models ignore it.
    pub position_m: f32,
    /// This sample's oil-loss (condition) level in `[0, 1]`, with `NEMM_SAMPLE_ALPHA`;
    /// without it the estimator steps at its own level. The observer ignores it.
    pub alpha: f32,
    /// Measured damper force (N), positive in tension, with `NEMM_SAMPLE_FORCE`: the
    /// observer's input (without it the sample is a missing measurement,
    /// `NEMM_OBSERVER_FORCE_FAULT`). The estimator ignores it.
    pub force_n: f32,
    /// Which optional fields are present: `NEMM_SAMPLE_POSITION`, `NEMM_SAMPLE_ALPHA`,
    /// `NEMM_SAMPLE_FORCE` (other bits: `NEMM_E_INVALID_ARGUMENT`).
    pub fields: u8,
}

impl nemm_sample_t {
    /// The nemm-core sample; other bits than the three `NEMM_SAMPLE_*` are refused.
    pub(crate) fn to_core(self) -> Result<Sample, nemm_status_t> {
        let f = self.fields;
        if f & !(NEMM_SAMPLE_POSITION | NEMM_SAMPLE_ALPHA | NEMM_SAMPLE_FORCE) != 0 {
            return Err(NEMM_E_INVALID_ARGUMENT);
        }
        let present = |bit: u8, v: f32| (f & bit != 0).then_some(v);
        Ok(Sample {
            velocity_m_s: self.velocity_m_s,
            position_m: present(NEMM_SAMPLE_POSITION, self.position_m),
            alpha: present(NEMM_SAMPLE_ALPHA, self.alpha),
            force_n: present(NEMM_SAMPLE_FORCE, self.force_n),
        })
    }
}

impl From<Estimate> for nemm_estimate_t {
    fn from(e: Estimate) -> Self {
        Self {
            force_n: e.force_n,
            flags: e.flags.0,
        }
    }
}

/// What an initialised estimator holds: its model, settings and counters.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct nemm_estimator_info_t {
    /// Model kind, a `NEMM_KIND_*` value.
    pub kind: u32,
    /// `NEMM_MODE_EXACT` or `NEMM_MODE_TABLE`.
    pub mode: u32,
    /// Where the tables came from: `NEMM_TABLES_NONE`, `_BUILT` or `_STORED`.
    pub table_origin: u32,
    /// Bytes of the tables in use (0 without tables).
    pub table_bytes: u32,
    /// 1 if the model adds a static force and so needs the stroke position
    /// (`nemm_estimator_step_with_position`), else 0.
    pub needs_position: u32,
    /// The step the model was trained at (s): call a step function once per this period.
    pub dt_s: f32,
    /// The oil-loss level in use.
    pub alpha: f32,
    /// The model's trained oil-loss range, lowest first.
    pub alpha_min: f32,
    /// Highest trained oil-loss level.
    pub alpha_max: f32,
    /// The plausibility limit of the velocity in use (m/s).
    pub velocity_limit_m_s: f32,
    /// Steps since init.
    pub steps: u32,
    /// Samples replaced by the last good velocity since init.
    pub held_samples: u32,
    /// Divergence resets since init.
    pub resets: u32,
}

/// The `mode` value of an evaluation mode.
pub(crate) fn mode_value(mode: EvalMode) -> u32 {
    match mode {
        EvalMode::Exact => NEMM_MODE_EXACT,
        EvalMode::Table(_) => NEMM_MODE_TABLE,
    }
}

/// The `table_origin` value of a table origin.
pub(crate) fn origin_value(origin: TableOrigin) -> u32 {
    match origin {
        TableOrigin::None => NEMM_TABLES_NONE,
        TableOrigin::Built(_) => NEMM_TABLES_BUILT,
        TableOrigin::Stored => NEMM_TABLES_STORED,
    }
}

/// What loaded level tables hold (`nemm_levels_info`).
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct nemm_levels_info_t {
    /// Number of levels loaded (2 to `NEMM_LEVELS_CAPACITY`).
    pub levels: u32,
    /// Bytes the loaded tables take in the blob, where they are read in place (`32 + 28 x
    /// NEMM_TABLE_SEGMENTS` per table, two tables per level for the NEMM, one for
    /// NEMM-Light): the blob's memory (flash on a microcontroller), not the storage's. The
    /// level tables' RAM is their storage, `NEMM_LEVELS_SIZE` bytes whatever the number of
    /// levels.
    pub table_bytes: u32,
    /// The error bound every level's tables were built and checked with (relative, against
    /// the exact network at that level).
    pub table_max_rel_error: f32,
    /// The levels, ascending; the entries from `levels` on are 0.
    pub alpha: [f32; NEMM_LEVELS_CAPACITY],
}

/// Settings of an alpha observer. Start from `nemm_observer_config_default`; the fields
/// whose default depends on the model are 0 there and mean "the model's".
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct nemm_observer_config_t {
    /// Lowest level of the grid in `[0, 1]`; `grid_lo` and `grid_hi` both 0: the model's
    /// trained range (`[0, 1]` for a model trained at one level).
    pub grid_lo: f32,
    /// Highest level of the grid in `[0, 1]`, above `grid_lo`.
    pub grid_hi: f32,
    /// Levels of the grid, `2..=NEMM_OBSERVER_MAX_POINTS`; 0: `NEMM_OBSERVER_MAX_POINTS`.
    pub points: u32,
    /// Window length (s): the estimate is the fit over the newest whole stroke cycles
    /// within it, updated at each close of a block of cycles (at least an eighth of the
    /// window). Default 3 s.
    pub horizon_s: f32,
    /// Outlier threshold, a multiple (> 1) of the running mean absolute residual. Default 4.
    pub outlier_threshold: f32,
    /// Time constant of the running mean absolute residual (s). Default 0.05 s.
    pub scale_horizon_s: f32,
    /// Force noise floor (N) of the band; 0: 1e-3 of the model's force scale.
    pub force_noise_n: f32,
    /// Largest plausible |force| (N), beyond it a sensor fault; 0: three times the model's
    /// force scale.
    pub force_limit_n: f32,
    /// Largest plausible |velocity| (m/s); 0: the estimator's default.
    pub velocity_limit_m_s: f32,
    /// Time (s) after a velocity fault during which the estimate is not updated. Default
    /// 0.005 s.
    pub fault_holdoff_s: f32,
    /// Time (s) from init and reset during which the estimate is not updated. Default
    /// 0.01 s.
    pub warmup_s: f32,
    /// Correlation time of the fit residual assumed by the band (s). Default 0.005 s.
    pub residual_correlation_s: f32,
    /// Half-width of the band in standard deviations. Default 2.
    pub band_sigmas: f32,
    /// Widest band (half-width, in alpha) at which the data count as exciting. Default 0.05.
    pub max_band: f32,
    /// Hysteresis of the stroke-cycle detector, a fraction in (0, 1) of the recent peak
    /// velocity. Default 0.1.
    pub crossing_hysteresis: f32,
    /// Settle tolerance (alpha): `NEMM_OBSERVER_NOT_SETTLED` unless the last update moved
    /// the estimate by at most this and the newest block's own fit agrees with it. Default
    /// 0.02.
    pub settle_tolerance: f32,
    /// Change tolerance (alpha): the two newest blocks within this of each other and both
    /// beyond it from the older blocks, on one side, restart the window. Default 0.03.
    pub change_tolerance: f32,
}

impl nemm_observer_config_t {
    /// nemm-core's defaults.
    pub(crate) fn default_values() -> Self {
        let d = ObserverConfig::new();
        let (grid_lo, grid_hi) = d.grid.unwrap_or((0.0, 0.0));
        let zero_if_none = |v: Option<f32>| v.unwrap_or(0.0);
        Self {
            grid_lo,
            grid_hi,
            points: d.points.map_or(0, |p| u32::try_from(p).unwrap_or(u32::MAX)),
            horizon_s: d.horizon_s,
            outlier_threshold: d.outlier_threshold,
            scale_horizon_s: d.scale_horizon_s,
            force_noise_n: zero_if_none(d.force_noise_n),
            force_limit_n: zero_if_none(d.force_limit_n),
            velocity_limit_m_s: zero_if_none(d.velocity_limit_m_s),
            fault_holdoff_s: d.fault_holdoff_s,
            warmup_s: d.warmup_s,
            residual_correlation_s: d.residual_correlation_s,
            band_sigmas: d.band_sigmas,
            max_band: d.max_band,
            crossing_hysteresis: d.crossing_hysteresis,
            settle_tolerance: d.settle_tolerance,
            change_tolerance: d.change_tolerance,
        }
    }

    /// The nemm-core configuration (0 of a model-dependent field: `None`).
    pub(crate) fn to_core(self) -> ObserverConfig {
        let none_if_zero = |v: f32| (v != 0.0).then_some(v);
        ObserverConfig {
            grid: (self.grid_lo != 0.0 || self.grid_hi != 0.0)
                .then_some((self.grid_lo, self.grid_hi)),
            points: (self.points != 0).then_some(self.points as usize),
            horizon_s: self.horizon_s,
            outlier_threshold: self.outlier_threshold,
            scale_horizon_s: self.scale_horizon_s,
            force_noise_n: none_if_zero(self.force_noise_n),
            force_limit_n: none_if_zero(self.force_limit_n),
            velocity_limit_m_s: none_if_zero(self.velocity_limit_m_s),
            fault_holdoff_s: self.fault_holdoff_s,
            warmup_s: self.warmup_s,
            residual_correlation_s: self.residual_correlation_s,
            band_sigmas: self.band_sigmas,
            max_band: self.max_band,
            crossing_hysteresis: self.crossing_hysteresis,
            settle_tolerance: self.settle_tolerance,
            change_tolerance: self.change_tolerance,
        }
    }
}

/// The result of one observer step.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct nemm_alpha_estimate_t {
    /// Estimated oil-loss level, within the grid. Always finite.
    pub alpha: f32,
    /// Half-width of the uncertainty band (`alpha +- band`), at most the grid's span.
    pub band: f32,
    /// The model's force at the estimate (N).
    pub force_n: f32,
    /// `NEMM_OBSERVER_*` bits (0: an excited, in-range estimate updated by a good sample).
    pub flags: u8,
}

impl From<AlphaEstimate> for nemm_alpha_estimate_t {
    fn from(a: AlphaEstimate) -> Self {
        Self {
            alpha: a.alpha,
            band: a.band,
            force_n: a.force_n,
            flags: a.flags.0,
        }
    }
}
