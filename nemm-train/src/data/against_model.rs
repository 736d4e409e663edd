//! Do recorded runs suit a trained model? The checks `nemm identify` and `nemm diagnose` make
//! before they run a model over a dataset: no absurd sample (finite but far outside what a
//! damper bench records), a force scale within a factor of the model's training force scale,
//! and a force that dissipates energy (not an inverted sign). Each refusal names the run, and
//! the sample's line where there is one.

use crate::data::preprocess::Dissipation;
use anyhow::{bail, Result};
use nemm_core::Model;
use nemm_dataset::{sample_line, short_number, Dataset};

/// A displacement beyond this (m) is not a damper's stroke.
pub(crate) const MAX_DISPLACEMENT_M: f64 = 1.0;
/// A measured velocity beyond this (m/s) is not a damper bench's.
pub(crate) const MAX_VELOCITY_M_S: f64 = 100.0;
/// A force sample beyond this many of the model's force scales is absurd.
pub(crate) const MAX_FORCE_SCALES: f64 = 100.0;
/// The runs' largest force may be at most this many times the model's force scale (and at
/// least its inverse times, below which a warning is printed).
pub(crate) const FORCE_SCALE_FACTOR: f64 = 10.0;

/// Checks the runs `selected` of `ds` against `model` before any work: every sample within
/// [`MAX_DISPLACEMENT_M`], [`MAX_VELOCITY_M_S`] and [`MAX_FORCE_SCALES`] force scales; the
/// runs' largest force within [`FORCE_SCALE_FACTOR`] of the model's force scale above (and
/// 100 times below; 10 times below is a warning); and, unless `allow_inverted`, each run's
/// force dissipating energy against `velocity(i)` (the velocity of run `i` the command
/// uses), as [`Dissipation::force_assists_motion`] judges it.
pub(crate) fn check_runs_against_model(
    model: &Model,
    ds: &Dataset,
    selected: &[usize],
    velocity: impl Fn(usize) -> Vec<f64>,
    allow_inverted: bool,
) -> Result<()> {
    let scale = f64::from(model.meta.force_scale_n);
    let mut largest = 0.0f64;
    for &i in selected {
        let run = &ds.runs[i];
        let file = run.entry.file.display();
        let mut columns: Vec<(&str, &[f64], f64)> = vec![
            ("displacement_m", &run.displacement_m, MAX_DISPLACEMENT_M),
            ("force_n", &run.force_n, MAX_FORCE_SCALES * scale),
        ];
        if let Some(v) = &run.velocity_m_s {
            columns.push(("velocity_m_s", v, MAX_VELOCITY_M_S));
        }
        for (column, values, bound) in columns {
            if let Some(k) = values.iter().position(|v| !(-bound..=bound).contains(v)) {
                bail!(
                    "{file}:{}: {column} = {} is beyond what a damper bench records (at most \
                     {} in magnitude{}): a corrupt sample or a wrong unit; fix or cut the run",
                    sample_line(k),
                    short_number(values[k]),
                    short_number(bound),
                    if column == "force_n" {
                        format!(", {MAX_FORCE_SCALES} times the model's force scale {scale:.0} N")
                    } else {
                        String::new()
                    }
                );
            }
        }
        largest = run.force_n.iter().fold(largest, |m, f| m.max(f.abs()));
        if !allow_inverted {
            let d = Dissipation::of(&run.force_n, &velocity(i));
            if d.force_assists_motion() {
                bail!("{file}: the force assists the motion ({})", d.explain());
            }
        }
    }
    let ratio = largest / scale;
    if !(1.0 / (FORCE_SCALE_FACTOR * FORCE_SCALE_FACTOR)..=FORCE_SCALE_FACTOR).contains(&ratio) {
        bail!(
            "the runs' largest force is {largest:.0} N, {ratio:.3} times the model's force scale \
             ({scale:.0} N, the largest force it was trained on): the data do not suit this \
             model (a wrong force unit or gain, e.g. kN for N, or another damper); re-import \
             with the right unit or use a model trained on such data"
        );
    }
    if ratio < 1.0 / FORCE_SCALE_FACTOR {
        eprintln!(
            "warning: the runs' largest force is {largest:.0} N, {ratio:.3} times the model's \
             force scale ({scale:.0} N): check the force unit"
        );
    }
    Ok(())
}
