"""The run module: drives fixed-step runs of a feedback integrator.

One job: given a :class:`~liefi.FeedbackIntegrator`, a step, a horizon and a
scheme of the registry (:mod:`liefi.schemes.registry`), it

1. resolves the scheme once, first, into its object (:mod:`liefi.schemes.registry`: the one look-up by name of
   the run; the policy, the step for a tolerance, the gains, the guard, the dense output, the numpy loop
   :func:`liefi.schemes.core.step_loop` and the compiled engine all get the object), and validates the
   arguments once (the policy's step, :func:`liefi.schemes.steps_for`); a given
   ``dt`` that does not divide the span runs whole steps and then one last step shortened to
   end at ``t_final`` (:func:`liefi.schemes.core.step_grid`, a partial step of
   :mod:`liefi.integrator.dense`), reported in ``solution.method`` (``"last_step"``, and in ``"why"``);
2. plans the run (:class:`RunPlan`): the number of steps, the memory of the
   saved output -- refused when it would not fit in memory, and capped by
   default (``save_every=None`` keeps at most :data:`DEFAULT_SAVE_BYTES`) --
   and the expected time, from the measured cost of one step;
3. asks the run's one policy (:class:`liefi.integrator.policy.Policy`) for the step (given,
   or chosen for a tolerance), the starting gains and the pre-run checks, then
   runs in segments on the chosen backend (numpy, or the compiled engine
   :func:`liefi.engine.run_feedback`), asking the policy once per segment for
   the verdict and the next gains, and for the audit of the saved states after;
4. shows progress on stderr for runs expected to take more than
   :data:`PROGRESS_SECONDS` (``tqdm`` when installed, ``liefi[progress]``; a
   plain line otherwise; quiet when stderr is not a terminal);
5. reports ``cpu_seconds`` (the integration loops alone) and
   ``overhead_seconds`` (estimate, guard, kernel loading and compiling)
   separately on the :class:`~liefi.schemes.Solution`;
6. in the shape of ``solve_ivp``: over ``t_span`` (``t_final`` or
   ``(t0, t_final)``), watching ``events`` after every segment (a terminal one
   ends the run), with ``t_eval``, ``dense_output`` and the events' states
   given by partial steps of the run's scheme from the last step before them
   (:mod:`liefi.integrator.dense`: the steps' order, and the invariants kept as at the steps).  :func:`positional_span` reads
   ``run(t0, t_final)`` as a span and refuses the retired ``run(dt, t_final, scheme)``.

:func:`check_ivp` is the guard of the adaptive ``scipy:METHOD`` path and
:func:`check_result_drift` the drift guard of schemes run outside this loop
(DLA).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from .._data import as_state
from .._progress import Progress, stderr_is_terminal
from ..schemes import IntegrationError, Solution, positive_int
from ..schemes.core import step_grid, step_loop
from ..schemes import registry as _registry
from ..schemes import split as _split
from .tolerance import MAX_RUN_STEPS  # a run of more steps is refused before it starts (``--max-steps``)
from . import _run_gains

#: Saved output kept by default (``save_every=None``): at most this many bytes.
DEFAULT_SAVE_BYTES = 256 * 2**20
#: Show progress for runs expected to take longer than this (seconds).
PROGRESS_SECONDS = 3.0
#: Refuse an explicit ``scipy:`` method expected to need more steps than this.
IVP_MAX_STEPS = 1e6
#: An adaptive ``scipy:`` run of more evaluations of the field than this is stopped early, from the
#: projection of its pace (:meth:`liefi.schemes.ivp.ScipyMethod.solve`): minutes of Python calls.
IVP_MAX_EVALUATIONS = 1e6


def available_memory():
    """Bytes of memory available to this process (``MemAvailable``; physical memory as a fallback)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 2**34


@dataclass
class RunPlan:
    """What a run will cost, known before it starts.

    Attributes
    ----------
    n_steps : int
    save_every : int
    n_saved : int
        Saved states (per batch member), the start and the end included.
    saved_bytes : int
        Memory of the saved output.
    seconds_per_step : float
        Measured cost of one step (numpy: a timed evaluation of the field at
        the start; compiled: updated after the first segment).
    expected_seconds : float
    """

    n_steps: int
    save_every: int
    n_saved: int
    saved_bytes: int
    seconds_per_step: float = math.nan
    expected_seconds: float = math.nan


