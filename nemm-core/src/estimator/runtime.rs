//! The estimator's per-step machinery: each coefficient as a constant, a compiled scaler or
//! its table, the RK stages they feed, and the storage of every model kind (written in place
//! by [`super::Estimator::load`]).

use super::*;

/// How a [`Coef`] is evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum CoefKind {
    /// The constant `value`.
    Const,
    /// The compiled scaler `exact`.
    Neural,
    /// The table `table` (of `exact`, which is kept to rebuild it on `set_alpha`).
    Table,
}

/// A coefficient that is constant, a compiled neural scaler of one state input, or a table
/// of that scaler. Every representation has its storage, so that [`Estimator::load`] writes
/// in place whatever the model; `kind` says which one is in use. `repr(C)`: the table (its
/// scalars first) right after the kind, near the start of the runtime.
#[derive(Debug, Clone)]
#[repr(C)]
pub(super) struct Coef<const P: usize, const T: usize> {
    pub(super) kind: CoefKind,
    pub(super) value: f32,
    pub(super) table: Table1D<T>,
    pub(super) exact: CompiledScaler<P>,
}

impl<const P: usize, const T: usize> Coef<P, T> {
    pub(super) const fn empty() -> Self {
        Self {
            kind: CoefKind::Const,
            value: 0.0,
            table: Table1D::empty(),
            exact: CompiledScaler::empty(),
        }
    }

    /// The coefficient at state input `u`; a clamped table input sets `*out`.
    #[inline(always)]
    pub(super) fn eval(&self, u: f32, out: &mut bool) -> f32 {
        match self.kind {
            CoefKind::Const => self.value,
            CoefKind::Neural => self.exact.eval(u),
            CoefKind::Table => self.table.eval(u, out),
        }
    }

    /// The table, in table mode.
    pub(super) fn table(&self) -> Option<&Table1D<T>> {
        (self.kind == CoefKind::Table).then_some(&self.table)
    }

    /// In place: the constant `p_ini` without a scaler; otherwise the scaler (its MLP and
    /// alpha branch, or its cumulative scaler between the scaler's bounds) compiled for
    /// `alpha` and, in table mode, its table over `[-m u_scale, m u_scale]` (`m` the
    /// configured domain margin): read from `stored` (a stored table of `T` segments, see
    /// [`crate::format::tables`]) if given and it reads back on that domain, else built.
    /// `name` names the coefficient in errors. Returns, in table mode, whether the table
    /// was read from `stored`.
    pub(super) fn load(
        &mut self,
        name: &'static str,
        scaler: Option<(&Scaler<P>, Option<&AlphaBranch>, Option<&CumulativeScaler>)>,
        p_ini: f32,
        u_scale: f32,
        (alpha, alpha_scale): (f32, f32),
        (mode, stored): (&EvalMode, Option<(&[u8], StoredLayout)>),
    ) -> Result<Option<bool>, EstimatorError> {
        self.kind = CoefKind::Const;
        self.value = p_ini;
        let Some((scaler, branch, cumulative)) = scaler else {
            return Ok(None);
        };
        match cumulative {
            None => self
                .exact
                .compile_into(scaler, branch, p_ini, u_scale, alpha, alpha_scale),
            Some(c) => self.exact.compile_cumulative_into(
                c,
                scaler.s_min,
                scaler.s_max,
                p_ini,
                u_scale,
                alpha,
                alpha_scale,
            ),
        }
        .ok_or(EstimatorError::Compile)?;
        self.kind = CoefKind::Neural;
        let EvalMode::Table(tc) = mode else {
            return Ok(None);
        };
        let d = tc.domain_margin * u_scale;
        let read =
            stored.is_some_and(|(b, layout)| self.table.read_layout(b, layout, -d, d).is_some());
        if !read {
            self.table
                .compile_into(&self.exact, -d, d, tc.max_rel_error, name)
                .map_err(EstimatorError::Table)?;
        }
        self.kind = CoefKind::Table;
        Ok(Some(read))
    }

