"""The ``liefi`` command and ``liefi reproduce`` can be trusted with a user's folders and time.

* outputs are checked before any work; liefi writes only into a new or empty
  folder or one it owns (``liefi-manifest.json``): stale figures go, a user's
  files stay;
* ``--out DIR`` on ``liefi run`` writes ``DIR/SCENE.png`` and says so;
* SIGINT prints one line, exits 130 and leaves a consistent summary;
* ``--version``, ``--out`` on every command, ``--jobs`` >= 1, flags for what the
  messages advise, a hint to install ``liefi[plot]``;
* ``liefi run --json`` carries the version, the backend, the reference method,
  the warnings, ``cpu_seconds`` and ``overhead_seconds``;
* the README's ``liefi run ... --plot`` example works.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time

import pytest

import liefi
from liefi import cli, reproduce, scenes

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run_cli(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _one_error_line(err, word):
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("liefi: error:")]
    assert len(lines) == 1 and word in lines[0], err
    assert "Traceback" not in err


def _no_run(monkeypatch):
    """Fail the test if a scene is run (outputs must be refused before any work)."""

    def boom(self, **kw):
        raise AssertionError("a scene was run before the output was checked")

    monkeypatch.setattr(scenes.Scene, "run", boom)


# --------------------------------------------------------------------------------------
# outputs
# --------------------------------------------------------------------------------------
def test_reproduce_refuses_an_unusable_out_before_any_work(capsys, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    _no_run(monkeypatch)
    a_file = tmp_path / "file"
    a_file.write_text("mine")
    for out in (a_file, a_file / "sub"):
        code, _, err = run_cli(capsys, "reproduce", "--only", "suslov", "--out", str(out))
        assert code == 2
        _one_error_line(err, "out")
    assert a_file.read_text() == "mine"


def test_reproduce_refuses_a_folder_it_does_not_own(capsys, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    _no_run(monkeypatch)
    d = tmp_path / "mine"
    d.mkdir()
    (d / "notes.txt").write_text("keep me")
    code, _, err = run_cli(capsys, "reproduce", "--only", "suslov", "--out", str(d))
    assert code == 2
    _one_error_line(err, "out")
    assert "not empty" in err
    assert sorted(os.listdir(d)) == ["notes.txt"] and (d / "notes.txt").read_text() == "keep me"


def test_reproduce_rerun_removes_stale_figures_and_keeps_user_files(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    d = tmp_path / "out"
    code, _, err = run_cli(capsys, "reproduce", "--only", "suslov", "--out", str(d), "--t-final-scale", "0.01",
                           "--jobs", "1")
    assert code == 0, err
    assert (d / "figure_Suslov_Pi_exact.png").exists()
    manifest = json.loads((d / reproduce.MANIFEST).read_text())
    assert "figure_Suslov_Pi_exact.png" in manifest["files"] and "summary.json" in manifest["files"]
    (d / "my-notes.txt").write_text("keep me")  # the user's, not in the manifest
    (d / "knife-edge-extended.png").write_text("not a figure of liefi's")  # would clash? (not a name used)
    code, _, err = run_cli(capsys, "reproduce", "--only", "knife-edge", "--out", str(d), "--t-final-scale", "0.001",
                           "--jobs", "1")
    assert code == 0, err
    names = set(os.listdir(d))
    assert not any(n.startswith("figure_Suslov") for n in names)  # nothing stale mixed in
    assert {"figure_knife_cycloid.png", "summary.json", "summary.md", "my-notes.txt"} <= names
    assert (d / "my-notes.txt").read_text() == "keep me"
    summary = json.loads((d / "summary.json").read_text())
    assert {r["scene"] for r in summary["runs"]} == {"knife-edge"}
    assert set(summary["figures"]) <= names


def test_reproduce_never_overwrites_a_file_it_did_not_write(tmp_path):
    pytest.importorskip("matplotlib")
    d = tmp_path / "out"
    out = reproduce.prepare_output(str(d))
    (d / "figure_Suslov_Pi_exact.png").write_text("the user's")
    with pytest.raises(reproduce.OutputError, match="out"):
        out.claim("figure_Suslov_Pi_exact.png")
    summary = reproduce.reproduce(str(d), only=["suslov"], t_final_scale=0.01, jobs=1)
    assert (d / "figure_Suslov_Pi_exact.png").read_text() == "the user's"
    assert any("figure_Suslov_Pi_exact.png" in f.get("error", "") for f in summary["failures"])


def test_run_out_is_checked_before_the_run(capsys, tmp_path, monkeypatch):
    """A folder that cannot be made (a file stands in its way) is refused before any work."""
    pytest.importorskip("matplotlib")
    _no_run(monkeypatch)
    (tmp_path / "afile").write_text("x")
    code, _, err = run_cli(capsys, "run", "suslov", "--out", str(tmp_path / "afile" / "x.png"))
    assert code == 2
    _one_error_line(err, "out")
    assert "not a folder" in err


@pytest.mark.parametrize("form", ["folder/", "folder/fig.png"])
def test_run_out_creates_a_missing_folder_as_bench_and_reproduce_do(capsys, tmp_path, form):
    """``--out figs/`` or ``--out figs/x.png`` whose folder does not exist: created (with its parents),
    as ``liefi bench`` and ``liefi reproduce`` create theirs; not taken for ``figs/.png``."""
    pytest.importorskip("matplotlib")
    target = str(tmp_path / "new" / "deeper") + "/" + form
    code, out, err = run_cli(capsys, "run", "knife-edge", "--t-final", "0.05", "--out", target)
    assert code == 0, err
    written = tmp_path / "new" / "deeper" / ("folder/knife-edge.png" if form.endswith("/") else form)
    assert written.is_file() and str(written) in out


def test_run_out_into_a_folder_writes_and_reports_the_file(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    d = tmp_path / "figs"
    d.mkdir()
    code, out, err = run_cli(capsys, "run", "knife-edge", "--t-final", "0.05", "--plot", str(d))
    assert code == 0, err
    assert os.listdir(d) == ["knife-edge.png"] and not (tmp_path / "figs.png").exists()
    assert f"figure written to {d / 'knife-edge.png'}" in out
    code, out, err = run_cli(capsys, "run", "knife-edge", "--t-final", "0.05", "--json", "--out", str(tmp_path / "k"))
    assert code == 0, err
    assert json.loads(out)["plot"] == str(tmp_path / "k.png") and (tmp_path / "k.png").exists()


def test_missing_matplotlib_gives_the_install_hint(capsys, tmp_path, monkeypatch):
    _no_run(monkeypatch)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    code, _, err = run_cli(capsys, "run", "suslov", "--out", str(tmp_path / "x.png"))
    assert code == 2
    _one_error_line(err, "liefi[plot]")
    code, _, err = run_cli(capsys, "reproduce", "--only", "suslov", "--out", str(tmp_path / "o"))
    assert code == 2
    _one_error_line(err, "liefi[plot]")


# --------------------------------------------------------------------------------------
# interrupts
# --------------------------------------------------------------------------------------
def test_keyboard_interrupt_is_one_line_and_exit_130(capsys, monkeypatch):
    from liefi import bench

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(scenes.Scene, "run", interrupted)
    code, out, err = run_cli(capsys, "run", "suslov")
    assert code == 130 and err.strip().startswith("liefi: interrupted") and len(err.strip().splitlines()) == 1
    monkeypatch.setattr(bench, "run_from_args", interrupted)
    code, out, err = run_cli(capsys, "bench", "suslov")
    assert code == 130 and err.strip().startswith("liefi: interrupted") and "Traceback" not in err


def test_reproduce_interrupted_keeps_a_summary_of_what_finished(capsys, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    real = reproduce._scene_job

    def job(task):
        if task[0] == "knife-edge":
            raise KeyboardInterrupt
        return real(task)

    monkeypatch.setattr(reproduce, "_scene_job", job)
    monkeypatch.setattr(reproduce, "_weight", lambda name: {"suslov": 2.0, "knife-edge": 1.0}.get(name, 0.0))
    d = tmp_path / "out"
    code, out, err = run_cli(capsys, "reproduce", "--only", "suslov,knife-edge", "--out", str(d),
                             "--t-final-scale", "0.01", "--jobs", "1")
    assert code == 130
    assert err.strip().splitlines()[-1].startswith("liefi: interrupted") and "Traceback" not in err
    summary = json.loads((d / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["not_run"] == ["knife-edge"]
    assert {r["scene"] for r in summary["runs"]} == {"suslov"}
    assert all((d / f).exists() for f in summary["figures"])
    md = (d / "summary.md").read_text()
    assert "Interrupted" in md and md.count("| suslov |") == len(summary["runs"])


def test_sigint_on_reproduce_exits_130_with_a_consistent_summary(tmp_path):
    """A real SIGINT to a running ``liefi reproduce`` (worker processes included)."""
    pytest.importorskip("matplotlib")
    d = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "liefi", "reproduce", "--out", str(d), "--t-final-scale", "0.02",
         "--only", "suslov,chaplygin,knife-edge,heisenberg,vertical-disk", "--jobs", "2"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    deadline = time.time() + 240
    summary_path = d / "summary.json"
    while time.time() < deadline and proc.poll() is None:
        if summary_path.exists():  # a first scene finished
            break
        time.sleep(0.2)
    if proc.poll() is not None:
        pytest.skip("reproduce finished before it could be interrupted")
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    assert [ln for ln in err.splitlines() if ln.startswith("liefi: ")][-1].startswith("liefi: interrupted")
    summary = json.loads(summary_path.read_text())
    assert summary["interrupted"] is True and summary["runs"]
    done = {r["scene"] for r in summary["runs"]}
    assert done and not (done & set(summary["not_run"]))
    assert all((d / f).exists() for f in summary["figures"])
    manifest = json.loads((d / reproduce.MANIFEST).read_text())
    assert set(summary["figures"]) <= set(manifest["files"])


# --------------------------------------------------------------------------------------
# flags and JSON
# --------------------------------------------------------------------------------------
def test_version(capsys):
    code, out, err = run_cli(capsys, "--version")
    assert code == 0 and out.strip() == f"liefi {liefi.__version__}"


def test_out_everywhere_and_jobs_refused(capsys):
    p = cli.build_parser()
    assert p.parse_args(["stability", "suslov", "--out", "m.png"]).out == "m.png"
    assert p.parse_args(["stability", "suslov", "--plot", "m.png"]).out == "m.png"  # the old spelling still works
    assert p.parse_args(["run", "suslov", "--out", "r.png"]).out == "r.png"
    assert p.parse_args(["reproduce", "--out", "d"]).out == "d"
    for argv in (["stability", "suslov", "--jobs", "0"], ["stability", "suslov", "--jobs", "-3"],
                 ["reproduce", "--jobs", "0"], ["run", "suslov", "--save-every", "0"]):
        code, _, err = run_cli(capsys, *argv)
        assert code == 2
        _one_error_line(err, "jobs" if "--jobs" in argv else "save-every")
    with pytest.raises(ValueError, match="jobs"):
        reproduce.reproduce("unused", jobs=0)


def test_flags_for_what_the_messages_advise(capsys):
    code, out, err = run_cli(capsys, "run", "suslov", "--paper", "--t-final", "0.1", "--save-every", "10", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["steps"] == 100
    for flag in ("--no-check-stability", "--adaptive"):
        code, out, err = run_cli(capsys, "run", "suslov", "--t-final", "0.1", flag, "--json")
        assert code == 0, err
    code, out, err = run_cli(capsys, "run", "suslov", "--t-final", "0.1", "--scheme", "imex-euler", "--json")
    assert code == 0, err
    help_text = cli.build_parser()._subparsers._group_actions[0].choices["run"].format_help()
    for flag in ("--save-every", "--no-check-stability", "--adaptive", "--gains"):
        assert flag in help_text


def test_run_json_carries_version_backend_reference_warnings_and_costs(capsys, monkeypatch):
    import warnings

    from liefi.stability import LiefiStabilityWarning

    real = scenes.Scene.run

    def run(self, **kw):  # a warning raised during the run, as the stability guard raises them
        warnings.warn("dt*lambda_max = 2 is at the stability bound; use adaptive=True", LiefiStabilityWarning)
        return real(self, **kw)

    monkeypatch.setattr(scenes.Scene, "run", run)
    code, out, err = run_cli(capsys, "run", "knife-edge", "--t-final", "0.1", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["liefi_version"] == liefi.__version__
    assert d["backend"] in ("numpy", "numba")
    assert d["reference"] == "exact" and "exact" in d["reference_method"]
    assert d["warnings"] == ["LiefiStabilityWarning: dt*lambda_max = 2 is at the stability bound; use --adaptive"]
    assert "LiefiStabilityWarning" in err  # and on stderr, when raised
    assert d["cpu_seconds"] > 0 and d["overhead_seconds"] >= 0
    code, out, err = run_cli(capsys, "run", "oscillator", "--t-final", "0.1", "--json", "--backend", "numpy")
    d = json.loads(out)
    assert code == 0 and d["backend"] == "numpy" and "DOP853" in d["reference_method"]


def test_readme_run_example_with_a_figure_works(capsys, tmp_path, monkeypatch):
    """The README's ``liefi run ... --plot FILE`` example (on a short horizon) exits 0 and writes FILE."""
    pytest.importorskip("matplotlib")
    readme = open(os.path.join(ROOT, "README.md")).read()
    lines = [ln.split("#")[0].strip() for ln in readme.splitlines() if re.match(r"\s*liefi run .*--(plot|out) ", ln)]
    assert lines, "the README shows a liefi run with a figure"
    assert "../shared" not in readme
    monkeypatch.chdir(tmp_path)
    for line in lines:
        argv = shlex.split(line)[1:] + ["--t-final", "0.5"]
        code, out, err = run_cli(capsys, *argv)
        assert code == 0, (line, err)
        target = argv[argv.index("--plot" if "--plot" in argv else "--out") + 1]
        assert (tmp_path / target).exists(), line


