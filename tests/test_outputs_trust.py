"""Outputs that can be trusted: nothing overwritten, mixed, malformed, late or unexplained.

* ``liefi bench --out DIR`` owns its folder the way ``liefi reproduce`` does (one
  manifest mechanism): a user's files, or a ``reproduce`` folder, are refused
  before any work and left as they were;
* ``summary.json``, the CSV and the console describe exactly this invocation's
  task set; ``complete`` means every one of its tasks has a stored result;
* every JSON that the CLI prints or writes is strict (no ``NaN``/``Infinity``);
* an ``--out`` format matplotlib cannot write, and a run longer than
  ``--max-steps``, are refused before any work (``liefi bench`` with the check
  ``liefi run`` makes);
* a run that blows up where the metric turned indefinite names the metric, at
  the last finite state and its time; complex-valued data are called complex,
  not non-finite; ``from_sympy`` refuses strings (it never runs them).
"""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest

import liefi
from liefi import bench, cli, reproduce, scenes
from liefi.bench.core import build_tasks, summarize
from liefi.sweep import ResultStore, TaskError

#: the smallest real bench: 3 runs of the oscillator (FI, Euler, the scene's gains, --quick)
#: serial: the fixtures below replace bench's runs in this process (a process pool would not see them)
TINY = ["oscillator", "--quick", "--methods", "FI", "--schemes", "euler", "--gains", "scene", "--scheduler", "serial"]


@pytest.fixture(autouse=True)
def _slow_only_when_asked(request):
    """``@pytest.mark.slow`` tests run only with ``-m slow``."""
    if request.node.get_closest_marker("slow") and "slow" not in (request.config.getoption("-m") or ""):
        pytest.skip("slow: run with -m slow")


def strict(text):
    """``json.loads`` that refuses ``NaN``, ``Infinity`` and ``-Infinity``."""
    def refuse(const):
        raise ValueError(f"not JSON: {const}")

    return json.loads(text, parse_constant=refuse)


