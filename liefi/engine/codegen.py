"""Code generation: traced graphs printed as straight-line Python, and the stepping loops.

:func:`function_source` prints a traced graph as a function of ``(y, p, out)``
with one assignment per node (in creation order, a topological order);
:func:`scalar_function_source` prints the same graph as a function of scalars
returning a tuple.  The loops (:func:`scalar_loop_source`: a scheme's tableau
unrolled, the same arithmetic order as
:meth:`liefi.schemes.ExplicitRungeKutta.step`, the state, stages and
parameters in local variables so that the compiled loop keeps them in
registers; :func:`loop_source`, the same on arrays, for the projected loops;
each for one trajectory and for a batch with ``prange``), the Newton
projection and the DLA loop are templates around them.  Every ``@njit`` reads ``CACHE`` from the module header
(:func:`module_text`), so the same source runs with numba's on-disk cache or
compiled in memory (:mod:`liefi.engine.cache`), or as plain Python.
"""

from __future__ import annotations

import math

import numpy as np

from .symbolic import _BINARY, _UNARY, as_sym

def _literal(v):
    if v != v:
        return "math.nan"
    if v in (math.inf, -math.inf):
        return "math.inf" if v > 0 else "(-math.inf)"
    r = repr(float(v))
    return f"({r})" if v < 0 or r.startswith("-") else r


def reachable(outputs):
    """Every non-constant node reachable from ``outputs``, in creation order (a topological order of the graph)."""
    seen = {}
    stack = list(outputs)
    while stack:
        node = stack.pop()
        if node.id in seen or node.op == "const":
            continue
        seen[node.id] = node
        if node.op != "var":
            stack.extend(node.args)
    return sorted(seen.values(), key=lambda s: s.id)


def node_expression(node, ref):
    """The Python expression of an operation node, its arguments printed by ``ref[id]`` (constants as literals)."""
    a = [_literal(x.value) if x.op == "const" else ref[x.id] for x in node.args]
    if node.op == "pow" and node.args[1].op == "const":
        return f"({a[0]} ** {_literal(node.args[1].value)})"
    if node.op in _BINARY:
        return _BINARY[node.op].format(*a)
    return _UNARY[node.op].format(*a)


def node_lines(outputs, var_ref, indent="    ", prefix="", ref=None):
    """Assignments ``t<id> = ...`` (``<prefix>_t<id>`` with a prefix) of every node reachable from ``outputs``
    (in creation order, a topological order of the graph) and the expressions of the outputs;
    ``var_ref(name, index)`` prints an input.  ``ref`` (node id -> name; updated): nodes already computed,
    which are not computed again."""
    ref = {} if ref is None else ref
    lines = []
    for node in reachable(outputs):
        if node.id in ref:
            continue
        if node.op == "var":
            ref[node.id] = var_ref(*node.args)
            continue
        name = f"{prefix}_t{node.id}" if prefix else f"t{node.id}"
        lines.append(f"{indent}{name} = {node_expression(node, ref)}")
        ref[node.id] = name
    return lines, [_literal(o.value) if o.op == "const" else ref[o.id] for o in outputs]



def _syms(outputs):
    return [as_sym(o) for o in np.asarray(outputs, dtype=object).reshape(-1)]


def function_source(name, outputs, args=("y", "p", "out")):
    """Python source of ``def name(*args)`` writing ``outputs`` (Syms) into ``out[j]``.

    One assignment per reachable node, in creation order (a topological order
    of the graph).
    """
    outputs = _syms(outputs)
    body, vals = node_lines(outputs, lambda name, i: f"{name}[{i}]")
    lines = [f"def {name}({', '.join(args)}):"] + body
    lines += [f"    {args[-1]}[{j}] = {v}" for j, v in enumerate(vals)]
    if len(lines) == 1 or not outputs:
        lines.append("    return")
    return "\n".join(lines) + "\n"


