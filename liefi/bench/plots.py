"""Work-precision diagrams and long-horizon figures (matplotlib imported by each function)."""

from __future__ import annotations

import os

import numpy as np

from .._files import replacing
from ..results.scene_figures import finish_panel_grid, legend_columns, panel_grid

# ======================================================================================
# plots
# ======================================================================================

_COLORS = {"FI": "C3", "FI-tuned": "C6", "FI-accurate": "C5", "FI/solve_ivp": "C1", "FI-rtol": "k", "no-feedback": "C7", "constrained": "C0", "projection": "C2", "projection-1": "C8", "DLA": "C4"}
#: scheme -> (marker, line): the marker by the order's base scheme, the line by the kind
#: (explicit solid, split ``imex-*`` dash-dot, adaptive solve_ivp dashed, implicit dotted)
_STYLES = {"euler": ("o", "-"), "heun": ("s", "-"), "midpoint": ("P", "-"), "rk3": ("h", "-"), "rk4": ("^", "-"),
           "imex-euler": ("o", "-."), "imex-heun": ("s", "-."), "imex-rk4": ("^", "-."),
           "RK23": ("<", "--"), "RK45": ("v", "--"), "DOP853": ("D", "--"), "LSODA": ("X", ":"), "Radau": ("*", ":"),
           "BDF": ("p", ":"), "dla": ("x", "-")}
#: inches on the right of a work-precision figure for its grouped legends
_LEGEND_WIDTH = 3.0


def _alpha(gain):
    """FI rows with a fixed gain k are drawn lighter the smaller k (the scene's gains: opaque)."""
    return 1.0 if gain is None else float(np.clip(0.45 + 0.15 * np.log10(gain) + 0.15, 0.3, 0.9))


def _series(rows):
    groups = {}
    for r in rows:
        if r["status"] != "ok":
            continue
        groups.setdefault((r["method"], r["scheme"], r.get("gain")), []).append(r)
    return groups


def _legends(rows):
    """The grouped legends of a work-precision figure (:func:`liefi.results.scene_figures.legend_columns`): the
    method families by colour with the FI gains by lightness below them, the schemes by marker
    and line -- one entry per family, scheme and gain, not one per series."""
    from matplotlib.lines import Line2D

    ok = [r for r in rows if r["status"] == "ok"]
    fams = [m for m in dict.fromkeys([*_COLORS, *(r["method"] for r in ok)]) if any(r["method"] == m for r in ok)]
    schemes = list(dict.fromkeys(r["scheme"] for r in ok))
    gains = list(dict.fromkeys(r.get("gain") for r in ok if str(r["method"]).startswith("FI")))
    gains.sort(key=lambda k: -1.0 if k is None else k)
    fam = ("method", [Line2D([], [], color=_COLORS.get(m, "k"), lw=2.5) for m in fams], fams)
    sch = ("scheme", [Line2D([], [], color="k", marker=_STYLES.get(s, ("o", "-"))[0], ls=_STYLES.get(s, ("o", "-"))[1],
                             ms=4, lw=1) for s in schemes], schemes)
    blocks = [[fam], [sch]]
    if len(gains) > 1:
        blocks[0].append(("FI gain k", [Line2D([], [], color=_COLORS["FI"], lw=2.5, alpha=_alpha(k)) for k in gains],
                          ["the scene's" if k is None else f"{k:g}" for k in gains]))
    return blocks


def _draw(ax, rows, xkey, ykey):
    for (m, s, k), rs in _series(rows).items():
        pts = [(r[xkey], r[ykey]) for r in rs if r.get(ykey) is not None and np.isfinite(r[ykey]) and r[xkey]]
        if not pts:
            continue
        pts.sort()
        x, y = np.array(pts).T
        y = np.maximum(y, 1e-17)
        mk, ls = _STYLES.get(s, ("o", "-"))
        ax.loglog(x, y, marker=mk, ls=ls, color=_COLORS.get(m, "k"), ms=4, lw=1, alpha=_alpha(k),
                  label=f"{m} {s}" + ("" if k is None else f" k={k:g}"))
    ax.grid(True, which="major", alpha=0.3)


