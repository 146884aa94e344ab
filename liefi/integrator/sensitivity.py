r"""Forward discrete sensitivities of a run: ``d y(t) / d y0`` and ``d y(t) / d theta``, exact to rounding.

``fi.run(T, dt=..., sensitivities=("y0", "m"))`` gives ``sol.sensitivities[name]``:
the derivative of the *saved states liefi returned* with respect to the start
``y0`` (shape ``(n, n, n_t)``, rows ``y``, columns ``y0``) or to a parameter
(shape ``(n, n_t)``).  The parameters are the runtime constants of a system built
by :func:`liefi.mechanics.from_mechanics` (:attr:`MechanicsSystem.constants`), or those declared on
data built by hand (:mod:`liefi.systems.parameters`).

**Discrete sensitivities.**  A fixed-step run is the composition of one map,
``y_{s+1} = Phi(y_s; p, theta, dt)``, with ``p`` the feedback parameters (gains
and targets, :meth:`liefi.FeedbackIntegrator.parameters`) and ``theta`` the
system's constants.  The step ``dt`` and the gains are held fixed (the gains that
``gains="auto"`` chose are resolved once, before the run, and are a number of the
run, not a function of ``y0``); the *targets* (the energy ``h~(y0; theta)``, the
user invariants, the attitude Casimirs) are taken at the start and move with it.
The chain rule through the steps is

.. math:: S_{s+1} = \partial_y \Phi\, S_s + \partial_p \Phi\, P' + \partial_\theta \Phi\, \Theta',
          \qquad S_0 = \partial y_0, \quad P' = \partial p(y_0, \theta),

with ``S_s`` the ``n x k`` tangents of the ``k`` directions (``k = n`` for ``"y0"``, one per
parameter).  For a split scheme (``imex-*``, :mod:`liefi.schemes.split`) the map is the
tableau on the extended field ``X``, then the linearly implicit feedback step
``F(y_*) = y_* - dt A W^T mu``, ``(I + dt K W A W^T) mu = K r``, so the tangent of one step is

.. math:: \dot k_i = \partial X(Y_i)\, \dot Y_i + \partial_\theta X(Y_i)\, \dot\theta, \quad
          \dot Y_i = \dot y + dt \sum_j a_{ij} \dot k_j, \quad
          \dot y_* = \dot y + dt \sum_i b_i \dot k_i,

.. math:: \dot y_+ = \dot y_* - dt A (\dot W^T \mu + W^T \dot\mu), \quad
          (I + dt K W A W^T)\, \dot\mu = K \dot r - dt K (\dot W A W^T + W A \dot W^T) \mu,

``r_j = I_j(y_*) - I_{j0}`` with ``\dot r_j = \nabla I_j \cdot \dot y_* + \partial_\theta I_j
\dot\theta - \dot I_{j0}`` and ``\dot W`` the second derivatives of the invariants.

**How they are computed.**  The step map is traced once on symbolic arrays (the
engine's tracer, :mod:`liefi.engine.trace`, the same trace as the compiled kernels:
:meth:`~liefi.FeedbackIntegrator.vector_field`, or
:meth:`~liefi.FeedbackIntegrator.unforced_vector_field` and
:func:`~liefi.schemes.split.feedback_step`) at ``y + sum_j e_j v_j``, ``p + sum_j e_j w_j``,
``theta + sum_j e_j c_j``; the exact symbolic derivative of that graph in ``e_j`` at
``e = 0`` is the Jacobian--vector product of the step in direction ``j`` -- the
formulas above, every stage and the feedback step included, with the data's second
derivatives traced too.  Compiled (``engine="numba"``), one generated loop advances the state and its
``k`` tangents together, every node's tangent printed next to its value
(:mod:`liefi.integrator._tangent_loop`, :func:`fused_kernel`); on the numpy path the generated
Jacobians of the step are multiplied by the tangents (:func:`_step`).  :func:`propagate` steps them.  A complex step through the numpy step
would not be exact: the field differentiates the data by complex step itself
(``DataFunction.with_derivative``), and two nested complex steps are not exact (the
numpy field refuses complex states with ``x``-dependent data for that reason).

The replay's states are compared with the run's saved states: they agree to
rounding, or the run changed something the replay does not see (gains adapted
along the run: pass ``adaptive=False``) and a ``ValueError`` says so.
"""

