"""The models of sympy's own mechanics test suite, handed to ``liefi.from_mechanics`` as they are.

The models are collected by running sympy's own test functions (``sympy/physics/mechanics/tests/test_*.py`` of
the installed sympy, imported, never copied): ``KanesMethod.kanes_equations``,
``LagrangesMethod.form_lagranges_equations`` and ``System.form_eoms`` are wrapped for the run, and every model
whose equations were formed is kept (the outermost call: a ``System`` rather than the ``KanesMethod`` it forms
inside; one row per model object, the last call).  Each model is then handed to ``from_mechanics`` with its
symbolic parameters set to values in ``[0.5, 1.4]`` (``g = 9.81``), from a start at random coordinates (the
dependent ones solved from the configuration constraints) and random independent speeds, and:

* ``built``: the model's own equations (``mass_matrix_full \\ forcing_full``, the dependent speeds solved from the
  velocity constraints at each evaluation, the auxiliary speeds zero) and liefi's constrained field, both
  DOP853 at 1e-12 over ``[0, 2]``, agree to 1e-8 in ``(q, q')`` (relative to ``max(1, |q'|)``), and along liefi's
  run (imex-rk8, ``dt = 0.01``) the model's declared constraints (``f``, velocity) and the energy hold to 1e-12;
* ``wrong``: built, but outside those bounds;
* ``refused``: ``from_mechanics`` raised one of liefi's named errors (a ``ValueError``/``TypeError`` subclass raised
  by liefi with a message that says what to do);
* ``crashed``: any other exception, or one raised outside liefi's own code;
* ``no reference``: the model's own equations could not be integrated from the start (a singular mass matrix
  or velocity-constraint block there);
* ``run failed``: liefi's run (``IntegrationError``) met non-finite values (a start that reaches a singular
  configuration of the model's coordinates within ``[0, 2]``).

``reason`` also carries liefi's warnings on the model (``model: ...``), e.g. where the model's own equations differ
from its velocities (a stored acceleration that is not their derivative).

Columns: sympy's equations [s] (CPU, the wrapped call), ``from_mechanics`` [s] (CPU), error, the drifts.
Run from the repository root: ``python benchmarks/mechanics_corpus.py [--skip-slow] [--json out.json] [filter ...]``
(``filter``: substrings of ``file::test_function``, any of them); about 10 CPU minutes on a 2-core machine.
"""

from __future__ import annotations

import json
import math
import pathlib
import re
import signal
import sys
import time
import traceback
import warnings
import zlib

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import sympy  # noqa: E402
import sympy.physics.mechanics as me  # noqa: E402

import liefi  # noqa: E402
from own_equations import collect, compare, constants_of, value  # noqa: E402

SLOW = {"test_kane3"}  # the bicycle (its kanes_equations and its run: about a minute)
TIMEOUT = 900  # seconds per model (build and comparison)


def start(model, seed):
    m = model.eom_method if isinstance(model, me.System) else model
    rng = np.random.default_rng(seed)
    n = len(m.q)
    k = len(m.coneqs) if isinstance(m, me.LagrangesMethod) else len(m._udep)  # the dependent speeds
    nv = (n if isinstance(m, me.LagrangesMethod) else len(m.u)) - k
    return rng.uniform(-0.5, 0.5, n), rng.uniform(-1.0, 1.0, nv)


class _Timeout(Exception):
    pass


def _alarm(*_):
    raise _Timeout()


def _named(exc):
    """A refusal: liefi's own error class, or a ``ValueError``/``TypeError`` raised in liefi's code."""
    tb = traceback.extract_tb(exc.__traceback__)
    raised_in_liefi = bool(tb) and "/liefi/" in tb[-1].filename
    own_class = type(exc).__module__.startswith("liefi")
    return own_class or (raised_in_liefi and isinstance(exc, (ValueError, TypeError)))


