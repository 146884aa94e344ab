"""``liefi.from_mechanics`` on models as sympy's docs and tests write them: no crash, no silent wrong answer (issue 25).

Each test compares with the model's own equations: sympy's ``mass_matrix_full`` and
``forcing_full`` (lambdified here), whose rates ``(q', u')`` are carried to liefi's state
``z = (q, p)`` by a complex-step derivative of ``z(q, u) = (q, M(q) qdot(q, u))`` (exact to
rounding), with ``qdot(q, u)`` from the model's ``kindiffdict()``.

* the speeds in a point's ``pos_from(O).dt(N)`` (``set_ang_vel``, joints) were never
  substituted (``NameError: name 'u1'``);
* ``System.actuators`` were ignored (a particle on a ``LinearSpring`` stayed free);
* a ``KanesMethod`` got the bodies' ``potential_energy``, which Kane's equations ignore;
* the kinematic map was inverted symbolically, on a pivot ``sin(q3)`` that vanishes at an
  ordinary configuration (0/0 at the upright of a yaw--roll--pitch body), or hung in
  ``expand``.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")

import liefi  # noqa: E402

t = me.dynamicsymbols._t


# --- the model's own equations, carried to liefi's state ------------------------------------------
def own_field(system, eom, constants, q_sym, u_sym):
    """``f(q, u) -> (z, dz/dt)``: liefi's state at ``(q, u)`` and the model's own rates carried to it."""
    MM = sympy.lambdify(q_sym + u_sym, eom.mass_matrix_full.subs(constants), "numpy", cse=True)
    FF = sympy.lambdify(q_sym + u_sym, eom.forcing_full.subs(constants), "numpy", cse=True)
    kdd = eom.kindiffdict()
    qdot = sympy.lambdify(q_sym + u_sym, [kdd[s.diff(t)].subs(constants) for s in q_sym], "numpy")
    n = len(q_sym)

    def z(qq, uu):
        v = np.asarray(qdot(*qq, *uu), dtype=complex if np.iscomplexobj(qq) else float)
        return np.concatenate([qq, system.metric(qq) @ v])

    def field(qv, uv):
        rates = np.linalg.solve(np.asarray(MM(*qv, *uv), float), np.asarray(FF(*qv, *uv), float).ravel())
        h = 1e-30
        return z(qv, uv), np.imag(z(qv + 1j * h * rates[:n], uv + 1j * h * rates[n:])) / h

    return field


def dependent_speeds(eom, constants, q_sym, u_sym, cons):
    """``f(q, ui)``: all speeds, the dependent ones solved from the model's velocity constraints."""
    C = sympy.Matrix(cons).xreplace(eom.kindiffdict()).jacobian(u_sym).subs(constants)
    Cf = sympy.lambdify(q_sym, C, "numpy", cse=True)

    def speeds(qv, ui):
        Cn = np.asarray(Cf(*qv), float)
        k = len(ui)
        return np.concatenate([ui, np.linalg.solve(Cn[:, k:], -Cn[:, :k] @ ui)])

    return speeds


def assert_field(system, z, dz, tol=1e-12):
    f = system.constrained_vector_field(z)
    err = np.max(np.abs(f - dz)) / np.max(np.abs(dz))
    assert err <= tol, err


