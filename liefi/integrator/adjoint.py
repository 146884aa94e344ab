r"""Reverse mode (the discrete adjoint) of a fixed-step run: ``w . dy / d(y0, theta)`` for one cotangent ``w``.

For a scalar loss ``L`` of the saved states, ``W[:, t] = dL / dy(t_t)`` (shape ``(n, n_t)``), :func:`vjp`
gives ``dL / dy0`` and ``dL / dtheta`` (the system's parameters, :mod:`liefi.integrator.sensitivity`) at
the cost of one run that keeps its states and one backward sweep, whatever the number of parameters;
forward mode costs about one to two runs per parameter (docs/gradients.md, "Reverse mode").

The run is ``y_{s+1} = Phi(y_s; p, theta)``, ``p`` the feedback parameters with the targets taken at the
start (``p = p(y0, theta)``).  The adjoint recursion is

.. math:: \lambda_N = W_N, \qquad \lambda_s = W_s + \partial_y\Phi(y_s)^T \lambda_{s+1}, \qquad
          \bar p = \sum_s \partial_p\Phi(y_s)^T \lambda_{s+1}, \quad
          \bar\theta = \sum_s \partial_\theta\Phi(y_s)^T \lambda_{s+1},

(``W_s = 0`` at steps not saved), then ``dL/dy0 = lambda_0 + (d p / d y0)^T pbar`` and
``dL/dtheta = thetabar + (d p / d theta)^T pbar`` through the targets that follow the start.  One
backward step of a split scheme (the tableau ``(A, b)`` on ``X``, then the feedback step ``F``):
``zbar = dF(y_*)^T lambda``; ``kbar_i = dt b_i zbar``; for ``i`` from the last stage down,
``Ybar_i = dX(Y_i)^T kbar_i``, ``ybar += Ybar_i``, ``kbar_j += dt a_ij Ybar_i`` (``j < i``); then
``lambda_s = ybar``.  The transposed products are generated from the same trace as the forward
tangents, by reverse accumulation over the graph (:func:`liefi.integrator._tangent_loop.vjp_graph`),
and printed as scalar code: the step's nodes are recomputed from the kept state ``y_s``.

**Checkpoints** (:func:`segment_steps`).  Keeping every ``y_s`` costs ``8 n (N + 1)`` bytes.  With
``c`` checkpoints the forward pass keeps the first state of ``c`` segments of ``m = ceil(N / c)``
steps, and the backward sweep recomputes a segment's states from it, then sweeps it:
``8 n (c + m + 1)`` bytes, least at ``c ~ sqrt(N)``, for one more forward run.  ``lambda``, ``pbar``
and ``cbar`` pass from one segment to the next through the kernel's ``out`` (read at the segment's
end, written at its start), so the operations and their order are those of one sweep over all the
states: the result does not depend on ``c``, bitwise.

**The entry point** (``fi.run(..., adjoint=True)``, then ``sol.vjp(W)``: :class:`RunAdjoint`).
diffrax chooses the adjoint in the solve (``diffeqsolve(..., adjoint=RecursiveCheckpointAdjoint(
checkpoints=...))``) and SciMLSensitivity takes a solution and the loss's derivative at the saved
times (``adjoint_sensitivities(sol, alg; dgdu_discrete=...)``); liefi has no tracer for a user's
Python loss, so it does both: the run checks that it can be differentiated and keeps what the sweep
needs (:func:`check`, :func:`attach`), and the solution takes ``W = dL/dy`` at its saved states and
returns ``{name: dL/dname}`` for ``"y0"`` and every parameter, one sweep whatever their number.
Opt-in like ``sensitivities=``: a plain run keeps nothing.
"""

from __future__ import annotations

import math

import numpy as np

from . import _tangent_loop as tl
from . import sensitivity as _sens

__all__ = ["vjp", "segment_steps", "RecursiveCheckpointAdjoint"]


