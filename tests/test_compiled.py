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
from liefi import FeedbackIntegrator, Invariant, scenes
from liefi import engine as compiled
from liefi.engine import cache as _cache
from liefi.engine import codegen, kernels, trace
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
    with trace.trace() as tr:
        x = tr.symbols("y", 2)
        val = trace._call_datum(fun, x, (), "f")
        jac = trace.jacobian(val, list(x))
        src = codegen.function_source("f", np.concatenate([val.reshape(1), jac.reshape(-1)]), ("y", "p", "out"))
    ns = {}
    exec(codegen.module_text(src, "python", False), ns)
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
    p = fi.parameters()
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


@pytest.mark.parametrize("spec", SPACES)
@FIELD_PROPERTY
@given(data=st.data())
def test_vector_potential_is_compiled_without_engine_code(spec, data):
    """A datum the engine has no code for (the vector potential ``A(x)``, added to the core only)
    reaches the compiled field through the traced core: generated == numpy."""
    case = data.draw(cases(spec, vector_potential=True))
    sys_ = case.system
    z0 = case.constrained_state()
    fi = FeedbackIntegrator(sys_, z0, configuration=False, gains=1.5)
    z = z0 + 0.1 * case.rng.normal(size=z0.shape)
    f = compiled.compile_feedback(fi, engine="python")
    assert rel(f.rhs(z, fi.parameters()), fi.vector_field(z)) < TOL


@pytest.mark.parametrize("name", SCENES)
def test_scene_fields_equal_numpy(name):
    """Every scene, every variant, reduced and with the configuration: generated == numpy."""
    sc = scenes.get(name)
    rng = np.random.default_rng(3)
    for v in sc.variants:
        for cfg in (False, True):
            fi = sc.integrator(v, configuration=cfg)
            f = compiled.compile_feedback(fi, engine="python")
            p = fi.parameters()
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
    assert rel(f.rhs(z, fi.parameters()), fi.vector_field(z)) < TOL
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
    assert rel(f.rhs(y, fi.parameters()), fi.vector_field(y)) < TOL


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
    a = fi.run(500 * sc.dt, dt=sc.dt, scheme=scheme, save_every=7, backend="numpy")
    b = fi.run(500 * sc.dt, dt=sc.dt, scheme=scheme, save_every=7, backend="numba")
    assert b.y.shape == a.y.shape
    np.testing.assert_array_equal(a.t, b.t)
    assert rel(b.y, a.y) < TOL
    assert b.rhs_evaluations == a.rhs_evaluations and b.steps == a.steps
    assert b.names == a.names


@needs_numba
@pytest.mark.parametrize("name,cfg", [("suslov", True), ("knife-edge", False), ("roller-racer", True)])
@pytest.mark.parametrize("scheme", ["imex-euler", "imex-rk4"])
def test_compiled_split_run_equals_numpy_run(name, cfg, scheme):
    """The split schemes compile (the trace of ``feedback_step``): same states to 1e-12, one kernel for every gain."""
    sc = scenes.get(name)
    for gains in (3.0, 1e6):
        fi = sc.integrator(None, configuration=cfg).with_gains(gains)
        a = fi.run(300 * sc.dt, dt=sc.dt, scheme=scheme, save_every=7, check_stability=False, backend="numpy")
        b = fi.run(300 * sc.dt, dt=sc.dt, scheme=scheme, save_every=7, backend="numba", check_stability=False)
        assert b.backend == "numba" and a.backend == "numpy"
        np.testing.assert_array_equal(a.t, b.t)
        assert rel(b.y, a.y) < TOL
        assert b.rhs_evaluations == a.rhs_evaluations


@needs_numba
def test_compiled_split_ensemble_equals_numpy():
    sc = scenes.get("suslov")
    base = sc.integrator(None, configuration=True)
    rng = np.random.default_rng(2)
    Y0 = np.repeat(base.y0[None], 4, 0)
    Y0[:, 9:] = sc.system.project(base.y0[9:] + 0.3 * rng.normal(size=(4, 3)))
    fi = FeedbackIntegrator(sc.system, Y0, gains=50.0)
    a = fi.run(1.0, dt=1e-2, scheme="imex-rk4", save_every=10, check_stability=False, backend="numpy")
    b = fi.run(1.0, dt=1e-2, scheme="imex-rk4", save_every=10, backend="numba", check_stability=False)
    assert rel(b.y, a.y) < TOL


