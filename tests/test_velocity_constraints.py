"""``NonholonomicSystem.from_velocity_constraints``: Pfaffian rows ``A(x) v = 0`` as people write them.

liefi forms ``e_i = m^{-1} a_i`` (and scales it); the extended field must equal the
one of the vector form built by hand from the same data, to 1e-12 at random
states, for a non-identity ``x``-dependent metric, on the two kinds of phase space
with shape variables (and a constant case on a Lie group).
"""

from __future__ import annotations

import numpy as np
import pytest

from liefi import CotangentBundle, LieGroupPhaseSpace, NonholonomicSystem, TrivialPrincipalBundle
from liefi.groups import SE2, SO3

TOL = 1e-12


def _data(space, seed):
    """Random ``m(x)`` (SPD, x-dependent), rows ``a(x)``, potential and vector potential, complex-step safe."""
    rng = np.random.default_rng(seed)
    n, D = space.n, space.D
    K = 2
    L = rng.normal(size=(D, D))
    M0 = L @ L.T + np.eye(D)
    S = rng.normal(size=(D, D))
    S = 0.2 * (S + S.T) / np.linalg.norm(S + S.T, 2) * np.linalg.eigvalsh(M0).min()
    a0 = rng.normal(size=(K, D)) * np.array([[3.0], [0.02]])  # rows in very different "units"
    a1 = 0.3 * rng.normal(size=(K, D))
    c, f, Av = rng.normal(size=n), rng.normal(size=n), 0.3 * rng.normal(size=D)

    def metric(x):
        return M0 + np.sin(x @ c)[..., None, None] * S

    def rows(x):
        return a0 + np.cos(x @ f)[..., None, None] * a1

    def potential(x):
        return np.sin(x @ c) + 0.5 * np.sum(x * x, -1)

    def vector_potential(x):
        return Av * (1 + np.sin(x @ f))[..., None]

    return rng, metric, rows, potential, vector_potential


SPACES = [
    pytest.param(CotangentBundle(3), id="cotangent"),
    pytest.param(TrivialPrincipalBundle(SE2(), 2), id="bundle-SE2"),
]


def _by_hand(space, metric, rows, potential, vp, unit):
    def e(x):
        a = rows(x)
        E = np.swapaxes(np.linalg.solve(metric(x), np.swapaxes(a, -1, -2)), -1, -2)
        return E / np.sqrt(np.sum(a * E, -1))[..., None] if unit else E

    return NonholonomicSystem(space, metric, e, potential, vector_potential=vp)


@pytest.mark.parametrize("space", SPACES)
@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("scaling", [None, "unit"])
def test_same_extended_field_as_the_vector_form(space, seed, scaling):
    rng, metric, rows, potential, vp = _data(space, seed)
    pf = NonholonomicSystem.from_velocity_constraints(space, metric, rows, potential, scaling=scaling, vector_potential=vp)
    vec = _by_hand(space, metric, rows, potential, vp, unit=scaling == "unit")
    z = rng.normal(size=(5, space.nz))
    for f in ("extended_vector_field", "constrained_vector_field", "extended_hamiltonian", "constraint_momenta"):
        want = getattr(vec, f)(z)
        got = getattr(pf, f)(z)
        assert np.max(np.abs(got - want)) <= TOL * max(1.0, np.max(np.abs(want))), f
    if scaling == "unit":
        C = pf.gram_matrix(z[:, : space.n])
        np.testing.assert_allclose(np.diagonal(C, axis1=-2, axis2=-1), 1.0, rtol=0, atol=1e-14)


