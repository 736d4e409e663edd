"""Evaluation: per-run RMS, signature, alpha read-back, parameters. Writes results_tables.md.
Run: OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 nice -n 10 python3 evaluate.py [fits.npz]"""
import sys, json, time, numpy as np, common as C

t0 = time.time()
fn = sys.argv[1] if len(sys.argv) > 1 else "fits.npz"
fits = dict(np.load(fn))
models = [m for m in ("J1", "J3") if m in fits]
runs = C.load_all()
byname = {r["name"]: r for r in runs}
conds = sorted({r["cond"] for r in runs}, key=lambda c: (c[:4], c[5:]))
L = []
P = lambda *a: L.append(" ".join(str(x) for x in a))

# ---- 1. per-run RMS at own alpha
pred = {}
P("## 1. Force RMS error [N] after 0.3 s (model at the run's own alpha; 15 % = held out, alpha 0.15)\n")
P("| condition | " + " | ".join(f"{m} {lv}" for lv in ("00", "15", "30") for m in models) + " | J3 max c [mm] 00/15/30 |")
P("|---|" + "---|" * (3 * len(models)) + "---|")
cmax = {}
for c in conds:
    cells = []
    for lv in ("00", "15", "30"):
        r = byname[f"oil{lv}_{c}"]
        for m in models:
            F, Cc = C.sim_run(fits[m], r)
            pred[(m, r["name"])] = F
            if m == "J3":
                cmax[r["name"]] = 1e3 * Cc.max()
            cells.append(f"{C.rms((F - r['F'])[r['mask']]):.1f}")
    cm = "/".join(f"{cmax.get(f'oil{lv}_{c}', np.nan):.2f}" for lv in ("00", "15", "30"))
    P(f"| {c} | " + " | ".join(cells) + f" | {cm} |")
for lv in ("00", "15", "30"):
    s = []
    for m in models:
        v = [C.rms((pred[(m, r['name'])] - r['F'])[r['mask']]) for r in runs if r['name'].startswith(f'oil{lv}')]
        s.append(f"{m} median {np.median(v):.1f} / mean {np.mean(v):.1f}")
    P(f"\nlevel {lv}: " + "; ".join(s))
print("\n".join(L), flush=True)

# ---- 2. signature
P("\n## 2. Signature rel = RMS(dF_model - dF_meas)/RMS(dF_meas), dF = F(0 %) - F(level), after 0.3 s, common span\n")
P("| condition | RMS dF_meas 30 [N] | " + " | ".join(f"{m} rel30" for m in models) + " | RMS dF_meas 15 [N] | "
  + " | ".join(f"{m} rel15" for m in models) + " |")
P("|---|---|" + "---|" * len(models) + "---|" + "---|" * len(models))
rels = {(m, lv): [] for m in models for lv in ("15", "30")}
for c in conds:
    r0 = byname[f"oil00_{c}"]
    row = [c]
    for lv in ("30", "15"):
        r1 = byname[f"oil{lv}_{c}"]
        n = min(len(r0["t"]), len(r1["t"]))
        m_ = r0["mask"][:n] & r1["mask"][:n]
        dmeas = (r0["F"][:n] - r1["F"][:n])[m_]
        row.append(f"{C.rms(dmeas):.1f}")
        for m in models:
            dh = (pred[(m, r0['name'])][:n] - pred[(m, r1['name'])][:n])[m_]
            rel = C.rms(dh - dmeas) / C.rms(dmeas)
            rels[(m, lv)].append(rel)
            row.append(f"{rel:.3f}")
    P("| " + " | ".join(row) + " |")
P("| **median** | | " + " | ".join(f"**{np.median(rels[(m, '30')]):.3f}**" for m in models) + " | | "
  + " | ".join(f"**{np.median(rels[(m, '15')]):.3f}**" for m in models) + " |")
print("\n".join(L[-(len(conds) + 4):]), flush=True)

# ---- 3. read-back
grid = np.round(np.arange(0, 0.3001, 0.01), 4)
P("\n## 3. Alpha read-back (grid 0..0.3 step 0.01, parabolic refinement), force RMS after 0.3 s\n")
rb = {}
for m in models:
    for r in runs:
        e = np.array([C.rms((C.sim_run(fits[m], r, a)[0] - r["F"])[r["mask"]]) for a in grid])
        k = int(np.argmin(e))
        ah = grid[k]
        if 0 < k < len(grid) - 1:
            d2 = e[k - 1] - 2 * e[k] + e[k + 1]
            if d2 > 0:
                ah = grid[k] + 0.01 * 0.5 * (e[k - 1] - e[k + 1]) / d2
        rb[(m, r["name"])] = (ah, e[k], e)
    print(f"read-back {m} done t={time.time()-t0:.0f}s", flush=True)
