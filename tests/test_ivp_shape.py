"""FeedbackIntegrator.run in the shape of scipy's solve_ivp: t_span, t_eval, events, dense output, the
OdeResult fields, the positional span and the retired old form, and fi.jac for scipy's implicit methods."""

import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import liefi
from liefi import _diff, scenes
from liefi.schemes import IntegrationError


@pytest.fixture(scope="module")
def knife():
    sc = scenes.get("knife-edge")
    return sc, sc.integrator(gains=1.0)


def exact_state(sc, fi, t):
    ex = sc.exact(np.atleast_1d(np.asarray(t, float)), sc.variant(None))
    return np.stack([np.asarray(ex[nm], float) for nm in fi.names])


# --- t_span --------------------------------------------------------------------------------------------------


def test_t_span_number_and_pair_start_where_asked(knife):
    _, fi = knife
    a = fi.run(1.0, dt=1e-2, scheme="rk4")
    b = fi.run((2.5, 3.5), dt=1e-2, scheme="rk4")
    assert a.t[0] == 0.0 and a.t[-1] == 1.0 and b.t[0] == 2.5 and b.t[-1] == 3.5
    np.testing.assert_allclose(b.t - 2.5, a.t, atol=1e-13)
    np.testing.assert_array_equal(a.y, b.y)  # the field is autonomous: the start time only shifts t
    assert a.success and a.status == 0 and "end of the integration interval" in a.message
    assert a.nfev == a.rhs_evaluations == 4 * 100
    assert a.t_events is None and a.sol is None and a.integrator is fi


@pytest.mark.parametrize("span, word", [((1.0, 1.0), "after the start"), ((2.0, 1.0), "after the start"),
                                        (np.nan, "finite"), ("10", "final time"), ((0, 1, 2), "final time"),
                                        (-1.0, "after the start")])
def test_bad_t_span_is_named(knife, span, word):
    _, fi = knife
    with pytest.raises(ValueError, match=f"^t_span: .*{word}"):
        fi.run(span, dt=1e-2)


def test_missing_dt_chooses_the_step_for_the_tolerance(knife):
    _, fi = knife
    sol = fi.run(1.0, scheme="rk4", backend="numpy")
    assert sol.method["rtol"] == 1e-6 and sol.steps * sol.dt == pytest.approx(1.0)
    with pytest.raises(ValueError, match=r"^rtol: give a step"):
        fi.run(1.0, dt=1e-2, rtol=1e-6, backend="numpy")
    with pytest.raises(TypeError, match="missing t_span"):
        fi.run(dt=1e-2)


def test_dt_divides_the_span_not_t_final(knife):
    _, fi = knife
    sol = fi.run((0.5, 1.0), dt=0.125, check_stability=False)
    assert sol.steps == 4 and "last_step" not in sol.method
    short = fi.run((0.5, 1.0), dt=0.3, check_stability=False)  # the last step shortened, as solve_ivp
    assert short.steps == 2 and short.t[-1] == 1.0 and short.method["last_step"] == pytest.approx(0.2)


def test_failure_times_count_from_t0(knife):
    sc, _ = knife
    fi = sc.integrator(gains=1e5)
    with pytest.raises(IntegrationError) as e:
        fi.run((100.0, 101.0), dt=1e-2, scheme="euler", check_stability=False)
    assert 100.0 <= e.value.t < 101.0
    assert f"t={e.value.t:g}" in str(e.value) and "(t=100" in str(e.value)


def test_errors_return_gives_a_failed_solution(knife):
    sc, _ = knife
    fi = sc.integrator(gains=1e5)
    sol = fi.run((100.0, 101.0), dt=1e-2, scheme="euler", check_stability=False, errors="return")
    assert not sol.success and sol.status == -1 and "non-finite" in sol.message
    assert sol.t[0] == 100.0 and sol.t[-1] < 101.0 and np.all(np.isfinite(sol.y))
    with pytest.raises(ValueError, match="^errors: "):
        fi.run(1.0, dt=1e-2, errors="ignore")


# --- the old form ---------------------------------------------------------------------------------------------


