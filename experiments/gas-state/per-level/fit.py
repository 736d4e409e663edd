"""Feasibility: EMM damper model variants M1/M2/M3 (cavitation lost motion), fitted per oil-loss level.
Run: OMP_NUM_THREADS=1 python3 fit.py
"""
import os, sys, json, time
os.environ.setdefault("OMP_NUM_THREADS", "1"); os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("NUMBA_NUM_THREADS", "1")
import numpy as np
from scipy.signal import butter, filtfilt
from scipy.optimize import least_squares
from numba import njit

RUNS = os.environ.get("NEMM_BENCH", "out/bench") + "/runs"
OUT = os.path.dirname(os.path.abspath(__file__))
DT = 1e-4
T0 = 0.3
VELS = ["1048", "0524", "0262"]
LEVELS = ["00", "30"]
FSCALE = 2000.0


def load(level, vel):
    d = np.loadtxt(f"{RUNS}/oil{level}_a010_v{vel}.csv", delimiter=",", skiprows=1)
    t, x, F = d[:, 0], d[:, 1], d[:, 2]
    u_raw = np.gradient(x, t)                      # central differences
    b, a = butter(2, 500.0 / (0.5 / DT))           # 500 Hz, zero phase
    u = filtfilt(b, a, u_raw)
    return dict(t=t, x=x, F=F, u=u, u_raw=u_raw, mask=t >= T0, name=f"oil{level}_a010_v{vel}")


# ---------------------------------------------------------------- model
# physical parameter vector p (all positive), layout:
# 0 kp(+) 1 bpr 2 Tpr 3 bp0 4 bp1 5 bn0 6 bn1 | 7 hp 8 kn 9 hn | 10 g 11 u0 12 c0
# M1: k_pr = p[0] both sides, h = 0.  M2: k+ = p[0], h+ = p[7], k- = p[8], h- = p[9]
VBL = 1e-3    # b_fl side blend width on v_st [m/s]
XBL = 1e-5    # k side blend width on x_pr [m]
X0 = 1e-3
SP = 5e-3     # softplus sharpness [m/s]


@njit(cache=True)
def bfl(v, p):
    w = 0.5 * (1.0 + np.tanh(v / VBL))
    av = abs(v)
    return w * p[3] / (1.0 + p[4] * av) + (1.0 - w) * p[5] / (1.0 + p[6] * av)


@njit(cache=True)
def spring(x, p, model):
    if model == 1:
        return p[0] * x
    w = 0.5 * (1.0 + np.tanh(x / XBL))
    r = (x / X0) ** 2
    return (w * p[0] * (1.0 + p[7] * r) + (1.0 - w) * p[8] * (1.0 + p[9] * r)) * x


@njit(cache=True)
def rhs(s, u, p, model, out):
    xpr, vst, c = s[0], s[1], s[2]
    ueff = u
    dc = 0.0
    if model == 3:
        if u > 0.0:
            z = (u - p[11]) / SP
            sp = SP * (z + np.log1p(np.exp(-z))) if z > 0 else SP * np.log1p(np.exp(z))
            dc = p[10] * sp
        else:
            cc = c if c > 0.0 else 0.0
            sh = cc / (cc + p[12])
            dc = u * sh
            ueff = u * (1.0 - sh)
    b = bfl(vst, p)
    q = (spring(xpr, p, model) + p[1] * ueff) / (p[1] + b)
    out[0] = ueff - q
    out[1] = (q - vst) / p[2]
    out[2] = dc
    return b * q


@njit(cache=True)
def simulate(u, p, model):
    n = u.shape[0]
    F = np.empty(n)
    s = np.zeros(3); k1 = np.zeros(3); k2 = np.zeros(3); k3 = np.zeros(3); k4 = np.zeros(3); tmp = np.zeros(3)
    C = np.empty(n)
    for i in range(n):
        F[i] = rhs(s, u[i], p, model, k1)
        C[i] = s[2]
        if i == n - 1:
            break
        um = 0.5 * (u[i] + u[i + 1])
        for j in range(3):
            tmp[j] = s[j] + 0.5 * DT * k1[j]
        rhs(tmp, um, p, model, k2)
        for j in range(3):
            tmp[j] = s[j] + 0.5 * DT * k2[j]
        rhs(tmp, um, p, model, k3)
        for j in range(3):
            tmp[j] = s[j] + DT * k3[j]
        rhs(tmp, u[i + 1], p, model, k4)
        for j in range(3):
            s[j] += DT / 6.0 * (k1[j] + 2 * k2[j] + 2 * k3[j] + k4[j])
        if s[2] < 0.0:
            s[2] = 0.0
        if not np.isfinite(s[0]) or not np.isfinite(s[1]):
            F[:] = np.nan
            return F, C
    return F, C


