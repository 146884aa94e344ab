r"""Where a feedback integrator is stable, said before it runs; automatic and adaptive gains.

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

What this module does with that number:

* :func:`estimate` -- ``lambda_max`` at the start and along a cheap pilot of
  the extended field ``X`` (adaptive RK45, a few percent of the run's cost),
  the scheme's bound, the largest safe ``dt`` and gain;
  :func:`check` warns (:class:`LiefiStabilityWarning`) from ``dt lambda_max >=
  0.99 beta`` ("at the limit" within 1 %, "beyond" past it) and refuses
  (``ValueError``) past ``10 beta``.  :meth:`liefi.FeedbackIntegrator.run` calls
  it before every fixed-step run (``check_stability=False`` to skip).
* :func:`guarded_run` -- the run itself, in segments; between segments it
  watches ``dt lambda_max`` and the invariants' drift, stops with
  :class:`StabilityError` when the drift explodes past the limit (never O(1)
  garbage returned as a result), adds ``dt lambda_max`` and the safe ``dt`` to
  the message of a non-finite failure, and -- with ``adaptive`` -- rescales the
  gains so that ``dt lambda_max`` stays at the scheme's optimal value.
* Automatic gains (``gains="auto"``): every invariant weighted by
  ``1/|grad I_j|^2`` (the penalty by ``1/2``), all scaled so that
  ``dt lambda_max = x*``, the minimizer of ``|R(-x)|`` on ``[0, beta]`` (``x* = 1``
  for Euler: the optimal fixed gain ``k = 1/(dt L)`` of Bae & Chang, "Feedback
  integrators revisited", arXiv:2512.01528, with ``L`` the Lipschitz constant
  of ``grad V`` at unit gain), and re-chosen along the run (their Hessian-based
  adaptive gain, updated periodically) -- needed where the stiffness grows, e.g.
  the Heisenberg system, whose ``|grad J|^2`` grows like ``|q|^2``.
* :func:`stability_map` measures the stable region in the ``(dt, k)`` plane by
  bisection in ``dt`` per gain and :func:`plot_stability_map` draws it with the
  estimate ``dt_max(k) = beta / lambda_max(k)``; :func:`run_battery` runs the
  extreme cases; :func:`command` is the body of ``liefi stability SCENE``.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .reduction import core as _core
from .schemes import ExplicitRungeKutta, IntegrationError, Solution, integrate
from .schemes import registry as _registry
from .schemes import split as _stiff

#: ``dt lambda_max / beta`` within this of 1 is "at the limit" (marginal: the stiff mode neither grows nor decays).
LIMIT_BAND = 0.01
#: Refuse a run whose ``dt lambda_max`` exceeds the bound by this factor (unless ``check_stability=False``).
REFUSE_RATIO = 10.0
#: Warn when ``dt`` times the spectral radius of ``dX/dy`` (the unforced dynamics) exceeds this.
RESOLUTION_LIMIT = 0.2
#: Refuse when the scheme amplifies the unforced motion by more than this per step (``max |R(dt mu)|``).
GROWTH_LIMIT = 1.05
#: ``dt lambda_max`` targeted by automatic gains with a split (stiff-safe) scheme: the
#: feedback substep damps the stiffest mode by ``1/(1 + 10)`` per step.
SPLIT_RATE = _stiff.LinearlyImplicitSplit.optimal_rate
#: Fraction of a run's right-hand-side evaluations the pre-run pilot may spend (and its cap).
PILOT_FRACTION = 0.05
PILOT_MAX_EVALS = 6000
PILOT_MIN_EVALS = 60
#: In a run past the limit, a drift (relative to the invariant's scale) above this is an explosion.
GUARD_DRIFT = 1e-2


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


def positive_number(x, name, what="must be a positive finite number"):
    """``float(x)`` if it is a positive finite number, else a ``ValueError`` naming ``name``."""
    if isinstance(x, (bool, np.bool_)):
        raise ValueError(f"{name}: {what}, got {x!r}")
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {what}, got {x!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name}: {what}, got {x!r}")
    return v


def _positive_int(x, name):
    if isinstance(x, (bool, np.bool_)):
        raise ValueError(f"{name}: expected a positive integer, got {x!r}")
    try:
        v = int(x)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: expected a positive integer, got {x!r}") from None
    if v < 1 or v != x:
        raise ValueError(f"{name}: expected a positive integer, got {x!r}")
    return v


def _fmt_gains(gains):
    vals = list(gains.values())
    if vals and all(v == vals[0] for v in vals):
        return f"all {vals[0]:.4g}"
    return ", ".join(f"{k}={v:.4g}" for k, v in gains.items())


def _scaled(gains, factor):
    return {k: float(v) * float(factor) for k, v in gains.items()}


# --------------------------------------------------------------------------------
# schemes
# --------------------------------------------------------------------------------


def resolve_scheme(scheme):
    """``(scheme, beta)``: the registry's scheme and its real stability bound (``inf`` when stiff-safe)."""
    if isinstance(scheme, _stiff.BoundSplitStep):
        scheme = scheme.scheme
    sch = _registry.get(scheme)
    return sch, float(getattr(sch, "real_stability_bound", math.inf))


def _R(sch, z):
    return sch.stability_function(z)


def real_stability_bound(scheme):
    """The scheme's real stability bound ``beta`` (:attr:`liefi.schemes.rk.ExplicitRungeKutta.real_stability_bound`)."""
    return resolve_scheme(scheme)[1]


def optimal_rate(scheme):
    """The ``dt lambda_max`` automatic gains aim at: the scheme's ``optimal_rate``.

    Euler ``x* = 1`` (Bae & Chang's optimal gain ``1/(dt L)``), Heun 1, RK4
    ~1.6; split schemes :data:`SPLIT_RATE`.
    """
    sch, _ = resolve_scheme(scheme)
    r = getattr(sch, "optimal_rate", math.nan)
    return SPLIT_RATE if not (isinstance(r, float) and math.isfinite(r)) else float(r)


# --------------------------------------------------------------------------------
# the stiffness: largest eigenvalue of A Hess V
# --------------------------------------------------------------------------------


def _penalty_lam(fi, y):
    """Largest eigenvalue of ``k0 Hess P`` at ``y`` (``(...)``), 0 without a penalty."""
    y = np.asarray(y, float)
    if not fi.use_penalty or fi.gains.get("penalty", 0.0) == 0.0:
        return np.zeros(y.shape[:-1])
    H = _stiff.penalty_hessian(fi.system.space.group, y[..., : fi.nc])
    H = 0.5 * (H + np.swapaxes(H, -1, -2))
    return fi.gains["penalty"] * np.linalg.eigvalsh(H)[..., -1]


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
        W = jet.grad * np.sqrt(jet.gains)[:, None]
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


