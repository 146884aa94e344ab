r"""The nonholonomic oscillator (paper Sec. 3, subsection "The Nonholonomic Oscillator"): data only.

``T*R^3`` with ``q = (x, y, z)``, metric ``I``, potential ``|q|^2/2`` and the
constraint ``p . e = 0``, ``e = (1, 0, y)/sqrt(1 + y^2)`` (i.e.
``p_x + y p_z = 0``).  ``h~``, ``lambda~`` and every gradient are derived by
the library; the paper's printed ``grad H~``, ``lambda~`` and ``grad V`` are
test oracles only.

``V`` is the paper's

.. math:: V = \frac{k_1}{2} (\tilde H - \tilde H_0)^2
          + \frac{k_2}{2} (H_y - H_{y0})^2 + \frac{k_3}{2} J^2,

with ``H_y = p_y^2/2 + y^2/2`` (the :class:`~liefi.Invariant` ``"H_y"``; the
paper's ``H_{y0}(q, p)`` means ``H_y(q, p)``, docs/paper_notes.md item 5) and gains
``k_1 = 500`` (``"energy"``), ``k_2 = 300`` (``"H_y"``), ``k_3 = 300``
(``"J_1"``), ``(no:gains)``.  ``H_y`` is a first integral of the extended field
only on the constraint set (its rate off it is ``O(J)``), so this ``V`` meets
the assumption A1 only there -- the paper's choice, kept.

Start ``q(0) = (1, 1, 1)``, ``p(0) = 0`` (``(ns:ic)``; "``p(0,0,0)``" means
``p(0)``), Euler, ``dt = 1e-3``, ``t`` in ``[0, 200]``.  Reference: DOP853
(rtol 1e-12) on the constrained field, with the ``y`` subsystem replaced by its
closed form ``y = cos t`` (:func:`liefi.scenes.exact.oscillator_y`).

Extra scheme ``"dla"``: the first-order discrete Lagrange--d'Alembert
integrator, built from the same system by
:meth:`liefi.schemes.dla_integrator.DLAIntegrator.from_system`, started at ``q_0 = q_1 = (1, 1, 1)``
(``(ns:dla:ic)``), with the discrete momentum ``p_{i+1} = (q_{i+1} - q_i)/h``
paired with ``q_{i+1}``; the drifts reported for it are those of
``J = p . e(q)``, ``H``, ``H~`` and ``H_y`` at these pairs.  (The DLA keeps
``p_{i+1} . e(q_i) = 0`` exactly; ``p_{i+1} . e(q_{i+1})`` is ``O(h)``.)

:func:`poincare_section` extracts the snapshots of Figure
``(figure:Poincare:FI)``.
"""

import time

import numpy as np

from ..results import scene_figures as plotting
from ..schemes.dla_integrator import DLAIntegrator
from ..integrator.feedback import Invariant
from ..phase_space import CotangentBundle
from ..systems.system import NonholonomicSystem
from . import exact as _exact
from .base import PaperRun, Scene, Variant

#: the Poincaré sections of the oscillator run over [0, 400] (paper, "Comparisons")
POINCARE_T_FINAL = 400.0


def _y_energy(z):
    """``H_y = p_y^2/2 + y^2/2`` (complex-step safe)."""
    return 0.5 * z[..., 4] ** 2 + 0.5 * z[..., 1] ** 2


#: The energy of the ``y`` dynamics, a first integral on the constraint set.
H_Y = Invariant("H_y", _y_energy)