from __future__ import annotations

import time
import weakref

import numpy as np

#: the replay's states must match the run's saved ones to this (relative to each state's size)
REPLAY_RTOL = 1e-8

#: the tangent kernels built in this process: (system id, integrator layout, engine) -> (weak system, kernel)
_KERNELS: dict = {}


def _holder(system):
    """The object whose ``values`` the system's data read: the constants of
    :func:`~liefi.mechanics.from_mechanics`, or the :class:`~liefi.systems.parameters.Parameters` declared
    on data built by hand (:func:`~liefi.systems.parameters.declare`); ``None`` without parameters."""
    mech = getattr(system, "_mech", None)
    if mech is not None:
        return mech["constants"]
    return getattr(system, "declared_parameters", None)


def parameter_names(system):
    """The names that ``sensitivities=`` accepts for ``system`` besides ``"y0"``: its runtime constants, or
    the parameters declared on its data (:mod:`liefi.systems.parameters`)."""
    declared = getattr(system, "declared_parameters", None)
    names = getattr(system, "constant_names", None) if declared is None else declared.names
    try:
        return tuple(str(s) for s in names) if names is not None else ()
    except (TypeError, KeyError):
        return ()


def check(fi, sensitivities, *, t_eval=None, events=None, dense_output=False, y0=None, what="sensitivities"):
    """The checked tuple of names of ``sensitivities=`` (``None`` or empty: ``()``); a clear error otherwise.

    Before the run (:meth:`liefi.FeedbackIntegrator.run`): the names, and the run's options the
    sensitivities do not cover (the states between steps of ``t_eval``, ``dense_output`` and
    ``events``, an ensemble) are refused with what to do instead.  ``what`` names the argument in the
    messages (the adjoint's checks, :mod:`liefi.integrator.adjoint`, are these).
    """
    if sensitivities is None:
        return ()
    if isinstance(sensitivities, str):
        sensitivities = (sensitivities,)
    try:
        names = tuple(sensitivities)
    except TypeError:
        raise TypeError(f"{what}: expected a sequence of names (e.g. ('y0', 'm')), got {sensitivities!r}") \
            from None
    known = ("y0",) + parameter_names(fi.system)
    for nm in names:
        if not isinstance(nm, str) or nm not in known:
            extra = (f"the system's parameters are {list(known[1:])}" if len(known) > 1 else
                     "this system declares no parameters (the constants of liefi.mechanics.from_mechanics are; "
                     "declare them on data built by hand with liefi.systems.parameters.declare)")
            raise ValueError(f"{what}: unknown name {nm!r}; use 'y0' (d y / d y0) or a parameter; {extra}")
    if len(set(names)) != len(names):
        raise ValueError(f"{what}: a name is repeated in {names!r}; give each once")
    for opt, given in (("t_eval", t_eval is not None), ("events", bool(events)), ("dense_output", dense_output)):
        if given:
            raise ValueError(f"{what}: not available with {opt}= (the derivatives are those of the steps' "
                             "states); save the steps (save_every=) and read the times there")
    if y0 is not None and np.ndim(y0) > 1:
        raise ValueError(f"{what}: one trajectory only (y0 of shape (n,)); run the members of an ensemble "
                         "one by one")
    if names and np.ndim(_constants(fi.system)) > 1:
        raise ValueError(f"{what}: per-member constants (an ensemble) are not supported; set one value each")
    return names


class _SwappedConstants:
    """While tracing: the system's constants replaced by symbols (``values``), restored after."""

    def __init__(self, system, values):
        self.holder = _holder(system)
        self.values = values

    def __enter__(self):
        if self.holder is not None and self.values is not None and self.values.size:
            self.saved = self.holder.values
            self.holder.values = self.values
        return self

    def __exit__(self, *exc):
        if self.holder is not None and self.values is not None and self.values.size:
            self.holder.values = self.saved
        return False


