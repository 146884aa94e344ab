"""A step choice that costs less than the run and lands the error within the tolerance (issue 26).

Before, a run of fewer than 256 steps was not checked and ran at the local error model's step, an upper bound
that left the achieved error 1e-4 to 4e-2 of ``rtol`` (Suslov over ``[0, 20]`` at ``1e-6``: 1.5e-9); the
check's runs went through :meth:`liefi.FeedbackIntegrator.run`, each paying a user's run's set-up (gains,
exact invariants, guard, audit).  Now a short run is checked too on a compiled backend, its runs are single
calls of the compiled loop (:class:`liefi.integrator._check_runs.CheckRuns`), and the step between the
check's two finer steps is interpolated by the measured order.
"""

import warnings

import numpy as np
import pytest

from liefi import scenes
from liefi import FeedbackIntegrator
from liefi.integrator import tolerance as tol
from liefi.integrator._check_runs import CheckRuns
from liefi.schemes.registry import REGISTRY


@pytest.fixture(autouse=True)
def _no_store(monkeypatch):
    monkeypatch.setenv("LIEFI_REFERENCE_STORE", "0")


def _relative_error(r):
    """The largest over the compared components of ``max_t |y - y_ref| / max_t |y_ref|`` (the scene's reference)."""
    return max(r.max_error[k] / max(np.max(np.abs(r[k] - r.errors[k])), 1e-300) for k in r.max_error)


