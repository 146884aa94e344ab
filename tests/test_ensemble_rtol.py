"""What ``rtol`` means for an ensemble: every member within it, relative to its own size.

``FeedbackIntegrator.run(T, rtol=...)`` with an ensemble start ``y0`` of shape ``(N, n)`` chooses one step for
every member (:func:`liefi.integrator.tolerance.choose_step`).  The error scale is each member's own,
``s_{b,i} = atol_i + rtol max_t |y_{b,i}(t)|`` (the maximum over time only, never over members), and the
ensemble's error is the largest over the members of each member's scaled error.  So a member whose motion is
small is not judged against the largest member's size: each meets ``rtol`` against its own reference, and the
ensemble's step is at most the strictest member's alone (up to the step choice's own noise: an ensemble's
short run is not checked, :func:`liefi.integrator.tolerance_check.check_min_steps`, while a single compiled
trajectory's is).
"""

import warnings

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from liefi import FeedbackIntegrator, scenes

#: The ensemble's step may exceed the strictest member's alone by this fraction: the two choices go different
#: routes (an ensemble's short run is the local model's, one compiled trajectory's is measured), measured 0.9%.
MARGIN = 0.03


@pytest.fixture(autouse=True)
def _no_store(monkeypatch):
    monkeypatch.setenv("LIEFI_REFERENCE_STORE", "0")


def _own_error(fi, t, y, y0, T):
    """``max_t max_i |y_i(t) - y_ref,i(t)| / s_i``, ``s_i`` the member's own size ``max_t |y_ref,i|`` floored at
    1e-2 of the largest of its part (the module's scale): ``y_ref`` an independent DOP853 run at ``1e-10``."""
    ref = solve_ivp(lambda _t, x: fi.fun(_t, x), (0.0, T), y0, method="DOP853", rtol=1e-10, atol=1e-13,
                    dense_output=True)
    assert ref.success
    size = np.max(np.abs(ref.y), axis=1)
    nc, nx = fi.nc, fi.system.space.n
    for a, b in zip([0, nc, nc + nx], [nc, nc + nx, fi.n]):
        if b > a:
            size[a:b] = np.maximum(size[a:b], 1e-2 * np.max(size[a:b]))
    return float(np.max(np.abs(np.asarray(y) - ref.sol(np.asarray(t))) / size[:, None]))


def _members(name):
    fi0 = scenes.get(name).integrator(gains="auto")
    y0 = np.asarray(fi0.y0, float)
    if name == "kepler":  # orbits of sizes 1, 2 and 4 (the smallest the fastest) and eccentricities about
        return fi0, [y0 * np.r_[[a] * 3, [a ** -0.5] * 3] * np.r_[1, 1, 1, 1, f, 1]
                     for a, f in ((1, 1.0), (2, 1.0), (4, 1.0), (1, 0.9), (1, 1.1))]
    # the knife edge sliding at speeds 0, 0.3 and 2 beside its spin (the fastest the strictest)
    return fi0, [y0 + np.r_[0, 0, 0, v, 0, 0] for v in (0.0, 0.3, 2.0)]


@pytest.mark.parametrize("name, T", [("kepler", 100.0), ("knife-edge", 50.0)])
def test_every_member_of_an_ensemble_meets_rtol_against_its_own_reference(name, T):
    """Kepler over ``[0, 100]`` (the check measures the ensemble's step) and the knife edge over ``[0, 50]`` (an
    ensemble's short run: the local model's step), ``rtol = 1e-6``: each member's error relative to its own size
    is at most ``rtol``, and the ensemble's step at most the strictest member's alone times ``1 + MARGIN``."""
    rtol = 1e-6
    fi0, Y = _members(name)
    Y = np.stack(Y)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ens = FeedbackIntegrator(fi0.system, Y).run(T, rtol=rtol)
        alone = [FeedbackIntegrator(fi0.system, y).run(T, rtol=rtol) for y in Y]
    y = np.asarray(ens.y)
    assert y.shape[:2] == Y.shape
    errors = [_own_error(FeedbackIntegrator(fi0.system, Y[b]), ens.t, y[b], Y[b], T) / rtol for b in range(len(Y))]
    assert max(errors) <= 1.0, (name, errors)
    dts = [r.method["dt"] for r in alone]
    assert ens.method["dt"] <= min(dts) * (1 + MARGIN), (name, ens.method["dt"], dts)


def test_the_check_scales_each_member_by_its_own_size_and_takes_the_largest_error():
    """The measured check (:func:`liefi.integrator.tolerance_check._global_check`) of an ensemble of a small, fast
    Kepler orbit and a large, slow one at one coarse step: its error is the larger of the two members' checks
    alone (to rounding), not the small orbit's error against the large orbit's size."""
    from liefi.integrator import tolerance as tol
    from liefi.schemes.registry import REGISTRY

    fi0, Y = _members("kepler")
    Y = np.stack([Y[0], Y[2]])  # sizes 1 and 4
    sch = REGISTRY["imex-rk4"]
    T, H, rtol = 20.0, 0.2, 1e-6
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ens = FeedbackIntegrator(fi0.system, Y)
        flat = ens.members()
        with flat.selection():
            got = tol._global_check(flat, sch, Y, 0.0, T, H, T, rtol, np.asarray(0.0), 4, "numpy", n_min=8)
        each = [tol._global_check(FeedbackIntegrator(fi0.system, y), sch, y, 0.0, T, H, T, rtol, np.asarray(0.0),
                                  4, "numpy", n_min=8) for y in Y]
    assert got is not None and all(c is not None for c in each)
    assert each[0][0] > 10 * each[1][0]  # the small orbit is the demanding one
    for k in (0, 1, 8):  # E, E_safe and the coarse run's error E_1
        assert got[k] == pytest.approx(max(c[k] for c in each), rel=1e-9), k


