"""The data functions ``from_mechanics`` generates from sympy expressions (``liefi.systems._sympy_code``, issue 25's
build time): liefi's own code, printed by the printer of the compiled engine's graphs, instead of sympy's
``lambdify``; the values agree with ``lambdify``'s to rounding, on real, complex and traced inputs."""

from __future__ import annotations

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")

from liefi.systems._sympy_code import source, sympy_function, _graph  # noqa: E402
from liefi.systems.sympy_input import lambdify_checked  # noqa: E402

x, y, z = sympy.symbols("x y z")
k = sympy.Symbol("k", positive=True)

#: every kind of node the walk prints: sums with negative terms, products with denominators, powers (1/2, -1/2,
#: negative integers, rationals, symbolic), numbers (Rational, Float, pi, E), the elementary functions
EXPRS = [
    x + y - 2 * z, -x * y / z**2, sympy.sqrt(x * y) + 1 / sympy.sqrt(z), x**-3 + y**sympy.Rational(3, 2),
    sympy.Rational(1, 3) * x - sympy.Float("0.1234567890123456789") * y, sympy.pi * x + sympy.E, x**y,
    sympy.sin(x) * sympy.cos(y) - sympy.tan(z), sympy.exp(-x * k) * sympy.log(y), sympy.asin(x / 3) + sympy.acos(y / 3),
    sympy.atan(x) + sympy.sinh(y) * sympy.cosh(z) - sympy.tanh(x), sympy.asinh(x) + sympy.acosh(1 + y) + sympy.atanh(z / 3),
    (sympy.sin(x) ** 2 + sympy.cos(x) ** 2) / (x * y * z), sympy.Integer(7), -sympy.Rational(5, 2),
    -sympy.sin(x) / (y**2 * sympy.cos(z)),
]


def _values(f, pts, n):
    return np.array([np.broadcast_to(np.asarray(v), np.shape(pts[0])) for v in f(*pts)]).reshape(n, -1)


@pytest.mark.parametrize("complex_step", [False, True])
def test_generated_functions_agree_with_lambdify_to_rounding(complex_step):
    rng = np.random.default_rng(1)
    args = [x, y, z, k]
    f = sympy_function(sympy, args, EXPRS, "test")
    # sympy's own lambdify of the symbols as named (lambdify_checked dummifies them, which reorders the sums:
    # agreement to rounding of a cancellation, x + y - 2 z, then depends on the dummies' names)
    g = sympy.lambdify(args, EXPRS, modules=[np], cse=True)
    pts = [rng.uniform(0.2, 0.9, 50) for _ in args]
    if complex_step:  # liefi's complex-step derivatives: the imaginary parts are the derivatives, exact too
        pts = [p + 1e-30j * rng.uniform(0.5, 1.5, 50) for p in pts]
    a, b = _values(f, pts, len(EXPRS)), _values(g, pts, len(EXPRS))
    assert a.dtype == b.dtype
    np.testing.assert_allclose(a.real, b.real, rtol=4e-15, atol=0)
    np.testing.assert_allclose(a.imag, b.imag, rtol=1e-13, atol=0)  # derivatives: cancellations


def test_the_code_is_one_assignment_per_distinct_subexpression_and_names_nothing_of_the_model():
    """A shared subexpression is computed once (the cse ``lambdify(cse=True)`` ran sympy's for), and a symbol
    named as code (``__import__('os')``) is an argument ``a0`` like any other."""
    evil = sympy.Symbol("__import__('os').system('echo no')")
    s = sympy.sin(evil * y)
    nodes = _graph(sympy, [evil, y], [s + 1, s * y, s**2])
    src = source(nodes[:1] + nodes[2:], 2)
    assert src.count("math.sin(") == 1 and "import" not in src and "os" not in src
    f = sympy_function(sympy, [evil, y], [s + 1, s**2], "test")
    np.testing.assert_allclose(f(np.array(0.5), np.array(2.0)), [np.sin(1.0) + 1, np.sin(1.0) ** 2], rtol=1e-15)


def test_a_node_liefi_does_not_print_goes_to_lambdify_with_its_checks():
    f = sympy_function(sympy, [x], [sympy.sign(x) * x, sympy.Piecewise((x, x > 0), (0, True))], "test")
    np.testing.assert_array_equal(np.array(f(np.array([-2.0, 3.0]))), [[2.0, 3.0], [0.0, 3.0]])
    with pytest.raises(ValueError, match="metric: depends on"):
        sympy_function(sympy, [x], [x * y], "metric")
    with pytest.raises(ValueError, match="undefined function"):
        sympy_function(sympy, [x], [sympy.Function("f")(x)], "metric")


