r"""The default method and the step chosen for a tolerance.

**The default method.**  :meth:`liefi.FeedbackIntegrator.run` without ``scheme``
runs a split scheme (:mod:`liefi.schemes.split`): a Runge--Kutta tableau on the
extended field ``X``, then one linearly implicit feedback step.  Without ``dt``
its order is chosen with the step (step 6 below): ``imex-rk4``, ``imex-rk6`` or
``imex-rk8``, whichever needs the fewest field evaluations for the tolerance;
with a given ``dt`` it is :data:`DEFAULT_SCHEME`, ``imex-rk4`` (classical RK4).
With ``gains="auto"`` (the constructor's default) that step is a Gauss--Newton
step onto the invariant set (:data:`liefi.integrator.gains.SPLIT_RATE_MAX`), so every
invariant stays at rounding for the price of the tableau plus one gradient
evaluation, in any units: the harness
(``liefi bench``) finds it the cheapest run at a given error on every scene
where the error is meaningful.  Without ``dt`` the step is the one chosen here
for the tolerance ``rtol`` (default :data:`DEFAULT_RTOL`).

**A fixed step from an error estimate** (:func:`choose_step`).  Near the
invariant set the split step's error is the error of its tableau on ``X``
(the two substeps nearly commute there), so the step is chosen on ``X``:

1. an error scale per component, ``s_i = atol_i + rtol max_t |y_i(t)|``
   (``atol`` defaults to ``0``: the scale is relative to each component's own
   size, floored at :data:`PART_FLOOR` of the largest of its part, so no unit
   enters).  For an ensemble the scale is each member's own (``s_{b,i}``, the
   maximum over time of member ``b``'s component, never over the members) and
   the error is the largest over the members of each member's scaled error:
   ``rtol`` holds for every member relative to its own size, and the check's
   trust and measured order (step 5) are each member's, the step the strictest
   member's (:func:`liefi.integrator.tolerance_check.extrapolated_step`);
2. a first step: the largest ``h = T / 4^k`` whose step-doubling error is
   below :data:`FIRST_ERROR` relative and in the asymptotic regime (``h/4``
   has an error about ``4^{p+1}`` times smaller: no step aliases with a period
   of the motion), enlarged until the local error is well above rounding;
3. a pilot of :data:`PILOT_STEPS` steps (:data:`PILOT_STEPS_CHECKED` where the check of step 5 follows: it
   sets the step, the pilot plans it) of the tableau from ``y_0`` (on the
   compiled ``X`` when there is one), each with a step-doubling estimate
   ``e = |Phi_h(y) - Phi_{h/2}^2(y)| / (1 - 2^{-p}) = C h^{p+1}``, ``C`` the
   largest over the pilot;
4. **the local model**: the global error is ``E(T) = sum_n Phi'(T, t_n) e_n``;
   with the invariants held (the feedback) the propagated local errors add up
   as a phase error, linearly in ``t``, so ``E(T) <= T C dt^p`` and
   ``dt_0 = (1/(T C))^{1/p}``.  This is an upper bound, and a loose one: it
   takes the largest local error of a short pilot for the average along the
   run (Kepler's pericentre passages, Suslov's transient before the motion
   settles), and assumes no decay of the propagated errors.  Measured over
   ``[0, 1e3]`` it made the error 3e-4 to 0.6 times ``rtol`` (up to 7x too
   many RK4 steps);
5. **the check** (:func:`_check_plan`, :func:`_global_check`): the scheme itself -- the split step,
   compiled -- is run at a coarse step ``H``, at ``H/2`` and ``H/4`` over the *whole* horizon, and the
   Richardson error ``|y_{H/2} - y_{H/4}| / (1 - 2^{-p})`` is compared at every coarse step while the
   saved states take at most :data:`CHECK_BYTES` (else at :data:`CHECK_SAMPLES` common times or more; the runs at
   ``H/2`` and ``H/4`` at every step of the run at ``H/2`` where the states allow: an error that peaks between two
   coarse steps, Kepler's pericentre, is seen), in
   a norm that floors a component at :data:`CHECK_PART_FLOOR` of its part's largest size over the run.
   On a compiled backend the runs are single calls of the compiled loop with the run's gains and invariants,
   set up once (:class:`liefi.integrator._check_runs.CheckRuns`: no run's set-up each, a run made is not made
   again by the next try), so a run of :data:`CHECK_MIN_STEPS_COMPILED` steps or more is checked, its coarse
   runs of at least :func:`coarse_steps` steps; on numpy only a run of :data:`CHECK_MIN_STEPS` or more.
   Between ``H/2`` and ``H`` the step is interpolated by the *measured* order (:func:`measured_order`,
   ``log2`` of the errors at ``H`` and ``H/2``, at least ``p``): before the asymptotic regime the error falls
   faster than ``h^p`` (Kepler over ``[0, 20]``, ``imex-rk8``: ``h^{10}``), and the order alone extrapolated
   to 3.6 ``rtol``.  ``H`` is the asymptotic one (relative error
   :data:`CHECK_ERROR` by the local model) when the three runs cost at most :data:`CHECK_BUDGET` of
   the run (or :data:`CHECK_FLOOR` evaluations), else the finest the budget affords.  Trusted when
   halving divides the difference by ``>= 2^{p-1}``: then ``dt = H (TARGET / E)^{1/p}``, at most
   :data:`CHECK_GROWTH` ``H``, the coarse step, where the error was measured.  Where the tolerance allows
   more, a longer step is *run* and compared at every one of its steps with a run at ``dt/q <= H/2``, inside
   the measured regime (:func:`_verify_longer`): its error is then measured, not extrapolated, and the step
   is kept when it is within the tolerance (before, such a step was capped at ``H``: the roller racer at
   ``1e-4`` over ``[0, 1000]`` ran at 0.002 ``rtol``, the Chaplygin sleigh on SO(2) at 3e-5).  An
   untrusted check is halved while :data:`CHECK_TRIES_BUDGET` budgets allow; if still untrusted the
   step comes from the conservative bound ``2^p max_t |y_{H/2} - y_{H/4}|``, never longer than the
   local model's step (``info["conservative"]``).  A prefix extrapolated linearly is not safe: the
   rattleback's error jumps 300x between t = 1 and t = 2.
   **The invariants at rounding** (:func:`_drift_cap`): the one Gauss--Newton step of the split scheme
   leaves ``K e^2`` of the tableau's per-step defect ``e`` of the invariants (measured ``K`` 0.2--1.1),
   below rounding at the default tolerance but not at a loose one's long steps (the Chaplygin sleigh on
   SO(2) at ``1e-4``, ``dt omega = 2.4``: ``e = 7e-5``, drift ``3e-9``).  So the runs the check already
   makes report their drift (:func:`liefi.integrator.drift.drift`): a run at the coarse step, or a longer candidate,
   whose drift is above :data:`DRIFT_LEVEL` and more than :data:`DRIFT_FLOOR_RATIO` times the drift of
   the shorter run it was compared with is refused, and the step is cut to where ``K e^2 ~ dt^{2(p+1)}``
   reaches the level.  Its cost: the invariants evaluated at the saved states of runs already made;
6. **the order** (``choose_order``, the default when no scheme is named): the
   candidates of :data:`ORDER_CANDIDATES` (the tableau on ``X`` at orders 4,
   6 and 8: :data:`liefi.schemes.rk.RK4`, Butcher's ``RK6``, DOP853's ``RK8``)
   each get steps 1--4; the one with the fewest field evaluations ``stages x
   T/dt_0`` runs (the local model's pessimism is the motion's, about the same
   for every order, so it cancels in the comparison).

The step aims at :data:`TARGET` ``rtol``.  It is then shortened while the stability guard finds that
it does not resolve the unforced motion (:func:`resolved_step`), with the limit of
:func:`resolution_limit`, derived from the tableau's stability polynomial and the tolerance (never
below the guard's fixed 0.2), and rounded down to ``T/N``.  A step whose run's error was *measured* at
every one of its steps (the check's coarse step, or a longer step run and compared) counts as resolved
whatever the a-priori bound: the bound takes the fastest rate of ``X`` as lasting the whole run and every
mode's error as adding up, the measurement sees the run itself.  Where a comparison was sparser (a run
too long for :data:`CHECK_BYTES`) the bound stands: Suslov over ``[0, 1e7]`` compared sparsely missed
its transient and ran at ``dt omega = 2.5``.  The guard's growth limit (the tableau amplifying the
motion) is never lifted.  The table is ``benchmarks/rtol_table.py``.

Why a fixed step rather than an embedded pair (Dormand--Prince 5(4),
Bogacki--Shampine 3(2)) with the feedback after each accepted step: the
motions here have no fast transients (``X`` is the conservative extended
field; the stiff part is the feedback, which the split step takes implicitly
whatever the step), so the local error of ``X`` changes little along a
trajectory and a step adapted along the run buys little; a fixed step keeps
the compiled fixed-step engine, the stability guard and the gains policy
unchanged (one step, one gain for the whole run) and costs one pilot of a few
dozen numpy steps.  The measurement is in ``docs/choosing-a-method.md``.

A tolerance controls the error of the *state*; the invariants are at rounding
whatever the tolerance (the split feedback step, at a step whose measured drift
is at rounding: step 5), so ``rtol`` is not a knob for them.

Where the code lives: this module chooses (steps 6 and after, the default method, the description of a
run's method); steps 1--4, the local estimate, are :mod:`liefi.integrator.tolerance_local`; step 5, the
measured global check, :mod:`liefi.integrator.tolerance_check`, and its drift rule
:mod:`liefi.integrator.tolerance_drift`.  Every name of those is also a name of this module.
"""

