"""One choice of method for a tolerance, whichever way a user asks (issue 26).

``Scene.run(rtol=...)``, :meth:`liefi.FeedbackIntegrator.run` with ``rtol`` and ``liefi run --rtol`` must
run the same scheme at the same step: before, ``Scene.run`` kept the scene's own (paper) scheme and did not
choose the order, so scenes whose paper scheme is Euler chose a step of 1e-8 to 1e-16 and the rattleback ran
``imex-rk4`` at 632,000 steps where ``fi.run`` runs a higher order at a few thousand.
"""

import json

import pytest

from liefi import scenes
from liefi.cli import main
from liefi.scenes.base import tolerance_method

T, RTOL = 1.0, 1e-4


@pytest.fixture(autouse=True)
def _no_store(monkeypatch):
    monkeypatch.setenv("LIEFI_REFERENCE_STORE", "0")  # every path chooses, none reads a stored step


@pytest.mark.parametrize("name", ["suslov", "knife-edge", "kepler"])
def test_scene_run_fi_run_and_the_cli_choose_the_same_scheme_and_step(name, capsys):
    sc = scenes.get(name)
    sc.__dict__.pop("_stepcache", None)
    r = sc.run(t_final=T, rtol=RTOL, backend="numpy")
    fi = sc.integrator(sc.variant(), gains="auto")
    sol = fi.run(T, rtol=RTOL, backend="numpy")
    sc.__dict__.pop("_stepcache", None)  # the CLI chooses again, not from the scene's memory
    assert main(["run", name, "--rtol", str(RTOL), "--t-final", str(T), "--backend", "numpy", "--json"]) in (0, None)
    cli = json.loads(capsys.readouterr().out)["method"]
    assert r.method["scheme"] == sol.method["scheme"] == cli["scheme"], (name, r.method, sol.method, cli)
    assert r.method["dt"] == sol.method["dt"] == cli["dt"], (name, r.method["dt"], sol.method["dt"], cli["dt"])
    assert r.method["scheme"].startswith("imex-rk") and T / r.method["dt"] < 1e5


def test_the_method_for_a_tolerance_is_the_default_one_unless_named():
    assert tolerance_method(None, None, 1e-6, None, default="euler") == ("imex-rk4", True)
    assert tolerance_method(None, None, None, 1e-9, default="euler") == ("imex-rk4", True)
    assert tolerance_method("rk4", None, 1e-6, None, default="euler") == ("rk4", False)  # named: its order kept
    assert tolerance_method(None, 1e-3, None, None, default="euler") == ("euler", False)  # the scene's own step
    assert tolerance_method(None, None, None, None, default="dla") == ("dla", False)
    assert tolerance_method(None, None, 1e-6, None, False, default="euler") == ("imex-rk4", False)


def test_the_rattleback_chooses_one_step_for_one_integrator():
    """The rattleback's ``Scene.run`` (7.7e-4 over ``[0, 20]`` at ``1e-6``) and ``scene.integrator().run`` (1.05e-3)
    chose different steps because they run different integrators, not because the choice differs: a step for a
    tolerance runs with ``gains="auto"`` (as ``liefi run`` and ``FeedbackIntegrator(system, y0)``'s default), while
    ``scene.integrator()`` carries the scene's paper gains, fixed (``k = 1``), a weaker feedback whose runs have
    another error at the same step (measured at ``dt = 1.05e-3``: 1.2e-6 with ``"auto"``, 2.3e-7 with ``k = 1``;
    each choice lands its own run within ``rtol``).  With the same integrator every way of asking chooses the same
    step: ``Scene.run``, ``FeedbackIntegrator(scene.system, y0).run`` with its defaults, and
    ``scene.integrator(gains="auto").run``."""
    import liefi

    sc = scenes.get("rattleback")
    sc.__dict__.pop("_stepcache", None)
    T6 = 0.5
    # the step Scene.run(t_final=T6, rtol=1e-6) runs (its own call, without the reference it is compared with)
    scheme, choose_order = tolerance_method(None, None, 1e-6, None)
    dt, info = sc.step_for_tolerance(None, scheme, T6, 1e-6, gains="auto", choose_order=choose_order, backend="auto")
    paper = sc.integrator()
    assert paper.gains_mode == "fixed"
    user = liefi.FeedbackIntegrator(sc.system, paper.y0)  # a user's integrator, every setting its default
    assert user.gains_mode == "auto" and user.invariant_names == paper.invariant_names
    for fi in (user, sc.integrator(gains="auto")):
        sol = fi.run(T6, rtol=1e-6, backend="auto", progress=False)
        assert (sol.method["scheme"], sol.method["dt"]) == (info["scheme"], dt)
