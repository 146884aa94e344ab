r"""Rigid bodies rolling without slipping on a horizontal plane, built from the body's data.

A body is its mass ``m``, its inertia ``I`` about the centre of mass (principal
axes = body axes), gravity ``g`` and its surface, given by the *contact
function* ``r(Gamma)``: the vector, in body axes, from the centre of mass to
the point of the surface whose outward normal is ``-Gamma`` (the point that
touches the plane when the upward vertical seen from the body is ``Gamma``).
:func:`sphere`, :func:`ellipsoid` and :func:`disk` give it for common shapes; a
user may write their own (batch-first, complex-step safe).

The system (what liefi derives from these data)
-----------------------------------------------
Configuration ``(R, x, y) in SO(3) x R^2`` (attitude, horizontal position of
the centre of mass); velocities ``(Omega, u)``, ``Omega`` the body angular
velocity and ``u = (x', y')``.  The height of the centre of mass is fixed by
the contact, ``c_3 = -<Gamma, r(Gamma)>``, so its rate is ``c_3' = <w, Omega>``
with ``w = Gamma x r`` (the surface is tangent to the plane at the contact:
``<Gamma, dr> = 0``).  Hence

.. math::

    T = \tfrac12 \langle \Omega, (I + m\, w w^T) \Omega \rangle + \tfrac m2 |u|^2,
    \qquad U = -m g \langle \Gamma, r(\Gamma) \rangle,

and no slip at the contact, ``v_c + omega x (R r) = 0``, has the horizontal rows

.. math:: u_i + \langle \Omega, r \times \rho_i \rangle = 0, \qquad \rho_i = R^T e_i \quad (i = 1, 2),

(its vertical component is the height's rate above).  The metric and the
potential depend on the attitude through ``Gamma = R^T e_3``, the rows through
``R^T e_1``, ``R^T e_2`` as well: the data are invariant under the horizontal
translations and, together, under rotations about the vertical (``SE(2)``),
but *not* under all of ``SO(3)``.

Which space, which symmetry, and why
------------------------------------
The no-slip rows are kept as constraint momenta ``J_i`` on ``T*(SO(3) x R^2)``
and the data depend on the whole attitude through the advected vector
``(R^T e_1, R^T e_2, R^T e_3)`` in ``V = R^3 x R^3 x R^3`` (three copies of the
rotation block; :class:`liefi.groups.Representation`): the reduced state is
``(rho_1, rho_2, Gamma, Pi, p)`` on ``((so(3) x R^2) x| V)*``, with the
semidirect-product bracket.  This keeps the paper's structure -- ``h~`` and
the ``J_i`` are first integrals of the extended field, it equals the
constrained field on ``C``, ``V`` and the feedback integrator apply, and
extension commutes with reduction (tested) -- at the price of reducing by the
translations only (the ``SE(2)`` symmetry is not used: with the attitude
advected the reduced space still carries it, which a dynamics user also wants
for reconstruction).  Eliminating the rows instead (the Chaplygin ball's
``M' = M x Omega`` in ``(M, Gamma)``) leaves an unconstrained system whose
bracket is not Poisson (no Jacobi identity): no extension theory, no ``J``
for ``V`` to hold at zero.  The contact path is ``(x, y)`` minus the
horizontal part of ``R r``, reconstructed from ``g' = g xi``.

References
----------
Chaplygin, "On a ball's rolling on a horizontal plane", Mat. Sbornik 24 (1903),
transl. Regul. Chaotic Dyn. 7 (2002) 131; Borisov & Mamaev, "Rolling of a rigid
body on plane and sphere. Hierarchy of dynamics", Regul. Chaotic Dyn. 7 (2002) 177;
Bloch, *Nonholonomic Mechanics and Control*, 2nd ed., Sec. 1.7 and 5.8.
"""

from __future__ import annotations

import numpy as np

from .. import _diff, _fingerprint
from .._data import as_float, as_float_array
from .invariant import Invariant
from ..groups import SO3, Representation, Rn
from ..phase_space import LieGroupPhaseSpace
from .system import NonholonomicSystem

#: names of the advected vector ``(R^T e_1, R^T e_2, R^T e_3)``
ATTITUDE_NAMES = ("rho1_1", "rho1_2", "rho1_3", "rho2_1", "rho2_2", "rho2_3", "Gamma_1", "Gamma_2", "Gamma_3")


