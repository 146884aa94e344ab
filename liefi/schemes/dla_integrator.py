r"""First-order discrete Lagrange--d'Alembert (DLA) integrator on :math:`\mathbb R^n`.

The baseline the paper compares its feedback integrators against (paragraph
"Lagrange-d'Alembert Integrator" of the subsection "The Nonholonomic
Oscillator"), written for any mechanical system

.. math::

    L(q, \dot q) = \tfrac12 \dot q^{\mathsf T} M \dot q - U(q), \qquad
    A(q)\,\dot q = 0,

with a constant symmetric positive definite mass matrix :math:`M`
(:math:`n \times n`) and :math:`K` linear velocity constraints
:math:`A(q) \in \mathbb R^{K \times n}`.

Discretization (paper, equations ``(EZPHI)`` and ``(DiscLag)``)
---------------------------------------------------------------
With :math:`\phi(q_0, q_1) = (q_0, (q_1 - q_0)/h)` and :math:`L_d = L\circ\phi`,

.. math::

    L_d(q_0, q_1) = \frac{1}{2h^2}(q_1-q_0)^{\mathsf T} M (q_1-q_0) - U(q_0),

    D_1 L_d(q_0, q_1) = -\frac{M(q_1-q_0)}{h^2} - \nabla U(q_0), \qquad
    D_2 L_d(q_0, q_1) = \frac{M(q_1-q_0)}{h^2},

and the discrete constraint is :math:`C_d = \{(q_0,q_1) : A(q_0)(q_1-q_0) = 0\}`.
The DLA equations (McLachlan & Perlmutter 2006)

.. math::

    D_2 L_d(q_i, q_{i+1}) + D_1 L_d(q_{i+1}, q_{i+2}) = A(q_{i+1})^{\mathsf T}\lambda,
    \qquad A(q_{i+1})(q_{i+2} - q_{i+1}) = 0

are explicit in :math:`q_{i+2}`:

.. math::

    q_{i+2} = 2q_{i+1} - q_i - h^2 M^{-1}\bigl(\nabla U(q_{i+1})
              + A^{\mathsf T}\lambda\bigr),

    \bigl(A M^{-1} A^{\mathsf T}\bigr)\, h^2\lambda
        = A\,(q_{i+1} - q_i) - h^2 A M^{-1}\nabla U(q_{i+1}),
    \qquad A = A(q_{i+1}).

Equivalently, the step is the :math:`M`-orthogonal projection onto
:math:`\ker A(q_{i+1})` of the unconstrained displacement
:math:`\delta = q_{i+1} - q_i - h^2 M^{-1}\nabla U(q_{i+1})`; this is how it is
computed (the impulse :math:`h^2\lambda` is :math:`O(h)`, so no :math:`1/h^2`
enters the arithmetic).  For the nonholonomic oscillator (:math:`M = I`,
:math:`U = |q|^2/2`, :math:`A = (1, 0, y)`) these reduce to the paper's
``(ezDLA)``, ``(dynamics)`` and ``(EzLambda)``; the test suite checks that.

References
----------
.. [1] R. McLachlan and M. Perlmutter, "Integrators for nonholonomic mechanical
   systems", J. Nonlinear Sci. 16 (2006) 283--328.
"""

from __future__ import annotations

from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np

from liefi._diff import check_complex_step, gradient

__all__ = ["DLAIntegrator", "DLAResult", "DLANonFiniteError"]


class DLANonFiniteError(FloatingPointError):
    """A DLA step produced a non-finite value.

    Attributes
    ----------
    quantity : str
        Which quantity was non-finite (``"grad U(q)"``, ``"A(q)"``,
        ``"lambda"``, ``"q"``).
    step : int or None
        Index ``k`` of the update ``(q_{k-1}, q_k) -> q_{k+1}`` (``None`` from
        :meth:`DLAIntegrator.step`).
    time : float or None
        Time ``t_{k+1}`` of the point being computed.
    """

    def __init__(self, quantity, step=None, time=None):
        self.quantity, self.step, self.time = quantity, step, time
        where = "" if step is None else f" at step {step} (computing q at t = {time:.6g})"
        super().__init__(
            f"DLA integrator: non-finite {quantity}{where}. The trajectory has "
            "diverged or left the domain of the potential/constraints; reduce h "
            "or check the initial data."
        )


