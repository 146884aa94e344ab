"""Reverse mode (:mod:`liefi.integrator.adjoint`): ``w . dy/d(y0, theta)`` equals the forward tangents' ``sum_t S_t^T w_t``.

The forward tangents are checked against derivatives of whole runs in ``tests/test_sensitivity.py``; here
the adjoint of the same discrete run must agree with them to rounding, for a split and an explicit scheme,
the gains ``"auto"`` resolved (held), an adaptive gain schedule, the constants of ``from_mechanics`` and
parameters declared by hand (the targets taken at the start follow ``y0`` and ``theta``).  Plain Python
(``engine="python"``), short runs.
"""

import numpy as np
import pytest

import liefi
from liefi.integrator import adjoint, sensitivity
from liefi.scenes import get as get_scene
from liefi.schemes import registry

from models import sleigh_model
from test_sensitivity_parameters import hand_sleigh


def forward_reference(fi, sch, y0, dt, n_steps, saved, W, schedule=None):
    n, P = fi.n, len(sensitivity.parameter_names(fi.system))
    V = np.vstack([np.eye(n), np.zeros((P, n))])
    C = np.vstack([np.zeros((n, P)), np.eye(P)])
    _, S = sensitivity.tangents(fi, sch, y0, dt, n_steps, saved, V, C, schedule=schedule)
    g = np.einsum("jnt,nt->j", S, W)
    return g[:n], g[n:]


def check(fi, scheme, y0, dt, n_steps, saved, schedule=None):
    sch = registry.get(scheme)
    W = np.random.default_rng(3).standard_normal((fi.n, len(saved)))
    gy, gc = adjoint.vjp(fi, sch, y0, dt, n_steps, saved, W, schedule=schedule)
    ry, rc = forward_reference(fi, sch, y0, dt, n_steps, saved, W, schedule)
    scale = np.max(np.abs(np.r_[ry, rc]))
    assert np.max(np.abs(gy - ry)) / scale < 1e-12
    assert gc.shape == rc.shape and (rc.size == 0 or np.max(np.abs(gc - rc)) / scale < 1e-12)
    return gy, gc


@pytest.mark.parametrize("scheme", ["imex-rk4", "rk4"])
def test_suslov_adjoint_matches_the_forward_tangents(scheme):
    fi0 = get_scene("suslov").integrator(gains="auto", configuration=True)
    sol = fi0.run(0.2, dt=0.01, scheme=scheme, backend="numpy", adaptive=False)
    fi = liefi.FeedbackIntegrator(fi0.system, fi0.y0, gains=sol.stability.gains, configuration=True)  # as it ran
    check(fi, scheme, fi0.y0, 0.01, 20, np.array([0, 3, 7, 20]))


def test_suslov_adjoint_with_an_adaptive_gain_schedule():
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    g = fi.run(0.02, dt=0.01, scheme="euler", backend="numpy").stability.gains  # {name: gain}
    sched = [(0, fi.parameters(gains=g)), (7, fi.parameters(gains={k: 0.4 * v for k, v in g.items()})),
             (15, fi.parameters(gains={k: 2.0 * v for k, v in g.items()}))]
    check(fi, "euler", fi.y0, 0.01, 20, np.array([0, 7, 12, 20]), schedule=sched)


def test_from_mechanics_constants_and_declared_parameters_by_the_adjoint():
    LM, (m, I, a) = sleigh_model()
    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    sleigh = liefi.from_mechanics(LM, {m: 1.0, I: 0.5, a: 0.3})
    _, gc = check(liefi.FeedbackIntegrator(sleigh, y0, configuration=False, gains=5.0), "imex-rk4", y0, 0.01, 20,
                  np.array([0, 5, 20]))
    assert gc.shape == (3,) and np.all(np.abs(gc) > 0)
    system, _ = hand_sleigh()
    _, gc = check(liefi.FeedbackIntegrator(system, y0, configuration=False, gains=5.0), "rk4", y0, 0.01, 20,
                  np.array([10, 20]))
    assert gc.shape == (2,)


