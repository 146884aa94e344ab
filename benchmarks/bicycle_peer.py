"""The benchmark bicycle as PyDy users run it: sympy's ``KanesMethod``, generated numerics, ``solve_ivp``.

The peer of issue 27.  The Whipple bicycle of Meijaard, Papadopoulos, Ruina & Schwab
(Proc. R. Soc. A 463 (2007) 1955), written as sympy's own test writes it
(``sympy/physics/mechanics/tests/test_kane3.py``: minimal speeds for the rear contact,
the pitch dependent through one configuration constraint, three velocity constraints,
the Cramer solver; builder ``whipple_sympy_test`` of ``tests/bicycle_model.py``), or with
the contact points' coordinates (``--model contact``: ``whipple_contact_coordinates``).

What a user does, and what this script times in fresh processes:

* **linearize**: build the ``KanesMethod``, ``KanesMethod.linearize`` about the upright
  run at speed ``v`` (as sympy's test does), the benchmark's eigenvalues at
  v = 0, 4, 5, 10 m/s and the weave and capsize speeds by root finding
  (``--linearizer complex-step``, the default with ``--quick`` and ``--model contact``:
  complex steps of the generated right-hand side on the constraint set instead, in
  seconds; sympy's linearizer takes about 3 CPU minutes on the first model and did not
  finish in 14 on the second);
* **run**: build, generate the right-hand side of
  ``mass_matrix_full(x) x' = forcing_full(x)`` and integrate it with
  ``scipy.integrate.solve_ivp``.  The numerics come from PyDy's
  ``generate_ode_function(..., generator="lambdify")`` when ``pydy`` imports, and
  otherwise from ``sympy.lambdify(..., cse=True)`` of the same two matrices, which is
  what that PyDy backend does (the script says which one it used).

The state is all coordinates and all speeds, ``x = (q, u)``: the dependent pitch and the
dependent speeds are integrated like the others, so the integrator holds the
configuration constraint (the front contact's height) and the velocity constraints only
as well as its tolerance lets it -- PyDy's Carvallo-Whipple example says so ("The
holonomic constraint equation is not explicitly enforced ... will drift").

Runs, uncontrolled, from the upright straight run with a lean-rate perturbation:
5 m/s (self-stable), 3 m/s (weave grows), 8 m/s (slow capsize), each with lean rate
0.1 rad/s, and 4.6 m/s with 0.5 rad/s (the manoeuvre of PyDy's example), over [0, 100] s
or until the lean reaches 60 degrees (reported as "fell at").  Integrators:
DOP853 at rtol = atol = 1e-12 and RK45 at rtol = atol = 1e-6.

Measured on the dense output every 0.01 s: the largest ``|lean|`` on [0, 2] s and on
[8, 10] s (decayed or grown; on the last 2 s of a run that ends sooner), the front
contact's height ``max |f(q)|`` (m), the velocity constraints ``max_t max_i |c_i(q, u)|``
(m/s), the energy ``max |E - E0| / |E0|``; CPU seconds of each phase.

Run from the repository root (sympy and scipy needed; pydy optional)::

    python benchmarks/bicycle_peer.py            # full table, t in [0, 100]
    python benchmarks/bicycle_peer.py --quick    # t in [0, 5], one speed, eigenvalues by complex steps

Prints a Markdown table headed by the CPU model, and writes it with ``--out FILE``.
"""

import argparse
import json
import os
import subprocess
import sys

_HERE = os.path.dirname(os.path.abspath(__file__))
_ROOT = os.path.dirname(_HERE)
for _p in (_HERE, os.path.join(_ROOT, "tests")):
    if _p not in sys.path:
        sys.path.insert(0, _p)

SPEEDS = [0.0, 4.0, 5.0, 10.0]
CASES = [  # (label, forward speed m/s, lean rate rad/s)
    ("self-stable", 5.0, 0.1),
    ("weave grows", 3.0, 0.1),
    ("slow capsize", 8.0, 0.1),
    ("PyDy's 4.6 m/s, 0.5 rad/s", 4.6, 0.5),
]
METHODS = [("DOP853", 1e-12), ("RK45", 1e-6)]
FALL_LEAN = 1.0471975511965976  # 60 degrees