def _pair(i, j):
    """``<V_i, V_j>`` of the advected copies ``i, j`` (0: ``rho_1``, 1: ``rho_2``, 2: ``Gamma``), with its gradient."""

    def fun(z):
        return sum(z[..., 3 * i + k] * z[..., 3 * j + k] for k in range(3))

    def grad(z):
        zero = 0.0 * z[..., 0]
        g = [zero] * z.shape[-1]
        for k in range(3):
            g[3 * i + k] = g[3 * i + k] + z[..., 3 * j + k]
            g[3 * j + k] = g[3 * j + k] + z[..., 3 * i + k]
        return np.stack(g, -1)

    names = ("rho1", "rho2", "Gamma")
    name = f"|{names[i]}|^2" if i == j else f"{names[i]}.{names[j]}"
    return Invariant(name, _fingerprint.mark(fun, "attitude pair", i, j), _fingerprint.mark(grad, "attitude pair grad", i, j))


#: The six Casimirs ``<rho_i, rho_j>`` of the advected attitude (``|Gamma|^2`` among them): first
#: integrals of every field on :func:`rolling_space` (constraint forces act on the momenta only);
#: penalized in ``V`` they keep the rows of ``R`` orthonormal.
ATTITUDE_CASIMIRS = tuple(_pair(i, j) for i in range(3) for j in range(i, 3))


#: Relative tolerance of the checks of a start (orthonormal attitude rows, no slip at the contact): far
#: above rounding and a long run's drift, far below a mistake.
START_RTOL = 1e-8
#: The largest tangency residual (:func:`tangency_residual`) of a contact function taken for rounding.
TANGENCY_RTOL = 1e-6
#: The range of the body's scales (``m``, the moments of ``I``, ``m L^2``, ``m g L``) in which the mass
#: tensor, its inverse and the potential neither overflow nor underflow in double precision.
SCALE_RANGE = (1e-150, 1e150)
#: The largest ratio of ``m L^2`` to a moment of inertia (or of a moment to ``m L^2``) taken for a rigid
#: body of size ``L``: ``I_k <= m L^2``, and a needle of aspect ``1e6`` has ``I_min ~ 1e-12 m L^2``.
INERTIA_RATIO_MAX = 1e12
#: A radius of curvature this many times the body's size, where the data's derivatives fail, is a flat face.
FLAT_RATIO = 100.0


def _function_name(f):
    return getattr(f, "__qualname__", None) or getattr(f, "__name__", None) or repr(f)


def contact_jacobian(contact, Gamma):
    """``dr/dGamma`` of a contact function by complex step: ``(..., 3, 3)``, ``[..., i, k] = d r_i / d Gamma_k``."""
    _, jac = _diff.probe_jacobian(contact, np.asarray(Gamma, float))  # [..., k, i]
    return np.swapaxes(jac, -1, -2)


def tangency_residual(contact, Gamma):
    r"""How far ``contact`` is from the contact point of a surface at the unit vertical(s) ``Gamma``.

    The plane touches the surface at ``r(Gamma)``, so a tilt ``dGamma`` (tangent to
    the unit sphere: ``P dGamma``, ``P = I - Gamma Gamma^T``) moves the contact
    point along the surface, tangent to the plane,

    .. math:: \Gamma^T \, \frac{\partial r}{\partial \Gamma} \, P = 0,

    the identity behind the height's rate ``c_3' = <Gamma x r, Omega>`` (module
    docstring).  Returns ``|Gamma^T dr P| / |dr P|`` (Frobenius norms; 0 for a
    point contact, ``dr P = 0``): rounding for a surface.
    """
    Gamma = np.asarray(Gamma, float)
    JP = contact_jacobian(contact, Gamma) @ (np.eye(3) - Gamma[..., :, None] * Gamma[..., None, :])
    t = np.linalg.norm(np.einsum("...i,...ik->...k", Gamma, JP), axis=-1)
    scale = np.linalg.norm(JP, axis=(-2, -1))
    return np.where(scale > 0, t / np.where(scale > 0, scale, 1.0), 0.0)


