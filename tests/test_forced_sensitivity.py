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


def racer(signal, analytic=True, gains=100.0):
    scene = RollerRacer()
    system = scene.build_system(analytic_derivatives=analytic)
    y0 = np.concatenate([np.zeros(3), system.complete_momenta([scene.phi0], scene.momenta0)])
    return liefi.FeedbackIntegrator(system, y0, force=ForceLaw(steering_torque, inputs=("tau",)),
                                    inputs={"tau": signal}, configuration=True, gains=gains)


def make(kind, values):
    grid = np.linspace(0.0, T, N + 1)
    return piecewise_constant(grid, values) if kind == "piecewise" else spline(grid[:N], values)


@pytest.mark.parametrize("kind, scheme, gains", [("piecewise", "imex-rk4", 100.0), ("spline", "imex-rk4", 100.0),
                                                 ("spline", "rk4", 10.0), ("piecewise", "imex-rk4", "auto")])
def test_forced_sensitivities_match_whole_run_differences(kind, scheme, gains):
    """d y(t) / d tau_j of the run (the split scheme's feedback step, the explicit feedback field, the gains that
    "auto" chose held), against 4th-order central differences of whole runs along a random combination of the
    N directions: 1e-10 relative."""
    vals = 0.4 * np.cos(np.arange(N))
    sol = racer(make(kind, vals), gains=gains).run(T, dt=DT, scheme=scheme, sensitivities=("tau",))
    S = sol.sensitivities["tau"]
    assert S.shape == (10, N, sol.t.size)
    assert np.all(S[..., 0] == 0) and np.all(S[-1] == 0)  # y0 and the clock do not move
    w = np.random.default_rng(1).normal(size=N)
    held = gains if gains != "auto" else {"J_2": 1.0, **sol.stability.gains}  # "auto"'s choice (J_2 is kept exactly)

    def y(e):
        return racer(make(kind, vals + e * w), gains=held).run(T, dt=DT, scheme=scheme).y

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
