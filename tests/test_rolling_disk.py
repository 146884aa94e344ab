"""The rolling-disk scene: a thin disk against the rolling rigid body's equations written by hand, and two
special solutions (straight upright rolling, steady motion on a circle) derived here from those equations."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from liefi import FeedbackIntegrator, scenes
from liefi.groups import SO3
from liefi.reduction import full_vector_field
from liefi.rolling import rolling_start
from liefi.scenes.rolling_disk import GRAVITY, MASS, RADIUS, disk_equations, inertia_matrix, start_attitude

SCENE = scenes.get("rolling-disk")
FUN = disk_equations(inertia_matrix(), MASS, RADIUS, GRAVITY)
H = 1e-30


def _contact(G):
    """The disk's contact point, written again for the test: the lowest point of the rim."""
    s = np.sqrt(G[..., 0] ** 2 + G[..., 1] ** 2)
    return -RADIUS * np.stack([G[..., 0] / s, G[..., 1] / s, 0.0 * s], -1)


def _K(y):
    """``K = I Omega + m r x (Omega x r)`` from liefi's full state ``(R, x, rho_1, rho_2, Gamma, Pi, p)``."""
    V, P = y[11:20], y[20:]
    W = np.linalg.solve(SCENE.system.metric(V), P)[:3]
    r = _contact(V[6:9])
    return inertia_matrix() @ W + MASS * np.cross(r, np.cross(W, r))


def _reference_state(y):
    return np.concatenate([y[:11], _K(y).real])


def _states():
    rng = np.random.default_rng(7)
    out = [rolling_start(SCENE.system, *start_attitude())]
    for _ in range(4):
        R = SO3().exp(rng.normal(size=3) * np.array([1.0, 0.5, 1.0]))
        if abs(R[2, 2]) < 0.9:  # away from lying flat
            out.append(rolling_start(SCENE.system, R, rng.normal(size=3) * 2))
    return out


def test_scene_is_registered_and_starts_on_C():
    assert "rolling-disk" in scenes.names() and not SCENE.in_paper
    y0 = SCENE.initial_state(SCENE.variant())
    assert np.max(np.abs(SCENE.system.constraint_momenta(y0[11:]))) < 1e-15
    np.testing.assert_allclose(y0[17:20], [0.0, np.sin(np.radians(70)), np.cos(np.radians(70))], atol=1e-15)


@pytest.mark.parametrize("y", _states())
def test_field_equals_the_reference_equations_on_C(y):
    """liefi's derived field at states on ``C``: ``R'``, ``x'``, ``y'`` equal the reference's, and ``K'``
    (liefi's, by complex step of ``K`` along its field) equals the reference's ``K'``."""
    f = full_vector_field(SCENE.system, y)
    ref = FUN(0.0, _reference_state(y))
    np.testing.assert_allclose(f[:11], ref[:11], atol=1e-13 * max(1.0, np.max(np.abs(ref[:11]))))
    Kdot = (_K(y + 1j * H * f)).imag / H
    np.testing.assert_allclose(Kdot, ref[11:], atol=1e-12 * max(1.0, np.max(np.abs(ref[11:]))))


def test_upright_disk_rolls_in_a_straight_line():
    """Upright (``Gamma_3 = 0``), spinning about its axis at ``w``: the axis stays horizontal, ``Omega`` stays
    ``(0, 0, w)`` and the centre moves on a line at speed ``a w`` (the reference's equations give ``K' = 0``
    there: ``r x Gamma = 0``, ``r' || Omega x r``)."""
    w = 3.0
    R, _ = start_attitude(tilt_deg=90.0)
    y = np.concatenate([R.ravel(), [0.0, 0.0], np.zeros(3)])
    assert np.max(np.abs(FUN(0.0, np.concatenate([y[:11], inertia_matrix() @ [0, 0, w]]))[11:])) < 1e-14
    y0 = rolling_start(SCENE.system, R, [0.0, 0.0, w])
    fi = FeedbackIntegrator(SCENE.system, y0, invariants=SCENE.invariants(SCENE.variant()), gains="auto")
    sol = fi.run((0.0, 3.0), dt=1e-3, scheme="imex-rk4")
    Y = sol.y
    W = np.linalg.solve(SCENE.system.metric(Y[11:20].T), Y[20:].T[..., None])[..., 0][:, :3]
    assert np.max(np.abs(W - [0.0, 0.0, w])) < 1e-12
    assert np.max(np.abs(Y[19])) < 1e-13  # Gamma_3
    xy = Y[9:11]
    np.testing.assert_allclose(np.hypot(*(xy - xy[:, :1])), RADIUS * w * sol.t, rtol=1e-12, atol=1e-12)


