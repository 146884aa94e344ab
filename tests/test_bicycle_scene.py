"""The scene ``bicycle``: the benchmark bicycle built by ``liefi.from_mechanics`` from its Kane model, run
uncontrolled from a lean-rate kick.

Default (fast): the scene is registered, is not one of the paper's experiments (``liefi reproduce`` leaves
it out unless asked), and loading it builds nothing (no sympy).

Slow: the nonlinear runs of the four variants at the scene's settings (``imex-rk8``, ``dt = 0.005``), with
every declared constraint -- the four rolling rows and ``f'`` of the model's five velocity constraints, the
front contact's height -- and the energy from the model's own sympy expressions within 1e-12 over the runs
(``declared_residuals``); the lean decays at 5 m/s and 4.6 m/s, the weave grows at 3 m/s at the rate of
its eigenvalue without the bicycle falling by t = 10 s, the capsize mode grows slowly at 8 m/s; the IFToMM
manoeuvre against DOP853 at 1e-12 on sympy's own equations of the same model (the PyDy peer's numerics).
"""

import subprocess
import sys

import numpy as np
import pytest

from liefi import reproduce, scenes

#: variant -> horizon (s): the stable runs over [0, 100]; the weave and the capsize until before they fall
HORIZONS = {"self-stable": 100.0, "iftomm": 100.0, "weave": 10.0, "capsize": 30.0}


def test_bicycle_is_a_scene_outside_the_default_reproduce():
    sc = scenes.get("bicycle")
    assert "bicycle" in scenes.names() and not sc.in_paper
    assert "bicycle" not in reproduce.paper_scenes()
    assert {k: (v.options["speed"], v.options["lean_rate"]) for k, v in sc.variants.items()} == {
        "self-stable": (5.0, 0.5), "weave": (3.0, 1e-8), "capsize": (8.0, 0.05), "iftomm": (4.6, 0.5)}


def test_loading_the_bicycle_scene_builds_nothing():
    """``liefi list`` and ``liefi reproduce`` load every scene: the bicycle's costs sympy only when run."""
    code = ("import sys; from liefi import scenes; sc = scenes.get('bicycle'); "
            "assert 'sympy' not in sys.modules, 'sympy imported'; assert '_model' not in vars(sc)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


@pytest.fixture(scope="module")
def bicycle():
    return scenes.get("bicycle")


def _window(t, y, lo, hi):
    return float(np.abs(y[(t >= lo) & (t <= hi)]).max())


@pytest.mark.slow
@pytest.mark.parametrize("variant", sorted(HORIZONS))
def test_bicycle_runs_hold_every_declared_constraint_and_the_energy(bicycle, variant):
    from test_bicycle_liefi import declared_residuals

    T = HORIZONS[variant]
    r = bicycle.run(variant=variant, t_final=T, save_every=4)  # saved every 0.02 s
    assert r.t[-1] == pytest.approx(T) and r.scheme == "imex-rk8" and r.dt == 0.005
    velocity, f, energy = declared_residuals(bicycle.model, bicycle.system, r)
    assert np.abs(velocity).max() < 1e-12  # m/s: the rolling of both wheels (and f')
    assert np.abs(f).max() < 1e-12  # m: the front contact's height
    assert np.abs(energy - energy[0]).max() < 1e-12 * abs(energy[0])
    t, lean = r.t, r["q4"]
    first = _window(t, lean, 0.0, 2.0)
    at_10 = _window(t, lean, 9.7, 10.0)
    if variant in ("self-stable", "iftomm"):  # the lean decays, to rounding by t = 100
        assert at_10 < 0.05 * first
        assert _window(t, lean, 95.0, 100.0) < 1e-9 * first
    elif variant == "weave":  # grown, at the weave's rate 1.707 /s, and not fallen
        assert at_10 > 1e5 * first and _window(t, lean, 0.0, 10.0) < 0.2
        rate = np.log(_window(t, lean, 7.0, 9.0) / _window(t, lean, 3.0, 5.0)) / 4.0
        assert abs(rate - 1.707) < 0.02 * 1.707, rate
    else:  # the slow capsize: no oscillation left, the lean grows at the capsize eigenvalue 0.143 /s
        late = lean[t >= 10.0]
        assert np.all(np.sign(late) == np.sign(late[0])) and at_10 > 1.5 * first
        rate = np.log(abs(lean[np.argmin(abs(t - 20.0))]) / abs(lean[np.argmin(abs(t - 12.0))])) / 8.0
        assert abs(rate - 0.143) < 0.05 * 0.143, rate


def against_sympys_equations(bicycle, r, names=("q4", "q7", "q1", "q2", "q3")):
    """``{name: max |liefi - reference|}`` over the run ``r`` of ``bicycle``: the reference is DOP853 at 1e-12 on
    ``mass_matrix_full x' = forcing_full`` of the same ``KanesMethod``, from the same start (the PyDy peer's
    numerics, ``benchmarks/bicycle_peer.py``), at ``r.t``.  Also used by ``benchmarks/bicycle_runs.py``."""
    import os

    from scipy.integrate import solve_ivp

    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if os.path.join(here, "benchmarks") not in sys.path:
        sys.path.insert(0, os.path.join(here, "benchmarks"))
    import bicycle_peer as bp

    bike = bicycle.model
    rhs, _ = bp.numeric_model(bike)
    _, initial = bp.monitors_of(bike)
    o = bicycle.variant(r.variant).options
    sol = solve_ivp(rhs, (0.0, float(r.t[-1])), initial(o["speed"], o["lean_rate"]), method="DOP853", rtol=1e-12,
                    atol=1e-12, t_eval=r.t)
    q = [str(s.func) for s in bike.kane.q]
    return {n: (float(np.abs(r[n] - sol.y[q.index(n)]).max()), float(np.abs(sol.y[q.index(n)]).max())) for n in names}


@pytest.mark.slow
def test_bicycle_iftomm_manoeuvre_against_sympys_own_equations(bicycle):
    """4.6 m/s, 0.5 rad/s (IFToMM M2) over [0, 10]: liefi's lean, steer, rear contact and heading against DOP853
    at 1e-12 on sympy's own equations of the same model (:func:`against_sympys_equations`)."""
    r = bicycle.run(variant="iftomm", t_final=10.0, save_every=20)  # every 0.1 s
    for name, (diff, size) in against_sympys_equations(bicycle, r).items():
        assert diff < 1e-8 * max(1.0, size), (name, diff, size)


def test_liefi_list_verbose_does_not_build_the_bicycle(capsys):
    """``liefi list -v`` shows every scene's ``--gains`` order by building its integrator; the bicycle's build
    (sympy's ``kanes_equations`` and ``from_mechanics``, about 12 CPU s) is left to its first run."""
    from liefi.cli import main

    sc = scenes.get("bicycle")
    assert main(["list", "-v"]) in (0, None)
    out = capsys.readouterr().out
    assert "known once built (sympy's kanes_equations" in out and "--gains order: J_1,energy" in out
    assert "_model" not in vars(sc) and "system" not in vars(sc)
