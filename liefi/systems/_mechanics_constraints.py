r"""Configuration constraints of a ``sympy.physics.mechanics`` model as liefi's holonomic datum.

A model with dependent coordinates declares ``f(q) = 0`` (``KanesMethod``'s
``configuration_constraints``, ``LagrangesMethod``'s ``hol_coneqs``, ``System``'s
``holonomic_constraints``) and, as velocity constraints, usually also its time
derivative ``df(q) . qdot = 0`` (sympy puts ``d/dt hol_coneqs`` into a
``LagrangesMethod``'s ``coneqs``; a ``System``'s ``velocity_constraints`` are
``d/dt`` of its holonomic constraints unless overwritten; a Kane user writes them for
``u_dependent``).  liefi takes:

* the values ``f`` -> ``holonomic=`` of :class:`~liefi.NonholonomicSystem` (with the
  derivative ``df`` from sympy's Jacobian, exact), which appends the rows ``df`` and puts
  ``f`` into ``V`` (:mod:`liefi.systems.holonomic`);
* the velocity constraints -> rows as before, less those that the rows ``df`` span
  (the derivatives of ``f``: kept twice, the rows would be dependent).  A row is tested
  at a few generic configurations (not only on ``f = 0``, where the derivative of a
  configuration constraint is ``df . qdot`` as everywhere else): it is dropped if the
  rows ``df`` and the rows kept before it span it at every one, kept if at none; a row
  in the span at some but not all is :class:`ConstraintRowsError`.

The dependent coordinates and speeds stay in the state (the ``CotangentBundle`` of all
``q``); sympy's partition into independent and dependent ones is not needed.
"""

from __future__ import annotations

import numpy as np

from ._coefficients import linear_coefficients

#: generic test configurations: seeded, away from 0 and from multiples of pi/2 (where
#: chosen coordinates such as a pendulum's x or a linkage's angles are often special)
_RNG_SEED = 20221129
_N_POINTS = 3


class ConstraintRowsError(ValueError):
    """A velocity constraint of a model is the derivative of its configuration constraints at some
    configurations and not at others: liefi cannot tell whether to keep it."""


def generic_points(n, count=_N_POINTS):
    """``count`` generic configurations of ``n`` coordinates (seeded)."""
    rng = np.random.default_rng(_RNG_SEED)
    return rng.uniform(0.3, 1.2, (count, n)) * rng.choice([-1.0, 1.0], (count, n))


def holonomic_functions(sympy, f, q, X, params, bind):
    """``(f(x), df(x))``: the values, shape ``(H,)``, and ``d f_j/d x_k`` at ``[k, j]``, bound numerically.

    ``f``: sympy expressions in the coordinates ``q`` (dynamicsymbols), ``X`` the plain
    symbols that stand for them, ``bind(exprs, shape, what)`` liefi's lambdify with the
    constants bound.
    """
    given = [sympy.sympify(e, strict=True) for e in f]
    # read before q -> X: in the plain symbols a rate q' is Derivative(x, t), no longer the model's q' (and no
    # Derivative of q is formed to look for)
    bad = [e for e in given if e.has(sympy.Derivative)]
    plain = sympy.Matrix([e.xreplace(dict(zip(q, X))) for e in given])
    if bad:
        raise ValueError(f"model: the configuration constraints {bad} hold velocities; configuration "
                         "constraints are f(q) = 0 (velocity constraints go to velocity_constraints)")
    jac = _configuration_jacobian(sympy, f, q, X)
    jac = plain.jacobian(X) if jac is None else jac  # (H, n)
    H, n = jac.shape
    values = bind(list(plain), (H,), "configuration constraints")
    deriv = bind([jac[j, k] for k in range(n) for j in range(H)], (n, H), "configuration constraints")
    return values, deriv


def _configuration_jacobian(sympy, f, q, X):
    """``df/dq`` in the plain symbols ``X``, read as the coefficients of ``qdot`` in ``df/dt`` (``q`` dynamic
    symbols of one time ``t``), else ``None``.

    One derivative in ``t`` per constraint, which sympy took already for the model's own velocity
    constraints (its cache holds it), instead of one per coordinate of the plain expressions.
    """
    from sympy.core.function import AppliedUndef

    times = {s.args for s in q if isinstance(s, AppliedUndef)}
    if len(q) != len(X):  # coordinates liefi added (restored contact places, speeds' coordinates): the Jacobian
        return None  # in all of X
    if len(times) != 1 or not all(isinstance(s, AppliedUndef) for s in q) or len(next(iter(times))) != 1:
        return None
    t = next(iter(times))[0]
    J = linear_coefficients(sympy, [sympy.sympify(e, strict=True).diff(t) for e in f], [s.diff(t) for s in q])[0]
    return J.xreplace(dict(zip(q, X)))


