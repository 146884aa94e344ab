"""Models in minimal speeds, as sympy's docs and PyDy's examples write them, run by ``liefi.from_mechanics`` (issue 25).

A model in minimal speeds builds a rolling condition into its kinematics (a centre's velocity
``v2pt_theory`` from a contact point of zero velocity, or fewer speeds than coordinates).
liefi restores the eliminated places (the contact point's ``x_C, y_C``) and rows itself
(:func:`liefi.systems._kinematics._restore`), so each model runs as written; each is checked
against its own equations: sympy's ``mass_matrix_full`` and ``forcing_full``.

* the field: liefi's constrained field at states of the model equals the model's rates
  ``(q', u')`` carried to liefi's state ``z = (q, x_C, y_C, p)`` by a complex-step derivative
  of ``z(q, u)`` (exact to rounding);
* ``slow``: the trajectory over ``[0, 2]`` (both integrated by DOP853 at 1e-12) agrees to 1e-8,
  and liefi's default run holds the constraints and the energy to 1e-12.

The models are copied as a user holds them: ``rollingdisc_example_kane.rst``,
``rollingdisc_example_kane_constraints.rst`` and ``rollingdisc_example_lagrange.rst`` of sympy's
tutorials, a Chaplygin sleigh in minimal speeds, and the yaw--roll--pitch rattleback of Kane &
Levinson (1982) with its contact point of zero velocity.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")

import liefi  # noqa: E402

t = me.dynamicsymbols._t


# --- the models, as the docs write them ------------------------------------------------------------
def disc_kane():
    """sympy's tutorial ``rollingdisc_example_kane``: the disc from the contact point up, minimal speeds."""
    from sympy import symbols
    from sympy.physics.mechanics import KanesMethod, Point, ReferenceFrame, RigidBody, dot, dynamicsymbols, inertia

    q1, q2, q3, u1, u2, u3 = dynamicsymbols('q1 q2 q3 u1 u2 u3')
    r, m, g = symbols('r m g')
    N = ReferenceFrame('N')
    Y = N.orientnew('Y', 'Axis', [q1, N.z])
    L = Y.orientnew('L', 'Axis', [q2, Y.x])
    R = L.orientnew('R', 'Axis', [q3, L.y])
    w_R_N_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    C = Point('C')
    C.set_vel(N, 0)
    Dmc = C.locatenew('Dmc', r * L.z)
    Dmc.v2pt_theory(C, N, R)
    I = inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2)
    kd = [dot(R.ang_vel_in(N) - w_R_N_qd, uv) for uv in L]
    ForceList = [(Dmc, - m * g * Y.z)]
    BodyD = RigidBody('BodyD', Dmc, R, m, (I, Dmc))
    BodyList = [BodyD]
    KM = KanesMethod(N, q_ind=[q1, q2, q3], u_ind=[u1, u2, u3], kd_eqs=kd)
    (fr, frstar) = KM.kanes_equations(BodyList, ForceList)
    return KM, {r: 0.5, m: 1.0, g: 9.81}, dict(q=[0.1, 0.2, 0.3], u=[0.5, -1.0, 3.0]), dict(frame=N, bodies=BodyList,
                                                                                          loads=ForceList)


def disc_slope():
    """The tutorial's disc on a slope: gravity tilted by ``beta`` in the ``N.x`` direction (the load's potential then
    holds the restored place ``x_C``: ``U = -m g sin(beta) x_C + ...``)."""
    q1, q2, q3, u1, u2, u3 = me.dynamicsymbols('q1 q2 q3 u1 u2 u3')
    r, m, g, beta = sympy.symbols('r m g beta')
    N = me.ReferenceFrame('N')
    Y = N.orientnew('Y', 'Axis', [q1, N.z])
    L = Y.orientnew('L', 'Axis', [q2, Y.x])
    R = L.orientnew('R', 'Axis', [q3, L.y])
    w_R_N_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    C = me.Point('C')
    C.set_vel(N, 0)
    Dmc = C.locatenew('Dmc', r * L.z)
    Dmc.v2pt_theory(C, N, R)
    I = me.inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2)
    kd = [me.dot(R.ang_vel_in(N) - w_R_N_qd, uv) for uv in L]
    ForceList = [(Dmc, -m * g * (sympy.cos(beta) * N.z - sympy.sin(beta) * N.x))]
    KM = me.KanesMethod(N, q_ind=[q1, q2, q3], u_ind=[u1, u2, u3], kd_eqs=kd)
    KM.kanes_equations([me.RigidBody('BodyD', Dmc, R, m, (I, Dmc))], ForceList)
    return KM, {r: 0.5, m: 1.0, g: 9.81, beta: 0.2}, dict(q=[0.0, 0.2, 0.0], u=[0.0, 4.0, 0.3]), None