def scalar_names(name, size):
    """The scalar arguments ``name_0, ..., name_{size-1}`` of an input of :func:`scalar_function_source`."""
    return [f"{name}_{i}" for i in range(size)]


#: the most arguments of a function numba inlines (``inline='always'``); 31 fail in numba 0.6x
MAX_INLINE_ARGS = 30


def scalar_function_source(name, outputs, inputs, *, wrapper=None, inline=False):
    """``def name(y_0, ..., p_0, ...)`` returning ``outputs`` (Syms) as a tuple; inputs as scalars.

    ``inputs`` is ``[(symbol name, size), ...]`` in the order of the arguments.
    The loops keep the state and the parameters in local variables and call
    this form (numba inlines it; its tuple lives in registers).  ``wrapper``
    ``(fname, args)`` also prints the array form ``def fname(*args)`` (the
    inputs as arrays, then ``out``) that unpacks its arrays, calls ``name`` and
    writes ``out``: one home for the formulas, two calling conventions.
    ``inline``: numba inlines the function into its callers itself (``inline='always'``;
    for a function called once per step, which LLVM does not always inline).
    """
    outputs = _syms(outputs)
    params = [a for nm, size in inputs for a in scalar_names(nm, size)]
    body, vals = node_lines(outputs, lambda nm, i: f"{nm}_{i}")
    ret = ", ".join(vals) + ("," if len(vals) == 1 else "")
    # numba's inliner refuses a call of 31 or more arguments (CPython passes them as one tuple, "calling a
    # closure with *args is unsupported", and the whole kernel fails to load): larger systems (a rolling
    # body: 25 states and 18 parameters) keep the plain call
    inline = inline and len(params) <= MAX_INLINE_ARGS
    deco = NJIT.rstrip("\n")[:-1] + ", inline='always')" if inline else NJIT.rstrip("\n")
    lines = [deco, f"def {name}({', '.join(params)}):"] + body + [f"    return ({ret})"]
    if wrapper is not None:
        fname, args = wrapper
        call = ", ".join(f"{a}[{i}]" for a, (_, size) in zip(args, inputs) for i in range(size))
        lines += ["", "", NJIT.rstrip("\n"), f"def {fname}({', '.join(args)}):", f"    r = {name}({call})"]
        lines += [f"    {args[-1]}[{j}] = r[{j}]" for j in range(len(outputs))]
        if not outputs:
            lines.append("    return")
    return "\n".join(lines) + "\n"


_HEADER = '''\
# Generated by liefi.engine -- do not edit.  The hash of this text names this file.
import math
import numpy as np
{imports}
CACHE = {cache}
'''
# liefi's njit: numba's, with its on-disk cache signed and kept in the private kernel directory;
# the loops set flush-to-zero around their work (fpu)
_NUMBA_IMPORTS = (f"from numba import prange\nfrom {__package__}.numba_cache import njit\n"
                  f"from {__package__}.fpu import fpu_enter, fpu_exit\n")
_PYTHON_IMPORTS = '''\
def njit(*args, **kwargs):
    if args and callable(args[0]):
        return args[0]
    return lambda f: f
prange = range
def fpu_enter():
    return 0
def fpu_exit(state):
    return None
'''

#: the loops' arguments (one trajectory)
_LOOP_ARGS = "y0, p, dt, n_steps, save_every, check_every, out, bad, last, pp, maxit, tol"


def _flushing(fname, args, inner):
    """Source of ``fname(args)``: ``inner(args)`` with subnormals flushed to zero on the calling
    thread for its duration, the caller's floating-point state restored after (:mod:`liefi.engine.fpu`)."""
    return "\n".join([
        "@njit(cache=CACHE, error_model='numpy')",
        f"def {fname}({args}):",
        "    csr = fpu_enter()",
        f"    r = {inner}({args})",
        "    fpu_exit(csr)",
        "    return r",
        "",
    ])


