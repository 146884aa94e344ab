"""Inputs: external forces and controls (issue 28).

A force ``F(t, q, v; u)`` enters the field once (:func:`liefi.reduction.core.field_terms`), the state
gains the work ``W`` (and the clock), and the feedback holds the energy balance ``h~ - W`` and every
constraint; ``from_mechanics`` turns dampers, torques, sympy's actuators and specified inputs ``F(t)``
into such a force; ``linearize`` gains ``B``.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import liefi
from liefi.scenes.chaplygin import Chaplygin
from liefi.scenes.knife_edge import KnifeEdge
from liefi.systems.forcing import ForceLaw, piecewise_constant, spline

RUN = dict(dt=1e-2, scheme="imex-rk4", backend="numpy")


def knife_force(c=0.3):
    """A torque ``tau`` on ``phi`` (the input) and a linear damper ``-c v`` on the knife's translation."""
    def force(t, q, v, u):
        F = np.zeros(np.broadcast_shapes(np.shape(v), np.shape(u)[:-1] + (3,)), np.result_type(v, u, float))
        F[..., 0], F[..., 1], F[..., 2] = -c * v[..., 0], -c * v[..., 1], u[..., 0]
        return F
    return ForceLaw(force, inputs=("tau",))


def held(fi, sol):
    """The largest drift of the energy balance and of every constraint over the run."""
    inv = fi.invariant_values(np.moveaxis(sol.y, -1, 0))
    J = max((np.max(np.abs(v)) for k, v in inv.items() if k.startswith("J_")), default=0.0)
    return np.max(np.abs(inv["energy"] - inv["energy"][0])), J, inv


@pytest.mark.parametrize("signal", ["spline", "callable"])
def test_knife_edge_under_a_torque_and_a_damper_holds_the_energy_balance_and_the_constraint(signal):
    scene = KnifeEdge()
    system, z0 = scene.build_system(), scene.initial_state(None)
    tau = lambda t: 1.0 + t - 0.5 * t**2  # noqa: E731 -- a quadratic: RK4 integrates p_phi' = tau exactly
    nodes = np.linspace(0.0, 1.0, 11)
    sig = spline(nodes, tau(nodes)) if signal == "spline" else tau
    fi = liefi.FeedbackIntegrator(system, z0, force=knife_force(), inputs={"tau": sig})
    assert fi.names[-2:] == ("W", "time")
    sol = fi.run(1.0, **RUN)
    dE, J, inv = held(fi, sol)
    assert dE < 1e-12 and J < 1e-12, (dE, J)
    h = inv["h"]
    assert abs(h[-1] - h[0]) > 0.1  # work was done: h itself is not conserved, h - W is
    np.testing.assert_allclose(sol["time"], sol.t, rtol=0, atol=1e-14)
    # p_phi' = tau on the constraint set (the damper acts along the knife): p_phi(1) = p_phi(0) + int tau,
    # which RK4 integrates exactly; what is left is the feedback's energy correction along dh~ (RK4's
    # truncation of the translation, 4e-12)
    want = scene.p_phi0 + 1.0 + 0.5 - 1.0 / 6.0
    assert abs(sol["p_phi"][-1] - want) < 1e-10, sol["p_phi"][-1] - want


def test_chaplygin_sleigh_driven_by_a_torque_holds_the_balance_and_the_constraint():
    scene = Chaplygin()
    system, y0 = scene.build_system(), scene.initial_state(None)
    law = ForceLaw(lambda t, q, v, u: np.stack([u[..., 0], 0 * u[..., 0], 0 * u[..., 0]], -1), inputs=("tau",))
    nodes = np.linspace(0.0, 1.0, 6)
    fi = liefi.FeedbackIntegrator(system, y0, force=law, inputs={"tau": spline(nodes, [0.5, -1.0, 2.0, 0.0, 1.0, 1.5])})
    assert fi.configuration and fi.n == 3 + 3 + 2
    sol = fi.run(1.0, **RUN)
    dE, J, inv = held(fi, sol)
    assert dE < 1e-12 and J < 1e-12, (dE, J)
    assert np.ptp(inv["W"]) > 0.1
    # the torque spins the sleigh: without it the heading rate's history differs
    free = liefi.FeedbackIntegrator(system, y0).run(1.0, **RUN)
    assert abs(free["Pi_theta"][-1] - sol["Pi_theta"][-1]) > 0.1


