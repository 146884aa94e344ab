"""The work-precision harness and the sweep API.

Small grids on a short horizon only (the real sweeps live in ``benchmarks/``
and ``docs/``); the kernels are the ones ``test_compiled.py`` compiles, so
numba's on-disk cache serves both files.  No test asserts a time.
"""

from __future__ import annotations

import csv
import json
import math
import os
import pickle
import signal
import sqlite3
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor

import numpy as np
import pytest

from liefi import bench, engine, scenes
from liefi.sweep import ResultStore, SweepInterrupted, TaskError, open_executor, run_sweep

pytestmark = pytest.mark.skipif(not engine.available(), reason="the work-precision harness runs compiled kernels")

#: one small grid: the Suslov problem with R, Euler and RK45, every method family
SMALL = dict(t_final=0.5, dts=[5e-3], rtols=[1e-6], schemes=("euler",), ivp_methods=("RK45",), n_save=10)


def _strip(r):
    """A run without its timings (which differ from run to run)."""
    return {k: v for k, v in r.items() if k not in ("cpu_seconds", "compile_seconds", "cpu_spread", "setup_seconds")}


def _same(a, b):
    assert _strip(a).keys() == _strip(b).keys()
    for k in _strip(a):
        x, y = a[k], b[k]
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y)
        elif isinstance(x, float) and math.isnan(x):
            assert isinstance(y, float) and math.isnan(y)
        else:
            assert x == y, k


def test_tasks_cover_every_method_family():
    """Lie-group scenes get every family but DLA; a system on T*R^n with a constant metric gets DLA too."""
    t = bench.build_tasks("suslov", 1.0)
    assert {x["method"] for x in t} == set(bench.METHODS) - {"DLA"}
    assert {x["scheme"] for x in t if x["method"] == "FI"} == set(bench.FIXED_SCHEMES)
    assert {x["scheme"] for x in t if x["method"] == "constrained"} == set(bench.IVP_METHODS)
    t = bench.build_tasks("knife-edge", 1.0, quick=True)
    assert "DLA" in {x["method"] for x in t} and "FI-tuned" in {x["method"] for x in t}


def test_work_precision_writes_csv_and_diagrams(tmp_path):
    """One run per family; the CSV has the issue's columns; the PNGs exist; the numbers make sense."""
    rows = bench.work_precision("suslov", out_dir=str(tmp_path), **SMALL)
    assert {r["method"] for r in rows} == set(bench.METHODS) - {"DLA"}
    assert all(r["status"] == "ok" for r in rows), [r["message"] for r in rows]
    by = {r["method"]: r for r in rows}
    # the projection holds every invariant, the feedback integrator keeps them close, no feedback drifts more
    assert by["projection"]["max_drift"] < 1e-13
    assert by["FI"]["max_drift"] < by["no-feedback"]["max_drift"]
    assert by["FI"]["rhs_evaluations"] == 100 and by["projection"]["projection_evaluations"] >= 100
    for r in rows:
        assert r["cpu_seconds"] >= 0 and r["max_error"] < 1e-2
        assert {"drift_J_1", "drift_h", "drift_h~", "drift_orthogonality"} <= set(r)
    path = tmp_path / "suslov-work-precision.csv"
    with open(path) as fh:
        header = next(csv.reader(fh))
    for col in ("method", "scheme", "dt", "rtol", "cpu_seconds", "rhs_evaluations", "max_error", "drift_J_1"):
        assert col in header
    back = bench.read_csv(str(path))
    assert [r["method"] for r in back] == [r["method"] for r in rows]
    assert (tmp_path / "suslov-error.png").stat().st_size > 0
    assert (tmp_path / "suslov-drift.png").stat().st_size > 0
    best = bench.cheapest(rows, drift=1e-8)
    assert best is not None and best["max_drift"] <= 1e-8


def test_dla_and_fi_on_the_knife_edge():
    """The DLA peer runs where it applies; its discrete constraint makes J small but not zero."""
    rows = bench.work_precision("knife-edge", t_final=0.5, dts=[1e-3], methods=("FI", "DLA"), schemes=("euler",),
                                n_save=10)
    by = {r["method"]: r for r in rows}
    assert by["DLA"]["status"] == "ok" and by["FI"]["status"] == "ok"
    assert by["DLA"]["max_error"] < 1e-2 and by["FI"]["max_error"] < 1e-2


