r"""Parameters declared on data built by hand: named numbers that the data read when they are evaluated.

A system built by hand (:class:`~liefi.NonholonomicSystem` with callable data, :func:`liefi.systems.rolling.rolling_body`
with a contact function of one's own) can name some of the numbers in its data as parameters::

    par = Parameters(radius=1.0, height=0.1)

    def contact(G):                              # a ball whose centre of mass sits `height` above its centre
        return -par["radius"] * G - par["height"] * np.array([0.0, 0.0, 1.0])

    ball = declare(rolling_body(1.0, [0.3, 0.4, 0.5], contact), par)
    sol = liefi.FeedbackIntegrator(ball, y0).run(T, dt=dt, sensitivities=("radius", "height"))

The data read ``par[name]`` *each time they are evaluated* (not once, when the system is built), so:

* changing a value (``par["radius"] = 1.1``) changes the system without a rebuild, as the constants of
  :func:`liefi.mechanics.from_mechanics` do; the compiled kernels, which fold the values into their code,
  are kept per value (:attr:`Parameters.data_key` is the system's ``data_key``);
* the sensitivities (:mod:`liefi.integrator.sensitivity`) trace the data with the values replaced by
  symbols, and differentiate the run's steps by them exactly, as for ``from_mechanics`` constants.

Only the numbers read through ``par[...]`` inside the data move with a parameter: a value the builder took
as a number (``rolling_body``'s ``mass`` and ``inertia``, checked and folded at construction) is fixed.
"""

from __future__ import annotations

import numpy as np

from .._data import as_float

__all__ = ["Parameters", "declare"]


class Parameters:
    """Named real parameters that data built by hand read when evaluated (module docstring).

    Parameters
    ----------
    **values : float
        ``name=value``, in the order they become :attr:`names`.
    """

    def __init__(self, **values):
        if not values:
            raise ValueError("Parameters: give at least one name=value")
        self.names = tuple(values)
        vals = []
        for name, v in values.items():
            x = as_float(v, name, "a real number")
            if not np.isfinite(x):
                raise ValueError(f"{name}: expected a finite number, got {v!r}")
            vals.append(x)
        #: the current values, in the order of :attr:`names` (replaced by symbols while liefi traces the data)
        self.values = np.array(vals, float)

    def __getitem__(self, name):
        try:
            return self.values[self.names.index(name)]
        except ValueError:
            raise KeyError(f"{name!r} is not a declared parameter; they are {list(self.names)}") from None

    def __setitem__(self, name, value):
        if name not in self.names:
            raise KeyError(f"{name!r} is not a declared parameter; they are {list(self.names)}")
        x = as_float(value, name, "a real number")
        if not np.isfinite(x):
            raise ValueError(f"{name}: expected a finite number, got {value!r}")
        vals = np.array(self.values, float)  # a new array: a kernel built on the old values keeps them
        vals[self.names.index(name)] = x
        self.values = vals

    def as_dict(self):
        """``{name: value}`` of the current values."""
        return {n: float(v) for n, v in zip(self.names, self.values)}

    @property
    def data_key(self):
        """The current values as bytes (the compiled kernels are kept per value)."""
        return np.asarray(self.values, float).tobytes()

    def __repr__(self):
        return "Parameters(" + ", ".join(f"{n}={v!r}" for n, v in self.as_dict().items()) + ")"


class _Key:
    """The ``data_key`` of a system with declared parameters: hashes and compares as their current values."""

    __slots__ = ("parameters",)

    def __init__(self, parameters):
        self.parameters = parameters

    def __hash__(self):
        return hash(self.parameters.data_key)

    def __eq__(self, other):
        return isinstance(other, _Key) and other.parameters.data_key == self.parameters.data_key


def declare(system, parameters):
    """Declare ``parameters`` (a :class:`Parameters` its data read) on ``system``; returns ``system``.

    Afterwards ``sensitivities=`` accepts their names, and the compiled kernels of ``system`` are kept per
    value of them.  A system built by :func:`liefi.mechanics.from_mechanics` has its constants already.
    """
    if not isinstance(parameters, Parameters):
        raise TypeError(f"parameters: expected liefi.systems.parameters.Parameters, got {parameters!r}")
    if getattr(system, "_mech", None) is not None:
        raise ValueError("parameters: this system was built by from_mechanics; its constants are its parameters "
                         "(system.constant_names)")
    if not hasattr(system, "space"):
        raise TypeError(f"system: expected a liefi NonholonomicSystem, got {system!r}")
    system.declared_parameters = parameters
    system.data_key = _Key(parameters)
    return system
