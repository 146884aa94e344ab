"""What set a step chosen for a tolerance is named in ``method["why"]`` (issue 26).

A run too short to be checked (fewer than ``CHECK_MIN_STEPS`` steps) runs at the local error model's step,
an upper bound that can leave the achieved error far below ``rtol`` (Kepler over ``[0, 20]`` at ``1e-6``:
66 steps of ``imex-rk8``, error 1e-10, 1e-4 ``rtol``); the run says so instead of leaving the user to guess.
"""

import warnings

import pytest

from liefi import scenes
from liefi.integrator import tolerance as tol


@pytest.fixture(autouse=True)
def _no_store(monkeypatch):
    monkeypatch.setenv("LIEFI_REFERENCE_STORE", "0")


def _run(name, T, rtol):
    sc = scenes.get(name)
    fi = sc.integrator(sc.variant(), gains="auto")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fi.run(T, rtol=rtol, backend="numpy")


def test_an_unchecked_short_run_names_the_local_model_as_what_set_its_step():
    sol = _run("kepler", 20.0, 1e-6)
    n = round(20.0 / sol.method["dt"])
    assert n < tol.CHECK_MIN_STEPS
    assert "the step is set by the local error model alone" in sol.method["why"]
    assert f"{n} steps, fewer than {tol.CHECK_MIN_STEPS}" in sol.method["why"]


def test_a_checked_run_names_the_measurement():
    sol = _run("kepler", 200.0, 1e-6)
    assert round(200.0 / sol.method["dt"]) >= tol.CHECK_MIN_STEPS
    why = sol.method["why"]
    assert "the step is set by" in why and "local error model alone" not in why
    assert any(s in why for s in ("measured", "longer step run", "drift rule", "resolution limit", "conservative"))


def test_the_binding_names_the_shortest_bound():
    b = tol._binding(None, None, False, 1.0, 0.5, 0.5, 1.0, float("inf"), 10.0, 0.5)
    assert "resolution limit" in b
    b = tol._binding(None, None, False, 1.0, 1.0, 0.4, 1.0, float("inf"), 10.0, 0.4)
    assert "stability" in b
