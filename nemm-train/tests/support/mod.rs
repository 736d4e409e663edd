//! What nemm-train's integration tests build their inputs from: sine runs of a damper-like
//! force with known answers, datasets of them, deterministic noise, and small numeric helpers.
//! A test file takes it with `mod support;` and uses what it needs.
#![allow(dead_code)] // each test binary uses a part

use nemm_dataset::{Dataset, Run, RunEntry};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::f64::consts::PI;
use std::path::PathBuf;

/// Deterministic noise: xoshiro256++ with uniform and standard-normal draws.
pub struct Noise(Xoshiro256PlusPlus);

impl Noise {
    /// The generator of `seed`.
    pub fn new(seed: u64) -> Self {
        Noise(Xoshiro256PlusPlus::seed_from_u64(seed))
    }

    /// A uniform draw in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0.random()
    }

    /// A standard-normal draw.
    pub fn normal(&mut self) -> f64 {
        self.0.sample(StandardNormal)
    }
}

/// `x` rounded to a multiple of `lsb` (a quantised sensor).
pub fn quantise(x: f64, lsb: f64) -> f64 {
    (x / lsb).round() * lsb
}

/// Root mean square of `v`.
pub fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    (s / n as f64).sqrt()
}

/// A damper-like force `c(v, alpha) v + k x`: linear damping, stiffer in rebound (`v > 0`)
/// than in compression, softened by the condition level, plus a spring term (an elliptical
/// hysteresis loop in the force-velocity plane).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DamperForce {
    /// Rebound damping at alpha 0 \[N s/m\].
    pub c_rebound_ns_per_m: f64,
    /// Compression damping at alpha 0 \[N s/m\].
    pub c_compression_ns_per_m: f64,
    /// Fraction of the damping lost per unit of alpha.
    pub softening: f64,
    /// Spring rate \[N/m\].
    pub k_n_per_m: f64,
}

impl DamperForce {
    /// 2000 / 1200 N s/m, half of it lost at alpha 1, 30 kN/m.
    pub const DEFAULT: DamperForce = DamperForce {
        c_rebound_ns_per_m: 2000.0,
        c_compression_ns_per_m: 1200.0,
        softening: 0.5,
        k_n_per_m: 30_000.0,
    };

    /// The force \[N\] at displacement `x` \[m\], velocity `v` \[m/s\] and level `alpha`.
    pub fn at(&self, x: f64, v: f64, alpha: f64) -> f64 {
        let c = if v > 0.0 {
            self.c_rebound_ns_per_m
        } else {
            self.c_compression_ns_per_m
        } * (1.0 - self.softening * alpha);
        c * v + self.k_n_per_m * x
    }
}

/// A sinusoidal run `x = A w(t) sin(2 pi f t + phase)` at level `alpha` with a
/// [`DamperForce`]; `w(t)` is a raised-cosine ramp-in over `ramp_periods` periods (none by
/// default). The manifest entry records the amplitude and `2 pi f A`.
#[derive(Debug, Clone, PartialEq)]
pub struct SineRun {
    /// Run file relative to the manifest.
    pub file: String,
    /// Condition level.
    pub alpha: f64,
    /// Amplitude `A` \[m\].
    pub amplitude_m: f64,
    /// Frequency `f` \[Hz\].
    pub freq_hz: f64,
    /// Phase at t = 0 \[rad\].
    pub phase: f64,
    /// Sample rate \[Hz\].
    pub fs: f64,
    /// Number of samples.
    pub samples: usize,
    /// Periods of the raised-cosine ramp-in (0: none).
    pub ramp_periods: f64,
    /// The force.
    pub force: DamperForce,
}

impl SineRun {
    /// `samples` samples at `fs` of `A sin(2 pi f t)` at `alpha`, no ramp, the default force.
    pub fn new(
        file: &str,
        alpha: f64,
        amplitude_m: f64,
        freq_hz: f64,
        fs: f64,
        samples: usize,
    ) -> Self {
        SineRun {
            file: file.into(),
            alpha,
            amplitude_m,
            freq_hz,
            phase: 0.0,
            fs,
            samples,
            ramp_periods: 0.0,
            force: DamperForce::DEFAULT,
        }
    }

    /// The run, measured exactly.
    pub fn build(&self) -> Run {
        self.build_measured(|x, f| (x, f))
    }