def _check_tangent(contact, Gamma, where):
    """Raise if ``contact`` is no surface's contact point at the unit vertical(s) ``Gamma`` (``(N, 3)``)."""
    res = np.atleast_1d(tangency_residual(contact, Gamma))
    i = int(np.argmax(res))
    if res[i] > TANGENCY_RTOL:
        G = np.atleast_2d(Gamma)[i]
        raise ValueError(
            f"contact: {_function_name(contact)}(Gamma) is not the contact point of any surface: at Gamma = "
            f"{np.round(G, 6).tolist()} ({where}) a tilt moves it off the plane (the tangency "
            f"<Gamma, dr> = 0 fails by {res[i]:.3g} of |dr|; a surface gives ~1e-16). r(Gamma) must be the "
            "point of the body's surface whose outward normal is -Gamma: use liefi.rolling.sphere, ellipsoid "
            "or disk, or for a convex body with support function h, r(Gamma) = grad h(-Gamma)")


def _size(contact, Gamma0):
    """``L``: the largest ``|r|`` over the vertical ``Gamma0`` and ``+-e_k`` (where the contact function is finite)."""
    pts = np.concatenate([Gamma0[None], np.eye(3), -np.eye(3)])
    with np.errstate(all="ignore"):
        try:
            r = np.asarray(contact(pts), float)
            if r.shape != (7, 3):
                raise ValueError
        except Exception:  # noqa: BLE001 -- the user's function: fall back to the sample alone
            r = np.asarray(contact(Gamma0), float)[None]
        n = np.linalg.norm(r, axis=-1)
    n = n[np.isfinite(n)]
    return float(np.max(n)) if n.size else 0.0


def _check_scales(m, moments, g, L):
    """Name a mass, inertia or size whose products overflow, or a mass and inertia no rigid body has."""
    lo, hi = SCALE_RANGE
    mL2 = m * L * L
    for label, v in (("the mass m", m), ("the smallest moment of inertia", moments[0]),
                     ("the largest moment of inertia", moments[-1]), ("m L^2", mL2), ("m g L", m * g * L)):
        if v != 0 and not lo <= v <= hi:
            raise ValueError(
                f"mass, inertia, gravity: {label} = {v:.3g} is outside {lo:.0e} .. {hi:.0e} (L = {L:.3g}, the "
                "body's size from the contact function), where the mass tensor I + m w w^T, its inverse and the "
                "potential m g <Gamma, r> overflow or underflow in double precision; express the body in units "
                "where m, I and the size of r are moderate numbers (e.g. g or t instead of kg, mm or km instead of m)")
    if L > 0:
        ratio = max(mL2 / moments[0], moments[-1] / mL2)
        if ratio > INERTIA_RATIO_MAX:
            raise ValueError(
                f"mass, inertia: m L^2 = {mL2:.3g} (L = {L:.3g}, the body's size from the contact function) and the "
                f"moments of inertia {np.asarray(moments).tolist()} differ by a factor {ratio:.3g}, which no rigid "
                f"body has (its moments are at most m L^2, and a needle a million times longer than thick has "
                f"1e-12 m L^2); check the units of mass, inertia and contact (e.g. kg, kg m^2 and m)")


def rolling_space():
    """``((so(3) x R^2) x| (R^3)^3)*``: ``SO(3) x R^2`` with the whole attitude advected, ``a_0 = (e_1, e_2, e_3)``.

    The space carries :data:`ATTITUDE_CASIMIRS` (``casimirs=``), so a
    :class:`~liefi.FeedbackIntegrator` of a rolling body penalizes them by default.
    """
    G = SO3() * Rn(2)
    rep = Representation(G, block=(0, 3), copies=3, names=ATTITUDE_NAMES)
    return LieGroupPhaseSpace(G, advected=rep, a0=np.eye(3).ravel(), casimirs=ATTITUDE_CASIMIRS)


