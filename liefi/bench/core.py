"""Work-precision: the feedback integrator against every method a user could pick, in one run.

:func:`work_precision` runs, on one scene, over a grid of steps ``dt`` or
tolerances ``rtol`` (each run from the scene's start to ``t_final``):

==================  =======================================================================
``FI``              the feedback integrator (``X - grad V``) with liefi's fixed-step schemes
                    ``euler``, ``heun``, ``rk4``, with the scene's gains and with each fixed
                    gain k of :data:`FI_GAINS` on every invariant (column ``gain``)
``FI-tuned``        the feedback integrator with fixed gains matched to ``dt`` and the scheme
                    (:func:`liefi.integrator.gains.auto_gains`: ``dt lambda_max(Hess V)`` at the
                    scheme's optimal rate along a pilot run), same schemes
``FI-accurate``     the feedback integrator with the gains of :func:`liefi.integrator.gains.accurate_gains`
                    (least drift bound for the scheme, ``dt`` and ``t_final``; zero on the
                    invariants the scheme keeps exactly); a run whose gains vanish on an
                    invariant the scheme does not keep is the no-feedback method, and is
                    recorded as ``not-applicable``
``FI/solve_ivp``    the same field with ``solve_ivp`` ``RK45``, ``DOP853``, ``LSODA``
``FI-rtol``         liefi's default run driven by a tolerance: ``FeedbackIntegrator.run(t_final,
                    rtol=r)`` with the constructor's default gains (``"auto"``), no scheme and no
                    ``dt`` (the library chooses both), for each r of :data:`FI_RTOLS`; column
                    ``dt`` is the step it chose, ``setup_seconds`` the CPU of the call outside
                    the integration (choosing the step, the guard)
``no-feedback``     the extended field ``X`` alone (gains zero) with ``euler``, ``heun``, ``rk4``
``constrained``     the original constrained equations (multipliers
                    ``lambda = C^{-1}{h, J}``, :func:`~liefi.reduction.full_vector_field`
                    with ``kind="constrained"``) with ``solve_ivp`` ``RK45``, ``DOP853``,
                    ``LSODA``: what a user of sympy.mechanics / PyDy does
``projection``      the constrained equations with ``euler``, ``heun``, ``rk4``, each step
                    followed by a Newton projection onto the invariant set (see below):
                    what DifferentialEquations.jl's ``ManifoldProjection`` does
``projection-1``    the same with exactly one Newton step per step and no convergence check:
                    the projection peer closest to a split feedback step at large gains
``DLA``             the discrete Lagrange--d'Alembert scheme of :mod:`liefi.schemes.dla_integrator`, where it
                    applies (systems on ``T*R^n`` with a constant metric)
==================  =======================================================================

and returns one row per run: method, scheme, ``dt`` or ``rtol``, CPU seconds,
right-hand-side evaluations, the max error against the scene's exact (or
reference) solution, and the max drift of every invariant (the constraint
momenta ``J_i``, ``h``, ``h~``, the scene's other invariants and
``orthogonality = ||R^T R - I||``).  :func:`write_csv` and :func:`plot` write
the CSV and the log-log diagrams; :func:`~liefi.bench.horizon.long_horizon` follows the drift of
each invariant against time up to ``t = 1e4`` for the feedback integrator and
each peer at matched cost.

How the runs are made comparable
--------------------------------
* Every field is the same generated, compiled code (:mod:`liefi.engine`):
  fixed-step schemes, the projection and the DLA scheme run entirely compiled; ``solve_ivp``
  calls the compiled right-hand side from its Python loop, which is what a
  scipy user with generated code (PyDy's Cython output) gets.  Compilation and
  warm-up are excluded from ``cpu_seconds`` and reported as ``compile_seconds``
  (for ``FI-tuned`` it includes the pilot run that chooses the gains).
  Because the fixed-step loops avoid Python's per-step overhead, part of a
  fixed-step method's advantage is the engine, not the method:
  ``rhs_evaluations`` is the engine-independent measure of work, and
  :func:`plot` draws error against it too.
* ``cpu_seconds`` is process CPU time (robust to other load on the machine),
  the least of ``repeats`` timed runs (:data:`REPEATS`; after the warm-up);
  ``cpu_spread = (second least - least) / least`` over the repeats is the run's
  measured noise (:func:`best_of`), which :mod:`liefi.bench.verdict` uses to call a ratio a tie.
* The state is the scene's full state ``(g, z)`` (configuration integrated, so
  that ``R^T R = I`` is an invariant to keep) unless ``configuration=False``.
* The projection is the Euclidean orthogonal projection onto
  ``{r(y) = 0}``, ``r`` = (upper triangle of ``R^T R - I`` for every orthogonal
  block, ``J_i``, ``h - h0``, each user invariant minus its target), by Newton's
  method along ``G(y)^T`` (``G = dr/dy``), up to 3 iterations per step, stopping
  at ``max |r| <= 1e-14``: the same fixed point as ManifoldProjection.  Its
  residual/Jacobian evaluations are counted in ``projection_evaluations``.
* Drifts are measured at the saved points (``n_save`` per run, uniform in time).

Tasks are plain dicts run by :func:`run_task` through :func:`liefi.results.sweep.run_sweep`,
so any executor (processes, a Dask cluster) can run the grid; every run is
measured as it arrives and appended to ``results.sqlite`` in the output folder
(a rerun resumes), and a run that raises or whose worker dies is a row with
``status = "error"``, never a lost sweep.  matplotlib is
imported by the plotting functions only.
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
import signal
import threading
import time

import numpy as np

from .. import engine as _engine
from .. import scenes as _scenes
from .._files import replacing
from ..results.sweep import ResultStore, StoreError, SweepInterrupted, TaskError, run_sweep
from .verdict import FI_METHODS, RTOL_METHOD, cheapest, summarize, summary  # noqa: F401  (re-exported)

FIXED_SCHEMES = ("euler", "heun", "rk4", "imex-euler", "imex-heun", "imex-rk4")
IVP_METHODS = ("RK45", "DOP853", "LSODA")
METHODS = ("FI", "FI-tuned", "FI-accurate", "FI/solve_ivp", "FI-rtol", "no-feedback", "constrained", "projection",
           "projection-1", "DLA")
#: the gains of the ``FI`` rows: ``None`` is the scene's own (the paper's) gains, a number k is k on every
#: invariant.  Small gains belong here: with RK4 at the scene's step, k = 0.1 keeps the oscillator's
#: invariants bounded at the cost of plain RK4.  Zero is the ``no-feedback`` method, not an FI.
FI_GAINS = (None, 0.1, 1.0, 10.0)
#: the tolerances of the ``FI-rtol`` rows (``FeedbackIntegrator.run(t_final, rtol=r)``)
FI_RTOLS = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
#: every run is timed this many times and keeps the least CPU time (``cpu_spread``: the repeats' relative spread)
REPEATS = 3
STORE = "results.sqlite"
#: CPU seconds one ``solve_ivp`` call of a sweep may take; past it the call is stopped and the run recorded
#: as ``failed`` with the reason.  ``solve_ivp`` has no limit of its own: LSODA at ``rtol = 1e-3`` on the
#: perturbed Kepler problem lets the orbit fall into ``r = 0`` (the ``-delta/r^3`` well), reaches a
#: non-finite state at ``t = 489.77`` and retries that step for ever (13 million evaluations a minute).
#: The slowest ``solve_ivp`` run of the grids finishing normally takes under 5 s.
IVP_CPU_CAP = 60.0


# ======================================================================================
# tasks
# ======================================================================================


def default_grid(scene, t_final, quick=False):
    """``(dts, rtols)``: steps ``scene.dt * 2^k`` and tolerances ``1e-3 ... 1e-11``."""
    if quick:
        return [scene.dt * f for f in (4.0, 1.0, 0.25)], [1e-4, 1e-8]
    return [scene.dt * f for f in (8.0, 4.0, 2.0, 1.0, 0.5, 0.25, 0.125, 0.0625)], [1e-3, 1e-5, 1e-7, 1e-9, 1e-11]


def default_fi_rtols(quick=False):
    """The tolerances of the ``FI-rtol`` rows: :data:`FI_RTOLS`, or ``1e-4, 1e-7, 1e-10`` with ``quick``."""
    return [1e-4, 1e-7, 1e-10] if quick else list(FI_RTOLS)


def applicable_methods(scene):
    """The method families that apply to ``scene`` (DLA only on ``T*R^n`` with a constant metric)."""
    out = list(METHODS)
    if not _engine.dla_applies(scene.system):
        out.remove("DLA")
    return out


def build_tasks(scene, t_final, *, variant=None, dts=None, rtols=None, methods=None, configuration=True,
                n_save=1000, quick=False, schemes=FIXED_SCHEMES, ivp_methods=IVP_METHODS, gains=FI_GAINS,
                fi_rtols=None, repeats=REPEATS):
    """The list of task dicts of a work-precision sweep (see :func:`run_task`).

    ``schemes`` (liefi's fixed-step schemes) and ``ivp_methods`` (``solve_ivp``'s)
    restrict the grid; the defaults are :data:`FIXED_SCHEMES` and :data:`IVP_METHODS`.
    ``gains`` are the gains of the ``FI`` rows (:data:`FI_GAINS`; ``None``: the scene's).
    ``fi_rtols``: the tolerances of the ``FI-rtol`` rows (default :func:`default_fi_rtols`).
    ``repeats``: timed runs per task, the least CPU time kept (:data:`REPEATS`).
    """
    from .validate import check_grid, positive_int

    t_final, dts, rtols, gains = check_grid(t_final, dts, rtols, gains)
    fi_rtols = default_fi_rtols(quick) if fi_rtols is None else check_grid(t_final, None, fi_rtols, ())[2]
    repeats = positive_int("repeats", repeats)
    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    v = sc.variant(variant).name
    g_dts, g_rtols = default_grid(sc, t_final, quick)
    dts = g_dts if dts is None else list(dts)
    rtols = g_rtols if rtols is None else list(rtols)
    methods = applicable_methods(sc) if methods is None else list(methods)
    common = {"scene": sc.name, "variant": v, "t_final": float(t_final), "configuration": bool(configuration),
              "n_save": int(n_save), "gain": None, "repeats": repeats}
    from ..schemes import get as _scheme

    # a split imex-* scheme steps the feedback field: it is a feedback integrator only
    split = [s for s in schemes if _scheme(s).kind == "split"]
    explicit = [s for s in schemes if s not in split]
    tasks = []
    for m in methods:
        if m == "FI":
            tasks += [dict(common, method=m, scheme=s, dt=float(dt), rtol=None, gain=k)
                      for k in gains for s in schemes for dt in dts]
        elif m in ("FI-tuned", "FI-accurate"):
            tasks += [dict(common, method=m, scheme=s, dt=float(dt), rtol=None) for s in schemes for dt in dts]
        elif m in ("no-feedback", "projection", "projection-1"):
            tasks += [dict(common, method=m, scheme=s, dt=float(dt), rtol=None) for s in explicit for dt in dts]
        elif m == "FI/solve_ivp":
            tasks += [dict(common, method=m, scheme=s, dt=None, rtol=float(r), gain=k)
                      for k in gains for s in ivp_methods for r in rtols]
        elif m == RTOL_METHOD:
            tasks += [dict(common, method=m, scheme="default", dt=None, rtol=float(r)) for r in fi_rtols]
        elif m == "constrained":
            tasks += [dict(common, method=m, scheme=s, dt=None, rtol=float(r)) for s in ivp_methods for r in rtols]
        elif m == "DLA":
            tasks += [dict(common, method=m, scheme="dla", dt=float(dt), rtol=None) for dt in dts]
        else:
            raise ValueError(f"methods: unknown method {m!r}; choose from {METHODS}")
    return tasks


def _split_scheme(name):
    from ..schemes import get

    return get(name).kind == "split"


def _integrator(task, gains=None):
    sc = _scenes.get(task["scene"])
    v = sc.variant(task["variant"])
    cfg = task["configuration"] and sc.system.space.group.config_dim > 0
    return sc, v, sc.integrator(v, configuration=cfg, gains=gains)


def best_of(repeats, timed):
    """Call ``timed()`` (returning ``(result, cpu_seconds)``) ``repeats`` times.

    Returns ``(result, cpu, spread)``: the result of the fastest call, the least CPU
    time, and the spread ``(second least - least) / least`` of the CPU times (``nan``
    for one call): how far the next-best repeat is from the kept one.  The second
    least rather than the largest, so that one repeat slowed by another process (or
    a cold cache) does not turn every comparison of the scene into a tie.
    """
    runs = [timed() for _ in range(max(1, int(repeats)))]
    cpus = [c for _, c in runs]
    i = int(np.argmin(cpus))
    lo = cpus[i]
    spread = (sorted(cpus)[1] - lo) / lo if len(cpus) > 1 and lo > 0 else math.nan
    return runs[i][0], lo, spread


class CpuCapExceeded(RuntimeError):
    """A call ran past its CPU cap (:func:`cpu_cap`)."""


@contextlib.contextmanager
def cpu_cap(seconds):
    """Within the block, raise :class:`CpuCapExceeded` once this process has spent ``seconds`` of CPU time
    in it (``ITIMER_PROF``; the exception is raised at the next Python instruction, e.g. in the
    right-hand side ``solve_ivp`` calls).  ``None``, a thread other than the main one or a platform
    without ``setitimer``: the block runs uncapped.  The caller's handler and timer are restored."""
    if seconds is None or not hasattr(signal, "setitimer") or threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise CpuCapExceeded(f"stopped after {seconds:g} s of CPU")

    old = signal.signal(signal.SIGPROF, stop)
    signal.setitimer(signal.ITIMER_PROF, float(seconds))
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0.0)
        signal.signal(signal.SIGPROF, old)


