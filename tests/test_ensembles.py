"""An ensemble is its members run one by one (issue 15): per-member targets, gains, automatic gains and
adaptive schedules, on numpy and the compiled engine; and the test gaps of that audit (the split schemes'
accurate rate, a group with two orthogonal blocks, dropping an exactly kept invariant only on target)."""

import warnings

import numpy as np
import pytest

import liefi
from liefi import scenes
from liefi.groups import SO2, SO3, MatrixLieGroup, ProductGroup

try:
    import numba  # noqa: F401

    BACKENDS = ["numpy", "numba"]
except ImportError:  # pragma: no cover
    BACKENDS = ["numpy"]


def _quiet(f, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*a, **k)


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.fixture(scope="module")
def suslov3():
    """Three Suslov states with h = 0.782, 0.885, 0.703 (issue 15's example)."""
    sc = scenes.get("suslov")
    fi = sc.integrator()
    h0 = fi.invariant_values(fi.y0)["h"]
    Y = np.repeat(fi.y0[None], 3, 0)
    for i, h in enumerate((0.782, 0.885, 0.703)):
        Y[i, fi.nc :] *= np.sqrt(h / h0)
    return sc, fi, Y


def _ensemble_and_singles(sc, fi, Y, scheme, gains, backend, dt, T, targets=None, **kw):
    def make(y, g, t):
        return liefi.FeedbackIntegrator(sc.system, y, gains=g, targets=t, configuration=fi.configuration)

    ens = _quiet(make(Y, gains, targets).run, T, dt=dt, scheme=scheme, backend=backend, **kw)
    singles = []
    for i in range(len(Y)):
        gi = {k: v[i] for k, v in gains.items()} if isinstance(gains, dict) else gains
        ti = {k: v[i] for k, v in targets.items()} if targets else None
        singles.append(_quiet(make(Y[i], gi, ti).run, T, dt=dt, scheme=scheme, backend=backend, **kw))
    return ens, singles


def test_issue_example_each_member_keeps_its_own_energy(suslov3):
    sc, fi, Y = suslov3
    ens, singles = _ensemble_and_singles(sc, fi, Y, "heun", sc.gains, "numpy", 1e-3, 0.5)
    h = fi.invariant_values(ens.y[..., -1])["h"]
    np.testing.assert_allclose(h, [0.782, 0.885, 0.703], rtol=1e-5)  # was 0.79 for every member
    for i, s in enumerate(singles):
        assert _rel(ens.y[i], s.y) < 1e-10


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("scheme,gains,T", [("euler", "auto", 0.5), ("heun", 100.0, 0.5), ("rk4", "auto", 5.0),
                                            ("imex-rk4", "auto", 0.5), ("imex-euler", 10.0, 0.5)])
def test_ensemble_equals_single_runs(suslov3, backend, scheme, gains, T):
    """Member by member to 1e-10: explicit and split schemes, fixed and automatic gains (euler: adapted)."""
    sc, fi, Y = suslov3
    dt = 1e-3 if T < 1 else 1e-2
    ens, singles = _ensemble_and_singles(sc, fi, Y, scheme, gains, backend, dt, T)
    assert ens.backend == backend
    for i, s in enumerate(singles):
        assert _rel(ens.y[i], s.y) < 1e-10, (i, _rel(ens.y[i], s.y))
    if gains == "auto" and scheme != "rk4":  # the members' own automatic gains differ (rk4: z* = 0 here)
        g = ens.stability.gains["energy"]
        assert np.ndim(g) == 1 and np.ptp(g) > 0
        np.testing.assert_allclose(g, [s.stability.gains["energy"] for s in singles], rtol=1e-12)


