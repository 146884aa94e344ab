"""The compiled engine computes the numpy reference's fields and runs (to 1e-12).

The generated code is checked in two ways: as plain Python (``engine="python"``,
no compilation: fast, so it runs over every kind of random system and every
scene) and compiled by numba on a few runs (the loops, ensembles, the
projection and DLA kernels).  No test here asserts a time.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import liefi
from liefi import FeedbackIntegrator, Invariant, compiled, scenes
from liefi.reduction import core as _core
from liefi.schemes import IntegrationError
from hypothesis import HealthCheck, settings

from strategies import MAX_EXAMPLES, SPACES, cases

TOL = 1e-12
needs_numba = pytest.mark.skipif(not compiled.available(), reason="numba is not installed")


def rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b), initial=0.0) / max(1.0, np.max(np.abs(b), initial=0.0)))


def _scene_list():
    out = []
    for name in scenes.names():
        try:
            scenes.get(name)
        except ImportError:  # a scene not written yet
            continue
        out.append(name)
    return out


SCENES = _scene_list()


# --------------------------------------------------------------------------------------
# the symbolic layer: derivatives and tracing
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "fun",
    [
        lambda x: np.sin(x[..., 0]) * np.cos(x[..., 1]) + x[..., 0] ** 3,
        lambda x: np.sqrt(1.0 + x[..., 0] ** 2) / (2.0 + np.tanh(x[..., 1])),
        lambda x: np.exp(-x[..., 0] * x[..., 1]) + np.log1p(x[..., 0] ** 2) + np.arctan(x[..., 1]),
        lambda x: x[..., 0] ** x[..., 1] + np.arcsinh(x[..., 0]) - np.expm1(x[..., 1]) ** 2,
        lambda x: np.einsum("...i,ij,...j->...", x, np.array([[2.0, 0.5], [0.5, 1.0]]), x),
    ],
    ids=["trig", "sqrt-tanh", "exp-log", "pow", "einsum"],
)
def test_traced_derivative_is_the_complex_step_derivative(fun):
    """d/dx of a traced function (symbolic) equals liefi's complex-step derivative to rounding."""
    x0 = np.array([0.7, 1.3])
    _, want = liefi._diff.gradient(fun, x0)
    with compiled.trace() as tr:
        x = tr.symbols("y", 2)
        val = compiled._call_datum(fun, x, (), "f")
        jac = compiled.jacobian(val, list(x))
        src = compiled.function_source("f", np.concatenate([val.reshape(1), jac.reshape(-1)]), ("y", "p", "out"))
    ns = {}
    exec(compiled._HEADER.format(imports=compiled._PYTHON_IMPORTS) + src, ns)
    out = np.empty(3)
    ns["f"](x0, np.zeros(0), out)
    assert rel(out[0], fun(x0)) < 1e-14
    assert rel(out[1:], want) < 1e-13


def test_untraceable_datum_is_named():
    """A datum that branches on its argument cannot be compiled; the error names it."""

    def potential(x):
        return np.where(x[..., 0] > 0, x[..., 0] ** 2, 0.0 * x[..., 0])

    space = liefi.CotangentBundle(2)
    sys_ = liefi.NonholonomicSystem(space, np.eye(2), [[1.0, 1.0]], potential, check=False)
    fi = FeedbackIntegrator(sys_, np.array([0.1, 0.2, 0.3, -0.3]))
    with pytest.raises(compiled.NotCompilable, match="potential"):
        compiled.compile_feedback(fi, engine="python")


# --------------------------------------------------------------------------------------
# fields: generated code == numpy reference
# --------------------------------------------------------------------------------------


