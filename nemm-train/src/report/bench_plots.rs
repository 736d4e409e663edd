//! `nemm bench plot`: force-velocity loops (like Fig. 4 of the paper), difference loops
//! against 0 % oil loss (like Fig. 5) and the quasi-static characteristic of any dataset in the
//! interchange format (virtual or real bench).
//!
//! Periodic runs (the rule of [`crate::data::support_points::periodicity`]: manifest metadata or
//! regular zero crossings) are reduced to one cycle-averaged loop each: the last full periods
//! (at least one, up to 60 % of the run) are folded onto the phase of the displacement (a
//! least-squares sine fit at the excitation frequency), and velocity and force are averaged in
//! phase bins: [`MAX_PHASE_BINS`] (256), or, when a period has fewer samples, the largest
//! power of two not above the samples per period, halved until every bin holds a sample
//! (at least [`MIN_PHASE_BINS`]). The displacement is centred on the fit's offset, so a
//! transducer zero away from the stroke centre does not move the quasi-static window. The
//! velocity is the one the trainer sees, derived once per run by the preprocessing
//! ([`crate::data::preprocess::run_signals`]: zero-phase low-pass of the displacement and
//! central difference, or the measured column). Averaging over periods removes the sensor
//! noise without the phase lag of a filter. Forces are normalised by the largest
//! cycle-averaged |force| of the dataset, as in the paper's figures.
//!
//! Non-periodic runs (random excitation) have no loop: `random_runs.png` shows, per run, the
//! force-velocity density (a 2-D histogram of the samples) and time traces of force and
//! velocity.

use crate::data::preprocess::{run_signals, SignalConfig, Signals};
use crate::data::support_points::periodicity;
use crate::report::plot::{palette, Figure, HeatmapPanel, LegendPosition, LinePanel, Series};
use anyhow::{bail, Context, Result};
use nemm_dataset::{self as dataset, alpha_text, ConditionSpec, Dataset, Run};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

/// Phase bins of a cycle-averaged loop when a period has enough samples.
pub(crate) const MAX_PHASE_BINS: usize = 256;
/// Fewest phase bins of a loop; a period with fewer samples gives no loop.
pub(crate) const MIN_PHASE_BINS: usize = 8;
/// Runs drawn in `random_runs.png` (the first ones of the dataset's non-periodic runs).
pub(crate) const MAX_RANDOM_RUNS: usize = 8;
/// Cells per axis of the force-velocity density.
pub(crate) const DENSITY_BINS: usize = 48;
/// Length of the time traces of a non-periodic run \[s\].
pub(crate) const TRACE_S: f64 = 2.0;

/// One run reduced to a cycle-averaged loop.
#[derive(Debug, Clone, PartialEq)]
pub struct CycleLoop {
    /// Oil loss alpha \[-\].
    pub oil_loss: f64,
    /// Stroke amplitude \[m\] (metadata, else fitted).
    pub amplitude_m: f64,
    /// Excitation frequency \[Hz\].
    pub frequency_hz: f64,
    /// Peak velocity \[m/s\] (metadata, else `2 pi f A`).
    pub peak_velocity_m_s: f64,
    /// Mean displacement per phase bin \[m\], centred on the fitted stroke centre (bin 0
    /// starts at the upward zero crossing).
    pub displacement_m: Vec<f64>,
    /// Mean velocity per phase bin \[m/s\].
    pub velocity_m_s: Vec<f64>,
    /// Mean force per phase bin \[N\].
    pub force_n: Vec<f64>,
    /// Number of periods averaged.
    pub periods: usize,
}

impl CycleLoop {
    /// Number of phase bins.
    pub fn bins(&self) -> usize {
        self.force_n.len()
    }

    /// Phase of the centre of bin `k` \[rad\].
    pub(crate) fn bin_phase(&self, k: usize) -> f64 {
        (k as f64 + 0.5) / self.bins() as f64 * 2.0 * PI
    }
}

