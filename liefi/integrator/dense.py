r"""Dense output and events of a fixed-step run, in the shape of ``scipy.integrate.solve_ivp``.

A fixed-step run of a feedback integrator (:func:`liefi.integrator.run.run_feedback`)
steps on the grid ``t_k = t_0 + k dt`` with the one-step map ``Phi_dt`` of
its scheme (an explicit tableau on ``X - A grad V``; a split scheme's tableau
on ``X`` followed by its feedback step, :mod:`liefi.schemes.split`).  The
state at a time ``t`` between two steps is **a partial step of the same
map** from the last step point before it:

.. math:: y(t) = \Phi_{h}(y_k), \qquad t_k \le t < t_{k+1}, \quad h = t - t_k \in [0, dt).

Why this and not an interpolant.  ``Phi_h`` is a step of the scheme with a
shorter step, so its local error is ``O(h^{p+1}) <= O(dt^{p+1})`` and the
state at ``t`` has the global error of the run at ``t_k`` plus at most one
local error: the run's order ``p`` and its tolerance, whatever ``p``.  And it
is the scheme's own map, feedback step included, so it keeps the invariants
as the steps do: a state on the invariant set moves off it by the scheme's
local error in ``I_j`` (``O(h^{p+1})``), which the feedback term removes in
the same step -- a split scheme's feedback step divides it by
``1 + (h/dt) z``, ``z = dt k |grad I_j|^2`` the step's rate, so the residual
is at most ``(h/dt)^p`` times a full step's.  A polynomial interpolant
(the cubic Hermite one, or a continuous extension of the tableau) keeps
neither: a cubic between the steps of an eighth-order run has an error
``O(dt^4)``, orders of magnitude above the steps', and no polynomial in
``t`` keeps a nonlinear constraint such as the knife edge's
``J_1 = (p_x sin phi - p_y cos phi)/sqrt(m)``.  The cost is one step per
output point, vectorised over all the points (a batch of states stepped with
one step each: ``h`` is an array over the batch); the run itself is not
touched, and a run without ``t_eval``, ``dense_output`` or ``events`` pays
nothing.  With states saved every ``save_every`` steps, the step points
between two saved states are first re-made by full steps of the same map
(at most ``save_every - 1`` of them).  The partial steps use the numpy map
also after a compiled run: the two backends' steps are the same formulas and
agree to rounding (:mod:`liefi.engine`), and the numpy map is the one that
steps a batch of different ``h`` at once.

**The gains of the step they continue.**  A step from ``t_k`` -- partial, or a
full step re-made between saved states -- uses the gains the run had in effect
at ``t_k`` (:meth:`StepMap.switch`: the schedule of an ``adaptive`` run, the one
:func:`liefi.integrator.sensitivity.gain_schedule` replays), so that ``Phi_h``
is the map of that step and ``Phi_{dt}(y_k) = y_{k+1}`` to rounding.  The gains
do not act only on the drift: an explicit tableau steps the feedback's stiff
mode by ``R(-h lambda)``.  Kepler with rk4, ``dt = 0.02``, the paper's gains
adapted from 4 down to 0.94 towards the apocentre and back up to 4 at the end:
with the gains of the end, ``dt lambda`` at the apocentre is 6.8, past RK4's
bound ``beta = 2.79`` (``|R(-6.8)| = 53``); before the schedule a step from
``y_k`` missed the run's own ``y_{k+1}`` by 1e-6 and ``sol(t)`` between states
saved every 10 or 50 steps was ``nan`` -- silently, while the run's steps were
within 1.2e-5 of the exact orbit.

The same primitive gives a run whose ``dt`` does not divide the span its last,
shortened step (:func:`liefi.integrator.run.run_feedback`), and the state at an event:
a sign change of ``event(t, y)`` between two saved states is located by
Brent's method (:func:`scipy.optimize.brentq`, to ``4 eps |t|``) on
``event(t, Phi_{t - t_k}(y_k))``, so the event's state is a partial-step
state of the run, not an interpolated one.

:class:`DenseOutput` is ``solution.sol`` (``dense_output=True``), called as
scipy's ``OdeSolution``; ``t_eval=`` is the same map at given times.
Events are scipy's: functions ``event(t, y)`` with optional attributes
``terminal`` (bool, or the number of occurrences after which to stop) and
``direction`` (``> 0``: only rising zero crossings; ``< 0``: only falling ones).
"""

from __future__ import annotations

import math

import numpy as np

#: Steps per segment of a run that has terminal events, numpy and compiled: the run
#: goes past a terminal event by at most this many steps before it is seen and the
#: run stops (a compiled segment costs a call into the kernel, a numpy one nothing).
EVENT_SEGMENT_STEPS = {"numpy": 64, "compiled": 1024}

#: Marks a saved state that is not on the step grid (a shortened last step, an event's state).
OFF_GRID = -1