@pytest.mark.parametrize("name, rtol", [("suslov", 1e-6), ("kepler", 1e-8)])
def test_a_short_run_lands_its_error_within_the_tolerance(name, rtol):
    """Suslov at ``1e-6`` (24 steps; before 55, error 1.5e-3 ``rtol``) and Kepler at ``1e-8`` (46 steps; before
    118 at 5e-5 ``rtol``; extrapolated by the order alone 36 steps at 3.6 ``rtol``, the error falling like
    ``h^10`` there) over ``[0, 20]``: the achieved error against the scene's independent reference is in
    ``[rtol/30, rtol]`` and the step is the check's."""
    sc = scenes.get(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = sc.run(t_final=20.0, rtol=rtol, backend="auto")
    rel = _relative_error(r)
    assert rtol / 30 <= rel <= rtol, (name, rel / rtol, r.scheme, r.steps)
    assert "local error model alone" not in r.method["why"]


def test_the_checks_runs_pay_no_runs_set_up(monkeypatch):
    """Choosing the step for Kepler over ``[0, 200]`` (checked before too) calls
    :meth:`~liefi.FeedbackIntegrator.run` not once on a compiled backend (before: three runs or more, each
    choosing its gains, the invariants the scheme keeps and its guard)."""
    sc = scenes.get("kepler")
    fi = sc.integrator(sc.variant(None), gains="auto")
    calls = []
    orig = FeedbackIntegrator.run
    monkeypatch.setattr(FeedbackIntegrator, "run", lambda self, *a, **k: calls.append(k) or orig(self, *a, **k))
    dt, info = tol.choose_step(fi, REGISTRY["imex-rk4"], fi.y0, 0.0, 200.0, 1e-6, choose_order=True, backend="auto")
    assert info["check_step"] is not None and info["check_trusted"], info
    assert calls == []


def test_a_check_run_is_the_runs_own_and_is_made_once(monkeypatch):
    """At its first step a run of :class:`CheckRuns` is bit for bit the scheme's run through
    :meth:`~liefi.FeedbackIntegrator.run` (same gains, same invariants left out); asked again (a coarser
    saving, as the check's next try asks), it is not run again."""
    sc = scenes.get("suslov")
    fi = sc.integrator(sc.variant(None), gains="auto")
    sch = REGISTRY["imex-rk8"]
    T, h = 20.0, 20.0 / 64
    runs = CheckRuns(fi, sch, fi.y0, "auto")
    ys = runs(0.0, T, h, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = fi.run((0.0, T), dt=h, scheme=sch, save_every=1, progress=False, check_stability=False,
                     backend="auto", drop_exact=True)
    np.testing.assert_array_equal(ys, np.moveaxis(np.asarray(ref.y), -1, 0))
    cf = runs._set[1]
    made = []
    monkeypatch.setattr(type(cf), "run", lambda *a, **k: made.append(1))
    np.testing.assert_array_equal(runs(0.0, T, h, 4), ys[::4])
    assert made == []


def test_the_measured_order_is_at_least_the_schemes():
    """``log2(E_1 / E)``, the growth of the measured error from the check's step to twice it, where it is steeper
    than ``2^p``; ``p`` otherwise (or without the coarse run's error)."""
    assert tol.measured_order((1.0, 0, 0, 0, True, True, 0, 0, 2.0 ** 10), 8) == pytest.approx(10.0)
    assert tol.measured_order((1.0, 0, 0, 0, True, True, 0, 0, 2.0 ** 5), 8) == 8.0
    assert tol.measured_order((1.0, 0, 0, 0, True, True, 0, 0), 8) == 8.0


def test_scene_run_fi_run_and_the_cli_choose_the_same_on_the_compiled_backend(capsys):
    """The short run now checked on the compiled backend (Suslov over ``[0, 20]`` at ``1e-6``) gets the same scheme
    and step whichever way it is asked: ``Scene.run``, ``fi.run`` and ``liefi run``."""
    import json

    from liefi.cli import main

    sc = scenes.get("suslov")
    sc.__dict__.pop("_stepcache", None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = sc.run(t_final=20.0, rtol=1e-6, backend="auto")
        sol = sc.integrator(sc.variant(), gains="auto").run(20.0, rtol=1e-6, backend="auto", progress=False)
    sc.__dict__.pop("_stepcache", None)
    assert main(["run", "suslov", "--rtol", "1e-6", "--t-final", "20", "--backend", "auto", "--json"]) in (0, None)
    cli = json.loads(capsys.readouterr().out)["method"]
    assert r.method["scheme"] == sol.method["scheme"] == cli["scheme"]
    assert r.method["dt"] == sol.method["dt"] == cli["dt"]
    assert "checked by two short runs" in cli["why"]


def test_the_invariants_are_evaluated_only_where_the_drift_rule_needs_them(monkeypatch):
    """Perturbed Kepler over ``[0, 50]`` at ``1e-6``: the check's first try is untrusted and repeated, then a longer
    step is run and measured.  The invariants are evaluated at the runs the step depends on only: the last try's
    coarse run, the shorter run beside a drift only where the drift is above rounding (the cap is ``inf`` whatever
    that floor), and their scales at the start once (every run starts there).  Before: both runs of every try and
    of every candidate (6 drifts, 12 evaluations of the scales); the step is the same."""
    from liefi.integrator import drift as _drift, tolerance_check

    sc = scenes.get("perturbed-kepler")
    fi = sc.integrator(sc.variant(None), gains="auto")
    calls = {"drift": 0, "scales": 0, "check": 0}

    def counted(name, f):
        def g(*a, **k):
            calls[name] += 1
            return f(*a, **k)
        return g

    monkeypatch.setattr(_drift, "drift", counted("drift", _drift.drift))
    monkeypatch.setattr(_drift, "drift_scales", counted("scales", _drift.drift_scales))
    monkeypatch.setattr(tolerance_check, "_global_check", counted("check", tolerance_check._global_check))
    dt, info = tol.choose_step(fi, REGISTRY["imex-rk4"], fi.y0, 0.0, 50.0, 1e-6, choose_order=True, backend="auto")
    assert calls["check"] == 2 and info["check_trusted"] and info["verified_step"] is not None, (calls, info)
    # one drift for the last try's coarse run (at rounding: no floor), one or two for the longer step's runs
    assert calls["drift"] <= 3, calls
    assert calls["scales"] <= calls["drift"] + 1, calls  # each drift's own, and the start's once
    assert info["check_drift"] <= tol.DRIFT_LEVEL


def test_the_checks_set_up_finds_the_exactly_kept_invariants_once(monkeypatch):
    """:class:`CheckRuns`' set-up asks :func:`liefi.integrator.gains.exactly_kept` once, for the invariants left
    out and for the gains of the others (before: twice, 2--9 ms each on the rolling bodies), and its gains are
    those of :func:`~liefi.integrator.gains.run_gains` on its own."""
    from liefi.integrator import gains

    sc = scenes.get("suslov")
    fi = sc.integrator(sc.variant(None), gains="auto")
    sch = REGISTRY["imex-rk8"]
    made = []
    orig = gains.exactly_kept
    monkeypatch.setattr(gains, "exactly_kept", lambda *a, **k: made.append(1) or orig(*a, **k))
    runs = CheckRuns(fi, sch, fi.y0, "auto")
    runs(0.0, 20.0, 20.0 / 64, 1)
    assert len(made) == 1
    monkeypatch.setattr(gains, "exactly_kept", orig)
    run_fi = runs._set[0]
    drops = gains.exact_drops(fi.for_batch(()), sch, fi.y0)
    base = fi.for_batch(()).without(drops) if drops else fi.for_batch(())
    ref = gains.run_gains(base, fi.y0, 20.0 / 64, sch, 20.0).fi
    assert run_fi.gains == ref.gains and run_fi.invariant_names == ref.invariant_names
