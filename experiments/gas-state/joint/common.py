"""Shared code: data loading, numba RK4 EMM (+ optional cascade gas filter), joint alpha-affine parameterisation.
Reuses the proto-cav conventions (central difference + 500 Hz zero-phase Butterworth, RK4 10 kHz, midpoint input,
side-blended b_fl, M3 cavity law)."""
import os
os.environ.setdefault("OMP_NUM_THREADS", "1"); os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")
import re
import numpy as np
from scipy.signal import butter, filtfilt
from numba import njit

BENCH = os.environ.get("NEMM_BENCH", "out/bench")
DT = 1e-4
T0 = 0.3
FSCALE = 2000.0
DEC = 10          # residual decimation
VBL = 1e-3
SP = 5e-3


def manifest():
    txt = open(f"{BENCH}/manifest.toml").read()
    runs = []
    for blk in txt.split("[[runs]]")[1:]:
        d = {}
        for line in blk.strip().splitlines():
            m = re.match(r'\s*(\w+)\s*=\s*(.+)$', line)
            if m:
                v = m.group(2).strip()
                d[m.group(1)] = v.strip('"') if v.startswith('"') else float(v)
        runs.append(d)
    return runs


def load(entry):
    d = np.loadtxt(f"{BENCH}/{entry['file']}", delimiter=",", skiprows=1)
    t, x, F = d[:, 0], d[:, 1], d[:, 2]
    u_raw = np.gradient(x, t)
    b, a = butter(2, 500.0 / (0.5 / DT))
    u = filtfilt(b, a, u_raw)
    name = os.path.basename(entry["file"])[:-4]
    cond = name.split("_", 1)[1]
    mask = t >= T0
    idx = np.nonzero(mask)[0][::DEC]
    return dict(t=t, x=x, F=F, u=u, mask=mask, idx=idx, name=name, cond=cond,
                alpha=float(entry["oil_loss"]), amp=float(entry["amplitude_m"]),
                w=1.0 / np.sqrt(len(idx)))


def load_all():
    return [load(e) for e in manifest()]


# kernel parameter layout: 0 k 1 bpr 2 Tpr 3 bext0 4 bext1 5 bcmp0 6 bcmp1 7 g 8 u0 9 c0 ; gas flag
@njit(cache=True)
def bfl(v, p):
    w = 0.5 * (1.0 + np.tanh(v / VBL))
    av = abs(v)
    return w * p[3] / (1.0 + p[4] * av) + (1.0 - w) * p[5] / (1.0 + p[6] * av)


@njit(cache=True)
def rhs(s, u, p, gas, out):
    xpr, vst, c = s[0], s[1], s[2]
    ueff = u
    dc = 0.0
    if gas:
        if u > 0.0:
            z = (u - p[8]) / SP
            sp = SP * (z + np.log1p(np.exp(-z))) if z > 0 else SP * np.log1p(np.exp(z))
            dc = p[7] * sp
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
def simulate(u, p, gas):
    n = u.shape[0]
    F = np.empty(n)
    C = np.empty(n)
    s = np.zeros(3); k1 = np.zeros(3); k2 = np.zeros(3); k3 = np.zeros(3); k4 = np.zeros(3); tmp = np.zeros(3)
    for i in range(n):
        F[i] = rhs(s, u[i], p, gas, k1)
        C[i] = s[2]
        if i == n - 1:
            break
        um = 0.5 * (u[i] + u[i + 1])
        for j in range(3):
            tmp[j] = s[j] + 0.5 * DT * k1[j]
        rhs(tmp, um, p, gas, k2)
        for j in range(3):
            tmp[j] = s[j] + 0.5 * DT * k2[j]
        rhs(tmp, um, p, gas, k3)
        for j in range(3):
            tmp[j] = s[j] + DT * k3[j]
        rhs(tmp, u[i + 1], p, gas, k4)
        for j in range(3):
            s[j] += DT / 6.0 * (k1[j] + 2 * k2[j] + 2 * k3[j] + k4[j])
        if s[2] < 0.0:
            s[2] = 0.0
        if not np.isfinite(s[0]) or not np.isfinite(s[1]):
            F[:] = np.nan
            return F, C
    return F, C


# ---------------- joint parameterisation
# theta J1 (11): 0 ln k0, 1 k_a, 2 ln bpr0, 3 bpr_a, 4 ln Tpr, 5 ln bext0_0, 6 bext0_a, 7 ln bext1,
#                8 ln bcmp0_0, 9 bcmp0_a, 10 ln bcmp1
# J3 adds (5): 11 g0, 12 g1, 13 u00, 14 u01, 15 ln c0
NAMES = ["ln k_pr0", "k_pr_a", "ln b_pr0", "b_pr_a", "ln T_pr", "ln b_ext0_0", "b_ext0_a", "ln b_ext1",
         "ln b_cmp0_0", "b_cmp0_a", "ln b_cmp1", "g0", "g1", "u00", "u01", "ln c0"]
ALPHA_ONLY = {1, 3, 6, 9, 12, 14}   # parameters that have no effect at alpha = 0
LB = np.array([np.log(1e3), -30, np.log(1e0), -30, np.log(2e-4), np.log(1e1), -30, np.log(1e-4),
               np.log(1e1), -30, np.log(1e-4), 0.0, 0.0, 0.0, -3.0, np.log(1e-6)])
UB = np.array([np.log(1e8), 30, np.log(1e5), 30, np.log(5e-2), np.log(1e5), 30, np.log(1e3),
               np.log(1e5), 30, np.log(1e3), 3.0, 10.0, 2.0, 3.0, np.log(1e-2)])


def phys(theta, alpha):
    th = theta
    p = np.zeros(10)
    p[0] = np.exp(th[0] + th[1] * alpha)
    p[1] = np.exp(th[2] + th[3] * alpha)
    p[2] = np.exp(th[4])
    p[3] = np.exp(th[5] + th[6] * alpha)
    p[4] = np.exp(th[7])
    p[5] = np.exp(th[8] + th[9] * alpha)
    p[6] = np.exp(th[10])
    gas = len(th) > 11
    if gas:
        p[7] = th[11] + th[12] * alpha
        p[8] = max(0.0, th[13] + th[14] * alpha)
        p[9] = np.exp(th[15])
    return p, gas


def sim_run(theta, r, alpha=None):
    a = r["alpha"] if alpha is None else alpha
    p, gas = phys(theta, a)
    return simulate(r["u"], p, gas)


def run_resid(theta, r):
    F, _ = sim_run(theta, r)
    e = (F[r["idx"]] - r["F"][r["idx"]]) / FSCALE * r["w"]
    if not np.all(np.isfinite(e)):
        e = np.full(e.shape, 10.0 * r["w"])
    return e


def rms(a):
    return float(np.sqrt(np.mean(np.asarray(a) ** 2)))
