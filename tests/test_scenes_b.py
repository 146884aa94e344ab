"""Scenes roller-racer, heisenberg, oscillator against their exact or reference solutions.

Short horizons (t <= 2) keep the file fast.  The tolerances come from the
schemes' orders: the observed order between ``dt`` and ``dt/2`` must match the
declared one (Euler 1, RK4 4, DLA 1), Heisenberg's straight lines are exact
for every explicit scheme (so the error is rounding only), and the drifts of
the penalized invariants stay at the level the feedback holds them to.  The
paper's closed forms (the oscillator's DLA step ``(dynamics)``/``(EzLambda)``,
``y = cos t``) are written here as oracles only.
"""

import importlib.util
import pathlib
import warnings

import re

import numpy as np
import pytest

from liefi import IntegrationError, scenes
from liefi.dla import DLAIntegrator
from liefi.scenes.base import Variant
from liefi.scenes.oscillator import poincare_section

EXAMPLES = pathlib.Path(__file__).resolve().parent.parent / "examples"


def max_error(result):
    return max(result.max_error.values())


def observed_order(scene, scheme, dt, **kw):
    """``log2(err(dt) / err(dt/2))`` and the finer run."""
    coarse = scene.run(scheme=scheme, dt=dt, **kw)
    fine = scene.run(scheme=scheme, dt=dt / 2, **kw)
    return np.log2(max_error(coarse) / max_error(fine)), fine


# ------------------------------------------------------------------ roller racer
@pytest.fixture(scope="module")
def racer():
    return scenes.get("roller-racer")


def test_roller_racer_data(racer):
    """The reduced mass tensor inverts to the paper's h; e_1, e_2 orthonormal; start on C."""
    sys = racer.system
    m, I1, I2 = racer.m, racer.I1, racer.I2
    rng = np.random.default_rng(1)
    z = rng.normal(size=(6, 5))
    phi, Pt, Px, Py, pp = z.T
    h_paper = (Px**2 + Py**2) / (2 * m) + (Pt - pp) ** 2 / (2 * I1) + pp**2 / (2 * I2)
    np.testing.assert_allclose(sys.hamiltonian(z), h_paper, rtol=1e-13)
    np.testing.assert_allclose(sys.gram_matrix(z[:, :1]), np.broadcast_to(np.eye(2), (6, 2, 2)), atol=1e-14)
    z0 = racer.initial_state(racer.variant())[3:]
    assert np.abs(sys.constraint_momenta(z0)).max() < 1e-14
    assert sys.hamiltonian(z0) > 0  # the theorem's h~_0 > 0


def test_complete_momenta_rejects_wrong_count(racer):
    with pytest.raises(ValueError, match="give 2 of the momenta"):
        racer.system.complete_momenta([0.3], {"Pi_theta": 1.0})


@pytest.mark.parametrize("variant", ["extended", "original"])
def test_roller_racer_euler_first_order(racer, variant):
    order, fine = observed_order(racer, "euler", 2e-3, t_final=1.0, variant=variant)
    assert 0.85 < order < 1.2
    assert max_error(fine) < 1e-3 * 1.0  # C dt t with C ~ 0.2
    assert max(fine.max_drift.values()) < 1e-5


def test_roller_racer_rk4_fourth_order_and_pose(racer):
    order, fine = observed_order(racer, "rk4", 4e-3, t_final=1.0)
    assert 3.6 < order < 4.6
    assert max_error(fine) < 1e-8
    # the pose is integrated on request, and compared too
    r = racer.run(scheme="rk4", dt=2e-3, t_final=1.0, configuration=True)
    assert {"theta", "x", "y"} <= set(r.max_error)
    assert max_error(r) < 1e-8


def test_roller_racer_scipy(racer):
    r = racer.run(scheme="scipy:DOP853", t_final=0.5)
    assert max_error(r) < 1e-7
    assert r.max_drift["J_1"] < 1e-7


# ------------------------------------------------------------------- Heisenberg
@pytest.fixture(scope="module")
def heis():
    return scenes.get("heisenberg")


@pytest.mark.parametrize("variant", ["special", "generic"])
@pytest.mark.parametrize("scheme", ["euler", "heun"])
def test_heisenberg_straight_lines_exact(heis, variant, scheme):
    """On V^{-1}(0) every explicit RK step of the field is exact: errors are rounding only."""
    r = heis.run(variant=variant, scheme=scheme, t_final=1.0)
    assert max_error(r) < 1e-12
    assert max(r.max_drift.values()) < 1e-13


def test_heisenberg_scipy(heis):
    r = heis.run(variant="generic", scheme="scipy:DOP853", t_final=1.0)
    assert max_error(r) < 1e-7


