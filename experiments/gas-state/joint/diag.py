import numpy as np
d=np.load("readback.npz"); g=np.round(np.arange(0,0.3001,0.01),4)
print("run | model | e(min) | e(label)-e(min) | e(0)-e(min) | e(0.3)-e(min)  [N]")
for lv,lab in (("15",15),("30",30)):
  for m in ("J1","J3"):
    rows=[]
    for k in sorted(d.files):
      if not k.startswith(f"{m}_oil{lv}"): continue
      e=d[k]; rows.append((k[3:], e.min(), e[lab]-e.min(), e[0]-e.min(), e[-1]-e.min()))
    for r in rows: print(f"{r[0]} {m} {r[1]:.1f} {r[2]:.2f} {r[3]:.2f} {r[4]:.2f}")
