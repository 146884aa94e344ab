"""Output between the steps (``t_eval``, ``sol(t)``, event states) as accurate as the steps and on the
invariant set (issue 23): partial steps of the run's scheme (:mod:`liefi.dense`), checked against the knife
edge's exact solution; a ``t_eval`` time at a terminal event kept; a ``dt`` that does not divide the span
ending with one shortened step."""

import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from liefi import dense, scenes

XYPHI = ("x", "y", "phi")


@pytest.fixture(scope="module")
def knife():
    sc = scenes.get("knife-edge")
    return sc, sc.integrator()


def exact(sc, fi, t):
    ex = sc.exact(np.atleast_1d(np.asarray(t, float)), sc.variant(None))
    return np.stack([np.asarray(ex[nm], float) for nm in fi.names])


def error(sc, fi, t, Y):
    """Largest error of the configuration (x, y, phi) against the exact solution."""
    i = [fi.names.index(n) for n in XYPHI]
    return float(np.max(np.abs(Y[i] - exact(sc, fi, t)[i])))


def invariant_errors(fi, Y):
    """``(max |J_1|, max |energy - energy(y0)|)`` over the states ``Y`` (``(n, m)`` or ``(n,)``)."""
    vals = fi.invariant_values(np.asarray(Y).T)
    e0 = fi.invariant_values(fi.y0)["energy"]
    return float(np.max(np.abs(vals["J_1"]))), float(np.max(np.abs(np.asarray(vals["energy"]) - e0)))


def knife_table(sc, fi, T, rtols, backend):
    """Per rtol: the errors at the steps, at t_eval, in sol(t), and the invariants there and at an event."""
    te = np.linspace(0.0, T, 201)[:-1] + 0.37 * T / 200  # between the steps
    ip = fi.names.index("p_x")

    def event(t, y):
        return y[ip] - 0.2

    rows = {}
    for rtol in rtols:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = fi.run(T, rtol=rtol, backend=backend, t_eval=te, dense_output=True, events=event)
        steps_t = out.sol.ts  # the run's steps (every step saved)
        steps_y = out.sol(steps_t)  # their states: a saved time gives its saved state
        tm = np.sort(np.random.default_rng(1).uniform(0.0, T, 97))
        rows[rtol] = dict(
            steps=error(sc, fi, steps_t, steps_y), t_eval=error(sc, fi, te, out.y),
            sol=error(sc, fi, tm, out.sol(tm)), inv_t_eval=invariant_errors(fi, out.y),
            inv_sol=invariant_errors(fi, out.sol(tm)), inv_event=invariant_errors(fi, out.y_events[0].T),
            dt=out.dt, n_events=out.t_events[0].size,
        )
    return rows


def check_table(rows):
    for rtol, r in rows.items():
        floor = 1e-13  # rounding of the exact solution's evaluation and of the states
        assert r["t_eval"] <= 3 * r["steps"] + floor, (rtol, r)  # as accurate as the steps
        assert r["sol"] <= 3 * r["steps"] + floor, (rtol, r)
        assert r["t_eval"] <= rtol and r["sol"] <= rtol, (rtol, r)  # and within the tolerance
        for key in ("inv_t_eval", "inv_sol", "inv_event"):
            assert max(r[key]) <= 1e-12, (rtol, key, r)


def test_knife_edge_output_between_steps_meets_rtol_and_keeps_the_invariants(knife):
    """Quick version of the issue's table (horizon 2, numpy); before: t_eval off by 2.5e-4 at rtol 1e-6."""
    sc, fi = knife
    rows = knife_table(sc, fi, 2.0, (1e-6, 1e-8, 1e-10), "numpy")
    check_table(rows)
    assert all(r["dt"] > 0.2 and r["n_events"] >= 1 for r in rows.values())  # long steps: a cubic would miss


@pytest.mark.slow
def test_knife_edge_table_long_horizon(knife):
    """The issue's table on the scene's horizon 200, on the default backend."""
    sc, fi = knife
    check_table(knife_table(sc, fi, 200.0, (1e-6, 1e-8, 1e-10), None))


def test_event_state_is_a_partial_step_state(knife):
    """The event's state is the run's partial step to the event's time: sol(t_event) gives it back."""
    sc, fi = knife
    ip = fi.names.index("p_x")

    def event(t, y):
        return y[ip] - 0.2

    sol = fi.run(3.0, dt=0.25, scheme="imex-rk8", backend="numpy", events=event, dense_output=True)
    t_ev, y_ev = sol.t_events[0], sol.y_events[0]
    assert t_ev.size >= 2
    np.testing.assert_allclose(y_ev[:, ip], 0.2, atol=1e-13)
    np.testing.assert_array_equal(sol.sol(t_ev).T, y_ev)
    assert max(invariant_errors(fi, y_ev.T)) <= 1e-12
    i = [fi.names.index(n) for n in XYPHI]
    assert np.max(np.abs(y_ev.T[i] - exact(sc, fi, t_ev)[i])) <= 1e-9


