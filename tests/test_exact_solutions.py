"""Closed forms of ``liefi.scenes.exact`` against an independent numerical oracle.

The oracle is written here only: the Lagrange--d'Alembert equations with a
*constant* mass matrix ``M`` (chosen coordinates: centre of mass for the
Chaplygin sleigh),

    M q'' = F(q) + A(q)^T lambda,      A(q) q' = 0,

with the multiplier solved from ``d/dt (A q') = 0``:

    (A M^-1 A^T) lambda = -(A M^-1 F + A' q').

For the Suslov problem the reduced (Euler--Poincare--Suslov) form
``Pi' = Pi x Omega + lambda a`` with ``lambda`` from ``d/dt (a . Omega) = 0`` is
used.  Everything is integrated with DOP853 at rtol = atol = 1e-12.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from liefi.scenes import exact

TOL = 1e-9
SOLVER = dict(method="DOP853", rtol=1e-12, atol=1e-12)


def _integrate(rhs, y0, t_end, n=41):
    t = np.linspace(0.0, t_end, n)
    sol = solve_ivp(rhs, (0.0, t_end), np.asarray(y0, dtype=float), t_eval=t, **SOLVER)
    assert sol.success, sol.message
    return t, sol.y


def _lda_rhs(mass, force, A, Adot):
    """Lagrange-d'Alembert field on (q, q') for a constant diagonal mass matrix."""
    minv = 1.0 / np.asarray(mass, dtype=float)
    n = minv.size

    def rhs(_t, state):
        q, qd = state[:n], state[n:]
        F = force(q)
        Aq = np.atleast_2d(A(q))
        G = (Aq * minv) @ Aq.T
        b = -(Aq @ (minv * F) + np.atleast_2d(Adot(q, qd)) @ qd)
        lam = np.linalg.solve(G, b)
        return np.concatenate([qd, minv * (F + Aq.T @ lam)])

    return rhs


def _close(exact_value, numeric_value, tol=TOL):
    err = np.max(np.abs(np.asarray(exact_value) - np.asarray(numeric_value)))
    assert err < tol, err
    return err


# ----------------------------------------------------------------------------
# Suslov
# ----------------------------------------------------------------------------

II = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 1.0, 2.0]])
II_INV = np.linalg.inv(II)
A_SUSLOV = np.array([0.0, 0.0, 1.0])


def _suslov_rhs(_t, Pi):
    Om = II_INV @ Pi
    f = np.cross(Pi, Om)
    w = II_INV @ A_SUSLOV
    lam = -(w @ f) / (w @ A_SUSLOV)  # keeps a . Omega = a . II^-1 Pi constant
    return f + lam * A_SUSLOV


@pytest.mark.parametrize(
    "Pi0",
    [(0.0, 1.0, 1.0), (0.7, -0.4, -0.4), (-2.0, 0.3, 0.3), (1.5, 0.0, 0.0)],
)
def test_suslov(Pi0):
    t, Y = _integrate(_suslov_rhs, Pi0, 5.0)
    sol = exact.suslov(t, Pi0=Pi0)
    for i, key in enumerate(("Pi_1", "Pi_2", "Pi_3")):
        _close(sol[key], Y[i])


def test_suslov_paper_formula_and_constraint():
    t = np.linspace(0.0, 10.0, 101)
    sol = exact.suslov(t)
    _close(sol["Pi_1"], -np.tanh(t), 1e-15)
    _close(sol["Pi_2"], 1.0 / np.cosh(t), 1e-15)
    Pi = np.stack([sol["Pi_1"], sol["Pi_2"], sol["Pi_3"]], axis=-1)
    e = II_INV @ A_SUSLOV / np.sqrt(A_SUSLOV @ II_INV @ A_SUSLOV)
    _close(Pi @ e, 0.0, 1e-15)
    h = 0.5 * np.einsum("...i,ij,...j->...", Pi, II_INV, Pi)
    _close(h, 0.5, 1e-14)
    with pytest.raises(ValueError):
        exact.suslov(t, Pi0=(0.0, 1.0, 1.1))


# ----------------------------------------------------------------------------
# knife edge
# ----------------------------------------------------------------------------

def _knife_rhs(m, J, g, alpha):
    return _lda_rhs(
        (m, m, J),
        lambda q: np.array([m * g * np.sin(alpha), 0.0, 0.0]),
        lambda q: np.array([np.sin(q[2]), -np.cos(q[2]), 0.0]),
        lambda q, qd: qd[2] * np.array([np.cos(q[2]), np.sin(q[2]), 0.0]),
    )


KNIFE_CASES = [
    dict(),  # the paper's data
    dict(m=2.0, J=0.5, g=9.81, alpha=0.3, p_phi0=-1.3, x0=0.2, y0=-1.0, phi0=0.7, v0=0.4),
    dict(m=0.7, J=1.3, g=1.0, alpha=1.0, p_phi0=0.0, phi0=-0.4, v0=-0.3),
    dict(m=1.0, J=1.0, g=2.0, alpha=0.5, p_phi0=1e-7, phi0=2.0, v0=1.0),
]


@pytest.mark.parametrize("case", KNIFE_CASES)
def test_knife_edge(case):
    p = dict(m=1.0, J=1.0, g=1.0, alpha=np.pi / 6, p_phi0=0.5, x0=0.0, y0=0.0, phi0=0.0, v0=0.0)
    p.update(case)
    q0 = (p["x0"], p["y0"], p["phi0"])
    qd0 = (p["v0"] * np.cos(p["phi0"]), p["v0"] * np.sin(p["phi0"]), p["p_phi0"] / p["J"])
    t, Y = _integrate(_knife_rhs(p["m"], p["J"], p["g"], p["alpha"]), q0 + qd0, 6.0)
    sol = exact.knife_edge(t, **p)
    for i, key in enumerate(("x", "y", "phi")):
        _close(sol[key], Y[i])
    mass = (p["m"], p["m"], p["J"])
    for i, key in enumerate(("p_x", "p_y", "p_phi")):
        _close(sol[key], mass[i] * Y[3 + i])
    # constraint and energy along the closed form
    _close(sol["p_x"] * np.sin(sol["phi"]) - sol["p_y"] * np.cos(sol["phi"]), 0.0, 1e-13)
    H = ((sol["p_x"] ** 2 + sol["p_y"] ** 2) / (2 * p["m"]) + sol["p_phi"] ** 2 / (2 * p["J"])
         - p["m"] * p["g"] * sol["x"] * np.sin(p["alpha"]))
    _close(H, H[0], 1e-12)


def test_knife_edge_notes_item_1():
    """docs/paper_notes.md item 1: with the paper's data x = (1 - cos t)/2, phi = t/2."""
    t = np.linspace(0.0, 200.0, 2001)
    sol = exact.knife_edge(t)
    _close(sol["x"], (1.0 - np.cos(t)) / 2.0, 1e-13)
    _close(sol["y"], (t - np.sin(t)) / 2.0, 1e-12)
    _close(sol["phi"], t / 2.0, 1e-13)
    # and the printed x = 1 - cos t, phi = t are not the solution
    assert np.max(np.abs(sol["x"] - (1.0 - np.cos(t)))) > 0.5
    # the oracle agrees with the corrected formulas
    tn, Y = _integrate(_knife_rhs(1.0, 1.0, 1.0, np.pi / 6), (0, 0, 0, 0, 0, 0.5), 12.0)
    _close((1.0 - np.cos(tn)) / 2.0, Y[0])
    _close((tn - np.sin(tn)) / 2.0, Y[1])
    _close(tn / 2.0, Y[2])