# --- the models, as sympy's docs and tests write them ---------------------------------------------
def sleigh_kane(body_speeds=False):
    """Chaplygin sleigh, KanesMethod: ``B.set_ang_vel(N, u3*N.z)``, the mass centre ``a`` ahead of the blade, in ``B``.

    Inertial speeds ``u1, u2`` of the blade point, or body-frame speeds ``u1 = v.B.x``, ``u2 = v.B.y``.
    """
    x, y, th = me.dynamicsymbols("x y theta")
    u1, u2, u3 = me.dynamicsymbols("u1:4")
    m, I, a = sympy.symbols("m I a")
    N = me.ReferenceFrame("N")
    B = N.orientnew("B", "Axis", [th, N.z])
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    if body_speeds:
        v = P.pos_from(O).dt(N)
        kd = [u1 - v.dot(B.x), u2 - v.dot(B.y), u3 - th.diff()]
        P.set_vel(N, u1 * B.x + u2 * B.y)
    else:
        kd = [x.diff() - u1, y.diff() - u2, th.diff() - u3]
        P.set_vel(N, u1 * N.x + u2 * N.y)
    B.set_ang_vel(N, u3 * N.z)
    G = P.locatenew("G", a * B.x)
    G.v2pt_theory(P, N, B)
    sled = me.RigidBody("sled", G, B, m, (me.inertia(B, 0, 0, I), G))
    cons = [P.vel(N).dot(B.y)]
    KM = me.KanesMethod(N, [x, y, th], [u1, u3], kd_eqs=kd, u_dependent=[u2], velocity_constraints=cons)
    KM.kanes_equations([sled], [])
    return KM, {m: 1.5, I: 0.7, a: 0.4}, cons


def cart_pendulum():
    """sympy's ``System`` docs: a cart on a rail (PrismaticJoint) and a pendulum bob (PinJoint), gravity."""
    g, l = sympy.symbols("g l")
    rail, cart, bob = me.RigidBody("rail"), me.RigidBody("cart"), me.Particle("bob")
    bob_frame = me.ReferenceFrame("bob_frame")
    system = me.System.from_newtonian(rail)
    system.add_joints(
        me.PrismaticJoint("slider", rail, cart, joint_axis=rail.x),
        me.PinJoint("pin", cart, bob, joint_axis=cart.z, child_interframe=bob_frame, child_point=l * bob_frame.y),
    )
    system.apply_uniform_gravity(-g * system.y)
    consts = {g: 9.81, l: 0.8, cart.mass: 2.0, bob.mass: 0.5}
    return system, consts


def spring_particle(l0=0):
    """A particle on a ``LinearSpring`` actuator from the wall (System, PrismaticJoint)."""
    q, u = me.dynamicsymbols("q u")
    m, k = sympy.symbols("m k")
    wall = me.RigidBody("wall")
    system = me.System.from_newtonian(wall)
    bob = me.Particle("bob", mass=m)
    system.add_joints(me.PrismaticJoint("J", wall, bob, q, u))
    return system, wall, bob, (m, k), me.LinearPathway(wall.masscenter, bob.masscenter)


def top_ypr(heavy=True):
    """A heavy top on a fixed point, yaw q1 - roll q2 - pitch q3, the body rates as speeds (PyDy's examples):
    the kinematic equations solved for the angle rates, so ``K_u`` has ``sin(q3)`` in its first pivot.
    ``heavy=False``: Euler's free rigid body (mass centre at the fixed point, no loads)."""
    q1, q2, q3 = me.dynamicsymbols("q1:4")
    u1, u2, u3 = me.dynamicsymbols("u1:4")
    m, g, l, A, B, C = sympy.symbols("m g l A B C")
    N = me.ReferenceFrame("N")
    R = N.orientnew("R", "Body", [q1, q2, q3], "zxy")
    w = R.ang_vel_in(N)
    qd = sympy.solve([w.dot(R.x) - u1, w.dot(R.y) - u2, w.dot(R.z) - u3], [q1.diff(), q2.diff(), q3.diff()])
    kd = [s.diff() - qd[s.diff()] for s in (q1, q2, q3)]
    R.set_ang_vel(N, u1 * R.x + u2 * R.y + u3 * R.z)
    O = me.Point("O")
    O.set_vel(N, 0)
    if not heavy:
        body = me.RigidBody("body", O, R, m, (me.inertia(R, A, B, C), O))
        KM = me.KanesMethod(N, [q1, q2, q3], [u1, u2, u3], kd_eqs=kd)
        KM.kanes_equations([body], [])
        return KM, {m: 1.0, A: 0.02, B: 0.03, C: 0.015}
    G = O.locatenew("G", l * R.z)
    G.v2pt_theory(O, N, R)
    top = me.RigidBody("top", G, R, m, (me.inertia(R, A, B, C), G))
    KM = me.KanesMethod(N, [q1, q2, q3], [u1, u2, u3], kd_eqs=kd)
    KM.kanes_equations([top], [(G, -m * g * N.z)])
    return KM, {m: 1.0, g: 9.81, l: 0.3, A: 0.02, B: 0.03, C: 0.015}


