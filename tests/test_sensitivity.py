"""Forward discrete sensitivities (liefi.integrator.sensitivity): exact derivatives of the states a run returns.

The references differentiate whole runs:

* Suslov (constant data): a complex step through the numpy step map, ``h = 1e-30``, exact to rounding
  (``Im y(y0 + i h e_j) / h``, the targets taken at the complex start as the run takes them at ``y0``);
* the Chaplygin ball and the ``from_mechanics`` sleigh: their data depend on ``x`` and the numpy field
  differentiates them by complex step itself, so a complex start is refused (two nested complex steps
  are not exact); the reference is the 8th-order central difference of whole runs
  (``sum_m c_m (y(p + m h) - y(p - m h)) / h``, ``m = 1..4``), truncation ``O(h^8)``, rounding
  ``~ eps |y| / h``: with ``h = 1e-2`` both below 1e-12 of the sensitivity's size.

The runs hold the gains that ``gains="auto"`` resolved (``solution.stability.gains``), as the
sensitivities do.
"""

import numpy as np
import pytest

import liefi
from liefi.reduction import core as _core
from liefi.scenes import get as get_scene
from liefi.schemes import registry
from liefi.schemes.split import feedback_step

from models import sleigh_model

#: weights of the 8th-order central difference, (y(+m h) - y(-m h)) for m = 1..4
C8 = np.array([4 / 5, -1 / 5, 4 / 105, -1 / 280])
RTOL = 1e-10


def central8(run, h):
    """``d run(s) / ds`` at 0 by the 8th-order central difference of whole runs."""
    return sum(c * (run(m * h) - run(-m * h)) for m, c in zip(range(1, 5), C8)) / h


def rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def rerun(fi, sol, y0, T, dt, scheme, system=None):
    """The run of ``fi``'s options from ``y0`` with the gains ``sol`` ran with (targets taken at ``y0``)."""
    f = liefi.FeedbackIntegrator(fi.system if system is None else system, y0, gains=sol.stability.gains,
                                 configuration=fi.configuration, invariants=_invariants(fi))
    if sol.dropped:
        f = f.without({d["name"]: d["reason"] for d in sol.dropped})
    return f.run(T, dt=dt, scheme=scheme, backend="numpy", adaptive=False).y


def _invariants(fi):
    names = (("constraints",) if fi.use_constraints else ()) + (("energy",) if fi.use_energy else ())
    return names + tuple(fi.user)


# --- Suslov: complex step of the whole run ----------------------------------------------------------


def _suslov_complex_run(fr, sch, y0c, T, dt, report):
    """The numpy step map of ``sch`` on ``fr`` from a complex start, with the targets taken there and the
    gains of ``report`` (an adaptive run's updates from their steps on)."""
    lay = fr.parameter_layout
    g, z = fr.split(y0c)
    t = _core.evaluate(fr.system, z, derivatives=False)
    steps = [0] + [int(round(tt / dt)) for tt in report.gain_times]
    ps = []
    for gains in [report.gains] + list(report.gain_history):
        p = fr.parameters(gains=gains).astype(complex)
        p[lay.energy_target] = t.ht if fr.energy == "extended" else t.h
        ps.append(p)
    y, out = y0c, [y0c]
    for s in range(int(round(T / dt))):
        p = ps[max(i for i, a in enumerate(steps) if a <= s)]
        if sch.kind == "split":
            y = feedback_step(fr, sch.explicit.step(lambda q: fr.unforced_vector_field(q, p), y, dt), dt, p)
        else:
            y = sch.step(lambda q: fr.vector_field(q, p), y, dt)
        out.append(y)
    return np.stack(out, -1)