def row(where, model, sympy_s):
    out = dict(model=where, kind=type(model).__name__, sympy=sympy_s)
    consts = constants_of(model)
    signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(TIMEOUT)
    try:
        t0 = time.process_time()
        try:
            try:
                system = liefi.from_mechanics(model, consts)
            except ValueError as exc:  # a parameter outside the equations (a body's, a load's): liefi names it
                missing = re.search(r"no value for the model's parameter\(s\) \[(.*?)\]", str(exc))
                if not missing:
                    raise
                consts.update({sympy.Symbol(n.strip(" '")): value(n.strip(" '")) for n in missing.group(1).split(",")})
                t0 = time.process_time()
                system = liefi.from_mechanics(model, consts)
        except _Timeout:
            raise
        except Exception as exc:
            out.update(build=time.process_time() - t0, status="refused" if _named(exc) else "crashed",
                       reason=f"{type(exc).__name__}: {str(exc).splitlines()[0][:160]}")
            return out
        out["build"] = time.process_time() - t0
        q0, v0 = start(model, zlib.crc32(where.encode()))
        try:
            res = compare(model, consts, system, q0, v0)
        except RuntimeError as exc:
            out.update(status="no reference", reason=str(exc)[:160])
            return out
        except np.linalg.LinAlgError as exc:
            out.update(status="no reference", reason=f"LinAlgError: {exc}")
            return out
        except liefi.IntegrationError as exc:  # a start that runs into a singular configuration of the model
            out.update(status="run failed", reason=f"IntegrationError: {str(exc)[:160]}")
            return out
        out.update(res)
        good = res["error"] <= 1e-8 and max(res["f"], res["velocity"], res["energy"]) <= 1e-12
        out["status"] = "built" if good else "wrong"
    except _Timeout:
        out.update(status="timeout", reason=f"over {TIMEOUT} s")
    except Exception as exc:
        out.update(status="crashed", reason=f"{type(exc).__name__}: {str(exc).splitlines()[0][:160] if str(exc) else ''}")
    finally:
        signal.alarm(0)
    return out


def _fmt(x):
    return "" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.1e}" if isinstance(x, float) else str(x)


def main(argv):
    skip_slow = "--skip-slow" in argv
    argv = [a for a in argv if a != "--skip-slow"]
    out_json = None
    if "--json" in argv:
        i = argv.index("--json")
        out_json, argv = argv[i + 1], argv[:i] + argv[i + 2:]
    only = argv or None
    from own_equations import FILES

    files = [f for f in FILES if not (skip_slow and f in SLOW)]
    models = collect(files, only)
    print(f"sympy {sympy.__version__}; liefi from {pathlib.Path(liefi.__file__).parent}; {len(models)} models")
    print("| model | method | sympy's equations [s] | from_mechanics [s] | status | error | f | velocity | energy | reason |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for where, model, sec in models:
        with warnings.catch_warnings(record=True) as caught:  # liefi's word on the model (where it differs from it)
            warnings.simplefilter("always")
            r = row(where, model, sec)
        said = sorted({str(w.message).split(":")[1].split(";")[0].strip()[:120] for w in caught
                       if str(w.message).startswith("model:")})
        if said:
            r["reason"] = "; ".join(([r["reason"]] if r.get("reason") else []) + [f"liefi warns: {x}" for x in said])
        rows.append(r)
        print(f"| {r['model']} | {r['kind']} | {r['sympy']:.2f} | {_fmt(r.get('build'))} | {r['status']} | "
              f"{_fmt(r.get('error'))} | {_fmt(r.get('f'))} | {_fmt(r.get('velocity'))} | {_fmt(r.get('energy'))} | "
              f"{r.get('reason', '')} |", flush=True)
    counts = {}
    for r in rows:
        counts[r["status"]] = counts.get(r["status"], 0) + 1
    print("\n" + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
    if out_json:
        pathlib.Path(out_json).write_text(json.dumps(rows, indent=1, default=float))
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