def pilot(fi, y0, t_final, *, max_evals=2000, rtol=1e-6):
    """A cheap preview of the run: the extended field ``X`` (no feedback) by adaptive RK45.

    Returns ``(t, Y)`` with ``Y`` of shape ``(N,) + y0.shape``: the accepted
    steps plus three dense-output points inside each, until ``t_final`` or the
    budget of ``max_evals`` evaluations of ``X`` (so ``t[-1]`` says how far it got).
    ``X`` keeps every invariant, so the feedback run stays near this trajectory.
    """
    from scipy.integrate import RK45

    y0 = np.asarray(y0, dtype=float)
    shape = y0.shape
    X = fi.unforced_vector_field

    def fun(_t, y):
        return np.asarray(X(y.reshape(shape)), float).reshape(-1)

    ts, Ys = [0.0], [y0]
    scale = max(1.0, float(np.max(np.abs(y0), initial=0.0)))
    with np.errstate(all="ignore"):
        try:
            solver = RK45(fun, 0.0, y0.reshape(-1), float(t_final), rtol=rtol, atol=1e-9 * scale)
        except Exception:  # noqa: BLE001 -- a pilot that cannot start leaves the estimate at y0
            return np.array(ts), np.stack(Ys)
        while solver.status == "running" and solver.nfev < max_evals:
            t_prev = solver.t
            try:
                solver.step()
            except Exception:  # noqa: BLE001
                break
            if solver.status == "failed" or not np.all(np.isfinite(solver.y)):
                break
            try:
                dense = solver.dense_output()
                for s in (0.25, 0.5, 0.75):
                    tt = t_prev + s * (solver.t - t_prev)
                    ts.append(tt)
                    Ys.append(np.asarray(dense(tt)).reshape(shape))
            except Exception:  # noqa: BLE001
                pass
            ts.append(solver.t)
            Ys.append(solver.y.reshape(shape))
    return np.array(ts), np.stack(Ys)


def dynamics_eigenvalues(fi, y):
    """Eigenvalues of ``dX/dy`` (the unforced field) at the states ``y`` by central differences (flat array)."""
    y = np.asarray(y, dtype=float)
    n = y.shape[-1]
    h = 1e-6 * np.maximum(1.0, np.abs(y))
    E = np.eye(n)
    pts = np.concatenate([y[..., None, :] + h[..., None, :] * E, y[..., None, :] - h[..., None, :] * E], -2)
    with np.errstate(all="ignore"):
        F = fi.unforced_vector_field(pts)
        Jt = (F[..., :n, :] - F[..., n:, :]) / (2 * h[..., :, None])  # rows: d f / d y_k
        ev = np.linalg.eigvals(np.swapaxes(Jt, -1, -2))
    return ev.ravel()


def dynamics_rate(fi, y):
    """Spectral radius of ``dX/dy`` (the unforced field) at ``y`` (max over a batch)."""
    ev = dynamics_eigenvalues(fi, y)
    return float(np.max(np.abs(ev), initial=0.0))


def dynamics_growth(scheme, dt, eigenvalues):
    """``max |R(dt mu)|`` over the eigenvalues ``mu`` of ``dX/dy``: the unforced dynamics' growth per step.

    ``R`` is the stability function of the scheme's explicit tableau (for a split
    scheme, the tableau that steps ``X``).  Above 1 the scheme amplifies the
    motion itself -- e.g. Euler on a rotation, ``|1 + i dt omega|`` -- which no
    feedback on the invariants can repair when it is large.
    """
    sch, _ = resolve_scheme(scheme)
    tab = sch.explicit if isinstance(sch, _stiff.LinearlyImplicitSplit) else sch
    mu = np.asarray(eigenvalues).ravel()
    mu = mu[np.isfinite(mu)]
    if mu.size == 0 or not isinstance(tab, ExplicitRungeKutta):
        return math.nan
    return float(np.max(np.abs(_R(tab, dt * mu))))


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
    #: ``max |R(dt mu)|`` over the eigenvalues of ``dX/dy`` (:func:`dynamics_growth`)
    growth: float = float("nan")
    #: a few states of the pilot (start included), shape ``(k,) + y0.shape``
    samples: np.ndarray = field(repr=False, default=None)

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
        """``dt`` times the fastest rate of ``X`` exceeds :data:`RESOLUTION_LIMIT` (a warning)."""
        return math.isfinite(self.rate) and self.rate > RESOLUTION_LIMIT

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

    def resolution_message(self):
        s = (
            f"dt times the fastest rate of the unforced dynamics is {self.rate:.3g} (> {RESOLUTION_LIMIT:g}): "
            f"the step under-resolves the motion itself, whatever the gains, so the trajectory will be "
            f"inaccurate; take dt below {self.dt * RESOLUTION_LIMIT / self.rate:.3g}."
        )
        if self.unresolvable:
            s += (f" {self.scheme} amplifies that motion by |R(dt mu)| = {self.growth:.3g} per step: the run "
                  "cannot be meaningful.")
        return s


def _max_evals(n_steps, stages):
    return int(min(PILOT_MAX_EVALS, max(PILOT_MIN_EVALS, PILOT_FRACTION * n_steps * stages)))


def estimate(fi, dt, scheme="euler", *, t_final=None, y0=None, max_evals=None, resolution=True) -> StabilityEstimate:
    """Estimate the stability limit of ``fi.run(dt, t_final, scheme)`` before running it.

    ``lambda_max`` is evaluated at ``y0`` and along :func:`pilot` (up to
    ``t_final``, within ``max_evals`` evaluations of ``X``; default a few
    percent of the run's work).  ``t_final=None``: at ``y0`` only.
    """
    sch, beta = resolve_scheme(scheme)
    y0 = fi.y0 if y0 is None else np.asarray(y0, float)
    if t_final is not None and max_evals is None:
        max_evals = _max_evals(t_final / dt, getattr(sch, "stages", 1))
    if t_final is not None and math.isfinite(beta):
        ts, Ys = pilot(fi, y0, t_final, max_evals=max_evals)
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
    ev = np.asarray(st.eigenvalues).reshape((len(ts), -1) + st.eigenvalues.shape[-1:])[i]
    ev = ev[int(np.argmax(lam_t[i]))]
    rate = growth = float("nan")
    if resolution:
        try:  # at the start and at a few points of the pilot
            pick = np.unique(np.linspace(0, len(ts) - 1, min(len(ts), 6)).astype(int))
            evX = dynamics_eigenvalues(fi, Ys[pick])
            rate = dt * float(np.max(np.abs(evX), initial=0.0))
            growth = dynamics_growth(sch, dt, evX)
        except Exception:  # noqa: BLE001 -- a diagnostic only
            rate = growth = float("nan")
    over = np.nonzero(dt * per_t > beta * (1 + LIMIT_BAND))[0] if math.isfinite(beta) else []
    t_cross = float(ts[over[0]]) if len(over) else float("nan")
    return StabilityEstimate(
        getattr(sch, "name", str(scheme)), beta, float(dt), lam, lam0, float(ts[i]), float(ts[-1]),
        float(t_final if t_final is not None else 0.0), dict(fi.gains), dom, ev, rate, t_cross, growth,
        Ys[np.unique(np.linspace(0, len(ts) - 1, min(len(ts), 8)).astype(int))],
    )


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


# --------------------------------------------------------------------------------
# automatic gains
# --------------------------------------------------------------------------------


def unit_rate_gains(fi, y=None):
    """Gains with ``lambda_max(Hess V)(y) = 1``, every invariant weighted by ``1/|grad I_j(y)|^2``.

    The Jacobi scaling of the Gram matrix: each invariant alone would relax at
    the same rate; the common factor makes the largest eigenvalue 1 (max over a
    batch).  The penalty (Hessian eigenvalue 2 on the group) gets weight 1/2.
    A vanishing gradient gets the weight of the largest one.
    """
    y = fi.y0 if y is None else np.asarray(y, float)
    jet = fi.invariant_gradients(y)
    n2 = np.einsum("...mn,...mn->...m", jet.grad, jet.grad).reshape(-1, len(jet.names)).max(axis=0) if jet.names else np.zeros(0)
    top = float(np.max(n2, initial=0.0))
    floor = max(top * 1e-12, 1e-300)
    w = {nm: 1.0 / max(float(v), floor) if top > 0 else 1.0 for nm, v in zip(jet.names, n2)}
    if fi.use_penalty:
        w["penalty"] = 0.5
    trial = fi.with_gains({k: w.get(k, 1.0) for k in fi.invariant_names})
    lam = float(np.max(stiffness(trial, y).lam, initial=0.0))
    if not (lam > 0 and math.isfinite(lam)):
        return dict(trial.gains)
    return _scaled(trial.gains, 1.0 / lam)


