"""Subnormal numbers: Suslov's per-step cost to t = 1e4 against t = 500, with and without flush-to-zero.

Run (from the repository root; numba required, about a minute)::

    python benchmarks/subnormals.py                 # Euler and imex-rk4, dt = 1e-3
    python benchmarks/subnormals.py --schemes euler --reps 5

Suslov's exact ``Pi_2 = Pi_3 = sech t`` falls below ``2.2e-308`` (the smallest
normal double) near ``t = 709``; products such as ``Pi_2^2`` do so near
``t = 355``.  liefi's generated loops run with FTZ/DAZ set
(:mod:`liefi.engine.fpu`); each loop ``run_<scheme>`` wraps ``run_<scheme>_loop``,
the same loop without the flush.  This script calls both from the same compiled
module, interleaved, best of ``--reps``, and prints the CPU time per step over
``[0, 300]`` (no subnormal yet), ``[0, 500]`` and ``[0, 1e4]``, the ratios, and
the largest difference between the two loops' states at the end of each run.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from liefi import engine, scenes  # noqa: E402
from liefi.engine import fpu  # noqa: E402
from _machine import cpu_model  # noqa: E402 -- benchmarks/_machine.py


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--schemes", nargs="+", default=["euler", "imex-rk4"])
    ap.add_argument("--dt", type=float, default=1e-3)
    ap.add_argument("--horizons", nargs="+", type=float, default=[300.0, 500.0, 1e4])
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args(argv)
    sc = scenes.get("suslov")
    fi = sc.integrator(configuration=True)
    print(f"CPU: {cpu_model()}; flush active: {fpu.ACTIVE}")
    for scheme in args.schemes:
        cf = engine.compile_split(fi) if scheme.startswith("imex") else engine.compile_feedback(fi)
        name = "run_" + scheme.replace("-", "_")
        cf.warmup(scheme)
        loops = {"flush": getattr(cf.module, name), "no flush": getattr(cf.module, name + "_loop")}
        p = np.ascontiguousarray(fi.parameters(), float)
        N = fi.y0.size
        best = {(k, T): np.inf for k in loops for T in args.horizons}
        final = {}
        for _ in range(args.reps):
            for T in args.horizons:
                n = int(round(T / args.dt))
                for k, f in loops.items():
                    out, bad, last = np.empty((N, 2)), np.empty(N), np.empty(N)
                    c0 = time.process_time()
                    r = f(fi.y0.copy(), p, args.dt, n, n, n, out, bad, last, np.zeros(1), 0, 0.0)
                    c = time.process_time() - c0
                    if r[0]:
                        raise RuntimeError(f"{scheme} ({k}) failed at step {r[0]}")
                    best[k, T] = min(best[k, T], c / n)
                    final[k, T] = out[:, -1].copy()
        print(f"\n{scheme}, dt = {args.dt:g}: CPU ns per step (best of {args.reps})")
        print("  horizon    " + "".join(f"{k:>12}" for k in loops) + "   no flush / flush   max |y_flush - y|")
        for T in args.horizons:
            a, b = best["flush", T], best["no flush", T]
            d = float(np.max(np.abs(final["flush", T] - final["no flush", T])))
            print(f"  {T:8g}   {a * 1e9:12.1f}{b * 1e9:12.1f}   {b / a:16.2f}   {d:.3g}")
        T0, T1 = args.horizons[-2], args.horizons[-1]
        for k in loops:
            print(f"  {k}: per step to t = {T1:g} over per step to t = {T0:g}: {best[k, T1] / best[k, T0]:.3f}"
                  f"  (over t = {args.horizons[0]:g}: {best[k, T1] / best[k, args.horizons[0]]:.3f})")
        print(f"  final Pi (flush): {final['flush', T1][-3:]}, (no flush): {final['no flush', T1][-3:]}")


if __name__ == "__main__":
    main()
