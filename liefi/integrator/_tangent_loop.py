r"""The fused compiled loop of forward sensitivities: one step advances the state and its ``k`` tangents.

:func:`fused_loop_source` prints ``tangent_fused(y0, S0, p, c, PC, dt, n_steps, saved, Y, St)`` for a
fixed scheme and a fixed number ``k`` of directions, in the style of the plain run's scalar loop
(:func:`liefi.engine.codegen.scalar_loop_source`): the state ``y_r``, the stages ``k<i>_r``, the
parameters and their tangents are local scalars, and the field and the feedback step are written out
inline, node by node, with the tangent of every node along each direction ``j`` printed next to it
(forward mode on the traced graph, :func:`jvp_graph`).  No array is read or written inside a step but
the saves, and no function is called: a direction costs the tangent nodes of the step and nothing else
(about twice the primal nodes: ``d(a b) = da b + a db``).  From :data:`LANES_FROM` directions on,
:func:`fused_lanes_source` keeps the code size independent of ``k``: the tangents are rows of small
arrays and each graph's tangent nodes are one loop over the directions.

The arithmetic of the state is the plain loop's (``yi_r = y_r + c<i>_<l> k<l>_r ...``, the update by
:func:`~liefi.engine.codegen._update_terms`), and that of the tangent is its derivative term for term:
``Si_r = S_r + c<i>_<l> kS<l>_r ...``.
"""

from __future__ import annotations

from ..engine.codegen import _coeff_source, _literal, _update_terms, node_expression, node_lines, reachable
from ..engine.symbolic import _d_unary, add, as_sym, const, derivative, div, mul, power, sub, unary

#: the most directions one fused kernel carries; more are stepped in blocks of this many
K_MAX = 16

#: from this many directions on, the fused loop carries them as lanes (:func:`fused_lanes_source`)
LANES_FROM = 8

#: the most tangent nodes (summed over the directions) printed one copy per direction; a larger step
#: (a rolling body's) carries its directions as lanes from two on, so that its code stays compilable
UNROLLED_NODES_MAX = 4000


def as_lanes(k, field, feedback):
    """Whether the fused loop of ``k`` directions carries them as lanes: from :data:`LANES_FROM` on, or
    when ``k`` copies of the tangent code (the field's once per stage counted once) exceed
    :data:`UNROLLED_NODES_MAX` nodes."""
    if k >= LANES_FROM:
        return True
    nodes = sum(len(reachable(T)) for _, T in [field] + ([feedback] if feedback is not None else []))
    return k > 1 and k * nodes > UNROLLED_NODES_MAX


def jvp_graph(f, inputs, directions):
    """``(f, T)``: the outputs ``f`` (Syms) and their derivatives ``T`` along the symbols ``directions``
    (``directions[q]`` the tangent of ``inputs[q]``), by forward differentiation of the graph."""
    f = [as_sym(o) for o in f]
    memo = {x.id: directions[q] for q, x in enumerate(inputs)}
    return f, [derivative(e, None, memo) for e in f]


def _partials(node):
    """``[(argument, d node / d argument), ...]`` of an operation node (traced)."""
    op, a = node.op, node.args
    if op == "add":
        return [(a[0], const(1.0)), (a[1], const(1.0))]
    if op == "sub":
        return [(a[0], const(1.0)), (a[1], const(-1.0))]
    if op == "mul":
        return [(a[0], a[1]), (a[1], a[0])]
    if op == "div":
        return [(a[0], div(1.0, a[1])), (a[1], unary("neg", div(node, a[1])))]
    if op == "pow":
        out = [(a[0], mul(a[1], power(a[0], sub(a[1], 1.0))))]
        return out if a[1].op == "const" else out + [(a[1], mul(node, unary("log", a[0])))]
    return [(a[0], _d_unary(op, a[0], const(1.0), node))]


