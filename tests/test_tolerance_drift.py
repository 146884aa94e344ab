"""The invariants at rounding whatever the tolerance (liefi.tolerance: the drift of the measured runs)."""

import math

import numpy as np

from liefi import scenes
from liefi import tolerance as tol


def test_a_loose_tolerance_keeps_the_invariants_at_rounding():
    """The Chaplygin sleigh on SO(2) at rtol = 1e-4 over [0, 300]: the longest step within the tolerance
    (2.42, ``dt omega`` 2.4) leaves the tableau a per-step defect of the invariants ``e ~ 1e-4``, and the one
    Gauss--Newton step of the split scheme ``~0.5 e^2 = 5e-9`` of it.  The candidate runs report their drift
    and such a step is refused: the run's drift is at rounding, its error still within the tolerance, and its
    step still longer than the check's coarse step (measured, not capped there)."""
    sc = scenes.get("chaplygin-so2")
    rtol = 1e-4
    dt, info = sc.step_for_tolerance(sc.variant(None), "imex-rk4", 300.0, rtol, gains="auto", choose_order=True)
    assert info["verified_step"] is not None and dt > 2 * info["check_step"] * (1 + 1e-9), info
    r = sc.run(scheme="imex-rk4", gains="auto", t_final=300.0, rtol=rtol, choose_order=True)
    assert r.dt == dt
    assert max(r.max_drift.values()) <= tol.DRIFT_LEVEL, r.max_drift  # 5e-9 before
    sizes = {k: np.max(np.abs(r[k] - r.errors[k])) if k in r.names else 1.0 for k in r.max_error}
    rel = max(r.max_error[k] / sizes[k] for k in r.max_error if sizes[k] > 0)
    assert rel <= 10 * rtol, (rel, r.dt)


def test_the_drift_cap_follows_the_gauss_newton_residual():
    """``_drift_cap``: no cap at rounding (below the level, or a floor a shorter step does not lower); above it
    the step at which ``K e^2 ~ dt^{2(p+1)}`` falls to the level."""
    L, p = tol.DRIFT_LEVEL, 8
    assert 1e-13 < L < 1e-11
    assert tol._drift_cap(1.0, L / 2, 0.0, p) == math.inf
    assert tol._drift_cap(1.0, 10 * L, 5 * L, p) == math.inf  # the shorter run drifts as much: rounding's floor
    cap = tol._drift_cap(2.0, 1e6 * L, 1e-3 * L, p)
    assert math.isclose(cap, 2.0 * (tol.DRIFT_AIM * 1e-6) ** (1 / 18), rel_tol=1e-12)
    assert tol._drift_cap(1.0, math.inf, 0.0, p) == 0.0
