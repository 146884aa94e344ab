"""Models with configuration constraints and dependent coordinates, written as sympy's docs write them.

Each is built by one call of ``liefi.from_mechanics``, and must agree over [0, 2] with the
model's own equations (sympy's ``mass_matrix_full`` and ``forcing_full``, the dependent
speeds solved from the velocity constraints at each evaluation, DOP853 at 1e-12) to 1e-8,
and hold every declared constraint (values and velocity constraints) and the energy to
1e-12 along liefi's run.
"""

import time

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import liefi

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")
T_END = 2.0
T_EVAL = np.linspace(0.0, T_END, 21)


# --- the models, as sympy's documentation writes them ------------------------------------
def kane_pendulum(solver="LU"):
    """doc/src/tutorials/physics/mechanics/lin_pend_nonmin_example.rst, Kane's method."""
    from sympy.physics.mechanics import dynamicsymbols, ReferenceFrame, Point, Particle, KanesMethod
    from sympy import symbols, atan, Matrix, solve
    q1, q2 = dynamicsymbols('q1:3')
    q1d, q2d = dynamicsymbols('q1:3', level=1)
    u1, u2 = dynamicsymbols('u1:3')
    u1d, u2d = dynamicsymbols('u1:3', level=1)
    L, m, g, t = symbols('L, m, g, t')
    N = ReferenceFrame('N')
    pN = Point('N*')
    pN.set_vel(N, 0)
    theta1 = atan(q2/q1)
    A = N.orientnew('A', 'axis', [theta1, N.z])
    P = pN.locatenew('P1', q1*N.x + q2*N.y)
    pP = Particle('pP', P, m)
    kde = Matrix([q1d - u1,
                  q2d - u2])
    dq_dict = solve(kde, [q1d, q2d])
    P.set_vel(N, P.pos_from(pN).dt(N).subs(dq_dict))
    f_c = Matrix([P.pos_from(pN).magnitude() - L])
    f_v = Matrix([P.vel(N).express(A).dot(A.x)])
    f_v.simplify()
    R = m*g*N.x
    KM = KanesMethod(N, q_ind=[q2], u_ind=[u2], q_dependent=[q1],
                     u_dependent=[u1], configuration_constraints=f_c,
                     velocity_constraints=f_v, kd_eqs=kde, constraint_solver=solver)
    start = time.perf_counter()
    (fr, frstar) = KM.kanes_equations([pP], [(P, R)])
    return dict(model=KM, eom_seconds=time.perf_counter() - start, constants={L: 0.7, m: 1.3, g: 9.81},
                hol=list(f_c), vel=list(f_v), kde=kde, u=[u1, u2])


def lagrange_pendulum():
    """doc/src/tutorials/physics/mechanics/lin_pend_nonmin_example.rst, Lagrange's method."""
    from sympy.physics.mechanics import dynamicsymbols, ReferenceFrame, Point, Particle, Lagrangian, LagrangesMethod
    from sympy import symbols, Matrix, atan
    q1, q2 = dynamicsymbols('q1:3')
    q1d, q2d = dynamicsymbols('q1:3', level=1)
    L, m, g, t = symbols('L, m, g, t')
    N = ReferenceFrame('N')
    pN = Point('N*')
    pN.set_vel(N, 0)
    theta1 = atan(q2/q1)
    A = N.orientnew('A', 'axis', [theta1, N.z])
    P = pN.locatenew('P1', q1*N.x + q2*N.y)
    P.set_vel(N, P.pos_from(pN).dt(N))
    pP = Particle('pP', P, m)
    f_c = Matrix([q1**2 + q2**2 - L**2])
    R = m*g*N.x
    Lag = Lagrangian(N, pP)
    LM = LagrangesMethod(Lag, [q1, q2], hol_coneqs=f_c, forcelist=[(P, R)], frame=N)
    start = time.perf_counter()
    lag_eqs = LM.form_lagranges_equations()
    return dict(model=LM, eom_seconds=time.perf_counter() - start, constants={L: 0.7, m: 1.3, g: 9.81},
                hol=list(f_c), vel=list(LM.coneqs), q_dep=[q1])


