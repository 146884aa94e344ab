"""Sensitivities of a forced run with respect to its control values (liefi.integrator._forced_sensitivity)."""

import numpy as np
import pytest

import liefi
from liefi.scenes.roller_racer import RollerRacer
from liefi.systems.forcing import ForceLaw, piecewise_constant, spline

T, DT, N = 0.6, 0.02, 6


def steering_torque(t, q, v, u):
    """A torque on the steering joint phi (the last velocity of the roller racer)."""
    F = np.zeros(np.broadcast_shapes(v.shape, u.shape[:-1] + (4,)), np.result_type(v, u, float))
    F[..., 3] = u[..., 0]
    return F


def racer(signal, analytic=True, gains=100.0):
    scene = RollerRacer()
    system = scene.build_system(analytic_derivatives=analytic)
    y0 = np.concatenate([np.zeros(3), system.complete_momenta([scene.phi0], scene.momenta0)])
    return liefi.FeedbackIntegrator(system, y0, force=ForceLaw(steering_torque, inputs=("tau",)),
                                    inputs={"tau": signal}, configuration=True, gains=gains)


def make(kind, values):
    # piecewise constant: N intervals of [0, T]; spline: N nodes spanning [0, T] (no extrapolation past them)
    if kind == "piecewise":
        return piecewise_constant(np.linspace(0.0, T, N + 1), values)
    return spline(np.linspace(0.0, T, N), values)


@pytest.mark.parametrize("kind, scheme, gains", [("piecewise", "imex-rk4", 100.0), ("spline", "imex-rk4", 100.0),
                                                 ("spline", "rk4", 10.0), ("piecewise", "imex-rk4", "auto")])
def test_forced_sensitivities_match_whole_run_differences(kind, scheme, gains):
    """d y(t) / d tau_j of the run (the split scheme's feedback step, the explicit feedback field, the gains that
    "auto" chose held), against 4th-order central differences of whole runs along a random combination of the
    N directions: 1e-10 relative."""
    vals = 0.4 * np.cos(np.arange(N))
    sol = racer(make(kind, vals), gains=gains).run(T, dt=DT, scheme=scheme, sensitivities=("tau",))
    S = sol.sensitivities["tau"]
    assert S.shape == (10, N, sol.t.size)
    assert np.all(S[..., 0] == 0) and np.all(S[-1] == 0)  # y0 and the clock do not move
    w = np.random.default_rng(1).normal(size=N)
    held = gains if gains != "auto" else {"J_2": 1.0, **sol.stability.gains}  # "auto"'s choice (J_2 is kept exactly)

    def y(e):
        return racer(make(kind, vals + e * w), gains=held).run(T, dt=DT, scheme=scheme).y

    e = 2e-3
    fd = (8 * (y(e) - y(-e)) - (y(2 * e) - y(-2 * e))) / (12 * e)
    jvp = np.einsum("ijk,j->ik", S, w)
    assert np.abs(jvp).max() > 0.1  # the torque steers the racer
    assert np.abs(jvp - fd).max() <= 1e-10 * np.abs(jvp).max()


def test_forced_sensitivities_named_errors():
    fi = racer(make("piecewise", np.zeros(N)))
    with pytest.raises(ValueError, match=r"\['m'\] are neither inputs of this forced run nor 'y0' nor constants"):
        fi.run(T, dt=DT, scheme="imex-rk4", sensitivities=("m",))
    with pytest.raises(ValueError, match="give the step"):
        fi.run(T, scheme="imex-rk4", sensitivities=("tau",))
    callable_input = racer(lambda t: 0.1 * t)
    with pytest.raises(ValueError, match="piecewise_constant or spline"):
        callable_input.run(T, dt=DT, scheme="imex-rk4", sensitivities=("tau",))


def test_data_without_analytic_derivatives_get_an_eighth_order_difference_inside_the_replay():
    """The racer's constraints differentiated by the field's own complex step: inside the complex replay their
    derivative is an 8th-order central difference, and the sensitivities equal those of the racer with analytic
    derivatives to 1e-11 relative; the data are restored after."""
    sig = make("piecewise", 0.4 * np.cos(np.arange(N)))
    numeric = racer(sig, analytic=False)
    S = numeric.run(T, dt=DT, scheme="imex-rk4", sensitivities=("tau", "y0")).sensitivities
    ref = racer(sig).run(T, dt=DT, scheme="imex-rk4", sensitivities=("tau", "y0")).sensitivities
    for name in ("tau", "y0"):
        assert np.abs(S[name] - ref[name]).max() <= 1e-11 * np.abs(ref[name]).max(), name
    assert numeric.system.constraints._derivative is None


