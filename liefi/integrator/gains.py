r"""Every choice of gains: the feedback rate that minimizes a drift bound, per scheme, step and horizon.

This module holds all the choosing of gains; the theory it reads (``lambda_max(Hess V)``,
the unforced rates, the schemes' bounds, the pilot) is :mod:`liefi.integrator.stability`, below it,
and the run's policy (:mod:`liefi.integrator.policy`), above it, asks it for a run's gains:

* :func:`unit_rate_gains` (``lambda_max = 1``, Jacobi weights) and :func:`rate_gains`
  (those at a rate ``z``: every gain chosen through a rate is this product);
* :func:`accurate_rate`, :func:`accurate_gains` and :func:`accurate_setting` -- the
  accurate rate ``z*`` (``gains="auto"``; derivation below);
* :func:`optimal_rate` and :func:`auto_gains` -- the contraction rate ``x*`` that
  minimizes ``|R(-x)|`` (Bae & Chang's optimal fixed gain for Euler), for a fixed step;
* :func:`adapted_gains` and :func:`lowered_gains` -- the gains re-chosen along an
  adaptive run (numeric gains only lowered where ``dt lambda_max`` passes the rate);
* :func:`exactly_kept` and :func:`exact_drops` -- the invariants that need no gain;
* :func:`run_gains` -- what a fixed-step run starts with: the gains, the rate they are
  adapted at and which members adapt (the one question :class:`liefi.integrator.policy.Policy`
  asks here at a run's start; :func:`adapted_gains` the one between its segments).

The feedback term ``-k_j (I_j - I_j0) grad I_j`` relaxes the residual
``r_j = I_j - I_j0`` at the rate ``kappa_j = k_j |grad I_j|^2`` (the eigenvalue
of ``Hess V`` along ``grad I_j`` on the invariant set).  The gain is chosen
through the dimensionless rate ``z = dt * kappa``: the gains are
:func:`unit_rate_gains` (every invariant weighted by
``1 / |grad I_j|^2``, the penalty by ``1/2``, largest eigenvalue of
``Hess V`` equal to 1) times ``z / dt``.  Both factors are unit-invariant: a
change of the units of a state variable or of an invariant changes
``|grad I_j|^2`` and ``k_j`` together, and ``z`` is a number.

Derivation
----------
*One step, the residual of one invariant.*  Near the invariant set the
residual of ``I_j`` obeys, to first order, the Prothero--Robinson problem

.. math:: e' = -\kappa\, e, \qquad e = y_\perp - \varphi(t),

where ``y_perp`` is the state's coordinate along ``grad I_j / |grad I_j|`` and
``varphi(t)`` the position of the level set along that (moving) normal: the
level set turns with the motion, at the rate ``omega`` of the unforced field
``X``, so ``varphi^{(l)} ~ omega^l`` (in units of the state).  One step of an
explicit Runge--Kutta scheme ``(A, b, c)`` of order ``p`` from ``e_0`` gives
(stages ``E = (I + zA)^{-1}(e_0 1 + Delta)``, ``Delta_i`` the stage defects)

.. math:: e_1 = R(-z)\, e_0 + \delta(z), \qquad
          \delta(z) = \sum_{l \ge 2} h^l \varphi^{(l)}
          \Big[\varepsilon_l - z\, b^T (I + zA)^{-1} d_l\Big],

with ``epsilon_l = b^T c^{l-1}/(l-1)! - 1/l!`` (zero for ``l <= p``: the
scheme's own local error, ``l = p + 1``) and the stage defects
``d_l = A c^{l-1}/(l-1)! - c^l/l!`` (not zero from ``l = 2`` on: explicit
schemes have stage order 1).  The second term is the feedback's own
truncation error: ``z^a (h omega)^l`` with ``a + l >= p + 1`` (the order
conditions), i.e. for ``z ~ h omega`` it is of the scheme's order, but at
``z = O(1)`` it is ``O(h^2)`` whatever ``p`` -- the order reduction that
makes the drift of a feedback integrator with gains matched to the step fall
like ``dt^2``.  With ``varphi^{(l)} ~ omega^l`` the bound per step is

.. math:: \delta(z) \le \sum_{l=2}^{p+1} (h\omega)^l\,
          \big|\varepsilon_l - z\, b^T (I + zA)^{-1} d_l\big| .

*Many steps.*  Over ``N = T/h`` steps the injected ``delta`` is contracted
by ``|R(-z)|`` per step, so the residual stays below

.. math:: D(z) = \delta(z)\; \frac{1 - |R(-z)|^N}{1 - |R(-z)|}

(``N delta(0)``: the linear drift of the scheme alone, at ``z = 0``), plus
the rounding errors, a random walk ``u sqrt(sum_n |R|^{2n})`` (``u = 2^-53``
relative): without feedback it grows like ``u sqrt(N)``, which sets the
drift of a high-order scheme at a small step.  The
accurate rate is ``z* = argmin D(z)`` over ``[0, beta)`` (``beta`` the real
stability bound).  It depends on the scheme, on ``h omega`` and on ``N``
only:

* Euler (``p = 1``): ``d_2 = 0``, ``delta`` does not depend on ``z``, and
  ``D`` is least where ``|R(-z)| = |1 - z|`` vanishes: ``z* = 1``, Bae &
  Chang's optimal fixed gain ``alpha = 1/(h L0)`` (J. Bae and D. E. Chang,
  "Feedback integrators revisited", arXiv:2512.01528).
* RK4: ``epsilon_5 = 1/2880`` and the first stage-defect term is
  ``z^3 (h omega)^2 / 96``; for ``z = x h omega``,
  ``D ~ (h omega)^4 (1/2880 + x^3/96)/x``, least at ``x^3 = 1/60``:
  ``kappa* ~ 0.26 omega`` -- the feedback should relax the invariants
  *slower than the motion itself turns*, not at the step's stability limit
  (``z ~ 1.6``, the previous automatic choice, costs a factor
  ``~ (1.6/(h omega))^3`` in the local error).
* Short horizons (``N |1 - R(-z)| << 1`` for every useful ``z``): the
  contraction never acts and ``D`` grows with ``z``: ``z* = 0``, no feedback.

*Split schemes* (:mod:`liefi.schemes.split`: the tableau on ``X``, then the
linearly implicit feedback substep).  The tableau moves the residual as the
scheme alone does (``delta(0)``: no feedback truncation error, the feedback
is not in the stages) and the substep multiplies it by ``1/(1 + z)``:
``e_1 = (e_0 + delta(0)) / (1 + z)``, so ``D(z) = delta(0) / z`` (long
horizons) *decreases* for every ``z``: the larger the gain the smaller the
drift, and the trajectory is that of the tableau on ``X`` followed by a
Gauss--Newton step towards the invariant set (the substep's limit).  The
accurate rate is the end of the range, ``z* = 1/sqrt(u) ~ 9.5e7``
(:data:`SPLIT_RATE_MAX`): beyond it ``1/(1+z)`` is below ``sqrt(u)`` and the
residual left is the ``O(r^2)`` curvature term the linear model leaves out,
which further gain does not reduce.  This is the one regime where a feedback
integrator keeps a quadratic invariant to rounding at the cost of the plain
scheme plus one gradient evaluation per step.

*A bound, not a measurement.*  The model sizes the level set's motion by the
generic ``(h omega)^l``; a given invariant can be kept far better (Heun keeps
``R^T R = I`` to ``O(h^4)`` per step on a rotation), and there the bound asks
for a feedback that only adds its own truncation error (Suslov with Heun,
``T = 100``: drift 7e-7 with these gains, 4e-8 without).  Measuring each
invariant's one-step defect at the start instead was tried and is worse: on
the nonholonomic oscillator the defect of Heun without feedback is 8e-14 per
step at the start, which predicts a drift of 8e-8 over ``t = 1000``, while the
run drifts by 1.3e-3 as the motion grows (k = 1 holds 8e-7).  The split
schemes do not have the problem: their rule does not depend on the model's
sizes.

``omega`` is the spectral radius of ``dX/dy`` (unit-invariant: eigenvalues
survive a change of state units; it scales as 1/time), the largest over the
states given; where it vanishes (a free motion) the horizon ``1/T`` is used.

*Invariants the scheme keeps exactly* (:func:`exactly_kept`): an invariant
with a constant gradient ``a`` that is a first integral of the field
(``a . X(y) = 0`` for every ``y``, on and off the invariant set) and is
orthogonal to the gradients of the other penalized invariants (so that their
feedback does not move it) is kept to rounding by every Runge--Kutta scheme
applied to the feedback field (``a . y_{n+1} = a . y_n + h sum b_i a . F(Y_i)``,
``a . F = 0``); its residual stays zero, its feedback term vanishes
identically and only costs work.  Its gain is 0 and it should be left out of
``V`` (``invariants=`` of :class:`~liefi.FeedbackIntegrator`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..schemes import ExplicitRungeKutta, positive_number
from ..schemes.registry import names as _scheme_names, takes_scheme
from ..schemes import split as _split
from .stability import _scaled, drift_scales, dynamics_rate, dynamics_rates, estimate, resolve_scheme, stiffness


#: Rounding error injected per step, relative to the state's scale (unit roundoff of float64).
ROUNDOFF = 2.0**-53
#: The largest rate ``z`` considered for a split scheme: ``1/sqrt(u)``.  Past it the feedback
#: substep leaves ``1/(1 + z) < sqrt(u)`` of the residual, below the second-order term
#: ``O(r^2)`` the linear model leaves out (module docstring, "Split schemes").
SPLIT_RATE_MAX = 1.0 / math.sqrt(ROUNDOFF)
#: ``dt lambda_max`` targeted by the contraction gains with a split (stiff-safe) scheme: the
#: feedback substep damps the stiffest mode by ``1/(1 + 10)`` per step.
SPLIT_RATE = _split.LinearlyImplicitSplit.optimal_rate


# --------------------------------------------------------------------------------
# unit-rate gains and the contraction rate
# --------------------------------------------------------------------------------


def unit_rate_gains(fi, y=None):
    """Gains with ``lambda_max(Hess V)(y) = 1``, every invariant weighted by ``1/|grad I_j(y)|^2``.

    The Jacobi scaling of the Gram matrix: each invariant alone would relax at
    the same rate; the common factor makes the largest eigenvalue 1
    (:func:`liefi.integrator.stability.stiffness`).  The penalty (Hessian eigenvalue 2 on
    the group) gets weight 1/2.  A vanishing gradient gets the weight of the
    largest one.  For a batch ``y`` (an ensemble) each member gets its own
    (arrays of shape ``y.shape[:-1]``): the gains a single run of that member gets.
    """
    y = fi.y0 if y is None else np.asarray(y, float)
    batch = y.shape[:-1]
    jet = fi.invariant_gradients(y)
    n2 = np.einsum("...mn,...mn->...m", jet.grad, jet.grad)  # (..., m)
    top = np.max(n2, axis=-1, initial=0.0)
    floor = np.maximum(top * 1e-12, 1e-300)
    w = {nm: np.where(top > 0, 1.0 / np.maximum(n2[..., j], floor), 1.0) for j, nm in enumerate(jet.names)}
    if fi.use_penalty:
        w["penalty"] = np.full(batch, 0.5)
    w = {k: float(v) if np.ndim(v) == 0 else v for k, v in w.items()}
    trial = fi.for_batch(batch).with_gains({k: w.get(k, 1.0) for k in fi.invariant_names})
    lam = np.asarray(stiffness(trial, y).lam, float)
    scale = np.where((lam > 0) & np.isfinite(lam), 1.0 / np.where(lam > 0, lam, 1.0), 1.0)
    return _scaled(trial.gains, float(scale) if scale.ndim == 0 else scale)


def rate_gains(unit, z, dt):
    """``{name: k * z / dt}``: the unit-rate gains ``unit`` (:func:`unit_rate_gains`) at the rate ``z = dt kappa``.

    ``z`` a number, or an array (one rate per member of an ensemble).  Every
    gain chosen through a rate -- accurate, contraction, adapted along a run --
    is this product.
    """
    return {k: v * z / dt for k, v in unit.items()}


def optimal_rate(scheme):
    """The ``dt lambda_max`` the contraction gains aim at: the scheme's ``optimal_rate``.

    Euler ``x* = 1`` (Bae & Chang's optimal gain ``1/(dt L)``), Heun 1, RK4
    ~1.6; split schemes :data:`SPLIT_RATE`.
    """
    sch, _ = resolve_scheme(scheme)
    r = getattr(sch, "optimal_rate", math.nan)
    return SPLIT_RATE if not (isinstance(r, float) and math.isfinite(r)) else float(r)


def auto_gains(fi, dt, scheme="euler", *, y=None, t_final=None):
    """Fixed gains for ``dt`` and ``scheme``: :func:`unit_rate_gains` scaled to ``dt lambda_max = x*``.

    ``x*`` is :func:`optimal_rate` (1 for Euler: Bae & Chang's ``k = 1/(dt L)``).
    With ``t_final`` the largest ``lambda_max`` along a pilot up to ``t_final``
    (:func:`liefi.integrator.stability.estimate`) is used, so the gains are safe over the
    whole run (without adapting).
    """
    dt = positive_number(dt, "dt")
    unit = fi.with_gains(unit_rate_gains(fi, y))
    lam = 1.0
    if t_final is not None:
        lam = max(estimate(unit, dt, scheme, t_final=t_final, y0=y, resolution=False).lam, 1e-300)
    return _scaled(unit.gains, optimal_rate(scheme) / (dt * lam))


def lowered_gains(fi, y, rate, dt, *, split=False):
    """``fi``'s gains lowered where ``dt lambda_max`` passes ``rate``, member by member (``adaptive=True``).

    Every gain times ``min(1, rate / (dt lambda_max(y)))``; unchanged on a
    split scheme (``split=True``: its feedback substep is stable at every rate).
    """
    lam = np.asarray(stiffness(fi, y).lam, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_ = np.where((lam > 0) & (not split), np.minimum(1.0, rate / (dt * lam)), 1.0)
    s_ = float(s_) if s_.ndim == 0 else s_
    return {k: v * s_ if np.ndim(s_) == 0 else np.asarray(v) * s_ for k, v in fi.gains.items()}


def adapted_gains(fi, y, rate, dt, *, auto, split=False):
    """The gains of an adaptive run's next segment at the states ``y``, re-chosen from ``fi``'s.

    ``auto=True`` (``gains="auto"``): the unit-rate gains at ``y`` at the run's
    rate (:func:`rate_gains`; ``rate`` one per member of an ensemble or common);
    numeric gains: :func:`lowered_gains` (their ratios kept).
    """
    if auto:
        return rate_gains(unit_rate_gains(fi, y), rate, dt)
    return lowered_gains(fi, y, rate, dt, split=split)


# --------------------------------------------------------------------------------
# the accurate rate: the drift bound and its minimizer
# --------------------------------------------------------------------------------


@takes_scheme
def _tableau(scheme):
    """``(scheme, A, b, c)``: the explicit tableau of ``scheme`` (of its explicit part for a split scheme)."""
    sch = scheme
    sch = getattr(sch, "scheme", sch)  # a split scheme bound to an integrator
    tab = sch.explicit if getattr(sch, "kind", None) == "split" else sch
    if not isinstance(tab, ExplicitRungeKutta):
        raise ValueError(
            f"scheme: accurate gains are derived for explicit Runge-Kutta tableaux and the split schemes, got "
            f"{scheme!r}; use one of {', '.join(_scheme_names('explicit') + _scheme_names('split'))}"
        )
    s = tab.stages
    A = np.array([list(r) + [0.0] * (s - len(r)) for r in tab.A], float)
    b = np.array(tab.b, float)
    c = A.sum(axis=1)
    return sch, A, b, c


def _is_split(sch):
    return getattr(sch, "kind", None) == "split"


def _polynomials(scheme):
    r"""``(sch, E, Q, P)``: the scheme's defect and stability polynomials in ``z``.

    ``A`` is strictly lower triangular (an explicit tableau), so
    ``(I + zA)^{-1} = sum_{k<s} (-z)^k A^k`` and every quantity of the bound is a
    polynomial in ``z``: ``b^T (I + zA)^{-1} d_l = sum_k Q[l, k] z^k`` and
    ``R(-z) = 1 - z sum_k P[k] z^k``; ``E[l] = epsilon_l`` (module docstring),
    rows ``l = 2 .. p + 1``.  Evaluated at many rates (and many members) at once.
    """
    sch, A, b, c = _tableau(scheme)
    try:
        return _POLYNOMIALS[sch]
    except (KeyError, TypeError):
        pass
    s = len(b)
    powers = [np.linalg.matrix_power(A, k) for k in range(s)]
    P = np.array([(-1.0) ** k * b @ powers[k] @ np.ones(s) for k in range(s)])
    E, Q = [], []
    for l in range(2, sch.order + 2):
        E.append(b @ c ** (l - 1) / math.factorial(l - 1) - 1.0 / math.factorial(l))
        d = A @ c ** (l - 1) / math.factorial(l - 1) - c**l / math.factorial(l)
        Q.append([(-1.0) ** k * b @ powers[k] @ d for k in range(s)])
    out = (sch, np.array(E), np.array(Q), P)
    for a in out[1:]:
        a.setflags(write=False)  # shared by every later call (_POLYNOMIALS)
    try:
        _POLYNOMIALS[sch] = out  # a scheme of the registry is hashable: computed once per scheme
    except TypeError:
        pass
    return out


_POLYNOMIALS = {}


def _polyval(coef, z):
    """``sum_k coef[k] z^k`` (Horner) at the rates ``z`` (any shape)."""
    out = np.zeros(np.shape(z))
    for ck in coef[::-1]:
        out = out * z + ck
    return out


def _defect_terms(sch, E, Q, z):
    """``|eps_l - z b^T (I + zA)^{-1} d_l|`` for ``l = 2 .. p + 1``: shape ``(p,) + z.shape`` (module docstring)."""
    if _is_split(sch):  # the tableau acts on X alone: the feedback substep adds no truncation error
        z = np.zeros_like(z)
    return np.stack([np.abs(E[j] - z * _polyval(Q[j], z)) for j in range(len(E))])


def _geometric_sums(sch, P, z, n_steps):
    """``(sum_{k<N} |R|^k, sum_{k<N} |R|^{2k})`` with ``R = R(-z)``: how ``N`` steps add up defects and rounding."""
    if _is_split(sch):  # explicit tableau on X, then the residual times 1/(1 + z)
        R = 1.0 / (1.0 + z)
    else:
        R = np.abs(1.0 - z * _polyval(P, z))
    N = float(n_steps)
    out = []
    for Rk in (R, R * R):
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            geo = np.where(np.abs(1.0 - Rk) < 1e-12, N, (1.0 - Rk**N) / (1.0 - Rk))
        out.append(np.where(R >= 1.0, np.maximum(geo, N), geo))
    return out[0], out[1]


def local_defect(scheme, z, hw):
    r"""The bound ``delta(z)`` on the residual injected per step (module docstring), for rates ``z``.

    ``z``: ``dt * kappa`` (array); ``hw``: ``dt * omega`` (a number, or an array
    broadcasting with ``z``, e.g. ``(B, 1)`` against rates ``(B, G)``: one per
    member).  Returns an array shaped like ``z``, in units of ``|varphi|`` (the
    state's scale).
    """
    sch, E, Q, _ = _polynomials(scheme)
    z = np.atleast_1d(np.asarray(z, float))
    hw = np.asarray(hw, float)
    out = np.zeros(np.broadcast_shapes(z.shape, hw.shape))
    for j, term in enumerate(_defect_terms(sch, E, Q, z)):
        out = out + hw ** (j + 2) * term
    return out


def drift_bound(scheme, z, hw, n_steps):
    r"""The residual bound after ``N`` steps (module docstring), relative to the state's scale.

    ``D(z) = delta(z) (1 - |R|^N)/(1 - |R|) + u sqrt((1 - |R|^{2N})/(1 - |R|^2))``,
    ``R = R(-z)``, ``u`` = :data:`ROUNDOFF` (a random walk of rounding errors).
    ``z`` and ``hw`` as in :func:`local_defect`.
    """
    sch, _, _, P = _polynomials(scheme)
    z = np.atleast_1d(np.asarray(z, float))
    geo, geo2 = _geometric_sums(sch, P, z, n_steps)
    return local_defect(scheme, z, hw) * geo + ROUNDOFF * np.sqrt(geo2)


#: the rates :func:`accurate_rate` searches first: 0 and a log grid from this to the end of the range
RATE_GRID_MIN = 1e-12
#: points of that grid, and of each of the two refinements around its best point
RATE_GRID, RATE_REFINE = 2001, 33


def _rate_table(scheme, n_steps, zmax):
    """The coarse grid of :func:`accurate_rate` and ``D`` there as a polynomial in ``hw``.

    ``D(z, hw) = sum_l hw^(l+2) a_l(z) + b(z)``: returns ``(zs, a (p, G), b (G,))``,
    the same for every member, so that ``D`` over a whole ensemble is one matrix product.
    """
    key = (scheme, float(n_steps), float(zmax))
    hit = _RATE_TABLES.get(key)
    if hit is None:
        sch, E, Q, P = _polynomials(scheme)
        zs = np.concatenate([[0.0], np.geomspace(RATE_GRID_MIN, zmax, RATE_GRID)])
        geo, geo2 = _geometric_sums(sch, P, zs, n_steps)
        hit = zs, _defect_terms(sch, E, Q, zs) * geo, ROUNDOFF * np.sqrt(geo2)
        if len(_RATE_TABLES) > 64:
            _RATE_TABLES.clear()
        _RATE_TABLES[key] = hit
    return hit


_RATE_TABLES = {}


def accurate_rate(scheme, dt, omega, t_final):
    """``z* = argmin_z D(z)`` on ``[0, 0.95 beta]`` (``z = dt * kappa``; module docstring).

    ``omega``: the rate of the unforced motion (1/time); ``t_final``: the horizon.
    Returns 0 when no feedback beats the scheme alone.  For a split scheme
    (``beta = inf``) the range is ``[0, SPLIT_RATE_MAX]`` and ``D`` decreases
    on all of it: ``z* = SPLIT_RATE_MAX`` whenever feedback helps (module docstring).
    ``omega`` may be an array (one rate per member of an ensemble): then ``z*``
    is an array of the same shape, each entry the one a single run would get.

    The search: ``D`` on a log grid (:data:`RATE_GRID` points from
    :data:`RATE_GRID_MIN`, the same for every member, so that an ensemble's
    bounds are one matrix product), then twice :data:`RATE_REFINE` points
    between the neighbours of the best point: ``z*`` to about 3e-5 relative,
    at a cost per member of a few microseconds.
    """
    dt = positive_number(dt, "dt")
    t_final = positive_number(t_final, "t_final")
    om = np.asarray(omega, dtype=float)
    om = np.where((om > 0) & np.isfinite(om), om, 1.0 / t_final)
    beta = float(_tableau(scheme)[0].real_stability_bound)  # the scheme's own (inf for a split scheme)
    zmax = 0.95 * beta if math.isfinite(beta) else SPLIT_RATE_MAX
    n = max(1, int(round(t_final / dt)))
    hw = (dt * om).reshape(-1)
    if not math.isfinite(beta):  # split: D falls on the whole range, so only its end is a candidate
        D = drift_bound(scheme, np.array([0.0, zmax]), hw[:, None], n)
        out = np.where(D[:, 1] < 0.5 * D[:, 0], zmax, 0.0)
        return float(out[0]) if om.ndim == 0 else out.reshape(om.shape)
    zs, a, b = _rate_table(scheme, n, zmax)
    powers = np.arange(2, a.shape[0] + 2)
    out = np.empty(hw.shape)
    for i in range(0, hw.size, 1024):  # a few tens of MB at a time
        h = hw[i : i + 1024, None]
        D = (h**powers) @ a + b
        j = np.argmin(D, axis=-1)
        D0, best = D[:, 0], D[np.arange(len(j)), j]
        lo, hi = zs[np.maximum(j - 1, 0)], zs[np.minimum(j + 1, len(zs) - 1)]
        z = zs[j]
        for _ in range(2):  # refine between the neighbours of the best point
            zz = lo[:, None] + (hi - lo)[:, None] * np.linspace(0.0, 1.0, RATE_REFINE)
            Dz = drift_bound(scheme, zz, h, n)
            k = np.argmin(Dz, axis=-1)
            rows = np.arange(len(k))
            better = Dz[rows, k] < best
            z, best = np.where(better, zz[rows, k], z), np.where(better, Dz[rows, k], best)
            step = (hi - lo) / (RATE_REFINE - 1)
            lo, hi = np.maximum(z - step, lo), np.minimum(z + step, hi)
        # no feedback unless it buys a clear factor (the bound is a model, not a measurement)
        out[i : i + 1024] = np.where(best < 0.5 * D0, z, 0.0)
    return float(out[0]) if om.ndim == 0 else out.reshape(om.shape)


def rate_needs_omega(scheme, dt, t_final):
    """Whether :func:`accurate_rate` depends on ``omega`` at all for this scheme, step and horizon.

    On a split scheme ``D(z*) - D(0)/2 = delta(0) (S1(z*) - N/2) + u (sqrt(S2(z*)) - sqrt(N)/2)``
    (``S1, S2`` the geometric sums of ``1/(1 + z)``) is linear in ``delta(0)``, the
    only place ``omega`` enters: when both coefficients are negative (``N >= 16`` or
    so) feedback helps whatever ``omega`` is, and the rates of an ensemble's members,
    a Jacobian each, need not be computed.  An explicit tableau always needs them.
    """
    sch, _, _, P = _polynomials(scheme)
    if not _is_split(sch):
        return True
    n = max(1, int(round(positive_number(t_final, "t_final") / positive_number(dt, "dt"))))
    geo, geo2 = _geometric_sums(sch, P, np.array([SPLIT_RATE_MAX]), n)
    return not (geo[0] - 0.5 * n < 0 and math.sqrt(geo2[0]) - 0.5 * math.sqrt(n) < 0)


def unforced_rate(fi, y=None):
    """``omega``: spectral radius of ``dX/dy`` (the unforced field), max over the states ``y`` (default ``fi.y0``)."""
    y = fi.y0 if y is None else np.asarray(y, float)
    return dynamics_rate(fi, y)


def unforced_rates(fi, y=None):
    """``omega`` of each state of ``y`` (shape ``y.shape[:-1]``; a float for one state)."""
    y = fi.y0 if y is None else np.asarray(y, float)
    return dynamics_rates(fi, y)


def exactly_kept(fi, scheme="rk4", y=None, *, n_samples=6, rel=1e-2, tol=1e-10):
    """Names of the penalized invariants every Runge--Kutta scheme keeps to rounding.

    An invariant qualifies when its gradient ``a`` is constant, it is a first
    integral of the (extended) field, and the feedback of every invariant that
    does not qualify leaves it alone (``a . grad I_k = 0``): checked at ``y``
    (default ``fi.y0``) and ``n_samples`` states around it, off the invariant
    set (relative perturbation ``rel``, fixed seed).  Then ``a . y`` is
    unchanged by the whole feedback field, ``a . y_{n+1} = a . y_n`` for any
    RK step, and its feedback term vanishes identically (module docstring).
    A linear first integral of ``X`` alone is not enough: the energy's
    feedback ``-k (h - h0) grad h`` moves ``a . y`` when ``a . grad h != 0``
    (Suslov's ``J_1``, the roller racer's ``J_2``), and then its own feedback
    is needed.  The embedding penalty (quadratic) never qualifies.
    ``scheme`` must be a Runge--Kutta tableau.
    """
    _tableau(scheme)
    y0 = fi.y0 if y is None else np.asarray(y, float)
    y0 = np.asarray(y0, float).reshape(-1, fi.n)[0]
    fi = fi.members(0)  # a property of the field: the first member (its targets, its constants) stands for all
    rng = np.random.default_rng(12345)
    scale = np.maximum(np.abs(y0), 1e-3 * max(1.0, float(np.max(np.abs(y0)))))
    Y = np.concatenate([y0[None], y0 + rel * scale * rng.standard_normal((n_samples, fi.n))])
    with fi.selection():
        jet = fi.invariant_gradients(Y)
        X = fi.unforced_vector_field(Y)
    norms = np.linalg.norm(jet.grad, axis=-1)  # (s, m)
    linear = []
    for j in range(len(jet.names)):
        G = jet.grad[:, j, :]
        gn = float(np.max(norms[:, j]))
        if gn == 0.0:
            continue
        constant = np.max(np.abs(G - G[0])) <= tol * gn
        xn = np.maximum(np.linalg.norm(X, axis=-1), 1e-300)
        integral = np.max(np.abs(np.einsum("sn,sn->s", G, X)) / (gn * xn)) <= tol
        if constant and integral:
            linear.append(j)
    # the other invariants' feedback must not move it: a . grad I_k = 0 for every I_k not kept
    kept = list(linear)
    changed = True
    while changed:
        changed = False
        for j in list(kept):
            a = jet.grad[0, j, :]
            for k in range(len(jet.names)):
                if k in kept:
                    continue
                dots = np.abs(jet.grad[:, k, :] @ a) / np.maximum(norms[:, k] * np.linalg.norm(a), 1e-300)
                if np.max(dots) > tol:
                    kept.remove(j)
                    changed = True
                    break
    return tuple(jet.names[j] for j in kept)


def _accurate(fi, dt, scheme, t_final, y, omega, kept=None):
    """``(z*, gains, unit, omega)``: :func:`accurate_setting`, with the unit-rate gains and the unforced rates.

    ``omega`` is computed only where :func:`rate_needs_omega` (``None`` otherwise, unless given); ``kept``: the
    names of :func:`exactly_kept` at ``y`` when the caller has them (else they are evaluated here).
    """
    dt = positive_number(dt, "dt")
    T = 1000.0 * dt if t_final is None else positive_number(t_final, "t_final")
    y = fi.y0 if y is None else np.asarray(y, float)
    if omega is None and rate_needs_omega(scheme, dt, T):
        omega = unforced_rates(fi, y)
    z = accurate_rate(scheme, dt, np.zeros(y.shape[:-1]) if omega is None else omega, T)
    unit = unit_rate_gains(fi, y)
    gains = rate_gains(unit, z, dt)
    if np.ndim(z) == 0:
        gains = {k: float(v) for k, v in gains.items()}
    for name in exactly_kept(fi, scheme, y) if kept is None else kept:
        gains[name] = 0.0
    return z, gains, unit, omega


def accurate_setting(fi, dt, scheme="rk4", t_final=None, y=None, *, omega=None):
    """``(z*, gains)``: the accurate rate (:func:`accurate_rate`) and the gains of :func:`accurate_gains`.

    For an ensemble ``y`` (``(..., n)``) every member gets its own: ``z*`` from
    its own ``omega`` and the unit-rate gains at its own state (arrays of shape
    ``y.shape[:-1]``), the values a single run of that member gets.  ``omega``: the
    unforced rates at ``y`` (:func:`unforced_rates`) when the caller has them already.
    """
    return _accurate(fi, dt, scheme, t_final, y, omega)[:2]


def accurate_gains(fi, dt, scheme="rk4", t_final=None, y=None) -> dict:
    """Gains minimizing the drift bound ``D(z)`` for ``scheme``, ``dt`` and the horizon ``t_final``.

    ``{name: k}`` over ``fi.invariant_names``: :func:`unit_rate_gains`
    at ``y`` (default ``fi.y0``) times ``z*/dt``, ``z* = accurate_rate(scheme, dt,
    omega, t_final)`` with ``omega`` the unforced field's rate at ``y``
    (module docstring); the invariants of :func:`exactly_kept` get 0.
    ``t_final`` defaults to ``1000 dt``.  Unit-invariant.
    """
    return accurate_setting(fi, dt, scheme, t_final, y)[1]


def exact_drops(fi, sch, y0, *, rtol=1e-12, kept=None):
    """``{name: reason}``: the penalized invariants the scheme ``sch`` keeps exactly from ``y0`` (left out of ``V``).

    :func:`exactly_kept` (a first integral with a constant gradient, untouched by
    the other invariants' feedback: every Runge--Kutta step keeps it to
    rounding), for an explicit tableau, and only where the invariant is on its
    target at every member of ``y0`` (relative ``rtol``): off it, its own
    feedback is what brings it back.  One vectorized evaluation over the batch.  ``kept``: :func:`exactly_kept`
    at the first member when the caller has it.
    """
    if getattr(sch, "kind", None) not in ("explicit", "split") or not fi.invariant_names:
        return {}
    Y = np.asarray(y0, float).reshape(-1, fi.n)
    flat = fi.for_batch(np.shape(y0)[:-1]).members()  # every member's own target
    with np.errstate(all="ignore"):
        kept = exactly_kept(flat.members(0), sch, Y[0]) if kept is None else kept
        if not kept:
            return {}
        with flat.selection():  # the members flattened: their own constants
            jet = flat.invariant_gradients(Y)
        scales = drift_scales(fi)
    out = {}
    for name in kept:
        j = jet.names.index(name)
        if np.max(np.abs(jet.residual[..., j])) <= rtol * max(scales.get(name, 1.0), 1e-300):
            out[name] = (f"kept exactly by {sch.name}: a first integral with a constant gradient that no other "
                         "feedback term moves, so every Runge-Kutta step keeps it to rounding and its feedback "
                         "term vanishes identically (liefi.gains.exactly_kept)")
    return out


# --------------------------------------------------------------------------------
# the gains of a run
# --------------------------------------------------------------------------------

#: ``gains="auto"`` on an explicit tableau adapts the gains along the run (at the accurate rate
#: ``z*``) when ``z*`` is at least this fraction of the real stability bound (Euler: ``z* = 1``).
AUTO_ADAPT_FRACTION = 0.25


class RunGains(NamedTuple):
    """What a fixed-step run starts with (:func:`run_gains`)."""

    #: the integrator with the gains the run starts with (``fi`` itself when they are kept as given)
    fi: object
    #: ``dt lambda_max`` the adapted gains keep: ``z*`` (``gains="auto"``, one per member of an
    #: ensemble or common), else the scheme's ``optimal_rate``
    rate: object
    #: whether the gains are re-chosen along the run (:func:`adapted_gains`), and for which members (shape: the batch)
    adaptive: bool
    mask: np.ndarray
    #: the unforced rates at the start where ``z*`` needed them (:func:`unforced_rates`), else ``None``
    omega: object


def _merge(old, new, sel):
    """``{k: new[k] where sel else old[k]}``: per-member gains (floats for one trajectory)."""
    if np.ndim(sel) == 0:
        return dict(new) if sel else dict(old)
    return {k: np.where(sel, new[k], old[k]) for k in new}


def run_gains(fi, y, dt, scheme, t_final, *, adaptive=None, kept=None) -> RunGains:
    """The gains a fixed-step run of ``fi`` from ``y`` starts with, and whether they adapt along it.

    ``scheme``: a registry scheme (explicit or split); ``t_final``: the run's
    length.  ``gains="auto"``: the accurate gains (:func:`accurate_setting`),
    every member of an ensemble its own; with ``adaptive=None`` they are adapted
    along the run (at ``z*``, the unit-rate gains re-chosen: :func:`adapted_gains`)
    only for the members whose ``z*`` is at least :data:`AUTO_ADAPT_FRACTION` of
    the scheme's bound -- never on a split scheme, whose feedback substep is
    stable at every rate.  Numeric gains are kept, or with ``adaptive=True``
    lowered where ``dt lambda_max`` passes the scheme's ``optimal_rate``
    (:func:`lowered_gains`).  ``kept``: :func:`exactly_kept` of ``fi`` at ``y`` when the caller has it.
    """
    batch = tuple(getattr(fi, "batch", ()))
    auto = getattr(fi, "gains_mode", "fixed") == "auto"
    adapt = auto if adaptive is None else bool(adaptive)
    rate = scheme.optimal_rate
    mask = np.full(batch, adapt)
    if not auto:
        run_fi = fi.with_gains(lowered_gains(fi, y, rate, dt, split=scheme.kind == "split")) if adapt else fi
        return RunGains(run_fi, rate, adapt, mask, None)
    z, acc, unit, omega = _accurate(fi, dt, scheme, t_final, y, None, kept)
    if adaptive is None:
        mask = np.broadcast_to(z >= AUTO_ADAPT_FRACTION * float(scheme.real_stability_bound), batch)
        adapt = bool(np.any(mask))
    if adapt:
        rate = z
        return RunGains(fi.with_gains(_merge(acc, rate_gains(unit, rate, dt), mask)), rate, adapt, mask, omega)
    return RunGains(fi.with_gains(acc), rate, adapt, mask, omega)


__all__ = ["accurate_gains", "accurate_rate", "accurate_setting", "adapted_gains", "auto_gains", "drift_bound",
           "exact_drops", "exactly_kept", "local_defect", "lowered_gains", "optimal_rate", "rate_gains",
           "rate_needs_omega", "run_gains", "unforced_rate", "unforced_rates", "unit_rate_gains", "RunGains",
           "AUTO_ADAPT_FRACTION", "SPLIT_RATE", "SPLIT_RATE_MAX"]
