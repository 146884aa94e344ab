r"""The rattleback (celt): Kane & Levinson's (1982) ellipsoid, rolling without slipping, reverses its spin.

Built by :func:`liefi.rolling.rolling_body` from the body's data only, on
``SO(3) x R^2`` with the whole attitude advected and the two no-slip rows kept
as constraint momenta (:mod:`liefi.rolling` says why).  No dissipation: the
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

with Kane & Levinson's contact point ``r = -A^2 Gamma / |A Gamma| + h e_3``
written out by hand, scalar by scalar, in :func:`rattleback_equations`
(independent of liefi's derivation), solved by DOP853 at ``1e-13``; its first
reversal -- the first zero of the long axis' heading rate (:func:`heading_rate`) -- is located on
its dense output (:meth:`Rattleback.reference_reversal`).  The run's is read from its samples (:func:`first_reversal`): the
step ``dt = 1e-4`` is the scene's because the body rocks fast (at ``1e-3``, ``imex-rk4`` is off by
5e-2 at ``t = 20``) and because near the reversal the heading rate dips through zero for well under
a millisecond.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .. import plotting
from ..groups import SO3
from ..rolling import ATTITUDE_CASIMIRS, ellipsoid, rolling_body, rolling_start
from .base import Scene, Variant

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


def rattleback_equations(inertia, mass, semi_axes, h, g):
    """The rolling rigid body's equations for an ellipsoid, ``fun(t, y)``, ``y = (R row-major, x, y, K)``
    (reference only; module docstring).  Scalar code: a 3 x 3 solve by Cramer's rule."""
    I = np.asarray(inertia, float)
    i11, i12, i13, i22, i23, i33 = I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2]
    a2, b2, c2 = (float(s) ** 2 for s in semi_axes)
    m = float(mass)

    def fun(t, y):
        R11, R12, R13, R21, R22, R23, G1, G2, G3 = y[:9]
        K1, K2, K3 = y[11], y[12], y[13]
        e = math.sqrt(a2 * G1 * G1 + b2 * G2 * G2 + c2 * G3 * G3)
        r1, r2, r3 = -a2 * G1 / e, -b2 * G2 / e, -c2 * G3 / e + h
        rr = r1 * r1 + r2 * r2 + r3 * r3
        # K = (I + m (|r|^2 - r r^T)) Omega
        m11, m12, m13 = i11 + m * (rr - r1 * r1), i12 - m * r1 * r2, i13 - m * r1 * r3
        m22, m23, m33 = i22 + m * (rr - r2 * r2), i23 - m * r2 * r3, i33 + m * (rr - r3 * r3)
        c11, c12, c13 = m22 * m33 - m23 * m23, m13 * m23 - m12 * m33, m12 * m23 - m13 * m22
        c22, c23, c33 = m11 * m33 - m13 * m13, m12 * m13 - m11 * m23, m11 * m22 - m12 * m12
        det = m11 * c11 + m12 * c12 + m13 * c13
        W1 = (c11 * K1 + c12 * K2 + c13 * K3) / det
        W2 = (c12 * K1 + c22 * K2 + c23 * K3) / det
        W3 = (c13 * K1 + c23 * K2 + c33 * K3) / det
        # Gamma' = Gamma x Omega, and r' by hand
        d1, d2, d3 = G2 * W3 - G3 * W2, G3 * W1 - G1 * W3, G1 * W2 - G2 * W1
        ed = (a2 * G1 * d1 + b2 * G2 * d2 + c2 * G3 * d3) / e
        q1, q2, q3 = -a2 * (d1 - G1 * ed / e) / e, -b2 * (d2 - G2 * ed / e) / e, -c2 * (d3 - G3 * ed / e) / e
        v1, v2, v3 = W2 * r3 - W3 * r2, W3 * r1 - W1 * r3, W1 * r2 - W2 * r1  # Omega x r
        Kd1 = K2 * W3 - K3 * W2 + m * (q2 * v3 - q3 * v2) + m * g * (r2 * G3 - r3 * G2)
        Kd2 = K3 * W1 - K1 * W3 + m * (q3 * v1 - q1 * v3) + m * g * (r3 * G1 - r1 * G3)
        Kd3 = K1 * W2 - K2 * W1 + m * (q1 * v2 - q2 * v1) + m * g * (r1 * G2 - r2 * G1)
        out = np.empty(14)
        for i, (a, b_, c) in enumerate(((R11, R12, R13), (R21, R22, R23), (G1, G2, G3))):
            out[3 * i:3 * i + 3] = (b_ * W3 - c * W2, c * W1 - a * W3, a * W2 - b_ * W1)  # R Omega^
        out[9] = -(R11 * v1 + R12 * v2 + R13 * v3)
        out[10] = -(R21 * v1 + R22 * v2 + R23 * v3)
        out[11:14] = (Kd1, Kd2, Kd3)
        return out

    def omega(y):
        """``(Omega, r)`` at ``y`` (the same algebra as ``fun``, vectorised over the last axis)."""
        one = np.ndim(y) == 1
        y = np.asarray(y, float).reshape(len(y), -1)
        G = y[6:9]
        e = np.sqrt(a2 * G[0] ** 2 + b2 * G[1] ** 2 + c2 * G[2] ** 2)
        r = np.stack([-a2 * G[0] / e, -b2 * G[1] / e, -c2 * G[2] / e + h])
        rr = np.sum(r * r, 0)
        Mop = I[..., None] + m * (rr * np.eye(3)[..., None] - r[:, None] * r[None, :])
        W = np.linalg.solve(np.moveaxis(Mop, -1, 0), np.moveaxis(y[11:14], -1, 0)[..., None])[..., 0]
        W = np.moveaxis(W, 0, -1)
        return (W[:, 0], r[:, 0]) if one else (W, r)

    fun.omega = omega
    return fun


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