@dataclass(frozen=True)
class DLAResult:
    """Trajectory produced by :meth:`DLAIntegrator.run`.

    Attributes
    ----------
    t : ndarray, shape ``(n_saved,)``
        Saved times ``t0 + k h``.
    q : ndarray, shape ``(..., n, n_saved)``
        Positions :math:`q_k` (time on the last axis, as in ``scipy``).
    p : ndarray, shape ``(..., n, n_saved)``
        Discrete momenta :math:`p_k = M (q_k - q_{k-1})/h` (the paper's
        :math:`p_{i+1} = (q_{i+1} - q_i)/h`, with the mass matrix), and
        :math:`p_0 = M (q_1 - q_0)/h`.  Note :math:`A(q_{k-1}) M^{-1} p_k = 0`
        holds exactly, :math:`A(q_k) M^{-1} p_k = 0` only to :math:`O(h)`.
    h : float
        Time step.
    steps : int
        Number of DLA updates performed (``n_steps - 1`` for ``n_steps >= 1``).
    rhs_evaluations : int
        Number of evaluations of :math:`\\nabla U` and of :math:`A(q)` (one each
        per update).
    """

    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    h: float
    steps: int
    rhs_evaluations: int


def _as_real_array(x, name):
    try:
        a = np.asarray(x)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name}: cannot convert to an array ({exc}).") from exc
    if a.dtype == object or np.iscomplexobj(a) or not (
        np.issubdtype(a.dtype, np.number) or a.dtype == bool
    ):
        raise ValueError(f"{name}: expected a real numeric array, got dtype {a.dtype}.")
    a = a.astype(float)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains non-finite values (nan or inf).")
    return a


def _real(a):
    """``a`` as a float array (kept as it is when traced: an object array of the compiled engine)."""
    a = np.asarray(a)
    return a if a.dtype == object else a.astype(float)


def _check_h(h):
    if isinstance(h, bool) or not isinstance(h, Real) and not (
        isinstance(h, np.ndarray) and h.ndim == 0 and np.isrealobj(h)
    ):
        raise ValueError(f"h: the time step must be a real scalar, got {h!r}.")
    h = float(h)
    if not np.isfinite(h) or h <= 0.0:
        raise ValueError(f"h: the time step must be finite and > 0, got {h!r}.")
    return h


