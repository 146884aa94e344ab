r"""The Heisenberg system (paper Sec. 3, subsection "The Heisenberg System"): data only.

``T*R^3`` with ``q = (x, y, z)``, ``p = (p_x, p_y, p_z)`` (the paper writes
``q = (x, z, y)``, a typo: docs/paper_notes.md item 7), metric ``I``, no potential, and the
constraint ``p . e = p_z - y p_x + x p_y = 0`` with the **non-normalized**
``e = (-y, x, 1)``.  The paper computes the multiplier with the general formula
``(lambda:general)``; liefi does the same natively (Gram matrix
``C = |e|^2 = 1 + x^2 + y^2``), so nothing is normalized here.  The
constrained motion is a straight line, ``q = q_0 + p_0 t``
(:func:`liefi.scenes.exact.heisenberg`).

``V`` penalizes

.. math:: V = \frac{k_1}{2} J_1^2 + \frac{k_2}{2} (J_2 - J_{20})^2
          + \frac{k_3}{2} (\tilde H - \tilde H_0)^2,

with ``J_1 = p . e`` (``"J_1"``), the angular momentum ``J_2 = x p_y - y p_x``,
a :class:`~liefi.Invariant` called ``"L_z"`` (not ``"J_2"``: liefi reserves
``J_i`` for constraint momenta, whose target is 0), and the *extended* energy
``H~ = |p|^2/2 - J_1^2 / (2 |e|^2)`` where the paper writes ``H``.

Why ``H~`` and not the paper's ``H``: the paper integrates ``q' = p, p' = 0``
(its "extended" system is the original one, since ``lambda = 0``
everywhere), of which ``H`` is a first integral everywhere.  liefi integrates
its derived extended field (the general form of Remark
``(remark:nonhol:general)``: ``e`` is not normalized), which agrees with it on
``J_1 = 0`` and keeps ``H~``, ``J_1`` and ``J_2`` everywhere -- but not
``H = H~ + J_1^2 / (2 |e|^2)``, because the Gram matrix ``|e|^2 = 1 + x^2 + y^2``
varies with ``q`` (the paper's Remark claims the Corollary
``(H:intermsof:Htilde:pe)`` carries over; it does only for constant ``C``).
With ``H`` the assumption A1 would fail off the constraint set, and
:class:`~liefi.FeedbackIntegrator` refuses ``energy="original"`` here.  ``H~``
equals ``H`` on the constraint set and so do their gradients, so ``V`` has
the same zero set and the same Hessian there (the same stiffness) as the
paper's.  The alternative -- ``orthonormalize=True``, which replaces ``e`` by
``e/|e|`` so that ``H`` is conserved -- would change ``J_1`` to
``p . e/|e|`` and with it the paper's ``V``.

Notes
-----
* Euler maps a point of ``V^{-1}(0)`` exactly onto the next point of the
  straight line (``J_1``, ``L_z`` and ``H`` are conserved exactly by the
  Euler step of ``q' = p, p' = 0``), so any error comes from rounding
  amplified by the feedback term.  The zero set of ``V`` is not compact and the
  Hessian of ``V`` grows like ``k (x^2 + y^2)`` (``|grad J_1|^2 = 1 + x^2 + y^2
  + p_x^2 + p_y^2``, ``|grad J_2|^2 = x^2 + y^2 + p_x^2 + p_y^2``): explicit
  Euler becomes unstable once ``dt k (1 + 2(x^2 + y^2))`` exceeds about 2.

Variants (``Variant.options`` holds the start):

* ``special``: ``q_0 = (1, 0, 0)``, ``p_0 = (0, 1/2, -1/2)``.  Along this
  line ``x = 1`` and ``p_x = 0`` stay exact, so every product in ``J_1``,
  ``L_z``, ``H`` and their gradients is exact in floating point: ``V`` stays
  exactly 0, no rounding error seeds the instability, and the run is exact
  (to the rounding of ``y += dt p_y``) at any gain -- even past Euler's
  stability bound (run with ``check_stability=False`` there).
* ``generic``: ``q_0 = (1, 1/2, 0)``, ``p_0 = (0.3, 0.4, -0.25)`` (``x, y,
  p_x, p_y`` all nonzero; ``p_z`` from the constraint).  With the default
  gains 10 and ``t_final = 10`` the run is bounded and exact to ~1e-12
  (``dt k (1 + 2(x^2 + y^2)) < 1`` all along).  With gains 100 Euler crosses
  its stability bound at ``t ~ 4.3`` (``x^2 + y^2 ~ 10``) and leaves the
  straight line (visibly so after ``t ~ 5``).  It does not overflow: each
  burst of the unstable mode throws the state back inside the stable region,
  so an unguarded run (``check_stability=False``) returns a *finite, wrong*
  trajectory.  liefi's stability guard (:mod:`liefi.integrator.stability`) therefore
  refuses ``t_final = 20`` up front (``ValueError``) and stops
  ``t_final = 10`` at ``t ~ 4.6`` with a :class:`liefi.IntegrationError`
  (``StabilityError``) naming the time and the invariant.  Adaptive gains are
  the stability work's business.

The paper leaves the simulation to the reader: liefi uses Euler,
``dt = 1e-3``, every gain 10, ``t`` in ``[0, 10]``.
"""

import numpy as np

from ..integrator.feedback import Invariant
from ..phase_space import CotangentBundle
from ..systems.system import NonholonomicSystem
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
            "start q=(1,0,0), p=(0,1/2,-1/2): V stays exactly 0, Euler is exact",
            options={"q0": (1.0, 0.0, 0.0), "p0": (0.0, 0.5, -0.5)},
        ),
        "generic": Variant(
            "generic",
            "start q=(1,1/2,0), p=(0.3,0.4,-0.25): bounded at gains 10 on [0,10]",
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

    stability_variant = "generic"
    stability_cases = ("far from origin",)

    def stability_case(self, case):
        """``"far from origin"``: ``q0 = (1e3, 5e2, 0)`` on the constraint set, where ``|grad J|^2 ~ |q|^2`` is large."""
        if case != "far from origin":
            return super().stability_case(case)
        q0 = np.array([1e3, 5e2, 0.0])
        p0 = np.array([0.3, 0.4, 0.0])
        p0[2] = q0[1] * p0[0] - q0[0] * p0[1]  # on the constraint set p_z = y p_x - x p_y
        g = self.variant("generic")
        v = Variant("far", "q0 = (1e3, 5e2, 0)", energy=g.energy, field=g.field,
                    options={**g.options, "q0": tuple(q0), "p0": tuple(p0)})
        return self, v, True

    def initial_state(self, variant):
        o = variant.options
        return np.concatenate([np.asarray(o["q0"], float), np.asarray(o["p0"], float)])

    def invariants(self, variant):
        return ("constraints", "energy", L_Z)

    def exact(self, t, variant):
        return _exact.heisenberg(t, variant.options["q0"], variant.options["p0"])


SCENE = Heisenberg()
