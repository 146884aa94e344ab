r"""A compiled engine for liefi's fields, derived from the system's data by tracing.

The numpy path (:meth:`liefi.FeedbackIntegrator.vector_field` ->
:func:`liefi.reduction.core.evaluate`) is the reference: batch-first, generic,
and about 20 microseconds per call whatever the system.  This module builds, for
one system and one choice of invariants, *straight-line scalar code* for the
same field and runs the whole fixed-step loop (any explicit Runge--Kutta
tableau of :mod:`liefi.schemes`) inside numba.  Nothing here knows a particular
system: the code is generated from the same data the numpy path uses.

How the code is derived
-----------------------
1. **Tracing.**  The system's data functions (metric, constraints, potential,
   their optional analytic derivatives, user invariants) are batch-first numpy
   functions.  They are called once on an object array of symbols
   (:class:`Sym`): every ``+ - * / **``, ``np.sin``, ``np.sqrt``, ``np.stack``,
   ``np.einsum``, ``@``, indexing ... then records a scalar expression graph
   instead of computing numbers.  Constant data (arrays) stay numbers and are
   folded.  Identical sub-expressions are shared (hash-consing), so the graph
   is its own common-subexpression elimination.
2. **Derivatives.**  Where the numpy path takes ``d/dx`` of a datum by complex
   step (exact to rounding), the traced graph is differentiated symbolically
   (also exact to rounding); an analytic derivative passed by the user is
   traced instead, as the numpy path uses it instead.
3. **The field.**  :func:`symbolic_terms` mirrors
   :func:`liefi.reduction.core.evaluate` line by line on these arrays, and the
   bracket, ``lambda~`` and the field itself are computed by calling the
   library's own :func:`~liefi.reduction.core._multipliers`,
   :func:`~liefi.reduction.core._field`, the phase space's bracket and the
   group's ``ad*``, ``config_rate``, ``penalty_grad`` on the symbolic arrays.
   :func:`symbolic_feedback_field` mirrors ``FeedbackIntegrator._parts``.
   Gains and targets are run-time parameters, so one compiled kernel serves
   every gain.
4. **Code.**  The graph is printed as a Python function of ``(y, p, out)``
   with one assignment per node, compiled by ``numba.njit``; the stepping loop
   (the scheme's tableau unrolled, the same arithmetic order as
   :meth:`liefi.schemes.ExplicitRungeKutta.step`) is generated next to it, for
   one trajectory or for a batch (``prange`` over trajectories).  Generated
   modules are written to a cache directory (``$LIEFI_CACHE_DIR``, default
   ``~/.cache/liefi``) so numba's on-disk cache makes a second process start
   instantly.

The compiled and numpy paths agree to ``1e-12`` (``tests/test_compiled.py``):
the formulas are the same, only the order of a few floating-point sums differs.

Limits
------
A datum that cannot be traced -- it calls ``np.linalg`` beyond ``solve``/``inv``,
``float()``, compares its argument, assigns into a float array, uses
``np.where`` ... -- makes
:func:`compile_feedback` raise :class:`NotCompilable` naming the datum and the
operation; ``FeedbackIntegrator.run(backend="auto")`` then runs the numpy path
and says why (a :class:`CompilationWarning`).  Without numba the generated code
still runs as plain Python (``engine="python"``, slow: for debugging only);
``backend="numba"`` warns and falls back to numpy.
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass

import numpy as np

#: numba (optional: ``liefi[fast]``), imported on first use so that importing liefi stays light;
#: ``None`` once an import failed (the reason in :data:`NUMBA_ERROR`).
_numba = False
NUMBA_ERROR = None


def _nb():
    """The numba module, or ``None`` when it cannot be imported."""
    global _numba, NUMBA_ERROR
    if _numba is False:
        try:
            import numba

            _numba = numba
        except Exception as exc:  # noqa: BLE001 -- any import failure means "no numba"
            _numba = None
            NUMBA_ERROR = f"{type(exc).__name__}: {exc}"
    return _numba

__all__ = [
    "available",
    "NotCompilable",
    "CompilationWarning",
    "Sym",
    "trace",
    "symbolic_terms",
    "symbolic_feedback_field",
    "symbolic_constrained_field",
    "compile_feedback",
    "compile_constrained",
    "compile_dla",
    "CompiledField",
    "CompiledDLA",
]


def available() -> bool:
    """True when numba is importable (the compiled engine can run at full speed)."""
    return _nb() is not None


class NotCompilable(ValueError):
    """A system's datum (or invariant) cannot be traced into scalar code; the message says which and why."""


class CompilationWarning(RuntimeWarning):
    """The compiled engine was asked for but the numpy path runs instead (the message says why)."""


# ======================================================================================
# 1. Symbolic scalars
# ======================================================================================

#: unary operations: name -> code template (``math`` functions: numba compiles them to libm calls)
_UNARY = {
    "neg": "(-{0})",
    "sin": "math.sin({0})",
    "cos": "math.cos({0})",
    "tan": "math.tan({0})",
    "exp": "math.exp({0})",
    "log": "math.log({0})",
    "sqrt": "math.sqrt({0})",
    "arcsin": "math.asin({0})",
    "arccos": "math.acos({0})",
    "arctan": "math.atan({0})",
    "sinh": "math.sinh({0})",
    "cosh": "math.cosh({0})",
    "tanh": "math.tanh({0})",
    "arcsinh": "math.asinh({0})",
    "arccosh": "math.acosh({0})",
    "arctanh": "math.atanh({0})",
    "expm1": "math.expm1({0})",
    "log1p": "math.log1p({0})",
    "abs": "abs({0})",
    "sign": "math.copysign(1.0, {0})",
}
_BINARY = {"add": "({0} + {1})", "sub": "({0} - {1})", "mul": "({0} * {1})", "div": "({0} / {1})", "pow": "({0} ** {1})"}
_NP_UNARY = {
    np.negative: "neg", np.sin: "sin", np.cos: "cos", np.tan: "tan", np.exp: "exp", np.log: "log",
    np.sqrt: "sqrt", np.arcsin: "arcsin", np.arccos: "arccos", np.arctan: "arctan", np.sinh: "sinh",
    np.cosh: "cosh", np.tanh: "tanh", np.arcsinh: "arcsinh", np.arccosh: "arccosh",
    np.arctanh: "arctanh", np.expm1: "expm1", np.log1p: "log1p", np.absolute: "abs",
    np.positive: "pos", np.conjugate: "pos", np.real: "pos", np.square: "square",
    np.reciprocal: "reciprocal",
}
_NP_BINARY = {np.add: "add", np.subtract: "sub", np.multiply: "mul", np.true_divide: "div", np.power: "pow"}


class _Graph:
    """Hash-consing table of the nodes built while tracing (one per :func:`trace` session)."""

    def __init__(self):
        self.table = {}
        self.nodes = []

    def node(self, op, args, value=None):
        key = (op, args if op != "const" else value.hex())
        got = self.table.get(key)
        if got is None:
            got = Sym(op, args, value, len(self.nodes))
            self.table[key] = got
            self.nodes.append(got)
        return got


_local = threading.local()


def _graph() -> _Graph:
    g = getattr(_local, "graph", None)
    if g is None:
        raise RuntimeError("liefi.compiled: symbolic arithmetic outside a tracing session")
    return g


class _Untraceable(TypeError):
    pass


