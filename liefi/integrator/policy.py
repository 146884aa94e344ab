"""The run policy: the step and the gains of one fixed-step run, decided in one place.

The run loop (:mod:`liefi.integrator.run`) drives; it asks one :class:`Policy`

* :meth:`Policy.step` -- the step: as given, or for a tolerance (:func:`liefi.integrator.tolerance.choose_step`:
  the error estimate, shortened until the step resolves the unforced motion), whole steps to the end;
* :meth:`Policy.drops` -- the invariants the scheme keeps exactly (:func:`liefi.integrator.gains.exact_drops`:
  their gain is 0, they leave ``V``);
* :meth:`Policy.start` -- the gains to start with, asked of :mod:`liefi.integrator.gains` once
  (:func:`liefi.integrator.gains.run_gains`: ``gains="auto"`` the accurate rate, adapted along
  the run only near the stability limit; fixed gains lowered where ``dt lambda_max``
  passes the rate with ``adaptive=True``) and the pre-run verdict
  (:meth:`liefi.integrator.guard.Guard.before`: :func:`liefi.integrator.stability.check`, a warning at the
  limit, a refusal 10x past it; the resolution of the unforced dynamics);
* :meth:`Policy.segment_length` and, once per segment, :meth:`Policy.between` --
  the verdict on the segment, asked of the guard once (:meth:`liefi.integrator.guard.Guard.segment`:
  the drift of the invariants, ``dt lambda_max``; :class:`~liefi.integrator.stability.StabilityError`
  when it exploded past the limit), and the length and gains of the next one
  (adaptive runs, member by member in an ensemble: :func:`liefi.integrator.gains.adapted_gains`,
  asked once);
* :meth:`Policy.after` -- the audit of the saved states; :meth:`Policy.failure` --
  what to change, appended to an :class:`~liefi.schemes.IntegrationError` (the guard's).

Below it, and never calling back up: :mod:`liefi.integrator.gains` (every choice of gains:
the unit-rate gains, the drift bound and the accurate rate, the contraction rate,
the gains re-chosen along a run), :mod:`liefi.integrator.tolerance` (the error estimate) and
:mod:`liefi.integrator.guard` (the verdicts, the audit and the messages made from their
numbers), and under them the theory, :mod:`liefi.integrator.stability` (the Hessian of
``V``, ``lambda_max``, the schemes' bounds, the unforced rates, the pilot), which
chooses nothing.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from .gains import adapted_gains, exact_drops, run_gains
from .guard import Guard, RunReport
from ..schemes import steps_for
from .stability import RESOLUTION_LIMIT, LiefiStabilityWarning, dynamics_rates, stiffness
from .tolerance import DEFAULT_RTOL, LiefiToleranceWarning, check_tolerance, chosen_step, unmeasured_message


def _span_length(t0, t_end):
    """``t_end - t0`` when it is a positive finite number, else ``1.0`` (:func:`steps_for` then names the fault)."""
    try:
        length = float(t_end) - float(t0)
    except (TypeError, ValueError):
        return 1.0
    return length if math.isfinite(length) and length > 0 else 1.0




def _chunk(s0, n_steps, N, save_every):
    """``(length, sub_save)`` of the next segment so that saved indices stay multiples of ``save_every``."""
    left = n_steps - s0
    nxt = (s0 // save_every + 1) * save_every
    if save_every <= N:
        if s0 % save_every:  # first back onto a multiple of save_every
            L = min(nxt - s0, left)
            return L, L
        L = save_every * max(1, N // save_every)
        return min(L, left), save_every
    L = min(N, nxt - s0, left)
    return L, L


def _segment(s0, n_steps, N, save_every):
    """``(length, sub_save)`` of the next segment: :func:`_chunk` for a common stride ``N``.

    ``N`` an array: the steps each member of an adaptive ensemble has left until
    its own next check (:meth:`Policy.segment_length`); the segment
    ends at the first of them, and not past a saved index when it starts between two.
    """
    if np.ndim(N) == 0:
        return _chunk(s0, n_steps, int(N), save_every)
    L = min(int(np.min(N)), n_steps - s0)
    if s0 % save_every:
        L = min(L, (s0 // save_every + 1) * save_every - s0)
    return L, (save_every if s0 % save_every == 0 and L >= save_every else L)


class Policy:
    """The step and the gains of one fixed-step run of a feedback integrator, and their checks (module docstring).

    Parameters as :func:`liefi.integrator.run.run_feedback`.  ``scheme`` is the scheme object the run loop
    resolved (explicit or split; never a name); ``beta`` its real stability bound.
    """

    def __init__(self, scheme, *, backend, check_stability=True, adaptive=None, stacklevel=3, choose_order=False,
                 resolution_limit=None):
        self.sch = scheme
        #: a step chosen for a tolerance may also choose the order (:func:`liefi.integrator.tolerance.choose_order`)
        self.choose_order = bool(choose_order)
        #: ``dt`` times the fastest rate that resolves the motion (a step for a tolerance brings its own)
        self.resolution_limit = RESOLUTION_LIMIT if resolution_limit is None else float(resolution_limit)
        self.beta = float(scheme.real_stability_bound)
        self.split = scheme.kind == "split"
        self.backend = backend
        self.check_stability = bool(check_stability)
        self._adaptive_arg = adaptive
        self.stacklevel = stacklevel
        #: the ``info`` of :func:`liefi.integrator.tolerance.choose_step` when the step was chosen for a tolerance
        self.chosen = None

    # --- the step -----------------------------------------------------------------------
    def step(self, fi, y0, t_start, t_end, dt, rtol, atol, *, check_every=1, max_steps, max_step=None):
        """``(dt, t_end, n_steps, check_every)``: the run's step, as given or chosen for ``rtol``/``atol``.

        ``dt=None``: :meth:`tolerance_step`, shortened to at most ``max_step``
        (``solve_ivp``'s cap; a given ``dt`` above it is refused).  Then
        :func:`liefi.schemes.steps_for`: a ``dt`` that does not divide
        ``[t_start, t_end]`` is refused with the nearest one that does.
        """
        cap = _max_step(max_step)
        if cap is not None and isinstance(dt, (int, float, np.integer, np.floating)) and dt > cap:
            raise ValueError(f"max_step: the given dt = {dt!r} is larger than max_step = {max_step!r}; give one "
                             "or the other (max_step caps a step chosen for rtol)")
        if dt is None:
            dt, _ = self.tolerance_step(fi, y0, t_start, t_end, rtol, atol, max_steps=max_steps)
            if cap is not None and dt > cap:
                dt = (t_end - t_start) / math.ceil((t_end - t_start) / cap - 1e-9)
                if self.chosen is not None:
                    self.chosen["max_step"] = cap
        dt, t_end, n_steps, _, check_every = steps_for(dt, t_end, check_every=check_every, t0=t_start)
        return dt, t_end, n_steps, check_every

    def tolerance_step(self, fi, y0, t_start, t_end, rtol, atol, *, max_steps):
        """``(dt, info)``: the step for ``rtol``/``atol`` over ``[t_start, t_end]`` (:func:`liefi.integrator.tolerance.choose_step`).

        ``y0`` the start (a batch: one step for every member, the most
        demanding).  A start that is not a finite state of ``fi`` gets the whole
        span as its step (the run then refuses ``y0``, naming what is wrong); a
        tolerance that needs more than ``max_steps`` steps is refused.
        """
        rtol = DEFAULT_RTOL if rtol is None else rtol
        check_tolerance(rtol, atol)
        t_end = steps_for(_span_length(t_start, t_end), t_end, t0=t_start)[1]  # the span checked first
        y_pilot = fi.y0 if y0 is None else np.asarray(y0, dtype=float)
        if not (np.shape(y_pilot)[-1:] == (fi.n,) and np.all(np.isfinite(y_pilot))):
            return t_end - t_start, None
        dt, self.chosen, sch = chosen_step(fi.for_batch(np.shape(y_pilot)[:-1]), self.sch, y_pilot, t_start, t_end,
                                           rtol, atol, backend=self.backend, choose_order=self.choose_order)
        self._set_scheme(sch)  # the order chosen for the tolerance
        if self.chosen.get("unmeasured"):
            warnings.warn(unmeasured_message(self.chosen, dt, t_start, t_end), LiefiToleranceWarning,
                          stacklevel=self.stacklevel + 2)
        self.resolution_limit = self.chosen.get("resolution_limit", RESOLUTION_LIMIT)
        if (t_end - t_start) / dt > max_steps:
            raise ValueError(f"rtol: {rtol!r} needs {(t_end - t_start) / dt:.3g} steps over t in [{t_start:g}, "
                             f"{t_end:g}], more than the {max_steps:.0e} allowed; loosen rtol or atol")
        return dt, self.chosen

    def _set_scheme(self, sch):
        self.sch = sch
        self.beta = float(self.sch.real_stability_bound)
        self.split = self.sch.kind == "split"

    def drops(self, fi, y0):
        """``{name: reason}``: the invariants left out of ``V`` (:func:`exact_drops`: their gain is 0)."""
        return exact_drops(fi, self.sch, y0)

    @property
    def active(self):
        """Whether the run must be watched between segments."""
        return self.check_stability or self.adaptive

    def _warn(self, msg, depth=0):
        """Warn (and report) ``msg`` at the caller's level of the run; ``depth``: the frames between here and the policy."""
        self.report.warnings.append(msg)
        warnings.warn(msg, LiefiStabilityWarning, stacklevel=self.stacklevel + 1 + depth)

    # --- the gains and the checks ---------------------------------------------------------
    def start(self, fi, dt, n_steps, y0, *, t0=0.0, monitor_every=None):
        """The integrator with the gains to start with, after the pre-run checks (module docstring).

        ``gains="auto"``: every member of an ensemble gets its own rate and gains
        (those of its single run); on an explicit tableau they are adapted along
        the run only when the accurate rate sits near the stability limit.
        Fixed gains: :func:`liefi.integrator.stability.check` (warn at the limit, refuse 10x
        past it) along a short pilot.  ``O(1)`` calls over the batch.
        """
        self.fi = fi
        self.dt = dt
        self.t0 = float(t0)  # the run starts at t0: step s is at t0 + s dt
        self.n_steps = n_steps
        self.auto = getattr(fi, "gains_mode", "fixed") == "auto"
        self.monitor_every = monitor_every
        self.ratio_set = None
        self.sched_t, self.sched_g = [self.t0], []
        self.resolutions = math.nan
        #: the ensemble's shape; members of an ensemble are adapted (and checked) on their own schedule
        self.batch = tuple(getattr(fi, "batch", ()))
        # the gains to start with, their rate and which members adapt: one question to liefi.integrator.gains
        # (gains="auto": the accurate rate z*, every member of an ensemble its own; adapted along the
        # run only where z* sits near the stability limit); then the pre-run verdict: one question
        # to the guard; O(1) calls over the batch
        run_fi, self.rate, self.adaptive, self.mask, omega = run_gains(fi, y0, dt, self.sch, self.n_steps * dt,
                                                                      adaptive=self._adaptive_arg)
        self.report = rep = RunReport(adaptive=self.adaptive)
        rep.gains = dict(run_fi.gains)
        self.sched_g = [dict(run_fi.gains)]
        if self.adaptive:  # each member's own pace of adaptation (Policy.segment_length), guard or not
            with np.errstate(all="ignore"):
                self.resolutions = dt * (dynamics_rates(run_fi, y0) if omega is None else omega)
        self.guard = Guard(self.sch, dt, rep, self._warn, check_stability=self.check_stability,
                           resolution_limit=self.resolution_limit, t0=self.t0)
        self.guard.before(run_fi, fi, y0, self.n_steps, adaptive=self.adaptive, backend=self.backend,
                          watch=self.active, stacklevel=self.stacklevel + 1)
        return run_fi

    def segment_length(self, n_steps, save_every=1):
        """Steps between two checks (deterministic: results never depend on timing).

        An adaptive ensemble: each member is checked (and its gains adapted) on
        the schedule of its own single run; the segment runs to the next check
        of any member (an array: the steps each adapted member has left).
        """
        N = self._segment_length(n_steps)
        self.save_every, self.total = save_every, n_steps
        if not (self.adaptive and self.batch):
            return N
        B = int(np.prod(self.batch, dtype=int))
        self.N_i = np.full(B, N, dtype=np.int64)
        cap = np.broadcast_to(self.N_cap, (B,)) if np.ndim(self.N_cap) else np.full(B, self.N_cap)
        self.N_cap_i = np.asarray(cap, dtype=np.int64)
        self.ratio_set_i = np.full(B, np.nan)
        self.next_i = np.array([_chunk(0, n_steps, int(n), save_every)[0] for n in self.N_i])
        return self._left(0)

    def _left(self, s0):
        """Steps until the next check of an adapted member (an array), or the non-adapted stride."""
        m = np.asarray(self.mask).reshape(-1)
        return self.next_i[m] - s0 if np.any(m) else np.array([self._segment_length(self.total - s0)])

    def _segment_length(self, n_steps):
        if self.monitor_every is not None:
            N = self.monitor_every
        elif self.adaptive:
            N = 100
        else:
            # a check costs about ten numpy steps of one state, and hundreds of compiled ones:
            # at most 100 checks on numpy, 20 compiled (the audit covers the states between them)
            N = max(200, n_steps // 100) if self.backend == "numpy" else max(20000, n_steps // 20)
        if self.adaptive and self.monitor_every is None:
            res = np.asarray(self.resolutions, float)  # dt x each member's fastest unforced rate
            r = np.where(np.isfinite(res), res / self.dt, 1.0)
            cap = np.minimum(50000, np.maximum(10, 0.5 / (self.dt * np.maximum(r, 1e-2)))).astype(np.int64)
            self.N_cap = int(cap) if cap.ndim == 0 else cap.reshape(-1)
        return max(1, min(N, n_steps))

    # --- between segments ---------------------------------------------------------------
    def between(self, run_fi, y, s0, N):
        """Check after ``s0`` steps at state ``y``; returns ``(run_fi, N)`` for the next segment."""
        dt, beta = self.dt, self.beta
        t_now = self.t0 + s0 * dt
        y_all = y
        sub = None
        if self.adaptive and self.batch:
            # an adapted ensemble: each member is checked on its own schedule (that of its single run),
            # so only the members due now (and those not adapted, checked at every segment) are evaluated
            due = (self.next_i == s0) | ~np.asarray(self.mask).reshape(-1)
            sub = np.nonzero(due)[0]
            run_fi_all, run_fi = run_fi, run_fi.members(sub)
            y = np.asarray(y, float).reshape(-1, run_fi.n)[sub]
        # the verdict on the segment: one question to the guard (some members: with their own per-member data)
        with run_fi.selection():
            st, _, ratio = self.guard.segment(run_fi, y, t_now, s0, y_all, adaptive=self.adaptive)
        if not self.adaptive:
            return run_fi, N
        # the next gains, asked of liefi.integrator.gains once: for the whole run, or for the members due now
        base, rate = self.fi, self.rate
        if sub is not None:
            keep = np.asarray(self.mask).reshape(-1)[sub] & (self.next_i[sub] == s0)  # those adapted now
            idx = sub[keep]
            if not idx.size:  # a segment that ended at a saved index: no member adapts now
                self._record(t_now, run_fi_all.gains)
                return run_fi_all, self._left(s0)
            y = y[keep]
            base = self.fi.members(idx)
            rate = rate if np.ndim(rate) == 0 else np.asarray(rate).reshape(-1)[idx]
        with base.selection():
            new = adapted_gains(base, y, rate, dt, auto=self.auto, split=self.split)
        if sub is not None:
            return self._adapt_members(run_fi_all, y, s0, t_now, idx, np.asarray(st.lam, float).reshape(-1)[keep], new)
        if self.monitor_every is None and self.ratio_set is not None:
            if ratio > self.ratio_set * 1.05 or ratio < self.ratio_set / 1.05:
                N = max(10, N // 2)
            elif self.ratio_set / 1.02 <= ratio <= self.ratio_set * 1.02:
                N = min(2 * N, self.N_cap)
        run_fi = run_fi.with_gains(new)
        self.ratio_set = (dt * float(np.max(stiffness(run_fi, y).lam, initial=0.0)) / beta
                          if math.isfinite(beta) else 0.0)
        self._record(t_now, new)
        return run_fi, N

    def _record(self, t_now, gains):
        """The gains in effect from ``t_now`` on (the report's history and the audit's schedule)."""
        self.report.gain_times.append(t_now)
        self.report.gain_history.append(dict(gains))
        self.sched_t.append(t_now)
        self.sched_g.append(dict(gains))

    def _adapt_members(self, run_fi, y, s0, t_now, idx, lam, new):
        """The adaptation of an ensemble: the members ``idx`` whose own check falls at step ``s0`` (module docstring).

        ``y`` their states at the time ``t_now``, ``lam`` their ``lambda_max`` at the gains of the segment
        that ended, ``new`` their next gains (:func:`liefi.integrator.gains.adapted_gains`); the
        other members keep theirs and their schedule.
        """
        dt, beta = self.dt, self.beta
        ratio = dt * lam / beta if math.isfinite(beta) else np.zeros_like(lam)
        if self.monitor_every is None:
            rs = self.ratio_set_i[idx]
            with np.errstate(invalid="ignore"):
                off = (ratio > rs * 1.05) | (ratio < rs / 1.05)
                near = (rs / 1.02 <= ratio) & (ratio <= rs * 1.02)
            Ni = self.N_i[idx]
            self.N_i[idx] = np.where(off, np.maximum(10, Ni // 2), np.where(near, np.minimum(2 * Ni, self.N_cap_i[idx]),
                                                                              Ni))
        B = int(np.prod(self.batch, dtype=int))
        gains = {}
        for k, v in new.items():  # the due members' new gains, the others' unchanged
            g = np.array(np.broadcast_to(np.asarray(run_fi.gains[k], float), self.batch)).reshape(B)
            g[idx] = np.broadcast_to(np.asarray(v, float), idx.shape)
            gains[k] = g.reshape(self.batch)
        run_fi = run_fi.with_gains(gains)
        due = run_fi.members(idx)
        with np.errstate(all="ignore"), due.selection():
            lam2 = np.asarray(stiffness(due, y).lam, float).reshape(-1)
        self.ratio_set_i[idx] = dt * lam2 / beta if math.isfinite(beta) else 0.0
        for i in idx:
            self.next_i[i] = s0 + _chunk(s0, self.total, int(self.N_i[i]), self.save_every)[0]
        self._record(t_now, gains)
        return run_fi, self._left(s0)

    # --- after ------------------------------------------------------------------------------
    def after(self, ts, Ys):
        """Audit the saved states ``Ys`` (``(n_t, ..., n)``) at times ``ts`` (:meth:`liefi.integrator.guard.Guard.audit`)."""
        self.guard.audit(self.fi, ts, Ys, (self.sched_t, self.sched_g), backend=self.backend)

    # --- failure --------------------------------------------------------------------------
    def failure(self, run_fi, exc, earlier):
        """The :class:`~liefi.schemes.IntegrationError` to raise for ``exc``, with the advice appended."""
        return self.guard.failure(run_fi, exc, earlier)


def _max_step(max_step):
    """``max_step`` checked: ``None`` (no cap: also for ``inf``, ``solve_ivp``'s default) or a positive number."""
    if max_step is None:
        return None
    from ..schemes import positive_number

    if isinstance(max_step, (int, float, np.integer, np.floating)) and max_step == math.inf:
        return None
    return positive_number(max_step, "max_step", "the largest step must be a positive number (or inf: no cap)")
