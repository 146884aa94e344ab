"""The extension of a nonholonomic system, computed from its data (Section 2).

For a system with momentum ``P = (mu, p_x)``, metric ``m(x)``, constraint
vectors ``e_i(x)`` (rows of ``E``), potential ``U(x)`` and vector potential
``A(x)`` (default 0; write ``Pi = P - A(x)``, the kinetic momentum, and
``v = m^{-1} Pi`` the velocity):

* constraint momenta ``J_i = <Pi, e_i>`` (the constraint ``<e_i^flat, v> = 0``
  on velocities), Gram matrix
  ``C^{li} = <e_l^flat, e_i> = (E m E^T)_{li}`` and its inverse ``C_{li}``
  (Remark ``(remark:nonhol:general)``);
* ``h = 1/2 <Pi, m^{-1} Pi> + U`` and the extended Hamiltonian
  ``h~ = h - 1/2 J^T C^{-1} J = h(P - e^flat C^{-1} J)`` (``(def:H:tilde:general)``; with orthonormal
  ``e_i`` this is ``(def:H:tilde)``, ``(def:reduced:h:tilde)``,
  ``(def:reduced:h:tilde:QG:trivial)``);
* multipliers ``lambda = C^{-1} {h, J}`` (``(lambda:general)``) and
  ``lambda~ = C^{-1} {h~, J}`` (``(lambda:tilde:general)``), with the bracket of
  the phase space (canonical, minus Lie--Poisson, or ``(bracket:QG:trivial)``);
* the constrained field ``z' = B dh + sum_i lambda_i e_i^flat`` and the
  extended field ``z' = B dh~ + sum_i lambda~_i e_i^flat``
  (``(bam:qp)``, ``(new:red:bam)``, ``(new:red:bam:QG:trivial)``), and the
  reconstruction ``g' = g . dh~/dmu``.

With ``A``, ``dh/dP = v``, ``dJ_i/dP = e_i`` as before and the ``x``-gradients
gain ``-(dA/dx)^T v`` and ``-(dA/dx)^T e_i``; the proofs that ``h~`` and ``J``
are first integrals of the extended field (``<e_l^flat, dh~/dP> = J_l - (C C^{-1}
J)_l = 0``) and that it equals the constrained field on ``J = 0`` (there
``C^{-1} J = 0``) go through unchanged, since they use only these gradients.

Data that depend on the group element through an advected vector ``Gamma =
g^{-1} . a_0`` (:mod:`liefi.phase_space`, ``advected=``) need nothing here
beyond reading the data at ``y = (x, Gamma)``: ``dh/dGamma``, ``dJ_i/dGamma`` and
``dh~/dGamma`` are formed exactly as the ``x``-gradients (the same terms, the
same complex step), and the semidirect-product bracket turns them into
``Gamma' = -xi . Gamma`` and the diamond term ``Gamma diamond dh~/dGamma`` of
``mu'``.  ``h~`` and ``J_i`` stay first integrals of the extended field and it
still equals the constrained field on ``C``: the proofs above use only that the
Poisson tensor is antisymmetric and that the forces act on the momentum slots.
Why this design: ``Gamma`` enters exactly where ``x`` does (a point at which
the data are read), so one pass, one derivative machinery and the compiled
engine's trace serve both; what is new lives in the bracket, in one place.

Everything is evaluated in one pass by :func:`evaluate`; every ``x``
derivative comes from the data's complex-step (or analytic) derivatives, so
the results are exact to rounding.  Nothing here knows any particular system.

The formulas are written once, for any array type: the numpy path calls them on
float (or complex) arrays, and the compiled engine (:mod:`liefi.engine`) calls
the very same functions on object arrays of traced scalars to generate its
code.  What differs between the two is only how the data are read, which a
*data accessor* says (:class:`NumpyData` here, ``liefi.engine.trace.TracedData``
for tracing).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import _diff, _sparse


class NumpyData:
    """How the formulas read a system's data: numbers, derivatives by complex step.

    A data accessor has three methods; :func:`evaluate`, the feedback field
    (:meth:`liefi.FeedbackIntegrator.field_parts`) and the DLA step take one as
    ``data=``.  This one evaluates the data on float arrays; the compiled engine
    passes one that traces them (``liefi.engine.trace.TracedData``), so both
    backends run the same formulas.
    """

    @staticmethod
    def value(datum, x):
        """``datum(x)`` for a :class:`~liefi._data.DataFunction`."""
        return datum(x)

    @staticmethod
    def value_and_derivative(datum, x):
        """``(datum(x), d datum/dx)`` (derivative ``None`` for a constant datum)."""
        return datum.with_derivative(x)

    @staticmethod
    def value_and_gradient(fun, z, grad=None, name=""):
        """``(fun(z), d fun/dz)`` of a scalar function: ``grad(z)`` if given, else by complex step."""
        if grad is not None:
            return np.asarray(fun(z)), np.asarray(grad(z))
        return _diff.gradient(fun, z)


#: the accessor of the numpy path (the default everywhere)
NUMPY_DATA = NumpyData()

#: Above this many products ``n K D^2`` a state (``dE m``, ``n`` coordinates, ``K`` constraints, ``D`` momenta) the
#: numpy path takes the term ``w^T dC w`` of ``d ht / dx`` as ``(w^T dE_k) . (m E^T w)`` (``n K D``); every scene
#: of liefi is far below it and keeps the dense products (bit-identical results).
_DENSE_DC_PRODUCTS = 10**6


def is_traced(a) -> bool:
    """Whether ``a`` is an array of traced scalars (object dtype): then no float casts apply."""
    return isinstance(a, np.ndarray) and a.dtype == object


def as_real(a):
    """``a`` as a float array, or unchanged when it is traced (object dtype) or complex (a complex step
    through liefi's functions, which :func:`evaluate` allows where the data do not depend on ``x``)."""
    a = np.asarray(a)
    return a if a.dtype == object or np.iscomplexobj(a) else a.astype(float, copy=False)


@dataclass(frozen=True)
class Terms:
    """Everything the extension needs at a batch of reduced states ``z``.

    Shapes: batch ``...``; ``nz`` state size, ``D`` momentum size, ``K`` constraints.
    """

    h: np.ndarray  #: (...,) original Hamiltonian
    ht: np.ndarray  #: (...,) extended Hamiltonian h~
    J: np.ndarray  #: (..., K) constraint momenta <P, e_i>
    dh: np.ndarray  #: (..., nz) gradient of h
    dht: np.ndarray  #: (..., nz) gradient of h~
    dJ: np.ndarray  #: (..., K, nz) gradients of J_i
    Eflat: np.ndarray  #: (..., K, D) e_i^flat = m e_i (rows)
    Cinv: np.ndarray  #: (..., K, K) inverse Gram matrix


def _state(z):
    """``z`` as a float array, or kept complex (for a complex step through liefi's functions)."""
    z = np.asarray(z)
    return z if z.dtype == object or np.iscomplexobj(z) else z.astype(float, copy=False)


def small_inverse(C):
    """Inverse of a batch of small matrices; closed forms for 1x1 and 2x2 (the common K).

    ``np.linalg.inv`` costs ~20 us of overhead per call, more than the rest of a
    step of a small system; the closed forms are exact to rounding.  (While the
    compiled engine traces, ``np.linalg.inv`` accepts traced matrices.)
    """
    K = C.shape[-1]
    if K == 0:
        return C
    if K == 1:
        return 1.0 / C
    if K == 2:
        a, b, c, d = C[..., 0, 0], C[..., 0, 1], C[..., 1, 0], C[..., 1, 1]
        det = a * d - b * c
        return np.stack([np.stack([d, -b], -1), np.stack([-c, a], -1)], -2) / det[..., None, None]
    return np.linalg.inv(C)


def evaluate(system, z, *, data=NUMPY_DATA, derivatives=True) -> Terms:
    """Compute :class:`Terms` at the reduced states ``z`` (shape ``(..., nz)``).

    ``derivatives=False``: the values ``h``, ``h~``, ``J`` (and ``Eflat``, ``Cinv``) only,
    without differentiating the data; the gradients ``dh``, ``dht``, ``dJ`` are then ``None``.

    ``data``: the data accessor (:class:`NumpyData`, or the engine's tracing one
    when ``z`` holds traced scalars).  The constant parts (``m^{-1}`` of a
    constant metric, ``e_i^flat`` and ``C^{-1}`` of constant data) are the
    system's cached :attr:`~liefi.NonholonomicSystem.metric_inverse`,
    :attr:`~liefi.NonholonomicSystem.flat_constraints` and
    :attr:`~liefi.NonholonomicSystem.gram_inverse`.
    """
    sp = system.space
    # n: the data point y = (x, Gamma) (Gamma: the advected vector, if any); the data
    # and their derivatives are read there, and dh/dy, dJ/dy, dh~/dy below are the
    # gradients in the first n slots of z (the bracket then gives the diamond term).
    n, d, D, K = sp.data_dim, sp.d, sp.D, system.K
    z = np.asarray(z)
    if np.iscomplexobj(z):
        # A complex step through liefi's own functions (e.g. an Invariant built from
        # system.extended_hamiltonian): exact when the data do not depend on x; with
        # x-dependent data it would nest two complex steps, which is not exact (unless
        # every x-dependent datum carries its analytic derivative: then nothing is nested).
        data_ = (system.metric, system.constraints, system.potential, system.vector_potential)
        if n and not all(f is None or f.constant or getattr(f, "_derivative", None) is not None for f in data_):
            raise TypeError(
                "z: complex input (a complex step through liefi's functions) is supported "
                "only for systems whose data do not depend on x or carry analytic derivatives "
                "(metric_derivative=, constraints_derivative=, ...); give the Invariant an "
                "explicit grad= instead"
            )
    elif z.dtype != object:
        z = z.astype(float, copy=False)
    x, P = z[..., :n], z[..., n : n + D]  # (a forced run's state carries W and the clock after P)
    batch = z.shape[:-1]

    def read(datum):
        return data.value_and_derivative(datum, x) if derivatives else (data.value(datum, x), None)

    m, dm = read(system.metric)
    E, dE = read(system.constraints)
    U, dU = read(system.potential)
    # Vector potential: h = 1/2 <P - A, m^{-1}(P - A)> + U and J = <P - A, e_i>; every
    # formula below is in the kinetic momentum Pi = P - A(x), plus the x-derivative
    # terms -dA^T v in dh/dx and -dA^T e_i in dJ_i/dx (added where those are formed).
    Pi, dA = P, None
    if system.vector_potential is not None:
        A, dA = read(system.vector_potential)
        Pi = P - A
    if system.metric.constant:
        minv = system.metric_inverse
    else:
        minv = small_inverse(m)
    if system.constant:
        Eflat, Cinv = system.flat_constraints, system.gram_inverse
    else:
        Eflat = _sparse.matmul(E, m)  # traced: the nonzero terms only (liefi._sparse), else E @ m
        Cinv = small_inverse(_sparse.matmul(Eflat, np.swapaxes(E, -1, -2)))

    # (traced: sums over the nonzero terms only, the same expressions, liefi._sparse)
    v = _sparse.matvec("...ij,...j->...i", minv, Pi)  # dh/dP = (P - A)^sharp, the velocity
    J = _sparse.matvec("...ij,...j->...i", E, Pi)
    w = _sparse.matvec("...ij,...j->...i", Cinv, J)  # C^{-1} J
    dht_dP = v - _sparse.matvec("...ji,...j->...i", E, w)
    h = 0.5 * np.einsum("...i,...i->...", Pi, v) + U
    ht = h - 0.5 * np.einsum("...k,...k->...", J, w)
    if not derivatives:
        return Terms(h, ht, J, None, None, None, np.broadcast_to(Eflat, batch + (K, D)), Cinv)

    dh_dx = np.zeros(batch + (n,))
    dJ_dx = np.zeros(batch + (n, K))
    dht_dx = np.zeros(batch + (n,))
    if n:
        if dU is not None:
            dh_dx = dh_dx + dU
        if dm is not None:
            dh_dx = dh_dx - 0.5 * np.einsum("...i,...kij,...j->...k", v, dm, v)
        if dA is not None:
            dh_dx = dh_dx - np.einsum("...kj,...j->...k", dA, v)
            dJ_dx = dJ_dx - np.einsum("...kj,...ij->...ki", dA, E)
        dht_dx = dh_dx
        if K:
            Et = np.swapaxes(E, -1, -2)
            dC = 0.0
            if dE is not None:
                # traced: dE's exact zeros found once for its two products (a chain's dE is (3N, N, 3N))
                zE = (_sparse.exact_zeros(dE), None) if is_traced(dE) else None
                if is_traced(dE) or is_traced(Pi):  # the same sums over the nonzero terms (liefi._sparse)
                    dJ_dx = dJ_dx + _sparse.matmul(dE, Pi[..., None, :, None], zeros=zE)[..., 0]
                else:
                    dJ_dx = dJ_dx + np.einsum("...kij,...j->...ki", dE, Pi)
                if not (is_traced(dE) or is_traced(m) or is_traced(w)) and n * K * D * D > _DENSE_DC_PRODUCTS:
                    # 0.5 w^T (dE_k m E^T + E m dE_k^T) w = (w^T dE_k) . (m E^T w): n K D products, not the
                    # n K D^2 of dE m (a chain of 64 knife edges: 2e6 against 5e8 a state)
                    u = np.einsum("...de,...e->...d", m, np.einsum("...id,...i->...d", E, w))
                    dht_dx = dht_dx + np.einsum("...kd,...d->...k", np.einsum("...i,...kid->...kd", w, dE), u)
                else:
                    if zE is None:
                        dC = _sparse.matmul(_sparse.matmul(dE, m[..., None, :, :]), Et[..., None, :, :])
                    else:
                        dEm = _sparse.matmul_rows(dE, m[..., None, :, :], zeros=zE)  # its nonzeros only
                        dC = _sparse.matmul(dEm, Et[..., None, :, :])
                    dC = _sparse.symmetrized(dC)  # traced: the nonzero sums only (liefi._sparse)
            if dm is not None:
                dC = dC + _sparse.matmul(_sparse.matmul(E[..., None, :, :], dm), Et[..., None, :, :])
            dht_dx = dht_dx - _sparse.matvec("...ij,...j->...i", dJ_dx, w)
            if not np.isscalar(dC):
                dht_dx = dht_dx + 0.5 * _sparse.quadratic(w, dC)

    dh = np.concatenate([dh_dx, np.broadcast_to(v, batch + (D,))], -1)
    dht = np.concatenate([dht_dx, np.broadcast_to(dht_dP, batch + (D,))], -1)
    dJ = np.concatenate(
        [np.swapaxes(dJ_dx, -1, -2), np.broadcast_to(E, batch + (K, D))], -1
    )
    return Terms(h, ht, J, dh, dht, dJ, np.broadcast_to(Eflat, batch + (K, D)), Cinv)


def _multipliers(system, z, dH, dJ, Cinv):
    """``C^{-1} {H, J}`` for the Hamiltonian with gradient ``dH``."""
    b = system.space.bracket(z[..., None, :], dH[..., None, :], dJ)  # (..., K)
    return np.einsum("...lk,...l->...k", Cinv, b)


def _field(system, z, dH, lam, Eflat):
    """``B dH + sum_i lam_i e_i^flat`` (the force acts on the momentum slot only)."""
    n = system.space.data_dim
    f = system.space.hamiltonian_vector_field(z, dH)
    if system.K:
        if is_traced(lam) or is_traced(Eflat):  # the same sums over the nonzero terms (liefi._sparse)
            force = _sparse.matvec("...ji,...j->...i", Eflat, lam)
        else:
            force = np.einsum("...k,...kj->...j", lam, Eflat)
        f = np.concatenate([f[..., :n], f[..., n:] + force], -1)
    return f


# --- public functional API -------------------------------------------------------


def hamiltonian(system, z):
    """The original (reduced) Hamiltonian ``h = 1/2 <P - A, m^{-1} (P - A)> + U``."""
    return evaluate(system, z).h


def extended_hamiltonian(system, z):
    """``h~ = h - 1/2 sum_ij <P, e_i> C_ij <P, e_j>`` (``(def:H:tilde:general)``)."""
    return evaluate(system, z).ht


def constraint_momenta(system, z):
    """``J_i = <P - A(x), e_i(x)>``, shape ``(..., K)``; the constraint set is ``J = 0``."""
    return evaluate(system, z).J


def gram_matrix(system, x):
    """``C^{li} = <e_l^flat, e_i> = (E m E^T)_{li}`` at data points ``x`` (shape points, and ``Gamma`` if advected)."""
    E = system.constraints(x)
    return E @ system.metric(x) @ np.swapaxes(E, -1, -2)


def multipliers(system, z):
    """``lambda_i = sum_l {h, J_l} C_{li}`` (``(lambda:general)``, ``(red:lambda)``, ``(def:lambda:QG:trivial)``)."""
    t = evaluate(system, z)
    return _multipliers(system, _state(z), t.dh, t.dJ, t.Cinv)


def extended_multipliers(system, z):
    """``lambda~_i = sum_l {h~, J_l} C_{li}`` (``(lambda:tilde:general)``, ``(def:reduced:lambda:tilde)``)."""
    t = evaluate(system, z)
    return _multipliers(system, _state(z), t.dht, t.dJ, t.Cinv)


def constrained_vector_field(system, z):
    """The constrained field ``(original:nonholo)`` (meaningful on ``J = 0``), reduced."""
    z = _state(z)
    t = evaluate(system, z)
    lam = _multipliers(system, z, t.dh, t.dJ, t.Cinv)
    return _field(system, z, t.dh, lam, t.Eflat)


def extended_vector_field(system, z):
    """The extended field ``(bam:qp)`` / ``(new:red:bam)`` / ``(new:red:bam:QG:trivial)``, reduced.

    Defined on the whole phase space; ``h~``, every ``J_i`` and ``h`` are first
    integrals of it, and it equals the constrained field on ``J = 0``.
    """
    z = _state(z)
    t = evaluate(system, z)
    lam = _multipliers(system, z, t.dht, t.dJ, t.Cinv)
    return _field(system, z, t.dht, lam, t.Eflat)


def project(system, z):
    """Project ``z`` onto the constraint set along ``m``: ``P -> P - sum_ij J_i C_ij e_j^flat``.

    The closest point of ``{J = 0}`` in the kinetic-energy norm ``<P, m^{-1} P>``
    (at fixed ``x``).
    """
    z = _state(z)
    return _project_with(system, z, evaluate(system, z))


def _project_with(system, z, t):
    """:func:`project` from the terms ``t = evaluate(system, z)`` already at hand."""
    if not system.K:
        return z
    n = system.space.data_dim
    D = system.space.D
    w = np.einsum("...kl,...l->...k", t.Cinv, t.J)
    P = z[..., n : n + D] - np.einsum("...k,...kj->...j", w, t.Eflat)
    return np.concatenate([z[..., :n], P, z[..., n + D :]], -1)


def field_terms(system, z, *, kind="extended", terms=None, data=NUMPY_DATA, force=None):
    """The reduced field and the body velocity in one pass: ``(zdot, xi, t_z)``.

    ``kind``: ``"extended"``, ``"constrained"`` or ``"projected"`` (the extended
    field at :func:`project` ``(z)``).  ``t_z`` are the terms *at z* (what a
    Lyapunov function needs), so a caller evaluates the system once for the
    extended field and twice for the projected one.  ``terms``: ``evaluate(system, z)``
    if the caller already has it; ``data``: the accessor passed to :func:`evaluate`.

    ``force``: an external generalized force ``F`` (``(..., D)``, a covector on the
    velocities ``v = (xi, x')``, acting on the momentum slots; not with
    ``kind="projected"``), the one place where a force enters the field.  Lagrange--d'Alembert with
    a force: ``z' = B dH + sum_i lambda_i e_i^flat + (0, F)`` with the multipliers
    chosen so that the ``J_i`` stay first integrals,
    ``lambda = C^{-1} ({H, J} - E F)``: the force acts through its projection
    ``F - E^flat^T C^{-1} E F`` onto the annihilator of the constraint forces, and
    ``dh~/dt = <dh~/dP, F>`` exactly (``E^flat dh~/dP = J - C C^{-1} J = 0``), the
    power ``F . v`` on the constraint set (:mod:`liefi.integrator.forced`).
    """
    if kind not in ("extended", "constrained", "projected"):
        raise ValueError(f"kind: expected 'extended', 'constrained' or 'projected', got {kind!r}")
    t_z = evaluate(system, z, data=data) if terms is None else terms
    if kind == "projected":
        z_eval = _project_with(system, z, t_z)
        t = evaluate(system, z_eval, data=data)
    else:
        z_eval, t = z, t_z
    dH = t.dh if kind == "constrained" else t.dht
    lam = _multipliers(system, z_eval, dH, t.dJ, t.Cinv)
    if force is not None:
        if kind == "projected":
            raise ValueError("force: not with the projected field (the force is read at z); use 'extended'")
        if system.K:  # lambda = C^{-1} ({H, J} - E F): the J_i stay first integrals
            EF = _sparse.matvec("...ij,...j->...i", t.dJ[..., system.space.data_dim :], force)
            lam = lam - _sparse.matvec("...ij,...j->...i", t.Cinv, EF)
    zdot = _field(system, z_eval, dH, lam, t.Eflat)
    n, d = system.space.data_dim, system.space.d
    if force is not None:
        zdot = np.concatenate([zdot[..., :n], zdot[..., n:] + force], -1)
    return zdot, dH[..., n : n + d], t_z


def projected_vector_field(system, z):
    """The extended field evaluated at :func:`project` ``(z)``.

    Another extension of the constrained field off ``J = 0`` (it agrees with
    it on the constraint set).  For systems whose constrained momenta are
    constant it is the paper's "further extension" ``(further:extended:eqn:vertical:disk)``
    derived rather than substituted by hand: every momentum is then a first
    integral.
    """
    return extended_vector_field(system, project(system, z))


def group_velocity(system, z, *, extended=True):
    """``xi = dh~/dmu`` (or ``dh/dmu``): the body velocity in ``g' = g . xi``."""
    t = evaluate(system, z)
    n, d = system.space.data_dim, system.space.d
    return (t.dht if extended else t.dh)[..., n : n + d]


def reconstruction(system, g, z, *, extended=True):
    """Rate of the group's stored numbers, ``g' = g . dh~/dmu`` (``(new:red:g)``)."""
    return system.space.group.config_rate(g, group_velocity(system, z, extended=extended))


def poisson_bracket(system, z, df, dg):
    """The reduced phase space's bracket ``{f, g}(z)`` from gradients (see :mod:`liefi.phase_space`)."""
    return system.space.bracket(z, df, dg)


def full_vector_field(system, y, *, kind="extended", data=NUMPY_DATA):
    """The field on ``y = (g, z)``: reconstruction of the group element plus the reduced field.

    ``kind`` is ``"extended"`` (``g' = g . dh~/dmu`` with the extended field),
    ``"constrained"`` (``g' = g . dh/dmu`` with the constrained field) or
    ``"projected"``.  ``data``: the accessor passed to :func:`evaluate`.
    """
    y = _state(y)
    nc = system.space.group.config_dim
    g, z = y[..., :nc], y[..., nc:]
    zdot, xi, _ = field_terms(system, z, kind=kind, data=data)
    gdot = system.space.group.config_rate(g, xi)
    return np.concatenate([np.broadcast_to(gdot, zdot.shape[:-1] + gdot.shape[-1:]), zdot], -1)
