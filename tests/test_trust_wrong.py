"""Issue 23, silent wrong answers and tolerance faults: each reproduction of the issue, as a test.

* per-member constants are applied to the members' axes, never matched to an axis by
  its length (a time-major stack with as many times as members; a build with as many
  members as coordinates);
* ``liefi run --scheme dla --rtol`` is refused (the DLA has no error control), and
  ``method.why`` names only what applied;
* a step chosen for a tolerance keeps an explicit scheme stable along the run (Kepler,
  rk4), and ``fi.run``, ``Scene.run`` and ``liefi run`` choose the same step for the same
  request;
* a tiny horizon with a tolerance is one step;
* a run that diverges into a singular matrix is a liefi error, and ``errors="return"``
  keeps its finished part;
* ``liefi stability --estimate --gains K`` honours and checks ``K``; ``--gains -1,5`` is a
  value, refused by name.
"""

from __future__ import annotations

import numpy as np
import pytest

import liefi


# --- per-member constants: the member axes are explicit --------------------------------------
def _sleigh(constants):
    from models import sleigh_model

    return liefi.from_mechanics(sleigh_model()[0], constants)


def test_per_member_constants_follow_the_members_not_an_axis_of_equal_length():
    """3 sleighs of masses 1, 2, 3 and 3 saved times: the energy of the time-major stack (T, 3, n)
    and the velocities of the Solution are each member's own (as 3 separate systems)."""
    masses = np.array([1.0, 2.0, 3.0])
    sleigh = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
    sleigh.constants = {"m": masses}
    q0 = np.zeros((3, 3))
    qd0 = np.array([0.5, 0.0, 1.0]) * masses[:, None]
    z0 = sleigh.state(q0, qd0)
    fi = liefi.FeedbackIntegrator(sleigh, z0, gains=1.0)
    sol = fi.run(1.0, dt=0.01, scheme="rk4", backend="numpy", t_eval=[0.0, 0.5, 1.0])
    assert sol.y.shape == (3, 6, 3)
    Yt = np.moveaxis(sol.y, -1, 0)  # (T, members, n): liefi's time-major stack
    h = fi.invariant_values(Yt)["h"]
    qdot = sleigh.velocities(sol)
    for k, mk in enumerate(masses):
        one = _sleigh({"m": mk, "I": 1.0, "a": 0.5})
        fk = liefi.FeedbackIntegrator(one, z0[k], gains=1.0)
        np.testing.assert_allclose(h[:, k], fk.invariant_values(sol.y[k].T)["h"], rtol=1e-13)
        np.testing.assert_allclose(qdot[k], one.velocities(sol.y[k].T).T, rtol=1e-13, atol=1e-15)
    # the energy is (nearly) kept by each member: no false drift from another member's mass
    assert np.max(np.abs(h - h[0])) < 1e-5 * np.max(np.abs(h))
    # a member-major stack (members first) is refused by name, not read with the wrong masses
    with pytest.raises(ValueError, match="constants: per-member constants .* time-major"):
        sleigh.metric(np.zeros((3, 2, 3)))


