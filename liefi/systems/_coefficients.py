r"""Coefficients of expressions linear in some variables, in one pass (the build-time path of ``from_mechanics``).

A model's velocities, kinematic equations and velocity constraints are linear in the
velocities ``w`` (``qdot``, the speeds ``u``): ``e(q, w) = J(q) w + e_0(q)``.  sympy's
``Matrix.jacobian`` differentiates each entry once per variable (``len(w)`` traversals), and
with respect to dynamic symbols (``q(t)``, ``q(t)'``) each derivative first substitutes a dummy
for the variable and back.  :func:`linear_coefficients` reads ``J`` and ``e_0`` of all
entries in one traversal of each (sympy's ``linear_eq_to_matrix``, which collects the
coefficients of a sum of products), after one substitution of plain symbols for ``w``; an
expression that is not linear as written falls back to the Jacobian.
"""

from __future__ import annotations


def plain_symbols(sympy, wrt):
    """``(symbols, to, back)``: a ``Dummy`` per variable of ``wrt``, and the substitutions ``wrt -> symbols`` and back."""
    D = [w if isinstance(w, sympy.Symbol) else sympy.Dummy() for w in wrt]
    return D, dict(zip(wrt, D)), dict(zip(D, wrt))


def linear_coefficients(sympy, exprs, wrt):
    r"""``(J, e0, linear)``: ``exprs = J w + e0`` with ``J = d exprs / d w`` (``len(exprs) x len(wrt)`` Matrix) and
    ``e0 = exprs(w = 0)`` (column Matrix), for ``w`` = ``wrt`` (symbols or dynamic symbols and their derivatives).

    ``linear`` is whether each expression is, as written, a sum of products with at most one factor
    holding ``w``, of degree one (then ``J`` is free of ``w`` and ``J, e0`` are read in one pass).
    Otherwise ``J`` is the Jacobian and ``e0`` the substitution ``w = 0`` (the caller tests ``J`` for
    ``w`` to refuse a nonlinear expression).
    """
    exprs = sympy.Matrix([sympy.sympify(e, strict=True) for e in exprs])
    wrt = list(wrt)
    D, to, back = plain_symbols(sympy, wrt)
    E = exprs.xreplace(to)
    if not wrt or not len(E):
        return sympy.zeros(len(E), len(wrt)), E, True
    try:
        J, b = sympy.linear_eq_to_matrix(list(E), D)
        linear = True
    except (ValueError, sympy.PolynomialError):  # nonlinear as written (NonlinearError is a ValueError)
        J, b, linear = E.jacobian(D), -E.xreplace(dict.fromkeys(D, 0)), False
    return J.xreplace(back), (-b).xreplace(back), linear
