"""gains="auto" = the accurate gains of liefi.gains; exactly kept invariants left out of V; the A1 check on
the constraint set; systems rebuilt with every datum (issue: gains chosen for accuracy)."""

import json
import warnings

import numpy as np
import pytest

import liefi
from liefi import scenes
from liefi.gains import accurate_setting, exactly_kept
from liefi.stability import LiefiStabilityWarning, first_integral_defect


def _quiet(f, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*a, **k)


# --- gains="auto" -----------------------------------------------------------------------------------


def test_auto_on_rk4_is_the_accurate_gains_fixed():
    sc = scenes.get("suslov")
    fi = sc.integrator(gains="auto", configuration=True)
    dt, T = 1e-2, 20.0
    z, acc = accurate_setting(fi, dt, "rk4", T)
    assert 0 < z < 0.1  # far from the stability limit of RK4 (2.785)
    sol = fi.run(T, dt=dt, scheme="rk4")
    assert not sol.stability.adaptive and sol.stability.gain_history == []
    assert sol.stability.gains == pytest.approx(acc, rel=1e-12)
    # the stiffness of the feedback at the start is z*/dt (unit-rate gains scaled)
    lam = float(liefi.stability.stiffness(fi.with_gains(acc), fi.y0).lam)
    assert dt * lam == pytest.approx(z, rel=1e-9)


def test_auto_on_split_is_the_projection_limit_and_keeps_the_invariants_to_rounding():
    """Split scheme: D(z) = delta(0)/z decreases, so z* = 1/sqrt(u) (liefi.gains), fixed, not adapted."""
    from liefi.gains import SPLIT_RATE_MAX

    sc = scenes.get("knife-edge")
    fi = sc.integrator(gains="auto")
    z, acc = accurate_setting(fi, 1e-2, "imex-rk4", 3.0)
    assert z == pytest.approx(SPLIT_RATE_MAX)
    sol = _quiet(fi.run, 3.0, dt=1e-2, scheme="imex-rk4")
    assert not sol.stability.adaptive and sol.stability.gain_history == []
    assert sol.stability.gains == pytest.approx(acc, rel=1e-12)
    free = _quiet(fi.with_gains(0.0).run, 3.0, dt=1e-2, scheme="rk4")
    vals = fi.invariant_values(np.moveaxis(sol.y, -1, 0))
    vals0 = fi.invariant_values(np.moveaxis(free.y, -1, 0))
    for name in ("J_1", "energy"):
        ref = 0.0 if name == "J_1" else fi.energy_target
        split_drift = np.max(np.abs(vals[name] - ref))
        free_drift = np.max(np.abs(vals0[name] - ref))
        assert split_drift < 1e-15 and split_drift < free_drift / 100  # to rounding, plain RK4 drifts


def test_auto_on_euler_keeps_adapting():
    sc = scenes.get("knife-edge")
    fi = sc.integrator(gains="auto")
    sol = _quiet(fi.run, 1.0, dt=1e-2, scheme="euler")  # Euler: z* = 1, near the limit 2: adapted at z*
    assert sol.stability.adaptive
    lam = float(liefi.stability.stiffness(fi.with_gains(sol.stability.gains), fi.y0).lam)
    assert 1e-2 * lam == pytest.approx(accurate_setting(fi, 1e-2, "euler", 1.0)[0], rel=1e-9)
    assert 1e-2 * lam == pytest.approx(1.0, rel=1e-2)  # Bae & Chang's deadbeat rate (on the rate grid)


@pytest.mark.parametrize("scheme", ["rk4", "imex-rk4"])
def test_auto_is_unit_invariant(scheme):
    """Suslov with momenta in other units (P -> s P, metric m -> s m): the same relative trajectory under auto."""
    sc = scenes.get("suslov")
    fi1 = sc.integrator(gains="auto", configuration=True)
    s = 37.0
    sys2 = sc.system.with_scaled_metric(np.sqrt(s) * np.eye(3))
    y2 = fi1.y0.copy()
    y2[9:] *= s
    fi2 = liefi.FeedbackIntegrator(sys2, y2, gains="auto")
    dt, T = 1e-2, 20.0
    a, b = fi1.run(T, dt=dt, scheme=scheme), fi2.run(T, dt=dt, scheme=scheme)
    assert any(v > 0 for v in a.stability.gains.values())
    # grad_P' h' = m'^-1 P' = m^-1 P and grad J' = e: the gradients and so the gains do not change; the
    # residuals (h, J) scale like the momenta, and so does the feedback term
    assert b.stability.gains == pytest.approx(a.stability.gains, rel=1e-9)
    yb = b.y.copy()
    yb[9:] /= s
    assert np.max(np.abs(yb - a.y)) / np.max(np.abs(a.y)) < 1e-12