def four_bar():
    """doc/src/tutorials/physics/mechanics/four_bar_linkage_example.rst (System, KanesMethod backend)."""
    from sympy import Matrix, linear_eq_to_matrix, pi, simplify, symbols
    from sympy.physics.mechanics import (dynamicsymbols, ReferenceFrame, Point, Inertia, RigidBody, System,
                                         PinJoint)
    q1, q2, q3, u1, u2, u3 = dynamicsymbols('q1:4, u1:4')
    l1, l2, l3, l4, rho = symbols('l1:5, rho')
    N = ReferenceFrame('N')
    mass_centers = [Point(f'mc{i}') for i in range(1, 5)]
    inertias = [Inertia.from_inertia_scalars(P, N, 0, 0, rho*l**3/12)
                for P, l in zip(mass_centers, (l1, l2, l3, l4))]
    link1 = RigidBody('Link1', frame=N, mass=rho*l1,
                      masscenter=mass_centers[0], inertia=inertias[0])
    link2 = RigidBody('Link2', mass=rho*l2, masscenter=mass_centers[1],
                      inertia=inertias[1])
    link3 = RigidBody('Link3', mass=rho*l3, masscenter=mass_centers[2],
                      inertia=inertias[2])
    link4 = RigidBody('Link4', mass=rho*l4, masscenter=mass_centers[3],
                      inertia=inertias[3])
    system = System.from_newtonian(link1)
    joint1 = PinJoint('J1', link1, link2, coordinates=q1, speeds=u1,
                      parent_point=l1/2*link1.x,
                      child_point=-l2/2*link2.x, joint_axis=link1.z)
    joint2 = PinJoint('J2', link2, link3, coordinates=q2, speeds=u2,
                      parent_point=l2/2*link2.x,
                      child_point=-l3/2*link3.x, joint_axis=link2.z)
    joint3 = PinJoint('J3', link3, link4, coordinates=q3, speeds=u3,
                      parent_point=l3/2*link3.x,
                      child_point=-l4/2*link4.x, joint_axis=link3.z)
    system.add_joints(joint1, joint2, joint3)
    start_point = link1.masscenter.locatenew('start_point', -l1/2*link1.x)
    end_point = link4.masscenter.locatenew('end_point', l4/2*link4.x)
    loop = end_point.pos_from(start_point)
    system.add_holonomic_constraints(loop.dot(link1.x), loop.dot(link1.y))
    system.q_ind = [q1]
    system.u_ind = [u1]
    system.q_dep = [q2, q3]
    system.u_dep = [u2, u3]
    system.validate_system()
    start = time.perf_counter()
    system.form_eoms()
    return dict(model=system, eom_seconds=time.perf_counter() - start,
                constants={l1: 2, l2: 1, l3: 2, l4: 1, rho: 5}, hol=list(system.holonomic_constraints),
                vel=list(system.velocity_constraints), kde=Matrix(system.kdes), u=[u1, u2, u3])




def four_bar_gravity():
    """The four-bar as the tutorial continues: auxiliary speeds and noncontributing forces at the closing joint,
    velocity constraints overwritten with them, and gravity (KanesMethod forms the equations with the auxiliary
    speeds at zero; the noncontributing forces do no work)."""
    from sympy import symbols
    from sympy.physics.mechanics import dynamicsymbols, Force
    case = four_bar()
    system = case["model"]
    N = system.frame
    link1, link4 = system.bodies[0], system.bodies[3]
    l1, l2, l3, l4, rho = sorted(case["constants"], key=str)
    start_point = link1.masscenter.locatenew('start_point', -l1/2*link1.x)
    end_point = link4.masscenter.locatenew('end_point', l4/2*link4.x)
    uaux1, uaux2 = dynamicsymbols('uaux1:3')
    end_point_aux = end_point.locatenew('end_point_aux', 0)
    end_point_aux.set_vel(N, end_point.vel(N) + uaux1*N.x + uaux2*N.y)
    system.velocity_constraints = [
       end_point_aux.vel(N).dot(N.x), end_point_aux.vel(N).dot(N.y)]
    faux1, faux2 = dynamicsymbols('faux1:3')
    end_point_forces = end_point.locatenew('end_point_forces', 0)
    end_point_forces.set_vel(N, uaux1*N.x + uaux2*N.y)
    noncontributing_forces = [Force(end_point_forces, faux1*N.x + faux2*N.y)]
    system.add_loads(*noncontributing_forces)
    system.u_aux = [uaux1, uaux2]
    g = symbols('g')
    system.apply_uniform_gravity(-g*N.y)
    system.validate_system()
    start = time.perf_counter()
    eoms = system.form_eoms()
    case.update(eom_seconds=time.perf_counter() - start, aux=[uaux1, uaux2],
                vel=list(system.velocity_constraints), constants={**case["constants"], g: 9.81})
    return case


