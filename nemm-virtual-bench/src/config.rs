//! Configuration of the virtual bench: a TOML file with every parameter and its unit.
//!
//! The default (`nemm-virtual-bench/assets/bench.toml`) is compiled in; a user file must contain every
//! key (unknown keys are rejected so that typos do not silently fall back to a default).

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The built-in default configuration (reproduces Table 1 of the paper).
pub const DEFAULT_TOML: &str = include_str!("../assets/bench.toml");

/// The whole virtual-bench configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    /// Name written to the dataset manifest.
    pub name: String,
    /// Damper geometry.
    pub geometry: Geometry,
    /// Oil properties.
    pub oil: Oil,
    /// Reservoir gas charge.
    pub gas: Gas,
    /// Free gas carried in the working chambers as a function of oil loss.
    pub aeration: Aeration,
    /// Piston valve.
    pub piston: PistonValve,
    /// Base valve.
    pub base: BaseValve,
    /// Seal friction.
    pub friction: Friction,
    /// Integrator settings.
    pub solver: Solver,
    /// The test programme (grid of runs, run lengths, sample rate).
    pub program: Program,
    /// Measurement chain (noise, quantisation, tare).
    pub sensors: Sensors,
}

/// Damper geometry \[m, m³\].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Geometry {
    /// Piston (= pressure-tube bore) diameter \[m\].
    pub piston_diameter_m: f64,
    /// Piston-rod diameter \[m\].
    pub rod_diameter_m: f64,
    /// Length of the rebound chamber at mid-stroke \[m\].
    pub rebound_chamber_length_m: f64,
    /// Length of the compression chamber at mid-stroke \[m\].
    pub compression_chamber_length_m: f64,
    /// Free volume of the reserve tube \[m³\].
    pub reservoir_volume_m3: f64,
    /// Oil volume in the reserve tube at rest, mid-stroke, without oil loss \[m³\].
    pub reservoir_oil_volume_m3: f64,
    /// Wall thickness of the pressure tube \[m\] (its radial expansion is a compliance of the
    /// working chambers, `D / (t E)` per Pa).
    pub pressure_tube_wall_m: f64,
    /// Young's modulus of the pressure tube \[Pa\].
    pub tube_youngs_modulus_pa: f64,
}

/// Oil properties.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Oil {
    /// Bulk modulus of the gas-free oil at working temperature \[Pa\] (the pressure-tube
    /// compliance is added from the geometry, free gas from the aeration).
    pub bulk_modulus_pa: f64,
    /// Density \[kg/m³\].
    pub density_kg_m3: f64,
    /// Absolute pressure below which a chamber cavitates \[Pa\].
    pub cavitation_pressure_pa: f64,
}

/// Reservoir gas charge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gas {
    /// Ambient pressure and reference pressure of normal gas volumes \[Pa\].
    pub atmospheric_pressure_pa: f64,
    /// Absolute gas pressure at rest, mid-stroke, without oil loss \[Pa\].
    pub charge_pressure_pa: f64,
    /// Polytropic exponent of the reservoir gas pocket \[-\].
    pub polytropic_exponent: f64,
    /// Polytropic exponent of gas bubbles entrained in the oil \[-\].
    pub bubble_polytropic_exponent: f64,
    /// Fraction of the gas charge retained after the oil loss \[-\].
    pub retained_fraction: f64,
}

/// Free gas (foam) in the working chambers, transported with the oil flow; normal volumes
/// (at atmospheric pressure) per volume of oil.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Aeration {
    /// Undissolved gas that never separates \[-\].
    pub background_gas_per_oil: f64,
    /// Foam drawn through the intake valve: linear coefficient in alpha \[-\].
    pub intake_gas_linear: f64,
    /// Foam drawn through the intake valve: quadratic coefficient in alpha \[-\].
    pub intake_gas_quadratic: f64,
    /// Time constant of the buoyant separation of gas above the background \[s\].
    pub separation_time_s: f64,
}

