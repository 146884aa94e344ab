"""Long horizons: drift against time at matched cost, and the crossover horizon of the feedback integrator."""

from __future__ import annotations

import math
import os

import numpy as np

from .. import scenes as _scenes
from .._files import replacing
from ..results.sweep import TaskError, run_sweep
from .core import FI_GAINS, _integrator, error_row, invariant_drifts, measure, run_task, write_csv
from .verdict import label as _label
from .plots import _series, plot_long_horizon, save_curves

# ======================================================================================
# long horizon
# ======================================================================================


def matched_tasks(rows, *, reference_method="FI", reference_scheme=None, t_final=1e4, n_save=2000, usable=1e-2):
    """For each (method, scheme) the run whose CPU time per unit time is closest to the feedback
    integrator's at the scene's own settings; returned as tasks with horizon ``t_final``.

    Candidates are the finished runs with finite drifts; a feedback-integrator run
    whose drift exceeds ``usable`` is left out: the feedback keeps the drift small
    by construction, so such a run is past its stability limit (it can end
    without overflowing and still be garbage).  The peers' runs are all kept:
    their drift is what they are compared on."""
    ok = [r for r in rows if r["status"] == "ok" and r.get("max_drift") is not None
          and np.isfinite(r["max_drift"])
          and (not r["method"].startswith("FI") or r["max_drift"] < usable)]
    if not ok:
        return []
    sc = _scenes.get(ok[0]["scene"])
    scheme = sc.scheme if reference_scheme is None else reference_scheme
    ref = [r for r in ok if r["method"] == reference_method and r["scheme"] == scheme and r.get("gain") is None]
    if not ref:
        return []
    target = min(ref, key=lambda r: abs(math.log(r["dt"] / sc.dt)))
    cost = target["cpu_seconds"] / target["t_final"]
    tasks = []
    for (m, s, k), rs in _series(ok).items():
        if (m, s, k) == (reference_method, scheme, None):
            pick = target
        else:
            pick = min(rs, key=lambda r: abs(math.log(max(r["cpu_seconds"], 1e-9) / r["t_final"] / max(cost, 1e-12))))
        t = {key: pick.get(key) for key in ("scene", "variant", "method", "scheme", "dt", "rtol", "gain")}
        t.update(t_final=float(t_final), configuration=bool(pick.get("configuration", True)), n_save=int(n_save))
        if t["dt"] is not None and abs(round(t_final / t["dt"]) * t["dt"] - t_final) > 1e-9 * t_final:
            continue
        tasks.append(t)
    return tasks


def long_horizon(rows, out_dir=None, executor=None, *, t_final=1e4, n_save=2000, curves_dir=None, log=None):
    """Drift of every invariant against time up to ``t_final`` for the feedback integrator (the
    scene's scheme and step) and each peer at matched cost (:func:`matched_tasks`).

    Returns ``(rows, curves)``: summary rows (as :func:`measure`, no error) and
    ``{label: (t, {invariant: drift(t)}, cpu_seconds)}``; writes
    ``<scene>-long-horizon.csv`` and ``<scene>-long-horizon.png`` into ``out_dir``
    and the curves (:func:`save_curves`, to redraw the figure) into ``curves_dir``
    (default ``out_dir``).
    """
    tasks = matched_tasks(rows, t_final=t_final, n_save=n_save)
    if not tasks:
        return [], {}
    if log:
        log(f"{tasks[0]['scene']}: long horizon, {len(tasks)} runs to t = {t_final:g}")
    results = run_sweep(run_task, tasks, executor, label=f"{tasks[0]['scene']} long horizon")
    _, _, fi = _integrator(tasks[0])
    sc = _scenes.get(tasks[0]["scene"])
    out_rows, curves = [], {}
    for task, r in zip(tasks, results):
        if isinstance(r, TaskError):
            out_rows.append(error_row(task, r))
            continue
        row = measure(sc, fi, r, None)
        out_rows.append(row)
        if r["y"] is not None:
            curves[_label(row)] = (r["t"], invariant_drifts(fi, r["y"]), row["cpu_seconds"], row["method"], row["scheme"])
    if out_dir:
        os.makedirs(out_dir, exist_ok=True)
        write_csv(out_rows, os.path.join(out_dir, f"{sc.name}-long-horizon.csv"))
        cdir = out_dir if curves_dir is None else curves_dir
        os.makedirs(cdir, exist_ok=True)
        save_curves(curves, os.path.join(cdir, f"{sc.name}-long-horizon.npz"))
        plot_long_horizon(curves, os.path.join(out_dir, f"{sc.name}-long-horizon.png"), sc.name, t_final)
    return out_rows, curves




# ======================================================================================
# crossover: from which horizon on is the feedback integrator the cheapest way to keep the invariants?
# ======================================================================================

#: the horizons at which :func:`horizon_row` reads a long run (each a prefix ``[0, H]`` of it)
HORIZONS = (1e2, 2e2, 5e2, 1e3, 2e3, 5e3, 1e4, 2e4, 5e4, 1e5, 2e5, 5e5, 1e6)


def horizon_tasks(scene, t_final=1e5, *, dts=None, schemes=("rk4", "imex-rk4"), gains=FI_GAINS, n_save=10000,
                  configuration=True):
    """The long runs of :func:`crossover`: every compiled fixed-step family (``FI`` with each gain,
    ``FI-accurate`` with the gains for this horizon, ``no-feedback``, ``projection``) with ``schemes`` at steps ``dts`` (default ``scene.dt * (8, 4, 2, 1)``),
    from the scene's start to ``t_final``."""
    from .core import build_tasks

    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    dts = [sc.dt * f for f in (8.0, 4.0, 2.0, 1.0)] if dts is None else list(dts)
    return build_tasks(sc, t_final, dts=dts, rtols=[1e-6],
                       methods=("FI", "FI-accurate", "no-feedback", "projection", "projection-1"),
                       schemes=tuple(schemes), gains=gains, n_save=n_save, configuration=configuration)


