"""Names and classes from a sympy model never become code, and never stand for something else.

liefi runs no code it did not write.  A model reaches generated code through sympy's printers (the
``lambdify`` fallback of :func:`liefi.systems.sympy_input.lambdify_checked`), through ``str`` and
``srepr`` (names, the kernel fingerprint) and through ``sympify``; each test below shows what ran or
what was shadowed before, with a marker file where code ran:

* a class that is not sympy's own -- a ``Function`` subclass with a printer hook (``_numpycode``), one
  named ``sin`` (read as numpy's sine), a ``Symbol`` subclass with a ``_sympystr`` hook, a function
  made by ``sympy.Function(name, __dict__={...})`` with a ``_sympyrepr`` hook -- is refused by name,
  before liefi calls any of its methods;
* a string hidden in a model (a body's potential energy set past sympy's setter) is refused, never
  ``sympify``-ed;
* a bound variable is renamed whatever its name (a ``Sum`` index named ``sin`` shadowed numpy's sine);
* a sympy function numpy has no counterpart for is a named error, not a name looked up at run time;
* a point or speed name is a name, never parsed (``dynamicsymbols("x_C D")`` made two symbols);
* a user's wrapper of liefi's contact function (``functools.wraps``) or a user's dataclass does not
  carry liefi's fingerprint (the compiled engine would have loaded another system's kernel);
* names that look like code or like the generated code's own variables (``a0``, ``t1``, ``math``,
  ``y``) are labels only: the generated source is the same as with plain names.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")

import liefi  # noqa: E402
from liefi import _fingerprint  # noqa: E402

t = me.dynamicsymbols._t
q1, q2, v1, v2 = sympy.symbols("q1 q2 v1 v2")
T = (v1**2 + v2**2) / 2
ROWS = [v1 - q1 * v2]
X = np.array([0.5, 0.2, 0.0, 0.0])


def _hook(marker):
    """A printer hook (``_numpycode(self, printer)``, ``_sympystr`` ...) that creates ``marker`` when it runs."""
    def hook(self, printer=None, *args, **kwargs):
        marker.touch()
        return "1.0"

    return hook


def _lagrange(U, q=(q1, q2), qd=(v1, v2), rows=ROWS):
    return liefi.from_sympy(T - U, list(q), list(qd), rows)


@pytest.mark.parametrize("where", ["from_sympy", "from_mechanics", "lambdify_checked"])
def test_a_function_class_with_a_printer_hook_is_refused_and_its_hook_never_runs(tmp_path, where):
    """Before: the ``lambdify`` fallback printed the expression, sympy's printer called ``_numpycode`` (the
    marker was made) and the potential read the hook's ``1.0``."""
    marker = tmp_path / "ran"
    hooked = type("hooked", (sympy.Function,), {k: _hook(marker) for k in ("_numpycode", "_lambdacode", "_pythoncode")})
    with pytest.raises(ValueError, match=r"class 'hooked' .* not one of sympy's own"):
        if where == "from_sympy":
            _lagrange(hooked(q1)).potential(X)
        elif where == "from_mechanics":
            x, y = me.dynamicsymbols("x y")
            lm = me.LagrangesMethod((x.diff(t) ** 2 + y.diff(t) ** 2) / 2 - hooked(x), [x, y],
                                    nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
            liefi.from_mechanics(lm).potential(X)
        else:
            from liefi.systems.sympy_input import lambdify_checked

            lambdify_checked(sympy, [q1], [hooked(q1) + 1], "test")(0.5)
    assert not marker.exists(), "a printer hook of the user's class ran"


def test_a_users_function_named_sin_is_refused_not_read_as_numpys_sine():
    """Before: the class ``sin`` (whose value is 2, as its ``evalf`` says) was printed as ``sin(x)`` and evaluated
    as numpy's sine: a silent wrong potential (0.479 at q1 = 0.5)."""
    class sin(sympy.Function):  # noqa: N801 -- the name is the point
        def _eval_evalf(self, prec):
            return sympy.Float(2.0)

    assert sympy.N(sin(q1)) == 2.0
    with pytest.raises(ValueError, match=r"L: contains an object of the class 'sin' \(of 'test_trust_names'\)"):
        _lagrange(sin(q1)).potential(X)


def test_a_symbol_subclass_as_a_coordinate_is_refused_before_it_is_printed(tmp_path):
    """Before: the coordinate's name was read through its ``_sympystr`` hook (the marker was made, the coordinate
    named by what the hook returned)."""
    marker = tmp_path / "ran"
    hooked = type("HookedSymbol", (sympy.Symbol,), {"_sympystr": _hook(marker)})
    e = hooked("e")
    with pytest.raises(ValueError, match=r"q: contains an object of the class 'HookedSymbol'"):
        _lagrange(e, q=(e, q2), rows=[v1 - e * v2])
    assert not marker.exists()
    with pytest.raises(ValueError, match=r"constants: contains an object of the class 'HookedSymbol'"):
        from liefi.systems.mechanics import _parameters

        _parameters(sympy, {e}, {e: 1.0})
    assert not marker.exists()


def test_a_dynamicsymbol_made_with_a_repr_hook_is_refused_before_the_fingerprint_prints_it(tmp_path):
    """``sympy.Function(name, __dict__={...})`` puts anything into the class (and compares equal to the plain
    function).  Before: the system was built, and its kernel fingerprint (``sympy.srepr`` of the model) ran the
    ``_sympyrepr`` hook."""
    marker = tmp_path / "ran"
    x = sympy.Function("x_hooked", __dict__={"_sympyrepr": _hook(marker)})(t)  # a name no other test applies (sympy's
    y = me.dynamicsymbols("y")  # cache hands back an equal function made before: sympy.Function("x")(t) is x(t))
    assert x == me.dynamicsymbols("x_hooked") and "_sympyrepr" in vars(type(x))
    with pytest.raises(ValueError, match=r"q: contains the function 'x_hooked' made by sympy.Function with attributes"):
        system = liefi.from_sympy((x.diff(t) ** 2 + y.diff(t) ** 2) / 2 - x, [x, y], [x.diff(t), y.diff(t)],
                                  [x.diff(t) - y * y.diff(t)])
        _fingerprint.of_system(system)
    assert not marker.exists(), "a repr hook of the model ran"


def test_implemented_function_is_refused_by_name_and_never_called():
    from sympy.utilities.lambdify import implemented_function

    called = []
    f = implemented_function("f", lambda a: called.append(a) or 1.0)
    with pytest.raises(ValueError, match=r"L: contains the implemented function 'f'"):
        _lagrange(f(q1))
    assert not called


def test_a_string_hidden_in_a_model_is_refused_not_sympified(tmp_path):
    """A body's potential energy set past sympy's setter (which sympifies what the user assigns) is a string.
    Before: liefi's ``sympify`` of it (the ignored-potential-energy warning of a Kane model) ran it."""
    marker = tmp_path / "ran"
    q, u = me.dynamicsymbols("q u")
    m, g = sympy.symbols("m g")
    N, O = me.ReferenceFrame("N"), me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", q * N.x)
    P.set_vel(N, u * N.x)
    bob = me.Particle("bob", P, m)
    bob._potential_energy = f"__import__('pathlib').Path({str(marker)!r}).touch() or 0"
    kane = me.KanesMethod(N, [q], [u], kd_eqs=[q.diff(t) - u])
    kane.kanes_equations([bob], [(P, -m * g * N.x)])
    with pytest.raises(TypeError, match=r"model: got a string"):
        liefi.from_mechanics(kane, {m: 1.0, g: 9.81})
    assert not marker.exists(), "a string in the model ran as code"


@pytest.mark.parametrize("name", ["sin", "cos", "k"])
def test_a_bound_variable_is_renamed_whatever_its_name(name):
    """Before: a ``Sum`` index named ``sin`` was printed as itself and shadowed numpy's sine inside the sum
    (``TypeError: 'int' object is not callable``)."""
    k = sympy.Symbol(name, integer=True)
    system = _lagrange(sympy.Sum(sympy.sin(q1) * k + sympy.cos(q1) ** 2, (k, 0, 2)))
    np.testing.assert_allclose(system.potential(X), 3 * np.sin(0.5) + 3 * np.cos(0.5) ** 2, rtol=1e-14)


def test_a_sympy_function_numpy_lacks_is_named_not_looked_up_at_run_time():
    """Before: ``besselj(0, x)`` was printed into the code as a name, and failed when called (``NameError``)."""
    with pytest.raises(ValueError, match=r"potential: liefi cannot evaluate it with numpy .*besselj"):
        _lagrange(sympy.besselj(0, q1))


def _disc(contact="C"):
    """The rolling disc in minimal speeds (Kane): its contact point's place is restored as ``x_<name>, y_<name>``."""
    q1_, q2_, q3_, u1, u2, u3 = me.dynamicsymbols("q1 q2 q3 u1 u2 u3")
    r, m, g = sympy.symbols("r m g")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1_, N.z])
    L = Y.orientnew("L", "Axis", [q2_, Y.x])
    R = L.orientnew("R", "Axis", [q3_, L.y])
    w = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    C = me.Point(contact)
    C.set_vel(N, 0)
    D = C.locatenew("D", r * L.z)
    D.v2pt_theory(C, N, R)
    disc = me.RigidBody("disc", D, R, m, (me.inertia(L, m / 4 * r**2, m / 2 * r**2, m / 4 * r**2), D))
    kane = me.KanesMethod(N, q_ind=[q1_, q2_, q3_], u_ind=[u1, u2, u3], kd_eqs=[me.dot(R.ang_vel_in(N) - w, e) for e in L])
    kane.kanes_equations([disc], [(D, -m * g * Y.z)])
    return liefi.from_mechanics(kane, {r: 0.5, m: 1.0, g: 9.81})


