"""The stability machinery (:mod:`liefi.stability`, :mod:`liefi.schemes.split`, :mod:`liefi.experiments`) against its defining facts.

* The Hessian of ``V`` on its zero set is ``sum_j k_j grad I_j grad I_j^T + k0 Hess P``:
  its largest eigenvalue from the small Gram matrix equals the one of the full
  (finite-difference) Hessian, on random systems of every kind.
* The knife edge at the paper's settings sits exactly on Euler's limit
  (``dt lambda_max = 2`` at ``t = pi``, docs/paper_notes.md item 3); ten percent more gain warns,
  ten times past the limit is refused, and a run past the limit stops with a
  named error instead of returning O(1) drift.
* The Suslov map: runs stay finite up to ``dt k ~ 1`` (the constraint mode,
  ``|e|^2 = 2``), accurate up to the estimate ``dt k = 2/2.618``.
* Automatic and adaptive gains; the split scheme is stable at any gain.

Everything here is fast (numpy backend, short horizons); the battery and the
maps of every scene are ``@pytest.mark.slow``.
"""

from __future__ import annotations

import math
import re
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.optimize import brentq
import pytest
from hypothesis import given
from hypothesis import strategies as st

import liefi
from liefi import scenes
from liefi.feedback import FeedbackIntegrator
from liefi.schemes import SCHEMES, IntegrationError
from liefi import gains as G
from liefi import stability as S
from liefi.experiments import battery as B
from liefi.experiments import stability_maps as M
from liefi.schemes import split as stiff
from liefi.scenes import exact as _exact

from strategies import PROPERTY, SPACES, cases


def knife_state(t):
    ke = scenes.get("knife-edge")
    ref = _exact.knife_edge(np.atleast_1d(t), m=1, J=1, g=1, alpha=np.pi / 6, p_phi0=0.5, x0=0, y0=0, phi0=0, v0=0)
    return np.stack([ref[n] for n in ke.integrator().names], -1)


# --- schemes ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(SCHEMES))
def test_real_stability_bound_matches_the_known_values_and_the_stability_polynomial(name):
    """The bound is derived from the tableau; it matches the classical values and the linear-solve ``R(z)``."""
    known = {"euler": 2.0, "heun": 2.0, "midpoint": 2.0, "rk3": 2.5127453266183286, "rk4": 2.785293563405282}
    sch = SCHEMES[name]
    beta = S.real_stability_bound(name)
    if name in known:
        assert beta == pytest.approx(known[name], abs=1e-9)
    else:  # the higher orders: the first crossing of |R(-x)| = 1, R(z) = 1 + z b^T (I - z A)^{-1} 1 by linear solves
        A = np.zeros((sch.stages, sch.stages))
        for i, row in enumerate(sch.A):
            A[i, :len(row)] = row
        b = np.asarray(sch.b)

        def excess(x):
            return abs(1.0 - x * b @ np.linalg.solve(np.eye(sch.stages) + x * A, np.ones(sch.stages))) - 1.0

        xs = np.linspace(1e-3, 10.0, 10001)
        i = next(j for j, x in enumerate(xs) if excess(x) > 0)
        assert beta == pytest.approx(brentq(excess, xs[i - 1], xs[i], xtol=1e-14), abs=1e-9)
    assert abs(sch.stability_polynomial(np.array([-beta]))[0]) == pytest.approx(1.0, abs=1e-9)
    assert abs(sch.stability_polynomial(np.array([-beta * 1.001]))[0]) > 1.0


def test_optimal_rate_minimizes_the_stability_function():
    assert G.optimal_rate("euler") == pytest.approx(1.0)  # R(-x) = 1 - x: the stiff mode removed in one step
    assert G.optimal_rate("heun") == pytest.approx(1.0)
    x = G.optimal_rate("rk4")
    R = np.abs(SCHEMES["rk4"].stability_polynomial(-np.linspace(0, 2.785, 300)))
    assert abs(SCHEMES["rk4"].stability_polynomial(np.array([-x]))[0]) <= R.min() + 1e-6
    assert math.isinf(S.resolve_scheme("imex-euler")[1])


