"""The fixed costs of a ``from_mechanics`` build (issue 25, build time), asserted by structure, not by timing.

* the build's checks (:func:`liefi.systems._kinematics._restore`, ``_Checks``) walk the model's own
  expressions in ``q(t)``, ``q'(t)``, ``u(t)``: no copy in plain symbols is formed (an ``xreplace`` that re-forms
  every node and asks sympy's assumptions anew: a fifth of the Kane pendulum's build);
* the complex-step probes of a datum (``DataFunction.check_differentiable``) run as one batch;
* a configuration constraint holding a rate is refused by name (the test for it looked for ``q'`` in the
  expression after ``q`` had been replaced, so it never fired).
"""

import numpy as np
import pytest

import liefi
from liefi._data import N_PROBES, DataFunction

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")


def _record_args(monkeypatch):
    """The argument lists the build's evaluators (``evaluator``, ``directional``) are made with."""
    from liefi.systems import _kinematics

    seen = []
    for name in ("evaluator", "directional"):
        original = getattr(_kinematics, name)

        def recording(sympy_, args, *rest, _original=original, **kw):
            seen.append(list(args))
            return _original(sympy_, args, *rest, **kw)

        monkeypatch.setattr(_kinematics, name, recording)
    return seen


@pytest.mark.parametrize("case", ["kane_pendulum", "sleigh_minimal"])
def test_the_checks_walk_the_models_own_symbols(monkeypatch, case):
    """Was: every check's expressions copied into ``Dummy`` symbols first (the Kane pendulum's ``_restore`` 11 ms of
    its 48 ms build, now 7 ms)."""
    import test_mechanics_holonomic as H
    import test_mechanics_minimal as M

    made = getattr(H if case == "kane_pendulum" else M, case)()
    model, constants = (made["model"], made["constants"]) if isinstance(made, dict) else made[:2]
    seen = _record_args(monkeypatch)
    liefi.from_mechanics(model, constants)
    assert seen, "the checks made no evaluator"
    dummies = [a for args in seen for a in args if isinstance(a, sympy.Dummy)]
    assert dummies == []
    q = set(model.q)
    assert all(q <= set(args) for args in seen if len(args) > len(q))  # the model's own coordinates


def test_evaluator_takes_dynamicsymbols_and_their_rates():
    """``evaluator`` and ``directional`` with ``q(t)``, ``q'(t)``, ``u(t)`` as arguments agree with ``lambdify`` /
    ``diff`` on the same expressions in plain symbols, on the walk and on the fallback (a node the walk does not
    know: ``floor``, ``sinc``)."""
    from liefi.systems._evaluate import directional, evaluator

    t = me.dynamicsymbols._t
    q1, q2, u = me.dynamicsymbols("q1 q2 u")
    a = sympy.Symbol("a")
    args = [q1, q2, q1.diff(t), q2.diff(t), u, a]
    exprs = [sympy.sin(q1) * q2.diff(t) + a * u ** 2, sympy.sqrt(1 + q2 ** 2) * q1.diff(t) / (2 + sympy.cos(q1)),
             sympy.floor(3 * q1) + q2]
    X = [sympy.Dummy() for _ in args]
    plain = [e.xreplace(dict(zip(args, X))) for e in exprs]  # q' whole before q (xreplace is top-down)
    rng = np.random.default_rng(1)
    vals = [rng.uniform(0.2, 1.0, 4) for _ in args]
    expected = np.array([sympy.lambdify(X, e, "numpy")(*vals) * np.ones(4) for e in plain])
    for some in (exprs[:2], exprs):  # walked; with floor: the lambdify fallback
        got = evaluator(sympy, args, some, "w")(*vals)
        np.testing.assert_allclose(got, expected[: len(some)], rtol=1e-13)
    dirs = [rng.normal(size=4) for _ in range(2)]
    smooth = [sympy.sin(q1) * q2 ** 2 * a, sympy.sqrt(1 + q1 ** 2 + q2 ** 2)]
    grads = [[sympy.lambdify(X, sympy.diff(e.xreplace(dict(zip(args, X))), X[k]), "numpy")(*vals) * np.ones(4)
              for k in range(2)] for e in smooth]
    for some in (smooth, smooth + [sympy.sinc(q1) * q2]):  # sinc: the walk does not know it (diff, lambdify)
        v, d = directional(sympy, [q1, q2, a], some, [q1, q2], "w")(vals[0], vals[1], vals[5], *dirs)
        np.testing.assert_allclose(d[:2], [g[0] * dirs[0] + g[1] * dirs[1] for g in grads], rtol=1e-12)
        assert np.asarray(v).shape == (len(some), 4)
    with pytest.raises(ValueError, match="w: depends on"):  # a free time is still named (lambdify's error)
        evaluator(sympy, [q1], [q1 + t], "w")(vals[0])