from __future__ import annotations

import importlib.util
import math

import numpy as np

from .._data import as_float_array
from .tolerance_drift import (  # noqa: F401 -- re-exported: liefi.integrator.tolerance.X as before the split
    DRIFT_AIM, DRIFT_FLOOR_RATIO, DRIFT_LEVEL, _drift_cap, _run_drift,
)
from .tolerance_local import (  # noqa: F401 -- re-exported: liefi.integrator.tolerance.X as before the split
    FIRST_ERROR, PART_FLOOR, PILOT_STEPS, PILOT_STEPS_CHECKED, TARGET, _local_estimate, _local_step, _parts, _size,
    _tableau, unforced_field,
)
from .tolerance_check import (  # noqa: F401 -- re-exported: liefi.integrator.tolerance.X as before the split
    CHECK_BUDGET, CHECK_BYTES, CHECK_COARSEST, CHECK_ERROR, CHECK_FLOOR, CHECK_GROWTH, CHECK_MIN_STEPS,
    CHECK_PART_FLOOR, CHECK_SAMPLES, CHECK_TRIES_BUDGET, CHECK_TRUST, CHECK_WIDEN, WIDEN_FACTOR, _check_plan,
    _global_check, _measure, _samples, _verify_longer, CHECK_MIN_COARSE, CHECK_MIN_STEPS_COMPILED, check_min_steps,
    coarse_steps, extrapolated_step, measured_order, predicted_error,
)
from ..schemes.registry import REGISTRY as _SCHEMES
from ._check_runs import CheckRuns

