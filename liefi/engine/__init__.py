"""liefi's compiled engine: the library's own functions traced into scalar code and compiled.

The numpy path (:meth:`liefi.FeedbackIntegrator.vector_field` ->
:func:`liefi.reduction.core.evaluate`) is batch-first and generic, about 20
microseconds per call whatever the system.  The engine runs *those same
functions* once on arrays of symbols (:mod:`liefi.engine.trace`), prints the
recorded graph as straight-line code (:mod:`liefi.engine.codegen`), loads it
through a private, self-healing cache (:mod:`liefi.engine.cache`; numba's
cache files signed and checked before they are loaded, :mod:`liefi.engine.numba_cache`) and runs the
whole fixed-step loop compiled by numba (:mod:`liefi.engine.runners`).  There
is no second copy of any formula: a change to the core changes both backends
(``tests/test_compiled.py`` checks this).  The kernels themselves are in
:mod:`liefi.engine.kernels`.

The compiled and numpy paths agree to ``1e-12``: the formulas are the same,
only the order of a few floating-point sums differs, and sums that cancel in
exact arithmetic (``(2 b - c) + (c - b) = b``, ``m sin^2 x + m cos^2 x = m``)
are computed in their reduced form, with fewer roundings
(:mod:`liefi.engine.symbolic`).  Without numba the
generated code still runs as plain Python (``engine="python"``, slow: for
debugging and tests); ``FeedbackIntegrator.run(backend="numba"/"auto")`` then
warns (:class:`CompilationWarning`) and runs the numpy path, as it does for an
untraceable datum or group method and for a kernel that fails to load or
compile.  A kernel cache that cannot be used or written (unsafe, read-only, a
full disk) is not such a failure: the kernel is compiled in memory.

Modules
-------
symbolic
    :class:`Sym` scalars: constant folding, exact sign rules, sharing, the exact algebra on sums,
    symbolic derivatives.
trace
    Tracing sessions, traced solves, :class:`TracedData`.
codegen
    Straight-line source of a graph; the stepping, projection and DLA loops.
cache
    The private kernel directory, loading, healing corrupt entries.
numba_cache
    numba's cache files of the kernels: in that directory only, signed and checked.
runners
    :class:`CompiledField` and :class:`CompiledDLA`: running the loaded kernels.
kernels
    What is traced (the feedback, constrained and DLA kernels) and the ``run`` hook.
"""

from __future__ import annotations

from .cache import KernelCacheWarning, available
from .kernels import (
    compile_constrained,
    compile_dla,
    compile_feedback,
    compile_split,
    dla_applies,
    invariant_residuals,
    parameters,
    projection_targets,
    run_feedback,
)
from .runners import CompiledDLA, CompiledField, KernelLoadError
from .trace import CompilationWarning, NotCompilable

__all__ = [
    "available",
    "CompilationWarning",
    "KernelCacheWarning",
    "KernelLoadError",
    "NotCompilable",
    "compile_feedback",
    "compile_split",
    "compile_constrained",
    "compile_dla",
    "dla_applies",
    "invariant_residuals",
    "parameters",
    "projection_targets",
    "run_feedback",
    "CompiledField",
    "CompiledDLA",
]


def __getattr__(name):
    if name == "NUMBA_ERROR":  # set when an import of numba failed (read live, not at import time)
        from . import cache

        return cache.NUMBA_ERROR
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
