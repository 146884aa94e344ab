"""Loading generated kernels: a private, self-healing on-disk cache (or none).

Numba caches what it compiles in files next to the source (``__pycache__``),
so a second process loads a kernel instead of compiling it.  Those cache files
are pickles, and unpickling runs code: whoever can put a file where liefi's
kernels are cached can make liefi run their code.  Hence:

* **Private.**  The directory (``$LIEFI_CACHE_DIR``, default
  ``$XDG_CACHE_HOME/liefi/kernels`` or ``~/.cache/liefi/kernels``) is created
  with mode ``0700`` and used only if it is a real directory owned by this user
  and not writable by group or others (:func:`check_private`).  Otherwise --
  and when it cannot be created or written, e.g. on a read-only filesystem --
  kernels go to a fresh private directory made by :func:`tempfile.mkdtemp`
  for this process (removed at exit), or, if that fails too, are compiled in
  memory without a disk cache.  A :class:`KernelCacheWarning` says which.
  There is no predictable shared fallback (such as ``$TMPDIR/liefi-kernels-<uid>``).
* **The variable.**  ``LIEFI_CACHE_DIR`` must be an absolute path (``~`` is
  expanded).  A relative value would name a different folder in every working
  directory, and blanks would name a folder of spaces: such a value is ignored,
  with a :class:`KernelCacheWarning` naming it, and the default is used
  (:func:`default_cache_dir`).  An empty value means unset.  A relative
  ``XDG_CACHE_HOME`` is ignored, as the XDG specification asks.
* **Never runs what it did not write.**  A module is executed from the text
  liefi generated, never read back from disk; the file on disk is rewritten
  whenever it differs from that text, and the numba cache files of a rewritten
  module are removed.  numba's cache files of liefi's kernels are kept in
  ``<directory>/__pycache__`` whatever ``NUMBA_CACHE_DIR`` says, and each is
  signed with a key only this user can read (:func:`signing_key`); a file
  whose signature does not match is never unpickled, but removed (with a
  warning) and the kernel compiled afresh.  See :mod:`liefi.engine.numba_cache`
  for the details and the reasons.
* **Self-healing.**  A numba cache entry that fails to load is removed and the
  kernel compiled afresh (:func:`heal`).  A cache that cannot be written (full
  disk) leaves the kernel compiled in memory, never the run on numpy.

Nothing here knows what a kernel computes.
"""

from __future__ import annotations

import atexit
import hashlib
import hmac
import json
import os
import secrets
import shutil
import stat
import sys
import tempfile
import threading
import time
import warnings

import numpy as np

from .codegen import module_text

#: numba (optional: ``liefi[fast]``), imported on first use; ``None`` once an import failed
_numba = False
#: why numba could not be imported (``None`` until an import failed)
NUMBA_ERROR = None


class KernelCacheWarning(RuntimeWarning):
    """The kernel cache directory is not used (not private, not writable); the message says why and what instead."""


def numba_module():
    """The numba module, or ``None`` when it cannot be imported (the reason in :data:`NUMBA_ERROR`)."""
    global _numba, NUMBA_ERROR
    if _numba is False:
        try:
            import numba

            _numba = numba
        except Exception as exc:  # noqa: BLE001 -- any import failure means "no numba"
            _numba = None
            NUMBA_ERROR = f"{type(exc).__name__}: {exc}"
    return _numba


def available() -> bool:
    """True when numba is importable (the compiled engine can run at full speed)."""
    return numba_module() is not None


# ======================================================================================
# the directory
# ======================================================================================


def _uid():
    """This process's user id (``None`` where there is none); the owner a cache directory must have."""
    return os.getuid() if hasattr(os, "getuid") else None


_BAD_VALUES: set = set()


def default_cache_dir():
    """``$LIEFI_CACHE_DIR``, else ``$XDG_CACHE_HOME/liefi/kernels``, else ``~/.cache/liefi/kernels``.

    ``LIEFI_CACHE_DIR`` must be an absolute path after ``~`` is expanded; a
    relative or blank value is ignored, with a :class:`KernelCacheWarning`
    (once per value and process) naming the variable.  An empty value is unset.
    """
    base = os.environ.get("XDG_CACHE_HOME", "")
    if not os.path.isabs(base):  # the XDG specification: a relative value is invalid and ignored
        base = os.path.join(os.path.expanduser("~"), ".cache")
    default = os.path.join(os.path.normpath(base), "liefi", "kernels")
    d = os.environ.get("LIEFI_CACHE_DIR", "")
    if d:
        full = os.path.expanduser(d)
        if os.path.isabs(full):
            return os.path.normpath(full)
        if d not in _BAD_VALUES:
            _BAD_VALUES.add(d)
            what = ("LIEFI_CACHE_DIR is set to blanks only" if not d.strip() else
                    f"LIEFI_CACHE_DIR={d!r} is not an absolute path (it would depend on the working directory)")
            warnings.warn(
                f"liefi: {what}; it is ignored and kernels are cached in {default}. "
                "Set LIEFI_CACHE_DIR to an absolute path, or unset it.",
                KernelCacheWarning,
                stacklevel=5,
            )
    return default


