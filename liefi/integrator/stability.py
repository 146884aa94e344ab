r"""Where a feedback integrator is stable, said before it runs: the stiffness, the bounds, the pilot.

The feedback term ``-A grad V`` of ``y' = X(y) - A grad V(y)`` is stiff by
design.  On the invariant set ``V = 0`` every residual ``I_j - I_j0`` vanishes,
so the Hessian of

.. math:: V = \frac{k_0}{4}\|R^T R - I\|^2 + \sum_j \frac{k_j}{2} (I_j - I_{j0})^2

is exactly

.. math:: \nabla^2 V = \sum_j k_j \nabla I_j \nabla I_j^T + k_0 \nabla^2 P ,

and (with ``A = I``) its largest eigenvalue ``lambda_max`` is the larger of
``2 k0`` (the penalty: ``P(R + dR) = ||sym(R^T dR)||^2 + O(dR^3)``) and the
largest eigenvalue of the ``m x m`` Gram matrix
``G_ij = sqrt(k_i k_j) grad I_i . grad I_j`` -- cheap enough to evaluate along
a run.  An explicit Runge--Kutta scheme applied to the stiff mode
``y' = -lambda y`` is stable while ``dt * lambda`` stays in ``[0, beta]``,
``beta`` the scheme's real stability bound (Euler and Heun 2, RK3 2.51, RK4
2.785: :attr:`liefi.schemes.ExplicitRungeKutta.real_stability_bound`).  Off
the invariant set the terms ``(I_j - I_j0) Hess I_j`` are dropped (they are of
the size of the drift; ``stiffness(..., exact=True)`` includes them by finite
differences of ``grad V``).

What this module does with that number -- the theory, which chooses no gains
and calls nothing above it:

* :func:`stiffness` -- ``lambda_max`` over a whole batch at once (vectorized
  Gram matrices, ``O(1)`` calls per run); :func:`stable_dt` -- the largest
  stable step for a spectrum; :func:`resolve_scheme` -- the scheme's bound
  (read from the scheme, :mod:`liefi.schemes.registry`).
* The unforced motion: :func:`dynamics_rates` (the spectral radius of
  ``dX/dy``), :func:`dynamics_growth` and :func:`growth_step` (how much the
  scheme amplifies it), :func:`pilot` (a cheap preview of it) and
  :func:`metric_defect` (where the metric degenerates along it).
* :func:`estimate` -- the largest safe ``dt`` and gain, at the start (or, with
  ``t_final``, along the pilot, for ``liefi stability --estimate``);
  :func:`check` warns (:class:`LiefiStabilityWarning`) from ``dt lambda_max >=
  0.99 beta`` and refuses (``ValueError``) past ``10 beta``.
* :func:`drift` and :func:`drift_scales` -- the invariants' drift relative to
  their scale, which the guard watches.

Above it, :mod:`liefi.integrator.gains` chooses the gains from these numbers (the unit-rate
gains ``1/|grad I_j|^2``, the accurate rate, the contraction rate ``x*`` of
Bae & Chang, "Feedback integrators revisited", arXiv:2512.01528, and the gains
re-chosen along an adaptive run -- needed where the stiffness grows, e.g. the
Heisenberg system, whose ``|grad J|^2`` grows like ``|q|^2``); the guard
(:mod:`liefi.integrator.guard`) turns them into verdicts; the run's policy
(:mod:`liefi.integrator.policy`) asks both, once per segment.

The (dt, gain) maps, the extreme-case battery and the stiff work-precision
study are experiments: :mod:`liefi.experiments`.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from .._diff import directions_after
from .drift import drift, drift_scales, first_integral_defect, residuals  # noqa: F401 -- part of this module's API
from ..schemes import IntegrationError
from ..schemes import positive_int as _positive_int  # noqa: F401
from ..schemes.registry import takes_scheme
from ..schemes import split as _stiff

#: ``dt lambda_max / beta`` within this of 1 is "at the limit" (marginal: the stiff mode neither grows nor decays).
LIMIT_BAND = 0.01
#: Refuse a run whose ``dt lambda_max`` exceeds the bound by this factor (unless ``check_stability=False``).
REFUSE_RATIO = 10.0
#: Warn when ``dt`` times the spectral radius of ``dX/dy`` (the unforced dynamics) exceeds this.
RESOLUTION_LIMIT = 0.2
#: Refuse when the scheme amplifies the unforced motion by more than this per step (``max |R(dt mu)|``).
GROWTH_LIMIT = 1.05
#: Fraction of a run's right-hand-side evaluations the pre-run pilot may spend (and its cap).
PILOT_FRACTION = 0.05
PILOT_MAX_EVALS = 6000
PILOT_MIN_EVALS = 60
#: The pilot a run's guard makes: this many evaluations of ``X`` at most (it only has
#: to find where the stiffness grows), on at most ``PILOT_MEMBERS`` members of a batch.
PILOT_GUARD_EVALS = 240
#: The pilot (of ``X``, which keeps every invariant) ends where its own relative drift passes this.
PILOT_DRIFT = 1e-3
PILOT_MEMBERS = 4
#: The pilot's step ``h`` keeps ``h rho <= PILOT_MAX_RATE`` (``rho`` the spectral radius of ``dX/dy`` at the start).
PILOT_MAX_RATE = 0.5
#: In a run past the limit, a drift (relative to the invariant's scale) above this is an explosion.
GUARD_DRIFT = 1e-2
#: Members of a batch on which the (per-state) resolution of the unforced dynamics is estimated.
RESOLUTION_MEMBERS = 16


class LiefiStabilityWarning(UserWarning):
    """A run is at or past its scheme's stability limit (or under-resolves the dynamics)."""