def test_an_adapted_ensemble_that_starts_late_records_its_gains_at_the_single_runs_times(suslov3):
    """Over t in [5, 7] each member's gains change at the times of its single run (t0 + steps * dt)."""
    sc, fi, Y = suslov3
    ens = _quiet(liefi.FeedbackIntegrator(sc.system, Y, gains="auto", configuration=fi.configuration).run,
                 (5.0, 7.0), dt=1e-2, scheme="euler", backend="numpy")
    one = _quiet(liefi.FeedbackIntegrator(sc.system, Y[0], gains="auto", configuration=fi.configuration).run,
                 (5.0, 7.0), dt=1e-2, scheme="euler", backend="numpy")
    assert ens.stability.adaptive and one.stability.gain_times
    assert ens.stability.gain_times == one.stability.gain_times
    assert min(ens.stability.gain_times) > 5.0


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("scheme", ["heun", "imex-rk4"])
def test_gains_and_targets_that_differ_between_members(suslov3, backend, scheme):
    """gains={"energy": array}, targets={"energy": array}: each member reads its own row of the parameters
    (the compiled ensemble kernel included)."""
    sc, fi, Y = suslov3
    gains = {"J_1": np.array([5.0, 50.0, 20.0]), "energy": np.array([1.0, 100.0, 30.0])}
    if fi.use_penalty:
        gains["penalty"] = np.array([1.0, 10.0, 3.0])
    targets = {"energy": np.array([0.8, 0.86, 0.72])}
    ens, singles = _ensemble_and_singles(sc, fi, Y, scheme, gains, backend, 1e-3, 0.3, targets=targets)
    assert ens.backend == backend
    for i, s in enumerate(singles):
        assert _rel(ens.y[i], s.y) < 1e-10, (i, _rel(ens.y[i], s.y))
    ensf = liefi.FeedbackIntegrator(sc.system, Y, gains=gains, targets=targets, configuration=fi.configuration)
    assert ensf.parameters().shape == (3, ensf.parameter_layout.size)  # one row per member


def test_per_member_values_are_checked(suslov3):
    sc, fi, Y = suslov3
    kw = {"configuration": fi.configuration}
    with pytest.raises(ValueError, match="gains: the gain of 'energy' has shape \\(2,\\).*one value per member"):
        liefi.FeedbackIntegrator(sc.system, Y, gains={"constraints": 1.0, "energy": [1.0, 2.0]}, **kw)
    with pytest.raises(ValueError, match="non-negative"):
        liefi.FeedbackIntegrator(sc.system, Y, gains={"constraints": 1.0, "energy": [1.0, -2.0, 1.0]}, **kw)
    with pytest.raises(ValueError, match="targets: the target of 'energy'"):
        liefi.FeedbackIntegrator(sc.system, Y, targets={"energy": [1.0, np.nan, 1.0]}, **kw)
    ens = liefi.FeedbackIntegrator(sc.system, Y, **kw)
    with pytest.raises(ValueError, match="y0: this integrator holds the targets and gains of an ensemble"):
        ens.run(0.01, dt=1e-3, y0=Y[:2])


# --- the split schemes' accurate rate ------------------------------------------------------------------


def test_split_auto_gains_keep_the_invariants_to_rounding():
    """gains="auto" on a split scheme is a Gauss--Newton step onto the invariant set (z* = 1/sqrt(u)):
    Suslov's J_1 and energy stay at rounding (1/u^(1/4) leaves ~1e-8)."""
    sc = scenes.get("suslov")
    fi = sc.integrator(gains="auto")
    sol = _quiet(fi.run, 20.0, dt=1e-2, scheme="imex-euler", save_every=100)
    vals = fi.invariant_values(sol.y.T)
    assert np.max(np.abs(vals["J_1"][5:])) < 1e-12
    assert np.max(np.abs(vals["energy"][5:] - fi.targets["energy"])) < 1e-12


# --- a group with two orthogonal blocks --------------------------------------------------------------


class SO3xSO2(MatrixLieGroup):
    """SO(3) x SO(2) as one 5x5 block-diagonal matrix group: two declared orthogonal blocks."""

    dim = 4
    matrix_dim = 5
    orthogonal_blocks = ((0, 3), (3, 2))
    algebra_names = ("Pi_1", "Pi_2", "Pi_3", "Pi_4")

    def hat(self, xi):
        xi = np.asarray(xi)
        out = np.zeros(xi.shape[:-1] + (5, 5), dtype=xi.dtype)
        out[..., :3, :3] = SO3().hat(xi[..., :3])
        out[..., 3:, 3:] = SO2().hat(xi[..., 3:])
        return out

    def vee(self, X):
        X = np.asarray(X)
        return np.concatenate([SO3().vee(X[..., :3, :3]), SO2().vee(X[..., 3:, 3:])], -1)

    def exp(self, xi):
        xi = np.asarray(xi, float)
        out = np.zeros(xi.shape[:-1] + (5, 5))
        out[..., :3, :3] = SO3().exp(xi[..., :3])
        out[..., 3:, 3:] = SO2().exp(xi[..., 3:])
        return out


