"""The stability map of a feedback integrator in the ``(dt, gain)`` plane: measured by bisection, drawn with the estimate.

For every gain ``k`` (all gains equal to ``k``) the largest ``dt`` whose run
stays finite and the largest whose drift stays below ``accurate`` are found by
bisection in ``dt``; :func:`plot_stability_map` draws them with the estimate
``dt_max(k) = beta / lambda_max(k)`` of :mod:`liefi.integrator.stability`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..schemes import IntegrationError, positive_number
from ..integrator.stability import PILOT_MAX_EVALS, drift, drift_scales, estimate, resolve_scheme
from .._progress import Progress

# --------------------------------------------------------------------------------
# the stability map in the (dt, gain) plane
# --------------------------------------------------------------------------------


@dataclass
class GainBoundary:
    """The measured and estimated stability limits in ``dt`` at one gain ``k`` (all gains equal to ``k``).

    ``finite = (lo, hi)``: runs at ``dt <= lo`` finished with finite numbers,
    at ``dt >= hi`` they overflowed (``None``: not found in the searched range).
    ``accurate = (lo, hi)``: the same for "finite and every invariant's drift
    at most ``accurate`` of its scale" (:func:`drift_scales`).
    ``dt_estimate``: ``beta / lambda_max(k)``, ``lambda_max`` the largest along the
    pilot; ``dt_estimate0``: the same at ``t = 0``.
    """

    gain: float
    dt_estimate: float
    dt_estimate0: float
    finite: tuple
    accurate: tuple
    runs: list = field(default_factory=list)

    @property
    def dt_finite(self):
        return _mid(self.finite)

    @property
    def dt_accurate(self):
        return _mid(self.accurate)


def _mid(b):
    lo, hi = b
    if lo is None or hi is None:
        return lo if hi is None else hi
    return math.sqrt(lo * hi)


@dataclass
class StabilityMap:
    """Result of :func:`stability_map`: one :class:`GainBoundary` per gain."""

    label: str
    scheme: str
    bound: float
    t_final: float
    tol: float
    accurate: float
    boundaries: list

    @property
    def gains(self):
        return np.array([b.gain for b in self.boundaries])

    def table(self):
        """Markdown table: gain, estimated and measured ``dt`` limits, ``dt k`` at each."""
        rows = [
            "| k | estimate dt_max (along run) | estimate at t=0 | measured: finite | measured: drift <= "
            f"{self.accurate:g} | dt*k (finite) | dt*k (accurate) |",
            "| --- | --- | --- | --- | --- | --- | --- |",
        ]

        def br(b):
            lo, hi = b
            if lo is None and hi is None:
                return "-"
            if hi is None:
                return f">= {lo:.4g}"
            if lo is None:
                return f"< {hi:.4g}"
            return f"{lo:.4g} .. {hi:.4g}"

        for b in self.boundaries:
            f, a = b.dt_finite, b.dt_accurate
            rows.append(
                f"| {b.gain:g} | {b.dt_estimate:.4g} | {b.dt_estimate0:.4g} | {br(b.finite)} | {br(b.accurate)} | "
                f"{'-' if f is None else f'{f * b.gain:.3g}'} | {'-' if a is None else f'{a * b.gain:.3g}'} |"
            )
        return "\n".join(rows)

    def to_dict(self):
        return {
            "label": self.label, "scheme": self.scheme, "bound": self.bound, "t_final": self.t_final,
            "tol": self.tol, "accurate": self.accurate,
            "boundaries": [
                {"gain": b.gain, "dt_estimate": b.dt_estimate, "dt_estimate0": b.dt_estimate0,
                 "finite": list(b.finite), "accurate": list(b.accurate), "runs": len(b.runs)}
                for b in self.boundaries
            ],
        }


def _target_integrator(target, variant=None):
    """``(FeedbackIntegrator, label, horizon)`` from a scene name, a Scene or an integrator."""
    from ..integrator.feedback import FeedbackIntegrator
    from ..scenes import base as _base

    if isinstance(target, str):
        from .. import scenes as _scenes

        target = _scenes.get(target)
    if isinstance(target, _base.Scene):
        v = target.variant(variant)
        return target.integrator(v), f"{target.name} ({v.name})", float(target.t_final)
    if isinstance(target, FeedbackIntegrator):
        return target, "integrator", math.inf
    raise TypeError(f"target: expected a scene name, a liefi Scene or a FeedbackIntegrator, got {target!r}")


def _classify(fi, dt, T, scheme, scales, backend):
    """Run ``fi`` at ``dt`` for ``T``; ``(finite, largest relative drift)``."""
    n = max(1, int(math.ceil(T / dt - 1e-9)))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sol = fi.run(n * dt, dt=dt, scheme=scheme, save_every=max(1, n // 2000), backend=backend,
                         check_stability=False, adaptive=False)
    except IntegrationError:
        return False, math.inf
    with np.errstate(all="ignore"):
        d, _ = drift(fi, np.moveaxis(sol.y, -1, 0), scales)
    return bool(np.isfinite(d)), float(d)


def _bisect(pred, start, tol, dt_min, dt_max):
    """``(lo, hi)`` with ``pred(lo)`` true, ``pred(hi)`` false and ``hi/lo <= 1 + tol`` (log bisection)."""
    lo = hi = None
    dt = min(max(start, dt_min), dt_max)
    for _ in range(60):
        if pred(dt):
            lo = dt
            if hi is not None or dt >= dt_max:
                break
            dt = min(dt * 2, dt_max)
        else:
            hi = dt
            if lo is not None or dt <= dt_min:
                break
            dt = max(dt / 2, dt_min)
    if lo is None or hi is None:
        return lo, hi
    while hi / lo > 1 + tol:
        mid = math.sqrt(lo * hi)
        if pred(mid):
            lo = mid
        else:
            hi = mid
    return lo, hi


def _boundary_task(task):
    """One gain's bisection (module level, so a process pool can run it)."""
    (spec, k, scheme, T, tol, accurate, backend, dt_guess, dt_est, dt_est0) = task
    if spec[0] == "scene":
        from .. import scenes as _scenes

        base = _scenes.get(spec[1]).integrator(spec[2])
    else:
        base = spec[1]
    fi = base.with_gains(float(k))
    scales = drift_scales(base)
    cache = {}

    def res(dt):
        key = float(f"{dt:.12g}")
        if key not in cache:
            cache[key] = _classify(fi, key, T, scheme, scales, backend)
        return cache[key]

    dt_min, dt_max = dt_guess * 1e-4, min(T / 4, dt_guess * 1e4)
    fin = _bisect(lambda d: res(d)[0], dt_guess, tol, dt_min, dt_max)
    start = fin[0] if fin[0] is not None else dt_guess
    acc = _bisect(lambda d: res(d)[0] and res(d)[1] <= accurate, start, tol, dt_min, dt_max)
    runs = sorted((d, f, a) for d, (f, a) in cache.items())
    return GainBoundary(float(k), dt_est, dt_est0, fin, acc, runs)


