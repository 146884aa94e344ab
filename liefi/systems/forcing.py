r"""External forces and controls on a nonholonomic system: force laws and input signals.

A **force law** is a generalized force ``F(t, q, v; u)`` on the velocities
``v = (xi, x')`` (body angular/linear velocity on the group part, ``x'`` on the
shape part): a covector, shape ``(D,)``, so that its power is ``F . v``.  It
acts on the momentum slots of the reduced state, as the constraint forces do
(Lagrange--d'Alembert with a force, :func:`liefi.reduction.core.field_terms`):

.. math:: \dot P = \dots + \sum_i \lambda_i e_i^\flat + F, \qquad
          \lambda = C^{-1} (\{H, J\} - E F),

so the force enters through its component that does work on the allowed
velocities and every constraint ``J_i`` stays a first integral.  ``q`` is the
configuration part of the state (the group's stored numbers when the
configuration is integrated, then the shape ``x``, in the order of
:attr:`liefi.FeedbackIntegrator.names`); ``u`` are the named **inputs** (controls,
specified forces ``F(t)``), given by the user when the integrator is built
(``FeedbackIntegrator(system, y0, force=law, inputs={"T": signal})``).

A **signal** is a function of time: a number (constant), a callable ``s(t)``,
:func:`piecewise_constant` or :func:`spline` over a time grid (what an optimizer
hands over).  Signals are evaluated at real ``t``; a complex ``t`` (a complex
step through the clock) gets the signal's derivative on its imaginary part.
"""

from __future__ import annotations

import numpy as np

from .._data import as_float_array


class Signal:
    """A scalar or vector function of time ``s(t)``; see :func:`piecewise_constant`, :func:`spline`, :func:`as_signal`."""

    #: ``"piecewise"`` or ``"spline"`` for a signal over a grid (then ``t_grid``, ``values`` are set), else None
    grid_kind = None

    def __init__(self, value, derivative, shape, what):
        self._value, self._derivative, self.shape, self.what = value, derivative, shape, what

    def __call__(self, t):
        t = np.asarray(t)
        if np.iscomplexobj(t):  # a complex step through the clock: s(Re t) + i Im t s'(Re t)
            tr, ti = t.real, t.imag
            d = np.asarray(self._derivative(tr))
            return np.asarray(self._value(tr)) + 1j * np.reshape(ti, ti.shape + (1,) * len(self.shape)) * d
        return np.asarray(self._value(t), float)

    def __repr__(self):
        return f"Signal({self.what}, shape={self.shape})"


def _grid(t_grid, values, name, min_points):
    t_grid = as_float_array(t_grid, f"{name}: t_grid")
    values = as_float_array(values, f"{name}: values")
    if t_grid.ndim != 1 or t_grid.size < min_points or not np.all(np.isfinite(t_grid)):
        raise ValueError(f"{name}: t_grid must be {min_points} or more finite times, got shape {t_grid.shape}")
    if np.any(np.diff(t_grid) <= 0):
        raise ValueError(f"{name}: t_grid must be strictly increasing")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name}: values contain non-finite numbers (NaN or inf)")
    return t_grid, values


def piecewise_constant(t_grid, values, *, name="signal"):
    """``s(t) = values[k]`` for ``t_grid[k] <= t < t_grid[k + 1]`` (the last value after the last node).

    ``t_grid``: ``N + 1`` increasing times (the intervals' ends) or ``N`` (their
    starts); ``values``: ``(N,)`` or ``(N, m)``.  Before ``t_grid[0]`` the first
    value holds.  The derivative is zero (a complex step through the clock sees none).
    """
    t_grid, values = _grid(t_grid, values, name, 1)
    N = values.shape[0] if values.ndim else 0
    if values.ndim == 0 or t_grid.size not in (N, N + 1):
        raise ValueError(f"{name}: values must have one row per interval of t_grid ({t_grid.size - 1} or "
                         f"{t_grid.size}), got shape {values.shape}")
    starts = t_grid[:N]

    def value(t):
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, N - 1)
        return values[k]

    def derivative(t):
        return np.zeros(np.shape(t) + values.shape[1:])

    sig = Signal(value, derivative, values.shape[1:], f"piecewise constant over {N} intervals")
    sig.grid_kind, sig.t_grid, sig.values = "piecewise", t_grid, values  # for sensitivities to the values
    return sig


