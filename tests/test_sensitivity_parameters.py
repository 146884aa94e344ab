"""Sensitivities by parameters declared on data built by hand (:mod:`liefi.systems.parameters`).

References, as in ``tests/test_sensitivity.py``: the data depend on ``x``, so the numpy field refuses a
complex state (two nested complex steps are not exact) and the reference is the 8th-order central
difference of whole runs of the numpy step map (truncation ``O(h^8)``, below 1e-12 at ``h = 1e-2``).  The targets the run takes at its start
(the energy) are taken at the perturbed parameter, as the sensitivities define them.
"""

import numpy as np
import pytest

import liefi
from liefi.integrator.sensitivity import _targets
from liefi.reduction.core import NUMPY_DATA
from liefi.schemes import registry
from liefi.schemes.split import feedback_step
from liefi.systems.parameters import Parameters, declare

from test_sensitivity import RTOL, central8, rel


def step_map_run(fr, sch, y0, T, dt, gains):
    """The numpy step map of ``sch`` on ``fr`` from ``y0``, the gains held, the targets taken at ``y0`` with the
    data's current parameters (complex ones too)."""
    p = _targets(fr, y0, fr.parameters(gains=gains).astype(complex if np.iscomplexobj(y0) else float), NUMPY_DATA)
    p = np.asarray(p, dtype=complex if np.iscomplexobj(p) or np.iscomplexobj(y0) else float)
    y, out = y0, [y0]
    for _ in range(int(round(T / dt))):
        if sch.kind == "split":
            y = feedback_step(fr, sch.explicit.step(lambda q: fr.unforced_vector_field(q, p), y, dt), dt, p)
        else:
            y = sch.step(lambda q: fr.vector_field(q, p), y, dt)
        out.append(y)
    return np.stack(out, -1)


# --- a sleigh built by hand: mass and contact offset declared, analytic data derivatives ---------------


def hand_sleigh():
    """The Chaplygin sleigh on ``T*R^3`` (``x, y, theta``): metric ``diag(m, m, I)``, the no-slip row
    ``(-sin theta, cos theta, -a)``; ``m`` and ``a`` read from the declared parameters."""
    par = Parameters(m=1.0, a=0.3)
    I = 0.5

    def metric(x):
        zero = 0.0 * x[..., :1, None]  # (..., 1, 1): the batch shape, and traceable
        return par["m"] * np.diag([1.0, 1.0, 0.0]) + np.diag([0.0, 0.0, I]) + zero

    def metric_derivative(x):
        return np.zeros(np.shape(x)[:-1] + (3, 3, 3))

    def constraints(x):
        th = x[..., 2]
        return np.stack([-np.sin(th), np.cos(th), -par["a"] + 0.0 * th], -1)[..., None, :]

    def constraints_derivative(x):
        th = x[..., 2]
        z = 0.0 * th
        d = np.stack([np.stack([z, z, z], -1), np.stack([z, z, z], -1), np.stack([-np.cos(th), -np.sin(th), z], -1)],
                     -2)
        return d[..., None, :]  # (..., n, K, D)

    sys_ = liefi.NonholonomicSystem(liefi.CotangentBundle(3), metric, constraints, metric_derivative=metric_derivative,
                                    constraints_derivative=constraints_derivative)
    return declare(sys_, par), par


@pytest.mark.parametrize("scheme", ["imex-rk4", "rk4"])
def test_hand_built_sleigh_two_declared_parameters(scheme):
    system, par = hand_sleigh()
    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    fi = liefi.FeedbackIntegrator(system, y0, configuration=False)  # gains="auto"
    T, dt = 0.2, 0.01
    sol = fi.run(T, dt=dt, scheme=scheme, backend="numpy", sensitivities=("y0", "m", "a"))
    assert sol.sensitivities["m"].shape == (fi.n, sol.t.size)
    fr = liefi.FeedbackIntegrator(system, y0, gains=sol.stability.gains, configuration=False)
    sch = registry.get(scheme)
    assert np.allclose(step_map_run(fr, sch, y0, T, dt, sol.stability.gains), sol.y, rtol=0, atol=1e-14)
    base = par.values.copy()
    for k, name in enumerate(par.names):
        def run(s, k=k):
            par.values = base + s * np.eye(2)[k]
            try:
                return step_map_run(fr, sch, y0, T, dt, sol.stability.gains)
            finally:
                par.values = base

        ref = central8(run, 1e-2)
        assert np.max(np.abs(ref)) > 1e-3  # the parameter moves the run
        assert rel(sol.sensitivities[name], ref) < RTOL, name


def test_declared_parameters_change_the_system_and_its_compiled_kernels():
    """A value set after the build is what the numpy run and a compiled run see (the kernels are kept per value)."""
    from liefi.engine import kernels

    system, par = hand_sleigh()
    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    fi = liefi.FeedbackIntegrator(system, y0, configuration=False, gains=5.0)
    kw = dict(dt=0.01, scheme="rk4")
    a = fi.run(0.2, backend="numpy", **kw).y
    par["a"] = 0.4
    b = fi.run(0.2, backend="numpy", **kw).y
    assert np.max(np.abs(a - b)) > 1e-3
    par["a"] = 0.3
    assert np.array_equal(fi.run(0.2, backend="numpy", **kw).y, a)
    first = kernels.compile_feedback(fi, engine="python")  # the trace folds the values into the code
    par["a"] = 0.4
    other = kernels.compile_feedback(fi, engine="python")
    assert other is not first
    par["a"] = 0.3
    assert kernels.compile_feedback(fi, engine="python") is first