def test_failed_run_is_a_row_not_an_exception():
    """Past the stability limit the feedback integrator diverges: recorded, the sweep goes on."""
    r = bench.run_task(dict(scene="knife-edge", variant="extended", method="FI", scheme="euler", dt=4e-3,
                            rtol=None, t_final=0.4, configuration=True, n_save=10))
    assert r["status"] == "diverged" and "non-finite" in r["message"]


def test_a_solve_ivp_run_past_its_cpu_cap_is_a_failed_row(monkeypatch):
    """LSODA at rtol 1e-3 lets the perturbed Kepler orbit fall into r = 0 and retries a non-finite step
    for ever: the cap stops it, the run is a row that says why, and the caller's SIGPROF handler is back."""
    from liefi.bench import core

    monkeypatch.setattr(core, "IVP_CPU_CAP", 0.5)
    before = signal.getsignal(signal.SIGPROF)
    t0 = time.process_time()
    r = bench.run_task(dict(scene="perturbed-kepler", variant="orbit", method="constrained", scheme="LSODA", dt=None,
                            rtol=1e-3, t_final=1000.0, configuration=True, n_save=100, gain=None, repeats=1))
    assert r["status"] == "failed" and "IVP_CPU_CAP" in r["message"] and "0.5 s of CPU" in r["message"]
    assert time.process_time() - t0 < 10.0
    assert signal.getsignal(signal.SIGPROF) is before and signal.getitimer(signal.ITIMER_PROF) == (0.0, 0.0)
    # a run that ends within the cap is untouched by it
    with core.cpu_cap(30.0):
        pass
    r = bench.run_task(dict(scene="perturbed-kepler", variant="orbit", method="constrained", scheme="LSODA", dt=None,
                            rtol=1e-5, t_final=100.0, configuration=True, n_save=100, gain=None, repeats=1))
    assert r["status"] == "ok"


def test_numerical_reference_is_at_the_scene_tolerances(monkeypatch):
    """The harness's reference integrates at the scene's reference_rtol/atol, not at one fixed tolerance."""
    import scipy.integrate

    seen = {}

    def spy(*args, **kw):
        seen.update(kw)
        raise RuntimeError("spied")

    monkeypatch.setattr(scipy.integrate, "solve_ivp", spy)
    sc = scenes.get("perturbed-kepler")
    with pytest.raises(RuntimeError, match="spied"):
        bench.reference(sc, sc.variant(), sc.integrator(configuration=True), 1.0)
    assert (seen["rtol"], seen["atol"]) == (sc.reference_rtol, sc.reference_atol) != (1e-12, 1e-12)


def test_run_sweep_is_executor_independent():
    """The same tasks through a thread pool give exactly the serial results."""
    tasks = bench.build_tasks("suslov", 0.2, dts=[5e-3], rtols=[1e-6], schemes=("euler",), ivp_methods=("RK45",),
                              methods=("FI", "constrained"), n_save=5)
    serial = run_sweep(bench.run_task, tasks)
    with ThreadPoolExecutor(2) as ex:
        threaded = run_sweep(bench.run_task, tasks, ex)
    for a, b in zip(serial, threaded):
        _same(a, b)
    assert run_sweep(abs, [-1, 2, -3]) == [1, 2, 3]
    with pytest.raises(TypeError):
        run_sweep(abs, [1], executor=object())
    # a failing task is a value, serially too: the others are kept
    out = run_sweep(abs, [-1, "x", 3])
    assert out[0] == 1 and out[2] == 3 and isinstance(out[1], TaskError) and out[1].type == "TypeError"


def test_schemes_come_from_the_registry(capsys):
    """--schemes takes any explicit tableau or split scheme of the scheme registry and solve_ivp's methods,
    and names the choices (DLA is a method of its own, not a scheme of the grid)."""
    from liefi.bench.cli import _schemes

    assert _schemes("midpoint,rk4,scipy:LSODA,RK45") == (("midpoint", "rk4"), ("LSODA", "RK45"))
    for bad in ("rk5", "dla"):
        with pytest.raises(ValueError, match=f"schemes: unknown scheme '{bad}'.*midpoint.*imex-euler"):
            _schemes(bad)


def test_accurate_gains_are_an_fi_over_a_long_enough_horizon():
    """FI-accurate (liefi.gains) runs where its gains are nonzero on every invariant the scheme does not keep."""
    r = bench.run_task(dict(scene="oscillator", variant=None, method="FI-accurate", scheme="rk4", dt=8e-3, rtol=None,
                            t_final=40.0, configuration=True, n_save=10, gain=None))
    assert r["status"] == "ok" and "H_y=" in r["message"], r["message"]
    # over a short horizon RK4's accurate gains vanish (the contraction never acts): the no-feedback method
    r = bench.run_task(dict(scene="oscillator", variant=None, method="FI-accurate", scheme="rk4", dt=8e-3, rtol=None,
                            t_final=0.08, configuration=True, n_save=10, gain=None))
    assert r["status"] == "not-applicable" and "no-feedback" in r["message"], r["message"]