class StabilityError(IntegrationError):
    """A run's invariants drifted away after ``dt lambda_max`` left the scheme's stability region.

    Attributes as :class:`~liefi.schemes.IntegrationError` (``t``: time of the
    check that failed, ``y``: the state there, ``components``: the invariants).
    """


# --------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------


def _fmt_gain(v):
    """A gain as text; per-member gains (an array) as their range."""
    if np.ndim(v) == 0:
        return f"{float(v):.4g}"
    lo, hi = float(np.min(v)), float(np.max(v))
    return f"{lo:.4g}" if lo == hi else f"{lo:.4g}..{hi:.4g} (per member)"


def _fmt_gains(gains):
    vals = [_fmt_gain(v) for v in gains.values()]
    if vals and all(v == vals[0] for v in vals):
        return f"all {vals[0]}"
    return ", ".join(f"{k}={v}" for k, v in zip(gains, vals))


def _scaled(gains, factor):
    """``{k: v * factor}``: a float for a common gain and factor, else an array (one per member)."""
    out = {k: np.asarray(v, float) * np.asarray(factor, float) for k, v in gains.items()}
    return {k: float(v) if v.ndim == 0 else v for k, v in out.items()}


# --------------------------------------------------------------------------------
# schemes
# --------------------------------------------------------------------------------


@takes_scheme
def resolve_scheme(scheme):
    """``(scheme, beta)``: the registry's scheme and its real stability bound (``inf`` when stiff-safe).

    A name is looked up at the call (:func:`liefi.schemes.registry.takes_scheme`); a run passes its object.
    """
    if isinstance(scheme, _stiff.BoundSplitStep):
        scheme = scheme.scheme
    sch = scheme
    return sch, float(getattr(sch, "real_stability_bound", math.inf))


def _R(sch, z):
    return sch.stability_function(z)


def real_stability_bound(scheme):
    """The scheme's real stability bound ``beta`` (:attr:`liefi.schemes.rk.ExplicitRungeKutta.real_stability_bound`)."""
    return resolve_scheme(scheme)[1]


# --------------------------------------------------------------------------------
# the stiffness: largest eigenvalue of A Hess V
# --------------------------------------------------------------------------------


def _penalty_lam(fi, y):
    """Largest eigenvalue of ``k0 Hess P`` at ``y`` (``(...)``), 0 without a penalty."""
    y = np.asarray(y, float)
    if not fi.use_penalty or np.all(np.asarray(fi.gains.get("penalty", 0.0)) == 0.0):
        return np.zeros(y.shape[:-1])
    return fi.gains["penalty"] * fi.system.space.group.penalty_hessian_max(y[..., : fi.nc])


@dataclass
class Stiffness:
    """Largest eigenvalue of ``A Hess V`` at a batch of states.

    Attributes
    ----------
    lam : ndarray (...)
        ``lambda_max`` (real part, when ``A`` makes the spectrum complex).
    dominant : ndarray of str (...)
        The invariant the stiffest mode belongs to most (``"penalty"`` for the embedding).
    eigenvalues : ndarray (..., r)
        The nonzero spectrum used for non-real stability checks (``A`` given), else the Gram eigenvalues.
    """

    lam: np.ndarray
    dominant: np.ndarray
    eigenvalues: np.ndarray


