"""Systems from sympy: a Lagrangian and Pfaffian constraints, as sympy.physics.mechanics users hold them.

:func:`from_sympy` reads

.. math:: L(q, \\dot q) = \\tfrac12 \\dot q^T M(q) \\dot q + b(q) \\cdot \\dot q - U(q),
          \\qquad a_i(q) \\cdot \\dot q = 0 \\quad (i = 1 \\dots K),

extracts ``M = d^2 L / dqd^2``, ``b = dL/dqd (qd = 0)``, ``U = -L(qd = 0)`` and the
rows ``a_i = d c_i / dqd``, and builds the :class:`~liefi.NonholonomicSystem` on
``T*R^n`` with the Legendre transform ``p = M qd + b``: metric ``M``, vector
potential ``b``, potential ``U`` and the velocity constraints ``a_i``
(:meth:`~liefi.NonholonomicSystem.from_velocity_constraints`, which forms
``e_i = M^{-1} a_i``), so that ``H = 1/2 (p - b).M^{-1}(p - b) + U``.  Every
datum is lambdified to a batch-first numpy function that accepts complex input
(sympy's numpy printer maps ``sin``, ``sqrt``, ``exp`` ... to the numpy
ufuncs), so liefi's complex-step derivatives are exact.

sympy is an optional dependency (``pip install "liefi[sympy]"``), imported only here.
"""

from __future__ import annotations

import abc
import keyword
import sys

import numpy as np

from ._coefficients import linear_coefficients

__all__ = ["from_sympy", "NotQuadraticError", "NonlinearConstraintError"]


class NotQuadraticError(ValueError):
    """``L`` is not kinetic energy quadratic in the velocities plus terms linear in them plus a potential."""


class NonlinearConstraintError(ValueError):
    """A constraint is not linear and homogeneous in the velocities (``a(q) . qd = 0``)."""


def _sympy():
    try:
        import sympy
    except ImportError:  # pragma: no cover - depends on the environment
        raise ImportError(
            "liefi.from_sympy needs sympy: pip install \"liefi[sympy]\" (or pip install sympy)"
        ) from None
    return sympy


def _symbols(sympy, seq, name):
    seq = list(seq) if isinstance(seq, (list, tuple)) else None
    if not seq:
        raise ValueError(f"{name}: expected a non-empty list of sympy Symbols")
    sympy_only(sympy, [s for s in seq if isinstance(s, sympy.Basic)], name)  # before any method of theirs runs
    for s in seq:
        if not isinstance(s, (sympy.Symbol, sympy.Function, sympy.Derivative)) or (
            isinstance(s, sympy.Function) and not isinstance(s, sympy.core.function.AppliedUndef)
        ):
            raise ValueError(f"{name}: expected sympy Symbols (or dynamicsymbols), got {s!r}")
    if len(set(seq)) != len(seq):
        raise ValueError(f"{name}: the symbols must be distinct, got {seq}")
    return seq


def plain_identifier(name):
    """True if ``name`` may appear in generated code as itself: an ASCII Python identifier, not a
    keyword, not starting with ``__`` (``__import__``, ``__builtins__``)."""
    return isinstance(name, str) and name.isascii() and name.isidentifier() and not keyword.iskeyword(name) \
        and not name.startswith("__")


#: what ``sympy.Function("f", real=True)`` writes into the class it makes, besides ``is_<assumption>`` flags
_UNDEFINED_KEYS = frozenset({"__doc__", "__module__", "_explicit_class_assumptions", "_kwargs", "_nargs",
                             "_prop_handler", "_sage_", "default_assumptions", "name"})
#: id(class) -> (class, why it is refused or None): the verdicts of :func:`_foreign` on classes other than
#: undefined functions (sympy makes a new class per ``Function(name)`` call; those are judged each time)
_VERDICTS = {}


