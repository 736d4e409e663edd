//! Reverse mode of the cumulative scaler (feature `reverse`): what the trainer's discrete
//! adjoint back-propagates through.

use super::*;
use crate::math::Scalar;

/// The difference quotients of a unit at `y = w x` (given `tanh(c)`, `tanh(y + c)` and
/// `h`): `D = dh/dy = (sech^2(y + c) - h) / y` and `E = dh/dc = (sech^2(y + c) - sech^2(c))
/// / y`, by their Taylor series in `y` for `|y| < 0.01`.
#[inline(always)]
fn quotients<L: Lane>(y: L, tc: L::Scalar, t1: L, h: L) -> (L, L) {
    let one = L::constant(1.0);
    let t = L::splat(tc);
    let psi = one - t * t;
    let psi1 = one - t1 * t1;
    // Derivatives of psi(u) = sech^2(u) at u = c (t' = psi).
    let d1 = L::constant(-2.0) * t * psi;
    let d2 = L::constant(4.0) * t * t * psi - L::constant(2.0) * psi * psi;
    let d3 = L::constant(16.0) * t * psi * psi - L::constant(8.0) * t * t * t * psi;
    let d4 = L::constant(16.0) * psi * psi * psi - L::constant(88.0) * t * t * psi * psi
        + L::constant(16.0) * t * t * t * t * psi;
    let d_series = d1 * L::constant(0.5)
        + y * (d2 * L::constant(1.0 / 3.0)
            + y * (d3 * L::constant(1.0 / 8.0) + y * d4 * L::constant(1.0 / 30.0)));
    let e_series = d1
        + y * (d2 * L::constant(0.5)
            + y * (d3 * L::constant(1.0 / 6.0) + y * d4 * L::constant(1.0 / 24.0)));
    let far = y * y - L::constant(SERIES_D * SERIES_D);
    let safe_y = L::select_nonneg(far, y, one);
    let d = L::select_nonneg(far, (psi1 - h) / safe_y, d_series);
    let e = L::select_nonneg(far, (psi1 - psi) / safe_y, e_series);
    (d, e)
}

impl<L: Lane> CumulativeFold<L> {
    /// Reverse mode of [`Self::mixture`] at `x` (the fold's level): adds `dL/dtheta` for the
    /// adjoint `mbar = dL/dm` of the mixture to `grad` (the flat layout of the module docs,
    /// summed over the lanes) and returns `dL/dx`. `view` must be the view the fold was made
    /// from. (For the scale `s`, `mbar = (s_max - s_min) dL/ds`.)
    pub fn mixture_backward(
        &self,
        view: &CumulativeView<'_, L::Scalar>,
        x: L,
        mbar: L,
        grad: &mut [L::Scalar],
    ) -> L {
        let k = self.units;
        let zero = L::default();
        let one = L::constant(1.0);
        // dL/dpi_j per lane.
        let mut pibar = [zero; MAX_CUMULATIVE_UNITS + 1];
        if let Some(p0) = pibar.first_mut() {
            *p0 = mbar;
        }
        let mut xbar = zero;
        let (ga, rest) = grad.split_at_mut((k + 1).min(grad.len()));
        let (gomega, rest) = rest.split_at_mut(k.min(rest.len()));
        let (gc, rest) = rest.split_at_mut(k.min(rest.len()));
        let (ggamma, gbeta) = rest.split_at_mut((k + 1).min(rest.len()));
        let units = self
            .w
            .iter()
            .zip(&self.c)
            .zip(&self.tc)
            .zip(self.pi.iter().skip(1))
            .zip(pibar.iter_mut().skip(1))
            .zip(gomega.iter_mut().zip(gc.iter_mut()));
        for (((((&w, &c), &tc), &pi), pib), (go, gcc)) in units.take(k) {
            let y = L::splat(w) * x;
            let (h, t1) = unit_mean(y, c, tc);
            let (d, e) = quotients(y, tc, t1, h);
            *pib = mbar * h;
            let mpi = mbar * pi;
            // d h / d omega = y D = sech^2(y + c) - h.
            *go = *go + L::sum(mpi * ((one - t1 * t1) - h));
            *gcc = *gcc + L::sum(mpi * e);
            xbar = L::fma(mpi * L::splat(w), d, xbar);
        }
        // pi_j = p_j g_j: the softmax's and the gates' adjoints.
        let mut pbar = [L::Scalar::from_f32(0.0); MAX_CUMULATIVE_UNITS + 1];
        let mut dot = L::Scalar::from_f32(0.0);
        for (j, pb) in pbar.iter_mut().enumerate().take(k + 1) {
            let (Some(&pij_bar), Some(&g), Some(&p)) = (pibar.get(j), self.g.get(j), self.p.get(j))
            else {
                continue;
            };
            *pb = L::sum(pij_bar * g);
            dot = dot + p * *pb;
            let ebar = pij_bar * L::splat(p) * g * (one - g);
            let gamma = view
                .gamma
                .get(j)
                .copied()
                .unwrap_or(L::Scalar::from_f32(0.0));
            let (_, du) = view.gate_slope(gamma);
            if let Some(gb) = gbeta.get_mut(j) {
                *gb = *gb + L::sum(ebar);
            }
            if let Some(gg) = ggamma.get_mut(j) {
                *gg = *gg + L::sum(ebar * self.alpha_n) * du;
            }
        }
        for ((ga, &p), &pb) in ga.iter_mut().zip(&self.p).zip(&pbar) {
            *ga = *ga + p * (pb - dot);
        }
        xbar
    }
}
