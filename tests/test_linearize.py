"""Linearization at steady motions (liefi.linearize): exactness, minimal coordinates, trivial modes, and the rolling
bodies' linear stability against the literature and the scenes' own reference equations.

Run alone: ``python -m pytest -q tests/test_linearize.py`` (the slow oracle runs: ``-m slow``).
"""
from __future__ import annotations

import numpy as np
import pytest

import liefi
from liefi.groups import SO3
from liefi.integrator.linearize import candidate_symmetries, field_and_jacobian
from liefi.systems.rolling import disk, rolling_body, rolling_start


# --- helpers ------------------------------------------------------------------------------------------------

def upright_disk(inertia=None, mass=1.0, radius=1.0, g=1.0):
    """A disk (uniform by default) standing upright: body axis 3 horizontal, ``Gamma = e_2``."""
    I = mass * radius**2 * np.array([0.25, 0.25, 0.5]) if inertia is None else np.asarray(inertia, float)
    R = SO3().exp([np.pi / 2, 0.0, 0.0])
    return rolling_body(mass, I, disk(radius), gravity=g, sample=R), R


def disk_sigma2(omega, A, C, m=1.0, a=1.0, g=1.0):
    """The upright rolling disk's tilt frequency squared (Routh, Advanced Rigid Dynamics, 1905, sec. 244;
    K. T. McDonald, "The rolling motion of a disk on a horizontal plane", arXiv:physics/0008227, sec. 2.5):
    ``sigma^2 = [C (C + m a^2) omega^2 - m g a A] / (A (A + m a^2))``, stable iff ``sigma^2 > 0``."""
    return (C * (C + m * a * a) * omega**2 - m * g * a * A) / (A * (A + m * a * a))


def cyclic_attitude(axis):
    """A rotation whose third row is ``e_axis``: the principal axis ``axis`` points up."""
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    return np.eye(3)[[i, j, axis]]


def chaplygin_linear(I, k, w, axis):
    """The linearization of Chaplygin's equations ``M' = M x Omega``, ``Gamma' = Gamma x Omega``,
    ``M = (I + k) Omega - k (Omega . Gamma) Gamma`` (``k = m a^2``) at the spin ``Omega = w e_axis``,
    ``Gamma = e_axis``, derived by hand in ``(dM_i, dM_j, gamma_i, gamma_j)`` (``dM_axis`` is conserved)."""
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    I1, I2, I3 = I[i], I[j], I[axis]
    A1, A2 = I1 + k, I2 + k
    return np.array([[0.0, w * (1 - I3 / A2), 0.0, -I3 * k * w * w / A2],
                     [-w * (1 - I3 / A1), 0.0, I3 * k * w * w / A1, 0.0],
                     [0.0, -1 / A2, 0.0, w * I2 / A2],
                     [1 / A1, 0.0, -w * I1 / A1, 0.0]])


def same_spectrum(a, b, tol):
    """Each eigenvalue of ``a`` matched to one of ``b`` (greedy), largest distance below ``tol``."""
    a, b = list(np.asarray(a)), list(np.asarray(b))
    assert len(a) == len(b), (a, b)
    for x in a:
        k = int(np.argmin([abs(x - y) for y in b]))
        assert abs(x - b[k]) <= tol * max(1.0, abs(x)), (x, b)
        b.pop(k)


@pytest.fixture(scope="module")
def rattleback():
    from liefi.scenes.rattleback import Rattleback

    return Rattleback().system


# --- the rolling disk: the upright rolling's criterion -----------------------------------------------------

