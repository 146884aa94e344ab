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
_GETATTR = np.frompyfunc(getattr, 3, 1)  # getattr(entry, name, default) of every entry, without a Python frame
#: peels of :func:`_kinds` (one pass over the entries left each) before it sorts the rest
_PEELS = 8


def _addresses(a):
    """``id`` of every entry of the C-contiguous object array ``a`` (int), read from its buffer of object
    pointers without a Python call per entry (CPython's ``id`` is the address), or by ``id`` if not so.
    A view of that buffer (no copy: a chain's ``dE`` holds ``9 N^3`` pointers), valid while ``a`` lives."""
    ptr = np.ctypeslib.as_array((ctypes.c_ssize_t * a.size).from_address(a.ctypes.data))
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


def _where(mask):
    """``np.argwhere(mask)`` (the indices of the true entries, C order) from the flat positions: a tenth of its
    cost on a chain's ``(3N, N, 3N)`` masks of a few nonzeros."""
    mask = np.asarray(mask)
    if mask.ndim == 0:
        return np.argwhere(mask)
    return np.stack(np.unravel_index(np.flatnonzero(mask), mask.shape), -1).astype(np.intp, copy=False)


def _zeros(*arrays):
    """The exact-zero masks of ``arrays``, or ``None`` if any holds a non-finite number or constant."""
    kinds = [_kinds(a) if a.dtype == object else np.where(a == 0, 1, np.where(np.isfinite(a), 0, 2))
             for a in map(np.asarray, arrays)]
    if any(np.any(k == 2) for k in kinds):
        return None
    return [k == 1 for k in kinds]


def is_object(a) -> bool:
    return isinstance(a, np.ndarray) and a.dtype == object


def exact_zeros(a):
    """The exact-zero mask of ``a`` (bool, ``a``'s shape), or ``None`` if it holds a non-finite number or
    constant: what :func:`matmul` takes as ``zeros=`` to classify an operand used twice once."""
    got = _zeros(a)
    return None if got is None else got[0]


def matmul(a, b, *, zeros=None):
    """``a @ b`` (shapes ``(..., i, j)`` and ``(..., j, l)``, batches broadcast).

    On object arrays: the sum of the structurally nonzero products (module
    docstring), an exact ``0.0`` where there is none.  Otherwise ``a @ b``.
    ``zeros``: ``(za, zb)``, the operands' exact-zero masks where known (:func:`exact_zeros`; ``None``
    entries are computed): on a chain's ``(3N, N, 3N)`` derivatives each pass over the entries is ``N^3``.
    ``a`` may be :class:`Rows` (:func:`matmul_rows`).
    """
    out, rows = _matmul(a, b, zeros)
    return rows.dense() if out is None else out


def matmul_rows(a, b, *, zeros=None):
    """:func:`matmul` on traced arrays as :class:`Rows` (its nonzero entries, no dense result); ``a`` may be
    :class:`Rows` too.  A dense array where :func:`matmul` falls back to numpy."""
    out, rows = _matmul(a, b, zeros, dense=False)
    return rows if out is None else out


class Rows:
    """The nonzero entries of a traced product of shape ``shape`` (``(..., i, l)``), in C order:
    ``entries[batch] = [(i, l, value), ...]``; ``written`` every sum formed, zeros included."""

    def __init__(self, shape, entries, written):
        self.shape, self.entries, self.written = shape, entries, written
        #: whether an entry is a non-finite number or constant (then nothing may be skipped)
        self.unknown = any(_kind(v) == 2 for *_, v in written)

    def dense(self):
        out = np.empty(self.shape, dtype=object)
        out.fill(0.0)
        for bi, i, l, v in self.written:
            out[bi + (i, l)] = v
        return out


