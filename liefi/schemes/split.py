r"""A stiff-safe scheme: explicit step of the extended field, linearly implicit step of the feedback.

The feedback field ``y' = X(y) - A grad V(y)`` is stiff by design: the gains
make ``A Hess V`` large while ``X`` is not stiff.  An explicit scheme is stable
only while ``dt`` times the largest eigenvalue of ``A Hess V`` stays inside its
stability region (:mod:`liefi.integrator.stability`).  The schemes here split the field
into its two terms (the two "terms" of a diffrax ``MultiTerm``):

1. an explicit Runge--Kutta step of the extended field ``X`` (Euler, Heun or
   RK4 -- a tableau of :mod:`liefi.schemes`): ``y* = Phi_dt^X(y)``;
2. one linearly implicit (Rosenbrock--Euler) step of the gradient flow
   ``y' = -A grad V(y)`` from ``y*``:

   .. math:: y_+ = y_* - \Delta t\,(I + \Delta t\, A H)^{-1} A \nabla V(y_*),
             \qquad H = W^T K W + k_0 \nabla^2 P,

   with the Gauss--Newton Hessian ``H`` of ``V`` (``W`` the rows
   ``grad I_j``, ``K = diag(k_j)``): exact on the invariant set ``V = 0``,
   where the terms ``(I_j - I_j0) Hess I_j`` vanish.

   **Solved through the small Gram matrix.**  The invariants' rows vanish on
   the group block, so ``H`` is block diagonal.  On the reduced block the
   push-through identity ``(I + dt A W^T K W)^{-1} A W^T = A W^T (I + dt K W A
   W^T)^{-1}`` turns the ``n x n`` solve into an ``m x m`` one (``m`` the
   number of invariants, 1 to 4):

   .. math:: \delta_z = \Delta t\, A W^T \mu, \qquad
             (I_m + \Delta t\, K\, W A W^T)\, \mu = K r .

   On the group block the penalty's Hessian on the group is ``2`` on the
   symmetric directions ``R S`` and ``grad P = R (R^T R - I)`` is such a
   direction to first order, so ``delta_g = dt k0 grad P / (1 + 2 dt k0)``
   (as ``dt k0`` grows this is the Newton--Schulz step
   ``R (3 I - R^T R) / 2`` towards the nearest rotation).  With a penalty
   the block structure needs ``A = None``.

For the linear model ``y' = -lambda y`` the second step multiplies by
``1 / (1 + dt lambda)``: stable for **every** gain and step, and the stiffest
modes are damped most.  With ``A = I`` the step is a Levenberg--Marquardt step
towards ``{I_j = I_j0}`` with damping ``1/dt``; as the gains grow it tends to
the Gauss--Newton projection onto the invariant set, so ``imex-rk4`` at large
gains behaves like RK4 followed by a projection (Hairer, Lubich & Wanner,
*Geometric Numerical Integration*, IV.4).  Near the invariant set the two
substeps nearly commute (``grad V`` vanishes there and ``V`` is a first integral
of ``X``), so the splitting error is of the size of the drift the feedback
removes and the trajectory error is that of the explicit tableau on ``X``.

Cost per step: the tableau's stages of ``X`` plus one evaluation of the
invariants' gradients and one ``m x m`` solve -- against the stages of
``X - A grad V`` for the explicit tableau: the feedback is paid once per step,
not once per stage.  The compiled engine runs these schemes too
(:func:`liefi.engine.compile_split`: the trace of :func:`feedback_step`).

Gains.  ``gains="auto"`` takes the rate ``z = dt k |grad I|^2`` of
:mod:`liefi.integrator.gains` for a split scheme: the residual after a step is
``(r + delta)/(1 + z)``, so the drift bound falls for every ``z`` and the
accurate rate is ``1/sqrt(u)`` -- the substep is then one Gauss--Newton step
onto the invariant set, and the invariants stay at rounding for the price of
the tableau on ``X`` plus one gradient evaluation.

Use them by name: ``FeedbackIntegrator.run(T, dt=dt, scheme="imex-euler")``,
``Scene.run(scheme="imex-rk4")``; the registry lists them
(``liefi.schemes.names("split")``, from :data:`SPLIT_SCHEMES`).  For an
adaptive implicit solver use ``Scene.run(scheme="scipy:Radau")`` (or ``BDF``),
which integrates ``fun(t, y)`` with a finite-difference Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _diff, _sparse
from ..reduction import core as _core
from .rk import EULER, HEUN, RK4, RK6, RK8, ExplicitRungeKutta


@dataclass(frozen=True)
class LinearlyImplicitSplit:
    """Explicit tableau on ``X`` then a linearly implicit step of ``-A grad V`` (module docstring).

    Attributes
    ----------
    name : str
    explicit : ExplicitRungeKutta
        The tableau used for the extended field ``X``.
    """

    name: str
    explicit: ExplicitRungeKutta

    kind = "split"
    #: The real stability bound of the stiff part: unbounded (A-stable feedback step).
    real_stability_bound = float("inf")
    #: Stable for every gain and step (the feedback substep is A-stable).
    stiff_safe = True
    #: ``dt lambda_max`` of the contraction gains (:func:`liefi.integrator.gains.auto_gains`; ``gains="auto"``
    #: takes the accurate rate of :mod:`liefi.integrator.gains` instead): the substep damps the stiffest mode by 1/11.
    optimal_rate = 10.0

    @property
    def order(self):
        """The tableau's order on ``X`` (the splitting is formally first order, see module docstring)."""
        return self.explicit.order

    @property
    def stages(self):
        """Evaluations per step: the tableau's stages plus the feedback step."""
        return self.explicit.stages + 1

    def stability_function(self, z):
        """``R(z) = 1 / (1 - z)`` of the feedback substep for ``y' = z y / dt`` (``z = -dt lambda``)."""
        return 1.0 / (1.0 - np.asarray(z, dtype=complex))

    def step(self, fi, y, dt):
        """One step of the feedback integrator ``fi``: the tableau on ``X``, then the feedback substep."""
        return feedback_step(fi, self.explicit.step(fi.unforced_vector_field, y, dt), dt)

    def bind(self, fi):
        """A stepper for :func:`liefi.schemes.integrate` that steps ``fi`` (``step(f, y, dt)`` ignores ``f``)."""
        return BoundSplitStep(self, fi)