@pytest.mark.parametrize("group", [SO3xSO2(), ProductGroup(SO3(), SO2())], ids=["declared", "product"])
def test_the_second_orthogonal_block_is_penalized_and_monitored(group):
    """Both blocks enter P = 1/4 sum ||R^T R - I||^2, its gradient, its Hessian bound, and the drift."""
    rng = np.random.default_rng(0)
    blocks = group.orthogonal_matrices(np.arange(group.config_dim, dtype=float))
    assert len(blocks) == 2
    g = group.identity_config() if hasattr(group, "identity_config") else None
    g = np.asarray(g, float).copy()
    idx = group._orthogonal_index if hasattr(group, "_orthogonal_index") else None
    second = np.asarray(idx[1]).ravel() if idx is not None else np.arange(9, 13)
    g[second] += 1e-2 * rng.standard_normal(second.size)  # only the second block leaves the group
    R = group.orthogonal_matrices(g)[1]
    E = R.T @ R - np.eye(R.shape[-1])
    assert group.penalty(g) == pytest.approx(0.25 * np.sum(E * E), rel=1e-12)
    grad = group.penalty_grad(g)
    assert np.max(np.abs(grad[second])) > 1e-3 and np.max(np.abs(np.delete(grad, second))) == 0.0
    h = 1e-7
    fd = np.array([(group.penalty(g + h * e) - group.penalty(g - h * e)) / (2 * h) for e in np.eye(g.size)])
    np.testing.assert_allclose(grad, fd, atol=1e-9)
    assert group.penalty_hessian_max(g) > 2.0  # off the group the second block's curvature is seen

    # monitored: a system on this group reports the penalty's drift from the second block
    sys_ = liefi.NonholonomicSystem(liefi.LieGroupPhaseSpace(group), np.diag([1.0, 2.0, 3.0, 1.5]))
    fi = liefi.FeedbackIntegrator(sys_, np.concatenate([g, [0.1, 0.2, 0.3, 0.4]]), invariants=["energy"], gains=1.0)
    assert fi.invariant_values(fi.y0)["penalty"] == pytest.approx(group.penalty(g), rel=1e-12)
    assert liefi.stability.drift(fi, fi.y0)[1] == "penalty"
    sol = _quiet(fi.run, 1.0, dt=1e-2, scheme="heun", backend="numpy")
    assert group.penalty(sol.y[: group.config_dim, -1]) < 0.5 * group.penalty(g)  # the feedback repairs it


# --- exactly kept invariants are dropped only on their target ----------------------------------------


def test_not_dropped_off_target_on_a_field_where_it_is_a_first_integral():
    """The vertical disk's Pi_x is a first integral with a constant gradient on the scene's (projected)
    field, so rk4 keeps it exactly; moved off its target it must keep its feedback."""
    from liefi.gains import exactly_kept

    sc = scenes.get("vertical-disk")
    fi = sc.integrator()
    off = liefi.FeedbackIntegrator(sc.system, fi.y0, invariants=fi.user, targets={"Pi_x": fi.targets["Pi_x"] + 0.1},
                                   configuration=fi.configuration, field=fi.field, gains=1.0)
    assert "Pi_x" in exactly_kept(off, "rk4")  # the condition under test is the target, nothing else
    sol = _quiet(off.run, 0.1, dt=1e-3, scheme="rk4", backend="numpy")
    dropped = [d["name"] for d in sol.dropped]
    assert "Pi_x" not in dropped and "Pi_y" in dropped
    r0 = 0.1
    r1 = off.invariant_values(sol.y[:, -1])["Pi_x"] - off.targets["Pi_x"]
    assert abs(r1) < 0.99 * r0  # its feedback acts


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_guard_watches_and_does_not_steer_adapted_gains(suslov3, backend):
    """An adapted ensemble (Euler, gains="auto") gets the same gains, schedule and states with the guard off:
    the pace of adaptation is the policy's (the members' own unforced rates), not the guard's."""
    sc, fi, Y = suslov3
    if backend == "numba":
        pytest.importorskip("numba")
    ens = liefi.FeedbackIntegrator(sc.system, Y, gains="auto", configuration=fi.configuration)
    a = _quiet(ens.run, 3.0, dt=1e-3, scheme="euler", backend=backend)
    b = _quiet(ens.run, 3.0, dt=1e-3, scheme="euler", backend=backend, check_stability=False)
    assert a.stability.adaptive and len(a.stability.gain_times) > 1
    assert a.stability.gain_times == b.stability.gain_times
    assert np.array_equal(a.y, b.y)
