"""Memory and CPU of the adjoint's backward sweep: every state kept against checkpointed segments.

Run (from the repository root; numba required; the first call compiles the adjoint's loops)::

    python benchmarks/adjoint_checkpoints.py                  # Suslov, imex-rk4, 20 000 and 200 000 steps
    python benchmarks/adjoint_checkpoints.py --steps 20000 --reps 5

For each number of steps ``N`` it runs :func:`liefi.integrator.adjoint.vjp` (compiled) with
``checkpoints="all"`` (every state kept) and with the default for long runs, ``ceil(sqrt(N))``
kept states, and prints the CPU seconds (best of ``--reps``, against the plain compiled run),
the peak of the memory numpy allocates during the call (``tracemalloc``), and whether the two
gradients are bitwise equal.  The loss reads the state every ``--save-every`` steps.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import tracemalloc

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from liefi import scenes  # noqa: E402
from liefi.integrator.adjoint import vjp  # noqa: E402
from _machine import cpu_model  # noqa: E402 -- benchmarks/_machine.py


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scheme", default="imex-rk4")
    ap.add_argument("--dt", type=float, default=1e-3)
    ap.add_argument("--steps", nargs="+", type=int, default=[20_000, 200_000])
    ap.add_argument("--save-every", type=int, default=1000)
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args(argv)
    fi = scenes.get("suslov").integrator(gains=10.0, configuration=True)
    dt = args.dt
    kw = dict(dt=dt, scheme=args.scheme, backend="numba", adaptive=False, check_stability=False)
    fi.run(10 * dt, **kw)  # compile
    vjp(fi, args.scheme, fi.y0, dt, 10, np.array([10]), np.ones((fi.n, 1)), engine="numba")
    print(f"# Suslov, {args.scheme}, gains 10, dt {dt:g}, n = {fi.n}; CPU: {cpu_model()}; best of {args.reps}")
    print(f"{'steps':>8} {'checkpoints':>11} {'CPU s':>8} {'plain runs':>10} {'peak MB':>8} {'states MB':>9} "
          f"{'bitwise':>7}")
    for N in args.steps:
        saved = np.unique(np.r_[np.arange(0, N + 1, args.save_every), N]).astype(np.int64)
        W = np.random.default_rng(1).standard_normal((fi.n, saved.size))
        plain = min(fi.run(N * dt, save_every=args.save_every, **kw).cpu_seconds for _ in range(args.reps))
        res = {}
        for ck in ("all", math.isqrt(N - 1) + 1):
            best = np.inf
            for _ in range(args.reps):
                t = time.process_time()
                g = vjp(fi, args.scheme, fi.y0, dt, N, saved, W, engine="numba", checkpoints=ck)
                best = min(best, time.process_time() - t)
            tracemalloc.start()
            vjp(fi, args.scheme, fi.y0, dt, N, saved, W, engine="numba", checkpoints=ck)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            res[ck] = g
            same = all(np.array_equal(a, b) for a, b in zip(g, res["all"]))
            print(f"{N:>8} {ck!s:>11} {best:>8.3f} {best / plain:>10.2f} {peak / 1e6:>8.2f} "
                  f"{8 * fi.n * (N + 1) / 1e6 if ck == 'all' else 8 * fi.n * (ck + 2 * (-(-N // ck))) / 1e6:>9.3f} "
                  f"{str(same):>7}")
        print(f"{N:>8} {'plain run':>11} {plain:>8.3f} {1.0:>10.2f}")


if __name__ == "__main__":
    main()
