"""Alias of :mod:`liefi.engine` kept while code that imports ``liefi.compiled`` moves over.

Everything public lives in :mod:`liefi.engine`; import it from there.
"""

from __future__ import annotations

from .engine import *  # noqa: F401,F403
from .engine import __all__  # noqa: F401


def __getattr__(name):
    from . import engine

    return getattr(engine, name)
