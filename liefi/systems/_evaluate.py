r"""sympy expressions evaluated at a few points without generating code (the build-time checks of ``from_mechanics``).

The checks of a model (:func:`liefi.systems._kinematics._restore`, :class:`~liefi.systems._kinematics._Checks`)
evaluate large expressions at a handful of random states.  ``lambdify`` spends its time on
common-subexpression elimination, printing and compiling code that runs a few times;
:func:`evaluator` instead walks each expression once per call, every distinct subexpression
once (a memo by structural equality), with numpy arrays holding all the points at once.
An expression with a node it does not know (other than sums, products, powers, numbers and
the elementary functions of :data:`_FUNCTIONS`) is handed to :func:`lambdify_checked` (the
one path to generated code).
"""

from __future__ import annotations

import numpy as np

from .sympy_input import lambdify_checked

#: sympy function name -> numpy function (the elementary functions; anything else goes to lambdify)
_FUNCTIONS = {
    "sin": np.sin, "cos": np.cos, "tan": np.tan, "exp": np.exp, "log": np.log, "asin": np.arcsin,
    "acos": np.arccos, "atan": np.arctan, "sinh": np.sinh, "cosh": np.cosh, "tanh": np.tanh,
    "asinh": np.arcsinh, "acosh": np.arccosh, "atanh": np.arctanh, "Abs": np.abs, "sign": np.sign,
    "atan2": np.arctan2, "cot": lambda a: 1 / np.tan(a), "sec": lambda a: 1 / np.cos(a),
    "csc": lambda a: 1 / np.sin(a),
}


class _Unknown(Exception):
    """A node the walker does not evaluate (the expressions then go to lambdify)."""


def _walk(sympy, exprs, values):
    """The values of ``exprs`` with ``values`` ``{symbol: array}`` (complex arrays of one shape)."""
    memo = dict(values)
    functions = {getattr(sympy, name): fun for name, fun in _FUNCTIONS.items()}  # sympy's own classes only

    def ev(e):
        try:
            return memo[e]
        except KeyError:
            pass
        if e.is_Add:
            args = [ev(a) for a in e.args]
            v = args[0]
            for a in args[1:]:
                v = v + a
        elif e.is_Mul:
            args = [ev(a) for a in e.args]
            v = args[0]
            for a in args[1:]:
                v = v * a
        elif e.is_Pow:
            b, p = ev(e.base), e.exp
            if p == sympy.S.Half:
                v = np.sqrt(b)
            elif p == -sympy.S.Half:
                v = 1 / np.sqrt(b)
            elif p.is_Integer:
                v = _power(b, int(p))
            else:
                v = b ** ev(p)
        elif e.is_Number or e.is_NumberSymbol or e is sympy.I:
            if not e.is_finite:
                raise _Unknown(e)
            v = float(e) if e.is_extended_real else complex(e)
        elif type(e) in functions:
            v = functions[type(e)](*[ev(a) for a in e.args])
        else:
            raise _Unknown(e)
        memo[e] = v
        return v

    return [ev(e) for e in exprs]


def _known(sympy, args):
    """The symbols an expression in ``args`` may hold: ``args`` and the free symbols of those that are not symbols
    (the time ``t`` of ``q(t)``, ``Derivative(q(t), t)``: a walk takes such an argument whole, as a key of its
    memo, and meets a bare ``t`` as a node it does not know)."""
    known = set(args)
    for a in args:
        if not isinstance(a, sympy.Symbol):
            known |= a.free_symbols
    return known


def _plain(sympy, args, exprs, wrt=()):
    """``(args, exprs, wrt)`` with every argument that is not a symbol replaced by a ``Dummy`` (for lambdify and
    sympy's ``diff``, the paths that need plain symbols): one ``xreplace``, which takes a node before its
    arguments, so ``Derivative(q(t), t)`` is replaced whole before ``q(t)``."""
    to = {a: sympy.Dummy() for a in args if not isinstance(a, sympy.Symbol)}
    if not to:
        return list(args), list(exprs), list(wrt)
    return [to.get(a, a) for a in args], [e.xreplace(to) for e in exprs], [to.get(s, s) for s in wrt]