@needs_numba
def test_compiled_ensemble_equals_numpy_batch():
    """A batch of trajectories (prange over trajectories) equals the numpy batch run, per-member
    targets included (each member against its own single run: tests/test_ensembles.py)."""
    sc = scenes.get("suslov")
    base = sc.integrator(None, configuration=True)
    rng = np.random.default_rng(1)
    Y0 = np.repeat(base.y0[None], 6, 0)
    Y0[:, 9:] = sc.system.project(base.y0[9:] + 0.3 * rng.normal(size=(6, 3)))
    fi = FeedbackIntegrator(sc.system, Y0.reshape(2, 3, 12), gains=sc.gains)
    a = fi.run(0.3, dt=1e-3, scheme="heun", save_every=50, backend="numpy")
    b = fi.run(0.3, dt=1e-3, scheme="heun", save_every=50, backend="numba")
    assert b.y.shape == a.y.shape == (2, 3, 12, 7)
    assert rel(b.y, a.y) < TOL


@needs_numba
@pytest.mark.filterwarnings("ignore:.*stability bound")
def test_compiled_divergence_raises_like_numpy():
    """A run past the stability limit raises IntegrationError at the same step as numpy."""
    sc = scenes.get("knife-edge")
    fi = sc.integrator(None, gains=4000.0)
    with pytest.raises(IntegrationError) as a:
        fi.run(1.0, dt=1e-3, scheme="euler", backend="numpy")
    with pytest.raises(IntegrationError) as b:
        fi.run(1.0, dt=1e-3, scheme="euler", backend="numba")
    assert a.value.step == b.value.step
    assert a.value.components == b.value.components
    assert np.all(np.isfinite(b.value.y))


@needs_numba
@pytest.mark.skipif(not hasattr(liefi.groups.LieGroup, "orthogonal_matrices"),
                    reason="the groups do not declare orthogonal_matrices yet (merged from the groups branch)")
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
    monkeypatch.setattr(_cache, "_numba", None)
    monkeypatch.setattr(kernels, "_WARNED", set())
    sc = scenes.get("suslov")
    fi = sc.integrator()
    want = fi.run(0.05, dt=1e-3, backend="numpy")
    with pytest.warns(compiled.CompilationWarning, match="numba is not available"):
        got = fi.run(0.05, dt=1e-3, backend="numba")
    np.testing.assert_array_equal(got.y, want.y)


def test_backend_auto_falls_back_for_untraceable_data(monkeypatch):
    """An untraceable datum: backend='auto' warns and runs the numpy path (same numbers)."""
    monkeypatch.setattr(kernels, "_WARNED", set())

    def potential(x):
        return np.where(x[..., 0] > 0, x[..., 0] ** 2, x[..., 0] ** 2)

    sys_ = liefi.NonholonomicSystem(liefi.CotangentBundle(2), np.eye(2), [[1.0, 1.0]], potential, check=False)
    fi = FeedbackIntegrator(sys_, np.array([0.1, 0.2, 0.3, -0.3]))
    want = fi.run(0.01, dt=1e-3, backend="numpy")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        got = fi.run(0.01, dt=1e-3, backend="auto")
    if compiled.available():
        assert any(issubclass(x.category, compiled.CompilationWarning) and "potential" in str(x.message) for x in w)
    np.testing.assert_array_equal(got.y, want.y)


# --------------------------------------------------------------------------------------
# one source: the engine traces the core, it has no copy of it
# --------------------------------------------------------------------------------------


def _fresh_knife_edge_fi():
    """A knife-edge integrator on a new system object (so no kernel of it is cached)."""
    sc = scenes.get("knife-edge")
    sys0 = sc.system
    sys_ = liefi.NonholonomicSystem(sys0.space, sys0.metric.value, sys0.constraints.fun, sys0.potential.fun)
    return FeedbackIntegrator(sys_, sc.initial_state(sc.variant()), gains=2.0)