def test_a_point_name_is_a_name_never_parsed():
    """Before: the restored coordinates were made by ``dynamicsymbols("x_C D y_C D")``, which parses its text:
    four symbols for two places (``ValueError: q: the symbols must be distinct``); ``"a:c"`` is a range there."""
    plain, odd = _disc("C"), _disc("C a:c")
    z = np.array([0.1, 0.2, 0.3, 0.4, -0.2, 0.5, -1.0, 3.0, 0.1, 0.0])
    assert odd.restored_coordinates == ("x_C a:c", "y_C a:c")
    np.testing.assert_array_equal(odd.metric(z[:5]), plain.metric(z[:5]))
    np.testing.assert_array_equal(odd.constraints(z[:5]), plain.constraints(z[:5]))


def test_a_speed_name_is_a_name_never_parsed():
    """A speed without a coordinate gets the coordinate ``q_<speed>``.  Before: ``dynamicsymbols("q_u 2")`` made two
    symbols (a tuple in the coordinates: ``AttributeError``)."""
    def rotor(spin):
        q, u1 = me.dynamicsymbols("q u1")
        u2 = sympy.Function(spin)(t)
        m, l, g = sympy.symbols("m l g")
        N = me.ReferenceFrame("N")
        A = N.orientnew("A", "Axis", [q, N.z])
        A.set_ang_vel(N, u1 * N.z)
        W = me.ReferenceFrame("W")
        W.set_ang_vel(A, u2 * A.x)
        O = me.Point("O")
        O.set_vel(N, 0)
        P = O.locatenew("P", l * A.x)
        P.v2pt_theory(O, N, A)
        bodies = [me.Particle("bob", P, m), me.RigidBody("rotor", P, W, m, (me.inertia(A, 0.02, 0.01, 0.01), P))]
        kane = me.KanesMethod(N, q_ind=[q], u_ind=[u1, u2], kd_eqs=[q.diff() - u1])
        kane.kanes_equations(bodies, [(P, 2 * m * g * N.x)])
        return liefi.from_mechanics(kane, {m: 1.0, l: 0.7, g: 9.81})

    plain, odd = rotor("u2"), rotor("u 2")
    assert odd.space.shape_names == ("q", "q_u 2")
    z = np.array([0.3, 0.1, 0.2, -0.4])
    np.testing.assert_allclose(odd.hamiltonian(z), plain.hamiltonian(z), rtol=1e-15)


