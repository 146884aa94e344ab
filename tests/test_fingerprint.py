"""A kernel found by the fingerprint of the system's data skips the trace (issue 26), and only then.

* ``from_sympy``, ``from_mechanics`` and ``rolling_body`` (with liefi's contact functions) stamp their
  systems: a later process (simulated here by forgetting everything held in memory) loads the kernel
  the first one generated, with no trace, the same module text.
* A changed constant, expression or contact misses; so does an index entry or module file not as liefi
  signed it.
* A system built from a user's callables, or a user's invariant, never uses the path.

No kernel is compiled here (only traced and loaded): quick.
"""

from __future__ import annotations

import glob
import json
import os

import numpy as np
import pytest

import liefi
from liefi import _fingerprint
from liefi import engine as compiled
from liefi.engine import cache as _cache
from liefi.engine import kernels

sympy = pytest.importorskip("sympy")
pytestmark = pytest.mark.skipif(not compiled.available(), reason="numba is not installed")


@pytest.fixture
def fresh(tmp_path, monkeypatch):
    """A private kernel directory; ``fresh()`` forgets every kernel held in memory (a new process, as far as
    the cache can tell); ``fresh.traces`` counts the tracing sessions."""
    monkeypatch.setenv("LIEFI_CACHE_DIR", str(tmp_path / "kernels"))
    count = [0]
    real = kernels.trace

    class counted(real):
        def __enter__(self):
            count[0] += 1
            return super().__enter__()

    monkeypatch.setattr(kernels, "trace", counted)

    def forget():
        _cache.clear_memory()
        kernels._KERNELS.clear()

    forget()
    forget.traces = lambda: count[0]
    forget.dir = tmp_path / "kernels"
    yield forget
    forget()


def knife(m=1.0):
    """The knife edge on an incline from a sympy Lagrangian (a fresh build, as in a new process)."""
    x, y, phi, xd, yd, phid = sympy.symbols("x y phi xd yd phid")
    L = m * (xd**2 + yd**2) / 2 + phid**2 / 2 + m * sympy.Rational(1, 2) * x
    system = liefi.from_sympy(L, [x, y, phi], [xd, yd, phid], [yd * sympy.cos(phi) - xd * sympy.sin(phi)])
    return system, np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5])


def sleigh(m=1.0):
    from models import sleigh_model

    LM, (ms, I, a) = sleigh_model()
    return liefi.from_mechanics(LM, {ms: m, I: 1.0, a: 0.5})


def integrator(system, y0):
    return liefi.FeedbackIntegrator(system, y0, gains=10.0)


def test_a_hit_skips_the_trace_and_loads_the_same_kernel(fresh):
    system, y0 = knife()
    first = kernels.compile_split(integrator(system, y0))
    assert fresh.traces() == 1 and first.traced
    assert glob.glob(str(fresh.dir / "fingerprint-*.json"))
    fresh()  # a new process: nothing in memory
    system, y0 = knife()
    again = kernels.compile_split(integrator(system, y0))
    assert fresh.traces() == 1, "the kernel was traced again though its data are the same"
    assert not again.traced
    assert again.kernel.text == first.kernel.text and again.kernel.name == first.kernel.name
    assert (again.n_params, again.kind, again.nodes) == (first.n_params, first.kind, first.nodes)


def test_every_kind_of_kernel_and_the_rolling_body(fresh):
    from liefi.systems.rolling import ATTITUDE_CASIMIRS, ellipsoid, rolling_body, rolling_start

    def build():
        body = rolling_body(1.0, [2e-4, 1.6e-3, 1.7e-3], ellipsoid([0.2, 0.03, 0.02], offset=(0, 0, -0.01)))
        return liefi.FeedbackIntegrator(body, rolling_start(body, np.eye(3), [0.0, 0.0, 5.0]),
                                        invariants=("constraints", "energy") + ATTITUDE_CASIMIRS, gains=1.0)

    made = [kernels.compile_split(build()), kernels.compile_feedback(build()), kernels.compile_constrained(build())]
    assert fresh.traces() == 3
    fresh()
    got = [kernels.compile_split(build()), kernels.compile_feedback(build()), kernels.compile_constrained(build())]
    assert fresh.traces() == 3
    assert [g.kernel.text for g in got] == [m.kernel.text for m in made]
    assert got[2].projection == made[2].projection > 0


