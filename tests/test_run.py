"""The run module (:mod:`liefi.run`), its guard and the guards of the other paths (issues 9 and 10)."""

from __future__ import annotations

import pickle
import warnings

import numpy as np
import pytest

import liefi
from liefi import scenes
from liefi import stability as S
from liefi.feedback import FeedbackIntegrator, parse_gains
from liefi.schemes import IntegrationError, steps_for


@pytest.fixture(scope="module")
def suslov():
    return scenes.get("suslov")


# --- one validator ----------------------------------------------------------------------------


def test_dt_not_dividing_t_final_shortens_the_last_step(suslov):
    fi = suslov.integrator()
    sol = fi.run(0.01, dt=0.003, backend="numpy")  # 3 steps of 0.003, then one of 0.001
    assert sol.steps == 4 and sol.t[-1] == 0.01 and sol.method["last_step"] == pytest.approx(0.001)
    assert "shortened to 0.001" in sol.method["why"]
    # the validator itself still refuses it (liefi bench's grids), naming the nearest dt
    with pytest.raises(ValueError, match=r"dt: 0.003 does not divide t_final = 10.*nearest step.*dt = 0\.0030003.*\(3333 steps\)"):
        steps_for(0.003, 10.0)
    assert steps_for(0.25, 10.0)[2] == 40


@pytest.mark.parametrize("kw, word", [({"dt": True}, "dt"), ({"dt": -1}, "dt"), ({"t_final": np.nan}, "t_span"),
                                      ({"save_every": 0}, "save_every"), ({"check_every": 1.5}, "check_every"),
                                      ({"save_every": True}, "save_every")])
def test_run_arguments_are_validated_once(suslov, kw, word):
    args = {"dt": 1e-3, "t_final": 0.01, **kw}
    with pytest.raises(ValueError, match=f"^{word}: "):
        suslov.integrator().run(args.pop("t_final"), dt=args.pop("dt"), **args)


# --- saving, plan, progress, overhead -------------------------------------------------------------


def test_saving_is_capped_by_default_and_refused_past_memory(suslov, monkeypatch):
    import liefi.run as R

    fi = suslov.integrator()
    monkeypatch.setattr(R, "DEFAULT_SAVE_BYTES", 8 * fi.n * 101)  # room for 101 states
    sol = fi.run(1.0, dt=1e-3)
    assert sol.plan.save_every == 10 and sol.t.size == 101 and sol.t[-1] == pytest.approx(1.0)
    assert sol.plan.saved_bytes <= R.DEFAULT_SAVE_BYTES
    monkeypatch.setattr(R, "available_memory", lambda: 2 * 8 * fi.n * 50)
    with pytest.raises(ValueError, match="save_every: saving every 1 step.*take save_every >= 21"):
        fi.run(1.0, dt=1e-3, save_every=1)


def test_run_reports_cpu_and_overhead_apart(suslov):
    sol = suslov.integrator().run(0.5, dt=1e-3, scheme="euler", backend="numpy")
    assert sol.cpu_seconds > 0 and sol.overhead_seconds >= 0
    assert sol.plan.n_steps == 500 and np.isfinite(sol.plan.expected_seconds)


def test_progress_on_stderr_when_asked(suslov, capsys):
    suslov.integrator().run(0.5, dt=1e-3, progress=True, check_stability=False)
    assert "500" in capsys.readouterr().err
    suslov.integrator().run(0.5, dt=1e-3)  # short, not a TTY: quiet
    assert capsys.readouterr().err == ""


def test_ensemble_guard_cost_does_not_grow_with_the_batch(suslov, monkeypatch):
    """The pre-run pilot follows a few members of a batch, not all of them."""
    seen = []
    real = S.pilot

    def spy(fi, y0, t_final, **kw):
        seen.append(np.shape(y0))
        return real(fi, y0, t_final, **kw)

    monkeypatch.setattr(S, "pilot", spy)
    fi = suslov.integrator()
    y0 = np.repeat(fi.y0[None], 500, axis=0)
    fi.run(0.2, dt=1e-3, y0=y0, scheme="euler", backend="numpy")  # an explicit scheme: the guard's pilot
    assert seen and all(np.prod(s[:-1]) <= S.PILOT_MEMBERS for s in seen)