def test_declare_refuses_what_is_no_parameters():
    system, _ = hand_sleigh()
    with pytest.raises(TypeError, match="parameters: expected"):
        declare(system, {"m": 1.0})
    with pytest.raises(KeyError, match="not a declared parameter"):
        Parameters(m=1.0)["r"]
    with pytest.raises(ValueError, match="m: expected a finite number"):
        Parameters(m=np.nan)
    fi = liefi.FeedbackIntegrator(system, np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5]), configuration=False, gains=5.0)
    with pytest.raises(ValueError, match=r"unknown name 'I'.*\['m', 'a'\]"):
        fi.run(0.1, dt=0.01, scheme="rk4", backend="numpy", sensitivities=("I",))


# --- the Chaplygin ball by rolling_body: radius and centre-of-mass height declared -------------------


def declared_ball():
    """``(ball, par, y0)``: the Chaplygin ball by ``rolling_body`` with its radius and centre-of-mass height declared."""
    from liefi.groups import SO3
    from liefi.systems.rolling import rolling_body, rolling_start

    par = Parameters(radius=1.0, height=0.05)
    e3 = np.array([0.0, 0.0, 1.0])

    def contact(G):  # the ball's centre of mass `height` above its centre, along the body's third axis
        G = np.asarray(G)
        return -par["radius"] * G - par["height"] * (e3 + 0.0 * G)

    ball = declare(rolling_body(1.0, [0.3, 0.4, 0.5], contact, gravity=1.0), par)
    return ball, par, rolling_start(ball, SO3().exp(np.array([0.3, -0.2, 0.1])), np.array([0.5, -0.3, 1.0]))


@pytest.mark.slow  # ~30 s: the ball's trace (25 states) and 16 runs of the reference
def test_chaplygin_ball_two_declared_parameters_through_a_split_scheme_with_auto_gains():
    ball, par, y0 = declared_ball()
    fi = liefi.FeedbackIntegrator(ball, y0)  # gains="auto"
    T, dt, scheme = 0.05, 0.01, "imex-rk4"
    sol = fi.run(T, dt=dt, scheme=scheme, backend="numpy", sensitivities=("radius", "height"))
    fr = liefi.FeedbackIntegrator(ball, y0, gains=sol.stability.gains)
    if sol.dropped:
        fr = fr.without({d["name"]: d["reason"] for d in sol.dropped})
    sch = registry.get(scheme)
    assert np.allclose(step_map_run(fr, sch, y0, T, dt, sol.stability.gains), sol.y, rtol=0, atol=1e-13)
    base = par.values.copy()
    for k, name in enumerate(par.names):
        def run(s, k=k):
            par.values = base + s * np.eye(2)[k]
            try:
                return step_map_run(fr, sch, y0, T, dt, sol.stability.gains)
            finally:
                par.values = base

        ref = central8(run, 1e-2)
        assert np.max(np.abs(ref)) > 1e-4
        assert rel(sol.sensitivities[name], ref) < RTOL, name


# --- Suslov's body built by hand, with weight: its centre-of-mass offset and weight declared ----------


def weighted_suslov(gradient=False):
    """Suslov's constrained rigid body (inertia and constraint of ``liefi.scenes.suslov``) under gravity, on the
    space with the advected vertical ``Gamma``: ``U = mg chi . Gamma``, ``chi = (0.1, 0, h)``; ``mg`` and ``h``
    declared (Suslov's own data are constant arrays, which parameters do not reach: the weight is a function).
    ``gradient=True`` also gives the weight's analytic gradient (then a complex step through a run is exact)."""
    from liefi.groups import SO3
    from liefi.groups.representation import Representation
    from liefi.scenes.suslov import Suslov

    par = Parameters(mg=1.0, h=0.3)

    def potential(x, G):
        return par["mg"] * (0.1 * G[..., 0] + par["h"] * G[..., 2])

    def potential_gradient(x, G):
        return par["mg"] * np.stack(np.broadcast_arrays(0.1 + 0 * G[..., 0], 0 * G[..., 1], par["h"] + 0 * G[..., 2]), -1)

    I, a = Suslov.inertia, Suslov.a
    e = np.linalg.solve(I, a) / np.sqrt(a @ np.linalg.solve(I, a))
    space = liefi.LieGroupPhaseSpace(SO3(), advected=Representation(SO3()), a0=[0.0, 0.0, 1.0])
    grad = dict(potential_gradient=potential_gradient) if gradient else {}
    system = declare(liefi.NonholonomicSystem(space, I, e, potential=potential, **grad), par)
    g0 = SO3().exp(np.array([0.4, 0.1, 0.0])).ravel()
    return system, par, np.concatenate([g0, space.advected_vector(g0), [0.0, 1.0, 1.0]])


def test_suslov_with_declared_weight_two_parameters_through_a_split_scheme_with_auto_gains():
    system, par, y0 = weighted_suslov()
    fi = liefi.FeedbackIntegrator(system, y0)  # gains="auto"
    T, dt, scheme = 0.2, 0.01, "imex-rk4"
    sol = fi.run(T, dt=dt, scheme=scheme, backend="numpy", sensitivities=("y0", "mg", "h"))
    fr = liefi.FeedbackIntegrator(system, y0, gains=sol.stability.gains)
    if sol.dropped:
        fr = fr.without({d["name"]: d["reason"] for d in sol.dropped})
    sch = registry.get(scheme)
    assert np.allclose(step_map_run(fr, sch, y0, T, dt, sol.stability.gains), sol.y, rtol=0, atol=1e-14)
    base = par.values.copy()
    for k, name in enumerate(par.names):
        def run(s, k=k):
            par.values = base + s * np.eye(2)[k]
            try:
                return step_map_run(fr, sch, y0, T, dt, sol.stability.gains)
            finally:
                par.values = base

        ref = central8(run, 1e-2)
        assert np.max(np.abs(ref)) > 1e-4
        assert rel(sol.sensitivities[name], ref) < RTOL, name
