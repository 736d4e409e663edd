//! The learned coefficients of the NEMM against the virtual bench's equivalent EMM
//! coefficients ([`nemm_virtual_bench::reference`]): the relative change of each between alpha = 0
//! and the largest training level, in `report.json` (`bench_reference`) and printed by
//! `nemm compare` when the dataset came from the virtual bench.

use nemm_core::Model;
use nemm_dataset::alpha_text;
use nemm_virtual_bench::reference::{Coefficient, EmmReference};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// Velocities at which `b_fl` is compared \[m/s\].
pub(crate) const COMPARED_VELOCITIES_M_S: [f64; 6] = [-1.0, -0.5, -0.1, 0.1, 0.5, 1.0];

/// One learned coefficient against one reference coefficient.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReferenceRow {
    /// The learned coefficient, e.g. `k_pr(x_pr = 0)`.
    pub learned: String,
    /// The reference it is compared with, e.g. `k_pr, both chambers`.
    pub reference: String,
    /// Learned value at `alpha_from` and at `alpha_to` (N/m or N s/m).
    pub learned_from: f64,
    /// Learned value at `alpha_to`.
    pub(crate) learned_to: f64,
    /// `learned_to / learned_from - 1`.
    pub(crate) learned_change: f64,
    /// Reference value at `alpha_from` (N/m or N s/m).
    pub(crate) reference_from: f64,
    /// Reference value at `alpha_to`.
    pub(crate) reference_to: f64,
    /// `reference_to / reference_from - 1`.
    pub reference_change: f64,
    /// `learned_change / reference_change`: 1 when the model moves as the bench does, >= 0.5
    /// for "the right direction and at least half the size".
    pub ratio: f64,
}

/// The comparison of a model with the bench reference.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReferenceComparison {
    /// Lower level (0).
    pub(crate) alpha_from: f64,
    /// Upper level: the model's largest training level, within the reference's range.
    pub(crate) alpha_to: f64,
    /// The reference run, e.g. `10 mm, 1.048 m/s`.
    pub run: String,
    /// One row per pair.
    pub rows: Vec<ReferenceRow>,
}

/// Compares the NEMM `model` with `reference` between alpha = 0 and the model's largest
/// training level (clamped to the reference's range): `k_pr(x_pr = 0)` with the compression,
/// rebound and combined chamber stiffness and the describing-function `k_pr`, `b_pr` with the
/// describing-function `b_pr` (with a lost-motion element also the stiffness through it at
/// the start of the compression and the rebound side against those chambers' stiffness),
/// `b_fl(v)` with the quasi-static `b_fl(v)` at
/// `COMPARED_VELOCITIES_M_S`. Rows whose learned coefficient the model does not have are
/// left out.
pub fn compare(model: &Model, reference: &EmmReference) -> ReferenceComparison {
    let a1 = comparison_alpha(model, reference);
    let mut rows = Vec::new();
    let mut push = |learned: String, f: &dyn Fn(f32) -> Option<f32>, c: Coefficient| {
        let (Some(l0), Some(l1)) = (f(0.0), f(a1 as f32)) else {
            return;
        };
        let (Some(r0), Some(r1)) = (reference.value(c, 0.0), reference.value(c, a1)) else {
            return;
        };
        let (l0, l1) = (f64::from(l0), f64::from(l1));
        let lc = l1 / l0 - 1.0;
        let rc = r1 / r0 - 1.0;
        rows.push(ReferenceRow {
            learned,
            reference: c.name(),
            learned_from: l0,
            learned_to: l1,
            learned_change: lc,
            reference_from: r0,
            reference_to: r1,
            reference_change: rc,
            ratio: lc / rc,
        });
    };
    for c in [
        Coefficient::KPrCompression,
        Coefficient::KPrRebound,
        Coefficient::KPrCombined,
        Coefficient::KPrDescribing,
    ] {
        push("k_pr(x_pr = 0)".into(), &|a| model.k_pr(0.0, a), c);
    }
    if model.lost_motion.is_some() {
        // The pressure pair's stiffness through the lost-motion element at the start of
        // each side (the secant at x_pr -> 0: k_l f0 / (f0 + d k_l)).
        let side = 1e-9f32;
        for (learned, x, c) in [
            (
                "k_pr,eff(x_pr -> 0-), lost motion",
                -side,
                Coefficient::KPrCompression,
            ),
            (
                "k_pr,eff(x_pr -> 0+), lost motion",
                side,
                Coefficient::KPrRebound,
            ),
        ] {
            push(learned.into(), &|a| model.k_pr_eff(x, a), c);
        }
    }
    push(
        "b_pr".into(),
        &|a| model.b_pr(a),
        Coefficient::BPrDescribing,
    );
    for v in COMPARED_VELOCITIES_M_S {
        push(
            format!("b_fl(v_st = {v} m/s)"),
            &|a| model.b_fl(v as f32, a),
            Coefficient::BFl(v),
        );
    }
    ReferenceComparison {
        alpha_from: 0.0,
        alpha_to: a1,
        run: format!(
            "{} mm, {} m/s",
            reference.run.amplitude_m * 1e3,
            reference.run.peak_velocity_m_s
        ),
        rows,
    }
}

