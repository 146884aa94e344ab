"""Closed-form solves of 2 x 2 and 3 x 3 systems (Cramer's rule), for any numbers with ``+ - * /``.

The tracer (:mod:`liefi.engine.trace`) solves small traced systems with it --
the Gram systems of :func:`liefi.schemes.split.feedback_step` are ``m x m`` with
``m`` the number of invariants, 1 to 3 in practice -- so the generated code
holds ``adj(A) b / det A``: every component is one division by ``det A``, and
the divisions do not wait for each other, where Gaussian elimination chains
``k`` of them (pivot, update, back substitution).  For 2 x 2 and 3 x 3 systems
Cramer's rule is forward stable: its error is bounded by a small multiple of
``cond(A) u`` (Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd
ed., Sec. 1.10.1), as for Gaussian elimination.  Written with operators only,
it runs on floats as on traced values (the tests compare it with numpy).
"""

from __future__ import annotations

import numpy as np


def cramer_solve(A, X):
    """``A^{-1} X`` for ``A`` of shape ``(k, k)``, ``k`` in ``(2, 3)``, and ``X`` of shape ``(k, r)``.

    ``adj(A) X / det A``.  2 x 2: ``x0 = (a11 b0 - a01 b1) / det``,
    ``x1 = (a00 b1 - a10 b0) / det``, ``det = a00 a11 - a01 a10``.  3 x 3:
    the cofactors ``C[r][c]`` with cyclic indices (the sign is in the order),
    ``det`` along the first row, ``x_i = sum_j C[j][i] b_j / det``.  Returns an
    object array of shape ``(k, r)``.
    """
    A = np.asarray(A, dtype=object)
    X = np.asarray(X, dtype=object)
    k = A.shape[0]
    if A.shape != (k, k) or k not in (2, 3) or X.ndim != 2 or X.shape[0] != k:
        raise ValueError(f"A, X: expected shapes (k, k) and (k, r) with k = 2 or 3, got {A.shape} and {X.shape}")
    if k == 2:
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        return np.array([[(A[1, 1] * b[0] - A[0, 1] * b[1]) / det for b in X.T],
                         [(A[0, 0] * b[1] - A[1, 0] * b[0]) / det for b in X.T]], dtype=object)
    C = [[A[(r + 1) % 3, (c + 1) % 3] * A[(r + 2) % 3, (c + 2) % 3]
          - A[(r + 1) % 3, (c + 2) % 3] * A[(r + 2) % 3, (c + 1) % 3] for c in range(3)] for r in range(3)]
    det = A[0, 0] * C[0][0] + A[0, 1] * C[0][1] + A[0, 2] * C[0][2]
    return np.array([[(C[0][i] * b[0] + C[1][i] * b[1] + C[2][i] * b[2]) / det for b in X.T] for i in range(3)],
                    dtype=object)
