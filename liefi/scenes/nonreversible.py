r"""Non-reversible contact oscillators (Modin & Verdier's test problems): data only.

Why these problems.  Modin & Verdier (*What makes nonholonomic integrators
work?*, Numer. Math. 145 (2020) 405--435, arXiv:1707.04514) showed that the
standard nonholonomic test problems -- the paper's nonholonomic oscillator
among them -- are reversible integrable: the map ``(q, p) -> (q, -p)``
reverses their flow and they are integrable, so a reversible integrator keeps
their first integrals near their initial values for exponentially long times
by reversible KAM theory, whatever discrete Lagrange--d'Alembert principle it
has or lacks.  To separate integrators they perturb the test problems into
problems that are still integrable but *not* reversible for the standard map.
No choice of metric, potential or linear constraints can do that: with
``H`` even in ``p`` and linear constraints, ``(q, p) -> (q, -p)`` reverses
every such system.  Their recipe is a gauge shift of the momenta (Verdier's
``NonReversibleContactOscillator`` in the public ``odelab`` package):

.. math:: H(q, p) = \tfrac12 |p + \nabla S(q)|^2 + U(q),

the same motion ``q(t)`` as with ``S = 0`` (``dS/dt`` is a null Lagrangian), in
momenta ``p = v - \nabla S(q)`` shifted by a function of ``q``: a symplectic
change of coordinates that does not commute with ``p -> -p``.  The problem is
integrable (conjugate to an integrable one) and reversible only for the
non-standard map ``(q, p) -> (q, -p - 2\nabla S(q))``.  An integrator that is not
covariant under the shift (none of the published ones, nor Euler or RK4) sees a
different problem.

liefi writes the shift as its vector potential: ``H = 1/2 <P - A, m^{-1}(P - A)>
+ U`` with ``A(q) = -\nabla S(q)``, and the constraint on the velocity
``m^{-1}(P - A)``.  Everything else -- ``h~``, ``lambda~``, the fields, ``V`` -- is
derived from the data.

Data (both scenes), on ``T*R^3`` with ``q = (x, y, z)``:

* metric ``I``;
* the contact constraint ``v_x + y v_z = 0``: ``e = (1, 0, y)/sqrt(1 + y^2)``
  (unit, as in the ``oscillator`` scene);
* ``U = |q|^2/2 + eps x^2 z^2/2`` (McLachlan & Perlmutter, *Integrators for
  nonholonomic mechanical systems*, J. Nonlinear Sci. 16 (2006) 283--328,
  Sec. 5.2: ``eps = 0`` is the contact oscillator, the paper's nonholonomic
  oscillator; ``eps > 0`` its nonlinear perturbation);
* ``S(q) = cos z`` (odelab's choice), so ``A = (0, 0, sin z)``.

First integrals: the energy ``h`` (and ``h~``), the constraint momentum ``J``
and ``H_y = (y^2 + v_y^2)/2`` (``A_y = 0`` and ``e_y = 0``, so ``y'' = -y``
is untouched by the shift and the constraint; ``v_y = p_y``).  ``h - H_y`` is
McLachlan & Perlmutter's third integral on the constraint set, not independent.

Scenes
------
``nonreversible-oscillator``
    ``eps = 0``, the paper's start in velocities: ``q(0) = (1, 1, 1)``,
    ``v(0) = 0``, i.e. ``p(0) = A(q(0)) = (0, 0, sin 1)``.  Its motion ``q(t)``
    is *exactly* that of the ``oscillator`` scene (``tests/test_nonreversible.py``
    checks it), so the two scenes are the reversible and the non-reversible
    form of one problem.
``nonreversible-contact-oscillator``
    ``eps = 0.3`` (odelab's test value), odelab's ``initial_sin`` start with
    ``z0 = 0.1 sqrt 2``, energy ``1.5`` and ``H_y = 0.5``: ``q(0) = (x0, 0, z0)``,
    ``v(0) = (0, 1, 0)``, ``x0 = sqrt((2 - z0^2)/(1 + eps z0^2))``.  (odelab
    pairs the gauge shift with ``eps = 0``; the nonlinear shifted problem is our
    combination of its two classes.)

Settings (liefi's choice, neither source gives FI settings): RK4, ``dt = 1e-2``,
``t`` in ``[0, 200]``, every gain 1 (small gains keep the invariants at ~1e-10
with RK4, where the paper's ``O(1/dt)`` gains cost accuracy).  Reference:
DOP853 (rtol 1e-12) on the constrained field, with ``y, p_y`` replaced by the
closed form (:func:`liefi.scenes.exact.oscillator_y`).  ``V`` penalizes ``J``,
the energy and ``H_y``; variants ``extended`` (``h~``) and ``original`` (``h``).
"""