class Sym:
    """A scalar node of a traced expression graph.

    Built only through arithmetic during a tracing session: ``Sym`` objects
    support ``+ - * / **``, unary minus, ``abs`` and the numpy ufuncs listed in
    ``_NP_UNARY`` (called either on a ``Sym`` or, through numpy's object loops,
    as the methods ``x.sin()`` ...).  Comparisons, ``float()`` and ``bool()``
    of a non-constant node raise, which is how an untraceable function is
    detected.
    """

    __slots__ = ("op", "args", "value", "id")
    __array_priority__ = 1000

    def __init__(self, op, args, value, id_):
        self.op, self.args, self.value, self.id = op, args, value, id_

    def __repr__(self):
        if self.op == "const":
            return repr(self.value)
        if self.op == "var":
            return f"{self.args[0]}[{self.args[1]}]"
        return f"{self.op}{tuple(self.args)}"

    # --- identity: hashing by node identity (the graph is hash-consed) -----------------
    __hash__ = object.__hash__

    def __eq__(self, other):
        raise _Untraceable("comparison of a traced value")

    __ne__ = __lt__ = __le__ = __gt__ = __ge__ = __eq__

    def __bool__(self):
        if self.op == "const":
            return bool(self.value)
        raise _Untraceable("truth value of a traced value (an `if` or comparison on the argument)")

    def __float__(self):
        if self.op == "const":
            return self.value
        raise _Untraceable("float() of a traced value")

    def __index__(self):
        raise _Untraceable("a traced value used as an index")

    # --- arithmetic --------------------------------------------------------------------
    def __add__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return add(self, o)

    def __radd__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return add(o, self)

    def __sub__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return sub(self, o)

    def __rsub__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return sub(o, self)

    def __mul__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return mul(self, o)

    def __rmul__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return mul(o, self)

    def __truediv__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return div(self, o)

    def __rtruediv__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return div(o, self)

    def __pow__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return power(self, o)

    def __rpow__(self, o):
        if isinstance(o, np.ndarray) and o.ndim:
            return NotImplemented
        return power(o, self)

    def __neg__(self):
        return unary("neg", self)

    def __pos__(self):
        return self

    def __abs__(self):
        return unary("abs", self)

    @property
    def real(self):
        return self

    @property
    def imag(self):
        return const(0.0)

    def conjugate(self):
        return self

    # numpy's object loops call these methods
    def sin(self):
        return unary("sin", self)

    def cos(self):
        return unary("cos", self)

    def tan(self):
        return unary("tan", self)

    def exp(self):
        return unary("exp", self)

    def log(self):
        return unary("log", self)

    def sqrt(self):
        return unary("sqrt", self)

    def arcsin(self):
        return unary("arcsin", self)

    def arccos(self):
        return unary("arccos", self)

    def arctan(self):
        return unary("arctan", self)

    def sinh(self):
        return unary("sinh", self)

    def cosh(self):
        return unary("cosh", self)

    def tanh(self):
        return unary("tanh", self)

    def arcsinh(self):
        return unary("arcsinh", self)

    def arccosh(self):
        return unary("arccosh", self)

    def arctanh(self):
        return unary("arctanh", self)

    def expm1(self):
        return unary("expm1", self)

    def log1p(self):
        return unary("log1p", self)

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        if method != "__call__" or kwargs.get("out") is not None:
            return NotImplemented
        if any(isinstance(i, np.ndarray) and i.ndim > 0 for i in inputs):
            # an array meets a bare Sym: apply element-wise through object arrays
            args = [_obj0(i) if isinstance(i, Sym) else _objectify(i) for i in inputs]
            return ufunc(*args)
        vals = [i.item() if isinstance(i, np.ndarray) else i for i in inputs]
        if len(vals) == 1 and ufunc in _NP_UNARY:
            return _apply_unary(_NP_UNARY[ufunc], vals[0])
        if len(vals) == 2 and ufunc in _NP_BINARY:
            return _BIN_FUN[_NP_BINARY[ufunc]](vals[0], vals[1])
        raise _Untraceable(f"numpy function {ufunc.__name__}")


def _obj0(v):
    """A 0-d object array holding ``v`` (``np.asarray`` would unwrap nothing but is ambiguous)."""
    a = np.empty((), dtype=object)
    a[()] = v
    return a


def _objectify(a):
    """Object array whose numbers are wrapped as constants (numpy's object loops need methods)."""
    if isinstance(a, np.ndarray) and a.dtype == object:
        r = _to_sym_array(a)
        return r if isinstance(r, np.ndarray) else _obj0(r)
    return a


def const(v) -> Sym:
    v = float(v)
    return _graph().node("const", (), v)


def as_sym(v) -> Sym:
    """A number or ``Sym`` as a ``Sym``."""
    if isinstance(v, Sym):
        return v
    if isinstance(v, (bool, int, float, np.integer, np.floating)):
        return const(v)
    if isinstance(v, np.ndarray) and v.ndim == 0:
        return as_sym(v.item())
    if isinstance(v, (complex, np.complexfloating)):
        if v.imag != 0:
            raise _Untraceable("a complex constant")
        return const(v.real)
    raise _Untraceable(f"a value of type {type(v).__name__}")


_to_sym_array = np.frompyfunc(as_sym, 1, 1)


def _is_const(a, v=None):
    return a.op == "const" and (v is None or a.value == v)


def _folded(a, b, ufunc):
    """The constant ``ufunc(a, b)`` when both are constants (numpy's float semantics), else ``None``."""
    if a.op == "const" and b.op == "const":
        with np.errstate(all="ignore"):
            return const(ufunc(np.float64(a.value), np.float64(b.value)))
    return None


def add(a, b):
    a, b = as_sym(a), as_sym(b)
    r = _folded(a, b, np.add)
    if r is not None:
        return r
    if _is_const(a, 0.0):
        return b
    if _is_const(b, 0.0):
        return a
    if a.id > b.id:  # a + b == b + a exactly: one canonical order shares more nodes
        a, b = b, a
    return _graph().node("add", (a, b))


def sub(a, b):
    a, b = as_sym(a), as_sym(b)
    r = _folded(a, b, np.subtract)
    if r is not None:
        return r
    if _is_const(b, 0.0):
        return a
    if _is_const(a, 0.0):
        return unary("neg", b)
    if a is b:
        return const(0.0)
    return _graph().node("sub", (a, b))


def mul(a, b):
    a, b = as_sym(a), as_sym(b)
    r = _folded(a, b, np.multiply)
    if r is not None:
        return r
    if _is_const(a, 0.0) or _is_const(b, 0.0):
        return const(0.0)
    if _is_const(a, 1.0):
        return b
    if _is_const(b, 1.0):
        return a
    if _is_const(a, -1.0):
        return unary("neg", b)
    if _is_const(b, -1.0):
        return unary("neg", a)
    if a.id > b.id:
        a, b = b, a
    return _graph().node("mul", (a, b))


def div(a, b):
    a, b = as_sym(a), as_sym(b)
    r = _folded(a, b, np.true_divide)
    if r is not None:
        return r
    if _is_const(a, 0.0):
        return const(0.0)
    if _is_const(b, 1.0):
        return a
    return _graph().node("div", (a, b))


def power(a, b):
    a, b = as_sym(a), as_sym(b)
    r = _folded(a, b, np.power)
    if r is not None:
        return r
    if _is_const(b):
        if b.value == 1.0:
            return a
        if b.value == 0.0:
            return const(1.0)
        if b.value == 2.0:
            return mul(a, a)  # numpy computes x**2 as x*x
        if b.value == 0.5:
            return unary("sqrt", a)
        if b.value == -1.0:
            return div(1.0, a)
    return _graph().node("pow", (a, b))


_BIN_FUN = {"add": add, "sub": sub, "mul": mul, "div": div, "pow": power}


def _apply_unary(op, a):
    if op == "pos":
        return as_sym(a)
    if op == "square":
        return mul(a, a)
    if op == "reciprocal":
        return div(1.0, a)
    return unary(op, a)


_FOLD = {
    "neg": lambda v: -v, "sin": math.sin, "cos": math.cos, "tan": math.tan, "exp": math.exp,
    "log": math.log, "sqrt": math.sqrt, "arcsin": math.asin, "arccos": math.acos, "arctan": math.atan,
    "sinh": math.sinh, "cosh": math.cosh, "tanh": math.tanh, "arcsinh": math.asinh,
    "arccosh": math.acosh, "arctanh": math.atanh, "expm1": math.expm1, "log1p": math.log1p,
    "abs": abs, "sign": lambda v: math.copysign(1.0, v),
}


_NP_NAME = {"neg": "negative", "abs": "absolute", "sign": "sign"}


def unary(op, a):
    a = as_sym(a)
    if a.op == "const":
        try:
            return const(_FOLD[op](a.value))
        except (ValueError, OverflowError):  # outside the domain: numpy's nan / inf
            with np.errstate(all="ignore"):
                return const(float(getattr(np, _NP_NAME.get(op, op))(np.float64(a.value))))
    if op == "neg" and a.op == "neg":
        return a.args[0]
    return _graph().node(op, (a,))


# --- derivatives ------------------------------------------------------------------------


def _d_unary(op, a, da, node):
    """d op(a) = f'(a) da (symbolic)."""
    if op == "neg":
        return unary("neg", da)
    if op == "sin":
        return mul(unary("cos", a), da)
    if op == "cos":
        return unary("neg", mul(unary("sin", a), da))
    if op == "tan":
        return mul(add(1.0, mul(node, node)), da)
    if op == "exp":
        return mul(node, da)
    if op == "log":
        return div(da, a)
    if op == "sqrt":
        return div(da, mul(2.0, node))
    if op == "arcsin":
        return div(da, unary("sqrt", sub(1.0, mul(a, a))))
    if op == "arccos":
        return unary("neg", div(da, unary("sqrt", sub(1.0, mul(a, a)))))
    if op == "arctan":
        return div(da, add(1.0, mul(a, a)))
    if op == "sinh":
        return mul(unary("cosh", a), da)
    if op == "cosh":
        return mul(unary("sinh", a), da)
    if op == "tanh":
        return mul(sub(1.0, mul(node, node)), da)
    if op == "arcsinh":
        return div(da, unary("sqrt", add(mul(a, a), 1.0)))
    if op == "arccosh":
        return div(da, unary("sqrt", sub(mul(a, a), 1.0)))
    if op == "arctanh":
        return div(da, sub(1.0, mul(a, a)))
    if op == "expm1":
        return mul(unary("exp", a), da)
    if op == "log1p":
        return div(da, add(1.0, a))
    if op == "abs":
        return mul(unary("sign", a), da)
    if op == "sign":
        return const(0.0)
    raise _Untraceable(f"derivative of {op}")