class BoundSplitStep:
    """A :class:`LinearlyImplicitSplit` bound to one :class:`~liefi.FeedbackIntegrator`.

    Duck-types :class:`~liefi.schemes.ExplicitRungeKutta` for
    :func:`liefi.schemes.integrate` (``name``, ``stages``, ``order``,
    ``real_stability_bound``, ``step``).  ``integrate`` passes the full field
    ``f``; the step ignores it and uses the integrator's two terms.
    """

    def __init__(self, scheme: LinearlyImplicitSplit, fi):
        self.scheme = scheme
        self.fi = fi
        self.name = scheme.name
        self.stages = scheme.stages
        self.order = scheme.order
        self.real_stability_bound = scheme.real_stability_bound

    def with_integrator(self, fi):
        """The same scheme bound to another integrator (e.g. one with other gains)."""
        return BoundSplitStep(self.scheme, fi)

    def step(self, f, y, dt):
        return self.scheme.step(self.fi, y, dt)

    def __getattr__(self, name):  # the scheme's other properties (stability_function, kind, ...)
        if name == "scheme":
            raise AttributeError(name)
        return getattr(self.scheme, name)


def penalty_hessian(group, g):
    """Hessian of the embedding penalty ``P(g)`` (``(..., nc, nc)``), exact by complex step of its gradient.

    On the group (``R^T R = I``) its eigenvalues are 2 (symmetric directions
    ``R S``, ``S = S^T``) and 0 (tangent directions ``R W``, ``W = -W^T``):
    ``P(R + dR) = ||sym(R^T dR)||^2 + O(dR^3)``.
    """
    g = np.asarray(g, dtype=float)
    return _diff.jacobian(group.penalty_grad, g)[1]


def feedback_hessian(fi, y, jet=None):
    """``(grad V, H)`` at ``y``: the gradient and the Gauss--Newton Hessian of ``V``.

    ``H = sum_j k_j grad I_j grad I_j^T + k0 Hess P`` (shape ``(..., n, n)``);
    it equals ``Hess V`` on the invariant set.  ``jet`` is
    ``fi.invariant_gradients(y)`` if already computed.
    """
    y = np.asarray(y, dtype=float)
    if jet is None:
        jet = fi.invariant_gradients(y)
    k = jet.gains
    gradV = np.einsum("...m,...mn->...n", k * jet.residual, jet.grad)
    H = np.einsum("...mi,m,...mj->...ij", jet.grad, k, jet.grad)
    if fi.use_penalty and fi.gains.get("penalty", 0.0) > 0:
        k0 = fi.gains["penalty"]
        G = fi.system.space.group
        g = y[..., : fi.nc]
        nc = fi.nc
        gradV = gradV.copy()
        gradV[..., :nc] += k0 * G.penalty_grad(g)
        H = H.copy()
        H[..., :nc, :nc] += k0 * penalty_hessian(G, g)
    return gradV, H


