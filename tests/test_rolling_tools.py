"""``liefi bench`` and ``liefi reproduce`` on the rolling scenes (short horizons; the CLI runs are slow)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from liefi import bench, engine, scenes
from liefi.reproduce import reproduce

ROLLING = ("heavy-top", "chaplygin-ball", "rattleback", "rolling-disk")


@pytest.mark.parametrize("name", ROLLING)
def test_bench_builds_every_applicable_method(name):
    """Every family but DLA (the metric is not constant), at the scene's steps."""
    tasks = bench.build_tasks(name, 1.0, quick=True)
    methods = {t["method"] for t in tasks}
    assert {"FI", "constrained", "projection", "no-feedback"} <= methods
    assert "DLA" not in methods
    assert {t["t_final"] for t in tasks} == {1.0}


@pytest.mark.skipif(not engine.available(), reason="the harness runs compiled kernels")
@pytest.mark.parametrize("name", ROLLING[:2])
def test_bench_runs_and_measures_one_task(name):
    sc = scenes.get(name)
    task = bench.build_tasks(name, 0.04, quick=True, methods=["FI"], schemes=("rk4",), n_save=5)[0]
    res = bench.run_task(task)
    assert res["status"] == "ok", res["message"]
    fi = sc.integrator(task["variant"], configuration=task["configuration"])
    row = bench.measure(sc, fi, res, bench.reference(sc, task["variant"], fi, 0.04))
    assert row["max_drift"] < 1e-8 and row["max_error"] < 1e-6, row


@pytest.mark.parametrize("name", ROLLING[:2])
def test_reproduce_runs_the_scene_and_draws_its_figures(name, tmp_path):
    summary = reproduce(tmp_path / "out", only=[name], t_final_scale=0.005, jobs=1)
    data = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert data and summary
    figs = {p.name for p in (tmp_path / "out").glob("*.png")}
    assert any(f.startswith(name) for f in figs), figs


@pytest.mark.slow
@pytest.mark.parametrize("name", ROLLING)
def test_cli_bench_quick(name, tmp_path):
    """``python -m liefi bench NAME --quick --t-final 1``."""
    out = subprocess.run([sys.executable, "-m", "liefi", "bench", name, "--quick", "--t-final", "1", "--out",
                          str(tmp_path)], capture_output=True, text=True, timeout=1200)
    assert out.returncode == 0, out.stderr[-2000:]
    assert list(tmp_path.glob("*.csv"))


@pytest.mark.slow
def test_reproduce_rattleback(tmp_path):
    reproduce(tmp_path / "out", only=["rattleback"], t_final_scale=0.01, jobs=1)
    figs = {p.name for p in (tmp_path / "out").glob("*.png")}
    assert {"rattleback-spin.png", "rattleback-energy.png"} <= figs, figs
