r"""The textbook rolling rigid body, written by hand: the independent reference of the rolling scenes.

Borisov & Mamaev ("Rolling of a rigid body on plane and sphere. Hierarchy of
dynamics", Regul. Chaotic Dyn. 7 (2002) 177): with ``K = I Omega + m r x (Omega
x r)`` the angular momentum about the contact point and ``r(Gamma)`` the vector
from the centre of mass to it,

.. math:: \dot K = K \times \Omega + m \dot r \times (\Omega \times r) + m g\, r \times \Gamma, \qquad
          \dot R = R \hat\Omega, \qquad \dot x_i = -\langle R^T e_i, \Omega \times r \rangle,

on ``y = (R row-major, x, y, K)``.  Nothing here comes from liefi's derivation:
the contact point and its rate are the scene's own hand-written formulas
(:func:`rolling_equations`' ``contact``), the 3 x 3 solve is Cramer's rule,
scalar by scalar.  :class:`RollingReferenceScene` solves them by DOP853 and
maps the solution to liefi's names (``rattleback``, ``rolling-disk``).
"""

from __future__ import annotations


import numpy as np

from .base import Scene


def rolling_equations(inertia, mass, g, contact):
    """The rolling rigid body's equations, ``fun(t, y)``, ``y = (R row-major, x, y, K)`` (module docstring).

    ``contact(G1, G2, G3, d1, d2, d3) -> (r1, r2, r3, q1, q2, q3)``: the contact
    point ``r(Gamma)`` and its rate ``q = dr(Gamma) . d`` along ``Gamma' = d``,
    written by hand, scalar code that also takes arrays.  ``fun.omega(y)`` gives
    ``(Omega, r)`` at ``y`` (vectorised over the last axis).
    """
    I = np.asarray(inertia, float)
    i11, i12, i13, i22, i23, i33 = I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2]
    m = float(mass)

    def fun(t, y):
        R11, R12, R13, R21, R22, R23, G1, G2, G3 = y[:9]
        K1, K2, K3 = y[11], y[12], y[13]
        r1, r2, r3, _, _, _ = contact(G1, G2, G3, 0.0, 0.0, 0.0)
        rr = r1 * r1 + r2 * r2 + r3 * r3
        # K = (I + m (|r|^2 - r r^T)) Omega
        m11, m12, m13 = i11 + m * (rr - r1 * r1), i12 - m * r1 * r2, i13 - m * r1 * r3
        m22, m23, m33 = i22 + m * (rr - r2 * r2), i23 - m * r2 * r3, i33 + m * (rr - r3 * r3)
        c11, c12, c13 = m22 * m33 - m23 * m23, m13 * m23 - m12 * m33, m12 * m23 - m13 * m22
        c22, c23, c33 = m11 * m33 - m13 * m13, m12 * m13 - m11 * m23, m11 * m22 - m12 * m12
        det = m11 * c11 + m12 * c12 + m13 * c13
        W1 = (c11 * K1 + c12 * K2 + c13 * K3) / det
        W2 = (c12 * K1 + c22 * K2 + c23 * K3) / det
        W3 = (c13 * K1 + c23 * K2 + c33 * K3) / det
        # Gamma' = Gamma x Omega, and r' by hand
        d1, d2, d3 = G2 * W3 - G3 * W2, G3 * W1 - G1 * W3, G1 * W2 - G2 * W1
        _, _, _, q1, q2, q3 = contact(G1, G2, G3, d1, d2, d3)
        v1, v2, v3 = W2 * r3 - W3 * r2, W3 * r1 - W1 * r3, W1 * r2 - W2 * r1  # Omega x r
        Kd1 = K2 * W3 - K3 * W2 + m * (q2 * v3 - q3 * v2) + m * g * (r2 * G3 - r3 * G2)
        Kd2 = K3 * W1 - K1 * W3 + m * (q3 * v1 - q1 * v3) + m * g * (r3 * G1 - r1 * G3)
        Kd3 = K1 * W2 - K2 * W1 + m * (q1 * v2 - q2 * v1) + m * g * (r1 * G2 - r2 * G1)
        out = np.empty(14, dtype=np.result_type(y, float))  # complex in, complex out (a complex step)
        for i, (a, b_, c) in enumerate(((R11, R12, R13), (R21, R22, R23), (G1, G2, G3))):
            out[3 * i:3 * i + 3] = (b_ * W3 - c * W2, c * W1 - a * W3, a * W2 - b_ * W1)  # R Omega^
        out[9] = -(R11 * v1 + R12 * v2 + R13 * v3)
        out[10] = -(R21 * v1 + R22 * v2 + R23 * v3)
        out[11:14] = (Kd1, Kd2, Kd3)
        return out

    def omega(y):
        """``(Omega, r)`` at ``y`` (the same algebra as ``fun``, vectorised over the last axis)."""
        one = np.ndim(y) == 1
        y = np.asarray(y, float).reshape(len(y), -1)
        G = y[6:9]
        zero = 0.0 * G[0]
        r = np.stack(contact(G[0], G[1], G[2], zero, zero, zero)[:3])
        rr = np.sum(r * r, 0)
        Mop = I[..., None] + m * (rr * np.eye(3)[..., None] - r[:, None] * r[None, :])
        W = np.linalg.solve(np.moveaxis(Mop, -1, 0), np.moveaxis(y[11:14], -1, 0)[..., None])[..., 0]
        W = np.moveaxis(W, 0, -1)
        return (W[:, 0], r[:, 0]) if one else (W, r)

    fun.omega = omega
    return fun


