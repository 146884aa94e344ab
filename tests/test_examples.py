"""The README's examples run and conserve what the theory says they conserve."""

import importlib.util
import pathlib

import numpy as np
import pytest

EXAMPLES = pathlib.Path(__file__).resolve().parent.parent / "examples"


def load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("name", ["user_system", "new_group", "gyrostat"])
def test_readme_example_conserves_invariants(name, capsys):
    v = load(name).main(t_final=1.0)
    for k in v:
        if k.startswith("J_"):
            assert np.abs(v[k]).max() < 1e-10, k
    assert np.ptp(v["h~"]) < 1e-10
    assert np.ptp(v["h"]) < 1e-10
    if "penalty" in v:
        assert v["penalty"].max() < 1e-20


def test_gyrostat_example_follows_euler_equations(capsys):
    """The gyrostat (vector potential = rotor momentum, Suslov constraint) against Euler's equations."""
    assert load("gyrostat").main(t_final=2.0)["error"] < 1e-10


def test_knife_edge_example_from_its_velocity_constraint(capsys):
    """The paper's knife edge written as users write it (a Pfaffian row on velocities) follows the
    corrected exact solution and keeps J_1 and p_phi at the paper's Euler level."""
    err, drift = load("knife_edge").main(t_final=2.0)
    assert max(err.values()) < 1e-3
    assert drift["J_1"] < 1e-6 and drift["p_phi"] < 1e-6


def test_from_mechanics_example_rolls_and_sweeps(capsys):
    """The sympy.physics.mechanics example: the Kane rolling disk keeps its constraints and energy, and
    the sleigh's mass sweep (one ensemble run) turns the lighter sleighs faster."""
    pytest.importorskip("sympy")
    out = load("from_mechanics").main(t_final=0.1, dt=1e-3)
    assert out["drift"]["J_1"] < 1e-9 and out["drift"]["J_2"] < 1e-9 and out["drift"]["h~"] < 1e-9
    assert out["sweep"].y.shape == (5, 6, 101)
    assert np.all(np.diff(out["theta"]) < 0)  # heavier sleigh (I fixed): larger I + m a^2, slower turn
    assert "rolling disk: built in" in capsys.readouterr().out


@pytest.mark.slow  # about 20 s on a loaded 2-core machine (a dozen forced runs with sensitivities)
def test_steering_example_improves_the_distance_and_holds_the_constraints_on_every_iterate(capsys):
    """The roller racer steered by minimize(jac=liefi's forced-run sensitivities): the loss drops from the start,
    the gradient is that of the loss (central differences of whole runs), and every iterate's run keeps both
    constraints and the energy balance h~ - W within 1e-12, with the torque piecewise constant (held over whole
    steps)."""
    mod = load("steering")
    out = mod.main(T=1.0, n=5, dt=0.05, maxiter=3, compare=False)
    res, racer = out["exact"], out["racer"]
    assert racer.kind == "piecewise" and racer.signal(np.zeros(racer.n)).grid_kind == "piecewise"  # as issue 28 asks
    tau0 = 0.2 * np.sin(4 * np.pi * np.arange(racer.n) / racer.n)
    assert res.fun < racer.loss(tau0) - 1e-3
    assert len(res.drift) == res.nit + 1 and max(res.drift) <= 1e-12
    e, w = 1e-4, np.linspace(1.0, -0.5, racer.n)
    fd = (racer.loss(res.x + e * w, False) - racer.loss(res.x - e * w, False)) / (2 * e)
    assert abs(racer.gradient(res.x) @ w - fd) <= 1e-6 * max(1.0, abs(fd))


@pytest.mark.slow  # the compiled rattleback's kernels: minutes at the first run (numba's disk cache after), then ~1 min
def test_identify_rattleback_recovers_its_constants_within_the_noise(capsys):
    """The identification example (issue 28): ``least_squares`` with liefi's sensitivities recovers the
    centre-of-mass height and the inertia misalignment within two standard errors (``s^2 (J^T J)^-1``) of
    the truth, the residual's RMS is the noise's, liefi's Jacobian is closer to the 8th-order central
    difference of whole runs than least_squares' own '2-point' (2.2e-6 and 4.6e-5 measured), and the fit with
    '2-point' lands on the same parameters within a tenth of a standard error."""
    pytest.importorskip("sympy")
    pytest.importorskip("numba")
    out = load("identify_rattleback").main(None, compare=("2-point",))
    assert np.all(np.abs(out["z"]) < 2.0), out["z"]
    assert 0.9 < out["s"] / out["sigma"] < 1.1
    assert out["jac_err"]["liefi"] < 1e-5 and out["jac_err"]["liefi"] < out["jac_err"]["2-point"]
    assert np.all(np.abs(out["fits"]["2-point"]["res"].x - out["fit"]) < 0.1 * out["std"])
    assert "| liefi |" in out["table"]
