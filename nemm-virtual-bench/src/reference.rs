//! Equivalent EMM coefficients implied by the virtual bench: what a model of the bench's data
//! should learn per oil-loss level (the derivation is in `docs/virtual-bench.md`, section
//! "Equivalent EMM coefficients"; `nemm bench reference` prints the numbers).
//!
//! Per level `alpha` the reference holds
//!
//! * the **chamber stiffnesses** `k_c = A_p² K_eff(p̄_c, c_c) / V_c` (compression chamber,
//!   piston area) and `k_r = A_ann² K_eff(p̄_r, c_r) / V_r` (rebound chamber, annulus area) at
//!   mid-stroke, with the tangent bulk modulus `K_eff` of the chamber fluid
//!   ([`VirtualBench::effective_bulk_modulus_pa`]) at the cycle-mean chamber pressure `p̄` of
//!   the reference run and its conditioned free-gas content `c` (normal gas volume per oil
//!   volume), and their sum `k_c + k_r`: the rod force's stiffness with every valve closed
//!   (the two chambers act on the piston in parallel);
//! * the **quasi-static flow damping** `b_fl(v) = F_qs(v) / v`
//!   ([`VirtualBench::quasi_static_force`]) at a list of velocities;
//! * the **describing-function EMM**: `k_pr` and `b_pr` of the linear pressure element that,
//!   in series with the first-harmonic equivalent of the quasi-static characteristic, gives
//!   the first harmonic of the bench's simulated (noise-free) force on the reference run:
//!   `1 / Z = 1 / b_eq + 1 / (b_pr + k_pr / (j ω))` with `Z = F_1 / V_1`. The bench has no
//!   dissipation in parallel with the fluid's compliance (the bubbles are loss-free, every
//!   dissipative path carries flow between chambers), so `b_pr` has no first-principles
//!   counterpart; this equivalent-parameter identification is its reference.
//!
//! Units: SI throughout (N/m, N s/m, Pa, m³, m/s).

use super::hydraulics::Filling;
use super::{program, Trace, VirtualBench};
use anyhow::{bail, Result};
use serde::Serialize;
use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::Path;

/// File a generated virtual-bench dataset carries next to its manifest: the bench
/// configuration it was simulated with (written by `nemm bench generate`), from which the
/// report recomputes the reference.
pub const BENCH_CONFIG_FILE: &str = "bench.toml";

/// Velocities at which the reference lists `b_fl` \[m/s\].
pub const REFERENCE_VELOCITIES_M_S: [f64; 6] = [-1.0, -0.5, -0.1, 0.1, 0.5, 1.0];

/// Spacing of the default oil-loss levels of the reference \[-\].
pub const ALPHA_STEP: f64 = 0.05;

/// Full-amplitude periods simulated after the ramp-in on the reference run; the last
/// [`ANALYSED_PERIODS`] are analysed.
const SIMULATED_PERIODS: u32 = 3;
/// Periods at the end of the reference run over which the pressures are averaged and the
/// first harmonic is taken.
const ANALYSED_PERIODS: u32 = 2;
/// Points of the quadrature of the first-harmonic equivalent of the quasi-static force.
const HARMONIC_POINTS: usize = 256;

/// The sine run at which the working state is evaluated: Table 1's smallest amplitude at its
/// highest peak velocity (10 mm, 1.048 m/s, 16.7 Hz on the default bench), where oil loss
/// changes the loops most.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReferenceRun {
    /// Stroke amplitude \[m\].
    pub amplitude_m: f64,
    /// Peak velocity \[m/s\].
    pub peak_velocity_m_s: f64,
}

impl ReferenceRun {
    /// The smallest amplitude and the highest peak velocity of the bench's sine programme.
    pub fn of(bench: &VirtualBench) -> Self {
        let p = &bench.config().program;
        ReferenceRun {
            amplitude_m: p.amplitudes_m.iter().copied().fold(f64::INFINITY, f64::min),
            peak_velocity_m_s: p.peak_velocities_m_s.iter().copied().fold(0.0, f64::max),
        }
    }

    /// Excitation frequency \[Hz\].
    pub fn frequency_hz(&self) -> f64 {
        self.peak_velocity_m_s / (2.0 * PI * self.amplitude_m)
    }
}

