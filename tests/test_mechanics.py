"""``liefi.from_mechanics``: models written as the sympy docs write them, handed over in one call.

A Chaplygin sleigh (``LagrangesMethod``), a rolling disk (``KanesMethod`` with dependent
speeds) and a knife edge (``System``) each give the same vector fields, at random states on
and off the constraint set, and the same trajectories as a system written by hand (or the
scene) to 1e-12; the knife edge and the sleigh also follow the closed-form solutions.  The
constants change without a rebuild, and a mass sweep is one ensemble call equal member by
member to separate builds.  Bad models get named errors.
"""

from __future__ import annotations

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")

import liefi  # noqa: E402
from liefi import CotangentBundle, NonholonomicSystem, scenes  # noqa: E402
from liefi.mechanics import NonConservativeLoadError  # noqa: E402
from liefi.scenes import exact  # noqa: E402

TOL = 1e-12


# --- the models, written as in the sympy.physics.mechanics docs ------------------------------
from models import sleigh_model  # noqa: E402 -- the sleigh as sympy's docs write it (tests/models.py)


def disk_model(minimal=False):
    """Rolling disk (yaw q1, lean q2, spin q3, contact point x, y), Kane's method with dependent speeds.

    ``minimal=True`` is the docs' minimal-speeds disk (the centre's velocity by ``v2pt_theory``
    from a contact point of zero velocity), which liefi refuses.
    """
    q1, q2, q3, x, y = me.dynamicsymbols("q1 q2 q3 x y")
    u1, u2, u3, u4, u5 = me.dynamicsymbols("u1:6")
    m, r, g = sympy.symbols("m r g")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w_R_N_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    I = me.inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2)
    kd = [me.dot(R.ang_vel_in(N) - w_R_N_qd, uv) for uv in L]
    if minimal:
        C = me.Point("C")
        C.set_vel(N, 0)
        Dmc = C.locatenew("Dmc", r * L.z)
        Dmc.v2pt_theory(C, N, R)
        disc = me.RigidBody("disc", Dmc, R, m, (I, Dmc))
        return me.KanesMethod(N, q_ind=[q1, q2, q3], u_ind=[u1, u2, u3], kd_eqs=kd, bodies=[disc],
                              forcelist=[(Dmc, -m * g * Y.z)]), (m, r, g)
    O = me.Point("O")
    O.set_vel(N, 0)
    C = O.locatenew("C", x * N.x + y * N.y)  # the contact point
    Dmc = C.locatenew("Dmc", r * L.z)  # the centre of the disk
    Dmc.set_vel(N, Dmc.pos_from(O).dt(N).subs({x.diff(): u4, y.diff(): u5}))
    kd += [u4 - x.diff(), u5 - y.diff()]
    # rolling without slipping: the material point of the disk at C has zero velocity
    v_contact = Dmc.vel(N) + me.cross(R.ang_vel_in(N), C.pos_from(Dmc))
    disc = me.RigidBody("disc", Dmc, R, m, (I, Dmc))
    KM = me.KanesMethod(N, q_ind=[q1, q2, q3, x, y], u_ind=[u1, u2, u3], u_dependent=[u4, u5], kd_eqs=kd,
                        velocity_constraints=[me.dot(v_contact, N.x), me.dot(v_contact, N.y)],
                        bodies=[disc], forcelist=[(Dmc, -m * g * N.z)])
    return KM, (m, r, g)


def knife_model():
    """Knife edge on an inclined plane as a ``System``: gravity along the plane, ``g sin(alpha)``."""
    x, y, phi = me.dynamicsymbols("x y phi")
    m, J, g, alpha = sympy.symbols("m J g alpha")
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    B = N.orientnew("B", "Axis", [phi, N.z])
    P = O.locatenew("P", x * N.x + y * N.y)
    blade = me.RigidBody("blade", P, B, m, (me.inertia(B, 0, 0, J), P))
    system = me.System(N, O)
    system.add_coordinates(x, y, phi)
    system.add_bodies(blade)
    system.apply_uniform_gravity(g * sympy.sin(alpha) * N.x)
    system.add_nonholonomic_constraints(P.vel(N).dot(B.y))
    return system, (m, J, g, alpha)