def test_advice_names_flags_that_exist(capsys):
    """Past the stability limit (the README's example without --gains auto) the warning and the
    error advise ``liefi`` flags, and every flag they name exists."""
    code, out, err = run_cli(capsys, "run", "knife-edge", "--paper", "--variant", "original", "--scheme", "rk4",
                             "--dt", "1e-2", "--t-final", "1")
    assert code == 2 and "--gains auto" in err
    assert "gains='auto'" not in err and "adaptive=True" not in err
    run_parser = cli.build_parser()._subparsers._group_actions[0].choices["run"]
    known = set(run_parser._option_string_actions)
    for flag in set(re.findall(r"(?<![\w-])--[a-z][\w-]*", err)):
        assert flag in known, flag
    assert cli.as_flags("use check_stability=False or save_every=10") == "use --no-check-stability or --save-every 10"


def _check_run_steps(monkeypatch):
    """The steps of every check run the step choice makes (:class:`liefi.integrator._check_runs.CheckRuns`,
    the only integration before a run whose length follows the horizon), in a list."""
    from liefi.integrator._check_runs import CheckRuns

    steps, call = [], CheckRuns.__call__

    def counted(self, t0, tau, h, save_every):
        steps.append(tau / h)
        if sum(steps) > 1e6:  # fail now, not after the hours of the run
            raise AssertionError(f"a check run of {tau / h:.3g} steps before the refusal")
        return call(self, t0, tau, h, save_every)

    monkeypatch.setattr(CheckRuns, "__call__", counted)
    return steps