class Rattleback(Scene):
    name = "rattleback"
    in_paper = False
    title = "Rattleback (Kane & Levinson 1982) rolling without slipping: the spin reverses"
    paper = "future work of the paper: rolling bodies (semidirect-product reduction)"
    reference = "numerical"
    dt = 1e-4
    t_final = 5.0
    scheme = "imex-rk4"
    gains = 1.0
    variants = {"kane-levinson": Variant(
        "kane-levinson", "a, b, c = 0.2, 0.03, 0.02, h = 0.01, M = 1, A, B, C, D = 2e-4, 1.6e-3, 1.7e-3, -2e-5; "
                         "tilt 0.5 deg, spin -5 rad/s (Kane & Levinson's axes)")}
    figures_need_configuration = True
    reference_rtol = 1e-13
    reference_atol = 1e-13

    @property
    def error_variables(self):
        return ("r_1", "r_2") + self.system.state_names + ("spin", "heading_rate")

    def build_system(self):
        contact = ellipsoid(SEMI_AXES, offset=(0.0, 0.0, -H))
        return rolling_body(MASS, inertia_matrix(), contact, gravity=GRAVITY)

    def initial_state(self, variant):
        R, W = start_attitude()
        return rolling_start(self.system, R, W)

    def invariants(self, variant):
        return ("constraints", "energy") + ATTITUDE_CASIMIRS

    def observables(self, y, names):
        """``spin = <Omega, Gamma>``, the angular velocity about the vertical, and the heading rate of the long
        axis (:func:`heading_rate`), from the reduced state."""
        z = np.stack([y[names.index(n)] for n in self.system.state_names], -1)
        m = np.asarray(self.system.metric(z[..., :9]), float)
        W = np.linalg.solve(m, z[..., 9:][..., None])[..., 0][..., :3]
        return {"spin": np.sum(W * z[..., 6:9], -1), "heading_rate": heading_rate(W, z[..., 6:9])}

    def reference_method(self):
        return (f"DOP853 (scipy solve_ivp, rtol {self.reference_rtol:g}, atol {self.reference_atol:g}) on the "
                "rolling rigid body's equations written by hand (liefi.scenes.rattleback.rattleback_equations)")

    def _reference(self, t_final):
        """The dense reference on ``[0, t_final]``, cached by horizon."""
        from scipy.integrate import solve_ivp

        cache = self.__dict__.setdefault("_refcache", {})
        hit = cache.get("dense")
        if hit is None or hit[0] < t_final:
            y0 = np.asarray(self.initial_state(self.variant()), float)
            R0, W0 = start_attitude()
            fun = rattleback_equations(inertia_matrix(), MASS, SEMI_AXES, H, GRAVITY)
            r0 = fun.omega(np.concatenate([y0[:11], np.zeros(3)]))[1]
            K0 = inertia_matrix() @ W0 + MASS * np.cross(r0, np.cross(W0, r0))

            start = time.process_time()
            sol = solve_ivp(fun, (0.0, float(t_final)), np.concatenate([y0[:11], K0]), method="DOP853",
                            rtol=self.reference_rtol, atol=self.reference_atol, dense_output=True)
            self.reference_seconds = getattr(self, "reference_seconds", 0.0) + time.process_time() - start
            if not sol.success:
                raise RuntimeError(f"reference solution of {self.name!r} failed: {sol.message}")
            hit = cache["dense"] = (float(t_final), sol.sol, None, fun.omega)
        return hit

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

    def reference_solution(self, variant, t_final, *, backend=None):
        """The hand-written reference on ``[0, t_final]`` (what :meth:`exact` reads; ``liefi reproduce``
        computes it once up front), not the base class' liefi-derived constrained field."""
        self._reference(float(t_final))
        return lambda t: self.exact(t, variant)

    def exact(self, t, variant):
        t = np.asarray(t, float)
        T, dense, _, omega = self._reference(float(t[-1]))
        Y = dense(t)
        W, r = omega(Y)
        G = Y[6:9]
        u = -np.stack([np.sum(Y[0:3] * np.cross(W.T, r.T).T, 0), np.sum(Y[3:6] * np.cross(W.T, r.T).T, 0)])
        w = np.cross(G.T, r.T).T  # Gamma x r: the height's rate is <w, Omega>
        Pi = inertia_matrix() @ W + MASS * w * np.sum(w * W, 0)
        names = self.system.space.group.config_names + self.system.state_names + ("spin", "heading_rate")
        vals = np.concatenate([Y[:11], Y[:9], Pi, MASS * u, np.sum(W * G, 0)[None], heading_rate(W.T, G.T)[None]])
        return {n: vals[i] for i, n in enumerate(names)}

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
