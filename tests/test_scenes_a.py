"""Scenes knife-edge, chaplygin, chaplygin-so2, vertical-disk against their exact solutions.

Three kinds of check:

* the scenes' *data* reproduce the paper's printed formulas, used here as
  oracles only (``h~``, ``lambda~``, ``e^flat`` and the extended fields are
  derived by liefi from metric + constraints + potential, never typed in a
  scene); where the paper slipped (docs/paper_notes.md items 2 and 4) the test says so;
* convergence on a short horizon, with bounds stated from the scheme's order:
  explicit Euler ``max error <= C_EULER dt`` and halving ``dt`` halves the
  error; RK4 ``max error <= C_RK4 dt^4`` and its log-ratio over a halving is 4;
  the feedback keeps every penalized invariant within ``C_DRIFT dt``;
* ``scipy.integrate.solve_ivp`` (DOP853) runs every scene, and the examples run.
"""

import importlib.util
import pathlib

import numpy as np
import pytest

import liefi
from liefi.scenes import get

T = 1.0  # short horizon for the convergence checks
DT = 1e-3
#: Euler: global error <= C_EULER * dt on [0, T].  Measured constants at T = 1:
#: knife edge 0.125, sleigh 0.112, disk 0.42 (the disk's error is Euler's on x, y).
C_EULER = 1.0
#: Feedback: an invariant sits where the O(dt^2) per-step defect balances the
#: O(k dt) contraction, so its drift is O(dt) (measured <= 7e-3 dt: sleigh's ||R^T R - I||).
C_DRIFT = 1e-2
#: RK4: global error and drift <= C_RK4 * dt^4 (measured: knife edge at gain 1000, whose
#: stiff feedback mode has |lambda| dt ~ 2, error 4.8e3 and drift of J_1 1.2e4; sleigh 48
#: and 1.3e3 (||R^T R - I||); disk roundoff).
C_RK4 = 3e4

CASES = [
    ("knife-edge", "extended"),
    ("knife-edge", "original"),
    ("chaplygin", "extended"),
    ("chaplygin", "original"),
    ("chaplygin-so2", "extended"),
    ("chaplygin-so2", "original"),
    ("vertical-disk", "further"),
    ("vertical-disk", "extended"),
]


def _max(d):
    return max(d.values()) if d else 0.0


# ------------------------------------------------------------------ convergence
@pytest.mark.parametrize("name,variant", CASES)
def test_euler_error_is_first_order(name, variant):
    s = get(name)
    r1 = s.run(variant=variant, dt=DT, t_final=T)
    r2 = s.run(variant=variant, dt=DT / 2, t_final=T)
    assert set(r1.max_error) == set(s.error_variables)
    e1, e2 = _max(r1.max_error), _max(r2.max_error)
    assert e1 <= C_EULER * DT, r1.max_error
    assert 1.8 < e1 / e2 < 2.2, (e1, e2)
    # the feedback keeps every monitored invariant within O(dt); halving dt halves it
    d1, d2 = _max(r1.max_drift), _max(r2.max_drift)
    assert d1 <= C_DRIFT * DT, r1.max_drift
    if d1 > 1e-12:
        assert 1.7 < d1 / d2 < 2.3, (r1.max_drift, r2.max_drift)


@pytest.mark.parametrize("name,variant", CASES)
def test_rk4_error_is_fourth_order_bound(name, variant):
    s = get(name)
    r = s.run(variant=variant, dt=DT, t_final=T, scheme="rk4")
    assert _max(r.max_error) <= C_RK4 * DT**4, r.max_error
    assert _max(r.max_drift) <= C_RK4 * DT**4, r.max_drift


@pytest.mark.parametrize("name", ["knife-edge", "chaplygin", "chaplygin-so2"])
def test_rk4_order(name):
    """Error ratio 2^4 over a halving of dt, at a gain where the feedback is not stiff.

    The gain does not change the exact solution (``V = 0`` along it), only
    the stiffness: at the knife edge's gain 1000 the stiff mode has
    ``|lambda| dt ~ 2`` and the asymptotic regime starts below ``dt ~ 5e-4``.
    """
    s = get(name)
    e = [_max(s.run(dt=dt, t_final=T, scheme="rk4", gains=10.0).max_error) for dt in (4e-3, 2e-3)]
    assert 14 < e[0] / e[1] < 18, e


