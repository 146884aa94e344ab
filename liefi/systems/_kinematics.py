"""The kinematics of a ``sympy.physics.mechanics`` model: its speed map and the identities it must satisfy.

Private helpers of :mod:`liefi.systems.mechanics` (which exports the two errors): the kinematic differential equations as
matrices (:func:`_kinematics`), the speed map solved numerically at each evaluation
(:class:`_Speeds`) and the numerical checks of the model (:class:`_Checks`).
"""

from __future__ import annotations

import numpy as np

from ._coefficients import linear_coefficients
from ._evaluate import directional, evaluator


class NonConservativeLoadError(ValueError):
    """A load of the model has no potential liefi can derive (velocity-dependent, a torque, or a force
    varying in the inertial frame); pass ``potential=`` if the loads are conservative."""


class MinimalSpeedsError(ValueError):
    """Bodies located from one zero-velocity point give it different velocities: no one restored place of
    that point fits them all (a model in minimal speeds whose bodies' velocities come from different
    kinematics); see :func:`_restore`."""


def _kinematics(sympy, kd, q, qd, u):
    """``(K_qdot, K_u)``: the kinematic differential equations as ``K_qdot(q) qdot + K_u(q) u = 0``.

    Only the matrices: the map is solved numerically at each evaluation (:class:`_Speeds`),
    never by a symbolic inverse, whose pivots may vanish where the map is regular.  Fewer
    speeds than coordinates (``m < n``, minimal speeds: ``qdot = B(q) u``) are taken: the
    velocities then lie in the range of ``B`` (:func:`_annihilator` gives its rows).
    """
    n = len(q)
    if len(u) > n:
        raise ValueError(f"model: the kinematic differential equations hold {len(u)} generalized speeds "
                         f"{[str(getattr(s, 'func', s)) for s in u]} for {n} coordinates, so the coordinates' rates do "
                         "not fix the speeds (a velocity constraint among them does not help); liefi needs at most one "
                         "speed per coordinate: write the model with one speed per coordinate (substitute a speed a "
                         "velocity constraint fixes), move the speeds of reaction forces to u_auxiliary=, and leave a "
                         "rate with no coordinate (a wheel's spin) out of kd_eqs (liefi then gives it a coordinate)")
    K = sympy.Matrix(kd)
    if K.shape[0] != n:
        raise ValueError(f"model: {K.shape[0]} kinematic differential equations for {n} coordinates; give one per "
                         "coordinate")
    J, rest, _ = linear_coefficients(sympy, K, list(u) + list(qd))  # one pass, not a Jacobian per variable
    Ku, Kq = J[:, : len(u)], J[:, len(u):]
    if any(Ku.has(s) or Kq.has(s) for s in list(u) + list(qd)):
        raise ValueError("model: the kinematic differential equations are not linear in u and qdot")
    if any(e != 0 and sympy.simplify(e) != 0 for e in rest):
        raise ValueError("model: the kinematic differential equations K_qdot qdot + K_u u + f_k = 0 have a term "
                         f"f_k = {list(rest)} free of u and qdot; liefi needs the speeds linear and homogeneous in "
                         "qdot (time-dependent kinematics are not integrated)")
    return Kq, Ku


def _speed_coordinates(sympy, me, kd, q, qd, u):
    """``(q, qd, kd)`` with a coordinate ``q_<u_j>`` and the equation ``q_<u_j>' - u_j = 0`` for each speed that no
    kinematic differential equation holds, when there are more speeds than coordinates.

    A Kane model may give a body a rate of a coordinate it does not carry (sympy's bicycle test: the
    wheels' spins ``u3, u6`` with no wheel angles, which nothing depends on); liefi's velocities are
    coordinate rates, so that coordinate is added (an ignorable one: no position depends on it).
    """
    t = me.dynamicsymbols._t
    free = [s for s in u if not any(sympy.sympify(e, strict=True).has(s) for e in kd)]
    if len(u) <= len(q) or not free:
        return q, qd, kd
    taken = {str(getattr(s, "func", s)) for s in q}
    new = []
    for s in free:
        name = f"q_{s.func}"
        if name in taken:
            raise ValueError(f"model: a coordinate is named {name!r}, the name liefi gives the coordinate whose "
                             f"rate is {s.func}; rename the coordinate")
        new.append(sympy.Function(name)(t))  # the name as it is (dynamicsymbols would parse "u 1", "u:3")
    return (list(q) + new, list(qd) + [c.diff(t) for c in new],
            list(kd) + [c.diff(t) - s for c, s in zip(new, free)])