def horizon_row(task, result, horizons=HORIZONS):
    """Reduce one long run to prefix maxima: for each horizon ``H <= t_final``, the max drift of every
    invariant over ``[0, H]`` (``drift_at``) and, where the scene has an exact solution, the max
    relative state error over ``[0, H]`` (``error_at``: ``max_t |x - x_ref| / max_t |x_ref|``, largest
    over the scene's compared variables; ``None`` without an exact solution, where a reference to
    ``t = 1e5`` would itself need the accuracy being measured).  The cost of the prefix is
    ``cpu_seconds * H / t_final`` (a fixed-step run costs the same per step all along)."""
    sc = _scenes.get(task["scene"])
    _, v, fi = _integrator(task)
    row = measure(sc, fi, result, None)
    row["horizons"] = [h for h in horizons if h <= task["t_final"] * (1 + 1e-12)]
    row["drift_at"], row["error_at"] = [], []
    row["error_measured"] = sc.reference == "exact"
    if result.get("y") is None:
        return row
    t, Y = np.asarray(result["t"]), np.asarray(result["y"])
    with np.errstate(all="ignore"):
        d = invariant_drifts(fi, Y)
        dmax = np.max(np.vstack(list(d.values())), axis=0) if d else np.zeros_like(t)
        dmax = np.where(np.isfinite(dmax), dmax, np.inf)
        emax = None
        if sc.reference == "exact":
            data = {n: Y[i] for i, n in enumerate(fi.names)}
            data.update(sc.observables(Y, fi.names))
            ref = sc.exact(t, v)
            rel = [np.abs(data[k] - ref[k]) / max(float(np.max(np.abs(ref[k]))), 1e-300)
                   for k in sc.error_variables if k in data and k in ref]
            if rel:
                emax = np.max(np.vstack(rel), axis=0)
                emax = np.where(np.isfinite(emax), emax, np.inf)
    for h in row["horizons"]:
        m = t <= h * (1 + 1e-12)
        row["drift_at"].append(float(np.max(dmax[m])))
        row["error_at"].append(None if emax is None else float(np.max(emax[m])))
    return row


def cost_curves(rows, *, drift=1e-10, error=1e-6):
    """``{label: {H: cpu}}``: per (method, scheme, gain), the least cost to keep every invariant within
    ``drift`` over ``[0, H]`` (and the relative error within ``error`` where measured), over the steps."""
    out = {}
    for r in rows:
        if r.get("status") != "ok" or not r.get("horizons"):
            continue
        lab = f"{r['method']} {r['scheme']}" + ("" if r.get("gain") is None else f" k={r['gain']:g}")
        curve = out.setdefault(lab, {})
        T = r["t_final"]
        measured = r.get("error_measured", False)
        for h, d, e in zip(r["horizons"], r["drift_at"], r["error_at"]):
            if d is not None and d <= drift and (not measured or (e is not None and e <= error)):
                c = r["cpu_seconds"] * h / T
                curve[h] = min(curve.get(h, math.inf), c)
    return out


def crossover(rows, *, drift=1e-10, error=1e-6):
    """The crossover horizon of one scene from :func:`horizon_row` rows.

    Returns a dict: ``fi_best`` and ``other_best`` (``{H: (label, cpu)}``, the
    cheapest FI / non-FI way to keep every invariant within ``drift`` -- and the
    relative state error within ``error`` where measured -- over ``[0, H]``), and
    ``crossover``: the least horizon ``H`` of the grid from which on the FI is
    cheapest at every longer horizon measured: there it keeps the invariants
    and no other method does so for less (``None``: not at the longest horizon
    -- including when no method of the grid meets the criterion there).
    """
    curves = cost_curves(rows, drift=drift, error=error)
    hs = sorted({h for r in rows if r.get("status") == "ok" for h in (r.get("horizons") or [])})
    fi_best, other_best = {}, {}
    for h in hs:
        for lab, c in curves.items():
            if h not in c:
                continue
            best = fi_best if lab.startswith("FI") else other_best
            if h not in best or c[h] < best[h][1]:
                best[h] = (lab, c[h])
    wins = [h for h in hs if h in fi_best and (h not in other_best or fi_best[h][1] < other_best[h][1])]
    cross = None
    for h in reversed(hs):
        if h in wins:
            cross = h
        else:
            break
    return {"fi_best": fi_best, "other_best": other_best, "crossover": cross, "horizons": hs, "curves": curves}


def plot_cost_vs_horizon(curves, path, name, drift=1e-10):
    """Cost (CPU s) to keep every invariant within ``drift`` over ``[0, H]`` against ``H``, one line per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .plots import _COLORS

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for i, (lab, c) in enumerate(sorted(curves.items())):
        if not c:
            continue
        h = sorted(c)
        m = lab.split()[0]
        ax.loglog(h, [c[x] for x in h], marker="o^sDvx"[i % 6], ms=3.5, lw=1, color=_COLORS.get(m, "k"),
                  ls="-" if m.startswith("FI") else "--", label=lab)
    ax.set_xlabel("horizon H")
    ax.set_ylabel("CPU s to keep every invariant within %g over [0, H]" % drift, fontsize=8)
    ax.set_title(f"{name}: cost against horizon (missing: no step of the grid keeps the drift)", fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    with replacing(path) as tmp:  # whole or not at all
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path