impl Aeration {
    /// Gas per oil volume in the flow drawn from the reservoir at oil loss `alpha`.
    pub fn intake_gas_per_oil(&self, alpha: f64) -> f64 {
        self.background_gas_per_oil
            + self.intake_gas_linear * alpha
            + self.intake_gas_quadratic * alpha * alpha
    }
}

/// A power-law restriction `dp = B q^exponent` (Reybrouck 1994, Appendix A), with `B` given by
/// one reference point `(flow_ref, dp_ref)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Restriction {
    /// Pressure difference at the reference flow \[Pa\].
    pub dp_ref_pa: f64,
    /// Reference flow \[m³/s\].
    pub flow_ref_m3_s: f64,
    /// Exponent of the flow in the pressure drop \[-\] (1.75 for the Blasius regime).
    pub exponent: f64,
}

/// A preloaded disc valve with a first-order opening lag.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiscValve {
    /// Cracking pressure difference \[Pa\].
    pub preload_dp_pa: f64,
    /// Additional pressure difference above the preload for full lift \[Pa\].
    pub full_lift_dp_pa: f64,
    /// Flow area at full lift \[m²\].
    pub max_area_m2: f64,
    /// Orifice discharge coefficient \[-\].
    pub discharge_coefficient: f64,
    /// Time constant of the opening lag \[s\].
    pub time_constant_s: f64,
}

/// Piston valve parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PistonValve {
    /// Leak (bleed) restriction, both directions.
    pub leak: Restriction,
    /// Port restriction in series with the valve group, both directions.
    pub port: Restriction,
    /// Rebound blow-off valve.
    pub rebound_valve: DiscValve,
    /// Compression check valve.
    pub check_valve: DiscValve,
}

/// Base valve parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaseValve {
    /// Leak (bleed) restriction, both directions.
    pub leak: Restriction,
    /// Compression valve (to the reservoir).
    pub compression_valve: DiscValve,
    /// Intake check valve (from the reservoir).
    pub intake_valve: DiscValve,
}

/// Seal friction `F = (coulomb + c_p (p_rebound - p_atm)^+) tanh(v / v_s)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Friction {
    /// Coulomb friction \[N\].
    pub coulomb_n: f64,
    /// Rod-seal friction per Pa of rebound-chamber gauge pressure \[N/Pa\].
    pub pressure_coefficient_n_per_pa: f64,
    /// Velocity scale of the tanh smoothing \[m/s\].
    pub smoothing_velocity_m_s: f64,
}

/// Integrator settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Solver {
    /// Backward-Euler step \[s\]; must divide the sample period.
    pub internal_step_s: f64,
    /// Newton tolerance on the chamber pressures \[Pa\].
    pub pressure_tolerance_pa: f64,
    /// Newton iterations before the step is split in two.
    pub max_newton_iterations: u32,
    /// Pressure difference below which the flow laws become linear (laminar) \[Pa\].
    pub laminar_transition_pa: f64,
    /// Rounding of the valve opening characteristic at its corners \[Pa\].
    pub valve_smoothing_pa: f64,
}

/// The test programme.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Program {
    /// Output sample rate \[Hz\].
    pub sample_rate_hz: f64,
    /// Oil-loss levels alpha \[-\].
    pub oil_loss: Vec<f64>,
    /// Stroke amplitudes \[m\].
    pub amplitudes_m: Vec<f64>,
    /// Peak (zero-crossing) velocities \[m/s\].
    pub peak_velocities_m_s: Vec<f64>,
    /// Ramp-in length in periods \[-\].
    pub ramp_periods: f64,
    /// Upper bound of the ramp-in length \[s\].
    pub max_ramp_s: f64,
    /// Minimum number of full-amplitude periods after the ramp.
    pub min_steady_periods: u32,
    /// Minimum full-amplitude duration after the ramp \[s\].
    pub min_steady_s: f64,
    /// Random excitation instead of the sine grid (optional table `[program.random]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub random: Option<RandomProgram>,
    /// Oil loss changing within every run (optional table `[program.alpha_schedule]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha_schedule: Option<AlphaScheduleProgram>,
}

