"""The tracer's exact algebra on sums (:mod:`liefi.engine.symbolic`): cancellation and ``sin^2 + cos^2``.

A sum whose operands cancel in exact arithmetic is rebuilt from its reduced
polynomial form when that costs no more operations; the generated code then
computes the same function with fewer roundings.  Each test checks the
structure (what is left in the graph) and the values against numpy.  Fast: plain
Python, no compilation.
"""

from __future__ import annotations

import numpy as np

from liefi import scenes
from liefi.engine import codegen, kernels, symbolic, trace


def _generated(outputs, n_in):
    ns = {}
    exec(codegen.module_text(codegen.function_source("f", outputs), "python", False), ns)

    def f(y):
        out = np.empty(len(outputs))
        ns["f"](np.asarray(y, float), np.zeros(0), out)
        return out

    return f


def _inputs(src):
    return {f"y[{i}]" for i in range(8) if f"y[{i}]" in src}


def test_linear_cancellation_leaves_the_surviving_input():
    """``(2 b - c) + (c - b)`` is the node ``b`` (Suslov's ``xi_2 = (I^{-1} Pi)_2 - J e_2``)."""
    with trace.trace() as tr:
        a, b, c = tr.symbols("y", 3)
        assert (2.0 * b - c) + (c - b) is b
        assert (a * ((2.0 * b - c) + (c - b)) - a * b).op == "const"  # and what is built on it shares
        assert ((a + b) - (b + a)).op == "const"


def test_quadratic_cancellation_matches_numpy():
    """``(a^2 + b (2b - c) + c (c - b))/2 - (c - b)^2/2 = (a^2 + b^2)/2``: ``c`` disappears, the values agree."""
    with trace.trace() as tr:
        a, b, c = tr.symbols("y", 3)
        e = 0.5 * (a * a + b * (2.0 * b - c) + c * (c - b)) - 0.5 * (c - b) * (c - b)
        src = codegen.function_source("f", [e])
        f = _generated([e], 3)
    assert _inputs(src) == {"y[0]", "y[1]"}
    rng = np.random.default_rng(1)
    for _ in range(50):
        x, y, z = rng.normal(size=3)
        want = 0.5 * (x * x + y * (2 * y - z) + z * (z - y)) - 0.5 * (z - y) ** 2
        assert abs(f([x, y, z])[0] - want) <= 8 * np.finfo(float).eps * (x * x + 2 * y * y + 2 * z * z)


def test_coefficients_that_cancel_to_rounding_are_dropped():
    """``x (0.1 + 0.2) - 0.3 x``: the coefficients differ by one rounding, the term is gone; a real
    difference (``1.0000001 x - x``) stays."""
    with trace.trace() as tr:
        x, y = tr.symbols("y", 2)
        assert ((0.1 + 0.2) * x + y) - 0.3 * x is y
        kept = 1.0000001 * x - x
        assert kept.op == "sub"


def test_pythagoras():
    """``m sin^2 + m cos^2 = m`` (the Gram matrix of an orthonormal frame is constant); values agree."""
    with trace.trace() as tr:
        x, m, y = tr.symbols("y", 3)
        s, c = np.sin(x), np.cos(x)
        assert (s * s + c * c).op == "const" and (s * s + c * c).value == 1.0
        e = y + (m * s) * s + m * (c * c)
        g = 1.0 / (s * s + c * c) * (y * s)
        src = codegen.function_source("f", [e, g])
        f = _generated([e, g], 3)
    assert "math.cos" not in src and " / " not in src
    rng = np.random.default_rng(2)
    for _ in range(50):
        u, v, w = rng.normal(size=3)
        want = [w + v * np.sin(u) ** 2 + v * np.cos(u) ** 2, w * np.sin(u) / (np.sin(u) ** 2 + np.cos(u) ** 2)]
        assert np.allclose(f([u, v, w]), want, rtol=1e-15, atol=1e-15 * (abs(v) + abs(w)))


def test_a_reduction_that_costs_more_is_not_made():
    """``(a + b + c)(d + e + f) - a d`` has 8 monomials (15 operations) against 7 as traced: kept."""
    with trace.trace() as tr:
        a, b, c, d, e, f = tr.symbols("y", 6)
        left = (a + b + c) * (d + e + f)
        r = left - a * d
        assert r.op == "sub" and r.args[0] is left


def test_forms_are_bounded():
    """A product of two sums of 4 terms (16 monomials > FORM_TERMS) is an atom of the forms above it."""
    assert symbolic.FORM_TERMS < 16
    with trace.trace() as tr:
        y = tr.symbols("y", 8)
        p = (y[0] + y[1] + y[2] + y[3]) * (y[4] + y[5] + y[6] + y[7])
        assert symbolic._form(p) == {(p.id,): 1.0}
        assert (p + y[0]) - p is y[0]  # still exact on the atom


def test_reductions_reach_the_generated_fields():
    """The Suslov field has no ``xi_3 = 0`` and ``xi_2 = Pi_2`` terms left; the knife edge's ``C = sin^2 + cos^2``
    is gone: no division in its field."""
    sus = scenes.get("suslov")
    src = kernels.compile_split(sus.integrator(None, gains="auto", configuration=True), engine="python").kernel.text
    xrhs = src.split("def xrhs_s(")[1].split("return")[0]
    assert xrhs.count(" = ") == 21  # what one writes by hand: 6 operations per row of R, 3 on Pi
    knife = scenes.get("knife-edge")
    src = kernels.compile_feedback(knife.integrator(None), engine="python").kernel.text
    rhs = src.split("def rhs_s(")[1].split("return")[0]
    assert " / " not in rhs
