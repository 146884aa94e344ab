"""A user-given first integral of a system: its name, its function of the reduced state, its gradient.

A system builder (:mod:`liefi.systems.rolling`, a scene) hands its integrals on as
:class:`Invariant` objects; the feedback integrator (:mod:`liefi.integrator.feedback`)
penalizes their drift.  Re-exported as ``liefi.Invariant``.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..reduction import core as _core


@dataclass(frozen=True)
class Invariant:
    """A user-given first integral of the extended field, a function of the reduced state.

    Parameters
    ----------
    name : str
    fun : callable
        ``fun(z)``: ``(..., nz) -> (...)``, complex-step safe unless ``grad`` is given.
    grad : callable, optional
        ``grad(z)``: ``(..., nz) -> (..., nz)``.
    """

    name: str
    fun: object
    grad: object = None

    def value_and_grad(self, z, data=_core.NUMPY_DATA):
        """``(I(z), dI/dz)``: ``grad`` if given, else by complex step (or traced, with the engine's ``data``)."""
        return data.value_and_gradient(self.fun, z, self.grad, f"invariant {self.name!r}")
