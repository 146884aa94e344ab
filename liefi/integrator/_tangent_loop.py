r"""The fused compiled loop of forward sensitivities: one step advances the state and its ``k`` tangents.

:func:`fused_source` prints ``tangent_fused(y0, S0, p, c, PC, dt, n_steps, saved, Y, St)`` for a
fixed scheme, in the style of the plain run's scalar loop (:func:`liefi.engine.codegen.scalar_loop_source`):
the state ``y_r``, the stages ``k<i>_r`` and the parameters are local scalars, and the field and the
feedback step are written out inline, node by node, with their tangents (forward mode on the traced
graph, :func:`jvp_graph`).  The number of directions ``K`` is read at run time, so one kernel per system
and scheme serves every ``k``: one direction runs as scalars (no array inside a step), more as lanes,
each graph's tangent nodes one loop over the directions that the compiler vectorizes (four lanes per
instruction).  No function is called inside a step: a direction costs the tangent nodes of the step.

The arithmetic of the state is the plain loop's (``yi_r = y_r + c<i>_<l> k<l>_r ...``, the update by
:func:`~liefi.engine.codegen._update_terms`), and that of the tangent is its derivative term for term:
``si_r = S[r, j] + c<i>_<l> kS[l, r, j] ...``.

**Activity.**  Only the inputs that can move carry a direction (``active`` of :func:`jvp_graph`): the
state always, the parameters whose tangent is not structurally zero (the invariants' targets that follow
the start, not the gains, which are held), the system's constants.  A node that depends on no moving input
is primal, computed once per step, and the derivative of a product with a primal factor is one
multiplication, not three (the graph's constant folding: ``d(c a) = c da``).
"""

from __future__ import annotations

from ..engine.codegen import _coeff_source, _literal, _update_terms, node_expression, node_lines, reachable
from ..engine.symbolic import _d_unary, add, as_sym, const, derivative, div, mul, power, sub, unary

#: the most directions one pass of the fused loop carries (the columns of its lanes); more are stepped in
#: blocks of this many, the same kernel again
K_MAX = 16

#: the lanes of one vector instruction (AVX2: four doubles); the lanes' loop runs a multiple of this many
VECTOR = 4


def jvp_graph(f, inputs, directions, active=None):
    """``(f, T)``: the outputs ``f`` (Syms) and their derivatives ``T`` along the symbols ``directions``
    (``directions[q]`` the tangent of ``inputs[q]``), by forward differentiation of the graph.

    ``active``: the indices ``q`` of the inputs that move (default all); the others' tangents are zero,
    so the derivative work of the nodes that depend on them alone is never built.
    """
    f = [as_sym(o) for o in f]
    moving = range(len(inputs)) if active is None else set(active)
    memo = {x.id: directions[q] if q in moving else const(0.0) for q, x in enumerate(inputs)}
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


def _emit_lanes(f, T, var, direction, prefix, indent, inputs, store, loop):
    """Lines computing the primal outputs ``f`` once, then one loop over the ``K`` directions (lanes)
    computing every tangent node of ``T`` as a scalar of the lane ``j``; and the primal outputs' names.

    ``var(name, i)`` prints an input of the graph, ``direction(i)`` the tangent of the input that the
    direction symbol ``d[i]`` seeds, at lane ``j``; ``inputs(used)`` gives the loop's first lines (the
    lane's inputs, ``used`` the indices ``i`` the graph reads); ``store(r, value)`` the line storing the
    tangent of output ``r``; ``loop`` the loop's header (``None``: one direction, as scalars, no loop).
    A node that depends on no direction is primal (printed once, before the loop); within the loop,
    every store comes after every read of the lane's inputs.
    """
    ref, lane, head, tail, used = {}, {}, [], [], set()
    nodes = reachable(f + T)
    for node in nodes:
        if node.op == "var":
            if node.args[0] == "d":
                lane[node.id] = direction(node.args[1])
                used.add(node.args[1])
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
    lane_lines = inputs(sorted(used)) + [f"{lane[node.id]} = {node_expression(node, both)}" for node in tail]
    lane_lines += [store(r, _literal(o.value) if o.op == "const" else both[o.id]) for r, o in enumerate(T)]
    outs = [_literal(o.value) if o.op == "const" else ref[o.id] for o in f]
    if loop is None:
        return list(head) + [f"{indent}{x}" for x in lane_lines], outs
    return list(head) + [f"{indent}{loop}"] + [f"{indent}    {x}" for x in lane_lines], outs