# --- 1. the speeds in pos_from(O).dt(N) -----------------------------------------------------------
def test_sleigh_with_set_ang_vel_and_an_offset_mass_centre_agrees_with_kanes_equations():
    KM, consts, cons = sleigh_kane()
    sleigh = liefi.from_mechanics(KM, consts)  # was NameError / "depends on 't'"
    q, u = list(KM.q), list(KM.u)
    rng = np.random.default_rng(0)
    field, speeds = own_field(sleigh, KM, consts, q, u), dependent_speeds(KM, consts, q, u, cons)
    for _ in range(3):
        qv = rng.uniform(-1, 1, 3)
        assert_field(sleigh, *field(qv, speeds(qv, rng.normal(size=2))))


def test_joints_cart_pendulum_from_the_docs_agrees_with_form_eoms():
    system, consts = cart_pendulum()
    cp = liefi.from_mechanics(system, consts)  # was NameError / "depends on 't'"
    system.form_eoms()
    q, u = list(system.q), list(system.u)
    rng = np.random.default_rng(1)
    field = own_field(cp, system.eom_method, consts, q, u)
    for _ in range(3):
        assert_field(cp, *field(rng.uniform(-1, 1, 2), rng.normal(size=2)))


# --- 2. actuators ------------------------------------------------------------------------------------
def _run_q(system, consts, q0, t_final, sample=None):
    s = liefi.from_mechanics(system, consts, sample=sample)
    z0 = s.state([q0], u=[0.0])
    sol = liefi.FeedbackIntegrator(s, z0, gains=1.0).run(t_final, dt=1e-2, scheme="rk4", backend="numpy")
    return sol.y[0, -1]


def _sympy_q(system, consts, q0, t_final):
    from scipy.integrate import solve_ivp

    system.form_eoms()
    y = list(system.q) + list(system.u)
    MM = sympy.lambdify(y, system.mass_matrix_full.subs(consts))
    FF = sympy.lambdify(y, system.forcing_full.subs(consts))
    r = solve_ivp(lambda tt, s: np.linalg.solve(MM(*s), FF(*s)).ravel(), (0, t_final), [q0, 0.0],
                  method="DOP853", rtol=1e-12, atol=1e-12)
    return r.y[0, -1]


@pytest.mark.parametrize("l0, q0", [(0.0, 0.5), (0.8, 1.0)])
def test_linear_spring_actuator_is_integrated_as_sympy_means_it(l0, q0):
    system, wall, bob, (m, k), path = spring_particle()
    system.add_actuators(me.LinearSpring(k, path, l0))
    consts = {m: 1.0, k: 2.0}
    got = _run_q(system, consts, q0, 2.0, sample=np.array([q0]))  # (the length |q| has a kink at q = 0)
    want = _sympy_q(system, consts, q0, 2.0)
    assert abs(got - want) < 1e-7, (got, want)  # RK4 at dt = 1e-2; was q(2) = q0: the spring ignored


@pytest.mark.parametrize("make", ["damper", "torque", "time"])
def test_non_conservative_actuators_and_loads_become_the_systems_force(make):
    system, wall, bob, (m, k), path = spring_particle()
    c = sympy.symbols("c")
    if make == "damper":
        system.add_actuators(me.LinearDamper(c, path))
    elif make == "torque":
        system.add_actuators(me.TorqueActuator(c, wall.frame.z, wall.frame))
    else:
        system.add_loads((bob.masscenter, c * sympy.sin(t) * wall.frame.x))
    s = liefi.from_mechanics(system, {m: 1.0, c: 0.3}, sample=np.array([0.5]))  # was NonConservativeLoadError
    F = s.force(0.7, np.array([0.5]), np.array([2.0]), None)
    want = {"damper": -0.3 * 2.0, "torque": 0.0, "time": 0.3 * np.sin(0.7)}[make]  # the wall's frame does not turn
    np.testing.assert_allclose(F, [want], rtol=1e-14, atol=1e-15)
    if make == "damper":
        got = _run_q(system, {m: 1.0, c: 0.3}, 0.5, 2.0, sample=np.array([0.5]))
        assert abs(got - _sympy_q(system, {m: 1.0, c: 0.3}, 0.5, 2.0)) < 1e-7


