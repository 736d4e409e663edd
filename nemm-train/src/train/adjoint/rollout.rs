//! The rollout over packs of [`LANES`] windows and its exact discrete adjoint: the scalers
//! and coefficients over lanes, the pack's forward sweep with its records, the reverse sweep,
//! and the entry points ([`loss_and_grad`], [`simulate`], [`simulate_x_pr`]).

use super::*;

// ---------------------------------------------------------------------------------------
// Scalers over lanes: nemm-core's `ScalerView` (forward `raw`, reverse `raw_backward`)
// ---------------------------------------------------------------------------------------

/// One scaler over the lanes at the pack's condition level: nemm-core's view of its
/// weights ([`mlp::ScalerView`]) and its alpha level folded in ([`mlp::Folded`]).
#[derive(Debug, Clone)]
struct LaneScaler<'a, T> {
    view: mlp::ScalerView<'a, T>,
    fold: Box<mlp::Folded<WindowLanes<T>>>,
    /// The MLP's first input when it has no state input (`b_pr`: `alpha_n`, or 0 with a
    /// branch).
    x_alpha: WindowLanes<T>,
    /// The MLP's second input (`alpha_n`, or 0 with a branch).
    second: WindowLanes<T>,
    /// The branch's `alpha_n`.
    alpha_n: WindowLanes<T>,
}

impl<'a, T: Real> LaneScaler<'a, T> {
    fn new(s: &'a ScalerWeights<T>, alpha_n: WindowLanes<T>) -> Self {
        let direction = s.branch.map_or(Direction::None, |b| b.direction);
        let view = mlp::ScalerView::new(s.layout(), &s.w, direction)
            .expect("scaler weight count does not match its shape");
        let (x_alpha, second) = view.inputs(WindowLanes::default(), alpha_n);
        let fold = Box::new(
            view.fold::<Unfused, WindowLanes<T>>(second, alpha_n)
                .expect("consistent scaler shape"),
        );
        Self {
            view,
            fold,
            x_alpha,
            second,
            alpha_n,
        }
    }

    /// A record of the right size for this scaler.
    fn act(&self) -> Act<T> {
        let l = &self.view.layout;
        Act::new(l.hidden, l.layers, l.branch.map_or(0, |b| b.units))
    }

    /// Raw output `z` at first input `x`, recording into `rec` if given.
    #[inline]
    fn raw(&self, x: WindowLanes<T>, rec: Option<&mut Act<T>>) -> WindowLanes<T> {
        let z = match rec {
            None => self
                .view
                .raw::<Unfused, WindowLanes<T>>(&self.fold, x, None),
            Some(r) => {
                r.x0 = x;
                self.view
                    .raw::<Unfused, WindowLanes<T>>(&self.fold, x, Some(&mut r.tape_mut()))
            }
        };
        z.expect("consistent scaler shape")
    }

    /// Reverse mode of [`Self::raw`]: adds the weight gradients to `g` (the flat layout)
    /// and returns `dL/dx`.
    #[inline]
    fn backward(&self, rec: &Act<T>, zbar: WindowLanes<T>, g: &mut [T]) -> WindowLanes<T> {
        let (gm, gb) = g.split_at_mut(self.view.layout.mlp_len());
        self.view
            .raw_backward(&rec.tape(), rec.x0, self.second, self.alpha_n, zbar, gm, gb)
            .expect("consistent scaler shape")
    }
}

/// Activations of one scaler evaluation over the lanes (for the backward pass): the
/// storage of nemm-core's [`mlp::Tape`], the input and the sigmoid.
#[derive(Debug, Clone)]
struct Act<T> {
    /// The MLP's first input.
    x0: WindowLanes<T>,
    /// Normalised pre-activations `n = (h - mean) r`, `layers * H`.
    n: Vec<WindowLanes<T>>,
    /// `1 / sqrt(var + eps)`, per layer.
    r: Vec<WindowLanes<T>>,
    /// Activations after LeakyReLU, `layers * H`.
    a: Vec<WindowLanes<T>>,
    /// `sigmoid(z)`.
    sig: WindowLanes<T>,
    /// The alpha branch's pre-activations `t_k` (empty without a branch).
    bt: Vec<WindowLanes<T>>,
}

impl<T: Real> Act<T> {
    fn new(h: usize, layers: usize, units: usize) -> Self {
        Self {
            x0: WindowLanes::default(),
            n: vec![WindowLanes::default(); h * layers],
            r: vec![WindowLanes::default(); layers],
            a: vec![WindowLanes::default(); h * layers],
            sig: WindowLanes::default(),
            bt: vec![WindowLanes::default(); units],
        }
    }

