r"""The outer eigenvalues of ``dX/dy`` of a large system, from Jacobian-vector products (Arnoldi).

The guard needs the eigenvalues ``mu`` of the unforced field's Jacobian ``dX/dy`` for the spectral
radius (``dt max |mu|``, the resolution) and the scheme's growth ``max |R(dt mu)|``: both are set by the
outer part of the spectrum.  Central differences of ``X`` along every coordinate cost ``2n`` field
evaluations per state, each of which (a constrained system read from a user's callables) costs
``O(n^2)`` or more: on a chain of ``N`` knife edges that is ``N^4`` work and memory (5 GB at
``N = 32``).  Above :data:`DENSE_MAX_STATES` states the eigenvalues are the Ritz values of ``k``
(:data:`KRYLOV_DIM`) steps of Arnoldi's method instead,

.. math:: J V_k = V_{k+1} \bar H_k, \qquad J v \approx \frac{X(y + \varepsilon v) - X(y - \varepsilon v)}
          {2 \varepsilon}, \quad \varepsilon = 10^{-6} \max(1, \|y\|_\infty),

from a fixed start vector (deterministic), with Gram--Schmidt applied twice; the eigenvalues of
``H_k`` (``k x k``) converge first to the outermost ones (Saad, *Numerical Methods for Large
Eigenvalue Problems*, ch. 6), so the spectral radius and the growth are those of the dense
Jacobian to a few per cent at ``2k`` field evaluations per state, independent of ``n``.
"""

from __future__ import annotations

import numpy as np

from .._diff import directions_after

#: Up to this many states the Jacobian is formed densely (exact eigenvalues; every scene of liefi).
DENSE_MAX_STATES = 64
#: The Krylov dimension above it.
KRYLOV_DIM = 32


def ritz_values(field, y, k=KRYLOV_DIM):
    """Ritz values of ``dX/dy`` at the states ``y`` (``(..., n)``) from ``k`` Arnoldi steps: ``(..., m)``,
    ``m <= k`` (fewer when the Krylov space is invariant).  ``field`` is ``X`` on a batch ``(..., 2, n)``."""
    y = np.asarray(y, dtype=float)
    n = y.shape[-1]
    k = int(min(k, n))
    batch = y.shape[:-1]
    v0 = np.random.default_rng(0).standard_normal(n)
    V = np.zeros(batch + (k + 1, n))
    H = np.zeros(batch + (k + 1, k))
    V[..., 0, :] = v0 / np.linalg.norm(v0)
    eps = 1e-6 * np.maximum(1.0, np.max(np.abs(y), axis=-1, initial=0.0))[..., None]
    m = k
    with np.errstate(all="ignore"), directions_after(y):
        for j in range(k):
            v = V[..., j, :]
            F = field(np.stack([y + eps * v, y - eps * v], axis=-2))
            w = (F[..., 0, :] - F[..., 1, :]) / (2 * eps)
            for _ in range(2):  # Gram--Schmidt, twice: orthogonal to rounding
                c = np.einsum("...in,...n->...i", V[..., : j + 1, :], w)
                w = w - np.einsum("...i,...in->...n", c, V[..., : j + 1, :])
                H[..., : j + 1, j] += c
            beta = np.linalg.norm(w, axis=-1)
            H[..., j + 1, j] = beta
            scale = np.max(np.abs(H[..., : j + 2, : j + 1]), axis=(-2, -1), initial=0.0)
            done = ~(beta > 1e-12 * scale)
            if np.all(done):  # an invariant subspace: its eigenvalues are exact
                m = j + 1
                break
            V[..., j + 1, :] = np.where(done[..., None], 0.0, w / np.where(done, 1.0, beta)[..., None])
    return np.linalg.eigvals(H[..., :m, :m])