#: The scheme :meth:`liefi.FeedbackIntegrator.run` and ``liefi run`` run unless told otherwise when ``dt`` is
#: given; without ``dt`` it names the kind, and the order is chosen for the tolerance (:data:`ORDER_CANDIDATES`).
DEFAULT_SCHEME = "imex-rk4"
#: The relative tolerance of a run given neither ``dt`` nor ``rtol``.
DEFAULT_RTOL = 1e-6
#: A step chosen for a tolerance is at most this fraction of the largest step stable along the run (explicit
#: scheme, fixed gains: :func:`stable_step`), a margin for the stiffness the guard's pilot did not reach.
STABLE_FRACTION = 0.9
#: The schemes among which ``choose_order`` picks, by kind: the same method at orders 4, 6 and 8.
ORDER_CANDIDATES = {"split": ("imex-rk4", "imex-rk6", "imex-rk8"), "explicit": ("rk4", "rk6", "rk8")}
ORDER_SCHEMES = {kind: tuple(_SCHEMES[n] for n in names) for kind, names in ORDER_CANDIDATES.items()}  # looked up once
#: A run of more steps than this is refused before it starts (``liefi run``, ``liefi bench``: ``--max-steps``;
#: :meth:`liefi.FeedbackIntegrator.run`); where the local model already predicts more, the check is not run
#: (its runs would cost minutes before the refusal).
MAX_RUN_STEPS = 10**8


class LiefiToleranceWarning(UserWarning):
    """A step chosen for a tolerance whose global error could not be measured (:func:`choose_step`'s check failed).

    The step is then the local model's (errors adding up linearly in ``t``); a motion that amplifies errors
    exponentially (a chaotic or unstable one: the rattleback's spin reversals over long horizons) can end far
    above ``rtol``.
    """


def unmeasured_message(info, dt, t0, t_end):
    """The warning of a step chosen for a tolerance whose check could not be made (``info["unmeasured"]``)."""
    return (f"rtol={info['rtol']:g}: the global error of dt={dt:.6g} over t in [{t0:g}, {t_end:g}] could not be "
            "measured (the check's runs at a coarser step diverged or left the data's domain); the step is the "
            "local error model's, which assumes the errors add up linearly in t. A motion that amplifies errors "
            "(chaotic or unstable) can end far above rtol: compare with a run at dt/2 (dt=...) or shorten the "
            "horizon")


def default_backend():
    """``"auto"`` (the compiled engine) when numba is installed, else ``"numpy"``: no warning either way."""
    return "auto" if importlib.util.find_spec("numba") is not None else "numpy"


