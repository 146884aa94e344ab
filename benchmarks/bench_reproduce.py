"""Time ``liefi reproduce`` at the paper's settings with the compiled engine, first run included.

Run::

    python benchmarks/bench_reproduce.py                 # fresh kernel cache: compile included
    python benchmarks/bench_reproduce.py --warm          # reuse ~/.cache/liefi (second run)
    python benchmarks/bench_reproduce.py --backend numpy # the reference path, for comparison

``liefi reproduce`` runs every scene through ``Scene.run -> FeedbackIntegrator.run``,
whose backend is ``"auto"`` when numba is installed; ``--backend`` forces one by
wrapping ``FeedbackIntegrator.run`` (the oscillator's DLA runs are stepped by the
compiled DLA kernel too).  With the default fresh cache (a temporary
``LIEFI_CACHE_DIR``) every kernel is traced and compiled in the run, as on a first
installation.  Prints wall and CPU seconds and the per-experiment table of
``liefi reproduce``.  The command itself, timed the same way:
``LIEFI_CACHE_DIR=$(mktemp -d) time liefi reproduce --out OUT``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))


def _compiled_dla():
    """Make the oscillator scene's ``run_extra("dla")`` step with the compiled DLA kernel."""
    import numpy as np

    from liefi import engine, scenes
    from liefi.schemes.dla_integrator import DLAIntegrator

    sc = scenes.get("oscillator")
    cls = type(sc)
    orig = cls.run_extra

    def run_extra(self, scheme, variant, dt, T, save_every, fi):
        if scheme != "dla" or not engine.available():
            return orig(self, scheme, variant, dt, T, save_every, fi)
        n = self.system.space.n
        y0 = np.asarray(self.initial_state(variant), float)
        q0, q1 = DLAIntegrator.from_system(self.system).initial_pair(y0[:n], y0[n:], dt)
        t, q, p, cpu, updates = engine.compile_dla(self.system).run(q0, q1, dt, int(round(T / dt)), save_every=save_every)
        return t, np.concatenate([q, p], 0), self.system.state_names, cpu, updates, updates

    cls.run_extra = run_extra


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", default="auto", choices=("auto", "numba", "numpy"))
    ap.add_argument("--warm", action="store_true", help="keep the user's kernel cache (not a first run)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--only", default=None)
    ap.add_argument("--compiled-dla", action="store_true", dest="compiled_dla",
                    help="step the oscillator's DLA runs with liefi.engine.compile_dla (the wiring proposed "
                         "for OscillatorScene.run_extra) instead of liefi.dla's numpy loop")
    a = ap.parse_args(argv)
    if not a.warm:
        os.environ["LIEFI_CACHE_DIR"] = tempfile.mkdtemp(prefix="liefi-fresh-cache-")
    out = a.out or tempfile.mkdtemp(prefix="liefi-reproduce-")
    def cpu_now():  # this process and its worker processes (liefi reproduce runs scenes in parallel)
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system

    w0, c0 = time.perf_counter(), cpu_now()

    import liefi.integrator.feedback as F
    from liefi import reproduce

    orig = F.FeedbackIntegrator.run

    def run(self, *args, backend=a.backend, **kw):
        return orig(self, *args, backend=backend, **kw)

    F.FeedbackIntegrator.run = run
    if a.compiled_dla:
        _compiled_dla()
    only = a.only.split(",") if a.only else None
    summary = reproduce.reproduce(out, only=only)
    wall, cpu = time.perf_counter() - w0, cpu_now() - c0
    print(reproduce.markdown_table(summary))
    print(f"\nliefi reproduce, backend={a.backend}, {'warm' if a.warm else 'fresh'} kernel cache: "
          f"{wall:.1f} s wall, {cpu:.1f} s CPU (load average {os.getloadavg()[0]:.1f}); figures in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
