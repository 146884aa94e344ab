"""The kernel cache runs only what liefi wrote, and its faults never cost the compiled run or a Ctrl-C.

* A pickle planted among numba's cache files -- in liefi's private kernel
  directory, or under ``$NUMBA_CACHE_DIR`` where numba would look by itself --
  does not run: ``liefi run`` and ``FeedbackIntegrator.run(backend="numba")``
  still succeed, compiling afresh, and say that a file was not trusted.
* Ctrl-C while numba compiles is never dropped: exit code 130.
* ``LIEFI_CACHE_DIR`` blank or relative is ignored with a warning naming it.
* A full disk while numba writes its cache leaves the kernel compiled in memory.

The subprocess tests compile small kernels from an empty cache (about a second each).
"""

from __future__ import annotations

import errno
import os
import pickle
import random
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from liefi import FeedbackIntegrator, scenes
from liefi import engine as compiled
from liefi.engine import cache as _cache
from liefi.engine import kernels

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
needs_numba = pytest.mark.skipif(not compiled.available(), reason="numba is not installed")
needs_signals = pytest.mark.skipif(os.name != "posix", reason="POSIX signals")


class _Evil:
    """A pickle that writes ``marker`` when it is loaded (what a planted numba cache file can do)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        import pathlib

        return (pathlib.Path.write_text, (pathlib.Path(self.marker), "planted pickle ran"))


def _env(tmp_path, **extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "LIEFI_"))}
    env.update(LIEFI_CACHE_DIR=str(tmp_path / "kernels"), PYTHONPATH=ROOT, **extra)
    return env


def _liefi_run(env, *extra):
    return subprocess.run([sys.executable, "-m", "liefi", "run", "suslov", "--backend", "numba", "--t-final", "0.5",
                           *extra], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def _cache_files(*dirs):
    """Every numba cache file (``.nbi``, ``.nbc``) below ``dirs``."""
    out = []
    for d in dirs:
        for root, _, files in os.walk(d):
            out += [os.path.join(root, f) for f in files if f.endswith((".nbi", ".nbc"))]
    return sorted(out)


def _plant(path, marker):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "wb") as fh:
        fh.write(pickle.dumps(_Evil(marker)))


# --------------------------------------------------------------------------------------
# planted pickles
# --------------------------------------------------------------------------------------


@needs_numba
def test_pickle_planted_in_the_private_cache_does_not_run(tmp_path):
    """Every numba cache file of `liefi run suslov` replaced by a payload: the next run does not
    execute it, still succeeds (compiling again) and warns that a cache file was not trusted."""
    env = _env(tmp_path)
    first = _liefi_run(env)
    assert first.returncode == 0, first.stderr
    files = _cache_files(tmp_path / "kernels")
    assert any(f.endswith(".nbi") for f in files) and any(f.endswith(".nbc") for f in files)
    marker = tmp_path / "marker"
    for f in files:
        _plant(f, marker)
    second = _liefi_run(env)
    assert not marker.exists(), "a planted cache pickle ran"
    assert second.returncode == 0, second.stderr
    assert "not trusted" in second.stderr
    # the files were rewritten by liefi (signed), and a third run loads them without a warning
    third = _liefi_run(env)
    assert third.returncode == 0 and "not trusted" not in third.stderr and not marker.exists()


@needs_numba
def test_pickle_planted_under_numba_cache_dir_does_not_run(tmp_path):
    """With NUMBA_CACHE_DIR set, numba would read a liefi kernel's cache from
    $NUMBA_CACHE_DIR/<folder>_<sha1 of the folder>, a name anyone can compute. A payload planted
    there, under the names the kernel's cache files have, does not run."""
    from numba.core.caching import _CacheLocator

    shared = tmp_path / "shared-numba-cache"
    env = _env(tmp_path, NUMBA_CACHE_DIR=str(shared))
    first = _liefi_run(env)
    assert first.returncode == 0, first.stderr
    kernels_dir = tmp_path / "kernels"
    files = _cache_files(kernels_dir, shared)
    assert files
    marker = tmp_path / "marker"
    for py in kernels_dir.glob("liefi_kernel_*.py"):
        sub = shared / _CacheLocator.get_suitable_cache_subpath(str(py))
        for f in files:
            _plant(str(sub / os.path.basename(f)), marker)
    planted = set(_cache_files(shared))
    second = _liefi_run(env)
    assert not marker.exists(), "a pickle planted under NUMBA_CACHE_DIR ran"
    assert second.returncode == 0, second.stderr
    # liefi's kernels are cached in its private directory only: numba wrote nothing under NUMBA_CACHE_DIR
    assert _cache_files(kernels_dir) and set(_cache_files(shared)) == planted


@pytest.fixture
def kernel_env(monkeypatch, tmp_path):
    """A clean kernel table and a private cache directory ``tmp_path/private`` (returned)."""
    private = tmp_path / "private"
    monkeypatch.setenv("LIEFI_CACHE_DIR", str(private))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(kernels, "_KERNELS", {})
    monkeypatch.setattr(kernels, "_WARNED", set())
    _cache.clear_memory()
    yield private
    _cache.clear_memory()