def _foreign(sympy, cls):
    """``None`` if ``cls`` and every class it derives from are sympy's own, else why not (a phrase).

    sympy's own: defined in a ``sympy`` module and found there by its name, or an undefined function
    that ``sympy.Function(name, **assumptions)`` made (``dynamicsymbols`` too) with nothing but
    assumptions in it -- no ``_imp_`` (``implemented_function``), no method, no printer hook.
    """
    from sympy.core.assumptions import _assume_defined
    from sympy.core.function import UndefinedFunction

    for k in cls.__mro__[:-1]:  # object last
        if isinstance(k, UndefinedFunction):
            d = vars(k)
            if "_imp_" in d:
                return (f"the implemented function {_shown(k.__name__)} (sympy's implemented_function: its Python "
                        "implementation would run)")
            extra = sorted(key for key in d if key not in _UNDEFINED_KEYS and not (
                key.startswith("is_") and key[3:] in _assume_defined and d[key] in (True, False, None)))
            extra += [key for key in d.get("_kwargs", {}) if key not in _assume_defined]
            if extra or not isinstance(d.get("name"), str):
                return (f"the function {_shown(k.__name__)} made by sympy.Function with attributes "
                        f"{[_shown(e, 30) for e in extra]} besides assumptions")
            continue
        if k is abc.ABC:  # no code of its own (sympy's tensors derive from it)
            continue
        mod = getattr(k, "__module__", None) or ""
        found = sys.modules.get(mod) if mod.split(".")[0] == "sympy" else None
        for part in k.__qualname__.split("."):
            found = getattr(found, part, None)
        if found is not k:
            return f"an object of the class {_shown(k.__name__)} (of {_shown(mod or 'no module')}), not one of sympy's own"
    return None


def sympy_only(sympy, exprs, what):
    """Refuse (``ValueError`` naming ``what``) any part of ``exprs`` whose class is not sympy's own (:func:`_foreign`).

    liefi reads, differentiates, evaluates and prints the model's expressions; a class of the user's
    (a ``Function`` subclass with its own ``eval``, ``_numpycode``, ``_lambdacode``, ``_sympystr`` ...,
    a ``Symbol`` subclass, an ``implemented_function``) would run its code inside liefi's (sympy's
    printers call the hooks) or be printed under a name that means something else (a class named
    ``sin`` as numpy's sine).  Strings are refused too (``TypeError``: turning text into an expression
    runs it).  Every distinct node is visited once, before liefi calls any of its methods.
    """
    stack, seen = list(exprs), set()
    while stack:
        e = stack.pop()
        if id(e) in seen:
            continue
        seen.add(id(e))
        if isinstance(e, (str, bytes)):
            raise TypeError(f"{what}: got a string ({_shown(e)}); liefi takes sympy expressions only, since turning "
                            "text into an expression runs it as Python code (sympify) and liefi runs no code it did "
                            "not write; parse text you trust yourself (sympy.parsing.sympy_parser.parse_expr)")
        if type(e) in (int, float, complex, bool):
            continue
        cls = type(e)
        got = _VERDICTS.get(id(cls))
        if got is None or got[0] is not cls:
            got = (cls, _foreign(sympy, cls))
            if not isinstance(cls, sympy.core.function.UndefinedFunction):
                _VERDICTS[id(cls)] = got
        if got[1] is not None:
            raise ValueError(
                f"{what}: contains {got[1]}; liefi evaluates sympy's own classes only and runs no code it did not "
                "write (a method or printer hook of the class would run, or its name would stand for another "
                "function): write it with sympy's functions (expr.replace(f, lambda x: ...)), or build the "
                "NonholonomicSystem from numpy functions of your own"
            )
        if isinstance(e, sympy.MatrixBase):
            stack.extend(e)
        elif isinstance(e, sympy.Basic):
            stack.extend(e.args)
        else:
            raise ValueError(f"{what}: contains {_shown(type(e).__name__)}, not a sympy expression")