@pytest.mark.parametrize("omega", [0.3, 0.5, 0.8, 2.0])
def test_rolling_disk_upright_eigenvalues_are_rouths(omega):
    """The uniform disk (``A = m a^2 / 4``, ``C = m a^2 / 2``): two nontrivial eigenvalues ``+-sqrt(-sigma^2)``,
    to 1e-12; the four trivial zeros named (energy, heading, the disk's own axis, the family of steady motions)."""
    system, R = upright_disk()
    lin = system.linearize(rolling_start(system, R, [0.0, 0.0, omega]))
    assert lin.A.shape == (6, 6) and lin.B is None
    expected = np.sqrt(complex(-disk_sigma2(omega, 0.25, 0.5)))
    same_spectrum(lin.nontrivial_eigenvalues, [expected, -expected], 1e-13)
    kinds = sorted(m.kind for m in lin.trivial_modes)
    assert kinds == ["family", "integral", "symmetry", "symmetry"], lin.trivial_modes
    names = " ".join(m.name for m in lin.trivial_modes)
    assert "vertical" in names and "body axis 3" in names and "energy" in names
    assert lin.rates["rotation about body axis 3"] == pytest.approx(omega, rel=1e-14)
    assert (lin.spectral_abscissa > 1e-9) == (omega**2 < 1.0 / 3.0)


@pytest.mark.parametrize("inertia, critical", [((0.25, 0.25, 0.5), 1.0 / 3.0), ((0.5, 0.5, 1.0), 0.25)])
def test_rolling_disk_critical_speed_by_root_finding(inertia, critical):
    """The critical spin ``omega_c^2 = m g a A / (C (C + m a^2))``: ``g / (3a)`` for the uniform disk, ``g / (4a)``
    for a ring (Greenhill, Encyclopaedia Britannica 11th ed., "Gyroscope": ``V^2 / 2g > a/6`` or ``a/8``), found
    as the root of ``-trace(A^2) / 2 = sigma^2`` (the trivial modes are zeros) to 1e-13."""
    from scipy.optimize import brentq

    system, R = upright_disk(inertia)

    def sigma2(w):  # the trivial modes are zero: trace(A^2) = 2 lambda^2 = -2 sigma^2, with no eigensolver
        A = system.linearize(rolling_start(system, R, [0.0, 0.0, w])).A
        return -0.5 * float(np.trace(A @ A))

    assert sigma2(0.8) == pytest.approx(disk_sigma2(0.8, inertia[0], inertia[2]), rel=1e-13)
    wc = brentq(sigma2, 0.1, 2.0, xtol=1e-15, rtol=1e-15)
    assert wc == pytest.approx(np.sqrt(critical), rel=1e-13)


def test_kane_rolling_disk_from_mechanics_linearizes_in_q_and_independent_speeds():
    """sympy's rolling disk (KanesMethod: yaw, lean, spin, contact x, y; u1..u3 independent, u4, u5 dependent):
    ``MechanicsSystem.linearize(q, u=u_ind)`` in the coordinates ``(q, u1, u2, u3)``, the same criterion."""
    pytest.importorskip("sympy")
    import sys
    import pathlib

    sys.path.insert(0, str(pathlib.Path(__file__).parents[1] / "examples"))
    from from_mechanics import rolling_disk

    KM, constants = rolling_disk()  # m = 1, r = 0.5, g = 9.81
    system = liefi.from_mechanics(KM, constants)
    trans = [s for s in candidate_symmetries(system) if s.name.split()[2] in ("q3", "x", "y")]

    def yaw(z):  # the rotation about the vertical: q1 and the contact point (and its momenta) turn
        z = np.asarray(z)
        o = 0.0 * z[..., 0]
        return np.stack([o + 1, o, o, -z[..., 4], z[..., 3], o, o, o, -z[..., 9], z[..., 8]], -1)

    for w in (1.0, 4.0):
        lin = system.linearize([0.0] * 5, u=[0.0, w, 0.0], symmetries=trans + [liefi.Symmetry("yaw", yaw)])
        assert lin.coordinates == ("q1", "q2", "q3", "x", "y", "u1", "u2", "u3")
        s2 = disk_sigma2(w, 0.25 * 0.25, 0.5 * 0.25, a=0.5, g=9.81)
        expected = np.sqrt(complex(-s2))
        same_spectrum(lin.nontrivial_eigenvalues, [expected, -expected], 1e-13)
        assert len(lin.trivial_modes) == 6
        # without the yaw: the turn of the heading and the steady turns are found as the family
        plain = system.linearize([0.0] * 5, u=[0.0, w, 0.0])
        same_spectrum(plain.nontrivial_eigenvalues, [expected, -expected], 1e-13)
        assert [m.kind for m in plain.trivial_modes].count("family") == 2