def disc_kane_aux():
    """sympy's tutorial ``rollingdisc_example_kane_constraints``: the contact point's auxiliary speeds and forces."""
    from sympy import symbols
    from sympy.physics.mechanics import (KanesMethod, Point, ReferenceFrame, RigidBody, cross, dot, dynamicsymbols,
                                         inertia)

    q1, q2, q3, u1, u2, u3 = dynamicsymbols('q1 q2 q3 u1 u2 u3')
    r, m, g = symbols('r m g')
    u4, u5, u6, f1, f2, f3 = dynamicsymbols('u4 u5 u6 f1 f2 f3')
    N = ReferenceFrame('N')
    Y = N.orientnew('Y', 'Axis', [q1, N.z])
    L = Y.orientnew('L', 'Axis', [q2, Y.x])
    R = L.orientnew('R', 'Axis', [q3, L.y])
    w_R_N_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    C = Point('C')
    C.set_vel(N, u4 * L.x + u5 * cross(Y.z, L.x) + u6 * Y.z)
    Dmc = C.locatenew('Dmc', r * L.z)
    vel = Dmc.v2pt_theory(C, N, R)  # noqa: F841
    I = inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2)
    kd = [dot(R.ang_vel_in(N) - w_R_N_qd, uv) for uv in L]
    ForceList = [(Dmc, - m * g * Y.z), (C, f1 * L.x + f2 * cross(Y.z, L.x) + f3 * Y.z)]
    BodyD = RigidBody('BodyD', Dmc, R, m, (I, Dmc))
    BodyList = [BodyD]
    KM = KanesMethod(N, q_ind=[q1, q2, q3], u_ind=[u1, u2, u3], kd_eqs=kd, u_auxiliary=[u4, u5, u6])
    (fr, frstar) = KM.kanes_equations(BodyList, ForceList)
    return KM, {r: 0.5, m: 1.0, g: 9.81}, dict(q=[0.1, 0.2, 0.3], u=[0.5, -1.0, 3.0]), None


def disc_lagrange():
    """sympy's tutorial ``rollingdisc_example_lagrange``: the Lagrangian of the disc from the contact point up."""
    from sympy import cos, symbols
    from sympy.physics.mechanics import LagrangesMethod, Lagrangian, Point, ReferenceFrame, RigidBody, dynamicsymbols, \
        inertia

    q1, q2, q3 = dynamicsymbols('q1 q2 q3')
    r, m, g = symbols('r m g')
    N = ReferenceFrame('N')
    Y = N.orientnew('Y', 'Axis', [q1, N.z])
    L = Y.orientnew('L', 'Axis', [q2, Y.x])
    R = L.orientnew('R', 'Axis', [q3, L.y])
    C = Point('C')
    C.set_vel(N, 0)
    Dmc = C.locatenew('Dmc', r * L.z)
    Dmc.v2pt_theory(C, N, R)
    I = inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2)
    BodyD = RigidBody('BodyD', Dmc, R, m, (I, Dmc))
    BodyD.potential_energy = - m * g * r * cos(q2)
    Lag = Lagrangian(N, BodyD)
    q = [q1, q2, q3]
    l = LagrangesMethod(Lag, q)  # noqa: E741
    le = l.form_lagranges_equations()  # noqa: F841
    return l, {r: 0.5, m: 1.0, g: 9.81}, dict(q=[0.1, 0.2, 0.3], qd=[0.5, -1.0, 3.0]), None


