"""The reference store: numerical reference solutions computed once and kept on disk, signed.

A scene's numerical reference (DOP853 at ``rtol = 1e-12`` on the constrained
field, or on equations written by hand) costs far more than the run it is
compared with: the rigid body's 1e4 DOP853 steps take seconds where the run
takes milliseconds.  The values of :meth:`Scene.exact <liefi.scenes.Scene.exact>`
at a run's saved times are therefore kept in a file, and a later run -- in any
process -- that asks for the same reference reads it back.

* **Keyed by everything the reference depends on.**  The file's name is the
  SHA-256 of: the scene's class and name, the variant (its name, ``V``, field and
  options), every public data attribute of the scene (its parameters: inertia,
  mass, start, ``reference_rtol``/``atol``...; a scene holding anything else is
  not stored), the system's constants when they were set since its build, the full start
  ``initial_state(variant)``, the times ``t``, the
  text of every module of liefi (and of the scene's own module when it lives
  outside liefi), and the versions of Python, numpy and scipy, and whether numba
  is installed (the reference's field is the compiled one then).  Change any of
  them and the reference is solved again.
* **Arrays only, signed.**  A file holds the names and the value arrays
  (``np.savez``), read back with ``allow_pickle=False``: loading runs no code.
  It starts with ``LIEFIRF1`` and ``HMAC-SHA256(key, file name + payload)``
  (:func:`liefi.engine.cache.tag`) with the kernel cache's key
  (:func:`liefi.engine.cache.signing_key`, a ``0600`` file only this user can
  read), and is used only if the tag matches the bytes read and the key stored
  inside is the one asked for.  A planted, copied or damaged file is removed,
  a :class:`ReferenceStoreWarning` names it, and the reference is solved again.
* **Where.**  ``references/`` in the kernel cache's private ``0700``
  directory (:func:`liefi.engine.cache.kernel_dir`: ``$LIEFI_CACHE_DIR``, else
  ``~/.cache/liefi/kernels``), itself ``0700``.  At most :data:`MAX_ENTRIES` files
  and :data:`MAX_BYTES` bytes are kept; the oldest go first.
* **Never fails a run.**  A store that cannot be created, read or written (a
  full disk, a read-only directory) costs only the time of solving the
  reference: a :class:`ReferenceStoreWarning` (once per process) says so and the
  run goes on.  ``LIEFI_REFERENCE_STORE=0`` turns the store off.
"""

from __future__ import annotations

import hashlib
import importlib.util
import io
import os
import sys
import threading
import warnings

import numpy as np

#: the first bytes of every file of the store (the format's version)
MAGIC = b"LIEFIRF1"
_TAG = hashlib.sha256().digest_size
_HEAD = len(MAGIC) + _TAG
#: the most files the store keeps, and the most bytes (the least recently written are removed first)
MAX_ENTRIES = 32
MAX_BYTES = 256 * 2**20
#: the store's folder inside the kernel cache directory
FOLDER = "references"


class ReferenceStoreWarning(RuntimeWarning):
    """The reference store is not used or a file of it is not trusted; the reference is solved instead."""


_WARNED: set = set()
_LOCK = threading.RLock()
_SOURCE: dict = {}


def _warn_once(what, msg):
    if what not in _WARNED:
        _WARNED.add(what)
        warnings.warn(msg, ReferenceStoreWarning, stacklevel=4)


def enabled():
    """False when ``LIEFI_REFERENCE_STORE`` is ``0``, ``no``, ``off`` or ``false``."""
    return os.environ.get("LIEFI_REFERENCE_STORE", "").strip().lower() not in ("0", "no", "off", "false")


# ======================================================================================
# the key
# ======================================================================================


class _NotData(TypeError):
    """A scene attribute the key cannot encode (the reference is then not stored)."""