def sleigh_with(tau):
    scene = Chaplygin()
    system, y0 = scene.build_system(), scene.initial_state(None)
    law = ForceLaw(lambda t, q, v, u: np.stack([u[..., 0], 0 * u[..., 0], 0 * u[..., 0]], -1), inputs=("tau",))
    return liefi.FeedbackIntegrator(system, y0, force=law, inputs={"tau": tau})


def test_a_piecewise_constant_torque_is_held_over_whole_steps_across_its_switches():
    """A zero-order hold: every stage of a step reads the value of the interval that contains the step, so a
    switch at a step end is exact. The balance and the constraint stay at rounding across the two switches
    (read per stage, the last stage of the step ending at a switch saw the new value: 1.1e-11), and the run
    equals the three runs with constant torques chained at the switches."""
    tau = piecewise_constant([0.0, 0.3, 0.6, 1.0], [0.5, -1.0, 2.0])
    assert tau(0.29) == 0.5 and tau(0.3) == -1.0 and tau(5.0) == 2.0 and tau(-1.0) == 0.5
    fi = sleigh_with(tau)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # switches on the step grid: no warning
        sol = fi.run(1.0, **RUN)
    dE, J, inv = held(fi, sol)
    assert dE < 1e-14 and J < 1e-14, (dE, J)
    y = fi.y0
    for (a, b), value in zip([(0.0, 0.3), (0.3, 0.6), (0.6, 1.0)], [0.5, -1.0, 2.0]):
        y = sleigh_with(value).run((a, b), y0=y, **RUN).y[:, -1]
    np.testing.assert_allclose(y[:-1], sol.y[:-1, -1], rtol=0, atol=1e-13)


def test_a_switch_between_steps_is_named_in_a_warning_and_acts_at_the_nearest_step_end():
    tau = piecewise_constant([0.0, 0.304, 1.0], [0.5, -1.0])
    with pytest.warns(liefi.integrator.forced.InputGridWarning,
                      match=r"input 'tau' switches at t = 0.304, which is not a step end .*Choose a dt that divides"):
        sol = sleigh_with(tau).run(0.5, **RUN)
    aligned = sleigh_with(piecewise_constant([0.0, 0.3, 1.0], [0.5, -1.0])).run(0.5, **RUN)
    np.testing.assert_array_equal(sol.y, aligned.y)  # the step [0.30, 0.31] held at its midpoint 0.305: -1


def test_a_damped_model_loses_energy_and_holds_h_minus_W():
    scene = KnifeEdge()
    system, z0 = scene.build_system(), scene.initial_state(None)
    z0 = system.complete_momenta(z0[:3], {"p_x": 0.0, "p_phi": 0.5})
    z0 = system.project(np.r_[z0[:3], 0.8, 0.4, 0.5])
    fi = liefi.FeedbackIntegrator(system, z0, force=knife_force(c=2.0), inputs={"tau": 0.0})
    sol = fi.run(1.0, **RUN)
    dE, J, inv = held(fi, sol)
    assert dE < 1e-12 and J < 1e-12, (dE, J)
    assert np.all(np.diff(inv["W"]) < 0)  # a damper only takes energy


# --- from_mechanics: the loads sympy's own equations hold -------------------------------------------------
sympy = pytest.importorskip("sympy")
me = pytest.importorskip("sympy.physics.mechanics")
T_EVAL = np.linspace(0.0, 2.0, 21)


def damped_particle(F_load=True):
    """A particle on a LinearSpring and a LinearDamper from the wall, pushed by a specified input F(t) and a
    load sin(3 t) (System, PrismaticJoint)."""
    t = me.dynamicsymbols._t
    q, u, F = me.dynamicsymbols("q u F")
    m, k, c = sympy.symbols("m k c")
    wall = me.RigidBody("wall")
    system = me.System.from_newtonian(wall)
    bob = me.Particle("bob", mass=m)
    system.add_joints(me.PrismaticJoint("J", wall, bob, q, u))
    path = me.LinearPathway(wall.masscenter, bob.masscenter)
    system.add_actuators(me.LinearSpring(k, path, 1), me.LinearDamper(c, path))
    if F_load:
        system.add_loads((bob.masscenter, (F + sympy.sin(3 * t) / 5) * wall.frame.x))
    return system, {m: 1.5, k: 2.0, c: 0.3}, F, (q, u)