    fn tape_mut(&mut self) -> mlp::TapeMut<'_, WindowLanes<T>> {
        mlp::TapeMut {
            n: &mut self.n,
            r: &mut self.r,
            a: &mut self.a,
            branch_t: &mut self.bt,
        }
    }

    fn tape(&self) -> mlp::Tape<'_, WindowLanes<T>> {
        mlp::Tape {
            n: &self.n,
            r: &self.r,
            a: &self.a,
            branch_t: &self.bt,
        }
    }
}

// ---------------------------------------------------------------------------------------
// Coefficients
// ---------------------------------------------------------------------------------------

/// A coefficient: constant `c0`, or `c0 (s_min + (s_max - s_min) sigmoid(z(state / scale,
/// alpha_n)))` (nemm-core's [`mlp::bounded`] with `lo = c0 s_min`, `span = c0 (s_max -
/// s_min)`).
struct Coef<'a, T> {
    c0: T,
    neural: Option<NeuralCoef<'a, T>>,
}

struct NeuralCoef<'a, T> {
    scaler: LaneScaler<'a, T>,
    s_min: T,
    span: T,
    inv_scale: T,
}

impl<'a, T: Real> Coef<'a, T> {
    fn new(c0: T, s: Option<&'a ScalerWeights<T>>, scale: T, alpha_n: WindowLanes<T>) -> Self {
        Self {
            c0,
            neural: s.map(|s| NeuralCoef {
                scaler: LaneScaler::new(s, alpha_n),
                s_min: s.s_min,
                span: s.s_max - s.s_min,
                inv_scale: T::one() / scale,
            }),
        }
    }

    fn act(&self) -> Option<Act<T>> {
        self.neural.as_ref().map(|n| n.scaler.act())
    }

    #[inline]
    fn eval(&self, x: WindowLanes<T>, mut rec: Option<&mut Act<T>>) -> WindowLanes<T> {
        match &self.neural {
            None => WindowLanes::splat(self.c0),
            Some(n) => {
                let x0 = x * WindowLanes::splat(n.inv_scale);
                let z = n.scaler.raw(x0, rec.as_deref_mut());
                let (p, sig) = self.bounded(n, z);
                if let Some(rec) = rec {
                    rec.sig = sig;
                }
                p
            }
        }
    }

    /// The output mapping of the neural coefficient `n` at raw output `z`: `(p, sigmoid)`.
    #[inline(always)]
    fn bounded(
        &self,
        n: &NeuralCoef<'_, T>,
        z: WindowLanes<T>,
    ) -> (WindowLanes<T>, WindowLanes<T>) {
        mlp::bounded::<Unfused, WindowLanes<T>>(
            z,
            WindowLanes::splat(self.c0 * n.s_min),
            WindowLanes::splat(self.c0 * n.span),
        )
    }