def _cross(a, b):
    """``a x b`` batch-first without ``np.cross`` (which some traced inputs do not take)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], -1)


def _vector(value, name, size=3):
    v = as_float_array(value, name)
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: expected {size} finite numbers, got {np.shape(value)}")
    return v


def rolling_body(mass, inertia, contact, gravity=9.81, *, sample=None, scaling="unit", check=True):
    """The rolling-without-slipping system of a rigid body on a plane (module docstring).

    Parameters
    ----------
    mass : float
        ``m > 0``.
    inertia : array_like (3,) or (3, 3)
        The inertia about the centre of mass in body axes (principal moments, or
        a symmetric positive definite matrix).
    contact : callable
        ``r(Gamma)``: ``(..., 3) -> (..., 3)``, body-axes vector from the centre of
        mass to the contact point for the upward vertical ``Gamma``; batch-first
        and complex-step safe (:func:`sphere`, :func:`ellipsoid`, :func:`disk`).
    gravity : float
        ``g >= 0`` (along ``-e_3``).
    sample : array_like (3, 3), optional
        An attitude ``R`` at which the data are checked (default the identity;
        give one where the contact function is regular, e.g. a disk standing up).
        There the contact function must be complex-step safe and tangent
        (:func:`tangency_residual`), the surface not degenerate (a flat face);
        the mass, the inertia and the size of ``r`` must be of moderate scale
        (:data:`SCALE_RANGE`, :data:`INERTIA_RATIO_MAX`).
    scaling : {"unit", "orthonormal", None}
        Scaling of the constraint rows, see
        :meth:`NonholonomicSystem.from_velocity_constraints`.

    Returns
    -------
    NonholonomicSystem
        On :func:`rolling_space`, state ``(rho_1, rho_2, Gamma, Pi, p)``, two
        constraints (the horizontal no-slip rows).  Its ``start_check`` refuses a
        :class:`~liefi.FeedbackIntegrator` start that is no state of the body:
        attitude rows not orthonormal, a configuration ``R`` other than the rows,
        a slipping contact, or one where the contact function is no surface's.
    """
    m = as_float(mass, "mass", "a positive number")
    if not np.isfinite(m) or m <= 0:
        raise ValueError(f"mass: expected a positive number, got {mass!r}")
    I = as_float_array(inertia, "inertia")
    if not np.all(np.isfinite(I)):
        what = "NaN" if np.any(np.isnan(I)) else "an infinite number"
        raise ValueError(f"inertia: contains {what} ({I.tolist()}); give 3 finite principal moments or a finite "
                         "3 x 3 matrix")
    if I.shape == (3,):
        I = np.diag(I)
    if I.shape != (3, 3):
        raise ValueError(f"inertia: expected 3 principal moments or a 3 x 3 matrix, got shape {I.shape}")
    asym = float(np.max(np.abs(I - I.T)))
    if asym > 1e-12 * float(np.max(np.abs(I))):
        raise ValueError(f"inertia: not symmetric (max |I - I^T| = {asym:.3g}); the inertia tensor is symmetric, "
                         "e.g. pass (I + I.T) / 2 if that is what you meant")
    moments = np.linalg.eigvalsh(I)
    if moments[0] <= 0:
        raise ValueError(f"inertia: must be positive definite (a rigid body's principal moments about its centre of "
                         f"mass are positive), got the moments {moments.tolist()}")
    g = as_float(gravity, "gravity", "a non-negative number")
    if not np.isfinite(g) or g < 0:
        raise ValueError(f"gravity: expected a non-negative number, got {gravity!r}")
    if not callable(contact):
        raise TypeError(f"contact: expected a function r(Gamma) -> (..., 3), got {contact!r}")
    R0 = np.eye(3) if sample is None else as_float_array(sample, "sample")
    if R0.shape != (3, 3) or not np.allclose(R0.T @ R0, np.eye(3), atol=1e-12):
        raise ValueError("sample: expected a rotation matrix (3 x 3, R^T R = I)")
    with np.errstate(all="ignore"):
        probe = np.asarray(contact(R0[2]))
    if probe.shape != (3,):
        raise ValueError(f"contact: r(Gamma) must return 3 numbers for Gamma of shape (3,), got shape {probe.shape}")
    if not np.all(np.isfinite(probe)):
        raise ValueError(f"contact: r(Gamma) is not finite at Gamma = {R0[2].tolist()} (the attitude sample); "
                         "pass sample= an attitude where the surface is regular (a disk standing on its rim)")
    L = _size(contact, R0[2])
    _check_scales(m, moments, g, L)
    name = _function_name(contact)
    radius = 0.0  # the largest radius of curvature at the sample, |dr P|
    if check:
        try:
            P = np.eye(3) - np.outer(R0[2], R0[2])
            radius = float(np.linalg.norm(contact_jacobian(contact, R0[2]) @ P, 2))
        except (TypeError, ValueError):  # named by the complex-step check below
            pass
        step = 1e-6 * min(1.0, L / radius) if radius > 0 and L > 0 else 1e-6  # differences finer than the surface
        try:
            _diff.check_complex_step(contact, R0[2], f"contact {name}", step=step)
        except ValueError as exc:
            raise ValueError(
                f"contact: {name}(Gamma) is not complex-step safe at Gamma = {R0[2].tolist()} ({exc}). liefi "
                "differentiates r(Gamma) by complex step, so the function must accept complex Gamma and keep its "
                "imaginary part: write |Gamma| as np.sqrt(Gamma @ Gamma) (batch-first: "
                "np.sqrt(np.sum(Gamma * Gamma, -1))) rather than np.linalg.norm or abs(), and use no np.real, "
                "comparisons or float() casts") from exc
        _check_tangent(contact, R0[2], "the attitude sample")

    def r_at(V):
        return np.asarray(contact(V[..., 6:9]))

    def metric(x, V):
        w = _cross(V[..., 6:9], r_at(V))  # c_3' = <w, Omega>
        top = I + m * w[..., :, None] * w[..., None, :]
        batch = top.shape[:-2]
        zero = np.zeros(batch + (3, 2), dtype=top.dtype)
        bottom = np.concatenate([np.zeros(batch + (2, 3), dtype=top.dtype),
                                 np.broadcast_to(m * np.eye(2), batch + (2, 2)).astype(top.dtype)], -1)
        return np.concatenate([np.concatenate([top, zero], -1), bottom], -2)

    def potential(x, V):
        return -m * g * np.einsum("...i,...i->...", V[..., 6:9], r_at(V))

    def rows(x, V):  # u_i + <Omega, r x rho_i> = 0
        r = r_at(V)
        one = 1.0 + 0.0 * r[..., 0]
        zero = 0.0 * r[..., 0]
        r1 = np.concatenate([_cross(r, V[..., 0:3]), np.stack([one, zero], -1)], -1)
        r2 = np.concatenate([_cross(r, V[..., 3:6]), np.stack([zero, one], -1)], -1)
        return np.stack([r1, r2], -2)

    def start_check(y, configuration):  # FeedbackIntegrator's start: a state of this body? (_check_start)
        _check_start(y, configuration, metric, rows, r_at, contact)

    try:
        system = NonholonomicSystem.from_velocity_constraints(
            rolling_space(), metric, rows, potential, scaling=scaling, check=check, sample=attitude_state(R0),
            start_check=start_check)
        # pure data when the contact is liefi's own (sphere, ellipsoid, disk): kernels found without a trace
        return _fingerprint.stamp(system, "rolling_body", m, I, contact, g, R0, scaling, check)
    except ValueError as exc:
        if radius > FLAT_RATIO * L and "complex-step" in str(exc):  # the contact is the only datum the user wrote
            raise ValueError(
                f"contact: the surface of {name} is degenerate at Gamma = {R0[2].tolist()} (the attitude sample): "
                f"its largest radius of curvature there, {radius:.3g}, is {radius / L:.3g} times the body's size "
                f"{L:.3g} -- a nearly flat face, on which the contact point jumps under the slightest tilt, too "
                "stiff to differentiate or integrate. Give the body a rounded surface (e.g. semi-axes within a "
                "factor 1000 of each other), or pass sample= an attitude where it touches the plane on a curved "
                "part") from exc
        raise


def _check_start(y, configuration, metric, rows, r_at, contact):
    """Raise a ``ValueError`` naming what makes ``y`` (a start ``(R, x, y, rho_1, rho_2, Gamma, Pi, p)``, or its
    reduced part without ``configuration``; any batch) no state of the rolling body: attitude rows not
    orthonormal or a reflection, a configuration ``R`` that is not the rows, a slipping contact, a contact
    function that is no surface's at the start (tolerances :data:`START_RTOL`, :data:`TANGENCY_RTOL`)."""
    y = np.asarray(y, float)
    nc = 11 if configuration else 0
    flat = y.reshape(-1, y.shape[-1])
    V = flat[:, nc:nc + 9]
    rows3 = V.reshape(-1, 3, 3)
    def member(i):  # which member of an ensemble
        return "" if y.ndim == 1 else f" (member {tuple(int(k) for k in np.unravel_index(i, y.shape[:-1]))})"
    fix = "pass the rows of a rotation matrix R, or use liefi.rolling.rolling_start(system, R, Omega)"
    off = np.max(np.abs(rows3 @ np.swapaxes(rows3, -1, -2) - np.eye(3)), axis=(-2, -1))
    i = int(np.argmax(off))
    if off[i] > START_RTOL:
        n = np.linalg.norm(rows3[i], axis=-1)
        G = rows3[i] @ rows3[i].T
        raise ValueError(
            f"y0: the attitude rows R^T e1, R^T e2, Gamma are not orthonormal{member(i)} (|rho1| = {n[0]:.6g}, "
            f"|rho2| = {n[1]:.6g}, |Gamma| = {n[2]:.6g}, rho1.rho2 = {G[0, 1]:.3g}, rho1.Gamma = {G[0, 2]:.3g}, "
            f"rho2.Gamma = {G[1, 2]:.3g}); {fix}")
    det = np.linalg.det(rows3)
    if np.any(det < 0):
        i = int(np.argmin(det))
        raise ValueError(f"y0: the attitude rows R^T e1, R^T e2, Gamma form a reflection{member(i)} (det = "
                         f"{det[i]:.3g}), not a rotation; {fix}")
    if nc:
        d = np.max(np.abs(flat[:, :9] - V), axis=-1)
        i = int(np.argmax(d))
        if d[i] > START_RTOL:
            raise ValueError(
                f"y0: the configuration R (the first 9 numbers) and the attitude rows (rho1, rho2, Gamma, numbers "
                f"12-20) differ by {d[i]:.3g}{member(i)}; they are the same matrix R, row by row: {fix}")
    v = np.linalg.solve(metric(None, V), flat[:, nc + 9:nc + 14, None])[..., 0]  # (Omega, u) = m^-1 (Pi, p)
    slip = np.einsum("...kd,...d->...k", rows(None, V), v)  # u_i + <Omega, r x rho_i>: the contact's velocity
    speed = np.linalg.norm(v[:, :3], axis=-1) * np.linalg.norm(r_at(V), axis=-1) + np.linalg.norm(v[:, 3:], axis=-1)
    rel = np.linalg.norm(slip, axis=-1) / np.where(speed > 0, speed, 1.0)
    i = int(np.argmax(rel))
    if rel[i] > START_RTOL:
        raise ValueError(
            f"y0: the contact point slips{member(i)}: its horizontal velocity is {np.round(slip[i], 6).tolist()} "
            f"({rel[i]:.3g} of the body's speed; the no-slip rows u_i + <Omega, r x R^T e_i> = 0 fail). A rolling "
            "body starts rolling without slipping: solve u from Omega with liefi.rolling.rolling_start(system, R, "
            "Omega), or project the momenta onto the no-slip set with system.project(z)")
    _check_tangent(contact, V[:, 6:9], "the start" if y.ndim == 1 else "a member's start")