def _constants(system):
    holder = _holder(system)
    if holder is None:
        return np.zeros(0)
    return np.asarray(holder.values, float)


def _targets(fi, y, p, data):
    """The parameter vector ``p`` with its targets evaluated at the start ``y`` (traced)."""
    from ..reduction import core as _core

    lay = fi.parameter_layout
    g, z = fi.split(y)
    out = np.array(p, dtype=object)
    t = _core.evaluate(fi.system, z, data=data, derivatives=False)
    if fi.use_energy:
        out[lay.energy_target] = t.ht if fi.energy == "extended" else t.h
    for u, it in zip(fi.user, lay.user_target):
        out[it] = u.value_and_grad(z, data)[0]
    return out


def _jacobian_rows(out_expr, inputs):
    """``[f, df/d(inputs)]`` flattened: ``f`` (``m``) then the ``m x len(inputs)`` Jacobian, row-major."""
    from ..engine.trace import jacobian

    f = np.asarray(out_expr, dtype=object).reshape(-1)
    J = jacobian(f, list(inputs)).T  # (m, len(inputs))
    return np.concatenate([f, J.reshape(-1)])


def _targets_source(fi, y, p, c):
    """Source of ``ptargets(y, p, c, out)``: the parameter vector with its targets at ``y`` and its
    Jacobian in ``(y, c)`` (traced on the symbols ``y, p, c`` of the current session)."""
    from ..engine.codegen import NJIT, function_source
    from ..engine.trace import TRACED_DATA, traced_call

    with _SwappedConstants(fi.system, c):
        p0 = traced_call("the invariants' targets", _targets, fi, y, p, TRACED_DATA)
    return NJIT + function_source("ptargets", _jacobian_rows(p0, [*y, *c]), ("y", "p", "c", "out"))


def targets_kernel(fi):
    """The plain-Python module of ``ptargets`` alone (:func:`_targets_source`), called once per run."""

    def make(tr):
        n, size, P = fi.n, fi.parameter_layout.size, _constants(fi.system).size
        y, p, c = tr.symbols("y", n), tr.symbols("p", size), tr.symbols("c", P)
        return _targets_source(fi, y, p, c), size, "targets", 0

    return _kept(fi, ("tangent-targets",), "python", make)


def _kept(fi, kind, engine, make):
    """The kernel ``make`` builds for ``fi``'s system and layout, kept per system (not per constants' value)."""
    from ..engine.kernels import _engine, _fi_key, _field_kernel

    key = (id(fi.system),) + _fi_key(fi, kind) + (_engine(engine),)
    got = _KERNELS.get(key)
    if got is not None and got[0]() is fi.system:
        return got[1]
    made = _field_kernel(fi, kind, engine, make)
    _KERNELS[key] = (weakref.ref(fi.system), made)
    return made


