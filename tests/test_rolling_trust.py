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
