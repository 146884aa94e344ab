"""Tracing grows with the system, not its cube (issue 26): the chain of knife edges of ``benchmarks/scale.py``.

The work of a trace is the number of symbolic operations the tracer performs (every ``+ - * /`` on traced
scalars first tries constant folding, :func:`liefi.engine.symbolic._folded`): numpy's dense ``@`` on the
chain's mostly-zero data made it grow like ``N^4`` (``dE @ m`` in :func:`liefi.reduction.core.evaluate`).
Structural, not a wall-clock time.
"""

import importlib.util
import os

import numpy as np
import pytest

import liefi
from liefi import _sparse
from liefi.engine import cache, kernels, symbolic

_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks", "scale.py")


@pytest.fixture(scope="module")
def chain():
    spec = importlib.util.spec_from_file_location("scale_benchmark", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.chain


class _Stop(Exception):
    pass


def _trace_work(chain, N, monkeypatch):
    """``(operations, characters of generated code)`` of the split kernel's trace of the chain of ``N``."""
    system, y0 = chain(N)
    fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=10.0)
    count, size = [0], [0]
    folded = symbolic._folded

    def counted(a, b, ufunc):
        count[0] += 1
        return folded(a, b, ufunc)

    def no_load(source, engine="numba"):
        size[0] = len(source)
        raise _Stop

    monkeypatch.setattr(symbolic, "_folded", counted)
    monkeypatch.setattr(cache, "load", no_load)
    with pytest.raises(_Stop):
        kernels.compile_split(fi, engine="python")
    monkeypatch.undo()
    return count[0], size[0]


def test_trace_of_the_chain_grows_subquadratically(chain, monkeypatch):
    """From ``N = 4`` to ``N = 8`` the tracer's operations and the generated code grow less than 4x
    (``N^2``); the dense products made the operations grow ~12x."""
    ops4, code4 = _trace_work(chain, 4, monkeypatch)
    ops8, code8 = _trace_work(chain, 8, monkeypatch)
    assert ops8 < 3 * ops4, (ops4, ops8)  # N^1.6 at most
    assert code8 < 3 * code4, (code4, code8)


def test_sparse_products_build_numpy_s_expressions():
    """:func:`liefi._sparse.matmul` and :func:`~liefi._sparse.quadratic` on traced arrays with exact zeros
    build the very nodes numpy's dense loops build (hash-consed: the same objects), and on floats they are
    numpy's operations."""
    rng = np.random.default_rng(3)
    A0, B0, w0 = rng.standard_normal((2, 3, 4)), rng.standard_normal((4, 5)), rng.standard_normal(4)
    A0[A0 < 0.3] = 0.0
    B0[B0 < 0] = 0.0
    with liefi.engine.trace.trace() as tr:
        x = tr.symbols("x", 4)
        A = np.empty(A0.shape, dtype=object)
        for idx in np.ndindex(*A0.shape):
            A[idx] = symbolic.mul(A0[idx], x[idx[-1]]) if A0[idx] else symbolic.const(0.0)
        B = B0.astype(object)
        C = np.empty((4, 4, 4), dtype=object)
        C[...] = symbolic.const(0.0)
        C[0, 1, 2], C[3, 0, 0] = x[1], symbolic.mul(x[0], x[2])
        dense, sparse = A @ B, _sparse.matmul(A, B)
        for idx in np.ndindex(*dense.shape):
            d = symbolic.as_sym(dense[idx])
            assert symbolic.as_sym(sparse[idx]) is d or (d.op == "const" and d.value == 0.0
                                                        and float(sparse[idx]) == 0.0)
        dq, sq = np.einsum("...i,...kij,...j->...k", x, C, x), _sparse.quadratic(x, C)
        for k in range(4):
            d = symbolic.as_sym(dq[k])
            assert symbolic.as_sym(sq[k]) is d or (d.op == "const" and float(sq[k]) == 0.0)
    assert np.array_equal(_sparse.matmul(A0, B0), A0 @ B0)
    C0 = np.zeros((4, 4, 4))
    C0[0, 1, 2], C0[3, 0, 0] = 1.5, -0.25
    assert np.array_equal(_sparse.quadratic(w0, C0), np.einsum("...i,...kij,...j->...k", w0, C0, w0))
    assert np.array_equal(_sparse.matvec("...ji,...j->...i", B0, w0[:4] @ np.ones((4, 4))[:, :4]),
                          np.einsum("...ji,...j->...i", B0, w0[:4] @ np.ones((4, 4))[:, :4]))


