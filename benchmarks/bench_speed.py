"""Speed of liefi's integration engine against hand-written compiled kernels.

Run::

    python benchmarks/bench_speed.py            # 1e6-step runs, 1e4-trajectory ensemble
    python benchmarks/bench_speed.py --quick    # 1e5 steps, 1e3 trajectories (a smoke test)
    python benchmarks/bench_speed.py --guard    # the guard's cost per ensemble call, gains="auto"

Prints, for the Suslov problem (R and Pi integrated, the paper's system), the
knife edge and the roller racer (reduced, the scene's default), all with
explicit Euler at the scene's step and gains:

* the numpy reference path (``FeedbackIntegrator.run``, Python loop) per step;
* liefi's compiled loop (``run(backend="numba")``) per step, over a 1e6-step run,
  as a user calls it (the run module's default path, :mod:`liefi.run` with its guard on) and the
  engine alone (``check_stability=False``), with the compile / cache-load time
  reported separately;
* the hand-written numba kernel (``hand_kernels.py``) per step, same run;
* the ratio liefi / hand (target: <= 3);

then the ensemble throughput (trajectory-steps per second) of 1e4 Suslov
trajectories stepped together, with numba's threads (both cores) and with one.

Times are process CPU time (``time.process_time``), best of ``--repeat`` runs,
so that other work on the machine does not inflate them; the ensemble is timed
in wall-clock seconds too (what "both cores used" buys), which *is* sensitive
to a loaded machine: the load average is printed next to it.  Nothing here is
asserted; the ratios are the result.  The kernels are checked to compute the
same field as liefi (max relative difference printed) before they are timed.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import numba  # noqa: E402

import hand_kernels  # noqa: E402
from liefi import FeedbackIntegrator, engine, scenes  # noqa: E402
from liefi.schemes import integrate  # noqa: E402

CASES = (("suslov", True), ("knife-edge", False), ("roller-racer", False))


def _best(fn, repeat):
    best = np.inf
    out = None
    for _ in range(repeat):
        c = time.process_time()
        out = fn()
        best = min(best, time.process_time() - c)
    return best, out


def field_agreement(fi, field, c, rng, k=20):
    """Max relative difference between the hand kernel's field and liefi's numpy field."""
    worst = 0.0
    out = np.empty(fi.n)
    for _ in range(k):
        y = fi.y0 + 0.05 * rng.normal(size=fi.n)
        field(y, c, out)
        ref = fi.vector_field(y)
        worst = max(worst, float(np.max(np.abs(out - ref)) / max(1.0, np.max(np.abs(ref)))))
    return worst


def single(name, configuration, n_steps, repeat, rng):
    sc = scenes.get(name)
    fi = sc.integrator(None, configuration=configuration)
    dt = sc.dt
    field, euler, c = hand_kernels.for_scene(sc, fi)
    agree = field_agreement(fi, field, c, rng)

    # numpy reference path: the Python loop over the numpy field that run(backend="numpy") steps
    n_np = 2000
    t_np, _ = _best(lambda: integrate(fi.vector_field, fi.y0, dt, n_np, "euler", save_every=n_np), 1)
    # liefi compiled: the first call traces, generates and compiles (or loads numba's on-disk cache)
    w = time.perf_counter()
    fi.run(dt, dt=dt, scheme="euler", backend="numba", check_stability=False)
    setup = time.perf_counter() - w
    cf = engine.compile_feedback(fi)
    compile_s = sum(cf.compile_seconds.values())
    # the user-facing loop: FeedbackIntegrator.run with its default stability guard (segments + monitor)
    t_liefi, sol = _best(lambda: fi.run(n_steps * dt, dt=dt, scheme="euler", save_every=n_steps, backend="numba"),
                         repeat)
    # without the stability guard (its fixed per-run costs remain: see the printed note)
    t_bare, _ = _best(lambda: fi.run(n_steps * dt, dt=dt, scheme="euler", save_every=n_steps, backend="numba",
                                     check_stability=False), repeat)
    # the engine alone: liefi.engine's loop, what FeedbackIntegrator.run calls
    p = engine.parameters(fi)
    t_engine, _ = _best(lambda: cf.run(fi.y0, p, dt, n_steps, "euler", save_every=n_steps), repeat)
    # hand kernel
    w = time.perf_counter()
    euler(fi.y0, c, dt, 1)
    hand_compile = time.perf_counter() - w
    t_hand, yh = _best(lambda: euler(fi.y0, c, dt, n_steps), repeat)
    yl = sol.y[..., -1]
    final = float(np.max(np.abs(yl - yh)) / max(1.0, np.max(np.abs(yh))))
    # compiled vs numpy on the same 2000 steps
    a = fi.run(n_np * dt, dt=dt, scheme="euler", save_every=100)
    b = fi.run(n_np * dt, dt=dt, scheme="euler", save_every=100, backend="numba")
    return {
        "scene": name,
        "configuration": configuration,
        "state_size": fi.n,
        "dt": dt,
        "steps": n_steps,
        "numpy_us_per_step": 1e6 * t_np / n_np,
        "liefi_ns_per_step": 1e9 * t_liefi / n_steps,
        "liefi_unguarded_ns_per_step": 1e9 * t_bare / n_steps,
        "engine_ns_per_step": 1e9 * t_engine / n_steps,
        "hand_ns_per_step": 1e9 * t_hand / n_steps,
        "ratio_liefi_over_hand": t_liefi / t_hand,
        "ratio_unguarded_over_hand": t_bare / t_hand,
        "ratio_engine_over_hand": t_engine / t_hand,
        "speedup_over_numpy": (t_np / n_np) / (t_liefi / n_steps),
        "liefi_setup_seconds": setup,
        "liefi_compile_seconds": compile_s,
        "hand_compile_seconds": hand_compile,
        "hand_vs_liefi_field_max_rel": agree,
        "hand_vs_liefi_final_state_max_rel": final,
        "numba_vs_numpy_2000_steps_max_abs": float(np.max(np.abs(a.y - b.y))),
    }


def ensemble(B, n_steps, repeat, rng):
    sc = scenes.get("suslov")
    base = sc.integrator(None, configuration=True)
    Y0 = np.repeat(base.y0[None], B, 0)
    Y0[:, 9:] = sc.system.project(base.y0[9:] + 0.2 * rng.normal(size=(B, 3)))
    fi = FeedbackIntegrator(sc.system, Y0, gains=sc.gains)
    dt = sc.dt
    fi.run(dt, dt=dt, scheme="euler", backend="numba", check_stability=False)  # compile
    out = {"trajectories": B, "steps": n_steps}
    for threads in (numba.config.NUMBA_NUM_THREADS, 1):
        numba.set_num_threads(threads)
        best_wall, best_cpu = np.inf, np.inf
        for _ in range(repeat):
            s = fi.run(n_steps * dt, dt=dt, scheme="euler", save_every=n_steps, backend="numba", check_stability=False)
            best_wall = min(best_wall, s.wall_seconds)
            best_cpu = min(best_cpu, s.cpu_seconds)
        out[f"threads_{threads}"] = {
            "traj_steps_per_s_wall": B * n_steps / best_wall,
            "traj_steps_per_cpu_s": B * n_steps / best_cpu,
            "wall_seconds": best_wall,
            "cpu_seconds": best_cpu,
        }
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    # numpy over the same batch, a few steps
    n_np = 20
    c = time.process_time()
    integrate(fi.vector_field, fi.y0, dt, n_np, "euler", save_every=n_np)
    out["numpy_traj_steps_per_cpu_s"] = B * n_np / (time.process_time() - c)
    # the same ensemble through the run module's default path (liefi.run.run_feedback, the guard on:
    # plan, pre-run estimate, kernel loading, segments checked by the guard, audit of the saved states)
    c = time.process_time()
    s = fi.run(n_steps * dt, dt=dt, scheme="euler", save_every=n_steps, backend="numba")
    out["default_run_cpu_seconds"] = time.process_time() - c
    out["default_run_loop_wall_seconds"] = getattr(s, "wall_seconds", float("nan"))
    out["default_run_overhead_seconds"] = getattr(s, "overhead_seconds", float("nan"))
    # once every kernel is loaded (loading is paid once per process): the default call against
    # the same call without the guard, CPU summed over threads, best of `repeat`
    best = np.inf
    for _ in range(repeat):
        c = time.process_time()
        fi.run(n_steps * dt, dt=dt, scheme="euler", save_every=n_steps, backend="numba")
        d = time.process_time() - c
        c = time.process_time()
        fi.run(n_steps * dt, dt=dt, scheme="euler", save_every=n_steps, backend="numba", check_stability=False)
        best = min(best, d / (time.process_time() - c))
    out["default_over_loop"] = best
    return out


def guard_cost(B, n_steps, repeat, rng, schemes=("euler", "imex-rk4")):
    """The guard's fixed cost per ensemble call: ``B`` Suslov states near ``y0`` x ``n_steps``, ``gains="auto"``.

    For each scheme, the default call (``run(..., backend="numba")``, the guard on: pre-run
    estimate, checks between segments, audit of the saved states) and the same call with
    ``check_stability=False``, interleaved, CPU time of the whole call (summed over threads),
    best of ``repeat`` each, after one warm call of both (kernels loaded).  The gains and
    their adaptation (Euler: every member adapted on its own schedule) are the run policy's
    and the same in both calls; the ratio is the guard's share.
    """
    sc = scenes.get("suslov")
    base = sc.integrator(None, configuration=True)
    Y0 = np.repeat(base.y0[None], B, 0)
    Y0[:, 9:] = sc.system.project(base.y0[9:] + 0.2 * rng.normal(size=(B, 3)))
    fi = FeedbackIntegrator(sc.system, Y0, gains="auto")
    dt = sc.dt
    out = {"trajectories": B, "steps": n_steps}
    for scheme in schemes:
        kw = dict(dt=dt, scheme=scheme, save_every=n_steps, backend="numba")
        fi.run(n_steps * dt, **kw)
        fi.run(n_steps * dt, check_stability=False, **kw)
        on, off = [], []
        for _ in range(repeat):
            c = time.process_time()
            s = fi.run(n_steps * dt, **kw)
            on.append(time.process_time() - c)
            c = time.process_time()
            fi.run(n_steps * dt, check_stability=False, **kw)
            off.append(time.process_time() - c)
        out[scheme] = {"guarded_cpu_seconds": min(on), "unguarded_cpu_seconds": min(off),
                       "ratio": min(on) / min(off), "checks": s.stability.monitors}
    return out


def suslov_t1000():
    """What ``liefi run suslov --t-final 1000`` costs with the compiled loop (Pi only and with R):
    the run's ``cpu_seconds`` with the stability guard (default) and without."""
    sc = scenes.get("suslov")
    out = {}
    for cfg in (False, True):
        fi = sc.integrator(None, configuration=cfg)
        fi.run(sc.dt, dt=sc.dt, scheme="euler", backend="numba")
        key = "with_R" if cfg else "Pi_only"
        out[key] = fi.run(1000.0, dt=sc.dt, scheme="euler", save_every=50, backend="numba").cpu_seconds
        out[key + "_no_guard"] = fi.run(1000.0, dt=sc.dt, scheme="euler", save_every=50, backend="numba",
                                        check_stability=False).cpu_seconds
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=float, default=1e6)
    ap.add_argument("--batch", type=int, default=10000)
    ap.add_argument("--batch-steps", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="1e5 steps, 1e3 trajectories")
    ap.add_argument("--json", default=None, metavar="FILE", help="also write the results as JSON")
    ap.add_argument("--guard", action="store_true",
                    help="only the guard's cost per ensemble call (1e4 Suslov states x 1000 steps, gains='auto', "
                         "euler and imex-rk4, best of 5, interleaved)")
    a = ap.parse_args(argv)
    if a.guard:
        B, n_steps = (1000, 200) if a.quick else (10000, 1000)
        g = guard_cost(B, n_steps, 5, np.random.default_rng(0))
        print(f"guard cost: {B} Suslov states x {n_steps} steps, gains='auto', CPU of the call, best of 5, "
              f"interleaved (load average {os.getloadavg()[0]:.2f})")
        for scheme in ("euler", "imex-rk4"):
            r = g[scheme]
            print(f"  {scheme:9s} guard on {r['guarded_cpu_seconds']:.3f} s, off {r['unguarded_cpu_seconds']:.3f} s: "
                  f"{r['ratio']:.3f} x ({r['checks']} checks)")
        if a.json:
            with open(a.json, "w") as fh:
                json.dump({"guard_cost": g}, fh, indent=2)
        return
    if a.quick:
        a.steps, a.batch, a.batch_steps, a.repeat = 1e5, 1000, 500, 1
    rng = np.random.default_rng(0)
    n = int(a.steps)
    # the knife edge runs at the paper's settings, exactly at Euler's stability bound (docs/paper_notes.md item 3)
    warnings.filterwarnings("ignore", message=".*stability bound.*")
    print(f"numba {numba.__version__}, {numba.config.NUMBA_NUM_THREADS} threads, os.cpu_count() = {os.cpu_count()}, "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"explicit Euler, {n:.0e} steps, CPU time, best of {a.repeat}\n")
    print(f"{'':14s} {'':3s} {'ns per step (CPU)':^49s}   {'ratio to the hand kernel':^30s}")
    print(f"{'scene':14s} {'N':>3s} {'numpy':>9s} {'run()':>9s} {'no guard':>9s} {'engine':>9s} {'hand':>9s} "
          f"  {'run()':>8s} {'no guard':>9s} {'engine':>8s} {'setup':>7s} {'field diff':>10s}")
    rows = []
    for name, cfg in CASES:
        r = single(name, cfg, n, a.repeat, rng)
        rows.append(r)
        print(f"{name:14s} {r['state_size']:3d} {1e3 * r['numpy_us_per_step']:9.0f} {r['liefi_ns_per_step']:9.1f} "
              f"{r['liefi_unguarded_ns_per_step']:9.1f} {r['engine_ns_per_step']:9.1f} {r['hand_ns_per_step']:9.1f}   "
              f"{r['ratio_liefi_over_hand']:8.2f} {r['ratio_unguarded_over_hand']:9.2f} {r['ratio_engine_over_hand']:8.2f} "
              f"{r['liefi_setup_seconds']:6.2f}s {r['hand_vs_liefi_field_max_rel']:10.1e}")
    print("\nrun(): FeedbackIntegrator.run(backend='numba') as a user calls it, the run module's default path"
          " (liefi.run, its guard liefi.guard on);\nno guard: run(..., check_stability=False); engine: liefi.engine's"
          " loop alone (CompiledField.run, what run() calls).\nThe differences are fixed per-run costs of the default"
          " path (the guard's pre-run estimate of Hess V and its checks between segments), not per-step costs.\n"
          "setup: first call in this process (trace + generate + numba compile, or load numba's on-disk cache);"
          " field diff: hand kernel vs liefi's numpy field;\nnumba vs numpy over 2000 steps: "
          + ", ".join(f"{r['scene']} {r['numba_vs_numpy_2000_steps_max_abs']:.1e}" for r in rows))
    e = ensemble(a.batch, a.batch_steps, a.repeat, rng)
    print(f"\nensemble: {e['trajectories']} Suslov trajectories (R and Pi) x {e['steps']} Euler steps "
          f"(load average {os.getloadavg()[0]:.2f})")
    for k, v in e.items():
        if k.startswith("threads_"):
            print(f"  {k.replace('_', ' '):10s}: {v['traj_steps_per_s_wall']:.3g} trajectory-steps/s (wall), "
                  f"{v['traj_steps_per_cpu_s']:.3g} per CPU-second")
    print(f"  numpy     : {e['numpy_traj_steps_per_cpu_s']:.3g} trajectory-steps per CPU-second")
    print("  (run(..., check_stability=False); wall = the compiled loop's elapsed time, CPU = summed over threads:"
          " CPU/wall near the thread count means every core worked; on a loaded machine it is lower)")
    print(f"  CPU/wall with {numba.config.NUMBA_NUM_THREADS} threads: "
          f"{e[f'threads_{numba.config.NUMBA_NUM_THREADS}']['cpu_seconds'] / e[f'threads_{numba.config.NUMBA_NUM_THREADS}']['wall_seconds']:.2f}")
    print(f"  the same ensemble through run()'s default path (liefi.run, guard on): "
          f"{e['default_run_cpu_seconds']:.2f} s CPU for the call (all threads), the loop "
          f"{e['default_run_loop_wall_seconds']:.2f} s wall; the run's overhead_seconds (estimate, guard, kernel "
          f"loading) {e['default_run_overhead_seconds']:.2f} s (first call: the kernel is loaded)")
    print(f"  once loaded, the default call costs {e['default_over_loop']:.2f} x the same call without the guard "
          "(CPU, best of --repeat)")
    t1000 = suslov_t1000()
    print(f"\nSuslov to t = 1000 (1e6 Euler steps), compiled, the run's cpu_seconds: Pi only {t1000['Pi_only']:.3f} s "
          f"({t1000['Pi_only_no_guard']:.3f} s without the guard), with R {t1000['with_R']:.3f} s "
          f"({t1000['with_R_no_guard']:.3f} s)")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"single": rows, "ensemble": e, "suslov_t1000": t1000}, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