@pytest.mark.parametrize("name", ["knife-edge", "chaplygin", "chaplygin-so2", "vertical-disk"])
def test_scipy_dop853(name):
    r = get(name).run(scheme="scipy:DOP853", t_final=0.5, rtol=1e-10, atol=1e-12)
    assert _max(r.max_error) < 1e-7, r.max_error
    assert _max(r.max_drift) < 1e-7, r.max_drift


@pytest.mark.filterwarnings("ignore::UserWarning")  # liefi rightly warns that this run is marginal
def test_knife_edge_paper_run_is_bounded_at_the_stability_limit():
    """k = 1000, dt = 1e-3: Euler's stiff mode sits at |1 - lambda dt| = 1 (docs/paper_notes.md item 3)."""
    r = get("knife-edge").run(t_final=5.0)
    assert _max(r.max_error) < 1e-3 and r.max_drift["J_1"] < 1e-6, (r.max_error, r.max_drift)


# ------------------------------------------------------------------ data vs the paper's formulas (oracles)
def _rng_states(n, nz, seed=0):
    return np.random.default_rng(seed).normal(size=(n, nz))


def test_knife_edge_derived_extension_matches_paper():
    s = get("knife-edge")
    sys = s.system
    m, J, g, al = s.m, s.J, s.g, s.alpha
    z = _rng_states(20, 6)
    x, y, phi, px, py, pphi = z.T
    c, sn = np.cos(phi), np.sin(phi)
    u = px * c + py * sn
    J1 = (px * sn - py * c) / np.sqrt(m)
    np.testing.assert_allclose(sys.constraint_momenta(z)[:, 0], J1, atol=1e-13)
    # H~ (two printed forms)
    Ht = u**2 / (2 * m) + pphi**2 / (2 * J) - m * g * x * np.sin(al)
    np.testing.assert_allclose(sys.extended_hamiltonian(z), Ht, atol=1e-13)
    # lambda~ as printed
    lam = (-m * g * np.sin(al) * sn - pphi * u / J) / np.sqrt(m)
    np.testing.assert_allclose(sys.extended_multipliers(z)[:, 0], lam, atol=1e-12)
    # extended field (ext:sys:kinfe) with grad_q H~ *corrected* (docs/paper_notes.md item 2):
    # the printed (-m g sin(alpha), 0, 0) lacks the phi-component -u J_1 / sqrt(m)
    grad_q = np.stack([np.full_like(x, -m * g * np.sin(al)), 0 * x, -u * J1 / np.sqrt(m)], -1)
    grad_p = np.stack([u * c / m, u * sn / m, pphi / J], -1)
    me = np.stack([sn, -c, 0 * x], -1) * np.sqrt(m)  # m e
    f = np.concatenate([grad_p, -grad_q + lam[:, None] * me], -1)
    np.testing.assert_allclose(sys.extended_vector_field(z), f, atol=1e-12)


