r"""Tracing: scalar expression graphs recorded by running liefi's own numpy code.  The nodes and their
rules live in :mod:`liefi.engine.symbolic`.

The compiled engine does not re-implement any formula.  It calls the library's
functions (:func:`liefi.reduction.core.evaluate`, the feedback field
:meth:`liefi.FeedbackIntegrator.vector_field`, the DLA step
:meth:`liefi.schemes.dla_integrator.DLAIntegrator.update`, the group's ``config_rate``,
``penalty_grad``, ``orthogonal_matrices`` ...) on object arrays of :class:`Sym`
scalars: every ``+ - * / **``, ``np.sin``, ``np.sqrt``, ``np.stack``,
``np.einsum``, ``@``, indexing ... then records a node of a scalar expression
graph instead of computing a number.  Constants stay numbers and are folded;
identical sub-expressions are shared (hash-consing), so the graph is its own
common-subexpression elimination.

Where the numpy path takes ``d/dx`` of a datum by complex step (exact to
rounding), the graph is differentiated symbolically (:func:`derivative`, also
exact to rounding); an analytic derivative given by the user is traced
instead.  :class:`TracedData` is the data accessor (see
:class:`liefi.reduction.core.NumpyData`) that does this.

A function that cannot be traced -- ``float()`` of its argument, a comparison,
``np.where``, an assignment into a float array, ``np.linalg`` beyond
``solve``/``inv`` -- raises the internal ``_Untraceable``, which
:func:`traced_call` turns into :class:`NotCompilable` naming the function.
"""

from __future__ import annotations

import os
import threading
import traceback

import numpy as np

from .cramer import cramer_solve
from .symbolic import (_BINARY, _UNARY, Sym, _Graph, _local, _to_sym_array, _Untraceable, _obj0, add, as_sym,  # noqa: F401
                       const, derivative, div, jacobian, mul, power, sub, unary)

__all__ = ["NotCompilable", "CompilationWarning", "Sym", "trace", "derivative", "jacobian", "TracedData",
           "TRACED_DATA", "traced_call"]


class NotCompilable(ValueError):
    """A system's datum, invariant or group method cannot be traced into scalar code; the message says which and why."""


class CompilationWarning(RuntimeWarning):
    """The compiled engine was asked for but the numpy path runs instead (the message says why)."""




# ======================================================================================
# Tracing sessions
# ======================================================================================


def _is_traced(a):
    return isinstance(a, Sym) or (isinstance(a, np.ndarray) and a.dtype == object)


def _gauss_solve(A, B):
    """Solve ``A X = B`` for a small matrix ``A`` of traced scalars (object arrays).

    2 x 2 and 3 x 3: Cramer's rule (:func:`liefi.engine.cramer.cramer_solve`).  Larger: Gaussian
    elimination without pivoting (a traced value has no magnitude to
    pivot on), which is stable for the symmetric positive definite and
    diagonally dominant matrices that data functions meet (Golub & Van Loan,
    Sec. 4.2; e.g. ``orthonormalize=True``: a Cholesky factor).  ``B`` is
    ``(k,)`` or ``(k, r)``.
    """
    A = np.array(A, dtype=object)
    X = np.array(B, dtype=object)
    vec = X.ndim == 1
    if vec:
        X = X[:, None]
    k = A.shape[0]
    if k in (2, 3):  # closed form: no elimination chain (each division waited for the previous one)
        X = cramer_solve(A, X)
        return X[:, 0] if vec else X
    zero = None  # the tracer's 0 / a (a not a constant): +0.0, once formed
    quotients = {}  # constant / constant pivot: folded once per pair (a K x K Gram of the chain: K^2 of 0 / c)

    def _zero(v):
        return v.op == "const" and v.value == 0.0

    def _div(a, pivot):
        if a.op != "const" or pivot.op != "const":
            return div(a, pivot)
        key = (a.id, pivot.id)  # the constant a / pivot (the node formed the first time, as div forms it)
        got = quotients.get(key)
        if got is None:
            got = quotients[key] = div(a, pivot)
        return got

    for i in range(k):
        pivot = A[i, i]
        for r in range(i + 1, k):
            if zero is not None and _zero(A[r, i]) and pivot.op != "const":
                continue  # f = 0 / pivot = 0 (as below, without forming it again)
            f = _div(A[r, i], pivot)
            if _zero(f):
                if _zero(A[r, i]) and pivot.op != "const":
                    zero = f
                continue  # the row update would subtract exact zeros (folded away): k^2, not k^3, on sparse A
            for c in range(i, k):
                A[r, c] = sub(A[r, c], mul(f, A[i, c]))
            for c in range(X.shape[1]):
                X[r, c] = sub(X[r, c], mul(f, X[i, c]))
    for i in reversed(range(k)):
        pivot = A[i, i]
        nonzero = [j for j in range(i + 1, k) if not _zero(A[i, j])]  # s - 0 x = s (folded away)
        for c in range(X.shape[1]):
            s = X[i, c]
            for j in nonzero:
                s = sub(s, mul(A[i, j], X[j, c]))
            if zero is not None and _zero(s) and pivot.op != "const":
                X[i, c] = zero  # div(0, pivot), as formed before
            else:
                X[i, c] = _div(s, pivot)
                if zero is None and _zero(s) and pivot.op != "const":
                    zero = X[i, c]
    return X[:, 0] if vec else X