def tangent_kernel(fi, sch, *, engine="python"):
    """The generated Jacobians of one step of ``fi`` with scheme ``sch`` (module docstring).

    The module holds ``fj(y, p, c, out)``: the field the tableau steps (``X - A grad V``, or
    ``X`` alone for a split scheme) and its Jacobian in ``(y, p, c)``; for a split scheme
    ``gj(y, p, c, hh, out)``: the feedback step :func:`~liefi.schemes.split.feedback_step`
    and its Jacobian in ``(y, p, c)``; and ``ptargets(y, p, c, out)``: the parameter vector
    with its targets at the start ``y`` and its Jacobian in ``(y, c)``.  Each is traced on
    fresh symbols, so the data's derivatives inside are differentiated exactly.  The constants are
    inputs, so one kernel serves every value of them (a fit changes them at every iteration): it is
    kept per system and integrator layout, not per value as the compiled field is (which folds them in).
    """
    from ..engine.codegen import NJIT, function_source
    from ..engine.trace import TRACED_DATA, traced_call
    from ..schemes.split import feedback_step

    n, size, P = fi.n, fi.parameter_layout.size, _constants(fi.system).size
    split = sch.kind == "split"

    def make(tr):
        y, p, c = tr.symbols("y", n), tr.symbols("p", size), tr.symbols("c", P)
        field = fi.unforced_vector_field if split else fi.vector_field
        inputs = [*y, *p, *c]
        with _SwappedConstants(fi.system, c):
            f = traced_call("the field", field, y, p, data=TRACED_DATA)
            src = NJIT + function_source("fj", _jacobian_rows(f, inputs), ("y", "p", "c", "out"))
            if split:
                h = tr.symbols("hh", 1)[0]
                g = traced_call("the feedback step", feedback_step, fi, y, h, p, data=TRACED_DATA)
                src += "\n\n" + NJIT + function_source("gj", _jacobian_rows(g, inputs),
                                                       ("y", "p", "c", "hh", "out"))
        return src + "\n\n" + _targets_source(fi, y, p, c), size, "tangent", 0

    return _kept(fi, "tangent-split" if split else "tangent", engine, make)


def fused_kernel(fi, sch, *, engine="numba"):
    """The compiled loop that steps the state and its tangents together (:mod:`._tangent_loop`).

    One kernel per system, integrator layout and scheme, for every number of directions (a run-time
    size); the traces are those of :func:`tangent_kernel` (the field, the feedback step), their tangents
    printed inline in one loop over the directions.  The parameters that carry a direction are those
    :func:`tangents` may move: the invariants' targets (:func:`_targets`), not the gains.
    """
    from ..engine.trace import TRACED_DATA, traced_call
    from ..schemes.split import feedback_step
    from . import _tangent_loop as tl

    n, size, P = fi.n, fi.parameter_layout.size, _constants(fi.system).size
    split = sch.kind == "split"
    tab = sch.explicit if split else sch

    def make(tr):
        y, p, c = tr.symbols("y", n), tr.symbols("p", size), tr.symbols("c", P)
        inputs = [*y, *p, *c]
        d = tr.symbols("d", len(inputs))
        field = fi.unforced_vector_field if split else fi.vector_field
        with _SwappedConstants(fi.system, c):
            # a parameter moves only if it is a target (the start's Jacobian row of a gain is zero)
            p0 = np.asarray(traced_call("the invariants' targets", _targets, fi, y, p, TRACED_DATA), dtype=object)
            active = [*range(n), *(n + q for q in range(size) if tl.as_sym(p0[q]) is not p[q]),
                      *range(n + size, n + size + P)]
            f = traced_call("the field", field, y, p, data=TRACED_DATA)
            fT = tl.jvp_graph(np.asarray(f, dtype=object).reshape(-1), inputs, d, active)
            gT = None
            if split:
                h = tr.symbols("hh", 1)[0]
                g = traced_call("the feedback step", feedback_step, fi, y, h, p, data=TRACED_DATA)
                gT = tl.jvp_graph(np.asarray(g, dtype=object).reshape(-1), inputs, d, active)
        src = tl.fused_source(fT, gT, tab, n, size, P, split=split)
        return src, size, "tangent-fused", 0

    return _kept(fi, ("tangent-lanes", sch.name), engine, make)


