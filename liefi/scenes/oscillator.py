r"""The nonholonomic oscillator (paper Sec. 3, subsection "The Nonholonomic Oscillator"): data only.

``T*R^3`` with ``q = (x, y, z)``, metric ``I``, potential ``|q|^2/2`` and the
constraint ``p . e = 0``, ``e = (1, 0, y)/sqrt(1 + y^2)`` (i.e.
``p_x + y p_z = 0``).  ``h~``, ``lambda~`` and every gradient are derived by
the library; the paper's printed ``grad H~``, ``lambda~`` and ``grad V`` are
test oracles only.

``V`` is the paper's

.. math:: V = \frac{k_1}{2} (\tilde H - \tilde H_0)^2
          + \frac{k_2}{2} (H_y - H_{y0})^2 + \frac{k_3}{2} J^2,

with ``H_y = p_y^2/2 + y^2/2`` (the :class:`~liefi.Invariant` ``"H_y"``; the
paper's ``H_{y0}(q, p)`` means ``H_y(q, p)``, NOTES item 5) and gains
``k_1 = 500`` (``"energy"``), ``k_2 = 300`` (``"H_y"``), ``k_3 = 300``
(``"J_1"``), ``(no:gains)``.  ``H_y`` is a first integral of the extended field
only on the constraint set (its rate off it is ``O(J)``), so this ``V`` meets
the assumption A1 only there -- the paper's choice, kept.

Start ``q(0) = (1, 1, 1)``, ``p(0) = 0`` (``(ns:ic)``; "``p(0,0,0)``" means
``p(0)``), Euler, ``dt = 1e-3``, ``t`` in ``[0, 200]``.  Reference: DOP853
(rtol 1e-12) on the constrained field, with the ``y`` subsystem replaced by its
closed form ``y = cos t`` (:func:`liefi.scenes.exact.oscillator_y`).

Extra scheme ``"dla"``: the first-order discrete Lagrange--d'Alembert
integrator, built from the same system by
:meth:`liefi.dla.DLAIntegrator.from_system`, started at ``q_0 = q_1 = (1, 1, 1)``
(``(ns:dla:ic)``), with the discrete momentum ``p_{i+1} = (q_{i+1} - q_i)/h``
paired with ``q_{i+1}``; the drifts reported for it are those of
``J = p . e(q)``, ``H``, ``H~`` and ``H_y`` at these pairs.  (The DLA keeps
``p_{i+1} . e(q_i) = 0`` exactly; ``p_{i+1} . e(q_{i+1})`` is ``O(h)``.)

:func:`poincare_section` extracts the snapshots of Figure
``(figure:Poincare:FI)``.
"""

import time

import numpy as np

from ..dla import DLAIntegrator
from ..feedback import Invariant
from ..phase_space import CotangentBundle
from ..system import NonholonomicSystem
from . import exact as _exact
from .base import Scene, Variant


def _y_energy(z):
    """``H_y = p_y^2/2 + y^2/2`` (complex-step safe)."""
    return 0.5 * z[..., 4] ** 2 + 0.5 * z[..., 1] ** 2


#: The energy of the ``y`` dynamics, a first integral on the constraint set.
H_Y = Invariant("H_y", _y_energy)


