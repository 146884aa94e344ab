"""Work-precision: the feedback integrator against every method a user could pick, in one run.

:func:`work_precision` runs, on one scene, over a grid of steps ``dt`` or
tolerances ``rtol`` (each run from the scene's start to ``t_final``):

==================  =======================================================================
``FI``              the feedback integrator (``X - grad V``, the scene's gains) with
                    liefi's fixed-step schemes ``euler``, ``heun``, ``rk4``
``FI-tuned``        the feedback integrator with fixed gains matched to ``dt`` and the scheme
                    (:func:`liefi.stability.auto_gains`: ``dt lambda_max(Hess V)`` at the
                    scheme's optimal rate along a pilot run), same schemes
``FI/solve_ivp``    the same field with ``solve_ivp`` ``RK45``, ``DOP853``, ``LSODA``
``no-feedback``     the extended field ``X`` alone (gains zero) with ``euler``, ``heun``, ``rk4``
``constrained``     the original constrained equations (multipliers
                    ``lambda = C^{-1}{h, J}``, :func:`~liefi.reduction.full_vector_field`
                    with ``kind="constrained"``) with ``solve_ivp`` ``RK45``, ``DOP853``,
                    ``LSODA``: what a user of sympy.mechanics / PyDy does
``projection``      the constrained equations with ``euler``, ``heun``, ``rk4``, each step
                    followed by a Newton projection onto the invariant set (see below):
                    what DifferentialEquations.jl's ``ManifoldProjection`` does
``DLA``             the discrete Lagrange--d'Alembert scheme of :mod:`liefi.dla`, where it
                    applies (systems on ``T*R^n`` with a constant metric)
==================  =======================================================================

and returns one row per run: method, scheme, ``dt`` or ``rtol``, CPU seconds,
right-hand-side evaluations, the max error against the scene's exact (or
reference) solution, and the max drift of every invariant (the constraint
momenta ``J_i``, ``h``, ``h~``, the scene's other invariants and
``orthogonality = ||R^T R - I||``).  :func:`write_csv` and :func:`plot` write
the CSV and the log-log diagrams; :func:`long_horizon` follows the drift of
each invariant against time up to ``t = 1e4`` for the feedback integrator and
each peer at matched cost.

How the runs are made comparable
--------------------------------
* Every field is the same generated, compiled code (:mod:`liefi.compiled`):
  fixed-step schemes, the projection and the DLA scheme run entirely compiled; ``solve_ivp``
  calls the compiled right-hand side from its Python loop, which is what a
  scipy user with generated code (PyDy's Cython output) gets.  Compilation and
  warm-up are excluded from ``cpu_seconds`` and reported as ``compile_seconds``
  (for ``FI-tuned`` it includes the pilot run that chooses the gains).
  Because the fixed-step loops avoid Python's per-step overhead, part of a
  fixed-step method's advantage is the engine, not the method:
  ``rhs_evaluations`` is the engine-independent measure of work, and
  :func:`plot` draws error against it too.
* ``cpu_seconds`` is process CPU time (robust to other load on the machine).
* The state is the scene's full state ``(g, z)`` (configuration integrated, so
  that ``R^T R = I`` is an invariant to keep) unless ``configuration=False``.
* The projection is the Euclidean orthogonal projection onto
  ``{r(y) = 0}``, ``r`` = (upper triangle of ``R^T R - I`` for every orthogonal
  block, ``J_i``, ``h - h0``, each user invariant minus its target), by Newton's
  method along ``G(y)^T`` (``G = dr/dy``), up to 3 iterations per step, stopping
  at ``max |r| <= 1e-14``: the same fixed point as ManifoldProjection.  Its
  residual/Jacobian evaluations are counted in ``projection_evaluations``.
* Drifts are measured at the saved points (``n_save`` per run, uniform in time).

Tasks are plain dicts run by :func:`run_task` through :func:`liefi.sweep.run_sweep`,
so any executor (processes, a Dask cluster) can run the grid.  matplotlib is
imported by the plotting functions only.
"""