def partial_step(fi, sch, y, h):
    """One step of the scheme ``sch`` of the integrator ``fi``, of size ``h`` per state.

    ``y`` is ``(m, ..., n)`` (``m`` states, each a state or a batch of them)
    and ``h`` is ``(m,)``, ``h >= 0``: row ``i`` is stepped by ``h[i]`` with
    the run's one-step map (an explicit tableau on ``fi.vector_field``; a
    split scheme's tableau on ``X``, then its feedback step,
    :func:`liefi.schemes.split.feedback_step`).  A row with ``h = 0`` is
    returned unchanged (bit for bit).  Module docstring: why this is the
    dense output.
    """
    from ..schemes.split import feedback_step

    y = np.asarray(y, dtype=float)
    h = np.asarray(h, dtype=float)
    hb = h.reshape(h.shape + (1,) * (y.ndim - h.ndim))  # against (m, ..., n)
    with np.errstate(all="ignore"):
        if sch.kind == "split":
            out = feedback_step(fi, sch.explicit.step(fi.unforced_vector_field, y, hb), hb[..., 0])
        else:
            out = sch.step(fi.vector_field, y, hb)
    return np.where(hb == 0, y, out)


class StepMap:
    """A run's one-step map on its grid ``t_k = t_start + k dt``, ``k = 0..n_full``.

    ``fi`` the integrator the run starts with (its gains in effect), ``sch`` its
    scheme.  :meth:`states` gives the states at any times from states on the
    grid: full steps to the last grid point ``t_k <= t``, then the partial
    step ``Phi_{t - t_k}`` (module docstring), each with the gains in effect at
    the step it starts from (:meth:`switch`).
    """

    def __init__(self, fi, sch, t_start, dt, n_full):
        self.sch = sch
        self.t_start, self.dt, self.n_full = float(t_start), float(dt), int(n_full)
        self.steps = 0  # steps (full or partial) taken, per state: for rhs_evaluations
        self._from = [0]  # the grid step from which each integrator of the schedule is in effect
        self._fis = [fi]

    @property
    def fi(self):
        """The integrator in effect now (the last of the schedule)."""
        return self._fis[-1]

    def switch(self, k, fi):
        """From grid step ``k`` on, the run steps with ``fi`` (an adaptive run's new gains)."""
        k = int(k)
        if fi is self._fis[-1]:
            return
        if k <= self._from[-1]:  # replaces the one that started there
            self._fis[-1] = fi
            return
        self._from.append(k)
        self._fis.append(fi)

    def integrator(self, k):
        """The integrator in effect at grid step ``k`` (a number)."""
        return self._fis[int(np.searchsorted(self._from, int(k), side="right")) - 1]

    def time(self, k):
        """The grid's times ``t_start + k dt``, computed as the run computes them."""
        return self.t_start + self.dt * np.asarray(k, dtype=float)

    def index(self, t):
        """The largest ``k <= n_full`` with ``t_k <= t`` (``0`` before the start)."""
        t = np.asarray(t, dtype=float)
        with np.errstate(invalid="ignore"):
            k = np.clip(np.floor((t - self.t_start) / self.dt), 0, self.n_full).astype(np.int64)
        k = k - ((self.time(k) > t) & (k > 0))
        return k + ((k < self.n_full) & (self.time(k + 1) <= t))

    def step(self, y, h, k=None):
        """:func:`partial_step` of this run from grid steps ``k`` (``(m,)``; default: the integrator in effect
        now, e.g. for the shortened last step); counts the steps."""
        self.steps += int(np.size(h))
        if k is None or len(self._fis) == 1:
            return partial_step(self.fi if k is None else self._fis[0], self.sch, y, h)
        y = np.asarray(y, dtype=float)
        h = np.asarray(h, dtype=float)
        which = np.searchsorted(self._from, np.asarray(k, dtype=np.int64), side="right") - 1
        out = np.empty(y.shape)
        for w in np.unique(which):  # one vectorised step per set of gains
            sel = which == w
            out[sel] = partial_step(self._fis[w], self.sch, y[sel], h[sel])
        return out

    def states(self, y, k0, t):
        """The states at times ``t`` (``(m,)``) from grid states ``y`` (``(m, ..., n)``) at steps ``k0`` (``(m,)``).

        ``t >= t_{k0}``; ``k0`` full steps to the last grid point before ``t``,
        then one partial step, each with the gains in effect at its start.
        """
        t = np.asarray(t, dtype=float)
        k0 = np.asarray(k0, dtype=np.int64)
        k = np.maximum(self.index(t), k0)
        y = np.array(y, dtype=float)
        full = k - k0
        for r in range(int(full.max(initial=0))):  # re-make the steps between saved states
            sel = full > r
            y[sel] = self.step(y[sel], np.full(int(sel.sum()), self.dt), k0[sel] + r)
        return self.step(y, np.maximum(t - self.time(k), 0.0), k)


