"""Schemes: one stepper protocol and one registry (:mod:`liefi.schemes.registry`).

* :mod:`~liefi.schemes.rk` -- explicit Runge--Kutta tableaux and their stability polynomials;
* :mod:`~liefi.schemes.split` -- the stiff-safe ``imex-*`` splits of the feedback field;
* :mod:`~liefi.schemes.dla` -- the discrete Lagrange--d'Alembert integrator;
* :mod:`~liefi.schemes.ivp` -- ``scipy:METHOD`` (``solve_ivp``'s public methods);
* :mod:`~liefi.schemes.core` -- :func:`integrate` (the batch-first fixed-step
  loop), :class:`Solution`, :class:`IntegrationError` and the one validator of
  run arguments (:func:`run_arguments`, :func:`steps_for`).

``get(name)`` and ``names(kind=None)`` read the registry.
"""

from .core import (  # noqa: F401
    MAX_STEPS,
    IntegrationError,
    Solution,
    _fail,
    integrate,
    positive_int,
    positive_number,
    run_arguments,
    steps_for,
)
from .registry import REGISTRY, describe, get, names
from .rk import EULER, HEUN, MIDPOINT, RK3, RK4, RK6, RK8, TABLEAUX, ExplicitRungeKutta

#: The explicit tableaux by name (the fixed-step schemes of the compiled engine).
SCHEMES = {s.name: s for s in TABLEAUX}


def get_scheme(scheme):
    """An explicit tableau from its name, or a stepper object (``step(f, y, dt)``, ``name``, ``stages``) itself.

    A split scheme steps a :class:`~liefi.FeedbackIntegrator`: pass its name to
    :meth:`~liefi.FeedbackIntegrator.run`, or ``get(name).bind(fi)`` here.
    """
    if not isinstance(scheme, str) and callable(getattr(scheme, "step", None)) and hasattr(scheme, "stages"):
        return scheme
    return get(scheme, kind="explicit")


__all__ = [
    "EULER", "HEUN", "MIDPOINT", "RK3", "RK4", "RK6", "RK8", "SCHEMES", "REGISTRY", "ExplicitRungeKutta", "IntegrationError",
    "Solution", "describe", "get", "get_scheme", "integrate", "names", "run_arguments", "steps_for",
]
