"""benchmarks/make_docs.py: the grid and summary stages honour --methods."""

from __future__ import annotations

import importlib.util
import os

_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks", "make_docs.py")


def _load():
    spec = importlib.util.spec_from_file_location("make_docs", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_grid_tasks_keep_only_the_methods_asked_for():
    md = _load()
    a = md.argparse.Namespace(dts="64,1", t_final=1e3, repeats=1, methods=None)
    every = md._grid_tasks(a, ["heisenberg"])["heisenberg"]
    assert {t["method"] for t in every} >= {"FI", "FI-rtol", "constrained", "FI/solve_ivp"}
    assert {t["scheme"] for t in every if t["method"] == "FI/solve_ivp"} == {"LSODA"}
    a.methods = "FI,FI/solve_ivp,constrained"
    some = md._grid_tasks(a, ["heisenberg"])["heisenberg"]
    assert {t["method"] for t in some} == {"FI", "FI/solve_ivp", "constrained"}
    assert some == [t for t in every if t["method"] in ("FI", "FI/solve_ivp", "constrained")]