def test_a_wrapper_of_liefis_contact_does_not_carry_its_fingerprint():
    """``functools.wraps`` copies a function's attributes, the fingerprint too.  Before: a user's contact 1.5 times
    liefi's ellipsoid, wrapped around it, had the ellipsoid's fingerprint, and so had the rolling body built on it:
    the compiled engine would have loaded the ellipsoid's kernel for it."""
    from liefi.systems.rolling import ellipsoid, rolling_body

    e = ellipsoid([0.2, 0.03, 0.02])

    @functools.wraps(e)
    def bigger(Gamma):
        return 1.5 * e(Gamma)

    assert _fingerprint.of(e) is not None and _fingerprint.of(bigger) is None
    inertia = [2e-4, 1.6e-3, 1.7e-3]
    assert _fingerprint.of_system(rolling_body(1.0, inertia, e)) is not None
    assert _fingerprint.of_system(rolling_body(1.0, inertia, bigger)) is None


def test_a_users_dataclass_is_not_fingerprinted_by_its_fields():
    """Before: a user's dataclass was encoded by its module, name and fields, not its code: two contacts of
    different shapes (a class redefined, as in a notebook) had one fingerprint."""
    def contact(scale):
        @dataclasses.dataclass
        class Contact:
            r: float

            def __call__(self, Gamma):
                return -scale * self.r * Gamma

        return Contact(0.1)

    assert _fingerprint.digest(contact(1.0)) is None and _fingerprint.digest(contact(2.0)) is None


