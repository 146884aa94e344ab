"""numba's on-disk cache of liefi's kernels: kept in liefi's private directory, every file signed.

numba stores what it compiles as two pickles per function: an index
(``<module>.<function>-<line>.py311.nbi``) and one data file per signature
(``...<n>.nbc``).  Unpickling runs code, so a planted file runs its payload.
numba itself checks neither who wrote them nor their content, and where they
go depends on the environment (``NUMBA_CACHE_DIR`` puts them under
``$NUMBA_CACHE_DIR/<folder>_<sha1 of the folder>``, a name anyone can compute;
``NUMBA_CACHE_LOCATOR_CLASSES`` can redirect them anywhere).

The generated modules of :mod:`liefi.engine.cache` therefore do not use
numba's own cache.  Their ``@njit(cache=CACHE)`` is :func:`njit` below: a plain
``numba.njit`` whose dispatcher gets a :class:`TrustedCache` in place of
numba's ``FunctionCache``.  It differs in two ways, and in nothing else:

* **Where.**  The files are in ``<kernel directory>/__pycache__`` (next to the
  module, the private ``0700`` directory of :func:`liefi.engine.cache.kernel_dir`),
  whatever ``NUMBA_CACHE_DIR`` or ``NUMBA_CACHE_LOCATOR_CLASSES`` say: the
  locator is fixed, not chosen from numba's list.
* **Signed.**  Every file liefi writes starts with ``LIEFINB1`` and a tag
  ``HMAC-SHA256(key, file name + payload)``; the payload is exactly what numba
  would have written.  A file is read whole, its tag checked against the bytes
  read, and only then are those same bytes unpickled -- no window in which the
  file could change between the check and the load.  The key is 32 random bytes
  in a ``0600`` file of the kernel directory
  (:func:`liefi.engine.cache.signing_key`): only a process of this user that
  could read it can sign a file.  A file without a valid tag -- planted, copied
  from elsewhere, damaged, or written by numba itself -- is never unpickled:
  a :class:`~liefi.engine.cache.KernelCacheWarning` names it, it is removed, and
  the kernel is compiled afresh (and its new files signed).

Why both, and not only one: the private directory alone relies on a check of
its owner and mode made when the process starts; the tag alone would still let
numba read and write a shared, predictable folder.  A manifest of digests
(one file for all entries) was considered and not chosen: concurrent processes
would have to lock it, while a tag inside each file is written atomically with
it (numba writes to a temporary file and renames).

A cache file that cannot be written (a full disk, a quota, a read-only
directory) does not fail the run: the kernel compiled in memory is used, a
:class:`~liefi.engine.cache.KernelCacheWarning` says the cache is not written,
and that function's cache is disabled for the rest of the process.

This module imports numba: it is imported only by the generated modules.
The names it uses from ``numba.core.caching`` are checked at import
(:data:`SUPPORTED`); with a numba whose cache differs, kernels are compiled in
memory (no disk cache) after a warning, never read back with numba's loader.
"""

from __future__ import annotations

import hashlib
import hmac
import io
import os
import pickle
import sys
import threading
import warnings

import numba
from numba.core import caching as _nc

from . import cache as _cache

#: the first bytes of every cache file liefi writes (the format's version)
MAGIC = b"LIEFINB1"
_TAG = hashlib.sha256().digest_size
_HEAD = len(MAGIC) + _TAG

_NEEDED = {
    _nc.IndexDataCacheFile: ("_load_index", "_save_index", "_load_data", "_save_data", "_open_for_write", "_dump",
                             "_data_path"),
    _nc.FunctionCache: ("load_overload", "save_overload", "_load_overload", "_save_overload", "_index_key"),
    _nc.CompileResultCacheImpl: ("reduce", "rebuild", "check_cachable"),
}
#: True when numba's cache classes have the members this module builds on
SUPPORTED = all(callable(getattr(cls, m, None)) for cls, ms in _NEEDED.items() for m in ms)


def _warn(msg):
    warnings.warn(msg, _cache.KernelCacheWarning, stacklevel=2)


#: ``HMAC-SHA256(key, name + NUL + payload)`` (:func:`liefi.engine.cache.tag`)
tag = _cache.tag


