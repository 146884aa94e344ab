"""Holonomic constraints f(x) = 0 as a datum of a system (liefi.systems.holonomic).

A planar pendulum in Cartesian coordinates (x, y) with f = x^2 + y^2 - l^2, built from
data: energy and |f| held to rounding by the default run, and the motion of the angle
pendulum (closed form by Jacobi's elliptic functions).
"""

import numpy as np
import pytest
from scipy.special import ellipj, ellipk

import liefi
from liefi.systems.holonomic import stability_margin

MASS, G, L = 1.3, 9.81, 0.7
TH0 = 1.0


def f(x):
    return x[..., 0] ** 2 + x[..., 1] ** 2 - L**2


def df(x):
    return np.stack([2 * x[..., 0], 2 * x[..., 1]], -1)


def pendulum(derivative=True):
    return liefi.NonholonomicSystem(
        liefi.CotangentBundle(2, names=("x", "y")), MASS * np.eye(2), potential=lambda x: MASS * G * x[..., 1],
        holonomic=f, holonomic_derivative=df if derivative else None, sample=[0.3, -0.5])


def exact(t):
    """The angle pendulum released from rest at TH0: sin(th/2) = k sn(K - w t | k^2)."""
    k = np.sin(TH0 / 2)
    sn = ellipj(ellipk(k**2) - np.sqrt(G / L) * t, k**2)[0]
    th = 2 * np.arcsin(k * sn)
    return np.stack([L * np.sin(th), -L * np.cos(th)], -1)


Y0 = np.array([L * np.sin(TH0), -L * np.cos(TH0), 0.0, 0.0])


def test_rows_and_values_join_the_constraints_and_V():
    s = pendulum()
    assert s.K == 1 and s.holonomic.H == 1
    fi = liefi.FeedbackIntegrator(s, Y0)
    assert set(fi.invariant_names) == {"J_1", "energy", "f_1"}
    assert fi.targets["f_1"] == 0.0
    # J = df . qdot / |df|_{m^-1}: the velocity along the rod, in the kinetic-energy norm
    z = np.array([0.3, -0.4, 0.5, 0.2])
    qdot = z[2:] / MASS
    a = df(z[:2])
    assert np.isclose(s.constraint_momenta(z)[0], a @ qdot / np.sqrt(a @ a / MASS), rtol=1e-14)
    # without an analytic derivative: the same rows and the same extended field to ~1e-9
    s2 = pendulum(derivative=False)
    assert np.allclose(s2.extended_vector_field(z), s.extended_vector_field(z), rtol=1e-9, atol=1e-9)


@pytest.mark.slow
def test_cartesian_pendulum_default_run_holds_energy_and_f():
    s = pendulum()
    fi = liefi.FeedbackIntegrator(s, Y0)
    sol = fi.run(50.0)
    Y = sol.y.T
    h = s.hamiltonian(Y)
    assert np.max(np.abs(h - h[0])) < 1e-12 * abs(h[0])
    assert np.max(np.abs(f(Y[:, :2]))) < 1e-12
    assert np.max(np.abs(s.constraint_momenta(Y))) < 1e-12
    sol = fi.run(2.0, rtol=1e-11)
    assert np.max(np.abs(sol.y.T[:, :2] - exact(sol.t))) < 1e-8


def test_cartesian_pendulum_numpy_run_agrees_with_angle_pendulum():
    s = pendulum()
    fi = liefi.FeedbackIntegrator(s, Y0)
    sol = fi.run(1.0, dt=1e-2, scheme="imex-rk8", backend="numpy")
    Y = sol.y.T
    h = s.hamiltonian(Y)
    assert np.max(np.abs(h - h[0])) < 1e-12 * abs(h[0])
    assert np.max(np.abs(f(Y[:, :2]))) < 1e-12
    assert np.max(np.abs(Y[:, :2] - exact(sol.t))) < 1e-8


def test_feedback_restores_f_off_the_constraint():
    """Started off f = 0 (and J != 0), the continuous feedback field drives V to 0 when the margin is positive."""
    from scipy.integrate import solve_ivp

    s = pendulum()
    th, w = 1.0, 3.0
    y0 = np.array([L * np.sin(th), -L * np.cos(th), MASS * L * w * np.cos(th), MASS * L * w * np.sin(th)])
    fi = liefi.FeedbackIntegrator(s, y0, gains={"J_1": 10.0, "energy": 1.0, "f_1": 10.0})
    assert stability_margin(s, y0, fi.gains) > 0
    yp = y0 + 1e-6 * np.array([1, -1, 2, 1.0])
    sol = solve_ivp(fi.fun, (0, 1), yp, method="DOP853", rtol=1e-8, atol=1e-12, t_eval=[0, 1])
    V = fi.lyapunov(sol.y.T)
    assert V[-1] < 1e-6 * V[0]


def test_bad_holonomic_input_is_named():
    sp = liefi.CotangentBundle(2)
    with pytest.raises(ValueError, match="holonomic_derivative: given without holonomic"):
        liefi.NonholonomicSystem(sp, np.eye(2), holonomic_derivative=df)
    with pytest.raises(ValueError, match="holonomic: the differentials"):
        liefi.NonholonomicSystem(sp, np.eye(2), holonomic=lambda x: np.stack([f(x), 2 * f(x)], -1),
                                 sample=[0.3, -0.5])
    with pytest.raises(ValueError, match="holonomic_derivative: differs"):
        liefi.NonholonomicSystem(sp, np.eye(2), holonomic=f, holonomic_derivative=lambda x: df(x) * 2,
                                 sample=[0.3, -0.5])
    with pytest.raises(ValueError, match="holonomic: constraints f"):
        liefi.NonholonomicSystem(liefi.LieGroupPhaseSpace(liefi.groups.SO3()), np.eye(3), holonomic=f)