def test_sleigh_from_lagrange_model_decays_at_the_textbook_rate():
    """The Chaplygin sleigh (LagrangesMethod) running straight at speed ``v``: the turning rate obeys
    ``(I + m a^2) omega' = -m a v omega`` (Bloch, Nonholonomic Mechanics and Control, sec. 1.7), so the one
    nontrivial eigenvalue is ``-m a v / (I + m a^2)``; the translations and the rotation are trivial modes
    (the rotation a non-commuting one: ``A a`` lies in the translations' span)."""
    pytest.importorskip("sympy")
    from models import sleigh_model

    LM, (m, I, a) = sleigh_model()
    system = liefi.from_mechanics(LM, {m: 2.0, I: 0.5, a: 0.3})
    th, v = 0.4, 1.5

    def rotation(z):
        z = np.asarray(z)
        o = 0.0 * z[..., 0]
        return np.stack([-z[..., 1], z[..., 0], o + 1, -z[..., 4], z[..., 3], o], -1)

    q, qdot = [0.1, -0.2, th], [v * np.cos(th), v * np.sin(th), 0.0]
    lin = system.linearize(q, qdot, symmetries=list(candidate_symmetries(system))[:2]
                           + [liefi.Symmetry("rotation", rotation)])
    assert lin.coordinates == ("x", "y", "theta", "x'", "theta'")
    assert lin.nontrivial_eigenvalues == pytest.approx([-2.0 * 0.3 * v / (0.5 + 2.0 * 0.3**2)], rel=1e-12)
    # by default only the ignorable x, y are found as symmetries; the turn of the heading is then found as the
    # family of steady motions through the state (straight runs in other directions: A v in their span)
    plain = system.linearize(q, qdot)
    assert [m.name.split()[2] for m in plain.trivial_modes if m.kind == "symmetry"] == ["x", "y"]
    family = [m.vector for m in plain.trivial_modes if m.kind == "family"]
    assert len(family) == 1 and abs(family[0][2]) > 0.5 * np.linalg.norm(family[0])  # mostly theta
    assert plain.nontrivial_eigenvalues == pytest.approx(lin.nontrivial_eigenvalues, rel=1e-12)


# --- the rattleback --------------------------------------------------------------------------------------

