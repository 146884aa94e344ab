"""The abelian group (R^n, +)."""

from __future__ import annotations

import numpy as np

from .base import LieGroup


class Rn(LieGroup):
    """Translations of R^n: abelian (zero bracket), stored as the vector itself.

    ``hat`` is the ``(n+1) x (n+1)`` translation generator; ``Rn(0)`` is the
    trivial group, used for systems with no symmetry (a plain cotangent bundle).
    """

    def __init__(self, n: int):
        if int(n) != n or n < 0:
            raise ValueError(f"n: expected a non-negative integer, got {n!r}")
        self.n = int(n)
        self.dim = self.config_dim = self.n
        self.matrix_dim = self.n + 1
        self.algebra_names = tuple(f"p_{i + 1}" for i in range(self.n))
        self.config_names = tuple(f"r_{i + 1}" for i in range(self.n))

    def __repr__(self):
        return f"Rn({self.n})"

    def hat(self, xi):
        xi = np.asarray(xi)
        X = np.zeros(xi.shape[:-1] + (self.n + 1, self.n + 1), dtype=xi.dtype)
        X[..., : self.n, self.n] = xi
        return X

    def vee(self, X):
        return np.asarray(X)[..., : self.n, self.n]

    @property
    def structure_constants(self):
        return np.zeros((self.n,) * 3)

    def exp(self, xi):
        G = self.hat(xi) + np.eye(self.n + 1)
        return G

    def identity_config(self):
        return np.zeros(self.n)

    def config_rate(self, g, xi):
        return np.broadcast_to(np.asarray(xi), np.broadcast_shapes(np.shape(g), np.shape(xi)))

    def config_to_matrix(self, g):
        return self.exp(g)

    def matrix_to_config(self, G):
        return self.vee(G)
