"""Build time of ``liefi.from_mechanics`` against sympy's own equations, one row per corpus model.

* ``sympy [s]``: CPU time of sympy's ``kanes_equations`` / ``form_lagranges_equations`` / ``System.form_eoms``
  while the model is written (the calls are timed where they happen);
* ``from_mechanics [s]``: CPU time of liefi's build right after;
* ``ratio``: ``from_mechanics / sympy``;
* ``warm``: ``from_mechanics`` after one trivial ``sympy.lambdify(..., modules="numpy")`` in the process, which
  imports sympy's code printers and runs sympy's one-time ``from numpy import *`` (it imports ``numpy.f2py``,
  ``numpy.testing`` ...: about 0.2 s).  sympy's equations never lambdify, so the first column counts the printers'
  import in liefi's build; liefi itself hands lambdify the numpy module object and never runs that star import
  (``liefi.systems.sympy_input.lambdify_checked``), so it is not in either column of a current checkout (an older
  one paid it in the first column).

Each number is the best of ``--repeat`` (3) runs, each in a fresh Python process (so sympy's cache starts
empty every time).  Run from the repository root: ``python benchmarks/build_time.py [name ...]``; compare
two checkouts with ``PYTHONPATH=<checkout> python benchmarks/build_time.py``.
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent

MODELS = {  # name: (test module, factory expression)
    "Kane pendulum (LU)": ("test_mechanics_holonomic", "kane_pendulum"),
    "Lagrange pendulum": ("test_mechanics_holonomic", "lagrange_pendulum"),
    "four-bar linkage": ("test_mechanics_holonomic", "four_bar"),
    "four-bar + gravity": ("test_mechanics_holonomic", "four_bar_gravity"),
    "disc on an incline": ("test_mechanics_holonomic", "disc_on_incline"),
    "sleigh, Lagrange hol + nonhol": ("test_mechanics_holonomic", "lagrange_sleigh"),
    "sleigh, System hol + nonhol": ("test_mechanics_holonomic", "system_sleigh"),
    "disc, Kane minimal": ("test_mechanics_minimal", "disc_kane"),
    "disc, Kane aux": ("test_mechanics_minimal", "disc_kane_aux"),
    "disc, Lagrange": ("test_mechanics_minimal", "disc_lagrange"),
    "disc, System": ("test_mechanics_minimal", "disc_system"),
    "sleigh, minimal": ("test_mechanics_minimal", "sleigh_minimal"),
    "sleigh, body speeds": ("test_mechanics_minimal", "lambda: T.sleigh_offset(body_speeds=True)"),
    "rattleback": ("test_mechanics_minimal", "rattleback"),
}


def _one(name, warm=False):
    """In this process: build the model (timing sympy's equations) and then liefi's system; print JSON."""
    sys.path.insert(0, str(ROOT / "tests"))
    import importlib

    import sympy.physics.mechanics as me

    import liefi

    spent, depth = [0.0], [0]

    def timed(f):
        def wrapper(*a, **k):
            depth[0] += 1
            t0 = time.process_time()
            try:
                return f(*a, **k)
            finally:
                depth[0] -= 1
                if depth[0] == 0:
                    spent[0] += time.process_time() - t0
        return wrapper

    me.KanesMethod.kanes_equations = timed(me.KanesMethod.kanes_equations)
    me.LagrangesMethod.form_lagranges_equations = timed(me.LagrangesMethod.form_lagranges_equations)
    me.System.form_eoms = timed(me.System.form_eoms)
    module, factory = MODELS[name]
    T = importlib.import_module(module)  # noqa: N806
    make = eval(factory, {"T": T}) if factory.startswith("lambda") else getattr(T, factory)
    made = make()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    if warm:
        import sympy

        x = sympy.Symbol("x")
        sympy.lambdify([x], [x], modules="numpy")
    t0 = time.process_time()
    liefi.from_mechanics(model, consts)
    build = time.process_time() - t0
    print(json.dumps(dict(sympy=spent[0], build=build)))


def measure(name, repeat=3, warm=False):
    """``(sympy, from_mechanics)`` CPU seconds: the best of ``repeat`` fresh processes."""
    env = dict(os.environ)
    env.setdefault("PYTHONPATH", str(ROOT))
    runs = []
    for _ in range(repeat):
        out = subprocess.run([sys.executable, __file__, "--one", name] + ["--warm"] * warm, env=env, capture_output=True, text=True,
                             check=True)
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    return min(r["sympy"] for r in runs), min(r["build"] for r in runs)


def main(argv):
    if argv[:1] == ["--one"]:
        return _one(argv[1], warm="--warm" in argv)
    repeat = 3
    if argv[:1] == ["--repeat"]:
        repeat, argv = int(argv[1]), argv[2:]
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _machine import cpu_model

    import liefi

    print(f"CPU: {cpu_model()}; liefi from {pathlib.Path(liefi.__file__).parent}; best of {repeat} fresh processes")
    print("| model | sympy's equations [s] | from_mechanics [s] | ratio | from_mechanics, warm [s] | ratio, warm |")
    print("|---|---|---|---|---|---|")
    for name in argv or MODELS:
        s, b = measure(name, repeat)
        s_w, w = measure(name, repeat, warm=True)
        s = min(s, s_w)
        print(f"| {name} | {s:.3f} | {b:.3f} | {b / s:.1f} | {w:.3f} | {w / s:.1f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
