r"""The measured global check of a step chosen for a tolerance: the scheme run over the whole horizon.

Step 5 of :mod:`liefi.integrator.tolerance` (the maths there): the scheme itself is run at a coarse step ``H``,
at ``H/2`` and ``H/4`` (:func:`_global_check`, planned within a budget by :func:`_check_plan`), and the
Richardson error ``|y_{H/2} - y_{H/4}| / (1 - 2^{-p})`` is compared along the run; where the tolerance
allows more, a longer step is run and measured (:func:`_verify_longer`).  The invariants' drift of these
runs is judged by :mod:`liefi.integrator.tolerance_drift`.  Re-exported by :mod:`liefi.integrator.tolerance`.
"""

from __future__ import annotations

import math

import numpy as np

from .._members import MembersError

from ._check_runs import CheckRuns
from .tolerance_local import TARGET, _size
from .tolerance_drift import _drift_cap, _drift_pair

#: The floor of the error scale (:data:`PART_FLOOR`) in the check's comparisons, over the whole horizon
#: (where each component's size is seen, not a pilot's window of it): a position beside a winding angle is
#: measured against its own size, not 1e-2 of the angle's.
CHECK_PART_FLOOR = 1e-3
#: The check's coarse step has a relative error of at most this by the local model (asymptotic regime).
CHECK_ERROR = 1e-3
#: ... and is at most this many local-model steps.
CHECK_COARSEST = 64.0
#: A run of fewer steps than this is not checked on numpy (the local model alone: the check would cost more than
#: the run).
CHECK_MIN_STEPS = 256
#: ... and on a compiled backend, where the check's runs (:class:`liefi.integrator._check_runs.CheckRuns`: one call
#: of the compiled loop each, no run's set-up) cost microseconds a step: a short run is checked too (before it
#: was not, and its local model's step left the error 1e-4 to 4e-2 of ``rtol``: Suslov, Kepler over ``[0, 20]``).
CHECK_MIN_STEPS_COMPILED = 8
#: The fewest coarse steps of a short run's check (a run of ``CHECK_MIN_STEPS`` steps or more: 64).
CHECK_MIN_COARSE = 8
#: The check's two runs cost at most this fraction of the run the local model predicts.
CHECK_BUDGET = 0.25
#: ... or at most this many field evaluations when that is more (a few milliseconds of compiled loop; compiled
#: backends only: on numpy that would be seconds).
CHECK_FLOOR = 3e5
#: Common times at which the check's two runs are compared (at least; every coarse step up to this many
#: steps): dense enough to catch a short transient where the error peaks.
CHECK_SAMPLES = 4096
#: ... and every coarse step while a run's saved states take at most this many bytes (a comparison at every
#: step measures the error of the whole run: its step counts as resolved, :func:`resolved_step`).
CHECK_BYTES = 2**25
#: A check whose two runs differ by more than this (relative) is not trusted (not asymptotic).
CHECK_TRUST = 5e-2
#: An untrusted check is repeated at half the coarse step while all its tries cost at most this many budgets.
CHECK_TRIES_BUDGET = 4.0
#: Longer steps tried, each run and measured, where a trusted check allows more than its coarse step
#: (:func:`_verify_longer`).
CHECK_WIDEN = 4
#: ... each at most this many times the longest step measured so far.
WIDEN_FACTOR = 4.0
#: The step is at most this many times the check's coarse step (where the error was measured).
CHECK_GROWTH = 2.0


def check_min_steps(backend, batch=False):
    """The fewest steps of a run that is checked on ``backend`` (:data:`CHECK_MIN_STEPS`; compiled, one
    trajectory, :data:`CHECK_MIN_STEPS_COMPILED`: an ensemble's check runs through the run loop)."""
    return CHECK_MIN_STEPS if backend == "numpy" or batch else CHECK_MIN_STEPS_COMPILED


def coarse_steps(T, dt0):
    """The fewest coarse steps of the check of a run of ``T / dt0`` steps: 64, or for a shorter run than
    :data:`CHECK_MIN_STEPS`, a quarter of its steps (at least :data:`CHECK_MIN_COARSE`), so that its coarse
    step is within a few of its own."""
    return int(min(64, max(CHECK_MIN_COARSE, math.ceil(T / dt0 / 4 - 1e-9))))


