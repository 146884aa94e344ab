r"""The rattleback (celt): Kane & Levinson's (1982) ellipsoid, rolling without slipping, reverses its spin.

Built by :func:`liefi.systems.rolling.rolling_body` from the body's data only, on
``SO(3) x R^2`` with the whole attitude advected and the two no-slip rows kept
as constraint momenta (:mod:`liefi.systems.rolling` says why).  No dissipation: the
energy is conserved and the spin about the vertical, ``<Omega, Gamma>``,
reverses, then reverses back, again and again.

Data (Kane & Levinson, "Realistic mathematical modeling of the rattleback",
Int. J. Non-Linear Mech. 17 (1982) 175, as reproduced in SI units in PyDy's
rattleback example, ``examples/rattleback/cpp/reproduceKane1982_sim.cc``):

* the surface is the *ellipsoid* with semi-axes ``a, b, c = 0.2, 0.03, 0.02`` m
  (Kane & Levinson's surface, eqs. 16--18; PyDy also has a paraboloid
  variant, which is not theirs);
* the centre of mass a distance ``h = 0.01`` m below the ellipsoid's centre,
  on the short axis; mass ``M = 1`` kg, ``g = 9.81``;
* the central inertia ``A, B, C = 2e-4, 1.6e-3, 1.7e-3`` kg m^2 about the
  ellipsoid's axes, with the product of inertia ``D = -2e-5`` kg m^2 in the
  ``a``-``b`` plane (the inertia matrix element ``I_12``: the misalignment of
  the principal axes against the shape);
* start: tilts ``alpha = beta = 0.5`` degrees, no rocking, spin ``omega_3 =
  -5`` rad/s.

**Frames.** Kane & Levinson's body axis 3 points *down* (towards the contact
point at rest; their ``mu`` is the downward vertical and the centre of mass
sits at ``+h`` on axis 3).  liefi's body axis 3 points *up* (``Gamma = R^T
e_3`` is the upward vertical).  The proper rotation by ``pi`` about the long
axis, ``P = diag(1, -1, -1)``, carries theirs to liefi's: the inertia's product
becomes ``I_12 = -D = +2e-5``, the centre of mass ``(0, 0, -h)``, the start's
upward vertical ``Gamma = -P mu = (cos a sin b, sin a, cos a cos b)`` and its
body angular velocity ``P (0, 0, -5) = (0, 0, +5)``: the same motion, a spin
of ``+5`` rad/s about the upward vertical (counter-clockwise seen from above).
The heading is free (Kane & Levinson's ``gamma``, ignorable): the start's
attitude is the rotation about ``Gamma x e_3`` taking ``Gamma`` to ``e_3``.

Invariants in ``V``: the two constraint momenta, ``h~`` and the six attitude
Casimirs.  The rattleback has no other first integral.

Reference: the textbook rolling rigid body (Borisov & Mamaev 2002) with
``K = I Omega + M r x (Omega x r)`` the angular momentum about the contact
point and ``r`` the vector from the centre of mass to it,

.. math:: \dot K = K \times \Omega + M \dot r \times (\Omega \times r) + M g\, r \times \Gamma, \qquad
          \dot R = R \hat\Omega, \qquad \dot x_i = -\langle R^T e_i, \Omega \times r \rangle,

written out by hand, scalar by scalar, in
:func:`liefi.scenes.rolling_reference.rolling_equations`, with Kane & Levinson's
contact point ``r = -A^2 Gamma / |A Gamma| + h e_3`` and its rate by hand in
:func:`rattleback_equations` (independent of liefi's derivation), solved by DOP853 at ``1e-13``; its first
reversal -- the first zero of the long axis' heading rate (:func:`heading_rate`) -- is located on
its dense output (:meth:`Rattleback.reference_reversal`).  The run's is read from its samples (:func:`first_reversal`): the
step ``dt = 1e-4`` is the scene's because the body rocks fast (at ``1e-3``, ``imex-rk4`` is off by
5e-2 at ``t = 20``) and because near the reversal the heading rate dips through zero for well under
a millisecond.
"""

from __future__ import annotations

import math
import numpy as np

from ..results import scene_figures as plotting
from ..groups import SO3
from ..systems.rolling import ATTITUDE_CASIMIRS, ellipsoid, rolling_body, rolling_start
from .base import Variant
from .rolling_reference import RollingReferenceScene, rolling_equations

# --- Kane & Levinson (1982) in SI units (PyDy's reproduceKane1982_sim.cc) -------------------
SEMI_AXES = (0.2, 0.03, 0.02)
H = 0.01
MASS = 1.0
GRAVITY = 9.81
A_, B_, C_, D_ = 2e-4, 1.6e-3, 1.7e-3, -2e-5
TILT_DEG = 0.5
SPIN = -5.0  # omega_3 about Kane & Levinson's downward body axis 3