def vjp_graph(f, inputs, cotangents):
    r"""The vector--Jacobian product ``sum_i cot_i d f_i / d inputs`` (Syms, one per input) by reverse
    accumulation over the graph: the nodes in reverse creation order, each node's adjoint the sum over
    its users of ``d user / d node`` times the user's adjoint."""
    f = [as_sym(o) for o in f]
    adj = {}
    for o, c in zip(f, cotangents):
        if o.op != "const":
            adj[o.id] = add(adj[o.id], c) if o.id in adj else c
    for node in reversed(reachable(f)):
        if node.op == "var" or node.id not in adj:
            continue
        for arg, d in _partials(node):
            if arg.op == "const":
                continue
            term = mul(d, adj[node.id])
            adj[arg.id] = add(adj[arg.id], term) if arg.id in adj else term
    return [adj.get(x.id, const(0.0)) for x in inputs]


def emit_plain(outputs, var, prefix, indent, ref=None):
    """Lines computing ``outputs`` (every reachable node once, ``<prefix>_t<id>``) and their names;
    ``var(name, i)`` prints an input.  ``ref`` (node id -> name; updated): nodes already computed."""
    return node_lines(outputs, var, indent, prefix, ref)


def _emit(f, T, var, direction, prefix, k, indent):
    """Lines computing ``f`` and, for each of the ``k`` directions, ``T``; and the names of the results.

    ``var(name, i)`` prints an input of the graph, ``direction(i, j)`` the ``j``-th tangent of the
    input the direction symbol ``d[i]`` seeds.  The primal nodes are printed once, the nodes that
    depend on a direction once per direction (``<prefix>_<j>_t<id>``).
    """
    ref, moving, head, tail = {}, set(), [], []
    nodes = reachable(f + T)
    for node in nodes:
        if node.op == "var":
            if node.args[0] == "d":
                moving.add(node.id)
            else:
                ref[node.id] = var(*node.args)
            continue
        if any(a.id in moving for a in node.args):
            moving.add(node.id)
            tail.append(node)
        else:
            head.append(f"{indent}{prefix}_t{node.id} = {node_expression(node, ref)}")
            ref[node.id] = f"{prefix}_t{node.id}"

    def val(o, r):
        return _literal(o.value) if o.op == "const" else r[o.id]

    lines, outs, touts = list(head), [val(o, ref) for o in f], []
    for j in range(k):
        rj = dict(ref)
        for node in nodes:
            if node.op == "var" and node.id in moving:
                rj[node.id] = direction(node.args[1], j)
        for node in tail:
            lines.append(f"{indent}{prefix}_{j}_t{node.id} = {node_expression(node, rj)}")
            rj[node.id] = f"{prefix}_{j}_t{node.id}"
        touts.append([val(o, rj) for o in T])
    return lines, outs, touts


