"""Undo the reduction: the canonical system on ``T*Q`` whose left trivialization is a given reduced one.

Given a reduced system on ``g*`` (:class:`~liefi.phase_space.LieGroupPhaseSpace`)
or on ``g* x T*X`` (:class:`~liefi.phase_space.TrivialPrincipalBundle`) and a
chart ``s -> G(s)`` of the group, :func:`unreduce` writes down the *unreduced*
system on ``T*Q``, ``Q = G x X``, in the coordinates ``q = (s, x)``, as an
ordinary :class:`~liefi.systems.system.NonholonomicSystem` on a
:class:`~liefi.phase_space.CotangentBundle`, together with the map
``pi : (q, p) -> (g, z)`` (left trivialization) and its tangent map.

Both systems are then extended by the *same generic code*
(:mod:`liefi.reduction.core`): the unreduced one by the canonical formulas
``(bam:qp)``, the reduced one by ``(new:red:bam)`` /
``(new:red:bam:QG:trivial)``.  The paper's commutative diagrams (Sections 2.2
and 2.3, "extension commutes with reduction") say that ``pi`` carries the first
onto the second; ``tests/test_reduction_diagram.py`` checks this numerically.
"""

from __future__ import annotations

import numpy as np

from .. import _diff
from ..phase_space import CotangentBundle, PhaseSpace

__all__ = ["LeftTrivialization", "unreduce"]


