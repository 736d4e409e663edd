//! Export-time check of the tabulated fast path (`nemm_kernels::table`): is the model safe to
//! run in `EvalMode::Table`, and with which error?
//!
//! For each table size a firmware may use (256 segments, the `nemm-core` default, and 128,
//! the example firmware's `TABLE_SEGMENTS`) and a grid of oil-loss levels over the model's
//! training range (`meta.alpha_min ..= meta.alpha_max`, 7 levels), it builds the estimator in
//! table mode with the bound (`nemm export --table-bound`, default 1e-4) exactly as a target
//! does at boot, and records the largest relative coefficient error the table compile
//! measured on its check grid (128 points per segment; after its rescans for missed kinks
//! where the error exceeded the bound) and the kinks it made knots. The verdict compares
//! the worst of them with the bound: a relative error `e` of a coefficient changes the
//! quasi-static force by at most `e |F| <= e` times the force scale (docs/core.md, "Tabulated
//! fast path", which also has the measured force differences over whole bench programmes).

use nemm_core::{
    Estimator, EstimatorConfig, EstimatorError, EvalMode, Model, TableConfig, TableError,
};
use nemm_dataset::{alpha_text, ConditionSpec};

/// Default bound of the relative coefficient error.
pub const DEFAULT_TABLE_BOUND: f32 = nemm_kernels::table::DEFAULT_MAX_REL_ERROR;

/// Oil-loss levels checked across the training range.
pub(crate) const ALPHA_LEVELS: usize = 7;

/// The result for one table size.
#[derive(Debug, Clone, PartialEq)]
pub struct SizeCheck {
    /// Segments per table.
    pub segments: usize,
    /// Worst measured relative error over the levels (`None` if no table could be built).
    pub worst: Option<f32>,
    /// Oil-loss level of the worst error.
    pub(crate) worst_alpha: f32,
    /// Kinks in the worst table (0 if the worst table was refused: the error carries none).
    pub(crate) kinks: usize,
    /// Why a table could not be built at some level (e.g. more kinks than segments).
    pub failure: Option<String>,
}

impl SizeCheck {
    /// True if every level built and the worst error is within `bound`.
    pub fn passes(&self, bound: f32) -> bool {
        self.failure.is_none() && self.worst.is_some_and(|w| w <= bound)
    }
}

fn check_size<const T: usize>(model: &Model, alphas: &[f32], bound: f32) -> SizeCheck {
    let mut c = SizeCheck {
        segments: T,
        worst: None,
        worst_alpha: 0.0,
        kinks: 0,
        failure: None,
    };
    for &alpha in alphas {
        // With the caller's bound: the compile rescans for missed kinks only where the error
        // exceeds it, as on the target.
        let cfg = EstimatorConfig {
            mode: EvalMode::Table(TableConfig::new(bound)),
            ..EstimatorConfig::new(alpha)
        };
        let mut record = |e: f32, kinks: Option<usize>| {
            if c.worst.is_none_or(|w| e > w) {
                c.worst = Some(e);
                c.worst_alpha = alpha;
                c.kinks = kinks.unwrap_or(c.kinks);
            }
        };
        match Estimator::<{ nemm_core::DEFAULT_PARAM_CAPACITY }, T>::with_segments(model, cfg) {
            Ok(est) => {
                if let Some(a) = est.table_accuracy() {
                    record(a.max_rel_error, Some(a.kinks));
                }
            }
            // Missed: the measured error is the verdict's input, not a failure to build.
            Err(EstimatorError::Table(TableError::ExceedsBound { max_rel_error, .. })) => {
                record(max_rel_error, None);
            }
            Err(EstimatorError::Table(e)) => {
                c.failure = Some(format!("alpha {}: {e}", alpha_text(f64::from(alpha))));
                break;
            }
            Err(e) => {
                c.failure = Some(format!("alpha {}: {e}", alpha_text(f64::from(alpha))));
                break;
            }
        }
    }
    c
}

