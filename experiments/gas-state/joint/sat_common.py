"""J4 = J3 + saturating gas volume. Extension: dc/dt = g(alpha) softplus(u-u0) * max(0, 1 - c/c_max(alpha)),
c_max = cm0 + cm1*alpha (theta 16, 17 in mm, >= 0). Compression as J3. Everything else from common.py."""
import numpy as np
from numba import njit
import common as C
from common import bfl, SP, DT


@njit(cache=True)
def rhs4(s, u, p, cmax, out):
    xpr, vst, c = s[0], s[1], s[2]
    ueff = u
    dc = 0.0
    if u > 0.0:
        z = (u - p[8]) / SP
        sp = SP * (z + np.log1p(np.exp(-z))) if z > 0 else SP * np.log1p(np.exp(z))
        fr = 0.0
        if cmax > 1e-12:
            fr = 1.0 - c / cmax
            if fr < 0.0:
                fr = 0.0
        dc = p[7] * sp * fr
    else:
        cc = c if c > 0.0 else 0.0
        sh = cc / (cc + p[9])
        dc = u * sh
        ueff = u * (1.0 - sh)
    b = bfl(vst, p)
    q = (p[0] * xpr + p[1] * ueff) / (p[1] + b)
    out[0] = ueff - q
    out[1] = (q - vst) / p[2]
    out[2] = dc
    return b * q


@njit(cache=True)
def simulate4(u, p, cmax):
    n = u.shape[0]
    F = np.empty(n)
    Cc = np.empty(n)
    s = np.zeros(3); k1 = np.zeros(3); k2 = np.zeros(3); k3 = np.zeros(3); k4 = np.zeros(3); tmp = np.zeros(3)
    for i in range(n):
        F[i] = rhs4(s, u[i], p, cmax, k1)
        Cc[i] = s[2]
        if i == n - 1:
            break
        um = 0.5 * (u[i] + u[i + 1])
        for j in range(3):
            tmp[j] = s[j] + 0.5 * DT * k1[j]
        rhs4(tmp, um, p, cmax, k2)
        for j in range(3):
            tmp[j] = s[j] + 0.5 * DT * k2[j]
        rhs4(tmp, um, p, cmax, k3)
        for j in range(3):
            tmp[j] = s[j] + DT * k3[j]
        rhs4(tmp, u[i + 1], p, cmax, k4)
        for j in range(3):
            s[j] += DT / 6.0 * (k1[j] + 2 * k2[j] + 2 * k3[j] + k4[j])
        if s[2] < 0.0:
            s[2] = 0.0
        if not np.isfinite(s[0]) or not np.isfinite(s[1]):
            F[:] = np.nan
            return F, Cc
    return F, Cc


NAMES = C.NAMES + ["cm0 [mm]", "cm1 [mm]"]
ALPHA_ONLY = C.ALPHA_ONLY | {17}
LB = np.r_[C.LB, 0.0, 0.0]
UB = np.r_[C.UB, 50.0, 300.0]


def cmax_of(theta, alpha):
    return 1e-3 * (theta[16] + theta[17] * alpha)


def sim_run(theta, r, alpha=None):
    """Works for J1 (11), J3 (16) and J4 (18) theta vectors."""
    a = r["alpha"] if alpha is None else alpha
    if len(theta) <= 16:
        return C.sim_run(theta, r, a)
    p, _ = C.phys(theta[:16], a)
    return simulate4(r["u"], p, cmax_of(theta, a))


def run_resid(theta, r):
    F, _ = sim_run(theta, r)
    e = (F[r["idx"]] - r["F"][r["idx"]]) / C.FSCALE * r["w"]
    if not np.all(np.isfinite(e)):
        e = np.full(e.shape, 10.0 * r["w"])
    return e
