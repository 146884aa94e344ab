"""Convergence order and stability of liefi's fixed-step schemes (``liefi.schemes.SCHEMES``).

As in diffrax's ``test_ode_order``: the global error at a fixed time is fitted
against the step on a log-log scale and the slope must be within 0.2 of the
scheme's declared ``order``, (a) on a linear ODE with exact solution
``expm(t A) y0`` and (b) on the Suslov feedback integrator (gains 1, the data of
the paper's Suslov simulation) against the exact solution
``Pi_1 = -tanh t, Pi_2 = Pi_3 = sech t``: a start on ``V^{-1}(0)`` stays on the
exact trajectory of the constrained system, so the feedback term must not spoil
the order.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from liefi import FeedbackIntegrator, IntegrationError, LieGroupPhaseSpace, NonholonomicSystem
from liefi.groups import SO3
from liefi.schemes import SCHEMES, integrate

SCHEME_NAMES = sorted(SCHEMES)


def _slope(dts, errs):
    return np.polyfit(np.log(dts), np.log(errs), 1)[0]


#: Steps per unit time, by order: coarse enough for the high orders to stay above rounding.
LINEAR_STEPS = {6: [4, 6, 8, 12], 8: [2, 3, 4, 6]}
SUSLOV_STEPS = {6: [8, 12, 16, 24], 8: [4, 6, 8, 12]}


# ------------------------------------------------------------------------ linear ODE
A_LIN = np.array([[-0.3, 1.0, 0.2], [-1.0, -0.1, 0.5], [0.1, -0.4, -0.2]])
Y0_LIN = np.array([1.0, -0.5, 0.3])


@pytest.mark.parametrize("name", SCHEME_NAMES)
def test_order_on_linear_ode(name):
    """``y' = A y``: error at ``t = 1`` ~ ``dt^order``."""
    sch = SCHEMES[name]
    exact = expm(A_LIN) @ Y0_LIN
    Ns = LINEAR_STEPS.get(sch.order, [16, 32, 64, 128])
    errs = [np.linalg.norm(integrate(lambda y: y @ A_LIN.T, Y0_LIN, 1.0 / N, N, sch).y[..., -1] - exact) for N in Ns]
    slope = _slope([1.0 / N for N in Ns], errs)
    assert abs(slope - sch.order) < 0.2, (name, slope, errs)


# ------------------------------------------------------------------------ Suslov
def suslov_feedback(gains=1.0):
    II = np.array([[1.0, 0, 0], [0, 1, 1], [0, 1, 2]])
    a = np.array([0.0, 0, 1])
    e = np.linalg.solve(II, a) / np.sqrt(a @ np.linalg.solve(II, a))
    sys_ = NonholonomicSystem(LieGroupPhaseSpace(SO3()), II, e)
    y0 = np.concatenate([np.eye(3).ravel(), [0.0, 1.0, 1.0]])
    return FeedbackIntegrator(sys_, y0, gains=gains)


def suslov_exact(t):
    return np.array([-np.tanh(t), 1 / np.cosh(t), 1 / np.cosh(t)])


def test_suslov_start_is_on_the_zero_set():
    fi = suslov_feedback()
    vals = fi.invariant_values(fi.y0)
    assert vals["J_1"] == pytest.approx(0.0, abs=1e-15)
    assert vals["h"] == pytest.approx(0.5) and vals["h~"] == pytest.approx(0.5)
    assert fi.lyapunov(fi.y0) == 0.0


@pytest.mark.parametrize("name", SCHEME_NAMES)
def test_order_on_suslov_feedback_integrator(name):
    """Feedback integrator of ``(Suslov:FI:tilde)``, gains ``k0 = k1 = k2 = 1``: error of
    ``Pi(1)`` against the exact solution ~ ``dt^order``."""
    sch = SCHEMES[name]
    fi = suslov_feedback()
    Ns = SUSLOV_STEPS.get(sch.order, [20, 40, 80, 160])
    errs = []
    for N in Ns:
        y = integrate(fi.vector_field, fi.y0, 1.0 / N, N, sch).y[..., -1]
        errs.append(np.linalg.norm(y[9:] - suslov_exact(1.0)))
    slope = _slope([1.0 / N for N in Ns], errs)
    assert abs(slope - sch.order) < 0.2, (name, slope, errs)


