"""Strict JSON: what every JSON output of liefi is written with.

Python's ``json`` writes ``NaN``, ``Infinity`` and ``-Infinity`` by default;
they are not JSON (RFC 8259; ``JSON.parse`` and every strict parser refuse
them).  liefi writes a non-finite number as ``null``; each output documents
what ``null`` means in its fields (for instance ``liefi stability --json``:
``"bound": null`` is a scheme with no real stability bound).
"""

from __future__ import annotations

import json


def plain(x):
    """``x`` with numpy arrays and scalars as Python lists and numbers, tuples as lists and every
    non-finite float as ``None``: strict JSON, which SQLite's ``json_extract`` can read."""
    import numpy as np

    if isinstance(x, dict):
        return {k: plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and (x != x or x in (float("inf"), float("-inf"))):
        return None
    return x


def dumps(obj, *, default=None, **kw):
    """``json.dumps`` of :func:`plain` ``(obj)`` with ``allow_nan=False``: never ``NaN`` or ``Infinity``.

    ``default`` converts other objects (as in :func:`json.dumps`); what it returns
    is made plain too.
    """
    hook = None if default is None else (lambda o: plain(default(o)))
    return json.dumps(plain(obj), allow_nan=False, default=hook, **kw)
