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
  constants are Table 1 converted by Moore.

Imported only by tests and benchmarks.  Each builder returns a :class:`Bicycle`
holding the ``KanesMethod`` after ``kanes_equations`` (about a minute of sympy for the
first, more for the second), its symbols, the numeric parameters and the functions of
the state a peer monitors (holonomic constraint, velocity constraints, energy).

The published eigenvalues (Table 2 of the paper) and the weave and capsize speeds are
:data:`BENCHMARK_EIGENVALUES`, :data:`WEAVE_SPEED` and :data:`CAPSIZE_SPEED`.
"""

from dataclasses import dataclass, field
import math

#: Table 1 of Meijaard et al. (2007), SI units, in the paper's own axes (x forward,
#: z down): the values are exact (the paper says "no round-off").
TABLE_1 = {
    "w": 1.02,  # wheel base
    "c": 0.08,  # trail
    "lam": math.pi / 10,  # steer axis tilt (pi/2 - head angle)
    "g": 9.81,
    "rR": 0.3, "mR": 2.0, "IRxx": 0.0603, "IRyy": 0.12,
    "xB": 0.3, "zB": -0.9, "mB": 85.0,
    "IBxx": 9.2, "IByy": 11.0, "IBzz": 2.8, "IBxz": 2.4,
    "xH": 0.9, "zH": -0.7, "mH": 4.0,
    "IHxx": 0.05892, "IHyy": 0.06, "IHzz": 0.00708, "IHxz": -0.00756,
    "rF": 0.35, "mF": 3.0, "IFxx": 0.1405, "IFyy": 0.28,
}

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


@dataclass
class Bicycle:
    """A built bicycle: the ``KanesMethod`` and what a peer needs around it.

    Attributes
    ----------
    kane : sympy.physics.mechanics.KanesMethod
        After ``kanes_equations``.
    q, u : list
        All coordinates and all speeds in the ``KanesMethod``'s order (independent
        first), the order of ``mass_matrix_full`` / ``forcing_full``.
    params : dict
        Numeric values of the model's constants (symbol -> float).
    holonomic : sympy expression
        The configuration constraint (front contact height above the ground, m).
    nonholonomic : list
        The velocity constraints as the model declares them (m/s).
    energy : sympy expression
        Kinetic plus gravitational energy (J).
    lean, steer, lean_rate, steer_rate, yaw, pitch : symbols
        The benchmark's coordinates in this model (sign as the model defines them).
    speed_of : callable
        ``speed_of(v)``: the operating point ``{speed symbol: value}`` of the upright
        straight run at forward speed ``v`` (all other speeds zero).
    pitch0 : float
        The pitch of the upright configuration (solves the holonomic constraint).
    extra : dict
        Model-specific symbols (contact coordinates, ...).
    """

    kane: object
    q: list
    u: list
    params: dict
    holonomic: object
    nonholonomic: list
    energy: object
    lean: object
    steer: object
    lean_rate: object
    steer_rate: object
    yaw: object
    pitch: object
    speed_of: object
    pitch0: float
    extra: dict = field(default_factory=dict)


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


def moore_parameters():
    """Table 1 converted to the frames of Moore (2012) used by PyDy's Carvallo-Whipple example.

    The rear frame ``C`` is the roll frame pitched by the steer axis tilt ``lam`` (``c3``
    along the steer axis, ``z`` down as in the paper), so with ``C1 = cos(lam) B1 - sin(lam) B3``,
    ``C3 = sin(lam) B1 + cos(lam) B3``:

    * ``d1 = cos(lam) (c + w - rR tan(lam))``, ``d3 = -cos(lam) (c - rF tan(lam))``,
      ``d2 = (rR + d1 sin(lam) - rF + d3 sin(lam)) / cos(lam)``;
    * ``(l1, l2)``: the rear body's mass centre from the rear wheel centre,
      ``(xB, zB + rR)`` in the paper's axes, in ``C``; ``(l3, l4)``: the front assembly's
      mass centre from the front wheel centre, ``(xH - w, zH + rF)``, in ``C``;
    * the inertias ``I_C = R^T I R`` with ``R = [C1 C2 C3]`` in the paper's axes.

    These reproduce the constants printed in PyDy's example to the last digit or so.
    Returns a dict of floats keyed by the names ``rf, rr, d1, d2, d3, l1..l4, mc, md, me,
    mf, id11, id22, if11, if22, ic11, ic22, ic33, ic31, ie11, ie22, ie33, ie31, g``.
    """
    T = TABLE_1
    lam = T["lam"]
    cl, sl = math.cos(lam), math.sin(lam)
    d1 = cl * (T["c"] + T["w"] - T["rR"] * math.tan(lam))
    d3 = -cl * (T["c"] - T["rF"] * math.tan(lam))
    d2 = (T["rR"] + d1 * sl - T["rF"] + d3 * sl) / cl

    def in_c(x, z):
        return x * cl - z * sl, x * sl + z * cl

    def inertia_c(ixx, iyy, izz, ixz):
        c11 = cl * cl * ixx - 2 * sl * cl * ixz + sl * sl * izz
        c33 = sl * sl * ixx + 2 * sl * cl * ixz + cl * cl * izz
        c31 = sl * cl * (ixx - izz) + (cl * cl - sl * sl) * ixz
        return c11, iyy, c33, c31

    l1, l2 = in_c(T["xB"], T["zB"] + T["rR"])
    l3, l4 = in_c(T["xH"] - T["w"], T["zH"] + T["rF"])
    ic11, ic22, ic33, ic31 = inertia_c(T["IBxx"], T["IByy"], T["IBzz"], T["IBxz"])
    ie11, ie22, ie33, ie31 = inertia_c(T["IHxx"], T["IHyy"], T["IHzz"], T["IHxz"])
    return {"rf": T["rF"], "rr": T["rR"], "d1": d1, "d2": d2, "d3": d3,
            "l1": l1, "l2": l2, "l3": l3, "l4": l4,
            "mc": T["mB"], "md": T["mR"], "me": T["mH"], "mf": T["mF"],
            "id11": T["IRxx"], "id22": T["IRyy"], "if11": T["IFxx"], "if22": T["IFyy"],
            "ic11": ic11, "ic22": ic22, "ic33": ic33, "ic31": ic31,
            "ie11": ie11, "ie22": ie22, "ie33": ie33, "ie31": ie31, "g": T["g"]}


def whipple_contact_coordinates():
    """The Whipple bicycle written with the contact points' coordinates (Moore 2012 frames).

    Coordinates ``q1, q2`` (rear contact on the ground, along ``N1``, ``N2``), ``q3`` yaw,
    ``q4`` roll (lean), ``q5`` pitch (dependent), ``q6`` rear wheel angle, ``q7`` steer,
    ``q8`` front wheel angle; every speed ``u_i = q_i'``.  ``z`` points down.

    Constraints as a Kane user declares them:

    * holonomic: the front contact's height above the ground,
      ``f(q4, q5, q7) = r_{fn/dn} . A3 = 0``, pitch ``q5`` dependent;
    * rolling of the rear wheel: the velocity of the wheel's material point at the
      contact, along ``N1`` and ``N2`` (2 rows); rolling of the front wheel: the velocity
      of its material point at the contact along ``A3``, ``A2``, ``A1`` (3 rows; the
      ``A3`` row is ``f'``).  Dependent speeds ``u1, u2, u5, u3, u8`` in that order, so
      that sympy's LU solve pivots on entries that do not vanish on the upright run
      (``u3``'s coefficient along ``A1`` is proportional to the steer angle: PyDy's example
      pivots on it and divides by zero at zero steer).

    Returns
    -------
    Bicycle
    """
    sympy, me = _sympy()
    q1, q2, q3, q4, q5, q6, q7, q8 = me.dynamicsymbols('q1:9')
    u1, u2, u3, u4, u5, u6, u7, u8 = me.dynamicsymbols('u1:9')
    t = me.dynamicsymbols._t
    rf, rr, d1, d2, d3 = sympy.symbols('rf rr d1 d2 d3')
    l1, l2, l3, l4, g = sympy.symbols('l1 l2 l3 l4 g')
    mc, md, me_, mf = sympy.symbols('mc md me mf')
    ic11, ic22, ic33, ic31 = sympy.symbols('ic11 ic22 ic33 ic31')
    id11, id22 = sympy.symbols('id11 id22')
    ie11, ie22, ie33, ie31 = sympy.symbols('ie11 ie22 ie33 ie31')
    if11, if22 = sympy.symbols('if11 if22')

    N, A, B, C, D, E, F = (me.ReferenceFrame(n) for n in "NABCDEF")
    A.orient(N, 'Axis', (q3, N.z))
    B.orient(A, 'Axis', (q4, A.x))
    C.orient(B, 'Axis', (q5, B.y))
    E.orient(C, 'Axis', (q7, C.z))
    D.orient(C, 'Axis', (q6, C.y))
    F.orient(E, 'Axis', (q8, E.y))
    A.set_ang_vel(N, u3 * N.z)
    B.set_ang_vel(A, u4 * A.x)
    C.set_ang_vel(B, u5 * B.y)
    D.set_ang_vel(C, u6 * C.y)
    E.set_ang_vel(C, u7 * C.z)
    F.set_ang_vel(E, u8 * E.y)

    O = me.Point('O')
    O.set_vel(N, 0)
    dn = O.locatenew('dn', q1 * N.x + q2 * N.y)  # rear contact (geometric point)
    dn.set_vel(N, u1 * N.x + u2 * N.y)
    do = dn.locatenew('do', -rr * B.z)  # rear wheel centre
    do.set_vel(B, 0)
    do.v1pt_theory(dn, N, B)
    co = do.locatenew('co', l1 * C.x + l2 * C.z)
    ce = do.locatenew('ce', d1 * C.x)
    fo = ce.locatenew('fo', d2 * E.z + d3 * E.x)
    eo = fo.locatenew('eo', l3 * E.x + l4 * E.z)
    fn = fo.locatenew('fn', rf * E.y.cross(A.z).cross(E.y).normalize())
    dw = do.locatenew('dw', rr * B.z)  # the rear wheel's material point at the contact
    co.v2pt_theory(do, N, C)
    ce.v2pt_theory(do, N, C)
    fo.v2pt_theory(ce, N, E)
    eo.v2pt_theory(fo, N, E)
    fn.v2pt_theory(fo, N, F)
    dw.v2pt_theory(do, N, D)

    holonomic = fn.pos_from(dn).dot(A.z)
    nonholonomic = [dw.vel(N).dot(N.x), dw.vel(N).dot(N.y),
                    fn.vel(N).dot(A.z), fn.vel(N).dot(A.y), fn.vel(N).dot(A.x)]
    kd = [qi.diff(t) - ui for qi, ui in zip([q1, q2, q3, q4, q5, q6, q7, q8],
                                             [u1, u2, u3, u4, u5, u6, u7, u8])]

    bodies = [me.RigidBody('rear frame', co, C, mc, (me.inertia(C, ic11, ic22, ic33, 0, 0, ic31), co)),
              me.RigidBody('rear wheel', do, D, md, (me.inertia(C, id11, id22, id11), do)),
              me.RigidBody('front frame', eo, E, me_, (me.inertia(E, ie11, ie22, ie33, 0, 0, ie31), eo)),
              me.RigidBody('front wheel', fo, F, mf, (me.inertia(E, if11, if22, if11), fo))]
    loads = [(co, mc * g * A.z), (do, md * g * A.z), (eo, me_ * g * A.z), (fo, mf * g * A.z)]

    kane = me.KanesMethod(N, q_ind=[q1, q2, q3, q4, q6, q7, q8], u_ind=[u4, u6, u7], kd_eqs=kd,
                          q_dependent=[q5], configuration_constraints=[holonomic],
                          u_dependent=[u1, u2, u5, u3, u8], velocity_constraints=nonholonomic)
    kane.kanes_equations(bodies, loads)

    values = moore_parameters()
    names = {"rf": rf, "rr": rr, "d1": d1, "d2": d2, "d3": d3, "l1": l1, "l2": l2, "l3": l3, "l4": l4,
             "mc": mc, "md": md, "me": me_, "mf": mf, "id11": id11, "id22": id22, "if11": if11,
             "if22": if22, "ic11": ic11, "ic22": ic22, "ic33": ic33, "ic31": ic31, "ie11": ie11,
             "ie22": ie22, "ie33": ie33, "ie31": ie31, "g": g}
    params = {names[k]: float(v) for k, v in values.items()}

    ke = sum(b.kinetic_energy(N) for b in bodies)
    pe = sum(-force.dot(N.z) * P.pos_from(O).dot(N.z) for P, force in loads)
    # The upright pitch solves f(0, q5, 0) = 0 (it is the steer axis tilt up to rounding).
    f0 = sympy.lambdify(q5, holonomic.subs({q4: 0, q7: 0}).xreplace(params), "math")
    from scipy.optimize import brentq
    pitch0 = brentq(f0, 0.0, 1.0, xtol=1e-16, rtol=1e-15)
    return Bicycle(
        kane=kane, q=list(kane.q), u=list(kane.u), params=params,
        holonomic=holonomic, nonholonomic=nonholonomic, energy=ke + pe,
        lean=q4, steer=q7, lean_rate=u4, steer_rate=u7, yaw=q3, pitch=q5,
        speed_of=lambda v: {u1: v, u6: -v / values["rr"], u8: -v / values["rf"]},
        pitch0=pitch0,
        extra={"rear_contact": (q1, q2), "frames": {"N": N, "A": A},
               "points": {"rear_contact": dn, "front_contact": fn}},
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
