"""``dla``: the discrete Lagrange--d'Alembert integrator (:mod:`liefi.schemes.dla_integrator`) as a scheme of the registry.

It steps positions, not the feedback field: ``step(integrator, q_prev, q_curr, h)``
is :meth:`liefi.schemes.dla_integrator.DLAIntegrator.step`.  It has no feedback term, hence no
stiffness bound; its failure mode is an implicit step that converges to a
wrong root or a step too large for the motion, which the run module's drift
guard catches (the energy drift of a variational integrator stays bounded
when the step resolves the motion).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class DLAScheme:
    """The DLA integrator's registry entry (module docstring)."""

    name: str = "dla"
    order: int = 2
    kind = "dla"
    stiff_safe = True
    real_stability_bound = math.inf
    optimal_rate = math.nan
    stages = 1

    def integrator(self, system):
        """The :class:`~liefi.schemes.dla_integrator.DLAIntegrator` of a system (positions ``q``, mass from the metric)."""
        from .dla_integrator import DLAIntegrator

        return DLAIntegrator.from_system(system)

    def step(self, integrator, q_prev, q_curr, h):
        """One step ``(q_{k-1}, q_k) -> q_{k+1}`` of ``integrator``."""
        return integrator.step(q_prev, q_curr, h)


DLA = DLAScheme()
