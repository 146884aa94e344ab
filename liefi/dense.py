"""Dense output and events of a fixed-step run, in the shape of ``scipy.integrate.solve_ivp``.

A fixed-step run of a feedback integrator (:func:`liefi.run.run_feedback`)
keeps its states ``y_k`` at the saved times ``t_k`` (every step by default).
Between two of them the state is the cubic Hermite interpolant of the two
states and of the field at them, ``f_k = f(y_k)``:

.. math:: y(t_k + s h) = (2s^3 - 3s^2 + 1)\\, y_k + (s^3 - 2s^2 + s)\\, h f_k
          + (3s^2 - 2s^3)\\, y_{k+1} + (s^3 - s^2)\\, h f_{k+1}, \\quad 0 \\le s \\le 1,

``h = t_{k+1} - t_k`` (Hairer, Norsett & Wanner, *Solving Ordinary Differential
Equations I*, Sec. II.6).  It is continuous with a continuous derivative, it
passes through every saved state exactly, and it is of order 3: where the
nodes and slopes are exact its error is ``O(h^4)``
(``h^4 max|y''''| / 384``).  The run's own error, ``O(dt^p)`` for a scheme of
order ``p``, adds to it; with states saved every ``save_every`` steps the
interpolation error grows as ``(save_every dt)^4``.  ``f`` is the field the
scheme's tableau integrates: ``X - A grad V`` for an explicit tableau, the
extended field ``X`` for a split scheme (whose feedback step only removes the
rounding-level drift from the invariant set, where the two fields agree).

:class:`DenseOutput` is ``solution.sol`` (``dense_output=True``), called as
scipy's ``OdeSolution``; ``t_eval=`` is the same interpolant at given times.
Events are scipy's: functions ``event(t, y)`` with optional attributes
``terminal`` (bool, or the number of occurrences after which to stop) and
``direction`` (``> 0``: only rising zero crossings; ``< 0``: only falling ones);
a sign change between two saved states is located by Brent's method on the
interpolant (:func:`scipy.optimize.brentq`, to ``4 eps |t|``).
"""

from __future__ import annotations

import math

import numpy as np

#: Steps per segment of a run that has terminal events, numpy and compiled: the run
#: goes past a terminal event by at most this many steps before it is seen and the
#: run stops (a compiled segment costs a call into the kernel, a numpy one nothing).
EVENT_SEGMENT_STEPS = {"numpy": 64, "compiled": 1024}


def slopes(fi, scheme_kind, Y):
    """The field at the saved states ``Y`` (``(..., n, n_t)``), the slopes of the interpolant (module docstring)."""
    f = fi.unforced_vector_field if scheme_kind == "split" else fi.vector_field
    with np.errstate(all="ignore"):
        return np.moveaxis(f(np.moveaxis(Y, -1, 0)), 0, -1)