def test_the_guard_s_eigenvalues_of_a_large_system_cost_a_fixed_number_of_field_evaluations(chain):
    """Above 64 states the eigenvalues of ``dX/dy`` come from Jacobian-vector products (Arnoldi): at most
    ``2 KRYLOV_DIM`` evaluations of ``X`` per state, not ``2n`` (central differences along every coordinate,
    whose batch made the chain of 32 knife edges' first run take 21 s and 3.7 GB), with the same spectral
    radius and growth as the dense Jacobian."""
    from liefi.integrator import _krylov, stability

    system, y0 = chain(12)  # 72 states
    fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=10.0)
    Y = np.stack([y0, y0 + 0.01 * np.sin(np.arange(y0.size))])
    seen = [0]
    field = fi.unforced_vector_field

    def counted(y, *a, **k):
        seen[0] += int(np.prod(np.shape(y)[:-1]))
        return field(y, *a, **k)

    fi.unforced_vector_field = counted
    ev = stability._dynamics_eigenvalues(fi, Y)
    assert seen[0] <= 2 * _krylov.KRYLOV_DIM * len(Y) < 2 * fi.n * len(Y)
    fi.unforced_vector_field = field
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(_krylov, "DENSE_MAX_STATES", 10**6)
        dense = stability._dynamics_eigenvalues(fi, Y)
    np.testing.assert_allclose(np.max(np.abs(ev), -1), np.max(np.abs(dense), -1), rtol=1e-4)
    for dt in (0.1, 1.0, 1.5):
        assert abs(stability.dynamics_growth("rk4", dt, ev) - stability.dynamics_growth("rk4", dt, dense)) < 1e-4


def test_checking_a_system_s_data_calls_them_a_number_of_times_independent_of_their_size():
    """The checks at construction (complex step against central differences, the imaginary part kept) take the
    ``2n`` differences in two calls on a batch of directions: one call per direction made the chain of 32 knife
    edges' construction 1.9 s (``N^2.75``: ``N`` stacks per call of its constraint, ``6N`` calls per probe)."""
    calls = {}

    def build(n):
        count = [0]

        def constraint(q):
            count[0] += 1
            row = [np.cos(q[..., 0]), np.sin(q[..., 0])] + [q[..., k] * 0.0 for k in range(2, n)]
            return np.stack(row, -1)[..., None, :]

        def potential(q):
            return 0.5 * np.sum(q**2, -1)

        liefi.NonholonomicSystem(liefi.CotangentBundle(n), np.eye(n), constraint, potential)
        calls[n] = count[0]

    build(3)
    build(24)
    assert calls[24] == calls[3], calls