def disc_on_incline():
    """sympy/physics/mechanics/tests/test_lagrange.py::test_disc_on_an_incline_plane (hol_coneqs linear in q)."""
    from sympy import symbols, pi, sin
    from sympy.physics.mechanics import dynamicsymbols, ReferenceFrame, Point, RigidBody, Lagrangian, LagrangesMethod
    y, theta = dynamicsymbols('y theta')
    yd, thetad = dynamicsymbols('y theta', 1)
    m, g, R, l, alpha = symbols('m g R l alpha')
    N = ReferenceFrame('N')
    A = N.orientnew('A', 'Axis', [pi/2 - alpha, N.z])
    B = A.orientnew('B', 'Axis', [-theta, A.z])
    Do = Point('Do')
    Do.set_vel(N, yd * A.x)
    I = m * R**2/2 * B.z | B.z
    D = RigidBody('D', Do, B, m, (I, Do))
    D.potential_energy = m * g * (l - y) * sin(alpha)
    L = Lagrangian(N, D)
    q = [y, theta]
    hol_coneqs = [y - R * theta]
    LM = LagrangesMethod(L, q, hol_coneqs=hol_coneqs)
    start = time.perf_counter()
    LM.form_lagranges_equations()
    return dict(model=LM, eom_seconds=time.perf_counter() - start, hol=hol_coneqs, vel=list(LM.coneqs), q_dep=[theta],
                constants={m: 2.0, g: 9.81, R: 0.3, l: 5.0, alpha: 0.4})

def sleigh_parts():
    """A Chaplygin sleigh whose mass centre C has its own coordinates (x_c, y_c): two configuration constraints
    tie C to the contact point P, one velocity constraint (no sideways slip at P)."""
    from sympy import symbols, cos, sin
    from sympy.physics.mechanics import dynamicsymbols, ReferenceFrame, Point, RigidBody, inertia
    x, y, th, xc, yc = dynamicsymbols('x y theta x_c y_c')
    m, I, a = symbols('m I a')
    N = ReferenceFrame('N')
    B = N.orientnew('B', 'Axis', [th, N.z])
    O = Point('O')
    O.set_vel(N, 0)
    P = O.locatenew('P', x*N.x + y*N.y)
    C = O.locatenew('C', xc*N.x + yc*N.y)
    body = RigidBody('body', C, B, m, (inertia(B, 0, 0, I), C))
    hol = [xc - x - a*cos(th), yc - y - a*sin(th)]
    return locals()


def lagrange_sleigh():
    """LagrangesMethod with hol_coneqs and nonhol_coneqs."""
    from sympy.physics.mechanics import Lagrangian, LagrangesMethod
    v = sleigh_parts()
    N, P, C, O, B, body = v["N"], v["P"], v["C"], v["O"], v["B"], v["body"]
    x, y, th, xc, yc = v["x"], v["y"], v["th"], v["xc"], v["yc"]
    P.set_vel(N, P.pos_from(O).dt(N))
    C.set_vel(N, C.pos_from(O).dt(N))
    L = Lagrangian(N, body)
    LM = LagrangesMethod(L, [x, y, th, xc, yc], hol_coneqs=v["hol"], nonhol_coneqs=[P.vel(N).dot(B.y)], frame=N)
    start = time.perf_counter()
    LM.form_lagranges_equations()
    return dict(model=LM, eom_seconds=time.perf_counter() - start, constants={v["m"]: 2.0, v["I"]: 0.3, v["a"]: 0.4},
                hol=v["hol"], vel=list(LM.coneqs), q_dep=[y, xc, yc])


