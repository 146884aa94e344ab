"""What a new user trips on (issue 23): solve_ivp's keywords, misspelt keywords, the first compile's silence,
the documented default, and the time-left estimate of a sweep of unequal tasks."""

import json
import os
import re
import threading

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


class _WatchedCompile(dict):
    """``liefi._progress._COMPILE`` that records what the notice's watcher thread reads of the compile's start
    (``since``: ``None`` when no compile runs), so that a test waits for the watcher's looks, not for a time."""

    def __init__(self, state):
        super().__init__(state)
        self.looks = []

    def __getitem__(self, key):
        value = super().__getitem__(key)
        if key == "since" and threading.current_thread().name == "liefi-compile-notice":
            self.looks.append(value)
        return value


def _wait_for(cond, what):
    """Until ``cond()`` (the watcher looks every 0.1 s; 60 s only guards against a hang)."""
    import time

    deadline = time.monotonic() + 60.0
    while not cond():
        assert time.monotonic() < deadline, f"waited 60 s for {what}"
        time.sleep(0.01)


def _watchers():
    return [t for t in threading.enumerate() if t.name == "liefi-compile-notice" and t.is_alive()]


def _looked(state, watchers, k=2):
    """A condition: the watchers looked ``k`` more times from now, or have ended (a notice ends a watcher)."""
    n = len(state.looks)
    return lambda: len(state.looks) >= n + k or not any(t.is_alive() for t in watchers)


@pytest.fixture
def notice_clock(monkeypatch):
    """``liefi._progress`` on a clock that only the test moves, its compile state watched: ``(clock, state)``."""
    from liefi import _progress

    clock, state = _Clock(), _WatchedCompile(_progress._COMPILE)
    monkeypatch.setattr(_progress, "time", clock)
    monkeypatch.setattr(_progress, "_COMPILE", state)
    return clock, state


def test_a_long_compile_is_announced_and_a_short_one_or_none_is_not(capsys, notice_clock):
    """Compiles that last 0.5 s, 0.01 s and 0.3 s on the notice's clock: one line for the first, nothing for the
    short one, for other work after it, or where the notice is off.  The test waits for the watcher's looks,
    never for a time (before: real sleeps, whose lengths and the watcher's wake-ups a loaded machine stretches)."""
    from liefi._progress import COMPILE_MESSAGE, compile_notice, compiling

    clock, state = notice_clock
    err = []

    def said():
        err.append(capsys.readouterr().err)
        return "".join(err).count(COMPILE_MESSAGE)

    with compile_notice(after=0.05, enabled=True):
        watchers = _watchers()
        with compiling():
            clock.now += 0.5
            _wait_for(_looked(state, watchers), "the notice of a compile of 0.5 s")  # a notice ends the watcher
    assert said() == 1
    with compile_notice(after=0.3, enabled=True):
        watchers = _watchers()
        with compiling():
            clock.now += 0.01  # kernels loaded from the cache
            _wait_for(_looked(state, watchers), "two looks at the compile")
        _wait_for(_looked(state, watchers), "two looks after it")  # no look at its start still under way
        clock.now += 0.5  # other work: not a compile
        _wait_for(_looked(state, watchers), "two looks at the other work")
        assert all(t.is_alive() for t in watchers)  # still watching: nothing said
    n = len(state.looks)
    with compile_notice(after=0.05, enabled=False):  # stderr neither a terminal nor a notebook
        with compiling():
            clock.now += 0.3
            assert not state["watching"]
    assert len(state.looks) == n  # no watcher
    assert said() == 1 and "".join(err) == COMPILE_MESSAGE + "\n"


def test_a_run_announces_its_compile_and_its_progress_starts_after_it(knife, monkeypatch, capsys, notice_clock):
    """A (slow, faked) compile in fi.run: one line on stderr while it lasts, and the bar starts after it.  The
    compile lasts 1.5 s on the notice's clock and ends once the watcher has looked at it (before: a real sleep
    of 1.5 s, within which a loaded machine had to wake the watcher)."""
    import warnings

    from liefi import _progress
    from liefi.engine import kernels
    from liefi.engine.trace import NotCompilable

    clock, state = notice_clock
    _, fi = knife
    ended, starts = [], []

    def slow_compile(fi, **kw):
        with _progress.compiling():
            clock.now += 1.5
            _wait_for(_looked(state, _watchers()), "the watcher's look at the compile")
        ended.append(clock.now)
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
    assert starts and min(starts) >= ended[0] > 0.0  # the progress counts steps, not the compile


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
