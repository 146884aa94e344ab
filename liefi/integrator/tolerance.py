r"""The default method and the step chosen for a tolerance.

**The default method.**  :meth:`liefi.FeedbackIntegrator.run` without ``scheme``
runs a split scheme (:mod:`liefi.schemes.split`): a Runge--Kutta tableau on the
extended field ``X``, then one linearly implicit feedback step.  Without ``dt``
its order is chosen with the step (step 6 below): ``imex-rk4``, ``imex-rk6`` or
``imex-rk8``, whichever needs the fewest field evaluations for the tolerance;
with a given ``dt`` it is :data:`DEFAULT_SCHEME`, ``imex-rk4`` (classical RK4).
With ``gains="auto"`` (the constructor's default) that step is a Gauss--Newton
step onto the invariant set (:data:`liefi.gains.SPLIT_RATE_MAX`), so every
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
   enters);
2. a first step: the largest ``h = T / 4^k`` whose step-doubling error is
   below :data:`FIRST_ERROR` relative and in the asymptotic regime (``h/4``
   has an error about ``4^{p+1}`` times smaller: no step aliases with a period
   of the motion), enlarged until the local error is well above rounding;
3. a pilot of :data:`PILOT_STEPS` steps of the tableau from ``y_0`` (on the
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
   saved states take at most :data:`CHECK_BYTES` (else at :data:`CHECK_SAMPLES` common times or more), in
   a norm that floors a component at :data:`CHECK_PART_FLOOR` of its part's largest size over the run.  ``H`` is the asymptotic one (relative error
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
   makes report their drift (:func:`liefi.drift.drift`): a run at the coarse step, or a longer candidate,
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
"""

from __future__ import annotations

import importlib.util
import math

import numpy as np

from .._data import as_float_array
from ..schemes.registry import REGISTRY as _SCHEMES
#: The scheme :meth:`liefi.FeedbackIntegrator.run` and ``liefi run`` run unless told otherwise when ``dt`` is
#: given; without ``dt`` it names the kind, and the order is chosen for the tolerance (:data:`ORDER_CANDIDATES`).
DEFAULT_SCHEME = "imex-rk4"
#: The relative tolerance of a run given neither ``dt`` nor ``rtol``.
DEFAULT_RTOL = 1e-6
#: A step chosen for a tolerance is at most this fraction of the largest step stable along the run (explicit
#: scheme, fixed gains: :func:`stable_step`), a margin for the stiffness the guard's pilot did not reach.
STABLE_FRACTION = 0.9
#: Steps of the pilot (each with a step-doubling error estimate).
PILOT_STEPS = 24
#: A component's error scale is at least this fraction of the largest size of its part.
PART_FLOOR = 1e-2
#: ... in the check's comparisons, over the whole horizon (where each component's size is seen, not a pilot's
#: window of it): a position beside a winding angle is measured against its own size, not 1e-2 of the angle's.
CHECK_PART_FLOOR = 1e-3
#: The schemes among which ``choose_order`` picks, by kind: the same method at orders 4, 6 and 8.
ORDER_CANDIDATES = {"split": ("imex-rk4", "imex-rk6", "imex-rk8"), "explicit": ("rk4", "rk6", "rk8")}
ORDER_SCHEMES = {kind: tuple(_SCHEMES[n] for n in names) for kind, names in ORDER_CANDIDATES.items()}  # looked up once
#: The first pilot step is the largest ``T / 4^k`` whose relative local error is below this.
FIRST_ERROR = 1e-5
#: The chosen step aims its estimated global error at this fraction of the tolerance (``solve_ivp``'s
#: achieved error is of the order of ``rtol``; a default run's should not exceed it).
TARGET = 1.0 / 3.0
#: The check's coarse step has a relative error of at most this by the local model (asymptotic regime).
CHECK_ERROR = 1e-3
#: ... and is at most this many local-model steps.
CHECK_COARSEST = 64.0
#: A run of more steps than this is refused before it starts (``liefi run``, ``liefi bench``: ``--max-steps``;
#: :meth:`liefi.FeedbackIntegrator.run`); where the local model already predicts more, the check is not run
#: (its runs would cost minutes before the refusal).
MAX_RUN_STEPS = 10**8
#: A run of fewer steps than this is not checked (the local model alone: the check would cost more than the run).
CHECK_MIN_STEPS = 256
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
CHECK_TRUST = 1e-2
#: An untrusted check is repeated at half the coarse step while all its tries cost at most this many budgets.
CHECK_TRIES_BUDGET = 4.0
#: Longer steps tried, each run and measured, where a trusted check allows more than its coarse step
#: (:func:`_verify_longer`).
CHECK_WIDEN = 3
#: ... each at most this many times the longest step measured so far.
WIDEN_FACTOR = 4.0
#: The step is at most this many times the check's coarse step (where the error was measured).
CHECK_GROWTH = 2.0
#: The invariants' relative drift (:func:`liefi.drift.drift`, against their scales at the start) that counts as
#: rounding: ``1e4 u`` (``2.2e-12``), ten times the highest floor of evaluating the invariants in floating point
#: that no step lowers (the non-reversible knife edge: ``1.5e-13 = 700 u`` whatever the step).  Below it the
#: drift need not follow the step: the roller racer's stays at ``1.2e-12`` from ``dt = 0.92`` to ``1.01``.
DRIFT_LEVEL = 1e4 * np.finfo(float).eps
#: A run's drift above :data:`DRIFT_LEVEL` is the step's when it is more than this many times the drift of the
#: run at a shorter step it was compared with (the Gauss--Newton residual falls like ``dt^{2(p+1)}``; a floor
#: that a shorter step does not lower is the evaluation's rounding, not the step's).
DRIFT_FLOOR_RATIO = 4.0
#: The step a drift above the level is cut to aims at this fraction of :data:`DRIFT_LEVEL`: the measured drift
#: falls a little slower than ``dt^{2(p+1)}`` (Kepler at order 8: ``dt^{16.8}``, not ``dt^{18}``).
DRIFT_AIM = 0.25


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