def _saved(n_steps, save_every):
    return n_steps // save_every + 1 + (1 if n_steps % save_every else 0)


def plan(y0, n_steps, save_every=None, *, max_bytes=None):
    """The :class:`RunPlan` of ``n_steps`` steps from ``y0``: the saving and its memory.

    ``save_every=None``: every step while the output stays under
    :data:`DEFAULT_SAVE_BYTES` (``max_bytes``), else the smallest stride that
    keeps it there.  An explicit ``save_every`` whose output would not fit in
    the available memory is refused with the smallest stride that fits.
    """
    per_state = int(np.asarray(y0).size) * 8
    if save_every is None:
        cap = DEFAULT_SAVE_BYTES if max_bytes is None else int(max_bytes)
        save_every = max(1, math.ceil((n_steps + 1) * per_state / max(cap, per_state)))
        save_every = min(save_every, n_steps)
    else:
        save_every = positive_int(save_every, "save_every")
        limit = 0.5 * available_memory() if max_bytes is None else int(max_bytes)
        need = _saved(n_steps, save_every) * per_state
        if need > limit:
            fit = max(1, math.ceil((n_steps + 1) * per_state / max(limit, per_state)))
            raise ValueError(
                f"save_every: saving every {save_every} step(s) of {n_steps} keeps {need / 2**30:.3g} GiB, more "
                f"than the {limit / 2**30:.3g} GiB this run may use; take save_every >= {fit} "
                "(or save_every=None: capped automatically)"
            )
    n_saved = _saved(n_steps, save_every)
    return RunPlan(n_steps, save_every, n_saved, n_saved * per_state)


def _want_progress(progress, expected):
    if progress is not None:
        return bool(progress)
    return expected > PROGRESS_SECONDS and stderr_is_terminal()


def _fixed_step_scheme(scheme):
    if isinstance(scheme, _split.BoundSplitStep):
        return scheme.scheme
    sch = scheme if _registry.is_scheme_object(scheme) else _registry.get(scheme)
    if getattr(sch, "kind", None) not in ("explicit", "split"):
        raise ValueError(
            f"scheme: {sch.name!r} is not a fixed-step scheme of a feedback integrator; choose one of "
            f"{', '.join(_registry.names('explicit') + _registry.names('split'))} (scipy:METHOD and dla run "
            "through Scene.run)"
        )
    return sch


def _segment_runner(sch, dt, backend, names, t_start=0.0):
    """``run(fi_cur, y, n, s0, save_every, check_every) -> Solution`` on the requested backend.

    Times are absolute (step ``s`` is at ``t_start + s dt``); an :class:`~liefi.schemes.IntegrationError` is re-raised
    with the absolute time of the last finite state and the absolute step.
    """
    state = {"backend": backend}
    split = sch.kind == "split"
    if backend not in ("numpy", "numba", "auto"):
        raise ValueError(f"backend: expected 'numpy', 'numba' or 'auto', got {backend!r}")

    def run(fi_cur, y, n, s0, save_every, check_every, out=None):
        t0 = t_start + s0 * dt
        if state["backend"] != "numpy":
            from ..engine import kernels

            try:
                sol = kernels.run_feedback(fi_cur, dt, n, sch, y, save_every, check_every, state["backend"])
            except IntegrationError as exc:  # times relative to the segment
                raise IntegrationError(str(exc), t0 + exc.t, s0 + exc.step, exc.y, exc.components,
                                       getattr(exc, "what", "")) from None
            if sol is not None:
                sol.t = sol.t + t0
                return sol
            state["backend"] = "numpy"
        stepper = sch.bind(fi_cur) if split else sch
        try:
            return step_loop(fi_cur.vector_field, y, dt, n, stepper, t0=t0, save_every=save_every,
                             names=names, check_every=check_every, out=out)
        except IntegrationError as exc:  # t absolute, step relative
            raise IntegrationError(str(exc), exc.t, s0 + exc.step, exc.y, exc.components,
                                   getattr(exc, "what", "")) from None

    def prepare(fi_cur, y):
        """Compile (or load) the kernel now, before the progress starts; the numpy path if it cannot run."""
        if state["backend"] != "numpy":
            from ..engine.kernels import prepare_feedback

            if prepare_feedback(fi_cur, sch, y, state["backend"]) is None:
                state["backend"] = "numpy"

    run.state = state
    run.prepare = prepare
    return run


