"""The non-reversible test problems (``liefi/scenes/nonreversible.py``): fast checks only.

Oracles: the gauge shift ``p = v - grad S(q)`` is a symplectic change of
coordinates, so the shifted problem's fields are the push-forward of the
unshifted ones (exact to rounding, at random states, on and off the constraint
set), its constrained motion ``q(t)`` is the ``oscillator`` scene's, and it is
reversible for ``(q, p) -> (q, -p + 2 A(q))`` but not for ``(q, p) -> (q, -p)``.
The long-time comparison is ``benchmarks/nonreversible.py``.
"""

import numpy as np
import pytest

from liefi import scenes
from liefi.reduction import core
from liefi.scenes.nonreversible import GaugeShiftedContactOscillator

NAMES = [n for n in scenes.names() if n.startswith("nonreversible-")]


def test_registered():
    assert len(NAMES) >= 2
    for n in NAMES:
        assert scenes.get(n).name == n


class _Unshifted(GaugeShiftedContactOscillator):
    """The same data without the gauge shift (``A = 0``): the reversible problem."""

    name = "unshifted"

    def __init__(self, eps):
        self.eps = eps

    def build_system(self):
        from liefi import CotangentBundle, NonholonomicSystem

        return NonholonomicSystem(CotangentBundle(3, names=("x", "y", "z")), np.eye(3), self.constraint,
                                  self.potential)


def _unshifted(sc):
    """The reversible twin's system: the same data with ``A = 0``."""
    if sc.name == "nonreversible-knife-edge":
        return scenes.get("knife-edge").system
    return _Unshifted(sc.eps).system


def _random_states(rng, k=20):
    q = rng.uniform(-1.5, 1.5, (k, 3))
    v = rng.normal(size=(k, 3))
    return q, v


def _jacobian_A(sc, q):
    """``dA/dq`` of the scene's vector potential, by central differences of its closed form."""
    h = 1e-6
    cols = []
    for j in range(3):
        dq = np.zeros(3)
        dq[j] = h
        cols.append((sc.vector_potential(q + dq) - sc.vector_potential(q - dq)) / (2 * h))
    return np.stack(cols, -1)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("kind", ["extended", "constrained"])
def test_fields_are_the_push_forward_of_the_unshifted_ones(name, kind):
    """``G(q, P) = (q, P + A(q))``: ``X_shifted(G y) = DG X_unshifted(y)`` at random states."""
    sc = scenes.get(name)
    ref = _unshifted(sc)
    rng = np.random.default_rng(7)
    q, v = _random_states(rng)
    y = np.concatenate([q, v], -1)  # unshifted: P = m v (m = I here)
    if kind == "constrained":
        y = ref.project(y)
    yg = y.copy()
    yg[:, 3:] += sc.vector_potential(y[:, :3])
    X = core.full_vector_field(ref, y, kind=kind)
    Xg = core.full_vector_field(sc.system, yg, kind=kind)
    assert np.max(np.abs(Xg[:, :3] - X[:, :3])) <= 1e-12 * max(1.0, np.max(np.abs(X)))
    push = X[:, 3:] + np.einsum("kij,kj->ki", np.stack([_jacobian_A(sc, qq) for qq in y[:, :3]]), X[:, :3])
    assert np.max(np.abs(Xg[:, 3:] - push)) <= 1e-8 * max(1.0, np.max(np.abs(X)))