    /// Re-folds `alpha` into the scaler and, in table mode, rebuilds the table over its
    /// domain. If the new table misses the bound, the scaler and the table are rebuilt at
    /// `old_alpha` (compilation is deterministic: the same bits as before) and the error is
    /// returned.
    pub(super) fn set_alpha(
        &mut self,
        name: &'static str,
        alpha: f32,
        old_alpha: f32,
        cfg: Option<&TableConfig>,
    ) -> Result<(), EstimatorError> {
        match self.kind {
            CoefKind::Const => Ok(()),
            CoefKind::Neural => {
                self.exact.set_alpha(alpha);
                Ok(())
            }
            CoefKind::Table => {
                let Some(cfg) = cfg else {
                    return Err(EstimatorError::Compile);
                };
                let (lo, hi) = self.table.domain();
                self.exact.set_alpha(alpha);
                let built = self
                    .table
                    .compile_into(&self.exact, lo, hi, cfg.max_rel_error, name);
                if let Err(e) = built {
                    self.exact.set_alpha(old_alpha);
                    self.table
                        .compile_into(&self.exact, lo, hi, cfg.max_rel_error, name)
                        .map_err(EstimatorError::Table)?;
                    return Err(EstimatorError::Table(e));
                }
                Ok(())
            }
        }
    }
}

/// One coefficient at a stage as a function of its state input: a constant (`f32`), a
/// table (`&Table1D`, read with [`Table1D::eval_finite`]: stage states are finite, bounded by
/// the divergence guard) or a compiled scaler (`&CompiledScaler`, exact mode).
pub(super) trait StateCoef {
    fn at(&self, u: f32) -> f32;
}

impl StateCoef for f32 {
    #[inline(always)]
    fn at(&self, _: f32) -> f32 {
        *self
    }
}

impl<const T: usize> StateCoef for &Table1D<T> {
    #[inline(always)]
    fn at(&self, u: f32) -> f32 {
        self.eval_finite(u)
    }
}

impl<const P: usize> StateCoef for &CompiledScaler<P> {
    #[inline(always)]
    fn at(&self, u: f32) -> f32 {
        self.eval(u)
    }
}

/// The coefficients at an RK stage from `b_fl(v_st)`, `k_pr(x_pr)` and the constant `b_pr`,
/// monomorphised per source so that every stage is inlined (the domain flag of table mode
/// is raised for the new state only, by the caller). A model with the lost-motion element
/// runs `K` = [`LostMotionK`] around its `k_pr` source, so that a model without it runs no
/// instruction of it.
pub(super) struct CoefStage<B, K> {
    pub(super) b_fl: B,
    pub(super) k_pr: K,
    pub(super) b_pr: f32,
}

impl<B: StateCoef, K: StateCoef> Stage for CoefStage<B, K> {
    #[inline(always)]
    fn coeffs(&mut self, s: &State) -> Coefficients {
        Coefficients {
            b_fl: self.b_fl.at(s.v_st_m_s),
            b_pr: self.b_pr,
            k_pr: self.k_pr.at(s.x_pr_m),
        }
    }
}

/// A `k_pr` source through the lost-motion element at the current level: `k_eff(k_l(x_pr),
/// x_pr)`.
#[derive(Clone, Copy)]
pub(super) struct LostMotionK<'a, K> {
    pub(super) k_l: K,
    pub(super) at: &'a LostMotionAt,
}

impl<K: StateCoef> StateCoef for LostMotionK<'_, K> {
    #[inline(always)]
    fn at(&self, x_pr: f32) -> f32 {
        self.at.k_eff(self.k_l.at(x_pr), x_pr)
    }
}

/// `k_pr` at `x_pr` through the lost-motion element `lm`, if any (the paths outside the
/// per-step stages).
#[inline(always)]
pub(super) fn k_pr_eff(k_pr: f32, x_pr: f32, lm: Option<&LostMotionAt>) -> f32 {
    match lm {
        None => k_pr,
        Some(a) => a.k_eff(k_pr, x_pr),
    }
}