@pytest.mark.parametrize("scheme", ["rk4", "imex-rk4"])
def test_partial_steps_join_the_steps(knife, scheme):
    """sol(t) is continuous: it starts at each step's state and ends at the next one's (h -> dt).

    (A split scheme's feedback step takes the state onto the invariant set within ``h ~ dt / z``, so it
    joins ``y_k`` to within the invariants' residual at ``y_k``: at rounding for imex-rk4 here, 1e-6 for
    the first-order imex-euler, whose states are that far off.)"""
    sc, _ = knife
    fi = sc.integrator(gains="auto")  # gains chosen for the step (the scene's 1000 are too stiff for rk4 here)
    sol = fi.run(1.0, dt=0.125, scheme=scheme, backend="numpy", dense_output=True)
    eps = 1e-9
    np.testing.assert_allclose(sol.sol(sol.t[:-1] + eps), sol.y[:, :-1], atol=1e-8)
    np.testing.assert_allclose(sol.sol(sol.t[1:] - eps), sol.y[:, 1:], atol=1e-8)
    assert sol.sol.order == sol.sol.stepper.sch.order


def test_saved_every_k_steps_gives_the_same_dense_output(knife):
    """With states saved every 4 steps the steps between are re-made: the same output as saving every step."""
    _, fi = knife
    tm = np.linspace(0.0, 1.0, 23)
    a = fi.run(1.0, dt=0.05, scheme="imex-rk4", backend="numpy", dense_output=True)
    b = fi.run(1.0, dt=0.05, scheme="imex-rk4", backend="numpy", dense_output=True, save_every=4)
    assert b.t.size < a.t.size
    np.testing.assert_allclose(b.sol(tm), a.sol(tm), rtol=0, atol=1e-14)