def test_heisenberg_invariants(heis):
    """V penalizes J_1 = p.e (non-normalized e), J_2 = x p_y - y p_x and the energy: h~, since
    h is not a first integral of the extended field when |e|^2 varies with q (A1)."""
    v = heis.variant("generic")
    fi = heis.integrator(v)
    assert fi.energy == "extended"
    assert set(fi.invariant_names) == {"J_1", "energy", "L_z"}
    x, y, z, px, py, pz = heis.initial_state(v)
    assert fi.targets["L_z"] == pytest.approx(x * py - y * px)
    zt = np.array([0.3, -0.7, 2.0, 0.1, 0.2, 0.4])
    vals = fi.invariant_values(zt)
    J = 0.4 + 0.7 * 0.1 + 0.3 * 0.2
    assert vals["J_1"] == pytest.approx(J)
    assert vals["h~"] == pytest.approx(0.5 * (0.01 + 0.04 + 0.16) - J**2 / (2 * (1 + 0.09 + 0.49)))
    with pytest.raises(ValueError, match="original"):
        heis.integrator(Variant("h", "", energy="original", options=v.options))


def test_heisenberg_special_start_stays_exact_past_the_stability_bound(heis):
    """dt k (1 + 2 y^2) reaches ~10 on [0, 10] at gain 100, but nothing seeds the unstable mode."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = heis.run(variant="special", gains=100.0, t_final=10.0, check_stability=False)
    assert max_error(r) < 1e-11
    assert max(r.max_drift.values()) == 0.0


def test_heisenberg_gain_100_generic_never_returns_a_wrong_line(heis):
    """With k = 100 the generic start leaves the straight line after t ~ 5 (the
    stiffness of V grows like k (x^2 + y^2)).  Without a guard Euler does not overflow
    there: each burst throws the state back inside the stable region and the run returns a
    finite, wrong trajectory.  liefi must not return it: over [0, 20] the run is refused
    up front or stopped, and over [0, 10] it stops with an IntegrationError naming the time
    and the invariant that drifted."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises((ValueError, IntegrationError)):
            heis.run(variant="generic", gains=100.0, t_final=20.0)
        with pytest.raises(IntegrationError) as info:
            heis.run(variant="generic", gains=100.0, t_final=10.0)
    err = info.value
    assert 3.0 < err.t < 10.0
    assert err.components
    msg = str(err)
    assert re.search(r"\bt ?[=~] ?\d", msg), msg
    assert all(str(c) in msg for c in err.components)


def test_heisenberg_blow_up_names_time_and_components(heis):
    """A start so fast that the energy term alone is past Euler's bound (dt k |p|^2 = 2.5)
    overflows within a few dozen steps: the error names the step time and the components."""
    fast = Variant("fast", "", options={"q0": (1.0, 0.5, 0.0), "p0": (3.0, 4.0, -2.5)})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(IntegrationError) as info:
            heis.run(variant=fast, gains=100.0, t_final=1.0, check_stability=False)
    err = info.value
    assert err.t < 0.1
    assert set(err.components) <= set(heis.system.state_names) and err.components
    assert "t=" in str(err) or "t =" in str(err)


# ------------------------------------------------------------------- oscillator
@pytest.fixture(scope="module")
def osc():
    return scenes.get("oscillator")


def test_oscillator_settings_are_the_papers(osc):
    fi = osc.integrator()
    assert fi.gains == {"energy": 500.0, "H_y": 300.0, "J_1": 300.0}
    np.testing.assert_array_equal(osc.initial_state(osc.variant()), [1, 1, 1, 0, 0, 0])
    assert (osc.dt, osc.t_final, osc.scheme) == (1e-3, 200.0, "euler")


def test_oscillator_euler_first_order(osc):
    # dt = 2e-3 is past Euler's stability bound at the paper's gains: halve from 1e-3
    order, fine = observed_order(osc, "euler", 1e-3, t_final=1.0)
    assert 0.85 < order < 1.2
    assert max_error(fine) < 1e-3
    assert max(fine.max_drift.values()) < 1e-5
    # y has a closed form (y = cos t) and the reference uses it
    np.testing.assert_allclose(osc.exact(fine.t, osc.variant())["y"], np.cos(fine.t), atol=1e-15)


def test_oscillator_rk4(osc):
    euler = osc.run(scheme="euler", t_final=1.0)
    rk4 = osc.run(scheme="rk4", t_final=1.0)
    assert max_error(rk4) < 1e-6 and max_error(rk4) < 1e-3 * max_error(euler)