def derivative(expr: Sym, var: Sym, memo: dict) -> Sym:
    """``d expr / d var`` by forward differentiation of the graph (``memo`` per ``var``)."""
    stack = [expr]
    while stack:
        node = stack[-1]
        if node.id in memo:
            stack.pop()
            continue
        if node.op == "const" or node.op == "var":
            memo[node.id] = const(1.0 if node is var else 0.0)
            stack.pop()
            continue
        pending = [a for a in node.args if a.id not in memo]
        if pending:
            stack.extend(pending)
            continue
        stack.pop()
        op, args = node.op, node.args
        if op in _UNARY:
            memo[node.id] = _d_unary(op, args[0], memo[args[0].id], node)
            continue
        a, b = args
        da, db = memo[a.id], memo[b.id]
        if op == "add":
            r = add(da, db)
        elif op == "sub":
            r = sub(da, db)
        elif op == "mul":
            r = add(mul(da, b), mul(a, db))
        elif op == "div":
            r = div(sub(da, mul(node, db)), b)
        elif op == "pow":
            if b.op == "const":
                r = mul(mul(b, power(a, b.value - 1.0)), da)
            else:
                r = mul(node, add(mul(db, unary("log", a)), div(mul(b, da), a)))
        else:  # pragma: no cover
            raise _Untraceable(f"derivative of {op}")
        memo[node.id] = r
    return memo[expr.id]


def jacobian(values, variables):
    """Symbolic Jacobian: array ``(len(variables), *values.shape)``, ``d values / d variables[k]``."""
    values = _to_sym_array(np.asarray(values, dtype=object)) if np.ndim(values) else np.asarray(as_sym(values), dtype=object)
    flat = values.reshape(-1)
    out = np.empty((len(variables), flat.size), dtype=object)
    for k, v in enumerate(variables):
        memo = {}
        for j, e in enumerate(flat):
            out[k, j] = derivative(e, v, memo)
    return out.reshape((len(variables),) + values.shape)


# ======================================================================================
# 2. Tracing sessions
# ======================================================================================


class trace:
    """A tracing session: ``with trace() as tr: y = tr.symbols("y", 5)``.

    Inside the block, :class:`Sym` arithmetic records nodes in ``tr.graph``.
    """

    def __enter__(self):
        if getattr(_local, "graph", None) is not None:
            raise RuntimeError("liefi.compiled: tracing sessions do not nest")
        self.graph = _Graph()
        _local.graph = self.graph
        return self

    def __exit__(self, *exc):
        _local.graph = None
        return False

    def symbols(self, name, size):
        """An object array of ``size`` input symbols ``name[0] ... name[size-1]``."""
        out = np.empty(size, dtype=object)
        for i in range(size):
            out[i] = self.graph.node("var", (name, i))
        return out


def _is_traced(a):
    return isinstance(a, Sym) or (isinstance(a, np.ndarray) and a.dtype == object)


def _traced_solve(a, b):
    """``np.linalg.solve`` on traced arrays (numpy 2 semantics: ``b`` is a vector only if 1-D).

    Gaussian elimination without pivoting: exact for triangular matrices and
    stable for symmetric positive definite and diagonally dominant ones, which
    is what data functions meet (e.g. ``orthonormalize=True``: a Cholesky factor).
    """
    a, b = np.asarray(a, dtype=object), np.asarray(b, dtype=object)
    vec = b.ndim == 1
    B = b[:, None] if vec else b
    batch = np.broadcast_shapes(a.shape[:-2], B.shape[:-2])
    A = np.broadcast_to(a, batch + a.shape[-2:])
    B = np.broadcast_to(B, batch + B.shape[-2:])
    out = np.empty(batch + B.shape[-2:], dtype=object)
    for idx in np.ndindex(*batch):
        out[idx] = _sym_solve(_sym(A[idx]), _sym(B[idx]))
    return out[..., 0] if vec else out


def _traced_inv(a):
    a = np.asarray(a, dtype=object)
    return _traced_solve(a, np.broadcast_to(np.eye(a.shape[-1]), a.shape))


class _TracedLinalg:
    """Within the block, ``np.linalg.solve``/``inv`` accept traced arrays (others go to numpy).

    Installed only while a datum is traced, under a lock (tracing is quick); a
    thread calling ``np.linalg.solve`` on numbers meanwhile gets numpy's own.
    """

    _lock = threading.RLock()

    def __enter__(self):
        self._lock.acquire()
        self.saved = np.linalg.solve, np.linalg.inv
        solve, inv = self.saved

        def traced_solve(a, b):
            return _traced_solve(a, b) if _is_traced(a) or _is_traced(b) else solve(a, b)

        def traced_inv(a):
            return _traced_inv(a) if _is_traced(a) else inv(a)

        np.linalg.solve, np.linalg.inv = traced_solve, traced_inv
        return self

    def __exit__(self, *exc):
        np.linalg.solve, np.linalg.inv = self.saved
        self._lock.release()
        return False


def _call_datum(fun, x, shape, name):
    """``fun`` at the symbolic point ``x`` (shape ``(n,)``) -> object array of ``shape``."""
    try:
        with np.errstate(all="ignore"), _TracedLinalg():
            out = np.asarray(fun(x[None, :]), dtype=object)
            if out.shape == (1,) + tuple(shape):
                out = out.reshape(shape)
            else:
                out = np.asarray(fun(x), dtype=object)
        if out.shape != tuple(shape):
            out = np.broadcast_to(out, shape)
        return _sym(out)
    except NotCompilable:
        raise
    except Exception as exc:  # noqa: BLE001 -- report any tracing failure with the datum's name
        raise NotCompilable(
            f"{name}: cannot be traced into compiled code ({type(exc).__name__}: {exc}). Write it with "
            "numpy arithmetic and ufuncs (np.sin, np.sqrt, np.stack, +, *, np.linalg.solve, ...) without "
            "float(), comparisons, np.where or other np.linalg functions on its argument -- the same rules "
            "as for the complex step -- or run with backend='numpy'."
        ) from exc


def symbolic_datum(datum, x):
    """``(value, d value / dx)`` of a :class:`~liefi._data.DataFunction` at symbolic ``x``.

    Constant data are returned as numbers with derivative ``None`` (as
    ``DataFunction.with_derivative`` does); callable data are traced and
    differentiated symbolically unless an analytic derivative was given.
    """
    if datum.constant:
        return datum.value, None
    n = datum.n
    val = _call_datum(datum.fun, x, datum.shape, datum.name)
    if datum._derivative is not None:
        der = _call_datum(datum._derivative, x, (n,) + datum.shape, f"{datum.name} derivative")
    else:
        der = jacobian(val, list(x))
    return val, der


# ======================================================================================
# 3. The fields on symbolic arrays (mirrors of liefi.reduction.core / liefi.feedback)
# ======================================================================================


def _sym_solve(A, B):
    """Solve ``A X = B`` for a small symmetric positive definite ``A`` (object arrays).

    Gaussian elimination without pivoting, which is stable for SPD matrices
    (Golub & Van Loan, Sec. 4.2); ``B`` is ``(k,)`` or ``(k, r)``.
    """
    A = np.array(A, dtype=object)
    X = np.array(B, dtype=object)
    vec = X.ndim == 1
    if vec:
        X = X[:, None]
    k = A.shape[0]
    for i in range(k):
        for r in range(i + 1, k):
            f = div(A[r, i], A[i, i])
            for c in range(i, k):
                A[r, c] = sub(A[r, c], mul(f, A[i, c]))
            for c in range(X.shape[1]):
                X[r, c] = sub(X[r, c], mul(f, X[i, c]))
    for i in reversed(range(k)):
        for c in range(X.shape[1]):
            s = X[i, c]
            for j in range(i + 1, k):
                s = sub(s, mul(A[i, j], X[j, c]))
            X[i, c] = div(s, A[i, i])
    return X[:, 0] if vec else X


def _sym_inv(A):
    k = np.shape(A)[0]
    return _sym_solve(A, np.eye(k))


def _sym(a):
    """Object array of Syms (numbers become constants); 0-d stays a 0-d array."""
    a = np.asarray(a, dtype=object)
    return _to_sym_array(a) if a.ndim else _obj0(as_sym(a.item()))


