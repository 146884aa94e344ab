"""A rolling body's defaults and its checks of bad input (issue 23): what it holds, what it refuses and why.

* the default :class:`~liefi.FeedbackIntegrator` of a rolling body holds the six attitude
  Casimirs (the phase space carries them), so ``|Gamma|^2`` stays at rounding;
* a start that is not a state of the body (attitude rows not orthonormal, a slipping
  contact, a configuration that disagrees with the rows) is refused, naming what is wrong;
* bad body data are named for what they are (inertia not positive definite, NaN,
  overflow, a degenerate surface, a contact function that is not complex-step safe or
  that no surface has).
"""

from __future__ import annotations

import numpy as np
import pytest

from liefi import FeedbackIntegrator, rolling
from liefi.groups import SO3

A, B, C, M = 0.03, 0.03, 0.045, 0.06
INERTIA = M / 5 * np.array([B**2 + C**2, A**2 + C**2, A**2 + B**2])
EGG = rolling.ellipsoid([A, B, C], offset=[0.0, 0.0, -0.003])


@pytest.fixture(scope="module")
def egg():
    body = rolling.rolling_body(M, INERTIA, EGG, gravity=9.81)
    lying = SO3().exp(np.array([np.pi / 2 - 0.1, 0.0, 0.0]))
    return body, rolling.rolling_start(body, lying, Omega=[0.0, 8.0, 1.0])


# --- item: the default holds the attitude Casimirs ------------------------------------------------


def test_default_integrator_holds_the_attitude_casimirs(egg):
    body, y0 = egg
    fi = FeedbackIntegrator(body, y0, gains="auto")
    names = [c.name for c in rolling.ATTITUDE_CASIMIRS]
    assert set(names) <= set(fi.invariant_names)
    assert all(fi.gains[n] > 0 for n in names)
    sol = fi.run(0.05, dt=1e-3, scheme="imex-rk4", backend="numpy")
    z = sol.y.T[:, fi.nc:]
    for c in rolling.ATTITUDE_CASIMIRS:
        v = c.fun(z)
        assert np.max(np.abs(v - v[0])) < 5e-15, c.name


def test_an_explicit_choice_of_invariants_is_kept(egg):
    body, y0 = egg
    fi = FeedbackIntegrator(body, y0, invariants=("constraints", "energy"))
    assert fi.invariant_names == ("penalty", "J_1", "J_2", "energy")


# --- item: a start that is no state of the body is refused -------------------------------------------

NC = 11  # (R, x, y) before the reduced state (rho_1, rho_2, Gamma, Pi, p)


def _bad_starts(y0):
    gamma2 = y0.copy()
    gamma2[NC + 6:NC + 9] *= 2.0  # |Gamma| = 2
    rows = y0.copy()
    rows[NC:NC + 3] *= 1.3  # |rho_1| = 1.3
    slip = y0.copy()
    slip[-2] += 0.5  # p_1: u no longer solves the no-slip rows
    config = y0.copy()
    config[:9] = 2.0 * config[:9]  # R is not the rows
    reflection = y0.copy()
    reflection[NC:NC + 3] *= -1.0
    reflection[:3] *= -1.0
    return [("gamma", gamma2, r"not orthonormal .*\|Gamma\| = 2\b"), ("slip", slip, "slips"),
            ("rows", rows, r"not orthonormal .*\|rho1\| = 1\.3"), ("config", config, "configuration R"),
            ("reflection", reflection, "reflection")]


@pytest.mark.parametrize("case", range(5), ids=["gamma", "slip", "rows", "config", "reflection"])
def test_a_start_that_is_no_state_of_the_body_is_named(egg, case):
    body, y0 = egg
    name, y, match = _bad_starts(y0)[case]
    with pytest.raises(ValueError, match="y0: .*" + match):
        FeedbackIntegrator(body, y)
    if name != "config":  # the reduced start alone, and an ensemble, are checked the same way
        with pytest.raises(ValueError, match="y0: .*" + match):
            FeedbackIntegrator(body, y[NC:], configuration=False)
        with pytest.raises(ValueError, match=r"member \(1,\)"):
            FeedbackIntegrator(body, np.stack([y0, y]))