def check_private(path):
    """``None`` if ``path`` is a directory owned by this user and writable by no one else, else the reason."""
    try:
        st = os.lstat(path)
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link"
    if not stat.S_ISDIR(st.st_mode):
        return "is not a directory"
    uid = _uid()
    if uid is not None and st.st_uid != uid:
        return f"is owned by another user (uid {st.st_uid}, this process runs as uid {uid})"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"is writable by group or others (mode {stat.S_IMODE(st.st_mode):04o}); chmod 700 it"
    return None


def _make_dir(path):
    """Create ``path`` (mode 0700) if missing; return the reason it cannot serve as a cache, or ``None``."""
    os.makedirs(path, mode=0o700, exist_ok=True)
    for p in (path, os.path.join(path, "__pycache__")):
        if p != path and not os.path.lexists(p):
            continue
        why = check_private(p)
        if why is not None:
            return f"{p} {why}"
    fd, probe = tempfile.mkstemp(dir=path, prefix=".probe")
    os.close(fd)
    os.remove(probe)
    return None


_DIRS: dict = {}
_DIR_LOCK = threading.RLock()


def kernel_dir():
    """The private directory kernels are written to, or ``None`` (compile in memory).

    Resolved once per process for each value of :func:`default_cache_dir`.
    """
    want = default_cache_dir()
    with _DIR_LOCK:
        if want in _DIRS:
            return _DIRS[want]
        try:
            why = _make_dir(want)
        except OSError as exc:
            why = f"{want} cannot be created or written ({exc.strerror or exc})"
        if why is None:
            _DIRS[want] = want
            return want
        try:
            got = tempfile.mkdtemp(prefix="liefi-kernels-")
            atexit.register(shutil.rmtree, got, True)
            if check_private(got) is not None:  # pragma: no cover -- mkdtemp makes it 0700 and ours
                raise OSError("the temporary directory is not private")
            instead = f"kernels go to the private temporary directory {got} for this process"
        except OSError:
            got = None
            instead = "kernels are compiled in memory (no disk cache: every process compiles them again)"
        warnings.warn(
            f"liefi: the kernel cache is not used: {why}; {instead}. Set LIEFI_CACHE_DIR to a directory "
            "of your own (mode 700) to keep compiled kernels between runs.",
            KernelCacheWarning,
            stacklevel=4,
        )
        _DIRS[want] = got
        return got


#: the file (in the kernel directory) holding the key that signs numba's cache files
KEY_NAME = "cache-signing.key"
_KEY_SIZE = 32
_KEYS: dict = {}


