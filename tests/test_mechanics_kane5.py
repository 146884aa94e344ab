"""sympy's own rolling disc test model (``sympy/physics/mechanics/tests/test_kane5.py``), handed over as written.

Its ``KanesMethod`` (``constraint_solver='LU'``, implicit kinematics) holds the velocity constraints with sympy's
symbolic LU solution of the kinematic equations substituted: ``k_nh`` divides by ``sin q3`` (``0/0`` at the
upright ``q = 0``, an ordinary configuration).  liefi clears the rows' denominators
(``liefi.systems._kinematics._regular_rows``), so the model builds by one call and its field is finite at the
upright.  The reference there is the same disc with sympy's kinematics simplified (the test's
``kd_eqs_solver=lambda A, b: simplify(A.LUsolve(b))``), whose own equations are regular at ``q = 0``; at a generic
point both models' own equations are the reference.
"""

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")
kane5 = pytest.importorskip("sympy.physics.mechanics.tests.test_kane5")

import liefi  # noqa: E402
import own_equations as OE  # noqa: E402

G, R, M = sympy.symbols("g r m")
CONSTANTS = {G: 9.81, R: 0.26, M: 3.43}
GENERIC = [0.3, 0.1, 1.97, -0.35, 2.27]
U_IND = [-0.2, 1.3, 0.15]  # rolling, leaning and spinning


def _disc(simplified=False):
    """The model exactly as sympy's test builds it (LU), or with the simplified kinematics."""
    props = kane5._create_rolling_disc()
    how = dict(kd_eqs_solver=lambda A, b: sympy.simplify(A.LUsolve(b))) if simplified else dict(constraint_solver="LU")
    kane = me.KanesMethod(props["frame"], props["q_ind"], props["u_ind"], props["kdes"], u_dependent=props["u_dep"],
                          velocity_constraints=props["fnh"], bodies=props["bodies"], forcelist=props["loads"],
                          explicit_kinematics=False, **how)
    kane.kanes_equations()
    return kane


@pytest.fixture(scope="module")
def built():
    kane = _disc()
    return kane, liefi.from_mechanics(kane, CONSTANTS)  # one call: no sample=


#: the 8th-order central difference of a first derivative (rounding ~1e-13 at h = 1e-3, truncation ~h^8)
STENCIL = {1: 4 / 5, 2: -1 / 5, 3: 4 / 105, 4: -1 / 280}


def _liefi_rates(system, q):
    """``(q', u_ind')`` of liefi's constrained field at ``(q, U_IND)``: ``u'`` as the derivative of
    ``generalized_speeds`` along the field (a directional derivative, exact up to the stencil's error)."""
    z = system.state(np.asarray(q, float), u=U_IND)
    zd = system.constrained_vector_field(z)
    h = 1e-3

    def u(s):
        speeds = system.generalized_speeds(z + s * zd)
        return np.array([speeds[name] for name in ("u1", "u2", "u3")])
    ud = sum(c * (u(k * h) - u(-k * h)) for k, c in STENCIL.items()) / h
    return z, np.concatenate([zd[:5], ud])


def _own_rates(kane, system, z, q):
    own = OE.Own(kane, CONSTANTS, q)
    return own.rates(np.concatenate([q, U_IND]))


@pytest.mark.parametrize("q", [np.zeros(5), np.full(5, 1e-9), np.array(GENERIC)], ids=["upright", "1e-9", "generic"])
def test_the_rolling_disc_of_sympys_test_builds_and_its_field_is_its_own_equations(built, q):
    kane, system = built
    z, mine = _liefi_rates(system, q)
    assert np.all(np.isfinite(z)) and np.all(np.isfinite(mine))
    refs = [_own_rates(_disc(simplified=True), system, z, q)]
    if q[2] != 0:  # the model's own equations as sympy forms them: 0/0 at q3 = 0, inexact near it
        refs.append(_own_rates(kane, system, z, q)) if abs(q[2]) > 1e-3 else None
    for ref in refs:
        assert np.max(np.abs(mine - ref)) <= 1e-12 * max(1.0, np.max(np.abs(ref))), (mine, ref)


@pytest.mark.slow
@pytest.mark.parametrize("start", ["upright", "generic"])
def test_the_rolling_disc_of_sympys_test_runs_as_its_own_equations(built, start):
    kane, system = built
    model, q0 = (_disc(simplified=True), np.zeros(5)) if start == "upright" else (kane, np.array(GENERIC))
    out = OE.compare(model, CONSTANTS, system, q0, U_IND)
    assert out["error"] <= 1e-8, out
    assert max(out["f"], out["velocity"]) <= 1e-12, out
    assert out["energy"] <= 1e-12, out


def test_a_datum_that_is_not_finite_at_the_checked_configuration_is_refused_saying_what_to_do():
    """The refusal the disc met before (``constraints: non-finite values at x = [0 0 0 0 0]``) says what to do."""
    def rows(x):  # the row (cos(x1) / sin(x1), 1): 0/0-like at x = 0
        x = np.asarray(x)
        with np.errstate(divide="ignore"):
            return np.stack([np.cos(x[..., 0]) / np.sin(x[..., 0]), np.ones(x.shape[:-1])], -1)[..., None, :]

    with pytest.raises(ValueError, match=r"constraints: non-finite values at x = .*pass sample= an ordinary "
                                         r"configuration.*write the datum without that division"):
        liefi.NonholonomicSystem(liefi.CotangentBundle(2), np.eye(2), rows)
    liefi.NonholonomicSystem(liefi.CotangentBundle(2), np.eye(2), rows, sample=[0.5, 0.0])  # the advice holds


def test_rows_singular_at_the_zero_configuration_are_cleared_and_the_others_kept_as_they_are():
    from liefi.systems._kinematics import _regular_rows

    q1, q2, u1, u2 = me.dynamicsymbols("q1 q2 u1 u2")
    rows = [u1 * sympy.cot(q1) + u2, u1 * sympy.cos(q1) / (sympy.sin(q1) + sympy.cos(q1) ** 2 / sympy.sin(q1)) + u2,
            u1 / sympy.cos(q1) + u2, u1 * sympy.tan(q2) + u2]
    out = _regular_rows(sympy, rows, [q1, q2])
    at0 = {q1: 0, q2: 0}
    for new, old in zip(out[:2], rows[:2]):  # the same constraint (the row times a function of q), finite at q = 0
        assert not new.xreplace(at0).has(sympy.zoo, sympy.nan) and new.xreplace(at0) != 0
        c, d = ([e.diff(s) for s in (u1, u2)] for e in (new, old))
        assert sympy.simplify(c[0] * d[1] - c[1] * d[0]) == 0  # proportional coefficients
    assert sympy.simplify(out[0] - rows[0] * sympy.sin(q1)) == 0
    assert out[2] is rows[2] and out[3] is rows[3]  # regular at q = 0: kept (bit-identical data)
