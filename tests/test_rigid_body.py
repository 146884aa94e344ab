"""The rigid-body scene (Bae & Chang's benchmark): a K = 0 system, the Lie-Poisson splitting, projected RK4."""

import warnings

import numpy as np
import pytest

from liefi import engine, scenes
from liefi.scenes.rigid_body import splitting

SC = scenes.get("rigid-body")


def test_scene_is_unconstrained_free_rigid_body():
    assert SC.system.K == 0
    fi = SC.integrator()
    assert fi.invariant_names == ("penalty", "energy", "casimir")
    assert fi.gains == {"penalty": 50.0, "energy": 100.0, "casimir": 50.0}
    assert np.allclose(fi.y0[9:], [3.0, 2.0, 1.0])
    # the extended field is Euler's: Pi' = Pi x Omega, R' = R hat(Omega)
    X = fi.unforced_vector_field(fi.y0)
    Om = fi.y0[9:] / SC.inertia
    assert np.allclose(X[9:], np.cross(fi.y0[9:], Om), rtol=1e-12, atol=1e-14)
    hat = np.array([[0, -Om[2], Om[1]], [Om[2], 0, -Om[0]], [-Om[1], Om[0], 0]])
    assert np.allclose(X[:9], (np.eye(3) @ hat).ravel(), rtol=1e-12, atol=1e-14)
    # without the configuration the penalty has no gain
    assert SC.integrator(configuration=False).invariant_names == ("energy", "casimir")


def _rk4_reference(T, h):
    fi = SC.integrator()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = fi.with_gains(0.0).run(T, dt=h, scheme="rk4", check_stability=False)
    return sol.y[:, -1]


def test_splitting_is_second_order_and_keeps_casimir_momentum_orthogonality():
    fi = SC.integrator()
    T = 2.0
    ref = _rk4_reference(T, 1e-3)
    errs = []
    for h in (2e-2, 1e-2):
        _, Y, _ = splitting(fi.y0[:9], fi.y0[9:], SC.inertia, h, int(round(T / h)))
        errs.append(np.max(np.abs(Y[:, -1] - ref)))
    assert 3.6 < errs[0] / errs[1] < 4.4
    _, Y, _ = splitting(fi.y0[:9], fi.y0[9:], SC.inertia, 1e-2, 20000, 100)
    R = Y[:9].T.reshape(-1, 3, 3)
    Pi = Y[9:].T
    assert np.max(np.abs(np.linalg.norm(Pi, axis=1) - np.sqrt(14.0))) < 1e-12
    assert np.max(np.linalg.norm(np.swapaxes(R, 1, 2) @ R - np.eye(3), axis=(1, 2))) < 1e-12
    m = np.einsum("tij,tj->ti", R, Pi)
    assert np.max(np.abs(m - [3.0, 2.0, 1.0])) < 1e-11
    E = 0.5 * np.sum(Pi**2 / SC.inertia, 1)
    assert 0 < np.max(np.abs(E - 3.0)) < 1e-4  # bounded O(h^2) energy error, not exact


def test_scene_runs_splitting_and_projected_rk4():
    r = SC.run(scheme="splitting", dt=1e-2, t_final=5.0)
    assert r.max_drift["casimir"] < 1e-12 and r.max_drift["orthogonality"] < 1e-12
    assert max(r.max_error.values()) < 1e-3
    if not engine.available():
        pytest.skip("projected-rk4 needs numba")
    r = SC.run(scheme="projected-rk4", dt=1e-2, t_final=5.0)
    assert max(r.max_drift.values()) < 1e-12
    assert max(r.max_error.values()) < 1e-6


def test_compiled_reference_equals_numpy_reference():
    v = SC.variant()
    t = np.linspace(0.0, 5.0, 51)
    a, b = SC.exact(t, v), SC.numerical_reference(t, v)
    assert set(a) == set(b)
    assert max(np.max(np.abs(a[k] - b[k])) for k in a) < 1e-10
