r"""Sensitivities of a forced run with respect to its control values: ``d y(t) / d u_j``.

A forced run (:mod:`liefi.integrator.forced`) with an input ``u`` given as
:func:`~liefi.systems.forcing.piecewise_constant` or :func:`~liefi.systems.forcing.spline`
over a grid of ``N`` values ``u_j`` is, step by step, the map

.. math:: y_{s+1} = \Phi(y_s, t_s; u), \qquad y_0 \text{ fixed},

the scheme's tableau on the extended forced field (every stage reads ``u`` at its own
time ``t_s + c_i dt``) then, for a split scheme, the linearly implicit feedback step.
``fi.run(..., sensitivities=("tau",))`` gives ``sol.sensitivities["tau"]``, shape
``(n, N, n_t)``: ``[i, j, k] = d y_i(t_k) / d u_j``, the derivative of the saved states
liefi returned (the work ``W`` and the clock included; the clock's row is zero), with
the step ``dt``, the gains and the targets of ``V`` held (the targets are taken at
``y0``, which the controls do not move).  These are **discrete** sensitivities: the
tangent recursion

.. math:: S_{s+1} = \partial_y \Phi\, S_s + \partial_u \Phi, \qquad S_0 = 0,

solved exactly, not a discretization of the continuous variational equation.

**How: a complex step through the numpy step.**  Each direction ``j`` is one member of
an ensemble run of the *same* step function on complex states, started at ``y_0`` with
the input's values ``u + i h e_j`` (``h = 1e-30``); then ``y_s = Re + i h S_s e_j`` up
to ``O(h^2)``, i.e. ``Im(y_s)/h`` is the tangent of the recursion above, exact to rounding:
a complex step has no subtraction, so ``h`` can be far below the rounding unit and the
truncation ``O(h^2 |Phi'''|)`` vanishes.  The ``N`` directions run as one batch of ``N``
members, so the cost is about that of one ensemble run of ``N`` members.  Chosen over a
traced forward mode (:mod:`liefi.integrator.sensitivity`) because a user's force and
its signal are plain numpy and cannot be traced; chosen over finite differences
because those give half the digits and need a step to tune.

Requirements, each refused with a message: every x-dependent datum of the system
(metric, constraints, potential) carries its **analytic derivative**
(``metric_derivative=``, ``constraints_derivative=``, ...), or is constant -- otherwise
the field differentiates the data by a complex step of its own and two nested complex
steps are not exact; the force is complex-step safe in ``v`` and ``u`` (no ``abs``,
no ``.real``, no in-place fill into a float array); fixed gains (no gain updates along
the run); a step ``dt`` that divides the span; no ``t_eval``, ``dense_output``, ``events``.
"""

from __future__ import annotations

import copy
import time

import numpy as np

#: the imaginary step (any number far below the rounding unit of the states works)
STEP = 1e-30
#: the complex replay's real part must match the run's saved states to this (relative)
REPLAY_RTOL = 1e-8


def _complex_signal(sig, name):
    """The signal ``sig`` over its grid with values ``u + i STEP e_j`` for member ``j`` (one member per value)."""
    kind = getattr(sig, "grid_kind", None)
    if kind is None:
        raise ValueError(f"sensitivities: the input {name!r} is {sig.what}; sensitivities are taken with respect to "
                         "the values of a piecewise_constant or spline signal (liefi.systems.forcing)")
    grid, values = sig.t_grid, np.asarray(sig.values, float)
    if values.ndim != 1:
        raise ValueError(f"sensitivities: the input {name!r} must be scalar, values of shape {values.shape}")
    N = values.size
    V = values[:, None] + 1j * STEP * np.eye(N)  # (N, members)
    members = np.arange(N)
    if kind == "piecewise":
        starts = grid[:N]

        def value(t):
            t = np.real(np.asarray(t))
            idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, N - 1)
            return V[idx, np.broadcast_to(members, idx.shape)]
    else:
        from scipy.interpolate import CubicSpline

        cs = CubicSpline(grid, V, axis=0, bc_type=sig.bc_type)

        def value(t):
            t = np.real(np.asarray(t))
            return cs(t)[..., members, members] if t.ndim else cs(t)

    return value