/// Checks 256- and 128-segment tables built with `bound` at `ALPHA_LEVELS` levels over the
/// training range. Empty for kinds without neural state coefficients (SEM, Linear EMM).
pub fn check(model: &Model, bound: f32) -> Vec<SizeCheck> {
    if !matches!(
        model.kind(),
        nemm_core::ModelKind::NemmLight | nemm_core::ModelKind::Nemm
    ) {
        return Vec::new();
    }
    let (a0, a1) = (model.meta.alpha_min, model.meta.alpha_max);
    let alphas: Vec<f32> = (0..ALPHA_LEVELS)
        .map(|i| a0 + (a1 - a0) * i as f32 / (ALPHA_LEVELS - 1) as f32)
        .collect();
    vec![
        check_size::<256>(model, &alphas, bound),
        check_size::<128>(model, &alphas, bound),
    ]
}

/// The report lines of [`check`] against `bound`.
pub fn report(model: &Model, bound: f32) -> String {
    let checks = check(model, bound);
    if checks.is_empty() {
        return format!(
            "table check: {} has no neural state coefficients; exact and table mode are the same\n",
            model.kind().name()
        );
    }
    let condition = ConditionSpec::from_core(&model.condition);
    let mut s = format!(
        "table check (fast path, bound {bound:.1e} relative per coefficient, {ALPHA_LEVELS} {} levels, alpha {} to {}):\n",
        condition.name,
        alpha_text(f64::from(model.meta.alpha_min)),
        alpha_text(f64::from(model.meta.alpha_max))
    );
    for c in &checks {
        let verdict = if c.passes(bound) {
            "meets the bound"
        } else {
            "MISSES the bound: use the exact mode or more segments"
        };
        match (&c.failure, c.worst) {
            (Some(f), _) => s += &format!("  {} segments: {f}; {verdict}\n", c.segments),
            (None, Some(w)) => {
                // A refused table reports its error, not its kinks.
                let kinks = if c.kinks > 0 {
                    format!(" ({} kinks made knots)", c.kinks)
                } else {
                    String::new()
                };
                s += &format!(
                    "  {} segments ({} B per table): worst measured error {w:.2e} at alpha {}{kinks}; {verdict}\n",
                    c.segments,
                    nemm_kernels::table::TABLE_BYTES_PER_SEGMENT * c.segments,
                    alpha_text(f64::from(c.worst_alpha)),
                )
            }
            (None, None) => s += &format!("  {} segments: no table built\n", c.segments),
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn verdict_is_the_measured_worst_against_the_bound() {
        let m: Model = nemm_core::testing::example_model(nemm_core::ModelKind::Nemm, 16, 5)
            .expect("example model");
        let checks = check(&m, DEFAULT_TABLE_BOUND);
        assert_eq!(checks.len(), 2);
        for c in &checks {
            // The verdict is the measured worst against the bound (the pseudo-random example
            // NEMM: 1.8e-5 with 256 segments, 2.8e-6 with 128 at the default bound).
            let w = c.worst.expect("tables built");
            assert!(c.failure.is_none() && c.kinks > 0, "{c:?}");
            assert!(w > 0.0 && w <= DEFAULT_TABLE_BOUND, "{c:?}");
            assert!(
                c.passes(DEFAULT_TABLE_BOUND) && c.passes(w) && !c.passes(0.5 * w),
                "{c:?}"
            );
        }
        // A bound no table meets: measured, reported, missed (not a failure to build).
        for c in &check(&m, 1e-9) {
            let w = c.worst.expect("errors measured");
            assert!(c.failure.is_none() && w > 1e-9 && !c.passes(1e-9), "{c:?}");
        }
        let r = report(&m, 1e-9);
        assert!(r.contains("MISSES"), "{r}");
        let lin: Model = nemm_core::testing::example_model(nemm_core::ModelKind::LinearEmm, 16, 5)
            .expect("example model");
        assert!(check(&lin, DEFAULT_TABLE_BOUND).is_empty());
    }
}
