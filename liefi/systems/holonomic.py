r"""Holonomic constraints ``f(x) = 0`` as a datum of a system: rows ``df``, values in ``V``.

A system built with ``NonholonomicSystem(..., holonomic=f)`` (``f(x)``, shape
``(H,)``, on the shape variables ``x``) carries two things derived from ``f``:

* **rows.**  Differentiating ``f(x(t)) = 0`` gives the Pfaffian rows ``a_j =
  (0, df_j(x))`` on the velocities ``v = (xi, x')``: ``df_j(x) . x' = 0``, on a
  ``CotangentBundle`` ``df_j(q) . qdot = 0``.  They are constraint rows like the
  nonholonomic ones, scaled as :meth:`~liefi.NonholonomicSystem.from_velocity_constraints`
  does with ``scaling="unit"``: ``e_j = m^{-1} a_j / |a_j|_{m^{-1}}`` with
  ``|a|_{m^{-1}}^2 = <a, m^{-1} a>``, so ``J_j = <P - A, e_j> = df_j . x' /
  |df_j|_{m^{-1}}``.  They are appended after the nonholonomic rows: ``J_{K-H+1}
  ... J_K`` belong to ``f_1 ... f_H``.
* **values.**  The invariants ``f_1 ... f_H`` (:func:`holonomic_invariants`,
  target 0) join ``V`` with the constraint momenta (``invariants`` entry
  ``"constraints"``), as a rotation block's orthogonality does, so that the
  position-level constraint is held, not only its derivative.

**Dependent coordinates stay in the state.**  The motion lives on ``Q_f = {f =
0}``, but the state keeps every coordinate of the ambient ``Q`` and ``f`` is
held by feedback: one global chart, no local chart switching (a closed chain or
a pendulum in Cartesian coordinates has no global independent coordinates, and
a solve for the dependent ones is singular where the chart ends), and the
extension is the paper's, on the ambient space, with the integrable rows among
the others (Chang, Perlmutter & Vankerschaver 2022).

**What the theory gives for integrable rows.**  The extension (Remark
``(remark:nonhol:general)``) does not ask whether rows are integrable: for the
rows ``e`` (nonholonomic and holonomic together) ``h~`` and every ``J_i`` are
first integrals of the extended field ``X`` everywhere, and on ``{J = 0}`` it is
the constrained (Lagrange--d'Alembert) motion, which for integrable rows is the
holonomic motion on ``Q_f`` (the reduction then reads the same).  ``f`` itself
is *not* a first integral of ``X``: along ``X``

.. math:: \dot f_j = df_j(x) . x' = |df_j|_{m^{-1}} J_j ,

so ``f`` is invariant only on ``{J_f = 0}``, where it is constant (any level
``f = c`` of the holonomic motion is invariant, not only ``c = 0``).  Hence
``grad V . X = sum_j k_{f_j} f_j N_j J_j`` (``N_j = |df_j|_{m^{-1}}``) need not
vanish, and the decrease of ``V = ... + sum_j k_{f_j} f_j^2/2`` along
``X - grad V`` is no longer automatic.

**Local exponential stability** (as in Chang, Perlmutter & Vankerschaver 2022)
still holds, with a condition on the gains.  Near the invariant set
``M = {V = 0}`` write ``r`` for the residuals (``J``, ``f``, the energy...), ``G =
(grad r_a . grad r_b)`` for their Gram matrix (positive definite where the
gradients are independent; ``grad J_f`` has a momentum part, ``grad f`` none)
and ``K = diag(k)``.  To first order ``r' = (-G K + C) r``, where the only
entries of ``C`` are ``C_{f_j, J_j} = N_j``.  With ``s = K r``,

.. math:: \dot V = r^T K r' = -s^T G s + s^T C K^{-1} s
          \le -(\lambda_{\min}(G) - \max_j N_j / k_{J_j}) |s|^2 ,

so ``V`` is a strict Lyapunov function and ``M`` is locally exponentially
stable whenever ``k_{J_j} \lambda_{\min}(G) > N_j`` for every holonomic row: the
gain on ``J_f`` must damp ``J_f`` faster than ``J_f`` feeds ``f``.  The gains of
:class:`~liefi.FeedbackIntegrator` (``"auto"``: ``k = w z*/dt``) are of order
``1/dt`` and meet it by a wide margin; the split schemes (``imex-*``, the
default) take a Gauss--Newton step onto ``M`` every step, which holds ``f`` with
the other residuals.  :func:`stability_margin` evaluates the condition.

References
----------
Chang, D. E., Perlmutter, M. & Vankerschaver, J., "Feedback integrators for
mechanical systems with holonomic constraints", *Sensors* 22(17) (2022) 6487,
doi:10.3390/s22176487 (the Dirac formula on the ambient space; a spherical pendulum).
"""

