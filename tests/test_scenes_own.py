"""Scenes own what is particular to them; plotting, reproduce and the CLI are generic.

* no scene name in any module outside ``liefi/scenes/`` (``plotting``, ``reproduce``,
  ``cli``, the experiments, bench, ...);
* every scene's figures come from ``Scene.figures`` and draw;
* whether the figures need the configuration is the scene's attribute, and the
  CLI asks it;
* the numerical reference is computed once per start (``liefi reproduce``
  integrates the oscillator's once, not once per run) and agrees with a direct
  ``solve_ivp`` on the same times;
* the stability battery's scene cases and the stiff study's scene are scene data.
"""

from __future__ import annotations

import ast
import json
import os

import numpy as np
import pytest

from liefi import cli, scenes
from liefi.scenes import PaperRun, Scene

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: every module of liefi outside liefi/scenes/ (the CLI included: its help texts may cite a
#: scene inside a longer string, never as a value of its own)
GENERIC = sorted(
    os.path.relpath(os.path.join(d, f), ROOT)
    for d, _, files in os.walk(os.path.join(ROOT, "liefi"))
    if os.path.relpath(d, ROOT).split(os.sep)[:2] != ["liefi", "scenes"]
    for f in files
    if f.endswith(".py")
)


def test_the_scan_covers_the_generic_modules():
    assert {"liefi/results/scene_figures.py", "liefi/reproduce.py", "liefi/cli.py", "liefi/experiments/battery.py",
            "liefi/bench/core.py"} <= set(GENERIC)
    assert not any(p.startswith("liefi/scenes/") for p in GENERIC)


@pytest.mark.parametrize("path", GENERIC)
def test_no_scene_name_in_generic_modules(path):
    """No string constant in liefi outside ``scenes/`` is a scene name (help texts may cite one)."""
    names = set(scenes.names())
    tree = ast.parse(open(os.path.join(ROOT, path)).read())
    hits = [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in names
    ]
    assert hits == [], f"{path} names scenes: {hits}"


def _short(scene, **kw):
    return scene.run(t_final=20 * scene.dt, **kw)


@pytest.mark.parametrize("name", scenes.names())
def test_every_scene_draws_its_figures(name):
    pytest.importorskip("matplotlib")
    from liefi import plotting

    sc = scenes.get(name)
    cfg = True if sc.figures_need_configuration else None
    r = _short(sc, configuration=cfg)
    specs = sc.figures(r)
    assert specs and all(isinstance(s, plotting.FigureSpec) for s in specs)
    for s in specs:
        fig = s.draw(None)
        assert fig.get_axes(), s.key
    # a mapping of labelled runs is accepted too
    assert [s.key for s in sc.figures({"paper": r})] == [s.key for s in specs]


def test_paper_figures_are_the_scenes():
    pytest.importorskip("matplotlib")
    sus = scenes.get("suslov")
    r = _short(sus, configuration=True)
    assert [s.key for s in sus.figures(r)] == ["figure:Suslov_Pi_exact", "figure:Suslov_integrals"]
    assert sus.figures_need_configuration and not scenes.get("knife-edge").figures_need_configuration
    assert [s.key for s in scenes.get("chaplygin").figures(_short(scenes.get("chaplygin")))] == ["generic"]


def test_a_new_scene_gets_the_generic_figure_and_one_paper_run():
    """A user scene supplies data only and still works with the generic tools."""
    pytest.importorskip("matplotlib")

    class Mine(type(scenes.get("heisenberg"))):
        name = "mine"

    sc = Mine()
    assert sc.paper_runs(sc.variant()) == (PaperRun(),)
    assert [s.key for s in sc.figures(_short(sc))] == ["generic"]
    assert Scene.stability_cases == ()


def test_cli_asks_the_scene_whether_figures_need_the_configuration(capsys, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    cls = type(scenes.get("roller-racer"))
    code = cli.main(["run", "roller-racer", "--t-final", "0.02", "--json", "--out", str(tmp_path / "a.png")])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["configuration"] is False and "x" not in d["max_error"]
    monkeypatch.setattr(cls, "figures_need_configuration", True)
    code = cli.main(["run", "roller-racer", "--t-final", "0.02", "--json", "--out", str(tmp_path / "b.png")])
    d = json.loads(capsys.readouterr().out)
    assert code == 0 and d["configuration"] is True and {"x", "y", "theta"} <= set(d["max_error"])


def test_oscillator_reference_is_computed_once_per_start(tmp_path):
    """``liefi reproduce`` integrates the oscillator's reference once (both variants share the
    start; the longest horizon first), not once per run."""
    pytest.importorskip("matplotlib")
    from liefi import reproduce

    sc = scenes.get("oscillator")
    sc.__dict__.pop("_refcache", None)
    summary = reproduce.reproduce(str(tmp_path / "out"), only=["oscillator"], t_final_scale=0.005, jobs=1)
    assert not summary["failures"]
    assert len(summary["runs"]) == 6  # FI and DLA, short and long; DLA once for both variants
    cache = sc.__dict__["_refcache"]
    assert len(cache) == 1
    (T, _, _), = cache.values()
    assert T == pytest.approx(400 * 0.005)
    ref = [r for r in summary["runs"] if r["reference_seconds"] > 0]
    assert ref == []  # computed before the runs, not inside one
    refs = summary["references"]  # ... and its cost is in the summary: paid by the first variant only
    assert [(r["variant"], r["reused"]) for r in refs] == [("extended", False), ("original", True)]
    assert refs[0]["seconds"] > 0 and "DOP853" in refs[0]["method"]


def test_dense_reference_agrees_with_a_direct_solve(monkeypatch):
    """The cached dense reference at any times agrees with ``solve_ivp(t_eval=...)`` on the
    numpy constrained field (the old per-call reference)."""
    from scipy.integrate import solve_ivp

    from liefi.reduction import core

    sc = scenes.get("oscillator")
    sc.__dict__.pop("_refcache", None)
    v = sc.variant()
    sc.reference_solution(v, 3.0)
    t = np.linspace(0.0, 2.0, 201)
    got = sc.numerical_reference(t, v)
    y0 = np.asarray(sc.initial_state(v), float)
    sol = solve_ivp(lambda _t, y: core.full_vector_field(sc.system, y, kind="constrained"), (0.0, 2.0), y0,
                    method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t)
    for i, n in enumerate(sc.system.state_names):
        np.testing.assert_allclose(got[n], sol.y[i], atol=1e-10)
    with pytest.raises(ValueError, match="t"):
        sc.reference_solution(v, 3.0)(np.array([5.0]))


def test_reproduce_runs_the_papers_scenes_by_default():
    from liefi import reproduce

    paper = reproduce.paper_scenes()
    assert paper[:8] == ["suslov", "knife-edge", "chaplygin", "chaplygin-so2", "vertical-disk", "roller-racer",
                         "heisenberg", "oscillator"]
    assert all(scenes.get(n).in_paper for n in paper)
    assert [n for n in scenes.names() if n not in paper] == [n for n in scenes.names() if not scenes.get(n).in_paper]


def test_stability_cases_are_scene_data():
    assert scenes.get("roller-racer").stability_cases == ("near-singular",)
    assert scenes.get("heisenberg").stability_cases == ("far from origin",)
    assert scenes.get("heisenberg").stability_variant == "generic"
    assert scenes.get("suslov").stability_cases == ()
    # the stiff work-precision study of the stability report runs on the scene that says so
    assert [n for n in scenes.names() if scenes.get(n).stiff_study] == ["knife-edge"]
