"""A user defines a system the paper does not treat, with data only.

(a) A rigid body on SO(3) with two *non-orthonormal* linear constraints
    (``LieGroupPhaseSpace(SO3())``, constant inertia);
(b) a planar body carrying a rotor, ``SE(2) x S^1`` as
    ``TrivialPrincipalBundle(SE2(), 1)``, with a shape-dependent metric and
    shape-dependent, non-orthonormal constraints (the README example).

For each: build the :class:`~liefi.FeedbackIntegrator` from the data, run RK4 for
a short horizon from a start on the constraint set and on the group, and check
that ``h~``, ``h`` and every ``J_i`` are conserved -- without feedback (drift at
the level of RK4's error) and with feedback gains 10 -- and that the
configuration stays on the group.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import liefi
from liefi.groups import SE2, SO3

DT, T_FINAL = 2e-3, 0.5
TOL = 1e-9


def rigid_body_with_two_constraints():
    """(a) Inertia with products of inertia; constraints ``e_1``, ``e_2`` neither unit nor orthogonal."""
    II = np.array([[2.0, 0.3, -0.1], [0.3, 1.5, 0.2], [-0.1, 0.2, 1.0]])
    E = np.array([[1.0, 0.4, 0.0], [0.2, 1.0, 0.7]])
    body = liefi.NonholonomicSystem(liefi.LieGroupPhaseSpace(SO3()), II, E)
    Pi0 = body.project(np.array([0.3, -0.8, 1.1]))
    R0 = SO3().exp(np.array([0.2, -0.4, 0.9])).ravel()
    return body, np.concatenate([R0, Pi0])


def rotor_on_planar_body():
    """(b) The README's system: ``x = psi``, ``P = (Pi_theta, Pi_x, Pi_y, p_psi)``."""

    def metric(x):
        c = np.cos(x[..., 0]); one = np.ones_like(c); zero = 0 * c  # noqa: E702
        return np.stack([np.stack([2 + 0.5 * c, zero, 0.3 * one, 0.4 * one], -1),
                         np.stack([zero, one, zero, zero], -1),
                         np.stack([0.3 * one, zero, one, zero], -1),
                         np.stack([0.4 * one, zero, zero, 0.5 * one], -1)], -2)

    def constraints(x):
        s = np.sin(x[..., 0]); one = np.ones_like(s); zero = 0 * s  # noqa: E702
        return np.stack([np.stack([zero, zero, one, zero], -1),           # no side slip
                         np.stack([0.2 * s, one, zero, -one], -1)], -2)   # rotor rolls with the body

    racer = liefi.NonholonomicSystem(liefi.TrivialPrincipalBundle(SE2(), 1, names=("psi",)), metric, constraints)
    z0 = racer.project(np.array([0.3, 1.0, 0.5, 0.0, -0.2]))
    return racer, np.concatenate([SE2().identity_config(), z0])


SYSTEMS = {"rigid_body_two_constraints": rigid_body_with_two_constraints, "rotor_on_planar_body": rotor_on_planar_body}


@pytest.fixture(scope="module", params=sorted(SYSTEMS))
def runs(request):
    """RK4 runs without (gains 0) and with (gains 10) feedback, shared by the tests below."""
    system, y0 = SYSTEMS[request.param]()
    out = {}
    for gains in (0.0, 10.0):
        fi = liefi.FeedbackIntegrator(system, y0, gains=gains)
        if gains:  # the README's way
            sol = fi.run(T_FINAL, dt=DT, scheme="rk4", save_every=25)
        else:  # the plain driver on the same field
            sol = liefi.integrate(fi.vector_field, y0, DT, int(round(T_FINAL / DT)), "rk4", save_every=25, names=fi.names)
        out[gains] = (fi, sol)
    return request.param, system, y0, out


def test_data_define_a_valid_nonorthonormal_system(runs):
    name, system, y0, out = runs
    fi = out[10.0][0]
    z0 = y0[fi.nc:]
    assert system.K == 2
    C = system.gram_matrix(z0[: system.space.n])
    assert np.max(np.abs(C - np.eye(2))) > 0.1  # genuinely not orthonormal
    assert np.max(np.abs(system.constraint_momenta(z0))) < 1e-14
    assert set(fi.invariant_names) == {"penalty", "J_1", "J_2", "energy"}
    assert fi.lyapunov(y0) < 1e-28


@pytest.mark.parametrize("gains", [0.0, 10.0], ids=["no_feedback", "feedback_10"])
def test_first_integrals_conserved(runs, gains):
    """``h~``, ``h`` and ``J_1, J_2`` stay at their initial values; ``R`` stays on the group."""
    name, system, y0, out = runs
    fi, sol = out[gains]
    v = fi.invariant_values(np.moveaxis(sol.y, -1, 0))
    for k in ("J_1", "J_2"):
        assert np.max(np.abs(v[k])) < TOL, (k, np.max(np.abs(v[k])))
    for k in ("h~", "h"):
        assert np.max(np.abs(v[k] - v[k][0])) < TOL * max(1.0, abs(v[k][0])), (k, np.ptp(v[k]))
    assert np.max(v["penalty"]) < 1e-18
    assert np.all(np.isfinite(sol.y))


def test_feedback_does_not_change_the_trajectory(runs):
    """Started on ``V^{-1}(0)``, the feedback and the plain extended field give the same motion."""
    name, system, y0, out = runs
    y_plain, y_fb = out[0.0][1].y, out[10.0][1].y
    assert np.max(np.abs(y_plain - y_fb)) < 1e-9 * max(1.0, np.abs(y_plain).max())
    assert np.max(np.abs(y_plain[..., -1] - y0)) > 1e-3  # and it does move


def test_scipy_solve_ivp_agrees(runs):
    """The same ``fun(t, y)`` in ``scipy.integrate.solve_ivp`` (DOP853) reproduces the RK4 run."""
    name, system, y0, out = runs
    fi, sol = out[10.0]
    ivp = solve_ivp(fi.fun, (0.0, T_FINAL), y0, method="DOP853", rtol=1e-11, atol=1e-12)
    assert ivp.success
    np.testing.assert_allclose(ivp.y[:, -1], sol.y[..., -1], atol=1e-9)