def _tableau(sch):
    """The explicit tableau that steps ``X`` in ``sch`` (the split scheme's, or ``sch`` itself)."""
    return getattr(sch, "explicit", sch)


def _parts(fi):
    """The slices of the state whose components share units: the group element, ``x``, the momenta."""
    nc, nx = fi.nc, fi.system.space.n
    cuts = [0, nc, nc + nx, fi.n]
    return [slice(a, b) for a, b in zip(cuts, cuts[1:]) if b > a]


def unforced_field(fi, Y, backend):
    """``f(y)``: ``X`` at a batch ``y`` of shape ``(k, n)``, compiled when ``backend`` allows and the
    system compiles (the split kernel's ``xrhs``, the one the run loads anyway), else numpy."""
    if backend != "numpy" and Y.shape[0] == 1:
        try:
            import warnings

            from ..engine.kernels import compile_split
            from ..engine.trace import NotCompilable

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cf = compile_split(fi)
                p = np.ascontiguousarray(fi.parameters(), dtype=float)
                out = np.empty(fi.n)
                cf._first_call("xrhs", "xrhs", np.ascontiguousarray(Y[0]), p, out)
            xrhs = cf.module.xrhs

            def f(y):
                out = np.empty(fi.n)
                xrhs(np.ascontiguousarray(y[0]), p, out)
                return out[None]

            return f
        except (NotCompilable, ImportError, RuntimeError, AttributeError, TypeError, ValueError):
            pass
    return fi.unforced_vector_field