def _step(mod, sch, y, S, p, c, Wt, Ct, dt, bufs):
    """One step of ``y`` and its tangents ``S`` (``(n, k)``): the tableau's stages, then the feedback step.

    ``Wt`` (``(size, k)``) and ``Ct`` (``(P, k)``) are the tangents of ``p`` and ``c``.
    """
    n = y.size
    fbuf, gbuf = bufs
    tab = sch.explicit if sch.kind == "split" else sch

    def field(yi, Si):
        mod.fj(yi, p, c, fbuf)
        J = fbuf[n:].reshape(n, -1)
        return fbuf[:n].copy(), J[:, :n] @ Si + J[:, n:] @ PC

    PC = np.concatenate([Wt, Ct], 0)
    ks, kS = [], []
    for i in range(tab.stages):
        yi, Si = y, S
        for j, a in enumerate(tab.A[i][:i]):
            if a:
                yi = yi + (dt * a) * ks[j]
                Si = Si + (dt * a) * kS[j]
        ki, kSi = field(yi, Si)
        ks.append(ki)
        kS.append(kSi)
    yn, Sn = y, S
    for bi, ki, kSi in zip(tab.b, ks, kS):
        if bi:
            yn = yn + (dt * bi) * ki
            Sn = Sn + (dt * bi) * kSi
    if sch.kind == "split":
        mod.gj(yn, p, c, np.array([dt]), gbuf)
        J = gbuf[n:].reshape(n, -1)
        yn, Sn = gbuf[:n].copy(), J[:, :n] @ Sn + J[:, n:] @ PC
    return yn, Sn


def directions(fi, y0, names):
    """``(labels, V0, dtheta)``: the seeds of ``names`` -- ``V0`` ``(k, n)`` the start's tangents, ``dtheta``
    ``(k, P)`` the constants' -- and ``labels[j] = (name, column or None)``."""
    n = fi.n
    consts = parameter_names(fi.system)
    rows_v, rows_c, labels = [], [], []
    P = len(consts)
    for nm in names:
        if nm == "y0":
            for i in range(n):
                rows_v.append(np.eye(n)[i])
                rows_c.append(np.zeros(P))
                labels.append(("y0", i))
        else:
            rows_v.append(np.zeros(n))
            rows_c.append(np.eye(P)[consts.index(nm)])
            labels.append((nm, None))
    k = len(labels)
    return labels, np.array(rows_v, float).reshape(k, n), np.array(rows_c, float).reshape(k, P)


def tangents(fi, sch, y0, dt, n_steps, saved_steps, V, C=None, *, engine="python", schedule=None):
    """Directional derivatives (JVPs) of a run: the tangents of ``k`` directions of ``(y0, theta)``.

    ``V`` ``(k, n)``: the directions of the start; ``C`` ``(k, P)``: those of the system's
    constants (default 0).  Returns ``(states, S)``: the replayed states ``(n, n_t)`` at
    ``saved_steps`` and ``S`` ``(k, n, n_t)``, ``S[j] = d y / d s`` along direction ``j``.
    ``engine="numba"`` runs the compiled loop (:func:`tangent_kernel`'s ``tangent_run``).
    ``schedule``: ``[(step, p), ...]``, the parameter vector in effect from each step on (the
    gains an adaptive run changed along the way, held as numbers); default ``fi.parameters()``:
    ``fi`` steps with its own gains, so give it those of the run (``sol.stability.gains``,
    :meth:`~liefi.FeedbackIntegrator.with_gains`), not the unit-rate gains ``gains="auto"`` starts from.
    ``sch``: a scheme of the registry or its name (``"imex-rk4"``).
    """
    if isinstance(sch, str):
        from ..schemes import registry

        sch = registry.get(sch)
    y0 = np.ascontiguousarray(y0, dtype=float)
    n = fi.n
    c = np.ascontiguousarray(_constants(fi.system), dtype=float)
    P = c.size
    V = np.asarray(V, float).reshape(-1, n)
    k = V.shape[0]
    C = np.zeros((k, P)) if C is None else np.asarray(C, float).reshape(k, P)
    if schedule is None:
        schedule = [(0, fi.parameters())]
    schedule = [(int(a), np.ascontiguousarray(q, dtype=float)) for a, q in schedule]
    p = schedule[0][1]
    size = p.size
    mod = (targets_kernel(fi) if engine == "numba" else tangent_kernel(fi, sch, engine=engine)).kernel.module
    # the start's parameter vector and its tangents: the targets taken at y0 follow it (the gains
    # are held, so their rows of the Jacobian are zero and every segment of the schedule shares them)
    buf = np.empty(size + size * (n + P))
    mod.ptargets(y0, p, c, buf)
    p_at, Jp = buf[:size], buf[size:].reshape(size, n + P)
    follow = (np.abs(p_at - p) <= 1e-14 * np.maximum(1.0, np.abs(p)))
    Wt = (Jp[:, :n] @ V.T + Jp[:, n:] @ C.T) * follow[:, None]  # (size, k)
    saved_steps = np.asarray(saved_steps, dtype=np.int64)
    Y = np.empty((n, saved_steps.size))
    St = np.empty((n, k, saved_steps.size))
    at0 = saved_steps == 0
    Y[:, at0], St[..., at0] = y0[:, None], V.T[..., None]
    y, S = y0, np.ascontiguousarray(V.T)
    for i, (a, q) in enumerate(schedule):
        b = schedule[i + 1][0] if i + 1 < len(schedule) else int(n_steps)
        if b <= a:
            continue
        inside = (saved_steps > a) & (saved_steps <= b)
        want = np.union1d(saved_steps[inside] - a, [b - a]).astype(np.int64)
        Ys, Ss = _segment(mod, sch, y, S, q, c, Wt, C, float(dt), b - a, want, engine, fi)
        pick = np.isin(want, saved_steps[inside] - a)  # the segment's end is computed, saved only if asked
        Y[:, inside], St[..., inside] = Ys[:, pick], Ss[..., pick]
        y, S = np.ascontiguousarray(Ys[:, -1]), np.ascontiguousarray(Ss[..., -1])
    return Y, np.moveaxis(St, 1, 0)  # (k, n, n_t)


