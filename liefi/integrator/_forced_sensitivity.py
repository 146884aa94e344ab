r"""Sensitivities of a forced run: ``d y(t) / d u_j`` (its control values), ``d y(t) / d y0`` and ``d y(t) / d theta``.

A forced run (:mod:`liefi.integrator.forced`) with an input ``u`` given as
:func:`~liefi.systems.forcing.piecewise_constant` or :func:`~liefi.systems.forcing.spline`
over a grid of ``N`` values ``u_j`` is, step by step, the map

.. math:: y_{s+1} = \Phi(y_s, t_s; u), \qquad y_0 \text{ fixed},

the scheme's tableau on the extended forced field (every stage reads a spline at its own
time ``t_s + c_i dt``, a piecewise-constant input at the step's midpoint: held over the step) then, for a split scheme, the linearly implicit feedback step.
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

**The start and the constants.**  ``sensitivities=("y0", "m", ...)`` on a forced run gives, as
for a conservative run (:mod:`liefi.integrator.sensitivity`), ``sol.sensitivities["y0"]`` of shape
``(n, n, n_t)`` (rows ``y``, columns ``y0``; ``n`` counts ``W`` and the clock: the clock's column
is the derivative with respect to the time the clock starts from, the inputs' timing) and, for a
constant ``theta`` of :func:`~liefi.mechanics.from_mechanics` (or one declared on data built by
hand), ``sol.sensitivities["m"]`` of shape ``(n, n_t)``.  The recursion is

.. math:: S_{s+1} = \partial_y \Phi\, S_s + \partial_p \Phi\, P' + \partial_\theta \Phi\, \Theta',
          \qquad S_0 = \partial y_0, \quad P' = \partial p(y_0, \theta),

with the step and the gains held and the targets of ``V`` that were taken at the start (the
balance ``h~ - W`` at ``y0``, the user invariants) moving with ``y0`` and ``theta``, as a new
integrator built at the perturbed start would take them.  The invariants the run left out of
``V`` because the scheme keeps them exactly on the invariant set (``sol.dropped``) stay left
out, as the gains stay held: a run from a start off such an invariant would keep it in ``V``
(compare with ``drop_exact=False`` runs).  Same complex step: the ``n`` columns of
``y0`` and the constants (a from_mechanics model's constants per member) are the members of one
ensemble, started at ``y0 + i h e_j`` with the targets evaluated there, or with the constants
``theta + i h e_k`` (the model's force reads them too: a damper's ``c``).

**Data without an analytic derivative** (a :func:`~liefi.mechanics.from_mechanics` model's
lambdified data; a scene built without ``analytic_derivatives=True``).  The field differentiates
such a datum by a complex step of its own, and two nested complex steps are not exact (the
inner one drops the outer one's imaginary part).  For the replay only, such a datum's first
derivative is taken by the 8th-order central difference :func:`central_derivative` (relative
step :data:`FD_STEP`, truncation ``O(FD_STEP^8)``, rounding ``O(eps / FD_STEP)``: about
``1e-13`` relative), which is linear in the datum's values and so carries the outer complex
step exactly: the sensitivities are then those of a run whose data derivatives differ from the
run's own by that much.  Data with an analytic derivative, and constant data, are used as they are.

Requirements, each refused with a message: the force is complex-step safe in ``v`` and ``u`` (no ``abs``,
no ``.real``, no in-place fill into a float array); fixed gains (no gain updates along
the run); a step ``dt`` that divides the span; no ``t_eval``, ``dense_output``, ``events``.
"""

from __future__ import annotations

import contextlib
import copy
import time

import numpy as np

from .. import _members

#: the imaginary step (any number far below the rounding unit of the states works)
STEP = 1e-30
#: the complex replay's real part must match the run's saved states to this (relative)
REPLAY_RTOL = 1e-8
#: relative step of :func:`central_derivative`, and its 8th-order central weights (offsets 1..4)
FD_STEP = 1e-2
FD_WEIGHTS = (4.0 / 5.0, -1.0 / 5.0, 4.0 / 105.0, -1.0 / 280.0)