def _canon(x):
    """A canonical, unambiguous text of ``x`` (numbers, strings, arrays, and tuples, lists, dicts of them)."""
    if x is None or isinstance(x, (bool, str)):
        return repr(x)
    if isinstance(x, (int, np.integer)):
        return f"i{int(x)}"
    if isinstance(x, np.floating) and np.finfo(type(x)).nmant > 52:  # extended precision: float() would round it
        return f"l{np.format_float_scientific(x, unique=True)}"
    if isinstance(x, (float, np.floating)):
        return f"f{float(x).hex()}"
    if isinstance(x, complex):
        return f"c{x.real.hex()},{x.imag.hex()}"
    if isinstance(x, np.ndarray):
        if x.dtype == object:
            raise _NotData("an object array")
        a = np.ascontiguousarray(x)
        if a.dtype.kind in "fc" and np.finfo(a.dtype).nmant > 52:
            # extended precision: its bytes hold padding; the shortest text that reads back each value
            parts = (a.real, a.imag) if a.dtype.kind == "c" else (a,)
            text = ",".join(np.format_float_scientific(v, unique=True) for part in parts for v in part.ravel())
            return f"a{a.dtype.str}{a.shape}{hashlib.sha256(text.encode()).hexdigest()}"
        return f"a{a.dtype.str}{a.shape}{hashlib.sha256(a.tobytes()).hexdigest()}"
    if isinstance(x, (tuple, list)):
        return "(" + ",".join(_canon(i) for i in x) + ")"
    if isinstance(x, dict):
        return "{" + ",".join(f"{_canon(k)}:{_canon(v)}" for k, v in sorted(x.items(), key=lambda kv: repr(kv[0]))) + "}"
    raise _NotData(type(x).__name__)


#: attributes of a scene that are not its parameters (bookkeeping, or set by runs)
_NOT_PARAMETERS = frozenset({"reference_seconds", "variants", "stability_cases", "extra_schemes", "title", "paper",
                             "in_paper", "stiff_study", "figures_need_configuration", "stability_variant"})


def _parameters(scene):
    """``[(name, canonical text)]`` of the scene's public data attributes (class and instance)."""
    import inspect

    out = {}
    for klass in reversed(type(scene).__mro__):
        for k, val in vars(klass).items():
            if k.startswith("_") or k in _NOT_PARAMETERS or callable(val) or inspect.isdatadescriptor(val) \
                    or isinstance(val, (staticmethod, classmethod, property)):
                continue
            if inspect.ismethoddescriptor(val) or hasattr(val, "__set_name__"):  # e.g. cached_property
                continue
            out[k] = val
    for k, val in vars(scene).items():
        if k.startswith("_") or k in _NOT_PARAMETERS or k == "system":
            continue
        if callable(val):
            raise _NotData(f"attribute {k!r} is callable")
        out[k] = val
    return [(k, _canon(out[k])) for k in sorted(out)]


def _source_digest(scene):
    """SHA-256 of the text of liefi's modules (and of the scene's module when it lives outside liefi)."""
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # the liefi package
    files = [here]
    mod = sys.modules.get(type(scene).__module__)
    own = getattr(mod, "__file__", None)
    if own and not os.path.abspath(own).startswith(here + os.sep):
        files.append(os.path.abspath(own))
    key = tuple(files)
    with _LOCK:
        if key not in _SOURCE:
            h = hashlib.sha256()
            paths = []
            for root, dirs, names in os.walk(here):
                dirs[:] = sorted(d for d in dirs if d != "__pycache__")
                paths += [os.path.join(root, n) for n in sorted(names) if n.endswith(".py")]
            for p in paths + files[1:]:
                h.update(os.path.relpath(p, here).encode() + b"\0")
                with open(p, "rb") as fh:
                    h.update(hashlib.sha256(fh.read()).digest())
            _SOURCE[key] = h.hexdigest()
        return _SOURCE[key]


def key(scene, variant, what):
    """The store's key (hex) of ``what`` (e.g. ``("reference", t)``) for ``scene`` and ``variant``, or ``None``
    when the scene or ``what`` cannot be keyed."""
    import platform

    import scipy

    try:
        parts = [
            "liefi-reference-1",
            f"{type(scene).__module__}.{type(scene).__qualname__}",
            _canon(scene.name),
            _canon([variant.name, variant.energy, variant.field, variant.options]),
            _canon(_parameters(scene)),
            _canon(np.asarray(scene.initial_state(variant), float)),
            _canon(what),
            _source_digest(scene),
            f"python {platform.python_version()} numpy {np.__version__} scipy {scipy.__version__} "
            f"numba {importlib.util.find_spec('numba') is not None}",
        ]
        changed = getattr(scene, "_changed_data", lambda: None)()
        if changed is not None:  # the system's constants set since its build (scene.system.constants = ...)
            parts.append(f"constants {changed}")
    except (_NotData, OSError):
        return None
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


# ======================================================================================
# the files
# ======================================================================================