def test_knife_edge_small_omega_limit():
    t = np.linspace(0.0, 3.0, 7)
    base = dict(g=1.3, alpha=0.4, phi0=0.9, v0=-0.2)
    s0 = exact.knife_edge(t, p_phi0=0.0, **base)
    s1 = exact.knife_edge(t, p_phi0=1e-9, **base)
    G = 1.3 * np.sin(0.4)
    _close(s0["x"], np.cos(0.9) * (-0.2 * t + 0.5 * G * np.cos(0.9) * t**2), 1e-15)
    _close(s0["y"], np.sin(0.9) * (-0.2 * t + 0.5 * G * np.cos(0.9) * t**2), 1e-15)
    for key in s0:
        _close(s0[key], s1[key], 1e-8)


# ----------------------------------------------------------------------------
# Chaplygin sleigh
# ----------------------------------------------------------------------------

def _chaplygin_oracle(m, I, a, theta0, v0, w0, t_end):
    """Centre-of-mass coordinates (xc, yc, theta): M = diag(m, m, I) constant.

    Constraint: the contact point (xc, yc) - a (cos th, sin th) has no lateral
    velocity, -xc' sin th + yc' cos th - a th' = 0.
    """
    rhs = _lda_rhs(
        (m, m, I),
        lambda q: np.zeros(3),
        lambda q: np.array([-np.sin(q[2]), np.cos(q[2]), -a]),
        lambda q, qd: qd[2] * np.array([-np.cos(q[2]), -np.sin(q[2]), 0.0]),
    )
    c, s = np.cos(theta0), np.sin(theta0)
    lat = a * w0  # lateral velocity of the centre of mass
    y0 = (a * c, a * s, theta0, v0 * c - lat * s, v0 * s + lat * c, w0)
    t, Y = _integrate(rhs, y0, t_end)
    th, xd, yd, thd = Y[2], Y[3], Y[4], Y[5]
    Pi_x = m * (xd * np.cos(th) + yd * np.sin(th))
    Pi_y = m * (-xd * np.sin(th) + yd * np.cos(th))
    Pi_theta = I * thd + a * Pi_y  # p_theta in contact-point coordinates
    return t, dict(theta=th, Pi_theta=Pi_theta, Pi_x=Pi_x, Pi_y=Pi_y)