def symbolic_terms(system, z):
    """:class:`~liefi.reduction.core.Terms` at the symbolic state ``z`` (object array ``(nz,)``).

    A line-by-line mirror of :func:`liefi.reduction.core.evaluate` for one
    point (no batch axes); the data and their ``x``-derivatives come from
    :func:`symbolic_datum`.
    """
    from .reduction.core import Terms

    sp = system.space
    n, D, K = sp.n, sp.D, system.K
    x, P = z[:n], z[n:]

    m, dm = symbolic_datum(system.metric, x)
    E, dE = symbolic_datum(system.constraints, x)
    U, dU = symbolic_datum(system.potential, x)
    Pi, dA = P, None
    if system.vector_potential is not None:  # kinetic momentum P - A(x), as in evaluate
        A, dA = symbolic_datum(system.vector_potential, x)
        Pi = P - np.asarray(A, dtype=object)
    m = np.asarray(m, dtype=object)
    E = np.asarray(E, dtype=object)
    if system.constant:
        Eflat, Cinv = system._Eflat, system._Cinv
    else:
        Eflat = E @ m
        Cinv = _sym_inv(Eflat @ E.T) if K else np.zeros((0, 0))

    if system.metric.constant:
        v = np.einsum("ij,j->i", system._minv, Pi)  # dh/dP = (P - A)^sharp
    else:
        v = _sym_solve(m, Pi)
    J = np.einsum("kj,j->k", E, Pi)
    w = np.einsum("kl,l->k", Cinv, J)  # C^{-1} J
    dht_dP = v - np.einsum("kj,k->j", E, w)
    h = 0.5 * np.einsum("i,i->", Pi, v) + U
    ht = h - 0.5 * np.einsum("k,k->", J, w)

    dh_dx = np.zeros(n, dtype=object)
    dJ_dx = np.zeros((n, K), dtype=object)
    if n:
        if dU is not None:
            dh_dx = dh_dx + dU
        if dm is not None:
            dh_dx = dh_dx - 0.5 * np.einsum("i,kij,j->k", v, dm, v)
        if dA is not None:
            dh_dx = dh_dx - np.einsum("kj,j->k", dA, v)
            dJ_dx = dJ_dx - np.einsum("kj,ij->ki", dA, E)
        dht_dx = dh_dx
        if K:
            Et = E.T
            dC = None
            if dE is not None:
                dJ_dx = dJ_dx + np.einsum("kij,j->ki", dE, Pi)
                dEm = dE @ m[None, :, :]
                dC = dEm @ Et[None, :, :]
                dC = dC + np.swapaxes(dC, -1, -2)
            if dm is not None:
                term = E[None, :, :] @ dm @ Et[None, :, :]
                dC = term if dC is None else dC + term
            dht_dx = dh_dx - np.einsum("ki,i->k", dJ_dx, w)
            if dC is not None:
                dht_dx = dht_dx + 0.5 * np.einsum("i,kij,j->k", w, dC, w)
    else:
        dht_dx = dh_dx

    dh = np.concatenate([dh_dx, v])
    dht = np.concatenate([dht_dx, dht_dP])
    dJ = np.concatenate([np.swapaxes(dJ_dx, -1, -2), np.asarray(E, dtype=object).reshape(K, D)], -1)
    return Terms(
        _sym(h), _sym(ht), _sym(J), _sym(dh), _sym(dht), _sym(dJ),
        _sym(np.broadcast_to(Eflat, (K, D))), _sym(Cinv),
    )


def _sym_project(system, z, t):
    """Mirror of :func:`liefi.reduction.core.project` given the terms ``t`` at ``z``."""
    n = system.space.n
    if not system.K:
        return z
    w = np.einsum("kl,l->k", t.Cinv, t.J)
    P = z[n:] - np.einsum("k,kj->j", w, t.Eflat)
    return _sym(np.concatenate([z[:n], P]))


def _reduced_field(system, z, t, extended=True):
    """``(zdot, dH)``: the extended (or constrained) reduced field, by the library's own functions."""
    from .reduction import core as _core

    dH = t.dht if extended else t.dh
    lam = _core._multipliers(system, z, dH, t.dJ, t.Cinv)
    return _sym(_core._field(system, z, dH, lam, t.Eflat)), dH


def symbolic_feedback_field(fi, y, params, *, feedback=True):
    """``X(y) - A grad V(y)`` of a :class:`~liefi.FeedbackIntegrator` on symbols (mirror of ``_parts``).

    ``params`` is an object array of symbols laid out by :func:`parameter_layout`
    (gains and targets); with ``feedback=False`` only the extended field ``X``.
    """
    sys = fi.system
    sp = sys.space
    nc = fi.nc
    g, z = y[:nc], y[nc:]
    if fi.field == "projected":
        t0 = symbolic_terms(sys, z)
        zf = _sym_project(sys, z, t0)
        tf = symbolic_terms(sys, zf)
        zdot, dHf = _reduced_field(sys, zf, tf)
        t = t0
    else:
        t = symbolic_terms(sys, z)
        zf, tf = z, t
        zdot, dHf = _reduced_field(sys, z, t)
    n, d = sp.n, sp.d
    X = zdot
    if fi.configuration:
        gdot = _sym(sp.group.config_rate(g, dHf[n : n + d]))
        X = np.concatenate([gdot, zdot])
    if not feedback:
        return _sym(X)

    lay = parameter_layout(fi)
    gz = np.zeros(sp.nz, dtype=object)
    if fi.use_constraints:
        kJ = params[lay["J"]] * t.J
        gz = gz + np.einsum("k,kj->j", kJ, t.dJ)
    if fi.use_energy:
        Ev, dEv_ = (t.ht, t.dht) if fi.energy == "extended" else (t.h, t.dh)
        dEv = Ev - params[lay["energy_target"]]
        gz = gz + (params[lay["energy"]] * dEv) * dEv_
    for j, u in enumerate(fi.user):
        val, grad = symbolic_invariant(u, z)
        dv = val - params[lay["user_target"][j]]
        gz = gz + (params[lay["user"][j]] * dv) * grad
    if fi.configuration:
        if fi.use_penalty:
            gg = params[lay["penalty"]] * np.asarray(sp.group.penalty_grad(g), dtype=object)
        else:
            gg = np.zeros(nc, dtype=object)
        gradV = np.concatenate([gg, gz])
    else:
        gradV = gz
    if fi.A is not None:
        gradV = np.einsum("ij,j->i", fi.A, gradV)
    return _sym(X - gradV)


def symbolic_invariant(inv, z):
    """``(value, gradient)`` of a user :class:`~liefi.Invariant` at symbolic ``z``."""
    name = f"invariant {inv.name!r}"
    val = _call_datum(inv.fun, z, (), name)
    if inv.grad is not None:
        grad = _call_datum(inv.grad, z, z.shape, f"{name} gradient")
    else:
        grad = jacobian(val, list(z))
    return val.item() if isinstance(val, np.ndarray) else val, grad


def parameter_layout(fi):
    """Where each gain and target sits in the parameter vector ``p`` of a compiled field.

    Returns a dict: ``"J"`` (index array), ``"energy"``, ``"energy_target"``,
    ``"penalty"``, ``"user"``, ``"user_target"`` (lists), ``"size"``.
    """
    i = 0
    lay = {"J": np.arange(0), "user": [], "user_target": []}
    if fi.use_constraints:
        lay["J"] = np.arange(fi.system.K)
        i = fi.system.K
    if fi.use_energy:
        lay["energy"], lay["energy_target"] = i, i + 1
        i += 2
    for _ in fi.user:
        lay["user"].append(i)
        lay["user_target"].append(i + 1)
        i += 2
    if fi.use_penalty:
        lay["penalty"] = i
        i += 1
    lay["size"] = i
    return lay


def parameters(fi, gains=None):
    """The parameter array ``(..., size)`` (gains, targets) of ``fi`` for :func:`parameter_layout`.

    ``gains`` (optional) overrides ``fi.gains`` (e.g. all zero); targets may be
    per trajectory (an ensemble built from a batch ``y0``), hence the batch axes.
    """
    g = fi.gains if gains is None else gains
    cols = []
    if fi.use_constraints:
        cols += [g[f"J_{i + 1}"] for i in range(fi.system.K)]
    if fi.use_energy:
        cols += [g["energy"], fi._eh]
    for u, tgt in zip(fi.user, fi._user_targets):
        cols += [g[u.name], tgt]
    if fi.use_penalty:
        cols.append(g["penalty"])
    try:  # the common case: every gain and target a number
        return np.array(cols, dtype=float)
    except (TypeError, ValueError):  # per-trajectory targets (an ensemble)
        cols = [np.asarray(c, dtype=float) for c in cols]
        shape = np.broadcast_shapes(*(c.shape for c in cols))
        return np.stack([np.broadcast_to(c, shape) for c in cols], -1)