def checked_names(sympy, expr, what, known=()):
    """``expr`` with names liefi may print into generated code, or a ``ValueError`` naming the first that it may not.

    ``sympy.lambdify`` writes the name of every symbol and function into the Python source it
    executes, so a name from outside data (``sympy.Function("__import__('os').system('...')")``,
    a symbol named ``"x; ..."``) would run as code, and a name of the code's own (``sin``, ``x0``
    of its common subexpressions, ``_Dummy_12`` of an argument) would stand for something else.
    The ``known`` symbols (the arguments, which liefi replaces by names of its own) pass; an
    undefined function (``sympy.Function("f")(x)``) is refused, since it has no value and its name
    would be code; every other symbol (a bound variable: a ``Sum``'s index) is renamed to a liefi
    ``Dummy``, whatever its name; every other name (a ``Str`` ...) must be a :func:`plain_identifier`.
    The classes are :func:`sympy_only`'s to check (before this walk).
    """
    from sympy.core.function import AppliedUndef

    known, rename = set(known), {}
    for node in sympy.preorder_traversal(expr):
        if isinstance(node, sympy.Symbol):
            if node not in known:
                rename.setdefault(node, sympy.Dummy(f"s{len(rename)}"))
            continue
        if isinstance(node, AppliedUndef):
            raise ValueError(
                f"{what}: contains the undefined function {_shown(node.func.__name__)} (a sympy.Function without "
                "an expression): liefi cannot evaluate it and never turns a name into code; replace it by an "
                "expression of the coordinates and parameters (expr.subs(f(x), ...)) before building the system"
            )
        names = [node.func.__name__] if isinstance(node, sympy.Function) else []
        name = getattr(node, "name", None)
        names += [str(name)] if isinstance(name, (str, sympy.core.symbol.Str)) else []
        for nm in names:
            if not plain_identifier(nm):
                raise ValueError(
                    f"{what}: contains a {type(node).__name__} named {_shown(nm)}, not a plain Python identifier; "
                    "liefi generates code only from names it has checked: rename it (letters, digits, '_')"
                )
    return expr.xreplace(rename) if rename else expr


def _shown(name, limit=80):
    """``repr(name)``, cut to ``limit`` characters (a name from outside data can be long)."""
    r = repr(str(name))
    return r if len(r) <= limit else r[: limit - 4] + "...'"


def lambdify_checked(sympy, args, exprs, what, **kw):
    """``sympy.lambdify(args, exprs, modules=[numpy], dummify=True, **kw)`` after :func:`sympy_only` and
    :func:`checked_names` on every expression.

    The expressions may depend on ``args`` only (a ``ValueError`` names any other free symbol);
    the arguments are always dummified (lambdify prints names of its own for them, so no name of
    the model reaches the code), and the printer is numpy's, strict, without unknown functions:
    a sympy function numpy has no counterpart for is a ``ValueError`` naming ``what``, never a name
    looked up in the generated code's namespace.  The one path from sympy expressions to sympy's
    generated code.
    """
    from sympy.printing.codeprinter import PrintMethodNotImplementedError
    from sympy.printing.numpy import NumPyPrinter

    args = list(args)
    exprs = [sympy.sympify(e, strict=True) for e in exprs]
    sympy_only(sympy, args + exprs, what)
    out = []
    for e in exprs:
        extra = e.free_symbols - set(args)
        if extra:
            raise ValueError(f"{what}: depends on {sorted(_shown(s.name) for s in extra)}, which liefi has no value "
                             "for (give them as constants or substitute numbers)")
        out.append(checked_names(sympy, e, what, args))
    printer = NumPyPrinter({"fully_qualified_modules": False, "inline": True, "allow_unknown_functions": False,
                            "strict": True, "user_functions": {}})
    # numpy as the module object, not the name "numpy": sympy then reads the names of numpy's namespace
    # instead of running ``from numpy import *`` once per process, which imports numpy's lazily loaded
    # submodules (f2py, testing, ... 0.1-0.2 s); the printer (NumPyPrinter) and the code are the same
    try:
        return sympy.lambdify(args, out, modules=[np], printer=printer, **{**kw, "dummify": True})
    except PrintMethodNotImplementedError as exc:
        raise ValueError(f"{what}: liefi cannot evaluate it with numpy ({exc}); write it with functions numpy "
                         "has (sin, exp, sqrt, Piecewise, Abs ...)") from None


def is_zero(sympy, expr):
    """``sympy.simplify(expr) == 0``, answered without ``simplify`` where a cheaper test is exact.

    ``expr == 0`` first (most zero tests in liefi meet a literal zero after a substitution);
    then the value at one point (positive non-integer values for the symbols, used only if they fit
    every assumption of the symbols; every applied function and derivative of the dynamic symbols a
    value of its own), to 30 digits: a value above ``1e-12`` proves that
    ``expr`` is not the zero function, so ``simplify`` (which only rewrites it into an equal
    expression) cannot return ``0`` either.  Only a value that is zero to rounding, or no value,
    leaves the answer to ``simplify`` itself: the answer is always ``simplify``'s.
    """
    e = sympy.sympify(expr, strict=True)
    if e == 0:
        return True
    if _nonzero_somewhere(sympy, e):
        return False
    return sympy.simplify(e) == 0


