"""The cost of compiled forward sensitivities against the plain compiled run (``benchmarks/sensitivities.py``).

The tangents step in one fused loop per ``k`` (:mod:`liefi.integrator._tangent_loop`): a direction
costs the tangent nodes of the step, about one to two plain steps.  The bounds are loose (a shared
machine; best of interleaved repetitions) but far below the generic loop this replaced (15x the plain
run at ``k = 1``, 45x at ``k = 16``, same case).
"""

import time

import numpy as np
import pytest

import liefi
from liefi.integrator.sensitivity import tangents
from liefi.scenes import get as get_scene
from liefi.schemes import registry


@pytest.mark.slow  # numba compiles of the plain run and of two tangent loops
def test_compiled_tangents_cost_a_few_plain_runs_per_direction():
    pytest.importorskip("numba")
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    T, dt = 20.0, 1e-3
    n_steps = int(round(T / dt))
    kw = dict(dt=dt, scheme="imex-rk4", backend="numba", save_every=100, adaptive=False)
    fi.run(T, **kw)
    sch = registry.get("imex-rk4")
    saved = np.arange(0, n_steps + 1, 100)
    V = {k: np.random.default_rng(0).standard_normal((k, fi.n)) for k in (1, 16)}
    for k in V:
        tangents(fi, sch, fi.y0, dt, 10, saved[:1], V[k], engine="numba")  # compile
    plain, best = np.inf, {k: np.inf for k in V}
    for _ in range(5):
        plain = min(plain, fi.run(T, **kw).cpu_seconds)
        for k in V:
            t = time.process_time()
            tangents(fi, sch, fi.y0, dt, n_steps, saved, V[k], engine="numba")
            best[k] = min(best[k], time.process_time() - t)
    assert best[1] / plain < 6.0, (best, plain)
    assert best[16] / plain < 30.0, (best, plain)
    for k in V:  # k = 1: the directions unrolled as scalars; k = 16: as lanes; both the numpy path's numbers
        a = tangents(fi, sch, fi.y0, dt, 50, np.array([0, 20, 50]), V[k], engine="python")[1]
        b = tangents(fi, sch, fi.y0, dt, 50, np.array([0, 20, 50]), V[k], engine="numba")[1]
        assert np.max(np.abs(a - b)) / np.max(np.abs(a)) < 1e-13, k