/// Band-limited random excitation (`[program.random]`): for every oil-loss level and every
/// velocity RMS one run, a random-phase multisine with a flat velocity spectrum in `band_hz`
/// (see `bench::program::Multisine`). Replaces the sine grid (`amplitudes_m`,
/// `peak_velocities_m_s`, `ramp_periods`, `max_ramp_s`, `min_steady_*` are then unused).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomProgram {
    /// Seed of the random phases (with the run's file name, through `sensor::run_rng`).
    pub seed: u64,
    /// Velocity RMS of the steady stroke, one run per entry and level \[m/s\].
    pub velocity_rms_m_s: Vec<f64>,
    /// Lower and upper edge of the flat velocity spectrum \[Hz\].
    pub band_hz: [f64; 2],
    /// Steady duration `T` after the ramp \[s\]; the lines are `k / T`.
    pub duration_s: f64,
    /// Raised-cosine ramp-in \[s\].
    pub ramp_s: f64,
    /// Largest `|x|` of the steady stroke \[m\]; larger strokes are scaled down.
    pub max_stroke_m: f64,
}

/// Oil loss changing within a run (`[program.alpha_schedule]`): segments of random length,
/// levels drawn from `program.oil_loss` (see `bench::program::alpha_schedule`). The runs get
/// the per-sample `alpha` column.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AlphaScheduleProgram {
    /// Seed of the segment lengths and levels.
    pub seed: u64,
    /// Shortest segment \[s\].
    pub min_segment_s: f64,
    /// Longest segment \[s\].
    pub max_segment_s: f64,
}

/// Measurement chain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sensors {
    /// Standard deviation of the white load-cell noise \[N\].
    pub force_noise_std_n: f64,
    /// Quantisation step of the force channel \[N\].
    pub force_resolution_n: f64,
    /// Amplitude of the mains pick-up on the force channel \[N\].
    pub mains_hum_n: f64,
    /// Mains frequency \[Hz\].
    pub mains_frequency_hz: f64,
    /// Standard deviation of the displacement noise before quantisation \[m\].
    pub displacement_noise_std_m: f64,
    /// Quantisation step of the displacement channel \[m\].
    pub displacement_resolution_m: f64,
    /// Subtract the static force at rest, mid-stroke (zeroing of the load cell).
    pub tare_static_force: bool,
    /// Write a `velocity_m_s` column.
    pub write_velocity: bool,
    /// Noise of the written velocity column \[m/s\].
    pub velocity_noise_std_m_s: f64,
    /// Resolution of the written time stamps \[s\] (optional; default 1 ns): a logger that
    /// rounds its clock, e.g. 1e-4 for 0.1 ms.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_resolution_s: Option<f64>,
    /// Zero offset of the displacement transducer \[m\] (optional; default 0): added to every
    /// written displacement, like a potentiometer whose zero is not the stroke centre.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub displacement_offset_m: Option<f64>,
}

impl Default for BenchConfig {
    fn default() -> Self {
        // The embedded default is checked by a unit test; failing here would be a build defect.
        parse(DEFAULT_TOML, "<built-in bench.toml>").expect("built-in bench.toml is valid")
    }
}

impl BenchConfig {
    /// The configuration as TOML that [`parse`] reads back to the same value.
    pub fn to_toml(&self) -> Result<String> {
        toml::to_string(self).context("cannot write the bench config as TOML")
    }
}

/// Loads and validates a configuration file.
pub fn load(path: &Path) -> Result<BenchConfig> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read bench config {}", path.display()))?;
    parse(&text, &path.display().to_string())
}

