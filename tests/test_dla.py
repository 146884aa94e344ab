"""Tests of the discrete Lagrange-d'Alembert integrator (liefi.dla).

The paper's closed form for the nonholonomic oscillator, equations (dynamics)
and (EzLambda), is written here as an oracle; the library derives the step from
M, U and A alone.
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from liefi.dla import DLAIntegrator, DLANonFiniteError, DLAResult


# --------------------------------------------------------------------- systems
def oscillator_U(q):
    return 0.5 * np.sum(q * q, axis=-1)


def oscillator_A(q):
    """A(q) = (1, 0, y) as a (..., 1, 3) array (complex-safe)."""
    y = q[..., 1]
    return np.stack([np.ones_like(y), np.zeros_like(y), y], axis=-1)[..., None, :]


def oscillator(analytic_gradient=False):
    if analytic_gradient:
        return DLAIntegrator(np.eye(3), oscillator_U, oscillator_A, potential_gradient=lambda q: q)
    return DLAIntegrator(np.eye(3), oscillator_U, oscillator_A)


def paper_step(q0, q1, h):
    """Oracle: the paper's (EzLambda) and (dynamics) for the nonholonomic oscillator."""
    x0, z0 = q0[..., 0], q0[..., 2]
    x1, y1, z1 = q1[..., 0], q1[..., 1], q1[..., 2]
    lam = ((1 - h**2) * x1 - x0 + y1 * ((1 - h**2) * z1 - z0)) / (h**2 * (1 + y1**2))  # (EzLambda)
    e = np.stack([np.ones_like(y1), np.zeros_like(y1), y1], axis=-1)
    q2 = 2 * q1 - q0 - h**2 * q1 - h**2 * lam[..., None] * e  # (dynamics)
    return q2, lam


def continuous_oscillator(t, s):
    """Continuous constrained oscillator: q' = p, p' = -q + lam (1, 0, y),
    lam from d/dt (p_x + y p_z) = 0:  lam = (x + y z - p_y p_z) / (1 + y^2)."""
    x, y, z, px, py, pz = s
    lam = (x + y * z - py * pz) / (1 + y * y)
    return [px, py, pz, -x + lam, -y, -z + lam * y]


# ------------------------------------------------------------------- (a) oracle
@pytest.mark.parametrize("analytic_gradient", [False, True])
def test_step_matches_paper_dynamics_and_EzLambda(analytic_gradient):
    rng = np.random.default_rng(0)
    N = 500
    h = 10.0 ** rng.uniform(-3, -1, size=())
    q1 = rng.normal(size=(N, 3))
    q0 = q1 - h * rng.normal(size=(N, 3))
    dla = oscillator(analytic_gradient)
    q2, lam = dla.step(q0, q1, h, return_multiplier=True)
    q2_ref, lam_ref = paper_step(q0, q1, h)
    np.testing.assert_allclose(q2, q2_ref, rtol=0, atol=1e-14)
    # The impulse h^2 lambda is O(h); compare it absolutely (lambda itself is O(1/h)).
    np.testing.assert_allclose(h**2 * lam[..., 0], h**2 * lam_ref, rtol=0, atol=1e-14)
    # Generic states (not on C_d) with h = 0.1, too.
    q0 = rng.normal(size=(N, 3))
    q2, lam = dla.step(q0, q1, 0.1, return_multiplier=True)
    q2_ref, lam_ref = paper_step(q0, q1, 0.1)
    np.testing.assert_allclose(q2, q2_ref, rtol=0, atol=1e-14 * np.max(np.abs(q2_ref)))