def test_stable_dt_of_complex_spectrum_uses_the_polynomial():
    mu = np.array([1.0 + 1.0j, 1.0 - 1.0j])
    dt = S.stable_dt("euler", mu)
    assert abs(1 - dt * mu[0]) == pytest.approx(1.0, abs=1e-9)  # on the boundary of Euler's disc
    assert S.stable_dt("euler", np.array([4.0])) == pytest.approx(0.5)


# --- the Hessian of V on its zero set ------------------------------------------------------


@pytest.mark.parametrize("spec", [p for p in SPACES if p.id in ("cotangent", "lie-SO3", "bundle-SE2xS1", "lie-SO2")])
@given(data=st.data())
@PROPERTY
def test_gram_eigenvalue_equals_largest_eigenvalue_of_hessian_on_invariant_set(spec, data):
    case = data.draw(cases(spec, min_K=1))
    rng = case.rng
    z = case.constrained_state()
    G = case.space.group
    g = G.random_config(rng) if G.config_dim else np.zeros(0)
    fi0 = FeedbackIntegrator(case.system, np.concatenate([g, z]))
    gains = {k: float(rng.uniform(0.5, 3.0)) for k in fi0.invariant_names}
    fi = fi0.with_gains(gains)
    y = fi.y0  # on V^{-1}(0): every residual vanishes
    lam_gram = S.stiffness(fi, y).lam
    lam_full = S.stiffness(fi, y, exact=True).lam
    assert lam_gram == pytest.approx(lam_full, rel=1e-5, abs=1e-6)


def test_penalty_hessian_has_eigenvalues_two_and_zero_on_the_group():
    G = liefi.groups.SO3()
    R = G.random_config(np.random.default_rng(1))
    ev = np.sort(np.linalg.eigvalsh(stiff.penalty_hessian(G, R)))
    assert ev[:3] == pytest.approx(0.0, abs=1e-12)  # skew directions R W: tangent to the group
    assert ev[3:] == pytest.approx(2.0, abs=1e-12)  # symmetric directions R S


def test_knife_edge_paper_settings_sit_exactly_on_eulers_limit_at_t_pi():
    """docs/paper_notes.md item 3: lambda_max(Hess V) = k (1 + v^2) = 2k where the speed v = 1, i.e. t = pi."""
    fi = scenes.get("knife-edge").integrator()
    st_ = S.stiffness(fi, knife_state([0.0, np.pi]))
    assert st_.lam[0] == pytest.approx(1000 * (3 + np.sqrt(5)) / 4)  # (1.5 + sqrt(1.25))/2 at t = 0
    assert 1e-3 * st_.lam[1] == pytest.approx(2.0, rel=1e-12)
    assert st_.dominant[1] == "J_1"


# --- warnings, refusals, errors -------------------------------------------------------------


def test_estimate_finds_the_limit_along_the_run_not_at_the_start():
    fi = scenes.get("knife-edge").integrator()
    est = S.estimate(fi, 1e-3, "euler", t_final=4.0)
    assert est.lam0 * 1e-3 == pytest.approx(1.309, abs=1e-3)
    assert est.ratio == pytest.approx(1.0, abs=2e-3) and est.verdict == "limit"
    assert est.t_max == pytest.approx(np.pi, abs=0.05)


def test_knife_edge_with_ten_percent_more_gain_warns_with_safe_dt_and_gain():
    fi = scenes.get("knife-edge").integrator(gains=1100.0)
    with pytest.warns(S.LiefiStabilityWarning) as rec:
        est = S.check(fi, 1e-3, "euler", t_final=4.0)
    msg = str(rec[0].message)
    assert est.verdict == "beyond"
    assert "2.2 exceeds the stability bound 2 of euler" in msg
    assert "Largest safe dt at these gains: 0.0009091" in msg
    assert "largest safe gain at dt = 0.001: 1000" in msg
    assert issubclass(S.LiefiStabilityWarning, UserWarning)


