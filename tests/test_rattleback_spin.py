"""The rattleback's steady spin about the vertical: liefi's linearization against an independent route, and
which spin direction is stable.

The second route is the scene's hand-written reference equations
(:func:`liefi.scenes.rattleback.rattleback_equations`: ``Gamma' = Gamma x Omega`` and the momentum balance
about the contact point, in ``(Gamma, K)``), differentiated by complex step at the steady spin
``Gamma = e_3``, ``Omega = omega e_3``.  Their 6 x 6 Jacobian has two zeros (the Casimir ``|Gamma|`` and the
family of steady spins) and the four nontrivial eigenvalues, which :func:`liefi.linearize` must reproduce
from the traced field to 1e-10.

Which direction is stable.  Without dissipation the model is time-reversible (``t -> -t``, ``Omega -> -Omega``
maps a motion to a motion), so the spectrum at ``-omega`` is minus the spectrum at ``omega``.  "Stable one way,
unstable the other" therefore means: one direction has every nontrivial eigenvalue in the open left half-plane
(asymptotically stable to first order, which a nonholonomic system can be with no dissipation, having no
invariant measure), the other has them all in the right.  Two regimes, both reproduced here:

* slow spin (Walker 1896; Garcia & Hubbard, Proc. R. Soc. A 418 (1988) 165): the misalignment of the inertia
  and curvature axes makes the pitching mode grow for one sign of the spin and the rolling mode for the
  other, so *each* direction has a growing mode and the conservative rattleback reverses both ways, at very
  different rates.  Kane & Levinson's body stays in this regime at every spin from 0.5 to 200 rad/s.
* fast spin (the "steady direction" in which Kondo & Nakanishi, arXiv:1704.06717 (2017), see the
  conservative rattleback spin on without reversing): for other bodies the slow (rolling) mode's growth
  changes sign at a finite spin, and past it one direction is asymptotically stable and the other
  unstable.
"""

import numpy as np
import pytest

from liefi.scenes import rattleback as rb
from liefi.systems.rolling import ellipsoid, rolling_body, rolling_start

# A rattleback with the fast-spin "steady direction": semi-axes (m), centre of mass below the centre of the
# ellipsoid by H_STEADY, principal inertia (kg m^2, the long axis first) turned 6.5 degrees about the vertical.
SEMI_STEADY = (0.067, 0.0146, 0.0076)
H_STEADY = 0.0039
PRINCIPAL_STEADY = (8.25e-4, 3.40e-4, 6.77e-4)
MISALIGNMENT_DEG = 6.5


def steady_inertia():
    d = np.radians(MISALIGNMENT_DEG)
    Rz = np.array([[np.cos(d), -np.sin(d), 0.0], [np.sin(d), np.cos(d), 0.0], [0.0, 0.0, 1.0]])
    return Rz @ np.diag(PRINCIPAL_STEADY) @ Rz.T


def body(inertia, semi, h):
    return rolling_body(rb.MASS, inertia, ellipsoid(semi, offset=(0.0, 0.0, -h)), gravity=rb.GRAVITY)


def oracle_spectrum(inertia, semi, h, omega):
    """The four nontrivial eigenvalues of the reference equations' Jacobian in ``(Gamma, K)`` at the spin."""
    fun = rb.rattleback_equations(inertia, rb.MASS, semi, h, rb.GRAVITY)
    r = np.array([0.0, 0.0, -semi[2] + h])  # the contact point at Gamma = e_3
    M = inertia + rb.MASS * (r @ r * np.eye(3) - np.outer(r, r))
    y0 = np.concatenate([np.eye(3)[:2].ravel(), [0.0, 0.0, 1.0], [0.0, 0.0], M @ [0.0, 0.0, omega]])
    sub = [6, 7, 8, 11, 12, 13]
    assert np.abs(fun(0.0, y0)[sub]).max() < 1e-14  # it is a steady motion of the reference too
    J = np.empty((6, 6))
    for j, k in enumerate(sub):
        y = y0.astype(complex)
        y[k] += 1e-30j
        J[:, j] = fun(0.0, y)[sub].imag / 1e-30
    ev = np.linalg.eigvals(J)
    order = np.argsort(np.abs(ev))
    assert np.abs(ev[order[:2]]).max() < 1e-9 * np.abs(ev).max()  # the Casimir and the family
    return ev[order[2:]]


def same_spectrum(a, b, tol):
    b = list(b)
    assert len(a) == len(b), (a, b)
    for x in a:
        k = int(np.argmin([abs(x - y) for y in b]))
        assert abs(x - b[k]) <= tol * abs(x), (x, b)
        b.pop(k)


def abscissa(system, omega):
    lin = system.linearize(rolling_start(system, np.eye(3), [0.0, 0.0, omega]))
    return lin.nontrivial_eigenvalues, lin.spectral_abscissa


@pytest.mark.parametrize("omega", [-5.0, 5.0])
def test_kane_levinson_spin_matches_the_reference_equations(omega):
    system = body(rb.inertia_matrix(), rb.SEMI_AXES, rb.H)
    ev, _ = abscissa(system, omega)
    same_spectrum(ev, oracle_spectrum(rb.inertia_matrix(), rb.SEMI_AXES, rb.H, omega), 1e-10)


def test_kane_levinson_reverses_both_ways_at_every_spin():
    """Walker's regime throughout: each direction has exactly one growing pair, the pitching one (~107 rad/s
    at rest) for ``omega > 0`` and the rolling one (~34 rad/s) for ``omega < 0``, and the spectra are
    mirror images."""
    system = body(rb.inertia_matrix(), rb.SEMI_AXES, rb.H)
    for omega in (0.5, 5.0, 50.0, 200.0):
        plus, a_plus = abscissa(system, omega)
        minus, a_minus = abscissa(system, -omega)
        same_spectrum(minus, -plus, 1e-9)
        assert a_plus > 0 and a_minus > 0
        grow_plus = [e for e in plus if e.real > 0]
        grow_minus = [e for e in minus if e.real > 0]
        assert len(grow_plus) == len(grow_minus) == 2
        assert min(abs(e.imag) for e in grow_plus) > max(abs(e.imag) for e in grow_minus)  # pitch vs roll


def test_fast_spin_is_stable_one_way_and_unstable_the_other():
    """The steady-direction body: at 5 rad/s both directions grow (Walker); at 40 rad/s the negative spin has
    all four nontrivial eigenvalues in the left half-plane and the positive spin all four in the right.  The
    crossing is found by bisection, and both sides agree with the reference equations to 1e-10."""
    I = steady_inertia()
    system = body(I, SEMI_STEADY, H_STEADY)
    _, slow_plus = abscissa(system, 5.0)
    _, slow_minus = abscissa(system, -5.0)
    assert slow_plus > 0 and slow_minus > 0
    for omega in (40.0, -40.0):
        ev, _ = abscissa(system, omega)
        same_spectrum(ev, oracle_spectrum(I, SEMI_STEADY, H_STEADY, omega), 1e-10)
    stable, a_stable = abscissa(system, -40.0)
    unstable, a_unstable = abscissa(system, 40.0)
    assert a_stable < -0.05 and all(e.real < 0 for e in stable)
    assert all(e.real > 0 for e in unstable) and a_unstable > 1.0
    lo, hi = 5.0, 40.0  # the spin at which the steady direction turns stable
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if abscissa(system, -mid)[1] > 0 else (lo, mid)
    assert 5.0 < hi < 40.0 and abscissa(system, -1.01 * hi)[1] < 0 < abscissa(system, -0.99 * hi)[1]
