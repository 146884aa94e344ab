r"""A stiff-safe scheme: explicit step of the extended field, linearly implicit step of the feedback.

The feedback field ``y' = X(y) - A grad V(y)`` is stiff by design: the gains
make ``A Hess V`` large while ``X`` is not stiff.  An explicit scheme is stable
only while ``dt`` times the largest eigenvalue of ``A Hess V`` stays inside its
stability region (:mod:`liefi.stability`).  The schemes here split the field
into its two terms (the two "terms" of a diffrax ``MultiTerm``):

1. an explicit Runge--Kutta step of the extended field ``X`` (Euler, Heun or
   RK4 -- a tableau of :mod:`liefi.schemes`): ``y* = Phi_dt^X(y)``;
2. one linearly implicit (Rosenbrock--Euler) step of the gradient flow
   ``y' = -A grad V(y)`` from ``y*``:

   .. math:: y_+ = y_* - \Delta t\,(I + \Delta t\, A H)^{-1} A \nabla V(y_*),
             \qquad H = \sum_j k_j \nabla I_j \nabla I_j^T + k_0 \nabla^2 P,

   with the Gauss--Newton Hessian ``H`` of ``V``: exact on the invariant set
   ``V = 0``, where the terms ``(I_j - I_j0) Hess I_j`` vanish (``P`` is the
   embedding penalty, whose Hessian is taken exactly, by complex step).

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
invariants' gradients and one ``n x n`` solve (``n`` is the state size).

Use them by name: ``FeedbackIntegrator.run(dt, T, scheme="imex-euler")``,
``Scene.run(scheme="imex-rk4")``; the registry lists them
(``liefi.schemes.names("split")``, from :data:`SPLIT_SCHEMES`).  For an
adaptive implicit solver use ``Scene.run(scheme="scipy:Radau")`` (or ``BDF``),
which integrates ``fun(t, y)`` with a finite-difference Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _diff
from .rk import EULER, HEUN, RK4, ExplicitRungeKutta


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
    #: ``dt lambda_max`` targeted by automatic gains: the feedback substep damps the
    #: stiffest mode by ``1/(1 + 10)`` per step.
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


def feedback_step(fi, y, dt):
    """One linearly implicit Euler step of ``y' = -A grad V(y)``: ``y - dt (I + dt A H)^{-1} A grad V``."""
    y = np.asarray(y, dtype=float)
    gradV, H = feedback_hessian(fi, y)
    n = y.shape[-1]
    if fi.A is not None:
        gradV = np.einsum("ij,...j->...i", fi.A, gradV)
        H = np.einsum("ij,...jk->...ik", fi.A, H)
    M = np.eye(n) + dt * H
    with np.errstate(all="ignore"):
        try:
            delta = np.linalg.solve(M, (dt * gradV)[..., None])[..., 0]
        except np.linalg.LinAlgError:
            # I + dt A H singular to working precision (dt * gain ~ 1/eps): no meaningful step.
            # Non-finite values make the run's check raise IntegrationError with the time.
            return np.full(y.shape, np.nan)
    return y - delta


SPLIT_SCHEMES = {
    s.name: s
    for s in (
        LinearlyImplicitSplit("imex-euler", EULER),
        LinearlyImplicitSplit("imex-heun", HEUN),
        LinearlyImplicitSplit("imex-rk4", RK4),
    )
}


def is_split_scheme(scheme) -> bool:
    """True for the names of :data:`SPLIT_SCHEMES` and for split-scheme objects."""
    if isinstance(scheme, (LinearlyImplicitSplit, BoundSplitStep)):
        return True
    return isinstance(scheme, str) and scheme.lower() in SPLIT_SCHEMES