def _step_lines(field, feedback, tab, n, split, S, kS, loop, ind):
    """Lines of one step (indent ``ind``): the state's scalars and the tangents, ``S(r)`` and ``kS(i, r)``
    printing a tangent of the state and of stage ``i`` at the lane ``j`` (:func:`_emit_lanes`, ``loop``)."""
    body = []

    def lane_inputs(name, assemble):
        return lambda used: [f"{name}_{i} = {assemble(i)}" for i in used if i < n]

    def direction(name):
        return lambda i: f"{name}_{i}" if i < n else S(i)

    def update(r):
        return f"{S(r)} + " + _update_terms(tab, lambda l: kS(l, r))

    for i in range(tab.stages):
        coeffs = [l for l, a in enumerate(tab.A[i][:i]) if a]
        ys = "yi" if coeffs else "y"
        for r in range(n) if coeffs else ():
            body.append(f"{ind}yi_{r} = y_{r} + " + " + ".join(f"c{i}_{l} * k{l}_{r}" for l in coeffs))

        def stage_in(r, i=i, coeffs=coeffs):
            return " + ".join([S(r)] + [f"c{i}_{l} * {kS(l, r)}" for l in coeffs])

        def var(nm, idx, ys=ys):
            return f"{ys}_{idx}" if nm == "y" else f"{nm}_{idx}"

        lines, outs = _emit_lanes(*field, var, direction("si"), "f", ind, lane_inputs("si", stage_in),
                                  lambda r, v, i=i: f"{kS(i, r)} = {v}", loop)
        body += lines
        body += [f"{ind}k{i}_{r} = {outs[r]}" for r in range(n)]
    body += [f"{ind}z_{r} = y_{r} + " + _update_terms(tab, lambda l: f"k{l}_{r}") for r in range(n)]
    if split:
        def gvar(nm, idx):
            return f"z_{idx}" if nm == "y" else ("dt" if nm == "hh" else f"{nm}_{idx}")

        lines, outs = _emit_lanes(*feedback, gvar, direction("sz"), "g", ind, lane_inputs("sz", update),
                                  lambda r, v: f"{S(r)} = {v}", loop)
        body += lines
        body += [f"{ind}y_{r} = {outs[r]}" for r in range(n)]
    else:
        body += [f"{ind}y_{r} = z_{r}" for r in range(n)]
        lanes = [f"{S(r)} = {update(r)}" for r in range(n)]
        body += [f"{ind}{x}" for x in lanes] if loop is None else [f"{ind}{loop}"] + [f"{ind}    {x}" for x in lanes]
    return body


