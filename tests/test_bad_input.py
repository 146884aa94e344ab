"""Bad input fails early with an error that names the parameter and says what to change.

Targeted cases check the message of each kind of mistake (non-symmetric or
indefinite metric, dependent constraints, non-finite numbers, wrong shapes, a
start off the constraint set, non-positive steps and gains); hypothesis then
fuzzes the constructors and the run options: every failure must be a
``ValueError`` or ``TypeError`` whose message starts with, or names, one of
the parameters that were passed -- nothing else escapes.
"""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import liefi
from liefi import CotangentBundle, FeedbackIntegrator, LieGroupPhaseSpace, NonholonomicSystem, TrivialPrincipalBundle
from liefi import scenes
from liefi.groups import S1, SE2, SO3
from liefi.stability import LiefiStabilityWarning

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def names_parameter(exc, params):
    """True when the message names one of ``params`` (as ``name:`` or as a word)."""
    msg = str(exc)
    return any(re.search(rf"(^|\W){re.escape(p)}(\W|$)", msg) for p in params)


# --- targeted: the system's data --------------------------------------------------------------


def _racer_metric_filled_in_place(x):
    """The README racer's metric written the tempting way: ``cos`` filled into a float array.

    The fill drops the imaginary part of the complex step, so liefi would see
    ``dm/dpsi = 0``; at ``psi = 0`` that is also the true derivative of ``cos``."""
    x = np.asarray(x)
    m = np.zeros(x.shape[:-1] + (4, 4))
    m[..., 0, 0] = 2 + 0.5 * np.cos(x[..., 0])  # ComplexWarning: imaginary part discarded
    m[..., 0, 2] = m[..., 2, 0] = 0.3
    m[..., 0, 3] = m[..., 3, 0] = 0.4
    m[..., 1, 1] = m[..., 2, 2] = 1.0
    m[..., 3, 3] = 0.5
    return m


def test_complex_step_unsafe_datum_with_zero_derivative_at_the_sample_is_caught():
    """Issue 10 item 9: checked at several points, not only at ``x = 0`` (where ``cos' = 0``)."""
    space = TrivialPrincipalBundle(SE2(), 1, names=("psi",))
    rows = np.array([[0.0, 0.0, 1.0, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpy's ComplexWarning from the fill
        with pytest.raises(ValueError, match="metric: its complex-step derivative (disagrees|is exactly zero)"):
            NonholonomicSystem(space, _racer_metric_filled_in_place, rows)
        # the same function with its derivative supplied is accepted (the check is on the derivative)
        def dm(x):
            x = np.asarray(x)
            out = np.zeros(x.shape[:-1] + (1, 4, 4))
            out[..., 0, 0, 0] = -0.5 * np.sin(x[..., 0])
            return out

        NonholonomicSystem(space, _racer_metric_filled_in_place, rows, metric_derivative=dm)


@pytest.mark.filterwarnings("error")  # named, without a numpy warning on the way
@pytest.mark.parametrize("unsafe", ["real", "astype"])
def test_other_complex_step_unsafe_potentials_are_caught(unsafe):
    def potential(x):
        c = np.cos(x[..., 0])
        return np.real(c) if unsafe == "real" else c.astype(float)

    with pytest.raises(ValueError, match="potential: its complex-step derivative (disagrees|is exactly zero)"):
        NonholonomicSystem(CotangentBundle(1), np.eye(1), None, potential)


@pytest.mark.filterwarnings("error")  # named, without a numpy warning on the way
def test_complex_constant_metric_is_refused():
    """Issue 10 item 10: a complex constant metric was taken with its imaginary part dropped."""
    with pytest.raises(ValueError, match="metric: complex values"):
        NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.diag([1.0, 2.0, 3.0]) + 0.1j * np.eye(3))
    with pytest.raises(ValueError, match="constraints: complex values"):
        NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.eye(3), [[1.0, 1j, 0.0]])
    with pytest.raises(ValueError, match="metric: returns complex values"):
        NonholonomicSystem(CotangentBundle(1), lambda x: (1 + 0.1j) * np.ones(np.shape(x)[:-1] + (1, 1)))
    # a complex array with zero imaginary part is a real array
    NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.eye(3) + 0j)


def test_non_symmetric_metric():
    with pytest.raises(ValueError, match="metric: not symmetric.*\\(m \\+ m.T\\) / 2"):
        NonholonomicSystem(CotangentBundle(2), [[1.0, 0.5], [0.0, 1.0]])