def _directory():
    """``(path, signing key)`` of the store, or ``None`` (after a warning when it cannot be used)."""
    from ..engine import cache as _cache

    base = _cache.kernel_dir()  # warns (once per process) when the directory cannot be used
    sign = _cache.signing_key(base) if base is not None else None
    if base is None or sign is None:
        _warn_once("dir", "liefi: the reference store is not used (no private cache directory or key); "
                          "references are solved in every run")
        return None
    path = os.path.join(base, FOLDER)
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
    except OSError as exc:
        _warn_once("dir", f"liefi: the reference store {path} cannot be created ({exc.strerror or exc}); "
                          "references are solved in every run")
        return None
    why = _cache.check_private(path)
    if why is not None:
        _warn_once("dir", f"liefi: the reference store {path} is not used: it {why}; references are solved in "
                          "every run")
        return None
    return path, sign


def _file(path, k):
    return os.path.join(path, f"{k}.npz")


def load(k):
    """The stored ``{name: array}`` under key ``k``, or ``None`` (missing, or not trusted: removed, with a warning)."""
    from ..engine.cache import tag

    where = _directory()
    if where is None:
        return None
    path, sign = where
    name = _file(path, k)
    try:
        with open(name, "rb") as fh:
            blob = fh.read()
    except FileNotFoundError:
        return None
    except OSError as exc:
        _warn_once("read", f"liefi: the stored result {name} cannot be read ({exc.strerror or exc}); "
                           "it is computed again")
        return None
    payload = blob[_HEAD:]
    import hmac

    trusted = blob[: len(MAGIC)] == MAGIC and hmac.compare_digest(blob[len(MAGIC):_HEAD],
                                                                  tag(sign, os.path.basename(name), payload))
    values = None
    if trusted:
        try:
            with np.load(io.BytesIO(payload), allow_pickle=False) as z:
                if str(z["key"]) == k:
                    names = [str(n) for n in z["names"]]
                    values = {n: z[f"v{i}"] for i, n in enumerate(names)}
        except Exception:  # noqa: BLE001 -- a signed file that does not read as ours: treat it as damaged
            values = None
    if values is None:
        warnings.warn(f"liefi: the stored result {name} is not trusted (not signed by liefi for this key, or "
                      "damaged); it was not used and is removed, and it is computed again (a reference is solved)",
                      ReferenceStoreWarning, stacklevel=3)
        try:
            os.remove(name)
        except OSError:
            pass
    return values


def save(k, values):
    """Keep ``values`` (``{name: array}``) under key ``k``; a failure to write warns once and is otherwise ignored."""
    from ..engine.cache import atomic_write, tag

    where = _directory()
    if where is None:
        return False
    path, sign = where
    name = _file(path, k)
    names = list(values)
    buf = io.BytesIO()
    arrays = {f"v{i}": np.asarray(values[n]) for i, n in enumerate(names)}
    if any(a.dtype == object for a in arrays.values()):
        return False
    np.savez(buf, key=np.array(k), names=np.array(names, dtype=str), **arrays)
    payload = buf.getvalue()
    try:
        atomic_write(name, MAGIC + tag(sign, os.path.basename(name), payload) + payload, prefix=".ref")
    except OSError as exc:
        _warn_once("write", f"liefi: the result cannot be kept in the store {path} ({exc.strerror or exc}); "
                            "the run goes on, and the next run computes it again (a reference is solved again)")
        return False
    _evict(path)
    return True


def _evict(path):
    """Remove the oldest files beyond :data:`MAX_ENTRIES` files or :data:`MAX_BYTES` bytes."""
    try:
        entries = sorted(((e.stat().st_mtime, e.stat().st_size, e.path) for e in os.scandir(path)
                          if e.name.endswith(".npz")), reverse=True)  # newest first
        total = 0
        for i, (_, size, name) in enumerate(entries):
            total += size
            if i >= MAX_ENTRIES or (i > 0 and total > MAX_BYTES):
                os.remove(name)
    except OSError:
        pass


def reference(scene, variant, t, compute):
    """``compute()`` (the reference ``{name: array}`` at ``t``), read from the store when it was kept before
    (:meth:`liefi.scenes.Scene.reference_values`)."""
    return remember(scene, variant, ("reference", np.asarray(t, float)), compute)


def remember(scene, variant, what, compute):
    """``compute()`` (a ``{name: array}``), read from the store when it was kept before for the same
    ``scene``, ``variant``, ``what`` and liefi code; else computed and kept.  The one entry point of the store."""
    if not enabled():
        return compute()
    k = key(scene, variant, what)
    if k is None:
        return compute()
    got = load(k)
    if got is not None:
        return got
    values = compute()
    try:
        flat = {n: np.asarray(v) for n, v in values.items()}
    except AttributeError:
        return values
    save(k, flat)
    return values
