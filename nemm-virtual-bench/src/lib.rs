//! # nemm-virtual-bench
//!
//! The virtual test bench: a first-principles hydraulic twin-tube damper with oil loss,
//! driven through the sinusoidal programme of the paper (Table 1), measured with a noisy,
//! quantising load cell and displacement transducer, written in the dataset interchange format
//! ([`nemm_dataset`]).
//!
//! It is a test instrument, not part of training: `nemm bench`, `nemm demo` and the tests
//! generate data with it, and the trainer's reports draw the equivalent EMM coefficients of
//! its damper ([`reference`](mod@reference)) as reference curves on virtual-bench data.
//!
//! The model is deliberately richer than the EMM (section 4 of the paper): three chambers
//! (rebound, compression, gas-charged reservoir), oil compressibility with entrained free gas
//! (the effective bulk modulus falls at low pressure and with oil loss), cavitation with vapour
//! cavities (lost motion), the piston valve of Appendix A (port restriction in series with a
//! 1.75-power leak, a preloaded blow-off valve and a check valve), a base valve (preloaded
//! compression valve, intake check valve, leak), first-order valve lags and seal friction.
//! Equations, sources, units and the integrator's stability argument are in
//! `docs/virtual-bench.md`.
//!
//! ```no_run
//! use nemm_virtual_bench::{config::BenchConfig, VirtualBench};
//! let bench = VirtualBench::new(BenchConfig::default());
//! let dataset = bench.generate(42, |_done, _total| {});
//! ```

pub mod config;
pub mod fixtures;
mod hydraulics;
pub mod program;
pub mod reference;
pub mod sensor;
mod simulate;

pub use simulate::{SolverStats, Trace};

use config::BenchConfig;
use hydraulics::{Damper, Filling};
use nemm_dataset::{Dataset, Run, RunEntry};
use program::RunSpec;
use rand::RngExt;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use sensor::Quantiser;
use simulate::{Foam, Segment, StepSettings};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Conditioning periods simulated before each run to settle the free gas (see
/// `simulate::condition`).
const CONDITIONING_PASSES: u32 = 2;

/// The virtual bench: a configured damper model plus the measurement programme.
#[derive(Debug, Clone)]
pub struct VirtualBench {
    cfg: BenchConfig,
    damper: Damper,
}

/// Pressures of the damper at rest for one oil-loss level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestState {
    /// Absolute pressure in all chambers at rest, mid-stroke \[Pa\].
    pub pressure_pa: f64,
    /// Static rod force at rest (gas force; negative = pushes the rod out) \[N\].
    pub static_force_n: f64,
    /// Reservoir gas volume at rest \[m³\].
    pub reservoir_gas_m3: f64,
    /// Free gas in the compression chamber (normal volume) \[m³\].
    pub compression_free_gas_m3: f64,
}

impl VirtualBench {
    /// A bench for a validated configuration (see [`config::parse`]).
    pub fn new(cfg: BenchConfig) -> Self {
        let damper = Damper::new(&cfg);
        VirtualBench { cfg, damper }
    }

    /// The configuration.
    pub fn config(&self) -> &BenchConfig {
        &self.cfg
    }

    /// The runs of the configured programme.
    pub fn runs(&self) -> Vec<RunSpec> {
        program::grid(&self.cfg.program)
    }

    fn filling(&self, alpha: f64) -> Filling {
        self.damper.filling(&self.cfg, alpha)
    }

    /// The damper at rest for oil loss `alpha`.
    pub fn rest_state(&self, alpha: f64) -> RestState {
        let f = self.filling(alpha);
        RestState {
            pressure_pa: f.p_rest,
            static_force_n: self.damper.force(f.p_rest, f.p_rest, 0.0),
            reservoir_gas_m3: f.v_gas_rest,
            compression_free_gas_m3: f.gas_compression,
        }
    }

    /// Tangent bulk modulus \[Pa\] of the working-chamber fluid at absolute pressure
    /// `pressure_pa` with `gas_per_oil` normal volumes of free gas per volume of oil: the oil
    /// and pressure-tube compliance in series with the isothermal/polytropic bubbles (Wood).
    /// With `gas_per_oil = aeration.background_gas_per_oil` this is the damper without oil
    /// loss; with 0 it is the liquid column alone.
    pub fn effective_bulk_modulus_pa(&self, pressure_pa: f64, gas_per_oil: f64) -> f64 {
        self.damper.fluid.tangent_modulus(gas_per_oil, pressure_pa)
    }