def disc_system():
    """The minimal-speeds disc through sympy's ``System`` (the contact point as its fixed point), ``form_eoms()``."""
    q1, q2, q3, u1, u2, u3 = me.dynamicsymbols('q1 q2 q3 u1 u2 u3')
    r, m, g = sympy.symbols('r m g')
    N = me.ReferenceFrame('N')
    Y = N.orientnew('Y', 'Axis', [q1, N.z])
    L = Y.orientnew('L', 'Axis', [q2, Y.x])
    R = L.orientnew('R', 'Axis', [q3, L.y])
    w_R_N_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    C = me.Point('C')
    C.set_vel(N, 0)
    Dmc = C.locatenew('Dmc', r * L.z)
    Dmc.v2pt_theory(C, N, R)
    disc = me.RigidBody('disc', Dmc, R, m, (me.inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2), Dmc))
    system = me.System(N, C)
    system.q_ind = [q1, q2, q3]
    system.u_ind = [u1, u2, u3]
    system.kdes = [me.dot(R.ang_vel_in(N) - w_R_N_qd, uv) for uv in L]
    system.add_bodies(disc)
    system.add_loads(me.Force(Dmc, -m * g * Y.z))
    system.form_eoms()
    return system, {r: 0.5, m: 1.0, g: 9.81}, dict(q=[0.1, 0.2, 0.3], u=[0.5, -1.0, 3.0]), None


def sleigh_minimal():
    """A Chaplygin sleigh in minimal speeds: the blade's forward speed ``u1`` and the yaw rate ``u2`` for the
    three coordinates ``x, y, theta`` (``x' = u1 cos theta``, ``y' = u1 sin theta``), the mass centre ``a``
    ahead of the blade."""
    x, y, th = me.dynamicsymbols("x y theta")
    u1, u2 = me.dynamicsymbols("u1 u2")
    m, I, a = sympy.symbols("m I a")
    N = me.ReferenceFrame("N")
    B = N.orientnew("B", "Axis", [th, N.z])
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    P.set_vel(N, u1 * B.x)
    B.set_ang_vel(N, u2 * N.z)
    G = P.locatenew("G", a * B.x)
    G.v2pt_theory(P, N, B)
    sled = me.RigidBody("sled", G, B, m, (me.inertia(B, 0, 0, I), G))
    kd = [x.diff() - u1 * sympy.cos(th), y.diff() - u1 * sympy.sin(th), th.diff() - u2]
    KM = me.KanesMethod(N, [x, y, th], [u1, u2], kd_eqs=kd)
    KM.kanes_equations([sled], [])
    return KM, {m: 1.5, I: 0.7, a: 0.4}, dict(q=[0.1, -0.2, 0.3], u=[0.8, 1.5]), None


def sleigh_offset(body_speeds=False):
    """The Chaplygin sleigh with ``B.set_ang_vel(N, u3*N.z)`` and the mass centre offset in ``B`` (inertial
    speeds of the blade, or ``body_speeds``: ``u1 = v . B.x``, ``u2 = v . B.y``); ``u2`` dependent."""
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
    return KM, {m: 1.5, I: 0.7, a: 0.4}, dict(q=[0.1, -0.2, 0.3], u=[0.8, 1.5]), None


#: Kane & Levinson (1982) in SI units, liefi's rattleback scene (body axis 3 up, I_12 = +2e-5)
RATTLEBACK = dict(a=0.20, b=0.03, c=0.02, h=0.01, m=1.0, g=9.81, A=2e-4, B=1.6e-3, C=1.7e-3, D=2e-5)