# --- the same systems by hand (numpy) ---------------------------------------------------------
def sleigh_by_hand(m, I, a):
    def metric(q):
        s, c = np.sin(q[..., 2]), np.cos(q[..., 2])
        o, z = np.ones_like(s), np.zeros_like(s)
        return np.stack([np.stack([m * o, z, -m * a * s], -1), np.stack([z, m * o, m * a * c], -1),
                         np.stack([-m * a * s, m * a * c, (I + m * a * a) * o], -1)], -2)

    def rows(q):
        return np.stack([-np.sin(q[..., 2]), np.cos(q[..., 2]), np.zeros_like(q[..., 2])], -1)[..., None, :]

    return NonholonomicSystem.from_velocity_constraints(CotangentBundle(3, names=("x", "y", "theta")), metric, rows)


def disk_by_hand(m, r, g):
    """``T = m/2 |v_G|^2 + 1/2 w.I.w`` with ``v_G = Jv qdot``, ``w = Jw qdot`` (``w`` in the lean frame)."""

    def jacobians(q):
        cy, sy, cl, sl = np.cos(q[..., 0]), np.sin(q[..., 0]), np.cos(q[..., 1]), np.sin(q[..., 1])
        o, z = np.ones_like(cy), np.zeros_like(cy)
        Jv = np.stack([np.stack([r * cy * sl, r * sy * cl, z, o, z], -1),
                       np.stack([r * sy * sl, -r * cy * cl, z, z, o], -1),
                       np.stack([z, -r * sl, z, z, z], -1)], -2)
        Jw = np.stack([np.stack([z, o, z, z, z], -1), np.stack([sl, z, o, z, z], -1), np.stack([cl, z, z, z, z], -1)], -2)
        return Jv, Jw, (cy, sy, cl, sl)

    def metric(q):
        Jv, Jw, _ = jacobians(q)
        inertia = np.diag([m * r * r / 4, m * r * r / 2, m * r * r / 4])
        return m * np.swapaxes(Jv, -1, -2) @ Jv + np.swapaxes(Jw, -1, -2) @ inertia @ Jw

    def rows(q):  # contact velocity v_G - r w2 L.x + r w1 L.y, its N.x and N.y components
        Jv, Jw, (cy, sy, cl, sl) = jacobians(q)
        vx = Jv[..., 0, :] - r * cy[..., None] * Jw[..., 1, :] - r * (sy * cl)[..., None] * Jw[..., 0, :]
        vy = Jv[..., 1, :] - r * sy[..., None] * Jw[..., 1, :] + r * (cy * cl)[..., None] * Jw[..., 0, :]
        return np.stack([vx, vy], -2)

    def U(q):
        return m * g * r * np.cos(q[..., 1])

    space = CotangentBundle(5, names=("q1", "q2", "q3", "x", "y"))
    return NonholonomicSystem.from_velocity_constraints(space, metric, rows, U)


def _agree(a, b, z):
    for f in ("extended_vector_field", "constrained_vector_field", "extended_hamiltonian"):
        want, got = getattr(b, f)(z), getattr(a, f)(z)
        assert np.max(np.abs(got - want)) <= TOL * max(1.0, np.max(np.abs(want))), f


def _same_trajectories(a, b, z0, t_final=1.0, dt=1e-2, gains=10.0):
    sa = liefi.FeedbackIntegrator(a, z0, gains=gains).run(t_final, dt=dt, scheme="rk4")
    sb = liefi.FeedbackIntegrator(b, z0, gains=gains).run(t_final, dt=dt, scheme="rk4")
    assert np.max(np.abs(sa.y - sb.y)) <= TOL * max(1.0, np.max(np.abs(sb.y)))
    return sa


