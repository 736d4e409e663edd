//! Force error and speed of the `micromath` math backend against `libm` over a test-bench run.
//!
//! The backend is chosen at compile time, so this example runs twice: once with the default
//! `libm` build writing its forces, once with `micromath` comparing against them.
//!
//! ```text
//! cargo run --release -p nemm-core --example math_backends -- write /tmp/nemm-libm.bin
//! cargo run --release -p nemm-core --example math_backends \
//!     --no-default-features --features micromath -- compare /tmp/nemm-libm.bin
//! ```
//!
//! The run: the example NEMM and NEMM-Light (`testing::example_model(kind, 16, 5)`, alpha
//! 0.15, RK4 at 10 kHz) over the paper's Table 1 grid of sinusoidal strokes (amplitudes 50,
//! 30, 10 mm x peak velocities 0.052 ... 1.048 m/s), three periods each from rest. `compare`
//! prints per stroke and overall the max and RMS force difference in N and relative to the
//! model's force scale (`meta.force_scale_n`, 3000 N), and the largest relative error of the
//! backend's `exp` and `1/sqrt` over the ranges the model uses. For the speed of the two
//! backends see `benches/step.rs`.

use nemm_core::Sample;
use nemm_core::{Estimator, EstimatorConfig, Model, ModelKind};

const MAGIC: &[u8; 8] = b"nemmrun2";
const KINDS: [ModelKind; 2] = [ModelKind::Nemm, ModelKind::NemmLight];
const AMPLITUDES_M: [f64; 3] = [0.05, 0.03, 0.01];
const PEAK_VELOCITIES_M_S: [f64; 6] = [0.052, 0.131, 0.262, 0.393, 0.524, 1.048];
const PERIODS: f64 = 3.0;
const ALPHA: f32 = 0.15;

struct Run {
    /// Forces of every stroke, in grid order, per kind.
    forces: Vec<Vec<f32>>,
}

fn stroke(amp: f64, v_peak: f64, dt: f64) -> Vec<f32> {
    let w = v_peak / amp;
    let n = (PERIODS * 2.0 * std::f64::consts::PI / w / dt).round() as usize;
    (0..n)
        .map(|k| (v_peak * (w * k as f64 * dt).cos()) as f32)
        .collect()
}

fn simulate() -> Run {
    let mut forces = Vec::new();
    for kind in KINDS {
        let m: Model = nemm_core::testing::example_model(kind, 16, 5).expect("example model");
        let mut est = Estimator::new(&m, EstimatorConfig::new(ALPHA)).expect("valid model");
        let inputs: Vec<Vec<f32>> = AMPLITUDES_M
            .iter()
            .flat_map(|&a| PEAK_VELOCITIES_M_S.iter().map(move |&v| (a, v)))
            .map(|(a, v)| stroke(a, v, f64::from(m.dt_s)))
            .collect();
        let mut out = Vec::new();
        for s in &inputs {
            est.reset();
            out.extend(s.iter().map(|&v| est.step(Sample::new(v)).unwrap().force_n));
        }
        assert_eq!(est.diagnostics().resets, 0);
        forces.push(out);
    }
    Run { forces }
}

fn write(path: &str, run: &Run) -> std::io::Result<()> {
    let mut b = MAGIC.to_vec();
    for f in &run.forces {
        b.extend_from_slice(&(f.len() as u64).to_le_bytes());
        for x in f {
            b.extend_from_slice(&x.to_le_bytes());
        }
    }
    std::fs::write(path, b)
}

fn read(path: &str) -> Result<Run, String> {
    let b = std::fs::read(path).map_err(|e| format!("cannot read {path}: {e}"))?;
    let mut rest = b
        .strip_prefix(MAGIC.as_slice())
        .ok_or_else(|| format!("{path} was not written by this example"))?;
    let mut take = |n: usize| -> Result<&[u8], String> {
        if rest.len() < n {
            return Err(format!("{path} is truncated"));
        }
        let (h, t) = rest.split_at(n);
        rest = t;
        Ok(h)
    };
    let mut run = Run { forces: Vec::new() };
    for _ in KINDS {
        let n = u64::from_le_bytes(take(8)?.try_into().map_err(|_| "length")?) as usize;
        let f = take(4 * n)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        run.forces.push(f);
    }
    Ok(run)
}