def rattleback():
    """The rattleback as a PyDy user writes it in minimal speeds: yaw ``q1``, roll ``q2``, pitch ``q3``, the body
    rates as speeds, the contact point ``P`` of zero velocity and the mass centre ``G`` by ``v2pt_theory``."""
    a, b, c, h, m, g, A, B, C, D = sympy.symbols("a b c h m g A B C D")
    q1, q2, q3 = me.dynamicsymbols("q1 q2 q3")
    u1, u2, u3 = me.dynamicsymbols("u1:4")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w = R.ang_vel_in(N)
    qd = sympy.solve([w.dot(R.x) - u1, w.dot(R.y) - u2, w.dot(R.z) - u3], [q1.diff(), q2.diff(), q3.diff()])
    kd = [s.diff() - qd[s.diff()] for s in (q1, q2, q3)]
    R.set_ang_vel(N, u1 * R.x + u2 * R.y + u3 * R.z)
    # the contact point of the ellipsoid (Kane & Levinson 1982, eqs. 16-18), from the mass centre G
    Gam = [N.z.dot(R.x), N.z.dot(R.y), N.z.dot(R.z)]
    eps = sympy.sqrt((a * Gam[0]) ** 2 + (b * Gam[1]) ** 2 + (c * Gam[2]) ** 2)
    r_GP = -a**2 * Gam[0] / eps * R.x - b**2 * Gam[1] / eps * R.y + (h - c**2 * Gam[2] / eps) * R.z
    P = me.Point("P")
    P.set_vel(N, 0)
    G = P.locatenew("G", -r_GP)
    G.v2pt_theory(P, N, R)
    body = me.RigidBody("rattleback", G, R, m, (me.inertia(R, A, B, C, D, 0, 0), G))
    KM = me.KanesMethod(N, q_ind=[q1, q2, q3], u_ind=[u1, u2, u3], kd_eqs=kd)
    KM.kanes_equations([body], [(G, -m * g * N.z)])
    consts = {s: RATTLEBACK[str(s)] for s in (a, b, c, h, m, g, A, B, C, D)}
    tilt = np.radians(0.5)
    return KM, consts, dict(q=[0.0, tilt, tilt], u=[0.0, 0.0, 5.0]), dict(frame=N, body=R)


# --- the model's own equations, carried to liefi's state -----------------------------------------
_RATES = {}


def own_rates(eom, constants):
    """``(q, u) -> (q', u')`` of the model's own ``mass_matrix_full \\ forcing_full`` (Kane), or ``(q, q') ->
    (q', q'')`` of ``LagrangesMethod.rhs()``."""
    if id(eom) in _RATES:
        return _RATES[id(eom)][1]
    _RATES[id(eom)] = (eom, _own_rates(eom, constants))  # the model kept: its id stays its own
    return _RATES[id(eom)][1]


def _own_rates(eom, constants):
    if isinstance(eom, me.System):
        eom = eom.eom_method  # the KanesMethod of form_eoms()
    if isinstance(eom, me.LagrangesMethod):
        q = list(eom.q)
        f = sympy.lambdify(q + [s.diff(t) for s in q], eom.rhs().subs(constants), "numpy", cse=True)
        return lambda qv, vv: np.asarray(f(*qv, *vv), float).ravel()
    q, u = list(eom.q), list(eom.u)
    MM = sympy.lambdify(q + u, eom.mass_matrix_full.subs(constants), "numpy", cse=True)
    FF = sympy.lambdify(q + u, eom.forcing_full.subs(constants), "numpy", cse=True)
    return lambda qv, uv: np.linalg.solve(np.asarray(MM(*qv, *uv), float), np.asarray(FF(*qv, *uv), float).ravel())


def liefi_state(system, qv, v, restored=None):
    """``z(q_all, v)``: liefi's state at the coordinates (restored places included) and the model's speeds ``v``
    (Kane) or velocities (Lagrange), complex-step safe (the system's own maps, no casts)."""
    n = len(system.coordinates)
    if system.speeds:
        qdot = system._mech["qdot_of_u"](np.concatenate([qv, v]))
    else:
        qdot = v
    return np.concatenate([qv, system.metric(qv) @ qdot])


def assert_field(system, eom, constants, qv, v, tol=1e-12):
    """liefi's constrained field at ``z(q, v)`` equals the model's rates carried to ``z`` (relative ``tol``)."""
    rates = own_rates(eom, constants)(np.asarray(qv, float), np.asarray(v, float))
    n, r = len(qv), len(system.restored_coordinates)
    q_all = np.concatenate([qv, 0.3 * np.arange(1, r + 1)])  # the restored places: any value
    z = liefi_state(system, q_all, np.asarray(v, float))
    qdot_all = system.velocities(z)
    h = 1e-30
    dq = np.concatenate([rates[:n], qdot_all[n:]])
    dz = np.imag(liefi_state(system, q_all + 1j * h * dq, np.asarray(v, float) + 1j * h * rates[n:])) / h
    f = system.constrained_vector_field(z)
    err = np.max(np.abs(f - dz)) / np.max(np.abs(dz))
    assert err <= tol, err
    return err


