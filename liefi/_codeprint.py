"""Straight-line code from expression graphs: the one home of liefi's printing of arithmetic.

A graph is made of nodes with ``op`` (``"const"``, ``"var"``, an operation of :data:`_BINARY` or
:data:`_UNARY`), ``args`` (the argument nodes; ``(name, index)`` for a ``"var"``), ``value`` (of a
``"const"``) and ``id`` (creation order, a topological order).  The compiled engine's traced graphs
(:mod:`liefi.engine.symbolic`) and the data functions that :func:`liefi.from_mechanics` generates from
sympy expressions (:mod:`liefi.systems._sympy_code`) are both printed by :func:`node_lines`.
"""

from __future__ import annotations

import math

#: unary operations: name -> code template (``math`` functions: numba compiles them to libm calls)
_UNARY = {
    "neg": "(-{0})",
    "sin": "math.sin({0})",
    "cos": "math.cos({0})",
    "tan": "math.tan({0})",
    "exp": "math.exp({0})",
    "log": "math.log({0})",
    "sqrt": "math.sqrt({0})",
    "arcsin": "math.asin({0})",
    "arccos": "math.acos({0})",
    "arctan": "math.atan({0})",
    "sinh": "math.sinh({0})",
    "cosh": "math.cosh({0})",
    "tanh": "math.tanh({0})",
    "arcsinh": "math.asinh({0})",
    "arccosh": "math.acosh({0})",
    "arctanh": "math.atanh({0})",
    "expm1": "math.expm1({0})",
    "log1p": "math.log1p({0})",
    "abs": "abs({0})",
    "sign": "math.copysign(1.0, {0})",
}
_BINARY = {"add": "({0} + {1})", "sub": "({0} - {1})", "mul": "({0} * {1})", "div": "({0} / {1})", "pow": "({0} ** {1})"}


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