def _segment(mod, sch, y0, S0, p, c, Wt, C, dt, n_steps, saved, engine, fi):
    """``n_steps`` steps from ``(y0, S0)`` with the parameters ``p``: states and tangents at ``saved`` (from 1).

    Compiled (``engine="numba"``, ``fi`` given): the fused loop (:func:`fused_kernel`, one kernel for
    every number of directions), the directions in blocks of at most ``K_MAX``, each block stepping the
    state again (the same arithmetic every time).
    """
    n, k = S0.shape
    m = n + p.size + c.size
    Y = np.empty((n, saved.size))
    St = np.empty((n, k, saved.size))
    if engine == "numba":
        from ._tangent_loop import K_MAX

        PC = np.concatenate([Wt, C.T], 0)
        fmod = fused_kernel(fi, sch, engine=engine).kernel.module
        for lo in range(0, k, K_MAX):
            hi = min(k, lo + K_MAX)
            Sb = np.empty((n, hi - lo, saved.size))
            with np.errstate(all="ignore"):
                fmod.tangent_fused(y0, np.ascontiguousarray(S0[:, lo:hi]), p, c, np.ascontiguousarray(PC[:, lo:hi]),
                                   dt, int(n_steps), saved, Y, Sb)
            St[:, lo:hi] = Sb
        return Y, St
    bufs = (np.empty(n + n * m), np.empty(n + n * m))
    y, S = y0.copy(), S0.copy()
    j = 0
    with np.errstate(all="ignore"):
        for s in range(1, int(n_steps) + 1):
            y, S = _step(mod, sch, y, S, p, c, Wt, C.T, dt, bufs)
            if j < saved.size and saved[j] == s:
                Y[:, j], St[..., j] = y, S
                j += 1
    return Y, St