from __future__ import annotations

import numpy as np

from .. import _diff
from .._data import DataFunction
from .invariant import Invariant

#: relative step of the central differences that give ``d df/dx`` when ``f`` has no analytic derivative
_FD_STEP = 2e-4


class HolonomicData:
    """The datum ``f(x)`` of a system: values, differential, rows, and the invariants ``f_j``.

    Parameters
    ----------
    f : callable
        ``f(x)``: ``(..., n) -> (..., H)`` (a ``(...)`` result is one constraint),
        batch-first, accepting complex input.
    derivative : callable, optional
        ``df(x)``: ``(..., n) -> (..., n, H)`` (``d f_j / d x_k`` at ``[..., k, j]``).
        Without it ``df`` is taken by complex step at real points (exact to rounding)
        and its own ``x``-derivative, which the extended field reads through the
        rows, by central differences of ``df`` (about 1e-10 relative; pass the
        derivative to have it exact, and to compile the field).
    n, D : int
        Shape dimension and momentum dimension of the space (the shape velocities are
        the last ``n`` of the ``D`` velocities).
    sample : array_like (n,), optional
    """

    def __init__(self, f, derivative, n, D, sample=None):
        if not callable(f):
            raise TypeError(f"holonomic: expected a function f(x) of the shape variables, got {f!r}")
        if derivative is not None and not callable(derivative):
            raise TypeError(f"holonomic_derivative: expected a function df(x) -> (..., n, H), got {derivative!r}")
        x0 = np.zeros(n) if sample is None else np.asarray(sample, float)
        try:
            probe = np.asarray(f(x0))
        except Exception as exc:  # noqa: BLE001 -- user code: say which datum failed
            raise ValueError(f"holonomic: calling it at x = {x0} failed: {exc!r}") from exc
        if probe.ndim > 1:
            raise ValueError(f"holonomic: expected the values f(x) of shape (H,), got {probe.shape}")
        fun, der = f, derivative
        if probe.ndim == 0:  # one constraint returned as (...): make it (..., 1)
            fun = lambda x, g=f: np.asarray(g(x))[..., None]  # noqa: E731
            if derivative is not None:
                der = lambda x, g=derivative: np.asarray(g(x))[..., None]  # noqa: E731
        self.H = 1 if probe.ndim == 0 else probe.shape[0]
        if self.H == 0:
            raise ValueError("holonomic: f(x) has no component; pass holonomic=None")
        self.n, self.D = n, D
        self.values = DataFunction(fun, (self.H,), n, "holonomic", der, sample)
        self.analytic = der is not None
        self.names = tuple(f"f_{j + 1}" for j in range(self.H))

    def differential(self, x):
        """``df(x)``: ``(..., H, n)``, row ``j`` the gradient of ``f_j``.

        Complex ``x`` (a complex step through the rows) is exact with an analytic
        derivative; without one, ``df(a + i b) = df(a) + i d(df)(a) b`` with
        ``d(df)`` by central differences of the complex-step ``df``.
        """
        x = np.asarray(x)
        if self.analytic or x.dtype == object:
            return np.swapaxes(np.asarray(self.values._derivative(x)), -1, -2)
        if not np.iscomplexobj(x):
            return np.swapaxes(self.values.with_derivative(x)[1], -1, -2)
        a, b = x.real, x.imag
        s = _FD_STEP * np.maximum(1.0, np.linalg.norm(a, axis=-1, keepdims=True))
        d = b / np.where(np.linalg.norm(b, axis=-1, keepdims=True) > 0, np.linalg.norm(b, axis=-1, keepdims=True), 1)
        nb = np.linalg.norm(b, axis=-1)[..., None, None]

        def grad(y):
            return np.swapaxes(self.values.with_derivative(y)[1], -1, -2)

        # 4th-order central difference of df along the unit direction d
        dd = (8 * (grad(a + s * d) - grad(a - s * d)) - (grad(a + 2 * s * d) - grad(a - 2 * s * d))) / (
            12 * s[..., None])
        return grad(a) + 1j * nb * dd

    def rows(self, metric):
        """The constraint vectors ``e_j(x) = m^{-1} a_j / |a_j|_{m^{-1}}``, ``a_j = (0, df_j)``: ``(..., H, D)``."""
        n, D, H = self.n, self.D, self.H

        def rows(x):
            x = np.asarray(x)
            df = self.differential(x)
            a = df if D == n else np.concatenate([np.zeros(df.shape[:-1] + (D - n,), dtype=df.dtype), df], -1)
            m = metric(x) if callable(metric) else np.asarray(metric, float)
            m = np.broadcast_to(m, a.shape[:-2] + (D, D)) if a.ndim > 2 else m
            e = np.swapaxes(np.linalg.solve(m, np.swapaxes(a, -1, -2)), -1, -2)
            return e / np.sqrt(np.sum(a * e, -1))[..., None]

        rows.liefi_data_point = True
        return rows

    def invariants(self):
        """``(Invariant("f_1", ...), ...)``: the values ``f_j(z[:n])`` and their gradients (zero on the momenta)."""
        out = []
        for j, name in enumerate(self.names):
            out.append(Invariant(name, self._value(j), self._grad(j)))
        return tuple(out)

    def _value(self, j):
        def fun(z):
            return self.values(z[..., : self.n])[..., j]

        return fun

    def _grad(self, j):
        n = self.n

        def grad(z):
            z = np.asarray(z)
            df = self.differential(z[..., :n])[..., j, :]
            zero = np.zeros(z.shape[:-1] + (z.shape[-1] - n,), dtype=np.result_type(df, float))
            if z.dtype == object:
                zero = zero.astype(object)
            return np.concatenate([np.broadcast_to(df, z.shape[:-1] + (n,)), zero], -1)

        return grad

    def check(self, x):
        """The values, and the independence of the rows ``df``, at ``x`` (a named ``ValueError``)."""
        f = np.asarray(self.values(x))
        if not np.all(np.isfinite(f)) or np.iscomplexobj(f) and np.any(f.imag):
            raise ValueError(f"holonomic: non-finite or complex values at x = {x}")
        df = np.asarray(self.differential(np.asarray(x, float)), float)
        if not np.all(np.isfinite(df)):
            raise ValueError(f"holonomic_derivative: non-finite values at x = {x}")
        sv = np.linalg.svd(df, compute_uv=False)
        if sv.size and sv.min() <= 1e-12 * max(1.0, sv.max()):
            raise ValueError(f"holonomic: the differentials df_j are (nearly) linearly dependent at x = {x} "
                             f"(singular values {sv.tolist()}); drop redundant constraints, or check that "
                             "x = sample lies on a regular point of f")
        if self.analytic:
            _, jac = _diff.jacobian(self.values.fun, np.asarray(x, float))
            err = np.max(np.abs(jac - np.asarray(self.values._derivative(np.asarray(x, float)))), initial=0.0)
            if err > 1e-8 * max(1.0, np.max(np.abs(jac), initial=0.0)):
                raise ValueError(f"holonomic_derivative: differs from the derivative of f by {err:.3g} at x = {x} "
                                 "(expected shape (..., n, H), d f_j / d x_k at [..., k, j])")