# --- guards on every path -------------------------------------------------------------------------


def test_explicit_scipy_method_on_a_stiff_field_is_refused_up_front(suslov):
    with pytest.raises(ValueError, match="scipy:RK45 is explicit.*scipy:LSODA.*scipy:BDF"):
        suslov.run(scheme="scipy:RK45", gains=1e7, t_final=1.0)


def test_dla_drift_guard():
    osc = scenes.get("oscillator")
    with pytest.raises(S.StabilityError, match="dla run became meaningless"):
        osc.run(scheme="dla", dt=5.0, t_final=500.0)
    r = osc.run(scheme="dla", dt=1e-2, t_final=20.0)
    assert max(r.max_drift.values()) < 5e-2


def test_imex_at_a_gain_past_one_over_eps_is_the_projection():
    """``dt k |a|^2 >> 1/eps``: the old ``n x n`` solve of ``I + dt k a a^T`` was singular in floating point;
    through the ``1 x 1`` Gram matrix the step is ``k r / (1 + dt k |a|^2)``: the projection onto ``a.y = 1``."""
    sysm = liefi.NonholonomicSystem(liefi.CotangentBundle(1), np.eye(1))
    a = np.array([1.0, 1.0])
    inv = liefi.Invariant("a.y", lambda z: z[..., 0] + z[..., 1], lambda z: np.broadcast_to(a, np.shape(z)))
    fi = FeedbackIntegrator(sysm, np.array([0.0, 1.0]), invariants=(inv,), gains=1e18)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = fi.run(1.0, dt=1e-1, scheme="imex-euler")
    assert np.all(np.isfinite(sol.y))
    assert np.max(np.abs(sol.y[0] + sol.y[1] - 1.0)) < 1e-14


def test_drift_of_huge_momenta_is_a_number(suslov):
    fi = suslov.integrator()
    y = fi.y0.copy()
    y[fi.nc:] *= 1e200
    with np.errstate(all="ignore"):
        d, who = S.drift(fi, y, S.drift_scales(fi))
    assert not d <= 1.0  # huge or inf, but no exception


def test_metric_turning_indefinite_is_named(monkeypatch):
    from liefi.guard import metric_defect

    sysm = liefi.NonholonomicSystem(liefi.CotangentBundle(1), lambda x: (1.0 - x[..., 0:1, None] ** 2))
    fi = FeedbackIntegrator(sysm, np.array([0.0, 1.0]), gains=1.0)
    assert metric_defect(fi, np.array([0.0, 1.0])) == ""
    assert "metric is not positive definite" in metric_defect(fi, np.array([2.0, 1.0]))


def test_a_metric_degenerating_at_a_gimbal_lock_names_its_null_direction_and_what_to_do():
    """Euler-angle-like coordinates: ``g = diag(1, cos(lean)^2)`` loses rank along ``yaw`` at ``lean = pi/2`` (as
    sympy's ``test_kane.py::test_aux`` disc, whose fixed-step run failed there with "check the metric's data")."""
    from liefi.guard import metric_defect

    def metric(x):
        one, c2 = np.ones_like(x[..., 0]), np.cos(x[..., 0]) ** 2
        return np.stack([np.stack([one, 0 * one], -1), np.stack([0 * one, c2], -1)], -2)

    sysm = liefi.NonholonomicSystem(liefi.CotangentBundle(2, names=("lean", "yaw")), metric)
    fi = FeedbackIntegrator(sysm, np.array([0.0, 0.0, 1.0, 1.0]), gains=1.0)
    assert metric_defect(fi, np.array([0.3, 0.0, 1.0, 1.0])) == ""
    msg = metric_defect(fi, np.array([1.5, 0.0, 1.0, 1.0]))
    assert "degenerates" in msg and "loses rank along +1 yaw" in msg.replace("-1 yaw", "+1 yaw")
    assert "lean" not in msg.split("loses rank along")[1].split("(")[0]
    assert "choose coordinates regular there" in msg and "smaller dt" in msg


