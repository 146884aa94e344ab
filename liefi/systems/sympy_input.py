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

import keyword

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


def checked_names(sympy, expr, what, known=()):
    """``expr`` with names liefi may print into generated code, or a ``ValueError`` naming the first that it may not.

    ``sympy.lambdify`` writes the name of every symbol and function into the Python source it
    executes, so a name from outside data (``sympy.Function("__import__('os').system('...')")``,
    a symbol named ``"x; ..."``) would run as code.  The ``known`` symbols (the arguments, which
    liefi replaces by names of its own) pass; an undefined function (``sympy.Function("f")(x)``)
    is refused, since it has no value and its name would be code; a bound variable (of a ``Sum``)
    whose name is not a :func:`plain_identifier` is renamed to a liefi ``Dummy``; every other
    name (of a function class, a ``MatrixSymbol`` ...) must be a :func:`plain_identifier`.
    """
    from sympy.core.function import AppliedUndef

    known, rename = set(known), {}
    for node in sympy.preorder_traversal(expr):
        if isinstance(node, sympy.Symbol):
            if node not in known and not plain_identifier(node.name):
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
    """``sympy.lambdify(args, exprs, modules=[numpy], **kw)`` after :func:`checked_names` on every expression.

    The expressions may depend on ``args`` only (a ``ValueError`` names any other free symbol);
    an argument whose name is not a :func:`plain_identifier` needs ``dummify=True`` (lambdify
    then prints a name of its own).  The one path from sympy expressions to generated code.
    """
    args = list(args)
    exprs = [sympy.sympify(e, strict=True) for e in exprs]
    if not kw.get("dummify") and not all(plain_identifier(a.name) for a in args):
        raise ValueError(f"{what}: arguments {[_shown(a.name) for a in args]} need dummify=True")  # pragma: no cover - liefi's own call
    out = []
    for e in exprs:
        extra = e.free_symbols - set(args)
        if extra:
            raise ValueError(f"{what}: depends on {sorted(_shown(s.name) for s in extra)}, which liefi has no value "
                             "for (give them as constants or substitute numbers)")
        out.append(checked_names(sympy, e, what, args))
    # numpy as the module object, not the name "numpy": sympy then reads the names of numpy's namespace
    # instead of running ``from numpy import *`` once per process, which imports numpy's lazily loaded
    # submodules (f2py, testing, ... 0.1-0.2 s); the printer (NumPyPrinter) and the code are the same
    return sympy.lambdify(args, out, modules=[np], **kw)


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
    e = sympy.sympify(expr)
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
    flat = [sympy.sympify(e) for e in exprs]
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