def _read_key(path):
    """The key in ``path``; ``None`` if missing; raises ``ValueError`` (the reason) if it is not private or valid."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ValueError(f"cannot be opened ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        uid = _uid()
        if not stat.S_ISREG(st.st_mode):
            raise ValueError("is not a regular file")
        if uid is not None and st.st_uid != uid:
            raise ValueError(f"is owned by another user (uid {st.st_uid})")
        if st.st_mode & 0o077:
            raise ValueError(f"is readable or writable by group or others (mode {stat.S_IMODE(st.st_mode):04o})")
        data = os.read(fd, _KEY_SIZE + 1)
    finally:
        os.close(fd)
    if len(data) != _KEY_SIZE:
        raise ValueError(f"has {len(data)} bytes, not {_KEY_SIZE}")
    return data


def _new_key(directory, path):
    """Create the key file ``path`` (mode 0600) unless another process just did; return the key in it."""
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=".key", suffix=".tmp")  # mode 0600
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(secrets.token_bytes(_KEY_SIZE))
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.link(tmp, path)  # never replaces a key another process made meanwhile
        except FileExistsError:
            pass
    finally:
        os.remove(tmp)
    return _read_key(path)


def signing_key(directory):
    """The secret key that signs numba's cache files in the kernel directory ``directory``, or ``None``.

    32 random bytes in ``directory/cache-signing.key`` (:data:`KEY_NAME`), mode
    ``0600``, made on first use.  A key file that is not private (a link, another
    owner, readable by others) or not 32 bytes is replaced, and the numba cache
    files signed with it are removed: they can no longer be trusted.  ``None``
    (after a :class:`KernelCacheWarning`) when no key can be made: kernels are
    then compiled in memory.  Read once per process and directory.
    """
    with _DIR_LOCK:
        if directory in _KEYS:
            return _KEYS[directory]
        path = os.path.join(directory, KEY_NAME)
        key = None
        try:
            try:
                key = _read_key(path)
            except ValueError as why:
                warnings.warn(f"liefi: the kernel cache key {path} {why}; a new key is made and the cached "
                              "kernels signed with the old one are removed (they are compiled again)",
                              KernelCacheWarning, stacklevel=4)
                os.remove(path)
                _purge_all(directory)
            if key is None:
                key = _new_key(directory, path)
        except (OSError, ValueError) as exc:
            warnings.warn(f"liefi: no key to sign the kernel cache in {directory} ({exc}); kernels are compiled "
                          "in memory (no disk cache)", KernelCacheWarning, stacklevel=4)
            key = None
        _KEYS[directory] = key
        return key


def tag(key, name, payload):
    """``HMAC-SHA256(key, name + NUL + payload)``: binds a signed file's content to its name.

    The signature of numba's cache files (:mod:`liefi.engine.numba_cache`) and of the
    reference store (:mod:`liefi.scenes.store`), with the key of :func:`signing_key`.
    """
    return hmac.new(key, name.encode() + b"\0" + payload, hashlib.sha256).digest()


def _purge_all(directory):
    """Remove every numba cache file (``.nbi``, ``.nbc``) in ``directory/__pycache__``."""
    _remove_cached(directory, lambda f: f.endswith((".nbi", ".nbc")))


def _remove_cached(directory, matches):
    """Remove the files of ``directory/__pycache__`` whose name ``matches``; a file already gone is no error."""
    pc = os.path.join(directory, "__pycache__")
    try:
        entries = os.listdir(pc)
    except OSError:
        return
    for f in entries:
        if matches(f):
            try:
                os.remove(os.path.join(pc, f))
            except OSError:
                pass


# ======================================================================================
# the modules
# ======================================================================================

_MODULES: dict = {}
_LOCK = threading.RLock()


class Kernel:
    """A generated module as loaded: ``module``, its ``name``, ``path`` (``None``: in memory) and ``load_seconds``."""

    def __init__(self, module, name, path, text, engine, load_seconds):
        self.module, self.name, self.path, self.text = module, name, path, text
        self.engine, self.load_seconds = engine, load_seconds
        self._claimed = False

    def claim(self):
        """True for the first caller only: the one whose run reports :attr:`load_seconds`."""
        first, self._claimed = not self._claimed, True
        return first


def atomic_write(path, data, prefix=".kernel"):
    """Write ``data`` (text or bytes) to ``path`` atomically (a private temporary file in the same directory,
    then rename)."""
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), prefix=prefix, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb" if isinstance(data, bytes) else "w") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise


def _intact(path, text):
    try:
        with open(path) as fh:
            return fh.read() == text
    except (OSError, UnicodeDecodeError):
        return False


def purge(directory, name):
    """Remove numba's (and Python's) cache files of the module ``name`` in ``directory``."""
    _remove_cached(directory, lambda f: f.startswith(name + "."))


def _execute(name, path, text):
    """A new module executing ``text`` (never the file's content) with ``__file__ = path``."""
    mod = type(sys)(name)
    mod.__file__ = path or f"<{name}>"
    sys.modules[name] = mod
    exec(compile(text, mod.__file__, "exec"), mod.__dict__)  # noqa: S102 -- liefi's own generated code
    return mod


def load(source, engine="numba"):
    """The :class:`Kernel` of generated ``source`` (cached per process by the hash of its text).

    ``engine="numba"``: the module's file is written to :func:`kernel_dir` (so that
    numba's on-disk cache works) or, without a usable directory, the module is
    compiled in memory; ``engine="python"``: the generated code runs as plain
    Python (no numba, no files).
    """
    if engine not in ("numba", "python"):
        raise ValueError(f"engine: expected 'numba' or 'python', got {engine!r}")
    nb = numba_module() if engine == "numba" else None
    if engine == "numba" and nb is None:
        raise RuntimeError(f"numba is not available ({NUMBA_ERROR}); install liefi[fast] or use engine='python'")
    tag = f"{engine}-{nb.__version__ if nb else ''}-{np.__version__}"
    key = hashlib.sha256((tag + source).encode()).hexdigest()[:32]
    with _LOCK:
        got = _MODULES.get(key)
        if got is not None:
            return got
        t = time.perf_counter()
        name = f"liefi_kernel_{key}"
        directory = kernel_dir() if engine == "numba" else None
        path = None
        if directory is not None:
            path = os.path.join(directory, name + ".py")
            text = module_text(source, engine, cache=True)
            try:
                if not _intact(path, text):  # missing, truncated or foreign: numba's cache of it is stale too
                    purge(directory, name)
                    atomic_write(path, text)
            except OSError as exc:
                warnings.warn(f"liefi: cannot write the kernel {path} ({exc}); compiling it in memory",
                              KernelCacheWarning, stacklevel=3)
                path = None
        if path is None:
            text = module_text(source, engine, cache=False)
        mod = _execute(name, path, text)
        got = Kernel(mod, name, path, text, engine, time.perf_counter() - t)
        _MODULES[key] = got
        return got


# ======================================================================================
# kernels found by the fingerprint of their data (no trace)
# ======================================================================================

#: the prefix of an index entry's file in the kernel directory: ``<prefix><fingerprint>.json``
INDEX_PREFIX = "fingerprint-"


def _index_path(directory, fingerprint):
    return os.path.join(directory, f"{INDEX_PREFIX}{fingerprint}.json")


def remember(fingerprint, kernel, meta):
    """Record, signed, that the data of ``fingerprint`` give the loaded ``kernel`` and ``meta`` (a dict of numbers
    and strings), so that a later process :func:`find` s it without tracing.  Nothing is written for a kernel
    compiled in memory; a write that fails is silent (the next process traces again)."""
    if kernel.path is None or kernel.engine != "numba":
        return
    directory = os.path.dirname(kernel.path)
    key = signing_key(directory)
    if key is None:
        return
    body = {"name": kernel.name, "text": hashlib.sha256(kernel.text.encode()).hexdigest(), "meta": meta}
    payload = json.dumps(body, sort_keys=True).encode()
    entry = {"body": body, "tag": tag(key, INDEX_PREFIX + fingerprint, payload).hex()}
    try:
        atomic_write(_index_path(directory, fingerprint), json.dumps(entry, sort_keys=True), prefix=".index")
    except OSError:
        pass


def find(fingerprint, engine="numba"):
    """``(Kernel, meta)`` recorded for ``fingerprint`` by :func:`remember`, loaded without a trace; else ``None``.

    Only what liefi signed is used: the entry's signature (the key of :func:`signing_key`) must
    match, and the module's file must hold exactly the text whose hash the entry names; anything
    else (no entry, a foreign or corrupt one, a changed module file) is a miss, and the caller
    traces as before (and :func:`load` rewrites the module).
    """
    if engine != "numba" or numba_module() is None:
        return None
    directory = kernel_dir()
    if directory is None:
        return None
    try:
        with open(_index_path(directory, fingerprint)) as fh:
            entry = json.load(fh)
        body = entry["body"]
        key = signing_key(directory)
        payload = json.dumps(body, sort_keys=True).encode()
        if key is None or not hmac.compare_digest(bytes.fromhex(entry["tag"]),
                                                  tag(key, INDEX_PREFIX + fingerprint, payload)):
            return None
        name = body["name"]
        if not (isinstance(name, str) and name.startswith("liefi_kernel_") and name[13:].isalnum()):
            return None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    with _LOCK:
        got = _MODULES.get(name[13:])
        if got is not None:
            return got, body["meta"]
        t = time.perf_counter()
        path = os.path.join(directory, name + ".py")
        try:
            with open(path) as fh:
                text = fh.read()
        except (OSError, UnicodeDecodeError):
            return None
        if hashlib.sha256(text.encode()).hexdigest() != body["text"]:
            return None
        mod = _execute(name, path, text)
        got = Kernel(mod, name, path, text, engine, time.perf_counter() - t)
        _MODULES[name[13:]] = got
        return got, body["meta"]


def heal(kernel):
    """Drop the on-disk numba cache of ``kernel`` and execute its module afresh (after a failed load).

    Returns the new module (also stored in ``kernel.module``).
    """
    with _LOCK:
        if kernel.path is not None:
            purge(os.path.dirname(kernel.path), kernel.name)
            if not _intact(kernel.path, kernel.text):
                atomic_write(kernel.path, kernel.text)
        kernel.module = _execute(kernel.name, kernel.path, kernel.text)
        return kernel.module


def clear_memory():
    """Forget the kernels loaded in this process (the next :func:`load` executes them again; for tests)."""
    with _LOCK:
        _MODULES.clear()
    with _DIR_LOCK:
        _DIRS.clear()
        _KEYS.clear()
        _BAD_VALUES.clear()
