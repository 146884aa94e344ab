"""The heavy-top scene: liefi's derived field against the textbook Euler--Poisson equations, runs, the peer."""

from __future__ import annotations

import numpy as np
import pytest

from liefi import scenes
from liefi.scenes.heavy_top import euler_poisson, splitting

SCENE = scenes.get("heavy-top")


def test_derived_field_is_the_textbook_heavy_top():
    """The reduced field and ``R' = R hat(Omega)`` equal :func:`euler_poisson` (written by hand) at random states."""
    from liefi.reduction import full_vector_field

    rng = np.random.default_rng(11)
    R = np.linalg.qr(rng.normal(size=(5, 3, 3)))[0]
    y = np.concatenate([R.reshape(5, 9), rng.normal(size=(5, 6))], -1)
    want = np.stack([euler_poisson(SCENE.inertia, SCENE.mg, SCENE.chi)(0.0, yi) for yi in y])
    got = full_vector_field(SCENE.system, y)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14 * np.max(np.abs(want)))


def test_start_is_consistent():
    """``Gamma(0) = R(0)^T e_3`` and the four invariants are what the data say."""
    y0 = SCENE.initial_state(SCENE.variant())
    R0 = y0[:9].reshape(3, 3)
    np.testing.assert_allclose(y0[9:12], R0.T @ [0.0, 0.0, 1.0], atol=1e-15)


def test_imex_rk4_auto_keeps_every_invariant_at_rounding():
    """A short run (numpy backend): the energy, ``<Pi, Gamma>``, ``Pi_3`` and ``|Gamma|^2`` within 1e-12,
    the state within 1e-8 of the DOP853 reference on the textbook equations."""
    r = SCENE.run(t_final=0.5, scheme="imex-rk4", gains="auto", backend="numpy")
    assert set(r.max_drift) >= {"h", "Pi.Gamma", "Pi_3", "|Gamma|^2"}
    assert max(r.max_drift.values()) < 1e-12, r.max_drift
    assert max(r.max_error.values()) < 1e-8, r.max_error


def test_splitting_peer_is_poisson_and_second_order():
    """The peer keeps ``|Gamma|^2`` and ``<Pi, Gamma>`` to rounding; its error falls by ~4 when ``dt`` halves."""
    v = SCENE.variant()
    y0 = SCENE.initial_state(v)
    T = 1.0
    ref = SCENE.exact(np.array([0.0, T]), v)
    errs = []
    for dt in (0.02, 0.01):
        t, Y, _ = splitting(y0[:9], y0[9:12], y0[12:], SCENE.inertia, SCENE.mg, SCENE.chi, dt, int(round(T / dt)))
        G, P = Y[9:12], Y[12:15]
        assert np.max(np.abs(np.sum(G * G, 0) - 1.0)) < 1e-13
        assert np.max(np.abs(np.sum(G * P, 0) - np.sum(G[:, 0] * P[:, 0]))) < 1e-12
        want = np.array([ref[n][-1] for n in SCENE.error_variables])
        errs.append(np.max(np.abs(Y[9:, -1] - want)))
    assert 3.0 < errs[0] / errs[1] < 5.0, errs


@pytest.mark.slow
def test_full_horizon_meets_the_issue():
    """``liefi run heavy-top --scheme imex-rk4 --gains auto`` at its horizon: invariants within 1e-12,
    state error within 1e-6."""
    r = SCENE.run(scheme="imex-rk4", gains="auto")
    assert max(r.max_drift.values()) < 1e-12, r.max_drift
    assert max(r.max_error.values()) < 1e-6, r.max_error