impl CycleLoop {
    /// Energy dissipated per cycle \[J\]: the loop integral of F dx (positive for a damper).
    pub fn dissipated_energy_j(&self) -> f64 {
        let n = self.force_n.len();
        (0..n)
            .map(|i| {
                let j = (i + 1) % n;
                0.5 * (self.force_n[i] + self.force_n[j])
                    * (self.displacement_m[j] - self.displacement_m[i])
            })
            .sum()
    }

    /// Area of the loop in the force-velocity plane \[N m/s\] (zero for a memoryless damper:
    /// the hysteresis the figures show).
    pub fn hysteresis_area(&self) -> f64 {
        let n = self.force_n.len();
        0.5 * (0..n)
            .map(|i| {
                let j = (i + 1) % n;
                self.velocity_m_s[i] * self.force_n[j] - self.velocity_m_s[j] * self.force_n[i]
            })
            .sum::<f64>()
            .abs()
    }

    /// Force \[N\] at a phase of the displacement `x = A sin(phase)` (linear interpolation
    /// between the bin centres, periodic).
    pub(crate) fn force_at_phase(&self, phase: f64) -> f64 {
        let n = self.force_n.len();
        let p = phase.rem_euclid(2.0 * PI) / (2.0 * PI) * n as f64 - 0.5;
        let i = p.floor();
        let s = p - i;
        let i = (i as isize).rem_euclid(n as isize) as usize;
        (1.0 - s) * self.force_n[i] + s * self.force_n[(i + 1) % n]
    }

    /// Opening of the loop at zero velocity \[N\]: the force at the upper stroke reversal
    /// (`x = +A`, end of the rebound stroke) minus the force at the lower one (`x = -A`). Zero
    /// for a memoryless damper; positive when the force lags the velocity (compliance), plus
    /// the small gas-spring and friction share.
    pub fn reversal_opening_n(&self) -> f64 {
        self.force_at_phase(0.5 * PI) - self.force_at_phase(1.5 * PI)
    }

    /// Largest cycle-averaged |force| \[N\].
    pub fn peak_force_n(&self) -> f64 {
        self.force_n.iter().fold(0.0f64, |m, f| m.max(f.abs()))
    }

    /// Quasi-static forces as in section 5.3 of the paper: the force of largest magnitude
    /// while |x| < 5 % of the amplitude, in rebound (x rising) and compression (x falling).
    pub fn quasi_static_n(&self) -> (f64, f64) {
        let (mut reb, mut comp) = (0.0f64, 0.0f64);
        for i in 0..self.force_n.len() {
            if self.displacement_m[i].abs() <= 0.05 * self.amplitude_m {
                if self.velocity_m_s[i] > 0.0 {
                    reb = reb.max(self.force_n[i]);
                } else {
                    comp = comp.min(self.force_n[i]);
                }
            }
        }
        (reb, comp)
    }
}

/// Reduces a run to its cycle-averaged loop, with the run's preprocessed `velocity_m_s`
/// (`Signals::velocity_m_s`).
pub fn cycle_loop(run: &Run, velocity_m_s: &[f64]) -> Result<CycleLoop> {
    cycle_loop_of_force(run, velocity_m_s, &run.force_n)
}

