"""Chaplygin sleigh on SE(2) with liefi's core API (paper Sec. 3, "The Chaplygin Sleigh").

The rotation is stored as a 2x2 matrix (``SE2(SO2())``), as in the paper's
``(FI:extended:SE2:SO2)``: the feedback integrator then also penalizes
``R^T R - I`` with the gain ``k0`` (``gains["penalty"]``).  liefi takes the
penalty's gradient from the group, ``k0 R (R^T R - I)``, so ``R`` is pulled
back to SO(2); the paper's printed ``grad_R V`` has the wrong sign (docs/paper_notes.md
item 4).  The data are the locked inertia and the constraint vector; the
extended field ``(extended:SE2:SO2)`` is derived.

Parameters are liefi's choice (the paper gives none): ``m = I = 1``,
``a = 0.5``, start at the identity with ``omega0 = 1``, ``v0 = 0.5``.
The heading ``theta = atan2(R21, R11)`` and the momenta are compared with
:func:`liefi.scenes.exact.chaplygin`.  The same runs are
``liefi.scenes.get("chaplygin-so2").run()`` and ``get("chaplygin").run()``.
"""

import numpy as np

import liefi
from liefi.groups import SE2, SO2
from liefi.scenes import exact

m, I, a = 1.0, 1.0, 0.5
M = I + m * a * a
inertia = np.array([[M, 0.0, m * a], [0.0, m, 0.0], [m * a, 0.0, m]])
e = np.array([m * a, 0.0, -M]) / np.sqrt(m * I * M)  # <Pi, e> = 0 <=> m a Pi_theta = (I + m a^2) Pi_y


def main(t_final=10.0, dt=1e-3, gains=100.0, scheme="euler"):
    """Integrate the sleigh (rotation as a matrix) and print max error and drifts.

    Returns
    -------
    max_error, max_drift : dict
    """
    system = liefi.NonholonomicSystem(liefi.LieGroupPhaseSpace(SE2(SO2())), inertia, e)
    omega0, v0 = 1.0, 0.5
    Pi0 = np.array([M * omega0, m * v0, m * a * omega0])
    y0 = np.concatenate([np.eye(2).ravel(), [0.0, 0.0], Pi0])  # (R11, R12, R21, R22, x, y, Pi)
    fi = liefi.FeedbackIntegrator(system, y0, invariants=("constraints", "energy"), gains=gains)
    print("state:", fi.names, " gains:", fi.gains)
    n_steps = int(round(t_final / dt))
    sol = fi.run(t_final, dt=dt, scheme=scheme, save_every=max(1, n_steps // 10000))

    theta = np.unwrap(np.arctan2(sol["R21"], sol["R11"]))
    ref = exact.chaplygin(sol.t, m, I, a, 0.0, Pi0)
    got = {"theta": theta, "Pi_theta": sol["Pi_theta"], "Pi_x": sol["Pi_x"], "Pi_y": sol["Pi_y"]}
    max_error = {k: float(np.max(np.abs(got[k] - ref[k]))) for k in got}
    values = fi.invariant_values(np.moveaxis(sol.y, -1, 0))
    max_drift = {
        "J_1": float(np.max(np.abs(values["J_1"]))),
        "h~": float(np.max(np.abs(values["h~"] - values["h~"][0]))),
        "orthogonality": float(np.max(2.0 * np.sqrt(values["penalty"]))),  # ||R^T R - I||_F
    }
    print(f"Chaplygin sleigh (R in R^2x2), {scheme}, dt={dt:g}, t in [0, {t_final:g}], "
          f"cpu {sol.cpu_seconds:.2f} s")
    print("  max error:", {k: f"{v:.3e}" for k, v in max_error.items()})
    print("  max drift:", {k: f"{v:.3e}" for k, v in max_drift.items()})
    return max_error, max_drift


if __name__ == "__main__":
    main()