def driven_pendulum():
    """A pendulum (gravity) with a TorqueActuator ``tau(t) - b u`` at its pin (System, PinJoint)."""
    q, u, tau = me.dynamicsymbols("q u tau")
    m, g, l, b = sympy.symbols("m g l b")
    wall = me.RigidBody("wall")
    system = me.System.from_newtonian(wall)
    rod = me.RigidBody("rod", mass=m)
    rod.central_inertia = me.inertia(rod.frame, 0, 0, sympy.Rational(1, 10))
    system.add_joints(me.PinJoint("P", wall, rod, q, u, child_point=-l * rod.frame.x, joint_axis=wall.frame.z))
    system.add_loads(me.Force(rod.masscenter, -m * g * wall.frame.y))
    system.add_actuators(me.TorqueActuator(tau - b * u, wall.frame.z, rod.frame, wall.frame))
    return system, {m: 1.0, g: 9.81, l: 0.5, b: 0.2}, tau, (q, u)


def sympy_run(system, consts, specified, value, q0):
    """sympy's own equations ``mass_matrix_full x' = forcing_full``, the input ``specified`` replaced by the sympy
    expression ``value`` of ``t``, by DOP853 at rtol = atol = 1e-12 (``own_equations.own_trajectory``)."""
    import own_equations as OE

    system.form_eoms()
    own = OE.Own(system, consts, [q0], inputs={str(specified.func): (value, None)})
    Q, _, V = OE.own_trajectory(own, np.array([q0], float), np.array([0.0]), T_EVAL)
    return np.array([Q[:, 0], V[:, 0]])


@pytest.mark.parametrize("make", [damped_particle, driven_pendulum])
def test_from_mechanics_damper_torque_and_specified_input_agree_with_sympys_equations(make):
    system, consts, specified, _ = make()
    t = me.dynamicsymbols._t
    q0 = 0.6
    s = liefi.from_mechanics(system, consts, sample=np.array([q0]))  # was NonConservativeLoadError
    assert s.force is not None and s.force.inputs == (str(specified.func),)
    fi = liefi.FeedbackIntegrator(s, s.state([q0], u=[0.0]), inputs={s.force.inputs[0]: lambda tt: np.sin(2 * tt)})
    sol = fi.run(2.0, t_eval=T_EVAL, dt=0.02, scheme="imex-rk8", backend="numpy")
    want = sympy_run(system, consts, specified, sympy.sin(2 * t), q0)
    got_q, got_v = sol.y[0], s.velocities(sol.y[:2].T)[:, 0]
    err = max(np.max(np.abs(got_q - want[0])), np.max(np.abs(got_v - want[1])))
    assert err < 1e-8, err
    dE, _, inv = held(fi, sol)
    assert dE < 1e-12 and np.ptp(inv["W"]) > 1e-2, (dE, np.ptp(inv["W"]))


def test_a_load_without_inputs_needs_none_and_a_missing_input_is_named():
    system, consts, _, _ = damped_particle()
    s = liefi.from_mechanics(system, consts, sample=np.array([1.0]))
    with pytest.raises(ValueError, match=r"inputs: no signal for \['F'\]"):
        liefi.FeedbackIntegrator(s, s.state([1.0], u=[0.0]))
    system, consts, _, _ = damped_particle(F_load=False)
    s = liefi.from_mechanics(system, consts, sample=np.array([1.0]))
    assert s.force.inputs == ()
    liefi.FeedbackIntegrator(s, s.state([1.0], u=[0.0]))


