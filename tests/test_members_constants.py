"""Per-member constants of a from_mechanics system: every path reads each member's own, or refuses.

An ensemble of ``N`` states whose system holds constants of shape ``(N, P)`` (a mass and a length per
member) must give, member by member, what a run of that member alone (one state, scalar constants) gives:
to rounding, or a ``ValueError`` naming ``constants``.  Reproductions of the silent wrong answers:

* the stability estimate before a run (and its pilot) read the first member's constants for the few members
  it follows: ``lambda_max`` 578 for an ensemble whose stiffest member has 549 (so a refusal "10.4x the
  bound" that no member alone gets);
* an adaptive ensemble adapted the gains of the members due for it with the first member's constants: the
  run ended in a ``StabilityError`` that no member alone meets;
* the resolution test of the step chosen for rtol, over 16 of 20 members, read them with the first member's
  constants (fastest rate 3.12 against the members' 1.9985);
* one state (or a batch of another shape) with per-member constants ran silently with the first member's
  (a forced run's sensitivities: a raw numpy broadcast error);
* ``system.constants`` changed after the integrator was built: the run steered to the old energy (now its
  targets taken at ``y0`` are taken again);
* a scene whose ``system.constants`` were set kept the reference (and step) of the old constants.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import liefi

pytest.importorskip("sympy")

M = np.array([1.0, 2.5, 1.6])  # mass per member
A = np.array([0.5, 0.3, 0.8])  # the blade-to-centre length per member
QD = np.array([[0.5, 0.0, 1.0], [0.3, 0.0, 0.7], [0.4, 0.0, -0.9]])  # each member's own start (qdot)


def _sleigh(constants):
    from models import sleigh_model

    return liefi.from_mechanics(sleigh_model()[0], constants)


@pytest.fixture(scope="module")
def sleighs():
    """The ensemble's system (constants (3, 3): m, I, a per member) and each member's own system."""
    ens = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
    ens.constants = {"m": M, "a": A}
    ones = [_sleigh({"m": M[k], "I": 1.0, "a": A[k]}) for k in range(3)]
    return ens, ones


@pytest.fixture
def no_refusal(monkeypatch):
    """Records every refusal of the constants (also one a diagnostic would swallow): a path that must run
    asserts it saw none."""
    from liefi.systems import mechanics

    seen = []
    aligned = mechanics._Constants.aligned

    def recording(self, batch):
        try:
            return aligned(self, batch)
        except ValueError as exc:
            seen.append(str(exc))
            raise

    monkeypatch.setattr(mechanics._Constants, "aligned", recording)
    return seen


def _starts(ens, ones):
    z0 = ens.state(np.zeros((3, 3)), QD)
    for k in range(3):
        np.testing.assert_allclose(z0[k], ones[k].state(np.zeros(3), QD[k]), rtol=1e-15, atol=1e-15)
    return z0


def _agree(got, want, tol=1e-13):
    got, want = np.asarray(got), np.asarray(want)
    assert got.shape == want.shape
    assert np.max(np.abs(got - want)) <= tol * max(1.0, np.max(np.abs(want)))


def test_fields_runs_dense_output_and_events_are_each_members_own(sleighs, no_refusal):
    """The field, a run at a given dt (default scheme, fixed and 'auto' gains), t_eval, dense output and the
    invariants of a time-major stack: member k of the ensemble equals member k alone."""
    ens, ones = sleighs
    z0 = _starts(ens, ones)
    fe = liefi.FeedbackIntegrator(ens, z0, gains=1.0)
    f1 = [liefi.FeedbackIntegrator(ones[k], z0[k], gains=1.0) for k in range(3)]
    y = z0 + 0.01
    for k in range(3):
        _agree(fe.vector_field(y)[k], f1[k].vector_field(y[k]))
        _agree(ens.constrained_vector_field(y)[k], ones[k].constrained_vector_field(y[k]))
    kw = dict(dt=0.02, backend="numpy", t_eval=[0.0, 0.37, 0.81], dense_output=True)
    sol = fe.run(1.0, **kw)
    for k in range(3):
        one = f1[k].run(1.0, **kw)
        _agree(sol.y[k], one.y)
        _agree(sol.sol(0.555)[k], one.sol(0.555))
    auto = liefi.FeedbackIntegrator(ens, z0).run(0.6, dt=0.02, backend="numpy")
    for k in range(3):
        _agree(auto.y[k], liefi.FeedbackIntegrator(ones[k], z0[k]).run(0.6, dt=0.02, backend="numpy").y)
    h = fe.invariant_values(np.moveaxis(sol.y, -1, 0))["h~"]  # a time-major stack (T, 3, n)
    for k in range(3):
        _agree(h[:, k], f1[k].invariant_values(sol.y[k].T)["h~"])
    assert not no_refusal


def test_events_of_an_ensemble_are_refused_and_each_member_alone_finds_its_own(sleighs):
    """Events are for one trajectory: an ensemble is refused by name (no member's crossing found with another's
    constants); each member alone, with its scalar constants, finds its own."""
    ens, ones = sleighs
    z0 = _starts(ens, ones)

    def event(t, y):  # the heading crosses 0.3
        return y[..., 2] - 0.3

    with pytest.raises(ValueError, match=r"events: only for a single trajectory"):
        liefi.FeedbackIntegrator(ens, z0, gains=1.0).run(1.0, dt=0.02, backend="numpy", events=event)
    one = liefi.FeedbackIntegrator(ones[0], z0[0], gains=1.0).run(1.0, dt=0.02, backend="numpy", events=event)
    assert one.t_events[0].size == 1  # member 0 turns past 0.3 rad within the second


def test_the_stability_estimate_follows_each_members_constants(no_refusal):
    """5 members (more than the pilot's 4): the estimate's lambda_max at the start and along the pilot and
    its resolution rate are the largest of the members' own (were 352.9 and 578.0 against 310.5 and 549.0:
    the pilot's members read the first member's constants)."""
    from liefi.integrator.stability import estimate

    rng = np.random.default_rng(0)
    N = 5
    m, a = 1 + 2 * rng.random(N), 0.3 + 0.5 * rng.random(N)
    qd = np.stack([0.3 + 0.4 * rng.random(N), np.zeros(N), rng.normal(size=N)], -1)
    ens = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
    ens.constants = {"m": m, "a": a}
    z0 = ens.state(np.zeros((N, 3)), qd)
    got = estimate(liefi.FeedbackIntegrator(ens, z0, gains=50.0), 0.05, "rk4", t_final=2.0)
    alone = []
    for k in range(N):
        one = _sleigh({"m": m[k], "I": 1.0, "a": a[k]})
        alone.append(estimate(liefi.FeedbackIntegrator(one, z0[k], gains=50.0), 0.05, "rk4", t_final=2.0))
    np.testing.assert_allclose(got.lam0, max(e.lam0 for e in alone), rtol=1e-12)
    np.testing.assert_allclose(got.lam, max(e.lam for e in alone), rtol=1e-12)
    np.testing.assert_allclose(got.rate, max(e.rate for e in alone), rtol=1e-12)
    assert not no_refusal


def test_an_adaptive_ensemble_adapts_each_member_with_its_own_constants(no_refusal):
    """Fixed gains lowered along the run (adaptive=True), 6 members on their own schedules: each member
    equals its run alone (the ensemble ended in a StabilityError at t = 4.24 that no member meets alone:
    the members due for adaptation were evaluated with the first member's constants)."""
    N = 6
    m, a = np.linspace(0.5, 4.0, N), np.linspace(0.9, 0.2, N)
    qd = np.stack([np.linspace(0.3, 1.0, N), np.zeros(N), np.linspace(-2, 2, N)], -1)
    ens = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
    ens.constants = {"m": m, "a": a}
    z0 = ens.state(np.zeros((N, 3)), qd)
    kw = dict(dt=0.02, scheme="rk4", backend="numpy", adaptive=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = liefi.FeedbackIntegrator(ens, z0, gains=5.0).run(5.0, **kw)
        changes = []
        for k in range(N):
            one = liefi.FeedbackIntegrator(_sleigh({"m": m[k], "I": 1.0, "a": a[k]}), z0[k], gains=5.0).run(5.0, **kw)
            _agree(sol.y[k], one.y)
            changes.append(len(one.stability.gain_times))
    assert len(set(changes)) > 1  # the members adapt on schedules of their own
    assert not no_refusal


@pytest.mark.slow  # about 12 s: three choices of the step for rtol on numpy (per-member constants do not compile)
def test_the_step_for_a_tolerance_is_the_ensembles_and_each_member_runs_as_alone(sleighs):
    """The default run(T) (no dt: the step chosen for rtol): the ensemble's step, run by each member alone,
    gives the ensemble's member; an ensemble of one member's constants repeated chooses that member's step."""
    ens, ones = sleighs
    z0 = _starts(ens, ones)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = liefi.FeedbackIntegrator(ens, z0, gains=1.0).run(1.0, rtol=1e-8, backend="numpy")
        for k in range(3):
            one = liefi.FeedbackIntegrator(ones[k], z0[k], gains=1.0).run(
                1.0, dt=sol.method["dt"], scheme=sol.method["scheme"], backend="numpy")
            _agree(sol.y[k], one.y, 1e-12)
        same = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
        same.constants = {"m": np.full(2, M[1]), "a": np.full(2, A[1])}
        two = liefi.FeedbackIntegrator(same, np.stack([z0[1], z0[1]]), gains=1.0).run(1.0, rtol=1e-8, backend="numpy")
        alone = liefi.FeedbackIntegrator(ones[1], z0[1], gains=1.0).run(1.0, rtol=1e-8, backend="numpy")
    assert two.method["dt"] == alone.method["dt"] and two.method["scheme"] == alone.method["scheme"]
    _agree(two.y[1], alone.y, 1e-12)


def test_states_that_are_not_the_ensembles_are_refused_naming_constants(sleighs):
    """One state, or a batch of another shape, with per-member constants: a ValueError naming constants and
    what to do (it ran silently with the first member's constants)."""
    ens, ones = sleighs
    z0 = _starts(ens, ones)
    with pytest.raises(ValueError, match=r"y0: the system holds per-member constants .*one state; give one state "
                                         r"per member \(shape \(3, n\)\)"):
        liefi.FeedbackIntegrator(ens, z0[1])
    with pytest.raises(ValueError, match=r"y0: the system holds per-member constants .*states of shape \(2,\)"):
        liefi.FeedbackIntegrator(ens, z0[:2])
    with pytest.raises(ValueError, match=r"constants: .*per-member constants .* a single state"):
        ens.metric(np.zeros(3))
    with pytest.raises(ValueError, match=r"constants: .*per-member constants .* batch shape \(2,\)"):
        ens.constrained_vector_field(z0[:2])
    with pytest.raises(ValueError, match=r"constants: .*per-member constants.*one system at one state"):
        liefi.linearize(ens, z0[0])
    with pytest.raises(ValueError, match="sensitivities: one trajectory only"):  # and one state is refused above
        liefi.FeedbackIntegrator(ens, z0).run(0.1, dt=0.01, sensitivities=("m",))
    # the ensemble's own states, also stacked time-major, still run
    assert ens.metric(np.zeros((4, 3, 3))).shape == (4, 3, 3, 3)


def test_the_compiled_backend_runs_per_member_constants_as_each_member_alone(sleighs):
    """backend='numba' (or 'auto') with per-member constants: the numpy path, member by member as alone."""
    pytest.importorskip("numba")
    ens, ones = sleighs
    z0 = _starts(ens, ones)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = liefi.FeedbackIntegrator(ens, z0, gains=1.0).run(0.5, dt=0.01, backend="numba")
    assert sol.method["backend"] == "numpy"
    for k in range(3):
        _agree(sol.y[k], liefi.FeedbackIntegrator(ones[k], z0[k], gains=1.0).run(0.5, dt=0.01, backend="numpy").y,
               1e-12)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_changed_constants_are_the_runs_whatever_was_cached(backend):
    """After a first run, system.constants = ...: the integrator built before runs as a fresh build of the new
    constants (it kept its energy target, taken at y0 with the old ones, and steered to the old energy); so does
    a new one (the compiled kernel, keyed on the constants, is not the old one's), at a given dt and at the
    step chosen for rtol; constants per member of an ensemble it does not hold are refused by name."""
    if backend == "numba":
        pytest.importorskip("numba")
    s = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
    z = s.state(np.zeros(3), [0.5, 0.0, 1.0])
    fi = liefi.FeedbackIntegrator(s, z, gains=1.0)
    auto = liefi.FeedbackIntegrator(s, z)
    first = fi.run(1.0, dt=0.01, backend=backend)
    auto.run(0.5, dt=0.01, backend=backend)
    s.constants = {"m": 3.0, "a": 0.8}
    fresh = _sleigh({"m": 3.0, "I": 1.0, "a": 0.8})
    for kw in (dict(dt=0.01), dict()) if backend == "numba" else (dict(dt=0.01),):  # dict(): the step for rtol
        want = liefi.FeedbackIntegrator(fresh, z, gains=1.0).run(1.0, backend=backend, **kw)
        for got in (fi.run(1.0, backend=backend, **kw),
                    liefi.FeedbackIntegrator(s, z, gains=1.0).run(1.0, backend=backend, **kw)):
            assert got.method["dt"] == want.method["dt"]
            _agree(got.y, want.y)
    assert np.max(np.abs(want.y[..., -1] - first.y[..., -1])) > 1e-3  # the new constants moved the run
    _agree(auto.run(0.5, dt=0.01, backend=backend).y,  # gains="auto": its unit-rate gains taken again too
           liefi.FeedbackIntegrator(fresh, z).run(0.5, dt=0.01, backend=backend).y)
    s.constants = {"m": [1.0, 2.0]}
    with pytest.raises(ValueError, match=r"y0: the system holds per-member constants"):
        fi.run(0.1, dt=0.01, backend=backend)


def test_a_forced_run_with_per_member_constants_is_each_members_own():
    """A forced from_mechanics sleigh (torque input, damper c): an ensemble with per-member m and c equals
    each member alone; one state with per-member constants is refused by name (was a raw numpy broadcast error
    on the sensitivities' path)."""
    from test_forced_sensitivity import sleigh_model as forced_sleigh
    from liefi.systems.forcing import piecewise_constant

    tau = piecewise_constant(np.linspace(0.0, 0.3, 5), [0.3, -0.2, 0.5, 0.1])
    m, c, th = np.array([2.0, 1.0, 3.0]), np.array([0.5, 0.1, 1.0]), np.array([0.3, 0.1, -0.2])
    s = forced_sleigh()
    s.constants = {"m": m, "c": c}
    z = s.state(np.stack([np.zeros(3), np.zeros(3), th], -1),
                np.stack([0.5 * np.cos(th), 0.5 * np.sin(th), np.full(3, 0.4)], -1))
    sol = liefi.FeedbackIntegrator(s, z, inputs={"tau": tau}, gains=10.0).run(0.3, dt=0.025, backend="numpy")
    for k in range(3):
        one = forced_sleigh()
        one.constants = {"m": m[k], "c": c[k]}
        _agree(sol.y[k], liefi.FeedbackIntegrator(one, z[k], inputs={"tau": tau}, gains=10.0).run(
            0.3, dt=0.025, backend="numpy").y)
    with pytest.raises(ValueError, match=r"y0: the system holds per-member constants"):
        liefi.FeedbackIntegrator(s, z[0], inputs={"tau": tau}).run(0.3, dt=0.025, sensitivities=("m",))


def test_a_scene_keys_what_it_keeps_by_its_systems_constants(monkeypatch):
    """scene.system.constants = ...: the scene's reference and its step for a tolerance are those of the new
    constants (they were the old ones', kept on the scene and in the store by keys without the constants)."""
    from liefi.scenes import store
    from liefi.scenes.base import Scene, Variant

    monkeypatch.setenv("LIEFI_REFERENCE_STORE", "0")

    class Sleigh(Scene):
        name = "members-sleigh"
        reference = "numerical"
        dt, t_final, scheme, gains = 0.01, 1.0, "rk4", 1.0
        variants = {"v": Variant("v", "a from_mechanics sleigh")}
        error_variables = ("x", "theta")
        in_paper = False
        mass = 1.0

        def build_system(self):
            return _sleigh({"m": self.mass, "I": 1.0, "a": 0.5})

        def initial_state(self, variant):  # fixed momenta: with another mass, other velocities
            return np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.4])

    t = np.linspace(0.0, 1.0, 5)
    sc, v = Sleigh(), Sleigh.variants["v"]
    before = sc.reference_values(t, v)
    key = store.key(sc, v, ("reference", t))
    sc.system.constants = {"m": 2.0, "a": 0.3}
    fresh = Sleigh()
    fresh.system.constants = {"m": 2.0, "a": 0.3}  # the same constants, set on a scene never used before
    after, want = sc.reference_values(t, v), fresh.reference_values(t, v)
    for name in ("x", "theta"):
        _agree(after[name], want[name], 1e-12)
    assert np.max(np.abs(after["x"] - before["x"])) > 1e-2
    assert store.key(sc, v, ("reference", t)) not in (None, key)
    assert store.key(sc, v, ("reference", t)) == store.key(fresh, v, ("reference", t))
    sc.system.constants = {"m": 1.0, "a": 0.5}  # back as built: the key as built
    assert store.key(sc, v, ("reference", t)) == key