def test_chaplygin_data_and_derived_extension_match_paper():
    s = get("chaplygin")
    m, I, a = s.m, s.I, s.a
    M = I + m * a * a
    e, inertia = s.constraint(), s.locked_inertia()
    assert np.isclose(e @ inertia @ e, 1.0)  # unit for the locked inertia
    np.testing.assert_allclose(inertia @ e, -m * I / np.sqrt(m * I * M) * np.array([0, 0, 1]), atol=1e-15)  # (e:flat:Chap)
    sys = s.system
    P = _rng_states(20, 3, seed=1)
    Pt, Px, Py = P.T
    # J = <Pi, e> is the paper's constraint m a Pi_theta - (I + m a^2) Pi_y, normalized
    np.testing.assert_allclose(sys.constraint_momenta(P)[:, 0], (m * a * Pt - M * Py) / np.sqrt(m * I * M), atol=1e-14)
    h = (Pt - a * Py) ** 2 / (2 * I) + (Px**2 + Py**2) / (2 * m)
    np.testing.assert_allclose(sys.hamiltonian(P), h, atol=1e-13)
    np.testing.assert_allclose(sys.extended_hamiltonian(P), Pt**2 / (2 * M) + Px**2 / (2 * m), atol=1e-13)  # (h:tilde:Chap)
    lam = -(Pt - a * Py) * Px / np.sqrt(m * I * M)  # (lambda:Chap)
    np.testing.assert_allclose(sys.extended_multipliers(P)[:, 0], lam, atol=1e-13)
    f = np.stack([-Px * Py / m, Pt * Py / M, -a * Px * Py / M], -1)  # (extended:system:Pi:Chap)
    np.testing.assert_allclose(sys.extended_vector_field(P), f, atol=1e-13)
    # reconstruction (extended:system:q:Chap) for both embeddings of the rotation
    th = np.random.default_rng(2).uniform(-3, 3, 20)
    q = np.stack([th, 0 * th, 0 * th], -1)
    qdot = np.stack([Pt / M, Px * np.cos(th) / m, Px * np.sin(th) / m], -1)
    np.testing.assert_allclose(sys.reconstruction(q, P), qdot, atol=1e-13)
    so2 = get("chaplygin-so2").system
    R = np.stack([np.cos(th), -np.sin(th), np.sin(th), np.cos(th)], -1)
    Jm = np.array([[0.0, 1.0], [-1.0, 0.0]])
    Rdot = -(Pt / M)[:, None, None] * R.reshape(-1, 2, 2) @ Jm  # (extended:SE2:SO2)
    gdot = so2.reconstruction(np.concatenate([R, 0 * q[:, :2]], -1), P)
    np.testing.assert_allclose(gdot[:, :4], Rdot.reshape(-1, 4), atol=1e-13)
    np.testing.assert_allclose(gdot[:, 4:], qdot[:, 1:], atol=1e-13)


def test_chaplygin_so2_penalty_gradient_contracts_and_printed_sign_diverges():
    """liefi's -grad_R V = -k0 R (R^T R - I) pulls R back to SO(2); the printed
    grad_R V = -k0 R (R^T R - I) (docs/paper_notes.md item 4) pushes it away."""
    s = get("chaplygin-so2")
    y0 = np.array(s.initial_state(s.variant()), float)
    y0[:4] *= 1.001  # R = 1.001 I: ||R^T R - I|| = 2.83e-3
    fi = s.integrator(y0=y0)
    orth = lambda y: 2 * np.sqrt(fi.system.space.group.penalty(y[..., :6]))  # noqa: E731
    o = orth(np.moveaxis(fi.run(0.2, dt=1e-3).y, -1, 0))
    o_ref = orth(np.moveaxis(s.integrator().run(0.2, dt=1e-3).y, -1, 0))  # from R = I
    # the offset decays like exp(-2 k0 t) = e^-40 down to Euler's own O(dt) floor (~7e-6)
    assert o[0] > 2e-3 and abs(o[-1] - o_ref[-1]) < 1e-10 and o_ref[-1] < C_DRIFT * DT

    def printed(y):
        g = fi.grad_lyapunov(y)
        g = np.concatenate([-g[..., :4], g[..., 4:]], -1)  # the paper's sign on the R block
        return fi.unforced_vector_field(y) - g

    bad = liefi.integrate(printed, y0, 1e-3, 20)
    assert orth(bad.y[..., -1]) > 10 * o[0]