def symbolic_constrained_field(system, y, *, configuration=True):
    """The original constrained field (multipliers ``lambda = C^{-1}{h, J}``), mirror of
    :func:`~liefi.reduction.core.full_vector_field` with ``kind="constrained"``."""
    sp = system.space
    nc = sp.group.config_dim if configuration else 0
    g, z = y[:nc], y[nc:]
    t = symbolic_terms(system, z)
    zdot, dH = _reduced_field(system, z, t, extended=False)
    if not nc:
        return zdot
    n, d = sp.n, sp.d
    gdot = _sym(sp.group.config_rate(g, dH[n : n + d]))
    return _sym(np.concatenate([gdot, zdot]))


# --- invariants for a projection after every step (the ManifoldProjection peer) ---------------


def orthogonal_blocks(group, offset=0):
    """``[(first index, k), ...]``: the ``k x k`` orthogonal matrices stored in a group's embedding.

    Read from the group's structure (an orthogonal :class:`~liefi.groups.base.MatrixLieGroup`,
    the rotation factor of :class:`~liefi.groups.SE2`, the factors of a product);
    :func:`check_orthogonal_blocks` verifies the result against the group's penalty.
    """
    from .groups.base import MatrixLieGroup
    from .groups.product import ProductGroup
    from .groups.se2 import SE2

    if isinstance(group, ProductGroup):
        out = []
        for f, o in zip(group.factors, group._cfg[:-1]):
            out += orthogonal_blocks(f, offset + int(o))
        return out
    if isinstance(group, SE2):
        return orthogonal_blocks(group.rotation_group, offset)
    if isinstance(group, MatrixLieGroup) and group.orthogonal:
        return [(offset, group.matrix_dim)]
    return []


def check_orthogonal_blocks(group, blocks, rng=None):
    """Raise :class:`NotCompilable` unless ``sum 1/4 ||R^T R - I||^2`` over ``blocks`` is the group's penalty."""
    rng = np.random.default_rng(0) if rng is None else rng
    g = rng.normal(size=group.config_dim)
    want = float(group.penalty(g))
    got = 0.0
    for o, k in blocks:
        R = g[o : o + k * k].reshape(k, k)
        S = R.T @ R - np.eye(k)
        got += 0.25 * float(np.sum(S * S))
    if not np.isclose(got, want, rtol=1e-12, atol=1e-14):
        raise NotCompilable(
            f"projection: cannot tell which numbers of {group!r}'s embedding form orthogonal matrices "
            f"(penalty {want:.6g} vs {got:.6g} from the blocks found)"
        )


def projection_targets(fi):
    """Parameters of :func:`symbolic_invariant_residuals`: ``[h0, user targets...]`` from ``fi.y0``."""
    vals = fi.invariant_values(fi.y0)
    return np.array([float(np.asarray(vals["h"]).reshape(-1)[0])] + [float(np.asarray(t).reshape(-1)[0]) for t in fi._user_targets])


def invariant_residual_names(fi):
    """Names of the residuals of :func:`symbolic_invariant_residuals`, in order."""
    names = []
    if fi.configuration:
        for o, k in orthogonal_blocks(fi.system.space.group):
            names += [f"RtR-I[{o}:{i}{j}]" for i in range(k) for j in range(i, k)]
    names += [f"J_{i + 1}" for i in range(fi.system.K)]
    names.append("h")
    names += [u.name for u in fi.user]
    return names


def symbolic_invariant_residuals(fi, y, params):
    """Residuals ``r(y)`` whose zero set is the invariant set, and their Jacobian ``(m, N)``.

    ``r`` = the upper triangle of ``R^T R - I`` for every orthogonal block of the
    configuration, every ``J_i``, ``h - h0`` (the original energy: the peer
    integrates the original constrained equations) and every user invariant
    minus its target.
    """
    sys = fi.system
    nc = fi.nc
    g, z = y[:nc], y[nc:]
    res = []
    if fi.configuration:
        blocks = orthogonal_blocks(sys.space.group)
        check_orthogonal_blocks(sys.space.group, blocks)
        for o, k in blocks:
            R = g[o : o + k * k].reshape(k, k)
            S = R.T @ R - np.eye(k)
            res += [S[i, j] for i in range(k) for j in range(i, k)]
    t = symbolic_terms(sys, z)
    res += list(t.J)
    res.append(t.h.item() - params[0])
    for j, u in enumerate(fi.user):
        res.append(symbolic_invariant(u, z)[0] - params[1 + j])
    r = np.empty(len(res), dtype=object)
    r[:] = [as_sym(v.item() if isinstance(v, np.ndarray) else v) for v in res]
    return r, jacobian(r, list(y)).T  # (m,), (m, N)


def symbolic_dla_update(system, q_prev, q_curr, h):
    """``q_{i+2}`` of the DLA scheme for a system on ``T*R^n`` with constant metric (mirror of
    :meth:`liefi.dla.DLAIntegrator._advance` with ``A(q) = E(q) M`` and ``U`` the potential)."""
    M = system.metric.value
    Minv = system._minv
    E, _ = symbolic_datum(system.constraints, q_curr)
    _, dU = symbolic_datum(system.potential, q_curr)
    g = np.zeros(system.space.n, dtype=object) if dU is None else dU
    delta = (q_curr - q_prev) - (h * h) * (g @ Minv)
    if system.K:
        A = np.asarray(E, dtype=object) @ M
        AMinv = A @ Minv
        S = AMinv @ A.T
        rhs = np.einsum("kj,j->k", A, delta)
        mu = _sym_solve(S, rhs)
        step = delta - np.einsum("kj,k->j", AMinv, mu)
    else:
        step = delta
    return _sym(q_curr + step)


# ======================================================================================
# 4. Code generation
# ======================================================================================


def _literal(v):
    if v != v:
        return "math.nan"
    if v in (math.inf, -math.inf):
        return "math.inf" if v > 0 else "(-math.inf)"
    r = repr(float(v))
    return f"({r})" if v < 0 or r.startswith("-") else r


def function_source(name, outputs, args=("y", "p", "out")):
    """Python source of ``def name(*args)`` writing ``outputs`` (Syms) into ``out[j]``.

    One assignment per reachable node, in creation order (a topological order
    of the graph).
    """
    outputs = [as_sym(o) for o in np.asarray(outputs, dtype=object).reshape(-1)]
    seen = {}
    stack = list(outputs)
    while stack:
        node = stack.pop()
        if node.id in seen or node.op == "const":
            continue
        seen[node.id] = node
        if node.op != "var":
            stack.extend(node.args)
    ref = {}
    lines = [f"def {name}({', '.join(args)}):"]
    for node in sorted(seen.values(), key=lambda s: s.id):
        if node.op == "var":
            ref[node.id] = f"{node.args[0]}[{node.args[1]}]"
            continue
        a = [_literal(x.value) if x.op == "const" else ref[x.id] for x in node.args]
        if node.op == "pow" and node.args[1].op == "const":
            c = node.args[1].value
            expr = f"({a[0]} ** {_literal(c)})"
        elif node.op in _BINARY:
            expr = _BINARY[node.op].format(*a)
        else:
            expr = _UNARY[node.op].format(*a)
        lines.append(f"    t{node.id} = {expr}")
        ref[node.id] = f"t{node.id}"
    for j, o in enumerate(outputs):
        val = _literal(o.value) if o.op == "const" else ref[o.id]
        lines.append(f"    {args[-1]}[{j}] = {val}")
    if len(lines) == 1 or not outputs:
        lines.append("    return")
    return "\n".join(lines) + "\n"


_HEADER = '''\
# Generated by liefi.compiled -- do not edit.  The source hash names this file.
import math
import numpy as np
{imports}
'''
_NUMBA_IMPORTS = "from numba import njit, prange\n"
_PYTHON_IMPORTS = '''\
def njit(*args, **kwargs):
    if args and callable(args[0]):
        return args[0]
    return lambda f: f
prange = range
'''


def _step_source(scheme, N, rhs="rhs"):
    """Body lines (indent 8) of one explicit RK step ``y -> y`` with buffers ``k0..``, ``yi``.

    Same arithmetic order as :meth:`liefi.schemes.ExplicitRungeKutta.step`:
    ``y_i = ((y + (dt a_i0) k_0) + (dt a_i1) k_1) + ...`` skipping zero
    coefficients, and likewise for the update with ``b``.
    """
    L = []
    for i in range(scheme.stages):
        coeffs = [(j, a) for j, a in enumerate(scheme.A[i][:i]) if a]
        if not coeffs:
            L.append(f"        {rhs}(y, p, k{i})")
            continue
        terms = " + ".join(f"c{i}_{j} * k{j}[i]" for j, _ in coeffs)
        L.append(f"        for i in range({N}):")
        L.append(f"            yi[i] = y[i] + {terms}")
        L.append(f"        {rhs}(yi, p, k{i})")
    terms = " + ".join(f"cb{j} * k{j}[i]" for j, b in enumerate(scheme.b) if b)
    L.append(f"        for i in range({N}):")
    L.append(f"            y[i] = y[i] + {terms}")
    return L