def _step_source(scheme, N, rhs="rhs"):
    """Body lines (indent 8) of one explicit RK step ``y -> y`` with buffers ``k0..``, ``yi``.

    Same arithmetic order as :meth:`liefi.schemes.ExplicitRungeKutta.step`:
    ``y_i = ((y + (dt a_i0) k_0) + (dt a_i1) k_1) + ...`` skipping zero
    coefficients, and likewise for the update with ``b``.
    """
    L = []
    for i in range(scheme.stages):
        coeffs = [(j, a) for j, a in enumerate(scheme.A[i][:i]) if a]
        if not coeffs:
            L.append(f"        {rhs}(y, p, k{i})")
            continue
        terms = " + ".join(f"c{i}_{j} * k{j}[i]" for j, _ in coeffs)
        L.append(f"        for i in range({N}):")
        L.append(f"            yi[i] = y[i] + {terms}")
        L.append(f"        {rhs}(yi, p, k{i})")
    L.append(f"        for i in range({N}):")
    L.append("            y[i] = y[i] + " + _update_terms(scheme, lambda j: f"k{j}[i]"))
    return L


def _b_groups(scheme):
    """The nonzero weights ``b_j`` grouped by value, in order of first appearance: ``[(b, [j, ...]), ...]``."""
    groups = {}
    for j, b in enumerate(scheme.b):
        if b:
            groups.setdefault(float(b), []).append(j)
    return list(groups.items())


def _update_terms(scheme, k):
    """``cb0 * (k0 + k3) + cb1 * (k1 + k2)``: the update ``dt sum_j b_j k_j`` with equal weights summed
    before their one multiplication (RK4: 2 products per component instead of 4)."""
    out = []
    for _, js in _b_groups(scheme):
        ks = " + ".join(k(j) for j in js)
        out.append(f"cb{js[0]} * " + (f"({ks})" if len(js) > 1 else ks))
    return " + ".join(out)


def _coeff_source(scheme):
    L = []
    for i in range(scheme.stages):
        for j, a in enumerate(scheme.A[i][:i]):
            if a:
                L.append(f"    c{i}_{j} = dt * {a!r}")
    for b, js in _b_groups(scheme):
        L.append(f"    cb{js[0]} = dt * {b!r}")
    return L


def _scalar_step_source(scheme, N, P, split):
    """Body lines (indent 8) of one step on the scalars ``y_0..`` (:func:`scalar_loop_source`).

    The arithmetic of :func:`_step_source`, term for term: ``yi_i = y_i + c1_0 * k0_i + ...``,
    ``z_i = y_i + cb0 * (k0_i + k3_i) + ...`` (:func:`_update_terms`); a split scheme then
    ``z = fstep_s(z, p, dt)``.  The new state is ``z``; the loop checks it and copies it to ``y``.
    """
    ys, ps = ", ".join(scalar_names("y", N)), ", ".join(scalar_names("p", P))
    rhs = "xrhs_s" if split else "rhs_s"
    pa = f", {ps}" if P else ""
    L = []
    for i in range(scheme.stages):
        coeffs = [(j, a) for j, a in enumerate(scheme.A[i][:i]) if a]
        ks = ", ".join(scalar_names(f"k{i}", N))
        if not coeffs:
            L.append(f"        {ks}{',' if N == 1 else ''} = {rhs}({ys}{pa})")
            continue
        for n in range(N):
            L.append(f"        yi_{n} = y_{n} + " + " + ".join(f"c{i}_{j} * k{j}_{n}" for j, _ in coeffs))
        L.append(f"        {ks}{',' if N == 1 else ''} = {rhs}({', '.join(scalar_names('yi', N))}{pa})")
    for n in range(N):
        L.append(f"        z_{n} = y_{n} + " + _update_terms(scheme, lambda j: f"k{j}_{n}"))
    if split:
        zs = ", ".join(scalar_names("z", N))
        L.append(f"        {zs}{',' if N == 1 else ''} = fstep_s({zs}{pa}, dt)")
    return L


