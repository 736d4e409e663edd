//! The identifiability report (`identify.md`, the `identify` key of `report.json`,
//! `identify.json`): per model and run, the best-fit level of [`crate::train::identify`]
//! against the label, a summary per level, and the whole-run force error per level and per
//! excitation condition (amplitude, frequency), training levels included.

use crate::data::preprocess::{distinct_levels, Prepared, RunRole, ALPHA_TOLERANCE};
use crate::train::identify::{identify_runs, AlphaGrid, Fit, Run, Search, FLAT_TOLERANCE};
use crate::train::pipeline::VariantInfo;
use anyhow::{Context, Result};
use nemm_core::ModelKind;
use nemm_dataset::{alpha_text, ConditionSpec, Dataset};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Instant;

/// A best fit within this distance of the label counts as reading the level back.
pub(crate) const WITHIN: f64 = 0.03;

/// One run of an [`IdentifyReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunInfo {
    /// Run index in the dataset.
    pub index: usize,
    /// Run file, relative to the manifest.
    pub file: String,
    /// The run's labelled level.
    pub alpha: f64,
    /// What the split uses the run for.
    pub role: RunRole,
    /// Stroke amplitude \[m\] (estimated from the run).
    pub amplitude_m: f64,
    /// Excitation frequency \[Hz\] (estimated; absent without two zero crossings).
    pub frequency_hz: Option<f64>,
    /// Peak stroke velocity \[m/s\] (estimated).
    pub peak_velocity_m_s: f64,
    /// The excitation condition the run belongs to across levels: the manifest's amplitude
    /// and target velocity where given, else the estimated amplitude and frequency.
    pub condition: String,
    /// `true` if the run has a level per sample (its label RMSE uses it).
    #[serde(default)]
    pub(crate) level_column: bool,
}

/// Per level, over one model's fits of the level's runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelSummary {
    /// The level.
    pub alpha: f64,
    /// `test`, `train` or `mixed` (the roles of the level's runs).
    pub role: String,
    /// Runs at the level.
    pub runs: usize,
    /// Runs whose best fit is within [`IdentifyReport::within`] of the label.
    pub within: usize,
    /// Runs whose RMSE curve is flat (no best fit).
    pub flat: usize,
    /// Whole-run RMSE at the label over the level's runs (pooled by samples), normalised by
    /// [`IdentifyReport::force_scale_n`].
    pub rmse: f64,
    /// The same \[N\].
    pub rmse_n: f64,
}

/// Whether the best fit orders the lowest and the highest level of each excitation
/// condition present at both.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OrderCheck {
    /// Lowest level.
    pub low: f64,
    /// Highest level.
    pub high: f64,
    /// Conditions with a run at both levels.
    pub conditions: usize,
    /// Conditions whose best fit at `low` is strictly below that at `high`.
    pub ordered: usize,
    /// `true` if every condition is ordered (and there is at least one).
    pub holds: bool,
    /// The conditions that are not ordered.
    #[serde(default)]
    pub(crate) unordered: Vec<String>,
}

/// One model's fits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VariantFits {
    /// The grid of levels.
    pub grid: Vec<f64>,
    /// One fit per run of [`IdentifyReport::runs`], in that order.
    pub fits: Vec<Fit>,
    /// Per level, ascending.
    pub levels: Vec<LevelSummary>,
    /// Lowest against highest level per condition (absent with fewer than two levels).
    pub order: Option<OrderCheck>,
    /// Wall time of the fits \[s\].
    pub seconds: f64,
}

/// The identifiability report of one or more models on a dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IdentifyReport {
    /// Grid step in alpha.
    pub step: f64,
    /// Which grid levels were simulated (`Search::unnamed` when absent).
    #[serde(default = "Search::unnamed")]
    pub search: Search,
    /// [`FLAT_TOLERANCE`].
    pub(crate) flat_tolerance: f64,
    /// `WITHIN`.
    pub within: f64,
    /// Force scale of the normalised RMSE \[N\] (Table 4's).
    pub force_scale_n: f64,
    /// Warm-up samples at the start of each run, simulated but not scored.
    pub warmup_samples: usize,
    /// What `alpha` stands for.
    #[serde(default)]
    pub condition: ConditionSpec,
    /// The runs.
    pub runs: Vec<RunInfo>,
    /// Per model, keyed as in [`crate::report::tables::Report::variants`].
    pub variants: BTreeMap<String, VariantFits>,
}

/// The excitation condition of run `i` of `prepared` ([`RunInfo::condition`]).
fn condition_of(prepared: &Prepared, i: usize) -> String {
    let s = &prepared.runs[i].summary;
    match (s.manifest_amplitude_m, s.manifest_target_velocity_m_s) {
        (Some(a), Some(v)) => format!("{:.0} mm, {v:.3} m/s", a * 1e3),
        _ => format!(
            "{:.0} mm, {}",
            s.excitation.amplitude_m * 1e3,
            s.excitation
                .frequency_hz
                .map_or("-".into(), |f| format!("{f:.1} Hz"))
        ),
    }
}

