r"""The benchmark bicycle: the Whipple bicycle of Meijaard, Papadopoulos, Ruina & Schwab, uncontrolled.

The bicycle of "Linearized dynamics equations for the balance and steer of a bicycle: a
benchmark and review", Proc. R. Soc. A 463 (2007) 1955-1982, with the parameters of its
Table 1, built the way a sympy user builds it: a ``KanesMethod`` written with
``sympy.physics.mechanics`` (:func:`whipple_contact_coordinates`), taken by
:func:`liefi.from_mechanics` in one call.  Four rigid bodies (rear frame with rider, front
fork and handlebar, two knife-edge wheels) roll without slipping on level ground:

* eight coordinates, the rear contact ``(q1, q2)``, yaw ``q3``, lean (roll) ``q4``, pitch
  ``q5``, rear wheel angle ``q6``, steer ``q7``, front wheel angle ``q8``;
* one holonomic constraint, the front contact's height ``f(q4, q5, q7) = 0`` (the pitch is
  dependent), and the rolling of both wheels, five velocity constraints (one of them is
  ``f'``, which ``from_mechanics`` recognises and drops).

The variants are runs of the *uncontrolled* bicycle from the upright straight run at forward
speed ``v`` with a lean-rate kick (the rear wheel turning at ``-v / rR``, the steer rate zero,
the dependent speeds solving the constraints):

* ``self-stable``: 5 m/s, 0.5 rad/s, inside the self-stable range (the weave speed 4.292 m/s to
  the capsize speed 6.024 m/s): the lean decays (the slowest eigenvalue is -0.323 /s);
* ``weave``: 3 m/s, 1e-8 rad/s, below the weave speed: the weave oscillation grows (its
  eigenvalues at 3 m/s are 1.707 +- 2.316 i /s, ``system.linearize``, a factor 2.6e7 in 10 s); from
  this small kick the lean at t = 10 s has grown a million times (to about 0.05 rad) and the
  bicycle has not fallen (from 0.1 rad/s it falls at t = 5.2 s, from 0.5 rad/s at t = 3 s);
* ``capsize``: 8 m/s, 0.05 rad/s, above the capsize speed: the capsize mode grows slowly
  (eigenvalue 0.143 /s), the IFToMM manoeuvre M3;
* ``iftomm``: 4.6 m/s, 0.5 rad/s: the "uncontrolled bicycle" manoeuvre M2 of the IFToMM
  multibody benchmark library (also PyDy's Carvallo-Whipple example's run).

What ``V`` penalizes: the constraint momenta ``J_1 .. J_5`` (the four rolling rows and liefi's own
``f' = df B(q) u``), the front contact's height ``f_1`` and the energy.
The reference is numerical: DOP853 on liefi's constrained field at 1e-12 (no closed form).

Cost: sympy's ``kanes_equations`` (about 7 CPU s) and ``from_mechanics`` (about 5 CPU s) when
the scene's system is first used, then the tracing and, on the compiled backend, a compile of
minutes the first time (the kernel cache keeps it).  The scene is not one of the paper's
experiments (``in_paper = False``): ``liefi reproduce`` runs it only with ``--all`` or
``--only bicycle``.

Needs sympy (``pip install sympy``); importing this module does not import it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..results import scene_figures as plotting
from .base import Scene, Variant

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


def _sympy():
    try:
        import sympy
        import sympy.physics.mechanics as me
    except ImportError as exc:  # pragma: no cover - sympy is a dependency of from_mechanics
        raise ImportError("bicycle: sympy is needed to build the bicycle; pip install sympy") from exc
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
        extra={"rear_contact": (q1, q2), "frames": {"N": N, "A": A}, "origin": O,
               "points": {"rear_contact": dn, "front_contact": fn}},
    )




def upright(bike, system, v):
    """``(q, u)`` of the upright straight run at forward speed ``v``, in ``system``'s order.

    Every coordinate zero but the pitch, which solves the holonomic constraint ``f = 0`` of the
    built ``system`` (Brent, to rounding); the speeds of ``bike.speed_of(v)`` (the wheels turning
    at ``v / r``), all others zero.  ``bike`` is a :class:`Bicycle`, ``system`` its
    :func:`liefi.from_mechanics` system.
    """
    from scipy.optimize import brentq

    names = [str(s) for s in system.space.shape_names]
    k = names.index(str(bike.pitch.func))

    def f(pitch):
        q = np.zeros(len(names))
        q[k] = pitch
        return float(np.asarray(system.holonomic.values(q)).ravel()[0])

    q = np.zeros(len(names))
    q[k] = brentq(f, 0.0, 1.0, xtol=1e-16, rtol=1e-15)
    speeds = [str(s.func) for s in system.speeds]
    u = np.zeros(len(speeds))
    for s, value in bike.speed_of(v).items():
        u[speeds.index(str(s.func))] = value
    return q, u


def kicked_start(bike, system, v, lean_rate):
    """The state of the upright run at ``v`` (:func:`upright`) with the lean rate ``lean_rate`` (rad/s).

    The independent speeds are given (lean rate, rear wheel rate ``-v / rR``, steer rate 0); the
    dependent ones solve the velocity constraints (``system.state``), so the start is on the
    constraint set.
    """
    q, u = upright(bike, system, v)
    speeds = [str(s.func) for s in system.speeds]
    independent = [str(s.func) for s in bike.kane.u[:len(bike.kane.u) - len(bike.kane._udep)]]
    given = {n: float(u[speeds.index(n)]) for n in independent}
    given[str(bike.lean_rate.func)] = float(lean_rate)
    return system.state(q, u=given)


def contact_paths(bike, system, y, names):
    """``{"rear": (x, y), "front": (x, y)}``: both wheels' contact points on the ground along a run.

    ``y`` (rows named ``names``) holds the coordinates; the front contact is the model's own point
    ``fn`` (``sympy.lambdify`` of its position from the ground's origin), the rear contact the
    coordinates ``(q1, q2)``.
    """
    sympy, _ = _sympy()
    N = bike.extra["frames"]["N"]
    origin = bike.extra["origin"]
    fn = bike.extra["points"]["front_contact"].pos_from(origin)
    q = list(bike.q)
    fun = sympy.lambdify(q, sympy.Matrix([fn.dot(N.x), fn.dot(N.y)]).xreplace(bike.params), "numpy", cse=True)
    Q = [np.asarray(y[list(names).index(str(s.func))], float) for s in q]
    front = np.asarray(fun(*Q), float).reshape(2, -1)
    x, yy = bike.extra["rear_contact"]
    return {"rear": (Q[q.index(x)], Q[q.index(yy)]), "front": (front[0], front[1])}


#: variant -> (forward speed m/s, lean rate rad/s, description)
RUNS = {
    "self-stable": (5.0, 0.5, "5 m/s, lean rate 0.5 rad/s: inside the self-stable range, the lean decays"),
    "weave": (3.0, 1e-8, "3 m/s, lean rate 1e-8 rad/s: below the weave speed, the weave grows"),
    "capsize": (8.0, 0.05, "8 m/s, lean rate 0.05 rad/s: above the capsize speed, the slow capsize (IFToMM M3)"),
    "iftomm": (4.6, 0.5, "4.6 m/s, lean rate 0.5 rad/s: the IFToMM uncontrolled-bicycle manoeuvre M2"),
}


class BenchmarkBicycle(Scene):
    name = "bicycle"
    in_paper = False  # sympy's model and a long first compile: liefi reproduce runs it with --all or --only
    title = "Benchmark bicycle (Meijaard et al. 2007) through from_mechanics, uncontrolled from a lean-rate kick"
    paper = "beyond the paper: the Whipple bicycle, Meijaard, Papadopoulos, Ruina & Schwab (2007)"
    reference = "numerical"
    dt = 0.005  # |fastest eigenvalue| dt <= 0.12 up to 10 m/s (-24.6 /s there; 0.2 is the resolution limit)
    t_final = 10.0
    scheme = "imex-rk8"
    # the split scheme takes the stiff feedback implicitly: at 1e3 the rolling rows, the front contact's height and
    # the energy stay within 1e-13 over [0, 100] s (at gains 1, 10, 100 the rolling rows reach 1.7e-12, 1.0e-12,
    # 8e-14 m/s on the IFToMM run)
    gains = 1000.0
    variants = {k: Variant(k, d, options={"speed": v, "lean_rate": w}) for k, (v, w, d) in RUNS.items()}
    error_variables = ("q4", "q7")  # lean and steer

    @property
    def model(self):
        """The :class:`Bicycle` (sympy's ``KanesMethod`` after ``kanes_equations``), built on first use."""
        if "_model" not in self.__dict__:
            self.__dict__["_model"] = whipple_contact_coordinates()
        return self.__dict__["_model"]

    def costly_build(self):
        return "sympy's kanes_equations and from_mechanics, about 12 CPU s"

    def build_system(self):
        from ..systems.mechanics import from_mechanics

        bike = self.model
        return from_mechanics(bike.kane, bike.params)

    def initial_state(self, variant):
        o = variant.options
        return kicked_start(self.model, self.system, o["speed"], o["lean_rate"])

    def figures(self, runs, *, tag=""):
        """Lean and steer against time, both wheels' contact paths; then the generic figure."""
        out = []
        for r in self.as_runs(runs).values():
            out += [plotting.FigureSpec("bicycle-lean-steer",
                                        lambda f, r=r: lean_steer_figure({r.variant: r}, f, tag=tag), 13, 3.8),
                    plotting.FigureSpec("bicycle-contacts", lambda f, r=r: contacts_figure({r.variant: r}, f, tag=tag),
                                        11, 3.8),
                    plotting.FigureSpec("generic", lambda f, r=r: plotting.generic(r, f, title=self.title, tag=tag),
                                        11, 4.0)]
        return out


def lean_steer_figure(runs, fig=None, *, tag=""):
    """Lean ``q4`` and steer ``q7`` against ``t``, and ``|lean|`` on a log axis, for ``runs`` (``{label:
    RunResult}``), one line per run: decay and growth at the rates of the eigenvalues."""
    fig = plotting.figure(fig, 13, 3.8)
    a0, a1, a2 = fig.subplots(1, 3)
    for label, r in runs.items():
        v = SCENE.variant(r.variant).options["speed"]
        a0.plot(r.t, r["q4"], lw=0.9, label=f"{label}, {v:g} m/s")
        a1.plot(r.t, r["q7"], lw=0.9, label=f"{label}, {v:g} m/s")
        plotting.logplot(a2, r.t, r["q4"], lw=0.9, label=f"{label}, {v:g} m/s")
    for ax, what in ((a0, "lean $q_4$ (rad)"), (a1, "steer $q_7$ (rad)"), (a2, "$|$lean$|$ (rad)")):
        if ax is not a2:
            ax.axhline(0.0, color="k", lw=0.4)
        ax.set_xlabel("$t$ (s)")
        ax.set_ylabel(what)
        ax.grid(alpha=0.3)
    a0.set_title(f"lean{tag}", fontsize=10)
    a1.set_title(f"steer{tag}", fontsize=10)
    a2.set_title(f"lean, log scale{tag}", fontsize=10)
    a2.legend(fontsize=8)
    return fig


def contacts_figure(runs, fig=None, *, tag=""):
    """Both wheels' contact paths on the ground (:func:`contact_paths`), one panel per run, seen from above
    (``x`` forward, ``y`` to the right: the model's ``z`` points down)."""
    fig = plotting.figure(fig, 11, 3.8)
    axes = np.atleast_1d(fig.subplots(1, len(runs)))
    for ax, (label, r) in zip(axes, runs.items()):
        paths = contact_paths(SCENE.model, SCENE.system, r.y, r.names)
        ax.plot(*paths["rear"], lw=1.2, label="rear contact")
        ax.plot(*paths["front"], lw=0.9, ls="--", label="front contact")
        ax.invert_yaxis()  # seen from above
        ax.set_xlabel("$x$ (m, forward)")
        ax.set_ylabel("$y$ (m, to the right)")
        v = SCENE.variant(r.variant).options["speed"]
        ax.set_title(f"{label}, {v:g} m/s, $t \\leq {r.t[-1]:g}$ s{tag}", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    return fig


SCENE = BenchmarkBicycle()