def scalar_loop_source(fname, scheme, N, P, *, split=False):
    """The loop of :func:`loop_source` (same signature, same results, the same flush-to-zero wrapper) on local variables.

    The state ``y_0..``, the stages ``k0_0..`` and the parameters ``p_0..`` (read
    once, before the loop) are scalars, and the fields are called in their scalar
    form (``rhs_s``, ``xrhs_s``, ``fstep_s`` of :func:`scalar_function_source`), so
    that the compiled loop keeps them in registers: no array is written per
    stage.  The checks and the saves count down instead of taking ``step % k``
    (an integer division per step).  A step computes the new state ``z_0..`` and
    checks it before it replaces ``y``: with a check every step the last finite
    state is still in ``y`` when a check fails, so nothing is stored per step
    (``last`` is written at a failure and at the end; with ``check_every > 1``, at
    every check, as the array loop does).
    """
    L = ["@njit(cache=CACHE, error_model='numpy')", f"def {fname}_loop({_LOOP_ARGS}):"]
    L += [f"    y_{i} = y0[{i}]" for i in range(N)]
    L += [f"    p_{i} = p[{i}]" for i in range(P)]
    L += _coeff_source(scheme)
    L += [f"    out[{i}, 0] = y_{i}" for i in range(N)]
    L += [f"    last[{i}] = y_{i}" for i in range(N)]
    L += ["    j = 1", "    last_step = 0", "    to_check = check_every", "    to_save = save_every",
          "    for step in range(1, n_steps + 1):"]
    L += _scalar_step_source(scheme, N, P, split)
    L += ["        to_check -= 1",
          "        if to_check == 0 or step == n_steps:",
          "            to_check = check_every",
          "            s = " + " + ".join(scalar_names("z", N)),
          "            if not (s - s == 0.0):"]
    L += [f"                bad[{i}] = z_{i}" for i in range(N)]
    L += ["                if last_step == step - 1:"]  # the last good state is the one this step started from
    L += [f"                    last[{i}] = y_{i}" for i in range(N)]
    L += ["                return step, last_step, 0",
          "            if check_every > 1:"]  # else the next check is next step's: y holds the state then
    L += [f"                last[{i}] = z_{i}" for i in range(N)]
    L += ["            last_step = step"]
    L += [f"        y_{i} = z_{i}" for i in range(N)]
    L += ["        to_save -= 1",
          "        if to_save == 0 or step == n_steps:",
          "            to_save = save_every"]
    L += [f"            out[{i}, j] = y_{i}" for i in range(N)]
    L += ["            j += 1"]
    L += [f"    last[{i}] = y_{i}" for i in range(N)]
    L += ["    return 0, last_step, 0", "", "", _flushing(fname, _LOOP_ARGS, f"{fname}_loop")]
    return "\n".join(L) + "\n" + _batch_source(fname)


def _batch_source(fname):
    return "\n".join([
        "",
        "@njit(parallel=True, cache=CACHE, error_model='numpy')",
        f"def {fname}_batch(Y0, P, dt, n_steps, save_every, check_every, OUT, BAD, LAST, PP, maxit, tol, STATUS):",
        "    for b in prange(Y0.shape[0]):",
        f"        r = {fname}(Y0[b], P[b], dt, n_steps, save_every, check_every, OUT[b], BAD[b], LAST[b], PP[b], maxit, tol)",
        "        STATUS[b, 0] = r[0]",
        "        STATUS[b, 1] = r[1]",
        "        STATUS[b, 2] = r[2]",
        "",
    ]) + "\n"