def test_a_changed_constant_or_expression_misses(fresh):
    a = sleigh(1.0)
    z0 = a.state([0.0, 0.0, 0.0], [0.5, 0.0, 1.0])
    kernels.compile_split(integrator(a, z0))
    assert fresh.traces() == 1
    fresh()
    kernels.compile_split(integrator(sleigh(2.0), z0))  # another mass: folded into the code, another kernel
    assert fresh.traces() == 2
    fresh()
    b = sleigh(1.0)
    b.constants = {"m": 3.0}  # changed in place
    kernels.compile_split(integrator(b, z0))
    assert fresh.traces() == 3
    fresh()
    kernels.compile_split(integrator(sleigh(1.0), z0))  # the first one again: found
    assert fresh.traces() == 3
    system, y0 = knife(1.0)
    kernels.compile_split(integrator(system, y0))
    system, y0 = knife(1.5)  # another number in the Lagrangian
    kernels.compile_split(integrator(system, y0))
    assert fresh.traces() == 5


def test_other_settings_of_the_integrator_miss(fresh):
    system, y0 = knife()
    fi = integrator(system, y0)
    fps = {kernels.kernel_fingerprint(fi, "split", "numba"), kernels.kernel_fingerprint(fi, "feedback", "numba"),
           kernels.kernel_fingerprint(liefi.FeedbackIntegrator(system, y0, invariants=("energy",)), "split", "numba"),
           kernels.kernel_fingerprint(liefi.FeedbackIntegrator(system, y0, energy="original"), "split", "numba"),
           kernels.kernel_fingerprint(fi.without({"energy": "test"}), "split", "numba"),
           kernels.kernel_fingerprint(liefi.FeedbackIntegrator(system, y0, A=2 * np.eye(6)), "split", "numba")}
    assert None not in fps and len(fps) == 6
    assert kernels.kernel_fingerprint(fi, "split", "python") is None  # no disk cache: nothing to find


def test_a_system_of_user_callables_keeps_the_trace(fresh):
    def metric(x):
        return np.broadcast_to(np.eye(3), np.shape(x)[:-1] + (3, 3))

    def rows(x):
        phi = x[..., 2]
        return np.stack([np.sin(phi), -np.cos(phi), 0.0 * phi], -1)[..., None, :]

    system = liefi.NonholonomicSystem(liefi.CotangentBundle(3), metric, rows, lambda x: -0.5 * x[..., 0])
    y0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5])
    fi = integrator(system, y0)
    assert kernels.kernel_fingerprint(fi, "split", "numba") is None
    kernels.compile_split(fi)
    fresh()
    kernels.compile_split(integrator(system, y0))
    assert fresh.traces() == 2
    assert not glob.glob(str(fresh.dir / "fingerprint-*.json"))


def test_a_users_contact_or_invariant_or_a_replaced_datum_voids_the_fingerprint():
    from liefi.systems.rolling import ellipsoid, rolling_body, rolling_start

    def mine(Gamma):  # a user's contact function: liefi cannot tell what it computes
        return ellipsoid([0.2, 0.03, 0.02])(Gamma)

    user = rolling_body(1.0, [2e-4, 1.6e-3, 1.7e-3], mine)
    y0 = rolling_start(user, np.eye(3), [0.0, 0.0, 5.0])
    assert kernels.kernel_fingerprint(liefi.FeedbackIntegrator(user, y0), "split", "numba") is None
    system, z0 = knife()
    assert kernels.kernel_fingerprint(integrator(system, z0), "split", "numba") is not None
    spin = liefi.Invariant("spin", lambda z: z[..., 5], lambda z: np.eye(6)[5] + 0 * z)
    fi = liefi.FeedbackIntegrator(system, z0, invariants=("constraints", "energy", spin))
    assert kernels.kernel_fingerprint(fi, "split", "numba") is None
    import copy

    system.potential = copy.copy(system.potential)  # new data in the same object
    assert _fingerprint.of_system(system) is None
    assert kernels.kernel_fingerprint(integrator(system, z0), "split", "numba") is None


def test_an_entry_or_module_not_as_liefi_wrote_it_is_a_miss(fresh):
    system, y0 = knife()
    kernels.compile_split(integrator(system, y0))
    (entry,) = glob.glob(str(fresh.dir / "fingerprint-*.json"))
    data = json.load(open(entry))
    data["body"]["meta"]["n_params"] += 1  # a changed entry: its signature no longer matches
    with open(entry, "w") as fh:
        json.dump(data, fh)
    fresh()
    kernels.compile_split(integrator(*knife()))
    assert fresh.traces() == 2  # traced again (and the entry rewritten)
    (module,) = glob.glob(str(fresh.dir / "liefi_kernel_*.py"))
    with open(module, "a") as fh:
        fh.write("\nimport os  # planted\n")
    fresh()
    cf = kernels.compile_split(integrator(*knife()))
    assert fresh.traces() == 3 and "planted" not in cf.kernel.text
    fresh()
    kernels.compile_split(integrator(*knife()))
    assert fresh.traces() == 3  # the module rewritten by the trace: found again