def stiffness(fi, y, *, exact=False) -> Stiffness:
    """``lambda_max(A Hess V)`` at ``y`` (batch-first), from the invariants' gradients.

    Parameters
    ----------
    fi : FeedbackIntegrator
    y : array_like (..., n)
    exact : bool
        Use the full Hessian of ``V`` by central differences of ``grad V``
        (includes the ``(I_j - I_j0) Hess I_j`` terms; ``2n`` gradient
        evaluations) instead of the Gram matrix (exact on the invariant set).
    """
    y = np.asarray(y, dtype=float)
    batch = y.shape[:-1]
    if exact:
        n = y.shape[-1]
        h = 1e-6 * np.maximum(1.0, np.abs(y))
        E = np.eye(n)
        pts = np.concatenate([y[..., None, :] + h[..., None, :] * E, y[..., None, :] - h[..., None, :] * E], -2)
        with directions_after(y):  # the axis of the 2n differences is not a state axis (per-member data)
            gV = fi.grad_lyapunov(pts)
        H = (gV[..., :n, :] - gV[..., n:, :]) / (2 * h[..., :, None])
        H = 0.5 * (H + np.swapaxes(H, -1, -2))
        M = H if fi.A is None else np.einsum("ij,...jk->...ik", fi.A, H)
        ev = np.linalg.eigvalsh(M) if fi.A is None else np.linalg.eigvals(M)
        lam = np.max(ev.real, axis=-1)
        return Stiffness(lam, np.full(batch, "Hess V", dtype=object), ev)
    jet = fi.invariant_gradients(y)
    if fi.A is not None:
        _, H = _stiff.feedback_hessian(fi, y, jet)
        ev = np.linalg.eigvals(np.einsum("ij,...jk->...ik", fi.A, H))
        lam = np.max(ev.real, axis=-1) if ev.shape[-1] else np.zeros(batch)
        return Stiffness(lam, np.full(batch, "A Hess V", dtype=object), ev)
    m = len(jet.names)
    lam_p = _penalty_lam(fi, y)
    if m:
        W = jet.grad * np.sqrt(jet.gains)[..., None]
        G = W @ np.swapaxes(W, -1, -2)
        w, vec = np.linalg.eigh(G)
        lam_z = w[..., -1]
        dom = np.asarray(jet.names, dtype=object)[np.argmax(np.abs(vec[..., :, -1]), axis=-1)]
    else:
        w = np.zeros(batch + (0,))
        lam_z = np.zeros(batch)
        dom = np.full(batch, "", dtype=object)
    lam = np.maximum(lam_z, lam_p)
    dom = np.where(lam_p > lam_z, "penalty", dom)
    ev = np.concatenate([w, lam_p[..., None]], -1) if fi.use_penalty else w
    return Stiffness(lam, dom, ev)


def stable_dt(scheme, eigenvalues):
    """Largest ``dt`` with ``|R(-dt mu)| <= 1`` for every eigenvalue ``mu`` of ``A Hess V``.

    For real ``mu >= 0`` this is ``beta / max mu``; complex eigenvalues (a
    non-symmetric ``A``) are checked on the scheme's stability polynomial.
    """
    sch, beta = resolve_scheme(scheme)
    mu = np.asarray(eigenvalues).ravel()
    mu = mu[np.abs(mu) > 0]
    if not np.isfinite(beta) or mu.size == 0:
        return math.inf
    if np.all(np.abs(mu.imag) <= 1e-12 * np.abs(mu.real)):
        return beta / float(np.max(mu.real))
    hi = beta / float(np.max(np.abs(mu)))
    lo = 0.0
    for _ in range(60):
        mid = 0.5 * (lo + hi) if lo else hi
        if np.all(np.abs(_R(sch, -mid * mu)) <= 1 + 1e-12):
            if mid == hi:
                return hi
            lo = mid
        else:
            hi = mid
    return lo


# --------------------------------------------------------------------------------
# pilot and estimate
# --------------------------------------------------------------------------------