def check_tolerance(rtol, atol):
    """``(rtol, atol)`` as floats, or a ``ValueError`` naming the bad one.

    ``rtol`` in ``[1e-13, 1)`` (below it rounding dominates any step);
    ``atol`` a number ``>= 0`` or an array of them, one per component.
    """
    try:
        r = float(rtol)
    except (TypeError, ValueError):
        raise ValueError(f"rtol: expected a number, got {rtol!r}") from None
    if not (1e-13 <= r < 1.0):
        raise ValueError(f"rtol: must lie in [1e-13, 1) (below 1e-13 rounding dominates any step), got {rtol!r}")
    a = as_float_array(0.0 if atol is None else atol, "atol", "a number >= 0 (or one per component)")
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"atol: expected a number >= 0 (or one per component), got {atol!r}")
    return r, a


def choose_step(fi, sch, y0, t0, t_end, rtol, atol=None, *, check=True, backend=None, choose_order=False):
    """``(dt, info)``: the fixed step for ``rtol``/``atol`` over ``[t0, t_end]`` (module docstring).

    ``fi`` the integrator, ``sch`` a scheme of the registry (explicit or split),
    ``y0`` the start (a batch: one step for every member, the most demanding: each member's error relative to
    its own size, step 1 of the module docstring, so every member meets ``rtol``).
    ``check``: measure the global error of the local model's step by the two short runs of step 5
    (``backend`` as :meth:`liefi.FeedbackIntegrator.run`'s).  ``choose_order``: ``sch`` is only the
    kind; the order is the one of :data:`ORDER_CANDIDATES` with the least predicted cost (step 6),
    named by ``info["scheme"]``.
    ``info``: ``{"rtol", "atol", "scheme", "order", "local_error_constant", "pilot_step",
    "local_step", "check_step", "check_span", "check_error", "estimated_error", "unmeasured", ...}``
    (errors relative to the tolerance; ``check_*`` ``None`` without the check; ``unmeasured`` true when a
    run long enough to be checked could not be: the run warns, :class:`LiefiToleranceWarning`).
    """
    return chosen_step(fi, sch, y0, t0, t_end, rtol, atol, check=check, backend=backend, choose_order=choose_order)[:2]


def chosen_step(fi, sch, y0, t0, t_end, rtol, atol=None, *, check=True, backend=None, choose_order=False):
    """``(dt, info, scheme)``: :func:`choose_step` and the scheme it chose (an object: no look-up by name).

    An ensemble is flattened to ``(B, n)`` first, with each member's own gains, targets and per-member
    constants (:meth:`~liefi.FeedbackIntegrator.members`, evaluated inside its ``selection()``): the pilot
    and the check step the flattened states.
    """
    if getattr(fi, "batch", ()):
        flat = fi.members()
        with flat.selection():
            return _chosen_step(flat, sch, np.asarray(y0, float).reshape(-1, fi.n), t0, t_end, rtol, atol,
                                check=check, backend=backend, choose_order=choose_order)
    return _chosen_step(fi, sch, y0, t0, t_end, rtol, atol, check=check, backend=backend, choose_order=choose_order)


