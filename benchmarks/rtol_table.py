"""The rtol table: every scene (or a list) over [0, T] at a range of tolerances, liefi's default method.

For each scene and ``rtol``: the scheme and step :func:`liefi.tolerance.choose_step` picks (the order
chosen by predicted cost unless ``--scheme`` is given), the achieved error (the largest over the
compared components of ``max_t |y_k - y_k_ref| / max_t |y_k_ref|``), its ratio to ``rtol``, the largest
invariant drift, the integration CPU and the CPU of choosing the step (pilot and check).

    python benchmarks/rtol_table.py [SCENES|all] [T] [RTOLS] [--scheme=NAME] [--ref-rtol=R] [--fine-ref=N]

e.g. ``python benchmarks/rtol_table.py all 1000 1e-4,1e-6,1e-8,1e-10``.  The references are the
scenes' own (DOP853 at their ``reference_rtol``); an achieved error near that floor is the
reference's, not the run's.  ``--fine-ref=N``: the reference is instead the run's own scheme at about ``N``
steps over ``[0, T]`` (a divisor of the run's step, compared at the run's saved points on the integrator's
components), for a scene whose DOP853 reference is the limit (perturbed Kepler over ``[0, 1000]``: DOP853 at
``3e-14`` is ``6e-8`` off, where ``imex-rk8`` at ``1e5`` and ``2e5`` steps agree to ``4e-13``).
"""
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from liefi import scenes
from liefi.scenes import names as scene_names

warnings.simplefilter("ignore")
args = [a for a in sys.argv[1:] if not a.startswith("--")]
opts = dict(a[2:].split("=", 1) for a in sys.argv[1:] if a.startswith("--") and "=" in a)
names = scene_names() if not args or args[0] == "all" else args[0].split(",")
T = float(args[1]) if len(args) > 1 else 1000.0
rtols = [float(r) for r in (args[2].split(",") if len(args) > 2 else ["1e-4", "1e-6", "1e-8", "1e-10"])]
scheme = opts.get("scheme")
print(f"T = {T:g}, scheme {scheme or 'chosen by cost'}")
print("| scene | rtol | scheme | dt | steps | achieved rel. error | err/rtol | max drift (rel.) | CPU s | choose s "
      "| reference |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for n in names:
    sc = scenes.get(n)
    if "ref-rtol" in opts:  # a tighter reference than the scene's (its error is the floor of the column)
        sc.reference_rtol = sc.reference_atol = float(opts["ref-rtol"])
    v = sc.variant(None)
    for r in rtols:
        try:
            t = time.process_time()
            sc.step_for_tolerance(v, scheme or "imex-rk4", T, r, gains="auto", choose_order=scheme is None)
            choose = time.process_time() - t  # kept on the scene: the run below reuses it
            res = sc.run(scheme=scheme or "imex-rk4", gains="auto", t_final=T, rtol=r, choose_order=scheme is None)
        except Exception as exc:  # a row that fails says why and the table goes on
            print(f"| {n} | {r:.0e} | failed: {type(exc).__name__}: {str(exc)[:120]} ||||||||||", flush=True)
            continue
        if "fine-ref" in opts:  # the same scheme at a divisor of the step, at the run's saved points
            fi = sc.integrator(v, gains="auto")
            q = max(1, int(np.ceil(float(opts["fine-ref"]) * res.dt / T - 1e-9)))
            every = int(round((res.t[1] - res.t[0]) / res.dt)) if len(res.t) > 1 else 1
            fine = fi.run((0.0, T), dt=res.dt / q, scheme=res.scheme, save_every=every * q, progress=False)
            Yf = np.moveaxis(np.asarray(fine.y), -1, 0)
            rel = max(np.max(np.abs(res[k] - Yf[:, i])) / max(np.max(np.abs(Yf[:, i])), 1e-300)
                      for i, k in enumerate(fi.names) if k in sc.error_variables and k in res.names)
            ref = f"{res.scheme} at dt/{q}"
        else:
            rel = max(res.max_error[k] / max(np.max(np.abs(res[k] - res.errors[k])) if k in res.names else 1.0,
                                             1e-300) for k in res.max_error)
            ref = "exact" if sc.reference == "exact" else f"{sc.reference} at {sc.reference_rtol:g}"
        drift = max(res.max_drift.values()) if res.max_drift else 0.0
        print(f"| {n} | {r:.0e} | {res.scheme} | {res.dt:.4g} | {res.steps} | {rel:.2e} | {rel / r:.2g} | "
              f"{drift:.1e} | {res.cpu_seconds:.3f} | {choose:.3f} | {ref} |", flush=True)
