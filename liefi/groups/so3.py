"""SO(3): rotations, embedded as 3x3 matrices with the orthogonality penalty."""

from __future__ import annotations

import numpy as np

from .base import MatrixLieGroup


class SO3(MatrixLieGroup):
    """The rotation group SO(3); algebra R^3 with the hat map of the paper.

    ``hat(Omega) @ v == np.cross(Omega, v)``, so the bracket is the cross product
    and the minus Lie--Poisson field of ``h`` is ``Pi' = Pi x dh/dPi`` (rigid body).
    """

    dim = 3
    matrix_dim = 3
    orthogonal_blocks = ((0, 3),)
    algebra_names = ("Pi_1", "Pi_2", "Pi_3")

    def hat(self, xi):
        xi = np.asarray(xi)
        z = np.zeros_like(xi[..., 0])
        a, b, c = xi[..., 0], xi[..., 1], xi[..., 2]
        return np.stack(
            [np.stack([z, -c, b], -1), np.stack([c, z, -a], -1), np.stack([-b, a, z], -1)], -2
        )

    def vee(self, X):
        X = np.asarray(X)
        return np.stack([X[..., 2, 1], X[..., 0, 2], X[..., 1, 0]], -1)

    def exp(self, xi):
        """Rodrigues' formula, with Taylor branches near zero angle.

        ``exp(hat w) = I + A hat w + B hat w^2``, ``A = sin t / t``,
        ``B = (1 - cos t) / t^2``, ``t = |w|``; for ``t^2 < sqrt(eps)`` the series
        ``A = 1 - t^2/6 + t^4/120``, ``B = 1/2 - t^2/24 + t^4/720`` (error below eps).
        """
        xi = np.asarray(xi, dtype=float)
        t2 = np.einsum("...i,...i->...", xi, xi)
        small = t2 < np.sqrt(np.finfo(xi.dtype).eps)
        t2s = np.where(small, 1.0, t2)
        t = np.sqrt(t2s)
        A = np.where(small, 1 - t2 / 6 + t2**2 / 120, np.sin(t) / t)
        B = np.where(small, 0.5 - t2 / 24 + t2**2 / 720, (1 - np.cos(t)) / t2s)
        W = self.hat(xi)
        return np.eye(3) + A[..., None, None] * W + B[..., None, None] * (W @ W)