# --- linearize: B ------------------------------------------------------------------------------------------
def test_linearize_B_and_the_dampers_A_are_sympys():
    system, consts, specified, (q, u) = damped_particle(F_load=False)
    F = specified
    system.add_loads((system.bodies[-1].masscenter, F * system.bodies[0].frame.x))
    s = liefi.from_mechanics(system, consts, sample=np.array([1.0]))
    lin = s.linearize([1.0], u=[0.0])
    system.form_eoms()
    A, B, r = system.eom_method.linearize(op_point={q: 1, u: 0}, A_and_B=True)
    assert lin.coordinates == ("q", "u") and lin.inputs == ("F",) and list(r) == [F]
    np.testing.assert_allclose(lin.A, np.array(A.subs(consts), float), rtol=0, atol=1e-8)
    np.testing.assert_allclose(lin.B, np.array(B.subs(consts), float), rtol=0, atol=1e-12)


def test_linearize_B_is_the_derivative_of_the_forced_field():
    scene = Chaplygin()
    system = scene.build_system()
    z0 = np.array([0.0, scene.m * 0.7, 0.0])  # a straight run: an equilibrium of the reduced field
    law = ForceLaw(lambda t, q, v, u: np.stack([u[..., 0], u[..., 1], 0 * u[..., 0]], -1), inputs=("tau", "f"))
    lin = liefi.linearize(system, z0, force=law, symmetries=())
    assert lin.B.shape == (len(lin.coordinates), 2)
    y0 = np.r_[scene.group0(), z0]
    d = 1e-4
    cols = []
    for j in range(2):
        f = [liefi.FeedbackIntegrator(system, y0, force=law, inputs={"tau": s * d * (j == 0), "f": s * d * (j == 1)},
                                      gains=1.0).vector_field(np.r_[y0, 0.0, 0.0])[3:6] for s in (1, -1)]
        cols.append((f[0] - f[1]) / (2 * d))  # the forced field is affine in the inputs: central difference exact
    B_fd = np.linalg.pinv(lin.basis) @ np.stack(cols, -1)
    np.testing.assert_allclose(lin.B, B_fd, rtol=0, atol=1e-10)
    assert np.linalg.norm(lin.B) > 0.1


# --- bad inputs ------------------------------------------------------------------------------------------------
def test_bad_inputs_get_named_errors():
    scene = KnifeEdge()
    system, z0 = scene.build_system(), scene.initial_state(None)
    FI = liefi.FeedbackIntegrator
    with pytest.raises(ValueError, match=r"inputs: no signal for \['tau'\]"):
        FI(system, z0, force=knife_force())
    with pytest.raises(ValueError, match=r"inputs: \['tua'\] are not inputs of the force"):
        FI(system, z0, force=knife_force(), inputs={"tau": 1.0, "tua": 2.0})
    with pytest.raises(ValueError, match="inputs: given without a force"):
        FI(system, z0, inputs={"tau": 1.0})
    with pytest.raises(ValueError, match="force: expected a generalized force of shape \\(..., 3\\)"):
        FI(system, z0, force=lambda t, q, v: np.zeros(2))
    with pytest.raises(ValueError, match="force: non-finite values"):
        FI(system, z0, force=lambda t, q, v: np.full(3, np.nan))
    with pytest.raises(ValueError, match="signal: values contain non-finite numbers"):
        piecewise_constant([0, 1, 2], [1.0, np.nan])
    with pytest.raises(ValueError, match="must have one row per interval"):
        piecewise_constant([0, 1, 2], [1.0, 2.0, 3.0, 4.0])
    with pytest.raises(ValueError, match="t_grid must be strictly increasing"):
        spline([0, 2, 1], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="the signal 'tau' must return finite real numbers"):
        FI(system, z0, force=knife_force(), inputs={"tau": lambda t: np.nan})
    with pytest.raises(ValueError, match="the signal 'tau' must be scalar"):
        FI(system, z0, force=knife_force(), inputs={"tau": [1.0, 2.0]})
    with pytest.raises(ValueError, match="the signal 'tau' contains non-finite numbers"):
        FI(system, z0, force=knife_force(), inputs={"tau": np.inf})
    with pytest.raises(ValueError, match="field: a forced system runs the extended field"):
        FI(system, z0, force=knife_force(), inputs={"tau": 1.0}, field="projected")
    fi = FI(system, z0, force=knife_force(), inputs={"tau": 1.0})
    with pytest.raises(ValueError, match="backend: a forced run .* numpy path only"):
        fi.run(0.1, dt=1e-2, backend="numba")
    with pytest.raises(ValueError, match=r"sensitivities: \['m'\] are neither inputs of this forced run nor 'y0'"):
        fi.run(0.1, dt=1e-2, sensitivities=("m",))
    with pytest.raises(ValueError, match="the input 'tau' is constant; sensitivities are taken with respect to"):
        fi.run(0.1, dt=1e-2, sensitivities=("tau",))
    with pytest.raises(ValueError, match=r"inputs: \['x'\] are not inputs of the force"):
        liefi.linearize(Chaplygin().build_system(), np.array([0.0, 0.7, 0.0]), symmetries=(),
                        force=knife_force(), inputs={"x": 1.0})