def _source(f_vjp, g_vjp, f, tab, n, size, P, split):
    """Source of ``adjoint_forward(y0, p, c, dt, n_steps, Yall)`` and
    ``adjoint_backward(Yall, p, c, dt, n_steps, W, wsteps, out)`` (``out``: ``lambda, pbar, cbar``, read
    at ``n_steps`` and written at step 0, so that consecutive segments chain with the same roundings)."""
    I1, I2, I3 = "    ", "        ", "            "
    coeff = tl._coeff_source(tab)

    def stage_inputs(i, L, ind):
        coeffs = [(l, a) for l, a in enumerate(tab.A[i][:i]) if a]
        if not coeffs:
            return "y"
        for r in range(n):
            L.append(f"{ind}yi{i}_{r} = y_{r} + " + " + ".join(f"c{i}_{l} * k{l}_{r}" for l, _ in coeffs))
        return f"yi{i}"

    def primal_stages(L, ind, refs):
        for i in range(tab.stages):
            ys = stage_inputs(i, L, ind)
            ref = {}
            lines, outs = tl.emit_plain(f, lambda nm, idx, ys=ys: f"{ys}_{idx}" if nm == "y" else f"{nm}_{idx}",
                                        f"f{i}", ind, ref)
            L += lines
            L += [f"{ind}k{i}_{r} = {outs[r]}" for r in range(n)]
            refs.append((ys, ref))
        for r in range(n):
            L.append(f"{ind}z_{r} = y_{r} + " + tl._update_terms(tab, lambda l: f"k{l}_{r}"))

    L = ["@njit(cache=CACHE, error_model='numpy')", "def adjoint_forward(y0, p, c, dt, n_steps, Yall):"]
    L += [f"{I1}y_{r} = y0[{r}]" for r in range(n)] + [f"{I1}p_{q} = p[{q}]" for q in range(size)]
    L += [f"{I1}c_{q} = c[{q}]" for q in range(P)] + coeff
    L += [f"{I1}Yall[{r}, 0] = y_{r}" for r in range(n)] + [f"{I1}for step in range(1, n_steps + 1):"]
    primal_stages(L, I2, [])
    if split:
        lines, outs = tl.emit_plain(g_vjp[1], lambda nm, idx: f"z_{idx}" if nm == "y" else
                                    ("dt" if nm == "hh" else f"{nm}_{idx}"), "g", I2)
        L += lines + [f"{I2}y_{r} = {outs[r]}" for r in range(n)]
    else:
        L += [f"{I2}y_{r} = z_{r}" for r in range(n)]
    L += [f"{I2}Yall[{r}, step] = y_{r}" for r in range(n)] + [f"{I1}return 0", "", ""]

    L += ["@njit(cache=CACHE, error_model='numpy')", "def adjoint_backward(Yall, p, c, dt, n_steps, W, wsteps, out):"]
    L += [f"{I1}p_{q} = p[{q}]" for q in range(size)] + [f"{I1}c_{q} = c[{q}]" for q in range(P)] + coeff
    L += [f"{I1}l_{r} = out[{r}]" for r in range(n)] + [f"{I1}pb_{q} = out[{n + q}]" for q in range(size)]
    L += [f"{I1}cb_{q} = out[{n + size + q}]" for q in range(P)]
    L += [f"{I1}js = wsteps.size - 1", f"{I1}for step in range(n_steps, 0, -1):",
          f"{I2}if js >= 0 and wsteps[js] == step:"]
    L += [f"{I3}l_{r} += W[{r}, js]" for r in range(n)] + [f"{I3}js -= 1"]
    L += [f"{I2}y_{r} = Yall[{r}, step - 1]" for r in range(n)]
    refs = []
    primal_stages(L, I2, refs)
    if split:
        gv, _ = g_vjp
        lines, outs = tl.emit_plain(gv, lambda nm, idx: f"z_{idx}" if nm == "y" else
                                    ("dt" if nm == "hh" else (f"l_{idx}" if nm == "lam" else f"{nm}_{idx}")), "g", I2)
        L += lines
        L += [f"{I2}zb_{r} = {outs[r]}" for r in range(n)]
        L += [f"{I2}pb_{q} += {outs[n + q]}" for q in range(size)]
        L += [f"{I2}cb_{q} += {outs[n + size + q]}" for q in range(P)]
    else:
        L += [f"{I2}zb_{r} = l_{r}" for r in range(n)]
    L += [f"{I2}yb_{r} = zb_{r}" for r in range(n)]
    for i in range(tab.stages):
        bi = tab.b[i]
        L += [f"{I2}kb{i}_{r} = {(f'(dt * {float(bi)!r}) * zb_{r}') if bi else '0.0'}" for r in range(n)]
    for i in reversed(range(tab.stages)):
        ys, ref = refs[i]
        lines, outs = tl.emit_plain(f_vjp, lambda nm, idx, ys=ys, i=i: f"{ys}_{idx}" if nm == "y" else
                                    (f"kb{i}_{idx}" if nm == "lam" else f"{nm}_{idx}"), f"f{i}", I2, ref)
        L += lines
        L += [f"{I2}Yb_{r} = {outs[r]}" for r in range(n)]
        L += [f"{I2}pb_{q} += {outs[n + q]}" for q in range(size)]
        L += [f"{I2}cb_{q} += {outs[n + size + q]}" for q in range(P)]
        L += [f"{I2}yb_{r} += Yb_{r}" for r in range(n)]
        for l, a in enumerate(tab.A[i][:i]):
            if a:
                L += [f"{I2}kb{l}_{r} += c{i}_{l} * Yb_{r}" for r in range(n)]
    L += [f"{I2}l_{r} = yb_{r}" for r in range(n)]
    L += [f"{I1}if js >= 0 and wsteps[js] == 0:"] + [f"{I2}l_{r} += W[{r}, js]" for r in range(n)]
    L += [f"{I1}out[{r}] = l_{r}" for r in range(n)] + [f"{I1}out[{n + q}] = pb_{q}" for q in range(size)]
    L += [f"{I1}out[{n + size + q}] = cb_{q}" for q in range(P)] + [f"{I1}return 0"]
    return "\n".join(L) + "\n"