class Oscillator(Scene):
    name = "oscillator"
    title = "Nonholonomic oscillator on T*R^3"
    paper = "Sec. 3, The Nonholonomic Oscillator"
    reference = "numerical"
    dt = 1e-3
    t_final = 200.0
    gains = {"energy": 500.0, "H_y": 300.0, "J_1": 300.0}
    variants = {
        "extended": Variant("extended", "V penalizes the extended energy H~ (as printed)"),
        "original": Variant("original", "V penalizes the original energy H", energy="original"),
    }
    error_variables = ("x", "y", "z", "p_x", "p_y", "p_z")
    extra_schemes = ("dla",)

    q0 = (1.0, 1.0, 1.0)
    p0 = (0.0, 0.0, 0.0)

    def build_system(self):
        def constraint(q):
            y = q[..., 1]
            s = np.sqrt(1.0 + y**2)
            return np.stack([1.0 / s, np.zeros_like(y), y / s], -1)[..., None, :]

        def potential(q):
            return 0.5 * np.sum(q**2, -1)

        space = CotangentBundle(3, names=("x", "y", "z"))
        return NonholonomicSystem(space, np.eye(3), constraint, potential)

    def initial_state(self, variant):
        return np.concatenate([np.asarray(self.q0, float), np.asarray(self.p0, float)])

    def invariants(self, variant):
        return ("constraints", "energy", H_Y)

    def exact(self, t, variant):
        ref = dict(self.numerical_reference(t, variant))
        ref.update(_exact.oscillator_y(t, self.q0[1], self.p0[1]))
        return ref

    def paper_runs(self, variant):
        """``figure:oscillator``: FI (Euler) and DLA on the paper's horizon ``[0, 200]``;
        ``figure:Poincare:FI``: both on ``[0, 400]`` with every step saved (the crossings
        ``y = 0`` are interpolated between saved points).  The DLA does not see ``V``, so
        its runs do not depend on the variant: they run once and every variant reuses them."""
        return (
            PaperRun("fi", scheme="euler", experiment="figure:oscillator"),
            PaperRun("dla", scheme="dla", experiment="figure:oscillator", variant_independent=True),
            PaperRun("fi-long", scheme="euler", t_final=POINCARE_T_FINAL, save_every=1,
                     experiment="figure:Poincare:FI"),
            PaperRun("dla-long", scheme="dla", t_final=POINCARE_T_FINAL, save_every=1,
                     experiment="figure:Poincare:FI", variant_independent=True),
        )

    def figures(self, runs, *, tag=""):
        """``figure:oscillator`` (a column per run on the paper's horizon: FI left, DLA right) and
        ``figure:Poincare:FI`` (a row per long run; a single run serves both figures)."""
        runs = self.as_runs(runs)
        short = [r for k, r in runs.items() if not k.endswith("-long")]
        long = [r for k, r in runs.items() if k.endswith("-long")] or short
        short.sort(key=lambda r: r.scheme == "dla")
        long.sort(key=lambda r: r.scheme == "dla")
        out = []
        if short:
            out.append(plotting.FigureSpec("figure:oscillator", lambda f: integrals_figure(short, f, tag=tag),
                                           5.5 * len(short) + 1.0, 7.5))
        if long:
            out.append(plotting.FigureSpec(
                "figure:Poincare:FI",
                lambda f: poincare_figure([(r, *sections_with_reference(r)) for r in long], f, tag=tag),
                12, 3.4 * len(long) + 0.4,
            ))
        return out

    def run_extra(self, scheme, variant, dt, T, save_every, fi):
        """``"dla"``: the discrete Lagrange--d'Alembert integrator from the same data."""
        if scheme != "dla":
            return super().run_extra(scheme, variant, dt, T, save_every, fi)
        dla = DLAIntegrator.from_system(self.system)
        n = self.system.space.n
        y0 = np.asarray(self.initial_state(variant), float)
        n_steps = int(round(T / dt))
        q0, q1 = dla.initial_pair(y0[:n], y0[n:], dt)
        import importlib.util

        if importlib.util.find_spec("numba") is not None:
            # the same DLA step generated from the data and compiled (bitwise equal to liefi.schemes.dla_integrator)
            from .. import engine

            t, q, p, cpu, updates = engine.compile_dla(self.system).run(q0, q1, dt, n_steps, save_every=save_every)
            return t, np.concatenate([q, p], 0), self.system.state_names, cpu, updates, updates
        start = time.process_time()
        res = dla.run(q0, q1, dt, n_steps, save_every)
        cpu = time.process_time() - start
        Y = np.concatenate([res.q, res.p], 0)
        return res.t, Y, self.system.state_names, cpu, res.steps, res.rhs_evaluations


