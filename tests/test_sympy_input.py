"""``liefi.from_sympy``: the knife edge and the nonholonomic oscillator from a sympy Lagrangian.

Their extended (and constrained) fields equal the hand-written scenes' to 1e-12 at
random states, on and off the constraint set; a Lagrangian with terms linear in
the velocities gives the vector potential; a non-quadratic ``L`` and a nonlinear
constraint are refused with named errors.
"""

from __future__ import annotations

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")

import liefi  # noqa: E402
from liefi import CotangentBundle, NonholonomicSystem, scenes  # noqa: E402
from liefi.sympy_input import NonlinearConstraintError, NotQuadraticError  # noqa: E402

TOL = 1e-12


def _agree(a, b, z):
    for f in ("extended_vector_field", "constrained_vector_field", "extended_hamiltonian", "hamiltonian"):
        want, got = getattr(b, f)(z), getattr(a, f)(z)
        assert np.max(np.abs(got - want)) <= TOL * max(1.0, np.max(np.abs(want))), f


def test_knife_edge_from_sympy_equals_the_scene():
    x, y, phi, xd, yd, phid = sympy.symbols("x y phi xd yd phid")
    sc = scenes.get("knife-edge")
    m, J, g, alpha = sc.m, sc.J, sc.g, sc.alpha
    L = m / 2 * (xd**2 + yd**2) + J / 2 * phid**2 + m * g * x * sympy.sin(alpha)
    # written with the opposite sign of the scene's row: a constant scaling, same field
    knife = liefi.from_sympy(L, [x, y, phi], [xd, yd, phid], [yd * sympy.cos(phi) - xd * sympy.sin(phi)])
    assert knife.state_names == sc.system.state_names
    assert knife.metric.constant and knife.vector_potential is None
    rng = np.random.default_rng(0)
    z = rng.normal(size=(6, 6))
    _agree(knife, sc.system, z)
    _agree(knife, sc.system, sc.system.project(z))


def test_oscillator_from_sympy_equals_the_scene():
    q = sympy.symbols("x y z")
    qd = sympy.symbols("xd yd zd")
    L = sum(v**2 for v in qd) / 2 - sum(c**2 for c in q) / 2
    osc = liefi.from_sympy(L, q, qd, [qd[0] + q[1] * qd[2]])
    sc = scenes.get("oscillator")
    z = np.random.default_rng(1).normal(size=(6, 6))
    _agree(osc, sc.system, z)
    # the feedback integrators agree too (same data, same V)
    fi_a = sc.integrator(sc.default_variant if hasattr(sc, "default_variant") else next(iter(sc.variants)),
                         configuration=False)
    fi_b = liefi.FeedbackIntegrator(osc, fi_a.y0, gains=dict(fi_a.gains), invariants=["constraints", "energy"] + list(fi_a.user),
                                    energy=fi_a.energy, configuration=False)
    np.testing.assert_allclose(fi_b.vector_field(z), fi_a.vector_field(z), rtol=TOL, atol=TOL * np.abs(fi_a.vector_field(z)).max())


def test_dynamicsymbols_and_x_dependent_metric():
    """A double-pendulum-like metric in q(t) symbols: fields equal the hand-made data form."""
    mech = pytest.importorskip("sympy.physics.mechanics")
    a, b = mech.dynamicsymbols("a b")
    t = mech.dynamicsymbols._t
    ad, bd = a.diff(t), b.diff(t)
    L = ad**2 + bd**2 / 2 + sympy.cos(a - b) * ad * bd + sympy.cos(a) + sympy.Rational(1, 2) * sympy.cos(b)
    sys_ = liefi.from_sympy(L, [a, b], [ad, bd], [ad + sympy.sin(b) * bd + 2 * bd])
    assert sys_.state_names == ("a", "b", "p_a", "p_b")

    def metric(x):
        c = np.cos(x[..., 0] - x[..., 1])
        one = np.ones_like(c)
        return np.stack([np.stack([2 * one, c], -1), np.stack([c, one], -1)], -2)

    def rows(x):
        return np.stack([np.ones_like(x[..., 0]), np.sin(x[..., 1]) + 2], -1)[..., None, :]

    def U(x):
        return -np.cos(x[..., 0]) - 0.5 * np.cos(x[..., 1])

    ref = NonholonomicSystem.from_velocity_constraints(CotangentBundle(2), metric, rows, U)
    _agree(sys_, ref, np.random.default_rng(2).normal(size=(5, 4)))


def test_terms_linear_in_the_velocities_become_the_vector_potential():
    """A charged particle ``L = 1/2 |qd|^2 + A(q).qd - U``: the same system as the data form."""
    q = sympy.symbols("q1 q2 q3")
    qd = sympy.symbols("v1 v2 v3")
    Aq = [q[1] * q[2], -q[0] + sympy.sin(q[2]), sympy.Integer(1)]
    L = sum(v**2 for v in qd) / 2 + sum(Ai * v for Ai, v in zip(Aq, qd)) - q[0] ** 2
    sys_ = liefi.from_sympy(L, q, qd, [qd[0] + q[1] * qd[1]])

    def A(x):
        return np.stack([x[..., 1] * x[..., 2], -x[..., 0] + np.sin(x[..., 2]), np.ones_like(x[..., 0])], -1)

    ref = NonholonomicSystem.from_velocity_constraints(
        CotangentBundle(3), np.eye(3), lambda x: np.stack([np.ones_like(x[..., 0]), x[..., 1], 0 * x[..., 0]], -1),
        lambda x: x[..., 0] ** 2, vector_potential=A)
    assert sys_.vector_potential is not None
    _agree(sys_, ref, np.random.default_rng(3).normal(size=(5, 6)))


def test_non_quadratic_lagrangian_is_named():
    x, xd = sympy.symbols("x xd")
    with pytest.raises(NotQuadraticError, match="L: of degree 4"):
        liefi.from_sympy(xd**4 / 4 + xd**2 / 2 - x**2, [x], [xd])
    with pytest.raises(NotQuadraticError, match="L: not a polynomial in the velocities"):
        liefi.from_sympy(sympy.cos(xd) - x**2, [x], [xd])


def test_nonlinear_constraint_is_named():
    q = sympy.symbols("x y")
    qd = sympy.symbols("xd yd")
    L = (qd[0] ** 2 + qd[1] ** 2) / 2
    with pytest.raises(NonlinearConstraintError, match=r"constraints\[0\]: .* not linear"):
        liefi.from_sympy(L, q, qd, [qd[0] ** 2 - qd[1]])
    with pytest.raises(NonlinearConstraintError, match=r"constraints\[1\]: .* not linear"):
        liefi.from_sympy(L, q, qd, [qd[0] - qd[1], sympy.sin(qd[0])])
    with pytest.raises(NonlinearConstraintError, match="affine"):
        liefi.from_sympy(L, q, qd, [qd[0] - 1])


def test_other_bad_input_is_named():
    x, xd, k = sympy.symbols("x xd k")
    with pytest.raises(ValueError, match=r"L: contains symbols \['k'\]"):
        liefi.from_sympy(xd**2 / 2 - k * x**2, [x], [xd])
    with pytest.raises(ValueError, match="qd: expected 1 velocities"):
        liefi.from_sympy(xd**2 / 2, [x], [xd, k])
    with pytest.raises(ValueError, match="q: expected"):
        liefi.from_sympy(xd**2 / 2, "x", [xd])
    with pytest.raises(ValueError, match="metric: not (symmetric )?positive definite"):
        liefi.from_sympy(-(xd**2) / 2, [x], [xd])