def test_per_member_constants_through_finite_differences_and_adaptive_gains():
    """gains='auto', adaptive: the stiffness and rates are finite differences along an axis appended after the
    members (declared: liefi._diff.directions_after); each member runs as if alone."""
    import warnings

    masses = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    sleigh = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
    sleigh.constants = {"m": masses}
    z0 = sleigh.state(np.zeros((6, 3)), np.array([0.5, 0.0, 1.0]) * masses[:, None])
    kw = dict(dt=0.05, scheme="rk4", backend="numpy", adaptive=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ens = liefi.FeedbackIntegrator(sleigh, z0, gains="auto").run(1.0, **kw)
        for k in (0, 5):
            one = _sleigh({"m": masses[k], "I": 1.0, "a": 0.5})
            sol = liefi.FeedbackIntegrator(one, z0[k], gains="auto").run(1.0, **kw)
            np.testing.assert_allclose(ens.y[k], sol.y, rtol=1e-12, atol=1e-12)


def test_per_member_constants_at_build_with_as_many_members_as_coordinates():
    """constants={m: [1, 2, 3]} with 3 coordinates: the build's complex-step check differentiates along
    an axis of length 3 that is not the members' (it was read as them: 'not complex-step safe')."""
    sleigh = _sleigh({"m": [1.0, 2.0, 3.0], "I": 1.0, "a": 0.5})
    assert sleigh.constants.shape == (3, 3)
    x = np.zeros((3, 3))
    M = sleigh.metric(x)  # one state per member: each member's own mass
    np.testing.assert_allclose(M[:, 0, 0], [1.0, 2.0, 3.0])


# --- liefi run --scheme dla --rtol: refused, and method.why says what ran -----------------------
def _cli(capsys, *argv):
    from liefi import cli

    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_dla_with_a_tolerance_is_refused_not_run_at_the_scenes_step(capsys, monkeypatch):
    """--scheme dla --rtol R ran at dt 1e-3 whatever R (error 1.95e-3 at rtol 1e-3 and 1e-12 alike)."""
    from liefi import scenes

    def boom(self, **kw):
        raise AssertionError("the scene was run")

    sc = scenes.get("oscillator")
    with pytest.raises(ValueError, match="rtol: the scheme 'dla' .* no error control"):
        sc.run(scheme="dla", rtol=1e-12, t_final=0.01)
    monkeypatch.setattr(scenes.Scene, "run", boom)
    for tol in ("--rtol", "--atol"):
        code, out, err = _cli(capsys, "run", "oscillator", "--scheme", "dla", tol, "1e-3")
        assert code == 2 and out == ""
        assert err.startswith("liefi: error: rtol: --scheme dla has no error control") and "--dt" in err


def test_method_why_says_the_step_that_ran(capsys):
    """--scheme dla at the scene's step: why names that step, not 'the step for the tolerance'."""
    import json

    code, out, err = _cli(capsys, "run", "oscillator", "--scheme", "dla", "--t-final", "0.01", "--backend", "numpy",
                          "--json")
    assert code == 0, err
    method = json.loads(out)["method"]
    assert method["dt"] == 0.001 and "tolerance" not in method["why"] and "step 0.001" in method["why"]
    assert "gains auto" not in method["why"] and method["gains"] == "none"


# --- a step chosen for a tolerance is stable along the run, and chosen alike by every entry point ---
def test_step_for_a_tolerance_keeps_an_explicit_scheme_stable_along_the_run():
    """Kepler, rk4 at the scene's fixed gains, rtol 1e-3: the step for the tolerance alone (0.0283 over
    [0, 1000]) passed beta / lambda_max along the orbit and the run blew up; the chosen step is now within
    the stability bound at the stiffest point of the guard's pilot over the horizon (over [0, 10]: 0.079, at
    4.0 x the bound, before)."""
    from liefi import scenes, stability, tolerance
    from liefi.schemes import registry

    sc = scenes.get("kepler")
    fi = sc.integrator(sc.variant(None))
    assert fi.gains_mode == "fixed"
    dt, info = tolerance.choose_step(fi, registry.get("rk4"), fi.y0, 0.0, 10.0, 1e-3, backend="numpy")
    # an independent pilot over the horizon (a finer step than the chooser's): dt lambda_max within beta (was 4.0 x beta)
    est = stability.estimate(fi, dt, "rk4", t_final=10.0, max_evals=400, resolution=False)
    assert est.ratio < 1
    assert info["stable_step"] is not None and dt <= info["stable_step"]


@pytest.mark.slow
def test_kepler_rk4_for_a_tolerance_runs_and_every_entry_point_chooses_the_same_step(capsys):
    """fi.run(1000, rtol=1e-3, scheme='rk4') ran at 0.0283 and blew up at t = 7.99 ('check the system's
    data'); liefi run chose 0.0114 (gains auto).  Now the fixed-gains run is stable, and with the same gains
    (auto: liefi run's and FeedbackIntegrator's default, and Scene.run's for a tolerance) the three agree."""
    import json
    import warnings

    from liefi import scenes

    sc = scenes.get("kepler")
    v = sc.variant(None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = sc.integrator(v).run(1000.0, rtol=1e-3, scheme="rk4")  # the scene's fixed gains
        assert sol.success and np.all(np.isfinite(sol.y))
        auto = liefi.FeedbackIntegrator(sc.system, sc.integrator(v).y0, invariants=sc.invariants(v),
                                        energy=v.energy).run(1000.0, rtol=1e-3, scheme="rk4")
        scene = sc.run(t_final=1000.0, scheme="rk4", rtol=1e-3)
    code, out, err = _cli(capsys, "run", "kepler", "--scheme", "rk4", "--rtol", "1e-3", "--json")
    assert code == 0, err
    assert auto.method["dt"] == scene.dt == json.loads(out)["method"]["dt"]
    # the scene's fixed gains asked of liefi run: the fixed-gains fi.run's step
    code, out, err = _cli(capsys, "run", "kepler", "--scheme", "rk4", "--rtol", "1e-3", "--json", "--gains",
                          ",".join(str(v) for v in sc.integrator(v).gains.values()))
    assert code == 0, err
    assert json.loads(out)["method"]["dt"] == sol.method["dt"]


# --- a tiny horizon with a tolerance: one step, not ZeroDivisionError ------------------------------
@pytest.mark.parametrize("T", [1e-300, 1e-200, 5e-324])
def test_a_tiny_horizon_with_a_tolerance_is_one_step(T):
    """fi.run(1e-300, rtol=...) divided by h^(p+1) = 0 (ZeroDivisionError); the span is legal."""
    from liefi import scenes

    sc = scenes.get("oscillator")
    fi = sc.integrator(sc.variant(None))
    for scheme in (None, "rk4"):
        sol = fi.run(T, rtol=1e-6, scheme=scheme, backend="numpy")
        assert sol.success and sol.t.tolist() == [0.0, T] and sol.method["dt"] == T
        np.testing.assert_allclose(sol.y[:, -1], fi.y0, rtol=1e-15, atol=10 * T)  # one step of length T


def test_a_tiny_horizon_on_the_command_line(capsys):
    import json

    code, out, err = _cli(capsys, "run", "oscillator", "--t-final", "1e-200", "--rtol", "1e-6", "--backend", "numpy",
                          "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["method"]["dt"] == 1e-200 and max(d["max_error"].values()) < 1e-150


# --- a diverging numpy run: a liefi error naming what happened, and errors="return" keeps the run ----
def test_a_run_diverging_into_a_singular_matrix_is_a_liefi_error_and_keeps_its_finished_part():
    """The rattleback at euler dt 0.5 (unchecked) ended in a bare numpy LinAlgError 'Singular matrix', and
    errors='return' lost the run; now an IntegrationError says it diverged, and the finished part is kept."""
    from liefi import scenes
    from liefi.schemes import IntegrationError

    sc = scenes.get("rattleback")
    fi = sc.integrator(sc.variant(None))
    kw = dict(dt=0.5, scheme="euler", backend="numpy", check_stability=False)
    with pytest.raises(IntegrationError, match=r"diverged: .* singular matrix.* at step 5 \(t=2.5\).*last finite state is at t=2") as info:
        fi.run(20.0, **kw)
    assert not isinstance(info.value, np.linalg.LinAlgError)
    sol = fi.run(20.0, errors="return", **kw)
    assert (sol.success, sol.status) == (False, -1) and "diverged" in sol.message
    assert sol.t.tolist() == [0.0, 0.5, 1.0, 1.5, 2.0]  # every saved step before the failure
    ok = fi.run(2.0, **kw)
    np.testing.assert_array_equal(sol.y, ok.y)


def test_errors_return_keeps_the_saved_states_before_non_finite_values():
    from liefi import scenes

    sc = scenes.get("oscillator")
    fi = sc.integrator(sc.variant(None))
    sol = fi.run(20.0, dt=0.5, scheme="euler", backend="numpy", check_stability=False, errors="return")
    assert not sol.success and sol.t.size > 3 and np.all(np.isfinite(sol.y))
    np.testing.assert_allclose(np.diff(sol.t), 0.5)


# --- liefi stability --estimate --gains K: honoured and checked; --gains -1,5 reaches the check -------
SHORT = ("--t-final", "1")  # the estimate's pilot over a short horizon


def test_stability_estimate_honours_and_checks_gains(capsys):
    """--estimate ignored --gains (-1 and 1e300 accepted, the estimate made at the scene's gains)."""
    import json

    code, out, err = _cli(capsys, "stability", "oscillator", "--estimate", "--gains", "5", "--json", *SHORT)
    assert code == 0, err
    one = json.loads(out)["estimate"]
    assert set(one["gains"].values()) == {5.0}
    code, out, err = _cli(capsys, "stability", "oscillator", "--estimate", "--gains", "5,10", "--json", *SHORT)
    two = json.loads(out)["estimate"]
    assert [set(e["gains"].values()) for e in two] == [{5.0}, {10.0}]
    # the estimate scales with the gain: lambda_max(10) = 2 lambda_max(5)
    assert two[1]["lambda_max"] == pytest.approx(2 * two[0]["lambda_max"], rel=1e-9)
    code, out, err = _cli(capsys, "stability", "oscillator", "--estimate", "--json", *SHORT)
    assert set(json.loads(out)["estimate"]["gains"].values()) != {5.0}  # the scene's own gains by default
    for bad, word in (("-1", "finite positive number, got -1.0"), ("0", "finite positive"),
                      ("nan", "finite positive"), ("1e300", "past the ~1e300"), ("x", "comma list of numbers")):
        code, out, err = _cli(capsys, "stability", "oscillator", "--estimate", "--gains", bad, *SHORT)
        assert code == 2 and out == "" and err.startswith("liefi: error: gains:") and word in err, (bad, err)


@pytest.mark.parametrize("argv", [["stability", "oscillator", "--estimate", "--gains", "-1,5"],
                                  ["run", "oscillator", "--gains", "-1,5,2", "--t-final", "0.01"]])
def test_a_negative_gain_list_is_a_value_refused_by_name(capsys, argv):
    """--gains -1,5 gave argparse's 'expected one argument' (the leading minus read as an option)."""
    code, out, err = _cli(capsys, *argv)
    assert code == 2 and out == ""
    assert "expected one argument" not in err and err.startswith("liefi: error: gains:") and "-1" in err, err


@pytest.mark.parametrize("argv, says, not_says", [
    (["--dt", "0.01"], "(imex-rk4, gains auto)", "tolerance"),
    (["--scheme", "scipy:RK45"], "solve_ivp's own steps", "tolerance"),
    (["--scheme", "rk4"], "the step for the tolerance", "imex-rk4"),
])
def test_method_why_names_only_the_defaults_that_apply(argv, says, not_says):
    from liefi import cli, scenes

    args = cli.build_parser().parse_args(["run", "oscillator", *argv])
    why = cli.run_settings(scenes.get("oscillator"), args)[-1]
    assert says in why and not_says not in why, why
