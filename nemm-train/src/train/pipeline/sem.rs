//! The SEM (static force-velocity map): knots from the quasi-static points, fitted per level.

use super::{
    PipelineConfig, Prepared, QuasiStaticPoint, TrainedVariant, MAX_SEM_ALPHAS, MAX_SEM_VELOCITIES,
};
use anyhow::{bail, Result};
use nemm_core::{Body, InputScales, Meta, Model, ModelKind, SemMap};
use std::time::Instant;

/// Relative velocity gap that separates two SEM support velocities (5 %).
pub(crate) const SEM_CLUSTER_GAP: f64 = 0.05;

/// Largest span of one velocity cluster, relative to its largest magnitude, in units of the
/// gap (4 x 5 % = 20 %).
pub(crate) const SEM_CLUSTER_SPAN: f64 = 4.0;

/// Knots from sorted velocities: the origin plus the mean of every cluster. A cluster holds
/// velocities of one sign, each less than `gap` times the larger magnitude from the previous
/// one, and spans at most [`SEM_CLUSTER_SPAN`] `gap` times its largest magnitude (so that dense
/// points, e.g. of random excitation, do not chain into one cluster).
fn velocity_knots(sorted: &[f64], gap: f64) -> Vec<f64> {
    let mut knots: Vec<f64> = vec![0.0];
    let mut cluster: Vec<f64> = Vec::new();
    for &v in sorted {
        if let (Some(&first), Some(&last)) = (cluster.first(), cluster.last()) {
            let scale = first.abs().max(v.abs());
            if (v - last).abs() > gap * last.abs().max(v.abs())
                || (v - first).abs() > SEM_CLUSTER_SPAN * gap * scale
                || v.signum() != last.signum()
            {
                knots.push(cluster.iter().sum::<f64>() / cluster.len() as f64);
                cluster.clear();
            }
        }
        cluster.push(v);
    }
    if !cluster.is_empty() {
        knots.push(cluster.iter().sum::<f64>() / cluster.len() as f64);
    }
    knots.sort_by(f64::total_cmp);
    knots.dedup_by(|a, b| (*a - *b).abs() < 1e-6);
    knots
}

/// The distinct levels of the points (within 1e-9), increasing.
pub(crate) fn point_levels(points: &[QuasiStaticPoint]) -> Vec<f64> {
    let mut levels: Vec<f64> = points.iter().map(|p| p.alpha).collect();
    levels.sort_by(f64::total_cmp);
    levels.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    levels
}

/// The map's levels for the points' levels: every distinct level ([`point_levels`]) when
/// there are at most [`MAX_SEM_ALPHAS`]; else [`MAX_SEM_ALPHAS`] bins of equally many
/// consecutive distinct levels (a level is never split), each at the mean level of its
/// points. Returns the map's levels (strictly increasing) and each point's bin.
pub(crate) fn sem_levels(points: &[QuasiStaticPoint]) -> (Vec<f64>, Vec<usize>) {
    let distinct = point_levels(points);
    // The bin of each distinct level: its own when they fit, else consecutive levels in
    // equal numbers (every bin holds at least one level).
    let bin_of_level: Vec<usize> = (0..distinct.len())
        .map(|k| k * MAX_SEM_ALPHAS.min(distinct.len()) / distinct.len().max(1))
        .collect();
    let bins = bin_of_level.last().map_or(0, |b| b + 1);
    let mut sum = vec![0.0f64; bins];
    let mut cnt = vec![0usize; bins];
    let level_index = |a: f64| distinct.partition_point(|&l| l < a - 1e-9);
    let point_bins: Vec<usize> = points
        .iter()
        .map(|p| {
            let b = bin_of_level[level_index(p.alpha).min(bin_of_level.len() - 1)];
            sum[b] += p.alpha;
            cnt[b] += 1;
            b
        })
        .collect();
    let levels = sum
        .iter()
        .zip(&cnt)
        .map(|(s, &c)| if c > 0 { s / c as f64 } else { f64::NAN })
        .collect();
    (levels, point_bins)
}

