"""Generate the work-precision CSVs, diagrams, summary and crossover tables of ``docs/work_precision.md``.

Run (both stages resume: every run is appended to a SQLite store as it
finishes, and a rerun skips what is there)::

    python benchmarks/make_docs.py grid                    # every scene, t in [0, 1e3]
    python benchmarks/make_docs.py long --t-final 1e5      # long runs, crossover horizons
    python benchmarks/make_docs.py long --t-final 1e6 --only roller-racer --dts 8 --gains 1 --methods FI,projection
    python benchmarks/make_docs.py tables                  # print the markdown tables
    python benchmarks/make_docs.py summary --out DIR --dts ...   # summary.json of every scene of a grid

``grid`` writes into ``docs/work_precision/`` (``--out``): per scene
``<scene>-work-precision.csv``, ``<scene>-error.png``, ``<scene>-drift.png``;
``results.sqlite`` (every run) and ``summary.json`` (per scene
``cheapest_overall``, ``cheapest_fi``, ``fi_over_best`` for "every invariant
<= 1e-8", as ``liefi bench`` writes it).  The grid is the scene's
``dt * (8, 4, 2, 1, 1/2, 1/4)`` for the fixed-step methods, the FI with the
scene's gains and k = 0.1, 1, 10 on every invariant, ``rtol = 1e-3 ... 1e-11``
for ``solve_ivp``; ``FI/solve_ivp`` with LSODA only (RK45 and DOP853 on the
stiff FI field cost minutes per run and never win).

``long`` runs every compiled fixed-step family (FI with k = 0.1 and 1,
``FI-accurate``, no-feedback, projection) with RK4 and the split ``imex-rk4``
(``--schemes``; projection and no-feedback with RK4 only) at ``dt * (8, 4)`` to ``--t-final`` and
writes ``long-<T>.sqlite``, ``crossover.json`` and ``<scene>-cost-horizon.png``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from liefi import bench, scenes  # noqa: E402
from liefi.sweep import ResultStore, TaskError, run_sweep, open_executor  # noqa: E402

OUT = os.path.join(os.path.dirname(HERE), "docs", "work_precision")


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _grid_select(task, methods=None):
    """The grid's part of :func:`liefi.bench.build_tasks`: ``FI/solve_ivp`` with LSODA only, and only the
    families of ``methods`` (``--methods``, comma-separated; ``None``: every family)."""
    if methods and task["method"] not in methods.split(","):
        return False
    return not (task["method"] == "FI/solve_ivp" and task["scheme"] != "LSODA")


def _grid_tasks(a, names):
    """``{scene: tasks}`` of the grid stage for ``names`` (its ``--dts``, ``--repeats`` and ``--t-final``)."""
    factors = [float(f) for f in (a.dts or "8,4,2,1,0.5,0.25").split(",")]
    out = {}
    for name in names:
        sc = scenes.get(name)
        out[name] = [t for t in bench.build_tasks(sc, a.t_final, dts=[sc.dt * f for f in factors],
                                                  repeats=a.repeats) if _grid_select(t, a.methods)]
    return out


def summary(a, names):
    """Rebuild ``summary.json`` for every scene of ``names`` (one grid invocation writes its own scenes only)."""
    doc = bench.write_summary(a.out, _grid_tasks(a, names))
    if doc is None:
        raise SystemExit(f"{a.out}: no results store ({bench.core.STORE}); run the grid stage first")
    for n, x in doc["scenes"].items():
        log(f"{n}: {x['runs']} of {x['tasks']} runs, complete {x['complete']}")


def grid(a, names):
    factors = [float(f) for f in (a.dts or "8,4,2,1,0.5,0.25").split(",")]
    with open_executor(a.scheduler) as ex:
        expected = {}
        for name in names:
            sc = scenes.get(name)
            dts = [sc.dt * f for f in factors]
            expected[name] = [t for t in bench.build_tasks(sc, a.t_final, dts=dts, repeats=a.repeats)
                              if _grid_select(t, a.methods)]
            try:
                rows = bench.work_precision(sc, a.t_final, a.out, ex, log=log, dts=dts,
                                            select=lambda t: _grid_select(t, a.methods),
                                            repeats=a.repeats, plots=not a.no_plots)
            except KeyboardInterrupt:
                bench.write_summary(a.out, expected)
                log(f"{name}: interrupted; what finished is in results.sqlite and summary.json")
                raise SystemExit(130) from None
            bench.write_summary(a.out, expected)
            log(f"{name}: " + bench.summary(rows).replace("\n", "; "))


def _cell(r):
    if r is None:
        return "none in the grid"
    p = f"dt={r['dt']:.3g}" if r.get("dt") else f"rtol={r['rtol']:.0e}"
    k = "" if r.get("gain") is None else f", k={r['gain']:g}"
    if r["method"] == "FI" and r.get("gain") is None:
        k = ", scene's gains"
    if r["method"] == bench.RTOL_METHOD:
        p = f"rtol={r['rtol']:.0e}, dt={r['dt']:.3g}"
    err = r.get("max_error")
    err = "" if err is None else f", error {err:.0e}"
    return f"{r['method']} {r['scheme']} ({p}{k}): {r['cpu_seconds']:.2g} s, drift {r['max_drift']:.0e}{err}"


def long(a, names):
    path = os.path.join(a.out, f"long-{a.t_final:g}.sqlite")
    res_path = os.path.join(a.out, "crossover.json")
    allres = json.load(open(res_path)) if os.path.exists(res_path) else {}
    factors = [float(f) for f in (a.dts or "8,4").split(",")]
    with open_executor(a.scheduler) as ex, ResultStore(path) as store:
        for name in names:
            sc = scenes.get(name)
            gains = tuple(None if g == "scene" else float(g) for g in a.gains.split(","))
            tasks = bench.horizon_tasks(sc, a.t_final, dts=[sc.dt * f for f in factors], n_save=a.n_save,
                                        gains=gains, schemes=tuple(a.schemes.split(",")))
            if a.methods:
                tasks = [t for t in tasks if t["method"] in a.methods.split(",")]
            log(f"{name}: {len(tasks)} runs to t = {a.t_final:g}")
            store.sweep = name
            vals = run_sweep(bench.run_task, tasks, ex, store=store, convert=bench.horizon_row, label=name)
            # every long run of this scene in every store of this folder (other steps and horizons too)
            rows = []
            for other in sorted(os.listdir(a.out)):
                if other.startswith("long-") and other.endswith(".sqlite"):
                    with ResultStore(os.path.join(a.out, other)) as o:
                        rows += [v for t, v in o.rows(name) if not isinstance(v, TaskError)]
            res = {}
            for crit, err in (("drift", None), ("drift+error", 1e-6)):
                c = bench.crossover(rows, drift=1e-10, error=err if err else math.inf)
                res[crit] = {"crossover": c["crossover"],
                             "fi_best": {f"{h:g}": v for h, v in c["fi_best"].items()},
                             "other_best": {f"{h:g}": v for h, v in c["other_best"].items()}}
                if crit == "drift+error" or sc.reference != "exact":
                    curves = c["curves"]
            res["error_measured"] = sc.reference == "exact"
            res["errors"] = [str(v) for v in vals if isinstance(v, TaskError)]
            allres[name] = res
            with open(res_path, "w") as fh:
                json.dump(allres, fh, indent=1)
            bench.plot_cost_vs_horizon(curves, os.path.join(a.out, f"{name}-cost-horizon.png"), name)
            log(f"{name}: crossover {res['drift+error']['crossover']} (drift only: {res['drift']['crossover']})")


def _ratio(r, reason=None):
    return f"null ({reason})" if r is None and reason else "-" if r is None else f"{r:.2f}"


def _verdict(v, ratio, noise):
    if v is None:
        return "-"
    if ratio is None:
        return v
    return f"{v} ({ratio:.2f}, noise {100 * noise:.2g} %)"


def _summaries(a, names):
    """Per scene the verdict recomputed from its CSV (:func:`liefi.bench.summarize`: both criteria), and
    the same without the ``FI-rtol`` rows (key ``without_rtol``)."""
    out = {}
    for n in names:
        p = os.path.join(a.out, f"{n}-work-precision.csv")
        if os.path.exists(p):
            rows = bench.read_csv(p)
            out[n] = bench.summarize(rows)
            out[n]["without_rtol"] = bench.summarize([r for r in rows if r["method"] != bench.RTOL_METHOD])
    return out


def tables(a, names):
    s = _summaries(a, names)
    # the verdict columns only where the timings were repeated, "without FI-rtol" only where there are FI-rtol rows
    timed = any(x["scene_noise"] is not None for x in s.values())
    rtol = any(x["rtol_vs_best"] for x in s.values())
    head = ["scene", "fi_over_best (drift <= 1e-8)"] + (["verdict (FI/other, noise)"] if timed else []) + \
        ["fi_over_best_accurate (error <= 1e-6, drift <= 1e-8)"] + (["verdict (FI/other, noise)"] if timed else []) + \
        (["fi_over_best_accurate without FI-rtol"] if rtol else []) + ["cheapest accurate run", "cheapest accurate FI"]
    print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    for n in names:
        if n in s:
            x, w = s[n], s[n]["without_rtol"]
            wo = _ratio(w["fi_over_best_accurate"], w["fi_over_best_accurate_reason"])
            if w["verdict_accurate"] is not None:
                wo += f", {_verdict(w['verdict_accurate'], w['fi_over_other_accurate'], w['noise_accurate'])}"
            cells = [n, _ratio(x["fi_over_best"], x["fi_over_best_reason"])]
            cells += [_verdict(x["verdict"], x["fi_over_other"], x["noise"])] if timed else []
            cells += [_ratio(x["fi_over_best_accurate"], x["fi_over_best_accurate_reason"])]
            cells += [_verdict(x["verdict_accurate"], x["fi_over_other_accurate"], x["noise_accurate"])] if timed else []
            cells += [wo] if rtol else []
            cells += [_cell(x["cheapest_accurate"]), _cell(x["cheapest_fi_accurate"])]
            print("| " + " | ".join(cells) + " |")
    if any(x["rtol_vs_best"] for x in s.values()):
        print("\n| scene | rtol | dt chosen | error | error / rtol | CPU (s) | cheapest grid run at that error | "
              "CPU / cheapest | CPU / cheapest with drift <= 1e-8 | (CPU + setup) / cheapest |\n"
              "|---|---|---|---|---|---|---|---|---|---|")
        for n in names:
            for e in s.get(n, {}).get("rtol_vs_best", ()):
                if e["status"] != "ok":
                    print(f"| {n} | {e['rtol']:.0e} | {e['status']} | | | | | | | |")
                    continue
                f = lambda v, spec: "-" if v is None else format(v, spec)  # noqa: E731
                print(f"| {n} | {e['rtol']:.0e} | {f(e['dt'], '.3g')} | {f(e['max_error'], '.1e')} | "
                      f"{f(e['error_over_rtol'], '.2g')} | {f(e['cpu_seconds'], '.2g')} | "
                      f"{_cell(e['cheapest_at_error']) if e['cheapest_at_error'] else '-'} | "
                      f"{f(e['cpu_over_cheapest'], '.2f')} | {f(e['cpu_over_cheapest_kept'], '.2f')} | "
                      f"{f(e['total_over_cheapest'], '.1f')} |")
    p = os.path.join(a.out, "crossover.json")
    if os.path.exists(p):
        c = json.load(open(p))
        print("\n| scene | crossover H (drift <= 1e-10, rel. error <= 1e-6) | crossover H (drift only) "
              "| at the longest H where a method qualifies: cheapest FI | cheapest other |\n|---|---|---|---|---|")
        for n in names:
            if n not in c:
                continue
            x = c[n]["drift+error"]
            hs = sorted(set(x["fi_best"]) | set(x["other_best"]), key=float)
            last = hs[-1] if hs else None
            fi = x["fi_best"].get(last) if last else None
            ot = x["other_best"].get(last) if last else None
            f = lambda v: "none" if v is None else f"{v[0]}: {v[1]:.2g} s"  # noqa: E731
            cr = lambda v: "never" if v is None else f"{v:g}"  # noqa: E731
            err = "" if c[n]["error_measured"] else " (error not measured)"
            print(f"| {n} | {cr(x['crossover'])}{err} | {cr(c[n]['drift']['crossover'])} | H={last}: {f(fi)} "
                  f"| {f(ot)} |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stage", choices=("grid", "long", "tables", "summary"))
    ap.add_argument("--out", default=OUT)
    ap.add_argument("--only", default=None, help="comma-separated scene names")
    ap.add_argument("--t-final", type=float, default=None, dest="t_final")
    ap.add_argument("--dts", default=None, help="steps as multiples of the scene's dt (grid: 8,4,2,1,0.5,0.25; "
                    "long: 8,4)")
    ap.add_argument("--repeats", type=int, default=bench.REPEATS,
                    help=f"grid: timed runs per task, the least CPU time kept (default {bench.REPEATS})")
    ap.add_argument("--gains", default="0.1,1", help="long: fixed FI gains ('scene': the scene's)")
    ap.add_argument("--methods", default=None, help="only these families, comma-separated (long: FI,no-feedback,projection; grid and "
                    "summary: any of liefi.bench.METHODS, e.g. every one but FI-rtol)")
    ap.add_argument("--schemes", default="rk4,imex-rk4", help="long: the fixed-step schemes (default rk4,imex-rk4)")
    ap.add_argument("--no-plots", action="store_true", dest="no_plots", help="grid: the CSVs and stores only")
    ap.add_argument("--n-save", type=int, default=10000, dest="n_save")
    ap.add_argument("--scheduler", default="processes:2")
    a = ap.parse_args(argv)
    warnings.filterwarnings("ignore")
    names = a.only.split(",") if a.only else scenes.names()
    os.makedirs(a.out, exist_ok=True)
    if a.t_final is None:
        a.t_final = 1e5 if a.stage == "long" else 1e3
    {"grid": grid, "long": long, "tables": tables, "summary": summary}[a.stage](a, names)
    return 0


if __name__ == "__main__":
    sys.exit(main())