/// [`cycle_loop`] of another force over the run's samples (a model's prediction): the
/// periods, phase fit and bins are the run's own, so the loop lines up with the measured
/// one bin for bin.
pub(crate) fn cycle_loop_of_force(
    run: &Run,
    velocity_m_s: &[f64],
    force_n: &[f64],
) -> Result<CycleLoop> {
    let name = run.entry.file.display();
    if force_n.len() != run.len() {
        bail!(
            "run {name}: {} force samples for {} samples",
            force_n.len(),
            run.len()
        );
    }
    if run.len() < 16 {
        bail!("run {name}: too short for a loop ({} samples)", run.len());
    }
    let t_end = run.time_s[run.len() - 1];
    let duration = t_end - run.time_s[0];
    let fs = (run.len() - 1) as f64 / duration;
    let freq = periodicity(run, &run.displacement_m, fs)
        .with_context(|| format!("run {name}: no periodic displacement found"))?
        .frequency_hz;
    let periods = ((0.6 * duration * freq).floor() as usize).max(1);
    let t_start = t_end - periods as f64 / freq;
    if t_start < run.time_s[0] - 1e-9 {
        bail!("run {name}: shorter than one period of {freq:.3} Hz");
    }
    let i0 = run.time_s.partition_point(|&t| t < t_start);
    let t = &run.time_s[i0..];
    let x = &run.displacement_m[i0..];
    if velocity_m_s.len() != run.len() {
        bail!(
            "run {name}: {} velocity samples for {} samples",
            velocity_m_s.len(),
            run.len()
        );
    }
    let w = 2.0 * PI * freq;
    let Some(fit) = SineFit::of(t, x, w) else {
        bail!("run {name}: cannot fit the excitation phase");
    };
    let per_period = t.len() as f64 / periods as f64;
    let v = &velocity_m_s[i0..];
    let f = &force_n[i0..];
    let Some(bins) = PhaseBins::of(t, x, v, f, &fit, per_period) else {
        bail!(
            "run {name}: {per_period:.0} samples per period are too few for \
             {MIN_PHASE_BINS} phase bins"
        );
    };
    // Without metadata the fitted amplitude, rounded to 1 mm so that runs group into rows.
    let amp_fit = fit.amplitude;
    let amplitude_m = run
        .entry
        .amplitude_m
        .unwrap_or(((amp_fit * 1e3).round() / 1e3).max(amp_fit.min(1e-3)));
    Ok(CycleLoop {
        oil_loss: run.entry.oil_loss,
        amplitude_m,
        frequency_hz: freq,
        peak_velocity_m_s: run.entry.target_velocity_m_s.unwrap_or(w * amplitude_m),
        displacement_m: bins.displacement_m,
        velocity_m_s: bins.velocity_m_s,
        force_n: bins.force_n,
        periods,
    })
}

/// The least-squares fit `x ~ R sin(w t + theta) + centre` of the displacement at the
/// excitation frequency: the phase reference of a loop.
struct SineFit {
    /// Angular frequency `w` \[rad/s\].
    w: f64,
    /// Phase `theta` \[rad\].
    phase: f64,
    /// Amplitude `R` \[m\].
    amplitude: f64,
    /// Stroke centre \[m\].
    centre: f64,
}