class DenseOutput:
    """A run's state at any time of its interval, ``sol(t)`` as scipy's ``OdeSolution``.

    A partial step of the run's scheme from the last step point before ``t``
    (module docstring): of the run's order, and it keeps the invariants as the
    steps do.  Calling it with a scalar ``t`` gives the state ``(..., n)``; with an
    array of times ``(m,)`` it gives ``(..., n, m)``, all stepped at once.  A
    saved time gives its saved state exactly.  Times outside
    ``[t_min, t_max]`` are refused (a step past the run is not the run).

    Parameters
    ----------
    stepper : StepMap
        The run's one-step map and grid.
    ts : ndarray (n_t,)
        Saved times, increasing.
    Y : ndarray (..., n, n_t)
        Saved states.
    steps : ndarray (n_t,)
        The grid index of each saved state; :data:`OFF_GRID` for a state off
        the grid (a shortened last step, a terminal event's).
    """

    def __init__(self, stepper, ts, Y, steps):
        self.stepper = stepper
        self.ts = np.asarray(ts, dtype=float)
        self.Y = np.asarray(Y, dtype=float)
        self.t_min, self.t_max = float(self.ts[0]), float(self.ts[-1])
        self.n_segments = self.ts.size - 1
        steps = np.asarray(steps, dtype=np.int64)
        on = steps != OFF_GRID
        self._on_t, self._on_i, self._on_k = self.ts[on], np.nonzero(on)[0], steps[on]

    @property
    def order(self):
        """The order of the run's scheme: the dense output has the steps' order."""
        return self.stepper.sch.order

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
        tt = np.clip(np.atleast_1d(t), self.t_min, self.t_max)
        out = np.empty(self.Y.shape[:-1] + (tt.size,))
        j = np.minimum(np.searchsorted(self.ts, tt), self.ts.size - 1)
        saved = self.ts[j] == tt
        out[..., saved] = self.Y[..., j[saved]]
        rest = np.nonzero(~saved)[0]
        if rest.size:
            i = np.searchsorted(self._on_t, tt[rest], side="right") - 1  # the last grid state before t
            y0 = np.moveaxis(self.Y[..., self._on_i[i]], -1, 0)
            y = self.stepper.states(y0, self._on_k[i], tt[rest])
            out[..., rest] = np.moveaxis(y, 0, -1)
        return out[..., 0] if t.ndim == 0 else out

    def __repr__(self):
        return (f"DenseOutput(t in [{self.t_min:g}, {self.t_max:g}], {self.n_segments} segments, "
                f"partial steps of {self.stepper.sch.name})")


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

    ``stepper`` (:class:`StepMap`) is the run's one-step map: a zero is
    located on the partial steps from the interval's start (module
    docstring).  :meth:`advance` takes the newly saved states; it records
    every zero crossing (``t_events``, ``y_events``) and returns ``(t, y, j)``:
    the first terminal event reached, with ``j`` the index of the saved
    interval it lies in, or ``None``.
    """

    def __init__(self, events, stepper):
        self.events = events
        self.stepper = stepper
        self.direction = [float(getattr(ev, "direction", 0)) for ev in events]
        term = [getattr(ev, "terminal", False) for ev in events]
        self.stop_after = [int(v) if not isinstance(v, (bool, np.bool_)) else (1 if v else 0) for v in term]
        self.count = [0] * len(events)
        self.t_events = [[] for _ in events]
        self.y_events = [[] for _ in events]
        self.g = None
        self.t_last = self.y_last = self.k_last = None

    def start(self, t0, y0, k0=0):
        self.g = [_value(ev, i, t0, y0) for i, ev in enumerate(self.events)]
        self.t_last, self.y_last, self.k_last = t0, y0, k0

    def advance(self, ts, Y, steps):
        """New saved times ``ts`` (``(m,)``), states ``Y`` (``(n, m)``), grid indices ``steps``, after the last."""
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

                t0, y0, k0 = self.t_last, self.y_last, self.k_last

                def state(s):  # the run's partial step from the interval's start
                    return self.stepper.states(y0[None], [k0], [s])[0]

                hits = []
                for i in found:
                    ev = self.events[i]
                    a, b = self.g[i], g1[i]
                    if a == 0:
                        root = t0
                    elif b == 0:
                        root = t1
                    else:
                        root = brentq(lambda s, ev=ev, i=i: _value(ev, i, s, state(s)), t0, t1,
                                      xtol=4 * np.finfo(float).eps * max(abs(t1), 1.0), rtol=4 * np.finfo(float).eps)
                    hits.append((root, i))
                hits.sort()
                for root, i in hits:
                    ys = y1 if root == t1 else y0 if root == t0 else state(root)  # a saved state exactly
                    self.t_events[i].append(root)
                    self.y_events[i].append(ys)
                    self.count[i] += 1
                    if self.stop_after[i] and self.count[i] >= self.stop_after[i]:
                        return root, ys, j
            self.g, self.t_last, self.y_last, self.k_last = g1, t1, y1, int(steps[j])
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