def test_single_source_core_change_reaches_both_backends(monkeypatch):
    """Monkeypatch one core formula -- the force term of the reduced field -- and both backends
    change alike: the compiled kernel is the trace of the core, not a copy of it."""
    fi = _fresh_knife_edge_fi()
    y = fi.y0 + 0.1 * np.random.default_rng(7).normal(size=fi.n)
    before = fi.vector_field(y)
    field = _core._field

    def field_with_a_force(system, z, dH, lam, Eflat):  # an extra force -0.3 sin(x) on the momenta
        f = field(system, z, dH, lam, Eflat)
        n = system.space.n
        return np.concatenate([f[..., :n], f[..., n:] - 0.3 * np.sin(z[..., n:])], -1)

    monkeypatch.setattr(_core, "_field", field_with_a_force)
    numpy_after = fi.vector_field(y)
    compiled_after = compiled.compile_feedback(fi, engine="python").rhs(y, fi.parameters())
    assert rel(numpy_after, before) > 1e-3  # the change is visible ...
    assert rel(compiled_after, numpy_after) < TOL  # ... and the compiled field has it too


def test_single_source_dla_step_is_traced(monkeypatch):
    """The compiled DLA kernel is the trace of DLAIntegrator.update: a change to it reaches the kernel."""
    from liefi.dla import DLAIntegrator

    sc = scenes.get("oscillator")
    sys0 = sc.system
    sys_ = liefi.NonholonomicSystem(sys0.space, sys0.metric.value, sys0.constraints.fun, sys0.potential.fun)
    update = DLAIntegrator.update

    def damped(self, q_prev, q_curr, h):
        q, mu, g = update(self, q_prev, q_curr, h)
        return q - 0.01 * (q_curr - q_prev), mu, g

    monkeypatch.setattr(DLAIntegrator, "update", damped)
    dla = DLAIntegrator.from_system(sys_)
    q0, q1 = dla.initial_pair(np.array([0.5, 0.2, -0.1]), np.array([0.1, 0.3, 0.0]), 1e-2)
    want = dla.run(q0, q1, 1e-2, 50, save_every=10)
    mod = compiled.compile_dla(sys_, engine="python").module
    qp, qc = q0.copy(), q1.copy()
    for _ in range(49):
        out = np.empty(3)
        mod.dla_update(qp, qc, np.array([1e-2]), out)
        qp, qc = qc, out
    assert rel(qc, want.q[:, -1]) < TOL


# --------------------------------------------------------------------------------------
# user groups: an override that cannot be traced falls back, never raises the internal error
# --------------------------------------------------------------------------------------


def _rigid_body_with(group):
    space = liefi.LieGroupPhaseSpace(group)
    sys_ = liefi.NonholonomicSystem(space, np.diag([1.0, 2.0, 3.0]), [[0.0, 0.0, 1.0]])
    y0 = np.concatenate([group.identity_config(), sys_.project(np.array([0.3, -0.2, 0.1]))])
    return FeedbackIntegrator(sys_, y0, gains=1.0)


class _OrientedSO3(liefi.groups.SO3):
    """SO(3) with an extra orientation penalty ``1/2 (det R - 1)^2``: ``np.linalg.det`` is complex-step
    safe (the group passes its checks) but cannot be traced."""

    def penalty(self, g):
        d = np.linalg.det(self.config_to_matrix(g))
        return super().penalty(g) + 0.5 * (d - 1.0) ** 2

    def penalty_grad(self, g):
        R = self.config_to_matrix(g)
        d = np.linalg.det(R)
        cofactor = d[..., None, None] * np.swapaxes(np.linalg.inv(R), -1, -2)
        return super().penalty_grad(g) + self.matrix_to_config((d - 1.0)[..., None, None] * cofactor)


def test_untraceable_group_override_is_named():
    fi = _rigid_body_with(_OrientedSO3())
    with pytest.raises(compiled.NotCompilable, match=r"det.*in penalty"):
        compiled.compile_feedback(fi, engine="python")