def _check_plan(fi, sch, tab, y0, t0, T, dt0, rtol, atol, p, backend, runs=None):
    """The check of step 5 over the whole horizon, or ``None`` for a run of too few steps to protect.

    The three runs cost at most :data:`CHECK_BUDGET` of the run ``dt0`` predicts, or, compiled,
    :data:`CHECK_FLOOR` field evaluations when that is more (the fixed cost of a run, a few
    milliseconds, is not worth saving below it; on numpy an evaluation costs about 1000 times more).  The coarse step is the asymptotic one (its relative
    error :data:`CHECK_ERROR` by the local model, at most :data:`CHECK_COARSEST` ``dt0``) when the
    budget affords it over ``[t0, T]``, else the finest the budget affords: the whole horizon is always
    measured, so that an error that grows late in the run (the rattleback's spin reversal) is seen;
    a check outside the asymptotic regime is repeated at half the step while all the tries cost at most
    :data:`CHECK_TRIES_BUDGET` budgets, and the last gives the conservative bound.
    """
    if T / dt0 < check_min_steps(backend, np.ndim(y0) > 1):
        return None
    n_min = coarse_steps(T, dt0)
    # the floor is a few milliseconds of compiled loop; on numpy (an evaluation costs ~1000x) only the fraction
    floor = CHECK_FLOOR / max(1, int(getattr(sch, "stages", 1))) if backend != "numpy" else 0.0
    budget = max(CHECK_BUDGET * T / dt0, floor)
    H = dt0 * min(max(1.0, (CHECK_ERROR / rtol) ** (1.0 / p)), CHECK_COARSEST)
    H = min(max(H, 7.0 * T / budget), T / n_min)
    spent, chk = 0.0, None
    runs = CheckRuns(fi, sch, y0, backend) if runs is None else runs
    while spent + 7.0 * T / H <= CHECK_TRIES_BUDGET * budget or chk is None:
        spent += 7.0 * T / H
        chk = _global_check(fi, sch, y0, t0, T, H, T, rtol, atol, p, backend, runs=runs, n_min=n_min, drift=False)
        if chk is None or chk[4]:
            break
        H = chk[2]  # outside the asymptotic regime: halve the coarse step while the budget allows (the runs at
        # the two finer steps are made: CheckRuns keeps them)
    # the drift of the last try only: an untrusted try that is repeated is not used (its runs' invariants are
    # not evaluated)
    return None if chk is None else chk[:6] + _drift_pair(fi, chk[6], chk[7], runs.drift_scales()) + chk[8:]


