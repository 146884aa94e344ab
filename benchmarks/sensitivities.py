"""Cost of forward sensitivities: a compiled run with k tangent directions against the plain run and central differences.

Run (from the repository root; numba required; the first call compiles the tangent kernel,
minutes under load, then numba's disk cache serves it)::

    python benchmarks/sensitivities.py                      # Suslov with R, imex-rk4, gains="auto"
    python benchmarks/sensitivities.py --scheme rk4 --gains 50 --t-final 20

For ``k`` = 1, 4, 16 random directions of the start it prints the CPU seconds of

* the plain compiled run (``fi.run(backend="numba")``, ``solution.cpu_seconds``: the loop alone);
* the compiled tangent run (:func:`liefi.integrator.sensitivity.tangents`, ``engine="numba"``:
  the states and their ``k`` tangents, the compile excluded by a warm-up), and its ratio to the
  plain run against the target ``1 + k``;
* central differences of whole compiled runs at equal ``k`` (``2 k`` runs), and their ratio;
* the adjoint (:func:`liefi.integrator.adjoint.vjp`, compiled): the gradient of one scalar loss by
  ``y0`` and every parameter, whatever their number;

best of ``--reps``, with the CPU model (``benchmarks/_machine.py``).  Both sides save every
``--save-every`` steps.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import liefi  # noqa: E402
from liefi import scenes  # noqa: E402
from liefi.integrator.adjoint import vjp  # noqa: E402
from liefi.integrator.sensitivity import tangents  # noqa: E402
from liefi.schemes import registry  # noqa: E402
from _machine import cpu_model  # noqa: E402 -- benchmarks/_machine.py


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="suslov")
    ap.add_argument("--scheme", default="imex-rk4")
    ap.add_argument("--gains", default="auto")
    ap.add_argument("--dt", type=float, default=1e-3)
    ap.add_argument("--t-final", type=float, default=50.0)
    ap.add_argument("--save-every", type=int, default=100)
    ap.add_argument("--ks", nargs="+", type=int, default=[1, 4, 16])
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args(argv)
    gains = args.gains if args.gains == "auto" else float(args.gains)
    sc = scenes.get(args.scene)
    fi = sc.integrator(gains=gains, configuration=True)
    T, dt = args.t_final, args.dt
    n_steps = int(round(T / dt))
    kw = dict(dt=dt, scheme=args.scheme, backend="numba", save_every=args.save_every, adaptive=False)
    sol = fi.run(T, **kw)  # compile, and the gains "auto" resolves (held for the other runs)
    run_fi = liefi.FeedbackIntegrator(fi.system, fi.y0, gains=sol.stability.gains, configuration=True,
                                      invariants=(("constraints",) if fi.use_constraints else ())
                                      + (("energy",) if fi.use_energy else ()) + tuple(fi.user))
    if sol.dropped:
        run_fi = run_fi.without({d["name"]: d["reason"] for d in sol.dropped})
    sch = registry.get(args.scheme)
    saved = np.r_[np.arange(0, n_steps + 1, args.save_every), [n_steps] if n_steps % args.save_every else []]
    saved = saved.astype(np.int64)
    t = time.perf_counter()
    for k in args.ks:  # compile (or load) the tangent loop of every k
        tangents(run_fi, sch, fi.y0, dt, 10, np.arange(11), np.eye(fi.n)[:1].repeat(k, 0), engine="numba")
    Wl = np.random.default_rng(1).standard_normal((fi.n, saved.size))  # a loss's dL/dy at the saved states
    vjp(run_fi, sch, fi.y0, dt, 10, saved[saved <= 10], Wl[:, saved <= 10], engine="numba")
    compile_s = time.perf_counter() - t
    rng = np.random.default_rng(0)
    Vs = {k: rng.standard_normal((k, fi.n)) for k in args.ks}
    # interleaved: every repetition runs the plain run, then the tangents of every k; best of the repetitions
    plain, best, out, adj = np.inf, {k: np.inf for k in args.ks}, {}, np.inf
    for _ in range(args.reps):
        plain = min(plain, fi.run(T, **kw).cpu_seconds)
        t = time.process_time()
        vjp(run_fi, sch, fi.y0, dt, n_steps, saved, Wl, engine="numba")
        adj = min(adj, time.process_time() - t)
        for k in args.ks:
            t = time.process_time()
            out[k] = tangents(run_fi, sch, fi.y0, dt, n_steps, saved, Vs[k], engine="numba")
            best[k] = min(best[k], time.process_time() - t)
    print(f"# {args.scene}, {args.scheme}, gains {args.gains} (resolved once, held), dt {dt:g}, t_final {T:g} "
          f"({n_steps} steps), n = {fi.n}; CPU: {cpu_model()}; best of {args.reps} interleaved repetitions")
    print(f"# plain compiled run: {plain:.4f} s CPU (loop); tangent kernels compile/load: {compile_s:.1f} s wall")
    print(f"# adjoint (reverse mode: dL/dy0 and dL/dtheta of one scalar loss, any number of parameters): {adj:.4f} s "
          f"CPU, {adj / plain:.2f} plain runs")
    print(f"{'k':>3} {'tangents s':>11} {'ratio':>7} {'target 1+k':>10} {'central FD s':>13} {'FD ratio':>9} "
          f"{'max |S_tan - S_FD| / |S|':>24}")
    for k in args.ks:
        V = Vs[k]
        Y, S = out[k]
        h = 1e-6
        fd_cpu, fd = 0.0, []
        for j in range(k):
            ys = []
            for s in (h, -h):
                f = liefi.FeedbackIntegrator(fi.system, fi.y0 + s * V[j], gains=sol.stability.gains,
                                             configuration=True)
                if sol.dropped:
                    f = f.without({d["name"]: d["reason"] for d in sol.dropped})
                r = f.run(T, **kw)
                fd_cpu += r.cpu_seconds
                ys.append(r.y)
            fd.append((ys[0] - ys[1]) / (2 * h))
        err = max(float(np.max(np.abs(S[j] - fd[j])) / np.max(np.abs(S[j]))) for j in range(k))
        print(f"{k:>3} {best[k]:>11.4f} {best[k] / plain:>7.2f} {1 + k:>10} {fd_cpu:>13.4f} {fd_cpu / plain:>9.2f} "
              f"{err:>24.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
