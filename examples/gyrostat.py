"""A gyrostat on SO(3) with a Suslov constraint: a term linear in the momenta (a vector potential).

A rigid body with inertia ``I`` carries a rotor spinning at constant momentum
``l`` (body frame).  Its reduced Hamiltonian is ``h = 1/2 <M - l, I^{-1}(M - l)>``
on ``so(3)*`` with the (minus) Lie--Poisson bracket: liefi takes ``l`` as the
constant ``vector_potential`` of the system.  The Suslov constraint forbids
rotation about a body axis ``b``: ``<b, w> = 0`` on the angular velocity ``w``,
given as a velocity constraint (liefi forms ``e = I^{-1} b`` itself).  The
rotor breaks the time reversal ``M -> -M`` of the plain Suslov problem.

Everything else -- ``J = <M - l, e>``, ``h~``, ``lambda~``, the extended field,
the Lyapunov function -- is derived from these data.
"""
import numpy as np

import liefi
from liefi.groups import SO3


def main(t_final=20.0):
    I = np.array([[2.0, 0.2, 0.0], [0.2, 1.5, 0.1], [0.0, 0.1, 1.0]])   # body inertia
    l = np.array([0.3, -0.2, 0.5])                                        # rotor momentum (body frame)
    b = np.array([[0.0, 0.0, 1.0]])                                       # <b, w> = 0: no spin about e_3
    body = liefi.NonholonomicSystem.from_velocity_constraints(
        liefi.LieGroupPhaseSpace(SO3()), I, b, vector_potential=l)
    M0 = body.complete_momenta(np.zeros(0), {"Pi_1": 1.0, "Pi_2": -0.5})  # Pi_3 solved from J = 0
    print("M0 =", M0, " J(M0) =", body.constraint_momenta(M0))

    y0 = np.concatenate([SO3().identity_config(), M0])                  # attitude R and momentum M
    fi = liefi.FeedbackIntegrator(body, y0, gains=10.0)
    sol = fi.run(t_final, dt=2e-3, scheme="rk4", save_every=50)
    v = fi.invariant_values(sol.y.T)
    print(f"max |J| = {np.abs(v['J_1']).max():.1e}, energy drift = {np.ptp(v['h']):.1e}, "
          f"max ||R^T R - I|| = {2 * np.sqrt(v['penalty'].max()):.1e}")

    from scipy.integrate import solve_ivp                               # reference: Euler's equations
    Ia = I @ body.constraints(np.zeros(0))[0]                           # the constraint row a = I e
    def euler(t, M):                                                    # I w' = (I w + l) x w + lambda a
        w = np.linalg.solve(I, M - l)
        f = np.cross(M, w)
        return f - (Ia @ np.linalg.solve(I, f)) / (Ia @ np.linalg.solve(I, Ia)) * Ia
    ref = solve_ivp(euler, (0, t_final), M0, method="DOP853", rtol=1e-12, atol=1e-12)
    err = np.abs(ref.y[:, -1] - sol.y[-3:, -1]).max()
    print(f"liefi RK4 (dt = 2e-3) and Euler's equations (DOP853) agree to {err:.1e} at t = {t_final}")
    v["error"] = err
    return v


if __name__ == "__main__":
    main()
