"""The code generator's loops and the tracer's small solves (fast: plain Python, no compilation).

The loops on local variables (:func:`liefi.engine.codegen.scalar_loop_source`)
take bit for bit the steps of the array loops (:func:`~liefi.engine.codegen.loop_source`);
2 x 2 and 3 x 3 traced solves are Cramer's rule (:mod:`liefi.engine.cramer`);
the tracer's sign rules change no value.  No test here asserts a time.
"""

from __future__ import annotations

import numpy as np
import pytest

from liefi import scenes
from liefi.engine import codegen, kernels, trace
from liefi.engine.cramer import cramer_solve
from liefi.schemes import SCHEMES
from liefi.schemes.split import SPLIT_SCHEMES


@pytest.mark.parametrize("k", [2, 3])
def test_cramer_solve_equals_numpy(k):
    rng = np.random.default_rng(k)
    for _ in range(20):
        A = rng.normal(size=(k, k)) + k * np.eye(k)
        X = rng.normal(size=(k, 2))
        got = cramer_solve(A, X).astype(float)
        assert np.max(np.abs(got - np.linalg.solve(A, X))) < 1e-13 * np.linalg.cond(A)


def test_cramer_solve_rejects_other_shapes():
    with pytest.raises(ValueError, match="k = 2 or 3"):
        cramer_solve(np.eye(4), np.ones((4, 1)))


def _generated(outputs, n_in, name="f"):
    ns = {}
    exec(codegen.module_text(codegen.function_source(name, outputs), "python", False), ns)

    def f(y):
        out = np.empty(len(outputs))
        ns[name](np.asarray(y, float), np.zeros(0), out)
        return out

    return f


@pytest.mark.parametrize("k", [2, 3])
def test_traced_small_solve_is_closed_form(k):
    """A traced 2 x 2 / 3 x 3 solve is ``adj(A) b / det A``: k divisions, numpy's solution to rounding."""
    rng = np.random.default_rng(10 + k)
    with trace.trace() as tr:
        y = tr.symbols("y", k * k + k)
        A = np.array(list(y[: k * k]), dtype=object).reshape(k, k)
        x = np.linalg.solve(A, np.array(list(y[k * k :]), dtype=object))
        src = codegen.function_source("f", x)
        f = _generated(list(x), k * k + k)
    assert src.count(" / ") == k
    for _ in range(10):
        A = rng.normal(size=(k, k)) + k * np.eye(k)
        b = rng.normal(size=k)
        assert np.max(np.abs(f(np.concatenate([A.ravel(), b])) - np.linalg.solve(A, b))) < 1e-13 * np.linalg.cond(A)


def test_sign_rules_are_exact_and_share_nodes():
    """``a (-b) + a b`` is 0, ``(-a)(-b)`` is the node ``a b``, ``a - (-b)`` is ``a + b``; values unchanged."""
    with trace.trace() as tr:
        a, b, c = tr.symbols("y", 3)
        assert (a * (-b) + a * b).op == "const"
        assert (-a) * (-b) is a * b
        assert a - (-b) is a + b
        assert (-a) - b is -(a + b)
        exprs = [(-a) * b / (-c) + a * (-c), (-a) - b * (-c), a + (-(b * c)), (-a) * (-(-b))]
        f = _generated(exprs, 3)
    rng = np.random.default_rng(0)
    for _ in range(20):
        x, y, z = rng.normal(size=3)
        want = [(-x) * y / (-z) + x * (-z), (-x) - y * (-z), x + (-(y * z)), (-x) * (-(-y))]
        assert np.array_equal(f([x, y, z]), np.array(want))


def _module(fi, split):
    cf = (kernels.compile_split if split else kernels.compile_feedback)(fi, engine="python")
    return cf, cf.module


def _old_loop(module, fname, scheme, N, split):
    """The array loop of :func:`codegen.loop_source` over the module's own ``rhs``/``xrhs``/``fstep``."""
    ns = dict(vars(module))
    exec(codegen.loop_source(fname, scheme, N, split=split), ns)
    return ns[fname]


@pytest.mark.parametrize("split", [False, True], ids=["explicit", "split"])
def test_scalar_loops_take_the_array_loops_steps_bit_for_bit(split):
    sc = scenes.get("suslov")
    fi = sc.integrator(None, gains="auto" if split else None, configuration=True)
    cf, mod = _module(fi, split)
    p = fi.parameters()
    y0 = fi.y0 + 1e-3 * np.arange(fi.n)
    n, dt = 7, 1e-2
    for sch in (SPLIT_SCHEMES.values() if split else SCHEMES.values()):
        name = codegen.split_loop_name(sch) if split else f"run_{sch.name}"
        tab = sch.explicit if split else sch
        outs = []
        for loop in (getattr(mod, name), _old_loop(mod, name + "_old", tab, fi.n, split)):
            out, bad, last = np.empty((fi.n, 5)), np.empty(fi.n), np.empty(fi.n)
            r = loop(y0, p, dt, n, 2, 3, out, bad, last, np.zeros(1), 0, 0.0)
            outs.append((tuple(r), out, last))
        (r1, o1, l1), (r2, o2, l2) = outs
        assert r1 == r2 == (0, n, 0)
        assert np.array_equal(o1, o2) and np.array_equal(l1, l2)


@pytest.mark.parametrize("check_every", [1, 3])
def test_scalar_loop_stops_at_the_first_non_finite_state_like_the_array_loop(check_every):
    """Same failing step, last good step and last good state (the scalar loop keeps the previous state in
    registers instead of storing it every step)."""
    sc = scenes.get("suslov")
    fi = sc.integrator(None, configuration=True)
    cf, mod = _module(fi, False)
    y0 = fi.y0.copy()
    y0[9] = 1e200  # overflows within a few steps
    res = []
    for loop in (mod.run_euler, _old_loop(mod, "run_euler_old", SCHEMES["euler"], fi.n, False)):
        out, bad, last = np.empty((fi.n, 11)), np.empty(fi.n), np.empty(fi.n)
        with np.errstate(all="ignore"):
            r = loop(y0, fi.parameters(), 1.0, 10, 1, check_every, out, bad, last, np.zeros(1), 0, 0.0)
        res.append((tuple(r), last.copy(), bad.copy()))
    assert res[0][0] == res[1][0] and res[0][0][0] > 0
    assert np.array_equal(res[0][1], res[1][1]) and np.all(np.isfinite(res[0][1]))
    assert np.array_equal(res[0][2], res[1][2], equal_nan=True)


def test_scalar_loop_reads_parameters_once_and_takes_no_modulo():
    src = codegen.scalar_loop_source("run_rk4", SCHEMES["rk4"], 3, 2)
    head, body = src.split("    for step in range(1, n_steps + 1):")
    assert "p_0 = p[0]" in head and "p[" not in body.split("def run_rk4_batch")[0]
    assert "%" not in src


def test_a_field_of_more_than_30_arguments_compiles_without_inlining():
    """numba cannot inline a call of 31+ arguments; a rolling body (25 states, 18 parameters) must still
    run compiled, not fall back to numpy with a CompilationWarning."""
    import warnings

    pytest.importorskip("numba")
    from liefi import scenes
    from liefi.engine.codegen import MAX_INLINE_ARGS

    sc = scenes.get("rolling-disk")
    fi = sc.integrator(None, configuration=True)
    assert fi.n + 18 > MAX_INLINE_ARGS  # the case this test is about
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sol = fi.run(0.01, dt=1e-3, scheme="imex-rk4", backend="numba", check_stability=False)
    assert sol.backend == "numba"
