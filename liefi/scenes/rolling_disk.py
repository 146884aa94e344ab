r"""A thin uniform disk rolling without slipping on a plane, no dissipation.

Built by :func:`liefi.systems.rolling.rolling_body` from the body's data only -- mass
``m``, radius ``a``, the uniform disk's inertia ``I = m a^2 (1/4, 1/4, 1/2)``
(diameters, axis) and the contact function :func:`liefi.systems.rolling.disk` -- on
``SO(3) x R^2`` with the whole attitude advected and the two no-slip rows kept
as constraint momenta (:mod:`liefi.systems.rolling` says why).  The disk lies in the
body's ``e_1 e_2`` plane; ``Gamma_3 = <R e_3, e_3>`` is the cosine of its
axis' angle to the vertical (``0``: upright, ``+-1``: lying flat, where the
contact point is not defined; the start is tilted 70 degrees from flat and
the motion stays far from it).

Data (dimensionless): ``m = a = g = 1``; start with the disk's plane at 70
degrees to the floor (``Gamma = (0, sin 70, cos 70)``), spinning about its axis
at ``Omega_3 = 4`` with a rocking ``Omega_1 = 0.5``.  Horizon ``t = 50``,
``dt = 1e-3``.

Invariants in ``V``: the two constraint momenta, ``h~``, the six attitude
Casimirs and, in the default variant ``integrals-in-V``, the disk's two first
integrals beyond the energy (Chaplygin 1897, Appell 1900, Korteweg 1899),
linear in the angular velocity with coefficients that are Legendre (Gauss
hypergeometric) functions of the tilt -- :func:`chaplygin_integrals` derives
them.  Penalized, they stay at rounding (4e-15 at ``t = 1000``) for about 1.3x
the CPU per step; the variant ``tilted`` only monitors them (reported drift),
and they then drift with the scheme's error (1e-11 at ``t = 1000``,
``dt = 1e-3``).  The tests
check them against the reference and at two special solutions derived there
from the reference's equations: upright rolling in a straight line at
constant spin, and steady motion on a circle at a fixed tilt.

Reference: the textbook rolling rigid body
(:func:`~liefi.scenes.rolling_reference.rolling_equations`) with the disk's
contact point ``r = -a (Gamma_1, Gamma_2, 0) / s``, ``s = sqrt(Gamma_1^2 +
Gamma_2^2)``, and its rate written by hand in :func:`disk_equations`, solved by
DOP853 at ``1e-13``.  Figures: the path of the centre of mass on the plane,
run and reference, and the errors of the path and of the tilt against time;
the drift of the two integrals next to the energy's and the no-slip violation.
"""

from __future__ import annotations

import math

import numpy as np

from ..results import scene_figures as plotting
from ..groups import SO3
from ..systems.rolling import ATTITUDE_CASIMIRS, disk, rolling_body, rolling_start
from .base import Variant
from .rolling_reference import RollingReferenceScene, rolling_equations

MASS = 1.0
RADIUS = 1.0
GRAVITY = 1.0
TILT_DEG = 70.0  # the disk's plane against the floor
OMEGA0 = (0.5, 0.0, 4.0)


def inertia_matrix(mass=MASS, radius=RADIUS):
    """The uniform thin disk's central inertia ``m a^2 diag(1/4, 1/4, 1/2)`` (axis = body ``e_3``)."""
    return mass * radius**2 * np.diag([0.25, 0.25, 0.5])


def start_attitude(tilt_deg=TILT_DEG, omega=OMEGA0):
    """``(R, Omega)``: the rotation by ``tilt`` about ``e_1`` (``Gamma = (0, sin tilt, cos tilt)``) and ``omega``."""
    return SO3().exp(np.array([math.radians(tilt_deg), 0.0, 0.0])), np.array(omega, float)


def _sqrt(x):
    return math.sqrt(x) if isinstance(x, float) else np.sqrt(x)