def _chosen_step(fi, sch, y0, t0, t_end, rtol, atol=None, *, check=True, backend=None, choose_order=False):
    rtol, atol = check_tolerance(rtol, atol)
    tab = _tableau(sch)
    p = int(tab.order)
    T = float(t_end) - float(t0)
    Y = np.asarray(y0, float).reshape(-1, fi.n)
    if atol.ndim and atol.shape[-1:] != (fi.n,):
        raise ValueError(f"atol: expected a number or {fi.n} numbers {fi.names}, got shape {atol.shape}")
    backend = default_backend() if backend is None else backend
    f = unforced_field(fi, Y, backend)
    ev = _unforced_eigenvalues(fi, Y, f)  # once: the guard's test at every step tried (resolved_step)
    # a shorter pilot where the measured check follows (it sets the step; the pilot plans it)
    steps = PILOT_STEPS_CHECKED if check and backend != "numpy" and np.ndim(y0) == 1 else PILOT_STEPS
    if choose_order:
        sch, C, h, costs = _cheapest_order(fi, sch, Y, T, rtol, atol, f, ev, steps)
        tab = _tableau(sch)
        p = int(tab.order)
    else:
        C, h, _ = _local_estimate(fi, tab, Y, T, rtol, atol, f, steps)
        costs = None
    dt_local = min(_local_step(C / TARGET, T, p, h), T)
    dt_est, chk, safe, verified, drift_cap, unmeasured = dt_local, None, False, None, math.inf, False
    if check and C > 0 and math.isfinite(C):
        dt0, _ = resolved_step(fi, tab, Y, dt_local, T, rtol, eigenvalues=ev)
        runs = CheckRuns(fi, sch, np.asarray(y0, float), backend)  # one set-up for all the check's runs
        chk = (None if T / dt0 > MAX_RUN_STEPS else
               _check_plan(fi, sch, tab, np.asarray(y0, float), float(t0), T, dt0, rtol, atol, p, backend, runs))
        # a run long enough to be checked whose check could not be made (its coarse runs diverged or left the
        # data's domain): the step is the local model's alone, and the run says so (LiefiToleranceWarning)
        unmeasured = chk is None and check_min_steps(backend, np.ndim(y0) > 1) <= T / dt0 <= MAX_RUN_STEPS
        if chk is not None:
            E, E_safe, H, _tau, trusted, _dense = chk[:6]
            # the measured error at H scaled to the target by the order; up to CHECK_GROWTH x H the coarse run
            # measured it; without the asymptotic regime the conservative bound, never longer than the local
            # model's step
            e = E if trusted else E_safe
            if trusted:  # up to CHECK_GROWTH x H by the error's measured order (an ensemble's: member by member)
                dt_est = extrapolated_step(chk, p, TARGET)
            else:
                dt_est = H * CHECK_GROWTH if e <= 0 else min(H * (TARGET / e) ** (1.0 / p), CHECK_GROWTH * H)
            # the invariants at rounding: the coarse run's drift, against the finest run's (rounding's floor)
            drift_cap = _drift_cap(CHECK_GROWTH * H, chk[6], chk[7], p)
            dt_est = min(dt_est, drift_cap)
            if not trusted:
                dt_est, safe = min(dt_est, dt_local), True
            elif predicted_error(chk, p, CHECK_GROWTH) < TARGET and drift_cap == math.inf:
                # the tolerance allows a step past the measured one: run it and measure its error directly
                verified = _verify_longer(fi, sch, np.asarray(y0, float), float(t0), T, chk, rtol, atol, p,
                                          backend, runs, coarse_steps(T, dt0))
                if verified is not None:
                    dt_est = max(dt_est, verified[0])
    # the measured step resolves the motion only where the check compared the runs at every coarse step (a
    # sparser comparison can miss a transient, e.g. Suslov's over t in [0, 1e7])
    measured = CHECK_GROWTH * chk[2] if chk is not None and chk[4] and chk[5] else None
    if verified is not None and verified[2]:
        measured = max(measured or 0.0, verified[0])
    wanted = min(dt_est, T)
    dt_est, limit = resolved_step(fi, tab, Y, wanted, T, rtol, measured, ev)
    resolved = min(dt_est, T)
    dt_est, dt_stable = stable_step(fi, sch, Y, min(dt_est, T), T)
    n = max(1, math.ceil(T / min(dt_est, T) - 1e-9))
    dt = T / n
    binding = _binding(chk, verified, safe, wanted, resolved, min(dt_est, T), dt_local, drift_cap, T, dt,
                       check_min_steps(backend, np.ndim(y0) > 1))
    if chk is None:
        est = (T * C * dt ** p) if C > 0 else 0.0
    else:
        est = (chk[0] if chk[4] else chk[1]) * (dt / chk[2]) ** p
        if verified is not None and dt > CHECK_GROWTH * chk[2]:
            est = verified[1] * min(1.0, dt / verified[0]) ** p
    info = {
        "rtol": rtol,
        "atol": float(atol) if atol.ndim == 0 else atol.tolist(),
        "scheme": sch.name,
        "order": p,
        "pilot_step": h,
        "local_error_constant": C,
        "local_step": dt_local,
        "check_step": None if chk is None else chk[2],
        "check_span": None if chk is None else chk[3],
        "check_error": None if chk is None else chk[0],
        "check_trusted": None if chk is None else bool(chk[4]),
        "conservative": safe,
        "verified_step": None if verified is None else verified[0],
        "verified_error": None if verified is None else verified[1],
        "check_drift": None if chk is None else chk[6],
        "drift_step_limit": None if drift_cap == math.inf else drift_cap,
        "resolution_limit": limit,
        "stable_step": None if dt_stable == math.inf else dt_stable,
        "estimated_error": est,
        "unmeasured": unmeasured,
        "binding": binding,
    }
    if costs is not None:
        info["predicted_cost"] = costs
    return dt, info, sch


