//! A pack's inputs on the model grid: velocity, condition level, force, static-force
//! features and per-lane loss weight, packed from up to [`LANES`] windows.

use crate::train::adjoint::{
    static_force, Grid, Lanes, Real, RolloutParams, StaticParams, Window, WindowLanes, LANES,
    STATIC_PARAMS,
};

/// Inputs of one pack on the model grid: per model step the lanes' velocity (and condition
/// level when it varies within a window); per data sample the force and where the sample
/// lies on the model grid; per lane the weight of its squared error (0 for padding).
pub(super) struct PackData<T> {
    /// Velocity per model step.
    pub(super) u: Vec<WindowLanes<T>>,
    /// Constant condition level per lane (`alpha_steps` is `None`).
    alpha0: WindowLanes<T>,
    /// Condition level per model step when some lane's level changes within its window.
    alpha_steps: Option<Vec<WindowLanes<T>>>,
    /// Measured force per data sample (empty for a forward-only pack).
    pub(super) f: Vec<WindowLanes<T>>,
    /// [`Grid::sample_at`] of every data sample (empty when `identity`).
    pub(super) at: Vec<(usize, T)>,
    /// Every model step is a data sample ([`Grid::SAME`]).
    pub(super) identity: bool,
    pub(super) lane_w: WindowLanes<T>,
    /// With a static force: its features per model step
    /// (`nemm_kernels::static_force::features` at the step's position, velocity and level).
    pub(super) phi: Option<Vec<[WindowLanes<T>; STATIC_PARAMS]>>,
}

impl<T: Real> PackData<T> {
    /// The condition level of every lane at model step `j`.
    #[inline]
    pub(super) fn alpha(&self, j: usize) -> WindowLanes<T> {
        match &self.alpha_steps {
            Some(a) if j < a.len() => a[j],
            _ => self.alpha0,
        }
    }

    /// The static force of every lane at model step `j` (0 without one).
    #[inline]
    pub(super) fn static_at(&self, p: &RolloutParams<T>, j: usize) -> WindowLanes<T> {
        match (&self.phi, &p.static_force) {
            (Some(phi), Some(sp)) => Lanes(std::array::from_fn(|l| {
                (0..STATIC_PARAMS).fold(T::zero(), |r, q| r + sp.theta[q] * phi[j][q].0[l])
            })),
            _ => WindowLanes::default(),
        }
    }

    /// `true` if the condition level changes from step `j - 1` to step `j`.
    #[inline]
    pub(super) fn alpha_changes(&self, j: usize) -> bool {
        match &self.alpha_steps {
            Some(a) if j > 0 => a[j] != a[j - 1],
            _ => false,
        }
    }
}

/// Packs up to [`LANES`] windows of at most `samples` data samples onto the model grid.
/// Lanes past `windows.len()` repeat the first window with zero weight; a shorter window is
/// padded with zero input (its tail is not scored). `with_force` copies the forces.
pub(super) fn pack_data<T: Real>(
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