class DLAIntegrator:
    r"""First-order discrete Lagrange--d'Alembert integrator (McLachlan & Perlmutter 2006).

    For :math:`L = \tfrac12\dot q^{\mathsf T} M\dot q - U(q)` on
    :math:`\mathbb R^n` with constraints :math:`A(q)\dot q = 0`, one step maps
    :math:`(q_i, q_{i+1})` to

    .. math::

        q_{i+2} = 2q_{i+1} - q_i - h^2 M^{-1}\bigl(\nabla U(q_{i+1})
                  + A(q_{i+1})^{\mathsf T}\lambda\bigr),

    with :math:`\lambda \in \mathbb R^K` fixed by
    :math:`A(q_{i+1})(q_{i+2} - q_{i+1}) = 0`, i.e. the :math:`K\times K` system

    .. math::

        A M^{-1} A^{\mathsf T}\,\lambda
            = A\,\frac{q_{i+1} - q_i}{h^2} - A M^{-1}\nabla U(q_{i+1}).

    This is the discretization :math:`\phi(q_0,q_1) = (q_0,(q_1-q_0)/h)` of the
    paper (equations ``(EZPHI)``, ``(DiscLag)``); for the nonholonomic
    oscillator it is the paper's ``(dynamics)`` with ``(EzLambda)``.  All
    arrays are batch-first, shape ``(..., n)``.

    Parameters
    ----------
    mass : array_like, shape ``(n, n)``
        Constant mass matrix :math:`M`, symmetric positive definite.
    potential : callable, optional
        ``U(q)``, mapping ``(..., n)`` to ``(...)``.  Unless
        ``potential_gradient`` is given, its gradient is taken by complex-step
        differentiation (:mod:`liefi._diff`), so ``U`` must accept complex
        input; this is checked against finite differences on first use.
        ``None`` (and no gradient) means :math:`U = 0`.
    constraints : callable or array_like, optional
        :math:`A(q)`: a callable mapping ``(..., n)`` to ``(..., K, n)``
        (broadcastable), or a constant array of shape ``(K, n)`` (a 1-D array
        of shape ``(n,)`` is one constraint).  ``None`` means unconstrained.
        The rows must be linearly independent.
    potential_gradient : callable, optional
        Analytic :math:`\nabla U(q)`, mapping ``(..., n)`` to ``(..., n)``.

    Raises
    ------
    ValueError
        If ``mass`` is not a finite symmetric positive definite square matrix,
        or a constant ``constraints`` array has the wrong shape or non-finite
        entries.
    TypeError
        If ``potential`` or ``potential_gradient`` is given but not callable.

    Notes
    -----
    The step is computed as the :math:`M`-orthogonal projection onto
    :math:`\ker A(q_{i+1})` of :math:`\delta = q_{i+1} - q_i - h^2 M^{-1}\nabla
    U(q_{i+1})`, so the discrete constraint holds to rounding error.  The
    scheme is first order; it conserves the constraint but not the energy
    (the paper's Figure "oscillator").

    References
    ----------
    .. [1] R. McLachlan and M. Perlmutter, "Integrators for nonholonomic
       mechanical systems", J. Nonlinear Sci. 16 (2006) 283--328.

    Examples
    --------
    The nonholonomic oscillator of the paper:

    >>> import numpy as np
    >>> dla = DLAIntegrator(np.eye(3), lambda q: 0.5 * np.sum(q**2, axis=-1),
    ...                     lambda q: np.stack([np.ones_like(q[..., 1]),
    ...                                         np.zeros_like(q[..., 1]),
    ...                                         q[..., 1]], axis=-1)[..., None, :])
    >>> q0, q1 = dla.initial_pair(np.ones(3), np.zeros(3), 1e-3)
    >>> res = dla.run(q0, q1, 1e-3, 1000, save_every=100)
    >>> res.q.shape
    (3, 11)
    """

    def __init__(self, mass, potential=None, constraints=None, *, potential_gradient=None):
        M = _as_real_array(mass, "mass")
        if M.ndim != 2 or M.shape[0] != M.shape[1] or M.shape[0] == 0:
            raise ValueError(f"mass: expected a square (n, n) matrix with n >= 1, got shape {M.shape}.")
        scale = float(np.max(np.abs(M)))
        if not np.allclose(M, M.T, rtol=0.0, atol=1e-12 * max(scale, np.finfo(float).tiny)):
            raise ValueError(
                f"mass: not symmetric (max |M - M^T| = {np.max(np.abs(M - M.T)):.3g})."
            )
        M = 0.5 * (M + M.T)
        try:
            L = np.linalg.cholesky(M)
        except np.linalg.LinAlgError:
            raise ValueError("mass: not positive definite (Cholesky factorization failed).") from None
        self.n = M.shape[0]
        self.mass = M
        Linv = np.linalg.inv(L)
        self.mass_inv = Linv.T @ Linv  # M^{-1} = L^{-T} L^{-1}
        self.mass.flags.writeable = False
        self.mass_inv.flags.writeable = False

        if potential is not None and not callable(potential):
            raise TypeError(f"potential: expected a callable U(q), got {type(potential).__name__}.")
        if potential_gradient is not None and not callable(potential_gradient):
            raise TypeError(
                f"potential_gradient: expected a callable grad U(q), got {type(potential_gradient).__name__}."
            )
        self.potential = potential
        self.potential_gradient = potential_gradient
        self._checked_complex_step = potential_gradient is not None or potential is None

        self._constant_A = None
        self._constraints = None
        if constraints is None:
            self._constant_A = np.zeros((0, self.n))
        elif callable(constraints):
            self._constraints = constraints
        else:
            A = _as_real_array(constraints, "constraints")
            if A.ndim == 1:
                A = A[None, :]
            if A.ndim != 2 or A.shape[1] != self.n:
                raise ValueError(
                    f"constraints: a constant A must have shape (K, {self.n}) (or ({self.n},)), "
                    f"got {np.shape(constraints)}."
                )
            self._constant_A = A
        if self._constant_A is not None:
            A = self._constant_A
            self._constant_AMinv = A @ self.mass_inv  # (K, n), rows of A M^{-1}
            self._constant_S = self._constant_AMinv @ A.T
            if A.shape[0] and np.linalg.matrix_rank(self._constant_S) < A.shape[0]:
                raise ValueError("constraints: the rows of A are linearly dependent.")

    @classmethod
    def from_system(cls, system, *, data=None):
        r"""The DLA integrator of a :class:`~liefi.NonholonomicSystem` on :math:`T^*\mathbb R^n`.

        The Lagrangian data are read off the Hamiltonian data:
        :math:`M` is the system's (constant) metric, :math:`U` its potential
        (with the system's derivative: analytic if one was given, complex step
        otherwise), and the velocity constraints are
        :math:`A(q) = E(q) M`, i.e. :math:`A\dot q = E M M^{-1} p = E p = J`
        (the rows of :math:`A` are the covectors :math:`e_i^\flat`).  Only the
        kernel of :math:`A` enters the step, so normalizing the
        :math:`e_i` does not change the trajectory.

        Parameters
        ----------
        system : NonholonomicSystem
            On a :class:`~liefi.CotangentBundle` with a constant metric.
        data : optional
            The data accessor (default :class:`liefi.reduction.core.NumpyData`);
            the compiled engine passes its tracing one and traces :meth:`update`.

        Returns
        -------
        DLAIntegrator

        Raises
        ------
        TypeError
            If ``system`` is not a :class:`~liefi.NonholonomicSystem`.
        ValueError
            If it has a symmetry group (the DLA integrator works in
            coordinates on :math:`\mathbb R^n`: use a cotangent bundle) or a
            configuration-dependent metric.
        """
        from liefi.phase_space import CotangentBundle
        from liefi.systems.system import NonholonomicSystem

        if not isinstance(system, NonholonomicSystem):
            raise TypeError(f"system: expected a liefi.NonholonomicSystem, got {system!r}")
        if not isinstance(system.space, CotangentBundle):
            raise ValueError(
                f"system: the DLA integrator needs a system on a CotangentBundle (coordinates "
                f"on R^n), got one on {system.space!r}; write the unreduced system on T*Q"
            )
        if not system.metric.constant:
            raise ValueError(
                "system: the DLA integrator needs a constant metric (mass matrix); this "
                "system's metric depends on q"
            )
        if system.vector_potential is not None:
            raise ValueError(
                "system: the DLA integrator is written for H = 1/2 p.M^-1 p + U; this system "
                "has a vector_potential (a term linear in the momenta), which it does not treat"
            )
        from liefi.reduction.core import NUMPY_DATA

        data = NUMPY_DATA if data is None else data
        M = np.asarray(system.metric.value, dtype=float)
        pot, cons = system.potential, system.constraints

        potential = None if pot.constant else pot.fun
        potential_gradient = None if pot.constant else (lambda q: data.value_and_derivative(pot, q)[1])
        if system.K == 0:
            constraints = None
        elif cons.constant:
            constraints = cons.value @ M
        else:
            def constraints(q):
                return np.asarray(data.value(cons, q)) @ M

        return cls(M, potential, constraints, potential_gradient=potential_gradient)

    # ------------------------------------------------------------------ pieces
    def _check_q(self, q, name):
        q = _as_real_array(q, name)
        if q.ndim == 0 or q.shape[-1] != self.n:
            raise ValueError(f"{name}: expected shape (..., {self.n}), got {q.shape}.")
        return q

    def _grad_U(self, q):
        """:math:`\\nabla U(q)`, shape ``q.shape``."""
        if self.potential_gradient is not None:
            g = _real(self.potential_gradient(q))
            name = "potential_gradient"
        elif self.potential is not None:
            if not self._checked_complex_step:
                check_complex_step(self.potential, q, "potential")
                self._checked_complex_step = True
            g = gradient(self.potential, q)[1]
            name = "potential"
        else:
            return np.zeros_like(q)
        if g.shape != q.shape:
            try:
                g = np.broadcast_to(g, q.shape)
            except ValueError:
                raise ValueError(
                    f"{name}: its gradient has shape {g.shape}, expected {q.shape}."
                ) from None
        return g

    def _A(self, q):
        """``(A, A M^{-1}, A M^{-1} A^T)`` at ``q``, shapes ``(..., K, n)``, ``(..., K, n)``, ``(..., K, K)``."""
        if self._constant_A is not None:
            return self._constant_A, self._constant_AMinv, self._constant_S
        A = _real(self._constraints(q))
        if A.ndim < 2 or A.shape[-1] != self.n:
            raise ValueError(
                f"constraints: A(q) must have shape (..., K, {self.n}) for q of shape {q.shape}, got {A.shape}."
            )
        try:
            ok = np.broadcast_shapes(A.shape[:-2], q.shape[:-1]) == q.shape[:-1]
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(
                f"constraints: A(q) of shape {A.shape} does not match the batch shape {q.shape[:-1]} of q."
            )
        AMinv = A @ self.mass_inv
        S = AMinv @ np.swapaxes(A, -1, -2)
        return A, AMinv, S

    def _project(self, q, delta, *, with_impulse=False):
        r"""M-orthogonal projection of ``delta`` onto :math:`\ker A(q)`.

        Returns ``delta - M^{-1} A^T mu`` with ``(A M^{-1} A^T) mu = A delta``
        (and ``mu`` if ``with_impulse``).
        """
        A, AMinv, S = self._A(q)
        K = A.shape[-2]
        if A.dtype != object and not np.all(np.isfinite(A)):
            raise DLANonFiniteError("A(q)")
        if K == 0:
            mu = np.zeros(delta.shape[:-1] + (0,))
            return (delta, mu) if with_impulse else delta
        rhs = np.einsum("...kj,...j->...k", A, delta)
        try:
            mu = np.linalg.solve(S, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            raise np.linalg.LinAlgError(
                "constraints: A(q) M^{-1} A(q)^T is singular; the rows of A(q) must be "
                "linearly independent at every visited q."
            ) from None
        out = delta - np.einsum("...kj,...k->...j", AMinv, mu)  # M^{-1} is symmetric
        return (out, mu) if with_impulse else out

    def update(self, q_prev, q_curr, h):
        """The formula of one DLA update: ``(q_next, h^2 lambda, grad U(q_curr))``, no checks.

        ``q_{i+2} = q_{i+1} + P (q_{i+1} - q_i - h^2 M^{-1} grad U(q_{i+1}))`` with ``P``
        the ``M``-orthogonal projection onto ``ker A(q_{i+1})`` (class docstring).
        Written for any array type: the compiled engine traces it
        (:func:`liefi.engine.compile_dla`).
        """
        g = self._grad_U(q_curr)
        delta = (q_curr - q_prev) - (h * h) * (g @ self.mass_inv)
        step, mu = self._project(q_curr, delta, with_impulse=True)
        return q_curr + step, mu, g

    def _advance(self, q_prev, q_curr, h):
        """One DLA update with its checks; returns ``(q_next, h^2 lambda)``."""
        with np.errstate(over="ignore", invalid="ignore"):
            q_next, mu, g = self.update(q_prev, q_curr, h)
        if not np.all(np.isfinite(g)):
            raise DLANonFiniteError("grad U(q)")
        if not np.all(np.isfinite(mu)):
            raise DLANonFiniteError("lambda")
        if not np.all(np.isfinite(q_next)):
            raise DLANonFiniteError("q")
        return q_next, mu

    # --------------------------------------------------------------- public API
    def constraint_matrix(self, q):
        """:math:`A(q)`, shape ``(..., K, n)`` (broadcast to the batch shape of ``q``)."""
        q = self._check_q(q, "q")
        A = self._A(q)[0]
        return np.broadcast_to(A, q.shape[:-1] + A.shape[-2:])

    def discrete_constraint(self, q0, q1):
        r"""Residual :math:`A(q_0)(q_1 - q_0)` of the discrete constraint :math:`C_d`, shape ``(..., K)``."""
        q0 = self._check_q(q0, "q0")
        q1 = self._check_q(q1, "q1")
        return np.einsum("...kj,...j->...k", self._A(q0)[0], q1 - q0)

    def step(self, q_prev, q_curr, h, *, return_multiplier=False):
        r"""One DLA step :math:`(q_i, q_{i+1}) \mapsto q_{i+2}`.

        Parameters
        ----------
        q_prev, q_curr : array_like, shape ``(..., n)``
            :math:`q_i` and :math:`q_{i+1}` (broadcast against each other).
        h : float
            Time step, > 0.
        return_multiplier : bool, optional
            Also return the discrete multiplier :math:`\lambda`.

        Returns
        -------
        q_next : ndarray, shape ``(..., n)``
            :math:`q_{i+2}` (paper, ``(dynamics)``).
        lam : ndarray, shape ``(..., K)``
            Only if ``return_multiplier``: :math:`\lambda` with the sign of the
            paper, :math:`D_2L_d + D_1L_d = A^{\mathsf T}\lambda`
            (``(EzLambda)`` for the oscillator).

        Raises
        ------
        ValueError
            On wrong shapes, non-finite input or ``h <= 0``.
        FloatingPointError
            (:class:`DLANonFiniteError`) if the step produces non-finite values.
        """
        h = _check_h(h)
        q_prev = self._check_q(q_prev, "q_prev")
        q_curr = self._check_q(q_curr, "q_curr")
        try:
            q_prev, q_curr = np.broadcast_arrays(q_prev, q_curr)
        except ValueError:
            raise ValueError(
                f"q_prev, q_curr: batch shapes {q_prev.shape} and {q_curr.shape} do not broadcast."
            ) from None
        q_next, mu = self._advance(q_prev, q_curr, h)
        if return_multiplier:
            return q_next, mu / (h * h)
        return q_next

    def initial_pair(self, q0, p0, h):
        r"""Second point :math:`q_1` of the trajectory from :math:`(q(0), p(0))`.

        .. math::

            q_1 = q_0 + h\,P_{q_0} M^{-1} p_0, \qquad
            P_q v = v - M^{-1}A^{\mathsf T}(A M^{-1} A^{\mathsf T})^{-1} A v,

        the :math:`M`-orthogonal projection onto :math:`\ker A(q_0)` (the
        constraint impulse that removes the inadmissible part of
        :math:`p_0`), so that :math:`(q_0, q_1) \in C_d`.  For :math:`p_0 = 0`
        this is the paper's choice :math:`q_1 = q_0` (``(ns:dla:ic)``).

        Parameters
        ----------
        q0, p0 : array_like, shape ``(..., n)``
        h : float

        Returns
        -------
        q0, q1 : ndarray, shape ``(..., n)``
        """
        h = _check_h(h)
        q0 = self._check_q(q0, "q0")
        p0 = self._check_q(p0, "p0")
        try:
            q0, p0 = np.broadcast_arrays(q0, p0)
        except ValueError:
            raise ValueError(f"q0, p0: batch shapes {q0.shape} and {p0.shape} do not broadcast.") from None
        v = self._project(q0, p0 @ self.mass_inv)
        return q0.copy(), q0 + h * v

    def run(self, q0, q1, h, n_steps, save_every=1, *, t0=0.0):
        r"""Integrate :math:`q_0, q_1, \dots, q_{N}` with :math:`N` = ``n_steps``.

        Parameters
        ----------
        q0, q1 : array_like, shape ``(..., n)``
            The first two points (see :meth:`initial_pair`); any batch shape.
        h : float
            Time step, > 0.
        n_steps : int
            :math:`N \ge 0`; the final time is ``t0 + N h`` and ``N - 1`` DLA
            updates are performed.
        save_every : int, optional
            Save :math:`q_k` for ``k = 0, save_every, 2 save_every, ...``; the
            final point :math:`q_N` is always saved.
        t0 : float, optional
            Time of :math:`q_0`.

        Returns
        -------
        DLAResult
            ``t`` of shape ``(n_saved,)``, ``q`` and ``p`` of shape
            ``(..., n, n_saved)``.

        Raises
        ------
        ValueError
            On bad arguments (the message names the parameter).
        FloatingPointError
            (:class:`DLANonFiniteError`) naming the step, the time and the
            quantity that became non-finite.
        """
        h = _check_h(h)
        for name, val, lo in (("n_steps", n_steps, 0), ("save_every", save_every, 1)):
            if isinstance(val, bool) or not isinstance(val, Integral) or val < lo:
                raise ValueError(f"{name}: expected an integer >= {lo}, got {val!r}.")
        n_steps, save_every = int(n_steps), int(save_every)
        if isinstance(t0, bool) or not isinstance(t0, Real) or not np.isfinite(t0):
            raise ValueError(f"t0: expected a finite real number, got {t0!r}.")
        q_prev = self._check_q(q0, "q0")
        q_curr = self._check_q(q1, "q1")
        try:
            q_prev, q_curr = np.broadcast_arrays(q_prev, q_curr)
        except ValueError:
            raise ValueError(f"q0, q1: batch shapes {q_prev.shape} and {q_curr.shape} do not broadcast.") from None
        q_prev, q_curr = q_prev.copy(), q_curr.copy()

        idx = list(range(0, n_steps + 1, save_every))
        if idx[-1] != n_steps:
            idx.append(n_steps)
        idx = np.array(idx)
        qs = np.empty(q_prev.shape + (idx.size,))
        ps = np.empty_like(qs)
        j = 0

        def save(k, qk, qkm1, qkp1):
            nonlocal j
            if j < idx.size and idx[j] == k:
                dq = qk - qkm1 if k > 0 else qkp1 - qk  # p_0 = M (q_1 - q_0)/h
                qs[..., j] = qk
                ps[..., j] = (dq @ self.mass) / h
                j += 1

        save(0, q_prev, None, q_curr)
        if n_steps >= 1:
            save(1, q_curr, q_prev, None)
        for k in range(1, n_steps):
            try:
                q_next, _ = self._advance(q_prev, q_curr, h)
            except DLANonFiniteError as err:
                raise DLANonFiniteError(err.quantity, k, t0 + (k + 1) * h) from None
            q_prev, q_curr = q_curr, q_next
            save(k + 1, q_curr, q_prev, None)
        updates = max(n_steps - 1, 0)
        return DLAResult(t=t0 + h * idx, q=qs, p=ps, h=h, steps=updates, rhs_evaluations=updates)
