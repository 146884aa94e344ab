"""Reverse mode (:mod:`liefi.integrator.adjoint`): ``w . dy/d(y0, theta)`` equals the forward tangents' ``sum_t S_t^T w_t``.

The forward tangents are checked against derivatives of whole runs in ``tests/test_sensitivity.py``; here
the adjoint of the same discrete run must agree with them to rounding, for a split and an explicit scheme,
the gains ``"auto"`` resolved (held), an adaptive gain schedule, the constants of ``from_mechanics`` and
parameters declared by hand (the targets taken at the start follow ``y0`` and ``theta``).  Plain Python
(``engine="python"``), short runs.
"""

import numpy as np
import pytest

import liefi
from liefi.integrator import adjoint, sensitivity
from liefi.scenes import get as get_scene
from liefi.schemes import registry

from models import sleigh_model
from test_sensitivity_parameters import hand_sleigh


def forward_reference(fi, sch, y0, dt, n_steps, saved, W, schedule=None):
    n, P = fi.n, len(sensitivity.parameter_names(fi.system))
    V = np.vstack([np.eye(n), np.zeros((P, n))])
    C = np.vstack([np.zeros((n, P)), np.eye(P)])
    _, S = sensitivity.tangents(fi, sch, y0, dt, n_steps, saved, V, C, schedule=schedule)
    g = np.einsum("jnt,nt->j", S, W)
    return g[:n], g[n:]


def check(fi, scheme, y0, dt, n_steps, saved, schedule=None):
    sch = registry.get(scheme)
    W = np.random.default_rng(3).standard_normal((fi.n, len(saved)))
    gy, gc = adjoint.vjp(fi, sch, y0, dt, n_steps, saved, W, schedule=schedule)
    ry, rc = forward_reference(fi, sch, y0, dt, n_steps, saved, W, schedule)
    scale = np.max(np.abs(np.r_[ry, rc]))
    assert np.max(np.abs(gy - ry)) / scale < 1e-12
    assert gc.shape == rc.shape and (rc.size == 0 or np.max(np.abs(gc - rc)) / scale < 1e-12)
    return gy, gc


@pytest.mark.parametrize("scheme", ["imex-rk4", "rk4"])
def test_suslov_adjoint_matches_the_forward_tangents(scheme):
    fi0 = get_scene("suslov").integrator(gains="auto", configuration=True)
    sol = fi0.run(0.2, dt=0.01, scheme=scheme, backend="numpy", adaptive=False)
    fi = liefi.FeedbackIntegrator(fi0.system, fi0.y0, gains=sol.stability.gains, configuration=True)
    if sol.dropped:
        fi = fi.without({d["name"]: d["reason"] for d in sol.dropped})
    check(fi, scheme, fi0.y0, 0.01, 20, np.array([0, 3, 7, 20]))


def test_suslov_adjoint_with_an_adaptive_gain_schedule():
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    g = fi.run(0.02, dt=0.01, scheme="euler", backend="numpy").stability.gains  # {name: gain}
    sched = [(0, fi.parameters(gains=g)), (7, fi.parameters(gains={k: 0.4 * v for k, v in g.items()})),
             (15, fi.parameters(gains={k: 2.0 * v for k, v in g.items()}))]
    check(fi, "euler", fi.y0, 0.01, 20, np.array([0, 7, 12, 20]), schedule=sched)


def test_from_mechanics_constants_and_declared_parameters_by_the_adjoint():
    LM, (m, I, a) = sleigh_model()
    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    sleigh = liefi.from_mechanics(LM, {m: 1.0, I: 0.5, a: 0.3})
    _, gc = check(liefi.FeedbackIntegrator(sleigh, y0, configuration=False, gains=5.0), "imex-rk4", y0, 0.01, 20,
                  np.array([0, 5, 20]))
    assert gc.shape == (3,) and np.all(np.abs(gc) > 0)
    system, _ = hand_sleigh()
    _, gc = check(liefi.FeedbackIntegrator(system, y0, configuration=False, gains=5.0), "rk4", y0, 0.01, 20,
                  np.array([10, 20]))
    assert gc.shape == (2,)


def test_bad_cotangents_are_refused():
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    with pytest.raises(ValueError, match=r"W: expected dL/dy at the saved steps, shape \(n, n_t\) = \(12, 2\)"):
        adjoint.vjp(fi, "rk4", fi.y0, 0.01, 10, [0, 10], np.ones((12, 3)))
    with pytest.raises(ValueError, match="saved_steps: expected increasing steps"):
        adjoint.vjp(fi, "rk4", fi.y0, 0.01, 10, [10, 0], np.ones((12, 2)))


@pytest.mark.slow  # numba compiles the adjoint's loops
def test_the_compiled_adjoint_agrees_with_the_python_one():
    pytest.importorskip("numba")
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    sch = registry.get("imex-rk4")
    saved = np.array([0, 50, 100])
    W = np.random.default_rng(2).standard_normal((fi.n, saved.size))
    a = adjoint.vjp(fi, sch, fi.y0, 0.01, 100, saved, W, engine="python")[0]
    b = adjoint.vjp(fi, sch, fi.y0, 0.01, 100, saved, W, engine="numba")[0]
    assert np.max(np.abs(a - b)) / np.max(np.abs(a)) < 1e-13
