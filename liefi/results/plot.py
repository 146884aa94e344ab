"""Figures of a user's own run: states, invariant drift, configuration path.

Each function takes a :class:`~liefi.schemes.Solution` (what
:meth:`liefi.FeedbackIntegrator.run` returns), draws into a matplotlib ``Axes``
(a new figure when ``ax`` is not given) and returns the ``Axes``;
:func:`overview` draws the three panels side by side and returns the ``Figure``.
matplotlib is imported only when a figure is drawn (``pip install liefi[plot]``),
with the Agg backend unless another one is already in use in the process::

    import liefi.plot
    sol = fi.run(10.0, dt=1e-3, scheme="rk4")
    fig = liefi.plot.overview(sol)            # states, drift (log scale), the (x, y) path
    fig.savefig("run.png")

The drift of an invariant ``I`` is ``|I(t) - I_0|`` with ``I_0`` its target
(``J_i``: 0, the energy and user invariants: their value at ``y0`` unless the
integrator was given other targets; the embedding penalty ``||R^T R - I||^2/4`` is
shown as is); it needs the integrator, which a solution of
:meth:`~liefi.FeedbackIntegrator.run` carries (``solution.integrator``).
A batch run is drawn for one member (``member=``, the flat index; default 0).

Between the saved states the states and the path are drawn from the run's dense
output (``fi.run(..., dense_output=True)``: ``sol.sol(t)``), so a run of long
steps draws a smooth path, not a polygon; without it they are drawn through the
saved states, with a warning where the path visibly turns between two of them.
A run of more than :data:`MAX_STATES` components (a rolling body has 25) draws
a readable selection by default (:func:`default_states`).  :func:`animate`
writes a GIF of the path being traced (planar bodies with their heading, rolling
bodies with their contact point).
"""

from __future__ import annotations

import pathlib
import re
import warnings

import numpy as np

from . import scene_figures as _pl

#: configuration coordinates looked for, in order, when the path's axes are not named
PATH_CANDIDATES = (("x", "y"), ("q_1", "q_2"), ("r_1", "r_2"), ("x_1", "x_2"))
#: a run of more components than this draws a selection of them by default (:func:`default_states`)
MAX_STATES = 12
#: left out of that selection: a rotation's matrix entries ``R11 ... R33`` and a rolling body's
#: attitude rows ``rho1_*``, ``rho2_*`` (the attitude shows through ``Gamma``, the path through ``r_1, r_2``)
ATTITUDE_ENTRIES = re.compile(r"^(R\d\d|rho\d_\d)$")
#: points drawn per saved interval from the dense output (at most ``_pl.thinned``'s 50000 in all)
POINTS_PER_STEP = 16
#: a path through the saved states alone that turns by more than this (degrees) between two of them warns
MAX_TURN_DEGREES = 10.0
#: heading angles looked for, in order, by :func:`animate` (else the body axis ``(R11, R21)``)
HEADING_CANDIDATES = ("phi", "theta", "psi")


def _axes(ax, width=5.0, height=3.6):
    if ax is not None:
        return ax
    return _pl.new_figure(width, height).add_subplot()


def _member(sol, member):
    """``(t, Y (n, n_t))`` of one member of a (possibly batch) solution."""
    Y = np.asarray(sol.y, dtype=float)
    if Y.ndim == 2:
        return np.asarray(sol.t), Y
    flat = Y.reshape((-1,) + Y.shape[-2:])
    if not 0 <= member < flat.shape[0]:
        raise ValueError(f"member: the batch has {flat.shape[0]} members (flat index), got {member!r}")
    return np.asarray(sol.t), flat[member]


def _dense(sol, t, Y, member):
    """``(t, Y)`` on a fine grid from the dense output ``sol.sol`` (the saved times kept), else as given."""
    dense = getattr(sol, "sol", None)
    if dense is None or t.size < 2:
        return t, Y
    m = min(50000, (t.size - 1) * POINTS_PER_STEP + 1)
    tt = np.union1d(np.linspace(t[0], t[-1], m), t) if m > t.size else t
    Z = np.asarray(dense(tt), dtype=float)
    return tt, (Z if Z.ndim == 2 else Z.reshape((-1,) + Z.shape[-2:])[member])