/// Parses and validates a configuration from TOML text; `origin` names the source in errors.
pub fn parse(text: &str, origin: &str) -> Result<BenchConfig> {
    let cfg: BenchConfig =
        toml::from_str(text).map_err(|e| anyhow::anyhow!("bench config {origin}: {e}"))?;
    if let Err(v) = cfg.validate() {
        let at = match find_key_line(text, &v.key) {
            Some(line) => format!("{origin}:{line}"),
            None => origin.to_string(),
        };
        bail!("bench config {at}: `{}` {}", v.key, v.message);
    }
    Ok(cfg)
}

/// A validation failure: the dotted key and what is wrong with it.
#[derive(Debug, Clone, PartialEq)]
pub struct Invalid {
    /// Dotted key, e.g. `geometry.rod_diameter_m`.
    pub key: String,
    /// What is wrong.
    pub message: String,
}

fn invalid(key: &str, message: String) -> Invalid {
    Invalid {
        key: key.to_string(),
        message,
    }
}

fn positive(key: &str, v: f64) -> Result<(), Invalid> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(key, format!("must be a positive number, got {v}")))
    }
}

fn non_negative(key: &str, v: f64) -> Result<(), Invalid> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(invalid(key, format!("must be a number >= 0, got {v}")))
    }
}

fn restriction(key: &str, r: &Restriction) -> Result<(), Invalid> {
    positive(&format!("{key}.dp_ref_pa"), r.dp_ref_pa)?;
    positive(&format!("{key}.flow_ref_m3_s"), r.flow_ref_m3_s)?;
    if !(r.exponent >= 1.0 && r.exponent <= 2.0) {
        return Err(invalid(
            &format!("{key}.exponent"),
            format!(
                "must be in [1, 2] (laminar .. turbulent), got {}",
                r.exponent
            ),
        ));
    }
    Ok(())
}

fn disc(key: &str, d: &DiscValve) -> Result<(), Invalid> {
    non_negative(&format!("{key}.preload_dp_pa"), d.preload_dp_pa)?;
    positive(&format!("{key}.full_lift_dp_pa"), d.full_lift_dp_pa)?;
    positive(&format!("{key}.max_area_m2"), d.max_area_m2)?;
    positive(&format!("{key}.time_constant_s"), d.time_constant_s)?;
    let cd = d.discharge_coefficient;
    if !(cd > 0.0 && cd <= 1.0) {
        return Err(invalid(
            &format!("{key}.discharge_coefficient"),
            format!("must be in (0, 1], got {cd}"),
        ));
    }
    Ok(())
}

impl BenchConfig {
    /// Checks ranges and consistency; the error names the offending key.
    pub fn validate(&self) -> Result<(), Invalid> {
        self.check_geometry()?;
        self.check_fluids()?;
        self.check_restrictions()?;
        self.check_solver()?;
        self.check_program()?;
        self.check_sensors()
    }

    /// `[geometry]`: positive sizes, a rod thinner than the piston, gas room in the reservoir, a thin tube wall.
    fn check_geometry(&self) -> Result<(), Invalid> {
        let g = &self.geometry;
        positive("geometry.piston_diameter_m", g.piston_diameter_m)?;
        positive("geometry.rod_diameter_m", g.rod_diameter_m)?;
        if g.rod_diameter_m >= g.piston_diameter_m {
            return Err(invalid(
                "geometry.rod_diameter_m",
                format!(
                    "must be smaller than geometry.piston_diameter_m ({})",
                    g.piston_diameter_m
                ),
            ));
        }
        positive(
            "geometry.rebound_chamber_length_m",
            g.rebound_chamber_length_m,
        )?;
        positive(
            "geometry.compression_chamber_length_m",
            g.compression_chamber_length_m,
        )?;
        positive("geometry.reservoir_volume_m3", g.reservoir_volume_m3)?;
        positive(
            "geometry.reservoir_oil_volume_m3",
            g.reservoir_oil_volume_m3,
        )?;
        if g.reservoir_oil_volume_m3 >= g.reservoir_volume_m3 {
            return Err(invalid(
                "geometry.reservoir_oil_volume_m3",
                "must be smaller than geometry.reservoir_volume_m3 (leave room for the gas)".into(),
            ));
        }
        positive("geometry.pressure_tube_wall_m", g.pressure_tube_wall_m)?;
        if g.pressure_tube_wall_m >= 0.5 * g.piston_diameter_m {
            return Err(invalid(
                "geometry.pressure_tube_wall_m",
                format!(
                    "must be a thin wall, below half of geometry.piston_diameter_m ({})",
                    g.piston_diameter_m
                ),
            ));
        }
        positive("geometry.tube_youngs_modulus_pa", g.tube_youngs_modulus_pa)?;
        Ok(())
    }

