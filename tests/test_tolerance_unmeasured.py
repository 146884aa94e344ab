"""A step chosen for a tolerance whose global error could not be measured says so (LiefiToleranceWarning)."""

import warnings

import pytest

from liefi import scenes
from liefi import tolerance as tol


def _run(monkeypatch, fail):
    if fail:  # the check's coarse runs diverge (as on the rattleback over [0, 1000])
        from liefi.integrator import tolerance_check

        monkeypatch.setattr(tolerance_check, "_global_check", lambda *a, **k: None)
    sc = scenes.get("chaplygin-so2")
    fi = sc.integrator(sc.variant(None), gains="auto")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        sol = fi.run(300.0, rtol=1e-6, progress=False)
    return sol, [w for w in seen if issubclass(w.category, tol.LiefiToleranceWarning)]


def test_a_failed_check_warns_and_the_run_says_why(monkeypatch):
    sol, seen = _run(monkeypatch, fail=True)
    assert len(seen) == 1, [str(w.message) for w in seen]
    msg = str(seen[0].message)
    assert "rtol=1e-06" in msg and "could not be measured" in msg and "dt/2" in msg
    assert seen[0].filename == __file__  # at the caller's line
    assert "not measured" in sol.method["why"]


def test_a_measured_step_does_not_warn(monkeypatch):
    sol, seen = _run(monkeypatch, fail=False)
    assert not seen
    assert "not measured" not in sol.method["why"]