/// SEM map from quasi-static points (see the module docs): a force-velocity curve per level,
/// with more levels than the map holds binned (`sem_levels`) and interpolated in alpha
/// between the bins by the map.
pub fn fit_sem(points: &[QuasiStaticPoint]) -> Result<SemMap> {
    if points.is_empty() {
        bail!("no quasi-static points in the training set: cannot build the SEM");
    }
    let (alphas, bin_of_point) = sem_levels(points);
    // Velocity clusters over all levels: 5 % gaps, widened until the knots fit the map.
    let mut vs: Vec<f64> = points.iter().map(|p| p.velocity_m_s).collect();
    vs.sort_by(f64::total_cmp);
    let mut gap = SEM_CLUSTER_GAP;
    let mut knots = velocity_knots(&vs, gap);
    while knots.len() > MAX_SEM_VELOCITIES && gap < 1.0 {
        gap *= 1.5;
        knots = velocity_knots(&vs, gap);
    }
    if knots.len() > MAX_SEM_VELOCITIES {
        bail!(
            "{} velocity support points; the SEM holds at most {MAX_SEM_VELOCITIES}",
            knots.len()
        );
    }
    let mut forces = Vec::new();
    for level in 0..alphas.len() {
        // This level's points, averaged per knot (nearest knot), plus the origin.
        let mut sum = vec![0.0f64; knots.len()];
        let mut cnt = vec![0usize; knots.len()];
        let own_points = points
            .iter()
            .zip(&bin_of_point)
            .filter(|(_, &b)| b == level)
            .map(|(p, _)| p);
        for p in own_points {
            let (i, _) = knots
                .iter()
                .enumerate()
                .map(|(i, k)| (i, (k - p.velocity_m_s).abs()))
                .min_by(|x, y| x.1.total_cmp(&y.1))
                .unwrap_or((0, 0.0));
            sum[i] += p.force_n;
            cnt[i] += 1;
        }
        let own: Vec<(f64, f64)> = knots
            .iter()
            .enumerate()
            .filter(|(i, k)| cnt[*i] > 0 || **k == 0.0)
            .map(|(i, &k)| {
                (
                    k,
                    if cnt[i] > 0 {
                        sum[i] / cnt[i] as f64
                    } else {
                        0.0
                    },
                )
            })
            .collect();
        for &k in &knots {
            forces.push(interp(&own, k) as f32);
        }
    }
    let map = SemMap {
        velocities_m_s: knots.iter().map(|&v| v as f32).collect(),
        alphas: alphas.iter().map(|&a| a as f32).collect(),
        forces_n: forces.into_iter().collect(),
    };
    map.validate()
        .map_err(|e| anyhow::anyhow!("SEM map from the quasi-static points is invalid: {e:?}"))?;
    Ok(map)
}

/// Piecewise-linear interpolation through sorted points, linear extrapolation at the ends.
fn interp(pts: &[(f64, f64)], x: f64) -> f64 {
    match pts.len() {
        0 => 0.0,
        1 => pts[0].1,
        n => {
            let i = pts.partition_point(|p| p.0 <= x).clamp(1, n - 1);
            let (x0, y0) = pts[i - 1];
            let (x1, y1) = pts[i];
            y0 + (y1 - y0) * (x - x0) / (x1 - x0)
        }
    }
}

/// The SEM from the training set's quasi-static points.
pub(super) fn train_sem(
    prepared: &Prepared,
    cfg: &PipelineConfig,
    meta: Meta,
) -> Result<TrainedVariant> {
    let t = Instant::now();
    let map = fit_sem(&prepared.quasi_static.train)?;
    let model = Model {
        integrator: cfg.integrator,
        dt_s: (1.0 / cfg.model_rate_hz) as f32,
        scales: InputScales {
            velocity_m_s: prepared.scales.velocity_m_s as f32,
            x_pr_m: 1.0,
            alpha: prepared.scales.alpha as f32,
        },
        meta,
        body: Body::Sem(map),
        condition: prepared.condition.clone(),
        alpha_branches: Default::default(),
        cumulative: Default::default(),
        provenance: Default::default(),
        static_force: None,
        lost_motion: None,
    };
    model
        .validate()
        .map_err(|e| anyhow::anyhow!("SEM model invalid: {e}"))?;
    let val = crate::train::eval::rmse_model(
        &model,
        &prepared.validation,
        prepared.dt_s,
        prepared.warmup_samples,
        prepared.scales.force_n,
    )?;
    let (velocities, levels) = match &model.body {
        Body::Sem(m) => (m.velocities_m_s.len(), m.alphas.len()),
        _ => (0, 0),
    };
    let distinct = point_levels(&prepared.quasi_static.train).len();
    eprintln!(
        "[sem] {velocities} support velocities x {levels} {} levels{}, validation RMSE \
         {val:.4}",
        prepared.condition.name.as_str(),
        if distinct > levels {
            format!(" ({distinct} binned)")
        } else {
            String::new()
        }
    );
    Ok(TrainedVariant {
        variant: ModelKind::Sem,
        model: Box::new(model),
        history: Vec::new(),
        val_rmse: val,
        stop: None,
        kept_epoch: None,
        seconds: t.elapsed().as_secs_f64(),
    })
}
