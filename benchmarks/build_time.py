"""Build time of ``liefi.from_mechanics`` against sympy's own equations, one row per corpus model.

* ``sympy [s]``: CPU time of sympy's ``kanes_equations`` / ``form_lagranges_equations`` / ``System.form_eoms``
  while the model is written (the calls are timed where they happen): issue 25's yardstick;
* ``sympy, method too [s]``: the same plus the construction of the ``KanesMethod`` / ``LagrangesMethod``
  (where sympy solves the kinematic equations and the dependent speeds; ``System.form_eoms`` builds its method
  inside, so the two columns agree for a System);
* ``from_mechanics [s]``: CPU time of liefi's build right after;
* ``ratio``: ``from_mechanics / sympy``; ``ratio, method too``: ``from_mechanics`` over the second column.

liefi generates its data functions itself (``liefi.systems._sympy_code``: no ``lambdify``, no sympy printers
imported), computes the kernel fingerprint of the system only when the compiled engine asks for it, and pauses
Python's cyclic garbage collector during the build (collections resume after it); sympy's calls are timed with
the collector on, as a user runs them.

Each number is the best of ``--repeat`` (3) runs, each in a fresh Python process (so sympy's cache starts
empty every time), with Python's bytecode cache on as in an installation (``PYTHONDONTWRITEBYTECODE`` is
dropped from the runs' environment: with it, every liefi module the build imports on first use was compiled
from source in every run, 4 ms of the Kane pendulum's build, a cost no installed liefi has).  Run from the
repository root: ``python benchmarks/build_time.py [name ...]``; compare two checkouts with
``PYTHONPATH=<checkout> python benchmarks/build_time.py``.
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


def _one(name):
    """In this process: build the model (timing sympy's equations) and then liefi's system; print JSON."""
    sys.path.insert(0, str(ROOT / "tests"))
    import importlib

    import sympy.physics.mechanics as me

    import liefi

    spent, depth = {"eqs": 0.0, "all": 0.0}, {"eqs": 0, "all": 0}

    def timed(f, *keys):
        def wrapper(*a, **k):
            t0 = time.process_time()
            for key in keys:
                depth[key] += 1
            try:
                return f(*a, **k)
            finally:
                for key in keys:
                    depth[key] -= 1
                    if depth[key] == 0:
                        spent[key] += time.process_time() - t0
        return wrapper

    me.KanesMethod.kanes_equations = timed(me.KanesMethod.kanes_equations, "eqs", "all")
    me.LagrangesMethod.form_lagranges_equations = timed(me.LagrangesMethod.form_lagranges_equations, "eqs", "all")
    me.System.form_eoms = timed(me.System.form_eoms, "eqs", "all")
    me.KanesMethod.__init__ = timed(me.KanesMethod.__init__, "all")
    me.LagrangesMethod.__init__ = timed(me.LagrangesMethod.__init__, "all")
    module, factory = MODELS[name]
    T = importlib.import_module(module)  # noqa: N806
    make = eval(factory, {"T": T}) if factory.startswith("lambda") else getattr(T, factory)
    made = make()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    t0 = time.process_time()
    liefi.from_mechanics(model, consts)
    build = time.process_time() - t0
    print(json.dumps(dict(sympy=spent["eqs"], method=spent["all"], build=build)))


def measure(name, repeat=3):
    """``(sympy's equations, with the method built too, from_mechanics)`` CPU seconds: the best of ``repeat`` fresh
    processes each."""
    env = dict(os.environ)
    env.setdefault("PYTHONPATH", str(ROOT))
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # bytecode cached as installed (see the module docstring)
    runs = []
    for _ in range(repeat):
        out = subprocess.run([sys.executable, __file__, "--one", name], env=env, capture_output=True, text=True,
                             check=True)
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    return tuple(min(r[k] for r in runs) for k in ("sympy", "method", "build"))


def main(argv):
    if argv[:1] == ["--one"]:
        return _one(argv[1])
    repeat = 3
    if argv[:1] == ["--repeat"]:
        repeat, argv = int(argv[1]), argv[2:]
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _machine import cpu_model

    import liefi

    print(f"CPU: {cpu_model()}; liefi from {pathlib.Path(liefi.__file__).parent}; best of {repeat} fresh processes")
    print("| model | sympy's equations [s] | sympy, method too [s] | from_mechanics [s] | ratio | ratio, method too |")
    print("|---|---|---|---|---|---|")
    for name in argv or MODELS:
        s, s_all, b = measure(name, repeat)
        print(f"| {name} | {s:.3f} | {s_all:.3f} | {b:.3f} | {b / s:.1f} | {b / s_all:.1f} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