/// The stiffness one working chamber's fluid gives the piston at mid-stroke.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ChamberStiffness {
    /// Area through which the piston compresses the chamber \[m²\] (`A_p` or `A_ann`).
    pub area_m2: f64,
    /// Chamber volume at mid-stroke \[m³\].
    pub volume_m3: f64,
    /// Cycle-mean absolute chamber pressure on the reference run \[Pa\].
    pub pressure_pa: f64,
    /// Conditioned free gas of the reference run, normal volume per oil volume \[-\].
    pub gas_per_oil: f64,
    /// Tangent bulk modulus of the chamber fluid at that pressure and gas content \[Pa\].
    pub bulk_modulus_pa: f64,
    /// `area² K_eff / volume` \[N/m\].
    pub k_n_per_m: f64,
}

/// The linear EMM pressure element identified from the first harmonic of the reference run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DescribingFit {
    /// First-harmonic equivalent damping of the quasi-static characteristic at the run's
    /// velocity amplitude, `b_eq = (1 / (π V)) ∫ F_qs(V cos θ) cos θ dθ` \[N s/m\].
    pub b_fl_eq_ns_per_m: f64,
    /// Real part of the run's impedance `Z = F_1 / V_1` \[N s/m\].
    pub impedance_re_ns_per_m: f64,
    /// Imaginary part of `Z` \[N s/m\].
    pub impedance_im_ns_per_m: f64,
    /// Equivalent pressure stiffness `k_pr = ω Im(Y) / |Y|²`, `Y = 1/Z - 1/b_eq` \[N/m\].
    pub k_pr_n_per_m: f64,
    /// Equivalent pressure damping `b_pr = Re(Y) / |Y|²` \[N s/m\].
    pub b_pr_ns_per_m: f64,
}

/// The quasi-static flow damping at one velocity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FlowDamping {
    /// Velocity \[m/s\] (positive = extension).
    pub velocity_m_s: f64,
    /// Quasi-static force \[N\] (tared like the recorded force).
    pub force_n: f64,
    /// `b_fl = F_qs / v` \[N s/m\].
    pub b_fl_ns_per_m: f64,
}

/// The reference at one oil-loss level.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LevelReference {
    /// Oil loss \[-\].
    pub alpha: f64,
    /// Absolute pressure at rest \[Pa\].
    pub rest_pressure_pa: f64,
    /// Compression chamber (piston area).
    pub compression: ChamberStiffness,
    /// Rebound chamber (annulus area).
    pub rebound: ChamberStiffness,
    /// Both chambers in parallel, `k_c + k_r` \[N/m\].
    pub k_pr_combined_n_per_m: f64,
    /// The describing-function EMM of the reference run.
    pub describing: DescribingFit,
    /// `b_fl` at [`EmmReference::velocities_m_s`].
    pub b_fl: Vec<FlowDamping>,
}

/// One reference coefficient, as a function of alpha.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Coefficient {
    /// `k_c`, compression chamber \[N/m\].
    KPrCompression,
    /// `k_r`, rebound chamber \[N/m\].
    KPrRebound,
    /// `k_c + k_r` \[N/m\].
    KPrCombined,
    /// `k_pr` of the describing-function EMM \[N/m\].
    KPrDescribing,
    /// `b_pr` of the describing-function EMM \[N s/m\].
    BPrDescribing,
    /// Quasi-static `b_fl` at the given velocity \[N s/m\].
    BFl(f64),
}

impl Coefficient {
    /// Short name for tables and legends.
    pub fn name(&self) -> String {
        match self {
            Coefficient::KPrCompression => "k_pr, compression chamber".into(),
            Coefficient::KPrRebound => "k_pr, rebound chamber".into(),
            Coefficient::KPrCombined => "k_pr, both chambers".into(),
            Coefficient::KPrDescribing => "k_pr, describing function".into(),
            Coefficient::BPrDescribing => "b_pr, describing function".into(),
            Coefficient::BFl(v) => format!("b_fl at v = {v} m/s"),
        }
    }
}

/// The bench's equivalent EMM coefficients over oil loss.
#[derive(Debug, Clone, Serialize)]
pub struct EmmReference {
    /// The run whose working state is used.
    pub run: ReferenceRun,
    /// Velocities of the `b_fl` entries \[m/s\].
    pub velocities_m_s: Vec<f64>,
    /// One entry per level, alpha increasing.
    pub levels: Vec<LevelReference>,
    #[serde(skip)]
    bench: VirtualBench,
}