@pytest.mark.parametrize("name", NAMES)
def test_not_reversible_for_the_standard_map_but_for_the_shifted_one(name):
    """Constrained field ``X``: ``X(R y) = -DR X(y)`` for ``R(q, p) = (q, -p + 2A(q))``, not for ``(q, -p)``."""
    sc = scenes.get(name)
    rng = np.random.default_rng(3)
    q, v = _random_states(rng)
    A = sc.vector_potential(q)
    y = sc.system.project(np.concatenate([q, v + A], -1))
    X = core.full_vector_field(sc.system, y, kind="constrained")
    scale = np.max(np.abs(X))

    def reversal_defect(R, DR):
        Ry = R(y)
        XR = core.full_vector_field(sc.system, Ry, kind="constrained")
        return np.max(np.abs(XR + np.einsum("kij,kj->ki", DR(y), X))) / scale

    def standard(y):
        return np.concatenate([y[:, :3], -y[:, 3:]], -1)

    def d_standard(y):
        return np.broadcast_to(np.diag([1.0, 1, 1, -1, -1, -1]), (len(y), 6, 6))

    def shifted(y):
        return np.concatenate([y[:, :3], -y[:, 3:] + 2 * sc.vector_potential(y[:, :3])], -1)

    def d_shifted(y):
        D = np.zeros((len(y), 6, 6))
        D[:, :3, :3] = np.eye(3)
        D[:, 3:, 3:] = -np.eye(3)
        D[:, 3:, :3] = 2 * np.stack([_jacobian_A(sc, qq) for qq in y[:, :3]])
        return D

    assert reversal_defect(shifted, d_shifted) < 1e-8
    assert reversal_defect(standard, d_standard) > 1e-2
    # the unshifted problem is reversible for the standard map
    ref = _unshifted(sc)
    y0 = ref.project(np.concatenate([q, v], -1))
    X0 = core.full_vector_field(ref, y0, kind="constrained")
    XR0 = core.full_vector_field(ref, standard(y0), kind="constrained")
    assert np.max(np.abs(XR0 + np.einsum("kij,kj->ki", d_standard(y0), X0))) < 1e-12 * np.max(np.abs(X0))


def test_motion_is_the_oscillator_scene_motion():
    """``nonreversible-oscillator`` moves exactly as ``oscillator``: same ``q(t)``, ``p = p_osc + A(q)``."""
    nr, osc = scenes.get("nonreversible-oscillator"), scenes.get("oscillator")
    v_nr, v_osc = nr.variant(), osc.variant()
    t = np.linspace(0.0, 10.0, 201)
    a = nr.numerical_reference(t, v_nr)
    b = osc.numerical_reference(t, v_osc)
    for k in ("x", "y", "z"):
        np.testing.assert_allclose(a[k], b[k], rtol=0, atol=1e-9)
    A = nr.vector_potential(np.stack([b["x"], b["y"], b["z"]], -1))
    for i, k in enumerate(("p_x", "p_y", "p_z")):
        np.testing.assert_allclose(a[k], b[k] + A[:, i], rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_start_and_first_integrals(name):
    """The start is on the constraint set; h, h~, J and H_y are first integrals of the
    constrained field (their derivative along it vanishes at random constrained states)."""
    sc = scenes.get(name)
    fi = sc.integrator(sc.variant())
    y0 = sc.initial_state(sc.variant())
    assert abs(float(sc.system.constraint_momenta(y0)[0])) < 1e-15
    rng = np.random.default_rng(11)
    q, v = _random_states(rng)
    y = sc.system.project(np.concatenate([q, v + sc.vector_potential(q)], -1))
    X = core.full_vector_field(sc.system, y, kind="constrained")
    h = 1e-6
    vp = fi.invariant_values(y + h * X)
    vm = fi.invariant_values(y - h * X)
    for k in vp:
        if k == "energy":
            continue
        rate = (np.asarray(vp[k]) - np.asarray(vm[k])) / (2 * h)
        assert np.max(np.abs(rate)) < 1e-6, k


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("variant", ["extended", "original"])
def test_runs_at_defaults_with_small_drift(name, variant):
    """The scene's defaults (RK4, dt = 1e-2, gains 1), on a short horizon: drift and error small."""
    sc = scenes.get(name)
    r = sc.run(t_final=20.0, variant=variant)
    assert max(r.max_drift.values()) <= 1e-8, r.max_drift
    assert max(r.max_error.values()) <= 1e-6, r.max_error
    assert r.scheme == "rk4" and r.dt == 1e-2