def _nonzero_somewhere(sympy, e):
    """True if ``e`` has a value of modulus above ``1e-12`` at a fixed point of its symbols (see :func:`is_zero`)."""
    from sympy.core.function import AppliedUndef

    atoms = e.atoms(sympy.Symbol, sympy.Derivative, AppliedUndef)
    proxy = sympy.Rational(7, 10)  # a value of the kind drawn: positive, real, rational, not an integer
    if any(getattr(proxy, f"is_{k}", None) != v for s in atoms if not isinstance(s, sympy.Derivative)
           for k, v in s.assumptions0.items()):
        return False  # a symbol those values would not fit (integer, negative, imaginary ...)
    # distinct, not rational-looking values in (0.5, 1.5): sqrt(2 + k) mod 1 + 0.5
    point = {s: sympy.Float(((2.0 + k) ** 0.5) % 1.0 + 0.5) for k, s in enumerate(sorted(atoms, key=sympy.default_sort_key))}
    try:
        v = e.xreplace(point).evalf(30)
        return bool(v.is_number and abs(complex(v)) > 1e-12)
    except (TypeError, ValueError, ArithmeticError):  # no finite value there: inconclusive
        return False


def _degree_at_most(sympy, e, V, k):
    """True if ``e`` is, as written (no expansion), a polynomial of total degree at most ``k`` in ``V``.

    A structural bound: sums take the largest degree of their terms, products the sum, powers
    with a positive integer exponent the multiple; a ``V`` under any other function makes it
    False.  True implies that ``Poly(expand(e), *V)`` exists with ``total_degree() <= k`` (its
    degree can only be lower); False leaves the question to that test.
    """
    V = set(V)

    def deg(x):
        if not (x.free_symbols & V):
            return 0
        if x in V:
            return 1
        if x.is_Add:
            return max(deg(a) for a in x.args)
        if x.is_Mul:
            return sum(deg(a) for a in x.args)
        if x.is_Pow and x.exp.is_Integer and x.exp > 0:
            return deg(x.base) * int(x.exp)
        return k + 1

    return deg(e) <= k


def _batch_function(sympy, x_syms, exprs, shape, what):
    """``(..., n) -> (..., *shape)`` numpy function of the sympy expressions (complex safe); a
    constant array if none depends on ``x``."""
    flat = [sympy.sympify(e, strict=True) for e in exprs]
    if not any(e.free_symbols & set(x_syms) for e in flat):
        return np.array([complex(e).real for e in flat], float).reshape(shape)
    f = lambdify_checked(sympy, x_syms, flat, what, cse=True)
    n = len(x_syms)

    def fun(x):
        x = np.asarray(x)
        batch = x.shape[:-1]
        vals = [np.broadcast_to(np.asarray(v), batch) for v in f(*[x[..., i] for i in range(n)])]
        return np.stack(vals, -1).reshape(batch + tuple(shape))

    return fun


