r"""Symbolic scalars: the nodes of the expression graphs that :mod:`liefi.engine.trace` records.

A :class:`Sym` is built only by arithmetic inside a tracing session
(:class:`liefi.engine.trace.trace`): ``+ - * / **``, the unary functions of
``_UNARY`` and the numpy ufuncs that map to them.  The constructors fold
constants, apply exact sign and identity rules (``x + 0``, ``x * 1``,
``a - (-b) = a + b``) and hash-cons the result, so that an expression built
twice is one node: the graph is its own common-subexpression elimination.
:func:`derivative` and :func:`jacobian` differentiate a graph symbolically.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from .._codeprint import _BINARY, _UNARY  # noqa: F401 (the templates' home: liefi/_codeprint.py)
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
        self.forms = {}  # node id -> its polynomial form (:func:`_form`)

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
        raise RuntimeError("liefi.engine: symbolic arithmetic outside a tracing session")
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

    # --- a scalar that indexes like a 0-d array (``x[..., None]``, ``x.shape``), as numpy's scalars do
    shape = ()
    ndim = 0

    def __getitem__(self, key):
        return _obj0(self)[key]

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
    """The constant ``ufunc(a, b)`` when both are constants (numpy's float semantics: the tracing
    session ignores floating-point errors for its duration), else ``None``."""
    if a.op == "const" and b.op == "const":
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
    if b.op == "neg" or a.op == "neg":  # a + (-b) == a - b exactly (signs out: more sharing, x - x = 0)
        return sub(a, b.args[0]) if b.op == "neg" else sub(b, a.args[0])
    if a.id > b.id:  # a + b == b + a exactly: one canonical order shares more nodes
        a, b = b, a
    return _sum_node("add", a, b)


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
    if b.op == "neg":  # a - (-b) == a + b, (-a) - b == -(a + b): exact
        return add(a, b.args[0])
    if a.op == "neg":
        return unary("neg", add(a.args[0], b))
    return _sum_node("sub", a, b)


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
    if a.op == "neg" or b.op == "neg":  # (-a) b == -(a b) exactly
        return mul(a.args[0], b.args[0]) if a.op == b.op else unary("neg", mul(*(
            (a.args[0], b) if a.op == "neg" else (a, b.args[0]))))
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


# --- exact algebra on sums: cancellation and sin^2 + cos^2 -----------------------------
#
# Every node has a *polynomial form*: ``{monomial: coefficient}``, a monomial being the
# sorted tuple of the ids of its *atoms* (inputs, transcendental functions, divisions
# by non-constants, and nodes whose form would pass the caps below).  A sum whose
# operands' forms cancel -- a monomial's coefficients add to zero, as in
# ``(2 b - c) + (c - b)`` or ``P.(I^{-1} P)/2 - J^2/2`` for a metric and a constraint
# that share terms -- or hold ``m sin(x)^2 + m cos(x)^2`` is rebuilt from its reduced
# form, when that costs no more operations than the sum as traced.  The reduced form
# is the same function in exact arithmetic, evaluated with fewer roundings: a
# monomial is dropped when its coefficients cancel to within ``4 u (|c_1| + |c_2|)``
# (the rounding of the coefficients themselves, ``u`` the unit roundoff), and
# ``sin^2 + cos^2`` differs from 1 by a few units of rounding.  The forms are bounded
# (:data:`FORM_TERMS`, :data:`FORM_DEGREE`), so tracing stays linear in the graph.

#: the most monomials of a node's form; a larger node is an atom of the forms above it
FORM_TERMS = 12
#: the highest degree of a monomial of a form
FORM_DEGREE = 4
_CANCEL = 4.0 * np.finfo(float).eps


def _atom(node):
    return {(node.id,): 1.0}


def _scaled(f, c):
    return {m: c * v for m, v in f.items()} if c != 1.0 else f


def _form(node):
    """The polynomial form of ``node`` (memoized per graph)."""
    g = _graph()
    f = g.forms.get(node.id)
    if f is not None:
        return f
    op = node.op
    if op == "const":
        f = {(): node.value} if node.value != 0.0 else {}
    elif op == "neg":
        f = _scaled(_form(node.args[0]), -1.0)
    elif op in ("add", "sub"):
        f, _ = _combine(_form(node.args[0]), _form(node.args[1]), 1.0 if op == "add" else -1.0)
    elif op == "mul":
        f = _product(*node.args)
        if f is None:
            f = _atom(node)
    elif op == "div" and node.args[1].op == "const" and node.args[1].value != 0.0:
        f = _scaled(_form(node.args[0]), 1.0 / node.args[1].value)
    else:
        f = _atom(node)
    if len(f) > FORM_TERMS:
        f = _atom(node)
    g.forms[node.id] = f
    return f


def _product(a, b):
    if a.op == "const":
        return _scaled(_form(b), a.value)
    if b.op == "const":
        return _scaled(_form(a), b.value)
    fa, fb = _form(a), _form(b)
    if len(fa) * len(fb) > FORM_TERMS:
        return None  # too large: an atom
    out = {}
    for ma, ca in fa.items():
        for mb, cb in fb.items():
            m = tuple(sorted(ma + mb))
            if len(m) > FORM_DEGREE:
                return None
            out[m] = out.get(m, 0.0) + ca * cb
    return out


def _accumulate(out, m, c):
    """``out[m] += c``; True when the coefficients cancel (the monomial is then dropped)."""
    old = out.get(m)
    if old is None:
        out[m] = c
        return False
    s = old + c
    if abs(s) <= _CANCEL * (abs(old) + abs(c)):
        del out[m]
        return True
    out[m] = s
    return False


def _combine(fa, fb, sign):
    """``fa + sign fb`` reduced, and whether anything cancelled (or ``sin^2 + cos^2`` met).

    Both forms are reduced already, so a pair ``sin^2, cos^2`` has a monomial of ``fb`` in it."""
    out = dict(fa)
    reduced = False
    squares = []
    for m, c in fb.items():
        if m in out:
            reduced |= _accumulate(out, m, sign * c)
        else:
            out[m] = sign * c
        if len(m) > 1 and len(set(m)) < len(m):
            squares.append(m)
    return out, (_pythagoras(out, squares) if squares and fa else False) or reduced


_PARTNER = {"sin": "cos", "cos": "sin"}


def _pythagoras(f, squares):
    """Replace ``c m sin(x)^2 + c m cos(x)^2`` by ``c m`` in the form ``f`` (in place), for the
    monomials ``squares`` of ``f``; True if any."""
    g = _graph()
    changed = False
    for m in squares:
        if m not in f:
            continue
        for i in range(len(m) - 1):
            if m[i] != m[i + 1]:
                continue
            s = g.nodes[m[i]]
            other = _PARTNER.get(s.op)
            co = None if other is None else g.table.get((other, s.args))
            if co is None:
                continue
            rest = m[:i] + m[i + 2:]
            mc = tuple(sorted(rest + (co.id, co.id)))
            c, cc = f[m], f.get(mc)
            if cc is None or abs(c - cc) > _CANCEL * (abs(c) + abs(cc)):
                continue
            del f[m], f[mc]
            _accumulate(f, rest, 0.5 * (c + cc))
            changed = True
            break
    return changed


def _traced_cost(roots, atoms):
    """Operations of the graph below ``roots`` down to ``atoms`` (ids) and constants."""
    seen, stack = set(), list(roots)
    while stack:
        n = stack.pop()
        if n.id in seen or n.id in atoms or n.op in ("const", "var"):
            continue
        seen.add(n.id)
        stack.extend(n.args)
    return len(seen) + 1


def _form_cost(f):
    coeffs = {abs(c) for m, c in f.items() if m}
    return (sum(max(len(m) - 1, 0) for m in f) + max(len(f) - 1, 0)
            + len(coeffs - {1.0}) + max(len(coeffs) - 1, 0))


def _monomial(m):
    g = _graph()
    if not m:
        return const(1.0)
    t = g.nodes[m[0]]
    for i in m[1:]:
        t = mul(t, g.nodes[i])
    return t


def _rebuild(f):
    """A node computing the form ``f``: per coefficient ``c``, ``c (sum of its monomials)``."""
    groups = {}
    for m, c in f.items():
        groups.setdefault(abs(c), []).append((c, m))
    total = const(0.0)
    for c, terms in groups.items():
        plus = minus = const(0.0)
        for ci, m in terms:
            if ci > 0:
                plus = add(plus, _monomial(m))
            else:
                minus = add(minus, _monomial(m))
        total = add(total, mul(c, sub(plus, minus)))
    return total


def _sum_node(op, a, b):
    """The node ``a + b`` or ``a - b``, or its reduced form when the operands' forms cancel."""
    fa, fb = _form(a), _form(b)
    f, reduced = _combine(fa, fb, 1.0 if op == "add" else -1.0)
    if reduced:
        atoms = {i for m in list(fa) + list(fb) for i in m}
        if _form_cost(f) <= _traced_cost((a, b), atoms):
            return _rebuild(f)
    node = _graph().node(op, (a, b))
    _graph().forms.setdefault(node.id, f if len(f) <= FORM_TERMS else _atom(node))
    return node


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


