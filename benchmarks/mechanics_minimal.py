"""The minimal-speeds models of ``tests/test_mechanics_minimal.py``: build time, error against the model's own
equations and drift, one row per model.

* ``model [s]``: writing the model and sympy's ``kanes_equations`` (or ``form_lagranges_equations``);
* ``from_mechanics [s]``: liefi's build;
* ``error``: ``max |(q, u) - (q, u)_own|`` at ``t = 2``, both fields integrated by DOP853 at 1e-12 (relative to
  ``max(1, |u|)``);
* ``drift``: the largest change of a constraint row ``J_i`` and of the energy ``h~`` along liefi's default run
  over ``[0, 2]`` (numpy backend).

Run from the repository root: ``python benchmarks/mechanics_minimal.py [name ...]``.
"""

from __future__ import annotations

import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import liefi  # noqa: E402
import test_mechanics_minimal as T  # noqa: E402


def row(name, make):
    t0 = time.perf_counter()
    eom, consts, start, _ = make()
    t_model = time.perf_counter() - t0
    t0 = time.perf_counter()
    system = liefi.from_mechanics(eom, consts)
    t_build = time.perf_counter() - t0
    err, z0 = T.error_against_own(eom, consts, start, system)
    fi = liefi.FeedbackIntegrator(system, z0)
    run = fi.run(2.0, backend="numpy")
    inv = fi.invariant_values(np.moveaxis(run.y, -1, 0))
    J = max((float(np.max(np.abs(inv[f"J_{i + 1}"] - inv[f"J_{i + 1}"][0]))) for i in range(system.K)), default=0.0)
    h = float(np.max(np.abs(inv["h~"] - inv["h~"][0])))
    print(f"| {name} | {', '.join(system.restored_coordinates) or '-'} | {t_model:.2f} | {t_build:.2f} | {err:.1e} | "
          f"{J:.1e} | {h:.1e} |", flush=True)


def main(names):
    models = dict(T.MODELS, rattleback=T.rattleback)
    print("| model | restored | model + sympy's equations [s] | from_mechanics [s] | error vs sympy, t = 2 | "
          "constraint drift | energy drift |")
    print("|---|---|---|---|---|---|---|")
    for name in names or models:
        row(name, models[name])


if __name__ == "__main__":
    main(sys.argv[1:])