@pytest.mark.parametrize("scheme,gains", [("imex-rk4", "auto"), ("rk4", 50.0), ("euler", "auto")])
def test_suslov_y0_matches_complex_step_of_the_whole_run(scheme, gains):
    """``euler`` with ``gains="auto"`` adapts its gains along the run: they are held as numbers from each update on."""
    fi = get_scene("suslov").integrator(gains=gains, configuration=True)
    T, dt = (0.2, 0.01) if scheme != "euler" else (2.0, 0.01)
    sol = fi.run(T, dt=dt, scheme=scheme, backend="numpy", sensitivities=("y0",))
    assert (len(sol.stability.gain_times) > 0) == (scheme == "euler")
    S = sol.sensitivities["y0"]
    assert S.shape == (fi.n, fi.n, sol.t.size)
    fr = liefi.FeedbackIntegrator(fi.system, fi.y0, gains=sol.stability.gains, configuration=True)
    if sol.dropped:  # the invariants the run left out of V (kept exactly by the scheme)
        fr = fr.without({d["name"]: d["reason"] for d in sol.dropped})
    sch = registry.get(scheme)
    run = _suslov_complex_run(fr, sch, fi.y0.astype(complex), T, dt, sol.stability)
    assert np.allclose(run.real, sol.y, rtol=0, atol=1e-14)
    h = 1e-30
    for j in range(fi.n):
        ref = _suslov_complex_run(fr, sch, fi.y0 + 1j * h * np.eye(fi.n)[j], T, dt, sol.stability).imag / h
        assert rel(S[:, j], ref) < RTOL, j


def test_the_run_is_unchanged_by_its_sensitivities():
    fi = get_scene("suslov").integrator(gains="auto", configuration=True)
    a = fi.run(0.1, dt=0.01, scheme="imex-rk4", backend="numpy")
    b = fi.run(0.1, dt=0.01, scheme="imex-rk4", backend="numpy", sensitivities=("y0",))
    assert np.array_equal(a.y, b.y) and a.sensitivities is None
    assert np.array_equal(b.sensitivities["y0"][..., 0], np.eye(fi.n))


# --- the from_mechanics sleigh: y0 and two constants --------------------------------------------------


@pytest.fixture(scope="module")
def sleigh():
    LM, (m, I, a) = sleigh_model()
    return liefi.from_mechanics(LM, {m: 1.0, I: 0.5, a: 0.3})


def test_sleigh_y0_and_two_constants_through_a_split_scheme_with_auto_gains(sleigh):
    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    fi = liefi.FeedbackIntegrator(sleigh, y0, configuration=False)  # gains="auto"
    T, dt, scheme = 0.2, 0.01, "imex-rk4"
    sol = fi.run(T, dt=dt, scheme=scheme, backend="numpy", sensitivities=("y0", "m", "a"))
    assert sol.sensitivities["m"].shape == (fi.n, sol.t.size)
    base = dict(sleigh.constants_dict())

    def with_constant(name, s):
        sleigh.constants = {name: base[name] + s}
        try:
            return rerun(fi, sol, y0, T, dt, scheme)
        finally:
            sleigh.constants = base

    for name in ("m", "a"):
        ref = central8(lambda s: with_constant(name, s), 1e-2)
        assert rel(sol.sensitivities[name], ref) < RTOL, name
    for j in (2, 5):
        ref = central8(lambda s: rerun(fi, sol, y0 + s * np.eye(fi.n)[j], T, dt, scheme), 1e-2)
        assert rel(sol.sensitivities["y0"][:, j], ref) < RTOL, j


def test_sleigh_explicit_scheme_fixed_gains(sleigh):
    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    fi = liefi.FeedbackIntegrator(sleigh, y0, configuration=False, gains=5.0)
    T, dt = 0.2, 0.01
    sol = fi.run(T, dt=dt, scheme="rk4", backend="numpy", sensitivities=("I",))
    base = dict(sleigh.constants_dict())

    def run(s):
        sleigh.constants = {"I": base["I"] + s}
        try:
            return rerun(fi, sol, y0, T, dt, "rk4")
        finally:
            sleigh.constants = base

    assert rel(sol.sensitivities["I"], central8(run, 1e-2)) < RTOL