def auto_gains(fi, dt, scheme="euler", *, y=None, t_final=None):
    """Fixed gains for ``dt`` and ``scheme``: :func:`unit_rate_gains` scaled to ``dt lambda_max = x*``.

    ``x*`` is :func:`optimal_rate` (1 for Euler: Bae & Chang's ``k = 1/(dt L)``).
    With ``t_final`` the largest ``lambda_max`` along a pilot up to ``t_final``
    is used, so the gains are safe over the whole run (without adapting).
    """
    dt = positive_number(dt, "dt")
    unit = fi.with_gains(unit_rate_gains(fi, y))
    lam = 1.0
    if t_final is not None:
        lam = max(estimate(unit, dt, scheme, t_final=t_final, y0=y, resolution=False).lam, 1e-300)
    return _scaled(unit.gains, optimal_rate(scheme) / (dt * lam))


# --------------------------------------------------------------------------------
# the guarded run
# --------------------------------------------------------------------------------


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
        H = _stiff.penalty_hessian(fi.system.space.group, Y[..., : fi.nc])
        lam = np.maximum(lam, k0 * np.linalg.eigvalsh(0.5 * (H + np.swapaxes(H, -1, -2)))[..., -1])
    return lam.reshape(len(gains_list), -1).max(axis=1), jet


def _guard_verdict(ratio_seen_beyond, rel, delta0):
    """``"error"`` (past the limit and drifted), ``"warn"`` (a large drift within the limit) or ``None``."""
    if ratio_seen_beyond and rel > max(GUARD_DRIFT, 10 * delta0):
        return "error"
    if not (rel <= max(0.1, 2 * delta0)):
        return "warn"
    return None


def _audit(fi, ts, Ys, dt, beta, sch, scales, delta0, schedule, max_points=2000):
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
        res = np.abs(jet.residual).reshape(len(idx), -1, len(jet.names)).max(axis=1)
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
            raise StabilityError(
                f"the run became meaningless at t ~ {t_bad:g}: the drift of {nm} reached {float(rel[i]):.3g} x "
                f"its scale after dt*lambda_max exceeded the stability bound {beta:.4g} of {sch.name} (at t ~ "
                f"{t_over:g}; largest dt*lambda_max seen {float(np.max(ratio)) * beta:.4g}, largest safe dt there "
                f"{dt / float(np.max(ratio)):.4g}): reduce dt or the gains, or use gains='auto', adaptive=True "
                "or scheme='imex-euler'. No result is returned.",
                t_bad, int(round(t_bad / dt)), Ys[idx[i]], [nm],
            )
        if v == "warn" and warn is None:
            warn = (float(tt[i]), str(who[i]), float(rel[i]))
    return warn


def first_integral_defect(fi, y, rtol=1e-6):
    """A warning text if a penalized invariant is not conserved by the extended field at ``y``, else ``""``.

    Assumption A1 of the theory: ``grad I_j . X = 0``.  A user invariant that is
    not a first integral (e.g. ``L_z`` once the metric is not isotropic) makes
    the feedback fight the dynamics: the run then drifts whatever the gains.
    """
    try:
        with np.errstate(all="ignore"):
            jet = fi.invariant_gradients(y)
            X = fi.unforced_vector_field(y)
            dI = np.einsum("...mn,...n->...m", jet.grad, X)
            scale = np.linalg.norm(jet.grad, axis=-1) * np.linalg.norm(X, axis=-1)[..., None]
            rel = np.abs(dI) / np.maximum(scale, 1e-300)
            rel = rel.reshape(-1, len(jet.names)).max(axis=0) if jet.names else rel
    except Exception:  # noqa: BLE001 -- a diagnostic only
        return ""
    bad = [(nm, float(r)) for nm, r in zip(jet.names, np.atleast_1d(rel)) if r > rtol]
    if not bad:
        return ""
    what = ", ".join(f"{nm} (relative dI/dt = {r:.2g})" for nm, r in bad)
    return (f"liefi: invariants: {what} not conserved by the extended field (at the start or along the "
            "pilot): V is not a first "
            "integral (assumption A1), so the feedback fights the dynamics and the run drifts whatever the "
            "gains; check that the invariant belongs to this system.")


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


def drift_scales(fi, y=None):
    """The scale of each penalized invariant, for relative drifts (``{name: s}``).

    ``J_i``: ``sqrt(2 E C_ii)``, the largest ``|<P, e_i>|`` at kinetic energy
    ``E`` (so ``J_i / s`` is a cosine); energy: ``E = max(|h|, T, |U|)``; a user
    invariant: ``max(|I_0|, sqrt(E))``; the penalty: 1 (for ``||R^T R - I||``).
    """
    y = fi.y0 if y is None else np.asarray(y, float)
    _, z = fi.split(y)
    t = _core.evaluate(fi.system, z)
    n = fi.system.space.n
    U = np.asarray(fi.system.potential(z[..., :n]), float)
    T = np.abs(t.h - U)
    E = float(max(np.max(np.abs(t.h)), np.max(T), np.max(np.abs(U)), 1e-12))
    out = {}
    if fi.use_constraints:
        C = np.asarray(_core.gram_matrix(fi.system, z[..., :n]), float)
        d = np.diagonal(C, axis1=-2, axis2=-1).reshape(-1, fi.system.K).max(axis=0)
        for i in range(fi.system.K):
            out[f"J_{i + 1}"] = math.sqrt(2 * E * max(float(d[i]), 1e-300))
    if fi.use_energy:
        out["energy"] = E
    for u in fi.user:
        out[u.name] = max(float(np.max(np.abs(np.asarray(fi.targets[u.name], float)))), math.sqrt(E), 1e-12)
    if fi.use_penalty:
        out["penalty"] = 1.0
    return out


def drift(fi, y, scales=None, jet=None):
    """``(delta, name)``: the largest relative residual ``|I_j - I_j0| / s_j`` at ``y`` (max over a batch).

    ``s_j`` is the larger of ``scales[name]`` (e.g. :func:`drift_scales` at the
    start) and the scale at ``y`` itself (the kinetic and potential energies
    exchange along a run: a start at rest must not make every later drift huge).
    """
    y = np.asarray(y, float)
    if jet is None:
        jet = fi.invariant_gradients(y)
    with np.errstate(all="ignore"):
        try:
            cur = drift_scales(fi, y)
        except Exception:  # noqa: BLE001 -- non-finite states: the start scales only
            cur = {}
    scales = {k: max(v for v in ((scales or {}).get(k, 0.0), cur.get(k, 0.0)) if np.isfinite(v)) or 1.0
              for k in set(cur) | set(scales or {})}
    best, who = 0.0, ""
    for j, nm in enumerate(jet.names):
        v = float(np.max(np.abs(jet.residual[..., j]), initial=0.0)) / scales.get(nm, 1.0)
        if not v <= best:  # also catches nan
            best, who = v, nm
    if fi.use_penalty:
        P = fi.system.space.group.penalty(y[..., : fi.nc])
        v = float(np.max(2 * np.sqrt(np.maximum(P, 0.0)), initial=0.0))
        if not v <= best:
            best, who = v, "penalty"
    return best, who


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


