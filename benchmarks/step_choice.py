"""The cost and the accuracy of choosing the step for a tolerance (issue 26).

Two tables, CPU time (``time.process_time``) in one process, kernels loaded first (a warm-up choice and run
per case: the figures are what choosing costs, not what loading the kernels costs):

1. ``--default``: every scene's default ``liefi run`` (its ``t_final``, ``rtol`` 1e-6, the order chosen, the
   default backend): the CPU of choosing the step and of the integration, and their ratio.  The target is
   ``choose <= max(integrate, 50 ms)``.
2. ``--accuracy``: Suslov, the rigid body, Kepler, the Chaplygin ball and the rattleback over ``[0, 20]`` at
   ``rtol`` 1e-4, 1e-6, 1e-8: the chosen scheme and step, the achieved error against the scene's independent
   reference (its closed form, or DOP853 at the scene's ``reference_rtol``), the error over ``rtol`` (the target
   is ``[1/30, 1]``) and what ``method["why"]`` names as setting the step.

The achieved error is the largest over the scene's compared components of ``max_t |y_k - y_k_ref| / max_t
|y_k_ref|`` (as ``benchmarks/rtol_table.py``).  No stored step is read (``LIEFI_REFERENCE_STORE=0``).

    python benchmarks/step_choice.py [--default] [--accuracy] [--scenes=a,b] [--backend=numpy]
"""
import os
import sys
import time
import warnings

os.environ["LIEFI_REFERENCE_STORE"] = "0"  # choose every time: no step stored by an earlier run
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

from liefi import scenes  # noqa: E402

warnings.simplefilter("ignore")
ACCURACY_SCENES = ("suslov", "rigid-body", "kepler", "chaplygin-ball", "rattleback")
ACCURACY_RTOLS = (1e-4, 1e-6, 1e-8)


def choose_cpu(fi, T, rtol, backend):
    """``(cpu, dt, info)``: the CPU of choosing the step for ``rtol`` over ``[0, T]`` (the order chosen, as
    ``Scene.run``, ``fi.run`` and ``liefi run`` choose it), best of 2, the kernels of ``fi`` loaded first."""
    from liefi.integrator.run import _fixed_step_scheme
    from liefi.integrator.tolerance import ORDER_SCHEMES, choose_step, unforced_field
    from liefi.engine.kernels import prepare_feedback

    if backend != "numpy":  # trace and load the kernels now: their cost is the run's, not the choice's
        unforced_field(fi, np.asarray(fi.y0, float)[None], backend)
        for sch in ORDER_SCHEMES["split"]:
            prepare_feedback(fi, sch, fi.y0, backend)
    best = None
    for _ in range(2):
        t = time.process_time()
        dt, info = choose_step(fi, _fixed_step_scheme("imex-rk4"), fi.y0, 0.0, T, rtol, choose_order=True,
                               backend=backend)
        c = time.process_time() - t
        best = c if best is None else min(best, c)
    return best, dt, info


def achieved(sc, res):
    """The largest relative error of the run against the scene's reference (module docstring)."""
    return max(res.max_error[k] / max(np.max(np.abs(res[k] - res.errors[k])) if k in res.names else 1.0, 1e-300)
               for k in res.max_error)


def case(name, T, rtol, backend):
    sc = scenes.get(name)
    fi = sc.integrator(sc.variant(None), gains="auto")
    c, dt, info = choose_cpu(fi, T, rtol, backend)
    kw = dict(t_final=T, rtol=rtol, backend=backend)
    sc.run(**kw)  # the warm-up: the scene's own integrator's kernels loaded, the reference computed and kept
    res = sc.run(**kw)  # the step chosen once (kept on the scene): the run alone
    assert res.dt == dt, (res.dt, dt)  # the scene chooses as choose_step on its integrator does
    return dict(choose=c, run=res.cpu_seconds, scheme=res.scheme, dt=res.dt, steps=res.steps,
                err=achieved(sc, res), why=res.method.get("why", ""), info=info)


def binding(why):
    i = why.find("the step is set by ")
    return why[i + len("the step is set by "):].split(";")[0][:70] if i >= 0 else "?"


def main():
    args = sys.argv[1:]
    opts = dict(a[2:].split("=", 1) for a in args if a.startswith("--") and "=" in a)
    backend = opts.get("backend", "auto")
    want_default = "--default" in args or "--accuracy" not in args
    want_acc = "--accuracy" in args or "--default" not in args
    if want_default:
        names = opts["scenes"].split(",") if "scenes" in opts else scenes.names()
        print(f"default `liefi run` (t_final of the scene, rtol 1e-6, order chosen), backend {backend}")
        print("| scene | T | scheme | dt | steps | choose CPU s | integrate CPU s | choose / max(int, 0.05) |")
        print("|---|---|---|---|---|---|---|---|")
        for n in names:
            sc = scenes.get(n)
            try:
                r = case(n, sc.t_final, 1e-6, backend)
            except Exception as exc:  # a row that fails says why and the table goes on
                print(f"| {n} | failed: {type(exc).__name__}: {str(exc)[:100]} |||||||", flush=True)
                continue
            print(f"| {n} | {sc.t_final:g} | {r['scheme']} | {r['dt']:.4g} | {r['steps']} | {r['choose']:.3f} | "
                  f"{r['run']:.3f} | {r['choose'] / max(r['run'], 0.05):.2f} |", flush=True)
    if want_acc:
        names = opts["scenes"].split(",") if "scenes" in opts else ACCURACY_SCENES
        print(f"\naccuracy over [0, 20], backend {backend}")
        print("| scene | rtol | scheme | dt | steps | choose CPU s | integrate CPU s | error | error / rtol | "
              "set by |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for n in names:
            for rtol in ACCURACY_RTOLS:
                try:
                    r = case(n, 20.0, rtol, backend)
                except Exception as exc:
                    print(f"| {n} | {rtol:.0e} | failed: {type(exc).__name__}: {str(exc)[:100]} ||||||||",
                          flush=True)
                    continue
                print(f"| {n} | {rtol:.0e} | {r['scheme']} | {r['dt']:.4g} | {r['steps']} | {r['choose']:.3f} | "
                      f"{r['run']:.3f} | {r['err']:.2e} | {r['err'] / rtol:.3g} | {binding(r['why'])} |",
                      flush=True)


if __name__ == "__main__":
    main()