def _step_seconds(fi, y0, sch):
    """Measured seconds of one numpy step at ``y0`` (one timed field evaluation times the stages)."""
    t = time.perf_counter()
    with np.errstate(all="ignore"):
        fi.vector_field(y0)
    return (time.perf_counter() - t) * getattr(sch, "stages", 1) * (3 if sch.kind == "split" else 1)


def _number(v):
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def positional_span(t_span, more, *, scheme=None):
    """The ``t_span`` of the positional arguments of :meth:`liefi.FeedbackIntegrator.run`.

    As ``solve_ivp``'s: ``run(t_final)`` (from 0), ``run((t0, t_final))`` or
    ``run(t0, t_final)``.  The retired form ``run(dt, t_final, scheme)`` (three
    positional arguments) is refused with the call that replaces it; two
    positional numbers are a span, never ``(dt, t_final)``.
    """
    if not more:
        return t_span
    if len(more) == 1 and _number(t_span) and _number(more[0]):
        return (t_span, more[0])
    if len(more) == 2 and _number(t_span) and _number(more[0]):
        sch = more[1] if scheme is None else scheme
        raise TypeError(
            f"run: the old form run(dt, t_final, scheme) is retired; two positional numbers are a span (t0, t_final) "
            f"as in solve_ivp, and the rest goes by keyword: write run({more[0]!r}, dt={t_span!r}, scheme={sch!r}) "
            f"for a step {t_span!r} over [0, {more[0]!r}]")
    raise TypeError(f"run: takes t_span positionally (a final time, (t0, t_final), or t0, t_final) and the rest by "
                    f"keyword, got the positional arguments {(t_span,) + tuple(more)!r}; write "
                    "run(t_span, dt=..., scheme=...)")


def method_scheme(method, scheme):
    """The ``scheme`` of ``run(method=...)``, ``solve_ivp``'s name for it: a liefi scheme (the object), or a clear
    refusal.

    ``method`` names a fixed-step scheme of :mod:`liefi.schemes` (``"rk4"``,
    ``"imex-rk8"``, case-insensitive); one of ``solve_ivp``'s adaptive methods
    (``"RK45"``, ``"DOP853"``, ...) is refused with the two ways to run it.
    """
    if method is None:
        return scheme
    if scheme is not None:
        raise TypeError("run: give scheme= or its solve_ivp spelling method=, not both")
    fixed = _registry.names("explicit") + _registry.names("split")
    try:
        sch = _registry.get(method)
    except ValueError:
        sch = None
    if sch is not None and sch.kind in ("explicit", "split"):
        return sch  # the object: the run loop does not look it up again
    try:
        ivp = _registry.get(f"scipy:{method}", kind="scipy")
    except ValueError:
        ivp = None
    if ivp is not None:
        raise ValueError(
            f"method: {method!r} is solve_ivp's adaptive method; FeedbackIntegrator.run steps with one of liefi's "
            f"fixed-step schemes, scheme= (default: the order and step chosen for rtol), one of {', '.join(fixed)}. "
            f"To run {ivp.name} on the feedback field: scene.run(scheme={ivp.name!r}), or "
            f"scipy.integrate.solve_ivp(fi.fun, t_span, fi.y0, method={ivp.method!r})")
    raise ValueError(f"method: unknown method {method!r}; liefi's schemes are {', '.join(fixed)} (scheme=)")