def _counting(fun):
    calls = []

    def counted(x):
        calls.append(np.shape(x))
        return fun(x)

    return counted, calls


def test_the_probes_run_as_one_batch():
    """Was ``3 + 3 N_PROBES`` calls of the datum (the complex step and the two differences at each probe point
    separately), now ``3 + 3``: the probes are one batch."""
    fun, calls = _counting(lambda x: np.stack([np.sin(x[..., 0]) * x[..., 1], np.cos(x[..., 1])], -1))
    datum = DataFunction(fun, (2,), 2, "f")
    calls.clear()
    datum.check_differentiable(np.array([0.3, -0.2]))
    assert len(calls) == 6
    assert N_PROBES > 1 and any(len(s) >= 2 and s[0] == N_PROBES for s in calls)  # the probes' batch


def test_a_probe_the_datum_raises_at_is_skipped_and_the_others_still_checked():
    """A batch the datum raises on (one probe outside its domain) is probed point by point: the other probes
    still find a dropped imaginary part (``np.real``, whose complex-step derivative vanishes at ``x = 0`` where
    the true one does too, so only the probes see it)."""
    def fun(x):
        if np.any(np.real(x[..., 0]) > 0.2):
            raise ValueError("outside the domain")
        return np.cos(np.real(x[..., 0])) + 0 * x[..., 1]

    datum = DataFunction(fun, (), 2, "f")
    rng = np.random.default_rng(20261122)  # the probes' own seed: some inside the domain, some outside
    probes = 0.5 * rng.uniform(-1.0, 1.0, size=(N_PROBES, 2))
    assert np.any(probes[:, 0] > 0.2) and np.any(probes[:, 0] < 0.2 - 1e-6)
    with pytest.raises(ValueError, match="drops the imaginary part"):
        datum.check_differentiable(np.zeros(2))


def test_a_configuration_constraint_with_a_rate_is_refused_by_name():
    """Was: the rate looked for after ``q -> x`` (where it is ``Derivative(x, t)``), never found; the build then
    failed in numpy's printer (``Printer has no method: _print_Derivative_Dummy``)."""
    q1, q2, u1, u2 = me.dynamicsymbols("q1 q2 u1 u2")
    L, m, g = sympy.symbols("L m g")
    N = me.ReferenceFrame("N")
    O = me.Point("O")  # noqa: E741
    O.set_vel(N, 0)
    P = O.locatenew("P", q1 * N.x + q2 * N.y)
    P.set_vel(N, u1 * N.x + u2 * N.y)
    KM = me.KanesMethod(N, q_ind=[q2], u_ind=[u2], q_dependent=[q1], u_dependent=[u1],
                        configuration_constraints=[q1 ** 2 + q2 ** 2 - L ** 2 + q1.diff()],
                        velocity_constraints=[q1 * u1 + q2 * u2], kd_eqs=[q1.diff() - u1, q2.diff() - u2])
    KM.kanes_equations([me.Particle("p", P, m)], [(P, m * g * N.x)])
    with pytest.raises(ValueError, match="configuration constraints .* hold velocities"):
        liefi.from_mechanics(KM, {L: 1.0, m: 1.0, g: 9.81})