MODELS = {"disc-kane": disc_kane, "disc-kane-aux": disc_kane_aux, "disc-lagrange": disc_lagrange, "disc-system": disc_system,
          "disc-slope": disc_slope,
          "sleigh-minimal": sleigh_minimal, "sleigh-offset": sleigh_offset,
          "sleigh-body-speeds": lambda: sleigh_offset(body_speeds=True)}


def build(name):
    eom, consts, start, extra = MODELS[name]()
    return eom, consts, start, liefi.from_mechanics(eom, consts)


# --- the field --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_model_builds_as_written_and_its_field_is_its_own(name):
    """Was ``MinimalSpeedsError`` (the discs), ``ValueError: 2 generalized speeds for 3 coordinates`` (the
    sleigh in minimal speeds); the field equals the model's own to 1e-12 at random states."""
    eom, consts, start, system = build(name)
    rng = np.random.default_rng(5)
    n = len(eom.q)
    for _ in range(3):
        qv = rng.uniform(-1, 1, n)
        v = rng.normal(size=len(start.get("u", start.get("qd"))))
        if name.startswith("sleigh-offset") or name == "sleigh-body-speeds":  # all three speeds on the constraint
            v = dependent(system, qv, v[:2])
        assert_field(system, eom, consts, qv, v)


def dependent(system, qv, ui):
    """All the model's speeds from the independent ones (liefi's own state(), read back)."""
    z = system.state(qv, u=ui)
    return np.stack(list(system.generalized_speeds(z).values()))


def test_the_disc_in_minimal_speeds_gets_its_contact_point_restored():
    """``x_C, y_C`` (the contact point's place; its height is constant, so not restored); ``state(q, u=...)`` takes
    the model's own q; the two restored rows are the rolling condition: the contact point moves at ``r`` times
    the spin rate.  Was ``MinimalSpeedsError``."""
    eom, consts, start, disc = build("disc-kane")
    assert disc.restored_coordinates == ("x_C", "y_C")
    assert disc.state_names[:5] == ("q1", "q2", "q3", "x_C", "y_C") and disc.K == 2
    z = disc.state(start["q"], u=start["u"])
    np.testing.assert_array_equal(z[3:5], 0.0)
    np.testing.assert_array_equal(disc.state(start["q"], u=start["u"], restored=[1.0, 2.0])[3:5], [1.0, 2.0])
    assert np.max(np.abs(disc.constraint_momenta(z))) < 1e-14
    qdot = disc.velocities(z)
    # the contact point rolls: |(x_C', y_C')| = r |q3'| (the disc's spin relative to the lean frame)
    assert abs(np.hypot(qdot[3], qdot[4]) - 0.5 * abs(qdot[2])) < 1e-14


def test_speeds_come_out_and_go_in_by_name_in_the_models_order():
    """One rule: ``generalized_speeds`` returns ``{name: values}`` in the model's order ``u_ind + u_dep``, and
    ``state(q, u=...)`` takes that mapping (or an array in that order, or the independent ones only)."""
    eom, consts, start, sled = build("sleigh-offset")
    z = sled.state(start["q"], u=start["u"])
    u = sled.generalized_speeds(z)
    assert list(u) == ["u1", "u3", "u2"] == [str(s.func) for s in eom.u]
    np.testing.assert_allclose([u["u1"], u["u3"]], start["u"], atol=1e-14)
    np.testing.assert_allclose(sled.state(start["q"], u=u), z, atol=1e-14)
    np.testing.assert_allclose(sled.state(start["q"], u={"u3": start["u"][1], "u1": start["u"][0]}), z, atol=1e-14)
    with pytest.raises(ValueError, match=r"u: expected the speeds \['u1', 'u3', 'u2'\]"):
        sled.state(start["q"], u={"u1": 1.0, "w": 2.0})
    with pytest.raises(ValueError, match=r"u: expected 3 speeds \['u1', 'u3', 'u2'\] \(or the 2 "):
        sled.state(start["q"], u=[1.0, 2.0, 3.0, 4.0])
    sol = liefi.FeedbackIntegrator(sled, z, gains=1.0).run(0.05, dt=1e-2, scheme="rk4", backend="numpy")
    us = sled.generalized_speeds(sol)
    assert list(us) == ["u1", "u3", "u2"] and us["u1"].shape == sol.t.shape