    /// `[oil]`, `[gas]` and `[aeration]`.
    fn check_fluids(&self) -> Result<(), Invalid> {
        positive("oil.bulk_modulus_pa", self.oil.bulk_modulus_pa)?;
        positive("oil.density_kg_m3", self.oil.density_kg_m3)?;
        positive(
            "oil.cavitation_pressure_pa",
            self.oil.cavitation_pressure_pa,
        )?;
        let gas = &self.gas;
        positive("gas.atmospheric_pressure_pa", gas.atmospheric_pressure_pa)?;
        positive("gas.charge_pressure_pa", gas.charge_pressure_pa)?;
        if gas.charge_pressure_pa <= self.oil.cavitation_pressure_pa {
            return Err(invalid(
                "gas.charge_pressure_pa",
                "must be above oil.cavitation_pressure_pa".into(),
            ));
        }
        for (key, n) in [
            ("gas.polytropic_exponent", gas.polytropic_exponent),
            (
                "gas.bubble_polytropic_exponent",
                gas.bubble_polytropic_exponent,
            ),
        ] {
            if !(1.0..=1.67).contains(&n) {
                return Err(invalid(key, format!("must be in [1, 1.67], got {n}")));
            }
        }
        if !(gas.retained_fraction > 0.0 && gas.retained_fraction <= 1.0) {
            return Err(invalid(
                "gas.retained_fraction",
                format!("must be in (0, 1], got {}", gas.retained_fraction),
            ));
        }
        let a = &self.aeration;
        non_negative("aeration.background_gas_per_oil", a.background_gas_per_oil)?;
        non_negative("aeration.intake_gas_linear", a.intake_gas_linear)?;
        non_negative("aeration.intake_gas_quadratic", a.intake_gas_quadratic)?;
        positive("aeration.separation_time_s", a.separation_time_s)?;
        if a.intake_gas_per_oil(1.0) >= 1.0 {
            return Err(invalid(
                "aeration.intake_gas_quadratic",
                "gives more gas than oil in the intake flow at alpha = 1".into(),
            ));
        }
        Ok(())
    }

    /// The valves and leaks of `[piston]` and `[base]`, and `[friction]`.
    fn check_restrictions(&self) -> Result<(), Invalid> {
        restriction("piston.leak", &self.piston.leak)?;
        restriction("piston.port", &self.piston.port)?;
        disc("piston.rebound_valve", &self.piston.rebound_valve)?;
        disc("piston.check_valve", &self.piston.check_valve)?;
        restriction("base.leak", &self.base.leak)?;
        disc("base.compression_valve", &self.base.compression_valve)?;
        disc("base.intake_valve", &self.base.intake_valve)?;
        non_negative("friction.coulomb_n", self.friction.coulomb_n)?;
        non_negative(
            "friction.pressure_coefficient_n_per_pa",
            self.friction.pressure_coefficient_n_per_pa,
        )?;
        positive(
            "friction.smoothing_velocity_m_s",
            self.friction.smoothing_velocity_m_s,
        )?;
        Ok(())
    }