def test_bad_cotangents_are_refused():
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    with pytest.raises(ValueError, match=r"W: expected dL/dy at the saved steps, shape \(n, n_t\) = \(12, 2\)"):
        adjoint.vjp(fi, "rk4", fi.y0, 0.01, 10, [0, 10], np.ones((12, 3)))
    with pytest.raises(ValueError, match="saved_steps: expected increasing steps"):
        adjoint.vjp(fi, "rk4", fi.y0, 0.01, 10, [10, 0], np.ones((12, 2)))


@pytest.mark.slow  # numba compiles the adjoint's loops
def test_the_compiled_adjoint_agrees_with_the_python_one():
    pytest.importorskip("numba")
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    sch = registry.get("imex-rk4")
    saved = np.array([0, 50, 100])
    W = np.random.default_rng(2).standard_normal((fi.n, saved.size))
    a = adjoint.vjp(fi, sch, fi.y0, 0.01, 100, saved, W, engine="python")[0]
    b = adjoint.vjp(fi, sch, fi.y0, 0.01, 100, saved, W, engine="numba")[0]
    assert np.max(np.abs(a - b)) / np.max(np.abs(a)) < 1e-13
    c = adjoint.vjp(fi, sch, fi.y0, 0.01, 100, saved, W, engine="numba", checkpoints=7)[0]  # 7 segments
    assert np.array_equal(b, c)


@pytest.mark.parametrize("checkpoints", [1, 2, 3, 5, 7, 22, None])
def test_checkpointed_backward_sweep_is_bitwise_the_stored_one(checkpoints):
    # segments of ceil(23 / c) steps recomputed from their first state, across the gain schedule's updates
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    g = fi.run(0.02, dt=0.01, scheme="euler", backend="numpy").stability.gains
    sched = [(0, fi.parameters(gains=g)), (9, fi.parameters(gains={k: 0.5 * v for k, v in g.items()}))]
    saved = np.array([0, 4, 9, 10, 17, 23])
    W = np.random.default_rng(5).standard_normal((fi.n, saved.size))
    ref = adjoint.vjp(fi, "imex-rk4", fi.y0, 0.01, 23, saved, W, schedule=sched, checkpoints="all")
    got = adjoint.vjp(fi, "imex-rk4", fi.y0, 0.01, 23, saved, W, schedule=sched, checkpoints=checkpoints)
    assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])
    m = {1: 23, 2: 12, 3: 8, 5: 5, 7: 4, 22: 2}.get(checkpoints, 23)  # ceil(23 / c); the default keeps all
    assert adjoint.segment_steps(23, fi.n, checkpoints) == m


def test_the_default_checkpoints_keep_about_sqrt_n_states_of_a_long_run():
    assert adjoint.segment_steps(20_000, 12) == 20_000  # 1.9 MB: every state kept
    assert adjoint.segment_steps(200_000, 12) == 447  # 19 MB: 448 segments of 447 steps
    assert adjoint.segment_steps(10, 12, 10) == 10 and adjoint.segment_steps(10, 12, 3) == 4
    for bad in (0, -2, 2.5, True, "some"):
        with pytest.raises(ValueError, match="checkpoints: expected None .* 'all' or the number of kept states"):
            adjoint.segment_steps(100, 12, bad)


def test_a_run_gives_the_gradient_of_a_scalar_loss_by_sol_vjp():
    # fi.run(..., adjoint=...) then sol.vjp(dL/dy): "auto" gains adapted along the run, held in the replay
    fi = get_scene("suslov").integrator(gains="auto", configuration=True)
    sol = fi.run(0.2, dt=0.01, scheme="imex-rk4", backend="numpy", sensitivities=("y0",), adjoint=True)
    W = np.random.default_rng(4).standard_normal(sol.y.shape)
    g = sol.vjp(W)
    ref = np.einsum("ijt,it->j", sol.sensitivities["y0"], W)
    assert list(g) == ["y0"] and np.max(np.abs(g["y0"] - ref)) / np.max(np.abs(ref)) < 1e-12
    ck = fi.run(0.2, dt=0.01, scheme="imex-rk4", backend="numpy", save_every=4,
                adjoint=adjoint.RecursiveCheckpointAdjoint(checkpoints=3))
    al = fi.run(0.2, dt=0.01, scheme="imex-rk4", backend="numpy", save_every=4,
                adjoint=adjoint.RecursiveCheckpointAdjoint(checkpoints="all"))
    W = W[:, : ck.y.shape[1]]
    assert np.array_equal(ck.vjp(W)["y0"], al.vjp(W)["y0"])