def test_names_like_code_or_like_the_generated_codes_own_are_labels_only(tmp_path):
    """Coordinates named ``a0``, ``t1``, ``math``, ``y`` (the names of liefi's generated code) and ``names=`` that
    are Python code: the system's values and its compiled kernel's source are those of plain names."""
    marker = tmp_path / "ran"
    from liefi.engine import kernels

    def build(names, labels=None):
        x, y, phi = sympy.symbols(names)
        xd, yd, phid = sympy.symbols([f"{s}_d" for s in names])
        L = (xd**2 + yd**2) / 2 + phid**2 / 2 + sympy.Rational(1, 2) * x + sympy.sin(phi) * sympy.cos(y)
        return liefi.from_sympy(L, [x, y, phi], [xd, yd, phid], [yd * sympy.cos(phi) - xd * sympy.sin(phi)],
                                names=labels)

    code = f"__import__('pathlib').Path({str(marker)!r}).touch()"
    plain = build(["x", "w", "phi"])
    odd = build(["a0", "t1", "math"], labels=(code, "y\n#", "out"))
    assert odd.state_names[:3] == (code, "y\n#", "out")
    z = np.array([0.1, 0.2, 0.3, 0.0, 0.0, 0.5])
    np.testing.assert_allclose(odd.hamiltonian(z), plain.hamiltonian(z), rtol=1e-15)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        texts = [kernels.compile_feedback(liefi.FeedbackIntegrator(s, z, gains=1.0), engine="python").kernel.text
                 for s in (plain, odd)]
    assert texts[0] == texts[1] and "pathlib" not in texts[1]
    assert not marker.exists()