def central_derivative(datum):
    """``derivative(x) -> (..., n, *shape)`` of a :class:`~liefi._data.DataFunction` by the 8th-order central
    difference ``sum_k w_k (f(x + k h e_i) - f(x - k h e_i)) / h``, ``h = FD_STEP max(1, |Re x_i|)`` (module
    docstring): linear in ``f``, so a complex ``x`` (the replay's complex step) gets the derivative's tangent."""
    n, shape = datum.n, datum.shape

    def derivative(x):
        x = np.asarray(x)
        h = FD_STEP * np.maximum(1.0, np.abs(x.real))  # (..., n)
        out = 0.0
        eye = np.eye(n).reshape((n,) + (1,) * (x.ndim - 1) + (n,))
        for k, w in enumerate(FD_WEIGHTS, 1):
            E = eye * (k * h)  # (n, ..., n): slice i moves x_i (the directions first: per-member constants last)
            out = out + w * (datum.fun(x + E) - datum.fun(x - E))
        out = np.moveaxis(out, 0, x.ndim - 1)  # (..., n, *shape)
        return out / h.reshape(h.shape + (1,) * len(shape))

    return derivative


@contextlib.contextmanager
def differentiated_data(system):
    """Inside, every x-dependent datum of ``system`` without an analytic derivative has :func:`central_derivative`
    (module docstring); restored on exit."""
    data = [getattr(system, a, None) for a in ("metric", "constraints", "potential", "vector_potential")]
    missing = [f for f in data if f is not None and not f.constant and getattr(f, "_derivative", None) is None]
    for f in missing:
        f._derivative = central_derivative(f)
    try:
        yield
    finally:
        for f in missing:
            f._derivative = None


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
    """The names of ``names`` (a tuple: inputs, ``"y0"``, constants), or a ``ValueError`` naming what is not
    supported."""
    from .sensitivity import parameter_names

    if isinstance(names, str):
        names = (names,)
    names = tuple(names)
    known = tuple(fi.signals) + ("y0",) + tuple(parameter_names(fi.system))
    unknown = [s for s in names if s not in known]
    if unknown:
        raise ValueError(f"sensitivities: {unknown} are neither inputs of this forced run nor 'y0' nor constants of "
                         f"its system; a forced run gives sensitivities with respect to its inputs' values "
                         f"{list(fi.signals)}, its start 'y0' and its system's constants "
                         f"{list(parameter_names(fi.system))}")
    if len(set(names)) != len(names):
        raise ValueError(f"sensitivities: names repeated in {names}")
    if t_eval is not None or events is not None or dense_output:
        raise ValueError("sensitivities: not available with t_eval=, events= or dense_output= (the states between "
                         "steps); take them at the saved steps")
    if np.asarray(fi.y0).ndim != 1:
        raise ValueError("sensitivities: an ensemble y0 of shape (B, n) is not supported; run one start")
    for s in names:
        if s in fi.signals:
            _complex_signal(fi.signals[s], s)  # a signal without a grid named now
    return names


def _start_parameters(fi, Y, y0):
    """The parameter vector of ``fi`` per member of the complex starts ``Y`` (``(B, n)``): gains held, the targets
    that ``fi`` took at the run's start ``y0`` evaluated at ``Y`` (with the constants in effect), others held."""
    from ..reduction import core as _core

    lay = fi.parameter_layout
    p = np.asarray(fi.parameters(), float)
    slots = ([lay.energy_target] if fi.use_energy else []) + list(lay.user_target)
    if not slots:
        return p
    out = np.broadcast_to(p, Y.shape[:-1] + p.shape[-1:]).astype(complex)
    zero = out.copy()
    zero[..., slots] = 0.0
    nz = fi.system.space.nz
    for Ys, ps, dest in ((np.asarray(y0, float)[None], zero[:1].real, None), (Y, zero, out)):
        _, z = fi.split(Ys)
        # the start alone: with the first member's constants of the complex ensemble (those of the run, to the
        # complex step's O(h^2)), its per-member constants (liefi._members) being the tangents'
        with _members.selected(Y.shape[:-1], 0) if dest is None else contextlib.nullcontext():
            terms = fi.invariant_terms(z, _core.evaluate(fi.system, z[..., :nz]), ps)
        vals = [r for name, r, _, _ in terms if name == "energy" or name in {u.name for u in fi.user}]
        if dest is None:  # which targets are the start's values (a given target, or another start: held)
            follow = [abs(complex(v[0]).real - p[sl]) <= 1e-12 * max(1.0, abs(p[sl])) for v, sl in zip(vals, slots)]
        else:
            for v, sl, f in zip(vals, slots, follow):
                if f:
                    dest[..., sl] = v
    return out