def test_rattleback_spin_directions(rattleback):
    """Kane & Levinson's rattleback spinning about the vertical at ``+-5`` rad/s (liefi's axes; ``+5`` is the
    scene's start, Kane & Levinson's ``-5``).  Without dissipation the model is time-reversible, so the spectrum
    at ``-omega`` is minus that at ``omega`` (to 1e-10): each direction has a growing mode (Garcia & Hubbard,
    Proc. R. Soc. A 418 (1988) 165: the spin reverses either way, at very different times).  At ``+5`` it is
    the pitching mode (the ~107 rad/s one at rest) growing at 2.12/s -- the fast reversal the scene shows;
    at ``-5`` the rolling mode (~34 rad/s) at 0.20/s, ten times slower: the direction that spins "steadily".
    Flipping the misalignment (the product of inertia) swaps the directions (Walker 1896)."""
    plus = rattleback.linearize(rolling_start(rattleback, np.eye(3), [0.0, 0.0, 5.0]))
    minus = rattleback.linearize(rolling_start(rattleback, np.eye(3), [0.0, 0.0, -5.0]))
    same_spectrum(minus.nontrivial_eigenvalues, -plus.nontrivial_eigenvalues, 1e-10)
    assert [m.kind for m in plus.trivial_modes] == ["integral", "symmetry"]
    top = plus.nontrivial_eigenvalues[0]
    assert top.real == pytest.approx(2.1207, abs=1e-4) and abs(top.imag) > 100  # pitching grows
    top = minus.nontrivial_eigenvalues[0]
    assert top.real == pytest.approx(0.2025, abs=1e-4) and 30 < abs(top.imag) < 40  # rolling grows, slowly
    assert plus.spectral_abscissa > 10 * minus.spectral_abscissa
    from liefi.scenes import rattleback as rb

    I = rb.inertia_matrix() * np.array([[1, -1, 1], [-1, 1, 1], [1, 1, 1]])  # the other misalignment
    mirror = rolling_body(rb.MASS, I, rb.ellipsoid(rb.SEMI_AXES, offset=(0.0, 0.0, -rb.H)), gravity=rb.GRAVITY)
    flipped = mirror.linearize(rolling_start(mirror, np.eye(3), [0.0, 0.0, -5.0]))
    assert flipped.spectral_abscissa == pytest.approx(plus.spectral_abscissa, rel=1e-10)


def test_the_extended_fields_jacobian_has_the_feedbacks_own_modes(rattleback):
    """At the rattleback at rest (an equilibrium), ``FeedbackIntegrator.jac`` (14 x 14) has the 6 eigenvalues of
    ``A`` and 8 more, normal to the constraint set and the attitude's level set, that scale with the gain;
    ``A`` has exactly the constrained ones, gain-free."""
    z0 = rolling_start(rattleback, np.eye(3), [0.0, 0.0, 0.0])[11:]
    lin = rattleback.linearize(z0)
    assert lin.A.shape == (6, 6)
    extra = []
    for gain in (1.0, 10.0):
        ev = list(np.linalg.eigvals(liefi.FeedbackIntegrator(rattleback, z0, gains=gain, configuration=False).jac(0, z0)))
        assert len(ev) == 14
        for x in lin.eigenvalues:  # each constrained eigenvalue is one of the extended field's
            k = int(np.argmin([abs(x - y) for y in ev]))
            assert abs(x - ev[k]) < 1e-7 * max(1.0, abs(x))
            ev.pop(k)
        extra.append(np.sort(np.real(ev)))
    assert np.all(extra[0] < -1.0) and np.allclose(extra[1], 10 * extra[0], rtol=1e-6)


def test_the_feedback_moves_the_energy_mode_off_zero():
    """The sleigh from data running straight (x, y ignorable, so the extended field's Jacobian is the co-moving
    one): ``A`` (5 x 5) has -m a v / (I + m a^2) and four zeros; ``FeedbackIntegrator.jac`` (6 x 6) has that
    eigenvalue, only three zeros, the constraint's mode and the energy's, both proportional to the gain: the
    energy penalty turns the energy's zero (along the constraint set) into a decay."""
    m, I, a, theta, v = 2.0, 0.5, 0.3, 0.4, 1.5

    def metric(q):
        s, c = np.sin(q[..., 2]), np.cos(q[..., 2])
        o, one = 0 * s, 1 + 0 * s
        return np.stack([np.stack([m * one, o, -m * a * s], -1), np.stack([o, m * one, m * a * c], -1),
                         np.stack([-m * a * s, m * a * c, (I + m * a * a) * one], -1)], -2)

    sleigh = liefi.NonholonomicSystem.from_velocity_constraints(
        liefi.CotangentBundle(3, names=("x", "y", "theta")), metric,
        lambda q: np.stack([-np.sin(q[..., 2]), np.cos(q[..., 2]), 0 * q[..., 2]], -1))
    q = np.array([0.0, 0.0, theta])
    z0 = np.concatenate([q, metric(q) @ [v * np.cos(theta), v * np.sin(theta), 0.0]])
    lin = sleigh.linearize(z0)
    rate = -m * a * v / (I + m * a * a)
    assert lin.nontrivial_eigenvalues == pytest.approx([rate], rel=1e-13)
    assert np.sum(np.abs(lin.eigenvalues) < 1e-6) == 4
    gain_modes = []
    for gain in (1.0, 10.0):
        ev = np.linalg.eigvals(liefi.FeedbackIntegrator(sleigh, z0, gains=gain).jac(0, z0))
        assert len(ev) == 6 and np.sum(np.abs(ev) < 1e-9) == 3
        assert np.min(np.abs(ev - rate)) < 1e-10
        gain_modes.append(np.sort(ev[(np.abs(ev) > 1e-9) & (np.abs(ev - rate) > 1e-9)].real))
    assert len(gain_modes[0]) == 2 and np.allclose(gain_modes[1], 10 * gain_modes[0], rtol=1e-9)