    fn tare(&self, f: &Filling) -> f64 {
        if self.cfg.sensors.tare_static_force {
            self.damper.force(f.p_rest, f.p_rest, 0.0)
        } else {
            0.0
        }
    }

    /// Noise-free simulation of one run with the configured internal step.
    pub fn simulate(&self, spec: &RunSpec) -> Trace {
        self.simulate_with_step(spec, self.cfg.solver.internal_step_s)
    }

    fn foam_at(&self, alpha: f64) -> Foam {
        let a = &self.cfg.aeration;
        Foam {
            c_bg: a.background_gas_per_oil,
            c_intake: a.intake_gas_per_oil(alpha),
            tau: a.separation_time_s,
        }
    }

    fn step_settings(&self, h: f64) -> StepSettings {
        StepSettings {
            h,
            pressure_tolerance: self.cfg.solver.pressure_tolerance_pa,
            max_iterations: self.cfg.solver.max_newton_iterations,
        }
    }

    /// The state a run of `spec` starts from: the rest state of its level with the free gas
    /// conditioned to the run's periodic state ([`simulate::condition`]), for internal step `h`.
    fn conditioned_start(&self, spec: &RunSpec, h: f64) -> Filling {
        let rest = self.filling(spec.oil_loss);
        let foam = self.foam_at(spec.oil_loss);
        // First guess from the mean flows, then two conditioning periods at the sample step.
        let (g_r, g_c) = foam.conditioned(&self.damper, spec.peak_velocity_m_s);
        let guess = self.damper.with_gas(&rest, g_r, g_c);
        let h_condition = h.max(1.0 / self.cfg.program.sample_rate_hz);
        simulate::condition(
            &self.damper,
            &guess,
            foam,
            &spec.excitation(),
            h_condition,
            &self.step_settings(h),
            CONDITIONING_PASSES,
        )
    }

    /// Noise-free simulation with internal step `h` \[s\] (rounded to divide the sample period).
    pub fn simulate_with_step(&self, spec: &RunSpec, h: f64) -> Trace {
        let rest = self.filling(spec.oil_loss);
        let foam_at = |alpha: f64| self.foam_at(alpha);
        let foam = foam_at(spec.oil_loss);
        let settings = self.step_settings(h);
        let excitation = spec.excitation();
        let f = self.conditioned_start(spec, h);
        // Later segments: the rest state of their level with the run's conditioned free gas
        // in the chambers (the first segment is the run's own level, `f`).
        let fs = self.cfg.program.sample_rate_hz;
        let segments: Vec<Segment> = spec
            .alpha_segments
            .iter()
            .filter(|s| s.start_s > 0.0)
            .map(|s| Segment {
                first_sample: (s.start_s * fs).ceil() as usize,
                alpha: s.alpha,
                filling: self.damper.with_gas(
                    &self.filling(s.alpha),
                    f.gas_rebound,
                    f.gas_compression,
                ),
                foam: foam_at(s.alpha),
            })
            .collect();
        simulate::simulate(&simulate::Job {
            damper: &self.damper,
            filling: &f,
            foam,
            excitation: &excitation,
            sample_rate_hz: self.cfg.program.sample_rate_hz,
            samples: spec.samples,
            settings,
            tare: self.tare(&rest),
            segments: &segments,
            alpha: spec.oil_loss,
        })
    }

    /// Quasi-static force \[N\] at constant velocity `v` \[m/s\] and mid-stroke: steady valve
    /// lifts, all flow through the valves equal to the displaced volumes (piston `A_a v`, base
    /// `-A_rod v`), cavitation where the compression chamber would fall below its limit.
    pub fn quasi_static_force(&self, v: f64, alpha: f64) -> f64 {
        let d = &self.damper;
        let f = self.filling(alpha);
        let rest = d.rest_lifts();
        let h = 1e6; // h >> valve time constants: lifts at their static values
        let dp_piston = invert_increasing(|dp| d.piston_flow(dp, &rest, h, 0.5).q, d.a_annulus * v);
        let dp_base = invert_increasing(|dp| d.base_flow(dp, &rest, h).q, -d.a_rod * v);
        let p_c = (f.p_rest + dp_base).max(d.fluid.p_cav);
        let p_r = p_c + dp_piston;
        d.force(p_r, p_c, d.friction(v, p_r)) - self.tare(&f)
    }