def _traced_solve(a, b):
    """``np.linalg.solve`` on traced arrays (numpy 2 semantics: ``b`` is a vector only if 1-D)."""
    a, b = np.asarray(a, dtype=object), np.asarray(b)
    if b.dtype.kind != "f":  # (float numbers stay: _sym makes a constant per distinct number)
        b = b.astype(object)
    vec = b.ndim == 1
    B = b[:, None] if vec else b
    batch = np.broadcast_shapes(a.shape[:-2], B.shape[:-2])
    A = np.broadcast_to(a, batch + a.shape[-2:])
    B = np.broadcast_to(B, batch + B.shape[-2:])
    out = np.empty(batch + B.shape[-2:], dtype=object)
    for idx in np.ndindex(*batch):
        out[idx] = _gauss_solve(_sym(A[idx]), _sym(B[idx]))
    return out[..., 0] if vec else out


def _traced_inv(a):
    a = np.asarray(a, dtype=object)
    return _traced_solve(a, np.broadcast_to(np.eye(a.shape[-1]), a.shape))


def _sym(a):
    """Object array of Syms (numbers become constants); 0-d stays a 0-d array.

    A float array: one constant per distinct number (bit pattern), formed in the order of first occurrence
    (as an entry-by-entry loop forms them), not a Python call per entry (``inv`` of a ``K x K`` matrix
    solves against the identity: ``K^2`` entries).
    """
    a = np.asarray(a)
    if a.ndim and a.dtype.kind == "f":
        flat = a.astype(np.float64).reshape(-1)
        _, first, inverse = np.unique(flat.view(np.int64), return_index=True, return_inverse=True)
        syms = np.empty(first.size, dtype=object)
        for u in np.argsort(first):
            syms[u] = as_sym(float(flat[first[u]]))
        return syms[inverse.reshape(-1)].reshape(a.shape)
    a = np.asarray(a, dtype=object)
    if a.ndim and a.size > _SYM_EACH:
        return _sym_objects(a)
    return _to_sym_array(a) if a.ndim else _obj0(as_sym(a.item()))


#: object arrays up to this size go through ``as_sym`` entry by entry
_SYM_EACH = 64
_TYPE = np.frompyfunc(type, 1, 1)
#: the numbers :func:`_sym_objects` makes one constant per distinct value of (``as_sym``: ``const(float(v))``)
_NUMBERS = tuple(np.array(t, dtype=object) for t in (float, int, np.float64, np.int64))  # (0-d: compared as objects)
_SYM_TYPE = np.array(Sym, dtype=object)