def _matmul(a, b, zeros, dense=True):
    """``(out, rows)``: ``a @ b`` dense (``dense=True``, or numpy's fallback, then ``rows`` is ``None``) and
    its :class:`Rows` (``out`` ``None`` when not ``dense``)."""
    if isinstance(a, Rows):
        if a.unknown:  # a non-finite entry: nothing is skipped (numpy's product of the dense array)
            return _matmul(a.dense(), b, None if zeros is None else (None, zeros[1]), dense)
        a_rows, a_shape = a, a.shape
    else:
        if not (is_object(a) or is_object(b)):
            return a @ b, None
        a = np.asarray(a)
        a_rows, a_shape = None, a.shape
    b = np.asarray(b)
    if len(a_shape) < 2 or b.ndim < 2 or a_shape[-1] != b.shape[-2]:
        return (a.dense() if a_rows else a) @ b, None  # numpy's own message for mismatched shapes
    za, zb = zeros if zeros is not None else (None, None)
    todo = [x for x, z in ((a, za if a_rows is None else 0), (b, zb)) if z is None]
    masks = _zeros(*todo) if todo else []
    if masks is None:
        return (a.dense() if a_rows else a) @ b, None
    if a_rows is None and za is None:
        za = masks.pop(0)
    zb = masks.pop(0) if zb is None else zb
    b = b.astype(object, copy=False)
    batch = np.broadcast_shapes(a_shape[:-2], b.shape[:-2])
    nb = len(batch)
    a_full = (1,) * (nb + 2 - len(a_shape)) + a_shape
    b, zb = b.reshape((1,) * (nb + 2 - b.ndim) + b.shape), zb.reshape((1,) * (nb + 2 - b.ndim) + b.shape)
    # the nonzero l of each row j of b, per b's own batch index
    cols = {}
    for idx in map(tuple, _where(~zb).tolist()):
        cols.setdefault(idx[:-1], []).append(idx[-1])
    a_batch = [n != 1 for n in a_full[:nb]]
    b_batch = [n != 1 for n in b.shape[:nb]]
    if a_rows is not None:  # (its batch is the full one of a_shape: pad on the left)
        pad = (0,) * (nb + 2 - len(a_shape))
        groups = {pad + k: v for k, v in a_rows.entries.items()}
    else:
        a, za = a.astype(object, copy=False).reshape(a_full), za.reshape(a_full)
        a_nz = _where(~za)  # C order: batch, then i, then j ascending
        # the rows of a_nz of each batch index of a (contiguous in C order)
        if nb and len(a_nz):
            keys = a_nz[:, :nb]
            cut = np.flatnonzero(np.any(keys[1:] != keys[:-1], axis=1)) + 1
            groups = {tuple(keys[s0].tolist()): a_nz[s0:e0, nb:].tolist()
                      for s0, e0 in zip(np.r_[0, cut], np.r_[cut, len(a_nz)])}
        else:
            groups = {(): a_nz[:, nb:].tolist()} if len(a_nz) else {}
    shape = batch + (a_full[-2], b.shape[-1])
    written, entries = [], {}
    for bi in np.ndindex(*batch):
        ai = tuple(x if f else 0 for x, f in zip(bi, a_batch))
        sel = groups.get(ai)
        if not sel:
            continue
        bj = tuple(x if f else 0 for x, f in zip(bi, b_batch))
        B = b[bj]
        if a_rows is None:
            A = a[ai]
            sel = [(i, j, A[i, j]) for i, j in sel]
        acc, row, mine = {}, None, []
        for i, j, x in sel:
            if i != row:
                mine.extend((row, l, v) for l, v in sorted(acc.items()))
                acc, row = {}, i
            for l in cols.get(bj + (j,), ()):
                p = x * B[j, l]
                acc[l] = p if l not in acc else acc[l] + p
        mine.extend((row, l, v) for l, v in sorted(acc.items()))
        written.extend((bi, i, l, v) for i, l, v in mine)
        entries[bi] = [(i, l, v) for i, l, v in mine if _kind(v) != 1]
    rows = Rows(shape, entries, written)
    return (rows.dense() if dense else None), rows


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
    w, C = w.astype(object, copy=False), C.astype(object, copy=False)
    batch = np.broadcast_shapes(w.shape[:-1], C.shape[:-3])
    w, zw = np.broadcast_to(w, batch + w.shape[-1:]), np.broadcast_to(masks[0], batch + w.shape[-1:])
    C, zC = np.broadcast_to(C, batch + C.shape[-3:]), np.broadcast_to(masks[1], batch + C.shape[-3:])
    out = np.empty(batch + C.shape[-3:-2], dtype=object)
    out.fill(0.0)
    for idx in np.ndindex(*batch):
        W, nzw = w[idx], ~zw[idx]
        nz = ~zC[idx] & nzw[None, :, None] & nzw[None, None, :]
        acc = {}
        for k, i, j in _where(nz).tolist():  # C order: k, then i, then j
            p = (W[i] * C[idx + (k, i, j)]) * W[j]
            acc[k] = p if k not in acc else acc[k] + p
        for k, v in acc.items():
            out[idx + (k,)] = v
    return out


def symmetrized(C):
    """``C + swapaxes(C, -1, -2)`` (the last two axes square).

    On object arrays: the sum taken only where ``C_ij`` or ``C_ji`` is not an exact zero, entry by entry in C
    order with Python's ``+`` (numpy's object loop: the same expressions); an exact zero ``0.0`` elsewhere (the
    sign of a zero is not kept: :func:`quadratic` and :func:`matmul` skip exact zeros).  Otherwise numpy's sum.
    A dense object sum of a chain's ``(n, K, K)`` Gram derivative made ``n K^2`` Python calls and as many
    distinct float zeros, ``N^3`` (:func:`liefi.reduction.core.evaluate`).
    """
    Ct = np.swapaxes(C, -1, -2)
    if not is_object(C):
        return C + Ct
    masks = _zeros(C)
    if masks is None:
        return C + Ct
    z = masks[0]
    out = np.empty(C.shape, dtype=object)
    out.fill(0.0)
    for idx in map(tuple, _where(~(z & np.swapaxes(z, -1, -2))).tolist()):  # C order
        out[idx] = C[idx] + Ct[idx]
    return out