def _coeff_source(scheme):
    L = []
    for i in range(scheme.stages):
        for j, a in enumerate(scheme.A[i][:i]):
            if a:
                L.append(f"    c{i}_{j} = dt * {a!r}")
    for j, b in enumerate(scheme.b):
        if b:
            L.append(f"    cb{j} = dt * {b!r}")
    return L


def loop_source(fname, scheme, N, cache, *, project=False):
    """Source of the fixed-step loop of one trajectory (and its batch version ``fname + '_batch'``).

    ``fname(y0, p, dt, n_steps, save_every, check_every, out, bad, last, pp, maxit, tol)``
    returns ``(failed_step, last_good_step, projection_evaluations)``; ``failed_step == 0``
    means success.  ``out`` ``(N, n_saved)`` receives the saved states,
    ``bad``/``last`` the first non-finite state and the last finite one.  With
    ``project`` every step is followed by the Newton projection ``project(y, pp, ...)``.
    """
    S = scheme.stages
    L = [f"@njit(cache={cache}, error_model='numpy')", f"def {fname}(y0, p, dt, n_steps, save_every, check_every, out, bad, last, pp, maxit, tol):"]
    L.append("    y = y0.copy()")
    for i in range(S):
        L.append(f"    k{i} = np.empty({N})")
    L += ["    yi = np.empty(%d)" % N]
    if project:
        L += ["    buf = np.empty(PROJ_SIZE)", "    GG = np.empty((PROJ_M, PROJ_M))", "    lam = np.empty(PROJ_M)"]
    L += _coeff_source(scheme)
    L += [
        f"    for i in range({N}):",
        "        out[i, 0] = y[i]",
        "        last[i] = y[i]",
        "    j = 1",
        "    last_step = 0",
        "    nproj = 0",
        "    for step in range(1, n_steps + 1):",
    ]
    L += _step_source(scheme, N)
    if project:
        L.append("        nproj += project(y, pp, buf, GG, lam, maxit, tol)")
    L += [
        "        if step % check_every == 0 or step == n_steps:",
        "            s = 0.0",
        f"            for i in range({N}):",
        "                s += y[i]",
        "            if not (s - s == 0.0):",
        f"                for i in range({N}):",
        "                    bad[i] = y[i]",
        "                return step, last_step, nproj",
        f"            for i in range({N}):",
        "                last[i] = y[i]",
        "            last_step = step",
        "        if step % save_every == 0 or step == n_steps:",
        f"            for i in range({N}):",
        "                out[i, j] = y[i]",
        "            j += 1",
        "    return 0, last_step, nproj",
        "",
        "",
        f"@njit(parallel=True, cache={cache}, error_model='numpy')",
        f"def {fname}_batch(Y0, P, dt, n_steps, save_every, check_every, OUT, BAD, LAST, PP, maxit, tol, STATUS):",
        "    for b in prange(Y0.shape[0]):",
        f"        r = {fname}(Y0[b], P[b], dt, n_steps, save_every, check_every, OUT[b], BAD[b], LAST[b], PP[b], maxit, tol)",
        "        STATUS[b, 0] = r[0]",
        "        STATUS[b, 1] = r[1]",
        "        STATUS[b, 2] = r[2]",
        "",
    ]
    return "\n".join(L) + "\n"


_PROJECT_SOURCE = '''
@njit(cache={cache}, error_model='numpy')
def project(y, pp, buf, GG, lam, maxit, tol):
    """Newton projection onto resid(y) = 0 along G^T (G G^T)^{{-1}}: returns evaluations used."""
    M = PROJ_M
    N = {N}
    nev = 0
    for it in range(maxit + 1):
        resid(y, pp, buf)
        nev += 1
        rmax = 0.0
        for a in range(M):
            rmax = max(rmax, abs(buf[a]))
        if rmax <= tol or it == maxit:
            break
        for a in range(M):
            for c in range(a + 1):
                s = 0.0
                for i in range(N):
                    s += buf[M + a * N + i] * buf[M + c * N + i]
                GG[a, c] = s
        # Cholesky G G^T = L L^T in the lower triangle, then two triangular solves
        for a in range(M):
            for c in range(a + 1):
                s = GG[a, c]
                for k in range(c):
                    s -= GG[a, k] * GG[c, k]
                if a == c:
                    GG[a, a] = math.sqrt(s) if s > 0.0 else 1e-300
                else:
                    GG[a, c] = s / GG[c, c]
        for a in range(M):
            s = buf[a]
            for k in range(a):
                s -= GG[a, k] * lam[k]
            lam[a] = s / GG[a, a]
        for a in range(M - 1, -1, -1):
            s = lam[a]
            for k in range(a + 1, M):
                s -= GG[k, a] * lam[k]
            lam[a] = s / GG[a, a]
        for i in range(N):
            s = 0.0
            for a in range(M):
                s += buf[M + a * N + i] * lam[a]
            y[i] -= s
    return nev
'''

_DLA_LOOP = '''
@njit(cache={cache}, error_model='numpy')
def dla_run(q0, q1, p, n_steps, save_every, out, bad):
    """q_0 .. q_N of the DLA scheme; out[:, j] holds q at saved index j, out[:, j + n_saved] the
    previous point (for the discrete momentum).  Returns the failing update index (0: success)."""
    n = {n}
    ns = out.shape[1] // 2
    qp = q0.copy()
    qc = q1.copy()
    qn = np.empty(n)
    j = 0
    for k in range(0, n_steps + 1):
        if k >= 2:
            dla_update(qp, qc, p, qn)
            s = 0.0
            for i in range(n):
                s += qn[i]
            if not (s - s == 0.0):
                for i in range(n):
                    bad[i] = qn[i]
                return k - 1
            for i in range(n):
                qp[i] = qc[i]
                qc[i] = qn[i]
        if k % save_every == 0 or k == n_steps:
            for i in range(n):
                out[i, j] = qp[i] if k == 0 else qc[i]
                out[i, j + ns] = qp[i]
            j += 1
    return 0
'''


# --- building and caching modules ----------------------------------------------------------------

_MODULES: dict = {}
_LOCK = threading.RLock()


