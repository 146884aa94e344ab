"""The ``liefi`` command line: list, run (report, --json, --gains, errors, --plot), reproduce.

Fast: every run is short (``--t-final`` of a fraction of a second, or
``reproduce --t-final-scale``).  ``main(argv)`` is called in-process where we
only need its exit code and output; a subprocess checks what is imported.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from liefi import cli
from liefi import scenes

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

REQUIRED_KEYS = {"scene", "scheme", "dt", "t_final", "steps", "cpu_seconds", "max_error", "max_drift", "reference"}


def run_cli(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def run_json(capsys, *argv):
    code, out, err = run_cli(capsys, "run", *argv, "--json")
    assert code == 0, err
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert len(lines) == 1, out  # ONE JSON object
    return json.loads(lines[0])


def test_list_names_every_scene(capsys):
    code, out, err = run_cli(capsys, "list")
    assert code == 0, err
    listed = [ln.split()[0] for ln in out.splitlines() if ln and not ln[0].isspace()]
    assert listed == scenes.names()
    assert len(listed) == len(scenes.REGISTRY) >= 8
    suslov = next(ln for ln in out.splitlines() if ln.startswith("suslov"))
    assert "Sec. 3.1" in suslov and "extended" in suslov and "original" in suslov


def test_run_json_keys_and_values(capsys):
    d = run_json(capsys, "suslov", "--t-final", "0.5", "--paper")  # the paper's settings
    assert REQUIRED_KEYS <= set(d)
    assert d["scene"] == "suslov" and d["scheme"] == "euler" and d["reference"] == "exact"
    assert d["dt"] == 1e-3 and d["t_final"] == 0.5 and d["steps"] == 500
    assert d["cpu_seconds"] > 0
    assert set(d["max_error"]) == {"Pi_1", "Pi_2", "Pi_3"}
    assert all(0 <= v < 1e-3 for v in d["max_error"].values())
    # every constraint momentum and the energy
    assert {"J_1", "h"} <= set(d["max_drift"])
    assert all(0 <= v < 1e-3 for v in d["max_drift"].values())


def test_run_report_is_human_readable(capsys):
    code, out, err = run_cli(capsys, "run", "suslov", "--t-final", "0.2")
    assert code == 0, err
    assert "CPU time" in out and "exact solution" in out and "Pi_1" in out and "J_1" in out


def test_run_configuration_adds_orthogonality(capsys):
    d = run_json(capsys, "suslov", "--t-final", "0.2", "--configuration")
    assert "orthogonality" in d["max_drift"] and d["max_drift"]["orthogonality"] < 1e-4
    assert set(d["gains"]) == {"penalty", "J_1", "energy"}


@pytest.mark.parametrize(
    "gains, expected",
    [
        ("7", {"J_1": 7.0, "energy": 7.0}),
        ("7,9", {"J_1": 7.0, "energy": 9.0}),  # the order of invariant_names
        ("energy=9", {"J_1": 100.0, "energy": 9.0}),  # the others keep the paper's value
        ("constraints=3,energy=4", {"J_1": 3.0, "energy": 4.0}),
    ],
)
def test_run_gains_forms(capsys, gains, expected):
    d = run_json(capsys, "suslov", "--t-final", "0.1", "--gains", gains)
    assert d["gains"] == expected


def test_gains_order_follows_invariant_names(capsys):
    scene = scenes.get("suslov")
    names = scene.integrator(configuration=True).invariant_names
    d = run_json(capsys, "suslov", "--t-final", "0.1", "--configuration", "--gains", "1,2,3")
    assert d["gains"] == dict(zip(names, (1.0, 2.0, 3.0)))


@pytest.mark.parametrize(
    "argv, word",
    [
        (["run", "no-such-scene"], "scene"),
        (["run", "suslov", "--variant", "nope"], "variant"),
        (["run", "suslov", "--gains", "1,2,3"], "gains"),
        (["run", "suslov", "--gains", "abc"], "gains"),
        (["run", "suslov", "--gains", "k9=1"], "gains"),
        (["run", "suslov", "--gains", "-1"], "gains"),
        (["run", "suslov", "--dt", "0"], "dt"),
        (["run", "suslov", "--t-final", "x"], "t-final"),
        (["run", "suslov", "--scheme", "leapfrog"], "scheme"),
        (["run", "suslov", "--scheme", "scipy:Nope"], "scheme"),
        (["reproduce", "--only", "nope"], "only"),
        (["frobnicate"], "COMMAND"),
    ],
)
def test_bad_input_exits_2_with_one_line(capsys, argv, word):
    code, out, err = run_cli(capsys, *argv)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("liefi: error:") and word in lines[0]
    assert "Traceback" not in err


def test_gains_error_shows_the_order(capsys):
    code, _, err = run_cli(capsys, "run", "suslov", "--gains", "1,2,3")
    assert code == 2 and "J_1,energy" in err


def test_diverging_run_exits_2(capsys):
    # Euler far beyond its stability limit: refused up front or stopped when it
    # blows up -- either way one line, no traceback
    code, out, err = run_cli(capsys, "run", "suslov", "--paper", "--t-final", "1", "--gains", "1e7")
    assert code == 2
    assert err.startswith("liefi: error:") and len(err.strip().splitlines()) == 1


def test_integration_error_exits_2(capsys, monkeypatch):
    from liefi.schemes import IntegrationError

    def boom(self, **kw):
        raise IntegrationError("integration with euler produced non-finite values at step 7", 0.006, 7, None, ["Pi_1"])

    monkeypatch.setattr(type(scenes.get("suslov")), "run", boom)
    code, out, err = run_cli(capsys, "run", "suslov", "--t-final", "0.1")
    assert code == 2 and out == ""
    assert err.strip() == "liefi: error: integration with euler produced non-finite values at step 7"


def test_run_plot_writes_png(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "suslov.png"
    code, out, err = run_cli(capsys, "run", "suslov", "--t-final", "0.2", "--plot", str(png))
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the Suslov figure needs R(t): --plot integrates the configuration
    assert "orthogonality" in out


def test_reproduce_only_suslov(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    out_dir = tmp_path / "out"
    code, out, err = run_cli(capsys, "reproduce", "--only", "suslov", "--out", str(out_dir), "--t-final-scale", "0.02")
    assert code == 0, err
    pngs = sorted(p.name for p in out_dir.glob("*.png"))
    assert "figure_Suslov_Pi_exact.png" in pngs and "figure_Suslov_integrals.png" in pngs
    assert len(pngs) == 2 * len(scenes.get("suslov").variants)
    summary = json.loads((out_dir / "summary.json").read_text())
    runs = summary["runs"]
    assert {r["variant"] for r in runs} == set(scenes.get("suslov").variants)
    for r in runs:
        assert r["status"] == "ok" and r["max_error"] and "J_1" in r["max_drift"] and r["cpu_seconds"] > 0
    md = (out_dir / "summary.md").read_text()
    assert md.startswith("| scene |") and "suslov" in md
    assert "| scene |" in out  # the table is printed at the end
    assert "suslov" in err  # progress on stderr


def _modules_after(code):
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60
    )
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_import_liefi_does_not_import_matplotlib():
    out = _modules_after("import sys, liefi, liefi.cli, liefi.plotting, liefi.reproduce; print('matplotlib' in sys.modules)")
    assert out.strip() == "False"


def test_run_json_does_not_import_matplotlib():
    code = (
        "import sys, io, contextlib\n"
        "from liefi.cli import main\n"
        "buf = io.StringIO()\n"
        "with contextlib.redirect_stdout(buf):\n"
        "    rc = main(['run', 'suslov', '--t-final', '0.1', '--json'])\n"
        "assert rc == 0\n"
        "print(any(m == 'matplotlib' or m.startswith('matplotlib.') for m in sys.modules))\n"
    )
    assert _modules_after(code).strip() == "False"


def test_python_dash_m_liefi():
    r = subprocess.run(
        [sys.executable, "-m", "liefi", "run", "suslov", "--paper", "--t-final", "0.1", "--json"],
        capture_output=True, text=True, cwd=ROOT, timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["steps"] == 100
    r = subprocess.run([sys.executable, "-m", "liefi", "run", "suslov", "--variant", "x"],
                       capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "variant" in r.stderr


def test_list_verbose_shows_gain_order(capsys):
    code, out, err = run_cli(capsys, "list", "-v")
    assert code == 0, err
    assert "--gains order: J_1,energy" in out


def test_oscillator_dla_and_plot(capsys, tmp_path):
    """The oscillator's extra scheme and its figures (figure:oscillator, figure:Poincare:FI)."""
    pytest.importorskip("matplotlib")
    d = run_json(capsys, "oscillator", "--scheme", "dla", "--t-final", "0.5")
    assert d["scheme"] == "dla" and d["reference"] == "numerical" and "H_y" in d["max_drift"]
    png = tmp_path / "osc.png"
    # t in [0, 7] holds one upward crossing of y = cos t (t = 3 pi / 2)
    code, out, err = run_cli(capsys, "run", "oscillator", "--t-final", "7", "--plot", str(png))
    assert code == 0, err
    assert png.stat().st_size > 10_000


def test_stability_warning_is_printed_before_the_run(capsys):
    """Issue 5's must-show: past the limit liefi warns on stderr *before* running, with the safe dt."""
    from liefi.cli import main

    code = main(["run", "knife-edge", "--paper", "--gains", "1100", "--t-final", "10", "--json"])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and "LiefiStabilityWarning" in lines[0]
    assert "Largest safe dt" in lines[0] and "largest safe gain" in lines[0]
    assert "liefi: liefi:" not in err
    assert code in (0, 2)


def test_stability_and_bench_commands(capsys, tmp_path):
    import json

    from liefi.cli import main

    assert main(["stability", "suslov", "--estimate", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["scene"] == "suslov" and 0 < out["estimate"]["ratio"] < 1
    assert main(["bench", "no-such-scene"]) == 2
    assert "scene" in capsys.readouterr().err