class Oscillator(Scene):
    name = "oscillator"
    title = "Nonholonomic oscillator on T*R^3"
    paper = "Sec. 3, The Nonholonomic Oscillator"
    reference = "numerical"
    dt = 1e-3
    t_final = 200.0
    gains = {"energy": 500.0, "H_y": 300.0, "J_1": 300.0}
    variants = {
        "extended": Variant("extended", "V penalizes the extended energy H~ (as printed)"),
        "original": Variant("original", "V penalizes the original energy H", energy="original"),
    }
    error_variables = ("x", "y", "z", "p_x", "p_y", "p_z")
    extra_schemes = ("dla",)

    q0 = (1.0, 1.0, 1.0)
    p0 = (0.0, 0.0, 0.0)

    def build_system(self):
        def constraint(q):
            y = q[..., 1]
            s = np.sqrt(1.0 + y**2)
            return np.stack([1.0 / s, np.zeros_like(y), y / s], -1)[..., None, :]

        def potential(q):
            return 0.5 * np.sum(q**2, -1)

        space = CotangentBundle(3, names=("x", "y", "z"))
        return NonholonomicSystem(space, np.eye(3), constraint, potential)

    def initial_state(self, variant):
        return np.concatenate([np.asarray(self.q0, float), np.asarray(self.p0, float)])

    def invariants(self, variant):
        return ("constraints", "energy", H_Y)

    def exact(self, t, variant):
        ref = dict(self.numerical_reference(t, variant))
        ref.update(_exact.oscillator_y(t, self.q0[1], self.p0[1]))
        return ref

    def run_extra(self, scheme, variant, dt, T, save_every, fi):
        """``"dla"``: the discrete Lagrange--d'Alembert integrator from the same data."""
        if scheme != "dla":
            return super().run_extra(scheme, variant, dt, T, save_every, fi)
        dla = DLAIntegrator.from_system(self.system)
        n = self.system.space.n
        y0 = np.asarray(self.initial_state(variant), float)
        n_steps = int(round(T / dt))
        q0, q1 = dla.initial_pair(y0[:n], y0[n:], dt)
        import importlib.util

        if importlib.util.find_spec("numba") is not None:
            # the same DLA step generated from the data and compiled (bitwise equal to liefi.dla)
            from .. import compiled

            t, q, p, cpu, updates = compiled.compile_dla(self.system).run(q0, q1, dt, n_steps, save_every=save_every)
            return t, np.concatenate([q, p], 0), self.system.state_names, cpu, updates, updates
        start = time.process_time()
        res = dla.run(q0, q1, dt, n_steps, save_every)
        cpu = time.process_time() - start
        Y = np.concatenate([res.q, res.p], 0)
        return res.t, Y, self.system.state_names, cpu, res.steps, res.rhs_evaluations


def poincare_section(result, coordinates=("x", "z", "p_z"), variable="y", momentum="p_y"):
    """Snapshots where ``y`` crosses zero upward (Figure ``(figure:Poincare:FI)``).

    Between consecutive saved points ``t_k < t_{k+1}`` with ``y_k < 0 <= y_{k+1}``
    and ``p_y > 0`` (the upward crossing, ``y' = p_y``) the crossing time and the
    coordinates are interpolated linearly.  The interpolation error is
    ``O(dt_saved^2)``, so run with ``save_every=1`` (or close), e.g.::

        from liefi import scenes
        from liefi.scenes.oscillator import poincare_section
        sc = scenes.get("oscillator")
        fi = poincare_section(sc.run(t_final=400, save_every=1))
        dla = poincare_section(sc.run(t_final=400, save_every=1, scheme="dla"))

    For the DLA run ``p_z`` is the discrete momentum, i.e. the paper's ``v_z``.

    Parameters
    ----------
    result : RunResult
        A run of the oscillator (any scheme), or anything with ``t``, ``y``
        (components first, time last) and ``names``.
    coordinates : sequence of str
        Components to report at the crossings (default ``x, z, p_z``).
    variable, momentum : str
        The crossing variable and its momentum (default ``y``, ``p_y``).

    Returns
    -------
    dict
        ``"t"`` and one array per coordinate, all of length the number of
        upward crossings.
    """
    names = tuple(result.names)
    Y = np.asarray(result.y)
    t = np.asarray(result.t, float)
    y = Y[names.index(variable)]
    py = Y[names.index(momentum)]
    k = np.nonzero((y[:-1] < 0.0) & (y[1:] >= 0.0))[0]
    s = -y[k] / (y[k + 1] - y[k])  # fraction of the interval at the crossing
    s_py = py[k] + s * (py[k + 1] - py[k])
    keep = s_py > 0.0
    k, s = k[keep], s[keep]
    out = {"t": t[k] + s * (t[k + 1] - t[k])}
    for c in coordinates:
        v = Y[names.index(c)]
        out[c] = v[k] + s * (v[k + 1] - v[k])
    return out


SCENE = Oscillator()
