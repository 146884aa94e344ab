"""Knife edge on an inclined plane with liefi's core API (paper Sec. 3, "The Knife Edge").

The system is given by its data only -- metric, potential, constraint vector --
and liefi derives the extended field ``(ext:sys:kinfe)``, ``H~``, ``lambda~``
and the gradient of the Lyapunov function of ``(FI:knife)``.  The run is
compared with the exact cycloid ``x = (1 - cos t)/2``, ``y = (t - sin t)/2``,
``phi = t/2`` (the paper prints ``x = 1 - cos t``, ``phi = t``: docs/paper_notes.md item 1).

Run ``python examples/knife_edge.py`` for the paper's run (Euler,
``dt = 1e-3``, ``t`` in ``[0, 200]``, gains 1000; about 20 s).  The same run
is ``liefi.scenes.get("knife-edge").run()``.
"""

import numpy as np

import liefi
from liefi.scenes import exact

# --- data (the paper's) -----------------------------------------------------------
m = J = g = 1.0
alpha = np.pi / 6


def potential(q):
    """``U = -m g x sin(alpha)``: batch-first and complex-step safe."""
    return -m * g * np.sin(alpha) * q[..., 0]


def no_side_slip(q):
    """The constraint as one writes it, on velocities: ``xdot sin(phi) - ydot cos(phi) = 0``.

    One Pfaffian row ``a(q) = (sin phi, -cos phi, 0)``, shape ``(..., 1, 3)``; liefi forms
    ``e = m^{-1} a`` scaled to unit Gram diagonal, the paper's ``(sin phi, -cos phi, 0)/sqrt(m)``.
    """
    phi = q[..., 2]
    return np.stack([np.sin(phi), -np.cos(phi), np.zeros_like(phi)], -1)[..., None, :]


def main(t_final=200.0, dt=1e-3, gains=1000.0, scheme="euler"):
    """Integrate the knife edge and print the max error and invariant drifts.

    Returns
    -------
    max_error, max_drift : dict
    """
    space = liefi.CotangentBundle(3, names=("x", "y", "phi"))
    system = liefi.NonholonomicSystem.from_velocity_constraints(space, np.diag([m, m, J]), no_side_slip, potential)
    z0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5])  # (x, y, phi, p_x, p_y, p_phi)
    fi = liefi.FeedbackIntegrator(system, z0, invariants=("constraints", "energy", "p_phi"), gains=gains)
    n_steps = int(round(t_final / dt))
    sol = fi.run(t_final, dt=dt, scheme=scheme, save_every=max(1, n_steps // 10000))

    ref = exact.knife_edge(sol.t, m=m, J=J, g=g, alpha=alpha, p_phi0=0.5)
    max_error = {k: float(np.max(np.abs(sol[k] - ref[k]))) for k in ("x", "y", "phi")}
    values = fi.invariant_values(np.moveaxis(sol.y, -1, 0))
    max_drift = {k: float(np.max(np.abs(values[k] - (0.0 if k.startswith("J_") else values[k][0]))))
                 for k in ("J_1", "h", "h~", "p_phi")}
    print(f"knife edge, {scheme}, dt={dt:g}, t in [0, {t_final:g}], gains {gains:g}, "
          f"cpu {sol.cpu_seconds:.2f} s")
    print("  max error:", {k: f"{v:.3e}" for k, v in max_error.items()})
    print("  max drift:", {k: f"{v:.3e}" for k, v in max_drift.items()})
    return max_error, max_drift


if __name__ == "__main__":
    main()