def stability_margin(system, z, gains):
    r"""``min_j (k_{J_j} \lambda_{\min}(G) - N_j)`` at the state ``z`` (module docstring): positive = locally stable.

    ``gains``: ``{name: k}`` of the feedback integrator (``fi.gains``); ``G`` is the Gram
    matrix of the gradients of the penalized ``J``, ``f`` and the energy.  E.g. a pendulum
    in Cartesian coordinates (``m = 1.3``, ``l = 0.7``, at rest): the automatic gains of
    ``imex-rk8`` at ``dt = 0.089`` (``k_J = 95``, ``k_f = 37``) give a margin of 71; with
    ``k_J = 1e-3``, ``k_f = 10`` it is -1.2, the frozen-time linearization of ``X - grad V``
    has the eigenvalue ``+0.73`` and ``V`` stalls at 2e-16 instead of decaying.
    """
    hol = system.holonomic
    if hol is None:
        return np.inf
    from ..reduction import core as _core

    z = np.asarray(z, float)
    t = _core.evaluate(system, z)
    rows = [t.dJ[i] for i in range(system.K)] + [np.asarray(g(z)) for g in (i.grad for i in hol.invariants())]
    rows.append(t.dht)
    Gm = np.array(rows) @ np.array(rows).T
    lam = np.linalg.eigvalsh(Gm).min()
    x = z[: system.space.data_dim]
    df = np.asarray(hol.differential(x), float)
    m = np.asarray(system.metric(x), float)
    a = np.concatenate([np.zeros((hol.H, m.shape[0] - hol.n)), df], -1)  # a_j = (0, df_j)
    N = np.sqrt(np.einsum("jk,jk->j", a, np.linalg.solve(m, a.T).T))
    K0 = system.K - hol.H
    return float(min(gains[f"J_{K0 + j + 1}"] * lam - N[j] for j in range(hol.H)))
