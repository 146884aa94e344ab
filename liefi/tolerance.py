r"""The default method and the step chosen for a tolerance.

**The default method.**  :meth:`liefi.FeedbackIntegrator.run` without ``scheme``
runs :data:`DEFAULT_SCHEME`, the split scheme ``imex-rk4``
(:mod:`liefi.schemes.split`): classical RK4 on the extended field ``X``, then
one linearly implicit feedback step.  With ``gains="auto"`` (the constructor's
default) that step is a Gauss--Newton step onto the invariant set
(:data:`liefi.gains.SPLIT_RATE_MAX`), so every invariant stays at rounding for
the price of RK4 plus one gradient evaluation, in any units: the harness
(``liefi bench``) finds it the cheapest run at a given error on every scene
where the error is meaningful.  Without ``dt`` the step is the one chosen here
for the tolerance ``rtol`` (default :data:`DEFAULT_RTOL`).

**A fixed step from an error estimate** (:func:`choose_step`).  Near the
invariant set the split step's error is the error of its tableau on ``X``
(the two substeps nearly commute there), so the step is chosen on ``X``
alone, once, before the run:

1. an error scale per component, ``s_i = atol_i + rtol max_t |y_i(t)|`` over a
   short pilot (``atol`` defaults to ``0``: the scale is relative to each
   component's own size, so the choice does not depend on the units);
2. a first step: the largest ``h = T / 4^k`` whose step-doubling error is
   below :data:`FIRST_ERROR` relative to the components' size (no unit
   enters) and in the asymptotic regime (``h/4`` has an error about
   ``4^{p+1}`` times smaller: no step aliases with a period of the motion),
   enlarged until the local error is well above rounding;
3. a pilot of :data:`PILOT_STEPS` steps of the tableau from ``y_0``, each with a
   step-doubling (Richardson) estimate of its local error:
   ``e = |Phi_h(y) - Phi_{h/2}^2(y)| / (1 - 2^{-p})``, so that
   ``e = C h^{p+1}`` with ``C`` the largest over the pilot, in the norm
   ``max_i |e_i| / s_i``;
4. over ``[t0, t_final]`` of length ``T`` the local errors add up (the
   feedback keeps the invariants, and with them the actions, at rounding, so
   the error is a phase error that grows linearly in ``t``): the global
   error is about ``T C dt^p``.  The step is ``dt = SAFETY (1/(T C))^{1/p}``,
   shortened while the stability guard finds that it does not resolve the
   unforced motion (:func:`resolved_step`: a motion that RK4 integrates
   nearly exactly would otherwise get a step too long for it), then rounded down
   to ``T / N`` for a whole number ``N`` of steps.  The estimate is an upper
   bound in practice (the local error is not the largest all along, and not
   every component's error adds up): the achieved error is 0.001--1 times
   the tolerance on the scenes (``docs/choosing-a-method.md``).

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
whatever the tolerance (the split feedback step), so ``rtol`` is not a knob for
them.
"""

from __future__ import annotations

import importlib.util
import math

import numpy as np

#: The scheme :meth:`liefi.FeedbackIntegrator.run` and ``liefi run`` run unless told otherwise.
DEFAULT_SCHEME = "imex-rk4"
#: The relative tolerance of a run given neither ``dt`` nor ``rtol``.
DEFAULT_RTOL = 1e-6
#: Steps of the pilot (each with a step-doubling error estimate).
PILOT_STEPS = 24
#: The first pilot step is the largest ``T / 4^k`` whose relative local error is below this.
FIRST_ERROR = 1e-5
#: The chosen step is this fraction of the step the estimate allows.
SAFETY = 1.0


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
    a = np.asarray(0.0 if atol is None else atol, dtype=float) if not isinstance(atol, str) else None
    if a is None or not np.all(np.isfinite(a)) or np.any(a < 0):
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


