"""How the fixed costs grow with the system: a chain of ``N`` knife edges, and the rattleback's time to result (issue 26).

Run (from the repository root)::

    python benchmarks/scale.py                      # the chain at N = 1 ... 64 and the rattleback, best of 3
    python benchmarks/scale.py --n 1 2 4 8 --repeat 2 --no-rattleback
    python benchmarks/scale.py --no-chain           # the rattleback against the PyDy peer only
    python benchmarks/scale.py --profile 8          # cProfile of the trace at N = 8, by cumulative time

The rattleback part (:func:`rattleback`) times a user's first run of Kane & Levinson's rattleback over
``[0, 20]`` at ``rtol = 1e-6`` in fresh processes, through ``scenes.get("rattleback").run(t_final=20.0,
rtol=1e-6)`` and through ``FeedbackIntegrator.run((0, 20), rtol=1e-6)``: cold (an empty kernel cache),
warm (the kernels cached, no stored step: ``LIEFI_REFERENCE_STORE=0``) and, for the scene, warm with the
step stored by an earlier run.  Each is split, in CPU seconds of the process, into import (liefi and numba),
trace (tracing and generating the kernels, or finding them by their data's fingerprint), choose (the step
choice, less the traces and compiles it triggers), compile/load (executing the generated module, numba's
compile or the load of its cached code), integrate (the run's loop) and build (the rest: the system, the
integrator, its gains and checks, the result); a cold case also lists numba's compile of each function (its own
CPU, less the compiles nested in it: the field ``xrhs_s``, the feedback step ``fstep_s``, the loop).  The PyDy peer (``benchmarks/rattleback_pydy.py``:
``KanesMethod``, pydy's Cython code generation, ``solve_ivp`` DOP853 at ``1e-12``; its derivation, code
generation with the C compiler, and integration, CPU of the process and its children) runs in the same
rounds, interleaved.  PyDy is optional: ``--pydy-path`` puts a private installation on ``sys.path`` (for
example one made by ``pip install --target /tmp/pydy-lib pydy``).

The system is built from data, as a user would: ``N`` copies of the knife-edge scene's data
(:mod:`liefi.scenes.knife_edge`) on ``T*R^{3N}``, ``q = (x_1, y_1, phi_1, ..., x_N, y_N, phi_N)``,
metric ``diag(m, m, J, ...)``, one Pfaffian row per edge (``e_i`` = ``(sin phi_i, -cos phi_i, 0)`` in
the slots of edge ``i``) and the potential

.. math:: U = -m g \\sin\\alpha \\sum_i x_i + \\frac{k}{2} \\sum_{i<N}
          \\big((x_{i+1} - x_i)^2 + (y_{i+1} - y_i - \\ell)^2\\big),

springs of rest length ``ell`` between neighbours: ``6N`` states, ``N`` constraints.  Each ``N`` runs in
fresh processes (one first to fill the kernel cache, then ``--repeat`` timed, best of) and reports, in
CPU seconds (``time.process_time``): construction (system and
:class:`~liefi.FeedbackIntegrator`), trace (the trace and code generation of
:func:`liefi.engine.kernels.compile_split`), load (the kernel from the warm cache), integrate
(``imex-rk4``, ``dt`` 1e-3 over ``[0, 1]``), the whole first ``fi.run`` (the integration with its
checks before and after: the stability estimate, the guard's audit) and the peak RSS of the process; then the fitted growth
exponents ``d log(cost) / d log(N)`` over the measured ``N`` (least squares, ``N >= 4``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def chain(N, *, m=1.0, J=1.0, g=1.0, alpha=np.pi / 6, k=1.0, ell=1.0):
    """The :class:`~liefi.NonholonomicSystem` of ``N`` knife edges joined by springs, and a start on ``J = 0``."""
    import liefi

    def potential(q):
        x, y = q[..., 0::3], q[..., 1::3]
        U = -m * g * np.sin(alpha) * np.sum(x, -1)
        if N > 1:
            U = U + 0.5 * k * np.sum((x[..., 1:] - x[..., :-1]) ** 2 + (y[..., 1:] - y[..., :-1] - ell) ** 2, -1)
        return U

    def constraint(q):
        phi = q[..., 2::3]
        s, c, zero = np.sin(phi), -np.cos(phi), np.zeros_like(phi[..., 0])
        rows = []
        for i in range(N):
            row = [zero] * (3 * N)
            row[3 * i], row[3 * i + 1] = s[..., i] / np.sqrt(m), c[..., i] / np.sqrt(m)
            rows.append(np.stack(row, -1))
        return np.stack(rows, -2)

    space = liefi.CotangentBundle(3 * N)
    system = liefi.NonholonomicSystem(space, np.diag([m, m, J] * N), constraint, potential)
    q0 = np.zeros(3 * N)
    q0[1::3] = ell * np.arange(N)
    q0[2::3] = 0.1 * np.arange(N)
    p0 = np.zeros(3 * N)
    p0[2::3] = 0.5
    return system, np.concatenate([q0, p0])


_CASE = r"""
import json, resource, sys, time, warnings
warnings.simplefilter("ignore")
sys.path.insert(0, sys.argv[2])
import numpy as np
import liefi
import numba  # imported here, not inside the timed trace (liefi imports it on the engine's first use)
from liefi.engine import cache, kernels
from scale import chain
N = int(sys.argv[1])
out = {}
t = t_first = time.process_time()
system, y0 = chain(N)
fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=10.0)
out["construction"] = time.process_time() - t
spent = [0.0]
load = cache.load
def timed_load(*a, **k):
    t = time.process_time(); got = load(*a, **k); spent[0] += time.process_time() - t; return got