def _annihilator(sympy, Kq, Ku):
    r"""The rows ``a(q)`` with ``a B = 0``, ``B = -K_qdot^{-1} K_u`` (``n x m``, ``m < n``): ``a . qdot = 0``
    is the velocity constraint that minimal speeds build in (``qdot = B u``).

    The left null space of ``B`` symbolically, each row cleared of its denominators (a
    polynomial row, e.g. ``(-sin theta, cos theta, 0)`` for a sleigh's ``x' = u cos theta,
    y' = u sin theta``, not ``(-tan theta, 1, 0)``).  No inverse of ``K_qdot``: ``a B = 0`` if and
    only if ``a = b K_qdot`` with ``b K_u = 0``, so the rows are the left null space of ``K_u`` times
    ``K_qdot`` (a symbolic ``K_qdot^{-1}``, of implicit kinematics such as a quaternion's, hung
    the build in ``expand``).  The pivots are tested by :func:`is_zero` (``simplify``'s answer, asked of
    ``simplify`` only when a value at a point does not decide) and the rows cleared by ``cancel`` (a
    rational function's common factors), not by ``simplify`` on each entry.
    """
    from .sympy_input import is_zero

    eye = Kq == sympy.eye(Kq.shape[0])
    rows = [_cleared(sympy, b if eye else b.T * Kq) for b in Ku.T.nullspace(iszerofunc=lambda e: is_zero(sympy, e))]
    if len(rows) != Kq.shape[0] - Ku.shape[1]:
        raise ValueError(f"model: the kinematic differential equations give qdot = B(q) u with B of rank "
                         f"{Kq.shape[0] - len(rows)} < {Ku.shape[1]} speeds: the speeds are not independent")
    return rows


def _cleared(sympy, entries):
    """``entries`` times the least common multiple of their denominators (after ``together``), each ``cancel``-ed:
    the same row (or, for one entry, the same constraint) free of denominators.

    A product ``e * den`` that sympy's own ``Mul`` already cleared (``together``'s numerator times a
    constant: one entry, or entries over the same denominator) is kept as it is: ``cancel`` would only
    expand it (the same function; 12 ms of the 0.09 s build of sympy's non-minimal pendulum)."""
    v = [sympy.together(e) for e in entries]
    den = sympy.lcm([sympy.fraction(e)[1] for e in v])
    out = [e * den for e in v]
    return [w if sympy.fraction(w)[1] == 1 else sympy.cancel(w) for w in out]


def _regular_rows(sympy, rows, q):
    r"""The velocity constraints ``rows`` (expressions linear in the speeds), each with its denominators cleared
    (:func:`_cleared`) when one of them vanishes, or is itself singular, at the configuration ``q = 0``
    (``tan``, ``cot``, ``sec``, ``csc`` taken as quotients of ``sin`` and ``cos``).

    A ``KanesMethod`` holds its velocity constraints with its own symbolic solution of the kinematic
    equations substituted (``_k_nh``: ``qdot`` in ``u`` by sympy's LU pivots), and those pivots may vanish
    where the model is regular: sympy's rolling disc (``test_kane5.py``) has rows with entries
    ``\sin q_2 \cos q_3 / ((\sin q_3 + \cos^2 q_3/\sin q_3) \sin q_3 \cos q_2)``, ``0/0`` at the upright
    ``q_3 = 0``.  ``c = 0`` and ``d c = 0`` are the same constraint for a function ``d`` not zero, so
    the row is multiplied by its denominator, ``\cos q_2 (\sin^2 q_3 + \cos^2 q_3)`` there (zero only
    where the model's own kinematic map is singular).  A row whose denominators are regular and not zero at
    ``q = 0`` is kept as it is (no symbolic work on large rows, such as a bicycle's).
    """
    zero = dict.fromkeys(q, sympy.S.Zero)
    sin, cos = sympy.sin, sympy.cos
    quotients = {sympy.tan: lambda a: sin(a) / cos(a), sympy.cot: lambda a: cos(a) / sin(a),
                 sympy.sec: lambda a: 1 / cos(a), sympy.csc: lambda a: 1 / sin(a)}

    def singular(e):
        for p in e.atoms(sympy.Pow):
            if p.exp.is_negative and p.base.has(*q):
                b0 = p.base.xreplace(zero)
                if b0.is_zero or b0.has(sympy.zoo, sympy.nan, sympy.oo, -sympy.oo):
                    return True
        return False
    out = []
    for e in rows:
        e = sympy.sympify(e, strict=True)
        quotient = e.has(*quotients) and e
        for f, g in quotients.items():  # tan, cot, sec, csc as quotients of sin and cos, to find and clear
            quotient = quotient and quotient.replace(f, g)
        out.append(_cleared(sympy, [quotient or e])[0] if singular(quotient or e) else e)
    return out


