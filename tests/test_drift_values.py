"""The drift measurement reads values only (issue 26): no Jacobian of the data in drift_scales and drift."""

import numpy as np
import pytest

from liefi import _diff, scenes
from liefi.drift import drift, drift_scales


@pytest.mark.parametrize("name", ["knife-edge", "rattleback"])
def test_drift_measurement_computes_no_jacobian(name, monkeypatch):
    """``drift_scales`` and ``drift`` (without a jet) do not differentiate the data, and agree to rounding with
    the residuals of ``invariant_gradients`` (which does) and its scales with the derivatives."""
    fi = scenes.get(name).integrator()
    rng = np.random.default_rng(1)
    Y = fi.y0 + 1e-3 * rng.standard_normal((5,) + fi.y0.shape)
    jet = fi.invariant_gradients(Y)  # the reference, with gradients
    calls = []

    def no_jacobian(*a, **k):
        calls.append(a)
        raise AssertionError("drift measurement computed a Jacobian")

    monkeypatch.setattr(_diff, "jacobian", no_jacobian)
    scales = drift_scales(fi, Y[0])
    got, who = drift(fi, Y, scales)
    assert not calls
    monkeypatch.undo()
    want, who_want = drift(fi, Y, scales, jet)
    assert who == who_want and abs(got - want) <= 1e-13 * want, (got, want)


@pytest.mark.parametrize("name", ["bicycle", "rattleback", "kepler"])
def test_drift_evaluates_the_data_once(name, monkeypatch):
    """``drift`` without a jet evaluates the data's values once at the states (the residuals and the scales at
    them both read it: before, ``residuals`` and ``drift_scales`` each evaluated them, 2 calls; the bicycle's
    step choice spent a tenth of its profile in its two drifts), and gives exactly what the two separate
    evaluations give."""
    from liefi.integrator import drift as drift_module
    from liefi.reduction import core

    fi = scenes.get(name).integrator()
    rng = np.random.default_rng(2)
    Y = fi.y0 + 1e-3 * rng.standard_normal((7,) + fi.y0.shape)
    scales = drift_scales(fi, Y[0])
    # the reference: the two evaluations made separately (the jet given, drift evaluates the scales on its own)
    ref = drift(fi, Y, scales, drift_module.residuals(fi, Y))
    calls = []
    real = core.evaluate

    def counted(*a, **k):
        calls.append(k.get("derivatives", True))
        return real(*a, **k)

    monkeypatch.setattr(core, "evaluate", counted)
    got = drift(fi, Y, scales)
    monkeypatch.undo()
    assert calls == [False], calls  # one evaluation, values only
    assert got == ref and got[0] > 0, (got, ref)  # bit for bit: the same values, the same arithmetic
