"""Vertical rolling disk on SE(2) x S^1 (paper Sec. 3, "The Vertical Rolling Disk"): data only.

Group ``SE2(S1()) * S1("psi")``: configuration ``(theta, x, y, psi)`` (heading,
contact point, rolling angle), reduced momenta
``Pi = (Pi_theta, Pi_x, Pi_y, Pi_psi)`` on ``se(2)* x R``.

Data:

* locked inertia ``diag(J, m, m, I)``, so ``h = Pi_theta^2/(2J) +
  (Pi_x^2 + Pi_y^2)/(2m) + Pi_psi^2/(2I)``;
* constraint vectors ``e_1 = (0, 0, 1, 0)/sqrt(m)`` and
  ``e_2 = (0, I, 0, -m R)/sqrt(m I (I + m R^2))`` (orthonormal for the
  inertia), i.e. ``Pi_y = 0`` and ``I Pi_x - m R Pi_psi = 0``.

``h~``, ``lambda~_i``, the extended field ``(extended:eqn:vertical:disk)``
with the reconstruction of the group element and ``grad V`` are derived by
:mod:`liefi.reduction` and :class:`liefi.FeedbackIntegrator`.

Variants
--------
``further`` (the paper's ``(FI:vertical:disk)``)
    The paper modifies ``(extended:eqn:vertical:disk)`` off the constraint set
    "by substituting ``Pi_y = 0`` and ``I Pi_x - m R Pi_psi = 0``", which gives
    ``(further:extended:eqn:vertical:disk)``: ``Pi' = 0`` and
    ``q' = (Pi_theta/J, Pi_x cos(theta)/m, Pi_x sin(theta)/m, Pi_psi/I)``.
    liefi integrates instead its *projected* field (``Variant(field=
    "projected")``, :func:`liefi.reduction.projected_vector_field`): the
    extended field evaluated at the projection of ``Pi`` onto the constraint
    set along the inertia.  Since every momentum of the disk is constant on
    the constraint set, this field has ``Pi' = 0`` everywhere too, so all four
    momenta are first integrals, and ``V`` is the paper's
    ``sum_i k_i/2 (Pi_i - Pi_i0)^2`` over the four momentum components.  The
    ``q'`` of the two fields agree on the constraint set but differ off it:
    liefi's is ``q' = g . dh~/dPi`` at the projected momentum, e.g.
    ``x' = R (R Pi_x + Pi_psi)/(I + m R^2) cos(theta)`` and
    ``psi' = (R Pi_x + Pi_psi)/(I + m R^2)`` (the projection leaves ``h~`` and
    ``dh~/dPi`` unchanged), whereas the paper's substitution uses the raw
    ``Pi_x/m`` and ``Pi_psi/I``.  The substitution is one of many ways to
    write the field on ``C_red`` (``Pi_x/m = R Pi_psi/I`` there) and the
    choice is made by hand; liefi's projection is defined for any system
    from its data (metric and constraints) and is derived, not substituted.
``extended``
    The extended field ``(extended:eqn:vertical:disk)`` with ``V`` over the
    constraints ``J_1, J_2`` and the extended energy ``h~``.

Initial condition (docs/paper_notes.md item 7): the paper states it as
``I Pi_x0 - R Pi_psi0 = 0``; the factor ``m`` is missing, the constraint is
``I Pi_x0 - m R Pi_psi0 = 0``.

Simulation settings.  The paper gives none; liefi chooses ``J = 1``,
``m = 1``, ``I = 0.5``, ``R = 1``; start ``theta = x = y = psi = 0`` with
``Pi = (1, 1, 0, 0.5)`` (turning at ``theta' = 1`` while rolling at
``x' = 1``: a unit circle); explicit Euler, ``dt = 1e-3``, ``t`` in
``[0, 10]``, every gain 100.  Reference: the closed form
:func:`liefi.scenes.exact.vertical_disk` for every configuration number and
momentum.
"""

import numpy as np

from ..groups import SE2, S1
from ..phase_space import LieGroupPhaseSpace
from ..systems.system import NonholonomicSystem
from . import exact as _exact
from .base import Scene, Variant

class VerticalDisk(Scene):
    name = "vertical-disk"
    title = "Vertical rolling disk on SE(2) x S^1"
    paper = "Sec. 3, The Vertical Rolling Disk"
    reference = "exact"
    dt = 1e-3
    t_final = 10.0
    gains = 100.0
    variants = {
        "further": Variant(
            "further",
            "the paper's further extension (FI:vertical:disk): liefi's projected field, "
            "V penalizes the four momenta",
            field="projected",
        ),
        "extended": Variant(
            "extended", "the extended field (extended:eqn:vertical:disk), V penalizes J_1, J_2 and h~"
        ),
    }
    error_variables = ("theta", "x", "y", "psi", "Pi_theta", "Pi_x", "Pi_y", "Pi_psi")

    # --- parameters and start (liefi's choice; the paper gives none) ------------------
    J = 1.0
    m = 1.0
    I = 0.5
    R = 1.0
    q0 = np.array([0.0, 0.0, 0.0, 0.0])  # (theta, x, y, psi)
    Pi_theta0 = 1.0
    Pi_psi0 = 0.5

    # --- data ------------------------------------------------------------------------------
    def build_system(self):
        J, m, I, R = self.J, self.m, self.I, self.R
        space = LieGroupPhaseSpace(SE2(S1()) * S1("psi"))
        inertia = np.diag([J, m, m, I])
        e = np.array([
            [0.0, 0.0, 1.0, 0.0] / np.sqrt(m),
            [0.0, I, 0.0, -m * R] / np.sqrt(m * I * (I + m * R * R)),
        ])
        return NonholonomicSystem(space, inertia, e)

    def Pi0(self):
        """``(Pi_theta0, m R Pi_psi0 / I, 0, Pi_psi0)``: on the constraint set."""
        return np.array([self.Pi_theta0, self.m * self.R * self.Pi_psi0 / self.I, 0.0, self.Pi_psi0])

    def initial_state(self, variant):
        return np.concatenate([self.q0, self.Pi0()])

    def invariants(self, variant):
        if variant.name == "further":
            return self.system.space.momentum_names  # the four momenta, as in the paper's V
        return ("constraints", "energy")

    def exact(self, t, variant):
        return _exact.vertical_disk(t, self.m, self.I, self.J, self.R, self.q0, self.Pi0())


SCENE = VerticalDisk()
