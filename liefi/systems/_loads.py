r"""The non-conservative loads of a ``sympy.physics.mechanics`` model as a liefi force law.

A load ``(P, F)`` at a point (or ``(A, T)`` on a frame) with no potential -- a
damper, a torque, a ``LinearDamper`` or ``TorqueActuator``, a force that varies
in time or holds a specified input ``F(t)`` -- contributes the generalized force

.. math:: Q_j = F \cdot \frac{\partial v_P}{\partial w_j}
          \quad (T \cdot \partial \omega_A / \partial w_j)

on the model's velocities ``w = (qdot, u)`` (the partial velocities: the power
``F . v_P`` with ``F`` held), the Lagrange--d'Alembert force of the model's own
equations.  Through ``w = S(q) qdot`` (:class:`liefi.systems._kinematics._Speeds`)
it becomes the covector ``S^T Q`` on ``qdot``, liefi's velocities, exactly as the
vector potential does.  Dynamicsymbols of ``t`` that are no coordinate or speed
are the force's named *inputs* (given at run time, ``inputs={"F": signal}``), and
``t`` itself the clock.  The result is a :class:`liefi.systems.forcing.ForceLaw`
set as the system's ``force``.
"""

from __future__ import annotations

import numpy as np

from .forcing import ForceLaw


class LoadForces:
    """The generalized forces ``Q(t, q, w; u)`` of the non-conservative loads, as sympy expressions."""

    def __init__(self, sympy, exprs, T, Xq, Vw, inputs, names, speeds_count):
        self.sympy, self.exprs, self.T, self.Xq, self.Vw = sympy, exprs, T, Xq, Vw
        self.inputs, self.names, self.m = inputs, names, speeds_count

    @property
    def free_symbols(self):
        args = {self.T, *self.Xq, *self.Vw, *self.inputs}
        return set().union(*(e.free_symbols for e in self.exprs)) - args

    def bind(self, binder, speeds):
        """The :class:`ForceLaw` ``F(t, q, qdot, u)`` on liefi's velocities ``qdot``; ``binder(args, exprs, shape,
        what)`` lambdifies with the model's constants (``mechanics._bound``), ``speeds`` the model's speed map."""
        args = [self.T, *self.Xq, *self.Vw, *self.inputs]
        Q = binder(args, self.exprs, (len(self.exprs),), "loads")
        n = len(self.Xq)

        def force(t, q, v, u=None):
            q, v = np.asarray(q), np.asarray(v)
            batch = np.broadcast_shapes(q.shape[:-1], v.shape[:-1], np.shape(t))
            w = v if speeds is None else np.concatenate(
                [v, speeds.u_of_qdot(np.concatenate([q, v], -1))], -1)
            parts = [np.broadcast_to(np.asarray(t)[..., None], batch + (1,)), np.broadcast_to(q, batch + (n,)),
                     np.broadcast_to(w, batch + w.shape[-1:])]
            if self.inputs:
                parts.append(np.broadcast_to(u, batch + (len(self.inputs),)))
            x = np.concatenate(parts, -1)
            F = Q(x)
            if speeds is not None:  # the covector on w = (qdot, u) as one on qdot: S^T Q
                F = (np.swapaxes(speeds.S(q), -1, -2) @ F[..., None])[..., 0]
            return F

        force.__name__ = "loads"
        return ForceLaw(force, self.names)


def generalized_forces(sympy, me, pairs, power_of, qd, u, q):
    """:class:`LoadForces` of the load pairs ``(where, vec)``; ``power_of(where, vec)`` the model's power of one
    load (its velocities, restored places included), ``qd``/``u``/``q`` the model's velocities and coordinates."""
    t = me.dynamicsymbols._t
    w = list(qd) + list(u)
    held = [sympy.Dummy(f"w{j}") for j in range(len(w))]
    exprs = [sympy.S.Zero] * len(w)
    for where, vec in pairs:
        vec_held = vec.xreplace(dict(zip(w, held)))  # F held: the partial velocities of the power
        P = sympy.expand(power_of(where, vec_held))
        for j, wj in enumerate(w):
            exprs[j] += P.diff(wj)
    exprs = [e.xreplace(dict(zip(held, w))) for e in exprs]
    # plain symbols for t, q, w and the inputs: derivatives first (q' is a Derivative of q)
    T = sympy.Dummy("t")  # liefi's own: a model's symbol named like it (a constant "t_") stays the model's
    Xq = [sympy.Dummy(f"q{j}") for j in range(len(q))]
    Vw = [sympy.Dummy(f"v{j}") for j in range(len(w))]
    exprs = [e.xreplace(dict(zip(w, Vw))).xreplace(dict(zip(q, Xq))) for e in exprs]
    specified = sorted(set().union(*(me.find_dynamicsymbols(e) for e in exprs)), key=str)
    if any(isinstance(s, sympy.Derivative) for s in specified):
        raise ValueError(f"model: the loads hold derivatives of specified inputs "
                         f"{[str(s) for s in specified if isinstance(s, sympy.Derivative)]}; give them as inputs "
                         "of their own")
    names = [str(s.func) for s in specified]
    if len(set(names)) != len(names):
        raise ValueError(f"model: specified inputs with the same name {names}")
    inputs = [sympy.Dummy(nm) for nm in names]
    exprs = [e.xreplace(dict(zip(specified, inputs))).xreplace({t: T}) for e in exprs]
    return LoadForces(sympy, exprs, T, Xq, Vw, inputs, tuple(names), len(u))
