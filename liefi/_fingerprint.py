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

import hashlib
import os
import re
import threading

import numpy as np

#: the attribute holding the fingerprint of a function or a system
ATTR = "_liefi_fingerprint"
#: the attribute holding the ids of a stamped system's attributes at the time it was stamped
_IDS = "_liefi_fingerprint_ids"

_DUMMY = re.compile(r"dummy_index=(\d+)")


class _Unknown(Exception):
    """A value :func:`digest` cannot fingerprint (a user's callable, an unknown object)."""


def _encode(h, x, dummies):
    def put(tag, payload=b""):
        h.update(tag + len(payload).to_bytes(8, "little") + payload)

    if x is None or isinstance(x, (bool, np.bool_)):
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
    elif getattr(x, ATTR, None) is not None:
        put(b"X", getattr(x, ATTR).encode())
    elif type(x).__module__.split(".")[0] == "sympy" and hasattr(x, "free_symbols"):
        import sympy

        text = _DUMMY.sub(lambda m: "dummy_index=#%d" % dummies.setdefault(m.group(1), len(dummies)),
                          sympy.srepr(x))
        put(b"Y", text.encode())
    else:
        raise _Unknown(type(x).__name__)


def digest(*parts):
    """The SHA-256 (hex) of ``parts`` (pure data: numbers, strings, arrays, sympy objects, marked functions,
    tuples, lists and dicts of them); ``None`` when some part cannot be fingerprinted (a user's callable)."""
    h = hashlib.sha256()
    try:
        _encode(h, parts, {})
    except _Unknown:
        return None
    except RecursionError:  # a pathologically deep expression: no fingerprint, the safe path
        return None
    return h.hexdigest()


def mark(fun, *parts):
    """Give the function ``fun`` (made by liefi from the data ``parts``) the fingerprint of those data; return it."""
    fp = digest(*parts)
    if fp is not None:
        setattr(fun, ATTR, fp)
    return fun


def of(obj):
    """The fingerprint :func:`mark` gave ``obj``, or ``None``."""
    return getattr(obj, ATTR, None)


def stamp(system, *parts):
    """Stamp ``system`` (built by liefi from the data ``parts`` alone) with their fingerprint; return it.

    Nothing is stamped when a part cannot be fingerprinted.  The ids of the system's
    attributes are kept: an attribute assigned afterwards (new data in the same object)
    voids the stamp (:func:`of_system`).
    """
    fp = digest(*parts)
    if fp is not None:
        ids = {k: id(v) for k, v in vars(system).items()}
        setattr(system, ATTR, fp)
        setattr(system, _IDS, ids)
    return system


def of_system(system):
    """The stamp of ``system``, or ``None`` (not built from pure data, or one of its attributes replaced since)."""
    fp = getattr(system, ATTR, None)
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