def fused_loop_source(field, feedback, tab, n, size, P, k, *, split):
    """Source of ``tangent_fused(y0, S0, p, c, PC, dt, n_steps, saved, Y, St) -> number saved``.

    ``field = (f, T)`` of the field in the inputs ``y, p, c`` (:func:`jvp_graph`); ``feedback``
    likewise for the split schemes' feedback step (inputs ``y, p, c, hh``; ``None`` otherwise);
    ``tab`` the explicit tableau; ``n`` states, ``size`` parameters, ``P`` constants, ``k`` directions.
    ``S0`` is ``(n, k)``, ``PC`` ``(size + P, k)`` the tangents of ``(p, c)``; the state after the
    steps of ``saved`` (increasing, from 1) goes to ``Y[:, i]``, its tangents to ``St[:, :, i]``.
    """
    I1, I2 = "    ", "        "
    L = ["@njit(cache=CACHE, error_model='numpy')",
         "def tangent_fused(y0, S0, p, c, PC, dt, n_steps, saved, Y, St):"]
    L += [f"{I1}y_{r} = y0[{r}]" for r in range(n)]
    L += [f"{I1}S_{r}_{j} = S0[{r}, {j}]" for r in range(n) for j in range(k)]
    L += [f"{I1}p_{q} = p[{q}]" for q in range(size)]
    L += [f"{I1}c_{q} = c[{q}]" for q in range(P)]
    L += [f"{I1}w_{q}_{j} = PC[{q}, {j}]" for q in range(size + P) for j in range(k)]
    L += _coeff_source(tab)
    L += [f"{I1}ns = saved.size", f"{I1}js = 0", f"{I1}for step in range(1, n_steps + 1):"]

    def const_in(nm, i):
        return f"{nm}_{i}"

    def tangent_in(stage_y, stage_S):
        def direction(i, j):
            if i < n:
                return f"{stage_S}_{i}_{j}"
            return f"w_{i - n}_{j}"
        return direction

    for i in range(tab.stages):
        coeffs = [(l, a) for l, a in enumerate(tab.A[i][:i]) if a]
        ys, Ss = "y", "S"
        if coeffs:
            ys, Ss = "yi", "Si"
            for r in range(n):
                L.append(f"{I2}yi_{r} = y_{r} + " + " + ".join(f"c{i}_{l} * k{l}_{r}" for l, _ in coeffs))
                for j in range(k):
                    L.append(f"{I2}Si_{r}_{j} = S_{r}_{j} + "
                             + " + ".join(f"c{i}_{l} * kS{l}_{r}_{j}" for l, _ in coeffs))

        def var(nm, idx, ys=ys):
            return f"{ys}_{idx}" if nm == "y" else const_in(nm, idx)

        lines, outs, touts = _emit(*field, var, tangent_in(ys, Ss), f"f{i}", k, I2)
        L += lines
        L += [f"{I2}k{i}_{r} = {outs[r]}" for r in range(n)]
        L += [f"{I2}kS{i}_{r}_{j} = {touts[j][r]}" for j in range(k) for r in range(n)]
    for r in range(n):
        L.append(f"{I2}z_{r} = y_{r} + " + _update_terms(tab, lambda l: f"k{l}_{r}"))
        for j in range(k):
            L.append(f"{I2}Sz_{r}_{j} = S_{r}_{j} + " + _update_terms(tab, lambda l: f"kS{l}_{r}_{j}"))
    if split:
        def gvar(nm, idx):
            return f"z_{idx}" if nm == "y" else ("dt" if nm == "hh" else const_in(nm, idx))

        lines, outs, touts = _emit(*feedback, gvar, tangent_in("z", "Sz"), "g", k, I2)
        L += lines
        L += [f"{I2}y_{r} = {outs[r]}" for r in range(n)]
        L += [f"{I2}S_{r}_{j} = {touts[j][r]}" for j in range(k) for r in range(n)]
    else:
        L += [f"{I2}y_{r} = z_{r}" for r in range(n)]
        L += [f"{I2}S_{r}_{j} = Sz_{r}_{j}" for j in range(k) for r in range(n)]
    L += [f"{I2}if js < ns and saved[js] == step:"]
    L += [f"{I2}    Y[{r}, js] = y_{r}" for r in range(n)]
    L += [f"{I2}    St[{r}, {j}, js] = S_{r}_{j}" for r in range(n) for j in range(k)]
    L += [f"{I2}    js += 1"]
    L += [f"{I1}return js"]
    return "\n".join(L) + "\n"


def _emit_lanes(f, T, var, direction, prefix, K, indent, store):
    """:func:`_emit` with the directions as lanes: the primal nodes once, then one loop over the ``K``
    lanes (which the compiler may vectorize) computing every tangent node as a scalar of the lane ``j``;
    ``direction(i)`` prints the input row that ``d[i]`` seeds at lane ``j``, ``store(r)`` the row that
    receives the tangent of output ``r``.  Returns ``(lines, primal outputs, 0)``."""
    ref, lane, head, tail = {}, {}, [], []
    nodes = reachable(f + T)
    for node in nodes:
        if node.op == "var":
            if node.args[0] == "d":
                lane[node.id] = direction(node.args[1])
            else:
                ref[node.id] = var(*node.args)
            continue
        if any(a.id in lane for a in node.args):
            lane[node.id] = f"{prefix}_l{node.id}"
            tail.append(node)
        else:
            head.append(f"{indent}{prefix}_t{node.id} = {node_expression(node, ref)}")
            ref[node.id] = f"{prefix}_t{node.id}"
    both = dict(ref)
    both.update(lane)
    lines = list(head) + [f"{indent}for j in range({K}):"]
    for node in tail:
        lines.append(f"{indent}    {lane[node.id]} = {node_expression(node, both)}")
    for r, o in enumerate(T):
        lines.append(f"{indent}    {store(r)} = {_literal(o.value) if o.op == 'const' else both[o.id]}")
    outs = [_literal(o.value) if o.op == "const" else ref[o.id] for o in f]
    return lines, outs, 0