def stability_map(target, *, gains=None, scheme="euler", t_final=None, variant=None, tol=0.02, accurate=1e-2,
                  executor=None, backend="auto") -> StabilityMap:
    """Measure the stable region in the ``(dt, k)`` plane (every gain equal to ``k``).

    For each gain, bisection in ``dt`` (on a log scale, from the estimate
    ``beta/lambda_max(k)``) finds two boundaries to a relative tolerance
    ``tol``: where the run stops finishing with finite numbers ("finite"), and
    where its largest relative drift exceeds ``accurate`` ("accurate"); see
    :class:`GainBoundary`.  Each run is ``t_final`` long (default the scene's
    horizon capped at 10).  The search is bounded: ``dt`` within ``1e-4`` to
    ``1e4`` times the estimate and at most ``t_final / 4``.

    Parameters
    ----------
    target : str, Scene or FeedbackIntegrator
    gains : sequence of float, optional
        Default ``10**[0, 0.5, ..., 4]``.
    scheme : str
    t_final, variant, tol, accurate : see above
    executor : concurrent.futures.Executor, optional
        Runs the gains concurrently (``executor.map``); default serial.  With a
        process pool, give the target as a scene name (an integrator built
        from user lambdas cannot be pickled).
    backend : str
        ``"auto"`` (compiled when numba is available), ``"numpy"`` or ``"numba"``.

    Returns
    -------
    StabilityMap
    """
    fi, label, horizon = _target_integrator(target, variant)
    T = float(t_final) if t_final is not None else min(horizon, 10.0)
    T = positive_number(T, "t_final")
    gains = np.array([10 ** (i / 2) for i in range(9)] if gains is None else gains, dtype=float)
    if gains.ndim != 1 or gains.size == 0 or not np.all(np.isfinite(gains)) or np.any(gains <= 0):
        raise ValueError(f"gains: expected a non-empty list of positive finite gains, got {gains!r}")
    tol = positive_number(tol, "tol")
    accurate = positive_number(accurate, "accurate")
    sch, beta = resolve_scheme(scheme)
    unit = fi.with_gains(1.0)
    est = estimate(unit, 1.0, sch, t_final=T, max_evals=PILOT_MAX_EVALS, resolution=False)
    lam1, lam10 = max(est.lam, 1e-300), max(est.lam0, 1e-300)
    if isinstance(target, str) or not hasattr(target, "with_gains"):
        from ..scenes import base as _base

        sc = target if not isinstance(target, str) else None
        name = target if isinstance(target, str) else sc.name
        spec = ("scene", name, variant) if (isinstance(target, str) or isinstance(target, _base.Scene)) else ("fi", fi)
    else:
        spec = ("fi", fi)
    tasks = []
    for k in gains:
        dt_est = beta / (k * lam1) if math.isfinite(beta) else math.inf
        dt_est0 = beta / (k * lam10) if math.isfinite(beta) else math.inf
        guess = dt_est if math.isfinite(dt_est) else 1.0 / (k * lam1)
        tasks.append((spec, float(k), getattr(sch, "name", scheme), T, tol, accurate, backend, guess, dt_est, dt_est0))
    mapper = map if executor is None else executor.map
    with Progress(len(tasks), f"stability map {label}", unit="gain") as bar:
        bounds = []
        for b in mapper(_boundary_task, tasks):
            bounds.append(b)
            bar.update()
    return StabilityMap(label, getattr(sch, "name", str(scheme)), beta, T, tol, accurate, bounds)


