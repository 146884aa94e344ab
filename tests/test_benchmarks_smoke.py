"""Smoke test of the rattleback peer (``benchmarks/rattleback_pydy.py``, issue 18).

The peer's model, derived by ``sympy.physics.mechanics.KanesMethod``, is checked
against Kane & Levinson's (1982) closed-form equations of the angular
acceleration (their eqs. 16--70, written out here as an independent oracle, in
their frame: ``b_3`` down, so ``D``, ``omega_2``, ``omega_3`` and the pitch change sign),
and a 0.1 s run keeps energy and the no-slip constraint to the tolerance.
The full measurement is the benchmark script itself.
"""

import importlib.util
import os

import numpy as np
import pytest

pytest.importorskip("sympy")
pytest.importorskip("scipy")

_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                     "benchmarks", "rattleback_pydy.py")


@pytest.fixture(scope="module")
def peer():
    spec = importlib.util.spec_from_file_location("rattleback_pydy", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    model = mod.build_model()
    rhs, outputs, _ = mod.generate(model, "lambdify")
    mod.build_model = lambda: model  # the script's main reuses this derivation below
    return mod, rhs, outputs


def kane_levinson_omega_dot(p, alpha, beta, w):
    """Kane & Levinson's omega' (their frame, b_3 down), per unit mass, sigma = 0."""
    a2 = np.array([p["a"], p["b"], p["c"]]) ** 2
    A, B, C = (p[k] / p["m"] for k in "ABC")
    D = -p["D"] / p["m"]
    I0 = np.array([[A, D, 0.0], [D, B, 0.0], [0.0, 0.0, C]])
    mu = np.array([-np.cos(alpha) * np.sin(beta), np.sin(alpha), np.cos(alpha) * np.cos(beta)])
    eps = np.sqrt(a2 @ mu**2)
    x = a2 * mu / eps
    dmu = np.cross(mu, w)
    deps = a2 @ (mu * dmu) / eps
    dx = a2 * (eps * dmu - deps * mu) / eps**2
    x[2] -= p["h"]
    v = np.cross(x, w)
    zeta = np.cross(w, v - dx)
    rhs = p["g"] * np.cross(mu, x) + np.cross(I0 @ w, w) + np.cross(x, zeta)
    inertia = I0 + (x @ x) * np.eye(3) - np.outer(x, x)
    return np.linalg.solve(inertia, rhs)


def test_kanes_method_matches_kane_levinson(peer):
    mod, rhs, _ = peer
    rng = np.random.default_rng(18)
    for _ in range(5):
        yaw, roll, pitch = rng.uniform(-0.4, 0.4, 3)
        w = rng.normal(0.0, 3.0, 3)
        y = mod.state_on_constraint(yaw, roll, pitch, w)
        dw = rhs(0.0, y)[5:8]
        ref = kane_levinson_omega_dot(mod.PARAMS, roll, -pitch, w * np.array([1, -1, -1]))
        np.testing.assert_allclose(dw * np.array([1, -1, -1]), ref, rtol=1e-10,
                                   atol=1e-10 * np.abs(ref).max())


def test_short_run_keeps_energy_and_no_slip(peer):
    mod, rhs, outputs = peer
    y0 = mod.initial_state()
    E0, slip0, spin0 = (v[0] for v in outputs(y0[:, None]))
    assert slip0 < 1e-15 and spin0 > 4.9  # on the constraint, spinning the "wrong" way
    sol, _ = mod.integrate(rhs, y0, 0.1, "DOP853", 1e-10)
    E, slip, _ = outputs(sol.y)
    assert np.max(np.abs(E - E0)) / abs(E0) < 1e-9
    assert np.max(slip) < 1e-9


def test_script_writes_its_table(peer, tmp_path, capsys):
    mod, _, _ = peer
    rows = mod.main(["--t-final", "0.2", "--tols", "1e-6", "--methods", "RK45", "--ref-tol", "1e-10",
                     "--n-out", "21", "--no-figure", "--out", str(tmp_path)])
    assert [r["method"] for r in rows] == ["DOP853", "RK45"]
    assert rows[1]["state_err"] > 0 and rows[1]["energy_drift_rel"] > rows[0]["energy_drift_rel"]
    assert np.isnan(rows[1]["t_reversal"])  # no reversal within 0.2 s
    for name in ("rattleback_peer.csv", "rattleback_peer.json", "rattleback_peer.md"):
        assert (tmp_path / name).stat().st_size > 0
    if mod.liefi_scene() is None:  # LIEFI HOOK: until the scene exists, the script says so
        assert "missing" in capsys.readouterr().err


def test_reversal_times_first_and_settled(peer):
    mod = peer[0]
    assert mod.reversal_times([1.0, 1.2, 1.5, 4.0, 4.2]) == (1.0, 1.5)
    assert mod.reversal_times([1.0]) == (1.0, 1.0)
    first, settled = mod.reversal_times([])
    assert np.isnan(first) and np.isnan(settled)