from __future__ import annotations

import csv
import math
import os
import time

import numpy as np

from . import compiled as _compiled
from . import scenes as _scenes
from .sweep import run_sweep

__all__ = [
    "FIXED_SCHEMES",
    "IVP_METHODS",
    "default_grid",
    "build_tasks",
    "run_task",
    "work_precision",
    "measure",
    "write_csv",
    "read_csv",
    "plot",
    "cheapest",
    "long_horizon",
    "plot_long_horizon",
    "save_curves",
    "load_curves",
    "add_arguments",
    "run_from_args",
    "main",
]

FIXED_SCHEMES = ("euler", "heun", "rk4")
IVP_METHODS = ("RK45", "DOP853", "LSODA")
METHODS = ("FI", "FI-tuned", "FI/solve_ivp", "no-feedback", "constrained", "projection", "DLA")


# ======================================================================================
# tasks
# ======================================================================================


def default_grid(scene, t_final, quick=False):
    """``(dts, rtols)``: steps ``scene.dt * 2^k`` and tolerances ``1e-3 ... 1e-11``."""
    if quick:
        return [scene.dt * f for f in (4.0, 1.0, 0.25)], [1e-4, 1e-8]
    return [scene.dt * f for f in (8.0, 4.0, 2.0, 1.0, 0.5, 0.25, 0.125, 0.0625)], [1e-3, 1e-5, 1e-7, 1e-9, 1e-11]


def applicable_methods(scene):
    """The method families that apply to ``scene`` (DLA only on ``T*R^n`` with a constant metric)."""
    out = list(METHODS)
    if not _compiled.dla_applies(scene.system):
        out.remove("DLA")
    return out


def build_tasks(scene, t_final, *, variant=None, dts=None, rtols=None, methods=None, configuration=True,
                n_save=1000, quick=False, schemes=FIXED_SCHEMES, ivp_methods=IVP_METHODS):
    """The list of task dicts of a work-precision sweep (see :func:`run_task`).

    ``schemes`` (liefi's fixed-step schemes) and ``ivp_methods`` (``solve_ivp``'s)
    restrict the grid; the defaults are :data:`FIXED_SCHEMES` and :data:`IVP_METHODS`.
    """
    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    v = sc.variant(variant).name
    g_dts, g_rtols = default_grid(sc, t_final, quick)
    dts = g_dts if dts is None else list(dts)
    rtols = g_rtols if rtols is None else list(rtols)
    methods = applicable_methods(sc) if methods is None else list(methods)
    common = {"scene": sc.name, "variant": v, "t_final": float(t_final), "configuration": bool(configuration),
              "n_save": int(n_save)}
    tasks = []
    for m in methods:
        if m in ("FI", "FI-tuned", "no-feedback", "projection"):
            tasks += [dict(common, method=m, scheme=s, dt=float(dt), rtol=None) for s in schemes for dt in dts]
        elif m in ("FI/solve_ivp", "constrained"):
            tasks += [dict(common, method=m, scheme=s, dt=None, rtol=float(r)) for s in ivp_methods for r in rtols]
        elif m == "DLA":
            tasks += [dict(common, method=m, scheme="dla", dt=float(dt), rtol=None) for dt in dts]
        else:
            raise ValueError(f"methods: unknown method {m!r}; choose from {METHODS}")
    return tasks


def _integrator(task):
    sc = _scenes.get(task["scene"])
    v = sc.variant(task["variant"])
    cfg = task["configuration"] and sc.system.space.group.config_dim > 0
    return sc, v, sc.integrator(v, configuration=cfg)