def test_the_digest_is_the_same_in_every_process_and_tells_values_apart():
    x = sympy.Dummy("x")
    y = sympy.Dummy("x")  # another dummy of the same name
    a = _fingerprint.digest(sympy.sin(x) + x**2)
    z = sympy.Dummy("x")  # a dummy made later (as in another process: another index)
    assert a == _fingerprint.digest(sympy.sin(z) + z**2)
    assert _fingerprint.digest(sympy.sin(x) * y) == _fingerprint.digest(sympy.sin(y) * x)
    assert _fingerprint.digest(sympy.sin(x) * y) != _fingerprint.digest(sympy.sin(x) * x)
    assert _fingerprint.digest(1.0) != _fingerprint.digest(np.nextafter(1.0, 2.0))
    assert _fingerprint.digest(np.zeros(3)) != _fingerprint.digest(np.zeros(4))
    assert _fingerprint.digest(("a", "bc")) != _fingerprint.digest(("ab", "c"))
    assert _fingerprint.digest(lambda z: z) is None
    assert a is not None and os.path.basename(_fingerprint.sources()) == _fingerprint.sources()


def test_liefis_scenes_are_stamped_and_a_changed_or_foreign_scene_is_not_the_same():
    import warnings

    from liefi import scenes

    def fingerprint(sc):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return kernels.kernel_fingerprint(sc.integrator(), "split", "numba")

    kind = type(scenes.get("suslov"))
    a, b = kind(), kind()  # two new objects of liefi's scene (as in two processes)
    assert fingerprint(a) is not None and fingerprint(a) == fingerprint(b)
    c = kind()
    c.dt = c.dt / 2  # a changed datum of the scene (before its system is built): another fingerprint
    assert fingerprint(c) not in (None, fingerprint(a))

    class Mine(kind):  # a user's subclass: its code is not liefi's
        pass

    assert _fingerprint.of_system(Mine().system) is None


def test_the_invariants_of_configuration_constraints_are_the_systems_own(fresh):
    """``f_j`` of a model with configuration constraints: liefi's functions of the system's own data (made anew
    at every access), found by the fingerprint; the pendulum of sympy's nonminimal example."""
    from test_mechanics_holonomic import lagrange_pendulum

    def build():
        case = lagrange_pendulum()
        system = liefi.from_mechanics(case["model"], case["constants"])
        L = 0.7
        z0 = system.state([L * np.cos(0.3), L * np.sin(0.3)], [-0.1 * L * np.sin(0.3), 0.1 * L * np.cos(0.3)])
        return liefi.FeedbackIntegrator(system, z0, gains=1.0)

    fi = build()
    assert any(u.name.startswith("f_") for u in fi.user)
    first = kernels.compile_split(fi)
    fresh()
    again = kernels.compile_split(build())
    assert fresh.traces() == 1 and again.kernel.text == first.kernel.text


def test_the_stamp_is_computed_when_first_asked_for_from_the_data_as_stamped(monkeypatch):
    """Issue 25's build time: printing a large model's expressions (``srepr``) was up to 40 % of ``from_mechanics``
    (the rattleback: 0.27 of 0.66 s); the engine's kernel lookup asks for it, a numpy run never does."""
    printed = []
    real = _fingerprint._sympy_text  # srepr's printer, with the dummies numbered by first appearance
    monkeypatch.setattr(_fingerprint, "_sympy_text", lambda e, dummies: printed.append(1) or real(e, dummies))
    system = sleigh()
    assert not printed  # nothing printed while building
    fp = _fingerprint.of_system(system)
    assert fp is not None and printed and fp == _fingerprint.of_system(sleigh())
    data = [1.0, [2.0]]
    before = _fingerprint.digest("x", data)

    class Thing:
        pass

    thing = _fingerprint.stamp(Thing(), "x", data)
    data[1].append(3.0)  # changed after the stamp: the stamp keeps the data as they were
    assert _fingerprint.of_system(thing) == before != _fingerprint.digest("x", data)
