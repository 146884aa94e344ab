r"""The free rigid body on SO(3), the benchmark of Bae & Chang: data and two reference integrators.

J. Bae and D. E. Chang, "Feedback integrators revisited", arXiv:2512.01528,
free rigid body experiment: inertia ``I = diag(3, 2, 1)``, ``R(0) = I``,
``Omega(0) = (1, 1, 1)`` (so the body momentum ``Pi(0) = I Omega(0) = (3, 2, 1)``),
``t`` in ``[0, 1000]``, Euler with the feedback gains ``k0 = 50`` (the
embedding penalty ``k0/4 ||R^T R - I||^2``), ``k1 = 100`` (the energy) and
``k2 = 50`` (the momentum).  A :class:`~liefi.LieGroupPhaseSpace` of
:class:`~liefi.groups.SO3` with no constraints (``K = 0``): the extended
field is the rigid body's own (``Pi' = Pi x Omega``, ``R' = R hat(Omega)``,
``Omega = I^{-1} Pi``), derived by the library.

Differences from the peer, both forced by the model:

* the state is ``(R, Pi)`` (body momentum), theirs ``(R, Omega)``; the same
  gains therefore weight the invariants differently (``grad E`` is
  ``Omega`` here, ``I Omega`` there);
* liefi's invariants are functions of the reduced state, so ``k2`` weights
  the Casimir ``C = |Pi|^2/2`` (invariant ``"casimir"``), not the spatial
  momentum ``R Pi`` (whose three components fix the Casimir and two more
  numbers, which the orthogonality penalty and the energy do not).

Extra schemes:

* ``"splitting"``: the symmetric Lie--Poisson splitting of
  ``H = sum_i Pi_i^2/(2 I_i)`` into three free rotations about the principal
  axes, each solved exactly, composed as ``3(h/2) 2(h/2) 1(h) 2(h/2) 3(h/2)``
  (McLachlan, "Explicit Lie-Poisson integration and the Euler equations",
  Phys. Rev. Lett. 71 (1993) 3043; Touma & Wisdom, Astron. J. 107 (1994)
  1189; Reich 1993): symplectic on the coadjoint orbit, second order, keeps
  ``|Pi|`` and the spatial momentum ``R Pi`` to rounding and ``R`` on SO(3)
  to rounding; the energy error is ``O(h^2)`` and bounded.  The same method as
  the peer's "Strang splitting".
* ``"projected-rk4"``: classical RK4 on the free field, each step followed by
  liefi's projection onto ``{R^T R = I, h = h0, C = C0}``
  (:func:`liefi.engine.compile_constrained`, Newton along the invariants'
  gradients): needs numba.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..integrator.feedback import Invariant
from ..groups import SO3
from ..phase_space import LieGroupPhaseSpace
from ..systems.system import NonholonomicSystem
from .base import Scene, Variant


def _casimir(z):
    """``C = |Pi|^2 / 2`` (complex-step safe)."""
    return 0.5 * (z[..., 0] ** 2 + z[..., 1] ** 2 + z[..., 2] ** 2)


def _casimir_grad(z):
    """``grad C = Pi`` (traceable by :mod:`liefi.engine`)."""
    return np.stack([z[..., 0], z[..., 1], z[..., 2]], -1)


#: The Casimir of the Lie--Poisson bracket on so(3)*, a first integral of every rigid body.
CASIMIR = Invariant("casimir", _casimir, _casimir_grad)


def _split_loop(R, P, inertia, h, n_steps, save_every, out_R, out_P):
    """The symmetric splitting (module docstring), scalar code (compiled by numba when available).

    The flow of ``H_i = Pi_i^2/(2 I_i)`` for a time ``tau`` is the rotation by
    ``theta = tau Pi_i / I_i`` about the body axis ``e_i``:
    ``R <- R Q``, ``Pi <- Q^T Pi``, ``Q = exp(theta hat(e_i))``.
    """
    axes = (2, 1, 0, 1, 2)
    fracs = (0.5, 0.5, 1.0, 0.5, 0.5)
    k = 0
    for s in range(n_steps):
        for a in range(5):
            i = axes[a]
            th = fracs[a] * h * P[i] / inertia[i]
            c = math.cos(th)
            sn = math.sin(th)
            j = (i + 1) % 3
            l = (i + 2) % 3
            # Q = exp(th hat(e_i)) acts in the (e_j, e_l) plane: Q e_j = c e_j + s e_l, Q e_l = -s e_j + c e_l
            pj = P[j]
            pl = P[l]
            P[j] = c * pj + sn * pl
            P[l] = -sn * pj + c * pl
            for r in range(3):
                rj = R[r, j]
                rl = R[r, l]
                R[r, j] = c * rj + sn * rl
                R[r, l] = -sn * rj + c * rl
        if (s + 1) % save_every == 0:
            k += 1
            for r in range(3):
                out_P[r, k] = P[r]
                for q in range(3):
                    out_R[3 * r + q, k] = R[r, q]
    return k


_COMPILED = {}


def _splitter():
    if "split" not in _COMPILED:
        try:
            import numba

            _COMPILED["split"] = numba.njit(cache=False)(_split_loop)
        except Exception:  # noqa: BLE001 -- no numba: the Python loop
            _COMPILED["split"] = _split_loop
    return _COMPILED["split"]


def splitting(R0, Pi0, inertia, h, n_steps, save_every=1):
    """Run the splitting; returns ``(t, Y, cpu_seconds)`` with ``Y`` of shape ``(12, n_saved)`` (``R`` row-major, ``Pi``).

    Compilation (first call) is not counted in ``cpu_seconds``.
    """
    n_steps, save_every = int(n_steps), max(1, int(save_every))
    if n_steps % save_every:
        raise ValueError(f"save_every: {save_every} must divide the number of steps {n_steps}")
    ns = n_steps // save_every + 1
    f = _splitter()
    inertia = np.asarray(inertia, float).copy()
    if f is not _split_loop and "warm" not in _COMPILED:
        f(np.eye(3), np.ones(3), inertia, 1e-3, 1, 1, np.zeros((9, 2)), np.zeros((3, 2)))
        _COMPILED["warm"] = True
    R = np.array(R0, float).reshape(3, 3).copy()
    P = np.array(Pi0, float).copy()
    out_R = np.zeros((9, ns))
    out_P = np.zeros((3, ns))
    out_R[:, 0] = R.ravel()
    out_P[:, 0] = P
    start = time.process_time()
    f(R, P, inertia, float(h), n_steps, save_every, out_R, out_P)
    cpu = time.process_time() - start
    t = np.arange(ns) * (save_every * float(h))
    return t, np.concatenate([out_R, out_P], 0), cpu


class RigidBody(Scene):
    name = "rigid-body"
    in_paper = False  # Bae & Chang's benchmark: liefi reproduce runs it with --all or --only
    title = "Free rigid body on SO(3) (Bae & Chang's benchmark)"
    paper = "Bae & Chang, arXiv:2512.01528, free rigid body"
    reference = "numerical"
    dt = 1e-3
    t_final = 1000.0
    scheme = "euler"
    gains = {"penalty": 50.0, "energy": 100.0, "casimir": 50.0}
    variants = {"free": Variant("free", "Bae & Chang's free rigid body: I = diag(3, 2, 1), R0 = I, Omega0 = (1, 1, 1)")}
    error_variables = ("R11", "R12", "R13", "R21", "R22", "R23", "R31", "R32", "R33", "Pi_1", "Pi_2", "Pi_3")
    extra_schemes = ("splitting", "projected-rk4")

    inertia = np.array([3.0, 2.0, 1.0])
    Omega0 = np.array([1.0, 1.0, 1.0])

    def build_system(self):
        return NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.diag(self.inertia))

    def initial_state(self, variant):
        return np.concatenate([np.eye(3).ravel(), self.inertia * self.Omega0])

    def invariants(self, variant):
        return ("energy", CASIMIR)

    def exact(self, t, variant):
        """DOP853 (rtol 1e-12) on the free field, the compiled one when numba is installed.

        The same reference as :meth:`Scene.numerical_reference` (``K = 0``: the
        constrained field is the free one), 10-20 times cheaper over ``[0, 1000]``.
        """
        from .. import engine

        if not engine.available():
            return self.numerical_reference(t, variant)

        def solve():
            fi = self.integrator(variant, configuration=True)
            cf = engine.compile_feedback(fi)
            fun = cf.fun(engine.parameters(fi, {k: 0.0 for k in fi.gains}))
            sol = self.solve_reference(fun, fi.y0, t[-1], t_eval=t)
            return {n: sol.y[i] for i, n in enumerate(fi.names)}

        return self._kept(("compiled", variant.name, float(t[-1]), len(t)), solve)

    def integrator(self, variant=None, *, gains=None, configuration=None, y0=None):
        """As :meth:`Scene.integrator`; without the configuration there is no penalty to weight."""
        if gains is None and configuration is False:
            gains = {k: v for k, v in self.gains.items() if k != "penalty"}
        return super().integrator(variant, gains=gains, configuration=configuration, y0=y0)

    def run_extra(self, scheme, variant, dt, T, save_every, fi):
        y0 = np.asarray(self.initial_state(variant), float)
        n_steps = int(round(T / dt))
        if scheme == "splitting":
            se = save_every if n_steps % save_every == 0 else 1
            t, Y, cpu = splitting(y0[:9], y0[9:], self.inertia, dt, n_steps, se)
            # five rotations per step (no field evaluations); report steps as the work
            return t, Y, fi.names, cpu, n_steps, n_steps
        if scheme == "projected-rk4":
            from .. import engine

            if not engine.available():
                raise ValueError("scheme: 'projected-rk4' needs numba (pip install liefi[fast])")
            cf = engine.compile_constrained(fi, projection=True)
            proj = engine.projection_targets(fi)
            cf.warmup("rk4", project=True)
            sol = cf.run(fi.y0, np.zeros(0), dt, n_steps, "rk4", save_every=save_every, names=fi.names, project=proj)
            return sol.t, sol.y, sol.names, sol.cpu_seconds, sol.steps, sol.rhs_evaluations
        return super().run_extra(scheme, variant, dt, T, save_every, fi)


SCENE = RigidBody()