def disk_equations(inertia, mass, radius, g):
    """The rolling rigid body's equations for the thin disk, ``r = -a (Gamma_1, Gamma_2, 0) / s``, with its
    rate ``r_i' = -a (d_i - Gamma_i (Gamma_1 d_1 + Gamma_2 d_2) / s^2) / s`` written by hand (reference only)."""
    a = float(radius)

    def contact(G1, G2, G3, d1, d2, d3):
        s = _sqrt(G1 * G1 + G2 * G2)
        sd = (G1 * d1 + G2 * d2) / (s * s)
        return (-a * G1 / s, -a * G2 / s, 0.0 * s, -a * (d1 - G1 * sd) / s, -a * (d2 - G2 * sd) / s, 0.0 * s)

    return rolling_equations(inertia, mass, g, contact)


# --- the disk's two first integrals beyond the energy (Chaplygin 1897; Appell 1900; Korteweg 1899) ---------

#: ``|cos theta|`` (``|Gamma_3|``) up to which the integrals are summed: within ``acos 0.999 = 2.6`` degrees
#: of lying flat the series need tens of thousands of terms (and the contact point is ill-defined there)
COS_LIMIT = 0.999
_EPS = 1e-17  # the series' tails are summed to below this (absolute: the functions are O(1))


def axisymmetric_moments(inertia):
    """``(I_1, I_3)`` of a diagonal inertia with ``I_1 = I_2`` (3 x 3 or 3 moments); ``ValueError`` otherwise."""
    from .._data import as_float_array

    I = as_float_array(inertia, "inertia")
    I = np.diag(I) if I.shape == (3,) else I
    if I.shape != (3, 3) or not np.all(np.isfinite(I)):
        raise ValueError(f"inertia: expected 3 principal moments or a 3 x 3 matrix, got shape {I.shape}")
    off = I - np.diag(np.diag(I))
    if np.any(off != 0.0) or abs(I[0, 0] - I[1, 1]) > 1e-14 * abs(I[0, 0]) or np.any(np.diag(I) <= 0):
        raise ValueError("inertia: the disk's integrals need a diagonal inertia I = diag(I_1, I_1, I_3) about the "
                         f"disk's axes (axisymmetric, positive), got {I.tolist()}")
    return float(I[0, 0]), float(I[2, 2])


def legendre_parameter(inertia=None, mass=MASS, radius=RADIUS):
    r"""``(lambda, alpha)``: ``alpha = m a^2 / (I_3 + m a^2)``, ``lambda = alpha I_3 / I_1`` (module docstring of
    :func:`chaplygin_integrals`); the uniform thin disk has ``alpha = 2/3``, ``lambda = 4/3``."""
    m, a = float(mass), float(radius)
    if not (np.isfinite(m) and m > 0):
        raise ValueError(f"mass: expected a positive number, got {mass!r}")
    if not (np.isfinite(a) and a > 0):
        raise ValueError(f"radius: expected a positive number, got {radius!r}")
    I1, I3 = axisymmetric_moments(inertia_matrix(m, a) if inertia is None else inertia)
    alpha = m * a * a / (I3 + m * a * a)
    return alpha * I3 / I1, alpha


_SERIES = {}


