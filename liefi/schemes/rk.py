"""Explicit Runge--Kutta schemes as Butcher tableaux, with their stability properties.

A tableau ``(A, b, c)`` is data; everything else is derived from it:

* the stability polynomial ``R(z) = 1 + sum_k (b^T A^(k-1) 1) z^k`` of
  ``y' = L y`` (``y_{n+1} = R(dt L) y_n``; the tableau is explicit, so ``A`` is
  nilpotent and the sum stops at the number of stages);
* the real stability bound ``beta = sup{x : |R(-s)| <= 1 for s in [0, x]}``
  (2 for Euler and Heun, 2.5127 for RK3, 2.7853 for RK4): ``y' = -lambda y`` is
  stable while ``dt lambda`` stays in ``[0, beta]``;
* the optimal rate ``x* = argmin_{[0, beta]} |R(-x)|``, the ``dt lambda_max``
  that automatic gains aim at (1 for Euler: Bae & Chang's optimal fixed gain
  ``1/(dt L)``, "Feedback integrators revisited", arXiv:2512.01528).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ExplicitRungeKutta:
    """An explicit Runge--Kutta scheme ``(A, b, c)``; one entry of :mod:`liefi.schemes.registry`.

    Attributes
    ----------
    name : str
    A : tuple of tuples (strictly lower triangular), b, c : tuples
    order : int
        Classical order of accuracy.
    """

    name: str
    A: tuple
    b: tuple
    c: tuple
    order: int

    kind = "explicit"
    #: An explicit scheme is not stable for every stiffness.
    stiff_safe = False

    @property
    def stages(self):
        """Evaluations of the field per step."""
        return len(self.b)

    def step(self, f, y, dt):
        """One step ``y -> y + dt sum_i b_i k_i``, ``k_i = f(y + dt sum_j a_ij k_j)``.

        A field bound to an integrator with ``holding(y, dt)`` (a context: a forced run's zero-order
        hold, :mod:`liefi.integrator.forced`) is told the step's start and size around its stages.
        """
        hold = getattr(getattr(f, "__self__", None), "holding", None)
        if hold is not None:
            with hold(y, dt):
                return self._stages(f, y, dt)
        return self._stages(f, y, dt)

    def _stages(self, f, y, dt):
        ks = []
        for i in range(self.stages):
            yi = y
            for j, a in enumerate(self.A[i][:i]):
                if a:
                    yi = yi + (dt * a) * ks[j]
            ks.append(f(yi))
        out = y
        for bi, k in zip(self.b, ks):
            if bi:
                out = out + (dt * bi) * k
        return out

    # --- stability, derived from the tableau ----------------------------------------
    @property
    def stability_coefficients(self):
        """Coefficients of ``R(z)``, highest power first (for ``np.polyval``)."""
        return _poly(self)

    def stability_function(self, z):
        """``R(z)`` with ``y_{n+1} = R(dt L) y_n`` for ``y' = L y`` (the polynomial, evaluated)."""
        return np.polyval(_poly(self), np.asarray(z, dtype=complex))

    def stability_polynomial(self, z):
        """``R(z) = 1 + z b^T (I - z A)^{-1} 1`` by the linear solve (a check of :meth:`stability_function`)."""
        A = np.array([list(r) + [0.0] * (self.stages - len(r)) for r in self.A])
        b = np.array(self.b)
        z = np.asarray(z, dtype=complex)
        out = np.empty_like(z)
        for idx, zi in np.ndenumerate(z):
            out[idx] = 1 + zi * b @ np.linalg.solve(np.eye(self.stages) - zi * A, np.ones(self.stages))
        return out

    @property
    def real_stability_bound(self):
        """``beta``: the extent of the stability region on the negative real axis (module docstring)."""
        return _real_bound(self)

    @property
    def optimal_rate(self):
        """``x* = argmin |R(-x)|`` over ``[0, beta]``: the ``dt lambda_max`` automatic gains aim at.

        Euler: ``R(-x) = 1 - x``, so ``x* = 1`` (the stiffest mode is removed in
        one step).  Heun: ``x* = 1`` (``|R| = 1/2``).  RK4: ``x* ~ 1.6``.
        """
        return _optimal_rate(self)


@functools.lru_cache(maxsize=None)
def _poly(sch):
    s = sch.stages
    A = np.array([list(r) + [0.0] * (s - len(r)) for r in sch.A], float)
    b = np.array(sch.b, float)
    v = np.ones(s)
    c = [1.0]
    for _ in range(s):
        c.append(float(b @ v))
        v = A @ v
    out = np.array(c[::-1])
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=None)
def _real_bound(sch, xmax=10.0, tol=1e-13):
    p = _poly(sch)

    def R(x):
        return np.abs(np.polyval(p, -np.asarray(x, float)))

    xs = np.linspace(0.0, xmax, 20001)
    bad = np.nonzero(R(xs) > 1 + 1e-12)[0]
    if bad.size == 0:
        return math.inf
    lo, hi = float(xs[bad[0] - 1]), float(xs[bad[0]])
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if R(mid) <= 1 + 1e-15:
            lo = mid
        else:
            hi = mid
    return lo