/// Runs `$run` (an expression of `$stage`) with the `CoefStage` of `$b_fl`, `$k_pr`, `$b_pr`,
/// the `k_pr` source wrapped in [`LostMotionK`] when `$lm` (an `Option<&LostMotionAt>`) is
/// set: one monomorphised step per case, chosen once per step.
macro_rules! with_coef_stage {
    ($b_fl:expr, $k_pr:expr, $b_pr:expr, $lm:expr, |$stage:ident| $run:expr) => {
        match $lm {
            None => {
                let mut $stage = CoefStage {
                    b_fl: $b_fl,
                    k_pr: $k_pr,
                    b_pr: $b_pr,
                };
                $run
            }
            Some(at) => {
                let mut $stage = CoefStage {
                    b_fl: $b_fl,
                    k_pr: LostMotionK { k_l: $k_pr, at },
                    b_pr: $b_pr,
                };
                $run
            }
        }
    };
}
pub(super) use with_coef_stage;

/// Any runtime's coefficients through [`EmmRuntime::coeffs`] (mixes no model kind builds).
pub(super) struct RuntimeStage<'a, const P: usize, const T: usize>(pub(super) &'a EmmRuntime<P, T>);

impl<const P: usize, const T: usize> Stage for RuntimeStage<'_, P, T> {
    // Never runs for a model `Estimator::new` accepts: out of line, it costs no code size
    // in every step variant.
    #[inline(never)]
    fn coeffs(&mut self, s: &State) -> Coefficients {
        self.0.coeffs(s, &mut false)
    }
}

/// `repr(C)`: the per-step scalars first, then `b_fl` (whose table then starts within a few
/// dozen bytes), `k_pr`, and what only `set_alpha` reads.
#[derive(Debug, Clone)]
#[repr(C)]
pub(super) struct EmmRuntime<const P: usize, const T: usize> {
    pub(super) b_pr: f32,
    pub(super) inv_t_pr: f32,
    pub(super) integrator: Integrator,
    pub(super) h: StepSize,
    pub(super) x_limit: f32,
    pub(super) v_limit: f32,
    pub(super) b_fl: Coef<P, T>,
    pub(super) k_pr: Coef<P, T>,
    /// The table configuration in table mode.
    pub(super) table_cfg: Option<TableConfig>,
    /// Whether `b_pr` is `b_pr_ini * b_pr_scaler(alpha / alpha_scale)` (the NEMM) rather
    /// than the constant `b_pr_ini`.
    pub(super) b_pr_neural: bool,
    pub(super) b_pr_ini: f32,
    pub(super) alpha_scale: f32,
    /// The `b_pr(alpha)` scaler and its alpha branch, kept for `set_alpha`.
    pub(super) b_pr_scaler: Scaler<P>,
    pub(super) b_pr_branch: Option<AlphaBranch>,
    /// The model's lost-motion element and its value at the current level.
    pub(super) lost_motion: Option<(LostMotion, LostMotionAt)>,
}

impl<const P: usize, const T: usize> EmmRuntime<P, T> {
    pub(super) const fn empty() -> Self {
        Self {
            b_pr: 0.0,
            inv_t_pr: 0.0,
            integrator: Integrator::Rk4,
            h: StepSize {
                dt: 0.0,
                h2: 0.0,
                h6: 0.0,
            },
            x_limit: 0.0,
            v_limit: 0.0,
            b_fl: Coef::empty(),
            k_pr: Coef::empty(),
            table_cfg: None,
            b_pr_neural: false,
            b_pr_ini: 0.0,
            alpha_scale: 0.0,
            b_pr_scaler: Scaler::empty(),
            b_pr_branch: None,
            lost_motion: None,
        }
    }

    /// The lost-motion element at the current level, if the model has one.
    #[inline(always)]
    pub(super) fn lost_motion_at(&self) -> Option<&LostMotionAt> {
        self.lost_motion.as_ref().map(|(_, a)| a)
    }