def _steps(t_final, dt, n_save):
    from ..schemes import steps_for  # the one validator of a fixed-step run's arguments

    n = steps_for(dt, t_final)[2]
    return n, max(1, n // n_save)


#: The prior of :func:`expected_seconds`: seconds of one field evaluation compiled, one Newton projection
#: step, one DLA update, one evaluation of ``solve_ivp``'s Python right-hand side, and the fixed cost of a
#: task (its integrator, the warm-up, the error against the reference); measured on ``liefi bench suslov
#: --quick`` with warm kernels (a cold cache adds the compile to the first task of a kind).  Only their
#: ratios matter: the sweep's time left learns each kind's own rate from its finished tasks
#: (:class:`liefi._progress.Progress`).
EVAL_SECONDS, PROJECTION_SECONDS, DLA_SECONDS, IVP_EVAL_SECONDS, TASK_SECONDS = 3e-8, 7e-8, 1e-7, 3e-6, 0.05
#: ... the tolerance runs: the evaluations per unit time at ``rtol = 1`` (``n ~ K T rtol^{-1/p}``); the
#: factor of an explicit ``solve_ivp`` method on the stiff feedback field (``FI/solve_ivp``); the setup
#: of an ``FI-rtol`` run (the pilot and the check's runs) and the tuning of ``FI-tuned`` gains for an
#: explicit tableau (the split schemes need none).
IVP_EVALS_SCALE, STIFF_FACTOR, RTOL_SETUP_SECONDS, TUNE_SECONDS = 5.0, 30.0, 1.0, 4.0


def expected_seconds(task):
    """``(kind, seconds)``: the kind of a task (``"method scheme"``) and a prior of its seconds.

    The time left of a sweep is weighted by it (:func:`liefi.results.sweep.run_sweep`,
    ``expected``): a fixed-step run costs ``repeats x T/dt x`` its evaluations a
    step; a tolerance run ``K T rtol^{-1/p}`` evaluations of order ``p``
    (:data:`STIFF_FACTOR` more for an explicit ``solve_ivp`` method on the
    feedback field), a ``solve_ivp`` one capped at :data:`IVP_CPU_CAP` per call;
    each task :data:`TASK_SECONDS` more, and ``FI-tuned`` on an explicit tableau
    :data:`TUNE_SECONDS`.
    """
    from ..schemes import registry

    method, scheme, T = task["method"], task["scheme"], float(task["t_final"])
    repeats = 1 + int(task.get("repeats", 1))  # the warm-up and the timed runs
    kind = f"{method} {scheme}"
    if method == RTOL_METHOD:
        p = 8  # the order it usually chooses
        return kind, TASK_SECONDS + RTOL_SETUP_SECONDS + repeats * EVAL_SECONDS * 14 * IVP_EVALS_SCALE * T * \
            float(task["rtol"]) ** (-1.0 / p)
    if task.get("dt") is None:  # solve_ivp at a tolerance
        ivp = registry.get(f"scipy:{scheme}", kind="scipy")
        p = getattr(ivp, "order", 5) or 5
        evals = IVP_EVALS_SCALE * T * float(task["rtol"]) ** (-1.0 / p)
        if method == "FI/solve_ivp" and not ivp.stiff_safe:
            evals *= STIFF_FACTOR
        return kind, TASK_SECONDS + repeats * min(IVP_EVAL_SECONDS * evals, IVP_CPU_CAP)
    n = T / float(task["dt"])
    if method == "DLA":
        return kind, TASK_SECONDS + repeats * n * DLA_SECONDS
    sch = registry.get(scheme)
    per_step = (getattr(sch, "stages", 1) or 1) + (1 if sch.kind == "split" else 0)
    step = per_step * EVAL_SECONDS + (PROJECTION_SECONDS if method.startswith("projection") else 0.0)
    tune = TUNE_SECONDS if method == "FI-tuned" and sch.kind != "split" else 0.0
    return kind, TASK_SECONDS + tune + repeats * n * step


def run_task(task):
    """Run one method of a sweep; returns ``{t, y, cpu_seconds, rhs_evaluations, ...}`` or a failure.

    ``task``: ``scene``, ``variant``, ``method`` (one of :data:`METHODS`),
    ``scheme``, ``dt`` or ``rtol``, ``t_final``, ``configuration``, ``n_save``,
    ``repeats`` (default 1: timed runs after the warm-up, :func:`best_of`).
    ``y`` is ``(N, n_t)`` in the feedback integrator's state layout.  Never
    raises for a run that fails (diverges, solver gives up): ``status`` says so.
    """
    from scipy.integrate import solve_ivp

    from ..schemes import IntegrationError

    out = dict(task)
    out.update(status="ok", message="", cpu_seconds=math.nan, compile_seconds=0.0, rhs_evaluations=0,
               projection_evaluations=0, steps=0, t=None, y=None, cpu_spread=math.nan, setup_seconds=None)
    repeats = task.get("repeats", 1)
    try:
        method, scheme, T = task["method"], task["scheme"], task["t_final"]
        sc, v, fi = _integrator(task, gains="auto" if method == RTOL_METHOD else None)
        w = time.perf_counter()
        if method == RTOL_METHOD:
            # liefi's default run for a tolerance: no scheme, no dt, the constructor's default gains
            kw = dict(rtol=task["rtol"], progress=False)
            first = fi.run(T, save_every=2**62, **kw)  # the warm-up: compiles, and tells the number of steps
            n = first.plan.n_steps
            out["compile_seconds"] = time.perf_counter() - w
            se = max(1, n // task["n_save"])
            sol, cpu, spread = best_of(repeats, lambda: (lambda s: (s, s.cpu_seconds))(fi.run(T, save_every=se, **kw)))
            out.update(t=sol.t, y=sol.y, cpu_seconds=cpu, cpu_spread=spread, rhs_evaluations=int(sol.nfev), steps=n,
                       dt=float(sol.method["dt"]), scheme=sol.method["scheme"], setup_seconds=sol.overhead_seconds,
                       message=sol.method.get("why", "")[:300])
        elif method in ("FI", "FI-tuned", "FI-accurate", "no-feedback", "projection", "projection-1"):
            n, se = _steps(T, task["dt"], task["n_save"])
            # a split scheme (explicit tableau on X, then the feedback substep) has its own kernel
            compile_fi = _engine.compile_split if _split_scheme(scheme) else _engine.compile_feedback
            if method in ("projection", "projection-1"):
                cf = _engine.compile_constrained(fi, projection=True)
                p, proj = np.zeros(0), _engine.projection_targets(fi)
            elif method == "FI-tuned":
                from ..integrator.gains import auto_gains

                fi = fi.with_gains(auto_gains(fi, task["dt"], scheme, y=fi.y0, t_final=T))
                out["message"] = "gains " + ", ".join(f"{k}={v:.3g}" for k, v in fi.gains.items())
                cf = compile_fi(fi)
                p, proj = _engine.parameters(fi), None
            elif method == "FI-accurate":
                from ..integrator.gains import accurate_gains, exactly_kept

                g = accurate_gains(fi, task["dt"], scheme, t_final=T)
                out["message"] = "gains " + ", ".join(f"{k}={v:.3g}" for k, v in g.items())
                kept = set(exactly_kept(fi, scheme))
                zero = [k for k, v in g.items() if v == 0 and k not in kept]
                if zero or not any(g.values()):
                    out.update(status="not-applicable",
                               message=f"accurate gains are zero on {zero or list(g)}: that is the no-feedback method")
                    return out
                fi = fi.with_gains(g)
                if kept:  # left out of V, as a default run does (liefi.integrator.gains.exact_drops)
                    fi = fi.without({k: "kept exactly by the scheme" for k in kept})
                cf = compile_fi(fi)
                p, proj = _engine.parameters(fi), None
            else:
                if method == "FI" and task.get("gain") is not None:
                    fi = fi.with_gains(task["gain"])
                cf = compile_fi(fi) if method == "FI" else _engine.compile_feedback(fi, feedback=False)
                p, proj = _engine.parameters(fi), None
            cf.warmup(scheme, project=proj is not None)
            out["compile_seconds"] = time.perf_counter() - w
            newton = dict(maxit=1, tol=-1.0) if method == "projection-1" else {}  # one step, no check

            def timed():
                sol = cf.run(fi.y0, p, task["dt"], n, scheme, save_every=se, names=fi.names, project=proj, **newton)
                return sol, sol.cpu_seconds

            sol, cpu, spread = best_of(repeats, timed)
            out.update(t=sol.t, y=sol.y, cpu_seconds=cpu, cpu_spread=spread, rhs_evaluations=sol.rhs_evaluations,
                       steps=n, projection_evaluations=getattr(sol, "projection_evaluations", 0))
        elif method in ("FI/solve_ivp", "constrained"):
            if method == "FI/solve_ivp":
                if task.get("gain") is not None:
                    fi = fi.with_gains(task["gain"])
                cf = _engine.compile_feedback(fi)
                fun = cf.fun(_engine.parameters(fi))
            else:
                cf = _engine.compile_constrained(fi)
                fun = cf.fun(np.zeros(0))
            out["compile_seconds"] = time.perf_counter() - w
            t_eval = np.linspace(0.0, T, task["n_save"] + 1)
            rtol = task["rtol"]

            def timed():
                c0 = time.process_time()
                with np.errstate(all="ignore"), cpu_cap(IVP_CPU_CAP):
                    sol = solve_ivp(fun, (0.0, T), fi.y0, method=scheme, t_eval=t_eval, rtol=rtol, atol=1e-2 * rtol)
                return sol, time.process_time() - c0

            sol, cpu, spread = best_of(repeats, timed)
            out.update(cpu_seconds=cpu, cpu_spread=spread, rhs_evaluations=int(sol.nfev), steps=None)
            if not sol.success:
                out.update(status="failed", message=f"solve_ivp({scheme}): {sol.message}")
            elif not np.all(np.isfinite(sol.y)):
                out.update(status="diverged", message=f"solve_ivp({scheme}) returned non-finite values")
            else:
                out.update(t=sol.t, y=sol.y)
        elif method == "DLA":
            from ..schemes.dla_integrator import DLAIntegrator

            sys_ = sc.system
            n, se = _steps(T, task["dt"], task["n_save"])
            cd = _engine.compile_dla(sys_)
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
            (t, q, mom, _, updates), cpu, spread = best_of(
                repeats, lambda: (lambda r: (r, r[3]))(cd.run(q0, q1, task["dt"], n, save_every=se)))
            out.update(t=t, y=np.concatenate([q, mom], 0), cpu_seconds=cpu, cpu_spread=spread, rhs_evaluations=updates,
                       steps=n)
        else:
            raise ValueError(f"method: unknown {method!r}")
    except CpuCapExceeded as exc:
        out.update(status="failed", message=f"solve_ivp({task['scheme']}): {exc} (liefi.bench.core.IVP_CPU_CAP); "
                                            "no end in sight, e.g. a step retried on a non-finite state")
    except (IntegrationError, FloatingPointError) as exc:
        out.update(status="diverged", message=" ".join(str(exc).split())[:300])
    except _engine.NotCompilable as exc:
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
    scene's start by DOP853 at the scene's own reference tolerances
    (``scene.reference_rtol``, ``scene.reference_atol``) and evaluates its dense
    output.  Over the harness's horizon that tolerance is the floor of every
    measured error: a scene whose errors all stall at one value needs a tighter
    reference, not a better method (``perturbed-kepler``: at ``rtol = atol =
    1e-12`` the reference itself was 4.6e-6 off at ``t = 1000``).
    """
    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    v = sc.variant(variant) if not hasattr(variant, "name") else variant
    if sc.reference == "exact":
        return lambda t: sc.exact(np.asarray(t, float), v)
    from scipy.integrate import solve_ivp

    cf = _engine.compile_constrained(fi)
    sol = solve_ivp(cf.fun(np.zeros(0)), (0.0, float(t_final)), fi.y0, method="DOP853", rtol=sc.reference_rtol,
                    atol=sc.reference_atol, dense_output=True)
    if not sol.success:
        raise RuntimeError(f"reference solution of {sc.name!r} failed: {sol.message}")
    names = fi.names

    def ref(t):
        Y = sol.sol(np.asarray(t, float))
        return {n: Y[i] for i, n in enumerate(names)}

    return ref


_ROW_KEYS = ("scene", "variant", "method", "scheme", "dt", "rtol", "gain", "t_final", "configuration", "status",
             "cpu_seconds", "cpu_spread", "repeats", "setup_seconds", "compile_seconds", "rhs_evaluations",
             "projection_evaluations", "steps", "message")


def error_row(task, err):
    """The CSV row of a task that raised or whose worker died (a :class:`~liefi.results.sweep.TaskError`)."""
    row = {k: task.get(k) for k in _ROW_KEYS}
    row.update(status="error", message=str(err)[:300], cpu_seconds=math.nan, compile_seconds=0.0,
               rhs_evaluations=0, projection_evaluations=0, steps=0, max_error=math.nan, max_drift=math.nan)
    return row


def measure(scene, fi, result, ref=None):
    """Errors and drifts of one run (a :func:`run_task` result) -> a CSV row (dict).

    ``max_error`` is the max over the saved points and over the scene's compared
    variables of ``|x - x_ref|``; ``drift_<I>`` is ``max |I(t) - I(0)|`` (``J_i``
    and ``orthogonality`` against 0), as :class:`~liefi.scenes.Scene` reports it.
    """
    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    row = {k: result.get(k) for k in _ROW_KEYS}
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
                   ivp_methods=IVP_METHODS, gains=FI_GAINS, plots=True, log=None, progress=None, store=None,
                   select=None, fi_rtols=None, repeats=REPEATS):
    """Run the work-precision sweep of ``scene``; write ``<scene>-work-precision.csv`` and diagrams.

    Parameters
    ----------
    scene : str or Scene
    t_final : float, optional
        Horizon of every run (default: the scene's ``t_final``); finite and > 0.
    out_dir : str, optional
        Where to write the CSV and PNGs, and the results store ``results.sqlite``
        (:class:`~liefi.results.sweep.ResultStore`) that every run is appended to as it
        finishes; a rerun into the same ``out_dir`` skips the runs already there.
        Nothing is written without it.
    executor : concurrent.futures.Executor, optional
        Runs the grid (default: serially in this process); see :mod:`liefi.results.sweep`.
    variant, dts, rtols, methods, configuration, n_save, quick, schemes, ivp_methods, gains, fi_rtols
        The grid: see :func:`build_tasks` and :func:`default_grid`.
    repeats : int
        Timed runs per task; the least CPU time is kept (:data:`REPEATS`, default 3).
    select : callable, optional
        ``select(task) -> bool`` keeps part of the grid only.
    plots : bool
        Write the PNGs too (with ``out_dir``).
    log : callable, optional
        ``log(message)`` for messages.
    progress : bool, optional
        Progress on stderr (default: when stderr is a terminal).
    store : ResultStore, optional
        The store to use instead of ``out_dir/results.sqlite``.

    Returns
    -------
    list of dict
        One row per run (the CSV's rows), in task order.  A run that raised or
        whose worker died is a row with ``status = "error"`` and the error in
        ``message``; a run that diverged has ``status = "diverged"``.

    Raises
    ------
    liefi.results.sweep.SweepInterrupted
        On Ctrl-C (or SIGTERM), after the CSV of the runs finished so far is
        written (``exc.rows``: exactly the runs of the grid in the store).
    liefi.results.sweep.StoreError
        When the store cannot be written (disk full) or read (damaged), with
        ``exc.rows`` and the CSV as for an interrupt.
    """
    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    T = sc.t_final if t_final is None else t_final
    tasks = build_tasks(sc, T, variant=variant, dts=dts, rtols=rtols, methods=methods,
                        configuration=configuration, n_save=n_save, quick=quick, schemes=schemes,
                        ivp_methods=ivp_methods, gains=gains, fi_rtols=fi_rtols, repeats=repeats)
    if select is not None:
        tasks = [t for t in tasks if select(t)]
        if not tasks:
            raise ValueError("select: no task of the grid is selected")
    T = tasks[0]["t_final"]
    own = None
    if store is None and out_dir:
        os.makedirs(out_dir, exist_ok=True)  # checked before any work: an unwritable --out fails here
        store = own = ResultStore(os.path.join(out_dir, STORE), sweep=sc.name)
    if log:
        log(f"{sc.name}: {len(tasks)} runs to t = {T:g}")
    w = time.perf_counter()
    _, v, fi = _integrator(tasks[0])
    ref_cache = []

    def convert(task, result):
        if not ref_cache:
            ref_cache.append(reference(sc, v, fi, T))
        return measure(sc, fi, result, ref_cache[0])

    def rows_of(values):
        return [error_row(t, x) if isinstance(x, TaskError) else x for t, x in zip(tasks, values) if x is not None]

    def keep(exc):  # the CSV of what finished (all of it in the store), before the interrupt goes on
        exc.rows = rows_of(exc.results) if exc.results is not None else []
        exc.unwritten = None
        if out_dir and exc.rows:
            try:
                write_csv(exc.rows, os.path.join(out_dir, f"{sc.name}-work-precision.csv"))
            except OSError as err:  # e.g. the disk is full too: the store keeps everything
                exc.unwritten = str(err)

    try:
        rows = rows_of(run_sweep(run_task, tasks, executor, store=store, convert=convert, progress=progress,
                                 label=sc.name, expected=expected_seconds))
    except (SweepInterrupted, StoreError) as exc:
        keep(exc)
        raise
    finally:
        if own is not None:
            own.close()
    if log:
        bad = sum(r["status"] == "error" for r in rows)
        log(f"{sc.name}: done in {time.perf_counter() - w:.1f} s wall" + (f"; {bad} runs raised (see the CSV)" if bad else ""))
    if out_dir:
        write_csv(rows, os.path.join(out_dir, f"{sc.name}-work-precision.csv"))
        if plots:
            from .plots import plot

            plot(rows, out_dir, sc.name)
    return rows


# ======================================================================================
# CSV
# ======================================================================================

_FIRST = ("scene", "variant", "method", "scheme", "dt", "rtol", "gain", "t_final", "configuration", "status", "cpu_seconds",
          "cpu_spread", "repeats", "setup_seconds", "compile_seconds", "rhs_evaluations", "projection_evaluations",
          "steps", "max_error", "max_drift")


def write_csv(rows, path):
    """Write rows (dicts) with the columns of :data:`_FIRST` then every ``error_*`` and ``drift_*``."""
    extra = sorted({k for r in rows for k in r if k.startswith("error_")})
    extra += sorted({k for r in rows for k in r if k.startswith("drift_")})
    cols = list(_FIRST) + extra + ["message"]
    with replacing(path) as tmp, open(tmp, "w", newline="") as fh:  # whole or not at all
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