import numpy as np

from ..phase_space import CotangentBundle
from ..systems.system import NonholonomicSystem
from . import exact as _exact
from .base import Scene, Variant
from .oscillator import H_Y


class GaugeShiftedContactOscillator(Scene):
    in_paper = False  # a study beyond the paper: liefi reproduce runs it with --all or --only
    """The contact oscillator ``U = |q|^2/2 + eps x^2 z^2/2`` with momenta shifted by ``grad cos z``."""

    reference = "numerical"
    scheme = "rk4"
    dt = 1e-2
    t_final = 200.0
    gains = 1.0
    variants = {
        "extended": Variant("extended", "V penalizes J, H_y and the extended energy h~"),
        "original": Variant("original", "V penalizes J, H_y and the original energy h", energy="original"),
    }
    error_variables = ("x", "y", "z", "p_x", "p_y", "p_z")

    eps = 0.0
    q0 = (1.0, 1.0, 1.0)
    v0 = (0.0, 0.0, 0.0)

    # --- data --------------------------------------------------------------------
    @staticmethod
    def constraint(q):
        """``e(q) = (1, 0, y)/sqrt(1 + y^2)``, one row: ``v_x + y v_z = 0``."""
        y = q[..., 1]
        s = np.sqrt(1.0 + y**2)
        return np.stack([1.0 / s, np.zeros_like(y), y / s], -1)[..., None, :]

    def potential(self, q):
        """``U = |q|^2/2 + eps x^2 z^2/2``."""
        return 0.5 * np.sum(q**2, -1) + 0.5 * self.eps * q[..., 0] ** 2 * q[..., 2] ** 2

    @staticmethod
    def gauge(q):
        """``S(q) = cos z``: the momenta are ``p = v - grad S``."""
        return np.cos(q[..., 2])

    @staticmethod
    def vector_potential(q):
        """``A(q) = -grad S(q) = (0, 0, sin z)``."""
        z = q[..., 2]
        zero = np.zeros_like(z)
        return np.stack([zero, zero, np.sin(z)], -1)

    def build_system(self):
        space = CotangentBundle(3, names=("x", "y", "z"))
        return NonholonomicSystem(space, np.eye(3), self.constraint, self.potential,
                                  vector_potential=self.vector_potential)

    def initial_state(self, variant):
        q0 = np.asarray(self.q0, float)
        return np.concatenate([q0, np.asarray(self.v0, float) + self.vector_potential(q0)])

    def invariants(self, variant):
        return ("constraints", "energy", H_Y)

    def exact(self, t, variant):
        ref = dict(self.numerical_reference(t, self.variants["extended"]))  # the motion: the same for both
        y0 = self.initial_state(variant)
        ref.update(_exact.oscillator_y(t, y0[1], y0[4]))
        return ref


class NonreversibleOscillator(GaugeShiftedContactOscillator):
    name = "nonreversible-oscillator"
    title = "Nonholonomic oscillator with gauge-shifted momenta (not reversible)"
    paper = "Modin & Verdier 2020; the paper's Sec. 3 oscillator, p -> p - grad cos z"


class NonreversibleContactOscillator(GaugeShiftedContactOscillator):
    name = "nonreversible-contact-oscillator"
    title = "Nonlinear contact oscillator (eps = 0.3) with gauge-shifted momenta (not reversible)"
    paper = "Modin & Verdier 2020; McLachlan & Perlmutter 2006 Sec. 5.2, p -> p - grad cos z"
    eps = 0.3
    z0 = 0.1 * np.sqrt(2.0)
    q0 = (float(np.sqrt((2.0 - z0**2) / (1.0 + 0.3 * z0**2))), 0.0, z0)
    v0 = (0.0, 1.0, 0.0)


SCENES = {s.name: s for s in (NonreversibleOscillator(), NonreversibleContactOscillator())}