def test_the_numpy_field_of_a_large_system_takes_the_curvature_term_without_dense_products(chain, monkeypatch):
    """``0.5 w^T dC_k w`` of ``d ht / dx`` as ``(w^T dE_k) . (m E^T w)`` above ``_DENSE_DC_PRODUCTS``: ``n K D``
    products a state, not the ``n K D^2`` of ``dE m`` (the chain of 64 knife edges' first run spent 2 of its
    2.5 minutes there); the same values to rounding."""
    from liefi.reduction import core

    system, y0 = chain(16)
    Y = y0 + 0.1 * np.random.default_rng(1).standard_normal((3, y0.size))  # off J = 0: w != 0
    shapes = []
    matmul = _sparse.matmul

    def recorded(a, b):
        shapes.append(np.shape(a))
        return matmul(a, b)

    monkeypatch.setattr(_sparse, "matmul", recorded)
    fast = core.evaluate(system, Y)
    n, K, D = system.space.data_dim, system.K, system.space.D
    assert n * K * D * D > 10**6 and not any(s[-3:] == (n, K, D) for s in shapes), shapes
    monkeypatch.setattr(core, "_DENSE_DC_PRODUCTS", 10**15, raising=False)
    dense = core.evaluate(system, Y)
    np.testing.assert_allclose(fast.dht, dense.dht, rtol=0, atol=1e-14 * np.max(np.abs(dense.dht)))


def test_the_zero_masks_of_the_chain_s_trace_cost_a_python_call_per_distinct_object_not_per_entry(
        chain, monkeypatch):
    """:func:`liefi._sparse._kinds` classifies the entries of the traced arrays by identity (most are one
    shared zero): on the chain of 8 its Python calls (``type``, ``id``, ``_kind``) are at most two per
    distinct object plus one per peel, far fewer than its entries (a call of ``type`` and ``id`` per entry
    made it 60 % of the chain's trace at ``N = 64``: ``dE`` holds ``9 N^3`` entries)."""
    calls, entries, distinct, arrays = [0], [0], [0], [0]

    def counting(f):
        def g(*a):
            calls[0] += 1
            return f(*a)
        return g

    kinds = _sparse._kinds

    def counted_kinds(a):
        entries[0] += a.size
        distinct[0] += len({id(v) for v in a.reshape(-1)})
        arrays[0] += 1
        return kinds(a)

    monkeypatch.setattr(_sparse, "_TYPE", np.frompyfunc(counting(type), 1, 1))
    monkeypatch.setattr(_sparse, "_ID", np.frompyfunc(counting(id), 1, 1))
    monkeypatch.setattr(_sparse, "_kind", counting(_sparse._kind))
    monkeypatch.setattr(_sparse, "_kinds", counted_kinds)
    _trace_work(chain, 8, monkeypatch)
    bound = 2 * distinct[0] + _sparse._PEELS * arrays[0]
    assert entries[0] > 3 * bound, (entries, distinct, arrays)  # dE alone: 24 x 8 x 24 entries, 17 objects
    assert calls[0] <= bound, (calls, entries, distinct, arrays)


def test_the_zero_masks_are_those_of_each_entry():
    """:func:`liefi._sparse._kinds` is :func:`~liefi._sparse._kind` of every entry, whatever the layout
    (more distinct objects than it peels off, distinct float objects, strided views, one entry, 0-d)."""
    rng = np.random.default_rng(7)
    with liefi.engine.trace.trace() as tr:
        x = list(tr.symbols("x", 12))
        pool = x + [symbolic.const(0.0), symbolic.const(2.0), symbolic.const(np.inf), 0.0, -0.0, 1.5, np.nan,
                    np.inf, 0, 3, np.float64(0.0), np.float64(-np.inf), np.int64(0)]
        for shape in [(1,), (7,), (5, 6), (6, 4, 5), (20, 3, 20)]:
            for spread in (1, 4, len(pool)):
                a = np.empty(shape, dtype=object)
                for idx in np.ndindex(*shape):  # distinct float objects too: float(...) of a fresh value
                    r = rng.random()
                    a[idx] = pool[0 if spread == 1 else rng.integers(spread)] if r < 0.8 else float(rng.integers(2))
                for view in (a, np.swapaxes(a, 0, -1), a[..., ::2]):
                    want = np.array([_sparse._kind(v) for v in view.reshape(-1)], dtype=np.int8).reshape(view.shape)
                    got = _sparse._kinds(view)
                    assert got.dtype == np.int8 and np.array_equal(got, want), (shape, spread)
        zero = np.empty((), dtype=object)
        zero[()] = symbolic.const(0.0)
        assert _sparse._kinds(zero).shape == () and _sparse._kinds(zero)[()] == 1


