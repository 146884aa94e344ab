r"""The Chaplygin ball: a dynamically asymmetric ball rolling without slipping, centre of mass at its centre.

Built by :func:`liefi.systems.rolling.rolling_body` from its data only -- mass ``m``,
principal moments ``I = (I_1, I_2, I_3)`` (distinct), radius ``a`` --
on ``SO(3) x R^2`` with the whole attitude advected and the two no-slip rows
kept as constraint momenta (:mod:`liefi.systems.rolling` says why).  On the constraint
set liefi's field is Chaplygin's (1903)

.. math:: \dot M = M \times \Omega, \qquad \dot\Gamma = \Gamma \times \Omega, \qquad
          M = I\Omega + m a^2\, \Gamma \times (\Omega \times \Gamma),

with ``M`` the angular momentum about the contact point; in liefi's momenta
``M = Pi + a Gamma x (p_1 rho_1 + p_2 rho_2)`` (``p = m u``, ``rho_i = R^T e_i``).
First integrals: the energy, ``<M, Gamma>``, ``|M|^2`` and ``|Gamma|^2`` (and the
other inner products of the advected ``rho_1, rho_2, Gamma``: Casimirs).

``V`` penalizes the constraint momenta, ``h~``, the six Casimirs ``<rho_i, rho_j>``
and ``<M, Gamma>``, ``|M|^2``.  The last two are first integrals of the
constrained motion, not of the extended field off ``C`` (there ``d/dt <M,
Gamma> = O(|J|)``); ``V`` holds ``J`` at zero, where they are: the invariant set
``{J = 0, I_j = I_j0}`` is invariant and attracting.

Reference: Chaplygin's equations above, with ``rho_i' = rho_i x Omega``,
``R' = R hat(Omega)`` and the contact point's path ``(x, y)' = a (<rho_1, Omega x
Gamma>, <rho_2, Omega x Gamma>)``, written by hand in :func:`chaplygin_equations`
(independent of liefi's derivation) and solved by DOP853 at ``1e-13``.
Figure: the contact point's path on the plane.
"""

from __future__ import annotations


import numpy as np

from ..results import scene_figures as plotting
from ..integrator.feedback import Invariant
from ..groups import SO3
from ..systems.rolling import ATTITUDE_CASIMIRS, rolling_body, rolling_start, sphere
from .base import Scene, Variant

# reduced state z = (rho_1 (0:3), rho_2 (3:6), Gamma (6:9), Pi (9:12), p (12:14))


def contact_momentum(z, a):
    """``M = Pi + a Gamma x (p_1 rho_1 + p_2 rho_2)``: the angular momentum about the contact point."""
    rho1, rho2, G, Pi, p = z[..., 0:3], z[..., 3:6], z[..., 6:9], z[..., 9:12], z[..., 12:14]
    w = p[..., 0:1] * rho1 + p[..., 1:2] * rho2
    return Pi + a * np.stack([G[..., 1] * w[..., 2] - G[..., 2] * w[..., 1],
                              G[..., 2] * w[..., 0] - G[..., 0] * w[..., 2],
                              G[..., 0] * w[..., 1] - G[..., 1] * w[..., 0]], -1)


def _invariants(a):
    def m_gamma(z):
        M = contact_momentum(z, a)
        return M[..., 0] * z[..., 6] + M[..., 1] * z[..., 7] + M[..., 2] * z[..., 8]

    def m_sq(z):
        M = contact_momentum(z, a)
        return M[..., 0] ** 2 + M[..., 1] ** 2 + M[..., 2] ** 2

    return Invariant("M.Gamma", m_gamma), Invariant("|M|^2", m_sq)


def chaplygin_equations(inertia, mass, radius):
    """Chaplygin's equations ``fun(t, y)``, ``y = (R row-major, x, y, rho_1, rho_2, Gamma, M)`` (reference only)."""
    I = np.diag(np.asarray(inertia, float))
    ma2 = mass * radius**2

    def fun(t, y):
        R = y[:9].reshape(3, 3)
        r1, r2, G, M = y[11:14], y[14:17], y[17:20], y[20:23]
        W = np.linalg.solve(I + ma2 * (np.dot(G, G) * np.eye(3) - np.outer(G, G)), M)
        What = np.array([[0.0, -W[2], W[1]], [W[2], 0.0, -W[0]], [-W[1], W[0], 0.0]])
        v = np.cross(W, G)
        return np.concatenate([(R @ What).ravel(), radius * np.array([r1 @ v, r2 @ v]),
                               np.cross(r1, W), np.cross(r2, W), np.cross(G, W), np.cross(M, W)])

    return fun


