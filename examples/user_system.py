"""A system the paper does not treat, built from data only (the README example)."""
import numpy as np
import liefi
from liefi.groups import SE2


def main(t_final=10.0):
    # A planar body (SE(2), matrix embedding) carrying a rotor at angle psi (X = S^1):
    # the mass tensor depends on psi, and the two constraints are written on velocities.
    def metric(x):                                   # x[..., 0] = psi; P = (Pi_theta, Pi_x, Pi_y, p_psi)
        c = np.cos(x[..., 0]); one = np.ones_like(c); zero = 0 * c
        return np.stack([np.stack([2 + 0.5 * c, zero, 0.3 * one, 0.4 * one], -1),
                         np.stack([zero, one, zero, zero], -1),
                         np.stack([0.3 * one, zero, one, zero], -1),
                         np.stack([0.4 * one, zero, zero, 0.5 * one], -1)], -2)

    def A(x):                                        # A(psi) v = 0 on v = (omega, v_x, v_y, psi')
        s = np.sin(x[..., 0]); one = np.ones_like(s); zero = 0 * s
        return np.stack([np.stack([zero, zero, one, zero], -1),            # no side slip: v_y = 0
                         np.stack([0.2 * s, one, zero, -one], -1)], -2)    # rotor rolls with the body

    racer = liefi.NonholonomicSystem.from_velocity_constraints(            # liefi forms e_i = m^-1 a_i
        liefi.TrivialPrincipalBundle(SE2(), 1, names=("psi",)), metric, A)
    z0 = racer.project(np.array([0.3, 1.0, 0.5, 0.0, -0.2]))     # (psi, Pi_theta, Pi_x, Pi_y, p_psi) on J = 0
    print("J(z0) =", racer.constraint_momenta(z0))
    print("lambda~(z0) =", racer.extended_multipliers(z0))        # derived, by complex-step derivatives in psi

    y0 = np.concatenate([SE2().identity_config(), z0])             # (R, t, z): the group element too
    fi = liefi.FeedbackIntegrator(racer, y0, gains=10.0)           # V penalizes ||R^T R - I||, J_1, J_2, h~
    sol = fi.run(t_final, dt=1e-3, scheme="rk4", save_every=100)
    v = fi.invariant_values(sol.y.T)
    print(f"max |J_i| = {max(abs(v['J_1']).max(), abs(v['J_2']).max()):.1e}, "
          f"energy drift = {np.ptp(v['h']):.1e}, max ||R^T R - I|| = {2 * np.sqrt(v['penalty'].max()):.1e}")

    from scipy.integrate import solve_ivp                          # the same field, unchanged, in scipy
    ivp = solve_ivp(fi.fun, (0, t_final), y0, method="DOP853", rtol=1e-11, atol=1e-12)
    print(f"liefi RK4 and scipy DOP853 agree to {np.abs(ivp.y[:, -1] - sol.y[:, -1]).max():.1e}")
    return v


if __name__ == "__main__":
    main()