def _fresh_fi():
    """A knife-edge integrator on a new system object (so no kernel of it is cached in this process)."""
    import liefi

    sc = scenes.get("knife-edge")
    s0 = sc.system
    system = liefi.NonholonomicSystem(s0.space, s0.metric.value, s0.constraints.fun, s0.potential.fun)
    return FeedbackIntegrator(system, sc.initial_state(sc.variant()), gains=2.0)


@needs_numba
def test_planted_pickle_does_not_run_in_feedback_integrator_run(kernel_env, tmp_path):
    """FeedbackIntegrator.run(backend='numba') in a process whose kernel cache holds a planted
    index and data file: the payload does not run, the run is compiled and equals the first."""
    fi = _fresh_fi()
    want = fi.run(0.2, dt=1e-2, backend="numba", check_stability=False)
    assert want.backend == "numba"
    files = _cache_files(kernel_env)
    assert files
    marker = tmp_path / "marker"
    for f in files:
        _plant(f, marker)
    kernels._KERNELS.clear()
    _cache.clear_memory()
    with pytest.warns(compiled.KernelCacheWarning, match="not trusted"):
        got = _fresh_fi().run(0.2, dt=1e-2, backend="numba", check_stability=False)
    assert not marker.exists()
    assert got.backend == "numba"
    np.testing.assert_array_equal(got.y, want.y)


@needs_numba
def test_signature_binds_key_and_name(tmp_path):
    """A signed file is trusted only with the key it was signed with and under the name it was written as."""
    import warnings

    from liefi.engine import numba_cache

    d = str(tmp_path)
    a = numba_cache.SignedFiles(d, "liefi_kernel_x.f-1.py311", "stamp", b"k" * 32)
    a.save(("sig",), {"payload": 1})
    assert a.load(("sig",)) == {"payload": 1}
    index = os.path.join(d, "liefi_kernel_x.f-1.py311.nbi")
    other = numba_cache.SignedFiles(d, "liefi_kernel_x.f-1.py311", "stamp", b"j" * 32)
    with pytest.warns(compiled.KernelCacheWarning, match="not trusted"):
        assert other.load(("sig",)) is None  # another key: not trusted, removed
    assert not os.path.exists(index)
    a.save(("sig",), {"payload": 1})
    os.rename(index, os.path.join(d, "liefi_kernel_x.g-1.py311.nbi"))  # a renamed signed file
    b = numba_cache.SignedFiles(d, "liefi_kernel_x.g-1.py311", "stamp", b"k" * 32)
    with pytest.warns(compiled.KernelCacheWarning, match="not trusted"):
        assert b.load(("sig",)) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        a.save(("sig",), {"payload": 2})
        assert a.load(("sig",)) == {"payload": 2}


def test_signing_key_is_private_and_replaced_when_not(kernel_env):
    """The key is made 0600 once and read back; a key readable by others is replaced and the
    cache files signed with it are removed."""
    import stat

    d = _cache.kernel_dir()
    key = _cache.signing_key(d)
    path = os.path.join(d, _cache.KEY_NAME)
    assert len(key) == 32 and stat.S_IMODE(os.stat(path).st_mode) == 0o600
    _cache.clear_memory()
    assert _cache.signing_key(d) == key
    os.makedirs(os.path.join(d, "__pycache__"), exist_ok=True)
    old = os.path.join(d, "__pycache__", "liefi_kernel_x.f-1.py311.nbi")
    open(old, "wb").close()
    os.chmod(path, 0o644)
    _cache.clear_memory()
    with pytest.warns(compiled.KernelCacheWarning, match="readable or writable by group or others"):
        new = _cache.signing_key(d)
    assert new != key and len(new) == 32 and not os.path.exists(old)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600


# --------------------------------------------------------------------------------------
# Ctrl-C during the compile
# --------------------------------------------------------------------------------------

# Ctrl-C landing while LLVM calls back into Python (numba's object-code hook): a real SIGINT sent
# by the process to itself from inside that callback, the moment the audit's dropped interrupt hit.
_SIGINT_IN_CALLBACK = textwrap.dedent('''
    import os, signal, sys
    from numba.core import codegen
    if not hasattr(getattr(codegen, "JITCodeLibrary", None), "_object_compiled_hook"):
        sys.exit(99)  # another numba: no such hook to send the signal from
    hook = codegen.JITCodeLibrary._object_compiled_hook.__func__
    sent = []
    def notify(cls, ll_module, buf):
        if not sent:
            sent.append(1)
            os.kill(os.getpid(), signal.SIGINT)
        return hook(cls, ll_module, buf)
    codegen.JITCodeLibrary._object_compiled_hook = classmethod(notify)
    from liefi.cli import main
    sys.exit(main(["run", "suslov", "--backend", "numba", "--t-final", "0.5"]))
''')