def test_open_executor_strings():
    with open_executor(None) as ex:
        assert ex is None
    with open_executor("threads:2") as ex:
        assert run_sweep(abs, [-4], ex) == [4]
    with pytest.raises(ValueError, match="scheduler"):
        with open_executor("nonsense"):
            pass


def test_dask_cluster_gives_the_local_results():
    """A Dask LocalCluster (2 workers) through Client.get_executor() reproduces the local sweep exactly."""
    distributed = pytest.importorskip("distributed")
    tasks = bench.build_tasks("suslov", 0.2, dts=[5e-3], rtols=[1e-6], schemes=("euler",), ivp_methods=("RK45",),
                              methods=("FI", "constrained", "no-feedback"), n_save=5)
    local = run_sweep(bench.run_task, tasks)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cl:
        with distributed.Client(cl) as client:
            remote = run_sweep(bench.run_task, tasks, client.get_executor())
    assert len(remote) == len(local)
    for a, b in zip(local, remote):
        _same(a, b)


def test_long_horizon_matches_cost(tmp_path):
    """The long-horizon view picks, per method, the run whose cost per unit time is closest to the FI's."""
    rows = bench.work_precision("suslov", t_final=0.5, dts=[5e-3, 2.5e-3], rtols=[1e-4, 1e-8], schemes=("euler",),
                                ivp_methods=("RK45",), methods=("FI", "constrained"), n_save=10, gains=(None,))
    tasks = bench.matched_tasks(rows, t_final=1.0, n_save=20)
    assert {(t["method"], t["scheme"]) for t in tasks} == {("FI", "euler"), ("constrained", "RK45")}
    assert [t for t in tasks if t["method"] == "FI"][0]["dt"] == 2.5e-3  # closest to the scene's dt
    out, curves = bench.long_horizon(rows, str(tmp_path), t_final=1.0, n_save=20)
    assert len(out) == 2 and all(r["status"] == "ok" for r in out)
    assert os.path.exists(tmp_path / "suslov-long-horizon.png")


def test_bench_command_line(tmp_path, capsys):
    """``python -m liefi.bench`` (what ``liefi bench`` calls) prints the summary and writes the files."""
    code = bench.main(["suslov", "--t-final", "0.2", "--quick", "--out", str(tmp_path), "--methods", "FI,constrained",
                       "--schemes", "euler,RK45"])
    assert code == 0
    out = capsys.readouterr().out
    assert "cheapest with max drift" in out
    assert (tmp_path / "suslov-work-precision.csv").exists()


# ======================================================================================
# faults: every outcome is a value, nothing is lost
# ======================================================================================


def _faulty(x):
    """The fault battery's task: 3 raises, 5 diverges (an IntegrationError, which does not pickle
    by itself), 7 kills its own worker process; the others return x^2."""
    if x == 3:
        raise ValueError("bad three")
    if x == 5:
        from liefi.schemes import IntegrationError

        raise IntegrationError("diverged at t = 1", 1.0, 10, np.zeros(2), ["p"])
    if x == 7:
        os.kill(os.getpid(), signal.SIGKILL)
    return x * x


def _check_battery(out, n):
    assert len(out) == n
    for x, v in enumerate(out):
        if x == 3:
            assert isinstance(v, TaskError) and v.type == "ValueError" and "bad three" in v.message
            assert "_faulty" in v.traceback  # the worker's traceback, as text
        elif x == 5:
            assert isinstance(v, TaskError) and v.type == "IntegrationError" and "diverged" in v.message
        elif x == 7:
            assert isinstance(v, TaskError) and v.type == "WorkerDied", v
        else:
            assert v == x * x, (x, v)


def test_task_error_pickles_and_prints():
    e = TaskError.from_exception(ValueError("a\n  b"))
    assert pickle.loads(pickle.dumps(e)) == e and str(e) == "ValueError: a b"