    /// `[solver]`: positive settings and an internal step that divides the sample period of
    /// `[program]`.
    fn check_solver(&self) -> Result<(), Invalid> {
        let s = &self.solver;
        positive("solver.internal_step_s", s.internal_step_s)?;
        positive("solver.pressure_tolerance_pa", s.pressure_tolerance_pa)?;
        if s.max_newton_iterations < 2 {
            return Err(invalid(
                "solver.max_newton_iterations",
                "must be at least 2".into(),
            ));
        }
        positive("solver.laminar_transition_pa", s.laminar_transition_pa)?;
        positive("solver.valve_smoothing_pa", s.valve_smoothing_pa)?;
        let p = &self.program;
        positive("program.sample_rate_hz", p.sample_rate_hz)?;
        let ratio = 1.0 / (p.sample_rate_hz * s.internal_step_s);
        if ratio < 0.999 || (ratio - ratio.round()).abs() > 1e-6 * ratio {
            return Err(invalid(
                "solver.internal_step_s",
                format!(
                    "must divide the sample period 1/program.sample_rate_hz = {} s",
                    1.0 / p.sample_rate_hz
                ),
            ));
        }
        Ok(())
    }

    /// The longest stroke the chambers allow on either side (90 % of the shorter chamber).
    fn stroke_limit_m(&self) -> f64 {
        let g = &self.geometry;
        0.9 * g
            .rebound_chamber_length_m
            .min(g.compression_chamber_length_m)
    }

    /// `[program]`: levels, amplitudes that fit the chambers, velocities, ramps and steady
    /// periods, then `[program.random]` and `[program.alpha_schedule]`.
    fn check_program(&self) -> Result<(), Invalid> {
        let p = &self.program;
        for (key, list) in [
            ("program.oil_loss", &p.oil_loss),
            ("program.amplitudes_m", &p.amplitudes_m),
            ("program.peak_velocities_m_s", &p.peak_velocities_m_s),
        ] {
            if list.is_empty() {
                return Err(invalid(key, "must not be empty".into()));
            }
        }
        for (i, &alpha) in p.oil_loss.iter().enumerate() {
            if !(0.0..0.9).contains(&alpha) {
                return Err(invalid(
                    "program.oil_loss",
                    format!("entries must be in [0, 0.9), got {alpha}"),
                ));
            }
            // The run files are named by the level in whole percent (`oil15_...`).
            let percent = |a: f64| (a * 100.0).round();
            if let Some(other) = p.oil_loss[..i]
                .iter()
                .find(|&&b| percent(b) == percent(alpha))
            {
                return Err(invalid(
                    "program.oil_loss",
                    format!(
                        "{other} and {alpha} name the same run files (oil{:02}_...): levels \
                         must differ by at least 1 % after rounding",
                        percent(alpha)
                    ),
                ));
            }
        }
        for &amp in &p.amplitudes_m {
            positive("program.amplitudes_m", amp)?;
            if amp >= self.stroke_limit_m() {
                return Err(invalid(
                    "program.amplitudes_m",
                    format!(
                        "amplitude {amp} m does not fit the chambers (limit {:.4} m)",
                        self.stroke_limit_m()
                    ),
                ));
            }
        }
        for &v in &p.peak_velocities_m_s {
            positive("program.peak_velocities_m_s", v)?;
        }
        positive("program.ramp_periods", p.ramp_periods)?;
        positive("program.max_ramp_s", p.max_ramp_s)?;
        if p.min_steady_periods < 1 {
            return Err(invalid(
                "program.min_steady_periods",
                "must be at least 1".into(),
            ));
        }
        non_negative("program.min_steady_s", p.min_steady_s)?;
        if let Some(r) = &p.random {
            self.check_random_program(r)?;
        }
        if let Some(a) = &p.alpha_schedule {
            positive("program.alpha_schedule.min_segment_s", a.min_segment_s)?;
            if !(a.max_segment_s.is_finite() && a.max_segment_s >= a.min_segment_s) {
                return Err(invalid(
                    "program.alpha_schedule.max_segment_s",
                    "must be at least min_segment_s".into(),
                ));
            }
            if p.oil_loss.len() < 2 {
                return Err(invalid(
                    "program.oil_loss",
                    "needs at least two levels for an alpha schedule".into(),
                ));
            }
        }
        Ok(())
    }