def system_sleigh():
    """System with q_dep, u_dep, holonomic and nonholonomic constraints (KanesMethod backend)."""
    from sympy.physics.mechanics import System, dynamicsymbols
    v = sleigh_parts()
    N, P, C, O, B, body = v["N"], v["P"], v["C"], v["O"], v["B"], v["body"]
    x, y, th, xc, yc = v["x"], v["y"], v["th"], v["xc"], v["yc"]
    u1, u2, u3, u4, u5 = dynamicsymbols('u1:6')
    P.set_vel(N, u1*N.x + u2*N.y)
    C.set_vel(N, u4*N.x + u5*N.y)
    B.set_ang_vel(N, u3*N.z)
    system = System(N, O)
    system.q_ind = [x, y, th]
    system.q_dep = [xc, yc]
    system.u_ind = [u1, u3]
    system.u_dep = [u2, u4, u5]
    system.kdes = [x.diff() - u1, y.diff() - u2, th.diff() - u3, xc.diff() - u4, yc.diff() - u5]
    system.add_bodies(body)
    system.add_holonomic_constraints(*v["hol"])
    system.add_nonholonomic_constraints(P.vel(N).dot(B.y))
    system.validate_system()
    start = time.perf_counter()
    system.form_eoms()
    return dict(model=system, eom_seconds=time.perf_counter() - start,
                constants={v["m"]: 2.0, v["I"]: 0.3, v["a"]: 0.4}, hol=v["hol"],
                vel=list(system.velocity_constraints), kde=sympy.Matrix(system.kdes), u=[u1, u2, u3, u4, u5])


# --- the model's own equations ---------------------------------------------------------
def _lam(args, expr, constants, cse=False):
    """``lambdify`` of ``expr`` in the lists ``args`` of dynamicsymbols and their derivatives (derivatives
    replaced first by plain symbols, so that ``q'`` is not read as ``d/dt`` of the symbol of ``q``); ``cse``:
    common subexpressions once (large models)."""
    plain = [[sympy.Dummy() for _ in a] for a in args]
    subs = sorted(((s, p) for a, pa in zip(args, plain) for s, p in zip(a, pa)),
                  key=lambda sp: -len(sp[0].atoms(sympy.Derivative)) if isinstance(sp[0], sympy.Derivative) else 0)
    e = sympy.Matrix(expr).xreplace(constants)
    for s, p in subs:
        if isinstance(s, sympy.Derivative):
            e = e.xreplace({s: p})
    e = e.xreplace({s: p for s, p in subs if not isinstance(s, sympy.Derivative)})
    return sympy.lambdify(plain, e, "numpy", cse=cse)