def test_fault_battery_process_pool(tmp_path):
    """A raising task, a diverging task and a killed worker on a process pool: every other result comes back,
    the pool is restarted for the rest, and the store holds every outcome."""
    n = 12
    with ProcessPoolExecutor(2) as ex, ResultStore(tmp_path / "r.sqlite") as store:
        out = run_sweep(_faulty, range(n), ex, store=store)
    _check_battery(out, n)
    with ResultStore(tmp_path / "r.sqlite") as store:
        rows = dict(store.rows())
    assert len(rows) == n and rows[4] == 16 and rows[7].type == "WorkerDied"
    with sqlite3.connect(tmp_path / "r.sqlite") as db:  # a user's query
        assert db.execute("select count(*) from results where status = 'error'").fetchone()[0] == 3


def test_fault_battery_dask_cluster():
    """The same battery on a Dask LocalCluster of worker processes (a killed worker is Dask's KilledWorker)."""
    dask = pytest.importorskip("dask")
    distributed = pytest.importorskip("distributed")
    n = 10
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                      silence_logs=50) as cl:
            with distributed.Client(cl) as client:
                out = run_sweep(_faulty, range(n), client.get_executor())
    _check_battery(out, n)


_CALLS = []


def _count_calls(x):
    _CALLS.append(x)
    if x == 2 and len(_CALLS) < 4:
        raise RuntimeError("flaky")
    return {"x": x, "nan": math.nan, "a": np.arange(2.0)}


def test_store_resumes_and_retries_errors(tmp_path):
    """A rerun with the same store runs only what is not done (errors are retried); values are strict JSON."""
    path = tmp_path / "s.sqlite"
    with ResultStore(path) as st:
        out = run_sweep(_count_calls, [0, 1, 2], store=st)
    assert isinstance(out[2], TaskError) and out[0] == {"x": 0, "nan": None, "a": [0.0, 1.0]}
    assert _CALLS == [0, 1, 2]
    with ResultStore(path) as st:
        out2 = run_sweep(_count_calls, [0, 1, 2, 3], store=st)
    assert _CALLS == [0, 1, 2, 2, 3] and out2[:2] == out[:2] and out2[2]["x"] == 2
    with sqlite3.connect(path) as db:
        assert db.execute("select json_extract(value, '$.x') from results where idx = 3").fetchone()[0] == 3
    bad = tmp_path / "bad.sqlite"
    bad.write_text("not a database" * 100)
    with pytest.raises(OSError, match="results store"):
        ResultStore(bad)


def _slow_or_interrupt(x):
    if x == 2:
        raise KeyboardInterrupt
    return x


def test_interrupt_keeps_what_finished(tmp_path):
    with ResultStore(tmp_path / "i.sqlite") as st:
        with pytest.raises(SweepInterrupted) as info:
            run_sweep(_slow_or_interrupt, range(5), store=st)
        assert info.value.results == [0, 1, None, None, None] and info.value.done == 2
        assert len(st.rows()) == 2


# ======================================================================================
# liefi bench: named errors, summary.json, resume, Ctrl-C
# ======================================================================================


@pytest.mark.parametrize("args, name", [
    (["--t-final", "nan"], "--t-final"), (["--t-final", "inf"], "--t-final"), (["--t-final", "-1"], "--t-final"),
    (["--t-final", "0"], "--t-final"), (["--long-horizon", "-5"], "--long-horizon"), (["--gains", "0"], "gains"),
    (["--gains", "x"], "gains")])
def test_bench_refuses_bad_numbers(tmp_path, capsys, monkeypatch, args, name):
    """No hang on nan/inf, no verdict from failed runs: a named error and exit code 2, before any run (no
    task and no reference started: checked, not timed)."""
    from liefi.bench import horizon

    def no_work(*a, **k):
        raise AssertionError("work started before the arguments were checked")

    for where, attr in ((bench.core, "run_task"), (horizon, "run_task"), (scenes.Scene, "solve_reference")):
        monkeypatch.setattr(where, attr, no_work)
    code = bench.main(["suslov", "--quick", "--out", str(tmp_path / "o"), *args])
    assert code == 2
    err = capsys.readouterr().err
    assert name in err and "Traceback" not in err