    /// Back-propagates `cbar = dL/d(coefficient)`; returns `dL/d(state component)`.
    #[inline]
    fn backward(
        &self,
        rec: Option<&Act<T>>,
        cbar: WindowLanes<T>,
        c0bar: &mut T,
        g: &mut [T],
    ) -> WindowLanes<T> {
        match (&self.neural, rec) {
            (Some(n), Some(rec)) => {
                *c0bar += WindowLanes::sum(
                    cbar * (WindowLanes::splat(n.s_min) + WindowLanes::splat(n.span) * rec.sig),
                );
                let zbar =
                    mlp::bounded_backward(rec.sig, WindowLanes::splat(self.c0 * n.span), cbar);
                n.scaler.backward(rec, zbar, g) * WindowLanes::splat(n.inv_scale)
            }
            _ => {
                *c0bar += WindowLanes::sum(cbar);
                WindowLanes::default()
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// Pack rollout
// ---------------------------------------------------------------------------------------

/// A state over the lanes (or its adjoint).
type LaneState<T> = State<WindowLanes<T>>;
/// Coefficient values at one state over the lanes (or their adjoints).
type LaneCoefficients<T> = Coefficients<WindowLanes<T>>;

/// Where to record the activations of the `b_fl` and `k_pr` evaluations.
type ActPair<'r, T> = (&'r mut Option<Act<T>>, &'r mut Option<Act<T>>);

/// The `b_pr(alpha)` scaler of a pack: its MLP, alpha branch, activations and output
/// bounds.
struct BprRecord<'a, T> {
    scaler: LaneScaler<'a, T>,
    act: Act<T>,
    s_min: T,
    span: T,
}

/// Everything fixed for one pack (a batch of windows advanced in lock step).
struct Pack<'a, T> {
    /// The `b_fl(v_st, alpha)` coefficient at the pack's levels.
    b_fl: Coef<'a, T>,
    /// The `k_pr(x_pr, alpha)` coefficient at the pack's levels.
    k_pr: Coef<'a, T>,
    /// `b_pr(alpha)` per lane (constant over a window).
    b_pr: WindowLanes<T>,
    /// The `b_pr(alpha)` scaler's evaluation, for its backward pass.
    b_pr_record: Option<BprRecord<'a, T>>,
    /// `1 / T_pr`.
    inv_t_pr: T,
    integrator: Integrator,
    /// The model step `dt` and its fractions.
    step_size: StepSize<WindowLanes<T>>,
}

impl<'a, T: Real> Pack<'a, T> {
    fn new(p: &'a RolloutParams<T>, alphas: WindowLanes<T>) -> Self {
        let alpha_n = alphas / WindowLanes::splat(p.alpha_scale);
        let (bp, b_pr_record) = match &p.b_pr {
            None => (WindowLanes::splat(p.b_pr0), None),
            Some(s) => {
                let scaler = LaneScaler::new(s, alpha_n);
                let mut act = scaler.act();
                let z = scaler.raw(scaler.x_alpha, Some(&mut act));
                let span = s.s_max - s.s_min;
                let (bp, sig) = mlp::bounded::<Unfused, WindowLanes<T>>(
                    z,
                    WindowLanes::splat(p.b_pr0 * s.s_min),
                    WindowLanes::splat(p.b_pr0 * span),
                );
                act.sig = sig;
                (
                    bp,
                    Some(BprRecord {
                        scaler,
                        act,
                        s_min: s.s_min,
                        span,
                    }),
                )
            }
        };
        Self {
            b_fl: Coef::new(p.b_fl0, p.b_fl.as_ref(), p.v_scale, alpha_n),
            k_pr: Coef::new(p.k0, p.k_pr.as_ref(), p.x_scale, alpha_n),
            b_pr: bp,
            b_pr_record,
            inv_t_pr: T::one() / p.t_pr,
            integrator: p.integrator,
            step_size: StepSize::splat(p.dt),
        }
    }

    #[inline]
    fn coeffs(&self, s: &LaneState<T>, rec: Option<ActPair<'_, T>>) -> LaneCoefficients<T> {
        let (bf, k) = match rec {
            None => (
                self.b_fl.eval(s.v_st_m_s, None),
                self.k_pr.eval(s.x_pr_m, None),
            ),
            Some((rb, rk)) => (
                self.b_fl.eval(s.v_st_m_s, rb.as_mut()),
                self.k_pr.eval(s.x_pr_m, rk.as_mut()),
            ),
        };
        Coefficients {
            b_fl: bf,
            b_pr: self.b_pr,
            k_pr: k,
        }
    }

    /// One RK step from `s` (coefficients `c1`) with inputs `u0` -> `u1`: nemm-core's
    /// [`integrator::step_with`] over the lanes, unfused.
    fn step(
        &self,
        s: &LaneState<T>,
        c1: &LaneCoefficients<T>,
        u0: WindowLanes<T>,
        u1: WindowLanes<T>,
    ) -> LaneState<T> {
        integrator::step_with::<Unfused, WindowLanes<T>, _>(
            self.integrator,
            &mut PackStage { pk: self },
            c1,
            WindowLanes::splat(self.inv_t_pr),
            s,
            u0,
            u1,
            &self.step_size,
        )
    }
}

/// The stage coefficients of a pack's forward step (no record).
struct PackStage<'p, 'a, T> {
    pk: &'p Pack<'a, T>,
}

impl<T: Real> Stage<WindowLanes<T>> for PackStage<'_, '_, T> {
    #[inline(always)]
    fn coeffs(&mut self, s: &LaneState<T>) -> LaneCoefficients<T> {
        self.pk.coeffs(s, None)
    }
}

/// Adjoint accumulators of one pack.
struct PackAdjoint<T> {
    g: RolloutGrads<T>,
    /// dL/d b_pr per lane (b_pr is constant over a window).
    b_pr: WindowLanes<T>,
}

/// Activation records of the `b_fl` and `k_pr` scalers at one state.
type RecPair<T> = (Option<Act<T>>, Option<Act<T>>);

/// The stage coefficients of a pack's step for [`integrator::step_backward`]: stages 2..=4
/// record their scalers' activations and back-propagate through them.
struct PackStagesBack<'p, 'a, T> {
    pk: &'p Pack<'a, T>,
    bar: &'p mut PackAdjoint<T>,
    recs: &'p mut [RecPair<T>; 3],
}

impl<T: Real> StageBackward<WindowLanes<T>> for PackStagesBack<'_, '_, T> {
    #[inline(always)]
    fn coeffs(&mut self, i: usize, s: &LaneState<T>) -> LaneCoefficients<T> {
        let (rb, rk) = &mut self.recs[i - 2];
        self.pk.coeffs(s, Some((rb, rk)))
    }

    #[inline(always)]
    fn backward(&mut self, i: usize, cbar: &LaneCoefficients<T>, sbar: &mut LaneState<T>) {
        let (rb, rk) = &self.recs[i - 2];
        self.pk.coef_backward(rb, rk, cbar, sbar, self.bar);
    }
}

impl<T: Real> Pack<'_, T> {
    /// Back-propagates coefficient adjoints through the scalers at the recorded state (and
    /// `b_pr`'s into its per-lane accumulator).
    #[inline]
    fn coef_backward(
        &self,
        rb: &Option<Act<T>>,
        rk: &Option<Act<T>>,
        cbar: &LaneCoefficients<T>,
        sbar: &mut LaneState<T>,
        bar: &mut PackAdjoint<T>,
    ) {
        let xv = self
            .b_fl
            .backward(rb.as_ref(), cbar.b_fl, &mut bar.g.b_fl0, &mut bar.g.b_fl);
        let xx = self
            .k_pr
            .backward(rk.as_ref(), cbar.k_pr, &mut bar.g.k0, &mut bar.g.k_pr);
        sbar.v_st_m_s = sbar.v_st_m_s + xv;
        sbar.x_pr_m = sbar.x_pr_m + xx;
        bar.b_pr = bar.b_pr + cbar.b_pr;
    }
}

/// Inputs of one pack on the model grid: per model step the lanes' velocity (and condition
/// level when it varies within a window); per data sample the force and where the sample
/// lies on the model grid; per lane the weight of its squared error (0 for padding).
struct PackData<T> {
    /// Velocity per model step.
    u: Vec<WindowLanes<T>>,
    /// Constant condition level per lane (`alpha_steps` is `None`).
    alpha0: WindowLanes<T>,
    /// Condition level per model step when some lane's level changes within its window.
    alpha_steps: Option<Vec<WindowLanes<T>>>,
    /// Measured force per data sample (empty for a forward-only pack).
    f: Vec<WindowLanes<T>>,
    /// [`Grid::sample_at`] of every data sample (empty when `identity`).
    at: Vec<(usize, T)>,
    /// Every model step is a data sample ([`Grid::SAME`]).
    identity: bool,
    lane_w: WindowLanes<T>,
    /// With a static force: its features per model step
    /// (`nemm_core::semantics::static_force::features` at the step's position, velocity and level).
    phi: Option<Vec<[WindowLanes<T>; STATIC_PARAMS]>>,
}

impl<T: Real> PackData<T> {
    /// The condition level of every lane at model step `j`.
    #[inline]
    fn alpha(&self, j: usize) -> WindowLanes<T> {
        match &self.alpha_steps {
            Some(a) if j < a.len() => a[j],
            _ => self.alpha0,
        }
    }