def reference(case, q0, v_ind0):
    """The model's own equations: ``mass_matrix_full x' = forcing_full`` with the dependent speeds solved from
    the velocity constraints at each evaluation, integrated by DOP853 at rtol = atol = 1e-12.

    State ``(q, v_ind)``: Kane/System speeds ``u`` (``v`` = independent ``u``), Lagrange ``qdot``.
    Returns ``(q(t), qdot(t))`` at :data:`T_EVAL`.
    """
    model, c = case["model"], case["constants"]
    t = me.dynamicsymbols._t
    aux = case.get("aux", [])  # sympy's equations hold with the auxiliary speeds (and their rates) at zero
    c = {**c, **dict.fromkeys([a.diff(t) for a in aux] + list(aux), 0)}
    if isinstance(model, me.System):
        model = model.eom_method
    if isinstance(model, me.LagrangesMethod):
        q = list(model.q)
        v = [s.diff(t) for s in q]
        ind = [v[i] for i in range(len(q)) if q[i] not in case.get("q_dep", [q[0]])]
        cons = sympy.Matrix(model.coneqs)
    else:
        q, v = list(model.q), list(model.u)
        ind = list(model._uind) if hasattr(model, "_uind") else v[:len(v) - len(model._udep)]
        cons = model._k_nh * model.u + model._f_nh
    dep = [s for s in v if s not in ind]
    n, w = len(q), len(v)
    if isinstance(model, me.LagrangesMethod):
        qdot_of = lambda qq, vv: vv  # noqa: E731
    else:  # the model's kinematic differential equations, solved for qdot
        kdd = model.kindiffdict()
        qdot_of = _lam([q, v], [kdd[s.diff(t)] for s in q], c)
        qdot_of = (lambda f: lambda qq, vv: np.asarray(f(qq, vv), float).ravel())(qdot_of)
    MM = _lam([q, v], model.mass_matrix_full, c)
    F = _lam([q, v], model.forcing_full, c)
    Ad = _lam([q], cons.jacobian(dep), c)
    rest = _lam([q, ind], cons.xreplace(dict.fromkeys(dep, 0)), c)
    qdot_rows = n  # x' = (q', v', [lambda])
    ii = [v.index(s) for s in ind]
    di = [v.index(s) for s in dep]

    def speeds(qq, vi):
        vv = np.zeros(w)
        vv[ii] = vi
        vv[di] = np.linalg.solve(np.asarray(Ad(qq), float), -np.asarray(rest(qq, vi), float).ravel())
        return vv

    def fun(_, y):
        qq, vi = y[:n], y[n:]
        vv = speeds(qq, vi)
        xd = np.linalg.solve(np.asarray(MM(qq, vv), float), np.asarray(F(qq, vv), float).ravel())
        return np.concatenate([xd[:n], xd[qdot_rows:qdot_rows + w][ii]])

    sol = solve_ivp(fun, (0, T_END), np.concatenate([q0, v_ind0]), method="DOP853", rtol=1e-12, atol=1e-12,
                    t_eval=T_EVAL)
    Q = sol.y[:n].T
    Qd = np.array([fun(0, y)[:n] for y in sol.y.T])
    return Q, Qd, lambda qq, vi: qdot_of(qq, speeds(qq, vi))


def on_constraints(case, q_guess, fixed):
    """``q`` with ``f(q) = 0``: Newton on the coordinates not in ``fixed`` (indices kept at ``q_guess``)."""
    model = case["model"]
    q = list(model.q)
    f = sympy.Matrix(case["hol"]).xreplace(case["constants"])
    free = [i for i in range(len(q)) if i not in fixed]
    F = sympy.lambdify([q], f, "numpy", dummify=True)
    DF = sympy.lambdify([q], f.jacobian([q[i] for i in free]), "numpy", dummify=True)
    x = np.array(q_guess, float)
    for _ in range(50):
        x[free] -= np.linalg.solve(np.asarray(DF(x), float), np.asarray(F(x), float).ravel())
    assert np.max(np.abs(np.asarray(F(x), float))) < 1e-14
    return x


def declared(case):
    """The model's declared constraints as functions of ``(q, qdot)``: values ``f`` and velocity constraints."""
    model, c = case["model"], case["constants"]
    t = me.dynamicsymbols._t
    q = list(model.q)
    qd = [s.diff(t) for s in q]
    vel = sympy.Matrix(case["vel"]).xreplace(dict.fromkeys(case.get("aux", []), 0))
    if case.get("u"):  # speeds in terms of qdot (the kinematic differential equations)
        vel = vel.xreplace(sympy.solve(case["kde"], case["u"]))
    F = _lam([q], case["hol"], c)
    V = _lam([q, qd], vel, c)
    return (lambda Q: np.array([np.asarray(F(x), float).ravel() for x in Q]),
            lambda Q, Qd: np.array([np.asarray(V(x, v), float).ravel() for x, v in zip(Q, Qd)]))