def independent_rows(A, df, n, points):
    """Indices of the velocity-constraint rows ``A(x)`` (``(K, n)`` in ``qdot``) not spanned by ``df`` and the
    rows kept before them, at every configuration of ``points``."""
    D = np.asarray(df(points), float)  # (P, n, H)
    R = np.asarray(A(points), float)  # (P, K, n)
    keep = []
    for i in range(R.shape[-2]):
        spanned = []
        for p in range(len(points)):
            basis = np.concatenate([D[p].T, R[p, keep]], 0)
            row = R[p, i]
            coef, *_ = np.linalg.lstsq(basis.T, row, rcond=None)
            res = np.linalg.norm(basis.T @ coef - row)
            spanned.append(res <= 1e-9 * max(np.linalg.norm(row), 1e-300))
        if all(spanned):
            continue
        if any(spanned):
            raise ConstraintRowsError(
                f"model: the velocity constraint {i + 1} is a combination of the derivatives of the configuration "
                "constraints (and the velocity constraints before it) at some configurations and not at others; "
                "give the velocity constraints as the time derivatives of the configuration constraints plus "
                "independent nonholonomic ones")
        keep.append(i)
    return keep


def select_rows(A, keep, K):
    """``A`` restricted to the rows ``keep`` (``A`` itself when all ``K`` are kept, ``None`` when none)."""
    if len(keep) == K:
        return A
    if not keep:
        return None
    idx = np.asarray(keep)

    def rows(x):
        return A(x)[..., idx, :]

    return rows


def holonomic_data(sympy, hol, q, X, A, K, speeds, kw, bind):
    """``(A, kw, keep)``: the velocity-constraint rows ``A`` (in the model's velocities) less the derivatives of the
    configuration constraints ``hol``, and ``kw`` with ``holonomic=``, ``holonomic_derivative=`` (and a
    generic ``sample`` unless given: ``x = 0`` is often a singular configuration of ``f``).

    ``speeds``: the model's kinematic map (``_Speeds``) when ``A`` is in ``(qdot, u)``, else ``None``.
    """
    f, df = holonomic_functions(sympy, hol, q, X, (), bind)
    n = len(X)
    kw = dict(kw)
    if kw.get("sample") is None:
        kw["sample"] = generic_points(n, 1)[0]
    keep = list(range(K))
    if A is not None:
        Aq = speeds.rows(A) if speeds is not None else A
        keep = independent_rows(Aq, df, n, generic_points(n))
        A = select_rows(A, keep, K)
    kw["holonomic"], kw["holonomic_derivative"] = f, df
    return A, kw, keep


def regularized_metric(metric, A, kw):
    r"""The model's metric, or ``m + c a^T a`` where ``m`` is singular (coordinates without mass).

    A model in more coordinates than degrees of freedom may give some of them no kinetic
    energy (a massless contact point with its own coordinates, its mass centre with
    others).  Its metric ``m(q)`` is then singular on the ambient space, though positive on
    the velocities the constraints allow.  With the constraint rows ``a`` (``df`` and the
    kept velocity constraints, in ``qdot``), ``T' = T + c |a qdot|^2 / 2`` equals ``T`` on
    the constraint set, and the constrained motion is the same: the Euler--Lagrange terms
    of the added energy are ``c a^T d/dt(a qdot) + c (d/dt a^T - d_q(a qdot)^T)(a qdot)``,
    zero where ``a qdot = 0`` along the motion (the first is along the rows, a constraint
    force).  ``c`` is the metric's largest eigenvalue over the largest ``|a_i|^2`` at the
    sample point (a constant: the units of the metric).  ``m`` regular: returned as is.
    """
    x0 = np.asarray(kw["sample"], float)
    m0 = np.asarray(metric(x0), float)
    eig = np.linalg.eigvalsh(m0)
    if eig.min() > 1e-9 * max(eig.max(), 1e-300):
        return metric
    df = kw.get("holonomic_derivative")  # None: velocity constraints only (a restored root point, _restore)

    def rows(x):
        if df is None:
            return np.asarray(A(x))
        d = np.swapaxes(np.asarray(df(x)), -1, -2)
        return d if A is None else np.concatenate([d, np.asarray(A(x))], -2)

    R = np.asarray(rows(x0), float)
    c = eig.max() / np.max(np.sum(R * R, -1))

    def regular(x):
        a = rows(x)
        return metric(x) + c * (np.swapaxes(a, -1, -2) @ a)

    eig2 = np.linalg.eigvalsh(np.asarray(regular(x0), float))
    if eig2.min() <= 1e-9 * eig2.max():
        raise ValueError("model: the kinetic energy is zero along velocities that the constraints allow (a "
                         "coordinate without mass that no constraint ties to a massive one); give it mass or "
                         "eliminate it")
    return regular
