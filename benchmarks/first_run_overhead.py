"""The first run in a Python process: its overhead once kernels are cached.

Run (from the repository root; about a minute)::

    python benchmarks/first_run_overhead.py            # best of 3 fresh processes per case
    python benchmarks/first_run_overhead.py --repeat 5

For each case -- the README's system (the planar body with a rotor, ``SE(2) x S^1``)
and two scenes (Suslov, the free rigid body) -- a fresh process builds
``fi = FeedbackIntegrator(system, y0)`` and calls ``fi.run(T)`` twice, at liefi's
defaults.  The *overhead* of the first call is its wall time minus the second's
(what a process pays once: importing numba, tracing the system, loading the
kernel from the cache, ...).  One process fills the cache first; then each case
runs ``--repeat`` times (best of).  CPU time (``time.process_time``) is printed
next to the wall time: on a busy machine the wall time mostly measures the queue.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")

_CASE = r"""
import json, sys, time, warnings
warnings.simplefilter("ignore")
import numpy as np
import liefi
case = sys.argv[1]
if case == "readme":
    from liefi.groups import SE2

    def metric(x):
        c = np.cos(x[..., 0]); one = np.ones_like(c); zero = 0 * c
        return np.stack([np.stack([2 + 0.5 * c, zero, 0.3 * one, 0.4 * one], -1),
                         np.stack([zero, one, zero, zero], -1),
                         np.stack([0.3 * one, zero, one, zero], -1),
                         np.stack([0.4 * one, zero, zero, 0.5 * one], -1)], -2)

    def A(x):
        s = np.sin(x[..., 0]); one = np.ones_like(s); zero = 0 * s
        return np.stack([np.stack([zero, zero, one, zero], -1),
                         np.stack([0.2 * s, one, zero, -one], -1)], -2)

    system = liefi.NonholonomicSystem.from_velocity_constraints(
        liefi.TrivialPrincipalBundle(SE2(), 1, names=("psi",)), metric, A)
    z0 = system.project(np.array([0.3, 1.0, 0.5, 0.0, -0.2]))
    y0, T = np.concatenate([SE2().identity_config(), z0]), 10.0
else:
    from liefi import scenes

    sc = scenes.get(case)
    system, T = sc.system, sc.t_final
    y0 = np.asarray(sc.initial_state(sc.variant()), float)
fi = liefi.FeedbackIntegrator(system, y0)
out = []
for _ in range(2):
    w, c = time.perf_counter(), time.process_time()
    sol = fi.run(T)
    out.append((time.perf_counter() - w, time.process_time() - c))
print(json.dumps({"runs": out, "backend": sol.backend, "steps": int(sol.steps),
                  "numba_imported": "numba" in sys.modules}))
"""


def _case(case, env):
    p = subprocess.run([sys.executable, "-c", _CASE, case], cwd=ROOT, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{case} failed: {p.stderr.strip()[-400:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", default=["readme", "suslov", "rigid-body"])
    ap.add_argument("--repeat", type=int, default=3, help="fresh processes per case (best of; default 3)")
    args = ap.parse_args(argv)
    print("| case | backend | steps | first run wall (s) | second run wall (s) | overhead wall (s) | overhead CPU (s) |")
    print("|---|---|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory(prefix="liefi-first-") as cache:
        env = dict(os.environ, LIEFI_CACHE_DIR=cache, PYTHONPATH=ROOT)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        for case in args.cases:
            _case(case, env)  # fill the cache
            got = [_case(case, env) for _ in range(max(1, args.repeat))]
            best = min(got, key=lambda g: g["runs"][0][0] - g["runs"][1][0])
            (w1, c1), (w2, c2) = best["runs"]
            cpu = min(g["runs"][0][1] - g["runs"][1][1] for g in got)
            print(f"| {case} | {best['backend']} | {best['steps']} | {w1:.3f} | {w2:.3f} | {w1 - w2:.3f} | {cpu:.3f} |",
                  flush=True)
    print(f"\nload average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