def check_case(case, q0, v_ind0, **run):
    start = time.perf_counter()
    system = liefi.from_mechanics(case["model"], case["constants"])
    build = time.perf_counter() - start
    Q, Qd, speeds = reference(case, q0, v_ind0)
    y0 = system.state(q0, speeds(q0, v_ind0))
    fi = liefi.FeedbackIntegrator(system, y0)
    sol = fi.run(T_END, t_eval=T_EVAL, **run)
    Y = sol.y.T
    Ql, Qdl = Y[:, :len(q0)], system.velocities(Y)
    err = max(np.max(np.abs(Ql - Q)), np.max(np.abs(Qdl - Qd)))
    fval, vel = declared(case)
    h = system.hamiltonian(Y)
    out = dict(build=build, sympy=case["eom_seconds"], error=err, f=np.max(np.abs(fval(Ql))),
               velocity=np.max(np.abs(vel(Ql, Qdl))), energy=np.max(np.abs(h - h[0])) / max(1.0, abs(h[0])))
    return system, out


def assert_case(out):
    assert out["error"] < 1e-8, out
    assert out["f"] < 1e-12, out
    assert out["velocity"] < 1e-12, out
    assert out["energy"] < 1e-12, out


RUN = dict(dt=0.05, scheme="imex-rk8", backend="numpy")  # numpy: no compile in the default suite


@pytest.mark.parametrize("solver", ["LU", "CRAMER", "callable"])
def test_kane_nonminimal_pendulum(solver):
    if solver == "callable":
        solver = lambda A, b: A.LUsolve(b)  # noqa: E731 -- a user's own solver
    case = kane_pendulum(solver)
    q0 = on_constraints(case, [0.3, 0.6], fixed=[0])  # q = (q2, q1): q2 given, q1 from f = 0
    system, out = check_case(case, q0, [0.8], **RUN)
    assert system.holonomic.H == 1 and system.K == 1  # the velocity constraint is df . qdot: one row
    assert_case(out)


def test_lagrange_nonminimal_pendulum():
    case = lagrange_pendulum()
    q0 = on_constraints(case, [0.6, 0.3], fixed=[1])  # q = (q1, q2): q2 given, q1 from f = 0
    system, out = check_case(case, q0, [0.8], **RUN)
    assert system.holonomic.H == 1 and system.K == 1
    assert_case(out)


@pytest.mark.slow
def test_four_bar_linkage():
    case = four_bar()
    q0 = on_constraints(case, [np.pi / 2 + 0.2, np.pi / 2 - 0.2, np.pi / 2 + 0.2], fixed=[0])
    system, out = check_case(case, q0, [0.3], **RUN)
    assert system.holonomic.H == 2 and system.K == 2
    assert_case(out)


@pytest.mark.slow
def test_four_bar_linkage_with_gravity_and_auxiliary_speeds():
    case = four_bar_gravity()
    a = 1.5 * np.pi - 0.3  # hanging, 0.3 from the bottom: far from the collinear (singular) configurations
    q0 = on_constraints(case, [a, np.pi - a, a], fixed=[0])
    system, out = check_case(case, q0, [0.3], **RUN)
    assert system.holonomic.H == 2 and system.K == 2
    assert_case(out)


def test_four_bar_linkage_builds_with_both_loop_constraints():
    """The four-bar as sympy's docs write it builds in one call: two loop-closure values f in V, two rows df (the
    System's velocity constraints, their derivatives, are not counted twice); the field at a start on the
    constraint set is sympy's."""
    case = four_bar()
    system = liefi.from_mechanics(case["model"], case["constants"])
    assert system.holonomic.H == 2 and system.K == 2
    q0 = on_constraints(case, [np.pi / 2 + 0.2, np.pi / 2 - 0.2, np.pi / 2 + 0.2], fixed=[0])
    fi = liefi.FeedbackIntegrator(system, system.state(q0, [0.3, -0.3, 0.3]))
    assert {"f_1", "f_2", "J_1", "J_2"} <= set(fi.invariant_names)
    assert np.max(np.abs(fi.invariant_gradients(fi.y0).residual)) < 1e-13


def test_disc_on_an_incline_plane():
    case = disc_on_incline()
    system, out = check_case(case, np.array([0.3, 1.0]), [0.2], **RUN)  # y = R theta at the start
    assert system.holonomic.H == 1 and system.K == 1
    assert_case(out)


SLEIGH_Q = [0.1, -0.2, 0.3, 0.0, 0.0]  # (x, y, theta, x_c, y_c): x_c, y_c from f = 0


