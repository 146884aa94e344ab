r"""The heavy symmetric (Lagrange) top: an advected vector and the semidirect product ``so(3) x| R^3``.

A rigid body with a fixed point, in gravity.  Its potential
``U = M g <R chi, e_3> = M g <chi, Gamma>`` depends on the attitude ``R`` only
through the upward vertical seen from the body, ``Gamma = R^T e_3``: the data
are invariant under rotations about the vertical only, and the top reduces to
``(so(3) x| R^3)*`` with state ``(Gamma, Pi)`` (:mod:`liefi.phase_space`).
The scene gives the data -- inertia ``I = diag(I_1, I_1, I_3)``, the centre of
mass ``chi = (0, 0, l)`` on the symmetry axis, ``M g`` -- and nothing else;
liefi derives the Euler--Poisson equations

.. math:: \dot\Pi = \Pi \times \Omega + M g\, \Gamma \times \chi, \qquad
          \dot\Gamma = \Gamma \times \Omega, \qquad \Omega = I^{-1} \Pi

from the bracket (Marsden & Ratiu, *Introduction to Mechanics and Symmetry*;
Holm, Marsden & Ratiu 1998).  Holonomic (``K = 0``): the extended
field is the top's own.  First integrals: the energy ``E``, the Casimirs
``<Pi, Gamma>`` (the vertical angular momentum) and ``|Gamma|^2``, and for
the symmetric top ``Pi_3`` (Lagrange's integral).  ``V`` penalizes all four.

Reference: the textbook equations above written out by hand in
:func:`euler_poisson` (a second, independent route: they are not liefi's field)
and solved by DOP853 at ``rtol = atol = 1e-13``.

Extra scheme ``"splitting"`` (the peer): the Lie--Poisson splitting
``H = sum_i Pi_i^2/(2 I_i) + M g <chi, Gamma>`` into three free rotations about
the body axes and a kick, each solved exactly, composed as
``U(h/2) 3(h/2) 2(h/2) 1(h) 2(h/2) 3(h/2) U(h/2)`` (McLachlan, Phys. Rev. Lett.
71 (1993) 3043; Touma & Wisdom, Astron. J. 107 (1994) 1189): second order,
Poisson, keeps ``|Gamma|`` and ``<Pi, Gamma>`` to rounding and ``R`` on SO(3);
its energy error is ``O(h^2)`` and bounded.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..integrator.feedback import Invariant
from ..groups import SO3, Representation
from ..phase_space import LieGroupPhaseSpace
from ..systems.system import NonholonomicSystem
from .base import Scene, Variant

# state z = (Gamma_1, Gamma_2, Gamma_3, Pi_1, Pi_2, Pi_3); traceable gradients for the engine


def _pi_gamma(z):
    return z[..., 0] * z[..., 3] + z[..., 1] * z[..., 4] + z[..., 2] * z[..., 5]


def _pi_gamma_grad(z):
    return np.stack([z[..., 3], z[..., 4], z[..., 5], z[..., 0], z[..., 1], z[..., 2]], -1)


def _gamma_sq(z):
    return z[..., 0] ** 2 + z[..., 1] ** 2 + z[..., 2] ** 2


def _gamma_sq_grad(z):
    zero = 0.0 * z[..., 0]
    return np.stack([2 * z[..., 0], 2 * z[..., 1], 2 * z[..., 2], zero, zero, zero], -1)


def _pi3(z):
    return z[..., 5]


def _pi3_grad(z):
    zero = 0.0 * z[..., 0]
    return np.stack([zero, zero, zero, zero, zero, zero + 1.0], -1)


#: ``<Pi, Gamma>``: the vertical angular momentum, a Casimir of ``(so(3) x| R^3)*``
PI_GAMMA = Invariant("Pi.Gamma", _pi_gamma, _pi_gamma_grad)
#: ``|Gamma|^2``: a Casimir (``Gamma`` stays on its sphere)
GAMMA_SQ = Invariant("|Gamma|^2", _gamma_sq, _gamma_sq_grad)
#: ``Pi_3``: Lagrange's integral of the symmetric top
PI3 = Invariant("Pi_3", _pi3, _pi3_grad)


def euler_poisson(inertia, mg, chi):
    """The textbook heavy-top equations ``fun(t, y)``, ``y = (R row-major, Gamma, Pi)`` (reference only).

    ``R' = R hat(Omega)``, ``Gamma' = Gamma x Omega``, ``Pi' = Pi x Omega + M g Gamma x chi``.
    """
    inertia, chi = np.asarray(inertia, float), np.asarray(chi, float)

    def fun(t, y):
        R, G, P = y[:9].reshape(3, 3), y[9:12], y[12:15]
        W = P / inertia
        What = np.array([[0.0, -W[2], W[1]], [W[2], 0.0, -W[0]], [-W[1], W[0], 0.0]])
        return np.concatenate([(R @ What).ravel(), np.cross(G, W), np.cross(P, W) + mg * np.cross(G, chi)])

    return fun


def _split_loop(R, G, P, inertia, mgchi, h, n_steps, save_every, out):
    """The symmetric splitting (module docstring), scalar code (numba-compiled when available).

    Flow of ``Pi_i^2/(2 I_i)`` for a time ``tau``: rotation by ``theta = tau Pi_i / I_i`` about
    ``e_i``: ``R <- R Q``, ``Gamma <- Q^T Gamma``, ``Pi <- Q^T Pi``.  Flow of ``U``:
    ``Pi <- Pi + tau Gamma x (M g chi)``.
    """
    axes = (2, 1, 0, 1, 2)
    fracs = (0.5, 0.5, 1.0, 0.5, 0.5)
    k = 0
    for s in range(n_steps):
        for stage in range(3):  # U(h/2), the five rotations, U(h/2)
            if stage == 1:
                for a in range(5):
                    i = axes[a]
                    th = fracs[a] * h * P[i] / inertia[i]
                    c = math.cos(th)
                    sn = math.sin(th)
                    j = (i + 1) % 3
                    m = (i + 2) % 3
                    pj, pm = P[j], P[m]
                    P[j] = c * pj + sn * pm
                    P[m] = -sn * pj + c * pm
                    gj, gm = G[j], G[m]
                    G[j] = c * gj + sn * gm
                    G[m] = -sn * gj + c * gm
                    for r in range(3):
                        rj, rm = R[r, j], R[r, m]
                        R[r, j] = c * rj + sn * rm
                        R[r, m] = -sn * rj + c * rm
            else:
                tau = 0.5 * h
                P[0] += tau * (G[1] * mgchi[2] - G[2] * mgchi[1])
                P[1] += tau * (G[2] * mgchi[0] - G[0] * mgchi[2])
                P[2] += tau * (G[0] * mgchi[1] - G[1] * mgchi[0])
        if (s + 1) % save_every == 0:
            k += 1
            for r in range(3):
                for q in range(3):
                    out[3 * r + q, k] = R[r, q]
                out[9 + r, k] = G[r]
                out[12 + r, k] = P[r]
    return k


_COMPILED = {}


def splitting(R0, Gamma0, Pi0, inertia, mg, chi, h, n_steps, save_every=1):
    """Run the splitting; ``(t, Y, cpu_seconds)``, ``Y`` of shape ``(15, n_saved)``: ``R`` row-major, ``Gamma``, ``Pi``.

    Compilation (first call) is not counted in ``cpu_seconds``.
    """
    n_steps, save_every = int(n_steps), max(1, int(save_every))
    if n_steps % save_every:
        raise ValueError(f"save_every: {save_every} must divide the number of steps {n_steps}")
    if "split" not in _COMPILED:
        try:
            import numba

            f = numba.njit(cache=False)(_split_loop)
            f(np.eye(3), np.ones(3), np.ones(3), np.ones(3), np.ones(3), 1e-3, 1, 1, np.zeros((15, 2)))
        except Exception:  # noqa: BLE001 -- no numba: the Python loop
            f = _split_loop
        _COMPILED["split"] = f
    f = _COMPILED["split"]
    ns = n_steps // save_every + 1
    R = np.array(R0, float).reshape(3, 3).copy()
    G, P = np.array(Gamma0, float).copy(), np.array(Pi0, float).copy()
    out = np.zeros((15, ns))
    out[:, 0] = np.concatenate([R.ravel(), G, P])
    start = time.process_time()
    f(R, G, P, np.asarray(inertia, float).copy(), mg * np.asarray(chi, float), float(h), n_steps, save_every, out)
    cpu = time.process_time() - start
    return np.arange(ns) * (save_every * float(h)), out, cpu


class HeavyTop(Scene):
    name = "heavy-top"
    in_paper = False
    title = "Heavy symmetric top (Lagrange) on (so(3) x| R^3)*"
    paper = "future work of the paper: data that depend on the attitude (semidirect-product reduction)"
    reference = "numerical"
    dt = 1e-3
    t_final = 100.0
    scheme = "imex-rk4"
    gains = 1.0
    variants = {"lagrange": Variant(
        "lagrange", "I = diag(1, 1, 0.6), chi = (0, 0, 1), M g = 1; tilted 0.5 rad, spinning at 6 rad/s about its axis")}
    error_variables = ("Gamma_1", "Gamma_2", "Gamma_3", "Pi_1", "Pi_2", "Pi_3")
    extra_schemes = ("splitting",)

    inertia = np.array([1.0, 1.0, 0.6])
    chi = np.array([0.0, 0.0, 1.0])
    mg = 1.0
    tilt = 0.5
    Omega0 = np.array([0.4, -0.2, 6.0])
    #: tolerances of the DOP853 reference on the textbook equations
    reference_rtol = 1e-13
    reference_atol = 1e-13

    def build_system(self):
        space = LieGroupPhaseSpace(SO3(), advected=Representation(SO3()), a0=[0.0, 0.0, 1.0])
        mgchi = self.mg * self.chi
        return NonholonomicSystem(space, np.diag(self.inertia), potential=lambda x, Gamma: Gamma @ mgchi)

    def initial_state(self, variant):
        R0 = SO3().exp(np.array([self.tilt, 0.0, 0.0]))
        g0 = R0.ravel()
        Gamma0 = self.system.space.advected_vector(g0)
        return np.concatenate([g0, Gamma0, self.inertia * self.Omega0])

    def invariants(self, variant):
        return ("energy", PI_GAMMA, PI3, GAMMA_SQ)

    def reference_method(self):
        return (f"DOP853 (scipy solve_ivp, rtol {self.reference_rtol:g}, atol {self.reference_atol:g}) on the "
                "textbook Euler-Poisson equations written by hand (liefi.scenes.heavy_top.euler_poisson)")

    def exact(self, t, variant):
        t = np.asarray(t, float)

        def solve():
            y0 = np.asarray(self.initial_state(variant), float)
            sol = self.solve_reference(euler_poisson(self.inertia, self.mg, self.chi), y0, t[-1], t_eval=t)
            names = tuple(SO3().config_names) + self.system.state_names
            return {n: sol.y[i] for i, n in enumerate(names)}

        return self._kept((variant.name, float(t[-1]), len(t)), solve)

    def run_extra(self, scheme, variant, dt, T, save_every, fi):
        if scheme == "splitting":
            y0 = np.asarray(self.initial_state(variant), float)
            n_steps = int(round(T / dt))
            se = save_every if n_steps % save_every == 0 else 1
            t, Y, cpu = splitting(y0[:9], y0[9:12], y0[12:], self.inertia, self.mg, self.chi, dt, n_steps, se)
            names = tuple(SO3().config_names) + self.system.state_names
            if not fi.configuration:
                Y, names = Y[9:], names[9:]
            return t, Y, names, cpu, n_steps, n_steps
        return super().run_extra(scheme, variant, dt, T, save_every, fi)


SCENE = HeavyTop()