# --- tests -------------------------------------------------------------------------------------
def test_lagranges_method_sleigh_equals_the_hand_written_system_and_the_closed_form():
    LM, (m, I, a) = sleigh_model()
    sleigh = liefi.from_mechanics(LM, {m: 1.0, I: 1.0, a: 0.5})
    ref = sleigh_by_hand(1.0, 1.0, 0.5)
    assert sleigh.state_names == ("x", "y", "theta", "p_x", "p_y", "p_theta")
    z = np.random.default_rng(0).normal(size=(5, 6))
    _agree(sleigh, ref, z)
    _agree(sleigh, ref, ref.project(z))
    # the scene's start (omega0 = 1, forward speed 0.5 at theta = 0), as (q, qdot)
    sc = scenes.get("chaplygin")
    z0 = sleigh.state([0.0, 0.0, 0.0], [sc.v0, 0.0, sc.omega0])
    np.testing.assert_allclose(sleigh.velocities(z0), [sc.v0, 0.0, sc.omega0], rtol=0, atol=1e-15)
    sol = _same_trajectories(sleigh, ref, z0)
    ex = exact.chaplygin(sol.t, sc.m, sc.I, sc.a, sc.theta0, sc.Pi0())
    assert np.max(np.abs(sol["theta"] - ex["theta"])) < 1e-7  # RK4, dt = 1e-2: O(dt^4)


def test_kanes_method_rolling_disk_equals_the_hand_written_system():
    KM, (m, r, g) = disk_model()
    disk = liefi.from_mechanics(KM, {m: 2.0, r: 0.5, g: 9.81})
    ref = disk_by_hand(2.0, 0.5, 9.81)
    assert disk.K == 2 and disk.speeds == tuple(KM.u)
    rng = np.random.default_rng(1)
    z = np.concatenate([rng.uniform(-1, 1, (6, 5)), rng.normal(size=(6, 5))], -1)
    _agree(disk, ref, z)
    _agree(disk, ref, ref.project(z))
    # start from the independent speeds (spin 4, yaw rate 0.3 in the lean frame); u4, u5 from the constraints
    q0 = np.array([0.0, 0.2, 0.0, 0.0, 0.0])
    z0 = disk.state(q0, u=[0.0, 4.0, 0.3])
    assert np.max(np.abs(disk.constraint_momenta(z0))) < 1e-14
    u0 = np.stack(list(disk.generalized_speeds(z0).values()))  # {name: value} in the model's order
    np.testing.assert_allclose(u0[:3], [0.0, 4.0, 0.3], atol=1e-14)
    np.testing.assert_allclose(disk.state(q0, u=u0), z0, atol=1e-14)  # all five speeds: the same state
    sol = _same_trajectories(disk, ref, z0, gains=1.0)
    u, qdot = np.stack(list(disk.generalized_speeds(sol).values())), disk.velocities(sol)
    assert u.shape == qdot.shape == (5, sol.t.size)
    np.testing.assert_allclose(u[3:], qdot[3:], rtol=0, atol=1e-12)  # u4, u5 = x', y'
    # rolling: the contact point moves at r times the spin rate, |(x', y')| = r |q3'|
    np.testing.assert_allclose(np.hypot(qdot[3], qdot[4]), 0.5 * np.abs(qdot[2]), rtol=1e-5)