class LeftTrivialization:
    """The projection ``pi : T*Q -> G x g* x T*X`` in a chart, and its tangent map.

    With ``q = (s, x)``, ``p = (p_s, p_x)`` and the left-trivialized Jacobian
    ``T(s)`` of the chart (``G(s)^{-1} dG/ds_k = hat(T(s)[:, k])``),

    .. math::

        \\pi(q, p) = \\bigl(g = G(s),\\; z = (x,\\ \\mu = T(s)^{-T} p_s,\\ p_x)\\bigr),

    i.e. ``mu = g^{-1} . alpha_g`` (the paper's left trivialization, so that the
    body velocity is ``xi = g^{-1} g' = T(s) s'`` and ``<mu, xi> = <p_s, s'>``).

    Not built directly: :func:`unreduce` returns one.

    Attributes
    ----------
    group : LieGroup
        The symmetry group ``G``.
    d, n : int
        ``dim G`` (= number of chart coordinates ``s``) and ``dim X``.
    chart, chart_jacobian : callable
        As passed to :func:`unreduce`.
    """

    def __init__(self, space: PhaseSpace, chart, chart_jacobian):
        self.space = space
        self.group = space.group
        self.d = space.d
        self.n = space.n
        self.chart = chart
        self.chart_jacobian = chart_jacobian

    def __repr__(self):
        return f"LeftTrivialization({self.space!r})"

    # --- the chart ------------------------------------------------------------
    def body_jacobian(self, s):
        """``T(s)``, shape ``(..., d, d)``: ``T[:, k] = vee(G(s)^{-1} dG/ds_k)``.

        The body velocity of the curve ``G(s(t))`` is ``xi = T(s) s'``.  Complex-step
        safe when ``chart`` and ``chart_jacobian`` are (which :func:`unreduce` checks).
        """
        s = np.asarray(s)
        G = np.asarray(self.chart(s))
        dG = np.asarray(self.chart_jacobian(s))  # (..., k, m, m)
        X = np.linalg.solve(G[..., None, :, :], dG)  # G^{-1} dG/ds_k
        return np.swapaxes(np.asarray(self.group.vee(X)), -1, -2)

    def _split(self, q, p):
        q = np.asarray(q)
        p = np.asarray(p)
        d = self.d
        return q[..., :d], q[..., d:], p[..., :d], p[..., d:]

    def advected(self, s):
        """``Gamma(s) = G(s)^{-1} . a_0`` (shape ``(..., k)``; empty without an advected vector); complex-step safe."""
        s = np.asarray(s)
        if not self.space.k:
            return np.zeros(s.shape[:-1] + (0,), dtype=s.dtype)
        return self.space.advected.body_from_matrix(self.chart(s), self.space.a0)

    def _reduced_state(self, q, p):
        """``z = (x, Gamma(s), T(s)^{-T} p_s, p_x)``; complex-step safe."""
        s, x, ps, px = self._split(q, p)
        T = self.body_jacobian(s)
        mu = np.linalg.solve(np.swapaxes(T, -1, -2), ps[..., None])[..., 0]
        Gamma = self.advected(s)
        batch = np.broadcast_shapes(x.shape[:-1], Gamma.shape[:-1], mu.shape[:-1], px.shape[:-1])
        return np.concatenate(
            [np.broadcast_to(a, batch + a.shape[-1:]) for a in (x, Gamma, mu, px)], -1
        )

    # --- pi, its tangent map, and a right inverse -----------------------------
    def __call__(self, q, p):
        """``pi(q, p) = (g, z)``.

        Parameters
        ----------
        q, p : array_like, shape (..., d + n)
            Canonical coordinates ``q = (s, x)`` and momenta ``p = (p_s, p_x)``.

        Returns
        -------
        g : ndarray, shape (..., config_dim)
            ``G(s)`` in the group's configuration embedding (``matrix_to_config``).
        z : ndarray, shape (..., n + k + d + n)
            The reduced state ``(x, Gamma, mu, p_x)``, ``mu = T(s)^{-T} p_s``,
            ``Gamma = G(s)^{-1} . a_0`` (no ``Gamma`` without an advected vector).
        """
        q = np.asarray(q, dtype=float)
        g = self.group.matrix_to_config(np.asarray(self.chart(q[..., : self.d])))
        return g, self._reduced_state(q, np.asarray(p, dtype=float))

    def push(self, q, p, qdot, pdot):
        """Tangent map ``T pi``: the rates ``(g', z')`` of ``pi(q, p)`` along ``(q', p')``.

        ``z'`` is the complex-step derivative of ``z(q, p)`` along ``(q', p')``
        (exact to rounding).  ``g'`` is the rate of the stored numbers of
        ``G(s)``: with ``G' = sum_k dG/ds_k s'_k`` (from ``chart_jacobian``) and
        ``xi = vee(G^{-1} G') = T(s) s'``, it is ``group.config_rate(g, xi)``,
        the embedding's own derivative along ``g' = g . xi`` (a chart embedding
        such as an angle is not complex-step safe through ``matrix_to_config``).

        Returns
        -------
        gdot : ndarray, shape (..., config_dim)
        zdot : ndarray, shape (..., nz)
        """
        q, p, qdot, pdot = (np.asarray(a, dtype=float) for a in (q, p, qdot, pdot))
        h = _diff.STEP
        zdot = self._reduced_state(q + 1j * h * qdot, p + 1j * h * pdot).imag / h
        s = q[..., : self.d]
        xi = np.einsum("...ak,...k->...a", self.body_jacobian(s), qdot[..., : self.d])
        g = self.group.matrix_to_config(np.asarray(self.chart(s)))
        return np.asarray(self.group.config_rate(g, xi)), zdot

    def lift(self, s, z):
        """A right inverse of ``pi`` at the chart point ``s``: ``(q, p)`` with ``pi(q, p) = (G(s), z)``.

        ``q = (s, x)``, ``p = (T(s)^T mu, p_x)`` for ``z = (x, mu, p_x)`` (or
        ``(x, Gamma, mu, p_x)``, which is in the image only when ``Gamma = G(s)^{-1} . a_0``).
        """
        s = np.asarray(s, dtype=float)
        x, mu, px = self.space.split(np.asarray(z, dtype=float))
        ps = np.einsum("...ka,...k->...a", self.body_jacobian(s), mu)
        batch = np.broadcast_shapes(s.shape[:-1], x.shape[:-1], ps.shape[:-1])

        def b(a):
            return np.broadcast_to(a, batch + a.shape[-1:])

        return np.concatenate([b(s), b(x)], -1), np.concatenate([b(ps), b(px)], -1)


