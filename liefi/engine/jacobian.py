"""The exact Jacobian of the feedback field, for implicit solvers (``solve_ivp(..., jac=fi.jac)``).

The field ``f(y) = X(y) - A grad V(y)`` of :meth:`liefi.FeedbackIntegrator.vector_field`
is traced once on symbolic ``y`` and ``p`` (the same trace as the compiled
kernel, :func:`liefi.engine.compile_feedback`), differentiated symbolically
(:func:`liefi.engine.trace.jacobian`: forward differentiation of the recorded
graph, exact), and the ``n x n`` entries ``df_i/dy_j`` are generated as one
straight-line function.  The data's own ``x``-derivatives enter the trace as
traced derivatives of the traced data, so second derivatives of the data are
exact too (a complex step through the numpy field would nest two complex steps
wherever the data depend on ``x``, which is not exact).

The function runs as plain Python by default (an implicit solver evaluates the
Jacobian rarely, and numba would spend seconds compiling it);
``engine="numba"`` compiles it.
"""

from __future__ import annotations

import numpy as np

from .kernels import _field_kernel
from .trace import TRACED_DATA, NotCompilable, jacobian, traced_call

#: engine of the Jacobian kernel by default (see the module docstring)
DEFAULT_ENGINE = "python"


def compile_jacobian(fi, *, engine=DEFAULT_ENGINE):
    """The generated Jacobian ``jac(y, p, out)`` of ``fi``'s feedback field (``out`` of length ``n * n``, row-major).

    Returns a :class:`~liefi.engine.CompiledField` whose module holds ``jac``;
    raises :class:`~liefi.engine.NotCompilable` naming what cannot be traced.
    """

    def make(tr):
        y = tr.symbols("y", fi.n)
        size = fi.parameter_layout.size
        p = tr.symbols("p", size)
        f = traced_call("the feedback field", fi.vector_field, y, p, data=TRACED_DATA)
        J = jacobian(np.asarray(f, dtype=object), list(y)).T  # J[i, j] = d f_i / d y_j
        from .codegen import NJIT, function_source

        return NJIT + function_source("jac", J.reshape(-1)), size, "jacobian", 0

    return _field_kernel(fi, "jacobian", engine, make)


def field_jacobian(fi, y, *, engine=DEFAULT_ENGINE):
    """``df/dy`` of ``fi.vector_field`` at ``y`` (``(n,)`` -> ``(n, n)``; a batch ``(..., n)`` -> ``(..., n, n)``).

    Exact to rounding (module docstring), at the integrator's current gains and
    targets (:meth:`~liefi.FeedbackIntegrator.parameters`).
    """
    y = np.asarray(y, dtype=float)
    if y.shape[-1:] != (fi.n,):
        raise ValueError(f"y: expected a state of {fi.n} numbers {fi.names}, got shape {y.shape}")
    p = np.ascontiguousarray(fi.parameters(), dtype=float)
    if p.ndim != 1:
        raise ValueError("jac: the integrator has a target per trajectory (a batch y0); build it from one state "
                         "to evaluate its Jacobian")
    try:
        cf = compile_jacobian(fi, engine=engine)
    except NotCompilable as exc:
        raise ValueError(f"jac: the field of this system cannot be traced ({exc}), so liefi has no exact "
                         "Jacobian for it; call solve_ivp without jac= (finite differences)") from exc
    n = fi.n
    flat = y.reshape(-1, n)
    out = np.empty((flat.shape[0], n * n))
    for i, yi in enumerate(flat):
        cf._first_call("jac", "jac", np.ascontiguousarray(yi), p, out[i])
    return out.reshape(y.shape[:-1] + (n, n))