# --- the Chaplygin ball ----------------------------------------------------------------------------------

@pytest.mark.parametrize("axis", [0, 1, 2])
def test_chaplygin_ball_spin_about_a_principal_axis(axis):
    """The Chaplygin ball (``I = (0.3, 0.4, 0.5)``, ``m = a = 1``) spinning at 2 rad/s about a vertical principal
    axis: liefi's four nontrivial eigenvalues are those of Chaplygin's equations linearized by hand (to 1e-10);
    the middle axis is unstable (a real pair), the largest and smallest not."""
    from liefi.scenes.chaplygin_ball import ChaplyginBall

    scene = ChaplyginBall()
    system = scene.system
    w = 2.0
    lin = system.linearize(rolling_start(system, cyclic_attitude(axis), 2.0 * np.eye(3)[axis]))
    ref = np.linalg.eigvals(chaplygin_linear(scene.inertia, 1.0, w, axis))
    same_spectrum(lin.nontrivial_eigenvalues, ref, 1e-13)
    assert (lin.spectral_abscissa > 1e-3) == (axis == 1)


# --- exactness, the basis, the trivial modes -------------------------------------------------------------

def test_the_traced_jacobian_is_the_complex_step_one_where_that_is_exact():
    """Suslov's problem (constant data: a complex step through the constrained field is exact there): the
    traced ``DX`` agrees with it to 1e-14."""
    inertia = np.diag([1.0, 2.0, 3.0])
    e = np.array([0.0, 1.0, 0.0]) @ np.linalg.inv(inertia)
    suslov = liefi.NonholonomicSystem(liefi.LieGroupPhaseSpace(SO3()), inertia, e[None, :])
    z = suslov.project(np.array([1.0, 0.3, 0.5]))
    X, DX = field_and_jacobian(suslov, z)
    h = 1e-30
    cs = np.stack([suslov.constrained_vector_field(z + 1j * h * np.eye(3)[k]).imag / h for k in range(3)], -1)
    assert np.max(np.abs(DX - cs)) <= 1e-14 * np.max(np.abs(cs))
    assert np.max(np.abs(X - suslov.constrained_vector_field(z))) <= 1e-15


def test_basis_and_trivial_modes_are_what_they_claim(rattleback):
    lin = rattleback.linearize(rolling_start(rattleback, np.eye(3), [0.0, 0.0, 5.0]))
    z0, T = lin.point, lin.basis
    G = np.concatenate([liefi.reduction.core.evaluate(rattleback, z0).dJ] +
                       [c.value_and_grad(z0)[1][None] for c in rattleback.space.casimirs])
    assert np.max(np.abs(G @ T)) < 1e-13  # tangent to J = 0 and the attitude's level set
    assert T.shape == (14, 6) and np.linalg.matrix_rank(T) == 6
    nA = np.linalg.norm(lin.A)
    for m in lin.trivial_modes:
        r = m.vector @ lin.A if m.kind == "integral" else lin.A @ m.vector
        assert np.linalg.norm(r) <= 1e-12 * nA * np.linalg.norm(m.vector), m.name
    # the eigenvectors are A's
    assert np.allclose(lin.A @ lin.eigenvectors, lin.eigenvectors * lin.eigenvalues, atol=1e-10 * nA)