def test_vertical_disk_derived_extension_matches_paper():
    s = get("vertical-disk")
    sys = s.system
    J, m, I, R = s.J, s.m, s.I, s.R
    Mr = I + m * R * R
    P = _rng_states(20, 4, seed=3)
    Pt, Px, Py, Pp = P.T
    np.testing.assert_allclose(sys.extended_hamiltonian(P), Pt**2 / (2 * J) + (R * Px + Pp) ** 2 / (2 * Mr), atol=1e-13)
    lam = np.stack([Pt * Px / (J * np.sqrt(m)), -I * Pt * Py / (J * np.sqrt(m * I * Mr))], -1)
    np.testing.assert_allclose(sys.extended_multipliers(P), lam, atol=1e-13)
    e1f = np.array([0, 0, np.sqrt(m), 0])
    e2f = np.array([0, m * I, 0, -m * R * I]) / np.sqrt(m * I * Mr)
    f = np.stack([-R * (R * Px + Pp) * Py / Mr, Pt * Py / J, -Pt * Px / J, 0 * Pt], -1)
    f = f + lam[:, :1] * e1f + lam[:, 1:] * e2f  # (extended:eqn:vertical:disk)
    np.testing.assert_allclose(sys.extended_vector_field(P), f, atol=1e-13)

    # liefi's "further" field: Pi' = 0 everywhere; its q' agrees with the paper's
    # (further:extended:eqn:vertical:disk) on C_red and differs off it.
    th = np.random.default_rng(4).uniform(-3, 3, 20)
    g = np.stack([th, 0 * th, 0 * th, 0 * th], -1)
    y = np.concatenate([g, P], -1)
    F = liefi.reduction.full_vector_field(sys, y, kind="projected")
    np.testing.assert_allclose(F[:, 4:], 0.0, atol=1e-13)
    w = (R * Px + Pp) / Mr
    np.testing.assert_allclose(F[:, :4], np.stack([Pt / J, R * w * np.cos(th), R * w * np.sin(th), w], -1), atol=1e-13)
    paper = lambda Pt, Px, Pp: np.stack([Pt / J, Px * np.cos(th) / m, Px * np.sin(th) / m, Pp / I], -1)  # noqa: E731
    assert np.max(np.abs(F[:, :4] - paper(Pt, Px, Pp))) > 0.1  # off C_red: different extensions
    Pc = sys.project(P)
    Fc = liefi.reduction.full_vector_field(sys, np.concatenate([g, Pc], -1), kind="projected")
    np.testing.assert_allclose(Fc[:, :4], paper(Pc[:, 0], Pc[:, 1], Pc[:, 3]), atol=1e-13)


def test_vertical_disk_further_converges_off_the_constraint_set():
    """(FI:vertical:disk): Pi' = -k (Pi - Pi0) exactly, so Euler gives (1 - k dt)^n."""
    s = get("vertical-disk")
    sys = s.system
    y0 = s.initial_state(s.variant("further"))
    nc = sys.space.group.config_dim
    target = dict(zip(sys.space.momentum_names, y0[nc:]))
    off = y0.copy()
    off[nc:] += [0.1, -0.2, 0.3, 0.1]
    k, dt, n = 10.0, 1e-3, 500
    fi = liefi.FeedbackIntegrator(sys, off, invariants=sys.space.momentum_names, gains=k,
                                  field="projected", targets=target)
    sol = fi.run(n * dt, dt=dt, scheme="euler", backend="numpy")
    np.testing.assert_allclose(sol.y[nc:, -1] - y0[nc:], (off - y0)[nc:] * (1 - k * dt) ** n, atol=1e-14)


def test_vertical_disk_names_and_initial_condition():
    s = get("vertical-disk")
    assert s.system.space.state_names == ("Pi_theta", "Pi_x", "Pi_y", "Pi_psi")
    Pi0 = s.Pi0()
    assert Pi0[2] == 0 and np.isclose(s.I * Pi0[1] - s.m * s.R * Pi0[3], 0)  # with the factor m (docs/paper_notes.md item 7)
    assert np.all(np.abs(s.system.constraint_momenta(Pi0)) < 1e-15)


# ------------------------------------------------------------------ examples
EXAMPLES = pathlib.Path(__file__).resolve().parent.parent / "examples"


def _load(name):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("name", ["knife_edge", "chaplygin"])
def test_example_runs(name, capsys):
    err, drift = _load(name).main(t_final=0.5)
    assert max(err.values()) < C_EULER * DT and max(drift.values()) < C_DRIFT * DT
    assert "max error" in capsys.readouterr().out


def test_example_vertical_disk_runs(capsys):
    res = _load("vertical_disk").main(t_final=0.5)
    assert set(res) == {"further", "extended"}
    assert all(_max(r.max_error) < C_EULER * DT for r in res.values())
    assert "off the constraint set" in capsys.readouterr().out
