"""``liefi.from_mechanics``: time to build, and the generated data against hand-written numpy data.

For the rolling disk (``KanesMethod``), the Chaplygin sleigh (``LagrangesMethod``) and the
knife edge (``System``), written as in ``tests/test_mechanics.py``:

* the time to write the model in sympy and the time of ``from_mechanics`` (best of 3);
* one field evaluation and a 1000-step RK4 run of the generated system against the same
  system written by hand in numpy (``tests/test_mechanics.py``), interleaved, best of 5 / 3:
  the ratio generated / hand;
* a mass sweep of the sleigh: one ensemble run of 8 members against 8 separate runs
  (interleaved, best of 3).

Run from the repository root: ``python benchmarks/mechanics.py``.
"""

from __future__ import annotations

import importlib.util
import pathlib
import sys
import time
import warnings

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # tests/test_mechanics.py imports its models from tests/models.py

import liefi  # noqa: E402


def _tests():
    spec = importlib.util.spec_from_file_location("test_mechanics", ROOT / "tests" / "test_mechanics.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def best(fun, repeat):
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fun()
        out.append(time.perf_counter() - t)
    return min(out)


def interleaved(funs, repeat):
    times = {k: [] for k in funs}
    for _ in range(repeat):
        for k, f in funs.items():
            t = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t)
    return {k: min(v) for k, v in times.items()}


def main():
    T = _tests()
    cases = {
        "rolling disk (KanesMethod)": (T.disk_model, lambda s: {s[0]: 1.0, s[1]: 0.5, s[2]: 9.81},
                                       lambda: T.disk_by_hand(1.0, 0.5, 9.81),
                                       lambda sys_: sys_.state([0.0, 0.2, 0.0, 0.0, 0.0], u=[0.0, 4.0, 0.3]), 1.0),
        "Chaplygin sleigh (LagrangesMethod)": (T.sleigh_model, lambda s: {s[0]: 1.0, s[1]: 1.0, s[2]: 0.5},
                                               lambda: T.sleigh_by_hand(1.0, 1.0, 0.5),
                                               lambda sys_: sys_.state(np.zeros(3), [0.5, 0.0, 1.0]), 10.0),
        "knife edge (System)": (T.knife_model, lambda s: {s[0]: 1.0, s[1]: 1.0, s[2]: 1.0, s[3]: np.pi / 6},
                                lambda: liefi.scenes.get("knife-edge").system,
                                lambda sys_: np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5]), 10.0),
    }
    print("| model | write in sympy [s] | from_mechanics [s] | field: generated / hand | 1000 RK4 steps: generated [s] | hand [s] | ratio |")
    print("|---|---|---|---|---|---|---|")
    for name, (model, consts, hand, start, gains) in cases.items():
        t_model = best(model, 3)
        built = {}

        def build():
            m, syms = model()
            built["sys"] = liefi.from_mechanics(m, consts(syms))

        t_build = best(build, 3)
        gen, ref = built["sys"], hand()
        z0 = start(gen)
        fa = liefi.FeedbackIntegrator(gen, z0, gains=gains)
        fb = liefi.FeedbackIntegrator(ref, z0, gains=gains)
        field = interleaved({"gen": lambda: [fa.vector_field(z0) for _ in range(100)],
                             "hand": lambda: [fb.vector_field(z0) for _ in range(100)]}, 5)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run = interleaved({"gen": lambda: fa.run(1.0, dt=1e-3, scheme="rk4"), "hand": lambda: fb.run(1.0, dt=1e-3, scheme="rk4")}, 3)
        print(f"| {name} | {t_model:.3f} | {t_build:.3f} | {field['gen'] / field['hand']:.2f} | "
              f"{run['gen']:.2f} | {run['hand']:.2f} | {run['gen'] / run['hand']:.2f} |")

    m, syms = T.sleigh_model()
    sled = liefi.from_mechanics(m, {syms[0]: 1.0, syms[1]: 1.0, syms[2]: 0.5})
    masses = np.linspace(0.5, 4.0, 8)
    q0, v0 = np.zeros(3), np.array([0.5, 0.0, 1.0])

    def ensemble():
        sled.constants = {"m": masses}
        z = sled.state(np.broadcast_to(q0, (8, 3)), np.broadcast_to(v0, (8, 3)))
        return liefi.FeedbackIntegrator(sled, z, gains=10.0).run(1.0, dt=1e-3, scheme="rk4")

    def separate():
        out = []
        for mk in masses:
            sled.constants = {"m": mk}
            z = sled.state(q0, v0)
            out.append(liefi.FeedbackIntegrator(sled, z, gains=10.0).run(1.0, dt=1e-3, scheme="rk4"))
        return out

    sweep = interleaved({"ensemble": ensemble, "separate": separate}, 3)
    print(f"\nmass sweep of the sleigh, 8 members x 1000 RK4 steps: one ensemble run {sweep['ensemble']:.2f} s, "
          f"8 separate runs {sweep['separate']:.2f} s (ratio {sweep['separate'] / sweep['ensemble']:.1f}x)")


if __name__ == "__main__":
    main()