def test_a_state_that_is_no_steady_motion_is_refused_and_steady_motion_finds_one(rattleback):
    """The scene's start (tilted 0.5 degrees, spinning) is no steady motion: named, with the residual;
    ``liefi.steady_motion`` from it converges to a steady spin, which then linearizes."""
    from liefi.scenes.rattleback import Rattleback

    start = Rattleback().initial_state(None)
    with pytest.raises(ValueError, match="not a steady motion.*relative residual"):
        rattleback.linearize(start)
    z, rates = liefi.steady_motion(rattleback, start)
    assert abs(rates["rotation about the vertical (heading)"]) > 4.0
    lin = rattleback.linearize(z)
    assert lin.residual < 1e-10 and len(lin.nontrivial_eigenvalues) == 4


def test_bad_input_is_named(rattleback):
    with pytest.raises(ValueError, match="state: expected a reduced state of 14"):
        rattleback.linearize(np.zeros(5))
    z = rolling_start(rattleback, np.eye(3), [0.0, 0.0, 5.0])[11:]
    z[12] += 0.1
    with pytest.raises(ValueError, match="not on the constraint set"):
        rattleback.linearize(z)
    z = rolling_start(rattleback, np.eye(3), [0.0, 0.0, 5.0])
    with pytest.raises(ValueError, match="integrals: 'Gamma_1' is not conserved"):
        rattleback.linearize(z, integrals=[liefi.Invariant("Gamma_1", lambda y: y[..., 6] * y[..., 4])])
    with pytest.raises(TypeError, match="symmetries"):
        rattleback.linearize(z, symmetries=[lambda y: y])
    with pytest.raises(ValueError, match="qdot, u"):
        rattleback.linearize(z, u=[1.0])


# --- the scenes' oracles: their hand-written equations, run from a perturbed steady motion ---------------

def _perturbed(system, lin, eps, rng=None):
    """``(R, Omega)`` of ``z_0 + eps d``: ``d`` the real part of the most unstable eigenvector (or, with ``rng``,
    a random tangent vector), the attitude made orthonormal again and the momenta projected onto ``J = 0``."""
    if rng is None:
        k = int(np.argmax(lin.eigenvalues.real))
        d = np.real(lin.basis @ lin.eigenvectors[:, k])
    else:
        d = lin.basis @ rng.standard_normal(lin.basis.shape[1])
    z = lin.point + eps * d / np.linalg.norm(d)
    U, _, Vt = np.linalg.svd(z[:9].reshape(3, 3))
    z[:9] = (U @ Vt).ravel()
    z = system.project(z)
    return (U @ Vt), np.linalg.solve(system.metric(z[:9]), z[9:14])[:3]


def _envelope_slope(ts, dev, n, fit):
    """The slope of ``log`` of the running maximum of ``dev`` over windows of ``n`` samples, in ``fit``."""
    m = len(dev) // n * n
    env, tc = dev[:m].reshape(-1, n).max(1), ts[:m].reshape(-1, n).mean(1)
    sel = (tc > fit[0]) & (tc < fit[1])
    return np.polyfit(tc[sel], np.log(env[sel]), 1)[0]