def loop_source(fname, scheme, N, *, project=False, split=False):
    """Source of the fixed-step loop of one trajectory (and its batch version ``fname + '_batch'``).

    ``scheme`` is an explicit tableau.  With ``split`` it steps ``xrhs`` (the
    extended field ``X``) and follows every step by the feedback substep
    ``fstep(y, p, hh, out)`` of a split scheme (:mod:`liefi.schemes.split`).

    ``fname(y0, p, dt, n_steps, save_every, check_every, out, bad, last, pp, maxit, tol)``
    returns ``(failed_step, last_good_step, projection_evaluations)``; ``failed_step == 0``
    means success.  ``out`` ``(N, n_saved)`` receives the saved states,
    ``bad``/``last`` the first non-finite state and the last finite one.  With
    ``project`` every step is followed by the Newton projection ``project(y, pp, ...)``.
    ``fname`` runs the loop ``fname + '_loop'`` with subnormals flushed to zero
    (:mod:`liefi.engine.fpu`), on the thread that runs it, and restores the
    caller's floating-point state after it.
    """
    S = scheme.stages
    L = ["@njit(cache=CACHE, error_model='numpy')", f"def {fname}_loop({_LOOP_ARGS}):"]
    L.append("    y = y0.copy()")
    for i in range(S):
        L.append(f"    k{i} = np.empty({N})")
    L += ["    yi = np.empty(%d)" % N]
    if split:
        L += ["    hh = np.empty(1)", "    hh[0] = dt"]
    if project:
        L += ["    buf = np.empty(PROJ_SIZE)", "    GG = np.empty((PROJ_M, PROJ_M))", "    lam = np.empty(PROJ_M)"]
    L += _coeff_source(scheme)
    L += [
        f"    for i in range({N}):",
        "        out[i, 0] = y[i]",
        "        last[i] = y[i]",
        "    j = 1",
        "    last_step = 0",
        "    nproj = 0",
        "    for step in range(1, n_steps + 1):",
    ]
    L += _step_source(scheme, N, rhs="xrhs" if split else "rhs")
    if split:
        L += ["        fstep(y, p, hh, yi)", f"        for i in range({N}):", "            y[i] = yi[i]"]
    if project:
        L.append("        nproj += project(y, pp, buf, GG, lam, maxit, tol)")
    L += [
        "        if step % check_every == 0 or step == n_steps:",
        "            s = 0.0",
        f"            for i in range({N}):",
        "                s += y[i]",
        "            if not (s - s == 0.0):",
        f"                for i in range({N}):",
        "                    bad[i] = y[i]",
        "                return step, last_step, nproj",
        f"            for i in range({N}):",
        "                last[i] = y[i]",
        "            last_step = step",
        "        if step % save_every == 0 or step == n_steps:",
        f"            for i in range({N}):",
        "                out[i, j] = y[i]",
        "            j += 1",
        "    return 0, last_step, nproj",
        "",
        "",
        _flushing(fname, _LOOP_ARGS, f"{fname}_loop"),
    ]
    return "\n".join(L) + "\n" + _batch_source(fname)


_PROJECT_SOURCE = '''
@njit(cache=CACHE, error_model='numpy')
def project(y, pp, buf, GG, lam, maxit, tol):
    """Newton projection onto resid(y) = 0 along G^T (G G^T)^{{-1}}: returns evaluations used.
    tol < 0: exactly maxit Newton steps, no convergence check."""
    M = PROJ_M
    N = {N}
    nev = 0
    for it in range(maxit + 1):
        if tol < 0.0 and it == maxit:
            break
        resid(y, pp, buf)
        nev += 1
        rmax = 0.0
        for a in range(M):
            rmax = max(rmax, abs(buf[a]))
        if rmax <= tol or it == maxit:
            break
        for a in range(M):
            for c in range(a + 1):
                s = 0.0
                for i in range(N):
                    s += buf[M + a * N + i] * buf[M + c * N + i]
                GG[a, c] = s
        # Cholesky G G^T = L L^T in the lower triangle, then two triangular solves
        for a in range(M):
            for c in range(a + 1):
                s = GG[a, c]
                for k in range(c):
                    s -= GG[a, k] * GG[c, k]
                if a == c:
                    GG[a, a] = math.sqrt(s) if s > 0.0 else 1e-300
                else:
                    GG[a, c] = s / GG[c, c]
        for a in range(M):
            s = buf[a]
            for k in range(a):
                s -= GG[a, k] * lam[k]
            lam[a] = s / GG[a, a]
        for a in range(M - 1, -1, -1):
            s = lam[a]
            for k in range(a + 1, M):
                s -= GG[k, a] * lam[k]
            lam[a] = s / GG[a, a]
        for i in range(N):
            s = 0.0
            for a in range(M):
                s += buf[M + a * N + i] * lam[a]
            y[i] -= s
    return nev
'''