    /// Moves the lost-motion element (if any) to level `alpha`.
    fn lost_motion_to(&mut self, alpha: f32) {
        if let Some((l, a)) = &mut self.lost_motion {
            *a = l.at(alpha);
        }
    }

    /// `b_pr` at `alpha`.
    pub(super) fn b_pr_at(&self, alpha: f32) -> Result<f32, EstimatorError> {
        if !self.b_pr_neural {
            return Ok(self.b_pr_ini);
        }
        b_pr_of(
            &self.b_pr_scaler,
            self.b_pr_branch.as_ref(),
            self.b_pr_ini,
            self.alpha_scale,
            alpha,
        )
        .ok_or(EstimatorError::Compile)
    }

    #[inline(always)]
    pub(super) fn coeffs(&self, s: &State, out: &mut bool) -> Coefficients {
        Coefficients {
            b_fl: self.b_fl.eval(s.v_st_m_s, out),
            b_pr: self.b_pr,
            k_pr: k_pr_eff(
                self.k_pr.eval(s.x_pr_m, out),
                s.x_pr_m,
                self.lost_motion_at(),
            ),
        }
    }

    /// One RK step from `x` (coefficients `c`) with the multiply-add `M` and the stage
    /// coefficients of `stage` (inlined at every stage), then the coefficients at the new
    /// state and the force there: table mode runs [`Unfused`] with the tables, exact mode
    /// [`Fused`] (the reference arithmetic) with the compiled scalers or constants.
    #[inline(always)]
    pub(super) fn run<M: MulAdd, S: Stage>(
        &self,
        stage: &mut S,
        x: &State,
        c: &Coefficients,
        u0: f32,
        u1: f32,
    ) -> (State, Coefficients, f32) {
        let x1 = integrator::step_with::<M, f32, S>(
            self.integrator,
            stage,
            c,
            self.inv_t_pr,
            x,
            u0,
            u1,
            &self.h,
        );
        let c1 = stage.coeffs(&x1);
        (x1, c1, emm::force_with::<M, f32>(&c1, &x1, u1))
    }

    /// One RK step from `x0` (coefficients `c0`) with inputs `u0` -> `u1`, then the
    /// coefficients and the force at the new state, with the stage coefficients of this
    /// runtime's kinds (dispatched once per step, not per coefficient evaluation): tables
    /// [`Unfused`], compiled scalers and constants [`Fused`] (the reference arithmetic).
    /// Sets `out` when the new state lies outside a table's domain.
    #[inline(always)]
    pub(super) fn advance(
        &self,
        x0: &State,
        c0: &Coefficients,
        u0: f32,
        u1: f32,
        out: &mut bool,
    ) -> (State, Coefficients, f32) {
        let b_pr = self.b_pr;
        let lost_motion = self.lost_motion_at();
        match (self.b_fl.kind, self.k_pr.kind) {
            (CoefKind::Table, CoefKind::Table) => {
                let (tb, tk) = (&self.b_fl.table, &self.k_pr.table);
                let r = with_coef_stage!(tb, tk, b_pr, lost_motion, |stage| self
                    .run::<Unfused, _>(&mut stage, x0, c0, u0, u1));
                *out = !(tb.contains(r.0.v_st_m_s) && tk.contains(r.0.x_pr_m));
                r
            }
            (CoefKind::Table, CoefKind::Const) => {
                let tb = &self.b_fl.table;
                let r =
                    with_coef_stage!(tb, self.k_pr.value, b_pr, lost_motion, |stage| self
                        .run::<Unfused, _>(&mut stage, x0, c0, u0, u1));
                *out = !tb.contains(r.0.v_st_m_s);
                r
            }
            // Exact mode: the reference (fused) arithmetic; the scalers out of line.
            (CoefKind::Neural, CoefKind::Neural) => {
                with_coef_stage!(
                    &self.b_fl.exact,
                    &self.k_pr.exact,
                    b_pr,
                    lost_motion,
                    |stage| self.run::<Fused, _>(&mut stage, x0, c0, u0, u1)
                )
            }
            (CoefKind::Neural, CoefKind::Const) => {
                with_coef_stage!(
                    &self.b_fl.exact,
                    self.k_pr.value,
                    b_pr,
                    lost_motion,
                    |stage| self.run::<Fused, _>(&mut stage, x0, c0, u0, u1)
                )
            }
            // The Linear EMM: constants, the reference (fused) arithmetic.
            (CoefKind::Const, CoefKind::Const) => {
                with_coef_stage!(
                    self.b_fl.value,
                    self.k_pr.value,
                    b_pr,
                    lost_motion,
                    |stage| self.run::<Fused, _>(&mut stage, x0, c0, u0, u1)
                )
            }
            // No model kind builds these mixes; any coefficient through `coeffs`.
            _ => {
                let r = self.run::<Fused, _>(&mut RuntimeStage(self), x0, c0, u0, u1);
                self.coeffs(&r.0, out);
                r
            }
        }
    }

