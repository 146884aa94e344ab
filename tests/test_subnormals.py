"""Compiled loops flush subnormal numbers to zero for their duration only (liefi.engine.fpu).

Suslov's ``Pi_2 = Pi_3 = sech t`` decays through the subnormal range.  The
tests start the Suslov motion at ``Pi = (-1, s, s)`` with ``s = 1e-305`` (on
the constraint set: ``<Pi, e> = 0`` for any ``(x, s, s)``), so that a short run
crosses ``2.2e-308`` and products such as ``Pi_2^2`` are subnormal from the
first step.
"""

import numpy as np
import pytest

from liefi import engine, scenes

needs_numba = pytest.mark.skipif(not engine.available(), reason="numba is not installed")

TINY = np.finfo(float).tiny  # 2.2e-308, the smallest normal double
CONTROL = 0xFFC0  # MXCSR's control bits (masks, rounding, FTZ, DAZ); bits 0-5 are sticky status flags


def _near_subnormal_suslov():
    sc = scenes.get("suslov")
    y0 = np.concatenate([np.eye(3).ravel(), [-1.0, 1e-305, 1e-305]])
    return sc.integrator(y0=y0, configuration=False)


def _subnormal(a):
    a = np.abs(np.asarray(a))
    return (a > 0) & (a < TINY)


@needs_numba
def test_caller_state_restored_after_compiled_runs():
    from liefi.engine import fpu

    fi = _near_subnormal_suslov()
    before = fpu.read_mxcsr() & CONTROL
    fi.run(1.0, dt=1e-2, scheme="euler", backend="numba", check_stability=False)
    fi.run(1.0, dt=1e-2, scheme="imex-rk4", backend="numba", check_stability=False)
    fi.run(1.0, dt=1e-2, scheme="rk4", y0=np.stack([fi.y0, fi.y0]), backend="numba", check_stability=False)  # batch
    assert fpu.read_mxcsr() & CONTROL == before
    if fpu.ACTIVE:
        assert not before & fpu.FTZ_DAZ  # the caller did not flush ...
    # ... and still does not: numpy and Python keep IEEE subnormals after the runs
    assert np.finfo(float).tiny / 2 > 0.0
    assert np.float64(TINY) / np.float64(2.0) == 1.1125369292536007e-308
    assert np.multiply(np.full(3, 1e-300), 1e-10)[0] > 0.0


@needs_numba
@pytest.mark.parametrize("scheme", ["euler", "imex-rk4"])
def test_compiled_run_through_subnormals_matches_numpy(scheme):
    """numpy keeps subnormal values; the compiled loop flushes them: the states agree to rounding.

    The flush zeroes any result below ``2.2e-308``, e.g. the increment ``h k`` of a
    component that decays at rate ``lambda``: it stalls below ``2.2e-308 / (h lambda)``
    (``~7e-306`` here, ``h = 1e-2``, ``lambda ~ 1``) where numpy's keeps decaying.  The
    change is absolute and far below the rounding unit of the state
    (``Pi_1 = -1``: ``1.1e-16``).  We ask for agreement to ``1e-15`` absolute (the
    state has norm ~1), relative agreement of the components above ``1e-300``,
    absolute agreement below ``100 * 2.2e-308 / h`` of the others, and check that
    the run really went through the subnormal range in numpy and never in the
    compiled loop (where a subnormal result is 0).
    """
    from liefi.engine import fpu

    fi = _near_subnormal_suslov()
    a = fi.run(10.0, dt=1e-2, scheme=scheme, backend="numpy", check_stability=False)
    b = fi.run(10.0, dt=1e-2, scheme=scheme, backend="numba", check_stability=False)
    assert b.backend == "numba"
    assert np.max(np.abs(a.y - b.y)) <= 1e-15
    small = np.abs(a.y[-2:]) < 1e-300
    np.testing.assert_allclose(b.y[-2:][~small], a.y[-2:][~small], rtol=1e-12, atol=0)  # normal values: relative
    assert np.max(np.abs(a.y[-2:][small] - b.y[-2:][small]), initial=0.0) < 100 * TINY / 1e-2
    assert _subnormal(a.y).any() or _subnormal(a.y[-2:] * a.y[-2:]).any()
    if fpu.ACTIVE:
        assert not _subnormal(b.y).any()