def _max_turn(xs, ys):
    """The largest visible turn (degrees) of the polyline ``(xs, ys)`` at one of its vertices.

    A turn counts where both segments at the vertex are longer than 1 % of the
    path's extent: a cusp of the motion itself (the knife edge stops and turns
    back) is approached by ever shorter segments and draws no corner.
    """
    d = np.diff(np.stack([np.asarray(xs, float), np.asarray(ys, float)]), axis=1)
    length = np.hypot(*d)
    span = max(float(np.ptp(xs)), float(np.ptp(ys))) if d.shape[1] else 0.0
    if d.shape[1] < 2 or span == 0.0:
        return 0.0
    turn = np.degrees(np.abs(np.diff(np.unwrap(np.arctan2(d[1], d[0])))))
    seen = np.minimum(length[:-1], length[1:]) > 0.01 * span
    return float(np.max(turn[seen], initial=0.0))


def _index(sol, name, what):
    names = tuple(sol.names)
    if name not in names:
        raise ValueError(f"{what}: {name!r} is not a component; components are {names}")
    return names.index(name)


def default_states(sol):
    """The components :func:`states` draws when not told: all, or for a run of more than
    :data:`MAX_STATES` those that are not attitude entries (:data:`ATTITUDE_ENTRIES`), at most
    :data:`MAX_STATES` of them.  A rolling body (25 components) draws ``r_1, r_2, Gamma, Pi, p``."""
    names = tuple(sol.names)
    if len(names) <= MAX_STATES:
        return names
    kept = tuple(n for n in names if not ATTITUDE_ENTRIES.match(n)) or names
    return kept[:MAX_STATES]


def states(sol, names=None, *, ax=None, member=0):
    """The components in ``names`` (default :func:`default_states`) against ``t``, on one axis.

    Between the saved states from the dense output when the run has one (``sol.sol``).
    """
    _pl.require_matplotlib()
    t, Y = _dense(sol, *_member(sol, member), member)
    names = default_states(sol) if names is None else tuple(names)
    ax = _axes(ax)
    for nm in names:
        ax.plot(*_pl.thinned(t, Y[_index(sol, nm, "names")]), label=_pl.label(nm), lw=1)
    ax.set_xlabel("$t$")
    n = len(sol.names)
    ax.set_title("states" if len(names) == n else f"states ({len(names)} of {n}; names= for others)")
    ax.legend(fontsize=7, ncol=1 if len(names) <= 6 else 2 if len(names) <= 12 else 3, loc="best")
    return ax


def drift(sol, *, ax=None, member=0, invariants=None):
    """``|I(t) - I_0|`` of every monitored invariant (or those in ``invariants``), on a log scale."""
    _pl.require_matplotlib()
    from ..schemes.export import energy_name, invariant_series, invariant_targets

    series = invariant_series(sol)  # "energy" is h~ or h: one series per quantity
    targets = invariant_targets(sol)
    names = list(series) if invariants is None else [
        energy_name(sol.integrator) if k == "energy" else k for k in invariants]
    ax = _axes(ax)
    for k in names:
        if k not in series:
            raise ValueError(f"invariants: {k!r} is not monitored; the invariants are {tuple(series)}")
        v = np.asarray(series[k], dtype=float)
        v = v.reshape((-1, v.shape[-1]))[member] if v.ndim > 1 else v
        target = targets[k] if np.ndim(targets[k]) == 0 else np.ravel(targets[k])[member]  # per member
        _pl.logplot(ax, sol.t, v - target, label=_pl.label(k), lw=1)
    ax.set_yscale("log")
    ax.set_xlabel("$t$")
    ax.set_title("invariant drift $|I(t) - I_0|$")
    ax.legend(fontsize=7, loc="best")
    return ax


def path_names(sol, x=None, y=None):
    """The two components of the configuration path: ``(x, y)`` as given, else the first of
    :data:`PATH_CANDIDATES` present, else a ``ValueError`` asking for them."""
    if x is not None or y is not None:
        if x is None or y is None:
            raise ValueError("path: name both components, e.g. path(sol, x='x', y='y')")
        _index(sol, x, "x"), _index(sol, y, "y")
        return x, y
    for a, b in PATH_CANDIDATES:
        if a in sol.names and b in sol.names:
            return a, b
    raise ValueError(f"path: no (x, y) components among {tuple(sol.names)}; name the two components of the "
                     "path, e.g. liefi.plot.path(sol, x='q_1', y='q_2')")


