"""SE(3) = SO(3) x| R^3: rigid motions in space, a :class:`MatrixLieGroup` with a rotation block."""

from __future__ import annotations

import numpy as np

from .base import MatrixLieGroup
from .so3 import SO3

_SO3 = SO3()


class SE3(MatrixLieGroup):
    """Rigid motions ``[[R, t], [0, 1]]``; algebra ``(Omega, v)`` (body angular and linear velocity).

    ``hat(Omega, v) = [[hat(Omega), v], [0, 0]]`` with the hat map of :class:`SO3`;
    left reconstruction ``(R, t)' = (R hat(Omega), R v)``.  The embedding stores
    the top three rows ``[R | t]`` row-major (12 numbers ``R11 R12 R13 x R21 ...
    z``; the last row is constant on the group), and declares the rotation block
    ``G[0:3, 0:3]`` orthogonal: the penalty ``1/4 ||R^T R - I||^2``, its gradient
    and its Hessian bound are derived from that declaration.
    """

    dim = 6
    matrix_dim = 4
    orthogonal_blocks = ((0, 3),)
    algebra_names = ("Pi_1", "Pi_2", "Pi_3", "P_x", "P_y", "P_z")

    def hat(self, xi):
        xi = np.asarray(xi)
        W = _SO3.hat(xi[..., :3])  # (..., 3, 3)
        top = np.concatenate([W, xi[..., 3:, None]], -1)  # (..., 3, 4)
        bottom = np.zeros_like(top[..., :1, :])
        return np.concatenate([top, bottom], -2)

    def vee(self, X):
        X = np.asarray(X)
        return np.concatenate([_SO3.vee(X[..., :3, :3]), X[..., :3, 3]], -1)

    @property
    def config_names(self):
        return ("R11", "R12", "R13", "x", "R21", "R22", "R23", "y", "R31", "R32", "R33", "z")

    def exp(self, xi):
        """``exp [[W, v], [0, 0]] = [[exp W, V v], [0, 1]]``, ``V = I + B W + C W^2``,
        ``B = (1 - cos t)/t^2``, ``C = (t - sin t)/t^3`` (Taylor series near ``t = 0``)."""
        xi = np.asarray(xi, dtype=float)
        w = xi[..., :3]
        t2 = np.einsum("...i,...i->...", w, w)
        small = t2 < np.sqrt(np.finfo(float).eps)
        t2s = np.where(small, 1.0, t2)
        t = np.sqrt(t2s)
        B = np.where(small, 0.5 - t2 / 24 + t2**2 / 720, (1 - np.cos(t)) / t2s)
        C = np.where(small, 1 / 6 - t2 / 120 + t2**2 / 5040, (t - np.sin(t)) / (t2s * t))
        W = _SO3.hat(w)
        V = np.eye(3) + B[..., None, None] * W + C[..., None, None] * (W @ W)
        G = np.zeros(xi.shape[:-1] + (4, 4))
        G[..., :3, :3] = _SO3.exp(w)
        G[..., :3, 3] = np.einsum("...ij,...j->...i", V, xi[..., 3:])
        G[..., 3, 3] = 1.0
        return G
