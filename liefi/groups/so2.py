"""The circle group S^1 = SO(2), in two embeddings: the 2x2 matrix and the angle."""

from __future__ import annotations

import numpy as np

from .base import LieGroup, MatrixLieGroup


def rotation2(theta):
    """Rotation matrices ``[[cos, -sin], [sin, cos]]`` of shape ``(..., 2, 2)``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


class SO2(MatrixLieGroup):
    """S^1 embedded as 2x2 matrices ``R`` (4 numbers) with the penalty ``1/4||R^T R - I||^2``.

    ``hat(w) = [[0, -w], [w, 0]]`` (so ``R' = R hat(w) = -w R J`` with the paper's
    ``J = [[0, 1], [-1, 0]]``, eq. ``(general:form:SE2:w:SO2)``).  Abelian.
    """

    dim = 1
    matrix_dim = 2
    orthogonal_blocks = ((0, 2),)

    def __init__(self, name: str = "theta"):
        #: name of the angle: momentum ``Pi_<name>``; matrix entries ``R11 ... R22``
        self.name = str(name)
        self.algebra_names = (f"Pi_{self.name}",)

    def __repr__(self):
        return "SO2()" if self.name == "theta" else f"SO2({self.name!r})"

    def hat(self, xi):
        w = np.asarray(xi)[..., 0]
        z = np.zeros_like(w)
        return np.stack([np.stack([z, -w], -1), np.stack([w, z], -1)], -2)

    def vee(self, X):
        return np.asarray(X)[..., 1, 0][..., None]

    def exp(self, xi):
        return rotation2(np.asarray(xi)[..., 0])

    def rotation(self, g):
        """The rotation matrix stored in ``g``."""
        return self.config_to_matrix(g)


class S1(LieGroup):
    """S^1 in the angle chart: one number ``theta`` (or ``name``), ``theta' = xi``, no penalty.

    The same group as :class:`SO2`; only the embedding differs (a chart, not an
    embedding in Euclidean space, so nothing needs to be kept on the group).
    """

    dim = 1
    config_dim = 1
    matrix_dim = 2

    def __init__(self, name: str = "theta"):
        #: name of the angle (configuration ``<name>``, momentum ``Pi_<name>``)
        self.name = str(name)
        self.algebra_names = (f"Pi_{self.name}",)
        self.config_names = (self.name,)

    def __repr__(self):
        return "S1()" if self.name == "theta" else f"S1({self.name!r})"

    hat = SO2.hat
    vee = SO2.vee
    exp = SO2.exp

    def identity_config(self):
        return np.zeros(1)

    def config_rate(self, g, xi):
        return np.broadcast_to(np.asarray(xi), np.broadcast_shapes(np.shape(g), np.shape(xi)))

    def config_to_matrix(self, g):
        return rotation2(np.asarray(g)[..., 0])

    def matrix_to_config(self, G):
        G = np.asarray(G)
        return np.arctan2(G[..., 1, 0], G[..., 0, 0])[..., None]

    def rotation(self, g):
        return rotation2(np.asarray(g)[..., 0])