def test_a_constant_named_like_liefis_clock_stays_a_constant():
    """The loads' force law had its clock as ``sympy.Symbol("t_")``, equal to a model's constant of that name.
    Before: the constant ``t_ = 5`` was taken for the time: the force ``sin(t) + t_`` read 4.04 at ``t = 2``
    (not 5.91), silently."""
    x, y = me.dynamicsymbols("x y")
    m = sympy.Symbol("m")
    N, O = me.ReferenceFrame("N"), me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    P.set_vel(N, x.diff(t) * N.x + y.diff(t) * N.y)

    def force(name):
        c = sympy.Symbol(name)
        lm = me.LagrangesMethod(m * (x.diff(t) ** 2 + y.diff(t) ** 2) / 2, [x, y], frame=N,
                                forcelist=[(P, (sympy.sin(t) + c) * N.x)], nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            system = liefi.from_mechanics(lm, {m: 1.0, c: 5.0})
        return system.force(2.0, np.array([0.1, 0.2]), np.array([0.0, 0.0]), None)

    for name in ("c", "t_"):
        np.testing.assert_allclose(force(name), [np.sin(2.0) + 5.0, 0.0], rtol=1e-15, err_msg=name)
    with pytest.raises(ValueError, match=r"constants: 't' is the time of sympy.physics.mechanics"):
        force("t")  # sympy's own time symbol (Symbol("t") is dynamicsymbols._t): before, its value was ignored


def test_a_name_holding_dummy_index_text_is_not_renumbered():
    """The fingerprint writes each ``Dummy``'s process-local index as its number of first appearance.  Before: the
    renumbering was a substitution in ``srepr``'s text, which reached into names too: ``Symbol("dummy_index=1")``
    and ``Symbol("dummy_index=2")`` had one encoding (the digest promises that no two values share one)."""
    one, two = sympy.Symbol("dummy_index=1"), sympy.Symbol("dummy_index=2")
    assert _fingerprint.digest(one) != _fingerprint.digest(two)
    a, b = sympy.Dummy("x"), sympy.Dummy("x")
    assert _fingerprint.digest(a + 2 * b) == _fingerprint.digest(sympy.Dummy("x") + 2 * sympy.Dummy("x"))
    assert _fingerprint.digest((a, a)) != _fingerprint.digest((a, b))


def test_names_given_as_one_string_are_refused_not_split_into_letters():
    """Before: ``names="abc"`` named three coordinates ``a``, ``b``, ``c``, silently."""
    x, y, z, xd, yd, zd = sympy.symbols("x y z xd yd zd")
    with pytest.raises(ValueError, match=r"names: expected a sequence of 3 shape-coordinate names, got the string"):
        liefi.from_sympy((xd**2 + yd**2 + zd**2) / 2, [x, y, z], [xd, yd, zd], [xd - z * yd], names="abc")


def test_a_model_named_like_liefis_own_variables_is_the_same_model():
    """Coordinates named ``x0``, ``v0`` (liefi's plain symbols for q and qdot are ``Dummy("x0")``, ``Dummy("v0")``),
    constants named ``a0``, ``t1`` (the generated code's arguments and nodes), ``__builtins__``: the same numbers as
    plain names, in values and in the compiled kernel's source."""
    from liefi.engine import kernels

    def build(qn, cn):
        x, y = me.dynamicsymbols(qn)
        m, k, b = sympy.symbols(cn)
        L = m * (x.diff(t) ** 2 + y.diff(t) ** 2) / 2 - k * sympy.cos(x) * b - k * y**2 / 2
        lm = me.LagrangesMethod(L, [x, y], nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
        return liefi.from_mechanics(lm, {m: 1.5, k: 2.0, b: 0.5})

    plain, odd = build("q r", "m n o"), build("x0 v0", "a0 t1 __builtins__")
    z = np.array([0.3, -0.2, 0.4, 0.1])
    np.testing.assert_allclose(odd.hamiltonian(z), plain.hamiltonian(z), rtol=1e-15)
    np.testing.assert_allclose(odd.constraints(z[:2]), plain.constraints(z[:2]), rtol=1e-15)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        texts = [kernels.compile_feedback(liefi.FeedbackIntegrator(s, z, gains=1.0), engine="python").kernel.text
                 for s in (plain, odd)]
    assert texts[0] == texts[1]
