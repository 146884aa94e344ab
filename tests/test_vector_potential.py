"""The vector potential ``A(x)``: ``h = 1/2 <P - A, m^{-1}(P - A)> + U``, ``J_i = <P - A, e_i>``.

On every kind of phase space and every group (``strategies.SPACES``, with a
random ``x``-dependent ``A`` on the bundles and the cotangent bundle, a random
constant one on the Lie groups):

* ``h~`` and every ``J_i`` are first integrals of the extended field
  everywhere (``(theorem:first:integrals)``), with gradients from liefi and,
  independently, from complex steps of ``strategies.oracle``;
* on ``C`` the extended field equals the constrained one
  (``(theorem:extension:nonhol)``).

Two second routes that do not use the Hamiltonian formulas at all:

* on ``T*R^n``: the Lagrange--d'Alembert equations of ``L = 1/2 v.m v + A.v - U``
  with the constraint ``(E m) v = 0`` (a charged particle with magnetic force
  ``(dA^T - dA) v``), solved as a saddle-point system;
* on ``SO(3)``: the gyrostat's Euler equations ``I w' = (I w + l) x w + lambda a``
  with a Suslov constraint ``<a, w> = 0``.

The reduction diagram with ``A`` is in ``test_reduction_diagram.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from liefi import CotangentBundle, FeedbackIntegrator, LieGroupPhaseSpace, NonholonomicSystem
from liefi import _diff
from liefi.groups import SO3
from liefi.reduction import evaluate
from strategies import BATCH_SHAPES, SPACES, SYSTEM_PROPERTY, cases, cs_grad, field_scale, oracle_ht, oracle_J, rel_err

TOL = 1e-10
#: worst relative residual per (identity, space kind); printed by ``python tests/test_vector_potential.py``
WORST: dict = {}


def _record(key, value):
    WORST[key] = max(WORST.get(key, 0.0), value)
    return value


def _orth(grad, X, scale):
    num = np.abs(np.einsum("...j,...j->...", grad, X))
    scale = np.asarray(scale)[..., None] if num.ndim > np.ndim(scale) else scale
    return float(np.max(num / (np.linalg.norm(grad, axis=-1) * scale + 1e-300), initial=0.0))


@pytest.mark.parametrize("spec", SPACES)
@SYSTEM_PROPERTY
@given(data=st.data())
def test_first_integrals_and_extension_with_vector_potential(spec, data):
    case = data.draw(cases(spec, vector_potential=True))
    assert case.system.vector_potential is not None
    z = case.random_state(data.draw(BATCH_SHAPES))
    sys_ = case.system
    X = sys_.extended_vector_field(z)
    sc = field_scale(case, z)
    t = evaluate(sys_, z)
    kind = spec[0]
    # the oracle (P - A written out from the raw data) agrees with liefi's h~ and J and their gradients
    assert _record(("dh~ liefi vs oracle", kind), rel_err(t.dht, cs_grad(oracle_ht(case), z), np.max(np.abs(t.dht), initial=1.0))) < TOL
    assert _record(("dh~.X~", kind), _orth(cs_grad(oracle_ht(case), z), X, sc)) < TOL
    if case.K:
        XK = np.broadcast_to(X[..., None, :], X.shape[:-1] + (case.K, X.shape[-1]))
        assert _record(("dJ.X~", kind), _orth(cs_grad(oracle_J(case), z), XK, sc)) < TOL
    zc = sys_.project(z)
    assert np.max(np.abs(sys_.constraint_momenta(zc)), initial=0.0) < 1e-12 * max(1.0, np.max(np.abs(zc)))
    Xe, Xc = sys_.extended_vector_field(zc), sys_.constrained_vector_field(zc)
    assert _record(("X~ = X_c on C", kind), rel_err(Xe, Xc, np.max(np.abs(Xc), initial=1.0))) < TOL


# ------------------------------------------------------------------ second route: Lagrange-d'Alembert
def _charged_particle(seed):
    rng = np.random.default_rng(seed)
    n = 3
    M0 = rng.normal(size=(n, n))
    M0 = M0 @ M0.T + np.eye(n)
    S = rng.normal(size=(n, n))
    S = 0.1 * (S + S.T)
    a0, a1 = rng.normal(size=(2, n))
    G = rng.normal(size=(n, n))
    e0, e1 = rng.normal(size=(2, 1, n))

    def metric(x):
        return M0 + np.sin(x[..., 0])[..., None, None] * S

    def A(x):
        return a0 + np.einsum("ij,...j->...i", G, x) + np.sin(x[..., 1])[..., None] * a1

    def E(x):
        return e0 + np.cos(x[..., 2])[..., None, None] * e1

    def U(x):
        return np.sin(x[..., 0]) * x[..., 1]

    return n, metric, A, E, U, rng


@pytest.mark.parametrize("seed", range(5))
def test_constrained_field_equals_lagrange_dalembert_for_a_charged_particle(seed):
    """``L = 1/2 v.m(x) v + A(x).v - U(x)``, constraint ``(E m) v = 0``: ``d/dt (m v + A) = dL/dx +
    (E m)^T lambda`` solved for ``v'`` directly; liefi's ``P' = d/dt (m v + A)`` must match."""
    n, metric, A, E, U, rng = _charged_particle(seed)
    sys_ = NonholonomicSystem(CotangentBundle(n), metric, E, U, vector_potential=A)
    z = sys_.project(rng.normal(size=2 * n))
    x, P = z[:n], z[n:]
    m = metric(x)
    v = np.linalg.solve(m, P - A(x))
    _, dm = _diff.jacobian(metric, x)  # dm[k] = dm/dx_k
    _, dA = _diff.jacobian(A, x)  # dA[k, j] = dA_j/dx_k
    _, dU = _diff.jacobian(U, x)
    _, da = _diff.jacobian(lambda y: E(y) @ metric(y), x)  # rows a = E m
    dLdx = 0.5 * np.einsum("i,kij,j->k", v, dm, v) + dA @ v - dU
    mdot_v = np.einsum("kij,k,j->i", dm, v, v)
    rhs = dLdx - mdot_v - dA.T @ v  # m v' = rhs + a^T lambda
    a = E(x) @ m
    adot_v = np.einsum("kij,k,j->i", da, v, v)
    K = a.shape[0]
    sol = np.linalg.solve(np.block([[m, -a.T], [a, np.zeros((K, K))]]), np.concatenate([rhs, -adot_v]))
    vdot = sol[:n]
    Pdot = m @ vdot + mdot_v + dA.T @ v
    want = np.concatenate([v, Pdot])
    for field in (sys_.constrained_vector_field, sys_.extended_vector_field):
        got = field(z)
        assert _record(("Lagrange-d'Alembert", "cotangent"), rel_err(got, want, np.max(np.abs(want)))) < 1e-12