def test_a_run_from_another_start_time_starts_the_clock_there():
    scene = KnifeEdge()
    system, z0 = scene.build_system(), scene.initial_state(None)
    fi = liefi.FeedbackIntegrator(system, z0, force=knife_force(), inputs={"tau": lambda t: t})
    sol = fi.run((1.0, 1.2), **RUN)
    np.testing.assert_allclose(sol["time"], sol.t, rtol=0, atol=1e-14)
    assert abs(sol["p_phi"][-1] - (0.5 + (1.2**2 - 1.0) / 2)) < 1e-10


# --- a nonholonomic model from sympy, driven by a torque -----------------------------------------------------
@pytest.mark.parametrize("kind", ["LagrangesMethod", "System"])
def test_sleigh_with_configuration_and_velocity_constraints_driven_by_a_torque_agrees_with_sympy(kind):
    """The sleigh of test_mechanics_holonomic (its mass centre with coordinates of its own: two configuration
    constraints and one velocity constraint) with a torque ``tau(t)`` on its body: sympy's own equations agree
    to 1e-8 over [0, 2], and ``h - W`` and every constraint hold to 1e-12."""
    import test_mechanics_holonomic as H

    v = H.sleigh_parts()
    N, P, C, O, B, body = v["N"], v["P"], v["C"], v["O"], v["B"], v["body"]
    tau = me.dynamicsymbols("tau")
    qs = [v["x"], v["y"], v["th"], v["xc"], v["yc"]]
    consts = {v["m"]: 2.0, v["I"]: 0.3, v["a"]: 0.4}
    if kind == "LagrangesMethod":
        P.set_vel(N, P.pos_from(O).dt(N))
        C.set_vel(N, C.pos_from(O).dt(N))
        model = me.LagrangesMethod(me.Lagrangian(N, body), qs, hol_coneqs=v["hol"],
                                   nonhol_coneqs=[P.vel(N).dot(B.y)], forcelist=[(B, tau * N.z)], frame=N)
        model.form_lagranges_equations()
        case = dict(model=model, hol=v["hol"], vel=list(model.coneqs), q_dep=[v["y"], v["xc"], v["yc"]])
    else:
        us = me.dynamicsymbols("u1:6")
        P.set_vel(N, us[0] * N.x + us[1] * N.y)
        C.set_vel(N, us[3] * N.x + us[4] * N.y)
        B.set_ang_vel(N, us[2] * N.z)
        model = me.System(N, O)
        model.q_ind, model.q_dep = qs[:3], qs[3:]
        model.u_ind, model.u_dep = [us[0], us[2]], [us[1], us[3], us[4]]
        model.kdes = [q.diff() - u for q, u in zip(qs, us)]
        model.add_bodies(body)
        model.add_holonomic_constraints(*v["hol"])
        model.add_nonholonomic_constraints(P.vel(N).dot(B.y))
        model.add_loads(me.Torque(B, tau * N.z))
        model.validate_system()
        model.form_eoms()
        case = dict(model=model, hol=v["hol"], vel=list(model.velocity_constraints), kde=sympy.Matrix(model.kdes),
                    u=list(us))
    s = liefi.from_mechanics(model, consts)
    assert s.force.inputs == ("tau",)
    # sympy's equations at tau = -1/4 (a torque that slows the turn: the reference solves y' from the blade's
    # constraint, whose pivot cos(theta) vanishes at theta = pi/2, where a faster turn would take it)
    case["constants"] = {**consts, tau: -sympy.Rational(1, 4)}
    q0 = H.on_constraints(case, H.SLEIGH_Q, fixed=[0, 1, 2])
    Q, Qd, speeds = H.reference(case, q0, [0.5, 0.4])
    fi = liefi.FeedbackIntegrator(s, s.state(q0, speeds(q0, [0.5, 0.4])), inputs={"tau": -0.25})
    sol = fi.run(H.T_END, t_eval=H.T_EVAL, **H.RUN)
    Y = sol.y.T
    Ql, Qdl = Y[:, :5], s.velocities(Y[:, :10])
    err = max(np.max(np.abs(Ql - Q)), np.max(np.abs(Qdl - Qd)))
    assert err < 1e-8, err
    case["constants"] = consts
    fval, vel = H.declared(case)
    assert np.max(np.abs(fval(Ql))) < 1e-12 and np.max(np.abs(vel(Ql, Qdl))) < 1e-12
    dE, J, inv = held(fi, sol)
    assert dE < 1e-12 and J < 1e-12 and np.ptp(inv["W"]) > 0.05, (dE, J, np.ptp(inv["W"]))