def plot_stability_map(smap, path=None, ax=None):
    """Draw a :class:`StabilityMap`: measured boundaries over the estimate ``dt_max(k) = beta/lambda_max(k)``.

    Returns the matplotlib axes; writes ``path`` (PNG) when given.
    """
    import matplotlib

    if ax is None and path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(6.0, 4.2))
    b = smap.boundaries
    k = np.array([x.gain for x in b])
    est = np.array([x.dt_estimate for x in b])
    est0 = np.array([x.dt_estimate0 for x in b])

    def col(which, i):
        return np.array([np.nan if getattr(x, which)[i] is None else getattr(x, which)[i] for x in b], float)

    f_lo, f_hi, a_lo, a_hi = col("finite", 0), col("finite", 1), col("accurate", 0), col("accurate", 1)
    f_mid = np.sqrt(f_lo * f_hi)
    a_mid = np.sqrt(a_lo * a_hi)
    finite_all = np.concatenate([x[np.isfinite(x)] for x in (est, f_lo, f_hi, a_lo, a_hi)])
    top = float(np.nanmax(finite_all)) * 4 if finite_all.size else 1.0
    bottom = float(np.nanmin(finite_all)) / 4 if finite_all.size else 1e-6
    hi_f = np.where(np.isfinite(f_mid), f_mid, top)
    hi_a = np.where(np.isfinite(a_mid), a_mid, hi_f)
    ax.fill_between(k, hi_f, top, color="tab:red", alpha=0.15, lw=0, label="overflow (non-finite)")
    ax.fill_between(k, hi_a, hi_f, color="tab:orange", alpha=0.2, lw=0, label=f"finite, drift > {smap.accurate:g}")
    ax.fill_between(k, bottom, hi_a, color="tab:green", alpha=0.12, lw=0, label="stable and accurate")
    ax.plot(k, 1.0 / k, color="0.6", ls="--", lw=0.8, label="dt k = 1")
    if np.all(np.isfinite(est)):
        ax.plot(k, est, "k-", lw=1.5, label=r"estimate $\beta/\lambda_{max}(k)$ along the run")
        ax.plot(k, est0, "k:", lw=1.2, label=r"estimate at $t=0$")
    ax.errorbar(k, f_mid, yerr=[f_mid - f_lo, f_hi - f_mid], fmt="o", color="tab:red", ms=4, label="measured: finite")
    ax.errorbar(k, a_mid, yerr=[a_mid - a_lo, a_hi - a_mid], fmt="s", color="tab:green", ms=4,
                label="measured: accurate")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(bottom, top)
    ax.set_xlabel("gain k (every gain equal to k)")
    ax.set_ylabel("dt")
    ax.set_title(f"{smap.label}, {smap.scheme}, t in [0, {smap.t_final:g}]", fontsize=10)
    ax.legend(fontsize=7, loc="lower left")
    if own and path is not None:
        fig.tight_layout()
        from .._files import replacing

        with replacing(path) as tmp:  # whole or not at all
            fig.savefig(tmp, dpi=110)
        plt.close(fig)
    return ax

