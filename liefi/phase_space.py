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

Advected vectors (semidirect-product reduction).  When the data depend on the
group element through ``Gamma = g^{-1} . a_0`` (a heavy top's potential, a
rolling body's inertia and no-slip rows; ``advected=`` a
:class:`~liefi.groups.Representation` of ``G`` on ``V = R^k``), the symmetry
left is the isotropy group of ``a_0`` and the reduced state is
``z = (x, Gamma, mu, p_x)`` on ``(g x| V)* x T*X``, with the minus Lie--Poisson
bracket of the semidirect product plus the canonical one,

.. math:: \\{f, g\\} = -\\langle \\mu, [f_\\mu, g_\\mu] \\rangle
          + \\langle f_\\mu \\cdot \\Gamma, g_\\Gamma \\rangle
          - \\langle g_\\mu \\cdot \\Gamma, f_\\Gamma \\rangle
          + f_x \\cdot g_{p_x} - g_x \\cdot f_{p_x}

(Marsden & Ratiu, *Introduction to Mechanics and Symmetry*, the heavy top: ``-Pi.(f_Pi x g_Pi) - Gamma.(f_Pi x
g_Gamma - g_Pi x f_Gamma)``).  Its Hamiltonian field is ``Gamma' = -h_mu .
Gamma`` (``= Gamma x Omega`` on ``SO(3)``, which is what ``Gamma = g^{-1} . a_0``
does along ``g' = g h_mu``) and ``mu' = ad*_{h_mu} mu + Gamma diamond h_Gamma``
(``Pi x Omega + Gamma x h_Gamma``).  Everything else is unchanged, because the
data simply take ``Gamma`` beside ``x``: the leading ``n + k`` numbers of ``z``
(``data_dim``) are the point at which the data are evaluated and differentiated,
the trailing ``D`` the momentum.  Casimirs (functions that commute with
everything): ``|Gamma|^2`` when ``G`` acts by rotations, and ``<mu, Gamma>`` on
``so(3) x| R^3``.
"""

from __future__ import annotations

import numpy as np

from . import _sparse
from ._data import as_float_array
from .groups import LieGroup, Representation, Rn


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
    casimirs : sequence of Invariant, optional
        Casimir functions of the space's bracket that its users should hold
        (e.g. the six ``<rho_i, rho_j>`` of a rolling body's advected attitude,
        :data:`liefi.systems.rolling.ATTITUDE_CASIMIRS`): first integrals of every field
        on the space, which :class:`~liefi.FeedbackIntegrator` penalizes by
        default.  Default none.
    """

    #: Casimirs that :class:`~liefi.FeedbackIntegrator` penalizes by default (``casimirs=``)
    casimirs = ()

    def __init__(self, group: LieGroup, n: int = 0, names=None, *, advected=None, a0=None, casimirs=()):
        if not isinstance(group, LieGroup):
            raise TypeError(f"group: expected a liefi.groups.LieGroup, got {group!r}")
        if int(n) != n or n < 0:
            raise ValueError(f"n: expected a non-negative integer (dimension of X), got {n!r}")
        self.group = group
        self.n = int(n)
        self.casimirs = tuple(casimirs)
        self.d = group.dim
        self.D = self.d + self.n
        #: the representation of ``G`` on ``V`` where ``Gamma`` lives (None: no advected vector)
        self.advected = advected
        #: ``a_0``: the advected vector at the identity, ``Gamma = g^{-1} . a_0``
        self.a0 = None
        self.k = 0
        if advected is not None:
            if not isinstance(advected, Representation):
                raise TypeError(f"advected: expected a liefi.groups.Representation, got {advected!r}")
            if advected.group != group:
                raise ValueError(f"advected: a representation of {advected.group!r}, but the group is {group!r}")
            self.k = advected.dim
            if a0 is None:
                raise ValueError(f"a0: required with advected= (the vector of V = R^{self.k} fixed in space, "
                                 "e.g. the vertical e_3, with Gamma = g^-1 . a0)")
            a0 = as_float_array(a0, "a0")
            if a0.shape != (self.k,) or not np.all(np.isfinite(a0)):
                raise ValueError(f"a0: expected {self.k} finite numbers (a vector of V), got {a0.tolist()!r}")
            a0.setflags(write=False)
            self.a0 = a0
        elif a0 is not None:
            raise ValueError("a0: given without advected= (the representation it lives in)")
        #: the leading ``n + k`` numbers of ``z``, ``(x, Gamma)``: where the data are evaluated
        self.data_dim = self.n + self.k
        self.nz = self.data_dim + self.D
        if isinstance(names, (str, bytes)):  # tuple("abc") would be three names, silently
            raise ValueError(f"names: expected a sequence of {self.n} shape-coordinate names, got the string {names!r}")
        names = tuple(names) if names is not None else tuple(f"x_{i + 1}" for i in range(self.n))
        if len(names) != self.n:
            raise ValueError(f"names: expected {self.n} shape-coordinate names, got {len(names)}")
        self.shape_names = names
        #: names of the components of ``Gamma`` (empty without an advected vector)
        self.advected_names = tuple(advected.names) if advected is not None else ()
        self.momentum_names = tuple(group.algebra_names) + tuple(f"p_{s}" for s in names)
        #: names of the reduced state ``z = (x, Gamma, mu, p_x)``
        self.state_names = names + self.advected_names + self.momentum_names
        #: names of the configuration numbers ``(g, x)``
        self.config_names = tuple(group.config_names) + names

    def __repr__(self):
        return f"{type(self).__name__}(group={self.group!r}, n={self.n}{self._advected_repr()})"

    def _advected_repr(self):
        return "" if self.advected is None else f", advected={self.advected!r}, a0={self.a0.tolist()}"

    # --- slicing -----------------------------------------------------------
    def split(self, z):
        """``z -> (x, mu, p_x)`` (``Gamma``: :meth:`advected_part`)."""
        n, d, a = self.n, self.d, self.data_dim
        return z[..., :n], z[..., a : a + d], z[..., a + d :]

    def advected_part(self, z):
        """``Gamma`` from ``z`` (shape ``(..., k)``; empty without an advected vector)."""
        return z[..., self.n : self.data_dim]

    def data_point(self, z):
        """``(x, Gamma)``: the leading ``data_dim`` numbers of ``z``, where the data are evaluated."""
        return z[..., : self.data_dim]

    def momentum(self, z):
        """``P = (mu, p_x)`` from ``z``."""
        return z[..., self.data_dim :]

    def advected_vector(self, g):
        """``Gamma = g^{-1} . a_0`` from the group's stored numbers ``g`` (reconstruction, initial data)."""
        if self.advected is None:
            raise ValueError("advected_vector: this phase space has no advected vector (advected=None)")
        return self.advected.body(g, self.a0)

    # --- bracket -----------------------------------------------------------
    def bracket(self, z, df, dg):
        """``{f, g}(z)`` from the gradients ``df``, ``dg`` of shape ``(..., nz)``."""
        n, d, a = self.n, self.d, self.data_dim
        x_f, mu_f, px_f = df[..., :n], df[..., a : a + d], df[..., a + d :]
        x_g, mu_g, px_g = dg[..., :n], dg[..., a : a + d], dg[..., a + d :]
        mu = z[..., a : a + d]
        lp = -np.einsum("...c,...c->...", mu, self.group.bracket(mu_f, mu_g)) if d else 0.0
        if self.k:  # <f_mu . Gamma, g_Gamma> - <g_mu . Gamma, f_Gamma>
            G, rep = z[..., n:a], self.advected
            lp = lp + np.einsum("...j,...j->...", rep.action(mu_f, G), dg[..., n:a]) - np.einsum(
                "...j,...j->...", rep.action(mu_g, G), df[..., n:a])
        # the canonical pairing, 2 n K products on the traced (object) gradients of K constraints: the sums over
        # the nonzero terms only, the same expressions (liefi._sparse)
        return lp + _sparse.dot(x_f, px_g) - _sparse.dot(x_g, px_f)

    def poisson_tensor(self, z):
        """``B(z)`` of shape ``(..., nz, nz)``, antisymmetric, with ``{f, g} = df . B . dg``."""
        n, d, a = self.n, self.d, self.data_dim
        z = np.asarray(z)
        B = np.zeros(z.shape[:-1] + (self.nz, self.nz))
        B[..., :n, a + d :] = np.eye(n)
        B[..., a + d :, :n] = -np.eye(n)
        if d:
            B[..., a : a + d, a : a + d] = self.group.lie_poisson_tensor(z[..., a : a + d])
        if self.k:  # B[mu_a, Gamma_j] = (L_a Gamma)_j = -B[Gamma_j, mu_a]
            T = self.advected.tensor(z[..., n:a])  # (..., k, d)
            B[..., a : a + d, n:a] = np.swapaxes(T, -1, -2)
            B[..., n:a, a : a + d] = -T
        return B

    def hamiltonian_vector_field(self, z, dh):
        """``z' = B(z) dh``: ``x' = h_{p_x}``, ``Gamma' = -h_mu . Gamma``,
        ``mu' = ad*_{h_mu} mu + Gamma diamond h_Gamma``, ``p_x' = -h_x``."""
        n, d, a = self.n, self.d, self.data_dim
        parts = [dh[..., a + d :]]
        if self.k:
            G, rep = z[..., n:a], self.advected
            parts.append(-rep.action(dh[..., a : a + d], G))
        if d:
            mudot = self.group.ad_star(dh[..., a : a + d], z[..., a : a + d])
            if self.k:
                mudot = mudot + rep.diamond(G, dh[..., n:a])
            parts.append(mudot)
        parts.append(-dh[..., :n])
        return np.concatenate(parts, -1)


class CotangentBundle(PhaseSpace):
    """``T*Q``, ``Q = R^n`` in coordinates ``q``, with the canonical bracket (Sec. 2.1)."""

    def __init__(self, n: int, names=None):
        super().__init__(Rn(0), n, names)

    def __repr__(self):
        return f"CotangentBundle(n={self.n})"


class LieGroupPhaseSpace(PhaseSpace):
    """``T*G = G x g*`` reduced to ``g*`` with the minus Lie--Poisson bracket (Sec. 2.2).

    With ``advected=`` (a :class:`~liefi.groups.Representation` on ``V``) and
    ``a0``: reduced by the isotropy group of ``a0`` to ``(g x| V)*``, state
    ``(Gamma, mu)`` (the heavy top: ``(Gamma, Pi)``).
    """

    def __init__(self, group: LieGroup, *, advected=None, a0=None, casimirs=()):
        super().__init__(group, 0, advected=advected, a0=a0, casimirs=casimirs)

    def __repr__(self):
        return f"LieGroupPhaseSpace({self.group!r}{self._advected_repr()})"


class TrivialPrincipalBundle(PhaseSpace):
    """``T*(G x X)`` reduced to ``g* x T*X``, bracket ``(bracket:QG:trivial)`` (Sec. 2.3).

    With ``advected=`` and ``a0``: reduced to ``(g x| V)* x T*X``, state
    ``(x, Gamma, mu, p_x)``.
    """

    def __repr__(self):
        return f"TrivialPrincipalBundle({self.group!r}, n={self.n}{self._advected_repr()})"