def from_sympy(L, q, qd, constraints=(), names=None, *, scaling="unit", **kw):
    """A :class:`~liefi.NonholonomicSystem` on ``CotangentBundle(len(q))`` from a sympy Lagrangian.

    Parameters
    ----------
    L : sympy expression
        The Lagrangian ``1/2 qd.M(q) qd + b(q).qd - U(q)``: quadratic in the
        velocities, with an optional part linear in them (a vector potential:
        gyroscopic or magnetic terms) and a potential.  A sympy expression, not
        a string: text is refused (turning it into an expression runs it as
        Python code, and liefi runs no code it did not write); parse text you
        trust yourself (``sympy.parsing.sympy_parser.parse_expr``) first.
    q, qd : list of sympy Symbol
        The coordinates and their velocities, in the same order
        (``sympy.physics.mechanics.dynamicsymbols`` ``q(t)``, ``q(t).diff(t)`` work too).
    constraints : sequence of sympy expressions
        ``c_i(q, qd)``, each linear and homogeneous in ``qd``: the constraint is
        ``c_i = a_i(q) . qd = 0``.
    names : sequence of str, optional
        Names of the coordinates (default ``str(q_i)``).
    scaling : {"unit", "orthonormal", None}
        Scaling of the constraint vectors, see
        :meth:`~liefi.NonholonomicSystem.from_velocity_constraints`.
    **kw
        Passed on (``sample``, ``check`` ...).

    Returns
    -------
    NonholonomicSystem
        State ``(q, p)`` with ``p = M qd + b``.

    Raises
    ------
    TypeError
        If ``L`` or a constraint is a string (see ``L``).
    NotQuadraticError
        If ``L`` is not polynomial of degree at most 2 in ``qd``.
    NonlinearConstraintError
        If a constraint is not linear and homogeneous in ``qd``.
    ValueError
        For symbols other than ``q`` and ``qd`` in the expressions (substitute numbers
        for parameters), or data liefi refuses (an indefinite ``M``, dependent rows).
    """
    sympy = _sympy()
    from ..phase_space import CotangentBundle
    from .system import NonholonomicSystem

    from .._fingerprint import stamp

    data = ("from_sympy", L, q, qd, constraints, names, scaling, kw)  # the inputs, before they are read
    X, M, b, U, rows, q = lagrangian_data(sympy, _scalar_lagrangian(sympy, L), q, qd, constraints)
    n = len(q)
    metric = _batch_function(sympy, X, [e for row in M for e in row], (n, n), "metric")
    potential = None if is_zero(sympy, U) else _batch_function(sympy, X, [U], (), "potential")
    vector_potential = None
    if not all(is_zero(sympy, e) for e in b):
        vector_potential = _batch_function(sympy, X, b, (n,), "vector potential")
    if names is None:
        names = coordinate_names(sympy, q)
    space = CotangentBundle(n, names=names)
    if not rows:  # stamped: pure data, so its kernels are found without a trace (liefi._fingerprint)
        return stamp(NonholonomicSystem(space, metric, None, potential, vector_potential=vector_potential, **kw), *data)
    A = _batch_function(sympy, X, [e for row in rows for e in row], (len(rows), n), "constraints")
    return stamp(NonholonomicSystem.from_velocity_constraints(
        space, metric, A, potential, scaling=scaling, vector_potential=vector_potential, **kw
    ), *data)


def _scalar_lagrangian(sympy, L):
    """``L`` itself, the element of a 1x1 Matrix (as ``LagrangesMethod`` stores it), or a named error."""
    if type(L).__name__ in ("LagrangesMethod", "KanesMethod", "System"):
        raise TypeError(
            f"L: a sympy.physics.mechanics {type(L).__name__}, not a Lagrangian expression; hand the "
            "model itself to liefi.from_mechanics(model, constants={...})"
        )
    if isinstance(L, sympy.MatrixBase):
        if L.shape != (1, 1):
            raise ValueError(f"L: expected one scalar expression (the Lagrangian), got a {L.shape[0]}x{L.shape[1]} Matrix")
        return L[0, 0]
    return L


def coordinate_names(sympy, q):
    """``str(q_i)`` of plain symbols, the function name of ``dynamicsymbols`` (``x`` of ``x(t)``)."""
    return tuple(str(s.func) if isinstance(s, sympy.core.function.AppliedUndef) else str(s) for s in q)


