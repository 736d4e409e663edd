//! Build-time inputs of the firmware, all written to `OUT_DIR`:
//!
//! - `memory.x` for cortex-m-rt's `link.x`: the layout named by `NEMM_MEMORY_X`, default
//!   `boards/mps2-an386.x` (QEMU, with an STM32F4's budget; `boards/mps2-an500.x` with the
//!   `mps2-an500` feature; `boards/stm32f407.x` for an STM32F405/407), and
//!   `nemm-sections.x`, which every layout includes. (There is no
//!   `memory.x` in the crate directory: the linker would find it there first.)
//! - `weights.slot`: the weights slot (the `nemm-slot` format) holding the `.nemm` blob named by
//!   `NEMM_WEIGHTS` (default `data/trained-nemm.nemm`, the NEMM the project trained on its
//!   virtual bench with `cargo xtask firmware-model`; any trainer's `model.nemm` drops in
//!   here).
//! - `trace.bin`: the bench trace the replay device serves (`src/trace.rs`): the run CSV
//!   named by `NEMM_TRACE` (`time_s,displacement_m,force_n[,velocity_m_s]`, the project's
//!   dataset format read by its reader `nemm-dataset`, the measured force included; oil loss
//!   from `NEMM_TRACE_OIL_LOSS`,
//!   default 0.15), by default
//!   `data/e2e/runs/oil15_a050_v1048.csv` (a virtual-bench run, see `data/README.md`);
//!   `NEMM_TRACE=synthetic` selects a deterministic synthetic run over the paper's Table 1
//!   conditions instead.
//!
//! Relative paths are relative to this crate's directory.
// A failed build step panics with its reason.
#![allow(clippy::expect_used, clippy::panic)]

use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::SplitMix64;
use std::env;
use std::f64::consts::PI;
use std::fs;
use std::path::{Path, PathBuf};

/// The firmware's weights-slot format (one writer of the layout).
use nemm_slot as slot;

/// The trace format, the same source as the firmware's (one writer of the format).
#[path = "src/trace.rs"]
#[allow(dead_code)]
mod trace;

const SAMPLE_RATE_HZ: f64 = 10_000.0;
const DEFAULT_OIL_LOSS: f32 = 0.15;
const DEFAULT_TRACE: &str = "data/e2e/runs/oil15_a050_v1048.csv";

fn main() {
    let manifest_dir = PathBuf::from(env::var("CARGO_MANIFEST_DIR").expect("cargo sets it"));
    let out = PathBuf::from(env::var("OUT_DIR").expect("cargo sets it"));

    // The board feature's layout unless NEMM_MEMORY_X names another.
    let board_layout = if env::var_os("CARGO_FEATURE_MPS2_AN500").is_some() {
        "boards/mps2-an500.x"
    } else {
        "boards/mps2-an386.x"
    };
    let memory = input_path(&manifest_dir, "NEMM_MEMORY_X", board_layout);
    fs::copy(&memory, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("NEMM_MEMORY_X: cannot copy {}: {e}", memory.display()));
    fs::copy(
        manifest_dir.join("nemm-sections.x"),
        out.join("nemm-sections.x"),
    )
    .expect("copy nemm-sections.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=nemm-sections.x");

    let weights = input_path(&manifest_dir, "NEMM_WEIGHTS", "data/trained-nemm.nemm");
    let blob = fs::read(&weights)
        .unwrap_or_else(|e| panic!("NEMM_WEIGHTS: cannot read {}: {e}", weights.display()));
    fs::write(out.join("weights.slot"), slot(&blob, &weights)).expect("write weights.slot");

    println!("cargo:rerun-if-env-changed=NEMM_TRACE");
    println!("cargo:rerun-if-env-changed=NEMM_TRACE_OIL_LOSS");
    let oil_loss: f32 = match env::var("NEMM_TRACE_OIL_LOSS") {
        Ok(s) => s
            .parse()
            .ok()
            .filter(|a| (0.0..=1.0).contains(a))
            .unwrap_or_else(|| panic!("NEMM_TRACE_OIL_LOSS={s}: expected a number in [0, 1]")),
        Err(_) => DEFAULT_OIL_LOSS,
    };
    let trace_var = env::var_os("NEMM_TRACE").unwrap_or_else(|| DEFAULT_TRACE.into());
    let trace = match (trace_var != "synthetic").then_some(trace_var) {
        Some(p) => {
            let p = manifest_dir.join(p);
            println!("cargo:rerun-if-changed={}", p.display());
            let (rate, samples) = read_run_csv(&p, oil_loss)
                .unwrap_or_else(|e| panic!("NEMM_TRACE: {}: {e}", p.display()));
            encode_trace(rate, oil_loss, &samples)
        }
        None => encode_trace(SAMPLE_RATE_HZ as f32, oil_loss, &synthetic_run()),
    };
    fs::write(out.join("trace.bin"), trace).expect("write trace.bin");
}

