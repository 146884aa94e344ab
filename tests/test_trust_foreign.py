"""Foreign code, faults and signals (issue 23): liefi runs no code it did not write, and ends as told.

* Names from a sympy model never become code: an undefined ``Function`` whose name is Python
  code is refused by name (before, ``lambdify`` wrote it into the generated source and it ran),
  a bound variable with such a name is renamed; marker files prove that nothing ran.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")

import liefi  # noqa: E402


def _code(marker):
    """A name that is Python code creating ``marker`` when it runs (and evaluating to 1.0)."""
    return f"(lambda *a: __import__('pathlib').Path({str(marker)!r}).touch() or 1.0)"


def _plane(q1, q2, v1, v2):
    return (v1**2 + v2**2) / 2, [v1 - q1 * v2]


@pytest.mark.parametrize("where", ["L", "constraints"])
def test_from_sympy_refuses_an_undefined_function_whose_name_is_code(tmp_path, where):
    marker = tmp_path / "ran"
    f = sympy.Function(_code(marker))
    q1, q2, v1, v2 = sympy.symbols("q1 q2 v1 v2")
    T, cons = _plane(q1, q2, v1, v2)
    L = T - f(q1) if where == "L" else T
    if where == "constraints":
        cons = [v1 - f(q1) * v2]
    with pytest.raises(ValueError, match=r"undefined function .*__import__") as info:
        liefi.from_sympy(L, [q1, q2], [v1, v2], cons)
    assert str(info.value).startswith(where)
    assert not marker.exists(), "code from a sympy Function's name ran"


def test_from_mechanics_refuses_an_undefined_function_whose_name_is_code(tmp_path):
    marker = tmp_path / "ran"
    f = sympy.Function(_code(marker))
    x, y = me.dynamicsymbols("x y")
    t = me.dynamicsymbols._t
    lm = me.LagrangesMethod((x.diff(t) ** 2 + y.diff(t) ** 2) / 2 - f(x), [x, y],
                            nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
    with pytest.raises(ValueError, match="undefined function"):
        liefi.from_mechanics(lm)
    assert not marker.exists(), "code from a sympy Function's name ran"


def test_from_mechanics_refuses_code_in_a_given_potential(tmp_path):
    """``potential=`` goes through the loads' power check (its own generated code) first."""
    marker = tmp_path / "ran"
    f = sympy.Function(_code(marker))
    x, y = me.dynamicsymbols("x y")
    m, g = sympy.symbols("m g")
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    O.set_vel(N, 0)
    P = O.locatenew("P", x * N.x + y * N.y)
    P.set_vel(N, P.pos_from(O).dt(N))
    t = me.dynamicsymbols._t
    lm = me.LagrangesMethod(m * (x.diff(t) ** 2 + y.diff(t) ** 2) / 2, [x, y], forcelist=[(P, -m * g * N.y)],
                            frame=N, nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
    with pytest.raises(ValueError, match="potential: contains the undefined function"):
        liefi.from_mechanics(lm, constants={m: 1.0, g: 9.81}, potential=m * g * y + f(x))
    assert not marker.exists(), "code from a sympy Function's name ran"


def test_a_bound_symbol_whose_name_is_code_is_renamed(tmp_path):
    """A ``Sum``'s index is printed into the generated code by name: before, this one closed the
    expression and ran its own (the potential read 0); now it is renamed and the sum is right."""
    marker = tmp_path / "ran"
    k = sympy.Symbol(f"k for k in range(3)) if __import__('pathlib').Path({str(marker)!r}).touch() else 0)] #",
                     integer=True)
    q1, q2, v1, v2 = sympy.symbols("q1 q2 v1 v2")
    T, cons = _plane(q1, q2, v1, v2)
    sys_ = liefi.from_sympy(T - sympy.Sum(q1**k, (k, 0, 2)), [q1, q2], [v1, v2], cons)
    x = np.array([[0.5, 0.0, 0.0, 0.0], [2.0, 1.0, 0.0, 0.0]])
    np.testing.assert_allclose(sys_.potential(x), 1 + x[:, 0] + x[:, 0] ** 2, rtol=1e-15)
    assert not marker.exists(), "code from a sympy Symbol's name ran"


def test_a_parameter_whose_name_is_code_is_a_constant_like_any_other(tmp_path):
    marker = tmp_path / "ran"
    m = sympy.Symbol(f"m) or __import__('pathlib').Path({str(marker)!r}).touch() or (m")
    x, y = me.dynamicsymbols("x y")
    t = me.dynamicsymbols._t
    lm = me.LagrangesMethod(m * (x.diff(t) ** 2 + y.diff(t) ** 2) / 2 - m * x**2, [x, y],
                            nonhol_coneqs=[x.diff(t) - y * y.diff(t)])
    sys_ = liefi.from_mechanics(lm, constants={m: 2.0})
    np.testing.assert_allclose(sys_.potential(np.array([0.5, 0.0, 0.0, 0.0])), 2.0 * 0.25, rtol=1e-15)
    assert not marker.exists(), "code from a sympy Symbol's name ran"


def test_checked_names_refuses_other_names_that_are_not_identifiers():
    from liefi.sympy_input import checked_names, plain_identifier

    assert plain_identifier("theta_1") and not plain_identifier("__import__") and not plain_identifier("a b")
    assert not plain_identifier("lambda") and not plain_identifier("θ")
    A = sympy.MatrixSymbol("A; import os", 2, 2)
    with pytest.raises(ValueError, match=r"metric: contains a MatrixSymbol named 'A; import os'"):
        checked_names(sympy, A[0, 0] + 1, "metric")


# --------------------------------------------------------------------------------------
# liefi run --scheme scipy:METHOD
# --------------------------------------------------------------------------------------
def test_liefi_run_scipy_method_reports_its_method(capsys):
    import json

    from liefi import cli

    code = cli.main(["run", "suslov", "--scheme", "scipy:RK45", "--t-final", "0.2", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    got = json.loads(out)
    assert got["backend"] == "scipy" and got["method"]["scheme"] == "scipy:RK45"
    assert got["method"]["rtol"] == 1e-9 and got["method"]["dt"] is None and "adaptive" in got["method"]["why"]
    assert max(got["max_error"].values()) < 1e-6


@pytest.mark.parametrize("flag, value", [("--atol", "-1"), ("--rtol", "1e-20"), ("--rtol", "2")])
def test_liefi_run_scipy_bad_tolerance_is_refused_before_integrating(capsys, monkeypatch, flag, value):
    from liefi import cli
    from liefi.schemes import ivp

    def never(*a, **k):
        raise AssertionError("solve_ivp was called with a bad tolerance")

    monkeypatch.setattr(ivp.ScipyMethod, "solve", never)
    code = cli.main(["run", "suslov", "--scheme", "scipy:RK45", "--t-final", "1", flag, value])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"liefi: error: {flag[2:]}:"), err
    assert len(err.strip().splitlines()) == 1


def test_scipy_run_past_its_evaluation_budget_stops_early_and_says_so():
    """The projection from the pace stops a run that would take 1e6 evaluations after a few thousand."""
    from liefi.schemes import registry
    from liefi.schemes.ivp import EvaluationBudgetError

    calls = []

    def osc(t, y):
        calls.append(t)
        return np.array([y[1], -y[0]])

    rk23 = registry.get("scipy:RK23")
    with pytest.raises(EvaluationBudgetError, match=r"scipy:RK23 at rtol 1e-13 would need about .* evaluations"):
        rk23.solve(osc, 1000.0, [1.0, 0.0], rtol=1e-13, atol=1e-13, max_evaluations=1e5)
    assert len(calls) < 1e4  # stopped from the projection, long before the budget itself
    sol, _ = rk23.solve(osc, 1.0, [1.0, 0.0], rtol=1e-6, atol=1e-9, max_evaluations=1e5)  # within it: unchanged
    ref, _ = rk23.solve(osc, 1.0, [1.0, 0.0], rtol=1e-6, atol=1e-9)
    assert sol.success and np.array_equal(sol.y, ref.y)


def test_liefi_run_scipy_evaluation_guard_is_one_line(capsys, monkeypatch):
    import liefi.run
    from liefi import cli

    monkeypatch.setattr(liefi.run, "IVP_MAX_EVALUATIONS", 1000)
    code = cli.main(["run", "suslov", "--scheme", "scipy:RK23", "--rtol", "1e-13", "--t-final", "50"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("liefi: error: scheme: scipy:RK23 at rtol 1e-13 would need about"), err
    assert len(err.strip().splitlines()) == 1


# --------------------------------------------------------------------------------------
# --out proven writable before the run
# --------------------------------------------------------------------------------------
@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")
def test_out_in_proc_is_refused_before_the_run(capsys, monkeypatch):
    """``os.access`` says yes to root for ``/proc``; the check now opens the file itself."""
    from liefi import cli, scenes

    def never(self, **kw):
        raise AssertionError("the run started although --out cannot be written")

    monkeypatch.setattr(scenes.Scene, "run", never)
    code = cli.main(["run", "suslov", "--t-final", "1", "--out", "/proc/x.png"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("liefi: error: out: cannot write '/proc/x.png'"), err
    assert len(err.strip().splitlines()) == 1


def test_probe_writable_leaves_no_trace(tmp_path):
    from liefi._files import probe_writable

    old = tmp_path / "old.png"
    old.write_bytes(b"kept")
    assert probe_writable(str(old)) is None and old.read_bytes() == b"kept"
    new = tmp_path / "new.png"
    assert probe_writable(str(new)) is None and not new.exists()
    assert probe_writable(str(tmp_path / "missing" / "x.png"))  # a reason, not None
