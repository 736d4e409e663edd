"""Follow-ups: (a) continue M3 level-00 fit (hit max_nfev); (b) M3 with c0 restricted to <= 0.1 mm (sharp lost motion)."""
import numpy as np, fit as M
from scipy.optimize import least_squares
f = np.load("fits.npz")
data = {lv: [M.load(lv, v) for v in M.VELS] for lv in M.LEVELS}
out = {}
r = least_squares(M.resid, f["L00_M3"], args=(data["00"], 3), bounds=(M.LB, M.UB), diff_step=1e-4, max_nfev=400)
print("L00 M3 continued: cost", r.cost, "nfev", r.nfev, "status", r.status, "params", dict(zip(M.NAMES, np.round(np.exp(r.x), 6))), flush=True)
out["L00_M3_cont"] = r.x
UB2 = M.UB.copy(); UB2[12] = np.log(1e-4)
for lv in M.LEVELS:
    best = None
    for c0 in [2e-5, 5e-5]:
        th = f[f"L{lv}_M3"].copy(); th[12] = np.log(c0)
        rr = least_squares(M.resid, th, args=(data[lv], 3), bounds=(M.LB, UB2), diff_step=1e-4, max_nfev=150)
        print(f"L{lv} M3 c0<=0.1mm start c0={c0}: cost {rr.cost:.4f} nfev {rr.nfev} status {rr.status}", flush=True)
        if best is None or rr.cost < best.cost: best = rr
    out[f"L{lv}_M3_sharp"] = best.x
    print(f"L{lv} sharp params", dict(zip(M.NAMES, np.round(np.exp(best.x), 6))), flush=True)
np.savez("fits_refine.npz", **out)
# evaluate both variants
def ev(th00, th30, tag):
    for i, v in enumerate(M.VELS):
        r0, r3 = data["00"][i], data["30"][i]; m = r0["mask"]
        F0, _ = M.simulate(r0["u"], M.full_p(th00, 3), 3); F3, _ = M.simulate(r3["u"], M.full_p(th30, 3), 3)
        dm = (r0["F"] - r3["F"])[m]; dh = (F0 - F3)[m]
        print(f"{tag} v{v}: rms00 {M.rms((F0-r0['F'])[m]):.1f} rms30 {M.rms((F3-r3['F'])[m]):.1f} rel_sig {M.rms(dh-dm)/M.rms(dm):.3f}")
ev(out["L00_M3_cont"], f["L30_M3"], "M3(cont L00)")
ev(out["L00_M3_sharp"], out["L30_M3_sharp"], "M3 sharp c0<=0.1mm")