def test_lagrange_sleigh_holonomic_and_nonholonomic():
    case = lagrange_sleigh()
    q0 = on_constraints(case, SLEIGH_Q, fixed=[0, 1, 2])
    system, out = check_case(case, q0, [0.5, 0.4], **RUN)  # (x', theta') independent
    assert system.holonomic.H == 2 and system.K == 3
    assert_case(out)


def test_system_sleigh_holonomic_and_nonholonomic():
    case = system_sleigh()
    q0 = on_constraints(case, SLEIGH_Q, fixed=[0, 1, 2])
    system, out = check_case(case, q0, [0.5, 0.4], **RUN)  # (u1, u3) independent
    assert system.holonomic.H == 2 and system.K == 3
    assert_case(out)



def test_rows_that_are_derivatives_only_somewhere_are_named():
    from liefi.systems._mechanics_constraints import ConstraintRowsError, independent_rows

    df = lambda x: np.stack([2 * x[..., 0], 2 * x[..., 1]], -1)[..., None]  # noqa: E731 -- f = x^2 + y^2 - l^2
    same = lambda x: np.stack([x[..., 0], x[..., 1]], -1)[..., None, :]  # noqa: E731 -- df/2: dropped
    other = lambda x: np.stack([-x[..., 1], x[..., 0]], -1)[..., None, :]  # noqa: E731 -- independent: kept
    pts = np.array([[0.5, 0.2], [-0.3, 0.9], [0.7, -0.4]])
    assert independent_rows(same, df, 2, pts) == []
    assert independent_rows(other, df, 2, pts) == [0]
    mixed = lambda x: np.stack([x[..., 0], x[..., 1] * (x[..., 0] > 0)], -1)[..., None, :]  # noqa: E731
    with pytest.raises(ConstraintRowsError, match="velocity constraint 1 is a combination"):
        independent_rows(mixed, df, 2, pts)


def test_a_free_massless_coordinate_is_named():
    """A coordinate with no mass that no constraint ties to a massive one: the kinetic energy is degenerate on C."""
    from sympy.physics.mechanics import dynamicsymbols, ReferenceFrame, Point, Particle, Lagrangian, LagrangesMethod
    q1, q2, s = dynamicsymbols('q1 q2 s')
    N = ReferenceFrame('N')
    O = Point('O')
    O.set_vel(N, 0)
    P = O.locatenew('P', q1*N.x + q2*N.y)
    P.set_vel(N, P.pos_from(O).dt(N))
    LM = LagrangesMethod(Lagrangian(N, Particle('p', P, 1)), [q1, q2, s], hol_coneqs=[q1**2 + q2**2 - 1], frame=N)
    LM.form_lagranges_equations()
    with pytest.raises(ValueError, match="kinetic energy is zero along velocities that the constraints allow"):
        liefi.from_mechanics(LM)

if __name__ == "__main__":  # the table of the closing note: python tests/test_mechanics_holonomic.py
    rows = [("Kane pendulum (LU)", kane_pendulum, [0.3, 0.6], [0], [0.8]),
            ("Kane pendulum (CRAMER)", lambda: kane_pendulum("CRAMER"), [0.3, 0.6], [0], [0.8]),
            ("Lagrange pendulum", lagrange_pendulum, [0.6, 0.3], [1], [0.8]),
            ("four-bar linkage", four_bar, [np.pi / 2 + 0.2, np.pi / 2 - 0.2, np.pi / 2 + 0.2], [0], [0.3]),
            ("four-bar + gravity, aux speeds", four_bar_gravity,
             [1.5 * np.pi - 0.3, 0.3 - 0.5 * np.pi, 1.5 * np.pi - 0.3], [0], [0.3]),
            ("disc on an incline (sympy's test_lagrange)", disc_on_incline, [0.3, 1.0], [0], [0.2]),
            ("sleigh, Lagrange hol + nonhol", lagrange_sleigh, SLEIGH_Q, [0, 1, 2], [0.5, 0.4]),
            ("sleigh, System hol + nonhol", system_sleigh, SLEIGH_Q, [0, 1, 2], [0.5, 0.4])]
    print("| model | sympy eom s | from_mechanics s | max err vs sympy | max abs f | max vel. constraint | energy drift |")
    print("|---|---|---|---|---|---|---|")
    for name, make, guess, fixed, v in rows:
        case = make()
        _, o = check_case(case, on_constraints(case, guess, fixed), v, **RUN)
        print(f"| {name} | {o['sympy']:.3f} | {o['build']:.2f} | {o['error']:.1e} | {o['f']:.1e} | "
              f"{o['velocity']:.1e} | {o['energy']:.1e} |")


