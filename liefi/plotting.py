"""The paper's figures (Section 3) and a generic figure for the other scenes.

Every function here draws into a matplotlib ``Figure`` (or ``SubFigure``) and
returns it; matplotlib is imported *inside* the functions (Agg backend), never
at module import, so ``import liefi`` and ``liefi run --json`` stay free of it.

Figures that mirror the paper (titles cite the paper's figure labels):

=============================  ====================================================
function                       paper figure
=============================  ====================================================
:func:`suslov_momentum_error`  ``figure:Suslov_Pi_exact``: ``Delta Pi_i(t)``, 3 panels
:func:`suslov_integrals`       ``figure:Suslov_integrals``: ``||R^T R - I||``,
                               ``|Delta J|``, ``|Delta h|`` (needs the configuration)
:func:`knife_cycloid`          ``figure:knife_cycloid``: ``(x, y)`` numerical and
                               exact, axes swapped as in the paper
:func:`knife_errors`           ``figure:knife_exact``: ``|Delta x|, |Delta y|, |Delta phi|``
:func:`knife_integrals`        ``figure:knife_integrals``: ``|Delta J_1|``,
                               ``|Delta p_phi|``, ``|Delta H|``
:func:`oscillator_integrals`   ``figure:oscillator``: ``Delta H``, ``Delta H_y``,
                               ``J_c = p_x + y p_z``; left FI, right DLA
:func:`oscillator_poincare`    ``figure:Poincare:FI``: rows FI / DLA; ``y(t)``,
                               snapshots in the ``xz`` and ``z p_z`` planes
:func:`generic`                scenes without a paper figure: ``|error|`` and
                               drifts vs ``t`` (semilogy)
=============================  ====================================================

:func:`scene_figures` lists the figures of one run, :func:`plot_run` writes
them into one PNG (``liefi run --plot``), :func:`save` writes one figure.
"""

from __future__ import annotations

import math

import numpy as np

#: scenes whose figures need the group element integrated (``||R^T R - I||``)
_NEEDS_CONFIGURATION = {"suslov"}

#: tiny positive floor: a log axis cannot show 0, so exact zeros are masked
_TINY = 1e-300

#: name of a quantity -> mathtext label
_LABELS = {
    "Pi_1": r"\Pi_1", "Pi_2": r"\Pi_2", "Pi_3": r"\Pi_3", "Pi_4": r"\Pi_4",
    "Pi_theta": r"\Pi_\theta", "Pi_x": r"\Pi_x", "Pi_y": r"\Pi_y", "Pi_psi": r"\Pi_\psi",
    "phi": r"\varphi", "theta": r"\theta", "psi": r"\psi",
    "p_phi": r"p_\varphi", "p_theta": r"p_\theta", "p_psi": r"p_\psi",
    "p_x": "p_x", "p_y": "p_y", "p_z": "p_z",
    "h": "h", "h~": r"\tilde h", "H": "H", "H_y": "H_y",
    "orthogonality": r"\|R^TR-I\|",
}


def needs_configuration(scene_name: str) -> bool:
    """True when the scene's paper figure needs the group element (Suslov: ``||R^T R - I||``)."""
    return scene_name in _NEEDS_CONFIGURATION


_GREEK = {"Pi", "theta", "phi", "psi", "lambda", "mu", "xi", "alpha", "omega", "Omega"}


def _tex_word(w):
    if w == "phi":
        return r"\varphi"
    return "\\" + w if w in _GREEK else w


def label(name: str) -> str:
    """Mathtext for a variable or invariant name (``"Pi_theta_2"`` -> ``$\\Pi_{\\theta,2}$``)."""
    if name in _LABELS:
        return f"${_LABELS[name]}$"
    if name in ("energy", "penalty", "constraints"):
        return name
    if name.endswith("~"):
        return f"$\\tilde {{{label(name[:-1]).strip('$')}}}$"
    base, *subs = name.split("_")
    if not subs:
        return f"${_tex_word(base)}$" if (len(base) == 1 or base in _GREEK) else name
    return f"${_tex_word(base)}_{{{','.join(_tex_word(w) for w in subs)}}}$"


# --------------------------------------------------------------------------------------
# matplotlib plumbing (imported lazily)
# --------------------------------------------------------------------------------------
def _new_figure(width, height):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained", dpi=110)