@pytest.mark.parametrize("scheme", ["imex-rk4", "rk4"])
def test_partial_steps_on_a_group_with_a_penalty(scheme):
    """The Suslov problem integrated on SO(3) (an embedding penalty): the partial steps keep R^T R = I
    as well as the steps do, and are as accurate as they are."""
    sc = scenes.get("suslov")
    fi = sc.integrator(configuration=True, gains="auto")

    def penalty(Y):
        R = Y[:9].T.reshape(-1, 3, 3)
        return np.max(np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = fi.run(0.5, dt=0.05, scheme=scheme, backend="numpy", dense_output=True)
        fine = fi.run(0.5, dt=0.0025, scheme="imex-rk4", backend="numpy", dense_output=True)
    tm = np.linspace(0.0, 0.5, 16) + 0.013
    tm[-1] = 0.5
    Y = sol.sol(tm)
    assert penalty(Y) <= 2 * penalty(sol.y) + 1e-14
    ref = fine.sol(tm)
    err_steps = np.max(np.abs(sol.y - fine.y[:, ::20]))
    assert np.max(np.abs(Y - ref)) <= 3 * err_steps + 1e-12


def test_batch_dense_output_matches_each_member(knife):
    _, fi = knife
    Y0 = np.stack([fi.y0, fi.y0 + np.r_[0.0, 0.1, 0.0, 0.0, 0.0, 0.0]])
    tm = np.array([0.05, 0.33, 0.71])
    both = fi.run(1.0, dt=0.1, scheme="imex-rk4", backend="numpy", y0=Y0, t_eval=tm)
    for b in range(2):
        one = fi.run(1.0, dt=0.1, scheme="imex-rk4", backend="numpy", y0=Y0[b], t_eval=tm)
        np.testing.assert_allclose(both.y[b], one.y, rtol=0, atol=1e-14)


# --- item: a t_eval time at a terminal event -------------------------------------------------------------------


def test_t_eval_time_equal_to_a_terminal_event_is_kept(knife):
    """scipy keeps a t_eval time equal to a terminal event's time; so does liefi, with the event's state."""
    sc, _ = knife
    fi = sc.integrator(gains=1.0)
    ip = fi.names.index("p_x")

    def event(t, y):
        return y[ip] - 0.2

    event.terminal = True
    first = fi.run(4.0, dt=0.1, scheme="imex-rk4", backend="numpy", events=event)
    t_ev = float(first.t_events[0][0])
    te = np.array([0.05, 0.5 * t_ev, t_ev, t_ev + 0.5])
    sol = fi.run(4.0, dt=0.1, scheme="imex-rk4", backend="numpy", events=event, t_eval=te)
    assert sol.status == 1
    np.testing.assert_array_equal(sol.t, te[:3])
    np.testing.assert_array_equal(sol.y[:, -1], sol.y_events[0][0])
    # scipy does the same with its own event time
    t_sp = solve_ivp(fi.fun, (0.0, 4.0), fi.y0, events=event, rtol=1e-9, atol=1e-12).t_events[0][0]
    ref = solve_ivp(fi.fun, (0.0, 4.0), fi.y0, t_eval=[0.05, 0.5 * t_sp, t_sp, t_sp + 0.5], events=event,
                    rtol=1e-9, atol=1e-12)
    assert ref.status == 1 and ref.t.size == 3 and ref.t[-1] == t_sp and abs(t_sp - t_ev) < 1e-6


# --- item: a dt that does not divide the span --------------------------------------------------------------------


def test_dt_not_dividing_the_span_shortens_the_last_step(knife):
    sc, _ = knife
    fi = sc.integrator(gains=1.0)
    sol = fi.run((0.5, 1.0), dt=0.3, scheme="rk4", backend="numpy", check_stability=False)
    np.testing.assert_allclose(sol.t, [0.5, 0.8, 1.0], rtol=0, atol=1e-15)
    assert sol.t[-1] == 1.0 and sol.steps == 2 and sol.success
    assert sol.method["last_step"] == pytest.approx(0.2) and "shortened to 0.2" in sol.method["why"]
    # the whole steps are the run's, bit for bit; the last one is a step of the scheme of 0.2
    grid = fi.run((0.5, 0.8), dt=0.3, scheme="rk4", backend="numpy", check_stability=False)
    np.testing.assert_array_equal(sol.y[:, :2], grid.y)
    assert error(sc, fi, sol.t[-1:], sol.y[:, -1:]) < 2 * error(sc, fi, sol.t[1:2], sol.y[:, 1:2]) + 1e-4 * 0.2**5
    with pytest.raises(ValueError, match="^dt: "):
        fi.run(1.0, dt=-0.3)


def test_shortened_last_step_keeps_order_and_invariants(knife):
    sc, fi = knife
    T = 1.03
    sol = fi.run(T, dt=0.1, scheme="imex-rk8", backend="numpy")
    assert sol.t[-1] == T and sol.steps == 11 and sol.method["last_step"] == pytest.approx(0.03)
    assert error(sc, fi, sol.t, sol.y) < 1e-10
    assert max(invariant_errors(fi, sol.y)) <= 1e-12
    one = fi.run(0.05, dt=0.1, scheme="imex-rk8", backend="numpy")  # dt longer than the span: one step
    assert one.steps == 1 and one.t.tolist() == [0.0, 0.05] and one.dt == 0.05
    assert "longer than the span" in one.method["why"]


def test_scene_run_with_a_dt_that_does_not_divide(knife):
    """``liefi run --dt`` goes through Scene.run: a dt that does not divide --t-final runs too."""
    sc, _ = knife
    r = sc.run(dt=0.03, t_final=1.0, scheme="rk4", gains="auto", backend="numpy")
    assert r.t[-1] == 1.0 and r.steps == 34 and r.method["last_step"] == pytest.approx(0.01)
    assert "shortened" in r.method["why"] and max(r.max_error.values()) < 1e-6


# --- item: an adaptive run's partial steps take the gains of the step they continue --------------------------------


def test_adaptive_gains_partial_and_remade_steps_use_the_gains_of_their_step():
    """Kepler, rk4, the paper's gains 4/2 adapted along the run (lowered to ~0.95 towards the apocentre, back to 4
    at the pericentre at the end).  Before, every partial step took the gains of the run's end: at the apocentre
    ``dt lambda_max`` was past RK4's stability bound, a step to ``t_{k+1}`` missed the run's own ``y_{k+1}`` by
    1e-6 (|R(-6.8)| = 53 on the drift) and the steps re-made between states saved every 10 were nan."""
    sc = scenes.get("kepler")
    fi = sc.integrator()
    kw = dict(dt=0.02, scheme="rk4", adaptive=True, dense_output=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        every = fi.run(70.0, **kw)
        sparse = fi.run(70.0, save_every=10, **kw)
    g = [h["L_x"] for h in every.stability.gain_history]
    assert min(g) < 0.3 * g[-1]  # the gains the run ends with are far above those of its middle
    # a step of the run's map from y_k to t_{k+1} (up to 1e-12) gives the run's y_{k+1} back
    np.testing.assert_allclose(every.sol(every.t[1:] - 1e-12), every.y[:, 1:], rtol=0, atol=1e-10)
    # and the states re-made between the saved ones are the run's: sparse.sol at the saved states of `sparse`
    # approached from the previous one (9 full steps re-made, then one of dt - 1e-12)
    near = np.nonzero((sparse.t > 25.0) & (sparse.t < 45.0))[0]  # around the apocentre, t = 35
    np.testing.assert_allclose(sparse.sol(sparse.t[near] - 1e-12), sparse.y[:, near], rtol=0, atol=1e-10)
    tm = np.linspace(0.0, 70.0, 41)[1:] - 0.0071  # between the steps
    ex = sc.exact(tm, sc.variant(None))
    ref = np.stack([np.asarray(ex[n], float) for n in fi.names])
    ex_steps = sc.exact(every.t, sc.variant(None))
    err_steps = np.max(np.abs(every.y - np.stack([np.asarray(ex_steps[n], float) for n in fi.names])))
    for sol in (every, sparse):
        assert np.max(np.abs(sol.sol(tm) - ref)) <= 2 * err_steps