def test_fewer_speeds_than_coordinates_give_the_annihilator_row():
    """The sleigh in minimal speeds: ``qdot = B u`` with ``B`` of rank 2, so one row ``-sin(theta) x' + cos(theta)
    y' = 0`` (the blade's no-slip condition), regular at every heading; no coordinate restored."""
    eom, consts, start, sled = build("sleigh-minimal")
    assert sled.K == 1 and sled.restored_coordinates == ()
    for th in (0.0, np.pi / 2, 2.0):
        z = sled.state([0.0, 0.0, th], u=[0.8, 1.5])
        assert np.max(np.abs(sled.constraint_momenta(z))) < 1e-14
        qd = sled.velocities(z)
        assert abs(-np.sin(th) * qd[0] + np.cos(th) * qd[1]) < 1e-14
        np.testing.assert_allclose(list(sled.generalized_speeds(z).values()), [0.8, 1.5], atol=1e-14)


# --- the rattleback ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def rattleback_built():
    KM, consts, start, extra = rattleback()
    t0 = time.perf_counter()
    rb = liefi.from_mechanics(KM, consts)
    return KM, consts, start, extra, rb, time.perf_counter() - t0


@pytest.mark.slow
@pytest.mark.parametrize("tilt", [0.0, 1e-9, 1e-6])
def test_rattleback_in_minimal_speeds_at_the_upright_has_the_models_own_field(rattleback_built, tilt):
    """The yaw--roll--pitch rattleback of zero-velocity contact point (was ``MinimalSpeedsError``): its contact
    point ``x_P, y_P`` restored, the field at roll/pitch ``0, 1e-9, 1e-6`` equals sympy's ``mass_matrix_full \\
    forcing_full`` to 1e-12 relative (no pivot on a function that vanishes at the upright)."""
    KM, consts, start, extra, rb, _ = rattleback_built
    assert rb.restored_coordinates == ("x_P", "y_P")
    for qv in ([0.3, tilt, tilt], [0.3, tilt, 0.02], [0.3, 0.02, tilt]):
        assert_field(rb, KM, consts, np.array(qv), np.array([0.1, -0.2, 5.0]))


def rattleback_on_liefi_rolling():
    """The same body built with :func:`liefi.rolling.rolling_body` (the rattleback scene's data)."""
    from liefi.rolling import ellipsoid, rolling_body

    P = RATTLEBACK
    inertia = [[P["A"], P["D"], 0.0], [P["D"], P["B"], 0.0], [0.0, 0.0, P["C"]]]  # sympy's inertia(R, A, B, C, D)
    return rolling_body(P["m"], inertia, ellipsoid((P["a"], P["b"], P["c"]), offset=(0.0, 0.0, -P["h"])), P["g"])