def spline(t_grid, values, *, name="signal", bc_type="not-a-knot"):
    """A cubic spline through ``(t_grid[k], values[k])`` (``scipy.interpolate.CubicSpline``); ``values`` ``(N,)`` or
    ``(N, m)``.  Outside the grid the end polynomials extrapolate (a forced run past the nodes warns:
    :class:`liefi.integrator.forced.InputGridWarning`)."""
    from scipy.interpolate import CubicSpline

    t_grid, values = _grid(t_grid, values, name, 2)
    if values.ndim == 0 or values.shape[0] != t_grid.size:
        raise ValueError(f"{name}: values must have one row per node of t_grid ({t_grid.size}), got shape "
                         f"{values.shape}")
    try:
        cs = CubicSpline(t_grid, values, axis=0, bc_type=bc_type)
    except ValueError as exc:  # a bad bc_type, or values that do not meet it (periodic)
        raise ValueError(f"{name}: bc_type={bc_type!r} cannot be used here: {exc} (scipy.interpolate.CubicSpline; "
                         "the default 'not-a-knot' fits any values)") from exc
    sig = Signal(cs, cs.derivative(), values.shape[1:], f"cubic spline through {t_grid.size} nodes")
    sig.grid_kind, sig.t_grid, sig.values, sig.bc_type = "spline", t_grid, values, bc_type
    return sig


def _checked(f, name, shape):
    """The user's function of time ``f`` as the run calls it, checked at every call.

    A run calls a signal with arrays of times (all the stages of a step at once), not only with the
    ``t = 0`` that :func:`as_signal` probes: an exception, a result that is not ``shape`` per time
    (broadcastable to ``t.shape + shape``) or a non-finite number at a finite time is a ``ValueError``
    naming the signal and the time, not a raw exception from inside the force or a NaN left to
    the run.  At non-finite times (a run that already diverged) the result is not checked: the run
    reports its own failure."""

    def value(t):
        t = np.asarray(t, float)
        want = t.shape + tuple(shape)
        try:
            v = np.asarray(f(t))
        except Exception as exc:  # noqa: BLE001 -- user code: say which input failed, and when
            if not np.all(np.isfinite(t)):
                return np.full(want, np.nan)
            hint = (f"; a signal is called with an array of times (here shape {t.shape}): write it with numpy "
                    "(np.sin, np.where, ...) rather than math, or wrap it in np.vectorize"
                    if t.ndim and isinstance(exc, (TypeError, ValueError)) else "")
            raise ValueError(f"inputs: the signal {name!r} failed at t = {_times(t)}: {exc!r}{hint}") from exc
        try:
            fits = v.dtype.kind in "biuf" and np.broadcast_shapes(v.shape, want) == want
        except ValueError:
            fits = False
        if not fits:
            raise ValueError(f"inputs: the signal {name!r} called with times of shape {t.shape} (t = {_times(t)}) "
                             f"returned {v.dtype.name} numbers of shape {v.shape}; expected real numbers of shape "
                             f"{want} (one value of shape {tuple(shape)} per time): write it with numpy "
                             "(np.sin, np.where, ...), or wrap it in np.vectorize")
        v = v.astype(float)
        bad = ~np.isfinite(np.broadcast_to(v, want)) & np.isfinite(t).reshape(t.shape + (1,) * len(shape))
        if np.any(bad):
            raise ValueError(f"inputs: the signal {name!r} returned a non-finite number (NaN or inf) at t = "
                             f"{_times(t[np.any(bad.reshape(t.shape + (-1,)), -1)])}; it must be finite at "
                             "every time of the run")
        return v

    return value


def _times(t):
    """A few of the times ``t`` for a message."""
    t = np.ravel(t)
    return f"{t[0]:.6g}" if t.size == 1 else "[" + ", ".join(f"{x:.6g}" for x in t[:3]) + (", ...]" if t.size > 3 else "]")