@pytest.mark.parametrize("argv", [["--dt", "1e-9"], ["--t-final", "1e9"]])
def test_runs_of_hours_are_refused_before_they_start(capsys, monkeypatch, argv):
    """No run and no check run of the horizon's length: at most the step choice's pilot (a fixed number of
    steps) before the refusal.  Counted, not timed: with a cold kernel cache the pilot's compile took 29 s of
    the 30 s the test allowed at a load of 18 on 2 cores."""
    _no_run(monkeypatch)
    monkeypatch.setenv("LIEFI_REFERENCE_STORE", "0")  # the pilot runs (a step stored before would skip it)
    steps = _check_run_steps(monkeypatch)
    code, out, err = run_cli(capsys, "run", "suslov", *argv)
    assert code == 2 and sum(steps) <= 1e6, steps  # the refused run: 2.6e10 steps at --t-final 1e9
    _one_error_line(err, "steps")
    assert "--max-steps" in err and "--dt" in err


def test_max_steps_lets_a_long_run_through(capsys):
    code, out, err = run_cli(capsys, "run", "suslov", "--paper", "--t-final", "0.2", "--max-steps", "100")
    assert code == 2 and "--max-steps" in err
    code, out, err = run_cli(capsys, "run", "suslov", "--paper", "--t-final", "0.2", "--max-steps", "1000", "--json")
    assert code == 0 and json.loads(out)["steps"] == 200


def test_stability_out_is_checked_before_any_work(capsys, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    from liefi.experiments import stability_cli

    def boom(args):
        raise AssertionError("the map was computed before its output was checked")

    monkeypatch.setattr(stability_cli, "command", boom)
    (tmp_path / "afile").write_text("x")  # a folder that cannot be made (a missing one is created)
    code, _, err = run_cli(capsys, "stability", "suslov", "--out", str(tmp_path / "afile" / "map.png"))
    assert code == 2
    _one_error_line(err, "out")
    seen = {}
    monkeypatch.setattr(stability_cli, "command", lambda args: seen.setdefault("plot", args.out) and 0)
    assert cli.main(["stability", "suslov", "--out", str(tmp_path)]) == 0
    assert seen["plot"] == str(tmp_path / "suslov-stability.png")