def _binding(chk, verified, safe, wanted, resolved, stable, dt_local, drift_cap, T, dt, min_steps=CHECK_MIN_STEPS):
    """What set the step :func:`chosen_step` chose (``info["binding"]``, said by :func:`describe`): the step
    is the shortest of the tolerance's (local model, measured check or verified longer step, drift rule), the
    resolution limit's and the explicit feedback's stability, rounded down to ``T/N``."""
    if stable < resolved * (1 - 1e-12):
        return "the stability of the explicit feedback at these gains"
    if resolved < wanted * (1 - 1e-12):
        return "the resolution limit of the unforced motion (dt times its fastest rate)"
    if wanted >= T * (1 - 1e-12) and dt == T:
        return "the span: one step"
    if chk is None and math.ceil(T / dt - 1e-9) >= min_steps:
        return "the local error model alone (the check's runs could not be made)"
    if chk is None:
        return (f"the local error model alone, an upper bound (local errors adding up linearly in t): a run of "
                f"{math.ceil(T / dt - 1e-9)} steps, fewer than {min_steps}, is not checked, so its error "
                "can be far below rtol")
    if drift_cap < math.inf and wanted >= drift_cap * (1 - 1e-12):
        return "the drift rule (the invariants kept at rounding)"
    if safe:
        return "the conservative bound of an untrusted check"
    if verified is not None and wanted >= verified[0] * (1 - 1e-12):
        if len(verified) > 3 and verified[3]:
            return ("the drift rule (the invariants kept at rounding): a longer step within the tolerance drifted "
                    "above rounding")
        return "a longer step run and measured within the tolerance"
    if wanted >= CHECK_GROWTH * chk[2] * (1 - 1e-12):
        return f"the measured error's range: at most {CHECK_GROWTH:g} x the check's coarse step"
    return "the measured global error (the check's runs)"


def _cheapest_order(fi, sch, Y, T, rtol, atol, f=None, eigenvalues=None, steps=None):
    """``(scheme, C, h, costs)``: the candidate of ``sch``'s kind with the least predicted cost.

    The cost of a candidate is its evaluations per step (:attr:`stages`) times ``T / dt`` at the step of
    its local model (:func:`_local_estimate`, :func:`resolved_step`): the local model's pessimism is
    about the same for every order (it is the motion's, step 4), so it cancels in the comparison.
    ``costs`` maps each candidate's name to its predicted evaluations.
    """
    names = ORDER_CANDIDATES.get(sch.kind, ())
    if sch.name not in names:
        C, h, _ = _local_estimate(fi, _tableau(sch), Y, T, rtol, atol, f, steps)
        return sch, C, h, None
    best, costs = None, {}
    for name, cand in zip(names, ORDER_SCHEMES[sch.kind]):
        tab = _tableau(cand)
        C, h, _ = _local_estimate(fi, tab, Y, T, rtol, atol, f, steps)
        dt, _ = resolved_step(fi, tab, Y, min(_local_step(C / TARGET, T, int(tab.order), h), T), T, rtol,
                              eigenvalues=eigenvalues)
        costs[name] = cand.stages * math.ceil(T / dt - 1e-9)
        if best is None or costs[name] < best[0]:
            best = (costs[name], cand, C, h)
    return best[1], best[2], best[3], costs


def resolution_limit(tab, T, omega, rtol, target=None):
    r"""The largest ``theta = dt omega`` at which ``tab`` keeps a mode of frequency ``omega`` within the tolerance.

    The unforced motion linearized about the trajectory has modes ``exp(mu t)``, ``|mu| <= omega``
    (the spectral radius of ``dX/dy``); the tableau steps each by its stability polynomial ``R(dt mu)``.
    Its relative error per step is ``|R(z) e^{-z} - 1|``, ``z = dt mu``, about ``c |z|^{p+1}``; over the
    ``T / dt`` steps of the run the errors add up (a phase error, linear in ``t``), so the run keeps
    the mode within ``target rtol`` (relative) when

    .. math:: \frac{T \omega}{\theta} \max_{z \in \{i\theta, \theta, -\theta\}} |R(z) e^{-z} - 1|
              \le \mathrm{target}\, \mathrm{rtol}

    (a rotation, ``mu = i omega``, and its real analogue, a mode growing or decaying at ``omega``).  The
    largest ``theta`` below the first crossing, on a grid of ``theta`` in ``[1e-4, 4]`` (``1e-4`` if the
    grid's first point fails: a tolerance below what the mode allows at any reasonable step).  A higher
    order allows a longer step at the same tolerance, and a looser tolerance a longer step: the guard's
    fixed ``dt omega <= 0.2`` (:data:`liefi.integrator.stability.RESOLUTION_LIMIT`) ignores both.  ``target``:
    default :data:`TARGET`.
    """
    target = TARGET if target is None else target
    if not (omega > 0 and math.isfinite(omega) and T > 0):
        return math.inf
    th, err = _mode_error(tab)
    with np.errstate(all="ignore"):
        ok = (T * omega / th) * err <= target * rtol
    bad = np.nonzero(~ok)[0]
    if bad.size == 0:
        return float(th[-1])
    return float(th[max(bad[0] - 1, 0)])


_MODE_ERROR = {}