class DenseOutput:
    """The cubic Hermite interpolant of a run's saved states: ``sol(t)`` as scipy's ``OdeSolution``.

    Calling it with a scalar ``t`` gives the state ``(..., n)``; with an array
    of times ``(m,)`` it gives ``(..., n, m)``.  Times outside
    ``[t_min, t_max]`` are refused (a cubic extrapolated past the run is not
    the run).  Order 3: see the module docstring.

    Parameters
    ----------
    ts : ndarray (n_t,)
        Saved times, increasing.
    Y : ndarray (..., n, n_t)
        Saved states.
    F : ndarray (..., n, n_t)
        The field at them (:func:`slopes`).
    """

    order = 3

    def __init__(self, ts, Y, F):
        from scipy.interpolate import CubicHermiteSpline

        self.ts = np.asarray(ts, dtype=float)
        self.t_min, self.t_max = float(self.ts[0]), float(self.ts[-1])
        self.n_segments = self.ts.size - 1
        if self.ts.size == 1:  # a run of length 0 (a terminal event at the start)
            self._y0 = np.asarray(Y)[..., 0]
            self._spline = None
        else:
            self._spline = CubicHermiteSpline(self.ts, Y, F, axis=-1, extrapolate=True)

    def __call__(self, t):
        t = np.asarray(t, dtype=float)
        if t.ndim > 1:
            raise ValueError(f"t: expected a time or a 1-d array of times, got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError("t: contains non-finite times")
        slack = 4 * np.finfo(float).eps * max(abs(self.t_min), abs(self.t_max), 1.0)
        if t.size and (np.min(t) < self.t_min - slack or np.max(t) > self.t_max + slack):
            raise ValueError(
                f"t: the dense output covers [{self.t_min:g}, {self.t_max:g}] (the run's interval), "
                f"got times in [{np.min(t):g}, {np.max(t):g}]"
            )
        if self._spline is None:
            y = self._y0
            return y if t.ndim == 0 else np.repeat(y[..., None], t.size, -1)
        return self._spline(np.clip(t, self.t_min, self.t_max))

    def __repr__(self):
        return f"DenseOutput(t in [{self.t_min:g}, {self.t_max:g}], {self.n_segments} cubic Hermite segments)"


def check_events(events):
    """``events`` (a callable or a sequence of them) -> a list of callables; a ``TypeError`` naming the bad one."""
    if events is None:
        return []
    evs = [events] if callable(events) else list(events) if isinstance(events, (list, tuple)) else None
    if evs is None:
        raise TypeError(f"events: expected a callable event(t, y) or a list of them, got {events!r}")
    for i, ev in enumerate(evs):
        if not callable(ev):
            raise TypeError(f"events[{i}]: expected a callable event(t, y), got {ev!r}")
        term = getattr(ev, "terminal", False)
        if not isinstance(term, (bool, np.bool_)) and not (
            isinstance(term, (int, np.integer)) and term >= 0
        ):
            raise ValueError(f"events[{i}].terminal: expected a bool or a non-negative integer, got {term!r}")
        d = getattr(ev, "direction", 0)
        try:
            float(d)
        except (TypeError, ValueError):
            raise ValueError(f"events[{i}].direction: expected a number (>0, <0 or 0), got {d!r}") from None
    return evs


def _value(ev, i, t, y):
    v = ev(t, y)
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"events[{i}]: event(t, y) must return a number, got {v!r} at t={t:g}") from None
    return v


class EventTracker:
    """Watches the events along a run, one saved interval after another.

    ``fi`` and ``kind`` give the slopes of the interpolant (:func:`slopes`).
    :meth:`advance` takes the newly saved states; it records every zero
    crossing (``t_events``, ``y_events``) and returns ``(t, y, j)``: the first
    terminal event reached, with ``j`` the index of the saved interval it lies
    in, or ``None``.
    """

    def __init__(self, events, fi, kind):
        self.events = events
        self.fi, self.kind = fi, kind
        self.direction = [float(getattr(ev, "direction", 0)) for ev in events]
        term = [getattr(ev, "terminal", False) for ev in events]
        self.stop_after = [int(v) if not isinstance(v, (bool, np.bool_)) else (1 if v else 0) for v in term]
        self.count = [0] * len(events)
        self.t_events = [[] for _ in events]
        self.y_events = [[] for _ in events]
        self.g = None
        self.t_last = self.y_last = None
        self.nodes = 0

    def start(self, t0, y0):
        self.g = [_value(ev, i, t0, y0) for i, ev in enumerate(self.events)]
        self.t_last, self.y_last = t0, y0

    def advance(self, ts, Y):
        """New saved times ``ts`` (``(m,)``) and states ``Y`` (``(n, m)``) after the last ones."""
        for j in range(ts.size):
            t1, y1 = float(ts[j]), Y[..., j]
            g1 = [_value(ev, i, t1, y1) for i, ev in enumerate(self.events)]
            found = []
            for i, (a, b) in enumerate(zip(self.g, g1)):
                up, down = a <= 0 <= b, a >= 0 >= b
                d = self.direction[i]
                if (up and d > 0) or (down and d < 0) or ((up or down) and d == 0):
                    if (a == 0 and b == 0) or (a == 0 and self.t_events[i] and self.t_events[i][-1] == self.t_last):
                        continue  # zero over the interval, or a zero at the last state already recorded
                    found.append(i)
            if found:
                from scipy.optimize import brentq

                t0, y0 = self.t_last, self.y_last
                pair = np.stack([y0, y1], -1)
                dense = DenseOutput(np.array([t0, t1]), pair, slopes(self.fi, self.kind, pair))
                self.nodes += 2
                hits = []
                for i in found:
                    ev = self.events[i]
                    a, b = self.g[i], g1[i]
                    if a == 0:
                        root = t0
                    elif b == 0:
                        root = t1
                    else:
                        root = brentq(lambda s, ev=ev, i=i: _value(ev, i, s, dense(s)), t0, t1,
                                      xtol=4 * np.finfo(float).eps * max(abs(t1), 1.0), rtol=4 * np.finfo(float).eps)
                    hits.append((root, i))
                hits.sort()
                for root, i in hits:
                    ys = y1 if root == t1 else y0 if root == t0 else dense(root)  # a saved state exactly
                    self.t_events[i].append(root)
                    self.y_events[i].append(ys)
                    self.count[i] += 1
                    if self.stop_after[i] and self.count[i] >= self.stop_after[i]:
                        return root, ys, j
            self.g, self.t_last, self.y_last = g1, t1, y1
        return None

    def results(self):
        """``(t_events, y_events)`` as ``solve_ivp`` gives them: per event an array ``(k,)`` and ``(k, n)``."""
        n = np.shape(self.y_last)[-1] if self.y_last is not None else 0
        t_ev = [np.asarray(v, dtype=float) for v in self.t_events]
        y_ev = [np.asarray(v, dtype=float).reshape(len(v), n) for v in self.y_events]
        return t_ev, y_ev