@pytest.mark.slow
def test_rattleback_in_minimal_speeds_runs_as_the_same_body_built_with_liefi_rolling(rattleback_built):
    """liefi's default run of the sympy model over ``[0, 5]`` against the same body built with ``liefi.rolling``
    (its field integrated by DOP853 at 1e-12): the attitude rows and the body rates (relative to their largest)
    within 1e-6 (5e-8 and 2.6e-7 measured).  The numpy path's default run chooses a coarser step here (1.7e-3
    against the compiled run's 9.5e-4, with a warning that the global error could not be measured) and is off
    by 1e-5."""
    from scipy.integrate import solve_ivp

    from liefi.rolling import rolling_start

    KM, consts, start, extra, rb, _ = rattleback_built
    body = rattleback_on_liefi_rolling()
    dcm = sympy.lambdify(list(KM.q), extra["frame"].dcm(extra["body"]), "numpy")  # rows: N's axes in the body's
    q0, u0 = np.array(start["q"]), np.array(start["u"])
    y0 = rolling_start(body, np.asarray(dcm(*q0), float), u0)[11:]  # (rho_1, rho_2, Gamma, Pi, p)
    ref = solve_ivp(lambda _, y: body.constrained_vector_field(y), (0.0, 5.0), y0, method="DOP853", rtol=1e-12,
                    atol=1e-12, dense_output=True)
    sol = liefi.FeedbackIntegrator(rb, rb.state(q0, u=u0)).run(5.0)  # the default: compiled, rtol 1e-6
    Yr = ref.sol(sol.t).T
    V = np.stack([np.asarray(dcm(*q), float).ravel() for q in sol.y[:3].T])
    Omega_ref = np.linalg.solve(body.metric(Yr[:, :9]), Yr[:, 9:][..., None])[..., :3, 0]
    Omega = np.stack(list(rb.generalized_speeds(sol).values()), -1)
    err = max(np.max(np.abs(V - Yr[:, :9])), np.max(np.abs(Omega - Omega_ref)) / np.max(np.abs(Omega_ref)))
    assert err <= 1e-6, err


# --- the trajectories and the drift (slow) -------------------------------------------------------------
def own_trajectory(eom, consts, start, system, t_final=2.0):
    """The model's own equations from the start, DOP853 at 1e-12: ``(q, v)`` at ``t_final``."""
    from scipy.integrate import solve_ivp

    f = own_rates(eom, consts)
    n = len(eom.q)
    v0 = np.asarray(start.get("u", start.get("qd")), float)
    if system.speeds and len(v0) < len(system.speeds):
        v0 = dependent(system, np.asarray(start["q"], float), v0)
    y0 = np.concatenate([start["q"], v0])
    sol = solve_ivp(lambda _, y: f(y[:n], y[n:]), (0.0, t_final), y0, method="DOP853", rtol=1e-12, atol=1e-12)
    return sol.y[:n, -1], sol.y[n:, -1], y0


def error_against_own(eom, consts, start, system):
    """``(err, z0)``: liefi's constrained field against the model's own equations at ``t = 2`` (both DOP853 at
    1e-12), the largest difference in ``(q, u)`` (or ``(q, qdot)``) relative to the speeds' size; ``z0`` liefi's start."""
    from scipy.integrate import solve_ivp

    q_own, v_own, y0 = own_trajectory(eom, consts, start, system)
    n = len(eom.q)
    z0 = system.state(y0[:n], u=y0[n:]) if system.speeds else system.state(y0[:n], y0[n:])
    sol = solve_ivp(lambda _, z: system.constrained_vector_field(z), (0.0, 2.0), z0, method="DOP853", rtol=1e-12,
                    atol=1e-12)
    z = sol.y[:, -1]
    v = np.stack(list(system.generalized_speeds(z).values())) if system.speeds else system.velocities(z)[:n]
    err = max(np.max(np.abs(z[:n] - q_own)), np.max(np.abs(v - v_own))) / max(1.0, np.max(np.abs(v_own)))
    return err, z0


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_model_runs_as_its_own_equations_and_holds_its_constraints_and_energy(name):
    """Over ``[0, 2]`` liefi's field (DOP853 at 1e-12) agrees with the model's own to 1e-8 in ``(q, u)``; along
    liefi's default run every constraint row (the model's and the restored ones) and the energy hold to 1e-12."""
    eom, consts, start, system = build(name)
    err, z0 = error_against_own(eom, consts, start, system)
    assert err <= 1e-8, err
    fi = liefi.FeedbackIntegrator(system, z0)
    run = fi.run(2.0, backend="numpy")
    inv = fi.invariant_values(np.moveaxis(run.y, -1, 0))
    scale = max(1.0, float(np.max(np.abs(run.y))))
    for key in [f"J_{i + 1}" for i in range(system.K)] + ["h~"]:
        drift = float(np.max(np.abs(inv[key] - inv[key][0])))
        assert drift <= 1e-12 * scale * max(1.0, abs(float(inv[key][0]))), (key, drift)