def test_forced_sensitivities_to_the_start_match_whole_run_differences():
    """d y / d y0 of a forced roller racer (gains held, the balance's target taken at the start and moving with
    it, as an integrator built at the moved start takes it): shape (n, n, n_t), the identity at t = 0, and
    against 4th-order central differences of whole runs along a random direction: 1e-10 relative. (No
    invariant is left out of V here: a run leaves out those kept exactly on the invariant set, J_2 of the
    racer, and the sensitivities hold that choice, as they hold the gains; a moved start off J_2 = 0 would
    keep it in V.)"""
    vals = 0.4 * np.cos(np.arange(N))
    fi = racer(make("piecewise", vals))
    sol = fi.run(T, dt=DT, scheme="imex-rk4", sensitivities=("y0",), drop_exact=False)
    S = sol.sensitivities["y0"]
    assert S.shape == (10, 10, sol.t.size)
    np.testing.assert_array_equal(S[..., 0], np.eye(10))
    w = np.random.default_rng(2).normal(size=10)
    w[-1] = 0.0  # the clock starts at the span's start (its column: the inputs' timing)
    y0 = fi.y0.copy()

    def y(e):
        moved = liefi.FeedbackIntegrator(fi.system, y0 + e * w, force=fi.force_law, inputs=fi.signals,
                                         configuration=True, gains=100.0)
        return moved.run(T, dt=DT, scheme="imex-rk4", drop_exact=False).y

    e = 2.5e-4  # the differences' truncation e^4: 3.6e-10 relative at 1e-3, 2.4e-12 here
    fd = (8 * (y(e) - y(-e)) - (y(2 * e) - y(-2 * e))) / (12 * e)
    jvp = np.einsum("ijk,j->ik", S, w)
    assert np.abs(jvp - fd).max() <= 1e-10 * np.abs(jvp).max()


def sleigh_model():
    """A Chaplygin sleigh from sympy (LagrangesMethod, the blade's nonholonomic constraint), pushed by a
    torque ``tau(t)`` (a specified input) and slowed by a damper ``-c v_P`` at the blade."""
    sympy = pytest.importorskip("sympy")
    me = pytest.importorskip("sympy.physics.mechanics")
    x, y, th, tau = me.dynamicsymbols("x y th tau")
    m, I, a, c = sympy.symbols("m I a c")
    Nf = me.ReferenceFrame("N")
    B = Nf.orientnew("B", "Axis", [th, Nf.z])
    O = me.Point("O")
    P = O.locatenew("P", x * Nf.x + y * Nf.y)
    C = P.locatenew("C", a * B.x)
    P.set_vel(Nf, P.pos_from(O).dt(Nf))
    C.set_vel(Nf, C.pos_from(O).dt(Nf))
    B.set_ang_vel(Nf, th.diff() * Nf.z)
    body = me.RigidBody("body", C, B, m, (me.inertia(B, 0, 0, I), C))
    model = me.LagrangesMethod(me.Lagrangian(Nf, body), [x, y, th], nonhol_coneqs=[P.vel(Nf).dot(B.y)],
                               forcelist=[(B, tau * Nf.z), (P, -c * P.vel(Nf))], frame=Nf)
    model.form_lagranges_equations()
    return liefi.from_mechanics(model, {m: 2.0, I: 0.3, a: 0.4, c: 0.5})


def test_forced_from_mechanics_sensitivities_to_the_start_and_the_constants_match_whole_run_differences():
    """A forced from_mechanics model (its data lambdified: no analytic derivatives), a piecewise-constant torque:
    d y / d y0 ((n, n, n_t)) and d y / d m, d y / d c ((n, n_t); c is the damper's, read by the force) against
    4th-order central differences of whole runs (the targets taken at the moved start or with the moved
    constant, as a new integrator takes them): 1e-10 relative."""
    s = sleigh_model()
    assert s.force.inputs == ("tau",) and set(s.constant_names) == {"m", "I", "a", "c"}
    th0, v0, w0 = 0.3, 0.5, 0.4
    start = s.state([0.0, 0.0, th0], [v0 * np.cos(th0), v0 * np.sin(th0), w0])
    tau = piecewise_constant(np.linspace(0.0, 0.3, 5), [0.3, -0.2, 0.5, 0.1])  # switches every 3 steps
    run = dict(dt=0.025, scheme="imex-rk4", drop_exact=False)  # no invariant left out of V (see above)

    def build(y0=start, **consts):
        s.constants = {"m": 2.0, "I": 0.3, "a": 0.4, "c": 0.5, **consts}
        return liefi.FeedbackIntegrator(s, y0, inputs={"tau": tau}, gains=1e6)

    fi = build()
    sol = fi.run(0.3, sensitivities=("y0", "m", "c"), **run)
    n = fi.n
    S = sol.sensitivities
    assert S["y0"].shape == (n, n, sol.t.size) and S["m"].shape == S["c"].shape == (n, sol.t.size)
    inv = fi.invariant_values(sol.y.T)
    assert np.abs(inv["J_1"]).max() < 1e-12 and np.ptp(inv["energy"]) < 1e-12 and np.ptp(inv["W"]) > 1e-3
    w = np.random.default_rng(3).normal(size=n)
    w[-1] = 0.0
    full = fi.y0.copy()

    def central(moved, e):
        return (8 * (moved(e) - moved(-e)) - (moved(2 * e) - moved(-2 * e))) / (12 * e)

    checks = [(np.einsum("ijk,j->ik", S["y0"], w), central(lambda e: build(full + e * w).run(0.3, **run).y, 1e-3))]
    for name, value in (("m", 2.0), ("c", 0.5)):
        checks.append((S[name], central(lambda e: build(**{name: value + e}).run(0.3, **run).y, 1e-3)))
    build()
    for got, fd in checks:
        assert np.abs(fd).max() > 1e-3
        assert np.abs(got - fd).max() <= 1e-10 * np.abs(got).max()