def as_signal(s, name):
    """``s`` as a :class:`Signal`: a Signal, a finite number or array (constant), or a callable ``s(t)``."""
    if isinstance(s, Signal):
        return s
    if callable(s):
        try:
            probe = np.asarray(s(0.0))
        except Exception as exc:  # noqa: BLE001 -- user code: say which input failed
            raise ValueError(f"inputs: the signal {name!r} failed at t = 0: {exc!r}") from exc
        if probe.dtype.kind not in "biuf" or not np.all(np.isfinite(probe)):
            raise ValueError(f"inputs: the signal {name!r} must return finite real numbers, got {probe!r} at t = 0")
        value = _checked(s, name, probe.shape)

        def derivative(t, f=value):  # a callable: its derivative by central difference (for a complex step only)
            h = 1e-6 * np.maximum(1.0, np.abs(t))
            return (f(t + h) - f(t - h)) / (2 * h)

        return Signal(value, derivative, probe.shape, "a function of t")
    value = as_float_array(s, f"inputs: {name!r}")
    if not np.all(np.isfinite(value)):
        raise ValueError(f"inputs: the signal {name!r} contains non-finite numbers (NaN or inf)")
    return Signal(lambda t: np.broadcast_to(value, np.shape(t) + value.shape),
                  lambda t: np.zeros(np.shape(t) + value.shape), value.shape, "constant")


class ForceLaw:
    """A generalized force ``F(t, q, v, u)`` with named inputs ``u`` (module docstring).

    Parameters
    ----------
    fun : callable
        ``fun(t, q, v)`` (no inputs) or ``fun(t, q, v, u)`` with ``u`` of shape
        ``(..., m)`` in the order of ``inputs``; returns ``(..., D)`` (or ``(D,)``):
        the force's components on the velocities ``v = (xi, x')``.  Batch-first and,
        for the feedback's gains and ``linearize``'s ``B``, complex-step safe in ``q``,
        ``v`` and ``u``.
    inputs : sequence of str
        The names of the inputs (each a scalar signal), given with the integrator's ``inputs=``.
    """

    def __init__(self, fun, inputs=()):
        if not callable(fun):
            raise TypeError(f"force: expected a callable force(t, q, v) or force(t, q, v, u), got {fun!r}")
        if isinstance(inputs, str):
            inputs = (inputs,)
        self.fun, self.inputs = fun, tuple(inputs)
        if len(set(self.inputs)) != len(self.inputs) or not all(isinstance(s, str) for s in self.inputs):
            raise ValueError(f"inputs: expected distinct names, got {self.inputs!r}")

    def __call__(self, t, q, v, u):
        return self.fun(t, q, v, u) if self.inputs else self.fun(t, q, v)

    def __repr__(self):
        return f"ForceLaw({getattr(self.fun, '__name__', 'force')}, inputs={self.inputs})"


def as_force_law(force):
    """``force`` as a :class:`ForceLaw` (a callable ``force(t, q, v)`` has no inputs)."""
    return force if isinstance(force, ForceLaw) else ForceLaw(force)


def bind_inputs(law, inputs):
    """``{name: Signal}`` for every input of ``law``, from the user's ``inputs`` mapping (named errors)."""
    inputs = {} if inputs is None else inputs
    if not isinstance(inputs, dict):
        raise TypeError(f"inputs: expected a dict {{name: signal}}, got {type(inputs).__name__}")
    missing = [s for s in law.inputs if s not in inputs]
    unknown = [s for s in inputs if s not in law.inputs]
    if missing:
        raise ValueError(f"inputs: no signal for {missing}; the force's inputs are {list(law.inputs)}: pass "
                         f"inputs={{{', '.join(repr(s) + ': ...' for s in missing)}}} (a number, a function of t, "
                         "liefi.systems.forcing.piecewise_constant or spline)")
    if unknown:
        raise ValueError(f"inputs: {unknown} are not inputs of the force; its inputs are {list(law.inputs)}")
    out = {}
    for s in law.inputs:
        sig = as_signal(inputs[s], s)
        if sig.shape != ():
            raise ValueError(f"inputs: the signal {s!r} must be scalar (one number per time), got shape {sig.shape}")
        out[s] = sig
    return out