def test_bodies_that_give_their_contact_point_different_velocities_are_named():
    """A bead located from the disc's contact point ``C`` with a velocity of its own: the disc and the bead give
    ``C`` two different motions, so no one restored place of ``C`` fits both; ``MinimalSpeedsError`` names them."""
    from liefi.mechanics import MinimalSpeedsError

    q1, q2, q3, u1, u2, u3 = me.dynamicsymbols("q1 q2 q3 u1 u2 u3")
    r, m, g = sympy.symbols("r m g")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w_R_N_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    C = me.Point("C")
    C.set_vel(N, 0)
    Dmc = C.locatenew("Dmc", r * L.z)
    Dmc.v2pt_theory(C, N, R)
    bead = C.locatenew("bead", r * Y.x)
    bead.set_vel(N, r * u1 * N.x)
    kd = [me.dot(R.ang_vel_in(N) - w_R_N_qd, uv) for uv in L]
    bodies = [me.RigidBody("BodyD", Dmc, R, m, (me.inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2), Dmc)),
              me.Particle("bead", bead, m)]
    KM = me.KanesMethod(N, q_ind=[q1, q2, q3], u_ind=[u1, u2, u3], kd_eqs=kd, bodies=bodies,
                        forcelist=[(Dmc, -m * g * Y.z)])
    with pytest.raises(MinimalSpeedsError, match=r"\['BodyD', 'bead'\] located from C give it different velocities"):
        liefi.from_mechanics(KM, {r: 0.5, m: 1.0, g: 9.81})


def test_a_speed_without_a_coordinate_gets_one_and_a_frame_given_its_rate_only_builds():
    """sympy's bicycle test gives the wheels the rates ``u3, u6`` but no angles, and their frames an angular
    velocity but no orientation: liefi adds the coordinate ``q_<u>`` (``q_<u>' = u``, ignorable) and forms
    the kinetic energy in the frame of the body's inertia.  Here a pendulum whose bob is a rotor spinning
    about the rod: ``((m + m_r) l^2 + I_r) q'' = -(m + m_r) g l sin q`` (the spin's gyroscopic torque is
    along ``A.y``, taken by the plane), so ``omega^2 = (m + m_r) g l / ((m + m_r) l^2 + I_r)`` at any spin."""
    q = me.dynamicsymbols("q")
    u1, u2 = me.dynamicsymbols("u1 u2")
    m, mr, l, g, Ia, Ir = sympy.symbols("m m_r l g I_a I_r")
    N = me.ReferenceFrame("N")
    A = N.orientnew("A", "Axis", [q, N.z])
    A.set_ang_vel(N, u1 * N.z)
    W = me.ReferenceFrame("W")  # the rotor: its rate about the rod only
    W.set_ang_vel(A, u2 * A.x)
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", l * A.x)
    P.v2pt_theory(O, N, A)
    bodies = [me.Particle("bob", P, m), me.RigidBody("rotor", P, W, mr, (me.inertia(A, Ia, Ir, Ir), P))]
    kane = me.KanesMethod(N, q_ind=[q], u_ind=[u1, u2], kd_eqs=[q.diff() - u1])
    kane.kanes_equations(bodies, [(P, (m + mr) * g * N.x)])
    c = {m: 1.0, mr: 0.5, l: 0.7, g: 9.81, Ia: 0.02, Ir: 0.01}
    system = liefi.from_mechanics(kane, c)
    assert tuple(system.space.shape_names) == ("q", "q_u2")
    lin = system.linearize([0.0, 0.0], u=[0.0, 3.0])
    w2 = (c[m] + c[mr]) * c[g] * c[l] / ((c[m] + c[mr]) * c[l] ** 2 + c[Ir])
    np.testing.assert_allclose(np.sort_complex(lin.nontrivial_eigenvalues), [-1j * np.sqrt(w2), 1j * np.sqrt(w2)],
                               rtol=1e-12)
    assert "translation of q_u2 (ignorable)" in [mode.name for mode in lin.trivial_modes]
    z = system.state([0.3, 0.0], u=[0.0, 3.0])  # the rotor's energy counts: I_a u2^2 / 2 at rest
    U = -(c[m] + c[mr]) * c[g] * c[l] * np.cos(0.3)
    assert system.hamiltonian(z) == pytest.approx(c[Ia] * 9.0 / 2 + U, rel=1e-13)