def test_bench_summary_json_and_resume(tmp_path, capsys):
    """summary.json: cheapest_overall, cheapest_fi (an FI, every gain nonzero) and their CPU ratio; a rerun resumes."""
    out = tmp_path / "o"
    argv = ["suslov", "--t-final", "0.5", "--quick", "--out", str(out), "--methods", "FI,no-feedback,projection",
            "--schemes", "rk4", "--gains", "scene,0.1,1"]
    assert bench.main(argv) == 0
    doc = json.loads((out / "summary.json").read_text())
    s = doc["scenes"]["suslov"]
    assert s["complete"] and s["runs"] == s["tasks"] == 3 * 3 + 3 + 3
    best, fi = s["cheapest_overall"], s["cheapest_fi"]
    for r in (best, fi):
        assert {"method", "scheme", "dt", "rtol", "cpu_seconds"} <= set(r) and r["max_drift"] <= 1e-8
    assert fi["method"] == "FI" and fi["gain"] != 0
    assert s["fi_over_best"] == pytest.approx(fi["cpu_seconds"] / best["cpu_seconds"])
    assert s["fi_over_best"] >= 1.0 or best["method"] == "FI"
    with sqlite3.connect(out / "results.sqlite") as db:
        stamps = db.execute("select key, finished_at from results").fetchall()
    assert "fi_over_best" in capsys.readouterr().out
    assert bench.main(argv) == 0  # resumed: nothing is run again
    with sqlite3.connect(out / "results.sqlite") as db:
        assert db.execute("select key, finished_at from results").fetchall() == stamps
    assert json.loads((out / "summary.json").read_text()) == doc


def test_bench_interrupted_by_sigint_keeps_a_consistent_summary(tmp_path):
    """Ctrl-C after the first results: one line, exit 130, the store and summary.json agree; a rerun finishes."""
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "liefi.bench", "suslov", "--t-final", "100", "--quick", "--out", str(out), "--methods",
           "FI,no-feedback", "--schemes", "euler,heun,rk4", "--no-progress"]
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    p = subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    db_path = out / "results.sqlite"
    deadline = time.time() + 120
    done = 0
    while time.time() < deadline and p.poll() is None:
        if db_path.exists():
            with contextlib_closing(sqlite3.connect(db_path)) as db:
                try:
                    done = db.execute("select count(*) from results").fetchone()[0]
                except sqlite3.OperationalError:
                    done = 0
            if done >= 2:
                break
        time.sleep(0.05)
    assert p.poll() is None, p.communicate()
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=60)
    assert p.returncode == 130, stderr
    assert "Traceback" not in stderr and "interrupted" in stderr
    assert len([ln for ln in stderr.splitlines() if "interrupted" in ln]) == 1
    s = json.loads((out / "summary.json").read_text())["scenes"]["suslov"]
    with sqlite3.connect(db_path) as db:
        stored = db.execute("select count(*) from results").fetchone()[0]
    assert s["runs"] == stored >= 2 and not s["complete"] and s["tasks"] == 5 * 3 * 3
    assert bench.main(cmd[3:]) == 0
    s = json.loads((out / "summary.json").read_text())["scenes"]["suslov"]
    assert s["complete"] and s["runs"] == 45


def contextlib_closing(x):
    import contextlib

    return contextlib.closing(x)


def test_crossover_from_prefix_maxima():
    """The crossover is the least horizon from which on the FI keeps the invariants for less than any other
    method; costs scale with the horizon; a horizon where no FI qualifies ends it."""
    def row(method, gain, cpu, drifts, errors=None):
        hs = [1e2, 1e3, 1e4]
        return dict(method=method, scheme="rk4", gain=gain, status="ok", t_final=1e4, cpu_seconds=cpu, horizons=hs,
                    drift_at=drifts, error_at=errors or [None] * 3, error_measured=errors is not None)

    rows = [row("FI", 0.1, 2.0, [1e-12, 1e-11, 5e-11]),          # bounded drift, 2 s to 1e4
            row("no-feedback", None, 1.0, [1e-12, 1e-11, 1e-9]),  # cheaper, but drifts past 1e-10 by 1e4
            row("projection", None, 3.0, [1e-14, 1e-14, 1e-14])]
    c = bench.crossover(rows, drift=1e-10)
    assert c["crossover"] == 1e4
    assert c["other_best"][1e3] == ("no-feedback rk4", pytest.approx(0.1))
    assert c["fi_best"][1e4] == ("FI rk4 k=0.1", 2.0) and c["other_best"][1e4] == ("projection rk4", 3.0)
    rows[0]["drift_at"][-1] = None  # the FI diverged before 1e4: no crossover
    assert bench.crossover(rows, drift=1e-10)["crossover"] is None
    # a relative state error where measured
    rows = [row("FI", 1.0, 2.0, [0, 0, 0], [1e-9, 1e-8, 1e-5]), row("projection", None, 3.0, [0, 0, 0], [0, 0, 0])]
    assert bench.crossover(rows, drift=1e-10, error=1e-6)["crossover"] is None
    assert bench.crossover(rows, drift=1e-10, error=1e-4)["crossover"] == 1e2