def _mode_error(tab):
    """``(theta, max_z |R(z) e^{-z} - 1|)`` on :func:`resolution_limit`'s grid, computed once per tableau."""
    try:
        return _MODE_ERROR[tab]
    except (KeyError, TypeError):
        pass
    th = np.geomspace(1e-4, 4.0, 600)
    with np.errstate(all="ignore"):
        err = np.zeros_like(th)
        for z in (1j * th, th + 0j, -th + 0j):
            err = np.maximum(err, np.abs(tab.stability_function(z) * np.exp(-z) - 1.0))
    try:
        _MODE_ERROR[tab] = (th, err)  # a tableau is a frozen dataclass: hashable by its coefficients
    except TypeError:
        pass
    return th, err


def resolved_step(fi, tab, Y, dt, T=None, rtol=None, measured=None, eigenvalues=None):
    """``(dt, limit)``: ``dt`` shortened until it resolves the unforced motion (the stability guard's test).

    The guard (:func:`liefi.integrator.stability.estimate`) warns past ``dt omega > limit`` and refuses when the
    tableau amplifies the unforced motion by more than :data:`~liefi.integrator.stability.GROWTH_LIMIT` a step.
    ``limit``: :func:`resolution_limit` for the horizon ``T`` and ``rtol`` when both are given (the run
    passes it to the guard), else :data:`~liefi.integrator.stability.RESOLUTION_LIMIT`.  ``measured``: a step at
    which the run's global error was measured in the asymptotic regime (the check): up to it the motion
    is resolved by measurement, whatever the bound.  ``eigenvalues``: those of ``dX/dy`` at the start
    (:func:`_unforced_eigenvalues`), computed once by the caller; the guard's test is theirs at every ``dt``
    (the rate ``dt max |mu|`` and the growth ``max |R(dt mu)|``, as the estimate at the start computes them).
    """
    from .stability import RESOLUTION_LIMIT

    if eigenvalues is None:
        eigenvalues = _unforced_eigenvalues(fi, Y)
    limit = RESOLUTION_LIMIT
    for _ in range(60):
        rate, unresolvable = _rate_and_growth(tab, dt, eigenvalues)
        if T is not None and rtol is not None and rate > 0:
            # never below the guard's fixed limit: shortening the step for accuracy is the measured error's
            # job (the bound takes the fastest rate as lasting the whole run: Kepler's pericentre does not)
            limit = max(resolution_limit(tab, T, rate / dt, rtol), RESOLUTION_LIMIT)
            if measured:
                limit = max(limit, rate / dt * measured * (1 + 1e-9))
        if not (rate > limit or unresolvable):
            break
        # the rate scales with dt: straight to just inside its limit; past the growth limit 0.8x a time
        dt *= 0.8 if unresolvable or not rate > 0 else min(0.98, 0.98 * limit / rate)
    return dt, limit


def _unforced_eigenvalues(fi, Y, f=None):
    """The eigenvalues of ``dX/dy`` at the start ``Y`` (a few members of a batch), as
    :func:`liefi.integrator.stability.estimate` at the start takes them; ``None`` where they cannot be evaluated.
    ``f``: :func:`unforced_field`'s ``X``; a compiled one (one state) evaluates the ``2n`` central differences
    state by state, to rounding the values of numpy's field at a hundredth of its cost (7--10 ms on the rolling
    bodies)."""
    from .stability import RESOLUTION_MEMBERS, _spread, dynamics_eigenvalues

    field = None
    if f is not None and f is not fi.unforced_vector_field and Y.shape[0] == 1:
        def field(P):
            flat = P.reshape(-1, fi.n)
            return np.stack([f(p[None])[0] for p in flat]).reshape(P.shape)
    try:
        with np.errstate(all="ignore"):
            fm, Ym = _spread(fi, Y, RESOLUTION_MEMBERS)  # a few members, with their own per-member data
            with fm.selection():
                return dynamics_eigenvalues(fm, Ym, field)
    except Exception:  # noqa: BLE001 -- as the estimate's: no rate, no limit from it
        return None


def _rate_and_growth(tab, dt, eigenvalues):
    """``(rate, unresolvable)`` of :func:`liefi.integrator.stability.estimate` at ``dt`` from the eigenvalues of the
    start: ``dt max |mu|`` and whether ``tab`` amplifies a mode by more than the guard's growth limit."""
    from .stability import GROWTH_LIMIT, dynamics_growth

    if eigenvalues is None:
        return math.nan, False
    with np.errstate(all="ignore"):
        try:
            rate = dt * float(np.max(np.abs(eigenvalues), initial=0.0))
            growth = dynamics_growth(tab, dt, eigenvalues)
        except Exception:  # noqa: BLE001 -- as the estimate's
            return math.nan, False
    return rate, math.isfinite(growth) and growth > GROWTH_LIMIT