def _steps(t_final, dt, n_save):
    n = int(round(t_final / dt))
    if abs(n * dt - t_final) > 1e-9 * t_final:
        raise ValueError(f"t_final: {t_final} is not a whole number of steps dt={dt}")
    return n, max(1, n // n_save)


def run_task(task):
    """Run one method of a sweep; returns ``{t, y, cpu_seconds, rhs_evaluations, ...}`` or a failure.

    ``task``: ``scene``, ``variant``, ``method`` (one of :data:`METHODS`),
    ``scheme``, ``dt`` or ``rtol``, ``t_final``, ``configuration``, ``n_save``.
    ``y`` is ``(N, n_t)`` in the feedback integrator's state layout.  Never
    raises for a run that fails (diverges, solver gives up): ``status`` says so.
    """
    from scipy.integrate import solve_ivp

    from .schemes import IntegrationError

    out = dict(task)
    out.update(status="ok", message="", cpu_seconds=math.nan, compile_seconds=0.0, rhs_evaluations=0,
               projection_evaluations=0, steps=0, t=None, y=None)
    try:
        sc, v, fi = _integrator(task)
        method, scheme, T = task["method"], task["scheme"], task["t_final"]
        w = time.perf_counter()
        if method in ("FI", "FI-tuned", "no-feedback", "projection"):
            n, se = _steps(T, task["dt"], task["n_save"])
            if method == "projection":
                cf = _compiled.compile_constrained(fi, projection=True)
                p, proj = np.zeros(0), _compiled.projection_targets(fi)
            elif method == "FI-tuned":
                from .stability import auto_gains

                fi = fi.with_gains(auto_gains(fi, task["dt"], scheme, y=fi.y0, t_final=T))
                out["message"] = "gains " + ", ".join(f"{k}={v:.3g}" for k, v in fi.gains.items())
                cf = _compiled.compile_feedback(fi)
                p, proj = _compiled.parameters(fi), None
            else:
                cf = _compiled.compile_feedback(fi, feedback=method == "FI")
                p, proj = _compiled.parameters(fi), None
            cf.warmup(scheme, project=proj is not None)
            out["compile_seconds"] = time.perf_counter() - w
            sol = cf.run(fi.y0, p, task["dt"], n, scheme, save_every=se, names=fi.names, project=proj)
            out.update(t=sol.t, y=sol.y, cpu_seconds=sol.cpu_seconds, rhs_evaluations=sol.rhs_evaluations, steps=n,
                       projection_evaluations=getattr(sol, "projection_evaluations", 0))
        elif method in ("FI/solve_ivp", "constrained"):
            if method == "FI/solve_ivp":
                cf = _compiled.compile_feedback(fi)
                fun = cf.fun(_compiled.parameters(fi))
            else:
                cf = _compiled.compile_constrained(fi)
                fun = cf.fun(np.zeros(0))
            out["compile_seconds"] = time.perf_counter() - w
            t_eval = np.linspace(0.0, T, task["n_save"] + 1)
            rtol = task["rtol"]
            c0 = time.process_time()
            with np.errstate(all="ignore"):
                sol = solve_ivp(fun, (0.0, T), fi.y0, method=scheme, t_eval=t_eval, rtol=rtol, atol=1e-2 * rtol)
            cpu = time.process_time() - c0
            out.update(cpu_seconds=cpu, rhs_evaluations=int(sol.nfev), steps=None)
            if not sol.success:
                out.update(status="failed", message=f"solve_ivp({scheme}): {sol.message}")
            elif not np.all(np.isfinite(sol.y)):
                out.update(status="diverged", message=f"solve_ivp({scheme}) returned non-finite values")
            else:
                out.update(t=sol.t, y=sol.y)
        elif method == "DLA":
            from .dla import DLAIntegrator

            sys_ = sc.system
            n, se = _steps(T, task["dt"], task["n_save"])
            cd = _compiled.compile_dla(sys_)
            M = sys_.metric.value
            dla = DLAIntegrator(
                M, None if sys_.potential.constant else sys_.potential.fun,
                (lambda q: np.asarray(sys_.constraints(q)) @ M) if sys_.K else None,
            )
            k = sys_.space.n
            q0, p0 = fi.y0[:k], fi.y0[k:]
            q0, q1 = dla.initial_pair(q0, p0, task["dt"])
            cd.run(q0, q1, task["dt"], 2)  # compile
            out["compile_seconds"] = time.perf_counter() - w
            t, q, mom, cpu, updates = cd.run(q0, q1, task["dt"], n, save_every=se)
            out.update(t=t, y=np.concatenate([q, mom], 0), cpu_seconds=cpu, rhs_evaluations=updates, steps=n)
        else:
            raise ValueError(f"method: unknown {method!r}")
    except (IntegrationError, FloatingPointError) as exc:
        out.update(status="diverged", message=" ".join(str(exc).split())[:300])
    except _compiled.NotCompilable as exc:
        out.update(status="not-applicable", message=str(exc)[:300])
    except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        out.update(status="failed", message=f"{type(exc).__name__}: " + " ".join(str(exc).split())[:300])
    return out


# ======================================================================================
# measuring
# ======================================================================================


def reference(scene, variant, fi, t_final):
    """A callable ``t -> {name: values}``: the scene's exact solution, or a DOP853 reference.

    The numerical reference integrates the constrained field (compiled) from the
    scene's start with ``rtol = atol = 1e-12`` (the scene's own reference
    settings) and evaluates its dense output.
    """
    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    v = sc.variant(variant) if not hasattr(variant, "name") else variant
    if sc.reference == "exact":
        return lambda t: sc.exact(np.asarray(t, float), v)
    from scipy.integrate import solve_ivp

    cf = _compiled.compile_constrained(fi)
    sol = solve_ivp(cf.fun(np.zeros(0)), (0.0, float(t_final)), fi.y0, method="DOP853", rtol=1e-12, atol=1e-12,
                    dense_output=True)
    if not sol.success:
        raise RuntimeError(f"reference solution of {sc.name!r} failed: {sol.message}")
    names = fi.names

    def ref(t):
        Y = sol.sol(np.asarray(t, float))
        return {n: Y[i] for i, n in enumerate(names)}

    return ref


def measure(scene, fi, result, ref=None):
    """Errors and drifts of one run (a :func:`run_task` result) -> a CSV row (dict).

    ``max_error`` is the max over the saved points and over the scene's compared
    variables of ``|x - x_ref|``; ``drift_<I>`` is ``max |I(t) - I(0)|`` (``J_i``
    and ``orthogonality`` against 0), as :class:`~liefi.scenes.Scene` reports it.
    """
    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    row = {k: result[k] for k in ("scene", "variant", "method", "scheme", "dt", "rtol", "t_final", "configuration", "status",
                                  "cpu_seconds", "compile_seconds", "rhs_evaluations", "projection_evaluations",
                                  "steps", "message")}
    row["max_error"] = math.nan
    row["max_drift"] = math.nan
    if result["y"] is None:
        return row
    t, Y = result["t"], np.asarray(result["y"])
    names = fi.names
    if ref is not None:
        data = {n: Y[i] for i, n in enumerate(names)}
        data.update(sc.observables(Y, names))
        r = ref(t)
        errs = {k: float(np.max(np.abs(data[k] - r[k]))) for k in sc.error_variables if k in data and k in r}
        for k, e in errs.items():
            row[f"error_{k}"] = e
        row["max_error"] = max(errs.values()) if errs else math.nan
    drifts = invariant_drifts(fi, Y)
    for k, d in drifts.items():
        row[f"drift_{k}"] = float(np.max(d))
    row["max_drift"] = max(row[f"drift_{k}"] for k in drifts) if drifts else math.nan
    if not np.isfinite(row["max_drift"]) and row["status"] == "ok":
        row["status"] = "diverged"
    return row


def invariant_drifts(fi, Y):
    """``{name: |I(t) - I(0)|}`` along ``Y`` (``(N, n_t)``) for every invariant ``fi`` monitors."""
    with np.errstate(all="ignore"):
        vals = fi.invariant_values(np.asarray(Y).T)
    out = {}
    for k, val in vals.items():
        if k == "energy":
            continue
        val = np.asarray(val, float)
        if k == "penalty":
            if fi.use_penalty:  # a chart (an angle) has nothing to keep orthogonal
                out["orthogonality"] = 2.0 * np.sqrt(np.maximum(val, 0.0))
        elif k.startswith("J_"):
            out[k] = np.abs(val)
        else:
            out[k] = np.abs(val - val[0])
    return out


def work_precision(scene, t_final=None, out_dir=None, executor=None, *, variant=None, dts=None, rtols=None,
                   methods=None, configuration=True, n_save=1000, quick=False, schemes=FIXED_SCHEMES,
                   ivp_methods=IVP_METHODS, plots=True, log=None):
    """Run the work-precision sweep of ``scene``; write ``<scene>-work-precision.csv`` and diagrams.

    Parameters
    ----------
    scene : str or Scene
    t_final : float, optional
        Horizon of every run (default: the scene's ``t_final``).
    out_dir : str, optional
        Where to write the CSV and PNGs (nothing is written without it).
    executor : concurrent.futures.Executor, optional
        Runs the grid (default: serially in this process); see :mod:`liefi.sweep`.
    variant, dts, rtols, methods, configuration, n_save, quick, schemes, ivp_methods
        The grid: see :func:`build_tasks` and :func:`default_grid`.
    plots : bool
        Write the PNGs too (with ``out_dir``).
    log : callable, optional
        ``log(message)`` for progress.

    Returns
    -------
    list of dict
        One row per run (the CSV's rows), in task order.
    """
    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    T = float(sc.t_final if t_final is None else t_final)
    tasks = build_tasks(sc, T, variant=variant, dts=dts, rtols=rtols, methods=methods,
                        configuration=configuration, n_save=n_save, quick=quick, schemes=schemes,
                        ivp_methods=ivp_methods)
    if log:
        log(f"{sc.name}: {len(tasks)} runs to t = {T:g}")
    w = time.perf_counter()
    results = run_sweep(run_task, tasks, executor)
    _, v, fi = _integrator(tasks[0])
    ref = reference(sc, v, fi, T)
    rows = [measure(sc, fi, r, ref) for r in results]
    if log:
        log(f"{sc.name}: done in {time.perf_counter() - w:.1f} s wall")
    if out_dir:
        os.makedirs(out_dir, exist_ok=True)
        write_csv(rows, os.path.join(out_dir, f"{sc.name}-work-precision.csv"))
        if plots:
            plot(rows, out_dir, sc.name)
    return rows


# ======================================================================================
# CSV
# ======================================================================================

_FIRST = ("scene", "variant", "method", "scheme", "dt", "rtol", "t_final", "configuration", "status", "cpu_seconds",
          "compile_seconds", "rhs_evaluations", "projection_evaluations", "steps", "max_error", "max_drift")


def write_csv(rows, path):
    """Write rows (dicts) with the columns of :data:`_FIRST` then every ``error_*`` and ``drift_*``."""
    extra = sorted({k for r in rows for k in r if k.startswith("error_")})
    extra += sorted({k for r in rows for k in r if k.startswith("drift_")})
    cols = list(_FIRST) + extra + ["message"]
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k, "")) for k in cols})
    return path