def test_indefinite_metric():
    with pytest.raises(ValueError, match="metric: not .*positive definite"):
        NonholonomicSystem(CotangentBundle(2), np.diag([1.0, -1.0]))
    with pytest.raises(ValueError, match="metric: not .*positive definite"):
        NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.diag([1.0, 0.0, 1.0]))


def test_x_dependent_indefinite_metric():
    def metric(x):
        return np.stack([np.stack([1 + 0 * x[..., 0], 0 * x[..., 0]], -1),
                         np.stack([0 * x[..., 0], x[..., 0] - 1], -1)], -2)

    with pytest.raises(ValueError, match="metric: not positive definite"):
        NonholonomicSystem(CotangentBundle(2), metric)


def test_dependent_constraints():
    with pytest.raises(ValueError, match="constraints: .*linearly dependent.*drop redundant"):
        NonholonomicSystem(CotangentBundle(3), np.eye(3), [[1.0, 0.0, 1.0], [2.0, 0.0, 2.0]])


def test_non_finite_data():
    with pytest.raises(ValueError, match="metric: contains non-finite"):
        NonholonomicSystem(CotangentBundle(2), [[1.0, 0.0], [0.0, np.nan]])
    with pytest.raises(ValueError, match="constraints: contains non-finite"):
        NonholonomicSystem(CotangentBundle(2), np.eye(2), [np.inf, 1.0])