def test_kanes_method_agrees_with_kanes_equations():
    """liefi's constrained field, read as du/dt, equals sympy's own Kane equations (mass matrix \\ forcing)."""
    KM, (m, r, g) = disk_model()
    KM.kanes_equations()
    disk = liefi.from_mechanics(KM, {m: 2.0, r: 0.5, g: 9.81})
    q, u = list(KM.q), list(KM.u)
    t = me.dynamicsymbols._t
    subs = {s: v for s, v in zip((m, r, g), (2.0, 0.5, 9.81))}
    Mf = sympy.lambdify(q + u, KM.mass_matrix_full.subs(subs), "numpy")
    ff = sympy.lambdify(q + u, KM.forcing_full.subs(subs), "numpy")
    rng = np.random.default_rng(3)
    for _ in range(3):
        z = disk.project(np.concatenate([rng.uniform(-1, 1, 5), rng.normal(size=5)]))
        speeds = lambda z: np.stack(list(disk.generalized_speeds(z).values()))  # noqa: E731
        uz = speeds(z)
        args = list(z[:5]) + list(uz)
        want = np.linalg.solve(np.asarray(Mf(*args), float), np.asarray(ff(*args), float).ravel())
        h = 1e-6  # d/dt of u(q, qdot) along liefi's constrained field, by a central difference
        dz = disk.constrained_vector_field(z)
        got = (speeds(z + h * dz) - speeds(z - h * dz)) / (2 * h)
        np.testing.assert_allclose(disk.velocities(z), dz[:5], atol=1e-12)
        np.testing.assert_allclose(got, want[5:], rtol=1e-6, atol=1e-6)
    del t


def test_system_knife_edge_equals_the_scene_and_the_exact_solution():
    system, (m, J, g, alpha) = knife_model()
    sc = scenes.get("knife-edge")
    knife = liefi.from_mechanics(system, {m: sc.m, J: sc.J, g: sc.g, alpha: sc.alpha})
    assert knife.state_names == sc.system.state_names
    z = np.random.default_rng(2).normal(size=(6, 6))
    _agree(knife, sc.system, z)
    _agree(knife, sc.system, sc.system.project(z))
    z0 = sc.initial_state(sc.variants["extended"])
    sol = _same_trajectories(knife, sc.system, z0)
    ex = sc.exact(sol.t, sc.variants["extended"])
    assert max(np.max(np.abs(sol[k] - ex[k])) for k in ("x", "y", "phi")) < 1e-8


def test_constants_change_without_a_rebuild():
    LM, (m, I, a) = sleigh_model()
    sleigh = liefi.from_mechanics(LM, {"m": 1.0, I: 1.0, a: 0.5})
    assert sleigh.constant_names == ("m", "I", "a")
    z = np.random.default_rng(4).normal(size=(4, 6))
    sleigh.constants = {"m": 3.0}
    _agree(sleigh, sleigh_by_hand(3.0, 1.0, 0.5), z)
    sleigh.constants = [2.0, 0.7, -0.2]
    _agree(sleigh, sleigh_by_hand(2.0, 0.7, -0.2), z)
    assert sleigh.constants_dict()["a"] == -0.2
    with pytest.raises(ValueError, match="constants: 'k' is not a parameter"):
        sleigh.constants = {"k": 1.0}
    with pytest.raises(ValueError, match=r"constants: expected 3 values"):
        sleigh.constants = [1.0, 2.0]


def test_mass_sweep_is_one_ensemble_call_equal_to_separate_builds():
    LM, (m, I, a) = sleigh_model()
    sleigh = liefi.from_mechanics(LM, {m: 1.0, I: 1.0, a: 0.5})
    masses = np.array([0.5, 1.0, 2.0, 4.0])
    q0, qdot0 = np.zeros(3), np.array([0.5, 0.0, 1.0])
    sleigh.constants = {"m": masses}  # per-member constants, shape (4, 3): no rebuild
    assert sleigh.constants.shape == (4, 3)
    z0 = sleigh.state(np.broadcast_to(q0, (4, 3)), np.broadcast_to(qdot0, (4, 3)))
    # one call; V penalizes the constraint (target 0) and the energy (each member's own h~ at its start)
    fi = liefi.FeedbackIntegrator(sleigh, z0, gains=10.0)
    np.testing.assert_allclose(fi.targets["energy"], fi.invariant_values(z0)["h~"], rtol=1e-15)
    ens = fi.run(1.0, dt=1e-2, scheme="rk4", backend="numpy")  # per-member constants: the numpy path
    assert ens.y.shape == (4, 6, 101)
    qdot = sleigh.velocities(ens)  # each member's velocities with its own mass
    assert qdot.shape == (4, 3, 101)
    for k, mk in enumerate(masses):
        LMk, (mm, II, aa) = sleigh_model()
        one = liefi.from_mechanics(LMk, {mm: mk, II: 1.0, aa: 0.5})
        zk = one.state(q0, qdot0)
        np.testing.assert_allclose(z0[k], zk, rtol=0, atol=1e-15)
        solk = liefi.FeedbackIntegrator(one, zk, gains=10.0).run(1.0, dt=1e-2, scheme="rk4")
        assert np.max(np.abs(ens.y[k] - solk.y)) <= TOL * np.max(np.abs(solk.y))
        np.testing.assert_allclose(qdot[k], one.velocities(solk), rtol=0, atol=1e-12)
    theta = ens.y[:, 2, -1]
    assert np.ptp(theta) > 1e-2  # the members differ: each ran with its own mass


