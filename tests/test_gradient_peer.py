"""The gradient peer (``benchmarks/gradient_peer.py``): liefi's sensitivities against JAX + diffrax on the Chaplygin ball.

Its eliminated equations in ``(M, Gamma)`` are the scene's oracle (``chaplygin_equations``) without the
attitude and the path; its reference gradient (complex step of DOP853 at 1e-13) agrees with a central
difference of the same reference; liefi's gradient (three forward tangents along ``d y0 / d Omega0``)
agrees with the reference to the run's own accuracy; without a JAX interpreter the benchmark says so.
"""

import importlib.util
import os
import sys

import numpy as np
import pytest

_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks", "gradient_peer.py")


@pytest.fixture(scope="module")
def peer():
    spec = importlib.util.spec_from_file_location("gradient_peer", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_eliminated_equations_are_the_oracles(peer):
    """``(M, Gamma)'`` of the peer's ODE equals the rows ``Gamma, M`` of the scene's ``chaplygin_equations``."""
    from liefi.scenes.chaplygin_ball import chaplygin_equations

    I, ma2 = np.array([0.3, 0.4, 0.5]), 1.0
    full = chaplygin_equations(I, 1.0, 1.0)
    rng = np.random.default_rng(28)
    for _ in range(3):
        G = rng.normal(size=3)
        G /= np.linalg.norm(G)
        y = peer.start(I, ma2, G, rng.normal(size=3))
        Y = np.concatenate([np.eye(3).ravel(), [0.0, 0.0], rng.normal(size=6), y[3:6], y[:3]])
        f = full(0.0, Y)
        np.testing.assert_allclose(peer.rates(I, ma2)(0.0, y), np.concatenate([f[20:23], f[17:20]]), rtol=0,
                                   atol=1e-14)


def test_reference_gradient_is_the_derivative_of_the_reference(peer):
    case = dict(inertia=np.array([0.3, 0.4, 0.5]), ma2=1.0, G0=np.array([0.0, 0.6, 0.8]),
                W0=np.array([1.0, 0.5, 2.0]), ts=np.linspace(0.0, 1.0, 11))
    case["Ghat"] = peer.reference(case, case["W0"] + peer.DATA_SHIFT)
    L, g = peer.reference_gradient(case)
    h = 1e-5
    fd = np.array([(peer.loss_of(peer.reference(case, case["W0"] + h * e), case["Ghat"])
                    - peer.loss_of(peer.reference(case, case["W0"] - h * e), case["Ghat"])) / (2 * h)
                   for e in np.eye(3)])
    assert L > 0 and np.max(np.abs(g - fd)) < 1e-7 * np.max(np.abs(g))


def test_without_a_jax_interpreter_the_peer_is_skipped_with_a_message(peer, tmp_path):
    rows, why = peer.run_jax(None, {}, 1, [])
    assert rows is None and "LIEFI_JAX_PYTHON" in why and "--jax-python" in why
    rows, why = peer.run_jax(str(tmp_path / "no-python"), {}, 1, [])
    assert rows is None and "does not exist" in why


@pytest.mark.slow  # the ball's tangent trace (25 states): ~20 s
def test_liefi_gradient_agrees_with_the_reference(peer):
    """liefi at ``dt = 1e-2`` over ``[0, 1]``: the loss and its gradient within 1e-6 of the reference (the
    run's own error, fourth order), the no-slip rows held to 1e-9."""
    case = peer.make_case(1.0, 0.1)
    L, g = peer.reference_gradient(case)
    (row,) = peer.liefi_rows(case, [1e-2], 0, "python")
    assert abs(row["loss"] - L) < 1e-6 * L
    assert np.max(np.abs(np.asarray(row["grad"]) - g)) < 1e-6 * np.max(np.abs(g))
    assert row["drift"] < 1e-9


def test_jax_side_runs_when_an_interpreter_is_given(peer):
    python = os.environ.get("LIEFI_JAX_PYTHON")
    if not python or not os.path.exists(python):
        pytest.skip("LIEFI_JAX_PYTHON is not set to a python with jax and diffrax")
    case = dict(inertia=np.array([0.3, 0.4, 0.5]), ma2=1.0, G0=np.array([0.0, 0.6, 0.8]),
                W0=np.array([1.0, 0.5, 2.0]), ts=np.linspace(0.0, 1.0, 11))
    case["Ghat"] = peer.reference(case, case["W0"] + peer.DATA_SHIFT)
    L, g = peer.reference_gradient(case)
    out, why = peer.run_jax(python, case, 1, [("Tsit5", 1e-10)])
    assert out is not None, why
    (row,) = out["rows"]
    assert np.max(np.abs(np.asarray(row["grad"]) - g)) < 1e-6 * np.max(np.abs(g))


if __name__ == "__main__":
    sys.exit(pytest.main([__file__]))
