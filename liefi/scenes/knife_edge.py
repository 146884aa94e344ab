"""Knife edge on an inclined plane (paper Sec. 3, "The Knife Edge"): data only.

System (Bloch, Sec. 1.6) on the cotangent bundle ``T*R^3``, ``q = (x, y, phi)``:

* metric ``diag(m, m, J)``, so ``H = (p_x^2 + p_y^2)/(2m) + p_phi^2/(2J) + U``;
* potential ``U(q) = -m g x sin(alpha)``;
* one constraint vector ``e(q) = (sin phi, -cos phi, 0) / sqrt(m)`` (unit for
  the metric), i.e. ``J_1 = <p, e> = (p_x sin phi - p_y cos phi)/sqrt(m) = 0``.

Everything else -- ``H~``, ``lambda~``, the extended field ``(ext:sys:kinfe)``
and the gradient of ``V`` in ``(FI:knife)`` -- is derived by
:mod:`liefi.reduction` and :class:`liefi.FeedbackIntegrator` from these data.
In particular the paper's printed ``grad_q H~`` drops the phi-component
``-(p_x cos phi + p_y sin phi) J_1 / sqrt(m)`` (docs/paper_notes.md item 2); it vanishes on
the constraint set only, and liefi's derived gradient contains it.

``V`` penalizes ``J_1`` (target 0), the energy, and the momentum ``p_phi``
(the paper's ``J_2``; a state component, so its drift is reported as
``"p_phi"``).  Variants: ``extended`` (``V`` uses ``H~``, the paper's main
construction) and ``original`` (``V`` uses ``H``, the Remark after
``(theorem:crit:knife)``).

Paper's settings: ``m = J = g = 1``, ``alpha = pi/6``, start
``x = y = phi = p_x = p_y = 0``, ``p_phi = 0.5``; explicit Euler,
``dt = 1e-3``, ``t`` in ``[0, 200]``, ``k1 = k2 = k3 = 1000``.  (The paper's
simulation paragraph cites ``(theorem:crit:knife)`` for the system integrated;
it means ``(FI:knife)``, docs/paper_notes.md item 7.)

Reference: the *corrected* exact solution ``x = (1 - cos t)/2``,
``y = (t - sin t)/2``, ``phi = t/2`` (:func:`liefi.scenes.exact.knife_edge`);
the paper prints ``x = 1 - cos t``, ``phi = t`` (docs/paper_notes.md item 1).

Stability (docs/paper_notes.md item 3): at ``k = 1000``, ``dt = 1e-3`` the largest
eigenvalue of the Hessian of ``V`` on its zero set times ``dt`` is 2, exactly
Euler's real stability bound: the paper's run stays bounded (the stiff mode
neither grows nor decays), and ten percent more gain or step diverges.
"""

import numpy as np

from ..results import scene_figures as plotting
from ..phase_space import CotangentBundle
from ..systems.system import NonholonomicSystem
from . import exact as _exact
from .base import Scene, Variant


class KnifeEdge(Scene):
    name = "knife-edge"
    title = "Knife edge on an inclined plane"
    paper = "Sec. 3, The Knife Edge"
    reference = "exact"
    dt = 1e-3
    t_final = 200.0
    gains = 1000.0
    variants = {
        "extended": Variant("extended", "V penalizes J_1, p_phi and the extended energy H~ (FI:knife)"),
        "original": Variant(
            "original", "V penalizes J_1, p_phi and the original energy H (Remark after theorem:crit:knife)",
            energy="original",
        ),
    }
    error_variables = ("x", "y", "phi")
    stiff_study = True  # the stability report's work-precision study (exact solution, gains of 1000)

    # --- parameters and start (the paper's) ---------------------------------------
    m = 1.0
    J = 1.0
    g = 1.0
    alpha = np.pi / 6
    q0 = np.array([0.0, 0.0, 0.0])  # (x, y, phi)
    v0 = 0.0  # initial speed along the blade (p = m v0 (cos phi0, sin phi0))
    p_phi0 = 0.5

    # --- data ---------------------------------------------------------------------
    def potential(self, q):
        """``U(q) = -m g x sin(alpha)`` (batch-first, complex-step safe)."""
        return -self.m * self.g * np.sin(self.alpha) * q[..., 0]

    def constraint(self, q):
        """``e(q) = (sin phi, -cos phi, 0) / sqrt(m)`` as one row, shape ``(..., 1, 3)``."""
        phi = q[..., 2]
        e = np.stack([np.sin(phi), -np.cos(phi), np.zeros_like(phi)], -1) / np.sqrt(self.m)
        return e[..., None, :]

    def build_system(self):
        space = CotangentBundle(3, names=("x", "y", "phi"))
        metric = np.diag([self.m, self.m, self.J])
        return NonholonomicSystem(space, metric, self.constraint, self.potential)

    def initial_state(self, variant):
        phi0 = self.q0[2]
        p0 = [self.m * self.v0 * np.cos(phi0), self.m * self.v0 * np.sin(phi0), self.p_phi0]
        return np.concatenate([self.q0, p0])

    def invariants(self, variant):
        return ("constraints", "energy", "p_phi")

    def exact(self, t, variant):
        x0, y0, phi0 = self.q0
        return _exact.knife_edge(
            t, m=self.m, J=self.J, g=self.g, alpha=self.alpha, p_phi0=self.p_phi0,
            x0=x0, y0=y0, phi0=phi0, v0=self.v0,
        )

    def figures(self, runs, *, tag=""):
        """``figure:knife_cycloid``, ``figure:knife_exact`` and ``figure:knife_integrals`` of each run."""
        out = []
        for r in self.as_runs(runs).values():
            out += [
                plotting.FigureSpec("figure:knife_cycloid", lambda f, r=r: cycloid_figure(r, f, tag=tag), 13, 4.2),
                plotting.FigureSpec("figure:knife_exact", lambda f, r=r: errors_figure(r, f, tag=tag), 13, 3.4),
                plotting.FigureSpec("figure:knife_integrals", lambda f, r=r: integrals_figure(r, f, tag=tag), 13, 3.4),
            ]
        return out