def attitude_state(R):
    """The advected vector ``(R^T e_1, R^T e_2, R^T e_3)`` = the rows of ``R``, from a rotation matrix."""
    return np.asarray(R, float).reshape(np.shape(R)[:-2] + (9,))


def contact_point(position, attitude, contact):
    r"""The contact point on the plane, from the centre of mass' place and the attitude.

    The contact point is ``c + R r(Gamma)`` (``c`` the centre of mass, ``r`` the
    contact function in body axes); its horizontal components are
    ``e_i . R r = <R^T e_i, r> = <rho_i, r>``, so

    .. math:: (x_c, y_c) = (x, y) + (\langle \rho_1, r(\Gamma) \rangle, \langle \rho_2, r(\Gamma) \rangle).

    Parameters
    ----------
    position : array_like (..., 2)
        ``(x, y)``, the centre of mass' horizontal place (the state's ``r_1, r_2``).
    attitude : array_like (..., 9)
        ``(rho_1, rho_2, Gamma)``, the rows of ``R`` (:data:`ATTITUDE_NAMES`, :func:`attitude_state`).
    contact : callable
        The body's contact function ``r(Gamma)`` (:func:`sphere`, :func:`ellipsoid`, :func:`disk`).

    Returns
    -------
    ndarray (..., 2)
    """
    V = as_float_array(attitude, "attitude")
    c = as_float_array(position, "position")
    if V.shape[-1:] != (9,) or c.shape[-1:] != (2,):
        raise ValueError(f"contact_point: expected position (..., 2) and attitude (..., 9), got {c.shape} and {V.shape}")
    r = np.asarray(contact(V[..., 6:9]), dtype=float)
    return c + np.stack([np.einsum("...i,...i->...", V[..., 0:3], r), np.einsum("...i,...i->...", V[..., 3:6], r)], -1)