def parse_span(t_span):
    """``t_span`` -> ``(t0, t_final)``: a final time (start 0) or a pair ``(t0, t_final)``, ``t_final > t0``."""
    if isinstance(t_span, (bool, np.bool_, str, bytes)):
        raise ValueError(f"t_span: expected a final time or a pair (t0, t_final), got {t_span!r}")
    if np.ndim(t_span) == 0:
        t0, tf = 0.0, t_span
    else:
        try:
            t0, tf = t_span
        except (TypeError, ValueError):
            raise ValueError(f"t_span: expected a final time or a pair (t0, t_final), got {t_span!r}") from None
    try:
        t0, tf = float(t0), float(tf)
    except (TypeError, ValueError):
        raise ValueError(f"t_span: expected numbers, got {t_span!r}") from None
    if not (math.isfinite(t0) and math.isfinite(tf)):
        raise ValueError(f"t_span: expected finite times, got {t_span!r}")
    if not tf > t0:
        raise ValueError(
            f"t_span: the final time must be after the start, got t0 = {t0:g}, t_final = {tf:g} (a feedback "
            "integrator runs forward in time: its Lyapunov function decreases only forward)"
        )
    return t0, tf


def check_t_eval(t_eval, t0, tf):
    """``t_eval`` as a sorted 1-d float array within ``[t0, t_final]``, else a ``ValueError`` naming it."""
    if t_eval is None:
        return None
    try:
        te = np.asarray(t_eval, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"t_eval: expected an array of times, got {t_eval!r}") from None
    if te.ndim != 1:
        raise ValueError(f"t_eval: expected a 1-d array of times, got shape {te.shape}")
    if not np.all(np.isfinite(te)):
        raise ValueError("t_eval: contains non-finite times")
    slack = 4 * np.finfo(float).eps * max(abs(t0), abs(tf), 1.0)
    if te.size and (te.min() < t0 - slack or te.max() > tf + slack):
        raise ValueError(f"t_eval: times must lie in t_span = [{t0:g}, {tf:g}], got [{te.min():g}, {te.max():g}]")
    if np.any(np.diff(te) < 0):
        raise ValueError("t_eval: times must be sorted increasingly (the run goes forward in time)")
    return np.clip(te, t0, tf)