CHAPLYGIN_CASES = [
    # m, I, a, theta0, v0, omega0, t_end
    (1.0, 1.0, 1.0, 0.0, 0.0, 1.0, 6.0),
    (2.0, 0.5, 0.3, 0.4, -0.8, 1.7, 6.0),
    (1.0, 2.0, -0.7, -1.0, 0.5, -0.9, 6.0),
    (1.5, 1.0, 2.0, 0.3, 2.0, 0.2, 4.0),   # |k t| large: v saturates
    (1.0, 1.0, 1e-6, 0.2, 0.3, 0.8, 5.0),  # nearly a = 0
    (1.0, 1.0, 0.0, 0.2, 0.3, 0.8, 5.0),   # a = 0
    (1.0, 1.0, 0.8, 0.5, 1.2, 0.0, 5.0),   # omega0 = 0
    (1.0, 1.0, 0.8, 0.5, 0.0, -1e-3, 5.0),  # slowly turning
]


@pytest.mark.parametrize("m, I, a, theta0, v0, w0, t_end", CHAPLYGIN_CASES)
def test_chaplygin(m, I, a, theta0, v0, w0, t_end):
    M = I + m * a * a
    Pi0 = (M * w0, m * v0, m * a * w0)
    t, ref = _chaplygin_oracle(m, I, a, theta0, v0, w0, t_end)
    sol = exact.chaplygin(t, m, I, a, theta0, Pi0)
    for key in ("theta", "Pi_theta", "Pi_x", "Pi_y"):
        _close(sol[key], ref[key])
    # constraint and energy m v^2 + M omega^2 along the closed form
    _close(m * a * sol["Pi_theta"] - M * sol["Pi_y"], 0.0, 1e-12)
    E = sol["Pi_x"] ** 2 / m + sol["Pi_theta"] ** 2 / M
    _close(E, E[0], 1e-12)


def test_chaplygin_long_time_and_errors():
    t = np.array([0.0, 1e3, 1e5])
    sol = exact.chaplygin(t, 1.0, 1.0, 1.0, 0.0, (2.0, 0.0, 1.0))
    assert np.all(np.isfinite(np.stack(list(sol.values()))))
    # omega0 = 1 (M = 2), v0 = 0: total turn sqrt(M/m) * pi/2 / a
    assert abs(sol["theta"][-1] - np.sqrt(2.0) * np.pi / 2) < 1e-12
    with pytest.raises(ValueError):
        exact.chaplygin(t, 1.0, 1.0, 1.0, 0.0, (2.0, 0.0, 0.5))


# ----------------------------------------------------------------------------
# vertical rolling disk
# ----------------------------------------------------------------------------

def _disk_rhs(R):
    def A(q):
        th = q[0]
        return np.array([[0.0, 1.0, 0.0, -R * np.cos(th)], [0.0, 0.0, 1.0, -R * np.sin(th)]])

    def Adot(q, qd):
        th, thd = q[0], qd[0]
        return thd * np.array([[0.0, 0.0, 0.0, R * np.sin(th)], [0.0, 0.0, 0.0, -R * np.cos(th)]])

    return A, Adot