def inertia_matrix():
    """The central inertia in liefi's body axes (axis 3 up): ``[[A, -D, 0], [-D, B, 0], [0, 0, C]]``."""
    return np.array([[A_, -D_, 0.0], [-D_, B_, 0.0], [0.0, 0.0, C_]])


def start_attitude(tilt_deg=TILT_DEG):
    """``(R, Omega)`` of Kane & Levinson's start in liefi's axes (module docstring, *Frames*)."""
    al = be = math.radians(tilt_deg)
    mu = np.array([-math.cos(al) * math.sin(be), math.sin(al), math.cos(al) * math.cos(be)])  # their eq. 37
    P = np.diag([1.0, -1.0, -1.0])
    G = -P @ mu
    axis = np.cross(G, [0.0, 0.0, 1.0])
    angle = math.atan2(np.linalg.norm(axis), G[2])
    R = SO3().exp(axis / np.linalg.norm(axis) * angle) if angle > 0 else np.eye(3)
    return R, P @ np.array([0.0, 0.0, SPIN])


def _sqrt(x):
    return math.sqrt(x) if isinstance(x, float) else np.sqrt(x)


def rattleback_equations(inertia, mass, semi_axes, h, g):
    """The rolling rigid body's equations (:func:`~liefi.scenes.rolling_reference.rolling_equations`) for
    Kane & Levinson's ellipsoid, ``r = -A^2 Gamma / |A Gamma| + h e_3``, with its rate written by hand
    (reference only; module docstring)."""
    a2, b2, c2 = (float(s) ** 2 for s in semi_axes)

    def contact(G1, G2, G3, d1, d2, d3):
        e = _sqrt(a2 * G1 * G1 + b2 * G2 * G2 + c2 * G3 * G3)
        ed = (a2 * G1 * d1 + b2 * G2 * d2 + c2 * G3 * d3) / e
        return (-a2 * G1 / e, -b2 * G2 / e, -c2 * G3 / e + h,
                -a2 * (d1 - G1 * ed / e) / e, -b2 * (d2 - G2 * ed / e) / e, -c2 * (d3 - G3 * ed / e) / e)

    return rolling_equations(inertia, mass, g, contact)


def heading_rate(Omega, Gamma):
    """``psi' = (Omega_2 Gamma_2 + Omega_3 Gamma_3) / (1 - Gamma_1^2)``: the turning rate of the long axis'
    horizontal direction (``psi = atan2(R_21, R_11)``, ``R' = R hat(Omega)``), batch-first.

    It is the spin about the vertical ``<Omega, Gamma>`` without the roll about the long axis
    (``Omega_1 Gamma_1``), which flickers through zero while the body rocks; its zeros are the
    turning points of the heading, where the reversal is read.
    """
    Omega, Gamma = np.asarray(Omega), np.asarray(Gamma)
    return (Omega[..., 1] * Gamma[..., 1] + Omega[..., 2] * Gamma[..., 2]) / (1.0 - Gamma[..., 0] ** 2)


def first_reversal(t, spin):
    """The first time the spin ``spin(t)`` (samples) changes sign: a degree-5 interpolant on six samples
    around the first sign change, solved by bisection to rounding; ``nan`` if it never does."""
    t, spin = np.asarray(t, float), np.asarray(spin, float)
    s0 = np.sign(spin[0])
    idx = np.flatnonzero(np.sign(spin) != s0)
    if not idx.size:
        return float("nan")
    k = int(idx[0])
    lo, hi = max(0, k - 3), min(len(t), k + 3)
    lo = max(0, min(lo, hi - 6))
    step = t[k] - t[k - 1]
    x, ss = (t[lo:hi] - t[k - 1]) / step, spin[lo:hi]
    coef = np.polyfit(x, ss, len(x) - 1)
    a, b = 0.0, 1.0
    fa = np.polyval(coef, a)
    for _ in range(200):
        mid = 0.5 * (a + b)
        fm = np.polyval(coef, mid)
        if np.sign(fm) == np.sign(fa):
            a, fa = mid, fm
        else:
            b = mid
        if b - a <= 1e-15:
            break
    return float(t[k - 1] + 0.5 * (a + b) * step)


