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
"""

from __future__ import annotations

import numpy as np

from . import plotting as _pl

#: configuration coordinates looked for, in order, when the path's axes are not named
PATH_CANDIDATES = (("x", "y"), ("q_1", "q_2"), ("r_1", "r_2"), ("x_1", "x_2"))


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


def _index(sol, name, what):
    names = tuple(sol.names)
    if name not in names:
        raise ValueError(f"{what}: {name!r} is not a component; components are {names}")
    return names.index(name)


def states(sol, names=None, *, ax=None, member=0):
    """Every component (or those in ``names``) against ``t``, on one axis."""
    _pl.require_matplotlib()
    t, Y = _member(sol, member)
    names = tuple(sol.names) if names is None else tuple(names)
    ax = _axes(ax)
    for nm in names:
        ax.plot(*_pl.thinned(t, Y[_index(sol, nm, "names")]), label=_pl.label(nm), lw=1)
    ax.set_xlabel("$t$")
    ax.set_title("states")
    ax.legend(fontsize=7, ncol=max(1, len(names) // 8), loc="best")
    return ax


def drift(sol, *, ax=None, member=0, invariants=None):
    """``|I(t) - I_0|`` of every monitored invariant (or those in ``invariants``), on a log scale."""
    _pl.require_matplotlib()
    from .export import invariant_series, invariant_targets

    series = invariant_series(sol)
    targets = invariant_targets(sol)
    names = [k for k in series if k != "energy"] if invariants is None else list(invariants)
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
    """The configuration path: component ``y`` against component ``x`` (default ``("x", "y")``), equal axes."""
    _pl.require_matplotlib()
    a, b = path_names(sol, x, y)
    t, Y = _member(sol, member)
    ax = _axes(ax, 4.2, 4.2)
    _, xs, ys = _pl.thinned(t, Y[_index(sol, a, "x")], Y[_index(sol, b, "y")])
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
