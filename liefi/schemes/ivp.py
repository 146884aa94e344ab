"""``scipy:METHOD``: the methods of ``scipy.integrate.solve_ivp`` (its public API only) as schemes.

An adaptive method has no fixed ``dt``: its "step" is a whole ``solve_ivp``
call.  The explicit ones (RK23, RK45, DOP853) have a bounded stability region
like the tableaux of :mod:`liefi.schemes.rk`: with stiff gains their step size
collapses to ``~ beta / lambda_max`` and a run takes minutes, so the run module
estimates the stiffness before calling them.  Radau, BDF and LSODA are
stiff-safe (implicit, or switching to BDF).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ScipyMethod:
    """``solve_ivp(..., method=method)`` as a scheme of the registry.

    Attributes
    ----------
    method : str
        The ``solve_ivp`` method name.
    order : int
        The order of the method (of its propagated solution).
    stiff_safe : bool
        Implicit (or stiffness-switching): stable for any gain.
    """

    method: str
    order: int
    stiff_safe: bool

    kind = "scipy"

    @property
    def tableau(self):
        """The explicit pair's propagating tableau (from scipy's public solver class), ``None`` if implicit."""
        if self.stiff_safe:
            return None
        import scipy.integrate

        from .rk import ExplicitRungeKutta

        M = getattr(scipy.integrate, self.method)
        n = M.n_stages
        A = np.asarray(M.A)[:n, :n]
        return ExplicitRungeKutta(self.name, tuple(tuple(A[i, :i]) for i in range(n)), tuple(M.B), tuple(M.C[:n]),
                                  int(M.order))

    @property
    def real_stability_bound(self):
        """``beta`` of the propagating tableau (RK23 2.51, RK45 3.31, DOP853 6.39); ``inf`` when stiff-safe."""
        tab = self.tableau
        return math.inf if tab is None else tab.real_stability_bound

    @property
    def name(self):
        return f"scipy:{self.method}"

    @property
    def optimal_rate(self):
        return math.nan  # adaptive: no fixed dt to match the gains to

    def solve(self, fun, t_final, y0, *, t_eval=None, rtol=1e-9, atol=1e-12, max_evaluations=None):
        """``solve_ivp(fun, (0, t_final), y0, method=...)``; returns ``(sol, cpu_seconds)``.

        ``max_evaluations``: a bound on the evaluations of ``fun``.  Every 256 evaluations the
        count, and past the first 4096 also the run's total projected from its pace,
        ``n_total ~ n t_final / t`` (``t`` the latest time reached), are compared with it; past
        it the run stops at once with an :class:`EvaluationBudgetError` that gives both.
        """
        from scipy.integrate import solve_ivp

        T = float(t_final)
        if max_evaluations is not None:
            fun = _budgeted(fun, T, float(max_evaluations), self.name, rtol)
        start = time.process_time()
        sol = solve_ivp(fun, (0.0, T), np.asarray(y0, float), method=self.method, t_eval=t_eval,
                        rtol=rtol, atol=atol)
        return sol, time.process_time() - start

    def step(self, fun, t_final, y0, **kwargs):
        """The protocol's ``step``: one adaptive ``solve_ivp`` call over ``[0, t_final]`` (see :meth:`solve`)."""
        return self.solve(fun, t_final, y0, **kwargs)


class EvaluationBudgetError(ValueError):
    """An adaptive ``scipy:`` run would take more evaluations of the field than its bound (``max_evaluations``)."""


def _budgeted(fun, t_final, limit, name, rtol):
    """``fun`` counting its calls; raises :class:`EvaluationBudgetError` when the count, or its
    projection ``n t_final / t`` from the latest time ``t`` reached, passes ``limit``."""
    state = {"n": 0, "t": 0.0}

    def counted(t, y):
        state["n"] += 1
        n = state["n"]
        state["t"] = max(state["t"], float(t))
        if n % 256 == 0:
            projected = math.inf if state["t"] <= 0 else n * t_final / state["t"]
            if n > limit or (n >= 4096 and projected > limit):
                raise EvaluationBudgetError(
                    f"scheme: {name} at rtol {float(rtol):g} would need about {min(projected, 1e300):.3g} evaluations "
                    f"of the field over t in [0, {t_final:g}] (at its pace: {n} by t = {state['t']:.3g}), more than "
                    f"the {limit:.3g} liefi allows a scipy run; stopped. Loosen rtol, take a shorter horizon, or "
                    "use a higher-order method (scipy:DOP853) or liefi's own (imex-rk8)"
                )
        return fun(t, y)

    return counted


#: ``solve_ivp``'s methods (``scipy.integrate.solve_ivp``'s documented ``method`` names).
SCIPY_METHODS = (
    ScipyMethod("RK23", 3, False),
    ScipyMethod("RK45", 5, False),
    ScipyMethod("DOP853", 8, False),
    ScipyMethod("Radau", 5, True),
    ScipyMethod("BDF", 5, True),
    ScipyMethod("LSODA", 12, True),
)