def read_csv(path):
    """Rows of a CSV written by :func:`write_csv`, numbers as floats."""
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            out = {}
            for k, v in r.items():
                if k in ("scene", "variant", "method", "scheme", "status", "message"):
                    out[k] = v
                elif k == "configuration":
                    out[k] = v == "True"
                else:
                    out[k] = float(v) if v not in ("", None) else None
            rows.append(out)
    return rows


# ======================================================================================
# reading the results
# ======================================================================================


def cheapest(rows, *, drift=1e-8, error=None, methods=None):
    """The row of least ``cpu_seconds`` among successful runs with ``max_drift <= drift``
    (and ``max_error <= error`` when given), optionally among ``methods`` only."""
    def good(r):
        if r["status"] != "ok" or r.get("max_drift") is None or not np.isfinite(r["max_drift"]):
            return False
        if error is not None and not (r.get("max_error") is not None and r["max_error"] <= error):
            return False
        return r["max_drift"] <= drift and (methods is None or r["method"] in methods)

    ok = [r for r in rows if good(r)]
    return min(ok, key=lambda r: r["cpu_seconds"]) if ok else None


def _label(r):
    p = f"dt={r['dt']:.3g}" if r.get("dt") else f"rtol={r['rtol']:.0e}"
    return f"{r['method']} {r['scheme']} ({p})"


