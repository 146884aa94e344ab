"""Abstract Lie group: algebra structure, coadjoint action, configuration embedding.

Conventions (the paper's, ``../shared/NOTES.md``): left action, left
trivialization ``T*G = G x g*``, reconstruction ``g' = g . xi``, and the
**minus** Lie--Poisson bracket ``{f1, f2}(mu) = -<mu, [df1/dmu, df2/dmu]>``, so
that the Hamiltonian vector field of ``h`` is ``mu' = ad*_{dh/dmu} mu``.

A concrete group supplies only

* ``dim`` (of the algebra), ``hat`` (algebra vector -> matrix) and ``vee``;
* its *configuration embedding*: the flat array that stores a group element in
  Euclidean space (``config_dim`` numbers), the reconstruction rate
  ``config_rate(g, xi)`` of ``g' = g . xi`` in that embedding, and the penalty
  that keeps an embedded element on the group with its gradient.

The structure constants, ``bracket``, ``ad``, ``ad*`` and the Lie--Poisson
tensor are *derived* from ``hat``/``vee``: ``[E_a, E_b] = vee(hat(E_a) hat(E_b)
- hat(E_b) hat(E_a)) = C_ab^c E_c``.  A matrix group whose embedding is the
whole matrix (``MatrixLieGroup``) needs nothing else.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np


class LieGroup:
    """Base class of liefi's Lie groups (immutable; all methods batch-first).

    Attributes
    ----------
    dim : int
        Dimension of the Lie algebra ``g`` (and of ``g*``).
    config_dim : int
        Number of real numbers that store one group element in the embedding.
    matrix_dim : int
        Size of the matrices returned by :meth:`hat`.
    algebra_names, config_names : tuple of str
        Names of the algebra coordinates and of the stored configuration numbers
        (used to label states and errors).
    """

    dim: int = 0
    config_dim: int = 0
    matrix_dim: int = 0
    algebra_names: tuple = ()
    config_names: tuple = ()

    # --- to supply -----------------------------------------------------
    def hat(self, xi):
        """Algebra vector ``(..., dim)`` -> matrix ``(..., matrix_dim, matrix_dim)``."""
        raise NotImplementedError

    def vee(self, X):
        """Inverse of :meth:`hat` on the algebra."""
        raise NotImplementedError

    def identity_config(self):
        """The identity element in the configuration embedding, shape ``(config_dim,)``."""
        raise NotImplementedError

    def config_rate(self, g, xi):
        """Rate of the stored numbers under ``g' = g . xi`` (left reconstruction).

        ``g``: ``(..., config_dim)``, ``xi``: ``(..., dim)`` -> ``(..., config_dim)``.
        """
        raise NotImplementedError

    def config_to_matrix(self, g):
        """Stored numbers -> group matrix ``(..., matrix_dim, matrix_dim)``."""
        raise NotImplementedError

    def matrix_to_config(self, G):
        """Group matrix -> stored numbers (inverse of :meth:`config_to_matrix` on the group)."""
        raise NotImplementedError

    def penalty(self, g):
        """``1/4 sum ||R^T R - I||_F^2`` over the embedded rotation blocks of ``g``.

        Zero exactly on the group (a chart such as an angle has no penalty).
        The Lyapunov function multiplies it by the gain ``k0``.
        """
        return np.zeros(np.shape(g)[:-1])

    def penalty_grad(self, g):
        """Gradient of :meth:`penalty` w.r.t. the stored numbers: ``R (R^T R - I)`` per block."""
        return np.zeros(np.shape(g))

    def penalty_hessian_bound(self):
        """Largest eigenvalue of the Hessian of :meth:`penalty` on the group (0 if none).

        For ``1/4 ||R^T R - I||^2`` at ``R`` in O(n) the Hessian is
        ``dR -> R sym(R^T dR) * 2 / 2``, whose largest eigenvalue is 2.
        """
        return 0.0

    # --- derived --------------------------------------------------------
    @cached_property
    def structure_constants(self):
        """``C[a, b, c]`` with ``[E_a, E_b] = sum_c C[a, b, c] E_c``, derived from hat/vee."""
        d = self.dim
        if d == 0:
            return np.zeros((0, 0, 0))
        E = self.hat(np.eye(d))  # (d, m, m)
        comm = E[:, None] @ E[None, :] - E[None, :] @ E[:, None]  # (d, d, m, m)
        C = self.vee(comm)
        return np.ascontiguousarray(C)

    def bracket(self, xi, eta):
        """Lie bracket ``[xi, eta]`` (antisymmetric, Jacobi), batch-first."""
        return np.einsum("...a,...b,abc->...c", xi, eta, self.structure_constants)

    def ad(self, xi):
        """Matrix of ``ad_xi``: ``ad(xi) @ eta == bracket(xi, eta)``."""
        return np.einsum("...a,abc->...cb", xi, self.structure_constants)

    def ad_star(self, xi, mu):
        """Coadjoint ``ad*_xi mu``, defined by ``<ad*_xi mu, eta> = <mu, [xi, eta]>``."""
        return np.einsum("...a,...c,abc->...b", xi, mu, self.structure_constants)

    def lie_poisson_tensor(self, mu):
        """``Lambda(mu)_ab = -<mu, [E_a, E_b]>`` so that ``{f, g} = df . Lambda . dg``.

        The Hamiltonian vector field of ``h`` on ``g*`` is
        ``mu' = Lambda(mu) dh/dmu = ad*_{dh/dmu} mu``.
        """
        return -np.einsum("...c,abc->...ab", mu, self.structure_constants)

    def exp(self, xi):
        """Group exponential as a matrix (generic: ``scipy.linalg.expm`` per element)."""
        from scipy.linalg import expm

        X = np.asarray(self.hat(xi))
        flat = X.reshape(-1, *X.shape[-2:])
        return np.stack([expm(a) for a in flat]).reshape(X.shape)

    def random_config(self, rng, shape=()):
        """Random group elements in the embedding (via ``exp`` of a random algebra vector)."""
        xi = rng.normal(size=tuple(shape) + (self.dim,))
        return self.matrix_to_config(self.exp(xi))

    def __mul__(self, other):
        from .product import ProductGroup

        return ProductGroup(self, other)

    def __repr__(self):
        return f"{type(self).__name__}()"

    def __eq__(self, other):
        return type(self) is type(other) and self.__dict__.keys() == other.__dict__.keys() and repr(self) == repr(other)

    def __hash__(self):
        return hash(repr(self))


def _penalty_block(R):
    """``1/4 ||R^T R - I||^2`` and its gradient ``R (R^T R - I)`` for ``R`` of shape (..., n, n)."""
    n = R.shape[-1]
    S = np.swapaxes(R, -1, -2) @ R - np.eye(n)
    return 0.25 * np.einsum("...ij,...ij->...", S, S), R @ S


class MatrixLieGroup(LieGroup):
    """A matrix group embedded as its whole ``matrix_dim x matrix_dim`` matrix.

    Subclasses give ``dim``, ``matrix_dim``, ``hat``, ``vee``; set
    ``orthogonal = True`` when the matrices are orthogonal, which adds the
    penalty ``1/4 ||R^T R - I||^2``.  Reconstruction is ``G' = G hat(xi)``.
    """

    orthogonal: bool = False

    @property
    def config_dim(self):
        return self.matrix_dim**2

    @property
    def config_names(self):
        m = self.matrix_dim
        return tuple(f"R{i + 1}{j + 1}" for i in range(m) for j in range(m))

    def identity_config(self):
        return np.eye(self.matrix_dim).reshape(-1)

    def config_to_matrix(self, g):
        g = np.asarray(g)
        return g.reshape(g.shape[:-1] + (self.matrix_dim, self.matrix_dim))

    def matrix_to_config(self, G):
        G = np.asarray(G)
        return G.reshape(G.shape[:-2] + (-1,))

    def config_rate(self, g, xi):
        G = self.config_to_matrix(g)
        return self.matrix_to_config(G @ self.hat(xi))

    def penalty(self, g):
        if not self.orthogonal:
            return super().penalty(g)
        return _penalty_block(self.config_to_matrix(g))[0]

    def penalty_grad(self, g):
        if not self.orthogonal:
            return super().penalty_grad(g)
        return self.matrix_to_config(_penalty_block(self.config_to_matrix(g))[1])

    def penalty_hessian_bound(self):
        return 2.0 if self.orthogonal else 0.0