def test_the_step_choices_resolution_test_reads_each_members_constants(no_refusal):
    """20 members (more than the 16 the resolution test of the step for rtol spreads over): the fastest rate
    of the unforced dynamics at the start is the fastest of the members alone (was 3.12 against 1.9985: the
    16 states were read with the first member's constants)."""
    from liefi.integrator.tolerance import _unforced_eigenvalues

    N = 20
    m, a = np.linspace(0.5, 4.0, N), np.linspace(0.9, 0.2, N)
    ens = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
    ens.constants = {"m": m, "a": a}
    z = ens.state(np.zeros((N, 3)), np.stack([np.linspace(0.3, 1.0, N), np.zeros(N), np.linspace(-2, 2, N)], -1))
    got = np.max(np.abs(_unforced_eigenvalues(liefi.FeedbackIntegrator(ens, z, gains=1.0), z)))
    one = _sleigh({"m": 1.0, "I": 1.0, "a": 0.5})
    alone = []
    for k in np.unique(np.linspace(0, N - 1, 16).astype(int)):
        one.constants = {"m": m[k], "a": a[k]}
        alone.append(np.max(np.abs(_unforced_eigenvalues(liefi.FeedbackIntegrator(one, z[k], gains=1.0), z[k][None]))))
    np.testing.assert_allclose(got, max(alone), rtol=1e-12)
    assert not no_refusal