# --- the Chaplygin ball ---------------------------------------------------------------------------


@pytest.mark.slow  # ~20 s: the ball's trace (25 states, 18 parameters) and 16 runs of the reference
def test_chaplygin_ball_y0_through_a_split_scheme_with_auto_gains():
    from liefi.groups import SO3
    from liefi.systems.rolling import rolling_start

    sc = get_scene("chaplygin-ball")
    fi = sc.integrator(gains="auto")
    T, dt, scheme = 0.05, 0.01, "imex-rk4"
    sol = fi.run(T, dt=dt, scheme=scheme, backend="numpy", sensitivities=("y0",))
    S = sol.sensitivities["y0"]
    assert S.shape == (fi.n, fi.n, sol.t.size)
    R0 = SO3().exp(sc.R0_axis)
    for k in (0, 2):  # a start of the ball moves along its states: the spin Omega_k of rolling_start
        def start(s):
            return rolling_start(fi.system, R0, sc.Omega0 + s * np.eye(3)[k])

        d = (start(0.5) - start(-0.5)) / 1.0  # rolling_start is linear in Omega: exact to rounding
        ref = central8(lambda s: rerun(fi, sol, start(s), T, dt, scheme), 1e-2)
        assert rel(np.einsum("ijt,j->it", S, d), ref) < RTOL, k


# --- refusals ----------------------------------------------------------------------------------------


def test_unknown_names_and_uncovered_options_are_refused():
    fi = get_scene("suslov").integrator(gains=10.0)
    with pytest.raises(ValueError, match="sensitivities: unknown name 'm'.*declares no parameters"):
        fi.run(0.1, dt=0.01, scheme="rk4", backend="numpy", sensitivities=("y0", "m"))
    with pytest.raises(ValueError, match="sensitivities: not available with t_eval"):
        fi.run(0.1, dt=0.01, scheme="rk4", backend="numpy", t_eval=[0.05], sensitivities="y0")
    with pytest.raises(ValueError, match="repeated"):
        fi.run(0.1, dt=0.01, scheme="rk4", backend="numpy", sensitivities=("y0", "y0"))
    with pytest.raises(ValueError, match="dt that divides"):
        fi.run(0.1, dt=0.03, scheme="rk4", backend="numpy", sensitivities=("y0",))
    with pytest.raises(TypeError, match="sequence of names"):
        fi.run(0.1, dt=0.01, scheme="rk4", backend="numpy", sensitivities=3)
    with pytest.raises(ValueError, match="one trajectory only"):
        fi.run(0.1, dt=0.01, scheme="rk4", backend="numpy", y0=np.stack([fi.y0, fi.y0]), sensitivities="y0")


# --- the compiled path -------------------------------------------------------------------------------


@pytest.mark.slow  # the numba compile of the tangent kernel: a minute or two
def test_compiled_tangents_agree_with_the_numpy_path(sleigh):
    pytest.importorskip("numba")
    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    fi = liefi.FeedbackIntegrator(sleigh, y0, configuration=False)
    kw = dict(dt=0.01, scheme="imex-rk4", sensitivities=("y0", "m"))
    a = fi.run(0.2, backend="numpy", **kw)
    b = fi.run(0.2, backend="numba", **kw)
    assert b.backend != "numpy"
    for name in ("y0", "m"):
        assert rel(b.sensitivities[name], a.sensitivities[name]) < 1e-12, name


def test_one_tangent_kernel_serves_every_value_of_the_constants(sleigh):
    from liefi.integrator.sensitivity import tangent_kernel

    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    base = dict(sleigh.constants_dict())
    first = tangent_kernel(liefi.FeedbackIntegrator(sleigh, y0, configuration=False), registry.get("imex-rk4"))
    sleigh.constants = {"m": 2.0}
    try:
        again = tangent_kernel(liefi.FeedbackIntegrator(sleigh, y0, configuration=False), registry.get("imex-rk4"))
    finally:
        sleigh.constants = base
    assert again is first