cache.load = timed_load
t = time.process_time()
compiled = kernels.compile_split(fi)
out["trace"] = time.process_time() - t - spent[0]
out["load"] = spent[0]
out["nodes"] = compiled.nodes
t = time.process_time()
sol = fi.run(1.0, dt=1e-3, scheme="imex-rk4")
out["run"] = time.process_time() - t
out["first"] = time.process_time() - t_first
out["integrate"] = float(sol.cpu_seconds)
out["ns_per_step"] = 1e9 * float(sol.cpu_seconds) / 1000
out["rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
out["y_end"] = sol.y[:, -1].tolist()
print("RESULT " + json.dumps(out))
"""

COLUMNS = ("construction", "trace", "load", "integrate", "run", "first", "ns_per_step", "rss_mib", "nodes")


def _child(code, args, env, timeout):
    """The ``RESULT`` dict a fresh Python process running ``code`` prints; ``None`` (with the reason) on failure."""
    try:
        p = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=env,
                           timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        print(f"{args}: over {timeout} s, stopped", flush=True)
        return None
    got = [line for line in p.stdout.splitlines() if line.startswith("RESULT ")]
    if not got:
        print(f"{args} failed:\n{p.stderr[-2000:]}", flush=True)
        return None
    return json.loads(got[0][7:])


def _env(cache_dir=None, store=False):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    if cache_dir is not None:
        env["LIEFI_CACHE_DIR"] = cache_dir
    env["LIEFI_REFERENCE_STORE"] = "1" if store else "0"
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as an installed package runs
    return env


def measure(N, repeat, timeout, cache_dir=None, cold=False):
    """Best of ``repeat`` fresh processes at ``N`` (after one that fills the kernel cache ``cache_dir``); ``None``
    on failure.  ``cold``: every process starts from an empty kernel cache (its own temporary directory)."""
    best = None
    for i in range(repeat + (0 if cold else 1)):
        where = tempfile.mkdtemp(prefix="liefi-scale-cold-") if cold else cache_dir
        try:
            r = _child(_CASE, [str(N), os.path.dirname(os.path.abspath(__file__))], _env(where), timeout)
        finally:
            if cold:
                shutil.rmtree(where, ignore_errors=True)
        if r is None:
            return best
        if i == 0 and not cold and repeat > 0:
            continue  # fills the kernel cache
        best = r if best is None else {k: (min(best[k], r[k]) if k in COLUMNS else r[k]) for k in r}
    return best


_RATTLEBACK = r"""
import json, sys, time
PARTS = ("trace", "compile_load", "choose")
acc = dict.fromkeys(PARTS, 0.0)
stack = []


def start():
    stack.append([time.process_time(), 0.0])


def stop(part):  # the CPU of the call less the CPU of the calls inside it counted elsewhere
    t, inner = stack.pop()
    dt = time.process_time() - t
    acc[part] += dt - inner
    if stack:
        stack[-1][1] += dt


def wrap(part, f):
    def g(*a, **k):
        start()
        try:
            return f(*a, **k)
        finally:
            stop(part)
    return g


import liefi
import numba  # liefi imports it on first use; counted with the import
t_import = time.process_time()
from numba.core import event
kernel_compiles, compiling = {}, []


class _Compiles(event.Listener):  # numba's compile of each function, less the compiles nested in it
    def on_start(self, ev):
        compiling.append([ev.data["dispatcher"].py_func.__name__, time.process_time(), 0.0])

    def on_end(self, ev):
        name, t, inner = compiling.pop()
        dt = time.process_time() - t
        kernel_compiles[name] = kernel_compiles.get(name, 0.0) + dt - inner
        if compiling:
            compiling[-1][2] += dt


event.register("numba:compile", _Compiles())
from liefi.engine import cache, kernels, runners, trace
from liefi.integrator import policy, tolerance
cache.load, cache.find = wrap("compile_load", cache.load), wrap("compile_load", cache.find)
runners._Overhead._compile_call_timed = wrap("compile_load", runners._Overhead._compile_call_timed)
kernels.kernel_fingerprint = wrap("trace", kernels.kernel_fingerprint)
enter, leave = trace.trace.__enter__, trace.trace.__exit__
def traced_enter(self):
    start()
    return enter(self)
def traced_exit(self, *exc):
    try:
        return leave(self, *exc)
    finally:
        stop("trace")
trace.trace.__enter__, trace.trace.__exit__ = traced_enter, traced_exit
tolerance.chosen_step = policy.chosen_step = wrap("choose", tolerance.chosen_step)
from liefi import scenes
sc = scenes.get("rattleback")
if sys.argv[1] == "scene":
    res = sc.run(t_final=20.0, rtol=1e-6)
    integrate, scheme, dt = res.cpu_seconds, res.method["scheme"], res.dt
else:
    sol = sc.integrator().run((0.0, 20.0), rtol=1e-6)
    integrate, scheme, dt = sol.cpu_seconds, sol.method["scheme"], sol.dt
total = time.process_time()
out = {"total": total, "import": t_import, "integrate": integrate, **acc, "scheme": scheme, "dt": dt,
       "compiles": {k: round(v, 3) for k, v in sorted(kernel_compiles.items(), key=lambda kv: -kv[1]) if v >= 0.01}}
out["build"] = total - t_import - integrate - sum(acc.values())
print("RESULT " + json.dumps(out))
"""

_PEER = r"""
import json, sys
sys.path[:0] = [p for p in sys.argv[1:] if p]
from rattleback_pydy import build_model, cpu, generate, initial_state, integrate
model = build_model()
rhs, outputs, _ = generate(model, "pydy-cython")
sol, seconds = integrate(rhs, initial_state(), 20.0, "DOP853", 1e-12)
print("RESULT " + json.dumps({"total": cpu(), "integrate": seconds}))
"""

#: the rattleback's rows: (label, path, kernel cache, stored step)
RATTLEBACK_CASES = (("Scene.run, cold", "scene", "cold", False), ("Scene.run, warm", "scene", "warm", False),
                    ("Scene.run, warm, step stored", "scene", "warm", True), ("fi.run, cold", "fi", "cold", False),
                    ("fi.run, warm", "fi", "warm", False))
SPLIT = ("import", "build", "trace", "choose", "compile_load", "integrate")


def rattleback(repeat, timeout, pydy_path=None, cold_repeat=1):
    """The rattleback's time to result (module docstring), best of ``repeat`` rounds (the cold cases in the first
    ``cold_repeat`` rounds only: each compiles afresh); the rounds interleave the cases and the PyDy peer.
    Returns ``{label: result}`` (``None`` for a case that failed)."""
    warm = tempfile.mkdtemp(prefix="liefi-scale-warm-")
    stored = os.path.join(tempfile.mkdtemp(prefix="liefi-scale-stored-"), "kernels")
    here = os.path.dirname(os.path.abspath(__file__))
    try:
        _child(_RATTLEBACK, ["scene"], _env(warm), timeout)  # the kernels cached
        _child(_RATTLEBACK, ["fi"], _env(warm), timeout)
        shutil.copytree(warm, stored)  # the same kernels, and the step stored by one run
        _child(_RATTLEBACK, ["scene"], _env(stored, store=True), timeout)
        best = {}
        for round_ in range(repeat):
            for label, path, kernels, keep in RATTLEBACK_CASES:
                if kernels == "cold" and round_ >= cold_repeat:
                    continue
                cold = tempfile.mkdtemp(prefix="liefi-scale-cold-") if kernels == "cold" else None
                try:
                    r = _child(_RATTLEBACK, [path], _env(cold or (stored if keep else warm), store=keep), timeout)
                finally:
                    if cold:
                        shutil.rmtree(cold, ignore_errors=True)
                print(f"  {label}: {json.dumps(r)}", flush=True)
                if r is not None and (best.get(label) is None or r["total"] < best[label]["total"]):
                    best[label] = r
            env = _env()
            if pydy_path:  # also for the C build pydy runs in a process of its own
                env["PYTHONPATH"] = pydy_path + os.pathsep + env["PYTHONPATH"]
            r = _child(_PEER, [here, pydy_path or ""], env, timeout)
            print(f"  peer: {json.dumps(r)}", flush=True)
            if r is not None and (best.get("peer") is None or r["total"] < best["peer"]["total"]):
                best["peer"] = r
        return best
    finally:
        shutil.rmtree(warm, ignore_errors=True)
        shutil.rmtree(os.path.dirname(stored), ignore_errors=True)


def print_rattleback(best):
    peer = best.get("peer")
    print("\nRattleback, t in [0, 20], rtol 1e-6, fresh processes; CPU seconds, best of the rounds")
    print(f"| case | {' | '.join(SPLIT)} | total | peer / total | scheme, dt |")
    print("|---|" + "---|" * (len(SPLIT) + 3))
    for label, *_ in RATTLEBACK_CASES:
        r = best.get(label)
        if r is None:
            print(f"| {label} | failed |")
            continue
        ratio = f"{peer['total'] / r['total']:.2f}" if peer else "n/a"
        print(f"| {label} | " + " | ".join(f"{r[k]:.2f}" for k in SPLIT)
              + f" | {r['total']:.2f} | {ratio} | {r['scheme']}, {r['dt']:.3g} |")
    for label, _, kernels, _ in RATTLEBACK_CASES:
        r = best.get(label)
        if kernels == "cold" and r is not None and r.get("compiles"):
            print(f"numba's compile by function, {label} (CPU s, each less the compiles nested in it): "
                  + ", ".join(f"{k} {v:.2f}" for k, v in r["compiles"].items()))
    if peer:
        print(f"| PyDy peer (KanesMethod, Cython, DOP853 1e-12) | | | | | | {peer['integrate']:.2f} | "
              f"{peer['total']:.2f} | 1 | |")
    else:
        print("| PyDy peer | not measured (pydy not importable; --pydy-path) |")


def exponents(ns, rows, key, n_min=4):
    """Least-squares slope of ``log rows[key]`` against ``log N`` over ``N >= n_min`` (``nan`` below 2 points)."""
    pts = [(np.log(n), np.log(r[key])) for n, r in zip(ns, rows) if r is not None and n >= n_min and r[key] > 0]
    if len(pts) < 2:
        return float("nan")
    x, y = np.array(pts).T
    return float(np.polyfit(x, y, 1)[0])


def profile(N, top=40):
    """cProfile of the trace and code generation of the chain at ``N``, sorted by cumulative time."""
    import cProfile
    import pstats

    import liefi
    from liefi.engine import kernels

    system, y0 = chain(N)
    fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=10.0)
    from liefi.engine import cache

    cache.load = lambda source, engine="numba": _NoLoad()  # the trace only
    pr = cProfile.Profile()
    pr.enable()
    try:
        kernels.compile_split(fi, engine="python")
    except Exception:  # noqa: BLE001 -- the stand-in kernel is not a real one
        pass
    pr.disable()
    pstats.Stats(pr).sort_stats("cumulative").print_stats(top)


class _NoLoad:
    def claim(self):
        return False


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64])
    ap.add_argument("--cold-n", type=int, nargs="*", default=None,
                    help="the N measured cold (default: every N; the cold runs are the long ones)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cold-repeat", type=int, default=1,
                    help="cold processes per N, and rounds with the rattleback's cold cases (each compiles afresh)")
    ap.add_argument("--timeout", type=float, default=1800.0)
    ap.add_argument("--profile", type=int, default=None, metavar="N")
    ap.add_argument("--no-chain", action="store_true")
    ap.add_argument("--no-rattleback", action="store_true")
    ap.add_argument("--pydy-path", default=None, help="a folder to put first on the peer's sys.path (a private pydy)")
    args = ap.parse_args(argv)
    if args.profile is not None:
        profile(args.profile)
        return
    from _machine import cpu_model  # benchmarks/_machine.py (here: the chain imports from its path alone)

    print(f"CPU: {cpu_model()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; CPU seconds, best of "
          f"{args.repeat} fresh processes (warm: after one that filled a kernel cache of this benchmark's own)")
    if not args.no_chain:
        chain_table(args)
    if not args.no_rattleback:
        print_rattleback(rattleback(args.repeat, args.timeout, args.pydy_path, args.cold_repeat))
    print(f"load at the end {os.getloadavg()[0]:.1f}")


def chain_table(args):
    """The chain's table: warm (best of ``--repeat``) and cold (``--cold-repeat``) first runs, by ``N``."""
    head = f"{'N':>4} {'states':>6} {'build s':>8} {'trace s':>8} {'load s':>8} {'integ s':>8} {'run s':>8} " \
           f"{'first s':>8} {'cold s':>8} {'ns/step':>8} {'RSS MiB':>8} {'cold MiB':>8} {'nodes':>8}"
    print("first = construction + trace + load + the first fi.run (warm kernel cache); cold = the same from an "
          "empty kernel cache; RSS = the process's peak", flush=True)
    print(head, flush=True)
    rows, colds = [], []
    warm = tempfile.mkdtemp(prefix="liefi-scale-warm-")
    try:
        for N in args.n:
            r = measure(N, args.repeat, args.timeout, cache_dir=warm)
            c = measure(N, args.cold_repeat, args.timeout, cold=True) \
                if args.cold_n is None or N in args.cold_n else None
            rows.append(r)
            colds.append(c)
            if r is not None:
                cold = (f"{c['first']:>8.2f}", f"{c['rss_mib']:>8.0f}") if c else (f"{'-':>8}", f"{'-':>8}")
                print(f"{N:>4} {6 * N:>6} {r['construction']:>8.3f} {r['trace']:>8.3f} {r['load']:>8.3f} "
                      f"{r['integrate']:>8.3f} {r['run']:>8.3f} {r['first']:>8.2f} {cold[0]} {r['ns_per_step']:>8.0f} "
                      f"{r['rss_mib']:>8.0f} {cold[1]} {r['nodes']:>8}", flush=True)
    finally:
        shutil.rmtree(warm, ignore_errors=True)
    print("growth N^a (N >= 4): " + ", ".join(
        f"{k} {exponents(args.n, rows, k):.2f}" for k in ("construction", "trace", "integrate", "run", "first",
                                                           "rss_mib", "nodes"))
          + f", cold first {exponents(args.n, colds, 'first'):.2f}")


if __name__ == "__main__":
    main()