/// The runs of `prepared` an identification covers by default: every run the split uses.
pub fn used_runs(prepared: &Prepared) -> Vec<usize> {
    prepared
        .runs
        .iter()
        .filter(|r| r.role != RunRole::Unused)
        .map(|r| r.summary.index)
        .collect()
}

/// Identifies runs `runs` (dataset indices) of `ds` with each model of `models`, on the
/// preprocessed velocity and position of `prepared` and the force the trainer scores (raw,
/// or low-passed with `filter_force`), each model on its [`AlphaGrid::for_model`] grid of
/// step `step` searched by `search`; normalises by `force_scale_n`.
pub fn identify_report(
    models: &[(ModelKind, &nemm_core::Model)],
    ds: &Dataset,
    prepared: &Prepared,
    runs: &[usize],
    step: f64,
    search: Search,
    force_scale_n: f64,
) -> Result<IdentifyReport> {
    let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    struct Signals {
        velocity: Vec<f32>,
        position: Vec<f32>,
        alphas: Option<Vec<f32>>,
    }
    let mut infos = Vec::with_capacity(runs.len());
    let mut signals = Vec::with_capacity(runs.len());
    for &i in runs {
        let sig = prepared
            .signals
            .get(i)
            .with_context(|| format!("run {i} is not in the prepared set"))?;
        let run = &prepared.runs[i];
        infos.push(RunInfo {
            index: i,
            file: run.summary.file.display().to_string(),
            alpha: run.summary.alpha,
            role: run.role,
            amplitude_m: run.summary.excitation.amplitude_m,
            frequency_hz: run.summary.excitation.frequency_hz,
            peak_velocity_m_s: run.summary.excitation.peak_velocity_m_s,
            condition: condition_of(prepared, i),
            level_column: sig.alpha.is_some(),
        });
        signals.push(Signals {
            velocity: f32s(&sig.velocity_m_s),
            position: f32s(&sig.displacement_m),
            alphas: sig.alpha.as_deref().map(f32s),
        });
    }
    let inputs: Vec<Run<'_>> = runs
        .iter()
        .zip(&signals)
        .zip(&infos)
        .map(|((&i, s), info)| Run {
            velocity_m_s: &s.velocity,
            position_m: Some(&s.position),
            force_n: if prepared.config.signal.filter_force {
                &prepared.signals[i].force_filtered_n
            } else {
                &ds.runs[i].force_n
            },
            label: info.alpha,
            label_alphas: s.alphas.as_deref(),
        })
        .collect();
    let mut variants = BTreeMap::new();
    for &(v, model) in models {
        let t = Instant::now();
        let grid = AlphaGrid::for_model(model, step)?;
        let fits = identify_runs(
            model,
            &inputs,
            &grid,
            prepared.dt_s,
            prepared.warmup_samples,
            search,
        )
        .with_context(|| format!("cannot identify with the {}", v.title()))?;
        let seconds = t.elapsed().as_secs_f64();
        eprintln!(
            "identify ({}): {} runs, grid of {} levels ({}, {} simulated) in {seconds:.1} s",
            v.title(),
            fits.len(),
            grid.alphas.len(),
            search.name(),
            fits.iter().map(|f| f.levels.len()).sum::<usize>()
        );
        let levels = level_summaries(&infos, &fits, force_scale_n);
        let order = order_check(&infos, &fits);
        variants.insert(
            v.key().to_string(),
            VariantFits {
                grid: grid.alphas,
                fits,
                levels,
                order,
                seconds,
            },
        );
    }
    Ok(IdentifyReport {
        step,
        search,
        flat_tolerance: FLAT_TOLERANCE,
        within: WITHIN,
        force_scale_n,
        warmup_samples: prepared.warmup_samples,
        condition: ConditionSpec::from_core(&prepared.condition),
        runs: infos,
        variants,
    })
}

/// `true` if `a` and `b` are one level.
fn same_level(a: f64, b: f64) -> bool {
    (a - b).abs() <= ALPHA_TOLERANCE
}

fn role_name(role: RunRole) -> &'static str {
    match role {
        RunRole::TrainValidation => "train",
        RunRole::Test => "test",
        RunRole::Unused => "unused",
    }
}

