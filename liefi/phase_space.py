"""Reduced phase spaces ``g* x T*X`` and their Poisson brackets.

One class serves the paper's three kinds of system (Section 2):

* :class:`CotangentBundle` -- ``T*Q`` with ``Q = R^n`` in coordinates, canonical
  bracket (Sec. 2.1): no group, ``X = Q``;
* :class:`LieGroupPhaseSpace` -- ``T*G = G x g*`` reduced to ``g*`` with the minus
  Lie--Poisson bracket (Sec. 2.2): ``X`` is a point;
* :class:`TrivialPrincipalBundle` -- ``T*(G x X) = G x g* x T*X`` reduced to
  ``g* x T*X`` with the bracket ``(bracket:QG:trivial)`` (Sec. 2.3).

The reduced state is ``z = (x, mu, p_x)`` (``n + d + n`` numbers); the
momentum ``P = (mu, p_x)`` has ``D = d + n`` components.  The bracket of two
functions with gradients ``df``, ``dg`` (w.r.t. ``z``) is

.. math:: \\{f, g\\} = -\\langle \\mu, [f_\\mu, g_\\mu] \\rangle
          + f_x \\cdot g_{p_x} - g_x \\cdot f_{p_x},

i.e. ``{f, g} = df . B(z) . dg`` with the Poisson tensor ``B`` of
:meth:`PhaseSpace.poisson_tensor`.  The group element ``g`` itself is carried
only for reconstruction ``g' = g . df/dmu`` in the group's embedding.
"""

from __future__ import annotations

import numpy as np

from .groups import LieGroup, Rn


class PhaseSpace:
    """The reduced phase space ``g* x T*X`` of a trivial principal bundle ``G x X``.

    Parameters
    ----------
    group : LieGroup
        The symmetry group ``G`` (``Rn(0)`` for none).
    n : int
        Dimension of the shape space ``X`` (coordinates ``x``; 0 for none).
    names : sequence of str, optional
        Names of the shape coordinates (default ``x_1 ... x_n``).
    """

    def __init__(self, group: LieGroup, n: int = 0, names=None):
        if not isinstance(group, LieGroup):
            raise TypeError(f"group: expected a liefi.groups.LieGroup, got {group!r}")
        if int(n) != n or n < 0:
            raise ValueError(f"n: expected a non-negative integer (dimension of X), got {n!r}")
        self.group = group
        self.n = int(n)
        self.d = group.dim
        self.D = self.d + self.n
        self.nz = self.n + self.D
        names = tuple(names) if names is not None else tuple(f"x_{i + 1}" for i in range(self.n))
        if len(names) != self.n:
            raise ValueError(f"names: expected {self.n} shape-coordinate names, got {len(names)}")
        self.shape_names = names
        self.momentum_names = tuple(group.algebra_names) + tuple(f"p_{s}" for s in names)
        #: names of the reduced state ``z = (x, mu, p_x)``
        self.state_names = names + self.momentum_names
        #: names of the configuration numbers ``(g, x)``
        self.config_names = tuple(group.config_names) + names

    def __repr__(self):
        return f"{type(self).__name__}(group={self.group!r}, n={self.n})"

    # --- slicing -----------------------------------------------------------
    def split(self, z):
        """``z -> (x, mu, p_x)``."""
        n, d = self.n, self.d
        return z[..., :n], z[..., n : n + d], z[..., n + d :]

    def momentum(self, z):
        """``P = (mu, p_x)`` from ``z``."""
        return z[..., self.n :]

    # --- bracket -----------------------------------------------------------
    def bracket(self, z, df, dg):
        """``{f, g}(z)`` from the gradients ``df``, ``dg`` of shape ``(..., nz)``."""
        n, d = self.n, self.d
        x_f, mu_f, px_f = df[..., :n], df[..., n : n + d], df[..., n + d :]
        x_g, mu_g, px_g = dg[..., :n], dg[..., n : n + d], dg[..., n + d :]
        mu = z[..., n : n + d]
        lp = -np.einsum("...c,...c->...", mu, self.group.bracket(mu_f, mu_g)) if d else 0.0
        return lp + np.einsum("...i,...i->...", x_f, px_g) - np.einsum("...i,...i->...", x_g, px_f)

    def poisson_tensor(self, z):
        """``B(z)`` of shape ``(..., nz, nz)``, antisymmetric, with ``{f, g} = df . B . dg``."""
        n, d = self.n, self.d
        z = np.asarray(z)
        B = np.zeros(z.shape[:-1] + (self.nz, self.nz))
        B[..., :n, n + d :] = np.eye(n)
        B[..., n + d :, :n] = -np.eye(n)
        if d:
            B[..., n : n + d, n : n + d] = self.group.lie_poisson_tensor(z[..., n : n + d])
        return B

    def hamiltonian_vector_field(self, z, dh):
        """``z' = B(z) dh``: ``x' = h_{p_x}``, ``mu' = ad*_{h_mu} mu``, ``p_x' = -h_x``."""
        n, d = self.n, self.d
        parts = [dh[..., n + d :]]
        if d:
            parts.append(self.group.ad_star(dh[..., n : n + d], z[..., n : n + d]))
        parts.append(-dh[..., :n])
        return np.concatenate(parts, -1)


class CotangentBundle(PhaseSpace):
    """``T*Q``, ``Q = R^n`` in coordinates ``q``, with the canonical bracket (Sec. 2.1)."""

    def __init__(self, n: int, names=None):
        super().__init__(Rn(0), n, names)

    def __repr__(self):
        return f"CotangentBundle(n={self.n})"


class LieGroupPhaseSpace(PhaseSpace):
    """``T*G = G x g*`` reduced to ``g*`` with the minus Lie--Poisson bracket (Sec. 2.2)."""

    def __init__(self, group: LieGroup):
        super().__init__(group, 0)

    def __repr__(self):
        return f"LieGroupPhaseSpace({self.group!r})"


class TrivialPrincipalBundle(PhaseSpace):
    """``T*(G x X)`` reduced to ``g* x T*X``, bracket ``(bracket:QG:trivial)`` (Sec. 2.3)."""

    def __repr__(self):
        return f"TrivialPrincipalBundle({self.group!r}, n={self.n})"