def test_errors_pickle():
    for e in (IntegrationError("m", 1.0, 2, np.ones(2), ["x"]), S.StabilityError("s", 3.0, 4, None, ["J_1"])):
        e2 = pickle.loads(pickle.dumps(e))
        assert (type(e2), str(e2), e2.t, e2.step, e2.components) == (type(e), str(e), e.t, e.step, e.components)


# --- gains and targets ----------------------------------------------------------------------------


@pytest.mark.parametrize("gains", [True, np.bool_(False), {"J_1": True, "energy": 1.0}])
def test_bool_is_not_a_gain(suslov, gains):
    with pytest.raises(ValueError, match="^gains: .*bool"):
        suslov.integrator(gains=gains)


@pytest.mark.parametrize("target", ["high", np.nan, np.inf, [1.0, 2.0], True])
def test_bad_targets_are_named(suslov, target):
    with pytest.raises(ValueError, match="^targets: the target of 'energy'"):
        FeedbackIntegrator(suslov.system, suslov.integrator().y0, configuration=False, targets={"energy": target})


def test_one_gain_parser_for_cli_and_api():
    names = ("J_1", "energy")
    assert parse_gains("7", names) == {"J_1": 7.0, "energy": 7.0}
    assert parse_gains("7,9", names) == {"J_1": 7.0, "energy": 9.0}
    assert parse_gains("energy=9", names, defaults={"J_1": 1.0, "energy": 2.0}) == {"J_1": 1.0, "energy": 9.0}
    assert parse_gains({"constraints": 3, "energy": 4}, names) == {"J_1": 3.0, "energy": 4.0}
    assert parse_gains("auto", names) == "auto"
    for bad in ("1,2,3", "abc", "k9=1", "-1", "1,", "energy=1,2"):
        with pytest.raises(ValueError, match="^gains: "):
            parse_gains(bad, names)
    import inspect

    import liefi.cli

    assert "parse_gains as _parse" in inspect.getsource(liefi.cli.parse_gains)


def test_blow_up_from_an_indefinite_metric_is_not_blamed_on_the_gains():
    """m(x) = 1 - x^2 turns indefinite at |x| = 1: the failure names the metric."""
    sysm = liefi.NonholonomicSystem(liefi.CotangentBundle(1), lambda x: (1.0 - x[..., 0:1, None] ** 2),
                                    sample=[0.0])
    fi = FeedbackIntegrator(sysm, np.array([0.0, 1.0]), gains=1.0)
    with pytest.raises((IntegrationError, ValueError)) as exc:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fi.run(5.0, dt=1e-3, scheme="euler", backend="numpy")
    assert "metric" in str(exc.value)