class _ModelRuns:
    """The check's runs (:class:`liefi.integrator._check_runs.CheckRuns`) replaced by a model of their errors: the
    run at step ``h`` of member ``b`` is its start plus ``1e-6 K_b (h / H_0)^{q_b} (t - t_0) / tau`` times its
    own size, ``H_0`` the first step asked (the check's coarse step), so each member has its own error and
    order (``K_b`` in units of ``rtol = 1e-6``)."""

    models = None

    def __init__(self, fi, sch, y0, backend):
        from liefi.integrator.tolerance_check import CHECK_PART_FLOOR, _size

        self.y0 = np.asarray(y0, float)
        self.size = _size(fi, np.abs(self.y0), CHECK_PART_FLOOR)  # the check's scale of the start
        self.H0 = None

    def drift_scales(self):
        return None

    def __call__(self, t0, tau, h, save_every):
        self.H0 = h if self.H0 is None else self.H0
        n = int(round(tau / h))
        t = np.arange(0, n + 1, save_every) * h / tau
        K, q = (np.asarray(a, float) for a in zip(*self.models))
        amp = (K * (h / self.H0) ** q).reshape((-1, 1) if self.y0.ndim > 1 else ())
        return self.y0 + (amp * self.size)[None] * (1e-6 * t).reshape((-1,) + (1,) * self.y0.ndim)


def _model(E, q):
    """``(K, q)`` of :class:`_ModelRuns` whose check error (Richardson, order 4) at ``h = H_0/2`` is ``E rtol``:
    ``K 2^-q (1 - 2^-q) / (1 - 2^-4) = E``."""
    return E * (1 - 2.0 ** -4) / (2.0 ** -q * (1 - 2.0 ** -q)), q


def _model_choices(monkeypatch, models, rtol=1e-6, T=200.0):
    """``[(dt, info)]`` of :func:`liefi.integrator.tolerance.choose_step` (``imex-rk4``, numpy, Kepler's start
    for every member) with the check's runs :class:`_ModelRuns` of ``models``: the ensemble of all, then each
    member alone."""
    import math

    from liefi.integrator import tolerance as tol, tolerance_check as tc
    from liefi.schemes.registry import REGISTRY

    monkeypatch.setattr(tol, "CheckRuns", _ModelRuns)
    monkeypatch.setattr(tol, "_drift_cap", lambda *a: math.inf)  # the model's states do not keep the invariants
    monkeypatch.setattr(tc, "_drift_cap", lambda *a: math.inf)
    monkeypatch.setattr(tc, "_drift_pair", lambda *a: (None, None))
    fi0 = scenes.get("kepler").integrator(gains="auto")
    y0 = np.asarray(fi0.y0, float)
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for which in [list(range(len(models)))] + [[k] for k in range(len(models))]:
            _ModelRuns.models = [models[k] for k in which]
            Y = np.stack([y0] * len(which)) if len(which) > 1 else y0
            out.append(tol.choose_step(FeedbackIntegrator(fi0.system, Y), REGISTRY["imex-rk4"], Y, 0.0, T, rtol,
                                       backend="numpy"))
    return out


def test_an_ensembles_step_is_each_members_own_error_at_its_own_measured_order(monkeypatch):
    """Two members whose check errors follow different orders: member 0's is ``30 rtol`` at the check's step
    ``h = H/2`` and of order 4, member 1's ``3 rtol`` and of order 12 (so its error at ``H`` is the larger).
    The ensemble's step is the strictest member's alone, each member's error extrapolated by its own order.
    Before, the order was ``log2`` of the largest error at ``H`` (member 1's) over the largest at ``h``
    (member 0's), 8.6: the ensemble's step was 1.82 times member 0's own (0.0588 against 0.0322), where
    member 0's error is ``30 (0.0588 / 0.0993)^4 = 3.7 rtol``: a silent wrong answer."""
    got = _model_choices(monkeypatch, [_model(30.0, 4.0), _model(3.0, 12.0)])
    assert all(info["check_step"] is not None and info["check_trusted"] for _, info in got)
    dts = [dt for dt, _ in got]
    assert dts[0] <= min(dts[1:]) * (1 + 1e-9), dts


def test_an_ensembles_check_is_trusted_only_where_every_member_converges(monkeypatch):
    """Member 0 small (``0.1 rtol``) but not in the asymptotic regime (order 1: halving the step halves the
    difference), member 1 large and of order 4: the check is untrusted, as member 0's alone is, and the
    ensemble's step at most the strictest member's.  Before, the ratio test took the largest difference at
    ``H`` (member 1's) over the largest at ``H/2`` and trusted it."""
    got = _model_choices(monkeypatch, [_model(0.1, 1.0), _model(3.0, 4.0)])
    assert [info["check_trusted"] for _, info in got] == [False, False, True]
    assert got[0][0] <= min(dt for dt, _ in got[1:]) * (1 + 1e-9)