# --- 3. potential_energy: the model's own meaning -------------------------------------------------
def _particle_with_potential_energy(kane=True):
    x, v = me.dynamicsymbols("x v")
    m, k = sympy.symbols("m k")
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x)
    P.set_vel(N, v * N.x if kane else x.diff() * N.x)
    p = me.Particle("p", P, m)
    p.potential_energy = k * x**2 / 2
    return x, v, m, k, N, p


def test_kanes_method_ignores_potential_energy_as_sympy_does_and_says_so():
    x, v, m, k, N, p = _particle_with_potential_energy()
    KM = me.KanesMethod(N, [x], [v], kd_eqs=[x.diff() - v])
    KM.kanes_equations([p], [])
    assert KM.forcing[0] == 0  # sympy: no loads, no force
    with pytest.warns(UserWarning, match=r"potential_energy of \['p'\] is ignored"):
        s = liefi.from_mechanics(KM, {m: 1.0, k: 4.0})
    sol = liefi.FeedbackIntegrator(s, s.state([1.0], u=[0.0]), gains=1.0).run(1.0, dt=1e-2, scheme="rk4",
                                                                             backend="numpy")
    assert np.max(np.abs(sol.y[0] - 1.0)) == 0.0  # at rest, as Kane's equations say (was cos(2 t))


def test_lagranges_method_and_a_lagrange_system_keep_potential_energy():
    x, v, m, k, N, p = _particle_with_potential_energy(kane=False)
    LM = me.LagrangesMethod(me.Lagrangian(N, p), [x], frame=N)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = liefi.from_mechanics(LM, {m: 1.0, k: 4.0})
    sol = liefi.FeedbackIntegrator(s, s.state([1.0], [0.0]), gains=1.0).run(1.0, dt=1e-2, scheme="rk4",
                                                                           backend="numpy")
    assert abs(sol.y[0, -1] - np.cos(2.0)) < 1e-7
    # sympy's System docs: a bob with potential_energy on a PrismaticJoint, formed with LagrangesMethod
    q, qd = me.dynamicsymbols("q"), me.dynamicsymbols("q", 1)
    wall = me.RigidBody("W")
    system = me.System.from_newtonian(wall)
    bob = me.Particle("P", mass=m)
    bob.potential_energy = sympy.S.Half * k * q**2
    system.add_joints(me.PrismaticJoint("J", wall, bob, q, qd))
    system.form_eoms(me.LagrangesMethod)
    s = liefi.from_mechanics(system, {m: 1.0, k: 4.0})
    np.testing.assert_allclose(s.potential(np.array([0.5])), 4.0 * 0.25 / 2, rtol=1e-15)


# --- 4. the kinematic map solved numerically -------------------------------------------------------
@pytest.mark.parametrize("heavy", [False, True])
@pytest.mark.parametrize("q3", [0.0, 1e-9, 1e-6])
def test_yaw_roll_pitch_body_at_the_singular_pivot_agrees_with_kanes_equations(q3, heavy):
    KM, consts = top_ypr(heavy)
    top = liefi.from_mechanics(KM, consts, sample=np.array([0.1, 0.2, 0.3]))
    q, u = list(KM.q), list(KM.u)
    qv, uv = np.array([0.3, 0.2, q3]), np.array([0.4, -0.3, 6.0])
    assert_field(top, *own_field(top, KM, consts, q, u)(qv, uv))  # was 0/0 at q3 = 0