def test_two_positional_numbers_are_a_span_as_in_solve_ivp(knife):
    """fi.run(0.5, 10.0) is t_span = (0.5, 10.0), never the old run(dt=0.5, t_final=10.0)."""
    _, fi = knife
    pair = fi.run((0.5, 1.0), dt=1e-2, scheme="heun")
    two = fi.run(0.5, 1.0, dt=1e-2, scheme="heun")
    assert two.t[0] == 0.5 and two.t[-1] == 1.0 and two.dt == 1e-2
    np.testing.assert_array_equal(two.y, pair.y)
    zero = fi.run(0, 1, scheme="rk4", backend="numpy")  # was "dt: ... got 0"
    assert zero.t[0] == 0.0 and zero.t[-1] == 1.0 and zero.steps > 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fi.run(0.5, 1.0, dt=1e-2, scheme="heun")  # no warning either


def test_old_form_is_retired_with_the_new_call(knife):
    _, fi = knife
    with pytest.raises(TypeError, match=r"retired.*write run\(0.5, dt=0.01, scheme='heun'\)"):
        fi.run(1e-2, 0.5, "heun")
    with pytest.raises(TypeError, match=r"^t_final: run\(\) does not take t_final=.*run\(\(t0, t_final\), dt=\.\.\.\)"):
        fi.run(dt=1e-2, t_final=0.5, scheme="heun")
    with pytest.raises(TypeError, match="takes t_span positionally"):
        fi.run(0.5, "rk4")


# --- t_eval and dense output -----------------------------------------------------------------------------------


def test_t_eval_on_the_grid_returns_the_saved_states(knife):
    _, fi = knife
    full = fi.run(0.5, dt=1e-2, scheme="rk4")
    te = full.t[::10]
    sol = fi.run(0.5, dt=1e-2, scheme="rk4", t_eval=te)
    np.testing.assert_array_equal(sol.t, te)
    np.testing.assert_allclose(sol.y, full.y[:, ::10], rtol=0, atol=1e-15)


def test_dense_output_has_the_order_of_the_steps(knife):
    """Between states h apart the dense output (partial steps of RK4) is as accurate as the steps: no
    interpolation error that grows as h^4 (the cubic Hermite interpolant it replaced, issue 23)."""
    sc, fi = knife
    errs = []
    for k in (10, 20):
        sol = fi.run(1.0, dt=5e-3, scheme="rk4", save_every=k, dense_output=True)
        mid = 0.5 * (sol.t[:-1] + sol.t[1:])
        errs.append(np.max(np.abs(sol.sol(mid) - exact_state(sc, fi, mid))))
    nodes = np.max(np.abs(sol.y - exact_state(sc, fi, sol.t)))
    assert errs[0] < 3 * nodes + 1e-15 and errs[1] < 3 * nodes + 1e-15
    assert sol.sol.order == 4


def test_dense_output_calls_like_odesolution(knife):
    _, fi = knife
    sol = fi.run((1.0, 2.0), dt=2e-2, scheme="rk4", dense_output=True)
    assert sol.sol(1.5).shape == (fi.n,) and sol.sol(np.array([1.0, 1.5, 2.0])).shape == (fi.n, 3)
    np.testing.assert_allclose(sol.sol(sol.t), sol.y, atol=1e-15)
    assert sol.sol.t_min == 1.0 and sol.sol.t_max == 2.0
    with pytest.raises(ValueError, match=r"t: the dense output covers \[1, 2\]"):
        sol.sol(2.5)
    with pytest.raises(ValueError, match="t_eval: times must lie in t_span"):
        fi.run((1.0, 2.0), dt=1e-2, t_eval=[0.5])
    with pytest.raises(ValueError, match="t_eval: times must be sorted"):
        fi.run((1.0, 2.0), dt=1e-2, t_eval=[1.5, 1.2])


def test_batch_t_eval_and_dense_output(knife):
    _, fi = knife
    Y0 = np.stack([fi.y0, fi.y0])
    Y0[1, 3:5] *= 1.0  # same start, so both members must agree
    sol = fi.run((0.0, 0.5), dt=1e-2, scheme="rk4", y0=Y0, t_eval=[0.105, 0.25], dense_output=True)
    one = fi.run((0.0, 0.5), dt=1e-2, scheme="rk4", t_eval=[0.105, 0.25])
    assert sol.y.shape == (2, fi.n, 2) and sol.sol(0.3).shape == (2, fi.n)
    np.testing.assert_allclose(sol.y[0], one.y, atol=1e-14)
    with pytest.raises(ValueError, match=r"events: only for a single trajectory"):
        fi.run(0.5, dt=1e-2, y0=Y0, events=lambda t, y: y[0])


