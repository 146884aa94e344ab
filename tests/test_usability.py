"""The small things a user trips on at the command line (each failed before its fix)."""

from __future__ import annotations

import json

import pytest

from liefi import cli, reproduce, scenes
from liefi.schemes import names as scheme_names


def run_cli(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def _no_run(monkeypatch):
    def boom(self, **kw):
        raise AssertionError("a scene was run although its arguments were refused")

    monkeypatch.setattr(scenes.Scene, "run", boom)


# --------------------------------------------------------------------------------------
# a negative number for a numeric option reaches the option's own check
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, word", [
    (("run", "suslov", "--dt", "-1e-3"), "dt must be a positive number"),
    (("run", "suslov", "--t-final", "-5"), "t-final must be a positive number"),
    (("run", "suslov", "--dt", "-.5E+2"), "dt must be a positive number"),
    (("bench", "suslov", "--t-final", "-1e3", "--out", "unused"), "--t-final"),
])
def test_a_negative_number_is_refused_by_its_option_not_taken_for_an_option(capsys, monkeypatch, argv, word):
    _no_run(monkeypatch)
    code, _, err = run_cli(capsys, *argv)
    assert code == 2
    assert "expected one argument" not in err and word in err, err
    assert len(err.strip().splitlines()) == 1


def test_a_negative_number_as_a_positional_or_after_a_flag_is_left_alone(capsys, monkeypatch):
    _no_run(monkeypatch)
    code, _, err = run_cli(capsys, "run", "-1e-3")
    assert code == 2 and "unknown scene" not in err  # argparse's own complaint, not a joined option
    assert cli.build_parser()._join_negative(["--json", "-1"]) == ["--json", "-1"]  # a flag takes no value


# --------------------------------------------------------------------------------------
# did you mean
# --------------------------------------------------------------------------------------
def test_a_misspelled_scene_gets_the_closest_names():
    with pytest.raises(ValueError, match=r"did you mean 'suslov'\?"):
        scenes.get("suslv")
    with pytest.raises(ValueError, match=r"did you mean 'knife-edge'"):
        scenes.get("knife_edge")
    with pytest.raises(ValueError) as exc:
        scenes.get("zzzzzz")
    assert "did you mean" not in str(exc.value) and "suslov" in str(exc.value)


@pytest.mark.parametrize("argv", [("run", "suslv"), ("bench", "suslv"), ("reproduce", "--only", "suslov,knife")])
def test_every_command_says_did_you_mean(capsys, monkeypatch, argv):
    _no_run(monkeypatch)
    code, _, err = run_cli(capsys, *argv)
    assert code == 2 and "did you mean" in err, err


# --------------------------------------------------------------------------------------
# help that tells the truth
# --------------------------------------------------------------------------------------
def test_bench_help_names_the_schemes_it_accepts(capsys):
    code, out, _ = run_cli(capsys, "bench", "--help")
    assert code == 0
    text = " ".join(out.split()).replace("- ", "-")  # argparse wraps at hyphens
    for name in scheme_names("explicit") + scheme_names("split"):
        assert name in text, name
    assert "liefi list --schemes" in text  # and the command it names lists them
    code, out, _ = run_cli(capsys, "list", "--schemes")
    assert code == 0
    listed = {ln.split()[0] for ln in out.splitlines() if ln.strip()}
    assert set(scheme_names("explicit") + scheme_names("split")) <= listed


def test_plain_run_says_which_gain_was_dropped(capsys):
    """roller-racer: ``J_2`` is kept exactly by Euler and left out of ``V``; the report says so."""
    sc = scenes.get("roller-racer")
    result = sc.run(t_final=0.02)
    assert [d["name"] for d in result.dropped] == ["J_2"]
    cli.report(result)
    out = capsys.readouterr().out
    gains = next(ln for ln in out.splitlines() if ln.strip().startswith("gains"))
    assert "J_2=0 (kept exactly by euler; dropped from V)" in gains
    assert "J_1=100," in gains and "J_1=100 (" not in gains


# --------------------------------------------------------------------------------------
# figures and summaries
# --------------------------------------------------------------------------------------
def _texts(fig):
    out = [t.get_text() for t in fig.texts]
    if getattr(fig, "_suptitle", None) is not None:
        out.append(fig._suptitle.get_text())
    out += [ax.get_title() for ax in fig.axes]
    return " ".join(out)


def test_figure_titles_carry_no_latex_label_and_name_the_variant_once():
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    knife = scenes.get("knife-edge")
    r = knife.run(t_final=0.05, configuration=True)
    for spec in knife.figures(r, tag=" [variant original]"):
        fig = spec.draw(None)
        assert "figure:" not in _texts(fig) and "Fig. " not in _texts(fig), spec.key
        plt.close(fig)
    heis = scenes.get("heisenberg")
    r = heis.run(t_final=0.05, variant="generic")
    (spec,) = heis.figures(r, tag=reproduce._tag("generic", "special"))
    fig = spec.draw(None)
    assert fig._suptitle.get_text().count("generic") == 1, fig._suptitle.get_text()
    plt.close(fig)


def test_summary_md_shows_the_cpu_time_of_a_millisecond_run():
    row = {"scene": "s", "variant": "v", "experiment": "paper", "scheme": "euler", "dt": 1e-3, "t_final": 1.0,
           "steps": 1000, "cpu_seconds": 0.00123, "reference": "exact", "max_error": {}, "max_drift": {},
           "status": "ok"}
    summary = {"runs": [row], "figures": [], "failures": [], "wall_seconds": 1.0, "cpu_seconds": 1.0,
               "t_final_scale": 1.0}
    line = next(ln for ln in reproduce.markdown_table(summary).splitlines() if ln.startswith("| s |"))
    assert "| 0.00123 |" in line


def test_reproduce_interrupted_inside_a_scene_summarizes_its_finished_runs(capsys, tmp_path, monkeypatch):
    """Ctrl-C during knife-edge's second variant: its first run and figures are in the summary."""
    pytest.importorskip("matplotlib")
    real, calls = reproduce._run_one, []

    def run_one(scene, variant, *a, **k):
        calls.append(variant)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(scene, variant, *a, **k)

    monkeypatch.setattr(reproduce, "_run_one", run_one)
    d = tmp_path / "out"
    code, _, err = run_cli(capsys, "reproduce", "--only", "knife-edge", "--out", str(d),
                           "--t-final-scale", "0.01", "--jobs", "1")
    assert code == 130
    summary = json.loads((d / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["not_run"] == [] and summary["unfinished"] == ["knife-edge"]
    assert [(r["scene"], r["variant"], r["status"]) for r in summary["runs"]] == [("knife-edge", "extended", "ok")]
    assert len(summary["figures"]) == 3 and all((d / f).exists() for f in summary["figures"])
    md = (d / "summary.md").read_text()
    assert "1 runs, 3 figures" in md and "Interrupted" in md and "Cut short" in md
    # a finished reproduction leaves no partial record behind
    monkeypatch.setattr(reproduce, "_run_one", real)
    code, _, _ = run_cli(capsys, "reproduce", "--only", "heisenberg", "--out", str(d / "again"),
                         "--t-final-scale", "0.01", "--jobs", "1")
    assert code == 0 and not [p for p in (d / "again").iterdir() if "partial" in p.name]