def test_the_bracket_multiplies_only_the_nonzero_terms_of_the_chain(chain, monkeypatch):
    """``{H, J}`` in :func:`liefi.reduction.core._multipliers` on the traced chain of 8: the symbolic
    multiplications the bracket makes are at most twice the structurally nonzero entries of ``dJ`` (each meets
    one entry of ``dH`` in ``x_f . p_g - x_g . p_f``), not the dense einsum's ``2 K n``."""
    from liefi.phase_space import PhaseSpace

    system, y0 = chain(8)
    fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=10.0)
    inside, muls, seen = [False], [0], []
    folded, bracket = symbolic._folded, PhaseSpace.bracket

    def counted(a, b, ufunc):
        muls[0] += inside[0] and ufunc is np.multiply
        return folded(a, b, ufunc)

    def watched(self, z, df, dg):
        inside[0] = True
        try:
            out = bracket(self, z, df, dg)
        finally:
            inside[0] = False
        seen.append((np.size(dg), int(np.sum(_sparse._kinds(np.asarray(dg, dtype=object)) != 1))))
        return out

    def no_load(source, engine="numba"):
        raise _Stop

    monkeypatch.setattr(symbolic, "_folded", counted)
    monkeypatch.setattr(PhaseSpace, "bracket", watched)
    monkeypatch.setattr(cache, "find", lambda *a, **k: None)
    monkeypatch.setattr(cache, "load", no_load)
    with pytest.raises(_Stop):
        kernels.compile_split(fi, engine="python")
    monkeypatch.undo()
    assert seen and muls[0] > 0
    dense, nonzero = sum(s for s, _ in seen), sum(nz for _, nz in seen)
    assert nonzero < dense / 4, seen  # the chain's dJ is mostly exact zeros: the bound below is not the dense one
    assert muls[0] <= 2 * nonzero, (muls[0], nonzero, dense)  # the products, and what the sums fold


def test_sparse_dot_builds_numpy_s_expressions():
    """:func:`liefi._sparse.dot` on traced vectors with exact zeros (batches broadcast) builds the nodes
    numpy's object einsum builds, and on floats it is numpy's einsum."""
    rng = np.random.default_rng(5)
    A0, w0 = rng.standard_normal((3, 6)), rng.standard_normal(6)
    A0[A0 < 0.2] = 0.0
    A0[1] = 0.0
    with liefi.engine.trace.trace() as tr:
        x = tr.symbols("x", 6)
        A = np.empty(A0.shape, dtype=object)
        for idx in np.ndindex(*A0.shape):
            A[idx] = symbolic.mul(A0[idx], x[idx[-1]]) if A0[idx] else symbolic.const(0.0)
        dense, sparse = np.einsum("...i,...i->...", x[None, :], A), _sparse.dot(x[None, :], A)
        assert sparse.shape == dense.shape == (3,)
        for k in range(3):
            d = symbolic.as_sym(dense[k])
            assert symbolic.as_sym(sparse[k]) is d or (d.op == "const" and float(sparse[k]) == 0.0)
        assert symbolic.as_sym(_sparse.dot(A[0], x)) is symbolic.as_sym(np.einsum("...i,...i->...", A[0], x))
    assert np.array_equal(_sparse.dot(A0, w0), np.einsum("...i,...i->...", A0, w0))