impl SineFit {
    /// The fit to `x(t)` at angular frequency `w`; `None` when the normal equations are
    /// singular.
    fn of(t: &[f64], x: &[f64], w: f64) -> Option<Self> {
        // x ~ a sin(wt) + b cos(wt) + c.
        let (mut sss, mut scc, mut ssc, mut sxs, mut sxc, mut ss, mut sc, mut sx) =
            (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..t.len() {
            let (s, c) = (w * t[i]).sin_cos();
            sss += s * s;
            scc += c * c;
            ssc += s * c;
            sxs += x[i] * s;
            sxc += x[i] * c;
            ss += s;
            sc += c;
            sx += x[i];
        }
        let n = t.len() as f64;
        // Normal equations of the 3-parameter fit, solved by Cramer's rule.
        let m = [[sss, ssc, ss], [ssc, scc, sc], [ss, sc, n]];
        let rhs = [sxs, sxc, sx];
        let det3 = |m: &[[f64; 3]; 3]| {
            m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
                - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
        };
        let det = det3(&m);
        if det.abs() < 1e-300 {
            return None;
        }
        let solve = |k: usize| {
            let mut mk = m;
            for r in 0..3 {
                mk[r][k] = rhs[r];
            }
            det3(&mk) / det
        };
        let (a, b) = (solve(0), solve(1));
        Some(SineFit {
            w,
            phase: b.atan2(a), // x ~ R sin(w t + theta)
            amplitude: a.hypot(b),
            centre: solve(2),
        })
    }

    /// The phase `w t + theta` at time `t`, in `[0, 2 pi)`.
    fn phase_at(&self, t: f64) -> f64 {
        (self.w * t + self.phase).rem_euclid(2.0 * PI)
    }
}

/// Displacement (centred on the fit's centre), velocity and force averaged in phase bins.
struct PhaseBins {
    displacement_m: Vec<f64>,
    velocity_m_s: Vec<f64>,
    force_n: Vec<f64>,
}

impl PhaseBins {
    /// Averages the samples `(t, x, v, f)` over the phase of `fit`, in [`MAX_PHASE_BINS`]
    /// bins or the largest power of two not above `per_period` (samples per period), halved
    /// until every bin holds a sample; `None` when [`MIN_PHASE_BINS`] still leave one empty.
    fn of(
        t: &[f64],
        x: &[f64],
        v: &[f64],
        f: &[f64],
        fit: &SineFit,
        per_period: f64,
    ) -> Option<Self> {
        let mut bins = MAX_PHASE_BINS;
        while bins > MIN_PHASE_BINS && bins as f64 > per_period {
            bins /= 2;
        }
        loop {
            if let Some(averaged) = Self::averaged(bins, t, x, v, f, fit) {
                return Some(averaged);
            }
            if bins <= MIN_PHASE_BINS {
                return None;
            }
            bins /= 2;
        }
    }

    /// The averages in `bins` bins; `None` when a bin holds no sample.
    fn averaged(
        bins: usize,
        t: &[f64],
        x: &[f64],
        v: &[f64],
        f: &[f64],
        fit: &SineFit,
    ) -> Option<Self> {
        let mut sum_x = vec![0.0; bins];
        let mut sum_v = vec![0.0; bins];
        let mut sum_f = vec![0.0; bins];
        let mut count = vec![0usize; bins];
        for i in 0..t.len() {
            let phase = fit.phase_at(t[i]);
            let k = ((phase / (2.0 * PI) * bins as f64) as usize).min(bins - 1);
            sum_x[k] += x[i] - fit.centre;
            sum_v[k] += v[i];
            sum_f[k] += f[i];
            count[k] += 1;
        }
        if count.contains(&0) {
            return None;
        }
        let avg = |s: Vec<f64>| {
            s.iter()
                .zip(&count)
                .map(|(s, &c)| s / c as f64)
                .collect::<Vec<f64>>()
        };
        Some(PhaseBins {
            displacement_m: avg(sum_x),
            velocity_m_s: avg(sum_v),
            force_n: avg(sum_f),
        })
    }
}

pub(crate) fn same(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 * a.abs().max(b.abs()).max(1e-12)
}

pub(crate) fn sorted_unique(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| same(*a, *b));
    v
}

pub(crate) fn frequency_label(f: f64) -> String {
    if f < 1.0 {
        format!("{f:.2} Hz")
    } else {
        format!("{f:.1} Hz")
    }
}

/// Loads a dataset, derives the signals of its runs (default [`SignalConfig`]) and draws its
/// figures into `out`; returns the written files.
pub fn plot_dataset(dir: &Path, out: &Path) -> Result<Plotted> {
    let ds =
        dataset::load(dir).with_context(|| format!("cannot load the dataset {}", dir.display()))?;
    let signals = run_signals(&ds, &SignalConfig::default())
        .context("cannot derive the velocity of the runs")?;
    plot_loaded(&ds, &signals, out)
}

/// What [`plot_loaded`] drew: the written files, and the runs it could not draw with the
/// reason (a run shorter than its period, say), which the figures leave out.
#[derive(Debug, Clone, Default)]
pub struct Plotted {
    /// The figures written.
    pub written: Vec<PathBuf>,
    /// `(run file, reason)` of every run left out.
    pub skipped: Vec<(PathBuf, String)>,
}

