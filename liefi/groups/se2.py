"""SE(2) = SO(2) x| R^2, algebra coordinates ``(omega, v_x, v_y)`` (paper's ``(Pi_theta, Pi_x, Pi_y)``)."""

from __future__ import annotations

import numpy as np

from .base import LieGroup
from .so2 import SO2, S1


class SE2(LieGroup):
    """Planar rigid motions ``(R, t)``, stored as the rotation's embedding then ``t``.

    Parameters
    ----------
    rotation : SO2 or S1
        Embedding of the rotation factor: ``SO2()`` (2x2 matrix and the
        orthogonality penalty; the paper's ``chaplygin-so2``) or ``S1()`` (the
        angle ``theta``; coordinates ``(theta, x, y)`` of Marsden--Ratiu 14.6).

    Notes
    -----
    ``hat(omega, v) = [[0, -omega, v_x], [omega, 0, v_y], [0, 0, 0]]``; left
    reconstruction ``(R, t)' = (R hat(omega), R v)``.  With this basis the minus
    Lie--Poisson field is Marsden--Ratiu (14.6.16), as used in
    ``(general:form:SE2:eqn)``.
    """

    dim = 3
    matrix_dim = 3
    algebra_names = ("Pi_theta", "Pi_x", "Pi_y")

    def __init__(self, rotation=None):
        self.rotation_group = SO2() if rotation is None else rotation
        if not isinstance(self.rotation_group, (SO2, S1)):
            raise TypeError("rotation: expected liefi.groups.SO2() or liefi.groups.S1()")
        self.config_dim = self.rotation_group.config_dim + 2
        self.config_names = self.rotation_group.config_names + ("x", "y")

    def __repr__(self):
        return f"SE2(rotation={self.rotation_group!r})"

    def hat(self, xi):
        xi = np.asarray(xi)
        w, vx, vy = xi[..., 0], xi[..., 1], xi[..., 2]
        z = np.zeros_like(w)
        return np.stack(
            [np.stack([z, -w, vx], -1), np.stack([w, z, vy], -1), np.stack([z, z, z], -1)], -2
        )

    def vee(self, X):
        X = np.asarray(X)
        return np.stack([X[..., 1, 0], X[..., 0, 2], X[..., 1, 2]], -1)

    def exp(self, xi):
        xi = np.asarray(xi, dtype=float)
        w = xi[..., 0]
        small = np.abs(w) < 1e-4
        ws = np.where(small, 1.0, w)
        a = np.where(small, 1 - w**2 / 6 + w**4 / 120, np.sin(ws) / ws)  # sin w / w
        b = np.where(small, w / 2 - w**3 / 24, (1 - np.cos(ws)) / ws)  # (1 - cos w) / w
        V = np.stack([np.stack([a, -b], -1), np.stack([b, a], -1)], -2)
        t = np.einsum("...ij,...j->...i", V, xi[..., 1:])
        G = np.zeros(xi.shape[:-1] + (3, 3))
        G[..., :2, :2] = np.asarray(self.rotation_group.exp(xi[..., :1]))
        G[..., :2, 2] = t
        G[..., 2, 2] = 1.0
        return G

    def _split(self, g):
        k = self.rotation_group.config_dim
        return g[..., :k], g[..., k:]

    def identity_config(self):
        return np.concatenate([self.rotation_group.identity_config(), np.zeros(2)])

    def config_rate(self, g, xi):
        r, _ = self._split(np.asarray(g))
        R = self.rotation_group.config_to_matrix(r)
        rdot = self.rotation_group.config_rate(r, xi[..., :1])
        tdot = np.einsum("...ij,...j->...i", R, xi[..., 1:])
        return np.concatenate([np.broadcast_to(rdot, tdot.shape[:-1] + rdot.shape[-1:]), tdot], -1)

    def config_to_matrix(self, g):
        r, t = self._split(np.asarray(g))
        R = self.rotation_group.config_to_matrix(r)
        G = np.zeros(np.broadcast_shapes(R.shape[:-2], t.shape[:-1]) + (3, 3), dtype=np.result_type(R, t))
        G[..., :2, :2] = R
        G[..., :2, 2] = t
        G[..., 2, 2] = 1.0
        return G

    def matrix_to_config(self, G):
        G = np.asarray(G)
        return np.concatenate([self.rotation_group.matrix_to_config(G[..., :2, :2]), G[..., :2, 2]], -1)

    def orthogonal_matrices(self, g):
        """The rotation factor's blocks (the 2x2 matrix with ``SO2()``, none with ``S1()``)."""
        return self.rotation_group.orthogonal_matrices(self._split(np.asarray(g))[0])
