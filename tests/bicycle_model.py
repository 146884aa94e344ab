"""The Whipple bicycle as Kane users write it (test and benchmark helper; sympy optional).

Two builders, both with the benchmark parameters of Meijaard, Papadopoulos, Ruina &
Schwab, "Linearized dynamics equations for the balance and steer of a bicycle: a
benchmark and review", Proc. R. Soc. A 463 (2007) 1955-1982, Table 1:

* :func:`whipple_sympy_test` -- the model of sympy's own test
  ``sympy/physics/mechanics/tests/test_kane3.py::test_bicycle`` (github.com/sympy/sympy),
  line for line: minimal speeds for the rear contact (its velocity set to zero, no
  contact coordinates), the pitch ``q4`` dependent through one configuration
  constraint, three velocity constraints (the front contact's velocity in the yaw
  frame), ``constraint_solver="CRAMER"``; and sympy's conversion of Table 1 to that
  model's parameters.
* :func:`whipple_contact_coordinates` -- the same bicycle written by a Kane user *with*
  the contact points' coordinates: the rear contact ``(x, y)`` in ``q``, every speed
  ``u = q'``, the rolling of both wheels as five velocity constraints with dependent
  speeds, and the front contact's height as a configuration constraint with the pitch
  dependent.  Frames, points and parameters after PyDy's Carvallo-Whipple example
  (github.com/pydy/pydy, ``docs/examples/carvallo-whipple.rst``; Moore 2012), whose
  constants are Table 1 converted by Moore.  It is the model of the scene ``bicycle`` and lives
  with it, in ``liefi/scenes/bicycle.py``; this module re-exports it.

Imported only by tests and benchmarks.  Each builder returns a :class:`Bicycle`
holding the ``KanesMethod`` after ``kanes_equations`` (about a minute of sympy for the
first, more for the second), its symbols, the numeric parameters and the functions of
the state a peer monitors (holonomic constraint, velocity constraints, energy).

The published eigenvalues (Table 2 of the paper) and the weave and capsize speeds are
:data:`BENCHMARK_EIGENVALUES`, :data:`WEAVE_SPEED` and :data:`CAPSIZE_SPEED`.
"""

# The bicycle as the scene builds it (liefi.scenes.bicycle: the model's one home): Table 1, the conversion to
# Moore's frames, the contact-coordinates model and the Bicycle record.  sympy's test model stays here, as
# sympy's test writes it: a second, independent user's model of the same bicycle.
from liefi.scenes.bicycle import TABLE_1, Bicycle, moore_parameters, whipple_contact_coordinates  # noqa: F401

#: Table 2 of Meijaard et al. (2007): eigenvalues of the benchmark bicycle, by speed (m/s).
BENCHMARK_EIGENVALUES = {
    0.0: [3.13164324790656, -3.13164324790656, 5.53094371765393, -5.53094371765393],
    4.0: [-12.15861426576447, -1.42944427361326,
          0.41325331521125 + 3.07910818603206j, 0.41325331521125 - 3.07910818603206j],
    5.0: [-14.07838969279822, -0.32286642900409,
          -0.77534188219585 + 4.46486771378823j, -0.77534188219585 - 4.46486771378823j],
    10.0: [-24.62459635017404, 0.16105338653172,
           -3.72016840437287 + 10.90681139476287j, -3.72016840437287 - 10.90681139476287j],
}
#: The speed where the weave pair crosses the imaginary axis (m/s).
WEAVE_SPEED = 4.29238253634111
#: The speed where the capsize eigenvalue crosses zero (m/s).
CAPSIZE_SPEED = 6.02426201538837


def _sympy():
    try:
        import sympy
        import sympy.physics.mechanics as me
    except ImportError as exc:  # pragma: no cover - sympy is installed with the test extras
        raise ImportError("bicycle_model: sympy is needed to build the bicycle; pip install sympy") from exc
    return sympy, me