NPAR = {1: 7, 2: 10, 3: 13}
NAMES = ["k_pos", "b_pr", "T_pr", "b_ext0", "b_ext1", "b_cmp0", "b_cmp1", "h_pos", "k_neg", "h_neg", "g", "u0", "c0"]
# log bounds (physical): keep RK4 at 10 kHz stable and stay physical
LB = np.log([1e3, 1e1, 2e-4, 1e1, 1e-4, 1e1, 1e-4, 1e-6, 1e3, 1e-6, 1e-5, 1e-5, 1e-6])
UB = np.log([1e8, 1e5, 5e-2, 1e5, 1e3, 1e5, 1e3, 1e2, 1e8, 1e2, 1.0, 2.0, 1e-2])


def full_p(theta, model):
    p = np.zeros(13)
    p[:NPAR[model]] = np.exp(theta)
    if model == 1:
        p[7] = 0.0; p[8] = p[0]; p[9] = 0.0
    return p


def resid(theta, runs, model):
    p = full_p(theta, model)
    out = []
    for r in runs:
        F, _ = simulate(r["u"], p, model)
        e = (F - r["F"])[r["mask"]] / FSCALE
        if not np.all(np.isfinite(e)):
            e = np.full(e.shape, 10.0)
        out.append(e)
    return np.concatenate(out)


def fit(runs, model, starts, max_nfev=120):
    best = None
    for th0 in starts:
        th0 = np.clip(th0, LB[:NPAR[model]] + 1e-6, UB[:NPAR[model]] - 1e-6)
        try:
            res = least_squares(resid, th0, args=(runs, model), bounds=(LB[:NPAR[model]], UB[:NPAR[model]]),
                                x_scale=1.0, diff_step=1e-4, max_nfev=max_nfev, method="trf")
        except Exception as ex:  # noqa
            print("  start failed:", ex); continue
        print(f"  M{model} start cost={res.cost:.5f} nfev={res.nfev} status={res.status}", flush=True)
        if best is None or res.cost < best.cost:
            best = res
    return best


def rms(a):
    return float(np.sqrt(np.mean(a ** 2)))