impl EmmReference {
    /// The reference at the levels `alphas` (sorted, duplicates removed) on the run `run`,
    /// `b_fl` at `velocities_m_s`. Levels must lie in `[0, valid_alpha_max]`.
    pub fn compute(
        bench: &VirtualBench,
        alphas: &[f64],
        run: ReferenceRun,
        velocities_m_s: &[f64],
    ) -> Result<Self> {
        let mut al: Vec<f64> = alphas.to_vec();
        al.sort_by(f64::total_cmp);
        al.dedup_by(|a, b| (*a - *b).abs() < 1e-12);
        let a_max = valid_alpha_max(bench);
        if al.is_empty() || al[0] < 0.0 || al[al.len() - 1] > a_max {
            bail!("reference levels must lie in [0, {a_max:.3}] (the bench's valid range), got {al:?}");
        }
        if !(run.amplitude_m > 0.0 && run.peak_velocity_m_s > 0.0) {
            bail!("reference run needs a positive amplitude and velocity, got {run:?}");
        }
        use rayon::prelude::*;
        let levels = al
            .par_iter()
            .map(|&a| level(bench, a, run, velocities_m_s))
            .collect::<Result<Vec<_>>>()?;
        Ok(EmmReference {
            run,
            velocities_m_s: velocities_m_s.to_vec(),
            levels,
            bench: bench.clone(),
        })
    }

    /// The reference of a bench at its default levels ([`default_alphas`]), on its reference
    /// run ([`ReferenceRun::of`]), `b_fl` at [`REFERENCE_VELOCITIES_M_S`].
    pub fn of(bench: &VirtualBench) -> Result<Self> {
        Self::compute(
            bench,
            &default_alphas(bench),
            ReferenceRun::of(bench),
            &REFERENCE_VELOCITIES_M_S,
        )
    }

    /// The bench the reference was computed for.
    pub fn bench(&self) -> &VirtualBench {
        &self.bench
    }

    /// Largest level of the reference.
    pub fn alpha_max(&self) -> f64 {
        self.levels.last().map_or(0.0, |l| l.alpha)
    }

    /// The value of `c` at every level: `(alpha, value)`.
    pub fn curve(&self, c: Coefficient) -> Vec<(f64, f64)> {
        self.levels
            .iter()
            .map(|l| (l.alpha, self.value_at_level(l, c)))
            .collect()
    }

    fn value_at_level(&self, l: &LevelReference, c: Coefficient) -> f64 {
        match c {
            Coefficient::KPrCompression => l.compression.k_n_per_m,
            Coefficient::KPrRebound => l.rebound.k_n_per_m,
            Coefficient::KPrCombined => l.k_pr_combined_n_per_m,
            Coefficient::KPrDescribing => l.describing.k_pr_n_per_m,
            Coefficient::BPrDescribing => l.describing.b_pr_ns_per_m,
            Coefficient::BFl(v) => match l.b_fl.iter().find(|b| b.velocity_m_s == v) {
                Some(b) => b.b_fl_ns_per_m,
                None => b_fl(&self.bench, v, l.alpha),
            },
        }
    }

    /// `c` at `alpha`, linear between the levels (`None` outside them).
    pub fn value(&self, c: Coefficient, alpha: f64) -> Option<f64> {
        let pts = self.curve(c);
        interpolate(&pts, alpha)
    }

    /// `c(alpha) / c(0) - 1` (`None` outside the levels or without a level at 0).
    pub fn relative(&self, c: Coefficient, alpha: f64) -> Option<f64> {
        let v0 = self.value(c, 0.0)?;
        let v = self.value(c, alpha)?;
        (v0 != 0.0).then(|| v / v0 - 1.0)
    }

