"""Linear representations of a matrix group on ``V = R^k``: where an advected vector lives.

A heavy top's potential, a rolling body's inertia about its contact point and its
no-slip rows depend on the body's attitude only through a vector fixed in space
seen from the body, ``Gamma = g^{-1} . a_0`` (for ``SO(3)``: ``Gamma = R^T a_0``,
the upward vertical in body axes).  ``g^{-1} . a_0`` is the action of a
representation ``rho`` of ``G`` on ``V``; its derivative ``xi . v = L(xi) v``
(``L`` linear in ``xi``) gives the advection law and the diamond operator

.. math::

    \\Gamma = \\rho(g)^{-1} a_0, \\qquad
    \\dot\\Gamma = -\\xi \\cdot \\Gamma \\quad (\\xi = g^{-1}\\dot g), \\qquad
    \\langle \\Gamma \\diamond w, \\eta \\rangle = \\langle \\eta \\cdot \\Gamma, w \\rangle,

so on ``SO(3)`` acting on ``R^3``: ``xi . v = xi x v``, ``Gamma' = Gamma x Omega``
and ``Gamma diamond w = Gamma x w`` (Marsden & Ratiu, *Introduction to Mechanics
and Symmetry*, 2nd ed., the heavy top; Holm, Marsden & Ratiu, *The Euler--Poincare
equations and semidirect products*, Adv. Math. 137 (1998)).

The representations here are the ones a matrix group carries for free: its matrix
acting on ``R^m`` (``m = matrix_dim``), or on a diagonal block of it that ``hat``
leaves invariant (the rotation block of ``SE(3)`` or of ``SO(3) x R^2`` acting
on directions), and direct sums of ``copies`` of that block (three copies of
``R^3`` carry the whole attitude ``(R^T e_1, R^T e_2, R^T e_3)``).  Nothing is
written per group: the generators ``L_a`` are read off ``hat``.
"""

from __future__ import annotations

import numpy as np

from .base import LieGroup