def _positive_zero(v) -> bool:
    """Whether ``v`` is the float ``+0.0`` or a traced constant ``+0.0``."""
    if type(v) is not float:
        if getattr(v, "op", None) != "const":
            return False
        v = v.value
    return v == 0 and math.copysign(1.0, v) > 0


def accumulate(y, a, x):
    """``y + a[..., None] * x``: the sum of a gradient ``x`` scaled by ``a`` into ``y``.

    On a traced (non-constant) scalar ``a`` and a traced vector ``x`` with exact zeros: numpy's two passes
    (every product, then every sum, in order), where a term with ``x_i`` an exact zero is ``a * x_i = 0``
    (the tracer's constant ``+0.0``) and ``y_i + 0`` is ``y_i`` for a non-constant ``y_i`` and ``0`` for a
    zero ``y_i = +0.0``, so neither is formed again: the same expressions with a Python call per nonzero
    term.  (:meth:`liefi.FeedbackIntegrator.field_parts` sums ``k_i r_i dJ_i`` over a chain's ``N``
    constraints, ``6 N^2`` products of mostly zeros.)  Otherwise numpy's expression.
    """
    op = getattr(a, "op", None)
    if not (is_object(x) and x.ndim == 1 and op is not None and op != "const"
            and (np.ndim(y) == 0 or np.shape(y) == x.shape)):
        return y + np.asarray(a)[..., None] * x
    kx = _kinds(x)
    if np.any(kx == 2):
        return y + np.asarray(a)[..., None] * x
    zero = kx == 1
    at = np.flatnonzero(zero)
    if at.size:  # a float -0.0 would be a new constant to the tracer: the zeros checked at once
        xz = x[at]
        ops = _GETATTR(xz, "op", None)
        if not np.all(np.asarray(ops == "const", dtype=bool) | _positive_zeros(xz, ops)):
            return y + np.asarray(a)[..., None] * x
    nonzero = np.flatnonzero(~zero)
    prod = np.empty(x.shape, dtype=object)
    z0 = None
    # numpy's first pass, the products in ascending i: a * x_i at the nonzero x_i, and one a * 0 (formed where
    # the first zero stands: the node order of numpy's loop) shared by every zero
    first_zero = at[0] if at.size else x.size
    before = [(i, a * x[i]) for i in nonzero[nonzero < first_zero].tolist()]
    if at.size:
        z0 = a * x[first_zero]
        if not _positive_zero(z0):
            return y + np.asarray(a)[..., None] * x  # (not the tracer's 0 * a = +0: every term formed)
        prod.fill(z0)
    for i, v in before:
        prod[i] = v
    for i in nonzero[nonzero > first_zero].tolist():
        prod[i] = a * x[i]
    ys = np.broadcast_to(np.asarray(y, dtype=object), x.shape)
    out = np.empty(x.shape, dtype=object)
    # the second, the sums: at a zero x_i, y_i + 0 is y_i for a non-constant traced y_i and the shared +0 for
    # a zero y_i = +0.0, found for all entries at once (no Python call per entry); every other sum is formed,
    # in ascending i
    kept = np.zeros(x.shape, dtype=bool)
    if at.size:
        ops = _GETATTR(ys, "op", None)
        traced = np.asarray(np.not_equal(ops, None), dtype=bool) & np.asarray(ops != "const", dtype=bool)
        out.fill(z0)
        out[traced] = ys[traced]
        kept = zero & (traced | _positive_zeros(ys, ops))
    for i in np.flatnonzero(~kept).tolist():
        out[i] = ys[i] + prod[i]
    return out


def _positive_zeros(v, ops):
    """Whether each entry of the object array ``v`` is a traced constant ``+0.0`` or a number ``+0`` (``ops``:
    each entry's ``op``, ``None`` for a number), read at once.  (A number ``+0`` of any type, as
    :func:`_positive_zero`'s float: ``s + 0`` and ``a * 0`` form the same nodes whatever its type.)"""
    out = np.zeros(v.shape, dtype=bool)
    is_const = np.asarray(ops == "const", dtype=bool)
    sel = is_const | np.asarray(np.equal(ops, None), dtype=bool)
    if sel.any():
        try:
            vals = np.where(is_const, _GETATTR(v, "value", None), v)[sel].astype(np.float64)
        except (TypeError, ValueError):  # not numbers: one by one
            return np.array([_positive_zero(e) for e in v.reshape(-1)], dtype=bool).reshape(v.shape)
        out[sel] = (vals == 0) & ~np.signbit(vals)
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
    for idx in map(tuple, _where(nz).tolist()):  # C order: batch, then i ascending
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