def derivative(expr: Sym, var: Sym, memo: dict, support=None, bit=0) -> Sym:
    """``d expr / d var`` by forward differentiation of the graph (``memo`` per ``var``).

    ``support`` (node id -> bitmask of the variables the node depends on, :func:`_supports`) and
    ``bit`` (``var``'s): a node that does not depend on ``var`` has derivative ``0`` without a walk.
    """
    stack = [expr]
    zero = None  # const(0.0), once formed (the same node each time: hash-consed)
    while stack:
        node = stack[-1]
        if node.id in memo:
            stack.pop()
            continue
        if support is not None and not support[node.id] & bit:
            memo[node.id] = zero = const(0.0) if zero is None else zero
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
        if zero is not None and (op == "add" or op == "sub") and (db is zero or (op == "add" and da is zero)):
            # d(a +- b) with one side's derivative 0: add and sub return the other (or fold 0 +- 0 to 0), as
            # they would; only -db is formed (a sum along a chain of N terms: N^2 calls otherwise)
            other = da if db is zero else db
            if other is zero or other.op != "const":
                memo[node.id] = other
                continue
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
    # which variables each node depends on: d e / d v is 0 unwalked where e does not depend on v, so the
    # Jacobian of sparse data (a chain's constraints: each row on its own body) costs its nonzeros
    bits = {}
    for k, v in enumerate(variables):
        bits[v.id] = bits.get(v.id, 0) | (1 << k)
    support = _supports(flat, bits)
    out.fill(const(0.0))
    memos = [{} for _ in variables]
    for j, e in enumerate(flat):
        m = support[e.id]
        while m:  # the variables e depends on, lowest first
            k = (m & -m).bit_length() - 1
            m &= m - 1
            out[k, j] = derivative(e, variables[k], memos[k], support, 1 << k)
    return out.reshape((len(variables),) + values.shape)


def _supports(exprs, bits):
    """``{node id: bitmask}`` of the variables (``bits``: variable node id -> its bit) each node of ``exprs``
    depends on: its own bit, or the union of its arguments'."""
    support = {}
    for expr in exprs:
        stack = [expr]
        while stack:
            node = stack[-1]
            if node.id in support:
                stack.pop()
                continue
            if node.op == "const" or node.op == "var":  # leaves (a variable's args are its name and slot)
                support[node.id] = bits.get(node.id, 0)
                stack.pop()
                continue
            pending = [a for a in node.args if a.id not in support]
            if pending:
                stack.extend(pending)
                continue
            stack.pop()
            m = bits.get(node.id, 0)
            for a in node.args:
                m |= support[a.id]
            support[node.id] = m
    return support