def _relabel(exc, dt, sch, extra):
    """Rebuild an IntegrationError (absolute ``t``, ``step``) with our advice appended."""
    comps = list(exc.components or [])
    msg = (
        f"integration with {getattr(sch, 'name', sch)} (dt={dt:g}) produced non-finite values at step "
        f"{exc.step} (t={exc.step * dt:g}) in components {comps}; the last finite state is at t={exc.t:g}. {extra}"
    )
    return IntegrationError(msg, exc.t, exc.step, exc.y, comps)


def _segment_runner(fi, sch, dt, backend, names):
    """``run(fi_cur, y, n, s0, save_every, check_every) -> Solution`` on the requested backend.

    Times are absolute; an :class:`~liefi.schemes.IntegrationError` is re-raised
    with the absolute time of the last finite state and the absolute step.
    """
    state = {"backend": backend}
    split = isinstance(sch, _stiff.LinearlyImplicitSplit)
    if backend not in ("numpy", "numba", "auto"):
        raise ValueError(f"backend: expected 'numpy', 'numba' or 'auto', got {backend!r}")
    if split and backend == "numba":
        raise ValueError(f"backend: the split scheme {sch.name!r} runs on numpy only; pass backend='numpy'")
    if split:
        state["backend"] = backend = "numpy"  # "auto": the split schemes have no compiled path

    def run(fi_cur, y, n, s0, save_every, check_every):
        t0 = s0 * dt
        if state["backend"] != "numpy":
            from .compiled import run_feedback

            try:
                sol = run_feedback(fi_cur, dt, n, sch, y, save_every, check_every, state["backend"])
            except IntegrationError as exc:  # times relative to the segment
                raise IntegrationError(str(exc), t0 + exc.t, s0 + exc.step, exc.y, exc.components) from None
            if sol is not None:
                sol.t = sol.t + t0
                return sol
            state["backend"] = "numpy"
        stepper = sch.bind(fi_cur) if split else sch
        try:
            return integrate(fi_cur.vector_field, y, dt, n, stepper, t0=t0, save_every=save_every,
                             names=names, check_every=check_every)
        except IntegrationError as exc:  # t absolute, step relative
            raise IntegrationError(str(exc), exc.t, s0 + exc.step, exc.y, exc.components) from None

    return run


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