def test_a_signal_that_fails_during_the_run_is_named_with_its_time():
    """The run calls a callable signal with arrays of times (the stages of a step), not only with the t = 0 that
    the integrator probes: ``math.sin``, a wrong shape for an array of times, an exception or a NaN later in the
    run each get a ValueError naming the signal and the time (before: a TypeError blamed on the force, a raw
    RuntimeError, a broadcast error, or the force's "non-finite values")."""
    import math

    scene = KnifeEdge()
    system, z0 = scene.build_system(), scene.initial_state(None)

    def run(signal):
        return liefi.FeedbackIntegrator(system, z0, force=knife_force(), inputs={"tau": signal}).run(0.2, **RUN)

    def boom(t):
        if np.any(np.asarray(t) > 0.05):
            raise RuntimeError("boom")
        return np.ones(np.shape(t))

    with pytest.raises(ValueError, match=r"the signal 'tau' failed at t = .*only 0-dimensional.*np\.vectorize"):
        run(lambda t: math.sin(t))
    with pytest.raises(ValueError, match=r"the signal 'tau' called with times of shape \(\d+,\).* returned float64 "
                                         r"numbers of shape \(3,\); expected real numbers of shape"):
        run(lambda t: np.ones(3) if np.ndim(t) else 1.0)
    with pytest.raises(ValueError, match=r"the signal 'tau' failed at t = 0\.0[5-9]\d*: RuntimeError\('boom'\)"):
        run(boom)
    with pytest.raises(ValueError, match=r"the signal 'tau' returned a non-finite number \(NaN or inf\) at t = 0\.0[5-9]"):
        run(lambda t: np.where(np.asarray(t) > 0.05, np.nan, 1.0))
    with pytest.raises(ValueError, match=r"signal: bc_type='periodic' cannot be used here"):
        spline([0.0, 1.0, 2.0], [1.0, 2.0, 3.0], bc_type="periodic")
    # what still works: a numpy signal, and one returning a number whatever the times (broadcast)
    a, b = run(lambda t: 0.5 * np.cos(t)), run(lambda t: 0.5)
    assert np.all(np.isfinite(a.y)) and np.all(np.isfinite(b.y)) and not np.allclose(a.y[..., -1], b.y[..., -1])


def test_a_run_past_a_splines_nodes_warns_naming_the_input_and_its_nodes():
    """Outside its nodes a spline is its end cubic: values [1, 2, 30] over [0, 0.02] read 5151 at t = 0.2.
    A run over [0, 0.2] said nothing before; it now warns (InputGridWarning) with the input's name and nodes,
    and a run inside the nodes stays silent."""
    import warnings

    from liefi.integrator.forced import InputGridWarning
    from liefi.systems.forcing import spline

    sig = spline([0.0, 0.01, 0.02], [1.0, 2.0, 30.0], name="tau")
    assert float(sig(np.array(0.2))) > 5000.0  # the extrapolation the warning is about
    fi = sleigh_with(sig)
    with pytest.warns(InputGridWarning, match=r"spline input 'tau' has nodes over \[0, 0.02\] only"):
        fi.run(0.2, dt=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputGridWarning)
        fi.run(0.02, dt=0.01)