def test_sol_vjp_by_the_parameters_of_from_mechanics():
    LM, (m, I, a) = sleigh_model()
    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    fi = liefi.FeedbackIntegrator(liefi.from_mechanics(LM, {m: 1.0, I: 0.5, a: 0.3}), y0, configuration=False,
                                  gains=5.0)
    names = sensitivity.parameter_names(fi.system)
    sol = fi.run(0.2, dt=0.01, scheme="imex-rk4", backend="numpy", sensitivities=names, adjoint=True)
    W = np.random.default_rng(6).standard_normal(sol.y.shape)
    g = sol.vjp(W, wrt=names[::-1])
    assert list(g) == list(names[::-1])
    for nm in names:
        ref = np.sum(sol.sensitivities[nm] * W)
        assert abs(g[nm] - ref) <= 1e-12 * abs(ref)


def test_sol_vjp_refuses_bad_input_by_name():
    fi = get_scene("suslov").integrator(gains=10.0, configuration=True)
    sol = fi.run(0.1, dt=0.01, scheme="rk4", backend="numpy", adjoint=True)
    with pytest.raises(ValueError, match=r"cotangent: expected dL/dy at the saved states, the shape of sol.y, "
                                         r"\(n, n_t\) = \(12, 11\), got \(12, 3\)"):
        sol.vjp(np.ones((12, 3)))
    with pytest.raises(ValueError, match="cotangent: expected dL/dy"):
        sol.vjp("a loss")
    with pytest.raises(ValueError, match="cotangent: contains non-finite numbers"):
        sol.vjp(np.full(sol.y.shape, np.nan))
    with pytest.raises(ValueError, match="wrt: unknown name 'mass'; use 'y0'"):
        sol.vjp(np.ones(sol.y.shape), wrt=("mass",))
    with pytest.raises(ValueError, match=r"vjp: this run kept no adjoint; run it with fi.run\(..., adjoint=True\)"):
        fi.run(0.1, dt=0.01, scheme="rk4", backend="numpy").vjp(np.ones(sol.y.shape))
    with pytest.raises(ValueError, match="vjp: the run ended with a step shortened"):
        fi.run(0.1, dt=0.03, scheme="rk4", backend="numpy", adjoint=True).vjp(np.ones((12, 5)))
    with pytest.raises(ValueError, match="adjoint: not available with t_eval="):
        fi.run(0.1, dt=0.01, t_eval=[0.05], adjoint=True)
    with pytest.raises(ValueError, match=r"adjoint: one trajectory only"):
        fi.run(0.1, dt=0.01, y0=np.stack([fi.y0, fi.y0]), adjoint=True)
    with pytest.raises(TypeError, match=r"adjoint: expected True, None or .*RecursiveCheckpointAdjoint"):
        fi.run(0.1, dt=0.01, adjoint="yes")
    with pytest.raises(ValueError, match="checkpoints: expected None"):
        adjoint.RecursiveCheckpointAdjoint(checkpoints=0)


def test_a_forced_run_has_no_adjoint_and_says_so():
    from test_forced_sensitivity import racer, make

    fi = racer(make("piecewise", 0.4 * np.cos(np.arange(6))))
    with pytest.raises(ValueError, match=r"adjoint: a forced run \(force=, inputs=\) has no adjoint yet"):
        fi.run(0.2, dt=0.02, adjoint=True)