/// Draws the figures of a loaded dataset into `out` from its runs' `signals` (in dataset
/// order). A periodic run that cannot be reduced to a loop is left out and listed in
/// [`Plotted::skipped`]; the other runs are drawn.
pub fn plot_loaded(ds: &Dataset, signals: &[Signals], out: &Path) -> Result<Plotted> {
    use rayon::prelude::*;
    if signals.len() != ds.runs.len() {
        bail!("{} signals for {} runs", signals.len(), ds.runs.len());
    }
    if ds.runs.is_empty() {
        bail!("the dataset has no runs");
    }
    let periodic: Vec<bool> = ds
        .runs
        .iter()
        .map(|r| periodicity(r, &r.displacement_m, ds.sample_rate_hz).is_some())
        .collect();
    let reduced: Vec<(PathBuf, Result<CycleLoop>)> = ds
        .runs
        .par_iter()
        .zip(signals)
        .zip(&periodic)
        .filter(|(_, p)| **p)
        .map(|((r, s), _)| (r.entry.file.clone(), cycle_loop(r, &s.velocity_m_s)))
        .collect();
    let mut loops = Vec::new();
    let mut plotted = Plotted::default();
    for (file, l) in reduced {
        match l {
            Ok(l) => loops.push(l),
            Err(e) => plotted.skipped.push((file, format!("{e:#}"))),
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    if !loops.is_empty() {
        plotted.written.extend(plot_loops(ds, &loops, out)?);
    }
    let others: Vec<usize> = (0..ds.runs.len()).filter(|&i| !periodic[i]).collect();
    if !others.is_empty() {
        plotted
            .written
            .push(plot_random(ds, signals, &others, out)?);
    }
    Ok(plotted)
}

/// The force-velocity density and time traces of the non-periodic runs `which` (at most
/// [`MAX_RANDOM_RUNS`]), one row per run: `random_runs.png`.
fn plot_random(ds: &Dataset, signals: &[Signals], which: &[usize], out: &Path) -> Result<PathBuf> {
    let which = &which[..which.len().min(MAX_RANDOM_RUNS)];
    let mut fig = Figure::new(which.len(), 3)
        .with_title(format!(
            "{}: non-periodic runs (force-velocity density, time traces)",
            ds.name
        ))
        .with_panel_size(480, 360);
    for &i in which {
        let run = &ds.runs[i];
        let v = &signals[i].velocity_m_s;
        let f = &run.force_n;
        let name = run.entry.file.display().to_string();
        let range = |x: &[f64]| {
            let (lo, hi) = x
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &y| {
                    (l.min(y), h.max(y))
                });
            if hi > lo {
                (lo, hi)
            } else {
                (lo - 0.5, lo + 0.5)
            }
        };
        let ((v0, v1), (f0, f1)) = (range(v), range(f));
        let n = DENSITY_BINS;
        let mut counts = vec![vec![0.0f64; n]; n];
        for (vi, fi) in v.iter().zip(f) {
            let ix = (((vi - v0) / (v1 - v0) * n as f64) as usize).min(n - 1);
            let iy = (((fi - f0) / (f1 - f0) * n as f64) as usize).min(n - 1);
            counts[iy][ix] += 1.0;
        }
        let z: Vec<Vec<f64>> = counts
            .iter()
            .map(|row| row.iter().map(|c| (1.0 + c).log10()).collect())
            .collect();
        let centres = |lo: f64, hi: f64| {
            (0..n)
                .map(|k| lo + (k as f64 + 0.5) / n as f64 * (hi - lo))
                .collect()
        };
        let levels = match &run.alpha {
            Some(a) => {
                let (lo, hi) = range(a);
                format!(
                    "alpha {}-{} (column)",
                    alpha_text(lo),
                    alpha_text(hi.min(1.0))
                )
            }
            None => ds
                .condition
                .clone()
                .unwrap_or_default()
                .level(run.entry.oil_loss),
        };
        fig = fig.with_panel(
            HeatmapPanel::new(
                format!("{name}: {levels}"),
                "velocity [m/s]",
                "force [N]",
                centres(v0, v1),
                centres(f0, f1),
                z,
            )
            .with_z_label("log10(1 + samples)"),
        );
        let end = run.time_s[0] + TRACE_S;
        let k = run.time_s.partition_point(|&t| t <= end);
        let trace = |y: &[f64]| -> Vec<(f64, f64)> {
            run.time_s[..k]
                .iter()
                .zip(&y[..k])
                .map(|(&t, &y)| (t, y))
                .collect()
        };
        fig = fig.with_panel(
            LinePanel::new(format!("{name}: force"), "time [s]", "force [N]")
                .with_series(Series::line("force", trace(f), palette::categorical(0)).unlabelled())
                .with_legend(LegendPosition::None),
        );
        fig = fig.with_panel(
            LinePanel::new(format!("{name}: velocity"), "time [s]", "velocity [m/s]")
                .with_series(
                    Series::line("velocity", trace(v), palette::categorical(1)).unlabelled(),
                )
                .with_zero_lines()
                .with_legend(LegendPosition::None),
        );
    }
    let path = out.join("random_runs.png");
    fig.save_png(&path)?;
    Ok(path)
}

/// Fig. 4, Fig. 5 and the quasi-static figure of the periodic runs' loops.
fn plot_loops(ds: &Dataset, loops: &[CycleLoop], out: &Path) -> Result<Vec<PathBuf>> {
    let levels = LoopLevels::of(loops);
    let mut written = vec![save(
        fig4_loops(ds, loops, &levels),
        out,
        "force_velocity_loops.png",
    )?];
    if let Some(fig) = fig5_difference_loops(ds, loops, &levels) {
        written.push(save(fig, out, "difference_loops.png")?);
    }
    written.push(save(
        quasi_static_figure(ds, loops, &levels),
        out,
        "quasi_static.png",
    )?);
    Ok(written)
}

/// Writes `fig` as `out/name`; returns the path.
fn save(fig: Figure, out: &Path, name: &str) -> Result<PathBuf> {
    let path = out.join(name);
    fig.save_png(&path)?;
    Ok(path)
}

/// The grid of the loop figures and their common scales.
struct LoopLevels {
    /// Largest cycle-averaged |force| of the dataset \[N\]: the force normalisation.
    f_max: f64,
    /// Oil-loss levels, ascending (figure columns).
    alphas: Vec<f64>,
    /// Amplitudes, descending as in the paper (figure rows).
    amps: Vec<f64>,
    /// Half-width of the velocity axes \[m/s\].
    v_lim: f64,
}

impl LoopLevels {
    fn of(loops: &[CycleLoop]) -> Self {
        let f_max = loops
            .iter()
            .flat_map(|l| l.force_n.iter())
            .fold(0.0f64, |m, f| m.max(f.abs()))
            .max(1e-9);
        let alphas = sorted_unique(loops.iter().map(|l| l.oil_loss).collect());
        let mut amps = sorted_unique(loops.iter().map(|l| l.amplitude_m).collect());
        amps.reverse(); // 50 mm first, as in the paper
        let v_lim = loops
            .iter()
            .flat_map(|l| l.velocity_m_s.iter())
            .fold(0.0f64, |m, v| m.max(v.abs()))
            * 1.05;
        LoopLevels {
            f_max,
            alphas,
            amps,
            v_lim,
        }
    }
}

/// The loops at amplitude `amp` and oil loss `alpha`.
fn loops_at(loops: &[CycleLoop], amp: f64, alpha: f64) -> Vec<&CycleLoop> {
    loops
        .iter()
        .filter(|l| same(l.amplitude_m, amp) && same(l.oil_loss, alpha))
        .collect()
}

/// An empty panel of the loops at level `alpha` of the dataset's condition and amplitude
/// `amp` over velocity, with zero lines; the paper's oil loss is titled in percent.
fn level_panel(ds: &Dataset, alpha: f64, amp: f64, y_label: &str) -> LinePanel {
    let condition = ds.condition.clone().unwrap_or_default();
    let level = if condition == ConditionSpec::default() {
        format!("oil loss {:.0} %", alpha * 100.0)
    } else {
        condition.level(alpha)
    };
    LinePanel::new(
        format!("{level}, amplitude {:.0} mm", amp * 1000.0),
        "velocity [m/s]",
        y_label,
    )
    .with_zero_lines()
    .with_legend(LegendPosition::UpperLeft)
}

/// Fig. 4: rows = amplitude, columns = oil loss, one normalised loop per frequency.
fn fig4_loops(ds: &Dataset, loops: &[CycleLoop], levels: &LoopLevels) -> Figure {
    let (f_max, v_lim, fn_lim) = (levels.f_max, levels.v_lim, 1.05);
    let mut fig = Figure::new(levels.amps.len(), levels.alphas.len())
        .with_title(format!(
            "{}: normalised force-velocity loops (F / {:.0} N)",
            ds.name, f_max
        ))
        .with_panel_size(520, 400);
    for &amp in &levels.amps {
        for &alpha in &levels.alphas {
            let mut sel = loops_at(loops, amp, alpha);
            sel.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
            let colors = palette::sequence(sel.len());
            let mut panel = level_panel(ds, alpha, amp, "normalised force [-]")
                .with_x_range(-v_lim, v_lim)
                .with_y_range(-fn_lim, fn_lim);
            for (l, c) in sel.iter().zip(colors) {
                let pts = l
                    .velocity_m_s
                    .iter()
                    .zip(&l.force_n)
                    .map(|(&v, &f)| (v, f / f_max))
                    .collect();
                panel = panel.with_series(Series::closed(frequency_label(l.frequency_hz), pts, c));
            }
            fig = fig.with_panel(panel);
        }
    }
    fig
}

/// Fig. 5: `F_norm,0% - F_norm,loss` over the 0 % velocity, per amplitude and oil loss above
/// 0 (each lossy loop against the 0 % loop of the same amplitude and peak velocity); `None`
/// without a 0 % level or a lossy one.
fn fig5_difference_loops(ds: &Dataset, loops: &[CycleLoop], levels: &LoopLevels) -> Option<Figure> {
    let a0 = levels.alphas.iter().copied().find(|a| *a == 0.0)?;
    let lossy: Vec<f64> = levels.alphas.iter().copied().filter(|a| *a > 0.0).collect();
    if lossy.is_empty() {
        return None;
    }
    let mut fig = Figure::new(levels.amps.len(), lossy.len())
        .with_title(format!(
            "{}: difference loops F_norm,0% - F_norm,loss",
            ds.name
        ))
        .with_panel_size(520, 400);
    let mut d_lim: f64 = 0.0;
    let mut panels = Vec::new();
    for &amp in &levels.amps {
        for &alpha in &lossy {
            let mut sel: Vec<(&CycleLoop, &CycleLoop)> = loops_at(loops, amp, alpha)
                .into_iter()
                .filter_map(|l| {
                    loops
                        .iter()
                        .find(|b| {
                            same(b.oil_loss, a0)
                                && same(b.amplitude_m, amp)
                                && same(b.peak_velocity_m_s, l.peak_velocity_m_s)
                        })
                        .map(|b| (b, l))
                })
                .collect();
            sel.sort_by(|a, b| a.1.frequency_hz.total_cmp(&b.1.frequency_hz));
            let colors = palette::sequence(sel.len());
            let mut panel = level_panel(ds, alpha, amp, "F_norm,0% - F_norm,loss [-]");
            for ((b, l), c) in sel.iter().zip(colors) {
                let pts: Vec<(f64, f64)> = (0..b.bins())
                    .map(|k| {
                        let df = b.force_n[k] - l.force_at_phase(b.bin_phase(k));
                        (b.velocity_m_s[k], df / levels.f_max)
                    })
                    .collect();
                d_lim = pts.iter().fold(d_lim, |m, p| m.max(p.1.abs()));
                panel = panel.with_series(Series::closed(frequency_label(l.frequency_hz), pts, c));
            }
            panels.push(panel.with_x_range(-levels.v_lim, levels.v_lim));
        }
    }
    let d_lim = (d_lim * 1.1).max(1e-3);
    for p in panels {
        fig = fig.with_panel(p.with_y_range(-d_lim, d_lim));
    }
    Some(fig)
}

/// The quasi-static characteristic (section 5.3 method), the energy dissipated per cycle and
/// the hysteresis, one line per oil loss and amplitude.
fn quasi_static_figure(ds: &Dataset, loops: &[CycleLoop], levels: &LoopLevels) -> Figure {
    let mut panel = LinePanel::new(
        "max |F| within |x| < 5 % of the amplitude",
        "peak velocity [m/s] (negative = compression)",
        "force [N]",
    )
    .with_zero_lines()
    .with_legend(LegendPosition::UpperLeft);
    let mut panel_energy = LinePanel::new(
        "energy dissipated per cycle",
        "peak velocity [m/s]",
        "energy [J]",
    )
    .with_legend(LegendPosition::UpperLeft);
    let mut panel_area = LinePanel::new(
        "hysteresis: loop area in the force-velocity plane",
        "peak velocity [m/s]",
        "area / (F_max v_max) [-]",
    )
    .with_legend(LegendPosition::UpperLeft);
    let v_max = loops
        .iter()
        .map(|l| l.peak_velocity_m_s)
        .fold(0.0f64, f64::max)
        .max(1e-9);
    let mut idx = 0;
    for &alpha in &levels.alphas {
        for &amp in &levels.amps {
            let mut sel = loops_at(loops, amp, alpha);
            sel.sort_by(|a, b| a.peak_velocity_m_s.total_cmp(&b.peak_velocity_m_s));
            let label = format!("{:.0} %, {:.0} mm", alpha * 100.0, amp * 1000.0);
            let c = palette::categorical(idx);
            idx += 1;
            panel = panel.with_series(Series::line(label.clone(), quasi_static_curve(&sel), c));
            let e: Vec<(f64, f64)> = sel
                .iter()
                .map(|l| (l.peak_velocity_m_s, l.dissipated_energy_j()))
                .collect();
            panel_energy = panel_energy.with_series(Series::line(label.clone(), e, c));
            let a: Vec<(f64, f64)> = sel
                .iter()
                .map(|l| {
                    (
                        l.peak_velocity_m_s,
                        l.hysteresis_area() / (levels.f_max * v_max),
                    )
                })
                .collect();
            panel_area = panel_area.with_series(Series::line(label, a, c));
        }
    }
    Figure::new(1, 3)
        .with_title(format!(
            "{}: quasi-static characteristic, dissipation, hysteresis",
            ds.name
        ))
        .with_panel_size(600, 480)
        .with_panel(panel)
        .with_panel(panel_energy)
        .with_panel(panel_area)
}

/// Quasi-static forces over peak velocity of loops sorted by peak velocity: compression at
/// negative velocities, the origin, rebound at positive ones.
fn quasi_static_curve(sel: &[&CycleLoop]) -> Vec<(f64, f64)> {
    let mut pts: Vec<(f64, f64)> = Vec::new();
    for l in sel.iter().rev() {
        pts.push((-l.peak_velocity_m_s, l.quasi_static_n().1));
    }
    pts.push((0.0, 0.0));
    for l in sel {
        pts.push((l.peak_velocity_m_s, l.quasi_static_n().0));
    }
    pts
}