@pytest.mark.parametrize("name", ["suslov", "oscillator", "roller-racer"])
def test_cli_auto_not_dominated(name, capsys):
    """`liefi run SCENE --scheme rk4 --gains auto --json`: no fixed gain in {0, 1, 10, 100} beats it 2x on both."""
    from liefi.cli import main

    def measure(g):
        argv = ["run", name, "--scheme", "rk4", "--gains", g, "--dt", "0.01", "--t-final", "50", "--json"]
        code = main(argv)
        out = capsys.readouterr().out
        if g != "auto" and code not in (0, None):  # refused or unstable at this step: it beats nothing
            return np.inf, np.inf, None
        assert code in (0, None)
        d = json.loads(out)
        return max(d["max_error"].values()), max(d["max_drift"].values()), d["gains"]

    err, drift, gains = measure("auto")
    assert any(v > 0 for v in gains.values())  # a horizon where the accurate rate is not zero
    for k in ("0", "1", "10", "100"):
        e, d, _ = measure(k)
        assert not (2 * e < err and 2 * d < drift), (name, k, (e, d), (err, drift))


# --- exactly kept invariants leave V ----------------------------------------------------------------


def test_vertical_disk_drops_every_momentum_and_says_why():
    sc = scenes.get("vertical-disk")
    fi = sc.integrator()
    sol = fi.run(1.0, dt=1e-3, scheme="rk4")
    assert [d["name"] for d in sol.dropped] == ["Pi_theta", "Pi_x", "Pi_y", "Pi_psi"]
    assert all("kept exactly by rk4" in d["reason"] for d in sol.dropped)
    full = fi.run(1.0, dt=1e-3, scheme="rk4", drop_exact=False)
    assert full.dropped == []
    # the dropped terms vanished identically: the same trajectory to rounding
    assert np.max(np.abs(sol.y - full.y)) < 1e-13 * max(1.0, np.max(np.abs(full.y)))
    r = sc.run(scheme="rk4", t_final=1.0)
    d = r.to_dict()
    assert [x["name"] for x in d["dropped"]] == ["Pi_theta", "Pi_x", "Pi_y", "Pi_psi"]
    assert set(d["max_drift"]) >= {"Pi_x", "Pi_psi"}  # still monitored
    assert max(d["max_drift"].values()) < 1e-12


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_roller_racer_drops_J2_only(backend):
    pytest.importorskip("numba") if backend == "numba" else None
    sc = scenes.get("roller-racer")
    fi = sc.integrator(gains=10.0)
    sol = _quiet(fi.run, 1.0, dt=1e-3, scheme="rk4", backend=backend)
    assert [d["name"] for d in sol.dropped] == ["J_2"]
    assert sol.backend == backend
    full = _quiet(fi.run, 1.0, dt=1e-3, scheme="rk4", drop_exact=False, backend="numpy")
    assert np.max(np.abs(sol.y - full.y)) < 1e-11
    vals = fi.invariant_values(sol.y.T)
    assert np.max(np.abs(vals["J_2"])) < 1e-13