def main():
    t_start = time.time()
    rng = np.random.default_rng(0)
    data = {lv: [load(lv, v) for v in VELS] for lv in LEVELS}
    # velocity check
    for lv in LEVELS:
        for r in data[lv]:
            m = r["mask"]
            print(r["name"], "u range", r["u"][m].min(), r["u"][m].max(),
                  "rms(u_raw-u) [mm/s]", 1e3 * rms((r["u_raw"] - r["u"])[m]))
    fits = {}
    for lv in LEVELS:
        runs = data[lv]
        # M1 starts
        starts = []
        for k in [1e5, 1e6]:
            for bpr in [500, 3000]:
                th = np.log([k, bpr, 1e-3, 2500, 0.5, 1500, 0.5])
                starts.append(th)
        starts.append(np.log([3e5, 1000, 1e-3, 3000, 1.0, 2000, 1.0]))
        print(f"level {lv} M1", flush=True)
        r1 = fit(runs, 1, starts)
        # M2 starts: from M1 best + variations
        p1 = np.exp(r1.x)
        starts = []
        for h in [1e-3, 1e-2, 0.1]:
            starts.append(np.log(np.r_[p1, h, p1[0], h]))
        for _ in range(1):
            starts.append(np.log(np.r_[p1, 1e-2, p1[0], 1e-2]) + rng.normal(0, 0.5, 10))
        print(f"level {lv} M2", flush=True)
        r2 = fit(runs, 2, starts)
        p2 = np.exp(r2.x)
        starts = []
        for g in [0.05, 0.3, 0.8]:
            for u0 in [0.1]:
                for c0 in [5e-5]:
                    starts.append(np.log(np.r_[p2, g, u0, c0]))
        starts.append(np.log(np.r_[p2, 0.3, 0.1, 2e-4]))
        starts.append(np.log(np.r_[p2, 0.1, 0.5, 1e-5]))
        print(f"level {lv} M3", flush=True)
        r3 = fit(runs, 3, starts)
        fits[lv] = {1: r1, 2: r2, 3: r3}
        print("elapsed", time.time() - t_start, flush=True)

    # ------------- evaluation
    pred = {}
    lines = []
    rows = []
    for lv in LEVELS:
        for i, r in enumerate(data[lv]):
            row = [r["name"]]
            for m in (1, 2, 3):
                p = full_p(fits[lv][m].x, m)
                F, C = simulate(r["u"], p, m)
                pred[(lv, i, m)] = (F, C)
                row.append(rms((F - r["F"])[r["mask"]]))
                row.append(rms(F - r["F"]))
            rows.append(row)
    lines.append("## Force RMS error [N] (after 0.3 s; whole run in parentheses)\n")
    lines.append("| run | M1 | M2 | M3 |\n|---|---|---|---|")
    for row in rows:
        lines.append(f"| {row[0]} | {row[1]:.1f} ({row[2]:.1f}) | {row[3]:.1f} ({row[4]:.1f}) | {row[5]:.1f} ({row[6]:.1f}) |")
    lines.append("\n## Degradation signature rel_sig = RMS(dF_hat - dF_meas)/RMS(dF_meas), dF = F00 - F30, after 0.3 s\n")
    lines.append("| condition | RMS(dF_meas) [N] | M1 | M2 | M3 | share of dF_meas^2 on u<0 |\n|---|---|---|---|---|---|")
    for i, v in enumerate(VELS):
        r0, r3_ = data["00"][i], data["30"][i]
        assert np.allclose(r0["t"], r3_["t"])
        m = r0["mask"]
        dmeas = (r0["F"] - r3_["F"])[m]
        vals = []
        for mm in (1, 2, 3):
            dhat = (pred[("00", i, mm)][0] - pred[("30", i, mm)][0])[m]
            vals.append(rms(dhat - dmeas) / rms(dmeas))
        comp = (r0["u"][m] < 0)
        share = float(np.sum(dmeas[comp] ** 2) / np.sum(dmeas ** 2))
        lines.append(f"| a010_v{v} | {rms(dmeas):.1f} | {vals[0]:.3f} | {vals[1]:.3f} | {vals[2]:.3f} | {share:.3f} |")
    lines.append("\n## Fitted parameters\n")
    lines.append("| param | " + " | ".join(f"M{m} L{lv}" for lv in LEVELS for m in (1, 2, 3)) + " |")
    lines.append("|---|" + "---|" * 6)
    for j, nm in enumerate(NAMES):
        cells = []
        for lv in LEVELS:
            for m in (1, 2, 3):
                cells.append(f"{np.exp(fits[lv][m].x[j]):.4g}" if j < NPAR[m] else "")
        lines.append(f"| {nm} | " + " | ".join(cells) + " |")
    lines.append("\nunits: k [N/m], b [N s/m], b_*1 [s/m], T_pr [s], h [-] (x0=1 mm), g [-], u0 [m/s], c0 [m]")
    lines.append("\nfit cost / nfev / status: " + "; ".join(
        f"L{lv} M{m}: {fits[lv][m].cost:.4f}/{fits[lv][m].nfev}/{fits[lv][m].status}" for lv in LEVELS for m in (1, 2, 3)))
    # cavity size stats
    for lv in LEVELS:
        for i, r in enumerate(data[lv]):
            C = pred[(lv, i, 3)][1]
            lines.append(f"- M3 {r['name']}: max cavity c = {1e3*C[r['mask']].max():.3f} mm")
    txt = "\n".join(lines)
    print(txt)
    with open(f"{OUT}/results_tables.md", "w") as f:
        f.write(txt + "\n")
    np.savez(f"{OUT}/fits.npz", **{f"L{lv}_M{m}": fits[lv][m].x for lv in LEVELS for m in (1, 2, 3)})

    # ------------- plot
    try:
        import matplotlib; matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        r30 = data["30"][0]; r00 = data["00"][0]
        t = r30["t"]; f = 1.048 / (2 * np.pi * 0.010)
        t1 = t[-1] - 1.0 / f
        sel = t >= t1
        fig, ax = plt.subplots(1, 2, figsize=(12, 5))
        ax[0].plot(1e3 * r30["x"][sel], r30["F"][sel], "k", lw=2, label="measured oil30")
        ax[0].plot(1e3 * r00["x"][sel], r00["F"][sel], color="0.6", lw=1, label="measured oil00")
        ax[0].plot(1e3 * r30["x"][sel], pred[("30", 0, 1)][0][sel], "b--", label="M1 (L30 fit)")
        ax[0].plot(1e3 * r30["x"][sel], pred[("30", 0, 3)][0][sel], "r-.", label="M3 (L30 fit)")
        ax[0].set_xlabel("displacement [mm]"); ax[0].set_ylabel("force [N]"); ax[0].legend(); ax[0].grid()
        ax[0].set_title("oil30_a010_v1048, last cycle")
        ax[1].plot(r30["u"][sel], r30["F"][sel], "k", lw=2, label="measured oil30")
        ax[1].plot(r30["u"][sel], pred[("30", 0, 1)][0][sel], "b--", label="M1")
        ax[1].plot(r30["u"][sel], pred[("30", 0, 3)][0][sel], "r-.", label="M3")
        ax2 = ax[1].twinx(); ax2.plot(r30["u"][sel], 1e3 * pred[("30", 0, 3)][1][sel], "g:", label="M3 cavity c [mm]")
        ax2.set_ylabel("c [mm]", color="g")
        ax[1].set_xlabel("u [m/s]"); ax[1].legend(loc="upper left"); ax[1].grid()
        fig.tight_layout(); fig.savefig(f"{OUT}/oil30_a010_v1048_cycle.png", dpi=110)
        print("plot saved")
    except Exception as ex:
        print("plot failed:", ex)


if __name__ == "__main__":
    main()