def plot(rows, out_dir, name):
    """Write ``<name>-error.png`` (error vs CPU time and vs RHS evaluations) and
    ``<name>-drift.png`` (each invariant's drift vs CPU time); log-log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    T = rows[0]["t_final"] if rows else float("nan")
    paths = []
    fig, axes = plt.subplots(1, 2, figsize=(12 + _LEGEND_WIDTH, 4.8))
    _draw(axes[0], rows, "cpu_seconds", "max_error")
    axes[0].set_xlabel("CPU time [s]")
    axes[0].set_ylabel("max error vs reference")
    _draw(axes[1], rows, "rhs_evaluations", "max_error")
    axes[1].set_xlabel("right-hand-side evaluations")
    axes[0].set_title(f"{name}: error vs CPU time, t in [0, {T:g}]")
    axes[1].set_title("error vs work (engine independent)")
    fig.liefi_legend_width = _LEGEND_WIDTH
    legend_columns(fig, _legends(rows))
    fig.tight_layout(rect=(0, 0, 1 - _LEGEND_WIDTH / fig.get_figwidth(), 1))
    p = os.path.join(out_dir, f"{name}-error.png")
    with replacing(p) as tmp:  # whole or not at all
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    paths.append(p)

    drifts = sorted({k for r in rows for k in r if k.startswith("drift_")})
    if all(not r.get("drift_orthogonality") for r in rows):  # no embedded rotation (older CSVs have zeros)
        drifts = [k for k in drifts if k != "drift_orthogonality"]
    if drifts:
        fig, axes = panel_grid(len(drifts), legend_width=_LEGEND_WIDTH)
        for ax, k in zip(axes, drifts):
            _draw(ax, rows, "cpu_seconds", k)
            ax.axhline(1e-8, color="k", lw=0.6, ls=":")
            ax.set_title(f"max |{k[6:]} drift|", fontsize=9)
            ax.set_xlabel("CPU time [s]", fontsize=8)
        p = finish_panel_grid(fig, axes, f"{name}: max drift of each invariant over t in [0, {T:g}] vs CPU time "
                              "(dotted: 1e-8; exact zeros drawn at 1e-17)", os.path.join(out_dir, f"{name}-drift.png"),
                              legends=_legends(rows))
        paths.append(p)
    return paths



def save_curves(curves, path):
    """Store the curves of :func:`long_horizon` (``np.savez_compressed``); see :func:`load_curves`."""
    arrays, meta = {}, []
    for i, (label, (t, d, cpu, m, s)) in enumerate(curves.items()):
        arrays[f"t{i}"] = np.asarray(t, np.float32)
        for k, v in d.items():
            arrays[f"d{i}:{k}"] = np.asarray(v, np.float32)
        meta.append([label, float(cpu), m, s, list(d)])
    import json

    path = path if str(path).endswith(".npz") else f"{path}.npz"  # numpy's own rule, for the final name
    with replacing(path) as tmp:  # whole or not at all: load_curves never reads half a file
        np.savez_compressed(tmp, meta=json.dumps(meta), **arrays)
    return path


def load_curves(path):
    """The curves saved by :func:`save_curves`."""
    import json

    with np.load(path) as z:
        meta = json.loads(str(z["meta"]))
        return {label: (z[f"t{i}"], {k: z[f"d{i}:{k}"] for k in keys}, cpu, m, s)
                for i, (label, cpu, m, s, keys) in enumerate(meta)}


def plot_long_horizon(curves, path, name, t_final):
    """Each invariant's drift against time (log-log), one panel per invariant."""
    invs = sorted({k for _, d, *_ in curves.values() for k in d})
    if not invs:
        return None
    fig, axes = panel_grid(len(invs), legend_width=2.6)
    for ax, k in zip(axes, invs):
        for label, (t, d, cpu, m, s) in curves.items():
            if k not in d:
                continue
            mk, ls = _STYLES.get(s, ("o", "-"))
            ax.loglog(t[1:], np.maximum(d[k][1:], 1e-17), ls=ls, color=_COLORS.get(m, "k"), lw=0.6,
                      marker=mk, ms=3.5, markevery=0.12, label=f"{label}, {cpu:.2g} s", rasterized=True)
        ax.set_title(f"|{k}(t) - {k}(0)|" if not k.startswith("J_") and k != "orthogonality" else f"|{k}(t)|",
                     fontsize=9)
        ax.set_xlabel("t", fontsize=8)
        ax.grid(True, alpha=0.3)
    return finish_panel_grid(fig, axes, f"{name}: drift vs time to t = {t_final:g}, each method at the cost closest "
                             "to the FI's (CPU s in the legend; exact zeros drawn at 1e-17)", path, legend_fontsize=6)


