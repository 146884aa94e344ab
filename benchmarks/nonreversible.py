"""Long-time comparison on the non-reversible test problems (``docs/nonreversible.md``).

Run from the repository root::

    python benchmarks/nonreversible.py                       # t = 1e4, every scene below
    python benchmarks/nonreversible.py --t-final 1e3 --quick # a smoke test
    python benchmarks/nonreversible.py --scenes nonreversible-oscillator
    python benchmarks/nonreversible.py --long --t-final 1e5   # RK4 runs only, to t = 1e5

For each scene -- the ``nonreversible-*`` scenes and, as baselines, the paper's
reversible ``oscillator`` and ``knife-edge`` (the same motions as
``nonreversible-oscillator`` and ``nonreversible-knife-edge`` in unshifted
momenta) -- it runs, from the scene's start to ``t_final``:

=====================  ==================================================================
``FI``                 the feedback integrator, RK4 at ``dt`` and explicit Euler at
                       ``dt/4`` (the same number of field evaluations), with the
                       scene's gains, the small gains 0.1 and 1, and the gains
                       :func:`liefi.gains.auto_gains` picks for the step and
                       scheme (the harness's ``FI-tuned``); and at the paper's
                       settings of the reversible problem (Euler, ``dt = 1e-3``,
                       gains 300 to 1000: 2.5 times the cost); compiled,
                       as ``FeedbackIntegrator.run(backend="auto")`` runs it
``no-feedback``        the extended field alone (plain RK4 at ``dt``)
``projection``         the constrained equations with RK4 at ``dt``, each step projected
                       (Newton) onto the set where ``J``, ``h`` and the scene's other
                       invariants keep their initial values
``constrained``        the constrained equations with ``solve_ivp``'s LSODA at ``rtol``
``DLA``                the first-order discrete Lagrange--d'Alembert scheme at ``dt/4``,
                       where :mod:`liefi.dla` applies
=====================  ==================================================================

The peers are run by :func:`liefi.bench.run_task` (the work-precision harness's
own runner, compiled fields) and every drift is measured by
:func:`liefi.bench.invariant_drifts`: ``|I(t) - I(0)|`` for each first integral,
``|J_i(t)|`` for the constraint momenta, at ``n_save`` points uniform in time.

Writes into ``--out`` (default ``docs/nonreversible``):

* ``drifts.csv``: one row per run -- scene, method, scheme, ``dt`` or ``rtol``,
  gains, CPU seconds (process time of the integration loop), field evaluations,
  and for each invariant its drift at the final time (``final_<I>``) and its max
  over the run (``max_<I>``);
* ``curves.csv``: each run's drift of each invariant against time at ~120
  log-spaced times;
* ``<scene>.png``: drift against time, one panel per invariant, one line per run.

Nothing is asserted: the numbers are the result.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from liefi import bench, engine, scenes  # noqa: E402
from liefi.gains import auto_gains  # noqa: E402
from liefi.schemes import IntegrationError  # noqa: E402

SCENES = ("oscillator", "nonreversible-oscillator", "nonreversible-contact-oscillator", "knife-edge",
          "nonreversible-knife-edge")
DT = 1e-2  # RK4 step of every fixed-step run; Euler and DLA take DT/4 (same field evaluations)
SMALL_GAINS = (0.1, 1.0)
#: the reversible twin of each non-reversible scene (same motion, unshifted momenta)
TWIN = {"nonreversible-oscillator": "oscillator", "nonreversible-contact-oscillator": "oscillator",
        "nonreversible-knife-edge": "knife-edge"}
LSODA_RTOL = 1e-9


def runs(sc, quick=False, long=False):
    """The list of runs ``(method, scheme, dt, rtol, gains)`` of one scene (``long``: the RK4 runs only)."""
    if long:
        return [("FI", "rk4", DT, None, g) for g in SMALL_GAINS] + [
            ("no-feedback", "rk4", DT, None, None), ("projection", "rk4", DT, None, None)]
    gains = [g for g in (sc.gains, *SMALL_GAINS) if not isinstance(g, dict)]
    gains = ([sc.gains] if isinstance(sc.gains, dict) else []) + sorted(set(gains), key=float) + ["auto"]
    out = []
    for g in gains:
        out.append(("FI", "rk4", DT, None, g))
    for g in gains:
        out.append(("FI", "euler", DT / 4, None, g))
    paper = scenes.get(TWIN.get(sc.name, sc.name))
    if (paper.scheme, paper.dt) not in (("rk4", DT), ("euler", DT / 4)):
        # the paper's settings (of the reversible twin): Euler, dt = 1e-3, gains 300 to 1000
        out.append(("FI", paper.scheme, paper.dt, None, paper.gains))
    out.append(("no-feedback", "rk4", DT, None, None))
    out.append(("projection", "rk4", DT, None, None))
    out.append(("constrained", "LSODA", None, LSODA_RTOL, None))
    if "DLA" in bench.applicable_methods(sc):
        out.append(("DLA", "dla", DT / 4, None, None))
    if quick:
        out = [r for r in out if r[4] in (None, 1.0) or r[0] != "FI"]
    return out


def _gains_label(g):
    if g is None:
        return ""
    if isinstance(g, dict):
        return "scene (" + ", ".join(f"{k}={v:g}" for k, v in g.items()) + ")"
    if isinstance(g, str):
        return g
    return f"{g:g}"


def _short(g):
    return "scene" if isinstance(g, dict) else _gains_label(g)


def run_fi(sc, v, scheme, dt, T, gains, n_save):
    """The feedback integrator with ``gains``, compiled as :func:`liefi.bench.run_task` runs it
    (compilation and, for ``"auto"``, the choice of the gains not counted in ``cpu_seconds``)."""
    out = dict(status="ok", message="", t=None, y=None, cpu_seconds=math.nan, rhs_evaluations=0)
    try:
        fi = sc.integrator(v, gains=1.0 if gains == "auto" else gains)
        if gains == "auto":
            fi = fi.with_gains(auto_gains(fi, dt, scheme, y=fi.y0, t_final=T))
        n = int(round(T / dt))
        cf = engine.compile_feedback(fi)
        cf.warmup(scheme)
        sol = cf.run(fi.y0, engine.parameters(fi), dt, n, scheme, save_every=max(1, n // n_save), names=fi.names)
        out.update(t=sol.t, y=sol.y, cpu_seconds=sol.cpu_seconds, rhs_evaluations=sol.rhs_evaluations)
        if gains == "auto":
            out["message"] = "gains " + ", ".join(f"{k}={x:.3g}" for k, x in fi.gains.items())
    except (IntegrationError, FloatingPointError, ValueError) as exc:
        out.update(status="diverged", message=f"{type(exc).__name__}: " + " ".join(str(exc).split())[:200])
    return out


def run_peer(sc, v, method, scheme, dt, rtol, T, n_save):
    task = dict(scene=sc.name, variant=v.name, method=method, scheme=scheme, dt=dt, rtol=rtol,
                t_final=float(T), configuration=True, n_save=int(n_save))
    return bench.run_task(task)


def log_samples(t, k=120):
    """Indices of ~k log-spaced times of ``t`` (t[0] = 0 excluded)."""
    if len(t) < 3:
        return np.arange(len(t))
    targets = np.geomspace(t[1], t[-1], k)
    idx = np.unique(np.clip(np.searchsorted(t, targets), 1, len(t) - 1))
    return idx


def study(names, T, out_dir, n_save=2000, quick=False, long=False, log=print):
    os.makedirs(out_dir, exist_ok=True)
    rows, curves = [], []
    for name in names:
        sc = scenes.get(name)
        v = sc.variant()
        fi_ref = sc.integrator(v)  # the invariants monitored (names, values) -- gains play no part
        for method, scheme, dt, rtol, gains in runs(sc, quick, long):
            w = time.perf_counter()
            if method == "FI":
                r = run_fi(sc, v, scheme, dt, T, gains, n_save)
            else:
                r = run_peer(sc, v, method, scheme, dt, rtol, T, n_save)
            row = dict(scene=name, method=method, scheme=scheme, dt=dt, rtol=rtol, gains=_gains_label(gains),
                       gains_value=gains,
                       t_final=T, status=r["status"], cpu_seconds=r["cpu_seconds"],
                       rhs_evaluations=r["rhs_evaluations"], message=r.get("message", ""))
            if r.get("y") is not None:
                Y = np.asarray(r["y"])
                d = bench.invariant_drifts(fi_ref, Y)
                for k, val in d.items():
                    row[f"final_{k}"] = float(val[-1])
                    row[f"max_{k}"] = float(np.max(val))
                if not all(np.all(np.isfinite(val)) for val in d.values()):
                    row["status"] = "diverged"
                t = np.asarray(r["t"], float)
                idx = log_samples(t)
                step = f"dt={dt:g}" if dt else f"rtol={rtol:g}"
                label = f"{method} {scheme} {step}" + (f" k={_short(gains)}" if method == "FI" else "")
                for i in idx:
                    curves.append(dict(scene=name, run=label, t=float(t[i]),
                                       **{k: float(val[i]) for k, val in d.items()}))
            rows.append(row)
            fin = {k[6:]: row[k] for k in row if k.startswith("final_")}
            log(f"{name:34s} {method:12s} {scheme:6s} {_gains_label(gains):28s} {row['status']:8s} "
                f"cpu {row['cpu_seconds']:.3g} s, wall {time.perf_counter() - w:.1f} s  "
                + " ".join(f"{k}={x:.1e}" for k, x in fin.items()))
    sfx = "-long" if long else ""
    _write(rows, os.path.join(out_dir, f"drifts{sfx}.csv"))
    with open(os.path.join(out_dir, f"table{sfx}.md"), "w") as fh:
        fh.write(markdown_table(rows))
    _write(curves, os.path.join(out_dir, f"curves{sfx}.csv"))
    for name in names:
        plot_scene([c for c in curves if c["scene"] == name], name, T, os.path.join(out_dir, f"{name}{sfx}.png"))
    return rows, curves


def markdown_table(rows):
    """Per scene, the drift of each first integral at the final time (and its max over the run)."""
    out = []
    for name in dict.fromkeys(r["scene"] for r in rows):
        rs = [r for r in rows if r["scene"] == name]
        invs = list(dict.fromkeys(k[6:] for r in rs for k in r if k.startswith("final_") and k != "final_h~"))
        T = rs[0]["t_final"]
        out.append(f"**{name}** (t = {T:g}; each cell: drift at t = {T:g} / max over [0, {T:g}])\n")
        out.append("| method | scheme | dt or rtol | gains | CPU s | " + " | ".join(invs) + " |")
        out.append("|" + "---|" * (5 + len(invs)))
        for r in rs:
            step = f"{r['dt']:g}" if r["dt"] else f"rtol {r['rtol']:g}"
            if r["status"] != "ok" or f"final_{invs[0]}" not in r:
                cells = [r["status"]] * len(invs)
            else:
                cells = [f"{r[f'final_{k}']:.1e} / {r[f'max_{k}']:.1e}" for k in invs]
            cpu = f"{r['cpu_seconds']:.2g}" if np.isfinite(r["cpu_seconds"]) else "-"
            out.append(f"| {r['method']} | {r['scheme']} | {step} | {_short(r['gains_value'])} | {cpu} | "
                       + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out) + "\n"


def _write(rows, path):
    cols = []
    for r in rows:
        for k in r:
            if k not in cols and k != "gains_value":
                cols.append(k)
    if "message" in cols:
        cols.remove("message")
        cols.append("message")
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else (f"{r[k]:.4g}" if isinstance(r.get(k), float) else r[k]))
                        for k in cols})


_COLOR = {"FI rk4": "C3", "FI euler": "C1", "FI paper": "C5", "no-feedback": "C7", "projection": "C2",
          "constrained": "C0", "DLA": "C4"}
_STYLE = {"0.1": ":", "1": "--", "auto": "-."}


def plot_scene(curves, name, T, path):
    from liefi.results.scene_figures import finish_panel_grid, panel_grid

    if not curves:
        return None
    invs = [k for k in curves[0] if k not in ("scene", "run", "t")]
    fig, axes = panel_grid(len(invs), ncols=2, width=6.2, height=3.8, legend_width=2.8)
    labels = list(dict.fromkeys(c["run"] for c in curves))
    for ax, k in zip(axes, invs):
        for lab in labels:
            pts = [(c["t"], c[k]) for c in curves if c["run"] == lab and k in c]
            if not pts:
                continue
            t, d = np.array(pts).T
            base = " ".join(lab.split()[:2]) if lab.startswith("FI") else lab.split()[0]
            gain = lab.split("k=")[-1] if "k=" in lab else ""
            if base == "FI euler" and "dt=0.001" in lab:
                base = "FI paper"
            ax.loglog(t, np.maximum(d, 1e-17), color=_COLOR.get(base, "k"), ls=_STYLE.get(gain, "-"), lw=1.0,
                      label=lab)
        ax.set_title(f"|{k}(t) - {k}(0)|" if not k.startswith("J_") else f"|{k}(t)|", fontsize=9)
        ax.set_xlabel("t", fontsize=8)
        ax.grid(True, alpha=0.3)
    return finish_panel_grid(fig, axes, f"{name}: drift of each first integral vs time, t in [0, {T:g}] "
                             "(exact zeros drawn at 1e-17)", path)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--t-final", type=float, default=1e4, dest="t_final")
    p.add_argument("--out", default=os.path.join(os.path.dirname(HERE), "docs", "nonreversible"))
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--n-save", type=int, default=2000, dest="n_save")
    p.add_argument("--quick", action="store_true", help="gains 1 only for the FI")
    p.add_argument("--long", action="store_true",
                   help="only FI RK4 (gains 0.1, 1), plain and projected RK4; files *-long.* (for t = 1e5)")
    a = p.parse_args(argv)
    names = [s.strip() for s in a.scenes.split(",") if s.strip()]
    study(names, a.t_final, a.out, n_save=a.n_save, quick=a.quick, long=a.long,
          log=lambda m: print(m, file=sys.stderr, flush=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