class ChaplyginBall(Scene):
    name = "chaplygin-ball"
    in_paper = False
    title = "Chaplygin ball rolling without slipping (whole attitude advected)"
    paper = "future work of the paper: rolling bodies (semidirect-product reduction)"
    reference = "numerical"
    dt = 1e-3
    t_final = 100.0
    scheme = "imex-rk4"
    gains = 1.0
    variants = {"asymmetric": Variant(
        "asymmetric", "m = 1, a = 1, I = (0.3, 0.4, 0.5); tilted start, Omega0 = (1, 0.5, 2)")}
    figures_need_configuration = True

    mass, radius = 1.0, 1.0
    inertia = np.array([0.3, 0.4, 0.5])
    R0_axis = np.array([0.3, -0.5, 0.2])
    Omega0 = np.array([1.0, 0.5, 2.0])
    reference_rtol = 1e-13
    reference_atol = 1e-13

    @property
    def error_variables(self):
        return ("r_1", "r_2") + self.system.state_names

    def build_system(self):
        return rolling_body(self.mass, self.inertia, sphere(self.radius), gravity=1.0)

    def initial_state(self, variant):
        return rolling_start(self.system, SO3().exp(self.R0_axis), self.Omega0)

    def invariants(self, variant):
        return ("constraints", "energy") + ATTITUDE_CASIMIRS + _invariants(self.radius)

    def reference_method(self):
        return (f"DOP853 (scipy solve_ivp, rtol {self.reference_rtol:g}, atol {self.reference_atol:g}) on "
                "Chaplygin's equations written by hand (liefi.scenes.chaplygin_ball.chaplygin_equations)")

    def exact(self, t, variant):
        t = np.asarray(t, float)

        def solve():
            y0 = np.asarray(self.initial_state(variant), float)
            R0, pos0, V0 = y0[:9].reshape(3, 3), y0[9:11], y0[11:20]
            G0, W0 = V0[6:9], self.Omega0
            M0 = self.inertia * W0 + self.mass * self.radius**2 * np.cross(G0, np.cross(W0, G0))
            sol = self.solve_reference(chaplygin_equations(self.inertia, self.mass, self.radius),
                                       np.concatenate([R0.ravel(), pos0, V0, M0]), t[-1], t_eval=t)
            Y = sol.y
            G, M = Y[17:20], Y[20:23]
            ma2 = self.mass * self.radius**2
            W = np.stack([np.linalg.solve(np.diag(self.inertia) + ma2 * (np.eye(3) - np.outer(g, g)), mm)
                          for g, mm in zip(G.T, M.T)], -1)
            v = np.cross(W.T, G.T).T  # Omega x Gamma
            u = self.radius * np.stack([np.sum(Y[11:14] * v, 0), np.sum(Y[14:17] * v, 0)])
            names = self.system.space.group.config_names + self.system.state_names
            vals = np.concatenate([Y[:20], self.inertia[:, None] * W, self.mass * u])
            return {n: vals[i] for i, n in enumerate(names)}

        return self._kept((variant.name, float(t[-1]), len(t)), solve)

    def figures(self, runs, *, tag=""):
        """The contact point's path on the plane (run and reference), then the generic errors and drifts."""
        out = []
        for r in self.as_runs(runs).values():
            out += [plotting.FigureSpec("chaplygin-ball-path", lambda f, r=r: path_figure(r, f, tag=tag), 11, 4.2),
                    plotting.FigureSpec("generic", lambda f, r=r: plotting.generic(r, f, title=self.title, tag=tag),
                                        11, 4.0)]
        return out


def path_figure(result, fig=None, *, tag=""):
    """The contact point's path ``(x(t), y(t))`` (the ball's centre is above it), run against reference."""
    fig = plotting.figure(fig, 11, 4.2)
    a0, a1 = fig.subplots(1, 2)
    x, y, xe, ye = plotting.plane_path(a0, result, "reference (Chaplygin's equations)",
                                       f"contact point on the plane{tag}")
    if x is not None and xe is not None:
        plotting.logplot(a1, result.t, np.hypot(x - xe, y - ye), lw=0.8)
    a1.set_xlabel("$t$")
    a1.set_ylabel("distance to the reference path")
    a1.grid(alpha=0.3)
    return fig


SCENE = ChaplyginBall()
