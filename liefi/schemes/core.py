"""The batch-first fixed-step driver, its result and its error.

A scheme comes from :mod:`liefi.schemes.registry`; :func:`integrate` steps any
batch-first vector field ``f(y)`` (``(..., n) -> (..., n)``) with it, checks
every step for non-finite numbers and reports where they appeared.  For
adaptive or implicit integration use ``scipy.integrate.solve_ivp`` with the
``fun(t, y)`` of a :class:`~liefi.FeedbackIntegrator`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np


class IntegrationError(FloatingPointError):
    """A run produced non-finite numbers; the message says when, where and what to change.

    Attributes
    ----------
    t : float
        Time of the last finite state.
    step : int
        Index of the step that failed.
    y : ndarray
        The last finite state (whole batch).
    components : list of str
        Names (or indices) of the components that became non-finite.
    what : str
        What happened at ``step``: ``""`` for non-finite values, else the failure's own words (a linear
        solve of the field that found a singular matrix: the run diverged out of the data's domain).
    """

    def __init__(self, message, t, step, y, components, what=""):
        super().__init__(message)
        self.t, self.step, self.y, self.components, self.what = t, step, y, components, what

    def __reduce__(self):  # pickles with its fields (process pools, sweeps)
        return (type(self), (str(self), self.t, self.step, self.y, self.components), self.__dict__)


#: ``Solution.message`` of a run that reached the end of its interval (``status`` 0), as scipy words it.
MESSAGE_DONE = "The solver successfully reached the end of the integration interval."
#: ``Solution.message`` of a run stopped by a terminal event (``status`` 1).
MESSAGE_EVENT = "A termination event occurred."


@dataclass
class Solution:
    """Result of a fixed-step run, in the layout of scipy's ``OdeResult``: time on the last axis.

    Attributes
    ----------
    t : ndarray (n_t,)
    y : ndarray (..., n, n_t)
    scheme : str
    dt : float
    steps : int
    rhs_evaluations : int
        Evaluations of the field per trajectory (also :attr:`nfev`).
    cpu_seconds : float
        Process time of the stepping loop.
    names : tuple of str
        The components' names (``Solution[name]``).
    success : bool
        False only for a run that failed with ``errors="return"``
        (:meth:`liefi.FeedbackIntegrator.run`); by default a failure raises.
    status : int
        ``0``: the end of the interval was reached; ``1``: a terminal event
        stopped the run; ``-1``: the run failed (``errors="return"``), or was
        interrupted (``KeyboardInterrupt().solution``, :meth:`liefi.FeedbackIntegrator.run`).
    message : str
        What ``status`` means, or the failure's message.
    t_events, y_events : list of ndarray, or None
        With ``events=``: per event, the times ``(n_k,)`` and states ``(n_k, n)``
        where it occurred (as ``solve_ivp``).
    sol : DenseOutput or None
        With ``dense_output=True``: ``sol(t)`` the state at any ``t`` in the
        run's interval (:class:`liefi.integrator.dense.DenseOutput`).
    integrator : FeedbackIntegrator or None
        The integrator that made the run, when known: :meth:`to_xarray` and
        :mod:`liefi.results.plot` read the invariants from it.
    sensitivities : dict or None
        With ``run(..., sensitivities=names)``: ``{name: d y / d name}`` at the saved
        states (:mod:`liefi.integrator.sensitivity`).
    adjoint : RunAdjoint or None
        With ``run(..., adjoint=True)``: what :meth:`vjp` needs (:mod:`liefi.integrator.adjoint`).
    """

    t: np.ndarray
    y: np.ndarray
    scheme: str
    dt: float
    steps: int
    rhs_evaluations: int
    cpu_seconds: float
    names: tuple = field(default=())
    success: bool = True
    status: int = 0
    message: str = MESSAGE_DONE
    t_events: list = None
    y_events: list = None
    sol: object = None
    integrator: object = field(default=None, repr=False, compare=False)
    sensitivities: dict = field(default=None, repr=False, compare=False)
    adjoint: object = field(default=None, repr=False, compare=False)

    def vjp(self, cotangent, wrt=None):
        """``{name: dL/dname}`` for ``cotangent = dL/dy`` (the shape of :attr:`y`), by reverse mode.

        For a run made with ``fi.run(..., adjoint=True)`` (:mod:`liefi.integrator.adjoint`): ``"y0"``
        and the system's parameters, or the names ``wrt``; one backward sweep whatever their number.
        """
        if self.adjoint is None:
            raise ValueError("vjp: this run kept no adjoint; run it with fi.run(..., adjoint=True) (or "
                             "adjoint=liefi.integrator.adjoint.RecursiveCheckpointAdjoint(checkpoints=...))")
        return self.adjoint(cotangent, wrt=wrt)

    @property
    def nfev(self):
        """Evaluations of the field per trajectory, as ``OdeResult.nfev`` (:attr:`rhs_evaluations`)."""
        return self.rhs_evaluations

    def __getitem__(self, name):
        """The trajectory of the component called ``name``, shape ``(..., n_t)``."""
        try:
            return self.y[..., self.names.index(name), :]
        except ValueError:
            raise KeyError(f"{name!r}: not a component; components are {self.names}") from None

    def to_dataframe(self, *, invariants=False):
        """The run as a ``pandas.DataFrame``: one column per component, indexed by time.

        A batch (``y`` of shape ``(..., n, n_t)``) gets a two-level index
        ``(member, t)``, ``member`` the flat index of the batch.  ``invariants=True``
        adds the monitored invariants (:meth:`liefi.FeedbackIntegrator.invariant_values`)
        as columns; it needs :attr:`integrator`.  Needs pandas (``pip install liefi[export]``).
        """
        from .export import to_dataframe

        return to_dataframe(self, invariants=invariants)

    def to_xarray(self, *, invariants=True):
        """The run as an ``xarray.Dataset``: one variable per component over the coordinate ``t``.

        A batch gets a leading dimension ``member``.  With :attr:`integrator`
        known (a run of :meth:`liefi.FeedbackIntegrator.run`) and ``invariants``
        (default True), the monitored invariants are variables too, with their
        targets as attributes.  The dataset round-trips through netCDF
        (``ds.to_netcdf(path, engine="scipy")``).  Needs xarray
        (``pip install liefi[export]``).
        """
        from .export import to_xarray

        return to_xarray(self, invariants=invariants)


def _number(x, name, what):
    if isinstance(x, (bool, np.bool_, str, bytes)):
        raise ValueError(f"{name}: {what}, got {x!r}")
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {what}, got {x!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name}: {what}, got {x!r}")
    return v


def positive_number(x, name, what="must be a positive finite number"):
    """``float(x)`` if it is a positive finite number (not a bool), else a ``ValueError`` naming ``name``."""
    return _number(x, name, what)


def positive_int(x, name):
    """``int(x)`` if it is a positive whole number (not a bool), else a ``ValueError`` naming ``name``."""
    if isinstance(x, (bool, np.bool_)):
        raise ValueError(f"{name}: expected a positive integer, got {x!r}")
    try:
        v = int(x)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: expected a positive integer, got {x!r}") from None
    if v < 1 or v != x:
        raise ValueError(f"{name}: expected a positive integer, got {x!r}")
    return v


#: More steps than this are refused (a typo in dt or t_final, not a run).
MAX_STEPS = 1e10
#: ``dt`` divides a span when a whole number of steps covers it to this relative tolerance.
DIVIDES_RTOL = 1e-9


def step_grid(dt, length):
    """``(n_full, h_last)``: the span ``length`` as ``n_full`` steps ``dt`` and a last, shorter step ``h_last``.

    ``h_last = 0`` when ``dt`` divides ``length`` (to :data:`DIVIDES_RTOL`
    relative, as :func:`steps_for`); else ``n_full = floor(length / dt)`` and
    ``0 < h_last = length - n_full dt < dt`` (``n_full = 0``: ``dt`` is longer
    than the span).  ``dt`` and ``length`` positive finite numbers.
    """
    n = int(round(length / dt))
    if n >= 1 and abs(n * dt - length) <= DIVIDES_RTOL * length:
        return n, 0.0
    n = int(math.floor(length / dt))
    return n, length - n * dt


def steps_for(dt, t_final, *, save_every=1, check_every=1, t0=0.0):
    """The one validator of a fixed-step run's arguments: ``(dt, t_final, n_steps, save_every, check_every)``.

    ``dt`` and ``t_final`` positive finite numbers, ``t_final / dt`` a whole
    number of steps (to ``1e-9`` relative; otherwise the message gives the
    nearest ``dt`` that divides ``t_final``), at most :data:`MAX_STEPS` steps;
    ``save_every`` and ``check_every`` positive integers.  With a start ``t0``
    (finite; ``t_final`` then any finite time after it) the span
    ``t_final - t0`` is what ``dt`` must divide.
    """
    dt = positive_number(dt, "dt", "the step must be a positive finite number")
    if t0 == 0.0:
        t_final = positive_number(t_final, "t_final", "must be a positive finite time")
        length, what = t_final, f"t_final = {t_final!r}"
    else:
        t_final = _number(t_final - t0 if _finite(t_final) else t_final, "t_span",
                          f"the final time must be a finite number after the start t0 = {t0!r}") + t0
        t_final = float(t_final)
        length = t_final - t0
        what = f"the span t_final - t0 = {length!r} (t0 = {t0!r})"
    save_every = positive_int(save_every, "save_every")
    check_every = positive_int(check_every, "check_every")
    ratio = length / dt
    if ratio > MAX_STEPS:
        raise ValueError(
            f"dt: {dt!r} with {what} means {ratio:.3g} steps (more than {MAX_STEPS:.0e}); "
            "take a larger dt or a shorter t_final"
        )
    n_steps = int(round(ratio))
    if n_steps < 1 or abs(n_steps * dt - length) > DIVIDES_RTOL * length:
        n = max(1, n_steps)
        up, down = length / n, length / (n + 1)
        near = up if abs(up - dt) <= abs(down - dt) else down
        raise ValueError(
            f"dt: {dt!r} does not divide {what} ({ratio:.6g} steps); the nearest step that "
            f"divides it is dt = {near:.12g} ({int(round(length / near))} steps)"
        )
    return dt, t_final, n_steps, save_every, check_every


def _finite(x):
    try:
        return not isinstance(x, (bool, np.bool_, str, bytes)) and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def run_arguments(scheme, dt, n_steps, save_every):
    """Checked ``(scheme, dt, n_steps, save_every)`` of a fixed-step run given its number of steps."""
    return (_get_scheme(scheme),) + _step_arguments(dt, n_steps, save_every)


def _step_arguments(dt, n_steps, save_every):
    """Checked ``(dt, n_steps, save_every)``: :func:`run_arguments` of a run whose scheme is an object already."""
    dt = positive_number(dt, "dt", "the step must be a positive finite number")
    if isinstance(n_steps, (bool, np.bool_)) or int(n_steps) != n_steps or int(n_steps) < 0:
        raise ValueError(f"n_steps: must be a non-negative integer, got {n_steps!r}")
    return dt, int(n_steps), positive_int(save_every, "save_every")


def _get_scheme(scheme):
    from . import get_scheme

    return get_scheme(scheme)


def integrate(f, y0, dt, n_steps, scheme="euler", *, t0=0.0, save_every=1, names=(), check_every=1, on_failure=None,
              out=None):
    """Step ``y' = f(y)`` with a fixed-step explicit scheme, batch-first.

    Parameters
    ----------
    f : callable
        Batch-first vector field ``(..., n) -> (..., n)``.
    y0 : array_like (..., n)
        Initial state(s).
    dt : float
        Step, positive.
    n_steps : int
        Number of steps.
    scheme : str or ExplicitRungeKutta
    save_every : int
        Keep every ``save_every``-th state (the last one is always kept).
    names : sequence of str
        Component names, for error messages and ``Solution[name]``.
    check_every : int
        Check for non-finite numbers every this many steps (1: every step).
    on_failure : callable, optional
        ``on_failure(y_last_finite, t, step) -> str``: extra advice appended to
        the error message (e.g. a stability estimate).
    out : ndarray (..., n, n_saved), optional
        Where to write the saved states (e.g. a slice of a larger buffer: no copy).

    Raises
    ------
    IntegrationError
        At the first check that finds a non-finite number: no NaN is returned.
    """
    return step_loop(f, y0, dt, n_steps, _get_scheme(scheme), t0=t0, save_every=save_every, names=names,
                     check_every=check_every, on_failure=on_failure, out=out)


def step_loop(f, y0, dt, n_steps, sch, *, t0=0.0, save_every=1, names=(), check_every=1, on_failure=None, out=None):
    """:func:`integrate` with its scheme resolved: ``sch`` a stepper object (``step(f, y, dt)``, ``name``,
    ``stages``), never a name.  The run loop (:mod:`liefi.integrator.run`) steps its numpy segments here, with the
    scheme it resolved once."""
    dt, n_steps, save_every = _step_arguments(dt, n_steps, save_every)
    y = np.array(y0, dtype=float)
    if not np.all(np.isfinite(y)):
        raise ValueError("y0: the initial state contains non-finite numbers")
    idx = list(range(0, n_steps + 1, save_every))
    if idx[-1] != n_steps:
        idx.append(n_steps)
    if out is None:
        out = np.empty(y.shape + (len(idx),))
    elif out.shape != y.shape + (len(idx),):
        raise ValueError(f"out: expected shape {y.shape + (len(idx),)}, got {out.shape}")
    out[..., 0] = y
    k = 1
    last_good, last_good_step = y, 0
    start = time.process_time()
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for i in range(1, n_steps + 1):
            try:
                y = sch.step(f, y, dt)
            except np.linalg.LinAlgError as exc:  # a solve of the field met a singular matrix: the run diverged
                _fail(y, last_good, last_good_step, i, t0, dt, sch, names, on_failure,
                      what=f"could not be evaluated (a linear solve found a {str(exc).lower() or 'singular matrix'})")
            if i % check_every == 0 or i == n_steps:
                if not np.all(np.isfinite(y)):
                    _fail(y, last_good, last_good_step, i, t0, dt, sch, names, on_failure)
                last_good, last_good_step = y, i
            if k < len(idx) and i == idx[k]:
                out[..., k] = y
                k += 1
    cpu = time.process_time() - start
    t = t0 + dt * np.array(idx, dtype=float)
    return Solution(t, out, sch.name, dt, n_steps, n_steps * sch.stages, cpu, tuple(names))


def _fail(y, last_good, last_good_step, i, t0, dt, sch, names, on_failure, what=""):
    """Raise the :class:`IntegrationError` of step ``i``: non-finite values in ``y``, or (``what``) a field that
    could not be evaluated there."""
    bad = ~np.isfinite(y)
    comp = np.nonzero(bad.reshape(-1, y.shape[-1]).any(axis=0))[0]
    labels = [] if what else [names[c] if c < len(names) else str(c) for c in comp]
    msg = f"integration with {sch.name} (dt={dt:g}) {failure_words(what, i, t0 + dt * i, labels)}; the last " \
          f"finite state is at t={t0 + dt * last_good_step:g}."
    if on_failure is not None:
        msg += " " + on_failure(last_good, t0 + dt * last_good_step, i)
    else:
        msg += " The step is probably beyond the scheme's stability limit: reduce dt or the gains."
    raise IntegrationError(msg, t0 + dt * last_good_step, i, last_good, labels, what)


def failure_words(what, step, t, components):
    """What went wrong at ``step`` (time ``t``), in the words of an :class:`IntegrationError`'s message."""
    if what:
        return f"diverged: the field {what} at step {step} (t={t:g}), its state left the data's domain"
    return f"produced non-finite values at step {step} (t={t:g}) in components {list(components)}"