def cycloid_figure(result, fig=None, *, tag=""):
    """``figure:knife_cycloid``: ``(x(t), y(t))`` numerical and exact; ``y`` horizontal, as in the paper.

    A third panel overlays both over the last two arches (``t >= t_final - 4 pi``), where
    the numerical error is largest.
    """
    fig = plotting.figure(fig, 13, 3.8)
    axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [2, 2, 1.3]})
    x, y = plotting.component(result, "x"), plotting.component(result, "y")
    xe, ye = plotting.reference_of(result, "x"), plotting.reference_of(result, "y")
    for ax, (xx, yy, what, color) in zip(axes[:2], ((x, y, "feedback integrator", "C0"), (xe, ye, "exact solution", "C1"))):
        ax.set_xlabel("$y$")
        ax.set_ylabel("$x$")
        ax.grid(alpha=0.3)
        ax.set_title(what, fontsize=10)
        if xx is None or yy is None:
            ax.text(0.5, 0.5, f"{what}: not available", transform=ax.transAxes, ha="center")
            continue
        ax.plot(yy, xx, lw=0.6, color=color)
    ax = axes[2]
    if x is not None and xe is not None:
        last = result.t >= result.t[-1] - 4 * np.pi
        ax.plot(ye[last], xe[last], lw=2.5, color="C1", alpha=0.6, label="exact")
        ax.plot(y[last], x[last], lw=0.9, color="C0", label="feedback integrator")
        ax.set_ylim(top=1.45 * max(np.max(x[last]), np.max(xe[last])))
        ax.legend(fontsize=8, loc="upper center", ncol=1, framealpha=0.9)
    ax.set_title("both, last two arches", fontsize=10)
    ax.set_xlabel("$y$")
    ax.set_ylabel("$x$")
    ax.grid(alpha=0.3)
    fig.suptitle(
        r"Knife edge trajectory $(x(t), y(t))$ ($y$ and $x$ swapped), "
        r"exact $x = (1-\cos t)/2$, $y = (t - \sin t)/2$" "\n"
        r"(the paper prints $x = 1-\cos t$, $\varphi = t$: docs/paper_notes.md, item 1)" + tag + "\n"
        + plotting.run_caption(result),
        fontsize=10,
    )
    return fig


def errors_figure(result, fig=None, *, tag=""):
    """``figure:knife_exact``: ``|Delta x|``, ``|Delta y|``, ``|Delta phi|`` against the exact solution."""
    panels = [(result.errors.get(k, f"no {k}"), rf"$|\Delta {plotting.label(k).strip('$')}|$", "log")
              for k in ("x", "y", "phi")]
    return plotting.panel_row(
        fig, result, panels,
        title=r"Error of $(x, y, \varphi)$ of the knife edge against the exact solution" + tag,
    )


def integrals_figure(result, fig=None, *, tag=""):
    """``figure:knife_integrals``: ``|Delta J_1|``, ``|Delta J_2| = |Delta p_phi|``, ``|Delta H|`` (original H)."""
    panels = []
    for k, ylabel in (("J_1", r"$|\Delta J_1|$"), ("p_phi", r"$|\Delta J_2| = |\Delta p_\varphi|$"),
                      ("h", r"$|\Delta H|$")):
        vals = result.invariants.get(k, plotting.component(result, k))
        panels.append((f"no {k}" if vals is None else plotting.drift(k, vals), ylabel, "log"))
    return plotting.panel_row(
        fig, result, panels,
        title=r"Constraint momentum error $|\Delta J_1|$, momentum error "
        r"$|\Delta p_\varphi|$ and energy error $|\Delta H|$ (original $H$) of the knife edge" + tag,
    )


SCENE = KnifeEdge()
