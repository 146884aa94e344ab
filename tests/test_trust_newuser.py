"""What a new user trips on (issue 23): solve_ivp's keywords, misspelt keywords, the first compile's silence,
the documented default, and the time-left estimate of a sweep of unequal tasks."""

import json
import os
import re

import numpy as np
import pytest

import liefi
from liefi import scenes


@pytest.fixture(scope="module")
def knife():
    sc = scenes.get("knife-edge")
    return sc, sc.integrator(gains=1.0)


# --- solve_ivp's keywords and misspellings ----------------------------------------------------------------------


def test_max_step_caps_the_step_chosen_for_the_tolerance(knife):
    _, fi = knife
    free = fi.run(1.0, scheme="rk4", backend="numpy")
    capped = fi.run(1.0, scheme="rk4", backend="numpy", max_step=free.dt / 3)
    assert capped.dt <= free.dt / 3 * (1 + 1e-12) and capped.steps * capped.dt == pytest.approx(1.0)
    assert fi.run(1.0, dt=1e-2, scheme="rk4", backend="numpy", max_step=np.inf).dt == 1e-2
    with pytest.raises(ValueError, match=r"^max_step: the given dt = 0.1 is larger than max_step = 0.05"):
        fi.run(1.0, dt=0.1, max_step=0.05)
    with pytest.raises(ValueError, match=r"^max_step: "):
        fi.run(1.0, max_step=-1.0)


def test_method_is_solve_ivps_name_for_scheme(knife):
    _, fi = knife
    a = fi.run(0.5, dt=1e-2, method="RK4", backend="numpy")
    b = fi.run(0.5, dt=1e-2, scheme="rk4", backend="numpy")
    assert a.method["scheme"] == "rk4"
    np.testing.assert_array_equal(a.y, b.y)
    with pytest.raises(ValueError, match=r"^method: 'RK45' is solve_ivp's adaptive method.*scheme='scipy:RK45'"):
        fi.run(0.5, method="RK45")
    with pytest.raises(TypeError, match="not both"):
        fi.run(0.5, method="rk4", scheme="rk4")


@pytest.mark.parametrize("kw, words", [({"first_step": 0.1}, "one fixed step"), ({"args": (1.0,)}, "constants"),
                                       ({"t_final": 1.0}, "retired")])
def test_solve_ivp_keywords_without_a_meaning_here_are_named(knife, kw, words):
    _, fi = knife
    name = next(iter(kw))
    with pytest.raises(TypeError, match=f"^{name}: run\\(\\) does not take {name}=; .*{words}"):
        fi.run(1.0, **kw)


def test_misspelt_keywords_get_did_you_mean(knife):
    sc, fi = knife
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'sheme'; did you mean 'scheme'\?"):
        fi.run(1.0, sheme="rk4")
    with pytest.raises(TypeError, match=r"^FeedbackIntegrator\(\) got .* 'gain'; did you mean 'gains'\?"):
        liefi.FeedbackIntegrator(sc.system, fi.y0, gain=1.0)
    with pytest.raises(TypeError, match=r"'t_finl'; did you mean 't_final'\?"):
        sc.run(t_finl=1.0)
    with pytest.raises(TypeError, match=r"^method: run\(\) does not take method=; .*scheme='scipy:RK45'"):
        sc.run(method="RK45")
    with pytest.raises(TypeError, match=r"'zzz'; the keywords are .*scheme"):
        fi.run(1.0, zzz=1)


def test_the_entry_points_keep_their_signatures_and_warnings_point_at_the_caller(knife):
    """The unknown keywords are caught inside the functions (**unknown, hidden): no wrapper frame."""
    import inspect
    import warnings

    from liefi.stability import LiefiStabilityWarning

    sc, _ = knife
    for f in (liefi.FeedbackIntegrator.run, liefi.FeedbackIntegrator, sc.run):
        assert "unknown" not in str(inspect.signature(f))
    assert "scheme" in str(inspect.signature(liefi.FeedbackIntegrator.run))
    fi = sc.integrator(gains=1e3)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        fi.run(0.02, dt=1e-2, scheme="rk4", backend="numpy", errors="return")
    stab = [w for w in seen if issubclass(w.category, LiefiStabilityWarning)]
    # outside liefi (a wrapper would have put it at its own line); which caller frame is the guard's own matter
    assert stab and not stab[0].filename.startswith(os.path.dirname(liefi.__file__))