def adjoint_kernel(fi, sch, *, engine="numba"):
    """The generated forward (states kept) and backward loops of :func:`vjp` for ``fi`` and scheme ``sch``."""
    from ..engine.trace import TRACED_DATA, traced_call
    from ..schemes.split import feedback_step

    n, size, P = fi.n, fi.parameter_layout.size, _sens._constants(fi.system).size
    split = sch.kind == "split"
    tab = sch.explicit if split else sch

    def make(tr):
        y, p, c = tr.symbols("y", n), tr.symbols("p", size), tr.symbols("c", P)
        lam = tr.symbols("lam", n)
        inputs = [*y, *p, *c]
        field = fi.unforced_vector_field if split else fi.vector_field
        with _sens._SwappedConstants(fi.system, c):
            f = [tl.as_sym(v) for v in np.asarray(traced_call("the field", field, y, p, data=TRACED_DATA),
                                                    dtype=object).reshape(-1)]
            g_vjp = None
            if split:
                h = tr.symbols("hh", 1)[0]
                g = [tl.as_sym(v) for v in np.asarray(traced_call("the feedback step", feedback_step, fi, y, h, p,
                                                                  data=TRACED_DATA), dtype=object).reshape(-1)]
                g_vjp = (tl.vjp_graph(g, inputs, list(lam)), g)
        f_vjp = tl.vjp_graph(f, inputs, list(lam))
        return _source(f_vjp, g_vjp, f, tab, n, size, P, split), size, "adjoint", 0

    return _sens._kept(fi, ("adjoint", sch.name), engine, make)


#: the default ``checkpoints`` keeps every state of a run while they take at most this many bytes
STORE_ALL_BYTES = 1 << 24