# --- events ----------------------------------------------------------------------------------------------------


def _level(fi, name, c):
    i = fi.names.index(name)
    return lambda t, y: y[i] - c


def test_event_times_match_the_exact_solution(knife):
    sc, fi = knife
    ev = _level(fi, "p_x", 0.2)  # p_x oscillates: crossings in both directions
    sol = fi.run(8.0, dt=1e-2, scheme="rk4", events=ev)
    i = fi.names.index("p_x")
    t = np.linspace(0, 8, 8001)
    g = exact_state(sc, fi, t)[i] - 0.2
    roots = [brentq(lambda s: exact_state(sc, fi, s)[i, 0] - 0.2, t[j], t[j + 1])
             for j in np.nonzero(np.sign(g[:-1]) != np.sign(g[1:]))[0]]
    assert len(roots) >= 3 and sol.t_events[0].shape == (len(roots),)
    np.testing.assert_allclose(sol.t_events[0], roots, atol=1e-8)
    np.testing.assert_allclose(sol.y_events[0][:, i], 0.2, atol=1e-12)
    assert sol.status == 0 and sol.t[-1] == 8.0


def test_event_direction_and_terminal(knife):
    _, fi = knife
    both = _level(fi, "p_x", 0.2)
    up, down = _level(fi, "p_x", 0.2), _level(fi, "p_x", 0.2)
    up.direction, down.direction = 1, -1
    sol = fi.run(8.0, dt=2e-2, scheme="rk4", events=[both, up, down], dense_output=True)
    t_all, t_up, t_dn = sol.t_events
    assert len(t_up) >= 1 and len(t_dn) >= 1 and len(t_up) + len(t_dn) == len(t_all)
    np.testing.assert_allclose(np.sort(np.r_[t_up, t_dn]), t_all, atol=1e-12)
    i = fi.names.index("p_x")
    assert np.all(sol.sol(t_up + 1e-3)[i] > 0.2) and np.all(sol.sol(t_dn + 1e-3)[i] < 0.2)
    stop = _level(fi, "p_x", 0.2)
    stop.terminal, stop.direction = True, -1
    s = fi.run(8.0, dt=2e-2, scheme="rk4", events=stop, dense_output=True)
    assert s.status == 1 and s.success and s.message == "A termination event occurred."
    assert s.t[-1] == t_dn[0] and s.t_events[0].shape == (1,)
    np.testing.assert_allclose(s.y[:, -1], s.y_events[0][0])
    assert s.sol.t_max == t_dn[0]
    second = _level(fi, "p_x", 0.2)
    second.terminal = 2
    assert fi.run(8.0, dt=2e-2, scheme="rk4", events=second).t[-1] == t_all[1]


def test_bad_events_are_named(knife):
    _, fi = knife
    with pytest.raises(TypeError, match=r"events\[1\]: expected a callable"):
        fi.run(1.0, dt=1e-2, events=[lambda t, y: y[0], 3])
    bad = _level(fi, "x", 0.0)
    bad.terminal = "yes"
    with pytest.raises(ValueError, match=r"events\[0\].terminal"):
        fi.run(1.0, dt=1e-2, events=bad)
    with pytest.raises(ValueError, match=r"events\[0\]: event\(t, y\) must return a number"):
        fi.run(1.0, dt=1e-2, events=lambda t, y: "no")


