"""A rolling disk from ``sympy.physics.mechanics`` (Kane's method) and a mass sweep of a sleigh (Lagrange's).

Both models are written as the sympy docs write them -- ``ReferenceFrame``,
``dynamicsymbols``, ``Point``, ``RigidBody``, ``KanesMethod`` / ``LagrangesMethod`` --
with their parameters left symbolic, and handed to liefi in one call each,
``liefi.from_mechanics(model, constants)``.  The disk carries its contact point
``(x, y)`` among the coordinates and rolls by two velocity constraints (dependent
speeds ``u4, u5``).  The sleigh's mass is swept without a rebuild: per-member
constants, one ensemble run.

Run ``python examples/from_mechanics.py``: it prints the time to build each system
and to integrate, and the drift of the invariants.
"""

import time

import numpy as np
import sympy as sp
import sympy.physics.mechanics as me

import liefi


def rolling_disk():
    """The rolling disk: yaw q1, lean q2, spin q3, contact point (x, y); speeds u1..u3 independent."""
    q1, q2, q3, x, y = me.dynamicsymbols("q1 q2 q3 x y")
    u1, u2, u3, u4, u5 = me.dynamicsymbols("u1:6")
    m, r, g = sp.symbols("m r g")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w_R_N_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    O = me.Point("O")
    O.set_vel(N, 0)
    C = O.locatenew("C", x * N.x + y * N.y)  # contact point
    Dmc = C.locatenew("Dmc", r * L.z)  # centre of the disk
    Dmc.set_vel(N, Dmc.pos_from(O).dt(N).subs({x.diff(): u4, y.diff(): u5}))
    kd = [me.dot(R.ang_vel_in(N) - w_R_N_qd, uv) for uv in L] + [u4 - x.diff(), u5 - y.diff()]
    v_contact = Dmc.vel(N) + me.cross(R.ang_vel_in(N), C.pos_from(Dmc))  # of the disk's material point at C
    disc = me.RigidBody("disc", Dmc, R, m, (me.inertia(L, m * r**2 / 4, m * r**2 / 2, m * r**2 / 4), Dmc))
    KM = me.KanesMethod(N, q_ind=[q1, q2, q3, x, y], u_ind=[u1, u2, u3], u_dependent=[u4, u5], kd_eqs=kd,
                        velocity_constraints=[me.dot(v_contact, N.x), me.dot(v_contact, N.y)],
                        bodies=[disc], forcelist=[(Dmc, -m * g * N.z)])
    return KM, {m: 1.0, r: 0.5, g: 9.81}


def sleigh():
    """The Chaplygin sleigh: blade at (x, y), heading theta, mass centre a ahead of the blade."""
    x, y, theta = me.dynamicsymbols("x y theta")
    m, I, a = sp.symbols("m I a")
    N = me.ReferenceFrame("N")
    B = N.orientnew("B", "Axis", [theta, N.z])
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    P.set_vel(N, P.pos_from(O).dt(N))
    G = P.locatenew("G", a * B.x)
    G.set_vel(N, G.pos_from(O).dt(N))
    sled = me.RigidBody("sled", G, B, m, (me.inertia(B, 0, 0, I), G))
    LM = me.LagrangesMethod(me.Lagrangian(N, sled), [x, y, theta], nonhol_coneqs=[P.vel(N).dot(B.y)], frame=N)
    return LM, {m: 1.0, I: 1.0, a: 0.5}


def main(t_final=5.0, dt=1e-3):
    """Build and run both; returns the timings, the drifts and the sweep's final headings."""
    t = time.perf_counter()
    KM, constants = rolling_disk()
    disk = liefi.from_mechanics(KM, constants)
    build = time.perf_counter() - t
    z0 = disk.state([0.0, 0.2, 0.0, 0.0, 0.0], u=[0.0, 4.0, 0.3])  # spin 4, yaw rate 0.3; u4, u5 solved
    fi = liefi.FeedbackIntegrator(disk, z0, gains=1.0)
    t = time.perf_counter()
    sol = fi.run(t_final, dt=dt, scheme="rk4")
    run = time.perf_counter() - t
    v = fi.invariant_values(np.moveaxis(sol.y, -1, -2))
    drift = {k: float(np.max(np.abs(v[k] - v[k][0]))) for k in ("J_1", "J_2", "h~")}
    u = disk.generalized_speeds(sol)  # {"u1": (n_t,), ..., "u5": (n_t,)}: by name, in the model's order
    print(f"rolling disk: built in {build:.2f} s, {sol.steps} rk4 steps in {run:.2f} s; drift {drift}; "
          f"final spin rate u2 = {u['u2'][-1]:.6f}")

    LM, constants = sleigh()
    t = time.perf_counter()
    sled = liefi.from_mechanics(LM, constants)
    build_sled = time.perf_counter() - t
    masses = np.array([0.25, 0.5, 1.0, 2.0, 4.0])
    sled.constants = {"m": masses}  # five members, no rebuild
    z0 = sled.state(np.zeros((masses.size, 3)), np.broadcast_to([0.5, 0.0, 1.0], (masses.size, 3)))
    t = time.perf_counter()
    sweep = liefi.FeedbackIntegrator(sled, z0, gains="auto").run(t_final, dt=dt, scheme="imex-rk4",
                                                                  backend="numpy")  # per-member constants
    run_sweep = time.perf_counter() - t
    theta = sweep["theta"][:, -1]
    print(f"sleigh: built in {build_sled:.2f} s; mass sweep {masses.tolist()} as one ensemble run in "
          f"{run_sweep:.2f} s; final headings {np.round(theta, 6).tolist()}")
    return dict(build=build, run=run, drift=drift, u=u, build_sleigh=build_sled, run_sweep=run_sweep,
                masses=masses, theta=theta, sweep=sweep)


if __name__ == "__main__":
    main()