    /// The reference as Markdown: the working state and stiffnesses, then the damping, each
    /// absolute and relative to alpha = 0.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let r = &self.run;
        let _ = writeln!(
            s,
            "Working state: reference run {} mm, {} m/s ({:.1} Hz), cycle mean over its last {} \
             periods; gas c in normal volumes per oil volume; K_eff tangent bulk modulus; k in kN/m; \
             (%) relative to alpha = 0.\n",
            fmt_g(r.amplitude_m * 1e3),
            fmt_g(r.peak_velocity_m_s),
            r.frequency_hz(),
            ANALYSED_PERIODS
        );
        let _ = writeln!(
            s,
            "| alpha | p_rest [bar] | p_c [bar] | c_c | K_c [MPa] | k_c [kN/m] (%) | p_r [bar] | c_r | K_r [MPa] | k_r [kN/m] (%) | k_c + k_r [kN/m] (%) |"
        );
        let _ = writeln!(
            s,
            "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
        );
        let rel = |c: Coefficient, a: f64| {
            self.relative(c, a)
                .map_or("n/a".to_string(), |x| format!("{:+.1} %", 100.0 * x))
        };
        for l in &self.levels {
            let (c, rb) = (&l.compression, &l.rebound);
            let _ = writeln!(
                s,
                "| {:.2} | {:.2} | {:.2} | {:.3} | {:.1} | {:.1} ({}) | {:.2} | {:.3} | {:.1} | {:.1} ({}) | {:.1} ({}) |",
                l.alpha,
                l.rest_pressure_pa / 1e5,
                c.pressure_pa / 1e5,
                c.gas_per_oil,
                c.bulk_modulus_pa / 1e6,
                c.k_n_per_m / 1e3,
                rel(Coefficient::KPrCompression, l.alpha),
                rb.pressure_pa / 1e5,
                rb.gas_per_oil,
                rb.bulk_modulus_pa / 1e6,
                rb.k_n_per_m / 1e3,
                rel(Coefficient::KPrRebound, l.alpha),
                l.k_pr_combined_n_per_m / 1e3,
                rel(Coefficient::KPrCombined, l.alpha),
            );
        }
        let _ = writeln!(
            s,
            "\nDescribing-function EMM of the reference run (Z = F_1 / V_1, b_eq of the quasi-static \
             characteristic; k in kN/m, b in N s/m) and quasi-static b_fl = F_qs / v [N s/m]:\n"
        );
        let mut head = "| alpha | b_eq | Z | k_pr [kN/m] (%) | b_pr (%) |".to_string();
        let mut rule = "|---:|---:|---:|---:|---:|".to_string();
        for v in &self.velocities_m_s {
            let _ = write!(head, " b_fl({v:+}) (%) |");
            rule.push_str("---:|");
        }
        let _ = writeln!(s, "{head}\n{rule}");
        for l in &self.levels {
            let d = &l.describing;
            let _ = write!(
                s,
                "| {:.2} | {:.0} | {:.0} {:+.0}j | {:.1} ({}) | {:.0} ({}) |",
                l.alpha,
                d.b_fl_eq_ns_per_m,
                d.impedance_re_ns_per_m,
                d.impedance_im_ns_per_m,
                d.k_pr_n_per_m / 1e3,
                rel(Coefficient::KPrDescribing, l.alpha),
                d.b_pr_ns_per_m,
                rel(Coefficient::BPrDescribing, l.alpha),
            );
            for b in &l.b_fl {
                let _ = write!(
                    s,
                    " {:.0} ({}) |",
                    b.b_fl_ns_per_m,
                    rel(Coefficient::BFl(b.velocity_m_s), l.alpha)
                );
            }
            s.push('\n');
        }
        s
    }
}

/// The reference on every condition (amplitude, peak velocity) of the bench's sine programme
/// at its oil-loss levels in the valid range (and 0): how far the pressure element's
/// degradation depends on the run, not on the level alone (the free gas each run draws in
/// grows with its intake flow). Conditions in the programme's order; no `b_fl` rows.
pub fn every_condition(bench: &VirtualBench) -> Result<Vec<EmmReference>> {
    use rayon::prelude::*;
    let p = &bench.config().program;
    let a_max = valid_alpha_max(bench);
    let mut alphas: Vec<f64> = p
        .oil_loss
        .iter()
        .copied()
        .filter(|a| (0.0..=a_max).contains(a))
        .collect();
    alphas.push(0.0);
    let runs: Vec<ReferenceRun> = p
        .amplitudes_m
        .iter()
        .flat_map(|&amplitude_m| {
            p.peak_velocities_m_s
                .iter()
                .map(move |&peak_velocity_m_s| ReferenceRun {
                    amplitude_m,
                    peak_velocity_m_s,
                })
        })
        .collect();
    runs.par_iter()
        .map(|&run| EmmReference::compute(bench, &alphas, run, &[]))
        .collect()
}