def run_feedback(fi, t_span, *, dt=None, scheme=None, t_eval=None, events=None, dense_output=False, errors="raise",
                 y0=None, save_every=None, check_every=1, backend=None, check_stability=True, adaptive=None,
                 monitor_every=None, progress=None, max_saved_bytes=None, drop_exact=True, rtol=None, atol=None,
                 stacklevel=3, resolution_limit=None, max_step=None, sensitivities=None, adjoint=None) -> Solution:
    """Integrate the feedback integrator ``fi`` over ``t_span`` with a fixed step (module docstring).

    The parameters are those of :meth:`liefi.FeedbackIntegrator.run`;
    ``progress``: ``None`` (automatic), True or False; ``max_saved_bytes``: the
    memory the saved output may use (default: :data:`DEFAULT_SAVE_BYTES` with
    ``save_every=None``, half the available memory with an explicit stride).
    ``drop_exact`` (default True): leave out of ``V`` the invariants the scheme
    keeps exactly (:func:`liefi.integrator.gains.exact_drops`); ``solution.dropped`` lists them
    (``{"name", "reason"}``).  ``t_eval``, ``events`` and ``dense_output`` as
    ``solve_ivp``'s, by partial steps of the scheme (:mod:`liefi.integrator.dense`).
    ``errors``: ``"raise"`` (default) or ``"return"``: a failed run returns the
    states up to the failure with ``success=False``, ``status=-1``.
    ``scheme=None``: :data:`liefi.integrator.tolerance.DEFAULT_SCHEME`; ``backend=None``:
    compiled when numba is installed, else numpy; ``dt=None``: the step of
    :func:`liefi.integrator.tolerance.choose_step` for ``rtol`` (default
    :data:`liefi.integrator.tolerance.DEFAULT_RTOL`) and ``atol``; a given ``dt`` that does not divide the span
    ends with one shortened step (``solution.method["last_step"]``; a ``dt`` longer than the span
    becomes one step of the span).  ``resolution_limit``: the largest ``dt``
    times the fastest rate the guard accepts without a warning, for a step chosen for a tolerance before
    the call (:meth:`liefi.scenes.Scene.run`; default :data:`liefi.integrator.stability.RESOLUTION_LIMIT`).
    ``max_step``: as ``solve_ivp``'s, the largest step: a step chosen for the tolerance is shortened to
    ``(t_final - t0) / ceil((t_final - t0) / max_step)``; a given ``dt`` above it is refused.
    ``sensitivities``: names (``"y0"``, the system's parameters) whose derivatives of the saved states
    ``solution.sensitivities`` holds (:mod:`liefi.integrator.sensitivity`); ``adjoint``: a
    :class:`~liefi.integrator.adjoint.RecursiveCheckpointAdjoint` (checked), for ``solution.vjp``.

    Returns the :class:`~liefi.schemes.Solution` with ``method`` (which method
    ran and why: :func:`liefi.integrator.tolerance.describe`), ``stability`` (the
    policy's :class:`~liefi.integrator.guard.RunReport`), ``plan`` (:class:`RunPlan`),
    ``cpu_seconds`` (integration) and ``overhead_seconds``.
    """
    from . import dense as _dense
    from .policy import Policy, _segment
    from ..schemes.core import MESSAGE_EVENT
    from .stability import StabilityError

    from . import tolerance as _tol

    start_all = time.process_time()
    t_start, t_end = _dense.parse_span(t_span)
    if dt is not None and (rtol is not None or atol is not None):
        raise ValueError("rtol: give a step (dt=) or a tolerance (rtol=, atol=), not both; without dt the step is "
                         "chosen for the tolerance")
    if errors not in ("raise", "return"):
        raise ValueError(f"errors: expected 'raise' or 'return', got {errors!r}")
    if y0 is not None:  # before the step is chosen from it (a complex or string y0 named, not cast)
        y0 = as_state(y0, "y0", fi.names)
    # the scheme, resolved once, here: every module below gets the object, none looks it up by name
    scheme_given = scheme is not None
    sch = _fixed_step_scheme(scheme if scheme_given else _tol.DEFAULT_SCHEME)
    dt_given = dt is not None
    t_final, h_last, last_note = t_end, 0.0, None
    if dt_given and _finite_positive(dt):  # a dt that does not divide the span: the last step shortened
        n_full, h_last = step_grid(float(dt), t_end - t_start)
        if n_full == 0:  # one step, of the span
            dt, h_last = t_end - t_start, 0.0
            last_note = f"dt longer than the span: one step of the span, {dt:.6g}"
        elif h_last:
            t_end = t_start + n_full * float(dt)  # the grid's end; a partial step goes on to t_final
            last_note = (f"dt does not divide the span: {n_full} step{'s' if n_full > 1 else ''} of dt, then a "
                         f"last step shortened to {h_last:.6g} to end at t_final")
    backend = _tol.default_backend() if backend is None else backend
    # the one policy of the run: its step, its gains and their checks
    policy = Policy(sch, backend=backend, check_stability=check_stability, adaptive=adaptive,
                    stacklevel=stacklevel + 1, choose_order=not scheme_given, resolution_limit=resolution_limit)
    dt, t_end, n_steps, check_every = policy.step(fi, y0, t_start, t_end, dt, rtol, atol, check_every=check_every,
                                                  max_steps=MAX_RUN_STEPS, max_step=max_step)
    chosen = policy.chosen
    sch = policy.sch  # a step for a tolerance may have chosen the order
    if not h_last:
        t_final = t_end
    t_eval = _dense.check_t_eval(t_eval, t_start, t_final)
    evs = _dense.check_events(events)
    if monitor_every is not None:
        monitor_every = positive_int(monitor_every, "monitor_every")
    if y0 is None:
        y0 = fi.y0
    if evs and y0.ndim > 1:
        raise ValueError(f"events: only for a single trajectory (y0 of shape ({fi.n},)), got a batch of shape "
                         f"{y0.shape}; run the members one by one to locate their events")
    fi = fi.for_batch(y0.shape[:-1])  # an integrator built on one state, run on a batch: common values
    user_fi = fi
    drops = policy.drops(fi, y0) if drop_exact else {}
    if drops:
        fi = fi.without(drops)
    pl = plan(y0, n_steps, save_every, max_bytes=max_saved_bytes)
    save_every = pl.save_every
    names = fi.names
    runner = _segment_runner(sch, dt, backend, names, t_start)
    run_fi = policy.start(fi, dt, n_steps, y0, t0=t_start, monitor_every=monitor_every)
    runner.prepare(run_fi, y0)  # the compile before the progress starts: the bar counts steps only
    if runner.state["backend"] == "numpy":
        pl.seconds_per_step = _step_seconds(run_fi, y0, sch)
        pl.expected_seconds = pl.seconds_per_step * n_steps

    # --- segments -------------------------------------------------------------------------
    extra = 1 if h_last else 0  # the shortened last step's state
    out = np.empty(y0.shape + (pl.n_saved + extra,))
    ts = np.empty(pl.n_saved + extra)
    grid = np.empty(pl.n_saved + extra, dtype=np.int64)  # each saved state's step (dense.OFF_GRID: off the grid)
    out[..., 0], ts[0], grid[0], k = y0, t_start, 0, 1
    if policy.active:
        N = policy.segment_length(n_steps, save_every)
    else:
        N = n_steps if not pl.expected_seconds > PROGRESS_SECONDS else max(1, n_steps // 100)
    stepper = _dense.StepMap(run_fi, sch, t_start, dt, n_steps)  # partial steps: t_eval, sol, events, h_last
    tracker = _dense.EventTracker(evs, stepper) if evs else None
    terminal = bool(tracker) and any(tracker.stop_after)
    next_guard = N
    if tracker:
        tracker.start(t_start, y0)
    desc = f"liefi {sch.name}" + (f" t in [{t_start:g}, {t_end:g}]" if t_start else "")
    bar = Progress(n_steps, desc, _want_progress(progress, pl.expected_seconds))
    y, s0, rhs, cpu, last = y0, 0, 0, 0.0, None
    checked = (y0, t_start)
    status, message = 0, None
    try:
        while s0 < n_steps:
            cap = _dense.EVENT_SEGMENT_STEPS["numpy" if runner.state["backend"] == "numpy" else "compiled"]
            L, sub = _segment(s0, n_steps, np.minimum(N, cap) if terminal else N, save_every)
            # numpy writes the segment straight into the output when its start is a saved state
            direct = runner.state["backend"] == "numpy" and s0 % save_every == 0 and sub == save_every
            buf = out[..., k - 1 : k + L // sub + (1 if L % sub else 0)] if direct else None
            try:
                seg = runner(run_fi, y, L, s0, sub, check_every, buf)
            except IntegrationError as exc:
                if direct and errors == "return":  # the states this segment saved before it failed are kept
                    done = max(0, min((int(round((exc.t - t_start) / dt)) - s0) // sub, L // sub, ts.size - k))
                    ts[k : k + done] = t_start + dt * (s0 + sub * np.arange(1, done + 1)).astype(float)
                    k += done
                raise policy.failure(run_fi, exc, checked) from None
            last = seg
            rhs += seg.rhs_evaluations
            cpu += seg.cpu_seconds
            gidx = s0 + np.round((seg.t - (t_start + s0 * dt)) / dt).astype(int)
            keep = np.nonzero((gidx % save_every == 0) | (gidx == n_steps))[0]
            keep = keep[keep >= 1]
            m = keep.size
            ts[k : k + m] = t_start + dt * gidx[keep].astype(float)
            grid[k : k + m] = gidx[keep]
            if m and gidx[keep[-1]] == n_steps:
                ts[k + m - 1] = t_end
            if not direct:
                out[..., k : k + m] = seg.y[..., keep]
            k_prev, k = k, k + m
            y = seg.y[..., -1]
            s0 += L
            bar.update(L)
            if tracker:
                hit = tracker.advance(ts[k_prev:k], out[..., k_prev:k], grid[k_prev:k])
                if hit is not None:  # a terminal event: the run ends there
                    k, status, message = _stop_at_event(hit, k_prev, ts, out, grid), 1, MESSAGE_EVENT
                    break
            if not math.isfinite(pl.expected_seconds) and s0 < n_steps:  # compiled: measured now
                pl.seconds_per_step = seg.cpu_seconds / L
                pl.expected_seconds = pl.seconds_per_step * n_steps
                if _want_progress(progress, pl.expected_seconds) and not bar.enabled:
                    bar = Progress(n_steps, desc, True)
                    bar.update(s0)
            if s0 >= n_steps:
                break
            if policy.active and (not terminal or s0 >= next_guard):  # short event segments: the guard's own pace
                run_fi, N = policy.between(run_fi, y, s0, N)
                next_guard = s0 + N
                checked = (y, t_start + s0 * dt)
                stepper.switch(s0, run_fi)  # the steps from s0 on: their gains for the partial steps
        if h_last and not status:  # the last step, shortened to end at t_final
            y_last = stepper.step(y[None], [h_last])[0]
            if not np.all(np.isfinite(y_last)):
                raise _last_step_failure(policy, run_fi, sch, y, y_last, names, t_end, t_final, n_steps) from None
            ts[k], out[..., k], grid[k] = t_final, y_last, _dense.OFF_GRID
            k += 1
            if tracker:
                hit = tracker.advance(ts[k - 1 : k], out[..., k - 1 : k], grid[k - 1 : k])
                if hit is not None:
                    k, status, message = _stop_at_event(hit, k - 1, ts, out, grid), 1, MESSAGE_EVENT
        policy.after(ts[:k], np.moveaxis(out[..., :k], -1, 0))
    except (IntegrationError, StabilityError) as exc:
        if errors == "raise":
            raise
        status, message = -1, str(exc)
        y_bad = np.asarray(getattr(exc, "y", None), dtype=float)
        if y_bad.shape == y0.shape and math.isfinite(exc.t) and exc.t > ts[k - 1] and k < ts.size:
            ts[k], out[..., k], grid[k] = exc.t, y_bad, int(round((exc.t - t_start) / dt))
            k += 1
    finally:
        bar.close()
    sol = Solution(ts[:k], out[..., :k], sch.name, dt, n_steps + (1 if h_last else 0), rhs, cpu, tuple(names))
    if status:
        sol.status, sol.success, sol.message = status, status >= 0, message
    sol.integrator = user_fi
    if tracker:
        sol.t_events, sol.y_events = tracker.results()
    if dense_output or t_eval is not None:
        interp = _dense.DenseOutput(stepper, sol.t, sol.y, grid[:k])
        if dense_output:
            sol.sol = interp
        if t_eval is not None:
            te = t_eval[t_eval <= sol.t[-1]] if status else t_eval  # a t_eval time at a terminal event is kept
            sol.t, sol.y = te, interp(te)
    sol.rhs_evaluations += stepper.steps * sch.stages  # the partial steps (each a step of the scheme)
    for attr in ("backend", "wall_seconds"):
        if last is not None and hasattr(last, attr):
            setattr(sol, attr, getattr(last, attr))
    sol.backend = getattr(sol, "backend", runner.state["backend"])
    if sensitivities:  # d y / d (y0, parameters) at the saved states (liefi.integrator.sensitivity)
        from .sensitivity import attach

        attach(sol, run_fi, sch, y0, dt, n_steps, grid[:k], sensitivities, report=policy.report, t0=t_start)
    if adjoint is not None:  # sol.vjp: the gradient of a scalar loss by reverse mode (liefi.integrator.adjoint)
        from .adjoint import attach as attach_adjoint

        attach_adjoint(sol, run_fi, sch, y0, dt, n_steps, grid[:k], adjoint, report=policy.report, t0=t_start)
    sol.stability = policy.report
    sol.dropped = list(run_fi.dropped)
    _run_gains.carry_dropped(sol.stability, run_fi.dropped)  # its gains replay as they are (gains=)
    sol.plan = pl
    sol.method = _tol.describe(sch.name, dt, getattr(user_fi, "gains_mode", "fixed"), sol.backend, chosen=chosen,
                               scheme_given=scheme_given, dt_given=dt_given)
    if last_note:
        sol.method["last_step"] = h_last if h_last else float(dt)
        sol.method["why"] += "; " + last_note
    sol.overhead_seconds = max(0.0, time.process_time() - start_all - cpu)
    return sol


def _finite_positive(x):
    try:
        return not isinstance(x, (bool, np.bool_, str, bytes)) and math.isfinite(float(x)) and float(x) > 0
    except (TypeError, ValueError):
        return False


def _last_step_failure(policy, run_fi, sch, y, y_bad, names, t_end, t_final, n_steps):
    """The :class:`~liefi.schemes.IntegrationError` of a shortened last step that gave non-finite numbers."""
    bad = np.nonzero((~np.isfinite(y_bad)).reshape(-1, y_bad.shape[-1]).any(axis=0))[0]
    comps = [names[c] for c in bad]
    msg = (f"integration with {sch.name} produced non-finite values in the last step, shortened to "
           f"{t_final - t_end:g} (t={t_final:g}), in components {comps}; the last finite state is at t={t_end:g}.")
    exc = IntegrationError(msg, t_end, n_steps + 1, y, comps)
    advice = str(policy.failure(run_fi, exc, (y, t_end))).split(f"the last finite state is at t={t_end:g}. ", 1)
    return IntegrationError(msg + (" " + advice[1] if len(advice) == 2 else ""), t_end, n_steps + 1, y, comps)


def _stop_at_event(hit, k_prev, ts, out, grid):
    """End the saved output at a terminal event ``hit = (t, y, j)`` (:meth:`liefi.integrator.dense.EventTracker.advance`).

    The states up to the ``j``-th new one (at ``k_prev + j``) are kept; the
    event's state is saved after them unless it is that saved state.  Returns
    the new number of saved states.
    """
    from . import dense as _dense

    t_ev, y_ev, j = hit
    k = k_prev + j
    if t_ev > ts[k - 1]:
        if t_ev != ts[k]:  # inside the step: a partial-step state, off the grid
            grid[k] = _dense.OFF_GRID
        ts[k], out[..., k] = t_ev, y_ev
        k += 1
    return k


# ------------------------------------------------------------------------------------------
# guards of the paths that do not go through the fixed-step loop
# ------------------------------------------------------------------------------------------


def check_step_count(dt, t_final, max_steps=None, *, name="dt",
                     advice="take a larger dt or a shorter t_final, or raise max_steps"):
    """Refuse, before any work, a run of more than ``max_steps`` steps (default :data:`MAX_RUN_STEPS`).

    The one check of a run's length that ``liefi run`` and ``liefi bench`` share.
    The count ``t_final / dt`` is the whole estimate: at liefi's fastest (about a
    microsecond a step, compiled) 1e8 steps take minutes, with numpy hours.
    Returns the count; raises a ``ValueError`` starting with ``name`` and ending
    with ``advice`` (the caller spells its own flags there).
    """
    n = float(t_final) / float(dt)
    limit = MAX_RUN_STEPS if max_steps is None else max_steps
    if n > limit:
        raise ValueError(
            f"{name}: dt {float(dt):g} over t_final {float(t_final):g} is {n:.3g} steps, more than the {limit:.3g} "
            f"allowed (about {n * 1e-6 / 3600:.2g} h at a microsecond a step, compiled; far longer with numpy); "
            + advice
        )
    return n


def check_ivp(fi, scheme, t_final, *, max_steps=IVP_MAX_STEPS):
    """Refuse an explicit ``scipy:`` method on a stiff feedback field before it runs for minutes.

    An explicit adaptive method keeps ``h lambda_max <= beta`` (``beta`` the
    real stability bound of its tableau), so it needs at least
    ``t_final lambda_max / beta`` steps; past ``max_steps`` it is refused with
    the advice to use ``scipy:LSODA`` or ``scipy:BDF``.  ``lambda_max`` is the
    Gram estimate of :func:`liefi.integrator.stability.stiffness` at the start (``O(1)``).
    """
    from .stability import stiffness

    sch = _registry.get(scheme, kind="scipy")
    if sch.stiff_safe:
        return None
    with np.errstate(all="ignore"):
        lam = float(np.max(stiffness(fi, fi.y0).lam, initial=0.0))
    need = float(t_final) * lam / sch.real_stability_bound
    if need > max_steps:
        raise ValueError(
            f"scheme: {sch.name} is explicit and the feedback term is stiff (lambda_max = {lam:.3g}, the largest "
            f"eigenvalue of Hess V at these gains): it would need at least {need:.3g} steps to stay stable over "
            f"t in [0, {float(t_final):g}]. Use scheme='scipy:LSODA' or 'scipy:BDF' (stiff-safe), or lower the gains."
        )
    return need


def check_result_drift(fi, t, Y, names, scheme, dt, *, limit=None):
    """The drift guard of a run made outside the loop (e.g. DLA): refuse garbage returned as a result.

    ``Y`` is ``(len(names), n_t)``.  When the largest relative drift of the
    integrator's invariants (:func:`liefi.integrator.stability.drift`, relative to their
    scale at the start) passes ``limit`` (default
    :data:`liefi.integrator.stability.GUARD_DRIFT` x 100, i.e. O(1): the run lost every
    invariant) a :class:`~liefi.integrator.stability.StabilityError` says when.
    """
    from .stability import GUARD_DRIFT, StabilityError, drift, drift_scales

    limit = 100 * GUARD_DRIFT if limit is None else limit
    try:
        idx = [list(names).index(n) for n in fi.names]
    except ValueError:
        return None
    states = np.stack([np.asarray(Y[i], float) for i in idx], -1)  # (n_t, n)
    scales = drift_scales(fi)
    finite = np.all(np.isfinite(states), axis=-1)
    n_t = states.shape[0]
    d = np.full(n_t, np.nan)

    def at(i):
        if np.isnan(d[i]):
            d[i] = drift(fi, states[i], scales)[0] if finite[i] else math.inf
        return d[i]

    # at most ~256 states checked (every k-th, and the last): a run that lost its invariants
    # stays lost, and the first bad state is then looked for in the stride before it
    k = max(1, -(-n_t // 256))
    with np.errstate(all="ignore"):
        first = next((int(i) for i in np.r_[np.arange(0, n_t, k), n_t - 1] if not at(int(i)) <= limit), None)
        nonfinite = np.nonzero(~finite)[0]
        if nonfinite.size and (first is None or nonfinite[0] < first):
            first = int(nonfinite[0])
        if first is not None:
            first = next(i for i in range(max(0, first - k + 1), first + 1) if not at(i) <= limit)
    bad = np.array([] if first is None else [first])
    if bad.size:
        i = int(bad[0])
        who = drift(fi, states[i], scales)[1] if math.isfinite(d[i]) else "the state"
        raise StabilityError(
            f"the {scheme} run became meaningless at t={float(t[i]):g}: the drift of {who} reached "
            f"{d[i]:.3g} x its scale (dt = {dt:g}); the step does not resolve the motion: reduce dt. "
            "No result is returned.",
            float(t[i]), i, states[max(i - 1, 0)], [who],
        )
    return float(np.nanmax(d)) if n_t else 0.0
