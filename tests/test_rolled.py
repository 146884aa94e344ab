"""The split schemes' rolled loop of a large system (:mod:`liefi.engine.split_loops`), in plain Python (fast).

For more than ``MAX_INLINE_ARGS`` scalar arguments the split loops are one loop over the stages, the
tableau read at run time: far less source for numba to compile (the cold compile of a rolling body),
and the same arithmetic as the unrolled loop (:func:`liefi.engine.codegen.scalar_loop_source`), so the
same bits, the same failing step and the same last good state.
"""

from __future__ import annotations

import numpy as np
import pytest

from liefi.engine import codegen, split_loops
from liefi.schemes.split import SPLIT_SCHEMES

N, P = 20, 12  # N + P > MAX_INLINE_ARGS


def _field_source():
    """``xrhs_s`` and ``fstep_s`` of a nonlinear toy system of ``N`` states and ``P`` parameters."""
    ys = codegen.scalar_names("y", N)
    ps = codegen.scalar_names("p", P)
    x = [f"{ys[(i + 1) % N]} / (1.5 + {ys[(i + 1) % N]} * {ys[(i + 1) % N]}) * {ps[i % P]} - 0.3 * {ys[i]} * {ys[(i + 7) % N]}" for i in range(N)]
    f = [f"{ys[i]} / (1.0 + hh_0 * {ps[(i + 3) % P]} * {ys[i]} * {ys[i]})" for i in range(N)]
    head = ", ".join(ys + ps)
    return (f"@njit\ndef xrhs_s({head}):\n    return ({', '.join(x)})\n\n"
            f"@njit\ndef fstep_s({head}, hh_0):\n    return ({', '.join(f)})\n")


def _module(extra=""):
    ns = {}
    src = _field_source() + "\n" + split_loops.split_loops_source(N, P) + extra
    exec(codegen.module_text(src, "python", False), ns)
    return ns


def test_large_systems_get_one_rolled_loop_shared_by_the_schemes():
    assert N + P > codegen.MAX_INLINE_ARGS
    src = split_loops.split_loops_source(N, P)
    assert src.count("def split_loop(") == 1
    unrolled = "\n".join(codegen.scalar_loop_source(codegen.split_loop_name(s), s.explicit, N, P, split=True)
                         for s in SPLIT_SCHEMES.values())

    def operations(text):  # what numba types and lowers one by one: the cost of its compile
        return sum(text.count(op) for op in (" + ", " * ", " - ", " / "))

    assert operations(src) < operations(unrolled) / 10
    small = split_loops.split_loops_source(3, 2)  # small systems keep the unrolled loops (registers)
    assert "def split_loop(" not in small


def _old(ns):
    extra = "\n".join(codegen.scalar_loop_source("old_" + codegen.split_loop_name(s)[4:], s.explicit, N, P, split=True)
                      for s in SPLIT_SCHEMES.values())
    old = {}
    exec(codegen.module_text(_field_source() + "\n" + extra, "python", False), old)
    return old


@pytest.mark.parametrize("check_every", [1, 3])
def test_rolled_loop_takes_the_unrolled_loops_steps_bit_for_bit(check_every):
    ns = _module()
    old = _old(ns)
    rng = np.random.default_rng(0)
    y0, p = rng.normal(size=N), rng.normal(size=P)
    n = 7
    for s in SPLIT_SCHEMES.values():
        name = codegen.split_loop_name(s)
        got = []
        for loop in (ns[name], old["old_" + name[4:]]):
            out, bad, last = np.empty((N, 5)), np.empty(N), np.empty(N)
            r = loop(y0, p, 1e-2, n, 2, check_every, out, bad, last, np.zeros(1), 0, 0.0)
            got.append((tuple(r), out, last))
        (r1, o1, l1), (r2, o2, l2) = got
        assert r1 == r2 == (0, n, 0), s.name
        assert np.array_equal(o1, o2) and np.array_equal(l1, l2), s.name


@pytest.mark.parametrize("check_every", [1, 3])
def test_rolled_loop_stops_at_the_first_non_finite_state_like_the_unrolled_loop(check_every):
    ns = _module()
    old = _old(ns)
    y0, p = np.full(N, 0.5), np.full(P, 1.0)
    y0[4] = 1e200  # overflows within a few steps
    res = []
    for loop in (ns["run_imex_rk4"], old["old_imex_rk4"]):
        out, bad, last = np.empty((N, 11)), np.empty(N), np.empty(N)
        with np.errstate(all="ignore"):
            r = loop(y0, p, 1.0, 10, 1, check_every, out, bad, last, np.zeros(1), 0, 0.0)
        res.append((tuple(r), last.copy(), bad.copy()))
    assert res[0][0] == res[1][0] and res[0][0][0] > 0
    assert np.array_equal(res[0][1], res[1][1]) and np.all(np.isfinite(res[0][1]))
    assert np.array_equal(res[0][2], res[1][2], equal_nan=True)
