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


# --- build time: what the build computes, counted (issue 25: from_mechanics within sympy's own equations' time) ---
def _counting(monkeypatch, owner, name):
    calls = []
    original = getattr(owner, name)

    def counting(*args, **kw):
        calls.append(args)
        return original(*args, **kw)

    monkeypatch.setattr(owner, name, counting)
    return calls


def test_the_checks_generate_no_code(monkeypatch):
    """The build generates code for its data functions (in ``_bound``) and nothing else: the checks (the restored
    places of ``_restore``, the loads' power against ``-dU/dt``) evaluate their expressions at their few
    points by a walk (:mod:`liefi.systems._evaluate`); each was a ``lambdify`` with common-subexpression
    elimination for four to eight evaluations (7 lambdify calls, 5 of them data functions).  The data
    functions are liefi's own code (:mod:`liefi.systems._sympy_code`), no ``lambdify`` at all."""
    import test_mechanics_minimal as M

    import liefi.systems.mechanics as mech

    KM, consts, _, _ = M.rattleback()  # minimal speeds (a restored contact point) and a gravity load
    inside, lambdified = [], []  # whether each lambdify ran for a data function (_bound)
    original_bound, original_lambdify = mech._bound, sympy.lambdify

    def bound(*args, **kw):
        inside.append(True)
        try:
            return original_bound(*args, **kw)
        finally:
            inside.pop()

    def lambdify(*args, **kw):
        lambdified.append(bool(inside))
        return original_lambdify(*args, **kw)

    generated, original_generate = [], mech.sympy_function

    def generate(*args, **kw):
        generated.append(bool(inside))
        return original_generate(*args, **kw)

    monkeypatch.setattr(mech, "_bound", bound)
    monkeypatch.setattr(sympy, "lambdify", lambdify)
    monkeypatch.setattr(mech, "sympy_function", generate)
    system = liefi.from_mechanics(KM, consts)
    assert system.restored_coordinates == ("x_P", "y_P") and system.potential is not None
    assert len(generated) >= 3 and all(generated) and not lambdified


def test_constant_data_are_not_lambdified():
    """A kinematic map written ``qdot - u`` has the constant matrices ``K_qdot = 1``, ``K_u = -1``: bound as
    numbers, with the values and dtypes the lambdified constants give."""
    import numpy as np

    import liefi.systems.mechanics as mech

    assert mech._numbers([sympy.Integer(1), sympy.Rational(1, 3), sympy.Float(2.5)]) == [1, 1 / 3, 2.5]
    assert mech._numbers([sympy.Integer(1), sympy.Symbol("x")]) is None
    assert mech._numbers([sympy.pi]) is None and mech._numbers([sympy.I]) is None  # lambdify's own
    holder = mech._Constants([], np.zeros(0))
    K = mech._bound(sympy, sympy.symbols("x0:2"), [], [sympy.Integer(1), sympy.Integer(0), sympy.Integer(-1),
                                                     sympy.Integer(1)], (2, 2), holder, "w")
    for x, dtype in ((np.zeros((3, 2)), float), (np.zeros(2, complex), complex)):
        out = K(x)
        assert out.dtype == dtype and out.shape == x.shape[:-1] + (2, 2)
        np.testing.assert_array_equal(out, np.broadcast_to([[1, 0], [-1, 1]], out.shape))


@pytest.mark.parametrize("case", ["four_bar", "kane_pendulum", "rattleback"])
def test_no_jacobian_of_the_models_expressions(monkeypatch, case):
    """The velocities, kinematic equations and velocity constraints are linear in the velocities: their
    coefficients are read in one pass (``linear_eq_to_matrix``), and the configuration constraints'
    ``df/dq`` from ``df/dt`` (which sympy's own velocity constraints already took), not by a Jacobian (one
    derivative per variable, each with respect to a dynamic symbol through a substitution)."""
    import test_mechanics_holonomic as H
    import test_mechanics_minimal as M

    made = getattr(M if case == "rattleback" else H, case)()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    from sympy.matrices.matrixbase import MatrixBase

    jacobians = _counting(monkeypatch, MatrixBase, "jacobian")
    liefi.from_mechanics(model, consts)
    assert jacobians == []