def poincare_section(result, coordinates=("x", "z", "p_z"), variable="y", momentum="p_y"):
    """Snapshots where ``y`` crosses zero upward (Figure ``(figure:Poincare:FI)``).

    Between consecutive saved points ``t_k < t_{k+1}`` with ``y_k < 0 <= y_{k+1}``
    and ``p_y > 0`` (the upward crossing, ``y' = p_y``) the crossing time and the
    coordinates are interpolated linearly.  The interpolation error is
    ``O(dt_saved^2)``, so run with ``save_every=1`` (or close), e.g.::

        from liefi import scenes
        from liefi.scenes.oscillator import poincare_section
        sc = scenes.get("oscillator")
        fi = poincare_section(sc.run(t_final=400, save_every=1))
        dla = poincare_section(sc.run(t_final=400, save_every=1, scheme="dla"))

    For the DLA run ``p_z`` is the discrete momentum, i.e. the paper's ``v_z``.

    Parameters
    ----------
    result : RunResult
        A run of the oscillator (any scheme), or anything with ``t``, ``y``
        (components first, time last) and ``names``.
    coordinates : sequence of str
        Components to report at the crossings (default ``x, z, p_z``).
    variable, momentum : str
        The crossing variable and its momentum (default ``y``, ``p_y``).

    Returns
    -------
    dict
        ``"t"`` and one array per coordinate, all of length the number of
        upward crossings.
    """
    names = tuple(result.names)
    Y = np.asarray(result.y)
    t = np.asarray(result.t, float)
    y = Y[names.index(variable)]
    py = Y[names.index(momentum)]
    k = np.nonzero((y[:-1] < 0.0) & (y[1:] >= 0.0))[0]
    s = -y[k] / (y[k + 1] - y[k])  # fraction of the interval at the crossing
    s_py = py[k] + s * (py[k + 1] - py[k])
    keep = s_py > 0.0
    k, s = k[keep], s[keep]
    out = {"t": t[k] + s * (t[k + 1] - t[k])}
    for c in coordinates:
        v = Y[names.index(c)]
        out[c] = v[k] + s * (v[k + 1] - v[k])
    return out


SCENE = Oscillator()


def sections_with_reference(result):
    """``(sections, reference_sections)`` of an oscillator run (``figure:Poincare:FI``).

    ``sections`` is :func:`poincare_section` of the run; the reference sections apply
    it to the reference solution at the saved times (``data - error``: no extra
    integration), or are ``None`` when the run lacks errors.
    """
    from types import SimpleNamespace

    sec = poincare_section(result)
    if not all(n in result.errors for n in result.names):
        return sec, None
    Y = np.stack([np.asarray(result[n]) - np.asarray(result.errors[n]) for n in result.names])
    return sec, poincare_section(SimpleNamespace(t=result.t, y=Y, names=result.names))


def quantities(result):
    """``(Delta H, Delta H_y, J_c)`` along a run, as ``figure:oscillator`` plots them.

    ``H`` (the original energy ``h``), ``H_y`` and ``J_1`` are the run's invariants
    (derived by the library); ``J_c = p_x + y p_z = sqrt(1 + y^2) J_1`` undoes the
    normalization of the constraint vector ``e``.
    """
    inv = result.invariants
    missing = [k for k in ("h", "H_y", "J_1") if k not in inv]
    if missing or "y" not in result.names:
        raise KeyError(f"oscillator run without {missing or ['y']} (has {sorted(inv)}, {result.names})")
    H, Hy = np.asarray(inv["h"]), np.asarray(inv["H_y"])
    Jc = np.sqrt(1.0 + np.asarray(result["y"]) ** 2) * np.asarray(inv["J_1"])
    return H - H[0], Hy - Hy[0], Jc