/// The upper level of the comparison: the model's largest training level, or the
/// reference's largest level when the model's lies beyond it (or is 0).
pub(crate) fn comparison_alpha(model: &Model, reference: &EmmReference) -> f64 {
    let a = f64::from(model.meta.alpha_max);
    let top = reference.alpha_max();
    if a > 0.0 && a <= top {
        a
    } else {
        top
    }
}

/// The two figures of a [`ReferenceComparison`] that say where the model puts the
/// degradation (each `None` where the comparison lacks its row).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct DegradationFigures {
    /// The compression chamber's `k_pr` change, learned over the bench's (through the
    /// lost-motion element when the model has one: its row follows `k_pr`'s).
    pub(crate) k_pr_compression_ratio: Option<f64>,
    /// The learned minus the bench's `b_fl` change at -1 m/s \[percentage points\].
    pub(crate) b_fl_change_pp: Option<f64>,
}

impl ReferenceComparison {
    /// Where the model puts the degradation against the bench: [`DegradationFigures`].
    pub(crate) fn degradation_figures(&self) -> DegradationFigures {
        let against = |c: Coefficient| {
            let name = c.name();
            self.rows.iter().filter(move |r| r.reference == name)
        };
        DegradationFigures {
            k_pr_compression_ratio: against(Coefficient::KPrCompression)
                .next_back()
                .map(|r| r.ratio),
            b_fl_change_pp: against(Coefficient::BFl(-1.0))
                .next()
                .map(|r| 100.0 * (r.learned_change - r.reference_change)),
        }
    }

    /// The comparison as a Markdown table.
    pub fn markdown(&self) -> String {
        let mut s = format!(
            "NEMM against the virtual bench's equivalent coefficients (reference run {}), \
             change from alpha = {} to {}:\n\n\
             | learned | reference | learned change | reference change | ratio |\n\
             |---|---|---:|---:|---:|\n",
            self.run,
            // Levels come from the blob's f32 (0.3 would print as 0.30000001192092896).
            alpha_text(self.alpha_from),
            alpha_text(self.alpha_to)
        );
        for r in &self.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {:+.1} % | {:+.1} % | {:.2} |",
                r.learned,
                r.reference,
                100.0 * r.learned_change,
                100.0 * r.reference_change,
                r.ratio
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::ReferenceComparison;

    #[test]
    fn the_table_prints_levels_as_the_blob_stores_them() {
        let c = ReferenceComparison {
            alpha_from: 0.0,
            alpha_to: f64::from(0.3f32),
            run: "10 mm, 1.048 m/s".into(),
            rows: Vec::new(),
        };
        assert!(
            c.markdown().contains("change from alpha = 0 to 0.3:"),
            "{}",
            c.markdown()
        );
    }
}