# --- the documented default --------------------------------------------------------------------------------------


def _schemes_named(text):
    return set(re.findall(r"imex-rk\d", text))


def test_the_documented_default_is_what_a_default_run_reports(knife, capsys):
    """--help, the run docstring and the CLI's description name the schemes a default run uses (sol.method)."""
    from liefi import cli
    from liefi.tolerance import ORDER_CANDIDATES

    _, fi = knife
    ran = {fi.run(10.0, backend="numpy").method["scheme"]}  # imex-rk8 on the knife edge
    assert cli.main(["run", "knife-edge", "--json", "--t-final", "10", "--backend", "numpy"]) in (0, None)
    ran.add(json.loads(capsys.readouterr().out)["method"]["scheme"])
    assert fi.run(1.0, dt=1e-2, backend="numpy").method["scheme"] == "imex-rk4"  # with a given dt

    run_parser = cli.build_parser()._subparsers._group_actions[0].choices["run"]
    scheme_help = next(a.help for a in run_parser._actions if "--scheme" in a.option_strings)
    doc = liefi.FeedbackIntegrator.run.__doc__
    texts = {
        "--scheme help": scheme_help.split("default:", 1)[1],
        "run --help": run_parser.description,
        "the run docstring": doc[doc.index("The default method"):].split("\n\n")[0],
        "the cli module": cli.__doc__[cli.__doc__.index("``liefi run`` runs"):].split("\n\n")[0],
    }
    for where, text in texts.items():
        named = _schemes_named(text)
        assert ran <= named, f"{where} names {named} as the default; a default run used {ran}"
        assert named == set(ORDER_CANDIDATES["split"]), where


# --- the time left of a sweep of unequal tasks -------------------------------------------------------------------


class _Clock:
    """A fake clock for both time.monotonic (the progress line) and time.perf_counter (the sweep's task times)."""

    def __init__(self):
        self.now = 0.0

    def monotonic(self):
        return self.now

    perf_counter = monotonic


def _cheap_then_costly(prior_b):
    """20 cheap tasks (1 s) first, then 10 costly ones (30 s): ``(tasks, expected)`` with the prior of a costly
    one ``prior_b`` (30: exact; 10: three times too low)."""
    tasks = [{"kind": "a", "seconds": 1.0}] * 20 + [{"kind": "b", "seconds": 30.0}] * 10
    return tasks, lambda t: (t["kind"], 1.0 if t["kind"] == "a" else prior_b)


@pytest.mark.parametrize("prior_b", [30.0, 10.0])
def test_sweep_time_left_is_weighted_by_the_cost_of_the_tasks_left(monkeypatch, prior_b):
    """At 31 % of a sweep whose costly tasks come last the time left is not the count's (21 s for 311 s)."""
    from liefi import _progress, sweep

    clock = _Clock()
    monkeypatch.setattr(_progress, "time", clock)
    monkeypatch.setattr(sweep, "time", clock)
    tasks, expected = _cheap_then_costly(prior_b)
    seen = []
    update = _progress.Progress.update

    def spy(self, *a, **kw):
        update(self, *a, **kw)
        seen.append((self.done, self.status(), self.time_left()))

    monkeypatch.setattr(_progress.Progress, "update", spy)

    def fn(task):
        clock.now += task["seconds"]
        return task["seconds"]

    assert sweep.run_sweep(fn, tasks, expected=expected, progress=False) == [t["seconds"] for t in tasks]
    truth = {i + 1: sum(t["seconds"] for t in tasks[i + 1:]) for i in range(len(tasks))}
    done, line, (left, unseen) = seen[8]  # 9 of 30 done: 30 %, the costly tasks all to come
    assert truth[done] == 311.0 and "(30 %)" in line
    if prior_b == 30.0:  # an exact prior: the estimate is the truth
        assert left == pytest.approx(truth[done]) and unseen == 10
        assert all(x[2][0] == pytest.approx(truth[x[0]]) for x in seen[:-1])
    else:  # a prior three times too low: said to be a guess until a costly task has finished ...
        assert left == pytest.approx(111.0) and "a guess: 10 tasks of kinds not timed yet" in line
        # ... then learned from it
        assert all(x[2][0] == pytest.approx(truth[x[0]]) and "guess" not in x[1] for x in seen[20:-1])
    # the count alone would have said 21 s left at 30 %, as it said "about 3 min left" of 17
    count = _progress.Progress(30, "sweep", False, unit="task")
    count._start, count.done = 0.0, 9
    clock.now = 9.0
    assert "about 21 s left" in count.status()


