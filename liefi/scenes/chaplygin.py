"""Chaplygin sleigh on SE(2) (paper Sec. 3, "The Chaplygin Sleigh"): data only.

Two scenes share the same data and differ only in how the rotation factor of
SE(2) is stored:

* ``chaplygin`` -- ``SE2(S1())``: the heading as the angle ``theta``,
  configuration ``(theta, x, y)`` (equations ``(FI:Chap)``);
* ``chaplygin-so2`` -- ``SE2(SO2())``: the rotation as a 2x2 matrix ``R``
  with the orthogonality penalty, configuration ``(R11, R12, R21, R22, x, y)``
  (equations ``(FI:extended:SE2:SO2)``).

Data (reduced to ``se(2)* = R^3``, ``Pi = (Pi_theta, Pi_x, Pi_y)``):

* locked inertia ``[[I + m a^2, 0, m a], [0, m, 0], [m a, 0, m]]``, so that
  ``h = (Pi_theta - a Pi_y)^2/(2I) + (Pi_x^2 + Pi_y^2)/(2m)``;
* one constraint vector ``e = (m a, 0, -(I + m a^2)) / sqrt(m I (I + m a^2))``;
  ``<e, inertia e> = 1`` (unit for the locked inertia, so ``e^flat =
  -(m I / sqrt(m I (I + m a^2))) (0, 0, 1)`` as in ``(e:flat:Chap)``) and
  ``J = <Pi, e> = 0`` is ``m a Pi_theta - (I + m a^2) Pi_y = 0``, the paper's
  ``C_red``.  Both facts are checked in ``tests/test_scenes_a.py``.

``h~`` ``(h:tilde:Chap)``, ``lambda~`` ``(lambda:Chap)``, the extended field
``(extended:system:Chap)`` with the reconstruction of the group element, and
``grad V`` are derived by :mod:`liefi.reduction` and
:class:`liefi.FeedbackIntegrator`.  ``V`` penalizes ``J`` and the energy;
variants ``extended`` (``h~``, as in the paper) and ``original`` (``h``).

Embedding penalty (``chaplygin-so2``; docs/paper_notes.md item 4).  The paper writes
``V = k0/2 ||R^T R - I||^2 + ...`` and prints ``grad_R V = -k0 R (R^T R - I)``:
the sign is wrong (and, for that ``V``, the factor: the gradient is
``+2 k0 R (R^T R - I)``); with the printed sign ``-grad_R V`` pushes ``R``
*away* from SO(2) and the run diverges by ``t ~ 0.07``.  liefi does not take a
gradient from the paper: the group supplies the penalty
``k0/4 ||R^T R - I||_F^2`` (:meth:`liefi.groups.SO2.penalty`) together with its
gradient ``k0 R (R^T R - I)``, and :class:`~liefi.FeedbackIntegrator` adds
``-k0 R (R^T R - I)`` to ``R'``.  This is correct by construction: it is
the gradient of the function actually penalized (checked against its
complex-step derivative in ``tests/test_group_axioms.py``; the printed sign
is shown to diverge in ``tests/test_scenes_a.py``).  It has the printed
magnitude with the opposite, contracting sign.  The gain is the
integrator's ``"penalty"`` gain (``k0``).

Simulation settings.  The paper gives none for the sleigh, so liefi chooses
``m = 1``, ``I = 1``, ``a = 0.5`` (``I + m a^2 = 1.25``); start at the
identity (``theta = x = y = 0``, ``R = I``) with angular velocity
``omega0 = 1`` and forward speed ``v0 = 0.5`` on the constraint set:
``Pi = ((I + m a^2) omega0, m v0, m a omega0) = (1.25, 0.5, 0.5)``; explicit
Euler, ``dt = 1e-3``, ``t`` in ``[0, 10]`` (the speed ``v = c tanh(k t + tau0)``
with ``k ~ 0.49`` has settled by then), every gain 100.

Reference: :func:`liefi.scenes.exact.chaplygin` gives ``theta`` and the
momenta; ``x, y`` have no closed form and are not compared.  For
``chaplygin-so2`` the heading is the observable
``theta = unwrap(atan2(R21, R11))``.
"""