_DLA_LOOP = '''
@njit(cache=CACHE, error_model='numpy')
def dla_run_loop(q0, q1, p, n_steps, save_every, out, bad):
    """q_0 .. q_N of the DLA scheme; out[:, j] holds q at saved index j, out[:, j + n_saved] the
    previous point (for the discrete momentum).  Returns the failing update index (0: success)."""
    n = {n}
    ns = out.shape[1] // 2
    qp = q0.copy()
    qc = q1.copy()
    qn = np.empty(n)
    j = 0
    for k in range(0, n_steps + 1):
        if k >= 2:
            dla_update(qp, qc, p, qn)
            s = 0.0
            for i in range(n):
                s += qn[i]
            if not (s - s == 0.0):
                for i in range(n):
                    bad[i] = qn[i]
                return k - 1
            for i in range(n):
                qp[i] = qc[i]
                qc[i] = qn[i]
        if k % save_every == 0 or k == n_steps:
            for i in range(n):
                out[i, j] = qp[i] if k == 0 else qc[i]
                out[i, j + ns] = qp[i]
            j += 1
    return 0
'''


#: the decorator line of a generated function
NJIT = "@njit(cache=CACHE, error_model='numpy')\n"


def module_text(source, engine, cache):
    """The full text of a generated module: header (imports, ``CACHE``) then ``source``."""
    imports = _NUMBA_IMPORTS if engine == "numba" else _PYTHON_IMPORTS
    return _HEADER.format(imports=imports, cache=bool(cache)) + source


def loops_source(N, *, projection=False, n_params=None):
    """The loops of every explicit scheme of :mod:`liefi.schemes` (with the projected ones).

    With ``n_params`` (the size of ``p``) the plain loops are those of
    :func:`scalar_loop_source` (they call ``rhs_s``); without, of :func:`loop_source`
    (they call ``rhs``).  The projected loops are :func:`loop_source`'s.
    """
    from ..schemes import SCHEMES

    src = []
    for sch in SCHEMES.values():
        if n_params is None:
            src.append(loop_source(f"run_{sch.name}", sch, N))
        else:
            src.append(scalar_loop_source(f"run_{sch.name}", sch, N, n_params))
        if projection:
            src.append(loop_source(f"run_{sch.name}_proj", sch, N, project=True))
    return "\n".join(src)


def split_loops_source(N, n_params):
    """The loops of the split schemes of :mod:`liefi.schemes.split` (``run_imex_euler``, ...), on
    ``xrhs_s`` and ``fstep_s`` (:func:`scalar_loop_source`)."""
    from ..schemes.split import SPLIT_SCHEMES

    return "\n".join(scalar_loop_source(split_loop_name(s), s.explicit, N, n_params, split=True)
                     for s in SPLIT_SCHEMES.values())


def split_loop_name(scheme):
    """The generated loop's name of a split scheme: ``imex-rk4`` -> ``run_imex_rk4``."""
    return "run_" + scheme.name.replace("-", "_")


def project_source(N, m):
    """The Newton projection onto ``m`` residuals ``resid(y, pp, out)`` of a state of size ``N``."""
    return f"\n\nPROJ_M = {m}\nPROJ_SIZE = {m * (N + 1)}\n" + _PROJECT_SOURCE.format(N=N)


def dla_loop_source(n):
    """The DLA loop around ``dla_update(qp, qc, p, out)`` for ``q`` of size ``n``."""
    return _DLA_LOOP.format(n=n) + "\n\n" + _flushing("dla_run", "q0, q1, p, n_steps, save_every, out, bad", "dla_run_loop")
