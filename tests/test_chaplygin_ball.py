"""The chaplygin-ball scene: short runs against Chaplygin's equations, the contact path figure."""

from __future__ import annotations

import numpy as np
import pytest

from liefi import scenes
from liefi.scenes.chaplygin_ball import chaplygin_equations

SCENE = scenes.get("chaplygin-ball")


def test_start_is_on_C_and_consistent():
    """The start has ``J = 0``, ``(rho_1, rho_2, Gamma)`` = the rows of ``R(0)``, and its momenta are ``m (Omega, u)``."""
    y0 = SCENE.initial_state(SCENE.variant())
    z = y0[11:]
    assert np.max(np.abs(SCENE.system.constraint_momenta(z))) < 1e-15
    np.testing.assert_allclose(z[:9], y0[:9], atol=0)
    np.testing.assert_allclose(z[9:12], SCENE.inertia * SCENE.Omega0, atol=1e-15)


def test_reference_equations_match_liefi_on_C():
    """Chaplygin's equations written by hand give liefi's rates at the start (a check of the oracle itself)."""
    from liefi.reduction import full_vector_field

    y0 = SCENE.initial_state(SCENE.variant())
    f = full_vector_field(SCENE.system, y0)
    G0, W0 = y0[17:20], SCENE.Omega0
    M0 = SCENE.inertia * W0 + SCENE.mass * SCENE.radius**2 * np.cross(G0, np.cross(W0, G0))
    ref = chaplygin_equations(SCENE.inertia, SCENE.mass, SCENE.radius)(0.0, np.concatenate([y0[:20], M0]))
    np.testing.assert_allclose(f[:20], ref[:20], atol=1e-14)


def test_imex_rk4_auto_keeps_every_invariant_at_rounding():
    """A short numpy run: ``E``, ``<M, Gamma>``, ``|M|^2``, ``|Gamma|^2``, ``J`` and the other Casimirs within
    1e-12; the state and the contact path within 1e-10 of the reference."""
    r = SCENE.run(t_final=0.3, scheme="imex-rk4", gains="auto", backend="numpy")
    assert {"h", "M.Gamma", "|M|^2", "|Gamma|^2", "J_1", "J_2"} <= set(r.max_drift)
    assert max(r.max_drift.values()) < 1e-12, r.max_drift
    assert {"r_1", "r_2"} <= set(r.max_error)
    assert max(r.max_error.values()) < 1e-10, r.max_error


def test_contact_path_figure():
    pytest.importorskip("matplotlib")
    r = SCENE.run(t_final=0.05, scheme="imex-rk4", gains="auto", backend="numpy")
    specs = SCENE.figures(r)
    assert [s.key for s in specs] == ["chaplygin-ball-path", "generic"]
    fig = specs[0].draw(None)
    assert fig.get_axes()[0].lines  # the path is drawn


@pytest.mark.slow
def test_full_horizon_meets_the_issue():
    """``liefi run chaplygin-ball --scheme imex-rk4 --gains auto`` (t = 100): invariants within 1e-12,
    state and path error within 1e-6."""
    r = SCENE.run(scheme="imex-rk4", gains="auto")
    assert max(r.max_drift.values()) < 1e-12, r.max_drift
    assert max(r.max_error.values()) < 1e-6, r.max_error
