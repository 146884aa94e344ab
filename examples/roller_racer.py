"""Roller racer with liefi's core API (paper Sec. 3, "The Roller Racer").

The system is given by its data only -- the group ``SE(2)`` (angle chart),
the shape space ``S^1`` of the steering angle, the reduced mass tensor and the
two reduced constraint vectors -- and liefi derives ``h~``, the multipliers
``lambda~_i`` the paper omits ("tedious but straightforward"), the extended
field ``(extended:roller:racer)`` with the reconstruction of the pose, and
``grad V`` of ``(FI:roller:racer)``.  The reference is a DOP853 integration of
the constrained field, derived from the same data.

Run ``python examples/roller_racer.py`` (Euler, ``dt = 1e-3``, ``t`` in
``[0, 10]``, gains 100; a few seconds).  The reduced run is also
``liefi.scenes.get("roller-racer").run()``.
"""

import numpy as np
from scipy.integrate import solve_ivp

import liefi
from liefi.groups import S1, SE2
from liefi.reduction import full_vector_field

# --- data (parameters chosen by liefi; the paper gives none) -------------------------
m, I1, I2, d1, d2 = 1.0, 1.0, 0.5, 1.0, 0.5

#: reduced mass tensor on (Pi_theta, Pi_x, Pi_y, p_phi)
metric = np.array([[I1 + I2, 0, 0, I2], [0, m, 0, 0], [0, 0, m, 0], [I2, 0, 0, I2]], float)


def constraints(x):
    """``e_1, e_2`` as printed (orthonormal for the metric), shape ``(..., 2, 4)``; complex-step safe."""
    phi = x[..., 0]
    c, s = np.cos(phi), np.sin(phi)
    zero, one = np.zeros_like(phi), np.ones_like(phi)
    norm = np.sqrt(s**2 / m + d1**2 * c**2 / I1 + d2**2 / I2)
    e1 = np.stack([d1 * c / I1, -s / m, zero, -d1 * c / I1 + d2 / I2], -1) / norm[..., None]
    e2 = np.stack([zero, zero, one, zero], -1) / np.sqrt(m)
    return np.stack([e1, e2], -2)


def main(t_final=10.0, dt=1e-3, gains=100.0, scheme="euler"):
    """Integrate the roller racer (pose and reduced state); print errors and drifts.

    Returns
    -------
    max_error, max_drift : dict
    """
    space = liefi.TrivialPrincipalBundle(SE2(S1()), 1, names=("phi",))
    system = liefi.NonholonomicSystem(space, metric, constraints)
    print("state:", space.config_names[:3], "+", system.state_names)

    # start: pose 0, phi = pi/4, Pi_theta = 1, p_phi = 1/2; (Pi_x, Pi_y) solved from J = 0
    z = system.complete_momenta([np.pi / 4], {"Pi_theta": 1.0, "p_phi": 0.5})
    y0 = np.concatenate([np.zeros(3), z])
    print("J(z0) =", system.constraint_momenta(z), " h(z0) =", system.hamiltonian(z))

    fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=gains)
    n_steps = int(round(t_final / dt))
    sol = fi.run(t_final, dt=dt, scheme=scheme, save_every=max(1, n_steps // 2000))

    ref = solve_ivp(lambda t, y: full_vector_field(system, y, kind="constrained"), (0.0, t_final), y0,
                    method="DOP853", rtol=1e-12, atol=1e-12, t_eval=sol.t)
    max_error = {k: float(np.max(np.abs(sol.y[i] - ref.y[i]))) for i, k in enumerate(fi.names)}
    values = fi.invariant_values(np.moveaxis(sol.y, -1, 0))
    max_drift = {k: float(np.max(np.abs(values[k] - (0.0 if k.startswith("J_") else values[k][0]))))
                 for k in ("J_1", "J_2", "h", "h~")}
    print(f"roller racer, {scheme}, dt={dt:g}, t in [0, {t_final:g}], gains {gains:g}, "
          f"cpu {sol.cpu_seconds:.2f} s")
    print("  max error:", {k: f"{v:.2e}" for k, v in max_error.items()})
    print("  max drift:", {k: f"{v:.2e}" for k, v in max_drift.items()})
    return max_error, max_drift


if __name__ == "__main__":
    main()
