"""What a cold compile of a generated kernel pays (issue 26): each scalar operation typed once, and no entry
point compiled for the step choice alone.  No test here asserts a time."""

from __future__ import annotations

import numpy as np
import pytest

numba = pytest.importorskip("numba")


def test_a_generated_kernel_types_each_scalar_operation_once(monkeypatch, tmp_path):
    """numba resolves ``a * b`` by trying the operator's templates one by one, at typing and again at lowering;
    a generated field's thousands of operations on float64 are a handful of distinct ones, resolved once."""
    from numba.core.typing import templates

    from liefi.engine import codegen, split_loops
    from liefi.engine.cache import load

    n = 150
    body = [f"    t{i} = t{i - 1} * a + (t{i - 2} - b) / c" for i in range(2, n)]
    src = ("@njit(cache=CACHE, error_model='numpy')\ndef f(a, b, c):\n    t0 = a\n    t1 = b\n"
           + "\n".join(body) + f"\n    return t{n - 1}\n")
    monkeypatch.setenv("LIEFI_CACHE_DIR", str(tmp_path))
    calls = [0]
    for cls in (templates.AbstractTemplate, templates.ConcreteTemplate):
        apply = cls.apply

        def counted(self, *a, _apply=apply, **k):
            calls[0] += 1
            return _apply(self, *a, **k)

        monkeypatch.setattr(cls, "apply", counted)
    mod = load(src, "numba").module
    got = mod.f(0.9, 0.3, 1.7)
    assert calls[0] < 100, calls[0]  # before: every one of the 444 operations, twice, each trying templates
    ns = {}
    exec(codegen.module_text(src, "python", False), ns)
    assert got == ns["f"](0.9, 0.3, 1.7)  # the same arithmetic


def test_the_step_choice_compiles_no_entry_point_of_its_own():
    """The step choice's pilot calls the split kernel's ``xrhs_s``, the function the run's loop calls (before:
    its own array wrapper ``xrhs``, a second compile of the whole field)."""
    from liefi import scenes
    from liefi.engine import kernels
    from liefi.integrator.tolerance_local import unforced_field

    fi = scenes.get("suslov").integrator()
    Y = fi.y0[None] + 0.0
    f = unforced_field(fi, Y, "auto")
    got = f(Y)
    assert got.shape == (1, fi.n)
    assert np.array_equal(got, np.asarray(fi.unforced_vector_field(Y))) or np.allclose(
        got, fi.unforced_vector_field(Y), rtol=1e-13, atol=1e-13)
    cf = kernels.compile_split(fi)
    assert not cf.module.xrhs.signatures  # never compiled


def test_a_rolled_split_scheme_compiles_no_wrapper_around_its_loop(monkeypatch, tmp_path):
    """A large system's ``run_<scheme>`` calls the compiled ``split_loop`` as it is: no compiled wrapper that
    would link the loop (with the field and the feedback step in it) into itself and optimise it all again
    (before: ``run_imex_rk4``, a second optimisation of the whole loop, about 1 s on the rattleback)."""
    from numba.core import event

    from liefi.engine import codegen, split_loops
    from liefi.engine.cache import load
    from liefi.engine.fpu import read_mxcsr

    N, P = 8, 24  # N + P > MAX_INLINE_ARGS: the rolled loop
    ys, ps = codegen.scalar_names("y", N), codegen.scalar_names("p", P)
    head = ", ".join(ys + ps)
    x = [f"{ys[(i + 1) % N]} * {ps[i % P]} - 0.3 * {ys[i]}" for i in range(N)]
    f = [f"{ys[i]} / (1.0 + hh_0 * {ys[i]} * {ys[i]})" for i in range(N)]
    src = (f"@njit(cache=CACHE, error_model='numpy')\ndef xrhs_s({head}):\n    return ({', '.join(x)})\n\n"
           f"@njit(cache=CACHE, error_model='numpy')\ndef fstep_s({head}, hh_0):\n    return ({', '.join(f)})\n\n"
           + split_loops.split_loops_source(N, P))
    monkeypatch.setenv("LIEFI_CACHE_DIR", str(tmp_path))
    compiled = []

    class Listener(event.Listener):
        def on_start(self, ev):
            compiled.append(ev.data["dispatcher"].py_func.__name__)

        def on_end(self, ev):
            pass

    mod = load(src, "numba").module
    rng = np.random.default_rng(0)
    y0, p = rng.normal(size=N), rng.normal(size=P)
    args = (y0, p, 1e-2, 7, 2, 1)
    csr = read_mxcsr()
    got = []
    with event.install_listener("numba:compile", Listener()):
        plain = {}
        exec(codegen.module_text(src, "python", False), plain)
        for run in (mod.run_imex_rk4, plain["run_imex_rk4"]):
            out, bad, last = np.empty((N, 5)), np.empty(N), np.empty(N)
            r = run(*args, out, bad, last, np.zeros(1), 0, 0.0)
            got.append((tuple(r), out, last))
    assert read_mxcsr() == csr  # the caller's floating-point state restored
    assert "split_loop" in compiled and not [c for c in compiled if c.startswith("run_")], compiled
    (r1, o1, l1), (r2, o2, l2) = got
    assert r1 == r2 == (0, 7, 0)
    assert np.array_equal(o1, o2) and np.array_equal(l1, l2)  # the same arithmetic as the plain loop