@functools.lru_cache(maxsize=None)
def _optimal_rate(sch):
    xs = np.linspace(0.0, sch.real_stability_bound, 20001)
    return float(xs[int(np.argmin(np.abs(np.polyval(_poly(sch), -xs))))])


EULER = ExplicitRungeKutta("euler", ((),), (1.0,), (0.0,), 1)
HEUN = ExplicitRungeKutta("heun", ((), (1.0,)), (0.5, 0.5), (0.0, 1.0), 2)
MIDPOINT = ExplicitRungeKutta("midpoint", ((), (0.5,)), (0.0, 1.0), (0.0, 0.5), 2)
RK3 = ExplicitRungeKutta("rk3", ((), (0.5,), (-1.0, 2.0)), (1 / 6, 2 / 3, 1 / 6), (0.0, 0.5, 1.0), 3)
RK4 = ExplicitRungeKutta(
    "rk4", ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)), (1 / 6, 1 / 3, 1 / 3, 1 / 6), (0.0, 0.5, 0.5, 1.0), 4
)

#: Butcher's 7-stage method of order 6 (J. C. Butcher, "On Runge--Kutta processes of high order",
#: J. Austral. Math. Soc. 4 (1964); Butcher, *Numerical Methods for ODEs*, 3rd ed., Sec. 325).
RK6 = ExplicitRungeKutta(
    "rk6",
    ((), (1 / 3,), (0.0, 2 / 3), (1 / 12, 1 / 3, -1 / 12), (-1 / 16, 9 / 8, -3 / 16, -3 / 8),
     (0.0, 9 / 8, -3 / 8, -3 / 4, 1 / 2), (9 / 44, -9 / 11, 63 / 44, 18 / 11, 0.0, -16 / 11)),
    (11 / 120, 0.0, 27 / 40, 27 / 40, -4 / 15, -4 / 15, 11 / 120),
    (0.0, 1 / 3, 2 / 3, 1 / 3, 1 / 2, 1 / 2, 1.0),
    6,
)

#: The 12-stage order-8 weights of Dormand & Prince's DOP853 (Hairer, Norsett & Wanner, *Solving
#: Ordinary Differential Equations I*, 2nd ed., II.10), used as a fixed-step method: the tableau
#: ``solve_ivp(method="DOP853")`` steps with (its embedded error estimators are not used here).
RK8 = ExplicitRungeKutta(
    "rk8",
    ((),
     (0.05260015195876773,),
     (0.0197250569845379, 0.0591751709536137),
     (0.02958758547680685, 0.0, 0.08876275643042054),
     (0.2413651341592667, 0.0, -0.8845494793282861, 0.924834003261792),
     (0.037037037037037035, 0.0, 0.0, 0.17082860872947386, 0.12546768756682242),
     (0.037109375, 0.0, 0.0, 0.17025221101954405, 0.06021653898045596, -0.017578125),
     (0.03709200011850479, 0.0, 0.0, 0.17038392571223998, 0.10726203044637328, -0.015319437748624402,
      0.008273789163814023),
     (0.6241109587160757, 0.0, 0.0, -3.3608926294469414, -0.868219346841726, 27.59209969944671,
      20.154067550477894, -43.48988418106996),
     (0.47766253643826434, 0.0, 0.0, -2.4881146199716677, -0.590290826836843, 21.230051448181193,
      15.279233632882423, -33.28821096898486, -0.020331201708508627),
     (-0.9371424300859873, 0.0, 0.0, 5.186372428844064, 1.0914373489967295, -8.149787010746927,
      -18.52006565999696, 22.739487099350505, 2.4936055526796523, -3.0467644718982196),
     (2.273310147516538, 0.0, 0.0, -10.53449546673725, -2.0008720582248625, -17.9589318631188,
      27.94888452941996, -2.8589982771350235, -8.87285693353063, 12.360567175794303, 0.6433927460157636)),
    (0.054293734116568765, 0.0, 0.0, 0.0, 0.0, 4.450312892752409, 1.8915178993145003, -5.801203960010585,
     0.3111643669578199, -0.1521609496625161, 0.20136540080403034, 0.04471061572777259),
    (0.0, 0.05260015195876773, 0.0789002279381516, 0.1183503419072274, 0.2816496580927726, 1 / 3, 0.25,
     4 / 13, 127 / 195, 0.6, 6 / 7, 1.0),
    8,
)

#: The explicit tableaux, in registry order.
TABLEAUX = (EULER, HEUN, MIDPOINT, RK3, RK4, RK6, RK8)
