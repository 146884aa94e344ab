"""Explicit Runge--Kutta schemes as Butcher tableaux, and a batch-first fixed-step driver.

A scheme is data (:class:`ExplicitRungeKutta`); :func:`integrate` steps any
batch-first vector field ``f(y)`` (``(..., n) -> (..., n)``) with it, checks
every step for non-finite numbers and reports where they appeared.  For
adaptive or implicit integration use ``scipy.integrate.solve_ivp`` with the
``fun(t, y)`` of a :class:`~liefi.FeedbackIntegrator`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ExplicitRungeKutta:
    """An explicit Runge--Kutta scheme ``(A, b, c)``.

    Attributes
    ----------
    name : str
    A : tuple of tuples (strictly lower triangular), b, c : tuples
    order : int
        Classical order of accuracy.
    real_stability_bound : float
        ``beta`` such that ``y' = -L y`` is stable for ``0 <= L dt <= beta``
        (the stability region's extent on the negative real axis).
    """

    name: str
    A: tuple
    b: tuple
    c: tuple
    order: int
    real_stability_bound: float

    @property
    def stages(self):
        return len(self.b)

    def step(self, f, y, dt):
        """One step ``y -> y + dt sum_i b_i k_i``."""
        ks = []
        for i in range(self.stages):
            yi = y
            for j, a in enumerate(self.A[i][:i]):
                if a:
                    yi = yi + (dt * a) * ks[j]
            ks.append(f(yi))
        out = y
        for bi, k in zip(self.b, ks):
            if bi:
                out = out + (dt * bi) * k
        return out

    def stability_polynomial(self, z):
        """``R(z)`` with ``y_{n+1} = R(dt L) y_n`` for ``y' = L y``."""
        A = np.array([list(r) + [0.0] * (self.stages - len(r)) for r in self.A])
        b = np.array(self.b)
        z = np.asarray(z, dtype=complex)
        out = np.empty_like(z)
        for idx, zi in np.ndenumerate(z):
            out[idx] = 1 + zi * b @ np.linalg.solve(np.eye(self.stages) - zi * A, np.ones(self.stages))
        return out


EULER = ExplicitRungeKutta("euler", ((),), (1.0,), (0.0,), 1, 2.0)
HEUN = ExplicitRungeKutta("heun", ((), (1.0,)), (0.5, 0.5), (0.0, 1.0), 2, 2.0)
MIDPOINT = ExplicitRungeKutta("midpoint", ((), (0.5,)), (0.0, 1.0), (0.0, 0.5), 2, 2.0)
RK3 = ExplicitRungeKutta("rk3", ((), (0.5,), (-1.0, 2.0)), (1 / 6, 2 / 3, 1 / 6), (0.0, 0.5, 1.0), 3, 2.5127453266183286)
RK4 = ExplicitRungeKutta(
    "rk4", ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)), (1 / 6, 1 / 3, 1 / 3, 1 / 6), (0.0, 0.5, 0.5, 1.0), 4, 2.785293563405282
)

#: The fixed-step schemes by name.
SCHEMES = {s.name: s for s in (EULER, HEUN, MIDPOINT, RK3, RK4)}


def get_scheme(scheme) -> ExplicitRungeKutta:
    """A scheme from its name (``"euler"``, ``"heun"``, ``"midpoint"``, ``"rk3"``, ``"rk4"``) or itself."""
    if isinstance(scheme, ExplicitRungeKutta):
        return scheme
    if callable(getattr(scheme, "step", None)) and hasattr(scheme, "stages") and hasattr(scheme, "name"):
        return scheme  # a stepper object, e.g. a split scheme of liefi.stiff bound to an integrator
    try:
        return SCHEMES[str(scheme).lower()]
    except KeyError:
        raise ValueError(
            f"scheme: unknown scheme {scheme!r}; choose one of {sorted(SCHEMES)} "
            "(or, with a FeedbackIntegrator, 'imex-euler', 'imex-heun', 'imex-rk4')"
        ) from None


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
    """

    def __init__(self, message, t, step, y, components):
        super().__init__(message)
        self.t, self.step, self.y, self.components = t, step, y, components


@dataclass
class Solution:
    """Result of :func:`integrate`, in scipy's layout: time on the last axis.

    Attributes
    ----------
    t : ndarray (n_t,)
    y : ndarray (..., n, n_t)
    scheme : str
    dt : float
    steps : int
    rhs_evaluations : int
    cpu_seconds : float
        Process time of the stepping loop.
    """

    t: np.ndarray
    y: np.ndarray
    scheme: str
    dt: float
    steps: int
    rhs_evaluations: int
    cpu_seconds: float
    names: tuple = field(default=())

    def __getitem__(self, name):
        """The trajectory of the component called ``name``, shape ``(..., n_t)``."""
        try:
            return self.y[..., self.names.index(name), :]
        except ValueError:
            raise KeyError(f"{name!r}: not a component; components are {self.names}") from None


def run_arguments(scheme, dt, n_steps, save_every):
    """Checked ``(scheme, dt, n_steps, save_every)`` of a fixed-step run (shared by every engine)."""
    sch = get_scheme(scheme)
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt: the step must be a positive finite number, got {dt!r}")
    n_steps = int(n_steps)
    if n_steps < 0:
        raise ValueError(f"n_steps: must be non-negative, got {n_steps}")
    return sch, dt, n_steps, max(1, int(save_every))


def integrate(f, y0, dt, n_steps, scheme="euler", *, t0=0.0, save_every=1, names=(), check_every=1, on_failure=None):
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

    Raises
    ------
    IntegrationError
        At the first check that finds a non-finite number: no NaN is returned.
    """
    sch, dt, n_steps, save_every = run_arguments(scheme, dt, n_steps, save_every)
    y = np.array(y0, dtype=float)
    if not np.all(np.isfinite(y)):
        raise ValueError("y0: the initial state contains non-finite numbers")
    idx = list(range(0, n_steps + 1, save_every))
    if idx[-1] != n_steps:
        idx.append(n_steps)
    out = np.empty(y.shape + (len(idx),))
    out[..., 0] = y
    k = 1
    last_good, last_good_step = y, 0
    start = time.process_time()
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for i in range(1, n_steps + 1):
            y = sch.step(f, y, dt)
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


def _fail(y, last_good, last_good_step, i, t0, dt, sch, names, on_failure):
    bad = ~np.isfinite(y)
    comp = np.nonzero(bad.reshape(-1, y.shape[-1]).any(axis=0))[0]
    labels = [names[c] if c < len(names) else str(c) for c in comp]
    t_fail = t0 + dt * i
    msg = (
        f"integration with {sch.name} (dt={dt:g}) produced non-finite values at step {i} "
        f"(t={t_fail:g}) in components {labels}; the last finite state is at t={t0 + dt * last_good_step:g}."
    )
    if on_failure is not None:
        msg += " " + on_failure(last_good, t0 + dt * last_good_step, i)
    else:
        msg += " The step is probably beyond the scheme's stability limit: reduce dt or the gains."
    raise IntegrationError(msg, t0 + dt * last_good_step, i, last_good, labels)