def fused_source(field, feedback, tab, n, size, P, *, split):
    """Source of ``tangent_fused(y0, S0, p, c, PC, dt, n_steps, saved, Y, St) -> number saved``.

    ``field = (f, T)`` of the field in the inputs ``y, p, c`` (:func:`jvp_graph`); ``feedback``
    likewise for the split schemes' feedback step (inputs ``y, p, c, hh``; ``None`` otherwise);
    ``tab`` the explicit tableau; ``n`` states, ``size`` parameters, ``P`` constants.  The number of
    directions ``K`` is a run-time size, ``S0.shape[1]`` (at most :data:`K_MAX`): one kernel serves
    every ``k``.  ``S0`` is ``(n, K)``, ``PC`` ``(size + P, K)`` the tangents of ``(p, c)``; the state
    after the steps of ``saved`` (increasing, from 1) goes to ``Y[:, i]``, its tangents to ``St[:, :, i]``.

    The state, the stages and the parameters are scalars, the field and the feedback step written out
    node by node, once per step, and the same step (:func:`_step_lines`) is printed in two renderings:

    * ``K = 1``: the tangent's nodes are scalars too, ``S_r``, ``kS<i>_r``, ``w_q`` (no array is read
      or written in a step but the saves);
    * ``K > 1``: the tangents are lanes, rows of one array ``B`` of :data:`K_MAX` columns: the state's
      ``S`` (rows ``0..n-1``), the tangents ``PC`` (rows ``n..n+size+P-1``) and the stages' ``kS``
      (row ``n+size+P + i n + r``).  Each graph's tangent nodes are one loop over the lanes, its trip
      count ``K`` rounded up to a multiple of :data:`VECTOR` (the padding lanes are zero directions,
      never saved).  The loop body is straight-line arithmetic on rows of one array a constant
      multiple of :data:`K_MAX` apart: the compiler proves the lanes independent without run-time
      alias checks and vectorizes across them (``VECTOR`` lanes per instruction).

    In both, a stage's tangent inputs ``si_r = S[r, j] + c<i>_<l> kS[l, r, j] ...`` are term for term
    the derivative of the state's ``yi_r = y_r + c<i>_<l> k<l>_r ...``.
    """
    I1, I2, I3 = "    ", "        ", "            "
    m = size + P
    kr = n + m  # the first row of the stages' tangents in B
    L = ["@njit(cache=CACHE, error_model='numpy')",
         "def tangent_fused(y0, S0, p, c, PC, dt, n_steps, saved, Y, St):",
         f"{I1}K = S0.shape[1]"]
    L += [f"{I1}y_{r} = y0[{r}]" for r in range(n)]
    L += [f"{I1}p_{q} = p[{q}]" for q in range(size)]
    L += [f"{I1}c_{q} = c[{q}]" for q in range(P)]
    L += _coeff_source(tab)
    L += [f"{I1}ns = saved.size", f"{I1}js = 0", f"{I1}if K == 1:"]
    L += [f"{I2}S_{r} = S0[{r}, 0]" for r in range(n)] + [f"{I2}w_{q} = PC[{q}, 0]" for q in range(m)]
    L += [f"{I2}for step in range(1, n_steps + 1):"]
    L += _step_lines(field, feedback, tab, n, split, lambda r: f"S_{r}" if r < n else f"w_{r - n}",
                     lambda i, r: f"kS{i}_{r}", None, I3)
    L += [f"{I3}if js < ns and saved[js] == step:"]
    L += [f"{I3}    Y[{r}, js] = y_{r}" for r in range(n)] + [f"{I3}    St[{r}, 0, js] = S_{r}" for r in range(n)]
    L += [f"{I3}    js += 1", f"{I2}return js"]
    L += [f"{I1}KV = (K + {VECTOR - 1}) // {VECTOR} * {VECTOR}",
          f"{I1}B = np.zeros(({kr + tab.stages * n}, {K_MAX}))", f"{I1}B[:{n}, :K] = S0", f"{I1}B[{n}:{kr}, :K] = PC"]
    L += [f"{I1}for step in range(1, n_steps + 1):"]
    L += _step_lines(field, feedback, tab, n, split, lambda r: f"B[{r}, j]", lambda i, r: f"B[{kr + i * n + r}, j]",
                     "for j in range(KV):", I2)
    L += [f"{I2}if js < ns and saved[js] == step:"]
    L += [f"{I2}    Y[{r}, js] = y_{r}" for r in range(n)]
    L += [f"{I2}    St[:, :, js] = B[:{n}, :K]", f"{I2}    js += 1", f"{I1}return js"]
    return "\n".join(L) + "\n"