/// [`every_condition`] as Markdown: per condition and level the compression chamber's free
/// gas and stiffness, the rebound chamber's stiffness and the describing-function `k_pr`, each
/// stiffness with its change from level 0 on the same condition; then the spread of the
/// compression chamber's change over the conditions at each level.
pub fn every_condition_markdown(refs: &[EmmReference]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "The pressure element per condition: each run conditioned as recorded, cycle means over \
         its last {ANALYSED_PERIODS} periods; c_c the compression chamber's free gas (normal \
         volumes per oil volume), k in kN/m, (%) against level 0 on the same condition.\n"
    );
    let _ = writeln!(
        s,
        "| amplitude [mm] | peak velocity [m/s] | frequency [Hz] | alpha | c_c | k_c [kN/m] (%) | k_r [kN/m] (%) | k_pr describing [kN/m] (%) |"
    );
    let _ = writeln!(s, "|---:|---:|---:|---:|---:|---:|---:|---:|");
    let pct = |r: &EmmReference, c: Coefficient, a: f64| {
        r.relative(c, a)
            .map_or(String::new(), |x| format!(" ({:+.0} %)", 100.0 * x))
    };
    for r in refs {
        for l in &r.levels {
            let _ = writeln!(
                s,
                "| {} | {} | {:.1} | {} | {:.3} | {:.0}{} | {:.0}{} | {:.0}{} |",
                fmt_g(r.run.amplitude_m * 1e3),
                fmt_g(r.run.peak_velocity_m_s),
                r.run.frequency_hz(),
                fmt_g(l.alpha),
                l.compression.gas_per_oil,
                l.compression.k_n_per_m / 1e3,
                pct(r, Coefficient::KPrCompression, l.alpha),
                l.rebound.k_n_per_m / 1e3,
                pct(r, Coefficient::KPrRebound, l.alpha),
                l.describing.k_pr_n_per_m / 1e3,
                pct(r, Coefficient::KPrDescribing, l.alpha),
            );
        }
    }
    let levels: Vec<f64> = refs
        .first()
        .map(|r| {
            r.levels
                .iter()
                .map(|l| l.alpha)
                .filter(|&a| a > 0.0)
                .collect()
        })
        .unwrap_or_default();
    if !levels.is_empty() {
        let _ = writeln!(
            s,
            "\nThe compression chamber's change over the {} conditions:",
            refs.len()
        );
    }
    for a in levels {
        let ch: Vec<f64> = refs
            .iter()
            .filter_map(|r| r.relative(Coefficient::KPrCompression, a))
            .collect();
        let (lo, hi) = (
            ch.iter().copied().fold(f64::INFINITY, f64::min),
            ch.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        );
        let _ = writeln!(
            s,
            "- alpha {}: from {:+.0} % to {:+.0} % (k_c(alpha) / k_c(0) from {:.2} to {:.2})",
            fmt_g(a),
            100.0 * lo,
            100.0 * hi,
            1.0 + lo,
            1.0 + hi
        );
    }
    s
}

/// The level at which the reserve tube would hold no oil at rest: the oil lost is then the
/// whole reservoir content (the intake would draw gas only, which the bench does not model).
pub fn reservoir_dry_alpha(bench: &VirtualBench) -> f64 {
    let f = bench.filling(0.0);
    (f.oil_total - f.m_rebound0 - f.m_compression0) / f.oil_total
}

/// Largest level of the reference: 90 % of [`reservoir_dry_alpha`] (0.36 on the default bench).
pub fn valid_alpha_max(bench: &VirtualBench) -> f64 {
    0.9 * reservoir_dry_alpha(bench)
}

/// Levels `0, ALPHA_STEP, ...` up to [`valid_alpha_max`], with the programme's oil-loss
/// levels that lie in that range (so that the trained levels are reference levels).
pub fn default_alphas(bench: &VirtualBench) -> Vec<f64> {
    let a_max = valid_alpha_max(bench);
    let mut v: Vec<f64> = (0..)
        .map(|i| f64::from(i) * ALPHA_STEP)
        .take_while(|&a| a <= a_max + 1e-12)
        .map(|a| (a * 1e6).round() / 1e6)
        .collect();
    v.extend(
        bench
            .config()
            .program
            .oil_loss
            .iter()
            .copied()
            .filter(|&a| (0.0..=a_max).contains(&a)),
    );
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    v
}