def test_untraceable_group_override_falls_back_under_auto(monkeypatch):
    """backend='auto' with an untraceable group method: a CompilationWarning and the numpy run."""
    monkeypatch.setattr(kernels, "_WARNED", set())
    fi = _rigid_body_with(_OrientedSO3())
    want = fi.run(0.2, dt=1e-2, backend="numpy")
    if not compiled.available():
        pytest.skip("numba is not installed (auto runs numpy without tracing)")
    with pytest.warns(compiled.CompilationWarning, match="penalty"):
        got = fi.run(0.2, dt=1e-2, backend="auto")
    np.testing.assert_array_equal(got.y, want.y)


# --------------------------------------------------------------------------------------
# the kernel cache: private, self-healing, never fatal
# --------------------------------------------------------------------------------------


@pytest.fixture
def kernel_env(monkeypatch, tmp_path):
    """A clean kernel table and a private cache directory ``tmp_path/private`` (returned)."""
    private = tmp_path / "private"
    monkeypatch.setenv("LIEFI_CACHE_DIR", str(private))
    monkeypatch.setattr(kernels, "_KERNELS", {})
    monkeypatch.setattr(kernels, "_WARNED", set())
    _cache.clear_memory()
    yield private
    _cache.clear_memory()


def _numba_cache_files(directory, name):
    pc = directory / "__pycache__"
    return sorted(p for p in pc.glob(name + ".*")) if pc.exists() else []


_EVIL = '''
import pathlib
pathlib.Path({marker!r}).write_text("planted code ran")
'''


