"""The house's layout (issue 24): one subpackage per stage of the flow, the old flat names kept.

Run alone: ``python -m pytest -q tests/test_layout.py``.
"""
from __future__ import annotations

import importlib
import pathlib

import pytest

import liefi

ROOT = pathlib.Path(liefi.__file__).parent

#: every public module a user imported by its flat name before the subpackages, and where it lives now
FLAT = {"system": "systems.system", "sympy_input": "systems.sympy_input", "mechanics": "systems.mechanics",
        "rolling": "systems.rolling", "feedback": "integrator.feedback", "run": "integrator.run",
        "policy": "integrator.policy", "tolerance": "integrator.tolerance", "gains": "integrator.gains",
        "guard": "integrator.guard", "stability": "integrator.stability", "drift": "integrator.drift",
        "dense": "integrator.dense", "dla": "schemes.dla_integrator", "export": "schemes.export",
        "plot": "results.plot", "plotting": "results.scene_figures", "sweep": "results.sweep"}


@pytest.mark.parametrize("old", sorted(FLAT))
def test_the_flat_names_still_import_the_same_module(old):
    """``liefi.gains``, ``import liefi.plot``, ``from liefi.rolling import sphere``: one module under both names."""
    new = importlib.import_module(f"liefi.{FLAT[old]}")
    assert importlib.import_module(f"liefi.{old}") is new
    assert getattr(liefi, old) is new
    assert new.__spec__.name == new.__name__ == f"liefi.{FLAT[old]}"  # the module keeps its own name
    ns = {}
    exec(f"from liefi.{old} import *", ns)  # noqa: S102 -- the old spelling of a user's import
    assert ns


def test_the_users_figures_and_the_scenes_figures_say_which_is_which():
    """``liefi.plot``: figures of a user's own run; ``results/scene_figures.py``: the helpers scenes draw with."""
    import liefi.plot

    assert liefi.plot.__name__ == "liefi.results.plot"
    assert liefi.plotting.__name__ == "liefi.results.scene_figures"
    assert not (ROOT / "plotting.py").exists() and not (ROOT / "results" / "plotting.py").exists()
    assert "user's own run" in liefi.plot.__doc__.splitlines()[0]
    assert "scenes" in liefi.plotting.__doc__.splitlines()[0]


def test_the_top_level_holds_at_most_eight_public_modules():
    """``liefi/``: subpackages by stage, and at most 8 public modules beside them (``_`` helpers aside)."""
    public = sorted(p.name for p in ROOT.glob("*.py") if not p.name.startswith("_"))
    assert len(public) <= 8, public
    packages = {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()}
    assert {"groups", "systems", "reduction", "schemes", "engine", "integrator", "results", "scenes"} <= packages
