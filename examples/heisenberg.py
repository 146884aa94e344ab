"""Heisenberg system with liefi's core API (paper Sec. 3, "The Heisenberg System").

Data only: ``T*R^3``, metric ``I``, no potential, and the constraint
``p_z - y p_x + x p_y = 0`` with the *non-normalized* vector ``e = (-y, x, 1)``
(liefi uses the general multiplier formula ``(lambda:general)``, like the
paper).  ``V`` penalizes the constraint momentum ``J_1``, the angular momentum
``J_2 = x p_y - y p_x`` (a user :class:`liefi.Invariant`) and the energy --
the extended ``H~``: the paper's ``H = |p|^2/2`` is not a first integral of
liefi's extended field off the constraint set, because ``|e|^2`` varies with
``q`` (``H~ = H`` there).  The exact motion is a straight line.

The paper leaves the simulation to the reader.  This script runs Euler,
``dt = 1e-3``, gains 10, ``t`` in ``[0, 10]`` from a generic start, then shows
the stiffness the paper's non-compact ``V^{-1}(0)`` brings: the Hessian of
``V`` grows like ``k (1 + 2 (x^2 + y^2))``, and once ``dt`` times it passes
Euler's stability bound 2 the run leaves the straight line.

Run ``python examples/heisenberg.py``; the same runs are
``liefi.scenes.get("heisenberg").run(variant="generic")``.
"""

import numpy as np

import liefi
from liefi.scenes import exact


def constraint(q):
    """``e = (-y, x, 1)`` as one row, shape ``(..., 1, 3)``; complex-step safe."""
    x, y = q[..., 0], q[..., 1]
    return np.stack([-y, x, np.ones_like(x)], -1)[..., None, :]


#: the paper's J_2 (named L_z: liefi reserves J_i for constraint momenta, whose target is 0)
L_z = liefi.Invariant("L_z", lambda z: z[..., 0] * z[..., 4] - z[..., 1] * z[..., 3])


def stiffness(fi, y, dt):
    """``dt`` times the largest eigenvalue of the Hessian of ``V`` at ``y`` (Euler needs < 2)."""
    eps = 1e-6
    n = y.size
    H = np.empty((n, n))
    for i in range(n):
        d = np.zeros(n)
        d[i] = eps
        H[:, i] = (fi.grad_lyapunov(y + d) - fi.grad_lyapunov(y - d)) / (2 * eps)
    return dt * np.max(np.linalg.eigvalsh(0.5 * (H + H.T)))


def main(t_final=10.0, dt=1e-3, gains=10.0, q0=(1.0, 0.5, 0.0), p0=(0.3, 0.4, -0.25)):
    """Integrate from ``(q0, p0)`` (on the constraint set); print errors, drifts and stiffness.

    Returns
    -------
    max_error, max_drift : dict
    """
    space = liefi.CotangentBundle(3, names=("x", "y", "z"))
    system = liefi.NonholonomicSystem(space, np.eye(3), constraint)
    z0 = np.concatenate([q0, p0])
    fi = liefi.FeedbackIntegrator(system, z0, invariants=("constraints", "energy", L_z), gains=gains)
    sol = fi.run(t_final, dt=dt, scheme="euler", save_every=max(1, int(round(t_final / dt)) // 2000))

    ref = exact.heisenberg(sol.t, q0, p0)
    max_error = {k: float(np.max(np.abs(sol[k] - ref[k]))) for k in system.state_names}
    values = fi.invariant_values(np.moveaxis(sol.y, -1, 0))
    max_drift = {k: float(np.max(np.abs(values[k] - (0.0 if k.startswith("J_") else values[k][0]))))
                 for k in ("J_1", "h~", "h", "L_z")}
    print(f"Heisenberg, euler, dt={dt:g}, t in [0, {t_final:g}], gains {gains:g}, cpu {sol.cpu_seconds:.2f} s")
    print("  max error:", {k: f"{v:.2e}" for k, v in max_error.items()})
    print("  max drift:", {k: f"{v:.2e}" for k, v in max_drift.items()})
    print(f"  dt * max eig Hess V: start {stiffness(fi, z0, dt):.2f}, end {stiffness(fi, sol.y[:, -1], dt):.2f}"
          " (Euler is stable below 2)")
    return max_error, max_drift


if __name__ == "__main__":
    main()
    print("\nthe same start with gains 100 over [0, 10]: Euler leaves the line at t ~ 4.5")
    try:
        main(gains=100.0)
    except liefi.IntegrationError as err:
        print(f"  stopped at t = {err.t:.3g} ({type(err).__name__}): {err}")
