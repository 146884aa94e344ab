"""Direct products of groups: everything block by block, no new code per product."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from .base import LieGroup


class ProductGroup(LieGroup):
    """Direct product ``G_1 x ... x G_r`` (algebra and embedding concatenated).

    ``SE2() * SO2()`` builds one.  The bracket is block diagonal, matrices are
    block diagonal, and the orthogonal blocks (hence the penalty) are the
    factors', offset.
    """

    def __init__(self, *factors):
        flat = []
        for f in factors:
            if not isinstance(f, LieGroup):
                raise TypeError(f"factors: expected LieGroup instances, got {f!r}")
            flat.extend(f.factors if isinstance(f, ProductGroup) else [f])
        self.factors = tuple(flat)
        self.dim = sum(f.dim for f in self.factors)
        self.config_dim = sum(f.config_dim for f in self.factors)
        self.matrix_dim = sum(f.matrix_dim for f in self.factors)
        self._alg = np.cumsum([0] + [f.dim for f in self.factors])
        self._cfg = np.cumsum([0] + [f.config_dim for f in self.factors])
        self._mat = np.cumsum([0] + [f.matrix_dim for f in self.factors])
        self.algebra_names = _unique(sum((f.algebra_names for f in self.factors), ()))
        self.config_names = _unique(sum((f.config_names for f in self.factors), ()))

    def __repr__(self):
        return " * ".join(repr(f) for f in self.factors)

    def _parts(self, a, offsets):
        return [a[..., offsets[i] : offsets[i + 1]] for i in range(len(self.factors))]

    @cached_property
    def structure_constants(self):
        C = np.zeros((self.dim,) * 3)
        for i, f in enumerate(self.factors):
            s = slice(self._alg[i], self._alg[i + 1])
            C[s, s, s] = f.structure_constants
        return C

    def hat(self, xi):
        xi = np.asarray(xi)
        X = np.zeros(xi.shape[:-1] + (self.matrix_dim,) * 2, dtype=xi.dtype)
        for i, (f, x) in enumerate(zip(self.factors, self._parts(xi, self._alg))):
            s = slice(self._mat[i], self._mat[i + 1])
            X[..., s, s] = f.hat(x)
        return X

    def vee(self, X):
        X = np.asarray(X)
        return np.concatenate(
            [f.vee(X[..., self._mat[i] : self._mat[i + 1], self._mat[i] : self._mat[i + 1]]) for i, f in enumerate(self.factors)], -1
        )

    def exp(self, xi):
        xi = np.asarray(xi)
        G = np.zeros(xi.shape[:-1] + (self.matrix_dim,) * 2)
        for i, (f, x) in enumerate(zip(self.factors, self._parts(xi, self._alg))):
            s = slice(self._mat[i], self._mat[i + 1])
            G[..., s, s] = f.exp(x)
        return G

    def identity_config(self):
        return np.concatenate([f.identity_config() for f in self.factors])

    def config_rate(self, g, xi):
        parts = [f.config_rate(a, b) for f, a, b in zip(self.factors, self._parts(g, self._cfg), self._parts(xi, self._alg))]
        shape = np.broadcast_shapes(*(p.shape[:-1] for p in parts))
        return np.concatenate([np.broadcast_to(p, shape + p.shape[-1:]) for p in parts], -1)

    def config_to_matrix(self, g):
        g = np.asarray(g)
        G = np.zeros(g.shape[:-1] + (self.matrix_dim,) * 2, dtype=g.dtype)
        for i, (f, a) in enumerate(zip(self.factors, self._parts(g, self._cfg))):
            s = slice(self._mat[i], self._mat[i + 1])
            G[..., s, s] = f.config_to_matrix(a)
        return G

    def matrix_to_config(self, G):
        G = np.asarray(G)
        return np.concatenate(
            [f.matrix_to_config(G[..., self._mat[i] : self._mat[i + 1], self._mat[i] : self._mat[i + 1]]) for i, f in enumerate(self.factors)], -1
        )

    def orthogonal_matrices(self, g):
        """The factors' orthogonal blocks, each read from its factor's slice of ``g``."""
        g = np.asarray(g)
        return [R for f, a in zip(self.factors, self._parts(g, self._cfg)) for R in f.orthogonal_matrices(a)]


def _unique(names):
    """Make names unique by suffixing repeats (``Pi_theta``, ``Pi_theta_2``)."""
    seen, out = {}, []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}_{seen[n]}")
    return tuple(out)