def _cpu():
    t = os.times()
    return t.user + t.system


def build(model):
    import bicycle_model as bm
    if model == "sympy-test":
        return bm.whipple_sympy_test()
    if model == "contact":
        return bm.whipple_contact_coordinates()
    raise ValueError(f"--model must be 'sympy-test' or 'contact', got {model!r}")


def phase_linearize(model, how="sympy"):
    """Build + linearize + eigenvalues + weave/capsize speeds; returns a JSON-able dict.

    ``how="sympy"``: ``KanesMethod.linearize`` (what sympy's test does; minutes);
    ``how="complex-step"``: complex steps of the generated right-hand side on the
    constraint set (``bicycle_model.complex_step_lateral``; seconds).
    """
    import bicycle_model as bm
    t0 = _cpu()
    bike = build(model)
    t_build = _cpu() - t0
    if how == "complex-step":
        lateral = bm.complex_step_lateral(bike)
    else:
        lateral = bm.lateral_matrix(bike)
    eig = {str(v): [[complex(w).real, complex(w).imag] for w in bm.eigenvalues(lateral(v))] for v in SPEEDS}
    weave, capsize = bm.weave_and_capsize_speeds(lateral)
    return {"build": t_build, "total": _cpu() - t0, "eigenvalues": eig, "weave": weave, "capsize": capsize,
            "how": how}


def numeric_model(bike):
    """The generated function a PyDy user integrates: ``(rhs, backend)`` with ``rhs(t, x)``.

    :func:`monitors_of` gives the measurements: ``monitors(X) -> (hol, nonhol, energy)``
    for states ``X`` of shape ``(n, len(x))``, and ``initial(v, lean_rate)``, the state of
    the upright run with the dependent speeds solved from the constraints.
    """
    import numpy as np
    import sympy
    kane = bike.kane
    q, u = list(kane.q), list(kane.u)
    consts = list(bike.params)
    pvals = np.array([bike.params[c] for c in consts])
    try:
        from pydy.codegen.ode_function_generators import generate_ode_function
        f = generate_ode_function(kane.forcing_full, q, u, consts, mass_matrix=kane.mass_matrix_full,
                                  generator="lambdify")
        backend = "pydy %s lambdify" % __import__("pydy").__version__

        def rhs(t, x):
            return f(x, t, pvals)
    except ImportError:
        fM = sympy.lambdify(q + u + consts, kane.mass_matrix_full, "numpy", cse=True)
        fF = sympy.lambdify(q + u + consts, kane.forcing_full, "numpy", cse=True)
        backend = "sympy lambdify (cse), as pydy's lambdify backend"

        def rhs(t, x):
            args = list(x) + list(pvals)
            return np.linalg.solve(np.asarray(fM(*args), dtype=float), np.asarray(fF(*args), dtype=float).ravel())

    return rhs, backend


def monitors_of(bike):
    """``(monitors, initial)``: the measurements of a run and its start (see :func:`numeric_model`)."""
    import numpy as np
    import sympy
    kane = bike.kane
    q, u = list(kane.q), list(kane.u)
    subs = bike.params
    hol = sympy.lambdify(q + u, bike.holonomic.xreplace(subs), "numpy", cse=True)
    non = sympy.lambdify(q + u, sympy.Matrix(bike.nonholonomic).xreplace(subs), "numpy", cse=True)
    en = sympy.lambdify(q + u, bike.energy.xreplace(subs), "numpy", cse=True)
    udep = list(kane._udep)
    cmat = sympy.Matrix(bike.nonholonomic).xreplace(subs)
    jac = sympy.lambdify(q + u, cmat.jacobian(udep), "numpy")

    def monitors(X):
        cols = [X[:, i] for i in range(X.shape[1])]
        h = np.abs(np.broadcast_to(hol(*cols), X.shape[:1]))
        c = np.array([np.broadcast_to(np.asarray(r, dtype=float).ravel() if np.ndim(r) else r, X.shape[:1])
                      for r in np.asarray(non(*cols), dtype=object).ravel()], dtype=float)
        e = np.broadcast_to(en(*cols), X.shape[:1]).astype(float)
        return h, np.abs(c).max(axis=0), e

    def initial(v, lean_rate):
        x = np.zeros(len(q) + len(u))
        x[q.index(bike.pitch)] = bike.pitch0
        for s, val in bike.speed_of(v).items():
            x[len(q) + u.index(s)] = val
        x[len(q) + u.index(bike.lean_rate)] = lean_rate
        idx = [len(q) + u.index(s) for s in udep]
        for _ in range(3):  # the constraints are linear in the dependent speeds
            r = np.asarray(non(*x), dtype=float).ravel()
            J = np.asarray(jac(*x), dtype=float)
            x[idx] -= np.linalg.solve(J, r)
        return x

    return monitors, initial