/// The reference of a dataset folder generated by the virtual bench: `None` when the folder
/// has no [`BENCH_CONFIG_FILE`] (data from elsewhere).
pub fn for_dataset(dir: &Path) -> Result<Option<EmmReference>> {
    let path = dir.join(BENCH_CONFIG_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let cfg = super::config::load(&path)?;
    EmmReference::of(&VirtualBench::new(cfg)).map(Some)
}

/// Quasi-static `b_fl = F_qs(v, alpha) / v` \[N s/m\] (`NaN` at `v = 0`).
pub fn b_fl(bench: &VirtualBench, v: f64, alpha: f64) -> f64 {
    if v == 0.0 {
        return f64::NAN;
    }
    bench.quasi_static_force(v, alpha) / v
}

/// Linear interpolation in sorted points (`None` outside them).
fn interpolate(pts: &[(f64, f64)], x: f64) -> Option<f64> {
    let eps = 1e-9;
    let first = pts.first()?;
    let last = pts.last()?;
    if x < first.0 - eps || x > last.0 + eps {
        return None;
    }
    if pts.len() == 1 {
        return Some(first.1);
    }
    let i = pts
        .windows(2)
        .position(|w| x <= w[1].0 + eps)
        .unwrap_or(pts.len() - 2);
    let (a, b) = (pts[i], pts[i + 1]);
    let t = ((x - a.0) / (b.0 - a.0)).clamp(0.0, 1.0);
    Some(a.1 + t * (b.1 - a.1))
}

fn fmt_g(v: f64) -> String {
    let s = format!("{v:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// The reference run at `alpha`, shortened to [`SIMULATED_PERIODS`] periods after the ramp.
fn run_spec(bench: &VirtualBench, alpha: f64, run: ReferenceRun) -> program::RunSpec {
    let p = &bench.config().program;
    let mut spec = program::run_spec(p, alpha, run.amplitude_m, run.peak_velocity_m_s);
    spec.steady_periods = SIMULATED_PERIODS;
    spec.samples = (spec.duration_s() * p.sample_rate_hz).round() as usize + 1;
    spec
}

/// Indices of the samples of the last `periods` periods of a trace (the first one at or
/// before the window start, so that the window is covered).
fn window(tr: &Trace, period_s: f64, periods: u32) -> std::ops::Range<usize> {
    let n = tr.time_s.len();
    let t_end = tr.time_s[n - 1];
    let t0 = t_end - f64::from(periods) * period_s;
    let first = tr.time_s.partition_point(|&t| t <= t0).saturating_sub(1);
    first..n
}

/// Mean of `y` over `[t_end - span, t_end]` and its first-harmonic coefficient
/// `(2 / span) ∫ y e^(-jωt) dt` as `(re, im)`; trapezoids on the samples, the partial first
/// interval by linear interpolation.
fn mean_and_harmonic(t: &[f64], y: &[f64], span: f64, omega: f64) -> (f64, (f64, f64)) {
    let t_end = t[t.len() - 1];
    let t0 = t_end - span;
    let (mut m, mut re, mut im) = (0.0, 0.0, 0.0);
    for i in 0..t.len() - 1 {
        let (mut ta, mut ya) = (t[i], y[i]);
        let (tb, yb) = (t[i + 1], y[i + 1]);
        if tb <= t0 {
            continue;
        }
        if ta < t0 {
            ya += (yb - ya) * (t0 - ta) / (tb - ta);
            ta = t0;
        }
        let dt = tb - ta;
        m += 0.5 * (ya + yb) * dt;
        re += 0.5 * (ya * (omega * ta).cos() + yb * (omega * tb).cos()) * dt;
        im -= 0.5 * (ya * (omega * ta).sin() + yb * (omega * tb).sin()) * dt;
    }
    (m / span, (2.0 * re / span, 2.0 * im / span))
}

/// First-harmonic equivalent damping of the quasi-static characteristic at velocity
/// amplitude `v_amp`: `(1 / (π V)) ∫_0^{2π} F_qs(V cos θ) cos θ dθ` (midpoint rule).
fn harmonic_b_fl(bench: &VirtualBench, v_amp: f64, alpha: f64) -> f64 {
    let n = HARMONIC_POINTS;
    let dth = 2.0 * PI / n as f64;
    let sum: f64 = (0..n)
        .map(|i| {
            let th = (i as f64 + 0.5) * dth;
            bench.quasi_static_force(v_amp * th.cos(), alpha) * th.cos()
        })
        .sum();
    sum * dth / (PI * v_amp)
}

fn chamber(bench: &VirtualBench, area: f64, volume: f64, p: f64, c: f64) -> ChamberStiffness {
    let k_eff = bench.effective_bulk_modulus_pa(p, c);
    ChamberStiffness {
        area_m2: area,
        volume_m3: volume,
        pressure_pa: p,
        gas_per_oil: c,
        bulk_modulus_pa: k_eff,
        k_n_per_m: area * area * k_eff / volume,
    }
}

fn level(
    bench: &VirtualBench,
    alpha: f64,
    run: ReferenceRun,
    velocities: &[f64],
) -> Result<LevelReference> {
    let d = &bench.damper;
    let spec = run_spec(bench, alpha, run);
    let h = bench.config().solver.internal_step_s;
    let start: Filling = bench.conditioned_start(&spec, h);
    let tr = bench.simulate_with_step(&spec, h);
    let omega = 2.0 * PI * spec.frequency_hz;
    let period = 1.0 / spec.frequency_hz;
    let span = f64::from(ANALYSED_PERIODS) * period;
    let w = window(&tr, period, ANALYSED_PERIODS);
    let t = &tr.time_s[w.clone()];
    let (p_c, _) = mean_and_harmonic(t, &tr.p_compression_pa[w.clone()], span, omega);
    let (p_r, _) = mean_and_harmonic(t, &tr.p_rebound_pa[w.clone()], span, omega);
    let (_, f1) = mean_and_harmonic(t, &tr.force_n[w.clone()], span, omega);
    let (_, v1) = mean_and_harmonic(t, &tr.velocity_m_s[w], span, omega);
    // Z = F1 / V1 (complex division).
    let vv = v1.0 * v1.0 + v1.1 * v1.1;
    let z = (
        (f1.0 * v1.0 + f1.1 * v1.1) / vv,
        (f1.1 * v1.0 - f1.0 * v1.1) / vv,
    );
    let v_amp = vv.sqrt();
    let b_eq = harmonic_b_fl(bench, v_amp, alpha);
    // Y = 1/Z - 1/b_eq = 1 / (b_pr + k_pr / (jω)) = 1 / (b_pr - j k_pr / ω).
    let zz = z.0 * z.0 + z.1 * z.1;
    let y = (z.0 / zz - 1.0 / b_eq, -z.1 / zz);
    let yy = y.0 * y.0 + y.1 * y.1;
    let describing = DescribingFit {
        b_fl_eq_ns_per_m: b_eq,
        impedance_re_ns_per_m: z.0,
        impedance_im_ns_per_m: z.1,
        k_pr_n_per_m: omega * y.1 / yy,
        b_pr_ns_per_m: y.0 / yy,
    };
    let c_c = start.gas_compression / start.m_compression0;
    let c_r = start.gas_rebound / start.m_rebound0;
    let compression = chamber(bench, d.a_piston, d.v_compression0, p_c, c_c);
    let rebound = chamber(bench, d.a_annulus, d.v_rebound0, p_r, c_r);
    let values = [
        compression.k_n_per_m,
        rebound.k_n_per_m,
        describing.k_pr_n_per_m,
        describing.b_pr_ns_per_m,
    ];
    if values.iter().any(|v| !v.is_finite()) {
        bail!("the reference at alpha = {alpha} is not finite: {values:?}");
    }
    Ok(LevelReference {
        alpha,
        rest_pressure_pa: bench.rest_state(alpha).pressure_pa,
        k_pr_combined_n_per_m: compression.k_n_per_m + rebound.k_n_per_m,
        compression,
        rebound,
        describing,
        b_fl: velocities
            .iter()
            .map(|&v| {
                let f = bench.quasi_static_force(v, alpha);
                FlowDamping {
                    velocity_m_s: v,
                    force_n: f,
                    b_fl_ns_per_m: f / v,
                }
            })
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::BenchConfig;

    #[test]
    fn interpolation_is_linear_and_bounded() {
        let pts = [(0.0, 10.0), (0.1, 8.0), (0.3, 4.0)];
        assert_eq!(interpolate(&pts, 0.0), Some(10.0));
        assert!((interpolate(&pts, 0.05).unwrap() - 9.0).abs() < 1e-12);
        assert!((interpolate(&pts, 0.2).unwrap() - 6.0).abs() < 1e-12);
        assert_eq!(interpolate(&pts, 0.3), Some(4.0));
        assert_eq!(interpolate(&pts, 0.31), None);
    }

    #[test]
    fn harmonic_of_a_sine_is_its_amplitude() {
        let fs = 10_000.0;
        let omega = 2.0 * PI * 16.68;
        let t: Vec<f64> = (0..3000).map(|i| f64::from(i) / fs).collect();
        let y: Vec<f64> = t
            .iter()
            .map(|&t| 3.0 + 2.0 * (omega * t).cos() - 5.0 * (omega * t).sin())
            .collect();
        let span = 2.0 * 2.0 * PI / omega;
        let (m, (re, im)) = mean_and_harmonic(&t, &y, span, omega);
        assert!((m - 3.0).abs() < 1e-3, "{m}");
        assert!(
            (re - 2.0).abs() < 1e-3 && (im - 5.0).abs() < 1e-3,
            "{re} {im}"
        );
    }

    fn default_reference() -> EmmReference {
        EmmReference::of(&VirtualBench::new(BenchConfig::default())).expect("reference")
    }

    #[test]
    fn pressure_stiffness_falls_with_oil_loss() {
        let r = default_reference();
        assert!(r.alpha_max() >= 0.3, "{}", r.alpha_max());
        for c in [
            Coefficient::KPrCompression,
            Coefficient::KPrRebound,
            Coefficient::KPrCombined,
            Coefficient::KPrDescribing,
        ] {
            let k = r.curve(c);
            assert!(
                k.iter().all(|p| p.1.is_finite() && p.1 > 0.0),
                "{c:?}: {k:?}"
            );
            assert!(
                k.windows(2).all(|w| w[1].1 < w[0].1),
                "{c:?} not falling: {k:?}"
            );
        }
        // The foam and the lower gas pressure: the compression chamber's fluid loses more than
        // half of its stiffness by 15 % (as the tangent-modulus test of the bench implies),
        // the rebound chamber, at its higher working pressure, less.
        let rc = r.relative(Coefficient::KPrCompression, 0.15).unwrap();
        let rr = r.relative(Coefficient::KPrRebound, 0.15).unwrap();
        assert!(rc < -0.5 && rr < 0.0 && rr > rc, "{rc} {rr}");
        // Magnitudes: 1e5..1e7 N/m at alpha = 0 (piston area² x 0.1-1 GPa / 0.1 l); the
        // describing-function stiffness of the run is of the size of the chambers'.
        let k0 = r.value(Coefficient::KPrCombined, 0.0).unwrap();
        assert!((1e5..1e7).contains(&k0), "{k0}");
        let kd = r.value(Coefficient::KPrDescribing, 0.0).unwrap();
        assert!(kd > 0.2 * k0 && kd < 2.0 * k0, "{kd} vs {k0}");
        let rd = r.relative(Coefficient::KPrDescribing, 0.3).unwrap();
        assert!(rd < -0.5, "{rd}");
    }

    #[test]
    fn flow_damping_barely_changes_and_never_rises() {
        let r = default_reference();
        for &v in &r.velocities_m_s {
            let b = r.curve(Coefficient::BFl(v));
            assert!(b.iter().all(|p| p.1.is_finite() && p.1 > 0.0), "{v}: {b:?}");
            assert!(b.windows(2).all(|w| w[1].1 <= w[0].1 + 1e-9), "{v}: {b:?}");
            let rel = r.relative(Coefficient::BFl(v), 0.3).unwrap();
            assert!(rel <= 0.0 && rel > -0.01, "{v}: {rel}");
        }
        // Rebound stiffer than compression, digressive: b_fl falls with |v|.
        let at = |v: f64| r.value(Coefficient::BFl(v), 0.0).unwrap();
        assert!(at(0.5) > at(-0.5) && at(0.1) > at(0.5) && at(-0.1) > at(-0.5));
        // A velocity not in the list is evaluated on the bench.
        assert!(
            (r.value(Coefficient::BFl(0.3), 0.0).unwrap() - b_fl(r.bench(), 0.3, 0.0)).abs() < 1e-9
        );
    }

    #[test]
    fn pressure_damping_is_positive_and_lower_at_30_percent() {
        let r = default_reference();
        let b = r.curve(Coefficient::BPrDescribing);
        assert!(b.iter().all(|p| p.1.is_finite() && p.1 > 0.0), "{b:?}");
        let rel = r.relative(Coefficient::BPrDescribing, 0.3).unwrap();
        assert!(rel < -0.2, "{rel}");
    }

    #[test]
    fn levels_outside_the_valid_range_are_refused() {
        let b = VirtualBench::new(BenchConfig::default());
        let run = ReferenceRun::of(&b);
        assert!(EmmReference::compute(&b, &[0.0, 0.6], run, &[0.5]).is_err());
        assert!(EmmReference::compute(&b, &[], run, &[0.5]).is_err());
    }

    #[test]
    fn default_levels_cover_the_programme() {
        let b = VirtualBench::new(BenchConfig::default());
        let a = default_alphas(&b);
        assert_eq!(a[0], 0.0);
        for l in &b.config().program.oil_loss {
            assert!(a.iter().any(|x| (x - l).abs() < 1e-9), "{l} in {a:?}");
        }
        let dry = reservoir_dry_alpha(&b);
        assert!((0.3..0.5).contains(&dry), "{dry}");
        assert!(a.iter().all(|&x| x <= valid_alpha_max(&b)));
    }
}
