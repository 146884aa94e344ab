r"""Linearization of a nonholonomic system at a steady motion: ``A``, its eigenvalues and its trivial modes.

A *steady motion* is a relative equilibrium of the reduced constrained field
``X`` (:meth:`~liefi.NonholonomicSystem.constrained_vector_field`): at ``z_0``
the field is a combination of symmetry generators,

.. math:: X(z_0) = \sum_k c_k\, \xi_k(z_0),

e.g. a rattleback's steady spin (``xi``: the rotation about the vertical, ``c``:
the spin), a disk's straight rolling (the rotation about its axis), a sleigh's
straight run (the translations); ``c = 0`` is an equilibrium.  In the frame that
moves with the symmetry, ``Y = X - sum_k c_k xi_k`` has ``z_0`` as an equilibrium,
and the linearized dynamics is ``DY(z_0)`` restricted to the tangent space at
``z_0`` of the invariant manifold on which the motion lives,

.. math:: M = \{ J(z) = 0 \} \cap \{ C_j(z) = C_j(z_0) \},

the constraint set and the level set of the phase space's Casimirs (a rolling
body's orthonormal attitude rows, ``|Gamma| = 1``).  ``DY(z_0)`` maps ``T_{z_0} M``
into itself (``Y`` is tangent to ``M`` and vanishes at ``z_0``), so with a basis
``T`` of ``T_{z_0} M`` (``nz x d``, ``d = dim M``: the minimal coordinates)

.. math:: A = T^+ \, DY(z_0)\, T, \qquad \dot{\delta} = A\, \delta .

``DX`` is the exact Jacobian of the traced constrained field (the same trace as
the compiled kernels, :mod:`liefi.engine.trace`, differentiated symbolically:
second derivatives of the data included, no finite differences); the generators
and the basis are differentiated by complex step.

**Why not the extended field's Jacobian.** The feedback field ``X~ - A grad V``
(:meth:`liefi.FeedbackIntegrator.jac`) lives on the whole phase space: normal to
``M`` it has the feedback's own modes (rates set by the gains), and its energy
penalty ``k_E (h~ - h~_0)^2`` shifts the mode along the energy.  ``A`` is the
constrained motion's, on ``M`` only, with no gain in it
(``tests/test_linearize.py`` shows both).

**Trivial modes.** A symmetry generator ``xi(z_0)`` is a right eigenvector of
``A`` of eigenvalue 0 (an ignorable coordinate, the heading of a spinning body);
the gradient ``dI(z_0) T`` of a first integral ``I`` (the energy; the user's
:class:`~liefi.Invariant`) is a left eigenvector of eigenvalue 0 (its partner is
the direction along the family of steady motions).  Each is found, checked
(``|A v|``, ``|w A|`` at rounding) and named; :attr:`Linearization.nontrivial_eigenvalues`
are the eigenvalues of ``A`` on the quotient ``W / S`` (``W``: the common kernel of
the integrals' gradients, ``S``: the span of the generators), i.e. the spectrum
with those zeros removed exactly rather than by a threshold.

Symmetries: ``symmetries=`` (a sequence of :class:`Symmetry`), or by default the
candidates that commute with the field (``[X, xi] = 0`` checked at ``z_0`` and at
perturbed points): the translations of every shape coordinate ``x_j`` (an
ignorable coordinate), and for a rolling body (:func:`liefi.rolling.rolling_body`)
the rotation about the vertical and the rotations about the body axes
(an axisymmetric body's own symmetry).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numpy as np

from .. import _diff
from ..groups import SO3
from ..reduction import core as _core
from ..systems.invariant import Invariant
from ..systems.mechanics import MechanicsSystem
from ..systems.system import NonholonomicSystem

#: relative residual of ``X(z_0) - sum c_k xi_k(z_0)`` up to which ``z_0`` is a steady motion
STEADY_RTOL = 1e-8
#: relative size of ``[X, xi]`` (and of ``A v``, ``w A``) up to which a generator (an integral) is taken as exact
SYMMETRY_RTOL = 1e-8
_STEP = 1e-30  # complex step of the generators and charts (linear or smooth functions)


@dataclass(frozen=True)
class Symmetry:
    """A symmetry of a system: its ``name`` and its generator ``generator(z) -> (..., nz)``, a vector field on the
    reduced states (batch-first, complex-step safe), whose flow maps solutions to solutions (``[X, xi] = 0``)."""

    name: str
    generator: object


@dataclass(frozen=True)
class TrivialMode:
    """A zero eigenvalue of ``A`` explained by a symmetry or a first integral.

    ``kind``: ``"symmetry"`` (``vector``: the right eigenvector ``a = T^+ xi(z_0)``), ``"integral"``
    (``vector``: the left eigenvector ``dI(z_0) T``) or ``"family"`` (``vector``: ``v`` with ``A v`` in the
    generators' span, the generalized eigenvector towards the steady motions nearby -- at another rate, another
    tilt --, kept when no integral's gradient already accounts for it); ``residual``: ``|A v| / (|A| |v|)``,
    ``|w A| / (|w| |A|)`` or ``|A v mod span S| / (|A| |v|)``, rounding for an exact mode.
    """

    name: str
    kind: str
    vector: np.ndarray
    residual: float


@dataclass(frozen=True)
class Linearization:
    """The linearized constrained dynamics at a steady motion, shaped as sympy's ``KanesMethod.linearize``.

    Attributes
    ----------
    A : ndarray (d, d)
        ``d delta / dt = A delta`` in the minimal coordinates ``delta`` (:attr:`coordinates`).
    B : ndarray (d, m) or None
        The input matrix ``d delta / dt = A delta + B delta_u`` for a system with a force with inputs
        (``force=``, or the loads of :func:`liefi.from_mechanics`; columns in the order of :attr:`inputs`),
        as sympy's ``linearize`` gives it; ``None`` without a force.
    basis : ndarray (nz, d)
        ``T``: ``delta z = T delta`` (columns in the reduced state ``z``).
    coordinates : tuple of str
        Names of the minimal coordinates (``q`` and the independent speeds of a mechanics model).
    point : ndarray (nz,)
        The steady motion ``z_0``.
    rates : dict
        ``{symmetry name: c_k}``: ``X(z_0) = sum c_k xi_k(z_0)`` (a spin, a rolling rate, a speed).
    eigenvalues, eigenvectors : ndarray
        Of ``A`` (columns, in the minimal coordinates; ``basis @ eigenvectors`` in ``z``), by decreasing
        real part.
    trivial_modes : tuple of TrivialMode
    nontrivial_eigenvalues : ndarray
        The eigenvalues with the trivial modes' zeros removed (module docstring), by decreasing real part.
        At a bifurcation (an eigenvalue crossing zero, e.g. a disk at its critical spin) the crossing mode is
        a tangent of a family of steady motions too: within rounding of the crossing it is counted as
        trivial (``"family"``) and drops out of this list.
    residual : float
        ``|X(z_0) - sum c_k xi_k(z_0)| / |X(z_0)|`` (0 at an equilibrium).
    """

    A: np.ndarray
    B: object
    basis: np.ndarray
    coordinates: tuple
    point: np.ndarray
    rates: dict
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    trivial_modes: tuple
    nontrivial_eigenvalues: np.ndarray
    residual: float
    symmetries: tuple = field(default=(), repr=False)
    inputs: tuple = ()  #: the names of the inputs (the columns of ``B``)

    @property
    def spectral_abscissa(self):
        """The largest real part of the nontrivial eigenvalues (``> 0``: linearly unstable)."""
        ev = self.nontrivial_eigenvalues
        return float(np.max(ev.real)) if ev.size else 0.0

    def __str__(self):
        modes = ", ".join(f"{m.name} ({m.kind})" for m in self.trivial_modes) or "none"
        return (f"Linearization: d = {len(self.coordinates)} minimal coordinates {self.coordinates}\n"
                f"  rates: {self.rates}\n  trivial modes (eigenvalue 0): {modes}\n"
                f"  nontrivial eigenvalues: {np.array2string(self.nontrivial_eigenvalues, precision=6)}")


# --- the exact Jacobian of the constrained field ---------------------------------------------------

_JACOBIANS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def field_and_jacobian(system, z):
    """``(X(z), DX(z))`` of the reduced constrained field, exact: the field traced and differentiated symbolically.

    The generated function is kept per system (and per its constants' ``data_key``).
    """
    from ..engine import cache as _cache  # the engine on first use (``import liefi`` stays light)
    from ..engine.codegen import function_source
    from ..engine.trace import TRACED_DATA, NotCompilable, jacobian, trace, traced_call

    key = getattr(system, "data_key", None)
    table = _JACOBIANS.setdefault(system, {})
    if key not in table:
        nz = len(system.state_names)
        try:
            with trace() as tr:
                zs = tr.symbols("y", nz)
                f = traced_call("the constrained field", lambda s: _core.field_terms(
                    system, s, kind="constrained", data=TRACED_DATA)[0], zs)
                f = np.asarray(f, dtype=object).reshape(-1)
                J = jacobian(f, list(zs)).T
                source = function_source("field", f) + function_source("jac", J.reshape(-1))
        except NotCompilable as exc:
            raise ValueError(f"system: its constrained field cannot be traced ({exc}), so liefi has no exact "
                             "Jacobian for it") from exc
        table[key] = _cache.load(source, "python").module
    module = table[key]
    z = np.ascontiguousarray(z, dtype=float)
    nz = z.shape[-1]
    X, J, p = np.empty(nz), np.empty(nz * nz), np.empty(0)
    module.field(z, p, X)
    module.jac(z, p, J)
    return X, J.reshape(nz, nz)


# --- symmetries --------------------------------------------------------------------------------------


def _is_rolling(system):
    from ..systems.rolling import ATTITUDE_NAMES

    return tuple(system.state_names[:9]) == ATTITUDE_NAMES and system.space.D == 5 and system.space.data_dim == 9


def _cross(a, b):
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)


def vertical_rotation():
    r"""A rolling body's rotation about the vertical, ``R -> R_z(t) R``: ``rho_1' = -rho_2``, ``rho_2' = rho_1``,
    ``p' = (-p_2, p_1)`` (``Gamma`` and ``Pi`` are body quantities: unchanged).  Its rate is the heading rate."""

    def xi(z):
        z = np.asarray(z)
        zero = 0.0 * z[..., :1]
        return np.concatenate([-z[..., 3:6], z[..., 0:3], zero * np.ones(6), -z[..., 13:14], z[..., 12:13]], -1)

    return Symmetry("rotation about the vertical (heading)", xi)


def body_rotation(axis):
    r"""A rolling body's rotation about its body axis ``axis`` (0, 1, 2), ``R -> R exp(t e_axis^)``:
    ``V' = V x e_axis`` for ``V = rho_1, rho_2, Gamma, Pi`` (``p`` unchanged); a symmetry of a body symmetric
    about that axis (a disk about its axis)."""
    n = np.eye(3)[axis]

    def xi(z):
        z = np.asarray(z)
        parts = [_cross(z[..., 3 * k:3 * k + 3], n) for k in range(4)]
        return np.concatenate(parts + [0.0 * z[..., 12:14]], -1)

    return Symmetry(f"rotation about body axis {axis + 1}", xi)


def coordinate_translation(system, j):
    """``d/dx_j``: the translation of the shape coordinate ``x_j`` (a symmetry when ``x_j`` is ignorable)."""
    nz = len(system.state_names)
    e = np.eye(nz)[j]

    def xi(z):
        return 0.0 * np.asarray(z) + e

    return Symmetry(f"translation of {system.state_names[j]} (ignorable)", xi)


def candidate_symmetries(system):
    """The symmetries liefi tries by default (module docstring)."""
    if _is_rolling(system):
        return (vertical_rotation(),) + tuple(body_rotation(k) for k in range(3))
    return tuple(coordinate_translation(system, j) for j in range(system.space.n))


def _generator(sym, z):
    """``(xi(z), Dxi(z))`` (``Dxi[i, k] = d xi_i / d z_k``)."""
    v, jac = _diff.jacobian(sym.generator, z, step=_STEP)
    return np.asarray(v, float), np.swapaxes(jac, -1, -2)


def _commutes(system, sym, points):
    """``[X, xi] = DX xi - Dxi X`` at rounding at every point of ``points``."""
    for z in points:
        X, DX = field_and_jacobian(system, z)
        v, Dv = _generator(sym, z)
        a, b = DX @ v, Dv @ X
        scale = np.linalg.norm(DX) * np.linalg.norm(v) + np.linalg.norm(Dv) * np.linalg.norm(X)
        if np.linalg.norm(a - b) > SYMMETRY_RTOL * max(scale, 1e-300):
            return False
    return True


def _probe_points(system, z0, rng):
    """``z_0`` and two perturbed states, projected onto ``J = 0`` (the attitude rows kept orthonormal)."""
    out = [z0]
    for _ in range(2):
        z = z0 + 1e-2 * rng.standard_normal(z0.shape) * (np.abs(z0) + 1e-2 * (np.linalg.norm(z0) + 1.0))
        if _is_rolling(system):
            R = z0[:9].reshape(3, 3)
            w = 1e-1 * rng.standard_normal(3)
            z[:9] = (R @ SO3().exp(w)).ravel()
        out.append(np.asarray(system.project(z), float))
    return out


# --- the invariant manifold ------------------------------------------------------------------------------


def _manifold_rows(system, z):
    """Gradients (rows) of ``J``, of the holonomic values ``f`` and of the phase space's Casimirs at ``z``:
    ``T_z M`` is their kernel (``M = {J = 0, f = 0, C = C(z_0)}``)."""
    rows = [np.asarray(_core.evaluate(system, z).dJ, float).reshape(-1, z.size)]
    for inv in system.holonomic_invariants:
        rows.append(np.asarray(inv.grad(z), float)[None])
    for c in system.space.casimirs:
        rows.append(np.asarray(c.value_and_grad(z)[1], float)[None])
    return np.concatenate(rows, 0)


def _null_space(G, n, rtol=1e-10):
    if G.shape[0] == 0:
        return np.eye(n)
    _, s, Vt = np.linalg.svd(G)
    rank = int(np.sum(s > rtol * max(s[0], 1e-300)))
    return Vt[rank:].T


def _reduced_state(system, state):
    """The reduced state ``z`` of a state given with or without the group's configuration numbers."""
    z = np.asarray(state, dtype=float)
    nz, nc = len(system.state_names), system.space.group.config_dim
    if z.shape == (nc + nz,) and nc:
        z = z[nc:]
    if z.shape != (nz,) or not np.all(np.isfinite(z)):
        raise ValueError(f"state: expected a reduced state of {nz} finite numbers {system.state_names} (or with the "
                         f"{nc} configuration numbers in front), got shape {np.shape(state)}")
    return z


# --- charts of mechanics models: the independent coordinates and speeds ---------------------------------


def _mechanics_chart(system, z0):
    """``(phi, c0, names)``: ``z = phi(q, v)`` on the constraint set, ``v`` the independent speeds (Kane) or
    velocities (Lagrange; the dependent ones chosen by a pivoted QR of the constraint rows at ``z_0``)."""
    n, K = system.space.n, system.K
    mech = system._mech
    q0 = z0[:n]
    qnames = [str(s) for s in system.space.shape_names]

    def momenta(q, qdot):
        p = np.einsum("...ij,...j->...i", system.metric(q), qdot)
        return p if system.vector_potential is None else p + system.vector_potential(q)

    if system.speeds:
        u0 = np.array(list(system.generalized_speeds(z0).values()), float)  # {name: value}, in the model's order
        names = [str(s).replace("(t)", "") for s in system.speeds[: n - K]]

        def phi(c):
            q, v = c[..., :n], c[..., n:]
            if K:
                A = mech["speed_constraints"](q)
                dep = np.linalg.solve(A[..., n - K:], -np.einsum("...ij,...j->...i", A[..., :n - K], v)[..., None])
                v = np.concatenate([v, dep[..., 0]], -1)
            qdot = mech["qdot_of_u"](np.concatenate([q, v], -1))
            return np.concatenate([q, momenta(q, qdot)], -1)

        return phi, np.concatenate([q0, u0[: n - K]]), qnames + names
    qd0 = np.asarray(system.velocities(z0), float)
    ind = list(range(n))
    if K:
        import scipy.linalg

        a0 = np.asarray(system.constraints(q0), float) @ np.asarray(system.metric(q0), float)
        piv = scipy.linalg.qr(a0, pivoting=True)[2]
        dep = sorted(int(k) for k in piv[:K])
        ind = [k for k in range(n) if k not in dep]
    names = [f"{qnames[k]}'" for k in ind]

    def phi(c):
        q, v = c[..., :n], c[..., n:]
        if not K:
            return np.concatenate([q, momenta(q, v)], -1)
        a = system.constraints(q) @ system.metric(q)
        vd = np.linalg.solve(a[..., dep], -np.einsum("...ij,...j->...i", a[..., ind], v)[..., None])[..., 0]
        cols = {k: v[..., i] for i, k in enumerate(ind)} | {k: vd[..., i] for i, k in enumerate(dep)}
        qdot = np.stack([cols[k] for k in range(n)], -1)
        return np.concatenate([q, momenta(q, qdot)], -1)

    return phi, np.concatenate([q0, qd0[ind]]), qnames + names


def _holonomic_chart(system, z0):
    r"""``(T, names)``: the basis of ``T_{z_0} M`` in the independent coordinates and speeds of a mechanics model
    with holonomic constraints ``f(q) = 0``.

    The chart ``c(z) = (q_ind, v_ind(z))`` (the coordinates less the dependent ones -- the model's
    ``q_dependent``, else a pivoted QR of ``df(q_0)`` -- and the independent speeds ``u_ind = W(q) qdot``
    (Kane) or velocities, as in :func:`_mechanics_chart`) restricted to ``M`` is a local diffeomorphism;
    its differential ``L = dc(z_0)`` (complex step) is invertible on ``T_{z_0} M = ker G`` (``G``:
    :func:`_manifold_rows`, with the rows ``df``).  With an orthonormal basis ``N`` of ``ker G``,
    ``T = N (L N)^{-1}`` is the basis with ``L T = 1``: ``delta z = T delta c`` on ``M``, no solve of
    ``f(q) = 0`` needed.
    """
    import scipy.linalg

    n, K, H = system.space.n, system.K, system.holonomic.H
    mech = system._mech
    q0 = z0[:n]
    qnames = [str(s) for s in system.space.shape_names]
    dep = list(mech.get("q_dependent") or [])
    if len(dep) != H:
        df = np.asarray(system.holonomic.differential(q0), float).reshape(H, n)
        dep = sorted(int(k) for k in scipy.linalg.qr(df, pivoting=True)[2][:H])
    qind = [k for k in range(n) if k not in dep]

    def qdot(z):
        q, p = z[..., :n], z[..., n:]
        if system.vector_potential is not None:
            p = p - system.vector_potential(q)
        return np.linalg.solve(system.metric(q), p[..., None])[..., 0]

    if system.speeds:
        vind = list(range(n - K))
        vnames = [str(s).replace("(t)", "") for s in system.speeds[: n - K]]

        def vel(z):
            return mech["u_of_qdot"](np.concatenate([z[..., :n], qdot(z)], -1))
    else:
        a0 = np.asarray(system.constraints(q0), float) @ np.asarray(system.metric(q0), float)
        vdep = sorted(int(k) for k in scipy.linalg.qr(a0, pivoting=True)[2][:K])
        vind = [k for k in range(n) if k not in vdep]
        vnames = [f"{qnames[k]}'" for k in vind]
        vel = qdot

    def chart(z):
        return np.concatenate([z[..., qind], vel(z)[..., vind]], -1)

    L = np.swapaxes(_diff.jacobian(chart, z0, step=_STEP)[1], -1, -2)
    N = _null_space(_manifold_rows(system, z0), z0.size)
    LN = L @ N
    if LN.shape[0] != LN.shape[1] or np.linalg.cond(LN) > 1e12:
        raise ValueError(f"state: the independent coordinates {[qnames[k] for k in qind]} and speeds {vnames} are no "
                         "chart of the constraint set there (a singular configuration of f or of the velocity "
                         "constraints); pass basis=")
    return N @ np.linalg.inv(LN), [qnames[k] for k in qind] + vnames


# --- the linearization ------------------------------------------------------------------------------------


def _steady_rates(system, z0, syms, forced=None):
    """``(X(z_0), DX(z_0), c, residual, generator values, their Jacobians)``; ``forced``: the force's ``(XF, DXF)``."""
    X, DX = field_and_jacobian(system, z0)
    if forced is not None:
        X, DX = X + forced[0], DX + forced[1]
    gens = [_generator(s, z0) for s in syms]
    V = np.stack([g[0] for g in gens], -1) if gens else np.zeros((z0.size, 0))
    c = np.linalg.lstsq(V, X, rcond=None)[0] if gens else np.zeros(0)
    r = X - V @ c
    return X, DX, c, r, gens


def _resolve_symmetries(system, z0, symmetries):
    if symmetries is not None:
        syms = tuple(symmetries)
        for s in syms:
            if not isinstance(s, Symmetry):
                raise TypeError(f"symmetries: expected liefi Symmetry objects (name, generator), got {s!r}")
        return syms
    points = _probe_points(system, z0, np.random.default_rng(0))
    return tuple(s for s in candidate_symmetries(system) if _commutes(system, s, points))


def linearize(system, state, qdot=None, *, u=None, symmetries=None, integrals=None, basis=None, force=None,
              inputs=None, t=0.0):
    r"""The linearized constrained dynamics at the steady motion ``state`` (module docstring).

    Parameters
    ----------
    system : NonholonomicSystem
        From data, :func:`liefi.rolling.rolling_body` or :func:`liefi.from_mechanics`.
    state : array_like
        The reduced state ``z_0`` (with or without the configuration numbers in front); for a
        :class:`~liefi.systems.mechanics.MechanicsSystem` with ``qdot`` or ``u``: the coordinates ``q``
        (as :meth:`~liefi.systems.mechanics.MechanicsSystem.state` takes them).
    qdot, u : array_like, optional
        The velocities or (Kane models) the generalized speeds, all or the independent ones.
    symmetries : sequence of Symmetry, optional
        Default: the candidates that commute with the field (module docstring); ``()`` for none.
    integrals : sequence of Invariant, optional
        First integrals beyond the energy (which is always used), e.g. a disk's Chaplygin integrals.
    basis : array_like (nz, d), optional
        A basis of ``T_{z_0} M`` (default: orthonormal, or the independent coordinates and speeds of a
        mechanics model).
    force, inputs, t : optional
        A force law (default the system's ``force``, e.g. the loads of :func:`liefi.from_mechanics`), the
        inputs' values at the steady motion ``{name: u0}`` (default 0) and the time it is read at.  ``A``
        then includes the force's state dependence (a damper) and ``B = T^+ dX/du``
        (:func:`liefi.integrator.forced.force_contribution`).

    Returns
    -------
    Linearization

    Raises
    ------
    ValueError
        If ``state`` is no steady motion (naming the residual and its largest components; see
        :func:`steady_motion`), or an integral is not conserved by the linearized dynamics.
    """
    if not isinstance(system, NonholonomicSystem):
        raise TypeError(f"system: expected a liefi NonholonomicSystem, got {system!r}")
    if getattr(system, "member_shape", ()):
        raise ValueError(f"constants: the system holds per-member constants (shape {system.constants.shape}); a "
                         "linearization is of one system at one state: set one value of each constant first "
                         "(system.constants = system.constants[k] for member k)")
    chart = None
    if isinstance(system, MechanicsSystem) and (qdot is not None or u is not None):
        z0 = np.asarray(system.state(state, qdot, u=u), float)
    else:
        if qdot is not None or u is not None:
            raise ValueError("qdot, u: only a system from liefi.from_mechanics takes its point as (q, qdot or u); "
                             "give the reduced state z")
        z0 = _reduced_state(system, state)
    J = np.asarray(system.constraint_momenta(z0), float)
    P = np.linalg.norm(z0[system.space.data_dim:])
    if system.K and np.max(np.abs(J)) > 1e-10 * max(P, 1.0):
        raise ValueError(f"state: not on the constraint set (J = {J.tolist()}); project it with system.project(z) "
                         "or build it with the system's own constructor of states")
    f = [float(inv.fun(z0)) for inv in system.holonomic_invariants]
    if f and max(abs(v) for v in f) > 1e-10 * max(np.linalg.norm(z0[: system.space.data_dim]), 1.0):
        raise ValueError(f"state: off the holonomic constraints (f = {f}); solve f(q) = 0 for the dependent "
                         "coordinates first (e.g. scipy.optimize.brentq or Newton)")
    if isinstance(system, MechanicsSystem) and basis is None:
        chart = _holonomic_chart(system, z0) if system.holonomic is not None else _mechanics_chart(system, z0)
    syms = _resolve_symmetries(system, z0, symmetries)
    law = force if force is not None else getattr(system, "force", None)
    forced = BF = None
    if law is not None:
        from ..systems.forcing import as_force_law
        from .forced import force_contribution

        law = as_force_law(law)
        u0 = _input_point(law, inputs)
        XF, DXF, BF = force_contribution(system, law, z0, u0, t)
        forced = (XF, DXF)
    X, DX, c, r, gens = _steady_rates(system, z0, syms, forced)
    # |z0| at least 1: an equilibrium at z_0 = 0 (every coordinate zero) has a field of rounding size only
    scale = max(np.linalg.norm(X), np.linalg.norm(DX) * max(np.linalg.norm(z0), 1.0) * 1e-3, 1e-300)
    res = float(np.linalg.norm(r) / scale)
    if res > STEADY_RTOL:
        big = np.argsort(-np.abs(r))[:3]
        what = ", ".join(f"{system.state_names[k]}' = {r[k]:.3g}" for k in big)
        names = [s.name for s in syms] or ["none"]
        raise ValueError(
            f"state: not a steady motion: the constrained field is not a combination of the symmetries {names} "
            f"there (relative residual {res:.3g}; largest: {what}). Find one near it with "
            "liefi.steady_motion(system, guess), or pass symmetries= the ones the motion uses")
    # the co-moving field Y = X - sum c_k xi_k: DY = DX - sum c_k Dxi_k
    DY = DX - sum((ck * g[1] for ck, g in zip(c, gens)), np.zeros_like(DX))
    if basis is not None:
        T = np.asarray(basis, float)
        coords = tuple(f"b{k + 1}" for k in range(T.shape[1]))
    elif chart is not None and system.holonomic is not None:
        T, coords = chart[0], tuple(chart[1])
    elif chart is not None:
        phi, c0, names = chart
        T = np.swapaxes(_diff.jacobian(phi, c0, step=_STEP)[1], -1, -2)
        coords = tuple(names)
    else:
        T = _null_space(_manifold_rows(system, z0), z0.size)
        coords = tuple(f"b{k + 1}" for k in range(T.shape[1]))
    G = _manifold_rows(system, z0)
    if T.ndim != 2 or T.shape[0] != z0.size or np.linalg.matrix_rank(T) != T.shape[1] or (
            G.size and np.linalg.norm(G @ T) > 1e-8 * np.linalg.norm(G) * np.linalg.norm(T)):
        raise ValueError(f"basis: expected {z0.size} x d independent columns tangent to the constraint set and the "
                         "Casimirs' level set at the state")
    Tp = np.linalg.pinv(T)
    A = Tp @ DY @ T
    nA = max(np.linalg.norm(A), 1e-300)
    modes, W = [], []
    damped = forced is not None and np.any(forced[1] != 0)  # a state-dependent force: no energy integral
    ints = ([] if damped else [Invariant("energy", system.hamiltonian)]) + list(integrals or ())
    for inv in ints:
        if not isinstance(inv, Invariant):
            raise TypeError(f"integrals: expected liefi.Invariant objects, got {inv!r}")
        if inv.name == "energy" and not damped and inv is ints[0]:
            dI = np.asarray(_core.evaluate(system, z0).dh, float)
        else:
            dI = np.asarray(inv.value_and_grad(z0)[1], float)
        w = dI @ T
        if np.linalg.norm(w) <= 1e-13 * np.linalg.norm(dI) * np.linalg.norm(T):
            continue  # a critical point of I on M (the energy at an equilibrium at rest), to rounding
        res_i = float(np.linalg.norm(w @ A) / (nA * np.linalg.norm(w)))
        if res_i > SYMMETRY_RTOL:
            raise ValueError(f"integrals: {inv.name!r} is not conserved by the linearized dynamics "
                             f"(|dI A| / (|dI| |A|) = {res_i:.3g}); is it a first integral of this system?")
        modes.append(TrivialMode(inv.name, "integral", w, res_i))
        W.append(w)
    Wn = _null_space(np.array(W), A.shape[0]) if W else np.eye(A.shape[0])
    S = _trivial_span(A, nA, Tp, T, syms, gens, Wn, np.array(W).reshape(-1, A.shape[0]), modes)
    lam, vec = np.linalg.eig(A)
    order = np.lexsort((-lam.imag, -lam.real))
    B = None if BF is None else Tp @ BF
    return Linearization(A, B, T, coords, z0, {s.name: float(ck) for s, ck in zip(syms, c)}, lam[order],
                         vec[:, order], tuple(modes), _quotient_eigenvalues(A, S, Wn), res, syms,
                         () if law is None else law.inputs)


def _input_point(law, inputs):
    """The inputs' values ``(m,)`` at the steady motion from ``{name: value}`` (default 0), named errors."""
    inputs = {} if inputs is None else dict(inputs)
    unknown = [k for k in inputs if k not in law.inputs]
    if unknown:
        raise ValueError(f"inputs: {unknown} are not inputs of the force; its inputs are {list(law.inputs)}")
    u0 = np.array([float(inputs.get(k, 0.0)) for k in law.inputs])
    if not np.all(np.isfinite(u0)):
        raise ValueError("inputs: the values at the steady motion contain non-finite numbers")
    return u0


def _off_span(v, S):
    """``v`` minus its least-squares part in the span of the vectors ``S``."""
    if not S:
        return v
    B = np.array(S).T
    return v - B @ np.linalg.lstsq(B, v, rcond=None)[0]


def _trivial_span(A, nA, Tp, T, syms, gens, Wn, W_rows, modes):
    """The trivial invariant subspace ``S`` (list of vectors inside ``ker W``), its modes appended to ``modes``.

    A generator ``a = T^+ xi(z_0)`` joins when ``A a`` lies in the span found so far (``A a = 0`` for a
    symmetry that commutes with the motion's own; in the span of those for a non-commuting one, e.g. the
    rotation of a straight run); then every ``v`` with ``A v`` in ``span S`` (the tangent of the family of
    steady motions through ``z_0``) joins when it lies in ``ker W`` (no integral's gradient accounts for it).
    """
    def in_kerW(v):
        return np.linalg.norm(v - Wn @ (Wn.T @ v)) <= 1e-6 * np.linalg.norm(v)

    S, pending = [], []
    for s, (v, _) in zip(syms, gens):
        a = Tp @ v
        if np.linalg.norm(a) > 0 and np.linalg.norm(T @ a - v) <= 1e-8 * np.linalg.norm(v) and in_kerW(a):
            pending.append((s.name, a))  # nonzero at z_0 and tangent to M
    grown = True
    while grown and pending:
        grown = False
        for k, (name, a) in enumerate(pending):
            r = float(np.linalg.norm(_off_span(A @ a, S)) / (nA * np.linalg.norm(a)))
            if r <= SYMMETRY_RTOL and np.linalg.norm(_off_span(a, S)) > 1e-8 * np.linalg.norm(a):
                modes.append(TrivialMode(name, "symmetry", a, r))
                S.append(a)
                del pending[k]
                grown = True
                break
    grown = bool(S)
    while grown:  # the family: v with A v in span S (a steady motion nearby), in ker W, beyond span S
        grown = False
        B = _null_space(np.array([v / np.linalg.norm(v) for v in S]), A.shape[0])  # S's orthogonal complement
        E = _null_space(B.T @ A, A.shape[0], 1e-12)
        if W_rows.size:
            E = E @ _null_space(W_rows @ E, E.shape[1], 1e-12)
        for v in E.T:
            v = _off_span(v, S)
            if np.linalg.norm(v) > 1e-6:
                r = float(np.linalg.norm(_off_span(A @ v, S)) / (nA * np.linalg.norm(v)))
                modes.append(TrivialMode("the family of steady motions through the state", "family", v, r))
                S.append(v)
                grown = True
    return S


def _quotient_eigenvalues(A, S, Wn):
    """Eigenvalues of ``A`` on ``ker W / span S`` (``Wn``: an orthonormal basis of ``ker W``; both spaces
    ``A``-invariant, ``S`` inside ``ker W``), by decreasing real part."""
    if S:
        coeff = Wn.T @ np.array([v / np.linalg.norm(v) for v in S]).T  # S lies in ker W (a symmetry keeps the integrals): its coordinates in Wn
        N = Wn @ _null_space(coeff.T, Wn.shape[1])
    else:
        N = Wn
    lam = np.linalg.eigvals(N.T @ A @ N) if N.shape[1] else np.zeros(0, complex)
    return lam[np.lexsort((-lam.imag, -lam.real))]


def steady_motion(system, guess, *, symmetries=None, tol=1e-13, max_iter=50):
    r"""A steady motion near ``guess``: Newton (minimum-norm steps) on ``X(z) - sum c_k xi_k(z) = 0``, ``J(z) = 0``
    and the Casimirs held at the guess' values.

    Returns ``(z, rates)`` (``rates``: ``{symmetry name: c_k}``).  The steady motions form families (a spin at
    every rate): the one found is the nearest to ``guess`` along the minimum-norm steps.  Raises
    ``ValueError`` when Newton does not converge.
    """
    z = _reduced_state(system, guess)
    syms = _resolve_symmetries(system, z, symmetries)
    cas = [cs.value_and_grad(z)[0] for cs in system.space.casimirs]
    X, DX, c, r, gens = _steady_rates(system, z, syms)
    for _ in range(max_iter):
        t = _core.evaluate(system, z)
        F = [X - sum((ck * g[0] for ck, g in zip(c, gens)), np.zeros_like(X)), np.asarray(t.J, float).ravel()]
        Jrows = [DX - sum((ck * g[1] for ck, g in zip(c, gens)), np.zeros_like(DX)),
                 np.asarray(t.dJ, float).reshape(-1, z.size)]
        for cs, c0 in zip(system.space.casimirs, cas):
            val, grad = cs.value_and_grad(z)
            F.append(np.atleast_1d(float(val) - float(c0)))
            Jrows.append(np.asarray(grad, float)[None])
        F = np.concatenate(F)
        Jz = np.concatenate(Jrows, 0)
        V = np.stack([g[0] for g in gens], -1) if gens else np.zeros((z.size, 0))
        Jc = np.concatenate([-V, np.zeros((Jz.shape[0] - z.size, V.shape[1]))], 0)
        scale = np.linalg.norm(DX) * np.linalg.norm(z) + np.linalg.norm(X)
        if np.linalg.norm(F) <= tol * max(scale, 1e-300):
            return z, {s.name: float(ck) for s, ck in zip(syms, c)}
        step = np.linalg.lstsq(np.concatenate([Jz, Jc], 1), -F, rcond=None)[0]
        z, c = z + step[:z.size], c + step[z.size:]
        X, DX = field_and_jacobian(system, z)
        gens = [_generator(s, z) for s in syms]
    raise ValueError(f"guess: Newton found no steady motion near it in {max_iter} iterations (residual "
                     f"{np.linalg.norm(F):.3g}); start nearer to one, or pass the symmetries= it uses")


def _system_linearize(self, state, qdot=None, *, u=None, symmetries=None, integrals=None, basis=None, **forcing):
    """The linearized constrained dynamics at a steady motion: :func:`~liefi.integrator.linearize.linearize` ``(self, ...)``.

    ``system.linearize(z)`` (a reduced state, with or without the configuration), or for a system from
    :func:`liefi.from_mechanics` ``system.linearize(q, qdot)`` / ``system.linearize(q, u=u)`` as its
    ``state`` takes them.
    """
    return linearize(self, state, qdot, u=u, symmetries=symmetries, integrals=integrals, basis=basis, **forcing)


# every system gets the method (systems/ may not import the engine whose trace this needs)
NonholonomicSystem.linearize = _system_linearize