def legendre_series(lam, X):
    """Coefficients ``(e, o)`` with ``y_1 = sum e_k X^k``, ``y_2 = x sum o_k X^k`` (``X = x^2``) summed to
    ``1e-17`` for ``0 <= X < 1``: ``e_{k+1}/e_k = (k^2 + k/2 + lambda/4) / ((k + 1/2)(k + 1))``, ``o_{k+1}/o_k
    = (k^2 + 3k/2 + lambda/4 + 1/2) / ((k + 3/2)(k + 1))`` -- the Gauss series of ``2F1(p, q; 1/2; X)`` and
    ``2F1(p + 1/2, q + 1/2; 3/2; X)`` with ``p + q = 1/2``, ``p q = lambda/4``, whose products ``(p)_k (q)_k``
    are real even when ``p, q`` are complex.  Cached by ``(lambda, number of terms)``."""
    X = float(X)
    # the tails of the series and of their derivatives: once the coefficients decrease (k > lambda/4),
    # sum_{k >= n} k c_k X^(k-1) <= c_n X^(n-1) (n/(1-X) + X/(1-X)^2)
    n = 2
    bound = (1.0 - X) ** -2
    while n < 10 + lam / 4 or X ** (n - 1) * (n + 1) * bound > _EPS:
        n += 1
        if n > 200000:
            raise ValueError(f"Gamma_3: |cos(tilt)| = {np.sqrt(X):.6g} is too close to 1 to sum the series")
    n = 8 * (-(-n // 8))  # a few sizes only, for the cache
    key = (float(lam), n)
    if key not in _SERIES:
        k = np.arange(n - 1, dtype=float)
        e = np.concatenate([[1.0], np.cumprod((k * k + k / 2 + lam / 4) / ((k + 0.5) * (k + 1)))])
        o = np.concatenate([[1.0], np.cumprod((k * k + 1.5 * k + lam / 4 + 0.5) / ((k + 1.5) * (k + 1)))])
        _SERIES[key] = (e, o)
    return _SERIES[key]


def _horner(c, X):
    """``(sum c_k X^k, sum k c_k X^(k-1))`` by Horner's scheme (plain arithmetic: complex steps and traced
    scalars pass through)."""
    f = 0.0 * X + c[-1]
    d = 0.0 * X
    for ck in c[-2::-1]:
        d = d * X + f
        f = f * X + float(ck)
    return f, d


def legendre_pair(lam, x, max_cos=None):
    """``(y_1, y_1', y_2, y_2')`` at ``x``: the solutions of ``(1 - x^2) y'' - 2 x y' - lambda y = 0`` with
    ``y_1(0) = 1, y_1'(0) = 0, y_2(0) = 0, y_2'(0) = 1`` (:func:`legendre_series`).  The number of terms is
    taken from ``max |x|`` of a numeric ``x`` (``ValueError`` beyond :data:`COS_LIMIT`), else from ``max_cos``."""
    from ..reduction.core import is_traced

    if is_traced(x):
        xm = COS_LIMIT if max_cos is None else float(max_cos)
    else:
        xm = float(np.max(np.abs(np.real(x)), initial=0.0))
        if not xm <= COS_LIMIT:
            raise ValueError(f"Gamma_3: the disk's integrals are summed for |Gamma_3| <= {COS_LIMIT} (tilted at "
                             f"least {np.degrees(np.arccos(COS_LIMIT)):.1f} degrees from lying flat); got "
                             f"|Gamma_3| = {xm:.6g}, where the disk (almost) lies flat and its contact point is "
                             "not defined")
    e, o = legendre_series(lam, xm * xm)
    X = x * x
    fe, de = _horner(e, X)
    fo, do = _horner(o, X)
    return fe, 2.0 * x * de, x * fo, fo + 2.0 * X * do


def chaplygin_integrals(Omega, Gamma, inertia=None, mass=MASS, radius=RADIUS, *, max_cos=None):
    r"""The thin disk's two first integrals beyond the energy, from ``(Omega, Gamma)`` (batch-first).

    Body axes: ``e_3`` the disk's axis, ``Gamma = R^T e_3`` the upward vertical, ``x = cos theta =
    Gamma_3`` (``theta`` the axis' angle to the vertical), ``s = sin theta``, ``u = (Gamma_1, Gamma_2,
    0)/s`` the unit vector in the disk's plane from the contact point to the centre, ``t = e_3 x u``
    (horizontal, along the rim).  With ``Omega = w_u u + w_t t + w_3 e_3`` the tilt moves at ``theta' =
    -w_t``.  The balance of angular momentum about the contact point, ``K = I Omega + m r x (Omega x r)``
    (:mod:`~liefi.scenes.rolling_reference`), has no gravity torque along ``e_3`` nor along ``u``; in the
    frame ``(u, t, e_3)``, which turns at ``Omega - phi' e_3`` (``phi' = w_3 - w_u cot theta``, the spin
    relative to it), those two components read, divided by ``theta' = -w_t``,

    .. math:: (I_3 + m a^2) \frac{d w_3}{d\theta} = m a^2 w_u, \qquad
              I_1 \frac{d w_u}{d\theta} = I_3 w_3 - I_1 \cot\theta\, w_u ,

    a linear system in ``theta``.  Eliminating ``w_u`` and putting ``x = cos theta``: ``w_3`` solves
    Legendre's equation ``(1 - x^2) y'' - 2 x y' - lambda y = 0``, ``lambda = alpha I_3 / I_1``, ``alpha =
    m a^2 / (I_3 + m a^2)`` (the uniform disk: ``lambda = 4/3``, degree ``nu = -1/2 + i sqrt(13/12)``: conical
    functions), and ``w_u = -(s/alpha) dw_3/dx``.  Its solutions even and odd in ``x``
    (:func:`legendre_pair`) are Gauss hypergeometric series,

    .. math:: y_1 = {}_2F_1(p, q; \tfrac12; x^2), \qquad y_2 = x\, {}_2F_1(p + \tfrac12, q + \tfrac12;
              \tfrac32; x^2), \qquad p + q = \tfrac12,\ pq = \tfrac\lambda4,

    with Wronskian ``y_1 y_2' - y_2 y_1' = 1/(1 - x^2)``.  Writing ``(w_3, w_u) = C_1 (y_1, -s y_1'/alpha) -
    C_2 (y_2, -s y_2'/alpha)`` and solving with the Wronskian gives the constants

    .. math:: C_1 = s^2 w_3\, y_2'(x) + \alpha\, \sigma\, y_2(x), \qquad
              C_2 = s^2 w_3\, y_1'(x) + \alpha\, \sigma\, y_1(x), \qquad \sigma = s\, w_u =
              \Omega_1 \Gamma_1 + \Omega_2 \Gamma_2 ,

    ``w_3 = Omega_3`` and ``s^2 = Gamma_1^2 + Gamma_2^2``: linear in ``Omega``, regular at every tilt (not
    lying flat).  Upright (``x = 0``): ``C_1 = Omega_3``, ``C_2 = alpha <Omega, u>``.  (Chaplygin 1897;
    Appell 1900; Korteweg 1899; Borisov, Mamaev & Kilin, "Dynamics of rolling disk", Regul. Chaotic Dyn. 8
    (2003) 201; O'Reilly, Nonlinear Dyn. 10 (1996) 287.)

    Parameters
    ----------
    Omega, Gamma : array_like (..., 3)
        Body angular velocity and upward vertical.
    inertia : array_like, optional
        ``diag(I_1, I_1, I_3)`` (default the uniform disk's, :func:`inertia_matrix`).
    mass, radius : float
    max_cos : float, optional
        ``|Gamma_3|`` bound that fixes the series' length for traced input (default :data:`COS_LIMIT`).

    Returns
    -------
    (C_1, C_2) : arrays (...)
    """
    W, G = np.asarray(Omega), np.asarray(Gamma)
    if W.shape[-1:] != (3,) or G.shape[-1:] != (3,):
        raise ValueError(f"Omega, Gamma: expected arrays (..., 3), got shapes {W.shape} and {G.shape}")
    sigma = W[..., 0] * G[..., 0] + W[..., 1] * G[..., 1]
    return _integrals(W[..., 2], sigma, G, legendre_parameter(inertia, mass, radius), max_cos)


def _integrals(w3, sigma, G, params, max_cos):
    """``(C_1, C_2)`` from ``w_3 = Omega_3``, ``sigma = Omega_1 Gamma_1 + Omega_2 Gamma_2`` and ``Gamma``."""
    lam, alpha = params
    y1, d1, y2, d2 = legendre_pair(lam, G[..., 2], max_cos)
    s2 = G[..., 0] * G[..., 0] + G[..., 1] * G[..., 1]
    return s2 * w3 * d2 + alpha * sigma * y2, s2 * w3 * d1 + alpha * sigma * y1


def chaplygin_invariants(inertia=None, mass=MASS, radius=RADIUS, *, max_cos=None):
    r"""``C_1``, ``C_2`` of :func:`chaplygin_integrals` as :class:`~liefi.Invariant` of the reduced state
    ``z = (rho_1, rho_2, Gamma, Pi, p)`` of :func:`liefi.systems.rolling.rolling_body` with :func:`liefi.systems.rolling.disk`.

    The momenta are ``Pi = I Omega + m w <w, Omega>`` with ``w = Gamma x r = (a Gamma_3 / s) (Gamma_2,
    -Gamma_1, 0)`` (:mod:`liefi.systems.rolling`): ``w`` has no axial component and is orthogonal to ``(Gamma_1,
    Gamma_2, 0)``, so ``Omega_3 = Pi_3 / I_3`` and ``Omega_1 Gamma_1 + Omega_2 Gamma_2 = (Pi_1 Gamma_1 +
    Pi_2 Gamma_2) / I_1`` -- all the integrals need.  First integrals of the constrained motion (on ``J =
    0``); monitored by the scene, and penalized in ``V`` by its default variant ``integrals-in-V``.
    """
    from ..integrator.feedback import Invariant

    I1, I3 = axisymmetric_moments(inertia_matrix(mass, radius) if inertia is None else inertia)
    params = legendre_parameter(inertia, mass, radius)

    def both(z):
        z = np.asarray(z)
        G = z[..., 6:9]
        sigma = (z[..., 9] * G[..., 0] + z[..., 10] * G[..., 1]) / I1
        return _integrals(z[..., 11] / I3, sigma, G, params, max_cos)

    return (Invariant("chaplygin_1", lambda z: both(z)[0]), Invariant("chaplygin_2", lambda z: both(z)[1]))


class RollingDisk(RollingReferenceScene):
    name = "rolling-disk"
    in_paper = False
    title = "Thin disk rolling without slipping on a plane (no dissipation)"
    paper = "future work of the paper: rolling bodies (semidirect-product reduction)"
    dt = 1e-3
    t_final = 50.0
    scheme = "imex-rk4"
    gains = 1.0
    variants = {
        "integrals-in-V": Variant(
            "integrals-in-V", "m = a = g = 1, I = m a^2 (1/4, 1/4, 1/2); plane at 70 deg to the floor, "
                              "Omega = (0.5, 0, 4); Chaplygin's two integrals C_1, C_2 penalized in V (kept to rounding)",
            options={"integrals_in_V": True}),
        "tilted": Variant(
            "tilted", "m = a = g = 1, I = m a^2 (1/4, 1/4, 1/2); plane at 70 deg to the floor, "
                      "Omega = (0.5, 0, 4); Chaplygin's integrals only monitored (they drift with the error; "
                      "about 1/1.3 the CPU per step)"),
    }
    #: ``|Gamma_3|`` bound of the compiled series of the integrals in ``V`` (the motion keeps ``Gamma_3`` in
    #: ``[0.27, 0.43]``; the numpy evaluation sums to rounding up to :data:`COS_LIMIT` whatever this is)
    series_max_cos = 0.6

    mass = MASS
    inertia = inertia_matrix()
    observable_names = ("spin", "axial_spin")

    def build_system(self):
        R, _ = start_attitude()
        return rolling_body(MASS, inertia_matrix(), disk(RADIUS), gravity=GRAVITY, sample=R)

    def initial_state(self, variant):
        return rolling_start(self.system, *start_attitude())

    def invariants(self, variant):
        extra = self.monitored(variant) if variant.options.get("integrals_in_V") else ()
        return ("constraints", "energy") + ATTITUDE_CASIMIRS + extra

    def monitored(self, variant):
        """Chaplygin's two integrals (:func:`chaplygin_invariants`): reported in ``max_drift``; penalized in
        ``V`` only by the variant ``integrals-in-V``."""
        return chaplygin_invariants(inertia_matrix(), MASS, RADIUS, max_cos=self.series_max_cos)

    def start_attitude(self):
        return start_attitude()

    def reference_equations(self):
        return disk_equations(inertia_matrix(), MASS, RADIUS, GRAVITY)

    def reference_observables(self, Omega, Gamma):
        """``spin = <Omega, Gamma>`` (about the vertical) and ``axial_spin = Omega_3`` (about the disk's
        axis), batch-first."""
        return {"spin": np.sum(Omega * Gamma, -1), "axial_spin": Omega[..., 2]}

    def figures(self, runs, *, tag=""):
        """The centre of mass' path (run and reference) with the path's and the tilt's errors; the drift of
        Chaplygin's two integrals next to the energy's; then the generic."""
        out = []
        for r in self.as_runs(runs).values():
            out += [plotting.FigureSpec("rolling-disk-path", lambda f, r=r: path_figure(r, f, tag=tag), 11, 4.2),
                    plotting.FigureSpec("rolling-disk-integrals", lambda f, r=r: integrals_figure(r, f, tag=tag),
                                        11, 4.0),
                    plotting.FigureSpec("generic", lambda f, r=r: plotting.generic(r, f, title=self.title, tag=tag),
                                        11, 4.0)]
        return out


def path_figure(result, fig=None, *, tag=""):
    """The centre of mass' path ``(x(t), y(t))``, run against reference, and the errors of the path and of
    the tilt ``Gamma_3`` against time."""
    fig = plotting.figure(fig, 11, 4.2)
    a0, a1 = fig.subplots(1, 2)
    x, y, xe, ye = plotting.plane_path(a0, result, "reference (rolling-body equations)",
                                       f"the disk's centre on the plane{tag}")
    g3, g3e = plotting.component(result, "Gamma_3"), plotting.reference_of(result, "Gamma_3")
    if xe is not None and x is not None:
        plotting.logplot(a1, result.t, np.hypot(x - xe, y - ye), lw=0.8, label="centre: distance to the reference")
    if g3e is not None and g3 is not None:
        plotting.logplot(a1, result.t, g3 - g3e, lw=0.8, label=r"tilt: error of $\Gamma_3$")
    if a1.lines:
        a1.legend(fontsize=8)
    a1.set_xlabel("$t$")
    a1.set_ylabel("error against the reference")
    a1.grid(alpha=0.3)
    return fig


def integrals_figure(result, fig=None, *, tag=""):
    """The drift ``|C_j(t) - C_j(0)|`` of the two integrals of :func:`chaplygin_integrals` (monitored, not in
    ``V``) next to the energy's ``|h~(t) - h~(0)|`` and the no-slip violation ``|J_i|`` (held by ``V``)."""
    fig = plotting.figure(fig, 11, 4.0)
    a0, a1 = fig.subplots(1, 2, sharex=True)
    inv = result.invariants
    for i, k in enumerate(("chaplygin_1", "chaplygin_2")):
        if k in inv:
            where = "in $V$" if k in result.gains else "monitored, not in $V$"
            plotting.logplot(a0, result.t, plotting.drift(k, inv[k]), lw=0.8, color=f"C{i}",
                             label=f"$C_{i + 1}$ (Chaplygin; {where})")
    a0.set_title(f"the disk's integrals beyond the energy{tag}", fontsize=9)
    for i, k in enumerate(("h~", "J_1", "J_2")):
        if k in inv:
            plotting.logplot(a1, result.t, plotting.drift(k, inv[k]), lw=0.8, color=f"C{i + 2}",
                             label=plotting.label(k) + " (in $V$)")
    a1.set_title(f"energy and no-slip violation{tag}", fontsize=9)
    for ax in (a0, a1):
        if ax.lines:
            ax.legend(fontsize=8)
        ax.set_xlabel("$t$")
        ax.set_ylabel(r"$|I(t) - I(0)|$")
        ax.grid(alpha=0.3)
    fig.suptitle(plotting.run_caption(result), fontsize=9)
    return fig


SCENE = RollingDisk()