def segment_steps(n_steps, n, checkpoints=None):
    """The steps ``m`` of a segment of the backward sweep (``m >= n_steps``: every state kept).

    ``checkpoints``: ``None`` (``"all"`` while ``8 n (N + 1) <=`` :data:`STORE_ALL_BYTES`, else
    ``ceil(sqrt(N))``), ``"all"``, or the number ``c >= 1`` of kept states: ``m = ceil(N / c)``.
    """
    N = int(n_steps)
    if checkpoints is None:
        checkpoints = "all" if 8 * n * (N + 1) <= STORE_ALL_BYTES else math.isqrt(max(N - 1, 0)) + 1
    if isinstance(checkpoints, str) and checkpoints == "all":
        return max(N, 1)
    if isinstance(checkpoints, (bool, np.bool_)) or not isinstance(checkpoints, (int, np.integer)) or checkpoints < 1:
        raise ValueError(f"checkpoints: expected None (the default), 'all' or the number of kept states, an integer "
                         f">= 1 (e.g. {math.isqrt(max(N - 1, 0)) + 1}, about sqrt(n_steps)), got {checkpoints!r}")
    return max(N, 1) if checkpoints >= N else -(-N // int(checkpoints))


def vjp(fi, sch, y0, dt, n_steps, saved_steps, W, *, engine="python", schedule=None, checkpoints=None):
    """``(dL/dy0, dL/dtheta)`` for the cotangents ``W`` (``(n, n_t)``, ``dL/dy`` at ``saved_steps``).

    Arguments as :func:`liefi.integrator.sensitivity.tangents` (``fi`` holding the run's gains,
    ``schedule`` an adaptive run's updates); ``theta`` the system's parameters in the order of
    :func:`~liefi.integrator.sensitivity.parameter_names`.  It equals
    ``sum_t S_t^T W[:, t]`` of the forward tangents, at the cost of two runs and a backward sweep
    whatever the number of parameters.  ``engine="numba"`` compiles the loops.

    ``checkpoints`` (:func:`segment_steps`): the states kept for the backward sweep.  ``"all"`` keeps
    every state (``8 n (N + 1)`` bytes); a number ``c`` keeps the first state of ``c`` segments of
    ``m = ceil(N / c)`` steps, and the backward sweep recomputes each segment's states from it
    (``8 n (c + m + 1)`` bytes, least at ``c = sqrt(N)``, for one more forward run).  The recomputed
    states are the same steps of the same code, and the adjoint and the sums ``pbar``, ``thetabar``
    are carried from one segment to the next in the same order of operations, so the result does not
    depend on ``checkpoints``: bitwise.  Default: all while they take at most
    :data:`STORE_ALL_BYTES`, else ``ceil(sqrt(N))``.
    """
    return _sweep(fi, sch, y0, dt, n_steps, saved_steps, W, engine=engine, schedule=schedule,
                  checkpoints=checkpoints)[:2]


def _sweep(fi, sch, y0, dt, n_steps, saved_steps, W, *, engine, schedule, checkpoints):
    """:func:`vjp`, and the state its forward pass reached at ``n_steps`` (the replay's check)."""
    if isinstance(sch, str):
        from ..schemes import registry

        sch = registry.get(sch)
    y0 = np.ascontiguousarray(y0, dtype=float)
    n = fi.n
    c = np.ascontiguousarray(_sens._constants(fi.system), dtype=float)
    P = c.size
    saved_steps = np.asarray(saved_steps, dtype=np.int64)
    W = np.asarray(W, float)
    if W.shape != (n, saved_steps.size):
        raise ValueError(f"W: expected dL/dy at the saved steps, shape (n, n_t) = ({n}, {saved_steps.size}), got "
                         f"{W.shape}")
    if np.any(np.diff(saved_steps) <= 0) or (saved_steps.size and (saved_steps[0] < 0 or saved_steps[-1] > n_steps)):
        raise ValueError(f"saved_steps: expected increasing steps in 0..{n_steps}, got {saved_steps.tolist()}")
    if schedule is None:
        schedule = [(0, fi.parameters())]
    schedule = [(int(a), np.ascontiguousarray(q, dtype=float)) for a, q in schedule]
    size = schedule[0][1].size
    N = int(n_steps)
    m = segment_steps(N, n, checkpoints)
    mod = adjoint_kernel(fi, sch, engine=engine).kernel.module
    buf = np.empty(size + size * (n + P))
    _sens.targets_kernel(fi).kernel.module.ptargets(y0, schedule[0][1], c, buf)
    p_at, Jp = buf[:size], buf[size:].reshape(size, n + P)
    follow = np.abs(p_at - schedule[0][1]) <= 1e-14 * np.maximum(1.0, np.abs(schedule[0][1]))
    pieces = []  # (a, b, q): the gain schedule's segments, cut in segments of at most m steps
    for i, (a, q) in enumerate(schedule):
        b = min(schedule[i + 1][0], N) if i + 1 < len(schedule) else N
        pieces += [(s, min(s + m, b), q) for s in range(a, b, m)]
    kept, y, dt = [], y0, float(dt)
    out = np.zeros(n + size + P)  # lambda, pbar, cbar: carried across the segments
    bufs = {}  # checkpointed: one buffer per segment length, reused

    def states(length):
        return np.empty((n, length + 1)) if m >= N else bufs.setdefault(length, np.empty((n, length + 1)))

    with np.errstate(all="ignore"):
        for a, b, q in pieces:  # forward: every state (m = N) or the first state of each segment
            Y = states(b - a)
            mod.adjoint_forward(y, q, c, dt, b - a, Y)
            kept.append(Y if m >= N else y)
            y = np.ascontiguousarray(Y[:, -1])
        lo = np.searchsorted(saved_steps, [a for a, _, _ in pieces], "right")
        hi = np.searchsorted(saved_steps, [b for _, b, _ in pieces], "right")
        if pieces and saved_steps.size and saved_steps[0] == 0:
            lo[0] = 0  # W at step 0: added by the first segment's sweep at its end
        for i in reversed(range(len(pieces))):  # backward, the segments recomputed from their first state
            (a, b, q), Y = pieces[i], kept[i]
            if Y.ndim == 1:
                Y0, Y = Y, states(b - a)
                mod.adjoint_forward(Y0, q, c, dt, b - a, Y)
            mod.adjoint_backward(Y, q, c, dt, b - a, np.ascontiguousarray(W[:, lo[i]:hi[i]]),
                                 saved_steps[lo[i]:hi[i]] - a, out)
    if not pieces:  # no step: y = y0
        out[:n] = W[:, saved_steps == 0].sum(1)
    lam, pbar, cbar = out[:n], out[n:n + size], out[n + size:]
    pb = pbar * follow
    return lam + Jp[:, :n].T @ pb, cbar + Jp[:, n:].T @ pb, y


class RecursiveCheckpointAdjoint:
    """How a run keeps what its adjoint needs: ``fi.run(..., adjoint=RecursiveCheckpointAdjoint(checkpoints=c))``.

    diffrax's name and meaning (``diffeqsolve(..., adjoint=RecursiveCheckpointAdjoint(checkpoints=...))``):
    ``checkpoints`` the number of states kept for the backward sweep, the others recomputed
    (:func:`segment_steps`; ``None``: every state while they take at most :data:`STORE_ALL_BYTES`,
    else ``ceil(sqrt(N))`` of them; ``"all"``: every state).  ``adjoint=True`` is this with the default.
    The gradient does not depend on ``checkpoints`` (bitwise), only its memory and CPU do.
    """

    def __init__(self, checkpoints=None):
        segment_steps(1, 1, checkpoints)  # the checkpoints' own check, before the run
        self.checkpoints = checkpoints

    def __repr__(self):
        return f"RecursiveCheckpointAdjoint(checkpoints={self.checkpoints!r})"


def check(fi, adjoint, *, t_eval=None, events=None, dense_output=False, y0=None):
    """``fi.run``'s ``adjoint=``, checked before the run: ``None`` or a :class:`RecursiveCheckpointAdjoint`."""
    if adjoint is None or adjoint is False:
        return None
    if adjoint is True:
        adjoint = RecursiveCheckpointAdjoint()
    if not isinstance(adjoint, RecursiveCheckpointAdjoint):
        raise TypeError(f"adjoint: expected True, None or liefi.integrator.adjoint.RecursiveCheckpointAdjoint"
                        f"(checkpoints=...), got {adjoint!r}")
    from .forced import ForcedFeedbackIntegrator

    if isinstance(fi, ForcedFeedbackIntegrator):
        raise ValueError("adjoint: a forced run (force=, inputs=) has no adjoint yet; take its forward sensitivities "
                         "to an input's values instead (sensitivities=('tau',), liefi.integrator._forced_sensitivity)")
    _sens.check(fi, ("y0",), t_eval=t_eval, events=events, dense_output=dense_output, y0=y0, what="adjoint")
    return adjoint


class RunAdjoint:
    """``sol.vjp(W)`` of a run made with ``fi.run(..., adjoint=...)``: what the backward sweep needs, held.

    The run's integrator (its gains, its dropped invariants), scheme, start, step and gain schedule;
    the sweep itself runs at each call (:func:`vjp`), with the run's ``checkpoints``.
    """

    def __init__(self, sol, fi, sch, y0, dt, n_steps, saved_steps, adjoint, *, report=None, t0=0.0):
        from ..engine import cache as _cache

        self.fi, self.sch, self.y0, self.dt, self.n_steps = fi, sch, np.array(y0, float), float(dt), int(n_steps)
        self.saved_steps = np.asarray(saved_steps, np.int64)
        self.checkpoints = adjoint.checkpoints
        self.schedule = _sens.gain_schedule(fi, report, dt, t0)
        self.engine = "numba" if getattr(sol, "backend", "numpy") != "numpy" and _cache.available() else "python"
        self.names = ("y0",) + _sens.parameter_names(fi.system)
        self.failed = None if sol.success else sol.message
        self.end = np.array(sol.y[..., -1], float) if self.saved_steps.size else None

    def __call__(self, cotangent, wrt=None):
        names = self.names if wrt is None else _sens.check(self.fi, wrt, what="wrt")
        if self.failed is not None:
            raise ValueError(f"vjp: the run failed ({self.failed}); it has no gradient")
        if np.any(self.saved_steps < 0):
            raise ValueError("vjp: the run ended with a step shortened to reach t_final (dt does not divide the "
                             "span); take a dt that divides it")
        n, n_t = self.fi.n, self.saved_steps.size
        try:
            W = np.asarray(cotangent, dtype=float)
        except (TypeError, ValueError):
            W = None
        if W is None or W.shape != (n, n_t):
            raise ValueError(f"cotangent: expected dL/dy at the saved states, the shape of sol.y, (n, n_t) = "
                             f"({n}, {n_t}), got {np.shape(cotangent)}")
        if not np.all(np.isfinite(W)):
            raise ValueError("cotangent: contains non-finite numbers")
        from ..engine.trace import NotCompilable

        try:
            gy, gc, end = _sweep(self.fi, self.sch, self.y0, self.dt, self.n_steps, self.saved_steps, W,
                                 engine=self.engine, schedule=self.schedule, checkpoints=self.checkpoints)
        except NotCompilable as exc:
            raise ValueError(f"vjp: liefi differentiates the run's step through its trace, and this system's step "
                             f"cannot be traced: {exc}") from None
        if self.saved_steps[-1] == self.n_steps:
            scale = np.maximum(1.0, np.max(np.abs(self.end)))
            err = float(np.max(np.abs(end - self.end)) / scale)
            if not err <= _sens.REPLAY_RTOL:
                raise ValueError(f"vjp: the replay of the run's steps ends {err:.3g} (relative) away from the run's "
                                 "last state: the run changed something the replay does not see; please report it, "
                                 "and meanwhile pass adaptive=False")
        full = dict(zip(self.names, [gy, *gc]))
        return {k: full[k] for k in names}


def attach(sol, fi, sch, y0, dt, n_steps, saved_steps, adjoint, *, report=None, t0=0.0):
    """Set ``sol.adjoint`` (a :class:`RunAdjoint`, which ``sol.vjp`` calls): the one call of the run loop."""
    sol.adjoint = RunAdjoint(sol, fi, sch, y0, dt, n_steps, saved_steps, adjoint, report=report, t0=t0)
    return sol
