"""Gains chosen for accuracy (liefi.gains): the derived rule, its limits, and non-domination on the scenes."""

import warnings

import numpy as np
import pytest

from liefi import NonholonomicSystem, scenes
from liefi.feedback import FeedbackIntegrator
from liefi.gains import accurate_gains, accurate_rate, drift_bound, exactly_kept, local_defect
from liefi.groups import SO3
from liefi.phase_space import LieGroupPhaseSpace
from liefi.scenes.rigid_body import CASIMIR


def test_euler_rate_is_bae_chang_deadbeat():
    # Euler: delta(z) does not depend on z, the bound is least where R(-z) = 1 - z vanishes
    for hw in (1e-3, 1e-2, 1e-1):
        assert accurate_rate("euler", 1e-3, hw / 1e-3, 1000.0) == pytest.approx(1.0, abs=2e-3)
    d = local_defect("euler", [0.0, 0.5, 1.5], 1e-2)
    assert np.allclose(d, 0.5e-4, rtol=1e-12)


def test_rk4_defect_coefficients():
    # the scheme's own local error: epsilon_5 = 1/2880; the first stage-defect term z^3 (h w)^2 / 96
    hw = 1e-3
    assert local_defect("rk4", 0.0, hw)[0] == pytest.approx(hw**5 / 2880, rel=1e-12)
    hw, z = 1e-7, 0.1
    assert local_defect("rk4", z, hw)[0] == pytest.approx(z**3 * hw**2 / 96, rel=1e-3)


def test_rk4_rate_small_and_zero_on_short_horizons():
    # long horizon: kappa* ~ 0.2-0.3 omega (x^3 = 1/60 up to the other terms), far below the stability limit
    z = accurate_rate("rk4", 1e-3, 1.0, 1e4)
    assert 0.15 < z / 1e-3 < 0.35
    # a horizon of a few steps: the contraction never acts, feedback only adds error
    assert accurate_rate("rk4", 1e-3, 1.0, 5e-3) == 0.0
    # the bound at z* is below the bound of the old automatic choice (z ~ 1.6) and of no feedback
    D = drift_bound("rk4", [0.0, z, 1.6], 1e-3, 1e7)
    assert D[1] < D[0] and D[1] < 1e-3 * D[2]


def test_exactly_kept_detection():
    # linear first integrals of the extended field that the other invariants' feedback leaves alone
    assert exactly_kept(scenes.get("roller-racer").integrator(), "rk4") == ("J_2",)
    vd = scenes.get("vertical-disk").integrator("further")
    assert set(exactly_kept(vd, "rk4")) == set(vd.invariant_names)
    # Suslov's J_1 is linear and a first integral of X, but the energy's feedback moves it
    assert exactly_kept(scenes.get("suslov").integrator(), "rk4") == ()
    # quadratic ones are not
    assert "energy" not in exactly_kept(scenes.get("oscillator").integrator(), "rk4")
    g = accurate_gains(scenes.get("roller-racer").integrator(), 1e-3, "rk4", 1e3)
    assert g["J_2"] == 0.0 and g["J_1"] > 0.0 and g["energy"] > 0.0
    assert exactly_kept(vd, "imex-euler") == exactly_kept(vd, "rk4")  # the split schemes keep them too
    with pytest.raises(ValueError, match="scheme.*imex-rk4"):
        exactly_kept(vd, "dla")


def test_unit_invariance():
    # the rigid body in other units of momentum (Pi -> s Pi, I -> s I): the same relative motion;
    # the rate z* is the same, k_casimir scales like 1/s^2 (grad C = Pi), k_energy does not change
    def fi(s):
        sys_ = NonholonomicSystem(LieGroupPhaseSpace(SO3()), s * np.diag([3.0, 2.0, 1.0]))
        y0 = np.concatenate([np.eye(3).ravel(), s * np.array([3.0, 2.0, 1.0])])
        return FeedbackIntegrator(sys_, y0, invariants=("energy", CASIMIR))

    g1, g4 = accurate_gains(fi(1.0), 1e-3, "rk4", 1e3), accurate_gains(fi(4.0), 1e-3, "rk4", 1e3)
    assert g4["energy"] == pytest.approx(g1["energy"], rel=1e-6)
    assert g4["casimir"] == pytest.approx(g1["casimir"] / 16, rel=1e-6)
    assert g4["penalty"] == pytest.approx(g1["penalty"], rel=1e-6)


@pytest.mark.parametrize("name", ["suslov", "oscillator", "roller-racer"])
def test_accurate_gains_not_dominated(name):
    """RK4 at the scene's dt: no fixed gain in {0, 1, 10, 100} beats the accurate gains 2x on both error and drift."""
    sc = scenes.get(name)
    T = 20.0
    g = accurate_gains(sc.integrator(), sc.dt, "rk4", T)
    assert any(v > 0 for v in g.values())

    def measure(gains):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = sc.run(scheme="rk4", t_final=T, gains=gains, backend="auto")
        return max(r.max_error.values()), max(r.max_drift.values())

    err, drift = measure(g)
    for k in (0.0, 1.0, 10.0, 100.0):
        e, d = measure(k)
        assert not (2 * e < err and 2 * d < drift), (name, k, (e, d), (err, drift))


def test_exactly_kept_means_kept_by_the_feedback_field():
    """With its own gain 0, a kept invariant stays at rounding; Suslov's J_1 (not kept) is moved by the energy's feedback."""

    def drift_J(name, which, gains):
        sc = scenes.get(name)
        fi = sc.integrator(gains=gains)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = fi.run(2.0, dt=1e-2, scheme="heun", check_stability=False)
        vals = fi.invariant_values(sol.y.T)
        return float(np.max(np.abs(vals[which])))

    assert drift_J("roller-racer", "J_2", {"J_1": 10.0, "J_2": 0.0, "energy": 10.0}) < 1e-13
    assert drift_J("suslov", "J_1", {"J_1": 0.0, "energy": 10.0}) > 1e-9


def test_the_gains_of_a_run_replay_as_they_are_with_what_it_dropped():
    """gains="auto" leaves J_2 of the roller racer out of V (kept exactly by imex-rk4): the run's gains have no
    entry for it, and carry it as dropped, so that FeedbackIntegrator(gains=sol.stability.gains) is the run's
    integrator (without fi.without(sol.dropped)): the same steps, bitwise."""
    import pickle

    from liefi.scenes import get

    fi0 = get("roller-racer").integrator(gains="auto")
    sol = fi0.run(0.05, dt=0.001, scheme="imex-rk4", backend="numpy", adaptive=False)
    assert [d["name"] for d in sol.dropped] == ["J_2"] and "J_2" not in sol.stability.gains
    fi = FeedbackIntegrator(fi0.system, fi0.y0, gains=sol.stability.gains, configuration=fi0.configuration)
    assert set(sol.stability.gains.dropped) == {"J_2"}
    assert [d["name"] for d in fi.dropped] == ["J_2"] and fi.gains == dict(sol.stability.gains)
    again = fi.run(0.05, dt=0.001, scheme="imex-rk4", backend="numpy", adaptive=False, drop_exact=False)
    assert np.array_equal(again.y, sol.y)
    assert pickle.loads(pickle.dumps(sol.stability.gains)).dropped == sol.stability.gains.dropped