class Rattleback(RollingReferenceScene):
    name = "rattleback"
    in_paper = False
    title = "Rattleback (Kane & Levinson 1982) rolling without slipping: the spin reverses"
    paper = "future work of the paper: rolling bodies (semidirect-product reduction)"
    dt = 1e-4
    t_final = 5.0
    scheme = "imex-rk4"
    gains = 1.0
    variants = {"kane-levinson": Variant(
        "kane-levinson", "a, b, c = 0.2, 0.03, 0.02, h = 0.01, M = 1, A, B, C, D = 2e-4, 1.6e-3, 1.7e-3, -2e-5; "
                         "tilt 0.5 deg, spin -5 rad/s (Kane & Levinson's axes)")}

    mass = MASS
    inertia = inertia_matrix()
    observable_names = ("spin", "heading_rate")

    def build_system(self):
        contact = ellipsoid(SEMI_AXES, offset=(0.0, 0.0, -H))
        return rolling_body(MASS, inertia_matrix(), contact, gravity=GRAVITY)

    def initial_state(self, variant):
        R, W = start_attitude()
        return rolling_start(self.system, R, W)

    def invariants(self, variant):
        return ("constraints", "energy") + ATTITUDE_CASIMIRS

    def start_attitude(self):
        return start_attitude()

    def reference_equations(self):
        return rattleback_equations(inertia_matrix(), MASS, SEMI_AXES, H, GRAVITY)

    def reference_observables(self, Omega, Gamma):
        """``spin = <Omega, Gamma>``, the angular velocity about the vertical, and the heading rate of the
        long axis (:func:`heading_rate`), batch-first."""
        return {"spin": np.sum(Omega * Gamma, -1), "heading_rate": heading_rate(Omega, Gamma)}

    def reference_reversal(self, t_final=None, spacing=1e-5):
        """The first zero of the heading rate on the reference: its dense output scanned every ``spacing``
        (the dips near the reversal are shorter than DOP853's steps, which its event finder only checks at
        their ends), then the bracketed root solved by ``brentq`` to rounding."""
        from scipy.optimize import brentq

        T, dense, _, omega = self._reference(self.t_final if t_final is None else t_final)

        def rate(t):
            Y = dense(np.atleast_1d(t))
            W, _ = omega(Y)
            return heading_rate(W.T, Y[6:9].T)

        s0 = np.sign(rate(0.0)[0])
        for lo in np.arange(0.0, T, 0.5):
            t = np.linspace(lo, min(lo + 0.5, T), int(round(min(0.5, T - lo) / spacing)) + 1)
            idx = np.flatnonzero(np.sign(rate(t)) != s0)
            if idx.size:
                k = int(idx[0])
                return float(brentq(lambda x: rate(x)[0], t[k - 1], t[k], xtol=1e-15, rtol=1e-15))
        return float("nan")

    def figures(self, runs, *, tag=""):
        """The spin about the vertical against time (run and reference), the energy drift; then the generic."""
        out = []
        for r in self.as_runs(runs).values():
            out += [plotting.FigureSpec("rattleback-spin", lambda f, r=r: spin_figure(r, f, tag=tag), 11, 4.2),
                    plotting.FigureSpec("rattleback-energy", lambda f, r=r: energy_figure(r, f, tag=tag), 7, 4.2),
                    plotting.FigureSpec("generic", lambda f, r=r: plotting.generic(r, f, title=self.title, tag=tag),
                                        11, 4.0)]
        return out


def _spin_of(result):
    """The run's spin (from its reduced state) and the reference's (``None`` when not compared)."""
    s = SCENE.observables(result.y, list(result.names))["spin"]
    err = result.errors.get("spin")
    return s, (None if err is None else s - np.asarray(err))


def spin_figure(result, fig=None, *, tag=""):
    """``<Omega, Gamma>`` against ``t``, run against reference, with its error."""
    fig = plotting.figure(fig, 11, 4.2)
    a0, a1 = fig.subplots(1, 2)
    s, se = _spin_of(result)
    a0.plot(result.t, s, lw=0.8, label="feedback integrator")
    if se is not None:
        a0.plot(result.t, se, lw=0.8, ls="--", label="reference (rolling-body equations)")
        plotting.logplot(a1, result.t, s - se, lw=0.8)
    a0.axhline(0.0, color="k", lw=0.4)
    a0.set_xlabel("$t$ (s)")
    a0.set_ylabel(r"spin about the vertical $\langle\Omega,\Gamma\rangle$ (rad/s)")
    a0.set_title(f"the rattleback reverses{tag}", fontsize=10)
    a0.legend(fontsize=8)
    a1.set_xlabel("$t$ (s)")
    a1.set_ylabel("error of the spin")
    a1.grid(alpha=0.3)
    return fig


def energy_figure(result, fig=None, *, tag=""):
    """``|h~(t) - h~(0)|`` and the constraint momenta ``|J_i|`` against ``t``."""
    fig = plotting.figure(fig, 7, 4.2)
    ax = fig.subplots(1, 1)
    for k in ("h", "h~", "J_1", "J_2"):
        if k in result.invariants:
            v = np.asarray(result.invariants[k])
            plotting.logplot(ax, result.t, v - (0.0 if k.startswith("J_") else v[0]), label=k, lw=0.8)
    ax.set_xlabel("$t$ (s)")
    ax.set_ylabel("drift")
    ax.set_title(f"rattleback: energy drift and no-slip violation{tag}", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return fig


SCENE = Rattleback()