def lagrangian_data(sympy, L, q, qd, constraints, parameters=(), speeds=()):
    """The metric, vector potential, potential and Pfaffian rows of ``L`` as sympy expressions.

    ``M = d^2 L / dqd^2``, ``b = dL/dqd (qd = 0)``, ``U = -L(qd = 0)``, ``a_i = d c_i / dqd``,
    in plain symbols ``X`` for ``q`` (and the ``parameters``, which may appear).
    With ``speeds`` (Kane's ``u``, related to ``qd`` by kinematic equations the caller
    solves numerically) the velocities are ``w = (qd, u)``: ``M = d^2 L / dw^2`` is
    ``2n x 2n``, ``b`` and the rows have ``2n`` entries, and ``L`` and the constraints may
    hold both ``qd`` and ``u``.
    Returns ``(X, M, b, U, rows, q)``; the errors are those of :func:`from_sympy`.
    """
    q = _symbols(sympy, q, "q")
    qd = _symbols(sympy, qd, "qd")
    n = len(q)
    if len(qd) != n:
        raise ValueError(f"qd: expected {n} velocities (one per coordinate in q), got {len(qd)}")
    qd = qd + list(speeds)
    # plain symbols for the coordinates and velocities (dynamicsymbols: velocities first)
    X = [sympy.Dummy(f"x{i}") for i in range(n)]
    V = [sympy.Dummy(f"v{i}") for i in range(len(qd))]
    to_plain = dict(zip(qd, V))
    to_plain_q = dict(zip(q, X))

    def plain(expr, what):
        if isinstance(expr, (str, bytes)):
            raise TypeError(
                f"{what}: got a string ({expr!r}); from_sympy takes sympy expressions only, since turning "
                "text into an expression runs it as Python code (sympify) and liefi runs no code it did not "
                "write. Build the expression from sympy.symbols, or parse text you trust yourself "
                "(sympy.parsing.sympy_parser.parse_expr) and pass the result"
            )
        try:  # strict: numbers and sympy objects only, never a conversion through text
            e = sympy.sympify(expr, strict=True)
        except (sympy.SympifyError, TypeError) as exc:
            raise ValueError(f"{what}: not a sympy expression ({exc})") from None
        sympy_only(sympy, [e], what)  # before any method of the expression's classes runs
        e = e.xreplace(to_plain).xreplace(to_plain_q)
        extra = e.free_symbols - set(X) - set(V) - set(parameters)
        if extra:
            raise ValueError(
                f"{what}: contains symbols {sorted(map(str, extra))} that are neither in q nor in qd; "
                "substitute numbers for the parameters (expr.subs({...})) first, or keep them as "
                "runtime constants: liefi.from_mechanics(LagrangesMethod(L, q, nonhol_coneqs=...), "
                "constants={...})"
            )
        return checked_names(sympy, e, what, set(X) | set(V) | set(parameters))

    Lp = plain(L, "L")
    try:
        poly = None if _degree_at_most(sympy, Lp, V, 2) else sympy.Poly(sympy.expand(Lp), *V)
    except sympy.PolynomialError as exc:
        raise NotQuadraticError(
            f"L: not a polynomial in the velocities qd ({exc}); liefi needs a kinetic energy "
            "quadratic in qd, plus terms linear in qd, plus a potential"
        ) from None
    if poly is not None and poly.total_degree() > 2:
        raise NotQuadraticError(
            f"L: of degree {poly.total_degree()} in the velocities qd; liefi needs a kinetic energy "
            "quadratic in qd (1/2 qd.M(q) qd), plus terms linear in qd, plus a potential"
        )
    zero = {v: 0 for v in V}
    held = Lp.free_symbols  # a velocity L does not hold has zero derivatives (no traversal of L for it)
    d = lambda *w: sympy.diff(Lp, *w) if all(x in held for x in w) else sympy.S.Zero  # noqa: E731
    M = [[d(V[i], V[j]) for j in range(len(V))] for i in range(len(V))]
    b = [d(V[i]).xreplace(zero) for i in range(len(V))]
    U = -Lp.xreplace(zero)

    if isinstance(constraints, (str, bytes)):
        plain(constraints, "constraints")  # refused with the reason
    rows = []
    for k, c in enumerate(constraints):
        cp = plain(c, f"constraints[{k}]")
        linear = _degree_at_most(sympy, cp, V, 1)
        try:
            cpoly = None if linear else sympy.Poly(sympy.expand(cp), *V)
        except sympy.PolynomialError:
            cpoly = None
        if not linear and (cpoly is None or cpoly.total_degree() > 1):
            raise NonlinearConstraintError(
                f"constraints[{k}]: {c} is not linear in the velocities qd; liefi treats linear "
                "nonholonomic constraints a(q) . qd = 0"
            )
        if linear:  # linear as written: the coefficients in one pass (not a derivative per velocity)
            J, rest, _ = linear_coefficients(sympy, [cp], V)
            row, rest = list(J), rest[0]
        else:
            row, rest = [sympy.diff(cp, v) for v in V], cp.xreplace(zero)
        if not is_zero(sympy, rest):
            raise NonlinearConstraintError(
                f"constraints[{k}]: {c} has a term without velocities (affine constraint); liefi "
                "treats linear homogeneous constraints a(q) . qd = 0"
            )
        rows.append(row)
    return X, M, b, U, rows, q
