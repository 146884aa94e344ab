r"""Components of ``sympy.physics.vector`` vectors and dyadics in a frame, read without sympy's dot products.

``Vector.to_matrix(F)`` forms ``v . F.x``, ``v . F.y``, ``v . F.z`` (each a rotation ``F.dcm(G)`` times
``v``'s components in ``G``) and ``Dyadic.to_matrix(F)`` the nine ``F.i . D . F.j``: for a vector or a
dyadic written in ``F`` itself these are the rotation by the identity and products with the unit vectors'
``0`` and ``1``, whose results are the stored components.  Read here from the stored components then
(the same expressions); any other vector or dyadic goes to sympy's ``to_matrix``.  A rolling disc's
kinetic energy spent two thirds of its time in those dot products (issue 25's build time).
"""

from __future__ import annotations


def frame_of(obj):
    """The one frame of the components of the vector or dyadic ``obj`` (a dyadic's unit vectors), else ``None``."""
    frames = set()
    for a in obj.args:
        if len(a) == 2:  # Vector: (components, frame)
            frames.add(a[1])
        else:  # Dyadic: (measure, unit vector, unit vector)
            frames.update(f for v in a[1:] for _, f in v.args)
    return frames.pop() if len(frames) == 1 else None


def vector_components(sympy, v, frame):
    """``v``'s components in ``frame``: a ``3 x 1`` Matrix (``v.to_matrix(frame)``)."""
    if not v.args:
        return sympy.zeros(3, 1)
    if frame_of(v) is frame:
        return sum((sympy.Matrix(c) for c, _ in v.args), sympy.zeros(3, 1))
    return v.to_matrix(frame)


def dyadic_components(sympy, D, frame):
    """``D``'s components ``frame.i . D . frame.j``: a ``3 x 3`` Matrix (``D.to_matrix(frame)``)."""
    if not D.args:
        return sympy.zeros(3, 3)
    if frame_of(D) is not frame:
        return D.to_matrix(frame)
    M = [[sympy.S.Zero] * 3 for _ in range(3)]
    for measure, a, b in D.args:  # a, b unit vectors of frame: a single 1 among their components
        (i,), (j,) = ([k for k, e in enumerate(v.args[0][0]) if e != 0] for v in (a, b))
        ea, eb = a.args[0][0][i], b.args[0][0][j]
        M[i][j] += measure * ea * eb
    return sympy.Matrix(M)


def dot(sympy, a, b):
    r"""``a . b``, the same function as ``a.dot(b)``, for ``a`` written in one frame ``F`` (a load: ``-m g N.z``).

    Each part of ``b`` written in a frame ``G`` meets ``a``'s components rotated into ``G`` first,
    ``b_G . (G.dcm(F) a_F)``, and only the nonzero products are formed; sympy's ``dot`` forms
    ``(b_G^T G.dcm(F)) a_F``: the large components of ``b`` times all nine entries of the rotation, zeros
    included (each product a query of the other factor's assumptions).  In one frame (``G = F``) the
    expression is sympy's own; else the same sum grouped otherwise (equal to rounding).
    """
    F = frame_of(a) if a.args and b.args else None
    if F is None:
        return a.dot(b)
    x = vector_components(sympy, a, F)
    out = []
    for comps, G in b.args:
        D = G.dcm(F) if G is not F else None
        xg = x if D is None else [sympy.Add(*[D[i, j] * x[j] for j in range(3) if x[j] != 0]) for i in range(3)]
        out += [comps[i] * xg[i] for i in range(3) if comps[i] != 0 and xg[i] != 0]
    return sympy.Add(*out)


def oriented(a, b):
    """Whether the frame ``a`` has an orientation path to ``b`` (sympy's ``dcm`` raises ``ValueError`` if not): a
    search of the frames' orientation graph (``_dcm_dict``, the graph ``dcm`` walks), without forming the matrix."""
    seen, todo = {a}, [a]
    while todo:
        f = todo.pop()
        if f is b:
            return True
        for g in getattr(f, "_dcm_dict", {}):
            if g not in seen:
                seen.add(g)
                todo.append(g)
    return False


def model_expressions(sympy, me, parts):
    """Every sympy expression a model holds as given (``liefi.systems.mechanics._parts``): its coordinates,
    speeds, kinematic equations, Lagrangian, constraints, the bodies' masses and inertias, the loads' vectors
    and the actuators' parameters -- what :func:`~liefi.systems.sympy_input.sympy_only` checks before liefi
    uses any of them."""
    out = [*parts["q"], *parts["u"], *parts["aux"], *(parts["kd"] or []), *parts["constraints"], *parts["holonomic"]]
    out += [] if parts["L"] is None else [parts["L"]]
    for body in parts["bodies"]:
        out += [getattr(body, "mass", 0)] + [a[0] for a in getattr(getattr(body, "central_inertia", None), "args", ())]
        out += [getattr(body, "potential_energy", 0)]
    for load in parts["loads"]:
        vec = load[-1] if isinstance(load, tuple) else getattr(load, "vector", None)
        out += [c for c, _ in getattr(vec, "args", ())]
    for act in parts["actuators"]:
        out += [v for v in vars(act).values() if isinstance(v, sympy.Basic)]
    return out