def summary(rows, drift=1e-8):
    """One paragraph of text: the cheapest method reaching ``drift`` and the feedback integrator's."""
    best = cheapest(rows, drift=drift)
    fi = cheapest(rows, drift=drift, methods=("FI",))
    lines = []
    lines.append(f"cheapest with max drift <= {drift:g}: "
                 + (f"{_label(best)}, {best['cpu_seconds']:.3g} s" if best else "none"))
    lines.append("feedback integrator (fixed step) reaching it: "
                 + (f"{_label(fi)}, {fi['cpu_seconds']:.3g} s" if fi else "none in the grid"))
    return "\n".join(lines)


# ======================================================================================
# plots
# ======================================================================================

_COLORS = {"FI": "C3", "FI-tuned": "C6", "FI/solve_ivp": "C1", "no-feedback": "C7", "constrained": "C0", "projection": "C2", "DLA": "C4"}
_STYLES = {"euler": ("o", "-"), "heun": ("s", "-"), "rk4": ("^", "-"), "RK45": ("o", "--"), "DOP853": ("D", "--"),
           "LSODA": ("v", ":"), "dla": ("x", "-")}


def _series(rows):
    groups = {}
    for r in rows:
        if r["status"] != "ok":
            continue
        groups.setdefault((r["method"], r["scheme"]), []).append(r)
    return groups


