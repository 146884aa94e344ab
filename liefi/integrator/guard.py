"""The stability guard: the verdicts and the messages of a run's checks.

The run's policy (:class:`liefi.integrator.policy.Policy`) decides the step and the gains
(:mod:`liefi.integrator.gains`); the guard turns the theory's numbers (:mod:`liefi.integrator.stability`:
``dt lambda_max`` against the scheme's bound, the invariants' drift, the metric)
into verdicts and words, and calls nothing above it.  The policy asks one
:class:`Guard` per run, once at each point of the run:

* :meth:`Guard.before` -- the pre-run verdict (:func:`liefi.integrator.stability.check`, or the
  resolution of the unforced dynamics where the gains adapt);
* :meth:`Guard.segment` -- after each segment, by the rule of :func:`_guard_verdict`:
  ``"error"`` when the drift exploded after ``dt lambda_max`` left the bound,
  ``"warn"`` for a large drift within it;
* :meth:`Guard.audit` -- the same rule on the saved states after a run
  (:func:`_audit`: a run may have settled into O(1) garbage between two checks);
* :meth:`Guard.failure` -- what to change (:func:`_advice`, :func:`_relabel`,
  :func:`data_defect`), appended to an :class:`~liefi.schemes.IntegrationError`;
* :class:`RunReport` -- what the checks saw (``solution.stability``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._data import check_real
from .._members import MembersError
from ..schemes import IntegrationError
from ..schemes import split as _split
from .stability import (
    GUARD_DRIFT,
    LIMIT_BAND,
    PILOT_GUARD_EVALS,
    RESOLUTION_LIMIT,
    RESOLUTION_MEMBERS,
    StabilityError,
    _max_evals,
    check,
    drift,
    drift_scales,
    dynamics_rate,
    estimate,
    first_integral_defect,
    metric_defect,
    residuals,
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
    # the start (idx 0) was measured before the run (delta0): its drift is at most delta0 there, which
    # neither verdict of _guard_verdict can take, so only the later points are evaluated
    k0 = 1 if len(idx) > 1 and idx[0] == 0 else 0
    n_pt = len(idx) - k0
    rel = np.zeros(len(idx))
    who = np.full(len(idx), "", dtype=object)
    with np.errstate(all="ignore"):
        Yl = Y[k0:]
        jet = residuals(fi, Yl)  # values only: no Jacobian of the data at every saved state
        cur = drift_scales(fi, Y)
        sc = {k: max(scales.get(k, 0.0), cur.get(k, 0.0)) or 1.0 for k in cur}
        rl, wl = rel[k0:], who[k0:]
        res = np.abs(jet.residual).reshape(n_pt, -1, max(len(jet.names), 1)).max(axis=1) if jet.names else None
        for j, nm in enumerate(jet.names):
            r = res[:, j] / sc.get(nm, 1.0)
            wl = np.where(~(r <= rl), nm, wl)
            rl = np.where(~(r <= rl), r, rl)
        if fi.use_penalty:
            P = fi.system.space.group.penalty(Yl[..., : fi.nc]).reshape(n_pt, -1).max(axis=1)
            r = 2 * np.sqrt(np.maximum(P, 0.0))
            wl = np.where(~(r <= rl), "penalty", wl)
            rl = np.where(~(r <= rl), r, rl)
        rel[k0:], who[k0:] = rl, wl
        # dt lambda_max (eigenvalues at every point) matters only where the drift is large enough for an
        # error (_guard_verdict): a run that kept its invariants is not evaluated further
        ratio = np.zeros(len(idx))
        if math.isfinite(beta) and np.any(rel > max(GUARD_DRIFT, 10 * delta0)):
            ratio = dt * _lam_schedule(fi, Y, gains_pt)[0] / beta
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
        x = np.asarray(y, float)[..., fi.nc : fi.nc + n]  # the states' own shape: per-member data
        flat = x.reshape(-1, n)
        sys_ = fi.system
        for datum in (sys_.metric, sys_.constraints, sys_.potential, sys_.vector_potential):
            if datum is None or datum.constant:
                continue
            with np.errstate(all="ignore"):
                check_real(datum(x), datum.name, flat[0] if flat.shape[0] == 1 else flat)
    except MembersError:
        raise
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
    from ..schemes.core import failure_words

    comps, what = list(exc.components or []), getattr(exc, "what", "")
    msg = (
        f"integration with {getattr(sch, 'name', sch)} (dt={dt:g}) "
        f"{failure_words(what, exc.step, t0 + exc.step * dt, comps)}; the last finite state is at t={exc.t:g}. {extra}"
    )
    return IntegrationError(msg, exc.t, exc.step, exc.y, comps, what)


#: Largest number of states (batch members x saved points) the post-run audit evaluates
#: (each costs a few field evaluations: the audit stays a few percent of an ensemble's loop).
AUDIT_STATES = 2000


class Guard:
    """The checks of one fixed-step run: before it, once per segment and after it (module docstring).

    Asked by the run's policy (:class:`liefi.integrator.policy.Policy`), one question at a
    time; fills in ``report`` (a :class:`RunReport`) and warns through
    ``warn(message, depth)`` (the policy's warning; ``depth``: the frames
    between it and the policy).  ``sch``: the registry scheme; ``t0``: the
    run's start.
    """

    def __init__(self, sch, dt, report, warn, *, check_stability=True, resolution_limit=RESOLUTION_LIMIT, t0=0.0):
        self.sch, self.dt, self.report, self.warn = sch, dt, report, warn
        self.beta = float(sch.real_stability_bound)
        self.split = sch.kind == "split"
        self.check_stability = bool(check_stability)
        self.resolution_limit = resolution_limit
        self.t0 = float(t0)
        self.beyond_at = None
        self.warned_in_run = False
        self.drift_warned = False

    def before(self, run_fi, fi, y0, n_steps, *, adaptive, backend, watch, stacklevel):
        """The pre-run verdict, and (``watch``) the drift at the start that the later checks compare with.

        Fixed gains on an explicit tableau: :func:`liefi.integrator.stability.check` along a
        short pilot (a warning at the limit, a refusal 10x past it); adapted
        gains or a split scheme: only the resolution of the unforced dynamics.
        ``stacklevel`` as :func:`liefi.integrator.stability.check`'s, counted from the caller.
        """
        dt, rep = self.dt, self.report
        if self.check_stability:
            batch = tuple(getattr(run_fi, "batch", ()))
            if not adaptive and not self.split:
                T = n_steps * dt
                budget = min(PILOT_GUARD_EVALS, _max_evals(n_steps, self.sch.stages))
                if backend != "numpy":  # a compiled step costs ~1/1000 of a numpy evaluation
                    budget = min(budget, PILOT_GUARD_EVALS // 2)
                rep.estimate = check(run_fi, dt, self.sch, t_final=T, y0=y0, max_evals=budget,
                                     stacklevel=stacklevel + 1)
                rep.resolution = rep.estimate.rate
                if rep.estimate.verdict in ("limit", "beyond"):
                    rep.warnings.append(rep.estimate.message())
            else:
                # the gains adapt (or the scheme is stiff-safe): only the resolution of the
                # unforced dynamics can make the run meaningless
                # (at the few members the resolution is estimated on: the stiffness is not the verdict here)
                flat = np.asarray(y0, float).reshape(-1, run_fi.n)
                few = np.unique(np.linspace(0, flat.shape[0] - 1, min(flat.shape[0], RESOLUTION_MEMBERS)).astype(int))
                est = estimate(run_fi.members(few), dt, self.sch.explicit if self.split else self.sch,
                               y0=flat[few] if batch else y0,
                               resolution_limit=self.resolution_limit)
                rep.resolution = est.rate
                if est.unresolvable:
                    raise ValueError("dt: " + est.resolution_message() + " Pass check_stability=False to run it anyway.")
                if est.under_resolved:
                    self.warn("liefi: " + est.resolution_message(), 1)
                rep.estimate = est
            flat = np.asarray(y0, float).reshape(-1, run_fi.n)
            pick = np.unique(np.linspace(0, flat.shape[0] - 1, min(flat.shape[0], RESOLUTION_MEMBERS)).astype(int))
            few = run_fi.members(pick)
            with few.selection():  # those members' own per-member data
                msg = first_integral_defect(few, flat[pick])
            if msg:
                self.warn(msg, 1)
        if watch:
            self.scales = drift_scales(fi)
            self.delta0, _ = drift(fi, y0, self.scales)

    def segment(self, run_fi, y, t_now, s0, y_all, *, adaptive):
        """The verdict after a segment, at the states ``y`` (the members checked now) at ``t_now``.

        ``dt lambda_max`` against the bound (remembered from the first time it
        passed it) and, with ``check_stability``, the drift of the invariants:
        :class:`~liefi.integrator.stability.StabilityError` when it exploded after the bound
        was passed (:func:`_guard_verdict`), a warning for a large drift within
        it, or (fixed gains) when the stiffness grew past the bound.  ``y_all``:
        the whole state, for the error.  Returns ``(st, lam, ratio)``: the
        :class:`~liefi.integrator.stability.Stiffness` at ``y``, its largest ``lambda_max``
        and ``dt lambda_max / beta``.
        """
        rep, dt, beta, sch = self.report, self.dt, self.beta, self.sch
        rep.monitors += 1
        with np.errstate(all="ignore"):
            jet = run_fi.invariant_gradients(y)
            st = stiffness(run_fi, y)
            lam = float(np.max(st.lam, initial=0.0))
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
                if math.isfinite(rep.resolution) and rep.resolution > self.resolution_limit:
                    why += (f"; note that dt also under-resolves the unforced dynamics (dt times its fastest "
                            f"rate = {rep.resolution:.3g}): reduce dt first")
                md = metric_defect(run_fi, y)
                if md:
                    why = "; " + md
                raise StabilityError(
                    f"the run became meaningless at t={t_now:g}: the drift of {who} reached {delta:.3g} x its "
                    f"scale {why}. No result is returned.",
                    t_now, s0, y_all, [who],
                )
            if verdict == "warn" and not self.drift_warned:
                self.drift_warned = True
                md = metric_defect(run_fi, y)
                self.warn(("liefi: " + md) if md else _drift_warning(t_now, who, delta, dt, rep.resolution), 1)
        if (not adaptive and ratio > 1 + LIMIT_BAND and not self.warned_in_run
                and (rep.estimate is None or rep.estimate.verdict == "ok")):
            self.warned_in_run = True
            self.warn(
                f"liefi: at t = {t_now:g} dt*lambda_max = {dt * lam:.4g} exceeds the stability bound "
                f"{beta:.4g} of {sch.name} (the stiffness grew along the run). Largest safe dt there: "
                f"{beta / lam:.4g} (or every gain x {beta / (dt * lam):.3g}); use gains='auto' or "
                "adaptive=True to follow it, or scheme='imex-euler'.", 1
            )
        return st, lam, ratio

    def audit(self, fi, ts, Ys, schedule, *, backend):
        """After the run: :func:`_audit` on the saved states ``Ys`` (``(n_t, ..., n)``) at times ``ts``.

        At most :data:`AUDIT_STATES` states; ``schedule = (times, gains)``: the
        gains in effect from each time on.
        """
        if not self.check_stability:
            return
        per = int(np.prod(Ys.shape[1:-1], dtype=int)) if Ys.ndim > 2 else 1
        pts = max(2, min(2000 if backend == "numpy" else 500, AUDIT_STATES // max(per, 1)))
        w = _audit(fi, np.asarray(ts), Ys, self.dt, self.beta, self.sch, self.scales, self.delta0,
                   schedule, max_points=pts, t0=self.t0)
        if w is not None and not self.drift_warned:
            self.warn(_drift_warning(w[0], w[1], w[2], self.dt, self.report.resolution), 1)

    def failure(self, run_fi, exc, earlier):
        """The :class:`~liefi.schemes.IntegrationError` to raise for ``exc``, with what to change appended."""
        extra = _advice(run_fi, exc.y, exc.t, self.dt, self.sch, self.beta, earlier)
        if self.split:
            extra = (f"The split scheme {self.sch.name} solves (I + dt K W A W^T) mu = K r through the Gram matrix of "
                     f"the invariants' gradients each step; non-finite numbers there mean the explicit part on X "
                     f"blew up (reduce dt) or the gains overflow (dt*gain past ~1e300). " + extra)
        return _relabel(exc, self.dt, self.sch, extra, self.t0)