def fused_lanes_source(field, feedback, tab, n, size, P, K, *, split):
    """:func:`fused_loop_source` with the ``K`` directions as lanes of small arrays (:func:`_emit_lanes`):
    the state scalar, its tangents ``S[r, :]``, one vectorizable loop over the directions per node."""
    I1, I2 = "    ", "        "
    L = ["@njit(cache=CACHE, error_model='numpy')",
         "def tangent_fused(y0, S0, p, c, PC, dt, n_steps, saved, Y, St):"]
    L += [f"{I1}y_{r} = y0[{r}]" for r in range(n)]
    L += [f"{I1}p_{q} = p[{q}]" for q in range(size)]
    L += [f"{I1}c_{q} = c[{q}]" for q in range(P)]
    L += [f"{I1}S = np.empty(({n}, {K}))", f"{I1}S[:, :] = S0", f"{I1}W = np.empty(({size + P}, {K}))",
          f"{I1}W[:, :] = PC", f"{I1}Si = np.empty(({n}, {K}))", f"{I1}Sz = np.empty(({n}, {K}))",
          f"{I1}kS = np.empty(({tab.stages}, {n}, {K}))"]
    L += _coeff_source(tab)
    body = []

    def tangent_in(Sname):
        return lambda i: f"{Sname}[{i}, j]" if i < n else f"W[{i - n}, j]"

    nf = ng = 0
    for i in range(tab.stages):
        coeffs = [(l, a) for l, a in enumerate(tab.A[i][:i]) if a]
        ys, Ss = "y", "S"
        if coeffs:
            ys, Ss = "yi", "Si"
            for r in range(n):
                body.append(f"{I2}yi_{r} = y_{r} + " + " + ".join(f"c{i}_{l} * k{l}_{r}" for l, _ in coeffs))
                body.append(f"{I2}for j in range({K}):")
                body.append(f"{I2}    Si[{r}, j] = S[{r}, j] + "
                            + " + ".join(f"c{i}_{l} * kS[{l}, {r}, j]" for l, _ in coeffs))

        def var(nm, idx, ys=ys):
            return f"{ys}_{idx}" if nm == "y" else f"{nm}_{idx}"

        lines, outs, nf = _emit_lanes(*field, var, tangent_in(Ss), "f", K, I2, lambda r, i=i: f"kS[{i}, {r}, j]")
        body += lines
        body += [f"{I2}k{i}_{r} = {outs[r]}" for r in range(n)]
    for r in range(n):
        body.append(f"{I2}z_{r} = y_{r} + " + _update_terms(tab, lambda l: f"k{l}_{r}"))
        body.append(f"{I2}for j in range({K}):")
        body.append(f"{I2}    Sz[{r}, j] = S[{r}, j] + " + _update_terms(tab, lambda l: f"kS[{l}, {r}, j]"))
    if split:
        def gvar(nm, idx):
            return f"z_{idx}" if nm == "y" else ("dt" if nm == "hh" else f"{nm}_{idx}")

        lines, outs, ng = _emit_lanes(*feedback, gvar, tangent_in("Sz"), "g", K, I2, lambda r: f"S[{r}, j]")
        body += lines
        body += [f"{I2}y_{r} = {outs[r]}" for r in range(n)]
    else:
        body += [f"{I2}y_{r} = z_{r}" for r in range(n)]
        body += [f"{I2}S[:, :] = Sz"]
    L += [f"{I1}ns = saved.size", f"{I1}js = 0", f"{I1}for step in range(1, n_steps + 1):"] + body
    L += [f"{I2}if js < ns and saved[js] == step:"]
    L += [f"{I2}    Y[{r}, js] = y_{r}" for r in range(n)]
    L += [f"{I2}    St[:, :, js] = S", f"{I2}    js += 1", f"{I1}return js"]
    return "\n".join(L) + "\n"