def test_run_ten_times_past_the_limit_is_refused():
    fi = scenes.get("suslov").integrator(gains=1e5)
    with pytest.raises(ValueError, match="check_stability=False"):
        fi.run(0.01, dt=1e-3, scheme="euler", backend="numpy")


def test_run_past_the_limit_stops_instead_of_returning_drift():
    """Suslov at dt k = 0.9: finite numbers, but O(1) drift -- must end in a named error."""
    fi = scenes.get("suslov").integrator(gains=100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", S.LiefiStabilityWarning)
        with pytest.raises(S.StabilityError, match="drift of .* after dt\\*lambda_max exceeded") as info:
            fi.run(0.009 * 1000, dt=0.009, scheme="euler", backend="numpy")
    assert isinstance(info.value, IntegrationError) and info.value.t > 0


def test_non_finite_failure_reports_stiffness_and_safe_dt():
    fi = scenes.get("suslov").integrator(gains=100.0)
    with pytest.raises(IntegrationError, match=r"dt\*lambda_max = .* exceeds .*Largest safe dt there: 0.007"):
        fi.run(0.012 * 500, dt=0.012, check_stability=False, scheme="euler", backend="numpy")


def test_in_run_warning_when_the_stiffness_grows_past_the_pilot():
    """Heisenberg: lambda grows like |q|^2; a pilot limited to a tiny budget cannot see it, the monitor does."""
    h = scenes.get("heisenberg")
    fi = h.integrator("generic", gains=10.0)
    est = S.estimate(fi, 1e-2, "euler", t_final=40.0)
    assert est.t_max == pytest.approx(40.0) and est.lam > 10 * est.lam0


# --- segmented runs --------------------------------------------------------------------------


@pytest.mark.parametrize("save_every", [1, 7, 150, 333, 1000])
def test_segmented_run_with_the_guard_is_bit_identical_to_the_plain_run(save_every):
    fi = scenes.get("suslov").integrator()
    a = fi.run(1.2, dt=1e-3, save_every=save_every, monitor_every=97)
    b = fi.run(1.2, dt=1e-3, save_every=save_every, check_stability=False)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.y, b.y)
    assert a.t[-1] == pytest.approx(1.2) and a.stability.monitors > 0


def test_adaptive_with_fixed_gains_only_lowers_them():
    fi = scenes.get("knife-edge").integrator(gains=1000.0)
    sol = fi.run(0.5, dt=1e-3, adaptive=True)
    rep = sol.stability
    assert all(v <= 1000.0 + 1e-9 for g in [rep.gains] + rep.gain_history for v in g.values())
    assert rep.max_ratio <= 0.55  # dt lambda_max held at Euler's optimum 1 (ratio 1/2)


# --- automatic gains --------------------------------------------------------------------------


def test_unit_rate_and_auto_gains():
    fi = scenes.get("knife-edge").integrator()
    unit = fi.with_gains(G.unit_rate_gains(fi))
    assert S.stiffness(unit, fi.y0).lam == pytest.approx(1.0)
    auto = fi.with_gains(G.auto_gains(fi, 1e-3, "euler"))
    assert 1e-3 * S.stiffness(auto, fi.y0).lam == pytest.approx(1.0)  # Bae & Chang: k = 1/(dt L)
    fa = scenes.get("knife-edge").integrator(gains="auto")
    assert fa.gains_mode == "auto" and S.stiffness(fa, fa.y0).lam == pytest.approx(1.0)


