"""Products of traced arrays over their structurally nonzero terms only.

While the compiled engine traces (:mod:`liefi.engine.trace`) the library's
formulas run on object arrays of symbolic scalars, and numpy's dense ``@`` on
them calls ``*`` and ``+`` once per term: ``dE @ m`` in
:func:`liefi.reduction.core.evaluate` is ``n K n^2`` calls for ``n`` coordinates
and ``K`` constraints, ``N^4`` on a chain of ``N`` bodies, although the data of
such a system are mostly exact zeros.  :func:`matmul` forms the same sums
from the nonzero terms only, in the same order, so the traced expressions are
the same ones numpy's loop builds (``0 * x = 0`` and ``s + 0 = s`` are exact,
and the tracer folds them to exactly these):

.. math:: (A B)_{il} = \\sum_{j:\\, A_{ij} \\ne 0,\\, B_{jl} \\ne 0} A_{ij} B_{jl}
          \\quad (\\text{ascending } j, \\text{ left to right}),

at a cost of the number of such terms plus one scan of the operands.  Plain
(float) arrays go to numpy unchanged.
"""

from __future__ import annotations

import ctypes
import math

import numpy as np


def _kind(v) -> int:
    """1 if ``v`` is an exact zero (the number 0 or a traced constant 0, a duck-typed ``Sym``), 2 if it is a
    non-finite number or constant (``0 * inf`` is not zero: nothing is skipped then), else 0."""
    if type(v) is float:
        return 1 if v == 0 else (0 if math.isfinite(v) else 2)
    op = getattr(v, "op", None)
    if op is None:
        if not isinstance(v, (int, float, np.integer, np.floating)):
            return 0
    elif op == "const":
        v = v.value
    else:
        return 0
    return 1 if v == 0 else (0 if math.isfinite(v) else 2)


_ID = np.frompyfunc(id, 1, 1)
_TYPE = np.frompyfunc(type, 1, 1)
#: peels of :func:`_kinds` (one pass over the entries left each) before it sorts the rest
_PEELS = 8


def _addresses(a):
    """``id`` of every entry of the C-contiguous object array ``a`` (int), read from its buffer of object
    pointers without a Python call per entry (CPython's ``id`` is the address), or by ``id`` if not so."""
    ptr = np.ctypeslib.as_array((ctypes.c_ssize_t * a.size).from_address(a.ctypes.data)).copy()
    flat = a.reshape(-1)
    if ptr[0] != id(flat[0]) or ptr[-1] != id(flat[-1]):
        return _ID(flat).astype(np.int64)
    return ptr


def _kinds_each(flat, ptr):
    """:func:`_kind` of the entries ``flat`` (1-d object) with addresses ``ptr``: floats by value at once,
    other entries once per distinct object."""
    kinds = np.zeros(flat.shape, np.int8)
    isf = np.asarray(_TYPE(flat) == float, dtype=bool)
    if isf.any():
        v = flat[isf].astype(float)
        kinds[isf] = np.where(v == 0, 1, np.where(np.isfinite(v), 0, 2))
    rest, ptr = flat[~isf], ptr[~isf]
    if rest.size:
        _, first, inverse = np.unique(ptr, return_index=True, return_inverse=True)
        kinds[~isf] = np.array([_kind(rest[i]) for i in first], dtype=np.int8)[inverse.reshape(-1)]
    return kinds


def _kinds(a):
    """:func:`_kind` of every entry of the object array ``a`` (int8).

    Traced arrays hold few distinct objects, most entries one shared zero (``0.0`` or a hash-consed
    constant): the entries are grouped by identity, peeling off the object of the first entry left
    (a comparison of addresses per entry left) up to :data:`_PEELS` times; what remains goes to
    :func:`_kinds_each`.
    """
    shape, kinds = a.shape, np.zeros(a.size, np.int8)
    if not a.size:
        return kinds.reshape(shape)
    a = np.ascontiguousarray(a)
    flat, ptr = a.reshape(-1), _addresses(a)
    pos = None  # the positions left (None: all)
    for _ in range(_PEELS):
        same = ptr == ptr[0]
        k = _kind(flat[0] if pos is None else flat[pos[0]])
        if k:
            kinds[same if pos is None else pos[same]] = k
        pos = np.flatnonzero(~same) if pos is None else pos[~same]
        ptr = ptr[~same]
        if not pos.size:
            return kinds.reshape(shape)
    kinds[pos] = _kinds_each(flat[pos], ptr)
    return kinds.reshape(shape)


def _zeros(*arrays):
    """The exact-zero masks of ``arrays``, or ``None`` if any holds a non-finite number or constant."""
    kinds = [_kinds(a) if a.dtype == object else np.where(a == 0, 1, np.where(np.isfinite(a), 0, 2))
             for a in map(np.asarray, arrays)]
    if any(np.any(k == 2) for k in kinds):
        return None
    return [k == 1 for k in kinds]


def is_object(a) -> bool:
    return isinstance(a, np.ndarray) and a.dtype == object


