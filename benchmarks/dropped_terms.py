"""Per-step cost saved by leaving out of V the invariants the scheme keeps exactly (vertical disk, RK4).

    PYTHONPATH=. python benchmarks/dropped_terms.py      # from the repository root

Runs the ``vertical-disk`` scene's integrator (every momentum ``Pi_*`` is kept
exactly by any Runge--Kutta scheme, :func:`liefi.gains.exactly_kept`) with
``drop_exact=True`` (the default: no feedback term) and ``drop_exact=False``
(every term), on the numpy and the compiled backend, in the same process, and
prints the CPU seconds per step and their ratio (best of a few repeats).
"""

import sys
import warnings

from liefi import scenes


def per_step(fi, backend, n, drop, repeats=3):
    best = float("inf")
    for _ in range(repeats):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = fi.run(n * 1e-3, dt=1e-3, scheme="rk4", backend=backend, drop_exact=drop, save_every=n)
        best = min(best, sol.cpu_seconds / n)
    return best, sol


def main():
    sc = scenes.get("vertical-disk")
    for configuration in (False, True):
        fi = sc.integrator(configuration=configuration)
        for backend, n in (("numpy", 20000), ("numba", 2000000)):
            per_step(fi, backend, 1000, True, 1)  # load the kernels
            per_step(fi, backend, 1000, False, 1)
            a, sol = per_step(fi, backend, n, True)
            b, _ = per_step(fi, backend, n, False)
            print(f"vertical-disk configuration={configuration!s:5s} {backend:5s} {n:8d} steps: "
                  f"dropped {a * 1e6:8.3f} us/step, kept {b * 1e6:8.3f} us/step, saving {1 - a / b:6.1%} "
                  f"(dropped: {', '.join(d['name'] for d in sol.dropped)}; backend {sol.backend})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