def whipple_sympy_test():
    """The Whipple bicycle as ``sympy/physics/mechanics/tests/test_kane3.py`` builds it.

    Coordinates: yaw ``q1``, roll (lean) ``q2``, pitch ``q4`` (dependent), steer ``q5``;
    speeds ``u1..u6`` with ``u2`` (lean rate), ``u3`` (rear wheel rate), ``u5`` (steer
    rate) independent and ``u1`` (yaw rate), ``u4`` (pitch rate), ``u6`` (front wheel
    rate) dependent.  The rear contact has zero velocity (minimal speeds: no contact
    coordinates).  In this model the frame's pitch is measured from the steer axis
    (``Frame`` is turned by ``q4 + htangle``), so the upright pitch is ``q4 = 0``.

    Returns
    -------
    Bicycle
    """
    sympy, me = _sympy()
    from sympy import pi, sin, cos, acos, sqrt, symbols
    from sympy.physics.mechanics import (ReferenceFrame, dynamicsymbols, KanesMethod, inertia,
                                         Point, RigidBody, dot)

    # --- as test_kane3.py writes it (ported from Autolev there) ---
    q1, q2, q4, q5 = dynamicsymbols('q1 q2 q4 q5')
    q1d, q2d, q4d, q5d = dynamicsymbols('q1 q2 q4 q5', 1)
    u1, u2, u3, u4, u5, u6 = dynamicsymbols('u1 u2 u3 u4 u5 u6')

    WFrad, WRrad, htangle, forkoffset = symbols('WFrad WRrad htangle forkoffset')
    forklength, framelength, forkcg1 = symbols('forklength framelength forkcg1')
    forkcg3, framecg1, framecg3, Iwr11 = symbols('forkcg3 framecg1 framecg3 Iwr11')
    Iwr22, Iwf11, Iwf22, Iframe11 = symbols('Iwr22 Iwf11 Iwf22 Iframe11')
    Iframe22, Iframe33, Iframe31, Ifork11 = symbols('Iframe22 Iframe33 Iframe31 Ifork11')
    Ifork22, Ifork33, Ifork31, g = symbols('Ifork22 Ifork33 Ifork31 g')
    mframe, mfork, mwf, mwr = symbols('mframe mfork mwf mwr')

    N = ReferenceFrame('N')
    Y = N.orientnew('Y', 'Axis', [q1, N.z])
    R = Y.orientnew('R', 'Axis', [q2, Y.x])
    Frame = R.orientnew('Frame', 'Axis', [q4 + htangle, R.y])
    WR = ReferenceFrame('WR')
    TempFrame = Frame.orientnew('TempFrame', 'Axis', [-htangle, Frame.y])
    Fork = Frame.orientnew('Fork', 'Axis', [q5, Frame.x])
    TempFork = Fork.orientnew('TempFork', 'Axis', [-htangle, Fork.y])
    WF = ReferenceFrame('WF')

    WR_cont = Point('WR_cont')
    WR_mc = WR_cont.locatenew('WR_mc', WRrad * R.z)
    Steer = WR_mc.locatenew('Steer', framelength * Frame.z)
    Frame_mc = WR_mc.locatenew('Frame_mc', - framecg1 * Frame.x + framecg3 * Frame.z)
    Fork_mc = Steer.locatenew('Fork_mc', - forkcg1 * Fork.x + forkcg3 * Fork.z)
    WF_mc = Steer.locatenew('WF_mc', forklength * Fork.x + forkoffset * Fork.z)
    WF_cont = WF_mc.locatenew('WF_cont', WFrad * (dot(Fork.y, Y.z) * Fork.y - Y.z).normalize())

    Y.set_ang_vel(N, u1 * Y.z)
    R.set_ang_vel(Y, u2 * R.x)
    WR.set_ang_vel(Frame, u3 * Frame.y)
    Frame.set_ang_vel(R, u4 * Frame.y)
    Fork.set_ang_vel(Frame, u5 * Fork.x)
    WF.set_ang_vel(Fork, u6 * Fork.y)

    WR_cont.set_vel(N, 0)
    WR_mc.v2pt_theory(WR_cont, N, WR)
    Steer.v2pt_theory(WR_mc, N, Frame)
    Frame_mc.v2pt_theory(WR_mc, N, Frame)
    Fork_mc.v2pt_theory(Steer, N, Fork)
    WF_mc.v2pt_theory(Steer, N, Fork)
    WF_cont.v2pt_theory(WF_mc, N, WF)

    Frame_I = (inertia(TempFrame, Iframe11, Iframe22, Iframe33, 0, 0, Iframe31), Frame_mc)
    Fork_I = (inertia(TempFork, Ifork11, Ifork22, Ifork33, 0, 0, Ifork31), Fork_mc)
    WR_I = (inertia(Frame, Iwr11, Iwr22, Iwr11), WR_mc)
    WF_I = (inertia(Fork, Iwf11, Iwf22, Iwf11), WF_mc)

    BodyFrame = RigidBody('BodyFrame', Frame_mc, Frame, mframe, Frame_I)
    BodyFork = RigidBody('BodyFork', Fork_mc, Fork, mfork, Fork_I)
    BodyWR = RigidBody('BodyWR', WR_mc, WR, mwr, WR_I)
    BodyWF = RigidBody('BodyWF', WF_mc, WF, mwf, WF_I)

    kd = [q1d - u1, q2d - u2, q4d - u4, q5d - u5]
    conlist_speed = [WF_cont.vel(N) & Y.x, WF_cont.vel(N) & Y.y, WF_cont.vel(N) & Y.z]
    conlist_coord = [WF_cont.pos_from(WR_cont) & Y.z]

    FL = [(Frame_mc, -mframe * g * Y.z),
          (Fork_mc, -mfork * g * Y.z),
          (WF_mc, -mwf * g * Y.z),
          (WR_mc, -mwr * g * Y.z)]
    BL = [BodyFrame, BodyFork, BodyWR, BodyWF]

    KM = KanesMethod(N, q_ind=[q1, q2, q5],
                     q_dependent=[q4], configuration_constraints=conlist_coord,
                     u_ind=[u2, u3, u5],
                     u_dependent=[u1, u4, u6], velocity_constraints=conlist_speed,
                     kd_eqs=kd,
                     constraint_solver="CRAMER")
    KM.kanes_equations(BL, FL)

    # --- sympy's conversion of Table 1 to this model's parameters (test_kane3.py) ---
    T = TABLE_1
    PaperRadRear = T["rR"]
    PaperRadFront = T["rF"]
    HTA = (pi / 2 - pi / 10).evalf()
    TrailPaper = T["c"]
    rake = (-(TrailPaper * sin(HTA) - (PaperRadFront * cos(HTA)))).evalf()
    PaperWb = T["w"]
    PaperFrameCgX = T["xB"]
    PaperFrameCgZ = -T["zB"]
    PaperForkCgX = T["xH"]
    PaperForkCgZ = -T["zH"]
    FrameLength = (PaperWb * sin(HTA) - (rake - (PaperRadFront - PaperRadRear) * cos(HTA))).evalf()
    FrameCGNorm = ((PaperFrameCgZ - PaperRadRear - (PaperFrameCgX / sin(HTA)) * cos(HTA)) * sin(HTA)).evalf()
    FrameCGPar = (PaperFrameCgX / sin(HTA) + (PaperFrameCgZ - PaperRadRear - PaperFrameCgX / sin(HTA) * cos(HTA))
                  * cos(HTA)).evalf()
    tempa = (PaperForkCgZ - PaperRadFront)
    tempb = (PaperWb - PaperForkCgX)
    tempc = (sqrt(tempa ** 2 + tempb ** 2)).evalf()
    PaperForkL = (PaperWb * cos(HTA) - (PaperRadFront - PaperRadRear) * sin(HTA)).evalf()
    ForkCGNorm = (rake + (tempc * sin(pi / 2 - HTA - acos(tempa / tempc)))).evalf()
    ForkCGPar = (tempc * cos((pi / 2 - HTA) - acos(tempa / tempc)) - PaperForkL).evalf()
    # The products of inertia change sign (the paper's z points down), as in sympy's test.
    params = {WFrad: PaperRadFront, WRrad: PaperRadRear, htangle: HTA, forkoffset: rake,
              forklength: PaperForkL, framelength: FrameLength, forkcg1: ForkCGPar,
              forkcg3: ForkCGNorm, framecg1: FrameCGNorm, framecg3: FrameCGPar,
              Iwr11: T["IRxx"], Iwr22: T["IRyy"], Iwf11: T["IFxx"], Iwf22: T["IFyy"],
              Ifork11: T["IHxx"], Ifork22: T["IHyy"], Ifork33: T["IHzz"], Ifork31: -T["IHxz"],
              Iframe11: T["IBxx"], Iframe22: T["IByy"], Iframe33: T["IBzz"], Iframe31: -T["IBxz"],
              mfork: T["mH"], mframe: T["mB"], mwf: T["mF"], mwr: T["mR"], g: T["g"]}
    params = {k: float(v) for k, v in params.items()}

    ke = sum(b.kinetic_energy(N) for b in BL)
    pe = sum(-(force & Y.z) * (P.pos_from(WR_cont) & Y.z) for P, force in FL)
    return Bicycle(
        kane=KM, q=list(KM.q), u=list(KM.u), params=params,
        holonomic=conlist_coord[0], nonholonomic=conlist_speed, energy=ke + pe,
        lean=q2, steer=q5, lean_rate=u2, steer_rate=u5, yaw=q1, pitch=q4,
        speed_of=lambda v: {u3: v / PaperRadRear, u6: v / PaperRadFront},
        pitch0=0.0,
        extra={"frames": {"N": N, "Y": Y}, "points": {"rear_contact": WR_cont, "front_contact": WF_cont}},
    )