def test_every_choice_of_gains_lives_in_gains_and_the_theory_calls_nothing_above_it():
    """stability.py: the stiffness, the bounds, the pilot; gains.py: every gain chosen from them."""
    import ast
    import pathlib

    for name in ("unit_rate_gains", "auto_gains", "optimal_rate", "rate_gains", "lowered_gains", "adapted_gains",
                 "run_gains", "exact_drops"):
        assert callable(getattr(G, name)) and not hasattr(S, name), name
    src = pathlib.Path(S.__file__).read_text()
    above = {"gains", "policy", "guard", "tolerance", "run", "feedback", "scenes"}
    for n in ast.walk(ast.parse(src)):  # lazy imports included
        if isinstance(n, ast.ImportFrom) and n.level:
            assert (n.module or "").split(".")[0] not in above, ast.unparse(n)


def test_run_gains_are_the_gains_a_run_starts_with():
    sc = scenes.get("knife-edge")
    fi = sc.integrator(gains="auto")
    dt, T = 1e-2, 1.0
    euler, rk4 = liefi.schemes.registry.get("euler"), liefi.schemes.registry.get("rk4")
    # Euler: z* = 1, near the bound 2: adapted at z*, from the unit-rate gains at the rate z*
    g = G.run_gains(fi, fi.y0, dt, euler, T)
    z, _ = G.accurate_setting(fi, dt, "euler", T)
    assert g.adaptive and g.rate == z and g.omega is not None
    assert g.fi.gains == G.rate_gains(G.unit_rate_gains(fi), z, dt)
    assert dt * float(S.stiffness(g.fi, fi.y0).lam) == pytest.approx(z, rel=1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = fi.run(T, dt=dt, scheme="euler", backend="numpy")
    assert sol.stability.adaptive and sol.stability.gains == g.fi.gains
    # RK4: z* far below the bound: the accurate gains, fixed
    g = G.run_gains(fi, fi.y0, dt, rk4, T)
    assert not g.adaptive and g.fi.gains == G.accurate_setting(fi, dt, "rk4", T)[1]
    # numeric gains, adaptive=True: lowered to the scheme's optimal rate where dt lambda_max passes it
    big = sc.integrator(gains=1e3)
    g = G.run_gains(big, big.y0, dt, rk4, T, adaptive=True)
    assert g.adaptive and g.rate == G.optimal_rate("rk4")
    assert dt * float(S.stiffness(g.fi, big.y0).lam) == pytest.approx(G.optimal_rate("rk4"), rel=1e-12)
    small = sc.integrator(gains=1e-3)
    assert G.run_gains(small, small.y0, dt, rk4, T, adaptive=True).fi.gains == small.gains  # below: kept
    assert G.run_gains(small, small.y0, dt, rk4, T).fi is small  # not adapted: as given


def test_adapted_gains_keep_the_rate_at_the_new_state():
    sc = scenes.get("heisenberg")
    fi = sc.integrator("generic", gains="auto")
    y = fi.y0.copy()
    y[fi.nc:] *= 3.0  # the stiffness grows with the state: the gains follow it
    dt, rate = 1e-3, 0.7
    new = fi.with_gains(G.adapted_gains(fi, y, rate, dt, auto=True))
    assert dt * float(S.stiffness(new, y).lam) == pytest.approx(rate, rel=1e-9)
    fixed = sc.integrator("generic", gains=1e4)
    low = fixed.with_gains(G.adapted_gains(fixed, y, rate, dt, auto=False))
    assert dt * float(S.stiffness(low, y).lam) == pytest.approx(rate, rel=1e-12)
    assert G.adapted_gains(fixed, y, rate, dt, auto=False, split=True) == fixed.gains  # a split scheme: kept


def test_heisenberg_generic_runs_with_adaptive_auto_gains_where_fixed_gains_are_refused():
    h = scenes.get("heisenberg")
    with pytest.raises(ValueError, match="dt\\*lambda_max"):
        h.run(variant="generic", gains=10.0, dt=1e-2, t_final=100.0)
    r = h.run(variant="generic", gains="auto", dt=1e-2, t_final=100.0)
    assert max(r.max_drift.values()) < 1e-9
    assert max(r.max_error.values()) < 1e-9


# --- the stiff-safe scheme -------------------------------------------------------------------------


def test_feedback_step_is_backward_euler_on_a_linear_gradient_flow():
    """V = k/2 (a.y)^2: the step multiplies the residual by 1/(1 + dt k |a|^2), for any k."""
    sysm = liefi.NonholonomicSystem(liefi.CotangentBundle(1), np.eye(1))
    a = np.array([0.0, 1.0])
    inv = liefi.Invariant("a.y", lambda z: z[..., 1], lambda z: np.broadcast_to(a, np.shape(z)))
    fi = FeedbackIntegrator(sysm, np.array([0.0, 1.0]), invariants=(inv,), gains=1e9)
    y = np.array([0.0, 3.0])
    yn = stiff.feedback_step(fi, y, 0.1)
    assert yn[1] - 1.0 == pytest.approx(2.0 / (1 + 0.1 * 1e9))


@pytest.mark.parametrize("name,cfg", [("knife-edge", False), ("roller-racer", True), ("oscillator", False),
                                      ("suslov", False)])
def test_feedback_step_through_the_gram_matrix_is_the_full_solve(name, cfg):
    """``y - dt A W^T (I + dt K W A W^T)^{-1} K r`` equals ``y - (I + dt A H)^{-1} dt A grad V`` with the
    Gauss--Newton Hessian ``H = W^T K W`` and ``grad V`` of field_parts (a second route), to rounding."""
    sc = scenes.get(name)
    fi0 = sc.integrator(configuration=cfg)
    rng = np.random.default_rng(3)
    y = fi0.y0 + 1e-2 * rng.standard_normal(fi0.n)
    n = fi0.n - fi0.nc
    A = np.eye(n) + 0.2 * np.diag(rng.uniform(size=n - 1), 1)  # non-symmetric, A + A^T > 0
    for fi in (fi0.with_gains({k: 2.0 + i for i, k in enumerate(fi0.invariant_names)}),
               FeedbackIntegrator(fi0.system, fi0.y0[fi0.nc:], invariants=(["constraints", "energy"] + fi0.user),
                                  gains=7.0, A=A, configuration=False)):
        yy = y[-fi.n:]
        for dt in (1e-3, 0.1, 10.0):
            jet = fi.invariant_gradients(yy)
            H = np.einsum("mi,m,mj->ij", jet.grad, jet.gains, jet.grad)
            AA = np.eye(fi.n) if fi.A is None else fi.A
            ref = yy - np.linalg.solve(np.eye(fi.n) + dt * AA @ H, dt * AA @ fi.grad_lyapunov(yy))
            got = stiff.feedback_step(fi, yy, dt)
            assert np.max(np.abs(got - ref)) <= 1e-13 * max(1.0, np.max(np.abs(yy)))


def test_feedback_step_on_the_penalty_is_newton_schulz_in_the_limit():
    """``g - dt k0 grad P / (1 + 2 dt k0)`` -> ``R (3I - R^T R)/2``: the defect of R^T R = I squares."""
    sc = scenes.get("suslov")
    fi = sc.integrator(configuration=True).with_gains({"penalty": 1e12, "J_1": 0.0, "energy": 0.0})
    G = fi.system.space.group
    y = fi.y0.copy()
    R = y[:9].reshape(3, 3) + 1e-4 * np.random.default_rng(4).standard_normal((3, 3))
    y[:9] = R.reshape(-1)
    yn = stiff.feedback_step(fi, y, 0.1)
    np.testing.assert_allclose(yn[:9].reshape(3, 3), R @ (3 * np.eye(3) - R.T @ R) / 2, atol=1e-11)
    d0 = np.linalg.norm(R.T @ R - np.eye(3))
    Rn = yn[:9].reshape(3, 3)
    assert np.linalg.norm(Rn.T @ Rn - np.eye(3)) < 10 * d0**2
    np.testing.assert_array_equal(yn[9:], y[9:])  # zero gains: the reduced block does not move
    assert G.penalty(yn[:9]) < 1e-6 * G.penalty(y[:9])  # P ~ d^2 -> d^4


def test_split_with_A_and_a_penalty_is_refused_by_name():
    sc = scenes.get("suslov")
    fi0 = sc.integrator(configuration=True)
    fi = FeedbackIntegrator(fi0.system, fi0.y0, A=np.eye(fi0.n))
    with pytest.raises(ValueError, match="A: the split schemes"):
        stiff.feedback_step(fi, fi.y0, 0.1)


def test_split_scheme_is_stable_at_any_gain():
    ke = scenes.get("knife-edge")
    with pytest.raises(ValueError):
        ke.run(gains=1e6, dt=1e-2, t_final=1.0)
    for scheme in ("imex-euler", "imex-rk4"):
        r = ke.run(gains=1e6, dt=1e-2, t_final=1.0, scheme=scheme)
        assert max(r.max_drift.values()) < 1e-8
    r = ke.run(gains=1e6, dt=1e-2, t_final=1.0, scheme="imex-rk4")
    assert max(r.max_error.values()) < 1e-9  # RK4 on X, projection-like feedback


def test_scipy_implicit_solvers_run_through_scene_run():
    r = scenes.get("knife-edge").run(scheme="scipy:Radau", t_final=1.0, gains=1e4, rtol=1e-8, atol=1e-10)
    assert max(r.max_drift.values()) < 1e-6


# --- the map -----------------------------------------------------------------------------------------


def test_suslov_map_reproduces_dt_k_one_and_the_estimate():
    m = M.stability_map("suslov", gains=[100.0], t_final=3.0, tol=0.02, backend="numpy")
    b = m.boundaries[0]
    assert 0.97 <= b.dt_finite * 100 <= 1.03  # finite up to dt k = 1: the constraint mode, k |e|^2 = 2k
    assert b.dt_estimate * 100 == pytest.approx(4 / (3 + math.sqrt(5)), rel=1e-3)  # 2 / 2.618
    assert b.dt_accurate >= 0.98 * b.dt_estimate  # accurate at least up to the estimate
    assert b.finite[1] / b.finite[0] <= 1.02 + 1e-9
    assert "| 100 |" in m.table()


def test_map_accepts_any_executor():
    with ThreadPoolExecutor(2) as ex:
        m = M.stability_map("suslov", gains=[100.0, 300.0], t_final=0.5, tol=0.1, backend="numpy", executor=ex)
    assert [b.gain for b in m.boundaries] == [100.0, 300.0]
    assert all(b.finite[0] is not None and b.finite[1] is not None for b in m.boundaries)


def test_plot_stability_map(tmp_path):
    pytest.importorskip("matplotlib")
    m = M.stability_map("suslov", gains=[100.0], t_final=0.5, tol=0.1, backend="numpy")
    M.plot_stability_map(m, tmp_path / "m.png")
    assert (tmp_path / "m.png").stat().st_size > 1000


# --- slow: the whole battery, the maps, the must-show run -------------------------------------------------


@pytest.mark.slow
def test_battery_has_no_silent_drift_and_no_crash():
    res = B.run_battery(quick=True)
    bad = [r for r in res if r.outcome in ("SILENT DRIFT", "CRASH")]
    assert not bad, B.battery_table(bad)


@pytest.mark.slow
@pytest.mark.parametrize("name", scenes.names())
def test_stability_map_of_every_scene(name):
    m = M.stability_map(name, gains=[10.0, 100.0, 1000.0], t_final=2.0, tol=0.05)
    for b in m.boundaries:
        assert b.finite[0] is not None


@pytest.mark.slow
def test_heisenberg_generic_auto_t1000():
    r = scenes.get("heisenberg").run(variant="generic", gains="auto", t_final=1000.0)
    assert max(r.max_drift.values()) < 1e-6


# --- the unforced motion's own growth is not the scheme's (issue: RK4 on Kepler refused) ------------------


def test_kepler_perihelion_growth_is_the_motion_not_the_scheme():
    """At perihelion Kepler's ``dX/dy`` has a real eigenvalue ``sqrt(2 mu / r^3)``: the motion stretches.

    RK4 at ``dt = 0.1`` follows that growth (``R(z) ~ exp(z)``), so it is not amplification;
    the growth against ``max(1, |exp(dt mu)|)`` stays 1 (it was 1.15 against 1).
    """
    fi = scenes.get("kepler").integrator()
    ev = S.dynamics_eigenvalues(fi, fi.y0)
    mu_real = float(np.max(ev.real))
    assert mu_real == pytest.approx(math.sqrt(2.0), rel=1e-6)  # r = 1, mu_K = 1 at the start (perihelion)
    raw = float(np.max(np.abs(SCHEMES["rk4"].stability_function(0.1 * ev))))
    assert raw > S.GROWTH_LIMIT  # the old criterion refused here
    assert S.dynamics_growth("rk4", 0.1, ev) <= 1.0 + 1e-6
    est = S.estimate(fi, 0.1, "rk4", y0=fi.y0)
    assert not est.unresolvable and not est.under_resolved


def test_kepler_rk4_at_dt_01_runs_accurately():
    fi = scenes.get("kepler").integrator(gains="auto")
    with warnings.catch_warnings():
        warnings.simplefilter("error", S.LiefiStabilityWarning)
        sol = fi.run(2 * 70.2481, dt=70.2481 / 700, scheme="rk4", backend="numpy")  # two periods, dt ~ 0.1
    ref = _exact.kepler(sol.t, fi.y0[:3], fi.y0[3:], 1.0)
    err = max(float(np.max(np.abs(ref[nm] - sol.y[i]))) for i, nm in enumerate(fi.names))
    assert err < 5e-2  # RK4 at dt*|mu| ~ 0.14 over two eccentric orbits: a phase error of ~1e-2, not garbage


def test_growth_refusal_suggests_a_smaller_step():
    """A step that truly amplifies the motion (RK4 past its imaginary-axis bound) is refused, the advice below it."""
    fi = scenes.get("kepler").integrator()
    dt = 3.0  # dt * |mu| ~ 4.2 at perihelion: past RK4's 2.83 on the imaginary axis
    est = S.estimate(fi, dt, "rk4", y0=fi.y0)
    assert est.unresolvable
    sugg = est.resolution_step()
    assert 0 < sugg < dt
    ev = S.dynamics_eigenvalues(fi, fi.y0)
    assert S.dynamics_growth("rk4", sugg, ev) <= S.GROWTH_LIMIT
    with pytest.raises(ValueError, match=r"take dt below ([0-9.e-]+)") as info:
        scenes.get("kepler").integrator(gains="auto").run(30.0, dt=dt, scheme="rk4", backend="numpy")
    said = float(re.search(r"take dt below ([0-9.e+-]+) \(", str(info.value)).group(1))
    assert said < dt


def test_resolution_message_never_suggests_a_larger_step():
    """Every refusal or warning of the resolution check names a step below the one given."""
    fi = scenes.get("rigid-body").integrator()
    for scheme in ("euler", "heun", "rk4"):
        for dt in (0.05, 0.3, 1.0, 3.0):
            est = S.estimate(fi, dt, scheme, y0=fi.y0)
            if est.under_resolved or est.unresolvable:
                assert est.resolution_step() < dt
                assert f"(dt = {dt:g} now)" in est.resolution_message()
