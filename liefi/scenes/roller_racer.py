r"""The roller racer (paper Sec. 3, subsection "The Roller Racer"): data only.

Configuration ``SE(2) x S^1``: the body's pose ``(theta, x, y)`` (angle chart,
Marsden--Ratiu 14.6) and the steering angle ``phi``.  Reduced by ``SE(2)`` the
state is ``z = (phi, Pi_theta, Pi_x, Pi_y, p_phi)`` on ``se(2)* x T*S^1``.

Data (nothing else is written here: ``h~``, ``lambda~_i``, the bracket terms
and ``grad V`` are derived by :mod:`liefi.reduction` and :mod:`liefi.integrator.feedback`):

* reduced mass tensor on ``(Pi_theta, Pi_x, Pi_y, p_phi)``

  .. math:: m = \begin{bmatrix} I_1 + I_2 & 0 & 0 & I_2 \\ 0 & m & 0 & 0 \\
            0 & 0 & m & 0 \\ I_2 & 0 & 0 & I_2 \end{bmatrix},

  whose inverse gives the paper's
  ``h = (Pi_x^2 + Pi_y^2)/2m + (Pi_theta - p_phi)^2/2I_1 + p_phi^2/2I_2``;
* the constraint vectors of the *reduced* constraint set, as printed:
  ``e_1 = (d_1 cos phi/I_1, -sin phi/m, 0, -d_1 cos phi/I_1 + d_2/I_2) / N(phi)``
  with ``N^2 = sin^2 phi/m + d_1^2 cos^2 phi/I_1 + d_2^2/I_2`` and
  ``e_2 = (0, 0, 1, 0)/sqrt(m)`` (orthonormal for ``m``).  The constraint set
  printed in the original coordinates misses ``-d_1 cos phi/I_1 p_phi``
  (docs/paper_notes.md item 6); the reduced form is the one used.  ``N^2 >= d_2^2/I_2 > 0``
  and ``e_2`` has no component where ``e_1`` lives but ``Pi_x``/``Pi_theta``,
  so the two stay independent for every ``phi``.

The paper gives no parameters or start; liefi uses ``m = 1, I_1 = 1,
I_2 = 1/2, d_1 = 1, d_2 = 1/2`` and the start ``theta = x = y = 0``,
``phi = pi/4``, ``Pi_theta = 1``, ``p_phi = 1/2`` with ``(Pi_x, Pi_y)`` solved
from the two (linear) constraints, so ``J = 0`` and ``h~_0 = h_0 > 0`` (the
theorem's assumption).  Euler, ``dt = 1e-3``, ``t`` in ``[0, 10]``, every gain
100 (``k_1, k_2`` on ``J_1, J_2``, ``k_3`` on the energy).  The reference is a
DOP853 integration (rtol 1e-12) of the constrained field.

Only the reduced state is integrated by default (the paper's stability theorem
concerns it; ``theta, x, y`` are a passive reconstruction).  Run with
``configuration=True`` to integrate the pose as well; its errors are then
reported too.

Variants: ``extended`` (``V`` penalizes ``h~``, as printed) and ``original``
(``V`` penalizes ``h``).
"""

import numpy as np

from ..groups import S1, SE2
from ..phase_space import TrivialPrincipalBundle
from ..systems.system import NonholonomicSystem
from .base import Scene, Variant


class RollerRacer(Scene):
    name = "roller-racer"
    title = "Roller racer on SE(2) x S^1"
    paper = "Sec. 3, The Roller Racer"
    reference = "numerical"
    dt = 1e-3
    t_final = 10.0
    gains = 100.0
    variants = {
        "extended": Variant("extended", "V penalizes the extended energy h~ (as printed)"),
        "original": Variant("original", "V penalizes the original energy h", energy="original"),
    }
    #: reduced variables always; the pose only when run with configuration=True
    error_variables = ("phi", "Pi_theta", "Pi_x", "Pi_y", "p_phi", "theta", "x", "y")

    m = 1.0
    I1 = 1.0
    I2 = 0.5
    d1 = 1.0
    d2 = 0.5
    #: the start: pose, steering angle, and the momenta chosen freely (the rest from J = 0)
    pose0 = (0.0, 0.0, 0.0)
    phi0 = np.pi / 4
    momenta0 = {"Pi_theta": 1.0, "p_phi": 0.5}

    def build_system(self, *, analytic_derivatives=False):
        """The system; ``analytic_derivatives=True`` gives the constraints their derivative in ``phi`` in closed
        form (``constraints_derivative=``), so that a complex step through a run is exact (the sensitivities of a
        forced run, :mod:`liefi.integrator._forced_sensitivity`); the default differentiates them by complex step."""
        m, I1, I2, d1, d2 = self.m, self.I1, self.I2, self.d1, self.d2
        metric = np.array(
            [[I1 + I2, 0.0, 0.0, I2], [0.0, m, 0.0, 0.0], [0.0, 0.0, m, 0.0], [I2, 0.0, 0.0, I2]]
        )

        def constraints(x):
            phi = x[..., 0]
            c, s = np.cos(phi), np.sin(phi)
            zero, one = np.zeros_like(phi), np.ones_like(phi)
            norm = np.sqrt(s**2 / m + d1**2 * c**2 / I1 + d2**2 / I2)
            e1 = np.stack([d1 * c / I1, -s / m, zero, -d1 * c / I1 + d2 / I2], -1) / norm[..., None]
            e2 = np.stack([zero, zero, one, zero], -1) / np.sqrt(m)
            return np.stack([e1, e2], -2)

        def constraints_derivative(x):
            # e_1 = a / N: d e_1 = a' / N - a N' / N^2, N N' = sin cos (1/m - d_1^2/I_1); e_2 constant
            phi = x[..., 0]
            c, s = np.cos(phi), np.sin(phi)
            zero = np.zeros_like(phi)
            norm = np.sqrt(s**2 / m + d1**2 * c**2 / I1 + d2**2 / I2)
            a = np.stack([d1 * c / I1, -s / m, zero, -d1 * c / I1 + d2 / I2], -1)
            da = np.stack([-d1 * s / I1, -c / m, zero, d1 * s / I1], -1)
            dnorm = s * c * (1 / m - d1**2 / I1) / norm
            de1 = da / norm[..., None] - a * (dnorm / norm**2)[..., None]
            return np.stack([de1, np.zeros_like(de1)], -2)[..., None, :, :]

        space = TrivialPrincipalBundle(SE2(S1()), 1, names=("phi",))
        if analytic_derivatives:
            return NonholonomicSystem(space, metric, constraints, sample=[self.phi0], orthonormalize=False,
                                      constraints_derivative=constraints_derivative)
        return NonholonomicSystem(space, metric, constraints, sample=[self.phi0])

    def needs_configuration(self):
        """Integrate the reduced state only unless ``configuration=True`` is asked for."""
        return False

    stability_cases = ("near-singular",)

    def stability_case(self, case):
        """``"near-singular"``: ``d1 cos(phi) + d2 = 0`` up to 1e-6, where ``e_1^flat`` loses its ``Pi_theta`` part."""
        if case != "near-singular":
            return super().stability_case(case)
        import copy
        import math

        scene = copy.copy(self)
        scene.__dict__ = {}
        scene.phi0 = math.acos(-self.d2 / self.d1) + 1e-6
        return scene, scene.variant(), False

    def initial_state(self, variant):
        z0 = self.system.complete_momenta([self.phi0], self.momenta0)
        return np.concatenate([np.asarray(self.pose0, float), z0])


SCENE = RollerRacer()
