"""The rattleback's time to result with liefi, in fresh processes (issue: the PyDy peer).

What a user pays for Kane & Levinson's rattleback over ``t in [0, 20]`` s, from
a fresh Python process with the kernel cache warm: starting Python, importing
liefi, building the system from the body's data (:func:`liefi.rolling.rolling_body`,
through the ``rattleback`` scene), choosing the order and step for ``rtol``
(:func:`liefi.tolerance.choose_step`, not kept: ``LIEFI_REFERENCE_STORE=0``),
loading the kernels and integrating.  The state error against the scene's
DOP853 reference (``rtol = 1e-13``), the energy's and the rolling constraint's
drift are measured in a separate process, so the reference's cost is not part
of the time.  Compare with ``docs/rattleback_peer.md`` (``benchmarks/rattleback_pydy.py``):
derivation + code generation + integration of the PyDy peer at the same state error.

Run from the repository root::

    python benchmarks/rattleback_time_to_result.py                  # rtol 1e-6, 1e-8; best of 3 wall times
    python benchmarks/rattleback_time_to_result.py --rtols 1e-7 --repeat 5
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

CHILD = r"""
import json, sys, time
c0 = time.process_time()
from liefi import scenes
sc = scenes.get("rattleback")
res = sc.run(t_final={T!r}, rtol={rtol!r}, choose_order=True, scheme="imex-rk4", gains="auto")
out = {{"cpu": time.process_time() - c0, "integration_cpu": res.cpu_seconds, "scheme": res.method["scheme"],
        "dt": res.dt}}
if {errors!r}:
    out["max_error"] = max(res.max_error.values())
    out["max_drift"] = res.max_drift
print(json.dumps(out))
"""


def child(T, rtol, errors):
    env = dict(os.environ, LIEFI_REFERENCE_STORE="0" if not errors else os.environ.get("LIEFI_REFERENCE_STORE", "1"))
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as an installed package runs
    w = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", CHILD.format(T=T, rtol=rtol, errors=errors)], cwd=ROOT, env=env,
                       capture_output=True, text=True, check=True)
    wall = time.perf_counter() - w
    return wall, json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rtols", type=float, nargs="+", default=[1e-6, 1e-8])
    ap.add_argument("--t-final", type=float, default=20.0)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    child(a.t_final, a.rtols[0], False)  # kernels compiled and cached once
    print("| rtol | scheme | dt | wall (s), fresh process | CPU (s) | integration CPU (s) | state error | "
          "largest drift |")
    print("|---|---|---|---|---|---|---|---|")
    for rtol in a.rtols:
        runs = [child(a.t_final, rtol, False) for _ in range(a.repeat)]
        wall, info = min(runs, key=lambda r: r[0])
        _, acc = child(a.t_final, rtol, True)
        drift = max(acc["max_drift"].values())
        print(f"| {rtol:g} | {info['scheme']} | {info['dt']:.3g} | {wall:.2f} | {info['cpu']:.2f} | "
              f"{info['integration_cpu']:.3f} | {acc['max_error']:.2g} | {drift:.2g} |", flush=True)


if __name__ == "__main__":
    main()
