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


# --- the flow ------------------------------------------------------------------------------------

#: the stages of the flow, lowest first: each may import only the stages before it (and the private
#: helpers ``liefi/_*.py``, which import only each other); docs/concepts.md, "Where things live"
FLOW = ("groups", "phase_space", "reduction", "systems", "schemes", "engine", "integrator", "results", "scenes",
        "experiments", "reproduce", "bench", "cli", "__main__")


def import_edges():
    """``{(unit, unit_imported): [file, ...]}`` over every import of liefi, lazy imports included.

    A unit is a subpackage or a top-level module of ``liefi/`` (``liefi`` itself for ``__init__.py``).
    """
    import ast

    edges = {}
    for p in ROOT.rglob("*.py"):
        rel = p.relative_to(ROOT.parent).with_suffix("").parts
        mod = ".".join(rel[:-1] if rel[-1] == "__init__" else rel)
        pkg = mod if rel[-1] == "__init__" else mod.rsplit(".", 1)[0]
        unit = mod.split(".")[1] if "." in mod else "liefi"
        for n in ast.walk(ast.parse(p.read_text())):
            if isinstance(n, ast.ImportFrom) and n.level:
                base = ".".join(pkg.split(".")[: len(pkg.split(".")) - (n.level - 1)])
                targets = [f"{base}.{n.module}"] if n.module else [f"{base}.{a.name}" for a in n.names]
            elif isinstance(n, ast.ImportFrom):
                targets = [n.module or ""]
            elif isinstance(n, ast.Import):
                targets = [a.name for a in n.names]
            else:
                continue
            for t in targets:
                parts = t.split(".")
                if parts[0] == "liefi" and len(parts) > 1 and parts[1] != unit and not parts[1].startswith("__"):
                    edges.setdefault((unit, parts[1]), []).append(str(p.relative_to(ROOT.parent)))
    return edges


def test_every_unit_of_liefi_is_a_stage_of_the_flow():
    units = {p.stem if p.is_file() else p.name for p in ROOT.iterdir()
             if (p.suffix == ".py" and not p.name.startswith("_")) or (p / "__init__.py").exists()}
    assert units == set(FLOW) - {"__main__"}, units ^ (set(FLOW) - {"__main__"})


def test_no_import_runs_back_up_the_flow():
    """Each stage imports only the stages before it: a line of code knows its room by its folder."""
    back = []
    for (a, b), files in sorted(import_edges().items()):
        if b.startswith("_"):
            continue  # the private helpers serve every stage
        if a.startswith("_") and a != "__main__":
            back.append(f"the helper liefi/{a}.py imports {b} ({files[0]})")
        elif a == "liefi":
            if FLOW.index(b) > FLOW.index("results"):
                back.append(f"liefi/__init__.py imports {b}")
        elif b not in FLOW or FLOW.index(b) >= FLOW.index(a):
            back.append(f"{a} imports {b} ({', '.join(sorted(set(files)))})")
    assert not back, "imports that run back up the flow:\n" + "\n".join(back)


def test_no_import_cycle_between_stages():
    edges = {}
    for a, b in import_edges():
        edges.setdefault(a, set()).add(b)

    def reach(u):
        seen, todo = set(), [u]
        while todo:
            for v in edges.get(todo.pop(), ()):
                if v not in seen:
                    seen.add(v)
                    todo.append(v)
        return seen

    assert not [u for u in edges if u in reach(u)]


def test_no_module_over_800_lines():
    long = {str(p.relative_to(ROOT.parent)): n for p in ROOT.rglob("*.py") if (n := len(p.read_text().splitlines())) > 800}
    assert not long


def test_the_tolerance_is_split_into_its_local_estimate_its_global_check_and_its_drift_rule():
    """``integrator/tolerance.py`` chooses; the local estimate, the measured global check and the drift rule are
    modules of their own, lowest first (drift rule, local estimate, check), and every name stays a name of
    ``liefi.tolerance``."""
    import liefi.tolerance as tol
    from liefi.integrator import tolerance_check, tolerance_drift, tolerance_local

    assert tol._local_estimate is tolerance_local._local_estimate
    assert tol._global_check is tolerance_check._global_check and tol.CHECK_BUDGET == tolerance_check.CHECK_BUDGET
    assert tol._drift_cap is tolerance_drift._drift_cap and tol.DRIFT_LEVEL == tolerance_drift.DRIFT_LEVEL
    edges = import_edges_within("integrator")
    assert not edges.get("tolerance_drift", set()) & {"tolerance", "tolerance_local", "tolerance_check"}
    assert not edges.get("tolerance_local", set()) & {"tolerance", "tolerance_check"}
    assert "tolerance" not in edges.get("tolerance_check", set())
    for name in ("tolerance", "tolerance_local", "tolerance_check", "tolerance_drift"):
        assert len((ROOT / "integrator" / f"{name}.py").read_text().splitlines()) <= 600


def import_edges_within(package):
    """``{module: {module imported, ...}}`` between the modules of one subpackage (lazy imports included)."""
    import ast

    edges = {}
    for p in (ROOT / package).glob("*.py"):
        for n in ast.walk(ast.parse(p.read_text())):
            if isinstance(n, ast.ImportFrom) and n.level == 1 and n.module:
                edges.setdefault(p.stem, set()).add(n.module.split(".")[0])
    return edges