def run_cli(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if a scene run, a stability sweep or a bench sweep starts."""
    def forbidden(*a, **k):
        raise AssertionError("work started before the arguments were refused")

    monkeypatch.setattr(scenes.base.Scene, "run", forbidden)
    monkeypatch.setattr("liefi.bench.cli.work_precision", forbidden)
    monkeypatch.setattr("liefi.experiments.stability_cli.stability_map", forbidden)
    monkeypatch.setattr("liefi.experiments.stability_cli.estimate", forbidden)


# --------------------------------------------------------------------------------------
# item 7: bench owns its folder (the mechanism of reproduce)
# --------------------------------------------------------------------------------------
def test_bench_refuses_a_folder_with_a_users_files(tmp_path, capsys, no_work):
    d = tmp_path / "mine"
    d.mkdir()
    (d / "summary.json").write_text('{"mine": 1}')
    (d / "oscillator-work-precision.csv").write_text("my,data\n")
    code, out, err = run_cli(capsys, "bench", *TINY, "--t-final", "0.01", "--out", d)
    assert code == 2 and "out:" in err and "not empty" in err and "liefi-manifest.json" in err
    assert (d / "summary.json").read_text() == '{"mine": 1}'
    assert (d / "oscillator-work-precision.csv").read_text() == "my,data\n"
    assert sorted(os.listdir(d)) == ["oscillator-work-precision.csv", "summary.json"]


def test_bench_refuses_a_reproduce_folder_and_reproduce_a_bench_folder(tmp_path, capsys, no_work):
    d = tmp_path / "rep"
    out = reproduce.prepare_output(str(d))
    out.write_text("summary.json", "the reproduction's summary")
    code, _, err = run_cli(capsys, "bench", *TINY, "--t-final", "0.01", "--out", d)
    assert code == 2 and "liefi reproduce" in err
    assert (d / "summary.json").read_text() == "the reproduction's summary"
    assert not (d / "results.sqlite").exists()
    # and the other way round: reproduce would remove the files a bench manifest lists (its store)
    b = tmp_path / "bench"
    reproduce.prepare_output(str(b), "bench", keep=True).claim("results.sqlite")
    (b / "results.sqlite").write_text("a store")
    with pytest.raises(reproduce.OutputError, match="liefi bench"):
        reproduce.prepare_output(str(b))
    assert (b / "results.sqlite").read_text() == "a store"


def test_bench_in_its_own_folder_refuses_a_file_it_did_not_write(tmp_path, capsys, no_work):
    d = tmp_path / "b"
    reproduce.prepare_output(str(d), "bench", keep=True)  # a folder an earlier bench owns
    (d / "oscillator-drift.png").write_text("a user's figure")
    code, _, err = run_cli(capsys, "bench", *TINY, "--t-final", "0.01", "--out", d)
    assert code == 2 and "oscillator-drift.png" in err and "not written by liefi" in err
    assert (d / "oscillator-drift.png").read_text() == "a user's figure"


# --------------------------------------------------------------------------------------
# item 8: summary.json, the CSV and the console describe exactly this invocation
# --------------------------------------------------------------------------------------
def _fake_row(task, **kw):
    row = dict(task, status="ok", cpu_seconds=1.0, rhs_evaluations=10, max_drift=1e-10, max_error=1e-9)
    row.update(kw)
    return row


def test_summary_is_the_invocations_task_set_from_the_store(tmp_path):
    sc = scenes.get("oscillator")
    kw = dict(quick=True, methods=["FI"], schemes=("euler", "heun"), gains=(None,))
    first = build_tasks(sc, 1.0, **kw)  # an earlier invocation: 6 tasks, all stored
    second = build_tasks(sc, 2.0, **dict(kw, schemes=("euler",)))  # this one: 3 tasks
    with ResultStore(str(tmp_path / "results.sqlite")) as store:
        for t in first:
            store.put(t, _fake_row(t, cpu_seconds=1e-6))  # cheaper than anything of this invocation
        store.put(second[0], _fake_row(second[0], cpu_seconds=2.0))
        store.put(second[1], TaskError("RuntimeError", "boom", ""))
    doc = bench.write_summary(str(tmp_path), {"oscillator": second}, {"t_final": 2.0})
    s = doc["scenes"]["oscillator"]
    assert s["t_final"] == 2.0 and s["tasks"] == 3 and s["runs"] == 2 and s["errors"] == 1
    assert s["complete"] is False  # one task not run, one raised
    assert s["cheapest_overall"]["cpu_seconds"] == 2.0  # not a run of the first invocation
    assert doc["other_runs_in_store"] == 6 and doc["arguments"] == {"t_final": 2.0}
    assert strict((tmp_path / "summary.json").read_text()) == doc
    with ResultStore(str(tmp_path / "results.sqlite")) as store:
        for t in second[1:]:
            store.put(t, _fake_row(t, cpu_seconds=3.0))
    assert bench.write_summary(str(tmp_path), {"oscillator": second})["scenes"]["oscillator"]["complete"] is True


def test_complete_means_every_task_has_a_stored_result():
    sc = scenes.get("oscillator")
    t1, t2 = build_tasks(sc, 1.0, quick=True, methods=["FI"], schemes=("euler",), gains=(None,))[:2]
    rows = [_fake_row(t1), bench.error_row(t2, TaskError("RuntimeError", "boom", ""))]
    assert summarize(rows, tasks=2)["complete"] is False  # a task that raised has no result
    assert summarize(rows[:1], tasks=2)["complete"] is False
    assert summarize([_fake_row(t1), _fake_row(t2)], tasks=2)["complete"] is True


@pytest.fixture
def fake_runs(monkeypatch):
    """Bench's runs replaced by instant ones (their cost: ``dt``; no reference solution needed)."""
    def run_task(task):
        return dict(task, status="ok", message="", cpu_seconds=task["dt"], compile_seconds=0.0, rhs_evaluations=1,
                    projection_evaluations=0, steps=1, t=None, y=None)

    monkeypatch.setattr("liefi.bench.core.run_task", run_task)
    monkeypatch.setattr("liefi.bench.core.reference", lambda *a, **k: None)


def test_two_invocations_do_not_mix(tmp_path, capsys, fake_runs):
    """The issue's probe, small: --t-final 0.01 over 2 schemes, then --t-final 0.02 over one."""
    _two_invocations(tmp_path, capsys)


@pytest.mark.slow
def test_two_real_invocations_do_not_mix(tmp_path, capsys):
    _two_invocations(tmp_path, capsys)


def _two_invocations(tmp_path, capsys):
    d = tmp_path / "out"
    code, _, _ = run_cli(capsys, "bench", *TINY, "--schemes", "euler,heun", "--t-final", "0.01", "--out", d)
    assert code == 0
    code, out, _ = run_cli(capsys, "bench", *TINY, "--t-final", "0.02", "--out", d)
    assert code == 0 and "t_final = 0.02" in out
    doc = strict((d / "summary.json").read_text())
    s = doc["scenes"]["oscillator"]
    assert (s["t_final"], s["runs"], s["tasks"], s["complete"]) == (0.02, 3, 3, True)
    assert doc["other_runs_in_store"] == 6 and doc["arguments"]["t_final"] == 0.02
    for k in ("cheapest_overall", "cheapest_fi"):
        assert s[k] is None or s[k]["scheme"] == "euler"
    with open(d / "oscillator-work-precision.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 and {r["t_final"] for r in rows} == {"0.02"}
    # bench writes only what it claimed, and it claimed it in its manifest
    listed = set(strict((d / "liefi-manifest.json").read_text())["files"])
    assert set(os.listdir(d)) - {"liefi-manifest.json"} <= listed
    assert strict((d / "liefi-manifest.json").read_text())["command"] == "bench"


# --------------------------------------------------------------------------------------
# item 9: strict JSON everywhere
# --------------------------------------------------------------------------------------
def test_stability_json_is_strict(capsys):
    code, out, _ = run_cli(capsys, "stability", "suslov", "--scheme", "imex-rk4", "--estimate", "--json")
    assert code == 0
    est = strict(out)["estimate"]
    assert est["bound"] is None and est["dt_safe"] is None  # no real stability bound: documented as null
    assert "null" in cli.build_parser()._subparsers._group_actions[0].choices["stability"].format_help()


def test_stability_map_json_is_strict(capsys):
    code, out, _ = run_cli(capsys, "stability", "oscillator", "--scheme", "imex-euler", "--gains", "1",
                           "--t-final", "0.05", "--backend", "numpy", "--json")
    assert code == 0
    doc = strict(out)
    assert doc["map"]["bound"] is None and doc["map"]["boundaries"][0]["finite"][1] is None


def test_run_json_is_strict(capsys):
    code, out, _ = run_cli(capsys, "run", "suslov", "--t-final", "0.01", "--json")
    assert code == 0 and strict(out)["scene"] == "suslov"


def test_strict_dumps_writes_null_for_non_finite_numbers():
    from liefi import _json

    text = _json.dumps({"a": float("inf"), "b": [np.nan, np.float64(-np.inf), 1.5], "c": np.arange(2)})
    assert strict(text) == {"a": None, "b": [None, None, 1.5], "c": [0, 1]}


# --------------------------------------------------------------------------------------
# item 10: an unsupported --out format is refused before any work
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("command", [["run", "suslov"], ["stability", "oscillator"]])
def test_unsupported_out_format_is_refused_before_any_work(tmp_path, capsys, no_work, command):
    code, _, err = run_cli(capsys, *command, "--out", tmp_path / "x.jpgz")
    assert code == 2 and "out:" in err and "'jpgz'" in err and "png" in err
    assert not os.listdir(tmp_path)


# --------------------------------------------------------------------------------------
# item 11: bench refuses the runs liefi run refuses, with the same check
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("extra", [["--t-final", "1e9"], ["--t-final", "0.01", "--long-horizon", "1e12"],
                                   ["--t-final", "0.2", "--max-steps", "100"]])
def test_bench_refuses_runs_liefi_run_refuses(tmp_path, capsys, no_work, extra):
    code, _, err = run_cli(capsys, "bench", *TINY, *extra, "--out", tmp_path / "b")
    assert code == 2 and "steps, more than the" in err and "--max-steps" in err
    assert not (tmp_path / "b").exists()  # nothing written either
    code, _, err_run = run_cli(capsys, "run", "suslov", "--t-final", "1e9")
    assert code == 2 and "steps, more than the" in err_run  # the same check


def test_bench_max_steps_lets_a_run_through(tmp_path, capsys, monkeypatch):
    class Reached(Exception):
        pass

    def reached(*a, **k):
        raise Reached

    monkeypatch.setattr("liefi.bench.cli.work_precision", reached)
    with pytest.raises(Reached):  # not refused: the sweep starts
        cli.main(["bench", *TINY, "--t-final", "0.2", "--max-steps", "1000", "--out", str(tmp_path / "b")])


# --------------------------------------------------------------------------------------
# item 14 and the smaller ones: the data's defects named; strings refused
# --------------------------------------------------------------------------------------
def _indefinite_system():
    sympy = pytest.importorskip("sympy")
    x, y, z, xd, yd, zd = sympy.symbols("x y z xd yd zd")
    T = (xd**2 + yd**2 + zd**2) / 2
    return liefi.from_sympy(T - x**2 * zd**2 - x**2 / 2, [x, y, z], [xd, yd, zd], [yd - z * xd])


def test_a_metric_that_turns_indefinite_during_a_run_is_named():
    sys_ = _indefinite_system()  # M_zz = 1 - 2 x^2: indefinite for |x| > 1/sqrt(2)
    y0 = sys_.project(np.array([0.0, 0.0, 0.3, 3.0, 0.0, 0.5]))
    fi = liefi.FeedbackIntegrator(sys_, y0, gains=1.0)
    with pytest.raises(liefi.IntegrationError) as info:
        fi.run(5.0, dt=1e-2, scheme="euler", check_stability=False)
    msg = str(info.value)
    t_last = info.value.t
    assert t_last > 1.0  # it turned indefinite during the run, not at the start
    assert f"At the last finite state (t={t_last:g}): The metric is not positive definite" in msg
    assert "singular metric or constraint?" not in msg


@pytest.mark.filterwarnings("ignore:Casting complex values to real")
def test_data_defect_names_complex_data_at_a_state():
    from liefi.guard import data_defect

    def A(x):
        x = np.asarray(x)
        one = np.ones_like(x[..., 0])
        return np.stack([one, np.sqrt(1.0 - x[..., 0] + 0j), 0 * one], -1)[..., None, :]

    sys_ = liefi.NonholonomicSystem.from_velocity_constraints(liefi.CotangentBundle(3), np.eye(3), A)
    fi = liefi.FeedbackIntegrator(sys_, sys_.project(np.array([0.0, 0, 0, 1.0, 0, 1.0])), gains=1.0)
    assert data_defect(fi, fi.y0) == ""
    y = fi.y0.copy()
    y[0] = 2.0  # x_1 > 1: sqrt(1 - x_1) is imaginary
    assert "constraints: returns complex values at real x = [2.0, 0.0, 0.0]" in data_defect(fi, y)


def test_complex_velocity_constraints_are_called_complex():
    def A(x):
        x = np.asarray(x)
        one = np.ones_like(x[..., 0])
        return np.stack([one, 1j * one, 0 * one], -1)[..., None, :]  # a.a = 0: "unit" scaling divides by 0

    with pytest.raises(ValueError, match=r"A: returns complex values at real x = \[0.0, 0.0, 0.0\].*real for real x"):
        liefi.NonholonomicSystem.from_velocity_constraints(liefi.CotangentBundle(3), np.eye(3), A)


def test_from_sympy_refuses_strings_and_never_runs_them(monkeypatch):
    sympy = pytest.importorskip("sympy")
    monkeypatch.delenv("LIEFI_TEST_RAN", raising=False)
    x, y, xd, yd = sympy.symbols("x y xd yd")
    code = "__import__('os').environ.__setitem__('LIEFI_TEST_RAN', '1') or xd**2/2 + yd**2/2"
    with pytest.raises(TypeError, match=r"L: got a string.*sympy expressions only.*parse_expr"):
        liefi.from_sympy(code, [x, y], [xd, yd])
    for constraints in (code, [code]):
        with pytest.raises(TypeError, match=r"constraints(\[0\])?: got a string"):
            liefi.from_sympy(xd**2 / 2 + yd**2 / 2, [x, y], [xd, yd], constraints)
    assert "LIEFI_TEST_RAN" not in os.environ