def test_not_dropped_off_target_and_dropped_on_split_schemes():
    sc = scenes.get("vertical-disk")
    fi = sc.integrator()
    off = liefi.FeedbackIntegrator(sc.system, fi.y0, invariants=fi.user, targets={"Pi_x": fi.targets["Pi_x"] + 0.1},
                                   configuration=fi.configuration, field=fi.field)
    # on this field Pi_x is kept exactly by RK4 (else the test says nothing): only its target keeps it in V
    assert "Pi_x" in exactly_kept(off, "rk4")
    sol = _quiet(off.run, 0.1, dt=1e-3, scheme="rk4")
    assert {d["name"] for d in sol.dropped} == set(exactly_kept(off, "rk4")) - {"Pi_x"}
    # a split scheme: the kept invariant's row of the Gram system decouples with a zero residual
    sol = _quiet(fi.run, 0.1, dt=1e-3, scheme="imex-euler")
    assert {d["name"] for d in sol.dropped} == {d["name"] for d in _quiet(fi.run, 0.1, dt=1e-3, scheme="rk4").dropped} != set()
    full = _quiet(fi.run, 0.1, dt=1e-3, scheme="imex-euler", drop_exact=False)
    assert np.max(np.abs(sol.y - full.y)) < 1e-12


def test_without_rejects_unknown_names():
    fi = scenes.get("suslov").integrator(configuration=True)
    with pytest.raises(ValueError, match="penalty"):
        fi.without({"penalty": "no"})


# --- the first-integral check lives on the constraint set ---------------------------------------------


def test_first_integral_check_silent_off_the_set_and_fires_for_a_false_invariant():
    sc = scenes.get("nonreversible-knife-edge")
    fi = sc.integrator()
    y1 = fi.run(3.0, dt=1e-2, scheme="rk4").y[:, -1]
    y = y1.copy()
    y[fi.names.index("p_y")] += 1e-3  # off the constraint set: J_1 != 0
    jet = fi.invariant_gradients(y)
    rate = (jet.grad @ fi.unforced_vector_field(y))[list(jet.names).index("p_phi")]
    assert abs(rate) > 1e-5  # off the set p_phi is not a first integral of the extended field (O(J_1))
    assert first_integral_defect(fi, y) == ""
    with warnings.catch_warnings():
        warnings.simplefilter("error", LiefiStabilityWarning)
        liefi.FeedbackIntegrator(sc.system, y, invariants=("constraints", "energy", "p_phi")).run(
            1.0, dt=1e-2, scheme="rk4")
    bad = liefi.FeedbackIntegrator(sc.system, y1, invariants=("constraints", "energy", "x"))
    assert "x (relative dI/dt" in first_integral_defect(bad, y)
    with pytest.warns(LiefiStabilityWarning, match="x .*not conserved"):
        bad.run(0.1, dt=1e-2, scheme="rk4")


def test_scene_run_does_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error", LiefiStabilityWarning)
        scenes.get("nonreversible-knife-edge").run(t_final=5.0)


# --- systems rebuilt with every datum --------------------------------------------------------------------


def test_mass_ratio_copy_keeps_every_datum():
    from liefi.experiments.battery import _with_mass_ratio

    sc = scenes.get("nonreversible-knife-edge")
    sc2 = _with_mass_ratio(sc, 1e6)
    s0, s1 = sc.system, sc2.system
    x = np.array([0.3, -0.2, 0.7])
    assert s1.vector_potential is not None
    assert np.allclose(s1.vector_potential(x), s0.vector_potential(x), rtol=0, atol=0)
    assert np.allclose(s1.constraints(x), s0.constraints(x), rtol=0, atol=0)
    assert s1.potential(x) == s0.potential(x)
    S = np.diag(np.sqrt(np.logspace(0.0, 6.0, 3)))
    assert np.allclose(s1.metric(x), S @ s0.metric(x) @ S, rtol=1e-15)


def test_with_scaled_metric_scales_a_given_derivative_and_checks_S():
    sp = liefi.CotangentBundle(1)
    sysm = liefi.NonholonomicSystem(sp, lambda x: np.exp(x)[..., None], metric_derivative=lambda x: np.exp(x)[..., None, None])
    s2 = sysm.with_scaled_metric([[3.0]])
    x = np.array([0.4])
    v, d = s2.metric.with_derivative(x)
    assert v == pytest.approx(9 * np.exp(0.4)) and d == pytest.approx(9 * np.exp(0.4))
    with pytest.raises(ValueError, match="S:"):
        sysm.with_scaled_metric(np.eye(2))
    with pytest.raises(ValueError, match="unknown"):
        sysm.replace(mass=1.0)