def unreduce(system, chart, chart_jacobian, *, names=None, sample=None, check: bool = True):
    """The unreduced canonical system on ``T*Q`` of a reduced one, and the projection ``pi``.

    A reduced system on ``G x g* x T*X`` (state ``z = (x, mu, p_x)``, momentum
    ``P = (mu, p_x)``) with mass tensor ``m(x)``, constraint vectors ``e_i(x)``
    in ``g x TX`` and potential ``U(x)`` is the left trivialization of a
    ``G``-invariant system on ``T*Q``, ``Q = G x X``.  In the chart
    ``q = (s, x)``, ``g = G(s)``, with the left-trivialized Jacobian ``T(s)``,

    .. math::

        G(s)^{-1} \\frac{\\partial G}{\\partial s_k} = \\widehat{T(s)_{:,k}},
        \\qquad \\xi = g^{-1}\\dot g = T(s)\\,\\dot s,
        \\qquad B(s) = \\operatorname{blockdiag}(T(s), I_n),

    the velocity ``(xi, x')`` is ``B q'`` and the momentum is ``P = B^{-T} p``
    (``<P, (xi, x')> = <p, q'>``).  Hence the unreduced data are

    .. math::

        M(q) = B^T m(x) B, \\qquad e_i(q) = B^{-1} e_i(x), \\qquad U(q) = U(x),

    and a vector potential becomes ``A(q) = B^T A(x)``; with an advected vector
    every datum is read at ``(x, Gamma(s))``, ``Gamma(s) = G(s)^{-1} . a_0``
    (semidirect-product reduction: the unreduced system is invariant only
    under the isotropy group of ``a_0``), and its ``s``-derivative gains
    ``(dGamma/ds)^T d/dGamma`` (chain rule; ``dGamma/ds`` by complex step of
    the chart), so that ``H(q, p) =
    h(pi(q, p))``, ``<p - A(q), e_i(q)> = <P - A(x), e_i(x)>`` and the Gram
    matrices agree, ``E_Q M E_Q^T = E m E^T``.  ``pi(q, p) = (G(s), (x,
    T^{-T} p_s, p_x))``.  By the commutative diagrams of Sections 2.2 and 2.3,
    ``pi`` maps the canonical extended field ``(bam:qp)`` (general form,
    Remark ``(remark:nonhol:general)``) of the returned system onto the
    reduced extended field ``(new:red:bam)`` / ``(new:red:bam:QG:trivial)``
    together with the reconstruction ``g' = g . dh~/dmu``, and its constrained
    field onto ``(sys:LiePoisson)`` / ``(sys:QG:trivial)``.

    Parameters
    ----------
    system : NonholonomicSystem
        The reduced system, on ``LieGroupPhaseSpace(G)`` or
        ``TrivialPrincipalBundle(G, n)``.
    chart : callable
        ``chart(s)``: ``(..., d) -> (..., matrix_dim, matrix_dim)``, the group
        element ``G(s)`` as a matrix in the representation of ``G.hat``,
        batch-first, ``d = G.dim``.  Must accept complex ``s`` (complex-step safe:
        ``np.sin``, ``np.stack`` ..., no float casts or in-place filling of real
        arrays).
    chart_jacobian : callable
        ``chart_jacobian(s)``: ``(..., d) -> (..., d, matrix_dim, matrix_dim)``,
        the analytic ``dG/ds_k`` (axis ``-3`` is ``k``), also complex-step safe.

        It is *required* because ``M(q)`` contains the first derivatives of the
        chart, so ``dM/dq`` contains its second derivatives: ``T(s)`` is built
        from ``chart_jacobian`` and differentiated once by complex step, which
        is exact; a complex-step ``dG/ds`` inside ``T`` would have to be
        complex-stepped again (nested complex steps lose the derivative), and a
        finite difference would cost half the digits.
    names : sequence of str, optional
        Names of the chart coordinates ``s`` (default ``s_1 ... s_d``); the
        shape coordinates keep the reduced system's names.
    sample : array_like, shape (d + n,), optional
        A point ``q`` at which the chart and the unreduced data are checked
        (default ``q = 0``; pass one away from the chart's singularities, e.g.
        gimbal lock).
    check : bool
        Check at ``sample`` that ``chart_jacobian`` is the derivative of
        ``chart`` (against a complex step of ``chart``), that ``G^{-1} dG/ds_k``
        lies in the Lie algebra and that ``T(s)`` is invertible.  Default True.

    Returns
    -------
    unreduced : NonholonomicSystem
        On ``CotangentBundle(d + n)``, state ``(q, p)``; its data are functions
        of ``q`` with exact derivatives (chain rule through ``T(s)`` and the
        reduced data's own derivatives), so liefi needs no complex step of them.
        Its constraint rows are orthonormal exactly when the reduced ones are
        (``orthonormalized`` is carried over).
    to_reduced : LeftTrivialization
        ``to_reduced(q, p) -> (g, z)`` and ``to_reduced.push(q, p, q', p') ->
        (g', z')``; ``to_reduced.lift(s, z)`` is a right inverse.

    Raises
    ------
    ValueError
        If the system has no symmetry group, or (with ``check``) the chart is
        wrong at ``sample``.

    References
    ----------
    Chang & Perlmutter, Sections 2.2-2.3: ``(sys:LiePoisson)``,
    ``(new:red:bam)``, ``(new:red:bam:QG:trivial)`` and the diagrams there.
    Marsden & Ratiu, *Introduction to Mechanics and Symmetry*, 13.3 (left
    trivialization) and 14.6 (SE(2)).
    """
    space = system.space
    if not isinstance(space, PhaseSpace) or space.d == 0:
        raise ValueError(
            "system: expected a reduced system on LieGroupPhaseSpace(G) or "
            "TrivialPrincipalBundle(G, n) with dim G > 0; a CotangentBundle is already unreduced"
        )
    group, d, n, D = space.group, space.d, space.n, space.D
    names = tuple(f"s_{k + 1}" for k in range(d)) if names is None else tuple(names)
    if len(names) != d:
        raise ValueError(f"names: expected {d} chart-coordinate names (dim G), got {len(names)}")
    q0 = np.zeros(D) if sample is None else np.asarray(sample, dtype=float)
    if q0.shape != (D,):
        raise ValueError(f"sample: expected a point q = (s, x) of shape ({D},), got {q0.shape}")
    pi = LeftTrivialization(space, chart, chart_jacobian)
    if check:
        _check_chart(pi, q0[:d])

    def bmat(T):
        B = np.zeros(T.shape[:-2] + (D, D), dtype=T.dtype)
        B[..., :d, :d] = T
        B[..., d:, d:] = np.eye(n)
        return B

    def parts(q):
        q = np.asarray(q)
        return q[..., :d], q[..., d:]

    def with_dB(s):
        """``B``, ``dB/dq`` (axis -3 over all of q; zero for the x slots)."""
        T, dT = _diff.jacobian(pi.body_jacobian, s)  # dT: (..., l, a, k)
        B = bmat(T)
        dB = np.zeros(T.shape[:-2] + (D, D, D))
        dB[..., :d, :d, :d] = dT
        return B, dB

    k = space.k

    def data_point(q):
        """``y(q) = (x, Gamma(s))``: where the reduced data are read (``x`` alone without ``Gamma``)."""
        s, x = parts(q)
        if not k:
            return x
        Gamma = pi.advected(s)
        batch = np.broadcast_shapes(x.shape[:-1], Gamma.shape[:-1])
        return np.concatenate([np.broadcast_to(x, batch + (n,)), Gamma], -1)

    def q_derivative(datum, q, batch):
        """``(datum(y(q)), d datum/dq)`` by the chain rule through ``y(q) = (x, Gamma(s))``.

        ``d/dx`` is the datum's own; ``d/ds = (dGamma/ds)^T d/dGamma``, with
        ``dGamma/ds`` by complex step of ``Gamma(s) = G(s)^{-1} . a_0`` (first
        derivatives of the chart only, so exact).
        """
        q = np.asarray(q, dtype=float)
        val, dval = datum.with_derivative(data_point(q))
        shape = datum.shape
        out = np.zeros(batch + (D,) + shape)
        if dval is not None:
            rest = (slice(None),) * len(shape)
            dval = np.broadcast_to(dval, batch + (n + k,) + shape)
            out[(Ellipsis, slice(d, None)) + rest] = dval[(Ellipsis, slice(None, n)) + rest]
            if k:
                _, dGamma = _diff.jacobian(pi.advected, q[..., :d])  # (..., d, k)
                dG = np.broadcast_to(dGamma, batch + (d, k))
                flat = dval[(Ellipsis, slice(n, None)) + rest].reshape(batch + (k, -1))
                out[(Ellipsis, slice(None, d)) + rest] += (dG @ flat).reshape(batch + (d,) + shape)
        return np.broadcast_to(val, batch + shape), out

    # --- metric M(q) = B^T m B --------------------------------------------------
    def metric(q):
        s = parts(q)[0]
        B = bmat(pi.body_jacobian(s))
        return np.swapaxes(B, -1, -2) @ system.metric(data_point(q)) @ B

    def metric_derivative(q):
        s = parts(np.asarray(q, dtype=float))[0]
        B, dB = with_dB(s)
        batch = B.shape[:-2]
        m, dm = q_derivative(system.metric, q, batch)
        Bt, Bk, mk = np.swapaxes(B, -1, -2)[..., None, :, :], B[..., None, :, :], m[..., None, :, :]
        dBm = np.swapaxes(dB, -1, -2) @ mk @ Bk
        return dBm + np.swapaxes(dBm, -1, -2) + Bt @ dm @ Bk

    # --- constraints e_i(q) = B^{-1} e_i(x), rows: E_Q = E B^{-T} ---------------
    def constraints(q):
        s = parts(q)[0]
        B = bmat(pi.body_jacobian(s))
        E = np.asarray(system.constraints(data_point(q)))
        E = np.broadcast_to(E, B.shape[:-2] + E.shape[-2:])
        return np.swapaxes(np.linalg.solve(B, np.swapaxes(E, -1, -2)), -1, -2)

    def constraints_derivative(q):
        s = parts(np.asarray(q, dtype=float))[0]
        B, dB = with_dB(s)
        batch = B.shape[:-2]
        E, dE = q_derivative(system.constraints, q, batch)
        BinvT = np.swapaxes(np.linalg.inv(B), -1, -2)[..., None, :, :]
        EQ = (E @ BinvT[..., 0, :, :])[..., None, :, :]
        return dE @ BinvT - EQ @ np.swapaxes(dB, -1, -2) @ BinvT

    # --- potential U(q) = U(x) ------------------------------------------------------
    if system.potential.constant:
        potential, potential_gradient = float(system.potential.value), None
    else:

        def potential(q):
            return system.potential(data_point(q))

        def potential_gradient(q):
            q = np.asarray(q, dtype=float)
            return q_derivative(system.potential, q, q.shape[:-1])[1]

    # --- vector potential A(q) = B^T A(x) (so that p - A(q) = B^T (P - A(x))) --------
    vector_potential = vector_potential_derivative = None
    if system.vector_potential is not None:

        def vector_potential(q):
            s = parts(q)[0]
            B = bmat(pi.body_jacobian(s))
            A = np.asarray(system.vector_potential(data_point(q)))
            return np.einsum("...ak,...a->...k", B, A)

        def vector_potential_derivative(q):
            s = parts(np.asarray(q, dtype=float))[0]
            B, dB = with_dB(s)
            A, dA = q_derivative(system.vector_potential, q, B.shape[:-2])
            return np.einsum("...lak,...a->...lk", dB, A) + np.einsum("...ak,...la->...lk", B, dA)

    # the reduced system's own class: the reduction layer never imports the system layer
    unreduced = type(system)(
        CotangentBundle(D, names + tuple(space.shape_names)),
        metric,
        constraints if system.K else None,
        potential,
        metric_derivative=metric_derivative,
        constraints_derivative=constraints_derivative if system.K else None,
        potential_gradient=potential_gradient,
        vector_potential=vector_potential,
        vector_potential_derivative=vector_potential_derivative,
        sample=q0,
        check=check,
    )
    # the Gram matrix is invariant (E_Q M E_Q^T = E m E^T): orthonormal rows stay orthonormal
    unreduced.orthonormalized = bool(getattr(system, "orthonormalized", False))
    return unreduced, pi