def _solve(A, B):
    """``A^{-1} B`` batch-first: LAPACK's pivoted LU on numbers (complex-step safe); traced (compiled engine)
    matrices, which have no magnitude to pivot on, by the normal equations ``A^T A X = A^T B`` (positive
    definite, so elimination without pivots meets no vanishing pivot where ``A`` is regular)."""
    A, B = np.asarray(A), np.asarray(B)
    if A.dtype == object:
        At = np.swapaxes(A, -1, -2)
        return np.linalg.solve(At @ A, At @ B)
    if B.dtype == object:
        return np.linalg.inv(A) @ B
    try:
        return np.linalg.solve(A, B)
    except np.linalg.LinAlgError:
        raise ValueError("model: the kinematic differential equations K_qdot(q) qdot + K_u(q) u = 0 are singular "
                         "at a state of the run (K_u or K_qdot not invertible): the model's speeds do not "
                         "parametrize its velocities there") from None


class _Speeds:
    r"""The model's speeds as a numerical map: ``u = W(q) qdot``, ``W = -K_u^{-1} K_qdot``.

    The data extracted in the velocities ``w = (qdot, u)`` (``(n+m) x (n+m)`` metric ``H``,
    covector ``c``, rows ``C``) become data in ``qdot`` through ``w = S qdot``, ``S = [1; W]``:

    .. math:: M = S^T H S, \qquad b = S^T c, \qquad a = C S,

    each evaluated from the numeric ``K_qdot(q)``, ``K_u(q)`` by a linear solve, so ``M`` is
    regular wherever the model's kinematic map and mass matrix are (no symbolic pivot).
    A ``K_u`` that is a constant matrix (``u_i = f_i(q, qdot)``, as most kinematic equations are
    written) is inverted once: ``W`` is then the lambdified ``-K_u^{-1} K_qdot`` (no solve per
    evaluation).  With fewer speeds than coordinates (``m < n``) ``W`` is the least-squares
    left inverse of ``B = -K_qdot^{-1} K_u``, ``W = -(K_u^T K_u)^{-1} K_u^T K_qdot`` (the speeds of
    a ``qdot`` in the range of ``B``, and an extension off it); the ``r`` restored coordinates
    (:func:`_restore`) take no part in ``u``: ``W`` has zero columns for them, and their rates
    come from their rows (:attr:`restored`).
    """

    def __init__(self, Kq, Ku, m, *, W=None, extra=0):
        self.Kq, self.Ku, self.m, self._W, self.extra = Kq, Ku, m, W, extra
        self.restored = None  # x -> the r restored rows in w = (qdot, u), unit on their own coordinate

    def W(self, x):
        if self._W is not None:
            W = self._W(x)
        else:
            Ku, Kq = self.Ku(x), self.Kq(x)
            if Ku.shape[-1] == Ku.shape[-2]:
                W = -_solve(Ku, Kq)
            else:  # fewer speeds than coordinates: the least-squares left inverse of B
                KuT = np.swapaxes(Ku, -1, -2)
                W = -_solve(KuT @ Ku, KuT @ Kq)
        if self.extra:
            W = np.concatenate([W, np.zeros(W.shape[:-1] + (self.extra,), W.dtype)], -1)
        return W

    def S(self, x):
        W = self.W(x)
        n = W.shape[-1]
        return np.concatenate([np.broadcast_to(np.eye(n), W.shape[:-2] + (n, n)), W], -2)

    def metric(self, H):
        def metric(x):
            S = self.S(x)
            return np.swapaxes(S, -1, -2) @ H(x) @ S
        return metric

    def covector(self, c):
        if c is None:
            return None
        return lambda x: (np.swapaxes(self.S(x), -1, -2) @ c(x)[..., None])[..., 0]

    def rows(self, C):
        if C is None:
            return None
        return lambda x: C(x) @ self.S(x)

    def rows_in_u(self, C):
        """``C [V; 1]`` with ``qdot = V u``, ``V = -K_qdot^{-1} K_u``: the constraint rows in ``u`` (rows with no
        entry on the restored coordinates)."""
        def rows(x):
            V = -_solve(self.Kq(x), self.Ku(x))
            Cx = C(x)
            n, m = V.shape[-2:]
            return Cx[..., :n] @ V + Cx[..., Cx.shape[-1] - m:]
        return rows

    def _split(self, z, m):
        z = np.asarray(z)
        return z[..., : z.shape[-1] - m], z[..., z.shape[-1] - m:]

    def u_of_qdot(self, z):
        x, v = self._split(z, np.shape(z)[-1] // 2)
        return (self.W(x) @ v[..., None])[..., 0]

    def qdot_of_u(self, z):
        """``(q, u) -> qdot``: ``qdot = -K_qdot^{-1} K_u u``, and the restored coordinates' rates from their rows."""
        x, v = self._split(z, self.m)
        qd = -_solve(self.Kq(x), (self.Ku(x) @ v[..., None]))[..., 0]
        if self.extra:
            Rw = self.restored(x)  # (r, n + r + m): unit on the restored rates
            n = qd.shape[-1]
            rest = (Rw[..., :n] @ qd[..., None] + Rw[..., n + self.extra:] @ v[..., None])[..., 0]
            qd = np.concatenate([qd, -rest], -1)
        return qd


def _restore(sympy, me, frame, bodies, fixed, q, qd, u, Kq, Ku, constraints, aux0):
    r"""The coordinates and rows that a model in minimal speeds eliminated, restored (route (a) of issue 25).

    A model in minimal speeds builds a rolling condition into its kinematics: a body's
    velocity is given (``set_vel``, ``v2pt_theory`` from a contact point ``C`` of zero
    velocity) but is not the time derivative of its position, since ``C``'s own place
    moves although its (material) velocity is zero.  For each body with mass centre ``P``
    and root ``R`` (the fixed point, the zero-velocity point of ``P``'s position tree, or its root point)
    the mismatch

    .. math:: d_P = v_P^{\mathrm{model}}(q, u) - \frac{d}{dt} r_{RP}(q, \dot q)

    is evaluated at random states (random parameter values) on the model's own velocity set
    (``qdot = B u``, ``u`` on its velocity constraints):

    * zero there: ``R`` is fixed; the body's kinetic energy is formed from ``d r_{RP}/dt`` on all
      of ``TQ`` whenever the model's velocity is not that derivative off the set (minimal
      speeds ``m < n``, or a velocity valid on the constraint set only), and is the model's
      own otherwise (unchanged);
    * not zero: ``R``'s place is restored: coordinates ``x_R, y_R`` (and ``z_R``) for the
      inertial components of ``d_P`` that do not vanish, ``r_R = x_R N.x + y_R N.y (+ z_R N.z)``,
      every body located from ``R`` gets the velocity ``dr_R/dt + dr_{RP}/dt``, and the
      rows ``dx_{R,k}/dt - d_{P,k} = 0`` (the model's velocity is the true one) are velocity
      constraints.  All bodies on ``R`` must give the same ``d`` (one place of ``R``).

    A tree with no fixed point has as ``R`` its root (:func:`_root_point`): a point given a velocity
    (``D.set_vel(F, u2*A.y)``) but no position, whose place the model's coordinates do not hold
    (sympy's ``test_kane2.py`` vehicles).  Then ``d_P = v_D`` and ``D``'s place is restored as above:
    without it, Lagrange--d'Alembert on ``q`` alone drops the terms that ``D``'s place carries
    (a Chaplygin system's, ``m a u_1 u_2``).  If ``d`` is a closed form in ``q`` (one speed per coordinate,
    ``P.set_vel(N, u N.x)`` with ``q' = u``), the place is a function of ``q``: nothing is restored.

    Returns ``None`` if nothing is to change, else a dict: ``coords`` (the restored
    dynamicsymbols), ``velocities`` ``{body: Vector}``, ``rows`` (expressions in
    ``(qdot, restored rates, u)``, linear and homogeneous) and ``offsets`` ``{R: r_R}`` (for
    the potentials of loads at points located from ``R``).
    """
    t = me.dynamicsymbols._t
    n, m = len(q), len(u)
    found, roots = [], set()
    for body in bodies:
        P = body.masscenter
        R = _fixed_point(P, frame, aux0, fixed=fixed)
        if R is None:
            R = _root_point(sympy, P, frame)
            roots.add(R)
        if R is None:
            raise ValueError(f"model: the velocity of {body}'s mass centre {P} in {frame} is not defined: no point of "
                             f"its position tree has a velocity in {frame}; locate {P} from a fixed point "
                             f"(locatenew) or give it or a point it is located from a velocity (set_vel)")
        try:
            v_model = P.vel(frame)
        except ValueError as exc:
            raise ValueError(f"model: the velocity of {P} in {frame} is not defined ({exc})") from None
        # the derivative of the position from R is compared numerically (forward mode along qdot) and formed
        # symbolically only for the bodies that take it (derived below)
        found.append((body, R, v_model.to_matrix(frame).xreplace(aux0), P.pos_from(R).to_matrix(frame).xreplace(aux0)))
    if not found:
        return None
    derived = {}

    def v_pos(k):
        """``(d r_RP/dt, its components in frame)`` of the ``k``-th body, formed once."""
        if k not in derived:
            vec = found[k][0].masscenter.pos_from(found[k][1]).dt(frame)
            derived[k] = (vec, vec.to_matrix(frame).xreplace(aux0))
        return derived[k]
    # evaluated in the model's own q, qdot, u (_evaluate walks them as they are; no copy in plain symbols)
    X, V, Us = list(q), list(qd), list(u)
    plain = lambda e: sympy.sympify(e, strict=True).xreplace(aux0)  # noqa: E731
    exprs = [e for (_, _, a, _) in found for e in a]  # the model's velocities
    places = [e for (_, _, _, r) in found for e in r]  # the positions from R
    C = sympy.Matrix([sympy.sympify(c, strict=True).xreplace(aux0) for c in constraints]) if constraints else sympy.zeros(0, 1)
    Cw = linear_coefficients(sympy, C, list(qd) + list(u))[0] if constraints else sympy.zeros(0, n + m)
    K = [Kq, Ku] if u else []
    allx = [plain(e) for e in exprs + places + [e for M in K for e in M] + list(Cw)]
    params = sorted(set().union(*(e.free_symbols for e in allx)) - set(X) - set(V) - set(Us) - {t}, key=str)
    rng = np.random.default_rng(20261126)
    pv = rng.uniform(0.5, 1.5, len(params))
    nb = len(exprs)
    # evaluated at a few points: walked (_evaluate), not lambdified (code generated to run eight times)
    kin = evaluator(sympy, X + V + Us + params, allx[2 * nb:], "model: the kinematic equations")  # K_qdot, K_u, rows
    vel = evaluator(sympy, X + V + Us + params, allx[:nb], "model: the bodies' velocities")
    pos = directional(sympy, X + params, allx[nb: 2 * nb], X, "model: the bodies' positions")  # d/dt: along qdot

    def point(x, on_set):
        """``(x, qdot, u)`` at ``x`` with velocities on all of TQ, or on the model's set."""
        vals = np.asarray(kin(*x, *np.zeros(n), *np.zeros(m), *pv), float)
        kq = vals[: n * n].reshape(n, n) if u else np.eye(n)
        ku = vals[n * n: n * n + n * m].reshape(n, m) if u else -np.eye(n)
        cw = vals[vals.size - Cw.shape[0] * (n + m):].reshape(Cw.shape[0], n + m)
        B = -np.linalg.solve(kq, ku)  # qdot = B u
        if on_set:
            A = cw[:, :n] @ B + cw[:, n:] if u else cw  # the model's rows in u
            basis = np.linalg.svd(A)[2][np.linalg.matrix_rank(A):].T if A.size else np.eye(B.shape[1])
            us = basis @ rng.normal(size=basis.shape[1])
            v = B @ us
        else:
            v = rng.normal(size=n)
            us = np.linalg.lstsq(B, v, rcond=None)[0] if u else v
        return np.concatenate([x, v, us if u else []])

    def mismatch(on_set):
        """``d_P`` relative to ``1 + max |v|`` over the bodies and samples: ``(bodies, samples, 3)``."""
        pts = np.stack([point(rng.uniform(-1, 1, n), on_set) for _ in range(4)], -1)  # (args, samples): one walk
        v_model = np.asarray(vel(*pts, *pv), float)  # (3 bodies, 4)
        v_derived = np.asarray(pos(*pts[:n], *pv, *pts[n: 2 * n])[1], float)
        vals = np.stack([v_model.reshape(len(found), 3, 4), v_derived.reshape(len(found), 3, 4)], 2)  # (b, 3, 2, 4)
        vals = np.moveaxis(vals, -1, 1).swapaxes(-1, -2)  # (bodies, samples, 2, 3)
        return (vals[..., 0, :] - vals[..., 1, :]) / (1.0 + np.abs(vals).max())

    def d_at(x, v):
        """``d_P`` of every body at ``x`` and the velocity ``v`` (the model's speeds ``u = B^{-1} v``): ``(b, 3)``."""
        vals = np.asarray(kin(*x, *np.zeros(n), *np.zeros(m), *pv), float)
        us = np.linalg.solve(-np.linalg.solve(vals[: n * n].reshape(n, n), vals[n * n: n * n + n * m].reshape(n, m)),
                             v) if u else []
        pts = np.concatenate([x, v, us])[:, None]
        v_derived = np.asarray(pos(*pts[:n], *pv, *pts[n: 2 * n])[1], float)
        return (np.asarray(vel(*pts, *pv), float) - v_derived).reshape(len(found), 3)

    def closed(on):
        r"""Whether the bodies ``on`` give their root a velocity ``d = c(q) qdot`` that is a closed form,
        ``dc(a, b) = D_a (c b) - D_b (c a) = 0`` (central differences at two random ``q``): its place is then a
        function of ``q`` (up to a constant) that the model's coordinates already fix, as ``P.set_vel(N, u N.x)``
        with ``q' = u`` (sympy's ``test_kane.py::test_one_dof``), and nothing is restored.  Only with one speed
        per coordinate (``d`` defined on all of ``TQ``)."""
        if m and m != n:
            return False
        h, worst, size = 1e-5, 0.0, 0.0
        for _ in range(2):
            x, a, b = rng.uniform(-1, 1, n), rng.normal(size=n), rng.normal(size=n)
            try:
                dab = (d_at(x + h * a, b) - d_at(x - h * a, b)) / (2 * h)
                dba = (d_at(x + h * b, a) - d_at(x - h * b, a)) / (2 * h)
            except np.linalg.LinAlgError:  # the kinematic map singular there: restored (right either way)
                return False
            worst = max(worst, float(np.max(np.abs(dab - dba)[on])))
            size = max(size, float(np.max(np.abs(d_at(x, a))[on])), float(np.max(np.abs(dab)[on])))
        return worst <= 1e-6 * (1.0 + size)

    off_tq, d_set = np.abs(mismatch(False)).max((1, 2)), mismatch(True)
    off_set = np.abs(d_set).max(1)
    tol = 1e-9
    velocities, rows, coords, offsets = {}, [], [], {}
    for R in dict.fromkeys(r for _, r, *_ in found):
        on = [k for k, (_, r, *_) in enumerate(found) if r is R]
        comps = [i for i in range(3) if any(off_set[k, i] > tol for k in on)]
        if R in roots and closed(on):  # a root whose place q fixes: the model's velocities, as they are
            continue
        offset = 0 * frame.x
        if comps:
            d = [found[k][2] - v_pos(k)[1] for k in on]
            if len(on) > 1:
                if np.max(np.abs(d_set[on[1:]] - d_set[on[0]])) > tol:
                    raise MinimalSpeedsError(
                        f"model: the bodies {[str(found[k][0]) for k in on]} located from {R} give it different "
                        "velocities (each body's velocity minus the derivative of its position from "
                        f"{R}): liefi cannot restore one place of {R}; define every body's velocity from the same "
                        "kinematics (v2pt_theory / a2pt_theory from one contact point)")
            names = [f"{c}_{R.name}" for c in "xyz"]
            taken = {str(s.func) if hasattr(s, "func") else str(s) for s in q}
            for i in comps:
                if names[i] in taken:
                    raise ValueError(f"model: a coordinate is named {names[i]!r}, the name liefi gives the restored "
                                     f"place of {R}; rename the coordinate")
                if names[i] in {str(s.func) for s in coords}:  # two points of one name: one place, silently
                    raise ValueError(f"model: two points named {R.name!r} (the roots of different bodies' position "
                                     f"trees) both need their places restored, as {names[i]!r}; give them "
                                     "different names")
            new = [sympy.Function(names[i])(t) for i in comps]  # by name, never parsed (a point named "C D" or "a:c")
            coords += new
            unit = (frame.x, frame.y, frame.z)
            for s, i in zip(new, comps):
                offset += s * unit[i]
                rows.append(s.diff(t) - d[0][i])
            offsets[R] = offset
        for k in on:
            if comps or off_tq[k] > tol or m < n:
                velocities[found[k][0]] = v_pos(k)[0] + offset.dt(frame) if comps else v_pos(k)[0]
    if not velocities:
        return None
    return dict(coords=coords, velocities=velocities, rows=rows, offsets=offsets)


def _tree(point):
    """The points of ``point``'s position tree (``locatenew`` / ``set_pos`` in either direction)."""
    seen, todo = {point}, [point]
    while todo:
        p = todo.pop(0)
        for other in p._pos_dict:
            if other not in seen:
                seen.add(other)
                todo.append(other)
    return seen


def _fixed_point(point, frame, aux0=None, roots=(), fixed=None):
    """``fixed`` (a ``System``'s fixed point) if it is in ``point``'s position tree, else a point of that tree with
    velocity set to zero in ``frame`` (the auxiliary speeds at zero), else one of ``roots`` (the root points whose
    places :func:`_restore` restored, see :func:`_root_point`) in that tree, or None."""
    if fixed is not None and fixed in _tree(point):
        return fixed
    seen, todo, root = {point}, [point], None
    while todo:
        p = todo.pop(0)
        v = p._vel_dict.get(frame, None)
        if v == 0 or (aux0 and v is not None and all(e == 0 for e in v.to_matrix(frame).xreplace(aux0))):
            return p
        if root is None and p in roots:
            root = p
        for other in p._pos_dict:
            if other not in seen:
                seen.add(other)
                todo.append(other)
    return root


def _root_point(sympy, point, frame):
    """The root of ``point``'s position tree when no point of it is fixed: a point whose velocity in ``frame`` is
    set (``set_vel``) but whose position from a fixed point is not known, as in sympy's ``pD.set_vel(F, u2*A.y)``
    with every body located from ``D`` (Kane & Levinson 1985, ex. 8.12); None if no point of the tree has a
    velocity set in ``frame``.

    Of the points with a velocity set, the one whose velocity is the shortest expression (the velocity given, not
    one ``v2pt_theory`` derived from it by adding ``omega x r``), then the one with the most points located from it
    (``locatenew``), then by name: the same point for every body of the tree.  Which one it is names the restored
    coordinates only: the bodies' velocities are checked to be those of one rigid tree (:func:`_restore`), so the
    place of any of its points fixes the places of all."""
    given = [p for p in _tree(point) if frame in p._vel_dict]
    size = lambda p: sum(sympy.count_ops(m) for m, _ in p._vel_dict[frame].args)  # noqa: E731
    return min(given, key=lambda p: (size(p), -len(p._pos_dict), p.name)) if given else None


class _Checks:
    """Numerical identities the model must satisfy, evaluated at random states with the given constants.

    The expressions may hold ``q``, ``qdot`` and the speeds ``u``; at each random ``(q, qdot)``
    the speeds are ``u = W(q) qdot`` from the model's kinematic map, solved numerically
    (:class:`_Speeds`), and the auxiliary speeds are zero.
    """

    def __init__(self, sympy, q, qd, u, frame, aux0=None):
        self.sympy, self.q, self.qd, self.u, self.frame = sympy, q, qd, u, frame
        self.aux0 = aux0 or {}
        self.params, self.values, self.speeds = (), np.zeros(0), None
        self.rng = np.random.default_rng(20261124)

    def _plain(self):
        """``(q, qdot, u, prepared)``: the arguments of the checks' evaluators (the model's own dynamicsymbols,
        which :mod:`liefi.systems._evaluate` walks as they are) and an expression's preparation (the auxiliary
        speeds at zero)."""
        sp = self.sympy  # the model's own symbols: _evaluate walks the expressions as they are (no plain copy)
        plain = lambda e: sp.sympify(e, strict=True).xreplace(self.aux0)  # noqa: E731
        return list(self.q), list(self.qd), list(self.u), plain

    def _points(self):
        """Four random ``(q, qdot)`` (rows of ``(4, 2n)``) and their speeds ``u = W(q) qdot`` (``(4, m)``)."""
        n = len(self.q)
        xv = []
        for _ in range(4):
            x, v = self.rng.uniform(-1, 1, n), self.rng.normal(size=len(self.qd))
            xv.append(np.concatenate([x, v]))
        xv = np.stack(xv)
        return xv, (self.speeds.u_of_qdot(xv) if self.u else np.zeros((4, 0)))

    def residual(self, exprs, scale_exprs, what):
        """Largest ``|exprs|`` relative to ``1 + |scale_exprs|`` at four random ``(q, qdot)``."""
        X, V, Us, plain = self._plain()
        # evaluated at four points: walked (_evaluate), not lambdified
        f = evaluator(self.sympy, X + V + Us + list(self.params), [plain(e) for e in list(exprs) + list(scale_exprs)],
                      what)
        xv, us = self._points()
        vals = np.abs(np.asarray(f(*xv.T, *us.T, *self.values), complex))  # (exprs, 4): the four points in one walk
        k = len(exprs)
        return float(np.max(np.max(vals[:k], 0, initial=0.0) / (1.0 + np.sum(vals[k:], 0)), initial=0.0))

    def power_is_minus_dU_dt(self, W, U, loads, given):
        """The power ``W`` of the loads equals ``-dU/dt = -grad U . qdot`` at four random ``(q, qdot)``, relative to
        ``1 + |W| + |dU/dt|``; ``dU/dt`` by forward-mode differentiation of ``U``'s walk (no symbolic derivative)."""
        what = "potential" if given else "model: the loads"
        X, V, Us, plain = self._plain()
        n, params = len(X), list(self.params)
        fW = evaluator(self.sympy, X + V + Us + params, [plain(W)], what)
        fU = directional(self.sympy, X + params, [plain(U)], X, what)
        xv, us = self._points()
        w = np.asarray(fW(*xv.T, *us.T, *self.values), complex)[0]  # (4,): the four points in one walk
        dU = np.asarray(fU(*xv[:, :n].T, *self.values, *xv[:, n:].T)[1], complex)[0]
        err = float(np.max(np.abs(w + dU) / (1.0 + np.abs(w) + np.abs(dU))))
        if err > 1e-9:
            what = "potential: its -dU/dt is not" if given else "model: liefi's potential gives a -dU/dt that is not"
            raise NonConservativeLoadError(
                f"{what} the power of the loads {[str(x) for x in loads]} (relative difference {err:.3g}); "
                "the loads are not conservative with this potential"
            )