def test_minimal_speeds_disk_is_the_disk_with_its_contact_point():
    """The docs' minimal-speeds disk (was refused, ``MinimalSpeedsError``): liefi restores the contact point's
    ``x_C, y_C`` and the two rolling rows, which gives the disk written with ``x, y`` and dependent speeds."""
    KM, (m, r, g) = disk_model(minimal=True)
    disk = liefi.from_mechanics(KM, {m: 2.0, r: 0.5, g: 9.81})
    full = liefi.from_mechanics(disk_model()[0], {m: 2.0, r: 0.5, g: 9.81})
    assert disk.restored_coordinates == ("x_C", "y_C") and disk.K == full.K == 2
    rng = np.random.default_rng(4)
    z = full.project(np.concatenate([rng.uniform(-1, 1, (4, 5)), rng.normal(size=(4, 5))], -1))
    np.testing.assert_allclose(disk.constrained_vector_field(z), full.constrained_vector_field(z), rtol=0, atol=1e-12)
    z0 = disk.state([0.0, 0.2, 0.0], u=[0.0, 4.0, 0.3])
    np.testing.assert_allclose(z0, full.state([0.0, 0.2, 0.0, 0.0, 0.0], u=[0.0, 4.0, 0.3]), rtol=0, atol=1e-14)


def test_loads_without_a_potential_are_named():
    x = me.dynamicsymbols("x")
    k, c, m = sympy.symbols("k c m")
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x)
    ball = me.Particle("ball", P, m)
    damper = (P, -c * x.diff() * N.x)
    LM = me.LagrangesMethod(me.Lagrangian(N, ball), [x], forcelist=[damper], frame=N)
    damped = liefi.from_mechanics(LM, {m: 1.0, c: 0.1})  # no potential: the system's force (issue 28)
    assert damped.force.inputs == ()
    np.testing.assert_allclose(damped.force(0.0, np.array([0.3]), np.array([2.0]), None), [-0.2], rtol=1e-15)
    spring = (P, -k * x * N.x)
    LM = me.LagrangesMethod(me.Lagrangian(N, ball), [x], forcelist=[spring], frame=N)
    osc = liefi.from_mechanics(LM, {m: 2.0, k: 3.0}, potential=k * x**2 / 2)
    np.testing.assert_allclose(osc.potential(np.array([0.5])), 3.0 * 0.25 / 2, rtol=1e-15)
    with pytest.raises(NonConservativeLoadError, match="potential: its -dU/dt is not the power"):
        liefi.from_mechanics(LM, {m: 2.0, k: 3.0}, potential=k * x**2)
    with pytest.raises(TypeError, match="potential: expected a sympy expression .* does not parse strings"):
        liefi.from_mechanics(LM, {m: 2.0, k: 3.0}, potential="k*x**2/2")
    # a load given to kanes_equations (the docs' older style) is read from there too
    u = me.dynamicsymbols("u")
    Q = O.locatenew("Q", x * N.x)
    Q.set_vel(N, u * N.x)
    KM = me.KanesMethod(N, [x], [u], kd_eqs=[x.diff() - u])
    KM.kanes_equations([me.Particle("p", Q, m)], [(Q, -m * k * N.x)])
    fall = liefi.from_mechanics(KM, {m: 2.0, k: 3.0})
    np.testing.assert_allclose(fall.potential(np.array([1.5])), 2.0 * 3.0 * 1.5, rtol=1e-15)