def _local_estimate(fi, tab, Y, T, rtol, atol, f=None):
    """``(C, h, mag)``: the local error constant of ``tab`` on ``X`` from the step-doubling pilot.

    ``C`` the largest ``e / h^{p+1}`` over :data:`PILOT_STEPS` steps of ``h`` (steps 1--3 of the module
    docstring), in the scaled norm; ``mag`` the componentwise largest ``|y|`` seen.  ``f``: ``X``
    (default: numpy's, :func:`unforced_field`).
    """
    p = int(tab.order)
    if f is None:
        f = fi.unforced_vector_field

    with np.errstate(all="ignore"):
        mag = np.abs(Y)

        def first_error(hh):
            try:
                y1 = tab.step(f, Y, hh)
                yh = tab.step(f, tab.step(f, Y, hh / 2), hh / 2)
            except (ArithmeticError, np.linalg.LinAlgError, ValueError):
                # a trial step so long that its stages leave the data's domain (a singular metric or
                # constraint there, e.g. a rolling body's stage far from the plane): too long, not an error
                return math.inf
            e = float(np.max(np.abs(y1 - yh) / _size(fi, np.maximum(mag, np.abs(yh)))))
            return e if math.isfinite(e) else math.inf

        # the first pilot step: the largest T / 4^k in the asymptotic regime (its error small, and a quarter
        # of it has an error 4^(p+1) times smaller, so that no step aliases with a period of the motion)
        h, e_h = T, first_error(T)
        for _ in range(60):
            e_q = first_error(h / 4)
            if (e_h <= FIRST_ERROR and (e_q <= 1e3 * np.finfo(float).eps or e_q * 4 ** (p + 1) / 8 <= e_h)
                    or h < 1e-12 * T):
                break
            h, e_h = h / 4, e_q
        C, hC = 0.0, h
        for _ in range(12):  # enlarge the pilot step until its error is well above rounding
            y, big, c, m = Y, 0.0, 0.0, mag
            for _k in range(PILOT_STEPS):
                try:
                    y1 = tab.step(f, y, h)
                    yh = tab.step(f, tab.step(f, y, h / 2), h / 2)
                except (ArithmeticError, np.linalg.LinAlgError, ValueError):  # out of the data's domain
                    e = math.inf
                    break
                m = np.maximum(m, np.abs(yh))
                err = np.abs(y1 - yh) / (1.0 - 2.0 ** -p)
                e = float(np.max(err / (atol + rtol * _size(fi, m))))
                if not math.isfinite(e):
                    break
                big = max(big, float(np.max(err / (np.finfo(float).eps * _size(fi, m)))))
                hp = h ** (p + 1)
                if hp > 0:  # a step so short that h^(p+1) underflows (a horizon of 1e-200) has no error to measure
                    c = max(c, e / hp)
                y = yh
            if not math.isfinite(e):
                break  # past the tableau's stability: keep the last estimate
            C, hC, mag = c, h, m
            if big > 1e4 or h >= T:
                break
            h = min(8.0 * h, T)
    return C, hC, mag


def _size(fi, m, floor_fraction=PART_FLOOR):
    """Each component's size ``m``, floored at :data:`PART_FLOOR` times the largest of its part (group
    element, ``x``, momenta).

    A component that stays near zero is measured against its neighbours of the same units, so that the
    error scale never vanishes; a small component beside a large one (a position beside an angle that
    winds up over the run) keeps its own scale.
    """
    parts = _parts(fi)
    floor = np.empty_like(m)
    for sl in parts:
        floor[..., sl] = np.max(m[..., sl], axis=-1, keepdims=True)
    return np.maximum(np.maximum(m, floor_fraction * floor), 1e-300)


def _local_step(C, T, p, h):
    """The step of the local model, ``(1 / (T C))^{1/p}`` (``T`` if ``X`` is exact at the pilot's step)."""
    if not (C > 0 and math.isfinite(C)):
        return T  # X is (numerically) exact at any step here, e.g. a state at rest
    return (1.0 / (max(T, h) * C)) ** (1.0 / p)