def test_step_satisfies_DLA_equations_with_general_mass():
    """Residual of D2 L_d(q0,q1) + D1 L_d(q1,q2) - A^T lam and of A(q1)(q2-q1), non-diagonal M."""
    rng = np.random.default_rng(1)
    B = rng.normal(size=(4, 4))
    M = B @ B.T + 4 * np.eye(4)
    def U(q):
        return np.sum(np.cos(q), axis=-1) + q[..., 0] * q[..., 1] ** 2
    def gradU(q):
        g = -np.sin(q)
        g[..., 0] += q[..., 1] ** 2
        g[..., 1] += 2 * q[..., 0] * q[..., 1]
        return g
    def A(q):
        return np.stack([np.stack([np.ones_like(q[..., 0]), q[..., 2], 0 * q[..., 0], np.sin(q[..., 1])], -1),
                         np.stack([q[..., 3], 0 * q[..., 0], np.ones_like(q[..., 0]), q[..., 0]], -1)], -2)
    dla = DLAIntegrator(M, U, A)
    h = 0.05
    q1 = rng.normal(size=(20, 4))
    q0 = q1 - h * rng.normal(size=(20, 4))
    q2, lam = dla.step(q0, q1, h, return_multiplier=True)
    D2 = (q1 - q0) @ M / h**2
    D1 = -(q2 - q1) @ M / h**2 - gradU(q1)
    res = D2 + D1 - np.einsum("...kj,...k->...j", A(q1), lam)
    assert np.max(np.abs(res)) < 1e-10 * np.max(np.abs(D2))
    assert np.max(np.abs(np.einsum("...kj,...j->...k", A(q1), q2 - q1))) < 1e-14


# -------------------------------------------------------- (b) discrete constraint
def test_discrete_constraint_holds_along_run():
    dla = oscillator()
    h = 1e-2
    q0, q1 = dla.initial_pair(np.array([1.0, 1.0, 1.0]), np.array([0.3, -0.2, 0.7]), h)
    assert abs(dla.discrete_constraint(q0, q1)[0]) < 1e-15
    res = dla.run(q0, q1, h, 2000)
    assert isinstance(res, DLAResult)
    q = res.q
    assert q.shape == (3, 2001) and res.t.shape == (2001,)
    r = dla.discrete_constraint(q[:, :-1].T, q[:, 1:].T)
    assert np.max(np.abs(r)) < 1e-14
    # p_{k} = M (q_k - q_{k-1})/h, so A(q_{k-1}) M^{-1} p_k = 0 exactly.
    Jc = res.p[0, 1:] + q[1, :-1] * res.p[2, 1:]
    assert np.max(np.abs(Jc)) < 1e-12
    assert res.steps == res.rhs_evaluations == 1999


def test_initial_pair_paper_choice_and_projection():
    dla = oscillator()
    q0, q1 = dla.initial_pair([1.0, 1.0, 1.0], [0.0, 0.0, 0.0], 1e-3)
    np.testing.assert_array_equal(q0, q1)  # the paper's (ns:dla:ic)
    # Admissible momentum is left unchanged.
    p = np.array([-2.0, 0.5, 2.0])  # p_x + y p_z = 0 at y = 1
    _, q1 = dla.initial_pair([1.0, 1.0, 1.0], p, 1e-3)
    np.testing.assert_allclose((q1 - 1.0) / 1e-3, p, atol=1e-12)


# ------------------------------------------------------------ (c) convergence
def test_first_order_convergence_against_DOP853():
    sol = solve_ivp(continuous_oscillator, (0.0, 1.0), [1, 1, 1, 0, 0, 0],
                    method="DOP853", rtol=1e-12, atol=1e-12)
    q_exact = sol.y[:3, -1]
    dla = oscillator()
    hs = np.array([1e-2, 5e-3, 2.5e-3, 1.25e-3])
    errs = []
    for h in hs:
        q0, q1 = dla.initial_pair(np.ones(3), np.zeros(3), h)
        n = int(round(1.0 / h))
        res = dla.run(q0, q1, h, n, save_every=n)
        assert res.t[-1] == pytest.approx(1.0)
        errs.append(np.linalg.norm(res.q[:, -1] - q_exact))
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(slope - 1.0) < 0.2, (slope, errs)


# ------------------------------------------------------------------ (d) batches
def test_batch_step_equals_individual_steps():
    rng = np.random.default_rng(2)
    dla = oscillator()
    h = 0.01
    q1 = rng.normal(size=(4, 3))
    q0 = q1 - h * rng.normal(size=(4, 3))
    batch = dla.step(q0, q1, h)
    assert batch.shape == (4, 3)
    for i in range(4):
        np.testing.assert_allclose(batch[i], dla.step(q0[i], q1[i], h), rtol=1e-15, atol=1e-15)