def save(fig, path):
    """Write ``fig`` to ``path`` (PNG); returns ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    fig.savefig(path)
    return path


def _figure(fig, width, height):
    return _new_figure(width, height) if fig is None else fig


def _drift(name, values):
    """``|I(t) - I(0)|``; constraint momenta and the orthogonality defect target 0."""
    values = np.asarray(values, float)
    if name.startswith("J_") or name == "orthogonality":
        return np.abs(values)
    return np.abs(values - values[0])


def _logplot(ax, t, values, *, label=None, **kw):
    """``semilogy`` of ``|values|`` with exact zeros masked.

    A series that is identically zero cannot be drawn on a log axis: it gets a
    legend entry ``... = 0`` (with a label) or a note in the panel (without).
    """
    a = np.abs(np.asarray(values, float))
    shown = np.where(a > _TINY, a, np.nan)
    if np.all(np.isnan(shown)):
        if label is not None:
            ax.plot([], [], label=f"{label} $\\equiv 0$", **dict(kw, ls=":"))
        else:
            ax.text(0.5, 0.5, "identically 0", transform=ax.transAxes, ha="center", va="center", color="gray")
        return
    ax.plot(t, shown, label=label, **kw)
    if label is None and log_span(a[1:] if a.size > 1 else a) < 1.0:
        # less than a decade (t = 0 excluded): a linear axis reads better
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
        return
    ax.set_yscale("log")


def _run_caption(result):
    scheme = result.scheme
    name = "Euler" if scheme == "euler" else ("first-order DLA" if scheme == "dla" else scheme)
    step = r"$h$" if scheme == "dla" else r"$\Delta t$"
    gains = ""
    if scheme != "dla" and result.gains:
        vals = sorted(set(result.gains.values()))
        gains = f", gains {vals[0]:g}" if len(vals) == 1 else ", gains " + ", ".join(
            f"{label(k)}: {v:g}" for k, v in result.gains.items()
        )
    return f"{name}, {step} = {result.dt:g}, $0 \\leq t \\leq {result.t_final:g}${gains}"


def _variant_tag(result, default_variant=None):
    if default_variant is not None and result.variant == default_variant:
        return ""
    return f" [variant {result.variant}]"


def _get(result, name):
    """A saved component, an observable, or ``None``."""
    if name in result.names:
        return np.asarray(result[name])
    return None


# --------------------------------------------------------------------------------------
# Suslov problem (Sec. 3.1)
# --------------------------------------------------------------------------------------
def suslov_momentum_error(result, fig=None, *, tag=""):
    """``figure:Suslov_Pi_exact``: ``Delta Pi_i(t) = Pi_i(t) - Pi_i,exact(t)``, one panel each."""
    fig = _figure(fig, 11, 3.4)
    axes = fig.subplots(1, 3, sharex=True)
    for ax, k in zip(axes, ("Pi_1", "Pi_2", "Pi_3")):
        err = result.errors.get(k)
        if err is None:
            ax.text(0.5, 0.5, f"no {k}", transform=ax.transAxes, ha="center")
            continue
        ax.plot(result.t, err, lw=0.9, color="C0")
        ax.set_xlabel("$t$")
        ax.set_ylabel(rf"$\Delta {_LABELS[k]}$")
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
        ax.grid(alpha=0.3)
    fig.suptitle(
        "Fig. figure:Suslov_Pi_exact: momentum error "
        r"$\Delta\Pi = \Pi - \Pi_{\rm exact}$ of the Suslov problem" + tag + "\n" + _run_caption(result),
        fontsize=10,
    )
    return fig


def suslov_integrals(result, fig=None, *, tag=""):
    """``figure:Suslov_integrals``: ``||R^T R - I||``, ``|Delta J|``, ``|Delta h|`` (original h)."""
    fig = _figure(fig, 11, 3.4)
    axes = fig.subplots(1, 3, sharex=True)
    panels = (
        ("orthogonality", r"$\|R^TR - I\|$"),
        ("J_1", r"$|\Delta J|$"),
        ("h", r"$|\Delta h|$"),
    )
    for ax, (k, ylabel) in zip(axes, panels):
        ax.set_xlabel("$t$")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if k not in result.invariants:
            ax.text(0.5, 0.5, f"{k} not available\n(integrate the configuration)", transform=ax.transAxes,
                    ha="center", va="center", color="gray")
            continue
        _logplot(ax, result.t, _drift(k, result.invariants[k]), lw=0.9, color="C0")
    fig.suptitle(
        r"Fig. figure:Suslov_integrals: $\|R^TR-I\|$, constraint error $|\Delta J|$ and energy error "
        r"$|\Delta h|$ (original $h$) of the Suslov problem" + tag + "\n" + _run_caption(result),
        fontsize=10,
    )
    return fig


# --------------------------------------------------------------------------------------
# Knife edge (Sec. 3.2)
# --------------------------------------------------------------------------------------
def _exact_of(result, name):
    """The reference value ``data - error`` of a compared component."""
    data, err = _get(result, name), result.errors.get(name)
    if data is None or err is None:
        return None
    return data - err


def knife_cycloid(result, fig=None, *, tag=""):
    """``figure:knife_cycloid``: ``(x(t), y(t))`` numerical and exact; ``y`` horizontal, as in the paper.

    A third panel overlays both over the last two arches (``t >= t_final - 4 pi``), where
    the numerical error is largest.
    """
    fig = _figure(fig, 13, 3.8)
    axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [2, 2, 1.3]})
    x, y = _get(result, "x"), _get(result, "y")
    xe, ye = _exact_of(result, "x"), _exact_of(result, "y")
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
        r"Fig. figure:knife_cycloid: knife edge trajectory $(x(t), y(t))$ ($y$ and $x$ swapped), "
        r"exact $x = (1-\cos t)/2$, $y = (t - \sin t)/2$" "\n"
        r"(the paper prints $x = 1-\cos t$, $\varphi = t$: NOTES.md slip 1)" + tag + "\n" + _run_caption(result),
        fontsize=10,
    )
    return fig


def knife_errors(result, fig=None, *, tag=""):
    """``figure:knife_exact``: ``|Delta x|``, ``|Delta y|``, ``|Delta phi|`` against the exact solution."""
    fig = _figure(fig, 11, 3.4)
    axes = fig.subplots(1, 3, sharex=True)
    for ax, k in zip(axes, ("x", "y", "phi")):
        ax.set_xlabel("$t$")
        ax.set_ylabel(rf"$|\Delta {_LABELS.get(k, k)}|$")
        ax.grid(alpha=0.3)
        if k not in result.errors:
            ax.text(0.5, 0.5, f"no {k}", transform=ax.transAxes, ha="center")
            continue
        _logplot(ax, result.t, result.errors[k], lw=0.8, color="C0")
    fig.suptitle(
        r"Fig. figure:knife_exact: error of $(x, y, \varphi)$ of the knife edge against the exact solution"
        + tag + "\n" + _run_caption(result),
        fontsize=10,
    )
    return fig


def knife_integrals(result, fig=None, *, tag=""):
    """``figure:knife_integrals``: ``|Delta J_1|``, ``|Delta J_2| = |Delta p_phi|``, ``|Delta H|`` (original H)."""
    fig = _figure(fig, 11, 3.4)
    axes = fig.subplots(1, 3, sharex=True)
    panels = (("J_1", r"$|\Delta J_1|$"), ("p_phi", r"$|\Delta J_2| = |\Delta p_\varphi|$"), ("h", r"$|\Delta H|$"))
    for ax, (k, ylabel) in zip(axes, panels):
        ax.set_xlabel("$t$")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if k in result.invariants:
            vals = result.invariants[k]
        elif _get(result, k) is not None:
            vals = _get(result, k)
        else:
            ax.text(0.5, 0.5, f"no {k}", transform=ax.transAxes, ha="center")
            continue
        _logplot(ax, result.t, _drift(k, vals), lw=0.8, color="C0")
    fig.suptitle(
        r"Fig. figure:knife_integrals: constraint momentum error $|\Delta J_1|$, momentum error "
        r"$|\Delta p_\varphi|$ and energy error $|\Delta H|$ (original $H$) of the knife edge"
        + tag + "\n" + _run_caption(result),
        fontsize=10,
    )
    return fig


# --------------------------------------------------------------------------------------
# Nonholonomic oscillator (Sec. 3.7)
# --------------------------------------------------------------------------------------
def oscillator_quantities(result):
    """``(Delta H, Delta H_y, J_c)`` along a run of the oscillator, from its ``q, p``.

    ``H = |p|^2/2 + |q|^2/2``, ``H_y = (p_y^2 + y^2)/2``, ``J_c = p_x + y p_z``
    (``= sqrt(1 + y^2) J_1``), as in ``figure:oscillator``.
    """
    q = [_get(result, k) for k in ("x", "y", "z")]
    p = [_get(result, k) for k in ("p_x", "p_y", "p_z")]
    if any(v is None for v in q + p):
        raise KeyError(f"oscillator run without x, y, z, p_x, p_y, p_z (has {result.names})")
    x, y, z = q
    px, py, pz = p
    H = 0.5 * (px**2 + py**2 + pz**2) + 0.5 * (x**2 + y**2 + z**2)
    Hy = 0.5 * (py**2 + y**2)
    Jc = px + y * pz
    return H - H[0], Hy - Hy[0], Jc


def oscillator_integrals(fi=None, dla=None, fig=None, *, tag=""):
    """``figure:oscillator``: ``Delta H``, ``Delta H_y``, ``J_c`` vs ``t``; left column FI, right DLA.

    Either run may be ``None`` (``liefi run oscillator --plot`` draws the one it has).
    Signed values on linear axes, as the paper prints them.
    """
    runs = [(r, w) for r, w in ((fi, "feedback integrator"), (dla, "DLA")) if r is not None]
    fig = _figure(fig, 5.5 * len(runs) + 0.5, 7.5)
    axes = np.asarray(fig.subplots(3, len(runs), sharex=True, squeeze=False))
    names = (r"$\Delta H$", r"$\Delta H_y$", r"$J_c = p_x + y\,p_z$")
    for j, (r, what) in enumerate(runs):
        qs = oscillator_quantities(r)
        for i, (val, ylabel) in enumerate(zip(qs, names)):
            ax = axes[i, j]
            ax.plot(r.t, val, lw=0.6, color="C0" if r.scheme != "dla" else "C3")
            ax.set_ylabel(ylabel)
            ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
            ax.grid(alpha=0.3)
        axes[0, j].set_title(f"{what}\n{_run_caption(r)}", fontsize=9)
        axes[-1, j].set_xlabel("$t$")
    fig.suptitle(
        r"Fig. figure:oscillator: energy error $\Delta H$, $y$-energy error $\Delta H_y$ and constraint $J_c$ "
        "of the nonholonomic oscillator" + tag,
        fontsize=10,
    )
    return fig


def oscillator_poincare(runs, fig=None, *, tag=""):
    """``figure:Poincare:FI``: one row per run (FI, DLA): ``y(t)``, snapshots in the ``xz`` plane
    and in the ``z p_z`` (DLA: ``z v_z``) plane when ``y`` crosses 0 upwards.

    ``runs`` is a list of ``(result, sections)`` or ``(result, sections, reference_sections)``;
    ``sections`` holds ``x, z, p_z`` at the crossings (``oscillator.poincare_section``).  The
    reference sections (the same crossings of the reference solution), when given, are drawn
    underneath in gray: not in the paper, but they show what the snapshots should look like.
    """
    fig = _figure(fig, 12, 3.4 * len(runs) + 0.4)
    axes = np.asarray(fig.subplots(len(runs), 3, squeeze=False))
    for i, run in enumerate(runs):
        r, sec = run[0], run[1] or {}
        ref = run[2] if len(run) > 2 else None
        dla = r.scheme == "dla"
        color = "C3" if dla else "C0"
        what = "first-order DLA" if dla else "feedback integrator (Euler)"
        a0, a1, a2 = axes[i]
        y = _get(r, "y")
        if y is not None:
            a0.plot(r.t, y, lw=0.5, color=color)
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
        r"Fig. figure:Poincare:FI: nonholonomic oscillator, Poincaré section $y = 0$, $\dot y > 0$; "
        + (f"rows: {rows}, " if len(runs) > 1 else "")
        + f"$0 \\leq t \\leq {T:g}$" + tag,
        fontsize=10,
    )
    return fig


# --------------------------------------------------------------------------------------
# generic figure
# --------------------------------------------------------------------------------------
def generic(result, fig=None, *, title=None, tag=""):
    """Errors ``|z(t) - z_ref(t)|`` and drifts ``|I(t) - I(0)|`` vs ``t``, both semilogy."""
    fig = _figure(fig, 11, 4.0)
    a0, a1 = fig.subplots(1, 2, sharex=True)
    ref = "exact solution" if result.reference == "exact" else "numerical reference (DOP853, tol 1e-12)"
    for i, (k, err) in enumerate(result.errors.items()):
        _logplot(a0, result.t, err, lw=0.8, label=label(k), color=f"C{i % 10}", ls="-" if i % 2 == 0 else "--")
    a0.set_title(f"error against the {ref}", fontsize=9)
    a0.set_xlabel("$t$")
    a0.set_ylabel(r"$|z(t) - z_{\rm ref}(t)|$")
    a0.grid(alpha=0.3)
    if result.errors:
        a0.legend(fontsize=8, ncol=2)
    for i, (k, val) in enumerate(result.invariants.items()):
        _logplot(a1, result.t, _drift(k, val), lw=0.8, label=label(k), color=f"C{i % 10}", ls="-" if i % 2 == 0 else "--")
    a1.set_title(r"drift $|I(t) - I(0)|$ ($|J_i(t)|$ for the constraints)", fontsize=9)
    a1.set_xlabel("$t$")
    a1.set_ylabel(r"$|\Delta I|$")
    a1.grid(alpha=0.3)
    drifts = [_drift(k, v) for k, v in result.invariants.items()]
    for ax, series in ((a0, list(result.errors.values())), (a1, drifts)):
        if series and all(np.all(np.abs(np.asarray(v)) <= _TINY) for v in series):
            ax.text(0.5, 0.5, "all identically 0", transform=ax.transAxes, ha="center", va="center", color="gray")
            ax.set_yticks([])
    if result.invariants:
        a1.legend(fontsize=8, ncol=2)
    head = title or f"{result.scene}"
    fig.suptitle(f"{head}, variant {result.variant} (no figure in the paper)\n{_run_caption(result)}", fontsize=10)
    return fig


# --------------------------------------------------------------------------------------
# a run's figures
# --------------------------------------------------------------------------------------
def scene_figures(result, *, title=None, sections=None):
    """The figures of one run: a list of ``(key, draw)`` with ``draw(fig)`` drawing into a figure.

    ``key`` is the paper's figure label (``"figure:Suslov_Pi_exact"``) or ``"generic"``.
    For the oscillator, ``sections`` is ``oscillator.poincare_section(result)`` or the pair
    ``(sections, reference_sections)`` of :func:`liefi.reproduce.oscillator_sections`.
    """
    s = result.scene
    if s == "suslov":
        return [
            ("figure:Suslov_Pi_exact", lambda f: suslov_momentum_error(result, f)),
            ("figure:Suslov_integrals", lambda f: suslov_integrals(result, f)),
        ]
    if s == "knife-edge":
        return [
            ("figure:knife_cycloid", lambda f: knife_cycloid(result, f)),
            ("figure:knife_exact", lambda f: knife_errors(result, f)),
            ("figure:knife_integrals", lambda f: knife_integrals(result, f)),
        ]
    if s == "oscillator":
        figs = [
            ("figure:oscillator", lambda f: oscillator_integrals(
                None if result.scheme == "dla" else result, result if result.scheme == "dla" else None, f)),
        ]
        if sections is not None:  # (sections, reference sections) or sections
            run = (result, *sections) if isinstance(sections, tuple) else (result, sections)
            figs.append(("figure:Poincare:FI", lambda f: oscillator_poincare([run], f)))
        return figs
    return [("generic", lambda f: generic(result, f, title=title))]


_HEIGHTS = {"figure:oscillator": 7.5, "figure:Poincare:FI": 3.8, "figure:knife_cycloid": 4.2, "generic": 4.0}


def plot_run(result, path, *, title=None, sections=None):
    """Write every figure of ``result`` (see :func:`scene_figures`) stacked into one PNG."""
    figs = scene_figures(result, title=title, sections=sections)
    heights = [_HEIGHTS.get(k, 3.5) for k, _ in figs]
    width = {"oscillator": 12, "knife-edge": 13}.get(result.scene, 11)
    fig = _new_figure(width, sum(heights))
    subs = fig.subfigures(len(figs), 1, height_ratios=heights) if len(figs) > 1 else [fig]
    for sub, (_, draw) in zip(np.atleast_1d(subs), figs):
        draw(sub)
    save(fig, path)
    return path


def log_span(values):
    """Decades spanned by the nonzero ``|values|`` (helps decide on a log axis)."""
    a = np.abs(np.asarray(values, float))
    a = a[a > 0]
    if a.size == 0:
        return 0.0
    return math.log10(a.max() / a.min())