def test_traced_inputs_give_the_graph_of_the_same_values():
    """The compiled engine calls the data functions on object arrays of traced scalars; the graph it records,
    printed by its own code generator, computes the same values."""
    import math

    from liefi.engine.codegen import function_source
    from liefi.engine.trace import trace

    f = sympy_function(sympy, [x, y, z, k], EXPRS, "test")
    point = np.array([0.3, 0.5, 0.7, 0.6])
    with trace() as tr:
        v = tr.symbols("v", 4)
        out = f(*[v[i : i + 1] for i in range(4)])
        src = function_source("g", [np.asarray(o).reshape(-1)[0] for o in out], args=("v", "out"))
    namespace = {"math": math}
    exec(src, namespace)
    got = np.empty(len(EXPRS))
    namespace["g"](point, got)
    np.testing.assert_allclose(got, np.array(f(*point), float), rtol=1e-15)


def test_from_mechanics_builds_the_corpus_without_lambdify(monkeypatch):
    """Issue 25's build time: ``lambdify`` (sympy's cse, printers and their import) was 30-50 % of a build."""
    import sys

    from test_mechanics_minimal import disc_kane

    import liefi

    def refused(*a, **k):
        raise AssertionError("sympy.lambdify called")

    lam = sys.modules["sympy.utilities.lambdify"]

    made = disc_kane()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    monkeypatch.setattr(lam, "lambdify", refused)
    monkeypatch.setattr(sympy, "lambdify", refused)
    system = liefi.from_mechanics(model, consts)
    z = system.state([0.1, 0.4, 0.2], u=[0.3, -0.2, 1.1])
    assert np.all(np.isfinite(system.constrained_vector_field(z)))


def test_from_mechanics_pauses_the_garbage_collector_and_resumes_it_even_on_an_error(monkeypatch):
    """A quarter to a third of a build was cyclic collections walking every sympy object of the process."""
    import gc

    import liefi
    import liefi.systems.mechanics as mech

    from test_mechanics_minimal import sleigh_minimal

    made = sleigh_minimal()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    during, real = [], mech.sympy_function
    monkeypatch.setattr(mech, "sympy_function", lambda *a: during.append(gc.isenabled()) or real(*a))
    assert gc.isenabled()
    liefi.from_mechanics(model, consts)
    assert during and not any(during) and gc.isenabled()
    with pytest.raises(ValueError, match="constants"):
        liefi.from_mechanics(model, {"no such symbol": 1.0})
    assert gc.isenabled()


#: the corpus of issue 25's build-time table (benchmarks/build_time.py): (test module, factory)
CORPUS = [("test_mechanics_holonomic", f) for f in ("kane_pendulum", "lagrange_pendulum", "four_bar", "four_bar_gravity",
                                                    "disc_on_incline", "lagrange_sleigh", "system_sleigh")] + [
    ("test_mechanics_minimal", f) for f in ("disc_kane", "disc_kane_aux", "disc_lagrange", "disc_system", "sleigh_minimal",
                                            "rattleback")]


@pytest.mark.slow
@pytest.mark.parametrize("module, factory", CORPUS, ids=[f for _, f in CORPUS])
def test_every_data_function_of_the_corpus_agrees_with_lambdify(monkeypatch, module, factory):
    """Each function ``from_mechanics`` generates, against ``lambdify(cse=True)`` of the same expressions, at random
    real and complex points (1.3e-15 relative at most over the 14 models when written)."""
    import importlib

    import liefi
    import liefi.systems.mechanics as mech

    made = getattr(importlib.import_module(module), factory)()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    calls, real = [], mech.sympy_function
    monkeypatch.setattr(mech, "sympy_function", lambda sp, a, e, w: calls.append((list(a), list(e))) or real(sp, a, e, w))
    liefi.from_mechanics(model, consts)
    assert calls
    rng = np.random.default_rng(2)
    for args, exprs in calls:
        f, g = real(sympy, args, exprs, "test"), lambdify_checked(sympy, args, exprs, "test", cse=True, dummify=True)
        for step in (0.0, 1e-30j):
            pts = [rng.uniform(0.3, 1.3, 20) + step for _ in args]
            a, b = _values(f, pts, len(exprs)), _values(g, pts, len(exprs))
            scale = np.maximum(np.abs(b.real), 1.0)
            assert np.max(np.abs(a.real - b.real) / scale) < 1e-14
            if step:
                assert np.max(np.abs(a.imag - b.imag) / np.maximum(np.abs(b.imag), 1e-30)) < 1e-12