@pytest.mark.slow
@pytest.mark.parametrize("omega, t_final", [(5.0, 5.0), (-5.0, 30.0)])
def test_rattleback_growth_rate_is_the_scene_references(rattleback, omega, t_final):
    """The scene's reference (the rolling rigid body's equations written by hand, DOP853 at 1e-12) from the
    steady spin perturbed by 1e-8 along the unstable eigenvector: the tilt's envelope grows at ``Re lambda``
    (2.1207/s at +5, 0.2025/s at -5), to 1e-3."""
    from scipy.integrate import solve_ivp

    from liefi.scenes import rattleback as rb

    scene = rb.Rattleback()
    lin = rattleback.linearize(rolling_start(rattleback, np.eye(3), [0.0, 0.0, omega]))
    R, W = _perturbed(rattleback, lin, 1e-8)
    r = rb.ellipsoid(rb.SEMI_AXES, offset=(0.0, 0.0, -rb.H))(R[2])
    K = (rb.inertia_matrix() + rb.MASS * (r @ r * np.eye(3) - np.outer(r, r))) @ W  # about the contact point
    sol = solve_ivp(scene.reference_equations(), (0, t_final), np.concatenate([R.ravel(), [0.0, 0.0], K]),
                    method="DOP853", rtol=1e-12, atol=1e-15, dense_output=True)
    ts = np.arange(0.0, t_final, 1e-3)
    Y = sol.sol(ts)
    slope = _envelope_slope(ts, np.hypot(Y[6], Y[7]), 100 if omega > 0 else 500, (0.5, t_final - 0.5))
    assert slope == pytest.approx(lin.spectral_abscissa, rel=1e-3)


@pytest.mark.slow
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_chaplygin_ball_long_run_of_the_scene_reference(axis):
    """Chaplygin's equations as the scene writes them by hand (DOP853 at 1e-12) over [0, 60] from the spin about
    a principal axis perturbed by 1e-8: about the middle axis ``Gamma`` leaves at ``Re lambda = 0.143223`` (to
    1e-6), about the others it stays within 1e-7 (a random perturbation)."""
    from scipy.integrate import solve_ivp

    from liefi.scenes.chaplygin_ball import ChaplyginBall, chaplygin_equations

    scene = ChaplyginBall()
    system = scene.system
    lin = system.linearize(rolling_start(system, cyclic_attitude(axis), 2.0 * np.eye(3)[axis]))
    R, W = _perturbed(system, lin, 1e-8, None if axis == 1 else np.random.default_rng(1))
    G = R[2]
    M = (np.diag(scene.inertia) + (G @ G * np.eye(3) - np.outer(G, G))) @ W  # m = a = 1
    y0 = np.concatenate([R.ravel(), [0.0, 0.0], R[0], R[1], R[2], M])
    sol = solve_ivp(chaplygin_equations(scene.inertia, 1.0, 1.0), (0, 60), y0, method="DOP853", rtol=1e-12,
                    atol=1e-15, dense_output=True)
    ts = np.arange(0.0, 60.0, 1e-2)
    dev = np.linalg.norm(sol.sol(ts)[17:20] - np.eye(3)[axis][:, None], axis=0)
    if axis == 1:
        assert _envelope_slope(ts, dev, 100, (5, 59)) == pytest.approx(lin.spectral_abscissa, rel=1e-6)
        assert lin.spectral_abscissa == pytest.approx(0.143223, abs=1e-6)
    else:
        assert dev.max() < 1e-7


def test_the_disk_example_finds_rouths_critical_spin():
    """``examples/linearize_disk.py`` (the docs' figure): the critical spin by root finding is ``sqrt(g / 3a)``."""
    import importlib.util
    import pathlib

    path = pathlib.Path(__file__).parents[1] / "examples" / "linearize_disk.py"
    spec = importlib.util.spec_from_file_location("linearize_disk", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    speeds, ev, wc = mod.main(out=None, speeds=np.array([0.3, 1.0]))
    assert wc == pytest.approx(np.sqrt(1.0 / 3.0), rel=1e-13)
    assert np.all(np.abs(ev[0].imag) < 1e-12) and np.all(np.abs(ev[1].real) < 1e-12)