def test_the_trace_s_symbolic_operations_grow_no_faster_than_n_to_the_1_5(chain, monkeypatch):
    """From ``N = 16`` to ``N = 32`` the chain's split trace performs at most ``2^1.5`` times the symbolic
    operations (every ``+ - * /`` on traced scalars): the terms that grew like ``N^2`` are formed only where
    nonzero -- ``grad V``'s sum of ``k_i r_i dJ_i`` over the ``N`` constraints (``6 N^2`` products of mostly
    zeros, :func:`liefi._sparse.accumulate`), Gaussian elimination's ``0 / pivot`` -- with the same generated
    code (3.02x on the starting commit: 11853 -> 35845)."""
    ops16, _ = _trace_work(chain, 16, monkeypatch)
    ops32, _ = _trace_work(chain, 32, monkeypatch)
    assert ops32 <= 2**1.5 * ops16, (ops16, ops32, ops32 / ops16)


def test_sparse_sums_build_numpy_s_expressions():
    """:func:`liefi._sparse.symmetrized`, :func:`~liefi._sparse.accumulate` and a product through
    :func:`~liefi._sparse.matmul_rows` build, on traced arrays with exact zeros, the nodes numpy's dense
    loops build (the same objects; zeros may differ only as exact zeros), and on floats they are numpy's."""
    rng = np.random.default_rng(11)
    C0, x0, B0, D0 = (rng.standard_normal(s) for s in ((3, 4, 4), (6,), (4, 5), (5, 3)))
    C0[C0 < 0.5], x0[x0 < 0] = 0.0, 0.0
    B0[B0 < 0] = 0.0

    def same(dense, sparse):
        for idx in np.ndindex(*np.shape(dense)):
            d = symbolic.as_sym(np.asarray(dense, dtype=object)[idx])
            s = symbolic.as_sym(np.asarray(sparse, dtype=object)[idx])
            assert s is d or (d.op == s.op == "const" and d.value == s.value == 0.0), idx

    with liefi.engine.trace.trace() as tr:
        v = tr.symbols("v", 6)
        C = np.empty(C0.shape, dtype=object)
        for idx in np.ndindex(*C0.shape):
            C[idx] = symbolic.mul(C0[idx], v[idx[-1]]) if C0[idx] else 0.0
        same(C + np.swapaxes(C, -1, -2), _sparse.symmetrized(C))
        x = np.array([symbolic.mul(x0[i], v[i]) if x0[i] else 0.0 for i in range(6)], dtype=object)
        a = symbolic.mul(v[0], v[1])
        y = 0.0
        for _ in range(3):  # a zero y first, then traced sums
            want = y + np.asarray(a)[..., None] * x
            got = _sparse.accumulate(y, a, x)
            same(want, got)
            y = got
        A = C[0]
        same((A @ B0) @ D0, _sparse.matmul(_sparse.matmul_rows(A, B0), D0))
    assert np.array_equal(_sparse.symmetrized(C0), C0 + np.swapaxes(C0, -1, -2))
    assert np.array_equal(_sparse.accumulate(0.5, 2.0, x0), 0.5 + 2.0 * x0)


def test_a_traced_datum_s_integer_zeros_make_one_constant_not_a_call_each(monkeypatch):
    """A datum written with ``np.zeros_like`` on the traced state holds Python ``int`` zeros (the chain's
    constraint rows: ``N x 3N`` entries, ``3N - 2`` zeros a row): :func:`liefi.engine.trace._sym` makes one
    constant per distinct number whatever its type (``int``, ``float``, numpy's), in the order of first
    occurrence, the very nodes an entry-by-entry ``as_sym`` makes (before: a call of ``as_sym`` per integer)."""
    from liefi.engine import trace as _trace

    calls = [0]
    as_sym = _trace.as_sym

    def counted(v):
        calls[0] += 1
        return as_sym(v)

    with liefi.engine.trace.trace() as tr:
        x = tr.symbols("x", 4)
        a = np.empty((20, 30), dtype=object)
        a[...] = 0
        for i in range(20):  # each row: two traced entries, the rest int zeros; a few other numbers
            a[i, (3 * i) % 30], a[i, (3 * i + 1) % 30] = x[i % 4], x[(i + 1) % 4] * 2.0
        a[3, 7], a[5, 9], a[6, 2], a[7, 4] = np.float64(-0.0), 2, np.int64(5), 2.0
        monkeypatch.setattr(_trace, "as_sym", counted)
        got = _trace._sym(a)
        monkeypatch.undo()
        want = symbolic._to_sym_array(a)
        assert all(g is w for g, w in zip(got.reshape(-1), want.reshape(-1)))
        assert np.signbit(got[3, 7].value) and got[6, 2].value == 5.0 and got[0, 2].value == 0.0
    assert calls[0] <= 5, calls  # 0, -0.0, 2, 5: one call per distinct number (before: 600, one per entry)


