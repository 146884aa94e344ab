"""Abstract Lie group: algebra structure, coadjoint action, configuration embedding.

Conventions (the paper's, ``docs/paper_notes.md``): left action, left
trivialization ``T*G = G x g*``, reconstruction ``g' = g . xi``, and the
**minus** Lie--Poisson bracket ``{f1, f2}(mu) = -<mu, [df1/dmu, df2/dmu]>``, so
that the Hamiltonian vector field of ``h`` is ``mu' = ad*_{dh/dmu} mu``.

A concrete group supplies only

* ``dim`` (of the algebra), ``hat`` (algebra vector -> matrix) and ``vee``;
* its *configuration embedding*: the flat array that stores a group element in
  Euclidean space (``config_dim`` numbers), the reconstruction rate
  ``config_rate(g, xi)`` of ``g' = g . xi`` in that embedding, and which stored
  numbers form matrices that must stay orthogonal (:meth:`LieGroup.orthogonal_matrices`);
  the penalty that keeps an embedded element on the group, its gradient and its
  Hessian bound are derived from that declaration.

The structure constants, ``bracket``, ``ad``, ``ad*`` and the Lie--Poisson
tensor are *derived* from ``hat``/``vee``: ``[E_a, E_b] = vee(hat(E_a) hat(E_b)
- hat(E_b) hat(E_a)) = C_ab^c E_c``.  A matrix group whose embedding is the
matrix (``MatrixLieGroup``) needs nothing else but the declaration
``orthogonal_blocks`` of its rotation blocks.
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

    def orthogonal_matrices(self, g):
        """The ``k x k`` matrices stored in ``g`` that must be orthogonal: a list of ``(..., k, k)``.

        This is the group's declaration of its embedding: liefi derives the
        penalty ``1/4 sum ||R^T R - I||_F^2``, its gradient, its Hessian bound
        and the compiled code from it.  Default: none (an angle chart, ``R^n``).

        Contract: every entry of every block is one stored number of ``g`` (a
        selection: indexing and ``reshape``, no arithmetic), no number appears
        twice, and the code works on numpy object arrays (the compiled engine
        traces it with symbolic scalars).  :meth:`check` verifies this.
        A :class:`MatrixLieGroup` declares ``orthogonal_blocks`` instead; a
        product lists its factors' blocks.
        """
        return []

    def penalty(self, g):
        """``P(g) = 1/4 sum_R ||R^T R - I||_F^2`` over :meth:`orthogonal_matrices`.

        Zero exactly on the group (a chart such as an angle has no penalty).
        The Lyapunov function adds ``k0 P`` (paper, Section 4; the penalty's
        gradient is in ``docs/paper_notes.md``).
        """
        g = np.asarray(g)
        out = np.zeros(g.shape[:-1], dtype=g.dtype if g.dtype == object else float)
        for R in self.orthogonal_matrices(g):
            S = _gram_defect(R)
            out = out + 0.25 * (S * S).sum(axis=(-2, -1))
        return out

    def penalty_grad(self, g):
        """Gradient of :meth:`penalty` w.r.t. the stored numbers: ``R (R^T R - I)`` per block,
        placed at the numbers the block was read from (zero elsewhere)."""
        g = np.asarray(g)
        blocks = self.orthogonal_matrices(g)
        out = np.zeros(g.shape, dtype=g.dtype if g.dtype.kind in "cO" else float)
        for R, idx in zip(blocks, self._orthogonal_index):
            out[..., idx] = R @ _gram_defect(R)
        return out

    def penalty_hessian_bound(self):
        """Largest eigenvalue of the Hessian of :meth:`penalty` on the group (0 if none).

        For ``1/4 ||R^T R - I||^2`` at ``R`` in O(k) the Hessian is
        ``dR -> R (R^T dR + dR^T R)``, whose largest eigenvalue is 2 (on the
        symmetric part of ``R^T dR``); blocks use disjoint numbers, so the bound
        of the sum is 2 as soon as there is one block.
        """
        return 2.0 if self._orthogonal_index else 0.0

    def penalty_hessian_max(self, g):
        """Largest eigenvalue of the Hessian of :meth:`penalty` at ``g`` (batch-first), in closed form.

        For ``f(R) = 1/4 ||R^T R - I||_F^2`` the Hessian is
        ``dR -> dR (R^T R - I) + R (dR^T R + R^T dR)``.  ``f(Q R P) = f(R)`` for
        orthogonal ``Q, P``, so with ``R = U diag(s) V^T`` its spectrum is that at
        ``diag(s)``: ``3 s_i^2 - 1`` on ``dR = e_i e_i^T`` and
        ``s_i^2 + s_j^2 - 1 +- s_i s_j`` on the ``(i, j), (j, i)`` pair.  The largest
        is ``3 s_max^2 - 1`` with ``s_max^2 = lambda_max(R^T R)``; blocks use disjoint
        numbers, so the penalty's is the largest over blocks (0 with none).  On the
        group it is :meth:`penalty_hessian_bound`, 2.  Costs one small ``eigvalsh``
        per block, where a complex-step Hessian costs ``nc`` gradient evaluations.
        """
        g = np.asarray(g, dtype=float)
        out = np.zeros(g.shape[:-1])
        for R in self.orthogonal_matrices(g):
            s2 = np.linalg.eigvalsh(np.swapaxes(R, -1, -2) @ R)[..., -1]
            out = np.maximum(out, 3.0 * s2 - 1.0)
        return out

    @property
    def _orthogonal_index(self):
        """Positions in ``g`` of the entries of each orthogonal block: a tuple of ``(k, k)`` int arrays."""
        cache = self.__dict__.get("_orthogonal_index_cache")
        if cache is None:
            cache = _selection(self)
            self.__dict__["_orthogonal_index_cache"] = cache
        return cache

    def check(self, rng=None):
        """Check the group's methods that liefi differentiates; raise a named ``ValueError`` if wrong.

        * :meth:`orthogonal_matrices` selects distinct stored numbers (its contract);
        * :meth:`penalty` vanishes on the group and :meth:`penalty_grad` is its gradient;
        * :meth:`config_rate` (in ``g`` and ``xi``) and :meth:`penalty_grad` are
          complex-step safe (the stiffness estimate differentiates ``penalty_grad``
          by complex step; a float buffer would silently give zero stiffness).

        Called by :class:`~liefi.NonholonomicSystem` when a system is built; a
        passed check is remembered per group (class and parameters: groups are
        immutable), so building many systems on one group checks it once.
        """
        key = (type(self), repr(self))
        if key in _CHECKED:
            return
        from .. import _diff

        rng = np.random.default_rng(20260516) if rng is None else rng
        name = type(self).__name__
        self._orthogonal_index  # noqa: B018 -- validates the declaration
        if self.config_dim:
            try:
                on = np.asarray(self.random_config(rng), dtype=float)
            except NotImplementedError:
                on = None  # a group without exp/matrix_to_config: nothing to place on it
            if on is not None:
                P = float(np.asarray(self.penalty(on)))
                if not abs(P) < 1e-20:
                    raise ValueError(
                        f"{name}.penalty: {P:.3g} at a point of the group (random_config); the "
                        "penalty must vanish on the group: check orthogonal_matrices / orthogonal_blocks"
                    )
            else:
                on = np.asarray(self.identity_config(), dtype=float)
            g = on + 0.1 * rng.normal(size=on.shape)
            xi = rng.normal(size=self.dim)
            _diff.check_complex_step(self.penalty_grad, g, f"{name}.penalty_grad")
            _diff.check_complex_step(lambda a: self.config_rate(a, xi), g, f"{name}.config_rate")
            if self.dim:
                _diff.check_complex_step(lambda b: self.config_rate(g, b), xi, f"{name}.config_rate")
            grad = np.asarray(self.penalty_grad(g), dtype=float)
            ref = _diff.gradient(self.penalty, g)[1]
            if not np.allclose(grad, ref, rtol=1e-8, atol=1e-10 * max(1.0, float(np.max(np.abs(ref), initial=0.0)))):
                raise ValueError(
                    f"{name}.penalty_grad: not the gradient of {name}.penalty (max difference "
                    f"{np.max(np.abs(grad - ref)):.3g}); declare the orthogonal blocks and let liefi "
                    "derive both, or fix the override"
                )
        _CHECKED.add(key)

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
        # caches (structure constants, the checked flag) live in __dict__: compare state, not caches
        mine = {k for k in self.__dict__ if not k.startswith("_") and k != "structure_constants"}
        theirs = {k for k in other.__dict__ if not k.startswith("_") and k != "structure_constants"}
        return type(self) is type(other) and mine == theirs and repr(self) == repr(other)

    def __hash__(self):
        return hash(repr(self))


#: groups whose check passed, by (class, repr)
_CHECKED: set = set()


def _gram_defect(R):
    """``R^T R - I`` for ``R`` of shape ``(..., k, k)`` (plain arithmetic: traceable, complex-step safe)."""
    return np.swapaxes(R, -1, -2) @ R - np.eye(R.shape[-1])


def _selection(group):
    """The positions in ``g`` read by ``group.orthogonal_matrices``, validated against its contract."""
    name = type(group).__name__
    n = group.config_dim
    try:
        blocks = group.orthogonal_matrices(np.arange(n, dtype=float))
    except Exception as exc:  # noqa: BLE001 -- user code: say which method failed
        raise ValueError(f"{name}.orthogonal_matrices: failed on a configuration vector of {n} numbers ({exc!r})") from exc
    out, seen = [], set()
    for b in blocks:
        b = np.asarray(b)
        if b.ndim != 2 or b.shape[0] != b.shape[1] or b.shape[0] == 0:
            raise ValueError(f"{name}.orthogonal_matrices: expected square k x k blocks, got shape {b.shape}")
        idx = np.rint(b).astype(int)
        if not np.array_equal(idx, b) or idx.min() < 0 or idx.max() >= n or seen & set(idx.ravel().tolist()) or len(set(idx.ravel().tolist())) != idx.size:
            raise ValueError(
                f"{name}.orthogonal_matrices: every block entry must be one stored number of g, "
                "none twice (select with indexing and reshape; no arithmetic)"
            )
        seen |= set(idx.ravel().tolist())
        out.append(idx)
    return tuple(out)


class MatrixLieGroup(LieGroup):
    """A matrix group, embedded as the rows of its matrix that can move.

    Subclasses give ``dim``, ``matrix_dim``, ``hat``, ``vee`` and, when some
    diagonal blocks of the matrix are rotations, the declaration
    ``orthogonal_blocks = ((first row, k), ...)``: SO(3) ``((0, 3),)`` (the
    whole matrix), SE(3) ``((0, 3),)`` of its 4 x 4 matrix (the rotation block).
    liefi derives the penalty ``1/4 sum ||R^T R - I||^2`` on those blocks, its
    gradient and its Hessian bound.

    Embedding: a row ``i`` with ``hat(xi)[i] = 0`` for every ``xi`` (the last
    row of an affine group) is ``e_i`` on the whole group (``exp`` of such
    matrices keeps it), so only the other rows are stored, row-major.
    Reconstruction is ``G' = G hat(xi)``.
    """

    #: Diagonal blocks ``G[s:s+k, s:s+k]`` of the group matrix that are orthogonal: ``((s, k), ...)``.
    orthogonal_blocks: tuple = ()

    @property
    def orthogonal(self):
        """True when the whole matrix is declared orthogonal (``orthogonal_blocks == ((0, matrix_dim),)``)."""
        return tuple(map(tuple, self.orthogonal_blocks)) == ((0, self.matrix_dim),)

    @property
    def stored_rows(self):
        """Rows of the group matrix kept in the embedding (those ``hat`` can make non-zero)."""
        rows = self.__dict__.get("_stored_rows")
        if rows is None:
            E = np.asarray(self.hat(np.eye(self.dim)), dtype=float).reshape(self.dim, self.matrix_dim, self.matrix_dim)
            rows = tuple(int(i) for i in np.flatnonzero(np.any(E != 0, axis=(0, 2))))
            self.__dict__["_stored_rows"] = rows
        return rows

    @property
    def config_dim(self):
        return len(self.stored_rows) * self.matrix_dim

    @property
    def config_names(self):
        m = self.matrix_dim
        return tuple(f"R{i + 1}{j + 1}" for i in self.stored_rows for j in range(m))

    def _rows(self, g):
        g = np.asarray(g)
        return g.reshape(g.shape[:-1] + (len(self.stored_rows), self.matrix_dim))

    def orthogonal_matrices(self, g):
        rows = self._rows(g)
        return [rows[..., i : i + k, s : s + k] for i, s, k in self._block_rows]

    @property
    def _block_rows(self):
        """``(stored row index, first matrix row/column, k)`` of each declared block (validated once)."""
        out = self.__dict__.get("_block_rows_cache")
        if out is None:
            where = {r: i for i, r in enumerate(self.stored_rows)}
            out = []
            for s, k in self.orthogonal_blocks:
                s, k = int(s), int(k)
                if k < 1 or s < 0 or s + k > self.matrix_dim or any(r not in where for r in range(s, s + k)):
                    raise ValueError(
                        f"{type(self).__name__}.orthogonal_blocks: block ({s}, {k}) covers a row that hat "
                        f"never moves (constant on the group) or lies outside the {self.matrix_dim} x "
                        f"{self.matrix_dim} matrix; declare only its rotation blocks ((first row, size), ...)"
                    )
                out.append((where[s], s, k))
            out = tuple(out)
            self.__dict__["_block_rows_cache"] = out
        return out

    def identity_config(self):
        return np.eye(self.matrix_dim)[list(self.stored_rows)].reshape(-1)

    def config_to_matrix(self, g):
        rows = self._rows(g)
        if len(self.stored_rows) == self.matrix_dim:
            return rows
        where = {r: i for i, r in enumerate(self.stored_rows)}
        full = [
            rows[..., where[r], :] if r in where else np.broadcast_to(np.eye(self.matrix_dim)[r], rows.shape[:-2] + (self.matrix_dim,))
            for r in range(self.matrix_dim)
        ]
        return np.stack(full, -2)

    def matrix_to_config(self, G):
        G = np.asarray(G)
        return G[..., list(self.stored_rows), :].reshape(G.shape[:-2] + (-1,))

    def config_rate(self, g, xi):
        rate = self._rows(g) @ self.hat(xi)
        return rate.reshape(rate.shape[:-2] + (-1,))