def test_horizon_row_reads_prefixes():
    """horizon_row turns a run into prefix maxima of the drift and of the relative error (exact solution)."""
    task = dict(scene="suslov", variant=None, method="FI", scheme="rk4", dt=8e-3, rtol=None, t_final=200.0,
                configuration=True, n_save=200, gain=1.0)
    r = bench.horizon_row(task, bench.run_task(task))
    assert r["horizons"] == [100.0, 200.0] and r["error_measured"]
    assert r["drift_at"][0] <= r["drift_at"][1] == pytest.approx(r["max_drift"])
    assert 0 < r["error_at"][0] <= r["error_at"][1] < 1e-6


def test_interrupt_stops_a_process_pool_at_once():
    """Ctrl-C while process-pool workers run long tasks: the workers are stopped and the sweep returns,
    not after the running tasks finish.  The tasks last an hour: a process that ends at all (within the
    120 s timeout; about 3 s) stopped them -- no bound on how fast (before: under 50 s for tasks of 60 s)."""
    code = (
        "import os, signal, threading, time, sys\n"
        "from liefi.sweep import run_sweep, open_executor, SweepInterrupted\n"
        "threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT)).start()\n"
        "try:\n"
        "    with open_executor('processes:2') as ex:\n"
        "        run_sweep(time.sleep, [3600.0] * 4, ex)\n"
        "except SweepInterrupted as e:\n"
        "    print('interrupted', e.done, e.results)\n"
    )
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["interrupted", "0", "[None,", "None,", "None,", "None]"], out.stdout + out.stderr


def test_split_schemes_are_feedback_integrator_rows_of_the_harness():
    """``--schemes imex-euler``: FI rows only (no-feedback/projection need an explicit tableau);
    at the paper's knife-edge gains (1000) the split step is stable at dt = 8e-3, where explicit Euler is not."""
    tasks = bench.build_tasks("knife-edge", 0.4, schemes=("euler", "imex-euler"), ivp_methods=(),
                              methods=("FI", "no-feedback", "projection"), dts=(8e-3,), gains=(None,))
    split = [t for t in tasks if t["scheme"] == "imex-euler"]
    assert split and {t["method"] for t in split} == {"FI"}
    rows = bench.work_precision("knife-edge", t_final=0.4, dts=[8e-3], methods=("FI",), schemes=("euler", "imex-euler"),
                                ivp_methods=(), gains=(None,), n_save=10, plots=False)
    by = {r["scheme"]: r for r in rows}
    assert by["imex-euler"]["status"] == "ok" and by["imex-euler"]["max_error"] < 0.1
    assert by["euler"]["status"] != "ok" or by["euler"]["max_error"] > 10 * by["imex-euler"]["max_error"]
    from liefi.bench.cli import _schemes

    assert _schemes("rk4,imex-rk4,LSODA") == (("rk4", "imex-rk4"), ("LSODA",))


@pytest.mark.skipif(not engine.available(), reason="numba not installed")
def test_split_accurate_rows_run_compiled_and_keep_the_invariants_at_rounding():
    """FI-accurate with imex-rk4: the compiled split kernel, gains at the rate 1/sqrt(u), drift at rounding where
    plain RK4 at the same step drifts; FI/solve_ivp rows carry the grid's gains."""
    base = dict(scene="suslov", variant=None, rtol=None, t_final=50.0, configuration=True, n_save=50, gain=None,
                dt=8e-3)
    split = bench.run_task(dict(base, method="FI-accurate", scheme="imex-rk4"))
    plain = bench.run_task(dict(base, method="no-feedback", scheme="rk4"))
    assert split["status"] == plain["status"] == "ok", split["message"]
    assert split["rhs_evaluations"] == 5 * split["steps"]  # four stages of X and the feedback step
    _, _, fi = bench.core._integrator(split)
    d_split = max(float(np.max(v)) for v in bench.core.invariant_drifts(fi, split["y"]).values())
    d_plain = max(float(np.max(v)) for v in bench.core.invariant_drifts(fi, plain["y"]).values())
    assert d_split < 1e-14 and d_plain > 100 * d_split
    tasks = bench.build_tasks("chaplygin", 10.0, methods=("FI/solve_ivp",), ivp_methods=("LSODA",), rtols=(1e-6,),
                              gains=(None, 0.1))
    assert sorted(str(t["gain"]) for t in tasks) == ["0.1", "None"]