def rolling_start(system, R, Omega, position=(0.0, 0.0)):
    """The full start ``(R, x, y, rho_1, rho_2, Gamma, Pi, p)`` of a rolling body on the constraint set.

    ``R``: the attitude (3 x 3), ``Omega``: the body angular velocity; the horizontal
    velocity ``u`` is solved from the no-slip rows and the momenta are ``m (Omega, u)``.
    """
    R = np.asarray(R, float)
    if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-12) or np.linalg.det(R) <= 0:
        raise ValueError("R: expected a rotation matrix (3 x 3, R^T R = I, det R = 1)")
    Omega = _vector(Omega, "Omega")
    position = _vector(position, "position", 2)
    V = attitude_state(R)
    m = np.asarray(system.metric(V), float)
    E = np.asarray(system.constraints(V), float) @ m  # the rows a_i (times their scaling)
    u = np.linalg.solve(E[:, 3:], -E[:, :3] @ Omega)
    P = m @ np.concatenate([Omega, u])
    return np.concatenate([R.ravel(), position, V, P])


# --- contact functions ------------------------------------------------------------------------


def sphere(radius, offset=(0.0, 0.0, 0.0)):
    """``r(Gamma) = -radius Gamma - offset``: a ball whose centre of mass sits at ``offset`` from its centre.

    (``offset`` in body axes; the Chaplygin ball has ``offset = 0``.)  Uses ``|Gamma| = 1``.
    """
    a = as_float(radius, "radius", "a positive number")
    if not np.isfinite(a) or a <= 0:
        raise ValueError(f"radius: expected a positive number, got {radius!r}")
    c = _vector(offset, "offset")

    def r(Gamma):
        return -a * np.asarray(Gamma) + (0.0 * np.asarray(Gamma) - c)

    return _fingerprint.mark(r, "sphere", a, c)


