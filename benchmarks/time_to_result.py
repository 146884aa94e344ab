"""Time to result: wall time of ``liefi run SCENE --json`` in fresh processes, for every scene.

Run (from the repository root; a few minutes)::

    python benchmarks/time_to_result.py                  # cold and warm, best of 3, every scene
    python benchmarks/time_to_result.py --split          # also where the warm time goes
    python benchmarks/time_to_result.py --cold-repeat 1 rigid-body suslov

For each scene, at its defaults:

* **cold**: the first call with an empty cache directory (``LIEFI_CACHE_DIR`` a
  fresh temporary directory): kernels compiled, the reference solved;
* **warm**: a later call in a fresh process with that directory kept (kernels
  loaded from numba's cache, the reference read from the reference store).

Wall time is what a user waits; CPU time (user + system of the child) is printed
next to it because on a busy machine the wall time mostly measures the queue.
The calls run as an installed package does: Python writes and reads the
modules' ``.pyc`` files (``PYTHONDONTWRITEBYTECODE`` is dropped for them).

Every call is a new ``python -m liefi run SCENE --json`` process (its whole wall
time: interpreter start, imports, run, output), best of ``--repeat`` (warm) and
``--cold-repeat`` (cold, a new empty directory each time).  ``--split`` adds one
more warm call per scene, in a process that times its phases: *import* (liefi's
CLI and numba), *kernel load* (numba dispatchers loading from
the cache), *reference* (solving or reading the reference), *run* (the rest of
``liefi run``: building the system, choosing the step, integrating, invariants)
and *output* (the JSON).  The table is printed in markdown.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")

#: the phases ``--split`` reports, timed inside one warm process
_SPLIT = r"""
import json, sys, time
t0 = time.perf_counter()
import liefi.cli
try:
    import numba
except ImportError:
    pass

t_import = time.perf_counter() - t0
acc = {"kernel load": 0.0, "reference": 0.0, "output": 0.0}

def timed(owner, name, phase):
    f = getattr(owner, name)
    def wrapper(*a, **k):
        s = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            acc[phase] += time.perf_counter() - s
    setattr(owner, name, wrapper)

try:
    from numba.core.dispatcher import Dispatcher
    timed(Dispatcher, "compile", "kernel load")
except ImportError:
    pass
from liefi.scenes.base import Scene
timed(Scene, "reference_values", "reference")
timed(liefi.cli._json, "dumps", "output")
import io, contextlib
s = time.perf_counter()
with contextlib.redirect_stdout(io.StringIO()):
    code = liefi.cli.main(["run", sys.argv[1], "--json"])
total = time.perf_counter() - s
acc["run"] = total - sum(acc.values())
acc["import"] = t_import
print(json.dumps(acc))
"""


def _call(scene, cache_dir, split=False):
    """``(wall seconds, CPU seconds, split or None)`` of one ``liefi run SCENE --json`` in a new process."""
    env = dict(os.environ, LIEFI_CACHE_DIR=cache_dir)
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as an installed package: modules load from their .pyc
    cmd = [sys.executable, "-c", _SPLIT, scene] if split else [sys.executable, "-m", "liefi", "run", scene, "--json"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[:3])} {scene} failed ({out.returncode}): {out.stderr.strip()[-400:]}")
    return wall, cpu, (json.loads(out.stdout.strip().splitlines()[-1]) if split else None)


def scenes():
    out = subprocess.run([sys.executable, "-m", "liefi", "list"], cwd=ROOT, capture_output=True, text=True, check=True)
    return [line.split()[0] for line in out.stdout.splitlines() if line.strip()]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", help="scenes (default: every scene of `liefi list`)")
    ap.add_argument("--repeat", type=int, default=3, help="warm calls per scene (best of; default 3)")
    ap.add_argument("--cold-repeat", type=int, default=3, help="cold calls per scene (best of; default 3)")
    ap.add_argument("--split", action="store_true", help="also time the phases of one warm call per scene")
    ap.add_argument("--cache-dir", default=None, metavar="DIR",
                    help="measure warm calls only, with this cache directory (kept; no cold call)")
    args = ap.parse_args(argv)
    names = args.scenes or scenes()
    rows = []
    for name in names:
        cold, warm = [(math.nan, math.nan)], []
        with tempfile.TemporaryDirectory(prefix="liefi-ttr-") as tmp:
            keep = args.cache_dir or tmp
            for _ in range(0 if args.cache_dir else max(1, args.cold_repeat)):
                with tempfile.TemporaryDirectory(prefix="liefi-ttr-") as fresh:
                    cold.append(_call(name, fresh)[:2])
            cold = cold[1:] or cold
            _call(name, keep)  # fill the cache
            warm = [_call(name, keep)[:2] for _ in range(max(1, args.repeat))]
            split = _call(name, keep, split=True)[2] if args.split else None
        rows.append((name, min(cold), min(warm), split))
        print(f"{name}: cold {min(cold)[0]:.2f} s, warm {min(warm)[0]:.2f} s", file=sys.stderr, flush=True)
    phases = ("import", "kernel load", "reference", "run", "output")
    head = "| scene | cold wall (s) | cold CPU (s) | warm wall (s) | warm CPU (s) |"
    print(head + ("".join(f" {p} |" for p in phases) if args.split else ""))
    print("|---|" + "---:|" * (4 + (len(phases) if args.split else 0)))
    for name, c, w, split in rows:
        extra = "".join(f" {split[p]:.2f} |" for p in phases) if split else ""
        print(f"| {name} | {c[0]:.2f} | {c[1]:.2f} | {w[0]:.2f} | {w[1]:.2f} |{extra}")
    worst = max(rows, key=lambda r: r[2][0])
    print(f"\nslowest warm call: {worst[2][0]:.2f} s wall ({worst[0]}); load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
