"""The split schemes' loop for a large system: one loop over the stages, the tableau read at run time.

:func:`liefi.engine.codegen.scalar_loop_source` unrolls a tableau: every stage's sums are printed
component by component, so that ``imex-rk8`` (12 stages) on the rattleback (25 states) is some 4000
operations of Python source, and numba's compile of it costs as much as that of the field itself, once
per scheme.  For a system whose field is not inlined anyway (more than
:data:`~liefi.engine.codegen.MAX_INLINE_ARGS` scalar arguments: the field is a call, its stages do not
live in registers across it) :func:`rolled_split_loops_source` prints one loop ``split_loop`` instead,
shared by every split scheme: the stages ``K`` in an array, the coefficients ``dt a_ij`` and the
grouped weights ``dt b`` (:func:`liefi.engine.codegen._b_groups`) in arrays made from the tableau.
Each scheme's entry ``run_<scheme>`` (the same signature, the same ``_batch``) passes its tableau; it is
plain Python, and ``split_loop`` flushes subnormals itself (:mod:`liefi.engine.fpu`): a compiled wrapper
would link the loop, with the field and the feedback step in it, into itself and optimise it all again.

The arithmetic is that of the unrolled loop, term for term, so the results are bit-identical:

.. math:: Y_i = (\\cdots((y + c_{i j_1} k_{j_1}) + c_{i j_2} k_{j_2}) + \\cdots), \\qquad
          z = (\\cdots(y + \\beta_1 (k_{g_{11}} + k_{g_{12}} + \\cdots)) + \\beta_2 (\\cdots)) \\cdots

over the nonzero ``a_ij`` (``c_ij = dt a_ij``) in the order of ``j``, and the groups of equal weights
(``beta_g = dt b_g``) in their order of first appearance; then the feedback step ``fstep_s``, and the
same checks, saves and returned ``(failed_step, last_good_step, 0)``.
"""

from __future__ import annotations

import numpy as np


def _tableau_arrays(scheme):
    """``(A, AJ, AN, B, BJ, BN)``: the nonzero ``a_ij`` of each stage ``i`` (``A[i, :AN[i]]``, columns
    ``AJ[i, :AN[i]]``, in the order of ``j``) and the weight groups (``B[g]``, members ``BJ[g, :BN[g]]``)."""
    from .codegen import _b_groups

    S = scheme.stages
    A, AJ, AN = np.zeros((S, max(S, 1))), np.zeros((S, max(S, 1)), np.int64), np.zeros(S, np.int64)
    for i in range(S):
        coeffs = [(j, a) for j, a in enumerate(scheme.A[i][:i]) if a]
        AN[i] = len(coeffs)
        for m, (j, a) in enumerate(coeffs):
            A[i, m], AJ[i, m] = float(a), j
    groups = _b_groups(scheme)
    B, BJ, BN = np.zeros(len(groups)), np.zeros((len(groups), S), np.int64), np.zeros(len(groups), np.int64)
    for g, (b, js) in enumerate(groups):
        B[g], BN[g] = b, len(js)
        BJ[g, :len(js)] = js
    return A, AJ, AN, B, BJ, BN


def _array_literal(name, a):
    """``name = np.array([...], dtype)``: the values printed exactly (``repr`` of a float round-trips)."""
    return f"{name} = np.array({a.tolist()!r}, np.{a.dtype.name})"


_TABLEAU = ("A", "AJ", "AN", "B", "BJ", "BN")


