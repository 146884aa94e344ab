"""A new group is a subclass with hat and vee; everything downstream is derived (README example)."""

import numpy as np

import liefi
from liefi.groups import MatrixLieGroup, S1


class Aff1(MatrixLieGroup):
    """The affine group of the line, matrices [[a, b], [0, 1]]: hat and vee are all it needs."""

    dim, matrix_dim = 2, 2
    algebra_names = ("Pi_a", "Pi_b")

    def hat(self, xi):
        xi = np.asarray(xi)
        z = np.zeros_like(xi[..., 0])
        return np.stack([np.stack([xi[..., 0], xi[..., 1]], -1), np.stack([z, z], -1)], -2)

    def vee(self, X):
        return np.stack([X[..., 0, 0], X[..., 0, 1]], -1)


def metric(x):
    """A shape-dependent mass tensor on (Pi_a, Pi_b, Pi_theta, p_s)."""
    return np.eye(4) + 0.5 * np.sin(x[..., 0])[..., None, None] * np.diag([1.0, 0, 0, 0])


def constraints(x):
    """One constraint row e_1(s)."""
    one = np.ones_like(x[..., 0])
    return np.stack([one, np.cos(x[..., 0]), 0 * one, one], -1)[..., None, :]


def main(t_final=2.0):
    G = Aff1()
    print("[E_a, E_b] =", G.structure_constants[0, 1], "(= E_b, derived from hat/vee)")
    system = liefi.NonholonomicSystem(liefi.TrivialPrincipalBundle(G * S1(), 1, names=("s",)), metric, constraints)
    z0 = system.project(np.array([0.2, 0.5, -0.3, 0.4, 0.1]))
    fi = liefi.FeedbackIntegrator(system, np.concatenate([(G * S1()).identity_config(), z0]), gains=10.0)
    sol = fi.run(t_final, dt=1e-3, scheme="rk4")
    v = fi.invariant_values(sol.y.T)
    print(f"max |J| = {np.abs(v['J_1']).max():.1e}, h~ drift = {np.ptp(v['h~']):.1e}")
    return v


if __name__ == "__main__":
    main()