def propagate(fi, sch, y0, dt, n_steps, saved_steps, names, *, engine="python", schedule=None):
    """Replay the run of ``fi`` (scheme ``sch``, step ``dt``) from ``y0`` with its tangents.

    Returns ``(states, tangents)``: the replayed states ``(n, n_t)`` at ``saved_steps``
    (the steps of the saved states, increasing, from 0) and ``{name: d y / d name}``
    (``(n, n, n_t)`` for ``"y0"``, ``(n, n_t)`` for a parameter).  The targets equal to
    the invariants' values at ``y0`` (taken at the start) move with it (module docstring);
    others (``FeedbackIntegrator(targets=...)``, or a run from another start) are held.
    ``schedule`` as in :func:`tangents`.
    """
    y0 = np.asarray(y0, float)
    n = fi.n
    labels, V, CW = directions(fi, y0, names)
    Y, S = tangents(fi, sch, y0, dt, n_steps, saved_steps, V, CW, engine=engine, schedule=schedule)
    n_t = Y.shape[-1]
    result = {}
    for i, (nm, col) in enumerate(labels):
        if col is None:
            result[nm] = S[i]
        else:
            result.setdefault(nm, np.empty((n, n, n_t)))[:, col, :] = S[i]
    return Y, result


def gain_schedule(fi, report, dt, t0=0.0):
    """``[(step, p), ...]``: the parameters of ``fi`` with the gains of the run's ``report`` from each update on.

    ``report`` the policy's :class:`~liefi.integrator.guard.RunReport` (``gains``, ``gain_times``,
    ``gain_history``), ``t0`` the run's start; ``None`` without gains (``fi``'s own parameters).
    """
    if report is None or not report.gains:
        return None
    schedule = [(0, fi.parameters(gains=report.gains))]
    for t, g in zip(report.gain_times, report.gain_history):
        schedule.append((int(round((t - t0) / dt)), fi.parameters(gains=g)))
    return schedule


def attach(sol, fi, sch, y0, dt, n_steps, saved_steps, names, *, report=None, t0=0.0, engine=None):
    """Set ``sol.sensitivities`` (``{name: array}``) for the run ``sol`` of ``fi``: the one call of the run loop.

    ``fi`` is the integrator that ran (its gains, its dropped invariants), ``sch`` its scheme,
    ``saved_steps`` the step of each saved state.  The replay's states must agree with
    ``sol.y`` (:data:`REPLAY_RTOL`); a failed run (``errors="return"``) gets ``None``.
    ``report`` (the policy's :class:`~liefi.integrator.guard.RunReport`) gives the gains of the run
    and their updates (``gain_times``, ``gain_history``: an adaptive run), held as numbers from
    the step of each update on (``t0`` the run's start).
    ``engine``: the tangents' loop, default compiled (``"numba"``) when the run was, else
    ``"python"`` (the generated Jacobians as plain Python, stepped with numpy).  The CPU
    seconds of the tangents (compile included) are ``sol.sensitivity_cpu_seconds``.
    """
    if engine is None:
        from ..engine import cache as _cache

        engine = "numba" if getattr(sol, "backend", "numpy") != "numpy" and _cache.available() else "python"
    names = check(fi, names, y0=y0)
    if not names:
        return sol
    saved_steps = np.asarray(saved_steps)
    if not sol.success:
        sol.sensitivities = None
        return sol
    if np.any(saved_steps < 0):
        raise ValueError("sensitivities: the run ended with a step shortened to reach t_final (dt does not divide the "
                         "span); take a dt that divides it")
    start = time.process_time()
    schedule = gain_schedule(fi, report, dt, t0)
    from ..engine.trace import NotCompilable

    try:
        Y, sens = propagate(fi, sch, y0, dt, n_steps, saved_steps, names, engine=engine, schedule=schedule)
    except NotCompilable as exc:
        raise ValueError(f"sensitivities: liefi differentiates the run's step through its trace, and this system's "
                         f"step cannot be traced: {exc}") from None
    sol.sensitivity_cpu_seconds = time.process_time() - start
    ref = np.asarray(sol.y, float)
    scale = np.maximum(1.0, np.max(np.abs(ref), axis=-1, keepdims=True))
    err = float(np.max(np.abs(Y - ref) / scale, initial=0.0))
    if not err <= REPLAY_RTOL:
        raise ValueError(
            f"sensitivities: the replay of the run's steps differs from the saved states by {err:.3g} (relative): the "
            "run changed something along the way that the replay does not see; please report it, and meanwhile pass "
            "adaptive=False")
    sol.sensitivities = sens
    return sol