def integrals_figure(runs, fig=None, *, tag=""):
    """``figure:oscillator``: ``Delta H``, ``Delta H_y``, ``J_c`` vs ``t``, one column per run
    (the paper: feedback integrator left, DLA right).  Signed values on linear axes, as printed."""
    fig = plotting.figure(fig, 5.5 * len(runs) + 1.0, 7.5)
    axes = np.asarray(fig.subplots(3, len(runs), sharex=True, squeeze=False))
    names = (r"$\Delta H$", r"$\Delta H_y$", r"$J_c = p_x + y\,p_z$")
    for j, r in enumerate(runs):
        what = "DLA" if r.scheme == "dla" else "feedback integrator"
        for i, (val, ylabel) in enumerate(zip(quantities(r), names)):
            ax = axes[i, j]
            ax.plot(*plotting.thinned(r.t, val), lw=0.6, color="C3" if r.scheme == "dla" else "C0")
            ax.set_ylabel(ylabel)
            ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
            ax.grid(alpha=0.3)
        axes[0, j].set_title(f"{what}\n{plotting.run_caption(r)}", fontsize=9)
        axes[-1, j].set_xlabel("$t$")
    fig.suptitle(
        r"Energy error $\Delta H$, $y$-energy error $\Delta H_y$ and constraint $J_c$ "
        "of the nonholonomic oscillator" + tag,
        fontsize=10,
    )
    return fig


def poincare_figure(runs, fig=None, *, tag=""):
    """``figure:Poincare:FI``: one row per run (FI, DLA): ``y(t)``, snapshots in the ``xz`` plane
    and in the ``z p_z`` (DLA: ``z v_z``) plane when ``y`` crosses 0 upwards.

    ``runs`` is a list of ``(result, sections)`` or ``(result, sections, reference_sections)``
    (:func:`sections_with_reference`).  The reference sections, when given, are drawn
    underneath in gray: not in the paper, but they show what the snapshots should look like.
    """
    fig = plotting.figure(fig, 12, 3.4 * len(runs) + 0.4)
    axes = np.asarray(fig.subplots(len(runs), 3, squeeze=False))
    for i, run in enumerate(runs):
        r, sec = run[0], run[1] or {}
        ref = run[2] if len(run) > 2 else None
        dla = r.scheme == "dla"
        color = "C3" if dla else "C0"
        what = "first-order DLA" if dla else f"feedback integrator ({r.scheme})"
        a0, a1, a2 = axes[i]
        y = plotting.component(r, "y")
        if y is not None:
            a0.plot(*plotting.thinned(r.t, y), lw=0.5, color=color)
        a0.set_xlabel("$t$")
        a0.set_ylabel("$y$")
        a0.set_title(f"{what}: $y(t)$", fontsize=9)
        a0.grid(alpha=0.3)
        mom = "v" if dla else "p"
        n = len(sec.get("z", ()))
        for ax, (u, v, xl, yl) in ((a1, ("x", "z", "$x$", "$z$")), (a2, ("z", "p_z", "$z$", f"${mom}_z$"))):
            if ref is not None and u in ref and v in ref:
                ax.plot(ref[u], ref[v], "o", ms=5, mfc="none", mec="0.6", mew=0.8, label="reference (DOP853)")
            if u in sec and v in sec:
                ax.plot(sec[u], sec[v], ".", ms=4, color=color, label=what)
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            ax.grid(alpha=0.3)
        a1.set_title(f"snapshots in the $xz$ plane ({n} crossings)", fontsize=9)
        a2.set_title(f"snapshots in the $z{mom}_z$ plane", fontsize=9)
        if ref is not None:
            a2.legend(fontsize=7, loc="center", framealpha=0.8)
    T = max(run[0].t_final for run in runs) if runs else 0
    rows = " / ".join("DLA" if run[0].scheme == "dla" else "feedback integrator" for run in runs)
    fig.suptitle(
        r"Nonholonomic oscillator, Poincaré section $y = 0$, $\dot y > 0$; "
        + (f"rows: {rows}, " if len(runs) > 1 else "")
        + f"$0 \\leq t \\leq {T:g}$" + tag,
        fontsize=10,
    )
    return fig
