"""The work-precision harness and the sweep API.

Small grids on a short horizon only (the real sweeps live in ``benchmarks/``
and ``docs/``); the kernels are the ones ``test_compiled.py`` compiles, so
numba's on-disk cache serves both files.  No test asserts a time.
"""

from __future__ import annotations

import csv
import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from liefi import bench, compiled, scenes
from liefi.sweep import open_executor, run_sweep

pytestmark = pytest.mark.skipif(not compiled.available(), reason="the work-precision harness runs compiled kernels")

#: one small grid: the Suslov problem with R, Euler and RK45, every method family
SMALL = dict(t_final=0.5, dts=[5e-3], rtols=[1e-6], schemes=("euler",), ivp_methods=("RK45",), n_save=10)


def _strip(r):
    """A run without its timings (which differ from run to run)."""
    return {k: v for k, v in r.items() if k not in ("cpu_seconds", "compile_seconds")}


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
                                ivp_methods=("RK45",), methods=("FI", "constrained"), n_save=10)
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
