"""Read-back error spread at 15 % from stored curves (no simulation)."""
import numpy as np
g = np.round(np.arange(0, 0.3001, 0.01), 4)
d = {**dict(np.load("readback.npz")), **dict(np.load("sat_readback.npz"))}
def rb(e):
    k = int(np.argmin(e)); a = g[k]
    if 0 < k < len(g) - 1:
        d2 = e[k-1] - 2*e[k] + e[k+1]
        if d2 > 0: a = g[k] + 0.005 * (e[k-1] - e[k+1]) / d2
    return a
for m in ("J1", "J3", "J4"):
    for lv, lab in (("15", 0.15), ("30", 0.3), ("00", 0.0)):
        err = np.array([rb(d[k]) - lab for k in sorted(d) if k.startswith(f"{m}_oil{lv}")])
        print(f"{m} @{lv}: |err|<=0.03 {np.sum(np.abs(err)<=0.03+1e-9)}, <=0.05 {np.sum(np.abs(err)<=0.05+1e-9)}, MAE {np.mean(np.abs(err)):.3f}, RMS {np.sqrt(np.mean(err**2)):.3f}")