    /// One measured run: simulation plus the measurement chain, deterministic for `seed`.
    pub fn measure(&self, spec: &RunSpec, seed: u64) -> Run {
        let trace = self.simulate(spec);
        self.apply_sensors(spec, &trace, seed)
    }

    fn apply_sensors(&self, spec: &RunSpec, tr: &Trace, seed: u64) -> Run {
        let s = &self.cfg.sensors;
        let mut rng = sensor::run_rng(seed, &spec.file.to_string_lossy());
        let qf = Quantiser::new(s.force_resolution_n);
        let qx = Quantiser::new(s.displacement_resolution_m);
        let qt = Quantiser::new(s.time_resolution_s.unwrap_or(1e-9));
        let x_offset = s.displacement_offset_m.unwrap_or(0.0);
        let qv = Quantiser::new(1e-6);
        let hum_phase = 2.0 * std::f64::consts::PI * rng.random::<f64>();
        let mut normal = || -> f64 { rng.sample(StandardNormal) };
        let n = tr.time_s.len();
        let mut time_s = Vec::with_capacity(n);
        let mut displacement_m = Vec::with_capacity(n);
        let mut force_n = Vec::with_capacity(n);
        let mut velocity = Vec::with_capacity(if s.write_velocity { n } else { 0 });
        for i in 0..n {
            let t = tr.time_s[i];
            time_s.push(qt.apply(t));
            displacement_m.push(
                qx.apply(tr.displacement_m[i] + x_offset + s.displacement_noise_std_m * normal()),
            );
            let hum = s.mains_hum_n
                * (2.0 * std::f64::consts::PI * s.mains_frequency_hz * t + hum_phase).sin();
            force_n.push(qf.apply(tr.force_n[i] + hum + s.force_noise_std_n * normal()));
            if s.write_velocity {
                velocity.push(qv.apply(tr.velocity_m_s[i] + s.velocity_noise_std_m_s * normal()));
            }
        }
        let sine = spec.random.is_none();
        Run {
            entry: RunEntry {
                file: spec.file.clone(),
                oil_loss: spec.oil_loss,
                amplitude_m: sine.then_some(spec.amplitude_m),
                target_velocity_m_s: sine.then_some(spec.peak_velocity_m_s),
            },
            time_s,
            displacement_m,
            force_n,
            velocity_m_s: s.write_velocity.then_some(velocity),
            alpha: (!spec.alpha_segments.is_empty()).then(|| tr.alpha.clone()),
        }
    }

    /// Generates the whole programme in parallel (rayon); `progress(done, total)` is called
    /// after each finished run (from worker threads). Runs are in programme order.
    pub fn generate(&self, seed: u64, progress: impl Fn(usize, usize) + Sync) -> Dataset {
        let specs = self.runs();
        let total = specs.len();
        let done = AtomicUsize::new(0);
        let runs: Vec<Run> = specs
            .par_iter()
            .map(|spec| {
                let run = self.measure(spec, seed);
                progress(done.fetch_add(1, Ordering::SeqCst) + 1, total);
                run
            })
            .collect();
        Dataset {
            name: self.cfg.name.clone(),
            sample_rate_hz: self.cfg.program.sample_rate_hz,
            condition: None,
            runs,
        }
    }
}

/// Solves `g(z) = target` for an increasing `g` by bracketing and bisection.
fn invert_increasing(g: impl Fn(f64) -> f64, target: f64) -> f64 {
    let (mut lo, mut hi) = (-1e5, 1e5);
    while g(lo) > target && lo > -1e10 {
        lo *= 4.0;
    }
    while g(hi) < target && hi < 1e10 {
        hi *= 4.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if g(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-6 {
            break;
        }
    }
    0.5 * (lo + hi)
}