def choose_step(fi, sch, y0, t0, t_end, rtol, atol=None):
    """``(dt, info)``: the fixed step for ``rtol``/``atol`` over ``[t0, t_end]`` (module docstring).

    ``fi`` the integrator, ``sch`` a scheme of the registry (explicit or split),
    ``y0`` the start (a batch: one step for every member, the most demanding).
    ``info``: ``{"rtol", "atol", "order", "local_error_constant", "pilot_step",
    "estimated_error"}`` (the estimated error relative to the tolerance).
    """
    rtol, atol = check_tolerance(rtol, atol)
    tab = _tableau(sch)
    p = int(tab.order)
    T = float(t_end) - float(t0)
    Y = np.asarray(y0, float).reshape(-1, fi.n)
    if atol.ndim and atol.shape[-1:] != (fi.n,):
        raise ValueError(f"atol: expected a number or {fi.n} numbers {fi.names}, got shape {atol.shape}")

    def f(y):
        return fi.unforced_vector_field(y)

    with np.errstate(all="ignore"):
        mag = np.abs(Y)

        parts = _parts(fi)

        def size(m):
            # each component's size, floored at the largest of its part (group element, x, momenta): a
            # component that starts at zero is measured against its neighbours of the same units
            floor = np.stack([np.max(m[..., sl], axis=-1) for sl in parts], -1)
            idx = np.concatenate([np.full(sl.stop - sl.start, j) for j, sl in enumerate(parts)])
            return np.maximum(np.maximum(m, floor[..., idx]), 1e-300)

        def scale(m):
            return atol + rtol * size(m)

        def first_error(hh):
            try:
                y1 = tab.step(f, Y, hh)
                yh = tab.step(f, tab.step(f, Y, hh / 2), hh / 2)
            except (ArithmeticError, np.linalg.LinAlgError, ValueError):
                # a trial step so long that its stages leave the data's domain (a singular metric or
                # constraint there, e.g. a rolling body's stage far from the plane): too long, not an error
                return math.inf
            e = float(np.max(np.abs(y1 - yh) / size(np.maximum(mag, np.abs(yh)))))
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
                e = float(np.max(err / scale(m)))
                if not math.isfinite(e):
                    break
                big = max(big, float(np.max(err / (np.finfo(float).eps * size(m)))))
                c = max(c, e / h ** (p + 1))
                y = yh
            if not math.isfinite(e):
                break  # past the tableau's stability: keep the last estimate
            C, hC, mag = c, h, m
            if big > 1e4 or h >= T:
                break
            h = min(8.0 * h, T)
        h = hC
    if not (C > 0 and math.isfinite(C)):
        dt_est = T  # X is (numerically) exact at any step here, e.g. a state at rest
    else:
        dt_est = SAFETY * (1.0 / (max(T, h) * C)) ** (1.0 / p)
    dt_est = resolved_step(fi, tab, Y, min(dt_est, T))
    n = max(1, math.ceil(T / min(dt_est, T) - 1e-9))
    dt = T / n
    info = {
        "rtol": rtol,
        "atol": float(atol) if atol.ndim == 0 else atol.tolist(),
        "order": p,
        "pilot_step": h,
        "local_error_constant": C,
        "estimated_error": (T * C * dt ** p) if C > 0 else 0.0,
    }
    return dt, info


def resolved_step(fi, tab, Y, dt):
    """``dt``, shortened until it resolves the unforced motion (the stability guard's test).

    The guard (:func:`liefi.stability.estimate`) warns past ``dt omega >``
    :data:`~liefi.stability.RESOLUTION_LIMIT` and refuses when the tableau
    amplifies the unforced motion by more than :data:`~liefi.stability.GROWTH_LIMIT`
    a step; a step chosen for a loose tolerance on a motion the tableau
    integrates (nearly) exactly would otherwise cross them.
    """
    from .stability import RESOLUTION_LIMIT, estimate

    for _ in range(60):
        with np.errstate(all="ignore"):
            est = estimate(fi, dt, tab, y0=Y.reshape(fi.batch + (fi.n,)) if fi.batch else Y[0])
        if not (est.under_resolved or est.unresolvable):
            break
        # the rate scales with dt: straight to just inside its limit; past the growth limit 0.8x a time
        dt *= 0.8 if est.unresolvable or not est.rate > 0 else min(0.98, 0.98 * RESOLUTION_LIMIT / est.rate)
    return dt


def describe(scheme, dt, gains_mode, backend, *, chosen=None, scheme_given=False, dt_given=False):
    """The ``method`` record of a run: ``{"scheme", "dt", "gains", "backend", "why", ...}``.

    ``chosen``: the ``info`` of :func:`choose_step` when the step was chosen for a tolerance.
    """
    parts = []
    if scheme_given:
        parts.append(f"scheme {scheme}")
    else:
        parts.append(f"scheme {scheme} by default (RK4 on X plus one feedback step: the invariants at rounding)")
    if gains_mode == "auto":
        parts.append("gains 'auto' (chosen for accuracy from the scheme, the step and the horizon)")
    else:
        parts.append("fixed gains as asked")
    if chosen is not None:
        parts.append(f"dt {dt:.6g} chosen for rtol {chosen['rtol']:g} (a step-doubling pilot of the order-"
                     f"{chosen['order']} tableau on X, global error ~ T C dt^{chosen['order']})")
    elif dt_given:
        parts.append(f"dt {dt:.6g} as asked")
    parts.append(f"backend {backend}")
    out = {"scheme": scheme, "dt": float(dt), "gains": "auto" if gains_mode == "auto" else "fixed",
           "backend": backend, "why": "; ".join(parts)}
    if chosen is not None:
        out["rtol"] = chosen["rtol"]
        out["atol"] = chosen["atol"]
    return out
