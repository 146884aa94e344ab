"""Bae & Chang's free rigid body benchmark, run by liefi against a Lie--Poisson splitting and projected RK4.

Run (from the repository root; numba required, a few minutes on one core)::

    python benchmarks/rigid_body.py                        # h = 1e-1 ... 1e-4, t in [0, 1000]
    python benchmarks/rigid_body.py --hs 1e-1 1e-2 --t-final 100 --out /tmp/rb   # a smoke test

Scene ``rigid-body`` (:mod:`liefi.scenes.rigid_body`): I = diag(3, 2, 1), R0 = I,
Omega0 = (1, 1, 1), their gains k0 = 50 (penalty), k1 = 100 (energy), k2 = 50
(here on the Casimir |Pi|^2/2).  Methods, per step h:

* ``FI-Euler B&C optimal``: Euler, gains ``k / (h L0)`` -- Bae & Chang's optimal
  fixed gain ``alpha = 1/(h L0)``, ``L0`` the largest Frobenius norm of ``Hess V``
  (at their gains) along the reference motion (a Lipschitz constant of ``grad V``;
  their code uses the constant 1986 for their coordinates);
* ``FI-Euler B&C adaptive``: Euler, ``alpha = 1/(h * 1.1 * ||Hess V(y)||_F)``
  re-estimated every 30 time units (their periodic Hessian-based rule and
  constants);
* ``FI-Euler accurate`` and ``FI-RK4 accurate``: :func:`liefi.gains.accurate_gains`;
* ``FI-imex-RK4 accurate``: the split scheme ``imex-rk4`` (RK4 on the free field, then the
  linearly implicit feedback substep, :mod:`liefi.schemes.split`) with the gains
  ``gains="auto"`` takes for it (the rate ``1/sqrt(u)``: a Gauss--Newton step onto the invariant set);
* ``FI-RK4 auto-1.6``: :func:`liefi.gains.auto_gains` (``dt lambda_max = 1.6``),
  the automatic gains before :mod:`liefi.gains`;
* ``RK4``: no feedback;
* ``projected RK4``: RK4 and a Newton projection onto ``{R^T R = I, h = h0, C = C0}``
  after every step (liefi's compiled projection);
* ``splitting``: the symmetric Lie--Poisson splitting into three exact free
  rotations (McLachlan 1993; Touma & Wisdom 1994; Reich 1993) -- the peer's
  "Strang splitting", the symplectic baseline of their rigid body figure.

Reference: DOP853 (rtol = atol = 1e-13) on the compiled free field; its
distance to RK4 at ``h_ref`` (default 1e-4) is printed and stored as the
floor of the state errors (rounding over 1e7 steps).  Errors are maxima over 1000 uniform points in
time: energy ``|E - E0|``, Casimir ``| |Pi| - |Pi0| |``, ``||R^T R - I||_F``,
the spatial momentum ``|R Pi - R0 Pi0|``, the state ``max |y - y_ref|`` over R
and Pi, Bae & Chang's own figure of merit
``V_BC = k0/4 ||R^T R - I||^2 + k1/2 (E - E0)^2 + k2/2 |R Pi - R0 Pi0|^2`` and
``V_inv``, the same with ``(|Pi| - |Pi0|)^2`` for the last term (what liefi's
``V`` penalizes).  Steps ``--small-hs`` (default 1e-6) run the Euler feedback
integrators and the splitting only (the others take minutes there).
CPU: process time of the compiled loop (compilation excluded).  Writes
``OUT/rigid_body.csv``, ``OUT/rigid_body.json`` and ``OUT/rigid_body.png``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from liefi import engine, scenes  # noqa: E402
from liefi.gains import accurate_gains, auto_gains  # noqa: E402
from liefi.scenes.rigid_body import splitting  # noqa: E402
from liefi.stability import stiffness  # noqa: E402

K_BC = (50.0, 100.0, 50.0)  # Bae & Chang's k0 (penalty), k1 (energy), k2 (momentum)
PERIOD = 30.0  # their update period of the adaptive gain (time units)
SAFETY = 1.1  # their factor on the Lipschitz estimate


def hess_frobenius(fi, Y):
    """``||Hess V||_F`` at states ``Y`` (``(..., n)``), by central differences of ``grad V``."""
    ev = stiffness(fi, Y, exact=True).eigenvalues
    return np.sqrt(np.sum(np.abs(ev) ** 2, axis=-1))


def metrics(sc, fi, Y, Yref):
    """Errors of a run ``Y`` (``(12, n_t)``) against the reference ``Yref``."""
    Yt = Y.T
    R = Yt[:, :9].reshape(-1, 3, 3)
    Pi = Yt[:, 9:]
    I = sc.inertia
    E = 0.5 * np.sum(Pi**2 / I, -1)
    y0 = fi.y0
    E0 = 0.5 * np.sum(y0[9:] ** 2 / I)
    C = np.linalg.norm(Pi, axis=-1)
    C0 = np.linalg.norm(y0[9:])
    orth = np.linalg.norm(np.swapaxes(R, -1, -2) @ R - np.eye(3), axis=(-2, -1))
    m = np.einsum("tij,tj->ti", R, Pi)
    m0 = y0[:9].reshape(3, 3) @ y0[9:]
    k0, k1, k2 = K_BC
    dm = np.sum((m - m0) ** 2, -1)
    V = k0 / 4 * orth**2 + k1 / 2 * (E - E0) ** 2 + k2 / 2 * dm
    Vi = k0 / 4 * orth**2 + k1 / 2 * (E - E0) ** 2 + k2 / 2 * (C - C0) ** 2
    return {
        "energy": float(np.max(np.abs(E - E0))),
        "casimir": float(np.max(np.abs(C - C0))),
        "orthogonality": float(np.max(orth)),
        "momentum": float(np.sqrt(np.max(dm))),
        "state": float(np.max(np.abs(Y - Yref))),
        "V_BC": float(np.max(V)),
        "V_inv": float(np.max(Vi)),
    }


def run_fi(fi, gains, h, n, se, scheme, cache):
    """One compiled FI run with fixed gains; returns ``(Y, cpu, rhs)``."""
    split = scheme.startswith("imex")
    key = (id(fi), split)
    if key not in cache:
        cache[key] = engine.compile_split(fi) if split else engine.compile_feedback(fi)
    cf = cache[key]
    cf.warmup(scheme)
    p = engine.parameters(fi, gains)
    sol = cf.run(fi.y0, p, h, n, scheme, save_every=se, names=fi.names)
    return sol.y, sol.cpu_seconds, sol.rhs_evaluations


def run_adaptive(fi, h, n, se, cache):
    """Bae & Chang's periodic adaptive gain with Euler: segments of :data:`PERIOD` time units."""
    key = (id(fi), False)
    if key not in cache:
        cache[key] = engine.compile_feedback(fi)
    cf = cache[key]
    cf.warmup("euler")
    seg = int(round(PERIOD / h))
    seg -= seg % se
    y = fi.y0.copy()
    out, cpu, rhs, done = [y[:, None]], 0.0, 0, 0
    while done < n:
        m = min(seg, n - done)
        L = SAFETY * float(hess_frobenius(fi, y))
        gains = {k: v / (h * L) for k, v in fi.gains.items()}
        sol = cf.run(y, engine.parameters(fi, gains), h, m, "euler", save_every=se, names=fi.names)
        out.append(sol.y[:, 1:])
        cpu += sol.cpu_seconds
        rhs += sol.rhs_evaluations
        y = sol.y[:, -1].copy()
        done += m
    return np.concatenate(out, 1), cpu, rhs