def test_inverting_a_diagonal_gram_matrix_of_constants_divides_once_per_row_and_zero(monkeypatch):
    """``np.linalg.inv`` of a traced ``K x K`` matrix with constant pivots and exact-zero off-diagonals (the
    chain's Gram matrix ``E m E^T``): each constant quotient ``0 / pivot`` is folded once, not at every entry
    (``K^2`` divisions before), and the inverse is the same nodes, ``-0.0`` where the pivot is negative."""
    from liefi.engine import trace as _trace

    K = 24
    rng = np.random.default_rng(2)
    d = rng.uniform(0.5, 2.0, K) * np.where(np.arange(K) % 3 == 0, -1.0, 1.0)
    calls = [0]
    div = _trace.div

    def counted(a, b):
        calls[0] += 1
        return div(a, b)

    with liefi.engine.trace.trace() as tr:
        x = tr.symbols("x", 1)[0]
        A = np.empty((K, K), dtype=object)
        A[...] = symbolic.const(0.0)
        for i in range(K):
            A[i, i] = symbolic.const(d[i])
        A[0, 1] = x  # one traced entry: the matrix is traced
        monkeypatch.setattr(_trace, "div", counted)
        inv = np.linalg.inv(A)
        monkeypatch.undo()
        for i in range(K):
            for c in range(K):
                v = symbolic.as_sym(inv[i, c])
                if i == c:
                    assert v.op == "const" and v.value == 1.0 / d[i]
                elif i == 0 and c == 1:
                    assert v.op != "const"
                elif i != 0:
                    assert v.op == "const" and v.value == 0.0 and np.signbit(v.value) == (d[i] < 0), (i, c)
    assert calls[0] <= 6 * K, calls  # before: 852 (every 0 / pivot of the elimination and the substitution)


def test_summing_a_gradient_with_exact_zeros_reads_the_zeros_at_once(monkeypatch):
    """:func:`liefi._sparse.accumulate` on a traced vector of ``n`` entries, three nonzero, the zeros distinct
    float objects (a gradient assembled in numpy): the zeros are checked and kept without a Python call each
    (:func:`liefi._sparse._positive_zero` before: 594 calls, ``2 n``), and the sums are numpy's expressions."""
    n = 300
    calls = [0]
    positive_zero = _sparse._positive_zero

    def counted(v):
        calls[0] += 1
        return positive_zero(v)

    with liefi.engine.trace.trace() as tr:
        v = tr.symbols("v", 4)
        a = symbolic.mul(v[0], v[1])
        x = np.zeros(n).astype(object)  # distinct float zero objects
        x[5], x[17], x[n - 1] = v[2], symbolic.mul(v[3], 2.0), v[1]
        y = np.zeros(n).astype(object)
        y[17], y[40] = v[0], symbolic.mul(v[2], v[3])
        y[41] = -0.0
        monkeypatch.setattr(_sparse, "_positive_zero", counted)
        got = _sparse.accumulate(y, a, x)
        monkeypatch.undo()
        want = y + np.asarray(a)[..., None] * x
        for i in range(n):
            g, w = symbolic.as_sym(got[i]), symbolic.as_sym(want[i])
            assert g is w or (g.op == w.op == "const" and g.value == w.value == 0.0
                              and np.signbit(g.value) == np.signbit(w.value)), i
    assert calls[0] <= 2, calls