def path(sol, x=None, y=None, *, ax=None, member=0):
    """The configuration path: component ``y`` against component ``x`` (default ``("x", "y")``), equal axes.

    Between the saved states from the dense output (``sol.sol``) when the run has
    one; else through the saved states, with a ``UserWarning`` when the line turns
    by more than :data:`MAX_TURN_DEGREES` at one of them (it would look polygonal).
    """
    _pl.require_matplotlib()
    a, b = path_names(sol, x, y)
    t, Y = _member(sol, member)
    i, j = _index(sol, a, "x"), _index(sol, b, "y")
    if getattr(sol, "sol", None) is None and _max_turn(Y[i], Y[j]) > MAX_TURN_DEGREES:
        warnings.warn(f"path: drawn through the {t.size} saved states only, and it turns by up to "
                      f"{_max_turn(Y[i], Y[j]):.0f} degrees between two of them; run with dense_output=True "
                      "(the path is then drawn between the steps) or save more often", UserWarning, stacklevel=2)
    t, Y = _dense(sol, t, Y, member)
    ax = _axes(ax, 4.2, 4.2)
    _, xs, ys = _pl.thinned(t, Y[i], Y[j])
    ax.plot(xs, ys, lw=1)
    ax.plot(xs[:1], ys[:1], "o", ms=4, label="start")
    ax.plot(xs[-1:], ys[-1:], "s", ms=4, label="end")
    ax.set_xlabel(_pl.label(a))
    ax.set_ylabel(_pl.label(b))
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("configuration path")
    ax.legend(fontsize=7, loc="best")
    return ax


def overview(sol, *, x=None, y=None, member=0, fig=None):
    """States, invariant drift (when the integrator is known) and the path (when it has one), side by side.

    Returns the matplotlib ``Figure`` (``fig.savefig("run.png")``).
    """
    _pl.require_matplotlib()
    panels = ["states"]
    if getattr(sol, "integrator", None) is not None:
        panels.append("drift")
    try:
        path_names(sol, x, y)
        panels.append("path")
    except ValueError:
        if x is not None or y is not None:
            raise
    if fig is None:
        fig = _pl.new_figure(4.6 * len(panels), 3.8)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, p in zip(axes, panels):
        if p == "states":
            states(sol, ax=ax, member=member)
        elif p == "drift":
            drift(sol, ax=ax, member=member)
        else:
            path(sol, x, y, ax=ax, member=member)
    return fig


def _heading(sol, heading):
    """``f(Y) -> (dx, dy)``, the body's heading in the plane, or ``None`` (module constants)."""
    names = tuple(sol.names)
    if heading is False:
        return None
    if heading is not None:
        k = _index(sol, heading, "heading")
        return lambda Y: (np.cos(Y[k]), np.sin(Y[k]))
    for nm in HEADING_CANDIDATES:
        if nm in names:
            k = names.index(nm)
            return lambda Y: (np.cos(Y[k]), np.sin(Y[k]))
    for a, b in (("R11", "R21"), ("rho1_1", "rho2_1")):  # the body axis e_1 seen from above: R e_1
        if a in names and b in names:
            i, j = names.index(a), names.index(b)
            return lambda Y: (Y[i], Y[j])
    return None


def _path_of(sol, x, y, contact):
    """``f(Y) -> (xs, ys)``: the configuration path, or a rolling body's contact point (``contact=``)."""
    if contact is None:
        a, b = path_names(sol, x, y)
        i, j = _index(sol, a, "x"), _index(sol, b, "y")
        return lambda Y: (Y[i], Y[j]), (a, b)
    from ..systems.rolling import ATTITUDE_NAMES, contact_point

    if not callable(contact):
        raise TypeError(f"contact: expected the body's contact function r(Gamma), got {contact!r}")
    need = ("r_1", "r_2") + ATTITUDE_NAMES
    missing = [n for n in need if n not in sol.names]
    if missing:
        raise ValueError(f"contact: the contact point needs the components {missing} of a rolling body run with its "
                         "configuration (liefi.rolling); this run has none of them" if len(missing) == len(need)
                         else f"contact: the contact point needs the components {missing}, missing from this run")
    pos = [sol.names.index(n) for n in need[:2]]
    att = [sol.names.index(n) for n in need[2:]]

    def f(Y):
        P = contact_point(np.moveaxis(Y[pos], 0, -1), np.moveaxis(Y[att], 0, -1), contact)
        return P[..., 0], P[..., 1]

    return f, ("contact point x", "contact point y")