def _sym_objects(a):
    """:func:`_sym` of a (non-empty) object array: ``Sym`` entries kept, numbers (:data:`_NUMBERS`) one constant
    per distinct value, anything else by ``as_sym``; the constants formed in the order of their first occurrence,
    as an entry-by-entry loop forms them (a traced datum's array of mostly zeros, ``N x 3N`` for a chain's
    constraints, whose zeros are ints: a Python call per distinct number, not per entry)."""
    flat = a.reshape(-1)
    kind = _TYPE(flat)
    is_sym = np.asarray(kind == _SYM_TYPE, dtype=bool)  # (``kind == Sym`` is not elementwise: Sym's own ==)
    is_float = np.zeros(flat.shape, dtype=bool)
    for number in _NUMBERS:  # (the zeros of np.zeros_like on a traced array are Python ints)
        is_float |= np.asarray(kind == number, dtype=bool)
    out = flat.copy()
    at_f = np.flatnonzero(is_float)
    firsts, members = [], {}
    if at_f.size:
        vals = flat[at_f].astype(np.float64)
        _, first, inverse = np.unique(vals.view(np.int64), return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        for u, f in enumerate(first):
            firsts.append((int(at_f[f]), u))
        members = inverse
    at_o = np.flatnonzero(~(is_sym | is_float))
    syms = np.empty(len(firsts), dtype=object)
    for i, u in sorted(firsts + [(int(i), None) for i in at_o]):
        if u is None:
            out[i] = as_sym(flat[i])
        else:
            syms[u] = as_sym(flat[i])
    if at_f.size:
        out[at_f] = syms[members]
    return out.reshape(a.shape)


class trace:
    """A tracing session: ``with trace() as tr: y = tr.symbols("y", 5)``.

    Inside the block, :class:`Sym` arithmetic records nodes in ``tr.graph``, and
    ``np.linalg.solve``/``inv`` accept traced arrays (numbers still go to
    numpy's own, so another thread calling them meanwhile is unaffected;
    sessions are serialized by a lock and do not nest).
    """

    _lock = threading.RLock()

    def __enter__(self):
        if getattr(_local, "graph", None) is not None:
            raise RuntimeError("liefi.engine: tracing sessions do not nest")
        self._lock.acquire()
        self.graph = _Graph()
        _local.graph = self.graph
        self.saved = np.linalg.solve, np.linalg.inv
        solve, inv = self.saved

        def traced_solve(a, b):
            return _traced_solve(a, b) if _is_traced(a) or _is_traced(b) else solve(a, b)

        def traced_inv(a):
            return _traced_inv(a) if _is_traced(a) else inv(a)

        np.linalg.solve, np.linalg.inv = traced_solve, traced_inv
        self._errstate = np.errstate(all="ignore")
        self._errstate.__enter__()
        return self

    def __exit__(self, *exc):
        self._errstate.__exit__(*exc)
        np.linalg.solve, np.linalg.inv = self.saved
        _local.graph = None
        self._lock.release()
        return False

    def symbols(self, name, size):
        """An object array of ``size`` input symbols ``name[0] ... name[size-1]``."""
        out = np.empty(size, dtype=object)
        for i in range(size):
            out[i] = self.graph.node("var", (name, i))
        return out

    @property
    def size(self):
        """Number of nodes recorded so far."""
        return len(self.graph.nodes)


_HERE = os.path.dirname(os.path.abspath(__file__))


def _culprit(exc):
    """``"name (file:line)"`` of the innermost frame of ``exc`` outside the tracing machinery and numpy."""
    frames = traceback.extract_tb(exc.__traceback__)
    np_dir = os.path.dirname(np.__file__)
    for fr in reversed(frames):
        f = os.path.abspath(fr.filename)
        if f.startswith(_HERE) or f.startswith(np_dir):
            continue
        return f"{fr.name} ({os.path.basename(f)}:{fr.lineno})"
    return "?"


def traced_call(what, fun, *args, **kwargs):
    """``fun(*args, **kwargs)`` inside a tracing session; any failure becomes :class:`NotCompilable`.

    ``what`` names the traced function in the message (e.g. ``"the feedback field"``);
    the innermost user or library frame that failed is named too, so that an
    untraceable group method or datum is identified.
    """
    try:
        return fun(*args, **kwargs)
    except NotCompilable:
        raise
    except Exception as exc:  # noqa: BLE001 -- report any tracing failure, never the internal _Untraceable
        raise NotCompilable(
            f"{what}: cannot be traced into compiled code: {type(exc).__name__}: {exc} in {_culprit(exc)}. "
            "Write it with numpy arithmetic and ufuncs (np.sin, np.sqrt, np.stack, +, *, np.linalg.solve, ...) "
            "without float(), comparisons, np.where, in-place fills of float arrays or other np.linalg "
            "functions on its argument -- the same rules as for the complex step -- or run with backend='numpy'."
        ) from exc


def _call_datum(fun, x, shape, name):
    """``fun`` at the symbolic point ``x`` (shape ``(n,)``) -> object array of ``shape``."""
    def call():
        out = np.asarray(fun(x[None, :]), dtype=object)
        if out.shape == (1,) + tuple(shape):
            out = out.reshape(shape)
        else:
            out = np.asarray(fun(x), dtype=object)
        if out.shape != tuple(shape):
            out = np.broadcast_to(out, shape)
        return _sym(out)

    return traced_call(name, call)


def _free_point(x):
    """Whether the traced point ``x`` is distinct input symbols (then ``d / d x_i`` is read off the graph)."""
    flat = [as_sym(v) for v in np.asarray(x, dtype=object).reshape(-1)]
    return all(v.op == "var" for v in flat) and len({v.id for v in flat}) == len(flat)


def _substitute(outputs, mapping):
    """``outputs`` (Syms) rebuilt with the nodes of ``mapping`` (node id -> Sym) replaced: ``e(u)`` -> ``e(x)``."""
    from .codegen import reachable

    new = dict(mapping)

    def arg(a):
        return new.get(a.id, a)  # constants are not in reachable's list: they stay

    for node in reachable(outputs):
        if node.id in new:
            continue
        if node.op == "var":
            new[node.id] = node
        elif node.op in _BINARY:
            new[node.id] = {"add": add, "sub": sub, "mul": mul, "div": div, "pow": power}[node.op](
                arg(node.args[0]), arg(node.args[1]))
        else:
            new[node.id] = unary(node.op, arg(node.args[0]))
    return [arg(o) for o in outputs]


_FRESH = [0]


def _at_point(fun, x, shape, name, grad, grad_shape, grad_name):
    r"""``(fun(x), d fun / d x)`` traced, ``d / d x_i`` the partial derivative in the ``i``-th entry of ``x``.

    At a point of distinct input symbols the derivative is read off the graph of ``fun(x)``.  At a
    composite point (``x_i`` expressions of other symbols, or repeated entries) the graph of ``fun(x)``
    need not pass through the nodes ``x_i`` (the tracer simplifies sums and products into their atoms),
    so ``fun`` is traced at fresh symbols ``u``, differentiated in ``u``, and ``u -> x`` substituted:
    :math:`\partial_i f(x) = (\partial f / \partial u_i)|_{u = x}`.
    """
    x = np.asarray(x, dtype=object)
    if _free_point(x):
        val = _call_datum(fun, x, shape, name)
        der = (_call_datum(grad, x, grad_shape, grad_name) if grad is not None else jacobian(val, list(x)))
        return val, der
    from .symbolic import _graph

    _FRESH[0] += 1
    u = np.empty(x.shape, dtype=object)
    for i in range(x.size):
        u[i] = _graph().node("var", (f"_point{_FRESH[0]}", i))
    val = _call_datum(fun, u, shape, name)
    der = (_call_datum(grad, u, grad_shape, grad_name) if grad is not None else jacobian(val, list(u)))
    val, der = np.asarray(val, dtype=object), np.asarray(der, dtype=object)
    flat = list(val.reshape(-1)) + list(der.reshape(-1))
    out = _substitute([as_sym(v) for v in flat], {ui.id: as_sym(xi) for ui, xi in zip(u, x.reshape(-1))})
    v = np.empty(len(out), dtype=object)
    v[:] = out
    return _sym(v[:val.size].reshape(val.shape)), _sym(v[val.size:].reshape(der.shape))


class TracedData:
    """The data accessor of tracing (see :class:`liefi.reduction.core.NumpyData`).

    Constant data are returned as numbers with derivative ``None`` (as
    ``DataFunction.with_derivative`` does); callable data are traced and
    differentiated symbolically unless an analytic derivative was given,
    which is traced instead.
    """

    @staticmethod
    def value(datum, x):
        if datum.constant:
            return datum.value
        return _call_datum(datum.fun, x, datum.shape, datum.name)

    @staticmethod
    def value_and_derivative(datum, x):
        if datum.constant:
            return datum.value, None
        return _at_point(datum.fun, x, datum.shape, datum.name, datum._derivative, (datum.n,) + datum.shape,
                         f"{datum.name} derivative")

    @staticmethod
    def value_and_gradient(fun, z, grad=None, name="function"):
        return _at_point(fun, z, (), name, grad, np.shape(z), f"{name} gradient")


#: the accessor that traces
TRACED_DATA = TracedData()
