"""Generate the work-precision CSVs, diagrams and summary used by ``docs/work_precision.md``.

Run::

    python benchmarks/make_docs.py                        # every scene, t = 1e3, long horizon 1e4
    python benchmarks/make_docs.py --only suslov --t-final 100 --long-horizon 0

Writes into ``docs/work_precision/`` (``--out``): per scene
``<scene>-work-precision.csv``, ``<scene>-error.png``, ``<scene>-drift.png``,
``<scene>-long-horizon.csv`` and ``<scene>-long-horizon.png`` (the curves behind
it go to ``--curves``, outside the docs); and
``summary.json`` / ``summary.md``: per scene, the cheapest run whose every
invariant drifts by at most 1e-8 over ``[0, t_final]``, the cheapest feedback
integrator run that does, and the feedback integrator at the paper's settings.
The grid runs on a process pool (``--scheduler``, see :mod:`liefi.sweep`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from liefi import bench, scenes  # noqa: E402
from liefi.sweep import open_executor  # noqa: E402


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _brief(r):
    if r is None:
        return None
    keys = ("method", "scheme", "dt", "rtol", "cpu_seconds", "rhs_evaluations", "max_error", "max_drift")
    return {k: r.get(k) for k in keys}


def summarize(name, rows, long_rows, drift=1e-8):
    sc = scenes.get(name)
    paper = [r for r in rows if r["method"] == "FI" and r["scheme"] == sc.scheme and r["dt"]
             and abs(r["dt"] - sc.dt) < 1e-12 * sc.dt]
    out = {
        "scene": name,
        "t_final": rows[0]["t_final"],
        "runs": len(rows),
        "failed": sum(r["status"] != "ok" for r in rows),
        "cheapest": _brief(bench.cheapest(rows, drift=drift)),
        "cheapest_fi": _brief(bench.cheapest(rows, drift=drift, methods=("FI",))),
        "cheapest_fi_any": _brief(bench.cheapest(rows, drift=drift, methods=("FI", "FI-tuned", "FI/solve_ivp"))),
        "cheapest_fi_tuned": _brief(bench.cheapest(rows, drift=drift, methods=("FI-tuned",))),
        "cheapest_accurate": _brief(bench.cheapest(rows, drift=drift, error=1e-6)),
        "cheapest_fi_accurate": _brief(bench.cheapest(rows, drift=drift, error=1e-6,
                                                      methods=("FI", "FI-tuned", "FI/solve_ivp"))),
        "fi_paper": _brief(paper[0]) if paper else None,
        "cheapest_by_method": {m: _brief(bench.cheapest(rows, drift=drift, methods=(m,))) for m in bench.METHODS},
        "long_horizon": [_brief(r) | {"status": r["status"], "t_final": r["t_final"]} for r in long_rows],
    }
    return out


def _cell(r):
    if r is None:
        return "none in the grid", "-"
    p = f"dt={r['dt']:.3g}" if r.get("dt") else f"rtol={r['rtol']:.0e}"
    err = "" if r.get("max_error") is None else f", err {r['max_error']:.0e}"
    return f"{r['method']} {r['scheme']} {p} (drift {r['max_drift']:.0e}{err})", f"{r['cpu_seconds']:.2g}"


def tables(summary, names):
    """Markdown tables of the summaries (the ones quoted in docs/work_precision.md)."""
    T = next((s["t_final"] for s in summary.values()), 0)
    out = [f"Every invariant's drift <= 1e-8 over [0, {T:g}]: the cheapest run (CPU seconds), over all methods and "
           "over the feedback integrator's rows.", "",
           "| scene | cheapest of all | CPU s | cheapest FI (paper's gains) | CPU s | cheapest FI-tuned | CPU s "
           "| FI at the paper's settings | CPU s |",
           "|---|---|---|---|---|---|---|---|---|"]
    for name in names:
        s = summary.get(name)
        if s:
            c = [_cell(s.get(k)) for k in ("cheapest", "cheapest_fi", "cheapest_fi_tuned", "fi_paper")]
            out.append(f"| {name} | " + " | ".join(f"{a} | {b}" for a, b in c) + " |")
    out += ["", "The same with the error against the reference also <= 1e-6:", "",
            "| scene | cheapest of all | CPU s | cheapest feedback integrator (any) | CPU s |", "|---|---|---|---|---|"]
    for name in names:
        s = summary.get(name)
        if s:
            c = [_cell(s.get(k)) for k in ("cheapest_accurate", "cheapest_fi_accurate")]
            out.append(f"| {name} | " + " | ".join(f"{a} | {b}" for a, b in c) + " |")
    return out


def _fmt(r):
    if r is None:
        return "none in the grid"
    p = f"dt = {r['dt']:.3g}" if r.get("dt") else f"rtol = {r['rtol']:.0e}"
    return f"{r['method']} {r['scheme']} ({p}): {r['cpu_seconds']:.3g} s, drift {r['max_drift']:.1e}, error {r['max_error']:.1e}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.join(os.path.dirname(HERE), "docs", "work_precision"))
    ap.add_argument("--only", default=None, help="comma-separated scene names")
    ap.add_argument("--t-final", type=float, default=1e3, dest="t_final")
    ap.add_argument("--long-horizon", type=float, default=1e4, dest="long_horizon")
    ap.add_argument("--long-n-save", type=int, default=20000, dest="long_n_save",
                    help="saved points of each long-horizon run (drifts are measured there)")
    ap.add_argument("--curves", default=os.path.join(os.path.expanduser("~"), ".cache", "liefi", "docs-curves"),
                    help="where the long-horizon curves (.npz, for --replot) go; kept out of the docs")
    ap.add_argument("--scheduler", default="processes:2")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--resume", action="store_true",
                    help="reuse a scene's work-precision CSV when it exists (and its long-horizon files)")
    ap.add_argument("--replot", action="store_true", help="only redraw every PNG from the CSV/NPZ files")
    ap.add_argument("--tables", action="store_true", help="only print the tables of summary.json")
    ap.add_argument("--redo-long", action="store_true", dest="redo_long",
                    help="with --resume: recompute the long horizon even when its files exist")
    ap.add_argument("--add-methods", default=None, dest="add_methods", metavar="M[,M]",
                    help="run only these method families and merge them into the existing CSVs "
                         "(then redo the long horizon unless --long-horizon 0)")
    a = ap.parse_args(argv)
    warnings.filterwarnings("ignore")
    names = a.only.split(",") if a.only else scenes.names()
    os.makedirs(a.out, exist_ok=True)
    path = os.path.join(a.out, "summary.json")
    summary = json.load(open(path)) if os.path.exists(path) else {}
    if a.tables:
        print("\n".join(tables(summary, [n for n in names if n in summary])))
        return 0
    if a.replot:
        for name in names:
            csv_path = os.path.join(a.out, f"{name}-work-precision.csv")
            if os.path.exists(csv_path):
                bench.plot(bench.read_csv(csv_path), a.out, name)
            npz = os.path.join(a.curves, f"{name}-long-horizon.npz")
            if os.path.exists(npz):
                curves = bench.load_curves(npz)
                T = max(float(t[-1]) for t, *_ in curves.values())
                bench.plot_long_horizon(curves, os.path.join(a.out, f"{name}-long-horizon.png"), name, T)
            log(f"{name}: replotted")
        return 0
    with open_executor(a.scheduler) as ex:
        for name in names:
            try:
                csv_path = os.path.join(a.out, f"{name}-work-precision.csv")
                lh_path = os.path.join(a.out, f"{name}-long-horizon.csv")
                if a.add_methods and os.path.exists(csv_path):
                    old = bench.read_csv(csv_path)
                    have = {r["method"] for r in old}
                    add = [m for m in a.add_methods.split(",")
                           if m in bench.applicable_methods(scenes.get(name)) and m not in have]
                    new = bench.work_precision(name, old[0]["t_final"], None, ex, methods=add, log=log) if add else []
                    order = {m: i for i, m in enumerate(bench.METHODS)}
                    rows = sorted(old + new, key=lambda r: order.get(r["method"], 99))
                    if new:
                        bench.write_csv(rows, csv_path)
                    bench.plot(rows, a.out, name)
                elif a.resume and os.path.exists(csv_path):
                    rows = bench.read_csv(csv_path)
                    log(f"{name}: reusing {csv_path}")
                else:
                    rows = bench.work_precision(name, a.t_final, a.out, ex, quick=a.quick, log=log)
                long_rows = []
                if (a.long_horizon and a.resume and not a.redo_long and os.path.exists(lh_path)
                        and os.path.exists(os.path.join(a.curves, f"{name}-long-horizon.npz"))):
                    long_rows = bench.read_csv(lh_path)
                elif a.long_horizon:
                    long_rows, _ = bench.long_horizon(rows, a.out, ex, t_final=a.long_horizon,
                                                      n_save=a.long_n_save, curves_dir=a.curves, log=log)
                summary[name] = summarize(name, rows, long_rows)
                with open(path, "w") as fh:
                    json.dump(summary, fh, indent=1, default=float)
                log(f"{name}: cheapest drift <= 1e-8: {_fmt(summary[name]['cheapest'])}")
                log(f"{name}: FI: {_fmt(summary[name]['cheapest_fi'])}")
            except Exception:  # noqa: BLE001 -- keep going with the other scenes
                log(f"{name}: FAILED\n{traceback.format_exc()}")
    lines = tables(summary, names)
    with open(os.path.join(a.out, "summary.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
