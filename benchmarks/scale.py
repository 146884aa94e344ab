"""How the fixed costs grow with the system: a chain of ``N`` knife edges (issue 26).

Run (from the repository root)::

    python benchmarks/scale.py                      # N = 1, 2, 4, 8, 16, 32, best of 2 fresh processes
    python benchmarks/scale.py --n 1 2 4 8 16 32 64 --repeat 3
    python benchmarks/scale.py --profile 8          # cProfile of the trace at N = 8, by cumulative time

The system is built from data, as a user would: ``N`` copies of the knife-edge scene's data
(:mod:`liefi.scenes.knife_edge`) on ``T*R^{3N}``, ``q = (x_1, y_1, phi_1, ..., x_N, y_N, phi_N)``,
metric ``diag(m, m, J, ...)``, one Pfaffian row per edge (``e_i`` = ``(sin phi_i, -cos phi_i, 0)`` in
the slots of edge ``i``) and the potential

.. math:: U = -m g \\sin\\alpha \\sum_i x_i + \\frac{k}{2} \\sum_{i<N}
          \\big((x_{i+1} - x_i)^2 + (y_{i+1} - y_i - \\ell)^2\\big),

springs of rest length ``ell`` between neighbours: ``6N`` states, ``N`` constraints.  Each ``N`` runs in
fresh processes (one first to fill the kernel cache, then ``--repeat`` timed, best of) and reports, in
CPU seconds (``time.process_time``): construction (system and
:class:`~liefi.FeedbackIntegrator`), trace (the trace and code generation of
:func:`liefi.engine.kernels.compile_split`), load (the kernel from the warm cache), integrate
(``imex-rk4``, ``dt`` 1e-3 over ``[0, 1]``), the whole first ``fi.run`` (the integration with its
checks before and after: the stability estimate, the guard's audit) and the peak RSS of the process; then the fitted growth
exponents ``d log(cost) / d log(N)`` over the measured ``N`` (least squares, ``N >= 4``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def chain(N, *, m=1.0, J=1.0, g=1.0, alpha=np.pi / 6, k=1.0, ell=1.0):
    """The :class:`~liefi.NonholonomicSystem` of ``N`` knife edges joined by springs, and a start on ``J = 0``."""
    import liefi

    def potential(q):
        x, y = q[..., 0::3], q[..., 1::3]
        U = -m * g * np.sin(alpha) * np.sum(x, -1)
        if N > 1:
            U = U + 0.5 * k * np.sum((x[..., 1:] - x[..., :-1]) ** 2 + (y[..., 1:] - y[..., :-1] - ell) ** 2, -1)
        return U

    def constraint(q):
        phi = q[..., 2::3]
        s, c, zero = np.sin(phi), -np.cos(phi), np.zeros_like(phi[..., 0])
        rows = []
        for i in range(N):
            row = [zero] * (3 * N)
            row[3 * i], row[3 * i + 1] = s[..., i] / np.sqrt(m), c[..., i] / np.sqrt(m)
            rows.append(np.stack(row, -1))
        return np.stack(rows, -2)

    space = liefi.CotangentBundle(3 * N)
    system = liefi.NonholonomicSystem(space, np.diag([m, m, J] * N), constraint, potential)
    q0 = np.zeros(3 * N)
    q0[1::3] = ell * np.arange(N)
    q0[2::3] = 0.1 * np.arange(N)
    p0 = np.zeros(3 * N)
    p0[2::3] = 0.5
    return system, np.concatenate([q0, p0])


_CASE = r"""
import json, resource, sys, time, warnings
warnings.simplefilter("ignore")
sys.path.insert(0, sys.argv[2])
import numpy as np
import liefi
from liefi.engine import cache, kernels
from scale import chain
N = int(sys.argv[1])
out = {}
t = time.process_time()
system, y0 = chain(N)
fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=10.0)
out["construction"] = time.process_time() - t
spent = [0.0]
load = cache.load
def timed_load(*a, **k):
    t = time.process_time(); got = load(*a, **k); spent[0] += time.process_time() - t; return got