def test_the_annihilator_of_minimal_speeds_is_formed_without_simplify(monkeypatch):
    """The sleigh in minimal speeds (``qdot = B u``, ``B`` 3 x 2): its row ``(-sin theta, cos theta, 0)`` from a
    null space whose pivots ``is_zero`` tests and a ``cancel``, no ``simplify`` (was one per entry)."""
    import test_mechanics_minimal as M

    import liefi.systems._kinematics as kin
    import liefi.systems.mechanics as mech

    rows = []
    original = kin._annihilator
    monkeypatch.setattr(mech, "_annihilator", lambda *a: rows.append(original(*a)) or rows[-1])
    made = M.sleigh_minimal()
    model, consts = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    calls = _counting_simplify(monkeypatch)
    liefi.from_mechanics(model, consts)
    assert calls == []
    theta = model.q[2] if len(model.q) > 2 else None
    (row,) = rows[0]
    assert [sympy.simplify(e) for e in row] == [-sympy.sin(theta), sympy.cos(theta), 0]


def test_lambdify_checked_does_not_run_numpys_star_import():
    """``lambdify_checked`` hands sympy the numpy module object: sympy's ``from numpy import *`` (which
    imports ``numpy.f2py``, ``numpy.testing`` ...: a tenth of a second or more, paid in the first build of a
    process) is never run; the generated code is the same."""
    import subprocess
    import sys

    code = ("import sys, sympy, numpy\n"
            "from liefi.systems.sympy_input import lambdify_checked\n"
            "x = sympy.Symbol('x')\n"
            "f = lambdify_checked(sympy, [x], [sympy.sin(x) * sympy.sqrt(x)], 'w', cse=True, dummify=True)\n"
            "assert abs(f(0.5)[0] - numpy.sin(0.5) * numpy.sqrt(0.5)) < 1e-15\n"
            "print('numpy.f2py' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_the_walk_agrees_with_lambdify_and_sympys_derivative():
    """:func:`evaluator` and :func:`directional` (forward mode) against ``lambdify`` and ``diff`` at random points;
    a node the walk does not know goes to ``lambdify_checked``, whose named errors it keeps."""
    import numpy as np

    from liefi.systems._evaluate import directional, evaluator

    x, y, z = sympy.symbols("x y z", real=True)
    exprs = [sympy.sin(x) * sympy.sqrt(y) + z / x**2, sympy.atan2(x, y) * sympy.pi + sympy.Abs(x - y) ** 3,
             3 * x / y ** sympy.Rational(3, 2) + sympy.exp(x * y) ** z, x**2 * y**3 - 1, y**x,
             sympy.tan(x) + sympy.asin(x / 3) + sympy.log(y) * sympy.cosh(z) + sympy.atan(x * z) + sympy.tanh(y)]
    rng = np.random.default_rng(1)
    X, D = list(rng.uniform(0.2, 1.2, (3, 5))), list(rng.normal(size=(3, 5)))
    T = sympy.symbols("t0:3", real=True)
    values = np.array(sympy.lambdify([x, y, z], exprs)(*X))
    rates = np.array(sympy.lambdify([x, y, z, *T], [sum(e.diff(s) * t for s, t in zip((x, y, z), T)) for e in exprs])(
        *X, *D))
    np.testing.assert_allclose(evaluator(sympy, [x, y, z], exprs, "w")(*X), values, rtol=1e-13)
    v, d = directional(sympy, [x, y, z], exprs, [x, y, z], "w")(*X, *D)
    np.testing.assert_allclose(v, values, rtol=1e-13)
    np.testing.assert_allclose(d, rates, rtol=1e-12)
    with pytest.raises(ValueError, match="w: contains the undefined function 'f'"):
        evaluator(sympy, [x], [sympy.Function("f")(x)], "w")(X[0])
    with pytest.raises(ValueError, match="w: depends on"):
        evaluator(sympy, [x], [x + y], "w")(X[0])
