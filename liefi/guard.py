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
    metric_defect,
    stiffness,
)

_stiff = _split


def _lam_schedule(fi, Y, gains_list):
    """``lambda_max`` at states ``Y`` (``(N, ..., n)``) with per-state gain dicts ``gains_list``."""
    jet = fi.invariant_gradients(Y)
    K = np.array([[g[nm] for nm in jet.names] for g in gains_list], float)  # (N, m)
    K = K.reshape((len(gains_list),) + (1,) * (Y.ndim - 2) + (len(jet.names),))
    lam = np.zeros(Y.shape[:-1])
    if jet.names:
        W = jet.grad * np.sqrt(K)[..., None]
        lam = np.linalg.eigvalsh(W @ np.swapaxes(W, -1, -2))[..., -1]
    if fi.use_penalty:
        k0 = np.array([g.get("penalty", 0.0) for g in gains_list]).reshape((len(gains_list),) + (1,) * (Y.ndim - 2))
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


def _advice(fi, y, t, dt, sch, beta, earlier=None):
    """Text appended to a failure: ``dt lambda_max`` at the last finite state and what to change.

    ``earlier = (y, t)``: a state checked before (used when the last finite one
    is already too large to evaluate).
    """
    found = []
    for yy, tt, lab in ((y, t, "At the last finite state"),) + (
        (earlier + ("At the last checked state",),) if earlier is not None else ()
    ):
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
    md = metric_defect(fi, y)
    if md:  # the data, not the gains
        return f"{label} (t={t:g}): {md}"
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


def _subsample(y, k):
    """At most ``k`` members of a batch ``(..., n)`` (flattened to ``(m, n)``), evenly spread."""
    y = np.asarray(y, float)
    flat = y.reshape(-1, y.shape[-1])
    if flat.shape[0] <= k:
        return flat
    return flat[np.unique(np.linspace(0, flat.shape[0] - 1, k).astype(int))]


class Guard:
    """The stability policy of one fixed-step run of a feedback integrator (module docstring).

    Parameters as :func:`liefi.run.run_feedback`.  ``scheme`` is a registry
    scheme (explicit or split); ``beta`` its real stability bound.
    """

    def __init__(self, fi, scheme, dt, n_steps, *, backend, check_stability, adaptive, monitor_every, stacklevel,
                 t0=0.0):
        self.fi = fi
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
            z, acc = accurate_setting(fi, dt, self.sch.name, self.n_steps * dt, _subsample(y0, RESOLUTION_MEMBERS))
            if self._adaptive_default:
                self.adaptive = z >= AUTO_ADAPT_FRACTION * self.beta
            if self.adaptive:
                self.rate = z
            rep.adaptive = self.adaptive
        rate = self.rate
        if self.auto and not self.adaptive:
            run_fi = fi.with_gains(acc)
        elif self.auto and self.adaptive:
            run_fi = fi.with_gains({k: v * rate / dt for k, v in unit_rate_gains(fi, y0).items()})
        elif self.adaptive:
            lam = float(np.max(stiffness(fi, y0).lam, initial=0.0))
            s = min(1.0, rate / (dt * lam)) if lam > 0 and not self.split else 1.0
            run_fi = fi.with_gains({k: v * s for k, v in fi.gains.items()})
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
                est = estimate(run_fi, dt, self.sch.explicit if self.split else self.sch, y0=y0)
                rep.resolution = est.rate
                if est.unresolvable:
                    raise ValueError("dt: " + est.resolution_message() + " Pass check_stability=False to run it anyway.")
                if est.under_resolved:
                    self._warn("liefi: " + est.resolution_message())
                rep.estimate = est
            msg = first_integral_defect(run_fi, _subsample(y0, RESOLUTION_MEMBERS))
            if msg:
                self._warn(msg)
        if self.active:
            self.scales = drift_scales(fi)
            self.delta0, _ = drift(fi, y0, self.scales)
        return run_fi

    def segment_length(self, n_steps):
        """Steps between two checks (deterministic: results never depend on timing)."""
        if self.monitor_every is not None:
            N = self.monitor_every
        elif self.adaptive:
            N = 100
        else:
            # a check costs about ten numpy steps of one state, and hundreds of compiled ones:
            # at most 100 checks on numpy, 20 compiled (the audit covers the states between them)
            N = max(200, n_steps // 100) if self.backend == "numpy" else max(20000, n_steps // 20)
        if self.adaptive and self.monitor_every is None:
            r = self.report.resolution / self.dt if math.isfinite(self.report.resolution) else 1.0
            self.N_cap = int(min(50000, max(10, 0.5 / (self.dt * max(r, 1e-2)))))
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
        if self.adaptive:
            base = self.fi
            if self.auto:
                new = {k: v * self.rate / dt for k, v in unit_rate_gains(base, y).items()}
            else:
                lam_b = float(np.max(stiffness(base, y).lam, initial=0.0))
                s_ = min(1.0, self.rate / (dt * lam_b)) if lam_b > 0 and not self.split else 1.0
                new = {k: v * s_ for k, v in base.gains.items()}
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