    /// An exact-mode level change whose `b_pr` at `alpha` is known (an observer's bank
    /// member): folds `alpha` into the neural coefficients' scalers (first-layer biases and
    /// alpha branch) and takes `b_pr`, without evaluating `b_pr(alpha)` again.
    pub(super) fn fold_exact_alpha(&mut self, alpha: f32, b_pr: f32) {
        for c in [&mut self.b_fl, &mut self.k_pr] {
            if c.kind == CoefKind::Neural {
                c.exact.set_alpha(alpha);
            }
        }
        self.b_pr = b_pr;
        self.lost_motion_to(alpha);
    }

    /// Re-folds `alpha` into the neural coefficients and `b_pr`; in table mode rebuilds and
    /// checks the tables first and changes nothing if one misses the bound.
    pub(super) fn set_alpha(&mut self, alpha: f32, old_alpha: f32) -> Result<(), EstimatorError> {
        let b_pr = self.b_pr_at(alpha)?;
        let cfg = self.table_cfg;
        self.b_fl
            .set_alpha("b_fl", alpha, old_alpha, cfg.as_ref())?;
        if let Err(e) = self.k_pr.set_alpha("k_pr", alpha, old_alpha, cfg.as_ref()) {
            self.b_fl
                .set_alpha("b_fl", old_alpha, alpha, cfg.as_ref())?;
            return Err(e);
        }
        self.b_pr = b_pr;
        self.lost_motion_to(alpha);
        Ok(())
    }

    pub(super) fn tables(&self) -> impl Iterator<Item = &Table1D<T>> {
        [&self.b_fl, &self.k_pr].into_iter().filter_map(Coef::table)
    }
}

/// `b_pr = b_pr_ini * scaler(alpha / alpha_scale)` with the scaler's alpha branch; `None`
/// for an inconsistent shape.
pub(super) fn b_pr_of<const P: usize>(
    scaler: &Scaler<P>,
    branch: Option<&AlphaBranch>,
    b_pr_ini: f32,
    alpha_scale: f32,
    alpha: f32,
) -> Option<f32> {
    scaler
        .scale_with(&[alpha / alpha_scale], branch)
        .map(|s| b_pr_ini * s)
}

/// Which model an estimator runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum RuntimeKind {
    /// None yet ([`Estimator::empty`], or a [`Estimator::load`] that failed).
    Empty,
    /// The SEM map.
    Sem,
    /// An EMM variant.
    Emm,
}

/// Storage for every model kind (so that [`Estimator::load`] writes in place); `kind` says
/// which is in use. `repr(C)`: the EMM runtime first (short offsets on Arm), the SEM after.
#[derive(Debug, Clone)]
#[repr(C)]
pub(super) struct Runtime<const P: usize, const T: usize> {
    pub(super) kind: RuntimeKind,
    pub(super) emm: EmmRuntime<P, T>,
    pub(super) sem_map: SemMap,
    pub(super) sem_curve: heapless::Vec<f32, MAX_SEM_VELOCITIES>,
}
