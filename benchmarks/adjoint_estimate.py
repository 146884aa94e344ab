"""Operation counts of the adjoint's cost estimate (docs/gradients.md, "Reverse mode"): Suslov's traced field and
feedback step, their primal nodes, the forward tangent of one direction (JVP; with the gains held, as they are in a
run, the code the fused loop prints) and a
reverse-mode sweep (VJP: every node's adjoint accumulated from its users, built on the same trace).

Run from the repository root: ``python benchmarks/adjoint_estimate.py`` (plain Python, a few seconds).
The VJP is the one :mod:`liefi.integrator.adjoint` compiles (:func:`liefi.integrator._tangent_loop.vjp_graph`).
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from liefi import scenes
from liefi.engine.trace import trace, TRACED_DATA, traced_call
from liefi.engine.codegen import reachable
from liefi.engine import symbolic as sy
from liefi.integrator._tangent_loop import jvp_graph, vjp_graph
from liefi.schemes.split import feedback_step

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
        lay = fi.parameter_layout  # the fused loop's activity: the gains are held, only the targets move
        moving = [*range(n), *(n + q for q in range(size) if q == lay.energy_target or q in lay.user_target)]
        jv_held = {x.id for x in reachable(jvp_graph(f, [*y, *p], d, moving)[1]) if x.op != "var"} - prim
        lam = tr.symbols("lam", n)
        outs = vjp_graph(f, [*y, *p], list(lam))
        vj = {x.id for x in reachable(outs) if x.op != "var"} - prim
        print(f"{name}: primal {len(prim)}, JVP (one direction) {len(jv)}, JVP with the gains held (the fused "
              f"loop's) {len(jv_held)}, VJP {len(vj)}")