P("| condition | " + " | ".join(f"{m} @{lv}" for lv in ("00", "15", "30") for m in models) + " |")
P("|---|" + "---|" * (3 * len(models)))
hits = {(m, lv): 0 for m in models for lv in ("00", "15", "30")}
errs = {(m, lv): [] for m in models for lv in ("00", "15", "30")}
for c in conds:
    cells = []
    for lv in ("00", "15", "30"):
        r = byname[f"oil{lv}_{c}"]
        for m in models:
            ah = rb[(m, r["name"])][0]
            ok = abs(ah - r["alpha"]) <= 0.03 + 1e-9
            hits[(m, lv)] += ok
            errs[(m, lv)].append(ah - r["alpha"])
            cells.append(f"{ah:.3f}" + ("" if ok else " x"))
    P(f"| {c} | " + " | ".join(cells) + " |")
P("\nRuns within 0.03 of label (of 18): " + "; ".join(
    f"{m}: 00 {hits[(m,'00')]}, 15 {hits[(m,'15')]}, 30 {hits[(m,'30')]}" for m in models))
P("Mean / median read-back error: " + "; ".join(
    f"{m}@{lv}: {np.mean(errs[(m,lv)]):+.3f}/{np.median(errs[(m,lv)]):+.3f}" for m in models for lv in ("00", "15", "30")))
for m in models:
    for amp in ("a010", "a030", "a050"):
        P(f"- {m} hits at 15 % for {amp}: {sum(abs(rb[(m, f'oil15_{c}')][0]-0.15)<=0.03+1e-9 for c in conds if c.startswith(amp))}/6")

# ---- 4. parameters
P("\n## 4. Fitted parameters (theta; physical values at alpha 0 / 0.15 / 0.3)\n")
P("| param | " + " | ".join(models) + " | bounds |\n|---|" + "---|" * len(models) + "---|")
for j, nm in enumerate(C.NAMES):
    cells = []
    for m in models:
        x = fits[m]
        if j < len(x):
            atb = " (AT BOUND)" if (abs(x[j] - C.LB[j]) < 1e-4 or abs(x[j] - C.UB[j]) < 1e-4) else ""
            cells.append(f"{x[j]:.4g}{atb}")
        else:
            cells.append("")
    P(f"| {nm} | " + " | ".join(cells) + f" | [{C.LB[j]:.3g}, {C.UB[j]:.3g}] |")
pn = ["k_pr [N/m]", "b_pr [N s/m]", "T_pr [s]", "b_ext0 [N s/m]", "b_ext1 [s/m]", "b_cmp0 [N s/m]", "b_cmp1 [s/m]", "g [-]", "u0 [m/s]", "c0 [m]"]
P("\n| physical | " + " | ".join(f"{m} a={a}" for m in models for a in (0, 0.15, 0.3)) + " |\n|---|" + "---|" * (3 * len(models)))
for j, nm in enumerate(pn):
    cells = []
    for m in models:
        for a in (0, 0.15, 0.3):
            p, gas = C.phys(fits[m], a)
            cells.append(f"{p[j]:.4g}" if (j < 7 or gas) else "")
    P(f"| {nm} | " + " | ".join(cells) + " |")
if "J3" in fits:
    P("\nJ3 max cavity c [mm] per run (lost motion): " + ", ".join(f"{k} {v:.2f}" for k, v in sorted(cmax.items())))
    big = [f"{k} {v:.2f} mm" for k, v in cmax.items() if "a050" in k and v > 10]
    P("J3 runs with c > 10 mm on 50 mm: " + (", ".join(big) if big else "none"))
    P("J3 c max / amplitude: " + ", ".join(f"{k} {v/ (1e3*byname[k]['amp']):.3f}" for k, v in sorted(cmax.items()) if k.startswith("oil30")))
txt = "\n".join(L)
open("results_tables.md", "w").write(txt + "\n")
np.savez("readback.npz", **{f"{m}_{n}": rb[(m, n)][2] for (m, n) in rb})
print(txt)
print("eval time", time.time() - t0)
