"""Joint fits J1 (no gas) and J3 (cascade gas filter) on the 36 runs at alpha 0 and 0.3.
Run: OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 nice -n 10 python3 fit.py > fit.log"""
import time, json, numpy as np, common as C
from scipy.optimize import least_squares

T_START = time.time()
runs = C.load_all()
train = [r for r in runs if r["alpha"] in (0.0, 0.3)]
print("train runs", len(train), "residual samples", sum(len(r["idx"]) for r in train), flush=True)


class Timeout(Exception):
    pass


class Problem:
    def __init__(self, n, tlimit):
        self.n = n; self.tlimit = tlimit; self.t0 = time.time()
        self.cache_x = None; self.cache_r = None
        self.best = (np.inf, None); self.nf = 0; self.nj = 0

    def per_run(self, x):
        return [C.run_resid(x, r) for r in train]

    def fun(self, x):
        if time.time() - self.t0 > self.tlimit:
            raise Timeout()
        pr = self.per_run(x)
        self.nf += 1
        self.cache_x = x.copy(); self.cache_r = pr
        e = np.concatenate(pr)
        c = 0.5 * e @ e
        if c < self.best[0]:
            self.best = (c, x.copy())
        if self.nf % 5 == 0:
            print(f"    nf={self.nf} nj={self.nj} cost={c:.6f} best={self.best[0]:.6f} t={time.time()-self.t0:.0f}s", flush=True)
        return e

    def jac(self, x):
        if self.cache_x is None or not np.array_equal(x, self.cache_x):
            self.fun(x)
        base = self.cache_r
        e0 = np.concatenate(base)
        J = np.zeros((len(e0), self.n))
        for j in range(self.n):
            h = 1e-4 * max(1.0, abs(x[j]))
            if x[j] + h > C.UB[j]:
                h = -h
            xp = x.copy(); xp[j] += h
            cols = []
            for r, b in zip(train, base):
                if j in C.ALPHA_ONLY and r["alpha"] == 0.0:
                    cols.append(np.zeros_like(b))
                else:
                    cols.append((C.run_resid(xp, r) - b) / h)
            J[:, j] = np.concatenate(cols)
        self.nj += 1
        return J


def fit(x0, tlimit, max_nfev, tag):
    n = len(x0)
    lb, ub = C.LB[:n], C.UB[:n]
    x0 = np.clip(x0, lb + 1e-9, ub - 1e-9)
    P = Problem(n, tlimit)
    t = time.time()
    try:
        res = least_squares(P.fun, x0, jac=P.jac, bounds=(lb, ub), method="trf", x_scale=1.0,
                            max_nfev=max_nfev, ftol=1e-8, xtol=1e-8, gtol=1e-8)
        out = dict(x=res.x, cost=float(res.cost), status=int(res.status), nfev=int(res.nfev), njev=P.nj, msg=res.message)
    except Timeout:
        out = dict(x=P.best[1], cost=float(P.best[0]), status=-99, nfev=P.nf, njev=P.nj, msg="time limit")
    out["time"] = time.time() - t
    print(f"[{tag}] cost={out['cost']:.6f} status={out['status']} nfev={out['nfev']} njev={out['njev']} "
          f"time={out['time']:.0f}s msg={out['msg']}", flush=True)
    print("   x=", np.array2string(out["x"], precision=4, max_line_width=250), flush=True)
    return out


L = np.log
# J1 starts
j1A = np.array([L(4.39e5), L(4.016 / 4.389) / .3, L(6731), L(158.8 / 6731) / .3, L(1.8e-3), L(4124), L(4677 / 4124) / .3,
                L(1.34), L(1666), L(725 / 1666) / .3, L(0.05)])
j1B = np.array([L(3e5), 0, L(1000), 0, L(1e-3), L(3000), 0, L(1.0), L(2000), 0, L(0.5)])
results = {}
results["J1A"] = fit(j1A, 600, 200, "J1 start A (proto M1 interp)")
results["J1B"] = fit(j1B, 300, 200, "J1 start B (generic)")
best1 = min((results[k] for k in ("J1A", "J1B")), key=lambda d: d["cost"])
np.savez("fits_partial.npz", J1=best1["x"])
gas0 = np.array([0.127, (0.312 - 0.127) / 0.3, 0.0, 0.045 / 0.3, L(1.8e-3)])
j3A = np.r_[best1["x"], gas0]
j3B = np.array([L(7.81e5), L(2.81 / 7.81) / .3, L(8593), L(18.56 / 8593) / .3, L(1.56e-3), L(3933), L(3682 / 3933) / .3,
                L(0.99), L(2235), L(996 / 2235) / .3, L(0.01)])
j3B = np.r_[j3B, gas0]
results["J3A"] = fit(j3A, 900, 200, "J3 start A (J1 opt + proto gas)")
remaining = 38 * 60 - (time.time() - T_START)
results["J3B"] = fit(j3B, max(120, min(600, remaining)), 200, "J3 start B (proto M3 interp)")
best3 = min((results[k] for k in ("J3A", "J3B")), key=lambda d: d["cost"])
np.savez("fits.npz", J1=best1["x"], J3=best3["x"])
with open("fits_summary.json", "w") as f:
    json.dump({k: dict(cost=v["cost"], status=v["status"], nfev=v["nfev"], njev=v["njev"], time=v["time"],
                       msg=str(v["msg"]), x=v["x"].tolist()) for k, v in results.items()}, f, indent=1)
print("total fit time", time.time() - T_START, flush=True)