#: three generated modules per example (~0.3 s): a few examples per system kind
FIELD_PROPERTY = settings(max_examples=max(1, MAX_EXAMPLES // 6), deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])


@pytest.mark.parametrize("spec", SPACES)
@FIELD_PROPERTY
@given(data=st.data())
def test_generated_field_equals_numpy_field(spec, data):
    """For random systems of every kind (x-dependent metric, constraints, potential; general,
    non-orthonormal constraints), the generated feedback, extended and constrained fields equal
    the numpy ones."""
    case = data.draw(cases(spec))
    sys_ = case.system
    G = sys_.space.group
    cfg = data.draw(st.booleans()) and G.config_dim > 0
    # h is a first integral of the extended field only with a constant Gram matrix (liefi refuses otherwise)
    energy = data.draw(st.sampled_from(["extended", "original"])) if case.constant_gram else "extended"
    z0 = case.constrained_state()
    y0 = np.concatenate([G.random_config(case.rng), z0]) if cfg else z0
    names = FeedbackIntegrator(sys_, y0, configuration=cfg).invariant_names
    gains = {k: float(case.rng.uniform(0.5, 3.0)) for k in names}
    fi = FeedbackIntegrator(sys_, y0, configuration=cfg, energy=energy, gains=gains)
    p = compiled.parameters(fi)
    y = y0 + 0.1 * case.rng.normal(size=y0.shape)
    f = compiled.compile_feedback(fi, engine="python")
    assert rel(f.rhs(y, p), fi.vector_field(y)) < TOL
    x = compiled.compile_feedback(fi, feedback=False, engine="python")
    assert rel(x.rhs(y, p), fi.unforced_vector_field(y)) < TOL
    c = compiled.compile_constrained(fi, engine="python")
    if cfg:
        want = _core.full_vector_field(sys_, y, kind="constrained")
    else:
        want = _core.constrained_vector_field(sys_, y)
    assert rel(c.rhs(y, np.zeros(0)), want) < TOL


@pytest.mark.parametrize("name", SCENES)
def test_scene_fields_equal_numpy(name):
    """Every scene, every variant, reduced and with the configuration: generated == numpy."""
    sc = scenes.get(name)
    rng = np.random.default_rng(3)
    for v in sc.variants:
        for cfg in (False, True):
            fi = sc.integrator(v, configuration=cfg)
            f = compiled.compile_feedback(fi, engine="python")
            p = compiled.parameters(fi)
            for _ in range(3):
                y = fi.y0 + 0.05 * rng.normal(size=fi.n)
                assert rel(f.rhs(y, p), fi.vector_field(y)) < TOL, (name, v, cfg)


def test_orthonormalized_system_is_traced():
    """``orthonormalize=True`` rows (a Cholesky factor and np.linalg.solve of x-dependent data) trace too."""
    from strategies import build_case

    from liefi.groups import SE2

    case = build_case("bundle", SE2(), np.random.default_rng(5), 2, 2)
    sys0 = case.system
    sys_ = liefi.NonholonomicSystem(sys0.space, case.metric, case.constraints, case.potential, orthonormalize=True)
    z0 = sys_.project(case.random_state())
    fi = FeedbackIntegrator(sys_, z0, energy="original", gains=2.0, configuration=False)
    f = compiled.compile_feedback(fi, engine="python")
    z = z0 + 0.1 * case.rng.normal(size=z0.shape)
    assert rel(f.rhs(z, compiled.parameters(fi)), fi.vector_field(z)) < TOL
    assert np.linalg.solve is not None and np.linalg.solve(np.eye(2), np.ones(2)).dtype == float


def test_projected_field_and_user_invariants():
    """field='projected' and a user invariant without a gradient (differentiated by tracing)."""
    sc = scenes.get("knife-edge")
    sys_ = sc.system
    inv = Invariant("pp", lambda z: z[..., 5] ** 2 + 0.1 * np.sin(z[..., 2]))
    y0 = sc.initial_state(sc.variant())
    fi = FeedbackIntegrator(sys_, y0, invariants=("constraints", "energy", inv), field="projected", gains=3.0)
    f = compiled.compile_feedback(fi, engine="python")
    y = y0 + 0.1 * np.random.default_rng(0).normal(size=y0.shape)
    assert rel(f.rhs(y, compiled.parameters(fi)), fi.vector_field(y)) < TOL


# --------------------------------------------------------------------------------------
# compiled runs (numba)
# --------------------------------------------------------------------------------------


@needs_numba
@pytest.mark.parametrize("name,cfg", [("suslov", True), ("knife-edge", False)])
@pytest.mark.parametrize("scheme", ["euler", "rk4"])
def test_compiled_run_equals_numpy_run(name, cfg, scheme):
    """``run(backend="numba")`` reproduces the numpy run: same saved times, states to 1e-12."""
    sc = scenes.get(name)
    fi = sc.integrator(None, configuration=cfg)
    a = fi.run(sc.dt, 500 * sc.dt, scheme, save_every=7)
    b = fi.run(sc.dt, 500 * sc.dt, scheme, save_every=7, backend="numba")
    assert b.y.shape == a.y.shape
    np.testing.assert_array_equal(a.t, b.t)
    assert rel(b.y, a.y) < TOL
    assert b.rhs_evaluations == a.rhs_evaluations and b.steps == a.steps
    assert b.names == a.names


@needs_numba
def test_ensemble_equals_single_runs():
    """A batch of trajectories (prange over trajectories) equals the numpy batch run,
    per-trajectory targets included."""
    sc = scenes.get("suslov")
    base = sc.integrator(None, configuration=True)
    rng = np.random.default_rng(1)
    Y0 = np.repeat(base.y0[None], 6, 0)
    Y0[:, 9:] = sc.system.project(base.y0[9:] + 0.3 * rng.normal(size=(6, 3)))
    fi = FeedbackIntegrator(sc.system, Y0.reshape(2, 3, 12), gains=sc.gains)
    a = fi.run(1e-3, 0.3, "heun", save_every=50)
    b = fi.run(1e-3, 0.3, "heun", save_every=50, backend="numba")
    assert b.y.shape == a.y.shape == (2, 3, 12, 7)
    assert rel(b.y, a.y) < TOL


@needs_numba
@pytest.mark.filterwarnings("ignore:.*stability bound")
def test_compiled_divergence_raises_like_numpy():
    """A run past the stability limit raises IntegrationError at the same step as numpy."""
    sc = scenes.get("knife-edge")
    fi = sc.integrator(None, gains=4000.0)
    with pytest.raises(IntegrationError) as a:
        fi.run(1e-3, 1.0, "euler")
    with pytest.raises(IntegrationError) as b:
        fi.run(1e-3, 1.0, "euler", backend="numba")
    assert a.value.step == b.value.step
    assert a.value.components == b.value.components
    assert np.all(np.isfinite(b.value.y))


@needs_numba
def test_projection_keeps_every_invariant():
    """The Newton projection after every step keeps R^T R = I, J, h and user invariants to 1e-13."""
    from liefi.bench import invariant_drifts

    sc = scenes.get("suslov")
    fi = sc.integrator(None, configuration=True)
    cf = compiled.compile_constrained(fi, projection=True)
    sol = cf.run(fi.y0, np.zeros(0), 1e-2, 500, "euler", save_every=50, project=compiled.projection_targets(fi))
    d = invariant_drifts(fi, sol.y)
    assert set(d) >= {"J_1", "h", "orthogonality"}
    assert max(float(np.max(v)) for v in d.values()) < 1e-13
    assert sol.projection_evaluations >= 500


@needs_numba
def test_compiled_dla_equals_liefi_dla():
    """The DLA kernel generated for the knife edge equals liefi.dla's numpy steps."""
    from liefi.dla import DLAIntegrator

    sc = scenes.get("knife-edge")
    sys_ = sc.system
    M = sys_.metric.value
    dla = DLAIntegrator(M, sys_.potential.fun, lambda q: np.asarray(sys_.constraints(q)) @ M)
    z0 = sc.initial_state(sc.variant()) + np.r_[0, 0, 0, 0.3, 0.1, 0]
    h = 1e-2
    q0, q1 = dla.initial_pair(z0[:3], z0[3:], h)
    ref = dla.run(q0, q1, h, 400, save_every=40)
    cd = compiled.compile_dla(sys_)
    t, q, p, _, updates = cd.run(q0, q1, h, 400, save_every=40)
    np.testing.assert_allclose(t, ref.t, rtol=0, atol=1e-12)
    assert rel(q, ref.q) < TOL and rel(p, ref.p) < 1e-10
    assert updates == ref.steps


def test_backend_numba_without_numba_falls_back(monkeypatch):
    """Without numba the numpy path runs, and a CompilationWarning says so."""
    monkeypatch.setattr(compiled, "_numba", None)
    monkeypatch.setattr(compiled, "_WARNED", set())
    sc = scenes.get("suslov")
    fi = sc.integrator()
    want = fi.run(1e-3, 0.05)
    with pytest.warns(compiled.CompilationWarning, match="numba is not available"):
        got = fi.run(1e-3, 0.05, backend="numba")
    np.testing.assert_array_equal(got.y, want.y)


def test_backend_auto_falls_back_for_untraceable_data(monkeypatch):
    """An untraceable datum: backend='auto' warns and runs the numpy path (same numbers)."""
    monkeypatch.setattr(compiled, "_WARNED", set())

    def potential(x):
        return np.where(x[..., 0] > 0, x[..., 0] ** 2, x[..., 0] ** 2)

    sys_ = liefi.NonholonomicSystem(liefi.CotangentBundle(2), np.eye(2), [[1.0, 1.0]], potential, check=False)
    fi = FeedbackIntegrator(sys_, np.array([0.1, 0.2, 0.3, -0.3]))
    want = fi.run(1e-3, 0.01)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        got = fi.run(1e-3, 0.01, backend="auto")
    if compiled.available():
        assert any(issubclass(x.category, compiled.CompilationWarning) and "potential" in str(x.message) for x in w)
    np.testing.assert_array_equal(got.y, want.y)