def cache_dir():
    """Directory of generated kernels (``$LIEFI_CACHE_DIR``, default ``~/.cache/liefi/kernels``)."""
    d = os.environ.get("LIEFI_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "liefi", "kernels")
    try:
        os.makedirs(d, exist_ok=True)
        probe = os.path.join(d, f".probe{os.getpid()}")
        with open(probe, "w") as fh:
            fh.write("")
        os.remove(probe)
        return d
    except OSError:
        d = os.path.join(tempfile.gettempdir(), f"liefi-kernels-{os.getuid() if hasattr(os, 'getuid') else 0}")
        os.makedirs(d, exist_ok=True)
        return d


def load_module(source, engine="numba"):
    """Import generated ``source`` (numba: from a file in :func:`cache_dir`, so numba's cache works)."""
    if engine == "numba" and _nb() is None:
        raise RuntimeError(f"numba is not available ({NUMBA_ERROR}); install liefi[fast] or use engine='python'")
    if engine not in ("numba", "python"):
        raise ValueError(f"engine: expected 'numba' or 'python', got {engine!r}")
    imports = _NUMBA_IMPORTS if engine == "numba" else _PYTHON_IMPORTS
    text = _HEADER.format(imports=imports) + source
    tag = f"{engine}-{_nb().__version__ if engine == 'numba' else ''}-{np.__version__}"
    key = hashlib.sha1((tag + text).encode()).hexdigest()[:24]
    with _LOCK:
        mod = _MODULES.get(key)
        if mod is not None:
            return mod
        name = f"liefi_kernel_{key}"
        if engine == "python":
            mod = type(sys)(name)
            exec(compile(text, f"<{name}>", "exec"), mod.__dict__)  # noqa: S102 -- our own generated code
        else:
            path = os.path.join(cache_dir(), name + ".py")
            if not os.path.exists(path):
                tmp = f"{path}.{os.getpid()}.{threading.get_ident()}.tmp"
                with open(tmp, "w") as fh:
                    fh.write(text)
                os.replace(tmp, path)
            spec = importlib.util.spec_from_file_location(name, path)
            mod = importlib.util.module_from_spec(spec)
            sys.modules[name] = mod
            spec.loader.exec_module(mod)
        _MODULES[key] = mod
        return mod


# ======================================================================================
# 5. Compiled fields and their runners
# ======================================================================================


@dataclass
class CompiledField:
    """A generated, compiled right-hand side ``rhs(y, p, out)`` and its fixed-step loops.

    Attributes
    ----------
    module : module
        The generated module (``rhs``, ``run_<scheme>``, ``run_<scheme>_batch``,
        and with a projection ``resid``, ``project``, ``run_<scheme>_proj``).
    N : int
        State size.
    n_params : int
        Size of the parameter vector ``p`` (see :func:`parameter_layout`).
    kind : str
        ``"feedback"``, ``"extended"`` (no feedback), ``"constrained"``.
    engine : str
        ``"numba"`` or ``"python"``.
    build_seconds : float
        Time spent tracing and generating the source.
    compile_seconds : dict
        Compile (first call) time of each function used so far.
    projection : int
        Number of invariant residuals of the projection (0: none).
    nodes : int
        Size of the traced graph (a measure of the generated code).
    """

    module: object
    N: int
    n_params: int
    kind: str
    engine: str
    build_seconds: float
    compile_seconds: dict
    projection: int = 0
    nodes: int = 0

    def rhs(self, y, p):
        """The field at one state ``y`` (shape ``(N,)``) with parameters ``p``."""
        out = np.empty(self.N)
        self._timed("rhs", self.module.rhs, np.ascontiguousarray(y, dtype=float), np.ascontiguousarray(p, dtype=float), out)
        return out

    def fun(self, p):
        """``fun(t, y)`` for ``scipy.integrate.solve_ivp`` with the parameters ``p`` fixed."""
        p = np.ascontiguousarray(p, dtype=float)
        f = self.module.rhs
        N = self.N
        self.rhs(np.zeros(N), p)  # compile outside the solver's timing

        def fun(t, y):
            out = np.empty(N)
            f(np.ascontiguousarray(y, dtype=float), p, out)
            return out

        return fun

    def _timed(self, key, fn, *args):
        if key in self.compile_seconds:
            return fn(*args)
        t = time.perf_counter()
        r = fn(*args)
        self.compile_seconds[key] = time.perf_counter() - t
        return r

    def warmup(self, scheme="euler", *, batch=False, project=False):
        """Compile the loop of ``scheme`` now (the first call of a numba function compiles it)."""
        from .schemes import get_scheme

        sch = get_scheme(scheme)
        fname = f"run_{sch.name}" + ("_proj" if project else "")
        key = fname + ("_batch" if batch else "")
        if key in self.compile_seconds:
            return self.compile_seconds[key]
        N, npar = self.N, self.n_params
        pp = np.zeros(max(1, self.projection + 1))
        t = time.perf_counter()
        if batch:
            getattr(self.module, fname + "_batch")(
                np.zeros((1, N)), np.zeros((1, npar)), 1.0, 0, 1, 1, np.zeros((1, N, 1)), np.zeros((1, N)),
                np.zeros((1, N)), np.zeros((1, pp.size)), 0, 0.0, np.zeros((1, 3), np.int64),
            )
        else:
            getattr(self.module, fname)(np.zeros(N), np.zeros(npar), 1.0, 0, 1, 1, np.zeros((N, 1)), np.zeros(N), np.zeros(N), pp, 0, 0.0)
        self.compile_seconds[key] = time.perf_counter() - t
        return self.compile_seconds[key]

    def run(self, y0, p, dt, n_steps, scheme="euler", *, save_every=1, check_every=1, t0=0.0, names=(),
            project=None, maxit=3, tol=1e-14):
        """Step from ``y0`` (shape ``(N,)`` or ``(..., N)``: an ensemble) with a fixed-step scheme.

        Parameters as :func:`liefi.schemes.integrate`; ``p`` is ``(n_params,)`` or per
        trajectory ``(..., n_params)``.  ``project`` (parameters of the residuals,
        e.g. :func:`projection_targets`) projects onto the invariant set after every
        step by Newton's method (at most ``maxit`` iterations, stop at ``max |r| <= tol``).

        Returns
        -------
        Solution
            As :func:`liefi.schemes.integrate`, with extra attributes
            ``wall_seconds`` (elapsed time of the loop; ``cpu_seconds`` is process
            time, summed over threads), ``compile_seconds`` (first-call compile of
            the loop, 0 if it was compiled before), ``backend`` and, with a
            projection, ``projection_evaluations``.
        """
        from .schemes import IntegrationError, Solution, _fail, get_scheme, run_arguments  # noqa: F401

        sch, dt, n_steps, save_every = run_arguments(scheme, dt, n_steps, save_every)
        check_every = max(1, int(check_every))
        if project is not None and not self.projection:
            raise ValueError("project: this compiled field has no invariant residuals (compile it with projection=True)")
        y0 = np.array(y0, dtype=float)
        if y0.shape[-1:] != (self.N,):
            raise ValueError(f"y0: expected shape (..., {self.N}), got {y0.shape}")
        if not np.all(np.isfinite(y0)):
            raise ValueError("y0: the initial state contains non-finite numbers")
        idx = np.arange(0, n_steps + 1, save_every)
        if idx[-1] != n_steps:
            idx = np.append(idx, n_steps)
        ns = idx.size
        batch = y0.shape[:-1]
        p = np.asarray(p, dtype=float)
        pp = np.atleast_1d(np.asarray(project if project is not None else [0.0], dtype=float))
        fname = f"run_{sch.name}" + ("_proj" if project is not None else "")
        compile_s = 0.0
        if batch == ():
            if p.ndim != 1:
                raise ValueError(f"p: expected shape ({self.n_params},) for one trajectory, got {p.shape}")
            key = fname
            if key not in self.compile_seconds:
                compile_s = self.warmup(sch, project=project is not None)
            out = np.empty((self.N, ns))
            bad, last = np.empty(self.N), np.empty(self.N)
            c0, w0 = time.process_time(), time.perf_counter()
            failed, last_step, nproj = getattr(self.module, fname)(
                y0, np.ascontiguousarray(p), dt, n_steps, save_every, check_every, out, bad, last, pp, int(maxit), float(tol)
            )
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        else:
            B = int(np.prod(batch))
            Y0 = np.ascontiguousarray(y0.reshape(B, self.N))
            P = np.ascontiguousarray(np.broadcast_to(p, batch + (self.n_params,)).reshape(B, self.n_params))
            PP = np.ascontiguousarray(np.broadcast_to(pp, batch + pp.shape[-1:]).reshape(B, -1))
            key = fname + "_batch"
            if key not in self.compile_seconds:
                compile_s = self.warmup(sch, batch=True, project=project is not None)
            OUT = np.empty((B, self.N, ns))
            BAD, LAST = np.empty((B, self.N)), np.empty((B, self.N))
            STATUS = np.zeros((B, 3), np.int64)
            c0, w0 = time.process_time(), time.perf_counter()
            getattr(self.module, key)(Y0, P, dt, n_steps, save_every, check_every, OUT, BAD, LAST, PP, int(maxit), float(tol), STATUS)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            failing = np.nonzero(STATUS[:, 0])[0]
            nproj = int(STATUS[:, 2].sum())
            if failing.size:
                first = failing[np.argmin(STATUS[failing, 0])]
                failed, last_step = int(STATUS[first, 0]), int(STATUS[first, 1])
                bad = BAD[first]
                last = LAST.reshape(batch + (self.N,))
            else:
                failed, last_step = 0, n_steps
            out = OUT.reshape(batch + (self.N, ns))
        if failed:
            _fail(bad, last, last_step, failed, t0, dt, sch, tuple(names), None)
        t = t0 + dt * idx.astype(float)
        sol = Solution(t, out, sch.name, dt, n_steps, n_steps * sch.stages, cpu, tuple(names))
        sol.wall_seconds = wall
        sol.compile_seconds = compile_s
        sol.backend = self.engine
        if project is not None:
            sol.projection_evaluations = int(nproj)
        return sol


@dataclass
class CompiledDLA:
    """The DLA scheme compiled for a system on ``T*R^n`` with a constant metric (:func:`compile_dla`)."""

    module: object
    n: int
    mass: np.ndarray
    engine: str
    build_seconds: float
    compile_seconds: dict

    def run(self, q0, q1, h, n_steps, *, save_every=1, t0=0.0):
        """``(t, q, p, cpu_seconds, updates)`` with ``q, p`` of shape ``(n, n_saved)`` and
        ``p_k = M (q_k - q_{k-1}) / h`` (``p_0 = M (q_1 - q_0)/h``), as :meth:`liefi.dla.DLAIntegrator.run`."""
        from .dla import DLANonFiniteError

        n_steps, save_every = int(n_steps), max(1, int(save_every))
        idx = list(range(0, n_steps + 1, save_every))
        if idx[-1] != n_steps:
            idx.append(n_steps)
        ns = len(idx)
        p = np.array([float(h)])
        if "dla_run" not in self.compile_seconds:
            t = time.perf_counter()
            self.module.dla_run(np.zeros(self.n), np.zeros(self.n), p, 0, 1, np.zeros((self.n, 2)), np.zeros(self.n))
            self.compile_seconds["dla_run"] = time.perf_counter() - t
        out = np.empty((self.n, 2 * ns))
        bad = np.empty(self.n)
        c0 = time.process_time()
        failed = self.module.dla_run(np.array(q0, float), np.array(q1, float), p, n_steps, save_every, out, bad)
        cpu = time.process_time() - c0
        if failed:
            raise DLANonFiniteError("q", int(failed), t0 + (failed + 1) * h)
        q, qprev = out[:, :ns], out[:, ns:]
        mom = (self.mass @ (q - qprev)) / h
        mom[:, 0] = self.mass @ (np.asarray(q1, float) - np.asarray(q0, float)) / h
        return t0 + h * np.array(idx, float), q, mom, cpu, max(n_steps - 1, 0)


_KERNELS: dict = {}


def _engine(engine):
    if engine is None:
        return "numba" if _nb() is not None else "python"
    return engine


def _fi_key(fi, kind, extra=()):
    return (
        kind, fi.nc, fi.configuration, fi.field, fi.energy, fi.use_constraints, fi.use_energy,
        tuple((u.name, id(u.fun), id(u.grad)) for u in fi.user), fi.use_penalty,
        None if fi.A is None else fi.A.tobytes(), extra,
    )


def _build(system, key, engine, make):
    """Trace and generate with ``make() -> (source, N, n_params, kind, projection, nodes)``.

    Cached per system (weakly) and ``key``; the generated module itself is
    cached by the hash of its source, so an identical field compiles once.
    """
    import weakref

    engine = _engine(engine)
    full = (id(system),) + key + (engine,)
    with _LOCK:
        got = _KERNELS.get(full)
        if got is not None and got[0]() is system:
            return got[1]
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        source, N, n_params, kind, projection, nodes = make()
    build = time.perf_counter() - t
    module = load_module(source, engine)
    cf = CompiledField(module, N, n_params, kind, engine, build, {}, projection, nodes)
    with _LOCK:
        _KERNELS[full] = (weakref.ref(system), cf)
    return cf


def _loops(N, cache, projection):
    from .schemes import SCHEMES

    src = []
    for sch in SCHEMES.values():
        src.append(loop_source(f"run_{sch.name}", sch, N, cache))
        if projection:
            src.append(loop_source(f"run_{sch.name}_proj", sch, N, cache, project=True))
    return "\n".join(src)


def _graph_size():
    return len(_graph().nodes)


def compile_feedback(fi, *, feedback=True, engine=None):
    """The compiled field ``X - A grad V`` of a :class:`~liefi.FeedbackIntegrator` (or ``X`` alone).

    Parameters
    ----------
    fi : FeedbackIntegrator
    feedback : bool
        ``False``: the extended field without feedback (the same scheme with gains zero,
        without computing ``grad V`` at all).
    engine : {"numba", "python"}, optional
        Default numba when importable.

    Returns
    -------
    CompiledField
        Call ``run(y0, parameters(fi), dt, n_steps, scheme)``.

    Raises
    ------
    NotCompilable
        Naming the datum that cannot be traced.
    """
    cache = _engine(engine) == "numba"

    def make():
        with trace() as tr:
            y = tr.symbols("y", fi.n)
            lay = parameter_layout(fi)
            p = tr.symbols("p", lay["size"])
            f = symbolic_feedback_field(fi, y, p, feedback=feedback)
            src = function_source("rhs", f) + "\n\n" + _loops(fi.n, cache, False)
            src = f"@njit(cache={cache}, error_model='numpy')\n" + src
            return src, fi.n, lay["size"], "feedback" if feedback else "extended", 0, _graph_size()

    return _build(fi.system, _fi_key(fi, "feedback" if feedback else "extended"), engine, make)


def compile_constrained(fi, *, projection=False, engine=None):
    """The original constrained field on ``fi``'s state layout, with the Newton projection.

    The state is ``fi``'s ``(g, z)`` (or ``z``); the multipliers are
    ``lambda = C^{-1} {h, J}`` (``(lambda:general)``), the field is
    :func:`~liefi.reduction.core.full_vector_field` with ``kind="constrained"``.
    The module also holds ``resid`` (the residuals of
    :func:`symbolic_invariant_residuals` and their Jacobian) and ``project``
    (Newton's method along ``G^T``, the Euclidean orthogonal projection used by
    DifferentialEquations.jl's ``ManifoldProjection``); run with
    ``project=projection_targets(fi)``.  They are always generated when
    possible (numba compiles a function on its first call only, so one module
    serves ``solve_ivp`` and the projected schemes); ``projection=True`` raises
    :class:`NotCompilable` when they cannot be.
    """
    cache = _engine(engine) == "numba"

    def make():
        with trace() as tr:
            y = tr.symbols("y", fi.n)
            f = symbolic_constrained_field(fi.system, y, configuration=fi.configuration)
            src = f"@njit(cache={cache}, error_model='numpy')\n" + function_source("rhs", f)
            m = 0
            try:
                pp = tr.symbols("pp", 1 + len(fi.user))
                r, G = symbolic_invariant_residuals(fi, y, pp)
                m = r.size
                src += (
                    f"\n\nPROJ_M = {m}\nPROJ_SIZE = {m * (fi.n + 1)}\n\n"
                    + f"@njit(cache={cache}, error_model='numpy')\n"
                    + function_source("resid", np.concatenate([r, G.reshape(-1)]), ("y", "pp", "out"))
                    + _PROJECT_SOURCE.format(cache=cache, N=fi.n)
                )
            except NotCompilable:
                if projection:
                    raise
            src += "\n\n" + _loops(fi.n, cache, m > 0)
            return src, fi.n, 0, "constrained", m, _graph_size()

    cf = _build(fi.system, _fi_key(fi, "constrained"), engine, make)
    if projection and not cf.projection:
        raise NotCompilable("projection: the invariant residuals of this system could not be generated")
    return cf


def dla_applies(system):
    """Whether :mod:`liefi.dla` applies: a system on ``T*R^n`` (no group) with a constant metric
    and no vector potential."""
    return (
        system.space.d == 0 and system.metric.constant and system.space.n > 0
        and system.vector_potential is None
    )


def compile_dla(system, *, engine=None):
    """The DLA scheme of :mod:`liefi.dla` compiled for ``system`` (``A(q) = E(q) M``, ``U`` its potential)."""
    if not dla_applies(system):
        raise NotCompilable("dla: the DLA integrator applies to systems on T*R^n with a constant metric")
    engine = _engine(engine)
    cache = engine == "numba"
    key = (id(system), "dla", engine)
    with _LOCK:
        got = _KERNELS.get(key)
        if got is not None and got[0]() is system:
            return got[1]
    n = system.space.n
    t = time.perf_counter()
    with trace() as tr:
        qp, qc = tr.symbols("qp", n), tr.symbols("qc", n)
        h = tr.symbols("p", 1)[0]
        qn = symbolic_dla_update(system, qp, qc, h)
        src = f"@njit(cache={cache}, error_model='numpy')\n" + function_source("dla_update", qn, ("qp", "qc", "p", "out"))
    src += _DLA_LOOP.format(cache=cache, n=n)
    build = time.perf_counter() - t
    module = load_module(src, engine)
    out = CompiledDLA(module, n, np.array(system.metric.value), engine, build, {})
    import weakref

    with _LOCK:
        _KERNELS[key] = (weakref.ref(system), out)
    return out


# ======================================================================================
# 6. The hook used by FeedbackIntegrator.run(backend=...)
# ======================================================================================

_WARNED: set = set()


def _say(msg, key):
    if key not in _WARNED:
        _WARNED.add(key)
        warnings.warn(msg, CompilationWarning, stacklevel=4)


def run_feedback(fi, dt, n_steps, scheme, y0, save_every, check_every, backend):
    """Run ``fi`` with the compiled engine; ``None`` (after a :class:`CompilationWarning`) to use numpy.

    ``backend``: ``"numba"`` (asked for explicitly: warn when it cannot be used) or
    ``"auto"`` (the same, warning once per system).
    """
    if backend not in ("numba", "auto"):
        raise ValueError(f"backend: expected 'numpy', 'numba' or 'auto', got {backend!r}")
    if _nb() is None:
        _say(f"liefi: numba is not available ({NUMBA_ERROR}); running the numpy path. "
             "Install it with `pip install liefi[fast]`.", "nonumba")
        return None
    try:
        cf = compile_feedback(fi)
    except NotCompilable as exc:
        _say(f"liefi: the compiled engine cannot run this system ({exc}); running the numpy path.", ("nc", id(fi.system)))
        return None
    p = parameters(fi)
    return cf.run(fi.y0 if y0 is None else y0, p, dt, n_steps, scheme, save_every=save_every,
                  check_every=check_every, names=fi.names)