def phase_run(model, cases, methods, t_final):
    """Build + generate + integrate each case; returns a JSON-able dict."""
    import numpy as np
    from scipy.integrate import solve_ivp
    t0 = _cpu()
    bike = build(model)
    t_build = _cpu() - t0
    rhs, backend = numeric_model(bike)
    t_gen = _cpu() - t0 - t_build
    monitors, initial = monitors_of(bike)
    lean_i = list(bike.kane.q).index(bike.lean)

    def fell(t, x):
        return abs(x[lean_i]) - FALL_LEAN
    fell.terminal = True

    rows = []
    for label, v, lean_rate in cases:
        x0 = initial(v, lean_rate)
        for name, tol in methods:
            t1 = _cpu()
            sol = solve_ivp(rhs, (0.0, t_final), x0, method=name, rtol=tol, atol=tol, dense_output=True,
                            events=fell)
            t_int = _cpu() - t1  # the user's cost; what follows is this script's measuring
            t_end = sol.t[-1]
            ts = np.append(np.arange(0.0, t_end, 0.01), t_end)
            X = sol.sol(ts).T
            h, c, e = monitors(X)
            e0 = monitors(x0[None, :])[2][0]
            lean = np.abs(X[:, lean_i])
            early = float(lean[ts <= 2.0].max())
            late_window = (8.0, 10.0) if t_end >= 10.0 else (max(0.0, t_end - 2.0), t_end)
            late = float(lean[(ts >= late_window[0]) & (ts <= late_window[1])].max())
            rows.append({"case": label, "v": v, "lean_rate": lean_rate, "method": name, "tol": tol,
                         "status": sol.status, "nfev": int(sol.nfev), "t_end": float(t_end),
                         "fell": bool(sol.status == 1), "cpu_integrate": t_int,
                         "holonomic": float(h.max()), "nonholonomic": float(c.max()),
                         "energy": float(np.abs(e - e0).max() / abs(e0)),
                         "lean_0_2": early, "lean_late": late, "late_window": late_window, "lean_max": float(lean.max())})
    return {"build": t_build, "generate": t_gen, "backend": backend, "rows": rows, "total": _cpu() - t0,
            "to_result": t_build + t_gen + sum(r["cpu_integrate"] for r in rows)}


def _child(args):
    """Run one phase in a fresh Python process; returns (its dict, its CPU seconds)."""
    cmd = [sys.executable, os.path.abspath(__file__), "--phase"] + args
    before = os.times()
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    after = os.times()
    cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
    return json.loads(out.strip().splitlines()[-1]), cpu


def table(model, lin, lin_cpu, run, run_cpu, t_final):
    from _machine import cpu_model
    backend = run["backend"] if run else "-"
    lines = [f"CPU: {cpu_model()}; model: {model}; numerics: {backend}", ""]
    if lin:
        lines += _eigen_lines(lin, lin_cpu)
    if run:
        lines += _run_lines(run, run_cpu, t_final)
    return "\n".join(lines)