def test_state_from_the_independent_speed_of_a_model_with_a_dependent_coordinate():
    """The dependent speed u1 solves the model's own velocity constraint, which is the
    derivative of its configuration constraint (dropped from the system's rows, kept for this)."""
    case = kane_pendulum()
    system = liefi.from_mechanics(case["model"], case["constants"])
    L = 0.7
    th = 0.4
    assert system.space.shape_names == ("q2", "q1")  # the model's order: q_ind + q_dep
    q1, q2 = L * np.cos(th), L * np.sin(th)  # on the circle
    z = system.state([q2, q1], u=[0.9])  # the independent speed u2 only
    speeds = system.generalized_speeds(z)
    assert list(speeds) == ["u2", "u1"]
    u1, u2 = speeds["u1"], speeds["u2"]
    assert u2 == pytest.approx(0.9, rel=1e-14)
    assert q1 * u1 + q2 * u2 == pytest.approx(0.0, abs=1e-14)  # tangent to the circle
    assert np.abs(system.constraint_momenta(z)).max() < 1e-13


# --- linearization on the constraint set with dependent coordinates (issue 27) ----------------------------
@pytest.mark.parametrize("which", ["kane", "lagrange"])
def test_linearize_nonminimal_pendulum_about_the_hanging_state(which):
    """The tangent space of ``{J = 0, f = 0}`` has the rows ``df``: ``A`` in ``(q2, q2')``, ``+-i sqrt(g/L)``."""
    case = kane_pendulum() if which == "kane" else lagrange_pendulum()
    system = liefi.from_mechanics(case["model"], case["constants"])
    if which == "kane":  # q = (q2, q1), u = (u2, u1); the mass hangs along N.x
        lin = system.linearize([0.0, 0.7], u=[0.0, 0.0])
        assert lin.coordinates == ("q2", "u2")
    else:  # q = (q1, q2): q1 dependent (pivoted QR of df at the state)
        lin = system.linearize([0.7, 0.0], [0.0, 0.0])
        assert lin.coordinates == ("q2", "q2'")
    w = np.sqrt(9.81 / 0.7)
    np.testing.assert_allclose(lin.A, [[0.0, 1.0], [-w ** 2, 0.0]], rtol=0, atol=1e-12 * w ** 2)
    lam = np.sort_complex(lin.nontrivial_eigenvalues)
    np.testing.assert_allclose(lam, [-1j * w, 1j * w], rtol=1e-13)
    with pytest.raises(ValueError, match="off the holonomic constraints"):
        system.linearize([0.0, 0.69], u=[0.0, 0.0]) if which == "kane" else system.linearize([0.69, 0.0], [0.0, 0.0])


def test_state_from_the_independent_speeds_solves_the_derivative_of_f_too():
    """``state(q, u=u_ind)``: the model's independent speeds (``u2``); the dependent ones solve the kept velocity
    constraints and ``f' = df(q) qdot = 0`` (here ``q1 u1 + q2 u2 = 0``), so the state is on the constraint set."""
    case = kane_pendulum()
    system = liefi.from_mechanics(case["model"], case["constants"])
    q0 = on_constraints(case, [0.3, 0.6], fixed=[0])  # q = (q2, q1)
    for u in ([0.8], {"u2": 0.8}):
        speeds = system.generalized_speeds(system.state(q0, u=u))
        assert list(speeds) == ["u2", "u1"]
        assert speeds["u2"] == pytest.approx(0.8, rel=1e-15)
        assert speeds["u1"] == pytest.approx(-q0[0] * 0.8 / q0[1], rel=1e-13)
