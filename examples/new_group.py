import numpy as np
import liefi
from liefi.groups import MatrixLieGroup

class Aff1(MatrixLieGroup):
    """The affine group of the line, matrices [[a, b], [0, 1]]: hat and vee are all it needs."""
    dim, matrix_dim = 2, 2
    algebra_names = ("Pi_a", "Pi_b")
    def hat(self, xi):
        xi = np.asarray(xi); z = np.zeros_like(xi[..., 0])
        return np.stack([np.stack([xi[..., 0], xi[..., 1]], -1), np.stack([z, z], -1)], -2)
    def vee(self, X):
        return np.stack([X[..., 0, 0], X[..., 0, 1]], -1)

G = Aff1()
print(G.structure_constants[0, 1])          # [E_a, E_b] = E_b, derived from hat/vee
sys = liefi.NonholonomicSystem(liefi.TrivialPrincipalBundle(G * liefi.groups.S1(), 1, names=("s",)),
                               metric=lambda x: np.eye(4) + 0.5 * np.sin(x[..., 0])[..., None, None] * np.diag([1.0, 0, 0, 0]),
                               constraints=lambda x: np.stack([np.ones_like(x[..., 0]), np.cos(x[..., 0]), 0 * x[..., 0], np.ones_like(x[..., 0])], -1)[..., None, :])
z0 = sys.project(np.array([0.2, 0.5, -0.3, 0.4, 0.1]))
fi = liefi.FeedbackIntegrator(sys, np.concatenate([G.identity_config(), [0.0], z0]), gains=10.0)
sol = fi.run(1e-3, 2.0, "rk4")
v = fi.invariant_values(sol.y.T)
print("max |J| =", np.abs(v["J_1"]).max(), " h~ drift =", np.ptp(v["h~"]))