cache.load = timed_load
t = time.process_time()
compiled = kernels.compile_split(fi)
out["trace"] = time.process_time() - t - spent[0]
out["load"] = spent[0]
out["nodes"] = compiled.nodes
t = time.process_time()
sol = fi.run(1.0, dt=1e-3, scheme="imex-rk4")
out["run"] = time.process_time() - t
out["integrate"] = float(sol.cpu_seconds)
out["ns_per_step"] = 1e9 * float(sol.cpu_seconds) / 1000
out["rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
out["y_end"] = sol.y[:, -1].tolist()
print("RESULT " + json.dumps(out))
"""

COLUMNS = ("construction", "trace", "load", "integrate", "run", "ns_per_step", "rss_mib", "nodes")


def measure(N, repeat, timeout):
    """Best of ``repeat`` fresh processes at ``N`` (after one that fills the kernel cache); ``None`` on failure."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    best = None
    for i in range(repeat + 1):
        try:
            p = subprocess.run([sys.executable, "-c", _CASE, str(N), os.path.dirname(os.path.abspath(__file__))],
                               capture_output=True, text=True, env=env, timeout=timeout)
        except subprocess.TimeoutExpired:
            print(f"N = {N}: over {timeout} s, stopped", flush=True)
            return best
        got = [line for line in p.stdout.splitlines() if line.startswith("RESULT ")]
        if not got:
            print(f"N = {N} failed:\n{p.stderr[-2000:]}", flush=True)
            return best
        r = json.loads(got[0][7:])
        if i == 0 and repeat > 0:
            continue  # fills the kernel cache
        best = r if best is None else {k: (min(best[k], r[k]) if k in COLUMNS else r[k]) for k in r}
    return best


def exponents(ns, rows, key, n_min=4):
    """Least-squares slope of ``log rows[key]`` against ``log N`` over ``N >= n_min`` (``nan`` below 2 points)."""
    pts = [(np.log(n), np.log(r[key])) for n, r in zip(ns, rows) if r is not None and n >= n_min and r[key] > 0]
    if len(pts) < 2:
        return float("nan")
    x, y = np.array(pts).T
    return float(np.polyfit(x, y, 1)[0])


def profile(N, top=40):
    """cProfile of the trace and code generation of the chain at ``N``, sorted by cumulative time."""
    import cProfile
    import pstats

    import liefi
    from liefi.engine import kernels

    system, y0 = chain(N)
    fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=10.0)
    from liefi.engine import cache

    cache.load = lambda source, engine="numba": _NoLoad()  # the trace only
    pr = cProfile.Profile()
    pr.enable()
    try:
        kernels.compile_split(fi, engine="python")
    except Exception:  # noqa: BLE001 -- the stand-in kernel is not a real one
        pass
    pr.disable()
    pstats.Stats(pr).sort_stats("cumulative").print_stats(top)


class _NoLoad:
    def claim(self):
        return False


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=1800.0)
    ap.add_argument("--profile", type=int, default=None, metavar="N")
    args = ap.parse_args(argv)
    if args.profile is not None:
        profile(args.profile)
        return
    from _machine import cpu_model  # benchmarks/_machine.py (here: the chain imports from its path alone)

    print(f"CPU: {cpu_model()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; CPU seconds, best of "
          f"{args.repeat} fresh processes (warm kernel cache)")
    head = f"{'N':>4} {'states':>6} {'build s':>8} {'trace s':>8} {'load s':>8} {'integ s':>8} {'run s':>8} " \
           f"{'ns/step':>8} {'RSS MiB':>8} {'nodes':>8}"
    print(head, flush=True)
    rows = []
    for N in args.n:
        r = measure(N, args.repeat, args.timeout)
        rows.append(r)
        if r is not None:
            print(f"{N:>4} {6 * N:>6} {r['construction']:>8.3f} {r['trace']:>8.3f} {r['load']:>8.3f} "
                  f"{r['integrate']:>8.3f} {r['run']:>8.3f} {r['ns_per_step']:>8.0f} {r['rss_mib']:>8.0f} {r['nodes']:>8}",
                  flush=True)
    print("growth N^a (N >= 4): " + ", ".join(
        f"{k} {exponents(args.n, rows, k):.2f}" for k in ("construction", "trace", "integrate", "run", "rss_mib",
                                                           "nodes")))


if __name__ == "__main__":
    main()