class SignedFiles(_nc.IndexDataCacheFile):
    """numba's index and data files, each prefixed with :data:`MAGIC` and its :func:`tag`."""

    def __init__(self, cache_path, filename_base, source_stamp, key):
        super().__init__(cache_path, filename_base, source_stamp)
        self._key = key

    def _read_signed(self, path):
        """The payload of the file ``path`` if its tag is valid; ``None`` if it is missing or not trusted."""
        try:
            with open(path, "rb") as fh:
                blob = fh.read()
        except FileNotFoundError:
            return None
        except OSError as exc:  # unreadable: compile instead (nothing is loaded)
            _warn(f"liefi: the kernel cache file {path} cannot be read ({exc.strerror or exc}); "
                  "the kernel is compiled afresh")
            return None
        payload = blob[_HEAD:]
        if blob[: len(MAGIC)] != MAGIC or not hmac.compare_digest(
                blob[len(MAGIC):_HEAD], tag(self._key, os.path.basename(path), payload)):
            _warn(f"liefi: the kernel cache file {path} is not trusted: it does not carry liefi's signature "
                  "(written by something other than liefi, or damaged). It was not loaded and is removed; "
                  "the kernel is compiled afresh.")
            try:
                os.remove(path)
            except OSError:
                pass
            return None
        return payload

    def _write_signed(self, path, payload):
        with self._open_for_write(path) as fh:
            fh.write(MAGIC + tag(self._key, os.path.basename(path), payload) + payload)

    def _load_index(self):
        payload = self._read_signed(self._index_path)
        if payload is None:
            return {}
        fh = io.BytesIO(payload)
        if pickle.load(fh) != self._version:  # signed by liefi, written by another numba version
            return {}
        stamp, overloads = pickle.loads(fh.read())
        return overloads if stamp == self._source_stamp else {}

    def _save_index(self, overloads):
        payload = pickle.dumps(self._version, protocol=-1) + self._dump((self._source_stamp, overloads))
        self._write_signed(self._index_path, payload)

    def _load_data(self, name):
        path = self._data_path(name)
        payload = self._read_signed(path)
        if payload is None:  # numba's load() reads an OSError as "no entry": compile
            raise FileNotFoundError(path)
        return pickle.loads(payload)

    def _save_data(self, name, data):
        self._write_signed(self._data_path(name), self._dump(data))


class PrivateLocator(_nc._CacheLocator):
    """The cache folder of a kernel: ``__pycache__`` in its private directory, and nothing else."""

    def __init__(self, py_file, cache_path, stamp, lineno):
        self._py_file, self._cache_path, self._stamp, self._lineno = py_file, cache_path, stamp, lineno

    def ensure_cache_path(self):
        os.makedirs(self._cache_path, mode=0o700, exist_ok=True)
        why = _cache.check_private(self._cache_path)
        if why is not None:
            raise PermissionError(f"{self._cache_path} {why}")

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return self._stamp

    def get_disambiguator(self):
        return str(self._lineno)


class _Impl(_nc.CompileResultCacheImpl):
    """numba's compile-result (de)serialisation with the :class:`PrivateLocator` (no locator search)."""

    def __init__(self, py_func, locator):  # noqa: super().__init__ would search numba's locators
        self._lineno = py_func.__code__.co_firstlineno
        self._locator = locator
        modname = os.path.splitext(os.path.basename(locator._py_file))[0]
        self._filename_base = self.get_filename_base(f"{modname}.{py_func.__qualname__}", getattr(sys, "abiflags", ""))


class TrustedCache(_nc.FunctionCache):
    """numba's per-function cache, in liefi's private directory, reading only files liefi signed."""

    def __init__(self, py_func, cache_path, key, stamp):  # noqa: super().__init__ would pick numba's locator
        self._name = repr(py_func)
        self._py_func = py_func
        locator = PrivateLocator(py_func.__code__.co_filename, cache_path, stamp, py_func.__code__.co_firstlineno)
        self._impl = _Impl(py_func, locator)
        self._cache_path = cache_path
        self._cache_file = SignedFiles(cache_path, self._impl.filename_base, stamp, key)
        self.enable()

    def load_overload(self, sig, target_context):
        """Load a cached kernel without refreshing numba's whole target context first.

        numba's ``load_overload`` calls ``target_context.refresh()``, which imports every
        registry numba compiles with (``numba.np.arraymath`` and through it ``scipy.linalg``,
        ``cffi``'s C parser...): about half a second, spent again in every process.  Linking
        a kernel's object code needs only the symbols the context defines when it is made
        (numba's C helpers, libm, the exception types), the runtime (``rtsys.initialize``)
        and the hash secret ``numba.cpython.hashing`` defines on import; parallel kernels
        start their threading layer through the cached ``reload_init``.  A kernel that is
        not in the cache is compiled by numba's compiler, which refreshes the context itself.
        """
        from numba.core.runtime import rtsys
        import numba.cpython.hashing  # noqa: F401 -- defines the _numba_hashsecret_ symbols

        rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    def save_overload(self, sig, data):
        """Save (signed); a write that fails (full disk, quota, read-only) keeps the kernel in memory."""
        try:
            super().save_overload(sig, data)
        except OSError as exc:
            self.disable()
            _warn(f"liefi: the compiled kernel cannot be written to the cache {self._cache_path} "
                  f"({exc.strerror or exc}); it runs compiled in memory and is compiled again by the next process")