def _draw(ax, rows, xkey, ykey):
    for (m, s), rs in _series(rows).items():
        pts = [(r[xkey], r[ykey]) for r in rs if r.get(ykey) is not None and np.isfinite(r[ykey]) and r[xkey]]
        if not pts:
            continue
        pts.sort()
        x, y = np.array(pts).T
        y = np.maximum(y, 1e-17)
        mk, ls = _STYLES.get(s, ("o", "-"))
        ax.loglog(x, y, marker=mk, ls=ls, color=_COLORS.get(m, "k"), ms=4, lw=1, label=f"{m} {s}")
    ax.grid(True, which="major", alpha=0.3)


def plot(rows, out_dir, name):
    """Write ``<name>-error.png`` (error vs CPU time and vs RHS evaluations) and
    ``<name>-drift.png`` (each invariant's drift vs CPU time); log-log."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    T = rows[0]["t_final"] if rows else float("nan")
    paths = []
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    _draw(axes[0], rows, "cpu_seconds", "max_error")
    axes[0].set_xlabel("CPU time [s]")
    axes[0].set_ylabel("max error vs reference")
    _draw(axes[1], rows, "rhs_evaluations", "max_error")
    axes[1].set_xlabel("right-hand-side evaluations")
    axes[0].set_title(f"{name}: error vs CPU time, t in [0, {T:g}]")
    axes[1].set_title("error vs work (engine independent)")
    h, lab = axes[0].get_legend_handles_labels()
    fig.legend(h, lab, loc="center right", fontsize=7)
    fig.tight_layout(rect=(0, 0, 0.84, 1))
    p = os.path.join(out_dir, f"{name}-error.png")
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    drifts = sorted({k for r in rows for k in r if k.startswith("drift_")})
    if all(not r.get("drift_orthogonality") for r in rows):  # no embedded rotation (older CSVs have zeros)
        drifts = [k for k in drifts if k != "drift_orthogonality"]
    if drifts:
        nc = min(3, len(drifts))
        nr = int(math.ceil(len(drifts) / nc))
        fig, axes = plt.subplots(nr, nc, figsize=(4.6 * nc + 2, 3.6 * nr), squeeze=False)
        for ax, k in zip(axes.flat, drifts):
            _draw(ax, rows, "cpu_seconds", k)
            ax.axhline(1e-8, color="k", lw=0.6, ls=":")
            ax.set_title(f"max |{k[6:]} drift|", fontsize=9)
            ax.set_xlabel("CPU time [s]", fontsize=8)
        for ax in list(axes.flat)[len(drifts):]:
            ax.axis("off")
        h, lab = axes.flat[0].get_legend_handles_labels()
        fig.legend(h, lab, loc="center right", fontsize=7)
        fig.suptitle(f"{name}: max drift of each invariant over t in [0, {T:g}] vs CPU time "
                     "(dotted: 1e-8; exact zeros drawn at 1e-17)")
        fig.tight_layout(rect=(0, 0, 1 - 1.9 / (4.6 * nc + 2), 0.95))
        p = os.path.join(out_dir, f"{name}-drift.png")
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths


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
    ref = [r for r in ok if r["method"] == reference_method and r["scheme"] == scheme]
    if not ref:
        return []
    target = min(ref, key=lambda r: abs(math.log(r["dt"] / sc.dt)))
    cost = target["cpu_seconds"] / target["t_final"]
    tasks = []
    for (m, s), rs in _series(ok).items():
        if (m, s) == (reference_method, scheme):
            pick = target
        else:
            pick = min(rs, key=lambda r: abs(math.log(max(r["cpu_seconds"], 1e-9) / r["t_final"] / max(cost, 1e-12))))
        t = {k: pick[k] for k in ("scene", "variant", "method", "scheme", "dt", "rtol")}
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
    results = run_sweep(run_task, tasks, executor)
    _, _, fi = _integrator(tasks[0])
    sc = _scenes.get(tasks[0]["scene"])
    out_rows, curves = [], {}
    for r in results:
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


def save_curves(curves, path):
    """Store the curves of :func:`long_horizon` (``np.savez_compressed``); see :func:`load_curves`."""
    arrays, meta = {}, []
    for i, (label, (t, d, cpu, m, s)) in enumerate(curves.items()):
        arrays[f"t{i}"] = np.asarray(t, np.float32)
        for k, v in d.items():
            arrays[f"d{i}:{k}"] = np.asarray(v, np.float32)
        meta.append([label, float(cpu), m, s, list(d)])
    import json

    np.savez_compressed(path, meta=json.dumps(meta), **arrays)
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    invs = sorted({k for _, d, *_ in curves.values() for k in d})
    if not invs:
        return None
    nc = min(3, len(invs))
    nr = int(math.ceil(len(invs) / nc))
    fig, axes = plt.subplots(nr, nc, figsize=(4.6 * nc + 2.6, 3.6 * nr), squeeze=False)
    for ax, k in zip(axes.flat, invs):
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
    for ax in list(axes.flat)[len(invs):]:
        ax.axis("off")
    h, lab = axes.flat[0].get_legend_handles_labels()
    fig.legend(h, lab, loc="center right", fontsize=6)
    fig.suptitle(f"{name}: drift vs time to t = {t_final:g}, each method at the cost closest to the FI's "
                 "(CPU s in the legend; exact zeros drawn at 1e-17)")
    fig.tight_layout(rect=(0, 0, 1 - 2.5 / (4.6 * nc + 2.6), 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ======================================================================================
# command line: `liefi bench` (see add_arguments / run_from_args) and `python -m liefi.bench`
# ======================================================================================


def add_arguments(parser):
    """Add ``liefi bench``'s arguments to an ``argparse`` (sub)parser."""
    parser.add_argument("scene", metavar="SCENE", help="scene name, or 'all'")
    parser.add_argument("--t-final", type=float, default=None, dest="t_final",
                        help="horizon of every run (default: the scene's)")
    parser.add_argument("--out", default="./liefi-bench", metavar="DIR", help="output directory")
    parser.add_argument("--variant", default=None, help="variant (default: the scene's first)")
    parser.add_argument("--scheduler", default=None, metavar="ADDR",
                        help="serial (default), processes[:N], threads[:N], dask[:N] or tcp://host:8786")
    parser.add_argument("--quick", action="store_true", help="a small grid (3 steps, 2 tolerances)")
    parser.add_argument("--long-horizon", type=float, default=None, dest="long_horizon", metavar="T",
                        help="also the drift against time up to T at matched cost (e.g. 1e4)")
    parser.add_argument("--no-configuration", action="store_true", dest="no_configuration",
                        help="integrate the reduced state only")
    parser.add_argument("--methods", default=None, metavar="M[,M]",
                        help=f"method families (default: all that apply): {','.join(METHODS)}")
    parser.add_argument("--schemes", default=None, metavar="S[,S]",
                        help=f"schemes (default: all): {','.join(FIXED_SCHEMES + IVP_METHODS)}")
    return parser