class Representation:
    """The representation of a matrix group by (a block of) its matrix, ``copies`` times.

    Parameters
    ----------
    group : LieGroup
        The group ``G`` (with ``hat`` and ``config_to_matrix``).
    block : (int, int), optional
        ``(first row, size)`` of the diagonal block of the group matrix that acts on
        one copy of ``V``; it must be invariant (``hat(xi)`` has no entries in the
        block's columns outside its rows).  Default: the whole matrix.
    copies : int
        How many copies of the block ``V`` holds (``V = R^(copies * size)``).
    names : sequence of str, optional
        Names of the components of ``V`` (default ``Gamma_1 ...``, or
        ``Gamma_<copy>_<i>`` for several copies).

    Attributes
    ----------
    dim : int
        ``k = dim V``.
    generators : ndarray (d, k, k)
        ``L_a``: ``E_a . v = L_a v`` for the basis ``E_a`` of the algebra, so that
        ``xi . v = sum_a xi_a L_a v``; ``L_[a, b] = [L_a, L_b]`` because ``hat`` is a
        Lie algebra homomorphism and the block is invariant.
    """

    def __init__(self, group: LieGroup, *, block=None, copies: int = 1, names=None):
        if not isinstance(group, LieGroup):
            raise TypeError(f"group: expected a liefi.groups.LieGroup, got {group!r}")
        m = group.matrix_dim
        s, size = (0, m) if block is None else (int(block[0]), int(block[1]))
        if size < 1 or s < 0 or s + size > m:
            raise ValueError(f"block: expected (first row, size) inside the {m} x {m} group matrix, got {block!r}")
        if int(copies) != copies or copies < 1:
            raise ValueError(f"copies: expected a positive integer, got {copies!r}")
        hats = np.asarray(group.hat(np.eye(group.dim)), dtype=float)  # (d, m, m)
        cols = hats[:, :, s : s + size]
        outside = np.delete(cols, np.s_[s : s + size], axis=1)
        if np.any(outside != 0):
            raise ValueError(
                f"block: rows {s}..{s + size - 1} of the {group!r} matrix are not an invariant block "
                "(hat(xi) maps them outside it); choose a diagonal block such as a rotation block"
            )
        self.group = group
        self.block = (s, size)
        self.copies = int(copies)
        self.dim = size * self.copies
        L = hats[:, s : s + size, s : s + size]
        self.generators = np.zeros((group.dim, self.dim, self.dim))
        for c in range(self.copies):
            self.generators[:, c * size : (c + 1) * size, c * size : (c + 1) * size] = L
        self.generators.setflags(write=False)
        if names is None:
            names = (
                tuple(f"Gamma_{i + 1}" for i in range(size)) if self.copies == 1
                else tuple(f"Gamma_{c + 1}_{i + 1}" for c in range(self.copies) for i in range(size))
            )
        names = tuple(names)
        if len(names) != self.dim:
            raise ValueError(f"names: expected {self.dim} names of the components of V, got {len(names)}")
        self.names = names

    def __repr__(self):
        extra = "" if self.block == (0, self.group.matrix_dim) else f", block={self.block}"
        extra += "" if self.copies == 1 else f", copies={self.copies}"
        return f"Representation({self.group!r}{extra})"

    def __eq__(self, other):
        return (isinstance(other, Representation) and other.group == self.group
                and other.block == self.block and other.copies == self.copies)

    def __hash__(self):
        return hash((type(self), self.group, self.block, self.copies))

    # --- the algebra's action -------------------------------------------------------
    def tensor(self, v):
        """``T(v)`` of shape ``(..., k, d)``, column ``a`` = ``L_a v``: ``xi . v = T(v) xi``."""
        return np.einsum("ajk,...k->...ja", self.generators, v)

    def action(self, xi, v):
        """``xi . v = sum_a xi_a L_a v`` (shape ``(..., k)``); on ``SO(3)``, ``xi x v``."""
        return np.einsum("ajk,...k,...a->...j", self.generators, v, xi)

    def diamond(self, v, w):
        """``v diamond w`` in ``g*``: ``<v diamond w, eta> = <eta . v, w>``; on ``SO(3)``, ``v x w``."""
        return np.einsum("ajk,...k,...j->...a", self.generators, v, w)

    # --- the group's action ------------------------------------------------------------
    def matrix(self, g):
        """``rho(g)`` of shape ``(..., k, k)`` from the group's stored numbers ``g``."""
        s, size = self.block
        G = np.asarray(self.group.config_to_matrix(g))[..., s : s + size, s : s + size]
        if self.copies == 1:
            return G
        z = np.zeros_like(G)
        return np.concatenate(
            [np.concatenate([G if i == j else z for j in range(self.copies)], -1) for i in range(self.copies)], -2
        )

    def body(self, g, a0):
        """``Gamma = rho(g)^{-1} a0`` (shape ``(..., k)``): the advected vector seen from the body.

        ``g``: the group's stored numbers.  Complex-step safe (a solve per copy, no casts).
        """
        return self.body_from_matrix(self.group.config_to_matrix(g), a0)

    def body_from_matrix(self, G, a0):
        """``rho(G)^{-1} a0`` from the group matrix ``G`` (shape ``(..., m, m)``), e.g. a chart's value."""
        s, size = self.block
        G = np.asarray(G)[..., s : s + size, s : s + size][..., None, :, :]  # one matrix for every copy
        a = np.asarray(a0).reshape(np.shape(a0)[:-1] + (self.copies, size))
        batch = np.broadcast_shapes(G.shape[:-2], a.shape[:-1])
        out = np.linalg.solve(np.broadcast_to(G, batch + (size, size)), np.broadcast_to(a, batch + (size,))[..., None])
        return out[..., 0].reshape(batch[:-1] + (self.dim,))
