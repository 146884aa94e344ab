"""Fingerprints of pure data: how the compiled engine finds a kernel without tracing (issue 26).

A system built by liefi from *data* -- sympy expressions (:func:`liefi.from_sympy`,
:func:`liefi.from_mechanics`), numbers and liefi's own contact functions
(:func:`liefi.systems.rolling.rolling_body` with :func:`~liefi.systems.rolling.sphere`,
:func:`~liefi.systems.rolling.ellipsoid`, :func:`~liefi.systems.rolling.disk`) -- is
determined by those data and by liefi's code.  Its builder stamps it with
:func:`digest` of the data (:func:`stamp`), and the engine then names a kernel by

.. math:: \\mathrm{SHA256}(\\text{liefi's sources},\\ \\text{the system's stamp},\\ \\text{its constants},
          \\ \\text{the integrator's settings},\\ \\text{the kernel's kind})

(:func:`liefi.engine.kernels.kernel_fingerprint`), which it can compute without running any
user code.  A later process with the same fingerprint loads the kernel the first one
generated, without tracing.  Anything that cannot be fingerprinted -- a user's callable,
an object liefi does not know -- makes :func:`digest` return ``None``, and the system keeps
the safe path (traced in every process).

Encoding: every value is written with its type and length, so that no two different
values share an encoding; floats by :meth:`float.hex` (exact), arrays by dtype, shape and
bytes, sympy objects by :func:`sympy.srepr` with the process-local indices of their
``Dummy`` symbols renumbered by first appearance (the same model in two processes gets the
same fingerprint; two different dummies in one model stay apart).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import sys
import threading
import types
import weakref

import numpy as np

#: the attribute holding the fingerprint of a function or a system
ATTR = "_liefi_fingerprint"
#: the attribute holding the ids of a stamped system's attributes at the time it was stamped
_IDS = "_liefi_fingerprint_ids"


class _Unknown(Exception):
    """A value :func:`digest` cannot fingerprint (a user's callable, an unknown object)."""


_ROOT = os.path.dirname(os.path.abspath(__file__))


def _liefi_file(path):
    """True for a path inside liefi's package (a file :func:`sources` hashes)."""
    return isinstance(path, str) and os.path.abspath(path).startswith(_ROOT + os.sep)


def _liefi_function(f):
    """True for a function whose code is in liefi's own files: its module's name is not enough (a user's function can
    carry any ``__module__``), its code object's file decides."""
    code = getattr(f, "__code__", None)
    return code is not None and (getattr(f, "__module__", None) or "").startswith("liefi.") and _liefi_file(code.co_filename)


def _liefi_class(cls):
    """True for a class defined in liefi's own files, and every class it derives from (``object`` aside)."""
    for k in cls.__mro__[:-1]:
        mod = getattr(k, "__module__", None) or ""
        if not mod.startswith("liefi.") or not _liefi_file(getattr(sys.modules.get(mod), "__file__", None)):
            return False
    return True


class _Mark:
    """The fingerprint :func:`mark` gave one function: it holds for that function only (``functools.wraps``
    copies a function's attributes to a wrapper of the user's, which computes something else)."""

    __slots__ = ("value", "owner")

    def __init__(self, value, owner):
        self.value, self.owner = value, weakref.ref(owner)

    def get(self, obj):
        return self.value if self.owner() is obj else None


def _is_sympy(x):
    """A sympy expression or matrix (without importing sympy: a sympy object means it is imported)."""
    sp = sys.modules.get("sympy")
    return sp is not None and isinstance(x, (sp.Basic, sp.MatrixBase))


def _encode(h, x, dummies):
    def put(tag, payload=b""):
        h.update(tag + len(payload).to_bytes(8, "little") + payload)

    known = dummies.get(("known", id(x))) if not isinstance(x, (int, float, str)) else None
    if known is not None:  # an object the caller names (a part of a stamped system)
        put(b"K", known.encode())
    elif x is None or isinstance(x, (bool, np.bool_)):
        put(b"N" if x is None else (b"T" if x else b"F"))
    elif isinstance(x, (int, np.integer)):
        put(b"I", str(int(x)).encode())
    elif isinstance(x, (float, np.floating)):
        put(b"D", float(x).hex().encode())
    elif isinstance(x, (complex, np.complexfloating)):
        put(b"C", (complex(x).real.hex() + "," + complex(x).imag.hex()).encode())
    elif isinstance(x, str):
        put(b"S", x.encode())
    elif isinstance(x, bytes):
        put(b"B", x)
    elif isinstance(x, (tuple, list)):
        put(b"L", str(len(x)).encode())
        for v in x:
            _encode(h, v, dummies)
    elif isinstance(x, dict):
        put(b"M", str(len(x)).encode())
        for k in sorted(x, key=repr):
            _encode(h, k, dummies)
            _encode(h, x[k], dummies)
    elif isinstance(x, np.ndarray):
        if x.dtype == object:
            _encode(h, ("object array", x.shape, x.reshape(-1).tolist()), dummies)
        else:
            put(b"A", f"{x.dtype.str}{x.shape}".encode() + np.ascontiguousarray(x).tobytes())
    elif _resolved(x) is not None:
        put(b"X", _resolved(x).encode())
    elif isinstance(x, types.FunctionType) and _liefi_function(x):
        # liefi's own function (its code is in sources()): named, with the data it closes over
        cells = tuple(c.cell_contents for c in (x.__closure__ or ()))
        _encode(h, ("function", x.__module__, x.__qualname__, x.__defaults__, x.__kwdefaults__, cells), dummies)
    elif dataclasses.is_dataclass(x) and not isinstance(x, type) and _liefi_class(type(x)):
        # a record of data of liefi's (a scene's Variant); a user's dataclass has code of its own (a __call__)
        _encode(h, (type(x).__module__, type(x).__qualname__,
                    {f.name: getattr(x, f.name) for f in dataclasses.fields(x)}), dummies)
    elif _is_sympy(x):
        put(b"Y", _sympy_text(x, dummies).encode())
    else:
        raise _Unknown(type(x).__name__)


_PRINTER = []


def _sympy_text(x, dummies):
    """``sympy.srepr(x)`` with each ``Dummy``'s process-local index written as its number of first appearance
    (``dummy_index=#0`` ...), by the printer itself: a symbol's *name* holding the text ``dummy_index=5`` stays
    as it is (a substitution in the text renumbered it too, and two different names had one encoding)."""
    if not _PRINTER:
        from sympy.printing.repr import ReprPrinter

        class Printer(ReprPrinter):
            def _print_Dummy(self, expr):
                d = dict(expr._assumptions_orig)
                d["dummy_index"] = "#%d" % self.dummies.setdefault(str(expr.dummy_index), len(self.dummies))
                return "%s(%s, %s)" % (type(expr).__name__, self._print(expr.name),
                                       ", ".join("%s=%s" % kv for kv in d.items()))

        _PRINTER.append(Printer)
    printer = _PRINTER[0]()
    printer.dummies = dummies
    return printer.doprint(x)


def digest(*parts, known=None):
    """The SHA-256 (hex) of ``parts`` (pure data: numbers, strings, arrays, sympy objects, marked functions,
    tuples, lists and dicts of them); ``None`` when some part cannot be fingerprinted (a user's callable).

    ``known``: ``{label: object}``, objects written as their label (the parts of a stamped system a
    function of liefi's closes over: the system's own data, fingerprinted by its stamp).
    """
    h = hashlib.sha256()
    try:
        _encode(h, parts, {("known", id(o)): label for label, o in (known or {}).items() if o is not None})
    except _Unknown:
        return None
    except RecursionError:  # a pathologically deep expression: no fingerprint, the safe path
        return None
    return h.hexdigest()


def mark(fun, *parts):
    """Give the function ``fun`` (made by liefi from the data ``parts``) the fingerprint of those data; return it."""
    fp = digest(*parts)
    if fp is not None:
        setattr(fun, ATTR, _Mark(fp, fun))
    return fun


def of(obj, known=None):
    """The fingerprint of the function ``obj``: the one :func:`mark` gave it, or for liefi's own function
    that of its name and the data it closes over (``known`` as in :func:`digest`); ``None`` for any other
    (a user's function)."""
    fp = _resolved(obj)
    return fp if fp is not None else digest(obj, known=known)


class _Deferred:
    """The fingerprint of a stamp's data, computed when first asked for (:func:`stamp`)."""

    __slots__ = ("parts", "value")
    _lock = threading.Lock()

    def __init__(self, parts):
        self.parts, self.value = parts, None

    def get(self):
        with self._lock:
            if self.parts is not None:
                self.value, self.parts = digest(*self.parts), None
            return self.value


def _frozen(x):
    """``x`` with its lists, tuples, dicts and arrays copied (a later change to them does not change a stamp)."""
    if isinstance(x, (list, tuple)):
        return type(x)(_frozen(v) for v in x) if type(x) in (list, tuple) else x
    if type(x) is dict:
        return {k: _frozen(v) for k, v in x.items()}
    if isinstance(x, np.ndarray):
        return x.copy()
    return x


def _resolved(obj):
    """The fingerprint ``obj`` carries (a deferred stamp's computed now), or ``None``."""
    fp = getattr(obj, ATTR, None)
    if isinstance(fp, _Mark):
        return fp.get(obj)
    return fp.get() if isinstance(fp, _Deferred) else None


def stamp(system, *parts):
    """Stamp ``system`` (built by liefi from the data ``parts`` alone) with their fingerprint; return it.

    The fingerprint is computed when it is first asked for (:func:`of_system`: the compiled engine's
    kernel lookup), from the data as they were at the stamp (its containers and arrays are copied now):
    printing a large model's expressions (``sympy.srepr``) cost a build up to 40 % of its time, and a
    run on the numpy path never needs it.  Nothing is stamped (``of_system`` gives ``None``) when a
    part cannot be fingerprinted.  The ids of the system's attributes are kept: an attribute
    assigned afterwards (new data in the same object) voids the stamp (:func:`of_system`).
    """
    ids = {k: id(v) for k, v in vars(system).items()}
    setattr(system, ATTR, _Deferred(_frozen(parts)))
    setattr(system, _IDS, ids)
    return system


def of_system(system):
    """The stamp of ``system``, or ``None`` (not built from pure data, or one of its attributes replaced since)."""
    fp = _resolved(system)
    ids = getattr(system, _IDS, None)
    if fp is None or ids is None:
        return None
    d = vars(system)
    if any(k not in d or id(d[k]) != i for k, i in ids.items()):
        return None
    return fp


_SOURCES = []
_SOURCES_LOCK = threading.Lock()


def sources():
    """SHA-256 of liefi's own source files (``liefi/**/*.py``, by relative path and content), once per process.

    Part of every kernel fingerprint: a kernel generated by other code (another version,
    an edited checkout) is never found by a fingerprint.
    """
    with _SOURCES_LOCK:
        if not _SOURCES:
            root = os.path.dirname(os.path.abspath(__file__))
            h = hashlib.sha256()
            for d, dirs, files in os.walk(root):
                dirs.sort()
                for f in sorted(files):
                    if f.endswith(".py"):
                        p = os.path.join(d, f)
                        with open(p, "rb") as fh:
                            data = fh.read()
                        _encode(h, (os.path.relpath(p, root).replace(os.sep, "/"), data), {})
            _SOURCES.append(h.hexdigest())
        return _SOURCES[0]


def _liefi_code(v):
    """True for a function, method or descriptor defined in liefi's own modules (covered by :func:`sources`)."""
    f = getattr(v, "__func__", None) or getattr(v, "fget", None) or getattr(v, "func", None) or v
    return _liefi_function(f) or isinstance(f, type) and _liefi_class(f)


def object_data(obj, skip=()):
    """The data of ``obj`` (an object of one of liefi's classes, e.g. a scene), for :func:`stamp`; ``None`` when
    it is not only liefi's code and pure data.

    Every class of ``obj`` (its MRO) must be defined in liefi; their attributes that are liefi's
    functions or descriptors are code (covered by :func:`sources`), the others data, and so is every
    attribute of ``obj`` itself (except ``skip``).  A function from elsewhere (a user's subclass, a
    replaced method, a user's callable in an attribute) gives ``None``: no stamp, the safe path.
    """
    parts = []
    if not _liefi_class(type(obj)):
        return None
    for cls in type(obj).__mro__:
        if cls is object:
            continue
        for k, v in sorted(vars(cls).items()):
            if k.startswith("__"):
                continue
            if callable(v) or hasattr(v, "__get__") and not isinstance(v, (int, float, str, tuple, np.ndarray)):
                if not _liefi_code(v):
                    return None
                continue
            parts.append((cls.__qualname__, k, v))
    parts += [("self", k, v) for k, v in sorted(vars(obj).items()) if k not in skip]
    return parts if digest(parts) is not None else None
