"""The build of ``from_mechanics`` without ``sympy.simplify`` where a cheaper test is exact (issue 25, build time).

The zero tests of the data (a load moving with the auxiliary speeds only, a zero potential or vector
potential, a constraint without a velocity-free term) ask :func:`is_zero`, whose answer is always
``sympy.simplify(e) == 0``'s: a literal zero, or a value above rounding at one point, decide without it.
The checks that ``L`` is quadratic and the constraints linear in the velocities read the expression's
structure before they expand it (:func:`_degree_at_most`).
"""

import pytest

import liefi
from liefi.systems.sympy_input import _degree_at_most, is_zero

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")


def _counting_simplify(monkeypatch):
    calls = []
    original = sympy.simplify

    def counting(*args, **kw):
        calls.append(args[0])
        return original(*args, **kw)

    monkeypatch.setattr(sympy, "simplify", counting)
    return calls


def test_four_bar_with_gravity_and_auxiliary_speeds_builds_without_simplify(monkeypatch):
    """Was 11 calls of ``sympy.simplify`` (about half of the build) on the loads' velocities with the
    auxiliary speeds at zero: the nonzero ones are now proved nonzero by their value at one point."""
    import test_mechanics_holonomic as H

    case = H.four_bar_gravity()
    calls = _counting_simplify(monkeypatch)
    system = liefi.from_mechanics(case["model"], case["constants"])
    assert calls == []
    assert system.potential is not None  # the gravity loads were kept (not taken for reactions)


def test_the_minimal_disc_with_auxiliary_speeds_builds_without_simplify(monkeypatch):
    import test_mechanics_minimal as M

    eom, consts, _, _ = M.disc_kane_aux()
    calls = _counting_simplify(monkeypatch)
    liefi.from_mechanics(eom, consts)
    assert calls == []


@pytest.mark.parametrize("make", [
    lambda q, x, p, n: sympy.sin(q) ** 2 + sympy.cos(q) ** 2 - 1,  # zero, only simplify shows it
    lambda q, x, p, n: sympy.sqrt(p ** 2) - p,  # zero by the assumption p > 0
    lambda q, x, p, n: sympy.sqrt(x ** 2) - x,  # not zero (x < 0), zero at every positive point
    lambda q, x, p, n: sympy.cos(sympy.pi * n) - (-1) ** n,  # zero for an integer n: no point drawn
    lambda q, x, p, n: q.diff() * sympy.sin(q) - 1e-13,  # nonzero, small
    lambda q, x, p, n: (x - 1) ** 2 - x ** 2 + 2 * x - 1,
    lambda q, x, p, n: 1 / (x - x),
])
def test_is_zero_answers_as_simplify(make):
    q = me.dynamicsymbols("q")
    e = make(q, sympy.Symbol("x"), sympy.Symbol("p", positive=True), sympy.Symbol("n", integer=True))
    assert is_zero(sympy, e) == (sympy.simplify(e) == 0)


def test_is_zero_asks_simplify_only_when_the_value_is_inconclusive(monkeypatch):
    q, x = me.dynamicsymbols("q"), sympy.Symbol("x")
    calls = _counting_simplify(monkeypatch)
    assert not is_zero(sympy, q.diff() * sympy.cos(q) + x)
    assert is_zero(sympy, (q * x).xreplace({x: 0}))
    assert calls == []
    assert is_zero(sympy, sympy.sin(q) ** 2 + sympy.cos(q) ** 2 - 1)
    assert len(calls) == 1


@pytest.mark.parametrize("e, k", [("a*v**2 + b*v + c", 2), ("(a*v + w)**2", 2), ("(v + w)**3 - v**3", 2),
                                  ("sin(v)", 1), ("1/v", 1), ("a*v*w + sin(a)", 2), ("v*w", 1)])
def test_degree_bound_never_claims_more_than_the_polynomial_has(e, k):
    """True only where ``Poly(expand(e))`` has degree at most ``k``; where False, the expansion decides."""
    v, w, a, b, c = sympy.symbols("v w a b c")
    e = sympy.sympify(e, locals=dict(v=v, w=w, a=a, b=b, c=c))
    if _degree_at_most(sympy, e, [v, w], k):
        assert sympy.Poly(sympy.expand(e), v, w).total_degree() <= k
    else:
        try:
            deg = sympy.Poly(sympy.expand(e), v, w).total_degree()
        except sympy.PolynomialError:
            deg = None
        assert deg is None or deg > k
