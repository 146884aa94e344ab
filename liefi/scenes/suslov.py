"""Suslov problem on SO(3) (paper Sec. 3.1): data only.

Rigid body with inertia ``I`` and the constraint ``<Pi, e> = 0``,
``e = I^{-1} a / sqrt(a . I^{-1} a)``, ``a = (0, 0, 1)``; start ``R = I``,
``Pi = (0, 1, 1)``; Euler, ``dt = 1e-3``, gains 100, ``t`` in [0, 10].
Exact solution ``Pi_1 = -tanh t``, ``Pi_2 = Pi_3 = sech t``.
Variants: ``extended`` (``V`` penalizes ``h~``, eq. ``(grad:V:Suslov)``) and
``original`` (``V`` penalizes ``h``, the Remark after ``(theorem:FI:Suslov)``).
"""

import numpy as np

from ..results import scene_figures as plotting
from ..groups import SO3
from ..phase_space import LieGroupPhaseSpace
from ..systems.system import NonholonomicSystem
from . import exact as _exact
from .base import Scene, Variant


class Suslov(Scene):
    name = "suslov"
    title = "Suslov problem on SO(3)"
    paper = "Sec. 3.1"
    reference = "exact"
    dt = 1e-3
    t_final = 10.0
    gains = 100.0
    variants = {
        "extended": Variant("extended", "V penalizes the extended energy h~ (grad:V:Suslov)"),
        "original": Variant("original", "V penalizes the original energy h (Remark)", energy="original"),
    }
    error_variables = ("Pi_1", "Pi_2", "Pi_3")
    #: ``figure:Suslov_integrals`` shows ``||R^T R - I||``: the rotation is integrated
    figures_need_configuration = True

    inertia = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 1.0, 2.0]])
    a = np.array([0.0, 0.0, 1.0])
    Pi0 = np.array([0.0, 1.0, 1.0])

    def build_system(self):
        Iinv_a = np.linalg.solve(self.inertia, self.a)
        e = Iinv_a / np.sqrt(self.a @ Iinv_a)
        return NonholonomicSystem(LieGroupPhaseSpace(SO3()), self.inertia, e)

    def initial_state(self, variant):
        return np.concatenate([np.eye(3).ravel(), self.Pi0])

    def exact(self, t, variant):
        return _exact.suslov(t, Pi0=self.Pi0)

    def figures(self, runs, *, tag=""):
        """``figure:Suslov_Pi_exact`` and ``figure:Suslov_integrals`` of each run."""
        out = []
        for r in self.as_runs(runs).values():
            out.append(plotting.FigureSpec("figure:Suslov_Pi_exact", lambda f, r=r: momentum_error_figure(r, f, tag=tag),
                                           11, 3.4))
            out.append(plotting.FigureSpec("figure:Suslov_integrals", lambda f, r=r: integrals_figure(r, f, tag=tag),
                                           11, 3.4))
        return out


def momentum_error_figure(result, fig=None, *, tag=""):
    """``figure:Suslov_Pi_exact``: ``Delta Pi_i(t) = Pi_i(t) - Pi_i,exact(t)``, one panel each."""
    panels = [
        (result.errors.get(k, f"no {k}"), rf"$\Delta {plotting.label(k).strip('$')}$", "linear")
        for k in ("Pi_1", "Pi_2", "Pi_3")
    ]
    return plotting.panel_row(
        fig, result, panels,
        title="Momentum error "
        r"$\Delta\Pi = \Pi - \Pi_{\rm exact}$ of the Suslov problem" + tag,
    )


def integrals_figure(result, fig=None, *, tag=""):
    """``figure:Suslov_integrals``: ``||R^T R - I||``, ``|Delta J|``, ``|Delta h|`` (original h)."""
    panels = []
    for k, ylabel in (("orthogonality", r"$\|R^TR - I\|$"), ("J_1", r"$|\Delta J|$"), ("h", r"$|\Delta h|$")):
        if k in result.invariants:
            panels.append((plotting.drift(k, result.invariants[k]), ylabel, "log"))
        else:
            panels.append((f"{k} not available\n(integrate the configuration)", ylabel, "log"))
    return plotting.panel_row(
        fig, result, panels,
        title=r"$\|R^TR-I\|$, constraint error $|\Delta J|$ and energy error "
        r"$|\Delta h|$ (original $h$) of the Suslov problem" + tag,
    )


SCENE = Suslov()