def test_sleigh_with_body_frame_speeds_builds_in_seconds_and_agrees():
    """Bounded in this process's CPU time (the build takes 0.04 s of it; it hung in ``sympy.expand`` before),
    not in wall-clock time, which the other processes of a loaded machine stretch."""
    KM, consts, cons = sleigh_kane(body_speeds=True)
    t0 = time.process_time()
    sleigh = liefi.from_mechanics(KM, consts)  # hung > 300 s in sympy.expand
    assert time.process_time() - t0 < 20.0
    q, u = list(KM.q), list(KM.u)
    rng = np.random.default_rng(2)
    field, speeds = own_field(sleigh, KM, consts, q, u), dependent_speeds(KM, consts, q, u, cons)
    for _ in range(3):
        qv = rng.uniform(-1, 1, 3)
        assert_field(sleigh, *field(qv, speeds(qv, rng.normal(size=2))))


def rattleback():
    """Kane & Levinson's rattleback as a PyDy user writes it: yaw q1, roll q2, pitch q3 and the mass centre's
    ``(x, y)``; the body rates as speeds (the kinematic equations solved for the angle rates), the no-slip rows
    as velocity constraints."""
    a, b, c, h, m, g, A, B, C, D = sympy.symbols("a b c h m g A B C D")
    q1, q2, q3, x, y = me.dynamicsymbols("q1 q2 q3 x y")
    u1, u2, u3, u4, u5 = me.dynamicsymbols("u1:6")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w = R.ang_vel_in(N)
    qd = sympy.solve([w.dot(R.x) - u1, w.dot(R.y) - u2, w.dot(R.z) - u3], [q1.diff(), q2.diff(), q3.diff()])
    kd = [s.diff() - qd[s.diff()] for s in (q1, q2, q3)] + [x.diff() - u4, y.diff() - u5]
    R.set_ang_vel(N, u1 * R.x + u2 * R.y + u3 * R.z)
    # the contact point P of the ellipsoid (Kane & Levinson 1982, eqs. 16-18), from the mass centre G
    Gam = [N.z.dot(R.x), N.z.dot(R.y), N.z.dot(R.z)]
    eps = sympy.sqrt((a * Gam[0]) ** 2 + (b * Gam[1]) ** 2 + (c * Gam[2]) ** 2)
    r_GP = -a**2 * Gam[0] / eps * R.x - b**2 * Gam[1] / eps * R.y + (h - c**2 * Gam[2] / eps) * R.z
    O = me.Point("O")
    O.set_vel(N, 0)
    G = O.locatenew("G", x * N.x + y * N.y - r_GP.dot(N.z) * N.z)
    G.set_vel(N, u4 * N.x + u5 * N.y + (-r_GP.dot(N.z)).diff(t) * N.z)
    v_contact = G.vel(N) + R.ang_vel_in(N).cross(r_GP)  # the body's point at the contact
    cons = [v_contact.dot(N.x), v_contact.dot(N.y)]
    body = me.RigidBody("rattleback", G, R, m, (me.inertia(R, A, B, C, D, 0, 0), G))
    KM = me.KanesMethod(N, q_ind=[q1, q2, q3, x, y], u_ind=[u1, u2, u3], u_dependent=[u4, u5], kd_eqs=kd,
                        velocity_constraints=cons)
    KM.kanes_equations([body], [(G, -m * g * N.z)])
    consts = dict(zip((a, b, c, h, m, g, A, B, C, D), (0.20, 0.03, 0.02, 0.01, 1.0, 9.81, 2e-4, 1.6e-3, 1.7e-3, 2e-5)))
    return KM, consts, cons