#[derive(Default)]
struct ErrStats {
    max: f64,
    sq: f64,
    n: usize,
    peak: f64,
}

impl ErrStats {
    fn add(&mut self, a: f32, b: f32) {
        let d = f64::from(a - b).abs();
        self.max = self.max.max(d);
        self.sq += d * d;
        self.n += 1;
        self.peak = self.peak.max(f64::from(b).abs());
    }
    fn rms(&self) -> f64 {
        (self.sq / self.n.max(1) as f64).sqrt()
    }
}

fn compare(path: &str, run: &Run) -> Result<(), String> {
    let reference = read(path)?;
    println!(
        "backend {} vs reference file {path}, alpha {ALPHA}, RK4 10 kHz, {PERIODS} periods per stroke",
        nemm_kernels::math::BACKEND
    );
    for (i, kind) in KINDS.iter().enumerate() {
        let m: Model = nemm_core::testing::example_model(*kind, 16, 5).expect("example model");
        let scale = f64::from(m.meta.force_scale_n);
        let (got, want) = (&run.forces[i], &reference.forces[i]);
        if got.len() != want.len() {
            return Err(format!("{}: sample counts differ", kind.name()));
        }
        println!("\n{} (force scale {scale} N)", kind.name());
        println!(
            "{:>6} {:>7} {:>8} {:>10} {:>10} {:>10}",
            "amp_mm", "v_m_s", "F_peak_N", "max_err_N", "rms_err_N", "max/peak"
        );
        let mut all = ErrStats::default();
        let mut at = 0;
        for &a in &AMPLITUDES_M {
            for &v in &PEAK_VELOCITIES_M_S {
                let n = stroke(a, v, f64::from(m.dt_s)).len();
                let mut e = ErrStats::default();
                for (&g, &w) in got[at..at + n].iter().zip(&want[at..at + n]) {
                    e.add(g, w);
                    all.add(g, w);
                }
                at += n;
                println!(
                    "{:>6.0} {:>7.3} {:>8.1} {:>10.4} {:>10.4} {:>10.2e}",
                    a * 1e3,
                    v,
                    e.peak,
                    e.max,
                    e.rms(),
                    e.max / e.peak
                );
            }
        }
        println!(
            "all {} samples: max {:.4} N ({:.2e} of scale), RMS {:.4} N ({:.2e} of scale)",
            all.n,
            all.max,
            all.max / scale,
            all.rms(),
            all.rms() / scale
        );
    }
    Ok(())
}

/// Largest relative error of this build's `exp` on [-20, 20] and `rsqrt` on [1e-5, 1e3]
/// (the ranges of the sigmoid argument and of `var + eps` in LayerNorm), against f64.
fn function_errors() {
    let mut e_exp = 0.0f64;
    for k in -200_000..=200_000 {
        let x = k as f32 * 1e-4;
        let want = f64::from(x).exp();
        e_exp = e_exp.max((f64::from(nemm_kernels::math::exp(x)) - want).abs() / want);
    }
    let mut e_rsqrt = 0.0f64;
    for k in 0..=400_000 {
        let x = 1e-5f32 * 10f32.powf(k as f32 * 2e-5);
        let want = 1.0 / f64::from(x).sqrt();
        e_rsqrt = e_rsqrt.max((f64::from(nemm_kernels::math::rsqrt(x)) - want).abs() / want);
    }
    println!(
        "{}: max relative error exp {e_exp:.2e} (on [-20, 20]), rsqrt {e_rsqrt:.2e} (on [1e-5, 1e3])",
        nemm_kernels::math::BACKEND
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    function_errors();
    let result = match (args.first().map(String::as_str), args.get(1)) {
        (Some("write"), Some(path)) => {
            let run = simulate();
            for (k, f) in KINDS.iter().zip(&run.forces) {
                println!(
                    "{} ({}): {} samples",
                    k.name(),
                    nemm_kernels::math::BACKEND,
                    f.len()
                );
            }
            write(path, &run).map_err(|e| format!("cannot write {path}: {e}"))
        }
        (Some("compare"), Some(path)) => compare(path, &simulate()),
        _ => Err("usage: math_backends (write | compare) <file>".into()),
    };
    if let Err(e) = result {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}