def _eigen_lines(lin, lin_cpu):
    import bicycle_model as bm
    import numpy as np
    how = {"sympy": "sympy `KanesMethod.linearize`",
           "complex-step": "complex steps of the generated right-hand side"}[lin["how"]]
    lines = [f"Eigenvalues (lean/steer, {how}) against Meijaard et al. (2007), Table 2:", "",
              "| v (m/s) | published | peer | max relative error |", "|---|---|---|---|"]
    for v in SPEEDS:
        ref = np.array(bm.BENCHMARK_EIGENVALUES[v])
        ref = ref[np.lexsort((ref.imag, ref.real))]
        got = np.array([complex(a, b) for a, b in lin["eigenvalues"][str(v)]])
        err = (np.abs(got - ref) / np.abs(ref)).max()
        fmt = lambda w: ", ".join(f"{z.real:.14f}" + (f"{z.imag:+.14f}i" if z.imag else "") for z in w)
        lines.append(f"| {v:g} | {fmt(ref)} | {fmt(got)} | {err:.1e} |")
    for name, ref in (("weave", bm.WEAVE_SPEED), ("capsize", bm.CAPSIZE_SPEED)):
        lines.append(f"| {name} speed | {ref:.14f} | {lin[name]:.14f} | {abs(lin[name] - ref) / ref:.1e} |")
    lines += ["", f"Time to eigenvalues (fresh process, CPU s): {lin_cpu:.1f} "
              f"(build {lin['build']:.1f}, linearize + eigenvalues + speeds {lin['total'] - lin['build']:.1f})", ""]
    return lines


def _run_lines(run, run_cpu, t_final):
    lines = [f"Nonlinear runs over [0, {t_final:g}] s, CPU s in a fresh process: build {run['build']:.1f}, "
             f"code generation {run['generate']:.1f}, each integration in the table; time to result "
             f"(build + generation + every integration) {run['to_result']:.1f}; the whole process, with imports "
             f"and this script's measuring, {run_cpu:.1f}.", "",
              "| case | v | method, tol | integrate (CPU s) | nfev | until t | max abs lean (rad) on [0, 2] s -> [8, 10] s | "
              "front height max | constraints max (m/s) | energy rel. |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in run["rows"]:
        until = f"fell at {r['t_end']:.2f}" if r["fell"] else f"{r['t_end']:g}"
        lines.append(f"| {r['case']} | {r['v']:g} | {r['method']} {r['tol']:.0e} | {r['cpu_integrate']:.1f} | "
                     f"{r['nfev']} | {until} | {r['lean_0_2']:.2g} -> {r['lean_late']:.2g}{_window(r)} | {r['holonomic']:.1e} | "
                     f"{r['nonholonomic']:.1e} | {r['energy']:.1e} |")
    return lines


def _window(row):
    a, b = row["late_window"]
    return "" if (a, b) == (8.0, 10.0) else f" (on [{a:.1f}, {b:.1f}] s)"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="t in [0, 5], the 5 m/s case only, eigenvalues by complex steps")
    ap.add_argument("--model", default="sympy-test", choices=["sympy-test", "contact"])
    ap.add_argument("--t-final", type=float, default=None, help="end time of the runs (default 100, 5 with --quick)")
    ap.add_argument("--linearizer", choices=["sympy", "complex-step"], default=None,
                    help="how the eigenvalues are found (default sympy; complex-step with --quick or --model contact)")
    ap.add_argument("--only", choices=["linearize", "run"], default=None, help="time one phase only")
    ap.add_argument("--out", default=None, help="also write the table to this file")
    ap.add_argument("--phase", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.phase:
        kind, model = a.phase[0], a.phase[1]
        if kind == "linearize":
            res = phase_linearize(model, a.phase[2])
        else:
            t_final, quick = float(a.phase[2]), a.phase[3] == "1"
            res = phase_run(model, CASES[:1] if quick else CASES, METHODS, t_final)
        print(json.dumps(res))
        return 0
    t_final = a.t_final if a.t_final is not None else (5.0 if a.quick else 100.0)
    lin = run = lin_cpu = run_cpu = None
    if a.only != "run":
        # sympy's linearizer takes ~3 CPU min on the sympy-test model and did not finish in
        # 14 CPU min on the contact model: complex steps are the default there.
        how = a.linearizer or ("complex-step" if a.quick or a.model == "contact" else "sympy")
        lin, lin_cpu = _child(["linearize", a.model, how])
    if a.only != "linearize":
        run, run_cpu = _child(["run", a.model, repr(t_final), "1" if a.quick else "0"])
    text = table(a.model, lin, lin_cpu, run, run_cpu, t_final)
    print(text)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