def test_wrong_shapes():
    with pytest.raises(ValueError, match="metric: expected shape \\(3, 3\\)"):
        NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.eye(2))
    with pytest.raises(ValueError, match="constraints: expected shape"):
        NonholonomicSystem(CotangentBundle(2), np.eye(2), [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="metric: .*number"):
        NonholonomicSystem(CotangentBundle(2), [["a", 0], [0, 1]])
    with pytest.raises(ValueError, match="sample"):
        NonholonomicSystem(CotangentBundle(2), np.eye(2), sample=[0.0, 0.0, 0.0])
    with pytest.raises(TypeError, match="space"):
        NonholonomicSystem("R2", np.eye(2))


# --- targeted: the integrator and the runs --------------------------------------------------


@pytest.fixture(scope="module")
def knife():
    return scenes.get("knife-edge")


def test_bad_start(knife):
    sys_ = knife.system
    with pytest.raises(ValueError, match="y0: expected a state of 6 numbers"):
        FeedbackIntegrator(sys_, np.zeros(5))
    with pytest.raises(ValueError, match="y0: contains non-finite"):
        FeedbackIntegrator(sys_, [0, 0, 0, 0, 0, np.nan])
    with pytest.raises(ValueError, match="y0: .*number"):
        FeedbackIntegrator(sys_, ["x"] * 6)
    fi = knife.integrator()
    with pytest.raises(ValueError, match="y0: expected a state of 6 numbers"):
        fi.run(0.01, dt=1e-3, y0=np.zeros(3))


def test_start_off_the_constraint_set_where_the_scene_needs_it_on():
    sus = type(scenes.get("suslov"))()
    sus.Pi0 = np.array([0.0, 1.0, 2.0])  # J = Pi . e = 1 with e = (0, -1, 1)
    with pytest.raises(ValueError, match="initial state: .*off the constraint set.*project"):
        sus.run(t_final=0.01)


@pytest.mark.parametrize("dt", [0.0, -1e-3, np.nan, np.inf, "a"])
def test_non_positive_or_non_finite_step(knife, dt):
    fi = knife.integrator()
    with pytest.raises(ValueError, match="^dt: "):
        fi.run(0.01, dt=dt, backend="numpy")  # (dt=None: the step chosen for rtol, tests/test_defaults.py)


@pytest.mark.parametrize("T", [0.0, -1.0, np.nan, "a"])
def test_non_positive_horizon(knife, T):
    with pytest.raises(ValueError, match="^t_final: "):
        knife.run(t_final=T)


@pytest.mark.parametrize("gains", [-1.0, np.nan, np.inf, "fast", {"J_1": -2.0, "energy": 1, "p_phi": 1},
                                   {"J_9": 1.0}, [1.0, 2.0]])
def test_bad_gains(knife, gains):
    with pytest.raises((ValueError, TypeError), match="^gains: "):
        knife.integrator(gains=gains)


def test_unknown_variant_and_scheme(knife):
    with pytest.raises(ValueError, match="^variant: "):
        knife.run(variant="nope", t_final=0.01)
    with pytest.raises(ValueError, match="^scheme: "):
        knife.run(scheme="rk5", t_final=0.01)
    with pytest.raises(ValueError, match="^scheme: "):
        knife.run(scheme="scipy:Nope", t_final=0.01)
    with pytest.raises(ValueError, match="^backend: "):
        knife.integrator().run(0.01, dt=1e-3, backend="cuda")


@pytest.mark.parametrize("opt", ["save_every", "check_every", "monitor_every"])
@pytest.mark.parametrize("value", [0, -3, 1.5, "x"])
def test_bad_run_counts(knife, opt, value):
    fi = knife.integrator()
    with pytest.raises(ValueError, match=f"^{opt}: "):
        fi.run(0.01, dt=1e-3, **{opt: value})


# --- fuzz: constructors ---------------------------------------------------------------------------

SPACES = [CotangentBundle(2), LieGroupPhaseSpace(SO3()), TrivialPrincipalBundle(SE2(S1()), 1)]
NUMBERS = st.one_of(
    st.floats(-3, 3, allow_nan=False, allow_infinity=False),
    st.sampled_from([0.0, np.nan, np.inf, -np.inf, 1e300, -1e-300]),
)


@st.composite
def arrays(draw, target_shape):
    """Arrays of about the right shape: right, one off, transposed, flat; sometimes garbage types."""
    kind = draw(st.sampled_from(["right", "right", "sym", "spd", "off", "flat", "scalar", "string", "ragged"]))
    shape = tuple(target_shape)
    if kind == "off" and shape:
        i = draw(st.integers(0, len(shape) - 1))
        shape = shape[:i] + (max(0, shape[i] + draw(st.sampled_from([-1, 1]))),) + shape[i + 1 :]
    if kind == "flat":
        shape = (int(np.prod(shape)),)
    if kind == "scalar":
        return draw(NUMBERS)
    if kind == "string":
        return "metric"
    if kind == "ragged":
        return [[1.0, 2.0], [3.0]]
    vals = draw(st.lists(NUMBERS, min_size=int(np.prod(shape)), max_size=int(np.prod(shape))))
    a = np.array(vals, float).reshape(shape)
    if kind in ("sym", "spd") and len(shape) == 2 and shape[0] == shape[1]:
        with np.errstate(all="ignore"):  # the drawn numbers include inf and -inf: inf + -inf is the NaN wanted
            a = a + a.T
            if kind == "spd":
                a = a @ a.T + np.eye(shape[0]) * draw(st.floats(-1.0, 1.0))
    return a


@given(data=st.data())
@FUZZ
def test_fuzz_system_constructor(data):
    space = data.draw(st.sampled_from(SPACES))
    D, n = space.D, space.n
    metric = data.draw(arrays((D, D)))
    K = data.draw(st.integers(0, D))
    constraints = data.draw(st.one_of(st.none(), arrays((K, D))))
    kwargs = {}
    if n and data.draw(st.booleans()):
        kwargs["sample"] = data.draw(arrays((n,)))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            NonholonomicSystem(space, metric, constraints, **kwargs)
    except (ValueError, TypeError) as exc:
        assert names_parameter(exc, ["metric", "constraints", "sample", "x"]), repr(exc)


@st.composite
def callables(draw, shape, n):
    kind = draw(st.sampled_from(["ok", "nan", "wrong", "raises", "complex_unsafe", "scalar"]))

    def f(x):
        x = np.asarray(x)
        base = np.broadcast_to(np.eye(shape[-1])[: shape[0]] if len(shape) == 2 else 1.0, x.shape[:-1] + shape)
        if kind == "ok":
            return base * (1.5 + np.sin(x[..., :1, None] if len(shape) == 2 else x[..., 0]))
        if kind == "nan":
            return base * np.nan
        if kind == "wrong":
            return np.zeros(x.shape[:-1] + (shape[0] + 1,) * max(1, len(shape)))
        if kind == "raises":
            raise RuntimeError("user code failed")
        if kind == "complex_unsafe":
            return base * (1.5 + np.abs(x[..., :1, None] if len(shape) == 2 else x[..., 0]))
        return 3.0

    return f


@given(data=st.data())
@FUZZ
def test_fuzz_system_with_functions_of_x(data):
    space = CotangentBundle(2)
    metric = data.draw(st.one_of(callables((2, 2), 2), arrays((2, 2))))
    constraints = data.draw(st.one_of(st.none(), callables((1, 2), 2)))
    potential = data.draw(st.one_of(st.none(), callables((), 2)))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            NonholonomicSystem(space, metric, constraints, potential)
    except (ValueError, TypeError) as exc:
        assert names_parameter(exc, ["metric", "constraints", "potential", "x"]), repr(exc)


# --- fuzz: run options ------------------------------------------------------------------------------

ANY = st.one_of(
    st.none(), NUMBERS, st.integers(-5, 10), st.text(max_size=4), st.sampled_from(["auto", "euler", "imex-euler"]),
    st.lists(NUMBERS, max_size=3), st.booleans(),
)


@given(data=st.data())
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_fuzz_scene_run_options(data):
    sc = scenes.get(data.draw(st.sampled_from(["suslov", "knife-edge", "chaplygin"])))
    opts = {}
    for name, strat in [
        ("dt", st.one_of(ANY, st.sampled_from([1e-3, 2e-3, 1e-2]))),
        ("t_final", st.one_of(ANY, st.sampled_from([0.01, 0.02]))),
        ("gains", st.one_of(ANY, st.sampled_from([1.0, 100.0, 1e7, "auto"]))),
        ("scheme", st.one_of(ANY, st.sampled_from(["euler", "rk4", "imex-euler", "scipy:RK45", "dla"]))),
        ("variant", st.one_of(st.none(), st.sampled_from(list(sc.variants) + ["nope"]))),
        ("save_every", st.one_of(st.none(), st.integers(-2, 5))),
    ]:
        if data.draw(st.booleans()):
            opts[name] = data.draw(strat)
    if "t_final" not in opts:
        opts["t_final"] = 0.01
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LiefiStabilityWarning)
            warnings.simplefilter("ignore", RuntimeWarning)
            r = sc.run(**opts)
    except (ValueError, TypeError) as exc:
        assert names_parameter(exc, list(opts) + ["n_steps"]), f"{opts}: {exc!r}"
    except liefi.IntegrationError as exc:  # a clear error at the moment it fails is fine
        assert "t=" in str(exc)
    else:
        assert all(math.isfinite(v) for v in r.max_drift.values())