def test_rounding_and_a_runs_drift_are_accepted(egg):
    body, y0 = egg
    rng = np.random.default_rng(0)
    y = y0 * (1.0 + 1e-12 * rng.standard_normal(y0.shape))  # a restart from a saved state
    FeedbackIntegrator(body, y)
    FeedbackIntegrator(body, body.project(y0[NC:]), configuration=False)  # the fix the message names


def test_a_contact_function_that_no_surface_has_is_named():
    A2 = np.array([0.03, 0.02, 0.045]) ** 2

    def egg_unnormalized(G):  # r_s(n) = -A^2 n without the 1/sqrt(n.A^2 n): no surface's contact point
        return -A2 * np.asarray(G)

    R = SO3().exp(np.array([0.4, -0.3, 0.2]))
    assert rolling.tangency_residual(EGG, R[2]) < 1e-14  # a surface: rounding
    assert rolling.tangency_residual(rolling.disk(1.0), R[2]) < 1e-14
    assert rolling.tangency_residual(egg_unnormalized, R[2]) > 0.1
    body = rolling.rolling_body(M, INERTIA, egg_unnormalized)  # tangent at the sample Gamma = e_3, by chance
    with pytest.raises(ValueError, match=r"contact: .*egg_unnormalized\(Gamma\) is not the contact point of any "
                                         r"surface: .*\(the start\)"):
        FeedbackIntegrator(body, rolling.rolling_start(body, R, [0.0, 8.0, 1.0]))
    with pytest.raises(ValueError, match=r"not the contact point of any surface: .*\(the attitude sample\)"):
        rolling.rolling_body(M, INERTIA, egg_unnormalized, sample=R)
    point = rolling.rolling_body(M, INERTIA, lambda G: 0.0 * np.asarray(G) + np.array([0.0, 0.0, -0.05]))
    FeedbackIntegrator(point, rolling.rolling_start(point, R, [0.0, 1.0, 0.0]))  # a point contact is a surface


# --- item: bad body data are named for what they are ----------------------------------------------------


@pytest.mark.parametrize("mass,inertia,match", [
    (M, [0.0, 0.0, 0.0], r"inertia: must be positive definite .*\[0\.0, 0\.0, 0\.0\]"),
    (M, [0.0, 1e-5, 1e-5], "inertia: must be positive definite"),
    (M, [np.nan, 1e-5, 1e-5], "inertia: contains NaN"),
    (M, np.diag([1e-5, np.inf, 1e-5]), "inertia: contains an infinite number"),
    (M, [[1e-5, 2e-6, 0], [0, 1e-5, 0], [0, 0, 1e-5]], "inertia: not symmetric"),
    (1e308, INERTIA, r"the mass m = 1e\+308 is outside .*overflow"),
    (1e-320, INERTIA, r"the mass m = 1e-320 is outside .*underflow"),
    (1e20, INERTIA, r"m L\^2 = .* differ by a factor .*check the units"),
], ids=["inertia 0", "a moment 0", "NaN", "inf", "asymmetric", "m 1e308", "m subnormal", "m vs I"])
def test_bad_body_data_are_named_for_what_they_are(mass, inertia, match):
    with pytest.raises(ValueError, match=match):
        rolling.rolling_body(mass, inertia, EGG)


def test_a_degenerate_surface_is_named():
    flat = rolling.ellipsoid([A, B, 1e-9])
    with pytest.raises(ValueError, match=r"contact: the surface of .*ellipsoid.* is degenerate .*radius of "
                                         r"curvature there, 9e\+05, is 3e\+07 times the body's size"):
        rolling.rolling_body(M, INERTIA, flat)
    rolling.rolling_body(M, INERTIA, rolling.ellipsoid([A, B, A / 1000]))  # thin, but curved enough: accepted


def test_a_contact_function_that_drops_the_imaginary_part_is_named():
    def ball_with_norm(G):
        G = np.asarray(G)
        return -0.05 * G / np.linalg.norm(G, axis=-1)[..., None]

    with pytest.raises(ValueError, match=r"contact: .*ball_with_norm\(Gamma\) is not complex-step safe.*"
                                         r"np\.sqrt\(Gamma @ Gamma\).*rather than np\.linalg\.norm"):
        rolling.rolling_body(M, INERTIA, ball_with_norm)

    def ball(G):  # the same written as the message says: accepted, the same system as rolling.sphere
        G = np.asarray(G)
        return -0.05 * G / np.sqrt(np.sum(G * G, -1))[..., None]

    rolling.rolling_body(M, INERTIA, ball)
