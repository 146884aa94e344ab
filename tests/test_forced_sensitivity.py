"""Sensitivities of a forced run with respect to its control values (liefi.integrator._forced_sensitivity)."""

import numpy as np
import pytest

import liefi
from liefi.scenes.roller_racer import RollerRacer
from liefi.systems.forcing import ForceLaw, piecewise_constant, spline

T, DT, N = 0.6, 0.02, 6


def steering_torque(t, q, v, u):
    """A torque on the steering joint phi (the last velocity of the roller racer)."""
    F = np.zeros(np.broadcast_shapes(v.shape, u.shape[:-1] + (4,)), np.result_type(v, u, float))
    F[..., 3] = u[..., 0]
    return F


def racer(signal, analytic=True):
    scene = RollerRacer()
    system = scene.build_system(analytic_derivatives=analytic)
    y0 = np.concatenate([np.zeros(3), system.complete_momenta([scene.phi0], scene.momenta0)])
    return liefi.FeedbackIntegrator(system, y0, force=ForceLaw(steering_torque, inputs=("tau",)),
                                    inputs={"tau": signal}, configuration=True, gains=100.0)


def make(kind, values):
    grid = np.linspace(0.0, T, N + 1)
    return piecewise_constant(grid, values) if kind == "piecewise" else spline(grid[:N], values)


@pytest.mark.parametrize("kind", ["piecewise", "spline"])
def test_forced_sensitivities_match_whole_run_differences(kind):
    """d y(t) / d tau_j of the imex-rk4 run (feedback step included), against 4th-order central differences of
    whole runs along a random combination of the N directions: 1e-10 relative."""
    vals = 0.4 * np.cos(np.arange(N))
    sol = racer(make(kind, vals)).run(T, dt=DT, scheme="imex-rk4", sensitivities=("tau",))
    S = sol.sensitivities["tau"]
    assert S.shape == (10, N, sol.t.size)
    assert np.all(S[..., 0] == 0) and np.all(S[-1] == 0)  # y0 and the clock do not move
    w = np.random.default_rng(1).normal(size=N)

    def y(e):
        return racer(make(kind, vals + e * w)).run(T, dt=DT, scheme="imex-rk4").y

    e = 2e-3
    fd = (8 * (y(e) - y(-e)) - (y(2 * e) - y(-2 * e))) / (12 * e)
    jvp = np.einsum("ijk,j->ik", S, w)
    assert np.abs(jvp).max() > 0.1  # the torque steers the racer
    assert np.abs(jvp - fd).max() <= 1e-10 * np.abs(jvp).max()


def test_forced_sensitivities_named_errors():
    fi = racer(make("piecewise", np.zeros(N)))
    with pytest.raises(ValueError, match="not inputs of this forced run"):
        fi.run(T, dt=DT, scheme="imex-rk4", sensitivities=("y0",))
    with pytest.raises(ValueError, match="give the step"):
        fi.run(T, scheme="imex-rk4", sensitivities=("tau",))
    callable_input = racer(lambda t: 0.1 * t)
    with pytest.raises(ValueError, match="piecewise_constant or spline"):
        callable_input.run(T, dt=DT, scheme="imex-rk4", sensitivities=("tau",))
    numeric_data = racer(make("piecewise", np.zeros(N)), analytic=False)  # constraints differentiated by complex step
    with pytest.raises(ValueError, match="analytic derivative"):
        numeric_data.run(T, dt=DT, scheme="imex-rk4", sensitivities=("tau",))