def guarded_run(fi, dt, n_steps, scheme="euler", *, y0=None, save_every=1, check_every=1, backend="numpy",
                check_stability=True, adaptive=None, monitor_every=None, guard=None, stacklevel=3) -> Solution:
    """Run ``fi`` for ``n_steps`` steps of ``dt`` with the stability machinery (module docstring).

    Called by :meth:`liefi.FeedbackIntegrator.run`; the parameters are those
    of that method.  ``guard`` (default ``check_stability``): stop with
    :class:`StabilityError` when a run past the limit drifts away.  Returns the
    :class:`~liefi.schemes.Solution` with ``solution.stability`` a :class:`RunReport`.
    """
    dt = positive_number(dt, "dt", "the step must be a positive finite number")
    n_steps = _positive_int(n_steps, "n_steps")
    save_every = _positive_int(save_every, "save_every")
    check_every = _positive_int(check_every, "check_every")
    if monitor_every is not None:
        monitor_every = _positive_int(monitor_every, "monitor_every")
    if y0 is None:
        y0 = fi.y0
    else:
        y0 = np.asarray(y0, dtype=float) if not isinstance(y0, str) else y0
        if not isinstance(y0, np.ndarray) or y0.shape[-1:] != (fi.n,):
            raise ValueError(f"y0: expected a state of {fi.n} numbers {fi.names}, got {np.shape(y0)}")
        if not np.all(np.isfinite(y0)):
            raise ValueError("y0: contains non-finite numbers")
    sch, beta = resolve_scheme(scheme)
    split = isinstance(sch, _stiff.LinearlyImplicitSplit)
    names = fi.names
    runner = _segment_runner(fi, sch, dt, backend, names)
    auto = getattr(fi, "gains_mode", "fixed") == "auto"
    adaptive = auto if adaptive is None else bool(adaptive)
    guard = bool(check_stability) if guard is None else bool(guard)
    rate = optimal_rate(sch)
    T = n_steps * dt
    rep = RunReport(adaptive=adaptive)

    # --- the gains at the start ------------------------------------------------------
    base = fi  # gains the adaptive rule starts from (user's, or unit-rate for auto)
    if auto and adaptive:
        run_fi = fi.with_gains(_scaled(unit_rate_gains(fi, y0), rate / dt))
    elif auto:
        run_fi = fi.with_gains(auto_gains(fi, dt, sch, y=y0, t_final=T))
    elif adaptive:
        lam = float(np.max(stiffness(fi, y0).lam, initial=0.0))
        s = min(1.0, rate / (dt * lam)) if lam > 0 and not split else 1.0
        run_fi = fi.with_gains(_scaled(fi.gains, s))
    else:
        run_fi = fi
    rep.gains = dict(run_fi.gains)

    # --- before the run -----------------------------------------------------------------
    if check_stability:
        if not adaptive and not split:
            budget = _max_evals(n_steps, sch.stages)
            if backend != "numpy":  # the compiled run itself is cheap: keep the numpy pilot short
                budget = min(budget, 2000)
            rep.estimate = check(run_fi, dt, sch, t_final=T, y0=y0, max_evals=budget, stacklevel=stacklevel + 1)
            rep.resolution = rep.estimate.rate
            if rep.estimate.verdict in ("limit", "beyond"):
                rep.warnings.append(rep.estimate.message())
        else:
            # the gains adapt (or the scheme is stiff-safe): only the resolution of the unforced
            # dynamics, at the start and along the pilot, can make the run meaningless
            est = estimate(run_fi, dt, sch.explicit if split else sch, t_final=T, y0=y0)
            rep.resolution = est.rate
            if est.unresolvable:
                raise ValueError("dt: " + est.resolution_message() + " Pass check_stability=False to run it anyway.")
            if est.under_resolved:
                warnings.warn("liefi: " + est.resolution_message(), LiefiStabilityWarning, stacklevel=stacklevel + 1)
            rep.estimate = rep.estimate or est
        samples = rep.estimate.samples if rep.estimate is not None and rep.estimate.samples is not None else y0
        msg = first_integral_defect(run_fi, samples)
        if msg:
            rep.warnings.append(msg)
            warnings.warn(msg, LiefiStabilityWarning, stacklevel=stacklevel + 1)

    start_cpu = time.process_time()
    if not (check_stability or adaptive or guard):
        try:
            sol = runner(run_fi, y0, n_steps, 0, save_every, check_every)
        except IntegrationError as exc:
            raise _relabel(exc, dt, sch, _advice(run_fi, exc.y, exc.t, dt, sch, beta, (y0, 0.0))) from None
        sol.stability = rep
        return sol

    # --- in segments, watching between them -------------------------------------------
    # The segment length N is deterministic (results never depend on timing):
    # fixed runs check every 200 steps (numpy) or n/200 (compiled); adaptive
    # runs halve N when dt*lambda_max moved by more than 5 % over a segment and
    # double it below 2 %, within [10, N_cap], N_cap ~ half a time unit of the
    # unforced dynamics.
    scales = drift_scales(fi)
    delta0, _ = drift(fi, y0, scales)
    fixed_N = monitor_every is not None
    if fixed_N:
        N = monitor_every
    elif adaptive:
        N = 100
    else:
        N = 200 if backend == "numpy" else max(2000, n_steps // 200)
    if adaptive and not fixed_N:
        r = rep.resolution / dt if math.isfinite(rep.resolution) else 1.0
        N_cap = int(min(50000, max(10, 0.5 / (dt * max(r, 1e-2)))))
    N = max(1, min(N, n_steps))
    y = y0
    s0 = 0
    ts, Ys = [0.0], [np.asarray(y0, float)]
    rhs = 0
    beyond_at = None
    warned_in_run = False
    drift_warned = False
    ratio_set = None
    last_sol = None
    sched_t, sched_g = [0.0], [dict(run_fi.gains)]
    while s0 < n_steps:
        L, sub = _chunk(s0, n_steps, N, save_every)
        try:
            seg = runner(run_fi, y, L, s0, sub, check_every)
        except IntegrationError as exc:
            raise _relabel(exc, dt, sch, _advice(run_fi, exc.y, exc.t, dt, sch, beta, (y, s0 * dt))) from None
        last_sol = seg
        rhs += seg.rhs_evaluations
        gidx = s0 + np.round((seg.t - s0 * dt) / dt).astype(int)
        for j in range(1, len(seg.t)):
            if gidx[j] % save_every == 0 or gidx[j] == n_steps:
                ts.append(dt * float(gidx[j]))  # as integrate() computes it: t0 + dt * index
                Ys.append(seg.y[..., j])
        y = seg.y[..., -1]
        s0 += L
        if s0 >= n_steps:
            break
        # --- check ---
        rep.monitors += 1
        t_now = s0 * dt
        with np.errstate(all="ignore"):
            jet = run_fi.invariant_gradients(y)
            lam = float(np.max(stiffness(run_fi, y).lam, initial=0.0))
        ratio = dt * lam / beta if math.isfinite(beta) else 0.0
        rep.max_ratio = max(rep.max_ratio, ratio)
        if ratio > 1 + LIMIT_BAND and beyond_at is None:
            beyond_at = t_now
        if guard:
            delta, who = drift(run_fi, y, scales, jet)
            verdict = _guard_verdict(beyond_at is not None, delta, delta0)
            if verdict == "error":
                why = (
                    f"after dt*lambda_max exceeded the stability bound {beta:.4g} of {sch.name} at "
                    f"t = {beyond_at:g} (now {dt * lam:.4g}; largest safe dt {beta / lam:.4g}, or every "
                    f"gain x {beta / (dt * lam):.3g}; or gains='auto', adaptive=True, scheme='imex-euler')"
                )
                if math.isfinite(rep.resolution) and rep.resolution > RESOLUTION_LIMIT:
                    why += (f"; note that dt also under-resolves the unforced dynamics (dt times its fastest "
                            f"rate = {rep.resolution:.3g}): reduce dt first")
                raise StabilityError(
                    f"the run became meaningless at t = {t_now:g}: the drift of {who} reached {delta:.3g} x its "
                    f"scale {why}. No result is returned.",
                    t_now, s0, y, [who],
                )
            if verdict == "warn" and not drift_warned:
                drift_warned = True
                msg = _drift_warning(t_now, who, delta, dt, rep.resolution)
                rep.warnings.append(msg)
                warnings.warn(msg, LiefiStabilityWarning, stacklevel=stacklevel + 1)
        if adaptive:
            if auto:
                new = _scaled(unit_rate_gains(base, y), rate / dt)
            else:
                lam_b = float(np.max(stiffness(base, y).lam, initial=0.0))
                s_ = min(1.0, rate / (dt * lam_b)) if lam_b > 0 and not split else 1.0
                new = _scaled(base.gains, s_)
            if not fixed_N and ratio_set is not None:
                if ratio > ratio_set * 1.05 or ratio < ratio_set / 1.05:
                    N = max(10, N // 2)
                elif ratio_set / 1.02 <= ratio <= ratio_set * 1.02:
                    N = min(2 * N, N_cap)
            run_fi = run_fi.with_gains(new)
            ratio_set = dt * float(np.max(stiffness(run_fi, y).lam, initial=0.0)) / beta if math.isfinite(beta) else 0.0
            rep.gain_times.append(t_now)
            rep.gain_history.append(dict(new))
            sched_t.append(t_now)
            sched_g.append(dict(new))
        elif ratio > 1 + LIMIT_BAND and not warned_in_run and (rep.estimate is None or rep.estimate.verdict == "ok"):
            warned_in_run = True
            msg = (
                f"liefi: at t = {t_now:g} dt*lambda_max = {dt * lam:.4g} exceeds the stability bound "
                f"{beta:.4g} of {sch.name} (the stiffness grew along the run). Largest safe dt there: "
                f"{beta / lam:.4g} (or every gain x {beta / (dt * lam):.3g}); use gains='auto' or "
                "adaptive=True to follow it, or scheme='imex-euler'."
            )
            rep.warnings.append(msg)
            warnings.warn(msg, LiefiStabilityWarning, stacklevel=stacklevel + 1)
    if guard:
        w = _audit(fi, np.array(ts), Ys, dt, beta, sch, scales, delta0, (sched_t, sched_g))
        if w is not None and not drift_warned:
            msg = _drift_warning(w[0], w[1], w[2], dt, rep.resolution)
            rep.warnings.append(msg)
            warnings.warn(msg, LiefiStabilityWarning, stacklevel=stacklevel + 1)
    cpu = time.process_time() - start_cpu
    out = np.stack(Ys, -1)
    sol = Solution(np.array(ts), out, sch.name, dt, n_steps, rhs, cpu, tuple(names))
    for attr in ("backend", "wall_seconds"):
        if last_sol is not None and hasattr(last_sol, attr):
            setattr(sol, attr, getattr(last_sol, attr))
    sol.stability = rep
    return sol


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
    from .feedback import FeedbackIntegrator
    from .scenes import base as _base

    if isinstance(target, str):
        from . import scenes as _scenes

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
            sol = guarded_run(fi, dt, n, scheme, save_every=max(1, n // 2000), backend=backend,
                              check_stability=False, adaptive=False, guard=False)
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
        from . import scenes as _scenes

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
        from .scenes import base as _base

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
    bounds = list(mapper(_boundary_task, tasks))
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
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return ax


# --------------------------------------------------------------------------------
# the extreme-case battery
# --------------------------------------------------------------------------------


@dataclass
class BatteryResult:
    """One case of :func:`run_battery`.

    ``outcome``: ``"ok"``, ``"ok (warned)"``, ``"refused"`` (a ``ValueError``
    before the run), ``"stopped"`` (:class:`StabilityError` or
    :class:`~liefi.schemes.IntegrationError` at the moment it failed, with
    ``t_fail``), or the failures the battery exists to catch: ``"SILENT DRIFT"``
    (a result returned with drift above 1 % of scale and no warning) and
    ``"CRASH"`` (any other exception).  Drifts are ``max_t |I(t) - I_0|`` over
    the constraint momenta (``drift_J``), the penalized energy (``drift_E``) and
    the other invariants (``drift_other``), against the targets (for a start off
    the invariant set: over the second half of the run); ``error`` is the max
    error against the exact solution where the scene has one.
    """

    scene: str
    case: str
    outcome: str
    drift_J: float = math.nan
    drift_E: float = math.nan
    drift_other: float = math.nan
    rel_drift: float = math.nan
    error: float = math.nan
    cpu: float = math.nan
    t_fail: float = math.nan
    note: str = ""

    def row(self):
        def f(x):
            return "-" if not isinstance(x, float) or not math.isfinite(x) else f"{x:.2g}"

        note = self.note.replace("|", "/")
        if len(note) > 160:
            note = note[:157] + "..."
        return (f"| {self.scene} | {self.case} | {self.outcome} | {f(self.drift_J)} | {f(self.drift_E)} | "
                f"{f(self.drift_other)} | {f(self.error)} | {f(self.cpu)} | {note} |")


BATTERY_HEADER = (
    "| scene | case | outcome | drift J | drift energy | drift other | error | cpu s | note |\n"
    "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
)

#: The cases of :func:`run_battery` (scene-specific ones are added for ``roller-racer`` and ``heisenberg``).
BATTERY_CASES = (
    "paper", "k=1e-2", "k=1", "k=1e2", "k=1e4", "k=1e6", "k=1e6 imex-euler", "auto",
    "horizon 1e4 auto", "mass ratio 1e6", "mass ratio 1e6 auto", "momenta x1e3", "momenta x1e3 auto",
    "off-set 0.1", "off-set 1", "dt at limit", "dt 1.1x limit",
)
#: The variant the battery runs (default: the scene's first).
BATTERY_VARIANTS = {"heisenberg": "generic"}
SCENE_CASES = {
    "roller-racer": ("near-singular", "near-singular auto"),
    "heisenberg": ("far from origin", "far from origin auto"),
}


def battery_table(results):
    """The markdown table of a list of :class:`BatteryResult`."""
    return BATTERY_HEADER + "\n" + "\n".join(r.row() for r in results)


def _with_mass_ratio(sc, ratio):
    """A copy of scene ``sc`` whose metric is ``S m S``, ``S = diag(sqrt(logspace(0, log10 ratio, D)))``.

    The constraint set, the potential and the start are unchanged; the mass
    (inertia) ratio spans ``ratio``.  The copy has no reference solution.
    """
    import copy

    from .system import NonholonomicSystem

    sys = sc.system
    D = sys.space.D
    S = np.diag(np.sqrt(np.logspace(0.0, math.log10(ratio), D)))
    m = sys.metric
    metric = S @ m.value @ S if m.constant else (lambda x, f=m.fun: S @ f(x) @ S)
    cons = None
    if sys.K:
        cons = sys.constraints.value if sys.constraints.constant else sys.constraints.fun
    pot = None
    if not sys.potential.constant:
        pot = sys.potential.fun
    elif float(sys.potential.value) != 0.0:
        pot = lambda x, c=float(sys.potential.value): c + 0.0 * x[..., 0]  # noqa: E731
    n = sys.space.n
    nc = sys.space.group.config_dim
    v = sc.variant()
    x0 = np.asarray(sc.initial_state(v), float)[nc : nc + n]
    new = NonholonomicSystem(sys.space, metric, cons, pot, sample=x0 if n else None)
    sc2 = copy.copy(sc)
    sc2.__dict__ = dict(sc.__dict__)
    sc2.__dict__["system"] = new
    sc2.__dict__.pop("_refcache", None)
    return sc2


def _battery_case(task):
    """Run one ``(scene name, case, quick, backend)``; never raises (module level for process pools)."""
    name, case, quick, backend = task
    from . import scenes as _scenes

    try:
        sc = _scenes.get(name)
        return _battery_run_case(sc, case, quick, backend)
    except Exception as exc:  # noqa: BLE001 -- the battery reports, it does not stop
        return BatteryResult(name, case, "CRASH", note=f"{type(exc).__name__}: {exc}")


def _battery_run_case(sc, case, quick, backend):
    from .feedback import FeedbackIntegrator  # noqa: F401
    from .scenes.base import Variant

    v = sc.variant(BATTERY_VARIANTS.get(sc.name))
    T = min(float(sc.t_final), 2.0 if quick else 10.0)
    dt = float(sc.dt)
    scheme = sc.scheme
    gains = None
    y_start = None
    off = None
    scene = sc
    has_ref = sc.reference == "exact"
    if case == "paper":
        pass
    elif case.startswith("k=") and case.endswith("imex-euler"):
        gains, scheme = float(case[2:].split()[0]), "imex-euler"
    elif case.startswith("k="):
        gains = float(case[2:])
    elif case == "auto":
        gains = "auto"
    elif case == "horizon 1e4 auto":
        gains, T = "auto", (100.0 if quick else 1e4)
    elif case.startswith("mass ratio"):
        scene = _with_mass_ratio(sc, 1e6)
        has_ref = False
        gains = "auto" if case.endswith("auto") else None
    elif case.startswith("momenta x1e3"):
        full = np.array(sc.initial_state(v), float)
        nc = sc.system.space.group.config_dim
        full[nc + sc.system.space.n :] *= 1e3
        y_start = full
        has_ref = False
        gains = "auto" if case.endswith("auto") else None
    elif case.startswith("off-set"):
        off = float(case.split()[1])
    elif case.startswith("near-singular"):
        import copy

        scene = copy.copy(sc)
        scene.__dict__ = {}
        scene.phi0 = math.acos(-sc.d2 / sc.d1) + 1e-6  # d1 cos(phi) + d2 = 0: e_1^flat loses its Pi_theta part
        has_ref = False
        gains = "auto" if case.endswith("auto") else None
    elif case.startswith("far from origin"):
        q0 = np.array([1e3, 5e2, 0.0])
        p0 = np.array([0.3, 0.4, 0.0])
        p0[2] = q0[1] * p0[0] - q0[0] * p0[1]  # on the constraint set p_z = y p_x - x p_y
        g = sc.variant("generic")
        v = Variant("far", "q0 = (1e3, 5e2, 0)", energy=g.energy, field=g.field,
                    options={**g.options, "q0": tuple(q0), "p0": tuple(p0)})
        has_ref = True
        gains = "auto" if case.endswith("auto") else None
    elif case.startswith("dt"):
        pass
    else:
        raise ValueError(f"case: unknown battery case {case!r}")

    fi = scene.integrator(v, gains=gains, y0=y_start)
    if case.startswith("dt"):
        est = estimate(fi, dt, scheme, t_final=T, resolution=False)
        dt = est.dt_safe * (1.1 if "1.1x" in case else 1.0)
    if off is not None:
        jet = fi.invariant_gradients(fi.y0)
        rng = np.random.default_rng(0)
        u = np.einsum("m,mn->n", rng.normal(size=len(jet.names)), jet.grad)
        u = u / np.linalg.norm(u)
        y_start = fi.y0 + off * u
    n = max(1, int(round(T / dt)))
    T = n * dt
    bk = "numpy" if _stiff.is_split_scheme(scheme) else backend
    caught = []
    t0 = time.process_time()
    try:
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always", LiefiStabilityWarning)
            sol = fi.run(dt, T, scheme, y0=y_start if off is not None else None,
                         save_every=max(1, n // 4000), backend=bk)
            caught = [str(x.message) for x in w if issubclass(x.category, LiefiStabilityWarning)]
    except StabilityError as exc:
        return BatteryResult(sc.name, case, "stopped", cpu=time.process_time() - t0, t_fail=exc.t,
                             note=f"StabilityError at t={exc.t:.4g}: {exc}")
    except IntegrationError as exc:
        return BatteryResult(sc.name, case, "stopped", cpu=time.process_time() - t0, t_fail=exc.t,
                             note=f"IntegrationError at t={exc.t:.4g}: {exc}")
    except ValueError as exc:
        return BatteryResult(sc.name, case, "refused", cpu=time.process_time() - t0, note=f"ValueError: {exc}")
    cpu = time.process_time() - t0
    Y = np.moveaxis(sol.y, -1, 0)
    t = sol.t
    keep = t >= (0.5 * T if off is not None else -1.0)
    with np.errstate(all="ignore"):
        jet = fi.invariant_gradients(Y)
        res = np.abs(jet.residual)
        scales = drift_scales(fi)
        cur = drift_scales(fi, Y[keep])
        scales = {k: max(scales.get(k, 0.0), cur.get(k, 0.0)) or 1.0 for k in cur}
        dJ = [j for j, nm in enumerate(jet.names) if nm.startswith("J_")]
        dE = [j for j, nm in enumerate(jet.names) if nm == "energy"]
        dO = [j for j, nm in enumerate(jet.names) if not nm.startswith("J_") and nm != "energy"]

        def mx(idx):
            return float(np.max(res[keep][..., idx])) if idx else math.nan

        rel = max(
            (float(np.max(res[keep][..., j])) / scales.get(nm, 1.0) for j, nm in enumerate(jet.names)), default=0.0
        )
        other = mx(dO)
        if fi.use_penalty:
            P = fi.system.space.group.penalty(Y[keep][..., : fi.nc])
            orth = float(np.max(2 * np.sqrt(np.maximum(P, 0))))
            other = orth if not math.isfinite(other) else max(other, orth)
            rel = max(rel, orth)
        err = math.nan
        if has_ref and y_start is None:
            ref = scene.exact(t, v)
            errs = [np.max(np.abs(Y[:, fi.names.index(k)] - ref[k])) for k in scene.error_variables
                    if k in fi.names and k in ref]
            err = float(max(errs)) if errs else math.nan
    notes = []
    returning = None
    if off is not None:
        d_all = np.array([drift(fi, Y[i], scales)[0] for i in range(len(t))])
        d0 = d_all[0]
        back = np.nonzero(d_all <= 1e-3 * d0)[0]
        returning = d_all[-1] <= 0.1 * d0
        notes.append(f"start drift {d0:.3g} x scale, end {d_all[-1]:.3g}; " + (
            f"back to 1e-3 of it by t = {t[back[0]]:.3g}" if back.size else "not back to 1e-3 of it within the run"))
    if isinstance(gains, str) and sol.stability.gain_history:
        g0, g1 = sol.stability.gains, sol.stability.final_gains
        notes.append("auto gains " + _fmt_gains(g0) + (f" -> {_fmt_gains(g1)}" if g1 != g0 else ""))
    if case.startswith("dt"):
        notes.append(f"dt = {dt:.4g}")
    if caught:
        notes.append("warned: " + caught[0][6:])
    outcome = "ok (warned)" if caught else "ok"
    if not (rel <= GUARD_DRIFT):
        if returning:
            outcome = "returning"
        else:
            outcome = "drift (warned)" if caught else "SILENT DRIFT"
    return BatteryResult(sc.name, case, outcome, mx(dJ), mx(dE), other, rel, err, cpu, note="; ".join(notes))


def run_battery(scenes=None, cases=None, *, quick=False, backend="auto", executor=None):
    """Run the extreme cases on every scene; returns a list of :class:`BatteryResult`.

    Cases (:data:`BATTERY_CASES`, plus :data:`SCENE_CASES`): the paper's
    settings; every gain equal to ``1e-2 ... 1e6`` with the scene's scheme and
    step (and ``1e6`` with ``imex-euler``); ``gains="auto"``; a horizon of ``1e4``
    with automatic gains; the metric scaled to a mass/inertia ratio of ``1e6``;
    momenta ``1e3`` times the paper's; starts at distance ``0.1`` and ``1`` off the
    invariant set (along the invariants' gradients; the note says how fast the
    drift returns); the roller racer where ``d1 cos(phi) + d2 = 0`` and the
    Heisenberg system at ``|q| ~ 1e3``; ``dt`` at the estimated limit and 10 %
    past it.  Other runs last ``min(t_final, 10)`` (``quick``: 2, horizon 100).

    ``executor``: any ``concurrent.futures.Executor`` (cases run as
    ``executor.map``); default serial.
    """
    from . import scenes as _scenes

    names = list(_scenes.names() if scenes is None else scenes)
    tasks = []
    for nm in names:
        cs = list(BATTERY_CASES if cases is None else cases)
        if cases is None:
            cs += list(SCENE_CASES.get(nm, ()))
        tasks += [(nm, c, bool(quick), backend) for c in cs]
    mapper = map if executor is None else executor.map
    return list(mapper(_battery_case, tasks))


# --------------------------------------------------------------------------------
# work-precision of the stiff-safe schemes next to the explicit ones
# --------------------------------------------------------------------------------

#: ``(label, scheme, gains)`` compared by :func:`stiff_work_precision`.
WP_METHODS = (
    ("euler, k=1000", "euler", 1000.0),
    ("euler, auto", "euler", "auto"),
    ("heun, auto", "heun", "auto"),
    ("rk4, auto", "rk4", "auto"),
    ("imex-euler, k=1000", "imex-euler", 1000.0),
    ("imex-euler, k=1e6", "imex-euler", 1e6),
    ("imex-rk4, k=1000", "imex-rk4", 1000.0),
    ("imex-rk4, k=1e6", "imex-rk4", 1e6),
)


def stiff_work_precision(scene="knife-edge", *, t_final=5.0, dts=(2e-2, 1e-2, 5e-3, 2e-3, 1e-3),
                         rtols=(1e-4, 1e-6, 1e-8), methods=WP_METHODS, ivp=("Radau", "BDF"), ivp_gains=1000.0):
    """Error, drift and CPU time of explicit, split and implicit (``solve_ivp``) runs of a scene.

    Every run is on the numpy path (the same field evaluation for all), so the
    CPU times compare the schemes, not the backends.  Returns a list of dicts
    (``label``, ``scheme``, ``dt`` or ``rtol``, ``outcome``, ``error``, ``drift``, ``cpu``).
    """
    from . import scenes as _scenes

    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    rows = []
    for label, scheme, gains in methods:
        for dt in dts:
            row = {"label": label, "scheme": scheme, "dt": dt, "rtol": None}
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", LiefiStabilityWarning)
                    r = sc.run(dt=dt, t_final=t_final, scheme=scheme, gains=gains)
                row.update(outcome="ok", error=max(r.max_error.values(), default=math.nan),
                           drift=max(r.max_drift.values(), default=math.nan), cpu=r.cpu_seconds)
            except (ValueError, IntegrationError) as exc:
                row.update(outcome=type(exc).__name__, error=math.nan, drift=math.nan, cpu=math.nan,
                           message=str(exc)[:200])
            rows.append(row)
    for method in ivp:
        for rtol in rtols:
            row = {"label": f"scipy:{method}, k={ivp_gains:g}", "scheme": f"scipy:{method}", "dt": None, "rtol": rtol}
            try:
                r = sc.run(t_final=t_final, scheme=f"scipy:{method}", gains=ivp_gains, rtol=rtol, atol=rtol * 1e-2)
                row.update(outcome="ok", error=max(r.max_error.values(), default=math.nan),
                           drift=max(r.max_drift.values(), default=math.nan), cpu=r.cpu_seconds)
            except Exception as exc:  # noqa: BLE001 -- report, do not stop
                row.update(outcome=type(exc).__name__, error=math.nan, drift=math.nan, cpu=math.nan,
                           message=str(exc)[:200])
            rows.append(row)
    return rows


def plot_work_precision(rows, path=None, title=""):
    """Two panels: max error and max invariant drift against CPU seconds, one line per method."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    labels = list(dict.fromkeys(r["label"] for r in rows))
    for i, lab in enumerate(labels):
        rs = [r for r in rows if r["label"] == lab and r["outcome"] == "ok"]
        if not rs:
            continue
        style = "--" if lab.startswith("imex") else (":" if lab.startswith("scipy") else "-")
        for ax, key in zip(axes, ("error", "drift")):
            ax.loglog([r["cpu"] for r in rs], [max(r[key], 1e-17) for r in rs], style, marker="o", ms=3,
                      label=lab, color=f"C{i % 10}")
    for ax, key in zip(axes, ("max error against the exact solution", "max invariant drift")):
        ax.set_xlabel("CPU seconds")
        ax.set_ylabel(key)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig


# --------------------------------------------------------------------------------
# ``liefi stability SCENE``
# --------------------------------------------------------------------------------


def add_arguments(parser):
    """Add the arguments of ``liefi stability`` to an ``argparse`` (sub)parser."""
    parser.add_argument("scene", help="scene name (see `liefi list`)")
    parser.add_argument("--variant", default=None)
    parser.add_argument("--scheme", default="euler", help="euler, heun, rk4, ... (default euler)")
    parser.add_argument("--gains", default=None, metavar="K1,K2,...",
                        help="the gains k of the sweep, every gain equal to k (default 1, 3.16, ..., 1e4)")
    parser.add_argument("--t-final", type=float, default=None, help="horizon of each run (default min(scene's, 10))")
    parser.add_argument("--tol", type=float, default=0.02, help="relative tolerance of the boundaries in dt")
    parser.add_argument("--accurate", type=float, default=1e-2, help="drift (relative to scale) called accurate")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1: serial)")
    parser.add_argument("--backend", default="auto", choices=("auto", "numpy", "numba"))
    parser.add_argument("--plot", default=None, metavar="PNG", help="write the map to this file")
    parser.add_argument("--estimate", action="store_true",
                        help="only the pre-run estimate at the scene's settings (no sweep)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return parser


def command(args, file=None):
    """Body of ``liefi stability SCENE`` (``args`` from :func:`add_arguments`); returns the exit code.

    Prints the estimate at the scene's settings and, unless ``--estimate``, the
    measured map (a table, or JSON with ``--json``); ``--plot`` writes the figure.
    Errors in the arguments raise ``ValueError`` naming the argument.
    """
    import json
    import sys

    from . import scenes as _scenes

    out = file or sys.stdout
    sc = _scenes.get(args.scene)
    fi = sc.integrator(sc.variant(args.variant))
    T = float(args.t_final) if args.t_final is not None else float(sc.t_final)
    est = estimate(fi, sc.dt, args.scheme, t_final=T)
    result = {"scene": sc.name, "estimate": {
        "scheme": est.scheme, "bound": est.bound, "dt": est.dt, "lambda_max": est.lam, "lambda_0": est.lam0,
        "t_max": est.t_max, "ratio": est.ratio, "verdict": est.verdict, "dt_safe": est.dt_safe,
        "gains": est.gains, "message": est.message()}}
    if not args.estimate:
        gains = None
        if args.gains:
            try:
                gains = [float(x) for x in str(args.gains).split(",")]
            except ValueError:
                raise ValueError(f"gains: expected a comma list of numbers, got {args.gains!r}") from None
        ex = None
        if args.jobs and int(args.jobs) > 1:
            from concurrent.futures import ProcessPoolExecutor

            ex = ProcessPoolExecutor(int(args.jobs))
        try:
            smap = stability_map(sc.name, gains=gains, scheme=args.scheme, variant=args.variant,
                                 t_final=min(T, 10.0) if args.t_final is None else T, tol=args.tol,
                                 accurate=args.accurate, executor=ex, backend=args.backend)
        finally:
            if ex is not None:
                ex.shutdown()
        result["map"] = smap.to_dict()
        if args.plot:
            plot_stability_map(smap, args.plot)
            result["plot"] = args.plot
    if args.json:
        out.write(json.dumps(result, indent=2, default=lambda o: None if o is None else float(o)) + "\n")
        return 0
    out.write(f"{sc.name}: at the scene's settings (dt = {sc.dt:g}, gains {sc.gains}, t in [0, {T:g}]):\n  "
              + est.message() + "\n")
    if not args.estimate:
        out.write(f"\nmeasured map ({smap.scheme}, runs of t in [0, {smap.t_final:g}], boundaries to "
                  f"{100 * smap.tol:g} % in dt):\n" + smap.table() + "\n")
        if args.plot:
            out.write(f"map written to {args.plot}\n")
    return 0


def write_report(out_dir="docs/stability", *, scenes=None, quick=False, executor=None, backend="auto"):
    """Regenerate the figures and tables of ``docs/stability.md``.

    Writes ``<out_dir>/map-<scene>.png`` for every scene, ``work-precision.png``
    and ``tables.md`` (the maps' tables, the battery's table and the
    work-precision rows).  Returns the markdown of ``tables.md``.
    """
    import os

    from . import scenes as _scenes

    os.makedirs(out_dir, exist_ok=True)
    names = list(_scenes.names() if scenes is None else scenes)
    parts = ["# Stability: generated tables\n", "Generated by `liefi.stability.write_report`.\n"]
    parts.append("## Stability maps (Euler, every gain equal to k)\n")
    gains = [1.0, 10.0, 100.0, 1000.0] if quick else None
    for nm in names:
        sc = _scenes.get(nm)
        v = BATTERY_VARIANTS.get(nm)
        smap = stability_map(nm, gains=gains, variant=v, t_final=2.0 if quick else None, executor=executor,
                             backend=backend)
        plot_stability_map(smap, os.path.join(out_dir, f"map-{nm}.png"))
        parts.append(f"### {nm} ({sc.variant(v).name}), t in [0, {smap.t_final:g}]\n\n![map](stability/map-{nm}.png)\n\n"
                     + smap.table() + "\n")
    res = run_battery(names, quick=quick, executor=executor, backend=backend)
    parts.append("## The extreme-case battery\n\n" + battery_table(res) + "\n")
    rows = stiff_work_precision(t_final=2.0 if quick else 5.0)
    plot_work_precision(rows, os.path.join(out_dir, "work-precision.png"),
                        "knife edge: explicit (auto gains), split imex and implicit solve_ivp")
    wp = ["| method | dt / rtol | outcome | max error | max drift | cpu s |", "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        f = lambda x: "-" if not isinstance(x, float) or not math.isfinite(x) else f"{x:.2g}"  # noqa: E731
        wp.append(f"| {r['label']} | {r['dt'] if r['dt'] is not None else r['rtol']:g} | {r['outcome']} | "
                  f"{f(r['error'])} | {f(r['drift'])} | {f(r['cpu'])} |")
    parts.append("## Work-precision (knife edge)\n\n![wp](stability/work-precision.png)\n\n" + "\n".join(wp) + "\n")
    text = "\n".join(parts)
    with open(os.path.join(out_dir, "tables.md"), "w") as fh:
        fh.write(text)
    return text


def main(argv=None):
    """``python -m liefi.stability SCENE [...]`` (the same as ``liefi stability``); ``--report DIR`` regenerates the docs."""
    import argparse
    import sys

    if argv is None:
        argv = sys.argv[1:]
    if argv and argv[0] == "--report":
        write_report(argv[1] if len(argv) > 1 else "docs/stability", quick="--quick" in argv)
        return 0
    p = add_arguments(argparse.ArgumentParser(prog="liefi stability", description=command.__doc__.split("\n")[0]))
    args = p.parse_args(argv)
    try:
        return command(args)
    except ValueError as exc:
        print(f"liefi stability: error: {exc}", file=__import__("sys").stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover -- ``python -m``: use the package's module (one set of classes)
    from liefi.stability import main as _main

    raise SystemExit(_main())