# ------------------------------------------------------------------ second route: the gyrostat
def gyrostat(seed=0):
    rng = np.random.default_rng(seed)
    L = rng.normal(size=(3, 3))
    I = L @ L.T + np.eye(3)
    l = rng.normal(size=3)
    e = rng.normal(size=3)
    return I, l, e, rng


@pytest.mark.parametrize("seed", range(5))
def test_gyrostat_suslov_equals_euler_equations(seed):
    """A body with a rotor of momentum ``l`` and the Suslov constraint ``<I e, w> = 0``:
    ``I w' = (I w + l) x w + lambda I e`` (Euler's equations of a gyrostat), ``M = I w + l``."""
    I, l, e, rng = gyrostat(seed)
    sys_ = NonholonomicSystem(LieGroupPhaseSpace(SO3()), I, e, vector_potential=l)
    M = sys_.project(rng.normal(size=3))
    w = np.linalg.solve(I, M - l)
    a = I @ e
    assert abs(a @ w) < 1e-13 * np.linalg.norm(a) * np.linalg.norm(w)
    f = np.cross(I @ w + l, w)
    lam = -(a @ np.linalg.solve(I, f)) / (a @ np.linalg.solve(I, a))
    want = f + lam * a  # M' = I w'
    for field in (sys_.constrained_vector_field, sys_.extended_vector_field):
        assert _record(("gyrostat Euler", "lie-SO3"), rel_err(field(M), want, np.max(np.abs(want)))) < 1e-13
    # the rotor changes the motion: without l the field differs
    plain = NonholonomicSystem(LieGroupPhaseSpace(SO3()), I, e)
    assert rel_err(plain.constrained_vector_field(plain.project(M)), want, np.max(np.abs(want))) > 1e-3


def test_constant_gauge_shift_is_a_translation():
    """A constant ``A`` on ``T*R^n`` only relabels the momenta: ``X_A(x, P) = X_0(x, P - A)``."""
    n, metric, _, E, U, rng = _charged_particle(7)
    A = rng.normal(size=n)
    with_A = NonholonomicSystem(CotangentBundle(n), metric, E, U, vector_potential=A)
    without = NonholonomicSystem(CotangentBundle(n), metric, E, U)
    z = rng.normal(size=(4, 2 * n))
    shifted = np.concatenate([z[:, :n], z[:, n:] - A], -1)
    np.testing.assert_allclose(with_A.extended_vector_field(z), without.extended_vector_field(shifted), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(with_A.extended_hamiltonian(z), without.extended_hamiltonian(shifted), rtol=1e-13)


def test_feedback_integrator_keeps_the_affine_constraint_set():
    """The FI with a vector potential penalizes ``J = E (P - A)``: a run started on ``C`` stays on it."""
    I, l, e, rng = gyrostat(3)
    sys_ = NonholonomicSystem(LieGroupPhaseSpace(SO3()), I, e, vector_potential=l)
    z0 = sys_.project(rng.normal(size=3))
    fi = FeedbackIntegrator(sys_, z0, gains=5.0, configuration=False)
    sol = fi.run(5.0, dt=1e-2, scheme="rk4")
    v = fi.invariant_values(sol.y.T)
    assert np.abs(v["J_1"]).max() < 1e-8
    assert np.ptp(v["h~"]) < 1e-8 * abs(v["h~"][0])
    assert np.abs(sys_.complete_momenta(np.zeros(0), {"Pi_1": z0[0], "Pi_2": z0[1]}) - z0).max() < 1e-12


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.ones(2), "vector_potential: expected shape"),
        (np.array([1.0, np.nan, 0.0]), "vector_potential: contains non-finite"),
        (lambda x: np.ones(3), "vector_potential: a system on a Lie group"),
    ],
)
def test_bad_vector_potential_is_named(bad, match):
    with pytest.raises(ValueError, match=match):
        NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.eye(3), vector_potential=bad)


def test_dla_refuses_a_vector_potential():
    from liefi.dla import DLAIntegrator

    n, _, A, E, U, _ = _charged_particle(1)
    sys_ = NonholonomicSystem(CotangentBundle(n), np.eye(n), None, U, vector_potential=A)
    with pytest.raises(ValueError, match="vector_potential"):
        DLAIntegrator.from_system(sys_)


if __name__ == "__main__":  # pragma: no cover
    import sys

    code = pytest.main([__file__, "-q", "-p", "no:cacheprovider"])
    worst = sys.modules["test_vector_potential"].WORST  # the module pytest ran, not __main__
    print("\n".join(f"{k[0]:>24s} {k[1]:>10s}: {v:.2e}" for k, v in sorted(worst.items())))
    sys.exit(code)