def lateral_matrix(bike):
    """The linearized lean-and-steer dynamics ``x' = A(v) x``, ``x = (lean, steer, lean rate, steer rate)``.

    Linearizes ``bike.kane`` with ``KanesMethod.linearize(A_and_B=True,
    linear_solver="CRAMER")`` about the upright straight run at a symbolic forward speed
    ``v`` (all coordinates zero except the pitch at ``bike.pitch0``, the speeds of
    ``bike.speed_of(v)``, all accelerations zero), substitutes the parameters, and keeps
    the rows and columns of lean, steer and their rates, as sympy's test does (the other
    states -- yaw, contact position, wheel angles, rear wheel rate -- do not feed back
    into them at first order).  About three CPU minutes for :func:`whipple_sympy_test`;
    for :func:`whipple_contact_coordinates` sympy's linearizer did not finish in 14 CPU
    minutes, use :func:`complex_step_lateral` there.

    Returns
    -------
    callable
        ``A(v) -> ndarray (4, 4)``.
    """
    import numpy as np
    sympy, me = _sympy()
    v = sympy.Symbol('v')
    op = {s.diff(): 0 for s in bike.u}
    op.update({s: 0 for s in bike.q})
    op[bike.pitch] = bike.pitch0
    op.update({s: 0 for s in bike.u})
    op.update(bike.speed_of(v))
    q_ind = list(bike.kane.q[:len(bike.kane.q) - len(bike.kane._qdep)])
    u_ind = list(bike.kane.u[:len(bike.kane.u) - len(bike.kane._udep)])
    x_ind = q_ind + u_ind
    cols = [x_ind.index(s) for s in (bike.lean, bike.steer, bike.lean_rate, bike.steer_rate)]
    A, _, _ = bike.kane.linearize(A_and_B=True, op_point=op, linear_solver="CRAMER")
    A4 = A.xreplace(bike.params).evalf().extract(cols, cols)
    f = sympy.lambdify(v, A4, "numpy")
    return lambda vv: np.array(f(vv), dtype=float)