#: every method of the benchmark, in the order of the table
METHODS = ("FI-Euler B&C optimal", "FI-Euler B&C adaptive", "FI-Euler accurate", "FI-RK4 accurate",
           "FI-imex-RK4 accurate", "FI-RK4 auto-1.6", "RK4", "projected RK4", "splitting")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hs", type=float, nargs="+", default=[1e-1, 1e-2, 1e-3, 1e-4])
    ap.add_argument("--t-final", type=float, default=1000.0)
    ap.add_argument("--h-ref", type=float, default=1e-4, help="step of the RK4 cross-check of the reference")
    ap.add_argument("--n-save", type=int, default=1000)
    ap.add_argument("--skip", nargs="*", default=[], help="methods to leave out")
    ap.add_argument("--small-hs", type=float, nargs="*", default=[1e-6],
                    help="further steps, run for the Euler feedback integrators and the splitting only")
    ap.add_argument("--only", nargs="*", default=None,
                    help="run only these methods; keep the rows of OUT/rigid_body.json (an earlier run) not run again")
    ap.add_argument("--table", metavar="JSON", help="only print the markdown table of an earlier run's JSON")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs", "rigid_body"))
    a = ap.parse_args(argv)
    if a.table:
        with open(a.table) as f:
            print(table(json.load(f)["rows"]), end="")
        return None
    if not engine.available():
        sys.exit("this benchmark needs numba")
    warnings.simplefilter("ignore")
    os.makedirs(a.out, exist_ok=True)
    sc = scenes.get("rigid-body")
    fi = sc.integrator()
    T = a.t_final
    cache = {}

    def steps(h):
        n = int(round(T / h))
        return n, max(1, n // a.n_save)

    # --- reference: DOP853 (rtol 1e-13) on the compiled free field, checked against RK4 -----
    t0 = time.time()
    from scipy.integrate import solve_ivp

    zero = {k: 0.0 for k in fi.gains}
    free = engine.compile_feedback(fi, feedback=False)
    t_eval = np.linspace(0.0, T, a.n_save + 1)
    sol = solve_ivp(free.fun(engine.parameters(fi)), (0.0, T), fi.y0, method="DOP853", t_eval=t_eval,
                    rtol=1e-13, atol=1e-13)
    Yref = sol.y
    n, se = steps(a.h_ref)
    Yrk, _, _ = run_fi(fi, zero, a.h_ref, n, se, "rk4", cache)
    ref_err = float(np.max(np.abs(Yref - Yrk)))
    print(f"reference DOP853 rtol 1e-13: {time.time() - t0:.1f}s; |DOP853 - RK4(h={a.h_ref:g})| = {ref_err:.2e}",
          flush=True)
    L0 = float(np.max(hess_frobenius(fi, Yref.T)))
    print(f"L0 = max ||Hess V||_F along the motion = {L0:.4g}", flush=True)

    rows = []
    methods = list(METHODS)
    methods = [m for m in methods if m not in a.skip and (a.only is None or m in a.only)]
    kept = []
    if a.only is not None:
        unknown = sorted(set(a.only) - set(METHODS))
        if unknown:
            sys.exit(f"--only: unknown method(s) {unknown}; choose from {METHODS}")
        old = os.path.join(a.out, "rigid_body.json")
        if os.path.exists(old):
            with open(old) as f:
                kept = json.load(f)["rows"]
    proj = None
    small = ("FI-Euler B&C optimal", "FI-Euler B&C adaptive", "splitting")
    for h in list(a.hs) + list(a.small_hs):
        n, se = steps(h)
        for meth in methods if h in a.hs else [m for m in methods if m in small]:
            w = time.time()
            gains = None
            try:
                if meth == "FI-Euler B&C optimal":
                    gains = {k: v / (h * L0) for k, v in fi.gains.items()}
                    Y, cpu, rhs = run_fi(fi, gains, h, n, se, "euler", cache)
                elif meth == "FI-Euler B&C adaptive":
                    Y, cpu, rhs = run_adaptive(fi, h, n, se, cache)
                elif meth == "FI-Euler accurate":
                    gains = accurate_gains(fi, h, "euler", T)
                    Y, cpu, rhs = run_fi(fi, gains, h, n, se, "euler", cache)
                elif meth == "FI-RK4 accurate":
                    gains = accurate_gains(fi, h, "rk4", T)
                    Y, cpu, rhs = run_fi(fi, gains, h, n, se, "rk4", cache)
                elif meth == "FI-imex-RK4 accurate":
                    gains = accurate_gains(fi, h, "imex-rk4", T)
                    Y, cpu, rhs = run_fi(fi, gains, h, n, se, "imex-rk4", cache)
                elif meth == "FI-RK4 auto-1.6":
                    gains = auto_gains(fi, h, "rk4")
                    Y, cpu, rhs = run_fi(fi, gains, h, n, se, "rk4", cache)
                elif meth == "RK4":
                    Y, cpu, rhs = run_fi(fi, zero, h, n, se, "rk4", cache)
                elif meth == "projected RK4":
                    if proj is None:
                        proj = engine.compile_constrained(fi, projection=True)
                        proj.warmup("rk4", project=True)
                    sol = proj.run(fi.y0, np.zeros(0), h, n, "rk4", save_every=se, names=fi.names,
                                   project=engine.projection_targets(fi))
                    Y, cpu, rhs = sol.y, sol.cpu_seconds, sol.rhs_evaluations
                else:
                    _, Y, cpu = splitting(fi.y0[:9], fi.y0[9:], sc.inertia, h, n, se)
                    rhs = n
                if not np.all(np.isfinite(Y)):
                    raise FloatingPointError("non-finite values")
                row = {"h": h, "method": meth, "status": "ok", "cpu_seconds": cpu, "steps": n, "rhs_evaluations": rhs}
                row.update(metrics(sc, fi, Y, Yref))
            except Exception as exc:  # noqa: BLE001 -- a diverged run is a result
                row = {"h": h, "method": meth, "status": f"failed: {type(exc).__name__}: {str(exc)[:120]}",
                       "cpu_seconds": math.nan, "steps": n}
            if gains is not None:
                row["gains"] = {k: float(v) for k, v in gains.items()}
            rows.append(row)
            print(f"h={h:g} {meth:22s} {time.time() - w:6.1f}s " + " ".join(
                f"{k}={row[k]:.2e}" for k in ("energy", "casimir", "orthogonality", "momentum", "state", "V_BC", "cpu_seconds")
                if k in row), flush=True)

    redone = {(r["method"], r["h"]) for r in rows}
    kept = [r for r in kept if (r["method"], r["h"]) not in redone]
    order = {m: i for i, m in enumerate(METHODS)}
    rows = sorted(kept + rows, key=lambda r: (-r["h"], order.get(r["method"], len(order))))
    meta = {"t_final": T, "h_ref": a.h_ref, "reference_self_error": ref_err, "L0": L0, "n_save": a.n_save,
            "k_bc": K_BC, "scene_gains": fi.gains}
    with open(os.path.join(a.out, "rigid_body.json"), "w") as f:
        json.dump({"meta": meta, "rows": rows}, f, indent=1)
    keys = ["h", "method", "status", "energy", "casimir", "orthogonality", "momentum", "state", "V_BC", "V_inv",
            "cpu_seconds", "steps"]
    with open(os.path.join(a.out, "rigid_body.csv"), "w") as f:
        f.write(",".join(keys) + "\n")
        for r in rows:
            f.write(",".join(str(r.get(k, "")) for k in keys) + "\n")
    plot(rows, os.path.join(a.out, "rigid_body.png"), T)
    with open(os.path.join(a.out, "rigid_body_table.md"), "w") as f:
        f.write(table(rows))
    return rows


def table(rows):
    """The results as a markdown table (one row per step and method)."""
    cols = ["energy", "casimir", "orthogonality", "momentum", "state", "V_BC", "V_inv", "cpu_seconds"]
    out = ["| h | method | " + " | ".join(cols) + " |", "|" + "---|" * (len(cols) + 2)]
    for r in rows:
        if r["status"] != "ok":
            out.append(f"| {r['h']:g} | {r['method']} | " + r["status"] + " |" * len(cols))
            continue
        out.append(f"| {r['h']:g} | {r['method']} | " + " | ".join(f"{r[c]:.2g}" for c in cols) + " |")
    return "\n".join(out) + "\n"


def plot(rows, path, T):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(14, 8))
    panels = [("energy", "|E - E0|"), ("casimir", "| |Pi| - |Pi0| |"), ("orthogonality", "||R^T R - I||_F"),
              ("momentum", "|R Pi - R0 Pi0| (spatial momentum)"), ("state", "state error")]
    methods = list(dict.fromkeys(r["method"] for r in rows))
    for ax, (key, label) in zip(axes.ravel(), panels):
        for i, m in enumerate(methods):
            rs = [r for r in rows if r["method"] == m and r["status"] == "ok"]
            if rs:
                ax.loglog([r["h"] for r in rs], [max(r[key], 1e-17) for r in rs], "o-", color=f"C{i}", label=m)
        ax.set_xlabel("h")
        ax.set_title(label)
        ax.grid(True, which="major", alpha=0.3)
    ax = axes.ravel()[5]
    for i, m in enumerate(methods):
        rs = [r for r in rows if r["method"] == m and r["status"] == "ok"]
        if rs:
            ax.loglog([max(r["cpu_seconds"], 1e-5) for r in rs], [max(r["state"], 1e-17) for r in rs], "o-",
                      color=f"C{i}", label=m)
    ax.set_xlabel("CPU seconds")
    ax.set_title("state error vs CPU")
    ax.grid(True, which="major", alpha=0.3)
    axes.ravel()[0].legend(fontsize=7)
    fig.suptitle(f"Free rigid body, I = diag(3, 2, 1), Omega0 = (1, 1, 1), t in [0, {T:g}]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
