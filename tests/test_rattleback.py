"""The rattleback scene: Kane & Levinson's body against the rolling rigid body's equations written by hand."""

from __future__ import annotations

import numpy as np
import pytest

from liefi import scenes
from liefi.scenes.rattleback import first_reversal, inertia_matrix, rattleback_equations, start_attitude

SCENE = scenes.get("rattleback")


def test_start_is_kane_levinsons_in_liefis_axes():
    """On ``C``; ``Gamma`` tilted 0.5 deg about both horizontal axes; spin +5 rad/s about the upward vertical."""
    y0 = SCENE.initial_state(SCENE.variant())
    z = y0[11:]
    assert np.max(np.abs(SCENE.system.constraint_momenta(z))) < 1e-15
    t = np.radians(0.5)
    np.testing.assert_allclose(z[6:9], [np.cos(t) * np.sin(t), np.sin(t), np.cos(t) ** 2], atol=1e-15)
    spin = SCENE.observables(y0[:, None], list(SCENE.system.space.group.config_names + SCENE.system.state_names))
    np.testing.assert_allclose(spin["spin"], 5.0 * np.cos(t) ** 2, rtol=1e-14)
    assert inertia_matrix()[0, 1] == 2e-5  # -D: axis 3 flipped up


def test_reference_equations_match_liefi_on_C():
    """The hand-written equations give liefi's rates at the start and at a rocking state (checks the oracle)."""
    from liefi.reduction import full_vector_field

    fun = rattleback_equations(inertia_matrix(), 1.0, (0.2, 0.03, 0.02), 0.01, 9.81)
    from liefi.groups import SO3
    from liefi.rolling import rolling_start

    for R, W in (start_attitude(), (SO3().exp(np.array([0.1, -0.05, 0.7])), np.array([3.0, -1.0, 2.0]))):
        y = rolling_start(SCENE.system, R, W)
        f = full_vector_field(SCENE.system, y)
        _, r = fun.omega(np.concatenate([y[:11], np.zeros(3)]))
        K = inertia_matrix() @ W + np.cross(r, np.cross(W, r))
        ref = fun(0.0, np.concatenate([y[:11], K]))
        np.testing.assert_allclose(f[:11], ref[:11], atol=1e-14)
        # K' from liefi's field: K is linear in (Pi, p) on C through Omega
        eps = 1e-7
        Wp, _ = fun.omega(np.concatenate([y[:11], K]) + eps * ref)
        Wm, _ = fun.omega(np.concatenate([y[:11], K]) - eps * ref)
        m = SCENE.system.metric(y[11:20])
        W1 = np.linalg.solve(SCENE.system.metric(y[11:20] + eps * f[11:20]), y[20:] + eps * f[20:])[:3]
        W0 = np.linalg.solve(SCENE.system.metric(y[11:20] - eps * f[11:20]), y[20:] - eps * f[20:])[:3]
        np.testing.assert_allclose((W1 - W0), (Wp - Wm), rtol=1e-5, atol=1e-9 * np.max(np.abs(W)))
        assert m.shape == (5, 5)


def test_first_reversal_interpolates_a_sampled_zero():
    t = np.linspace(0.0, 1.0, 101)
    assert abs(first_reversal(t, np.cos(3 * t)) - np.pi / 6) < 1e-11
    assert np.isnan(first_reversal(t, 2.0 + t))


def test_short_run_keeps_every_invariant_at_rounding():
    """0.1 s of ``imex-rk4 --gains auto`` at dt = 2e-4 (numpy engine): invariants within 1e-12, state within 1e-7."""
    r = SCENE.run(t_final=0.1, scheme="imex-rk4", gains="auto", backend="numpy", dt=2e-4)
    assert {"h", "J_1", "J_2", "|Gamma|^2", "rho1.rho2"} <= set(r.max_drift)
    assert max(r.max_drift.values()) < 1e-12, r.max_drift
    assert {"r_1", "spin", "heading_rate"} <= set(r.max_error)
    assert max(r.max_error.values()) < 1e-7, r.max_error


def test_figures():
    pytest.importorskip("matplotlib")
    r = SCENE.run(t_final=0.05, scheme="imex-rk4", gains="auto", backend="numpy", dt=1e-3)
    specs = SCENE.figures(r)
    assert [s.key for s in specs] == ["rattleback-spin", "rattleback-energy", "generic"]
    for s in specs[:2]:
        assert s.draw(None).get_axes()[0].lines


@pytest.mark.slow
def test_full_horizon_reverses_at_the_reference_time():
    """``liefi run rattleback --scheme imex-rk4 --gains auto`` (t = 5, dt = 1e-4): the first reversal within
    1e-6 relative of the reference's event, invariants within 1e-12, state error within 1e-6."""
    r = SCENE.run(scheme="imex-rk4", gains="auto")
    t_rev = first_reversal(r.t, SCENE.observables(r.y, list(r.names))["heading_rate"])
    t_ref = SCENE.reference_reversal()
    assert 2.0 < t_ref < 3.0
    assert abs(t_rev - t_ref) <= 1e-6 * t_ref, (t_rev, t_ref)
    assert max(r.max_drift.values()) < 1e-12, r.max_drift
    assert max(r.max_error.values()) < 1e-6, r.max_error