def _replay(bound, cfi, Y, dt, saved, n_steps, sol):
    """The complex states ``(n, B, n_t)`` of ``n_steps`` steps of ``bound`` on ``cfi`` from ``Y`` (``(B, n)``), at the
    steps ``saved``; their real part checked against the run's states ``sol.y`` (:data:`REPLAY_RTOL`)."""
    y = Y
    out = np.empty((cfi.n, Y.shape[0], saved.size), complex)
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
        raise ValueError(f"sensitivities: the complex step through the forced run failed: {exc}; the force and "
                         "every datum must be complex-step safe (no abs, .real, or fill into a float array)") from None
    ref = np.asarray(sol.y, float)
    scale = np.maximum(1.0, np.max(np.abs(ref), axis=-1, keepdims=True))
    err = float(np.max(np.abs(out.real - ref[:, None, :]) / scale[:, None, :], initial=0.0))
    if not err <= REPLAY_RTOL:
        raise ValueError(f"sensitivities: the complex replay of the run differs from its saved states by "
                         f"{err:.3g} (relative); the force or a datum is not complex-step safe (abs, .real, "
                         "a fill into a float array), or the run changed along the way")
    return out


def _start_and_constants(bound_for, run_fi, sol, wanted, dt, saved, n_steps):
    """``{name: tangent}`` for ``"y0"`` and the constants in ``wanted``: one complex ensemble (module docstring);
    a from_mechanics model's constants per member, declared parameters one run each."""
    from .sensitivity import _holder, parameter_names

    n, y0 = run_fi.n, np.asarray(sol.y[:, 0], float)
    consts = [s for s in wanted if s != "y0"]
    holder = _holder(run_fi.system)
    per_member = holder is not None and hasattr(holder, "aligned")  # from_mechanics: constants per member
    groups = [(["y0"] if "y0" in wanted else []) + (consts if per_member else [])] + \
        ([] if per_member else [[c] for c in consts])
    names_all = list(parameter_names(run_fi.system))
    result = {}
    for group in groups:
        if not group:
            continue
        k_y = n if group[0] == "y0" else 0
        cs = group[1:] if k_y else group
        B = k_y + len(cs)
        Y = np.broadcast_to(y0, (B, n)).astype(complex)
        Y[:k_y] += 1j * STEP * np.eye(n)
        old = None
        if cs:
            old = holder.values
            c = np.asarray(old, float)
            if per_member:
                C = np.broadcast_to(c, (B, c.size)).astype(complex)
                for r, nm in enumerate(cs):
                    C[k_y + r, names_all.index(nm)] += 1j * STEP
            else:
                C = c.astype(complex)
                C[names_all.index(cs[0])] += 1j * STEP
        try:
            if cs:
                holder.values = C
            cfi = copy.copy(run_fi)
            cfi._parameters = _start_parameters(run_fi, Y, y0)
            S = _replay(bound_for(cfi), cfi, Y, dt, saved, n_steps, sol).imag / STEP  # (n, B, n_t)
        finally:
            if old is not None:
                holder.values = old
        if k_y:
            result["y0"] = S[:, :n, :]
        for r, nm in enumerate(cs):
            result[nm] = S[:, k_y + r, :]
    return result


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

    def bound_for(cfi):
        return sch.with_integrator(cfi) if hasattr(sch, "with_integrator") else sch

    with differentiated_data(fi.system):
        _tangents(sens, fi, run_fi, sol, names, bound_for, dt, saved, n_steps)
    sol.sensitivities = {name: sens[name] for name in names}
    sol.sensitivity_cpu_seconds = time.process_time() - start
    return sol


def _tangents(sens, fi, run_fi, sol, names, bound_for, dt, saved, n_steps):
    """Fill ``sens`` with the tangents of ``names`` (:func:`attach`)."""
    for name in names:
        if name not in fi.signals:
            continue
        N = np.asarray(fi.signals[name].values).shape[0]
        cfi = copy.copy(run_fi)
        cfi.signals = dict(run_fi.signals)
        cfi.signals[name] = _complex_signal(run_fi.signals[name], name)
        y = np.broadcast_to(np.asarray(sol.y[:, 0], complex), (N, fi.n)).copy()
        sens[name] = _replay(bound_for(cfi), cfi, y, dt, saved, n_steps, sol).imag / STEP
    rest = [s for s in names if s not in fi.signals]
    if rest:
        sens.update(_start_and_constants(bound_for, run_fi, sol, rest, dt, saved, n_steps))