def _list(text, allowed, what):
    if text is None:
        return None
    items = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in items if t not in allowed]
    if bad or not items:
        raise ValueError(f"{what}: unknown {bad or text!r}; choose from {','.join(allowed)}")
    return items


def run_from_args(args, log=None):
    """Run ``liefi bench`` from parsed arguments; prints the summary, returns the exit code."""
    import sys

    from .sweep import open_executor

    log = log or (lambda m: print(m, file=sys.stderr, flush=True))
    if args.scene != "all" and args.scene not in _scenes.REGISTRY:
        raise ValueError(f"scene: unknown scene {args.scene!r}; choose one of {_scenes.names()} or 'all'")
    names = _scenes.names() if args.scene == "all" else [args.scene]
    if not _compiled.available():
        log(f"liefi bench: numba is not available ({_compiled.NUMBA_ERROR}); the generated code runs as plain "
            "Python, orders of magnitude slower. Install it with `pip install liefi[fast]`.")
    methods = _list(getattr(args, "methods", None), METHODS, "methods")
    chosen = _list(getattr(args, "schemes", None), FIXED_SCHEMES + IVP_METHODS, "schemes")
    schemes = FIXED_SCHEMES if chosen is None else tuple(s for s in chosen if s in FIXED_SCHEMES)
    ivp = IVP_METHODS if chosen is None else tuple(s for s in chosen if s in IVP_METHODS)
    with open_executor(args.scheduler) as ex:
        for name in names:
            try:
                sc = _scenes.get(name)
            except ImportError as exc:  # with 'all': a scene whose module is missing
                if args.scene != "all":
                    raise
                log(f"{name}: skipped ({exc})")
                continue
            use = None if methods is None else [m for m in methods if m in applicable_methods(sc)]
            rows = work_precision(sc, args.t_final, args.out, ex, variant=args.variant, quick=args.quick,
                                  configuration=not args.no_configuration, methods=use, schemes=schemes,
                                  ivp_methods=ivp, log=log)
            print(f"{name} (t_final = {rows[0]['t_final']:g}):")
            print("  " + summary(rows).replace("\n", "\n  "))
            if args.long_horizon:
                long_horizon(rows, args.out, ex, t_final=args.long_horizon, log=log)
    print(f"written to {args.out}")
    return 0


def main(argv=None):
    """``python -m liefi.bench SCENE [--t-final T] [--out DIR] [--scheduler ADDR] ...``."""
    import argparse

    p = argparse.ArgumentParser(prog="liefi bench", description="work-precision diagrams of a scene")
    add_arguments(p)
    return run_from_args(p.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