def check(fi, names, *, t_eval=None, events=None, dense_output=False):
    """The input names of ``names`` (a tuple), or a ``ValueError`` naming what is not supported."""
    if isinstance(names, str):
        names = (names,)
    names = tuple(names)
    unknown = [s for s in names if s not in fi.signals]
    if unknown:
        raise ValueError(f"sensitivities: {unknown} are not inputs of this forced run; a forced run gives "
                         f"sensitivities with respect to its inputs' values: {list(fi.signals)} (the start and "
                         "the constants are not supported for forced runs yet)")
    if len(set(names)) != len(names):
        raise ValueError(f"sensitivities: names repeated in {names}")
    if t_eval is not None or events is not None or dense_output:
        raise ValueError("sensitivities: not available with t_eval=, events= or dense_output= (the states between "
                         "steps); take them at the saved steps")
    if np.asarray(fi.y0).ndim != 1:
        raise ValueError("sensitivities: an ensemble y0 of shape (B, n) is not supported; run one start")
    for s in names:
        _complex_signal(fi.signals[s], s)  # a signal without a grid named now
    return names


def attach(sol, fi, names, *, scheme, dt, t0):
    """Set ``sol.sensitivities`` for the forced run ``sol`` of ``fi`` (module docstring)."""
    from ..schemes import registry

    if not sol.success:
        sol.sensitivities = None
        return sol
    start = time.process_time()
    rep = sol.stability
    if rep is not None and getattr(rep, "gain_history", None):
        raise ValueError("sensitivities: the run's gains changed along the way; pass adaptive=False (or fixed gains)")
    steps = (np.asarray(sol.t) - t0) / dt
    saved = np.rint(steps).astype(int)
    if np.any(np.abs(steps - saved) > 1e-9 * np.maximum(1.0, saved)):
        raise ValueError("sensitivities: the run ended with a step shortened to reach t_final (dt does not divide the "
                         "span); take a dt that divides it")
    run_fi = fi  # the integrator that ran: the invariants it left out of V (kept exactly), its resolved gains
    if getattr(sol, "dropped", None):
        run_fi = fi.without({d["name"]: d["reason"] for d in sol.dropped})
    if rep is not None and getattr(rep, "gains", None) and getattr(fi, "gains_mode", "fixed") != "fixed":
        run_fi = run_fi.with_gains(rep.gains)
    sch = registry.get(scheme).bind(run_fi) if hasattr(registry.get(scheme), "bind") else registry.get(scheme)
    sens = {}
    n_steps = int(saved[-1])
    for name in names:
        N = np.asarray(fi.signals[name].values).shape[0]
        cfi = copy.copy(run_fi)
        cfi.signals = dict(run_fi.signals)
        cfi.signals[name] = _complex_signal(run_fi.signals[name], name)
        bound = sch.with_integrator(cfi) if hasattr(sch, "with_integrator") else sch
        y = np.broadcast_to(np.asarray(sol.y[:, 0], complex), (N, fi.n)).copy()
        out = np.empty((fi.n, N, saved.size), complex)
        j = 0
        if saved[0] == 0:
            out[..., 0], j = y.T, 1
        try:
            for s in range(1, n_steps + 1):
                y = bound.step(cfi.vector_field, y, dt)
                while j < saved.size and saved[j] == s:
                    out[..., j] = y.T
                    j += 1
        except TypeError as exc:
            raise ValueError(f"sensitivities: the complex step through the forced run failed: {exc}; every "
                             "x-dependent datum of the system needs its analytic derivative "
                             "(metric_derivative=, constraints_derivative=, potential_gradient=)") from None
        ref = np.asarray(sol.y, float)
        scale = np.maximum(1.0, np.max(np.abs(ref), axis=-1, keepdims=True))
        err = float(np.max(np.abs(out.real - ref[:, None, :]) / scale[:, None, :], initial=0.0))
        if not err <= REPLAY_RTOL:
            raise ValueError(f"sensitivities: the complex replay of the run differs from its saved states by "
                             f"{err:.3g} (relative); the force or a datum is not complex-step safe (abs, .real, "
                             "a fill into a float array), or the run changed along the way")
        sens[name] = out.imag / STEP
    sol.sensitivities = sens
    sol.sensitivity_cpu_seconds = time.process_time() - start
    return sol