def rolled_split_loops_source(N, n_params, schemes):
    """Source of ``split_loop`` and of ``run_<scheme>`` (with ``_batch``) for each split scheme of ``schemes``,
    for a state of size ``N`` and ``n_params`` parameters, on ``xrhs_s`` and ``fstep_s``."""
    from .codegen import _LOOP_ARGS, _batch_source, scalar_names, split_loop_name

    ps = ", ".join(scalar_names("p", n_params))
    pa = f", {ps}" if n_params else ""
    def each(fmt, indent):
        return [" " * indent + fmt.format(n=n) for n in range(N)]

    ys, yis, zs = (", ".join(scalar_names(v, N)) for v in ("y", "yi", "z"))
    comma = "," if N == 1 else ""
    L = ["@njit(cache=CACHE, error_model='numpy')",
         f"def split_loop({_LOOP_ARGS}, A, AJ, AN, B, BJ, BN):"]
    L += ["    csr = fpu_enter()"]  # flushed here, not in a compiled wrapper: that would link and re-optimise the loop
    L += each("y_{n} = y0[{n}]", 4)
    L += [f"    p_{i} = p[{i}]" for i in range(n_params)]
    L += ["    S = AN.shape[0]",
          "    G = BN.shape[0]",
          f"    K = np.empty((S, {N}))",
          "    C = np.empty(A.shape)",
          "    CB = np.empty(G)",
          "    for i in range(S):",
          "        for m in range(AN[i]):",
          "            C[i, m] = dt * A[i, m]",
          "    for g in range(G):",
          "        CB[g] = dt * B[g]"]
    L += each("out[{n}, 0] = y_{n}", 4) + each("last[{n}] = y_{n}", 4)
    L += ["    j = 1", "    last_step = 0", "    to_check = check_every", "    to_save = save_every",
          "    for step in range(1, n_steps + 1):",
          "        for i in range(S):",
          "            if AN[i] == 0:",  # (two calls of the field: LLVM keeps it a call, not a copy in the loop)
          f"                r = xrhs_s({ys}{pa})",
          "            else:"]
    L += each("yi_{n} = y_{n}", 16)
    L += ["                for m in range(AN[i]):",  # component by component, the terms in the order of j
          "                    c = C[i, m]",
          "                    q = AJ[i, m]"]
    L += each("yi_{n} = yi_{n} + c * K[q, {n}]", 20)
    L += [f"                r = xrhs_s({yis}{pa})"]
    L += each("K[i, {n}] = r[{n}]", 12)
    L += each("z_{n} = y_{n}", 8)
    L += ["        for g in range(G):",  # the groups of equal weights, in their order of first appearance
          "            q = BJ[g, 0]"]
    L += each("t_{n} = K[q, {n}]", 12)
    L += ["            for m in range(1, BN[g]):",
          "                q = BJ[g, m]"]
    L += each("t_{n} = t_{n} + K[q, {n}]", 16)
    L += ["            c = CB[g]"]
    L += each("z_{n} = z_{n} + c * t_{n}", 12)
    L += [f"        {zs}{comma} = fstep_s({zs}{pa}, dt)"]
    L += ["        to_check -= 1",
          "        if to_check == 0 or step == n_steps:",
          "            to_check = check_every",
          "            s = " + " + ".join(scalar_names("z", N)),
          "            if not (s - s == 0.0):"]
    L += each("bad[{n}] = z_{n}", 16)
    L += ["                if last_step == step - 1:"]  # the last good state is the one this step started from
    L += each("last[{n}] = y_{n}", 20)
    L += ["                fpu_exit(csr)",
          "                return step, last_step, 0",
          "            if check_every > 1:"]  # else the next check is next step's: y holds the state then
    L += each("last[{n}] = z_{n}", 16)
    L += ["            last_step = step"]
    L += each("y_{n} = z_{n}", 8)
    L += ["        to_save -= 1",
          "        if to_save == 0 or step == n_steps:",
          "            to_save = save_every"]
    L += each("out[{n}, j] = y_{n}", 12)
    L += ["            j += 1"]
    L += each("last[{n}] = y_{n}", 4)
    L += ["    fpu_exit(csr)", "    return 0, last_step, 0", ""]
    for sch in schemes:
        fname = split_loop_name(sch)
        tag = fname.upper()
        L.append("")
        L += [_array_literal(f"{tag}_{k}", a) for k, a in zip(_TABLEAU, _tableau_arrays(sch.explicit))]
        call = f"split_loop({_LOOP_ARGS}, " + ", ".join(f"{tag}_{k}" for k in _TABLEAU) + ")"
        L += ["", "", f"def {fname}({_LOOP_ARGS}):",  # plain Python: calls the compiled loop as it is
              f"    return {call}", ""]
        L.append(_batch_source(fname, call=call))
    return "\n".join(L) + "\n"


def split_loops_source(N, n_params):
    """The loops of the split schemes of :mod:`liefi.schemes.split` (``run_imex_euler``, ...), on
    ``xrhs_s`` and ``fstep_s`` (:func:`scalar_loop_source`); for a system with more than
    :data:`MAX_INLINE_ARGS` scalar arguments, one loop shared by the schemes, their tableaux read at
    run time (:func:`rolled_split_loops_source`: the same arithmetic, a fraction
    of the compile)."""
    from ..schemes.split import SPLIT_SCHEMES
    from .codegen import MAX_INLINE_ARGS, scalar_loop_source, split_loop_name

    if N + n_params > MAX_INLINE_ARGS:
        return rolled_split_loops_source(N, n_params, SPLIT_SCHEMES.values())
    return "\n".join(scalar_loop_source(split_loop_name(s), s.explicit, N, n_params, split=True)
                     for s in SPLIT_SCHEMES.values())
