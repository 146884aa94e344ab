"""Models written the way sympy.physics.mechanics' docs write them, shared by the tests that hand them to liefi."""

import pytest


def sleigh_model():
    """Chaplygin sleigh (LagrangesMethod): blade at P = (x, y), heading theta, mass centre a ahead of the blade.

    Returns the ``LagrangesMethod`` and its constants' symbols ``(m, I, a)``.
    """
    sympy = pytest.importorskip("sympy")
    me = pytest.importorskip("sympy.physics.mechanics")
    x, y, theta = me.dynamicsymbols("x y theta")
    m, I, a = sympy.symbols("m I a")
    N = me.ReferenceFrame("N")
    B = N.orientnew("B", "Axis", [theta, N.z])
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    P.set_vel(N, P.pos_from(O).dt(N))
    G = P.locatenew("G", a * B.x)
    G.set_vel(N, G.pos_from(O).dt(N))
    sled = me.RigidBody("sled", G, B, m, (me.inertia(B, 0, 0, I), G))
    L = me.Lagrangian(N, sled)
    LM = me.LagrangesMethod(L, [x, y, theta], nonhol_coneqs=[P.vel(N).dot(B.y)], frame=N)
    return LM, (m, I, a)
