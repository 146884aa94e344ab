r"""Flush-to-zero for the compiled loops: no slowdown from subnormal numbers.

A subnormal (denormal) double is a nonzero number below ``2.2e-308`` in
magnitude (``np.finfo(float).tiny``).  Many x86 cores handle an operation
that reads or produces one in microcode, tens of times slower than a normal
one.  Some solutions decay towards zero for ever: Suslov's
``Pi_2 = Pi_3 = sech t`` passes ``2.2e-308`` near ``t = 709`` (products such
as ``Pi_2^2`` near ``t = 355``) and the run's values stall in the subnormal
range (``~1e-321``), so every later step pays the penalty (about 25x per step
has been reported on Intel cores; 1.9x with Euler on an AMD EPYC,
``benchmarks/subnormals.py``).

The generated loops therefore run with the two SSE control bits of the x86
``MXCSR`` register that remove the slow path:

* FTZ (flush to zero, bit 15): a result that would be subnormal is 0;
* DAZ (denormals are zero, bit 6): a subnormal operand is read as 0.

:func:`fpu_enter` sets both and returns the caller's ``MXCSR``;
:func:`fpu_exit` writes it back.  The generated loop of one trajectory calls
them around its body (:func:`liefi.engine.codegen.loop_source`), so the
setting lasts exactly the loop and is made on the thread that runs it (the
batch loops run trajectories on numba's worker threads: each trajectory sets
and restores its own thread's register).  Nothing outside the loop sees it:
numpy, scipy and the caller's code run with the register as they left it.

Why this changes nothing beyond rounding: with FTZ and DAZ an operation
differs from IEEE arithmetic only where an operand or its exact result is
below ``2.2e-308`` in magnitude, and then by less than ``2.2e-308`` in
absolute value.  Over a run these changes add up to where they are visible
at all: a component that decays at rate ``lambda`` stops decaying once its
increment ``h lambda x`` is flushed, at ``|x| < 2.2e-308 / (h lambda)``
(Suslov at ``h = 1e-3``: ``2.2e-305``; numpy's run carries on to
``~1e-321``).  Every change is thus absolute and of order ``1e-305``: ``1e289``
times below the rounding unit ``1.1e-16`` of a state of norm 1, below the
absolute rounding error of every sum with a normal number of size above
``1e-289``, and invisible to the errors, the invariants and the stability
checks (all measured against numbers of order ``1e-16`` times the state's
scale).  Only a model whose own scale is near ``1e-300`` would see it, and it
sits at the edge of double precision anyway: rescale its units.

Why the register and not a flush in the generated step (``if abs(v) < tiny:
v = 0``): intermediates go subnormal long before the state does (``Pi_2^2``
from ``t = 355``, ``Pi_2`` from ``t = 709``), so flushing the state would leave
the slow arithmetic inside the field, and a compare per value costs on every
step; the register costs two instructions per loop, and the per-step cost of
the flushing loop equals that of the plain one where nothing is subnormal
(20.0 ns both, Suslov Euler to ``t = 300``).  No package is needed either.

The register is read and written with the LLVM intrinsics
``llvm.x86.sse.stmxcsr`` / ``llvm.x86.sse.ldmxcsr`` (a numba ``@intrinsic``:
no C extension, no ``ctypes``).  On other processors (ARM's ``FPCR.FZ`` is
not touched) both functions do nothing and :data:`ACTIVE` is False.
"""

from __future__ import annotations

import platform

#: the FTZ (bit 15) and DAZ (bit 6) bits of ``MXCSR``
FTZ_DAZ = 0x8040

#: True where the loops flush subnormals (an x86-64 processor)
ACTIVE = platform.machine().lower() in ("x86_64", "amd64")


def _python_enter():
    return 0


def _python_exit(state):
    return None


try:  # numba is optional: without it the generated code runs as Python, with nothing to set
    from numba import njit as _njit
    from numba import types as _types
    from numba.extending import intrinsic as _intrinsic
except Exception:  # noqa: BLE001 -- any import failure means "no numba"
    _njit = None
    ACTIVE = False

if _njit is not None and ACTIVE:
    from llvmlite import ir as _ir
    from numba.core import cgutils as _cgutils

    def _csr_call(builder, name, slot):
        ptr = _ir.IntType(8).as_pointer()
        fn = _cgutils.get_or_insert_function(builder.module, _ir.FunctionType(_ir.VoidType(), [ptr]), name)
        builder.call(fn, [builder.bitcast(slot, ptr)])

    @_intrinsic
    def _stmxcsr(typingctx):
        def codegen(context, builder, signature, args):
            slot = _cgutils.alloca_once(builder, _ir.IntType(32))
            _csr_call(builder, "llvm.x86.sse.stmxcsr", slot)
            return builder.zext(builder.load(slot), _ir.IntType(64))

        return _types.int64(), codegen

    @_intrinsic
    def _ldmxcsr(typingctx, value):
        def codegen(context, builder, signature, args):
            slot = _cgutils.alloca_once(builder, _ir.IntType(32))
            builder.store(builder.trunc(args[0], _ir.IntType(32)), slot)
            _csr_call(builder, "llvm.x86.sse.ldmxcsr", slot)
            return context.get_dummy_value()

        return _types.void(_types.int64), codegen

    # not cached on disk here: they compile into the generated loops, which numba caches
    @_njit
    def fpu_enter():
        """Set FTZ and DAZ on the calling thread; returns the previous ``MXCSR`` for :func:`fpu_exit`."""
        old = _stmxcsr()
        _ldmxcsr(old | FTZ_DAZ)
        return old

    @_njit
    def fpu_exit(state):
        """Restore the ``MXCSR`` returned by :func:`fpu_enter`."""
        _ldmxcsr(state)

    @_njit
    def read_mxcsr():
        """``MXCSR`` of the calling thread."""
        return _stmxcsr()

elif _njit is not None:  # another processor: compiled no-ops
    fpu_enter = _njit(_python_enter)
    fpu_exit = _njit(_python_exit)
    read_mxcsr = _njit(_python_enter)
else:
    fpu_enter, fpu_exit, read_mxcsr = _python_enter, _python_exit, _python_enter
