//! `nemm bench plot`: force-velocity loops (like Fig. 4 of the paper), difference loops
//! against 0 % oil loss (like Fig. 5) and the quasi-static characteristic of any dataset in the
//! interchange format (virtual or real bench).
//!
//! Each run is reduced to one cycle-averaged loop: the last full periods (at least one, up to
//! 60 % of the run) are folded onto the phase of the displacement (a least-squares sine fit at
//! the excitation frequency), and velocity and force are averaged in 256 phase bins. The
//! velocity is the one the trainer sees, derived once per run by the preprocessing
//! ([`crate::data::preprocess::run_signals`]: zero-phase low-pass of the displacement and
//! central difference, or the measured column). Averaging
//! over periods removes the sensor noise without the phase lag of a filter. Forces are
//! normalised by the largest cycle-averaged |force| of the dataset, as in the paper's figures.

use crate::data::dataset::{self, Dataset, Run};
use crate::data::preprocess::{run_signals, SignalConfig, Signals};
use crate::report::plot::{palette, Figure, LegendPosition, LinePanel, Series};
use anyhow::{bail, Context, Result};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

/// Number of phase bins of a cycle-averaged loop.
pub const PHASE_BINS: usize = 256;

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
    /// Mean displacement per phase bin \[m\] (bin 0 starts at the upward zero crossing).
    pub displacement_m: Vec<f64>,
    /// Mean velocity per phase bin \[m/s\].
    pub velocity_m_s: Vec<f64>,
    /// Mean force per phase bin \[N\].
    pub force_n: Vec<f64>,
    /// Number of periods averaged.
    pub periods: usize,
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
    pub fn force_at_phase(&self, phase: f64) -> f64 {
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

    /// Widths of the loop at half the peak velocity \[N\], `(rebound, compression)`: the force
    /// while the speed falls minus the force while it rises, on each side (positive when
    /// the force lags the velocity, negative when it leads, e.g. from a lagging valve).
    pub fn half_velocity_widths_n(&self) -> (f64, f64) {
        let f = |deg: f64| self.force_at_phase(deg.to_radians());
        (f(60.0) - f(300.0), f(120.0) - f(240.0))
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

/// Estimates the excitation frequency from the upward mean crossings of the displacement.
fn estimate_frequency(run: &Run) -> Option<f64> {
    let x = &run.displacement_m;
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let ups: Vec<f64> = (1..x.len())
        .filter(|&i| x[i - 1] < mean && x[i] >= mean)
        .map(|i| run.time_s[i])
        .collect();
    // Ignore chatter from noise: require crossings at least 5 samples apart.
    let dt = run
        .time_s
        .get(1)
        .map(|t1| t1 - run.time_s[0])
        .unwrap_or(1.0);
    let clean: Vec<f64> = ups
        .windows(2)
        .filter(|w| w[1] - w[0] > 5.0 * dt)
        .map(|w| w[1] - w[0])
        .collect();
    if clean.len() < 2 {
        return None;
    }
    let mut periods = clean;
    periods.sort_by(f64::total_cmp);
    Some(1.0 / periods[periods.len() / 2])
}

/// Reduces a run to its cycle-averaged loop, with the run's preprocessed `velocity_m_s`
/// ([`Signals::velocity_m_s`]).
pub fn cycle_loop(run: &Run, velocity_m_s: &[f64]) -> Result<CycleLoop> {
    let name = run.entry.file.display();
    if run.len() < 16 {
        bail!("run {name}: too short for a loop ({} samples)", run.len());
    }
    let freq = match (run.entry.amplitude_m, run.entry.target_velocity_m_s) {
        (Some(a), Some(v)) if a > 0.0 && v > 0.0 => v / (2.0 * PI * a),
        _ => estimate_frequency(run)
            .with_context(|| format!("run {name}: no periodic displacement found"))?,
    };
    let t_end = run.time_s[run.len() - 1];
    let duration = t_end - run.time_s[0];
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
    let v = &velocity_m_s[i0..];
    let f = &run.force_n[i0..];
    // Least-squares fit x ~ a sin(wt) + b cos(wt) + c: phase reference.
    let w = 2.0 * PI * freq;
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
        bail!("run {name}: cannot fit the excitation phase");
    }
    let solve = |k: usize| {
        let mut mk = m;
        for r in 0..3 {
            mk[r][k] = rhs[r];
        }
        det3(&mk) / det
    };
    let (a, b) = (solve(0), solve(1));
    let theta = b.atan2(a); // x ~ R sin(w t + theta)
    let amp_fit = a.hypot(b);
    let mut sum_x = vec![0.0; PHASE_BINS];
    let mut sum_v = vec![0.0; PHASE_BINS];
    let mut sum_f = vec![0.0; PHASE_BINS];
    let mut count = vec![0usize; PHASE_BINS];
    for i in 0..t.len() {
        let phase = (w * t[i] + theta).rem_euclid(2.0 * PI);
        let k = ((phase / (2.0 * PI) * PHASE_BINS as f64) as usize).min(PHASE_BINS - 1);
        sum_x[k] += x[i];
        sum_v[k] += v[i];
        sum_f[k] += f[i];
        count[k] += 1;
    }
    if count.contains(&0) {
        bail!(
            "run {name}: {} samples per period are too few for {PHASE_BINS} phase bins",
            (t.len() / periods)
        );
    }
    let avg = |s: Vec<f64>| {
        s.iter()
            .zip(&count)
            .map(|(s, &c)| s / c as f64)
            .collect::<Vec<f64>>()
    };
    let amplitude_m = run.entry.amplitude_m.unwrap_or(amp_fit);
    Ok(CycleLoop {
        oil_loss: run.entry.oil_loss,
        amplitude_m,
        frequency_hz: freq,
        peak_velocity_m_s: run.entry.target_velocity_m_s.unwrap_or(w * amplitude_m),
        displacement_m: avg(sum_x),
        velocity_m_s: avg(sum_v),
        force_n: avg(sum_f),
        periods,
    })
}

fn same(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 * a.abs().max(b.abs()).max(1e-12)
}

fn sorted_unique(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| same(*a, *b));
    v
}