class _Evil:
    """A pickle that runs code when loaded (what a planted numba cache file can do)."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        import pathlib

        return (pathlib.Path.write_text, (pathlib.Path(self.marker), "planted pickle ran"))


@needs_numba
@pytest.mark.parametrize("unsafe", ["world-writable", "foreign-owned"])
def test_planted_kernel_is_never_imported(kernel_env, monkeypatch, tmp_path, unsafe):
    """A cache directory writable by others or owned by another user is never read: kernel files
    and numba cache files planted there do not run; kernels go to a private temporary directory."""
    import os
    import pickle

    fi = _fresh_knife_edge_fi()
    y = fi.y0 + 0.01
    cf = compiled.compile_feedback(fi)
    want = cf.rhs(y, fi.parameters())  # compiles and writes numba's cache files
    name = cf.kernel.name
    planted_files = _numba_cache_files(kernel_env, name)
    assert planted_files  # numba cached the kernel next to its source

    bad = tmp_path / "shared"
    (bad / "__pycache__").mkdir(parents=True)
    marker = tmp_path / "marker"
    (bad / (name + ".py")).write_text(cf.kernel.text + _EVIL.format(marker=str(marker)))
    for f in planted_files:
        (bad / "__pycache__" / f.name).write_bytes(pickle.dumps(_Evil(str(marker))))
    if unsafe == "world-writable":
        os.chmod(bad, 0o777)
    else:
        os.chmod(bad, 0o700)
        monkeypatch.setattr(_cache, "_uid", lambda: os.getuid() + 1)
    monkeypatch.setenv("LIEFI_CACHE_DIR", str(bad))
    monkeypatch.setattr(kernels, "_KERNELS", {})
    _cache.clear_memory()
    with pytest.warns(compiled.KernelCacheWarning, match="owned by another user" if unsafe == "foreign-owned" else "writable by group or others"):
        cf2 = compiled.compile_feedback(fi)
    got = cf2.rhs(y, fi.parameters())
    assert not marker.exists()
    if unsafe == "world-writable":  # a private temporary directory instead
        assert cf2.kernel.path is not None and not cf2.kernel.path.startswith(str(bad))
        assert _cache.check_private(os.path.dirname(cf2.kernel.path)) is None
    else:  # (the simulated uid owns no directory at all, so the kernel is compiled in memory)
        assert cf2.kernel.path is None
    np.testing.assert_array_equal(got, want)


@needs_numba
def test_corrupt_cache_heals(kernel_env):
    """A truncated kernel file and corrupt numba cache files are detected and rebuilt."""
    fi = _fresh_knife_edge_fi()
    y = fi.y0 + 0.01
    cf = compiled.compile_feedback(fi)
    want = cf.rhs(y, fi.parameters())
    path = cf.kernel.path
    files = _numba_cache_files(kernel_env, cf.kernel.name)
    assert path and files
    text = open(path).read()
    with open(path, "w") as fh:  # truncated kernel
        fh.write(text[: len(text) // 2])
    for f in files:  # truncated / garbage numba cache
        data = f.read_bytes()
        f.write_bytes(data[: len(data) // 3] if f.suffix == ".nbc" else b"garbage\n")
    kernels._KERNELS.clear()
    _cache.clear_memory()
    cf2 = compiled.compile_feedback(fi)
    assert rel(cf2.rhs(y, fi.parameters()), want) == 0.0  # (the rewritten kernel's stale cache was removed)
    assert open(path).read() == text

    # numba's cache alone corrupt (the kernel file intact): the first call fails, is healed, and reruns
    files = _numba_cache_files(kernel_env, cf.kernel.name)
    for f in files:
        f.write_bytes(b"garbage\n")
    kernels._KERNELS.clear()
    _cache.clear_memory()
    cf3 = compiled.compile_feedback(fi)
    with pytest.warns(compiled.KernelCacheWarning, match="not trusted"):  # garbage carries no signature
        assert rel(cf3.rhs(y, fi.parameters()), want) == 0.0
    assert all(f.read_bytes() != b"garbage\n" for f in _numba_cache_files(kernel_env, cf.kernel.name))


@needs_numba
def test_read_only_cache_falls_back(kernel_env, monkeypatch):
    """A read-only filesystem (no cache directory, no temporary directory): the kernel is compiled in
    memory, and the run under backend='auto' gives the numpy numbers (to 1e-12) without raising."""
    import errno
    import tempfile

    def read_only(*a, **k):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(_cache, "_make_dir", read_only)
    monkeypatch.setattr(tempfile, "mkdtemp", read_only)
    fi = _fresh_knife_edge_fi()
    want = fi.run(0.2, dt=1e-2, check_stability=False, backend="numpy")
    with pytest.warns(compiled.KernelCacheWarning, match="in memory"):
        got = fi.run(0.2, dt=1e-2, backend="auto", check_stability=False)
    assert rel(got.y, want.y) < TOL
    assert not kernel_env.exists()


def test_any_compile_failure_falls_back_under_auto(kernel_env, monkeypatch):
    """A failure to write, load or compile the kernel under backend='auto': numpy runs, with a CompilationWarning."""
    import errno

    def broken(*a, **k):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(_cache, "load", broken)
    fi = _fresh_knife_edge_fi()
    want = fi.run(0.2, dt=1e-2, check_stability=False, backend="numpy")
    if not compiled.available():
        pytest.skip("numba is not installed (auto runs numpy without compiling)")
    with pytest.warns(compiled.CompilationWarning, match="Read-only file system"):
        got = fi.run(0.2, dt=1e-2, backend="auto", check_stability=False)
    np.testing.assert_array_equal(got.y, want.y)


def test_cache_directory_is_created_private(kernel_env):
    """The cache directory is created with mode 0700 and passes the ownership/mode check."""
    import os
    import stat

    assert _cache.kernel_dir() == str(kernel_env)
    assert stat.S_IMODE(os.stat(kernel_env).st_mode) == 0o700
    assert _cache.check_private(str(kernel_env)) is None


def test_overhead_is_reported_once(kernel_env):
    """The one-off cost (trace, load, first-call compile) is reported by the first run only,
    apart from the loop's cpu_seconds."""
    fi = _fresh_knife_edge_fi()
    cf = compiled.compile_feedback(fi, engine="python")
    a = cf.run(fi.y0, fi.parameters(), 1e-2, 20)
    b = cf.run(fi.y0, fi.parameters(), 1e-2, 20)
    assert a.overhead_seconds > 0 and a.overhead_seconds >= cf.build_seconds
    assert b.overhead_seconds == 0.0
    assert a.cpu_seconds >= 0 and b.cpu_seconds >= 0