def test_dla_from_system_is_the_papers_step(osc):
    """from_system (A = e^flat rows, normalized e) reproduces (dynamics) and (EzLambda)."""
    dla = DLAIntegrator.from_system(osc.system)
    rng = np.random.default_rng(3)
    h = 1e-2
    q0 = rng.normal(size=(5, 3))
    q1 = q0 + h * rng.normal(size=(5, 3))
    x0, z0 = q0[:, 0], q0[:, 2]
    x1, y1, z1 = q1.T
    lam = ((1 - h**2) * x1 - x0 + y1 * ((1 - h**2) * z1 - z0)) / (h**2 * (1 + y1**2))  # (EzLambda)
    q2 = 2 * q1 - q0 - h**2 * q1 - h**2 * lam[:, None] * np.stack([np.ones(5), np.zeros(5), y1], -1)
    np.testing.assert_allclose(dla.step(q0, q1, h), q2, atol=1e-13)


def test_dla_from_system_rejects_what_it_cannot_do(racer):
    with pytest.raises(ValueError, match="CotangentBundle"):
        DLAIntegrator.from_system(racer.system)
    import liefi

    space = liefi.CotangentBundle(1)
    varying = liefi.NonholonomicSystem(space, lambda x: (1 + x[..., :1] ** 2)[..., None])
    with pytest.raises(ValueError, match="constant metric"):
        DLAIntegrator.from_system(varying)
    with pytest.raises(TypeError):
        DLAIntegrator.from_system("oscillator")


def test_oscillator_dla_scheme(osc):
    """The DLA run: first order, discrete constraint kept exactly, J(q_k, p_k) = O(h)."""
    coarse = osc.run(scheme="dla", dt=2e-3, t_final=2.0)
    fine = osc.run(scheme="dla", dt=1e-3, t_final=2.0, save_every=1)
    assert 0.85 < np.log2(max_error(coarse) / max_error(fine)) < 1.2
    assert fine.max_drift["J_1"] < 2e-3  # O(h) with the pairing (q_{i+1}, p_{i+1})
    q, p = fine.y[:3], fine.y[3:]
    e_prev = osc.system.constraints(q[:, :-1].T)[:, 0]  # e(q_i), paired with p_{i+1}
    assert np.abs(np.einsum("ki,ik->k", e_prev, p[:, 1:])).max() < 1e-12


def test_oscillator_figure_drifts_qualitatively(osc):
    """figure:oscillator: DLA is poor on the energy, good on H_y and J; FI good on all three."""
    fi = osc.run(t_final=2.0).max_drift
    assert max(fi["h"], fi["H_y"], fi["J_1"]) < 1e-5
    # DLA: H_y and J oscillate at O(h) and stay there; the energy error grows secularly
    dla = osc.run(scheme="dla", t_final=20.0)
    early, late = dla.t <= 5.0, dla.t >= 15.0
    dH, dHy = (np.abs(dla.invariants[k] - dla.invariants[k][0]) for k in ("h", "H_y"))
    assert dH[late].max() > 2 * dH[early].max()
    assert dHy[late].max() < 1.1 * dHy[early].max()
    assert dla.max_drift["h"] > 3 * dla.max_drift["H_y"] and dla.max_drift["h"] > 100 * fi["h"]


def test_poincare_section_interpolates_upward_crossings():
    class R:
        names = ("x", "y", "z", "p_x", "p_y", "p_z")

    R.t = np.linspace(0.0, 20.0, 20001)
    R.y = np.stack([R.t, np.cos(R.t), 2 * R.t, 0 * R.t, -np.sin(R.t), np.sin(R.t)])
    s = poincare_section(R)
    np.testing.assert_allclose(s["t"], [1.5 * np.pi, 3.5 * np.pi, 5.5 * np.pi], atol=1e-6)
    np.testing.assert_allclose(s["x"], s["t"], atol=1e-12)
    np.testing.assert_allclose(s["z"], 2 * s["t"], atol=1e-12)
    np.testing.assert_allclose(s["p_z"], -1.0, atol=1e-6)


def test_poincare_section_of_runs(osc):
    fi = osc.run(t_final=5.0, save_every=1)
    dla = osc.run(t_final=5.0, save_every=1, scheme="dla")
    ref = osc.exact(fi.t, osc.variant())
    for r in (fi, dla):
        s = poincare_section(r)
        assert s["t"] == pytest.approx([1.5 * np.pi], abs=2e-3)
        for k in ("x", "z", "p_z"):
            assert s[k][0] == pytest.approx(np.interp(s["t"][0], fi.t, ref[k]), abs=5e-3)


# --------------------------------------------------------------------- examples
def _load(name):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_example_roller_racer(capsys):
    err, drift = _load("roller_racer").main(t_final=0.5)
    assert max(err.values()) < 1e-3 and max(drift.values()) < 1e-5


def test_example_heisenberg(capsys):
    err, drift = _load("heisenberg").main(t_final=1.0)
    assert max(err.values()) < 1e-12 and max(drift.values()) < 1e-13


def test_example_oscillator(capsys):
    out = _load("oscillator").main(t_final=5.0)
    assert max(out["fi"].max_drift.values()) < 1e-5
    assert len(out["sections"]["dla"]["t"]) == 1