/// Per level: runs, best fits within [`WITHIN`], flat curves, pooled whole-run RMSE.
fn level_summaries(infos: &[RunInfo], fits: &[Fit], force_scale_n: f64) -> Vec<LevelSummary> {
    distinct_levels(infos.iter().map(|r| r.alpha))
        .into_iter()
        .map(|alpha| {
            let at: Vec<(&RunInfo, &Fit)> = infos
                .iter()
                .zip(fits)
                .filter(|(r, _)| same_level(r.alpha, alpha))
                .collect();
            let mut roles: Vec<&str> = at.iter().map(|(r, _)| role_name(r.role)).collect();
            roles.sort_unstable();
            roles.dedup();
            let role = if roles.len() == 1 { roles[0] } else { "mixed" };
            let (se, n) = at.iter().fold((0.0, 0), |(se, n), (_, f)| {
                (
                    se + f.rmse_label_n.powi(2) * f.samples as f64,
                    n + f.samples,
                )
            });
            let rmse_n = crate::train::eval::rmse_of(se, n);
            LevelSummary {
                alpha,
                role: role.to_string(),
                runs: at.len(),
                within: at.iter().filter(|(_, f)| f.within(WITHIN)).count(),
                flat: at.iter().filter(|(_, f)| f.best.is_none()).count(),
                rmse: rmse_n / force_scale_n,
                rmse_n,
            }
        })
        .collect()
}

/// The lowest level's best fit against the highest's, per condition present at both.
fn order_check(infos: &[RunInfo], fits: &[Fit]) -> Option<OrderCheck> {
    let levels = distinct_levels(infos.iter().map(|r| r.alpha));
    let (&low, &high) = (levels.first()?, levels.last()?);
    if levels.len() < 2 {
        return None;
    }
    let at = |level: f64, condition: &str| {
        infos
            .iter()
            .zip(fits)
            .find(|(r, _)| same_level(r.alpha, level) && r.condition == condition)
            .map(|(_, f)| f.best)
    };
    let mut conditions: Vec<&str> = infos.iter().map(|r| r.condition.as_str()).collect();
    conditions.sort_unstable();
    conditions.dedup();
    let (mut count, mut ordered, mut unordered) = (0, 0, Vec::new());
    for c in conditions {
        if let (Some(lo), Some(hi)) = (at(low, c), at(high, c)) {
            count += 1;
            match (lo, hi) {
                (Some(lo), Some(hi)) if lo < hi => ordered += 1,
                _ => unordered.push(c.to_string()),
            }
        }
    }
    Some(OrderCheck {
        low,
        high,
        conditions: count,
        ordered,
        holds: count > 0 && ordered == count,
        unordered,
    })
}

/// The variants of `r` in Table 4's order.
fn variants_of(r: &IdentifyReport) -> Vec<(ModelKind, &VariantFits)> {
    ModelKind::ALL
        .into_iter()
        .filter_map(|v| r.variants.get(v.key()).map(|f| (v, f)))
        .collect()
}

fn alpha_cell(a: Option<f64>) -> String {
    a.map_or("flat".into(), |a| format!("{a:.2}"))
}

/// The identifiability tables as Markdown: per model, one row per run (best fit, RMSE at
/// the label and at the best fit), then per level the runs read back within
/// [`IdentifyReport::within`] and the order of the lowest and highest level.
pub(crate) fn identify_markdown(r: &IdentifyReport) -> String {
    let mut s = String::new();
    let cond = &r.condition;
    let _ = writeln!(
        s,
        "## Identifiability: the best-fit {} per run\n",
        cond.column()
    );
    let levels = match r.search {
        Search::Full => format!("at every level of a grid (step {})", r.step),
        Search::CoarseToFine => format!(
            "at the levels of a grid (step {}) that a coarse-to-fine search visits (for the \
             NEMM and NEMM-Light the best level of a search on nemm-core's table-mode \
             estimators and {} levels on each side, else {} levels spread over the grid; then \
             those around each minimum within {} of the RMSE's range above the least, down to \
             the step)",
            r.step,
            crate::train::identify::TABLE_WINDOW,
            crate::train::identify::LANES - 1,
            crate::train::identify::MINIMA_MARGIN
        ),
    };
    let _ = writeln!(
        s,
        "Each run is simulated whole, from rest, {levels} and at its label; the best fit is the \
         level of least force RMSE (after {} warm-up samples). `flat`: the RMSE varies over the \
         simulated levels by at most {} of its largest value (the model does not tell the \
         levels apart on that run).\n",
        r.warmup_samples, r.flat_tolerance
    );
    for (v, f) in variants_of(r) {
        let grid = match (f.grid.first(), f.grid.last()) {
            (Some(&a), Some(&b)) => format!(
                "{} to {}, {} levels",
                alpha_text(a),
                alpha_text(b),
                f.grid.len()
            ),
            _ => "empty".into(),
        };
        let simulated = f.fits.iter().map(|f| f.curve_n.len()).sum::<usize>() as f64
            / f.fits.len().max(1) as f64;
        let _ = writeln!(
            s,
            "### {} (grid {grid}, {simulated:.1} simulated per run; {:.1} s)\n",
            v.title(),
            f.seconds
        );
        let _ = writeln!(
            s,
            "| run | role | {} | best fit | RMSE at label [N] | RMSE at best [N] |",
            cond.column()
        );
        let _ = writeln!(s, "|---|---|---:|---:|---:|---:|");
        for (run, fit) in r.runs.iter().zip(&f.fits) {
            let _ = writeln!(
                s,
                "| {} | {} | {}{} | {} | {:.1} | {:.1} |",
                run.file,
                role_name(run.role),
                cond.cell(run.alpha),
                if run.level_column { " (column)" } else { "" },
                alpha_cell(fit.best),
                fit.rmse_label_n,
                fit.rmse_best_n
            );
        }
        let _ = writeln!(s);
        for l in &f.levels {
            let _ = writeln!(
                s,
                "- {} ({}): {} of {} runs within {} of the label{}",
                cond.level(l.alpha),
                l.role,
                l.within,
                l.runs,
                r.within,
                if l.flat > 0 {
                    format!(" ({} flat)", l.flat)
                } else {
                    String::new()
                }
            );
        }
        if let Some(o) = &f.order {
            let _ = writeln!(
                s,
                "- best fit at {} below that at {}: {} of {} conditions ({}){}",
                o.low,
                o.high,
                o.ordered,
                o.conditions,
                if o.holds {
                    "every one"
                } else {
                    "not every one"
                },
                if o.unordered.is_empty() {
                    String::new()
                } else {
                    format!("; not: {}", o.unordered.join("; "))
                }
            );
        }
        let _ = writeln!(s);
    }
    s
}

