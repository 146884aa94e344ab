r"""The knife edge on an inclined plane with gauge-shifted momenta (not reversible): data only.

Modin & Verdier's recipe (*What makes nonholonomic integrators work?*, Numer.
Math. 145 (2020) 405--435; see :mod:`liefi.scenes.nonreversible`) applied to the
paper's knife edge (``knife-edge`` scene, Bloch Sec. 1.6): the momenta are
shifted by the gradient of ``S(q) = cos(x + y)``,

.. math:: H = \tfrac{1}{2m}\big((p_x + \partial_x S)^2 + (p_y + \partial_y S)^2\big)
          + \tfrac{1}{2J}(p_\varphi + \partial_\varphi S)^2 - m g x \sin\alpha,

i.e. liefi's vector potential ``A = -grad S = (sin(x + y), sin(x + y), 0)``, with
the constraint on the velocity (``J_1 = <P - A, e> = 0``, ``e`` the knife
edge's).  The motion ``q(t)`` is the knife edge's; the momenta are
``P = m v + A(q)``.  The shift makes the problem non-reversible for
``(q, p) -> (q, -p)`` (it is reversible for ``(q, p) -> (q, -p + 2A(q))``) and
keeps it integrable.  ``S`` is liefi's choice (Modin & Verdier's recipe does
not fix it): it shifts both momenta of the contact point, so the constraint
``J_1 = ((p_x - A_x) sin phi - (p_y - A_y) cos phi)/sqrt(m)`` and the energy
couple position and momenta in a way ``(q, p) -> (q, -p)`` does not respect,
while ``A_phi = 0`` leaves the spin ``p_phi = J phi'`` a momentum component.
As on the knife edge, ``p_phi`` is a first integral of the extended field only
on the constraint set (its rate off it is ``O(J_1)``): the stability guard's
check of that (:func:`liefi.integrator.stability.first_integral_defect`) evaluates it there.

First integrals: the energy ``h`` (and ``h~``), ``J_1`` and ``p_phi``.

Start: the paper's, in velocities (``q = 0``, ``v = 0``, ``phi' = 1/2``), so
``P(0) = (0, 0, 1/2)`` (``A(0) = 0``; the shift acts once the edge moves).
Settings (liefi's choice): RK4, ``dt = 1e-2``, ``t`` in ``[0, 200]``, every
gain 1.  Reference: the knife edge's closed form
(:func:`liefi.scenes.exact.knife_edge`) with the momenta shifted by ``A(q(t))``.
"""

import numpy as np

from ..phase_space import CotangentBundle
from ..systems.system import NonholonomicSystem
from .base import Variant
from .knife_edge import KnifeEdge


def _vector_potential(q):
    """``A(q) = -grad cos(x + y) = (sin(x + y), sin(x + y), 0)`` (batch-first, complex-step safe)."""
    s = np.sin(q[..., 0] + q[..., 1])
    return np.stack([s, s, np.zeros_like(s)], -1)


class NonreversibleKnifeEdge(KnifeEdge):
    name = "nonreversible-knife-edge"
    in_paper = False  # a study beyond the paper: liefi reproduce runs it with --all or --only
    stiff_study = False  # the stability report's stiff study is the paper's knife edge
    title = "Knife edge on an inclined plane with gauge-shifted momenta (not reversible)"
    paper = "Modin & Verdier 2020 recipe on the paper's Sec. 3 knife edge, p -> p - grad cos(x + y)"
    reference = "exact"
    scheme = "rk4"
    dt = 1e-2
    t_final = 200.0
    gains = 1.0
    variants = {
        "extended": Variant("extended", "V penalizes J_1, p_phi and the extended energy h~"),
        "original": Variant("original", "V penalizes J_1, p_phi and the original energy h", energy="original"),
    }
    error_variables = ("x", "y", "phi", "p_x", "p_y", "p_phi")

    vector_potential = staticmethod(_vector_potential)

    def build_system(self):
        space = CotangentBundle(3, names=("x", "y", "phi"))
        metric = np.diag([self.m, self.m, self.J])
        return NonholonomicSystem(space, metric, self.constraint, self.potential,
                                  vector_potential=_vector_potential)

    def initial_state(self, variant):
        z = super().initial_state(variant)  # the knife edge's (q, m v): velocities
        z[3:] += _vector_potential(z[:3])
        return z

    def exact(self, t, variant):
        ref = dict(super().exact(t, variant))
        A = _vector_potential(np.stack([ref["x"], ref["y"], ref["phi"]], -1))
        for i, k in enumerate(("p_x", "p_y", "p_phi")):
            ref[k] = ref[k] + A[..., i]
        return ref


SCENE = NonreversibleKnifeEdge()