@given(data=st.data())
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_fuzz_integrator_options(data):
    sc = scenes.get("suslov")
    kw = {}
    if data.draw(st.booleans()):
        kw["gains"] = data.draw(st.one_of(ANY, st.dictionaries(st.sampled_from(["J_1", "energy", "x"]), NUMBERS)))
    if data.draw(st.booleans()):
        kw["invariants"] = data.draw(st.one_of(st.just(("constraints",)), st.just(("nope",)), st.just(("Pi_1",))))
    if data.draw(st.booleans()):
        kw["A"] = data.draw(st.one_of(arrays((3, 3)), st.just(np.eye(3))))
    if data.draw(st.booleans()):
        kw["energy"] = data.draw(st.sampled_from(["extended", "original", "other"]))
    y0 = data.draw(st.one_of(st.just(np.array([0.0, 1.0, 1.0])), arrays((3,))))
    run = {k: data.draw(v) for k, v in [("dt", st.one_of(ANY, st.just(1e-3))),
                                         ("check_every", st.one_of(st.just(1), st.integers(-1, 3)))]
           if data.draw(st.booleans())}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LiefiStabilityWarning)
            warnings.simplefilter("ignore", RuntimeWarning)
            fi = FeedbackIntegrator(sc.system, y0, **kw)
            fi.run(0.01, dt=run.pop("dt", 1e-3), **run)
    except (ValueError, TypeError) as exc:
        assert names_parameter(exc, list(kw) + list(run) + ["y0", "dt", "t_final"]), f"{kw} {run}: {exc!r}"
    except liefi.IntegrationError as exc:
        assert "t=" in str(exc)


@pytest.mark.filterwarnings("error")  # named, without a numpy warning on the way
def test_overflowing_gram_matrix_is_named():
    """Constraint rows so large that E m E^T overflows: a named error, not LinAlgError from an SVD."""
    space = CotangentBundle(3)
    with pytest.raises(ValueError, match="constraints"):
        NonholonomicSystem(space, np.eye(3), np.array([[1e200, 1e200, 0.0]]))