def _global_check(fi, sch, y0, t0, T, H, tau, rtol, atol, p, backend, runs=None, n_min=64, drift=True):
    """The measured global error over ``[t0, t0 + tau]`` (step 5 of the module docstring), or ``None``.

    Three runs of the scheme itself, at ``H``, ``H/2`` and ``H/4``, compared at every coarse step while
    :data:`CHECK_BYTES` allows (else at :data:`CHECK_SAMPLES` common times or more).  Returns ``(E, E_safe, H/2, tau, trusted, dense)``, errors in
    units of the tolerance at the horizon ``T``, ``dense`` whether the runs were compared at every coarse
    step:

    - ``E``: the run at ``H/2`` has the error ``|y_{H/2} - y_{H/4}| / (1 - 2^{-p})`` (Richardson),
      ``E = max_t`` of it, times ``T / tau`` when ``tau < T`` (linear growth past the prefix);
    - ``trusted``: the asymptotic regime, the difference at ``H`` at least ``2^{p-1}`` times the
      difference at ``H/2`` (it is ``2^p`` there) and at most :data:`CHECK_TRUST` relative;
    - ``E_safe``: without the asymptotic regime, the bound that assumes only that halving the step does
      not increase the error, ``err(H/4) <= |y_{H/2} - y_{H/4}|``, expressed at ``H/2`` as
      ``2^p max_t |y_{H/2} - y_{H/4}|`` (``T / tau`` as ``E``): scaled to a step by the order it is
      conservative wherever the convergence is slower than ``p`` at ``H/4`` only because ``H`` is
      outside the regime.

    Then ``(drift, floor)`` of the runs at ``H`` and ``H/4`` (:func:`liefi.integrator.tolerance_drift._drift_pair`)
    and ``E_1``, the run at ``H``'s error (:func:`measured_order`).  ``drift=False``: in their place the
    two runs' saved states, for the caller to evaluate only if this check is the one kept (:func:`_check_plan`).

    An ensemble (``y0`` of shape ``(B, n)``): every error is in each member's own scale (its size the maximum over
    time, never over the members), ``E``, ``E_safe`` and ``E_1`` the largest over the members, ``trusted`` only
    when every member passes the ratio test, and a last entry ``(E_b, E_1b)``, each member's ``E`` and ``E_1``,
    from which :func:`predicted_error` and :func:`extrapolated_step` take each member's own measured order
    (never one member's error at ``H`` over another's at ``H/2``).
    """
    from ..schemes.core import IntegrationError

    n = max(n_min, int(math.ceil(tau / H - 1e-9)))
    m = max(1, n // max(CHECK_SAMPLES, _samples(y0)))
    n = m * int(math.ceil(n / m))
    H = tau / n
    runs = CheckRuns(fi, sch, y0, backend) if runs is None else runs
    try:
        import warnings

        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            # the runs at H/2 and H/4 compared at every step of the run at H/2 where the saved states allow (an
            # error that peaks between two coarse steps, Kepler's pericentre, is seen), the run at H at its own
            fine = 2 if m == 1 and 2 * n <= _samples(y0) else 1
            ys = [runs(t0, tau, H / k, k * m // fine if k > 1 else m) for k in (1, 2, 4)]
    except MembersError:  # states not the ensemble's: liefi's own fault, never a diverged run
        raise
    except (IntegrationError, ArithmeticError, np.linalg.LinAlgError, ValueError, RuntimeError):
        return None
    if any(y.shape[1:] != ys[0].shape[1:] or not np.all(np.isfinite(y)) for y in ys) or ys[1].shape != ys[2].shape:
        return None
    # each member's own scale (the max over time only) and each member's own errors, trust and order: the
    # ensemble's error is the largest member's, its step the strictest member's (never one member's error at
    # H against another's at H/2)
    size = _size(fi, np.max(np.abs(ys[2]), axis=0), CHECK_PART_FLOOR)
    d1 = _per_member(np.abs(ys[0] - ys[2][::fine]) / size)
    d2 = _per_member(np.abs(ys[1][::fine] - ys[2][::fine]) / size)
    diff = _per_member(np.abs(ys[1] - ys[2]) / (atol + rtol * size))
    E = float(np.max(diff)) / (1.0 - 2.0 ** -p) * (T / tau)
    E_safe = float(np.max(diff)) * 2.0 ** p * (T / tau)
    e1 = _per_member(np.abs(ys[0] - ys[2][::fine]) / (atol + rtol * size)) * (T / tau)
    E1 = float(np.max(e1))
    if not (math.isfinite(E) and math.isfinite(E_safe)):
        return None
    trusted = bool(np.all((d1 <= CHECK_TRUST) & ~((d2 > 1e3 * np.finfo(float).eps) & (d1 < 2.0 ** (p - 1) * d2))))
    states = (ys[0], ys[2][::fine])
    members = () if np.ndim(y0) < 2 else ((diff / (1.0 - 2.0 ** -p) * (T / tau), e1),)
    return (E, E_safe, H / 2, tau, trusted, m == 1) + (_drift_pair(fi, *states, runs.drift_scales()) if drift
                                                      else states) + (E1,) + members


def _per_member(a):
    """The largest of ``a`` (``(n_saved, ..., n)``) over time and components, one value per member (``(B,)`` for
    an ensemble's ``(n_saved, B, n)``, a 0-d array for one trajectory's ``(n_saved, n)``)."""
    a = np.asarray(a)
    return np.max(a.reshape(a.shape[0], -1, a.shape[-1]), axis=(0, 2)) if a.ndim > 2 else np.max(a)


def _members_orders(chk, p):
    """``(E_b, q_b)``: each member's error at the check's step and its measured order (:func:`measured_order`
    member by member), or ``None`` for one trajectory's check (no per-member record, ``chk[9]``)."""
    if len(chk) < 10:
        return None
    Eb, E1b = (np.asarray(a, float) for a in chk[9])
    with np.errstate(all="ignore"):
        q = np.where((Eb > 0) & (E1b > Eb), np.log2(E1b / Eb), float(p))
    return Eb, np.maximum(float(p), q)


def predicted_error(chk, p, x):
    """The error of a run at ``x`` times the check's step ``H/2`` (``x`` in ``[1, CHECK_GROWTH]``, in units of the
    tolerance) by the measured order: ``E x^q`` (:func:`measured_order`); for an ensemble the largest over the
    members of each member's ``E_b x^{q_b}`` (each member's own error and order, not the largest error's with
    another member's order)."""
    per = _members_orders(chk, p)
    if per is None:
        return chk[0] * x ** measured_order(chk, p)
    return float(np.max(per[0] * x ** per[1]))


def extrapolated_step(chk, p, target):
    """The step at which the trusted check's run meets ``target`` by the measured order, at most
    :data:`CHECK_GROWTH` times its step ``h = H/2``: ``h (target / E)^{1/q}``; for an ensemble the least over the
    members of ``h (target / E_b)^{1/q_b}`` (the strictest member's)."""
    h = chk[2]
    per = _members_orders(chk, p)
    if per is None:
        e, q = chk[0], measured_order(chk, p)
        return h * CHECK_GROWTH if e <= 0 else min(h * (target / e) ** (1.0 / q), CHECK_GROWTH * h)
    Eb, qb = per
    with np.errstate(all="ignore"):
        steps = np.where(Eb > 0, h * (target / np.where(Eb > 0, Eb, 1.0)) ** (1.0 / qb), CHECK_GROWTH * h)
    return float(min(np.min(steps), CHECK_GROWTH * h))


def measured_order(chk, p):
    r"""The order by which the check's error grows from its step ``H/2`` to ``H``: ``log2(E_1 / E)``, ``E_1`` the
    run at ``H``'s difference from the run at ``H/4`` (its error, measured), at least ``p``.

    Before the asymptotic regime the error falls faster than ``h^p`` (Kepler over ``[0, 20]`` with ``imex-rk8``:
    ``h^{10}`` between 36 and 72 steps); a step extrapolated from ``H/2`` up to ``H`` by ``p`` alone then
    misses the tolerance (there: 3.6 ``rtol``).  The error at ``H`` is measured, so the step between is
    interpolated by the measured order."""
    if len(chk) < 9 or not (chk[0] > 0 and chk[8] > chk[0]):
        return float(p)
    return max(float(p), math.log2(chk[8] / chk[0]))


def _samples(y0):
    """The states of ``y0``'s size that a run may save for a comparison (:data:`CHECK_BYTES`)."""
    return max(1, int(CHECK_BYTES // (8 * max(1, np.asarray(y0).size))))


def _verify_longer(fi, sch, y0, t0, T, chk, rtol, atol, p, backend, runs=None, n_min=64):
    r"""``(dt, e, dense, drift_bound)``: a step longer than the trusted check's coarse step, with its run's measured
    error ``e`` (in units of the tolerance, ``e <= 1``), or ``None``; ``drift_bound``: a longer step within the
    tolerance was refused for its drift (:func:`liefi.integrator.tolerance_drift._drift_cap`).

    The check measured the error up to its coarse step ``H``; past it the error is not known to follow
    ``h^p`` (the asymptotic regime may end there).  So a longer step ``dt`` is *run*, over the whole
    horizon, and compared at every one of its steps (or as many as :data:`CHECK_BYTES` allows:
    ``dense``) with a run of the same scheme at ``dt / q``, ``q`` the least integer with ``dt / q <= H/2``.
    That run is inside the measured regime, its error at most ``E (dt / (q H/2))^p <= E`` (``E`` the
    check's, at ``H/2``), so

    .. math:: e(dt) \le \max_n |y_{dt}(t_n) - y_{dt/q}(t_n)| / (atol + rtol\, s) + E .

    The candidates start from the order's extrapolation ``H (TARGET / e(H))^{1/p}`` and follow each
    measurement the same way, each at most :data:`WIDEN_FACTOR` times the longest step accepted so far,
    :data:`CHECK_WIDEN` tries; a step is accepted when ``e <= 1``: the run that follows is the one
    measured (same scheme, start and ``dt = T/N``), so its error is within the tolerance by measurement,
    not by a model.
    """
    E, _E_safe, h = chk[0], chk[1], chk[2]
    lo, e_lo = CHECK_GROWTH * h, predicted_error(chk, p, CHECK_GROWTH)
    best, hi = None, math.inf  # hi: the least step cut for its drift so far (no later candidate past it)
    refused = math.inf  # the least step within the tolerance refused for its drift
    prop = lo * (TARGET / e_lo) ** (1.0 / p) if e_lo > 0 else math.inf
    for _ in range(CHECK_WIDEN):
        cand = min(prop, hi, WIDEN_FACTOR * lo, T / n_min)
        if not cand > 1.05 * lo:
            break
        got = _measure(fi, sch, y0, t0, T, cand, h, E, rtol, atol, p, backend, runs=runs)
        if got is None:
            break
        e, dense, cand, drift, floor = got
        cap = _drift_cap(cand, drift, floor, p)
        # the order of the error's growth between the longest accepted step and this one, measured (at least p)
        q = max(float(p), math.log(e / e_lo) / math.log(cand / lo)) if e > e_lo > 0 and cand > lo else float(p)
        if e <= 1.0 and cap == math.inf:
            best, lo, e_lo = (cand, e, dense), cand, e
        elif e <= 1.0:  # within the tolerance, refused for its drift
            refused = min(refused, cand)
        elif e > 1.0:
            hi = min(hi, cand)  # too long: no later candidate past it
        hi = min(hi, cap)
        prop = cand * (TARGET / e) ** (1.0 / q) if e > 0 else math.inf
    return None if best is None else best + (refused > best[0],) if refused < math.inf else best + (False,)


def _measure(fi, sch, y0, t0, T, dt, h, E, rtol, atol, p, backend, runs=None):
    """``(e, dense, dt, drift, floor)``: the error of the run at ``dt`` (rounded to ``T/N``) against the run at
    ``dt/q <= h`` whose error is at most ``E (dt / (q h))^p`` (:func:`_verify_longer`), and the invariants' drift
    of the two runs (:func:`_run_drift`), or ``None`` when a run fails."""
    from ..schemes.core import IntegrationError

    N = max(1, int(math.ceil(T / dt - 1e-9)))
    m = max(1, -(-N // _samples(y0)))
    N = m * int(math.ceil(N / m))
    dt = T / N
    q = max(1, int(math.ceil(dt / h - 1e-9)))
    runs = CheckRuns(fi, sch, y0, backend) if runs is None else runs
    try:
        import warnings

        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            ys = [runs(t0, T, dt / k, k * m) for k in (1, q)]
    except MembersError:  # states not the ensemble's: liefi's own fault, never a diverged run
        raise
    except (IntegrationError, ArithmeticError, np.linalg.LinAlgError, ValueError, RuntimeError):
        return None
    if ys[0].shape != ys[1].shape or not all(np.all(np.isfinite(y)) for y in ys):
        return None
    size = _size(fi, np.max(np.abs(ys[1]), axis=0), CHECK_PART_FLOOR)
    e = float(np.max(np.abs(ys[0] - ys[1]) / (atol + rtol * size))) + E * (dt / (q * h)) ** p
    return (e, m == 1, dt) + _drift_pair(fi, ys[0], ys[1], runs.drift_scales()) if math.isfinite(e) else None