@needs_numba
@needs_signals
def test_ctrl_c_inside_a_compiler_callback_is_not_dropped(tmp_path):
    """SIGINT arriving inside LLVM's callback into Python: exit 130 and one line, not
    'Exception ignored ... KeyboardInterrupt' and exit 0."""
    r = subprocess.run([sys.executable, "-c", _SIGINT_IN_CALLBACK], cwd=ROOT, env=_env(tmp_path),
                       capture_output=True, text=True, timeout=300)
    if r.returncode == 99:
        pytest.skip("this numba has no object-code hook to send the signal from")
    assert r.returncode == 130, (r.returncode, r.stderr[-2000:])
    assert "Exception ignored" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("liefi: interrupted")


_SAY_WHEN_COMPILING = textwrap.dedent('''
    import sys
    from liefi.engine import runners
    first = runners._Overhead._first_call
    def say(self, key, *a):
        if key not in self.compile_seconds:
            print("compiling", flush=True)
        return first(self, key, *a)
    runners._Overhead._first_call = say
    from liefi.cli import main
    sys.exit(main(["run", "suslov", "--backend", "numba", "--scheme", "rk4", "--t-final", "0.5"]))
''')


@needs_numba
@needs_signals
@pytest.mark.parametrize("attempt", range(3))
def test_ctrl_c_during_compile_exits_130(tmp_path, attempt):
    """A real SIGINT at a random moment of the first compile (empty cache): exit 130, one line."""
    p = subprocess.Popen([sys.executable, "-c", _SAY_WHEN_COMPILING], cwd=ROOT, env=_env(tmp_path),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "compiling"
        time.sleep(random.Random(attempt).uniform(0.0, 0.25))
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, (p.returncode, err[-2000:])
    assert "Exception ignored" not in err and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("liefi: interrupted")


def test_interrupts_held_raises_after_the_block():
    """Inside interrupts_held a SIGINT is recorded, the block finishes, then KeyboardInterrupt."""
    from liefi.engine.runners import interrupts_held

    if os.name != "posix":
        pytest.skip("POSIX signals")
    done = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts_held() as got:
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # let the handler run
                pass
            done.append(list(got))
    assert done == [[signal.SIGINT]]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# --------------------------------------------------------------------------------------
# LIEFI_CACHE_DIR
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("value", ["   ", "relative/kernels", "  /leading-blank"])
def test_cache_dir_blank_or_relative_is_ignored(monkeypatch, tmp_path, value):
    """A blank or relative LIEFI_CACHE_DIR is refused with a warning naming the variable; kernels
    go to the default directory, the same from every working directory, and no folder of that
    name is created."""
    monkeypatch.setenv("LIEFI_CACHE_DIR", value)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    _cache.clear_memory()
    try:
        with pytest.warns(compiled.KernelCacheWarning, match="LIEFI_CACHE_DIR"):
            got = _cache.kernel_dir()
        assert got == str(tmp_path / "xdg" / "liefi" / "kernels")
        other = tmp_path / "elsewhere"
        other.mkdir()
        monkeypatch.chdir(other)
        assert _cache.default_cache_dir() == got
        assert os.listdir(work) == []
    finally:
        _cache.clear_memory()


def test_cache_dir_absolute_and_home(monkeypatch, tmp_path):
    """An absolute value is used as it is (normalised); '~' is expanded; empty means unset."""
    import warnings

    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("XDG_CACHE_HOME", "relative-xdg")  # ignored, as the XDG specification says
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        monkeypatch.setenv("LIEFI_CACHE_DIR", str(tmp_path / "a" / ".." / "b"))
        assert _cache.default_cache_dir() == str(tmp_path / "b")
        monkeypatch.setenv("LIEFI_CACHE_DIR", "~/k")
        assert _cache.default_cache_dir() == str(tmp_path / "k")
        monkeypatch.setenv("LIEFI_CACHE_DIR", "")
        assert _cache.default_cache_dir() == str(tmp_path / ".cache" / "liefi" / "kernels")


# --------------------------------------------------------------------------------------
# a full disk while numba writes its cache
# --------------------------------------------------------------------------------------


@needs_numba
def test_full_disk_while_numba_writes_keeps_the_compiled_run(kernel_env, monkeypatch):
    """numba's cache write fails with ENOSPC: the run is still compiled (backend 'numba', the same
    numbers), with a KernelCacheWarning, not a drop to numpy."""
    import warnings

    from numba.core import caching

    def full(self, path):
        raise OSError(errno.ENOSPC, "No space left on device", path)

    monkeypatch.setattr(caching.IndexDataCacheFile, "_open_for_write", full)
    fi = _fresh_fi()
    want = fi.run(0.2, dt=1e-2, backend="numpy", check_stability=False)  # the numpy reference
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = fi.run(0.2, dt=1e-2, backend="numba", check_stability=False)
    assert got.backend == "numba"
    assert not [w for w in caught if issubclass(w.category, compiled.CompilationWarning)]
    assert any(issubclass(w.category, compiled.KernelCacheWarning) and "No space left" in str(w.message)
               for w in caught)
    assert float(np.max(np.abs(got.y - want.y))) < 1e-12 * max(1.0, float(np.max(np.abs(want.y))))
    assert not _cache_files(kernel_env)