/// The whole-run force error at the label as Markdown: per level (training levels marked)
/// and per run ordered by amplitude, frequency and level, every model as `normalised (N)`.
pub(crate) fn whole_run_markdown(r: &IdentifyReport) -> String {
    let mut s = String::new();
    let vs = variants_of(r);
    if vs.is_empty() || r.runs.is_empty() {
        return s;
    }
    let cond = &r.condition;
    let cell = |e_n: f64| format!("{:.4} ({:.1} N)", e_n / r.force_scale_n, e_n);
    let heads: String = vs
        .iter()
        .map(|(v, _)| format!(" {} |", v.title()))
        .collect();
    let rule: String = vs.iter().map(|_| "---:|").collect();
    let _ = writeln!(
        s,
        "Whole-run RMSE at the label per level (runs simulated whole from rest; normalised by \
         {:.0} N, and in N):\n",
        r.force_scale_n
    );
    let _ = writeln!(s, "| {} | role | runs |{heads}", cond.column());
    let _ = writeln!(s, "|---:|---|---:|{rule}");
    if let Some((_, first)) = vs.first() {
        for (k, l) in first.levels.iter().enumerate() {
            let mut row = format!("| {} | {} | {} |", cond.cell(l.alpha), l.role, l.runs);
            for (_, f) in &vs {
                row.push_str(&match f.levels.get(k) {
                    Some(l) => format!(" {} |", cell(l.rmse_n)),
                    None => " - |".into(),
                });
            }
            let _ = writeln!(s, "{row}");
        }
    }
    let _ = writeln!(
        s,
        "\nWhole-run RMSE at the label per run, by amplitude, frequency and level:\n"
    );
    let _ = writeln!(
        s,
        "| amplitude [mm] | frequency [Hz] | {} | role | run |{heads}",
        cond.column()
    );
    let _ = writeln!(s, "|---:|---:|---:|---|---|{rule}");
    let mut order: Vec<usize> = (0..r.runs.len()).collect();
    let round = |x: f64, q: f64| (x / q).round();
    order.sort_by(|&a, &b| {
        let (ra, rb) = (&r.runs[a], &r.runs[b]);
        round(ra.amplitude_m, 5e-4)
            .total_cmp(&round(rb.amplitude_m, 5e-4))
            .then(
                round(ra.frequency_hz.unwrap_or(0.0), 0.05)
                    .total_cmp(&round(rb.frequency_hz.unwrap_or(0.0), 0.05)),
            )
            .then(ra.alpha.total_cmp(&rb.alpha))
    });
    for i in order {
        let run = &r.runs[i];
        let mut row = format!(
            "| {:.0} | {} | {} | {} | {} |",
            run.amplitude_m * 1e3,
            run.frequency_hz.map_or("-".into(), |f| format!("{f:.1}")),
            cond.cell(run.alpha),
            role_name(run.role),
            run.file
        );
        for (_, f) in &vs {
            row.push_str(&match f.fits.get(i) {
                Some(fit) => format!(" {} |", cell(fit.rmse_label_n)),
                None => " - |".into(),
            });
        }
        let _ = writeln!(s, "{row}");
    }
    s
}