import numpy as np

from ..groups import SE2, SO2, S1
from ..groups.so2 import rotation2
from ..phase_space import LieGroupPhaseSpace
from ..systems.system import NonholonomicSystem
from . import exact as _exact
from .base import Scene, Variant


class Chaplygin(Scene):
    """Chaplygin sleigh with the heading as an angle (``SE2(S1())``)."""

    name = "chaplygin"
    title = "Chaplygin sleigh on SE(2), heading as an angle"
    paper = "Sec. 3, The Chaplygin Sleigh, (FI:Chap)"
    reference = "exact"
    dt = 1e-3
    t_final = 10.0
    gains = 100.0
    variants = {
        "extended": Variant("extended", "V penalizes J and the extended energy h~ (FI:Chap)"),
        "original": Variant("original", "V penalizes J and the original energy h", energy="original"),
    }
    error_variables = ("theta", "Pi_theta", "Pi_x", "Pi_y")

    # --- parameters and start (liefi's choice; the paper gives none) -----------------
    m = 1.0
    I = 1.0
    a = 0.5
    theta0 = 0.0
    position0 = np.array([0.0, 0.0])
    omega0 = 1.0  # initial angular velocity theta'
    v0 = 0.5  # initial forward speed of the contact point

    def rotation(self):
        """The embedding of the rotation factor."""
        return S1()

    # --- data ------------------------------------------------------------------------
    def locked_inertia(self):
        m, I, a = self.m, self.I, self.a
        return np.array([[I + m * a * a, 0.0, m * a], [0.0, m, 0.0], [m * a, 0.0, m]])

    def constraint(self):
        m, I, a = self.m, self.I, self.a
        M = I + m * a * a
        return np.array([m * a, 0.0, -M]) / np.sqrt(m * I * M)

    def build_system(self):
        space = LieGroupPhaseSpace(SE2(self.rotation()))
        return NonholonomicSystem(space, self.locked_inertia(), self.constraint())

    def Pi0(self):
        """The initial momentum ``(M omega0, m v0, m a omega0)``, on the constraint set."""
        m, I, a = self.m, self.I, self.a
        return np.array([(I + m * a * a) * self.omega0, m * self.v0, m * a * self.omega0])

    def group0(self):
        """The initial group element ``(theta, x, y)`` in the angle chart."""
        return np.r_[self.theta0, self.position0]

    def initial_state(self, variant):
        return np.concatenate([self.group0(), self.Pi0()])

    def exact(self, t, variant):
        return _exact.chaplygin(t, self.m, self.I, self.a, self.theta0, self.Pi0())


class ChaplyginSO2(Chaplygin):
    """Chaplygin sleigh with the rotation as a 2x2 matrix (``SE2(SO2())``) and the penalty."""

    name = "chaplygin-so2"
    title = "Chaplygin sleigh on SE(2), rotation embedded as a 2x2 matrix"
    paper = "Sec. 3, The Chaplygin Sleigh, (FI:extended:SE2:SO2)"
    variants = {
        "extended": Variant(
            "extended", "V penalizes R^T R - I (gain k0 = 'penalty'), J and h~ (FI:extended:SE2:SO2)"
        ),
        "original": Variant(
            "original", "V penalizes R^T R - I (gain k0 = 'penalty'), J and the original energy h",
            energy="original",
        ),
    }

    def rotation(self):
        return SO2()

    def group0(self):
        """The initial group element ``(R11, R12, R21, R22, x, y)``."""
        return np.r_[rotation2(self.theta0).ravel(), self.position0]

    def needs_configuration(self):
        # the heading is read from R (an observable), so R must be integrated
        return True

    def observables(self, y, names):
        """``theta = unwrap(atan2(R21, R11))``, continued from ``theta0``."""
        R11, R21 = y[names.index("R11")], y[names.index("R21")]
        th = np.unwrap(np.arctan2(R21, R11), axis=-1)
        th = th + 2 * np.pi * np.round((self.theta0 - th[..., :1]) / (2 * np.pi))
        return {"theta": th}


SCENES = {s.name: s for s in (Chaplygin(), ChaplyginSO2())}