def pilot(fi, y0, t_final, *, max_evals=2000, max_rate=None):
    """A cheap preview of the run: the extended field ``X`` (no feedback) by fixed-step RK4.

    Returns ``(t, Y)`` with ``Y`` of shape ``(N,) + y0.shape``: the start and
    every pilot step, until ``t_final`` or the budget of ``max_evals``
    evaluations of ``X`` (so ``t[-1]`` says how far it got).  The step ``h``
    keeps ``h rho <= max_rate`` (``rho`` the spectral radius of ``dX/dy`` at
    the start; RK4's local error is ``(h rho)^5 / 120 ~ 3e-4`` at 1/2: enough to
    find where the stiffness grows) and spreads the budget over ``[0, t_final]``.  ``X`` keeps every invariant, so the
    feedback run stays near this trajectory.
    """
    from ..schemes.rk import RK4

    max_rate = PILOT_MAX_RATE if max_rate is None else max_rate
    y0 = np.asarray(y0, dtype=float)
    X = fi.unforced_vector_field
    budget = max(1, int(max_evals) // RK4.stages - 1)
    with np.errstate(all="ignore"):
        try:
            few, Y0 = _spread(fi, y0, PILOT_MEMBERS)
            with few.selection():
                rho = dynamics_rate(few, Y0)
        except Exception:  # noqa: BLE001 -- a pilot that cannot start leaves the estimate at y0
            return np.array([0.0]), y0[None]
        h = float(t_final) / budget
        if math.isfinite(rho) and rho > 0:
            h = min(h, float(max_rate) / rho)
        if not h > 0:  # a horizon so short (a subnormal) that its pilot step underflows: the start alone
            return np.array([0.0]), y0[None]
        steps = int(min(budget, math.ceil(float(t_final) / h - 1e-9)))
        ts, Ys, y = [0.0], [y0], y0
        for k in range(1, steps + 1):
            try:
                y = RK4.step(X, y, h)
            except Exception:  # noqa: BLE001
                break
            if not np.all(np.isfinite(y)):
                break
            ts.append(min(k * h, float(t_final)))
            Ys.append(y)
        ts, Ys = np.array(ts), np.stack(Ys)
        # X keeps every invariant: where the pilot's own drift passes PILOT_DRIFT it has stopped
        # following the motion (its step was set at the start), so it ends there
        try:
            scales = drift_scales(fi, y0)
            jet = fi.invariant_gradients(Ys)
            rel = np.zeros(len(ts))
            for j, nm in enumerate(jet.names):
                r = np.abs(jet.residual[..., j] - jet.residual[:1, ..., j]).reshape(len(ts), -1).max(axis=1)
                rel = np.maximum(rel, np.nan_to_num(r / scales.get(nm, 1.0), nan=np.inf))
            bad = np.nonzero(rel > PILOT_DRIFT)[0]
            if bad.size:
                ts, Ys = ts[: max(int(bad[0]), 1)], Ys[: max(int(bad[0]), 1)]
        except Exception:  # noqa: BLE001 -- keep the pilot as it is
            pass
    return ts, Ys


def dynamics_eigenvalues(fi, y, field=None):
    """Eigenvalues of ``dX/dy`` (the unforced field) at the states ``y`` by central differences (flat array);
    ``field``: ``X`` on a batch of states when the caller has a faster one (compiled), else numpy's."""
    return _dynamics_eigenvalues(fi, y, field).ravel()


def dynamics_rates(fi, y):
    """Spectral radius of ``dX/dy`` at each state of ``y`` (shape ``y.shape[:-1]``; a float for one state)."""
    r = np.max(np.abs(_dynamics_eigenvalues(fi, y)), axis=-1, initial=0.0)
    return float(r) if r.ndim == 0 else r


def _dynamics_eigenvalues(fi, y, field=None):
    """Eigenvalues of ``dX/dy`` at the states ``y``: ``(..., n)``; above
    :data:`~liefi.integrator._krylov.DENSE_MAX_STATES` states the outer ones (``(..., m)``, Arnoldi's Ritz
    values from Jacobian-vector products, :func:`~liefi.integrator._krylov.ritz_values`)."""
    from ._krylov import DENSE_MAX_STATES, ritz_values

    y = np.asarray(y, dtype=float)
    n = y.shape[-1]
    if n > DENSE_MAX_STATES:
        return ritz_values(fi.unforced_vector_field, y)
    h = 1e-6 * np.maximum(1.0, np.abs(y))
    E = np.eye(n)
    pts = np.concatenate([y[..., None, :] + h[..., None, :] * E, y[..., None, :] - h[..., None, :] * E], -2)
    with np.errstate(all="ignore"), directions_after(y):  # the differences' axis is not a state axis
        F = (fi.unforced_vector_field if field is None else field)(pts)
        Jt = (F[..., :n, :] - F[..., n:, :]) / (2 * h[..., :, None])  # rows: d f / d y_k
        ev = np.linalg.eigvals(np.swapaxes(Jt, -1, -2))
    return ev


def dynamics_rate(fi, y):
    """Spectral radius of ``dX/dy`` (the unforced field) at ``y`` (max over a batch)."""
    ev = dynamics_eigenvalues(fi, y)
    return float(np.max(np.abs(ev), initial=0.0))


def dynamics_growth(scheme, dt, eigenvalues):
    r"""``max |R(dt mu)| / max(1, |exp(dt mu)|)`` over the eigenvalues ``mu`` of ``dX/dy``: the scheme's own growth.

    ``R`` is the stability function of the scheme's explicit tableau (for a split
    scheme, the tableau that steps ``X``).  The exact flow of the linearized
    motion multiplies the mode of ``mu`` by ``exp(dt mu)`` a step; a mode the
    motion itself stretches (a real ``mu > 0``: Kepler's radial direction near
    perihelion, ``mu = sqrt(2 mu_K / r^3)``) grows under any accurate scheme,
    and is not the scheme's fault.  What no feedback on the invariants can repair
    is growth *beyond* that and beyond 1 -- e.g. Euler on a rotation,
    ``|1 + i dt omega| > 1 = |exp(i dt omega)|`` -- so the growth is measured
    against ``max(1, |exp(dt mu)|)``: 1 for an exact or a contracting step, ``> 1``
    for one that amplifies the motion past the flow's own.
    """
    sch, _ = resolve_scheme(scheme)
    tab = sch.explicit if isinstance(sch, _stiff.LinearlyImplicitSplit) else sch
    mu = np.asarray(eigenvalues).ravel()
    mu = mu[np.isfinite(mu)]
    if mu.size == 0 or getattr(tab, "kind", None) != "explicit":
        return math.nan
    z = dt * mu
    exact = np.maximum(1.0, np.exp(np.minimum(np.real(z), 700.0)))
    return float(np.max(np.abs(_R(tab, z)) / exact))


def growth_step(scheme, dt, eigenvalues, limit=None):
    """The largest step ``<= dt`` whose :func:`dynamics_growth` stays within ``limit`` (:data:`GROWTH_LIMIT`).

    Bisection on ``[0, dt]`` (the growth is 1 at a step of 0); ``dt`` itself
    when it is within the limit.  Never larger than ``dt``: the step to suggest
    when a run is refused for amplifying the motion.
    """
    limit = GROWTH_LIMIT if limit is None else limit
    g = dynamics_growth(scheme, dt, eigenvalues)
    if not g > limit:
        return float(dt)
    lo, hi = 0.0, float(dt)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if dynamics_growth(scheme, mid, eigenvalues) > limit:
            hi = mid
        else:
            lo = mid
    return lo


#: A run that fails where the metric's smallest eigenvalue fell below this fraction of
#: its value at the start is said to fail from the metric's degeneracy.
METRIC_DEGENERACY = 0.1


def metric_defect(fi, y, rtol=METRIC_DEGENERACY):
    """A message if the metric loses positive definiteness at a state of ``y`` (else ``""``).

    Lost: an eigenvalue ``<= 0``, or below ``rtol`` times the smallest at the
    start: the inverse metric, the field and ``Hess V`` with it (``~ 1 /
    eigenvalue``) blow up as the metric degenerates.  A run that fails there
    fails from the system's data, not from its gains.
    """
    try:
        n = fi.system.space.data_dim
        if not n:
            return ""

        def metrics(yy):
            x = np.asarray(yy, float)[..., fi.nc : fi.nc + n]  # the states' own shape: per-member data
            m = np.asarray(fi.system.metric(x), float)
            m = np.broadcast_to(m, x.shape[:-1] + m.shape[-2:]).reshape((-1,) + m.shape[-2:])
            x = x.reshape(-1, n)
            return x, 0.5 * (m + np.swapaxes(m, -1, -2))

        with np.errstate(all="ignore"):
            w0 = np.linalg.eigvalsh(metrics(fi.y0)[1])[..., 0]
            x, m = metrics(y)
            w = np.linalg.eigvalsh(m)[..., 0]
    except Exception:  # noqa: BLE001 -- a diagnostic only
        return ""
    bad = np.nonzero(~(w > rtol * float(np.min(w0))))[0]
    if not bad.size:
        return ""
    i = int(bad[0])
    what = "is not positive definite" if not w[i] > 0 else "degenerates (nearly singular)"
    eig = f"smallest eigenvalue {float(w[i]):.3g}" if math.isfinite(w[i]) else "eigenvalues not finite"
    return (f"The metric {what} at x = [{', '.join(f'{v:.6g}' for v in x[i])}] ({eig}; smallest eigenvalue "
            f"{float(np.min(w0)):.3g} at the start): the motion runs into a degenerate metric, where the field "
            f"and the stiffness grow like 1/eigenvalue; no choice of gains repairs that.{_null_direction(fi, m[i])} "
            "If the coordinates are singular there (Euler angles where two of their axes align, as a disc's yaw "
            "and spin at a lean of +-pi/2: the model's own kinematic map divides by zero there too), choose "
            "coordinates regular there or a shorter horizon; a run that stepped through such a place between two "
            "steps (rates grow like 1/sqrt(eigenvalue) near it) may pass with a smaller dt; else check the "
            "metric's data there.")


def _null_direction(fi, m):
    """`` The metric loses rank along [names] ...``: the coordinates of the eigenvector of ``m``'s smallest
    eigenvalue with at least a third of its largest component (``""`` if ``m`` is not finite)."""
    if not np.all(np.isfinite(m)):
        return ""
    v = np.linalg.eigh(m)[1][:, 0]
    names = [str(s) for s in getattr(fi.system.space, "shape_names", ())]
    if len(names) != len(v):
        names = [f"x[{j}]" for j in range(len(v))]
    big = np.nonzero(np.abs(v) >= np.max(np.abs(v)) / 3)[0]
    return (f" It loses rank along {', '.join(f'{v[j]:+.3g} {names[j]}' for j in big)} (the eigenvector of its "
            "smallest eigenvalue).")


@dataclass
class StabilityEstimate:
    """The stability limit of one run, estimated before it (see :func:`estimate`).

    Attributes
    ----------
    scheme : str
    bound : float
        The scheme's real stability bound ``beta`` (``inf``: stiff-safe).
    dt : float
    lam, lam0 : float
        ``lambda_max(A Hess V)``: the largest along the pilot, and at the start.
    t_max : float
        Where along the pilot ``lam`` was reached.
    t_pilot, t_final : float
        How far the pilot got, and the run's horizon.
    gains : dict
    dominant : str
        The invariant the stiffest mode belongs to most.
    eigenvalues : ndarray
        The spectrum at the stiffest point (for non-real checks).
    rate : float
        ``dt`` times the spectral radius of ``dX/dy`` at the start (resolution of
        the unforced dynamics; ``nan`` if not computed).
    """

    scheme: str
    bound: float
    dt: float
    lam: float
    lam0: float
    t_max: float
    t_pilot: float
    t_final: float
    gains: dict
    dominant: str
    eigenvalues: np.ndarray = field(repr=False, default=None)
    rate: float = float("nan")
    #: first pilot time where ``dt lambda`` passes the bound by more than 1 % (``nan``: never)
    t_cross: float = float("nan")
    #: ``max |R(dt mu)| / max(1, |exp(dt mu)|)`` over the eigenvalues of ``dX/dy`` (:func:`dynamics_growth`)
    growth: float = float("nan")
    #: a few states of the pilot (start included), shape ``(k,) + y0.shape``
    samples: np.ndarray = field(repr=False, default=None)
    #: :func:`metric_defect` along the pilot (``""``: the metric stays positive definite)
    metric: str = ""
    #: the largest step ``<= dt`` within :data:`GROWTH_LIMIT` at those eigenvalues (:func:`growth_step`)
    dt_growth: float = float("nan")
    #: the largest ``rate`` that resolves the motion (a run for a tolerance passes its own)
    limit: float = RESOLUTION_LIMIT

    @property
    def dt_safe(self):
        """Largest ``dt`` stable at these gains along the pilot (``inf`` for a stiff-safe scheme)."""
        if not math.isfinite(self.bound) or self.lam <= 0:
            return math.inf
        if self.eigenvalues is not None and np.iscomplexobj(self.eigenvalues) and np.any(self.eigenvalues.imag):
            return stable_dt(self.scheme, self.eigenvalues)
        return self.bound / self.lam

    @property
    def ratio(self):
        """``dt lambda_max / beta`` (1 is the limit); 0 for a stiff-safe scheme."""
        if not math.isfinite(self.dt_safe):
            return 0.0
        return self.dt / self.dt_safe

    @property
    def gain_factor(self):
        """The factor by which every gain may be scaled at this ``dt`` (``dt_safe / dt``)."""
        return self.dt_safe / self.dt

    @property
    def verdict(self):
        """``"ok"``, ``"limit"`` (within 1 % of the bound), ``"beyond"`` or ``"refuse"`` (10x past it)."""
        r = self.ratio
        if r > REFUSE_RATIO:
            return "refuse"
        if r > 1 + LIMIT_BAND:
            return "beyond"
        if r >= 1 - LIMIT_BAND:
            return "limit"
        return "ok"

    @property
    def under_resolved(self):
        """``dt`` times the fastest rate of ``X`` exceeds ``limit`` (:data:`RESOLUTION_LIMIT`; a warning)."""
        return math.isfinite(self.rate) and self.rate > self.limit

    @property
    def unresolvable(self):
        """The scheme amplifies the unforced motion by more than :data:`GROWTH_LIMIT` per step (a refusal)."""
        return math.isfinite(self.growth) and self.growth > GROWTH_LIMIT

    def safe_gains(self, fraction=1.0):
        """The gains scaled to ``fraction`` of the limit at this ``dt``."""
        return _scaled(self.gains, fraction * self.gain_factor)

    def message(self):
        """One paragraph: the numbers, the safe ``dt`` and gain, what to change."""
        r = self.ratio
        v = self.verdict
        where = (
            "at t = 0"
            if self.t_max == 0.0
            else f"reached at t ~ {self.t_max:.4g} of the run (at t = 0: {self.lam0:.4g})"
        )
        head = {
            "ok": "is within",
            "limit": "is at",
            "beyond": "exceeds",
            "refuse": f"is {r:.3g}x",
        }[v]
        s = (
            f"dt*lambda_max = {self.dt * self.lam:.4g} {head} the stability bound {self.bound:.4g} of "
            f"{self.scheme} (dt = {self.dt:g}; lambda_max = {self.lam:.4g}, the largest eigenvalue of "
            f"Hess V, mostly {self.dominant}, {where}; gains {_fmt_gains(self.gains)})."
        )
        if v == "limit":
            s += (
                " The run is marginal: the stiffest mode neither grows nor decays, and a few percent "
                "more gain or step diverges."
            )
        elif v in ("beyond", "refuse"):
            s += " The feedback term is unstable: its stiff mode grows by |R(-dt lambda)| > 1 per step."
        if self.t_pilot < self.t_final * (1 - 1e-9):
            s += f" (Estimated over t in [0, {self.t_pilot:.4g}]; the run is monitored beyond.)"
        if v != "ok":
            gf = self.gain_factor
            vals = list(self.gains.values())
            if vals and all(x == vals[0] for x in vals):
                gtxt = f"{vals[0] * gf:.4g}"
            else:
                gtxt = f"every gain x {gf:.3g}"
            s += (
                f" Largest safe dt at these gains: {self.dt_safe:.4g}; largest safe gain at dt = {self.dt:g}: "
                f"{gtxt}. Or use gains='auto' (chosen from dt and Hess V, adapted along the run), "
                "adaptive=True, or the stiff-safe scheme 'imex-euler' (stable for any gain)."
            )
        return s

    def resolution_step(self):
        """The step to suggest when the run under-resolves or amplifies the motion: never above ``dt``.

        The smaller of ``dt limit / rate`` (when under-resolved) and
        :func:`growth_step` (when the scheme amplifies the motion), times 0.98.
        """
        cands = [self.dt]
        if self.under_resolved:
            cands.append(self.dt * self.limit / self.rate)
        if self.unresolvable and math.isfinite(self.dt_growth):
            cands.append(self.dt_growth)
        return 0.98 * min(cands) if len(cands) > 1 else self.dt

    def resolution_message(self):
        parts = []
        if self.under_resolved:
            parts.append(
                f"dt times the fastest rate of the unforced dynamics is {self.rate:.3g} (> {self.limit:g}): "
                f"the step under-resolves the motion itself, whatever the gains, so the trajectory will be "
                "inaccurate"
            )
        if self.unresolvable:
            parts.append(
                f"{self.scheme} amplifies the linearized unforced motion by {self.growth:.3g} per step beyond the "
                f"exact flow's own growth (max |R(dt mu)| / max(1, |exp(dt mu)|) over the eigenvalues mu of dX/dy, "
                f"at dt times the fastest rate {self.rate:.3g}): the run cannot be meaningful"
            )
        if not parts:
            return f"dt = {self.dt:g} resolves the unforced motion (dt times its fastest rate {self.rate:.3g})."
        return "; ".join(parts) + f"; take dt below {self.resolution_step():.3g} (dt = {self.dt:g} now)."


def _max_evals(n_steps, stages):
    return int(min(PILOT_MAX_EVALS, max(PILOT_MIN_EVALS, PILOT_FRACTION * n_steps * stages)))


def estimate(fi, dt, scheme="euler", *, t_final=None, y0=None, max_evals=None, resolution=True,
             resolution_limit=RESOLUTION_LIMIT) -> StabilityEstimate:
    """Estimate the stability limit of ``fi.run(t_final, dt=dt, scheme=scheme)`` before running it.

    ``lambda_max`` is evaluated at ``y0`` and along :func:`pilot` (up to
    ``t_final``, within ``max_evals`` evaluations of ``X``; default a few
    percent of the run's work).  ``t_final=None``: at
    ``y0`` only.  ``resolution_limit``: the estimate's ``limit`` (a run for a
    tolerance passes the one of :func:`liefi.integrator.tolerance.resolution_limit`).  For a batch ``y0`` the pilot follows :data:`PILOT_MEMBERS`
    members, the stiffest at the start among them: its cost does not grow with
    the batch.
    """
    sch, beta = resolve_scheme(scheme)
    y0 = fi.y0 if y0 is None else np.asarray(y0, float)
    with contextlib.ExitStack() as members:
        members.enter_context(fi.selection())  # some members of an ensemble: their own per-member data
        if fi.batch:  # per-member gains and targets: the pilot's members take theirs along
            fi = fi.members()
            y0 = y0.reshape(-1, y0.shape[-1])
            members.enter_context(fi.selection())
        if t_final is not None and max_evals is None:
            max_evals = _max_evals(t_final / dt, getattr(sch, "stages", 1))
        if t_final is not None and math.isfinite(beta):
            start = y0
            flat = y0.reshape(-1, y0.shape[-1])
            if flat.shape[0] > PILOT_MEMBERS:  # a batch: the pilot follows its stiffest member and a few others
                with np.errstate(all="ignore"):
                    lam_b = np.nan_to_num(np.asarray(stiffness(fi, flat).lam, float), nan=-np.inf)
                pick = np.unique(np.concatenate([[int(np.argmax(lam_b))],
                                                 np.linspace(0, flat.shape[0] - 1, PILOT_MEMBERS - 1).astype(int)]))
                start = flat[pick]
                fi = fi.members(pick)
                members.enter_context(fi.selection())
            ts, Ys = pilot(fi, start, t_final, max_evals=max_evals)
            if len(ts) > 2:  # refine around the stiffest pilot step (a fixed 16 RK4 steps)
                with np.errstate(all="ignore"):
                    lam_p = np.nan_to_num(np.asarray(stiffness(fi, Ys).lam, float), nan=-np.inf)
                i = int(np.argmax(lam_p.reshape(len(ts), -1).max(axis=1)))
                j0, j1 = max(i - 1, 0), min(i + 1, len(ts) - 1)
                t2, Y2 = pilot(fi, Ys[j0], ts[j1] - ts[j0], max_evals=4 * 17)
                ts = np.concatenate([ts, ts[j0] + t2[1:]])
                Ys = np.concatenate([Ys, Y2[1:]])
                order = np.argsort(ts, kind="stable")
                ts, Ys = ts[order], Ys[order]
        else:
            ts, Ys = np.array([0.0]), y0[None]
        with np.errstate(all="ignore"):
            st = stiffness(fi, Ys)
        lam_t = np.asarray(st.lam).reshape(len(ts), -1)
        lam_t = np.where(np.isfinite(lam_t), lam_t, -np.inf)
        per_t = lam_t.max(axis=1)
        i = int(np.argmax(per_t))
        lam = float(max(per_t[i], 0.0))
        lam0 = float(max(per_t[0], 0.0))
        dom = np.asarray(st.dominant, dtype=object).reshape(len(ts), -1)[i]
        dom = str(dom[int(np.argmax(lam_t[i]))])
        ev = np.asarray(st.eigenvalues).reshape((len(ts), lam_t.shape[1]) + st.eigenvalues.shape[-1:])[i]
        ev = ev[int(np.argmax(lam_t[i]))]
        rate = growth = dt_growth = float("nan")
        if resolution:
            try:  # at the start and at a few points of the pilot, on a few members of a batch
                pick = np.unique(np.linspace(0, len(ts) - 1, min(len(ts), 6)).astype(int))
                few, Yp = _spread(fi, Ys[pick], RESOLUTION_MEMBERS)
                with few.selection():
                    evX = dynamics_eigenvalues(few, Yp)
                rate = dt * float(np.max(np.abs(evX), initial=0.0))
                growth = dynamics_growth(sch, dt, evX)
                dt_growth = growth_step(sch, dt, evX) if growth > GROWTH_LIMIT else float(dt)
            except Exception:  # noqa: BLE001 -- a diagnostic only
                rate = growth = dt_growth = float("nan")
        over = np.nonzero(dt * per_t > beta * (1 + LIMIT_BAND))[0] if math.isfinite(beta) else []
        t_cross = float(ts[over[0]]) if len(over) else float("nan")
        return StabilityEstimate(
            getattr(sch, "name", str(scheme)), beta, float(dt), lam, lam0, float(ts[i]), float(ts[-1]),
            float(t_final if t_final is not None else 0.0), dict(fi.gains), dom, ev, rate, t_cross, growth,
            _members(Ys[np.unique(np.linspace(0, len(ts) - 1, min(len(ts), 8)).astype(int))], RESOLUTION_MEMBERS),
            metric_defect(fi, Ys[: i + 2]) if len(ts) > 1 else "", dt_growth, float(resolution_limit),
        )


def _members(Y, k):
    """At most ``k`` states of ``Y`` (``(..., n)``), evenly spread, as ``(m, n)``."""
    flat = np.asarray(Y, float).reshape(-1, np.shape(Y)[-1])
    if flat.shape[0] <= k:
        return flat
    return flat[np.unique(np.linspace(0, flat.shape[0] - 1, k).astype(int))]


def _spread(fi, Y, k):
    """``(fi_k, states)``: :func:`_members` of ``Y`` and ``fi`` restricted to the members they are states of.

    ``Y`` holds states of ``fi``'s ensemble (``(*B, n)``, or a time-major stack ``(T, *B, n)``: flat state
    ``i`` is member ``i mod prod(B)``); ``fi_k`` (:meth:`~liefi.FeedbackIntegrator.members`) evaluates them
    with their own per-member data inside ``fi_k.selection()``.
    """
    flat = np.asarray(Y, float).reshape(-1, np.shape(Y)[-1])
    idx = np.arange(flat.shape[0])
    if flat.shape[0] > k:
        idx = np.unique(np.linspace(0, flat.shape[0] - 1, k).astype(int))
    if not fi.batch:
        return fi, flat[idx]
    return fi.members(idx % int(np.prod(fi.batch, dtype=int))), flat[idx]


def check(fi, dt, scheme="euler", *, t_final=None, y0=None, max_evals=None, stacklevel=2) -> StabilityEstimate:
    """:func:`estimate`, then warn at or past the limit and refuse 10x past it.

    Raises
    ------
    ValueError
        When ``dt lambda_max`` exceeds the scheme's bound by more than
        :data:`REFUSE_RATIO`: the run could not be meaningful.

    Warns
    -----
    LiefiStabilityWarning
        At the limit (within 1 %) or past it, with the largest safe ``dt`` and
        gain; also when ``dt`` under-resolves the unforced dynamics.
    """
    est = estimate(fi, dt, scheme, t_final=t_final, y0=y0, max_evals=max_evals)
    v = est.verdict
    if est.metric and v != "ok":
        raise ValueError(f"initial state: along the motion from it (a pilot of the unforced field) {est.metric}")
    if v == "refuse":
        when = "within a few steps" if not est.t_cross > 0 else f"soon after t ~ {est.t_cross:.3g}"
        raise ValueError(
            "dt: " + est.message() + f" The run would blow up {when}; pass "
            "check_stability=False to run it anyway."
        )
    if est.unresolvable:
        raise ValueError("dt: " + est.resolution_message() + " Pass check_stability=False to run it anyway.")
    if v in ("limit", "beyond"):
        warnings.warn("liefi: " + est.message(), LiefiStabilityWarning, stacklevel=stacklevel + 1)
    if est.under_resolved:
        warnings.warn("liefi: " + est.resolution_message(), LiefiStabilityWarning, stacklevel=stacklevel + 1)
    return est
