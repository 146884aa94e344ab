"""Operation counts of the adjoint's cost estimate (docs/gradients.md, "Reverse mode"): Suslov's traced field and
feedback step, their primal nodes, the forward tangent of one direction (JVP, the code the fused loop prints) and a
reverse-mode sweep (VJP: every node's adjoint accumulated from its users, built on the same trace).

Run from the repository root: ``python benchmarks/adjoint_estimate.py`` (plain Python, a few seconds).
The VJP here is only counted, not compiled: liefi has no adjoint yet.
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from liefi import scenes
from liefi.engine.trace import trace, TRACED_DATA, traced_call
from liefi.engine.codegen import reachable
from liefi.engine import symbolic as sy
from liefi.integrator._tangent_loop import jvp_graph
from liefi.schemes.split import feedback_step

def partials(node):
    """``[(argument, d node / d argument), ...]``."""
    op, a = node.op, node.args
    if op == "add": return [(a[0], sy.const(1.0)), (a[1], sy.const(1.0))]
    if op == "sub": return [(a[0], sy.const(1.0)), (a[1], sy.const(-1.0))]
    if op == "mul": return [(a[0], a[1]), (a[1], a[0])]
    if op == "div": return [(a[0], sy.div(1.0, a[1])), (a[1], sy.unary("neg", sy.div(node, a[1])))]
    if op == "pow":
        return [(a[0], sy.mul(a[1], sy.power(a[0], sy.sub(a[1], 1.0))))] + ([] if a[1].op == "const" else [(a[1], sy.mul(node, sy.unary("log", a[0])))])
    d = sy._d_unary(op, a[0], sy.const(1.0), node)
    return [(a[0], d)]

def vjp(outs, cot):
    """``{node id: adjoint}``: the cotangents ``cot`` of ``outs`` pulled back through the graph."""
    nodes = reachable(outs)
    adj = {}
    for o, c in zip(outs, cot):
        if o.op != "const":
            adj[o.id] = sy.add(adj.get(o.id, sy.const(0.0)), c)
    for node in reversed(nodes):
        if node.op == "var" or node.id not in adj: continue
        for arg, d in partials(node):
            if arg.op == "const": continue
            adj[arg.id] = sy.add(adj.get(arg.id, sy.const(0.0)), sy.mul(d, adj[node.id]))
    return adj

fi = scenes.get("suslov").integrator(gains=10.0, configuration=True)
n, size = fi.n, fi.parameter_layout.size
for name, build in (("field", lambda y, p, h: fi.unforced_vector_field(y, p, data=TRACED_DATA)),
                    ("feedback step", lambda y, p, h: feedback_step(fi, y, h, p, data=TRACED_DATA))):
    with trace() as tr:
        y, p = tr.symbols("y", n), tr.symbols("p", size)
        h = tr.symbols("hh", 1)[0]
        f = [sy.as_sym(v) for v in np.asarray(build(y, p, h), dtype=object).reshape(-1)]
        prim = {x.id for x in reachable(f) if x.op != "var"}
        d = tr.symbols("d", n + size)
        fT = jvp_graph(f, [*y, *p], d)
        jv = {x.id for x in reachable(fT[1]) if x.op != "var"} - prim
        lam = tr.symbols("lam", n)
        adj = vjp(f, list(lam))
        outs = [adj.get(x.id, sy.const(0.0)) for x in [*y, *p]]
        vj = {x.id for x in reachable(outs) if x.op != "var"} - prim
        print(f"{name}: primal {len(prim)}, JVP (one direction) {len(jv)}, VJP {len(vj)}")