@pytest.mark.slow
def test_rattleback_started_upright_agrees_with_kanes_equations():
    """The field at ``q3 = 0, 1e-9, 1e-6`` equals the model's own to 1e-12 (was NaN at 0, 9 % off at 1e-8, and
    the build hung in ``expand``); it builds from the default sample, the upright (was refused there)."""
    KM, consts, cons = rattleback()
    t0 = time.process_time()  # this process's CPU time: the machine's load is not the build's
    rb = liefi.from_mechanics(KM, consts)
    assert time.process_time() - t0 < 60.0
    q, u = list(KM.q), list(KM.u)
    field, speeds = own_field(rb, KM, consts, q, u), dependent_speeds(KM, consts, q, u, cons)
    for q3 in (0.0, 1e-9, 1e-6):
        qv = np.array([0.3, 0.02, q3, 0.1, -0.2])
        assert_field(rb, *field(qv, speeds(qv, np.array([0.1, -0.2, 5.0]))))


# --- 5. auxiliary speeds ----------------------------------------------------------------------------
def test_auxiliary_speeds_for_a_reaction_force_leave_the_equations_unchanged():
    """Kane & Levinson's way to a pivot's reaction: the pivot moves with auxiliary speeds ``ua1, ua2`` and
    carries the unknown reaction ``(R1, R2)``; sympy forms the equations with the auxiliary speeds at zero."""
    q, u = me.dynamicsymbols("q u")
    ua1, ua2, R1, R2 = me.dynamicsymbols("ua1 ua2 R1 R2")
    m, g, l = sympy.symbols("m g l")
    N = me.ReferenceFrame("N")
    A = N.orientnew("A", "Axis", [q, N.z])
    A.set_ang_vel(N, u * N.z)
    O = me.Point("O")
    O.set_vel(N, 0)
    pivot = O.locatenew("pivot", 0)
    pivot.set_vel(N, ua1 * N.x + ua2 * N.y)
    bob = pivot.locatenew("bob", -l * A.y)
    bob.v2pt_theory(pivot, N, A)
    loads = [(bob, -m * g * N.y), (pivot, R1 * N.x + R2 * N.y)]
    KM = me.KanesMethod(N, [q], [u], kd_eqs=[q.diff() - u], u_auxiliary=[ua1, ua2])
    KM.kanes_equations([me.Particle("P", bob, m)], loads)
    consts = {m: 1.0, g: 9.81, l: 0.7}
    pend = liefi.from_mechanics(KM, consts)  # was refused: "auxiliary speeds"
    field = own_field(pend, KM, consts, [q], [u])
    for qv, uv in ((0.3, -1.0), (2.0, 0.5)):
        assert_field(pend, *field(np.array([qv]), np.array([uv])))


def test_the_rolling_disc_with_auxiliary_speeds_builds_with_its_contact_point_restored():
    """sympy's test_kane aux disc: was refused for its minimal speeds (the centre's velocity from the contact
    point); liefi restores the contact point's place (tests/test_mechanics_minimal.py), and the auxiliary
    speeds change nothing."""
    q1, q2, q3, u1, u2, u3 = me.dynamicsymbols("q1 q2 q3 u1 u2 u3")
    u4, u5, f1, f2 = me.dynamicsymbols("u4, u5, f1, f2")
    r, m, g = sympy.symbols("r m g")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w_R_N_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    C = me.Point("C")
    C.set_vel(N, u4 * L.x + u5 * (Y.z ^ L.x))
    Dmc = C.locatenew("Dmc", r * L.z)
    Dmc.v2pt_theory(C, N, R)
    I = me.inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2)
    kd = [me.dot(R.ang_vel_in(N) - w_R_N_qd, uv) for uv in L]
    ForceList = [(Dmc, -m * g * Y.z), (C, f1 * L.x + f2 * (Y.z ^ L.x))]
    KM2 = me.KanesMethod(N, q_ind=[q1, q2, q3], u_ind=[u1, u2, u3], kd_eqs=kd, u_auxiliary=[u4, u5])
    KM2.kanes_equations([me.RigidBody("BodyD", Dmc, R, m, (I, Dmc))], ForceList)
    disc = liefi.from_mechanics(KM2, {r: 0.5, m: 1.0, g: 9.81})
    assert disc.restored_coordinates == ("x_C", "y_C") and disc.K == 2