def evaluator(sympy, args, exprs, what):
    r"""``f(*arrays) -> array (len(exprs), *shape)``: ``exprs`` (sympy, in the symbols ``args``) at the points given
    by one array per argument (broadcast to one shape), in numpy's arithmetic of the arrays given.

    The expressions are walked at each call (no code is generated): for a few calls of large
    expressions, as the checks make, this is cheaper than ``lambdify``; an expression with a node
    the walker does not know, or a symbol that is not an argument, goes to :func:`lambdify_checked`
    (whose errors, naming ``what``, it then raises).  The arguments may be dynamicsymbols ``q(t)`` and their
    derivatives ``Derivative(q(t), t)`` (a model's own expressions, walked as they are: no copy in plain symbols
    is built, whose ``xreplace`` re-forms every node and asks sympy's assumptions anew); the fallback replaces
    them by plain symbols first (:func:`_plain`).
    """
    args = list(args)
    exprs = [sympy.sympify(e, strict=True) for e in exprs]
    known = _known(sympy, args)
    compiled = []

    def f(*vals):
        if not compiled:
            try:
                if any(not (e.free_symbols <= known) for e in exprs):
                    raise _Unknown
                shape = np.broadcast_shapes(*[np.shape(v) for v in vals])
                out = _walk(sympy, exprs, {a: np.asarray(v) for a, v in zip(args, vals)})
                return np.stack([np.broadcast_to(o, shape) for o in out]) if out else np.zeros((0,) + shape)
            except _Unknown:
                compiled.append(lambdify_checked(sympy, *_plain(sympy, args, exprs)[:2], what, cse=True, dummify=True))
        shape = np.broadcast_shapes(*[np.shape(v) for v in vals])
        out = compiled[0](*vals)
        return np.stack([np.broadcast_to(np.asarray(o), shape) for o in out]) if out else np.zeros((0,) + shape)

    return f


#: d f(a) / da from the argument ``a`` and the value ``v = f(a)`` (the one-argument functions of _FUNCTIONS)
_DERIVATIVES = {
    "sin": lambda a, v: np.cos(a), "cos": lambda a, v: -np.sin(a), "tan": lambda a, v: 1 + v * v,
    "exp": lambda a, v: v, "log": lambda a, v: 1 / a, "asin": lambda a, v: 1 / np.sqrt(1 - a * a),
    "acos": lambda a, v: -1 / np.sqrt(1 - a * a), "atan": lambda a, v: 1 / (1 + a * a),
    "sinh": lambda a, v: np.cosh(a), "cosh": lambda a, v: np.sinh(a), "tanh": lambda a, v: 1 - v * v,
    "asinh": lambda a, v: 1 / np.sqrt(a * a + 1), "acosh": lambda a, v: 1 / np.sqrt(a * a - 1),
    "atanh": lambda a, v: 1 / (1 - a * a), "Abs": lambda a, v: np.sign(a), "sign": lambda a, v: 0 * a,
    "cot": lambda a, v: -(1 + v * v), "sec": lambda a, v: v * np.tan(a), "csc": lambda a, v: -v / np.tan(a),
}


def _power(b, k):
    """``b ** k`` for an integer ``k`` (a reciprocal for ``k < 0``, 1 for ``k = 0``)."""
    return 1.0 if k == 0 else b ** k if k > 0 else 1 / b ** -k