    /// The run with `measure(x, f)` giving the recorded displacement and force of the true
    /// ones (noise, quantisation), called once per sample in time order.
    pub fn build_measured(&self, mut measure: impl FnMut(f64, f64) -> (f64, f64)) -> Run {
        let (a, w) = (self.amplitude_m, 2.0 * PI * self.freq_hz);
        let ramp = self.ramp_periods / self.freq_hz;
        let n = self.samples;
        let (mut time_s, mut displacement_m, mut force_n) = (
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        );
        for i in 0..n {
            let t = i as f64 / self.fs;
            let (x, v) = if self.ramp_periods > 0.0 {
                let (r, dr) = if t < ramp {
                    let p = PI * t / ramp;
                    (0.5 * (1.0 - p.cos()), 0.5 * PI / ramp * p.sin())
                } else {
                    (1.0, 0.0)
                };
                let (s, c) = ((w * t + self.phase).sin(), (w * t + self.phase).cos());
                (a * r * s, a * (dr * s + r * w * c))
            } else {
                (
                    a * (w * t + self.phase).sin(),
                    a * w * (w * t + self.phase).cos(),
                )
            };
            let (xm, fm) = measure(x, self.force.at(x, v, self.alpha));
            time_s.push(t);
            displacement_m.push(xm);
            force_n.push(fm);
        }
        Run {
            entry: RunEntry {
                file: PathBuf::from(&self.file),
                oil_loss: self.alpha,
                amplitude_m: Some(a),
                target_velocity_m_s: Some(a * w),
            },
            time_s,
            displacement_m,
            force_n,
            velocity_m_s: None,
            alpha: None,
        }
    }
}

/// A recorded sine run `file` at level `alpha`: amplitude `amplitude_m` \[m\], peak velocity
/// `peak_velocity_m_s` \[m/s\] in the manifest entry, the samples as given, no velocity or
/// alpha column.
pub fn sine_record(
    file: String,
    alpha: f64,
    amplitude_m: f64,
    peak_velocity_m_s: f64,
    time_s: Vec<f64>,
    displacement_m: Vec<f64>,
    force_n: Vec<f64>,
) -> Run {
    Run {
        entry: RunEntry {
            file: PathBuf::from(file),
            oil_loss: alpha,
            amplitude_m: Some(amplitude_m),
            target_velocity_m_s: Some(peak_velocity_m_s),
        },
        time_s,
        displacement_m,
        force_n,
        velocity_m_s: None,
        alpha: None,
    }
}

/// A dataset of `runs` at `fs`, without a named condition.
pub fn dataset(name: &str, fs: f64, runs: Vec<Run>) -> Dataset {
    Dataset {
        name: name.into(),
        sample_rate_hz: fs,
        condition: None,
        runs,
    }
}

/// Runs the `nemm` binary with `args` and returns its standard output; panics with its error
/// output if it fails.
pub fn nemm_ok(args: &[&std::ffi::OsStr]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_nemm"))
        .args(args)
        .output()
        .expect("run nemm");
    assert!(
        out.status.success(),
        "nemm {args:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A virtual bench of 6 runs (10 mm at 0.262 and 1.048 m/s, three oil-loss levels) with
/// short ramps and 2.6 s steady (five of the demo's 0.5 s windows, one of them for
/// validation) in `dir/bench`: generated by `nemm bench generate` from the default
/// configuration with a smaller programme.
pub fn small_bench(dir: &std::path::Path) -> PathBuf {
    let config = nemm_ok(&["bench".as_ref(), "config".as_ref()]);
    let mut small = String::new();
    for line in config.lines() {
        let key = line.split('=').next().unwrap_or("").trim();
        small.push_str(match key {
            "amplitudes_m" => "amplitudes_m = [0.01]",
            "peak_velocities_m_s" => "peak_velocities_m_s = [0.262, 1.048]",
            "max_ramp_s" => "max_ramp_s = 0.1",
            "min_steady_s" => "min_steady_s = 2.6",
            _ => line,
        });
        small.push('\n');
    }
    let toml = dir.join("small-bench.toml");
    std::fs::write(&toml, small).expect("write config");
    let data = dir.join("bench");
    nemm_ok(&[
        "bench".as_ref(),
        "generate".as_ref(),
        "--config".as_ref(),
        toml.as_os_str(),
        "--out".as_ref(),
        data.as_os_str(),
    ]);
    let ds = nemm_dataset::load(&data).expect("load the generated bench");
    assert_eq!(ds.runs.len(), 6);
    data
}
