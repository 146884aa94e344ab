"""Exact solutions of the constrained (nonholonomic) dynamics of the paper's examples.

Every function here is a pure, vectorised numpy function of the time array
``t`` and of the physical parameters, and returns a ``dict`` mapping the name of
a state component to an array of the same shape as ``t``.  Only the dynamics *on
the constraint set* is solved (the true nonholonomic motion); the initial data
must lie on that set, and the functions raise :class:`ValueError` otherwise.

Components without a closed form are left out rather than approximated:

* Suslov problem: ``R(t)`` (see :func:`suslov`);
* Chaplygin sleigh: ``x(t), y(t)`` (see :func:`chaplygin`);
* nonholonomic oscillator: everything but the ``y`` subsystem.

The formulas are written without subtractive cancellation (``sinc``-type
functions instead of ``(sin(w t + a) - sin a) / w``), so the limits
``omega -> 0`` (knife edge, vertical disk) and ``a -> 0`` (Chaplygin sleigh)
are exact and need no special-casing by the caller.

Conventions follow the paper (Chang & Perlmutter, arXiv:1811.03757) and ``docs/paper_notes.md``:
se(2)* coordinates ``(Pi_theta, Pi_x, Pi_y) = (p_theta, p_x cos th + p_y sin th,
-p_x sin th + p_y cos th)``.  The knife-edge formula corrects slip 1 of
``docs/paper_notes.md`` (the paper prints ``x = 1 - cos t``, ``phi = t``).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "suslov",
    "knife_edge",
    "chaplygin",
    "vertical_disk",
    "heisenberg",
    "oscillator_y",
    "kepler",
]

#: Absolute tolerance (relative to the size of the data) used to decide whether
#: initial data lie on the constraint set.
_CONSTRAINT_TOL = 1e-9


# ----------------------------------------------------------------------------
# cancellation-free elementary helpers
# ----------------------------------------------------------------------------

def _sinc(u):
    """``sin(u) / u`` with the value 1 at ``u = 0`` (``np.sinc`` is normalised)."""
    return np.sinc(np.asarray(u, dtype=float) / np.pi)


def _u_minus_sin_over_u3(u):
    """``(u - sin u) / u**3``, accurate for all ``u`` (limit 1/6 at 0)."""
    u = np.asarray(u, dtype=float)
    u2 = u * u
    # Taylor series sum_{k>=0} (-1)^k u^(2k) / (2k+3)!, truncated at u^10;
    # for |u| < 0.5 the next term is < 2e-16 relative.
    series = (1.0 / 6.0 + u2 * (-1.0 / 120.0 + u2 * (1.0 / 5040.0 + u2 * (
        -1.0 / 362880.0 + u2 * (1.0 / 39916800.0 + u2 * (-1.0 / 6227020800.0))))))
    small = np.abs(u) < 0.5
    safe = np.where(small, 1.0, u)
    direct = (safe - np.sin(safe)) / safe**3
    return np.where(small, series, direct)


def _sech(s):
    """``1 / cosh(s)`` without overflow for large ``|s|``."""
    e = np.exp(-np.abs(np.asarray(s, dtype=float)))
    return 2.0 * e / (1.0 + e * e)


def _gd(s):
    """Gudermannian ``gd(s) = arctan(sinh s) = 2 arctan(tanh(s/2))``."""
    return 2.0 * np.arctan(np.tanh(0.5 * np.asarray(s, dtype=float)))


def _gd_difference(w, d):
    """``gd(w + d) - gd(w)`` without cancellation when ``d`` is small.

    With ``A = sinh(w + d)``, ``B = sinh(w)`` one has exactly
    ``gd(w + d) - gd(w) = atan2(A - B, 1 + A B)`` (both arctangents lie in
    ``(-pi/2, pi/2)``).  Both arguments are multiplied by the positive number
    ``sech(w + d) sech(w)`` to keep them bounded, and
    ``A - B = 2 cosh(w + d/2) sinh(d/2)``.  Used for ``|d| < 1``; elsewhere the
    plain difference has no cancellation worth the name.
    """
    w = np.asarray(w, dtype=float)
    d = np.asarray(d, dtype=float)
    u = w + d
    s = w + 0.5 * d
    # cosh(s) sech(u) sech(w), written with exp(-|.|) so nothing overflows
    # (|s| <= (|u| + |w|) / 2, so the exponent is <= 0).
    eu, ew, es = np.exp(-2 * np.abs(u)), np.exp(-2 * np.abs(w)), np.exp(-2 * np.abs(s))
    ratio = 2.0 * np.exp(np.abs(s) - np.abs(u) - np.abs(w)) * (1 + es) / ((1 + eu) * (1 + ew))
    small = np.abs(d) < 1.0
    dh = np.where(small, 0.5 * d, 0.0)
    num = 2.0 * np.sinh(dh) * ratio
    den = _sech(u) * _sech(w) + np.tanh(u) * np.tanh(w)
    careful = np.arctan2(num, den)
    return np.where(small, careful, _gd(u) - _gd(w))


def _as_time(t):
    return np.asarray(t, dtype=float)


def _check(residual, scale, what):
    if not abs(residual) <= _CONSTRAINT_TOL * (1.0 + scale):
        raise ValueError(f"initial data are not on the constraint set: {what} = {residual!r}")


# ----------------------------------------------------------------------------
# Suslov problem
# ----------------------------------------------------------------------------

def suslov(t, Pi0=(0.0, 1.0, 1.0)):
    r"""Body momentum of the Suslov problem with the paper's inertia tensor.

    Data of the paper (Sec. "The Suslov Problem on SO(3)"):
    ``II = [[1, 0, 0], [0, 1, 1], [0, 1, 2]]``, ``a = (0, 0, 1)``,
    ``e = II^{-1} a / sqrt(a . II^{-1} a)``.  The default ``Pi0 = (0, 1, 1)``
    gives the printed solution

    .. math:: \Pi_1 = -\tanh t, \qquad \Pi_2 = \Pi_3 = \operatorname{sech} t .

    Parameters
    ----------
    t : array_like
        Times.
    Pi0 : array_like, shape (3,)
        ``Pi(0)``; must satisfy the constraint ``Pi . e = 0``, i.e.
        ``Pi0[1] == Pi0[2]``.

    Returns
    -------
    dict
        ``"Pi_1", "Pi_2", "Pi_3"``: arrays shaped like ``t``.

    Raises
    ------
    ValueError
        If ``Pi0`` violates the constraint.

    Notes
    -----
    ``II^{-1} = [[1, 0, 0], [0, 2, -1], [0, -1, 1]]``, so ``II^{-1} a = (0, -1, 1)``,
    ``a . II^{-1} a = 1``, ``e = (0, -1, 1)`` and ``II e = a``.  The constraint
    ``Pi . e = 0`` is ``Pi_2 = Pi_3 =: P``; then ``Omega = II^{-1} Pi =
    (Pi_1, P, 0)`` (the Suslov condition ``Omega_3 = 0``) and

    .. math:: \Pi \times \Omega = (-P^2,\ \Pi_1 P,\ 0),

    so ``Pi' = Pi x Omega + lambda a`` reduces to ``Pi_1' = -P^2``,
    ``P' = Pi_1 P`` (with ``lambda = Pi_1 P`` keeping ``Pi_3 = Pi_2``).  The
    energy ``h = (Pi_1^2 + P^2) / 2`` is conserved; with ``c = sqrt(2 h)``,
    ``Pi_1' = Pi_1^2 - c^2`` gives

    .. math:: \Pi_1 = -c \tanh(c t + \tau_0), \qquad
              P = \sigma c \operatorname{sech}(c t + \tau_0),

    with ``sigma = sign(P(0))`` and ``sinh(tau_0) = -Pi_1(0) / |P(0)|``.  If
    ``P(0) = 0`` the state is an equilibrium.

    The attitude has no elementary closed form, so ``R`` is not returned.  For
    the default data ``Omega = (-tanh t, sech t, 0) = Rz(beta) e_1`` is a unit
    vector turning about the body axis ``e_3`` with ``beta = pi/2 + gd(t)``,
    ``beta' = sech t``.  Writing ``R = S Rz(beta)^T`` gives
    ``S' = S (e_1 + sech(t) e_3)^``: a body angular velocity of *non-fixed*
    direction, so ``R`` is not a rotation about a fixed axis (numerically the
    spatial angular velocity ``R Omega`` changes direction too).  The SU(2)
    lift of that equation is a two-level problem with constant detuning and a
    ``sech`` pulse (Rosen--Zener type), solvable only through hypergeometric
    functions with complex parameters.
    """
    t = _as_time(t)
    P10, P20, P30 = (float(v) for v in np.asarray(Pi0, dtype=float).reshape(3))
    _check(P30 - P20, abs(P20) + abs(P30), "Pi_3 - Pi_2")
    c = np.hypot(P10, P20)
    if P20 == 0.0:
        # Equilibrium: Pi_1' = -P^2 = 0, P' = Pi_1 P = 0.
        P1 = np.full_like(t, P10)
        P = np.zeros_like(t)
    else:
        sigma = np.sign(P20)
        tau0 = np.arcsinh(-P10 / abs(P20))
        s = c * t + tau0
        P1 = -c * np.tanh(s)
        P = sigma * c * _sech(s)
    return {"Pi_1": P1, "Pi_2": P, "Pi_3": P.copy()}


# ----------------------------------------------------------------------------
# knife edge on an inclined plane
# ----------------------------------------------------------------------------

def knife_edge(t, m=1.0, J=1.0, g=1.0, alpha=np.pi / 6, p_phi0=0.5,
               x0=0.0, y0=0.0, phi0=0.0, v0=0.0):
    r"""Knife edge on an inclined plane (Bloch, Sec. 1.6), closed form.

    Hamiltonian ``H = (p_x^2 + p_y^2)/(2m) + p_phi^2/(2J) - m g x sin(alpha)``,
    constraint ``p_x sin(phi) - p_y cos(phi) = 0`` (velocity along the blade
    ``(cos phi, sin phi)``).  The start is ``(x0, y0, phi0)`` with momentum
    ``p = (m v0 cos phi0, m v0 sin phi0, p_phi0)``; ``v0`` is the initial speed
    along the blade, so every start on the constraint set is covered.

    With the paper's data (``m = J = g = 1``, ``alpha = pi/6``,
    ``p_phi0 = 1/2``, everything else zero) the solution is

    .. math:: x = \tfrac12 (1 - \cos t), \quad y = \tfrac12 (t - \sin t),
              \quad \varphi = t / 2,

    which corrects the printed ``x = 1 - cos t``, ``phi = t`` (docs/paper_notes.md item 1).

    Parameters
    ----------
    t : array_like
        Times.
    m, J, g, alpha : float
        Mass, moment of inertia about the vertical axis, gravity, inclination.
    p_phi0 : float
        Angular momentum ``p_phi`` (conserved).
    x0, y0, phi0, v0 : float
        Initial position, blade angle and along-blade speed.

    Returns
    -------
    dict
        ``"x", "y", "phi", "p_x", "p_y", "p_phi"``, arrays shaped like ``t``.

    Notes
    -----
    The constraint force is normal to the blade and has no torque, so
    ``p_phi`` is constant and ``phi = phi0 + omega t``, ``omega = p_phi0 / J``.
    Along the blade only gravity ``(m G, 0)``, ``G = g sin(alpha)``, acts:
    ``v' = G cos(phi)``.  With

    .. math:: C(t) = \int_0^t \cos\varphi\,ds
                   = t \cos(\varphi_0 + \omega t/2)\,\operatorname{sinc}(\omega t/2),
              \qquad
              S(t) = \int_0^t \sin\varphi\,ds
                   = t \sin(\varphi_0 + \omega t/2)\,\operatorname{sinc}(\omega t/2)

    (``sinc u = sin(u)/u``) one has ``v = v0 + G C`` and, since
    ``x' = v cos(phi) = v0 C' + G C C'``,

    .. math:: x = x_0 + v_0 C + \tfrac{G}{2} C^2 .

    For ``y' = v0 S' + G C S'`` use ``C S' - S C' = 1 - cos(omega s)``:

    .. math:: y = y_0 + v_0 S + \tfrac{G}{2}\Big(C S + W\Big), \qquad
              W = \int_0^t (1 - \cos\omega s)\,ds = \frac{\omega t - \sin\omega t}{\omega^2}
                = \omega t^3 f(\omega t),

    with ``f(u) = (u - sin u)/u^3`` (evaluated by its series near 0).  For
    ``phi0 = v0 = 0`` this is the familiar cycloid
    ``x = G (1 - cos 2 omega t) / (4 omega^2)``,
    ``y = G (2 omega t - sin 2 omega t) / (4 omega^2)``, and for ``omega = 0``
    uniform acceleration along the fixed blade.  The momenta are
    ``p_x = m v cos(phi)``, ``p_y = m v sin(phi)``, ``p_phi = p_phi0``.  The
    energy ``m v^2/2 + p_phi^2/(2J) - m G x`` is conserved since
    ``(v^2/2)' = G v cos(phi) = G x'``.
    """
    t = _as_time(t)
    G = g * np.sin(alpha)
    omega = p_phi0 / J
    phi = phi0 + omega * t
    half = phi0 + 0.5 * omega * t
    sc = t * _sinc(0.5 * omega * t)
    C = np.cos(half) * sc
    S = np.sin(half) * sc
    W = omega * t**3 * _u_minus_sin_over_u3(omega * t)
    x = x0 + v0 * C + 0.5 * G * C * C
    y = y0 + v0 * S + 0.5 * G * (C * S + W)
    v = v0 + G * C
    return {
        "x": x,
        "y": y,
        "phi": phi,
        "p_x": m * v * np.cos(phi),
        "p_y": m * v * np.sin(phi),
        "p_phi": np.full_like(t, float(p_phi0)),
    }


# ----------------------------------------------------------------------------
# Chaplygin sleigh
# ----------------------------------------------------------------------------

def chaplygin(t, m, I, a, theta0, Pi0):
    r"""Chaplygin sleigh on SE(2): heading and reduced momenta in closed form.

    Paper Sec. "The Chaplygin Sleigh": ``(x, y)`` is the contact point of the
    blade, ``a`` the distance from it to the centre of mass, ``I`` the moment of
    inertia about the centre of mass.  Reduced momenta
    ``Pi = (Pi_theta, Pi_x, Pi_y)``; constraint
    ``m a Pi_theta - (I + m a^2) Pi_y = 0``.

    Parameters
    ----------
    t : array_like
        Times.
    m, I, a : float
        Mass, moment of inertia, offset (any sign, may be 0).
    theta0 : float
        Initial heading.
    Pi0 : array_like, shape (3,)
        ``(Pi_theta, Pi_x, Pi_y)`` at ``t = 0``, on the constraint set.

    Returns
    -------
    dict
        ``"theta", "Pi_theta", "Pi_x", "Pi_y"``, arrays shaped like ``t``.
        ``x, y`` have no closed form and are omitted.

    Raises
    ------
    ValueError
        If ``Pi0`` violates the constraint.

    Notes
    -----
    Let ``M = I + m a^2``, ``omega = Pi_theta / M = theta'`` and ``v = Pi_x / m``
    (forward speed).  On the constraint set ``Pi_y = m a omega`` and the
    equations are

    .. math:: v' = a\,\omega^2, \qquad M \omega' = -m a v \omega .

    ``E = m v^2 + M omega^2`` is conserved (twice the energy).  Put
    ``c = sqrt(E/m)`` and ``k = m a c / M``.  Then ``v' = (k/c)(c^2 - v^2)``, so

    .. math:: v = c \tanh(k t + \tau_0), \qquad
              \omega = \sigma \sqrt{m/M}\, c\, \operatorname{sech}(k t + \tau_0),

    with ``sigma = sign(omega0)`` (``omega`` never changes sign) and
    ``sinh(tau_0) = sqrt(m/M) v0 / |omega0|`` (the ratio ``tanh/sech``; no shift
    of ``v`` is needed).  Integrating ``omega`` with
    ``d gd(s)/ds = sech s``, ``gd(s) = arctan(sinh s)``:

    .. math:: \theta = \theta_0 + \sigma \frac{\sqrt{M/m}}{a}
              \big(\operatorname{gd}(k t + \tau_0) - \operatorname{gd}(\tau_0)\big),

    evaluated as ``atan2`` of a cancellation-free difference so that small
    ``a`` loses no accuracy.  As ``t -> +inf`` (for ``a > 0``) ``v -> c``,
    ``omega -> 0`` and the total turn is
    ``sigma sqrt(M/m) (pi/2 - gd(tau_0)) / a``.

    Edge cases: ``omega0 = 0`` is a relative equilibrium (straight motion with
    ``v = v0``, ``theta = theta0``); ``a = 0`` gives constant ``v`` and
    ``omega`` (``theta = theta0 + omega0 t``).
    """
    t = _as_time(t)
    Pt0, Px0, Py0 = (float(v) for v in np.asarray(Pi0, dtype=float).reshape(3))
    M = I + m * a * a
    _check(m * a * Pt0 - M * Py0, abs(m * a * Pt0) + abs(M * Py0), "m a Pi_theta - (I + m a^2) Pi_y")
    v0 = Px0 / m
    w0 = Pt0 / M
    if w0 == 0.0:
        v = np.full_like(t, v0)
        omega = np.zeros_like(t)
        theta = np.full_like(t, float(theta0))
    elif a == 0.0:
        v = np.full_like(t, v0)
        omega = np.full_like(t, w0)
        theta = theta0 + w0 * t
    else:
        sigma = np.sign(w0)
        c = np.sqrt(v0 * v0 + (M / m) * w0 * w0)
        k = m * a * c / M
        tau0 = np.arcsinh(np.sqrt(m / M) * v0 / abs(w0))
        s = k * t + tau0
        v = c * np.tanh(s)
        omega = sigma * np.sqrt(m / M) * c * _sech(s)
        theta = theta0 + sigma * (np.sqrt(M / m) / a) * _gd_difference(tau0, k * t)
    return {
        "theta": theta,
        "Pi_theta": M * omega,
        "Pi_x": m * v,
        "Pi_y": m * a * omega,
    }


# ----------------------------------------------------------------------------
# vertical rolling disk
# ----------------------------------------------------------------------------

def vertical_disk(t, m, I, J, R, q0, Pi0):
    r"""Vertical rolling disk on SE(2) x S^1, closed form.

    Paper Sec. "The Vertical Rolling Disk": ``q = (theta, x, y, psi)``, locked
    inertia ``diag(J, m, m, I)``, reduced momenta
    ``Pi = (Pi_theta, Pi_x, Pi_y, Pi_psi)``, constraints ``Pi_y = 0`` and
    ``I Pi_x - m R Pi_psi = 0`` (rolling without slipping, ``x' = R psi' cos
    theta``, ``y' = R psi' sin theta``).

    Parameters
    ----------
    t : array_like
        Times.
    m, I, J, R : float
        Mass, moment of inertia about the rolling axis, about a diameter, radius.
    q0 : array_like, shape (4,)
        ``(theta, x, y, psi)`` at ``t = 0``.
    Pi0 : array_like, shape (4,)
        ``(Pi_theta, Pi_x, Pi_y, Pi_psi)``, on the constraint set.

    Returns
    -------
    dict
        ``"theta", "x", "y", "psi", "Pi_theta", "Pi_x", "Pi_y", "Pi_psi"``.

    Raises
    ------
    ValueError
        If ``Pi0`` violates a constraint.

    Notes
    -----
    On the constraint set all reduced momenta are constant (the reaction forces
    do no work on ``theta`` and, eliminating them, ``(I + m R^2) psi'' = 0``).
    Hence ``theta = theta0 + omega t`` with ``omega = Pi_theta / J``,
    ``psi = psi0 + Pi_psi t / I`` and, with ``u = Pi_x / m``,

    .. math:: x = x_0 + u\,t \cos(\theta_0 + \omega t/2)\,\operatorname{sinc}(\omega t/2),
              \qquad
              y = y_0 + u\,t \sin(\theta_0 + \omega t/2)\,\operatorname{sinc}(\omega t/2),

    i.e. a circle of radius ``|u / omega|`` (a straight line if
    ``Pi_theta = 0``, which the ``sinc`` form covers without a special case).
    """
    t = _as_time(t)
    th0, x0, y0, ps0 = (float(v) for v in np.asarray(q0, dtype=float).reshape(4))
    Pt, Px, Py, Pp = (float(v) for v in np.asarray(Pi0, dtype=float).reshape(4))
    _check(Py, 0.0, "Pi_y")
    _check(I * Px - m * R * Pp, abs(I * Px) + abs(m * R * Pp), "I Pi_x - m R Pi_psi")
    omega = Pt / J
    u = Px / m
    sc = t * _sinc(0.5 * omega * t)
    half = th0 + 0.5 * omega * t
    return {
        "theta": th0 + omega * t,
        "x": x0 + u * np.cos(half) * sc,
        "y": y0 + u * np.sin(half) * sc,
        "psi": ps0 + (Pp / I) * t,
        "Pi_theta": np.full_like(t, Pt),
        "Pi_x": np.full_like(t, Px),
        "Pi_y": np.full_like(t, Py),
        "Pi_psi": np.full_like(t, Pp),
    }


# ----------------------------------------------------------------------------
# Heisenberg system
# ----------------------------------------------------------------------------

def heisenberg(t, q0, p0):
    r"""Heisenberg system: straight lines.

    ``H = |p|^2 / 2``, ``q = (x, y, z)``, ``p = (p_x, p_y, p_z)`` (the paper's
    ``q = (x, z, y)`` is a typo, docs/paper_notes.md item 7), constraint
    ``p_z - y p_x + x p_y = 0``.

    Parameters
    ----------
    t : array_like
        Times.
    q0, p0 : array_like, shape (3,)
        Initial position and momentum, on the constraint set.

    Returns
    -------
    dict
        ``"x", "y", "z", "p_x", "p_y", "p_z"``.

    Raises
    ------
    ValueError
        If ``(q0, p0)`` violates the constraint.

    Notes
    -----
    With the constraint covector ``e = (-y, x, 1)`` the multiplier is
    ``lambda = -(d e/dt . p) / |e|^2 = -(-y' p_x + x' p_y) / |e|^2
    = -(-p_y p_x + p_x p_y) / |e|^2 = 0``, so ``q = q0 + p0 t``, ``p = p0``.
    The constraint stays satisfied:
    ``p_z - (y0 + p_y t) p_x + (x0 + p_x t) p_y = p_z - y0 p_x + x0 p_y``.
    """
    t = _as_time(t)
    x0, y0, z0 = (float(v) for v in np.asarray(q0, dtype=float).reshape(3))
    px, py, pz = (float(v) for v in np.asarray(p0, dtype=float).reshape(3))
    _check(pz - y0 * px + x0 * py, abs(pz) + abs(y0 * px) + abs(x0 * py), "p_z - y p_x + x p_y")
    return {
        "x": x0 + px * t,
        "y": y0 + py * t,
        "z": z0 + pz * t,
        "p_x": np.full_like(t, px),
        "p_y": np.full_like(t, py),
        "p_z": np.full_like(t, pz),
    }


# ----------------------------------------------------------------------------
# nonholonomic oscillator
# ----------------------------------------------------------------------------

def oscillator_y(t, y0, py0):
    r"""Nonholonomic oscillator: the ``y`` subsystem (the only closed-form part).

    ``H = |p|^2/2 + |q|^2/2``, constraint ``p_x + y p_z = 0``.  The constraint
    covector ``(1, 0, y)`` has no ``y`` component, so the reaction force does
    not act on ``y`` and ``y'' = -y``:

    .. math:: y = y_0 \cos t + p_{y0} \sin t, \qquad
              p_y = -y_0 \sin t + p_{y0} \cos t .

    With the paper's start ``q(0) = (1, 1, 1)``, ``p(0) = 0`` this is
    ``y = cos t``.  ``x, z`` couple through the constraint and have no closed
    form.

    Parameters
    ----------
    t : array_like
        Times.
    y0, py0 : float
        Initial ``y`` and ``p_y``.

    Returns
    -------
    dict
        ``"y", "p_y"``.
    """
    t = _as_time(t)
    c, s = np.cos(t), np.sin(t)
    return {"y": y0 * c + py0 * s, "p_y": -y0 * s + py0 * c}


def kepler(t, q0, p0, mu=1.0):
    r"""The bound Kepler orbit ``q'' = -mu q / |q|^3`` from ``(q0, p0)`` (unit mass: ``p = q'``).

    Kepler's equation ``E - e sin E = M`` for the eccentric anomaly (Newton's
    method from ``E = M + 0.85 e sign(sin M)``, Danby's start, to ``2 ulp``),
    then the Lagrange coefficients
    ``q = f q0 + g p0``, ``p = f' q0 + g' p0`` with, for ``dE = E - E0``,
    ``f = 1 - (a/r0)(1 - cos dE)``, ``g = t - (dE - sin dE)/n``,
    ``f' = -sqrt(mu a) sin dE / (r r0)``, ``g' = 1 - (a/r)(1 - cos dE)``,
    ``r = a (1 - e cos E)``, ``a = -mu/(2 E_tot)``, ``n = sqrt(mu/a^3)``
    (e.g. Danby, *Fundamentals of Celestial Mechanics*, 2nd ed., Sec. 6.8).
    Times are reduced modulo the period first, so a horizon of thousands of
    periods costs no accuracy beyond the reduction's rounding.

    Returns ``{x, y, z, p_x, p_y, p_z}``.  Raises :class:`ValueError` for an
    unbound (``E_tot >= 0``) or rectilinear (``L = 0``) start.
    """
    t = _as_time(t)
    q0 = np.asarray(q0, float)
    p0 = np.asarray(p0, float)
    r0 = float(np.linalg.norm(q0))
    energy = 0.5 * float(p0 @ p0) - mu / r0
    if not energy < 0:
        raise ValueError(f"q0, p0: the orbit is not bound (energy {energy:g} >= 0)")
    L = np.cross(q0, p0)
    if not np.linalg.norm(L) > 0:
        raise ValueError("q0, p0: the start has no angular momentum (a rectilinear orbit)")
    a = -mu / (2.0 * energy)
    n = np.sqrt(mu / a**3)
    period = 2.0 * np.pi / n
    ecosE0 = 1.0 - r0 / a
    esinE0 = float(q0 @ p0) / np.sqrt(mu * a)
    e = float(np.hypot(ecosE0, esinE0))
    E0 = float(np.arctan2(esinE0, ecosE0))
    tau = np.mod(t, period)  # the motion is periodic: reduce the time first
    M = E0 - esinE0 + n * tau
    E = M + 0.85 * e * np.sign(np.sin(M))
    for _ in range(50):
        dE = (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
        E = E - dE
        if np.max(np.abs(dE), initial=0.0) <= 4e-16 * max(1.0, float(np.max(np.abs(M), initial=0.0))):
            break
    d = E - E0
    cd, sd = np.cos(d), np.sin(d)
    r = a * (1.0 - e * np.cos(E))
    f = 1.0 - (a / r0) * (1.0 - cd)
    g = tau - (d - sd) / n
    fd = -np.sqrt(mu * a) * sd / (r * r0)
    gd = 1.0 - (a / r) * (1.0 - cd)
    q = f[..., None] * q0 + g[..., None] * p0
    p = fd[..., None] * q0 + gd[..., None] * p0
    names = ("x", "y", "z", "p_x", "p_y", "p_z")
    return dict(zip(names, [q[..., i] for i in range(3)] + [p[..., i] for i in range(3)]))
