"""Bae & Chang's Kepler benchmarks: error against the step h, liefi's feedback integrators against symplectic peers.

Run (from the repository root; numba and matplotlib required; about 5 CPU-minutes)::

    python benchmarks/kepler.py                                  # both scenes, the full grids
    python benchmarks/kepler.py --scene kepler --periods 20 --hs 1e-1 1e-2 --out /tmp/k   # a smoke test

Scenes ``kepler`` and ``perturbed-kepler`` (:mod:`liefi.scenes.kepler`).  Their
settings (J. Bae and D. E. Chang, arXiv:2512.01528, and their public code):
Kepler from ``q0 = (1, 0, 0)``, ``v0 = (0, sqrt 1.8, 0)``, ``mu = 1``, gains
``k1 = 4`` on ``|L - L0|^2`` and ``k2 = 2`` on ``|A - A0|^2``, 2000 periods of
70.2481 (their code now runs 1000); perturbed Kepler ``U = -1/r - 0.0025/r^3``
from ``e = 0.6`` (``q0 = (0.4, 0, 0)``, ``v0 = (0, 2, 0)``), ``kE = 3`` on the
energy, ``kL = 2`` on ``|L - L0|^2``, ``t`` in ``[0, 200]``.  Methods, per step ``h``
(``h`` is rounded so that a whole number of steps ends at the horizon):

* ``FI-Euler B&C optimal``: liefi's Euler feedback integrator (compiled) with
  their optimal fixed gain ``alpha = 1/(h L0)`` on every gain, ``L0 = 515.4``
  (Kepler) and ``148.03`` (perturbed), their constants
  (:func:`liefi.scenes.kepler.optimal_gains`);
* ``FI-Euler unity``: the same with ``alpha = 1`` (the gains as printed);
* ``FI-Euler B&C adaptive``: their periodic Hessian rule
  ``alpha = 1/(h max(1e-10, 1.1 ||H(y)||_F))`` re-evaluated every ``ceil(0.1/h)``
  steps, ``H = sum_j k_j grad I_j grad I_j^T`` (the Hessian of ``V`` on the
  invariant set); a numba kernel written here from their formulas (liefi's
  loops take a gain that is fixed over a run segment);
* ``FI-imex-RK4 auto``: liefi's split scheme (RK4 on the free field, then one
  Gauss--Newton step onto the invariant set), ``gains="auto"``;
* ``Stormer-Verlet``: kick-drift-kick, second order, symplectic (their baseline);
* ``Yoshida-4``: the 4th-order symmetric composition of Verlet with steps
  ``w1 h, w0 h, w1 h``, ``w1 = 1/(2 - 2^{1/3})``, ``w0 = 1 - 2 w1`` (H. Yoshida,
  Phys. Lett. A 150 (1990) 262; E. Forest and R. Ruth, Physica D 43 (1990) 105).

Measured at ``--n-save`` uniform times (every ``ceil(n_steps / n_save)`` steps; their code
takes maxima over every step): ``V_BC = max k1 |dL|^2 + k2 |dA|^2`` (the quantity their
figure plots, twice liefi's ``V``; perturbed: ``kL |dL|^2 + kE dE^2``), ``max |dL|``,
``max |dA|`` (perturbed: ``max |dE|``), the energy drift, the state error
``max |y - y_ref|`` (reference: the exact orbit for Kepler, DOP853 with
``rtol = atol = 1e-13`` for perturbed Kepler) and the CPU (process) time of the loop,
compilation excluded.  Writes ``OUT/<scene>.csv``, ``OUT/<scene>.json``,
``OUT/<scene>.png`` and ``OUT/kepler_table.md``.
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

from liefi import scenes  # noqa: E402
from liefi.schemes import IntegrationError  # noqa: E402
from liefi.scenes.kepler import PERIOD, optimal_gains  # noqa: E402

NAMES = ("x", "y", "z", "p_x", "p_y", "p_z")
UPDATE_PERIOD = 0.1  # their adaptive gain's update period (time units)
SAFETY = 1.1  # their factor on the Hessian norm
HMIN = 1e-10  # their floor of the Hessian norm


# ======================================================================================
# peers: hand-written numba kernels (independent of liefi's field)
# ======================================================================================


def _kernels():
    from numba import njit

    @njit(cache=False)
    def accel(r, mu, delta, a):
        r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
        inv3 = 1.0 / (r2 * math.sqrt(r2))
        c = -mu * inv3 if delta == 0.0 else -(mu + 3.0 * delta / r2) * inv3
        for i in range(3):
            a[i] = c * r[i]

    @njit(cache=False)
    def verlet(y0, h, n, stride, mu, delta, out, weights):
        """Kick-drift-kick Verlet, composed with step fractions ``weights`` (1: Verlet; 3: Yoshida)."""
        r = y0[:3].copy()
        v = y0[3:].copy()
        a = np.empty(3)
        accel(r, mu, delta, a)
        j = 1
        for i in range(6):
            out[i, 0] = y0[i]
        for s in range(1, n + 1):
            for w in weights:
                hw = h * w
                for i in range(3):
                    v[i] += 0.5 * hw * a[i]
                for i in range(3):
                    r[i] += hw * v[i]
                accel(r, mu, delta, a)
                for i in range(3):
                    v[i] += 0.5 * hw * a[i]
            if s % stride == 0 or s == n:
                for i in range(3):
                    out[i, j] = r[i]
                    out[3 + i, j] = v[i]
                j += 1
        return j

    @njit(cache=False)
    def jacobians(r, v, mu, delta, J):
        """Rows of ``J`` (7 x 6): ``grad L_x, L_y, L_z, A_x, A_y, A_z, E`` at ``(r, v)``."""
        rn = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        rv = r[0] * v[0] + r[1] * v[1] + r[2] * v[2]
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            # L_i = r_j v_k - r_k v_j
            for c in range(6):
                J[i, c] = 0.0
            J[i, j] = v[k]
            J[i, k] = -v[j]
            J[i, 3 + k] = r[j]
            J[i, 3 + j] = -r[k]
            # A = r (|v|^2 - mu/r) - v (r . v)
            for c in range(3):
                J[3 + i, c] = (vv - mu / rn if c == i else 0.0) + mu * r[i] * r[c] / rn**3 - v[i] * v[c]
                J[3 + i, 3 + c] = 2.0 * r[i] * v[c] - v[i] * r[c] - (rv if c == i else 0.0)
        up = mu / rn**2 + 3.0 * delta / rn**4
        for c in range(3):
            J[6, c] = up * r[c] / rn
            J[6, 3 + c] = v[c]

    @njit(cache=False)
    def values(r, v, mu, delta, I):
        """``L``, ``A``, ``E`` at ``(r, v)`` into ``I`` (7)."""
        rn = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        rv = r[0] * v[0] + r[1] * v[1] + r[2] * v[2]
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            I[i] = r[j] * v[k] - r[k] * v[j]
            I[3 + i] = r[i] * (vv - mu / rn) - v[i] * rv
        I[6] = 0.5 * vv - mu / rn - delta / rn**3

    @njit(cache=False)
    def fi_euler_adaptive(y0, h, n, stride, mu, delta, k, m, out):
        """Euler on ``X - alpha grad V``, ``V = sum_j k_j/2 (I_j - I_j0)^2`` over ``L, A, E`` (``k``: 7 gains),
        ``alpha = 1/(h max(HMIN, SAFETY ||H||_F))`` every ``m`` steps, ``H = sum_j k_j grad I_j grad I_j^T``."""
        y = y0.copy()
        J = np.empty((7, 6))
        I = np.empty(7)
        I0 = np.empty(7)
        a = np.empty(3)
        f = np.empty(6)
        values(y[:3], y[3:], mu, delta, I0)
        for i in range(6):
            out[i, 0] = y0[i]
        j = 1
        alpha = 0.0
        for s in range(n):
            jacobians(y[:3], y[3:], mu, delta, J)
            if s % m == 0:
                h2 = 0.0  # ||H||_F^2 = sum_{jl} k_j k_l (grad I_j . grad I_l)^2
                for p in range(7):
                    for q in range(7):
                        if k[p] != 0.0 and k[q] != 0.0:
                            g = 0.0
                            for c in range(6):
                                g += J[p, c] * J[q, c]
                            h2 += k[p] * k[q] * g * g
                alpha = 1.0 / (h * max(HMIN, SAFETY * math.sqrt(h2)))
            values(y[:3], y[3:], mu, delta, I)
            accel(y[:3], mu, delta, a)
            for c in range(3):
                f[c] = y[3 + c]
                f[3 + c] = a[c]
            for p in range(7):
                if k[p] != 0.0:
                    w = alpha * k[p] * (I[p] - I0[p])
                    for c in range(6):
                        f[c] -= w * J[p, c]
            for c in range(6):
                y[c] += h * f[c]
            if (s + 1) % stride == 0 or s + 1 == n:
                for c in range(6):
                    out[c, j] = y[c]
                j += 1
        return j

    return verlet, fi_euler_adaptive


_K = {}


def kernels():
    if not _K:
        _K["verlet"], _K["adaptive"] = _kernels()
    return _K["verlet"], _K["adaptive"]


YOSHIDA_W1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
WEIGHTS = {"Stormer-Verlet": np.array([1.0]),
           "Yoshida-4": np.array([YOSHIDA_W1, 1.0 - 2.0 * YOSHIDA_W1, YOSHIDA_W1])}


def run_peer(method, sc, y0, h, n, stride, gains):
    """``(Y (6, n_saved), cpu)`` of a hand-written peer."""
    verlet, adaptive = kernels()
    ns = -(-n // stride) + 1 if n % stride else n // stride + 1
    out = np.full((6, ns), np.nan)
    if method in WEIGHTS:
        w = WEIGHTS[method]
        verlet(y0, h, 2, 1, sc.mu, sc.delta, np.empty((6, 3)), w)  # compile outside the timing
        c0 = time.process_time()
        verlet(y0, h, n, stride, sc.mu, sc.delta, out, w)
    else:
        k = np.zeros(7)
        for name, g in gains.items():
            k[{"L_x": 0, "L_y": 1, "L_z": 2, "A_x": 3, "A_y": 4, "A_z": 5, "energy": 6}[name]] = g
        m = max(1, int(math.ceil(UPDATE_PERIOD / h)))
        adaptive(y0, h, 2, 1, sc.mu, sc.delta, k, m, np.empty((6, 3)))
        c0 = time.process_time()
        adaptive(y0, h, n, stride, sc.mu, sc.delta, k, m, out)
    return out, time.process_time() - c0


# ======================================================================================
# one run and its measures
# ======================================================================================

LIEFI_METHODS = ("FI-Euler B&C optimal", "FI-Euler unity", "FI-imex-RK4 auto")
PEERS = ("FI-Euler B&C adaptive", "Stormer-Verlet", "Yoshida-4")
METHODS = LIEFI_METHODS[:2] + PEERS[:1] + LIEFI_METHODS[2:] + PEERS[1:]


def run_liefi(method, sc, h, n, stride, tf):
    gains = {"FI-Euler B&C optimal": optimal_gains(sc, h), "FI-Euler unity": dict(sc.gains),
             "FI-imex-RK4 auto": "auto"}[method]
    scheme = "imex-rk4" if "imex" in method else "euler"
    fi = sc.integrator(gains=gains)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fi.run(10 * h, dt=h, scheme=scheme, backend="numba", check_stability=False)  # compile outside the timing
        sol = fi.run(tf, dt=h, scheme=scheme, backend="numba", check_stability=False, save_every=stride)
    return sol.y, sol.cpu_seconds


def measure(sc, Y, t, ref, y0):
    """Bae & Chang's measures and the state error of a run ``Y`` (6, n_t) at times ``t``."""
    r, v = Y[:3].T, Y[3:].T
    L = np.cross(r, v)
    rn = np.linalg.norm(r, axis=1)
    A = np.cross(v, L) - sc.mu * r / rn[:, None]
    E = 0.5 * np.sum(v * v, 1) - sc.mu / rn - sc.delta / rn**3
    r0, v0 = y0[:3], y0[3:]
    L0 = np.cross(r0, v0)
    A0 = np.cross(v0, L0) - sc.mu * r0 / np.linalg.norm(r0)
    E0 = 0.5 * v0 @ v0 - sc.mu / np.linalg.norm(r0) - sc.delta / np.linalg.norm(r0) ** 3
    dL = np.linalg.norm(L - L0, axis=1)
    dA = np.linalg.norm(A - A0, axis=1)
    dE = np.abs(E - E0)
    g = sc.gains
    if "energy" in g:
        vbc = g["L_x"] * dL**2 + g["energy"] * dE**2
    else:
        vbc = g["L_x"] * dL**2 + g["A_x"] * dA**2
    Yref = np.stack([ref[nm] for nm in NAMES])
    finite = bool(np.all(np.isfinite(Y)))
    big = lambda a: float(np.max(a)) if finite else float("nan")  # noqa: E731
    return {"V_BC": big(vbc), "dL": big(dL), "dA": big(dA), "dE": big(dE),
            "state_error": big(np.abs(Y - Yref)), "finite": finite}


