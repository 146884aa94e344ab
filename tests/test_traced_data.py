"""The tracer's data accessor (:class:`liefi.engine.trace.TracedData`) at composite points.

``value_and_derivative(datum, x)`` and ``value_and_gradient(fun, z)`` give the partial derivatives in
the entries of the point.  At a point of distinct input symbols they are read off the graph; at a
composite point (entries that are expressions of other symbols, or repeated ones: a Runge--Kutta stage
``y + dt a k``, a reduced state made of the configuration) the graph of ``fun(x)`` need not pass through
the entries' nodes (the tracer simplifies sums into their atoms), and they were read as zeros.  Each
case compares the generated code with the exact derivative.  Fast: plain Python, no compilation.
"""

from __future__ import annotations

import numpy as np
import pytest

from liefi._data import DataFunction
from liefi.engine import codegen, trace


def _fun(x):
    return np.stack([x[..., 0] ** 2 * x[..., 1], np.sin(x[..., 1]) + x[..., 0]], -1)


def _exact(x):
    """``d fun_i / d x_k`` as ``(k, i)``."""
    return np.array([[2 * x[0] * x[1], 1.0], [x[0] ** 2, np.cos(x[1])]])


def _generated(outputs, y):
    ns = {}
    flat = list(np.asarray(outputs, dtype=object).reshape(-1))
    exec(codegen.module_text(codegen.function_source("f", flat), "python", False), ns)
    out = np.empty(len(flat))
    ns["f"](np.asarray(y, float), np.zeros(0), out)
    return out.reshape(np.shape(outputs))


POINTS = {
    "symbols": lambda y: [y[0], y[1]],
    "sums": lambda y: [y[0] + y[1], 2.0 * y[1]],  # a stage-like point: the entries' nodes are not atoms
    "repeated": lambda y: [y[0], y[0]],
    "constant entry": lambda y: [y[0] * y[1], 0.5],
}


def _point(kind, yv):
    return np.array(POINTS[kind](yv), dtype=float)


@pytest.mark.parametrize("kind", list(POINTS))
@pytest.mark.parametrize("analytic", [False, True])
def test_value_and_derivative_at_a_point_built_from_the_inputs(kind, analytic):
    deriv = (lambda x: np.stack([np.stack([2 * x[..., 0] * x[..., 1], np.ones_like(x[..., 0])], -1),
                                 np.stack([x[..., 0] ** 2, np.cos(x[..., 1])], -1)], -2)) if analytic else None
    datum = DataFunction(_fun, (2,), 2, "demo", derivative=deriv)
    yv = np.array([0.3, 0.7])
    with trace.trace() as tr:
        y = tr.symbols("y", 2)
        x = np.empty(2, dtype=object)
        x[:] = POINTS[kind](y)
        val, der = trace.TRACED_DATA.value_and_derivative(datum, x)
        got_val, got_der = _generated(val, yv), _generated(der, yv)
    xv = _point(kind, yv)
    np.testing.assert_allclose(got_val, _fun(xv), rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(got_der, _exact(xv), rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("kind", list(POINTS))
def test_value_and_gradient_at_a_point_built_from_the_inputs(kind):
    def h(z):
        return z[..., 0] ** 3 + z[..., 0] * np.exp(z[..., 1])

    yv = np.array([0.3, 0.7])
    with trace.trace() as tr:
        y = tr.symbols("y", 2)
        z = np.empty(2, dtype=object)
        z[:] = POINTS[kind](y)
        val, g = trace.TRACED_DATA.value_and_gradient(h, z)
        got_val, got_g = _generated(np.atleast_1d(val), yv), _generated(g, yv)
    zv = _point(kind, yv)
    np.testing.assert_allclose(got_val, [h(zv)], rtol=1e-15)
    np.testing.assert_allclose(got_g, [3 * zv[0] ** 2 + np.exp(zv[1]), zv[0] * np.exp(zv[1])], rtol=1e-14)
