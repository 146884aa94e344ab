"""rtol table: scene, rtol, achieved relative error, max invariant drift, dt, CPU (imex-rk4, gains auto)."""
import sys, time, warnings, numpy as np
from liefi import scenes
warnings.simplefilter("ignore")
names = sys.argv[1].split(",")
T = float(sys.argv[2]) if len(sys.argv) > 2 else 100.0
rtols = [float(r) for r in (sys.argv[3].split(",") if len(sys.argv) > 3 else ["1e-4", "1e-6", "1e-8", "1e-10"])]
print("| scene | rtol | achieved rel. error | err/rtol | max drift (rel.) | dt | steps | CPU s |")
print("|---|---|---|---|---|---|---|---|")
for n in names:
    sc = scenes.get(n)
    for r in rtols:
        res = sc.run(scheme="imex-rk4", gains="auto", t_final=T, rtol=r)
        rel = max(res.max_error[k] / max(np.max(np.abs(res[k])) if k in res.names else 1.0, 1e-300)
                  for k in res.max_error)
        drift = max(res.max_drift.values()) if res.max_drift else 0.0
        print(f"| {n} | {r:.0e} | {rel:.2e} | {rel/r:.2g} | {drift:.1e} | {res.dt:.4g} | {res.steps} | {res.cpu_seconds:.3f} |", flush=True)
