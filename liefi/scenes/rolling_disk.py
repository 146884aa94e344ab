r"""A thin uniform disk rolling without slipping on a plane, no dissipation.

Built by :func:`liefi.rolling.rolling_body` from the body's data only -- mass
``m``, radius ``a``, the uniform disk's inertia ``I = m a^2 (1/4, 1/4, 1/2)``
(diameters, axis) and the contact function :func:`liefi.rolling.disk` -- on
``SO(3) x R^2`` with the whole attitude advected and the two no-slip rows kept
as constraint momenta (:mod:`liefi.rolling` says why).  The disk lies in the
body's ``e_1 e_2`` plane; ``Gamma_3 = <R e_3, e_3>`` is the cosine of its
axis' angle to the vertical (``0``: upright, ``+-1``: lying flat, where the
contact point is not defined; the start is tilted 70 degrees from flat and
the motion stays far from it).

Data (dimensionless): ``m = a = g = 1``; start with the disk's plane at 70
degrees to the floor (``Gamma = (0, sin 70, cos 70)``), spinning about its axis
at ``Omega_3 = 4`` with a rocking ``Omega_1 = 0.5``.  Horizon ``t = 50``,
``dt = 1e-3``.

Invariants in ``V``: the two constraint momenta, ``h~`` and the six attitude
Casimirs.  The disk has two more first integrals (Chaplygin 1897, Appell
1900: linear in the angular velocity, with coefficients that are
hypergeometric functions of the tilt); they are not monitored.  The tests
check, besides the reference, two special solutions derived there from the
reference's equations: upright rolling in a straight line at constant spin,
and steady motion on a circle at a fixed tilt.

Reference: the textbook rolling rigid body
(:func:`~liefi.scenes.rolling_reference.rolling_equations`) with the disk's
contact point ``r = -a (Gamma_1, Gamma_2, 0) / s``, ``s = sqrt(Gamma_1^2 +
Gamma_2^2)``, and its rate written by hand in :func:`disk_equations`, solved by
DOP853 at ``1e-13``.  Figures: the path of the centre of mass on the plane,
run and reference, and the errors of the path and of the tilt against time.
"""

from __future__ import annotations

import math

import numpy as np

from .. import plotting
from ..groups import SO3
from ..rolling import ATTITUDE_CASIMIRS, disk, rolling_body, rolling_start
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


class RollingDisk(RollingReferenceScene):
    name = "rolling-disk"
    in_paper = False
    title = "Thin disk rolling without slipping on a plane (no dissipation)"
    paper = "future work of the paper: rolling bodies (semidirect-product reduction)"
    dt = 1e-3
    t_final = 50.0
    scheme = "imex-rk4"
    gains = 1.0
    variants = {"tilted": Variant(
        "tilted", "m = a = g = 1, I = m a^2 (1/4, 1/4, 1/2); plane at 70 deg to the floor, "
                  "Omega = (0.5, 0, 4)")}

    mass = MASS
    inertia = inertia_matrix()
    observable_names = ("spin", "axial_spin")

    def build_system(self):
        R, _ = start_attitude()
        return rolling_body(MASS, inertia_matrix(), disk(RADIUS), gravity=GRAVITY, sample=R)

    def initial_state(self, variant):
        return rolling_start(self.system, *start_attitude())

    def invariants(self, variant):
        return ("constraints", "energy") + ATTITUDE_CASIMIRS

    def start_attitude(self):
        return start_attitude()

    def reference_equations(self):
        return disk_equations(inertia_matrix(), MASS, RADIUS, GRAVITY)

    def reference_observables(self, Omega, Gamma):
        """``spin = <Omega, Gamma>`` (about the vertical) and ``axial_spin = Omega_3`` (about the disk's
        axis), batch-first."""
        return {"spin": np.sum(Omega * Gamma, -1), "axial_spin": Omega[..., 2]}

    def figures(self, runs, *, tag=""):
        """The centre of mass' path (run and reference) with the path's and the tilt's errors; then the generic."""
        out = []
        for r in self.as_runs(runs).values():
            out += [plotting.FigureSpec("rolling-disk-path", lambda f, r=r: path_figure(r, f, tag=tag), 11, 4.2),
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


SCENE = RollingDisk()