def test_bench_tasks_have_a_prior_and_tight_tolerances_cost_more():
    from liefi.bench import core

    tasks = core.build_tasks("suslov", 100.0, quick=True)
    got = [core.expected_seconds(t) for t in tasks]
    assert all(s > 0 and np.isfinite(s) for _, s in got)
    by = {(t["method"], t["scheme"], t["dt"], t["rtol"]): s for t, (_, s) in zip(tasks, got)}
    fi = sorted((dt, s) for (m, sch, dt, _), s in by.items() if m == "FI" and sch == "rk4")
    assert fi[0][1] > fi[-1][1]  # the finest step costs the most
    ivp = sorted((r, s) for (m, sch, _, r), s in by.items() if m == "constrained" and sch == "RK45")
    assert ivp[0][1] > ivp[-1][1]


# --- the first compile ------------------------------------------------------------------------------------------


def test_a_long_compile_is_announced_and_a_short_one_or_none_is_not(capsys):
    import time

    from liefi._progress import COMPILE_MESSAGE, compile_notice, compiling

    with compile_notice(after=0.05, enabled=True):
        with compiling():
            time.sleep(0.5)
    assert capsys.readouterr().err.count(COMPILE_MESSAGE) == 1
    with compile_notice(after=0.3, enabled=True):
        with compiling():
            time.sleep(0.01)  # kernels loaded from the cache
        time.sleep(0.5)  # other work: not a compile
    with compile_notice(after=0.05, enabled=False):  # stderr neither a terminal nor a notebook
        with compiling():
            time.sleep(0.3)
    assert capsys.readouterr().err == ""


def test_a_run_announces_its_compile_and_its_progress_starts_after_it(knife, monkeypatch, capsys):
    """A (slow, faked) compile in fi.run: one line on stderr while it lasts, and the bar starts after it."""
    import time
    import warnings

    from liefi import _progress
    from liefi.engine import kernels
    from liefi.engine.trace import NotCompilable

    _, fi = knife
    ended, starts = [], []

    def slow_compile(fi, **kw):
        with _progress.compiling():
            time.sleep(1.5)
        ended.append(time.monotonic())
        raise NotCompilable("a test's stand-in for a long compile")

    init = _progress.Progress.__init__

    def spy(self, total, *a, **kw):
        init(self, total, *a, **kw)
        if self.enabled:
            starts.append(self._start)

    monkeypatch.setattr(kernels, "compile_split", slow_compile)
    monkeypatch.setattr(_progress, "stderr_is_terminal", lambda: True)
    monkeypatch.setattr(_progress, "NOTICE_SECONDS", 0.3)
    monkeypatch.setattr(_progress.Progress, "__init__", spy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = fi.run(0.5, dt=1e-2, scheme="imex-rk4", backend="numba", progress=True)
    assert sol.backend == "numpy" and ended
    assert capsys.readouterr().err.count(_progress.COMPILE_MESSAGE) == 1
    assert starts and min(starts) >= ended[0]  # the progress counts steps, not the compile


def test_the_notice_is_on_in_a_notebook(monkeypatch):
    """A Jupyter kernel's stderr is not a terminal but shows what is written to it: the notice is on there."""
    import sys
    import types

    from liefi import _progress

    OutStream = type("OutStream", (), {"__module__": "ipykernel.iostream", "write": lambda self, s: None,
                                       "flush": lambda self: None, "isatty": lambda self: False})
    monkeypatch.setitem(sys.modules, "ipykernel", types.ModuleType("ipykernel"))
    monkeypatch.setattr(sys, "stderr", OutStream())
    assert _progress.in_notebook() and not _progress.stderr_is_terminal()
    with _progress.compile_notice(after=10.0):
        assert _progress._COMPILE["watching"]  # the watcher runs
    assert not _progress._COMPILE["watching"]