def test_batch_run_shapes_and_values():
    rng = np.random.default_rng(3)
    dla = oscillator(analytic_gradient=True)
    h = 0.01
    q0, q1 = dla.initial_pair(rng.normal(size=(2, 2, 3)), rng.normal(size=(2, 2, 3)), h)
    res = dla.run(q0, q1, h, 25, save_every=10)
    np.testing.assert_allclose(res.t, [0.0, 0.1, 0.2, 0.25])
    assert res.q.shape == res.p.shape == (2, 2, 3, 4)
    single = dla.run(q0[1, 0], q1[1, 0], h, 25, save_every=10)
    np.testing.assert_allclose(res.q[1, 0], single.q, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(res.p[1, 0], single.p, rtol=1e-14, atol=1e-14)


def test_constant_constraints_and_free_particle():
    """A constant A (as an array) and U = 0: q moves on a line in ker A."""
    dla = DLAIntegrator(np.diag([1.0, 2.0]), constraints=[1.0, 1.0])
    q0, q1 = dla.initial_pair([0.0, 0.0], [1.0, 0.0], 0.1)
    res = dla.run(q0, q1, 0.1, 10)
    np.testing.assert_allclose(res.q[0] + res.q[1], 0.0, atol=1e-15)
    # M-orthogonal projection of M^{-1} p0 = (1, 0) onto ker A: (1/3, -1/3); then uniform motion.
    np.testing.assert_allclose(np.diff(res.q, axis=-1), np.broadcast_to([[1 / 30], [-1 / 30]], (2, 10)),
                               rtol=0, atol=1e-15)


# ---------------------------------------------------------------- (e) bad input
@pytest.mark.parametrize("mass, match", [
    (np.array([[1.0, 0.5], [0.0, 1.0]]), "mass: not symmetric"),
    (np.array([[1.0, 2.0], [2.0, 1.0]]), "mass: not positive definite"),
    (np.ones(3), "mass: expected a square"),
    (np.array([[1.0, np.nan], [np.nan, 1.0]]), "mass: contains non-finite"),
])
def test_bad_mass(mass, match):
    with pytest.raises(ValueError, match=match):
        DLAIntegrator(mass)


def test_bad_arguments_name_the_parameter():
    dla = oscillator()
    q = np.ones(3)
    with pytest.raises(ValueError, match="constraints"):
        DLAIntegrator(np.eye(3), constraints=np.ones((2, 4)))
    with pytest.raises(ValueError, match="constraints"):
        DLAIntegrator(np.eye(3), constraints=lambda q: np.ones(q.shape[:-1] + (4,))).step(q, q, 0.1)
    with pytest.raises(ValueError, match="constraints: the rows"):
        DLAIntegrator(np.eye(3), constraints=np.ones((2, 3)))
    with pytest.raises(TypeError, match="potential"):
        DLAIntegrator(np.eye(3), potential=3.0)
    for h in (0.0, -1e-3, np.inf, np.nan, "0.1"):
        with pytest.raises(ValueError, match="h:"):
            dla.step(q, q, h)
    with pytest.raises(ValueError, match="q_curr"):
        dla.step(q, np.ones(2), 0.1)
    with pytest.raises(ValueError, match="q_prev"):
        dla.step([1.0, np.inf, 0.0], q, 0.1)
    with pytest.raises(ValueError, match="p0"):
        dla.initial_pair(q, np.ones(4), 0.1)
    with pytest.raises(ValueError, match="n_steps"):
        dla.run(q, q, 0.1, -1)
    with pytest.raises(ValueError, match="save_every"):
        dla.run(q, q, 0.1, 10, save_every=0)
    with pytest.raises(ValueError, match="potential"):
        DLAIntegrator(np.eye(3), lambda q: np.sum(np.abs(q), axis=-1)).step(q, 1.1 * q, 0.1)


def test_divergence_raises_floating_point_error_with_step_and_time():
    dla = DLAIntegrator(np.eye(1), potential_gradient=lambda q: q**9)
    with pytest.raises(FloatingPointError, match=r"non-finite .* at step \d+ \(computing q at t = "):
        dla.run([2.0], [2.0], 0.5, 50)
    try:
        dla.run([2.0], [2.0], 0.5, 50)
    except DLANonFiniteError as err:
        assert err.step >= 1 and err.time == pytest.approx(0.5 * (err.step + 1))
