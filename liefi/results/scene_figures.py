"""Generic figures and the helpers scenes draw their own figures with (liefi's own figures: scenes, bench,
reproduce).  A user's figures of their own run are :mod:`liefi.results.plot` (``liefi/results/plot.py``).

Every function here draws into a matplotlib ``Figure`` (or ``SubFigure``) and
returns it; matplotlib is imported *inside* the functions (Agg backend), never
at module import, so ``import liefi`` and ``liefi run --json`` stay free of it.
Nothing here knows a scene: a scene's own figures (the paper's, e.g.
``figure:Suslov_Pi_exact``) are built by :meth:`liefi.scenes.Scene.figures`
from these helpers.

=============================  ====================================================
helper                         what it draws
=============================  ====================================================
:func:`generic`                ``|error|`` and drifts vs ``t`` (semilogy): the
                               figure of a scene without a paper figure
:func:`panel_row`              one row of panels over ``t`` (signed values on a
                               linear axis, or ``|values|`` on a log axis)
:func:`logplot`                ``semilogy`` of ``|values|`` with exact zeros masked
:func:`stack`                  several :class:`FigureSpec` stacked into one file
                               (``liefi run --plot``)
=============================  ====================================================

:class:`FigureSpec` is what ``Scene.figures`` returns: a key (the paper's
figure label, or ``"generic"``), a ``draw(fig)`` callable and a size.
:func:`save` writes one figure, :func:`require_matplotlib` raises a clear
error (install ``liefi[plot]``) when matplotlib is missing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

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


@dataclass(frozen=True)
class FigureSpec:
    """One figure of a run: what :meth:`liefi.scenes.Scene.figures` returns.

    ``key`` is the paper's figure label (``"figure:Suslov_Pi_exact"``) or
    ``"generic"``; ``draw(fig)`` draws into a matplotlib figure (or subfigure)
    and returns it; ``width`` and ``height`` (inches) size it alone or stacked.
    """

    key: str
    draw: Callable
    width: float = 11.0
    height: float = 3.5


def require_matplotlib():
    """Import matplotlib (Agg backend) or raise an ``ImportError`` that says how to install it."""
    try:
        import matplotlib
    except ImportError:
        raise ImportError(
            "figures need matplotlib, which is not installed; install it with pip install 'liefi[plot]' "
            "(or pip install matplotlib)"
        ) from None
    matplotlib.use("Agg")
    return matplotlib


_GREEK = {"Pi", "theta", "phi", "psi", "lambda", "mu", "xi", "alpha", "omega", "Omega", "Gamma", "rho"}


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
def new_figure(width, height):
    """A new matplotlib ``Figure`` (constrained layout, 110 dpi), not attached to pyplot."""
    require_matplotlib()
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained", dpi=110)


def check_format(path, name="out"):
    """``path`` if matplotlib writes its suffix's format (``.png``, ``.pdf``, ``.svg`` ...), else a
    ``ValueError`` naming ``name`` and the formats it can write: checked before any work, so a typo in
    the suffix does not cost the run it was to draw."""
    import os

    require_matplotlib()
    from matplotlib.backend_bases import FigureCanvasBase

    formats = FigureCanvasBase.get_supported_filetypes()
    ext = os.path.splitext(path)[1][1:].lower()
    if ext not in formats:
        raise ValueError(f"{name}: cannot write a figure as {path!r}: the format {ext or '(none)'!r} is not one "
                         f"matplotlib writes; choose a suffix among {', '.join(sorted(formats))}")
    return path


def save(fig, path):
    """Write ``fig`` to ``path`` (the format from its suffix, e.g. ``.png``), whole or not at all
    (:func:`liefi._files.replacing`); returns ``path``."""
    require_matplotlib()
    from .._files import replacing

    with replacing(path) as tmp:  # whole or not at all: an interrupt leaves no half figure
        fig.savefig(tmp)
    return path


def panel_grid(n, *, ncols=3, width=4.6, height=3.6, legend_width=2.0):
    """A figure of ``n`` panels in rows of ``ncols`` (each ``width x height`` inches) with
    ``legend_width`` inches on the right for one shared legend; returns ``(fig, axes)``, the
    ``n`` axes in reading order (spare cells are hidden).  Finish it with :func:`finish_panel_grid`."""
    require_matplotlib()
    from matplotlib.figure import Figure

    nc = max(1, min(ncols, n))
    nr = -(-n // nc)
    fig = Figure(figsize=(width * nc + legend_width, height * nr), dpi=110)
    cells = list(fig.subplots(nr, nc, squeeze=False).flat)
    for ax in cells[n:]:
        ax.axis("off")
    fig.liefi_legend_width = legend_width
    return fig, cells[:n]


def finish_panel_grid(fig, axes, title, path, *, legend_fontsize=7, legends=None):
    """One legend for every panel on the right (each label once), the title, a tight layout; saves to ``path``.

    ``legends``: instead, grouped legends in columns (:func:`legend_columns`)."""
    if legends is not None:
        legend_columns(fig, legends, fontsize=legend_fontsize)
    else:
        entries = {}
        for ax in axes:
            for h, lab in zip(*ax.get_legend_handles_labels()):
                entries.setdefault(lab, h)
        fig.legend(list(entries.values()), list(entries), loc="center right", fontsize=legend_fontsize)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0, 1 - fig.liefi_legend_width / fig.get_figwidth(), 0.95))
    return save(fig, path)


def legend_columns(fig, columns, *, fontsize=7):
    """Grouped legends in the right margin of ``fig`` (``fig.liefi_legend_width`` inches, see
    :func:`panel_grid`), side by side: each column a list of one or two blocks
    ``(title, handles, labels)``, the first hung from the top, the second stood on the bottom.

    For many similar series (a work-precision diagram): one block per attribute (colour: the
    method family; marker and line: the scheme; lightness: the gain) instead of one entry per
    series, so the legend stays shorter than the figure."""
    width = fig.liefi_legend_width / fig.get_figwidth()
    x0 = 1 - width
    for i, blocks in enumerate(columns):
        for j, (title, handles, labels) in enumerate(blocks[:2]):
            top = j == 0
            fig.legend(handles, labels, title=title, loc="upper left" if top else "lower left",
                       bbox_to_anchor=(x0 + i * width / len(columns), 0.98 if top else 0.02), fontsize=fontsize,
                       title_fontsize=fontsize + 1, frameon=False, alignment="left")


def figure(fig, width, height):
    """``fig``, or a new figure of the given size when ``fig`` is ``None``."""
    return new_figure(width, height) if fig is None else fig


def drift(name, values):
    """``|I(t) - I(0)|``; constraint momenta and the orthogonality defect target 0."""
    values = np.asarray(values, float)
    if name.startswith("J_") or name == "orthogonality":
        return np.abs(values)
    return np.abs(values - values[0])


def logplot(ax, t, values, *, label=None, **kw):
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
    ax.plot(*thinned(t, shown), label=label, **kw)
    if label is None and log_span(a[1:] if a.size > 1 else a) < 1.0:
        # less than a decade (t = 0 excluded): a linear axis reads better
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
        return
    ax.set_yscale("log")


def run_caption(result, width=None, fontsize=10):
    """Scheme, step, horizon and gains of a run (the caption under a figure title): one line, or
    with ``width`` (inches) the lines of :func:`wrap_caption` that fit it at ``fontsize`` points."""
    scheme = result.scheme
    name = "Euler" if scheme == "euler" else ("first-order DLA" if scheme == "dla" else scheme)
    step = r"$h$" if scheme == "dla" else r"$\Delta t$"
    gains = ""
    if scheme != "dla" and result.gains:
        vals = sorted(set(result.gains.values()))
        gains = f", gains {vals[0]:g}" if len(vals) == 1 else ", gains " + ", ".join(
            f"{label(k)}: {v:g}" for k, v in result.gains.items()
        )
    text = f"{name}, {step} = {result.dt:g}, $0 \\leq t \\leq {result.t_final:g}${gains}"
    return text if width is None else wrap_caption(text, width, fontsize)


def wrap_caption(text, width, fontsize=10):
    """``text`` broken after its commas into lines that fit ``width`` inches at ``fontsize`` points.

    A character is taken as ``0.6 fontsize`` wide and mathtext is counted as written (both
    overestimates), so a line of at most ``width * 72 / (0.6 fontsize)`` characters fits.
    """
    limit = max(20, int(width * 72 / (0.6 * fontsize)))
    lines, line = [], ""
    for piece in text.split(", "):
        if line and len(line) + 2 + len(piece) > limit:
            lines.append(line + ",")
            line = piece
        else:
            line = f"{line}, {piece}" if line else piece
    return "\n".join(lines + [line])


def component(result, name):
    """A saved component of ``result``, or ``None``."""
    if name in result.names:
        return np.asarray(result[name])
    return None


def thinned(t, *series, max_points=50000):
    """``t`` and ``series`` at every k-th point, at most ``max_points`` (and the last point kept).

    For drawing only: a line of 4e5 points on a figure a thousand pixels wide shows
    nothing more than one of 5e4, and costs seconds to lay out and rasterize.
    """
    t = np.asarray(t)
    k = max(1, -(-t.size // max_points))
    if k == 1:
        return (t, *series)
    idx = np.r_[np.arange(0, t.size - 1, k), t.size - 1]
    return (t[idx], *(np.asarray(s)[..., idx] for s in series))


def reference_of(result, name):
    """The reference value ``data - error`` of a compared component, or ``None``."""
    data, err = component(result, name), result.errors.get(name)
    if data is None or err is None:
        return None
    return data - err


def panel_row(fig, result, panels, *, title, width=11.0, height=3.4):
    """One row of panels over ``t`` with a title and the run's caption.

    ``panels`` is a sequence of ``(values, ylabel, scale)``: ``values`` an array over
    ``result.t`` (``None``: "not available", or a string shown in the panel),
    ``scale`` ``"linear"`` (signed values, scientific ticks) or ``"log"``
    (``|values|`` on a log axis, exact zeros masked, see :func:`logplot`).
    """
    fig = figure(fig, width, height)
    axes = np.atleast_1d(fig.subplots(1, len(panels), sharex=True))
    for ax, (values, ylabel, scale) in zip(axes, panels):
        ax.set_xlabel("$t$")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if values is None or isinstance(values, str):
            ax.text(0.5, 0.5, values or "not available", transform=ax.transAxes, ha="center", va="center",
                    color="gray")
            continue
        if scale == "log":
            logplot(ax, result.t, values, lw=0.9, color="C0")
        else:
            ax.plot(*thinned(result.t, values), lw=0.9, color="C0")
            ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
    fig.suptitle(title + "\n" + run_caption(result, fig.bbox.width / fig.dpi), fontsize=10)
    return fig


# --------------------------------------------------------------------------------------
# generic figure
# --------------------------------------------------------------------------------------
def generic(result, fig=None, *, title=None, tag=""):
    """Errors ``|z(t) - z_ref(t)|`` and drifts ``|I(t) - I(0)|`` vs ``t``, both semilogy."""
    fig = figure(fig, 11, 4.0)
    a0, a1 = fig.subplots(1, 2, sharex=True)
    ref = "exact solution" if result.reference == "exact" else "numerical reference (DOP853, tol 1e-12)"
    for i, (k, err) in enumerate(result.errors.items()):
        logplot(a0, result.t, err, lw=0.8, label=label(k), color=f"C{i % 10}", ls="-" if i % 2 == 0 else "--")
    a0.set_title(f"error against the {ref}", fontsize=9)
    a0.set_xlabel("$t$")
    a0.set_ylabel(r"$|z(t) - z_{\rm ref}(t)|$")
    a0.grid(alpha=0.3)
    if result.errors:
        a0.legend(fontsize=8, ncol=2)
    for i, (k, val) in enumerate(result.invariants.items()):
        logplot(a1, result.t, drift(k, val), lw=0.8, label=label(k), color=f"C{i % 10}", ls="-" if i % 2 == 0 else "--")
    a1.set_title(r"drift $|I(t) - I(0)|$ ($|J_i(t)|$ for the constraints)", fontsize=9)
    a1.set_xlabel("$t$")
    a1.set_ylabel(r"$|\Delta I|$")
    a1.grid(alpha=0.3)
    drifts = [drift(k, v) for k, v in result.invariants.items()]
    for ax, series in ((a0, list(result.errors.values())), (a1, drifts)):
        if series and all(np.all(np.abs(np.asarray(v)) <= _TINY) for v in series):
            ax.text(0.5, 0.5, "all identically 0", transform=ax.transAxes, ha="center", va="center", color="gray")
            ax.set_yticks([])
    if result.invariants:
        a1.legend(fontsize=8, ncol=2)
    head = title or f"{result.scene}"
    tag = "" if f"variant {result.variant}" in tag else tag  # the title names the variant once
    caption = run_caption(result, fig.bbox.width / fig.dpi)  # a stacked panel is a SubFigure
    fig.suptitle(f"{head}, variant {result.variant} (no figure in the paper){tag}\n{caption}", fontsize=10)
    return fig


# --------------------------------------------------------------------------------------
# several figures in one file
# --------------------------------------------------------------------------------------
def stack(specs, path):
    """Draw every :class:`FigureSpec` of ``specs``, stacked top to bottom, into one file ``path``."""
    specs = list(specs)
    if not specs:
        raise ValueError("stack: no figure to draw")
    heights = [s.height for s in specs]
    fig = new_figure(max(s.width for s in specs), sum(heights))
    subs = fig.subfigures(len(specs), 1, height_ratios=heights) if len(specs) > 1 else [fig]
    for sub, spec in zip(np.atleast_1d(subs), specs):
        spec.draw(sub)
    save(fig, path)
    return path


def log_span(values):
    """Decades spanned by the nonzero ``|values|`` (helps decide on a log axis)."""
    a = np.abs(np.asarray(values, float))
    a = a[a > 0]
    if a.size == 0:
        return 0.0
    return math.log10(a.max() / a.min())


def plane_path(ax, result, reference_label, title):
    """Draw a run's path ``(r_1, r_2)`` on the plane against its reference's (a rolling body's contact
    point or centre); returns ``(x, y, xe, ye)`` (``None`` where the run or the reference has no path)."""
    x, y = component(result, "r_1"), component(result, "r_2")
    xe, ye = reference_of(result, "r_1"), reference_of(result, "r_2")
    if x is None or y is None:
        ax.text(0.5, 0.5, "run without the configuration: no path", transform=ax.transAxes, ha="center")
    else:
        ax.plot(x, y, lw=0.7, label="feedback integrator")
        if xe is not None:
            ax.plot(xe, ye, lw=0.7, ls="--", label=reference_label)
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=8)
    ax.set_xlabel("$x$")
    ax.set_ylabel("$y$")
    ax.set_title(title, fontsize=10)
    return x, y, xe, ye

