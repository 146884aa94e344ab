"""The kinematics of a ``sympy.physics.mechanics`` model: its speed map and the identities it must satisfy.

Private helpers of :mod:`liefi.systems.mechanics` (which exports the two errors): the kinematic differential equations as
matrices (:func:`_kinematics`), the speed map solved numerically at each evaluation
(:class:`_Speeds`) and the numerical checks of the model (:class:`_Checks`).
"""

from __future__ import annotations

import numpy as np

from .sympy_input import lambdify_checked


class NonConservativeLoadError(ValueError):
    """A load of the model has no potential liefi can derive (velocity-dependent, a torque, or a force
    varying in the inertial frame); pass ``potential=`` if the loads are conservative."""


class MinimalSpeedsError(ValueError):
    """A body's velocity is not the time derivative of its position: the model builds the rolling
    constraint into its kinematics instead of stating it as a velocity constraint."""


def _kinematics(sympy, kd, q, qd, u):
    """``(K_qdot, K_u)``: the kinematic differential equations as ``K_qdot(q) qdot + K_u(q) u = 0``.

    Only the matrices: the map is solved numerically at each evaluation (:class:`_Speeds`),
    never by a symbolic inverse, whose pivots may vanish where the map is regular.
    """
    n = len(q)
    if len(u) != n:
        raise ValueError(f"model: {len(u)} generalized speeds for {n} coordinates; liefi needs one speed per coordinate")
    K = sympy.Matrix(kd)
    Ku, Kq = K.jacobian(u), K.jacobian(qd)
    rest = K.xreplace(dict.fromkeys(u, 0)).xreplace(dict.fromkeys(qd, 0))
    if any(Ku.has(s) or Kq.has(s) for s in list(u) + list(qd)):
        raise ValueError("model: the kinematic differential equations are not linear in u and qdot")
    if any(e != 0 and sympy.simplify(e) != 0 for e in rest):
        raise ValueError("model: the kinematic differential equations K_qdot qdot + K_u u + f_k = 0 have a term "
                         f"f_k = {list(rest)} free of u and qdot; liefi needs the speeds linear and homogeneous in "
                         "qdot (time-dependent kinematics are not integrated)")
    return Kq, Ku


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

    The data extracted in the velocities ``w = (qdot, u)`` (``2n x 2n`` metric ``H``, covector
    ``c``, rows ``C``) become data in ``qdot`` through ``w = S qdot``, ``S = [1; W]``:

    .. math:: M = S^T H S, \qquad b = S^T c, \qquad a = C S,

    each evaluated from the numeric ``K_qdot(q)``, ``K_u(q)`` by a linear solve, so ``M`` is
    regular wherever the model's kinematic map and mass matrix are (no symbolic pivot).
    """

    def __init__(self, Kq, Ku):
        self.Kq, self.Ku = Kq, Ku

    def W(self, x):
        return -_solve(self.Ku(x), self.Kq(x))

    def S(self, x):
        W = self.W(x)
        return np.concatenate([np.broadcast_to(np.eye(W.shape[-1]), W.shape), W], -2)

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
        """``C [V; 1]`` with ``qdot = V u``, ``V = -K_qdot^{-1} K_u``: the constraint rows in ``u``."""
        def rows(x):
            V = -_solve(self.Kq(x), self.Ku(x))
            Cx = C(x)
            n = V.shape[-1]
            return Cx[..., :n] @ V + Cx[..., n:]
        return rows

    def _split(self, z):
        z = np.asarray(z)
        n = z.shape[-1] // 2
        return z[..., :n], z[..., n:]

    def u_of_qdot(self, z):
        x, v = self._split(z)
        return (self.W(x) @ v[..., None])[..., 0]

    def qdot_of_u(self, z):
        x, v = self._split(z)
        return -_solve(self.Kq(x), (self.Ku(x) @ v[..., None]))[..., 0]


def _fixed_point(point, frame, aux0=None):
    """A point of ``point``'s position tree with velocity set to zero in ``frame`` (the auxiliary speeds at zero), or None."""
    seen, todo = {point}, [point]
    while todo:
        p = todo.pop(0)
        v = p._vel_dict.get(frame, None)
        if v == 0 or (aux0 and v is not None and all(e == 0 for e in v.to_matrix(frame).xreplace(aux0))):
            return p
        for other in p._pos_dict:
            if other not in seen:
                seen.add(other)
                todo.append(other)
    return None


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

    def residual(self, exprs, scale_exprs, what):
        """Largest ``|exprs|`` relative to ``1 + |scale_exprs|`` at four random ``(q, qdot)``."""
        sp = self.sympy
        X = [sp.Dummy() for _ in self.q]
        V = [sp.Dummy() for _ in self.qd]
        Us = [sp.Dummy() for _ in self.u]
        to = {**dict(zip(self.qd, V)), **dict(zip(self.u, Us))}
        plain = lambda e: sp.sympify(e).xreplace(self.aux0).xreplace(to).xreplace(dict(zip(self.q, X)))  # noqa: E731
        f = lambdify_checked(sp, X + V + Us + list(self.params),
                             [plain(e) for e in list(exprs) + list(scale_exprs)], what, dummify=True)
        worst = 0.0
        for _ in range(4):
            x, v = self.rng.uniform(-1, 1, len(X)), self.rng.normal(size=len(V))
            us = self.speeds.u_of_qdot(np.concatenate([x, v])) if self.u else np.zeros(0)
            vals = np.abs(np.asarray(f(*x, *v, *us, *self.values), complex))
            worst = max(worst, float(np.max(vals[: len(exprs)], initial=0.0) / (1.0 + np.sum(vals[len(exprs):]))))
        return worst

    def velocities_are_derivatives(self, me, bodies, fixed):
        for body in bodies:
            P = body.masscenter
            O = fixed or _fixed_point(P, self.frame, self.aux0)
            if O is None:
                continue
            try:
                v_model = P.vel(self.frame)
            except ValueError as exc:
                raise ValueError(f"model: the velocity of {P} in {self.frame} is not defined ({exc})") from None
            v_pos = P.pos_from(O).dt(self.frame)
            a, b = v_model.to_matrix(self.frame), v_pos.to_matrix(self.frame)
            err = self.residual(list(a - b), list(a) + list(b), f"model: the velocity of {P}")
            if err > 1e-9:
                raise MinimalSpeedsError(
                    f"model: the velocity of {P} (body {body}) is not the time derivative of its position from "
                    f"the fixed point {O} (relative difference {err:.3g}): the model builds a rolling condition "
                    "into its kinematics (minimal speeds). liefi needs the contact point's coordinates among the "
                    "generalized coordinates and the rolling condition as velocity constraints (KanesMethod "
                    "u_dependent= and velocity_constraints=, LagrangesMethod nonhol_coneqs=)"
                )

    def power_is_minus_dU_dt(self, W, U, loads, given):
        dU = sum((self.sympy.diff(U, qi) * vi for qi, vi in zip(self.q, self.qd)), self.sympy.S.Zero)
        err = self.residual([W + dU], [W, dU], "potential" if given else "model: the loads")
        if err > 1e-9:
            what = "potential: its -dU/dt is not" if given else "model: liefi's potential gives a -dU/dt that is not"
            raise NonConservativeLoadError(
                f"{what} the power of the loads {[str(x) for x in loads]} (relative difference {err:.3g}); "
                "the loads are not conservative with this potential"
            )