def eigenvalues(A):
    """The eigenvalues of ``A`` sorted by real part, then imaginary part."""
    import numpy as np
    w = np.linalg.eigvals(A)
    return w[np.lexsort((w.imag, w.real))]


def weave_and_capsize_speeds(lateral, weave_bracket=(3.0, 5.0), capsize_bracket=(5.5, 8.0)):
    """The weave and capsize speeds of ``lateral(v) -> A`` by root finding (Brent, ``xtol`` 1e-15).

    The weave speed is where the real part of the oscillatory pair (the eigenvalue with
    the largest imaginary part) crosses zero; the capsize speed is where the largest real
    eigenvalue (imaginary part zero) crosses zero.
    """
    import numpy as np
    from scipy.optimize import brentq

    def weave(v):
        w = np.linalg.eigvals(lateral(v))
        return w[np.argmax(w.imag)].real

    def capsize(v):
        w = np.linalg.eigvals(lateral(v))
        real = w[np.abs(w.imag) < 1e-12 * max(1.0, np.abs(w).max())].real
        return real.max()

    kw = dict(xtol=1e-15, rtol=1e-15, maxiter=200)
    return brentq(weave, *weave_bracket, **kw), brentq(capsize, *capsize_bracket, **kw)


def complex_step_lateral(bike):
    """``A(v)`` of :func:`lateral_matrix` from the generated numerics, by complex-step differentiation.

    An independent check of the nonlinear right-hand side a peer integrates: the rates
    ``x' = M(x)^{-1} F(x)`` (``mass_matrix_full``, ``forcing_full``, ``sympy.lambdify``),
    restricted to the constraint set through the independent coordinates and speeds
    ``y = (q_ind, u_ind)``: the dependent coordinate solves ``f(q) = 0`` (Newton) and the
    dependent speeds the velocity constraints (linear in them).  Then
    ``dy'/dy_j = Im y'(y0 + i h e_j) / h`` with ``h = 1e-30``, exact to rounding (no
    difference is taken).
    """
    import numpy as np
    sympy, me = _sympy()
    kane = bike.kane
    q, u = list(kane.q), list(kane.u)
    qd, ud = list(kane._qdep), list(kane._udep)
    qi, ui = q[:len(q) - len(qd)], u[:len(u) - len(ud)]
    p = bike.params
    args = q + u
    fM = sympy.lambdify(args, kane.mass_matrix_full.xreplace(p), "numpy", cse=True)
    fF = sympy.lambdify(args, kane.forcing_full.xreplace(p), "numpy", cse=True)
    hol = sympy.Matrix([bike.holonomic]).xreplace(p)
    fh = sympy.lambdify(args, hol, "numpy", cse=True)
    fhj = sympy.lambdify(args, hol.jacobian(qd), "numpy", cse=True)
    con = sympy.Matrix(bike.nonholonomic).xreplace(p)
    fc = sympy.lambdify(args, con, "numpy", cse=True)
    fcj = sympy.lambdify(args, con.jacobian(ud), "numpy", cse=True)
    iq = [q.index(s) for s in qd]
    iu = [len(q) + u.index(s) for s in ud]
    ind = [q.index(s) for s in qi] + [len(q) + u.index(s) for s in ui]
    lat = [(qi + ui).index(s) for s in (bike.lean, bike.steer, bike.lean_rate, bike.steer_rate)]

    def full(y, x_guess):
        x = np.array(x_guess, dtype=complex)
        x[ind] = y
        for _ in range(8):  # Newton on f(q) = 0 (complex arithmetic carries the derivative)
            x[iq] -= np.linalg.solve(np.asarray(fhj(*x), dtype=complex), np.asarray(fh(*x), dtype=complex).ravel())
        for _ in range(2):  # the constraints are linear in the dependent speeds
            x[iu] -= np.linalg.solve(np.asarray(fcj(*x), dtype=complex), np.asarray(fc(*x), dtype=complex).ravel())
        return x

    def rates(y, x_guess):
        x = full(y, x_guess)
        xd = np.linalg.solve(np.asarray(fM(*x), dtype=complex), np.asarray(fF(*x), dtype=complex).ravel())
        return xd[ind]

    def lateral(v, h=1e-30):
        x0 = np.zeros(len(args))
        x0[q.index(bike.pitch)] = bike.pitch0
        for s, val in bike.speed_of(v).items():
            x0[len(q) + u.index(s)] = val
        x0 = full(x0[ind], x0).real
        y0 = x0[ind].astype(complex)
        J = np.empty((len(ind), len(ind)))
        for j in range(len(ind)):
            y = y0.copy()
            y[j] += 1j * h
            J[:, j] = rates(y, x0).imag / h
        return J[np.ix_(lat, lat)]
    return lateral
