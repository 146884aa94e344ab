"""Foreign code, faults and signals (issue 23): liefi runs no code it did not write, and ends as told.

* Names from a sympy model never become code: an undefined ``Function`` whose name is Python
  code is refused by name (before, ``lambdify`` wrote it into the generated source and it ran),
  a bound variable with such a name is renamed; marker files prove that nothing ran.
* ``liefi run --scheme scipy:METHOD`` reports its run (before: an error after the integration);
  a bad ``rtol``/``atol`` is refused before any work; a run past its evaluation budget stops
  early from the projection of its pace and says so.
* ``--out`` is proven writable (opened) before the run, also as root in ``/proc``.
* Ctrl-C and SIGTERM end the ``liefi`` process with one line and 130 / 143 wherever they land:
  while liefi imports numpy, after the output is complete, in a callback from C (libc's qsort,
  LLVM's object-code hook in a cold numba compile), within ``GRACE`` seconds.  The signal points
  are made deterministic (an import hook, the callbacks themselves); the slow test spreads
  signals over a whole run from a ready marker (the process catching SIGTERM).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")

import liefi  # noqa: E402


def _code(marker):
    """A name that is Python code creating ``marker`` when it runs (and evaluating to 1.0)."""
    return f"(lambda *a: __import__('pathlib').Path({str(marker)!r}).touch() or 1.0)"


def _plane(q1, q2, v1, v2):
    return (v1**2 + v2**2) / 2, [v1 - q1 * v2]


@pytest.mark.parametrize("where", ["L", "constraints"])
def test_from_sympy_refuses_an_undefined_function_whose_name_is_code(tmp_path, where):
    marker = tmp_path / "ran"
    f = sympy.Function(_code(marker))
    q1, q2, v1, v2 = sympy.symbols("q1 q2 v1 v2")
    T, cons = _plane(q1, q2, v1, v2)
    L = T - f(q1) if where == "L" else T
    if where == "constraints":
        cons = [v1 - f(q1) * v2]
    with pytest.raises(ValueError, match=r"undefined function .*__import__") as info:
        liefi.from_sympy(L, [q1, q2], [v1, v2], cons)
    assert str(info.value).startswith(where)
    assert not marker.exists(), "code from a sympy Function's name ran"


def test_from_mechanics_refuses_an_undefined_function_whose_name_is_code(tmp_path):
    marker = tmp_path / "ran"
    f = sympy.Function(_code(marker))
    x, y = me.dynamicsymbols("x y")
    t = me.dynamicsymbols._t
    lm = me.LagrangesMethod((x.diff(t) ** 2 + y.diff(t) ** 2) / 2 - f(x), [x, y],
                            nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
    with pytest.raises(ValueError, match="undefined function"):
        liefi.from_mechanics(lm)
    assert not marker.exists(), "code from a sympy Function's name ran"


def test_from_mechanics_refuses_code_in_a_given_potential(tmp_path):
    """``potential=`` goes through the loads' power check (its own generated code) first."""
    marker = tmp_path / "ran"
    f = sympy.Function(_code(marker))
    x, y = me.dynamicsymbols("x y")
    m, g = sympy.symbols("m g")
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    P.set_vel(N, P.pos_from(O).dt(N))
    t = me.dynamicsymbols._t
    lm = me.LagrangesMethod(m * (x.diff(t) ** 2 + y.diff(t) ** 2) / 2, [x, y], forcelist=[(P, -m * g * N.y)],
                            frame=N, nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
    with pytest.raises(ValueError, match="potential: contains the undefined function"):
        liefi.from_mechanics(lm, constants={m: 1.0, g: 9.81}, potential=m * g * y + f(x))
    assert not marker.exists(), "code from a sympy Function's name ran"


def test_a_bound_symbol_whose_name_is_code_is_renamed(tmp_path):
    """A ``Sum``'s index is printed into the generated code by name: before, this one closed the
    expression and ran its own (the potential read 0); now it is renamed and the sum is right."""
    marker = tmp_path / "ran"
    k = sympy.Symbol(f"k for k in range(3)) if __import__('pathlib').Path({str(marker)!r}).touch() else 0)] #",
                     integer=True)
    q1, q2, v1, v2 = sympy.symbols("q1 q2 v1 v2")
    T, cons = _plane(q1, q2, v1, v2)
    sys_ = liefi.from_sympy(T - sympy.Sum(q1**k, (k, 0, 2)), [q1, q2], [v1, v2], cons)
    x = np.array([[0.5, 0.0, 0.0, 0.0], [2.0, 1.0, 0.0, 0.0]])
    np.testing.assert_allclose(sys_.potential(x), 1 + x[:, 0] + x[:, 0] ** 2, rtol=1e-15)
    assert not marker.exists(), "code from a sympy Symbol's name ran"


def test_a_parameter_whose_name_is_code_is_a_constant_like_any_other(tmp_path):
    marker = tmp_path / "ran"
    m = sympy.Symbol(f"m) or __import__('pathlib').Path({str(marker)!r}).touch() or (m")
    x, y = me.dynamicsymbols("x y")
    t = me.dynamicsymbols._t
    lm = me.LagrangesMethod(m * (x.diff(t) ** 2 + y.diff(t) ** 2) / 2 - m * x**2, [x, y],
                            nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
    sys_ = liefi.from_mechanics(lm, constants={m: 2.0})
    np.testing.assert_allclose(sys_.potential(np.array([0.5, 0.0, 0.0, 0.0])), 2.0 * 0.25, rtol=1e-15)
    assert not marker.exists(), "code from a sympy Symbol's name ran"


def test_checked_names_refuses_other_names_that_are_not_identifiers():
    from liefi.sympy_input import checked_names, plain_identifier

    assert plain_identifier("theta_1") and not plain_identifier("__import__") and not plain_identifier("a b")
    assert not plain_identifier("lambda") and not plain_identifier("θ")
    A = sympy.MatrixSymbol("A; import os", 2, 2)
    with pytest.raises(ValueError, match=r"metric: contains a MatrixSymbol named 'A; import os'"):
        checked_names(sympy, A[0, 0] + 1, "metric")


# --------------------------------------------------------------------------------------
# liefi run --scheme scipy:METHOD
# --------------------------------------------------------------------------------------
def test_liefi_run_scipy_method_reports_its_method(capsys):
    import json

    from liefi import cli

    code = cli.main(["run", "suslov", "--scheme", "scipy:RK45", "--t-final", "0.2", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    got = json.loads(out)
    assert got["backend"] == "scipy" and got["method"]["scheme"] == "scipy:RK45"
    assert got["method"]["rtol"] == 1e-9 and got["method"]["dt"] is None and "adaptive" in got["method"]["why"]
    assert max(got["max_error"].values()) < 1e-6


@pytest.mark.parametrize("flag, value", [("--atol", "-1"), ("--rtol", "1e-20"), ("--rtol", "2")])
def test_liefi_run_scipy_bad_tolerance_is_refused_before_integrating(capsys, monkeypatch, flag, value):
    from liefi import cli
    from liefi.schemes import ivp

    def never(*a, **k):
        raise AssertionError("solve_ivp was called with a bad tolerance")

    monkeypatch.setattr(ivp.ScipyMethod, "solve", never)
    code = cli.main(["run", "suslov", "--scheme", "scipy:RK45", "--t-final", "1", flag, value])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"liefi: error: {flag[2:]}:"), err
    assert len(err.strip().splitlines()) == 1


def test_scipy_run_past_its_evaluation_budget_stops_early_and_says_so():
    """The projection from the pace stops a run that would take 1e6 evaluations after a few thousand."""
    from liefi.schemes import registry
    from liefi.schemes.ivp import EvaluationBudgetError

    calls = []

    def osc(t, y):
        calls.append(t)
        return np.array([y[1], -y[0]])

    rk23 = registry.get("scipy:RK23")
    with pytest.raises(EvaluationBudgetError, match=r"scipy:RK23 at rtol 1e-13 would need about .* evaluations"):
        rk23.solve(osc, 1000.0, [1.0, 0.0], rtol=1e-13, atol=1e-13, max_evaluations=1e5)
    assert len(calls) < 1e4  # stopped from the projection, long before the budget itself
    sol, _ = rk23.solve(osc, 1.0, [1.0, 0.0], rtol=1e-6, atol=1e-9, max_evaluations=1e5)  # within it: unchanged
    ref, _ = rk23.solve(osc, 1.0, [1.0, 0.0], rtol=1e-6, atol=1e-9)
    assert sol.success and np.array_equal(sol.y, ref.y)


def test_liefi_run_scipy_evaluation_guard_is_one_line(capsys, monkeypatch):
    import liefi.run
    from liefi import cli

    monkeypatch.setattr(liefi.run, "IVP_MAX_EVALUATIONS", 1000)
    code = cli.main(["run", "suslov", "--scheme", "scipy:RK23", "--rtol", "1e-13", "--t-final", "50"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("liefi: error: scheme: scipy:RK23 at rtol 1e-13 would need about"), err
    assert len(err.strip().splitlines()) == 1


# --------------------------------------------------------------------------------------
# --out proven writable before the run
# --------------------------------------------------------------------------------------
@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")
def test_out_in_proc_is_refused_before_the_run(capsys, monkeypatch):
    """``os.access`` says yes to root for ``/proc``; the check now opens the file itself."""
    from liefi import cli, scenes

    def never(self, **kw):
        raise AssertionError("the run started although --out cannot be written")

    monkeypatch.setattr(scenes.Scene, "run", never)
    code = cli.main(["run", "suslov", "--t-final", "1", "--out", "/proc/x.png"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("liefi: error: out: cannot write '/proc/x.png'"), err
    assert len(err.strip().splitlines()) == 1


def test_probe_writable_leaves_no_trace(tmp_path):
    from liefi._files import probe_writable

    old = tmp_path / "old.png"
    old.write_bytes(b"kept")
    assert probe_writable(str(old)) is None and old.read_bytes() == b"kept"
    new = tmp_path / "new.png"
    assert probe_writable(str(new)) is None and not new.exists()
    assert probe_writable(str(tmp_path / "missing" / "x.png"))  # a reason, not None


# --------------------------------------------------------------------------------------
# Signals: Ctrl-C and SIGTERM end the `liefi` process wherever they land
# --------------------------------------------------------------------------------------
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import textwrap  # noqa: E402
import time  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
needs_signals = pytest.mark.skipif(os.name != "posix", reason="POSIX signals")

#: the start of the console script ``liefi`` (its ``sys.argv[0]`` names it), then ``BODY``
_AS_COMMAND = '''
import os, signal, sys, time
sys.argv[0] = os.path.join(os.path.dirname(sys.executable), "liefi")
'''


def _env(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "LIEFI_"))}
    env.update(LIEFI_CACHE_DIR=str(tmp_path / "kernels"), PYTHONPATH=ROOT)
    return env


def _grace():
    from liefi import _signals

    return getattr(_signals, "GRACE", 2.0)


def _command(tmp_path, body, timeout=300):
    """Run ``body`` as the ``liefi`` process; returns ``(code, stdout, stderr lines)``."""
    r = subprocess.run([sys.executable, "-c", _AS_COMMAND + textwrap.dedent(body)], cwd=ROOT, env=_env(tmp_path),
                       capture_output=True, text=True, timeout=timeout)
    return r.returncode, r.stdout, r.stderr.strip().splitlines()


def test_is_command_process_only_in_the_liefi_process():
    from liefi._signals import is_command_process

    assert is_command_process(["/venv/bin/liefi"], []) and is_command_process(["-m"], ["python", "-m", "liefi"])
    assert is_command_process(["-m"], ["python", "-X", "dev", "-mliefi", "run"])
    for argv, orig in [(["-m"], ["python", "-m", "pytest"]), (["-c"], ["python", "-c", "import liefi"]),
                       (["nb.py"], ["python", "nb.py"]), (["-m"], ["python", "-m", "liefi.bench"])]:
        assert not is_command_process(argv, orig), orig


@needs_signals
def test_ctrl_c_while_liefi_imports_numpy_is_one_line_and_130(tmp_path):
    """SIGINT while ``import liefi`` is still importing numpy (the first ~0.3 s of every command):
    before, a traceback of 20-30 lines and rc -2."""
    code, out, err = _command(tmp_path, '''
        import importlib.abc
        class Interrupt(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name == "numpy":
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(5)  # the handler runs here
                return None
        sys.meta_path.insert(0, Interrupt())
        from liefi.cli import main
        sys.exit(main(["--version"]))
    ''')
    assert code == 130 and err == ["liefi: interrupted"], (code, err[-5:])


@needs_signals
@pytest.mark.parametrize("when", ["after main", "in an exit handler"])
def test_ctrl_c_after_the_output_is_complete_is_one_line_and_130(tmp_path, when):
    """SIGINT once the command has printed its result: the output is kept, one line, 130 (before:
    a traceback and rc 1 or -2, or "Exception ignored in atexit callback" and rc 0)."""
    late = ("code = main(['list']); os.kill(os.getpid(), signal.SIGINT); time.sleep(5); sys.exit(code)"
            if when == "after main" else
            "import atexit\natexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(5)))\n"
            "sys.exit(main(['list']))")
    code, out, err = _command(tmp_path, "from liefi.cli import main\n" + late)
    assert code == 130 and err == ["liefi: interrupted"], (code, err[-5:])
    assert out.splitlines()[0].startswith("suslov")  # the output printed before is kept


#: a SIGTERM that lands in a callback from C (libc's qsort calling a Python comparison, as LLVM calls
#: numba back): before, "Exception ignored on calling ctypes callback function", every further SIGTERM
#: ignored, and the run went on to its end
_TERM_IN_CALLBACK = '''
    import ctypes, ctypes.util
    from liefi import cli, scenes
    libc = ctypes.CDLL(ctypes.util.find_library("c"))
    CMP = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_int))
    sent = []
    def compare(a, b):
        if not sent:
            sent.append(time.time())
            print(sent[0], flush=True)
            os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.002)  # 4000 numbers: about 100 s of comparisons
        return a[0] - b[0]
    def run(self, **kw):
        arr = (ctypes.c_int * 4000)(*range(4000, 0, -1))
        libc.qsort(arr, 4000, ctypes.sizeof(ctypes.c_int), CMP(compare))
        raise SystemExit(0)
    scenes.Scene.run = run
    sys.exit(cli.main(["run", "suslov", "--t-final", "1"]))
'''


@needs_signals
def test_sigterm_dropped_in_a_callback_from_c_still_ends_the_command(tmp_path):
    start = time.time()
    code, out, err = _command(tmp_path, _TERM_IN_CALLBACK, timeout=200)
    ended = time.time()
    assert code == 143, (code, err[-6:])
    assert not any("Exception ignored" in line for line in err) and len(err) == 1, err[-6:]
    assert err[0].startswith("liefi: terminated by SIGTERM")
    took = ended - float(out.split()[0])
    assert took < _grace() + 8, f"{took:.1f} s from the SIGTERM to the exit (started {ended - start:.1f} s before)"


_TERM_IN_COMPILER = '''
    from numba.core import codegen
    if not hasattr(getattr(codegen, "JITCodeLibrary", None), "_object_compiled_hook"):
        sys.exit(99)  # another numba: no such hook to send the signal from
    hook = codegen.JITCodeLibrary._object_compiled_hook.__func__
    sent = []
    def notify(cls, ll_module, buf):
        if not sent:
            sent.append(time.time())
            print(sent[0], flush=True)
            os.kill(os.getpid(), signal.SIGTERM)
        return hook(cls, ll_module, buf)
    codegen.JITCodeLibrary._object_compiled_hook = classmethod(notify)
    from liefi.cli import main
    sys.exit(main(["run", "suslov", "--backend", "numba", "--t-final", "0.5", "--json"]))
'''


@needs_signals
def test_sigterm_inside_the_compiler_callback_is_143_promptly(tmp_path):
    """SIGTERM landing while LLVM calls back into Python during a cold compile: before, dropped
    ("Exception ignored ..."), the compile and run went on for 7-9 s and exited 0."""
    from liefi import engine

    if not engine.available():
        pytest.skip("numba is not installed")
    code, out, err = _command(tmp_path, _TERM_IN_COMPILER)
    ended = time.time()
    if code == 99:
        pytest.skip("this numba has no object-code hook to send the signal from")
    assert code == 143, (code, err[-6:])
    assert not any("Exception ignored" in line for line in err) and len(err) == 1, err[-6:]
    assert err[0].startswith("liefi: terminated by SIGTERM")
    took = ended - float(out.split()[0])
    assert took < _grace() + 8, f"{took:.1f} s from the SIGTERM to the exit"


def _catches_sigterm(pid):
    """True once the process ``pid`` has a handler for SIGTERM (``SigCgt`` in ``/proc/PID/status``):
    liefi's handling has begun (:func:`liefi._signals.install_for_command`)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            cgt = next(line for line in fh if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(int(cgt.split()[1], 16) >> (signal.SIGTERM - 1) & 1)


@pytest.mark.slow
@needs_signals
@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads /proc/PID/status")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signal_at_any_moment_of_a_command_is_one_line(tmp_path, signum):
    """Signals at evenly spread moments of a whole ``liefi run``, from the moment liefi handles
    them (the ready marker: the process catches SIGTERM) to its end, at most 60 s in all: each
    ends with one line and 128 + signum, or the run had finished (complete output, 0)."""
    body = ("from liefi.cli import main\n"
            "sys.exit(main(['run', 'suslov', '--t-final', '0.2', '--backend', 'numpy', '--json']))")
    argv = [sys.executable, "-c", _AS_COMMAND + body]

    def start():
        p = subprocess.Popen(argv, cwd=ROOT, env=_env(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
        while not _catches_sigterm(p.pid) and p.poll() is None:
            time.sleep(0.001)
        return p, time.time()

    p, t0 = start()
    p.communicate(timeout=120)
    whole = time.time() - t0
    deadline = time.time() + 60
    results = []
    for k in range(12):
        if time.time() > deadline:
            break
        p, t0 = start()
        time.sleep(max(0.0, k / 11 * whole * 1.1 - (time.time() - t0)))
        sent = p.poll() is None
        if sent:
            p.send_signal(signum)
        out, err = p.communicate(timeout=120)
        lines = err.strip().splitlines()
        results.append((k, sent, p.returncode, lines[-3:]))
        if p.returncode == 0:
            assert out.strip().endswith("}") and not lines, results[-1]
        else:
            assert p.returncode == 128 + signum and len(lines) == 1 and "Traceback" not in err, results[-1]
    assert len(results) >= 4 and sum(r[2] == 128 + signum for r in results) >= 2, results
