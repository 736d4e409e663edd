//! `nemm inspect`: what is inside a weights blob.
use anyhow::{Context, Result};
use nemm_core::{
    decode_with_tables, read_header, Body, Model, Scaler, StoredTables, DEFAULT_PARAM_CAPACITY,
};
use std::fmt::Write as _;
use std::path::Path;

/// Describes a decoded model and its blob's stored tables in a few lines (kind, integrator,
/// constants, scalers, bounds, tables).
pub(crate) fn describe(model: &Model, tables: &StoredTables, blob_len: usize) -> String {
    let mut s = String::new();
    describe_shape(&mut s, model, blob_len);
    describe_body(&mut s, model);
    describe_condition(&mut s, model);
    describe_static_force(&mut s, model);
    describe_lost_motion(&mut s, model);
    describe_provenance(&mut s, model);
    describe_tables(&mut s, tables);
    if let Some(tau) = model.fastest_time_constant_s() {
        let _ = writeln!(
            s,
            "stability:       fastest reachable time constant {:.1} us; the step of {:.1} us needs at least {:.1} us",
            tau * 1e6,
            model.dt_s * 1e6,
            nemm_core::shortest_stable_time_constant_s(model.integrator, model.dt_s) * 1e6
        );
    }
    s
}

/// Kind, size, integrator, input scales, training data and the EMM constants.
fn describe_shape(s: &mut String, model: &Model, blob_len: usize) {
    let _ = writeln!(s, "kind:            {}", model.kind().name());
    let _ = writeln!(s, "size:            {blob_len} bytes");
    let _ = writeln!(
        s,
        "integrator:      {} at dt = {} s ({:.0} Hz)",
        model.integrator.name(),
        model.dt_s,
        1.0 / model.dt_s
    );
    let _ = writeln!(
        s,
        "input scales:    |v| <= {} m/s, |x_pr| <= {} m, alpha <= {}",
        model.scales.velocity_m_s,
        model.scales.x_pr_m,
        level(model.scales.alpha)
    );
    let _ = writeln!(
        s,
        "training data:   force scale {} N, alpha in [{}, {}]",
        model.meta.force_scale_n,
        level(model.meta.alpha_min),
        level(model.meta.alpha_max)
    );
    if let Some(e) = model.emm() {
        let _ = writeln!(
            s,
            "EMM constants:   b_fl,ini = {} N s/m, b_pr,ini = {} N s/m, k_pr,ini = {} N/m, T_pr = {} s",
            e.b_fl_ns_per_m, e.b_pr_ns_per_m, e.k_pr_n_per_m, e.t_pr_s
        );
    }
}