    /// The static force of every lane at model step `j` (0 without one).
    #[inline]
    fn static_at(&self, p: &RolloutParams<T>, j: usize) -> WindowLanes<T> {
        match (&self.phi, &p.static_force) {
            (Some(phi), Some(sp)) => Lanes(std::array::from_fn(|l| {
                (0..STATIC_PARAMS).fold(T::zero(), |r, q| r + sp.theta[q] * phi[j][q].0[l])
            })),
            _ => WindowLanes::default(),
        }
    }

    /// `true` if the condition level changes from step `j - 1` to step `j`.
    #[inline]
    fn alpha_changes(&self, j: usize) -> bool {
        match &self.alpha_steps {
            Some(a) if j > 0 => a[j] != a[j - 1],
            _ => false,
        }
    }
}

/// Packs up to [`LANES`] windows of at most `samples` data samples onto the model grid.
/// Lanes past `windows.len()` repeat the first window with zero weight; a shorter window is
/// padded with zero input (its tail is not scored). `with_force` copies the forces.
fn pack_data<T: Real>(
    windows: &[&Window<'_>],
    grid: &Grid,
    samples: usize,
    with_force: bool,
    stat: Option<&StaticParams<T>>,
) -> PackData<T> {
    let n = grid.steps(samples);
    let mut u = vec![WindowLanes::default(); n];
    let mut f = if with_force {
        vec![WindowLanes::default(); samples]
    } else {
        Vec::new()
    };
    let mut lane_w = WindowLanes::<T>::default();
    let mut alpha0 = WindowLanes::<T>::default();
    let varying = windows.iter().any(|w| w.alphas.is_some());
    let mut alpha_steps = varying.then(|| vec![WindowLanes::default(); n]);
    let identity = *grid == Grid::SAME;
    let mut phi = stat.map(|_| vec![[WindowLanes::default(); STATIC_PARAMS]; n]);
    // Per model step, the sample position of its input (shared by the lanes).
    let inputs: Vec<(usize, f64)> = if identity {
        Vec::new()
    } else {
        (0..n).map(|j| grid.input_at(j)).collect()
    };
    for k in 0..LANES {
        let (win, wgt) = match windows.get(k) {
            Some(w) => (w, T::one()),
            None => (&windows[0], T::zero()),
        };
        lane_w.0[k] = wgt;
        alpha0.0[k] = T::c(f64::from(win.alpha));
        let len = win.u.len();
        if identity {
            for (uj, &v) in u.iter_mut().zip(win.u) {
                uj.0[k] = T::c(f64::from(v));
            }
        } else {
            for (j, &(i, _)) in inputs.iter().enumerate() {
                if i < len {
                    u[j].0[k] = T::c(grid.interpolate(win.u, j));
                }
            }
        }
        if let Some(a) = alpha_steps.as_mut() {
            for (j, aj) in a.iter_mut().enumerate() {
                aj.0[k] = match (win.alphas, identity) {
                    (Some(x), true) => T::c(f64::from(x[j.min(x.len().saturating_sub(1))])),
                    (Some(x), false) => T::c(grid.interpolate(x, j)),
                    (None, _) => alpha0.0[k],
                };
            }
        }
        for (i, fi) in f.iter_mut().enumerate().take(win.f.len()) {
            fi.0[k] = T::c(f64::from(win.f[i]));
        }
        if let (Some(phi), Some(sp)) = (phi.as_mut(), stat) {
            let phi: &mut Vec<[WindowLanes<T>; STATIC_PARAMS]> = phi;
            for (j, pj) in phi.iter_mut().enumerate() {
                let x = match win.x {
                    Some(x) if identity => x.get(j).map_or(sp.x_ref, |&v| T::c(f64::from(v))),
                    Some(x) => T::c(grid.interpolate(x, j)),
                    None => sp.x_ref,
                };
                let a = match &alpha_steps {
                    Some(a) => a[j].0[k],
                    None => alpha0.0[k],
                };
                let f = static_force::features(sp.x_ref, sp.v_c, x, u[j].0[k], a);
                for q in 0..STATIC_PARAMS {
                    pj[q].0[k] = f[q];
                }
            }
        }
    }
    PackData {
        u,
        alpha0,
        alpha_steps,
        f,
        at: if identity {
            Vec::new()
        } else {
            (0..samples)
                .map(|k| {
                    let (j, w) = grid.sample_at(k);
                    (j, T::c(w))
                })
                .collect()
        },
        identity,
        lane_w,
        phi,
    }
}

/// Forward sweep over the model grid: states after every step (index 0 = rest, before step
/// 0) and forces per step. A step whose condition level changed re-folds it (a new [`Pack`])
/// and re-evaluates the coefficients at the step's start state with it, as
/// `nemm_core::Estimator::set_alpha` does.
fn forward_sweep<T: Real>(
    p: &RolloutParams<T>,
    d: &PackData<T>,
) -> (Vec<LaneState<T>>, Vec<WindowLanes<T>>) {
    let n = d.u.len();
    let mut pk = Pack::new(p, d.alpha(0));
    let mut states = Vec::with_capacity(n + 1);
    let mut ys = Vec::with_capacity(n);
    let mut s = LaneState::default();
    let mut c = pk.coeffs(&s, None);
    let mut u_prev = WindowLanes::default();
    states.push(s);
    for (j, u) in d.u.iter().enumerate() {
        if d.alpha_changes(j) {
            pk = Pack::new(p, d.alpha(j));
            c = pk.coeffs(&s, None);
        }
        s = pk.step(&s, &c, u_prev, *u);
        c = pk.coeffs(&s, None);
        let r = d.static_at(p, j);
        let y = emm::force_with::<Unfused, WindowLanes<T>>(&c, &s, *u);
        ys.push(y + r);
        states.push(s);
        u_prev = *u;
    }
    (states, ys)
}

/// The forces of a forward sweep at the data samples (output interpolation of [`Grid`]).
fn at_samples<T: Real>(d: &PackData<T>, ys: &[WindowLanes<T>]) -> Vec<WindowLanes<T>> {
    if d.identity {
        return ys.to_vec();
    }
    d.at.iter()
        .map(|&(j, w)| {
            if w == T::zero() {
                ys[j]
            } else {
                let (a, b) = (ys[j], ys[j + 1]);
                Lanes(std::array::from_fn(|k| a.0[k] + w * (b.0[k] - a.0[k])))
            }
        })
        .collect()
}

/// Back-propagates the accumulated `dL/d b_pr` of the current condition level through the
/// `b_pr(alpha)` scaler (or into `b_pr,ini`) and clears it.
fn bpr_backward<T: Real>(p: &RolloutParams<T>, pk: &Pack<'_, T>, bar: &mut PackAdjoint<T>) {
    let bp_bar = bar.b_pr.0;
    match &pk.b_pr_record {
        None => bar.g.b_pr0 += WindowLanes::sum(bar.b_pr),
        Some(BprRecord {
            scaler,
            act,
            s_min,
            span,
        }) => {
            for k in 0..LANES {
                bar.g.b_pr0 += bp_bar[k] * (*s_min + *span * act.sig.0[k]);
            }
            let zbar =
                mlp::bounded_backward(act.sig, WindowLanes::splat(p.b_pr0 * *span), bar.b_pr);
            // No state input: the input's adjoint is not used.
            let _ = scaler.backward(act, zbar, &mut bar.g.b_pr);
        }
    }
    bar.b_pr = WindowLanes::splat(T::zero());
}

/// Loss sum (unnormalised) and gradient of one pack. `ybar_scale` is `2 / (F_s^2 M)`;
/// samples before `warmup` are not scored.
fn pack_loss_grad<T: Real>(
    p: &RolloutParams<T>,
    d: &PackData<T>,
    warmup: usize,
    inv_fs: T,
    ybar_scale: T,
) -> (T, RolloutGrads<T>) {
    let n = d.u.len();
    let mut pk = Pack::new(p, d.alpha(n.saturating_sub(1)));
    let (states, ys) = forward_sweep(p, d);
    // The loss at the data samples and its adjoint per model step: formed here on a
    // coarser data grid, inline in the reverse sweep when every step is a sample.
    let mut loss = T::zero();
    let sample_loss = |y: &WindowLanes<T>, f: &WindowLanes<T>, loss: &mut T| -> WindowLanes<T> {
        Lanes(std::array::from_fn(|l| {
            let e = (y.0[l] - f.0[l]) * d.lane_w.0[l];
            let en = e * inv_fs;
            *loss += en * en;
            ybar_scale * e
        }))
    };
    let on_grid: Option<(Vec<WindowLanes<T>>, Vec<bool>)> = (!d.identity).then(|| {
        let mut ybar = vec![WindowLanes::<T>::default(); n];
        let mut scored = vec![false; n];
        for (k, (y, f)) in at_samples(d, &ys).iter().zip(&d.f).enumerate().skip(warmup) {
            let (j, wgt) = d.at[k];
            let g = sample_loss(y, f, &mut loss);
            if wgt == T::zero() {
                ybar[j] = ybar[j] + g;
                scored[j] = true;
            } else {
                ybar[j] = ybar[j] + WindowLanes::splat(T::one() - wgt) * g;
                ybar[j + 1] = ybar[j + 1] + WindowLanes::splat(wgt) * g;
                scored[j] = true;
                scored[j + 1] = true;
            }
        }
        (ybar, scored)
    });
    let mut bar = PackAdjoint {
        g: RolloutGrads::zeros(p),
        b_pr: WindowLanes::splat(T::zero()),
    };
    let it = WindowLanes::splat(pk.inv_t_pr);
    // dL/d(1/T_pr) per lane.
    let mut it_bar = WindowLanes::<T>::splat(T::zero());
    // Reverse sweep. `sbar` is dL/ds_n (direct paths so far); `cbar_n` the coefficient
    // adjoint at s_n from stage 1 of step n+1; `rb_n`/`rk_n` the activations at s_n.
    let mut sbar = LaneState::<T>::default();
    let mut cbar_n = LaneCoefficients::<T>::default();
    let (mut rb_n, mut rk_n) = (pk.b_fl.act(), pk.k_pr.act());
    let mut have_rec_n = false;
    let (mut rb1, mut rk1) = (pk.b_fl.act(), pk.k_pr.act());
    let mut recs: [RecPair<T>; 3] = std::array::from_fn(|_| (pk.b_fl.act(), pk.k_pr.act()));
    for i in (0..n).rev() {
        let s_n = states[i + 1];
        let s_p = states[i];
        let u1 = d.u[i];
        let u0 = if i == 0 {
            WindowLanes::default()
        } else {
            d.u[i - 1]
        };
        // Coefficients at s_n with activations (carried from the previous iteration's stage 1).
        let c_n = if have_rec_n {
            pk.coeffs_from_rec(&rb_n, &rk_n)
        } else {
            pk.coeffs(&s_n, Some((&mut rb_n, &mut rk_n)))
        };
        // Output y_i = F(s_n, u_i).
        let ybar_i = match &on_grid {
            Some((ybar, scored)) => scored[i].then(|| ybar[i]),
            None => (i >= warmup).then(|| sample_loss(&ys[i], &d.f[i], &mut loss)),
        };
        if let (Some(yb), Some(phi)) = (&ybar_i, &d.phi) {
            for (q, gq) in bar.g.static_force.iter_mut().enumerate() {
                *gq += (0..LANES).fold(T::zero(), |a, l| a + yb.0[l] * phi[i][q].0[l]);
            }
        }
        if let Some(yb) = ybar_i {
            emm::force_backward::<Unfused, WindowLanes<T>>(
                &c_n,
                &s_n,
                u1,
                yb,
                &mut sbar,
                &mut cbar_n,
            );
        }
        // Scalers at s_n: complete dL/ds_n.
        pk.coef_backward(&rb_n, &rk_n, &cbar_n, &mut sbar, &mut bar);
        // Step i: s_p -> s_n, its stages recomputed with activations.
        let c1 = pk.coeffs(&s_p, Some((&mut rb1, &mut rk1)));
        let mut sbar_p = LaneState::<T>::default();
        let mut cbar1 = LaneCoefficients::<T>::default();
        integrator::step_backward::<Unfused, WindowLanes<T>, _>(
            pk.integrator,
            &mut PackStagesBack {
                pk: &pk,
                bar: &mut bar,
                recs: &mut recs,
            },
            &c1,
            it,
            &s_p,
            u0,
            u1,
            &pk.step_size,
            &sbar,
            &mut sbar_p,
            &mut cbar1,
            &mut it_bar,
        );
        // Move to s_p: its activations are rb1/rk1, its coefficient adjoint cbar1.
        sbar = sbar_p;
        cbar_n = cbar1;
        std::mem::swap(&mut rb_n, &mut rb1);
        std::mem::swap(&mut rk_n, &mut rk1);
        have_rec_n = true;
        if d.alpha_changes(i) {
            // Step i ran at its own level: its stage-1 coefficients at s_p go back through
            // that level's scalers, and so does b_pr's adjoint so far; step i - 1 (and the
            // output at s_p) ran at the previous level.
            pk.coef_backward(&rb_n, &rk_n, &cbar_n, &mut sbar, &mut bar);
            cbar_n = LaneCoefficients::<T>::default();
            bpr_backward(p, &pk, &mut bar);
            pk = Pack::new(p, d.alpha(i - 1));
            have_rec_n = false;
        }
    }
    // s_{-1} is the fixed rest state: its adjoint is dropped, but the coefficients there
    // depend on the weights.
    let mut sdummy = LaneState::default();
    pk.coef_backward(&rb_n, &rk_n, &cbar_n, &mut sdummy, &mut bar);
    // b_pr: constant over the window (or since its last change).
    bpr_backward(p, &pk, &mut bar);
    // T_pr from 1/T_pr.
    bar.g.t_pr = -WindowLanes::sum(it_bar) * pk.inv_t_pr * pk.inv_t_pr;
    (loss, bar.g)
}

impl<T: Real> Pack<'_, T> {
    /// Coefficient values from recorded activations (no recomputation).
    fn coeffs_from_rec(&self, rb: &Option<Act<T>>, rk: &Option<Act<T>>) -> LaneCoefficients<T> {
        let val = |c: &Coef<'_, T>, r: &Option<Act<T>>| -> WindowLanes<T> {
            match (&c.neural, r) {
                (Some(n), Some(r)) => Unfused::mul_add(
                    WindowLanes::splat(c.c0 * n.span),
                    r.sig,
                    WindowLanes::splat(c.c0 * n.s_min),
                ),
                _ => WindowLanes::splat(c.c0),
            }
        };
        Coefficients {
            b_fl: val(&self.b_fl, rb),
            b_pr: self.b_pr,
            k_pr: val(&self.k_pr, rk),
        }
    }
}

