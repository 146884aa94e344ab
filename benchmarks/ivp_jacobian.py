"""solve_ivp's implicit methods on liefi's field, without and with the exact Jacobian ``jac=fi.jac``.

The system is the README's (``examples/user_system.py``: a planar body on SE(2)
with a rotor, gains 10); ``solve_ivp(fi.fun, (0, T), y0, method=M)`` with
finite-difference Jacobians against ``jac=fi.jac``.  Best of ``--repeat``
interleaved runs (process time).  "calls of fun" counts every evaluation of the
field, the finite differences' included (scipy's ``nfev`` leaves those out);
``njev`` and ``nlu`` are scipy's counts of Jacobians and LU factorizations.

    python benchmarks/ivp_jacobian.py [--t-final 10] [--repeat 3] [--methods Radau,BDF] [--rtol 1e-3 --atol 1e-6]
                                      [--gains 10]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import liefi  # noqa: E402
from liefi.groups import SE2  # noqa: E402


def readme_integrator(gains=10.0):
    """The README's system and integrator (the data of ``examples/user_system.py``; its gains 10)."""

    def metric(x):
        c = np.cos(x[..., 0]); one = np.ones_like(c); zero = 0 * c  # noqa: E702
        return np.stack([np.stack([2 + 0.5 * c, zero, 0.3 * one, 0.4 * one], -1),
                         np.stack([zero, one, zero, zero], -1),
                         np.stack([0.3 * one, zero, one, zero], -1),
                         np.stack([0.4 * one, zero, zero, 0.5 * one], -1)], -2)

    def A(x):
        s = np.sin(x[..., 0]); one = np.ones_like(s); zero = 0 * s  # noqa: E702
        return np.stack([np.stack([zero, zero, one, zero], -1),
                         np.stack([0.2 * s, one, zero, -one], -1)], -2)

    racer = liefi.NonholonomicSystem.from_velocity_constraints(
        liefi.TrivialPrincipalBundle(SE2(), 1, names=("psi",)), metric, A)
    z0 = racer.project(np.array([0.3, 1.0, 0.5, 0.0, -0.2]))
    y0 = np.concatenate([SE2().identity_config(), z0])
    return liefi.FeedbackIntegrator(racer, y0, gains=gains)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-final", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--methods", default="Radau,BDF")
    ap.add_argument("--rtol", type=float, default=1e-3)
    ap.add_argument("--atol", type=float, default=1e-6)
    ap.add_argument("--gains", type=float, default=10.0)
    a = ap.parse_args(argv)
    fi = readme_integrator(a.gains)
    fi.jac(0.0, fi.y0)  # generate the Jacobian once, outside the timings
    T = a.t_final
    rows = []
    for method in a.methods.split(","):
        best = {"fd": np.inf, "jac": np.inf}
        res = {}
        for _ in range(a.repeat):  # interleaved
            for key, jac in (("fd", None), ("jac", fi.jac)):
                calls = [0]

                def fun(t, y):
                    calls[0] += 1
                    return fi.fun(t, y)

                t = time.process_time()
                r = solve_ivp(fun, (0, T), fi.y0, method=method, jac=jac, rtol=a.rtol, atol=a.atol)
                best[key] = min(best[key], time.process_time() - t)
                r.calls = calls[0]
                res[key] = r
        diff = float(np.max(np.abs(res["fd"].y[:, -1] - res["jac"].y[:, -1])))
        for key in ("fd", "jac"):
            r = res[key]
            rows.append((method, "finite differences" if key == "fd" else "jac=fi.jac", r.status, r.calls, r.nfev,
                         r.njev, r.nlu, r.t.size - 1, best[key]))
        rows.append((method, "ratio", "", "", "", "", "", "", best["fd"] / best["jac"]))
        print(f"# {method}: final states differ by {diff:.2e}", file=sys.stderr)
    print(f"README system, gains {a.gains:g}, t in [0, {T:g}], rtol={a.rtol:g}, atol={a.atol:g}, best of {a.repeat}\n")
    print("| method | Jacobian | status | calls of fun | nfev | njev | nlu | steps | CPU [s] |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for m, k, st, calls, nfev, njev, nlu, steps, sec in rows:
        cpu = f"{sec:.2f}x faster" if k == "ratio" else f"{sec:.3f}"
        print(f"| {m} | {k} | {st} | {calls} | {nfev} | {njev} | {nlu} | {steps} | {cpu} |")


if __name__ == "__main__":
    main()