def feedback_step(fi, y, dt, params=None, *, data=_core.NUMPY_DATA):
    """One linearly implicit Euler step of ``y' = -A grad V(y)``: ``y - dt (I + dt A H)^{-1} A grad V``.

    Solved through the ``m x m`` Gram matrix of the invariants' gradients
    (module docstring).  ``dt`` is one step, or an array of steps of the
    batch's shape ``y.shape[:-1]`` (one per state: the partial steps of
    :func:`liefi.integrator.dense.partial_step`).  ``params`` (default ``fi.parameters()``) and ``data`` as
    in :meth:`liefi.FeedbackIntegrator.field_parts`: the compiled engine traces
    this function with a symbolic state, parameter vector and step.
    """
    y = _core.as_real(y)
    p = fi.parameters() if params is None else params
    if fi.A is not None and fi.use_penalty:
        raise ValueError(
            "A: the split schemes solve the feedback step block by block and need A=None on a system "
            "with an embedding penalty; use an explicit scheme (euler, heun, rk4) or scheme='scipy:Radau'"
        )
    g, z = fi.split(y)
    batch = y.shape[:-1]
    terms = fi.invariant_terms(z, _core.evaluate(fi.system, z, data=data), p, data)
    nz = z.shape[-1]
    delta = np.zeros(y.shape, dtype=y.dtype)
    if terms:
        W = np.stack([np.broadcast_to(gr, batch + (nz,)) for _, _, gr, _ in terms], -2)  # (..., m, nz)
        kk = np.stack([np.broadcast_to(k, batch) for *_, k in terms], -1)  # (..., m)
        kr = np.stack([np.broadcast_to(k * r, batch) for _, r, _, k in terms], -1)
        Az = None if fi.A is None else fi.A[:, fi.nc :]  # the columns that act on the reduced block
        AWt = np.swapaxes(W, -1, -2) if Az is None else np.einsum("ij,...mj->...im", Az, W)  # (..., n or nz, m)
        WAWt = _sparse.matmul(W, AWt if Az is None else AWt[..., fi.nc :, :])  # traced: nonzero terms only
        M = np.eye(len(terms)) + _per_state(dt, 2) * kk[..., :, None] * WAWt
        with np.errstate(all="ignore"):
            try:
                mu = np.linalg.solve(M, kr[..., None])[..., 0]
            except np.linalg.LinAlgError:
                # I + dt K W W^T has eigenvalues >= 1 (similar to I + dt K^1/2 W W^T K^1/2); a singular
                # matrix here means overflowed entries: non-finite values make the run's check raise
                # IntegrationError with the time.
                return np.full(y.shape, np.nan)
        dz = _per_state(dt, 1) * _sparse.matvec("...ij,...j->...i", AWt, mu)  # traced: nonzero terms only
        if Az is None:
            delta = np.concatenate([np.zeros(batch + (fi.nc,), dtype=dz.dtype), dz], -1)
        else:
            delta = dz
    if fi.use_penalty:
        G = fi.system.space.group
        k0 = p[..., fi.parameter_layout.penalty]
        c = dt * k0 / (1.0 + G.penalty_hessian_bound() * dt * k0)
        dg = np.asarray(c)[..., None] * G.penalty_grad(g)
        delta = delta + np.concatenate([np.broadcast_to(dg, batch + (fi.nc,)), np.zeros(batch + (nz,))], -1)
    return y - delta


def _per_state(dt, k):
    """``dt`` against an array of ``k`` more trailing axes: one step as it is, a step per state with ``k`` new axes."""
    return dt if not isinstance(dt, np.ndarray) or dt.ndim == 0 else dt[(...,) + (None,) * k]


SPLIT_SCHEMES = {
    s.name: s
    for s in (
        LinearlyImplicitSplit("imex-euler", EULER),
        LinearlyImplicitSplit("imex-heun", HEUN),
        LinearlyImplicitSplit("imex-rk4", RK4),
        LinearlyImplicitSplit("imex-rk6", RK6),
        LinearlyImplicitSplit("imex-rk8", RK8),
    )
}


def is_split_scheme(scheme) -> bool:
    """True for the names of :data:`SPLIT_SCHEMES` and for split-scheme objects."""
    if isinstance(scheme, (LinearlyImplicitSplit, BoundSplitStep)):
        return True
    return isinstance(scheme, str) and scheme.lower() in SPLIT_SCHEMES