def matmul(a, b):
    """``a @ b`` (shapes ``(..., i, j)`` and ``(..., j, l)``, batches broadcast).

    On object arrays: the sum of the structurally nonzero products (module
    docstring), an exact ``0.0`` where there is none.  Otherwise ``a @ b``.
    """
    if not (is_object(a) or is_object(b)):
        return a @ b
    a, b = np.asarray(a), np.asarray(b)
    if a.ndim < 2 or b.ndim < 2 or a.shape[-1] != b.shape[-2]:
        return a @ b  # numpy's own message for mismatched shapes
    masks = _zeros(a, b)
    if masks is None:
        return a @ b
    a, b = a.astype(object), b.astype(object)
    batch = np.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    nb = len(batch)
    a, za = a.reshape((1,) * (nb + 2 - a.ndim) + a.shape), masks[0].reshape((1,) * (nb + 2 - a.ndim) + a.shape)
    b, zb = b.reshape((1,) * (nb + 2 - b.ndim) + b.shape), masks[1].reshape((1,) * (nb + 2 - b.ndim) + b.shape)
    # the nonzero l of each row j of b, per b's own batch index
    cols = {}
    for idx in zip(*np.nonzero(~zb)):
        cols.setdefault(idx[:-1], []).append(idx[-1])
    out = np.empty(batch + (a.shape[-2], b.shape[-1]), dtype=object)
    out.fill(0.0)
    a_batch = [n != 1 for n in a.shape[:nb]]
    b_batch = [n != 1 for n in b.shape[:nb]]
    a_nz = np.argwhere(~za)  # C order: batch, then i, then j ascending
    for bi in np.ndindex(*batch):
        ai = tuple(x if f else 0 for x, f in zip(bi, a_batch))
        bj = tuple(x if f else 0 for x, f in zip(bi, b_batch))
        A, B, o = a[ai], b[bj], out[bi]
        sel = a_nz[np.all(a_nz[:, :nb] == ai, axis=1)] if nb else a_nz
        acc, row = {}, None
        for i, j in sel[:, nb:]:
            if i != row:
                for l, v in acc.items():
                    o[row, l] = v
                acc, row = {}, i
            x = A[i, j]
            for l in cols.get(bj + (j,), ()):
                p = x * B[j, l]
                acc[l] = p if l not in acc else acc[l] + p
        for l, v in acc.items():
            o[row, l] = v
    return out


def quadratic(w, C):
    """``np.einsum("...i,...kij,...j->...k", w, C, w)``: ``sum_ij (w_i C_kij) w_j``.

    On object arrays: the nonzero terms only, in numpy's order (``i`` outer, ``j`` inner).
    """
    if not (is_object(w) or is_object(C)):
        return np.einsum("...i,...kij,...j->...k", w, C, w)
    w, C = np.asarray(w), np.asarray(C)
    masks = _zeros(w, C)
    if masks is None:
        return np.einsum("...i,...kij,...j->...k", w, C, w)
    w, C = w.astype(object), C.astype(object)
    batch = np.broadcast_shapes(w.shape[:-1], C.shape[:-3])
    w, zw = np.broadcast_to(w, batch + w.shape[-1:]), np.broadcast_to(masks[0], batch + w.shape[-1:])
    C, zC = np.broadcast_to(C, batch + C.shape[-3:]), np.broadcast_to(masks[1], batch + C.shape[-3:])
    out = np.empty(batch + C.shape[-3:-2], dtype=object)
    out.fill(0.0)
    for idx in np.ndindex(*batch):
        W, nzw = w[idx], ~zw[idx]
        nz = ~zC[idx] & nzw[None, :, None] & nzw[None, None, :]
        acc = {}
        for k, i, j in np.argwhere(nz):  # C order: k, then i, then j
            p = (W[i] * C[idx + (k, i, j)]) * W[j]
            acc[k] = p if k not in acc else acc[k] + p
        for k, v in acc.items():
            out[idx + (k,)] = v
    return out


def matvec(spec, A, x):
    """``np.einsum(spec, A, x)`` for ``spec`` ``"...ij,...j->...i"`` (``A x``) or ``"...ji,...j->...i"``
    (``A^T x``); on object arrays :func:`matmul`'s sum over the nonzero terms (the same expressions:
    numpy's object einsum adds the products from ``0`` in the order of ``j``)."""
    if not (is_object(A) or is_object(x)):
        return np.einsum(spec, A, x)
    if spec == "...ji,...j->...i":
        A = np.swapaxes(A, -1, -2)
    elif spec != "...ij,...j->...i":
        raise ValueError(f"spec: expected '...ij,...j->...i' or '...ji,...j->...i', got {spec!r}")
    return matmul(A, np.asarray(x)[..., None])[..., 0]


def dot(a, b):
    """``np.einsum("...i,...i->...", a, b)`` (batches broadcast).

    On object arrays: the nonzero products ``a_i b_i`` summed in ascending ``i``, left to right (numpy's
    object einsum adds them to ``0`` in that order: the same expressions, module docstring), an exact
    ``0.0`` where there is none.  Otherwise numpy's einsum.
    """
    if not (is_object(a) or is_object(b)):
        return np.einsum("...i,...i->...", a, b)
    a, b = np.asarray(a), np.asarray(b)
    masks = _zeros(a, b) if a.ndim and b.ndim and a.shape[-1] == b.shape[-1] else None
    if masks is None:
        return np.einsum("...i,...i->...", a, b)
    shape = np.broadcast_shapes(a.shape, b.shape)
    a, b = np.broadcast_to(a, shape), np.broadcast_to(b, shape)
    nz = ~(np.broadcast_to(masks[0], shape) | np.broadcast_to(masks[1], shape))
    out = np.empty(shape[:-1], dtype=object)
    out.fill(0.0)
    acc, at = None, None
    for idx in map(tuple, np.argwhere(nz)):  # C order: batch, then i ascending
        p = a[idx] * b[idx]
        if idx[:-1] != at:
            if at is not None:
                out[at] = acc
            acc, at = p, idx[:-1]
        else:
            acc = acc + p
    if at is not None:
        out[at] = acc
    return out if out.ndim else out[()]