_WARNED = set()


def _attach(disp):
    """Give the dispatcher ``disp`` a :class:`TrustedCache` (or leave it without a disk cache, after a warning)."""
    py_func = getattr(disp, "py_func", None)
    if py_func is None:  # NUMBA_DISABLE_JIT: the plain function, nothing to cache
        return disp
    path = py_func.__globals__.get("__file__")
    if not SUPPORTED:
        if "numba" not in _WARNED:
            _WARNED.add("numba")
            _warn(f"liefi: numba {numba.__version__}'s cache is not one liefi can sign; kernels are compiled in "
                  "memory (no disk cache)")
        return disp
    if not path or not os.path.isabs(path) or not hasattr(disp, "_cache"):
        return disp
    directory = os.path.dirname(path)
    key = _cache.signing_key(directory)
    if key is None:  # the warning is given by signing_key
        return disp
    stamp = py_func.__globals__.get("__name__")  # liefi_kernel_<hash of the module's text>
    disp._cache = TrustedCache(py_func, os.path.join(directory, "__pycache__"), key, stamp)
    return disp


# --- typing a generated kernel: each scalar operation's signature resolved once ----------------------
#
# numba types every operation of a function by trying each template of the operator in turn (``+`` on two
# floats tries numpy's ufunc rules, formats their failures...), and again when it lowers it: about 40 % of
# the compile of a generated field, whose thousands of operations are a handful of (operator, float64,
# float64).  While a generated kernel compiles, :func:`_memo_call_type` remembers the signature numba
# resolved for a function type and plain scalar arguments (non-literal floats, integers, booleans), and
# gives it again: the same signature numba's own resolution returns, so the same code.  Other compiles
# in the process are untouched.

_BaseFunction = getattr(getattr(numba.core.types, "functions", None), "BaseFunction", None)
_PLAIN = (numba.core.types.Float, numba.core.types.Integer, numba.core.types.Boolean)
_local = threading.local()
_SIGS: dict = {}


def _memo_call_type(self, context, args, kws, _resolve=getattr(_BaseFunction, "get_call_type", None)):
    if not getattr(_local, "on", 0) or kws or not all(type(a) in _PLAIN for a in args):
        return _resolve(self, context, args, kws)
    key = (self, context, args)
    sig = _SIGS.get(key)
    if sig is None:
        sig = _SIGS[key] = _resolve(self, context, args, kws)
    return sig


if _BaseFunction is not None and callable(getattr(_BaseFunction, "get_call_type", None)):
    _BaseFunction.get_call_type = _memo_call_type


def _memo_compile(disp):
    """``disp.compile`` with :func:`_memo_call_type` on in this thread for its duration."""
    compile_ = disp.compile

    def compile(sig):
        _local.on = getattr(_local, "on", 0) + 1
        try:
            return compile_(sig)
        finally:
            _local.on -= 1

    disp.compile = compile
    return disp


def njit(*args, cache=False, **kwargs):
    """``numba.njit``; with ``cache=True`` the dispatcher caches through :class:`TrustedCache`.  Its compiles
    resolve each scalar operation's type once (:func:`_memo_call_type`)."""
    if args and callable(args[0]) and len(args) == 1:
        return njit(cache=cache, **kwargs)(args[0])

    def decorate(func):
        disp = numba.njit(*args, cache=False, **kwargs)(func)
        if hasattr(disp, "py_func"):  # not under NUMBA_DISABLE_JIT
            _memo_compile(disp)
        return _attach(disp) if cache else disp

    return decorate