@pytest.mark.parametrize(
    "m, I, J, R, q0, Pt, Pp",
    [
        (1.0, 0.5, 0.25, 1.0, (0.0, 0.0, 0.0, 0.0), 0.3, 0.8),
        (2.0, 0.3, 1.1, 0.4, (0.9, -1.0, 2.0, 0.5), -1.4, 0.6),
        (1.0, 0.5, 0.25, 1.0, (0.4, 0.1, 0.2, 0.0), 0.0, -0.7),  # Pi_theta = 0
    ],
)
def test_vertical_disk(m, I, J, R, q0, Pt, Pp):
    Px = m * R * Pp / I
    Pi0 = (Pt, Px, 0.0, Pp)
    th0 = q0[0]
    qd0 = (Pt / J, Px / m * np.cos(th0), Px / m * np.sin(th0), Pp / I)
    A, Adot = _disk_rhs(R)
    rhs = _lda_rhs((J, m, m, I), lambda q: np.zeros(4), A, Adot)
    t, Y = _integrate(rhs, tuple(q0) + qd0, 6.0)
    sol = exact.vertical_disk(t, m, I, J, R, q0, Pi0)
    for i, key in enumerate(("theta", "x", "y", "psi")):
        _close(sol[key], Y[i])
    p = np.array([J, m, m, I])[:, None] * Y[4:]
    th = Y[0]
    Pi_ref = (p[0], p[1] * np.cos(th) + p[2] * np.sin(th), -p[1] * np.sin(th) + p[2] * np.cos(th), p[3])
    for key, ref in zip(("Pi_theta", "Pi_x", "Pi_y", "Pi_psi"), Pi_ref):
        _close(sol[key], ref)
    with pytest.raises(ValueError):
        exact.vertical_disk(t, m, I, J, R, q0, (Pt, Px, 0.1, Pp))
    with pytest.raises(ValueError):
        exact.vertical_disk(t, m, I, J, R, q0, (Pt, Px + 0.1, 0.0, Pp))


# ----------------------------------------------------------------------------
# Heisenberg system
# ----------------------------------------------------------------------------

@pytest.mark.parametrize(
    "q0, pxy",
    [((0.0, 0.0, 0.0), (1.0, 0.5)), ((0.3, -1.2, 0.7), (-0.4, 0.9)), ((2.0, 1.0, -1.0), (0.2, 0.1))],
)
def test_heisenberg(q0, pxy):
    x0, y0, _ = q0
    px, py = pxy
    p0 = (px, py, y0 * px - x0 * py)
    rhs = _lda_rhs(
        (1.0, 1.0, 1.0),
        lambda q: np.zeros(3),
        lambda q: np.array([-q[1], q[0], 1.0]),
        lambda q, qd: np.array([-qd[1], qd[0], 0.0]),
    )
    t, Y = _integrate(rhs, tuple(q0) + p0, 5.0)
    sol = exact.heisenberg(t, q0, p0)
    for i, key in enumerate(("x", "y", "z", "p_x", "p_y", "p_z")):
        _close(sol[key], Y[i])
    _close(sol["p_z"] - sol["y"] * sol["p_x"] + sol["x"] * sol["p_y"], 0.0, 1e-14)
    with pytest.raises(ValueError):
        exact.heisenberg(t, q0, (px, py, p0[2] + 0.1))


# ----------------------------------------------------------------------------
# nonholonomic oscillator
# ----------------------------------------------------------------------------

@pytest.mark.parametrize(
    "q0, p0",
    [((1.0, 1.0, 1.0), (0.0, 0.0, 0.0)),  # the paper's start: y = cos t
     ((0.3, -0.5, 2.0), (0.5 * 0.4, 0.7, 0.4))],  # p_x = -y p_z
)
def test_oscillator_y(q0, p0):
    rhs = _lda_rhs(
        (1.0, 1.0, 1.0),
        lambda q: -q,
        lambda q: np.array([1.0, 0.0, q[1]]),
        lambda q, qd: np.array([0.0, 0.0, qd[1]]),
    )
    t, Y = _integrate(rhs, tuple(q0) + tuple(p0), 8.0)
    _close(Y[3] + Y[1] * Y[5], 0.0)  # the oracle keeps the constraint
    sol = exact.oscillator_y(t, q0[1], p0[1])
    _close(sol["y"], Y[1])
    _close(sol["p_y"], Y[4])
    if q0 == (1.0, 1.0, 1.0):
        _close(sol["y"], np.cos(t), 1e-15)


def test_vectorised_shapes():
    t = np.linspace(0.0, 2.0, 12).reshape(3, 4)
    calls = [
        lambda tt: exact.suslov(tt),
        lambda tt: exact.knife_edge(tt),
        lambda tt: exact.chaplygin(tt, 1.0, 1.0, 0.5, 0.0, (1.25, 0.3, 0.5)),
        lambda tt: exact.vertical_disk(tt, 1.0, 0.5, 0.25, 1.0, (0, 0, 0, 0), (0.3, 1.6, 0.0, 0.8)),
        lambda tt: exact.heisenberg(tt, (1.0, 2.0, 3.0), (0.5, 0.5, 0.5)),
        lambda tt: exact.oscillator_y(tt, 1.0, 0.0),
    ]
    for call in calls:
        out2d, out1d = call(t), call(t.ravel())
        assert out2d.keys() == out1d.keys()
        for key in out2d:
            assert np.shape(out2d[key]) == t.shape, key
            np.testing.assert_array_equal(np.ravel(out2d[key]), out1d[key])
        scalar = call(1.0)
        for key in scalar:
            assert np.shape(scalar[key]) == (), key