    /// `[program.random]`: velocities, duration and ramp, a stroke that fits the chambers, a
    /// band below half the sample rate with a line of the run's spectrum in it.
    fn check_random_program(&self, r: &RandomProgram) -> Result<(), Invalid> {
        if r.velocity_rms_m_s.is_empty() {
            return Err(invalid(
                "program.random.velocity_rms_m_s",
                "must not be empty".into(),
            ));
        }
        for &v in &r.velocity_rms_m_s {
            positive("program.random.velocity_rms_m_s", v)?;
        }
        positive("program.random.duration_s", r.duration_s)?;
        non_negative("program.random.ramp_s", r.ramp_s)?;
        positive("program.random.max_stroke_m", r.max_stroke_m)?;
        if r.max_stroke_m >= self.stroke_limit_m() {
            return Err(invalid(
                "program.random.max_stroke_m",
                format!(
                    "does not fit the chambers (limit {:.4} m)",
                    self.stroke_limit_m()
                ),
            ));
        }
        let [lo, hi] = r.band_hz;
        let fs = self.program.sample_rate_hz;
        if !(lo.is_finite() && lo > 0.0 && hi > lo && hi < 0.5 * fs) {
            return Err(invalid(
                "program.random.band_hz",
                format!(
                    "must be [low, high] with 0 < low < high < half the sample rate ({} Hz), \
                     got [{lo}, {hi}]",
                    0.5 * fs
                ),
            ));
        }
        if (hi * r.duration_s).floor() < (lo * r.duration_s).ceil() {
            return Err(invalid(
                "program.random.duration_s",
                "leaves no line k / duration_s inside band_hz".into(),
            ));
        }
        Ok(())
    }

    /// `[sensors]`.
    fn check_sensors(&self) -> Result<(), Invalid> {
        let se = &self.sensors;
        non_negative("sensors.force_noise_std_n", se.force_noise_std_n)?;
        positive("sensors.force_resolution_n", se.force_resolution_n)?;
        non_negative("sensors.mains_hum_n", se.mains_hum_n)?;
        positive("sensors.mains_frequency_hz", se.mains_frequency_hz)?;
        non_negative(
            "sensors.displacement_noise_std_m",
            se.displacement_noise_std_m,
        )?;
        positive(
            "sensors.displacement_resolution_m",
            se.displacement_resolution_m,
        )?;
        non_negative("sensors.velocity_noise_std_m_s", se.velocity_noise_std_m_s)?;
        if let Some(q) = se.time_resolution_s {
            positive("sensors.time_resolution_s", q)?;
        }
        if let Some(x) = se.displacement_offset_m {
            if !x.is_finite() {
                return Err(invalid(
                    "sensors.displacement_offset_m",
                    format!("must be a finite number, got {x}"),
                ));
            }
        }
        Ok(())
    }
}