def stable_step(fi, sch, Y, dt, T):
    """``(dt, dt_stable)``: ``dt`` shortened to :data:`STABLE_FRACTION` of the largest step at which an explicit
    scheme keeps the feedback stable along the run, at ``fi``'s fixed gains.

    An explicit tableau steps the feedback's stiff mode ``-lambda`` by ``R(-dt lambda)``, stable while
    ``dt lambda_max <= beta`` (:mod:`liefi.integrator.stability`); ``lambda_max`` (of ``A Hess V``) changes along the motion
    (Kepler's grows 4.6x from the start to the pericentre), so it is taken along the stability guard's pilot
    over the horizon ``T`` (:func:`liefi.integrator.stability.estimate`) with a budget that covers the horizon at the
    pilot's step (within :data:`~liefi.integrator.stability.PILOT_MAX_EVALS`; the run's own check scales its budget with
    the run's steps, which on a short horizon buys a pilot too short to reach the stiff part of the motion).  A step chosen for the
    tolerance alone could pass it: the run then blew up (Kepler, rk4, gains 4/2, rtol 1e-3: ``dt = 0.0283``
    against ``beta / lambda_max = 0.0193``; it diverged at ``t = 8``).  ``dt_stable`` is ``inf`` where the
    feedback sets no limit: a split scheme (implicit feedback), or ``gains="auto"`` (chosen from ``dt`` at the
    run's start, within the bound).
    """
    from .stability import PILOT_MAX_EVALS, PILOT_MAX_RATE, PILOT_MEMBERS, PILOT_MIN_EVALS, dynamics_rate, estimate

    beta = float(getattr(sch, "real_stability_bound", math.inf))
    if not math.isfinite(beta) or getattr(fi, "gains_mode", "fixed") == "auto":
        return dt, math.inf
    with np.errstate(all="ignore"):
        try:  # the pilot's budget: its steps h = PILOT_MAX_RATE / rho over the whole horizon, within the cap
            steps = T * dynamics_rate(fi, Y[:PILOT_MEMBERS]) / PILOT_MAX_RATE
            evals = int(min(PILOT_MAX_EVALS, max(PILOT_MIN_EVALS, 4 * (math.ceil(steps) + 1))))
        except (ValueError, OverflowError, np.linalg.LinAlgError):
            evals = PILOT_MAX_EVALS
        est = estimate(fi, dt, sch, t_final=T, y0=Y.reshape(fi.batch + (fi.n,)) if fi.batch else Y[0],
                       resolution=False, max_evals=evals)
    safe = float(est.dt_safe)
    if not (safe > 0):
        return dt, math.inf
    return min(dt, STABLE_FRACTION * safe), safe


def describe(scheme, dt, gains_mode, backend, *, chosen=None, scheme_given=False, dt_given=False):
    """The ``method`` record of a run: ``{"scheme", "dt", "gains", "backend", "why", ...}``.

    ``chosen``: the ``info`` of :func:`choose_step` when the step was chosen for a tolerance.
    """
    parts = []
    if scheme_given:
        parts.append(f"scheme {scheme}")
    else:
        parts.append(f"scheme {scheme} by default (the tableau on X plus one feedback step: the invariants at "
                     "rounding)")
    if gains_mode == "auto":
        parts.append("gains 'auto' (chosen for accuracy from the scheme, the step and the horizon)")
    else:
        parts.append("fixed gains as asked")
    if chosen is not None:
        how = ("checked by two short runs at a coarse step" if chosen.get("check_error") is not None
               else "global error ~ T C dt^p")
        if chosen.get("unmeasured"):
            how = "global error ~ T C dt^p, not measured: the check's runs at a coarser step failed"
        if chosen.get("conservative"):
            how = ("the check's runs were not in the asymptotic regime within its budget: the conservative bound "
                   "2^p |y_{H/2} - y_{H/4}|, a shorter step than the estimate's")
        order = (f"; order {chosen['order']} the cheapest of {', '.join(chosen['predicted_cost'])} by predicted "
                 "evaluations" if chosen.get("predicted_cost") else "")
        parts.append(f"dt {dt:.6g} chosen for rtol {chosen['rtol']:g} (a step-doubling pilot of the order-"
                     f"{chosen['order']} tableau on X, {how}{order})")
        if chosen.get("binding"):
            parts.append(f"the step is set by {chosen['binding']}")
    elif dt_given:
        parts.append(f"dt {dt:.6g} as asked")
    parts.append(f"backend {backend}")
    out = {"scheme": scheme, "dt": float(dt), "gains": "auto" if gains_mode == "auto" else "fixed",
           "backend": backend, "why": "; ".join(parts)}
    if chosen is not None:
        out["rtol"] = chosen["rtol"]
        out["atol"] = chosen["atol"]
    return out