def animate(sol, filename, *, x=None, y=None, contact=None, heading=None, frames=40, fps=10, member=0, dpi=80):
    """Write a GIF of the run's path being traced; returns the file's ``pathlib.Path``.

    Each frame shows the whole path (grey), the part travelled up to its time
    (blue), the body's place and its heading (an arrow), and the time.  The
    frames' times are evenly spread over the run; their states come from the
    dense output (``sol.sol``) when the run has one, else from the saved state
    at or after each time; the path between them as in :func:`path`.

    Parameters
    ----------
    sol : Solution
        A run of :meth:`liefi.FeedbackIntegrator.run` (one member of a batch: ``member=``).
    filename : str or path-like
        The GIF to write (suffix ``.gif``), with matplotlib's ``PillowWriter``.
    x, y : str, optional
        The path's two components (as :func:`path`; default ``x, y`` or ``r_1, r_2`` ...).
    contact : callable, optional
        A rolling body's contact function ``r(Gamma)`` (:func:`liefi.systems.rolling.sphere` ...):
        the path is then the contact point's (:func:`liefi.systems.rolling.contact_point`),
        which needs a run with the configuration.
    heading : str or False, optional
        The heading angle's component (an arrow at angle ``heading``); default the
        first of :data:`HEADING_CANDIDATES` present, else the body axis ``R e_1``
        seen from above (``R11, R21`` or ``rho1_1, rho2_1``); ``False``: no arrow.
    frames : int
        Number of frames (default 40).
    fps : float
        Frames per second (default 10).
    dpi : float
        Resolution (default 80; the figure is 4.2 x 4.2 inches).
    """
    _pl.require_matplotlib()
    from matplotlib.animation import PillowWriter

    from ..schemes.core import positive_int, positive_number

    frames = positive_int(frames, "frames")
    fps = positive_number(fps, "fps")
    dpi = positive_number(dpi, "dpi")
    out = pathlib.Path(filename)
    if out.suffix.lower() != ".gif":
        raise ValueError(f"filename: animate writes a GIF; give a name ending in .gif, got {str(filename)!r}")
    if not out.parent.is_dir():
        raise ValueError(f"filename: the folder {str(out.parent)!r} does not exist")
    where, labels = _path_of(sol, x, y, contact)
    head = _heading(sol, heading)
    t, Y = _member(sol, member)
    tf, Yf = _dense(sol, t, Y, member)
    xs, ys = where(Yf)
    ft = np.linspace(t[0], t[-1], frames)
    if getattr(sol, "sol", None) is not None:
        Z = np.asarray(sol.sol(ft), dtype=float)
        Z = Z if Z.ndim == 2 else Z.reshape((-1,) + Z.shape[-2:])[member]
    else:
        Z = Y[:, np.clip(np.searchsorted(t, ft), 0, t.size - 1)]
    fx, fy = where(Z)
    ends = np.searchsorted(tf, ft, side="right")  # the travelled part of the fine path at each frame
    span = max(float(np.ptp(xs)), float(np.ptp(ys)), 1e-12)
    arrow = 0.1 * span
    fig = _pl.new_figure(4.2, 4.2)
    fig.set_dpi(dpi)
    ax = fig.add_subplot()
    pad = 0.05 * span + (arrow if head is not None else 0.0)
    ax.set_xlim(float(np.min(xs)) - pad, float(np.max(xs)) + pad)
    ax.set_ylim(float(np.min(ys)) - pad, float(np.max(ys)) + pad)
    ax.set_aspect("equal", adjustable="box")
    ax.plot(xs, ys, lw=0.8, color="0.8")
    trail, = ax.plot([], [], lw=1.2, color="tab:blue")
    dot, = ax.plot([], [], "o", ms=5, color="tab:blue")
    pointer, = ax.plot([], [], lw=2, color="tab:orange")
    ax.set_xlabel(labels[0] if contact is not None else _pl.label(labels[0]))
    ax.set_ylabel(labels[1] if contact is not None else _pl.label(labels[1]))
    title = ax.set_title(("contact path" if contact is not None else "path") + f", t = {ft[-1]:.3g}")
    fig.draw_without_rendering()  # lay the figure out once: the frames only move lines
    fig.set_layout_engine("none")
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, str(out), dpi):
        for k in range(frames):
            trail.set_data(xs[: ends[k]], ys[: ends[k]])
            dot.set_data([fx[k]], [fy[k]])
            if head is not None:
                dx, dy = head(Z[:, k : k + 1])
                norm = float(np.hypot(dx[0], dy[0])) or 1.0
                pointer.set_data([fx[k], fx[k] + arrow * dx[0] / norm], [fy[k], fy[k] + arrow * dy[0] / norm])
            title.set_text(("contact path" if contact is not None else "path") + f", t = {ft[k]:.3g}")
            writer.grab_frame()
    return out