/// Checks that all windows have the same length and returns it.
fn common_len(windows: &[Window<'_>]) -> usize {
    let n = windows.first().map_or(0, |w| w.u.len());
    assert!(
        windows.iter().all(|w| w.u.len() == n
            && w.f.len() == n
            && w.alphas.is_none_or(|a| a.len() == n)
            && w.x.is_none_or(|x| x.len() == n)),
        "all windows of a batch must have the same length"
    );
    n
}

/// Normalised MSE loss (eq. 23) over `windows` and its exact gradient. The model integrates
/// on `grid`'s model steps and is scored at the data samples from sample `warmup` on (see
/// [`Grid`]). Returns `(loss, gradient)`; packs of [`LANES`] windows run in parallel.
pub fn loss_and_grad<T: Real>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
    warmup: usize,
    force_scale: f64,
) -> (f64, RolloutGrads<T>) {
    let n = common_len(windows);
    if n <= warmup || windows.is_empty() {
        return (0.0, RolloutGrads::zeros(p));
    }
    let m = (windows.len() * (n - warmup)) as f64;
    let inv_fs = T::c(1.0 / force_scale);
    let ybar_scale = T::c(2.0 / (force_scale * force_scale * m));
    let refs: Vec<&Window<'_>> = windows.iter().collect();
    let results: Vec<(T, RolloutGrads<T>)> = refs
        .par_chunks(LANES)
        .map(|chunk| {
            let d = pack_data::<T>(chunk, grid, n, true, p.static_force.as_ref());
            pack_loss_grad(p, &d, warmup, inv_fs, ybar_scale)
        })
        .collect();
    let mut g = RolloutGrads::zeros(p);
    let mut loss = 0.0f64;
    for (l, gi) in &results {
        loss += l.to_f64().unwrap_or(f64::NAN);
        g.add(gi);
    }
    (loss / m, g)
}