/// Finds the 1-based line of a dotted key (`table.sub.key`) in TOML text: the line of `key =`
/// after the header of its table. Good enough for the flat layout of bench files.
fn find_key_line(text: &str, dotted: &str) -> Option<usize> {
    let (table, key) = match dotted.rsplit_once('.') {
        Some((t, k)) => (t, k),
        None => ("", dotted),
    };
    let mut current = String::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if let Some(h) = line.strip_prefix('[') {
            current = h.trim_end_matches(']').trim().to_string();
            continue;
        }
        if current == table {
            if let Some((k, _)) = line.split_once('=') {
                if k.trim() == key {
                    return Some(i + 1);
                }
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_config_is_valid_and_reproduces_table_1() {
        let cfg = parse(DEFAULT_TOML, "default").unwrap();
        assert_eq!(cfg.program.oil_loss, vec![0.0, 0.15, 0.30]);
        assert_eq!(cfg.program.amplitudes_m, vec![0.05, 0.03, 0.01]);
        assert_eq!(
            cfg.program.peak_velocities_m_s,
            vec![0.052, 0.131, 0.262, 0.393, 0.524, 1.048]
        );
        assert_eq!(cfg.program.sample_rate_hz, 10_000.0);
    }

    #[test]
    fn levels_that_name_the_same_run_files_are_refused() {
        let mut cfg = BenchConfig::default();
        cfg.program.oil_loss = vec![0.0, 0.075, 0.15, 0.225, 0.3];
        assert!(cfg.validate().is_ok());
        cfg.program.oil_loss = vec![0.0, 0.15, 0.152];
        let e = cfg.validate().unwrap_err();
        assert_eq!(e.key, "program.oil_loss");
        assert!(e.message.contains("oil15_"), "{}", e.message);
    }

    #[test]
    fn config_round_trips_through_toml() {
        let mut cfg = BenchConfig::default();
        assert_eq!(parse(&cfg.to_toml().unwrap(), "written").unwrap(), cfg);
        cfg.sensors.time_resolution_s = Some(1e-4);
        cfg.program.random = Some(RandomProgram {
            seed: 3,
            velocity_rms_m_s: vec![0.1],
            band_hz: [0.5, 10.0],
            duration_s: 4.0,
            ramp_s: 0.05,
            max_stroke_m: 0.04,
        });
        assert_eq!(parse(&cfg.to_toml().unwrap(), "written").unwrap(), cfg);
    }

    #[test]
    fn unknown_key_is_named_with_its_line() {
        let text = DEFAULT_TOML.replace("rod_diameter_m = 0.020", "rod_diametre_m = 0.020");
        let err = parse(&text, "my.toml").unwrap_err().to_string();
        assert!(err.contains("my.toml"), "{err}");
        assert!(err.contains("rod_diametre_m"), "{err}");
        assert!(err.contains("line"), "{err}");
    }

    #[test]
    fn missing_key_is_named() {
        let text = DEFAULT_TOML.replace("density_kg_m3 = 850.0\n", "");
        let err = parse(&text, "my.toml").unwrap_err().to_string();
        assert!(err.contains("density_kg_m3"), "{err}");
    }

    #[test]
    fn bad_value_is_named_with_key_and_line() {
        let text = DEFAULT_TOML.replace("rod_diameter_m = 0.020", "rod_diameter_m = 0.040");
        let err = parse(&text, "my.toml").unwrap_err().to_string();
        assert!(err.contains("geometry.rod_diameter_m"), "{err}");
        let line = DEFAULT_TOML
            .lines()
            .position(|l| l.starts_with("rod_diameter_m"))
            .unwrap()
            + 1;
        assert!(err.contains(&format!("my.toml:{line}")), "{err}");

        let text = DEFAULT_TOML.replace("internal_step_s = 2.5e-5", "internal_step_s = 3e-5");
        let err = parse(&text, "my.toml").unwrap_err().to_string();
        assert!(err.contains("solver.internal_step_s"), "{err}");

        let text = DEFAULT_TOML.replace(
            "exponent = 1.75\n\n[piston.port]",
            "exponent = 3.0\n\n[piston.port]",
        );
        let err = parse(&text, "my.toml").unwrap_err().to_string();
        assert!(err.contains("piston.leak.exponent"), "{err}");
    }

    #[test]
    fn wrong_type_is_reported() {
        let text = DEFAULT_TOML.replace(
            "max_newton_iterations = 30",
            "max_newton_iterations = \"many\"",
        );
        let err = parse(&text, "my.toml").unwrap_err().to_string();
        assert!(err.contains("max_newton_iterations"), "{err}");
    }
}