def test_progress_falls_back_to_a_plain_line_without_tqdm(suslov, capsys, monkeypatch):
    import builtins

    real = builtins.__import__

    def no_tqdm(name, *a, **kw):
        if name == "tqdm":
            raise ImportError("no tqdm")
        return real(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", no_tqdm)
    suslov.integrator().run(0.5, dt=1e-3, progress=True, check_stability=False)
    err = capsys.readouterr().err
    assert "500/500 steps" in err


# --- layout -------------------------------------------------------------------------------------

MINE = ("integrator", "schemes", "engine", "experiments")


def _import_graph():
    import ast
    import pathlib

    root = pathlib.Path(liefi.__file__).parent
    edges = {}
    for p in root.rglob("*.py"):
        rel = p.relative_to(root.parent).with_suffix("").parts
        mod = ".".join(rel[:-1] if rel[-1] == "__init__" else rel)
        pkg = mod if rel[-1] == "__init__" else mod.rsplit(".", 1)[0]
        unit = mod.split(".")[1] if "." in mod else None
        for n in ast.walk(ast.parse(p.read_text())):  # lazy imports included
            if isinstance(n, ast.ImportFrom) and n.level:
                base = ".".join(pkg.split(".")[: len(pkg.split(".")) - (n.level - 1)])
                targets = [base + "." + n.module] if n.module else [base + "." + a.name for a in n.names]
            elif isinstance(n, ast.ImportFrom):
                targets = [n.module or ""]
            elif isinstance(n, ast.Import):
                targets = [a.name for a in n.names]
            else:
                continue
            for t in targets:
                if t.startswith("liefi.") and unit and t.split(".")[1] != unit:
                    edges.setdefault(unit, set()).add(t.split(".")[1])
    return edges


def test_no_import_cycle_through_the_run_machinery():
    """integrator (feedback -> run -> guard -> stability) -> engine -> schemes, experiments on top: no cycle, lazy
    imports included."""
    edges = _import_graph()

    def reach(a):
        seen, todo = set(), [a]
        while todo:
            for b in edges.get(todo.pop(), ()):
                if b not in seen:
                    seen.add(b)
                    todo.append(b)
        return seen

    for u in MINE:
        assert u not in reach(u), f"{u} is on an import cycle"
    assert "scenes" not in reach("integrator") and "integrator" not in reach("schemes")


def test_modules_of_the_run_machinery_stay_under_800_lines():
    import pathlib

    root = pathlib.Path(liefi.__file__).parent
    files = list((root / "integrator").glob("*.py"))
    files += list((root / "schemes").glob("*.py")) + list((root / "experiments").glob("*.py"))
    long = {f.name: n for f in files if (n := len(f.read_text().splitlines())) > 800}
    assert not long


# --- one resolution of the scheme per run (issue 24) ----------------------------------------------


@pytest.mark.parametrize("kw", [{}, {"dt": 0.01}, {"dt": 0.01, "scheme": "rk4"}, {"dt": 0.01, "scheme": "rk4", "adaptive": True},
                                {"dt": 0.01, "method": "RK4"},
                                {"t_span": 4.0, "scheme": "rk4", "rtol": 1e-9, "dense_output": True, "t_eval": [0.5, 3.9]}],
                         ids=["rtol-order-chosen", "dt", "rk4", "rk4-adaptive", "method", "rtol-checked-guard-dense"])
def test_the_run_loop_looks_its_scheme_up_by_name_once(suslov, kw, monkeypatch):
    """The run loop resolves the scheme once and hands the object down: no module below it -- policy,
    tolerance (the order chosen for a tolerance, the runs of its global check), gains, guard, stability, dense
    output, the numpy loop, the compiled engine -- enters the registry again, by name or with the object."""
    import sys

    from liefi import schemes
    from liefi.schemes import registry

    get, get_scheme, calls = registry.get, schemes.get_scheme, []

    def counted(name, kind=None):
        calls.append((sys._getframe(1).f_globals["__name__"], name if isinstance(name, str) else "an object"))
        return get(name, kind)

    def counted_scheme(scheme):
        calls.append((sys._getframe(1).f_globals["__name__"], "get_scheme"))
        return get_scheme(scheme)

    fi = suslov.integrator(gains="auto")
    kw = dict(kw)
    t_span = kw.pop("t_span", 0.5)
    monkeypatch.setattr(registry, "get", counted)
    monkeypatch.setattr(schemes, "get_scheme", counted_scheme)
    sol = fi.run(t_span, backend="numpy", **kw)
    assert sol.success
    if "rtol" in kw:  # the tolerance's global check ran (its runs are runs of the same scheme object)
        assert sol.method["why"].count("checked by two short runs"), sol.method["why"]
        assert sol.t.tolist() == kw["t_eval"] and sol.sol is not None and sol.stability is not None
    assert calls == [("liefi.integrator.run", kw.get("method", kw.get("scheme", "imex-rk4")))], calls