/// Runs every window from rest on `grid` and returns, per window, `out` of the forward
/// sweep's forces and states at the window's data samples.
fn sweep_windows<T: Real, R: Send>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
    out: impl Fn(&PackData<T>, &[LaneState<T>], &[WindowLanes<T>], usize, usize) -> R + Sync,
) -> Vec<R> {
    let refs: Vec<&Window<'_>> = windows.iter().collect();
    refs.par_chunks(LANES)
        .flat_map_iter(|chunk| {
            let samples = chunk.iter().map(|w| w.u.len()).max().unwrap_or(0);
            let d = pack_data::<T>(chunk, grid, samples, false, p.static_force.as_ref());
            let (states, ys) = forward_sweep(p, &d);
            chunk
                .iter()
                .enumerate()
                .map(|(k, w)| out(&d, &states, &ys, k, w.u.len()))
                .collect::<Vec<_>>()
        })
        .collect()
}

/// Simulated forces of every window at its data samples (same semantics as the estimator
/// at the model step; see [`Grid`] for the samples), one vector per window.
pub fn simulate<T: Real>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
) -> Vec<Vec<f64>> {
    sweep_windows(p, windows, grid, |d, _, ys, k, len| {
        at_samples(d, ys)
            .iter()
            .take(len)
            .map(|y| y.0[k].to_f64().unwrap_or(f64::NAN))
            .collect()
    })
}

/// Simulated states `x_pr` of every window at its data samples (for the `x_pr`
/// normalisation scale).
pub fn simulate_x_pr<T: Real>(
    p: &RolloutParams<T>,
    windows: &[Window<'_>],
    grid: &Grid,
) -> Vec<Vec<f64>> {
    sweep_windows(p, windows, grid, |d, states, _, k, len| {
        let x: Vec<WindowLanes<T>> = states.iter().skip(1).map(|s| s.x_pr_m).collect();
        at_samples(d, &x)
            .iter()
            .take(len)
            .map(|y| y.0[k].to_f64().unwrap_or(f64::NAN))
            .collect()
    })
}