def _steady(tilt_deg, s):
    """The precession rate ``n`` of steady motion ``Omega = n Gamma + s e_3`` at the given tilt: every vector
    in the body co-rotates about ``e_3`` (``X' = s X x e_3``), so the reference's ``K'`` must be ``s K x e_3``;
    its one non-trivial component, quadratic in ``n``, is solved by ``brentq``."""
    from scipy.optimize import brentq

    R, _ = start_attitude(tilt_deg=tilt_deg)
    G = R[2]

    def residual(n):
        W = n * G + s * np.array([0.0, 0.0, 1.0])
        r = _contact(G)
        K = inertia_matrix() @ W + MASS * np.cross(r, np.cross(W, r))
        Kd = FUN(0.0, np.concatenate([R.ravel(), [0.0, 0.0], K]))[11:]
        return Kd - s * np.cross(K, [0.0, 0.0, 1.0])

    grid = np.linspace(-20.0, 20.0, 401)
    vals = np.array([residual(n)[0] for n in grid])
    k = int(np.flatnonzero(np.sign(vals[1:]) != np.sign(vals[:-1]))[0])  # the first root (there are two)
    n = brentq(lambda n: residual(n)[0], grid[k], grid[k + 1], xtol=1e-15, rtol=1e-15)
    assert np.max(np.abs(residual(n))) < 1e-12  # the other components vanish: a steady motion
    return R, n * G + s * np.array([0.0, 0.0, 1.0]), n


def test_tilted_disk_in_steady_circular_motion():
    """At a fixed tilt (60 deg from flat), with the spin ``s`` and the precession ``n`` the reference's
    equations fix, liefi keeps the tilt and ``Omega_3``, and the centre runs on a circle at rate ``n``."""
    R, W, n = _steady(60.0, 2.0)
    y0 = rolling_start(SCENE.system, R, W)
    fi = FeedbackIntegrator(SCENE.system, y0, invariants=SCENE.invariants(SCENE.variant()), gains="auto")
    sol = fi.run((0.0, 2.0), dt=1e-3, scheme="imex-rk4")
    Y = sol.y
    assert np.max(np.abs(Y[19] - Y[19, 0])) < 1e-11  # the tilt
    Wt = np.linalg.solve(SCENE.system.metric(Y[11:20].T), Y[20:].T[..., None])[..., 0][:, :3]
    assert np.max(np.abs(Wt[:, 2] - W[2])) < 1e-11
    assert np.max(np.abs(np.sum(Wt * Y[17:20].T, -1) - (n + 2.0 * Y[19, 0]))) < 1e-11  # spin about the vertical
    # the centre's velocity turns at rate n with constant speed: a circle
    v = np.diff(Y[9:11], axis=1) / np.diff(sol.t)
    speed = np.hypot(*v)
    assert np.ptp(speed) < 1e-9 * speed[0]
    heading = np.unwrap(np.arctan2(v[1], v[0]))
    rate = np.diff(heading) / np.diff(sol.t)[1:]
    np.testing.assert_allclose(rate, n, rtol=1e-8)


def test_short_run_keeps_every_invariant_at_rounding():
    """2 time units of ``imex-rk4 --gains auto`` at the scene's step: invariants within 1e-12, state 1e-8."""
    r = SCENE.run(t_final=2.0, scheme="imex-rk4", gains="auto")
    assert {"h", "J_1", "J_2", "|Gamma|^2", "rho1.rho2"} <= set(r.max_drift)
    in_V = {k: v for k, v in r.max_drift.items() if not k.startswith("chaplygin_")}  # those: monitored only
    assert max(in_V.values()) < 1e-12, r.max_drift
    assert {"r_1", "Gamma_3", "spin", "axial_spin"} <= set(r.max_error)
    assert max(r.max_error.values()) < 1e-8, r.max_error


def test_figures():
    pytest.importorskip("matplotlib")
    r = SCENE.run(t_final=0.05, scheme="imex-rk4", gains="auto", backend="numpy", dt=1e-2)
    specs = SCENE.figures(r)
    assert [s.key for s in specs] == ["rolling-disk-path", "rolling-disk-integrals", "generic"]
    assert specs[1].draw(None).get_axes()[0].lines
    assert specs[0].draw(None).get_axes()[0].lines


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["tilted", "integrals-in-V"])
def test_full_horizon_cli(variant):
    """``python -m liefi run rolling-disk --scheme imex-rk4 --gains auto`` (t = 50): every invariant in ``V``
    within 1e-12, the state within 1e-6 of the reference; Chaplygin's integrals, monitored only, drift with the
    state error (the default variant), or within 1e-12 too when ``V`` penalizes them (``integrals-in-V``)."""
    import json

    out = subprocess.run([sys.executable, "-m", "liefi", "run", "rolling-disk", "--scheme", "imex-rk4", "--gains",
                          "auto", "--variant", variant, "--json"], capture_output=True, text=True, timeout=1200)
    assert out.returncode == 0, out.stderr[-2000:]
    data = json.loads(out.stdout)
    drift = data["max_drift"]
    in_V = {k: v for k, v in drift.items() if variant == "integrals-in-V" or not k.startswith("chaplygin_")}
    assert max(in_V.values()) < 1e-12, drift
    assert {"chaplygin_1", "chaplygin_2"} <= set(drift)
    assert max(data["max_error"].values()) < 1e-6, data["max_error"]


# ``python -m liefi bench rolling-disk --quick --t-final 1``: tests/test_rolling_tools.py (ROLLING)