# ------------------------------------------------------------------------ batch-first
@pytest.mark.parametrize("name", SCHEME_NAMES)
def test_batch_step_equals_member_steps(name):
    """Stepping a batch ``(2, 3, n)`` equals stepping each member alone (nonlinear field)."""
    fi = suslov_feedback(gains={"penalty": 2.0, "J_1": 3.0, "energy": 1.5})
    rng = np.random.default_rng(7)
    Y0 = fi.y0 + 0.05 * rng.normal(size=(2, 3, fi.n))
    sol = integrate(fi.vector_field, Y0, 0.01, 10, name, save_every=5)
    assert sol.y.shape == (2, 3, fi.n, 3)
    np.testing.assert_array_equal(sol.t, [0.0, 0.05, 0.1])
    for idx in np.ndindex(2, 3):
        one = integrate(fi.vector_field, Y0[idx], 0.01, 10, name, save_every=5)
        np.testing.assert_allclose(sol.y[idx], one.y, rtol=1e-14, atol=1e-15)


# ------------------------------------------------------------------------ blow-up
def test_integration_error_names_time_and_components():
    """Euler on ``y' = -L y`` with ``L dt = 3`` (|R| = 2 per step) in component ``a`` only:
    an ``IntegrationError`` (not NaN) naming the time and the component."""
    dt = 0.01
    L = np.array([3.0 / dt, 0.1, 0.2])

    def f(y):
        return -L * y

    with pytest.raises(IntegrationError) as info:
        integrate(f, np.array([1.0, 1.0, 1.0]), dt, 5000, "euler", names=("a", "b", "c"))
    err = info.value
    assert err.components == ["a"]
    assert 1000 <= err.step <= 1100  # 2^1024 overflows double precision
    assert np.all(np.isfinite(err.y))
    assert err.t == pytest.approx(dt * (err.step - 1))
    msg = str(err)
    assert "'a'" in msg and "'b'" not in msg
    assert f"t={dt * err.step:g}" in msg and f"step {err.step}" in msg


def test_integration_error_on_batch_names_components():
    dt = 0.01

    def f(y):
        out = -0.1 * y
        out[1, 2] = -3.0 / dt * y[1, 2]  # one member, one component blows up
        return out

    with pytest.raises(IntegrationError) as info:
        integrate(f, np.ones((2, 3)), dt, 3000, "euler", names=("a", "b", "c"))
    assert info.value.components == ["c"]
    assert info.value.y.shape == (2, 3)


# ------------------------------------------------------------------------ stability polynomial
@pytest.mark.parametrize("name", SCHEME_NAMES)
def test_stability_polynomial_at_real_stability_bound(name):
    """``|R(-beta)| = 1`` at ``beta = real_stability_bound``; ``|R(-x)| <= 1`` on ``[0, beta]``;
    ``|R| > 1`` just beyond; and ``R(z)`` is the degree-``order`` Taylor polynomial of ``e^z``
    (``stages == order`` for these explicit schemes)."""
    sch = SCHEMES[name]
    beta = sch.real_stability_bound
    R = lambda x: np.abs(sch.stability_polynomial(np.atleast_1d(np.asarray(x, dtype=complex))))  # noqa: E731
    assert abs(R(-beta)[0] - 1.0) < 1e-12
    assert np.all(R(-np.linspace(0, beta, 41)) <= 1 + 1e-12)
    assert R(-beta * 1.001)[0] > 1.0
    z = np.array([0.3, -0.7 + 0.2j, 1.1j])
    taylor = sum(z**k / np.prod(np.arange(1, k + 1)) for k in range(sch.order + 1))
    if sch.stages == sch.order:
        np.testing.assert_allclose(sch.stability_polynomial(z), taylor, rtol=1e-14)
    else:  # more stages than the order (rk6, rk8): R agrees with e^z up to z^order
        coef = sch.stability_coefficients[::-1]
        np.testing.assert_allclose(coef[: sch.order + 1], [1 / math.factorial(k) for k in range(sch.order + 1)],
                                   rtol=1e-12)
        np.testing.assert_allclose(sch.stability_polynomial(z), sch.stability_function(z), rtol=1e-12)


# ------------------------------------------------------------------------ the registry
from liefi.schemes import registry  # noqa: E402


@pytest.mark.parametrize("name", registry.names("explicit") + ["scipy:RK23", "scipy:RK45", "scipy:DOP853"])
def test_tableau_consistency(name):
    """Every explicit tableau: ``c_i = sum_j a_ij``, ``sum_i b_i = 1``, ``A`` strictly lower triangular."""
    sch = registry.get(name)
    tab = sch.tableau if sch.kind == "scipy" else sch
    assert len(tab.A) == len(tab.b) == len(tab.c)
    for i, row in enumerate(tab.A):
        assert len(row) <= i  # explicit
        assert sum(row) == pytest.approx(tab.c[i], abs=1e-14), f"{name}: c_{i} != sum_j a_{i}j"
    assert sum(tab.b) == pytest.approx(1.0, abs=1e-14)