@pytest.mark.parametrize("space", SPACES)
def test_constant_row_scaling_does_not_change_the_extended_field(space):
    """Rows rescaled by constants: the same extended field everywhere.  Any scaling (also the
    x-dependent "unit" and "orthonormal" ones): the same field on the constraint set, and the
    same constraint set."""
    rng, metric, rows, potential, vp = _data(space, 11)
    D = np.diag([25.0, 0.1])
    base = NonholonomicSystem.from_velocity_constraints(space, metric, rows, potential, scaling=None, vector_potential=vp)
    scaled = NonholonomicSystem.from_velocity_constraints(
        space, metric, lambda x: D @ rows(x), potential, scaling=None, vector_potential=vp)
    z = rng.normal(size=(5, space.nz))
    want = base.extended_vector_field(z)
    np.testing.assert_allclose(scaled.extended_vector_field(z), want, rtol=0, atol=TOL * np.abs(want).max())
    zc = base.project(z)
    want = base.extended_vector_field(zc)
    for scaling in ("unit", "orthonormal"):
        other = NonholonomicSystem.from_velocity_constraints(space, metric, rows, potential, scaling=scaling, vector_potential=vp)
        np.testing.assert_allclose(other.project(z), zc, rtol=0, atol=1e-12 * np.abs(zc).max())
        np.testing.assert_allclose(other.extended_vector_field(zc), want, rtol=0, atol=TOL * np.abs(want).max())


def test_velocity_constraint_holds_on_the_constraint_set():
    """On ``C`` the velocity ``v = dh/dP`` satisfies the user's rows: ``A(x) v = 0``."""
    space = TrivialPrincipalBundle(SE2(), 2)
    rng, metric, rows, potential, vp = _data(space, 4)
    pf = NonholonomicSystem.from_velocity_constraints(space, metric, rows, potential, vector_potential=vp)
    z = pf.project(rng.normal(size=(4, space.nz)))
    x, P = z[:, : space.n], z[:, space.n :]
    v = np.linalg.solve(metric(x), (P - vp(x))[..., None])[..., 0]
    Av = np.einsum("...kj,...j->...k", rows(x), v)
    assert np.abs(Av).max() < 1e-13 * np.abs(rows(x)).max() * np.abs(v).max()


def test_lie_group_rows_and_one_row_forms():
    I = np.diag([2.0, 1.5, 1.0])
    b = np.array([0.0, 0.0, 2.0])
    s1 = NonholonomicSystem.from_velocity_constraints(LieGroupPhaseSpace(SO3()), I, b)
    s2 = NonholonomicSystem(LieGroupPhaseSpace(SO3()), I, np.linalg.solve(I, b) / np.sqrt(b @ np.linalg.solve(I, b)))
    np.testing.assert_allclose(s1.constraints(np.zeros(0)), s2.constraints(np.zeros(0)), rtol=1e-15)
    # one constraint as a (..., D) function
    space = CotangentBundle(2)
    one = NonholonomicSystem.from_velocity_constraints(space, np.eye(2), lambda x: np.stack([np.cos(x[..., 0]), np.sin(x[..., 0])], -1))
    assert one.K == 1


@pytest.mark.parametrize(
    "A, match",
    [
        (np.zeros((1, 3)), "A: row"),
        (np.ones((1, 2)), "A: expected constraint rows of shape"),
        ("abc", "A: expected an array of real numbers"),
        (lambda x: 1 / 0, "A: calling it"),
    ],
)
def test_bad_rows_are_named(A, match):
    with pytest.raises(ValueError, match=match):
        NonholonomicSystem.from_velocity_constraints(CotangentBundle(3), np.eye(3), A)


def test_bad_scaling_is_named():
    with pytest.raises(ValueError, match="scaling"):
        NonholonomicSystem.from_velocity_constraints(CotangentBundle(2), np.eye(2), [[1.0, 0.0]], scaling="max")


def test_unit_scaling_makes_the_rows_units_free():
    """Rows written in wildly different units: the raw Gram matrix looks singular (refused as
    dependent), the default unit scaling gives C with unit diagonal and the same constraint set."""
    space = CotangentBundle(3)
    rows = np.array([[1e4, 2e4, 0.0], [0.0, 1e-4, 3e-4]])
    with pytest.raises(ValueError, match="linearly dependent"):
        NonholonomicSystem.from_velocity_constraints(space, np.eye(3), rows, scaling=None)
    s = NonholonomicSystem.from_velocity_constraints(space, np.eye(3), rows)
    np.testing.assert_allclose(np.diag(s.gram_matrix(np.zeros(3))), 1.0, rtol=1e-15)
    same = NonholonomicSystem.from_velocity_constraints(space, np.eye(3), rows / np.array([[1e4], [1e-4]]))
    z = np.random.default_rng(0).normal(size=(4, 6))
    np.testing.assert_allclose(s.extended_vector_field(z), same.extended_vector_field(z), rtol=1e-13, atol=1e-13)