def ellipsoid(semi_axes, offset=(0.0, 0.0, 0.0), rotation=None):
    """Contact function of an ellipsoid: ``r = Q r_s(Q^T Gamma) - offset``, ``r_s(n) = -A^2 n / sqrt(n.A^2 n)``.

    ``semi_axes`` ``(a, b, c)`` along the shape axes, which are rotated by ``Q =
    rotation`` against the body (inertia) axes -- the rattleback's misalignment;
    ``offset``: the centre of mass relative to the ellipsoid's centre, in body axes
    (``(0, 0, -h)`` for a centre of mass a height ``h`` below it).  ``r_s(n)`` is
    the point of ``x.A^-2 x = 1`` whose outward normal is ``-n``.
    """
    A = _vector(semi_axes, "semi_axes")
    if np.any(A <= 0):
        raise ValueError(f"semi_axes: expected three positive numbers, got {semi_axes!r}")
    A2 = A**2
    c = _vector(offset, "offset")
    Q = np.eye(3) if rotation is None else as_float_array(rotation, "rotation")
    if Q.shape != (3, 3) or not np.allclose(Q.T @ Q, np.eye(3), atol=1e-12):
        raise ValueError("rotation: expected a rotation matrix (3 x 3, orthogonal)")

    def r(Gamma):
        n = np.einsum("ji,...j->...i", Q, Gamma)  # Q^T Gamma
        An = A2 * n
        rs = -An / np.sqrt(np.einsum("...i,...i->...", n, An))[..., None]
        return np.einsum("ij,...j->...i", Q, rs) - c

    return _fingerprint.mark(r, "ellipsoid", A, c, Q)


def disk(radius):
    """Contact function of a thin disk in the body's ``e_1 e_2`` plane, centre of mass at its centre.

    ``r(Gamma) = -radius (Gamma - Gamma_3 e_3) / sqrt(Gamma_1^2 + Gamma_2^2)``: the
    lowest point of the rim (singular when the disk lies flat, ``Gamma = +-e_3``).
    """
    a = as_float(radius, "radius", "a positive number")
    if not np.isfinite(a) or a <= 0:
        raise ValueError(f"radius: expected a positive number, got {radius!r}")

    def r(Gamma):
        Gamma = np.asarray(Gamma)
        s = np.sqrt(Gamma[..., 0] ** 2 + Gamma[..., 1] ** 2)
        return -a * np.stack([Gamma[..., 0] / s, Gamma[..., 1] / s, 0.0 * s], -1)

    return _fingerprint.mark(r, "disk", a)