def _walk_tangent(sympy, exprs, values, tangents):
    r"""``(values, derivatives)`` of ``exprs``: forward-mode differentiation along ``tangents`` ``{symbol: array}``
    (the directional derivative ``sum_k d e / d s_k  t_k``, exact: the chain rule on each node)."""
    memo = {s: (v, tangents.get(s, 0.0)) for s, v in values.items()}
    functions = {getattr(sympy, name): name for name in _FUNCTIONS}

    def ev(e):
        try:
            return memo[e]
        except KeyError:
            pass
        if e.is_Add:
            v, d = 0.0, 0.0
            for a in e.args:
                va, da = ev(a)
                v, d = v + va, d + da
        elif e.is_Mul:
            v, d = 1.0, 0.0
            for a in e.args:
                va, da = ev(a)
                v, d = v * va, d * va + v * da
        elif e.is_Pow:
            (b, db), p = ev(e.base), e.exp
            if p == sympy.S.Half:
                v = np.sqrt(b)
                d = db / (2 * v)
            elif p.is_Integer:
                v, d = _power(b, int(p)), int(p) * _power(b, int(p) - 1) * db
            elif p.is_Number:
                v, d = b ** float(p), float(p) * b ** (float(p) - 1) * db
            else:
                vp, dp = ev(p)
                v = b ** vp
                d = v * (dp * np.log(b) + vp * db / b)
        elif e.is_Number or e.is_NumberSymbol or e is sympy.I:
            if not e.is_finite:
                raise _Unknown(e)
            v, d = (float(e) if e.is_extended_real else complex(e)), 0.0
        elif type(e) in functions and type(e) is sympy.atan2:
            (y, dy), (x, dx) = ev(e.args[0]), ev(e.args[1])
            v, d = np.arctan2(y, x), (x * dy - y * dx) / (x * x + y * y)
        elif type(e) in functions:
            (a, da), name = ev(e.args[0]), functions[type(e)]
            v = _FUNCTIONS[name](a)
            d = _DERIVATIVES[name](a, v) * da
        else:
            raise _Unknown(e)
        memo[e] = (v, d)
        return v, d

    out = [ev(e) for e in exprs]
    return [o[0] for o in out], [o[1] for o in out]


def directional(sympy, args, exprs, wrt, what):
    r"""``f(*arrays, *directions) -> (values, derivatives)``, each ``(len(exprs), *shape)``: ``exprs`` and their
    derivative along ``wrt``, ``sum_k d e / d wrt_k  direction_k`` (``dU/dt = grad U . qdot`` with the
    velocities as the directions), by forward-mode differentiation of the walk (no symbolic derivative).

    An expression with a node the walk does not know is differentiated by sympy and evaluated by
    :func:`evaluator`.
    """
    args, wrt = list(args), list(wrt)
    exprs = [sympy.sympify(e, strict=True) for e in exprs]
    known = _known(sympy, args)  # dynamicsymbols as arguments: as in evaluator
    fallback = []

    def f(*vals):
        vals, dirs = vals[: len(args)], vals[len(args):]
        shape = np.broadcast_shapes(*[np.shape(v) for v in vals + dirs])
        stacked = lambda out: np.stack([np.broadcast_to(o, shape) for o in out]) if out else np.zeros((0,) + shape)  # noqa: E731
        if not fallback:
            try:
                if any(not (e.free_symbols <= known) for e in exprs):
                    raise _Unknown
                v, d = _walk_tangent(sympy, exprs, {a: np.asarray(x) for a, x in zip(args, vals)},
                                     {s: np.asarray(t) for s, t in zip(wrt, dirs)})
                return stacked(v), stacked(d)
            except _Unknown:
                pargs, pexprs, pwrt = _plain(sympy, args, exprs, wrt)
                T = [sympy.Dummy() for _ in wrt]
                grads = [sum((e.diff(s) * t for s, t in zip(pwrt, T)), sympy.S.Zero) for e in pexprs]
                fallback.append(evaluator(sympy, pargs + T, pexprs + grads, what))
        out = fallback[0](*vals, *dirs)
        return out[: len(exprs)], out[len(exprs):]

    return f
