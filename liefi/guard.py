"""The stability guard: the policy :mod:`liefi.run` consults before, between and after segments.

The guard does not drive the loop.  The run module asks it

* :meth:`Guard.before` -- the pre-run estimate (:func:`liefi.stability.estimate`
  at the start: ``lambda_max`` from the Gram matrix of the invariants'
  gradients over the whole batch, vectorized, ``O(1)`` calls per run), a
  warning at the limit, a refusal 10x past it, the resolution of the
  unforced dynamics on a few members of the batch;
* :meth:`Guard.between` -- after a segment: ``dt lambda_max`` and the drift of
  the invariants; stops with :class:`~liefi.stability.StabilityError` when the
  drift explodes past the limit, warns once when the stiffness grew past it,
  and (adaptive runs) gives the new gains;
* :meth:`Guard.after` -- the audit of the saved states (a run may have
  settled into O(1) garbage between two checks);
* :meth:`Guard.advice` -- what to change, appended to an
  :class:`~liefi.schemes.IntegrationError`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from ._data import check_real
from .schemes import IntegrationError
from .schemes import split as _split
from .stability import (
    GUARD_DRIFT,
    PILOT_GUARD_EVALS,
    _max_evals,
    LIMIT_BAND,
    RESOLUTION_LIMIT,
    LiefiStabilityWarning,
    StabilityError,
    drift,
    drift_scales,
    dynamics_rate,
    dynamics_rates,
    metric_defect,
    stiffness,
)

_stiff = _split


def _lam_schedule(fi, Y, gains_list):
    """``lambda_max`` at states ``Y`` (``(N, ..., n)``) with per-state gain dicts ``gains_list``."""
    jet = fi.invariant_gradients(Y)
    batch = Y.shape[1:-1]  # each gain a number or one per member (shape batch)
    K = np.stack([np.stack([np.broadcast_to(np.asarray(g[nm], float), batch) for nm in jet.names], -1)
                  if jet.names else np.zeros(batch + (0,)) for g in gains_list])  # (N, ..., m)
    lam = np.zeros(Y.shape[:-1])
    if jet.names:
        W = jet.grad * np.sqrt(K)[..., None]
        lam = np.linalg.eigvalsh(W @ np.swapaxes(W, -1, -2))[..., -1]
    if fi.use_penalty:
        k0 = np.stack([np.broadcast_to(np.asarray(g.get("penalty", 0.0), float), batch) for g in gains_list])
        lam = np.maximum(lam, k0 * fi.system.space.group.penalty_hessian_max(Y[..., : fi.nc]))
    return lam.reshape(len(gains_list), -1).max(axis=1), jet


def _guard_verdict(ratio_seen_beyond, rel, delta0):
    """``"error"`` (past the limit and drifted), ``"warn"`` (a large drift within the limit) or ``None``."""
    if ratio_seen_beyond and rel > max(GUARD_DRIFT, 10 * delta0):
        return "error"
    if not (rel <= max(0.1, 2 * delta0)):
        return "warn"
    return None


def _audit(fi, ts, Ys, dt, beta, sch, scales, delta0, schedule, max_points=2000, t0=0.0):
    """After a run: the guard's rule on (up to ``max_points`` of) the saved states.

    Between two checks a run may have gone unstable and settled into O(1)
    garbage (a segment can be long); this makes sure no such result is
    returned.  ``schedule = (times, gains)``: the gains in effect from each time on.
    Returns ``(t, name, rel)`` of a large drift within the limit (for a warning), or None.
    """
    idx = np.unique(np.linspace(0, len(ts) - 1, min(len(ts), max_points)).astype(int))
    Y = np.stack([Ys[i] for i in idx])
    tt = ts[idx]
    times, glist = schedule
    which = np.searchsorted(np.asarray(times), tt, side="right") - 1
    gains_pt = [glist[max(w, 0)] for w in which]
    with np.errstate(all="ignore"):
        lam, jet = _lam_schedule(fi, Y, gains_pt)
        ratio = dt * lam / beta if math.isfinite(beta) else np.zeros(len(idx))
        cur = drift_scales(fi, Y)
        sc = {k: max(scales.get(k, 0.0), cur.get(k, 0.0)) or 1.0 for k in cur}
        rel = np.zeros(len(idx))
        who = np.full(len(idx), "", dtype=object)
        res = np.abs(jet.residual).reshape(len(idx), -1, max(len(jet.names), 1)).max(axis=1) if jet.names else None
        for j, nm in enumerate(jet.names):
            r = res[:, j] / sc.get(nm, 1.0)
            who = np.where(~(r <= rel), nm, who)
            rel = np.where(~(r <= rel), r, rel)
        if fi.use_penalty:
            P = fi.system.space.group.penalty(Y[..., : fi.nc]).reshape(len(idx), -1).max(axis=1)
            r = 2 * np.sqrt(np.maximum(P, 0.0))
            who = np.where(~(r <= rel), "penalty", who)
            rel = np.where(~(r <= rel), r, rel)
    beyond = np.maximum.accumulate(ratio > 1 + LIMIT_BAND)
    warn = None
    for i in range(len(idx)):
        v = _guard_verdict(bool(beyond[i]), float(rel[i]), delta0)
        if v == "error":
            t_bad, nm = float(tt[i]), str(who[i])
            t_over = float(tt[int(np.argmax(ratio > 1 + LIMIT_BAND))])
            md = metric_defect(fi, Y[: i + 1])
            if md:  # the data, not the gains
                raise StabilityError(f"the run became meaningless at t={t_bad:g}: the drift of {nm} reached "
                                     f"{float(rel[i]):.3g} x its scale. {md} No result is returned.",
                                     t_bad, int(round((t_bad - t0) / dt)), Ys[idx[i]], [nm])
            raise StabilityError(
                f"the run became meaningless at t={t_bad:g}: the drift of {nm} reached {float(rel[i]):.3g} x "
                f"its scale after dt*lambda_max exceeded the stability bound {beta:.4g} of {sch.name} (at t ~ "
                f"{t_over:g}; largest dt*lambda_max seen {float(np.max(ratio)) * beta:.4g}, largest safe dt there "
                f"{dt / float(np.max(ratio)):.4g}): reduce dt or the gains, or use gains='auto', adaptive=True "
                "or scheme='imex-euler'. No result is returned.",
                t_bad, int(round((t_bad - t0) / dt)), Ys[idx[i]], [nm],
            )
        if v == "warn" and warn is None:
            warn = (float(tt[i]), str(who[i]), float(rel[i]))
    return warn


def _drift_warning(t, who, rel, dt, rate):
    s = (f"liefi: the drift of {who} reached {rel:.3g} x its scale at t = {t:g} although dt*lambda_max stayed "
         f"within the stability bound: the gains are too small to hold the invariants against the scheme's "
         f"error at dt = {dt:g}. Raise the gains (or gains='auto') or reduce dt.")
    if math.isfinite(rate) and rate > RESOLUTION_LIMIT:
        s += f" dt also under-resolves the unforced dynamics (dt times its fastest rate = {rate:.3g})."
    return s


@dataclass
class RunReport:
    """What the stability machinery saw during a run (``solution.stability``).

    Attributes
    ----------
    estimate : StabilityEstimate or None
        The pre-run estimate (None when skipped).
    gains : dict
        The gains at the start of the run.
    adaptive : bool
    gain_times : list of float
        Times of the gain updates (adaptive runs).
    gain_history : list of dict
        The gains from each update on.
    max_ratio : float
        The largest ``dt lambda_max / beta`` seen at the checks.
    monitors : int
        Number of checks during the run.
    warnings : list of str
    """

    estimate: object = None
    gains: dict = field(default_factory=dict)
    adaptive: bool = False
    gain_times: list = field(default_factory=list)
    gain_history: list = field(default_factory=list)
    max_ratio: float = 0.0
    monitors: int = 0
    warnings: list = field(default_factory=list)
    #: ``dt`` times the fastest rate of the unforced dynamics (``nan``: not computed)
    resolution: float = math.nan

    @property
    def final_gains(self):
        return self.gain_history[-1] if self.gain_history else self.gains


def data_defect(fi, y):
    """A message if the system's data fail at a state of ``y`` (else ``""``): the metric loses
    positive definiteness (:func:`metric_defect`), or a datum (metric, constraints, potential,
    vector potential) returns complex values for the real shape point there."""
    md = metric_defect(fi, y)
    if md:
        return md
    try:
        n = fi.system.space.data_dim
        if not n:
            return ""
        x = np.asarray(y, float)[..., fi.nc : fi.nc + n].reshape(-1, n)
        sys_ = fi.system
        for datum in (sys_.metric, sys_.constraints, sys_.potential, sys_.vector_potential):
            if datum is None or datum.constant:
                continue
            with np.errstate(all="ignore"):
                check_real(datum(x), datum.name, x[0] if x.shape[0] == 1 else x)
    except ValueError as exc:
        return (f"{' '.join(str(exc).split())}: the system's data leave the real numbers at this state, which "
                "no choice of gains or step repairs; check their formulas there (e.g. a square root or a "
                "logarithm of a negative number, written for complex input).")
    except Exception:  # noqa: BLE001 -- a diagnostic only
        return ""
    return ""


def _advice(fi, y, t, dt, sch, beta, earlier=None):
    """Text appended to a failure: ``dt lambda_max`` at the last finite state and what to change.

    ``earlier = (y, t)``: a state checked before (used when the last finite one
    is already too large to evaluate).
    """
    states = ((y, t, "At the last finite state"),) + (
        (earlier + ("At the last checked state",),) if earlier is not None else ()
    )
    for yy, tt, lab in states:  # the data first, where the run last was: no gain repairs a bad metric
        md = data_defect(fi, yy)
        if md:
            return f"{lab} (t={tt:g}): {md}"
    found = []
    for yy, tt, lab in states:
        try:
            with np.errstate(all="ignore"):
                st = stiffness(fi, yy)
                lam_ = float(np.max(st.lam))
                if not math.isfinite(lam_):
                    raise FloatingPointError
                dom_ = str(np.asarray(st.dominant, dtype=object).ravel()[int(np.argmax(np.asarray(st.lam).ravel()))])
            found.append((lam_, dom_, yy, tt, lab))
        except Exception:  # noqa: BLE001
            pass
    if not found:
        return (
            "The state was already too large to evaluate the stiffness: reduce dt or the gains, use "
            "gains='auto' or scheme='imex-euler'."
        )
    # A state that has already blown up has a meaningless stiffness: prefer the checked one then.
    pick = found[0]
    if len(found) == 2 and found[0][0] > 10 * found[1][0]:
        pick = found[1]
    lam, dom, y, t, label = pick
    name = getattr(sch, "name", str(sch))
    if math.isfinite(beta) and dt * lam > beta:
        safe = beta / lam
        return (
            f"{label} (t={t:g}) dt*lambda_max = {dt * lam:.4g} exceeds the stability bound "
            f"{beta:.4g} of {name} (lambda_max = {lam:.4g} from {dom}): the feedback term is stiff past the "
            f"limit. Largest safe dt there: {safe:.4g} (or every gain x {safe / dt:.3g}); or use gains='auto', "
            "adaptive=True, or scheme='imex-euler'."
        )
    try:
        rate = dt * dynamics_rate(fi, y)
    except Exception:  # noqa: BLE001
        rate = float("nan")
    if math.isfinite(rate) and rate > RESOLUTION_LIMIT:
        return (
            f"{label} (t={t:g}) dt*lambda_max = {dt * lam:.4g} is within {name}'s bound "
            f"{beta:.4g}, but dt times the fastest rate of the unforced dynamics is {rate:.3g}: the step "
            f"under-resolves the motion; take dt below {dt / rate * 0.2:.3g}."
        )
    return (
        f"{label} (t={t:g}) dt*lambda_max = {dt * lam:.4g} is within {name}'s bound "
        f"{beta:.4g} and dt resolves the dynamics (rate {rate:.3g}): the blow-up is not the feedback's "
        "stiffness; check the system's data near this state (a singular metric or constraint?)."
    )


def _relabel(exc, dt, sch, extra, t0=0.0):
    """Rebuild an IntegrationError (absolute ``t``, ``step`` from the start ``t0``) with our advice appended."""
    comps = list(exc.components or [])
    msg = (
        f"integration with {getattr(sch, 'name', sch)} (dt={dt:g}) produced non-finite values at step "
        f"{exc.step} (t={t0 + exc.step * dt:g}) in components {comps}; the last finite state is at t={exc.t:g}. {extra}"
    )
    return IntegrationError(msg, exc.t, exc.step, exc.y, comps)


#: Largest number of states (batch members x saved points) the post-run audit evaluates
#: (each costs a few field evaluations: the audit stays a few percent of an ensemble's loop).
AUDIT_STATES = 2000
#: ``gains="auto"`` on an explicit tableau adapts the gains along the run (at the accurate rate
#: ``z*``) when ``z*`` is at least this fraction of the real stability bound (Euler: ``z* = 1``).
AUTO_ADAPT_FRACTION = 0.25
#: Members of a batch on which the unforced dynamics' resolution is estimated.
RESOLUTION_MEMBERS = 16


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
    its own next check (:meth:`liefi.guard.Guard.segment_length`); the segment
    ends at the first of them, and not past a saved index when it starts between two.
    """
    if np.ndim(N) == 0:
        return _chunk(s0, n_steps, int(N), save_every)
    L = min(int(np.min(N)), n_steps - s0)
    if s0 % save_every:
        L = min(L, (s0 // save_every + 1) * save_every - s0)
    return L, (save_every if s0 % save_every == 0 and L >= save_every else L)


class Guard:
    """The stability policy of one fixed-step run of a feedback integrator (module docstring).

    Parameters as :func:`liefi.run.run_feedback`.  ``scheme`` is a registry
    scheme (explicit or split); ``beta`` its real stability bound.
    """

    def __init__(self, fi, scheme, dt, n_steps, *, backend, check_stability, adaptive, monitor_every, stacklevel,
                 t0=0.0, resolution_limit=RESOLUTION_LIMIT):
        self.fi = fi
        self.resolution_limit = float(resolution_limit)  # dt omega that resolves the motion (a run's own)
        self.sch = scheme
        self.beta = float(scheme.real_stability_bound)
        self.split = scheme.kind == "split"
        self.dt = dt
        self.t0 = float(t0)  # the run starts at t0: step s is at t0 + s dt
        self.n_steps = n_steps
        self.backend = backend
        self.check_stability = bool(check_stability)
        self.auto = getattr(fi, "gains_mode", "fixed") == "auto"
        # auto on an explicit tableau: the accurate gains (liefi.gains), fixed unless their rate is
        # near the stability limit (decided in before()); on a split scheme: the contraction rate,
        # adapted along the run
        self.adaptive = self.auto if adaptive is None else bool(adaptive)
        self._adaptive_default = adaptive is None
        self.monitor_every = monitor_every
        self.stacklevel = stacklevel
        self.rate = scheme.optimal_rate
        self.report = RunReport(adaptive=self.adaptive)
        self.beyond_at = None
        self.warned_in_run = False
        self.drift_warned = False
        self.ratio_set = None
        self.sched_t, self.sched_g = [self.t0], []
        self.resolutions = math.nan
        #: the ensemble's shape; members of an ensemble are adapted (and checked) on their own schedule
        self.batch = tuple(getattr(fi, "batch", ()))
        self.mask = np.full(self.batch, self.adaptive)

    @property
    def active(self):
        """Whether the run must be watched between segments."""
        return self.check_stability or self.adaptive

    def _warn(self, msg):
        self.report.warnings.append(msg)
        warnings.warn(msg, LiefiStabilityWarning, stacklevel=self.stacklevel + 1)

    # --- before -----------------------------------------------------------------------
    def before(self, y0):
        """The gains to start with (an integrator) and the pre-run checks; ``O(1)`` calls over the batch."""
        from .stability import check, estimate, first_integral_defect, unit_rate_gains

        fi, dt, rep = self.fi, self.dt, self.report
        if self.auto:
            from .gains import accurate_setting

            # the accurate rate z* (liefi.gains) for this scheme, step and horizon; adapted along
            # the run (at that rate) only when it sits near the stability limit (never for a split
            # scheme: its feedback substep is stable at every rate)
            # every member of an ensemble gets its own rate and gains: those of its single run
            z, acc = accurate_setting(fi, dt, self.sch.name, self.n_steps * dt, y0)
            if self._adaptive_default:
                self.mask = np.broadcast_to(z >= AUTO_ADAPT_FRACTION * self.beta, self.batch)
                self.adaptive = bool(np.any(self.mask))
            if self.adaptive:
                self.rate = z
            rep.adaptive = self.adaptive
        rate = self.rate
        if self.auto and self.adaptive:
            unit = unit_rate_gains(fi, y0)
            run_fi = fi.with_gains(self._merge(acc, {k: v * rate / dt for k, v in unit.items()}, self.mask))
        elif self.auto:
            run_fi = fi.with_gains(acc)
        elif self.adaptive:
            run_fi = fi.with_gains(self._lowered(fi, y0))
        else:
            run_fi = fi
        rep.gains = dict(run_fi.gains)
        self.sched_g = [dict(run_fi.gains)]
        if self.check_stability:
            if not self.adaptive and not self.split:
                T = self.n_steps * dt
                budget = min(PILOT_GUARD_EVALS, _max_evals(self.n_steps, self.sch.stages))
                if self.backend != "numpy":  # a compiled step costs ~1/1000 of a numpy evaluation
                    budget = min(budget, PILOT_GUARD_EVALS // 2)
                rep.estimate = check(run_fi, dt, self.sch, t_final=T, y0=y0, max_evals=budget,
                                     stacklevel=self.stacklevel + 1)
                rep.resolution = rep.estimate.rate
                if rep.estimate.verdict in ("limit", "beyond"):
                    rep.warnings.append(rep.estimate.message())
            else:
                # the gains adapt (or the scheme is stiff-safe): only the resolution of the
                # unforced dynamics can make the run meaningless
                est = estimate(run_fi, dt, self.sch.explicit if self.split else self.sch, y0=y0,
                               resolution_limit=self.resolution_limit)
                rep.resolution = est.rate
                if self.adaptive:  # each member's own (its schedule of checks depends on it)
                    with np.errstate(all="ignore"):
                        self.resolutions = dt * dynamics_rates(run_fi, y0)
                if est.unresolvable:
                    raise ValueError("dt: " + est.resolution_message() + " Pass check_stability=False to run it anyway.")
                if est.under_resolved:
                    self._warn("liefi: " + est.resolution_message())
                rep.estimate = est
            flat = np.asarray(y0, float).reshape(-1, run_fi.n)
            pick = np.unique(np.linspace(0, flat.shape[0] - 1, min(flat.shape[0], RESOLUTION_MEMBERS)).astype(int))
            msg = first_integral_defect(run_fi.members(pick), flat[pick])
            if msg:
                self._warn(msg)
        if self.active:
            self.scales = drift_scales(fi)
            self.delta0, _ = drift(fi, y0, self.scales)
        return run_fi

    @staticmethod
    def _merge(old, new, sel):
        """``{k: new[k] where sel else old[k]}``: per-member gains (floats for one trajectory)."""
        if np.ndim(sel) == 0:
            return dict(new) if sel else dict(old)
        return {k: np.where(sel, new[k], old[k]) for k in new}

    def _lowered(self, base, y):
        """Fixed gains lowered where ``dt lambda_max`` passes the rate (``adaptive=True``), member by member."""
        lam = np.asarray(stiffness(base, y).lam, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            s_ = np.where((lam > 0) & (not self.split), np.minimum(1.0, self.rate / (self.dt * lam)), 1.0)
        s_ = float(s_) if s_.ndim == 0 else s_
        return {k: v * s_ if np.ndim(s_) == 0 else np.asarray(v) * s_ for k, v in base.gains.items()}

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
        from .stability import unit_rate_gains

        rep, dt, beta, sch = self.report, self.dt, self.beta, self.sch
        rep.monitors += 1
        t_now = self.t0 + s0 * dt
        with np.errstate(all="ignore"):
            jet = run_fi.invariant_gradients(y)
            lam = float(np.max(stiffness(run_fi, y).lam, initial=0.0))
        ratio = dt * lam / beta if math.isfinite(beta) else 0.0
        rep.max_ratio = max(rep.max_ratio, ratio)
        if ratio > 1 + LIMIT_BAND and self.beyond_at is None:
            self.beyond_at = t_now
        if self.check_stability:
            delta, who = drift(run_fi, y, self.scales, jet)
            verdict = _guard_verdict(self.beyond_at is not None, delta, self.delta0)
            if verdict == "error":
                why = (
                    f"after dt*lambda_max exceeded the stability bound {beta:.4g} of {sch.name} at "
                    f"t = {self.beyond_at:g} (now {dt * lam:.4g}; largest safe dt {beta / lam:.4g}, or every "
                    f"gain x {beta / (dt * lam):.3g}; or gains='auto', adaptive=True, scheme='imex-euler')"
                )
                if math.isfinite(rep.resolution) and rep.resolution > RESOLUTION_LIMIT:
                    why += (f"; note that dt also under-resolves the unforced dynamics (dt times its fastest "
                            f"rate = {rep.resolution:.3g}): reduce dt first")
                md = metric_defect(run_fi, y)
                if md:
                    why = "; " + md
                raise StabilityError(
                    f"the run became meaningless at t={t_now:g}: the drift of {who} reached {delta:.3g} x its "
                    f"scale {why}. No result is returned.",
                    t_now, s0, y, [who],
                )
            if verdict == "warn" and not self.drift_warned:
                self.drift_warned = True
                md = metric_defect(run_fi, y)
                self._warn(("liefi: " + md) if md else _drift_warning(t_now, who, delta, dt, rep.resolution))
        if self.adaptive and self.batch:
            return self._between_members(run_fi, y, s0)
        if self.adaptive:
            base = self.fi
            if self.auto:
                new = {k: v * self.rate / dt for k, v in unit_rate_gains(base, y).items()}
            else:
                new = self._lowered(base, y)
            if self.monitor_every is None and self.ratio_set is not None:
                if ratio > self.ratio_set * 1.05 or ratio < self.ratio_set / 1.05:
                    N = max(10, N // 2)
                elif self.ratio_set / 1.02 <= ratio <= self.ratio_set * 1.02:
                    N = min(2 * N, self.N_cap)
            run_fi = run_fi.with_gains(new)
            self.ratio_set = (dt * float(np.max(stiffness(run_fi, y).lam, initial=0.0)) / beta
                              if math.isfinite(beta) else 0.0)
            rep.gain_times.append(t_now)
            rep.gain_history.append(dict(new))
            self.sched_t.append(t_now)
            self.sched_g.append(dict(new))
        elif (ratio > 1 + LIMIT_BAND and not self.warned_in_run
              and (rep.estimate is None or rep.estimate.verdict == "ok")):
            self.warned_in_run = True
            self._warn(
                f"liefi: at t = {t_now:g} dt*lambda_max = {dt * lam:.4g} exceeds the stability bound "
                f"{beta:.4g} of {sch.name} (the stiffness grew along the run). Largest safe dt there: "
                f"{beta / lam:.4g} (or every gain x {beta / (dt * lam):.3g}); use gains='auto' or "
                "adaptive=True to follow it, or scheme='imex-euler'."
            )
        return run_fi, N

    def _between_members(self, run_fi, y, s0):
        """The adaptation of an ensemble: the members whose own check falls at step ``s0`` (module docstring)."""
        from .stability import unit_rate_gains

        dt, beta, rep = self.dt, self.beta, self.report
        t_now = s0 * dt
        due = (self.next_i == s0) & np.asarray(self.mask).reshape(-1)
        with np.errstate(all="ignore"):
            lam = np.asarray(stiffness(run_fi, y).lam, float).reshape(-1)
        ratio = dt * lam / beta if math.isfinite(beta) else np.zeros_like(lam)
        if self.auto:
            new = {k: v * self.rate / dt for k, v in unit_rate_gains(self.fi, y).items()}
        else:
            new = self._lowered(self.fi, y)
        if self.monitor_every is None:
            rs = self.ratio_set_i
            with np.errstate(invalid="ignore"):
                off = (ratio > rs * 1.05) | (ratio < rs / 1.05)
                near = (rs / 1.02 <= ratio) & (ratio <= rs * 1.02)
            self.N_i = np.where(due & off, np.maximum(10, self.N_i // 2),
                                np.where(due & near, np.minimum(2 * self.N_i, self.N_cap_i), self.N_i))
        gains = self._merge(run_fi.gains, new, due.reshape(self.batch))
        run_fi = run_fi.with_gains(gains)
        with np.errstate(all="ignore"):
            lam2 = np.asarray(stiffness(run_fi, y).lam, float).reshape(-1)
        self.ratio_set_i = np.where(due, dt * lam2 / beta if math.isfinite(beta) else 0.0, self.ratio_set_i)
        for i in np.nonzero(due)[0]:
            self.next_i[i] = s0 + _chunk(s0, self.total, int(self.N_i[i]), self.save_every)[0]
        rep.gain_times.append(t_now)
        rep.gain_history.append(dict(gains))
        self.sched_t.append(t_now)
        self.sched_g.append(dict(gains))
        return run_fi, self._left(s0)

    # --- after ------------------------------------------------------------------------------
    def after(self, ts, Ys):
        """Audit the saved states ``Ys`` (``(n_t, ..., n)``) at times ``ts`` (at most :data:`AUDIT_STATES` states)."""
        if not self.check_stability:
            return
        per = int(np.prod(Ys.shape[1:-1], dtype=int)) if Ys.ndim > 2 else 1
        pts = max(2, min(2000 if self.backend == "numpy" else 500, AUDIT_STATES // max(per, 1)))
        w = _audit(self.fi, np.asarray(ts), Ys, self.dt, self.beta, self.sch, self.scales, self.delta0,
                   (self.sched_t, self.sched_g), max_points=pts, t0=self.t0)
        if w is not None and not self.drift_warned:
            self._warn(_drift_warning(w[0], w[1], w[2], self.dt, self.report.resolution))

    # --- failure --------------------------------------------------------------------------
    def failure(self, run_fi, exc, earlier):
        """The :class:`~liefi.schemes.IntegrationError` to raise for ``exc``, with the advice appended."""
        extra = _advice(run_fi, exc.y, exc.t, self.dt, self.sch, self.beta, earlier)
        if self.split:
            extra = (f"The split scheme {self.sch.name} solves (I + dt K W A W^T) mu = K r through the Gram matrix of "
                     f"the invariants' gradients each step; non-finite numbers there mean the explicit part on X "
                     f"blew up (reduce dt) or the gains overflow (dt*gain past ~1e300). " + extra)
        return _relabel(exc, self.dt, self.sch, extra, self.t0)