/// What the kind adds: the SEM's map or the scalers of the neural variants.
fn describe_body(s: &mut String, model: &Model) {
    match &model.body {
        Body::Sem(m) => {
            let _ = writeln!(
                s,
                "SEM map:         {} velocities in [{}, {}] m/s x {} condition levels (alpha) [{}]",
                m.velocities_m_s.len(),
                m.velocities_m_s.first().copied().unwrap_or(0.0),
                m.velocities_m_s.last().copied().unwrap_or(0.0),
                m.alphas.len(),
                m.alphas
                    .iter()
                    .map(|&a| level(a))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        Body::LinearEmm(_) => {}
        Body::NemmLight { b_fl, .. } => {
            describe_scaler(s, "b_fl", b_fl, model.cumulative.b_fl.as_ref())
        }
        Body::Nemm {
            b_fl, b_pr, k_pr, ..
        } => {
            let c = &model.cumulative;
            describe_scaler(s, "b_fl", b_fl, c.b_fl.as_ref());
            describe_scaler(s, "b_pr", b_pr, None);
            describe_scaler(s, "k_pr", k_pr, c.k_pr.as_ref());
        }
    }
}

/// One scaler: inputs, shape, parameters and the range of its scale factor (a cumulative
/// scaler, if the coefficient has one, in place of the MLP).
fn describe_scaler(
    s: &mut String,
    name: &str,
    sc: &Scaler<DEFAULT_PARAM_CAPACITY>,
    cumulative: Option<&nemm_core::CumulativeScaler>,
) {
    if let Some(c) = cumulative {
        let _ = writeln!(
            s,
            "scaler {name:<6}  cumulative (force monotone in the state by construction), {} \
             units, gates {} in alpha, {} parameters, scale in ({}, {})",
            c.units,
            c.direction.name(),
            c.params.len(),
            sc.s_min,
            sc.s_max
        );
        return;
    }
    let _ = writeln!(
        s,
        "scaler {name:<6}  {} input(s), {} x {} hidden, {} parameters, scale in ({}, {})",
        sc.mlp.inputs,
        sc.mlp.layers,
        sc.mlp.hidden,
        sc.mlp.params.len(),
        sc.s_min,
        sc.s_max
    );
}

/// A condition level of the blob (f32) as printed ([`nemm_dataset::alpha_text`]).
fn level(alpha: f32) -> String {
    nemm_dataset::alpha_text(f64::from(alpha))
}

/// The condition alpha stands for, its priors and the alpha branches that impose them.
fn describe_condition(s: &mut String, model: &Model) {
    let c = &model.condition;
    let spec = nemm_dataset::ConditionSpec::from_core(c);
    let _ = writeln!(
        s,
        "condition:       {} (alpha 0 = {} {u}, alpha 1 = {} {u}); priors in alpha: b_fl {}, b_pr {}, k_pr {}",
        c.name,
        spec.cell(0.0),
        spec.cell(1.0),
        c.priors.b_fl.name(),
        c.priors.b_pr.name(),
        c.priors.k_pr.name(),
        u = c.unit
    );
    let br = &model.alpha_branches;
    for (name, b) in [("b_fl", &br.b_fl), ("b_pr", &br.b_pr), ("k_pr", &br.k_pr)] {
        if let Some(b) = b {
            let _ = writeln!(
                s,
                "alpha branch {name}: {} units, {} in alpha by construction",
                b.units,
                b.direction.name()
            );
        }
    }
}

/// The lost-motion element, if the model has one: its parameters and the travels at the
/// training levels.
fn describe_lost_motion(s: &mut String, model: &Model) {
    let Some(l) = &model.lost_motion else {
        let _ = writeln!(s, "lost motion:     none");
        return;
    };
    let _ = writeln!(
        s,
        "lost motion:     f0 {} N; compression travel {} mm + {} mm x alpha, rebound travel {} \
         mm + {} mm x alpha",
        l.f0_n,
        1e3 * l.travel_c_m,
        1e3 * l.travel_c_per_alpha_m,
        1e3 * l.travel_r_m,
        1e3 * l.travel_r_per_alpha_m
    );
    for a in [model.meta.alpha_min, model.meta.alpha_max] {
        let at = l.at(a);
        let _ = writeln!(
            s,
            "                 at alpha {a}: compression {:.2} mm, rebound {:.2} mm",
            1e3 * at.travel_c_m,
            1e3 * at.travel_r_m
        );
    }
}

/// The static force of eq. 17, if the model has one.
fn describe_static_force(s: &mut String, model: &Model) {
    match &model.static_force {
        None => {
            let _ = writeln!(s, "static force:    none");
        }
        Some(f) => {
            let _ = writeln!(
                s,
                "static force:    gas force {} N + {} N x alpha at x_ref {} m, gas spring {} N/m + \
                 {} N/m x alpha, seal friction {} N (v_c {} m/s)",
                f.f_gas0_n,
                f.f_gas0_per_alpha_n,
                f.x_ref_m,
                f.k_gas_n_per_m,
                f.k_gas_per_alpha_n_per_m,
                f.f_c_n,
                f.v_c_m_s
            );
        }
    }
}

/// The command, dataset and commit that made the model.
fn describe_provenance(s: &mut String, model: &Model) {
    let p = &model.provenance;
    if p.is_empty() {
        let _ = writeln!(s, "provenance:      none recorded");
    } else {
        let or_unknown = |t: &str| {
            if t.is_empty() {
                "unknown".to_string()
            } else {
                t.to_string()
            }
        };
        let _ = writeln!(s, "provenance:      command {}", or_unknown(&p.command));
        let _ = writeln!(s, "                 dataset {}", or_unknown(&p.dataset));
        let _ = writeln!(s, "                 commit  {}", or_unknown(&p.commit));
    }
}

/// The precomputed fast-path tables stored in the blob, one line per level.
fn describe_tables(s: &mut String, stored: &StoredTables) {
    if stored.levels.is_empty() {
        let _ = writeln!(
            s,
            "stored tables:   none (a table-mode estimator builds them)"
        );
    }
    for level in &stored.levels {
        let mut tables = Vec::new();
        for (name, t) in [("b_fl", &level.b_fl), ("k_pr", &level.k_pr)] {
            if let Some(t) = t {
                tables.push(format!(
                    "{name} on [{}, {}] ({} kinks, max rel. error {:.2e})",
                    t.domain.0, t.domain.1, t.accuracy.kinks, t.accuracy.max_rel_error
                ));
            }
        }
        let _ = writeln!(
            s,
            "stored tables:   alpha {}, {} segments, bound {:.0e}, domain margin {}: {}",
            self::level(level.alpha),
            level.segments,
            level.config.max_rel_error,
            level.config.domain_margin,
            tables.join("; ")
        );
    }
}

/// Runs `nemm inspect FILE`.
pub fn run(path: &Path) -> Result<()> {
    let blob = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let header = read_header(&blob).with_context(|| format!("{}", path.display()))?;
    println!("file:            {}", path.display());
    println!("format version:  {}", header.version);
    let (model, tables): (Model, _) =
        decode_with_tables(&blob).with_context(|| format!("{}", path.display()))?;
    print!("{}", describe(&model, &tables, blob.len()));
    println!("CRC-32:          ok");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::describe;
    use nemm_core::{Model, ModelKind, StoredTables};

    #[test]
    fn the_lost_motion_is_described() {
        let mut m: Model = nemm_core::testing::example_model(ModelKind::Nemm, 4, 2).unwrap();
        let none = StoredTables::EMPTY;
        assert!(describe(&m, &none, 0).contains("lost motion:     none"));
        m.lost_motion = Some(nemm_core::testing::EXAMPLE_LOST_MOTION);
        let text = describe(&m, &none, 0);
        let l = nemm_core::testing::EXAMPLE_LOST_MOTION;
        assert!(text.contains(&format!("f0 {} N", l.f0_n)), "{text}");
        let top = l.at(m.meta.alpha_max);
        assert!(
            text.contains(&format!("compression {:.2} mm", 1e3 * top.travel_c_m)),
            "{text}"
        );
    }

    #[test]
    fn the_static_force_is_described() {
        let mut m: Model = nemm_core::testing::example_model(ModelKind::Nemm, 4, 2).unwrap();
        let none = StoredTables::EMPTY;
        assert!(describe(&m, &none, 0).contains("static force:    none"));
        m.static_force = Some(nemm_core::testing::EXAMPLE_STATIC_FORCE);
        let text = describe(&m, &none, 0);
        let f = nemm_core::testing::EXAMPLE_STATIC_FORCE;
        assert!(
            text.contains(&format!("gas force {} N", f.f_gas0_n))
                && text.contains(&format!("seal friction {} N", f.f_c_n)),
            "{text}"
        );
    }
}