def _check_chart(pi, s0):
    """Named errors for a chart that is not complex-step safe, a wrong ``chart_jacobian``, or a singular ``T``."""
    d, group = pi.d, pi.group
    k = group.matrix_dim
    try:
        G, dG_cs = _diff.jacobian(pi.chart, s0)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"chart: calling it with complex s failed ({exc}); write it with operations "
            "that accept complex input (np.sin, np.stack, ...)"
        ) from exc
    G = np.asarray(G)
    if G.shape != (k, k):
        raise ValueError(f"chart: expected a ({k}, {k}) matrix for s of shape ({d},), got {G.shape}")
    dG = np.asarray(pi.chart_jacobian(s0))
    if dG.shape != (d, k, k):
        raise ValueError(f"chart_jacobian: expected shape ({d}, {k}, {k}) for s of shape ({d},), got {dG.shape}")
    scale = max(1.0, float(np.max(np.abs(dG_cs))))
    if not np.allclose(dG, dG_cs, rtol=1e-8, atol=1e-8 * scale):
        raise ValueError(
            "chart_jacobian: disagrees with the complex-step derivative of chart at "
            f"s = {s0} (max difference {np.max(np.abs(dG - dG_cs)):.3g}); it must be dG/ds_k "
            "on axis -3, and chart must be complex-step safe"
        )
    X = np.linalg.solve(G, dG)
    if not np.allclose(group.hat(group.vee(X)), X, atol=1e-10 * max(1.0, float(np.max(np.abs(X))))):
        raise ValueError(
            f"chart: G(s)^-1 dG/ds is not in the Lie algebra of {group!r} at s = {s0}; "
            "the chart must return group elements in the representation of group.hat"
        )
    T = np.asarray(pi.body_jacobian(s0))
    if not np.isfinite(np.linalg.cond(T)) or np.linalg.cond(T) > 1e12:
        raise ValueError(
            f"chart: singular at s = {s0} (T(s) has condition number {np.linalg.cond(T):.3g}); "
            "pass a sample away from the chart's singularities"
        )
