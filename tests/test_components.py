"""Build-time shortcuts of ``from_mechanics`` (issue 25): the same expressions, less sympy work."""

import numpy as np
import sympy
from sympy.physics.mechanics import Dyadic, ReferenceFrame, dynamicsymbols, inertia

from liefi.systems._components import dyadic_components, frame_of, vector_components
from liefi.systems._kinematics import _cleared, _regular_rows


def _frames():
    q1, q2 = dynamicsymbols("q1:3")
    N = ReferenceFrame("N")
    A = N.orientnew("A", "Axis", [q1, N.z])
    B = A.orientnew("B", "Axis", [q2, A.x])
    return N, A, B


def test_components_are_sympys_to_matrix():
    """Read from the stored components where a vector or dyadic is written in the frame, sympy's ``to_matrix``
    elsewhere: the same expressions either way."""
    N, A, B = _frames()
    a, b, c, d = sympy.symbols("a:d")
    D = inertia(A, a, b, c, d, 0, -d) + 3 * (A.x | A.z)
    v = a * A.x - b * A.z
    mixed = a * A.x + b * B.y
    assert frame_of(D) is A and frame_of(v) is A and frame_of(mixed) is None
    for F in (A, B, N):
        assert dyadic_components(sympy, D, F) == D.to_matrix(F)
        for vec in (v, mixed, 0 * N.x):
            assert vector_components(sympy, vec, F) == vec.to_matrix(F)
    assert dyadic_components(sympy, Dyadic(0), A) == sympy.zeros(3, 3)


def test_kinetic_form_reads_the_inertia_in_its_own_frame(monkeypatch):
    """The rolling disc's inertia is given in its lean frame: its kinetic energy is formed there, with no
    ``Dyadic.to_matrix`` (nine dot products through the disc's rotation: two thirds of the disc's kinetic form)."""
    from test_mechanics_minimal import disc_kane

    import liefi

    made = disc_kane()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]

    def refused(*a, **k):
        raise AssertionError("Dyadic.to_matrix called")

    monkeypatch.setattr(Dyadic, "to_matrix", refused)
    system = liefi.from_mechanics(model, consts)
    z = system.state([0.1, 0.4, 0.2], u=[0.3, -0.2, 1.1])
    assert np.all(np.isfinite(system.constrained_vector_field(z)))


def test_a_row_cleared_by_its_own_product_is_not_cancelled(monkeypatch):
    """sympy's non-minimal pendulum row ``(q1 u1 + q2 u2) / sqrt(q1^2 + q2^2)`` (0/0 at ``q = 0``) times its
    denominator is already free of it: kept as it is (``cancel`` would only expand it), the same function."""
    q1, q2, u1, u2 = dynamicsymbols("q1 q2 u1 u2")
    row = sympy.sqrt((q1**2 + q2**2) / q1**2) * (q1 * u1 + q2 * u2) * q1 / (q1**2 + q2**2)
    cancelled = sympy.cancel(sympy.together(row) * (q1**2 + q2**2))
    calls = []
    real = sympy.cancel
    monkeypatch.setattr(sympy, "cancel", lambda e, *a, **k: calls.append(e) or real(e, *a, **k))
    (kept,) = _regular_rows(sympy, [row], [q1, q2])
    assert not calls
    assert sympy.fraction(kept)[1] == 1
    vals = dict(zip([q1, q2, u1, u2], [0.3, -0.7, 1.1, 0.4]))
    assert abs(float(kept.xreplace(vals)) - float(cancelled.xreplace(vals))) < 1e-14
    # a product that sympy's Mul does not clear still goes through cancel
    x = sympy.symbols("x")
    assert _cleared(sympy, [1 / (x + 1), 1 / (x**2 - 1)]) == [x - 1, 1] and calls


def test_dot_of_a_load_is_sympys_dot():
    """A load in one frame dotted with a velocity in several: rotated into each part's frame first, only nonzero
    products formed; the same function as sympy's ``dot`` (here even the same expression)."""
    from liefi.systems._components import dot

    N, A, B = _frames()
    q1, q2, q3 = dynamicsymbols("q1:4")
    a, b = sympy.symbols("a b")
    vel = q3 * B.y + q2 * A.x + q1 * N.z + A.z
    for load in (-a * b * N.z, a * B.z + b * B.x, a * N.x + b * N.z, 0 * N.x):
        mine, theirs = dot(sympy, load, vel), load.dot(vel)
        f = sympy.lambdify([q1, q2, q3, a, b], mine - theirs)
        assert abs(f(0.3, 0.5, -0.7, 1.1, 0.9)) < 1e-14


def test_power_of_a_load_on_a_minimal_speeds_disc_is_not_sympys_dot(monkeypatch):
    """The disc's weight dotted with the derived velocity of its centre: no sympy ``Vector.dot`` of the two (the
    big components times all nine entries of a rotation: 60 % of the disc's load potential)."""
    from sympy.physics.vector import Vector
    from test_mechanics_minimal import disc_kane

    import liefi

    made = disc_kane()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    real, big = Vector.dot, []

    def watched(self, other):
        if isinstance(other, Vector) and len(other.args) > 1 and len(self.args) == 1 and any(
                e.has(sympy.Derivative) for c, _ in other.args for e in c):
            big.append((self, other))
        return real(self, other)

    monkeypatch.setattr(Vector, "dot", watched)
    monkeypatch.setattr(Vector, "__and__", watched)
    liefi.from_mechanics(model, consts)
    assert not big
