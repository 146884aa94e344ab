r"""The Heisenberg system (paper Sec. 3, subsection "The Heisenberg System"): data only.

``T*R^3`` with ``q = (x, y, z)``, ``p = (p_x, p_y, p_z)`` (the paper writes
``q = (x, z, y)``, a typo: NOTES item 7), metric ``I``, no potential, and the
constraint ``p . e = p_z - y p_x + x p_y = 0`` with the **non-normalized**
``e = (-y, x, 1)``.  The paper computes the multiplier with the general formula
``(lambda:general)``; liefi does the same natively (Gram matrix
``C = |e|^2 = 1 + x^2 + y^2``), so nothing is normalized here.  The
constrained motion is a straight line, ``q = q_0 + p_0 t``
(:func:`liefi.scenes.exact.heisenberg`).

``V`` penalizes, as in the paper,

.. math:: V = \frac{k_1}{2} J_1^2 + \frac{k_2}{2} (J_2 - J_{20})^2
          + \frac{k_3}{2} (H - H_0)^2,

with ``J_1 = p . e`` (``"J_1"``), the *original* energy ``H = |p|^2/2``
(``energy="original"``) and the angular momentum ``J_2 = x p_y - y p_x``, a
:class:`~liefi.Invariant` called ``"L_z"`` (not ``"J_2"``: liefi reserves
``J_i`` for constraint momenta, whose target is 0).

Notes
-----
* The paper integrates ``q' = p, p' = 0`` (its "extended" system is the
  original one, since ``lambda = 0`` everywhere).  liefi integrates its
  derived extended field, which agrees with it on ``J_1 = 0``.  Off the
  constraint set ``J_1`` and ``L_z`` are still first integrals of it, but
  ``H = h~ + J_1^2 / (2 |e|^2)`` is not (``|e|`` varies with ``q``; the
  Corollary ``(H:intermsof:Htilde:pe)`` needs ``C`` constant); the defect is
  ``O(J_1^2)`` and invisible in the runs.
* Euler maps a point of ``V^{-1}(0)`` exactly onto the next point of the
  straight line (``J_1``, ``L_z`` and ``H`` are conserved exactly by the
  Euler step of ``q' = p, p' = 0``), so any error comes from rounding
  amplified by the feedback term.  The zero set of ``V`` is not compact and the
  Hessian of ``V`` grows like ``k |q|^2``: explicit Euler becomes unstable once
  ``dt * k * (1 + 2|q|^2)`` exceeds about 2.

Variants (``Variant.options`` holds the start):

* ``special``: ``q_0 = (1, 0, 0)``, ``p_0 = (0, 1, -1)``.  Every product in
  ``J_1``, ``L_z`` and their gradients along this line is exact in floating
  point, so ``V`` stays exactly 0 and no rounding error seeds the instability:
  the run is exact (to the rounding of ``y += dt p_y``) at any gain.
* ``generic``: ``q_0 = (1, 1/2, 0)``, ``p_0 = (0.3, 0.4, -0.25)`` (``x, y,
  p_x, p_y`` all nonzero; ``p_z`` from the constraint).  With the default
  gains 10 and ``t_final = 10`` the run is bounded (``|q| < 6``, stiffness
  ``dt k (1 + 2|q|^2) < 1``); with gains 100 and ``t_final = 20`` Euler loses
  stability around ``t ~ 10`` and the run stops with
  :class:`liefi.IntegrationError` (NOTES: "diverges after t ~ 5" for a start
  with ``|p| ~ 1``).  Adaptive gains are the stability work's business.

The paper leaves the simulation to the reader: liefi uses Euler,
``dt = 1e-3``, every gain 10, ``t`` in ``[0, 10]``.
"""

import numpy as np

from ..feedback import Invariant
from ..phase_space import CotangentBundle
from ..system import NonholonomicSystem
from . import exact as _exact
from .base import Scene, Variant


def _angular_momentum(z):
    """``J_2 = x p_y - y p_x`` (complex-step safe)."""
    return z[..., 0] * z[..., 4] - z[..., 1] * z[..., 3]


#: The paper's ``J_2``, the z-component of the angular momentum.
L_Z = Invariant("L_z", _angular_momentum)


class Heisenberg(Scene):
    name = "heisenberg"
    title = "Heisenberg system on T*R^3"
    paper = "Sec. 3, The Heisenberg System"
    reference = "exact"
    dt = 1e-3
    t_final = 10.0
    gains = 10.0
    variants = {
        "special": Variant(
            "special",
            "start q=(1,0,0), p=(0,1,-1): V stays exactly 0, Euler is exact",
            energy="original",
            options={"q0": (1.0, 0.0, 0.0), "p0": (0.0, 1.0, -1.0)},
        ),
        "generic": Variant(
            "generic",
            "start q=(1,1/2,0), p=(0.3,0.4,-0.25): bounded at gains 10 on [0,10]",
            energy="original",
            options={"q0": (1.0, 0.5, 0.0), "p0": (0.3, 0.4, -0.25)},
        ),
    }
    error_variables = ("x", "y", "z", "p_x", "p_y", "p_z")

    def build_system(self):
        def constraint(q):
            x, y = q[..., 0], q[..., 1]
            return np.stack([-y, x, np.ones_like(x)], -1)[..., None, :]

        space = CotangentBundle(3, names=("x", "y", "z"))
        return NonholonomicSystem(space, np.eye(3), constraint)

    def initial_state(self, variant):
        o = variant.options
        return np.concatenate([np.asarray(o["q0"], float), np.asarray(o["p0"], float)])

    def invariants(self, variant):
        return ("constraints", "energy", L_Z)

    def exact(self, t, variant):
        return _exact.heisenberg(t, variant.options["q0"], variant.options["p0"])


SCENE = Heisenberg()