@pytest.mark.parametrize("name", registry.names("explicit"))
def test_declared_order_is_that_of_the_stability_polynomial(name):
    """``R(z)`` agrees with ``exp(z)`` to the declared order: the coefficient of ``z^k`` is ``1/k!`` for ``k <= p``."""
    from math import factorial

    sch = registry.get(name)
    c = sch.stability_coefficients[::-1]
    for k in range(sch.order + 1):
        assert c[k] == pytest.approx(1 / factorial(k), rel=1e-14)


def test_registry_get_and_names():
    assert registry.names("explicit") == ["euler", "heun", "midpoint", "rk3", "rk4", "rk6", "rk8"]
    assert registry.names("split") == ["imex-euler", "imex-heun", "imex-rk4", "imex-rk6", "imex-rk8"]
    assert registry.names("dla") == ["dla"]
    assert registry.names("scipy") == [f"scipy:{m}" for m in ("RK23", "RK45", "DOP853", "Radau", "BDF", "LSODA")]
    assert registry.get("RK4") is registry.get("rk4")
    assert registry.get("scipy:lsoda").method == "LSODA"
    for s in registry.ENTRIES:
        assert isinstance(s.order, int) and s.order >= 1
        assert s.stiff_safe == (s.real_stability_bound == np.inf)
        assert callable(s.step)
    with pytest.raises(ValueError, match="choose one of.*rk4.*scipy:LSODA"):
        registry.get("rk5")
    with pytest.raises(ValueError, match="scipy:Radau"):
        registry.get("scipy:Foo")
    with pytest.raises(ValueError, match="kind"):
        registry.names("implicit")


def test_registry_uses_scipy_public_api_only():
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1] / "liefi"
    offenders = [str(p) for p in root.rglob("*.py") if "scipy.integrate._" in p.read_text()]
    assert not offenders


def test_errors_pickle_with_their_fields():
    import pickle

    from liefi.stability import StabilityError

    for cls in (IntegrationError, StabilityError):
        e = cls("boom at t=1", 1.5, 7, np.arange(3.0), ["J_1"])
        e2 = pickle.loads(pickle.dumps(e))
        assert type(e2) is cls and str(e2) == "boom at t=1"
        assert (e2.t, e2.step, e2.components) == (1.5, 7, ["J_1"])
        np.testing.assert_array_equal(e2.y, e.y)


# ------------------------------------------------------------------------ the high-order tableaux
def test_rk8_is_the_tableau_of_scipys_dop853():
    """``RK8`` is the 12-stage order-8 tableau that ``solve_ivp(method="DOP853")`` steps with."""
    from scipy.integrate._ivp import dop853_coefficients as d

    from liefi.schemes import RK8

    A = np.zeros((12, 12))
    for i, row in enumerate(RK8.A):
        A[i, : len(row)] = row
    np.testing.assert_allclose(A, d.A[:12, :12], rtol=1e-15, atol=1e-16)
    np.testing.assert_allclose(RK8.b, d.B, rtol=1e-15, atol=1e-16)
    np.testing.assert_allclose(RK8.c, d.C[:12], rtol=1e-15, atol=1e-16)


@pytest.mark.parametrize("name", ["rk6", "rk8"])
def test_high_order_split_schemes_run_compiled_at_their_order(name):
    """``imex-rk6``/``imex-rk8`` run compiled and match their numpy steps, and converge at their order
    on the rigid body (the feedback step keeps the invariants; the error is the tableau's on ``X``)."""
    from liefi import scenes

    sc = scenes.get("rigid-body")
    fi = sc.integrator(sc.variant(None), gains={"penalty": 1.0, "energy": 1.0, "casimir": 1.0})
    ref = fi.run(2.0, dt=2.0 / 256, scheme="imex-rk8", backend="auto", check_stability=False).y[..., -1]
    errs, Ns = [], [8, 12, 16]
    for N in Ns:
        a = fi.run(2.0, dt=2.0 / N, scheme=f"imex-{name}", backend="auto", check_stability=False)
        b = fi.run(2.0, dt=2.0 / N, scheme=f"imex-{name}", backend="numpy", check_stability=False)
        assert a.method["backend"] != "numpy"
        np.testing.assert_allclose(a.y, b.y, rtol=1e-11, atol=1e-12)
        errs.append(np.max(np.abs(a.y[..., -1] - ref)))
    assert abs(_slope([2.0 / N for N in Ns], errs) - int(name[2:])) < 0.5, errs