def _check_plan(fi, sch, tab, y0, t0, T, dt0, rtol, atol, p, backend):
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
    if T / dt0 < CHECK_MIN_STEPS:
        return None
    # the floor is a few milliseconds of compiled loop; on numpy (an evaluation costs ~1000x) only the fraction
    floor = CHECK_FLOOR / max(1, int(getattr(sch, "stages", 1))) if backend != "numpy" else 0.0
    budget = max(CHECK_BUDGET * T / dt0, floor)
    H = dt0 * min(max(1.0, (CHECK_ERROR / rtol) ** (1.0 / p)), CHECK_COARSEST)
    H = min(max(H, 7.0 * T / budget), T / 64)
    spent, chk = 0.0, None
    while spent + 7.0 * T / H <= CHECK_TRIES_BUDGET * budget or chk is None:
        spent += 7.0 * T / H
        chk = _global_check(fi, sch, y0, t0, T, H, T, rtol, atol, p, backend)
        if chk is None or chk[4]:
            break
        H /= 2.0  # outside the asymptotic regime: halve the coarse step while the budget allows
    return chk


def _global_check(fi, sch, y0, t0, T, H, tau, rtol, atol, p, backend):
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
    """
    from ..schemes.core import IntegrationError

    n = max(64, int(math.ceil(tau / H)))
    m = max(1, n // max(CHECK_SAMPLES, _samples(y0)))
    n = m * int(math.ceil(n / m))
    H = tau / n
    kw = dict(scheme=sch.name, progress=False, check_stability=False, backend=backend, drop_exact=True)
    try:
        import warnings

        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            ys = [np.moveaxis(np.asarray(fi.run((t0, t0 + tau), dt=H / k, save_every=k * m, y0=y0, **kw).y), -1, 0)
                  for k in (1, 2, 4)]
    except (IntegrationError, ArithmeticError, np.linalg.LinAlgError, ValueError, RuntimeError):
        return None
    if any(y.shape != ys[0].shape or not np.all(np.isfinite(y)) for y in ys):
        return None
    size = _size(fi, np.max(np.abs(ys[2]), axis=0), CHECK_PART_FLOOR)
    d1 = float(np.max(np.abs(ys[0] - ys[2]) / size))
    d2 = float(np.max(np.abs(ys[1] - ys[2]) / size))
    diff = np.abs(ys[1] - ys[2]) / (atol + rtol * size)
    E = float(np.max(diff)) / (1.0 - 2.0 ** -p) * (T / tau)
    E_safe = float(np.max(diff)) * 2.0 ** p * (T / tau)
    if not (math.isfinite(E) and math.isfinite(E_safe)):
        return None
    trusted = d1 <= CHECK_TRUST and not (d2 > 1e3 * np.finfo(float).eps and d1 < 2.0 ** (p - 1) * d2)
    return E, E_safe, H / 2, tau, trusted, m == 1, _run_drift(fi, ys[0]), _run_drift(fi, ys[2])


def _run_drift(fi, ys):
    """The largest relative drift of the invariants over a run's saved states ``ys`` (:func:`liefi.drift.drift`,
    scales at the start); ``0`` where it cannot be evaluated (no invariant: nothing to keep)."""
    from .drift import drift, drift_scales

    try:
        with np.errstate(all="ignore"):
            d = drift(fi, np.asarray(ys, float), drift_scales(fi, ys[0]))[0]
    except (ArithmeticError, np.linalg.LinAlgError, ValueError, TypeError, KeyError, IndexError):
        return 0.0
    return float(d) if math.isfinite(d) else math.inf


def _drift_cap(dt, drift, floor, p):
    r"""The longest step whose run keeps the invariants at rounding, from the drift ``drift`` measured at ``dt``.

    One Gauss--Newton step onto the invariant set leaves ``K e^2`` of the tableau's per-step defect
    ``e = c dt^{p+1}`` (measured: ``K`` 0.2 to 1.1 on the Chaplygin sleighs, Suslov, the oscillator, the roller
    racer), so the drift scales like ``dt^{2(p+1)}`` and the cap is ``dt (a L / drift)^{1 / (2(p+1))}``, ``L`` =
    :data:`DRIFT_LEVEL`, ``a`` = :data:`DRIFT_AIM`.  ``inf`` when the drift is at rounding: below ``L``, or within
    :data:`DRIFT_FLOOR_RATIO` of ``floor``, the drift of a run at a shorter step (rounding that no step lowers).
    """
    if not drift > max(DRIFT_LEVEL, DRIFT_FLOOR_RATIO * floor):
        return math.inf
    if not math.isfinite(drift):
        return 0.0
    return dt * (DRIFT_AIM * DRIFT_LEVEL / drift) ** (1.0 / (2.0 * (p + 1)))


def _samples(y0):
    """The states of ``y0``'s size that a run may save for a comparison (:data:`CHECK_BYTES`)."""
    return max(1, int(CHECK_BYTES // (8 * max(1, np.asarray(y0).size))))


def _verify_longer(fi, sch, y0, t0, T, chk, rtol, atol, p, backend):
    r"""``(dt, e, dense)``: a step longer than the trusted check's coarse step, with its run's measured error
    ``e`` (in units of the tolerance, ``e <= 1``), or ``None``.

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
    lo, e_lo = CHECK_GROWTH * h, E * CHECK_GROWTH ** p
    best, hi = None, math.inf  # hi: the least step cut for its drift so far (no later candidate past it)
    prop = lo * (TARGET / e_lo) ** (1.0 / p) if e_lo > 0 else math.inf
    for _ in range(CHECK_WIDEN):
        cand = min(prop, hi, WIDEN_FACTOR * lo, T / 64)
        if not cand > 1.05 * lo:
            break
        got = _measure(fi, sch, y0, t0, T, cand, h, E, rtol, atol, p, backend)
        if got is None:
            break
        e, dense, cand, drift, floor = got
        cap = _drift_cap(cand, drift, floor, p)
        if e <= 1.0 and cap == math.inf:
            best, lo = (cand, e, dense), cand
        hi = min(hi, cap)
        prop = cand * (TARGET / e) ** (1.0 / p) if e > 0 else math.inf
    return best


def _measure(fi, sch, y0, t0, T, dt, h, E, rtol, atol, p, backend):
    """``(e, dense, dt, drift, floor)``: the error of the run at ``dt`` (rounded to ``T/N``) against the run at
    ``dt/q <= h`` whose error is at most ``E (dt / (q h))^p`` (:func:`_verify_longer`), and the invariants' drift
    of the two runs (:func:`_run_drift`), or ``None`` when a run fails."""
    from ..schemes.core import IntegrationError

    N = max(1, int(math.ceil(T / dt - 1e-9)))
    m = max(1, -(-N // _samples(y0)))
    N = m * int(math.ceil(N / m))
    dt = T / N
    q = max(1, int(math.ceil(dt / h - 1e-9)))
    kw = dict(scheme=sch.name, progress=False, check_stability=False, backend=backend, drop_exact=True)
    try:
        import warnings

        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            ys = [np.moveaxis(np.asarray(fi.run((t0, t0 + T), dt=dt / k, save_every=k * m, y0=y0, **kw).y), -1, 0)
                  for k in (1, q)]
    except (IntegrationError, ArithmeticError, np.linalg.LinAlgError, ValueError, RuntimeError):
        return None
    if ys[0].shape != ys[1].shape or not all(np.all(np.isfinite(y)) for y in ys):
        return None
    size = _size(fi, np.max(np.abs(ys[1]), axis=0), CHECK_PART_FLOOR)
    e = float(np.max(np.abs(ys[0] - ys[1]) / (atol + rtol * size))) + E * (dt / (q * h)) ** p
    return (e, m == 1, dt, _run_drift(fi, ys[0]), _run_drift(fi, ys[1])) if math.isfinite(e) else None


def choose_step(fi, sch, y0, t0, t_end, rtol, atol=None, *, check=True, backend=None, choose_order=False):
    """``(dt, info)``: the fixed step for ``rtol``/``atol`` over ``[t0, t_end]`` (module docstring).

    ``fi`` the integrator, ``sch`` a scheme of the registry (explicit or split),
    ``y0`` the start (a batch: one step for every member, the most demanding).
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
    """``(dt, info, scheme)``: :func:`choose_step` and the scheme it chose (an object: no look-up by name)."""
    rtol, atol = check_tolerance(rtol, atol)
    tab = _tableau(sch)
    p = int(tab.order)
    T = float(t_end) - float(t0)
    Y = np.asarray(y0, float).reshape(-1, fi.n)
    if atol.ndim and atol.shape[-1:] != (fi.n,):
        raise ValueError(f"atol: expected a number or {fi.n} numbers {fi.names}, got shape {atol.shape}")
    backend = default_backend() if backend is None else backend
    f = unforced_field(fi, Y, backend)
    if choose_order:
        sch, C, h, costs = _cheapest_order(fi, sch, Y, T, rtol, atol, f)
        tab = _tableau(sch)
        p = int(tab.order)
    else:
        C, h, _ = _local_estimate(fi, tab, Y, T, rtol, atol, f)
        costs = None
    dt_local = min(_local_step(C / TARGET, T, p, h), T)
    dt_est, chk, safe, verified, drift_cap, unmeasured = dt_local, None, False, None, math.inf, False
    if check and C > 0 and math.isfinite(C):
        dt0, _ = resolved_step(fi, tab, Y, dt_local, T, rtol)
        chk = (None if T / dt0 > MAX_RUN_STEPS else
               _check_plan(fi, sch, tab, np.asarray(y0, float), float(t0), T, dt0, rtol, atol, p, backend))
        # a run long enough to be checked whose check could not be made (its coarse runs diverged or left the
        # data's domain): the step is the local model's alone, and the run says so (LiefiToleranceWarning)
        unmeasured = chk is None and CHECK_MIN_STEPS <= T / dt0 <= MAX_RUN_STEPS
        if chk is not None:
            E, E_safe, H, _tau, trusted, _dense = chk[:6]
            # the measured error at H scaled to the target by the order; up to CHECK_GROWTH x H the coarse run
            # measured it; without the asymptotic regime the conservative bound, never longer than the local
            # model's step
            e = E if trusted else E_safe
            dt_est = H * CHECK_GROWTH if e <= 0 else min(H * (TARGET / e) ** (1.0 / p), CHECK_GROWTH * H)
            # the invariants at rounding: the coarse run's drift, against the finest run's (rounding's floor)
            drift_cap = _drift_cap(CHECK_GROWTH * H, chk[6], chk[7], p)
            dt_est = min(dt_est, drift_cap)
            if not trusted:
                dt_est, safe = min(dt_est, dt_local), True
            elif e * CHECK_GROWTH ** p < TARGET and drift_cap == math.inf:
                # the tolerance allows a step past the measured one: run it and measure its error directly
                verified = _verify_longer(fi, sch, np.asarray(y0, float), float(t0), T, chk, rtol, atol, p,
                                          backend)
                if verified is not None:
                    dt_est = max(dt_est, verified[0])
    # the measured step resolves the motion only where the check compared the runs at every coarse step (a
    # sparser comparison can miss a transient, e.g. Suslov's over t in [0, 1e7])
    measured = CHECK_GROWTH * chk[2] if chk is not None and chk[4] and chk[5] else None
    if verified is not None and verified[2]:
        measured = max(measured or 0.0, verified[0])
    dt_est, limit = resolved_step(fi, tab, Y, min(dt_est, T), T, rtol, measured)
    dt_est, dt_stable = stable_step(fi, sch, Y, min(dt_est, T), T)
    n = max(1, math.ceil(T / min(dt_est, T) - 1e-9))
    dt = T / n
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
    }
    if costs is not None:
        info["predicted_cost"] = costs
    return dt, info, sch


def _cheapest_order(fi, sch, Y, T, rtol, atol, f=None):
    """``(scheme, C, h, costs)``: the candidate of ``sch``'s kind with the least predicted cost.

    The cost of a candidate is its evaluations per step (:attr:`stages`) times ``T / dt`` at the step of
    its local model (:func:`_local_estimate`, :func:`resolved_step`): the local model's pessimism is
    about the same for every order (it is the motion's, step 4), so it cancels in the comparison.
    ``costs`` maps each candidate's name to its predicted evaluations.
    """
    names = ORDER_CANDIDATES.get(sch.kind, ())
    if sch.name not in names:
        C, h, _ = _local_estimate(fi, _tableau(sch), Y, T, rtol, atol, f)
        return sch, C, h, None
    best, costs = None, {}
    for name, cand in zip(names, ORDER_SCHEMES[sch.kind]):
        tab = _tableau(cand)
        C, h, _ = _local_estimate(fi, tab, Y, T, rtol, atol, f)
        dt, _ = resolved_step(fi, tab, Y, min(_local_step(C / TARGET, T, int(tab.order), h), T), T, rtol)
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
    fixed ``dt omega <= 0.2`` (:data:`liefi.stability.RESOLUTION_LIMIT`) ignores both.  ``target``:
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


def resolved_step(fi, tab, Y, dt, T=None, rtol=None, measured=None):
    """``(dt, limit)``: ``dt`` shortened until it resolves the unforced motion (the stability guard's test).

    The guard (:func:`liefi.stability.estimate`) warns past ``dt omega > limit`` and refuses when the
    tableau amplifies the unforced motion by more than :data:`~liefi.stability.GROWTH_LIMIT` a step.
    ``limit``: :func:`resolution_limit` for the horizon ``T`` and ``rtol`` when both are given (the run
    passes it to the guard), else :data:`~liefi.stability.RESOLUTION_LIMIT`.  ``measured``: a step at
    which the run's global error was measured in the asymptotic regime (the check): up to it the motion
    is resolved by measurement, whatever the bound.
    """
    from .stability import RESOLUTION_LIMIT, estimate

    limit = RESOLUTION_LIMIT
    for _ in range(60):
        with np.errstate(all="ignore"):
            est = estimate(fi, dt, tab, y0=Y.reshape(fi.batch + (fi.n,)) if fi.batch else Y[0])
        if T is not None and rtol is not None and est.rate > 0:
            # never below the guard's fixed limit: shortening the step for accuracy is the measured error's
            # job (the bound takes the fastest rate as lasting the whole run: Kepler's pericentre does not)
            limit = max(resolution_limit(tab, T, est.rate / dt, rtol), RESOLUTION_LIMIT)
            if measured:
                limit = max(limit, est.rate / dt * measured * (1 + 1e-9))
        if not (est.rate > limit or est.unresolvable):
            break
        # the rate scales with dt: straight to just inside its limit; past the growth limit 0.8x a time
        dt *= 0.8 if est.unresolvable or not est.rate > 0 else min(0.98, 0.98 * limit / est.rate)
    return dt, limit


def stable_step(fi, sch, Y, dt, T):
    """``(dt, dt_stable)``: ``dt`` shortened to :data:`STABLE_FRACTION` of the largest step at which an explicit
    scheme keeps the feedback stable along the run, at ``fi``'s fixed gains.

    An explicit tableau steps the feedback's stiff mode ``-lambda`` by ``R(-dt lambda)``, stable while
    ``dt lambda_max <= beta`` (:mod:`liefi.stability`); ``lambda_max`` (of ``A Hess V``) changes along the motion
    (Kepler's grows 4.6x from the start to the pericentre), so it is taken along the stability guard's pilot
    over the horizon ``T`` (:func:`liefi.stability.estimate`) with a budget that covers the horizon at the
    pilot's step (within :data:`~liefi.stability.PILOT_MAX_EVALS`; the run's own check scales its budget with
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
    elif dt_given:
        parts.append(f"dt {dt:.6g} as asked")
    parts.append(f"backend {backend}")
    out = {"scheme": scheme, "dt": float(dt), "gains": "auto" if gains_mode == "auto" else "fixed",
           "backend": backend, "why": "; ".join(parts)}
    if chosen is not None:
        out["rtol"] = chosen["rtol"]
        out["atol"] = chosen["atol"]
    return out