class RollingReferenceScene(Scene):
    """A rolling body's scene whose reference is :func:`rolling_equations`, solved by DOP853.

    Subclasses give ``mass``, ``inertia`` (3 x 3), ``reference_equations()``,
    ``start_attitude()`` -> ``(R, Omega)`` and ``reference_observables(Omega,
    Gamma)`` -> dict (batch-first), the same quantities :meth:`observables` reads
    from liefi's reduced state.
    """

    reference = "numerical"
    figures_need_configuration = True
    reference_rtol = 1e-13
    reference_atol = 1e-13
    observable_names: tuple = ()

    @property
    def error_variables(self):
        return ("r_1", "r_2") + self.system.state_names + tuple(self.observable_names)

    def body_rates(self, y, names):
        """``(Omega, Gamma)`` from liefi's reduced state (rows of ``y`` named by ``names``), batch-first."""
        z = np.stack([y[names.index(n)] for n in self.system.state_names], -1)
        m = np.asarray(self.system.metric(z[..., :9]), float)
        W = np.linalg.solve(m, z[..., 9:][..., None])[..., 0][..., :3]
        return W, z[..., 6:9]

    def observables(self, y, names):
        return self.reference_observables(*self.body_rates(y, names))

    def reference_method(self):
        return (f"DOP853 (scipy solve_ivp, rtol {self.reference_rtol:g}, atol {self.reference_atol:g}) on the "
                "rolling rigid body's equations written by hand (liefi.scenes.rolling_reference)")

    def _reference(self, t_final):
        """The dense reference on ``[0, t_final]``, cached by horizon: ``(T, sol.sol, None, omega)``."""
        cache = self.__dict__.setdefault("_refcache", {})
        hit = cache.get("dense")
        if hit is None or hit[0] < t_final:
            y0 = np.asarray(self.initial_state(self.variant()), float)
            _, W0 = self.start_attitude()
            fun = self.reference_equations()
            r0 = fun.omega(np.concatenate([y0[:11], np.zeros(3)]))[1]
            K0 = self.inertia @ W0 + self.mass * np.cross(r0, np.cross(W0, r0))
            sol = self.solve_reference(fun, np.concatenate([y0[:11], K0]), t_final, dense_output=True)
            hit = cache["dense"] = (float(t_final), sol.sol, None, fun.omega)
        return hit

    def reference_solution(self, variant, t_final, *, backend=None):
        """The hand-written reference on ``[0, t_final]`` (what :meth:`exact` reads; ``liefi reproduce``
        computes it once up front), not the base class' liefi-derived constrained field."""
        self._reference(float(t_final))
        return lambda t: self.exact(t, variant)

    def exact(self, t, variant):
        t = np.asarray(t, float)
        T, dense, _, omega = self._reference(float(t[-1]))
        Y = dense(t)
        W, r = omega(Y)
        G = Y[6:9]
        u = -np.stack([np.sum(Y[0:3] * np.cross(W.T, r.T).T, 0), np.sum(Y[3:6] * np.cross(W.T, r.T).T, 0)])
        w = np.cross(G.T, r.T).T  # Gamma x r: the height's rate is <w, Omega>
        Pi = self.inertia @ W + self.mass * w * np.sum(w * W, 0)
        extra = self.reference_observables(W.T, G.T)
        names = self.system.space.group.config_names + self.system.state_names + tuple(self.observable_names)
        vals = np.concatenate([Y[:11], Y[:9], Pi, self.mass * u] + [np.asarray(extra[k])[None]
                                                                      for k in self.observable_names])
        return {n: vals[i] for i, n in enumerate(names)}