fn input_path(dir: &Path, var: &str, default: &str) -> PathBuf {
    println!("cargo:rerun-if-env-changed={var}");
    let p = dir.join(env::var_os(var).unwrap_or_else(|| default.into()));
    println!("cargo:rerun-if-changed={}", p.display());
    p
}

fn slot(blob: &[u8], path: &Path) -> Vec<u8> {
    let mut s = vec![0; slot::CAPACITY];
    if let Err(e) = slot::encode(blob, &mut s) {
        panic!(
            "NEMM_WEIGHTS: {} does not fit the weights slot ({e:?}); export a smaller model or \
             raise slot::CAPACITY (and the WEIGHTS region in boards/*.x)",
            path.display()
        );
    }
    s
}

/// `(displacement_m, velocity_m_s, force_n)` per sample; velocity or force NaN if not
/// recorded.
type Sample = (f32, f32, f32);

fn encode_trace(rate_hz: f32, oil_loss: f32, samples: &[Sample]) -> Vec<u8> {
    let mut b = vec![0; trace::encoded_len(samples.len()).expect("trace length")];
    trace::encode(rate_hz, oil_loss, samples, &mut b).expect("the trace fits its buffer");
    b
}

/// The run CSV at `path`, read by the dataset's reader (`nemm_dataset::read_lone_run`: the
/// header names `time_s`, `displacement_m` and `force_n`, optionally `velocity_m_s`; errors
/// name the file and line; time stamps on a uniform grid); returns the mean sample rate
/// `(n - 1) / (t_last - t_first)` and the samples.
fn read_run_csv(path: &Path, oil_loss: f32) -> Result<(f32, Vec<Sample>), String> {
    let entry = nemm_dataset::RunEntry {
        file: path.to_path_buf(),
        oil_loss: f64::from(oil_loss),
        amplitude_m: None,
        target_velocity_m_s: None,
    };
    let (run, _grid) = nemm_dataset::read_lone_run(path, entry).map_err(|e| e.to_string())?;
    let (Some(&t0), Some(&t1)) = (run.time_s.first(), run.time_s.last()) else {
        return Err("no samples".into());
    };
    if run.len() < 2 {
        return Err("need at least two samples".into());
    }
    let rate = (run.len() - 1) as f64 / (t1 - t0);
    let velocity: Vec<f32> = match &run.velocity_m_s {
        Some(v) => v.iter().map(|&v| v as f32).collect(),
        None => vec![f32::NAN; run.len()],
    };
    let samples = run
        .displacement_m
        .iter()
        .zip(&velocity)
        .zip(&run.force_n)
        .map(|((&x, &v), &f)| (x as f32, v, f as f32))
        .collect();
    Ok((rate as f32, samples))
}

/// Synthetic bench run: for each of the paper's Table 1 conditions (stroke amplitude 50 and
/// 10 mm, target velocities 0.052 .. 1.048 m/s at the zero crossing) a 0.15 s sinusoidal
/// stroke segment `x = A w(t) sin(v t / A)` that starts at the zero crossing, with a 20 ms
/// raised-cosine fade in and out `w(t)` (so the stroke is continuous from segment to segment),
/// plus 0.5 um RMS white displacement noise. The velocity channel is the exact derivative;
/// there is no force (NaN).
fn synthetic_run() -> Vec<Sample> {
    const AMPLITUDES_M: [f64; 2] = [0.05, 0.01];
    const VELOCITIES_M_S: [f64; 6] = [0.052, 0.131, 0.262, 0.393, 0.524, 1.048];
    const SEGMENT_S: f64 = 0.15;
    const FADE_S: f64 = 0.02;
    const NOISE_M: f64 = 0.5e-6;
    let n_seg = (SEGMENT_S * SAMPLE_RATE_HZ) as usize;
    let mut rng = SplitMix64::seed_from_u64(0x4E45_4D4D);
    let mut out = Vec::new();
    for a in AMPLITUDES_M {
        for v_peak in VELOCITIES_M_S {
            let w = v_peak / a;
            for n in 0..n_seg {
                let t = n as f64 / SAMPLE_RATE_HZ;
                // Window and its derivative.
                let (win, dwin) = if t < FADE_S {
                    let p = PI * t / FADE_S;
                    (0.5 - 0.5 * p.cos(), 0.5 * PI / FADE_S * p.sin())
                } else if t > SEGMENT_S - FADE_S {
                    let p = PI * (SEGMENT_S - t) / FADE_S;
                    (0.5 - 0.5 * p.cos(), -0.5 * PI / FADE_S * p.sin())
                } else {
                    (1.0, 0.0)
                };
                let x = a * win * (w * t).sin();
                let v = a * dwin * (w * t).sin() + a * win * w * (w * t).cos();
                let noise: f64 = StandardNormal.sample(&mut rng);
                out.push(((x + NOISE_M * noise) as f32, v as f32, f32::NAN));
            }
        }
    }
    out
}