fn frequency_label(f: f64) -> String {
    if f < 1.0 {
        format!("{f:.2} Hz")
    } else {
        format!("{f:.1} Hz")
    }
}

/// Loads a dataset, derives the signals of its runs (default [`SignalConfig`]) and draws its
/// figures into `out`; returns the written files.
pub fn plot_dataset(dir: &Path, out: &Path) -> Result<Vec<PathBuf>> {
    let ds =
        dataset::load(dir).with_context(|| format!("cannot load the dataset {}", dir.display()))?;
    let signals = run_signals(&ds, &SignalConfig::default())
        .context("cannot derive the velocity of the runs")?;
    plot_loaded(&ds, &signals, out)
}

/// Draws the figures of a loaded dataset into `out` from its runs' `signals` (in dataset
/// order); returns the written files.
pub fn plot_loaded(ds: &Dataset, signals: &[Signals], out: &Path) -> Result<Vec<PathBuf>> {
    use rayon::prelude::*;
    if signals.len() != ds.runs.len() {
        bail!("{} signals for {} runs", signals.len(), ds.runs.len());
    }
    let loops: Vec<CycleLoop> = ds
        .runs
        .par_iter()
        .zip(signals)
        .map(|(r, s)| cycle_loop(r, &s.velocity_m_s))
        .collect::<Result<_>>()?;
    if loops.is_empty() {
        bail!("the dataset has no runs");
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let f_max = loops
        .iter()
        .flat_map(|l| l.force_n.iter())
        .fold(0.0f64, |m, f| m.max(f.abs()))
        .max(1e-9);
    let alphas = sorted_unique(loops.iter().map(|l| l.oil_loss).collect());
    let mut amps = sorted_unique(loops.iter().map(|l| l.amplitude_m).collect());
    amps.reverse(); // 50 mm first, as in the paper
    let mut written = Vec::new();

    // Fig. 4: rows = amplitude, columns = oil loss, one curve per frequency.
    let mut fig = Figure::new(amps.len(), alphas.len())
        .with_title(format!(
            "{}: normalised force-velocity loops (F / {:.0} N)",
            ds.name, f_max
        ))
        .with_panel_size(520, 400);
    let (v_lim, fn_lim) = (
        loops
            .iter()
            .flat_map(|l| l.velocity_m_s.iter())
            .fold(0.0f64, |m, v| m.max(v.abs()))
            * 1.05,
        1.05,
    );
    for &amp in &amps {
        for &alpha in &alphas {
            let mut sel: Vec<&CycleLoop> = loops
                .iter()
                .filter(|l| same(l.amplitude_m, amp) && same(l.oil_loss, alpha))
                .collect();
            sel.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
            let colors = palette::sequence(sel.len());
            let mut panel = LinePanel::new(
                format!(
                    "oil loss {:.0} %, amplitude {:.0} mm",
                    alpha * 100.0,
                    amp * 1000.0
                ),
                "velocity [m/s]",
                "normalised force [-]",
            )
            .with_x_range(-v_lim, v_lim)
            .with_y_range(-fn_lim, fn_lim)
            .with_zero_lines()
            .with_legend(LegendPosition::UpperLeft);
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
    let path = out.join("force_velocity_loops.png");
    fig.save_png(&path)?;
    written.push(path);

    // Fig. 5: F_norm,0% - F_norm,loss over the 0 % velocity, per amplitude and oil loss > 0.
    let base = alphas.iter().copied().find(|a| *a == 0.0);
    let lossy: Vec<f64> = alphas.iter().copied().filter(|a| *a > 0.0).collect();
    if let (Some(a0), false) = (base, lossy.is_empty()) {
        let mut fig = Figure::new(amps.len(), lossy.len())
            .with_title(format!(
                "{}: difference loops F_norm,0% - F_norm,loss",
                ds.name
            ))
            .with_panel_size(520, 400);
        let mut d_lim: f64 = 0.0;
        let mut panels = Vec::new();
        for &amp in &amps {
            for &alpha in &lossy {
                let mut sel: Vec<(&CycleLoop, &CycleLoop)> = loops
                    .iter()
                    .filter(|l| same(l.amplitude_m, amp) && same(l.oil_loss, alpha))
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
                let mut panel = LinePanel::new(
                    format!(
                        "oil loss {:.0} %, amplitude {:.0} mm",
                        alpha * 100.0,
                        amp * 1000.0
                    ),
                    "velocity [m/s]",
                    "F_norm,0% - F_norm,loss [-]",
                )
                .with_zero_lines()
                .with_legend(LegendPosition::UpperLeft);
                for ((b, l), c) in sel.iter().zip(colors) {
                    let pts: Vec<(f64, f64)> = (0..PHASE_BINS)
                        .map(|k| (b.velocity_m_s[k], (b.force_n[k] - l.force_n[k]) / f_max))
                        .collect();
                    d_lim = pts.iter().fold(d_lim, |m, p| m.max(p.1.abs()));
                    panel =
                        panel.with_series(Series::closed(frequency_label(l.frequency_hz), pts, c));
                }
                panels.push(panel.with_x_range(-v_lim, v_lim));
            }
        }
        let d_lim = (d_lim * 1.1).max(1e-3);
        for p in panels {
            fig = fig.with_panel(p.with_y_range(-d_lim, d_lim));
        }
        let path = out.join("difference_loops.png");
        fig.save_png(&path)?;
        written.push(path);
    }

    // Quasi-static characteristic (section 5.3 method), one line per oil loss and amplitude.
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
    for &alpha in &alphas {
        for &amp in &amps {
            let mut sel: Vec<&CycleLoop> = loops
                .iter()
                .filter(|l| same(l.amplitude_m, amp) && same(l.oil_loss, alpha))
                .collect();
            sel.sort_by(|a, b| a.peak_velocity_m_s.total_cmp(&b.peak_velocity_m_s));
            let mut pts: Vec<(f64, f64)> = Vec::new();
            for l in sel.iter().rev() {
                pts.push((-l.peak_velocity_m_s, l.quasi_static_n().1));
            }
            pts.push((0.0, 0.0));
            for l in &sel {
                pts.push((l.peak_velocity_m_s, l.quasi_static_n().0));
            }
            let label = format!("{:.0} %, {:.0} mm", alpha * 100.0, amp * 1000.0);
            let c = palette::categorical(idx);
            idx += 1;
            panel = panel.with_series(Series::line(label.clone(), pts, c));
            let e: Vec<(f64, f64)> = sel
                .iter()
                .map(|l| (l.peak_velocity_m_s, l.dissipated_energy_j()))
                .collect();
            panel_energy = panel_energy.with_series(Series::line(label.clone(), e, c));
            let a: Vec<(f64, f64)> = sel
                .iter()
                .map(|l| (l.peak_velocity_m_s, l.hysteresis_area() / (f_max * v_max)))
                .collect();
            panel_area = panel_area.with_series(Series::line(label, a, c));
        }
    }
    let fig = Figure::new(1, 3)
        .with_title(format!(
            "{}: quasi-static characteristic, dissipation, hysteresis",
            ds.name
        ))
        .with_panel_size(600, 480)
        .with_panel(panel)
        .with_panel(panel_energy)
        .with_panel(panel_area);
    let path = out.join("quasi_static.png");
    fig.save_png(&path)?;
    written.push(path);
    Ok(written)
}