def test_compiled_backend_in_the_new_shape(knife):
    pytest.importorskip("numba")
    _, fi = knife
    kw = dict(dt=2e-2, scheme="rk4", t_eval=np.linspace(1.0, 3.0, 9), dense_output=True, events=_level(fi, "p_x", 0.2))
    a = fi.run((1.0, 3.0), **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a missing cache directory or compiler falls back with a warning
        b = fi.run((1.0, 3.0), backend="numba", **kw)
    np.testing.assert_allclose(b.y, a.y, atol=1e-12)
    np.testing.assert_allclose(b.t_events[0], a.t_events[0], atol=1e-12)
    np.testing.assert_allclose(b.sol(2.2), a.sol(2.2), atol=1e-12)


# --- fi.jac ----------------------------------------------------------------------------------------------------


def readme_integrator():
    from liefi.groups import SE2

    def metric(x):
        c = np.cos(x[..., 0]); one = np.ones_like(c); zero = 0 * c  # noqa: E702
        return np.stack([np.stack([2 + 0.5 * c, zero, 0.3 * one, 0.4 * one], -1),
                         np.stack([zero, one, zero, zero], -1),
                         np.stack([0.3 * one, zero, one, zero], -1),
                         np.stack([0.4 * one, zero, zero, 0.5 * one], -1)], -2)

    def A(x):
        s = np.sin(x[..., 0]); one = np.ones_like(s); zero = 0 * s  # noqa: E702
        return np.stack([np.stack([zero, zero, one, zero], -1), np.stack([0.2 * s, one, zero, -one], -1)], -2)

    racer = liefi.NonholonomicSystem.from_velocity_constraints(
        liefi.TrivialPrincipalBundle(SE2(), 1, names=("psi",)), metric, A)
    z0 = racer.project(np.array([0.3, 1.0, 0.5, 0.0, -0.2]))
    return liefi.FeedbackIntegrator(racer, np.concatenate([SE2().identity_config(), z0]), gains=10.0)


def central_difference(f, y, h=1e-6):
    return np.stack([(f(0.0, y + h * e) - f(0.0, y - h * e)) / (2 * h) for e in np.eye(y.size)], -1)


@pytest.mark.parametrize("name", ["readme", "knife-edge", "rigid-body", "chaplygin"])
def test_jac_against_a_central_difference(name):
    fi = readme_integrator() if name == "readme" else scenes.get(name).integrator(gains=3.0)
    y = fi.y0 + 0.05 * np.sin(1.0 + np.arange(fi.n))  # off the invariant set: the feedback term counts
    J = fi.jac(0.0, y)
    assert J.shape == (fi.n, fi.n)
    scale = np.max(np.abs(J))
    assert np.max(np.abs(J - central_difference(fi.fun, y))) < 1e-7 * scale
    assert np.max(np.abs(J - fi.jac(0.0, y))) == 0.0


@pytest.mark.parametrize("name", ["rigid-body", "chaplygin", "suslov"])
def test_jac_equals_a_complex_step_of_fun(name):
    """Where the data do not depend on x the numpy field takes complex input: both are exact."""
    fi = scenes.get(name).integrator(gains=3.0)
    y = fi.y0 + 0.05 * np.sin(1.0 + np.arange(fi.n))
    h = _diff.STEP
    Jc = np.stack([fi.fun(0.0, y + 1j * h * e).imag / h for e in np.eye(fi.n)], -1)  # column k: d fun / d y_k
    J = fi.jac(0.0, y)
    assert np.max(np.abs(J - Jc)) <= 1e-13 * np.max(np.abs(J))


def test_radau_and_bdf_with_jac_use_no_finite_differences():
    fi = readme_integrator()
    calls = {"fd": 0, "jac": 0}

    def counted(key):
        def fun(t, y):
            calls[key] += 1
            return fi.fun(t, y)
        return fun

    a = solve_ivp(counted("fd"), (0, 1.0), fi.y0, method="Radau", rtol=1e-8, atol=1e-10)
    b = solve_ivp(counted("jac"), (0, 1.0), fi.y0, method="Radau", rtol=1e-8, atol=1e-10, jac=fi.jac)
    assert a.success and b.success and b.njev >= 1
    assert calls["jac"] == b.nfev  # every call is the solver's own: no finite differences
    assert calls["fd"] >= a.nfev + a.njev * fi.n  # finite differences: n more calls per Jacobian
    np.testing.assert_allclose(b.y[:, -1], a.y[:, -1], atol=1e-7)
    c = solve_ivp(fi.fun, (0, 1.0), fi.y0, method="BDF", rtol=1e-8, atol=1e-10, jac=fi.jac)
    np.testing.assert_allclose(c.y[:, -1], a.y[:, -1], atol=1e-6)


def test_jac_refuses_a_bad_state(knife):
    _, fi = knife
    with pytest.raises(ValueError, match="^y: expected a state of 6 numbers"):
        fi.jac(0.0, np.zeros(4))


def test_a_zero_on_a_saved_state_is_one_event(knife):
    _, fi = knife
    sol = fi.run(1.0, dt=0.05, scheme="rk4", events=lambda t, y: t - 0.5)  # 0.5 = 10 * 0.05 exactly
    assert sol.t_events[0].tolist() == [0.5]
    np.testing.assert_array_equal(sol.y_events[0][0], sol.y[:, 10])