def test_bad_models_and_constants_are_named():
    LM, (m, I, a) = sleigh_model()
    with pytest.raises(ValueError, match=r"constants: no value for the model's parameter\(s\) \['a'\]"):
        liefi.from_mechanics(LM, {m: 1.0, I: 1.0})
    with pytest.raises(ValueError, match="constants: 'mass' is not a symbol of the model"):
        liefi.from_mechanics(LM, {"mass": 1.0, I: 1.0, a: 0.5})
    with pytest.raises(TypeError, match="expected a sympy.physics.mechanics LagrangesMethod"):
        liefi.from_mechanics(42)
    with pytest.raises(TypeError, match="from_sympy"):
        liefi.from_mechanics(sympy.Symbol("L"))
    sleigh = liefi.from_mechanics(LM, {m: 1.0, I: 1.0, a: 0.5})
    with pytest.raises(ValueError, match="generalized_speeds: a Lagrange model"):
        sleigh.generalized_speeds(np.zeros(6))
    with pytest.raises(ValueError, match="state: give the velocities qdot or"):
        sleigh.state(np.zeros(3))
    with pytest.raises(ValueError, match=r"qdot: expected 3 finite numbers"):
        sleigh.state(np.zeros(3), np.zeros(2))


def test_from_sympy_points_a_mechanics_model_to_from_mechanics():
    LM, (m, I, a) = sleigh_model()
    with pytest.raises(TypeError, match=r"L: a sympy.physics.mechanics LagrangesMethod.*from_mechanics"):
        liefi.from_sympy(LM, LM.q, LM._qdots, LM.coneqs)
    x, xd = sympy.symbols("x xd")
    osc = liefi.from_sympy(sympy.Matrix([xd**2 / 2 - x**2 / 2]), [x], [xd])  # a 1x1 Matrix is its element
    assert np.allclose(osc.potential(np.array([2.0])), 2.0)
    with pytest.raises(ValueError, match="L: expected one scalar expression .* 2x1 Matrix"):
        liefi.from_sympy(sympy.Matrix([xd**2, x]), [x], [xd])


def test_the_compiled_engine_folds_the_current_constants():
    """The traced kernel (generated code, run as Python) equals the numpy field for each value of the
    constants; per-member constants are refused by the tracer (the run then takes the numpy path)."""
    from liefi import engine

    KM, (m, r, g) = disk_model()
    disk = liefi.from_mechanics(KM, {m: 1.0, r: 0.5, g: 9.81})
    z0 = disk.state([0.0, 0.2, 0.0, 0.0, 0.0], u=[0.0, 4.0, 0.3])
    y = z0 + 0.05 * np.random.default_rng(5).normal(size=10)
    for radius in (0.5, 0.8):
        disk.constants = {"r": radius}
        fi = liefi.FeedbackIntegrator(disk, z0, gains=2.0)
        f = engine.compile_feedback(fi, engine="python")
        want = fi.vector_field(y)
        assert np.max(np.abs(f.rhs(y, fi.parameters()) - want)) <= TOL * np.max(np.abs(want))
    disk.constants = {"r": [0.5, 0.8]}
    fi = liefi.FeedbackIntegrator(disk, np.stack([z0, z0]), gains=2.0, invariants=("constraints",))
    with pytest.raises(engine.NotCompilable, match="per-member constants run on the numpy path"):
        engine.compile_feedback(fi, engine="python")