def study(name, hs, periods, n_save, imex_min_h, log=print):
    sc = scenes.get(name)
    v = sc.variant()
    y0 = np.asarray(sc.initial_state(v), float)
    tf = periods * PERIOD if name == "kepler" else sc.t_final
    rows = []
    refcache = {}
    for h_asked in hs:
        n = int(round(tf / h_asked))
        h = tf / n
        stride = max(1, -(-n // n_save))
        idx = np.arange(0, n + 1, stride)
        if idx[-1] != n:
            idx = np.append(idx, n)
        t = idx * h
        if (n, stride) not in refcache:
            refcache.clear()
            refcache[n, stride] = sc.exact(t, v)
        ref = refcache[n, stride]
        for method in METHODS:
            if method == "FI-imex-RK4 auto" and h < imex_min_h:
                continue
            w0 = time.perf_counter()
            try:
                if method in LIEFI_METHODS:
                    Y, cpu = run_liefi(method, sc, h, n, stride, tf)
                else:
                    Y, cpu = run_peer(method, sc, y0, h, n, stride, sc.gains)
                m = measure(sc, Y, t, ref, y0)
                status = "ok" if m.pop("finite") else "diverged"
            except IntegrationError:  # liefi stops a run that produces non-finite numbers
                m, cpu, status = {}, float("nan"), "diverged"
            row = {"scene": name, "method": method, "h": h, "steps": n, "t_final": tf, "cpu_seconds": cpu,
                   "status": status, **m}
            rows.append(row)
            log(f"{name:16s} h={h:9.3g} {method:22s} {status:9s} cpu={cpu:8.3f}s "
                f"V_BC={m.get('V_BC', float('nan')):9.3g} dL={m.get('dL', float('nan')):9.3g} "
                f"dA={m.get('dA', float('nan')):9.3g} dE={m.get('dE', float('nan')):9.3g} "
                f"err={m.get('state_error', float('nan')):9.3g}  ({time.perf_counter() - w0:.1f}s wall)")
    return rows


# ======================================================================================
# output
# ======================================================================================

STYLE = {"FI-Euler B&C optimal": ("C0", "^"), "FI-Euler unity": ("C7", "s"), "FI-Euler B&C adaptive": ("C1", "D"),
         "FI-imex-RK4 auto": ("C3", "*"), "Stormer-Verlet": ("C2", "v"), "Yoshida-4": ("C4", "o")}


def figure(rows, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    perturbed = rows[0]["scene"] == "perturbed-kepler"
    panels = [("V_BC", r"$\max\ V_{BC}$" + (r" $= k_L|\Delta L|^2 + k_E \Delta E^2$" if perturbed
                                            else r" $= k_1|\Delta L|^2 + k_2|\Delta A|^2$")),
              ("dL", r"$\max\ |\Delta L|$"),
              ("dE" if perturbed else "dA", r"$\max\ |\Delta E|$" if perturbed else r"$\max\ |\Delta A|$"),
              ("state_error", r"$\max\ |y - y_{ref}|$"), ("cpu_seconds", "CPU seconds")]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.2), constrained_layout=True)
    for ax, (key, label) in zip(axes, panels):
        for method in METHODS:
            pts = [(r["h"], r[key]) for r in rows if r["method"] == method and r["status"] == "ok"
                   and r.get(key) is not None and np.isfinite(r[key]) and r[key] > 0]
            if pts:
                c, mk = STYLE[method]
                ax.loglog(*zip(*pts), marker=mk, color=c, label=method, lw=1.5)
        ax.set_xlabel("$h$")
        ax.set_title(label, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def table(rows):
    perturbed = rows[0]["scene"] == "perturbed-kepler"
    third = "dE" if perturbed else "dA"
    head = (f"| h | method | max V_BC | max abs dL | max abs {third} | state error | CPU s |\n"
            "|---|---|---|---|---|---|---|\n")
    out = []
    for r in rows:
        if r["status"] != "ok":
            out.append(f"| {r['h']:.3g} | {r['method']} | {r['status']} | | | | |")
            continue
        out.append(f"| {r['h']:.3g} | {r['method']} | {r['V_BC']:.2e} | {r['dL']:.2e} | {r[third]:.2e} | "
                   f"{r['state_error']:.2e} | {r['cpu_seconds']:.3g} |")
    return head + "\n".join(out) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=["kepler", "perturbed-kepler", "both"], default="both")
    ap.add_argument("--hs", nargs="+", type=float, default=None, help="steps (default: the scene's grid)")
    ap.add_argument("--periods", type=float, default=2000, help="Kepler horizon in periods of 70.2481")
    ap.add_argument("--n-save", type=int, default=1_000_000, dest="n_save")
    ap.add_argument("--imex-min-h", type=float, default=None, dest="imex_min_h",
                    help="smallest h of the imex-rk4 runs (default: 1e-3 for Kepler, 1e-5 perturbed)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs", "kepler"))
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    grids = {"kepler": [10 ** -(1 + 0.5 * i) for i in range(6)],  # 1e-1 ... 10^-3.5 (1e-4: --hs, ~6 CPU-min more)
             "perturbed-kepler": [10 ** -(1 + 0.5 * i) for i in range(9)]}
    start = time.perf_counter()
    tables = []
    for name in (["kepler", "perturbed-kepler"] if a.scene == "both" else [a.scene]):
        hs = a.hs or grids[name]
        imin = a.imex_min_h if a.imex_min_h is not None else (1e-3 if name == "kepler" else 1e-5) * 0.999
        rows = study(name, hs, a.periods, a.n_save, imin)
        with open(os.path.join(a.out, f"{name}.json"), "w") as fh:
            json.dump(rows, fh, indent=1)
        import csv

        with open(os.path.join(a.out, f"{name}.csv"), "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=sorted({k for r in rows for k in r}))
            w.writeheader()
            w.writerows(rows)
        T = rows[0]["t_final"]
        what = (f"Kepler, {T / PERIOD:g} periods (t = {T:g})" if name == "kepler"
                else f"perturbed Kepler (delta = 0.0025, e = 0.6), t in [0, {T:g}]")
        figure(rows, os.path.join(a.out, f"{name}.png"), f"Bae & Chang's {what}: error against the step h")
        tables.append(f"### {what}\n\n" + table(rows))
    with open(os.path.join(a.out, "kepler_table.md"), "w") as fh:
        fh.write("\n".join(tables))
    print(f"wall time {time.perf_counter() - start:.0f} s; wrote {a.out}")


if __name__ == "__main__":
    main()
