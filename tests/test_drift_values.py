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
